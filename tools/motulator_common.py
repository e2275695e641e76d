"""
The pieces the closed-loop cross-checks against motulator 0.18 share.

Imported by tools/crosscheck_baselines.py, tools/crosscheck_flux_vector.py and
tools/crosscheck_vhz.py (and, for :data:`K`, :func:`rel_rms` and :func:`write_json`, by
tools/crosscheck_motulator.py), which run from a scratch Python 3.12 environment with motulator
0.18 (their module docs say how) and put tools/ on sys.path to import it. Importing it puts the
project's src/im_common and src/im_controller on sys.path (they are imported from src/, not
installed there); motulator is imported inside the functions that use it. The conventions
(peak-value against power-invariant scaling, the priming of the first period, events on the
period grid, the solver tolerances) are explained in tools/crosscheck_baselines.py's module doc.

Held here:

* :data:`K`, the scaling between the project's and motulator's space vectors;
* the speed reference step and motulator's sensored speed observer (:func:`speed_ref`,
  :func:`speed_filter_gain`, :class:`SpeedObserver`);
* the project's side: :func:`project_plant`, :func:`prime_first_period` and
  :func:`run_closed_loop` (the period loop with the load step, a law given as a function);
* motulator's side: :func:`motulator_drive` (the machine, the shaft with an external load torque,
  the converter and the drive with one period's delay), :func:`motulator_psi_s_nom`,
  :func:`count_torque_bounds`, :class:`Sampled` and :func:`simulate_motulator`;
* the command line options every tool has and the settings they give (:func:`add_common_args`,
  :func:`add_alpha_o_arg`, :func:`base_case`);
* the comparison: :func:`rel_rms`, :func:`compare`, :func:`print_comparison`,
  :func:`print_peak_and_bounds`, :func:`write_json`.
"""
from __future__ import annotations

import json
import math
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
# the project's pure-Python sources, imported from src/ (not installed in the scratch environment)
sys.path.insert(0, os.path.join(HERE, '..', 'src', 'im_common'))
sys.path.insert(0, os.path.join(HERE, '..', 'src', 'im_controller'))

K = math.sqrt(1.5)          # power-invariant vector = sqrt(3/2) x peak-value vector


def base_case(args) -> dict:
    """Return the run's settings every closed-loop cross-check has, from its parsed options."""
    n = int(round(args.duration / args.T_s))
    return {'n': n, 'T_s': args.T_s, 'w_ref': args.speed, 't_speed': args.speed_step_time,
            'tau_load': args.load, 't_load': args.load_step_time, 'u_dc': args.u_dc,
            'max_substep': args.max_substep, 'leave': args.leave}


def speed_filter_gain(alpha_o: float, T_s: float) -> float:
    """Return motulator's sensored speed-observer gain k_w = (1 − e^{−α_o T_s})/T_s [1/s]."""
    return -math.expm1(-alpha_o * T_s) / T_s


def speed_ref(t: float, case: dict) -> float:
    """Return the speed reference at the sampling instant t (mechanical rad/s)."""
    return case['w_ref'] if t >= case['t_speed'] - 0.5 * case['T_s'] else 0.0


class SpeedObserver:
    """
    motulator's sensored speed observer, ŵ ← ŵ + T_s k_w (ω_meas − ŵ), started at ŵ = 0.

    Read :attr:`w_hat` before :meth:`update` (motulator reads it before the update).
    """

    def __init__(self, alpha_o: float, T_s: float):
        self.T_s = T_s
        self.k_w = speed_filter_gain(alpha_o, T_s)
        self.w_hat = 0.0

    def update(self, w_meas: float) -> None:
        """Take the measured speed of this period [mechanical rad/s]."""
        self.w_hat += self.T_s * (self.k_w * (w_meas - self.w_hat))


def project_plant(motor, case: dict):
    """Return the project's PlantSimulator, no load, one period's delay, no limits or trips."""
    from im_common.loads import NoLoad
    from im_plant.plant_sim import PlantSimulator
    return PlantSimulator(motor, NoLoad(), T_s=case['T_s'], max_substep=case['max_substep'],
                          v_limit=None, current_trip=None, speed_trip=None,
                          inverter_rating=1e9, inverter={'delay': 1})


def prime_first_period(sim, ctrl, case: dict) -> None:
    """Prime the plant's and the controller's delay lines with one zero command."""
    if 'first-period' not in case['leave']:
        # the zero vector over [t_0, t_1], as motulator's delay line (module doc)
        sim.delay.push(0.0, 0.0)
        ctrl.out.line.push(0.0, 0.0)


