"""Campaigns: Monte Carlo validation of the drive over a parameter box (docs/campaign.md).

    ros2 run im_studies campaign SPEC.yaml [--out DIR] [--workers N | --address tcp://HOST:8786]
    ros2 run im_studies campaign SPEC.yaml --run INDEX [--graph] [--record BAG]   # one run alone

A spec (YAML) names the parameter box or distributions of the plant's motor, the number of draws,
the tasks, strategies, gain sets (each with its period), loads, profiles and the seed. Every draw
is a motor; every run is one draw × task × strategy × controller × gain set × load × profile,
executed by the
ROS-free loop (``im_bringup.offline``; same numbers as the graph) or, with ``mode: graph``, by
the in-process ROS graph. Runs are Dask tasks on a local cluster of every core, or on an existing
Dask scheduler (``--address``); Dask was chosen over Ray by ``benchmarks/bench_campaign.py``.

Every column of a row but ``wall_s`` is a function of (spec, index): the same spec and seed give
the same rows on any number of workers. Each finished run is appended to ``DIR/rows.jsonl`` (and
synced) before the next is counted, so a killed campaign resumes where it stopped with the same
command and runs nothing twice. At the end: ``DIR/runs.parquet`` (one row per run; spec, seed and
versions in its metadata), ``DIR/summary.json``, ``DIR/report.md`` with figures.
"""
from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, Iterable, List, Optional, Sequence

import numpy as np

from im_common.cli import logger

_log = logger('campaign')

SPEC_KEYS = ('name', 'seed', 'draws', 'motor', 'box', 'sigma_min', 'tasks', 'strategies',
             'controllers',
             'gain_sets', 'loads', 'profiles', 'duration', 'mode', 'map', 'worst',
             'speedup_runs')
#: parameters of the plant's motor a spec may draw (the motor's electrical parameters)
DRAWN = ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr')
#: what the stability map may be drawn over: a drawn parameter, σ or σL_s
MAP_AXES = DRAWN + ('sigma', 'sigma_L_s')
#: controllers a campaign runs: the nominal one, or with the adapter's improved or thesis law
CAMPAIGN_CONTROLLERS = ('nominal', 'adaptive', 'adaptive_thesis', 'adaptive_thesis_pair')
STATUSES = ('ok', 'tripped', 'diverged', 'failed')
UNSTABLE = ('tripped', 'diverged')
JOURNAL = 'rows.jsonl'
STATE = 'campaign.json'
FIGURES = ('pos_err_max_rad', 'pos_err_rms_rad', 'speed_err_max_rad_s', 'speed_err_rms_rad_s',
           'torque_err_max_Nm', 'E_in_J', 'E_loss_J', 'E_copper_J', 'E_core_J', 'i_max_A',
           'V_max_V', 'balance_relative')


class SpecError(ValueError):
    """A spec that cannot be run; the message is one line naming the key and the file."""


# ---------------------------------------------------------------------------------------- spec
def default_box() -> Dict[str, list]:
    """The chapter-4 box the robust gains are certified over (im_controller.gain_design)."""
    from im_controller.gain_design.motor import DEFAULT_BOX
    return {k: list(v) for k, v in DEFAULT_BOX.items()}


def _default_sigma_min() -> float:
    from im_controller.gain_design.motor import DEFAULT_SIGMA_MIN
    return DEFAULT_SIGMA_MIN


def _resolve(path: str, base: Path) -> str:
    """A file named in a spec: absolute, or relative to the spec's folder, or a shipped file of
    ``im_bringup``/``im_common`` (``config/...``)."""
    p = Path(os.path.expanduser(path))
    if p.is_absolute():
        return str(p)
    if (base / p).exists():
        return str((base / p).resolve())
    for pkg in ('im_bringup', 'im_common'):
        try:
            from ament_index_python.packages import get_package_share_directory
            q = Path(get_package_share_directory(pkg)) / p
        except Exception:   # package not installed in this environment: try the next one
            continue
        if q.exists():
            return str(q)
    return str((base / p).resolve())


def _distribution(name: str, value, where: str) -> dict:
    """A box entry as {'kind': 'uniform', 'lo', 'hi'} / {'kind': 'normal', 'mean', 'std', 'lo',
    'hi'} / {'kind': 'fixed', 'value'}."""
    def num(v, what):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise SpecError(f'{where}: box.{name}.{what} = {v!r} is not a finite number')
        return float(v)
    if isinstance(value, (list, tuple)):
        value = {'uniform': list(value)}
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = {'fixed': value}
    if not isinstance(value, dict) or len(set(value) & {'uniform', 'normal', 'fixed'}) != 1:
        raise SpecError(f'{where}: box.{name} = {value!r}: give [lo, hi] (uniform), '
                        '{normal: [mean, std], within: [lo, hi]} or a number')
    if 'fixed' in value:
        v = num(value['fixed'], 'fixed')
        d = {'kind': 'fixed', 'value': v, 'lo': v, 'hi': v}
    elif 'uniform' in value:
        u = value['uniform']
        if not isinstance(u, (list, tuple)) or len(u) != 2:
            raise SpecError(f'{where}: box.{name} = {u!r}: a uniform range is [lo, hi]')
        lo, hi = num(u[0], 'lo'), num(u[1], 'hi')
        d = {'kind': 'uniform', 'lo': lo, 'hi': hi}
    else:
        nv = value['normal']
        if not isinstance(nv, (list, tuple)) or len(nv) != 2:
            raise SpecError(f'{where}: box.{name}.normal = {nv!r}: give [mean, std]')
        mean, std = num(nv[0], 'mean'), num(nv[1], 'std')
        if std <= 0:
            raise SpecError(f'{where}: box.{name}.normal std = {std:g} must be > 0')
        w = value.get('within', [mean - 4 * std, mean + 4 * std])
        if not isinstance(w, (list, tuple)) or len(w) != 2:
            raise SpecError(f'{where}: box.{name}.within = {w!r}: give [lo, hi]')
        d = {'kind': 'normal', 'mean': mean, 'std': std, 'lo': num(w[0], 'within'),
             'hi': num(w[1], 'within')}
    extra = set(value) - {'uniform', 'normal', 'fixed', 'within'}
    if extra:
        raise SpecError(f'{where}: box.{name}: unknown key {sorted(extra)[0]!r}')
    if not 0 < d['lo'] <= d['hi']:
        raise SpecError(f'{where}: box.{name} range [{d["lo"]:g}, {d["hi"]:g}] must be positive '
                        'and increasing')
    return d


