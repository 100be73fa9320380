/*
 * FMI 3.0 co-simulation API on the shared co-simulation instance (instance.h).
 *
 * Only co-simulation without event mode, clocks or intermediate updates is provided; every
 * other function of the standard is exported and answers with a logged fmi3Error.  Memory
 * comes from the C library (FMI 3.0 has no allocation callbacks).
 */
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "instance.h"

#define STATE_SET_DEBUG_LOGGING (STATE_ANY_LIVE)
#define STATE_ENTER_INIT        (Instantiated)
#define STATE_EXIT_INIT         (InitializationMode)
#define STATE_ENTER_STEP_MODE   (StepComplete)
#define STATE_TERMINATE         (StepComplete | StepFailed)
#define STATE_RESET             (STATE_ANY_LIVE)
#define STATE_GET               (InitializationMode | STATE_AFTER_INIT)
#define STATE_SET               (Instantiated | InitializationMode | StepComplete)
#define STATE_FMU_STATE         (STATE_ANY_LIVE)
#define STATE_DO_STEP           (StepComplete)

#define BEGIN(name, allowed) \
    ModelInstance *model = (ModelInstance *)instance; \
    const char *function = name; \
    Status status = OK; \
    CALL(checkState(model, function, allowed))

#define RETURN return (fmi3Status)finishCall(model, status)

static void forwardLog(const ModelInstance *model, Status status, const char *category,
                       const char *message) {
    fmi3LogMessageCallback logger = (fmi3LogMessageCallback)model->logger;

    if (logger) {
        logger(model->environment, (fmi3Status)status, category, message);
    }
}

static void *allocateZeroed(size_t count, size_t size) {
    return calloc(count, size);
}

static fmi3Status unsupported(fmi3Instance instance, const char *name) {
    ModelInstance *model = (ModelInstance *)instance;

    if (!model) {
        return fmi3Error;
    }
    logError(model, "%s is not supported by this FMU", name);
    return (fmi3Status)finishCall(model, Error);
}

static fmi3Status noVariables(fmi3Instance instance, const char *name, size_t nValueReferences) {
    BEGIN(name, STATE_GET | STATE_SET);
    if (nValueReferences > 0) {
        logError(model, "%s: the model has no variables of this type", function);
        status = Error;
    }
END:
    RETURN;
}

/* Array and Float32 variables of a generated ROM FMU (config.h): {first value reference, number of values}.
 * An array's values sit at consecutive value references of the instance; the FMI 3 layer expands them. */
typedef struct {
    unsigned int first;
    unsigned int size;
} Port;

#ifdef N_ARRAY_PORTS
static const Port arrayPorts[N_ARRAY_PORTS] = ARRAY_PORTS;
#endif
#ifdef N_FLOAT32_PORTS
static const Port float32Ports[N_FLOAT32_PORTS] = FLOAT32_PORTS;
#endif

/* Number of values behind a declared value reference; 0 for the value references of an array's other
 * elements, which no variable declares. */
static size_t valueCount(unsigned int vr) {
#ifdef N_ARRAY_PORTS
    size_t i;
    for (i = 0; i < N_ARRAY_PORTS; i++) {
        if (arrayPorts[i].first == vr) {
            return arrayPorts[i].size;
        }
        if (vr > arrayPorts[i].first && vr - arrayPorts[i].first < arrayPorts[i].size) {
            return 0;
        }
    }
#endif
    (void)vr;
    return 1;
}

static int isFloat32(unsigned int vr) {
#ifdef N_FLOAT32_PORTS
    size_t i;
    for (i = 0; i < N_FLOAT32_PORTS; i++) {
        if (vr >= float32Ports[i].first && vr - float32Ports[i].first < float32Ports[i].size) {
            return 1;
        }
    }
#endif
    (void)vr;
    return 0;
}

/* A double as the nearest Float32, infinite beyond its range (a plain conversion is undefined there). */
static fmi3Float32 toFloat32(double value) {
    if (value > FLT_MAX) {
        return (fmi3Float32)INFINITY;
    }
    if (value < -FLT_MAX) {
        return (fmi3Float32)-INFINITY;
    }
    return (fmi3Float32)value;
}

static Status checkValues(const ModelInstance *model, const char *function, const void *values, size_t nValues) {
    if (nValues > 0 && !values) {
        logError(model, "%s: values is NULL", function);
        return Error;
    }
    return OK;
}

