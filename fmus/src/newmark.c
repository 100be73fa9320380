/*
 * Newmark kernel with embedded constraints (see newmark.h).
 */
#include <math.h>
#include <string.h>

#include "newmark.h"

/* ---------------------------------------------------------------- assembly */

typedef struct {
    size_t count;
    int *row;
    int *col;
    double *value;
} TripletList;

struct Assembly {
    int counting;
    int outOfRange;
    int rows[MatrixCount];
    int cols[MatrixCount];
    TripletList lists[MatrixCount];
};

void addEntry(Assembly *assembly, MatrixId id, int row, int col, double value) {
    TripletList *list;

    if (id < 0 || id >= MatrixCount || row < 0 || col < 0 ||
        row >= assembly->rows[id] || col >= assembly->cols[id]) {
        assembly->outOfRange = 1;
        return;
    }

    list = &assembly->lists[id];

    if (!assembly->counting) {
        list->row[list->count] = row;
        list->col[list->count] = col;
        list->value[list->count] = value;
    }

    list->count++;
}

static void setMatrixShapes(Assembly *assembly, int n, int m, int p, int nc) {
    assembly->rows[MatrixM] = n;  assembly->cols[MatrixM] = n;
    assembly->rows[MatrixD] = n;  assembly->cols[MatrixD] = n;
    assembly->rows[MatrixK] = n;  assembly->cols[MatrixK] = n;
    assembly->rows[MatrixG] = nc; assembly->cols[MatrixG] = n;
    assembly->rows[MatrixB] = n;  assembly->cols[MatrixB] = m;
    assembly->rows[MatrixCp] = p; assembly->cols[MatrixCp] = n;
    assembly->rows[MatrixCv] = p; assembly->cols[MatrixCv] = n;
    assembly->rows[MatrixF] = n;  assembly->cols[MatrixF] = 1;
    assembly->rows[MatrixDu] = p; assembly->cols[MatrixDu] = m;
    assembly->rows[MatrixY0] = p; assembly->cols[MatrixY0] = 1;
    assembly->rows[MatrixX0] = n; assembly->cols[MatrixX0] = 1;
    assembly->rows[MatrixV0] = n; assembly->cols[MatrixV0] = 1;
    assembly->rows[MatrixPhi] = 3 * n; assembly->cols[MatrixPhi] = 3 * n;
    assembly->rows[MatrixGamma] = 3 * n; assembly->cols[MatrixGamma] = m + 1;
    assembly->rows[MatrixMapStep] = 1; assembly->cols[MatrixMapStep] = 1;
    assembly->rows[MatrixModalSize] = 1; assembly->cols[MatrixModalSize] = 2;
    assembly->rows[MatrixModalBlocks] = 3 * n; assembly->cols[MatrixModalBlocks] = 2;
    assembly->rows[MatrixModalInput] = 3 * n; assembly->cols[MatrixModalInput] = m + 1;
    assembly->rows[MatrixModalInputChange] = 3 * n; assembly->cols[MatrixModalInputChange] = m;
    assembly->rows[MatrixModalShape] = 3 * n; assembly->cols[MatrixModalShape] = 3 * n;
    assembly->rows[MatrixModalProjection] = 3 * n; assembly->cols[MatrixModalProjection] = 3 * n;
    assembly->rows[MatrixModalRest] = 3 * n; assembly->cols[MatrixModalRest] = m + 1;
    assembly->rows[MatrixModalRestChange] = 3 * n; assembly->cols[MatrixModalRestChange] = m;
    assembly->rows[MatrixModalOutput] = p; assembly->cols[MatrixModalOutput] = 3 * n;
    assembly->rows[MatrixModalOutputInput] = p; assembly->cols[MatrixModalOutputInput] = m + 1;
    assembly->rows[MatrixX0Input] = n; assembly->cols[MatrixX0Input] = m;
}

static void freeTriplets(Assembly *assembly, const Allocator *allocator) {
    int id;

    for (id = 0; id < MatrixCount; id++) {
        allocator->release(assembly->lists[id].row);
        allocator->release(assembly->lists[id].col);
        allocator->release(assembly->lists[id].value);
        assembly->lists[id].row = NULL;
        assembly->lists[id].col = NULL;
        assembly->lists[id].value = NULL;
    }
}

static Status allocateTriplets(Assembly *assembly, const Allocator *allocator) {
    int id;

    for (id = 0; id < MatrixCount; id++) {
        TripletList *list = &assembly->lists[id];
        size_t capacity = list->count > 0 ? list->count : 1;

        list->row = (int *)allocator->allocate(capacity, sizeof(int));
        list->col = (int *)allocator->allocate(capacity, sizeof(int));
        list->value = (double *)allocator->allocate(capacity, sizeof(double));

        if (!list->row || !list->col || !list->value) {
            return Error;
        }

        list->count = 0;
    }

    return OK;
}

