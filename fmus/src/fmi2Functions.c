/*
 * FMI 2.0 co-simulation glue shared by every model (benchmark FMUs and exported ROMs).
 *
 * All FMI functions live here.  Each checks the instance and the states in which it may
 * be called, keeps the worst status of its inner calls, logs problems only through the
 * importer's logger callback and switches the instance to the error state on fmi2Error.
 * The model itself only provides assembleSystem() (model.h); the integration is the one
 * Newmark kernel (newmark.h).
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"
#include "newmark.h"

/* ------------------------------------------------------------ instance */

typedef enum {
    StartAndEnd        = 1 << 0,
    Instantiated       = 1 << 1,
    InitializationMode = 1 << 2,
    StepComplete       = 1 << 3,
    StepFailed         = 1 << 4,
    Terminated         = 1 << 5,
    ErrorState         = 1 << 6,
    FatalState         = 1 << 7
} ModelState;

#define STATE_SET_DEBUG_LOGGING (Instantiated | InitializationMode | StepComplete | StepFailed | \
                                 Terminated | ErrorState)
#define STATE_SETUP_EXPERIMENT  (Instantiated)
#define STATE_ENTER_INIT        (Instantiated)
#define STATE_EXIT_INIT         (InitializationMode)
#define STATE_TERMINATE         (StepComplete | StepFailed)
#define STATE_RESET             (Instantiated | InitializationMode | StepComplete | StepFailed | \
                                 Terminated | ErrorState)
#define STATE_GET               (InitializationMode | StepComplete | StepFailed | Terminated | \
                                 ErrorState)
#define STATE_SET               (Instantiated | InitializationMode | StepComplete)
#define STATE_GET_FMU_STATE     (Instantiated | InitializationMode | StepComplete | StepFailed | \
                                 Terminated | ErrorState)
#define STATE_SET_FMU_STATE     (Instantiated | InitializationMode | StepComplete | StepFailed | \
                                 Terminated | ErrorState)
#define STATE_SERIALIZE         (Instantiated | InitializationMode | StepComplete | StepFailed | \
                                 Terminated | ErrorState)
#define STATE_DO_STEP           (StepComplete)
#define STATE_GET_STATUS        (StepComplete | StepFailed | Terminated | ErrorState)
#define STATE_NONE              (0)

#define MESSAGE_LENGTH 512

/* Everything that an FMU state snapshot has to restore. */
typedef struct {
    ModelState state;
    double time;
    int accelerationPending;
    int stepCount;
    double parameters[ARRAY_LENGTH(N_PARAMETERS)];
    double u[ARRAY_LENGTH(N_INPUTS)];
    double uApplied[ARRAY_LENGTH(N_INPUTS)];  /* input the acceleration a is consistent with */
    double *x;
    double *v;
    double *a;
} DynamicState;

typedef struct {
    char *instanceName;
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment environment;
    Allocator allocator;
    int loggingOn;

    double startTime;
    double stopTime;
    int stopTimeDefined;

    DynamicState current;
    double y[ARRAY_LENGTH(N_OUTPUTS)];

    int systemReady;
    SecondOrderSystem system;
    NewmarkSolver solver;
} ModelInstance;

static const double parameterDefaults[ARRAY_LENGTH(N_PARAMETERS)] = PARAMETER_DEFAULTS;

/* ------------------------------------------------------------- logging */

static void logMessage(ModelInstance *instance, fmi2Status status, const char *category,
                       const char *format, ...) {
    char message[MESSAGE_LENGTH];
    va_list args;

    if (!instance || !instance->logger) {
        return;
    }

    va_start(args, format);
    vsnprintf(message, sizeof(message), format, args);
    va_end(args);

    instance->logger(instance->environment, instance->instanceName, status, category, message);
}

#define logError(instance, ...) logMessage(instance, fmi2Error, "logStatusError", __VA_ARGS__)
#define logEvent(instance, ...) \
    do { if ((instance)->loggingOn) logMessage(instance, fmi2OK, "logEvents", __VA_ARGS__); } while (0)

