/*
 * Kernel of the linear state-space FMUs built by fmu_opinf.lti_fmus (imitations of FMUs that
 * Modelica tools and LTI generators export): the ODE of a linear mechanical system in the
 * coordinates the "exporter" chose (q = state positions, qd = state velocities),
 *
 *     qdd = ( -stiffness_scale Kq q - Dq qd + Bq u + fq ) / mass_scale,
 *     x = T q + xoff,  v = T qd,  a = T qdd,  y = Cp x + Cv v + Ca a + y0,
 *
 * with variable access by value reference, explicit-Euler or RK4 co-simulation steps and the
 * call-order bookkeeping shared by the FMI 2.0 and FMI 3.0 layers (lti_fmi2.c, lti_fmi3.c).
 * Optional discrete events (off unless the generated model asks for them): a force offset that
 * switches on at a time event, and one that latches on when a position crosses a threshold (a
 * state event, one event indicator).  Both act only from the event on: the kernel changes them in
 * ltiUpdateDiscrete (event mode), never while the importer integrates.
 * The generated lti_model.c provides the sizes, the value-reference table and ltiAssemble().
 */
#ifndef LTI_H
#define LTI_H

#include <stddef.h>

typedef enum { LtiOK = 0, LtiWarning = 1, LtiDiscard = 2, LtiError = 3, LtiFatal = 4 } LtiStatus;

/* What a value reference designates. */
typedef enum {
    SlotTime, SlotQ, SlotQd, SlotQdd, SlotX, SlotV, SlotA, SlotY, SlotU, SlotPar,
    SlotQStart, SlotQdStart, SlotSize, SlotIndicator
} SlotKind;

typedef struct {
    int kind;      /* SlotKind */
    int index;     /* element (0-based); ignored for arrays */
    int isArray;   /* 1: the value reference holds every element (FMI 3 arrays) */
    int tunable;   /* 1: may be set after initialization (inputs); 2: a discrete input, which model exchange
                      may change only in event mode (LTI_DISCRETE_INPUTS) */
} LtiSlot;

/* Phases of the FMI state machines (both versions). */
typedef enum {
    PhaseInstantiated = 1 << 0,
    PhaseConfiguration = 1 << 1,
    PhaseInitialization = 1 << 2,
    PhaseEvent = 1 << 3,
    PhaseContinuous = 1 << 4,
    PhaseStep = 1 << 5,
    PhaseTerminated = 1 << 6,
    PhaseError = 1 << 7
} LtiPhase;

#define PHASE_BEFORE_INIT (PhaseInstantiated | PhaseConfiguration | PhaseInitialization)
#define PHASE_RUNNING (PhaseEvent | PhaseContinuous | PhaseStep)
#define PHASE_ANY (PHASE_BEFORE_INIT | PHASE_RUNNING | PhaseTerminated | PhaseError)

enum { CsEuler = 0, CsRungeKutta = 1, CsOneRungeKutta = 2 };  /* 2: one RK4 step per doStep */

typedef struct LtiInstance LtiInstance;
typedef void (*LtiCallback)(void);  /* any importer callback, cast back by the API layer */
typedef void (*LtiLogger)(const LtiInstance *inst, LtiStatus status, const char *category,
                          const char *message);

