"""
The two-level voltage-source inverter: carrier PWM, dead time, on-state drops, DC link.

Derivations in docs/plant.md §1. In short:

* Three legs fed from the DC link V_dc; leg x ∈ {a, b, c} has switch state s_x ∈ {0, 1} (lower /
  upper device conducting), so its pole voltage is s_x V_dc − V_on sgn(i_x) − r_on i_x (a device
  conducting current i drops V_on sgn(i) + r_on i, transistor or diode alike).
* The model's αβ frame is power-invariant (:func:`im_common.params.clarke`): a pole-voltage set
  (V_dc, 0, 0) is the vector √(2/3) V_dc, the six active vectors span a hexagon of that
  circumradius, and its inscribed circle — the largest rotating vector the inverter makes — has
  radius √(2/3)·(√3/2) V_dc = V_dc/√2 (V_dc = 311 V gives 220 V, a 220 V line-to-line RMS
  motor's rated vector magnitude).
* PWM by comparing each phase's reference with a triangular carrier of period T_c = 1/f_sw, the
  references shifted by the min-max zero sequence v_0 = −(max + min)/2 (equivalent to space-vector
  PWM: the linear range is the whole hexagon). The duty of leg x is d_x = ½ + (v_x + v_0)/V_dc; a
  command outside the hexagon (max − min > V_dc) is scaled onto its boundary, keeping its angle.
* The carrier starts each period at its peak, where the current is sampled (the middle of the
  zero vector: the ripple-free value). Single update: T_s = T_c, leg x is switched on during
  [(1 − d_x) T_c/2, (1 + d_x) T_c/2]; double update: T_s = T_c/2, the first half holds the turn-on
  edge and the second the turn-off edge, each with the command of its own period.
* Dead time t_d: the device that turns on does so t_d late. During a dead band both devices are
  off and the current's freewheeling diode sets the pole: s = 0 for i > 0, s = 1 for i < 0. Per
  carrier period that loses (i > 0) or gains (i < 0) t_d of pulse width at each of the two edges,
  the average error −sgn(i) t_d f_sw V_dc per phase. A lower device whose turn-on falls past the
  period's end (its leg switched off less than t_d before it, or on all period) is still waiting
  at the next period's start: that period's first off interval begins in a dead band of that
  length, the ``carry`` (:func:`carry_after`), so that a pulse of the lower device narrower than
  the dead time vanishes as an upper one does.
* Switching losses (``e_sw`` at ``v_sw``, ``i_sw``): each hard-switched edge of a leg — the
  transistor taking the current from the opposite diode or giving it back — dissipates
  ½ e_sw (V_dc/v_sw)(|i_x|/i_sw), i_x the leg's current at that instant: e_sw is the energy of
  one turn-on plus one turn-off at the reference point, scaled linearly in the voltage and the
  current switched (the datasheet model E_sw(V, I) = E_ref (V/V_ref)^K_v (I/I_ref)^K_i with
  K_v = K_i = 1; docs/plant.md §1). The edges are the pole transitions of the carrier's exact
  instants with the dead bands resolved (a pulse narrower than the dead time makes none), so a
  leg carrying a constant current i at duty 0 < d < 1 loses f_sw e_sw (V_dc/v_sw)(|i|/i_sw).
  Drawn from the DC link beside the conduction losses.
* Optional DC link (``C_dc`` > 0): a capacitor fed by a diode front end (the source V_dc behind
  ``R_source``, which can only deliver), a brake chopper (``R_chopper`` across the link while V
  > ``V_chopper``) and an over-voltage trip at ``V_trip``. Held over a period, updated at its end
  in energy form: ½C V_{k+1}² = ½C V_k² + (P_source − P_chopper) T_s − E_dc, E_dc the energy the
  legs drew over the period, so the DC-side books close exactly.
* Computational delay (``delay``, :mod:`im_common.delay`): the command computed from the
  measurement of step k acts over step k + delay. It needs no carrier: a block with neither
  ``V_dc`` nor ``pwm_frequency`` is the ideal voltage source with that delay, ``inverter: {delay:
  1}`` (docs/plant.md §10).
"""
from __future__ import annotations

import math
from typing import Literal, Optional

from pydantic import BaseModel, Field, model_validator

from .delay import MAX_DELAY
from .validation import BLOCK_CONFIG, InvalidParameter, parameter_spec, parse_block

SQRT_2_3 = math.sqrt(2.0 / 3.0)
HALF_SQRT3 = 0.5 * math.sqrt(3.0)
#: the longest dead time accepted, as a share of the PWM period
MAX_DEADTIME_SHARE = 0.1
#: the plant node's parameter of V_dc and pwm_frequency: 0 for 'not given' (the ideal source)
_NOT_GIVEN = parameter_spec(0.0, sentinels=((0.0, None, 'not given'),))