/* Convert a triplet list into CSR (duplicates kept; they are summed by every use). */
static Status tripletsToCsr(const TripletList *list, int rows, int cols, SparseMatrix *matrix,
                            const Allocator *allocator) {
    size_t k;
    int i;
    size_t capacity = list->count > 0 ? list->count : 1;
    int *next;

    matrix->rows = rows;
    matrix->cols = cols;
    matrix->rowStart = (int *)allocator->allocate((size_t)rows + 1, sizeof(int));
    matrix->colIndex = (int *)allocator->allocate(capacity, sizeof(int));
    matrix->values = (double *)allocator->allocate(capacity, sizeof(double));
    next = (int *)allocator->allocate((size_t)rows + 1, sizeof(int));

    if (!matrix->rowStart || !matrix->colIndex || !matrix->values || !next) {
        allocator->release(next);
        return Error;
    }

    for (k = 0; k < list->count; k++) {
        matrix->rowStart[list->row[k] + 1]++;
    }

    for (i = 0; i < rows; i++) {
        matrix->rowStart[i + 1] += matrix->rowStart[i];
        next[i] = matrix->rowStart[i];
    }

    for (k = 0; k < list->count; k++) {
        int position = next[list->row[k]]++;
        matrix->colIndex[position] = list->col[k];
        matrix->values[position] = list->value[k];
    }

    allocator->release(next);
    return OK;
}

static void freeSparseMatrix(SparseMatrix *matrix, const Allocator *allocator) {
    allocator->release(matrix->rowStart);
    allocator->release(matrix->colIndex);
    allocator->release(matrix->values);
    matrix->rowStart = NULL;
    matrix->colIndex = NULL;
    matrix->values = NULL;
}

Status assembleSecondOrderSystem(SecondOrderSystem *system, const double parameters[],
                                 const Allocator *allocator, const char **message) {
    Assembly assembly;
    Status status;
    int id;

    memset(&assembly, 0, sizeof(assembly));
    memset(system, 0, sizeof(*system));

    system->n = N_DOF;
    system->m = N_INPUTS;
    system->p = N_OUTPUTS;
    system->nc = N_CONSTRAINTS;
    system->constraint = (ConstraintKind)CONSTRAINT_KIND;
    setMatrixShapes(&assembly, system->n, system->m, system->p, system->nc);

    assembly.counting = 1;
    status = assembleSystem(parameters, &assembly, message);
    if (status > Warning) {
        return status;
    }

    if (allocateTriplets(&assembly, allocator) != OK) {
        freeTriplets(&assembly, allocator);
        *message = "out of memory while assembling the system matrices";
        return Error;
    }

    assembly.counting = 0;
    status = assembleSystem(parameters, &assembly, message);
    if (status > Warning) {
        freeTriplets(&assembly, allocator);
        return status;
    }

    if (assembly.outOfRange) {
        freeTriplets(&assembly, allocator);
        *message = "the model added a matrix entry outside the matrix dimensions";
        return Error;
    }

    for (id = 0; id < MatrixCount; id++) {
        if (tripletsToCsr(&assembly.lists[id], assembly.rows[id], assembly.cols[id],
                          &system->matrices[id], allocator) != OK) {
            freeTriplets(&assembly, allocator);
            freeSecondOrderSystem(system, allocator);
            *message = "out of memory while assembling the system matrices";
            return Error;
        }
    }

    freeTriplets(&assembly, allocator);
    return OK;
}

void freeSecondOrderSystem(SecondOrderSystem *system, const Allocator *allocator) {
    int id;

    for (id = 0; id < MatrixCount; id++) {
        freeSparseMatrix(&system->matrices[id], allocator);
    }
}

/* ---------------------------------------------------------- sparse kernels */

/* Dot product with four partial sums (independent chains keep long rows fast). */
static inline double dot(const double a[], const double b[], int count) {
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    int k = 0;

    for (; k + 4 <= count; k += 4) {
        s0 += a[k] * b[k];
        s1 += a[k + 1] * b[k + 1];
        s2 += a[k + 2] * b[k + 2];
        s3 += a[k + 3] * b[k + 3];
    }
    for (; k < count; k++) {
        s0 += a[k] * b[k];
    }

    return (s0 + s1) + (s2 + s3);
}

/* Sparse row times vector: sum_k values[k] x[index[k]], four partial sums. */
static inline double sparseDot(const double values[], const int index[], const double x[], int count) {
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    int k = 0;

    for (; k + 4 <= count; k += 4) {
        s0 += values[k] * x[index[k]];
        s1 += values[k + 1] * x[index[k + 1]];
        s2 += values[k + 2] * x[index[k + 2]];
        s3 += values[k + 3] * x[index[k + 3]];
    }
    for (; k < count; k++) {
        s0 += values[k] * x[index[k]];
    }

    return (s0 + s1) + (s2 + s3);
}

