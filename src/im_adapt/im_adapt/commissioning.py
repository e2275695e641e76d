"""
Self-commissioning: the motor's parameters measured by the drive itself (docs/commissioning.md).

ROS-free. :class:`Commissioning` is a test controller stepped once per period with what the drive
measures (stator current, shaft speed) and returning the voltage to apply; when it is done,
:meth:`Commissioning.result` identifies

* the inverse-Γ set R_s, σL_s (``L_sigma``), L_M, R_R (params.MotorParams.identifiable) from a
  standstill test: voltages along α only. At ω_r = 0 with everything on one axis the torque
  τ_m = v(ψ_sα i_sβ − ψ_sβ i_sα) is exactly zero, so the test is the same with the rotor free or
  locked. The machine is then the passive RL network v → i with admittance
  Y(s) = (sL_M + R_R) / ((R_s + sL_σ)(sL_M + R_R) + sL_M R_R), fitted by output error on its
  exact zero-order-hold discretization (least squares on the simulated current, parameters in
  log scale; the standard deviations from the residuals and the Jacobian), then refined
  (rotor free) jointly with the speed test's rotor-flux balance dm/dt = R_R (i_d − m/L_M), which
  pins L_σ + L_M far more precisely than the standstill's rotor time constant (:func:`fit_joint`);
* J and b (rotor free only) from a run-up, coast and braking under flux-oriented current control
  built on the identified model: J Δω + b ∫ω dt = ∫τ̂ dt over windows, with the torque from the
  voltage-model stator flux, τ̂ = v (ψ_sα i_β − ψ_sβ i_α), ψ_s = ∫(V − R̂_s i) dt;
* the pole pairs from the same run (the flux's rotation against the measured shaft speed) when
  no nameplate gives them;
* the magnetizing curve i_M(ψ_R) at several flux levels from a no-load test after the speed test
  (:mod:`im_adapt.magnetizing`, rotor free, ``magnetizing=True``).

Before the standstill test, the inverter's own voltage error (dead time and device drops,
docs/compensation.md) is measured: a slow current loop holds the α current at ±LEVELS × i_max in
turn, and the steady voltages fit V = R·I + c·sgn(I) (:func:`fit_dc_levels`): R is R_s (plus the
devices' r_on, which acts as stator resistance), c = 2·√(2/3)·v_dead the error vector of a current
along α. Every later test voltage is then compensated (:class:`InverterErrorModel`), and the
fits see the voltage the motor got; on an ideal source v_dead comes out as ~0.

Limits: every current stays below ``i_max`` (the standstill voltages are bounded by
R̂_s·I: the RL network's impulse response is positive, so |i| ≤ max|v| / R_s), every voltage
below ``v_max``; a current above 0.9·i_max zeroes the voltage and ends the test
(:class:`NotInformative`). A test whose data cannot determine a parameter (no current, a shaft
that does not turn) raises :class:`NotInformative` with one line saying which and why.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Dict, List, Optional, Tuple

from im_adapt.magnetizing import MIN_POINTS, NoLoadTest
from im_common.compensation import InverterErrorModel
from im_common.params import (check_real, IDENTIFIABLE_NAMES, InvalidParameter, MotorParams,
                              rated_rotor_flux, RATING_NAMES)
import numpy as np

#: the standstill excitation after the probe: (level as a fraction of the test voltage, seconds)
EXCITATION = ((1.0, 0.5), (-1.0, 0.5), (0.5, 0.02), (-0.5, 0.01), (1.0, 0.005), (-1.0, 0.005),
              (0.3, 0.05), (-0.7, 0.1), (1.0, 0.25), (0.0, 0.5))
PROBE_CURRENT = 0.25     # probe current as a fraction of i_max
TEST_CURRENT = 0.5       # standstill test current bound as a fraction of i_max
SPEED_CURRENT = 0.8      # |i*| during the speed test as a fraction of i_max
TRIP_FRACTION = 0.9      # a current above this fraction of i_max ends the test
SPEED_FRACTION = 0.5     # the speed test runs up to this fraction of the rated (test) speed
FLUX_WINDOW = 0.01       # block length of the speed test's flux balance [s]
OFFSET_BLOCKS = 5        # blocks per constant voltage-model offset in the flux balance
MECHANICS_WINDOW_S = 0.1  # the speed test's J, b regression windows [s]
EMF_FILTER_S = 0.005     # time constant of the run-up's EMF estimate (its stop test) [s]
#: the inverter-error test's α currents, as fractions of i_max (two magnitudes, both signs)
LEVELS = (-0.25, -0.5, 0.25, 0.5)
LEVEL_LOOP_S = 0.5       # time constant of its current loop on the probe's V/I [s] (faster on R_s)
LEVEL_WINDOW_S = 0.1     # a level is steady when two windows this long agree to LEVEL_STEADY
#: (the voltage creeps with the rotor time constant L_M/R_R while the loop holds the current)
LEVEL_STEADY = 2e-4
#: the ramp half-width of the compensation's sign, as a fraction of i_max
COMPENSATION_BAND = 0.02
#: with an inverter error that matters (above ERROR_SHARE of the test voltage), the standstill
#: test runs around a DC current (BIAS ± SWING, fractions of i_max, from the last level's steady
#: state): no phase current then crosses zero, where the dead time's error is the ripple's
BIAS, SWING, ERROR_SHARE = 0.35, 0.15, 0.05
#: the error vector of an α current against v_dead: every phase beyond the band, 2·√(2/3)
ALPHA_ERROR = 2.0 * math.sqrt(2.0 / 3.0)


class NotInformative(ValueError):
    """The test cannot determine a parameter; the message is one line saying which and why."""


@dataclass(frozen=True)
class Nameplate:
    """
    A motor's nameplate.

    Rated line-to-line voltage [V RMS], line current [A RMS], frequency [Hz], speed [rpm] and
    shaft power [W].
    """

    voltage: float
    current: float
    frequency: float
    speed: float
    power: float

    def __post_init__(self):
        for name in ('voltage', 'current', 'frequency', 'speed', 'power'):
            check_real(f'nameplate {name}', getattr(self, name), 0.0, lo_open=True)
        if self.speed >= 60.0 * self.frequency:
            raise InvalidParameter('nameplate speed', self.speed,
                                   f'must be below 60·frequency = {60 * self.frequency:g} rpm '
                                   f'(an induction motor runs below synchronous speed)')

    @property
    def pole_pairs(self) -> int:
        """Return the pole-pair count whose synchronous speed is just above the rated speed."""
        return max(1, int(math.floor(60.0 * self.frequency / self.speed)))

    def motor_fields(self) -> Dict[str, float]:
        """Return the motor file's nameplate fields (im_common.params.RATING_NAMES)."""
        return {'rated_voltage_rms_line': self.voltage, 'rated_current_rms': self.current,
                'rated_frequency': self.frequency, 'rated_speed_rpm': self.speed,
                'rated_power': self.power}

    def ratings(self) -> Dict[str, float]:
        """
        Return :meth:`motor_fields` and their model-frame magnitudes.

        These are the commissioning tests' limits: ``rated_voltage`` = line-to-line RMS,
        ``rated_current`` = √3 × line current, ``rated_speed`` [rad/s], ``rated_torque`` —
        converted by MotorParams, their one home (docs/limits.md). :meth:`Identification.motor`
        keeps the nameplate fields.
        """
        m = MotorParams(pole_pairs=self.pole_pairs, **self.motor_fields())
        return dict(self.motor_fields(), rated_voltage=m.rated_voltage,
                    rated_current=m.rated_current, rated_speed=m.rated_speed,
                    rated_torque=m.rated_torque)


