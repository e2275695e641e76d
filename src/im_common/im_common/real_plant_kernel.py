"""
The real plant's period, compiled: :meth:`im_common.real_plant.RealPlant._solve` in numba.

The exact interval solution of docs/plant.md §1 is scalar complex arithmetic, a few hundred
operations a period, which the interpreter spends most of the real plant's time on (§9, cost).
:func:`period` is the same arithmetic as the pure-Python path of ``_solve`` once its
predictions are made (the speed, the magnetizing slope and the iron loss's rotation offset
held over the period): the frozen system's eigenvalues, the switching intervals with the dead
bands resolved by the currents' signs at the period's start (``events``), the boundary
currents' sign check, the switching-loss tally and the closed-form energy integrals, in the same
order, operation by operation (complex products and quotients as CPython computes them, its
``cmath.sqrt`` algorithm), so the two agree to rounding (tests/test_real_plant_kernel.py: 1e-12).

The pure-Python path stays the reference: ``RealPlant.use_kernel`` (False: the reference) picks
it, and the kernel hands the rare periods back to it: repeated eigenvalues (status
:data:`FALLBACK`) and a current whose sign changes at an interval boundary (:data:`SIGN_CHANGE`:
the period again with explicit dead bands, :func:`im_common.inverter.period_plan`).

Without numba (:data:`available` False) the real plant runs the pure-Python path, and says so
once, at this module's import. ``cache=True``: the compiled code is kept beside this file (or
in ``NUMBA_CACHE_DIR``), so only a process's first call after an install compiles it.
"""
from __future__ import annotations

from cmath import exp as cexp
import logging
import math

import numpy as np

from .inverter import HALF_SQRT3, SQRT_2_3

try:
    from numba import njit
except ImportError:                             # pragma: no cover - numba is pinned
    njit = None

#: whether the compiled kernel exists (numba imports)
available = njit is not None
#: :func:`period`'s status: the period solved; the reference path must solve it
DONE, SIGN_CHANGE, FALLBACK = 0, 1, 2

SQRT3 = math.sqrt(3.0)                          # as im_common.params.SQRT3
TWO_PI = 2.0 * math.pi
DBL_MIN = 2.2250738585072014e-308

if not available:
    logging.getLogger(__name__).warning(
        'numba is not installed: the real plant runs its pure-Python period (docs/plant.md §9)')


def as_table(table):
    """Return a period's pole-vector table (unit, conj(unit), |unit|²) as three arrays."""
    return (np.array(table[0], dtype=np.complex128), np.array(table[1], dtype=np.complex128),
            np.array(table[2], dtype=np.float64))


def events_buffer():
    """Return the array :func:`events` writes a period's events into."""
    return np.empty((10, 2), dtype=np.float64)


def as_plan(plan):
    """Return a period's plan [(length, (s_a, s_b, s_c)), ...] as rows, nan for a dead band."""
    return np.array([(h, math.nan if a is None else a, math.nan if b is None else b,
                      math.nan if c is None else c) for h, (a, b, c) in plan], dtype=np.float64)


def as_events(events):
    """Return the period's events [(t, leg bit), ...] as one (n, 2) float64 array."""
    return np.array(events, dtype=np.float64)


def _csqrt(z):
    """Return cmath.sqrt(z) by CPython's algorithm (Modules/cmathmodule.c, finite z)."""
    if z.real == 0.0 and z.imag == 0.0:
        return complex(0.0, z.imag)
    ax = abs(z.real)
    ay = abs(z.imag)
    if ax < DBL_MIN and ay < DBL_MIN:           # hypot(ax, ay) subnormal: scaled up
        ax = math.ldexp(ax, 53)
        s = math.ldexp(math.sqrt(ax + math.hypot(ax, math.ldexp(ay, 53))), -27)
    else:
        ax /= 8.0
        s = 2.0 * math.sqrt(ax + math.hypot(ax, ay / 8.0))
    d = ay / (2.0 * s)
    if z.real >= 0.0:
        return complex(s, math.copysign(d, z.imag))
    return complex(d, math.copysign(s, z.imag))


