/*
 * Kernel of the linear state-space FMUs (see lti.h): storage, evaluation of the ODE right-hand
 * side and of the computed variables, value-reference access, co-simulation steps, the optional
 * time and state events.
 */
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lti.h"

#define DEFAULT_TOLERANCE 1e-4
#define MAX_SUBSTEPS 10000000.0

static char *copyString(const char *text) {
    size_t length = strlen(text ? text : "") + 1;
    char *copy = (char *)malloc(length);
    if (copy) memcpy(copy, text ? text : "", length);
    return copy;
}

void ltiLog(const LtiInstance *inst, LtiStatus status, const char *category, const char *format,
            ...) {
    char message[1024];
    va_list args;

    if (!inst || !inst->log) return;
    if (!inst->loggingOn && status < LtiDiscard) return;  /* errors and discards say why, whatever the setting */
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    inst->log(inst, status, category, message);
}

static size_t physicalSize(size_t nq) {
    return LTI_X_FOLLOWS_Q ? nq : LTI_NX_FIXED;
}

LtiInstance *ltiCreate(const char *name, int isCoSimulation, LtiLogger log, void *context,
                       LtiCallback callback, void *environment, int loggingOn) {
    size_t nq = LTI_NQ_MAX, nx, nu = LTI_NU ? LTI_NU : 1, ny = LTI_NY ? LTI_NY : 1;
    LtiInstance *inst = (LtiInstance *)calloc(1, sizeof(LtiInstance));

    if (!inst) return NULL;
    nx = physicalSize(nq);
    inst->name = copyString(name);
    inst->log = log;
    inst->context = context;
    inst->callback = callback;
    inst->environment = environment;
    inst->loggingOn = loggingOn;
    inst->isCoSimulation = isCoSimulation;
    inst->Kq = (double *)calloc(nq * nq, sizeof(double));
    inst->Dq = (double *)calloc(nq * nq, sizeof(double));
    inst->Bq = (double *)calloc(nq * nu, sizeof(double));
    inst->fq = (double *)calloc(nq, sizeof(double));
    inst->T = (double *)calloc(nx * nq, sizeof(double));
    inst->xoff = (double *)calloc(nx, sizeof(double));
    inst->Cp = (double *)calloc(ny * nx, sizeof(double));
    inst->Cv = (double *)calloc(ny * nx, sizeof(double));
    inst->Ca = (double *)calloc(ny * nx, sizeof(double));
    inst->y0 = (double *)calloc(ny, sizeof(double));
    inst->z = (double *)calloc(2 * nq, sizeof(double));
    inst->zStart = (double *)calloc(2 * nq, sizeof(double));
    inst->u = (double *)calloc(nu, sizeof(double));
    inst->qdd = (double *)calloc(nq, sizeof(double));
    inst->qddBefore = (double *)calloc(nq, sizeof(double));
    inst->x = (double *)calloc(nx, sizeof(double));
    inst->v = (double *)calloc(nx, sizeof(double));
    inst->a = (double *)calloc(nx, sizeof(double));
    inst->y = (double *)calloc(ny, sizeof(double));
    inst->yBefore = (double *)calloc(ny, sizeof(double));
    inst->work = (double *)calloc(14 * nq, sizeof(double));   /* RK4 10 nq, derivatives 2 nq, single precision 2 nq */
    if (!inst->name || !inst->Kq || !inst->Dq || !inst->Bq || !inst->fq || !inst->T ||
        !inst->xoff || !inst->Cp || !inst->Cv || !inst->Ca || !inst->y0 || !inst->z ||
        !inst->zStart || !inst->u || !inst->qdd || !inst->qddBefore || !inst->x || !inst->v || !inst->a ||
        !inst->y || !inst->yBefore || !inst->work) {
        ltiFree(inst);
        return NULL;
    }
    ltiReset(inst);
    return inst;
}

void ltiFree(LtiInstance *inst) {
    if (!inst) return;
    free(inst->name); free(inst->Kq); free(inst->Dq); free(inst->Bq); free(inst->fq);
    free(inst->T); free(inst->xoff); free(inst->Cp); free(inst->Cv); free(inst->Ca);
    free(inst->y0); free(inst->z); free(inst->zStart); free(inst->u); free(inst->qdd); free(inst->qddBefore);
    free(inst->x); free(inst->v); free(inst->a); free(inst->y); free(inst->yBefore); free(inst->work);
    free(inst);
}

