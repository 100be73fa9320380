/*
 * Version-independent co-simulation instance (see instance.h).
 */
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "instance.h"

#define MESSAGE_LENGTH 1024
#define STEP_SIZE_TOLERANCE 1e-12

static const double parameterDefaults[ARRAY_LENGTH(N_PARAMETERS)] = PARAMETER_DEFAULTS;

/* start values of the inputs (the source FMU's, for an exported ROM); zeros unless the configuration says */
#ifndef INPUT_STARTS
#define INPUT_STARTS { 0.0 }
#endif
static const double inputStarts[ARRAY_LENGTH(N_INPUTS)] = INPUT_STARTS;

/* declared [min, max] of the inputs (an exported ROM's: the range of the source it was trained on); an FMU
 * without them checks no range */
#ifdef INPUT_HELD
/* Inputs the model was made for at one value only (a ROM's inputs that its training held; their min = max). */
static const int inputHeld[ARRAY_LENGTH(N_INPUTS)] = INPUT_HELD;
static const char *const inputNames[ARRAY_LENGTH(N_INPUTS)] = INPUT_NAMES;
#endif
#ifdef PARAMETERS_FIXED
/* Parameters the model was made for at their start values only (an exported ROM's source parameters). */
static const char *const parameterNames[ARRAY_LENGTH(N_PARAMETERS)] = PARAMETER_NAMES;
#define FIXED_PARAMETER_TOLERANCE 1e-12
#endif
#ifdef PARAMETER_KINDS
/* The FMI type of each parameter (VariableKind); without the table every parameter is a Float64. */
static const int parameterKinds[ARRAY_LENGTH(N_PARAMETERS)] = PARAMETER_KINDS;
#define PARAMETER_KIND(index) ((VariableKind)parameterKinds[index])
#else
#define PARAMETER_KIND(index) KindFloat64
#endif
static const char *const kindNames[] = {"Float64", "Float32", "Int8", "UInt8", "Int16", "UInt16",
                                        "Int32 (FMI 2 Integer)", "UInt32", "Int64", "UInt64", "Boolean"};
#ifdef INPUT_MIN
static const double inputMin[ARRAY_LENGTH(N_INPUTS)] = INPUT_MIN;
static const double inputMax[ARRAY_LENGTH(N_INPUTS)] = INPUT_MAX;
#endif

/* ------------------------------------------------------------------- logging */

static void logFormatted(const ModelInstance *instance, Status status, const char *category,
                         const char *format, va_list args) {
    char message[MESSAGE_LENGTH];

    if (!instance || !instance->log) {
        return;
    }

    vsnprintf(message, sizeof(message), format, args);
    instance->log(instance, status, category, message);
}

void logError(const ModelInstance *instance, const char *format, ...) {
    va_list args;

    va_start(args, format);
    logFormatted(instance, Error, "logStatusError", format, args);
    va_end(args);
}

void logEvent(const ModelInstance *instance, const char *format, ...) {
    va_list args;

    if (!instance || !instance->loggingOn) {
        return;
    }

    va_start(args, format);
    logFormatted(instance, OK, "logEvents", format, args);
    va_end(args);
}

/* -------------------------------------------------------------------- checks */

Status checkState(const ModelInstance *instance, const char *function, int allowed) {
    if (!instance) {
        return Error;
    }
    if (!(instance->current.state & allowed)) {
        logError(instance, "%s must not be called in the current state (0x%x)", function,
                 (unsigned)instance->current.state);
        return Error;
    }
    return OK;
}

Status checkNotNull(const ModelInstance *instance, const char *function, const void *pointer,
                    const char *argument) {
    if (!pointer) {
        logError(instance, "%s: argument %s must not be NULL", function, argument);
        return Error;
    }
    return OK;
}

Status finishCall(ModelInstance *instance, Status status) {
    if (instance && status == Error) {
        instance->current.state = ErrorState;
    } else if (instance && status == Fatal) {
        instance->current.state = FatalState;
    }
    return status;
}

/* --------------------------------------------------------------- the system */

static void releaseSystem(ModelInstance *instance) {
    if (instance->systemReady) {
        freeNewmarkSolver(&instance->solver, &instance->allocator);
        freeSecondOrderSystem(&instance->system, &instance->allocator);
        instance->systemReady = 0;
    }
}