/* y = alpha A x + y */
static void addProduct(const SparseMatrix *A, double alpha, const double x[], double y[]) {
    int i;

    for (i = 0; i < A->rows; i++) {
        int begin = A->rowStart[i];
        y[i] += alpha * sparseDot(A->values + begin, A->colIndex + begin, x,
                                  A->rowStart[i + 1] - begin);
    }
}

/* --------------------------------------------------- envelope Cholesky */

static void freeEnvelope(EnvelopeFactor *envelope, const Allocator *allocator) {
    allocator->release(envelope->first);
    allocator->release(envelope->start);
    allocator->release(envelope->values);
    allocator->release(envelope->inverseDiagonal);
    envelope->first = NULL;
    envelope->start = NULL;
    envelope->values = NULL;
    envelope->inverseDiagonal = NULL;
}

/* Row envelope of the lower triangle of the union of the patterns of M, D, K. */
static Status allocateEnvelope(EnvelopeFactor *envelope, const SecondOrderSystem *system,
                               const Allocator *allocator) {
    const MatrixId ids[3] = { MatrixM, MatrixD, MatrixK };
    int n = system->n;
    int i, k, t;

    envelope->n = n;
    envelope->first = (int *)allocator->allocate((size_t)n, sizeof(int));
    envelope->start = (size_t *)allocator->allocate((size_t)n + 1, sizeof(size_t));
    envelope->inverseDiagonal = (double *)allocator->allocate((size_t)n, sizeof(double));

    if (!envelope->first || !envelope->start || !envelope->inverseDiagonal) {
        return Error;
    }

    for (i = 0; i < n; i++) {
        envelope->first[i] = i;
    }

    for (t = 0; t < 3; t++) {
        const SparseMatrix *A = &system->matrices[ids[t]];
        for (i = 0; i < n; i++) {
            for (k = A->rowStart[i]; k < A->rowStart[i + 1]; k++) {
                int j = A->colIndex[k];
                int low = j < i ? j : i;
                int high = j < i ? i : j;
                if (low < envelope->first[high]) {
                    envelope->first[high] = low;
                }
            }
        }
    }

    envelope->start[0] = 0;
    for (i = 0; i < n; i++) {
        envelope->start[i + 1] = envelope->start[i] + (size_t)(i - envelope->first[i] + 1);
    }

    envelope->values = (double *)allocator->allocate(envelope->start[n] > 0 ? envelope->start[n] : 1,
                                                     sizeof(double));
    return envelope->values ? OK : Error;
}

/* Load S = M + coefD D + coefK K (lower triangle) into the envelope. */
static void loadEnvelope(EnvelopeFactor *envelope, const SecondOrderSystem *system,
                         double coefD, double coefK) {
    const MatrixId ids[3] = { MatrixM, MatrixD, MatrixK };
    const double coefs[3] = { 1.0, coefD, coefK };
    int i, k, t;

    memset(envelope->values, 0, envelope->start[envelope->n] * sizeof(double));

    for (t = 0; t < 3; t++) {
        const SparseMatrix *A = &system->matrices[ids[t]];
        if (coefs[t] == 0.0) {
            continue;
        }
        for (i = 0; i < A->rows; i++) {
            for (k = A->rowStart[i]; k < A->rowStart[i + 1]; k++) {
                int j = A->colIndex[k];
                if (j <= i) {
                    envelope->values[envelope->start[i] + (size_t)(j - envelope->first[i])] +=
                        coefs[t] * A->values[k];
                }
            }
        }
    }
}

/* In-place row-oriented envelope Cholesky factorization; returns the failing row + 1. */
static int factorEnvelope(EnvelopeFactor *envelope) {
    int i, j, k;

    for (i = 0; i < envelope->n; i++) {
        int fi = envelope->first[i];
        double *rowI = envelope->values + envelope->start[i] - fi;   /* rowI[k] = L(i,k) */
        double diagonal;

        for (j = fi; j < i; j++) {
            int fj = envelope->first[j];
            const double *rowJ = envelope->values + envelope->start[j] - fj;
            k = fi > fj ? fi : fj;
            rowI[j] = (rowI[j] - dot(rowI + k, rowJ + k, j - k)) * envelope->inverseDiagonal[j];
        }

        diagonal = rowI[i] - dot(rowI + fi, rowI + fi, i - fi);

        if (!(diagonal > 0.0) || !isfinite(diagonal)) {
            return i + 1;
        }

        rowI[i] = sqrt(diagonal);
        envelope->inverseDiagonal[i] = 1.0 / rowI[i];
    }

    return 0;
}

