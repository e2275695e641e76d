"""
Efficiency maps of the whole drive and its losses at the IEC 61800-9-2 operating points.

    ros2 run im_studies efficiency_map RUN_FILE [--speeds N] [--torques M] [--out DIR]
        [--speed-max F] [--points grid|iec|both] [--settle S] [--window S] [--workers N]
        [--force]

The run file is a scenario's (docs/running.md: its motor, inverter and plant blocks, controller,
strategy, limits) with one key of this command's, ``compare``: a list of run-file overrides, one
per drive to map, e.g.::

    compare:
      - {strategy: constant_flux}
      - {strategy: min_loss}
      - {strategy: min_loss, loss_scope: drive}
      - {controller: current_vector, strategy: min_loss, label: CVC}

(without it, the run file's own drive alone). Every operating point — speed ω in 0 .. F × the
rated speed (``--speed-max``, F > 1 into field weakening where the limits allow), shaft torque
τ in 0 .. the rated torque — is a speed task held at ω against a constant load τ, started in the
controller's steady state there, run ``--settle`` s and then measured over ``--window`` s from
the plant's energy books (docs/efficiency.md): the mechanical output P_mech = τ ω, the motor's
losses by kind as dissipated (copper, iron, friction), the inverter's conduction and switching
losses, the power drawn from the DC link P_dc = P_in + P_inv, and the steady-state efficiencies
of motor (P_mech/(P_mech + motor losses)), inverter and system (P_mech/(P_mech + every
loss)). A point the drive cannot hold (a trip, or the speed off its reference, or the stored
energy still changing) is kept with ``held: false`` and the reason, without efficiencies.

The points run as jobs of the campaign engine (Dask: ``im_studies.campaign_pool``) and each
finished one is journaled (``DIR/rows.jsonl``, ``im_studies.campaign_journal``): a killed map
resumes with the same command. At the end: ``DIR/efficiency_map.json`` (every point of every
drive), ``DIR/report.md`` (the IEC table, the maps) and the plots ``DIR/efficiency_<drive>.png``
(system efficiency over the torque-speed plane) and ``DIR/difference_<a>_vs_<b>.png`` (system
loss saved by each drive against the first).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
from pathlib import Path
import sys
import time
from typing import List, Optional

from im_bringup.offline import simulate
from im_bringup.run_file import RunFile, RunFileError, Scenario
from im_common.cli import error as cli_error, logger, parse_args
from im_common.loads import ConstantLoad
from im_common.yamlio import read_yaml_file, YamlFileError
from im_controller.profiles import Profile
from im_recording.bag import write_atomic
import numpy as np
from pydantic import Field

from .campaign_journal import JOURNAL, Journal, prepare_out
from .campaign_pool import log_progress, one_line, Pool

_log = logger('efficiency_map')

#: the operating points of a power drive system in IEC 61800-9-2 (relative speed, relative
#: torque) [%]: the standard's eight (it leaves out 100 % speed at 25 % torque)
IEC_POINTS = ((0, 25), (0, 50), (0, 100), (50, 25), (50, 50), (50, 100), (100, 50), (100, 100))
#: a point is held when its mean speed is within this share of the rated speed of its reference
SPEED_BAND = 0.02
#: ... and the energy stored in the motor changed by less than this share of E_in over the window
STORAGE_BAND = 0.01
SETTLE_S = 0.5
WINDOW_S = 0.25
POINT_SETS = ('grid', 'iec', 'both')


class MapEntry(RunFile):
    """One drive of an efficiency map: run-file keys over the file's, and its label."""

    model_config = dict(RunFile.model_config, title='a drive of the map')

    label: Optional[str] = Field(None, description="the drive's name in the map (left out: "
                                 'from the keys it sets)')


class MapFile(RunFile):
    """
    An efficiency-map file: a run file, and the drives to map (docs/efficiency.md).

    Its JSON Schema (im_studies.schemas) is what an editor checks; :func:`read_map_file` reads
    each drive through :meth:`Scenario.from_mapping` (the run file's model and rules).
    """

    model_config = dict(RunFile.model_config, title='IM drive efficiency-map file')

    compare: Optional[List[MapEntry]] = Field(
        None, min_length=1, description='the drives mapped, each the run file with these keys '
        'over it (left out: the run file alone)')