static Status ensureSystem(ModelInstance *instance) {
    const char *message = "unknown problem";
    Status status;

    if (instance->systemReady) {
        return OK;
    }

    status = assembleSecondOrderSystem(&instance->system, instance->current.parameters,
                                       &instance->allocator, &message);
    if (status > Warning) {
        logError(instance, "cannot assemble the system: %s", message);
        return status;
    }

    if (allocateNewmarkSolver(&instance->solver, &instance->system, &instance->allocator) != OK) {
        freeNewmarkSolver(&instance->solver, &instance->allocator);
        freeSecondOrderSystem(&instance->system, &instance->allocator);
        logError(instance, "out of memory while allocating the Newmark solver");
        return Error;
    }

    instance->systemReady = 1;
    logEvent(instance, "assembled the system matrices (n = %d)", N_DOF);
    return OK;
}

static Status ensureInitialAcceleration(ModelInstance *instance) {
    const char *message = "unknown problem";
    Status status = OK;

    CALL(ensureSystem(instance));

    if (instance->current.accelerationPending) {
        if (instance->current.stepCount == 0 && (instance->current.state & (Instantiated | InitializationMode))) {
            /* the start is fixed when initialization ends (exitInitialization comes here first): an input set
             * after it, before the first step, changes the acceleration, not the start */
            initialState(&instance->system, instance->current.u, instance->current.x, instance->current.v);
        }
        status = initialAcceleration(&instance->solver, &instance->system, instance->current.u,
                                     instance->current.x, instance->current.v, instance->current.a,
                                     &instance->allocator, &message);
        if (status > Warning) {
            logError(instance, "cannot compute the consistent initial acceleration: %s", message);
            goto END;
        }
        memcpy(instance->current.uApplied, instance->current.u, sizeof(instance->current.u));
        instance->current.accelerationPending = 0;
        computeOutputs(&instance->system, instance->current.x, instance->current.v, instance->current.u,
                       instance->y);
    }

END:
    return status;
}

/* Make the acceleration consistent with the input currently held (as the reference does). */
static Status ensureInputApplied(ModelInstance *instance) {
    const char *message = "unknown problem";
    Status status = OK;

    CALL(ensureInitialAcceleration(instance));

    if (memcmp(instance->current.uApplied, instance->current.u, sizeof(instance->current.u)) != 0) {
        status = applyInputChange(&instance->solver, &instance->system, instance->current.uApplied,
                                  instance->current.u, instance->current.a, &instance->allocator,
                                  &message);
        if (status > Warning) {
            logError(instance, "cannot apply the new input: %s", message);
            goto END;
        }
        memcpy(instance->current.uApplied, instance->current.u, sizeof(instance->current.u));
    }

END:
    return status;
}

/* -------------------------------------------------------- life cycle */

static double *allocateVector(const ModelInstance *instance) {
    return (double *)instance->allocator.allocate((size_t)N_DOF, sizeof(double));
}

static void freeDynamicArrays(const ModelInstance *instance, DynamicState *state) {
    instance->allocator.release(state->x);
    instance->allocator.release(state->v);
    instance->allocator.release(state->a);
    state->x = NULL;
    state->v = NULL;
    state->a = NULL;
}

static void resetDynamicState(ModelInstance *instance) {
    size_t bytes = (size_t)N_DOF * sizeof(double);
    int i;

    instance->current.time = 0.0;
    instance->current.stepCount = 0;
    instance->current.accelerationPending = 1;
    for (i = 0; i < N_PARAMETERS; i++) {
        instance->current.parameters[i] = parameterDefaults[i];
    }
    for (i = 0; i < ARRAY_LENGTH(N_INPUTS); i++) {
        instance->current.u[i] = inputStarts[i];
        instance->current.uApplied[i] = inputStarts[i];
    }
    for (i = 0; i < ARRAY_LENGTH(N_OUTPUTS); i++) {
        instance->y[i] = 0.0;
    }
    memset(instance->current.x, 0, bytes);
    memset(instance->current.v, 0, bytes);
    memset(instance->current.a, 0, bytes);
    instance->startTime = 0.0;
    instance->stopTime = 0.0;
    instance->stopTimeDefined = 0;
}