/* The instance's scalar value references behind valueReferences (each array's values in order), in
 * scalars[] (nValues of them, allocated here, freed by the caller); the variables must be of the
 * function's type (single: Float32) and hold nValues values together. */
static Status expandReferences(const ModelInstance *model, const char *function,
                               const fmi3ValueReference valueReferences[], size_t nValueReferences,
                               size_t nValues, int single, unsigned int **scalars) {
    size_t i, j, total = 0;

    *scalars = NULL;
    if (nValueReferences > 0 && !valueReferences) {
        logError(model, "%s: valueReferences is NULL", function);
        return Error;
    }
    for (i = 0; i < nValueReferences; i++) {
        if (valueCount(valueReferences[i]) == 0) {
            logError(model, "%s: value reference %u is not declared (an element of an array variable is "
                     "reached through the array's value reference)", function, (unsigned)valueReferences[i]);
            return Error;
        }
        if (isFloat32(valueReferences[i]) != single) {
            logError(model, "%s: value reference %u is a %s variable; use fmi3%sFloat%s", function,
                     (unsigned)valueReferences[i], single ? "Float64" : "Float32",
                     strstr(function, "Get") ? "Get" : "Set", single ? "64" : "32");
            return Error;
        }
        total += valueCount(valueReferences[i]);
    }
    if (total != nValues) {
        logError(model, "%s: %lu values for value references that hold %lu", function,
                 (unsigned long)nValues, (unsigned long)total);
        return Error;
    }
    *scalars = (unsigned int *)calloc(total > 0 ? total : 1, sizeof(unsigned int));
    if (!*scalars) {
        logError(model, "%s: out of memory", function);
        return Error;
    }
    for (i = 0, total = 0; i < nValueReferences; i++) {
        size_t count = valueCount(valueReferences[i]);
        for (j = 0; j < count; j++) {
            (*scalars)[total++] = valueReferences[i] + (unsigned int)j;
        }
    }
    return OK;
}

/* ------------------------------------------------ inquire / logging */

const char *fmi3GetVersion(void) {
    return fmi3Version;
}

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    BEGIN("fmi3SetDebugLogging", STATE_SET_DEBUG_LOGGING);
    CALL(setDebugLogging(model, function, loggingOn, nCategories, categories));
END:
    RETURN;
}

/* ------------------------------------------------- creation / destruction */

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn;
    if (logMessage) {
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateModelExchange: only co-simulation is supported");
    }
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible,
                                         fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
                                         fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    Allocator allocator;

    (void)resourcePath; (void)visible; (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables; (void)intermediateUpdate;

    if (eventModeUsed || nRequiredIntermediateVariables > 0) {
        if (logMessage) {
            logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                       "fmi3InstantiateCoSimulation: event mode and intermediate variables are "
                       "not supported");
        }
        return NULL;
    }

    allocator.allocate = allocateZeroed;
    allocator.release = free;
    return createInstance(instanceName, instantiationToken, &allocator, forwardLog,
                          (GenericFunction)logMessage, instanceEnvironment, loggingOn);
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName,
                                               fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn; (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    if (logMessage) {
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateScheduledExecution: only co-simulation is supported");
    }
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    if (instance) {
        freeInstance((ModelInstance *)instance);
    }
}

/* ------------------------------------------------- initialization */

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    BEGIN("fmi3EnterInitializationMode", STATE_ENTER_INIT);
    (void)toleranceDefined;
    (void)tolerance;
    CALL(setupExperiment(model, startTime, stopTimeDefined, stopTime));
    model->current.state = InitializationMode;
END:
    RETURN;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    BEGIN("fmi3ExitInitializationMode", STATE_EXIT_INIT);
    CALL(exitInitialization(model));
END:
    RETURN;
}

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    BEGIN("fmi3EnterStepMode", STATE_ENTER_STEP_MODE);
END:
    RETURN;
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    BEGIN("fmi3Terminate", STATE_TERMINATE);
    model->current.state = Terminated;
END:
    RETURN;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    BEGIN("fmi3Reset", STATE_RESET);
    resetInstance(model);
END:
    RETURN;
}

