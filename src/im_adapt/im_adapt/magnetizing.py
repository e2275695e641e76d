"""
The no-load test: the magnetizing curve i_M(ψ_R) at several flux levels (docs/commissioning.md §8).

ROS-free. After the speed test the drive runs the unloaded motor from a rotating voltage of fixed
frequency ω_e (open-loop V/f, no orientation and no pole pairs needed), and at each flux level
waits for the steady state and measures it. In a frame turning at ω_e the steady state of the
inverse-Γ circuit is

    V = R_s I + j ω_e Ψ_s,      Ψ_R = Ψ_s − σL_s I,

with V, I the fundamentals of the applied voltage and the stator current in that frame. With the
rotor unloaded the slip is nearly zero, and whatever rotor current the friction draws is at right
angles to Ψ_R (0 = R_R I_R + j ω_slip Ψ_R), as is the iron-loss current (a conductance across the
branch, in phase with j ω_e Ψ_R): the current's component along Ψ_R is the magnetizing current
exactly, i_M = Re(I Ψ_R*)/|Ψ_R|. Each level gives one point (|Ψ_R|, i_M) of the curve.

The voltage command of a level is the one whose zero-slip steady state is the flux ψ on the
frame's real axis: V = ψ (R_s/L_M + j ω_e (1 + σL_s/L_M)) (L_M the standstill's, so the flux
actually reached departs from ψ as the iron saturates — the measurement does not use ψ). The
voltage of period k is turned to the frame's angle at mid-period, so the zero-order hold's
fundamental lies on the frame (its half-period delay cancels; its magnitude is sinc(ω_e T_s/2),
1 − 1e-5 at 10 kHz).

Limits: the levels rise; a level whose current (low-passed) reaches NOLOAD_CURRENT·i_max during
its flux ramp is held where it got and is the last; every voltage stays below the drive's limit
(ω_e is chosen for it).
"""
from __future__ import annotations

import cmath
import math
from typing import Dict, List, Optional, Tuple

import numpy as np

#: flux levels as fractions of L_M·i_max (L_M the standstill's), rising
NOLOAD_LEVELS = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
#: the level whose flux the run-up uses (index into NOLOAD_LEVELS)
RUNUP_LEVEL = 2
#: a level's flux ramp stops (the level is the last) at this fraction of i_max
NOLOAD_CURRENT = 0.8
#: the top voltage of the test as a fraction of the drive's limit
NOLOAD_VOLTAGE = 0.6
#: the flux ramp between levels [s] and the settling after it, in rotor time constants
FLUX_RAMP_S = 0.2
SETTLE_TAU = 6.0
#: the measuring window of a level [s] (rounded up to whole electrical periods)
MEASURE_S = 0.2
#: sub-windows the measurement is split into for its standard deviation
SUBWINDOWS = 4
#: the current magnitude's low-pass for the ramp's stop [s]
CURRENT_FILTER_S = 0.01
#: fewest points a usable curve has
MIN_POINTS = 5


def level_point(v: np.ndarray, i: np.ndarray, theta: np.ndarray, w_e: float, T_s: float,
                R_s: float, L_sigma: float) -> Tuple[float, float]:
    """
    Return one point (|Ψ_R| [Wb], i_M [A]) of the magnetizing curve from a steady window.

    ``v``, ``i``: complex stationary-frame voltage (held over each period of ``T_s``) and current
    (sampled at its start); ``theta``: the frame's angle at each sample instant; ``w_e`` its
    rate. The held voltage's fundamental is its value turned back by the frame's angle at
    mid-period (the hold's half-period delay; sinc(ω_e T_s/2) ≈ 1 dropped).
    """
    rot = np.exp(-1j * theta)
    V = complex(np.mean(v * rot)) * cmath.exp(-0.5j * w_e * T_s)
    current = complex(np.mean(i * rot))
    psi_s = (V - R_s * current) / (1j * w_e)
    psi_r = psi_s - L_sigma * current
    mag = abs(psi_r)
    return mag, (current * psi_r.conjugate()).real / mag


