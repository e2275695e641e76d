"""
Main-flux saturation: the magnetizing curve i_M(ψ) of the inverse-Γ model (docs/plant.md §2).

The curve lives in the inverse-Γ equivalent circuit, on the magnetizing inductance L_M that
carries the rotor flux ψ_R = θ φ_r (θ = L_sr/L_r, the motor's gauge; L_M0 = L_sr²/L_r is the
unsaturated value). The plant's state stays flux linkages, so the map the plant needs is the
explicit one, flux → current; no inversion by iteration is ever needed:

    i_μ = i_M(|ψ_R|) ψ_R/|ψ_R|,      W_M(ψ) = ∫₀^ψ i_M(ψ') dψ'   (the stored magnetic energy)

Two forms, written in a motor file's ``saturation:`` block:

* ``{law: power, beta: β [1/Wb], S: S}``: L_M(ψ) = L_M0 / (1 + (β ψ)^S) (the form motulator
  uses for its Γ-model), i_M(ψ) = ψ (1 + (β ψ)^S)/L_M0 and W_M = ψ²/(2 L_M0) + β^S ψ^(S+2) /
  ((S + 2) L_M0) in closed form.
* ``{table: [[ψ_1, i_1], [ψ_2, i_2], ...]}``: points of the curve (ψ [Wb], i_M [A]), the origin
  added, linear between points and beyond the last one with the last slope; both columns must
  rise strictly (a magnetizing curve is monotonic: a falling one is refused). W_M is the exact
  integral of the piecewise-linear curve.
"""
from __future__ import annotations

from bisect import bisect_right
import math
from typing import Literal, Mapping, Optional, Sequence, Tuple

from pydantic import BaseModel, Field, model_validator

from .validation import (BLOCK_CONFIG, check_block, check_real, InvalidParameter, parameter_spec,
                         parse_block)

#: the keys of a ``saturation:`` block: the law's, the table as [psi, i_M] rows (a run file, a
#: motor file) or as its two columns (a node's parameters, a motor file read by ROS)
SATURATION_KEYS = ('law', 'beta', 'S', 'table', 'table_psi', 'table_i_M')
SATURATION_SHAPE = '{law: power, beta, S} or {table: [[psi, i_M], ...]}'
#: a node parameter left out: a value the field refuses (beta >= 0, S > 0, a column of >= 2 points)
_NOT_GIVEN_BETA = parameter_spec(-1.0, sentinels=((-1.0, None, 'not given'),))
_NOT_GIVEN_S = parameter_spec(0.0, sentinels=((0.0, None, 'not given'),))
_NO_TABLE = parameter_spec([0.0], sentinels=(([0.0], (), 'no table'),))


def _table_error(psi: float, i_M: float, prev) -> Optional[str]:
    """Return why a table's point (psi, i_M) cannot follow the point ``prev``, or None."""
    if not (psi > prev[0] and i_M > prev[1]):
        return ('the magnetizing curve is not monotonic: psi and i_M must both rise from one '
                'point to the next')
    return None