/* Solve L L^T x = b in place. */
static void solveEnvelope(const EnvelopeFactor *envelope, double b[]) {
    int i, k;

    for (i = 0; i < envelope->n; i++) {
        int fi = envelope->first[i];
        const double *rowI = envelope->values + envelope->start[i] - fi;
        b[i] = (b[i] - dot(rowI + fi, b + fi, i - fi)) * envelope->inverseDiagonal[i];
    }

    for (i = envelope->n - 1; i >= 0; i--) {
        int fi = envelope->first[i];
        const double *rowI = envelope->values + envelope->start[i] - fi;
        double value = b[i] * envelope->inverseDiagonal[i];
        b[i] = value;
        for (k = fi; k < i; k++) {
            b[k] -= rowI[k] * value;
        }
    }
}

/* ------------------------------------------------- saddle-point factor */

static void freeSaddleFactor(SaddleFactor *factor, const Allocator *allocator) {
    freeEnvelope(&factor->envelope, allocator);
    allocator->release(factor->W);
    allocator->release(factor->schur);
    factor->W = NULL;
    factor->schur = NULL;
    factor->valid = 0;
}

/* Dense Cholesky of the nc x nc Schur complement (row-major, lower). */
static int factorDense(double A[], int size) {
    int i, j, k;

    for (j = 0; j < size; j++) {
        double diagonal = A[j * size + j];
        for (k = 0; k < j; k++) {
            diagonal -= A[j * size + k] * A[j * size + k];
        }
        if (!(diagonal > 0.0) || !isfinite(diagonal)) {
            return j + 1;
        }
        A[j * size + j] = sqrt(diagonal);
        for (i = j + 1; i < size; i++) {
            double sum = A[i * size + j];
            for (k = 0; k < j; k++) {
                sum -= A[i * size + k] * A[j * size + k];
            }
            A[i * size + j] = sum / A[j * size + j];
        }
    }

    return 0;
}

static void solveDense(const double L[], int size, double b[]) {
    int i, k;

    for (i = 0; i < size; i++) {
        double sum = b[i];
        for (k = 0; k < i; k++) {
            sum -= L[i * size + k] * b[k];
        }
        b[i] = sum / L[i * size + i];
    }

    for (i = size - 1; i >= 0; i--) {
        double sum = b[i];
        for (k = i + 1; k < size; k++) {
            sum -= L[k * size + i] * b[k];
        }
        b[i] = sum / L[i * size + i];
    }
}

static Status factorSaddle(SaddleFactor *factor, const SecondOrderSystem *system,
                           double coefD, double coefK, const Allocator *allocator,
                           const char **message) {
    const SparseMatrix *G = &system->matrices[MatrixG];
    int n = system->n;
    int nc = system->nc;
    int c, d, k;

    if (!factor->envelope.values) {
        if (allocateEnvelope(&factor->envelope, system, allocator) != OK) {
            *message = "out of memory while allocating the envelope factor";
            return Error;
        }
    }

    if (nc > 0 && !factor->W) {
        factor->W = (double *)allocator->allocate((size_t)n * (size_t)nc, sizeof(double));
        factor->schur = (double *)allocator->allocate((size_t)nc * (size_t)nc, sizeof(double));
        if (!factor->W || !factor->schur) {
            *message = "out of memory while allocating the constraint factor";
            return Error;
        }
    }

    factor->valid = 0;
    factor->coefD = coefD;
    factor->coefK = coefK;

    loadEnvelope(&factor->envelope, system, coefD, coefK);

    if (factorEnvelope(&factor->envelope) != 0) {
        *message = "the iteration matrix M + gamma h D + beta h^2 K is not positive definite";
        return Error;
    }

    for (c = 0; c < nc; c++) {
        double *w = factor->W + (size_t)c * (size_t)n;
        memset(w, 0, (size_t)n * sizeof(double));
        for (k = G->rowStart[c]; k < G->rowStart[c + 1]; k++) {
            w[G->colIndex[k]] += G->values[k];
        }
        solveEnvelope(&factor->envelope, w);
    }

    for (c = 0; c < nc; c++) {
        for (d = 0; d < nc; d++) {
            const double *w = factor->W + (size_t)d * (size_t)n;
            double sum = 0.0;
            for (k = G->rowStart[c]; k < G->rowStart[c + 1]; k++) {
                sum += G->values[k] * w[G->colIndex[k]];
            }
            factor->schur[c * nc + d] = sum;
        }
    }

    if (nc > 0 && factorDense(factor->schur, nc) != 0) {
        *message = "the constraint matrix G does not have full row rank";
        return Error;
    }

    factor->valid = 1;
    return OK;
}

/* Solve [S G^T; G 0][z; mu] = [rhs; c] in place: rhs <- z, mu <- multiplier. */
static void solveSaddle(const SaddleFactor *factor, const SecondOrderSystem *system,
                        double rhs[], const double c[], double mu[]) {
    const SparseMatrix *G = &system->matrices[MatrixG];
    int n = system->n;
    int nc = system->nc;
    int i, j, k;

    solveEnvelope(&factor->envelope, rhs);

    if (nc == 0) {
        return;
    }

    for (j = 0; j < nc; j++) {
        double sum = 0.0;
        for (k = G->rowStart[j]; k < G->rowStart[j + 1]; k++) {
            sum += G->values[k] * rhs[G->colIndex[k]];
        }
        mu[j] = sum - c[j];
    }

    solveDense(factor->schur, nc, mu);

    for (j = 0; j < nc; j++) {
        const double *w = factor->W + (size_t)j * (size_t)n;
        double muJ = mu[j];
        for (i = 0; i < n; i++) {
            rhs[i] -= w[i] * muJ;
        }
    }
}

