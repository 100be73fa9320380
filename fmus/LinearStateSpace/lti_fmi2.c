/*
 * FMI 2.0 model-exchange and co-simulation API over the linear state-space kernel (lti.h).
 * Events only where the generated model has them (a time event, one event indicator); no FMU
 * states, no directional derivatives: those functions answer fmi2Error.
 */
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "lti.h"

extern const int LTI_HAS_ME, LTI_HAS_CS;

typedef struct {
    LtiInstance *inst;
    fmi2CallbackFunctions callbacks;
} Fmi2Wrapper;

#define INST(c) (((Fmi2Wrapper *)(c))->inst)
#define CHECK(c, name, allowed)                                          \
    LtiInstance *inst;                                                   \
    if (!(c)) return fmi2Error;                                          \
    inst = INST(c);                                                      \
    if (ltiCheckPhase(inst, name, allowed) != LtiOK) return fmi2Error;

static void forwardLog(const LtiInstance *inst, LtiStatus status, const char *category,
                       const char *message) {
    const fmi2CallbackFunctions *callbacks = (const fmi2CallbackFunctions *)inst->context;
    if (callbacks && callbacks->logger) {
        callbacks->logger(callbacks->componentEnvironment, inst->name, (fmi2Status)status,
                          category, message);
    }
}

static fmi2Status finish(LtiInstance *inst, LtiStatus status) {
    return (fmi2Status)ltiFail(inst, status);
}

static fmi2Status unsupported(fmi2Component c, const char *name) {
    if (!c) return fmi2Error;
    ltiLog(INST(c), LtiError, "logStatusError", "%s is not supported by this FMU", name);
    return fmi2Error;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    CHECK(c, "fmi2SetDebugLogging", PHASE_ANY);
    (void)nCategories;
    (void)categories;
    inst->loggingOn = loggingOn;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    Fmi2Wrapper *wrapper;
    int cs = fmuType == fmi2CoSimulation;
    (void)fmuResourceLocation;
    (void)visible;

    if (!functions || !functions->logger) return NULL;
    if (!fmuGUID || strcmp(fmuGUID, LTI_INSTANTIATION_TOKEN) != 0) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error,
                          "logStatusError", "fmi2Instantiate: wrong GUID");
        return NULL;
    }
    if ((cs && !LTI_HAS_CS) || (!cs && !LTI_HAS_ME)) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error,
                          "logStatusError",
                          "fmi2Instantiate: this FMU does not provide the requested interface");
        return NULL;
    }
    wrapper = (Fmi2Wrapper *)calloc(1, sizeof(Fmi2Wrapper));
    if (!wrapper) return NULL;
    wrapper->callbacks = *functions;
    wrapper->inst = ltiCreate(instanceName, cs, forwardLog, &wrapper->callbacks, NULL,
                              functions->componentEnvironment, loggingOn);
    if (!wrapper->inst) {
        free(wrapper);
        return NULL;
    }
    return wrapper;
}

void fmi2FreeInstance(fmi2Component c) {
    if (!c) return;
    ltiFree(INST(c));
    free(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    CHECK(c, "fmi2SetupExperiment", PhaseInstantiated);
    ltiSetStopTime(inst, stopTimeDefined, stopTime);
    if (toleranceDefined) inst->tolerance = tolerance;
    inst->time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    CHECK(c, "fmi2EnterInitializationMode", PhaseInstantiated);
    inst->phase = PhaseInitialization;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    CHECK(c, "fmi2ExitInitializationMode", PhaseInitialization);
    ltiExitInitialization(inst);
    if (ltiEvaluate(inst, "fmi2ExitInitializationMode") != LtiOK) return finish(inst, LtiError);
    ltiStartEvents(inst);
    if (inst->isCoSimulation) ltiUpdateDiscrete(inst, NULL, NULL);  /* model exchange: the importer's event iteration */
    inst->phase = inst->isCoSimulation ? PhaseStep : PhaseEvent;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    CHECK(c, "fmi2Terminate", PHASE_RUNNING);
    inst->phase = PhaseTerminated;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    CHECK(c, "fmi2Reset", PHASE_ANY);
    ltiReset(inst);
    return fmi2OK;
}

/* ------------------------------------------------------------------ variables */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    CHECK(c, "fmi2GetReal", PHASE_ANY);
    return finish(inst, ltiGetReal(inst, "fmi2GetReal", vr, nvr, value, nvr));
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    CHECK(c, "fmi2SetReal", PHASE_BEFORE_INIT | PHASE_RUNNING);
    return finish(inst, ltiSetReal(inst, "fmi2SetReal", vr, nvr, value, nvr));
}

