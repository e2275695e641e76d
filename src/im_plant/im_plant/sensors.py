"""
Real sensors: an incremental encoder, phase-current sensors with an ADC, a DC-link voltmeter.

The ``sensors:`` block of a run file (docs/plant.md §5), e.g.
``{encoder_lines: 2048, adc_bits: 12, current_range: 20.0}``.

Encoder: ``encoder_lines`` lines, quadrature decoding, so 4 N counts per revolution; the count is
⌊θ 4N/2π⌋ and the measured position the count's angle (a truncation: error in [0, 2π/4N)).
Speed from counts, the M-method over a sliding window of ``speed_window`` periods::

    ω̂_k = (c_k − c_{k−W}) · 2π / (4N · W · T_s)

(the mean speed over the window: resolution 2π/(4N W T_s), delay W T_s/2; before W periods have
passed the window is the periods there are).

Currents: each phase x ∈ {a, b, c} is measured as gain_x · i_x + offset_x, then converted by an
ADC of ``adc_bits`` bits over [−current_range, current_range) (mid-tread rounding to the code,
clamped at the ends); the three measured phases give i_αβ by the model's Clarke transform
(:func:`im_common.params.clarke`). Sampled at the carrier's peak, which is the period's start.

DC link: measured by the same ADC bits over [0, vdc_range).
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Annotated, Tuple

from im_common.validation import BLOCK_CONFIG, parse_block
from pydantic import BaseModel, Field, field_validator

TWO_PI = 2.0 * math.pi
#: one number per phase (a, b, c); a block may give one number for all three
PhaseValues = Tuple[float, float, float]
_Gain = Annotated[float, Field(gt=0)]
#: the largest ADC resolution accepted [bits]
MAX_ADC_BITS = 32


@dataclass(frozen=True)
class Measurement:
    """What the drive measures at t_k: stator currents and the shaft (with optional noise)."""

    t: float
    i_alpha: float
    i_beta: float
    theta_r: float
    omega_r: float
    v_dc: float = math.nan      # the DC-link voltage measurement (runs with an inverter)


class Sensors(BaseModel):
    """The ``sensors:`` block of a run file (0 / left out: that sensor is ideal; module doc)."""

    model_config = BLOCK_CONFIG

    encoder_lines: int = Field(0, description='incremental encoder lines N, >= 1 (quadrature: '
                               '4 N counts per revolution; 0: the ideal shaft sensor)')
    speed_window: int = Field(10, ge=1, description='speed from counts: the M-method window '
                              '[periods]')
    adc_bits: int = Field(0, description='ADC resolution of the current and DC-link sensors '
                          f'[bits], 1 to {MAX_ADC_BITS} (0: ideal)')
    current_range: float = Field(50.0, gt=0, description='current ADC range: '
                                 '[-current_range, current_range) [A]')
    current_offset: PhaseValues = Field((0.0, 0.0, 0.0), description="current sensors' offset "
                                        'per phase a, b, c [A] (one number: all three)')
    current_gain: Tuple[_Gain, _Gain, _Gain] = Field(
        (1.0, 1.0, 1.0), description="current sensors' gain per phase a, b, c, > 0 (one "
        'number: all three)')
    vdc_range: float = Field(1000.0, gt=0, description='DC-link voltmeter ADC range: '
                             '[0, vdc_range) [V]')

    @field_validator('encoder_lines')
    @classmethod
    def _encoder(cls, value: int) -> int:
        if value <= 0:
            raise ValueError('an encoder needs >= 1 line (leave the key out for the ideal shaft '
                             'sensor)')
        return value

    @field_validator('adc_bits')
    @classmethod
    def _adc(cls, value: int) -> int:
        if value <= 0:
            raise ValueError('an ADC needs >= 1 bit (leave the key out for ideal current '
                             'sensors)')
        if value > MAX_ADC_BITS:
            raise ValueError(f'must be <= {MAX_ADC_BITS}')
        return value

    @field_validator('current_offset', 'current_gain', mode='before')
    @classmethod
    def _phases(cls, value):
        """Take one number for all three phases; a list must hold three."""
        if isinstance(value, (list, tuple)):
            if len(value) != 3:
                raise ValueError('must be one number or three (phases a, b, c)')
            return tuple(value)
        return (value, value, value)

    @classmethod
    def from_block(cls, spec, where: str = 'sensors') -> 'Sensors':
        """Return the Sensors of a ``sensors:`` block; errors are one line naming the key."""
        return parse_block(cls, spec, where)

    @property
    def counts_per_rev(self) -> int:
        return 4 * self.encoder_lines

    def count(self, theta: float) -> int:
        """Return the encoder count of shaft angle θ [rad] (quadrature: 4 N per revolution)."""
        return math.floor(theta * self.counts_per_rev / TWO_PI)

    def adc(self, x: float, lo: float, hi: float) -> float:
        """Return ``x`` through an ADC of ``adc_bits`` bits over [lo, hi) (ideal when 0 bits)."""
        bits = self.adc_bits
        if bits <= 0:
            return x
        n = 1 << bits
        lsb = (hi - lo) / n
        code = round((x - lo) / lsb)
        if code < 0:
            code = 0
        elif code >= n:
            code = n - 1
        return lo + code * lsb

    def phase_current(self, k: int, i: float) -> float:
        """Return the measurement of phase k's current ``i`` [A] (gain, offset, ADC)."""
        r = self.current_range
        return self.adc(self.current_gain[k] * i + self.current_offset[k], -r, r)

    def phase_currents(self, i_a: float, i_b: float, i_c: float):
        """Return the three phases' measurements: :meth:`phase_current` of each, in one call."""
        g = self.current_gain
        o = self.current_offset
        r = self.current_range
        adc = self.adc
        return (adc(g[0] * i_a + o[0], -r, r), adc(g[1] * i_b + o[1], -r, r),
                adc(g[2] * i_c + o[2], -r, r))

    def describe(self) -> dict:
        """Return the block as a run file writes it (an ideal encoder or ADC left out)."""
        out = self.model_dump()
        for key in ('current_offset', 'current_gain'):
            out[key] = list(out[key])
        return {k: v for k, v in out.items()
                if not (k in ('encoder_lines', 'adc_bits') and v == 0)}


class SpeedFromCounts:
    """
    The M-method over ``window`` periods of ``T_s`` (module doc); ``update(count)`` → ω̂.

    ``count0``: the count at t_0, or the counts of the periods up to it, oldest first (a shaft
    already turning at t_0 has been counted before it; :meth:`value` is then its speed at t_0).
    """

    def __init__(self, counts_per_rev: int, window: int, T_s: float, count0):
        self.scale = TWO_PI / (counts_per_rev * T_s)
        self.window = window
        self.hist = list(count0)[-(window + 1):] if isinstance(count0, (list, tuple)) \
            else [count0]

    def value(self) -> float:
        """Return ω̂ of the counts so far (0 with one count: no period has passed)."""
        h = self.hist
        return (h[-1] - h[0]) * self.scale / (len(h) - 1) if len(h) > 1 else 0.0

    def update(self, count: int) -> float:
        h = self.hist
        h.append(count)
        if len(h) > self.window + 1:
            del h[0]
        return (count - h[0]) * self.scale / (len(h) - 1)