struct LtiInstance {
    char *name;
    LtiLogger log;
    void *context;       /* FMI 2: the importer's callback functions */
    LtiCallback callback; /* FMI 3: the importer's logMessage */
    void *environment;
    int loggingOn;
    int isCoSimulation;
    int phase;
    double time;
    double tolerance;    /* relative tolerance of the RK4 co-simulation */
    /* sizes: nq state coordinates (runtime for structural sizes), nx physical dofs */
    size_t nq, nx, nqPending;
    /* model matrices, row-major, allocated for the maximal size */
    double *Kq, *Dq, *Bq, *fq, *T, *xoff, *Cp, *Cv, *Ca, *y0;
    double *z, *zStart;  /* 2 nq: q then qd */
    double *u;           /* force inputs */
    double par[2];       /* mass_scale, stiffness_scale */
    double *qdd, *x, *v, *a, *y, *work;
    double *qddBefore;   /* LTI_STALE_DERIVATIVES: qdd at the start of the last doStep */
    double *yBefore;     /* LTI_LATE_OUTPUTS: y at the start of the last doStep */
    int upToDate;
    int stale;           /* LTI_STALE_DERIVATIVES: doStep done, no input set since */
    int late;            /* LTI_LATE_OUTPUTS: a doStep done */
    int timeEventOn;     /* LTI_TIME_EVENT: the time event has switched its force on */
    int stateEventOn;    /* LTI_STATE_EVENT: the state event has latched its force on */
    int indicatorAbove;  /* LTI_STATE_EVENT: indicator > 0 at the last event (or initialization) */
    double timeCompleted; /* LTI_COMPLETED_GAP: time of the last completed integrator step (or event) */
    int completedEventAsked; /* LTI_COMPLETED_EVENT: the event was asked for */
    int terminated;      /* LTI_CS_TERMINATE (FMI 2): the model called terminate() in a doStep */
    int enabled;         /* LTI_ENABLE_INPUT: the Boolean input that lets the forces act (start false) */
    int order;           /* LTI_DISCRETE_PARAMETERS: the Integer parameter (no effect on the model) */
    int cache;           /* LTI_DISCRETE_PARAMETERS: the Boolean parameter (no effect on the model) */
    int method;          /* LTI_TYPED_PARAMETERS: the Enumeration parameter (no effect on the model) */
    float relTol;        /* LTI_TYPED_PARAMETERS, FMI 3: the Float32 parameter (no effect on the model) */
    int stopDefined;     /* the stop time given to setupExperiment / enterInitializationMode, if any */
    double stopTime;
};

#define PAR_MASS_SCALE 0
#define PAR_STIFFNESS_SCALE 1

/* ---- provided by the generated lti_model.c */
extern const char *const LTI_INSTANTIATION_TOKEN;
extern const int LTI_CS_METHOD;
extern const int LTI_STALE_DERIVATIVES; /* 1: after doStep, der() of the velocities are the values before it */
extern const int LTI_LATE_OUTPUTS;      /* 1: the outputs are computed at the start of doStep only (one step late) */
extern const double LTI_CS_FIXED_STEP;  /* > 0: doStep refuses (error) any other communication step */
extern const double LTI_CS_MAX_STEP;    /* > 0: doStep discards a longer communication step */
extern const int LTI_CS_EARLY_RETURN;   /* 1: fmi3DoStep returns early at LTI_CS_EARLY_RETURN_AT, even unallowed */
extern const double LTI_CS_EARLY_RETURN_AT;
extern const int LTI_CS_TERMINATE;      /* 1: fmi3DoStep asks to terminate once its time reaches LTI_CS_TERMINATE_AT;
                                           fmi2DoStep stops there, returns fmi2Discard and answers fmi2Terminated */
extern const double LTI_CS_TERMINATE_AT;
extern const int LTI_ME_TERMINATE;      /* 1: model exchange: a time event at LTI_ME_TERMINATE_AT whose event
                                           iteration asks to terminate (a Modelica `when time >= T then terminate()`) */
extern const double LTI_ME_TERMINATE_AT;
/* LTI_COMPLETED_TERMINATE 1: model exchange: CompletedIntegratorStep asks to terminate once its time reaches
   LTI_COMPLETED_TERMINATE_AT (a stop checked in accepted integrator steps) */
extern const int LTI_COMPLETED_TERMINATE;
extern const double LTI_COMPLETED_TERMINATE_AT;
extern const size_t LTI_NQ_DEFAULT, LTI_NQ_MAX, LTI_NX_FIXED, LTI_NU, LTI_NY;
extern const int LTI_X_FOLLOWS_Q;   /* 1: nx = nq (array family); else nx = LTI_NX_FIXED */
extern const int LTI_INTERLEAVED;   /* 1: FMI state vector (q1, qd1, q2, qd2, ...) */
extern const size_t LTI_N_SLOTS;
extern const LtiSlot LTI_SLOTS[];
extern const double LTI_PAR_DEFAULTS[2];
/* Optional events: LTI_TIME_EVENT: qdd += LTI_TIME_EVENT_FQ (before the division by mass_scale) from
   the event at LTI_TIME_EVENT_AT on; LTI_STATE_EVENT: event indicator x[LTI_STATE_EVENT_DOF] +
   LTI_STATE_EVENT_INPUT_GAIN u[0] - LTI_STATE_EVENT_THRESHOLD, whose first change of sign latches on qdd += LTI_STATE_EVENT_FQ. */