/* Back to the instantiated state with the start values of the current size. */
void ltiReset(LtiInstance *inst) {
    size_t i;

    inst->phase = PhaseInstantiated;
    inst->completedEventAsked = 0;
    inst->terminated = 0;
    inst->enabled = 0;
    inst->order = LTI_ORDER_START;
    inst->cache = LTI_CACHE_START;
    inst->method = LTI_METHOD_START;
    inst->relTol = (float)LTI_TOLERANCE_START;
    inst->stopDefined = 0;
    inst->stopTime = 0.0;
    inst->nq = LTI_NQ_DEFAULT;
    inst->time = 0.0;
    inst->tolerance = DEFAULT_TOLERANCE;
    inst->nqPending = inst->nq;
    inst->nx = physicalSize(inst->nq);
    inst->par[PAR_MASS_SCALE] = LTI_PAR_DEFAULTS[PAR_MASS_SCALE];
    inst->par[PAR_STIFFNESS_SCALE] = LTI_PAR_DEFAULTS[PAR_STIFFNESS_SCALE];
    for (i = 0; i < LTI_NU; i++) inst->u[i] = 0.0;
    ltiAssemble(inst);
    memcpy(inst->z, inst->zStart, 2 * inst->nq * sizeof(double));
    inst->upToDate = 0;
    inst->stale = 0;
    inst->late = 0;
    inst->timeEventOn = 0;
    inst->stateEventOn = 0;
    inst->indicatorAbove = 0;
}

LtiStatus ltiFail(LtiInstance *inst, LtiStatus status) {
    if (status >= LtiError) inst->phase = PhaseError;
    return status;
}

static const char *phaseName(int phase) {
    switch (phase) {
        case PhaseInstantiated: return "instantiated";
        case PhaseConfiguration: return "configuration mode";
        case PhaseInitialization: return "initialization mode";
        case PhaseEvent: return "event mode";
        case PhaseContinuous: return "continuous-time mode";
        case PhaseStep: return "step mode";
        case PhaseTerminated: return "terminated";
        default: return "error state";
    }
}

LtiStatus ltiCheckPhase(LtiInstance *inst, const char *function, int allowed) {
    if (!inst) return LtiError;
    if (!(inst->phase & allowed)) {
        ltiLog(inst, LtiError, "logStatusError", "%s must not be called in %s", function,
               phaseName(inst->phase));
        return LtiError;
    }
    return LtiOK;
}

/* y += A x for a row-major rows x cols matrix. */
static void addProduct(double *y, const double *A, const double *x, size_t rows, size_t cols,
                       double factor) {
    size_t i, j;
    for (i = 0; i < rows; i++) {
        double sum = 0.0;
        for (j = 0; j < cols; j++) sum += A[i * cols + j] * x[j];
        y[i] += factor * sum;
    }
}

/* The position x[dof] = xoff[dof] + T[dof, :] q of the state z (q, qd). */
static double position(const LtiInstance *inst, size_t dof, const double *z) {
    size_t nq = inst->nq, j;
    double x = inst->xoff[dof];
    for (j = 0; j < nq; j++) x += inst->T[dof * nq + j] * z[j];
    return x;
}

/* qdd of the state z (2 nq) under the current inputs and parameters. */
static LtiStatus accelerations(LtiInstance *inst, const char *function, const double *z,
                               double *qdd) {
    size_t nq = inst->nq, i;
    double massScale = inst->par[PAR_MASS_SCALE];

    if (massScale == 0.0 || !isfinite(massScale)) {
        ltiLog(inst, LtiError, "logStatusError",
               "%s: division by zero: mass_scale = %g makes the mass matrix singular", function,
               massScale);
        return LtiError;
    }
    if (LTI_SINGLE_PRECISION == 1) {   /* the state as a float, the terms below rounded to float */
        double *rounded = inst->work + 12 * nq;
        for (i = 0; i < 2 * nq; i++) rounded[i] = (float)z[i];
        z = rounded;
    }
    if (LTI_POSITION_LIMIT) {
        double x = position(inst, LTI_POSITION_LIMIT_DOF, z);
        if (!(fabs(x) <= LTI_POSITION_LIMIT_BOUND)) {
            LtiStatus refused = LTI_POSITION_LIMIT == 2 ? LtiDiscard : LtiError;
            ltiLog(inst, refused, "logStatusError", "%s: assert: position %lu = %g is out of its range +-%g",
                   function, (unsigned long)LTI_POSITION_LIMIT_DOF, x, LTI_POSITION_LIMIT_BOUND);
            return refused;
        }
    }
    for (i = 0; i < nq; i++) qdd[i] = inst->fq[i];
    if (LTI_SINGLE_PRECISION == 2) {   /* one block in float: the stiffness forces on the first half of the dofs */
        double *rounded = inst->work + 12 * nq, *force = rounded + nq, stiffness = -inst->par[PAR_STIFFNESS_SCALE];
        for (i = 0; i < nq; i++) {
            rounded[i] = (float)z[i];
            force[i] = 0.0;
        }
        addProduct(force, inst->Kq, rounded, nq, nq, stiffness);
        for (i = 0; i < nq / 2; i++) qdd[i] += (float)force[i];
        for (i = 0; i < nq; i++) force[i] = 0.0;
        addProduct(force, inst->Kq, z, nq, nq, stiffness);
        for (i = nq / 2; i < nq; i++) qdd[i] += force[i];
    } else {
        addProduct(qdd, inst->Kq, z, nq, nq, -inst->par[PAR_STIFFNESS_SCALE]);
    }
    addProduct(qdd, inst->Dq, z + nq, nq, nq, -1.0);
    if (!LTI_ENABLE_INPUT || inst->enabled) addProduct(qdd, inst->Bq, inst->u, nq, LTI_NU, 1.0);
    if (inst->timeEventOn) for (i = 0; i < nq; i++) qdd[i] += LTI_TIME_EVENT_FQ[i];
    if (inst->stateEventOn) for (i = 0; i < nq; i++) qdd[i] += LTI_STATE_EVENT_FQ[i];
    for (i = 0; i < nq; i++) qdd[i] /= massScale;
    if (LTI_SINGLE_PRECISION == 1) for (i = 0; i < nq; i++) qdd[i] = (float)qdd[i];
    return LtiOK;
}