def _gain_set(entry, i: int, where: str, base: Path) -> dict:
    if not isinstance(entry, dict):
        raise SpecError(f'{where}: gain_sets[{i}] = {entry!r}: give {{name, gains, T_s}}')
    unknown = set(entry) - {'name', 'gains', 'T_s'}
    if unknown:
        raise SpecError(f'{where}: gain_sets[{i}]: unknown key {sorted(unknown)[0]!r} '
                        '(name, gains, T_s)')
    T_s = entry.get('T_s')
    if isinstance(T_s, bool) or not isinstance(T_s, (int, float)) or not (
            math.isfinite(T_s) and T_s > 0):
        raise SpecError(f'{where}: gain_sets[{i}].T_s = {T_s!r} must be a period in seconds > 0')
    gains = entry.get('gains', 'thesis')
    name = str(entry.get('name', gains if gains in ('thesis', 'certified') else f'set{i}'))
    if not name.replace('_', '').isalnum():
        raise SpecError(f'{where}: gain_sets[{i}].name = {name!r}: letters, digits and _ only')
    g = {'name': name, 'T_s': float(T_s)}
    if gains in ('thesis', 'certified'):
        g['gains'] = gains
    elif isinstance(gains, str):
        path = _resolve(gains, base)
        if not os.path.isfile(path):
            raise SpecError(f'{where}: gain_sets[{i}].gains = {gains!r}: no such file (looked '
                            f'at {path})')
        g['gains'] = path
    else:
        raise SpecError(f'{where}: gain_sets[{i}].gains = {gains!r}: thesis, certified or a '
                        'gains file (design_gains --out)')
    return g


def _files(spec: dict, key: str, where: str, base: Path) -> List[str]:
    vals = spec.get(key, ['task'])
    if isinstance(vals, str):
        vals = [vals]
    if not isinstance(vals, list) or not vals:
        raise SpecError(f'{where}: {key} = {vals!r}: a list of files, or [task] for the '
                        "task's own")
    out = []
    for v in vals:
        if v == 'task':
            out.append('task')
            continue
        path = _resolve(str(v), base)
        if not os.path.isfile(path):
            raise SpecError(f'{where}: {key}: {v!r}: no such file (looked at {path})')
        out.append(path)
    return out


def normalize_spec(raw: dict, where: str = 'spec', base: Optional[Path] = None) -> dict:
    """The spec with every default filled in and every value checked (SpecError, one line)."""
    from im_bringup.config import STRATEGIES, TASKS
    base = Path(base or '.')
    if not isinstance(raw, dict):
        raise SpecError(f'{where}: a campaign spec is a mapping of {", ".join(SPEC_KEYS)}')
    unknown = set(raw) - set(SPEC_KEYS)
    if unknown:
        raise SpecError(f'{where}: unknown key {sorted(unknown)[0]!r} (one of '
                        f'{", ".join(SPEC_KEYS)})')
    spec: dict = {'name': str(raw.get('name', Path(where).stem))}
    for key, default, lo in (('seed', 0, 0), ('draws', 100, 1), ('worst', 10, 0),
                             ('speedup_runs', 0, 0)):
        v = raw.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise SpecError(f'{where}: {key} = {v!r} must be an integer >= {lo}')
        spec[key] = v
    motor = raw.get('motor', 'thesis')
    spec['motor'] = 'thesis' if motor == 'thesis' else _resolve(str(motor), base)
    if spec['motor'] != 'thesis' and not os.path.isfile(spec['motor']):
        raise SpecError(f'{where}: motor = {motor!r}: no such file (looked at {spec["motor"]})')
    box = raw.get('box') or default_box()
    if not isinstance(box, dict):
        raise SpecError(f'{where}: box = {box!r}: a mapping of parameter -> range')
    for k in box:
        if k not in DRAWN:
            raise SpecError(f'{where}: box.{k}: only {", ".join(DRAWN)} can be drawn')
    spec['box'] = {k: _distribution(k, box[k], where) for k in DRAWN if k in box}
    s = raw.get('sigma_min', _default_sigma_min())
    if isinstance(s, bool) or not isinstance(s, (int, float)) or not 0 < s < 1:
        raise SpecError(f'{where}: sigma_min = {s!r} must be in (0, 1)')
    spec['sigma_min'] = float(s)
    for key, allowed, default in (('tasks', TASKS, ['position']),
                                  ('strategies', STRATEGIES, ['min_energy']),
                                  ('controllers', CAMPAIGN_CONTROLLERS, ['nominal'])):
        v = raw.get(key, default)
        v = [v] if isinstance(v, str) else v
        if not isinstance(v, list) or not v:
            raise SpecError(f'{where}: {key} = {v!r}: a list, of {", ".join(allowed)}')
        for x in v:
            if x not in allowed:
                raise SpecError(f'{where}: {key}: {x!r} is not one of {", ".join(allowed)}')
        spec[key] = list(v)
    if 'torque' in spec['tasks'] and raw.get('profiles', ['task']) == ['task']:
        raise SpecError(f'{where}: tasks: the torque task needs profiles (files)')
    gsets = raw.get('gain_sets', [{'name': 'thesis', 'gains': 'thesis', 'T_s': 1e-4}])
    if not isinstance(gsets, list) or not gsets:
        raise SpecError(f'{where}: gain_sets = {gsets!r}: a list of {{name, gains, T_s}}')
    spec['gain_sets'] = [_gain_set(g, i, where, base) for i, g in enumerate(gsets)]
    names = [g['name'] for g in spec['gain_sets']]
    if len(set(names)) != len(names):
        raise SpecError(f'{where}: gain_sets: two sets named alike ({names})')
    spec['loads'] = _files(raw, 'loads', where, base)
    spec['profiles'] = _files(raw, 'profiles', where, base)
    d = raw.get('duration')
    if d is not None and (isinstance(d, bool) or not isinstance(d, (int, float))
                          or not (math.isfinite(d) and d > 0)):
        raise SpecError(f'{where}: duration = {d!r} must be > 0 s (or absent: the task default)')
    spec['duration'] = None if d is None else float(d)
    mode = raw.get('mode', 'offline')
    if mode not in ('offline', 'graph'):
        raise SpecError(f'{where}: mode = {mode!r}: offline (the ROS-free loop) or graph')
    spec['mode'] = mode
    m = raw.get('map', ['sigma_L_s', 'R_r'])
    if not isinstance(m, list) or len(m) != 2 or any(x not in MAP_AXES for x in m):
        raise SpecError(f'{where}: map = {m!r}: two of {", ".join(MAP_AXES)}')
    spec['map'] = list(m)
    return spec