class MapFileError(ValueError):
    """A bad run file or compare list: one line naming the file and the key."""


# ------------------------------------------------------------------------------- the drives
@dataclasses.dataclass(frozen=True)
class Drive:
    """One drive of the map: its label and the Scenario every point of it derives from."""

    label: str
    scenario: Scenario


def read_map_file(path: str) -> List[Drive]:
    """Return the drives a run file names (its ``compare`` list, or itself alone)."""
    try:
        doc = read_yaml_file(path, 'run file')
    except YamlFileError as exc:
        raise MapFileError(str(exc)) from None
    if not isinstance(doc, dict):
        raise MapFileError(f'{path}: run file: must be a mapping of run keys (docs/running.md)')
    compare = doc.pop('compare', None)
    if compare is None:
        compare = [{}]
    if not isinstance(compare, list) or not compare:
        raise MapFileError(f'{path}: compare: must be a non-empty list of run-file overrides, '
                           'e.g. [{strategy: min_loss}, {strategy: constant_flux}]')
    base_dir = os.path.dirname(os.path.abspath(path))
    drives: List[Drive] = []
    for j, entry in enumerate(compare):
        where = f'{path}: compare[{j}]'
        if not isinstance(entry, dict):
            raise MapFileError(f'{where}: must be a mapping of run keys (got {entry!r})')
        entry = dict(entry)
        label = entry.pop('label', None)
        try:
            sc = Scenario.from_mapping(doc, source=path, base_dir=base_dir, overrides=entry,
                                       override_source=where)
        except RunFileError as exc:
            raise MapFileError(str(exc)) from None
        if label is None:
            label = _label(sc, entry)
        if not isinstance(label, str) or not label or '/' in label:
            raise MapFileError(f'{where}.label: must be a non-empty name without / (got '
                               f'{label!r})')
        if any(d.label == label for d in drives):
            raise MapFileError(f"{where}: the label {label!r} is another entry's: give a "
                               'label')
        drives.append(Drive(label, sc))
    motor = drives[0].scenario.plant_motor()
    if not (motor.rated_speed > 0 and motor.rated_torque > 0):
        raise MapFileError(f"{path}: motor: the map needs the motor's rated speed and power "
                           '(rated_speed_rpm, rated_power in its motor file)')
    return drives


def _label(sc: Scenario, entry: dict) -> str:
    parts = [sc.controller, sc.strategy]
    parts += [f'{k}={v}' for k, v in sorted(entry.items())
              if k not in ('controller', 'strategy')]
    return '_'.join(str(p) for p in parts).replace('/', '-')


# ------------------------------------------------------------------------------- the points
def grid_points(motor, speeds: int, torques: int, speed_max: float) -> List[dict]:
    """Return the grid's points: speed 0 .. speed_max × rated, torque 0 .. rated (both ends)."""
    out = []
    for i in range(speeds):
        w_rel = speed_max * i / (speeds - 1) if speeds > 1 else speed_max
        for j in range(torques):
            t_rel = j / (torques - 1) if torques > 1 else 1.0
            out.append({'set': 'grid', 'speed_rel': w_rel, 'torque_rel': t_rel})
    return out


def iec_points() -> List[dict]:
    return [{'set': 'iec', 'speed_rel': w / 100.0, 'torque_rel': t / 100.0}
            for w, t in IEC_POINTS]


def point_scenario(base: Scenario, speed: float, torque: float, settle: float,
                   window: float) -> Scenario:
    """Return the run that holds (ω, τ): the speed task at ω, a constant load τ, steady start."""
    prof = Profile('speed', ((0.0, speed, None),), source='efficiency map')
    return dataclasses.replace(base, task='speed', profile=prof, omega0=speed, start='steady',
                               load_model=ConstantLoad(torque), duration=settle + window)