LtiStatus ltiEvaluate(LtiInstance *inst, const char *function) {
    size_t nq = inst->nq, nx = inst->nx, i;

    if (inst->upToDate) return LtiOK;
    if (accelerations(inst, function, inst->z, inst->qdd) != LtiOK) return LtiError;
    for (i = 0; i < nx; i++) {
        inst->x[i] = inst->xoff[i];
        inst->v[i] = 0.0;
        inst->a[i] = 0.0;
    }
    addProduct(inst->x, inst->T, inst->z, nx, nq, 1.0);
    addProduct(inst->v, inst->T, inst->z + nq, nx, nq, 1.0);
    addProduct(inst->a, inst->T, inst->qdd, nx, nq, 1.0);
    for (i = 0; i < LTI_NY; i++) inst->y[i] = inst->y0[i];
    addProduct(inst->y, inst->Cp, inst->x, LTI_NY, nx, 1.0);
    addProduct(inst->y, inst->Cv, inst->v, LTI_NY, nx, 1.0);
    addProduct(inst->y, inst->Ca, inst->a, LTI_NY, nx, 1.0);
    inst->upToDate = 1;
    return LtiOK;
}

/* The event indicator x[LTI_STATE_EVENT_DOF] + LTI_STATE_EVENT_INPUT_GAIN u[0] - LTI_STATE_EVENT_THRESHOLD of the
   state z (q, qd) and the first input (if any): with a gain, setting the input can move it across zero. */
static double indicator(const LtiInstance *inst, const double *z) {
    double x = position(inst, LTI_STATE_EVENT_DOF, z);
    if (LTI_NU > 0) x += LTI_STATE_EVENT_INPUT_GAIN * inst->u[0];
    return x - LTI_STATE_EVENT_THRESHOLD;
}

/* ----------------------------------------------------------- variable access */

static const LtiSlot *findSlot(LtiInstance *inst, const char *function, unsigned int vr) {
    if (vr >= LTI_N_SLOTS) {
        ltiLog(inst, LtiError, "logStatusError", "%s: unknown value reference %u", function, vr);
        return NULL;
    }
    return &LTI_SLOTS[vr];
}

static size_t slotLength(const LtiInstance *inst, const LtiSlot *slot) {
    if (!slot->isArray) return 1;
    switch (slot->kind) {
        case SlotX: case SlotV: case SlotA: return inst->nx;
        case SlotY: return LTI_NY;
        case SlotU: return LTI_NU;
        default: return inst->nq;
    }
}

static int needsEvaluation(int kind) {
    return kind == SlotQdd || kind == SlotX || kind == SlotV || kind == SlotA || kind == SlotY;
}

