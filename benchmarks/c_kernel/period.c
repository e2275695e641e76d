/*
 * The real plant's period in C, for the benchmark only (benchmarks/bench_real_plant.py).
 *
 * The same arithmetic as im_plant.real_plant_kernel.period (numba): the frozen system's
 * eigenvalues, the switching intervals with the dead bands resolved by the currents' signs,
 * the boundary sign check, the switching tally and the closed-form energy integrals
 * (docs/plant.md §1). The product keeps numba; this file measures a C extension against it
 * (issue 46: "numba, or a C extension; your choice, measured against the other"). C99 complex
 * arithmetic, so the results agree with numba's to rounding (the benchmark checks 1e-12), not
 * bit for bit.
 *
 * Inputs of one period, in[NIN]: ps, pr, i_s (re, im each), R_s, R_R, L_sigma, r_on, m, kappa,
 * pole pairs, w_star, T, V, drop (re, im), code, check, sa, sb, sc, ksw, sw, iron, k_h, k_e,
 * w00, core_exp; the events ev[2 n_ev] (t, leg bit); the pole-vector table (unit re, im and
 * |unit|^2, 8 each). Outputs out[NOUT]: status, end code, sw, lo, hi, i_s (re, im), psi_s
 * (re, im), psi_R (re, im), torque integral, mean rotation rate, int |i_s|^2, int |i_R|^2,
 * E_in, E_core, E_inv, int u (re, im).
 */
#include <complex.h>
#include <math.h>

#define NIN 30
#define NOUT 21
#define MAX_EV 10

typedef double complex cplx;

static const double SQRT3 = 1.7320508075688772;
static const double TWO_PI = 6.283185307179586;

static cplx mk(double re, double im) { return CMPLX(re, im); }

