"""
The gains of the baseline laws: the ``baseline:`` block of a run file (SI, rad/s).

Each loop is designed from one bandwidth (motulator 0.18's designs; power-invariant units, so
the gains in V/A and N·m·s are the same as motulator's):

* current loop, 2DOF complex-vector PI on the leakage inductance L_σ:
  k_t = α_c L_σ, k_p = (α_c + α_i) L_σ, k_i = α_c α_i L_σ (α_i = α_c unless given), so that
  i/i* = α_c/(s + α_c) on the plant L_σ di/dt = u − jω_c L_σ i;
* speed loop, 2DOF PI on the inertia J: k_t = α_s J, k_p = 2 α_s J, k_i = α_s² J, so that
  ω/ω* = α_s/(s + α_s) on J dω/dt = τ;
* position loop (position task), P on the angle: ω_cmd = ω* + α_p (θ* − θ), α_p = α_s/4;
* the angle advance of the output voltage, e^{j k_comp T_s ω_c}: k_comp = delay + ½ (the
  computational delay plus half a period of the zero-order hold) unless given.
"""
from __future__ import annotations

import math
from typing import Optional, Tuple

from im_common.validation import BLOCK_CONFIG, parameter_spec, parse_block
from pydantic import BaseModel, Field

#: motulator's default current-loop bandwidth, 2π·200 rad/s
DEFAULT_ALPHA_C = 2.0 * math.pi * 200.0
#: the thesis's speed gain k_v = 3 N·m·s on J = 0.03 kg·m² as a bandwidth α_s = k_v/J [rad/s]
DEFAULT_ALPHA_S = 100.0
#: the position loop's bandwidth, a quarter of the speed loop's (a cascade's usual separation)
DEFAULT_ALPHA_P = DEFAULT_ALPHA_S / 4.0
#: node parameters of the optional fields: 0 (alpha_i) / -1 (k_comp, where 0 is a value) = None
ALPHA_I_SENTINEL = parameter_spec(0.0, sentinels=((0.0, None, 'alpha_c'),))
K_COMP_SENTINEL = parameter_spec(-1.0, sentinels=((-1.0, None, 'delay + 0.5'),))


class LawGains(BaseModel):
    """What every baseline law's gains block has: the angle advance, and its parsing."""

    model_config = BLOCK_CONFIG

    k_comp: Optional[float] = Field(None, ge=0, le=5, description='angle advance of the output '
                                    'voltage [control periods] (None: delay + 0.5)',
                                    json_schema_extra=K_COMP_SENTINEL)

    @classmethod
    def from_block(cls, spec, where: str = 'baseline'):
        """Return the gains of a ``baseline:`` block; errors are one line naming the key."""
        return parse_block(cls, spec, where)

    def k_comp_for(self, delay: int) -> float:
        """Return the angle advance [control periods] for a delay of ``delay`` periods."""
        return delay + 0.5 if self.k_comp is None else self.k_comp


class SpeedLoopGains(LawGains):
    """The gains of a law with a speed PI (and a position loop around it): the module doc."""

    alpha_s: float = Field(DEFAULT_ALPHA_S, gt=0, description='speed-loop bandwidth alpha_s '
                           '[rad/s] (100: the thesis speed gain k_v = 3 N m s on J = 0.03)')
    alpha_p: float = Field(DEFAULT_ALPHA_P, gt=0, description='position-loop bandwidth alpha_p '
                           '[rad/s] of the position task (omega* + alpha_p (theta* - theta) to '
                           'the speed PI)')
    feedforward: bool = Field(True, description="feed the drive's reference forward to the "
                              'speed PI: its torque J theta_ddot* + b theta_dot* + load model and '
                              'the P path on the error, (k_p - k_t)(omega* - omega) (a ramp is '
                              "followed without lag); false: motulator's 2DOF PI as shipped, no "
                              'feedforward (it lags a ramp by its acceleration / alpha_s)')

    def speed_gains(self, J: float) -> Tuple[float, float, float]:
        """Return (k_t, k_p, k_i) of the speed controller [N·m·s, N·m·s, N·m]."""
        a = self.alpha_s
        return a * J, 2.0 * a * J, a * a * J


class BaselineGains(SpeedLoopGains):
    """The ``baseline:`` block: the bandwidths of the current-vector controller (module doc)."""

    alpha_c: float = Field(DEFAULT_ALPHA_C, gt=0, description='current-loop bandwidth alpha_c '
                           '[rad/s]: the reference-tracking pole of the current loop')
    alpha_i: Optional[float] = Field(None, gt=0, description='integral bandwidth of the current '
                                     'controller [rad/s] (None: alpha_c)',
                                     json_schema_extra=ALPHA_I_SENTINEL)

    @property
    def alpha_i_value(self) -> float:
        """Return the integral bandwidth of the current controller [rad/s]."""
        return self.alpha_c if self.alpha_i is None else self.alpha_i

    def current_gains(self, L_sigma: float) -> Tuple[float, float, float]:
        """Return (k_t, k_p, k_i) of the current controller [V/A, V/A, V/(A·s)]."""
        a_c, a_i = self.alpha_c, self.alpha_i_value
        return a_c * L_sigma, (a_c + a_i) * L_sigma, a_c * a_i * L_sigma