def read_spec(path: str) -> dict:
    """Read and normalize a spec file (SpecError naming the file on any problem)."""
    from im_common.params import read_yaml_file
    try:
        raw = read_yaml_file(path, 'campaign spec')
    except ValueError as exc:
        raise SpecError(str(exc)) from None
    return normalize_spec(raw, where=str(path), base=Path(path).resolve().parent)


def spec_hash(spec: dict) -> str:
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


# ---------------------------------------------------------------------------------------- jobs
def _base_motor(spec: dict):
    from im_common.params import THESIS_MOTOR, load_motor_file
    return THESIS_MOTOR if spec['motor'] == 'thesis' else load_motor_file(spec['motor'])


def draw(spec: dict, d: int) -> Dict[str, float]:
    """Motor parameters of draw ``d``: a function of (seed, d) only (rejection of σ < σ_min)."""
    base = _base_motor(spec)
    rng = np.random.default_rng(np.random.SeedSequence([spec['seed'], d]))
    for _ in range(10000):
        vals = {k: getattr(base, k) for k in DRAWN}
        for k, dist in spec['box'].items():
            if dist['kind'] == 'fixed':
                vals[k] = dist['value']
            elif dist['kind'] == 'uniform':
                vals[k] = float(rng.uniform(dist['lo'], dist['hi']))
            else:
                while True:
                    v = float(rng.normal(dist['mean'], dist['std']))
                    if dist['lo'] <= v <= dist['hi']:
                        break
                vals[k] = v
        sigma = 1.0 - vals['L_sr'] ** 2 / (vals['L_s'] * vals['L_r'])
        if sigma >= spec['sigma_min']:
            return vals
    raise SpecError(f'draw {d}: no motor with sigma >= {spec["sigma_min"]} in 10000 tries; '
                    'the box lies outside it')


def jobs(spec: dict) -> List[dict]:
    """Every run of the campaign, in index order (draw-major)."""
    import itertools
    out = []
    for d in range(spec['draws']):
        motor = draw(spec, d)
        for task, strategy, controller, g, load, profile in itertools.product(
                spec['tasks'], spec['strategies'], spec['controllers'], spec['gain_sets'],
                spec['loads'], spec['profiles']):
            out.append({'index': len(out), 'draw': d, 'task': task, 'strategy': strategy,
                        'controller': controller, 'gain_set': g['name'], 'T_s': g['T_s'],
                        'load': load, 'profile': profile, **motor})
    return out


def gain_arguments(spec: dict) -> Dict[str, dict]:
    """Per gain set: node-parameter overrides ({'controller': {...}, 'observer': {...}}) —
    empty for the thesis's gains, designed at T_s for 'certified', read from a gains file."""
    from im_controller.design_gains import design_for_scenario
    out = {}
    for g in spec['gain_sets']:
        if g['gains'] == 'thesis':
            out[g['name']] = {}
        elif g['gains'] == 'certified':
            out[g['name']] = design_for_scenario(g['T_s'])
        else:
            from im_bringup.scenario import merge_yaml
            params: dict = {'controller': {}, 'observer': {}}
            try:
                merge_yaml(params, g['gains'])
            except ValueError as exc:
                raise SpecError(str(exc)) from None
            for n, p in params.items():
                period = p.get('gain_period')
                if period is not None and abs(float(period) - g['T_s']) > 1e-12:
                    raise SpecError(f"{g['gains']}: {n}.gain_period = {period} s but gain set "
                                    f"{g['name']!r} runs at T_s = {g['T_s']:g} s")
            out[g['name']] = params
    return out


def scenario_for(job: dict, spec: dict, gains: dict):
    """The offline :class:`~im_bringup.offline.Scenario` of one job."""
    from im_bringup.offline import Scenario, gain_arguments_from_parameters
    from im_common.loads import load_file
    from im_controller.profiles import load_profile
    base = _base_motor(spec)
    motor = base.with_values(**{k: job[k] for k in DRAWN})
    return Scenario(task=job['task'], strategy=job['strategy'], T_s=job['T_s'],
                    controller=job['controller'],
                    duration=spec['duration'], motor=motor, estimates=base,
                    load_model=None if job['load'] == 'task' else load_file(job['load']),
                    profile=None if job['profile'] == 'task' else load_profile(job['profile']),
                    **gain_arguments_from_parameters(gains[job['gain_set']]))


