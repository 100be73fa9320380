/*
 * FMI 2.0 co-simulation API shared by every model (benchmark FMUs and exported ROMs).
 *
 * Each function checks the instance and the states in which it may be called, delegates
 * to the version-independent instance (instance.h), keeps the worst status and switches
 * the instance to the error state on fmi2Error.  Messages reach the importer only through
 * its logger callback.
 */
#include <string.h>

#include "fmi2Functions.h"
#include "instance.h"

#define STATE_SET_DEBUG_LOGGING (STATE_ANY_LIVE)
#define STATE_SETUP_EXPERIMENT  (Instantiated)
#define STATE_ENTER_INIT        (Instantiated)
#define STATE_EXIT_INIT         (InitializationMode)
#define STATE_TERMINATE         (StepComplete | StepFailed)
#define STATE_RESET             (STATE_ANY_LIVE)
#define STATE_GET               (InitializationMode | STATE_AFTER_INIT)
#define STATE_SET               (Instantiated | InitializationMode | StepComplete)
#define STATE_FMU_STATE         (STATE_ANY_LIVE)
#define STATE_DO_STEP           (StepComplete)
#define STATE_GET_STATUS        (STATE_AFTER_INIT)

#define BEGIN(name, allowed) \
    ModelInstance *instance = (ModelInstance *)c; \
    const char *function = name; \
    Status status = OK; \
    CALL(checkState(instance, function, allowed))

#define RETURN return (fmi2Status)finishCall(instance, status)

static void forwardLog(const ModelInstance *instance, Status status, const char *category,
                       const char *message) {
    fmi2CallbackLogger logger = (fmi2CallbackLogger)instance->logger;

    if (logger) {
        /* The FMI 2 logger's message is a printf format, and importers that format it read a '%' (in a variable
         * name) as a conversion with no argument behind it; others print it as it is.  Doubled, it is a plain '%'
         * to the first and "%%" to the second, and neither reads past the arguments. */
        char escaped[1024];
        size_t in, out = 0;

        for (in = 0; message[in] != '\0' && out + 2 < sizeof(escaped); in++) {
            if (message[in] == '%') {
                escaped[out++] = '%';
            }
            escaped[out++] = message[in];
        }
        escaped[out] = '\0';
        logger(instance->environment, instance->instanceName, (fmi2Status)status, category, escaped);
    }
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
    BEGIN("fmi2SetDebugLogging", STATE_SET_DEBUG_LOGGING);
    CALL(setDebugLogging(instance, function, loggingOn, nCategories, categories));
END:
    RETURN;
}

/* ------------------------------------------------- creation / destruction */

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    Allocator allocator;

    (void)fmuResourceLocation;
    (void)visible;

    if (!functions || !functions->allocateMemory || !functions->freeMemory) {
        return NULL;
    }

    if (fmuType != fmi2CoSimulation) {
        if (functions->logger) {
            functions->logger(functions->componentEnvironment, instanceName ? instanceName : "",
                              fmi2Error, "logStatusError",
                              "fmi2Instantiate: only co-simulation is supported");
        }
        return NULL;
    }

    allocator.allocate = functions->allocateMemory;
    allocator.release = functions->freeMemory;
    return createInstance(instanceName, fmuGUID, &allocator, forwardLog,
                          (GenericFunction)functions->logger, functions->componentEnvironment,
                          loggingOn);
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
    BEGIN("fmi2SetupExperiment", STATE_SETUP_EXPERIMENT);
    (void)toleranceDefined;
    (void)tolerance;
    CALL(setupExperiment(instance, startTime, stopTimeDefined, stopTime));
END:
    RETURN;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    BEGIN("fmi2EnterInitializationMode", STATE_ENTER_INIT);
    instance->current.state = InitializationMode;
END:
    RETURN;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    BEGIN("fmi2ExitInitializationMode", STATE_EXIT_INIT);
    CALL(exitInitialization(instance));
END:
    RETURN;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    BEGIN("fmi2Terminate", STATE_TERMINATE);
    instance->current.state = Terminated;
END:
    RETURN;
}

fmi2Status fmi2Reset(fmi2Component c) {
    BEGIN("fmi2Reset", STATE_RESET);
    resetInstance(instance);
END:
    RETURN;
}

/* ------------------------------------------------------ get / set */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    BEGIN("fmi2GetReal", STATE_GET);
    CALL(getFloat64(instance, function, vr, nvr, value));
END:
    RETURN;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    BEGIN("fmi2SetReal", STATE_SET);
    CALL(setFloat64(instance, function, vr, nvr, value));
END:
    RETURN;
}

static fmi2Status noVariables(fmi2Component c, const char *name, size_t nvr) {
    BEGIN(name, STATE_GET | STATE_SET);
    if (nvr > 0) {
        logError(instance, "%s: the model has no variables of this type", function);
        status = Error;
    }
END:
    RETURN;
}

/* Integer and Boolean variables: the parameters of those types (an exported ROM's source parameters), held as
 * doubles inside. */
