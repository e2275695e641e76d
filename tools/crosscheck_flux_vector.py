"""
Cross-check the ROS-free flux-vector controller against motulator 0.18's FluxVectorController.

The sibling of tools/crosscheck_baselines.py (the current-vector controller) and
tools/crosscheck_vhz.py (V/Hz), with their structure; the plant setup and helpers all three
share are in tools/motulator_common.py. motulator needs Python >= 3.12 and the project runs on
3.11, so this runs from a scratch environment outside the repository; the project's controller
and plant (pure Python, with pydantic) are imported from src/::

    python3.12 -m venv ../mot-env && ../mot-env/bin/pip install 'motulator==0.18.*' pydantic
    ../mot-env/bin/python tools/crosscheck_flux_vector.py [--duration 0.8] [--json out.json]

Both sides run the same closed speed loop: :class:`im_controller.baselines.flux_vector.
FluxVectorController` on :class:`im_plant.plant_sim.PlantSimulator`, and motulator's sensored
``FluxVectorController`` with its ``SpeedController`` in a ``VectorControlSystem`` on its
``Drive``. The same motor (the thesis motor, unsaturated, inverse-Γ L_σ, L_M, R_R), the same shaft
(J, viscous b as motulator's B_L), T_s = 100 µs, a computational delay of one period on both, the
same gains (motulator's defaults, which are the project's ``FluxVectorGains`` defaults: α_τ = α_ψ
= α_i = 2π·100 rad/s, k_u = k_b = 0.9, k_comp = 1.5 = delay + ½; speed α_s = 100 rad/s), the
sensored observer gain k_o = 1 + 0.2|ω_m|/(α − jω_m) (h = 1), the same nominal stator flux and
current limit. Both start at rest and unmagnetized (all states zero) and magnetize identically
from t = 0 at ω_M* = 0; the speed reference steps 0 → ``--speed`` at ``--speed-step-time``
(a step: the torque reference then rides on motulator's limits, the breakdown torque k_b τ_b and
τ_cl of the current limit, which the run counts), the load torque 0 → ``--load`` at
``--load-step-time``.

The convention differences, each removed in the inputs or the setup (none after the runs):

* Scaling: motulator's space vectors are peak-value scaled, the project's power-invariant
  (×√(3/2) = K). motulator's torques carry the factor 3/2 (estimate, breakdown torque, τ_cl, the
  flux-torque directions, the integral state x_τ's gain); with peak-scaled fluxes and currents
  its torques are the same N·m, so α_τ, α_i, k_b and the speed gains carry over as they are.
  ψ_s,nom and the current limit are given to motulator /K, the samples of its currents are ×K.
* Field weakening: motulator's reference generator weakens the flux when ψ_s,nom|ω_s| nears
  k_u u_dc/√3; the project weakens it only with a v_limit, given none by default. motulator's DC
  bus is set high (``--u-dc``, default 10 kV), so its ψ_s* stays at ψ_s,nom (or the current-limit
  cap) and the PWM never limits. ``--voltage-limit`` gives the project v_limit = K u_dc/√3 (the
  linear range of motulator's PWM), so that with a low ``--u-dc`` both weaken the field alike
  (ψ_s* = k_u v_limit/|ω_c|); where the voltage itself saturates they differ by design: the
  project clips to the circle, motulator's PWM overmodulates (MPE by default) into the hexagon.
* The first period: motulator's delay line and its PWM's record of the realized voltage start at
  zero duties; the project's CommandDelay is filled by the first command. Both the plant's line
  and the controller's own line are primed with one zero command (as the siblings do).
* The speed feedback: motulator's sensored mode feeds its speed observer's output ŵ (ŵ ← ŵ +
  T_s k_w (ω_meas − ŵ), k_w = (1 − e^{−α_o T_s})/T_s, α_o = 2π·400 rad/s, read before the update)
  to the flux observer and the speed PI; the project's controller is given the same ŵ
  (:class:`motulator_common.SpeedObserver`).
* No speed-controller feedforward in motulator: the project's SpeedPI gets τ_ff = 0.
* The speed reference: a step by default; ``--slew-rate`` ramps it (the same function of the
  sampling instant on both sides: motulator's reference function, not its rate limiter).
* Events on the period grid and integration: as the siblings (speed reference switched at
  t_step − T_s/2, the load between periods; motulator's solver at rtol 1e-10, atol 1e-12, the
  project's RK4 sub-steps of ``--max-substep``).

What is the same already and needs nothing: the observer, the flux-torque controller a.6 with its
integral states and their anti-windup on the realized voltage ½(V_{k−1} + V_k), the reference
generator's ψ_s* = min(ψ_s,nom, L_σ i_max + |ψ̂_R|) and its torque limits (k_b τ_b, τ_cl; no τ_max
here), the limited torque fed back to the speed PI, the angle advance.

``--leave NAME`` (repeatable) leaves one difference in place, to see what it alone is worth.

Printed: the relative RMS difference rms(ours − motulator)/rms(motulator) of the stator current
(α and β together) and of the shaft speed, sampled at every period start, over the whole run and
its segments (magnetizing, speed step, load step; no speed figure while both shafts are at rest),
how many periods motulator's torque reference was bound by τ_b or τ_cl, and the wall times.

Measured (motulator 0.18.0, defaults: thesis motor, from rest, 40 A, ω_M* 0 → 78.54 rad/s at
0.1 s, 10 N·m at 0.4 s, 0.8 s): current 1.5e-10, speed 8.3e-13 over the run (magnetizing 3.7e-13,
speed step 9.4e-11 / 1.3e-12, load step 2.4e-10 / 4.3e-14); motulator's τ_cl bound its torque
reference for 203 periods (the speed step rides on the current limit, peak |i_s| 39.9 A), the
breakdown torque never. ``--current-limit 1e5`` (the breakdown torque binds instead, 52 periods,
peak 134.9 A): 1.3e-10 / 6.1e-13. What is left is the project's plant's RK4 error (5.9e-8 /
2.4e-10 with one sub-step per period). Wall time: ours 0.5 s, motulator 3.1 s. Left in place one
at a time (current / speed, whole run): first-period 4.1e-3 / 2.0e-7, speed-feedback 1.1e-2 /
6.1e-4, flux-scaling 2.6e-1 / 1.3e-2, solver (motulator's default tolerances) no change
(1.5e-10 / 8.3e-13).

Field weakening, ``--voltage-limit --u-dc 400 --speed 150 --slew-rate 500 --load 5
--duration 1.0 --load-step-time 0.6`` (v_limit 282.8 V; the field weakened in 6892 of 10000
periods, the voltage never clipped): 2.0e-9 / 7.2e-13 (speed ramp 9.1e-10 / 1.1e-12, load step
3.9e-9 / 9.5e-14). The same as a step (no ``--slew-rate``): the voltage saturates for 323
periods, where the project's circular clip and motulator's MPE overmodulation differ: 1.9e-1 /
7.6e-3 — a transient difference that leaves an angle offset of the αβ currents (load step: speed
9.5e-14, currents 2.0e-1, the same |i_s|), not a defect of either.

Not exercised here, so unverified: τ_max, motulator's sensorless mode (the project's law is
sensored only), the fallback directions near c_τ = 0 (the module doc of flux_vector.py lists the
differences).
"""
from __future__ import annotations

