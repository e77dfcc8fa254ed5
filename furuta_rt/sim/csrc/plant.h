/* plant.c's interface: the parameters of the plant, its state layout and the one call that integrates it. */
#ifndef FURUTA_PLANT_H
#define FURUTA_PLANT_H

typedef struct {
    double alpha, beta, gamma, eps;     /* lumped parameters of eq. 4 */
    double fv_arm, bp, k, phi0;         /* arm viscous, pendulum viscous, spring */
    double fa0, fa1, offset, bias;      /* Bessel filter, theta offset, arm bias */
    double fc, fs;                      /* set-valued dry arm friction: sliding level, stick limit */
    double sigma0, sigma1, l_fc, l_fs, vs, l_fv; /* LuGre */
    double h;                           /* substep */
    int set_valued, lugre;
} plant_params_t;

enum { TH, THD, PH, PHD, Y, YD, Z, AFT, STUCK, N_STATE };

unsigned plant_params_size(void);
/* n substeps with the actuator terms (tau0, damp) of the current command cmd; ring: n_delay entries of
 * (tau0, damp, command), the oldest at *head (the actuator's transport delay, as Simulator.advance's deque). */
void plant_advance(const plant_params_t *p, double *s, double *ring, int n_delay, int *head,
                   double tau0, double damp, double cmd, long n);

#endif /* FURUTA_PLANT_H */