def nameplate_from_dict(doc, source: str = 'nameplate') -> Nameplate:
    """
    Return a :class:`Nameplate` from ``{voltage, current, frequency, speed, power}``.

    One-line errors naming ``source`` and the field.
    """
    keys = ('voltage', 'current', 'frequency', 'speed', 'power')
    if not isinstance(doc, dict):
        raise InvalidParameter(source, doc, f'must be a mapping with {", ".join(keys)}')
    for k in doc:
        if k not in keys:
            raise InvalidParameter(f'{source}: {k}', doc[k],
                                   f'unknown (fields: {", ".join(keys)})')
    for k in keys:
        if k not in doc:
            raise InvalidParameter(f'{source}: {k}', None, 'is missing')
        if isinstance(doc[k], bool) or not isinstance(doc[k], (int, float)):
            raise InvalidParameter(f'{source}: {k}', doc[k], 'must be a number')
    try:
        return Nameplate(**{k: float(doc[k]) for k in keys})
    except InvalidParameter as exc:
        raise InvalidParameter(f'{source}: {exc.name}', exc.value, exc.reason) from None


def _zoh(A: np.ndarray, B: np.ndarray, T_s: float):
    from scipy.linalg import expm  # heavy: scipy only for the fits
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = A, B
    E = expm(M * T_s)
    return E[:n, :n], E[:n, n]


def standstill_response(ident: np.ndarray, v: np.ndarray, T_s: float, x0=(0.0, 0.0)):
    """
    Simulate the standstill test on the inverse-Γ model (one axis).

    Stator current i_k and magnetizing flux ψ_R,k at t_k of the inverse-Γ model at standstill (one
    axis) for the voltages v_k held over [t_k, t_k+1], from the state ``x0`` = (i, ψ_R).

    ``ident`` = (R_s, L_σ, L_M, R_R); states i, ψ_R with L_σ di/dt = v − R_s i − dψ_R/dt,
    dψ_R/dt = R_R i − (R_R/L_M) ψ_R (docs/commissioning.md §2).
    """
    from scipy.signal import lfilter  # heavy: scipy only for the fits
    R_s, L_s, L_M, R_R = (float(x) for x in ident)
    A = np.array([[-(R_s + R_R) / L_s, R_R / (L_s * L_M)], [R_R, -R_R / L_M]])
    Ad, Bd = _zoh(A, np.array([1.0 / L_s, 0.0]), T_s)
    # x_{k+1} = Ad x_k + Bd v_k: each state is a sum of two first-order filters of the input
    w, V = np.linalg.eig(Ad)
    n = len(v)
    out = np.zeros((2, n))
    if np.all(np.isreal(w)) and abs(w[0] - w[1]) > 1e-12:
        w, V = w.real, V.real
        Vi = np.linalg.inv(V)
        zb = Vi @ Bd
        z0 = Vi @ np.asarray(x0, dtype=float)
        modes = np.zeros((2, n))
        for j in range(2):
            # z_{k+1} = w z_k + zb v_k, z_0 given: z_k for k = 0..n-1
            y, _ = lfilter([0.0, zb[j]], [1.0, -w[j]], v, zi=[z0[j]])
            modes[j] = y
        out = V @ modes
    else:                      # a repeated or complex pair (not a passive RL network): step it
        x = np.asarray(x0, dtype=float)
        for k in range(n):
            out[:, k] = x
            x = Ad @ x + Bd * v[k]
    return out[0], out[1]


@dataclass
class Identified:
    """What the tests measured: values and standard deviations (from the residuals)."""

    values: Dict[str, float]
    std: Dict[str, float]
    notes: Dict[str, str] = field(default_factory=dict)
    rms_residual: Dict[str, float] = field(default_factory=dict)
    #: the inverter's voltage error (v_dead, its std, R_dc, current_band; docs/compensation.md)
    inverter: Dict[str, float] = field(default_factory=dict)
    #: the no-load test's points of the magnetizing curve (psi, i_M, their std, w_e; rising)
    magnetizing: List[Dict[str, float]] = field(default_factory=list)

    def motor(self, ratings: Optional[Dict[str, float]] = None) -> MotorParams:
        """
        Return the identified motor in the equal-self-inductance gauge.

        The gauge is L_s = L_r (equal stator and
        rotor leakage, the gauge of Krause's T-circuit): L_s = L_r = σL_s + L_M, L_sr = √(L_M L_s),
        R_r = R_R L_s / L_M. Terminal-equivalent to every gauge (MotorParams.with_identifiable);
        k_e = k_h = 0 (the core loss does not act on the terminals: docs/commissioning.md §5).
        """
        v = self.values
        L = v['L_sigma'] + v['L_M']
        return MotorParams(R_s=v['R_s'], R_r=v['R_R'] * L / v['L_M'], L_s=L, L_r=L,
                           L_sr=math.sqrt(v['L_M'] * L), J=v['J'], b=max(v['b'], 0.0),
                           pole_pairs=int(v['pole_pairs']), k_e=0.0, k_h=0.0,
                           **{k: x for k, x in (ratings or {}).items() if k in RATING_NAMES})


