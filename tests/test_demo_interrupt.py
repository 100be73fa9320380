"""An interrupted or failed demo leaves its folder as it was (the previous run's files, byte for byte)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from fmu_opinf import demo
from fmu_opinf.errors import FileFormatError, Interrupted


def _tree(folder: Path) -> dict[str, str]:
    """Every file and folder under ``folder`` (hidden ones too), files with their SHA-256."""
    return {str(path.relative_to(folder)): (hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "dir")
            for path in sorted(folder.rglob("*"))}


def _previous_run(folder: Path) -> None:
    """A folder as a finished demo leaves it, plus a file of the user's that the demo does not write."""
    for name in ("anchored-msd", "triple-chain"):
        (folder / name / "report").mkdir(parents=True)
        (folder / name / "rom.h5").write_bytes(f"previous ROM of {name}".encode())
        (folder / name / "report" / "index.html").write_text(f"previous report of {name}")
    (folder / "summary.json").write_text('{"previous": true}')
    (folder / "index.html").write_text("previous summary page")
    (folder / "notes.txt").write_text("the user's own notes")


def _half_written(stop: BaseException):
    """Stand-in for the cases: writes part of a new run over the old one (a new file, a replaced one, a new model
    folder's content), then stops with ``stop``."""
    def run_cases(names, out_dir, **options):
        (out_dir / "anchored-msd").mkdir(exist_ok=True)
        (out_dir / "anchored-msd" / "rom.h5").write_bytes(b"half of a new ROM")
        (out_dir / "anchored-msd" / "snapshots.h5").write_bytes(b"new snapshots")
        (out_dir / "triple-chain").mkdir(exist_ok=True)
        (out_dir / "triple-chain" / "rom.h5").write_bytes(b"new")
        raise stop
    return run_cases


@pytest.mark.parametrize("stop", [KeyboardInterrupt(), Interrupted(15), RuntimeError("a case failed")],
                         ids=["ctrl-c", "sigterm", "error"])
def test_a_stopped_demo_puts_the_previous_run_back(tmp_path, monkeypatch, stop):
    _previous_run(tmp_path)
    before = _tree(tmp_path)
    monkeypatch.setattr(demo, "_run_cases", _half_written(stop))
    with pytest.raises(type(stop)):
        demo.run_demo(tmp_path, quiet=True)
    assert _tree(tmp_path) == before