def _edges(d, half, T_c, T_s, t_d):
    """Return :func:`im_common.inverter.edges` (t_on, t_on_end, t_off, t_off_end)."""
    big = 2.0 * T_s
    if d <= 0.0:
        return big, big, big, big
    if d >= 1.0:
        return -big, -big, big, big
    if T_s == T_c:
        t_on = 0.5 * (1.0 - d) * T_c
        t_off = 0.5 * (1.0 + d) * T_c
        return t_on, t_on + t_d, t_off, t_off + t_d
    if half == 0:
        t_on = 0.5 * (1.0 - d) * T_c
        return t_on, t_on + t_d, big, big
    t_off = 0.5 * d * T_c
    return -big, -big, t_off, t_off + t_d


def _events(ev, d0, d1, d2, half, T_c, T_s, t_d, c0, c1, c2, s0, s1, s2):
    """
    Write RealPlant._events's switching events into ``ev``'s rows (t, leg bit); return (n, code).

    The same instants, in the same order (sorted as the tuples (t, bit)), the last (T_s, 0):
    ``ev[:n]``. ``ev``: a (10, 2) float64 array (at most three a leg, and the period's end).
    """
    single = T_s == T_c
    code = 0
    n = 0
    for leg in range(3):
        bit = 1 << leg
        if leg == 0:
            dx, sg, c = d0, s0, c0
        elif leg == 1:
            dx, sg, c = d1, s1, c1
        else:
            dx, sg, c = d2, s2, c2
        if single and 0.0 < dx < 1.0:           # edges() of a single update, inline
            on0 = 0.5 * (1.0 - dx) * T_c
            on1 = 0.5 * (1.0 + dx) * T_c
            if sg > 0.0:
                on0 += t_d
            else:
                on1 += t_d
        else:
            t_on, t_on_end, t_off, t_off_end = _edges(dx, half, T_c, T_s, t_d)
            if sg > 0.0:
                on0, on1 = t_on_end, t_off
            else:
                on0, on1 = t_on, t_off_end
        if c > 0.0 and sg < 0.0 and on0 > 0.0:  # on until the lower device turns on
            code |= bit
            if on1 > on0 and on0 <= c:          # ... which it never does before the pulse
                c = on1 if on1 > c else c
                if c < T_s:
                    ev[n, 0] = c
                    ev[n, 1] = bit
                    n += 1
                continue
            ev[n, 0] = c
            ev[n, 1] = bit
            n += 1
        if on1 <= on0:
            continue                            # a pulse narrower than the dead time: none
        if on0 <= 0.0 < on1:
            code |= bit
        if 0.0 < on0 < T_s:
            ev[n, 0] = on0
            ev[n, 1] = bit
            n += 1
        if 0.0 < on1 < T_s:
            ev[n, 0] = on1
            ev[n, 1] = bit
            n += 1
    for j in range(1, n):                       # insertion sort by (t, bit), as list.sort
        t = ev[j, 0]
        b = ev[j, 1]
        k = j - 1
        while k >= 0 and (ev[k, 0] > t or (ev[k, 0] == t and ev[k, 1] > b)):
            ev[k + 1, 0] = ev[k, 0]
            ev[k + 1, 1] = ev[k, 1]
            k -= 1
        ev[k + 1, 0] = t
        ev[k + 1, 1] = b
    ev[n, 0] = T_s
    ev[n, 1] = 0.0
    return n + 1, code