ModelInstance *createInstance(const char *instanceName, const char *token,
                              const Allocator *allocator, LogFunction log, GenericFunction logger,
                              void *environment, int loggingOn) {
    ModelInstance probe;
    ModelInstance *instance;
    size_t length;

    memset(&probe, 0, sizeof(probe));
    probe.log = log;
    probe.logger = logger;
    probe.environment = environment;
    probe.instanceName = (char *)(instanceName ? instanceName : "");

    if (!instanceName || instanceName[0] == '\0') {
        logError(&probe, "instantiate: missing instance name");
        return NULL;
    }
    if (!token || strcmp(token, INSTANTIATION_TOKEN) != 0) {
        logError(&probe, "instantiate: wrong GUID / instantiation token \"%s\", expected \"%s\"",
                 token ? token : "(null)", INSTANTIATION_TOKEN);
        return NULL;
    }

    instance = (ModelInstance *)allocator->allocate(1, sizeof(ModelInstance));
    if (!instance) {
        logError(&probe, "instantiate: out of memory");
        return NULL;
    }

    instance->log = log;
    instance->logger = logger;
    instance->environment = environment;
    instance->allocator = *allocator;
    instance->loggingOn = loggingOn ? 1 : 0;

    length = strlen(instanceName) + 1;
    instance->instanceName = (char *)allocator->allocate(length, sizeof(char));
    instance->current.x = allocateVector(instance);
    instance->current.v = allocateVector(instance);
    instance->current.a = allocateVector(instance);

    if (!instance->instanceName || !instance->current.x || !instance->current.v ||
        !instance->current.a) {
        logError(&probe, "instantiate: out of memory");
        freeDynamicArrays(instance, &instance->current);
        allocator->release(instance->instanceName);
        allocator->release(instance);
        return NULL;
    }

    memcpy(instance->instanceName, instanceName, length);
    resetDynamicState(instance);
    instance->current.state = Instantiated;
    logEvent(instance, "instantiated %s (n = %d, m = %d, p = %d, nc = %d)", MODEL_IDENTIFIER,
             N_DOF, N_INPUTS, N_OUTPUTS, N_CONSTRAINTS);
    return instance;
}

void freeInstance(ModelInstance *instance) {
    void (*release)(void *) = instance->allocator.release;

    releaseSystem(instance);
    freeDynamicArrays(instance, &instance->current);
    release(instance->instanceName);
    release(instance);
}

Status setDebugLogging(ModelInstance *instance, const char *function, int loggingOn,
                       size_t nCategories, const char *const categories[]) {
    size_t i;

    if (nCategories > 0 && checkNotNull(instance, function, categories, "categories") != OK) {
        return Error;
    }

    for (i = 0; i < nCategories; i++) {
        if (!categories[i] || (strcmp(categories[i], "logEvents") != 0 &&
                               strcmp(categories[i], "logStatusError") != 0)) {
            logError(instance, "%s: unknown log category \"%s\"", function,
                     categories[i] ? categories[i] : "(null)");
            return Error;
        }
    }

    instance->loggingOn = loggingOn ? 1 : 0;
    return OK;
}

Status setupExperiment(ModelInstance *instance, double startTime, int stopTimeDefined,
                       double stopTime) {
    if (!isfinite(startTime) || (stopTimeDefined && (!isfinite(stopTime) || stopTime < startTime))) {
        logError(instance, "invalid start time %g or stop time %g", startTime, stopTime);
        return Error;
    }

    instance->startTime = startTime;
    instance->current.time = startTime;
    instance->stopTimeDefined = stopTimeDefined ? 1 : 0;
    instance->stopTime = stopTime;
    return OK;
}

Status exitInitialization(ModelInstance *instance) {
    Status status = ensureInitialAcceleration(instance);

    if (status <= Warning) {
        instance->current.state = StepComplete;
    }
    return status;
}

void resetInstance(ModelInstance *instance) {
    releaseSystem(instance);
    resetDynamicState(instance);
    instance->current.state = Instantiated;
    logEvent(instance, "reset to the instantiated state");
}