static fmi2Status noVariables(fmi2Component c, const char *name, size_t nvr) {
    CHECK(c, name, PHASE_ANY);
    if (nvr == 0) return fmi2OK;
    ltiLog(inst, LtiError, "logStatusError", "%s: the model has no variables of this type", name);
    return fmi2Error;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    if (!LTI_DISCRETE_PARAMETERS && !LTI_TYPED_PARAMETERS) return noVariables(c, "fmi2GetInteger", nvr);
    CHECK(c, "fmi2GetInteger", PHASE_ANY);
    return finish(inst, ltiGetInteger(inst, "fmi2GetInteger", LTI_INTEGER | LTI_ENUMERATION, vr, nvr, value));
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    if (!LTI_ENABLE_INPUT && !LTI_DISCRETE_PARAMETERS) return noVariables(c, "fmi2GetBoolean", nvr);
    CHECK(c, "fmi2GetBoolean", PHASE_ANY);
    return finish(inst, ltiGetBoolean(inst, "fmi2GetBoolean", vr, nvr, value));   /* (fmi2Boolean is int) */
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    (void)vr; (void)value;
    return noVariables(c, "fmi2GetString", nvr);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    if (!LTI_DISCRETE_PARAMETERS && !LTI_TYPED_PARAMETERS) return noVariables(c, "fmi2SetInteger", nvr);
    CHECK(c, "fmi2SetInteger", PHASE_BEFORE_INIT);
    return finish(inst, ltiSetInteger(inst, "fmi2SetInteger", LTI_INTEGER | LTI_ENUMERATION, vr, nvr, value));
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    if (!LTI_ENABLE_INPUT && !LTI_DISCRETE_PARAMETERS) return noVariables(c, "fmi2SetBoolean", nvr);
    CHECK(c, "fmi2SetBoolean", PHASE_BEFORE_INIT | PHASE_RUNNING);
    return finish(inst, ltiSetBoolean(inst, "fmi2SetBoolean", vr, nvr, value));
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    (void)vr; (void)value;
    return noVariables(c, "fmi2SetString", nvr);
}

/* ------------------------------------------------------ unsupported features */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)state;
    return unsupported(c, "fmi2GetFMUstate");
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    (void)state;
    return unsupported(c, "fmi2SetFMUstate");
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)state;
    return unsupported(c, "fmi2FreeFMUstate");
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    (void)state; (void)size;
    return unsupported(c, "fmi2SerializedFMUstateSize");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[],
                                 size_t size) {
    (void)state; (void)bytes; (void)size;
    return unsupported(c, "fmi2SerializeFMUstate");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size,
                                   fmi2FMUstate *state) {
    (void)state; (void)bytes; (void)size;
    return unsupported(c, "fmi2DeSerializeFMUstate");
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference unknowns[],
                                        size_t nUnknown, const fmi2ValueReference knowns[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)unknowns; (void)nUnknown; (void)knowns; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    return unsupported(c, "fmi2GetDirectionalDerivative");
}