def dc_state(p, i0: float) -> Tuple[float, float]:
    """Return the standstill state (i, ψ_R) in DC steady state at the current ``i0``."""
    return i0, float(p[2]) * i0


def fit_standstill(v: np.ndarray, i: np.ndarray, T_s: float, R_s0: float, i0: float = 0.0
                   ) -> Tuple[Dict[str, float], Dict[str, float], float, np.ndarray]:
    """
    Output-error least squares of (R_s, L_σ, L_M, R_R) on a standstill record.

    From rest, or (``i0`` ≠ 0) from the DC steady state at the current i0 (:func:`dc_state`).

    Returns (values, standard deviations, RMS residual [A], final state (i, ψ_R)). The start
    comes from an ARX fit mapped to the continuous model (docs/commissioning.md §2).
    """
    from scipy.optimize import least_squares  # heavy: scipy.optimize only for the fits
    v = np.asarray(v, dtype=float)
    i = np.asarray(i, dtype=float)
    p0 = _arx_start(v, i, T_s, R_s0)

    miss = np.full(len(i), 1e6)             # a step of the search off every model: refused

    def resid(lp):
        # a trial step of the search may leave the models (an overflowing exp, a state matrix
        # of infinities): a large residual sends it back, instead of a LinAlgError out of eig
        if not np.all(np.abs(lp) < 50.0):
            return miss
        p = np.exp(lp)
        try:
            sim, _ = standstill_response(p, v, T_s, dc_state(p, i0))
        except np.linalg.LinAlgError:
            return miss
        r = sim - i
        return r if np.all(np.isfinite(r)) else miss

    best = None
    for start in (p0, _physical_start(v, i, T_s, R_s0)):
        sol = least_squares(resid, np.log(start), method='lm', x_scale=1.0, xtol=1e-12,
                            ftol=1e-12, gtol=1e-12, max_nfev=400)
        if best is None or sol.cost < best.cost:
            best = sol
    if np.array_equal(best.fun, miss) or not np.all(np.abs(best.x) < 50.0):
        raise NotInformative('the standstill fit found no RL model of the record (every start '
                             'left the models): the excitation or the measurement is unusable')
    n = len(i)
    r = best.fun
    s2 = float(r @ r) / max(n - 4, 1)
    Jm = best.jac
    try:
        cov = s2 * np.linalg.inv(Jm.T @ Jm)
        rel = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        rel = np.full(4, np.inf)
    vals = np.exp(best.x)
    values = dict(zip(IDENTIFIABLE_NAMES, (float(x) for x in vals)))
    std = dict(zip(IDENTIFIABLE_NAMES, (float(x * s) for x, s in zip(vals, rel))))
    sim, psi = standstill_response(vals, v, T_s, dc_state(vals, i0))
    return values, std, math.sqrt(s2), np.array([sim[-1], psi[-1]])


def flux_balance(ident, psi_s: np.ndarray, i: np.ndarray, v: np.ndarray, T_s: float,
                 R_s: float, window: int) -> Tuple[np.ndarray, np.ndarray]:
    """
    Return the rotor-flux magnitude balance of a record under voltage-model flux estimation.

    ``psi_s`` is the drive's voltage-model stator flux at t_k, ``i`` the measured currents
    (complex, α + jβ), ``v`` the commanded voltages over [t_k, t_k+1], ``R_s`` the resistance
    the flux was integrated with, ``ident`` = (R_s, L_σ, L_M, R_R). With ψ_R = ψ_s − L_σ i,
    m = |ψ_R| and i_d the current along ψ_R, the rotor equation of the inverse-Γ model gives,
    whatever the speed (the rotation term is perpendicular to ψ_R),

        dm/dt = R_R (i_d − m / L_M),

    integrated over the record and compared as differences of consecutive block means of
    ``window`` samples (docs/commissioning.md §3). ∫i_d is the trapezoid corrected by the
    change of the current's slope within each period (Euler-Maclaurin): the held voltage
    against the turning back-EMF bends the current, which the trapezoid alone would misread by
    T_s² ω_e |e| / (12 L_σ i_d) (4·10⁻⁴ at half the thesis motor's rated speed). Returns the
    block-mean differences of m and of R_R ∫i_d and R_R ∫m [Wb] and the offset's columns N:
    the model is y = a − b/L_M + N c.
    """
    _, L_s, L_M, R_R = (float(x) for x in ident)
    lam = psi_s - L_s * i
    m = np.abs(lam)
    u = lam / m
    i_d = (i * np.conj(u)).real
    e = np.gradient(lam, T_s)                      # dψ_R/dt at t_k (central differences)
    du = (e - (e * np.conj(u)).real * u) / m        # du/dt
    # the current's slope just after t_k and just before t_k+1 (the command v_k held between)
    s0 = (v[:-1] - R_s * i[:-1] - e[:-1]) / L_s
    s1 = (v[:-1] - R_s * i[1:] - e[1:]) / L_s
    d0 = (s0 * np.conj(u[:-1])).real + (i[:-1] * np.conj(du[:-1])).real
    d1 = (s1 * np.conj(u[1:])).real + (i[1:] * np.conj(du[1:])).real
    F = 0.5 * T_s * (i_d[:-1] + i_d[1:]) - T_s * T_s / 12.0 * (d1 - d0)
    G = 0.5 * T_s * (m[:-1] + m[1:])
    SF = np.concatenate([[0.0], np.cumsum(F)])
    SG = np.concatenate([[0.0], np.cumsum(G)])
    nb = len(m) // window
    n = nb * window

    def means(x):
        return x[:n].reshape(nb, window).mean(axis=1)
    # the voltage model's offset c (its integral of R_s × current noise, a random walk) moves m
    # by Re(c̄ u): one constant offset per segment of OFFSET_BLOCKS blocks, fitted as a nuisance
    cols = []
    for a in range(0, n, OFFSET_BLOCKS * window):
        mask = np.zeros(len(m))
        mask[a:a + OFFSET_BLOCKS * window] = 1.0
        cols += [np.diff(means(mask * u.real)), np.diff(means(mask * u.imag))]
    return (np.diff(means(m)), R_R * np.diff(means(SF)), R_R * np.diff(means(SG)),
            np.column_stack(cols))


