/*
 * Version-independent co-simulation instance: state machine bookkeeping, argument and
 * call-order checks, logging through the importer's callback, variable access by value
 * reference, stepping with the Newmark kernel and FMU-state snapshots.  The FMI 2.0 and
 * FMI 3.0 API layers (fmi2Functions.c, fmi3Functions.c) are thin wrappers around it.
 */
#ifndef INSTANCE_H
#define INSTANCE_H

#include <stddef.h>

#include "model.h"
#include "newmark.h"

/* Value reference of the independent variable (time). */
#define VR_TIME 0

typedef enum {
    StartAndEnd        = 1 << 0,
    Instantiated       = 1 << 1,
    InitializationMode = 1 << 2,
    StepComplete       = 1 << 3,   /* FMI 2 slaveInitialized / FMI 3 step mode */
    StepFailed         = 1 << 4,
    Terminated         = 1 << 5,
    ErrorState         = 1 << 6,
    FatalState         = 1 << 7
} ModelState;

#define STATE_AFTER_INIT (StepComplete | StepFailed | Terminated | ErrorState)
#define STATE_ANY_LIVE   (Instantiated | InitializationMode | STATE_AFTER_INIT)

/* The FMI type of a variable (of a parameter, in PARAMETER_KINDS of config.h; the codes are fmus.py's
 * PARAMETER_KIND_CODES): each type has its own get/set functions, which refuse a variable of another type. */
typedef enum {
    KindFloat64 = 0,
    KindFloat32 = 1,
    KindInt8 = 2,
    KindUInt8 = 3,
    KindInt16 = 4,
    KindUInt16 = 5,
    KindInt32 = 6,   /* also FMI 2 Integer */
    KindUInt32 = 7,
    KindInt64 = 8,
    KindUInt64 = 9,
    KindBoolean = 10
} VariableKind;

typedef struct ModelInstance ModelInstance;

/* Generic function pointer: holds the importer's logger of either FMI version. */
typedef void (*GenericFunction)(void);

/* Forwards one formatted message to the importer's logger. */
typedef void (*LogFunction)(const ModelInstance *instance, Status status, const char *category,
                            const char *message);

/* Everything an FMU state snapshot restores. */
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

struct ModelInstance {
    char *instanceName;
    LogFunction log;
    GenericFunction logger;
    void *environment;
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
};

void logError(const ModelInstance *instance, const char *format, ...);
void logEvent(const ModelInstance *instance, const char *format, ...);

/* Keep the worst status; leave through END on Error or worse (needs `Status status`). */
#define CALL(expression) \
    do { Status s_ = (expression); if (s_ > status) status = s_; if (status > Warning) goto END; } while (0)

ModelInstance *createInstance(const char *instanceName, const char *token,
                              const Allocator *allocator, LogFunction log, GenericFunction logger,
                              void *environment, int loggingOn);
void freeInstance(ModelInstance *instance);

Status checkState(const ModelInstance *instance, const char *function, int allowed);
Status checkNotNull(const ModelInstance *instance, const char *function, const void *pointer,
                    const char *argument);
Status finishCall(ModelInstance *instance, Status status);

Status setDebugLogging(ModelInstance *instance, const char *function, int loggingOn,
                       size_t nCategories, const char *const categories[]);
Status setupExperiment(ModelInstance *instance, double startTime, int stopTimeDefined,
                       double stopTime);
Status exitInitialization(ModelInstance *instance);
void resetInstance(ModelInstance *instance);

Status getFloat64(ModelInstance *instance, const char *function, const unsigned int vr[],
                  size_t nvr, double value[]);
Status setFloat64(ModelInstance *instance, const char *function, const unsigned int vr[],
                  size_t nvr, const double value[]);
/* Parameters of an integer or Boolean kind (values as doubles: integers exact up to 2^53, Booleans 0 or 1); every
 * value reference must be a parameter of that kind. */
Status getParameters(ModelInstance *instance, const char *function, VariableKind kind, const unsigned int vr[],
                     size_t nvr, double value[]);
Status setParameters(ModelInstance *instance, const char *function, VariableKind kind, const unsigned int vr[],
                     size_t nvr, const double value[]);
Status doStep(ModelInstance *instance, const char *function, double point, double h);

Status getState(ModelInstance *instance, const char *function, void **state);
Status setState(ModelInstance *instance, const char *function, const void *state);
void freeState(ModelInstance *instance, void **state);
size_t serializedStateSize(void);
Status serializeState(ModelInstance *instance, const char *function, const void *state,
                      unsigned char buffer[], size_t size);
Status deserializeState(ModelInstance *instance, const char *function,
                        const unsigned char buffer[], size_t size, void **state);

#endif /* INSTANCE_H */
