"""
The real plant's period, compiled: :meth:`im_plant.real_plant.RealPlant._solve` in numba.

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

:func:`step` is the whole period in one call, where RealPlant can give it everything (a constant
parameter schedule and a load of :mod:`im_common.loads` it knows): the duties and the carry, the
events or the explicit plan (compiled too, :func:`_plan`), the predictions (the saturation
curve's chord, the iron loss's rotation offset, the load torque), :func:`period` or
:func:`explicit`, the shaft, the switching losses, the temperatures, the DC link, the encoder,
the ADC measurement and the state's currents, on one float64 array (the layout below) that
holds the constants and the state between periods: the interpreter touches Python objects once
a period. It hands a period back (:data:`FALLBACK`, :data:`NONFINITE`: the array untouched) for
the reference to take; the sign changes it solves itself, by the explicit plan.

Without numba (:data:`available` False) the real plant runs the pure-Python path, and says so
once, at this module's import. ``cache=True``: the compiled code is kept beside this file (or
in ``NUMBA_CACHE_DIR``), so only a process's first call after an install compiles it.
"""
from __future__ import annotations

from cmath import exp as cexp
import logging
import math

from im_common.inverter import HALF_SQRT3, SQRT_2_3
import numpy as np

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
    # resolved dead bands, constant drop: Σ conj(u) a = V Σ conj(û) a − conj(d) Δz; the loop
    # runs on w_i = z_i/g_i (w_i → u in steady state)
    status, code, sw, lo, hi, i, w1, w2, B1, B2, SU, SU2 = _resolved_loop(
        z10 / g1, z20 / g2, s1 * g1, s2 * g2, l1, l2, i_s, V, drop, code, ev, unit, unitc,
        norm2, check, sa, sb, sc, ksw, sw)
    if status == SIGN_CHANGE:
        return (SIGN_CHANGE, code, sw, lo, hi, i, 0j, 0j, 0.0, 0.0, 0.0, 0.0, 0.0,
                0.0, 0.0, 0j, 0.0, 0.0, 0.0)
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


def _resolved_loop(w1, w2, t1, t2, l1, l2, i_s, V, drop, code, ev, unit, unitc, norm2, check,
                   sa, sb, sc, ksw, sw):
    """
    Run :func:`_period`'s intervals on w_i = z_i/g_i (i_s = t1 w1 + t2 w2) between the events.

    Return (DONE or SIGN_CHANGE: a current's sign other than (sa, sb, sc) at a boundary, the
    code at the end, Σ|i_x| at the edges, lowest and highest i_sα, i_s, w1, w2, Σ conj(û) a_1,
    Σ conj(û) a_2, Σ û h, Σ |û|² h).
    """
    lo = hi = i_s.real
    B1 = B2 = SU = 0j
    SU2 = 0.0
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
                    return SIGN_CHANGE, code, sw, lo, hi, i, w1, w2, B1, B2, SU, SU2
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
    return DONE, code, sw, lo, hi, i, w1, w2, B1, B2, SU, SU2


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


# The whole period in one call (:func:`step`) -----------------------------------------------
#: the layout of the one float64 array :func:`step` reads and writes (RealPlant._whole): the
#: constants (set when the array is packed), the state carried from period to period, the
#: period's outputs (one contiguous run, read with one ``tolist``) and the path counters
(T_S, N_SUB, HAS_INV, T_C, T_D, V_ON, R_ON, DOUBLE, K_EDGE, V_DC, C_DC, R_SOURCE, V_CHOP, R_CHOP,
 V_TRIP, VP, J_IN, B_F, K_H, K_E, IRON, LOCKED, CORE_EXP, R_S0, R_R0, TH, L_SIG, INV_LM0, SAT,
 BETA, S_EXP, B_S, L_M0, N_SAT, THERM, T_AMB, R_TH_S, R_TH_R, DEC_S, DEC_R, ALPHA_S, ALPHA_R,
 T_REF, SENS, ENC, CPR, WIN, SCALE, BITS, I_RANGE, G_A, G_B, G_C, O_A, O_B, O_C, VDC_RANGE, LOAD,
 LP0, LP1, LP2, N_LOAD, I_TRIP, W_TRIP,
 PREV, PREV_T, PREV_TT, PREV_R0, PREV_TAU0, PREV_W00, PREV_TQ, PREV_W0BAR, CARRY_A, CARRY_B,
 CARRY_C, POLES, POLE_A, POLE_B, POLE_C, END_A, END_B, END_C, EDGES, E_SRC, E_CH, P_INV, E_SWT,
 P_SWT, RIPPLE, TEMP_S, TEMP_R, END_VALID, OMEGA_MEAS, N_EV, N_SIGN, N_EXPL,
 X0) = range(97)
#: the outputs from X0 on: the state, the mean voltage, i_s at the end (the exact solution's),
#: the state's currents (RealPlant.state_currents), the measurement, V_dc and R's factors
(V_APP, I_END, I_STATE, MEAS, V_LINK, F_S, F_R, HIST_N, HIST) = (
    X0 + 14, X0 + 16, X0 + 18, X0 + 22, X0 + 27, X0 + 28, X0 + 29, X0 + 30, X0 + 31)