class SaturationBlock(BaseModel):
    """
    The ``saturation:`` block of a motor file: the power law or a table (the module doc).

    Flat, so that a node takes it as parameters (``saturation.beta``, ``saturation.table_psi``);
    :func:`saturation_from_dict` takes the run file's and motor file's forms, ``table: [[psi,
    i_M], ...]`` included. :meth:`curve` is the :class:`Saturation` on a motor's L_M0.
    """

    model_config = BLOCK_CONFIG

    law: Literal['power'] = Field('power', description='the law L_M0/(1 + (beta psi)^S), with '
                                  'beta and S (a table takes none)')
    beta: Optional[float] = Field(None, ge=0, description='power law: beta [1/Wb]',
                                  json_schema_extra=_NOT_GIVEN_BETA)
    S: Optional[float] = Field(None, gt=0, description='power law: the exponent S',
                               json_schema_extra=_NOT_GIVEN_S)
    table_psi: Tuple[float, ...] = Field((), description='table: the flux psi of each point, '
                                         'rising [Wb] (with table_i_M; in place of the law)',
                                         json_schema_extra=_NO_TABLE)
    table_i_M: Tuple[float, ...] = Field((), description='table: the magnetizing current i_M '
                                         'of each point, rising [A] (with table_psi)',
                                         json_schema_extra=_NO_TABLE)

    @model_validator(mode='before')
    @classmethod
    def _columns(cls, spec):
        """Take a column as a list (a run file's, a node parameter's) too."""
        if isinstance(spec, Mapping):
            spec = {k: (tuple(v) if k in ('table_psi', 'table_i_M') and isinstance(v, list)
                        else v) for k, v in spec.items()}
        return spec

    @model_validator(mode='after')
    def _rules(self) -> 'SaturationBlock':
        """Refuse a table beside the law, a table's bad points, and the law without beta, S."""
        if self.table_psi or self.table_i_M:
            law = [k for k in ('law', 'beta', 'S') if k in self.model_fields_set]
            if law:
                raise InvalidParameter(law[0], getattr(self, law[0]),
                                       'give either a table or a law')
            n = len(self.table_psi)
            if n < 2:
                raise InvalidParameter('table_psi', list(self.table_psi),
                                       'must list at least two points')
            if len(self.table_i_M) != n:
                raise InvalidParameter('table_i_M', list(self.table_i_M),
                                       f'must list as many points as table_psi ({n})')
            prev = (0.0, 0.0)
            for k, point in enumerate(zip(self.table_psi, self.table_i_M)):
                for name, x in zip(('table_psi', 'table_i_M'), point):
                    if not x > 0:
                        raise InvalidParameter(f'{name}[{k}]', x, 'must be > 0')
                why = _table_error(*point, prev)
                if why:
                    raise InvalidParameter(f'table_psi[{k}]', list(point), why)
                prev = point
            return self
        for key in ('beta', 'S'):
            if getattr(self, key) is None:
                raise InvalidParameter(key, None, 'is missing')
        return self

    @property
    def table(self):
        """Return the table's points ((psi, i_M), ...), or None (the law)."""
        return tuple(zip(self.table_psi, self.table_i_M)) if self.table_psi else None

    def curve(self, L_M0: float) -> 'Saturation':
        """Return the :class:`Saturation` of this block on the unsaturated L_M0 [H]."""
        if self.table is not None:
            return Saturation(L_M0, table=self.table)
        return Saturation(L_M0, beta=self.beta, S=self.S)

    def describe(self) -> dict:
        """Return the block as a run file writes it (:meth:`Saturation.describe`'s form)."""
        if self.table is not None:
            return {'table': [list(p) for p in self.table]}
        return {'law': self.law, 'beta': self.beta, 'S': self.S}


