"""
PNG figures of recorded runs in the style of seed 000 (Figures 3.4-3.13 and 4.7-4.15).

Each function takes a list of :class:`~im_recording.recorded_run.RecordedRun` (one run, or several
overlaid for a comparison), writes one PNG and returns its path, or None when the runs lack the
data. matplotlib is imported lazily with the Agg backend, so importing this module costs nothing
and needs no display.

=====================  ====================================================================
file                   thesis figures
=====================  ====================================================================
position.png           3.4 / 3.7 / 4.7 / 4.8: (a) θ* and θ_r, (b) τ* and τ_m
speed.png              3.11 / 3.12 / 4.13 / 4.14: (a) ω* and ω_r, (b) τ* and τ_m
currents_dq.png        3.5 / 3.8 / 4.9 (a, b): stator current d and q axes, reference and real
flux_dq.png            3.6 / 3.9 / 4.9 (c, d): rotor flux d and q axes, reference and real
energy.png             3.10 / 3.13 / 4.12 / 4.15: energy drawn E_in and losses E_l = ∫P_l dt
observer.png           4.10: real and observed stator current and rotor flux (d and q axes)
estimates.png          4.11: real and adapted R_r and θ = L_sr/L_r (and L_M, R_R if present)
voltage_current.png    |V_s| and |i_s| (the peaks in the report table)
=====================  ====================================================================

The d-q frame is the reference rotor-flux frame (angle of φ*_αβ) when the controller publishes
it, else the true rotor-flux frame: there the reference q-axis flux is zero by construction and
the real q-axis flux shows the orientation error.
"""
from __future__ import annotations

from pathlib import Path
from typing import List, Optional, Sequence

import numpy as np

MAX_POINTS = 6000


def pyplot():
    """Return matplotlib.pyplot on the file backend (Agg), imported on first use."""
    import matplotlib       # heavy: matplotlib, only when a figure is drawn
    matplotlib.use('Agg', force=False)
    import matplotlib.pyplot as plt     # heavy: pyplot, after the Agg backend is chosen
    return plt


def _has(run, *keys) -> bool:
    return all(k in run.trace and np.isfinite(run.trace[k]).any() for k in keys)


def _dec(run, *keys):
    """
    Return the series at the instants where all of them were sampled.

    Time and the given series at the instants where all of them were sampled (decimated topics are
    NaN in between), thinned to at most MAX_POINTS samples.
    """
    tr = run.trace
    ok = np.ones(len(tr['t']), bool)
    for k in keys:
        ok &= np.isfinite(tr[k])
    idx = np.flatnonzero(ok)
    idx = idx[::max(1, int(np.ceil(len(idx) / MAX_POINTS)))]
    return [tr['t'][idx]] + [tr[k][idx] for k in keys]


def dq_frame_angle(trace) -> Optional[np.ndarray]:
    for a, b in (('phi_ref_alpha', 'phi_ref_beta'), ('phi_r_alpha', 'phi_r_beta')):
        if a in trace and b in trace and np.isfinite(trace[a]).any():
            return np.arctan2(trace[b], trace[a])
    return None


def to_dq(trace, a_key: str, b_key: str):
    """(d, q) components of an αβ pair in the frame of :func:`dq_frame_angle`."""
    rho = dq_frame_angle(trace)
    if rho is None or a_key not in trace or b_key not in trace:
        return None
    c, s = np.cos(rho), np.sin(rho)
    a, b = trace[a_key], trace[b_key]
    return a * c + b * s, -a * s + b * c


def _label(run, what: str, many: bool) -> str:
    return f'{what} — {run.label}' if many else what


def _style(i: int):
    colors = ['C0', 'C1', 'C2', 'C3', 'C4', 'C5']
    return colors[i % len(colors)]


def _save(fig, out_dir: Path, name: str) -> str:
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / name
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    pyplot().close(fig)
    return str(path)


