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

typedef struct {
    double stepSize;    /* step size the factor belongs to (0: none) */
    SaddleFactor factor;
    SaddleFactor massFactor;  /* [M G^T; G 0], for accelerations consistent with the input */
    double *inputResponse;    /* n x m, column j contiguous: Z with [M G^T; G 0][Z; L] = [B; 0] */
    double *rhs;        /* n */
    double *xp;         /* n */
    double *vp;         /* n */
    double *mu;         /* nc */
} NewmarkSolver;

/* Assemble the model's matrices (via assembleSystem) into CSR form. */
Status assembleSecondOrderSystem(SecondOrderSystem *system, const double parameters[],
                                 const Allocator *allocator, const char **message);
void freeSecondOrderSystem(SecondOrderSystem *system, const Allocator *allocator);

Status allocateNewmarkSolver(NewmarkSolver *solver, const SecondOrderSystem *system,
                             const Allocator *allocator);
void freeNewmarkSolver(NewmarkSolver *solver, const Allocator *allocator);

/* The model's start state: x = X0, v = V0 (zero unless the model adds MatrixX0 / MatrixV0 entries). */
void initialState(const SecondOrderSystem *system, double x[], double v[]);

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

/* y = Cp x + Cv v + Du u + y0 */
void computeOutputs(const SecondOrderSystem *system, const double x[], const double v[],
                    const double u[], double y[]);

#endif /* NEWMARK_H */