LtiStatus ltiGetReal(LtiInstance *inst, const char *function, const unsigned int vr[], size_t nvr,
                     double values[], size_t nValues) {
    size_t i, k, offset = 0;

    for (i = 0; i < nvr; i++) {
        const LtiSlot *slot = findSlot(inst, function, vr[i]);
        size_t length, first;
        if (!slot) return LtiError;
        if (slot->kind == SlotSize) {
            ltiLog(inst, LtiError, "logStatusError", "%s: value reference %u is not a real",
                   function, vr[i]);
            return LtiError;
        }
        if (needsEvaluation(slot->kind) && ltiEvaluate(inst, function) != LtiOK) return LtiError;
        length = slotLength(inst, slot);
        first = slot->isArray ? 0 : (size_t)slot->index;
        if (offset + length > nValues) {
            ltiLog(inst, LtiError, "logStatusError", "%s: %lu values are too few", function,
                   (unsigned long)nValues);
            return LtiError;
        }
        for (k = 0; k < length; k++) {
            size_t e = first + k;
            double value = 0.0;
            switch (slot->kind) {
                case SlotTime: value = inst->time; break;
                case SlotQ: value = inst->z[e]; break;
                case SlotQd: value = inst->z[inst->nq + e]; break;
                case SlotQdd: value = inst->stale ? inst->qddBefore[e] : inst->qdd[e]; break;
                case SlotX: value = inst->x[e]; break;
                case SlotV: value = inst->v[e]; break;
                case SlotA: value = inst->a[e]; break;
                case SlotY: value = inst->late ? inst->yBefore[e] : inst->y[e]; break;
                case SlotU: value = inst->u[e]; break;
                case SlotPar: value = inst->par[e]; break;
                case SlotQStart: value = inst->zStart[e]; break;
                case SlotQdStart: value = inst->zStart[inst->nq + e]; break;
                case SlotIndicator: value = indicator(inst, inst->z); break;
                default: break;
            }
            values[offset + k] = value;
        }
        offset += length;
    }
    return LtiOK;
}

LtiStatus ltiSetReal(LtiInstance *inst, const char *function, const unsigned int vr[], size_t nvr,
                     const double values[], size_t nValues) {
    size_t i, k, offset = 0;

    for (i = 0; i < nvr; i++) {
        const LtiSlot *slot = findSlot(inst, function, vr[i]);
        size_t length, first;
        if (!slot) return LtiError;
        if (slot->kind == SlotTime || slot->kind == SlotSize || slot->kind == SlotIndicator ||
            needsEvaluation(slot->kind)) {
            ltiLog(inst, LtiError, "logStatusError",
                   "%s: value reference %u is computed by the FMU and cannot be set", function,
                   vr[i]);
            return LtiError;
        }
        if (slot->tunable == 2 && !inst->isCoSimulation && (inst->phase & PhaseContinuous) &&
            values[offset] != inst->u[slot->index]) {
            ltiLog(inst, LtiError, "logStatusError",
                   "%s: discrete input (value reference %u) may only be set in event mode", function, vr[i]);
            return LtiError;
        }
        if (!slot->tunable && !(inst->phase & PHASE_BEFORE_INIT)) {
            ltiLog(inst, LtiError, "logStatusError",
                   "%s: value reference %u can only be set before initialization ends",
                   function, vr[i]);
            return LtiError;
        }
        length = slotLength(inst, slot);
        first = slot->isArray ? 0 : (size_t)slot->index;
        if (offset + length > nValues) {
            ltiLog(inst, LtiError, "logStatusError", "%s: %lu values are too few", function,
                   (unsigned long)nValues);
            return LtiError;
        }
        for (k = 0; k < length; k++) {
            size_t e = first + k, nq = inst->nq;
            double value = values[offset + k];
            switch (slot->kind) {
                case SlotQ: inst->z[e] = value; break;
                case SlotQd: inst->z[nq + e] = value; break;
                case SlotU: inst->u[e] = value; inst->stale = 0; break;
                case SlotPar: inst->par[e] = value; break;
                case SlotQStart: inst->zStart[e] = value; inst->z[e] = value; break;
                case SlotQdStart: inst->zStart[nq + e] = value; inst->z[nq + e] = value; break;
                default: break;
            }
        }
        offset += length;
    }
    inst->upToDate = 0;
    return LtiOK;
}

LtiStatus ltiGetSize(LtiInstance *inst, const char *function, const unsigned int vr[], size_t nvr,
                     unsigned long long values[]) {
    size_t i;
    for (i = 0; i < nvr; i++) {
        const LtiSlot *slot = findSlot(inst, function, vr[i]);
        if (!slot) return LtiError;
        if (slot->kind != SlotSize) {
            ltiLog(inst, LtiError, "logStatusError", "%s: value reference %u is not a UInt64",
                   function, vr[i]);
            return LtiError;
        }
        values[i] = (unsigned long long)(inst->phase == PhaseConfiguration ? inst->nqPending
                                                                            : inst->nq);
    }
    return LtiOK;
}

LtiStatus ltiSetSize(LtiInstance *inst, const char *function, const unsigned int vr[], size_t nvr,
                     const unsigned long long values[]) {
    size_t i;
    for (i = 0; i < nvr; i++) {
        const LtiSlot *slot = findSlot(inst, function, vr[i]);
        if (!slot) return LtiError;
        if (slot->kind != SlotSize) {
            ltiLog(inst, LtiError, "logStatusError", "%s: value reference %u is not a UInt64",
                   function, vr[i]);
            return LtiError;
        }
        if (inst->phase != PhaseConfiguration) {
            ltiLog(inst, LtiError, "logStatusError",
                   "%s: the structural parameter (value reference %u) can only be set in "
                   "configuration mode", function, vr[i]);
            return LtiError;
        }
        if (values[i] < 1 || values[i] > (unsigned long long)LTI_NQ_MAX) {
            ltiLog(inst, LtiError, "logStatusError",
                   "%s: size %llu is outside [1, %lu]", function, values[i],
                   (unsigned long)LTI_NQ_MAX);
            return LtiError;
        }
        inst->nqPending = (size_t)values[i];
    }
    return LtiOK;
}

