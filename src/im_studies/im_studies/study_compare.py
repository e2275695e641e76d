"""
The thesis law beside the drive industry's: every law × flux strategy on the same drive.

``python -m im_studies.study_compare`` (in ``make study``; docs/baselines.md) runs the thesis's
position and speed tasks and a load step of half the rated torque (100 rad/s, 1/6 → 2/3 of the
rated torque at 0.5 s, sensored) on the thesis motor's file, for each control law — the thesis's
(``nominal``), the current-vector controller, the flux-vector controller and observer-based V/Hz
(speed and load step only: it sets a frequency) — with each flux strategy of
:data:`STRATEGIES`, on two plants:

* ``ideal``: the ideal voltage source, no delay;
* ``real, delay 1``: the switched inverter (10 kHz, 2 µs dead time, 1 V + 20 mΩ devices, a
  700 V DC link: the speed task's 447 V vector fits), one period of computational delay, the
  motor's saturation, thermal networks and core loss, an encoder and 12-bit current ADCs;

each with the motor as the model has it and under the chapter-4 drift (``variation:
chapter4``: on the real plant, which varies no inductance, its rotor-resistance ramp alone,
R_r = 0.42 + 0.42 t Ω; the model keeps its nominal values). Every law has the same current
limit, :data:`CURRENT_LIMIT` (the thesis tasks need more than the motor's rated current), within
the motor file's overcurrent trip, and no voltage limit but the inverter's. The figures are the
run summary's: tracking error (position: max, RMS; speed and load step: max, RMS, the dip after
the step and its recovery), the motor's losses and the input energy, the peak current. The
verdict table names, per plant, drift, task and strategy, the law with the lowest losses and the
one with the lowest tracking error.

The drive check (``--part check``, :func:`check_cases`) runs every law on both shipped motors
(:data:`CHECK_MOTORS`) on the real plant with one period of delay and the inverter-error
compensation, sensored and sensorless, ``constant_flux`` and ``min_loss``: the speed task (the
thesis motor's, or a motor's rated-speed reversal) and the load step; its table adds each run's
speed error RMS over the thesis law's in the same run and the energy drawn from the DC link, and
its verdict line counts the trips and the PI laws' runs within 2× the thesis law's error.
``--quick`` runs each case for :data:`QUICK_DURATION` s.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import time
from typing import Callable, Optional

from im_bringup.offline import Scenario, simulate
from im_common.cli import error as cli_error
from im_common.inverter import Inverter
from im_common.loads import StepLoad
from im_common.metrics import LOAD_STEP_BAND
from im_common.params import CHAPTER4_VARIATION, load_motor_file, shipped_motors_dir
from im_controller.control_law import THESIS_LAW_GAINS
from im_controller.flux import COMPARED_STRATEGIES
from im_controller.profiles import Profile
from im_plant.sensors import Sensors
from im_recording.plots import pyplot
import numpy as np

from .study_motors import scaled_options, scaled_scenario
from .study_real_plant import INVERTER, real_plant, STEP_AFTER, STEP_BEFORE, STEP_DURATION, \
    STEP_SPEED, STEP_T

#: the laws compared (the run file's controller: the thesis's at nominal estimates, then the
#: baselines, docs/baselines.md)
LAWS = ('nominal', 'current_vector', 'flux_vector', 'vhz')
STRATEGIES = COMPARED_STRATEGIES
TASKS = ('position', 'speed', 'load_step')
PLANTS = ('ideal', 'real, delay 1')
DRIFTS = ('none', 'chapter4')
#: the real plant's DC link [V]: the thesis speed task's 447 V vector within the hexagon
V_DC = 700.0
#: every law's current limit [A]: above the thesis tasks' peaks (22.4 A at most), within the
#: motor file's 25.5 A overcurrent trip
CURRENT_LIMIT = 22.5
MOTOR = 'thesis'


#: the drive check (docs/comparison.md §2): both shipped motors on the real plant with one
#: period of delay and the inverter-error compensation, every law sensored and sensorless
CHECK_MOTORS = ('thesis', 'krause_3hp')
CHECK_TASKS = ('speed', 'load_step')
CHECK_STRATEGIES = ('constant_flux', 'min_loss')
SENSING = ('sensored', 'sensorless')
#: --quick: every run this long [s]
QUICK_DURATION = 0.3
PARTS = ('compare', 'check')


def motor_path(name: str = MOTOR) -> str:
    return os.path.join(shipped_motors_dir(), f'{name}.yaml')


def plant_keywords(plant: str) -> dict:
    """Return the Scenario keywords of a plant of :data:`PLANTS`."""
    if plant == 'ideal':
        return {}
    m = load_motor_file(motor_path())
    return {'inverter': Inverter.from_block(dict(INVERTER, V_dc=V_DC, delay=1)),
            'saturation': 'motor', 'thermal': 'motor', 'iron_loss': True,
            'sensors': Sensors.from_block({'encoder_lines': 2048, 'adc_bits': 12,
                                           'current_range': float(math.ceil(
                                               5.0 * math.sqrt(2.0) * m.rated_current))})}


def scenario(law: str, strategy: str, task: str, plant: str, drift: str,
             duration: Optional[float] = None) -> Scenario:
    """Return one run of the comparison (``duration``: shorter, for a quick look)."""
    if drift == 'chapter4' and plant != 'ideal':    # the real plant varies no inductance
        drift = {'R_r': CHAPTER4_VARIATION['R_r']}
    kw = dict(plant_keywords(plant), controller=law, strategy=strategy, motor=motor_path(),
              variation=drift, current_limit=CURRENT_LIMIT, v_limit=0, duration=duration)
    if task != 'load_step':
        return Scenario(task=task, **kw)
    m = load_motor_file(motor_path())
    prof = Profile('speed', ((0.0, STEP_SPEED, None),), source='load step')
    load = StepLoad(t=STEP_T, tau_before=STEP_BEFORE * m.rated_torque,
                    tau_after=STEP_AFTER * m.rated_torque)
    kw['duration'] = duration or STEP_DURATION
    return Scenario(task='speed', profile=prof, load_model=load, omega0=STEP_SPEED, **kw)


def check_scenario(motor: str, law: str, strategy: str, task: str, sensing: str,
                   duration: Optional[float] = None) -> Scenario:
    """
    Return one run of the drive check (``motor``: a name of :data:`CHECK_MOTORS`).

    The real plant with one period of delay and ``compensation: inverter``, sensored or
    sensorless. The thesis motor runs the comparison's tasks on its 700 V link; another motor
    its rated-speed reversal (:func:`im_studies.study_motors.scaled_scenario`) or the same load
    step (100 rad/s, 1/6 → 2/3 of its rated torque) on the link for its rating, with the
    rating-scaled flux and limits (a 2× overload current limit) and, for the thesis law, the
    rating-scaled gains.
    """
    sensorless = sensing == 'sensorless'
    if motor == MOTOR:
        base = scenario(law, strategy, task, 'real, delay 1', 'none', duration)
        return dataclasses.replace(base, compensation='inverter', sensorless=sensorless)
    m = load_motor_file(motor_path(motor))
    opts = {k: v for k, v in scaled_options(m, 'speed').items()    # a baseline: its own gains
            if law == 'nominal' or k not in THESIS_LAW_GAINS}
    kw = dict(real_plant(m, delay=1), motor=motor_path(motor), controller=law,
              controller_options=opts, compensation='inverter', sensorless=sensorless)
    if task == 'speed':
        base = scaled_scenario(m, 'speed', strategy)
        return dataclasses.replace(base, duration=duration or base.duration, **kw)
    prof = Profile('speed', ((0.0, STEP_SPEED, None),), source='load step')
    load = StepLoad(t=STEP_T, tau_before=STEP_BEFORE * m.rated_torque,
                    tau_after=STEP_AFTER * m.rated_torque)
    return Scenario(task='speed', strategy=strategy, profile=prof, load_model=load,
                    omega0=STEP_SPEED, duration=duration or STEP_DURATION,
                    v_limit=m.rated_voltage, **kw)


def check_cases(motors=CHECK_MOTORS, tasks=CHECK_TASKS, strategies=CHECK_STRATEGIES,
                laws=LAWS):
    """Yield (motor, law, strategy, task, sensing) of every run of the drive check."""
    for motor in motors:
        for task in tasks:
            for strategy in strategies:
                for law in laws:
                    for sensing in SENSING:
                        yield motor, law, strategy, task, sensing


def cases(tasks=TASKS, plants=PLANTS, drifts=DRIFTS, laws=LAWS, strategies=STRATEGIES):
    """Yield (law, strategy, task, plant, drift) of every run (V/Hz: no position task)."""
    for plant in plants:
        for drift in drifts:
            for task in tasks:
                for strategy in strategies:
                    for law in laws:
                        if law == 'vhz' and task == 'position':
                            continue
                        yield law, strategy, task, plant, drift


def _trip(trip) -> str:
    """Return a run's protection trip as text ('' if none)."""
    if not trip:
        return ''
    if isinstance(trip, dict):
        return f"at {trip['t']:.3f} s, {trip['reason']}"
    return str(trip)


