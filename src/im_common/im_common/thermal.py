"""
Winding temperatures: two first-order thermal networks and R_s(T), R_r(T) (docs/plant.md §4).

Each winding is one thermal capacitance C [J/K] with one resistance R_th [K/W] to the ambient
T_amb, heated by its own losses (the stator by its copper loss and the iron loss, the rotor by its
copper loss):

    C dT/dt = P − (T − T_amb)/R_th,      τ = R_th C

Over one control period the plant takes P as the period's mean loss (the energy its books
integrated over the period divided by T_s), and the update is the exact solution of that
first-order equation (no step-size limit):

    T_{k+1} = T_amb + (T_k − T_amb) e^{−T_s/τ} + R_th P (1 − e^{−T_s/τ})

The resistances follow the linear law R(T) = R_ref (1 + α (T − T_ref)), with the copper stator
α_s = 0.00393 /K and the aluminium cage α_r = 0.00403 /K by default; R_ref is the motor file's
value, at T_ref. The resistances are held over a period (the plant's energy books use the same
values, so they stay exact).
"""
from __future__ import annotations

import math
from typing import Mapping, Optional

from pydantic import BaseModel, Field

from .validation import BLOCK_CONFIG, parameter_spec, parse_block

#: temperature coefficients of resistance at 20 °C [1/K]: annealed copper, cast aluminium
ALPHA_COPPER = 0.00393
ALPHA_ALUMINIUM = 0.00403
#: absolute zero [°C]: every temperature lies above it
ABSOLUTE_ZERO = -273.15
#: the node parameter of an initial temperature left out (T_ambient): absolute zero, which the
#: field refuses, so it never stands for a temperature given
_AT_AMBIENT = parameter_spec(ABSOLUTE_ZERO, sentinels=((ABSOLUTE_ZERO, None, 'T_ambient'),))


class Thermal(BaseModel):
    """The ``thermal:`` block of a motor file (SI; temperatures in °C)."""

    model_config = BLOCK_CONFIG

    C_s: float = Field(gt=0, description='stator winding thermal capacitance (copper + the '
                       'share of iron it heats) [J/K]')
    R_th_s: float = Field(gt=0, description='stator winding to ambient thermal resistance [K/W]')
    C_r: float = Field(gt=0, description='rotor cage thermal capacitance [J/K]')
    R_th_r: float = Field(gt=0, description='rotor cage to ambient thermal resistance [K/W]')
    T_ambient: float = Field(25.0, gt=ABSOLUTE_ZERO, description='ambient temperature [degC]')
    T_ref: float = Field(25.0, gt=ABSOLUTE_ZERO, description="temperature of the motor's R_s, "
                         'R_r [degC]')
    T0_s: Optional[float] = Field(None, gt=ABSOLUTE_ZERO, description='initial stator winding '
                                  'temperature [degC]', json_schema_extra=_AT_AMBIENT)
    T0_r: Optional[float] = Field(None, gt=ABSOLUTE_ZERO, description='initial rotor cage '
                                  'temperature [degC]', json_schema_extra=_AT_AMBIENT)
    alpha_s: float = Field(ALPHA_COPPER, ge=0, description='stator temperature coefficient of '
                           'resistance [1/K] (copper)')
    alpha_r: float = Field(ALPHA_ALUMINIUM, ge=0, description='rotor temperature coefficient of '
                           'resistance [1/K] (aluminium)')

    @property
    def tau_s(self) -> float:
        return self.C_s * self.R_th_s

    @property
    def tau_r(self) -> float:
        return self.C_r * self.R_th_r

    def initial(self):
        """Return the initial stator and rotor temperatures [°C]."""
        t_s = self.T_ambient if self.T0_s is None else self.T0_s
        t_r = self.T_ambient if self.T0_r is None else self.T0_r
        return t_s, t_r

    def resistance_factors(self, T_s: float, T_r: float):
        """Return (R_s(T)/R_s_ref, R_r(T)/R_r_ref)."""
        return (1.0 + self.alpha_s * (T_s - self.T_ref),
                1.0 + self.alpha_r * (T_r - self.T_ref))

    def decay(self, h: float):
        """Return (e^{−h/τ_s}, e^{−h/τ_r}) for a period h [s] (computed once per plant)."""
        return math.exp(-h / self.tau_s), math.exp(-h / self.tau_r)

    def describe(self) -> dict:
        """Return the block as a motor file writes it (an initial temperature left out: none)."""
        return self.model_dump(exclude_none=True)


def first_order(T: float, T_amb: float, R_th: float, P: float, decay: float) -> float:
    """Exact step of C dT/dt = P − (T − T_amb)/R_th with P held, ``decay`` = e^{−h/τ}."""
    return T_amb + (T - T_amb) * decay + R_th * P * (1.0 - decay)


THERMAL_KEYS = tuple(Thermal.model_fields)


def thermal_from_dict(spec: Mapping, where: str = 'thermal') -> Thermal:
    """Return the :class:`Thermal` of a ``thermal:`` block; errors are one line naming the key."""
    return parse_block(Thermal, spec, where)