def _integrals(a, z1, z2, z10, z20, b1, b2, l1, l2, g1, g2, s1, s2, c1, c2, U1, U2, B1, B2, Dd,
               R_s, R_R, r_on, m, kappa, vp, w_star, T, iron, k_h, k_e, w00, core_exp, p0, p1,
               p2):
    """
    Return the period's closed-form integrals (RealPlant._solve after its intervals).

    (ψ_s, ψ_R at the end, ∫τ, the mean rotation rate, ∫|i_s|², ∫|i_R|², E_in, E_core, E_inv,
    ∫u, and the end poles p0, p1, p2 passed through).
    """
    # the period's integrals in closed form (docs/plant.md §1): the modes' first moments
    # and, from d/dt (z_i conj z_j) integrated over the period, their second moments
    X1 = g1 * U2 + B1 / l1                      # Σ conj(u) ∫ z_i
    X2 = g2 * U2 + B2 / l2
    M11 = (z1.real * z1.real + z1.imag * z1.imag - z10.real * z10.real
           - z10.imag * z10.imag - 2.0 * (b1.real * X1.real + b1.imag * X1.imag)
           ) / (2.0 * l1.real)
    M22 = (z2.real * z2.real + z2.imag * z2.imag - z20.real * z20.real
           - z20.imag * z20.imag - 2.0 * (b2.real * X2.real + b2.imag * X2.imag)
           ) / (2.0 * l2.real)
    M12 = (z1 * z2.conjugate() - z10 * z20.conjugate() - b1 * X2.conjugate()
           - b2.conjugate() * X1) / (l1 + l2.conjugate())
    M21 = M12.conjugate()
    f1 = s1.conjugate()
    f2 = s2.conjugate()
    Is2 = ((f1 * s1).real * M11 + (f2 * s2).real * M22 + 2.0 * (s1 * f2 * M12).real)
    mu = complex(m, kappa / R_R)                # i_R = i_s − μ ψ_R
    q1 = s1 - mu * c1
    q2 = s2 - mu * c2
    Ir2 = ((q1 * q1.conjugate()).real * M11 + (q2 * q2.conjugate()).real * M22
           + 2.0 * (q1 * q2.conjugate() * M12).real)
    k1 = c1.conjugate()
    k2 = c2.conjugate()
    torque = vp * (k1 * q1 * M11 + k2 * q2 * M22 + k1 * q2 * M21 + k2 * q1 * M12).imag
    e_in = (s1 * X1 + s2 * X2).real - r_on * Is2
    ps1 = a * (z1 + z2)
    e_inv = r_on * Is2 + Dd.real                # ∫ conj(d) i_s
    e_core = 0.0
    w0bar = w00
    if iron or k_h != 0.0 or k_e != 0.0:
        P2 = (c1 * k1).real * M11 + (c2 * k2).real * M22 + 2.0 * (c1 * k2 * M12).real
        rot = R_R * torque / vp + vp * w_star * P2
        if P2 > 1e-18 * T:
            w0bar = rot / P2 + kappa            # the period's mean rotation rate without loss
        if iron:
            e_core = kappa * rot / R_R
        elif P2 > 1e-18 * T:                    # booked: (k_h + k_e f) f |ψ_R|^n
            f = abs(rot) / (TWO_PI * P2)
            e_core = (k_h + k_e * f) * f * (P2 if core_exp == 2.0 else math.sqrt(P2 * T))
    pr1 = c1 * z1 + c2 * z2
    return (ps1, pr1, torque, w0bar, Is2, Ir2, e_in, e_core, e_inv, U1, p0, p1, p2)


def _modes(ps, pr, R_s, R_R, L_sig, r_on, m, kappa, vp, w_star):
    """
    Return the modes of the period's frozen system (RealPlant._solve).

    (ok: False for repeated eigenvalues, a, l1, l2, c1, c2, b1, b2, g1, g2, s1, s2, and the
    modes z10, z20 at the start).
    """
    a = (R_s + r_on) / L_sig
    g = R_R * m
    w = vp * w_star - kappa
    tr = complex(-a - R_R / L_sig - g, w)
    det = a * complex(g, -w)
    disc = _csqrt(tr * tr - 4.0 * det)
    if tr.real * disc.real + tr.imag * disc.imag >= 0.0:
        l1 = 0.5 * (tr + disc)                  # the root of the larger magnitude
    else:
        l1 = 0.5 * (tr - disc)
    l2 = det / l1
    dl = l2 - l1
    if abs(dl) <= 1e-3 * abs(l1):               # (nearly) repeated eigenvalues: RK4 instead
        return (False, a, l1, l2, l1, l1, l1, l1, l1, l1, l1, l1, l1, l1)
    inv = 1.0 / (a * dl)
    c1 = a + l1                                 # ψ_R = c1 z1 + c2 z2, ψ_s = a (z1 + z2)
    c2 = a + l2
    b1 = c2 * inv                               # the input's modal components
    b2 = -c1 * inv
    g1 = -b1 / l1                               # the modes' steady state per volt
    g2 = -b2 / l2
    s1 = -l1 / L_sig                            # i_s = s1 z1 + s2 z2
    s2 = -l2 / L_sig
    z10 = (c2 * ps - a * pr) * inv
    z20 = (a * pr - c1 * ps) * inv
    return (True, a, l1, l2, c1, c2, b1, b2, g1, g2, s1, s2, z10, z20)