def figures(summary: dict, task: str) -> dict:
    """Return a run's figures of merit (SI; position errors in rad)."""
    key = 'pos' if task == 'position' else 'speed'
    unit = 'rad' if task == 'position' else 'rad_s'
    out = {'err_max': summary[f'{key}_err_max_{unit}'],
           'err_rms': summary[f'{key}_err_rms_{unit}'],
           'E_loss_J': summary['E_loss_J'], 'E_in_J': summary['E_in_J'],
           'E_dc_J': summary.get('E_dc_J'),
           'i_max_A': summary['i_max_A'], 'V_max_V': summary['V_max_V'],
           'trip': _trip(summary.get('trip'))}
    if task == 'load_step':
        out.update(dip=summary.get('speed_dip_rad_s'), recovery_s=summary.get('speed_recovery_s'))
    return out


def _run_cases(todo: list, fields: tuple, build: Callable, progress, duration) -> list:
    """Run each case (a tuple of ``fields``, ``build``'s arguments); return its figures' rows."""
    rows = []
    t0 = time.monotonic()
    for n, case in enumerate(todo, 1):
        row = dict(zip(fields, case))
        row.update(figures(simulate(build(*case, duration)).summary, row['task']))
        rows.append(row)
        progress(f'  [{n}/{len(todo)} {time.monotonic() - t0:5.0f} s] {", ".join(case)}: error '
                 f'max {row["err_max"]:.4g}, RMS {row["err_rms"]:.4g}, losses '
                 f'{row["E_loss_J"]:.4g} J' + (f', trip {row["trip"]}' if row['trip'] else ''))
    return rows


