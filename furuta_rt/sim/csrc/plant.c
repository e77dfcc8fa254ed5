/* The plant of furuta_rt.sim.simulator.Simulator, substep for substep, compiled (hil_mock's device, the suites' recordings,
 * diagnose's stick windows).
 *
 * Reference: furuta_rt/sim/simulator.py (Simulator._substep, _rhs, _rhs_stuck, _held_torque, _integrate_stuck),
 * furuta_rt/model/plant.py (eq. 4: accelerations, arm_compliance, inverse_dynamics),
 * furuta_rt/model/friction.py (LuGre, eq. 3: advance, torque). The operations are written in the order of the
 * Python reference so that both round alike; furuta_rt/sim/compiled.py checks the model is one this file covers
 * and tests/test_compiled_plant.py holds the two to agreement tick for tick.
 *
 * State s[]: theta, theta_dot, phi, phi_dot, y, y_dot (Bessel filter), z (LuGre bristles), arm_friction_torque,
 * stuck (0/1). The actuator's transport delay is a ring of (tau0, damp, command) per substep, oldest at *head.
 */
#include <math.h>

#include "plant.h"

unsigned plant_params_size(void) { return (unsigned)sizeof(plant_params_t); }

static void accelerations(const plant_params_t *p, double th, double thd, double phd, double tau_arm, double tau_p,
                          double *thdd, double *phdd)
{
    double a = p->alpha, b = p->beta, c = p->gamma, e = p->eps;
    double s = sin(th), co = cos(th);
    double m11 = a, m12 = c * co, m22 = b + a * s * s;
    double f1 = a * phd * phd * s * co + e * s + tau_p;
    double f2 = c * thd * thd * s - 2.0 * a * thd * phd * s * co + tau_arm;
    double det = m11 * m22 - m12 * m12;
    *thdd = (m22 * f1 - m12 * f2) / det;
    *phdd = (m11 * f2 - m12 * f1) / det;
}

/* (thdd, phdd, ydd) of the smooth dynamics: Simulator._rhs */
static void rhs(const plant_params_t *p, double th, double thd, double ph, double phd, double y, double yd,
                double tau0, double damp, double F, double out[3])
{
    double tau_arm = tau0 - (damp + p->fv_arm) * phd + F - p->k * (ph - p->phi0);
    double tau_p = -p->bp * thd;
    accelerations(p, th, thd, phd, tau_arm, tau_p, &out[0], &out[1]);
    out[2] = p->fa0 * (th + p->offset - y) - p->fa1 * yd;
}

static void rhs_stuck(const plant_params_t *p, double th, double thd, double y, double yd, double *thdd, double *ydd)
{
    double tau_p = -p->bp * thd;
    *thdd = (p->eps * sin(th) + tau_p) / p->alpha;
    *ydd = p->fa0 * (th + p->offset - y) - p->fa1 * yd;
}

static double held_torque(const plant_params_t *p, const double *s, double tau_arm_ext)
{
    double thdd, ydd, th = s[TH], thd = s[THD];
    double a = p->alpha, b = p->beta, c = p->gamma;
    rhs_stuck(p, th, thd, s[Y], s[YD], &thdd, &ydd);
    double sn = sin(th), co = cos(th);
    double tau_arm = c * co * thdd + (b + a * (sn * sn)) * 0.0 - c * (thd * thd) * sn + 2.0 * a * thd * 0.0 * sn * co;
    return tau_arm - tau_arm_ext;
}

static void integrate_stuck(const plant_params_t *p, double *s, double h)
{
    double th = s[TH], thd = s[THD], y = s[Y], yd = s[YD], h2 = 0.5 * h;
    double a1, b1, a2, b2, a3, b3, a4, b4;
    rhs_stuck(p, th, thd, y, yd, &a1, &b1);
    rhs_stuck(p, th + h2 * thd, thd + h2 * a1, y + h2 * yd, yd + h2 * b1, &a2, &b2);
    rhs_stuck(p, th + h2 * (thd + h2 * a1), thd + h2 * a2, y + h2 * (yd + h2 * b1), yd + h2 * b2, &a3, &b3);
    rhs_stuck(p, th + h * (thd + h2 * a2), thd + h * a3, y + h * (yd + h2 * b2), yd + h * b3, &a4, &b4);
    double h6 = h / 6.0;
    s[TH] = th + h6 * (thd + 2 * (thd + h2 * a1) + 2 * (thd + h2 * a2) + (thd + h * a3));
    s[Y] = y + h6 * (yd + 2 * (yd + h2 * b1) + 2 * (yd + h2 * b2) + (yd + h * b3));
    s[THD] = thd + h6 * (a1 + 2 * a2 + 2 * a3 + a4);
    s[YD] = yd + h6 * (b1 + 2 * b2 + 2 * b3 + b4);
    s[PHD] = 0.0;
}