static fmi2Status getTyped(fmi2Component c, const char *name, VariableKind kind, const fmi2ValueReference vr[],
                           size_t nvr, int value[]) {
    double *buffer = NULL;
    size_t i;
    BEGIN(name, STATE_GET);
    if (nvr == 0) {
        goto END;
    }
    CALL(checkNotNull(instance, function, value, "value"));
    buffer = (double *)instance->allocator.allocate(nvr, sizeof(double));
    if (!buffer) {
        logError(instance, "%s: out of memory", function);
        status = Error;
        goto END;
    }
    CALL(getParameters(instance, function, kind, vr, nvr, buffer));
    for (i = 0; i < nvr; i++) {
        value[i] = kind == KindBoolean ? (buffer[i] != 0.0 ? fmi2True : fmi2False) : (int)buffer[i];
    }
END:
    if (buffer) {
        instance->allocator.release(buffer);
    }
    RETURN;
}

static fmi2Status setTyped(fmi2Component c, const char *name, VariableKind kind, const fmi2ValueReference vr[],
                           size_t nvr, const int value[]) {
    double *buffer = NULL;
    size_t i;
    BEGIN(name, STATE_SET);
    if (nvr == 0) {
        goto END;
    }
    CALL(checkNotNull(instance, function, value, "value"));
    buffer = (double *)instance->allocator.allocate(nvr, sizeof(double));
    if (!buffer) {
        logError(instance, "%s: out of memory", function);
        status = Error;
        goto END;
    }
    for (i = 0; i < nvr; i++) {
        buffer[i] = kind == KindBoolean ? (value[i] != fmi2False ? 1.0 : 0.0) : (double)value[i];
    }
    CALL(setParameters(instance, function, kind, vr, nvr, buffer));
END:
    if (buffer) {
        instance->allocator.release(buffer);
    }
    RETURN;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    return getTyped(c, "fmi2GetInteger", KindInt32, vr, nvr, value);
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    return getTyped(c, "fmi2GetBoolean", KindBoolean, vr, nvr, value);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    (void)vr; (void)value;
    return noVariables(c, "fmi2GetString", nvr);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    return setTyped(c, "fmi2SetInteger", KindInt32, vr, nvr, value);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    return setTyped(c, "fmi2SetBoolean", KindBoolean, vr, nvr, value);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    (void)vr; (void)value;
    return noVariables(c, "fmi2SetString", nvr);
}

/* ------------------------------------------------------ FMU state */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    BEGIN("fmi2GetFMUstate", STATE_FMU_STATE);
    CALL(getState(instance, function, FMUstate));
END:
    RETURN;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    BEGIN("fmi2SetFMUstate", STATE_FMU_STATE);
    CALL(setState(instance, function, FMUstate));
END:
    RETURN;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    if (!c) {
        return fmi2Error;
    }
    freeState((ModelInstance *)c, FMUstate);
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    BEGIN("fmi2SerializedFMUstateSize", STATE_FMU_STATE);
    CALL(checkNotNull(instance, function, FMUstate, "FMUstate"));
    CALL(checkNotNull(instance, function, size, "size"));
    *size = serializedStateSize();
END:
    RETURN;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    BEGIN("fmi2SerializeFMUstate", STATE_FMU_STATE);
    CALL(serializeState(instance, function, FMUstate, (unsigned char *)serializedState, size));
END:
    RETURN;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    BEGIN("fmi2DeSerializeFMUstate", STATE_FMU_STATE);
    CALL(deserializeState(instance, function, (const unsigned char *)serializedState, size,
                          FMUstate));
END:
    RETURN;
}

/* ------------------------------------------- unsupported capabilities */

static fmi2Status unsupported(fmi2Component c, const char *name) {
    BEGIN(name, STATE_ANY_LIVE);
    logError(instance, "%s is not supported by this FMU", function);
    status = Error;
END:
    RETURN;
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

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    BEGIN("fmi2DoStep", STATE_DO_STEP);
    (void)noSetFMUStatePriorToCurrentPoint;
    CALL(doStep(instance, function, currentCommunicationPoint, communicationStepSize));
END:
    RETURN;
}

/* --------------------------------------------------------- status */

static fmi2Status statusUnavailable(fmi2Component c, const char *name, int kind) {
    BEGIN(name, STATE_GET_STATUS);
    logError(instance, "%s: status kind %d is not available", function, kind);
    status = Discard;
END:
    RETURN;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    BEGIN("fmi2GetStatus", STATE_GET_STATUS);
    CALL(checkNotNull(instance, function, value, "value"));
    if (s != fmi2DoStepStatus) {
        return statusUnavailable(c, function, (int)s);
    }
    *value = fmi2OK;
END:
    RETURN;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    BEGIN("fmi2GetRealStatus", STATE_GET_STATUS);
    CALL(checkNotNull(instance, function, value, "value"));
    if (s != fmi2LastSuccessfulTime) {
        return statusUnavailable(c, function, (int)s);
    }
    *value = instance->current.time;
END:
    RETURN;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)value;
    return statusUnavailable(c, "fmi2GetIntegerStatus", (int)s);
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    BEGIN("fmi2GetBooleanStatus", STATE_GET_STATUS);
    CALL(checkNotNull(instance, function, value, "value"));
    if (s != fmi2Terminated) {
        return statusUnavailable(c, function, (int)s);
    }
    *value = fmi2False;
END:
    RETURN;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)value;
    return statusUnavailable(c, "fmi2GetStringStatus", (int)s);
}