def run_rows(progress: Callable[[str], None] = lambda line: None, duration=None,
             **selection) -> list:
    """Run every case of :func:`cases` (``selection``: its keywords); return the rows."""
    return _run_cases(list(cases(**selection)), ('law', 'strategy', 'task', 'plant', 'drift'),
                      scenario, progress, duration)


def run_check_rows(progress: Callable[[str], None] = lambda line: None, duration=None,
                   **selection) -> list:
    """Run every case of :func:`check_cases` (``selection``: its keywords); return the rows."""
    return _run_cases(list(check_cases(**selection)),
                      ('motor', 'law', 'strategy', 'task', 'sensing'), check_scenario, progress,
                      duration)


def rms_over_thesis(rows: list) -> dict:
    """
    Return {id(row): its speed error RMS over the thesis law's} for the drive check's rows.

    The thesis law's row is the one of the same motor, task, strategy and sensing; None where it
    or the row tripped.
    """
    thesis = {(r['motor'], r['task'], r['strategy'], r['sensing']): r for r in rows
              if r['law'] == 'nominal'}
    out = {}
    for r in rows:
        t = thesis.get((r['motor'], r['task'], r['strategy'], r['sensing']))
        out[id(r)] = (None if t is None or t['trip'] or r['trip'] or not t['err_rms'] > 0
                      else r['err_rms'] / t['err_rms'])
    return out


