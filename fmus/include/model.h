/*
 * Hook interface between the shared FMI glue / Newmark kernel and one model.
 *
 * A model is a linear second-order system with optional linear constraints
 *
 *     M a + D v + K x + G^T mu = B u + f,      y = Cp x + Cv v + Du u + y0,
 *     G x = 0 (ConstraintPosition, index 3)  or  G v = 0 (ConstraintVelocity, index 2).
 *
 * The generated config.h fixes the sizes and the constraint kind, and declares the identifier and
 * the instantiation token, which the generated fmu_identity.c defines.  A model only implements
 * assembleSystem(): it adds the matrix entries, computed from the parameter values, through
 * addEntry().  The glue calls it twice (once to count the entries, once to store them), so it must
 * be deterministic.
 */
#ifndef MODEL_H
#define MODEL_H

#include <stddef.h>

#include "config.h"

/* Sizes fixed at generation time by config.h:
 *   N_DOF (n), N_INPUTS (m), N_OUTPUTS (p), N_CONSTRAINTS (nc), N_PARAMETERS,
 *   CONSTRAINT_KIND, MODEL_IDENTIFIER, INSTANTIATION_TOKEN, PARAMETER_DEFAULTS */

#define ARRAY_LENGTH(count) ((count) > 0 ? (count) : 1)

/* Value references (contiguous blocks, in this order). */
#define VR_INPUTS      1
#define VR_OUTPUTS     (VR_INPUTS + N_INPUTS)
#define VR_PARAMETERS  (VR_OUTPUTS + N_OUTPUTS)
#define VR_POSITIONS   (VR_PARAMETERS + N_PARAMETERS)
#define VR_VELOCITIES  (VR_POSITIONS + N_DOF)
#define VR_ACCELERATIONS (VR_VELOCITIES + N_DOF)
#define VR_END         (VR_ACCELERATIONS + N_DOF)

/* Internal status values equal the fmi2Status values. */
typedef enum {
    OK,
    Warning,
    Discard,
    Error,
    Fatal
} Status;

typedef enum {
    ConstraintNone = 0,
    ConstraintPosition = 1,
    ConstraintVelocity = 2
} ConstraintKind;

typedef enum {
    MatrixM,
    MatrixD,
    MatrixK,
    MatrixG,
    MatrixB,
    MatrixCp,
    MatrixCv,
    MatrixF,    /* n x 1: constant force (equilibrium away from zero); optional */
    MatrixDu,   /* p x m: direct feedthrough; optional */
    MatrixY0,   /* p x 1: output offset; optional */
    MatrixX0,   /* n x 1: initial positions (the start state); optional, default zero */
    MatrixV0,   /* n x 1: initial velocities; optional, default zero */
    MatrixPhi,  /* 3n x 3n: optional precomputed step map s+ = Phi s + Gamma [u; 1], s = [x; v; a] */
    MatrixGamma, /* 3n x (m + 1): its input part (last column: the constant 1 of F) */
    MatrixMapStep, /* 1 x 1: the step size the map belongs to (a map model steps with it only) */
    /* Optional modal (real block-diagonal) form of the step at one step size, O(n) per step; the
     * state is then carried as modal coordinates w (k of them, k even, k <= 3n) between steps:
     *   s = [x; v; a] = Shape w + Rest [u_h; 1] + RestChange du,   w+ = Blocks w + Input [u; 1],
     *   an input change du before a step: w += InputChange du, where u_h is the input of the last
     *   step and du the input changes since; outputs after a step: y = Output w + OutputInput [u; 1]
     *   + Du u + y0. */
    MatrixModalSize,        /* 1 x 2: [k, the step size the modal form belongs to] */
    MatrixModalBlocks,      /* 3n x 2: row i holds the 2 x 2 block entries of w+_i (columns 2(i/2), 2(i/2)+1) */
    MatrixModalInput,       /* 3n x (m + 1) (rows 0..k-1 used) */
    MatrixModalInputChange, /* 3n x m */
    MatrixModalShape,       /* 3n x 3n (columns 0..k-1 used) */
    MatrixModalProjection,  /* 3n x 3n (rows 0..k-1 used): w = Projection s */
    MatrixModalRest,        /* 3n x (m + 1) */
    MatrixModalRestChange,  /* 3n x m */
    MatrixModalOutput,      /* p x 3n (columns 0..k-1 used) */
    MatrixModalOutputInput, /* p x (m + 1) */
    MatrixX0Input, /* n x m: how the start positions follow the inputs set before initialization ends,
                    * x = X0 + X0Input u (a model that starts at its static equilibrium); optional */
    MatrixCount
} MatrixId;

typedef struct Assembly Assembly;

/* Provided by the kernel: add value at (row, col), both 0-based.  Entries at the same
 * position are summed.  M, D and K must be symmetric and given in full. */
void addEntry(Assembly *assembly, MatrixId id, int row, int col, double value);

/* Implemented by every model: add all matrix entries for the given parameters.
 * Returns OK, or Error with *message pointing to a static explanation. */
Status assembleSystem(const double parameters[], Assembly *assembly, const char **message);

#endif /* MODEL_H */