/* ------------------------------------------------------------ modal form */

/* A step within this relative distance of the modal step size takes the modal form (as doStep snaps h). */
#define MODAL_STEP_TOLERANCE 1e-9

static const double unitColumn[1] = {1.0};

/* Dense rows x cols copy (row-major) of the leading part of a CSR matrix; NULL if out of memory. */
static double *denseCopy(const SparseMatrix *A, int rows, int cols, const Allocator *allocator) {
    double *dense = (double *)allocator->allocate((size_t)ARRAY_LENGTH(rows * cols), sizeof(double));
    int i, k;

    if (!dense) {
        return NULL;
    }
    for (i = 0; i < rows && i < A->rows; i++) {
        for (k = A->rowStart[i]; k < A->rowStart[i + 1]; k++) {
            if (A->colIndex[k] < cols) {
                dense[i * cols + A->colIndex[k]] += A->values[k];
            }
        }
    }
    return dense;
}

static void freeModalStep(ModalStep *modal, const Allocator *allocator) {
    double **arrays[] = { &modal->blocks, &modal->input, &modal->inputChange, &modal->shape,
                          &modal->projection, &modal->rest, &modal->restChange, &modal->output,
                          &modal->outputInput, &modal->w, &modal->next, &modal->held, &modal->change };
    size_t i;

    for (i = 0; i < sizeof(arrays) / sizeof(arrays[0]); i++) {
        allocator->release(*arrays[i]);
        *arrays[i] = NULL;
    }
    memset(modal, 0, sizeof(*modal));
}

/* Dense copies of the model's modal form (size 0 if it has none). */
static Status allocateModalStep(ModalStep *modal, const SecondOrderSystem *system, const Allocator *allocator) {
    const SparseMatrix *size = &system->matrices[MatrixModalSize];
    const SparseMatrix *A = system->matrices;
    int n3 = 3 * system->n, m = system->m, p = system->p, k, j;
    double entries[2] = {0.0, 0.0};

    memset(modal, 0, sizeof(*modal));
    for (j = size->rowStart[0]; j < size->rowStart[1]; j++) {
        entries[size->colIndex[j]] += size->values[j];
    }
    k = (int)entries[0];
    if (k <= 0 || k > n3 || k % 2 != 0 || !(entries[1] > 0.0)) {
        return OK;
    }
    modal->blocks = denseCopy(&A[MatrixModalBlocks], k, 2, allocator);
    modal->input = denseCopy(&A[MatrixModalInput], k, m + 1, allocator);
    modal->inputChange = denseCopy(&A[MatrixModalInputChange], k, m, allocator);
    modal->shape = denseCopy(&A[MatrixModalShape], n3, k, allocator);
    modal->projection = denseCopy(&A[MatrixModalProjection], k, n3, allocator);
    modal->rest = denseCopy(&A[MatrixModalRest], n3, m + 1, allocator);
    modal->restChange = denseCopy(&A[MatrixModalRestChange], n3, m, allocator);
    modal->output = denseCopy(&A[MatrixModalOutput], p, k, allocator);
    modal->outputInput = denseCopy(&A[MatrixModalOutputInput], p, m + 1, allocator);
    modal->w = (double *)allocator->allocate((size_t)k, sizeof(double));
    modal->next = (double *)allocator->allocate((size_t)k, sizeof(double));
    modal->held = (double *)allocator->allocate((size_t)m + 1, sizeof(double));
    modal->change = (double *)allocator->allocate((size_t)ARRAY_LENGTH(m), sizeof(double));
    if (!modal->blocks || !modal->input || !modal->inputChange || !modal->shape || !modal->projection ||
        !modal->rest || !modal->restChange || !modal->output || !modal->outputInput || !modal->w ||
        !modal->next || !modal->held || !modal->change) {
        freeModalStep(modal, allocator);
        return Error;
    }
    modal->size = k;
    modal->stepSize = entries[1];
    return OK;
}

void invalidateModalState(NewmarkSolver *solver) {
    solver->modal.current = 0;
    solver->modal.stale = 0;
}

