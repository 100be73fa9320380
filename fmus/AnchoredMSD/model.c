/*
 * AnchoredMSD: chain of CHAIN_LENGTH masses tied to each other and to the ground by
 * springs and dampers; masses 1 and g joined by a rigid bar (position constraint).
 * Mehrmann & Stykel 2005; see readme.md for the equations.
 */
#include "model.h"

static int addChainMatrix(Assembly *assembly, MatrixId id, double coupling, double ground,
                          double groundEnd) {
    int g = CHAIN_LENGTH;
    int i;

    for (i = 0; i + 1 < g; i++) {
        addEntry(assembly, id, i, i, coupling);
        addEntry(assembly, id, i + 1, i + 1, coupling);
        addEntry(assembly, id, i, i + 1, -coupling);
        addEntry(assembly, id, i + 1, i, -coupling);
    }

    for (i = 0; i < g; i++) {
        addEntry(assembly, id, i, i, (i == 0 || i == g - 1) ? groundEnd : ground);
    }

    return 0;
}

Status assembleSystem(const double parameters[], Assembly *assembly, const char **message) {
    int g = CHAIN_LENGTH;
    int i;

    if (g < 3) {
        *message = "the chain needs at least 3 masses";
        return Error;
    }
    if (!(parameters[PAR_MASS] > 0.0)) {
        *message = "parameter mass must be positive";
        return Error;
    }
    if (parameters[PAR_K1] < 0.0 || parameters[PAR_K2] < 0.0 || parameters[PAR_K2_END] < 0.0 ||
        parameters[PAR_D1] < 0.0 || parameters[PAR_D2] < 0.0 || parameters[PAR_D2_END] < 0.0) {
        *message = "spring and damper constants must not be negative";
        return Error;
    }

    for (i = 0; i < g; i++) {
        addEntry(assembly, MatrixM, i, i, parameters[PAR_MASS]);
    }

    addChainMatrix(assembly, MatrixK, parameters[PAR_K1], parameters[PAR_K2], parameters[PAR_K2_END]);
    addChainMatrix(assembly, MatrixD, parameters[PAR_D1], parameters[PAR_D2], parameters[PAR_D2_END]);

    /* rigid bar: x_1 - x_g = 0 */
    addEntry(assembly, MatrixG, 0, 0, 1.0);
    addEntry(assembly, MatrixG, 0, g - 1, -1.0);

    /* force on mass 1 */
    addEntry(assembly, MatrixB, 0, 0, 1.0);

    /* positions of masses 1, 2 and g - 1 */
    addEntry(assembly, MatrixCp, 0, 0, 1.0);
    addEntry(assembly, MatrixCp, 1, 1, 1.0);
    addEntry(assembly, MatrixCp, 2, g - 2, 1.0);

    return OK;
}
