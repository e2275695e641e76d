"""
``python -m im_studies.loss_bound RUN_FILE [--step S] [--run STRATEGY ...] [--json FILE]``.

The loss floor of any run: the convex lower bound (docs/controller.md §10) on the motor's losses
over every flux trajectory that delivers the run's torque exactly — the torque the run's
reference asks of the plant's motor and load, τ = J a* + b ω* + τ_L(t, θ*, ω*) — from the
plant's start flux over the run's duration. Copper only, and copper + core with the plant
motor's k_e, k_h. ``--run`` simulates the run file (ROS-free loop, :mod:`im_bringup.offline`)
with each strategy named and prints its losses over the bound from its own start flux (a
steady start is each strategy's own steady state).

On the real plant (docs/plant.md) the bound stays a lower bound, not a tight one: saturation
only adds magnetizing current for a flux (i_M(ψ) ≥ ψ/L_M0), and the acting iron loss dissipates
what the bound books. The torque task has no reference path (its speed is not known ahead): no
bound.
"""
from __future__ import annotations

import argparse
from dataclasses import replace
import json
import math
import sys

from im_bringup.offline import Scenario, simulate
from im_common.cli import error as cli_error
from im_common.params import InvalidParameter
from im_common.saturation import saturation_from_dict
from im_controller.control_law import DriveController
from im_controller.flux_plan import grid, plan_flux, PLAN_STEP, saturation_terms
from im_controller.reference import ModelCoefficients
import numpy as np


def start_flux(sc) -> float:
    """Return |φ_r(0)| [Wb] of the run's plant: 0 from rest, else its steady start."""
    x0, _ = sc.initial_state()
    return 0.0 if x0 is None else math.hypot(float(x0[2]), float(x0[3]))


def run_loss_bound(sc, step: float = None, core: bool = True, phi0: float = None,
                   i_max: float = None, phi_cap: float = None):
    """
    Return the loss floor of a :class:`~im_bringup.offline.Scenario` (a FluxPlan).

    ``phi0``: the start flux (default: the plant's, :func:`start_flux`); ``core``: with the
    plant motor's core loss (else copper only); ``i_max``, ``phi_cap``: a current limit [A] and
    a flux cap [Wb] (none: the floor over every trajectory; with them, ``torque_shortfall`` says
    what they cannot deliver).
    ValueError for the torque task.
    """
    step = PLAN_STEP if step is None else step
    m = sc.plant_schedule().params_at(0.0)
    load = sc.plant_load()
    nodes = grid(0.0, sc.duration, step)
    times = np.empty(2 * len(nodes) - 1)
    times[::2] = nodes
    times[1::2] = 0.5 * (nodes[:-1] + nodes[1:])
    theta, omega, acc = DriveController(sc.controller_config()).reference_preview(
        times, sc.theta0, sc.omega0)
    mid = slice(1, None, 2)
    tau = np.array([m.J * a + m.b * w + load.torque(t, th, w) for t, th, w, a in
                    zip(times[mid], theta[mid], omega[mid], acc[mid])])
    k = {'k_e': m.k_e, 'k_h': m.k_h} if core else {}
    c = ModelCoefficients.from_params(m)
    if sc.saturation is not None:       # the plant's magnetizing curve
        k['sat'] = saturation_terms(c, saturation_from_dict(sc.saturation, m.L_M))
    return plan_flux(c, nodes, tau, omega[mid], start_flux(sc) if phi0 is None else phi0,
                     i_max=i_max, phi_cap=phi_cap, **k)


