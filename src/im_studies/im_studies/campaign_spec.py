"""
Campaign specs (docs/campaign.md): read, check, draw the motors, name and execute the runs.

Reading and checking a spec, drawing its motors, the runs it names and executing one of them. Every
column of a run's row but ``wall_s`` is a function of (spec, index).
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
from pathlib import Path
import re
import time
from typing import Dict, List, Optional

from im_adapt.adaptation import AdaptationGains
from im_adapt.hook import LockstepAdapter
from im_bringup.config import ADAPTATION
from im_bringup.offline import gain_arguments_from_parameters, Scenario, simulate
from im_bringup.scenario import run_scenario
from im_common.loads import load_file
from im_common.params import load_motor_file, THESIS_MOTOR
from im_common.yamlio import (load_parameters_file, ParametersFileError, read_yaml_file,
                              YamlFileError)
from im_controller.control_law import MODES
from im_controller.design_gains import design_for_scenario
from im_controller.flux import STRATEGIES
from im_controller.gain_design.motor import DEFAULT_BOX, DEFAULT_SIGMA_MIN
from im_controller.profiles import load_profile
from im_observer.speed_observer import POSITION_NEEDS_SENSOR
import numpy as np

from .campaign_pool import one_line
from .commission_sim import COMPARED, identification_errors, with_ratings

SPEC_KEYS = ('name', 'seed', 'draws', 'motor', 'box', 'sigma_min', 'tasks', 'strategies',
             'controllers',
             'gain_sets', 'loads', 'profiles', 'duration', 'mode', 'map', 'worst',
             'speedup_runs', 'commission', 'sensorless')
#: parameters of the plant's motor a spec may draw (the motor's electrical parameters)
DRAWN = ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr')
#: what the stability map may be drawn over: a drawn parameter, σ or σL_s
MAP_AXES = DRAWN + ('sigma', 'sigma_L_s')
#: controllers a campaign (and the chapter-4 study) runs: the nominal one and every adaptive one
#: (im_bringup.config.ADAPTATION: the adapter's law and feed); robust has its own study
NOMINAL_AND_ADAPTIVE = ('nominal',) + tuple(ADAPTATION)
STATUSES = ('ok', 'tripped', 'diverged', 'failed')
UNSTABLE = ('tripped', 'diverged')
FIGURES = ('pos_err_max_rad', 'pos_err_rms_rad', 'speed_err_max_rad_s', 'speed_err_rms_rad_s',
           'torque_err_max_Nm', 'E_in_J', 'E_loss_J', 'E_copper_J', 'E_core_J', 'i_max_A',
           'V_max_V', 'balance_relative')


class SpecError(ValueError):
    """A spec that cannot be run; the message is one line naming the key and the file."""


# ---------------------------------------------------------------------------------------- spec
def default_box() -> Dict[str, list]:
    """Return the chapter-4 box the robust gains are certified over (im_controller.gain_design)."""
    return {k: list(v) for k, v in DEFAULT_BOX.items()}


def _default_sigma_min() -> float:
    return DEFAULT_SIGMA_MIN


def _resolve(path: str, base: Path) -> str:
    """
    Resolve a file named in a spec.

    It is absolute, or relative to the spec's folder, or a shipped file of
    ``im_bringup``/``im_common`` (``config/...``).
    """
    p = Path(os.path.expanduser(path))
    if p.is_absolute():
        return str(p)
    if (base / p).exists():
        return str((base / p).resolve())
    for pkg in ('im_bringup', 'im_common'):
        try:    # heavy: ament_index_python, only for a shipped file named in a spec
            from ament_index_python.packages import get_package_share_directory
            q = Path(get_package_share_directory(pkg)) / p
        except Exception:   # package not installed in this environment: try the next one
            continue
        if q.exists():
            return str(q)
    return str((base / p).resolve())


def _distribution(name: str, value, where: str) -> dict:
    """
    Check a box entry and return it as a dict with its ``kind``.

    The forms are {'kind': 'uniform', 'lo', 'hi'} / {'kind': 'normal', 'mean', 'std', 'lo', 'hi'} /
    {'kind': 'fixed', 'value'}.
    """
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
        raise SpecError(f'{where}: box.{name}: unknown key {sorted(extra, key=str)[0]!r}')
    if not 0 < d['lo'] <= d['hi']:
        raise SpecError(f'{where}: box.{name} range [{d["lo"]:g}, {d["hi"]:g}] must be positive '
                        'and increasing')
    return d


def _gain_set(entry, i: int, where: str, base: Path) -> dict:
    if not isinstance(entry, dict):
        raise SpecError(f'{where}: gain_sets[{i}] = {entry!r}: give {{name, gains, T_s}}')
    unknown = set(entry) - {'name', 'gains', 'T_s'}
    if unknown:
        raise SpecError(f'{where}: gain_sets[{i}]: unknown key {sorted(unknown, key=str)[0]!r} '
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
        for n, p in _gains_file(path).items():      # designed for this set's period
            period = p.get('gain_period')
            if period is not None and not (isinstance(period, (int, float))
                                           and abs(float(period) - g['T_s']) <= 1e-12):
                raise SpecError(f'{where}: gain_sets[{i}].T_s = {T_s!r}: its gains file {path} '
                                f'was designed for another period ({n}.gain_period = '
                                f'{period!r} s)')
    else:
        raise SpecError(f'{where}: gain_sets[{i}].gains = {gains!r}: thesis, certified or a '
                        'gains file (design_gains --out)')
    return g


def _gains_file(path: str) -> Dict[str, dict]:
    """Return ``{'controller': {...}, 'observer': {...}}`` of a gains file (design_gains --out)."""
    params: dict = {'controller': {}, 'observer': {}}
    try:
        for node, values in load_parameters_file(path, nodes=params).items():
            params[node].update(values)
    except ParametersFileError as exc:
        raise SpecError(str(exc)) from None
    return params


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
    """Return the spec, every default filled in and every value checked (one-line SpecError)."""
    base = Path(base or '.')
    if not isinstance(raw, dict):
        raise SpecError(f'{where}: a campaign spec is a mapping of {", ".join(SPEC_KEYS)}')
    unknown = set(raw) - set(SPEC_KEYS)
    if unknown:
        raise SpecError(f'{where}: unknown key {sorted(unknown, key=str)[0]!r} (one of '
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
    for key, allowed, default in (('tasks', MODES, ['position']),
                                  ('strategies', STRATEGIES, ['min_energy']),
                                  ('controllers', NOMINAL_AND_ADAPTIVE, ['nominal'])):
        v = raw.get(key, default)
        v = [v] if isinstance(v, str) else v
        if not isinstance(v, list) or not v:
            raise SpecError(f'{where}: {key} = {v!r}: a list, of {", ".join(allowed)}')
        for x in v:
            if x not in allowed:
                raise SpecError(f'{where}: {key}: {x!r} is not one of {", ".join(allowed)}')
        spec[key] = list(v)
    if 'sensorless' in raw:      # the axis: runs with and/or without the measured shaft
        v = raw['sensorless']
        v = [v] if isinstance(v, bool) else v
        if not isinstance(v, list) or not v or not all(isinstance(x, bool) for x in v):
            raise SpecError(f'{where}: sensorless = {v!r}: a list of true/false')
        if True in v and 'position' in spec['tasks']:
            raise SpecError(f'{where}: sensorless: {POSITION_NEEDS_SENSOR} (tasks has position)')
        spec['sensorless'] = list(dict.fromkeys(v))
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
    spec.update(commission_spec(raw, where))
    return spec


def read_spec(path: str) -> dict:
    """Read and normalize a spec file (SpecError naming the file on any problem)."""
    try:
        raw = read_yaml_file(path, 'campaign spec')
    except YamlFileError as exc:
        raise SpecError(str(exc)) from None
    return normalize_spec(raw, where=str(path), base=Path(path).resolve().parent)


def spec_hash(spec: dict) -> str:
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


# ---------------------------------------------------------------------------------------- jobs
def base_motor(spec: dict):
    return THESIS_MOTOR if spec['motor'] == 'thesis' else load_motor_file(spec['motor'])


def draw(spec: dict, d: int) -> Dict[str, float]:
    """Motor parameters of draw ``d``: a function of (seed, d) only (rejection of σ < σ_min)."""
    base = base_motor(spec)
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
    out = []
    for d in range(spec['draws']):
        motor = draw(spec, d)
        for task, strategy, controller, g, load, profile, sensorless in itertools.product(
                spec['tasks'], spec['strategies'], spec['controllers'], spec['gain_sets'],
                spec['loads'], spec['profiles'], spec.get('sensorless', [False])):
            out.append({'index': len(out), 'draw': d, 'task': task, 'strategy': strategy,
                        'controller': controller, 'gain_set': g['name'], 'T_s': g['T_s'],
                        'load': load, 'profile': profile, 'sensorless': sensorless, **motor})
    return out + commission_jobs(spec, len(out))


def gain_arguments(spec: dict) -> Dict[str, dict]:
    """
    Return the node-parameter overrides of each gain set.

    Overrides are ({'controller': {...}, 'observer': {...}}) — empty for the thesis's gains,
    designed at T_s for 'certified', read from a gains file.
    """
    out = {}
    for g in spec['gain_sets']:
        if g['gains'] == 'thesis':
            out[g['name']] = {}
        elif g['gains'] == 'certified':
            out[g['name']] = design_for_scenario(g['T_s'])
        else:               # its gain_period checked against T_s by normalize_spec
            out[g['name']] = _gains_file(g['gains'])
    return out


def scenario_for(job: dict, spec: dict, gains: dict):
    """Return the offline :class:`~im_bringup.offline.Scenario` of one job."""
    base = base_motor(spec)
    motor = base.with_values(**{k: job[k] for k in DRAWN})
    kw = gain_arguments_from_parameters(gains[job['gain_set']])
    if job.get('sensorless'):   # the controller orients on the observed flux (docs/sensorless.md)
        kw['controller_options'] = dict(kw.get('controller_options', {}), sensorless=True)
    return Scenario(task=job['task'], strategy=job['strategy'], T_s=job['T_s'],
                    controller=job['controller'],
                    duration=spec['duration'], motor=motor, estimates=base,
                    load_model=None if job['load'] == 'task' else load_file(job['load']),
                    profile=None if job['profile'] == 'task' else load_profile(job['profile']),
                    sensorless=bool(job.get('sensorless')), **kw)


def adapter_for(job: dict, spec: dict):
    """
    Return the offline loop's adapter hook of an adaptive job (None for the nominal controller).

    The adapter starts from the nominal motor, like the controller and observer.
    """
    if job['controller'] == 'nominal':
        return None
    return LockstepAdapter.build(base_motor(spec),
                                 AdaptationGains(**ADAPTATION[job['controller']]),
                                 sensorless=bool(job.get('sensorless')))


def graph_scenario(job: dict, spec: dict, gains: dict):
    """
    Return the run of one job on the ROS graph (the same run as :func:`scenario_for`).

    The gains as the designed node parameters ({node: {parameter: value}}), merged last.
    """
    base = base_motor(spec)
    return Scenario(task=job['task'], strategy=job['strategy'], controller=job['controller'],
                    T_s=job['T_s'], duration=spec['duration'],
                    motor=base.with_values(**{k: job[k] for k in DRAWN}), estimates=base,
                    load_model=None if job['load'] == 'task' else job['load'],
                    profile=None if job['profile'] == 'task' else job['profile'],
                    sensorless=bool(job.get('sensorless')), gains=gains[job['gain_set']])


def run_job(job: dict, spec: dict, gains: dict, alone: bool = False) -> dict:
    """
    Execute one run; never raises: the row says ok / tripped / diverged / failed.

    A graph run of the pool is on domain 150 + index mod 80 (its concurrent graphs never share
    one); ``alone`` (``campaign --run``), on ``ROS_DOMAIN_ID`` as every ROS 2 tool.
    """
    if job['task'] == COMMISSION_TASK:
        return commission_row(job, spec)
    row = dict(job)
    row['sigma'] = 1.0 - job['L_sr'] ** 2 / (job['L_s'] * job['L_r'])
    row['sigma_L_s'] = row['sigma'] * job['L_s']     # the current loop's inductance
    for k in FIGURES:
        row[k] = float('nan')
    row.update(status='failed', trip='', t_end_s=float('nan'), error='')
    t0 = time.perf_counter()
    try:
        if spec['mode'] == 'graph':
            s = run_scenario(graph_scenario(job, spec, gains), progress=False,
                             domain_id=None if alone else 150 + job['index'] % 80)
            s.pop('_run', None)
            if not s.get('ok', True) and not s.get('trip'):
                raise RuntimeError('; '.join(str(v) for v in (s.get('failures') or {}).values()))
        else:
            s = simulate(scenario_for(job, spec, gains), adapter=adapter_for(job, spec)).summary
    except (FloatingPointError, OverflowError) as exc:
        m = re.search(r't = ([0-9.eE+-]+)', str(exc))
        row.update(status='diverged', error=one_line(exc),
                   t_end_s=float(m.group(1)) if m else float('nan'))
    except Exception as exc:   # a failed run is a row of the campaign, never its end
        row.update(status='failed', error=one_line(exc))
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


# ------------------------------------------------------------------------ commissioning axis
#: the task name of a commissioning job (one per draw, after the runs: ``commission: true``)
COMMISSION_TASK = 'commission'
#: default current noise [A per 8.487 A of rated current] of the commissioning axis
COMMISSION_NOISE = 0.05


def commission_spec(raw: dict, where: str) -> dict:
    """
    ``commission``: absent / false (no commissioning), true, or ``{noise: A}``.

    Each draw is commissioned on the ROS-free plant (docs/commissioning.md §6) with that
    current noise [A per 8.487 A of rated current]. Only a commissioning spec carries the key,
    so the hash of every other spec (and a campaign folder's resumption) is unchanged.
    """
    v = raw.get('commission', False)
    if v is False or v is None:
        return {}
    if v is True:
        v = {}
    if not isinstance(v, dict) or set(v) - {'noise'}:
        raise SpecError(f'{where}: commission = {v!r}: true, false or {{noise: A}}')
    noise = v.get('noise', COMMISSION_NOISE)
    if isinstance(noise, bool) or not isinstance(noise, (int, float)) or not (
            math.isfinite(noise) and noise >= 0):
        raise SpecError(f'{where}: commission.noise = {noise!r} must be a current >= 0 A')
    return {'commission': {'noise': float(noise)}}


def commission_jobs(spec: dict, start: int) -> List[dict]:
    """One commissioning job per draw, numbered from ``start`` (after every run)."""
    if not spec.get('commission'):
        return []
    return [{'index': start + d, 'draw': d, 'task': COMMISSION_TASK, 'strategy': '',
             'controller': '', 'gain_set': '', 'T_s': 1e-4, 'load': '', 'profile': '',
             **draw(spec, d)} for d in range(spec['draws'])]


def commission_row(job: dict, spec: dict) -> dict:
    """
    Commission the drawn motor as ``commission_study`` does; return the job's row.

    Limits: the motor's ratings, else the thesis motor's. The row holds each parameter's error
    against the draw and its reported standard deviation [%]. Never raises: a refusal is a
    ``failed`` row saying why.
    """
    row = dict(job)
    row['sigma'] = 1.0 - job['L_sr'] ** 2 / (job['L_s'] * job['L_r'])
    row['sigma_L_s'] = row['sigma'] * job['L_s']
    for k in FIGURES:
        row[k] = float('nan')
    for n in COMPARED:
        row[n + '_err_pct'] = row[n + '_std_pct'] = float('nan')
    row.update(status='failed', trip='', t_end_s=float('nan'), error='')
    t0 = time.perf_counter()
    try:
        motor = with_ratings(base_motor(spec)).with_values(**{k: job[k] for k in DRAWN})
        com, _, errors = identification_errors(motor, spec['commission']['noise'],
                                               seed=job['draw'])
    except Exception as exc:   # NotInformative and anything else: a row, never the end
        row['error'] = one_line(exc)
    else:
        row.update(errors, status='ok', t_end_s=com.k * com.T_s)
    row['wall_s'] = time.perf_counter() - t0
    return row