class Inverter(BaseModel):
    """
    The ``inverter:`` block of a run file (SI; the module doc, docs/plant.md §1).

    With ``V_dc`` and ``pwm_frequency`` the switched inverter; with neither, the ideal voltage
    source, which takes only ``delay`` (:attr:`switched`).
    """

    model_config = BLOCK_CONFIG

    V_dc: Optional[float] = Field(None, gt=0, description='DC-link voltage V_dc [V] (with C_dc > '
                                  '0: the source behind the diode front end); with '
                                  'pwm_frequency, or neither for the ideal voltage source',
                                  json_schema_extra=_NOT_GIVEN)
    pwm_frequency: Optional[float] = Field(None, gt=0, description='switching (carrier) '
                                           'frequency f_sw [Hz]; with V_dc',
                                           json_schema_extra=_NOT_GIVEN)
    delay: int = Field(0, ge=0, le=MAX_DELAY, description='computational delay [control '
                       'periods]: the command computed from the measurement of step k acts over '
                       'step k + delay (0: at once, the theses; 1: a DSP)')
    deadtime: float = Field(0.0, ge=0, description='dead time t_d [s], at most a tenth of the '
                            'PWM period 1/pwm_frequency')
    update: Literal['single', 'double'] = Field(
        'single', description='control update per carrier period: single (T_s = 1/f_sw) or '
        'double (T_s = 1/(2 f_sw))')
    v_on: float = Field(0.0, ge=0, description="the devices' on-state voltage drop [V]")
    r_on: float = Field(0.0, ge=0, description="the devices' on-state resistance [ohm]")
    e_sw: float = Field(0.0, ge=0, description="one leg's switching energy [J]: a turn-on plus "
                        'a turn-off at v_sw and i_sw, scaled linearly in V_dc and the current '
                        'switched (0: no switching losses)')
    v_sw: Optional[float] = Field(None, gt=0, description="e_sw's reference voltage [V]; with "
                                  'e_sw', json_schema_extra=_NOT_GIVEN)
    i_sw: Optional[float] = Field(None, gt=0, description="e_sw's reference current [A]; with "
                                  'e_sw', json_schema_extra=_NOT_GIVEN)
    C_dc: float = Field(0.0, ge=0, description='DC-link capacitance [F] (0: a stiff DC link, '
                        'V_dc constant)')
    R_source: float = Field(0.5, gt=0, description="the diode front end's source resistance "
                            '[ohm] (DC link only)')
    V_chopper: float = Field(0.0, ge=0, description='brake-chopper threshold [V], between V_dc '
                             'and the trip voltage (0: no brake chopper; DC link only)')
    R_chopper: float = Field(50.0, gt=0, description='brake-chopper resistance [ohm]')
    V_trip: float = Field(0.0, ge=0, description='over-voltage trip [V], above V_dc (0: 1.3 '
                          'V_dc; DC link only)')

    @model_validator(mode='after')
    def _rules(self) -> 'Inverter':
        """Refuse what breaks the rules across fields: the pair, the dead time, the DC link."""
        if (self.V_dc is None) != (self.pwm_frequency is None):
            missing = 'pwm_frequency' if self.pwm_frequency is None else 'V_dc'
            raise InvalidParameter(missing, None, 'is missing: V_dc and pwm_frequency make the '
                                   'switched inverter together (neither: the ideal voltage '
                                   'source, which takes only delay)')
        if not self.switched:
            extra = [k for k in self.model_fields_set if k != 'delay'
                     and getattr(self, k) != type(self).model_fields[k].default]
            if extra:
                key = min(extra, key=list(type(self).model_fields).index)
                raise InvalidParameter(key, getattr(self, key), 'needs the switched inverter: '
                                       'give V_dc and pwm_frequency (the ideal voltage source '
                                       'takes only delay)')
            return self
        if self.e_sw > 0 and (self.v_sw is None or self.i_sw is None):
            missing = 'v_sw' if self.v_sw is None else 'i_sw'
            raise InvalidParameter(missing, None, 'is missing: e_sw is the switching energy at '
                                   'the reference point (v_sw, i_sw); give both')
        if self.e_sw == 0 and (self.v_sw is not None or self.i_sw is not None):
            key = 'v_sw' if self.v_sw is not None else 'i_sw'
            raise InvalidParameter(key, getattr(self, key), 'is the reference point of e_sw, '
                                   'which is not given (or 0): give e_sw too, or neither')
        if self.deadtime > MAX_DEADTIME_SHARE * self.T_c:
            raise InvalidParameter('deadtime', self.deadtime,
                                   f'longer than a tenth of the PWM period 1/pwm_frequency = '
                                   f'{self.T_c:.6g} s')
        if self.C_dc > 0:
            if self.trip_voltage <= self.V_dc:
                raise InvalidParameter('V_trip', self.V_trip, 'must be above V_dc')
            if self.V_chopper and not self.V_dc < self.V_chopper < self.trip_voltage:
                raise InvalidParameter('V_chopper', self.V_chopper,
                                       'must lie between V_dc and the trip voltage V_trip')
        return self

    @classmethod
    def from_block(cls, spec, where: str = 'inverter') -> 'Inverter':
        """Return the Inverter of an ``inverter:`` block; errors are one line naming the key."""
        return parse_block(cls, spec, where)

    @property
    def switched(self) -> bool:
        """Return True for the switched inverter (V_dc and pwm_frequency given)."""
        return self.V_dc is not None

    @property
    def T_c(self) -> float:
        """Return the carrier period [s]."""
        return 1.0 / self.pwm_frequency

    @property
    def T_s(self) -> float:
        """Return the control period synchronous with the carrier [s]."""
        return self.T_c if self.update == 'single' else 0.5 * self.T_c

    @property
    def v_max(self) -> float:
        """Return the radius of the hexagon's inscribed circle, V_dc/√2 (module doc) [V]."""
        return self.V_dc / math.sqrt(2.0)

    @property
    def switching_coefficient(self) -> float:
        """
        Return k = e_sw/(v_sw i_sw) [J/(V A)]: an edge switching i at V dissipates ½ k V |i|.

        0 without switching losses (module doc).
        """
        if not self.e_sw:
            return 0.0
        return self.e_sw / (self.v_sw * self.i_sw)

    def steady_loss_coefficients(self):
        """
        Return (r, c): the inverter's mean losses at a sinusoidal current vector |i|, r|i|² + c|i|.

        A phase current of amplitude Î = √(2/3)|i| (power-invariant vector) has the mean
        |i_x| = 2Î/π; one device of each leg conducts at any instant, so the on-state drops lose
        3 (v_on · 2Î/π) + 3 r_on Î²/2 = c_on|i| + r_on|i|², and each leg switches i_x on and off
        once a carrier period, f_sw (e_sw/(v_sw i_sw)) V_dc · 2Î/π a leg. With
        κ = 3·(2/π)·√(2/3) = 1.5594: c = κ (v_on + f_sw V_dc e_sw/(v_sw i_sw)), r = r_on. The
        dead time changes the voltage, not the losses (docs/efficiency.md §2).
        """
        if not self.switched:
            return 0.0, 0.0
        kappa = 6.0 / math.pi * SQRT_2_3
        return self.r_on, kappa * (self.v_on + self.pwm_frequency * self.V_dc
                                   * self.switching_coefficient)

    @property
    def trip_voltage(self) -> float:
        return self.V_trip if self.V_trip > 0 else 1.3 * self.V_dc

    def describe(self) -> dict:
        """Return the block as a run file writes it (every field; the ideal source: delay only)."""
        if not self.switched:
            return {'delay': self.delay}
        if not self.e_sw:                       # no switching losses: the block as before them
            return self.model_dump(exclude={'e_sw', 'v_sw', 'i_sw'})
        return self.model_dump()


