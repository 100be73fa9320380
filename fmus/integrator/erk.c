/*
 * Step loop of an explicit embedded Runge-Kutta method with step-size control, integrating the continuous
 * states of a model-exchange FMU by calling its C functions directly.
 *
 * fmu_opinf.sources._model_exchange compiles this file once per machine (into the per-user cache folder) and
 * calls erk_advance() through ctypes for every communication interval.  The Butcher tableau and the two error
 * estimators are passed in by the caller (the coefficients of scipy.integrate.DOP853, an order 8 method with
 * error estimators of orders 5 and 3), and the step-size control is the one of that class: the same method, the
 * same error norm and the same accepted steps as the Python loop it replaces, without Python between the
 * derivative evaluations.  Only forward integration (t_bound > t) is supported.
 *
 * The integrated variable may be the states' deviation from a fixed origin (erk_model.origin): the FMU is then
 * given origin + y.  Positions in global coordinates (6.4e6 m moving by millimetres) lose their motion to
 * rounding when each step adds a few ulps to them; the deviation keeps every digit of it.
 */
#include <math.h>
#include <stddef.h>
#include <string.h>

#if defined(_WIN32)
#define ERK_EXPORT __declspec(dllexport)
#else
#define ERK_EXPORT __attribute__((visibility("default")))
#endif

/* fmi2SetTime / fmi3SetTime, fmi2SetContinuousStates / fmi3SetContinuousStates, fmi2GetDerivatives /
   fmi3GetContinuousStateDerivatives: the same shapes in both versions; a status above 1 (warning) is an error. */
typedef int (*erk_set_time)(void *, double);
typedef int (*erk_set_states)(void *, const double *, size_t);
typedef int (*erk_get_derivatives)(void *, double *, size_t);
/* fmi2CompletedIntegratorStep / fmi3CompletedIntegratorStep: the same shape, but FMI 2's booleans are ints and
   FMI 3's are bools, so each version has its own pointer type. */
typedef int (*erk_completed2)(void *, int, int *, int *);
typedef int (*erk_completed3)(void *, _Bool, _Bool *, _Bool *);

typedef struct {
    void *component;
    erk_set_time set_time;
    erk_set_states set_states;
    erk_get_derivatives get_derivatives;
    size_t n;
    double rtol;
    const double *atol; /* n absolute tolerances */
    void *completed;    /* the FMU's CompletedIntegratorStep, called after each accepted step inside the interval */
    int fmi_version;    /* 2 or 3: how to call completed; 0: do not call it */
    const double *origin; /* n values added to y before it is given to the FMU, or NULL (y is the state) */
    double *absolute;     /* n doubles of scratch for origin + y */
} erk_model;

typedef struct {
    int stages;          /* s */
    int estimator_order; /* the error is proportional to h^(estimator_order + 1) */
    const double *a;     /* s x s, row-major, strictly lower triangular */
    const double *b;     /* s weights of the solution */
    const double *c;     /* s nodes */
    const double *e5;    /* s + 1 weights of the higher-order error estimate (the last one for f(t + h, y_new)) */
    const double *e3;    /* s + 1 weights of the lower-order error estimate */
} erk_tableau;

typedef struct {
    double t;          /* time reached */
    double h_abs;      /* next step size to try; <= 0 on the first call: chosen from the derivatives */
    double h_last;     /* size of the last step taken, 0 before the first */
    double t_failed;   /* time of the last evaluation: of the one that failed, after a failure */
    int have_f;        /* row 0 of the work array holds f(t, y) */
    long evaluations;  /* derivative evaluations so far */
    long steps;        /* accepted steps so far */
} erk_state;

enum {
    ERK_DONE = 0, ERK_PAUSED = 1, ERK_FMU_ERROR = 2, ERK_NOT_FINITE = 3, ERK_STEP_TOO_SMALL = 4,
    ERK_EVENT = 5, ERK_TERMINATE = 6, ERK_COMPLETED_ERROR = 7
};

static const double SAFETY = 0.9, MIN_FACTOR = 0.2, MAX_FACTOR = 10.0;

static int evaluate(const erk_model *m, erk_state *st, double t, const double *y, double *f) {
    size_t i;
    const double *x = y;
    st->evaluations++;
    st->t_failed = t;
    if (m->origin) {
        for (i = 0; i < m->n; i++) m->absolute[i] = m->origin[i] + y[i];
        x = m->absolute;
    }
    if (m->set_time(m->component, t) > 1 || m->set_states(m->component, x, m->n) > 1 ||
        m->get_derivatives(m->component, f, m->n) > 1)
        return ERK_FMU_ERROR;
    for (i = 0; i < m->n; i++)
        if (!isfinite(f[i])) return ERK_NOT_FINITE;
    return ERK_DONE;
}