/* ------------------------------------------------------------ model exchange */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    CHECK(c, "fmi2EnterEventMode", PhaseEvent | PhaseContinuous);
    inst->phase = PhaseEvent;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
    int nextDefined, statesChanged;
    double nextTime;
    CHECK(c, "fmi2NewDiscreteStates", PhaseEvent);
    statesChanged = ltiUpdateDiscrete(inst, &nextDefined, &nextTime);
    info->newDiscreteStatesNeeded = fmi2False;
    info->terminateSimulation = ltiTerminateEvent(inst, &nextDefined, &nextTime) ? fmi2True : fmi2False;
    info->nominalsOfContinuousStatesChanged = fmi2False;
    info->valuesOfContinuousStatesChanged = statesChanged ? fmi2True : fmi2False;
    info->nextEventTimeDefined = nextDefined ? fmi2True : fmi2False;
    info->nextEventTime = nextTime;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    CHECK(c, "fmi2EnterContinuousTimeMode", PhaseEvent);
    ltiEnterContinuousMode(inst);
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode,
                                       fmi2Boolean *terminateSimulation) {
    CHECK(c, "fmi2CompletedIntegratorStep", PhaseContinuous);
    (void)noSetFMUStatePriorToCurrentPoint;
    *enterEventMode = ltiCompletedStep(inst) ? fmi2True : fmi2False;
    *terminateSimulation = ltiCompletedTerminate(inst) ? fmi2True : fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    CHECK(c, "fmi2SetTime", PhaseEvent | PhaseContinuous | PHASE_BEFORE_INIT);
    if (ltiCheckStopTime(inst, "fmi2SetTime", time) != LtiOK) return finish(inst, LtiError);
    return finish(inst, ltiSetTime(inst, "fmi2SetTime", time));
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    CHECK(c, "fmi2SetContinuousStates", PhaseContinuous | PhaseEvent);
    if (nx != 2 * inst->nq) {
        ltiLog(inst, LtiError, "logStatusError", "fmi2SetContinuousStates: %lu states, expected %lu",
               (unsigned long)nx, (unsigned long)(2 * inst->nq));
        return finish(inst, LtiError);
    }
    return finish(inst, ltiSetStates(inst, x, nx));
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    CHECK(c, "fmi2GetDerivatives", PHASE_ANY);
    if (nx != 2 * inst->nq) {
        ltiLog(inst, LtiError, "logStatusError", "fmi2GetDerivatives: %lu states, expected %lu",
               (unsigned long)nx, (unsigned long)(2 * inst->nq));
        return finish(inst, LtiError);
    }
    return finish(inst, ltiDerivatives(inst, "fmi2GetDerivatives", derivatives));
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    CHECK(c, "fmi2GetEventIndicators", PHASE_ANY);
    /* a wrong count is an error of the call, not of the instance */
    return (fmi2Status)ltiEventIndicators(inst, "fmi2GetEventIndicators", eventIndicators, ni);
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    CHECK(c, "fmi2GetContinuousStates", PHASE_ANY);
    if (nx != 2 * inst->nq) {
        ltiLog(inst, LtiError, "logStatusError", "fmi2GetContinuousStates: %lu states, expected %lu",
               (unsigned long)nx, (unsigned long)(2 * inst->nq));
        return finish(inst, LtiError);
    }
    ltiGetStates(inst, x);
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real nominals[], size_t nx) {
    size_t i;
    CHECK(c, "fmi2GetNominalsOfContinuousStates", PHASE_ANY);
    for (i = 0; i < nx; i++) nominals[i] = 1.0;
    return fmi2OK;
}

/* ------------------------------------------------------------- co-simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return unsupported(c, "fmi2SetRealInputDerivatives");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[],
                                        fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return unsupported(c, "fmi2GetRealOutputDerivatives");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    double end = currentCommunicationPoint + communicationStepSize, slack = 1e-12 * communicationStepSize;
    CHECK(c, "fmi2DoStep", PhaseStep);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (ltiCheckStopTime(inst, "fmi2DoStep", end) != LtiOK) return finish(inst, LtiError);
    if (LTI_CS_TERMINATE && end >= LTI_CS_TERMINATE_AT - slack) {
        /* the model calls terminate() at LTI_CS_TERMINATE_AT: the step stops there and is discarded (FMI 2.0
           section 4.2.2); fmi2GetBooleanStatus(fmi2Terminated) says why, fmi2LastSuccessfulTime where */
        double h = LTI_CS_TERMINATE_AT - currentCommunicationPoint;
        LtiStatus status = ltiDoStep(inst, currentCommunicationPoint, h > 0.0 ? h : 0.0);
        if (status > LtiWarning) return finish(inst, status);
        inst->terminated = 1;
        ltiLog(inst, LtiDiscard, "logStatusDiscard", "fmi2DoStep: the model called terminate() at t=%g",
               inst->time);
        return fmi2Discard;
    }
    return finish(inst, ltiDoStep(inst, currentCommunicationPoint, communicationStepSize));
}

fmi2Status fmi2CancelStep(fmi2Component c) { return unsupported(c, "fmi2CancelStep"); }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s; (void)value;
    return unsupported(c, "fmi2GetStatus");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    CHECK(c, "fmi2GetRealStatus", PHASE_ANY);
    if (s == fmi2LastSuccessfulTime) {
        *value = inst->time;
        return fmi2OK;
    }
    return unsupported(c, "fmi2GetRealStatus");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s; (void)value;
    return unsupported(c, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    if (LTI_CS_TERMINATE && s == fmi2Terminated) {   /* (other FMUs refuse the query, as many exporters' do) */
        CHECK(c, "fmi2GetBooleanStatus", PHASE_ANY);
        *value = inst->terminated ? fmi2True : fmi2False;
        return fmi2OK;
    }
    return unsupported(c, "fmi2GetBooleanStatus");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s; (void)value;
    return unsupported(c, "fmi2GetStringStatus");
}