def _ref_real(ax, runs, ref_key, real_key, ylabel, ref_name, real_name, scale=1.0):
    many = len(runs) > 1
    for i, run in enumerate(runs):
        if _has(run, ref_key):
            t, y = _dec(run, ref_key)
            ax.plot(t, y * scale, '--', color=_style(i) if many else 'k', lw=1.2, zorder=3,
                    label=_label(run, ref_name, many))
        if _has(run, real_key):
            t, y = _dec(run, real_key)
            ax.plot(t, y * scale, '-', color=_style(i), lw=0.9, alpha=0.85,
                    label=_label(run, real_name, many))
    ax.set_ylabel(ylabel)
    ax.set_xlabel('t [s]')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc='best')


def plot_tracking(runs: Sequence, out_dir, kind: str) -> Optional[str]:
    """Plot (a) position or speed, reference and real; (b) torque, reference and real."""
    key, ref, unit, name = {
        'position': ('theta_r', 'theta_ref', 'rad', 'θ'),
        'speed': ('omega_r', 'omega_ref', 'rad/s', 'ω'),
    }[kind]
    runs = [r for r in runs if _has(r, key, ref)]
    if not runs:
        return None
    plt = pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(7.5, 6.5), sharex=True)
    _ref_real(axes[0], runs, ref, key, f'{name}_r [{unit}]', f'{name}* (reference)',
              f'{name}_r (real)')
    axes[0].set_title(f'(a) {kind}: reference and real')
    _ref_real(axes[1], runs, 'tau_ref', 'tau_m', 'τ_m [N·m]', 'τ* (reference)', 'τ_m (real)')
    axes[1].set_title('(b) electromagnetic torque: reference and real')
    return _save(fig, Path(out_dir), f'{kind}.png')


def _dq_traces(run, ref_pair, real_pair, prefix):
    tr = dict(run.trace)
    for pair, tag in ((ref_pair, 'ref'), (real_pair, 'real')):
        dq = to_dq(run.trace, *pair)
        if dq is not None:
            tr[f'{prefix}_{tag}_d'], tr[f'{prefix}_{tag}_q'] = dq
    return tr


class _View:
    """A run with extra trace entries (the d-q projections) and the same label."""

    def __init__(self, run, trace):
        self.trace = trace
        self.label = run.label


def plot_dq(runs: Sequence, out_dir, what: str) -> Optional[str]:
    if what == 'current':
        ref_pair, real_pair = ('i_ref_alpha', 'i_ref_beta'), ('i_alpha', 'i_beta')
        sym, unit, fname, title = 'i', 'A', 'currents_dq.png', 'stator current'
    else:
        ref_pair, real_pair = ('phi_ref_alpha', 'phi_ref_beta'), ('phi_r_alpha', 'phi_r_beta')
        sym, unit, fname, title = 'φ', 'Wb', 'flux_dq.png', 'rotor flux'
    views = []
    for r in runs:
        if not _has(r, *real_pair) or dq_frame_angle(r.trace) is None:
            continue
        views.append(_View(r, _dq_traces(r, ref_pair, real_pair, 'x')))
    if not views:
        return None
    plt = pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(7.5, 6.5), sharex=True)
    for ax, axis, tag in ((axes[0], 'd', '(a)'), (axes[1], 'q', '(b)')):
        _ref_real(ax, views, f'x_ref_{axis}', f'x_real_{axis}', f'{sym}_{axis} [{unit}]',
                  f'{sym}*_{axis} (reference)', f'{sym}_{axis} (real)')
        ax.set_title(f'{tag} {title}, {"direct" if axis == "d" else "quadrature"} axis')
    return _save(fig, Path(out_dir), fname)