def phase_values(x_a: float, x_b: float):
    """Return the phase values (a, b, c) of an αβ vector: the inverse power-invariant Clarke."""
    ka = SQRT_2_3 * x_a
    kb = SQRT_2_3 * HALF_SQRT3 * x_b
    return ka, -0.5 * ka + kb, -0.5 * ka - kb


def duties(v_a: float, v_b: float, V_dc: float):
    """
    Return each leg's duty (d_a, d_b, d_c) for the command (v_α, v_β), and the scale applied.

    Min-max zero-sequence injection; a command outside the hexagon is scaled onto it (scale < 1).
    """
    a, b, c = phase_values(v_a, v_b)
    hi = max(a, b, c)
    lo = min(a, b, c)
    spread = hi - lo
    scale = 1.0
    if spread > V_dc:
        scale = V_dc / spread
    v0 = -0.5 * (hi + lo)
    k = scale / V_dc
    return (0.5 + (a + v0) * k, 0.5 + (b + v0) * k, 0.5 + (c + v0) * k), scale


def clip_to_hexagon(v_a: float, v_b: float, V_dc: float):
    """Return the command scaled onto the hexagon when outside it (else unchanged)."""
    _, scale = duties(v_a, v_b, V_dc)
    return v_a * scale, v_b * scale