/* Keep the worst status; leave through END on Error or worse. */
#define CALL(expression) \
    do { Status s_ = (expression); if (s_ > status) status = s_; if (status > Warning) goto END; } while (0)

static Status checkState(ModelInstance *instance, const char *function, int allowed) {
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

static Status checkNotNull(ModelInstance *instance, const char *function, const void *pointer,
                           const char *argument) {
    if (!pointer) {
        logError(instance, "%s: argument %s must not be NULL", function, argument);
        return Error;
    }
    return OK;
}

static fmi2Status finish(ModelInstance *instance, Status status) {
    if (instance && status == Error) {
        instance->current.state = ErrorState;
    } else if (instance && status == Fatal) {
        instance->current.state = FatalState;
    }
    return (fmi2Status)status;
}

/* -------------------------------------------------------- model helpers */

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
        status = initialAcceleration(&instance->solver, &instance->system, instance->current.u,
                                     instance->current.x, instance->current.v, instance->current.a,
                                     &instance->allocator, &message);
        if (status > Warning) {
            logError(instance, "cannot compute the consistent initial acceleration: %s", message);
            goto END;
        }
        memcpy(instance->current.uApplied, instance->current.u, sizeof(instance->current.u));
        instance->current.accelerationPending = 0;
        computeOutputs(&instance->system, instance->current.x, instance->current.v, instance->y);
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
        instance->current.u[i] = 0.0;
        instance->current.uApplied[i] = 0.0;
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

static double *allocateVector(ModelInstance *instance) {
    return (double *)instance->allocator.allocate((size_t)N_DOF, sizeof(double));
}

static void freeDynamicArrays(ModelInstance *instance, DynamicState *state) {
    instance->allocator.release(state->x);
    instance->allocator.release(state->v);
    instance->allocator.release(state->a);
    state->x = NULL;
    state->v = NULL;
    state->a = NULL;
}

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

static int sameParameters(const double first[], const double second[]) {
    int i;
    for (i = 0; i < N_PARAMETERS; i++) {
        if (first[i] != second[i]) {
            return 0;
        }
    }
    return 1;
}

/* ------------------------------------------------ inquire / logging */

const char *fmi2GetTypesPlatform(void) {
    return fmi2TypesPlatform;
}

const char *fmi2GetVersion(void) {
    return fmi2Version;
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;
    size_t i;

    CALL(checkState(instance, "fmi2SetDebugLogging", STATE_SET_DEBUG_LOGGING));
    if (nCategories > 0) {
        CALL(checkNotNull(instance, "fmi2SetDebugLogging", categories, "categories"));
    }

    for (i = 0; i < nCategories; i++) {
        if (!categories[i] || (strcmp(categories[i], "logEvents") != 0 &&
                               strcmp(categories[i], "logStatusError") != 0)) {
            logError(instance, "fmi2SetDebugLogging: unknown log category \"%s\"",
                     categories[i] ? categories[i] : "(null)");
            status = Error;
            goto END;
        }
    }

    instance->loggingOn = loggingOn ? 1 : 0;

END:
    return finish(instance, status);
}

/* ------------------------------------------------- creation / destruction */

static void freeInstance(ModelInstance *instance) {
    fmi2CallbackFreeMemory release = (fmi2CallbackFreeMemory)instance->allocator.release;

    releaseSystem(instance);
    freeDynamicArrays(instance, &instance->current);
    release(instance->instanceName);
    release(instance);
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    ModelInstance *instance;
    ModelInstance probe;
    size_t length;

    (void)fmuResourceLocation;
    (void)visible;

    if (!functions || !functions->allocateMemory || !functions->freeMemory) {
        return NULL;
    }

    memset(&probe, 0, sizeof(probe));
    probe.logger = functions->logger;
    probe.environment = functions->componentEnvironment;
    probe.instanceName = (char *)(instanceName ? instanceName : "");

    if (!instanceName || instanceName[0] == '\0') {
        logError(&probe, "fmi2Instantiate: missing instance name");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        logError(&probe, "fmi2Instantiate: only co-simulation is supported");
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, INSTANTIATION_TOKEN) != 0) {
        logError(&probe, "fmi2Instantiate: wrong GUID \"%s\", expected \"%s\"",
                 fmuGUID ? fmuGUID : "(null)", INSTANTIATION_TOKEN);
        return NULL;
    }

    instance = (ModelInstance *)functions->allocateMemory(1, sizeof(ModelInstance));
    if (!instance) {
        logError(&probe, "fmi2Instantiate: out of memory");
        return NULL;
    }

    instance->logger = functions->logger;
    instance->environment = functions->componentEnvironment;
    instance->allocator.allocate = functions->allocateMemory;
    instance->allocator.release = functions->freeMemory;
    instance->loggingOn = loggingOn ? 1 : 0;

    length = strlen(instanceName) + 1;
    instance->instanceName = (char *)functions->allocateMemory(length, sizeof(char));
    instance->current.x = allocateVector(instance);
    instance->current.v = allocateVector(instance);
    instance->current.a = allocateVector(instance);

    if (!instance->instanceName || !instance->current.x || !instance->current.v ||
        !instance->current.a) {
        logError(&probe, "fmi2Instantiate: out of memory");
        freeDynamicArrays(instance, &instance->current);
        functions->freeMemory(instance->instanceName);
        functions->freeMemory(instance);
        return NULL;
    }

    memcpy(instance->instanceName, instanceName, length);
    resetDynamicState(instance);
    instance->current.state = Instantiated;
    logEvent(instance, "instantiated %s (n = %d, m = %d, p = %d, nc = %d)", MODEL_IDENTIFIER,
             N_DOF, N_INPUTS, N_OUTPUTS, N_CONSTRAINTS);
    return instance;
}