def plot_observer(runs: Sequence, out_dir) -> Optional[str]:
    views = []
    for r in runs:
        if not _has(r, 'phi_hat_alpha', 'phi_r_alpha') or dq_frame_angle(r.trace) is None:
            continue
        tr = dict(r.trace)
        for pair, tag in ((('i_alpha', 'i_beta'), 'i'), (('i_hat_alpha', 'i_hat_beta'), 'ih'),
                          (('phi_r_alpha', 'phi_r_beta'), 'p'),
                          (('phi_hat_alpha', 'phi_hat_beta'), 'ph')):
            dq = to_dq(r.trace, *pair)
            if dq is not None:
                tr[f'{tag}_d'], tr[f'{tag}_q'] = dq
        views.append(_View(r, tr))
    if not views:
        return None
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(11, 6.5), sharex=True)
    panels = [('i', 'ih', 'd', 'i_sd [A]', '(a) stator current, d axis'),
              ('i', 'ih', 'q', 'i_sq [A]', '(b) stator current, q axis'),
              ('p', 'ph', 'd', 'φ_rd [Wb]', '(c) rotor flux, d axis'),
              ('p', 'ph', 'q', 'φ_rq [Wb]', '(d) rotor flux, q axis')]
    for ax, (real, hat, axis, ylabel, title) in zip(axes.flat, panels):
        _ref_real(ax, views, f'{hat}_{axis}', f'{real}_{axis}', ylabel, 'observed', 'real')
        ax.set_title(title, fontsize=9)
    return _save(fig, Path(out_dir), 'observer.png')


def plot_energy(runs: Sequence, out_dir) -> Optional[str]:
    runs = [r for r in runs if _has(r, 'E_in')]
    if not runs:
        return None
    plt = pyplot()
    fig, ax = plt.subplots(1, 1, figsize=(7.5, 4.5))
    many = len(runs) > 1
    for i, r in enumerate(runs):
        keys = [k for k in ('E_in', 'E_cu_s', 'E_cu_r', 'E_core') if k in r.trace]
        t, *cols = _dec(r, *keys)
        e = {k: c - c[0] for k, c in zip(keys, cols)}        # energies over the window
        ax.plot(t, e['E_in'], '-', color=_style(i), label=_label(r, 'E_in (energy drawn)', many))
        loss = [e[k] for k in ('E_cu_s', 'E_cu_r', 'E_core') if k in e]
        if loss:
            ax.plot(t, sum(loss), '--', color=_style(i),
                    label=_label(r, 'E_l (losses: copper + core)', many))
    ax.set_xlabel('t [s]')
    ax.set_ylabel('energy [J]')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title('Energy drawn and electromagnetic losses')
    return _save(fig, Path(out_dir), 'energy.png')


def plot_estimates(runs: Sequence, out_dir) -> Optional[str]:
    names = [n for n in ('R_r', 'theta', 'L_M', 'R_R')
             if any(_has(r, f'{n}_hat') for r in runs)]
    if not names:
        return None
    units = {'R_r': 'Ω', 'theta': '—', 'L_M': 'H', 'R_R': 'Ω'}
    sym = {'R_r': 'R_r', 'theta': 'θ', 'L_M': 'L_M', 'R_R': 'R_R'}
    plt = pyplot()
    fig, axes = plt.subplots(len(names), 1, figsize=(7.5, 3.0 * len(names)), sharex=True,
                             squeeze=False)
    for ax, n, tag in zip(axes[:, 0], names, 'abcd'):
        _ref_real(ax, runs, f'{n}_hat', n, f'{sym[n]} [{units[n]}]', f'{sym[n]} adapted',
                  f'{sym[n]} real')
        ax.set_title(f'({tag}) real and adapted {sym[n]}', fontsize=9)
    return _save(fig, Path(out_dir), 'estimates.png')


def plot_voltage_current(runs: Sequence, out_dir) -> Optional[str]:
    runs = [r for r in runs if _has(r, 'v_alpha', 'i_alpha')]
    if not runs:
        return None
    plt = pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(7.5, 5.5), sharex=True)
    many = len(runs) > 1
    for i, r in enumerate(runs):
        t, va, vb, ia, ib = _dec(r, 'v_alpha', 'v_beta', 'i_alpha', 'i_beta')
        axes[0].plot(t, np.hypot(va, vb), color=_style(i), lw=0.9, label=_label(r, '|V_s|', many))
        axes[1].plot(t, np.hypot(ia, ib), color=_style(i), lw=0.9, label=_label(r, '|i_s|', many))
    axes[0].set_ylabel('|V_s| [V]')
    axes[1].set_ylabel('|i_s| [A]')
    axes[1].set_xlabel('t [s]')
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_title('Stator voltage and current magnitudes')
    return _save(fig, Path(out_dir), 'voltage_current.png')


