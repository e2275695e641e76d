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

A load step (a ``step`` or ``schedule`` load, docs/running.md "Loads") adds the speed figures of
:func:`load_step_figures`: how deep the speed dipped and how long it took to come back.

Energies come from the plant's integrated books (``truth`` dict at the final instant, see
:func:`im_common.metrics.energy_summary`), not from re-integrating sampled powers.
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


#: the speed band a drive is back in after a load step [rad/s] (the recovery time's)
LOAD_STEP_BAND = 2.0


class LoadStepFigures:
    """
    The speed figures of a load step at ``t_step``, fed in chunks of (t, ω − ω*).

    ``speed_dip_rad_s``: the largest |ω − ω*| from the step on; ``speed_recovery_s``: the time
    from the step until |ω − ω*| stays within ``band`` to the end of the run (0 if it never
    left it; NaN if it is outside at the end: not recovered). NaN samples are left out.
    """

    def __init__(self, t_step: float, band: float = LOAD_STEP_BAND):
        if not (math.isfinite(t_step) and math.isfinite(band) and band > 0):
            raise ValueError(f'load step at {t_step!r} s, band {band!r} rad/s: must be finite, '
                             'band > 0')
        self.t_step, self.band = float(t_step), float(band)
        self.dip = 0.0
        self.n = 0
        self.t_out = None           # the last instant outside the band
        self.t_back = None          # the first instant in the band after t_out
        self.outside = False        # the last sample is outside the band

    def add(self, t, e) -> None:
        """Take samples at instants ``t`` of the speed error ``e`` = ω − ω* [rad/s]."""
        t = np.asarray(t, dtype=float)
        a = np.abs(np.asarray(e, dtype=float))
        keep = (t >= self.t_step) & np.isfinite(a)
        t, a = t[keep], a[keep]
        if not len(t):
            return
        self.n += len(t)
        self.dip = max(self.dip, float(np.max(a)))
        out = np.flatnonzero(a > self.band)
        if len(out):
            last = out[-1]
            self.t_out = float(t[last])
            self.outside = last == len(t) - 1
            self.t_back = None if self.outside else float(t[last + 1])
        elif self.outside:          # the chunk starts back in the band
            self.t_back, self.outside = float(t[0]), False

    def figures(self) -> dict:
        """Return ``speed_dip_rad_s`` and ``speed_recovery_s`` (NaN without samples)."""
        nan = float('nan')
        if not self.n:
            return {'speed_dip_rad_s': nan, 'speed_recovery_s': nan}
        if self.t_out is None:
            rec = 0.0
        elif self.outside:
            rec = nan
        else:
            rec = self.t_back - self.t_step
        return {'speed_dip_rad_s': self.dip, 'speed_recovery_s': rec}


def load_step_figures(trace: Mapping[str, np.ndarray], t_step: float,
                      band: float = LOAD_STEP_BAND) -> dict:
    """
    Return the speed figures of a load step at ``t_step`` (:class:`LoadStepFigures`).

    The error is the true shaft's when the trace has it (``omega_true``), else ``omega_r``.
    """
    omega = 'omega_true' if 'omega_true' in trace else 'omega_r'
    acc = LoadStepFigures(t_step, band)
    acc.add(trace['t'], np.asarray(trace[omega], dtype=float) - np.asarray(trace['omega_ref']))
    return acc.figures()


def energy_figures(truth_final: Mapping[str, float]) -> dict:
    """Energy books at the end of a run (J) from a plant ``truth()`` dict."""
    return energy_summary(truth_final)


def balance_relative(fig: Mapping[str, float]) -> float:
    """|balance residual| relative to the energy drawn (dimensionless)."""
    return abs(fig['balance_residual_J']) / max(abs(fig['E_in_J']), 1e-12)


def energy_summary(truth: dict) -> dict:
    """
    Return the figures of merit of the energy books (J) from a ``truth()`` dict.

    Behind an inverter (the real plant's truth has ``E_inv``) also its losses ``E_inverter_J``
    (conduction and switching), their switching share ``E_switching_J`` and the energy drawn
    from the DC link, ``E_dc_J`` = E_in + E_inv.
    """
    e_cu = truth['E_cu_s'] + truth['E_cu_r']
    return {
        'E_in_J': truth['E_in'], 'E_copper_J': e_cu, 'E_core_J': truth['E_core'],
        'E_loss_J': e_cu + truth['E_core'], 'W_load_J': truth['W_load'],
        'E_friction_J': truth['E_friction'], 'dE_kinetic_J': truth['dE_kin'],
        'dW_magnetic_J': truth['dW_mag'], 'E_param_J': truth['E_param'],
        'balance_residual_J': truth['balance_residual'],
        **({'E_inverter_J': truth['E_inv'], 'E_dc_J': truth['E_in'] + truth['E_inv']}
           if 'E_inv' in truth else {}),
        # a recording made before the switching losses has none to report: no key, not a 0
        **({'E_switching_J': truth['E_switching']} if 'E_switching' in truth else {}),
    }
