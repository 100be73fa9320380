/*
 * FMI 3.0 model-exchange and co-simulation API over the linear state-space kernel (lti.h),
 * with configuration mode for the structural size of array FMUs, and the events the generated
 * model may have (a time event, one event indicator) in model exchange.  Event mode in
 * co-simulation, clocks, FMU states and derivatives of any kind are not provided: those
 * functions answer fmi3Error with a logged message.
 */
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "lti.h"

extern const int LTI_HAS_ME, LTI_HAS_CS;

#define CHECK(instance, name, allowed)                                               \
    LtiInstance *inst = (LtiInstance *)(instance);                                    \
    if (!inst) return fmi3Error;                                                      \
    if (ltiCheckPhase(inst, name, allowed) != LtiOK) return fmi3Error;

static void forwardLog(const LtiInstance *inst, LtiStatus status, const char *category,
                       const char *message) {
    fmi3LogMessageCallback logger = (fmi3LogMessageCallback)inst->callback;
    if (logger) logger(inst->environment, (fmi3Status)status, category, message);
}

static fmi3Status finish(LtiInstance *inst, LtiStatus status) {
    return (fmi3Status)ltiFail(inst, status);
}

static fmi3Status unsupported(fmi3Instance instance, const char *name) {
    if (!instance) return fmi3Error;
    ltiLog((LtiInstance *)instance, LtiError, "logStatusError", "%s is not supported by this FMU",
           name);
    return fmi3Error;
}

static fmi3Status noVariables(fmi3Instance instance, const char *name, size_t nvr) {
    CHECK(instance, name, PHASE_ANY);
    if (nvr == 0) return fmi3OK;
    ltiLog(inst, LtiError, "logStatusError", "%s: the model has no variables of this type", name);
    return fmi3Error;
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    CHECK(instance, "fmi3SetDebugLogging", PHASE_ANY);
    (void)nCategories;
    (void)categories;
    inst->loggingOn = loggingOn;
    return fmi3OK;
}

static fmi3Instance instantiate(fmi3String name, fmi3String token, int cs, fmi3Boolean loggingOn,
                                fmi3InstanceEnvironment environment,
                                fmi3LogMessageCallback logMessage) {
    if (!token || strcmp(token, LTI_INSTANTIATION_TOKEN) != 0) {
        if (logMessage) logMessage(environment, fmi3Error, "logStatusError",
                                   "fmi3Instantiate: wrong instantiation token");
        return NULL;
    }
    if ((cs && !LTI_HAS_CS) || (!cs && !LTI_HAS_ME)) {
        if (logMessage) logMessage(environment, fmi3Error, "logStatusError",
                                   "fmi3Instantiate: this FMU does not provide the requested "
                                   "interface");
        return NULL;
    }
    return ltiCreate(name, cs, forwardLog, NULL, (LtiCallback)logMessage, environment,
                     loggingOn);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)resourcePath;
    (void)visible;
    return instantiate(instanceName, instantiationToken, 0, loggingOn, instanceEnvironment,
                       logMessage);
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
    (void)resourcePath; (void)visible; (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables; (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    if (eventModeUsed) {
        if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                                   "fmi3InstantiateCoSimulation: event mode is not supported");
        return NULL;
    }
    return instantiate(instanceName, instantiationToken, 1, loggingOn, instanceEnvironment,
                       logMessage);
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
    if (logMessage) logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                               "scheduled execution is not supported by this FMU");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { ltiFree((LtiInstance *)instance); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    CHECK(instance, "fmi3EnterInitializationMode", PhaseInstantiated);
    ltiSetStopTime(inst, stopTimeDefined, stopTime);
    if (toleranceDefined) inst->tolerance = tolerance;
    inst->time = startTime;
    inst->phase = PhaseInitialization;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    CHECK(instance, "fmi3ExitInitializationMode", PhaseInitialization);
    ltiExitInitialization(inst);
    if (ltiEvaluate(inst, "fmi3ExitInitializationMode") != LtiOK) return finish(inst, LtiError);
    ltiStartEvents(inst);
    if (inst->isCoSimulation) ltiUpdateDiscrete(inst, NULL, NULL);  /* model exchange: the importer's event iteration */
    inst->phase = inst->isCoSimulation ? PhaseStep : PhaseEvent;
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    CHECK(instance, "fmi3EnterEventMode", PhaseEvent | PhaseContinuous);
    if (inst->isCoSimulation) return unsupported(instance, "fmi3EnterEventMode in co-simulation");
    inst->phase = PhaseEvent;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    CHECK(instance, "fmi3Terminate", PHASE_RUNNING);
    inst->phase = PhaseTerminated;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    CHECK(instance, "fmi3Reset", PHASE_ANY);
    ltiReset(inst);
    return fmi3OK;
}