static double lugre_g(const plant_params_t *p, double v)
{
    double r = v / p->vs;
    return (p->l_fc + (p->l_fs - p->l_fc) * exp(-(r * r))) / p->sigma0;
}

static void substep(const plant_params_t *p, double *s, double tau0, double damp)
{
    double h = p->h;
    tau0 += p->bias;
    double th = s[TH], thd = s[THD], ph = s[PH], phd = s[PHD], y = s[Y], yd = s[YD];
    double F = 0.0;
    if (p->lugre) {
        double z = s[Z], z_dot;
        if (phd == 0.0) {
            z_dot = 0.0;
        } else {
            double g = lugre_g(p, phd);
            if (g == 0.0) {
                z_dot = -z / h;
                z = 0.0;
            } else {
                double rate = fabs(phd) / g, z_ss = phd / rate;
                double z_next = z_ss + (z - z_ss) * exp(-rate * h);
                z_dot = (z_next - z) / h;
                z = z_next;
            }
        }
        s[Z] = z;
        F = -(p->sigma0 * z + p->sigma1 * z_dot + p->l_fv * phd);
    } else if (p->set_valued) {
        double spring = p->k != 0.0 ? -p->k * (ph - p->phi0) : 0.0;
        if (s[STUCK] != 0.0) {
            double held = held_torque(p, s, tau0 + spring);
            if (fabs(held) <= p->fs) {
                s[AFT] = held;
                integrate_stuck(p, s, h);
                return;
            }
            s[STUCK] = 0.0;
            F = copysign(p->fc, held);
        } else {
            double k0[3];
            rhs(p, th, thd, ph, phd, y, yd, tau0, damp, 0.0, k0);
            double phdd0 = k0[1], v_free = phd + h * phdd0;
            double a = p->alpha, sn = sin(th), co = cos(th), m22 = p->beta + a * sn * sn, cc = p->gamma * co;
            double comp = a / (a * m22 - cc * cc);
            double direction = phd != 0.0 ? phd : v_free;
            F = -copysign(p->fc, direction);
            double v_slide = phd + h * (phdd0 + comp * F);
            if (phd == 0.0 || v_slide * direction <= 0.0) {
                double needed = -v_free / (h * comp);
                if (fabs(needed) <= p->fs) {
                    s[STUCK] = 1.0;
                    s[PH] += 0.5 * h * phd;
                    s[PHD] = 0.0;
                    s[AFT] = needed;
                    integrate_stuck(p, s, h);
                    return;
                }
                F = -copysign(p->fc, v_free);
            }
        }
    }
    s[AFT] = F;

    double k1[3], k2[3], k3[3], k4[3], h2 = 0.5 * h;
    rhs(p, th, thd, ph, phd, y, yd, tau0, damp, F, k1);
    rhs(p, th + h2 * thd, thd + h2 * k1[0], ph + h2 * phd, phd + h2 * k1[1], y + h2 * yd, yd + h2 * k1[2],
        tau0, damp, F, k2);
    double thd2 = thd + h2 * k1[0], phd2 = phd + h2 * k1[1], yd2 = yd + h2 * k1[2];
    rhs(p, th + h2 * thd2, thd + h2 * k2[0], ph + h2 * phd2, phd + h2 * k2[1], y + h2 * yd2, yd + h2 * k2[2],
        tau0, damp, F, k3);
    double thd3 = thd + h2 * k2[0], phd3 = phd + h2 * k2[1], yd3 = yd + h2 * k2[2];
    rhs(p, th + h * thd3, thd + h * k3[0], ph + h * phd3, phd + h * k3[1], y + h * yd3, yd + h * k3[2],
        tau0, damp, F, k4);
    double thd4 = thd + h * k3[0], phd4 = phd + h * k3[1], yd4 = yd + h * k3[2];
    double h6 = h / 6.0;
    s[TH] = th + h6 * (thd + 2.0 * thd2 + 2.0 * thd3 + thd4);
    s[PH] = ph + h6 * (phd + 2.0 * phd2 + 2.0 * phd3 + phd4);
    s[Y] = y + h6 * (yd + 2.0 * yd2 + 2.0 * yd3 + yd4);
    s[THD] = thd + h6 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]);
    s[PHD] = phd + h6 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]);
    s[YD] = yd + h6 * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2]);
}

/* plant.h: n substeps with the current command's actuator terms, through the transport delay's ring. */
void plant_advance(const plant_params_t *p, double *s, double *ring, int n_delay, int *head,
                   double tau0, double damp, double cmd, long n)
{
    for (long i = 0; i < n; i++) {
        if (n_delay > 0) {
            double *e = ring + 3 * *head;
            double t = e[0], d = e[1];
            e[0] = tau0;
            e[1] = damp;
            e[2] = cmd;
            *head = (*head + 1) % n_delay;
            substep(p, s, t, d);
        } else {
            substep(p, s, tau0, damp);
        }
    }
}