/* ------------------------------------------------------ get / set */

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    unsigned int *scalars = NULL;
    BEGIN("fmi3GetFloat64", STATE_GET);
    CALL(expandReferences(model, function, valueReferences, nValueReferences, nValues, 0, &scalars));
    CALL(getFloat64(model, function, scalars, nValues, values));
END:
    free(scalars);
    RETURN;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    unsigned int *scalars = NULL;
    BEGIN("fmi3SetFloat64", STATE_SET);
    CALL(expandReferences(model, function, valueReferences, nValueReferences, nValues, 0, &scalars));
    CALL(setFloat64(model, function, scalars, nValues, values));
END:
    free(scalars);
    RETURN;
}

/* Float32 variables (inputs and outputs of a ROM of a single-precision source) hold doubles inside: the
 * scalar value references behind a Float32 call and a double buffer of its nValues values. */
static Status float32Call(const ModelInstance *model, const char *function,
                          const fmi3ValueReference valueReferences[], size_t nValueReferences,
                          const void *values, size_t nValues, unsigned int **scalars, double **buffer) {
    Status status = checkValues(model, function, values, nValues);

    if (status == OK) {
        status = expandReferences(model, function, valueReferences, nValueReferences, nValues, 1, scalars);
    }
    if (status == OK) {
        *buffer = (double *)calloc(nValues > 0 ? nValues : 1, sizeof(double));
        if (!*buffer) {
            logError(model, "%s: out of memory", function);
            status = Error;
        }
    }
    return status;
}

fmi3Status fmi3GetFloat32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float32 values[], size_t nValues) {
    unsigned int *scalars = NULL;
    double *buffer = NULL;
    size_t i;
    BEGIN("fmi3GetFloat32", STATE_GET);
    CALL(float32Call(model, function, valueReferences, nValueReferences, values, nValues, &scalars, &buffer));
    CALL(getFloat64(model, function, scalars, nValues, buffer));
    for (i = 0; i < nValues; i++) {
        values[i] = toFloat32(buffer[i]);
    }
END:
    free(buffer);
    free(scalars);
    RETURN;
}

fmi3Status fmi3SetFloat32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float32 values[], size_t nValues) {
    unsigned int *scalars = NULL;
    double *buffer = NULL;
    size_t i;
    BEGIN("fmi3SetFloat32", STATE_SET);
    CALL(float32Call(model, function, valueReferences, nValueReferences, values, nValues, &scalars, &buffer));
    for (i = 0; i < nValues; i++) {
        buffer[i] = (double)values[i];
    }
    CALL(setFloat64(model, function, scalars, nValues, buffer));
END:
    free(buffer);
    free(scalars);
    RETURN;
}

