"""POD basis: dense vs streamed Gram paths, order selection (eq. 18), kind resolution, bad data."""

from types import SimpleNamespace

import h5py
import numpy as np
import pytest
import scipy.linalg

from fmu_opinf.basis import PODBasis, cumulative_energy, energy_order, resolve_kind, svdvals
from fmu_opinf.errors import DataError, DimensionError, NotFittedError


@pytest.fixture()
def rng():
    """A fresh generator per test, so results do not depend on which tests ran before."""
    return np.random.default_rng(20251121)


def _low_rank_runs(rng, n, ks, rank=8, decay=0.5):
    """Runs whose stacked x has exactly ``rank`` well separated singular values."""
    modes = np.linalg.qr(rng.standard_normal((n, rank)))[0]
    runs = []
    for k in ks:
        coeff = rng.standard_normal((rank, k)) * (decay ** np.arange(rank))[:, None]
        x = modes @ coeff
        runs.append(SimpleNamespace(t=np.arange(k, dtype=float), x=x, xdot=2.0 * x, attrs={}))
    return runs


def _max_angle(a, b):
    return float(np.max(scipy.linalg.subspace_angles(a, b)))


@pytest.mark.parametrize("n, ks", [(40, [150, 110]), (300, [30, 25])], ids=["correlation", "snapshots"])
def test_streamed_equals_dense(rng, n, ks):
    runs = _low_rank_runs(rng, n, ks)
    dense = PODBasis(r=6, streamed=False).fit(runs)
    streamed = PODBasis(r=6, streamed=True, chunk_size=17).fit(runs)
    assert dense.method_ == "dense"
    assert streamed.method_ == ("streamed-correlation" if n <= sum(ks) else "streamed-snapshots")
    assert _max_angle(dense.basis_, streamed.basis_) < 1e-10
    np.testing.assert_allclose(streamed.svdvals_[:8], dense.svdvals_[:8], rtol=1e-10)
    assert streamed.rank_ == dense.rank_ == 8
    assert np.allclose(streamed.basis_.T @ streamed.basis_, np.eye(6), atol=1e-12)


@pytest.mark.parametrize("streamed, n, ks", [(False, 40, [150, 110]), (True, 40, [150, 110]), (True, 300, [30, 25])],
                         ids=["dense", "correlation", "snapshots"])
def test_wide_basis_extends_the_basis_from_one_decomposition(rng, streamed, n, ks):
    """``wide_order`` keeps more leading modes (bounded by the rank) whose first r are the basis a fit without it
    gives, on every path; the basis is the wide one's first r columns, not a second decomposition."""
    runs = _low_rank_runs(rng, n, ks)
    plain = PODBasis(r=3, streamed=streamed, chunk_size=17).fit(runs)
    wide = PODBasis(r=3, streamed=streamed, chunk_size=17, wide_order=50).fit(runs)
    assert wide.wide_basis_.shape == (n, 8)                            # rank 8 < 50
    assert np.array_equal(wide.basis_, wide.wide_basis_[:, :3])
    assert np.abs(wide.basis_ - plain.basis_).max() < 1e-15  # measured 0, 0, 5.6e-17
    assert np.allclose(wide.wide_basis_.T @ wide.wide_basis_, np.eye(8), atol=1e-12)
    assert _max_angle(wide.wide_basis_, PODBasis(r=8, streamed=False).fit(runs).basis_) < 1e-10
    default = PODBasis(r=3).fit(runs)
    assert default.wide_basis_ is default.basis_


@pytest.mark.parametrize("streamed, n, ks", [(False, 40, [150, 110]), (True, 40, [150, 110]), (True, 300, [30, 25])],
                         ids=["dense", "correlation", "snapshots"])