def fit_joint(v: np.ndarray, i: np.ndarray, T_s: float, start: Dict[str, float],
              flux_record: Tuple[np.ndarray, np.ndarray, np.ndarray, float],
              window: int, i0: float = 0.0) -> Tuple[Dict[str, float], Dict[str, float], float]:
    """
    Refine (R_s, L_σ, L_M, R_R) on the standstill record and the speed test's flux balance.

    ``v``, ``i``, ``i0``: the standstill record (as :func:`fit_standstill`); ``start``: its values;
    ``flux_record`` = (ψ_s, i, v, R_s) of the speed test from the end of magnetizing
    (:func:`flux_balance`). The standstill sees L_M only through the slow rotor time constant;
    the turning rotor's flux balance sees m/i_d = L_M in every steady state, i.e. L_σ + L_M
    (L_σ moves m and i_d the other way) against a much larger signal. The balance residuals are
    weighted by the standstill's residual scale over their own (one-lag autocorrelation
    included: neighbouring block differences share a block), so the covariance is
    s² (JᵀJ)⁻¹ of the joint problem. Returns (values, standard deviations, RMS standstill
    residual [A]).
    """
    from scipy.optimize import least_squares  # heavy: scipy.optimize only for the fits
    v = np.asarray(v, dtype=float)
    i = np.asarray(i, dtype=float)
    psi_s, i_c, v_c, R_s_used = flux_record
    p0 = np.array([start[n] for n in IDENTIFIABLE_NAMES])

    y, a, b, N = flux_balance(p0, psi_s, i_c, v_c, T_s, R_s_used, window)
    # the offsets are projected out (variable projection; their columns hardly move with p)
    Q, sv, _ = np.linalg.svd(N, full_matrices=False)
    Q = Q[:, sv > 1e-9 * sv.max()] if sv.size else Q
    dof = len(y) - Q.shape[1] - 1

    def project(x):
        return x - Q @ (Q.T @ x)

    def balance(p):
        y, a, b, _ = flux_balance(p, psi_s, i_c, v_c, T_s, R_s_used, window)
        return project(y - a + b / p[2])

    r_ss = standstill_response(p0, v, T_s, dc_state(p0, i0))[0] - i
    s_ss = math.sqrt(float(r_ss @ r_ss) / max(len(i) - 4, 1))
    # the balance's own noise: its residuals with L_M fitted to it alone (linear in 1/L_M)
    yp, ap, bp = project(y), project(a), project(b)
    g = float(bp @ (ap - yp)) / float(bp @ bp)
    r_fb = yp - ap + g * bp
    var_fb = float(r_fb @ r_fb) / max(dof, 1)
    lag1 = float(r_fb[1:] @ r_fb[:-1]) / max(dof, 1)
    # the variance of a sum of the residuals with their one-lag correlation, per residual
    var_fb = max(var_fb + 2.0 * lag1, 0.25 * var_fb)
    w = s_ss / math.sqrt(var_fb) if var_fb > 0 else 0.0

    def resid(lp):
        p = np.exp(lp)
        return np.concatenate([standstill_response(p, v, T_s, dc_state(p, i0))[0] - i,
                               w * balance(p)])

    sol = least_squares(resid, np.log(p0), method='lm', x_scale=1.0, xtol=1e-12, ftol=1e-12,
                        gtol=1e-12, max_nfev=200)
    n_ss = len(i)
    r = sol.fun[:n_ss]
    s2 = float(r @ r) / max(n_ss - 4, 1)
    try:
        rel = np.sqrt(np.maximum(np.diag(s2 * np.linalg.inv(sol.jac.T @ sol.jac)), 0.0))
    except np.linalg.LinAlgError:
        rel = np.full(4, np.inf)
    vals = np.exp(sol.x)
    return (dict(zip(IDENTIFIABLE_NAMES, (float(x) for x in vals))),
            dict(zip(IDENTIFIABLE_NAMES, (float(x * s) for x, s in zip(vals, rel)))),
            math.sqrt(s2))


def _physical_start(v, i, T_s, R_s0):
    """
    Return a start from the probe alone.

    σL_s from the largest current slope after a voltage step, L_M = 10 σL_s, R_R = R_s.
    """
    di = np.abs(np.diff(i))
    dv = np.abs(np.diff(v))
    k = int(np.argmax(dv))
    slope = abs(i[k + 2] - i[k + 1]) if k + 2 < len(i) else di.max()
    L_s = abs(v[k + 1] - v[k]) * T_s / max(slope, 1e-12)
    L_s = min(max(L_s, 1e-6), 10.0)
    return np.array([R_s0, L_s, 10.0 * L_s, R_s0])


def _arx_start(v, i, T_s, R_s0):
    """
    Start the standstill fit from a second-order ARX model.

    (R_s, L_σ, L_M, R_R) from a second-order ARX fit, mapped through the continuous form Y(s) =
    (1/L_σ)(s + z)/((s + p1)(s + p2)), z = R_R/L_M, p1 p2 = R_s z/L_σ, p1 + p2 = (R_s + R_R)/L_σ +
    z. Falls back to the probe's start when the fit is not a passive RL network.
    """
    Phi = np.column_stack([i[1:-1], i[:-2], v[1:-1], v[:-2]])
    y = i[2:]
    try:
        a1, a2, b1, b2 = np.linalg.lstsq(Phi, y, rcond=None)[0]
        zs = np.roots([1.0, -a1, -a2])
        if not (np.all(np.isreal(zs)) and np.all((zs.real > 0) & (zs.real < 1))):
            raise ValueError
        p = -np.log(zs.real) / T_s
        L_s = T_s / b1 if b1 > 0 else None
        R_s = (1.0 - a1 - a2) / (b1 + b2)
        z = p[0] * p[1] * L_s / R_s
        R_R = L_s * (p[0] + p[1] - z) - R_s
        L_M = R_R / z
        out = np.array([R_s, L_s, L_M, R_R])
        if not np.all(np.isfinite(out)) or np.any(out <= 0):
            raise ValueError
        return out
    except (ValueError, TypeError, np.linalg.LinAlgError, ZeroDivisionError):
        return _physical_start(v, i, T_s, R_s0)