def adapter_for(job: dict, spec: dict):
    """The offline loop's adapter hook of an adaptive job (None for the nominal controller):
    the adapter starts from the nominal motor, like the controller and observer."""
    if job['controller'] == 'nominal':
        return None
    from im_adapt.adaptation import AdaptationGains
    from im_adapt.hook import LockstepAdapter
    from im_bringup.config import ADAPTATION
    return LockstepAdapter.build(_base_motor(spec),
                                 AdaptationGains(**ADAPTATION[job['controller']]))


def graph_parameters(job: dict, spec: dict, gains: dict) -> dict:
    """Node parameters of one job for the ROS graph (the same run as :func:`scenario_for`)."""
    from im_bringup.config import node_parameters
    base = _base_motor(spec)
    params = node_parameters(job['task'], job['strategy'], job['controller'], 'none', job['T_s'],
                             spec['duration'],
                             motor=base.with_values(**{k: job[k] for k in DRAWN}),
                             estimates=base,
                             load=None if job['load'] == 'task' else job['load'],
                             profile=None if job['profile'] == 'task' else job['profile'])
    for node, values in gains[job['gain_set']].items():
        params[node].update(values)
    return params


def _one_line(exc: BaseException) -> str:
    text = ' '.join(str(exc).split())
    return f'{type(exc).__name__}: {text}'[:300]


def run_job(job: dict, spec: dict, gains: dict) -> dict:
    """Execute one run; never raises: the row says ok / tripped / diverged / failed."""
    import re
    row = dict(job)
    row['sigma'] = 1.0 - job['L_sr'] ** 2 / (job['L_s'] * job['L_r'])
    row['sigma_L_s'] = row['sigma'] * job['L_s']     # the current loop's inductance
    for k in FIGURES:
        row[k] = float('nan')
    row.update(status='failed', trip='', t_end_s=float('nan'), error='')
    t0 = time.perf_counter()
    try:
        if spec['mode'] == 'graph':
            from im_bringup.scenario import run_scenario
            s = run_scenario(graph_parameters(job, spec, gains), task=job['task'],
                             strategy=job['strategy'], controller=job['controller'],
                             progress=False,
                             domain_id=150 + job['index'] % 80)
            s.pop('_run', None)
            if not s.get('ok', True) and not s.get('trip'):
                raise RuntimeError('; '.join(str(v) for v in (s.get('failures') or {}).values()))
        else:
            from im_bringup.offline import simulate
            s = simulate(scenario_for(job, spec, gains), adapter=adapter_for(job, spec)).summary
    except (FloatingPointError, OverflowError) as exc:
        m = re.search(r't = ([0-9.eE+-]+)', str(exc))
        row.update(status='diverged', error=_one_line(exc),
                   t_end_s=float(m.group(1)) if m else float('nan'))
    except Exception as exc:   # a failed run is a row of the campaign, never its end
        row.update(status='failed', error=_one_line(exc))
    else:
        for k in FIGURES:
            v = s.get(k)
            row[k] = float('nan') if v is None else float(v)
        trip = s.get('trip')
        finite = all(math.isfinite(row[k]) for k in ('E_in_J', 'E_loss_J'))
        if trip:
            row.update(status='tripped', trip=str(trip.get('reason', trip)),
                       t_end_s=float(trip.get('t', float('nan'))))
        elif not finite:
            row.update(status='diverged', t_end_s=float(s.get('duration_s', float('nan'))))
        else:
            row.update(status='ok', t_end_s=float(s.get('duration_s', float('nan'))))
    row['wall_s'] = time.perf_counter() - t0
    return row


# ---------------------------------------------------------------------------------------- pool
@dataclass
class Pool:
    """A Dask client on a local cluster of ``workers`` single-threaded processes, or on an
    existing scheduler at ``address``. ``map`` yields (index, result) as they finish."""
    workers: Optional[int] = None
    address: Optional[str] = None

    def __enter__(self):
        import logging
        from distributed import Client, LocalCluster
        for name in ('distributed', 'distributed.scheduler', 'distributed.worker',
                     'distributed.nanny', 'distributed.core', 'distributed.http.proxy'):
            logging.getLogger(name).setLevel(logging.ERROR)
        t0 = time.perf_counter()
        if self.address:
            try:
                self.client = Client(self.address, timeout='10s')
            except (OSError, TimeoutError) as exc:
                raise ConnectionError(f'--address {self.address}: no Dask scheduler there '
                                      f'({_one_line(exc)})') from None
            self.cluster = None
        else:
            n = self.workers or os.cpu_count() or 1
            self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                        dashboard_address=':0', silence_logs=logging.ERROR)
            self.client = Client(self.cluster)
        self.n_workers = len(self.client.scheduler_info().get('workers', {})) or 1
        self.startup_s = time.perf_counter() - t0
        return self

    def __exit__(self, *exc):
        with contextlib.suppress(Exception):
            self.client.close()
        if self.cluster is not None:
            with contextlib.suppress(Exception):
                self.cluster.close()

    def map(self, fn: Callable, items: Sequence, *args) -> Iterable:
        from distributed import as_completed
        shared = [self.client.scatter(a, broadcast=True) for a in args]
        futures = {self.client.submit(fn, item, *shared, pure=False): i
                   for i, item in enumerate(items)}
        try:
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
        finally:
            for fut in futures:
                fut.cancel()


def _call(item, fn):
    return fn(item)


def pool_map(fn: Callable, items: Sequence, workers: Optional[int] = None,
             address: Optional[str] = None, label: str = '', progress: bool = True) -> list:
    """``[fn(x) for x in items]`` on the campaign pool, in order (``make reproduce``, studies).
    ``fn`` must be importable by the workers (a module-level function)."""
    results: list = [None] * len(items)
    if not items:
        return results
    with Pool(workers, address) as pool:
        t0 = time.perf_counter()
        for done, (i, r) in enumerate(pool.map(_call, items, fn), 1):
            results[i] = r
            if progress:
                _progress(label or 'pool', done, len(items), 0, time.perf_counter() - t0)
    return results