void fmi2FreeInstance(fmi2Component c) {
    if (c) {
        freeInstance((ModelInstance *)c);
    }
}

/* ------------------------------------------------- initialization */

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    (void)toleranceDefined;
    (void)tolerance;

    CALL(checkState(instance, "fmi2SetupExperiment", STATE_SETUP_EXPERIMENT));

    if (!isfinite(startTime) || (stopTimeDefined && (!isfinite(stopTime) || stopTime < startTime))) {
        logError(instance, "fmi2SetupExperiment: invalid start time %g or stop time %g", startTime,
                 stopTime);
        status = Error;
        goto END;
    }

    instance->startTime = startTime;
    instance->current.time = startTime;
    instance->stopTimeDefined = stopTimeDefined ? 1 : 0;
    instance->stopTime = stopTime;

END:
    return finish(instance, status);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    CALL(checkState(instance, "fmi2EnterInitializationMode", STATE_ENTER_INIT));
    instance->current.state = InitializationMode;

END:
    return finish(instance, status);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    CALL(checkState(instance, "fmi2ExitInitializationMode", STATE_EXIT_INIT));
    CALL(ensureInitialAcceleration(instance));
    instance->current.state = StepComplete;

END:
    return finish(instance, status);
}

fmi2Status fmi2Terminate(fmi2Component c) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    CALL(checkState(instance, "fmi2Terminate", STATE_TERMINATE));
    instance->current.state = Terminated;

END:
    return finish(instance, status);
}

fmi2Status fmi2Reset(fmi2Component c) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    CALL(checkState(instance, "fmi2Reset", STATE_RESET));
    releaseSystem(instance);
    resetDynamicState(instance);
    instance->current.state = Instantiated;
    logEvent(instance, "reset to the instantiated state");

END:
    return finish(instance, status);
}