def fit_dc_levels(v: np.ndarray, i: np.ndarray) -> Tuple[float, float, float, float]:
    """
    Fit the steady (V, I) points of the inverter-error test: V = R·I + c·sgn(I).

    Returns (R, c, std R, std c); least squares, the standard deviations from the residuals
    (0 with as many points as unknowns). :class:`NotInformative` without two magnitudes.
    """
    v, i = np.asarray(v, float), np.asarray(i, float)
    if len(set(np.round(np.abs(i), 9))) < 2 or np.all(i > 0) or np.all(i < 0):
        raise NotInformative('the inverter-error test needs two current magnitudes of each sign')
    A = np.column_stack([i, np.sign(i)])
    x, *_ = np.linalg.lstsq(A, v, rcond=None)
    dof = len(v) - 2
    s2 = float(np.sum((A @ x - v) ** 2) / dof) if dof > 0 else 0.0
    cov = s2 * np.linalg.inv(A.T @ A)
    return float(x[0]), float(x[1]), math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])


def fit_mechanics(omega: np.ndarray, tau: np.ndarray, T_s: float, window: int
                  ) -> Tuple[float, float, float, float, float]:
    """
    Fit the inertia J and friction b from the no-load speed run.

    J, b and their standard deviations (and the RMS residual [N·m·s]) from J (ω_end − ω_start) + b
    ∫ω dt = ∫τ̂ dt over consecutive windows of ``window`` steps (no load on the shaft). ``tau[k]``
    acts over [t_k, t_k+1].
    """
    n = (len(omega) - 1) // window
    rows, rhs = [], []
    for w in range(n):
        a, e = w * window, (w + 1) * window
        rows.append((omega[e] - omega[a], T_s * (0.5 * omega[a] + omega[a + 1:e].sum()
                                                 + 0.5 * omega[e])))
        rhs.append(T_s * (0.5 * tau[a] + tau[a + 1:e].sum() + 0.5 * tau[e]))
    Phi, y = np.array(rows), np.array(rhs)
    theta, *_ = np.linalg.lstsq(Phi, y, rcond=None)
    r = y - Phi @ theta
    s2 = float(r @ r) / max(len(y) - 2, 1)
    cov = s2 * np.linalg.pinv(Phi.T @ Phi)
    return (float(theta[0]), float(theta[1]), math.sqrt(max(cov[0, 0], 0.0)),
            math.sqrt(max(cov[1, 1], 0.0)), math.sqrt(s2))