def _progress(label: str, done: int, total: int, failed: int, elapsed: float) -> None:
    rate = done / elapsed if elapsed > 0 else 0.0
    eta = (total - done) / rate if rate > 0 else float('nan')
    eta_s = f'{int(eta // 60)}m{int(eta % 60):02d}s' if math.isfinite(eta) else '?'
    _log(f'{label}: {done}/{total} runs, {rate:.2f} runs/s, ETA {eta_s}'
         + (f', {failed} failed' if failed else ''))


# ------------------------------------------------------------------------------------ journal
def _versions() -> dict:
    from importlib import metadata
    out = {'python': sys.version.split()[0]}
    for dist in ('im_bringup', 'im_recording', 'im_studies', 'im_common', 'im_controller',
                 'im_observer', 'numpy', 'scipy',
                 'dask', 'distributed', 'pyarrow'):
        with contextlib.suppress(metadata.PackageNotFoundError):
            out[dist] = metadata.version(dist)
    return out


def read_journal(path: Path) -> Dict[int, dict]:
    """Rows already finished: {index: row}. A torn last line (the process was killed while
    writing it) is cut off, so that run is run again; nothing else is."""
    rows: Dict[int, dict] = {}
    if not path.exists():
        return rows
    good = 0
    with open(path, 'rb') as f:
        data = f.read()
    for line in data.splitlines(keepends=True):
        if not line.endswith(b'\n'):
            break
        try:
            row = json.loads(line)
        except ValueError:
            break
        rows[int(row['index'])] = row
        good += len(line)
    if good != len(data):
        with open(path, 'r+b') as f:
            f.truncate(good)
    return rows


class Journal:
    def __init__(self, path: Path):
        self.f = open(path, 'a', encoding='utf-8')

    def append(self, row: dict) -> None:
        self.f.write(json.dumps(row, allow_nan=True) + '\n')
        self.f.flush()
        os.fsync(self.f.fileno())

    def close(self) -> None:
        self.f.close()


# ------------------------------------------------------------------------------------ results
COLUMNS = (('index', 'int64'), ('draw', 'int64'), ('task', 'string'), ('strategy', 'string'),
           ('controller', 'string'),
           ('gain_set', 'string'), ('T_s', 'float64'), ('load', 'string'), ('profile', 'string'),
           *((k, 'float64') for k in DRAWN), ('sigma', 'float64'), ('sigma_L_s', 'float64'), ('status', 'string'),
           ('trip', 'string'), ('t_end_s', 'float64'), ('error', 'string'),
           *((k, 'float64') for k in FIGURES), ('wall_s', 'float64'))


def write_parquet(rows: List[dict], path: Path, metadata: dict) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq
    types = {'int64': pa.int64(), 'float64': pa.float64(), 'string': pa.string()}
    schema = pa.schema([(k, types[t]) for k, t in COLUMNS],
                       metadata={k: json.dumps(v) for k, v in metadata.items()})
    table = pa.Table.from_pylist([{k: r.get(k) for k, _ in COLUMNS} for r in rows], schema=schema)
    tmp = path.with_name('.' + path.name + '.tmp')
    pq.write_table(table, tmp)
    os.replace(tmp, path)


def read_rows(path) -> List[dict]:
    """Rows of a campaign's ``runs.parquet`` in index order."""
    import pyarrow.parquet as pq
    return pq.read_table(path).to_pylist()


def replay_command(spec_path: str, index: int) -> str:
    return f'ros2 run im_studies campaign {spec_path} --run {index}'


def summarize(rows: List[dict], spec: dict, info: dict, spec_path: str) -> dict:
    by_set: Dict[str, dict] = {}
    for g in spec['gain_sets']:
        rs = [r for r in rows if r['gain_set'] == g['name']]
        ok = [r for r in rs if r['status'] == 'ok']

        def pct(key, rr=ok):
            v = np.array([r[key] for r in rr if math.isfinite(r[key])])
            return ({'p50': float(np.percentile(v, 50)), 'p95': float(np.percentile(v, 95)),
                     'max': float(v.max())} if v.size else None)
        by_set[g['name']] = {
            'T_s': g['T_s'], 'gains': g['gains'] if g['gains'] in ('thesis', 'certified')
            else os.path.basename(g['gains']),
            'runs': len(rs), 'ok': len(ok),
            'unstable': sum(r['status'] in UNSTABLE for r in rs),
            'failed': sum(r['status'] == 'failed' for r in rs),
            'unstable_draws': sorted({r['draw'] for r in rs if r['status'] in UNSTABLE}),
            'E_loss_J': pct('E_loss_J'), 'pos_err_max_rad': pct('pos_err_max_rad'),
            'speed_err_max_rad_s': pct('speed_err_max_rad_s')}
    groups = []     # per gain set × controller × task × strategy: the spread of the figures
    for g in spec['gain_sets']:
        for c in spec['controllers']:
            for task in spec['tasks']:
                for strategy in spec['strategies']:
                    rs = [r for r in rows if (r['gain_set'], r['controller'], r['task'],
                                              r['strategy']) == (g['name'], c, task, strategy)]
                    ok = [r for r in rs if r['status'] == 'ok']
                    err = 'pos_err_rms_rad' if task == 'position' else 'speed_err_rms_rad_s'
                    if task == 'torque':
                        err = 'torque_err_max_Nm'
                    groups.append({'gain_set': g['name'], 'controller': c, 'task': task,
                                   'strategy': strategy, 'runs': len(rs), 'ok': len(ok),
                                   'unstable': sum(r['status'] in UNSTABLE for r in rs),
                                   'error_figure': err, err: pct(err, ok),
                                   'E_loss_J': pct('E_loss_J', ok)})
    worst = sorted(rows, key=_badness, reverse=True)[:spec['worst']]
    out = {'name': spec['name'], 'spec_hash': spec_hash(spec), 'seed': spec['seed'],
           'draws': spec['draws'], 'runs': len(rows),
           'failed': sum(r['status'] == 'failed' for r in rows),
           'failures': [{'index': r['index'], 'error': r['error'],
                         'replay': replay_command(spec_path, r['index'])}
                        for r in rows if r['status'] == 'failed'],
           **info,
           **{f'unstable_{n}': s['unstable'] for n, s in by_set.items()},
           'gain_sets': by_set,
           'groups': groups,
           'worst': [{'index': r['index'], 'draw': r['draw'], 'task': r['task'],
                      'strategy': r['strategy'], 'controller': r['controller'],
                      'gain_set': r['gain_set'],
                      'status': r['status'], 'trip': r['trip'], 'error': r['error'],
                      'pos_err_max_rad': r['pos_err_max_rad'],
                      'speed_err_max_rad_s': r['speed_err_max_rad_s'],
                      **{k: r[k] for k in DRAWN}, 'sigma': r['sigma'],
                      'sigma_L_s': r['sigma_L_s'],
                      'replay': replay_command(spec_path, r['index'])} for r in worst],
           'versions': _versions()}
    return out


