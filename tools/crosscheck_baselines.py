"""
Cross-check the ROS-free current-vector controller against motulator 0.18 (docs/baselines.md).

motulator needs Python >= 3.12 and the project runs on 3.11, so this runs from a scratch
environment outside the repository; the project's controller and plant (pure Python, with
pydantic) are imported from src/::

    python3.12 -m venv ../mot-env && ../mot-env/bin/pip install 'motulator==0.18.*' pydantic
    ../mot-env/bin/python tools/crosscheck_baselines.py [--duration 0.8] [--json out.json]

Both sides run the same closed loop: :class:`im_controller.baselines.current_vector.
CurrentVectorController` on :class:`im_plant.plant_sim.PlantSimulator`, and motulator's sensored
``CurrentVectorController`` (continuous-time 2DOF current PI, not the discrete one) with its
``SpeedController`` in a ``VectorControlSystem`` on its ``Drive``. The same motor (the thesis
motor, unsaturated, inverse-Γ L_σ, L_M, R_R; motulator's plant converts them to its Γ model,
which is the same machine), the same shaft (J, viscous b as motulator's B_L), T_s = 100 µs, a
computational delay of one period on both, the same bandwidths (α_c = 2π·200 rad/s, α_i = α_c,
α_s = 100 rad/s, speed α_i = α_s), the sensored observer gain k_o = 1 + 0.2|ω_m|/(α − jω_m),
k_comp = 1.5, the same rotor-flux reference, current limit and references. Both start at rest and
unmagnetized (all states zero) and magnetize identically from t = 0; the speed reference steps
0 → ``--speed`` at ``--speed-step-time``, the load torque 0 → ``--load`` at ``--load-step-time``.

The convention differences, each removed in the inputs or the setup (none after the runs):

* Scaling: motulator's space vectors are peak-value scaled, the project's power-invariant
  (×√(3/2) = K). Impedances, torques, speeds and the gains (V/A, N·m·s) are the same; the current
  limit is given to motulator as i_max/K, and the samples of motulator's currents are ×K.
* The flux reference: motulator takes the nominal stator flux ψ_s,nom and sets i_sd* =
  ψ_s,nom/(L_M + L_σ); the project sets i_sd* = ψ_R*/L_M (ψ_R* = θ φ_r*). motulator is given
  ψ_s,nom = (i_sd*/K)(L_M + L_σ), the same i_sd*.
* Field weakening: motulator's reference generator weakens the field when the voltage reference
  nears k_u u_dc/√3; the project's controller has none. motulator's DC bus is set high
  (``--u-dc``, default 10 kV), so i_sd* stays at its nominal value and the PWM never limits; the
  project runs without a voltage limit (and its inverter rating above any command).
* The first period: motulator's delay line and its PWM's record of the realized voltage start at
  zero duties (the zero vector over [t_0, t_1]); the project's :class:`im_common.delay.
  CommandDelay` is filled by the first command (it acts from t_0). Both the plant's line and the
  controller's own line are primed with one zero command before the first step, so the project too
  applies (and its observer and anti-windup take) the zero vector over the first period.
* The speed feedback: motulator's sensored mode does not use the measured speed directly but its
  speed observer, ŵ ← ŵ + T_s k_w (ω_meas − ŵ), k_w = (1 − e^{−α_o T_s})/T_s, α_o = 2π·400 rad/s
  by default, read before the update (so one period late and low-pass filtered); the observer and
  the speed PI take ŵ. The project's controller takes what it is given: it is given the same ŵ,
  computed from the plant's measured speed by the same recursion. ``--alpha-o inf`` makes it a
  pure one-period delay (ŵ_k = ω_{k−1}) on both.
* No speed-controller feedforward in motulator: the project's SpeedPI gets τ_ff = 0.
* Events on the period grid: the speed reference switches at t_step − T_s/2 (it is read at the
  sampling instants only, motulator's accumulated t_k cannot fall on the wrong side); the load
  torque is switched between periods on both (``PlantSimulator.set_load_offset`` before step k,
  and motulator's load function's value set at its sampling instant k, before its interval).
* Integration: motulator's solver tolerances are tightened (rtol 1e-10, atol 1e-12); the project's
  plant takes RK4 sub-steps of ``--max-substep``.

What is the same already and needs nothing: the gains' formulas (k_t, k_p, k_i of both loops),
k_comp = 1.5 (the project's delay + ½), the observer's hold-equivalent discretization and its
frame speed ω_m + ω̂_r, the conjugate-error gain (zero in motulator's sensored mode, h = 1), the
anti-windup voltage (the realized voltage averaged over the previous and the ongoing period), the
limited torque fed back to the speed PI, the d-axis priority and breakdown limit of i_sq*.

``--leave NAME`` (repeatable) leaves one difference in place, to see what it alone is worth.

Printed: the relative RMS difference rms(ours − motulator)/rms(motulator) of the stator current
(α and β together) and of the shaft speed, sampled at every period start, over the whole run and
over its segments (magnetizing, speed step, load step; no speed figure while both shafts are at
rest), and the wall time of both simulations.

Measured (motulator 0.18.0, defaults): current 1.7e-10, speed 8.5e-13 over the run; what is left
is the project's plant's RK4 error (6.7e-8 with one sub-step per period, 7.6e-11 with 1e-5 s:
fourth order). Left in place one at a time (current / speed, whole run): first-period 3.1e-3 /
8.0e-5, speed-feedback 3.2e-2 / 4.4e-4, flux-reference 1.5e-1 / 7.4e-3, solver (motulator's
default tolerances) no change (1.7e-10 / 8.4e-13).
"""
from __future__ import annotations