class Commissioning:
    """
    The commissioning test sequence, one period at a time (module docstring).

    ``step(i_a, i_b, omega)`` takes the measurement at t_k and returns the voltage (v_α, v_β)
    to hold over [t_k, t_k+1], or None when the tests are over; then :meth:`result`.

    Parameters
    ----------
    T_s : control period [s]
    i_max, v_max : the drive's current- and voltage-vector limits [A], [V]
    pole_pairs : from the nameplate (None: measured in the speed test)
    test_speed : top speed of the speed test [rad/s] (the nameplate's: half the rated speed)
    locked : the rotor is locked: the standstill tests only; J and b must come from elsewhere
    flux : magnetizing flux of the speed test [Wb] (None: 0.4·i_max·L_M, capped)
    magnetizing : run the no-load test after the speed test (the magnetizing curve)

    """

    def __init__(self, T_s: float, i_max: float, v_max: float, pole_pairs: Optional[int] = None,
                 test_speed: Optional[float] = None, locked: bool = False,
                 flux: Optional[float] = None, magnetizing: bool = True):
        self.T_s = check_real('T_s', T_s, 0.0, lo_open=True)
        self.magnetizing = bool(magnetizing)
        self._nl: Optional[NoLoadTest] = None
        self.i_max = check_real('current limit', i_max, 0.0, lo_open=True)
        self.v_max = check_real('voltage limit', v_max, 0.0, lo_open=True)
        self.pole_pairs = pole_pairs
        self.locked = bool(locked)
        if not self.locked and test_speed is None:
            raise InvalidParameter('test speed', None,
                                   'the speed test needs a top speed (a nameplate, or a test '
                                   'speed) unless the rotor is locked')
        self.test_speed = (None if test_speed is None
                           else check_real('test speed', test_speed, 0.0, lo_open=True))
        self.flux = flux
        self.k = 0
        self.phase = 'probe'
        self.phase_k = 0
        self.log_v: List[Tuple[float, float]] = []
        self.log_i: List[Tuple[float, float]] = []
        self.log_w: List[float] = []
        self.marks: Dict[str, int] = {'probe': 0}
        self.peak_i = 0.0
        self.peak_v = 0.0
        self._hold = 0.0
        self._win: List[float] = []
        self._prev_mean = None
        self.R_s0 = None
        self.electrical = None
        self.mechanical = None
        self._exc = None
        self.inverter_error: Optional[InverterErrorModel] = None   # once the DC levels are in
        self.excitation_bias = 0.0
        self.inverter_fit: Dict[str, float] = {}
        self.dc_levels: List[Tuple[float, float]] = []
        self._level = 0
        self._v_level = 0.0
        self.failure: Optional[str] = None
        self.done = False
        self.progress = ''

    # ---------------------------------------------------------------------------- stepping
    def _goto(self, phase: str) -> None:
        self.phase = phase
        self.phase_k = 0
        self.marks[phase] = self.k

    def _fail(self, text: str):
        self.failure = text
        self.done = True
        return None

    def step(self, i_a: float, i_b: float, omega: float = 0.0):
        """Map the measurement at t_k to the voltage over [t_k, t_k+1] (None: tests over)."""
        if self.done:
            return None
        self.log_i.append((i_a, i_b))
        self.log_w.append(omega)
        mag = math.hypot(i_a, i_b)
        self.peak_i = max(self.peak_i, mag)
        if mag > TRIP_FRACTION * self.i_max:
            self.log_v.append((0.0, 0.0))
            return self._fail(f'|i_s| = {mag:.4g} A above {TRIP_FRACTION:g} x the current limit '
                              f'{self.i_max:g} A in the {self.phase} test at '
                              f't = {self.k * self.T_s:.4f} s: stopped')
        cmd = getattr(self, '_' + self.phase)(i_a, i_b, omega)
        if cmd is None:
            self.done = True
            self.log_v.append((0.0, 0.0))
            return None
        va, vb = cmd
        m = math.hypot(va, vb)
        if m > self.v_max:
            va, vb = va * self.v_max / m, vb * self.v_max / m
        self.log_v.append((va, vb))         # the voltage the motor gets: what the fits see
        if self.inverter_error is not None:
            va, vb = self.inverter_error.command(va, vb, i_a, i_b)
        self.peak_v = max(self.peak_v, math.hypot(va, vb))
        self.k += 1
        self.phase_k += 1
        return va, vb

    def _probe(self, i_a, i_b, w):
        """Ramp the α voltage until the current reaches PROBE_CURRENT·i_max."""
        if abs(i_a) >= PROBE_CURRENT * self.i_max:
            # V/I over-estimates R_s (the rotor's transient, the inverter's error): a loop gain
            # on the safe side for the levels, whose fit gives R_s
            self.R_s0 = self._hold / abs(i_a)
            self._goto('levels')
            self._level = 0
            self._v_level = -self._hold if LEVELS[0] < 0 else self._hold
            self._win, self._prev_mean = [], None
            return self._levels(i_a, i_b, w)
        self._hold = min(self._hold + 0.25 * self.v_max * self.T_s, 0.5 * self.v_max)
        if self._hold >= 0.5 * self.v_max and self.phase_k * self.T_s > 5.0:
            return self._fail(f'no current: |i_s| = {abs(i_a):.3g} A at {self._hold:.4g} V '
                              f'(half the voltage limit) after {self.phase_k * self.T_s:.1f} s; '
                              f'is the motor connected?')
        self.progress = f'probe: {self._hold:.3g} V, {i_a:.3g} A'
        return self._hold, 0.0

    def _levels(self, i_a, i_b, w):
        """
        Hold the α current at each of LEVELS × i_max; record the steady (V, I); then fit.

        An integral current loop (time constant LEVEL_LOOP_S on the probe's V/I) moves the
        voltage; a level is done when two windows of LEVEL_WINDOW_S agree to 1e-3 and sit on
        the target within 1 %.
        """
        target = LEVELS[self._level] * self.i_max
        self._v_level += self.T_s * (self.R_s0 / LEVEL_LOOP_S) * (target - i_a)
        n = max(int(round(LEVEL_WINDOW_S / self.T_s)), 10)
        self._win.append((self._v_level, i_a))
        if len(self._win) == n:
            v_mean = sum(x[0] for x in self._win) / n
            i_mean = sum(x[1] for x in self._win) / n
            self._win = []
            prev, self._prev_mean = self._prev_mean, (v_mean, i_mean)
            if (prev is not None and abs(i_mean - prev[1]) < LEVEL_STEADY * abs(target)
                    and abs(v_mean - prev[0]) < LEVEL_STEADY * abs(v_mean)
                    and abs(i_mean - target) < 1e-2 * abs(target)):
                self.dc_levels.append((v_mean, i_mean))
                self._level += 1
                self._prev_mean = None
                if self._level == len(LEVELS):
                    return self._identify_inverter(i_a, i_b, w)
        if self.phase_k * self.T_s > 20.0 * len(LEVELS):
            return self._fail(f'the inverter-error test did not settle at {target:.4g} A within '
                              f'{20.0 * len(LEVELS):g} s ({i_a:.4g} A at {self._v_level:.4g} V)')
        self.progress = f'inverter error: level {self._level + 1}/{len(LEVELS)}, {i_a:.4g} A'
        return self._v_level, 0.0

    def _identify_inverter(self, i_a, i_b, w):
        """Fit the DC levels; compensate from here on; R_s0 from the fit; go on to excite."""
        v, i = zip(*self.dc_levels)
        R, c, sR, sc = fit_dc_levels(v, i)
        v_dead = max(c, 0.0) / ALPHA_ERROR
        self.inverter_fit = {'v_dead': v_dead, 'v_dead_std': sc / ALPHA_ERROR,
                             'R_dc': R, 'R_dc_std': sR}
        self.R_s0 = R
        model = InverterErrorModel(v_dead, 0.0, COMPENSATION_BAND * self.i_max)
        if ALPHA_ERROR * v_dead > ERROR_SHARE * R * TEST_CURRENT * self.i_max:
            # an error that matters against the test voltage: compensated from here on, and the
            # record so far (probe, levels) taken as the motor got it
            self.inverter_error = model
            self.log_v = [model.motor_voltage(va, vb, ia, ib)
                          for (va, vb), (ia, ib) in zip(self.log_v, self.log_i)]
        self._goto('excite')
        self._exc = self._excitation()
        return self._excite(i_a, i_b, w)

    def _excitation(self) -> List[float]:
        V = self.R_s0 * TEST_CURRENT * self.i_max
        bias = 0.0
        if self.inverter_error is not None:
            # around a DC current: no phase current crosses zero (BIAS, SWING)
            bias, V = self.R_s0 * BIAS * self.i_max, self.R_s0 * SWING * self.i_max
        self.excitation_bias = bias
        out = []
        for level, seconds in EXCITATION:
            out += [bias + level * V] * max(1, int(round(seconds / self.T_s)))
        return out

    def _excite(self, i_a, i_b, w):
        if self.phase_k >= len(self._exc):
            self._identify_electrical()
            if self.locked:
                return None
            self._start_speed_test()
            return self._speed(i_a, i_b, w)
        self.progress = f'standstill test {100.0 * self.phase_k / len(self._exc):.0f} %'
        return self._exc[self.phase_k], 0.0

    def _identify_electrical(self) -> None:
        # from rest, or (a biased excitation) from the last level's DC steady state
        k0 = self.marks['excite'] if self.excitation_bias else 0
        v = np.array(self.log_v)[k0:, 0]
        i = np.array(self.log_i)[k0:k0 + len(v), 0]
        i0 = float(i[0]) if k0 else 0.0
        values, std, rms, _ = fit_standstill(v, i, self.T_s, self.R_s0, i0)
        self.electrical = (values, std, rms)
        self._standstill_record = (v, i, i0)
        # the state at t_k of the current step: one more model step from the last logged one
        p = np.array([values[n] for n in IDENTIFIABLE_NAMES])
        _, psi = standstill_response(p, np.append(v, 0.0), self.T_s, dc_state(p, i0))
        self._psi_R0 = float(psi[-1])
        self._excitation_peak = float(np.max(np.abs(i)))

    # ----------------------------------------------------------------------- speed test
    def _start_speed_test(self) -> None:
        e = self.electrical[0]
        self.R_s, self.L_sigma, self.L_M, self.R_R = (e[n] for n in IDENTIFIABLE_NAMES)
        i_a = self.log_i[-1][0]
        # voltage-model stator flux: ψ_s = σL_s i + ψ_R at the start (from the fitted model)
        self.psi = [self.L_sigma * i_a + self._psi_R0, 0.0]
        self._psi_R_prev = (self._psi_R0, 0.0)
        i_d = (self.flux / self.L_M) if self.flux else 0.4 * self.i_max
        self.i_d = min(i_d, 0.5 * self.i_max)
        self.i_q = math.sqrt(max((SPEED_CURRENT * self.i_max) ** 2 - self.i_d ** 2, 0.0))
        self.t_mag = min(max(4.0 * self.L_M / self.R_R, 0.05), 3.0)
        self.w_peak = 0.0
        self._emf = 0.0
        self.t_accel = 0.0
        self.log_psi: List[Tuple[float, float]] = []
        self._goto('magnetize')

    def _speed(self, i_a, i_b, w):
        T_s = self.T_s
        # the flux after the previous period: ψ_s += T_s (V_{k-1} − R_s ī)
        if self.phase != 'magnetize' or self.phase_k > 0:
            va, vb = self.log_v[-1]
            ia0, ib0 = self.log_i[-2]
            self.psi[0] += T_s * (va - self.R_s * 0.5 * (ia0 + i_a))
            self.psi[1] += T_s * (vb - self.R_s * 0.5 * (ib0 + i_b))
        self.log_psi.append((self.psi[0], self.psi[1]))
        pr_a = self.psi[0] - self.L_sigma * i_a
        pr_b = self.psi[1] - self.L_sigma * i_b
        mag = math.hypot(pr_a, pr_b)
        c, s = (pr_a / mag, pr_b / mag) if mag > 1e-3 * self.L_M * self.i_max else (1.0, 0.0)
        e_a = (pr_a - self._psi_R_prev[0]) / T_s
        e_b = (pr_b - self._psi_R_prev[1]) / T_s
        self._psi_R_prev = (pr_a, pr_b)
        t = self.phase_k * T_s
        aw = abs(w)
        self.w_peak = max(self.w_peak, aw)
        iq = 0.0
        if self.phase == 'magnetize':
            if t >= self.t_mag:
                self._goto('accelerate')
                return self._speed_cmd(i_a, i_b, c, s, e_a, e_b, self.i_q)
        elif self.phase == 'accelerate':
            iq = self.i_q
            stuck = t > 1.0 and aw < 0.01 * SPEED_FRACTION * self.test_speed   # cannot turn
            # the rotor's EMF, low-passed: its finite difference carries the current noise times
            # L_σ/T_s (30 V a period on a 41 mH leakage with 0.05 A noise), which ended a run-up
            # after 3 periods
            self._emf += min(1.0, T_s / EMF_FILTER_S) * (math.hypot(e_a, e_b) - self._emf)
            if aw >= SPEED_FRACTION * self.test_speed or self._emf > 0.5 * self.v_max \
                    or t > 10.0 or stuck:
                self.t_accel = t
                self._goto('coast')
                iq = 0.0
        elif self.phase == 'coast':
            if t >= max(0.2, 0.3 * self.t_accel):
                self._goto('brake')
                iq = -self.i_q * math.copysign(1.0, w if w else 1.0)
        elif self.phase == 'brake':
            iq = -self.i_q * math.copysign(1.0, w if w else 1.0)
            if aw <= 0.05 * max(self.w_peak, 1e-9) or t > 2.0 * max(self.t_accel, 0.5):
                self._goto('rest')
                iq = 0.0
        elif self.phase == 'rest':
            if t >= 0.05:
                # the no-load test needs a rotor that turns (the speed test saw it turn)
                turned = self.w_peak >= 0.05 * SPEED_FRACTION * self.test_speed
                return self._start_noload(i_a, i_b, w) if self.magnetizing and turned else None
            return 0.0, 0.0
        self.progress = f'{self.phase}: omega_r = {w:.4g} rad/s'
        return self._speed_cmd(i_a, i_b, c, s, e_a, e_b, iq)

    _magnetize = _accelerate = _coast = _brake = _rest = _speed

    # ----------------------------------------------------------------------- no-load test
    def _start_noload(self, i_a, i_b, w):
        """Start the no-load test (:mod:`im_adapt.magnetizing`) from rest."""
        e, sd = self.electrical[0], self.electrical[1]
        w_e_max = (self.pole_pairs or 1) * SPEED_FRACTION * self.test_speed
        self._nl = NoLoadTest(self.T_s, self.i_max, self.v_max, e['R_s'], e['L_sigma'],
                              e['L_M'], e['R_R'], w_e_max, self.t_mag,
                              max(0.5, 3.0 * self.t_accel), R_s_std=sd['R_s'])
        self._goto('noload')
        return self._noload(i_a, i_b, w)

    def _noload(self, i_a, i_b, w):
        cmd = self._nl.step(i_a, i_b)
        self.progress = self._nl.progress
        return cmd

    def _speed_cmd(self, i_a, i_b, c, s, e_a, e_b, iq):
        ra = self.i_d * c - iq * s
        rb = self.i_d * s + iq * c
        g = 0.5 * self.L_sigma / self.T_s
        return (self.R_s * i_a + e_a + g * (ra - i_a), self.R_s * i_b + e_b + g * (rb - i_b))

    # ---------------------------------------------------------------------------- results
    def result(self) -> Identified:
        """
        Return the identified parameters.

        :class:`NotInformative` when the tests ended early or the data cannot determine a
        parameter.
        """
        if self.failure:
            raise NotInformative(self.failure)
        if not self.done or self.electrical is None:
            raise NotInformative(f'the tests did not finish (stopped in the {self.phase} test)')
        values, std, rms = self.electrical
        values, std = dict(values), dict(std)
        notes = {}
        for n in IDENTIFIABLE_NAMES:
            if not std[n] < 0.05 * values[n]:
                raise NotInformative(
                    f'{n} = {values[n]:.4g} is not determined by the standstill test '
                    f'(standard deviation {std[n]:.3g}, residual {rms:.3g} A RMS at '
                    f'{self._excitation_peak:.3g} A peak): too little current against the noise')
        out = Identified(values, std, notes, {'standstill_A': rms})
        if self.inverter_fit:                   # the inverter's error, as the drive compensates
            out.inverter = dict(self.inverter_fit, current_band=COMPENSATION_BAND * self.i_max,
                                compensated=self.inverter_error is not None)
        if self.locked:
            return out
        self._identify_mechanics(out)
        self._refine_electrical(out)
        if self._nl is not None:
            out.magnetizing = sorted(self._nl.points, key=lambda p: p['psi'])
            if self._nl.stopped:
                out.notes['saturation'] = self._nl.stopped
            elif len(out.magnetizing) < MIN_POINTS:
                out.notes['saturation'] = (
                    f'{len(out.magnetizing)} points of the magnetizing curve (fewer than '
                    f'{MIN_POINTS}: the current limit came first)')
        return out

    def _refine_electrical(self, out: Identified) -> None:
        """Refit the inverse-Γ set on the standstill record and the speed test's flux balance."""
        k0, ka, kr = self.marks['magnetize'], self.marks['accelerate'], self.marks['rest']
        psi = np.array(self.log_psi[ka - k0:kr - k0])
        i = np.array(self.log_i[ka:kr])
        v = np.array(self.log_v[ka:kr])
        window = max(int(round(FLUX_WINDOW / self.T_s)), 5)
        if len(psi) < 4 * window:
            return
        c = (psi[:, 0] + 1j * psi[:, 1], i[:, 0] + 1j * i[:, 1], v[:, 0] + 1j * v[:, 1],
             self.R_s)
        v_ss, i_ss, i0 = self._standstill_record
        values, std, rms = fit_joint(v_ss, i_ss, self.T_s, self.electrical[0], c, window, i0)
        out.values.update(values)
        out.std.update(std)
        out.rms_residual['standstill_A'] = rms
        out.notes['L_M'] = 'standstill and speed-test flux balance (docs/commissioning.md §3)'

    def _identify_mechanics(self, out: Identified) -> None:
        T_s = self.T_s
        k0 = self.marks['magnetize']
        w = np.array(self.log_w[k0:])
        i = np.array(self.log_i[k0:])
        psi = np.array(self.log_psi)
        n = min(len(psi), len(i), len(w))
        w, i, psi = w[:n], i[:n], psi[:n]
        cross = psi[:, 0] * i[:, 1] - psi[:, 1] * i[:, 0]
        ka = self.marks['accelerate'] - k0
        applied = float(np.mean(np.abs(cross[ka:self.marks['coast'] - k0])))
        turned = float(np.max(np.abs(w)))
        if turned < 0.05 * SPEED_FRACTION * self.test_speed:
            t_acc = (self.marks['coast'] - self.marks['accelerate']) * T_s
            raise NotInformative(
                f'J test: the rotor did not turn (|omega_r| <= {turned:.3g} rad/s with '
                f'{applied:.3g} Wb·A of torque per pole pair applied for {t_acc:.2f} s); free '
                f'the rotor, or commission it locked (--locked-rotor) with J and b given')
        # pole pairs: the flux's rotation against the shaft, slip removed
        pr = psi - self.L_sigma * i
        ang = np.unwrap(np.arctan2(pr[:, 1], pr[:, 0]))
        w_psi = np.diff(ang) / T_s
        m2 = np.maximum(np.sum(pr * pr, axis=1), 1e-30)
        slip = self.R_R * (pr[:, 0] * i[:, 1] - pr[:, 1] * i[:, 0]) / m2
        sel = np.abs(w[:-1]) > 0.3 * turned
        ratio = float(np.median((w_psi[sel] - slip[:-1][sel]) / w[:-1][sel]))
        vp = self.pole_pairs
        if vp is None:
            vp = int(round(ratio))
            if vp < 1 or abs(ratio - vp) > 0.2:
                raise NotInformative(f'pole pairs: the flux turns {ratio:.3f} times as fast as '
                                     f'the shaft, not a whole number; give a nameplate')
            out.notes['pole_pairs'] = f'measured (flux/shaft speed ratio {ratio:.4f})'
        else:
            out.notes['pole_pairs'] = f'nameplate (measured ratio {ratio:.4f})'
        tau = vp * cross
        # 0.1 s windows: an encoder's speed is quantized (2048 lines, 10-period M-method: 0.77
        # rad/s steps), and noise on each window's Δω biases J low (errors in variables): at
        # 20 ms J came out 23 % low on krause_3hp, at 0.1 s within 0.5 % (docs/commissioning.md)
        window = max(int(round(MECHANICS_WINDOW_S / T_s)), 5)
        J, b, sJ, sb, rms = fit_mechanics(w, tau, T_s, window)
        if not (J > 0 and sJ < 0.05 * J):
            raise NotInformative(f'J = {J:.4g} kg·m² is not determined by the speed test '
                                 f'(standard deviation {sJ:.3g})')
        out.values.update(J=J, b=b, pole_pairs=vp)
        out.std.update(J=sJ, b=sb)
        out.rms_residual['mechanics_Nms'] = rms