def _badness(r: dict) -> tuple:
    """Order for 'worst runs': unstable first (earliest end first), then failures, then the
    largest tracking error relative to the task's own scale."""
    rank = {'diverged': 3, 'tripped': 3, 'failed': 2, 'ok': 0}[r['status']]
    err = r['pos_err_max_rad'] if r['task'] == 'position' else r['speed_err_max_rad_s'] / 10.0
    err = err if math.isfinite(err) else 0.0
    t_end = r['t_end_s'] if math.isfinite(r['t_end_s']) else 0.0
    return (rank, -t_end if rank == 3 else err)


# ---------------------------------------------------------------------------------------- run
def _prepare_out(out: Path, spec: dict, force: bool) -> Dict[int, dict]:
    """Create or resume ``out``: rows already done (same spec), or refuse another campaign."""
    state = out / STATE
    if state.exists():
        try:
            old = json.loads(state.read_text())
        except ValueError:
            old = {}
        if old.get('spec_hash') != spec_hash(spec):
            if not force:
                raise FileExistsError(
                    f'{out}: holds another campaign ({old.get("name", "?")}, spec '
                    f'{old.get("spec_hash", "?")}); refusing to mix or overwrite it (choose '
                    'another --out, or pass --force to start over)')
            for name in (STATE, JOURNAL, 'runs.parquet', 'summary.json', 'report.md'):
                with contextlib.suppress(FileNotFoundError):
                    (out / name).unlink()
    elif (out / JOURNAL).exists() and not force:
        raise FileExistsError(f'{out}/{JOURNAL}: rows without a campaign state; refusing to '
                              'overwrite (pass --force)')
    out.mkdir(parents=True, exist_ok=True)
    if not state.exists():
        from im_recording.bag import write_atomic
        write_atomic(state, json.dumps({'name': spec['name'], 'spec_hash': spec_hash(spec),
                                        'spec': spec}, indent=2))
        with contextlib.suppress(FileNotFoundError):
            (out / JOURNAL).unlink()
    return read_journal(out / JOURNAL)


def measure_speedup(all_jobs: List[dict], spec: dict, gains: dict, n: int,
                    workers: Optional[int], progress: bool) -> dict:
    """Wall time of the same ``n`` runs (spread over the campaign) on 1 worker and on all."""
    idx = np.linspace(0, len(all_jobs) - 1, min(n, len(all_jobs))).round().astype(int)
    subset = [all_jobs[i] for i in sorted(set(idx.tolist()))]
    walls = {}
    for w in (1, workers or os.cpu_count() or 1):
        with Pool(w) as pool:
            t0 = time.perf_counter()
            for _ in pool.map(run_job, subset, spec, gains):
                pass
            walls[w] = time.perf_counter() - t0
        if progress:
            _log(f'speed-up subset: {len(subset)} runs on {w} worker(s) in {walls[w]:.1f} s')
    one, many = walls[1], walls[max(walls)]
    return {'speedup_vs_one_worker': one / many, 'speedup_runs': len(subset),
            'speedup_wall_1_worker_s': one, 'speedup_wall_all_workers_s': many,
            'speedup_workers': max(walls)}


def run_campaign(spec: dict, out: str, spec_path: str, workers: Optional[int] = None,
                 address: Optional[str] = None, force: bool = False,
                 progress: bool = True) -> dict:
    """Run (or resume) a campaign into ``out``; returns the summary (also written)."""
    out_p = Path(out)
    done = _prepare_out(out_p, spec, force)
    all_jobs = jobs(spec)
    gains = gain_arguments(spec)
    todo = [j for j in all_jobs if j['index'] not in done]
    if progress:
        _log(f"{spec['name']}: {len(all_jobs)} runs ({spec['draws']} draws), "
             f'{len(done)} already done, {len(todo)} to run')
    info: dict = {}
    sp_file = out_p / 'speedup.json'
    if spec['speedup_runs'] and not address:
        if sp_file.exists():
            info.update(json.loads(sp_file.read_text()))
        else:
            info.update(measure_speedup(all_jobs, spec, gains, spec['speedup_runs'], workers,
                                        progress))
            from im_recording.bag import write_atomic
            write_atomic(sp_file, json.dumps(info, indent=2))
    journal = Journal(out_p / JOURNAL)
    t0 = time.perf_counter()
    failed = 0
    try:
        with Pool(workers, address) as pool:
            info.update(engine='dask', address=address or 'local', workers=pool.n_workers,
                        startup_s=pool.startup_s)
            t_run = time.perf_counter()
            last = 0.0
            for k, (_, row) in enumerate(pool.map(run_job, todo, spec, gains), 1):
                journal.append(row)
                done[row['index']] = row
                failed += row['status'] == 'failed'
                now = time.perf_counter()
                if progress and (now - last > 2.0 or k == len(todo)):
                    last = now
                    _progress(spec['name'], len(done), len(all_jobs), failed, now - t_run)
            info['run_wall_s'] = time.perf_counter() - t_run
    finally:
        journal.close()
    info['wall_s'] = time.perf_counter() - t0
    info['runs_this_invocation'] = len(todo)
    rows = [done[i] for i in sorted(done)]
    meta = {'spec': spec, 'spec_hash': spec_hash(spec), 'seed': spec['seed'],
            'versions': _versions(), 'engine': 'dask'}
    write_parquet(rows, out_p / 'runs.parquet', meta)
    summary = summarize(rows, spec, info, spec_path)
    from im_recording.bag import write_atomic
    from im_recording.report import jsonable
    write_atomic(out_p / 'summary.json', json.dumps(jsonable(summary), indent=2,
                                                    allow_nan=False))
    write_report(rows, summary, spec, out_p)
    return summary


