"""
Cross-check the ROS-free observer-based V/Hz controller against motulator 0.18.

The sibling of tools/crosscheck_baselines.py (the current-vector controller), with its structure;
the plant setup and helpers they share are in tools/motulator_common.py. motulator needs Python
>= 3.12 and the project runs on 3.11, so this runs from a scratch environment outside the
repository; the project's controller and plant (pure Python, with pydantic) are imported from
src/::

    python3.12 -m venv ../mot-env && ../mot-env/bin/pip install 'motulator==0.18.*' pydantic
    ../mot-env/bin/python tools/crosscheck_vhz.py [--duration 1.0] [--json out.json]

Both sides run the same open speed loop (V/Hz takes no measured speed): :class:`im_controller.
baselines.vhz.ObserverBasedVHz` on :class:`im_plant.plant_sim.PlantSimulator`, and motulator's
``ObserverBasedVHzController`` in a ``VHzControlSystem`` on its ``Drive``. The same motor (the
thesis motor, unsaturated, inverse-Γ L_σ, L_M, R_R), the same shaft (J, viscous b as motulator's
B_L), T_s = 100 µs, a computational delay of one period on both, the same gains (motulator's
defaults, which are the project's ``VHzGains`` defaults: α_ψ = 2π·100, α_τ = 2π·20, α_f = 2π·1
rad/s, α_i = 0, k_u = k_b = 0.9, k_comp = 1.5 = delay + ½), the sensorless observer gain k_o =
(α/2 + 0.2|ω_m|)/(α − jω_m) with no conjugate-error weight (h = 0) on both, the same nominal
stator flux and the same speed-reference rate limiter (``--slew-rate``, given to both: motulator's
default is none, and V/Hz cannot take a speed step from rest). Both start at rest and
unmagnetized (all states zero) and magnetize identically from t = 0 at ω_M* = 0; the speed
reference steps 0 → ``--speed`` at ``--speed-step-time`` (and is ramped by the limiter), the load
torque 0 → ``--load`` at ``--load-step-time``.

The convention differences, each removed in the inputs or the setup (none after the runs):

* Scaling: motulator's space vectors are peak-value scaled, the project's power-invariant
  (×√(3/2) = K). motulator's torque (estimate, breakdown limit, the flux-torque directions) has the
  factor 3/2 that power-invariant units do not; with the peak-scaled fluxes and currents its
  torques are the same N·m, so the torque channel's gain α_τ, the low-pass α_f and k_b carry over
  as they are. ψ_s,nom and the current limit are given to motulator /K, the samples of its
  currents are ×K.
* The nominal stator flux: the project's default is ``nominal_stator_flux(motor)`` (ψ_s,nom =
  θ φ_d (L_M + L_σ)/L_M, 1.2385 Wb power-invariant); motulator is given that ψ_s,nom/K.
* Field weakening: motulator's reference generator weakens the flux when ψ_s,nom|ω_s| nears
  k_u u_dc/√3; the project weakens it only with a v_limit, given none here. motulator's DC bus is
  set high (``--u-dc``, default 10 kV), so its ψ_s* stays at ψ_s,nom and the PWM (MME
  overmodulation by default) never limits; the project runs without a voltage limit.
* The current limit: motulator's reference generator always caps ψ_s* at L_σ i_s,max + |ψ̂_R| and
  the torque reference at τ_cl, the torque with the stator flux on the ψ_s* circle within
  L_σ i_s,max of ψ̂_R (0 while ψ̂_R = 0); the project caps ψ_s* the same way when given a current
  limit but has no τ_cl (a difference of design, below). By default neither is limited: the
  project gets none, motulator i_s,max = 1e6 A/K, where τ_cl is far above any torque reference
  (it is 0 at ψ̂_R = 0, the first period only, where τ̂_lpf = 0 too). ``--current-limit`` gives
  both the same limit. The run counts the periods where motulator's τ_cl or its breakdown limit
  bound its torque reference.
* The first period: motulator's delay line and its PWM's record of the realized voltage start at
  zero duties (the zero vector over [t_0, t_1]); the project's CommandDelay is filled by the first
  command. Both the plant's line and the controller's own line are primed with one zero command
  before the first step (as in tools/crosscheck_baselines.py).
* Events on the period grid: the speed reference switches at t_step − T_s/2 (read at the sampling
  instants only), the load torque is switched between periods on both (``PlantSimulator.
  set_load_offset`` before step k, motulator's load function's value set at sampling instant k).
* Integration: motulator's solver tolerances are tightened (rtol 1e-10, atol 1e-12); the project's
  plant takes RK4 sub-steps of ``--max-substep``.

What is the same already and needs nothing: the observer (hold-equivalent voltage and current
models, the correction k_o e + k_o (ψ̂_R/ψ̂_R*) e* with the speed reference as the rotor speed,
the slip estimate and ω_c = n_p ω_M* + ω̂_r), the flux-torque directions t_ψ, t_τ (motulator's
3/2 cancels in them), the feedforward R_s i + jω_c ψ̂_s, the low-pass τ̂_lpf updated after the
output, the breakdown torque (motulator's 0.75 = (3/2)(1/2) on peak fluxes is the project's 1/2),
the angle advance, and the rate limiter (motulator's on the same reference, same slew).

``--leave NAME`` (repeatable) leaves one difference in place, to see what it alone is worth.

Printed: the relative RMS difference rms(ours − motulator)/rms(motulator) of the stator current
(α and β together) and of the shaft speed, sampled at every period start, over the whole run and
over its segments (magnetizing, speed step, load step; no speed figure while both shafts are at
rest), the wall time of both simulations, and how often motulator's torque limits bound.

Measured (motulator 0.18.0, defaults: thesis motor, from rest, ω_M* 0 → 78.54 rad/s at 0.1 s
ramped at 400 rad/s², 5 N·m at 0.5 s, 1 s): current 2.7e-10, speed 3.2e-12 over the run
(magnetizing 2.2e-12, speed step 1.1e-10 / 1.7e-12, load step 4.7e-10 / 3.7e-12); neither
torque limit of motulator's bound. What is left is the project's plant's RK4 error (8.1e-8 /
7.2e-10 with one sub-step per period, 3.9e-11 / 5.5e-13 with 1e-5 s). Wall time (one run alone):
ours 0.5 s, motulator 3.4-4.5 s. Left in place one at a time (current / speed, whole run):
first-period 1.7e-2 / 8.3e-9 (the magnetizing segment 2.6e-2, after it ~1e-7: V/Hz forgets the
first period almost entirely), flux-scaling 2.7e-1 / 3.5e-3 (motulator's flux √(3/2) too high),
solver (motulator's default tolerances) no change (2.7e-10 / 3.2e-12). ``--current-limit 40``
(both limited, peak |i_s| 35.6 A instead of 135.7 A while magnetizing): 3.1e-10 / 3.2e-12, τ_cl
never binds (at ω_M* = 0 every vector stays on the α axis, τ̂ = τ̂_lpf = 0 exactly).

Not exercised here, so unverified (the differences of design a run with them active would show):
the project has no τ_cl torque cap; its field weakening is k_u v_limit/|ω_c| with a circular
voltage clip, motulator's k_u u_dc/√3 with MME overmodulation (the same ψ_s* when v_limit =
K u_dc/√3); without flux motulator's fallback directions are t_ψ = 1, t_τ = 0 whenever c_τ ≤ 0,
the project's t_ψ = ψ̂_s/|ψ̂_s| only when |c_τ| ≤ 1e-12; the slip estimate is taken when
Re(ψ̂_s ψ̂_R*) > 0 (motulator) or > 1e-10 Wb² (project); at ψ̂_R = 0 motulator's conjugate-error
projection is 0, the project's 1.
"""
from __future__ import annotations