import argparse
import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))   # tools/: motulator_common
from motulator_common import (  # noqa: E402
    add_alpha_o_arg, add_common_args, base_case, compare, count_torque_bounds, K, motulator_drive,
    motulator_psi_s_nom, prime_first_period, print_comparison, print_peak_and_bounds,
    project_plant, run_closed_loop, simulate_motulator, speed_ref as step_speed_ref,
    SpeedObserver, write_json)


#: the convention differences ``--leave`` can leave in place (module doc)
LEAVE = {'first-period': "the project's first command acts from t_0 (its CommandDelay's fill)",
         'speed-feedback': 'the project gets the measured speed, motulator its speed observer',
         'flux-scaling': "motulator's psi_s_nom = the project's psi_s_nom as is (not /K)",
         'solver': "motulator's default solver tolerances (rtol 1e-3, atol 1e-6)"}


def speed_ref(t: float, case: dict) -> float:
    """Return the speed reference at the sampling instant t: a step, or a ramp at the slew rate."""
    if case['slew_rate'] is None:
        return step_speed_ref(t, case)
    t0 = case['t_speed'] - 0.5 * case['T_s']
    return min(max(t - t0, 0.0) * case['slew_rate'], case['w_ref'])


def run_ours(motor, case: dict):
    from im_controller.baselines.flux_vector import FluxVectorController, FluxVectorGains
    T_s = case['T_s']
    gains = FluxVectorGains(alpha_s=case['alpha_s'])
    ctrl = FluxVectorController(motor, T_s, gains, delay=1, psi_s_nom=case['psi_s_nom'],
                                current_limit=case['i_max'], v_limit=case['v_limit'], tau_max=None)
    sim = project_plant(motor, case)
    prime_first_period(sim, ctrl, case)
    measured = 'speed-feedback' in case['leave']
    obs = SpeedObserver(case['alpha_o'], T_s)
    bound = {'field_weakening': 0, 'v_limit': 0}

    def law(m):
        v = ctrl.compute(m.t, m.i_alpha, m.i_beta, m.theta_r,
                         m.omega_r if measured else obs.w_hat, speed_ref(m.t, case), 0.0)
        if ctrl.v_limit is not None:
            w_c = abs(ctrl.observer.omega_c)
            bound['field_weakening'] += (w_c > 0.0 and ctrl.gains.k_u * ctrl.v_limit / w_c
                                         <= ctrl.psi_ref)
            bound['v_limit'] += math.hypot(*v) >= ctrl.v_limit * (1.0 - 1e-12)
        obs.update(m.omega_r)
        return v

    out, wall = run_closed_loop(sim, case, law)
    return out, wall, bound