# ------------------------------------------------------------------------------------ report
def write_report(rows: List[dict], summary: dict, spec: dict, out: Path) -> None:
    """report.md with loss and error histograms, the stability map and the worst runs."""
    from im_recording.plots import _plt
    plt = _plt()
    figs = []
    sets = [g['name'] for g in spec['gain_sets']]
    colors = dict(zip(sets, plt.rcParams['axes.prop_cycle'].by_key()['color']))
    panels = [('E_loss_J', 'losses E_loss [J]')]
    if 'position' in spec['tasks']:
        panels.append(('pos_err_max_rad', 'max position error [rad]'))
    if 'speed' in spec['tasks']:
        panels.append(('speed_err_max_rad_s', 'max speed error [rad/s]'))
    fig, axes = plt.subplots(len(spec['tasks']), len(panels),
                             figsize=(4.2 * len(panels), 3.2 * len(spec['tasks'])), squeeze=False)
    for ti, task in enumerate(spec['tasks']):
        for pi, (key, label) in enumerate(panels):
            ax = axes[ti][pi]
            for s in sets:
                v = np.array([r[key] for r in rows if r['task'] == task and r['gain_set'] == s
                              and r['status'] == 'ok' and math.isfinite(r[key])])
                if v.size:
                    ax.hist(v, bins=30, alpha=0.6, color=colors[s], label=f'{s} ({v.size})')
            ax.set_xlabel(label)
            ax.set_title(f'{task} task', fontsize=9)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=7)
            else:   # e.g. the position error of the speed task: the task has no such figure
                ax.set_axis_off()
                ax.text(0.5, 0.5, f'{task} task: no {label.split(" [")[0]}', ha='center',
                        va='center', transform=ax.transAxes, fontsize=9, color='0.4')
    fig.tight_layout()
    fig.savefig(out / 'histograms.png', dpi=110)
    plt.close(fig)
    figs.append(('histograms.png', 'Losses and tracking errors of the stable runs'))
    x, y = spec['map']
    fig, axes = plt.subplots(1, len(sets), figsize=(4.5 * len(sets), 3.8), squeeze=False)
    for ax, s in zip(axes[0], sets):
        rs = [r for r in rows if r['gain_set'] == s]
        for status, marker, col in (('ok', '.', 'tab:green'), ('tripped', 'x', 'tab:red'),
                                    ('diverged', 'x', 'tab:purple'), ('failed', 's', 'k')):
            pts = [(r[x], r[y]) for r in rs if r['status'] == status]
            if pts:
                a = np.array(pts)
                ax.scatter(a[:, 0], a[:, 1], marker=marker, c=col, s=14,
                           label=f'{status} ({len(pts)})')
        g = summary['gain_sets'][s]
        if g['gains'] == 'thesis' and 'sigma_L_s' in (x, y):
            # the thesis's scalar current gain k1 on σL_s: discrete pole 1 − k1·T_s/(σL_s)
            # leaves the unit circle below σL_s = k1·T_s/2 (docs/campaign.md)
            from im_controller.gain_design.motor import THESIS_K1
            edge = THESIS_K1 * g['T_s'] / 2.0
            (ax.axvline if x == 'sigma_L_s' else ax.axhline)(
                edge, ls='--', c='tab:red', lw=0.8, label=f'k1·T_s/2 = {edge * 1e3:.3g} mH')
        ax.set_xlabel(x)
        ax.set_ylabel(y)
        ax.set_title(f'{s} (T_s = {g["T_s"] * 1e6:g} µs): {g["unstable"]} unstable', fontsize=9)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / 'stability_map.png', dpi=110)
    plt.close(fig)
    figs.append(('stability_map.png', f'Stability over ({x}, {y}), every run of each gain set'))
    lines = [f"# Campaign {summary['name']}", '',
             f"{summary['runs']} runs ({summary['draws']} draws, seed {summary['seed']}, spec "
             f"{summary['spec_hash']}) on {summary.get('workers', '?')} Dask worker(s) "
             f"({summary.get('address', 'local')}); failures: {summary['failed']}.", '',
             '| gain set | T_s [µs] | runs | stable | unstable | failed | losses p50 / p95 [J] '
             '| pos. err max p95 [mrad] | speed err max p95 [rad/s] |',
             '| --- | ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: |']
    for s, g in summary['gain_sets'].items():
        def p(key, field, scale=1.0):
            v = g.get(key)
            return '—' if not v else f'{v[field] * scale:.3g}'
        lines.append(f"| {s} | {g['T_s'] * 1e6:g} | {g['runs']} | {g['ok']} | {g['unstable']} "
                     f"| {g['failed']} | {p('E_loss_J', 'p50')} / {p('E_loss_J', 'p95')} | "
                     f"{p('pos_err_max_rad', 'p95', 1e3)} | {p('speed_err_max_rad_s', 'p95')} |")
    units = {'pos_err_rms_rad': ('position RMS', 'mrad', 1e3),
             'speed_err_rms_rad_s': ('speed RMS', 'rad/s', 1.0),
             'torque_err_max_Nm': ('torque max', 'N·m', 1.0)}
    lines += ['', '| gain set | controller | task | strategy | runs | unstable | error p50 / p95 '
              '/ max | losses p50 [J] |', '| --- | --- | --- | --- | ---: | ---: | --- | ---: |']
    for g in summary['groups']:
        name, unit, scale = units[g['error_figure']]
        e = g[g['error_figure']]
        err = (f'{e["p50"] * scale:.3g} / {e["p95"] * scale:.3g} / {e["max"] * scale:.3g} '
               f'{unit} ({name})' if e else '—')
        loss = f'{g["E_loss_J"]["p50"]:.1f}' if g['E_loss_J'] else '—'
        lines.append(f"| {g['gain_set']} | {g['controller']} | {g['task']} | {g['strategy']} | "
                     f"{g['runs']} | {g['unstable']} | {err} | {loss} |")
    if 'speedup_vs_one_worker' in summary:
        lines += ['', f"Speed-up: {summary['speedup_runs']} runs took "
                      f"{summary['speedup_wall_1_worker_s']:.1f} s on 1 worker and "
                      f"{summary['speedup_wall_all_workers_s']:.1f} s on "
                      f"{summary['speedup_workers']}: ×{summary['speedup_vs_one_worker']:.2f}."]
    lines += ['']
    for f, caption in figs:
        lines += [f'![{caption}]({f})', '', f'*{caption}*', '']
    lines += ['## Worst runs', '', '| index | task | strategy | controller | gain set | status | '
              'why / error | ' + ' | '.join(DRAWN) + ' | σ | σL_s [mH] | replay alone |',
              '| ---: | --- | --- | --- | --- | --- | --- |' + ' ---: |' * (len(DRAWN) + 2)
              + ' --- |']
    for w in summary['worst']:
        why = w['trip'] or w['error'] or (
            f"pos. err {w['pos_err_max_rad'] * 1e3:.3g} mrad" if w['task'] == 'position'
            else f"speed err {w['speed_err_max_rad_s']:.3g} rad/s")
        lines.append(f"| {w['index']} | {w['task']} | {w['strategy']} | {w['controller']} | "
                     f"{w['gain_set']} | {w['status']} | "
                     f"{why.replace('|', '∣')} | "
                     + ' | '.join(f'{w[k]:.4g}' for k in DRAWN)
                     + f" | {w['sigma']:.3f} | {w['sigma_L_s'] * 1e3:.3f} | `{w['replay']}` |")
    from im_recording.bag import write_atomic
    write_atomic(out / 'report.md', '\n'.join(lines) + '\n')