class Saturation:
    """
    A magnetizing curve i_M(ψ) with its energy; see the module doc.

    ``inv_L(psi)`` returns i_M(ψ)/ψ (the inverse secant inductance, 1/L_M(ψ)) and
    ``energy(psi)`` returns W_M(ψ); ``L_M(psi)`` the secant inductance.
    """

    def __init__(self, L_M0: float, beta: float = 0.0, S: float = 0.0,
                 table: Optional[Sequence[Tuple[float, float]]] = None):
        self.L_M0 = float(L_M0)
        self.table = None
        if table is not None:
            psi = [0.0] + [float(p) for p, _ in table]
            cur = [0.0] + [float(i) for _, i in table]
            self.table = (psi, cur)
            self._slopes = [(cur[k + 1] - cur[k]) / (psi[k + 1] - psi[k])
                            for k in range(len(psi) - 1)]
            # energy at each knot: ∫ of the piecewise-linear curve up to it
            w = [0.0]
            for k in range(len(psi) - 1):
                w.append(w[-1] + 0.5 * (cur[k] + cur[k + 1]) * (psi[k + 1] - psi[k]))
            self._w = w
            self.beta = self.S = 0.0
        else:
            self.beta = float(beta)
            self.S = float(S)
            self._bS = self.beta ** self.S

    def knots(self):
        """
        Return a table curve's knots: (ψ, i_M, slopes, W_M at each knot), lists; None (a law).

        ψ and i_M start at the origin; a slope per segment (the last one holds beyond the last
        knot); W_M the exact integral up to each knot.
        """
        if self.table is None:
            return None
        psi, cur = self.table
        return psi, cur, self._slopes, self._w

    @property
    def beta_S(self) -> float:
        """Return β^S of the power law (0.0 for a table)."""
        return getattr(self, '_bS', 0.0)

    def current(self, psi: float) -> float:
        """Return i_M(ψ) [A] for ψ ≥ 0 [Wb]."""
        return psi * self.inv_L(psi)

    def inv_L(self, psi: float) -> float:
        """Return 1/L_M(ψ) = i_M(ψ)/ψ [1/H] (the slope at the origin for ψ = 0)."""
        if self.table is None:
            return (1.0 + (self.beta * psi) ** self.S) / self.L_M0
        ps, cur = self.table
        if psi <= 0.0:
            return self._slopes[0]
        k = min(bisect_right(ps, psi) - 1, len(self._slopes) - 1)
        return (cur[k] + self._slopes[k] * (psi - ps[k])) / psi

    def L_M(self, psi: float) -> float:
        """Return the secant magnetizing inductance ψ/i_M(ψ) [H]."""
        return 1.0 / self.inv_L(psi)

    def energy(self, psi: float) -> float:
        """Return the stored energy W_M(ψ) = ∫₀^ψ i_M dψ [J]."""
        if self.table is None:
            return (0.5 * psi * psi + self._bS * psi ** (self.S + 2.0) / (self.S + 2.0)) \
                / self.L_M0
        ps, cur = self.table
        k = min(bisect_right(ps, psi) - 1, len(self._slopes) - 1)
        d = psi - ps[k]
        return self._w[k] + cur[k] * d + 0.5 * self._slopes[k] * d * d

    def chord(self, psi0: float, psi1: float) -> float:
        """
        Return the energy chord of the curve between two flux magnitudes [1/H].

        (W_M(ψ₁) − W_M(ψ₀))/(½ψ₁² − ½ψ₀²): the constant m for which i_μ = m ψ stores
        exactly the curve's energy change between the two magnitudes (a discrete gradient);
        1/L_M at the middle when they nearly coincide (there the two agree to (ψ₁ − ψ₀)²,
        docs/plant.md §1).
        """
        d = psi1 - psi0
        if abs(d) <= 1e-6 * (psi0 + psi1) or psi0 + psi1 <= 0.0:
            return self.inv_L(0.5 * (psi0 + psi1))
        return (self.energy(psi1) - self.energy(psi0)) / (0.5 * d * (psi0 + psi1))

    def flux(self, i_M: float) -> float:
        """Return ψ with i_M(ψ) = i_M (the exact inverse, by bisection; for tests and fits)."""
        lo, hi = 0.0, max(1e-3, i_M * self.L_M0)
        while self.current(hi) < i_M:
            hi *= 2.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if self.current(mid) < i_M:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    def describe(self) -> dict:
        """Return the block as written in a motor file (the run record)."""
        if self.table is not None:
            return {'table': [[p, i] for p, i in zip(self.table[0][1:], self.table[1][1:])]}
        return {'law': 'power', 'beta': self.beta, 'S': self.S}


def saturation_block(spec, where: str = 'saturation') -> SaturationBlock:
    """
    Return the :class:`SaturationBlock` of a ``saturation:`` block; errors name the key.

    The forms of the module doc, ``table: [[psi, i_M], ...]`` (its errors name the row,
    ``saturation.table[1]``) or its columns ``table_psi``, ``table_i_M``.
    """
    if isinstance(spec, SaturationBlock):
        return spec
    check_block(spec, where, SATURATION_KEYS, SATURATION_SHAPE)
    if 'table' in spec:
        others = [k for k in spec if k != 'table']
        if others:
            raise InvalidParameter(f'{where}.table', '...', 'give either a table or a law'
                                   if others[0] in ('law', 'beta', 'S') else
                                   'give the table once: as table or as table_psi, table_i_M')
        rows = spec['table']
        if not isinstance(rows, (list, tuple)) or len(rows) < 2:
            raise InvalidParameter(f'{where}.table', rows, 'must list at least two [psi, i_M] '
                                                           'points')
        prev = (0.0, 0.0)
        for k, row in enumerate(rows):
            if not isinstance(row, (list, tuple)) or len(row) != 2:
                raise InvalidParameter(f'{where}.table[{k}]', row, 'must be [psi, i_M]')
            p = check_real(f'{where}.table[{k}]', row[0], 0.0, lo_open=True)
            i = check_real(f'{where}.table[{k}]', row[1], 0.0, lo_open=True)
            why = _table_error(p, i, prev)
            if why:
                raise InvalidParameter(f'{where}.table[{k}]', row, why)
            prev = (p, i)
        spec = {'table_psi': [float(r[0]) for r in rows], 'table_i_M': [float(r[1]) for r in rows]}
    return parse_block(SaturationBlock, spec, where)


