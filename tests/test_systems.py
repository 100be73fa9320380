"""The assembled benchmark matrices match shared/spec/benchmarks.md entry by entry."""

import numpy as np
import pytest

from fmu_opinf import systems
from fmu_opinf.errors import DimensionError, FmuOpinfError


def test_anchored_chain_entries(anchored):
    K, D, M = anchored.K.toarray(), anchored.D.toarray(), anchored.M.toarray()
    g = anchored.n
    assert g == 600
    assert np.all(np.diag(K) == 6.0)
    assert np.all(np.diag(K, 1) == -2.0) and np.all(np.diag(K, -1) == -2.0)
    assert np.count_nonzero(K) == g + 2 * (g - 1)
    assert np.array_equal(D, 2.5 * K)
    assert np.array_equal(M, 100.0 * np.eye(g))
    G = anchored.G.toarray()
    assert G.shape == (1, g) and G[0, 0] == 1 and G[0, -1] == -1 and np.count_nonzero(G) == 2
    assert anchored.constraint == "position"
    B = anchored.B.toarray()
    assert B.shape == (g, 1) and B[0, 0] == 1 and np.count_nonzero(B) == 1
    Cp = anchored.Cp.toarray()
    assert Cp.shape == (3, g) and Cp[0, 0] == Cp[1, 1] == Cp[2, g - 2] == 1 and np.count_nonzero(Cp) == 3
    assert anchored.Cv.nnz == 0


def test_anchored_chain_ground_ties_doubled_at_ends():
    K = systems.anchored_msd(g=5, k1=1.0, k2=3.0).K.toarray()
    # K_ii = k1_{i-1} + k2_i + k1_i with k2 doubled at both ends
    assert np.allclose(np.diag(K), [1 + 6, 1 + 3 + 1, 1 + 3 + 1, 1 + 3 + 1, 6 + 1])


def test_triple_chain_entries(triple):
    n1, n = 100, 301
    K, M, D = triple.K.toarray(), triple.M.toarray(), triple.D.toarray()
    assert triple.n == n and K[n - 1, n - 1] == 81.0
    for c, (kc, mc) in enumerate(zip((10.0, 20.0, 1.0), (1.0, 2.0, 3.0))):
        block = slice(c * n1, (c + 1) * n1)
        assert np.all(np.diag(K)[block] == 2 * kc)
        assert np.all(np.diag(K, 1)[c * n1:(c + 1) * n1 - 1] == -kc)
        assert K[(c + 1) * n1 - 1, n - 1] == K[n - 1, (c + 1) * n1 - 1] == -kc
        assert np.all(np.diag(M)[block] == mc)
    assert M[n - 1, n - 1] == 10.0
    # chains are not coupled to each other directly
    assert K[n1 - 1, n1] == 0 and K[2 * n1 - 1, 2 * n1] == 0
    dampers = np.zeros(n)
    dampers[[0, n1 - 1, 2 * n1]] = 5.0
    assert np.allclose(D, 0.01 * M + 0.01 * K + np.diag(dampers), rtol=0, atol=1e-15)
    G = triple.G.toarray()
    pairs = [(1, 50), (51, 100), (101, 150), (151, 200), (201, 250), (251, 300)]
    assert G.shape == (6, n) and triple.constraint == "velocity"
    for row, (i, j) in enumerate(pairs):
        assert G[row, i - 1] == 1 and G[row, j - 1] == -1 and np.count_nonzero(G[row]) == 2
    assert np.array_equal(triple.B.toarray(), np.ones((n, 1)))
    assert np.array_equal(triple.Cp.toarray(), np.ones((1, n)))


def test_matrices_are_symmetric_and_definite(anchored, triple):
    for system in (anchored, triple):
        for A in (system.M, system.D, system.K):
            assert abs(A - A.T).max() == 0
        assert np.linalg.eigvalsh(system.K.toarray()).min() > 0
        assert np.linalg.eigvalsh(system.D.toarray()).min() > -1e-12


def test_bad_sizes_are_rejected():
    with pytest.raises(DimensionError, match="even n1"):
        systems.triple_chain(n1=7)
    with pytest.raises(DimensionError, match="g >= 4"):
        systems.anchored_msd(g=2)
    with pytest.raises(FmuOpinfError, match="unknown builtin model"):
        systems.builtin_system("pendulum")
