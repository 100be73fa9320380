/*
 * The one Newmark kernel (beta = 1/4, gamma = 1/2) for linear second-order systems with
 * embedded linear constraints, Bottasso-Dopico-Trainelli scaling.
 *
 * S = M + gamma h D + beta h^2 K is factored by an envelope (skyline) Cholesky
 * factorization; the nc constraint rows are eliminated through the Schur complement
 * G S^-1 G^T with W = S^-1 G^T precomputed.  No dense n x n storage; the cost per step
 * is linear in n for matrices whose envelope is O(n).
 */
#ifndef NEWMARK_H
#define NEWMARK_H

#include <stddef.h>

#include "model.h"

#define NEWMARK_BETA  0.25
#define NEWMARK_GAMMA 0.5

/* fmi2-compatible allocation callbacks (calloc-like allocate). */
typedef struct {
    void *(*allocate)(size_t count, size_t size);
    void (*release)(void *pointer);
} Allocator;

/* Compressed sparse row matrix. */
typedef struct {
    int rows;
    int cols;
    int *rowStart;      /* rows + 1 */
    int *colIndex;      /* nnz */
    double *values;     /* nnz */
} SparseMatrix;

typedef struct {
    int n;
    int m;
    int p;
    int nc;
    ConstraintKind constraint;
    SparseMatrix matrices[MatrixCount];
} SecondOrderSystem;

/* Lower envelope Cholesky factor: row i holds columns first[i]..i at values[start[i]..]. */
typedef struct {
    int n;
    int *first;
    size_t *start;      /* n + 1 */
    double *values;
    double *inverseDiagonal;  /* 1 / L(i,i): multiply instead of divide in the solves */
} EnvelopeFactor;

/* Factorization of [S G^T; G 0] with S = M + coefD D + coefK K. */
typedef struct {
    int valid;
    double coefD;
    double coefK;
    EnvelopeFactor envelope;
    double *W;          /* n x nc, column c contiguous: S^-1 G^T e_c */
    double *schur;      /* nc x nc lower Cholesky factor of G W (row-major) */
} SaddleFactor;

/* Dense copy of the model's optional modal step (MatrixModal*, see model.h) and the modal state. */
typedef struct {
    int size;           /* k modal coordinates (0: the model has no modal form) */
    double stepSize;    /* the step size the form belongs to */
    double *blocks;     /* k x 2 */
    double *input;      /* k x (m + 1) */
    double *inputChange;  /* k x m */
    double *shape;      /* 3n x k */
    double *projection; /* k x 3n */
    double *rest;       /* 3n x (m + 1) */
    double *restChange; /* 3n x m */
    double *output;     /* p x k */
    double *outputInput;  /* p x (m + 1) */
    double *w;          /* k: modal state */
    double *next;       /* k: work */
    double *held;       /* m + 1: [u; 1] of the last modal step */
    double *change;     /* m: input changes since that step */
    int current;        /* w, held, change describe the state */
    int stale;          /* x, v, a lag behind w (rebuilt by syncPhysicalState) */
} ModalStep;

typedef struct {
    double stepSize;    /* step size the factor belongs to (0: none) */
    SaddleFactor factor;
    SaddleFactor massFactor;  /* [M G^T; G 0], for accelerations consistent with the input */
    double *inputResponse;    /* n x m, column j contiguous: Z with [M G^T; G 0][Z; L] = [B; 0] */
    double *rhs;        /* n */
    double *xp;         /* n */
    double *vp;         /* n */
    double *mu;         /* nc */
    ModalStep modal;
} NewmarkSolver;

/* Assemble the model's matrices (via assembleSystem) into CSR form. */
Status assembleSecondOrderSystem(SecondOrderSystem *system, const double parameters[],
                                 const Allocator *allocator, const char **message);
void freeSecondOrderSystem(SecondOrderSystem *system, const Allocator *allocator);

Status allocateNewmarkSolver(NewmarkSolver *solver, const SecondOrderSystem *system,
                             const Allocator *allocator);
void freeNewmarkSolver(NewmarkSolver *solver, const Allocator *allocator);

/* The model's start state under the inputs u: x = X0 + X0Input u, v = V0 (zero unless the model adds
 * MatrixX0 / MatrixX0Input / MatrixV0 entries). */
void initialState(const SecondOrderSystem *system, const double u[], double x[], double v[]);

/* Consistent initial acceleration: [M G^T; G 0][a; l] = [B u + f - D v - K x; 0]. */
Status initialAcceleration(NewmarkSolver *solver, const SecondOrderSystem *system,
                           const double u[], const double x[], const double v[], double a[],
                           const Allocator *allocator, const char **message);

/* Keep the acceleration consistent with a newly held input: a += Z (uNew - uOld).  Exact
 * for the linear system; this is what the reference simulator does at each input change. */
Status applyInputChange(NewmarkSolver *solver, const SecondOrderSystem *system,
                        const double uOld[], const double uNew[], double a[],
                        const Allocator *allocator, const char **message);

/* Factor S for step size h (no-op if already factored for h). */
Status prepareStep(NewmarkSolver *solver, const SecondOrderSystem *system, double h,
                   const Allocator *allocator, const char **message);

/* Step size of the model's precomputed step map (MatrixPhi, MatrixGamma), 0 if it has none. */
double stepMapSize(const SecondOrderSystem *system);

/* One step of size h (after prepareStep): x, v, a at t_k -> t_{k+1}, input u held.  A model
 * with a step map takes that map instead (h must then be its step size, see stepMapSize). */
void newmarkStep(NewmarkSolver *solver, const SecondOrderSystem *system, double h,
                 const double u[], double x[], double v[], double a[]);

/* Modal path (models with MatrixModal*): newmarkStep carries the state as modal coordinates when h is the
 * modal step size, and x, v, a are rebuilt only on demand.  Call syncPhysicalState before reading x, v, a
 * (cheap when they are up to date), invalidateModalState after writing them from outside the kernel. */
void syncPhysicalState(NewmarkSolver *solver, const SecondOrderSystem *system, double x[], double v[],
                       double a[]);
void invalidateModalState(NewmarkSolver *solver);

/* Outputs right after newmarkStep: from the modal state if the step was modal, else computeOutputs. */
void computeStepOutputs(const NewmarkSolver *solver, const SecondOrderSystem *system, const double x[],
                        const double v[], const double u[], double y[]);

/* 1 if the state after newmarkStep is finite (checks the modal state after a modal step, else a). */
int stepIsFinite(const NewmarkSolver *solver, const SecondOrderSystem *system, const double a[]);

/* y = Cp x + Cv v + Du u + y0 */
void computeOutputs(const SecondOrderSystem *system, const double x[], const double v[],
                    const double u[], double y[]);

/* y += Du e_input change: the outputs' direct feedthrough of a changed input (the state is unchanged). */
void addFeedthroughChange(const SecondOrderSystem *system, int input, double change, double y[]);

#endif /* NEWMARK_H */