def test_at_order_gives_a_larger_order_from_the_same_decomposition(rng, streamed, n, ks):
    """``spare_order`` keeps leading modes for :meth:`PODBasis.at_order` (the fit's order search): a copy at a
    larger order, equal to what a fit at that order gives, while the basis itself keeps its order; beyond the
    modes kept it refuses."""
    runs = _low_rank_runs(rng, n, ks)
    pod = PODBasis(r=3, streamed=streamed, chunk_size=17, spare_order=6, wide_order=4).fit(runs)
    larger = pod.at_order(6)
    assert (pod.r_, pod.basis_.shape, larger.r_, larger.basis_.shape) == (3, (n, 3), 6, (n, 6))
    assert np.array_equal(larger.basis_[:, :3], pod.basis_)
    assert np.abs(larger.basis_ - PODBasis(r=6, streamed=streamed, chunk_size=17).fit(runs).basis_).max() < 1e-12
    assert larger.wide_basis_ is larger.basis_ and pod.wide_basis_.shape == (n, 4)
    assert pod.at_order(2).wide_basis_.shape == (n, 4)
    with pytest.raises(ValueError, match="spare_order=7"):
        pod.at_order(7)


def test_memory_limit_selects_streamed_path(rng):
    runs = _low_rank_runs(rng, 30, [200])
    assert PODBasis(r=3, max_memory=1e9).fit(runs).method_ == "dense"
    assert PODBasis(r=3, max_memory=1e4).fit(runs).method_ == "streamed-correlation"


def test_streamed_reads_h5py_datasets_in_chunks(tmp_path, rng):
    runs = _low_rank_runs(rng, 300, [40])
    with h5py.File(tmp_path / "x.h5", "w") as f:
        f.create_dataset("x", data=runs[0].x)
    with h5py.File(tmp_path / "x.h5", "r") as f:
        lazy = SimpleNamespace(t=runs[0].t, x=f["x"], xdot=f["x"], attrs={})
        pod = PODBasis(r=5, streamed=True, chunk_size=7).fit([lazy])
        projected = pod.project(f["x"], chunk_size=3)
    dense = PODBasis(r=5).fit(runs)
    assert _max_angle(pod.basis_, dense.basis_) < 1e-10
    np.testing.assert_allclose(projected, pod.basis_.T @ runs[0].x, atol=1e-12)


def test_projection_chunked_matches_dense(rng):
    runs = _low_rank_runs(rng, 25, [53])
    pod = PODBasis(r=4).fit(runs)
    np.testing.assert_allclose(pod.project(runs[0].x, chunk_size=5), pod.basis_.T @ runs[0].x, atol=1e-13)
    q = pod.project(runs[0].x)
    assert pod.reconstruct(q).shape == runs[0].x.shape


def test_singular_values_of_position_and_velocity_snapshots(rng):
    runs = _low_rank_runs(rng, 20, [60])
    sx = svdvals(runs, "positions")
    sv = svdvals(runs, "velocities")
    np.testing.assert_allclose(sv, 2.0 * sx, rtol=1e-12, atol=1e-12 * sx[0])


def test_cumulative_energy_and_order():
    sigma = np.array([4.0, 3.0, 2.0, 1.0])
    np.testing.assert_allclose(cumulative_energy(sigma), [0.4, 0.7, 0.9, 1.0])
    assert energy_order(sigma, 0.7) == 2
    assert energy_order(sigma, 0.71) == 3
    assert energy_order(sigma, 0.95) == 4
    with pytest.raises(ValueError, match="must lie in"):
        energy_order(sigma, 1.0)


def test_energy_threshold_resolves_tails_below_round_off():
    sigma = np.array([1.0, 1e-13, 1e-20])
    assert energy_order(sigma, 1 - 1e-12) == 1
    assert energy_order(sigma, 1 - 1e-14) == 2


def test_order_from_energy_is_capped_by_rank(rng):
    runs = _low_rank_runs(rng, 30, [100], rank=3)
    pod = PODBasis(energy=1 - 1e-15).fit(runs)
    assert pod.r_ == pod.rank_ == 3