/* ------------------------------------------------------------------ variables */

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    CHECK(instance, "fmi3GetFloat64", PHASE_ANY);
    return finish(inst, ltiGetReal(inst, "fmi3GetFloat64", valueReferences, nValueReferences,
                                   values, nValues));
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    CHECK(instance, "fmi3SetFloat64", PhaseInstantiated | PhaseInitialization | PHASE_RUNNING);
    return finish(inst, ltiSetReal(inst, "fmi3SetFloat64", valueReferences, nValueReferences,
                                   values, nValues));
}

/* Float32: the same values as Float64, rounded to single precision; in chunks, so no allocation is needed
   (the generated FMUs declare a variable Float32 only when an importer's single-precision path is tested) */
#define FLOAT32_CHUNK 64

/* Float32 arrays are not generated: one value per value reference, else an error that says so */
static int scalarsOnly(LtiInstance *inst, const char *function, size_t nValueReferences, size_t nValues) {
    if (nValues == nValueReferences) return 1;
    ltiLog(inst, LtiError, "logStatusError", "%s: only scalar Float32 variables (%lu values for %lu value "
           "references)", function, (unsigned long)nValues, (unsigned long)nValueReferences);
    return 0;
}

/* How many of the next value references (at most a chunk) go to the state slots together: up to the Float32
   parameter of LTI_TYPED_PARAMETERS, 0 where it is the first (served on its own) */
static size_t float32Run(const fmi3ValueReference valueReferences[], size_t left) {
    size_t count = 0;
    while (count < left && count < FLOAT32_CHUNK && !ltiIsTolerance(valueReferences[count])) count++;
    return count;
}

fmi3Status fmi3GetFloat32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float32 values[], size_t nValues) {
    double chunk[FLOAT32_CHUNK];
    size_t done = 0;
    CHECK(instance, "fmi3GetFloat32", PHASE_ANY);
    if (!scalarsOnly(inst, "fmi3GetFloat32", nValueReferences, nValues)) return finish(inst, LtiError);
    while (done < nValueReferences) {
        size_t count = float32Run(valueReferences + done, nValueReferences - done);
        LtiStatus status;
        if (count == 0) {   /* the Float32 parameter of LTI_TYPED_PARAMETERS */
            values[done++] = inst->relTol;
            continue;
        }
        status = ltiGetReal(inst, "fmi3GetFloat32", valueReferences + done, count, chunk, count);
        if (status != LtiOK) return finish(inst, status);
        for (size_t k = 0; k < count; k++) values[done + k] = (fmi3Float32)chunk[k];
        done += count;
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float32 values[], size_t nValues) {
    double chunk[FLOAT32_CHUNK];
    size_t done = 0;
    CHECK(instance, "fmi3SetFloat32", PhaseInstantiated | PhaseInitialization | PHASE_RUNNING);
    if (!scalarsOnly(inst, "fmi3SetFloat32", nValueReferences, nValues)) return finish(inst, LtiError);
    while (done < nValueReferences) {
        size_t count = float32Run(valueReferences + done, nValueReferences - done);
        LtiStatus status;
        if (count == 0) {   /* the Float32 parameter of LTI_TYPED_PARAMETERS */
            inst->relTol = values[done++];
            continue;
        }
        for (size_t k = 0; k < count; k++) chunk[k] = (double)values[done + k];
        status = ltiSetReal(inst, "fmi3SetFloat32", valueReferences + done, count, chunk, count);
        if (status != LtiOK) return finish(inst, status);
        done += count;
    }
    return fmi3OK;
}

fmi3Status fmi3GetUInt64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, fmi3UInt64 values[], size_t nValues) {
    CHECK(instance, "fmi3GetUInt64", PHASE_ANY);
    if (nValues < nValueReferences) return finish(inst, LtiError);
    return finish(inst, ltiGetSize(inst, "fmi3GetUInt64", valueReferences, nValueReferences,
                                   (unsigned long long *)values));
}