def rated_flux(ident: Dict[str, float], plate: Nameplate, theta: float) -> float:
    """
    Return the rated rotor flux |φ_r| of the nameplate.

    At the nameplate's rated voltage, frequency and speed, in the gauge θ = L_sr/L_r (φ_r = ψ_R/θ):
    the inverse-Γ circuit's magnetizing branch voltage over ω_e at the rated slip
    (docs/commissioning.md §4).
    """
    R_s, L_sigma, L_M, R_R = (ident[n] for n in IDENTIFIABLE_NAMES)
    return rated_rotor_flux(R_s, L_sigma, L_M, R_R, theta, plate.voltage, plate.frequency,
                            plate.speed, plate.pole_pairs)


def simulate_commissioning(plant, com: Commissioning, max_steps: int = 10 ** 7) -> Commissioning:
    """
    Run ``com`` on a ROS-free :class:`~im_plant.plant_sim.PlantSimulator`.

    The order is that of the lock-step graph: measure t_k, command, integrate.
    """
    for _ in range(max_steps):
        m = plant.measure()
        cmd = com.step(m.i_alpha, m.i_beta, m.omega_r)
        if cmd is None:
            break
        plant.step(*cmd)
        if plant.trip is not None:
            com._fail(f'the plant tripped at t = {plant.trip[0]:.4f} s: {plant.trip[1]}')
            break
    return com
