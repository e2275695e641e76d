"""
The real plant's cost: every block on against the ideal plant, in the same run (docs/plant.md).

The speed task (min_energy) on the shipped thesis motor file, once with the ideal plant and once
with every block of docs/plant.md on (switched inverter at 10 kHz with dead time, on-state drop
and a DC link with chopper, the motor file's saturation and thermal blocks, the iron loss acting,
encoder and ADC), run interleaved, best of the repeats:

- ``offline_*_steps_per_s``: the ROS-free loop (:func:`im_bringup.offline.simulate`);
- ``graph_*_steps_per_s``: the in-process graph (from the plant's first step, as bench_graph's);
- ``real_plant_over_ideal``: the smaller of the two ratios (real / ideal steps/s), the figure of
  summary.json (target >= 0.9, issue 46: the real plant costing little more than the ideal);
- ``offline_real_reference_steps_per_s``: the ROS-free loop on the real plant with the period's
  pure-Python reference, in the same run, and ``offline_real_compiled_over_reference`` (issue 46:
  at least 2);
- ``c_*``, ``numba_*``: the hot kernel (:func:`im_plant.real_plant_kernel.period`: the
  eigenvalues, the switching intervals and the closed-form integrals of a period) written in C
  (``benchmarks/c_kernel/period.c``), compiled here with ``cc -O2 -shared -fPIC`` into a
  temporary directory and called through ctypes, against numba on the same inputs (the periods
  of a short run with every block on): the compute alone (a loop over the periods inside each,
  ``*_us_per_period``, ``c_over_numba_us``) and one call from Python (``*_call_us``), and the
  largest difference of their results (``c_max_rel_diff``, equal to 1e-12). Benchmark only: the
  product keeps numba. Without a C compiler ``c_kernel_skipped`` says so and the row is skipped.

The real plant's period is compiled (:mod:`im_plant.real_plant_kernel`, numba: the whole period
in one call) unless ``--no-kernel`` (its pure-Python reference path,
``RealPlant.use_kernel = False``). Run
standalone: ``python benchmarks/bench_real_plant.py [--quick] [--no-kernel]`` (prints the figures
as JSON); a first 20-period run compiles the kernel, or loads it from the cache, before the
clock starts (``first_real_run_s``);
``benchmarks/run_all.py --only real_plant`` imports :func:`run`.
"""
from __future__ import annotations

import argparse
import ctypes
import json
import os
import shutil
import subprocess
import tempfile
import time

#: every block on (docs/plant.md): the run-file keys added to the ideal scenario
BLOCKS = {
    'saturation': 'motor', 'thermal': 'motor', 'iron_loss': True,
    'inverter': {'V_dc': 340.0, 'pwm_frequency': 10000.0, 'deadtime': 2.0e-6, 'v_on': 1.0,
                 'r_on': 0.02, 'C_dc': 1.0e-3, 'V_chopper': 400.0, 'R_chopper': 40.0},
    'sensors': {'encoder_lines': 2048, 'adc_bits': 12, 'current_range': 40.0},
}


def scenario(duration: float, real: bool):
    from im_bringup.run_file import Scenario
    from im_common.params import shipped_motors_dir
    motor = os.path.join(shipped_motors_dir(), 'thesis.yaml')
    return Scenario(task='speed', strategy='min_energy', duration=duration, motor=motor,
                    **(BLOCKS if real else {}))


def offline_steps_per_s(duration: float, real: bool) -> float:
    from im_bringup.offline import simulate
    sc = scenario(duration, real)
    t0 = time.perf_counter()
    res = simulate(sc)
    wall = time.perf_counter() - t0
    if res.summary.get('trip'):
        raise RuntimeError(f'run tripped: {res.summary["trip"]}')
    return round(duration / sc.T_s) / wall


def graph_steps_per_s(duration: float, real: bool) -> float:
    from im_bringup.graph import DriveGraph
    from im_recording.traces import Tap
    graph = DriveGraph(scenario(duration, real).node_parameters(), recorder=Tap(None))
    try:
        stats = graph.run()
    finally:
        graph.close()
    if not stats['ok']:
        raise RuntimeError(f'graph run failed: {stats["failures"]}')
    return graph.steps_per_s_running


C_SOURCE = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'c_kernel', 'period.c')
#: period.c's layout: inputs and outputs of one period, events at most
C_NIN, C_NOUT, C_MAX_EV = 30, 21, 10


def _period_calls(duration: float) -> list:
    """Return the arguments of every period kernel call of a short run with every block on."""
    from im_plant import real_plant_kernel
    from im_plant.real_plant import RealPlant
    real_plant_kernel.warm()                    # (its own calls are not the run's)
    calls = []
    compiled = real_plant_kernel.period
    whole = RealPlant._whole_arrays
    use = RealPlant.use_kernel

    def record(*args):
        calls.append(args[:15] + (args[15].copy(),) + args[16:])     # the events: a buffer's
        return compiled(*args)
    real_plant_kernel.period = record
    RealPlant._whole_arrays = lambda self: None     # the partial kernels: period from Python
    RealPlant.use_kernel = True
    try:
        offline_steps_per_s(duration, True)
    finally:
        real_plant_kernel.period = compiled
        RealPlant._whole_arrays = whole
        RealPlant.use_kernel = use
    return calls