/* ------------------------------------------------------------ variables */

/* A parameter of an integer or Boolean type is reached through its own functions only (FMI: the get/set function
 * of a variable's type), not as a real. */
static Status checkRealParameter(const ModelInstance *instance, const char *function, unsigned int r) {
    VariableKind kind = PARAMETER_KIND(r - VR_PARAMETERS);

    if (kind != KindFloat64 && kind != KindFloat32) {
        logError(instance, "%s: value reference %u is a parameter of type %s; use the get/set functions of that "
                 "type", function, r, kindNames[kind]);
        return Error;
    }
    return OK;
}

Status getFloat64(ModelInstance *instance, const char *function, const unsigned int vr[],
                  size_t nvr, double value[]) {
    Status status = OK;
    size_t i;

    if (nvr == 0) {
        return OK;
    }
    CALL(checkNotNull(instance, function, vr, "vr"));
    CALL(checkNotNull(instance, function, value, "value"));

    if (instance->current.state & (InitializationMode | StepComplete)) {
        CALL(ensureInputApplied(instance));
    }
    for (i = 0; i < nvr && instance->systemReady; i++) {
        if (vr[i] >= VR_POSITIONS && vr[i] < VR_END) {  /* states: rebuild them from a modal state */
            syncPhysicalState(&instance->solver, &instance->system, instance->current.x, instance->current.v,
                              instance->current.a);
            break;
        }
    }

    for (i = 0; i < nvr; i++) {
        unsigned int r = vr[i];
        if (r == VR_TIME) {
            value[i] = instance->current.time;
        } else if (r >= VR_INPUTS && r < VR_OUTPUTS) {
            value[i] = instance->current.u[r - VR_INPUTS];
        } else if (r >= VR_OUTPUTS && r < VR_PARAMETERS) {
            value[i] = instance->y[r - VR_OUTPUTS];
        } else if (r >= VR_PARAMETERS && r < VR_POSITIONS) {
            CALL(checkRealParameter(instance, function, r));
            value[i] = instance->current.parameters[r - VR_PARAMETERS];
        } else if (r >= VR_POSITIONS && r < VR_VELOCITIES) {
            value[i] = instance->current.x[r - VR_POSITIONS];
        } else if (r >= VR_VELOCITIES && r < VR_ACCELERATIONS) {
            value[i] = instance->current.v[r - VR_VELOCITIES];
        } else if (r >= VR_ACCELERATIONS && r < VR_END) {
            value[i] = instance->current.a[r - VR_ACCELERATIONS];
        } else {
            logError(instance, "%s: unknown value reference %u", function, r);
            status = Error;
            goto END;
        }
    }

END:
    return status;
}

#ifdef PARAMETERS_FIXED
/* Whether value is the parameter's trained one: bit-equal, a real one within a relative FIXED_PARAMETER_TOLERANCE,
 * a Float32 one equal as a float (an importer sets the float nearest to the declared start, 6e-8 off the double). */
static int isTrainedValue(int index, double value) {
    double trained = parameterDefaults[index];

    if (value == trained) {
        return 1;
    }
    if (PARAMETER_KIND(index) == KindFloat32) {
        return (float)value == (float)trained;
    }
    return PARAMETER_KIND(index) == KindFloat64 && fabs(value - trained) <= FIXED_PARAMETER_TOLERANCE * fabs(trained);
}

/* A parameter's value as its log line shows it: true / false for a Boolean, all digits of a float or a double. */
static void shownValue(VariableKind kind, double value, char text[32]) {
    if (kind == KindBoolean) {
        snprintf(text, 32, "%s", value != 0.0 ? "true" : "false");
    } else if (kind == KindFloat32) {
        snprintf(text, 32, "%.9g", value);
    } else {
        snprintf(text, 32, "%.17g", value);
    }
}
#endif