#: the outputs' length from X0 (RealPlant reads w[X0:X0 + N_OUT])
N_OUT = V_LINK + 3 - X0
#: the loads :func:`step` evaluates itself (im_common.loads), by kind
LOAD_NONE, LOAD_CONSTANT, LOAD_LINEAR, LOAD_PENDULUM, LOAD_STEP, LOAD_SCHEDULE = range(6)
#: :func:`step`'s status bits beside DONE: the DC link over its trip voltage, a protection limit
#: (near: PlantSimulator.protect decides), and the hand-backs (nothing committed)
TRIP_DC, PROTECT, NONFINITE = 4, 8, 16


def _clarke_pair(x_a, x_b, x_c):
    """Return :func:`im_common.params.clarke` (the same operations)."""
    k = SQRT_2_3
    return k * (x_a - 0.5 * x_b - 0.5 * x_c), k * 0.5 * SQRT3 * (x_b - x_c)


def _unit_table():
    """Return real_plant._UNIT as three arrays (the switch-state bit mask → clarke(s))."""
    unit = np.empty(8, dtype=np.complex128)
    for c in range(8):
        a, b = _clarke_pair(c & 1, (c >> 1) & 1, (c >> 2) & 1)
        unit[c] = complex(a, b)
    return unit, unit.conjugate(), np.array([(u * u.conjugate()).real for u in unit])


_UNIT_U, _UNIT_C, _UNIT_N = _unit_table()


def _bisect_right(w, tab, at, n, x):
    """Return bisect.bisect_right(tab[at:at + n], x)."""
    lo = 0
    hi = n
    while lo < hi:
        mid = (lo + hi) // 2
        if x < tab[at + mid]:
            hi = mid
        else:
            lo = mid + 1
    return lo


def _inv_L(w, tab, psi):
    """Return Saturation.inv_L(psi) (w[SAT]: 1 the power law, 2 the table)."""
    if w[SAT] == 1.0:
        return (1.0 + (w[BETA] * psi) ** w[S_EXP]) / w[L_M0]
    n = int(w[N_SAT])
    if psi <= 0.0:
        return tab[2 * n]
    k = min(_bisect_right(w, tab, 0, n, psi) - 1, n - 2)
    return (tab[n + k] + tab[2 * n + k] * (psi - tab[k])) / psi


def _energy(w, tab, psi):
    """Return Saturation.energy(psi)."""
    if w[SAT] == 1.0:
        S = w[S_EXP]
        return (0.5 * psi * psi + w[B_S] * psi ** (S + 2.0) / (S + 2.0)) / w[L_M0]
    n = int(w[N_SAT])
    k = min(_bisect_right(w, tab, 0, n, psi) - 1, n - 2)
    d = psi - tab[k]
    return tab[3 * n + k] + tab[n + k] * d + 0.5 * tab[2 * n + k] * d * d


def _chord(w, tab, psi0, psi1):
    """Return Saturation.chord(psi0, psi1)."""
    d = psi1 - psi0
    if abs(d) <= 1e-6 * (psi0 + psi1) or psi0 + psi1 <= 0.0:
        return _inv_L(w, tab, 0.5 * (psi0 + psi1))
    return (_energy(w, tab, psi1) - _energy(w, tab, psi0)) / (0.5 * d * (psi0 + psi1))


def _iron_rotation(w0, R_R, k_h, k_e):
    """Return im_common.model.iron_rotation (max(0, y) as Python's: y only if y > 0)."""
    c = TWO_PI * TWO_PI
    y = (c * abs(w0) - TWO_PI * R_R * k_h) / (c + R_R * k_e)
    return math.copysign(y if y > 0.0 else 0.0, w0)


def _load(w, tab, t, theta, omega, offset):
    """Return the plant's load torque (im_common.loads, by kind; the live offset added)."""
    kind = w[LOAD]
    if kind == LOAD_NONE:
        tau = 0.0
    elif kind == LOAD_CONSTANT:
        tau = w[LP0]
    elif kind == LOAD_LINEAR:
        tau = w[LP0] + w[LP1] * omega
    elif kind == LOAD_PENDULUM:
        tau = w[LP0] * math.cos(theta)
    elif kind == LOAD_STEP:
        tau = w[LP1] if t >= w[LP0] else w[LP2]
    else:
        n = int(w[N_LOAD])
        at = 4 * int(w[N_SAT])
        i = _bisect_right(w, tab, at, n, t) - 1
        if i < 0:
            tau = tab[at + n]
        elif i >= n - 1:
            tau = tab[at + 2 * n - 1]
        else:
            t0 = tab[at + i]
            a = tab[at + n + i]
            b = tab[at + n + i + 1]
            tau = a + (b - a) * (t - t0) / (tab[at + i + 1] - t0)
    if offset != 0.0:
        return tau + offset
    return tau


def _duties(v_a, v_b, V_dc):
    """Return im_common.inverter.duties's duties (the same operations)."""
    a = SQRT_2_3 * v_a
    kb = SQRT_2_3 * HALF_SQRT3 * v_b
    b = -0.5 * a + kb
    c = -0.5 * a - kb
    hi = a
    if b > hi:
        hi = b
    if c > hi:
        hi = c
    lo = a
    if b < lo:
        lo = b
    if c < lo:
        lo = c
    spread = hi - lo
    scale = 1.0
    if spread > V_dc:
        scale = V_dc / spread
    v0 = -0.5 * (hi + lo)
    k = scale / V_dc
    return 0.5 + (a + v0) * k, 0.5 + (b + v0) * k, 0.5 + (c + v0) * k