fmi3Status fmi3SetUInt64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const fmi3UInt64 values[], size_t nValues) {
    CHECK(instance, "fmi3SetUInt64", PHASE_ANY);
    if (nValues < nValueReferences) return finish(inst, LtiError);
    /* a rejected size is an error of the call, not of the instance */
    return (fmi3Status)ltiSetSize(inst, "fmi3SetUInt64", valueReferences, nValueReferences,
                                  (const unsigned long long *)values);
}

#define NO_GETTER(NAME, TYPE)                                                                  \
    fmi3Status NAME(fmi3Instance instance, const fmi3ValueReference valueReferences[],         \
                    size_t nValueReferences, TYPE values[], size_t nValues) {                  \
        (void)valueReferences; (void)values; (void)nValues;                                    \
        return noVariables(instance, #NAME, nValueReferences);                                 \
    }
#define NO_SETTER(NAME, TYPE)                                                                  \
    fmi3Status NAME(fmi3Instance instance, const fmi3ValueReference valueReferences[],         \
                    size_t nValueReferences, const TYPE values[], size_t nValues) {            \
        (void)valueReferences; (void)values; (void)nValues;                                    \
        return noVariables(instance, #NAME, nValueReferences);                                 \
    }

NO_GETTER(fmi3GetInt8, fmi3Int8)
NO_GETTER(fmi3GetUInt8, fmi3UInt8)
NO_GETTER(fmi3GetInt16, fmi3Int16)
NO_GETTER(fmi3GetUInt16, fmi3UInt16)
NO_GETTER(fmi3GetUInt32, fmi3UInt32)
NO_GETTER(fmi3GetString, fmi3String)
NO_SETTER(fmi3SetInt8, fmi3Int8)
NO_SETTER(fmi3SetUInt8, fmi3UInt8)
NO_SETTER(fmi3SetInt16, fmi3Int16)
NO_SETTER(fmi3SetUInt16, fmi3UInt16)
NO_SETTER(fmi3SetUInt32, fmi3UInt32)
NO_SETTER(fmi3SetString, fmi3String)

/* Int32: the parameter of LTI_DISCRETE_PARAMETERS only (fmi3Int32 is a C int32_t: converted element by element) */
fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Int32 values[], size_t nValues) {
    size_t i;
    int value;
    if (!LTI_DISCRETE_PARAMETERS) return noVariables(instance, "fmi3GetInt32", nValueReferences);
    CHECK(instance, "fmi3GetInt32", PHASE_ANY);
    if (nValues < nValueReferences) return finish(inst, LtiError);
    for (i = 0; i < nValueReferences; i++) {
        if (ltiGetInteger(inst, "fmi3GetInt32", LTI_INTEGER, valueReferences + i, 1, &value) != LtiOK)
            return finish(inst, LtiError);
        values[i] = (fmi3Int32)value;
    }
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Int32 values[], size_t nValues) {
    size_t i;
    int value;
    if (!LTI_DISCRETE_PARAMETERS) return noVariables(instance, "fmi3SetInt32", nValueReferences);
    CHECK(instance, "fmi3SetInt32", PHASE_BEFORE_INIT);
    if (nValues < nValueReferences) return finish(inst, LtiError);
    for (i = 0; i < nValueReferences; i++) {
        value = (int)values[i];
        if (ltiSetInteger(inst, "fmi3SetInt32", LTI_INTEGER, valueReferences + i, 1, &value) != LtiOK)
            return finish(inst, LtiError);
    }
    return fmi3OK;
}

/* Int64: the Enumeration parameter of LTI_TYPED_PARAMETERS only (FMI 3 gets and sets an Enumeration as an Int64) */
fmi3Status fmi3GetInt64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Int64 values[], size_t nValues) {
    size_t i;
    int value;
    if (!LTI_TYPED_PARAMETERS) return noVariables(instance, "fmi3GetInt64", nValueReferences);
    CHECK(instance, "fmi3GetInt64", PHASE_ANY);
    if (nValues < nValueReferences) return finish(inst, LtiError);
    for (i = 0; i < nValueReferences; i++) {
        if (ltiGetInteger(inst, "fmi3GetInt64", LTI_ENUMERATION, valueReferences + i, 1, &value) != LtiOK)
            return finish(inst, LtiError);
        values[i] = (fmi3Int64)value;
    }
    return fmi3OK;
}