def run_point(job: dict, drives: dict) -> dict:
    """Run one operating point of one drive; return its row (the books over the window)."""
    t0 = time.perf_counter()
    drive = drives[job['drive']]
    motor = drive.scenario.plant_motor()
    speed = job['speed_rel'] * motor.rated_speed
    torque = job['torque_rel'] * motor.rated_torque
    row = dict(job, speed=speed, torque=torque, held=False, reason='')
    settle, window = job['settle'], job['window']
    try:
        sc = point_scenario(drive.scenario, speed, torque, settle, window)
        res = simulate(sc, record_every=max(1, int(round(0.001 / sc.T_s))),
                       truth_at=(settle, settle + window))
    except Exception as exc:    # noqa: B902 (a point that cannot run is a row that says why)
        row['reason'] = one_line(exc)
        row['wall_s'] = time.perf_counter() - t0
        return row
    row.update(point_figures(res, settle, window, speed, torque, motor.rated_speed))
    row['wall_s'] = time.perf_counter() - t0
    return row


def point_figures(res, settle: float, window: float, speed: float, torque: float,
                  rated_speed: float) -> dict:
    """Return a point's powers, losses, efficiencies and checks from its run (module doc)."""
    a, b = res.summary['truth_at']
    dt = b['t'] - a['t'] if 't' in b else window

    def rate(key):
        return (b.get(key, 0.0) - a.get(key, 0.0)) / dt
    p_in = rate('E_in')
    p_mech = rate('W_load')
    p_inv = rate('E_inv')
    p_sw = rate('E_switching')
    out = {'P_in': p_in, 'P_mech': p_mech, 'P_inverter': p_inv, 'P_switching': p_sw,
           'P_conduction': p_inv - p_sw, 'P_dc': p_in + p_inv,
           'P_cu_s': rate('E_cu_s'), 'P_cu_r': rate('E_cu_r'), 'P_core': rate('E_core'),
           'P_friction': rate('E_friction')}
    # the losses as dissipated (the books' terms), not as P_in − P_mech: that difference holds
    # the window's change of the stored magnetic and kinetic energy too (its ripple is of the
    # order of the strategies' differences)
    iron = rate('E_iron') if 'E_iron' in b else 0.0
    out['P_iron'] = iron
    out['P_param'] = rate('E_param')
    out['P_motor_loss'] = (out['P_cu_s'] + out['P_cu_r'] + out['P_friction'] + iron
                           + out['P_param'])
    out['P_system_loss'] = out['P_motor_loss'] + p_inv
    storage = (b['dW_mag'] - a['dW_mag']) + (b['dE_kin'] - a['dE_kin'])
    out['P_storage'] = storage / dt
    trace = res.trace
    sel = trace['t'] >= settle
    w_mean = float(trace['omega_r'][sel].mean()) if sel.any() else math.nan
    out['omega_mean'] = w_mean
    out['balance_relative'] = res.summary['balance_relative']
    if 'balance_residual_dc' in b:
        out['balance_dc_relative'] = abs(b['balance_residual_dc']) / max(abs(b['E_in']), 1e-12)
    out['storage_share'] = abs(storage) / max(abs(p_in * dt), 1e-12)
    trip = res.summary['trip']
    if trip is not None:
        out['reason'] = f"tripped at {trip['t']:.4f} s: {trip['reason']}"
    elif not abs(w_mean - speed) <= SPEED_BAND * rated_speed:
        out['reason'] = (f'speed not held: mean {w_mean:.2f} rad/s for {speed:.2f} rad/s '
                         f"(torque {torque:.2f} N m beyond the drive's reach here)")
    elif out['storage_share'] > STORAGE_BAND and abs(p_in * dt) > 1e-6:
        out['reason'] = (f'not settled: the stored energy changed by {out["storage_share"]:.1%} '
                         'of E_in over the window (a longer --settle)')
    else:
        out['held'] = True
        out['reason'] = ''
        # the steady state's: output over output plus the losses (P_in and P_dc less the
        # window's storage ripple); zero only where no mechanical power is delivered: at zero
        # speed or zero load, whose P_mech is the speed loop's jitter about zero
        mech = max(p_mech, 0.0) if speed > 0.0 and torque > 0.0 else 0.0
        motor_in = mech + out['P_motor_loss']
        out['eta_motor'] = mech / motor_in if mech > 0.0 else 0.0
        out['eta_inverter'] = motor_in / (motor_in + p_inv) if motor_in > 0.0 else 0.0
        out['eta_system'] = mech / (motor_in + p_inv) if mech > 0.0 else 0.0
    return out