extern const int LTI_TIME_EVENT, LTI_STATE_EVENT, LTI_TIME_EVENT_JUMP;
extern const double LTI_TIME_EVENT_AT, LTI_STATE_EVENT_THRESHOLD, LTI_STATE_EVENT_INPUT_GAIN;
extern const size_t LTI_STATE_EVENT_DOF;
extern const double LTI_TIME_EVENT_FQ[], LTI_STATE_EVENT_FQ[];
/* LTI_TIME_EVENT_JUMP: qd += LTI_TIME_EVENT_DQD at the time event (a reinit of the velocities). */
extern const double LTI_TIME_EVENT_DQD[];
/* LTI_COMPLETED_GAP > 0: the FMU needs CompletedIntegratorStep after every integrator step (as a Modelica delay()
   buffer does) and refuses SetTime more than LTI_COMPLETED_GAP after the last one.  LTI_COMPLETED_EVENT: the first
   completed step at or after LTI_COMPLETED_EVENT_AT asks for event mode (an event iteration that changes nothing);
   with LTI_COMPLETED_EVENT_EVERY, every one from then on does. */
extern const double LTI_COMPLETED_GAP, LTI_COMPLETED_EVENT_AT;
extern const int LTI_COMPLETED_EVENT, LTI_COMPLETED_EVENT_EVERY;
/* LTI_SINGLE_PRECISION 1: the derivatives are computed from the state rounded to float, each product's terms added in
   double but the accelerations and velocities returned rounded to float (an export for an embedded target); 2: only
   the stiffness forces on the first half of the degrees of freedom are, from the positions rounded to float (one
   single-precision block beside double-precision ones). */
extern const int LTI_SINGLE_PRECISION;
/* LTI_POSITION_LIMIT: the model asserts |x[LTI_POSITION_LIMIT_DOF]| <= LTI_POSITION_LIMIT_BOUND in every evaluation,
   as a Modelica assert on a variable's range does: beyond it, an error, and the instance stays in error (1), or a
   discard, the instance staying usable (2: a state outside the model's domain). */
extern const int LTI_POSITION_LIMIT;
extern const size_t LTI_POSITION_LIMIT_DOF;
extern const double LTI_POSITION_LIMIT_BOUND;
/* LTI_STEADY_START: initialization ends at the equilibrium q = LTI_STEADY_Q0 + LTI_STEADY_QU u (nq x nu,
   row-major), qd = 0, under the inputs set then (a Modelica steady-state initialization). */
extern const int LTI_STEADY_START;
/* LTI_ENABLE_INPUT: a Boolean input (value reference LTI_ENABLE_VR, start false) without which the force inputs do
   not act (a drive's enable, a Simulink enabled subsystem).  LTI_STRICT_STOP: the stop time given to the FMU is
   kept with no slack: a doStep whose end, or a SetTime, passes it returns an error (FMI: the run's final time). */
extern const int LTI_ENABLE_INPUT, LTI_STRICT_STOP;
extern const unsigned int LTI_ENABLE_VR;
/* LTI_DISCRETE_PARAMETERS: an Integer (FMI 3: Int32) parameter at LTI_ORDER_VR and a Boolean one at LTI_CACHE_VR,
   settable before initialization and without effect on the model (an exporter's solver settings). */
extern const int LTI_DISCRETE_PARAMETERS, LTI_ORDER_START, LTI_CACHE_START;
extern const unsigned int LTI_ORDER_VR, LTI_CACHE_VR;
/* LTI_TYPED_PARAMETERS: an Enumeration parameter at LTI_METHOD_VR (items 1 .. LTI_METHOD_ITEMS; FMI 2: Integer
   functions, FMI 3: Int64 ones) and, FMI 3, a Float32 one at LTI_TOLERANCE_VR, settable before initialization and
   without effect on the model (an exporter's solver choice and tolerance). */
extern const int LTI_TYPED_PARAMETERS, LTI_METHOD_START, LTI_METHOD_ITEMS;
extern const unsigned int LTI_METHOD_VR, LTI_TOLERANCE_VR;
extern const double LTI_TOLERANCE_START;
extern const double LTI_STEADY_Q0[], LTI_STEADY_QU[];
/* Fills the matrices and start values for the current nq. */
void ltiAssemble(LtiInstance *inst);

/* ---- kernel */
LtiInstance *ltiCreate(const char *name, int isCoSimulation, LtiLogger log, void *context,
                       LtiCallback callback, void *environment, int loggingOn);