# ------------------------------------------------------------------------------------- main
def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='campaign', description=__doc__.split('\n\n')[0])
    ap.add_argument('spec', help='campaign spec (YAML); see docs/campaign.md')
    ap.add_argument('--out', help='output folder (default bags/campaign/<spec name>)')
    ap.add_argument('--workers', type=int, help='local worker processes (default: every core)')
    ap.add_argument('--address', help='an existing Dask scheduler, e.g. tcp://10.0.0.5:8786')
    ap.add_argument('--force', action='store_true',
                    help='start over in an --out that holds another campaign')
    ap.add_argument('--run', type=int, metavar='INDEX', help='run only this index, alone, in '
                    'this process, and print its row (the worst runs list this command)')
    ap.add_argument('--graph', action='store_true', help='with --run: through the ROS graph')
    ap.add_argument('--record', help='with --run --graph: record the run to this MCAP file')
    ap.add_argument('--no-progress', action='store_true')
    return ap


def _run_alone(spec: dict, args) -> int:
    all_jobs = jobs(spec)
    if not 0 <= args.run < len(all_jobs):
        print(f'error: --run {args.run}: the campaign has runs 0..{len(all_jobs) - 1}',
              file=sys.stderr)
        return 2
    job = all_jobs[args.run]
    gains = gain_arguments(spec)
    if args.record:
        from im_bringup.scenario import run_scenario
        s = run_scenario(graph_parameters(job, spec, gains), task=job['task'],
                         strategy=job['strategy'], controller=job['controller'],
                         record=args.record,
                         progress=not args.no_progress)
        print(f"recorded {args.record}; ok={s.get('ok')}, E_in = {s.get('E_in_J')}")
        return 0
    row = run_job(job, dict(spec, mode='graph' if args.graph else spec['mode']), gains)
    for k, v in row.items():
        print(f'  {k:22s} {v}')
    return 0


def main(argv=None) -> int:
    from im_common.cli import parse_args
    args = parse_args(build_parser(), argv)
    try:
        spec = read_spec(args.spec)
    except SpecError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    if args.workers is not None and args.workers < 1:
        print(f'error: --workers {args.workers}: must be >= 1', file=sys.stderr)
        return 2
    if args.record and not (args.run is not None and args.graph):
        print('error: --record needs --run INDEX --graph', file=sys.stderr)
        return 2
    try:
        if args.run is not None:
            return _run_alone(spec, args)
        out = args.out or os.path.join('bags', 'campaign', spec['name'])
        s = run_campaign(spec, out, args.spec, workers=args.workers, address=args.address,
                         force=args.force, progress=not args.no_progress)
    except (SpecError, FileExistsError, ConnectionError) as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'\ninterrupted; finished runs are kept in {out}/{JOURNAL}: the same command '
              'resumes the campaign', file=sys.stderr)
        return 130
    for n, g in s['gain_sets'].items():
        print(f"{n:>12s} (T_s = {g['T_s'] * 1e6:g} µs): {g['runs']} runs, {g['unstable']} "
              f"unstable, {g['failed']} failed")
    if 'speedup_vs_one_worker' in s:
        print(f"speed-up vs one worker: ×{s['speedup_vs_one_worker']:.2f}")
    print(f"written: {out}/runs.parquet, {out}/summary.json, {out}/report.md")
    return 0


if __name__ == '__main__':
    sys.exit(main())