# ------------------------------------------------------------------------------- the command
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog='efficiency_map', description='Efficiency maps of the whole drive over the '
        'torque-speed plane and its losses at the IEC 61800-9-2 operating points, for every '
        "drive of the run file's compare list (docs/efficiency.md).")
    p.add_argument('run_file', help='a run file (docs/running.md) with a compare: list')
    p.add_argument('--speeds', type=int, default=10, help='grid points in speed (default 10)')
    p.add_argument('--torques', type=int, default=10, help='grid points in torque (default 10)')
    p.add_argument('--speed-max', type=float, default=1.0,
                   help="the grid's top speed over the rated speed (default 1; above 1: into "
                   'field weakening, where the limits allow)')
    p.add_argument('--points', choices=POINT_SETS, default='both',
                   help="grid, iec (the standard's eight points only) or both (default)")
    p.add_argument('--settle', type=float, default=SETTLE_S,
                   help=f'time each point runs before it is measured [s] (default {SETTLE_S})')
    p.add_argument('--window', type=float, default=WINDOW_S,
                   help=f'the measuring window [s] (default {WINDOW_S})')
    p.add_argument('--out', default='bags/efficiency_map', help='output directory')
    p.add_argument('--workers', type=int, default=None, help='Dask workers (default: cores)')
    p.add_argument('--force', action='store_true',
                   help='start over in a DIR that holds another map')
    return p


def check_arguments(args) -> None:
    for name in ('speeds', 'torques'):
        v = getattr(args, name)
        if v < 1:
            raise MapFileError(f'--{name}: must be >= 1 (got {v})')
    if not (math.isfinite(args.speed_max) and 0.0 < args.speed_max <= 3.0):
        raise MapFileError(f'--speed-max: must be in (0, 3] (got {args.speed_max})')
    for name in ('settle', 'window'):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0.0):
            raise MapFileError(f'--{name}: must be > 0 s (got {v})')
    if args.workers is not None and args.workers < 1:
        raise MapFileError(f'--workers: must be >= 1 (got {args.workers})')


def jobs(drives: List[Drive], args) -> List[dict]:
    motor = drives[0].scenario.plant_motor()
    pts: List[dict] = []
    if args.points in ('grid', 'both'):
        pts += grid_points(motor, args.speeds, args.torques, args.speed_max)
    if args.points in ('iec', 'both'):
        pts += iec_points()
    out = []
    for d in drives:
        for p in pts:
            out.append(dict(p, index=len(out), drive=d.label, settle=args.settle,
                            window=args.window))
    return out


def map_spec(path: str, drives: List[Drive], args) -> dict:
    """Return what identifies the map (its journal refuses another's rows)."""
    return {'name': f'efficiency map of {os.path.basename(path)}',
            'drives': {d.label: d.scenario.to_mapping() for d in drives},
            'speeds': args.speeds, 'torques': args.torques, 'speed_max': args.speed_max,
            'points': args.points, 'settle': args.settle, 'window': args.window}


