"""
Full-order nonlinear observer of stator currents and rotor fluxes (seed 000 eq. 3.27-3.28, 4.13).

Plant, electrical part (eq. 1.112 / the first four rows of eq. 1.126), x = (i_s, φ_r) in αβ; the
coefficients come from :func:`im_common.model.eq112_coefficients`, the one home of the model:

    σL_s di/dt = V − R_eq i + (R_r L_sr/L_r²) φ − v ω (L_sr/L_r) 𝒥 φ
         dφ/dt = v ω 𝒥 φ + R_r (L_sr/L_r) i − (R_r/L_r) φ,          𝒥 = [[0, −1], [1, 0]]

with R_eq = R_s + R_r (L_sr/L_r)². In the D-weighted form D ẋ + A(ω) x = M V,
D = diag(σL_s I, I/L_r), the symmetric part of A(ω) is R_αβ + (vωL_sr/2L_r)[[0, 𝒥], [−𝒥, 0]]:
the speed coupling v ω (L_sr/L_r) 𝒥 appears in the current rows only, so it is *not*
skew-symmetric (the skew 𝒞_αβ of eq. 1.126 is skew only together with the mechanical row).

Observer (eq. 3.27): a copy of the plant driven by the measured current error e_i = i − î,

    σL_s dî/dt = V − R_eq î + (R_r L_sr/L_r²) φ̂ − v ω (L_sr/L_r) 𝒥 φ̂ + k_e e_i
         dφ̂/dt = v ω 𝒥 φ̂ + R_r (L_sr/L_r) î − (R_r/L_r) φ̂ + v ω L_sr 𝒥 e_i

The first injection is the thesis's F = diag(K_e, 0), K_e = k_e I (default k_e = 1/σ, §3.4.6).
The second injects the current error into the flux rows with exactly the gain that makes the
error matrix skew apart from R_αβ + F: with x̄ = x − x̂,

    D dx̄/dt + [𝒞̃(ω) + R_αβ + F] x̄ = 0,  𝒞̃(ω) = (vω/L_r)[[0, L_sr 𝒥], [L_sr 𝒥, −𝒥]] = −𝒞̃ᵀ
    (eq. 3.28)

so V = ½ x̄ᵀ D x̄ obeys dV/dt = −x̄ᵀ (R_αβ + F) x̄ < 0 for every speed. Without the second
injection (``skew_injection=False``, the literal F of the thesis) the error still converges in
practice but V is not monotone at speed (see docs/controller.md and the tests).

Estimates (eq. 4.13): ``set_estimates(R_r, theta)`` replaces R̂_r and θ̂ = L̂_sr/L̂_r (L̂_r =
L̂_sr/θ̂, L̂_s, L̂_sr, R̂_s fixed); ``set_estimates(L_M=..., R_R=..., L_sigma=...[, R_s=...])``
replaces the inverse-Γ parameters, so every coefficient follows the identified motor
(docs/adaptation.md §7).

Sampling: each ``step`` integrates [t_k, t_k + T_s] with V held (ZOH) and the measured current and
speed held at their t_k values, by classical RK4 in sub-steps of at most ``max_substep``.

Discrete-time gain (``injection_gain`` L, 4×2, row-major, designed for period ``gain_period``):
x̂_{k+1} = A_d x̂_k + B_d V_k + L (i_k − î_k), with A_d, B_d the ZOH discretization of the plant
copy (no continuous injection) at the measured speed, evaluated by the same RK4 sub-steps (which
reproduces exp(A T_s) to RK4 accuracy).

Everything is scalar Python (no numpy): this runs once per control period.
"""
from __future__ import annotations

import math
from typing import Optional, Sequence, Tuple

from im_common.model import eq112_coefficients
from im_common.params import (check_real, IDENTIFIABLE_NAMES, InvalidParameter, MotorParams,
                              THESIS_MOTOR)


_finite = check_real