def run_motulator(motor, case: dict):
    import motulator.drive.control.im as control

    par, mdl, load = motulator_drive(motor, case['u_dc'])
    psi_s_nom = motulator_psi_s_nom(case)
    cfg = control.FluxVectorControllerCfg(psi_s_nom=psi_s_nom, i_s_max=case['i_max'] / K,
                                          alpha_o=case['alpha_o'], sensorless=False,
                                          T_s=case['T_s'])
    fvc = control.FluxVectorController(par, cfg)
    bound = count_torque_bounds(fvc, par)
    speed_ctrl = control.SpeedController(J=motor.J, alpha_s=case['alpha_s'])
    ctrl = control.VectorControlSystem(fvc, speed_ctrl)
    samples, wall = simulate_motulator(mdl, ctrl, load, case, speed_ref)
    return samples, wall, bound


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    add_common_args(ap, duration=0.8, load=10.0, load_step_time=0.4, leave=LEAVE)
    ap.add_argument('--slew-rate', type=float, default=0.0,
                    help='ramp the speed reference at this rate [rad/s^2], on both (0: a step)')
    ap.add_argument('--current-limit', type=float, default=40.0,
                    help='current-vector limit [A], power-invariant, on both (motulator: '
                         '/sqrt(3/2))')
    add_alpha_o_arg(ap)
    ap.add_argument('--voltage-limit', action='store_true',
                    help="give the project v_limit = sqrt(3/2) u_dc/sqrt(3), motulator's linear "
                         'modulation range: both weaken the field alike (with --u-dc low enough)')
    args = ap.parse_args(argv)
    from im_common.params import THESIS_MOTOR
    from im_controller.baselines.vhz import nominal_stator_flux
    motor = THESIS_MOTOR
    case = {**base_case(args), 'i_max': args.current_limit,
            'alpha_s': 100.0, 'alpha_o': args.alpha_o, 'psi_s_nom': nominal_stator_flux(motor),
            'slew_rate': args.slew_rate or None,
            'v_limit': K * args.u_dc / math.sqrt(3.0) if args.voltage_limit else None}
    T_s, n = case['T_s'], case['n']
    ours, t_ours, ours_bound = run_ours(motor, case)
    theirs, t_mot, bound = run_motulator(motor, case)
    table, last = compare(ours, theirs, args)
    print_comparison(table, last)
    i_peak = print_peak_and_bounds(ours, bound)
    if case['v_limit'] is not None:
        print(f'periods where ours weakened the field: {ours_bound["field_weakening"]}, clipped '
              f'the voltage to v_limit = {case["v_limit"]:.1f} V: {ours_bound["v_limit"]}')
    print(f'wall time: ours {t_ours:.2f} s, motulator {t_mot:.2f} s')
    res = {'duration_s': args.duration, 'T_s': T_s, 'periods': n, 'speed_ref_rad_s': args.speed,
           'speed_step_time_s': args.speed_step_time, 'load_Nm': args.load,
           'load_step_time_s': args.load_step_time, 'current_limit_A': args.current_limit,
           'psi_s_nom_Wb': case['psi_s_nom'], 'alpha_o': args.alpha_o, 'u_dc_V': args.u_dc,
           'max_substep_s': args.max_substep, 'left_in_place': args.leave,
           'segments': table, 'final_sample': last, 'peak_current_A': i_peak,
           'motulator_torque_ref_bound_periods': bound, 'slew_rate_rad_s2': args.slew_rate,
           'v_limit_V': case['v_limit'], 'ours_bound_periods': ours_bound,
           'wall_s_ours': t_ours, 'wall_s_motulator': t_mot}
    write_json(args.json, res)
    return 0


if __name__ == '__main__':
    sys.exit(main())
