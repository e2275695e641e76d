"""
Torque-tracking drive controller with flux strategies.

Seed 000 §3.2-3.3, eq. 3.1, 3.13, 3.25-3.31; §4.2, eq. 4.10-4.14 with adapted estimates.

One call of :meth:`DriveController.compute` per control period t_k:

1. Mechanical loop (eq. 3.1): τ* = J θ̈* + b θ̇* + τ_c(θ, ω) − k_v(ω − ω*) − k_p(θ − θ*).
   The feedforward part and the load model are differentiated analytically (trajectory jerk,
   ∂τ_c/∂θ · ω); the PD part passes through a critically damped 2nd-order filter whose states are
   its value and derivative. So dτ*/dt is known without numerical differentiation.
2. Flux strategy → target flux → 2nd-order filter → (φ*, dφ*/dt, d²φ*/dt²) (:mod:`.flux`).
3. Reference model (eq. 3.13 in flux form, :mod:`.reference`) → dq currents, electrical slip ω_sl;
   field angle ρ integrated (trapezoid over the samples) from dρ/dt = v ω_r + ω_sl with the
   *measured* speed (indirect field orientation); αβ reference by eq. 3.26.
4. Voltage: V = V* + ΔV. V* = eq. 3.29 (exact inverse of the stator equation at the measured
   speed), rotated to the middle of the hold interval [t_k, t_k + T_s] when ``hold_compensation``
   (the voltage is held for a period; a rotating vector sampled at t_k lags by T_s/2).
   ΔV = −K₁ (i − i*) + v ω_r θ 𝒥 (φ̂ − φ*)   (eq. 3.30 with measured currents, observed fluxes).
   Sign convention: ΔV = −K₁(i − i*) with K₁ = k₁ I > 0 (the thesis's "k₁ = −40" is this gain
   with the sign of ΔV = K(x̂ − x*)). The flux term cancels the non-skew speed coupling of the
   stator equation, so with exact fluxes ½eᵀDe decreases along the tracking error
   (docs/controller.md); ``flux_coupling='thesis'`` uses the printed K₂ = −(vL_sr/2L_r) ω_r* 𝒥
   in ΔV = K₂(φ̂ − φ*) instead, ``'none'`` drops it.
5. Limits (docs/limits.md): τ* clamped to the torque limit and to the torque the current limit
   allows at the present flux; no torque pushing further beyond the speed limit; the flux target
   capped above base speed so the steady voltage fits the voltage limit (field weakening); the
   voltage vector scaled into the limit with an anti-windup that cannot latch: no controller state
   is ever frozen, and the one integrator (the speed task's θ* = ∫ω*) is back-calculated to the
   shaft while the voltage is limited.

Everything per call is scalar Python.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass, field
import math
from typing import Optional

from im_common.compensation import InverterErrorModel
from im_common.loads import make_load, MODEL_KINDS
from im_common.params import (check_real, estimate_arguments, InvalidParameter, MotorParams, RATED,
                              resolve_rated, THESIS_FLUX_LEVELS, THESIS_MOTOR)

from .flux import FluxStrategy, LOSS_OPTIMAL, LowPass2, STRATEGIES
from .reference import dq_reference, feedforward_dq, ModelCoefficients, steady_state
from .trajectories import SetpointPosition, SetpointSpeed, SetpointTorque, THESIS_TRAJECTORIES

MODES = ('position', 'speed', 'torque')
#: the tasks of the thesis's tables (torque is ours)
THESIS_TASKS = ('position', 'speed')
PROFILES = ('thesis', 'setpoint')
FLUX_COUPLINGS = ('cancel', 'thesis', 'none')
DEFAULT_FLUX_PREVIEW = 0.06
# Field weakening keeps the steady stator voltage ω_e (L_s/L_sr) φ below this share of the voltage
# limit; the rest is headroom for the resistive drop, the q-axis leakage drop and the transients.
DEFAULT_VOLTAGE_MARGIN = 0.85
# Under a current limit the optimizing strategies choose no flux whose steady current for the
# demanded torque exceeds this share of the limit; the rest is headroom for the flux rise
# (T_r dφ*/dt on the d axis) and the PD correction (docs/limits.md).
DEFAULT_CURRENT_MARGIN = 0.9
# Fields whose default RATED takes the motor model's rating (im_common.params.default_limits),
# and their value for a motor without that rating (the thesis's; ``from_ratings`` says which).
RATED_FIELDS = {'v_limit': None, 'current_limit': None, **THESIS_FLUX_LEVELS}
# |i_q*| ≤ MAGNETIZING_RATIO · i_d*/√σ: the torque a partly magnetized machine is asked for
MAGNETIZING_RATIO = 2.0
# Reconfigurable while running (ros2 param set on the controller node): gains, strategy, flux
# levels and limits. Everything else (mode, profile, motor model, period) is fixed for a run.
LIVE_FIELDS = ('strategy', 'phi_d', 'phi_min', 'phi_max', 'k1', 'k_p', 'k_v', 'current_gain',
               'flux_coupling', 'v_limit', 'torque_limit', 'current_limit', 'speed_limit',
               'field_weakening', 'voltage_margin', 'current_margin', 'flux_preview',
               'setpoint_duration')

# §3.4.6, decoded: the printed table is three columns (electrical gains | position | speed) read
# row by row: k1, k_e on the electrical side; position k_p = 10, k_v = 1; speed k_p = 1, k_v = 3.
DEFAULT_GAINS = {'position': (10.0, 1.0), 'speed': (1.0, 3.0), 'torque': (0.0, 0.0)}
DEFAULT_LOADS = {'position': 'pendulum', 'speed': 'linear', 'torque': 'none'}


_real = check_real


@dataclass
class ControllerConfig:
    """
    Configuration of :class:`DriveController` (SI units).

    Validated on construction; every error names the field.

    mode            'position' | 'speed' | 'torque'
    profile         'thesis' (§3.4.4 trajectories) | 'setpoint' (``set_setpoint``)
    strategy        'min_energy' (eq. 3.19/3.25) | 'constant_flux' (φ_d) | 'min_loss' |
                    'optimal' (the loss-optimal flux trajectory planned over a reference known
                    ahead, docs/controller.md §10; else min_loss, and ``plan_note`` says so)
    phi_d, phi_min, phi_max   [Wb] constant-flux level and the strategy bounds (§3.4.6);
                    RATED (default) → the model's rated flux, φ_min = 1/6 of it
                    (im_common.params.default_limits), else the thesis's 1.2, 0.2, 1.2 Wb
    k1              [V/A] > 0, current gain K₁ = k₁ I (§3.4.6 "k1 = −40", sign see module doc)
    k_p, k_v        [N·m/rad], [N·m·s/rad] PD gains of eq. 3.1; None → per-mode defaults
                    (position 10, 1; speed 1, 3; torque unused)
    load_known      use the load model τ_c(θ, ω) in eq. 3.1 (else τ_c = 0)
    load            'pendulum' | 'linear' | 'constant' | 'none' | None (per-mode default)
    load_mgl, load_c1, load_c2, load_tau   load-model coefficients (τ = mgl cos θ, c1 + c2 ω, τ)
    params          nominal motor parameters (the controller's estimates)
    v_limit         [V] magnitude limit of the voltage vector, or None; RATED (default) → the
                    model's rated voltage (line-to-line RMS), None without one
    current_gain    2×2 K₁ (ΔV = −K₁ (i − i*)) overriding k1·I, or None
    flux_coupling   'cancel' | 'thesis' | 'none' (see module doc)
    T_s             [s] control period (hold compensation and the first step)
    hold_compensation  rotate V* to the middle of the hold interval
    torque_filter_bandwidth  [rad/s] of the PD-part filter (critically damped)
    flux_time_constants  (τ₁, τ₂) [s] of the flux-reference filter; None → (T_r, 1 ms): the flux
                    follows its target like the rotor's own response to a d-current step
    core_loss_exponent  1 | 2, the loss model the ``min_loss`` map minimizes
    flux_preview    [s] look-ahead of the flux target: the strategy sees τ* plus the change of
                    the reference-path torque J θ̈* + b θ̇* + τ_c(θ*, θ̇*) over this horizon
                    (compensates the flux filter's lag; 0 = off; position/speed profiles only).
                    None → 0.06 s for ``min_loss`` (≈ 0.6 T_r, from the sweep in
                    docs/controller.md), 0 for the thesis strategies
    setpoint_duration  [s] of quintic setpoint transitions (torque: /10)
    setpoints       ((t, value, duration), ...) applied by the controller itself at t (profile
                    'setpoint'): a profile file reaches the node through its parameters;
                    duration None → ``setpoint_duration``
    torque_limit    [N·m] |τ*| bound, or None
    current_limit   [A] stator-current magnitude the torque demand may ask for, or None;
                    RATED (default) → the model's rated current (√3 × line RMS), None without one
    speed_limit     [rad/s] beyond it no torque pushes the shaft further, or None
    field_weakening cap the flux target above base speed (needs v_limit)
    voltage_margin  share of v_limit the steady voltage may use under field weakening
    current_margin  share of current_limit the steady current of min_energy / min_loss may use:
                    their flux is clipped into the range that fits (docs/limits.md)
    horizon         [s] the run's end on the controller's clock: ``optimal`` plans up to it
                    with the end flux free; None → open-ended (the plan ends on the steady
                    loss-optimal flux of the final reference)
    magnetizing_floor  [Wb] the smallest flux the reference model uses (a smooth floor, C²:
                    the start-up from a demagnetized machine needs no step); None → 0.1 φ_min
    sensorless      the θ, ω given to ``compute`` are the observer's estimates (θ̂ = ∫ω̂, ω̂):
                    the field angle is the observed flux angle ∠φ̂ (direct field orientation,
                    docs/sensorless.md §4) instead of ∫(vω + ω_sl), which drifts while ω̂ lags
    compensation    the inverter's voltage error ê(i) (an InverterErrorModel) added to the
                    command after the voltage limit, at the measured current (None: off;
                    docs/compensation.md)
    magnetizing     the motor's magnetizing curve (an im_common.saturation.Saturation, power
                    law): ``optimal`` plans on it (docs/controller.md §10); the drive's model
                    follows it through the estimates (SaturatedModel, docs/plant.md §2)
    """

    mode: str = 'position'
    profile: str = 'thesis'
    strategy: str = 'min_energy'
    phi_d: float = RATED
    phi_min: float = RATED
    phi_max: float = RATED
    k1: float = 40.0
    k_p: Optional[float] = None
    k_v: Optional[float] = None
    load_known: bool = True
    load: Optional[str] = None
    load_mgl: float = 10.0
    load_c1: float = 1.0
    load_c2: float = 0.001
    load_tau: float = 0.0
    params: MotorParams = field(default_factory=lambda: THESIS_MOTOR)
    v_limit: Optional[float] = RATED
    current_gain: Optional[list] = None
    flux_coupling: str = 'cancel'
    T_s: float = 1e-4
    hold_compensation: bool = True
    torque_filter_bandwidth: float = 1000.0
    flux_time_constants: Optional[tuple] = None
    core_loss_exponent: float = 2.0
    setpoint_duration: float = 0.5
    flux_preview: Optional[float] = None
    setpoints: tuple = ()
    torque_limit: Optional[float] = None
    current_limit: Optional[float] = RATED
    speed_limit: Optional[float] = None
    field_weakening: bool = True
    voltage_margin: float = DEFAULT_VOLTAGE_MARGIN
    current_margin: float = DEFAULT_CURRENT_MARGIN
    magnetizing_floor: Optional[float] = None
    horizon: Optional[float] = None
    sensorless: bool = False
    #: the inverter's voltage error the command compensates (im_common.compensation; None: off)
    compensation: Optional[InverterErrorModel] = None
    #: the magnetizing curve ``optimal`` plans on (im_common.saturation.Saturation; None: linear)
    magnetizing: object = field(default=None, compare=False)
    #: {field: (value, why)} of the fields the motor model's ratings set (RATED_FIELDS)
    from_ratings: Optional[dict] = field(default=None, compare=False)

    def __post_init__(self):
        for name, allowed in (('mode', MODES), ('profile', PROFILES), ('strategy', STRATEGIES),
                              ('flux_coupling', FLUX_COUPLINGS)):
            if getattr(self, name) not in allowed:
                raise InvalidParameter(name, getattr(self, name),
                                       f'must be one of {", ".join(allowed)}')
        if self.mode == 'torque' and self.profile == 'thesis':
            raise InvalidParameter('profile', self.profile,
                                   'the thesis profiles are position/speed trajectories; '
                                   "mode 'torque' needs profile 'setpoint'")
        if not isinstance(self.params, MotorParams):
            raise InvalidParameter('params', self.params, 'must be a MotorParams')
        self.from_ratings = resolve_rated(self, RATED_FIELDS, self.params, self.from_ratings)
        self.phi_d = _real('phi_d', self.phi_d, 0.0, lo_open=True)
        self.phi_min = _real('phi_min', self.phi_min, 0.0, lo_open=True)
        self.phi_max = _real('phi_max', self.phi_max, 0.0, lo_open=True)
        if self.phi_max < self.phi_min:
            raise InvalidParameter('phi_max', self.phi_max,
                                   f'must be >= phi_min = {self.phi_min:g}')
        self.k1 = _real('k1', self.k1, 0.0, lo_open=True)
        kp0, kv0 = DEFAULT_GAINS[self.mode]
        self.k_p = kp0 if self.k_p is None else _real('k_p', self.k_p, 0.0)
        self.k_v = kv0 if self.k_v is None else _real('k_v', self.k_v, 0.0)
        if self.mode == 'position' and self.k_p <= 0.0:
            raise InvalidParameter('k_p', self.k_p, 'must be > 0 in position mode')
        if self.mode == 'speed' and self.k_v <= 0.0:
            raise InvalidParameter('k_v', self.k_v, 'must be > 0 in speed mode')
        if not isinstance(self.load_known, bool):
            raise InvalidParameter('load_known', self.load_known, 'must be true or false')
        if self.load is None:
            self.load = DEFAULT_LOADS[self.mode]
        if self.load not in MODEL_KINDS:
            raise InvalidParameter('load', self.load, f'must be one of {", ".join(MODEL_KINDS)}')
        for name in ('load_mgl', 'load_c1', 'load_c2', 'load_tau'):
            setattr(self, name, _real(name, getattr(self, name)))
        self.v_limit = _real('v_limit', self.v_limit, 0.0, lo_open=True, allow_none=True)
        if self.current_gain is not None:
            g = self.current_gain
            try:
                rows = [[float(x) for x in r] for r in g]
            except (TypeError, ValueError):
                raise InvalidParameter('current_gain', g,
                                       'must be a 2x2 matrix of numbers') from None
            if len(rows) != 2 or any(len(r) != 2 for r in rows) or \
                    not all(math.isfinite(x) for r in rows for x in r):
                raise InvalidParameter('current_gain', g, 'must be a 2x2 matrix of finite numbers')
            # ΔV = −K e: the symmetric part of K must be positive definite for the dissipation
            # argument (K + Kᵀ > 0).
            a, b2, c2, d = rows[0][0], rows[0][1], rows[1][0], rows[1][1]
            s12 = 0.5 * (b2 + c2)
            if not (a > 0 and a * d - s12 * s12 > 0):
                raise InvalidParameter('current_gain', g,
                                       'K + K^T must be positive definite (Delta V = -K (i - i*))')
            self.current_gain = rows
        self.T_s = _real('T_s', self.T_s, 0.0, lo_open=True)
        if not isinstance(self.hold_compensation, bool):
            raise InvalidParameter('hold_compensation', self.hold_compensation,
                                   'must be true or false')
        self.torque_filter_bandwidth = _real('torque_filter_bandwidth',
                                             self.torque_filter_bandwidth,
                                             0.0, lo_open=True)
        if self.flux_time_constants is not None:
            try:
                tc = tuple(float(x) for x in self.flux_time_constants)
            except (TypeError, ValueError):
                raise InvalidParameter('flux_time_constants', self.flux_time_constants,
                                       'must be two time constants in seconds') from None
            if len(tc) != 2 or not all(math.isfinite(x) and x > 0 for x in tc):
                raise InvalidParameter('flux_time_constants', self.flux_time_constants,
                                       'must be two positive, finite time constants in seconds')
            self.flux_time_constants = tc
        if self.core_loss_exponent not in (1, 2, 1.0, 2.0):
            raise InvalidParameter('core_loss_exponent', self.core_loss_exponent, 'must be 1 or 2')
        self.core_loss_exponent = float(self.core_loss_exponent)
        self.setpoint_duration = _real('setpoint_duration', self.setpoint_duration, 0.0,
                                       lo_open=True)
        if self.flux_preview is None:
            self.flux_preview = DEFAULT_FLUX_PREVIEW if self.strategy in LOSS_OPTIMAL else 0.0
        self.flux_preview = _real('flux_preview', self.flux_preview, 0.0)
        for name in ('torque_limit', 'current_limit', 'speed_limit'):
            setattr(self, name,
                    _real(name, getattr(self, name), 0.0, lo_open=True, allow_none=True))
        if not isinstance(self.field_weakening, bool):
            raise InvalidParameter('field_weakening', self.field_weakening,
                                   'must be true or false')
        self.voltage_margin = _real('voltage_margin', self.voltage_margin, 0.0, lo_open=True)
        if self.voltage_margin > 1.0:
            raise InvalidParameter('voltage_margin', self.voltage_margin, 'must be <= 1')
        self.current_margin = _real('current_margin', self.current_margin, 0.0, lo_open=True)
        if self.current_margin > 1.0:
            raise InvalidParameter('current_margin', self.current_margin, 'must be <= 1')
        if self.magnetizing_floor is None:
            self.magnetizing_floor = 0.1 * self.phi_min
        self.magnetizing_floor = _real('magnetizing_floor', self.magnetizing_floor, 0.0,
                                       lo_open=True)
        if self.magnetizing_floor > self.phi_min:
            raise InvalidParameter('magnetizing_floor', self.magnetizing_floor,
                                   f'must be <= phi_min = {self.phi_min:g}')
        self.setpoints = _check_setpoints(self.setpoints, self.profile)
        if not isinstance(self.sensorless, bool):
            raise InvalidParameter('sensorless', self.sensorless, 'must be true or false')
        self.horizon = _real('horizon', self.horizon, 0.0, lo_open=True, allow_none=True)
        if self.current_limit is not None:
            i_mag = self.phi_max / self.params.L_sr
            if self.current_limit <= i_mag:
                raise InvalidParameter('current_limit', self.current_limit,
                                       f'must exceed the magnetizing current phi_max/L_sr = '
                                       f'{i_mag:.4g} A (no torque would be left)')


def _check_setpoints(setpoints, profile: str) -> tuple:
    """Return ((t, value, duration|None), ...) sorted by t; clear errors naming the entry."""
    out = []
    for k, entry in enumerate(setpoints or ()):
        try:
            t, value, duration = entry
        except (TypeError, ValueError):
            raise InvalidParameter(f'setpoints[{k}]', entry,
                                   'must be (t, value, duration)') from None
        t = _real(f'setpoints[{k}].t', t, 0.0)
        value = _real(f'setpoints[{k}].value', value)
        duration = _real(f'setpoints[{k}].duration', duration, 0.0, lo_open=True, allow_none=True)
        out.append((t, value, duration))
    if out and profile != 'setpoint':
        raise InvalidParameter('setpoints', setpoints, "need profile 'setpoint'")
    if any(b[0] < a[0] for a, b in zip(out, out[1:])):
        raise InvalidParameter('setpoints', setpoints, 'times must not decrease')
    return tuple(out)


def smooth_floor(phi: float, dphi: float, ddphi: float, eps: float):
    """
    Return (f, df/dt, d²f/dt²) of f(φ) = φ for φ ≥ 3ε and ε + φ²/(3ε) − φ³/(27ε²) below.

    f(0) = ε, f'(0) = 0, and f, f', f'' continuous at 3ε. So a flux reference rising from zero
    keeps φ* ≥ ε > 0 (eq. 3.13 divides by it) without a step in dφ*/dt or d²φ*/dt² — the
    start-up needs no voltage beyond the magnetizing ramp (docs/limits.md).
    """
    p1 = 3.0 * eps
    x = abs(phi)
    if x >= p1:
        return phi, dphi, ddphi
    f = eps + x * x / p1 - x ** 3 / (3.0 * p1 * p1)
    f1 = 2.0 * x / p1 - x * x / (p1 * p1)
    f2 = 2.0 / p1 - 2.0 * x / (p1 * p1)
    s = 1.0 if phi >= 0.0 else -1.0
    return f, f1 * s * dphi, f2 * dphi * dphi + f1 * s * ddphi


def sample_path(traj, schedule, times, setpoint_duration: float):
    """
    Return (θ*, ω*, a*) of a reference generator at rising ``times``, its setpoints applied.

    ``schedule``: (t, value, duration) rows, consumed as their times come (pass a copy).
    """
    import numpy as np
    theta, omega, acc = (np.empty(len(times)) for _ in range(3))
    for j, t in enumerate(times):
        while schedule and schedule[0][0] <= t:
            t_i, value, duration = schedule.pop(0)
            traj.set(value, t_i, duration or setpoint_duration)
        theta[j], omega[j], acc[j], _ = traj.sample(t)
    return theta, omega, acc


class DriveController:
    """Stateful controller: call :meth:`compute` once per period with increasing t."""

    def __init__(self, config: ControllerConfig | None = None):
        self.config = config if config is not None else ControllerConfig()
        self._c_nominal = ModelCoefficients.from_params(self.config.params)
        self._c = self._c_nominal
        self._est_key = None
        self._apply_config(self.config)
        tc = self.config.flux_time_constants or (self._c_nominal.T_r, 1e-3)
        self._flux_tc = tc
        self.reset()

    def _apply_config(self, cfg: ControllerConfig) -> None:
        """Build the derived objects of the reconfigurable fields (no run state touched)."""
        self.config = cfg
        curve = None
        if cfg.magnetizing is not None and cfg.core_loss_exponent == 2.0:
            from .flux_plan import saturation_terms
            c0 = ModelCoefficients.from_params(cfg.params)
            curve = (c0, saturation_terms(c0, cfg.magnetizing))
        self._strategy = FluxStrategy(
            cfg.strategy, cfg.phi_d, cfg.phi_min, cfg.phi_max, cfg.params.k_e, cfg.params.k_h,
            cfg.core_loss_exponent,
            i_max=None if cfg.current_limit is None else cfg.current_margin * cfg.current_limit,
            curve=curve)
        self._load = make_load(cfg.load if cfg.load_known else 'none', mgl=cfg.load_mgl,
                               c1=cfg.load_c1, c2=cfg.load_c2, tau=cfg.load_tau)
        if cfg.current_gain is None:
            self._K = (cfg.k1, 0.0, 0.0, cfg.k1)
        else:
            g = cfg.current_gain
            self._K = (g[0][0], g[0][1], g[1][0], g[1][1])

    # ------------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the run: the next ``compute`` re-initializes from its inputs."""
        cfg = self.config
        wb = cfg.torque_filter_bandwidth
        self._pd = LowPass2(1.0 / wb, 1.0 / wb)
        self._flux = LowPass2(self._flux_tc[0], self._flux_tc[1])
        self._t_prev = None
        self._rho = 0.0
        self._rho_dot = 0.0
        self._theta_offset = 0.0
        self._limited = False
        self._traj = None
        self._torque_sp = None
        self._schedule = list(cfg.setpoints)
        self.reference = {}
        self._plan = None            # optimal: the planned flux trajectory (flux_plan.FluxPlan)
        self._plan_tried = False
        self._live_setpoint = False  # a setpoint not in the configured profile: not known ahead
        self.plan_note = ''          # optimal: what the flux reference follows, and why
        if cfg.profile == 'thesis':
            self._traj = THESIS_TRAJECTORIES[cfg.mode]()

    def reconfigure(self, changes: dict) -> None:
        """
        Change live fields (:data:`LIVE_FIELDS`) while running.

        The whole new configuration is validated first (ValueError naming the field; the
        old one stays in force); then it is applied keeping every run state (filters, field
        angle, reference generator, estimates), so the next step continues from where this
        one left off.
        """
        from dataclasses import replace
        bad = [k for k in changes if k not in LIVE_FIELDS]
        if bad:
            raise InvalidParameter(bad[0], changes[bad[0]],
                                   f'cannot change while running (live: {", ".join(LIVE_FIELDS)})')
        values = dict(changes)
        if 'phi_min' in values and self.config.magnetizing_floor == 0.1 * self.config.phi_min:
            values['magnetizing_floor'] = None     # the default floor follows phi_min
        cfg = replace(self.config, **values)       # __post_init__ validates the whole
        self._apply_config(cfg)

    @property
    def coefficients(self) -> ModelCoefficients:
        return self._c

    @property
    def pd_filter(self) -> LowPass2:
        """Return the torque filter of the PD demand u_pd (its input ``u``, output ``y``)."""
        return self._pd

    def set_setpoint(self, kind: str, value: float, t: float,
                     duration: float | None = None) -> None:
        """
        Set a new setpoint ('position' rad | 'speed' rad/s | 'torque' N·m), reached smoothly.

        Quintic over ``duration`` (default ``setpoint_duration``; torque over a tenth of it),
        taking effect at the first step at or after its stamp ``t``.

        A stamp at or before the last computed step (0 included: ``ros2 topic pub`` leaves the
        header unset) means *now*: the transition starts at the next step from where the reference
        is then, so θ*, ω* (and a*) stay continuous — the past is never rebuilt. A future stamp
        waits in the schedule; the reference keeps moving as it was until then.
        """
        cfg = self.config
        if cfg.profile != 'setpoint':
            raise ValueError("set_setpoint needs profile 'setpoint' (the thesis profile is fixed)")
        if kind != cfg.mode:
            raise ValueError(f'setpoint kind {kind!r} does not match '
                             f'the controller mode {cfg.mode!r}')
        value = _real('value', value)
        t = _real('t', t)
        # a setpoint not in the configured profile: the reference is not known ahead
        self._live_setpoint = True
        # in stamp order; equal stamps in arrival order (insort_right)
        bisect.insort(self._schedule, (t, value, duration), key=lambda s: s[0])

    def _start_transition(self, value: float, t_i: float, duration: float | None,
                          t: float) -> None:
        """
        Start the transition of a setpoint stamped t_i at the step t (t_i <= t).

        Stamped after the last computed step (within this period), it starts at its stamp —
        joining the reference C² there; stamped at or before it (the past), it starts now,
        at t.
        """
        cfg = self.config
        start = t_i if t_i > self._t_prev else t
        if cfg.mode == 'torque':
            self._torque_sp.set(value, start, duration or 0.1 * cfg.setpoint_duration)
        else:
            self._traj.set(value, start, duration or cfg.setpoint_duration)

    def _set_estimates(self, estimates) -> None:
        """
        Set the adapted estimates.

        The inverse-Γ set when it carries ``L_sigma`` (the improved law, truth-fed runs:
        every coefficient follows), else the thesis's ``R_r``/``theta``.
        """
        args = estimate_arguments(estimates)
        key = tuple(args.items())
        if key != self._est_key:
            self._c = ModelCoefficients.from_params(self.config.params, **args)
            self._est_key = key

    def _init_run(self, t, theta_r, omega_r, phi_a, phi_b) -> None:
        cfg = self.config
        if cfg.profile == 'setpoint':
            if cfg.mode == 'position':
                self._traj = SetpointPosition(theta_r)
            elif cfg.mode == 'speed':
                self._traj = SetpointSpeed(omega_r, theta_r)
            else:
                self._torque_sp = SetpointTorque(0.0)
        elif cfg.mode == 'speed':
            # the speed task's position reference is ∫ω*, anchored at the measured position
            self._theta_offset = theta_r - self._traj.sample(t)[0]
        mag = math.hypot(phi_a, phi_b)
        self._flux.reset(mag)
        self._rho = math.atan2(phi_b, phi_a) if mag > 1e-9 else 0.0
        self._t_prev = t

    def _apply_schedule(self, t: float) -> None:
        """
        Start the setpoints whose time has come, in stamp order.

        Those of the configured profile and of ``set_setpoint``. Called at step t before
        ``_t_prev`` moves on (the first step: after ``_init_run``, with ``_t_prev`` = t).
        """
        sched = self._schedule
        while sched and sched[0][0] <= t:
            t_i, value, duration = sched.pop(0)
            self._start_transition(value, t_i, duration, t)

    def _path_torque(self, t: float, c: ModelCoefficients) -> float:
        """Return the torque to follow the reference exactly at t (feedforward + load model)."""
        theta, omega, acc, _ = self._traj.sample(t)
        return c.J * acc + c.b * omega + self._load.torque(t, theta + self._theta_offset, omega)

    # Stage 1 ----------------------------------------------------------------------------------
    def _mechanical(self, t, theta_r, omega_r, c):
        """Return eq. 3.1's (θ*, ω*, feedforward + load torque, its rate, PD input u_pd)."""
        cfg = self.config
        if cfg.mode == 'torque':
            tau_ff, dtau_ff = self._torque_sp.sample(t)
            return theta_r, omega_r, tau_ff, dtau_ff, 0.0
        theta_ref, omega_ref, acc_ref, jerk_ref = self._traj.sample(t)
        theta_ref += self._theta_offset
        load = self._load
        tau = c.J * acc_ref + c.b * omega_ref + load.torque(t, theta_r, omega_r)
        # the load's rate along the motion: measured position/speed, reference acceleration
        dtau = c.J * jerk_ref + c.b * acc_ref + load.rate(t, theta_r, omega_r, acc_ref)
        u_pd = -cfg.k_v * (omega_r - omega_ref) - cfg.k_p * (theta_r - theta_ref)
        return theta_ref, omega_ref, tau, dtau, u_pd

    # Stage 2 ----------------------------------------------------------------------------------
    def _flux_reference(self, t, tau, omega_r, c):
        """Return the target flux (strategy, capped above base speed) → filter → smooth floor."""
        cfg = self.config
        if cfg.strategy == 'optimal':
            planned = self._planned(t, c)
            if planned is not None:
                phi_p, dphi_p, ddphi_p = planned
                self._flux.reset(phi_p, dphi_p)   # a fallback continues from the plan
                phi, dphi, ddphi = smooth_floor(phi_p, dphi_p, ddphi_p, cfg.magnetizing_floor)
                return phi_p, phi, dphi, ddphi
        tau_tgt = tau
        if cfg.flux_preview > 0.0 and cfg.mode != 'torque':
            tau_tgt += self._path_torque(t + cfg.flux_preview, c) - self._path_torque(t, c)
        phi_tgt = self._strategy.target(c, tau_tgt, omega_r)
        cap = self.flux_cap(omega_r)
        if phi_tgt > cap:
            phi_tgt = cap
        flt = self._flux
        flt.set_input(phi_tgt)
        phi, dphi, ddphi = smooth_floor(flt.y, flt.dy, flt.accel, cfg.magnetizing_floor)
        return phi_tgt, phi, dphi, ddphi

    def _planned(self, t: float, c: ModelCoefficients):
        """
        Return the optimal plan's (φ, φ̇, φ̈) at t, or None where the causal fallback rules.

        None: no plan (the reason is in ``plan_note``), a live setpoint, or past the plan's end.
        """
        if not self._plan_tried:
            self._plan_tried = True
            self._make_plan(t, c)
        plan = self._plan
        if plan is None:
            return None
        if self._live_setpoint:
            self._plan = None
            self.plan_note = (f'optimal: a live setpoint at t = {t:.4f} s changed the reference '
                              f'the plan was made for: min_loss from here on')
            return None
        if t > plan.end:
            self._plan = None
            self.plan_note = (f"optimal: past the plan's end ({plan.end:g} s): "
                              'min_loss from here on')
            return None
        return plan.sample(t)

    def _make_plan(self, t0: float, c: ModelCoefficients) -> None:
        """
        Plan the loss-optimal flux trajectory over the reference known ahead.

        From the present flux reference (docs/controller.md §10), with the drive's limits as
        constraints.
        """
        import copy
        import numpy as np
        from .flux_plan import PLAN_STEP, PlanError, plan_flux, static_loss_optimal_flux
        cfg = self.config
        if cfg.mode == 'torque':
            self.plan_note = ("optimal: the torque task's speed is not known ahead: min_loss "
                              '(the best causal plan)')
            return
        if self._live_setpoint or (cfg.profile == 'setpoint' and not self._schedule):
            self.plan_note = ('optimal: setpoints arrive live, the reference is not known ahead: '
                              'min_loss (the best causal plan)')
            return
        traj, sched = copy.deepcopy(self._traj), list(self._schedule)
        if cfg.horizon is not None:
            t1 = cfg.horizon
        elif cfg.profile == 'thesis':
            t1 = traj.t0 + 3.0            # the thesis profiles settle within 1.7 s of t0
        else:
            t1 = max(s_[0] + (s_[2] or cfg.setpoint_duration) for s_ in sched) + 3.0 * c.T_r
        if t1 - t0 < 2.0 * PLAN_STEP:
            self.plan_note = 'optimal: the run ends now: min_loss'
            return
        n = max(2, int(math.ceil((t1 - t0) / PLAN_STEP - 1e-9)))
        times = np.linspace(t0, t1, 2 * n + 1)      # nodes (even) and midpoints (odd)
        theta, omega, acc = sample_path(traj, sched, times, cfg.setpoint_duration)
        tau = np.array([c.J * a + c.b * w + self._load.torque(t, th + self._theta_offset, w)
                        for t, th, w, a in zip(times, theta, omega, acc)])
        if cfg.torque_limit is not None:
            np.clip(tau, -cfg.torque_limit, cfg.torque_limit, out=tau)
        cap = np.array([min(cfg.phi_max, self.flux_cap(w)) for w in omega[::2]])
        i_max = None if cfg.current_limit is None else cfg.current_margin * cfg.current_limit
        phi_end = None
        if cfg.horizon is None:
            phi_end = min(static_loss_optimal_flux(c, tau[-1], omega[-1], cfg.params.k_e,
                                                   cfg.params.k_h), cap[-1])
        phi0 = max(self._flux.y, 0.0)
        sat = None
        if cfg.magnetizing is not None:     # on the curve: from the unsaturated model
            from .flux_plan import saturation_terms
            c = self._c_nominal
            sat = saturation_terms(c, cfg.magnetizing)
        try:
            plan = plan_flux(c, times[::2], tau[1::2], omega[1::2], phi0, k_e=cfg.params.k_e,
                             k_h=cfg.params.k_h, phi_end=phi_end, phi_cap=cap, i_max=i_max,
                             sat=sat)
        except PlanError as exc:
            self.plan_note = f'optimal: {exc}: min_loss (the best causal plan)'
            return
        self._plan = plan
        limits = [name for name, on in (
            ('current limit', plan.current_limit_active),
            ('flux cap', plan.flux_cap_active)) if on]
        self.plan_note = (f'optimal: planned the flux over [{t0:g}, {t1:g}] s ({n} intervals) in '
                          f'{plan.solve_s:.2f} s, predicted losses {plan.loss_J:.2f} J'
                          + (f', bound by the {" and ".join(limits)}' if limits else '')
                          + (f'; the limits leave {plan.torque_shortfall:.3g} N·m·s of the torque '
                             f'undelivered' if plan.torque_shortfall > 1e-9 else ''))

    def reference_preview(self, times, theta_r: float = 0.0, omega_r: float = 0.0):
        """
        Return (θ*, ω*, a*) at ``times`` of the reference this controller will follow.

        From a start at (θ_r, ω_r) at times[0], the configured profile and its setpoints (θ*
        with the speed task's anchor, as the load sees it); no run state of this controller is
        touched (a copy runs). The torque task has no reference path: ValueError.
        """
        import copy
        if self.config.mode == 'torque':
            raise ValueError('the torque task has no reference path (its speed is not known '
                             'ahead)')
        ctl = copy.deepcopy(self)
        ctl.reset()
        ctl._init_run(float(times[0]), theta_r, omega_r, 0.0, 0.0)
        theta, omega, acc = sample_path(ctl._traj, ctl._schedule, times,
                                        self.config.setpoint_duration)
        return theta + ctl._theta_offset, omega, acc

    def flux_cap(self, omega_r: float) -> float:
        """
        Return the field-weakening flux cap.

        The largest flux whose steady voltage ω_e (L_s/L_sr) φ stays within
        ``voltage_margin`` · v_limit at the speed ω_r (ω_e ≈ v ω_r); ∞ without a voltage
        limit.
        """
        cfg = self.config
        if cfg.v_limit is None or not cfg.field_weakening:
            return math.inf
        c = self._c
        w_e = c.v * abs(omega_r)
        if w_e <= 0.0:
            return math.inf
        return cfg.voltage_margin * cfg.v_limit * c.L_sr / (c.L_s * w_e)

    # Stage 1b: limits of the torque demand -----------------------------------------------------
    def _limit_torque(self, tau, dtau, phi, dphi, omega_r, c):
        """
        Limit τ* by the torque limit, the current limit at the present flux and the speed limit.

        dτ*/dt = 0 while a bound holds (the bound is what is demanded then).
        """
        cfg = self.config
        hi = math.inf if cfg.torque_limit is None else cfg.torque_limit
        i_d = (phi + c.T_r * dphi) / c.L_sr
        if i_d > 0.0:
            # torque grows with the flux: τ* ≤ v (L_sr/L_r)(φ* − ε) κ i_d*, κ = 2/√σ (twice the
            # min-energy ratio i_q/i_d = 1/√σ, eq. 3.19), zero at the floor ε: a torque demand
            # on a demagnetized machine does not step the q-current at start-up (docs/limits.md)
            hi = min(hi, c.v * c.L_sr * (phi - cfg.magnetizing_floor) * i_d * MAGNETIZING_RATIO
                     / (c.L_r * math.sqrt(c.sigma)))
        if cfg.current_limit is not None:
            room = cfg.current_limit * cfg.current_limit - i_d * i_d
            i_q_max = math.sqrt(room) if room > 0.0 else 0.0
            hi = min(hi, c.v * c.L_sr * phi * i_q_max / c.L_r)
        lo = -hi
        if cfg.speed_limit is not None:
            if omega_r > cfg.speed_limit:
                hi = min(hi, 0.0)
            elif omega_r < -cfg.speed_limit:
                lo = max(lo, 0.0)
        if tau > hi:
            return hi, 0.0, True
        if tau < lo:
            return lo, 0.0, True
        return tau, dtau, False

    # Stage 4 ----------------------------------------------------------------------------------
    def _voltage(self, c, i_ds, i_qs, di_ds, di_qs, phi, rho, rho_dot, dt, omega_r, omega_ref,
                 i_alpha, i_beta, phi_alpha_hat, phi_beta_hat):
        """Return feedforward eq. 3.29 rotated to the hold interval + feedback eq. 3.30-3.31."""
        cfg = self.config
        v = c.v
        cr, sr = math.cos(rho), math.sin(rho)
        i_a_ref = cr * i_ds - sr * i_qs
        i_b_ref = sr * i_ds + cr * i_qs
        p_a_ref = cr * phi
        p_b_ref = sr * phi
        v_d, v_q = feedforward_dq(c, i_ds, i_qs, di_ds, di_qs, phi, rho_dot, omega_r)
        if cfg.hold_compensation:
            rm = rho + 0.5 * (dt if dt > 0.0 else cfg.T_s) * rho_dot
            cm, sm = math.cos(rm), math.sin(rm)
        else:
            cm, sm = cr, sr
        v_a_ff = cm * v_d - sm * v_q
        v_b_ff = sm * v_d + cm * v_q
        ea = i_alpha - i_a_ref
        eb = i_beta - i_b_ref
        K11, K12, K21, K22 = self._K
        dva = -(K11 * ea + K12 * eb)
        dvb = -(K21 * ea + K22 * eb)
        fa = phi_alpha_hat - p_a_ref
        fb = phi_beta_hat - p_b_ref
        coupling = cfg.flux_coupling
        if coupling == 'cancel':
            g = v * omega_r * c.theta          # + g 𝒥 (φ̂ − φ*)
            dva -= g * fb
            dvb += g * fa
        elif coupling == 'thesis':
            g = -0.5 * v * c.theta * omega_ref   # K₂ = g 𝒥, ΔV = K₂ (φ̂ − φ*)
            dva -= g * fb
            dvb += g * fa
        refs = (i_a_ref, i_b_ref, p_a_ref, p_b_ref, v_a_ff, v_b_ff)
        return v_a_ff + dva, v_b_ff + dvb, refs

    def _observed_angle(self, rho: float, phi_a: float, phi_b: float) -> float:
        """
        Return the sensorless field angle: the observer's flux angle ∠φ̂.

        Unwrapped next to the integrated ρ, once |φ̂| is above the magnetizing floor; below it (a
        demagnetized machine, no angle to observe) the integrated ρ. Direct orientation: the
        angle does not integrate ω̂, so a lagging speed estimate does not rotate the current away
        from the flux.
        """
        if math.hypot(phi_a, phi_b) < self.config.magnetizing_floor:
            return rho
        d = math.atan2(phi_b, phi_a) - rho
        return rho + (d + math.pi) % (2.0 * math.pi) - math.pi

    # ------------------------------------------------------------------------------------------
    def compute(self, t: float, i_alpha: float, i_beta: float, theta_r: float, omega_r: float,
                phi_alpha_hat: float, phi_beta_hat: float, estimates: dict | None = None):
        """Return the stator voltage (V_α, V_β) to hold on [t, t + T_s]; set ``self.reference``."""
        if not (math.isfinite(t) and math.isfinite(i_alpha) and math.isfinite(i_beta)
                and math.isfinite(theta_r) and math.isfinite(omega_r)
                and math.isfinite(phi_alpha_hat) and math.isfinite(phi_beta_hat)):
            names = ('t', 'i_alpha', 'i_beta', 'theta_r', 'omega_r', 'phi_alpha_hat',
                     'phi_beta_hat')
            vals = (t, i_alpha, i_beta, theta_r, omega_r, phi_alpha_hat, phi_beta_hat)
            bad = [n for n, v in zip(names, vals) if not math.isfinite(v)]
            raise ValueError(f'controller input(s) not finite: {", ".join(bad)}')
        cfg = self.config
        if estimates:
            self._set_estimates(estimates)
        c = self._c
        first = self._t_prev is None
        if first:
            self._init_run(t, theta_r, omega_r, phi_alpha_hat, phi_beta_hat)
            dt = 0.0
        else:
            dt = t - self._t_prev
            if dt < 0.0:
                raise ValueError(f'time went backwards: t = {t!r} after {self._t_prev!r}')
            self._pd.advance(dt)
            self._flux.advance(dt)
            if self._limited and cfg.mode == 'speed':
                # back-calculation: while the voltage is limited, θ* = ∫ω* follows the shaft
                self._theta_offset += dt * (omega_r - self.reference['omega_ref'])
        if self._schedule:
            self._apply_schedule(t)

        # 1. mechanical loop, eq. 3.1
        theta_ref, omega_ref, tau_fc, dtau_fc, u_pd = self._mechanical(t, theta_r, omega_r, c)
        if first:
            self._pd.reset(u_pd)
        tau = tau_fc + self._pd.y
        dtau = dtau_fc + self._pd.dy
        # 2. flux reference (strategy, field weakening, smooth floor)
        phi_tgt, phi, dphi, ddphi = self._flux_reference(t, tau, omega_r, c)
        # 1b. torque, current and speed limits on τ*
        tau, dtau, tau_limited = self._limit_torque(tau, dtau, phi, dphi, omega_r, c)
        # 3. reference model, eq. 3.13 / 3.26
        i_ds, i_qs, di_ds, di_qs, _, _, w_sl = dq_reference(c, tau, dtau, phi, dphi, ddphi)
        rho_dot = c.v * omega_r + w_sl
        rho = self._rho if first else self._rho + 0.5 * dt * (self._rho_dot + rho_dot)
        if cfg.sensorless:
            rho = self._observed_angle(rho, phi_alpha_hat, phi_beta_hat)
        # 4. feedforward + feedback
        v_a, v_b, refs = self._voltage(c, i_ds, i_qs, di_ds, di_qs, phi, rho, rho_dot, dt, omega_r,
                                       omega_ref, i_alpha, i_beta, phi_alpha_hat, phi_beta_hat)
        # 5. voltage limit; the PD filter always takes its input (no frozen state, no latch)
        saturated = False
        if cfg.v_limit is not None:
            mag = math.hypot(v_a, v_b)
            if mag > cfg.v_limit:
                s = cfg.v_limit / mag
                v_a *= s
                v_b *= s
                saturated = True
        self._limited = saturated or tau_limited
        self._pd.set_input(u_pd)
        if cfg.compensation is not None:    # what the inverter loses, added (compensation.md)
            v_a, v_b = cfg.compensation.command(v_a, v_b, i_alpha, i_beta)

        self._t_prev = t
        self._rho = rho
        self._rho_dot = rho_dot
        i_a_ref, i_b_ref, p_a_ref, p_b_ref, v_a_ff, v_b_ff = refs
        self.reference = {
            't': t, 'theta_ref': theta_ref, 'omega_ref': omega_ref, 'tau_ref': tau,
            'dtau_ref': dtau, 'i_alpha_ref': i_a_ref, 'i_beta_ref': i_b_ref,
            'phi_alpha_ref': p_a_ref, 'phi_beta_ref': p_b_ref, 'phi_d_ref': phi,
            'phi_target': phi_tgt, 'i_d_ref': i_ds, 'i_q_ref': i_qs, 'omega_sl': w_sl,
            'rho': rho, 'v_alpha_ff': v_a_ff, 'v_beta_ff': v_b_ff, 'saturated': saturated,
            'torque_limited': tau_limited,
        }
        return v_a, v_b


def steady_operating_point(config: ControllerConfig, t0: float, theta0: float,
                           omega0: float) -> dict:
    """
    Return the electrical state the controller holds at t0, the shaft on its reference.

    The shaft is exactly on its reference at constant speed: torque from eq. 3.1 with zero
    tracking error, flux at the strategy's target, field angle 0. Used to start the speed task
    in steady state.
    """
    ctl = DriveController(config)
    c = ctl.coefficients
    if config.mode == 'torque':
        tau = 0.0
    else:
        _, w_ref, a_ref, _ = (ctl._traj.sample(t0) if ctl._traj is not None
                              else (theta0, omega0, 0.0, 0.0))
        if config.profile == 'setpoint':
            w_ref, a_ref = omega0, 0.0
        tau = c.J * a_ref + c.b * w_ref
        tau += ctl._load.torque(t0, theta0, omega0)
    phi = min(ctl._strategy.target(c, tau, omega0), ctl.flux_cap(omega0))
    out = steady_state(c, tau, phi, omega0, 0.0)
    out.update({'tau': tau, 'phi': phi})
    return out


def steady_start(config: ControllerConfig, plant: MotorParams, theta0: float, omega0: float,
                 flux_scale: float = 1.0):
    """
    Return (plant x₀, observer x̂₀) of a run started in the controller's steady state (θ₀, ω₀).

    The plant in the physical state that steady state is — the reference stator currents and
    the same inverse-Γ rotor flux ψ_R = θφ_r (θ = L_sr/L_r) — written in the plant's gauge (φ_r
    scaled by θ_model/θ_plant, ψ_s from the plant's inductances); the observer on the
    reference, in the model's gauge. A model written in another rotor gauge (same inverse-Γ
    set, docs/commissioning.md §1) thus starts the plant in the same state. ``flux_scale``
    scales the plant's rotor flux (its stator flux follows; the currents and the observer stay):
    a drive whose model's steady state is not exactly the motor's.
    """
    from im_common.model import stator_flux
    op = steady_operating_point(config, 0.0, theta0, omega0)
    gauge = flux_scale * config.params.theta / plant.theta
    phi_a, phi_b = gauge * op['phi_alpha'], gauge * op['phi_beta']
    psi_a, psi_b = stator_flux(op['i_alpha'], op['i_beta'], phi_a, phi_b,
                               plant.L_s, plant.L_r, plant.L_sr)
    x0 = (psi_a, psi_b, phi_a, phi_b, float(theta0), float(omega0))
    return x0, (op['i_alpha'], op['i_beta'], op['phi_alpha'], op['phi_beta'])
