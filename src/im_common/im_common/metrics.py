"""
Figures of merit of a run, from its traces.

One definition for the offline loop, the graph and the report (seed 000 §3.4: energy drawn, losses,
tracking errors).

A *trace* is a mapping of equal-length 1-D arrays sampled at the control instants t_k. Keys used
(missing optional keys simply drop their figures; NaN samples — instants where a decimated topic
has no value — are left out of each figure):

    t, theta_r, omega_r, theta_ref, omega_ref, tau_m, tau_ref, v_alpha, v_beta, i_alpha, i_beta,
    phi_r_alpha, phi_r_beta, phi_ref_alpha, phi_ref_beta (optional),
    phi_hat_alpha, phi_hat_beta (optional)
    theta_true, omega_true (optional: the true shaft; when present the tracking errors use it
    instead of the measured theta_r, omega_r, which may carry measurement noise)
    V_max, i_max (optional: the plant's peaks over every step since the previous sample; when
    present the peaks use them instead of the sampled v, i)

Energies come from the plant's integrated books (``truth`` dict at the final instant, see
:func:`im_common.plant_sim.energy_summary`), not from re-integrating sampled powers.
"""
from __future__ import annotations

import math
from typing import Mapping, Optional

import numpy as np


def _finite(x) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    return x[np.isfinite(x)]


def _maxabs(x) -> float:
    """
    Return the largest magnitude over the samples that exist.

    Largest magnitude over the samples that exist (NaN marks an instant a decimated topic was not
    sampled at).
    """
    x = _finite(x)
    return float(np.max(np.abs(x))) if len(x) else float('nan')


def _rms(x) -> float:
    x = _finite(x)
    return float(math.sqrt(np.mean(np.square(x)))) if len(x) else float('nan')


def tracking_figures(trace: Mapping[str, np.ndarray], task: Optional[str] = None) -> dict:
    """Max/RMS tracking errors and peaks. ``task`` is 'position', 'speed' or 'torque'."""
    out = {}
    theta = 'theta_true' if 'theta_true' in trace else 'theta_r'
    omega = 'omega_true' if 'omega_true' in trace else 'omega_r'
    if 'theta_ref' in trace and theta in trace:
        e = np.asarray(trace[theta]) - np.asarray(trace['theta_ref'])
        if task in (None, 'position'):
            out['pos_err_max_rad'] = _maxabs(e)
            out['pos_err_rms_rad'] = _rms(e)
        else:
            out['pos_err_max_rad'] = float('nan')
            out['pos_err_rms_rad'] = float('nan')
    if 'omega_ref' in trace and omega in trace:
        e = np.asarray(trace[omega]) - np.asarray(trace['omega_ref'])
        out['speed_err_max_rad_s'] = _maxabs(e)
        out['speed_err_rms_rad_s'] = _rms(e)
    if 'tau_ref' in trace and 'tau_m' in trace:
        e = np.asarray(trace['tau_m']) - np.asarray(trace['tau_ref'])
        out['torque_err_max_Nm'] = _maxabs(e)
        out['torque_err_rms_Nm'] = _rms(e)
    if 'phi_ref_alpha' in trace and 'phi_r_alpha' in trace:
        e = np.hypot(np.asarray(trace['phi_r_alpha']) - np.asarray(trace['phi_ref_alpha']),
                     np.asarray(trace['phi_r_beta']) - np.asarray(trace['phi_ref_beta']))
        out['flux_err_max_Wb'] = _maxabs(e)
        out['flux_err_rms_Wb'] = _rms(e)
    if 'phi_hat_alpha' in trace and 'phi_r_alpha' in trace:
        e = np.hypot(np.asarray(trace['phi_r_alpha']) - np.asarray(trace['phi_hat_alpha']),
                     np.asarray(trace['phi_r_beta']) - np.asarray(trace['phi_hat_beta']))
        out['flux_est_err_max_Wb'] = _maxabs(e)
        out['flux_est_err_rms_Wb'] = _rms(e)
    if 'V_max' in trace:
        out['V_max_V'] = _maxabs(trace['V_max'])
    elif 'v_alpha' in trace:
        out['V_max_V'] = _maxabs(np.hypot(trace['v_alpha'], trace['v_beta']))
    if 'i_max' in trace:
        out['i_max_A'] = _maxabs(trace['i_max'])
    elif 'i_alpha' in trace:
        out['i_max_A'] = _maxabs(np.hypot(trace['i_alpha'], trace['i_beta']))
    return out


def energy_figures(truth_final: Mapping[str, float]) -> dict:
    """Energy books at the end of a run (J) from a plant ``truth()`` dict."""
    from .plant_sim import energy_summary
    return energy_summary(truth_final)


def balance_relative(fig: Mapping[str, float]) -> float:
    """|balance residual| relative to the energy drawn (dimensionless)."""
    return abs(fig['balance_residual_J']) / max(abs(fig['E_in_J']), 1e-12)