def _period(ps, pr, i_s, R_s, R_R, L_sig, r_on, m, kappa, vp, w_star, T, V, drop, code, ev,
            unit, unitc, norm2, check, sa, sb, sc, ksw, sw, iron, k_h, k_e, w00, core_exp):
    """
    Integrate one period exactly between its switching instants (RealPlant._solve, events).

    ``ps``, ``pr``: the fluxes ψ_s, ψ_R at the start, ``i_s`` the stator current; the circuit
    (R_s, R_R, L_σ, r_on), the magnetizing slope ``m``, the iron loss's offset ``kappa``, the
    pole pairs ``vp`` and the held speed ``w_star``; the pole vectors ``V·unit[code]`` minus the
    constant ``drop``, the events ``ev`` (rows t, leg bit; the last (T, 0)); the signs (sa, sb,
    sc) checked at each boundary if ``check``; ``ksw`` nonzero: the edges' |i_x| added to
    ``sw``. Return (status, end code, Σ|i_x|, lowest and highest i_sα, i_s, ψ_s, ψ_R at the end,
    ∫τ, the mean rotation rate, ∫|i_s|², ∫|i_R|², E_in, E_core, E_inv, ∫u).
    """
    ok, a, l1, l2, c1, c2, b1, b2, g1, g2, s1, s2, z10, z20 = _modes(
        ps, pr, R_s, R_R, L_sig, r_on, m, kappa, vp, w_star)
    if not ok:                                  # (nearly) repeated eigenvalues: RK4 instead
        return (FALLBACK, code, sw, 0.0, 0.0, 0j, 0j, 0j, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                0j, 0.0, 0.0, 0.0)
    lo = hi = i_s.real
    # resolved dead bands, constant drop: Σ conj(u) a = V Σ conj(û) a − conj(d) Δz; the loop
    # runs on w_i = z_i/g_i (w_i → u in steady state)
    B1 = B2 = SU = 0j
    SU2 = 0.0
    w1 = z10 / g1
    w2 = z20 / g2
    t1 = s1 * g1                                # i_s = t1 w1 + t2 w2
    t2 = s2 * g2
    tp = 0.0
    i = i_s
    for k in range(ev.shape[0]):
        t_ev = ev[k, 0]
        bit = int(ev[k, 1])
        h = t_ev - tp
        if h > 1e-15:
            u = V * unit[code] - drop
            a1 = (w1 - u) * (cexp(l1 * h) - 1.0)
            a2 = (w2 - u) * (cexp(l2 * h) - 1.0)
            w1 += a1
            w2 += a2
            n2 = norm2[code]
            if n2 != 0.0:
                uc = unitc[code]
                B1 += uc * a1
                B2 += uc * a2
                SU += unit[code] * h
                SU2 += n2 * h
            i = t1 * w1 + t2 * w2
            ir = i.real
            if check:
                ii = SQRT3 * i.imag
                if ir * sa <= 0.0 or (ii - ir) * sb <= 0.0 or (-ii - ir) * sc <= 0.0:
                    return (SIGN_CHANGE, code, sw, lo, hi, i, 0j, 0j, 0.0, 0.0, 0.0, 0.0, 0.0,
                            0.0, 0.0, 0j, 0.0, 0.0, 0.0)
            if ir < lo:
                lo = ir
            elif ir > hi:
                hi = ir
            tp = t_ev
        if ksw != 0.0 and bit != 0:             # the edge at t_ev, with the current there
            ka = SQRT_2_3 * i.real              # im_common.inverter.phase_values
            if bit == 1:
                sw += abs(ka)
            else:
                kb = SQRT_2_3 * HALF_SQRT3 * i.imag
                if bit == 2:
                    sw += abs(-0.5 * ka + kb)
                else:
                    sw += abs(-0.5 * ka - kb)
        code ^= bit
    z1 = w1 * g1
    z2 = w2 * g2
    B1 *= g1
    B2 *= g2
    dc = drop.conjugate()
    U1 = V * SU - drop * T
    U2 = V * V * SU2 - 2.0 * V * (dc * SU).real + (drop * dc).real * T
    B1 = V * B1 - dc * (z1 - z10)
    B2 = V * B2 - dc * (z2 - z20)
    ps1 = a * (z1 + z2)
    Dd = dc * (U1 - ps1 + ps) / (R_s + r_on)    # ∫ i_s = (∫ u − Δψ_s)/(R_s + r_on)
    return (DONE, code, sw, lo, hi, i) + _integrals(
        a, z1, z2, z10, z20, b1, b2, l1, l2, g1, g2, s1, s2, c1, c2, U1, U2, B1, B2, Dd, R_s,
        R_R, r_on, m, kappa, vp, w_star, T, iron, k_h, k_e, w00, core_exp, 0.0, 0.0, 0.0)