static Status setParameter(ModelInstance *instance, const char *function, unsigned int r,
                           double value) {
    int index = (int)(r - VR_PARAMETERS);

    if (!(instance->current.state & (Instantiated | InitializationMode))) {
        logError(instance, "%s: parameter with value reference %u is fixed after initialization",
                 function, r);
        return Error;
    }

#ifdef PARAMETERS_FIXED
    /* an exported ROM: made for the parameters' training values only (its source's, --set ones included) */
    if (!isTrainedValue(index, value)) {
        char trained[32], given[32];
        shownValue(PARAMETER_KIND(index), parameterDefaults[index], trained);
        shownValue(PARAMETER_KIND(index), value, given);
        logError(instance, "%s: parameter %s (value reference %u) was %s in training, the only value the model "
                 "knows; %s refused: set it to %s or leave it, or record the snapshots and fit again with "
                 "--set %s=VALUE or parameters['%s']", function, parameterNames[index], r, trained, given, trained,
                 parameterNames[index], parameterNames[index]);
        return Error;
    }
    return OK;   /* the trained value stays, bit-equal */
#endif
    if (instance->current.parameters[index] != value) {
        instance->current.parameters[index] = value;
        instance->current.accelerationPending = 1;
        releaseSystem(instance);
    }

    return OK;
}

/* A value for an input outside its declared [min, max] is an error (FMI: setting a value outside the range is
 * not allowed, and an FMU may report it); the source FMUs that declare ranges refuse such values too. */
static Status checkInputRange(const ModelInstance *instance, const char *function, int input, unsigned int r,
                              double value) {
#ifdef INPUT_HELD
    if (inputHeld[input] && value != inputMin[input]) {
        logError(instance, "%s: input %s (value reference %u) was held at %.17g in training, the only value the "
                 "model knows; %.17g refused: set it to %.17g or leave it, or train with this input driven",
                 function, inputNames[input], r, inputMin[input], value, inputMin[input]);
        return Error;
    }
#endif
#ifdef INPUT_MIN
    if (value < inputMin[input] || value > inputMax[input]) {
        logError(instance, "%s: value %.17g of input %d (value reference %u) is outside its declared range "
                 "[%g, %g], the range the model accepts (a ROM: the range its source declared and it was "
                 "trained in)", function, value, input + 1, r, inputMin[input], inputMax[input]);
        return Error;
    }
#else
    (void)instance; (void)function; (void)input; (void)r; (void)value;
#endif
    return OK;
}

Status setFloat64(ModelInstance *instance, const char *function, const unsigned int vr[],
                  size_t nvr, const double value[]) {
    Status status = OK;
    size_t i;

    if (nvr == 0) {
        return OK;
    }
    CALL(checkNotNull(instance, function, vr, "vr"));
    CALL(checkNotNull(instance, function, value, "value"));

    for (i = 0; i < nvr; i++) {
        unsigned int r = vr[i];

        if (!isfinite(value[i])) {
            logError(instance, "%s: value of value reference %u is not finite", function, r);
            status = Error;
            goto END;
        }

        if (r >= VR_INPUTS && r < VR_OUTPUTS) {
            int input = (int)(r - VR_INPUTS);
            double change = value[i] - instance->current.u[input];
            CALL(checkInputRange(instance, function, input, r, value[i]));
            instance->current.u[input] = value[i];
            if (instance->current.stepCount == 0) {
                instance->current.accelerationPending = 1;
            } else if (change != 0.0 && instance->systemReady) {
                /* the outputs read before the next step see the new input through the feedthrough */
                addFeedthroughChange(&instance->system, input, change, instance->y);
            }
        } else if (r >= VR_PARAMETERS && r < VR_POSITIONS) {
            CALL(checkRealParameter(instance, function, r));
            CALL(setParameter(instance, function, r, value[i]));
        } else if (r == VR_TIME || (r >= VR_OUTPUTS && r < VR_END)) {
            logError(instance, "%s: variable with value reference %u cannot be set", function, r);
            status = Error;
            goto END;
        } else {
            logError(instance, "%s: unknown value reference %u", function, r);
            status = Error;
            goto END;
        }
    }

END:
    return status;
}

/* Whether r is a parameter of this kind; logs the error of the calling function where it is not. */
static int isParameterOf(const ModelInstance *instance, const char *function, VariableKind kind, unsigned int r) {
    if (r >= VR_PARAMETERS && r < VR_POSITIONS && PARAMETER_KIND(r - VR_PARAMETERS) == kind) {
        return 1;
    }
    logError(instance, "%s: no %s variable has value reference %u", function, kindNames[kind], r);
    return 0;
}