/* ------------------------------------------------------ get / set */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;
    size_t i;

    CALL(checkState(instance, "fmi2GetReal", STATE_GET));
    if (nvr == 0) {
        goto END;
    }
    CALL(checkNotNull(instance, "fmi2GetReal", vr, "vr"));
    CALL(checkNotNull(instance, "fmi2GetReal", value, "value"));

    if (instance->current.state & (InitializationMode | StepComplete)) {
        CALL(ensureInputApplied(instance));
    }

    for (i = 0; i < nvr; i++) {
        fmi2ValueReference r = vr[i];
        if (r >= VR_INPUTS && r < VR_OUTPUTS) {
            value[i] = instance->current.u[r - VR_INPUTS];
        } else if (r >= VR_OUTPUTS && r < VR_PARAMETERS) {
            value[i] = instance->y[r - VR_OUTPUTS];
        } else if (r >= VR_PARAMETERS && r < VR_POSITIONS) {
            value[i] = instance->current.parameters[r - VR_PARAMETERS];
        } else if (r >= VR_POSITIONS && r < VR_VELOCITIES) {
            value[i] = instance->current.x[r - VR_POSITIONS];
        } else if (r >= VR_VELOCITIES && r < VR_ACCELERATIONS) {
            value[i] = instance->current.v[r - VR_VELOCITIES];
        } else if (r >= VR_ACCELERATIONS && r < VR_END) {
            value[i] = instance->current.a[r - VR_ACCELERATIONS];
        } else {
            logError(instance, "fmi2GetReal: unknown value reference %u", (unsigned)r);
            status = Error;
            goto END;
        }
    }

END:
    return finish(instance, status);
}

static Status setParameter(ModelInstance *instance, fmi2ValueReference r, double value) {
    int index = (int)(r - VR_PARAMETERS);

    if (!(instance->current.state & (Instantiated | InitializationMode))) {
        logError(instance, "fmi2SetReal: parameter with value reference %u is fixed after "
                 "initialization", (unsigned)r);
        return Error;
    }

    if (instance->current.parameters[index] != value) {
        instance->current.parameters[index] = value;
        instance->current.accelerationPending = 1;
        releaseSystem(instance);
    }

    return OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;
    size_t i;

    CALL(checkState(instance, "fmi2SetReal", STATE_SET));
    if (nvr == 0) {
        goto END;
    }
    CALL(checkNotNull(instance, "fmi2SetReal", vr, "vr"));
    CALL(checkNotNull(instance, "fmi2SetReal", value, "value"));

    for (i = 0; i < nvr; i++) {
        fmi2ValueReference r = vr[i];

        if (!isfinite(value[i])) {
            logError(instance, "fmi2SetReal: value of value reference %u is not finite",
                     (unsigned)r);
            status = Error;
            goto END;
        }

        if (r >= VR_INPUTS && r < VR_OUTPUTS) {
            instance->current.u[r - VR_INPUTS] = value[i];
            if (instance->current.stepCount == 0) {
                instance->current.accelerationPending = 1;
            }
        } else if (r >= VR_PARAMETERS && r < VR_POSITIONS) {
            CALL(setParameter(instance, r, value[i]));
        } else if (r >= VR_OUTPUTS && r < VR_END) {
            logError(instance, "fmi2SetReal: variable with value reference %u cannot be set",
                     (unsigned)r);
            status = Error;
            goto END;
        } else {
            logError(instance, "fmi2SetReal: unknown value reference %u", (unsigned)r);
            status = Error;
            goto END;
        }
    }

END:
    return finish(instance, status);
}

static fmi2Status noVariables(fmi2Component c, const char *function, size_t nvr) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    CALL(checkState(instance, function, STATE_GET | STATE_SET));
    if (nvr > 0) {
        logError(instance, "%s: the model has no variables of this type", function);
        status = Error;
    }

END:
    return finish(instance, status);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    (void)vr; (void)value;
    return noVariables(c, "fmi2GetInteger", nvr);
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    (void)vr; (void)value;
    return noVariables(c, "fmi2GetBoolean", nvr);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    (void)vr; (void)value;
    return noVariables(c, "fmi2GetString", nvr);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    (void)vr; (void)value;
    return noVariables(c, "fmi2SetInteger", nvr);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    (void)vr; (void)value;
    return noVariables(c, "fmi2SetBoolean", nvr);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    (void)vr; (void)value;
    return noVariables(c, "fmi2SetString", nvr);
}