def c_versus_numba(duration: float = 0.05, repeats: int = 5) -> dict:
    """
    Return the C row's figures: period.c against real_plant_kernel.period on the same periods.

    Only ``c_kernel_skipped`` (one line) when it cannot run (no C compiler, no numba).
    """
    import numpy as np
    from im_plant import real_plant_kernel as K
    if not K.available:
        return {'c_kernel_skipped': 'numba not installed: the C row skipped'}
    cc = os.environ.get('CC') or shutil.which('cc') or shutil.which('gcc')
    if cc is None:
        return {'c_kernel_skipped': 'no C compiler found (cc): the C row skipped'}
    calls = [a for a in _period_calls(duration)
             if a[15].shape[0] <= C_MAX_EV and a[16].shape[0] == 8]     # the inverter's table
    n = len(calls)
    inp = np.zeros((n, C_NIN))
    ev = np.zeros((n, 2 * C_MAX_EV))
    n_ev = np.zeros(n, dtype=np.int32)
    for j, a in enumerate(calls):
        (ps, pr, i_s, R_s, R_R, L_sig, r_on, m, kappa, vp, w_star, T, V, drop, code, events,
         unit, unitc, norm2, check, sa, sb, sc, ksw, sw, iron, k_h, k_e, w00, core_exp) = a
        inp[j] = (ps.real, ps.imag, pr.real, pr.imag, i_s.real, i_s.imag, R_s, R_R, L_sig, r_on,
                  m, kappa, vp, w_star, T, V, drop.real, drop.imag, code, check, sa, sb, sc,
                  ksw, sw, iron, k_h, k_e, w00, core_exp)
        ev[j, :2 * events.shape[0]] = events.ravel()
        n_ev[j] = events.shape[0]
    unit, unitc, norm2 = calls[0][16], calls[0][17], calls[0][18]
    with tempfile.TemporaryDirectory() as tmp:
        lib_path = os.path.join(tmp, 'period.so')
        subprocess.run([cc, '-O2', '-shared', '-fPIC', '-o', lib_path, C_SOURCE, '-lm'],
                       check=True, capture_output=True)
        lib = ctypes.CDLL(lib_path)
        dp = ctypes.POINTER(ctypes.c_double)
        ip = ctypes.POINTER(ctypes.c_int32)
        lib.rp_period.argtypes = [dp, dp, ctypes.c_int, dp, dp, dp, dp]
        lib.rp_period.restype = ctypes.c_int
        lib.rp_period_batch.argtypes = [ctypes.c_int, dp, dp, ip, dp, dp, dp, dp]
        lib.rp_period_batch.restype = None
        ure = np.ascontiguousarray(unit.real)
        uim = np.ascontiguousarray(unit.imag)
        n2 = np.ascontiguousarray(norm2)
        out_c = np.zeros((n, C_NOUT))
        out_n = np.zeros((n, C_NOUT))
        ptr = (lambda arr: arr.ctypes.data_as(dp))
        args_c = (n, ptr(inp), ptr(ev), n_ev.ctypes.data_as(ip), ptr(ure), ptr(uim), ptr(n2),
                  ptr(out_c))
        batch = _numba_batch()
        ev3 = ev.reshape((n, C_MAX_EV, 2))      # the same rows, as the kernel takes them
        batch(inp, ev3, n_ev, unit, unitc, norm2, out_n)       # compiled before the clock
        best_c = best_n = float('inf')
        for _ in range(repeats):
            t0 = time.perf_counter()
            lib.rp_period_batch(*args_c)
            best_c = min(best_c, time.perf_counter() - t0)
            t0 = time.perf_counter()
            batch(inp, ev3, n_ev, unit, unitc, norm2, out_n)
            best_n = min(best_n, time.perf_counter() - t0)
        # one call from Python each: ctypes against numba's dispatch
        rows = [(ptr(inp[j]), ptr(ev[j]), int(n_ev[j]), ptr(ure), ptr(uim), ptr(n2),
                 ptr(out_c[j])) for j in range(n)]
        call_c = call_n = float('inf')
        for _ in range(repeats):
            t0 = time.perf_counter()
            for r in rows:
                lib.rp_period(*r)
            call_c = min(call_c, time.perf_counter() - t0)
            t0 = time.perf_counter()
            for a in calls:
                K.period(*a)
            call_n = min(call_n, time.perf_counter() - t0)
    done = out_n[:, 0] == 0.0
    scale = np.maximum(np.abs(out_n), 1.0)
    diff = float(np.max(np.abs(out_c - out_n)[done] / scale[done])) if done.any() else 0.0
    return {'c_kernel': 'real_plant_kernel.period (intervals, closed-form integrals) in C, '
                        f'{os.path.basename(cc)} -O2, ctypes',
            'c_kernel_periods': n,
            'numba_us_per_period': 1e6 * best_n / n, 'c_us_per_period': 1e6 * best_c / n,
            'c_over_numba_us': best_c / best_n,
            'numba_call_us': 1e6 * call_n / n, 'c_call_us': 1e6 * call_c / n,
            'c_over_numba_call': call_c / call_n,
            'c_max_rel_diff': diff, 'c_equal_to_1e-12': int(diff <= 1e-12)}