def _clarke(x_a, x_b, x_c):
    """Return :func:`im_common.params.clarke` as a complex number."""
    return complex(SQRT_2_3 * (x_a - 0.5 * x_b - 0.5 * x_c), SQRT_2_3 * 0.5 * SQRT3 * (x_b - x_c))


def _diode(q):
    """Return the pole state a dead band takes by its current's sign q (real_plant._DIODE)."""
    return 0.0 if q == 1.0 else (1.0 if q == -1.0 else 0.5)


def _explicit(ps, pr, i_s, R_s, R_R, L_sig, r_on, m, kappa, vp, w_star, T, V, v_on, pl, ksw,
              has_poles, p0, p1, p2, iron, k_h, k_e, w00, core_exp):
    """
    Integrate one period with explicit dead bands (RealPlant._solve, ``plan``).

    ``pl``: the plan's rows (length, s_a, s_b, s_c), nan for a dead band (it takes its leg's
    current's sign at its start, as the drops ``v_on`` do at each interval's start); (p0, p1,
    p2): the poles at the start if ``has_poles``. Return :func:`_period`'s tuple, the code -1
    and the poles at the end last.
    """
    ok, a, l1, l2, c1, c2, b1, b2, g1, g2, s1, s2, z10, z20 = _modes(
        ps, pr, R_s, R_R, L_sig, r_on, m, kappa, vp, w_star)
    if not ok:                                  # (nearly) repeated eigenvalues: RK4 instead
        return (FALLBACK, -1, 0.0, 0.0, 0.0, 0j, 0j, 0j, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                0j, 0.0, 0.0, 0.0)
    z1 = z10
    z2 = z20
    lo = hi = i_s.real
    B1 = B2 = U1 = Dd = 0j
    U2 = 0.0
    i = i_s
    sw = 0.0
    for k in range(pl.shape[0]):
        h = pl[k, 0]
        ir = i.real
        ii = SQRT3 * i.imag
        ib = ii - ir
        ic = -ii - ir
        q0 = 1.0 if ir > 0.0 else (-1.0 if ir < 0.0 else 0.0)
        q1 = 1.0 if ib > 0.0 else (-1.0 if ib < 0.0 else 0.0)
        q2 = 1.0 if ic > 0.0 else (-1.0 if ic < 0.0 else 0.0)
        x0 = pl[k, 1]
        x1 = pl[k, 2]
        x2 = pl[k, 3]
        if math.isnan(x0):
            x0 = _diode(q0)
        if math.isnan(x1):
            x1 = _diode(q1)
        if math.isnan(x2):
            x2 = _diode(q2)
        if ksw != 0.0 and has_poles and not (p0 == x0 and p1 == x1 and p2 == x2):
            ka = SQRT_2_3 * i.real              # real_plant._edge_currents
            kb = SQRT_2_3 * HALF_SQRT3 * i.imag
            sw += (abs(x0 - p0) * abs(ka) + abs(x1 - p1) * abs(-0.5 * ka + kb)
                   + abs(x2 - p2) * abs(-0.5 * ka - kb))
        p0 = x0
        p1 = x1
        p2 = x2
        has_poles = True
        dk = v_on * _clarke(q0, q1, q2) if v_on > 0.0 else 0j
        u = V * _clarke(x0, x1, x2) - dk
        a1 = (z1 - g1 * u) * (cexp(l1 * h) - 1.0)
        a2 = (z2 - g2 * u) * (cexp(l2 * h) - 1.0)
        uc = u.conjugate()
        B1 += uc * a1
        B2 += uc * a2
        U1 += u * h
        U2 += (u * uc).real * h
        if dk != 0j:
            Dd += dk.conjugate() * (s1 * (g1 * u * h + a1 / l1)
                                    + s2 * (g2 * u * h + a2 / l2))
        z1 += a1
        z2 += a2
        i = s1 * z1 + s2 * z2
        ir = i.real
        if ir < lo:
            lo = ir
        elif ir > hi:
            hi = ir
    return (DONE, -1, sw, lo, hi, i) + _integrals(
        a, z1, z2, z10, z20, b1, b2, l1, l2, g1, g2, s1, s2, c1, c2, U1, U2, B1, B2, Dd, R_s,
        R_R, r_on, m, kappa, vp, w_star, T, iron, k_h, k_e, w00, core_exp, p0, p1, p2)