def saturation_from_dict(spec: Mapping, L_M0: float, where: str = 'saturation') -> Saturation:
    """Return the :class:`Saturation` of a ``saturation:`` block; errors name the key."""
    return saturation_block(spec, where).curve(L_M0)


def power_law_fit(psi_rated: float, ratio: float, S: float) -> float:
    """
    Return β of L_M0/(1 + (βψ)^S) that puts L_M(ψ_rated)/L_M0 at ``ratio`` (e.g. 0.875).

    (β ψ_rated)^S = 1/ratio − 1: the rated flux is ``ratio`` of the flux L_M0 would give at the
    same magnetizing current (docs/plant.md §2, the shipped motors' fit).
    """
    return (1.0 / ratio - 1.0) ** (1.0 / S) / psi_rated


class SaturatedModel:
    """
    The drive's model on the magnetizing curve: the inverse-Γ set at the present rotor flux.

    In the inverse-Γ circuit only the magnetizing branch is nonlinear (docs/plant.md §2): i_μ =
    ψ_R/L_M(|ψ_R|) with the secant L_M. The linear model with L_M set to the secant at the
    present |ψ_R| therefore has exactly the saturated model's right-hand side at that flux, so
    an observer and a controller fed :meth:`estimates` each step (the adapter's interface,
    docs/adaptation.md §7) run on the curve (docs/plant.md §2, "The drive on the curve").

    ``params``: the drive's motor (its gauge θ = L_sr/L_r reads ψ_R = θ|φ̂_r| from the
    observer's rotor flux); ``resolution``: L_M moves in relative (logarithmic) steps of this
    size, so the models rebuild their coefficients only when the flux has moved (a relative
    error of half a step at most).
    """

    def __init__(self, curve: Saturation, params, resolution: float = 1e-4):
        self.curve = curve
        self.theta = params.L_sr / params.L_r
        ident = params.identifiable()
        self.L_M0 = ident['L_M']
        self.base = {'R_s': ident['R_s'], 'L_sigma': ident['L_sigma'], 'R_R': ident['R_R']}
        self.resolution = float(resolution)

    def L_M(self, phi_a: float, phi_b: float) -> float:
        """Return the secant L_M [H] at the rotor flux φ̂_r = (φ_a, φ_b) (the drive's gauge)."""
        psi = self.theta * math.hypot(phi_a, phi_b)
        ratio = self.curve.L_M(psi) / self.L_M0 if math.isfinite(psi) else 0.0
        if not ratio > 1e-6:
            raise ValueError(f"the observer's rotor flux |psi_R| = {psi:.4g} Wb is off the "
                             'magnetizing curve (L_M below 1e-6 L_M0): the run diverged')
        return self.L_M0 * math.exp(round(math.log(ratio) / self.resolution) * self.resolution)

    def estimates(self, phi_a: float, phi_b: float) -> dict:
        """Return the inverse-Γ set (R_s, L_sigma, L_M, R_R) at the rotor flux (φ_a, φ_b)."""
        return dict(self.base, L_M=self.L_M(phi_a, phi_b))


def saturated_model(block: Optional[SaturationBlock], params) -> Optional[SaturatedModel]:
    """Return the :class:`SaturatedModel` of ``params`` on a saturation block (None: none)."""
    return None if block is None else SaturatedModel(block.curve(params.L_M), params)