fmi3Status fmi3SetInt64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Int64 values[], size_t nValues) {
    size_t i;
    int value;
    if (!LTI_TYPED_PARAMETERS) return noVariables(instance, "fmi3SetInt64", nValueReferences);
    CHECK(instance, "fmi3SetInt64", PHASE_BEFORE_INIT);
    if (nValues < nValueReferences) return finish(inst, LtiError);
    for (i = 0; i < nValueReferences; i++) {
        value = values[i] < -2147483647 || values[i] > 2147483647 ? 0 : (int)values[i];   /* (0: no item's) */
        if (ltiSetInteger(inst, "fmi3SetInt64", LTI_ENUMERATION, valueReferences + i, 1, &value) != LtiOK)
            return finish(inst, LtiError);
    }
    return fmi3OK;
}

/* Booleans: the enable input of LTI_ENABLE_INPUT only (fmi3Boolean is a C bool: converted element by element) */
fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Boolean values[], size_t nValues) {
    size_t i;
    int value;
    if (!LTI_ENABLE_INPUT && !LTI_DISCRETE_PARAMETERS) return noVariables(instance, "fmi3GetBoolean", nValueReferences);
    CHECK(instance, "fmi3GetBoolean", PHASE_ANY);
    if (nValues < nValueReferences) return finish(inst, LtiError);
    for (i = 0; i < nValueReferences; i++) {
        if (ltiGetBoolean(inst, "fmi3GetBoolean", valueReferences + i, 1, &value) != LtiOK)
            return finish(inst, LtiError);
        values[i] = value ? fmi3True : fmi3False;
    }
    return fmi3OK;
}

fmi3Status fmi3SetBoolean(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Boolean values[], size_t nValues) {
    size_t i;
    int value;
    if (!LTI_ENABLE_INPUT && !LTI_DISCRETE_PARAMETERS) return noVariables(instance, "fmi3SetBoolean", nValueReferences);
    CHECK(instance, "fmi3SetBoolean", PHASE_BEFORE_INIT | PHASE_RUNNING);
    if (nValues < nValueReferences) return finish(inst, LtiError);
    for (i = 0; i < nValueReferences; i++) {
        value = values[i] ? 1 : 0;
        if (ltiSetBoolean(inst, "fmi3SetBoolean", valueReferences + i, 1, &value) != LtiOK)
            return finish(inst, LtiError);
    }
    return fmi3OK;
}

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

/* ------------------------------------------------------------- configuration */

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    CHECK(instance, "fmi3EnterConfigurationMode", PhaseInstantiated);
    inst->phase = PhaseConfiguration;
    inst->nqPending = inst->nq;
    return fmi3OK;
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    CHECK(instance, "fmi3ExitConfigurationMode", PhaseConfiguration);
    return finish(inst, ltiExitConfiguration(inst));
}

/* ------------------------------------------------------ unsupported features */

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
                                       fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent; (void)elementIndicesOfDependent; (void)independents;
    (void)elementIndicesOfIndependents; (void)dependencyKinds; (void)nDependencies;
    return unsupported(instance, "fmi3GetVariableDependencies");
}

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    (void)FMUState;
    return unsupported(instance, "fmi3GetFMUState");
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    (void)FMUState;
    return unsupported(instance, "fmi3SetFMUState");
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    (void)FMUState;
    return unsupported(instance, "fmi3FreeFMUState");
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState,
                                      size_t *size) {
    (void)FMUState; (void)size;
    return unsupported(instance, "fmi3SerializedFMUStateSize");
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size) {
    (void)FMUState; (void)serializedState; (void)size;
    return unsupported(instance, "fmi3SerializeFMUState");
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState) {
    (void)FMUState; (void)serializedState; (void)size;
    return unsupported(instance, "fmi3DeserializeFMUState");
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

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals; (void)qualifiers;
    return unsupported(instance, "fmi3GetIntervalDecimal");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance,
                                   const fmi3ValueReference valueReferences[],
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

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance,
                                   const fmi3ValueReference valueReferences[],
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

/* ------------------------------------------------------------ model exchange */

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    int nextDefined, statesChanged, terminate;
    double nextTime;
    CHECK(instance, "fmi3UpdateDiscreteStates", PhaseEvent);
    statesChanged = ltiUpdateDiscrete(inst, &nextDefined, &nextTime);
    terminate = ltiTerminateEvent(inst, &nextDefined, &nextTime);
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation) *terminateSimulation = terminate ? fmi3True : fmi3False;
    if (nominalsOfContinuousStatesChanged) *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged) *valuesOfContinuousStatesChanged = statesChanged ? fmi3True : fmi3False;
    if (nextEventTimeDefined) *nextEventTimeDefined = nextDefined ? fmi3True : fmi3False;
    if (nextEventTime) *nextEventTime = nextTime;
    return fmi3OK;
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    CHECK(instance, "fmi3EnterContinuousTimeMode", PhaseEvent);
    ltiEnterContinuousMode(inst);
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    CHECK(instance, "fmi3CompletedIntegratorStep", PhaseContinuous);
    (void)noSetFMUStatePriorToCurrentPoint;
    *enterEventMode = ltiCompletedStep(inst) ? fmi3True : fmi3False;
    *terminateSimulation = ltiCompletedTerminate(inst) ? fmi3True : fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    CHECK(instance, "fmi3SetTime", PhaseEvent | PhaseContinuous);
    if (ltiCheckStopTime(inst, "fmi3SetTime", time) != LtiOK) return finish(inst, LtiError);
    return finish(inst, ltiSetTime(inst, "fmi3SetTime", time));
}

