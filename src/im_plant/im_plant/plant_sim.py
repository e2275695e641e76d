"""
The simulated plant: motor model + load + inverter, stepped one control period at a time.

Built from parts (docs/architecture.md, "The plant built from parts"): :class:`PlantSimulator`
keeps the way a command takes to the motor and what watches it, and hands each period to its
*engine* (:class:`im_plant.engine.PlantEngine`), the one owner of the motor model, the state
``x`` and the period index ``k``: :class:`im_plant.engine.IdealPlant` (the model by RK4) or, with
any of the real plant's blocks, :class:`im_plant.real_plant.RealPlant`. The simulator reads the
engine's state through read-only attributes (``x``, ``k``, ``t``, ``model``, ``v_applied``) and
latches what the engine's period reports; neither sets the other's attributes.

The inverter is an ideal voltage source whose command is held over each period (zero-order hold),
limited in vector magnitude to ``v_limit`` (optional, the configured limit the controller knows
about: commands above it are scaled onto it). A command above the inverter's own rating
``inverter_rating`` is not something an inverter can make, and a controller asking for it has
lost control: it trips the protection (below), so no finite command however large reaches the
model and the fault is reported rather than hidden by a saturation.

Protection (docs/limits.md): after every period the plant checks the stator-current magnitude
against ``current_trip``, the speed against ``speed_trip`` and the state for non-finite values.
On a trip (or a command above the rating) it latches ``trip = (t, reason)`` and applies zero
voltage from then on (all lower
switches on: the stator is short-circuited through the inverter, the machine's stored magnetic
energy decays through its resistances and the shaft coasts against its load). A non-finite
state is not kept: the engine integrates the period again from the last finite state with zero
voltage and reports the trip (the real plant's DC link reports its over-voltage trip the same
way). Left at ``RATED`` (their default), ``v_limit`` and the trips come from the motor's ratings
(:func:`im_common.params.default_limits`; none for a motor without them; ``from_ratings`` says
which). The ideal engine integrates the model with fixed-step RK4 sub-steps in
each period (at most ``max_substep`` long), together with the energy integrals, so the energy books
are part of the integration and not computed after the fact.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Optional, Sequence

from im_common.delay import CommandDelay
from im_common.inverter import Inverter
from im_common.loads import LiveLoad, Load, NoLoad
from im_common.model import MotorModel
from im_common.params import (InvalidParameter, MotorParams, ParameterSchedule, RATED,
                              resolve_rated, THESIS_MOTOR)

from .engine import IdealPlant, PlantEngine
from .sensors import Measurement

# The inverter's own voltage-vector limit when none is given [V]: the DC link of a 690 V-class
# inverter (≈ 1 kV), above every shipped motor's needs; a larger command trips the plant.
DEFAULT_INVERTER_RATING = 1000.0
#: the plant's limits a motor's ratings set when left at RATED, and their value without a rating
RATED_PROTECTION = {'v_limit': None, 'current_trip': None, 'speed_trip': None}


@dataclass
class _Protection:
    v_limit: object
    current_trip: object
    speed_trip: object


class PlantSimulator:
    """
    Stateful plant stepped by ``step(v_alpha, v_beta)`` over [t_k, t_k + T_s].

    Parameters
    ----------
    schedule : ParameterSchedule or MotorParams
    load : Load
    T_s : float
        Control period [s].
    max_substep : float
        Longest RK4 sub-step [s]; the period is split into ceil(T_s / max_substep) equal sub-steps.
    v_limit : float or None
        Largest magnitude of the applied voltage vector [V] (None: no limit).
    current_noise_std, speed_noise_std : float
        Standard deviation of Gaussian measurement noise on i_αβ [A] and ω_r [rad/s].
    noise_seed : int
        Seed of the noise generator (runs are reproducible).
    theta0, omega0 : float
        Initial shaft position [rad] and speed [rad/s]; fluxes and currents start at zero unless
        ``x0`` (the 6-element state ψ_sα, ψ_sβ, φ_rα, φ_rβ, θ_r, ω_r) is given.
    locked_rotor : bool
        The shaft is held where it starts (a locked-rotor test); the speed must start at 0.
    inverter, saturation, thermal, sensors, iron_loss
        The real plant's blocks (:mod:`im_plant.real_plant`); an inverter block without V_dc is
        the ideal voltage source with its ``delay`` only. Any of them makes the engine
        (``engine``, module doc) a :class:`im_plant.real_plant.RealPlant`, also ``real``
        (None with the ideal plant's :class:`im_plant.engine.IdealPlant`).

    The inverter's ``delay`` (:mod:`im_common.delay`): the command given to :meth:`step` k acts
    over step k + delay (the first command from t_0). A non-finite command is refused as given;
    the inverter's rating, the trip and v_limit act on the command that acts, when it acts (the
    inverter sees a command when it is loaded): so the plant node may integrate step k before
    the command of step k has come (the delayed step overlapped) with the serial order's numbers.

    """

    def __init__(self, schedule: ParameterSchedule | MotorParams = THESIS_MOTOR,
                 load: Optional[Load] = None, T_s: float = 1e-4, max_substep: float = 1e-4,
                 v_limit: Optional[float] = RATED, current_noise_std: float = 0.0,
                 speed_noise_std: float = 0.0, noise_seed: int = 0, theta0: float = 0.0,
                 omega0: float = 0.0, x0: Optional[Sequence[float]] = None,
                 core_loss_exponent: float = 2.0, inverter_rating: float = DEFAULT_INVERTER_RATING,
                 current_trip: Optional[float] = RATED, speed_trip: Optional[float] = RATED,
                 locked_rotor: bool = False, inverter=None, saturation=None, thermal=None,
                 sensors=None, iron_loss: bool = False):
        # the load as given plus the live offset (set_load_offset): the object every model takes
        self.load = LiveLoad(load if load is not None else NoLoad())
        # the motor: its schedule, live load, loss exponent and shaft (the ideal plant's model;
        # the real plant makes its own from it)
        motor = MotorModel(schedule, self.load, core_loss_exponent, locked=locked_rotor)
        # left at RATED: the motor's rating (im_common.params.default_limits), else none
        lim = _Protection(v_limit, current_trip, speed_trip)
        self.from_ratings = resolve_rated(lim, RATED_PROTECTION, motor.schedule.base)
        v_limit, current_trip, speed_trip = lim.v_limit, lim.current_trip, lim.speed_trip
        _check_arguments(T_s, max_substep, v_limit, inverter_rating, current_trip, speed_trip,
                         current_noise_std, speed_noise_std)
        if locked_rotor and (omega0 != 0.0 or (x0 is not None and x0[5] != 0.0)):
            raise InvalidParameter('omega0', omega0, 'must be 0 with a locked rotor')
        T_s = float(T_s)
        self.v_limit = v_limit
        self.inverter_rating = float(inverter_rating)
        self._v_max = (self.inverter_rating if v_limit is None
                       else min(v_limit, self.inverter_rating))
        self.current_trip = current_trip
        self.speed_trip = speed_trip
        self.trip: Optional[tuple] = None     # (t, reason) once the protection tripped
        self.current_noise_std = float(current_noise_std)
        self.speed_noise_std = float(speed_noise_std)
        self._rng = None
        if self.current_noise_std > 0 or self.speed_noise_std > 0:
            import numpy as np
            self._rng = np.random.default_rng(noise_seed)
        start = _start(x0, theta0, omega0)
        if isinstance(inverter, Mapping):
            inverter = Inverter.from_block(inverter)
        self.delay = CommandDelay(inverter.delay if isinstance(inverter, Inverter) else 0)
        if isinstance(inverter, Inverter) and not inverter.switched:
            inverter = None                     # the ideal voltage source: the delay only
        n_sub = max(1, int(math.ceil(T_s / max_substep - 1e-9)))
        self.real = None                        # the engine when it is the real plant
        if (inverter is not None or saturation is not None or thermal is not None
                or sensors is not None or iron_loss):
            from .real_plant import RealPlant
            self.real = RealPlant(motor, T_s, n_sub, start, inverter, saturation, thermal,
                                  sensors, iron_loss, current_trip, speed_trip)
        # what integrates the motor over a period (im_plant.engine): the state is its own
        self.engine: PlantEngine = (self.real if self.real is not None
                                    else IdealPlant(motor, T_s, n_sub, start))

    # The engine's state, read here (docs/architecture.md, "The plant built from parts") -----
    @property
    def model(self):
        """Return the motor model the engine integrates."""
        return self.engine.model

    @property
    def schedule(self) -> ParameterSchedule:
        """Return the motor's (possibly time-varying) electrical parameters."""
        return self.engine.model.schedule

    @property
    def params(self) -> MotorParams:
        """Return the motor's base parameters (the schedule's base)."""
        return self.engine.model.params

    @property
    def x(self):
        """Return the engine's state at t_k (the model's augmented vector)."""
        return self.engine.x

    @property
    def k(self) -> int:
        """Return the index of the period the state is at."""
        return self.engine.k

    @property
    def t(self) -> float:
        """Return the simulated time t_k = k·T_s [s] (exact multiple, no accumulated round-off)."""
        return self.engine.t

    @property
    def T_s(self) -> float:
        """Return the control period [s]."""
        return self.engine.T_s

    @property
    def n_sub(self) -> int:
        """Return the RK4 sub-steps of a period (ceil(T_s / max_substep))."""
        return self.engine.n_sub

    @property
    def v_applied(self):
        """Return the (mean) voltage vector applied over the last period [V]."""
        return self.engine.v_applied

    @property
    def noisy(self) -> bool:
        """Tell whether the measurements get noise (``current_noise_std``, ``speed_noise_std``)."""
        return self._rng is not None

    def limit(self, v_a: float, v_b: float):
        """
        Return the voltage the inverter applies for a commanded (v_a, v_b).

        Zero once tripped, else scaled onto the limit when above it.
        """
        if self.trip is not None:
            return 0.0, 0.0
        mag = math.hypot(v_a, v_b)
        if mag > self._v_max:
            s = self._v_max / mag
            return v_a * s, v_b * s
        return v_a, v_b

    def admit(self, v_a: float, v_b: float):
        """
        Return the command the inverter applies: refuse a non-finite one (ValueError).

        A command above the inverter's rating latches the trip; the rest is :meth:`limit`'s.
        """
        self.check(v_a, v_b)
        return self.limit(v_a, v_b)

    def check(self, v_a: float, v_b: float) -> None:
        """Refuse a non-finite command (ValueError); latch the trip above the inverter's rating."""
        self._finite(v_a, v_b)
        self._rating(v_a, v_b)

    def _finite(self, v_a: float, v_b: float) -> None:
        if not (math.isfinite(v_a) and math.isfinite(v_b)):
            raise ValueError(f'non-finite voltage command ({v_a!r}, {v_b!r}) '
                             f'at t = {self.t:.9f} s')

    def _rating(self, v_a: float, v_b: float) -> None:
        if self.trip is None:
            mag = math.hypot(v_a, v_b)
            if mag > self.inverter_rating:
                self.trip = (self.t,
                             f'voltage command |V| = {mag:.4g} V above the inverter rating '
                             f'{self.inverter_rating:g} V')

    @property
    def load_offset(self) -> float:
        """Return the live load torque added to the load's own [N·m]."""
        return self.load.offset

    def set_load_offset(self, tau: float) -> None:
        """
        Add ``tau`` [N·m] to the load's torque from the next :meth:`step` on (a step boundary).

        The plant node's live ``load_offset``: a step integrates [t_k, t_k+1] with one offset,
        so the change acts from t_k of the step that follows the call.
        """
        if isinstance(tau, bool) or not isinstance(tau, (int, float)) or not math.isfinite(tau):
            raise InvalidParameter('load_offset', tau, 'must be a finite torque [N m]')
        self.load.set_offset(tau)

    def step(self, v_a: float, v_b: float) -> None:
        """
        Integrate [t_k, t_k+1] with the command held.

        Refuse non-finite commands; trip on overcurrent, overspeed or a non-finite state
        (module doc). With a delay the command that acts is the one given ``delay`` steps
        before (class doc).
        """
        if self.delay.d:
            self.enter(v_a, v_b)
            self.step_entered()
            return
        self._advance(*self.admit(v_a, v_b))

    def enter(self, v_a: float, v_b: float) -> None:
        """
        Enter the command of the next step into the delay line (refused if not finite).

        It acts ``delay`` steps later (the first one from t_0): :meth:`step_entered` integrates
        the step the line's next command acts over. The plant node enters each command when it
        comes and integrates a step as soon as its acting command is in the line (the delayed
        step overlapped, docs/architecture.md); :meth:`step` is the two at once.
        """
        self._finite(v_a, v_b)
        self.delay.enter(v_a, v_b)

    def step_entered(self) -> None:
        """
        Integrate [t_k, t_k+1] with the command acting over it, the delay line's next.

        Its checks act when it acts: above the inverter's rating it latches the trip at t_k.
        """
        v_a, v_b = self.delay.take()
        self._rating(v_a, v_b)
        self._advance(*self.limit(v_a, v_b))

    def _advance(self, v_a: float, v_b: float) -> None:
        """Have the engine integrate [t_k, t_k+1] with (v_a, v_b); latch what it reports."""
        report = self.engine.advance(v_a, v_b, self.trip is not None)
        if report.trip is not None:
            self.trip = report.trip
        elif report.check and self.trip is None:
            self.protect()

    def protect(self) -> None:
        """Latch a trip on overcurrent or overspeed at t_k (after the period)."""
        if self.current_trip is not None:
            i_a, i_b = self.engine.stator_currents()
            mag = math.hypot(i_a, i_b)
            if mag > self.current_trip:
                self.trip = (self.t, f'overcurrent: |i_s| = {mag:.4g} A > {self.current_trip:g} A')
                return
        omega = self.engine.x[5]
        if self.speed_trip is not None and abs(omega) > self.speed_trip:
            self.trip = (self.t, f'overspeed: |omega_r| = {abs(omega):.4g} rad/s > '
                                 f'{self.speed_trip:g} rad/s')

    # Outputs -----------------------------------------------------------------------------
    def stator_currents(self):
        """Return (i_sα, i_sβ) at t_k: the currents the protection watches."""
        return self.engine.stator_currents()

    def state_currents(self):
        """Return (i_sα, i_sβ, i_rα, i_rβ) at t_k."""
        return self.engine.state_currents()

    def measure(self) -> Measurement:
        """Measured stator currents and shaft position/speed at t_k (noise added if configured)."""
        m = self.engine.measure()
        if self._rng is None:
            return m
        i_sa, i_sb, omega = self.add_noise(m.i_alpha, m.i_beta, m.omega_r)
        return Measurement(m.t, i_sa, i_sb, m.theta_r, omega, m.v_dc)

    def add_noise(self, i_alpha: float, i_beta: float, omega: float):
        """Return (i_α, i_β, ω) with the configured Gaussian measurement noise added."""
        if self._rng is not None:
            if self.current_noise_std > 0:
                n = self._rng.normal(0.0, self.current_noise_std, 2)
                i_alpha += float(n[0])
                i_beta += float(n[1])
            if self.speed_noise_std > 0:
                omega += float(self._rng.normal(0.0, self.speed_noise_std))
        return i_alpha, i_beta, omega

    def truth(self) -> dict:
        """Ground truth at t_k: true state, torques, parameters, power and energy books."""
        return self.engine.truth(self.trip)