def _numba_batch():
    """Return a compiled loop calling real_plant_kernel.period on rows laid out as period.c's."""
    from im_plant import real_plant_kernel as K
    from numba import njit

    def batch(inp, ev, n_ev, unit, unitc, norm2, out):
        for j in range(inp.shape[0]):
            a = inp[j]
            events = ev[j, :int(n_ev[j])]
            r = K.period(complex(a[0], a[1]), complex(a[2], a[3]), complex(a[4], a[5]), a[6],
                         a[7], a[8], a[9], a[10], a[11], a[12], a[13], a[14], a[15],
                         complex(a[16], a[17]), int(a[18]), events, unit, unitc, norm2,
                         a[19] != 0.0, a[20], a[21], a[22], a[23], a[24], a[25] != 0.0, a[26],
                         a[27], a[28], a[29])
            o = out[j]
            o[0] = r[0]
            o[1] = r[1]
            o[2] = r[2]
            o[3] = r[3]
            o[4] = r[4]
            o[5] = r[5].real
            o[6] = r[5].imag
            o[7] = r[6].real
            o[8] = r[6].imag
            o[9] = r[7].real
            o[10] = r[7].imag
            o[11] = r[8]
            o[12] = r[9]
            o[13] = r[10]
            o[14] = r[11]
            o[15] = r[12]
            o[16] = r[13]
            o[17] = r[14]
            o[18] = r[15].real
            o[19] = r[15].imag
    return njit(batch)


def reference_rate(duration: float, repeats: int) -> dict:
    """
    Time the ROS-free loop on the real plant with its pure-Python period (the reference).

    ``offline_real_reference_steps_per_s``: the rate before the period was compiled, measured in
    the same run as the compiled one (``..._compiled_over_reference``: issue 46's "2x").
    """
    from im_plant.real_plant import RealPlant
    use = RealPlant.use_kernel
    RealPlant.use_kernel = False
    try:
        rate = max(offline_steps_per_s(duration, True) for _ in range(repeats))
    finally:
        RealPlant.use_kernel = use
    return {'offline_real_reference_steps_per_s': rate}


def run(quick: bool = False) -> dict:
    duration = 0.05 if quick else 0.5
    repeats = 1 if quick else 3
    t0 = time.perf_counter()
    offline_steps_per_s(0.002, True)        # the kernel compiled or loaded from its cache
    first = time.perf_counter() - t0
    best = {}
    for _ in range(repeats):                  # interleaved: the same machine load for both
        for kind in ('offline', 'graph'):
            fn = offline_steps_per_s if kind == 'offline' else graph_steps_per_s
            for real in (False, True):
                key = f'{kind}_{"real" if real else "ideal"}_steps_per_s'
                best[key] = max(best.get(key, 0.0), fn(duration, real))
    res = dict(best)
    res.update(reference_rate(duration, repeats))
    res['offline_real_compiled_over_reference'] = (best['offline_real_steps_per_s']
                                                   / res['offline_real_reference_steps_per_s'])
    res['offline_real_over_ideal'] = best['offline_real_steps_per_s'] / \
        best['offline_ideal_steps_per_s']
    res['graph_real_over_ideal'] = best['graph_real_steps_per_s'] / best['graph_ideal_steps_per_s']
    res['real_plant_over_ideal'] = min(res['offline_real_over_ideal'],
                                       res['graph_real_over_ideal'])
    res['duration_s'] = duration
    res['first_real_run_s'] = first         # a 20-period run, the kernel's compilation with it
    res.update(c_versus_numba(0.01 if quick else 0.05, 2 if quick else 5))
    return res


def main(argv=None) -> None:
    """Print :func:`run`'s figures (and the kernel's first call) as JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--quick', action='store_true', help='short runs (smoke test)')
    ap.add_argument('--no-kernel', action='store_true',
                    help='the pure-Python period (RealPlant.use_kernel = False)')
    args = ap.parse_args(argv)
    from im_plant.real_plant import RealPlant
    if args.no_kernel:
        RealPlant.use_kernel = False
    res = run(quick=args.quick)
    res['use_kernel'] = bool(getattr(RealPlant, 'use_kernel', False))
    print(json.dumps(res, indent=1))


if __name__ == '__main__':
    main()