def run_closed_loop(sim, case: dict, law):
    """
    Run the project's plant for case['n'] periods under ``law``; return the samples, wall time.

    ``law(m)`` takes the measurement of the period start and returns the voltage command. The
    samples (i_α, i_β, ω_M) are taken at every period start; the load torque steps to
    case['tau_load'] between periods, before period round(case['t_load']/T_s).
    """
    k_load = int(round(case['t_load'] / case['T_s']))
    out = []
    t0 = time.perf_counter()
    for k in range(case['n']):
        m = sim.measure()
        out.append((m.i_alpha, m.i_beta, m.omega_r))
        if k == k_load:
            sim.set_load_offset(case['tau_load'])
        sim.step(*law(m))
        if sim.trip is not None:
            raise RuntimeError(f'the plant tripped: {sim.trip}')
    return out, time.perf_counter() - t0


def motulator_drive(motor, u_dc: float):
    """
    Return motulator's drive model of the motor: (its parameters, the Drive, the load).

    The unsaturated inverse-Γ machine, the shaft (J, viscous b as B_L) with an external load
    torque read from the returned dict's 'tau' (0 at first), the converter at ``u_dc`` and the
    Drive with zero-order hold and one period's delay.
    """
    import motulator.drive.model as model
    par = model.InductionMachineInvGammaPars(n_p=motor.pole_pairs, R_s=motor.R_s, R_R=motor.R_R,
                                             L_sgm=motor.L_sigma, L_M=motor.L_M)
    machine = model.InductionMachine(par)
    mech = model.MechanicalSystem(J=motor.J, B_L=motor.b)
    load = {'tau': 0.0}
    mech.set_external_load_torque(lambda t: load['tau'])
    conv = model.VoltageSourceConverter(u_dc=u_dc)
    mdl = model.Drive(machine, mech, conv, delay=1)      # ZOH, one period's delay (defaults)
    return par, mdl, load


def motulator_psi_s_nom(case: dict) -> float:
    """Return motulator's nominal stator flux: the project's /K (unless 'flux-scaling' is left)."""
    psi_s_nom = case['psi_s_nom']
    if 'flux-scaling' not in case['leave']:
        psi_s_nom /= K
    return psi_s_nom


def count_torque_bounds(controller, par) -> dict:
    """
    Count the periods where τ_cl or the breakdown torque bound motulator's torque reference.

    Wraps the ``compute_output`` of the controller's reference generator; returns the counts
    {'tau_cl': ..., 'tau_b': ...}, updated as the simulation runs.
    """
    bound = {'tau_cl': 0, 'tau_b': 0}
    gen = controller.reference_gen
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
    return bound


class Sampled:
    """motulator's control system, with the samples and the load step at each period start."""

    def __init__(self, inner, load: dict, k_load: int, tau_load: float):
        self.inner = inner
        self.sampled_load = load
        self.sampled_k_load = k_load
        self.sampled_tau_load = tau_load
        self.samples = []

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def __call__(self, m):
        if len(self.samples) == self.sampled_k_load:
            self.sampled_load['tau'] = self.sampled_tau_load
        i_s = m.machine.out.i_s_ab
        self.samples.append((K * float(i_s.real), K * float(i_s.imag),
                             float(m.mechanics.out.w_M)))
        return self.inner(m)


def simulate_motulator(mdl, ctrl, load: dict, case: dict, speed_ref=speed_ref):
    """
    Simulate motulator's drive under its control system; return the samples and the wall time.

    The control system's speed reference is ``speed_ref(t, case)``. The samples as in
    :func:`run_closed_loop` (the currents ×K to power-invariant), the load torque stepped at the
    same period; the solver at rtol 1e-10, atol 1e-12 unless 'solver' is in case['leave']
    (motulator's defaults).
    """
    from motulator.common.model import Simulation, SolverCfg
    T_s, n = case['T_s'], case['n']
    ctrl.set_speed_ref(lambda t: speed_ref(t, case))
    sampled = Sampled(ctrl, load, int(round(case['t_load'] / T_s)), case['tau_load'])
    solver = SolverCfg() if 'solver' in case['leave'] else SolverCfg(rtol=1e-10, atol=1e-12)
    sim = Simulation(mdl, sampled, show_progress=False, cfg=solver)
    t0 = time.perf_counter()
    sim.simulate(t_stop=(n - 0.5) * T_s)     # its last controller call is at (n - 1) T_s
    if len(sampled.samples) != n:
        raise RuntimeError(f'motulator gave {len(sampled.samples)} samples, not {n}')
    return sampled.samples, time.perf_counter() - t0