def test_a_stopped_first_demo_leaves_no_file(tmp_path, monkeypatch):
    (tmp_path / "notes.txt").write_text("the user's own notes")
    before = _tree(tmp_path)
    monkeypatch.setattr(demo, "_run_cases", _half_written(KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        demo.run_demo(tmp_path, quiet=True)
    assert _tree(tmp_path) == before


def test_a_finished_run_replaces_only_its_own_entries_and_keeps_nothing_aside(tmp_path, monkeypatch):
    _previous_run(tmp_path)

    def one_case(names, out_dir, **options):
        assert not (out_dir / "triple-chain").exists()   # moved aside while the run writes
        (out_dir / "triple-chain").mkdir()
        (out_dir / "triple-chain" / "rom.h5").write_bytes(b"new ROM")
        return [{"model": "triple-chain", "r": 3, "dt": 0.1, "t_end": 1.0, "rom_fmu": None,
                 "rom": {"max_error": 1e-6, "speedup": 2.0}}]

    monkeypatch.setattr(demo, "_run_cases", one_case)
    monkeypatch.setattr(demo, "summary_table", lambda rows: "table")
    demo.run_demo(tmp_path, model="triple-chain", quiet=True)
    tree = _tree(tmp_path)
    assert sorted(tree) == ["anchored-msd", "anchored-msd/report", "anchored-msd/report/index.html",
                            "anchored-msd/rom.h5", "index.html", "notes.txt", "summary.json", "triple-chain",
                            "triple-chain/rom.h5"]
    assert (tmp_path / "anchored-msd" / "rom.h5").read_bytes() == b"previous ROM of anchored-msd"
    assert (tmp_path / "triple-chain" / "rom.h5").read_bytes() == b"new ROM"
    assert json.loads((tmp_path / "summary.json").read_text())["cases"][0]["model"] == "triple-chain"


def test_the_run_after_a_killed_one_puts_the_previous_run_back_first(tmp_path):
    """A run killed outright (SIGKILL: no handler runs) leaves the previous entries aside and its own half written:
    the next run restores the previous ones before it starts, and a failure of that run keeps them."""
    _previous_run(tmp_path)
    before = _tree(tmp_path)
    killed = demo._previous_run_kept(tmp_path, ["anchored-msd", "triple-chain", "summary.json", "index.html"])
    killed.__enter__()  # never left: the process died inside the block
    (tmp_path / "anchored-msd").mkdir()
    (tmp_path / "anchored-msd" / "rom.h5").write_bytes(b"half")
    assert _tree(tmp_path) != before
    with pytest.raises(RuntimeError):
        with demo._previous_run_kept(tmp_path, ["triple-chain"]):
            assert (tmp_path / "anchored-msd" / "rom.h5").read_bytes() == b"previous ROM of anchored-msd"
            assert not (tmp_path / "triple-chain").exists()
            (tmp_path / "triple-chain").mkdir()
            raise RuntimeError("this run fails too")
    assert _tree(tmp_path) == before


def test_a_manifest_naming_paths_outside_the_folder_is_not_followed(tmp_path):
    """The hidden folder is data: a manifest that names ``..`` or a path removes nothing outside the demo folder."""
    out, outside = tmp_path / "demo", tmp_path / "precious"
    out.mkdir()
    outside.mkdir()
    (outside / "file").write_text("keep me")
    keep = out / demo.PREVIOUS_RUN
    keep.mkdir()
    (keep / demo._MANIFEST).write_text(json.dumps(["..", "../precious", str(outside), "summary.json"]))
    (out / "summary.json").write_text("half")
    with demo._previous_run_kept(out, ["index.html"]):
        pass
    assert (outside / "file").read_text() == "keep me"
    assert sorted(path.name for path in out.iterdir()) == []


def test_an_entry_that_cannot_be_set_aside_stops_the_run_in_one_line_and_nothing_is_removed(tmp_path, monkeypatch):
    """Audit 67, finding 1: a model folder that cannot be renamed (a mount point: EBUSY) but whose files can be
    deleted.  The put-back took every name still in the folder for this run's and deleted the previous run's files
    (and the next run the summary files).  Now the run stops before any work and only what moved is moved back."""
    import errno

    _previous_run(tmp_path)
    before = _tree(tmp_path)
    rename = Path.rename

    def busy(self: Path, target):
        if self.name == "anchored-msd" and Path(target).parent.name == demo.PREVIOUS_RUN:
            raise OSError(errno.EBUSY, "Device or resource busy", str(self))
        return rename(self, target)

    monkeypatch.setattr(Path, "rename", busy)
    monkeypatch.setattr(demo, "_run_cases", _half_written(AssertionError("the cases must not run")))
    with pytest.raises(FileFormatError) as caught:
        demo.run_demo(tmp_path, quiet=True)
    message = str(caught.value)
    assert "\n" not in message and str(tmp_path / "anchored-msd") in message and "-o" in message, message
    assert _tree(tmp_path) == before
    monkeypatch.setattr(Path, "rename", rename)
    with demo._previous_run_kept(tmp_path, ["index.html"]):   # the next run finds nothing to put back or remove
        pass
    assert sorted(_tree(tmp_path)) == sorted(name for name in before if name != "index.html")


def test_a_folder_that_cannot_be_written_is_refused_in_one_line_before_the_work(tmp_path, monkeypatch, capsys):
    """Audit 67, finding 2: a read-only demo folder gave a traceback at the hidden folder's creation (exit 1); it
    is the one-line error of before (exit 2), now before any case runs."""
    from fmu_opinf import cli

    _previous_run(tmp_path)
    before = _tree(tmp_path)
    mkdir = Path.mkdir

    def read_only(self: Path, *args, **kwargs):
        if self.name == demo.PREVIOUS_RUN:
            raise PermissionError(1, "Operation not permitted", str(self))
        return mkdir(self, *args, **kwargs)

    monkeypatch.setattr(Path, "mkdir", read_only)
    monkeypatch.setattr(demo, "_run_cases", _half_written(AssertionError("the cases must not run")))
    assert cli.main(["demo", "-o", str(tmp_path), "--quick"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and "choose a writable location with -o" in err, err
    assert _tree(tmp_path) == before