static double rms(const double *x, const double *scale, size_t n) {
    double sum = 0.0;
    size_t i;
    for (i = 0; i < n; i++) sum += (x[i] / scale[i]) * (x[i] / scale[i]);
    return sqrt(sum / (double)n);
}

/* First step from the size of the state, of its derivative and of the derivative's change over a trial step
   (Hairer, Norsett, Wanner, Solving ODEs I, Sec. II.4). f1 and y1 are scratch rows. */
static int initial_step(const erk_model *m, const erk_tableau *tab, erk_state *st, double t_bound,
                        const double *y, const double *f0, double *y1, double *f1, double *scale) {
    const size_t n = m->n;
    const double interval = t_bound - st->t;
    double d0, d1, d2, h0, h1, sum = 0.0;
    size_t i;
    int status;
    for (i = 0; i < n; i++) scale[i] = m->atol[i] + fabs(y[i]) * m->rtol;
    d0 = rms(y, scale, n);
    d1 = rms(f0, scale, n);
    h0 = (d0 < 1e-5 || d1 < 1e-5) ? 1e-6 : 0.01 * d0 / d1;
    if (h0 > interval) h0 = interval;
    for (i = 0; i < n; i++) y1[i] = y[i] + h0 * f0[i];
    status = evaluate(m, st, st->t + h0, y1, f1);
    if (status) return status;
    for (i = 0; i < n; i++) {
        double d = (f1[i] - f0[i]) / scale[i];
        sum += d * d;
    }
    d2 = sqrt(sum / (double)n) / h0;
    if (d1 <= 1e-15 && d2 <= 1e-15)
        h1 = fmax(1e-6, h0 * 1e-3);
    else
        h1 = pow(0.01 / fmax(d1, d2), 1.0 / (tab->estimator_order + 1));
    st->h_abs = fmin(fmin(100.0 * h0, h1), interval);
    return ERK_DONE;
}

/* One trial step of size h from (t, y): stages into k (rows 1..s, row 0 holds f(t, y)), solution into y_new. */
static int trial_step(const erk_model *m, const erk_tableau *tab, erk_state *st, double t, double h,
                      const double *y, double *k, double *y_new, double *stage) {
    const size_t n = m->n;
    const int s = tab->stages;
    size_t i;
    int j, l, status;
    for (j = 1; j < s; j++) {
        const double *a = tab->a + (size_t)j * s;
        for (i = 0; i < n; i++) {
            double sum = 0.0;
            for (l = 0; l < j; l++) sum += k[(size_t)l * n + i] * a[l];
            stage[i] = y[i] + sum * h;
        }
        status = evaluate(m, st, t + tab->c[j] * h, stage, k + (size_t)j * n);
        if (status) return status;
    }
    for (i = 0; i < n; i++) {
        double sum = 0.0;
        for (l = 0; l < s; l++) sum += k[(size_t)l * n + i] * tab->b[l];
        y_new[i] = y[i] + h * sum;
    }
    return evaluate(m, st, t + h, y_new, k + (size_t)s * n);
}

/* Error norm of the trial step: the order 5 estimate, corrected by the order 3 one where that is larger. */
static double error_norm(const erk_model *m, const erk_tableau *tab, const double *k, double h,
                         const double *scale) {
    const size_t n = m->n;
    const int s = tab->stages;
    double norm5 = 0.0, norm3 = 0.0;
    size_t i;
    int l;
    for (i = 0; i < n; i++) {
        double err5 = 0.0, err3 = 0.0;
        for (l = 0; l <= s; l++) {
            err5 += k[(size_t)l * n + i] * tab->e5[l];
            err3 += k[(size_t)l * n + i] * tab->e3[l];
        }
        err5 /= scale[i];
        err3 /= scale[i];
        norm5 += err5 * err5;
        norm3 += err3 * err3;
    }
    if (norm5 == 0.0 && norm3 == 0.0) return 0.0;
    return fabs(h) * norm5 / sqrt((norm5 + 0.01 * norm3) * (double)n);
}