Status getParameters(ModelInstance *instance, const char *function, VariableKind kind, const unsigned int vr[],
                     size_t nvr, double value[]) {
    Status status = OK;
    size_t i;

    if (nvr == 0) {
        return OK;
    }
    CALL(checkNotNull(instance, function, vr, "vr"));
    CALL(checkNotNull(instance, function, value, "value"));
    for (i = 0; i < nvr; i++) {
        if (!isParameterOf(instance, function, kind, vr[i])) {
            status = Error;
            goto END;
        }
        value[i] = instance->current.parameters[vr[i] - VR_PARAMETERS];
    }

END:
    return status;
}

Status setParameters(ModelInstance *instance, const char *function, VariableKind kind, const unsigned int vr[],
                     size_t nvr, const double value[]) {
    Status status = OK;
    size_t i;

    if (nvr == 0) {
        return OK;
    }
    CALL(checkNotNull(instance, function, vr, "vr"));
    CALL(checkNotNull(instance, function, value, "value"));
    for (i = 0; i < nvr; i++) {
        if (!isParameterOf(instance, function, kind, vr[i])) {
            status = Error;
            goto END;
        }
        CALL(setParameter(instance, function, vr[i], value[i]));
    }

END:
    return status;
}

/* ------------------------------------------------------------- stepping */

static Status checkStepArguments(const ModelInstance *instance, const char *function, double point,
                                 double h) {
    double tolerance = 1e-9 * fmax(1.0, fabs(instance->current.time));

    if (!isfinite(h) || !(h > 0.0)) {
        logError(instance, "%s: communication step size %g must be positive and finite", function, h);
        return Error;
    }
    if (!isfinite(point) || fabs(point - instance->current.time) > tolerance) {
        logError(instance, "%s: communication point %.17g does not match the model time %.17g",
                 function, point, instance->current.time);
        return Error;
    }
    if (instance->stopTimeDefined && point + h > instance->stopTime + tolerance) {
        logError(instance, "%s: step to %.17g passes the stop time %.17g", function, point + h,
                 instance->stopTime);
        return Error;
    }
    return OK;
}

/* Round-off of a step size h computed as a difference of times near point, around a step size reference. */
static double stepRoundOff(double point, double h, double reference) {
    return STEP_SIZE_TOLERANCE * reference + 8.0 * DBL_EPSILON * (fabs(point) + fabs(h));
}

Status doStep(ModelInstance *instance, const char *function, double point, double h) {
    const char *message = "unknown problem";
    Status status = OK;
    long substeps = 1, i;

    CALL(checkStepArguments(instance, function, point, h));
    CALL(ensureInputApplied(instance));

    /* Importers compute h as a difference of times; a step within round-off of the factored
     * one is that step (avoids refactoring S for every last-bit change of h). */
    if (fabs(h - instance->solver.stepSize) <= stepRoundOff(point, h, instance->solver.stepSize)) {
        h = instance->solver.stepSize;
    }
    if (stepMapSize(&instance->system) > 0.0) {
        /* the exact step map holds the input over one map step: a multiple of it is that many map steps */
        double mapStep = stepMapSize(&instance->system);
        double count = floor(h / mapStep + 0.5);
        if (count < 1.0 || count > 1e9 || fabs(h - count * mapStep) > count * stepRoundOff(point, h, mapStep)) {
            logError(instance, "%s: this model steps with multiples of h = %.17g only (its exact step map), got "
                     "h = %.17g; use such a communication step, or export the ROM again with --step h or step=h",
                     function, mapStep, h);
            return Error;
        }
        substeps = (long)count;
        h = mapStep;
    }

    if (instance->solver.stepSize != h) {
        status = prepareStep(&instance->solver, &instance->system, h, &instance->allocator, &message);
        if (status > Warning) {
            logError(instance, "%s: cannot factor the step matrix for h = %g: %s", function, h,
                     message);
            goto END;
        }
        logEvent(instance, "factored the step matrix for h = %g", h);
    }

    for (i = 0; i < substeps; i++) {
        newmarkStep(&instance->solver, &instance->system, h, instance->current.u, instance->current.x,
                    instance->current.v, instance->current.a);
    }

    if (!stepIsFinite(&instance->solver, &instance->system, instance->current.a)) {
        logError(instance, "%s: the solution is not finite at t = %g", function, point + substeps * h);
        status = Error;
        goto END;
    }

    instance->current.time = point + substeps * h;
    instance->current.stepCount++;
    computeStepOutputs(&instance->solver, &instance->system, instance->current.x, instance->current.v,
                       instance->current.u, instance->y);

END:
    return status;
}

