"""
Speed-adaptive full-order observer.

The rotor flux *and* the shaft speed from the stator voltage and current only (speed-sensorless
mode; derivation and limits in docs/sensorless.md).

The flux part is :class:`im_observer.observer.RotorFluxObserver` (the plant copy of eq. 1.112 with
the current-error injections, the one home of those equations) driven by the *estimated* speed
ω̂ instead of a measured one. The speed follows from the current error e = i − î:

    ε = (e_α φ̂_β − e_β φ̂_α) / max(|φ̂|², φ_f²)          (the error along −𝒥φ̂, per unit flux²)
    ω̂ = k_p ε + k_i ∫ ε dt

ε is the measurable part of the Lyapunov derivative of the D-weighted estimation error: with
ω̃ = ω − ω̂ the current rows of the error system carry −v(L_sr/L_r) ω̃ 𝒥 φ̂, so a speed error
shows up as a current error perpendicular to φ̂; quasi-statically ε ≈ g ω̃ with
g = v K / (γ + k_e/σL_s) (:func:`error_gain`). The gains are chosen from a bandwidth α_ω of the
speed estimate: k_i = α_ω / g, k_p = 0 (:func:`adaptation_gains`). Normalizing by |φ̂|² makes the
loop's bandwidth independent of the flux level (min_energy's low flux); the floor φ_f keeps it
bounded while the machine is demagnetized (there the speed is unobservable: ε carries no speed).

Mechanical model (``mechanical_model``, default on; docs/sensorless.md §1): the estimated
air-gap torque τ̂ = v θ (i_β φ̂_α − i_α φ̂_β) accelerates the estimate through the model's J and b,
and the adaptation integrates the rest as a load estimate:

    dω̂/dt = k_i ε + (τ̂ − b ω̂ − τ̂_L)/J,      dτ̂_L/dt = −k_L ε,      k_L = β α_ω J / g

(β = ``load_bandwidth``): quasi-statically s² + α_ω s + α_ω β, so ω̂ follows an acceleration the
drive itself produces without lag, and a constant load without offset.

Flux-row gain (docs/sensorless.md §1): without it one real pole stays near −10 /s at every speed
(a speed error traded against a flux-angle error through the rotor time constant), so ω̂ lags
accelerations. The flux rows get dφ̂/dt += G(ω̂) e (complex), :meth:`flux_row_gain`, fitted to the
point-by-point optimum of :func:`linearized_poles` and faded out at low speed, where it would
destabilize regeneration.

Optional low-speed rotation of the error (``error_rotation`` η₀, default 0: off):

    ε = [e_⊥ − η(ω̂) e_∥] / max(|φ̂|², φ_f²),   e_⊥ = e_α φ̂_β − e_β φ̂_α,  e_∥ = e_α φ̂_α + e_β
    φ̂_β η(ω̂) = −η₀ sign(ω̂) max(0, 1 − |v ω̂|/ω_λ)

(without the flux-row gain η₀ = 0.3 reduced the regenerating-mode instability; with it, it does
not help).

Timing (lock-step): ``step`` takes V_k, i_k, computes ε_k from i_k − î_k, updates ω̂_k, and
advances the flux estimate over [t_k, t_k+1] at ω̂_k. ``omega_hat`` is then the speed the next
step's controller uses (estimated from data up to t_k), ``theta_hat`` = ∫ω̂ the shaft angle
integrated from it (a relative angle: the absolute one is unobservable).
"""
from __future__ import annotations

import math
from typing import Optional, Sequence

from im_common.model import eq112_coefficients
from im_common.params import check_real, InvalidParameter, MotorParams, THESIS_MOTOR
import numpy as np

from .observer import RotorFluxObserver

#: why a sensorless drive refuses the position task (one line, every place that refuses it)
POSITION_NEEDS_SENSOR = ('the position task needs the measured shaft position; a sensorless '
                         'drive runs the speed or torque task')
#: default bandwidth of the speed estimate [rad/s]: ~5× the speed task's loop (k_v/J ≈ 100 rad/s)
DEFAULT_SPEED_BANDWIDTH = 600.0
#: default floor of |φ̂| in the adaptation's normalization [Wb] (a quarter of the default phi_min)
DEFAULT_FLUX_FLOOR = 0.05
# : low-speed rotation of the adaptation error (η₀) and the electrical frequency where it ends
# [rad/s]
DEFAULT_ERROR_ROTATION = 0.0
#: flux-row gain (c₀, c₁ [rad/s], c₂ [rad/s]) and the electrical-speed band (w₀, w₁) [rad/s]
#: over which it fades in (SpeedAdaptiveObserver.flux_row_gain)
DEFAULT_FLUX_GAIN = (1.2, 200.0, 100.0)
DEFAULT_FLUX_GAIN_BAND = (10.0, 40.0)
DEFAULT_ROTATION_FREQUENCY = 200.0
#: bandwidth [rad/s] of the load-torque estimate of the mechanical model (mechanical_model)
DEFAULT_LOAD_BANDWIDTH = 50.0


