"""
Where a lock-step step of the in-process graph spends its time (cProfile, no ROS-side tools).

The issue's scenario (position task, min_loss, nominal controller, the summary tap that
``scenario`` folds every message into) runs once unprofiled (steps/s) and once under cProfile.
Each profiled Python function's own time is put into one category; a built-in (``struct``,
``hashlib``, rclpy's C++ ``publish`` ...) goes to the category of the Python code that called it,
split as cProfile saw the calls:

* ``decode``: the input extractors (``im_common.conversions.*_in``, ``cdr.decode_*``);
* ``tags``: signing and checking the message tags (``im_common.auth``);
* ``protocol``: the step gate, the input callback, the run protocol (``im_common.lockstep``) and
  the node shells' own lines (``*_node.py``);
* ``compute``: the model, control law, observer and adaptation (everything ROS-free);
* ``publish``: packing outputs (``cdr.pack_*``, ``conversions.*Out``) and rclpy's ``publish``;
* ``tap``: the scenario's summary tap (``im_recording.traces`` / ``run``);
* ``executor``: the native spin's own time — rclpy's executor and DDS in C++.

Figures are µs per step under the profiler (which inflates Python calls, so the shares matter,
not the sum), plus per node the time inside its step (``ready``) and its input callbacks'
share of the inputs it takes.
"""
from __future__ import annotations

import cProfile
import os
import pstats
import sys
import time

CATEGORIES = ('decode', 'tags', 'protocol', 'compute', 'publish', 'tap', 'executor', 'other')
NODE_FILES = {'plant_node.py': 'plant', 'controller_node.py': 'controller',
              'observer_node.py': 'observer', 'adapter_node.py': 'adapter'}
#: The run protocol's code on the step's path: the node adapter, its input path, the roles.
PROTOCOL_FILES = ('lockstep.py', 'lockstep_parts.py', 'lockstep_protocol.py')


def category(func) -> str:
    """Category of a Python function (file, line, name); '' for a built-in."""
    path, _line, name = func
    if path == '~' and 'spin' in name:
        return 'executor'           # the native spin's own time: rclpy's executor and DDS in C++
    if path == '~' or path.startswith('<'):
        return ''
    base = os.path.basename(path)
    if base == 'auth.py':
        return 'tags'
    if base == 'conversions.py':
        return 'decode' if name.endswith('_in') or name == 'named_values' else 'publish'
    if base == 'cdr.py':
        return 'decode' if name.startswith('decode') or name.startswith('_decode') else 'publish'
    if base == 'params.py' and name == 'estimate_arguments':
        return 'decode'
    if base in PROTOCOL_FILES or base in NODE_FILES:
        return 'protocol'
    if os.sep + 'rclpy' + os.sep in path:
        return 'publish' if base == 'publisher.py' else 'other'
    if base in ('traces.py', 'run.py', 'bag.py', 'report.py') or name == 'tapped':
        return 'tap'
    computing = ('im_plant', 'im_controller', 'im_observer', 'im_adapt', 'im_common')
    if any(f'{os.sep}{p}{os.sep}' in path for p in computing):
        return 'compute'
    return 'other'


def breakdown(stats: pstats.Stats) -> dict:
    """Own time per category [s]; built-ins split among their callers' categories."""
    raw = stats.stats
    out = dict.fromkeys(CATEGORIES, 0.0)

    def cat_of(func, depth=0):
        c = category(func)
        if c or depth > 3:
            return c or 'other'
        callers = raw.get(func, (0, 0, 0, 0, {}))[4]
        best = max(callers.items(), key=lambda kv: kv[1][2], default=None)
        return cat_of(best[0], depth + 1) if best else 'other'

    for func, (_cc, _nc, tt, _ct, callers) in raw.items():
        c = category(func)
        if c:
            out[c] += tt
            continue
        total = sum(v[2] for v in callers.values())
        if total <= 0:
            out['other'] += tt
            continue
        for caller, v in callers.items():
            out[cat_of(caller)] += tt * v[2] / total
    return out


#: Each node's step entry point: called once per complete step, inputs to outputs (the shells'
#: ``step``, which LockstepNode.ready calls; the figures keep their ``_ready`` names).
STEP_ENTRY = dict.fromkeys(('plant', 'controller', 'observer', 'adapter'), 'step')


def node_steps(stats: pstats.Stats) -> dict:
    """Cumulative time of each node's step entry point [s] (compute, publish, sign, gate)."""
    out = {}
    for (path, _line, name), (_cc, _nc, _tt, ct, _callers) in stats.stats.items():
        node = NODE_FILES.get(os.path.basename(path))
        if node and name == STEP_ENTRY[node]:
            out[node] = out.get(node, 0.0) + ct
    return out


def _graph(duration: float):
    from im_bringup.config import node_parameters
    from im_bringup.graph import DriveGraph
    from im_recording.traces import Tap
    params = node_parameters('position', 'min_loss', 'nominal', 'none', 1e-4, duration)
    return DriveGraph(params, recorder=Tap(keep=False))


def run(quick: bool = False) -> dict:
    d = 0.05 if quick else 1.0
    g = _graph(d)
    try:
        plain = g.run()
    finally:
        g.close()
    g = _graph(d)
    prof = cProfile.Profile()
    dump = os.environ.get('BENCH_PROFILE_DUMP')     # a file for pstats, to look further
    try:
        t0 = time.perf_counter()
        prof.enable()
        stats_run = g.run()
        prof.disable()
        wall = time.perf_counter() - t0
    finally:
        g.close()
    if not (plain['ok'] and stats_run['ok']):
        raise RuntimeError(f'graph run failed: {plain["failures"] or stats_run["failures"]}')
    n = stats_run['steps']
    if dump:
        prof.dump_stats(dump)
    st = pstats.Stats(prof, stream=sys.stderr)
    cats = breakdown(st)
    res = {'steps_per_s_unprofiled': plain['steps_per_s'],
           'steps_per_s_profiled': n / wall,
           'us_per_step_profiled': 1e6 * wall / n}
    cats['executor'] += max(wall - sum(cats.values()), 0.0)    # outside any profiled call
    for c in CATEGORIES:
        res[f'us_per_step_{c}'] = 1e6 * cats[c] / n
    for c in CATEGORIES:
        res[f'share_{c}'] = res[f'us_per_step_{c}'] / res['us_per_step_profiled']
    for node, ct in sorted(node_steps(st).items()):
        res[f'us_per_step_{node}_ready'] = 1e6 * ct / n
    if not quick:
        print('top 25 functions by own time (profiled run):', file=sys.stderr)
        st.sort_stats('tottime').print_stats(25)
    return res


if __name__ == '__main__':      # the table and JSON come from the driver
    from run_all import main
    sys.exit(main(['--only', 'profile'] + sys.argv[1:]))