_warm = []


def warm() -> None:
    """
    Compile the kernels (or load them from the cache) now, once a process.

    :class:`im_common.real_plant.RealPlant` calls it when built, so the compilation (about 2.5 s
    the first time after an install, 0.3 s from the cache) comes before a run's first step, not
    within it (a lock-step partner's input watchdog, im_common.lockstep_parts). The arguments'
    types are those of RealPlant's calls: one compiled signature each.
    """
    if _warm or not available:
        return
    ev = events_buffer()
    n, code = events(ev, 0.5, 0.25, 0.75, 0, 1e-4, 1e-4, 2e-6, 0.0, 0.0, 0.0, 1.0, -1.0, 1.0)
    unit, unitc, norm2 = as_table(((1 + 0j,), (1 - 0j,), (1.0,)))
    period(0.1 + 0j, 0.1 + 0j, 1 + 0j, 1.0, 1.0, 0.01, 0.0, 10.0, 0.0, 2.0, 0.0, 1e-4, 1.0, 0j,
           code, ev[:n], unit, unitc, norm2, True, 1.0, 1.0, 1.0, 0.0, 0.0, False, 0.0, 0.0,
           0.0, 2.0)
    explicit(0.1 + 0j, 0.1 + 0j, 1 + 0j, 1.0, 1.0, 0.01, 0.0, 10.0, 0.0, 2.0, 0.0, 1e-4, 1.0,
             1.0, as_plan([(1e-4, (0, None, 1))]), 0.0, False, 0.0, 0.0, 0.0, False, 0.0, 0.0,
             0.0, 2.0)
    _warm.append(True)


if available:
    _csqrt = njit(cache=True)(_csqrt)
    _edges = njit(cache=True)(_edges)
    _modes = njit(cache=True)(_modes)
    _integrals = njit(cache=True)(_integrals)
    _clarke = njit(cache=True)(_clarke)
    _diode = njit(cache=True)(_diode)
    events = njit(cache=True)(_events)
    period = njit(cache=True)(_period)
    explicit = njit(cache=True)(_explicit)
else:                                           # pragma: no cover - numba is pinned
    events = period = explicit = None