def check_markdown(rows: list) -> str:
    """Return the drive check's rows as a Markdown table and its verdict as one line."""
    ratio = rms_over_thesis(rows)
    out = ['| motor | task | strategy | law | sensing | speed error max / RMS | RMS / thesis '
           'law | losses [J] | DC link [J] | peak current [A] |',
           '|---|---|---|---|---|---|---:|---:|---:|---:|']
    for r in rows:
        q = ratio[id(r)]
        out.append(f"| {r['motor']} | {r['task']} | {r['strategy']} | {r['law']} | "
                   f"{r['sensing']} | {_err(r)} | {'' if q is None else f'{q:.3g}'} | "
                   f"{r['E_loss_J']:.4g} | {_dc(r)} | "
                   f"{r['i_max_A']:.3g} |")
    trips = [r for r in rows if r['trip']]
    pi = [r for r in rows if r['law'] in ('current_vector', 'flux_vector')]
    worse = [r for r in pi if ratio[id(r)] is None or ratio[id(r)] > 2.0]

    def names(rs):
        return '; '.join(f"{r['motor']} {r['task']} {r['strategy']} {r['law']} {r['sensing']}"
                         for r in rs)
    out += ['', f'{len(rows)} runs, {len(trips)} tripped'
            + (f' ({names(trips)})' if trips else '')
            + "; the current- and flux-vector controllers' speed error RMS within 2× the thesis "
            f"law's in {len(pi) - len(worse)} of {len(pi)} runs"
            + (f' (beyond: {names(worse)})' if worse else '') + '.']
    return '\n'.join(out)


def _key(r) -> tuple:
    return r['plant'], r['drift'], r['task'], r['strategy']


def verdicts(rows: list) -> list:
    """Return, per plant, drift, task and strategy, the lowest-loss and lowest-error laws."""
    groups = {}
    for r in rows:
        if not r['trip']:
            groups.setdefault(_key(r), []).append(r)
    out = []
    for key, rs in groups.items():
        best_loss = min(rs, key=lambda r: r['E_loss_J'])
        best_err = min(rs, key=lambda r: r['err_max'])
        thesis = next((r for r in rs if r['law'] == 'nominal'), None)
        out.append(dict(zip(('plant', 'drift', 'task', 'strategy'), key),
                        lowest_loss=best_loss['law'], lowest_error=best_err['law'],
                        thesis_loss_ratio=None if thesis is None else
                        thesis['E_loss_J'] / best_loss['E_loss_J'],
                        thesis_error_ratio=None if thesis is None or best_err['err_max'] == 0
                        else thesis['err_max'] / best_err['err_max']))
    return out


def _err(r) -> str:
    if r['trip']:
        return f"trip {r['trip']}"
    if r['task'] == 'position':
        return f"{r['err_max'] * 1e3:.3g} / {r['err_rms'] * 1e3:.3g} mrad"
    text = f"{r['err_max']:.3g} / {r['err_rms']:.3g} rad/s"
    if r['task'] == 'load_step' and r.get('dip') is not None and math.isfinite(r['dip']):
        rec = r.get('recovery_s')
        back = ('not back' if rec is None or not math.isfinite(rec) else
                'never out' if rec == 0 else f'back in {rec * 1e3:.0f} ms')
        text += f"; dip {r['dip']:.3g} ({back}, ±{LOAD_STEP_BAND:g} rad/s)"
    return text


def _dc(r) -> str:
    """Return a row's DC-link energy as text ('—' on the ideal source, which has no link)."""
    return '—' if r.get('E_dc_J') is None else f"{r['E_dc_J']:.4g}"