def _carry_after(d, half, T_c, T_s, t_d):
    """Return im_common.inverter.carry_after."""
    if t_d <= 0.0 or d <= 0.0:
        return 0.0
    if d >= 1.0 or (T_s != T_c and half == 0):
        return t_d
    t_off_end = _edges(d, half, T_c, T_s, t_d)[3]
    return t_off_end - T_s if t_off_end > T_s else 0.0


def _plan(pl, d0, d1, d2, half, T_c, T_s, t_d, extra, c0, c1, c2):
    """
    Write the period's plan with explicit dead bands into ``pl``; return its number of rows.

    im_common.inverter.period_plan without signs, the same instants and states.

    Rows (length, s_a, s_b, s_c), nan for a dead band; ``extra`` an added cut if > 0.
    """
    legs = np.empty((3, 5))
    cuts = np.empty(20)
    cuts[0] = 0.0
    cuts[1] = T_s
    n = 2
    if 0.0 < extra < T_s:
        cuts[n] = extra
        n += 1
    for j in range(3):
        dx = d0 if j == 0 else (d1 if j == 1 else d2)
        c = c0 if j == 0 else (c1 if j == 1 else c2)
        t_on, t_on_end, t_off, t_off_end = _edges(dx, half, T_c, T_s, t_d)
        c_end = min(c, t_on, T_s) if t_on > 0.0 else 0.0
        legs[j, 0] = t_on
        legs[j, 1] = t_on_end
        legs[j, 2] = t_off
        legs[j, 3] = t_off_end
        legs[j, 4] = c_end
        for q in range(5):
            t = legs[j, q]
            if 0.0 < t < T_s:
                cuts[n] = t
                n += 1
    ts = np.sort(cuts[:n])
    rows = 0
    prev = ts[0]
    for q in range(1, n):
        t1 = ts[q]
        if t1 == prev:
            continue                            # a set: each instant once
        t0 = prev
        prev = t1
        if t1 - t0 <= 1e-15:
            continue
        tm = 0.5 * (t0 + t1)
        pl[rows, 0] = t1 - t0
        for j in range(3):
            t_on = legs[j, 0]
            if legs[j, 1] <= tm < legs[j, 2]:
                s = 1.0
            elif tm < legs[j, 4]:
                s = math.nan                    # the lower device still waiting
            elif t_on <= tm < legs[j, 3]:
                s = math.nan
            else:
                s = 0.0
            pl[rows, j + 1] = s
        rows += 1
    return rows


def _sgn(x):
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


def _adc(x, lo, hi, bits):
    """Return Sensors.adc (round half to even, as Python's round)."""
    if bits <= 0:
        return x
    n = float(1 << bits)
    lsb = (hi - lo) / n
    code = np.rint((x - lo) / lsb)
    if code < 0.0:
        code = 0.0
    elif code >= n:
        code = n - 1.0
    return lo + code * lsb


def _step(w, tab, v_a, v_b, k, tripped, offset):
    """
    Integrate one period of the real plant and its blocks (RealPlant.advance, compiled).

    ``w``: the array of the layout above (constants, the state carried between periods, the
    outputs); ``tab``: the saturation table's columns and a schedule load's points; the
    admitted command (v_a, v_b), the period's index ``k``, ``tripped`` (the stator shorted) and
    the load's live offset. RealPlant._integrate, _solve, _finish, advance and _after_period,
    the measurement, the state's currents, the protection's limits: by stage, each a helper
    compiled into this one (``inline='always'``: ~3 % of the period inside numba, ~0 % of a
    call from Python, 1.6 µs with every block on; plain ``njit`` calls cost ~40 %). Return DONE
    (with the bits TRIP_DC, PROTECT) after committing the period to ``w``, or FALLBACK /
    NONFINITE with ``w`` untouched: the reference path takes the period (repeated eigenvalues,
    a non-finite state).
    """
    T_s = w[T_S]
    has_inv = w[HAS_INV] != 0.0
    fs, fr = w[F_S], w[F_R]
    R_s = w[R_S0] * fs
    R_R = w[R_R0] * fr
    V = w[V_LINK]
    x = w[X0:X0 + 14].copy()
    prevs = (w[PREV] != 0.0, w[PREV_T], w[PREV_TT], w[PREV_R0], w[PREV_TAU0], w[PREV_W00],
             w[PREV_TQ], w[PREV_W0BAR])
    carry = (w[CARRY_A], w[CARRY_B], w[CARRY_C])
    carries = carry
    poles = (w[POLES] != 0.0, w[POLE_A], w[POLE_B], w[POLE_C])
    ev = np.empty((10, 2))
    pl = np.empty((24, 4))
    ripple = w[RIPPLE]
    n_ev = n_sign = n_expl = 0
    i_end = 0j
    ends = (0.0, 0.0, 0.0)
    edges = va_avg = vb_avg = 0.0
    n_sub = int(w[N_SUB]) if not has_inv else 1
    T = T_s / n_sub if not has_inv else T_s
    for j in range(n_sub):
        ts = k * T_s + j * T if not has_inv else k * T_s
        plan = _step_plan(w, ev, pl, x[0], x[1], x[2], x[3], k, T, v_a, v_b, tripped, carry,
                          carries)
        carries = plan[15:18]
        pred = _step_predict(w, tab, x[0], x[1], x[2], x[3], x[4], x[5], ts, T, R_R, prevs,
                             offset)
        r = _step_intervals(w, ev, pl, v_a, v_b, tripped, plan, pred, carry, poles, R_s, R_R, T)
        if r[0] != DONE:
            return FALLBACK
        n_ev += r[1]
        n_sign += r[2]
        n_expl += r[3]
        ends = r[4:7]
        edges, lo, hi, i_end = r[7:11]
        _step_finish(w, x, T, R_s, R_R, pred, r)
        prevs = (True, ts + T, T, pred[3], pred[6], pred[7], r[13] / T, r[14])
        if has_inv:
            ripple = SQRT_2_3 * (hi - lo)
        va_avg = r[20].real / T
        vb_avg = r[20].imag / T
    if not has_inv:
        va_avg = 0.0 if tripped else v_a
        vb_avg = 0.0 if tripped else v_b
    total = 0.0
    for q in range(14):
        total += x[q]
    if not math.isfinite(total):
        return NONFINITE
    x0 = w[X0:X0 + 14]                          # a view: the state committed below
    if w[K_EDGE] != 0.0:                        # RealPlant.advance: the switching losses
        x[13] += _step_switching(w, V, edges, T_s)
        poles = (True, ends[0], ends[1], ends[2])
    # RealPlant._after_period: the temperatures, the DC link, the encoder
    fs, fr = _step_thermal(w, x[7] - x0[7], x[9] - x0[9], x[8] - x0[8], T_s, fs, fr)
    out = DONE
    if has_inv:
        V, out = _step_dc_link(w, x[13] - x0[13], x[6] - x0[6], V, tripped, T_s)
    omega_meas = _step_encoder(w, x[4])
    _step_commit(w, x, prevs, carries, poles, ends, edges, ripple, (n_ev, n_sign, n_expl),
                 va_avg, vb_avg, i_end, V, fs, fr)
    _step_state_currents(w, tab, x[0], x[1], x[2], x[3], x[5], fr)
    _step_measure(w, x[4], x[5], i_end, V, omega_meas, has_inv)
    return _step_near_limit(w, x[5], i_end, tripped, out)