import argparse
import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))   # tools/: motulator_common
from motulator_common import (  # noqa: E402
    add_common_args, base_case, compare, count_torque_bounds, K, motulator_drive,
    motulator_psi_s_nom, prime_first_period, print_comparison, print_peak_and_bounds,
    project_plant, run_closed_loop, simulate_motulator, speed_ref, write_json)


#: the convention differences ``--leave`` can leave in place (module doc)
LEAVE = {'first-period': "the project's first command acts from t_0 (its CommandDelay's fill)",
         'flux-scaling': "motulator's psi_s_nom = the project's psi_s_nom as is (not /K)",
         'solver': "motulator's default solver tolerances (rtol 1e-3, atol 1e-6)"}


def run_ours(motor, case: dict):
    from im_controller.baselines.vhz import ObserverBasedVHz, VHzGains
    gains = VHzGains(slew_rate=case['slew_rate'])
    ctrl = ObserverBasedVHz(motor, case['T_s'], gains, delay=1, psi_s_nom=case['psi_s_nom'],
                            v_limit=None, current_limit=case['i_max_ours'])
    sim = project_plant(motor, case)
    prime_first_period(sim, ctrl, case)
    return run_closed_loop(
        sim, case, lambda m: ctrl.compute(m.t, m.i_alpha, m.i_beta, speed_ref(m.t, case)))