def markdown(rows: list) -> str:
    """Return the rows and the verdicts as Markdown tables."""
    out = ['| plant | drift | task | strategy | law | error max / RMS | losses [J] | '
           'input [J] | DC link [J] | peak current [A] | peak voltage [V] |',
           '|---|---|---|---|---|---|---:|---:|---:|---:|---:|']
    for r in rows:
        out.append(f"| {r['plant']} | {r['drift']} | {r['task']} | {r['strategy']} | "
                   f"{r['law']} | {_err(r)} | {r['E_loss_J']:.4g} | {r['E_in_J']:.4g} | "
                   f"{_dc(r)} | {r['i_max_A']:.3g} | {r.get('V_max_V', math.nan):.4g} |")
    out += ['', '| plant | drift | task | strategy | lowest losses | thesis / lowest | lowest '
                'error | thesis / lowest |', '|---|---|---|---|---|---:|---|---:|']
    for v in verdicts(rows):
        ratio = ('thesis trips' if v['thesis_loss_ratio'] is None
                 else f"{v['thesis_loss_ratio']:.3f}")
        eratio = ('thesis trips' if v['thesis_error_ratio'] is None
                  else f"{v['thesis_error_ratio']:.3g}")
        out.append(f"| {v['plant']} | {v['drift']} | {v['task']} | {v['strategy']} | "
                   f"{v['lowest_loss']} | {ratio} | {v['lowest_error']} | {eratio} |")
    return '\n'.join(out)


def plot(rows: list, path: str) -> None:
    """Losses and tracking errors of every law × strategy, one row of panels per task."""
    plt = pyplot()
    tasks = [t for t in TASKS if any(r['task'] == t for r in rows)]
    plants = [p for p in PLANTS if any(r['plant'] == p for r in rows)]
    fig, axes = plt.subplots(len(tasks), 2, figsize=(11, 3.2 * len(tasks)), squeeze=False)
    width = 0.8 / (len(LAWS) * len(plants))
    for i, task in enumerate(tasks):
        for j, (field, label) in enumerate((('E_loss_J', 'motor losses [J]'),
                                            ('err_max', 'max tracking error'))):
            ax = axes[i][j]
            for p, plant in enumerate(plants):
                for q, law in enumerate(LAWS):
                    vals = [next((r[field] for r in rows if (r['task'], r['plant'], r['law'],
                                                             r['strategy'], r['drift']) ==
                                  (task, plant, law, s, 'none') and not r['trip']), np.nan)
                            for s in STRATEGIES]
                    x = np.arange(len(STRATEGIES)) + (p * len(LAWS) + q - 0.5 * (
                        len(LAWS) * len(plants) - 1)) * width
                    ax.bar(x, vals, width, label=f'{law}, {plant}', color=f'C{q}',
                           hatch='//' if p else None, edgecolor='k', lw=0.3)
            ax.set_xticks(range(len(STRATEGIES)), STRATEGIES)
            unit = ' [rad]' if task == 'position' and j else (' [rad/s]' if j else '')
            ax.set_ylabel(label + unit)
            if j:
                ax.set_yscale('log')
            ax.set_title(f"{task.replace('_', ' ')} (drift: none)")
            ax.grid(True, axis='y', alpha=0.3)
    axes[0][0].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    os.makedirs(os.path.dirname(path) or '.', exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='study_compare', description=__doc__.split('\n\n')[0])
    ap.add_argument('--part', choices=PARTS, action='append', help='compare: the thesis tasks '
                    'on the thesis motor; check: both shipped motors, sensored and sensorless '
                    '(default both; repeatable)')
    ap.add_argument('--task', choices=TASKS, action='append', help='only this task (repeatable; '
                    'the check has speed and load_step)')
    ap.add_argument('--plant', choices=PLANTS, action='append', help='only this plant')
    ap.add_argument('--drift', choices=DRIFTS, action='append', help='only this drift')
    ap.add_argument('--motor', choices=CHECK_MOTORS, action='append',
                    help='the drive check on this motor only')
    ap.add_argument('--quick', action='store_true', help=f'every run {QUICK_DURATION:g} s long '
                    '(a look at the machinery, not the figures)')
    ap.add_argument('--json', metavar='FILE', help='write the rows and verdicts as JSON')
    ap.add_argument('--plot', metavar='PNG', help='draw the losses and errors (drift: none)')
    ap.add_argument('--doc', metavar='MD', help='write the tables into this page, between '
                    '<!-- compare:begin --> and <!-- compare:end --> and between <!-- '
                    'check:begin --> and <!-- check:end --> (docs/comparison.md)')
    ap.add_argument('--from-json', metavar='FILE', help='take the rows of an earlier --json '
                    'instead of running (re-render the tables and the plot)')
    a = ap.parse_args(argv)
    parts = tuple(a.part or PARTS)
    sel = {k: tuple(v) for k, v in (('tasks', a.task), ('plants', a.plant), ('drifts', a.drift))
           if v}
    duration = QUICK_DURATION if a.quick else None
    progress = lambda line: print(line, file=sys.stderr, flush=True)    # noqa: E731
    try:
        if a.from_json:
            rows, check = load_rows(a.from_json), load_check_rows(a.from_json)
        else:
            rows = run_rows(progress, duration, **sel) if 'compare' in parts else []
            csel = {k: v for k, v in (('motors', tuple(a.motor or ())), ('tasks', tuple(
                t for t in a.task or () if t in CHECK_TASKS))) if v}
            if a.task and 'tasks' not in csel:
                parts = tuple(p for p in parts if p != 'check')   # no task of the check's
            check = run_check_rows(progress, duration, **csel) if 'check' in parts else []
        if rows:
            print(markdown(rows))
        if check:
            print(check_markdown(check))
        if a.json:
            os.makedirs(os.path.dirname(a.json) or '.', exist_ok=True)
            with open(a.json, 'w') as f:
                json.dump({'rows': rows, 'verdicts': verdicts(rows), 'check': check}, f, indent=1)
                f.write('\n')
        if a.plot and rows:
            plot(rows, a.plot)
        if a.doc:
            write_doc(a.doc, rows, check)
    except OSError as exc:
        return cli_error('study_compare', f'{exc.filename}: {exc.strerror or exc}')
    except ValueError as exc:       # not a --json of this study; a page without the section
        return cli_error('study_compare', exc)
    return 0