def error_gain(params: MotorParams, k_e: Optional[float] = None) -> float:
    """Return g = ∂ε/∂ω̃ in the quasi-static limit: v K / (γ + k_e/σL_s)."""
    c = eq112_coefficients(params.R_s, params.R_r, params.L_s, params.L_r, params.L_sr)
    ke = 1.0 / params.sigma if k_e is None else k_e
    return params.pole_pairs * c.K / (c.gamma + ke * c.inv_sigma_Ls)


def adaptation_gains(params: MotorParams, bandwidth: float, k_e: Optional[float] = None):
    """
    (k_p, k_i) of the speed adaptation for a speed-estimate bandwidth α_ω [rad/s].

    With the current error's own lag, ε = g γ'/(s + γ') ω̃ (γ' = γ + k_e/σL_s), and k_p = 0,
    k_i = α_ω/g the loop's characteristic polynomial is s² + γ' s + γ' α_ω: poles ≈ −α_ω and
    −(γ' − α_ω), real for α_ω ≤ γ'/4. A proportional part would only speed up the fast pole
    (and feed the current noise straight into ω̂), so k_p = 0.
    """
    g = error_gain(params, k_e)
    return 0.0, bandwidth / g


class SpeedAdaptiveObserver:
    """Rotor flux and speed from V and i; see the module docstring."""

    def __init__(self, params: MotorParams = THESIS_MOTOR, k_e: Optional[float] = None,
                 max_substep: float = 1e-4, x0: Sequence[float] = (0.0, 0.0, 0.0, 0.0),
                 omega0: float = 0.0, theta0: float = 0.0,
                 speed_bandwidth: float = DEFAULT_SPEED_BANDWIDTH,
                 flux_floor: float = DEFAULT_FLUX_FLOOR,
                 flux_gain: Sequence[float] = DEFAULT_FLUX_GAIN,
                 flux_gain_band: Sequence[float] = DEFAULT_FLUX_GAIN_BAND,
                 error_rotation: float = DEFAULT_ERROR_ROTATION,
                 rotation_frequency: float = DEFAULT_ROTATION_FREQUENCY, injection_gain=None,
                 gain_period: Optional[float] = None, mechanical_model: bool = True,
                 load_bandwidth: float = DEFAULT_LOAD_BANDWIDTH, inverter_error=None):
        self.flux = RotorFluxObserver(params, k_e=k_e, max_substep=max_substep, x0=x0,
                                      injection_gain=injection_gain, gain_period=gain_period,
                                      inverter_error=inverter_error)
        self.params = params
        bw = check_real('speed_bandwidth', speed_bandwidth, 0.0, lo_open=True)
        self.speed_bandwidth = bw
        self.flux_floor = check_real('flux_floor', flux_floor, 0.0, lo_open=True)
        self.error_rotation_gain = check_real('error_rotation', error_rotation, 0.0)
        self.rotation_frequency = check_real('rotation_frequency', rotation_frequency, 0.0,
                                             lo_open=True)
        self.k_p, self.k_i = adaptation_gains(params, bw, self.flux.k_e)
        if len(flux_gain) != 3:
            raise InvalidParameter('flux_gain', flux_gain, 'must be (c0, c1, c2)')
        self.flux_gain = tuple(check_real('flux_gain', x) for x in flux_gain)
        if len(flux_gain_band) != 2:
            raise InvalidParameter('flux_gain_band', flux_gain_band, 'must be (w0, w1) in rad/s')
        w0, w1 = (check_real('flux_gain_band', x, 0.0) for x in flux_gain_band)
        if not w1 > w0:
            raise InvalidParameter('flux_gain_band', flux_gain_band, 'needs w1 > w0')
        self.flux_gain_band = (w0, w1)
        if not isinstance(mechanical_model, bool):
            raise InvalidParameter('mechanical_model', mechanical_model, 'must be true or false')
        self.mechanical_model = mechanical_model
        lb = check_real('load_bandwidth', load_bandwidth, 0.0)
        self.k_load = lb * bw * params.J / error_gain(params, self.flux.k_e)
        self.load_hat = 0.0
        self._integral = check_real('omega0', omega0)
        self.omega_hat = self._integral
        self.theta_hat = check_real('theta0', theta0)
        self.epsilon = 0.0

    @property
    def state(self):
        return self.flux.state

    @property
    def estimates(self) -> dict:
        return self.flux.estimates

    def set_estimates(self, **kw) -> None:
        """Adapted motor estimates (as :meth:`RotorFluxObserver.set_estimates`)."""
        self.flux.set_estimates(**kw)

    def speed_error_signal(self, i_alpha: float, i_beta: float) -> float:
        """ε of the measured current against the present estimate (see module docstring)."""
        ia, ib, pa, pb = self.flux.state
        ea, eb = i_alpha - ia, i_beta - ib
        f2 = pa * pa + pb * pb
        floor2 = self.flux_floor * self.flux_floor
        den = f2 if f2 > floor2 else floor2
        eta = self.error_rotation(self.omega_hat)
        return (ea * pb - eb * pa - eta * (ea * pa + eb * pb)) / den

    def step(self, T_s: float, v_alpha: float, v_beta: float, i_alpha: float, i_beta: float):
        """
        Advance from t_k to t_k + T_s with V_k, i_k; returns (î_α, î_β, φ̂_α, φ̂_β) at t_k+1.

        ``omega_hat`` / ``theta_hat`` are updated (ω̂_k, θ̂_k+1).
        """
        for name, val in (('i_alpha', i_alpha), ('i_beta', i_beta)):
            if not math.isfinite(val):
                raise ValueError(f"observer input '{name}' is not finite ({val!r})")
        eps = self.speed_error_signal(i_alpha, i_beta)
        self.epsilon = eps
        self._integral += self.k_i * T_s * eps
        if self.mechanical_model:
            # the estimated air-gap torque accelerates the estimate (J, b of the model; the load
            # is what the adaptation integrates): ω̂ no longer lags a known acceleration
            ia, ib, pa, pb = self.flux.state
            p = self.params
            tau = p.pole_pairs * self.flux.theta * (i_beta * pa - i_alpha * pb)
            self.load_hat -= self.k_load * T_s * eps
            self._integral += T_s * (tau - p.b * self._integral - self.load_hat) / p.J
        w = self._integral + self.k_p * eps
        self.omega_hat = w
        ia, ib, _, _ = self.flux.state
        ea, eb = i_alpha - ia, i_beta - ib
        state = self.flux.step(T_s, v_alpha, v_beta, i_alpha, i_beta, w)
        gr, gi = self.flux_row_gain(w)
        if gr != 0.0 or gi != 0.0:     # + T_s G e with the error held, like the other injections
            state = (state[0], state[1], state[2] + T_s * (gr * ea - gi * eb),
                     state[3] + T_s * (gr * eb + gi * ea))
            self.flux.state = state
        self.theta_hat += T_s * w
        return state

    def flux_row_gain(self, omega_hat: float):
        """
        Return the flux-row injection gain G.

        (Re G, Im G) [Ω] of the flux-row injection dφ̂/dt += G e (complex, e = e_α + j e_β):

            G = −(γ′/K) h [c₀ + (c₁ − j c₂ sign ω̂) / (v|ω̂|)],  h = clip((v|ω̂| − w₀)/(w₁ − w₀),
            0, 1)

        (docs/sensorless.md §3: fitted to the gains that minimize the slowest linearized pole
        point by point; zero below w₀ where it would destabilize low-speed regeneration).
        """
        c0, c1, c2 = self.flux_gain
        w0, w1 = self.flux_gain_band
        w_e = abs(self.flux.v * omega_hat)
        if w_e <= w0 or (c0 == 0.0 and c1 == 0.0 and c2 == 0.0):
            return 0.0, 0.0
        h = min(1.0, (w_e - w0) / (w1 - w0))
        c = self.flux.coefficients
        scale = (c.gamma + self.flux.k_e * c.inv_sigma_Ls) / c.K
        sgn = 1.0 if omega_hat >= 0.0 else -1.0
        return -scale * h * (c0 + c1 / w_e), scale * h * c2 * sgn / w_e

    def error_rotation(self, omega_hat: float) -> float:
        """η(ω̂) = −η₀ sign(ω̂) max(0, 1 − |v ω̂|/ω_λ) (module docstring)."""
        w_e = abs(self.params.pole_pairs * omega_hat)
        if self.error_rotation_gain <= 0.0 or w_e >= self.rotation_frequency:
            return 0.0
        sgn = 1.0 if omega_hat >= 0.0 else -1.0
        return -self.error_rotation_gain * sgn * (1.0 - w_e / self.rotation_frequency)