/* ------------------------------------------------------------ FMU state */

static void copyDynamicState(DynamicState *target, const DynamicState *source) {
    size_t bytes = (size_t)N_DOF * sizeof(double);
    double *x = target->x, *v = target->v, *a = target->a;

    *target = *source;
    target->x = x;
    target->v = v;
    target->a = a;
    memcpy(target->x, source->x, bytes);
    memcpy(target->v, source->v, bytes);
    memcpy(target->a, source->a, bytes);
}

static DynamicState *allocateDynamicState(const ModelInstance *instance) {
    DynamicState *state = (DynamicState *)instance->allocator.allocate(1, sizeof(DynamicState));

    if (!state) {
        return NULL;
    }

    state->x = allocateVector(instance);
    state->v = allocateVector(instance);
    state->a = allocateVector(instance);

    if (!state->x || !state->v || !state->a) {
        freeDynamicArrays(instance, state);
        instance->allocator.release(state);
        return NULL;
    }

    return state;
}

Status getState(ModelInstance *instance, const char *function, void **state) {
    DynamicState *snapshot;

    if (checkNotNull(instance, function, state, "FMUstate") != OK) {
        return Error;
    }

    snapshot = (DynamicState *)*state;
    if (!snapshot) {
        snapshot = allocateDynamicState(instance);
        if (!snapshot) {
            logError(instance, "%s: out of memory", function);
            return Error;
        }
    }

    if (instance->systemReady) {
        syncPhysicalState(&instance->solver, &instance->system, instance->current.x, instance->current.v,
                          instance->current.a);
    }
    copyDynamicState(snapshot, &instance->current);
    *state = snapshot;
    return OK;
}

static int sameParameters(const double first[], const double second[]) {
    int i;
    for (i = 0; i < N_PARAMETERS; i++) {
        if (first[i] != second[i]) {
            return 0;
        }
    }
    return 1;
}

Status setState(ModelInstance *instance, const char *function, const void *state) {
    const DynamicState *snapshot = (const DynamicState *)state;

    if (checkNotNull(instance, function, state, "FMUstate") != OK) {
        return Error;
    }

    if (!sameParameters(snapshot->parameters, instance->current.parameters)) {
        releaseSystem(instance);
    }

    copyDynamicState(&instance->current, snapshot);
    invalidateModalState(&instance->solver);

    if (instance->current.state != Instantiated) {
        Status status = ensureSystem(instance);
        if (status > Warning) {
            return status;
        }
        computeOutputs(&instance->system, instance->current.x, instance->current.v, instance->current.u,
                       instance->y);
    }

    return OK;
}

void freeState(ModelInstance *instance, void **state) {
    DynamicState *snapshot;

    if (!state || !*state) {
        return;
    }

    snapshot = (DynamicState *)*state;
    freeDynamicArrays(instance, snapshot);
    instance->allocator.release(snapshot);
    *state = NULL;
}

/* Serialized layout: header of 8 int values, then doubles. */
#define SERIAL_MAGIC 0x4e4d4b31  /* "NMK1" */
#define SERIAL_HEADER 8
#define SERIAL_DOUBLES (1 + N_PARAMETERS + 2 * N_INPUTS + 3 * (size_t)N_DOF)
#define SERIAL_SIZE (SERIAL_HEADER * sizeof(int) + SERIAL_DOUBLES * sizeof(double))

size_t serializedStateSize(void) {
    return SERIAL_SIZE;
}

/* A 31-bit FNV-1a hash of the instantiation token: a state serialized by another model of the same sizes
 * (another ROM FMU) is refused. */