/* Applies a structural size set in configuration mode: new matrices and start values. */
LtiStatus ltiExitConfiguration(LtiInstance *inst) {
    if (inst->nqPending != inst->nq) {
        inst->nq = inst->nqPending;
        inst->nx = physicalSize(inst->nq);
        ltiAssemble(inst);
        memcpy(inst->z, inst->zStart, 2 * inst->nq * sizeof(double));
        ltiLog(inst, LtiOK, "logEvents", "resized to %lu masses", (unsigned long)inst->nq);
    }
    inst->phase = PhaseInstantiated;
    inst->upToDate = 0;
    return LtiOK;
}

/* ------------------------------------------------------------ time integration */

/* The FMI state vector is z = (q, qd), or (q1, qd1, q2, qd2, ...) with LTI_INTERLEAVED (the order of
   the model structure's state derivatives, as exporters that sort states by component produce). */
static void toFmiOrder(size_t nq, const double *z, double *out) {
    size_t i;
    if (!LTI_INTERLEAVED) {
        memcpy(out, z, 2 * nq * sizeof(double));
        return;
    }
    for (i = 0; i < nq; i++) {
        out[2 * i] = z[i];
        out[2 * i + 1] = z[nq + i];
    }
}

LtiStatus ltiDerivatives(LtiInstance *inst, const char *function, double dz[]) {
    size_t nq = inst->nq;
    double *internal = inst->work + 10 * nq;   /* the RK4 step uses the first 10 nq */
    size_t i;
    LtiStatus status = accelerations(inst, function, inst->z, internal + nq);
    if (status != LtiOK) return status;   /* a discard stays a discard */
    for (i = 0; i < nq; i++) internal[i] = LTI_SINGLE_PRECISION == 1 ? (float)inst->z[nq + i] : inst->z[nq + i];
    toFmiOrder(nq, internal, dz);
    return LtiOK;
}

LtiStatus ltiSetStates(LtiInstance *inst, const double z[], size_t n) {
    size_t nq = n / 2, i;
    if (!LTI_INTERLEAVED) {
        memcpy(inst->z, z, n * sizeof(double));
    } else {
        for (i = 0; i < nq; i++) {
            inst->z[i] = z[2 * i];
            inst->z[nq + i] = z[2 * i + 1];
        }
    }
    inst->upToDate = 0;
    return LtiOK;
}

void ltiGetStates(const LtiInstance *inst, double z[]) {
    toFmiOrder(inst->nq, inst->z, z);
}

/* dz = f(z) for a state given explicitly (2 nq values). */
static LtiStatus rate(LtiInstance *inst, const double *z, double *dz) {
    size_t nq = inst->nq;
    if (accelerations(inst, "fmiDoStep", z, dz + nq) != LtiOK) return LtiError;
    memcpy(dz, z + nq, nq * sizeof(double));
    return LtiOK;
}

/* Bound on the modulus of the eigenvalues of the first-order system (frequency scale). */
static double frequencyScale(const LtiInstance *inst) {
    size_t nq = inst->nq, i, j;
    double stiffness = 0.0, damping = 0.0, scale = fabs(inst->par[PAR_MASS_SCALE]);
    for (i = 0; i < nq; i++) {
        double k = 0.0, d = 0.0;
        for (j = 0; j < nq; j++) {
            k += fabs(inst->Kq[i * nq + j]);
            d += fabs(inst->Dq[i * nq + j]);
        }
        if (k > stiffness) stiffness = k;
        if (d > damping) damping = d;
    }
    stiffness *= fabs(inst->par[PAR_STIFFNESS_SCALE]) / scale;
    damping /= scale;
    return sqrt(stiffness) + damping + 1e-12;
}