void ltiFree(LtiInstance *inst);
void ltiReset(LtiInstance *inst);
void ltiLog(const LtiInstance *inst, LtiStatus status, const char *category, const char *format,
            ...);
LtiStatus ltiCheckPhase(LtiInstance *inst, const char *function, int allowed);
LtiStatus ltiEvaluate(LtiInstance *inst, const char *function);
LtiStatus ltiGetReal(LtiInstance *inst, const char *function, const unsigned int vr[], size_t nvr,
                     double values[], size_t nValues);
LtiStatus ltiSetReal(LtiInstance *inst, const char *function, const unsigned int vr[], size_t nvr,
                     const double values[], size_t nValues);
LtiStatus ltiGetSize(LtiInstance *inst, const char *function, const unsigned int vr[], size_t nvr,
                     unsigned long long values[]);
LtiStatus ltiSetSize(LtiInstance *inst, const char *function, const unsigned int vr[], size_t nvr,
                     const unsigned long long values[]);
LtiStatus ltiExitConfiguration(LtiInstance *inst);
LtiStatus ltiDerivatives(LtiInstance *inst, const char *function, double dz[]);
LtiStatus ltiSetStates(LtiInstance *inst, const double z[], size_t n);
void ltiGetStates(const LtiInstance *inst, double z[]);
LtiStatus ltiDoStep(LtiInstance *inst, double t, double h);
/* events: number of indicators, their values at the current state, the discrete update of event mode
   (next time event, if any, in *nextTime with *nextDefined = 1), and the start of the event bookkeeping */
size_t ltiEventIndicatorCount(void);
LtiStatus ltiEventIndicators(LtiInstance *inst, const char *function, double values[], size_t n);
/* Returns 1 if the continuous states changed (the time event's velocity jump), else 0. */
int ltiUpdateDiscrete(LtiInstance *inst, int *nextDefined, double *nextTime);
/* LTI_ME_TERMINATE: whether the event iteration at the current time terminates (logged); else announce its event */
int ltiTerminateEvent(LtiInstance *inst, int *nextDefined, double *nextTime);
/* LTI_COMPLETED_TERMINATE: whether the completed integrator step at the current time terminates (logged) */
int ltiCompletedTerminate(LtiInstance *inst);
void ltiStartEvents(LtiInstance *inst);
/* At the end of initialization: the steady start (LTI_STEADY_START), then the event bookkeeping. */
void ltiExitInitialization(LtiInstance *inst);
/* model exchange: SetTime (checks LTI_COMPLETED_GAP), CompletedIntegratorStep (returns 1 to ask for event mode),
   EnterContinuousTimeMode */
LtiStatus ltiSetTime(LtiInstance *inst, const char *function, double time);
int ltiCompletedStep(LtiInstance *inst);
void ltiEnterContinuousMode(LtiInstance *inst);
LtiStatus ltiFail(LtiInstance *inst, LtiStatus status);
/* LTI_ENABLE_INPUT: get / set the Boolean input (values 0 or 1); an error for any other value reference */
LtiStatus ltiGetBoolean(LtiInstance *inst, const char *function, const unsigned int vr[], size_t nvr, int values[]);
LtiStatus ltiSetBoolean(LtiInstance *inst, const char *function, const unsigned int vr[], size_t nvr,
                        const int values[]);
/* LTI_DISCRETE_PARAMETERS / LTI_TYPED_PARAMETERS: get / set the Integer parameter (kinds LTI_INTEGER) or the
   Enumeration one (LTI_ENUMERATION; FMI 2 serves both by its Integer functions); an error for any other value
   reference, and for an Enumeration value none of its items has (setting them also after initialization) */
#define LTI_INTEGER 1
#define LTI_ENUMERATION 2
LtiStatus ltiGetInteger(LtiInstance *inst, const char *function, int kinds, const unsigned int vr[], size_t nvr,
                        int values[]);
LtiStatus ltiSetInteger(LtiInstance *inst, const char *function, int kinds, const unsigned int vr[], size_t nvr,
                        const int values[]);
/* LTI_TYPED_PARAMETERS, FMI 3: whether vr is the Float32 parameter's */
int ltiIsTolerance(unsigned int vr);
/* Keep the stop time of the run; LTI_STRICT_STOP: an error (logged) where time passes it */
void ltiSetStopTime(LtiInstance *inst, int defined, double stopTime);
LtiStatus ltiCheckStopTime(LtiInstance *inst, const char *function, double time);

#endif /* LTI_H */