void syncPhysicalState(NewmarkSolver *solver, const SecondOrderSystem *system, double x[], double v[],
                       double a[]) {
    ModalStep *modal = &solver->modal;
    int n = system->n, m = system->m, k = modal->size, i, j;
    double *parts[3];

    if (!modal->current || !modal->stale) {
        return;
    }
    parts[0] = x; parts[1] = v; parts[2] = a;
    for (i = 0; i < 3 * n; i++) {
        const double *shape = modal->shape + (size_t)i * (size_t)k;
        const double *rest = modal->rest + (size_t)i * (size_t)(m + 1);
        double sum = dot(shape, modal->w, k) + dot(rest, modal->held, m + 1);
        for (j = 0; j < m; j++) {
            sum += modal->restChange[i * m + j] * modal->change[j];
        }
        parts[i / n][i % n] = sum;
    }
    modal->stale = 0;
}

/* w <- Blocks w + Input [u; 1], projecting [x; v; a] first if w is not current. */
static void modalStep(NewmarkSolver *solver, const SecondOrderSystem *system, const double u[],
                      const double x[], const double v[], const double a[]) {
    ModalStep *modal = &solver->modal;
    int n = system->n, m = system->m, k = modal->size, i, j;
    const double *blocks = modal->blocks, *input = modal->input;
    double *w = modal->w, *next = modal->next;

    if (!modal->current) {
        for (i = 0; i < k; i++) {
            const double *row = modal->projection + (size_t)i * (size_t)(3 * n);
            w[i] = dot(row, x, n) + dot(row + n, v, n) + dot(row + 2 * n, a, n);
        }
        modal->current = 1;
    }
    for (j = 0; j < m; j++) {
        modal->held[j] = u[j];
        modal->change[j] = 0.0;
    }
    modal->held[m] = 1.0;
    for (i = 0; i < k; i += 2) {
        double w0 = w[i], w1 = w[i + 1];
        double s0 = blocks[2 * i] * w0 + blocks[2 * i + 1] * w1;
        double s1 = blocks[2 * i + 2] * w0 + blocks[2 * i + 3] * w1;
        const double *g0 = input + (size_t)i * (size_t)(m + 1), *g1 = g0 + m + 1;
        for (j = 0; j <= m; j++) {
            s0 += g0[j] * modal->held[j];
            s1 += g1[j] * modal->held[j];
        }
        next[i] = s0;
        next[i + 1] = s1;
    }
    memcpy(w, next, (size_t)k * sizeof(double));
    modal->stale = 1;
}

void computeStepOutputs(const NewmarkSolver *solver, const SecondOrderSystem *system, const double x[],
                        const double v[], const double u[], double y[]) {
    const ModalStep *modal = &solver->modal;
    int i, k = modal->size, m = system->m;

    if (!modal->current || !modal->stale) {
        computeOutputs(system, x, v, u, y);
        return;
    }
    for (i = 0; i < system->p; i++) {
        y[i] = dot(modal->output + (size_t)i * (size_t)k, modal->w, k) +
               dot(modal->outputInput + (size_t)i * (size_t)(m + 1), modal->held, m + 1);
    }
    addProduct(&system->matrices[MatrixDu], 1.0, u, y);
    addProduct(&system->matrices[MatrixY0], 1.0, unitColumn, y);
}

int stepIsFinite(const NewmarkSolver *solver, const SecondOrderSystem *system, const double a[]) {
    const ModalStep *modal = &solver->modal;
    const double *values = modal->current && modal->stale ? modal->w : a;
    int count = modal->current && modal->stale ? modal->size : system->n, i;

    for (i = 0; i < count; i++) {
        if (!isfinite(values[i])) {
            return 0;
        }
    }
    return 1;
}

/* ---------------------------------------------------------------- solver */

Status allocateNewmarkSolver(NewmarkSolver *solver, const SecondOrderSystem *system,
                             const Allocator *allocator) {
    size_t n = (size_t)system->n;

    memset(solver, 0, sizeof(*solver));
    solver->rhs = (double *)allocator->allocate(n, sizeof(double));
    solver->xp = (double *)allocator->allocate(n, sizeof(double));
    solver->vp = (double *)allocator->allocate(n, sizeof(double));
    solver->mu = (double *)allocator->allocate((size_t)ARRAY_LENGTH(system->nc), sizeof(double));

    if (!solver->rhs || !solver->xp || !solver->vp || !solver->mu ||
        allocateModalStep(&solver->modal, system, allocator) != OK) {
        return Error;
    }

    return OK;
}

void freeNewmarkSolver(NewmarkSolver *solver, const Allocator *allocator) {
    freeSaddleFactor(&solver->factor, allocator);
    freeSaddleFactor(&solver->massFactor, allocator);
    freeModalStep(&solver->modal, allocator);
    allocator->release(solver->inputResponse);
    allocator->release(solver->rhs);
    allocator->release(solver->xp);
    allocator->release(solver->vp);
    allocator->release(solver->mu);
    memset(solver, 0, sizeof(*solver));
}


