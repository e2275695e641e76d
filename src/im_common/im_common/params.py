"""
Motor parameters, their validation, and time-varying parameter schedules.

One defaults table for the whole stack: :data:`THESIS_MOTOR` is the motor of seed 000 §3.4.1
(eq. 3.33). Every package reads its nominal values from here.

========  ==========  =======  =====================================================
symbol    default     unit     meaning
========  ==========  =======  =====================================================
R_s       0.687       Ω        stator resistance
R_r       0.842       Ω        rotor resistance (referred to the stator)
L_s       0.08397     H        stator self inductance
L_r       0.08528     H        rotor self inductance
L_sr      0.08136     H        stator-rotor mutual inductance
J         0.030       kg·m²    inertia of motor and load
b         0.010       N·m·s    viscous friction
pole_pairs 2          —        pole pairs ``v`` of the thesis (60 Hz, 1750 rpm)
k_e       0.012       W·s/Wb²  eddy-current core-loss coefficient (eq. 3.34)
k_h       0.012       W·s/Wb²  hysteresis core-loss coefficient (eq. 3.34)
rated_voltage_rms_line 0 V     nameplate voltage: line-to-line RMS (0: not given)
rated_current_rms 0   A        nameplate current: line current RMS, continuous (0: not given)
rated_frequency 0     Hz       nameplate supply frequency (0: not given)
rated_speed_rpm 0     rpm      nameplate (full-load) shaft speed (0: not given)
rated_power    0      W        nameplate shaft output power (0: not given)
rated_flux     0      Wb       rated rotor flux |φ_r| if known (0: derived, :func:`rated_flux`)
========  ==========  =======  =====================================================

Ratings are written as on the nameplate and converted once, here, to the model's
power-invariant αβ frame (:func:`clarke`; docs/limits.md "Ratings"): a balanced three-phase
set of phase RMS value X is the rotating vector of magnitude √3·X, so

* voltage-vector magnitude :attr:`MotorParams.rated_voltage` = √3 · V_LL/√3 = V_LL (the
  equivalent star's phase voltage is V_LL/√3, whether the motor is wired star or delta);
* current-vector magnitude :attr:`MotorParams.rated_current` = √3 · I_line (the equivalent
  star's phase current is the line current);
* :attr:`MotorParams.rated_speed` = 2π n/60 [rad/s], :attr:`MotorParams.rated_torque` =
  P/rated_speed [N·m].

Given ratings are the drive's defaults (:func:`default_limits`): the controller's v_limit and
current_limit, the plant's inverter limit and trips, and the flux levels; an explicit parameter
always overrides, and a motor without ratings (:data:`THESIS_MOTOR`) runs as the thesis did.

A motor of one's own is a ROS 2 parameters file (``/**:`` + ``ros__parameters:`` with the names
above) read by :func:`load_motor_file`; the same file given to the nodes with ``--params-file``
reaches every node through the ``/**`` wildcard. The shipped motors are in
``src/im_common/config/motors/`` (installed to ``share/im_common/config/motors``).

Derived quantities (seed 000 eq. 1.113, ch. 4): σ = 1 − L_sr²/(L_s L_r), θ = L_sr/L_r,
L_M = L_sr²/L_r (the magnetizing inductance seen from the stator terminals) and
R_R = R_r (L_sr/L_r)² (the rotor resistance seen from the terminals). With terminal
measurements only, R_s, σL_s, L_M and R_R are identifiable; R_r and θ separately are not.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
import difflib
import logging
import math
import os
import re
from typing import Callable, Dict, Literal, Mapping, Optional, Tuple

from pydantic import BaseModel, Field, model_validator
import yaml

from . import yamlio
from .saturation import saturation_block, SaturationBlock
from .thermal import Thermal, thermal_from_dict
from .validation import BLOCK_CONFIG, check_real, InvalidParameter, parameter_spec

ELECTRICAL_NAMES = ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr')
#: the nameplate fields of a motor file (0: not given); converted once by MotorParams' properties
RATING_NAMES = ('rated_voltage_rms_line', 'rated_current_rms', 'rated_frequency',
                'rated_speed_rpm', 'rated_power', 'rated_flux')
#: the model-frame ratings the motor files once held, and the nameplate field each now comes from
LEGACY_RATINGS = {'rated_voltage': 'rated_voltage_rms_line (line-to-line RMS [V], equal to the '
                                   'old vector magnitude)',
                  'rated_current': 'rated_current_rms (line current RMS [A] = the old vector '
                                   'magnitude / sqrt(3))',
                  'rated_speed': 'rated_speed_rpm (rpm = the old rad/s x 60/(2 pi))',
                  'rated_torque': 'rated_power (shaft power [W] = the old torque x rated speed)'}
INDUCTANCE_NAMES = ('L_s', 'L_r', 'L_sr')


def parameter_error(value, default, lo=None, hi=None) -> Optional[str]:
    """
    Say why ``value`` cannot be a parameter declared with ``default`` and range [lo, hi], or None.

    The parameters are typed as in ROS 2: an integer is not taken for a real-valued parameter
    (no silent conversion; the line says to write it as a real number). The one type and range
    rule of every path that takes parameters: the nodes (``LockstepNode.param``) and the motor
    files (:func:`motor_from_dict`).
    """
    if isinstance(default, bool):
        return None if isinstance(value, bool) else 'must be true or false'
    if isinstance(default, (int, float)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            kind = 'a whole number' if isinstance(default, int) else 'a real number'
            return f'must be {kind}, not {type(value).__name__}'
        if isinstance(default, float) and isinstance(value, int):
            return f'an integer where a real number is expected; write {value}.0'
        if isinstance(default, int) and isinstance(value, float):
            return 'must be a whole number'
        if not math.isfinite(value):
            return 'must be finite'
        if lo is not None and hi is not None and not lo <= value <= hi:
            return f'out of range [{lo:g}, {hi:g}]'
        return None
    if isinstance(default, str) and not isinstance(value, str):
        return f'must be a string, not {type(value).__name__}'
    if isinstance(default, (list, tuple)):
        if isinstance(value, (str, bytes)) or not hasattr(value, '__len__'):
            return f'must be a list, not {type(value).__name__}'
        if default and isinstance(default[0], float) and any(
                isinstance(v, bool) or not isinstance(v, float) for v in value):
            return 'must be a list of real numbers'
    return None


def _check_finite_positive(name: str, value, allow_zero: bool = False) -> None:
    check_real(name, value, 0.0, lo_open=not allow_zero)


def leakage_factor(L_s: float, L_r: float, L_sr: float) -> float:
    """σ = 1 − L_sr²/(L_s L_r) (seed 000 eq. 1.113)."""
    return 1.0 - L_sr * L_sr / (L_s * L_r)


SQRT3 = math.sqrt(3.0)


def clarke(x_a: float, x_b: float, x_c: float) -> Tuple[float, float]:
    """
    Apply the power-invariant Clarke transform of the model (seed 000 eq. 1.111-1.112).

    (x_α, x_β) = √(2/3)·(x_a − x_b/2 − x_c/2, (√3/2)(x_b − x_c)). Power-invariant: v_a i_a +
    v_b i_b + v_c i_c = v_α i_α + v_β i_β for a set without zero sequence.
    """
    k = math.sqrt(2.0 / 3.0)
    return k * (x_a - 0.5 * x_b - 0.5 * x_c), k * 0.5 * SQRT3 * (x_b - x_c)


def vector_magnitude(rms_phase: float) -> float:
    """
    Return the αβ-vector magnitude of a balanced three-phase set of phase RMS value ``rms_phase``.

    x_k = √2 X cos(ωt − 2πk/3) gives |x_αβ| = √(2/3)·(3/2)·√2 X = √3 X (:func:`clarke`;
    tests/test_ratings.py checks it on sampled waveforms).
    """
    return SQRT3 * rms_phase


@dataclass(frozen=True)
class MotorParams:
    """Parameters of the squirrel-cage induction motor and its shaft (SI, see module table)."""

    R_s: float = 0.687
    R_r: float = 0.842
    L_s: float = 0.08397
    L_r: float = 0.08528
    L_sr: float = 0.08136
    J: float = 0.030
    b: float = 0.010
    pole_pairs: int = 2
    k_e: float = 0.012
    k_h: float = 0.012
    rated_voltage_rms_line: float = 0.0
    rated_current_rms: float = 0.0
    rated_frequency: float = 0.0
    rated_speed_rpm: float = 0.0
    rated_power: float = 0.0
    rated_flux: float = 0.0

    def __post_init__(self):
        for name in ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr', 'J'):
            _check_finite_positive(name, getattr(self, name))
        for name in ('b', 'k_e', 'k_h') + RATING_NAMES:
            _check_finite_positive(name, getattr(self, name), allow_zero=True)
        v = self.pole_pairs
        if (isinstance(v, bool)
                or not isinstance(v, int) and not (isinstance(v, float) and v.is_integer())):
            raise InvalidParameter('pole_pairs', v, 'must be a whole number')
        if int(v) < 1:
            raise InvalidParameter('pole_pairs', v, 'must be >= 1')
        object.__setattr__(self, 'pole_pairs', int(v))
        sigma = leakage_factor(self.L_s, self.L_r, self.L_sr)
        if not sigma > 0.0:
            raise InvalidParameter(
                'L_sr', self.L_sr,
                f'leakage factor sigma = 1 - L_sr^2/(L_s*L_r) = {sigma:.4g} must be > 0 '
                f'(L_sr^2 must be below L_s*L_r = {self.L_s * self.L_r:.6g})')
        if self.rated_frequency > 0 and self.rated_speed_rpm > 0:
            sync = 60.0 * self.rated_frequency / self.pole_pairs
            if not self.rated_speed_rpm < sync:
                raise InvalidParameter(
                    'rated_speed_rpm', self.rated_speed_rpm,
                    f'must be below the synchronous speed 60 f/v = {sync:g} rpm of '
                    f'{self.rated_frequency:g} Hz and {self.pole_pairs} pole pairs (an induction '
                    f'motor runs below it)')

    # Ratings in the model's power-invariant frame (module doc; 0: not given) ---------------
    @property
    def rated_voltage(self) -> float:
        """
        Voltage-vector magnitude at the rated voltage [V].

        √3 × the phase voltage V_LL/√3 of the equivalent star (:func:`vector_magnitude`),
        i.e. the line-to-line RMS voltage.
        """
        return self.rated_voltage_rms_line

    @property
    def rated_current(self) -> float:
        """Current-vector magnitude at the rated current [A]: √3 × the line current RMS."""
        return vector_magnitude(self.rated_current_rms)

    @property
    def rated_speed(self) -> float:
        """Rated shaft speed [rad/s]."""
        return 2.0 * math.pi * self.rated_speed_rpm / 60.0

    @property
    def rated_torque(self) -> float:
        """Shaft torque at rated power and speed [N·m] (0 unless both are given)."""
        w = self.rated_speed
        return self.rated_power / w if w > 0 else 0.0

    # Derived quantities -------------------------------------------------------------------
    @property
    def sigma(self) -> float:
        return leakage_factor(self.L_s, self.L_r, self.L_sr)

    @property
    def theta(self) -> float:
        """θ = L_sr / L_r, the ratio adapted in seed 000 ch. 4."""
        return self.L_sr / self.L_r

    @property
    def L_M(self) -> float:
        return self.L_sr * self.L_sr / self.L_r

    @property
    def R_R(self) -> float:
        return self.R_r * (self.L_sr / self.L_r) ** 2

    @property
    def L_sigma(self) -> float:
        """σL_s = L_s − L_M, the stator transient (leakage) inductance of the inverse-Γ model."""
        return self.L_s - self.L_M

    @property
    def T_r(self) -> float:
        return self.L_r / self.R_r

    def identifiable(self) -> Dict[str, float]:
        """
        Return the inverse-Γ parameters {'R_s', 'L_sigma', 'L_M', 'R_R'}.

        Everything the terminals (voltages, currents, speed) determine (docs/adaptation.md §1).
        """
        return dict(zip(IDENTIFIABLE_NAMES, (self.R_s, self.L_sigma, self.L_M, self.R_R)))

    def with_identifiable(self, R_s: Optional[float] = None, L_sigma: Optional[float] = None,
                          L_M: Optional[float] = None, R_R: Optional[float] = None
                          ) -> 'MotorParams':
        """
        Return the motor with these inverse-Γ parameters, in this motor's gauge θ = L_sr/L_r.

        Terminal signals fix R_s, L_σ, L_M and R_R but not θ (docs/adaptation.md §1); keeping θ
        fixes the scale of the rotor-flux coordinate φ_r = φ_M/θ: L_sr = L_M/θ, L_r = L_M/θ²,
        L_s = L_σ + L_M, R_r = R_R/θ². The result is terminal-equivalent to any motor with the
        same four values, and equal to this motor when none changes. Raises InvalidParameter
        naming the value that is not a positive finite number.
        """
        th = self.theta
        ident = self.identifiable()
        given = {'R_s': R_s, 'L_sigma': L_sigma, 'L_M': L_M, 'R_R': R_R}
        for name, value in given.items():
            if value is not None:
                _check_finite_positive(name, value)
                ident[name] = float(value)
        if all(v is None for v in given.values()):
            return self
        return replace(self, R_s=ident['R_s'], L_s=ident['L_sigma'] + ident['L_M'],
                       L_sr=ident['L_M'] / th, L_r=ident['L_M'] / (th * th),
                       R_r=ident['R_R'] / (th * th))

    @property
    def v(self) -> int:
        """Pole pairs, named as in the thesis."""
        return self.pole_pairs

    def with_values(self, **values) -> 'MotorParams':
        """Return a copy with some values replaced (validated)."""
        return replace(self, **values)

    def as_dict(self) -> Dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


THESIS_MOTOR = MotorParams()
#: the inverse-Γ parameters: what the terminals identify (MotorParams.identifiable)
IDENTIFIABLE_NAMES = ('R_s', 'L_sigma', 'L_M', 'R_R')
#: the thesis's adapted pair (eq. 4.10-4.13: L_s, L_sr, R_s stay nominal)
THESIS_ESTIMATE_NAMES = ('R_r', 'theta')


def estimate_arguments(estimates: Mapping) -> Dict[str, float]:
    """
    Return what a controller or observer model takes from the adapter's estimates.

    The inverse-Γ set (``R_s``, ``L_sigma``, ``L_M``, ``R_R``, those present) when it carries
    ``L_sigma`` — the improved law and truth-fed runs —, else the thesis's ``R_r``/``theta``
    (docs/adaptation.md §7).
    """
    names = IDENTIFIABLE_NAMES if 'L_sigma' in estimates else THESIS_ESTIMATE_NAMES
    return {n: estimates[n] for n in names if estimates.get(n) is not None}


MOTOR_FIELDS = tuple(f.name for f in fields(MotorParams))

# Ratings as drive defaults ---------------------------------------------------------------
#: the plant's over-current trip as a multiple of the rated current: a protection above any
#: limit a controller is given on purpose (the rating-scaled studies run at 2× rated current,
#: im_studies.study_motors.OVERLOAD) with room for its transients
CURRENT_TRIP_MARGIN = 3.0
#: the plant's over-speed trip as a multiple of the rated speed (field weakening runs above
#: rated speed; twice it is where a general-purpose motor's mechanical limit usually lies)
SPEED_TRIP_MARGIN = 2.0
#: the thesis's flux levels [Wb] (§3.4.6): what a motor without a rated flux runs at
THESIS_FLUX_LEVELS = {'phi_d': 1.2, 'phi_min': 0.2, 'phi_max': 1.2}
#: φ_min/φ_max of the thesis (0.2/1.2 Wb), kept when the flux levels scale to the rated flux
FLUX_MIN_SHARE = THESIS_FLUX_LEVELS['phi_min'] / THESIS_FLUX_LEVELS['phi_max']


def rated_rotor_flux(R_s: float, L_sigma: float, L_M: float, R_R: float, theta: float,
                     voltage: float, frequency: float, speed_rpm: float, pole_pairs: int) -> float:
    """
    Return the rotor flux |φ_r| at rated voltage (vector magnitude, = V_LL), frequency, speed.

    The inverse-Γ equivalent circuit at ω_e = 2πf and the rated slip s = 1 − n v/(60 f):
    Z_M = jω_e L_M ∥ R_R/s, the magnetizing-branch voltage V_M = V·Z_M/(R_s + jω_e L_σ + Z_M),
    ψ_R = |V_M|/ω_e, and φ_r = ψ_R/θ in the motor's gauge θ = L_sr/L_r (docs/commissioning.md §4:
    the flux the motor carries at its rated operating point).
    """
    we = 2.0 * math.pi * frequency
    slip = 1.0 - speed_rpm * pole_pairs / (60.0 * frequency)
    z_m = 1.0 / (1.0 / (1j * we * L_M) + slip / R_R)
    v_m = voltage * z_m / (R_s + 1j * we * L_sigma + z_m)
    return abs(v_m) / we / theta


def rated_flux(motor: MotorParams) -> Optional[float]:
    """
    Return the motor's rated rotor flux [Wb].

    ``rated_flux`` when the file states it, else :func:`rated_rotor_flux` from the rated
    voltage, frequency and speed, else None.
    """
    if motor.rated_flux > 0:
        return motor.rated_flux
    if min(motor.rated_voltage_rms_line, motor.rated_frequency, motor.rated_speed_rpm) > 0:
        return rated_rotor_flux(motor.R_s, motor.L_sigma, motor.L_M, motor.R_R, motor.theta,
                                motor.rated_voltage, motor.rated_frequency,
                                motor.rated_speed_rpm, motor.pole_pairs)
    return None


def default_limits(motor: MotorParams) -> Dict[str, Tuple[float, str]]:
    """
    Return the defaults a motor's ratings give the drive.

    ``{parameter: (value, why)}`` for the parameters a rating exists for (an unrated motor
    gives {} — the run is the thesis's).

    Controller: ``v_limit`` = rated voltage-vector magnitude, ``current_limit`` = rated
    current-vector magnitude, ``phi_d`` = ``phi_max`` = the rated flux and ``phi_min`` =
    :data:`FLUX_MIN_SHARE` of it. Plant: ``v_limit`` (the inverter), ``current_trip`` =
    :data:`CURRENT_TRIP_MARGIN` × rated current, ``speed_trip`` = :data:`SPEED_TRIP_MARGIN` ×
    rated speed. The one home of these defaults: the nodes (for parameters left at -1) and the
    ROS-free loop call it; an explicit parameter always overrides.
    """
    out: Dict[str, Tuple[float, str]] = {}
    if motor.rated_voltage_rms_line > 0:
        out['v_limit'] = (motor.rated_voltage,
                          f'rated voltage {motor.rated_voltage_rms_line:g} V line-to-line RMS')
    if motor.rated_current_rms > 0:
        i = motor.rated_current
        out['current_limit'] = (i, f'rated current {motor.rated_current_rms:g} A RMS '
                                   f'(vector magnitude sqrt(3) x {motor.rated_current_rms:g})')
        out['current_trip'] = (CURRENT_TRIP_MARGIN * i,
                               f'{CURRENT_TRIP_MARGIN:g} x rated current {i:.4g} A')
    if motor.rated_speed_rpm > 0:
        out['speed_trip'] = (SPEED_TRIP_MARGIN * motor.rated_speed,
                             f'{SPEED_TRIP_MARGIN:g} x rated speed {motor.rated_speed_rpm:g} rpm')
    phi = rated_flux(motor)
    if phi is not None:
        why = ('stated rated_flux' if motor.rated_flux > 0 else
               'rated flux at rated voltage, frequency and speed')
        out['phi_d'] = (phi, why)
        out['phi_max'] = (phi, why)
        out['phi_min'] = (FLUX_MIN_SHARE * phi, f'{FLUX_MIN_SHARE:.4g} x {why}')
    return out


#: a limit or level left at RATED takes the motor's rating (:func:`default_limits`), or, for a
#: motor without that rating, the value it had before ratings were defaults (``fallback``)
RATED = 'rated'


def resolve_rated(owner, names: Mapping[str, object], motor: MotorParams,
                  previous: Optional[Mapping[str, Tuple[float, str]]] = None
                  ) -> Dict[str, Tuple[float, str]]:
    """
    Set each :data:`RATED` attribute of ``owner`` from ``motor``'s ratings, else its fallback.

    The attributes are those named in ``names`` ({name: fallback}). Returns ``{name: (value,
    why)}`` of those the ratings set, with the entries of ``previous`` still in force (a
    configuration copied with ``dataclasses.replace`` keeps saying where its limits came from).
    """
    limits = default_limits(motor)
    used = {k: x for k, x in (previous or {}).items() if getattr(owner, k, None) == x[0]}
    for name, fallback in names.items():
        if isinstance(getattr(owner, name), str) and getattr(owner, name) == RATED:
            if name in limits:
                object.__setattr__(owner, name, limits[name][0])
                used[name] = limits[name]
            else:
                object.__setattr__(owner, name, fallback)
    return used


def describe_defaults(used: Mapping[str, Tuple[float, str]]) -> str:
    """
    One line naming each default taken from the ratings, e.g. for the node logs.

    ``from the motor's ratings: current_limit = 8.66 (rated current 5 A RMS ...)``.
    """
    return "from the motor's ratings: " + '; '.join(
        f'{k} = {v:.4g} ({why})' for k, (v, why) in used.items())


REQUIRED_MOTOR_FIELDS = ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr', 'pole_pairs', 'J', 'b')
#: the fields a rated flux is derived from when ``rated_flux`` is not given (:func:`rated_flux`)
FLUX_RATING_NAMES = ('rated_voltage_rms_line', 'rated_frequency', 'rated_speed_rpm')


def motor_defaults(given, motor: MotorParams) -> list:
    """
    Return one line per default a motor description without some fields runs with.

    ``given``: the field names the description (a motor file, the nodes' parameters) holds. An
    absent core-loss coefficient is the thesis's (a written 0 is the file's: no core loss); a
    rating absent or 0 (the file format's "not given") is no limit or trip
    (:func:`default_limits`); without a rated flux the flux levels are the thesis's. A
    commissioned file with a nameplate writes every field: no line.
    """
    given = set(given)
    lines = []
    for name, what in (('k_e', 'eddy-current'), ('k_h', 'hysteresis')):
        if name not in given:
            lines.append(f"no {name}: the thesis's {what} core-loss coefficient {name} = "
                         f'{getattr(THESIS_MOTOR, name):g} W s/Wb^2 applies (write {name}: 0.0 '
                         'for none)')
    if not motor.rated_voltage_rms_line:
        lines.append('no rated_voltage_rms_line: no voltage limit (v_limit of the controller '
                     'and the plant off; only inverter_rating trips)')
    if not motor.rated_current_rms:
        lines.append('no rated_current_rms: no current limit and no over-current trip')
    if not motor.rated_speed_rpm:
        lines.append('no rated_speed_rpm: no over-speed trip')
    if rated_flux(motor) is None:
        lv = THESIS_FLUX_LEVELS
        lines.append(f'no rated_flux (nor {", ".join(FLUX_RATING_NAMES)} to derive it): the '
                     f"thesis's flux levels phi_d = phi_max = {lv['phi_d']:g} Wb, phi_min = "
                     f"{lv['phi_min']:g} Wb")
    return lines


_WARNED: set = set()


def warn_motor_defaults(source: str, given, motor: MotorParams, log=None) -> list:
    """
    Warn once per process, one line each, of the defaults :func:`motor_defaults` names.

    ``log`` (a node logger's ``warning``) or the ``im_common.params`` logger. Returns the lines
    warned now (a source already warned of is not warned of again).
    """
    out = []
    for line in motor_defaults(given, motor):
        text = f'{source}: {line}'
        if text in _WARNED:
            continue
        _WARNED.add(text)
        (log or logging.getLogger('im_common.params').warning)(text)
        out.append(text)
    return out


#: what each motor field is, and its unit: the nodes' parameter descriptions and the motor
#: file's schema (im_common.motor_file)
MOTOR_DOC = {
    'R_s': 'stator resistance [ohm]',
    'R_r': 'rotor resistance referred to the stator [ohm]',
    'L_s': 'stator self inductance [H]',
    'L_r': 'rotor self inductance [H]',
    'L_sr': 'stator-rotor mutual inductance [H]',
    'J': 'inertia of motor and load [kg m^2]',
    'b': 'viscous friction [N m s]',
    'k_e': 'eddy-current core-loss coefficient [W s/Wb^2]',
    'k_h': 'hysteresis core-loss coefficient [W s/Wb^2]',
    'rated_voltage_rms_line': 'nameplate voltage, line-to-line RMS [V] (0: not given)',
    'rated_current_rms': 'nameplate current, line RMS [A] (0: not given)',
    'rated_frequency': 'nameplate frequency [Hz] (0: not given)',
    'rated_speed_rpm': 'nameplate shaft speed [rpm] (0: not given)',
    'rated_power': 'nameplate shaft power [W] (0: not given)',
    'rated_flux': 'rated rotor flux [Wb] (0: from rated voltage, frequency and speed)',
}


#: the range of each motor field a motor file, a run file's motor mapping and a node take
#: (one home: im_common.node_params.declare_motor declares the nodes' parameters with them)
MOTOR_RANGES = {
    'R_s': (1e-6, 100.0), 'R_r': (1e-6, 100.0), 'L_s': (1e-6, 10.0), 'L_r': (1e-6, 10.0),
    'L_sr': (1e-6, 10.0), 'J': (1e-6, 1e9), 'b': (0.0, 100.0), 'k_e': (0.0, 10.0),
    'k_h': (0.0, 10.0), 'rated_voltage_rms_line': (0.0, 1e5), 'rated_current_rms': (0.0, 1e5),
    'rated_frequency': (0.0, 1e4), 'rated_speed_rpm': (0.0, 1e6), 'rated_power': (0.0, 1e9),
    'rated_flux': (0.0, 100.0), 'pole_pairs': (1, 64)}


def motor_from_dict(values: Mapping, source: str = 'motor') -> MotorParams:
    """
    Return a :class:`MotorParams` from a mapping of the motor fields.

    Every error is one line naming ``source`` and the field (missing, unknown with the nearest
    valid name, invalid).
    """
    if not isinstance(values, Mapping):
        raise InvalidParameter(f'{source}', values, 'must be a mapping of motor parameters')
    for key in values:
        if key in MOTOR_BLOCKS:
            continue                    # the plant's blocks: :func:`motor_blocks`
        if key in LEGACY_RATINGS:
            raise InvalidParameter(f'{source}: {key}', values[key],
                                   f'ratings are nameplate values now: write '
                                   f'{LEGACY_RATINGS[key]}')
        if key not in MOTOR_FIELDS:
            near = difflib.get_close_matches(str(key), MOTOR_FIELDS, n=1)
            hint = (f"; did you mean '{near[0]}'?" if near
                    else f" (known: {', '.join(MOTOR_FIELDS)})")
            raise InvalidParameter(f'{source}: {key}', values[key],
                                   f'unknown motor parameter{hint}')
    for key in REQUIRED_MOTOR_FIELDS:
        if key not in values:
            raise InvalidParameter(f'{source}: {key}', None, 'is missing')
    clean = {}
    for key, val in values.items():
        if key in MOTOR_BLOCKS:
            continue
        bad = parameter_error(val, getattr(THESIS_MOTOR, key), *MOTOR_RANGES[key])
        if bad:
            raise InvalidParameter(f'{source}: {key}', val, bad)
        clean[key] = val
    motor_blocks(values, source)    # a bad block is refused with the motor
    try:
        return MotorParams(**clean)
    except InvalidParameter as exc:
        raise InvalidParameter(f'{source}: {exc.name}', exc.value, exc.reason) from None


#: the real plant's blocks a motor file may hold (docs/plant.md) and the model of each: a node
#: takes one as flat parameters, ``saturation.beta``, ``thermal.C_s`` (what a motor file's nested
#: mapping ``saturation: {law: power, beta: 1.4, S: 7.0}`` gives a node;
#: :func:`im_common.node_params.declare_motor`)
MOTOR_BLOCK_MODELS = {'saturation': SaturationBlock, 'thermal': Thermal}
MOTOR_BLOCKS = tuple(MOTOR_BLOCK_MODELS)


def motor_blocks(values: Mapping, source: str = 'motor') -> Dict[str, dict]:
    """
    Return the validated ``saturation`` / ``thermal`` blocks of a motor's values ({} if none).

    Each is a mapping (a motor file's ``saturation: {law: power, beta: 1.3, S: 7.0}``) or, as
    motor files wrote it before, its YAML text; an empty string is no block. Errors are one line
    naming the source and the key.
    """
    out = {}
    for key in MOTOR_BLOCKS:
        spec = values.get(key)
        if spec is None or spec == '':
            continue
        if isinstance(spec, str):
            try:
                spec = yaml.safe_load(spec)
            except yaml.YAMLError as exc:
                raise InvalidParameter(f'{source}: {key}', spec,
                                       f'not a YAML mapping ({str(exc).splitlines()[0]})') \
                    from None
        try:
            if key == 'saturation':
                saturation_block(spec)
            else:
                thermal_from_dict(spec)
        except InvalidParameter as exc:
            raise InvalidParameter(f'{source}: {exc.name}', exc.value, exc.reason) from None
        out[key] = dict(spec)
    return out


def load_motor_blocks(path: str) -> Dict[str, dict]:
    """Return the ``saturation`` / ``thermal`` blocks of a motor file ({} if it has none)."""
    doc = read_yaml_file(path, 'motor file')
    load_motor_file(path)                       # the same layout and motor checks
    return motor_blocks(doc['/**']['ros__parameters'] or {}, source=path)


def read_yaml_file(path: str, what: str):
    """
    Return the YAML document in ``path``, read by :func:`im_common.yamlio.read_yaml_file`.

    The one reader's line (the file, and for a syntax error its line and column) comes as one
    :class:`InvalidParameter` naming ``what`` (e.g. 'motor file'), as this module's callers take.
    """
    def error(message):
        return InvalidParameter(what, path, message)
    return yamlio.read_yaml_file(path, what, error)


def load_motor_file(path: str) -> MotorParams:
    """
    Read a motor file.

    A ROS 2 parameters YAML whose ``/**`` (every node) section holds the motor fields under
    ``ros__parameters``.
    """
    doc = read_yaml_file(path, 'motor file')
    if not isinstance(doc, dict) or set(doc) != {'/**'} or not isinstance(doc['/**'], dict) \
            or set(doc['/**']) != {'ros__parameters'}:
        raise InvalidParameter(f'{path}', 'layout',
                               "must be '/**:' with one 'ros__parameters:' mapping (a ROS 2 "
                               'parameters file for every node)')
    values = doc['/**']['ros__parameters'] or {}
    motor = motor_from_dict(values, source=path)
    warn_motor_defaults(path, values, motor)        # what the file leaves out, once each
    return motor


def shipped_motors_dir() -> str:
    """Directory of the shipped motor files (installed share, else the source tree)."""
    try:    # heavy: ament_index_python, only for the installed share
        from ament_index_python.packages import get_package_share_directory
        d = os.path.join(get_package_share_directory('im_common'), 'config', 'motors')
        if os.path.isdir(d):
            return d
    except (ImportError, LookupError, OSError):   # not installed (run from src/): the source tree
        pass
    return os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'config',
                        'motors')


def shipped_motor(name: str, key: str = 'motor') -> str:
    """
    Return the path of the shipped motor file a bare name stands for (``krause_3hp``).

    InvalidParameter naming ``key`` and the shipped motors if there is none of that name.
    """
    d = shipped_motors_dir()
    path = os.path.join(d, f'{name}.yaml')
    if not os.path.isfile(path):
        names = sorted(f[:-5] for f in os.listdir(d) if f.endswith('.yaml'))
        raise InvalidParameter(key, name, 'is no motor file and no shipped motor (shipped: '
                               f'{", ".join(names)})')
    return path


def is_motor_name(value: object) -> bool:
    """Return whether a motor value is a bare name (no directory, no extension): a shipped one."""
    return isinstance(value, str) and re.fullmatch(r'[A-Za-z0-9_-]+', value) is not None


# Seed 000 §4.3: the controller's fixed estimates under the chapter-4 variation profile
# (R̂_s 0.687, L̂_s 0.084, L̂_sr 0.081, initial R̂_r 0.842 and θ̂ = L̂_sr/L̂_r = 0.952941).
CHAPTER4_ESTIMATES = THESIS_MOTOR.with_values(R_s=0.687, L_s=0.084, L_sr=0.081, R_r=0.842,
                                              L_r=0.081 / 0.952941)


# ---------------------------------------------------------------------------------------------
# Time-varying parameters
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Variation:
    """
    A scalar function of time with its derivative: ``value(t)``, ``rate(t)``.

    kind: ``constant`` (offset), ``ramp`` (offset + slope·t) or ``sinusoid``
    (offset + amplitude·sin(omega·t + phase)).
    """

    kind: str
    offset: float
    slope: float = 0.0
    amplitude: float = 0.0
    omega: float = 0.0
    phase: float = 0.0

    def __post_init__(self):
        if self.kind not in ('constant', 'ramp', 'sinusoid'):
            raise ValueError(f"unknown variation kind '{self.kind}' (constant, ramp, sinusoid)")
        for name in ('offset', 'slope', 'amplitude', 'omega', 'phase'):
            if not math.isfinite(float(getattr(self, name))):
                raise ValueError(f"variation field '{name}' must be finite")

    def value(self, t: float) -> float:
        if self.kind == 'constant':
            return self.offset
        if self.kind == 'ramp':
            return self.offset + self.slope * t
        return self.offset + self.amplitude * math.sin(self.omega * t + self.phase)

    def rate(self, t: float) -> float:
        if self.kind == 'constant':
            return 0.0
        if self.kind == 'ramp':
            return self.slope
        return self.amplitude * self.omega * math.cos(self.omega * t + self.phase)


def constant(value: float) -> Variation:
    return Variation('constant', float(value))


def ramp(start: float, slope: float) -> Variation:
    return Variation('ramp', float(start), slope=float(slope))


def sinusoid(offset: float, amplitude: float, omega: float, phase: float = 0.0) -> Variation:
    return Variation('sinusoid', float(offset), amplitude=float(amplitude), omega=float(omega),
                     phase=float(phase))


class ParameterSchedule:
    """
    Electrical parameters of the plant as functions of time.

    ``values(t)`` returns ``(R_s, R_r, L_s, L_r, L_sr)``; ``inductance_rates(t)`` returns
    ``(dL_s/dt, dL_r/dt, dL_sr/dt)``. Parameters without a variation keep the base value,
    and a schedule without variations returns one cached tuple (the plant's fast path).
    """

    def __init__(self, base: MotorParams = THESIS_MOTOR,
                 variations: Mapping[str, Variation] | None = None, name: str = 'none'):
        self.base = base
        self.name = name
        self.variations: Dict[str, Variation] = dict(variations or {})
        for key in self.variations:
            if key not in ELECTRICAL_NAMES:
                raise InvalidParameter(key, self.variations[key],
                                       f'only {", ".join(ELECTRICAL_NAMES)} can vary in time')
        self._constant = not self.variations
        self._values = tuple(getattr(base, n) for n in ELECTRICAL_NAMES)
        self._zero_rates = (0.0, 0.0, 0.0)
        self._fns: Tuple[Callable[[float], float], ...] = tuple(
            (self.variations[n].value if n in self.variations
             else (lambda t, c=getattr(base, n): c))
            for n in ELECTRICAL_NAMES)
        self._rate_fns = tuple(
            (self.variations[n].rate if n in self.variations else (lambda t: 0.0))
            for n in INDUCTANCE_NAMES)
        self._inductances_constant = not any(n in self.variations for n in INDUCTANCE_NAMES)

    @property
    def is_constant(self) -> bool:
        return self._constant

    @property
    def inductances_constant(self) -> bool:
        return self._inductances_constant

    def values(self, t: float) -> Tuple[float, float, float, float, float]:
        if self._constant:
            return self._values
        return tuple(f(t) for f in self._fns)

    def inductance_rates(self, t: float) -> Tuple[float, float, float]:
        if self._inductances_constant:
            return self._zero_rates
        return tuple(f(t) for f in self._rate_fns)

    def params_at(self, t: float) -> MotorParams:
        """Return the full, validated parameter set at time t."""
        return self.base.with_values(**dict(zip(ELECTRICAL_NAMES, self.values(t))))

    def validate(self, t_end: float, samples: int = 2001) -> None:
        """Check positivity and σ > 0 on a grid over [0, t_end]; raise naming parameter, time."""
        n = max(2, int(samples))
        for k in range(n):
            t = t_end * k / (n - 1)
            try:
                self.params_at(t)
            except InvalidParameter as exc:
                raise InvalidParameter(
                    exc.name, exc.value,
                    f'{exc.reason} at t = {t:.6g} s of schedule {self.name!r}') from None

    def describe(self) -> Dict[str, object]:
        return {'name': self.name,
                'variations': {k: {'kind': v.kind, 'offset': v.offset, 'slope': v.slope,
                                   'amplitude': v.amplitude, 'omega': v.omega, 'phase': v.phase}
                               for k, v in self.variations.items()}}


def chapter4_schedule(base: MotorParams = THESIS_MOTOR) -> ParameterSchedule:
    """
    Seed 000 §4.3 variation profile, as a breakpoint variation (:data:`CHAPTER4_VARIATION`).

    R_r = 0.42 t + 0.42, L_s = L_r = 0.1 + 0.016 sin(πt), L_sr = 0.097 + 0.016 sin(πt).
    """
    return variation_schedule(base, CHAPTER4_VARIATION, name='chapter4')


def single_variation_schedule(name: str, factor: float, base: MotorParams = THESIS_MOTOR
                              ) -> ParameterSchedule:
    """Return a constant scaling of one electrical parameter (seed 000 §4.2.1, sensitivity)."""
    if name not in ELECTRICAL_NAMES:
        raise InvalidParameter(name, factor, f'only {", ".join(ELECTRICAL_NAMES)} can be varied')
    return ParameterSchedule(base, {name: constant(getattr(base, name) * factor)},
                             name=f'{name}x{factor:g}')


#: Seed 000 §4.3 in the run file's ``variation:`` form (SI values; 0.5 Hz = π rad/s; the ramp
#: 0.42 t + 0.42 written up to 1000 s); the shipped run file config/runs/chapter4.yaml holds
#: the same
CHAPTER4_VARIATION = {
    'R_r': [{'t': 0.0, 'value': 0.42, 'shape': 'step'},
            {'t': 1000.0, 'value': 420.42, 'shape': 'ramp'}],
    'L_s': [{'t': 0.0, 'value': 0.1, 'shape': 'step'},
            {'sine': 0.016, 'frequency': 0.5, 'phase': 0.0}],
    'L_r': [{'t': 0.0, 'value': 0.1, 'shape': 'step'},
            {'sine': 0.016, 'frequency': 0.5, 'phase': 0.0}],
    'L_sr': [{'t': 0.0, 'value': 0.097, 'shape': 'step'},
             {'sine': 0.016, 'frequency': 0.5, 'phase': 0.0}],
}

SCHEDULES = {
    'none': lambda base=THESIS_MOTOR: ParameterSchedule(base),
    'chapter4': chapter4_schedule,
}


# Breakpoint schedules (the run file's ``variation:``; docs/running.md) -------------------------
BREAKPOINT_SHAPES = ('step', 'ramp')


class Breakpoints:
    """
    One parameter's value in time from breakpoints and optional sine terms.

    ``value(t)``, ``rate(t)``, as :class:`Variation`.

    ``points``: ((t, level, shape), ...) with t strictly increasing; ``step`` jumps to the level
    at t, ``ramp`` goes linearly from the previous breakpoint (the first from (0, ``start``)).
    Before the first breakpoint the level is ``start``, after the last it holds. ``sines``:
    ((amplitude, frequency [Hz], phase [rad]), ...) added to the level. ``unit`` multiplies
    the whole (the motor file's value for ``scale`` breakpoints, 1 for ``value`` ones).
    """

    def __init__(self, points, sines=(), start: float = 1.0, unit: float = 1.0):
        self.points = tuple((float(t), float(v), s) for t, v, s in points)
        self.sines = tuple((float(a), 2.0 * math.pi * float(f), float(p)) for a, f, p in sines)
        self.start = float(start)
        self.unit = float(unit)

    def _level(self, t: float):
        """(level, d level/dt) of the breakpoints at t."""
        prev_t, prev_v = 0.0, self.start
        for t_i, v_i, shape in self.points:
            if t < t_i:
                if shape == 'ramp' and t >= prev_t and t_i > prev_t:
                    slope = (v_i - prev_v) / (t_i - prev_t)
                    return prev_v + slope * (t - prev_t), slope
                return prev_v, 0.0
            prev_t, prev_v = t_i, v_i
        return prev_v, 0.0

    def value(self, t: float) -> float:
        v, _ = self._level(t)
        for a, w, p in self.sines:
            v = v + a * math.sin(w * t + p)
        return v if self.unit == 1.0 else self.unit * v

    def rate(self, t: float) -> float:
        _, r = self._level(t)
        for a, w, p in self.sines:
            r = r + a * w * math.cos(w * t + p)
        return r if self.unit == 1.0 else self.unit * r


def _spec_number(where: str, value, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InvalidParameter(where, value, 'must be a finite number')
    if positive and value <= 0:
        raise InvalidParameter(where, value, 'must be > 0')
    return float(value)


def normalize_variation(spec, where: str = 'variation') -> Dict[str, list]:
    """
    Return the validated, normalized form of a breakpoint variation ``{parameter: [item, ...]}``.

    See docs/running.md: items ``{t, scale|value, shape}`` (shape step by default) and
    ``{sine, frequency, phase}``. Errors are :class:`InvalidParameter` named by the key path,
    e.g. ``variation.R_r[0].shape``.
    """
    if spec is None:
        return {}
    if not isinstance(spec, Mapping):
        raise InvalidParameter(where, spec, 'must be a mapping {parameter: [breakpoints]} or a '
                               f'name ({", ".join(SCHEDULES)})')
    out: Dict[str, list] = {}
    for name, items in spec.items():
        key = f'{where}.{name}'
        if name not in ELECTRICAL_NAMES:
            raise InvalidParameter(key, items,
                                   f'only {", ".join(ELECTRICAL_NAMES)} can vary in time')
        if not isinstance(items, (list, tuple)) or not items:
            raise InvalidParameter(key, items, 'must be a non-empty list of breakpoints')
        clean, unit_kind, last_t = [], None, None
        for k, item in enumerate(items):
            at = f'{key}[{k}]'
            if not isinstance(item, Mapping):
                raise InvalidParameter(at, item, 'must be a mapping {t, scale, shape} or '
                                                 '{sine, frequency, phase}')
            if 'sine' in item:
                unknown = [x for x in item if x not in ('sine', 'frequency', 'phase')]
                if unknown:
                    raise InvalidParameter(f'{at}.{unknown[0]}', item[unknown[0]],
                                           'unknown in a sine term (sine, frequency, phase)')
                if 'frequency' not in item:
                    raise InvalidParameter(f'{at}.frequency', None, 'is missing (Hz)')
                clean.append({'sine': _spec_number(f'{at}.sine', item['sine']),
                              'frequency': _spec_number(f'{at}.frequency', item['frequency'],
                                                        True),
                              'phase': _spec_number(f'{at}.phase', item.get('phase', 0.0))})
                continue
            unknown = [x for x in item if x not in ('t', 'scale', 'value', 'shape')]
            if unknown:
                raise InvalidParameter(f'{at}.{unknown[0]}', item[unknown[0]],
                                       'unknown in a breakpoint (t, scale or value, shape)')
            if 't' not in item:
                raise InvalidParameter(f'{at}.t', None, 'is missing (s)')
            t = _spec_number(f'{at}.t', item['t'])
            if t < 0:
                raise InvalidParameter(f'{at}.t', t, 'must be >= 0')
            if last_t is not None and t <= last_t:
                raise InvalidParameter(f'{at}.t', t,
                                       f'must be after the previous breakpoint ({last_t:g} s)')
            kinds = [x for x in ('scale', 'value') if x in item]
            if len(kinds) != 1:
                raise InvalidParameter(at, dict(item), 'needs exactly one of scale (x the motor '
                                                       "file's value) or value (SI)")
            if unit_kind is not None and kinds[0] != unit_kind:
                raise InvalidParameter(f'{at}.{kinds[0]}', item[kinds[0]],
                                       f'all breakpoints of {name} use one of scale or value')
            unit_kind = kinds[0]
            shape = item.get('shape', 'step')
            if shape not in BREAKPOINT_SHAPES:
                raise InvalidParameter(f'{at}.shape', shape, 'must be step or ramp')
            clean.append({'t': t, unit_kind: _spec_number(f'{at}.{unit_kind}', item[unit_kind]),
                          'shape': shape})
            last_t = t
        out[name] = clean
    return out


#: a node parameter of a variation left out: one number, never a pair nor a triple
_NONE_GIVEN = parameter_spec([0.0], sentinels=(([0.0], (), 'none'),))


class ParameterVariation(BaseModel):
    """
    One parameter's breakpoint variation, flat: what a node takes as ``variation.<name>.*``.

    The run file's list ``[{t, scale|value, shape}, ..., {sine, frequency, phase}, ...]``
    (:func:`normalize_variation`) as the levels' kind, the breakpoints (t, level) and their
    shapes, and the sine terms; :func:`variation_block` builds it, :meth:`items` gives the list
    back (the breakpoints, then the sine terms: the schedule adds the sines to the breakpoints'
    level, in whatever order they were written).
    """

    model_config = BLOCK_CONFIG

    by: Literal['scale', 'value'] = Field('scale', description="the breakpoints' levels: scale "
                                          "(x the motor's value) or value (SI)")
    points: Tuple[float, ...] = Field((), description='breakpoints, flat (t [s], level) pairs, '
                                      't >= 0 and rising', json_schema_extra=_NONE_GIVEN)
    shape: Tuple[str, ...] = Field((), description="each breakpoint's shape: step (the level from "
                                   't on) or ramp (linear from the previous breakpoint)',
                                   json_schema_extra=parameter_spec(
                                       [''], sentinels=(([''], (), 'every breakpoint a step'),)))
    sines: Tuple[float, ...] = Field((), description='sine terms added to the level, flat '
                                     '(amplitude, frequency [Hz] > 0, phase [rad]) triples',
                                     json_schema_extra=_NONE_GIVEN)

    @model_validator(mode='before')
    @classmethod
    def _arrays(cls, spec):
        """Take an array as a list (a node parameter's) too; no shape: every breakpoint a step."""
        if not isinstance(spec, Mapping):
            return spec
        spec = {k: tuple(v) if k in ('points', 'shape', 'sines') and isinstance(v, list) else v
                for k, v in spec.items()}
        if 'shape' not in spec and isinstance(spec.get('points'), tuple):
            spec['shape'] = ('step',) * (len(spec['points']) // 2)
        return spec

    @model_validator(mode='after')
    def _rules(self) -> 'ParameterVariation':
        """Refuse what is no list of breakpoints and sine terms (one line naming the array)."""
        if not self.points and not self.sines:
            raise InvalidParameter('points', [], 'no breakpoint and no sine term: give points '
                                   'or sines (or leave the parameter out of the variation)')
        if len(self.points) % 2:
            raise InvalidParameter('points', list(self.points), 'must be (t, level) pairs: an '
                                   'even count of numbers')
        times = self.points[0::2]
        for k, t in enumerate(times):
            if t < 0:
                raise InvalidParameter('points', list(self.points), f't = {t:g} s of breakpoint '
                                       f'{k} must be >= 0')
            if k and not t > times[k - 1]:
                raise InvalidParameter('points', list(self.points), f't = {t:g} s of breakpoint '
                                       f'{k} must be after the previous breakpoint '
                                       f'({times[k - 1]:g} s)')
        if len(self.shape) != len(times):
            raise InvalidParameter('shape', list(self.shape), f'must give one shape per '
                                   f'breakpoint ({len(times)})')
        for s in self.shape:
            if s not in BREAKPOINT_SHAPES:
                raise InvalidParameter('shape', list(self.shape), 'must be step or ramp each')
        if len(self.sines) % 3:
            raise InvalidParameter('sines', list(self.sines), 'must be (amplitude, frequency, '
                                   'phase) triples: a count of numbers divisible by 3')
        for k, f in enumerate(self.sines[1::3]):
            if not f > 0:
                raise InvalidParameter('sines', list(self.sines), f'the frequency {f:g} Hz of '
                                       f'sine term {k} must be > 0')
        return self

    def items(self) -> list:
        """Return the run file's list of this variation (:func:`normalize_variation`'s form)."""
        pts = self.points
        out = [{'t': pts[2 * k], self.by: pts[2 * k + 1], 'shape': shape}
               for k, shape in enumerate(self.shape)]
        s = self.sines
        out += [{'sine': s[k], 'frequency': s[k + 1], 'phase': s[k + 2]}
                for k in range(0, len(s), 3)]
        return out


class VariationBlock(BaseModel):
    """A breakpoint variation, {parameter: :class:`ParameterVariation`} (None: not varied)."""

    model_config = BLOCK_CONFIG

    R_s: Optional[ParameterVariation] = None
    R_r: Optional[ParameterVariation] = None
    L_s: Optional[ParameterVariation] = None
    L_r: Optional[ParameterVariation] = None
    L_sr: Optional[ParameterVariation] = None

    def parts(self) -> Dict[str, ParameterVariation]:
        """Return {parameter: its variation} of those varied (in ELECTRICAL_NAMES order)."""
        return {n: getattr(self, n) for n in ELECTRICAL_NAMES if getattr(self, n) is not None}

    def spec(self) -> Dict[str, list]:
        """Return the run file's mapping of this variation (:func:`normalize_variation`'s form)."""
        return {n: part.items() for n, part in self.parts().items()}


def variation_block(spec, where: str = 'variation') -> VariationBlock:
    """
    Return the :class:`VariationBlock` of a run file's breakpoint variation (or the block itself).

    Errors are :func:`normalize_variation`'s lines (``variation.R_r[0].shape``).
    """
    if isinstance(spec, VariationBlock):
        return spec
    parts = {}
    for pname, items in normalize_variation(spec, where).items():
        points = [i for i in items if 'sine' not in i]
        by = 'value' if any('value' in i for i in points) else 'scale'
        parts[pname] = ParameterVariation(
            by=by, points=tuple(x for i in points for x in (i['t'], i[by])),
            shape=tuple(i['shape'] for i in points),
            sines=tuple(x for i in items if 'sine' in i
                        for x in (i['sine'], i['frequency'], i['phase'])))
    return VariationBlock(**parts)


def variation_schedule(base: MotorParams, spec, name: Optional[str] = None) -> ParameterSchedule:
    """
    Return the :class:`ParameterSchedule` of a breakpoint variation over the motor ``base``.

    The variation as :func:`normalize_variation` takes it, or its :class:`VariationBlock`:
    ``scale`` levels multiply the motor's value, ``value`` levels are SI; before the first
    breakpoint a parameter keeps the motor's value.
    """
    spec = normalize_variation(spec.spec() if isinstance(spec, VariationBlock) else spec)
    variations = {}
    for pname, items in spec.items():
        base_value = getattr(base, pname)
        by_value = any('value' in i for i in items)
        points = [(i['t'], i['value' if by_value else 'scale'], i['shape'])
                  for i in items if 'sine' not in i]
        sines = [(i['sine'], i['frequency'], i['phase']) for i in items if 'sine' in i]
        variations[pname] = Breakpoints(points, sines, start=base_value if by_value else 1.0,
                                        unit=1.0 if by_value else base_value)
    return ParameterSchedule(base, variations, name=name or describe_variation(spec))


def describe_variation(spec) -> str:
    """
    Return a one-line account of a breakpoint variation (summaries, console headers).

    The variation as :func:`variation_schedule` takes it; each parameter's breakpoints, then its
    sine terms (the same line however they were written, and from its :class:`VariationBlock`).
    """
    spec = normalize_variation(spec.spec() if isinstance(spec, VariationBlock) else spec)
    if not spec:
        return 'none'
    parts = []
    for pname in (n for n in ELECTRICAL_NAMES if n in spec):     # one order on every path
        items = spec[pname]
        terms = []
        for i in sorted(items, key=lambda i: 'sine' in i):     # stable: written order kept
            if 'sine' in i:
                terms.append(f"+{i['sine']:g} sin {i['frequency']:g} Hz")
            else:
                level = f"x{i['scale']:g}" if 'scale' in i else f"{i['value']:g}"
                terms.append(f"{i['shape']} {level} at {i['t']:g} s")
        parts.append(f'{pname} ' + ', '.join(terms))
    return '; '.join(parts)