def _step_plan(w, ev, pl, x_0, x_1, x_2, x_3, k, T, v_a, v_b, tripped, carry, carries):
    """
    Make a sub-period's plan for :func:`_step` (RealPlant._integrate; x_0..x_3: the fluxes).

    The duties and the dead bands' carry into the next period, then the events with the dead
    bands resolved by the currents' signs (``ev``), or explicit dead bands (``pl``), or the
    held command's one interval (no inverter). Return (code, events, plan rows, check, replan,
    the signs, the drop, the half period, the duties, the extra cut, the pole voltage, the
    carries after); ``carry``: the carries into this period, ``carries`` the last.
    """
    c0, c1, c2 = carry
    nc0, nc1, nc2 = carries
    has_inv = w[HAS_INV] != 0.0
    T_s = w[T_S]
    T_c = w[T_C]
    t_d = w[T_D]
    v_on = w[V_ON]
    th = w[TH]
    L_sig = w[L_SIG]
    code = 0
    n_e = 0
    n_p = 0
    check = False
    replan = False
    sa = 0.0
    sb = 0.0
    sc = 0.0
    drop = 0j
    half = 0
    d0 = d1 = d2 = 0.0
    extra = 0.5 * T_c if v_on > 0.0 and w[DOUBLE] == 0.0 else -1.0
    if not has_inv:
        ev[0, 0] = T
        ev[0, 1] = 0.0
        n_e = 1
        Vk = 1.0
    else:
        Vk = w[V_LINK]
        if tripped:                             # every lower device on: the stator shorted
            nc0 = nc1 = nc2 = 0.0
            pl[0, 0] = T_s
            pl[0, 1] = 0.0
            pl[0, 2] = 0.0
            pl[0, 3] = 0.0
            n_p = 1
        else:
            d0, d1, d2 = _duties(v_a, v_b, Vk)
            if w[DOUBLE] != 0.0:
                half = k % 2
            if t_d > 0.0:
                nc0 = _carry_after(d0, half, T_c, T_s, t_d)
                nc1 = _carry_after(d1, half, T_c, T_s, t_d)
                nc2 = _carry_after(d2, half, T_c, T_s, t_d)
            if t_d > 0.0 or v_on > 0.0:
                if w[END_VALID] != 0.0:
                    i_sa = w[I_END]
                    i_sb = w[I_END + 1]
                else:
                    i_sa = (x_0 - th * x_2) / L_sig
                    i_sb = (x_1 - th * x_3) / L_sig
                i_sb *= SQRT3
                sa = _sgn(i_sa)
                sb = _sgn(i_sb - i_sa)
                sc = _sgn(-i_sb - i_sa)
                if sa != 0.0 and sb != 0.0 and sc != 0.0:
                    n_e, code = _events_k(ev, d0, d1, d2, half, T_c, T_s, t_d, c0, c1, c2, sa,
                                          sb, sc)
                    da, db = _clarke_pair(sa, sb, sc)
                    drop = complex(da, db) * v_on
                    check = True
                    replan = True
                else:
                    n_p = _plan(pl, d0, d1, d2, half, T_c, T_s, t_d, extra, c0, c1, c2)
            else:
                n_e, code = _events_k(ev, d0, d1, d2, half, T_c, T_s, t_d, c0, c1, c2, 1.0,
                                      1.0, 1.0)
    return (code, n_e, n_p, check, replan, sa, sb, sc, drop, half, d0, d1, d2, extra, Vk, nc0,
            nc1, nc2)


