"""
Plant-kernel benchmark: RK4 steps per second and accuracy against solve_ivp (no ROS).

1. Throughput: ``PlantSimulator.step`` at T_s = 100 µs (one RK4 sub-step) with a balanced
   220 V / 60 Hz supply and the speed task's linear load (τ_L = 1 + 0.001 ω), best of 3 runs of
   ≥ 20,000 steps; the voltages are computed before the clock starts, so only the kernel (limit,
   four right-hand-side evaluations with the energy integrals, finiteness check) is timed. The same
   for the chapter-4 time-varying parameter schedule (slower path: parameters evaluated per call).
2. Accuracy: 0.2 s of the direct-on-line start, the plant against an independent integration of
   eq. 1.112 + 1.111 (state i_s, φ_r, θ_r, ω_r) by ``solve_ivp`` (DOP853, rtol 1e-10, atol 1e-12)
   with the same zero-order-held voltage, restarted at every period. Error per quantity is the
   largest deviation over the run divided by that quantity's largest magnitude; the figure is the
   worst quantity. Full runs repeat it at T_s = h = 200 µs and 50 µs to show the 4th order.

Run standalone: ``python benchmarks/bench_kernel.py [--quick]`` (prints a table, writes
benchmarks/results/kernel.json); ``benchmarks/run_all.py`` imports :func:`run`. ``--quick``
(seconds, a smoke test): 2,000 steps once, 0.01 s of the start against ``solve_ivp``.
"""
from __future__ import annotations

import math
import os
import sys
import time

from im_common.loads import LinearLoad
from im_common.model import eq112_matrices
from im_common.params import chapter4_schedule, THESIS_MOTOR
from im_plant.plant_sim import PlantSimulator
import numpy as np
from scipy.integrate import solve_ivp

HERE = os.path.dirname(os.path.abspath(__file__))
T_S = 1e-4
V_HAT = 220.0                       # power-invariant αβ amplitude = line-to-line RMS [V]
OMEGA_E = 2.0 * math.pi * 60.0


def _voltages(n: int, T_s: float):
    v = V_HAT * np.exp(1j * OMEGA_E * T_s * np.arange(n))
    return list(zip(v.real.tolist(), v.imag.tolist()))


def steps_per_second(schedule, n_steps: int, repeats: int = 3) -> float:
    """Best of ``repeats`` runs of n_steps PlantSimulator.step calls (steps per wall second)."""
    volts = _voltages(n_steps, T_S)
    best = math.inf
    for _ in range(repeats):
        sim = PlantSimulator(schedule, LinearLoad(1.0, 0.001), T_s=T_S)
        step = sim.step
        t0 = time.perf_counter()
        for v_a, v_b in volts:
            step(v_a, v_b)
        best = min(best, time.perf_counter() - t0)
    return n_steps / best


def _reference(params, load, T_s: float, n_steps: int) -> np.ndarray:
    """eq. 1.112 + 1.111 by DOP853, restarted each period with that period's held voltage."""
    vp, c = params.pole_pairs, params.L_sr / params.L_r

    def f(t, y, v):
        A, B = eq112_matrices(params.R_s, params.R_r, params.L_s, params.L_r, params.L_sr, vp,
                              y[5])
        tau = vp * c * (y[1] * y[2] - y[0] * y[3])
        return np.r_[A @ y[:4] + B @ v, y[5],
                     (tau - params.b * y[5] - load.torque(t, y[4], y[5])) / params.J]

    y = np.zeros(6)
    out = [y.copy()]
    for k, (v_a, v_b) in enumerate(_voltages(n_steps, T_s)):
        sol = solve_ivp(f, (k * T_s, (k + 1) * T_s), y, method='DOP853', rtol=1e-10, atol=1e-12,
                        args=(np.array([v_a, v_b]),))
        y = sol.y[:, -1]
        out.append(y.copy())
    return np.array(out)


def error_vs_solve_ivp(T_s: float = T_S, duration: float = 0.2) -> dict:
    """
    Relative error of the RK4 plant against the DOP853 reference over a start transient.

    One RK4 step per period (max_substep = T_s), so the RK4 step h equals T_s.
    """
    params, load = THESIS_MOTOR, LinearLoad(1.0, 0.001)
    n = int(round(duration / T_s))
    ref = _reference(params, load, T_s, n)
    sim = PlantSimulator(params, load, T_s=T_s, max_substep=T_s)
    got = [np.zeros(6)]
    for v_a, v_b in _voltages(n, T_s):
        sim.step(v_a, v_b)
        i_sa, i_sb, _, _ = sim.state_currents()
        got.append(np.array([i_sa, i_sb, sim.x[2], sim.x[3], sim.x[4], sim.x[5]]))
    got = np.array(got)
    groups = {'i_s': [0, 1], 'phi_r': [2, 3], 'theta_r': [4], 'omega_r': [5]}
    rel = {g: float(np.max(np.abs(got[:, ix] - ref[:, ix])) / np.max(np.abs(ref[:, ix])))
           for g, ix in groups.items()}
    rel['max'] = max(rel.values())
    return rel


def run(quick: bool = False) -> dict:
    n = 2000 if quick else 50000
    repeats = 1 if quick else 3
    res = {
        'T_s_s': T_S,
        'steps_timed': n,
        'kernel_steps_per_s': steps_per_second(THESIS_MOTOR, n, repeats),
        'kernel_chapter4_steps_per_s': steps_per_second(chapter4_schedule(), n, repeats),
    }
    res['kernel_us_per_step'] = 1e6 / res['kernel_steps_per_s']
    res['kernel_realtime_factor'] = res['kernel_steps_per_s'] * T_S   # simulated s per wall s
    err = error_vs_solve_ivp(T_S, duration=0.01 if quick else 0.2)
    for g, v in err.items():
        res[f'rel_err_vs_solve_ivp_{g}'] = v
    if not quick:
        for T_s in (2e-4, 5e-5):
            res[f'rel_err_vs_solve_ivp_max_h_{T_s * 1e6:g}us'] = error_vs_solve_ivp(T_s)['max']
    return res


if __name__ == '__main__':      # the table and JSON come from the driver
    from run_all import main
    sys.exit(main(['--only', 'kernel'] + sys.argv[1:]))