def operating_point(params: MotorParams, omega_r: float, torque: float, phi: float) -> dict:
    """
    Return the motor's steady state at speed ω_r, torque τ and rotor flux φ.

    Steady state of the motor at shaft speed ω_r, torque τ and rotor flux |φ_r| = φ, in the
    synchronous frame with φ_r on the d axis: currents, stator frequency ω_s = vω_r + ω_sl,
    voltage.
    """
    p = params
    k = p.L_sr / p.L_r
    i_d = phi / p.L_sr
    i_q = torque / (p.pole_pairs * k * phi)
    w_sl = p.R_r * k * i_q / phi
    w_s = p.pole_pairs * omega_r + w_sl
    sls = p.L_s - p.L_sr * k
    r_eq = p.R_s + p.R_r * k * k
    # 0 = V − R_eq i + (R_r L_sr/L_r²) φ − vω k 𝒥φ − ω_s σL_s 𝒥 i   (𝒥(a, b) = (−b, a))
    v_d = r_eq * i_d - p.R_r * k / p.L_r * phi - w_s * sls * i_q
    v_q = r_eq * i_q + p.pole_pairs * omega_r * k * phi + w_s * sls * i_d
    return {'i_d': i_d, 'i_q': i_q, 'phi': phi, 'omega_s': w_s, 'omega_sl': w_sl,
            'v_d': v_d, 'v_q': v_q}


