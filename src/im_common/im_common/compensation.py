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
inverter``) or from commissioning (``{v_dead, r_on, current_band}``); the mapping forms are the
pydantic model :class:`CompensationBlock`.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal, Mapping, Optional, Tuple

from pydantic import BaseModel, Field, field_validator, model_validator

from .inverter import Inverter, phase_values
from .params import clarke
from .validation import BLOCK_CONFIG, InvalidParameter, parse_block

#: the sign's ramp half-width when none is given [A]
DEFAULT_CURRENT_BAND = 0.2


class CompensationBlock(BaseModel):
    """
    A run file's ``compensation:`` mapping, exact or as commissioned.

    ``{inverter: true, current_band}`` or ``{v_dead, r_on, current_band}``; the bare forms
    ``false``, ``inverter``, ``true`` are :func:`compensation_from_dict`'s.
    """

    model_config = BLOCK_CONFIG

    inverter: Literal[True] = Field(None, description="true: the exact model of the run's "
                                    'inverter block (then no v_dead, r_on)')
    v_dead: Optional[float] = Field(None, ge=0, description="the dead time's and the devices' "
                                    'voltage loss t_d f_sw V_dc + v_on [V], as commissioned '
                                    '(without inverter: true)')
    r_on: float = Field(0.0, ge=0, description="the devices' on-state resistance [ohm]")
    current_band: float = Field(DEFAULT_CURRENT_BAND, ge=0, description="the sign's ramp "
                                'half-width [A]: the current ripple crosses zero within it')

    @field_validator('inverter', mode='before')
    @classmethod
    def _true(cls, value):
        if value is not True:
            raise ValueError('must be true')
        return value

    @model_validator(mode='after')
    def _one_form(self) -> 'CompensationBlock':
        """Refuse a mapping of neither form: v_dead missing, or given with inverter: true."""
        if self.inverter:
            given = [k for k in ('v_dead', 'r_on') if k in self.model_fields_set]
            if given:
                raise InvalidParameter(given[0], getattr(self, given[0]), 'unknown key with '
                                       'inverter: true (known: inverter, current_band)')
        elif self.v_dead is None:
            raise InvalidParameter('v_dead', None, 'is missing')
        return self


@dataclass(frozen=True)
class InverterErrorModel:
    """The drive's model of the inverter's voltage error (module doc); SI units."""

    v_dead: float
    r_on: float = CompensationBlock.model_fields['r_on'].default
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


#: the model's fields (its node parameters comp_<field>)
COMPENSATION_KEYS = tuple(f.name for f in fields(InverterErrorModel))


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
    if spec is True or spec == 'inverter':
        block = CompensationBlock(inverter=True)
    elif isinstance(spec, (Mapping, CompensationBlock)):
        block = parse_block(CompensationBlock, spec, where)
    else:
        raise InvalidParameter(where, spec, 'must be false, inverter, or a mapping {v_dead, '
                                            'r_on, current_band}')
    if not block.inverter:
        return InverterErrorModel(block.v_dead, block.r_on, block.current_band)
    if inverter is None:
        raise InvalidParameter(where, spec, "takes the run's inverter block, and this run "
                               'has none (the ideal plant has no inverter error)')
    return from_inverter(inverter, block.current_band)


def compensation_from_parameters(values: Mapping[str, float]) -> Optional[InverterErrorModel]:
    """Return the model the ``comp_*`` node parameters describe (None: off, v_dead = r_on = 0)."""
    m = InverterErrorModel(float(values.get('comp_v_dead', 0.0)),
                           float(values.get('comp_r_on', 0.0)),
                           float(values.get('comp_current_band', DEFAULT_CURRENT_BAND)))
    return m if m.active else None