def plot_real_plant(runs: Sequence, out_dir) -> Optional[str]:
    """
    Plot the real plant's truth (docs/plant.md), the panels there is data for.

    DC-link voltage; winding temperatures; R_s and R_r (with a thermal block); phase currents
    over the run's last 40 ms with the within-period ripple (with an inverter).
    """
    panels = []
    if any(_has(r, 'V_dc') for r in runs):
        panels.append('vdc')
    if any(_has(r, 'T_stator') for r in runs):
        panels += ['temp', 'res']
    if any(_has(r, 'i_a') for r in runs):
        panels.append('phase')
    if not panels:
        return None
    plt = pyplot()
    fig, axes = plt.subplots(len(panels), 1, figsize=(7.5, 2.6 * len(panels)), squeeze=False)
    many = len(runs) > 1
    for ax, panel in zip(axes[:, 0], panels):
        for i, r in enumerate(runs):
            c = _style(i)
            if panel == 'vdc' and _has(r, 'V_dc'):
                t, v = _dec(r, 'V_dc')
                ax.plot(t, v, color=c, lw=0.9, label=_label(r, 'V_dc', many))
                ax.set_ylabel('V_dc [V]')
            elif panel == 'temp' and _has(r, 'T_stator'):
                t, ts, tr_ = _dec(r, 'T_stator', 'T_rotor')
                ax.plot(t, ts, '-', color=c, label=_label(r, 'stator winding', many))
                ax.plot(t, tr_, '--', color=c, label=_label(r, 'rotor cage', many))
                ax.set_ylabel('T [°C]')
            elif panel == 'res' and _has(r, 'R_s', 'R_r', 'T_stator'):
                t, rs, rr = _dec(r, 'R_s', 'R_r')
                ax.plot(t, rs, '-', color=c, label=_label(r, 'R_s(T)', many))
                ax.plot(t, rr, '--', color=c, label=_label(r, 'R_r(T)', many))
                ax.set_ylabel('R [Ω]')
            elif panel == 'phase' and _has(r, 'i_a', 'i_ripple_pp'):
                t, ia, ib, ic, rip = _dec(r, 'i_a', 'i_b', 'i_c', 'i_ripple_pp')
                zoom = t >= t[-1] - 0.04
                for name, x, style in (('i_a', ia, '-'), ('i_b', ib, '--'), ('i_c', ic, ':')):
                    ax.plot(t[zoom], x[zoom], style, color=c, lw=0.9, label=_label(r, name, many))
                ax.fill_between(t[zoom], ia[zoom] - rip[zoom] / 2, ia[zoom] + rip[zoom] / 2,
                                color=c, alpha=0.25, label=_label(r, 'i_a ripple (p-p)', many))
                ax.set_ylabel('phase current [A]')
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    axes[0, 0].set_title('Real plant: DC link, windings, phase currents (last 40 ms)')
    axes[-1, 0].set_xlabel('t [s]')
    return _save(fig, Path(out_dir), 'real_plant.png')


def all_figures(runs: Sequence, out_dir) -> List[str]:
    """Every figure the runs have data for; returns the PNG paths."""
    out = []
    tasks = {r.task for r in runs}
    if 'speed' not in tasks or 'position' in tasks or None in tasks:
        out.append(plot_tracking([r for r in runs if r.task in (None, 'position')], out_dir,
                                 'position'))
    if 'position' not in tasks or 'speed' in tasks:
        out.append(plot_tracking([r for r in runs if r.task in (None, 'speed')], out_dir,
                                 'speed'))
    out.append(plot_dq(runs, out_dir, 'current'))
    out.append(plot_dq(runs, out_dir, 'flux'))
    out.append(plot_energy(runs, out_dir))
    out.append(plot_observer(runs, out_dir))
    out.append(plot_estimates(runs, out_dir))
    out.append(plot_voltage_current(runs, out_dir))
    out.append(plot_real_plant(runs, out_dir))
    return [p for p in out if p]