/* The state z advanced by h: one Euler step, RK4 substeps following the tolerance, or one RK4 step. */
static LtiStatus integrate(LtiInstance *inst, double h) {
    size_t n = 2 * inst->nq, i, k, steps = 1;
    double *k1 = inst->work, *k2 = k1 + n, *k3 = k2 + n, *k4 = k3 + n, *zt = k4 + n;
    double *z = inst->z, dt = h;

    if (LTI_CS_METHOD == CsRungeKutta && h > 0.0) {
        /* RK4 error per unit time ~ (w dt)^4 w: the substep follows the tolerance */
        double omega = frequencyScale(inst), tol = inst->tolerance > 0 ? inst->tolerance : 1e-4;
        double count = ceil(h * omega / pow(tol, 0.25));
        if (count > MAX_SUBSTEPS) count = MAX_SUBSTEPS;
        steps = count < 1.0 ? 1 : (size_t)count;
        dt = h / (double)steps;
    }
    for (k = 0; k < steps; k++) {
        if (rate(inst, z, k1) != LtiOK) return LtiError;
        if (LTI_CS_METHOD == CsEuler) {
            for (i = 0; i < n; i++) z[i] += dt * k1[i];
            continue;
        }
        for (i = 0; i < n; i++) zt[i] = z[i] + 0.5 * dt * k1[i];
        if (rate(inst, zt, k2) != LtiOK) return LtiError;
        for (i = 0; i < n; i++) zt[i] = z[i] + 0.5 * dt * k2[i];
        if (rate(inst, zt, k3) != LtiOK) return LtiError;
        for (i = 0; i < n; i++) zt[i] = z[i] + dt * k3[i];
        if (rate(inst, zt, k4) != LtiOK) return LtiError;
        for (i = 0; i < n; i++) z[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
    }
    return LtiOK;
}

/* The time event comes: its force on, and its velocity jump (if any) added to qd. */
static void timeEventOn(LtiInstance *inst) {
    size_t i;
    inst->timeEventOn = 1;
    if (LTI_TIME_EVENT_JUMP) for (i = 0; i < inst->nq; i++) inst->z[inst->nq + i] += LTI_TIME_EVENT_DQD[i];
    inst->upToDate = 0;
}

/* Co-simulation step.  Its time event is met exactly (the step is split there, and a step that ends
   at the event up to rounding ends after it); its state event is only looked at when the step ends,
   as simple exporters do (the latched force starts at the communication point after the crossing). */
LtiStatus ltiDoStep(LtiInstance *inst, double t, double h) {
    double end = t + h, slack = 1e-12 * h + 4.0 * DBL_EPSILON * fabs(end);
    int timeEventDue = LTI_TIME_EVENT && !inst->timeEventOn && LTI_TIME_EVENT_AT <= end + slack;

    if (h < 0.0 || !isfinite(h)) {
        ltiLog(inst, LtiError, "logStatusError", "fmiDoStep: step size %g is invalid", h);
        return LtiError;
    }
    if (LTI_CS_FIXED_STEP > 0.0 && fabs(h - LTI_CS_FIXED_STEP) > 1e-12 * LTI_CS_FIXED_STEP) {
        ltiLog(inst, LtiError, "logStatusError",
               "fmiDoStep: communication step %.17g differs from the fixed step %g", h, LTI_CS_FIXED_STEP);
        return LtiError;
    }
    if (LTI_CS_MAX_STEP > 0.0 && h > LTI_CS_MAX_STEP) {
        ltiLog(inst, LtiDiscard, "logStatusError",
               "fmiDoStep: step size %g exceeds the maximum step size %g of the embedded solver", h,
               LTI_CS_MAX_STEP);
        return LtiDiscard;
    }
    if (fabs(t - inst->time) > 1e-9 * (1.0 + fabs(t))) {
        ltiLog(inst, LtiError, "logStatusError",
               "fmiDoStep: communication point %.17g differs from the FMU time %.17g", t,
               inst->time);
        return LtiError;
    }
    if (LTI_STALE_DERIVATIVES) {   /* an exporter's defect, on request: der() read after the step is stale */
        if (ltiEvaluate(inst, "fmiDoStep") != LtiOK) return LtiError;
        memcpy(inst->qddBefore, inst->qdd, inst->nq * sizeof(double));
    }
    if (LTI_LATE_OUTPUTS) {   /* an exporter's defect, on request: outputs computed before the step only */
        if (ltiEvaluate(inst, "fmiDoStep") != LtiOK) return LtiError;
        memcpy(inst->yBefore, inst->y, LTI_NY * sizeof(double));
    }
    if (timeEventDue && LTI_TIME_EVENT_AT > t + slack && LTI_TIME_EVENT_AT < end - slack) {
        if (integrate(inst, LTI_TIME_EVENT_AT - t) != LtiOK) return LtiError;
        timeEventOn(inst);
        if (integrate(inst, end - LTI_TIME_EVENT_AT) != LtiOK) return LtiError;
    } else {
        if (integrate(inst, h) != LtiOK) return LtiError;
        if (timeEventDue) timeEventOn(inst);
    }
    inst->time = end;
    inst->upToDate = 0;
    inst->stale = LTI_STALE_DERIVATIVES;
    inst->late = LTI_LATE_OUTPUTS;
    if (LTI_STATE_EVENT) ltiUpdateDiscrete(inst, NULL, NULL);
    return LtiOK;
}

/* ------------------------------------------------------------------- events */

size_t ltiEventIndicatorCount(void) {
    return LTI_STATE_EVENT ? 1 : 0;
}

LtiStatus ltiEventIndicators(LtiInstance *inst, const char *function, double values[], size_t n) {
    if (n != ltiEventIndicatorCount()) {
        ltiLog(inst, LtiError, "logStatusError", "%s: %lu event indicators, expected %lu", function,
               (unsigned long)n, (unsigned long)ltiEventIndicatorCount());
        return LtiError;
    }
    if (n) values[0] = indicator(inst, inst->z);
    return LtiOK;
}

/* Event mode: the time event switches its force on once its time has come; a change of sign of the
   indicator since the last event latches the state event's force on.  No update is ever needed twice. */
int ltiUpdateDiscrete(LtiInstance *inst, int *nextDefined, double *nextTime) {
    int pending, statesChanged = 0;
    if (LTI_TIME_EVENT && !inst->timeEventOn && inst->time >= LTI_TIME_EVENT_AT) {
        timeEventOn(inst);
        statesChanged = LTI_TIME_EVENT_JUMP;
    }
    if (LTI_STATE_EVENT) {
        int above = indicator(inst, inst->z) > 0.0;
        if (above != inst->indicatorAbove && !inst->stateEventOn) {
            inst->stateEventOn = 1;
            inst->upToDate = 0;
        }
        inst->indicatorAbove = above;
    }
    pending = LTI_TIME_EVENT && !inst->timeEventOn;
    if (nextDefined) *nextDefined = pending;
    if (nextTime) *nextTime = pending ? LTI_TIME_EVENT_AT : 0.0;
    return statesChanged;
}

/* A model that ends its simulation at a time event, as Modelica's `when time >= T then terminate("...")` does: the
   event iteration at T asks to terminate and logs the model's message; before T the event is announced. */
int ltiTerminateEvent(LtiInstance *inst, int *nextDefined, double *nextTime) {
    if (!LTI_ME_TERMINATE) return 0;
    if (inst->time >= LTI_ME_TERMINATE_AT - 1e-12 * (1.0 + fabs(LTI_ME_TERMINATE_AT))) {
        ltiLog(inst, LtiDiscard, "logEvents", "terminate() called at t=%g: end of the test track", inst->time);
        return 1;
    }
    if (!*nextDefined || *nextTime > LTI_ME_TERMINATE_AT) {
        *nextDefined = 1;
        *nextTime = LTI_ME_TERMINATE_AT;
    }
    return 0;
}

/* A model whose stop is checked in its accepted integrator steps: the first completed step at or after
   LTI_COMPLETED_TERMINATE_AT asks to terminate, wherever the importer's integrator put it. */
int ltiCompletedTerminate(LtiInstance *inst) {
    if (!LTI_COMPLETED_TERMINATE || inst->time < LTI_COMPLETED_TERMINATE_AT) return 0;
    ltiLog(inst, LtiDiscard, "logEvents", "terminate() called at t=%.9g: the end stop is reached", inst->time);
    return 1;
}

/* End of initialization: the indicator's sign there is the reference of the first crossing. */
LtiStatus ltiSetTime(LtiInstance *inst, const char *function, double time) {
    if (LTI_COMPLETED_GAP > 0.0 && (inst->phase & PhaseContinuous) &&
        time - inst->timeCompleted > LTI_COMPLETED_GAP) {
        ltiLog(inst, LtiError, "logStatusError",
               "%s: buffer overrun: CompletedIntegratorStep not called since t=%g (now t=%g)", function,
               inst->timeCompleted, time);
        return LtiError;
    }
    if (LTI_COMPLETED_GAP > 0.0 && (inst->phase & PhaseContinuous) &&
        time < inst->timeCompleted - 1e-12 * (1.0 + fabs(time))) {
        ltiLog(inst, LtiError, "logStatusError",
               "%s: time %.17g is before the last completed integrator step at t=%.17g, which is never taken back",
               function, time, inst->timeCompleted);
        return LtiError;
    }
    inst->time = time;
    inst->upToDate = 0;
    return LtiOK;
}

int ltiCompletedStep(LtiInstance *inst) {
    inst->timeCompleted = inst->time;
    if (LTI_COMPLETED_EVENT && (LTI_COMPLETED_EVENT_EVERY || !inst->completedEventAsked)
        && inst->time >= LTI_COMPLETED_EVENT_AT) {
        inst->completedEventAsked = 1;
        return 1;
    }
    return 0;
}

void ltiEnterContinuousMode(LtiInstance *inst) {
    inst->phase = PhaseContinuous;
    inst->timeCompleted = inst->time;
}

void ltiExitInitialization(LtiInstance *inst) {
    if (LTI_STEADY_START) {
        size_t i, j, nq = inst->nq;
        for (i = 0; i < nq; i++) {
            double q = LTI_STEADY_Q0[i];
            if (!LTI_ENABLE_INPUT || inst->enabled)
                for (j = 0; j < LTI_NU; j++) q += LTI_STEADY_QU[i * LTI_NU + j] * inst->u[j];
            inst->z[i] = q;
            inst->z[nq + i] = 0.0;
        }
        inst->upToDate = 0;
    }
}

void ltiStartEvents(LtiInstance *inst) {
    if (LTI_STATE_EVENT) inst->indicatorAbove = indicator(inst, inst->z) > 0.0;
}

/* The Boolean behind vr (the enable input or the Boolean parameter); logs the error of the calling function and
   returns NULL where there is none. */
static int *booleanOf(LtiInstance *inst, const char *function, unsigned int vr) {
    if (LTI_ENABLE_INPUT && vr == LTI_ENABLE_VR) return &inst->enabled;
    if (LTI_DISCRETE_PARAMETERS && vr == LTI_CACHE_VR) return &inst->cache;
    ltiLog(inst, LtiError, "logStatusError", "%s: no Boolean variable has value reference %u", function, vr);
    return NULL;
}

LtiStatus ltiGetBoolean(LtiInstance *inst, const char *function, const unsigned int vr[], size_t nvr, int values[]) {
    size_t i;
    for (i = 0; i < nvr; i++) {
        int *target = booleanOf(inst, function, vr[i]);
        if (!target) return LtiError;
        values[i] = *target;
    }
    return LtiOK;
}

LtiStatus ltiSetBoolean(LtiInstance *inst, const char *function, const unsigned int vr[], size_t nvr,
                        const int values[]) {
    size_t i;
    for (i = 0; i < nvr; i++) {
        int *target = booleanOf(inst, function, vr[i]);
        if (!target) return LtiError;
        *target = values[i] != 0;
        inst->upToDate = 0;
    }
    return LtiOK;
}

/* The integer behind vr of the kinds a function serves (LTI_INTEGER, LTI_ENUMERATION); logs the error of the
   calling function and returns NULL where there is none. */
static int *integerOf(LtiInstance *inst, const char *function, int kinds, unsigned int vr) {
    if ((kinds & LTI_INTEGER) && LTI_DISCRETE_PARAMETERS && vr == LTI_ORDER_VR) return &inst->order;
    if ((kinds & LTI_ENUMERATION) && LTI_TYPED_PARAMETERS && vr == LTI_METHOD_VR) return &inst->method;
    ltiLog(inst, LtiError, "logStatusError", "%s: no %s variable has value reference %u", function,
           kinds == LTI_ENUMERATION ? "Enumeration" : "Integer", vr);
    return NULL;
}

LtiStatus ltiGetInteger(LtiInstance *inst, const char *function, int kinds, const unsigned int vr[], size_t nvr,
                        int values[]) {
    size_t i;
    for (i = 0; i < nvr; i++) {
        int *source = integerOf(inst, function, kinds, vr[i]);
        if (!source) return LtiError;
        values[i] = *source;
    }
    return LtiOK;
}

LtiStatus ltiSetInteger(LtiInstance *inst, const char *function, int kinds, const unsigned int vr[], size_t nvr,
                        const int values[]) {
    size_t i;
    for (i = 0; i < nvr; i++) {
        int *target = integerOf(inst, function, kinds, vr[i]);
        if (!target) return LtiError;
        if (target == &inst->method && (values[i] < 1 || values[i] > LTI_METHOD_ITEMS)) {
            ltiLog(inst, LtiError, "logStatusError", "%s: %d is not the value of an item of the Enumeration at value "
                   "reference %u (1 .. %d)", function, values[i], vr[i], LTI_METHOD_ITEMS);
            return LtiError;
        }
        *target = values[i];
    }
    return LtiOK;
}

int ltiIsTolerance(unsigned int vr) {
    return LTI_TYPED_PARAMETERS && vr == LTI_TOLERANCE_VR;
}

void ltiSetStopTime(LtiInstance *inst, int defined, double stopTime) {
    inst->stopDefined = defined;
    inst->stopTime = stopTime;
}

LtiStatus ltiCheckStopTime(LtiInstance *inst, const char *function, double time) {
    if (!LTI_STRICT_STOP || !inst->stopDefined || time <= inst->stopTime) return LtiOK;
    ltiLog(inst, LtiError, "logStatusError", "%s: t=%.17g passes the stop time %.17g", function, time,
           inst->stopTime);
    return LtiError;
}