def _check_arguments(T_s, max_substep, v_limit, inverter_rating, current_trip, speed_trip,
                     current_noise_std, speed_noise_std) -> None:
    """Refuse a period, sub-step, limit, rating, trip or noise out of its range."""
    if not (math.isfinite(T_s) and T_s > 0):
        raise InvalidParameter('T_s', T_s, 'must be a positive, finite period in seconds')
    if not (math.isfinite(max_substep) and max_substep > 0):
        raise InvalidParameter('max_substep', max_substep, 'must be > 0')
    if v_limit is not None and not (math.isfinite(v_limit) and v_limit > 0):
        raise InvalidParameter('v_limit', v_limit, 'must be > 0 (or None for no limit)')
    if not (math.isfinite(inverter_rating) and inverter_rating > 0):
        raise InvalidParameter('inverter_rating', inverter_rating, 'must be > 0 V')
    for name, val in (('current_trip', current_trip), ('speed_trip', speed_trip)):
        if val is not None and not (math.isfinite(val) and val > 0):
            raise InvalidParameter(name, val, 'must be > 0 (or None for no trip)')
    for name, val in (('current_noise_std', current_noise_std),
                      ('speed_noise_std', speed_noise_std)):
        if not (math.isfinite(val) and val >= 0):
            raise InvalidParameter(name, val, 'must be >= 0')


def _start(x0: Optional[Sequence[float]], theta0: float, omega0: float) -> list:
    """Return the start (ψ_sα, ψ_sβ, φ_rα, φ_rβ, θ_r, ω_r): ``x0``, else at rest at (θ0, ω0)."""
    if x0 is None:
        return [0.0, 0.0, 0.0, 0.0, float(theta0), float(omega0)]
    if len(x0) != 6 or not all(math.isfinite(v) for v in x0):
        raise InvalidParameter('x0', x0, 'must be 6 finite numbers')
    return [float(v) for v in x0]