/* Getters and setters of the types the model does not have. */
#define NO_GETTER(name, type) \
    fmi3Status name(fmi3Instance instance, const fmi3ValueReference valueReferences[], \
                    size_t nValueReferences, type values[], size_t nValues) { \
        (void)valueReferences; (void)values; (void)nValues; \
        return noVariables(instance, #name, nValueReferences); \
    }

#define NO_SETTER(name, type) \
    fmi3Status name(fmi3Instance instance, const fmi3ValueReference valueReferences[], \
                    size_t nValueReferences, const type values[], size_t nValues) { \
        (void)valueReferences; (void)values; (void)nValues; \
        return noVariables(instance, #name, nValueReferences); \
    }

/* Integer and Boolean variables: the parameters of those types (an exported ROM's source parameters), scalars held
 * as doubles inside: the buffer of a typed call's nValues values (one per value reference). */
static Status typedCall(const ModelInstance *model, const char *function, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const void *values, size_t nValues, double **buffer) {
    Status status = checkValues(model, function, values, nValues);

    if (status == OK && nValueReferences > 0 && !valueReferences) {
        logError(model, "%s: valueReferences is NULL", function);
        status = Error;
    }
    if (status == OK && nValues != nValueReferences) {
        logError(model, "%s: %lu values for %lu scalar variables", function, (unsigned long)nValues,
                 (unsigned long)nValueReferences);
        status = Error;
    }
    if (status == OK) {
        *buffer = (double *)calloc(nValues > 0 ? nValues : 1, sizeof(double));
        if (!*buffer) {
            logError(model, "%s: out of memory", function);
            status = Error;
        }
    }
    return status;
}

#define TYPED_GETTER(name, type, kind) \
    fmi3Status name(fmi3Instance instance, const fmi3ValueReference valueReferences[], \
                    size_t nValueReferences, type values[], size_t nValues) { \
        double *buffer = NULL; \
        size_t i; \
        BEGIN(#name, STATE_GET); \
        CALL(typedCall(model, function, valueReferences, nValueReferences, values, nValues, &buffer)); \
        CALL(getParameters(model, function, kind, valueReferences, nValues, buffer)); \
        for (i = 0; i < nValues; i++) { \
            values[i] = (type)buffer[i]; \
        } \
    END: \
        free(buffer); \
        RETURN; \
    }

#define TYPED_SETTER(name, type, kind) \
    fmi3Status name(fmi3Instance instance, const fmi3ValueReference valueReferences[], \
                    size_t nValueReferences, const type values[], size_t nValues) { \
        double *buffer = NULL; \
        size_t i; \
        BEGIN(#name, STATE_SET); \
        CALL(typedCall(model, function, valueReferences, nValueReferences, values, nValues, &buffer)); \
        for (i = 0; i < nValues; i++) { \
            buffer[i] = (double)values[i]; \
        } \
        CALL(setParameters(model, function, kind, valueReferences, nValues, buffer)); \
    END: \
        free(buffer); \
        RETURN; \
    }

/* (an fmi3Boolean is a C bool: (type)buffer[i] is true for any value but 0, and (double)true is 1) */
TYPED_GETTER(fmi3GetInt8, fmi3Int8, KindInt8)
TYPED_GETTER(fmi3GetUInt8, fmi3UInt8, KindUInt8)
TYPED_GETTER(fmi3GetInt16, fmi3Int16, KindInt16)
TYPED_GETTER(fmi3GetUInt16, fmi3UInt16, KindUInt16)
TYPED_GETTER(fmi3GetInt32, fmi3Int32, KindInt32)
TYPED_GETTER(fmi3GetUInt32, fmi3UInt32, KindUInt32)
TYPED_GETTER(fmi3GetInt64, fmi3Int64, KindInt64)
TYPED_GETTER(fmi3GetUInt64, fmi3UInt64, KindUInt64)
TYPED_GETTER(fmi3GetBoolean, fmi3Boolean, KindBoolean)
TYPED_SETTER(fmi3SetInt8, fmi3Int8, KindInt8)
TYPED_SETTER(fmi3SetUInt8, fmi3UInt8, KindUInt8)
TYPED_SETTER(fmi3SetInt16, fmi3Int16, KindInt16)
TYPED_SETTER(fmi3SetUInt16, fmi3UInt16, KindUInt16)
TYPED_SETTER(fmi3SetInt32, fmi3Int32, KindInt32)
TYPED_SETTER(fmi3SetUInt32, fmi3UInt32, KindUInt32)
TYPED_SETTER(fmi3SetInt64, fmi3Int64, KindInt64)
TYPED_SETTER(fmi3SetUInt64, fmi3UInt64, KindUInt64)
TYPED_SETTER(fmi3SetBoolean, fmi3Boolean, KindBoolean)
NO_GETTER(fmi3GetString, fmi3String)
NO_SETTER(fmi3SetString, fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, size_t valueSizes[], fmi3Binary values[],
                         size_t nValues) {
    (void)valueReferences; (void)valueSizes; (void)values; (void)nValues;
    return noVariables(instance, "fmi3GetBinary", nValueReferences);
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues) {
    (void)valueReferences; (void)valueSizes; (void)values; (void)nValues;
    return noVariables(instance, "fmi3SetBinary", nValueReferences);
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Clock values[]) {
    (void)valueReferences; (void)values;
    return noVariables(instance, "fmi3GetClock", nValueReferences);
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Clock values[]) {
    (void)valueReferences; (void)values;
    return noVariables(instance, "fmi3SetClock", nValueReferences);
}

/* ------------------------------------------------------ FMU state */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    BEGIN("fmi3GetFMUState", STATE_FMU_STATE);
    CALL(getState(model, function, FMUState));
END:
    RETURN;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    BEGIN("fmi3SetFMUState", STATE_FMU_STATE);
    CALL(setState(model, function, FMUState));
END:
    RETURN;
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    if (!instance) {
        return fmi3Error;
    }
    freeState((ModelInstance *)instance, FMUState);
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    BEGIN("fmi3SerializedFMUStateSize", STATE_FMU_STATE);
    CALL(checkNotNull(model, function, FMUState, "FMUState"));
    CALL(checkNotNull(model, function, size, "size"));
    *size = serializedStateSize();
END:
    RETURN;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size) {
    BEGIN("fmi3SerializeFMUState", STATE_FMU_STATE);
    CALL(serializeState(model, function, FMUState, serializedState, size));
END:
    RETURN;
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState) {
    BEGIN("fmi3DeserializeFMUState", STATE_FMU_STATE);
    CALL(deserializeState(model, function, serializedState, size, FMUState));
END:
    RETURN;
}

/* ------------------------------------------------------------ stepping */

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    BEGIN("fmi3DoStep", STATE_DO_STEP);
    (void)noSetFMUStatePriorToCurrentPoint;
    CALL(checkNotNull(model, function, eventHandlingNeeded, "eventHandlingNeeded"));
    CALL(checkNotNull(model, function, terminateSimulation, "terminateSimulation"));
    CALL(checkNotNull(model, function, earlyReturn, "earlyReturn"));
    CALL(checkNotNull(model, function, lastSuccessfulTime, "lastSuccessfulTime"));
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = model->current.time;
    CALL(doStep(model, function, currentCommunicationPoint, communicationStepSize));
    *lastSuccessfulTime = model->current.time;
END:
    RETURN;
}

/* ------------------------------------------- unsupported capabilities */

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance,
                                               fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference; (void)nDependencies;
    return unsupported(instance, "fmi3GetNumberOfVariableDependencies");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[], size_t nDependencies) {
    (void)dependent; (void)elementIndicesOfDependent; (void)independents;
    (void)elementIndicesOfIndependents; (void)dependencyKinds; (void)nDependencies;
    return unsupported(instance, "fmi3GetVariableDependencies");
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    return unsupported(instance, "fmi3GetDirectionalDerivative");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    return unsupported(instance, "fmi3GetAdjointDerivative");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterConfigurationMode");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3ExitConfigurationMode");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals; (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalDecimal");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[],
                                   fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalFraction");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return unsupported(instance, "fmi3GetShiftDecimal");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[],
                                fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3GetShiftFraction");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals;
    return unsupported(instance, "fmi3SetIntervalDecimal");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3SetIntervalFraction");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return unsupported(instance, "fmi3SetShiftDecimal");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return unsupported(instance, "fmi3SetShiftFraction");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    return unsupported(instance, "fmi3EvaluateDiscreteStates");
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined, fmi3Float64 *nextEventTime) {
    (void)discreteStatesNeedUpdate; (void)terminateSimulation;
    (void)nominalsOfContinuousStatesChanged; (void)valuesOfContinuousStatesChanged;
    (void)nextEventTimeDefined; (void)nextEventTime;
    return unsupported(instance, "fmi3UpdateDiscreteStates");
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterEventMode");
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return unsupported(instance, "fmi3EnterContinuousTimeMode");
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    return unsupported(instance, "fmi3CompletedIntegratorStep");
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    (void)time;
    return unsupported(instance, "fmi3SetTime");
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates; (void)nContinuousStates;
    return unsupported(instance, "fmi3SetContinuousStates");
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    (void)derivatives; (void)nContinuousStates;
    return unsupported(instance, "fmi3GetContinuousStateDerivatives");
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators) {
    (void)eventIndicators; (void)nEventIndicators;
    return unsupported(instance, "fmi3GetEventIndicators");
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates; (void)nContinuousStates;
    return unsupported(instance, "fmi3GetContinuousStates");
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    (void)nominals; (void)nContinuousStates;
    return unsupported(instance, "fmi3GetNominalsOfContinuousStates");
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    (void)nEventIndicators;
    return unsupported(instance, "fmi3GetNumberOfEventIndicators");
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    (void)nContinuousStates;
    return unsupported(instance, "fmi3GetNumberOfContinuousStates");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[],
                                    fmi3Float64 values[], size_t nValues) {
    (void)valueReferences; (void)nValueReferences; (void)orders; (void)values; (void)nValues;
    return unsupported(instance, "fmi3GetOutputDerivatives");
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference; (void)activationTime;
    return unsupported(instance, "fmi3ActivateModelPartition");
}