class RotorFluxObserver:
    """Observer of (i_α, i_β, φ_α, φ_β); see the module docstring for the equations."""

    def __init__(self, params: MotorParams = THESIS_MOTOR, k_e: Optional[float] = None,
                 max_substep: float = 1e-4, x0: Sequence[float] = (0.0, 0.0, 0.0, 0.0),
                 injection_gain=None, gain_period: Optional[float] = None,
                 skew_injection: bool = True, inverter_error=None):
        if not isinstance(params, MotorParams):
            raise InvalidParameter('params', params, 'must be a MotorParams')
        self.params = params
        # the inverter's voltage error (im_common.compensation): the motor got the command less
        # ê(i); None: the command as given
        self.inverter_error = inverter_error
        if k_e is None:
            k_e = 1.0 / params.sigma
        self.k_e = _finite('k_e', k_e)
        if self.k_e < 0.0:
            raise InvalidParameter('k_e', k_e, 'must be >= 0 (F + R_ab > 0 needs K_e >= 0)')
        ms = _finite('max_substep', max_substep)
        if ms <= 0.0:
            raise InvalidParameter('max_substep', max_substep, 'must be > 0 s')
        self.max_substep = ms
        if len(x0) != 4:
            raise InvalidParameter('x0', x0,
                                   'must have 4 elements (i_alpha, i_beta, phi_alpha, phi_beta)')
        self.state: Tuple[float, float, float, float] = tuple(_finite('x0', v) for v in x0)
        self.skew_injection = bool(skew_injection)
        self.L = None
        self.gain_period = None
        if injection_gain is not None:
            if not isinstance(injection_gain[0], (int, float)):
                rows = [list(r) for r in injection_gain]
            else:
                rows = [list(injection_gain[2 * i:2 * i + 2])
                        for i in range(len(injection_gain) // 2)]
            if len(rows) != 4 or any(len(r) != 2 for r in rows):
                raise InvalidParameter('injection_gain', injection_gain,
                                       'must be 4x2 (a list of 4 rows '
                                       'of 2, or 8 numbers row-major)')
            self.L = tuple(tuple(_finite('injection_gain', v) for v in r) for r in rows)
            gp = _finite('gain_period', gain_period) if gain_period is not None else None
            if gp is None or gp <= 0.0:
                raise InvalidParameter('gain_period', gain_period,
                                       'a discrete injection_gain needs the '
                                       'period it was designed for (> 0 s)')
            self.gain_period = gp
        self.R_s = params.R_s
        self.L_s = params.L_s
        self.L_sr = params.L_sr
        self.v = params.pole_pairs
        self._R_r = params.R_r
        self._theta = params.theta
        self._update()

    # ------------------------------------------------------------------------------------------
    def _update(self) -> None:
        th = self._theta
        L_r = self.L_sr / th
        if not self.L_s - self.L_sr * th > 0.0:
            raise InvalidParameter('theta', th, 'estimate makes sigma*L_s = L_s - L_sr*theta <= 0')
        self.L_r = L_r
        # the plant copy: eq. 1.112 at the estimates, from the model (the one home of the
        # equations)
        self._c = eq112_coefficients(self.R_s, self._R_r, self.L_s, L_r, self.L_sr)
        self._inv_sLs = self._c.inv_sigma_Ls

    @property
    def estimates(self) -> dict:
        return {'R_r': self._R_r, 'theta': self._theta}

    @property
    def theta(self) -> float:
        """Return the estimate θ̂ = L_sr/L_r the observer runs with."""
        return self._theta

    @property
    def coefficients(self):
        """Return the eq. 1.112 coefficients of the observer's plant copy (at the estimates)."""
        return self._c

    def set_estimates(self, R_r: Optional[float] = None, theta: Optional[float] = None,
                      **identifiable) -> None:
        """
        Use adapted estimates from now on.

        Use adapted estimates from now on, in one of two parametrizations:

        * ``R_r`` and/or ``theta`` = L̂_sr/L̂_r (eq. 4.13; L̂_s, L̂_sr, R̂_s fixed);
        * the inverse-Γ set ``L_M``, ``R_R``, ``L_sigma`` (and optionally ``R_s``): every
          coefficient follows them, in the rotor gauge of the nominal model (θ = L_sr/L_r of
          ``params``, :meth:`MotorParams.with_identifiable`; docs/adaptation.md §7).
        Errors (InvalidParameter) name the estimate.
        """
        if identifiable:
            unknown = set(identifiable) - set(IDENTIFIABLE_NAMES)
            if unknown:
                raise InvalidParameter(sorted(unknown)[0], identifiable[sorted(unknown)[0]],
                                       'is not an estimate (R_r, theta or R_s, L_sigma, L_M, '
                                       'R_R)')
            if R_r is not None or theta is not None:
                raise InvalidParameter('R_r' if R_r is not None else 'theta',
                                       R_r if R_r is not None else theta,
                                       'give either R_r/theta or the inverse-Gamma estimates '
                                       '(L_M, R_R, L_sigma), not both')
            p = self.params.with_identifiable(**{k: _finite(k, v) for k, v in identifiable.items()
                                                 if v is not None})
            self.R_s, self.L_s, self.L_sr = p.R_s, p.L_s, p.L_sr
            self._R_r, self._theta = p.R_r, p.theta
            self._update()
            return
        if R_r is not None:
            r = _finite('R_r', R_r)
            if r <= 0.0:
                raise InvalidParameter('R_r', R_r, 'estimate must be > 0 ohm')
            self._R_r = r
        if theta is not None:
            t = _finite('theta', theta)
            if t <= 0.0:
                raise InvalidParameter('theta', theta, 'estimate must be > 0')
            if self.L_s - self.L_sr * t <= 0.0:
                raise InvalidParameter('theta', theta,
                                       f'estimate must be below L_s/L_sr '
                                       f'= {self.L_s / self.L_sr:.6g}')
            self._theta = t
        self._update()

    def lyapunov(self, i_alpha: float, i_beta: float, phi_alpha: float, phi_beta: float) -> float:
        """V = ½ x̄ᵀ D x̄ of the estimation error against a given true state (eq. 3.28)."""
        ia, ib, pa, pb = self.state
        ea, eb, fa, fb = i_alpha - ia, i_beta - ib, phi_alpha - pa, phi_beta - pb
        return 0.5 * ((ea * ea + eb * eb) / self._inv_sLs + (fa * fa + fb * fb) / self.L_r)

    def reset(self, x0: Sequence[float] = (0.0, 0.0, 0.0, 0.0)) -> None:
        self.state = tuple(_finite('x0', v) for v in x0)

    # ------------------------------------------------------------------------------------------
    def step(self, T_s: float, v_alpha: float, v_beta: float, i_alpha: float, i_beta: float,
             omega_r: float) -> Tuple[float, float, float, float]:
        """
        Advance the estimate from t_k to t_k + T_s.

        Returns (î_α, î_β, φ̂_α, φ̂_β) at t_k + T_s.
        """
        if not (T_s > 0.0 and math.isfinite(T_s)):
            raise InvalidParameter('T_s', T_s, 'must be a positive, finite period in seconds')
        for name, val in (('v_alpha', v_alpha), ('v_beta', v_beta), ('i_alpha', i_alpha),
                          ('i_beta', i_beta), ('omega_r', omega_r)):
            if not math.isfinite(val):
                raise ValueError(f"observer input '{name}' is not finite ({val!r})")
        if self.inverter_error is not None:     # the voltage the motor actually got
            v_alpha, v_beta = self.inverter_error.motor_voltage(v_alpha, v_beta, i_alpha, i_beta)
        discrete = self.L is not None
        if discrete and abs(T_s - self.gain_period) > 1e-9 * self.gain_period:
            raise ValueError(f'injection_gain was designed for '
                             f'gain_period = {self.gain_period!r} s '
                             f'but step() was called with T_s = {T_s!r} s')
        n = int(math.ceil(T_s / self.max_substep - 1e-9))
        if n < 1:
            n = 1
        h = T_s / n
        c = self._c
        inv_sLs, inv_Tr = c.inv_sigma_Ls, c.inv_Tr
        R_th = c.L_sr * inv_Tr              # L_sr/T_r, flux rows' coefficient on î
        w = self.v * omega_r
        if discrete:
            k_e = 0.0
            w_Lsr = 0.0
        else:
            k_e = self.k_e
            w_Lsr = w * self.L_sr if self.skew_injection else 0.0
        ia, ib, pa, pb = self.state
        # Injection of the current error sampled at t_k and held over the period: the error
        # varies slowly (rate ~(R_eq + k_e)/σL_s) while the current itself rotates at the
        # stator frequency, so holding the *error* (not the measurement) keeps the held-input
        # perturbation small (see docs/controller.md, "sampling the injection").
        e_a0, e_b0 = i_alpha - ia, i_beta - ib
        ca = (v_alpha + k_e * e_a0) * inv_sLs
        cb = (v_beta + k_e * e_b0) * inv_sLs
        a_i = -c.gamma                      # di/dt coefficient on î
        a_p = c.K * inv_Tr                  # on φ̂
        a_w = w * c.K                       # on 𝒥-rotated φ̂ (with sign below)
        # flux rows: dφ̂ = w𝒥φ̂ + R_th î − φ̂/T_r + w L_sr 𝒥 e
        da_c = -w_Lsr * e_b0
        db_c = w_Lsr * e_a0

        def f(ia, ib, pa, pb):
            return (ca + a_i * ia + a_p * pa + a_w * pb,
                    cb + a_i * ib + a_p * pb - a_w * pa,
                    da_c - w * pb + R_th * ia - inv_Tr * pa,
                    db_c + w * pa + R_th * ib - inv_Tr * pb)

        h2 = 0.5 * h
        h6 = h / 6.0
        for _ in range(n):
            k1 = f(ia, ib, pa, pb)
            k2 = f(ia + h2 * k1[0], ib + h2 * k1[1], pa + h2 * k1[2], pb + h2 * k1[3])
            k3 = f(ia + h2 * k2[0], ib + h2 * k2[1], pa + h2 * k2[2], pb + h2 * k2[3])
            k4 = f(ia + h * k3[0], ib + h * k3[1], pa + h * k3[2], pb + h * k3[3])
            ia += h6 * (k1[0] + 2.0 * (k2[0] + k3[0]) + k4[0])
            ib += h6 * (k1[1] + 2.0 * (k2[1] + k3[1]) + k4[1])
            pa += h6 * (k1[2] + 2.0 * (k2[2] + k3[2]) + k4[2])
            pb += h6 * (k1[3] + 2.0 * (k2[3] + k3[3]) + k4[3])
        if discrete:
            L = self.L
            ia += L[0][0] * e_a0 + L[0][1] * e_b0
            ib += L[1][0] * e_a0 + L[1][1] * e_b0
            pa += L[2][0] * e_a0 + L[2][1] * e_b0
            pb += L[3][0] * e_a0 + L[3][1] * e_b0
        if not (math.isfinite(ia) and math.isfinite(ib)
                and math.isfinite(pa) and math.isfinite(pb)):
            raise FloatingPointError('observer state became non-finite')
        self.state = (ia, ib, pa, pb)
        return self.state