def _step_predict(w, tab, x_0, x_1, x_2, x_3, x_4, x_5, ts, T, R_R, prevs, offset):
    """
    Return a sub-period's predictions for :func:`_step` (RealPlant._solve; x_0..x_5: the state).

    From the start and the previous period (``prevs``: the flag, its end, length, |ψ_R|, τ₀,
    ω₀₀, mean torque and rotation rate): (ψ_s, ψ_R, i_s, |ψ_R|, ω, θ, τ₀, ω₀₀ at the
    start, the saturation curve's chord m, the iron loss's rotation offset κ, the held speed
    ω* and the load torque at the middle).
    """
    prev, p_t, p_T, p_r0, p_tau0, p_w00, p_tq, p_w0bar = prevs
    th = w[TH]
    L_sig = w[L_SIG]
    vp = w[VP]
    ps = complex(x_0, x_1)
    pr = complex(th * x_2, th * x_3)
    i_s = (ps - pr) / L_sig
    r0 = abs(pr)
    omega = x_5
    theta = x_4
    cross = pr.real * i_s.imag - pr.imag * i_s.real
    tau0 = vp * cross
    w00 = 0.0
    if r0 > 1e-9:
        w00 = R_R * cross / (r0 * r0) + vp * omega
    if prev and abs(p_t - ts) <= 1e-9 * T and p_T == T:
        r1 = 2.0 * r0 - p_r0
        if r1 < 0.0:
            r1 = 0.0
        w0m = p_w0bar + w00 - p_w00
        tau_hat = p_tq + tau0 - p_tau0
    else:
        r1 = r0
        w0m = w00
        tau_hat = tau0
    m = w[INV_LM0] if w[SAT] == 0.0 else _chord(w, tab, r0, r1)
    kappa = 0.0
    if w[IRON] != 0.0 and r0 > 1e-9:
        kappa = w0m - _iron_rotation(w0m, R_R, w[K_H], w[K_E])
    if w[LOCKED] != 0.0:
        w_star = 0.0
        tl = 0.0
    else:
        b_f = w[B_F]
        k2 = 0.5 * T / w[J_IN]
        w_star = (omega + k2 * (tau_hat - _load(w, tab, ts, theta, omega, offset))) / (
            1.0 + k2 * b_f)
        tl = _load(w, tab, ts + 0.5 * T, theta + 0.5 * T * w_star, w_star, offset)
    return ps, pr, i_s, r0, omega, theta, tau0, w00, m, kappa, w_star, tl


def _step_intervals(w, ev, pl, v_a, v_b, tripped, plan, pred, carry, poles, R_s, R_R, T):
    """
    Integrate a sub-period's intervals for :func:`_step`: :func:`period` or :func:`explicit`.

    ``plan``, ``pred``: :func:`_step_plan`'s and :func:`_step_predict`'s tuples; no inverter:
    the held command's one-vector table (``unit``). The events first (a sign change at a
    boundary: the explicit plan instead, if ``replan``), the switching losses' edge currents at
    the start (``poles``: has_poles and the poles at the start). Return (status, the three path
    counters' increments, the end poles, Σ|i_x|, lowest and highest i_sα, i_s, ψ_s, ψ_R at the
    end, ∫τ, the mean rotation rate, ∫|i_s|², ∫|i_R|², E_in, E_core, E_inv, ∫u).
    """
    has_inv = w[HAS_INV] != 0.0
    ksw = w[K_EDGE]
    r_on = w[R_ON]
    L_sig = w[L_SIG]
    vp = w[VP]
    iron = w[IRON] != 0.0
    k_h = w[K_H]
    k_e = w[K_E]
    core_exp = w[CORE_EXP]
    code, n_e, n_p, check, replan, sa, sb, sc, drop, half, d0, d1, d2, extra, Vk = plan[:15]
    ps, pr, i_s, _, _, _, _, w00, m, kappa, w_star, _ = pred
    c0, c1, c2 = carry
    has_poles, q0, q1, q2 = poles
    n_ev = n_sign = n_expl = 0
    status = FALLBACK
    e0 = e1 = e2 = edges = lo = hi = torque = w0bar = Is2 = Ir2 = e_in = e_core = e_inv = 0.0
    i_end = ps1 = pr1 = U1 = 0j
    if n_e > 0:
        sw = 0.0
        if ksw != 0.0 and has_poles:            # real_plant._edge_currents at the start
            b0 = float(code & 1)
            b1 = float((code >> 1) & 1)
            b2 = float((code >> 2) & 1)
            if not (q0 == b0 and q1 == b1 and q2 == b2):
                ka = SQRT_2_3 * i_s.real
                kb = SQRT_2_3 * HALF_SQRT3 * i_s.imag
                sw = (abs(b0 - q0) * abs(ka) + abs(b1 - q1) * abs(-0.5 * ka + kb)
                      + abs(b2 - q2) * abs(-0.5 * ka - kb))
        if has_inv:
            r = _period_k(ps, pr, i_s, R_s, R_R, L_sig, r_on, m, kappa, vp, w_star, T, Vk, drop,
                          code, ev[:n_e], _UNIT_U, _UNIT_C, _UNIT_N, check, sa, sb, sc, ksw, sw,
                          iron, k_h, k_e, w00, core_exp)
        else:                                   # the held command's one-vector table
            unit = np.empty(1, dtype=np.complex128)
            unit[0] = 0j if tripped else complex(v_a, v_b)
            u0 = unit[0]
            norm2 = np.empty(1)
            norm2[0] = u0.real * u0.real + u0.imag * u0.imag
            r = _period_k(ps, pr, i_s, R_s, R_R, L_sig, r_on, m, kappa, vp, w_star, T, Vk, drop,
                          code, ev[:n_e], unit, unit.conjugate(), norm2, check, sa, sb, sc, ksw,
                          sw, iron, k_h, k_e, w00, core_exp)
        status = r[0]
        if status == DONE:
            n_ev += 1
            e0 = float(r[1] & 1)
            e1 = float((r[1] >> 1) & 1)
            e2 = float((r[1] >> 2) & 1)
            (edges, lo, hi, i_end, ps1, pr1, torque, w0bar, Is2, Ir2, e_in, e_core, e_inv,
             U1) = r[2:16]
        elif status == SIGN_CHANGE and replan:
            n_sign += 1
            n_p = _plan(pl, d0, d1, d2, half, w[T_C], w[T_S], w[T_D], extra, c0, c1, c2)
    if n_p > 0:
        q = _explicit_k(ps, pr, i_s, R_s, R_R, L_sig, r_on, m, kappa, vp, w_star, T, Vk,
                        w[V_ON], pl[:n_p], ksw, has_poles, q0, q1, q2, iron, k_h, k_e, w00,
                        core_exp)
        status = q[0]
        if status == DONE:
            n_expl += 1
            e0 = q[16]
            e1 = q[17]
            e2 = q[18]
            (edges, lo, hi, i_end, ps1, pr1, torque, w0bar, Is2, Ir2, e_in, e_core, e_inv,
             U1) = q[2:16]
    return (status, n_ev, n_sign, n_expl, e0, e1, e2, edges, lo, hi, i_end, ps1, pr1, torque,
            w0bar, Is2, Ir2, e_in, e_core, e_inv, U1)