/* ------------------------------------------------------ FMU state */

static DynamicState *allocateDynamicState(ModelInstance *instance) {
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

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;
    DynamicState *state;

    CALL(checkState(instance, "fmi2GetFMUstate", STATE_GET_FMU_STATE));
    CALL(checkNotNull(instance, "fmi2GetFMUstate", FMUstate, "FMUstate"));

    state = (DynamicState *)*FMUstate;
    if (!state) {
        state = allocateDynamicState(instance);
        if (!state) {
            logError(instance, "fmi2GetFMUstate: out of memory");
            status = Error;
            goto END;
        }
    }

    copyDynamicState(state, &instance->current);
    *FMUstate = state;

END:
    return finish(instance, status);
}

static Status restoreState(ModelInstance *instance, const DynamicState *state) {
    if (!sameParameters(state->parameters, instance->current.parameters)) {
        releaseSystem(instance);
    }

    copyDynamicState(&instance->current, state);

    if (instance->current.state != Instantiated) {
        Status status = ensureSystem(instance);
        if (status > Warning) {
            return status;
        }
        computeOutputs(&instance->system, instance->current.x, instance->current.v, instance->y);
    }

    return OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    CALL(checkState(instance, "fmi2SetFMUstate", STATE_SET_FMU_STATE));
    CALL(checkNotNull(instance, "fmi2SetFMUstate", FMUstate, "FMUstate"));
    CALL(restoreState(instance, (const DynamicState *)FMUstate));

END:
    return finish(instance, status);
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;
    DynamicState *state;

    if (!instance) {
        return fmi2Error;
    }
    if (!FMUstate || !*FMUstate) {
        return fmi2OK;
    }

    state = (DynamicState *)*FMUstate;
    freeDynamicArrays(instance, state);
    instance->allocator.release(state);
    *FMUstate = NULL;
    return (fmi2Status)status;
}

/* Serialized layout: header of 8 int32 values, then doubles. */
#define SERIAL_MAGIC 0x4e4d4b31  /* "NMK1" */
#define SERIAL_HEADER 8
#define SERIAL_DOUBLES (1 + N_PARAMETERS + 2 * N_INPUTS + 3 * (size_t)N_DOF)
#define SERIAL_SIZE (SERIAL_HEADER * sizeof(int) + SERIAL_DOUBLES * sizeof(double))

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    CALL(checkState(instance, "fmi2SerializedFMUstateSize", STATE_SERIALIZE));
    CALL(checkNotNull(instance, "fmi2SerializedFMUstateSize", FMUstate, "FMUstate"));
    CALL(checkNotNull(instance, "fmi2SerializedFMUstateSize", size, "size"));
    *size = SERIAL_SIZE;

END:
    return finish(instance, status);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;
    const DynamicState *state = (const DynamicState *)FMUstate;
    int header[SERIAL_HEADER];
    char *cursor;
    size_t n = (size_t)N_DOF * sizeof(double);

    CALL(checkState(instance, "fmi2SerializeFMUstate", STATE_SERIALIZE));
    CALL(checkNotNull(instance, "fmi2SerializeFMUstate", FMUstate, "FMUstate"));
    CALL(checkNotNull(instance, "fmi2SerializeFMUstate", serializedState, "serializedState"));

    if (size < SERIAL_SIZE) {
        logError(instance, "fmi2SerializeFMUstate: buffer of %lu bytes is too small (%lu needed)",
                 (unsigned long)size, (unsigned long)SERIAL_SIZE);
        status = Error;
        goto END;
    }

    header[0] = SERIAL_MAGIC;
    header[1] = N_DOF;
    header[2] = N_INPUTS;
    header[3] = N_PARAMETERS;
    header[4] = (int)state->state;
    header[5] = state->accelerationPending;
    header[6] = state->stepCount;
    header[7] = 0;

    cursor = (char *)serializedState;
    memcpy(cursor, header, sizeof(header));
    cursor += sizeof(header);
    memcpy(cursor, &state->time, sizeof(double));
    cursor += sizeof(double);
    memcpy(cursor, state->parameters, (size_t)N_PARAMETERS * sizeof(double));
    cursor += (size_t)N_PARAMETERS * sizeof(double);
    memcpy(cursor, state->u, (size_t)N_INPUTS * sizeof(double));
    cursor += (size_t)N_INPUTS * sizeof(double);
    memcpy(cursor, state->uApplied, (size_t)N_INPUTS * sizeof(double));
    cursor += (size_t)N_INPUTS * sizeof(double);
    memcpy(cursor, state->x, n);
    cursor += n;
    memcpy(cursor, state->v, n);
    cursor += n;
    memcpy(cursor, state->a, n);