class NoLoadTest:
    """
    The no-load test, one period at a time (module docstring).

    ``step(i_a, i_b)`` returns the voltage over the next period, None when the test is over;
    ``points`` then holds one dict per level: psi, i_M and their standard deviations, w_e.
    """

    def __init__(self, T_s: float, i_max: float, v_max: float, R_s: float, L_sigma: float,
                 L_M: float, R_R: float, w_e_max: float, t_mag: float, t_ramp: float,
                 R_s_std: float = 0.0):
        self.T_s = T_s
        self.i_max = i_max
        self.R_s, self.L_sigma, self.L_M = R_s, L_sigma, L_M
        self.R_s_std = R_s_std
        self.fluxes = [f * L_M * i_max for f in NOLOAD_LEVELS]
        self.w_e = min(w_e_max, NOLOAD_VOLTAGE * v_max
                       / (self.fluxes[-1] * (1.0 + L_sigma / L_M)))
        self.t_mag, self.t_ramp = t_mag, t_ramp
        self.t_settle = SETTLE_TAU * L_M / R_R
        period = 2.0 * math.pi / self.w_e     # whole electrical periods: the harmonics cancel
        self.n_measure = int(round(math.ceil(MEASURE_S / period) * period / T_s))
        self.theta = 0.0
        self.w = 0.0
        self.psi = self.fluxes[RUNUP_LEVEL]
        self.level = 0
        self.stage = 'magnetize'
        self.stage_k = 0
        self.i_filt = 0.0
        self.last = False
        self.w_run = 0.0
        #: why the test stopped without its curve (None: it did not)
        self.stopped: Optional[str] = None
        self._ramp_from = self.psi
        self._win_v: List[complex] = []
        self._win_i: List[complex] = []
        self._win_th: List[float] = []
        self.points: List[Dict[str, float]] = []
        self.progress = ''

    def _goto(self, stage: str) -> None:
        self.stage = stage
        self.stage_k = 0

    def step(self, i_a: float, i_b: float) -> Optional[Tuple[float, float]]:
        """Map the current at t_k to the voltage over [t_k, t_k+1] (None: the test is over)."""
        T = self.T_s
        t = self.stage_k * T
        self.i_filt += min(1.0, T / CURRENT_FILTER_S) * (math.hypot(i_a, i_b) - self.i_filt)
        if self.stage == 'magnetize':          # DC flux at the run-up level, the frame at rest
            if t >= self.t_mag:
                self._goto('runup')
        elif self.stage == 'runup':            # ω_e ramps to its value; the rotor follows
            if self.i_filt >= NOLOAD_CURRENT * self.i_max:      # it does not: a load, a brake
                self.stopped = (f'the rotor did not follow the no-load run-up ({self.i_filt:.3g} '
                                f'A at omega_e = {self.w:.4g} rad/s): no magnetizing curve')
                self.w_run, self.stage_k = self.w, 0
                self._goto('rundown')
                return self._command(i_a, i_b)
            self.w = min(self.w_e, self.w_e * t / self.t_ramp)
            if self.w >= self.w_e:
                self._goto('ramp')
                self._ramp_from = self.psi
        elif self.stage == 'ramp':             # the flux ramps to the level's
            target = self.fluxes[self.level]
            x = min(1.0, t / FLUX_RAMP_S)
            self.psi = self._ramp_from + x * (target - self._ramp_from)
            if self.i_filt >= NOLOAD_CURRENT * self.i_max and self.psi > self._ramp_from:
                self.last = True               # held where it got: the last level
                self._goto('settle')
            elif x >= 1.0:
                self._goto('settle')
        elif self.stage == 'settle':
            if t >= self.t_settle:
                self._goto('measure')
        elif self.stage == 'measure':
            if len(self._win_i) >= self.n_measure:
                self._measure()
                if self.last or self.level + 1 == len(self.fluxes):
                    self.w_run = self.w
                    self._goto('rundown')
                else:
                    self.level += 1
                    self._ramp_from = self.psi
                    self._goto('ramp')
        elif self.stage == 'rundown':          # ω_e back to zero, the flux held
            self.w = max(0.0, self.w_run * (1.0 - t / self.t_ramp))
            if self.w <= 0.0:
                return None
        self.progress = (f'no-load test: {self.stage}, level {self.level + 1}, '
                         f'omega_e = {self.w:.4g} rad/s, {self.i_filt:.3g} A')
        return self._command(i_a, i_b)

    def _command(self, i_a: float, i_b: float) -> Tuple[float, float]:
        psi = self.psi
        V = psi * complex(self.R_s / self.L_M, self.w * (1.0 + self.L_sigma / self.L_M))
        mid = self.theta + 0.5 * self.w * self.T_s
        v = V * cmath.exp(1j * mid)
        if self.stage == 'measure':            # the current at t_k, the frame's angle, v_k
            self._win_i.append(complex(i_a, i_b))
            self._win_th.append(self.theta)
            self._win_v.append(v)
        self.theta += self.w * self.T_s
        self.stage_k += 1
        return v.real, v.imag

    def _measure(self) -> None:
        n = self.n_measure
        v = np.array(self._win_v[:n])
        i = np.array(self._win_i[:n])
        th = np.array(self._win_th[:n])
        psi, i_M = level_point(v, i, th, self.w_e, self.T_s, self.R_s, self.L_sigma)
        m = n // SUBWINDOWS
        subs = [level_point(v[j * m:(j + 1) * m], i[j * m:(j + 1) * m], th[j * m:(j + 1) * m],
                            self.w_e, self.T_s, self.R_s, self.L_sigma)
                for j in range(SUBWINDOWS)]
        sp = float(np.std([s[0] for s in subs], ddof=1)) / math.sqrt(SUBWINDOWS)
        si = float(np.std([s[1] for s in subs], ddof=1)) / math.sqrt(SUBWINDOWS)
        # R_s's own uncertainty moves Ψ_s by ΔR_s·I/ω_e (in quadrature with the noise)
        sp = math.hypot(sp, self.R_s_std * i_M / self.w_e)
        self.points.append({'psi': psi, 'i_M': i_M, 'psi_std': sp, 'i_M_std': si,
                            'w_e': self.w_e})
        self._win_v, self._win_i, self._win_th = [], [], []


def curve_table(points: List[Dict[str, float]]) -> List[List[float]]:
    """Return the points as a motor file's ``saturation: {table: ...}`` rows, rising."""
    rows = sorted((p['psi'], p['i_M']) for p in points)
    out: List[List[float]] = []
    for psi, i in rows:
        if not out or (psi > out[-1][0] and i > out[-1][1]):
            out.append([float(f'{psi:.5g}'), float(f'{i:.5g}')])
    return out