def _step_finish(w, x, T, R_s, R_R, pred, r):
    """
    Advance the shaft and write the sub-period's end into ``x`` (RealPlant._finish).

    ``pred``, ``r``: :func:`_step_predict`'s and :func:`_step_intervals`'s tuples.
    """
    _, _, _, _, omega, theta, _, _, _, _, w_star, tl = pred
    ps1, pr1, torque = r[11:14]
    Is2, Ir2, e_in, e_core, e_inv = r[15:20]
    if w[LOCKED] != 0.0:
        omega1 = omega
        theta1 = theta
        e_fric = 0.0
        w_load = 0.0
    else:
        b_f = w[B_F]
        omega1 = omega + (torque - T * (b_f * w_star + tl)) / w[J_IN]
        theta1 = theta + 0.5 * T * (omega + omega1)
        e_fric = T * b_f * w_star * w_star
        w_load = T * tl * w_star
    th = w[TH]
    x[6] = x[6] + e_in
    x[7] = x[7] + R_s * Is2
    x[8] = x[8] + R_R * Ir2
    x[9] = x[9] + e_core
    x[10] = x[10] + e_fric
    x[11] = x[11] + w_load
    x[13] = x[13] + e_inv
    x[0] = ps1.real
    x[1] = ps1.imag
    x[2] = pr1.real / th
    x[3] = pr1.imag / th
    x[4] = theta1
    x[5] = omega1


def _step_switching(w, V, edges, T_s):
    """Book the period's switching losses (RealPlant.advance) into ``w``; return the energy."""
    e_sw = w[K_EDGE] * V * edges
    w[E_SWT] += e_sw
    w[P_SWT] = e_sw / T_s
    return e_sw


def _step_thermal(w, d_cu_s, d_core, d_cu_r, T_s, fs, fr):
    """
    Advance the temperatures (RealPlant._after_period); return R_s's and R_R's factors.

    The period's stator copper, core and rotor copper energies: ``d_cu_s``, ``d_core``,
    ``d_cu_r``.
    """
    if w[THERM] != 0.0:
        p_s = d_cu_s
        if w[IRON] != 0.0:
            p_s += d_core
        p_r = d_cu_r / T_s
        d_s = w[DEC_S]
        d_r = w[DEC_R]
        T_amb = w[T_AMB]
        T_st = T_amb + (w[TEMP_S] - T_amb) * d_s + w[R_TH_S] * (p_s / T_s) * (1.0 - d_s)
        T_rt = T_amb + (w[TEMP_R] - T_amb) * d_r + w[R_TH_R] * p_r * (1.0 - d_r)
        w[TEMP_S] = T_st
        w[TEMP_R] = T_rt
        fs = 1.0 + w[ALPHA_S] * (T_st - w[T_REF])
        fr = 1.0 + w[ALPHA_R] * (T_rt - w[T_REF])
    return fs, fr


def _step_dc_link(w, e_inv, d_in, V, tripped, T_s):
    """
    Advance the DC link, its source and chopper (RealPlant._after_period).

    ``e_inv``, ``d_in``: the period's inverter loss and input energy. Return (V_dc at the end,
    DONE or TRIP_DC: over the trip voltage while not tripped).
    """
    out = DONE
    w[P_INV] = e_inv / T_s
    e_dc = d_in + e_inv
    C_dc = w[C_DC]
    if C_dc > 0:
        V_dc = w[V_DC]
        e_src = (V_dc - V) / w[R_SOURCE] * V * T_s if V < V_dc else 0.0
        e_ch = (V * V / w[R_CHOP] * T_s if w[V_CHOP] > 0 and V > w[V_CHOP] else 0.0)
        w[E_SRC] += e_src
        w[E_CH] += e_ch
        we = 0.5 * C_dc * V * V + e_src - e_ch - e_dc
        V = math.sqrt(2.0 * we / C_dc) if we > 0.0 else 0.0
        if not tripped and V > w[V_TRIP]:
            out |= TRIP_DC
    else:
        w[E_SRC] += e_dc
    return V, out