def test_kind_resolution():
    assert resolve_kind("auto", {"constraint": "velocity"}) == "velocities"
    assert resolve_kind("auto", {"constraint": "position"}) == "positions"
    assert resolve_kind("auto", {}) == "positions"  # black box: unknown constraint kind
    assert resolve_kind("velocities", {"constraint": "position"}) == "velocities"
    with pytest.raises(ValueError, match="not known"):
        resolve_kind("modal")


def test_auto_kind_follows_snapshot_metadata(rng):
    runs = _low_rank_runs(rng, 20, [50])
    snaps = SimpleNamespace(runs=runs, attrs={"constraint": "velocity"})
    assert PODBasis(r=2).fit(snaps).kind_ == "velocities"


def test_r_above_rank_is_rejected(rng):
    runs = _low_rank_runs(rng, 30, [100], rank=5)
    with pytest.raises(DataError, match=r"^r=9 exceeds the snapshot rank 5; choose r <= 5$"):
        PODBasis(r=9).fit(runs)
    with pytest.raises(DataError, match="r=9 exceeds the snapshot rank 5"):
        PODBasis(r=9, streamed=True, chunk_size=13).fit(runs)


def test_nan_snapshots_are_rejected(rng):
    runs = _low_rank_runs(rng, 10, [30])
    runs[0].x[3, 17] = np.nan
    with pytest.raises(DataError, match="snapshot array x of run 0 has NaN/Inf at column 17"):
        PODBasis(r=2).fit(runs)
    with pytest.raises(DataError, match="at column 17"):
        PODBasis(r=2, streamed=True, chunk_size=4).fit(runs)


def test_inconsistent_runs_are_rejected(rng):
    runs = _low_rank_runs(rng, 10, [30, 30])
    runs[1].x = runs[1].x[:8]
    with pytest.raises(DimensionError, match="runs disagree in the number of states"):
        PODBasis(r=2).fit(runs)
    short = _low_rank_runs(rng, 10, [30])
    short[0].t = short[0].t[:20]
    with pytest.raises(DimensionError, match="t has 20 entries"):
        PODBasis(r=2).fit(short)


def test_zero_data_and_no_runs_are_rejected():
    zero = SimpleNamespace(t=np.arange(5.0), x=np.zeros((4, 5)), xdot=np.zeros((4, 5)))
    with pytest.raises(DataError, match="all snapshots are zero"):
        PODBasis().fit([zero])
    with pytest.raises(DataError, match="no snapshot runs"):
        PODBasis().fit([])


def test_use_before_fit_is_an_error():
    with pytest.raises(NotFittedError, match="not fitted"):
        PODBasis().project(np.zeros((3, 3)))


@pytest.mark.slow
def test_fitting_without_dask_does_not_import_distributed(tmp_path):
    """Whether a Dask client is active was asked by importing ``distributed`` (0.15-0.26 s of a 1 s ``fmu-opinf
    fit``); without it imported no client can exist, so a fit from a file leaves it unimported."""
    import subprocess
    import sys

    from fmu_opinf.cli import main

    path = tmp_path / "train.h5"
    assert main(["snapshots", "builtin:anchored-msd", "--g", "12", "--input", "impulse:amplitude=100,t0=2,width=0.5",
                 "--dt", "0.5", "--t-end", "100", "-o", str(path), "-q"]) == 0
    code = ("import sys; from fmu_opinf.fit import fit_rom_file; "
            f"fit_rom_file({str(path)!r}, {str(tmp_path / 'rom.h5')!r}, r=4); print('distributed' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split()[-1] == "False"


@pytest.mark.parametrize("status, active", [("running", True), ("connecting", False), ("closing", False)])
def test_only_a_running_client_sends_the_pod_to_dask(monkeypatch, status, active):
    """A default client that is connecting again or closing (its scheduler gone) does not count as active: a fit
    would wait for it without end (2026-12-07, the fast test set hung once in such a POD)."""
    distributed = pytest.importorskip("distributed")
    from fmu_opinf import basis

    monkeypatch.setattr(distributed, "default_client", lambda: type("Client", (), {"status": status})())
    assert basis._client_active() is active