int rp_period(const double *in, const double *ev, int n_ev, const double *unit_re,
              const double *unit_im, const double *norm2, double *out)
{
    const double SQRT_2_3 = sqrt(2.0 / 3.0);
    const double HALF_SQRT3 = 0.5 * sqrt(3.0);
    cplx ps = mk(in[0], in[1]), pr = mk(in[2], in[3]), i_s = mk(in[4], in[5]);
    double R_s = in[6], R_R = in[7], L_sig = in[8], r_on = in[9], m = in[10], kappa = in[11];
    double vp = in[12], w_star = in[13], T = in[14], V = in[15];
    cplx drop = mk(in[16], in[17]);
    int code = (int)in[18], check = in[19] != 0.0;
    double sa = in[20], sb = in[21], sc = in[22], ksw = in[23], sw = in[24];
    int iron = in[25] != 0.0;
    double k_h = in[26], k_e = in[27], w00 = in[28], core_exp = in[29];
    int k;
    for (k = 0; k < NOUT; k++)
        out[k] = 0.0;
    /* the modes of the frozen system */
    double a = (R_s + r_on) / L_sig;
    double g = R_R * m;
    double w = vp * w_star - kappa;
    cplx tr = mk(-a - R_R / L_sig - g, w);
    cplx det = a * mk(g, -w);
    cplx disc = csqrt(tr * tr - 4.0 * det);
    cplx l1 = (creal(tr) * creal(disc) + cimag(tr) * cimag(disc) >= 0.0) ? 0.5 * (tr + disc)
                                                                          : 0.5 * (tr - disc);
    cplx l2 = det / l1;
    cplx dl = l2 - l1;
    if (cabs(dl) <= 1e-3 * cabs(l1)) {
        out[0] = 2.0;                         /* FALLBACK: repeated eigenvalues */
        out[1] = code;
        out[2] = sw;
        return 2;
    }
    cplx inv = 1.0 / (a * dl);
    cplx c1 = a + l1, c2 = a + l2;
    cplx b1 = c2 * inv, b2 = -c1 * inv;
    cplx g1 = -b1 / l1, g2 = -b2 / l2;
    cplx s1 = -l1 / L_sig, s2 = -l2 / L_sig;
    cplx z10 = (c2 * ps - a * pr) * inv;
    cplx z20 = (a * pr - c1 * ps) * inv;
    double lo = creal(i_s), hi = creal(i_s);
    cplx B1 = 0, B2 = 0, SU = 0;
    double SU2 = 0.0;
    cplx w1 = z10 / g1, w2 = z20 / g2;
    cplx t1 = s1 * g1, t2 = s2 * g2;
    double tp = 0.0;
    cplx i = i_s;
    for (k = 0; k < n_ev; k++) {
        double t_ev = ev[2 * k];
        int bit = (int)ev[2 * k + 1];
        double h = t_ev - tp;
        if (h > 1e-15) {
            cplx un = mk(unit_re[code], unit_im[code]);
            cplx u = V * un - drop;
            cplx a1 = (w1 - u) * (cexp(l1 * h) - 1.0);
            cplx a2 = (w2 - u) * (cexp(l2 * h) - 1.0);
            w1 += a1;
            w2 += a2;
            double n2 = norm2[code];
            if (n2 != 0.0) {
                cplx uc = conj(un);
                B1 += uc * a1;
                B2 += uc * a2;
                SU += un * h;
                SU2 += n2 * h;
            }
            i = t1 * w1 + t2 * w2;
            double ir = creal(i);
            if (check) {
                double ii = SQRT3 * cimag(i);
                if (ir * sa <= 0.0 || (ii - ir) * sb <= 0.0 || (-ii - ir) * sc <= 0.0) {
                    out[0] = 1.0;             /* SIGN_CHANGE */
                    out[1] = code;
                    out[2] = sw;
                    return 1;
                }
            }
            if (ir < lo)
                lo = ir;
            else if (ir > hi)
                hi = ir;
            tp = t_ev;
        }
        if (ksw != 0.0 && bit != 0) {
            double ka = SQRT_2_3 * creal(i);
            if (bit == 1)
                sw += fabs(ka);
            else {
                double kb = SQRT_2_3 * HALF_SQRT3 * cimag(i);
                sw += (bit == 2) ? fabs(-0.5 * ka + kb) : fabs(-0.5 * ka - kb);
            }
        }
        code ^= bit;
    }
    cplx z1 = w1 * g1, z2 = w2 * g2;
    B1 *= g1;
    B2 *= g2;
    cplx dc = conj(drop);
    cplx U1 = V * SU - drop * T;
    double U2 = V * V * SU2 - 2.0 * V * creal(dc * SU) + creal(drop * dc) * T;
    B1 = V * B1 - dc * (z1 - z10);
    B2 = V * B2 - dc * (z2 - z20);
    cplx ps1 = a * (z1 + z2);
    cplx Dd = dc * (U1 - ps1 + ps) / (R_s + r_on);
    /* the closed-form integrals */
    cplx X1 = g1 * U2 + B1 / l1, X2 = g2 * U2 + B2 / l2;
    double M11 = (creal(z1) * creal(z1) + cimag(z1) * cimag(z1) - creal(z10) * creal(z10)
                  - cimag(z10) * cimag(z10) - 2.0 * (creal(b1) * creal(X1) + cimag(b1) * cimag(X1)))
                 / (2.0 * creal(l1));
    double M22 = (creal(z2) * creal(z2) + cimag(z2) * cimag(z2) - creal(z20) * creal(z20)
                  - cimag(z20) * cimag(z20) - 2.0 * (creal(b2) * creal(X2) + cimag(b2) * cimag(X2)))
                 / (2.0 * creal(l2));
    cplx M12 = (z1 * conj(z2) - z10 * conj(z20) - b1 * conj(X2) - conj(b2) * X1)
               / (l1 + conj(l2));
    cplx M21 = conj(M12);
    cplx f1 = conj(s1), f2 = conj(s2);
    double Is2 = creal(f1 * s1) * M11 + creal(f2 * s2) * M22 + 2.0 * creal(s1 * f2 * M12);
    cplx mu = mk(m, kappa / R_R);
    cplx q1 = s1 - mu * c1, q2 = s2 - mu * c2;
    double Ir2 = creal(q1 * conj(q1)) * M11 + creal(q2 * conj(q2)) * M22
                 + 2.0 * creal(q1 * conj(q2) * M12);
    cplx k1 = conj(c1), k2 = conj(c2);
    double torque = vp * cimag(k1 * q1 * M11 + k2 * q2 * M22 + k1 * q2 * M21 + k2 * q1 * M12);
    double e_in = creal(s1 * X1 + s2 * X2) - r_on * Is2;
    double e_inv = r_on * Is2 + creal(Dd);
    double e_core = 0.0, w0bar = w00;
    if (iron || k_h != 0.0 || k_e != 0.0) {
        double P2 = creal(c1 * k1) * M11 + creal(c2 * k2) * M22 + 2.0 * creal(c1 * k2 * M12);
        double rot = R_R * torque / vp + vp * w_star * P2;
        if (P2 > 1e-18 * T)
            w0bar = rot / P2 + kappa;
        if (iron)
            e_core = kappa * rot / R_R;
        else if (P2 > 1e-18 * T) {
            double f = fabs(rot) / (TWO_PI * P2);
            e_core = (k_h + k_e * f) * f * (core_exp == 2.0 ? P2 : sqrt(P2 * T));
        }
    }
    cplx pr1 = c1 * z1 + c2 * z2;
    double res[NOUT] = {0.0, code, sw, lo, hi, creal(i), cimag(i), creal(ps1), cimag(ps1),
                        creal(pr1), cimag(pr1), torque, w0bar, Is2, Ir2, e_in, e_core, e_inv,
                        creal(U1), cimag(U1), 0.0};
    for (k = 0; k < NOUT; k++)
        out[k] = res[k];
    return 0;
}

/* n periods in one call: in[n NIN], ev[n 2 MAX_EV], n_ev[n], out[n NOUT] (the compute alone) */
void rp_period_batch(int n, const double *in, const double *ev, const int *n_ev,
                     const double *unit_re, const double *unit_im, const double *norm2,
                     double *out)
{
    for (int j = 0; j < n; j++)
        rp_period(in + j * NIN, ev + j * 2 * MAX_EV, n_ev[j], unit_re, unit_im, norm2,
                  out + j * NOUT);
}