def _step_encoder(w, theta):
    """Return the measured speed: SpeedFromCounts.update(Sensors.count(θ)) with an encoder."""
    omega_meas = w[OMEGA_MEAS]
    if w[ENC] != 0.0:
        cpr = w[CPR]
        count = math.floor(theta * cpr / TWO_PI)
        n = int(w[HIST_N])
        if n < int(w[WIN]) + 1:
            w[HIST + n] = count
            n += 1
            w[HIST_N] = n
        else:
            for q in range(n - 1):
                w[HIST + q] = w[HIST + q + 1]
            w[HIST + n - 1] = count
        omega_meas = (count - w[HIST]) * w[SCALE] / (n - 1)
        w[OMEGA_MEAS] = omega_meas
    return omega_meas


def _step_commit(w, x, prevs, carries, poles, ends, edges, ripple, counts, va_avg, vb_avg, i_end,
                 V, fs, fr):
    """
    Commit the period's state and outputs to ``w`` (the layout's carried state, X0 on).

    ``prevs``: the predictions' memory (prev, p_t, p_T, p_r0, p_tau0, p_w00, p_tq, p_w0bar);
    ``carries``, ``poles`` (has_poles, q0, q1, q2), ``ends`` (e0, e1, e2), ``counts`` (the
    paths' counters' increments).
    """
    prev, p_t, p_T, p_r0, p_tau0, p_w00, p_tq, p_w0bar = prevs
    nc0, nc1, nc2 = carries
    has_poles, q0, q1, q2 = poles
    e0, e1, e2 = ends
    n_ev, n_sign, n_expl = counts
    w[PREV] = 1.0 if prev else 0.0
    w[PREV_T] = p_t
    w[PREV_TT] = p_T
    w[PREV_R0] = p_r0
    w[PREV_TAU0] = p_tau0
    w[PREV_W00] = p_w00
    w[PREV_TQ] = p_tq
    w[PREV_W0BAR] = p_w0bar
    w[CARRY_A] = nc0
    w[CARRY_B] = nc1
    w[CARRY_C] = nc2
    w[POLES] = 1.0 if has_poles else 0.0
    w[POLE_A] = q0
    w[POLE_B] = q1
    w[POLE_C] = q2
    w[END_A] = e0
    w[END_B] = e1
    w[END_C] = e2
    w[EDGES] = edges
    w[RIPPLE] = ripple
    w[END_VALID] = 1.0
    w[N_EV] += n_ev
    w[N_SIGN] += n_sign
    w[N_EXPL] += n_expl
    for q in range(14):
        w[X0 + q] = x[q]
    w[V_APP] = va_avg
    w[V_APP + 1] = vb_avg
    w[I_END] = i_end.real
    w[I_END + 1] = i_end.imag
    w[V_LINK] = V
    w[F_S] = fs
    w[F_R] = fr


def _step_state_currents(w, tab, x_0, x_1, x_2, x_3, x_5, fr):
    """Write RealMotorModel.currents at the end (x_*: the state), R_R at the new temperature."""
    th = w[TH]
    L_sig = w[L_SIG]
    k_h = w[K_H]
    k_e = w[K_E]
    R_R = w[R_R0] * fr
    pa = th * x_2
    pb = th * x_3
    i_sa = (x_0 - pa) / L_sig
    i_sb = (x_1 - pb) / L_sig
    psi2 = pa * pa + pb * pb
    m = w[INV_LM0] if w[SAT] == 0.0 else _inv_L(w, tab, math.sqrt(psi2))
    i_ra = i_sa - m * pa
    i_rb = i_sb - m * pb
    if w[IRON] != 0.0 and psi2 > 1e-18:
        we = w[VP] * x_5
        w0 = (pa * (R_R * i_rb + we * pa) - pb * (R_R * i_ra - we * pb)) / psi2
        dw = (w0 - _iron_rotation(w0, R_R, k_h, k_e)) / R_R
        i_ra += dw * pb
        i_rb -= dw * pa
    w[I_STATE] = i_sa
    w[I_STATE + 1] = i_sb
    w[I_STATE + 2] = -th * i_ra
    w[I_STATE + 3] = -th * i_rb