def run_motulator(motor, case: dict):
    import motulator.drive.control.im as control

    par, mdl, load = motulator_drive(motor, case['u_dc'])
    psi_s_nom = motulator_psi_s_nom(case)
    cfg = control.ObserverBasedVHzControllerCfg(psi_s_nom=psi_s_nom, i_s_max=case['i_max'] / K,
                                                T_s=case['T_s'])
    vhz = control.ObserverBasedVHzController(par, cfg)
    bound = count_torque_bounds(vhz, par)
    ctrl = control.VHzControlSystem(vhz, slew_rate=(math.inf if case['slew_rate'] is None
                                                    else case['slew_rate']))
    samples, wall = simulate_motulator(mdl, ctrl, load, case)
    return samples, wall, bound


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    add_common_args(ap, duration=1.0, load=5.0, load_step_time=0.5, leave=LEAVE)
    ap.add_argument('--slew-rate', type=float, default=400.0,
                    help='rate limit of the speed reference [rad/s^2], on both (0: none)')
    ap.add_argument('--current-limit', type=float, default=None,
                    help='current-vector limit [A], power-invariant, on both (motulator: '
                         '/sqrt(3/2)); default: none (motulator: 1e6 A)')
    args = ap.parse_args(argv)
    from im_common.params import THESIS_MOTOR
    from im_controller.baselines.vhz import nominal_stator_flux
    motor = THESIS_MOTOR
    case = {**base_case(args), 'slew_rate': args.slew_rate or None,
            'i_max_ours': args.current_limit,
            'i_max': 1e6 if args.current_limit is None else args.current_limit,
            'psi_s_nom': nominal_stator_flux(motor)}
    T_s, n = case['T_s'], case['n']
    ours, t_ours = run_ours(motor, case)
    theirs, t_mot, bound = run_motulator(motor, case)
    table, last = compare(ours, theirs, args)
    print_comparison(table, last)
    i_peak = print_peak_and_bounds(ours, bound)
    print(f'wall time: ours {t_ours:.2f} s, motulator {t_mot:.2f} s')
    res = {'duration_s': args.duration, 'T_s': T_s, 'periods': n, 'speed_ref_rad_s': args.speed,
           'speed_step_time_s': args.speed_step_time, 'slew_rate_rad_s2': args.slew_rate,
           'load_Nm': args.load, 'load_step_time_s': args.load_step_time,
           'current_limit_A': args.current_limit, 'psi_s_nom_Wb': case['psi_s_nom'],
           'u_dc_V': args.u_dc, 'max_substep_s': args.max_substep,
           'left_in_place': args.leave,
           'segments': table, 'final_sample': last, 'peak_current_A': i_peak,
           'motulator_torque_ref_bound_periods': bound,
           'wall_s_ours': t_ours, 'wall_s_motulator': t_mot}
    write_json(args.json, res)
    return 0


if __name__ == '__main__':
    sys.exit(main())