def add_common_args(ap, *, duration: float, load: float, load_step_time: float,
                    leave: dict) -> None:
    """
    Add the options every closed-loop cross-check has, with the tool's defaults.

    --duration, --T-s, --speed, --speed-step-time, --load, --load-step-time, --u-dc,
    --max-substep, --leave (choices: the keys of ``leave``) and --json.
    """
    ap.add_argument('--duration', type=float, default=duration, help='simulated time [s]')
    ap.add_argument('--T-s', dest='T_s', type=float, default=1e-4, help='control period [s]')
    ap.add_argument('--speed', type=float, default=0.5 * 2 * math.pi * 50 / 2,
                    help='speed reference after the step [mechanical rad/s] (default: half the '
                         'synchronous speed of 50 Hz)')
    ap.add_argument('--speed-step-time', type=float, default=0.1, help='[s]')
    ap.add_argument('--load', type=float, default=load, help='load torque after the step [N m]')
    ap.add_argument('--load-step-time', type=float, default=load_step_time, help='[s]')
    ap.add_argument('--u-dc', type=float, default=1e4,
                    help="motulator's DC bus [V] (high: no PWM limit, no field weakening)")
    ap.add_argument('--max-substep', type=float, default=2.5e-5,
                    help="the project's plant RK4 sub-step [s]")
    ap.add_argument('--leave', action='append', default=[], choices=leave,
                    help='leave this convention difference in place, to see its size '
                         '(repeatable): ' + '; '.join(f'{k}: {v}' for k, v in leave.items()))
    ap.add_argument('--json', default=None, help='write the numbers here')


def add_alpha_o_arg(ap) -> None:
    """Add --alpha-o, motulator's sensored speed-observer pole, applied on both sides."""
    ap.add_argument('--alpha-o', type=float, default=2 * math.pi * 400,
                    help="motulator's sensored speed-observer pole [rad/s] (its default; inf: "
                         'a pure one-period delay), applied on both sides')


def rel_rms(a, b, cols, lo=0, hi=None):
    """Return rms(a − b)/rms(b) over the columns ``cols`` of the samples lo:hi."""
    a, b = a[lo:hi], b[lo:hi]
    num = sum((x[c] - y[c]) ** 2 for x, y in zip(a, b) for c in cols)
    den = sum(y[c] ** 2 for y in b for c in cols)
    return math.sqrt(num / den)


def compare(ours, theirs, args):
    """
    Return the relative RMS differences by segment and the final samples of both sides.

    The segments: the whole run, magnetizing (before the speed step), the speed step (before the
    load step) and the load step; no speed figure while both shafts are at rest.
    """
    n, T_s = len(ours), args.T_s
    k_s = int(round(args.speed_step_time / T_s))
    k_l = int(round(args.load_step_time / T_s))
    segments = {'whole run': (0, n), 'magnetizing': (0, min(k_s, n)),
                'speed step': (k_s, min(k_l, n)), 'load step': (k_l, n)}
    table = {name: {'current_rel_rms': rel_rms(ours, theirs, (0, 1), lo, hi),
                    'speed_rel_rms': rel_rms(ours, theirs, (2,), lo, hi) if hi > k_s else None}
             for name, (lo, hi) in segments.items() if min(hi, n) > lo}
    last = {'ours': [round(x, 9) for x in ours[-1]],
            'motulator': [round(x, 9) for x in theirs[-1]]}
    return table, last


def print_comparison(table: dict, last: dict) -> None:
    """Print the table of relative RMS differences and the final samples."""
    print(f'{"segment":14s} {"i_s rel RMS":>12s} {"speed rel RMS":>14s}')
    for name, r in table.items():
        sp = '-' if r['speed_rel_rms'] is None else f'{r["speed_rel_rms"]:.3e}'
        print(f'{name:14s} {r["current_rel_rms"]:12.3e} {sp:>14s}')
    print(f'final sample (i_a, i_b, w_M): ours {last["ours"]}, motulator {last["motulator"]}')


def print_peak_and_bounds(ours, bound: dict) -> float:
    """Print and return the peak |i_s| of ours, and print motulator's torque-bound counts."""
    i_peak = max(math.hypot(x[0], x[1]) for x in ours)
    print(f'peak |i_s| (ours, power-invariant): {i_peak:.2f} A; periods where motulator’s '
          f'torque reference was bound: tau_cl {bound["tau_cl"]}, breakdown {bound["tau_b"]}')
    return i_peak


def write_json(path, res: dict) -> None:
    """Write the results to ``path`` (nothing if it is None)."""
    if path:
        with open(path, 'w') as fh:
            json.dump(res, fh, indent=1)