/* rhs = B u + f - D v - K x */
static void forceResidual(const SecondOrderSystem *system, const double u[], const double x[],
                          const double v[], double rhs[]) {
    memset(rhs, 0, (size_t)system->n * sizeof(double));
    addProduct(&system->matrices[MatrixB], 1.0, u, rhs);
    addProduct(&system->matrices[MatrixF], 1.0, unitColumn, rhs);
    addProduct(&system->matrices[MatrixD], -1.0, v, rhs);
    addProduct(&system->matrices[MatrixK], -1.0, x, rhs);
}

/* Factor [M G^T; G 0] once and compute the input response Z (n x m). */
static Status ensureMassFactor(NewmarkSolver *solver, const SecondOrderSystem *system,
                               const Allocator *allocator, const char **message) {
    const SparseMatrix *B = &system->matrices[MatrixB];
    double zeros[ARRAY_LENGTH(N_CONSTRAINTS)];
    size_t n = (size_t)system->n;
    Status status;
    int i, j, k;

    if (solver->massFactor.valid) {
        return OK;
    }

    status = factorSaddle(&solver->massFactor, system, 0.0, 0.0, allocator, message);
    if (status != OK) {
        return status;
    }

    if (!solver->inputResponse) {
        solver->inputResponse = (double *)allocator->allocate(n * (size_t)system->m, sizeof(double));
        if (!solver->inputResponse) {
            solver->massFactor.valid = 0;
            *message = "out of memory while allocating the input response";
            return Error;
        }
    }

    for (j = 0; j < ARRAY_LENGTH(N_CONSTRAINTS); j++) {
        zeros[j] = 0.0;
    }

    for (j = 0; j < system->m; j++) {
        double *z = solver->inputResponse + (size_t)j * n;
        memset(z, 0, n * sizeof(double));
        for (i = 0; i < system->n; i++) {
            for (k = B->rowStart[i]; k < B->rowStart[i + 1]; k++) {
                if (B->colIndex[k] == j) {
                    z[i] += B->values[k];
                }
            }
        }
        solveSaddle(&solver->massFactor, system, z, zeros, solver->mu);
    }

    return OK;
}

Status initialAcceleration(NewmarkSolver *solver, const SecondOrderSystem *system,
                           const double u[], const double x[], const double v[], double a[],
                           const Allocator *allocator, const char **message) {
    double zeros[ARRAY_LENGTH(N_CONSTRAINTS)];
    Status status;
    int j;

    for (j = 0; j < ARRAY_LENGTH(N_CONSTRAINTS); j++) {
        zeros[j] = 0.0;
    }

    status = ensureMassFactor(solver, system, allocator, message);
    if (status != OK) {
        return status;
    }

    forceResidual(system, u, x, v, solver->rhs);
    solveSaddle(&solver->massFactor, system, solver->rhs, zeros, solver->mu);
    memcpy(a, solver->rhs, (size_t)system->n * sizeof(double));
    invalidateModalState(solver);
    return OK;
}

Status applyInputChange(NewmarkSolver *solver, const SecondOrderSystem *system,
                        const double uOld[], const double uNew[], double a[],
                        const Allocator *allocator, const char **message) {
    size_t n = (size_t)system->n;
    Status status;
    int i, j;

    status = ensureMassFactor(solver, system, allocator, message);
    if (status != OK) {
        return status;
    }

    for (j = 0; j < system->m; j++) {
        double change = uNew[j] - uOld[j];
        const double *z = solver->inputResponse + (size_t)j * n;
        if (change == 0.0) {
            continue;
        }
        if (solver->modal.current) {
            /* the modal state takes the change (the acceleration part of w); x, v, a follow on sync */
            ModalStep *modal = &solver->modal;
            for (i = 0; i < modal->size; i++) {
                modal->w[i] += modal->inputChange[i * system->m + j] * change;
            }
            modal->change[j] += change;
            if (modal->stale) {
                continue;
            }
        }
        for (i = 0; i < system->n; i++) {
            a[i] += z[i] * change;
        }
    }

    return OK;
}

Status prepareStep(NewmarkSolver *solver, const SecondOrderSystem *system, double h,
                   const Allocator *allocator, const char **message) {
    Status status;

    if (solver->factor.valid && solver->stepSize == h) {
        return OK;
    }

    solver->stepSize = 0.0;
    status = factorSaddle(&solver->factor, system, NEWMARK_GAMMA * h, NEWMARK_BETA * h * h,
                          allocator, message);
    if (status == OK) {
        solver->stepSize = h;
    }

    return status;
}

double stepMapSize(const SecondOrderSystem *system) {
    const SparseMatrix *step = &system->matrices[MatrixMapStep];
    return step->rowStart[1] > 0 ? step->values[0] : 0.0;
}

