"""
Inverter-error compensation: the voltage a two-level inverter loses, as the drive models it.

A leg of the inverter (docs/plant.md §1) gives the motor, on average over a carrier period, its
commanded phase voltage less

    e_x = v_dead · sgn(i_x) + r_on · i_x,     v_dead = t_d · f_sw · V_dc + v_on,

for x ∈ {a, b, c}: the dead time t_d loses (i > 0) or gains (i < 0) t_d of pulse width per
carrier period, and the conducting device drops v_on + r_on·i. The common mode of (e_a, e_b, e_c)
does not reach a star-connected motor; the αβ error is their power-invariant Clarke transform.

The drive compensates it (docs/compensation.md): the controller adds ê(i) to its command, and the
observer and adapter take the voltage the motor actually got, the command less ê(i). Both
evaluate ê at the measured current of the step (sampled at the carrier's peak: the period's mean
current), with the sign smoothed into a ramp over ±``current_band``: within the band the current
ripple crosses zero during the period and the true average error passes through zero with it.
The model's numbers come from the run's inverter block (exact knowledge, ``compensation:
inverter``) or from commissioning (``{v_dead, r_on, current_band}``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Optional, Tuple

from .inverter import Inverter, phase_values
from .params import clarke
from .validation import check_block, check_real, InvalidParameter

COMPENSATION_KEYS = ('v_dead', 'r_on', 'current_band')
#: the sign's ramp half-width when none is given [A]
DEFAULT_CURRENT_BAND = 0.2


@dataclass(frozen=True)
class InverterErrorModel:
    """The drive's model of the inverter's voltage error (module doc); SI units."""

    v_dead: float
    r_on: float = 0.0
    current_band: float = DEFAULT_CURRENT_BAND

    @property
    def active(self) -> bool:
        return self.v_dead > 0.0 or self.r_on > 0.0

    def phase_errors(self, i_a: float, i_b: float, i_c: float) -> Tuple[float, float, float]:
        """Return (e_a, e_b, e_c): each leg's average voltage loss at these phase currents [V]."""
        band = self.current_band
        vd, r = self.v_dead, self.r_on
        out = []
        for i in (i_a, i_b, i_c):
            s = i / band if band > 0.0 else (1.0 if i > 0 else -1.0 if i < 0 else 0.0)
            s = 1.0 if s > 1.0 else -1.0 if s < -1.0 else s
            out.append(vd * s + r * i)
        return out[0], out[1], out[2]

    def error(self, i_alpha: float, i_beta: float) -> Tuple[float, float]:
        """Return the αβ voltage the inverter loses at the stator current (i_α, i_β) [V]."""
        return clarke(*self.phase_errors(*phase_values(i_alpha, i_beta)))

    def command(self, v_alpha: float, v_beta: float, i_alpha: float,
                i_beta: float) -> Tuple[float, float]:
        """Return the command that makes the motor get (v_α, v_β): the controller's side."""
        ea, eb = self.error(i_alpha, i_beta)
        return v_alpha + ea, v_beta + eb

    def motor_voltage(self, v_alpha: float, v_beta: float, i_alpha: float,
                      i_beta: float) -> Tuple[float, float]:
        """Return the voltage the motor got for a command (v_α, v_β): observer and adapter."""
        ea, eb = self.error(i_alpha, i_beta)
        return v_alpha - ea, v_beta - eb

    def describe(self) -> dict:
        return {k: getattr(self, k) for k in COMPENSATION_KEYS}

    def parameters(self) -> dict:
        """Return the node parameters ``comp_v_dead``, ``comp_r_on``, ``comp_current_band``."""
        return {f'comp_{k}': float(getattr(self, k)) for k in COMPENSATION_KEYS}


def from_inverter(inv: Inverter, current_band: float = DEFAULT_CURRENT_BAND
                  ) -> InverterErrorModel:
    """Return the exact model of a known inverter: v_dead = t_d f_sw V_dc + v_on, its r_on."""
    return InverterErrorModel(inv.deadtime * inv.pwm_frequency * inv.V_dc + inv.v_on, inv.r_on,
                              current_band)


def compensation_from_dict(spec, inverter: Optional[Inverter] = None,
                           where: str = 'compensation') -> Optional[InverterErrorModel]:
    """
    Return the model of a run file's ``compensation`` value (None: no compensation).

    ``false``/None: off; ``inverter`` (or ``true``): exact, from the run's inverter block;
    ``{inverter: true, current_band}`` likewise with a band; a mapping ``{v_dead, r_on,
    current_band}``: as commissioned. Errors are one line naming the key.
    """
    if spec is None or spec is False:
        return None
    band = DEFAULT_CURRENT_BAND
    if isinstance(spec, Mapping) and 'inverter' in spec:
        check_block(spec, where, ('inverter', 'current_band'))
        if spec['inverter'] is not True:
            raise InvalidParameter(f'{where}.inverter', spec['inverter'], 'must be true')
        band = check_real(f'{where}.current_band', spec.get('current_band', band), 0.0)
        spec = 'inverter'
    if spec is True or spec == 'inverter':
        if inverter is None:
            raise InvalidParameter(where, spec, "takes the run's inverter block, and this run "
                                   'has none (the ideal plant has no inverter error)')
        return from_inverter(inverter, band)
    if not isinstance(spec, Mapping):
        raise InvalidParameter(where, spec, 'must be false, inverter, or a mapping {v_dead, '
                                            'r_on, current_band}')
    check_block(spec, where, COMPENSATION_KEYS)
    if 'v_dead' not in spec:
        raise InvalidParameter(f'{where}.v_dead', None, 'is missing')
    vals = {k: check_real(f'{where}.{k}', v, 0.0) for k, v in spec.items()}
    return InverterErrorModel(**vals)


def compensation_from_parameters(values: Mapping[str, float]) -> Optional[InverterErrorModel]:
    """Return the model the ``comp_*`` node parameters describe (None: off, v_dead = r_on = 0)."""
    m = InverterErrorModel(float(values.get('comp_v_dead', 0.0)),
                           float(values.get('comp_r_on', 0.0)),
                           float(values.get('comp_current_band', DEFAULT_CURRENT_BAND)))
    return m if m.active else None
