/*
 * TripleChainMSD: three chains of CHAIN_LENGTH masses, each tied to a wall, whose last
 * masses are tied to one common mass; six velocity constraints tie the ends of each half
 * chain.  Truhar & Veselic 2009, Example 2; see readme.md for the equations.
 */
#include "model.h"

#define N1 CHAIN_LENGTH
#define N_TOTAL (3 * CHAIN_LENGTH + 1)

/* Stiffness-pattern matrix: chains k_c tridiag(-1, 2, -1), coupling to the common mass. */
static void addStiffness(Assembly *assembly, MatrixId id, const double k[3], double k0,
                         double scale) {
    int last = N_TOTAL - 1;
    int c, i;

    for (c = 0; c < 3; c++) {
        int offset = c * N1;
        for (i = 0; i < N1; i++) {
            addEntry(assembly, id, offset + i, offset + i, scale * 2.0 * k[c]);
            if (i + 1 < N1) {
                addEntry(assembly, id, offset + i, offset + i + 1, -scale * k[c]);
                addEntry(assembly, id, offset + i + 1, offset + i, -scale * k[c]);
            }
        }
        addEntry(assembly, id, offset + N1 - 1, last, -scale * k[c]);
        addEntry(assembly, id, last, offset + N1 - 1, -scale * k[c]);
    }

    addEntry(assembly, id, last, last, scale * (k[0] + k[1] + k[2] + k0));
}

static void addMass(Assembly *assembly, MatrixId id, const double mass[3], double m0,
                    double scale) {
    int c, i;

    for (c = 0; c < 3; c++) {
        for (i = 0; i < N1; i++) {
            addEntry(assembly, id, c * N1 + i, c * N1 + i, scale * mass[c]);
        }
    }
    addEntry(assembly, id, N_TOTAL - 1, N_TOTAL - 1, scale * m0);
}

Status assembleSystem(const double parameters[], Assembly *assembly, const char **message) {
    const double mass[3] = { parameters[PAR_M1], parameters[PAR_M2], parameters[PAR_M3] };
    const double k[3] = { parameters[PAR_K1], parameters[PAR_K2], parameters[PAR_K3] };
    double alpha = parameters[PAR_ALPHA];
    double beta = parameters[PAR_BETA];
    double v = parameters[PAR_V];
    int half = N1 / 2;
    int c, i;

    if (N1 < 2 || N1 % 2 != 0) {
        *message = "the chain length n1 must be even and at least 2";
        return Error;
    }
    if (!(mass[0] > 0.0 && mass[1] > 0.0 && mass[2] > 0.0 && parameters[PAR_M0] > 0.0)) {
        *message = "masses must be positive";
        return Error;
    }
    if (!(k[0] > 0.0 && k[1] > 0.0 && k[2] > 0.0) || parameters[PAR_K0] < 0.0) {
        *message = "chain stiffnesses must be positive and k0 non-negative";
        return Error;
    }
    if (alpha < 0.0 || beta < 0.0 || v < 0.0) {
        *message = "damping parameters alpha, beta, v must not be negative";
        return Error;
    }

    addMass(assembly, MatrixM, mass, parameters[PAR_M0], 1.0);
    addStiffness(assembly, MatrixK, k, parameters[PAR_K0], 1.0);

    /* D = alpha M + beta K + v (e_1 e_1^T + e_n1 e_n1^T + e_{2 n1 + 1} e_{2 n1 + 1}^T) */
    addMass(assembly, MatrixD, mass, parameters[PAR_M0], alpha);
    addStiffness(assembly, MatrixD, k, parameters[PAR_K0], beta);
    addEntry(assembly, MatrixD, 0, 0, v);
    addEntry(assembly, MatrixD, N1 - 1, N1 - 1, v);
    addEntry(assembly, MatrixD, 2 * N1, 2 * N1, v);

    /* velocity constraints tying the two ends of each half chain */
    for (c = 0; c < 3; c++) {
        addEntry(assembly, MatrixG, 2 * c, c * N1, 1.0);
        addEntry(assembly, MatrixG, 2 * c, c * N1 + half - 1, -1.0);
        addEntry(assembly, MatrixG, 2 * c + 1, c * N1 + half, 1.0);
        addEntry(assembly, MatrixG, 2 * c + 1, (c + 1) * N1 - 1, -1.0);
    }

    for (i = 0; i < N_TOTAL; i++) {
        addEntry(assembly, MatrixB, i, 0, 1.0);
        addEntry(assembly, MatrixCp, 0, i, 1.0);
    }

    return OK;
}