/* s+ = Phi s + Gamma [u; 1] with s = [x; v; a]; the three parts of s+ go to rhs, xp, vp first. */
static void mapStep(NewmarkSolver *solver, const SecondOrderSystem *system, const double u[],
                    double x[], double v[], double a[]) {
    const SparseMatrix *phi = &system->matrices[MatrixPhi];
    const SparseMatrix *gamma = &system->matrices[MatrixGamma];
    double forced[N_INPUTS + 1];
    double *parts[3];
    const double *state[3];
    int n = system->n;
    int row, k, j;

    parts[0] = solver->rhs; parts[1] = solver->xp; parts[2] = solver->vp;
    state[0] = x; state[1] = v; state[2] = a;
    for (j = 0; j < system->m; j++) {
        forced[j] = u[j];
    }
    forced[system->m] = 1.0;

    for (row = 0; row < 3 * n; row++) {
        double sum = 0.0;
        for (k = phi->rowStart[row]; k < phi->rowStart[row + 1]; k++) {
            int col = phi->colIndex[k];
            sum += phi->values[k] * state[col / n][col % n];
        }
        for (k = gamma->rowStart[row]; k < gamma->rowStart[row + 1]; k++) {
            sum += gamma->values[k] * forced[gamma->colIndex[k]];
        }
        parts[row / n][row % n] = sum;
    }
    memcpy(x, parts[0], (size_t)n * sizeof(double));
    memcpy(v, parts[1], (size_t)n * sizeof(double));
    memcpy(a, parts[2], (size_t)n * sizeof(double));
}

void newmarkStep(NewmarkSolver *solver, const SecondOrderSystem *system, double h,
                 const double u[], double x[], double v[], double a[]) {
    const SparseMatrix *G = &system->matrices[MatrixG];
    double c[ARRAY_LENGTH(N_CONSTRAINTS)];
    int n = system->n;
    int i, j, k;

    if (solver->modal.size > 0) {
        if (fabs(h - solver->modal.stepSize) <= MODAL_STEP_TOLERANCE * solver->modal.stepSize) {
            modalStep(solver, system, u, x, v, a);
            return;
        }
        syncPhysicalState(solver, system, x, v, a);
        invalidateModalState(solver);
    }

    if (stepMapSize(system) > 0.0) {
        mapStep(solver, system, u, x, v, a);
        return;
    }

    for (j = 0; j < ARRAY_LENGTH(N_CONSTRAINTS); j++) {
        c[j] = 0.0;
    }

    for (i = 0; i < n; i++) {
        solver->xp[i] = x[i] + h * v[i] + h * h * (0.5 - NEWMARK_BETA) * a[i];
        solver->vp[i] = v[i] + h * (1.0 - NEWMARK_GAMMA) * a[i];
    }

    for (j = 0; j < system->nc; j++) {
        const double *predictor = system->constraint == ConstraintPosition ? solver->xp : solver->vp;
        double scale = system->constraint == ConstraintPosition ? NEWMARK_BETA * h * h
                                                                : NEWMARK_GAMMA * h;
        double sum = 0.0;
        for (k = G->rowStart[j]; k < G->rowStart[j + 1]; k++) {
            sum += G->values[k] * predictor[G->colIndex[k]];
        }
        c[j] = -sum / scale;
    }

    forceResidual(system, u, solver->xp, solver->vp, solver->rhs);
    solveSaddle(&solver->factor, system, solver->rhs, c, solver->mu);

    for (i = 0; i < n; i++) {
        a[i] = solver->rhs[i];
        x[i] = solver->xp[i] + NEWMARK_BETA * h * h * a[i];
        v[i] = solver->vp[i] + NEWMARK_GAMMA * h * a[i];
    }
}

void initialState(const SecondOrderSystem *system, const double u[], double x[], double v[]) {
    memset(x, 0, (size_t)system->n * sizeof(double));
    memset(v, 0, (size_t)system->n * sizeof(double));
    addProduct(&system->matrices[MatrixX0], 1.0, unitColumn, x);
    addProduct(&system->matrices[MatrixX0Input], 1.0, u, x);
    addProduct(&system->matrices[MatrixV0], 1.0, unitColumn, v);
}

void addFeedthroughChange(const SecondOrderSystem *system, int input, double change, double y[]) {
    const SparseMatrix *A = &system->matrices[MatrixDu];
    int i, e;

    for (i = 0; i < A->rows; i++) {
        for (e = A->rowStart[i]; e < A->rowStart[i + 1]; e++) {
            if (A->colIndex[e] == input) y[i] += change * A->values[e];
        }
    }
}

void computeOutputs(const SecondOrderSystem *system, const double x[], const double v[],
                    const double u[], double y[]) {
    memset(y, 0, (size_t)ARRAY_LENGTH(system->p) * sizeof(double));
    addProduct(&system->matrices[MatrixCp], 1.0, x, y);
    addProduct(&system->matrices[MatrixCv], 1.0, v, y);
    addProduct(&system->matrices[MatrixDu], 1.0, u, y);
    addProduct(&system->matrices[MatrixY0], 1.0, unitColumn, y);
}