static LtiStatus checkStates(LtiInstance *inst, const char *function, size_t n) {
    if (n == 2 * inst->nq) return LtiOK;
    ltiLog(inst, LtiError, "logStatusError", "%s: %lu states, expected %lu", function,
           (unsigned long)n, (unsigned long)(2 * inst->nq));
    return LtiError;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    CHECK(instance, "fmi3SetContinuousStates", PhaseContinuous | PhaseEvent);
    if (checkStates(inst, "fmi3SetContinuousStates", nContinuousStates) != LtiOK)
        return finish(inst, LtiError);
    return finish(inst, ltiSetStates(inst, continuousStates, nContinuousStates));
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    CHECK(instance, "fmi3GetContinuousStateDerivatives", PHASE_ANY);
    if (checkStates(inst, "fmi3GetContinuousStateDerivatives", nContinuousStates) != LtiOK)
        return finish(inst, LtiError);
    return finish(inst, ltiDerivatives(inst, "fmi3GetContinuousStateDerivatives", derivatives));
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators) {
    CHECK(instance, "fmi3GetEventIndicators", PHASE_ANY);
    /* a wrong count is an error of the call, not of the instance */
    return (fmi3Status)ltiEventIndicators(inst, "fmi3GetEventIndicators", eventIndicators,
                                          nEventIndicators);
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    CHECK(instance, "fmi3GetContinuousStates", PHASE_ANY);
    if (checkStates(inst, "fmi3GetContinuousStates", nContinuousStates) != LtiOK)
        return finish(inst, LtiError);
    ltiGetStates(inst, continuousStates);
    return fmi3OK;
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    size_t i;
    CHECK(instance, "fmi3GetNominalsOfContinuousStates", PHASE_ANY);
    for (i = 0; i < nContinuousStates; i++) nominals[i] = 1.0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    CHECK(instance, "fmi3GetNumberOfEventIndicators", PHASE_ANY);
    *nEventIndicators = ltiEventIndicatorCount();
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    CHECK(instance, "fmi3GetNumberOfContinuousStates", PHASE_ANY);
    *nContinuousStates = 2 * inst->nq;
    return fmi3OK;
}

/* ------------------------------------------------------------- co-simulation */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    CHECK(instance, "fmi3EnterStepMode", PhaseStep);
    return fmi3OK;
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    LtiStatus status;
    double end = currentCommunicationPoint + communicationStepSize, slack = 1e-12 * communicationStepSize;
    /* on request, a non-conforming FMU: it stops inside the step whether early return was allowed or not */
    int early = LTI_CS_EARLY_RETURN && LTI_CS_EARLY_RETURN_AT > currentCommunicationPoint + slack &&
                LTI_CS_EARLY_RETURN_AT < end - slack;
    CHECK(instance, "fmi3DoStep", PhaseStep);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (ltiCheckStopTime(inst, "fmi3DoStep", end) != LtiOK) return finish(inst, LtiError);
    status = ltiDoStep(inst, currentCommunicationPoint,
                       early ? LTI_CS_EARLY_RETURN_AT - currentCommunicationPoint : communicationStepSize);
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation)
        *terminateSimulation = LTI_CS_TERMINATE && inst->time >= LTI_CS_TERMINATE_AT - slack ? fmi3True : fmi3False;
    if (earlyReturn) *earlyReturn = early ? fmi3True : fmi3False;
    if (lastSuccessfulTime) *lastSuccessfulTime = inst->time;
    return finish(inst, status);
}
