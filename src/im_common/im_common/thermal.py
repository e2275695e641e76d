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

from dataclasses import asdict, dataclass
import math
from typing import Mapping

from .validation import check_block, check_real, InvalidParameter

#: temperature coefficients of resistance at 20 °C [1/K]: annealed copper, cast aluminium
ALPHA_COPPER = 0.00393
ALPHA_ALUMINIUM = 0.00403


@dataclass(frozen=True)
class Thermal:
    """The ``thermal:`` block of a motor file (SI; temperatures in °C)."""

    C_s: float                  # stator winding (copper + the share of iron it heats) [J/K]
    R_th_s: float               # stator winding to ambient [K/W]
    C_r: float                  # rotor cage [J/K]
    R_th_r: float               # rotor cage to ambient [K/W]
    T_ambient: float = 25.0     # [°C]
    T_ref: float = 25.0         # temperature of the motor file's R_s, R_r [°C]
    T0_s: float = math.nan      # initial stator temperature (nan: T_ambient) [°C]
    T0_r: float = math.nan      # initial rotor temperature (nan: T_ambient) [°C]
    alpha_s: float = ALPHA_COPPER
    alpha_r: float = ALPHA_ALUMINIUM

    @property
    def tau_s(self) -> float:
        return self.C_s * self.R_th_s

    @property
    def tau_r(self) -> float:
        return self.C_r * self.R_th_r

    def initial(self):
        """Return the initial stator and rotor temperatures [°C]."""
        t_s = self.T_ambient if math.isnan(self.T0_s) else self.T0_s
        t_r = self.T_ambient if math.isnan(self.T0_r) else self.T0_r
        return t_s, t_r

    def resistance_factors(self, T_s: float, T_r: float):
        """Return (R_s(T)/R_s_ref, R_r(T)/R_r_ref)."""
        return (1.0 + self.alpha_s * (T_s - self.T_ref),
                1.0 + self.alpha_r * (T_r - self.T_ref))

    def decay(self, h: float):
        """Return (e^{−h/τ_s}, e^{−h/τ_r}) for a period h [s] (computed once per plant)."""
        return math.exp(-h / self.tau_s), math.exp(-h / self.tau_r)

    def describe(self) -> dict:
        d = asdict(self)
        return {k: v for k, v in d.items() if not (isinstance(v, float) and math.isnan(v))}


def first_order(T: float, T_amb: float, R_th: float, P: float, decay: float) -> float:
    """Exact step of C dT/dt = P − (T − T_amb)/R_th with P held, ``decay`` = e^{−h/τ}."""
    return T_amb + (T - T_amb) * decay + R_th * P * (1.0 - decay)


THERMAL_KEYS = tuple(Thermal.__dataclass_fields__)
REQUIRED_THERMAL = ('C_s', 'R_th_s', 'C_r', 'R_th_r')


def thermal_from_dict(spec: Mapping, where: str = 'thermal') -> Thermal:
    """Return the :class:`Thermal` of a ``thermal:`` block; errors are one line naming the key."""
    check_block(spec, where, THERMAL_KEYS)
    for key in REQUIRED_THERMAL:
        if key not in spec:
            raise InvalidParameter(f'{where}.{key}', None, 'is missing')
    out = {}
    for key, val in spec.items():
        if key in REQUIRED_THERMAL:
            out[key] = check_real(f'{where}.{key}', val, 0.0, lo_open=True)
        elif key in ('alpha_s', 'alpha_r'):
            out[key] = check_real(f'{where}.{key}', val, 0.0)
        else:
            out[key] = check_real(f'{where}.{key}', val, -273.15, lo_open=True)
    return Thermal(**out)