static int modelFingerprint(void) {
    const char *text = INSTANTIATION_TOKEN;
    unsigned int hash = 2166136261u;

    while (*text) {
        hash ^= (unsigned char)*text++;
        hash *= 16777619u;
    }
    return (int)(hash & 0x7fffffffu);
}

static unsigned char *put(unsigned char *cursor, const void *data, size_t bytes) {
    memcpy(cursor, data, bytes);
    return cursor + bytes;
}

static const unsigned char *take(const unsigned char *cursor, void *data, size_t bytes) {
    memcpy(data, cursor, bytes);
    return cursor + bytes;
}

Status serializeState(ModelInstance *instance, const char *function, const void *state,
                      unsigned char buffer[], size_t size) {
    const DynamicState *snapshot = (const DynamicState *)state;
    size_t n = (size_t)N_DOF * sizeof(double);
    size_t inputs = (size_t)N_INPUTS * sizeof(double);
    int header[SERIAL_HEADER];
    unsigned char *cursor = buffer;

    if (checkNotNull(instance, function, state, "FMUstate") != OK ||
        checkNotNull(instance, function, buffer, "serializedState") != OK) {
        return Error;
    }
    if (size < SERIAL_SIZE) {
        logError(instance, "%s: buffer of %lu bytes is too small (%lu needed)", function,
                 (unsigned long)size, (unsigned long)SERIAL_SIZE);
        return Error;
    }

    header[0] = SERIAL_MAGIC;
    header[1] = N_DOF;
    header[2] = N_INPUTS;
    header[3] = N_PARAMETERS;
    header[4] = (int)snapshot->state;
    header[5] = snapshot->accelerationPending;
    header[6] = snapshot->stepCount;
    header[7] = modelFingerprint();

    cursor = put(cursor, header, sizeof(header));
    cursor = put(cursor, &snapshot->time, sizeof(double));
    cursor = put(cursor, snapshot->parameters, (size_t)N_PARAMETERS * sizeof(double));
    cursor = put(cursor, snapshot->u, inputs);
    cursor = put(cursor, snapshot->uApplied, inputs);
    cursor = put(cursor, snapshot->x, n);
    cursor = put(cursor, snapshot->v, n);
    put(cursor, snapshot->a, n);
    return OK;
}

Status deserializeState(ModelInstance *instance, const char *function,
                        const unsigned char buffer[], size_t size, void **state) {
    size_t n = (size_t)N_DOF * sizeof(double);
    size_t inputs = (size_t)N_INPUTS * sizeof(double);
    const unsigned char *cursor = buffer;
    DynamicState *snapshot;
    int header[SERIAL_HEADER];

    if (checkNotNull(instance, function, buffer, "serializedState") != OK ||
        checkNotNull(instance, function, state, "FMUstate") != OK) {
        return Error;
    }
    if (size != SERIAL_SIZE) {
        logError(instance, "%s: expected %lu bytes but got %lu", function,
                 (unsigned long)SERIAL_SIZE, (unsigned long)size);
        return Error;
    }

    cursor = take(cursor, header, sizeof(header));
    if (header[0] != SERIAL_MAGIC || header[1] != N_DOF || header[2] != N_INPUTS ||
        header[3] != N_PARAMETERS) {
        logError(instance, "%s: the data do not belong to this model", function);
        return Error;
    }
    if (header[7] != modelFingerprint()) {
        logError(instance, "%s: the data are the state of another model (another instantiation token)", function);
        return Error;
    }

    snapshot = (DynamicState *)*state;
    if (!snapshot) {
        snapshot = allocateDynamicState(instance);
        if (!snapshot) {
            logError(instance, "%s: out of memory", function);
            return Error;
        }
    }

    snapshot->state = (ModelState)header[4];
    snapshot->accelerationPending = header[5];
    snapshot->stepCount = header[6];
    cursor = take(cursor, &snapshot->time, sizeof(double));
    cursor = take(cursor, snapshot->parameters, (size_t)N_PARAMETERS * sizeof(double));
    cursor = take(cursor, snapshot->u, inputs);
    cursor = take(cursor, snapshot->uApplied, inputs);
    cursor = take(cursor, snapshot->x, n);
    cursor = take(cursor, snapshot->v, n);
    take(cursor, snapshot->a, n);
    *state = snapshot;
    return OK;
}
