"""
A sensorless drive's resistances from the windings' temperatures (docs/adaptation.md §9).

Sensorless, R_R and the speed meet only in the slip (docs/sensorless.md §3): the adapter holds
R̂_R. A warming cage moves R_R by 0.4 %/K, 20 % over a 50 K duty. What the drive knows is its
own losses; the motor file's ``thermal`` block (:mod:`im_common.thermal`) ties them to the
windings: each is one first-order network heated by its own loss,

    C dT/dt = P − (T − T_amb)/R_th,       R(T) = R_ref (1 + α (T − T_ref)),

so the drive runs the same two networks on its estimated losses — the stator's R̂_s|i|², the
cage's R̂_R|i − φ̂_M/L̂_M|² (the inverse-Γ rotor current) — and reads R̂_s and R̂_R from the
windings' temperatures. The networks start where the block says (T0_s, T0_r, else the ambient):
a motor that starts warmer than that, or a block whose constants are off, is an error the
networks carry (docs/adaptation.md §9 measures one).

Sensored, the least squares measure R_s (where it weighs) and R_R; the networks are then the
process model between measurements: after each update the temperatures are set to those the
estimates imply (:meth:`WindingTemperatures.anchor`), and until the next the estimates move as
the networks warm or cool them. Where the data pins the resistances the block's errors do not
accumulate; where it does not (R_s at high speed) the estimates still follow the windings.
"""
from __future__ import annotations

from im_common.thermal import first_order, Thermal, thermal_from_dict


class WindingTemperatures:
    """
    The two windings' temperatures from the drive's loss estimates.

    Parameters
    ----------
    thermal : Thermal
        The motor file's block (capacitances, resistances to ambient, T_ambient, T_ref, α).
    R_s_ref, R_R_ref : float
        The model's stator resistance and inverse-Γ rotor resistance at ``thermal.T_ref``.

    """

    def __init__(self, thermal: Thermal, R_s_ref: float, R_R_ref: float):
        self.thermal = thermal
        self.R_s_ref, self.R_R_ref = R_s_ref, R_R_ref
        self.T_s, self.T_r = thermal.initial()
        self._h = None

    def step(self, h: float, P_s: float, P_r: float) -> None:
        """One period of ``h`` [s] with the period's mean losses P_s, P_r [W]."""
        th = self.thermal
        if h != self._h:
            self._h = h
            self._decay = th.decay(h)
        self.T_s = first_order(self.T_s, th.T_ambient, th.R_th_s, P_s, self._decay[0])
        self.T_r = first_order(self.T_r, th.T_ambient, th.R_th_r, P_r, self._decay[1])

    def anchor(self, R_s: float, R_R: float) -> None:
        """
        Set the windings' temperatures to those the resistances R_s, R_R imply.

        The sensored adapter's least squares measure the resistances; the networks then carry
        them from there, heated by the losses, until the next measurement.
        """
        th = self.thermal
        self.T_s = th.T_ref + (R_s / self.R_s_ref - 1.0) / th.alpha_s
        self.T_r = th.T_ref + (R_R / self.R_R_ref - 1.0) / th.alpha_r

    @property
    def R_R(self) -> float:
        """Return the cage's inverse-Γ resistance at its estimated temperature [Ω]."""
        return self.R_R_ref * self.thermal.resistance_factors(self.T_s, self.T_r)[1]

    @property
    def R_s(self) -> float:
        """Return the stator resistance at its estimated temperature [Ω]."""
        return self.R_s_ref * self.thermal.resistance_factors(self.T_s, self.T_r)[0]


def tracking_for(thermal, params) -> WindingTemperatures:
    """Return the tracker of a motor's ``thermal`` block (a Thermal or its mapping)."""
    if not isinstance(thermal, Thermal):
        thermal = thermal_from_dict(thermal)
    return WindingTemperatures(thermal, params.R_s, params.R_R)
