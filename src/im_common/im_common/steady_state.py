"""
Closed forms for the induction motor: the phasor steady state of the equivalent circuit.

Pure helpers (numpy only) used by the physics tests and benchmarks to check the plant against a
formulation (phasors) that shares no code with :mod:`im_common.model`. The eq. 1.112 state
matrices live in the model (:func:`im_common.model.eq112_matrices`).

Phasor convention (power-invariant αβ, seed 000 eq. 1.111-1.113): a balanced sinusoidal supply is
the rotating vector ``V_αβ(t) = V_hat·e^{jω_e t}`` (α = real part, β = imaginary part), so
``V_hat`` equals the line-to-line RMS voltage. In steady state every electrical vector rotates
with it, ``x(t) = X·e^{jω_e t}``, and the stationary-frame equations

    dψ_s/dt = V_s − R_s i_s,        dφ_r/dt = −R_r i_r + j v ω_r φ_r
    ψ_s = L_s i_s + L_sr i_r,       φ_r = L_sr i_s + L_r i_r

become the equivalent circuit

    V_s = R_s I_s + jω_e Ψ_s,       0 = R_r I_r + j(ω_e − v ω_r) Φ_r.

The torque τ_m = v (L_sr/L_r)(i_sβ φ_rα − i_sα φ_rβ) (eq. 1.127) is
``v (L_sr/L_r) Im(conj(Φ_r)·I_s)``, constant in steady state, and equals the air-gap power over the
slip speed, ``v R_r |I_r|² / (ω_e − v ω_r)``. The input power V·i is ``Re(V_s conj(I_s))``,
also constant, and the stator power factor is ``P_in / (|V_s||I_s|)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PhasorSteadyState:
    """Steady state of the equivalent circuit (complex phasors at t = 0; SI units)."""

    V_s: complex
    I_s: complex
    I_r: complex
    Psi_s: complex
    Phi_r: complex
    omega_e: float
    omega_r: float
    tau_m: float
    tau_airgap: float
    P_in: float
    power_factor: float

    def state(self, t: float = 0.0):
        """Return the plant state ``[ψ_sα, ψ_sβ, φ_rα, φ_rβ]`` at time t."""
        rot = np.exp(1j * self.omega_e * t)
        psi, phi = self.Psi_s * rot, self.Phi_r * rot
        return [psi.real, psi.imag, phi.real, phi.imag]


def phasor_steady_state(R_s: float, R_r: float, L_s: float, L_r: float, L_sr: float,
                        pole_pairs: int, V_hat: complex, omega_e: float,
                        omega_r: float) -> PhasorSteadyState:
    """Solve the equivalent circuit for a supply ``V_hat·e^{jω_e t}`` at constant speed ω_r."""
    w_sl = omega_e - pole_pairs * omega_r
    M = np.array([[R_s + 1j * omega_e * L_s, 1j * omega_e * L_sr],
                  [1j * w_sl * L_sr, R_r + 1j * w_sl * L_r]], dtype=complex)
    I_s, I_r = np.linalg.solve(M, np.array([complex(V_hat), 0.0], dtype=complex))
    Psi_s = L_s * I_s + L_sr * I_r
    Phi_r = L_sr * I_s + L_r * I_r
    tau = pole_pairs * L_sr / L_r * float(np.imag(np.conj(Phi_r) * I_s))
    tau_ag = pole_pairs * R_r * abs(I_r) ** 2 / w_sl if w_sl != 0.0 else 0.0
    P_in = float(np.real(complex(V_hat) * np.conj(I_s)))
    pf = P_in / (abs(V_hat) * abs(I_s)) if I_s != 0 else 1.0
    return PhasorSteadyState(complex(V_hat), complex(I_s), complex(I_r), complex(Psi_s),
                             complex(Phi_r), float(omega_e), float(omega_r), tau, tau_ag, P_in, pf)


def params_steady_state(params, V_hat: complex, omega_e: float, omega_r: float
                        ) -> PhasorSteadyState:
    """:func:`phasor_steady_state` for a :class:`~im_common.params.MotorParams`."""
    return phasor_steady_state(params.R_s, params.R_r, params.L_s, params.L_r, params.L_sr,
                               params.pole_pairs, V_hat, omega_e, omega_r)


def zoh_gain(omega_e: float, T_s: float) -> float:
    """
    1/sinc(ω_e T_s/2): the gain that makes a zero-order-held sinusoid's fundamental exact.

    A staircase holding ``g·V_hat·e^{jω_e(t_k + T_s/2)}`` over each [t_k, t_k + T_s) has the
    fundamental ``g·sinc(ω_e T_s/2)·V_hat·e^{jω_e t}``, so with this g it is exactly the continuous
    phasor (the residue is at ω_e ± 2π/T_s and above).
    """
    x = 0.5 * omega_e * T_s
    return 1.0 if x == 0.0 else x / np.sin(x)


def zoh_sample_flux_offset(V_hat: complex, omega_e: float, T_s: float) -> complex:
    """
    Offset of ψ_s at the sampling instants t_k caused by the zero-order hold (leading order).

    With the hold of :func:`zoh_gain`, the held voltage minus the continuous one inside a step is,
    to first order in ω_e T_s, ``−jω_e V(t_mid)·(t − t_mid)`` (t_mid = t_k + T_s/2). Its zero-mean
    integral, the ψ_s ripple of the held plant around the continuous steady state, is
    ``−jω_e V·((t − t_mid)²/2 − T_s²/24)``, which at t = t_k equals ``−jω_e V(t_k)·T_s²/12``.
    The rotor flux barely moves within a step, so the stator current sampled at t_k is offset by
    this divided by σL_s. Returned as the phasor at t = 0 (multiply by e^{jω_e t_k}).
    """
    return -1j * omega_e * complex(V_hat) * T_s * T_s / 12.0