def _load(path: str) -> dict:
    with open(path) as f:
        try:
            doc = json.load(f)
        except json.JSONDecodeError as exc:
            raise ValueError(f'{path}: not JSON ({exc.msg}, line {exc.lineno})') from None
    if not isinstance(doc, dict) or not isinstance(doc.get('rows'), list):
        raise ValueError(f'{path}: not a study_compare --json (no rows)')
    return doc


def load_rows(path: str) -> list:
    """Return the rows of an earlier ``--json`` (ValueError naming the file if it is none)."""
    return _load(path)['rows']


def load_check_rows(path: str) -> list:
    """Return the drive check's rows of an earlier ``--json`` ([] if it ran none)."""
    check = _load(path).get('check', [])
    if not isinstance(check, list):
        raise ValueError(f'{path}: not a study_compare --json (its check is no list)')
    return check


def write_doc(path: str, rows: list, check: list = ()) -> None:
    """
    Write the tables into the page's ``compare`` and ``check`` sections (ValueError: none).

    A part with no rows leaves its section as it is.
    """
    from .docs import replace_section   # heavy: im_studies.docs imports rclpy and the nodes
    with open(path) as f:
        text = f.read()
    try:
        if rows:
            text = replace_section(text, 'compare', markdown(rows))
        if check:
            text = replace_section(text, 'check', check_markdown(check))
    except ValueError as exc:
        raise ValueError(f'{path}: {exc}') from None
    with open(path, 'w') as f:
        f.write(text)


if __name__ == '__main__':
    sys.exit(main())