def linearized_poles(observer: 'SpeedAdaptiveObserver', omega_r: float, torque: float,
                     phi: float, params: Optional[MotorParams] = None):
    """
    Return the poles of the observer and speed adaptation, linearized.

    Poles (numpy array) of the observer + speed adaptation linearized about the steady state (ω_r,
    τ, φ) of the motor ``params`` (default: the observer's own model), continuous time, in the
    synchronous frame. States (î_d, î_q, φ̂_d, φ̂_q, ∫): the true state is the equilibrium only
    when the models agree. Local stability ⇔ every real part < 0 (docs/sensorless.md §3).
    """
    obs = observer
    p = params if params is not None else obs.params
    op = operating_point(p, omega_r, torque, phi)
    w_s = op['omega_s']
    fo = obs.flux
    c = fo.coefficients
    vp = fo.v
    i_m = (op['i_d'], op['i_q'])
    V = (op['v_d'], op['v_q'])
    k_e = fo.k_e
    floor2 = obs.flux_floor ** 2

    def f(z):
        ia, ib, pa, pb, integ = z
        ea, eb = i_m[0] - ia, i_m[1] - ib
        f2 = max(pa * pa + pb * pb, floor2)
        eta = obs.error_rotation(integ)
        eps = (ea * pb - eb * pa - eta * (ea * pa + eb * pb)) / f2
        w = integ + obs.k_p * eps
        we = vp * w
        dia = (V[0] + k_e * ea) * c.inv_sigma_Ls - c.gamma * ia + c.K * c.inv_Tr * pa \
            + we * c.K * pb + w_s * ib
        dib = (V[1] + k_e * eb) * c.inv_sigma_Ls - c.gamma * ib + c.K * c.inv_Tr * pb \
            - we * c.K * pa - w_s * ia
        sk = we * c.L_sr if fo.skew_injection else 0.0
        gr, gi = obs.flux_row_gain(w)
        dpa = (-we * pb + c.L_sr * c.inv_Tr * ia - c.inv_Tr * pa - sk * eb + w_s * pb
               + gr * ea - gi * eb)
        dpb = (we * pa + c.L_sr * c.inv_Tr * ib - c.inv_Tr * pb + sk * ea - w_s * pa
               + gr * eb + gi * ea)
        return np.array([dia, dib, dpa, dpb, obs.k_i * eps])

    z0 = np.array([i_m[0], i_m[1], phi, 0.0, omega_r])
    jac = np.empty((5, 5))
    for j in range(5):
        h = 1e-6 * max(1.0, abs(z0[j]))
        zp, zm = z0.copy(), z0.copy()
        zp[j] += h
        zm[j] -= h
        jac[:, j] = (f(zp) - f(zm)) / (2.0 * h)
    return np.linalg.eigvals(jac)