def _step_measure(w, theta, omega, i_end, V, omega_meas, has_inv):
    """Write RealPlant.measure (the ADCs, the encoder's angle; the noise stays in Python)."""
    m_a = i_end.real
    m_b = i_end.imag
    m_theta = theta
    m_omega = omega
    m_v = V
    if w[SENS] != 0.0:
        ka = SQRT_2_3 * m_a
        kb = SQRT_2_3 * HALF_SQRT3 * m_b
        r_i = w[I_RANGE]
        bits = int(w[BITS])
        a = _adc(w[G_A] * ka + w[O_A], -r_i, r_i, bits)
        b = _adc(w[G_B] * (-0.5 * ka + kb) + w[O_B], -r_i, r_i, bits)
        c = _adc(w[G_C] * (-0.5 * ka - kb) + w[O_C], -r_i, r_i, bits)
        m_a, m_b = _clarke_pair(a, b, c)
        if w[ENC] != 0.0:
            m_theta = math.floor(m_theta * w[CPR] / TWO_PI) * TWO_PI / w[CPR]
            m_omega = omega_meas
        if has_inv:
            m_v = _adc(m_v, 0.0, w[VDC_RANGE], bits)
    w[MEAS] = m_a
    w[MEAS + 1] = m_b
    w[MEAS + 2] = m_theta
    w[MEAS + 3] = m_omega
    w[MEAS + 4] = m_v


def _step_near_limit(w, omega, i_end, tripped, out):
    """Return ``out`` with PROTECT near a protection limit (PlantSimulator.protect decides)."""
    if (not tripped and (out & TRIP_DC) == 0
            and (math.hypot(i_end.real, i_end.imag) > w[I_TRIP] * (1.0 - 1e-9)
                 or abs(omega) > w[W_TRIP] * (1.0 - 1e-9))):
        out |= PROTECT
    return out


_warm = []

#: :func:`step`'s argument types: the array, the tables, v_a, v_b, k, tripped, the load offset
STEP_SIGNATURE = '(float64[::1], float64[::1], float64, float64, int64, boolean, float64)'


def warm() -> None:
    """
    Compile the kernels (or load them from the cache) now, once a process.

    :class:`im_plant.real_plant.RealPlant` calls it when built, so the compilation (about 2.5 s
    the first time after an install, 0.3 s from the cache) comes before a run's first step, not
    within it (a lock-step partner's input watchdog, im_common.lockstep_parts). The arguments'
    types are those of RealPlant's calls: one compiled signature each.
    """
    if _warm or not available:
        return
    ev = events_buffer()
    n, code = _events_k(ev, 0.5, 0.25, 0.75, 0, 1e-4, 1e-4, 2e-6, 0.0, 0.0, 0.0, 1.0, -1.0, 1.0)
    unit, unitc, norm2 = as_table(((1 + 0j,), (1 - 0j,), (1.0,)))
    _period_k(0.1 + 0j, 0.1 + 0j, 1 + 0j, 1.0, 1.0, 0.01, 0.0, 10.0, 0.0, 2.0, 0.0, 1e-4, 1.0,
              0j, code, ev[:n], unit, unitc, norm2, True, 1.0, 1.0, 1.0, 0.0, 0.0, False, 0.0,
              0.0, 0.0, 2.0)
    _explicit_k(0.1 + 0j, 0.1 + 0j, 1 + 0j, 1.0, 1.0, 0.01, 0.0, 10.0, 0.0, 2.0, 0.0, 1e-4,
                1.0, 1.0, as_plan([(1e-4, (0, None, 1))]), 0.0, False, 0.0, 0.0, 0.0, False,
                0.0, 0.0, 0.0, 2.0)
    _step_k.compile(STEP_SIGNATURE)
    _warm.append(True)


if available:
    _csqrt = njit(cache=True)(_csqrt)
    _edges = njit(cache=True)(_edges)
    _modes = njit(cache=True)(_modes)
    _integrals = njit(cache=True)(_integrals)
    _resolved_loop = njit(cache=True, inline='always')(_resolved_loop)
    _clarke = njit(cache=True)(_clarke)
    _diode = njit(cache=True)(_diode)
    # step calls them by these names, which no test or benchmark replaces (they wrap the public
    # ones to count or record the calls from Python)
    events = _events_k = njit(cache=True)(_events)
    period = _period_k = njit(cache=True)(_period)
    explicit = _explicit_k = njit(cache=True)(_explicit)
    _clarke_pair = njit(cache=True)(_clarke_pair)
    _bisect_right = njit(cache=True)(_bisect_right)
    _inv_L = njit(cache=True)(_inv_L)
    _energy = njit(cache=True)(_energy)
    _chord = njit(cache=True)(_chord)
    _iron_rotation = njit(cache=True)(_iron_rotation)
    _load = njit(cache=True)(_load)
    _duties = njit(cache=True)(_duties)
    _carry_after = njit(cache=True)(_carry_after)
    _plan = njit(cache=True)(_plan)
    _sgn = njit(cache=True)(_sgn)
    _adc = njit(cache=True)(_adc)
    _step_plan = njit(cache=True, inline='always')(_step_plan)
    _step_predict = njit(cache=True, inline='always')(_step_predict)
    _step_intervals = njit(cache=True, inline='always')(_step_intervals)
    _step_finish = njit(cache=True, inline='always')(_step_finish)
    _step_switching = njit(cache=True, inline='always')(_step_switching)
    _step_thermal = njit(cache=True, inline='always')(_step_thermal)
    _step_dc_link = njit(cache=True, inline='always')(_step_dc_link)
    _step_encoder = njit(cache=True, inline='always')(_step_encoder)
    _step_commit = njit(cache=True, inline='always')(_step_commit)
    _step_state_currents = njit(cache=True, inline='always')(_step_state_currents)
    _step_measure = njit(cache=True, inline='always')(_step_measure)
    _step_near_limit = njit(cache=True, inline='always')(_step_near_limit)
    step = _step_k = njit(cache=True)(_step)
else:                                           # pragma: no cover - numba is pinned
    events = period = explicit = step = None