END:
    return finish(instance, status);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;
    DynamicState *state;
    int header[SERIAL_HEADER];
    const char *cursor;
    size_t n = (size_t)N_DOF * sizeof(double);

    CALL(checkState(instance, "fmi2DeSerializeFMUstate", STATE_SERIALIZE));
    CALL(checkNotNull(instance, "fmi2DeSerializeFMUstate", serializedState, "serializedState"));
    CALL(checkNotNull(instance, "fmi2DeSerializeFMUstate", FMUstate, "FMUstate"));

    if (size != SERIAL_SIZE) {
        logError(instance, "fmi2DeSerializeFMUstate: expected %lu bytes but got %lu",
                 (unsigned long)SERIAL_SIZE, (unsigned long)size);
        status = Error;
        goto END;
    }

    cursor = (const char *)serializedState;
    memcpy(header, cursor, sizeof(header));
    cursor += sizeof(header);

    if (header[0] != SERIAL_MAGIC || header[1] != N_DOF || header[2] != N_INPUTS ||
        header[3] != N_PARAMETERS) {
        logError(instance, "fmi2DeSerializeFMUstate: the data do not belong to this model");
        status = Error;
        goto END;
    }

    state = (DynamicState *)*FMUstate;
    if (!state) {
        state = allocateDynamicState(instance);
        if (!state) {
            logError(instance, "fmi2DeSerializeFMUstate: out of memory");
            status = Error;
            goto END;
        }
    }

    state->state = (ModelState)header[4];
    state->accelerationPending = header[5];
    state->stepCount = header[6];
    memcpy(&state->time, cursor, sizeof(double));
    cursor += sizeof(double);
    memcpy(state->parameters, cursor, (size_t)N_PARAMETERS * sizeof(double));
    cursor += (size_t)N_PARAMETERS * sizeof(double);
    memcpy(state->u, cursor, (size_t)N_INPUTS * sizeof(double));
    cursor += (size_t)N_INPUTS * sizeof(double);
    memcpy(state->uApplied, cursor, (size_t)N_INPUTS * sizeof(double));
    cursor += (size_t)N_INPUTS * sizeof(double);
    memcpy(state->x, cursor, n);
    cursor += n;
    memcpy(state->v, cursor, n);
    cursor += n;
    memcpy(state->a, cursor, n);
    *FMUstate = state;

END:
    return finish(instance, status);
}

/* ------------------------------------------- unsupported capabilities */

static fmi2Status unsupported(fmi2Component c, const char *function) {
    ModelInstance *instance = (ModelInstance *)c;

    if (!instance) {
        return fmi2Error;
    }
    logError(instance, "%s is not supported by this FMU", function);
    return finish(instance, Error);
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown;
    (void)dvKnown; (void)dvUnknown;
    return unsupported(c, "fmi2GetDirectionalDerivative");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return unsupported(c, "fmi2SetRealInputDerivatives");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return unsupported(c, "fmi2GetRealOutputDerivatives");
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    return unsupported(c, "fmi2CancelStep");
}

/* ------------------------------------------------------------ stepping */