def edges(d: float, half: int, T_c: float, T_s: float, t_d: float):
    """
    Return (t_on, t_on_end, t_off, t_off_end) of one leg in a period [0, T_s].

    The leg is on in [t_on_end, t_off), off outside [t_on, t_off_end), and in the dead bands
    between (both devices off) the current's sign decides. ``half`` is 0 for a single update or
    the first half of a double update, 1 for the second half.
    """
    big = 2.0 * T_s
    if d <= 0.0:
        return big, big, big, big                   # off all period, no edge
    if d >= 1.0:
        return -big, -big, big, big                 # on all period, no edge
    if T_s == T_c:                                  # single update
        t_on = 0.5 * (1.0 - d) * T_c
        t_off = 0.5 * (1.0 + d) * T_c
        return t_on, t_on + t_d, t_off, t_off + t_d
    if half == 0:
        t_on = 0.5 * (1.0 - d) * T_c
        return t_on, t_on + t_d, big, big
    t_off = 0.5 * d * T_c
    return -big, -big, t_off, t_off + t_d


def carry_after(d: float, half: int, T_c: float, T_s: float, t_d: float) -> float:
    """
    Return how long into the next period a leg's lower device still waits for its turn-on [s].

    The device turns on t_d after the leg's turn-off: past the period's end when the turn-off
    came less than t_d before it, or t_d into the next period when the leg was on at the end (on
    all period, or the first half of a double update) — 0 when it was already on.
    """
    if t_d <= 0.0 or d <= 0.0:
        return 0.0
    if d >= 1.0 or (T_s != T_c and half == 0):
        return t_d
    t_off_end = edges(d, half, T_c, T_s, t_d)[3]
    return t_off_end - T_s if t_off_end > T_s else 0.0


def period_plan(d, half: int, T_c: float, T_s: float, t_d: float, signs=(0, 0, 0),
                extra=(), carry=(0.0, 0.0, 0.0)):
    """
    Return the period's constant-switching intervals: a list of (length, states).

    ``states`` holds per leg 1 (on), 0 (off) or None (dead band: the current's sign decides at the
    interval's start). The instants are computed here, once, at the start of the period. A leg
    whose current sign is given (``signs`` ±1; 0: not known) has its dead bands resolved: for
    i > 0 the leg is on in [t_on + t_d, t_off), for i < 0 in [t_on, t_off + t_d). ``carry``
    (:func:`carry_after` of the last period) turns the start of a leg's first off interval into
    a dead band.
    """
    legs = []
    for x, sgn, c in zip(d, signs, carry):
        t_on, t_on_end, t_off, t_off_end = edges(x, half, T_c, T_s, t_d)
        c_end = min(c, t_on, T_s) if t_on > 0.0 else 0.0    # the waiting lower device
        if sgn > 0:
            t_on, t_off_end = t_on_end, t_off
            c_end = 0.0                         # the lower diode: off, as the device would be
        elif sgn < 0:
            t_on_end, t_off = t_on, t_off_end
        legs.append((t_on, t_on_end, t_off, t_off_end, c_end, sgn < 0))
    cuts = {0.0, T_s}
    cuts.update(t for t in extra if 0.0 < t < T_s)
    for e in legs:
        for t in e[:5]:
            if 0.0 < t < T_s:
                cuts.add(t)
    ts = sorted(cuts)
    plan = []
    for j in range(len(ts) - 1):
        t0, t1 = ts[j], ts[j + 1]
        if t1 - t0 <= 1e-15:
            continue
        tm = 0.5 * (t0 + t1)
        states = []
        for t_on, t_on_end, t_off, t_off_end, c_end, upper in legs:
            if t_on_end <= tm < t_off:
                states.append(1)
            elif tm < c_end:                    # the lower device still waiting
                states.append(1 if upper else None)
            elif t_on <= tm < t_off_end:
                states.append(None)
            else:
                states.append(0)
        plan.append((t1 - t0, tuple(states)))
    return plan


def check_against_motor(inv: Inverter, rated_voltage: float, T_s: float,
                        where: str = 'inverter') -> None:
    """Refuse a DC link too low for the motor's rated voltage and a period off the carrier."""
    if not inv.switched:
        return
    if rated_voltage > 0 and inv.v_max < rated_voltage * (1.0 - 1e-9):
        raise InvalidParameter(f'{where}.V_dc', inv.V_dc,
                               f'too low for the rated voltage {rated_voltage:g} V: the inverter '
                               f'makes at most V_dc/sqrt(2) = {inv.v_max:.4g} V (vector '
                               f'magnitude, power-invariant); needs V_dc >= '
                               f'{rated_voltage * math.sqrt(2.0):.4g} V')
    if abs(T_s - inv.T_s) > 1e-12 * max(T_s, inv.T_s):
        raise InvalidParameter(f'{where}.pwm_frequency', inv.pwm_frequency,
                               f'the control period T_s = {T_s:g} s must be the carrier period '
                               f'(update single: 1/pwm_frequency) or its half (update double); '
                               f'here {inv.T_s:g} s')
