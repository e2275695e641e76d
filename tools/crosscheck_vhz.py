"""
Cross-check the ROS-free observer-based V/Hz controller against motulator 0.18.

The sibling of tools/crosscheck_baselines.py (the current-vector controller), with its structure,
plant setup and helpers. motulator needs Python >= 3.12 and the project runs on 3.11, so this runs
from a scratch environment outside the repository; the project's controller and plant (pure
Python, with pydantic) are imported from src/::

    python3.12 -m venv ../mot-env && ../mot-env/bin/pip install 'motulator==0.18.*' pydantic
    ../mot-env/bin/python tools/crosscheck_vhz.py [--duration 1.0] [--json out.json]

Both sides run the same open speed loop (V/Hz takes no measured speed): :class:`im_controller.
baselines.vhz.ObserverBasedVHz` on :class:`im_common.plant_sim.PlantSimulator`, and motulator's
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
import json
import math
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, '..', 'src', 'im_common'))
sys.path.insert(0, os.path.join(HERE, '..', 'src', 'im_controller'))

from crosscheck_baselines import K, rel_rms, speed_ref  # noqa: E402


#: the convention differences ``--leave`` can leave in place (module doc)
LEAVE = {'first-period': "the project's first command acts from t_0 (its CommandDelay's fill)",
         'flux-scaling': "motulator's psi_s_nom = the project's psi_s_nom as is (not /K)",
         'solver': "motulator's default solver tolerances (rtol 1e-3, atol 1e-6)"}


def run_ours(motor, case: dict):
    from im_common.loads import NoLoad
    from im_common.plant_sim import PlantSimulator
    from im_controller.baselines.vhz import ObserverBasedVHz, VHzGains
    T_s, n = case['T_s'], case['n']
    gains = VHzGains(slew_rate=case['slew_rate'])
    ctrl = ObserverBasedVHz(motor, T_s, gains, delay=1, psi_s_nom=case['psi_s_nom'],
                            v_limit=None, current_limit=case['i_max_ours'])
    sim = PlantSimulator(motor, NoLoad(), T_s=T_s, max_substep=case['max_substep'],
                         v_limit=None, current_trip=None, speed_trip=None,
                         inverter_rating=1e9, inverter={'delay': 1})
    if 'first-period' not in case['leave']:
        # the zero vector over [t_0, t_1], as motulator's delay line (module doc)
        sim.delay.push(0.0, 0.0)
        ctrl.line.push(0.0, 0.0)
    k_load = int(round(case['t_load'] / T_s))
    out = []
    t0 = time.perf_counter()
    for k in range(n):
        m = sim.measure()
        out.append((m.i_alpha, m.i_beta, m.omega_r))
        if k == k_load:
            sim.set_load_offset(case['tau_load'])
        v = ctrl.compute(m.t, m.i_alpha, m.i_beta, speed_ref(m.t, case))
        sim.step(*v)
        if sim.trip is not None:
            raise RuntimeError(f'the plant tripped: {sim.trip}')
    return out, time.perf_counter() - t0


def run_motulator(motor, case: dict):
    import motulator.drive.control.im as control
    import motulator.drive.model as model
    from motulator.common.model import Simulation, SolverCfg

    T_s, n = case['T_s'], case['n']
    par = model.InductionMachineInvGammaPars(n_p=motor.pole_pairs, R_s=motor.R_s, R_R=motor.R_R,
                                             L_sgm=motor.L_sigma, L_M=motor.L_M)
    machine = model.InductionMachine(par)
    mech = model.MechanicalSystem(J=motor.J, B_L=motor.b)
    load = {'tau': 0.0}
    mech.set_external_load_torque(lambda t: load['tau'])
    conv = model.VoltageSourceConverter(u_dc=case['u_dc'])
    mdl = model.Drive(machine, mech, conv, delay=1)      # ZOH, one period's delay (defaults)
    psi_s_nom = case['psi_s_nom']
    if 'flux-scaling' not in case['leave']:
        psi_s_nom /= K
    cfg = control.ObserverBasedVHzControllerCfg(psi_s_nom=psi_s_nom, i_s_max=case['i_max'] / K,
                                                T_s=T_s)
    vhz = control.ObserverBasedVHzController(par, cfg)
    bound = {'tau_cl': 0, 'tau_b': 0}
    gen = vhz.reference_gen
    inner_gen = gen.compute_output

    def counted(tau_M_ref, w_s, psi_R, u_dc):
        """Count the periods where τ_cl or the breakdown torque bound the torque reference."""
        psi_s_ref, tau = inner_gen(tau_M_ref, w_s, psi_R, u_dc)
        if abs(tau) < abs(tau_M_ref):
            k = gen.k_b * par.L_M / (par.L_M + par.L_sgm)      # motulator's expression
            tau_b = 0.75 * par.n_p * k * psi_s_ref ** 2 / par.L_sgm
            bound['tau_b' if abs(tau) == tau_b else 'tau_cl'] += 1
        return psi_s_ref, tau

    gen.compute_output = counted
    ctrl = control.VHzControlSystem(vhz, slew_rate=(math.inf if case['slew_rate'] is None
                                                    else case['slew_rate']))
    ctrl.set_speed_ref(lambda t: speed_ref(t, case))
    k_load = int(round(case['t_load'] / T_s))
    samples = []

    class Sampled:
        """motulator's control system, with the samples and the load step at each period start."""

        def __init__(self, inner):
            self.inner = inner

        def __getattr__(self, name):
            return getattr(self.inner, name)

        def __call__(self, m):
            if len(samples) == k_load:
                load['tau'] = case['tau_load']
            i_s = m.machine.out.i_s_ab
            samples.append((K * float(i_s.real), K * float(i_s.imag),
                            float(m.mechanics.out.w_M)))
            return self.inner(m)

    solver = SolverCfg() if 'solver' in case['leave'] else SolverCfg(rtol=1e-10, atol=1e-12)
    sim = Simulation(mdl, Sampled(ctrl), show_progress=False, cfg=solver)
    t0 = time.perf_counter()
    sim.simulate(t_stop=(n - 0.5) * T_s)     # its last controller call is at (n - 1) T_s
    if len(samples) != n:
        raise RuntimeError(f'motulator gave {len(samples)} samples, not {n}')
    return samples, time.perf_counter() - t0, bound


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    ap.add_argument('--duration', type=float, default=1.0, help='simulated time [s]')
    ap.add_argument('--T-s', dest='T_s', type=float, default=1e-4, help='control period [s]')
    ap.add_argument('--speed', type=float, default=0.5 * 2 * math.pi * 50 / 2,
                    help='speed reference after the step [mechanical rad/s] (default: half the '
                         'synchronous speed of 50 Hz)')
    ap.add_argument('--speed-step-time', type=float, default=0.1, help='[s]')
    ap.add_argument('--slew-rate', type=float, default=400.0,
                    help='rate limit of the speed reference [rad/s^2], on both (0: none)')
    ap.add_argument('--load', type=float, default=5.0, help='load torque after the step [N m]')
    ap.add_argument('--load-step-time', type=float, default=0.5, help='[s]')
    ap.add_argument('--current-limit', type=float, default=None,
                    help='current-vector limit [A], power-invariant, on both (motulator: '
                         '/sqrt(3/2)); default: none (motulator: 1e6 A)')
    ap.add_argument('--u-dc', type=float, default=1e4,
                    help="motulator's DC bus [V] (high: no PWM limit, no field weakening)")
    ap.add_argument('--max-substep', type=float, default=2.5e-5,
                    help="the project's plant RK4 sub-step [s]")
    ap.add_argument('--leave', action='append', default=[], choices=LEAVE,
                    help='leave this convention difference in place, to see its size '
                         '(repeatable): ' + '; '.join(f'{k}: {v}' for k, v in LEAVE.items()))
    ap.add_argument('--json', default=None, help='write the numbers here')
    args = ap.parse_args(argv)
    from im_common.params import THESIS_MOTOR
    from im_controller.baselines.vhz import nominal_stator_flux
    motor = THESIS_MOTOR
    T_s = args.T_s
    n = int(round(args.duration / T_s))
    case = {'n': n, 'T_s': T_s, 'w_ref': args.speed, 't_speed': args.speed_step_time,
            'slew_rate': args.slew_rate or None,
            'tau_load': args.load, 't_load': args.load_step_time,
            'i_max_ours': args.current_limit,
            'i_max': 1e6 if args.current_limit is None else args.current_limit,
            'psi_s_nom': nominal_stator_flux(motor), 'u_dc': args.u_dc,
            'max_substep': args.max_substep, 'leave': args.leave}
    ours, t_ours = run_ours(motor, case)
    theirs, t_mot, bound = run_motulator(motor, case)
    k_s = int(round(args.speed_step_time / T_s))
    k_l = int(round(args.load_step_time / T_s))
    segments = {'whole run': (0, n), 'magnetizing': (0, min(k_s, n)),
                'speed step': (k_s, min(k_l, n)), 'load step': (k_l, n)}
    table = {name: {'current_rel_rms': rel_rms(ours, theirs, (0, 1), lo, hi),
                    'speed_rel_rms': rel_rms(ours, theirs, (2,), lo, hi) if hi > k_s else None}
             for name, (lo, hi) in segments.items() if min(hi, n) > lo}
    last = {'ours': [round(x, 9) for x in ours[-1]],
            'motulator': [round(x, 9) for x in theirs[-1]]}
    i_peak = max(math.hypot(x[0], x[1]) for x in ours)
    print(f'{"segment":14s} {"i_s rel RMS":>12s} {"speed rel RMS":>14s}')
    for name, r in table.items():
        sp = '-' if r['speed_rel_rms'] is None else f'{r["speed_rel_rms"]:.3e}'
        print(f'{name:14s} {r["current_rel_rms"]:12.3e} {sp:>14s}')
    print(f'final sample (i_a, i_b, w_M): ours {last["ours"]}, motulator {last["motulator"]}')
    print(f'peak |i_s| (ours, power-invariant): {i_peak:.2f} A; periods where motulator’s '
          f'torque reference was bound: tau_cl {bound["tau_cl"]}, breakdown {bound["tau_b"]}')
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
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump(res, fh, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