/* One accepted step towards t_bound, shrinking the step until the error norm is below 1. */
static int accepted_step(const erk_model *m, const erk_tableau *tab, erk_state *st, double t_bound, double *y,
                         double *work) {
    const size_t n = m->n;
    const int s = tab->stages;
    const double exponent = -1.0 / (tab->estimator_order + 1);
    double *k = work, *y_new = work + (size_t)(s + 1) * n, *stage = y_new + n, *scale = stage + n;
    const double t = st->t, min_step = 10.0 * fabs(nextafter(t, INFINITY) - t);
    double h_abs = st->h_abs < min_step ? min_step : st->h_abs, h = 0.0, t_new = t;
    int rejected = 0, status;
    size_t i;
    for (;;) {
        double norm;
        if (h_abs < min_step) return ERK_STEP_TOO_SMALL;
        t_new = t + h_abs;
        if (t_new > t_bound) t_new = t_bound;
        h = t_new - t;
        h_abs = fabs(h);
        status = trial_step(m, tab, st, t, h, y, k, y_new, stage);
        if (status) return status;
        for (i = 0; i < n; i++) scale[i] = m->atol[i] + fmax(fabs(y[i]), fabs(y_new[i])) * m->rtol;
        norm = error_norm(m, tab, k, h, scale);
        if (norm < 1.0) {
            double factor = norm == 0.0 ? MAX_FACTOR : fmin(MAX_FACTOR, SAFETY * pow(norm, exponent));
            if (rejected) factor = fmin(1.0, factor);
            h_abs *= factor;
            break;
        }
        h_abs *= fmax(MIN_FACTOR, SAFETY * pow(norm, exponent));
        rejected = 1;
    }
    memcpy(y, y_new, n * sizeof(double));
    memcpy(k, k + (size_t)s * n, n * sizeof(double)); /* f(t_new, y_new) starts the next step */
    st->t = t_new;
    st->h_abs = h_abs;
    st->h_last = h;
    st->steps++;
    return ERK_DONE;
}

/* CompletedIntegratorStep at the accepted point (st->t, y): the FMU's state is y already (the last evaluation of
   an accepted step is f(t + h, y_new)), its time is set again only where t + h rounded differently from st->t.
   Returns ERK_EVENT or ERK_TERMINATE when the FMU asks for event mode or for the end of the simulation. */
static int completed_step(const erk_model *m, erk_state *st) {
    int event = 0, terminate = 0, status;
    if (st->t_failed != st->t && m->set_time(m->component, st->t) > 1) return ERK_COMPLETED_ERROR;
    st->t_failed = st->t;
    if (m->fmi_version == 2) {
        status = ((erk_completed2)m->completed)(m->component, 1, &event, &terminate);
    } else {
        _Bool event3 = 0, terminate3 = 0;
        status = ((erk_completed3)m->completed)(m->component, 1, &event3, &terminate3);
        event = event3;
        terminate = terminate3;
    }
    if (status > 1) return ERK_COMPLETED_ERROR;
    return terminate ? ERK_TERMINATE : event ? ERK_EVENT : ERK_DONE;
}

/*
 * Integrate y from st->t towards t_bound, at most max_steps accepted steps per call (ERK_PAUSED: call again,
 * so that the caller can react to an interrupt).  work holds (stages + 4) * n doubles and must be kept between
 * the calls of one interval.  Returns ERK_DONE once st->t == t_bound, or an error code with st->t_failed.
 * With m->fmi_version set, the FMU's CompletedIntegratorStep is called after every accepted step that ends before
 * t_bound (the caller calls it at t_bound); when the FMU asks for an event (ERK_EVENT) or to terminate
 * (ERK_TERMINATE) the loop stops there, with st->t and y the accepted point.
 */
ERK_EXPORT int erk_advance(const erk_model *m, const erk_tableau *tab, erk_state *st, double t_bound, double *y,
                           double *work, long max_steps) {
    const size_t n = m->n;
    const int s = tab->stages;
    long taken = 0;
    int status;
    if (n == 0 || st->t >= t_bound) {
        st->t = t_bound;
        return ERK_DONE;
    }
    if (!st->have_f) {
        status = evaluate(m, st, st->t, y, work);
        if (status) return status;
        st->have_f = 1;
        if (st->h_abs <= 0.0) {
            double *scratch = work + (size_t)(s + 1) * n;
            status = initial_step(m, tab, st, t_bound, y, work, scratch, scratch + n, scratch + 2 * n);
            if (status) return status;
        }
    }
    while (st->t < t_bound) {
        if (taken++ >= max_steps) return ERK_PAUSED;
        status = accepted_step(m, tab, st, t_bound, y, work);
        if (status) return status;
        if (m->fmi_version && st->t < t_bound) {
            status = completed_step(m, st);
            if (status) return status;
        }
    }
    return ERK_DONE;
}