def drive_floor(sc, step: float = None):
    """
    Return the floor within the run's own drive limits (its current limit and flux cap φ_max).

    The floor of this drive rather than of the motor: a drive that may not raise the flux above
    φ_max cannot reach the unconstrained floor. None when the drive has neither limit.
    """
    cfg = sc.controller_config()
    cap = cfg.phi_max if math.isfinite(cfg.phi_max) else None
    if cfg.current_limit is None and cap is None:
        return None
    return run_loss_bound(sc, step, i_max=cfg.current_limit, phi_cap=cap)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='loss_bound', description=__doc__.split('\n\n')[1])
    ap.add_argument('run_file', help='a run file (docs/running.md)')
    ap.add_argument('--step', type=float, default=None,
                    help='the grid of the convex program [s] (default 1e-3)')
    ap.add_argument('--run', metavar='STRATEGY', action='append', default=[],
                    help='simulate the run file with this flux strategy and compare (repeatable)')
    ap.add_argument('--json', metavar='FILE', help='write the figures as JSON')
    a = ap.parse_args(argv)
    try:
        sc = Scenario.from_file(a.run_file)
        cu = run_loss_bound(sc, a.step, core=False)
        tot = run_loss_bound(sc, a.step)
    except (InvalidParameter, ValueError, OSError) as exc:
        return cli_error('loss_bound', f'{a.run_file}: {exc}')
    out = {'run_file': a.run_file, 'duration_s': sc.duration, 'start_flux_Wb':
           start_flux(sc), 'E_copper_bound_J': cu.copper_J, 'E_loss_bound_J': tot.loss_J,
           'runs': {}}
    print(f'loss floor of {a.run_file} ({sc.task} task, {out["duration_s"]:g} s from '
          f'{out["start_flux_Wb"]:.4g} Wb): {tot.loss_J:.4f} J with the core loss, '
          f'{cu.copper_J:.4f} J copper only')
    cfg = sc.controller_config()
    lim = drive_floor(sc, a.step)
    if lim is not None:
        out['E_loss_drive_floor_J'] = lim.loss_J
        out['torque_shortfall_Nms'] = lim.torque_shortfall
        print(f"  within the drive's limits (current {cfg.current_limit} A, flux cap "
              f'{cfg.phi_max:.4g} Wb): {lim.loss_J:.4f} J')
        if lim.torque_shortfall > 1e-9:
            print(f"  those limits cannot deliver this run's torque exactly "
                  f'({lim.torque_shortfall:.3g} N·m·s short): its runs track less closely')
    floors = {round(out['start_flux_Wb'], 12): tot}
    for st in a.run:
        print(f'  simulating {st} ...', file=sys.stderr, flush=True)
        run = replace(sc, strategy=st)
        phi0 = round(start_flux(run), 12)       # a steady start is the strategy's own flux
        if phi0 not in floors:
            floors[phi0] = run_loss_bound(run, a.step)
        floor = floors[phi0].loss_J
        try:
            s = simulate(run).summary
            dfl = None if lim is None else drive_floor(run, a.step).loss_J
        except (InvalidParameter, ValueError, ArithmeticError) as exc:
            return cli_error('loss_bound', f'{a.run_file} with {st}: {exc or type(exc).__name__}')
        out['runs'][st] = {'E_loss_J': s['E_loss_J'], 'E_copper_J': s['E_copper_J'],
                           'start_flux_Wb': phi0, 'E_loss_bound_J': floor,
                           'ratio_loss': s['E_loss_J'] / floor, 'trip': s['trip']}
        text = (f'  {st}: {s["E_loss_J"]:.4f} J = {s["E_loss_J"] / floor:.4f} x the floor from '
                f'its start flux {phi0:.4g} Wb ({floor:.4f} J)')
        if dfl is not None:
            out['runs'][st].update(E_loss_drive_floor_J=dfl, ratio_drive_floor=s['E_loss_J'] / dfl)
            text += f', {s["E_loss_J"] / dfl:.4f} x the floor within its limits'
        print(text + ('' if s['trip'] is None else f' (tripped: {s["trip"]["reason"]})'))
    if a.json:
        try:
            with open(a.json, 'w') as f:
                json.dump(out, f, indent=2)
        except OSError as exc:
            return cli_error('loss_bound', f'{a.json}: {exc.strerror or exc}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