import argparse
import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))   # tools/: motulator_common
from motulator_common import (  # noqa: E402
    add_alpha_o_arg, add_common_args, base_case, compare, K, motulator_drive, prime_first_period,
    print_comparison, project_plant, run_closed_loop, simulate_motulator, speed_ref,
    SpeedObserver, write_json)


#: the convention differences ``--leave`` can leave in place (module doc)
LEAVE = {'first-period': "the project's first command acts from t_0 (its CommandDelay's fill)",
         'speed-feedback': 'the project gets the measured speed, motulator its speed observer',
         'flux-reference': "motulator's psi_s_nom = psi_R*/K (the rotor-flux reference as is)",
         'solver': "motulator's default solver tolerances (rtol 1e-3, atol 1e-6)"}


def run_ours(motor, case: dict):
    from im_controller.baselines.current_vector import CurrentVectorController
    from im_controller.baselines.gains import BaselineGains
    T_s = case['T_s']
    gains = BaselineGains(alpha_c=case['alpha_c'], alpha_s=case['alpha_s'])
    ctrl = CurrentVectorController(motor, T_s, gains, delay=1, phi_r_ref=case['phi_r_ref'],
                                   current_limit=case['i_max'], v_limit=None, tau_max=None)
    sim = project_plant(motor, case)
    prime_first_period(sim, ctrl, case)
    measured = 'speed-feedback' in case['leave']
    obs = SpeedObserver(case['alpha_o'], T_s)

    def law(m):
        v = ctrl.compute(m.t, m.i_alpha, m.i_beta, m.theta_r,
                         m.omega_r if measured else obs.w_hat, speed_ref(m.t, case), 0.0)
        obs.update(m.omega_r)
        return v

    return run_closed_loop(sim, case, law)


def run_motulator(motor, case: dict):
    import motulator.drive.control.im as control

    par, mdl, load = motulator_drive(motor, case['u_dc'])
    i_sd = case['phi_r_ref'] * motor.theta / motor.L_M  # the project's i_sd* (power-invariant)
    psi_s_nom = i_sd / K * (motor.L_M + motor.L_sigma)
    if 'flux-reference' in case['leave']:
        psi_s_nom = case['phi_r_ref'] * motor.theta / K     # ψ_R* taken for ψ_s,nom
    cfg = control.CurrentVectorControllerCfg(
        psi_s_nom=psi_s_nom, i_s_max=case['i_max'] / K,
        alpha_c=case['alpha_c'], alpha_o=case['alpha_o'], sensorless=False, T_s=case['T_s'])
    vector_ctrl = control.CurrentVectorController(par, cfg)
    speed_ctrl = control.SpeedController(J=motor.J, alpha_s=case['alpha_s'])
    ctrl = control.VectorControlSystem(vector_ctrl, speed_ctrl)
    return simulate_motulator(mdl, ctrl, load, case)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    add_common_args(ap, duration=0.8, load=10.0, load_step_time=0.4, leave=LEAVE)
    ap.add_argument('--current-limit', type=float, default=40.0,
                    help='current-vector limit [A], power-invariant (motulator: /sqrt(3/2))')
    add_alpha_o_arg(ap)
    args = ap.parse_args(argv)
    from im_common.params import THESIS_FLUX_LEVELS, THESIS_MOTOR
    motor = THESIS_MOTOR
    case = {**base_case(args), 'i_max': args.current_limit,
            'alpha_c': 2 * math.pi * 200, 'alpha_s': 100.0, 'alpha_o': args.alpha_o,
            'phi_r_ref': THESIS_FLUX_LEVELS['phi_d']}
    T_s, n = case['T_s'], case['n']
    ours, t_ours = run_ours(motor, case)
    theirs, t_mot = run_motulator(motor, case)
    table, last = compare(ours, theirs, args)
    print_comparison(table, last)
    print(f'wall time: ours {t_ours:.2f} s, motulator {t_mot:.2f} s')
    res = {'duration_s': args.duration, 'T_s': T_s, 'periods': n, 'speed_ref_rad_s': args.speed,
           'speed_step_time_s': args.speed_step_time, 'load_Nm': args.load,
           'load_step_time_s': args.load_step_time, 'current_limit_A': args.current_limit,
           'alpha_o': args.alpha_o, 'u_dc_V': args.u_dc, 'max_substep_s': args.max_substep,
           'left_in_place': args.leave,
           'segments': table, 'final_sample': last,
           'wall_s_ours': t_ours, 'wall_s_motulator': t_mot}
    write_json(args.json, res)
    return 0


if __name__ == '__main__':
    sys.exit(main())