def run_map(path: str, args, progress: bool = True) -> dict:
    """Run (or resume) the map into ``args.out``; return the document written."""
    drives = read_map_file(path)
    check_arguments(args)
    all_jobs = jobs(drives, args)
    spec = map_spec(path, drives, args)
    out = Path(args.out)
    done = prepare_out(out, json.loads(json.dumps(spec, default=str)), args.force)
    todo = [j for j in all_jobs if j['index'] not in done]
    if progress:
        _log(f'{len(drives)} drive(s) × {len(all_jobs) // len(drives)} points: '
             f'{len(all_jobs)} runs, {len(done)} already done, {len(todo)} to run')
    t0 = time.perf_counter()
    rows = dict(done)
    if todo:
        journal = Journal(out / JOURNAL)
        try:
            with Pool(args.workers) as pool:
                by_label = {d.label: d for d in drives}
                for n, (_, row) in enumerate(pool.map(run_point, todo, by_label), 1):
                    journal.append(row)
                    rows[row['index']] = row
                    if progress and (n % max(1, len(todo) // 20) == 0 or n == len(todo)):
                        log_progress('efficiency map', n, len(todo), 0,
                                     time.perf_counter() - t0)
        finally:
            journal.close()
    wall = time.perf_counter() - t0
    ordered = [rows[j['index']] for j in all_jobs]
    motor = drives[0].scenario.plant_motor()
    doc = {'run_file': os.path.abspath(path), 'drives': [d.label for d in drives],
           'rated': {'speed': motor.rated_speed, 'torque': motor.rated_torque,
                     'power': motor.rated_power},
           'settle_s': args.settle, 'window_s': args.window, 'wall_s': wall,
           'resumed_points': len(done),        # wall_s is this command's: the rest ran before
           'workers': args.workers or os.cpu_count(), 'points': ordered,
           'iec': iec_table(ordered, [d.label for d in drives], motor.rated_power)}
    write_atomic(out / 'efficiency_map.json', json.dumps(doc, indent=1, allow_nan=True))
    figures = plot_maps(doc, out)
    write_report(doc, out, figures)
    return doc


def iec_table(rows: List[dict], labels: List[str], rated_power: float) -> List[dict]:
    """Return the PDS losses at the standard's points per drive: W and % of rated output."""
    out = []
    for w, t in IEC_POINTS:
        entry = {'speed_pct': w, 'torque_pct': t}
        for lab in labels:
            r = next((r for r in rows if r['set'] == 'iec' and r['drive'] == lab
                      and round(100 * r['speed_rel']) == w
                      and round(100 * r['torque_rel']) == t), None)
            if r is None or not r.get('held'):
                entry[lab] = None
                continue
            entry[lab] = {'P_loss_W': r['P_system_loss'],
                          'P_loss_pct': 100.0 * r['P_system_loss'] / rated_power,
                          'P_motor_loss_W': r['P_motor_loss'],
                          'P_inverter_W': r['P_inverter'], 'P_switching_W': r['P_switching']}
        out.append(entry)
    return out


def _grid_array(doc: dict, label: str, key: str):
    rows = [r for r in doc['points'] if r['set'] == 'grid' and r['drive'] == label]
    ws = sorted({r['speed_rel'] for r in rows})
    ts = sorted({r['torque_rel'] for r in rows})
    z = np.full((len(ts), len(ws)), np.nan)
    for r in rows:
        if r.get('held') and key in r:
            z[ts.index(r['torque_rel']), ws.index(r['speed_rel'])] = r[key]
    return np.array(ws), np.array(ts), z


def plot_maps(doc: dict, out: Path) -> List[str]:
    """Draw the system efficiency of each drive and the loss each saves against the first."""
    import matplotlib       # heavy: matplotlib, only for the figures
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt     # heavy: pyplot, after the Agg backend is chosen
    labels = doc['drives']
    rated = doc['rated']
    names: List[str] = []
    if not any(r['set'] == 'grid' for r in doc['points']):
        return names
    for lab in labels:
        ws, ts, z = _grid_array(doc, lab, 'eta_system')
        if len(ws) < 2 or len(ts) < 2:
            continue
        fig, ax = plt.subplots(figsize=(6.4, 4.8))
        W, Tq = np.meshgrid(ws * rated['speed'], ts * rated['torque'])
        cs = ax.contourf(W, Tq, 100.0 * z, levels=np.arange(0, 101, 5), cmap='viridis')
        ax.contour(W, Tq, 100.0 * z, levels=np.arange(50, 101, 5), colors='k',
                   linewidths=0.5)
        fig.colorbar(cs, ax=ax, label='system efficiency P_mech/P_dc [%]')
        ax.set(xlabel='speed [rad/s]', ylabel='torque [N m]', title=f'{lab}: the whole drive')
        name = f'efficiency_{lab}.png'
        fig.savefig(out / name, dpi=110, bbox_inches='tight')
        plt.close(fig)
        names.append(name)
    base = labels[0]
    for lab in labels[1:]:
        ws, ts, z0 = _grid_array(doc, base, 'P_system_loss')
        _, _, z1 = _grid_array(doc, lab, 'P_system_loss')
        if len(ws) < 2 or len(ts) < 2:
            continue
        saved = 100.0 * (z0 - z1) / np.where(z0 > 0, z0, np.nan)
        fig, ax = plt.subplots(figsize=(6.4, 4.8))
        W, Tq = np.meshgrid(ws * rated['speed'], ts * rated['torque'])
        lim = max(1.0, float(np.nanmax(np.abs(saved))) if np.isfinite(saved).any() else 1.0)
        cs = ax.contourf(W, Tq, saved, levels=np.linspace(-lim, lim, 21), cmap='RdBu')
        fig.colorbar(cs, ax=ax, label=f'system loss saved against {base} [%]')
        ax.set(xlabel='speed [rad/s]', ylabel='torque [N m]', title=f'{lab} against {base}')
        name = f'difference_{lab}_vs_{base}.png'
        fig.savefig(out / name, dpi=110, bbox_inches='tight')
        plt.close(fig)
        names.append(name)
    return names


def write_report(doc: dict, out: Path, figures: List[str]) -> None:
    labels = doc['drives']
    lines = [f"# Efficiency map: {os.path.basename(doc['run_file'])}", '',
             f"Rated: {doc['rated']['power']:g} W at {doc['rated']['speed']:.1f} rad/s, "
             f"{doc['rated']['torque']:.2f} N m. Each point settled {doc['settle_s']:g} s, "
             f"measured over {doc['window_s']:g} s; {len(doc['points'])} runs in "
             f"{doc['wall_s']:.0f} s on {doc['workers']} worker(s).", '']
    unheld = [r for r in doc['points'] if not r.get('held')]
    if any(r['set'] == 'iec' for r in doc['points']):
        lines += ['## PDS losses at the IEC 61800-9-2 operating points', '',
                  "P_loss: the motor's and the inverter's losses, in W and in % of the rated "
                  'output.', '',
                  '| speed % | torque % | ' + ' | '.join(labels) + ' |',
                  '|---|---|' + '---|' * len(labels)]
        for e in doc['iec']:
            cells = []
            for lab in labels:
                c = e[lab]
                cells.append('not held' if c is None else
                             f"{c['P_loss_W']:.1f} W ({c['P_loss_pct']:.2f} %)")
            lines.append(f"| {e['speed_pct']} | {e['torque_pct']} | " + ' | '.join(cells)
                         + ' |')
        lines.append('')
    if figures:
        lines += ['## Maps', ''] + [f'![{f}]({f})' for f in figures] + ['']
    if unheld:
        lines += ['## Points not held', '']
        lines += [f"- {r['drive']} ({r['set']}): {r['speed']:.1f} rad/s, {r['torque']:.2f} N m: "
                  f"{r['reason']}" for r in unheld]
        lines.append('')
    (out / 'report.md').write_text('\n'.join(lines))


def main(argv: Optional[List[str]] = None) -> int:
    args = parse_args(build_parser(), argv)
    try:
        doc = run_map(args.run_file, args)
    except (MapFileError, FileExistsError, ConnectionError) as exc:
        return cli_error('efficiency_map', exc)
    except KeyboardInterrupt:
        print('efficiency_map: interrupted; the finished points are kept in '
              f'{args.out}/{JOURNAL} (the same command resumes)', file=sys.stderr)
        return 130
    held = sum(1 for r in doc['points'] if r.get('held'))
    _log(f"{held}/{len(doc['points'])} points held; {args.out}/efficiency_map.json, "
         f'{args.out}/report.md')
    return 0


if __name__ == '__main__':
    sys.exit(main())