static Status checkStepArguments(ModelInstance *instance, double point, double h) {
    double tolerance = 1e-9 * fmax(1.0, fabs(instance->current.time));

    if (!isfinite(h) || !(h > 0.0)) {
        logError(instance, "fmi2DoStep: communication step size %g must be positive and finite", h);
        return Error;
    }
    if (!isfinite(point) || fabs(point - instance->current.time) > tolerance) {
        logError(instance, "fmi2DoStep: communication point %.17g does not match the model time "
                 "%.17g", point, instance->current.time);
        return Error;
    }
    if (instance->stopTimeDefined && point + h > instance->stopTime + tolerance) {
        logError(instance, "fmi2DoStep: step to %.17g passes the stop time %.17g", point + h,
                 instance->stopTime);
        return Error;
    }
    return OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    ModelInstance *instance = (ModelInstance *)c;
    const char *message = "unknown problem";
    Status status = OK;
    double h = communicationStepSize;
    int i;

    (void)noSetFMUStatePriorToCurrentPoint;

    CALL(checkState(instance, "fmi2DoStep", STATE_DO_STEP));
    CALL(checkStepArguments(instance, currentCommunicationPoint, h));
    CALL(ensureInputApplied(instance));

    if (instance->solver.stepSize != h) {
        status = prepareStep(&instance->solver, &instance->system, h, &instance->allocator, &message);
        if (status > Warning) {
            logError(instance, "fmi2DoStep: cannot factor the step matrix for h = %g: %s", h,
                     message);
            goto END;
        }
        logEvent(instance, "factored the step matrix for h = %g", h);
    }

    newmarkStep(&instance->solver, &instance->system, h, instance->current.u, instance->current.x,
                instance->current.v, instance->current.a);

    for (i = 0; i < N_DOF; i++) {
        if (!isfinite(instance->current.a[i])) {
            logError(instance, "fmi2DoStep: the solution is not finite at t = %g",
                     currentCommunicationPoint + h);
            status = Error;
            goto END;
        }
    }

    instance->current.time = currentCommunicationPoint + h;
    instance->current.stepCount++;
    computeOutputs(&instance->system, instance->current.x, instance->current.v, instance->y);

END:
    return finish(instance, status);
}

/* --------------------------------------------------------- status */

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    CALL(checkState(instance, "fmi2GetStatus", STATE_GET_STATUS));
    CALL(checkNotNull(instance, "fmi2GetStatus", value, "value"));
    if (s != fmi2DoStepStatus) {
        logError(instance, "fmi2GetStatus: status kind %d is not available", (int)s);
        status = Discard;
        goto END;
    }
    *value = fmi2OK;

END:
    return finish(instance, status);
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    CALL(checkState(instance, "fmi2GetRealStatus", STATE_GET_STATUS));
    CALL(checkNotNull(instance, "fmi2GetRealStatus", value, "value"));
    if (s != fmi2LastSuccessfulTime) {
        logError(instance, "fmi2GetRealStatus: status kind %d is not available", (int)s);
        status = Discard;
        goto END;
    }
    *value = instance->current.time;

END:
    return finish(instance, status);
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    (void)s;
    (void)value;
    CALL(checkState(instance, "fmi2GetIntegerStatus", STATE_GET_STATUS));
    logError(instance, "fmi2GetIntegerStatus: no integer status is available");
    status = Discard;

END:
    return finish(instance, status);
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    CALL(checkState(instance, "fmi2GetBooleanStatus", STATE_GET_STATUS));
    CALL(checkNotNull(instance, "fmi2GetBooleanStatus", value, "value"));
    if (s != fmi2Terminated) {
        logError(instance, "fmi2GetBooleanStatus: status kind %d is not available", (int)s);
        status = Discard;
        goto END;
    }
    *value = fmi2False;

END:
    return finish(instance, status);
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    ModelInstance *instance = (ModelInstance *)c;
    Status status = OK;

    (void)s;
    (void)value;
    CALL(checkState(instance, "fmi2GetStringStatus", STATE_GET_STATUS));
    logError(instance, "fmi2GetStringStatus: no string status is available");
    status = Discard;

END:
    return finish(instance, status);
}
