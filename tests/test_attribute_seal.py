"""The SHA-256 seal over every attribute of snapshot and ROM files (docs/file-format.md, "Attribute seal").

HDF5's Fletcher-32 checksums cover the datasets' bytes only: a changed attribute (``input_names``, which
``compare`` maps to FMU inputs by name; units, provenance, settings; the large values kept in ``_attrs``) was
read without a word.  Each test below changes one attribute behind the seal's back (h5py, mode ``r+``) and
expects the one-line refusal naming the file as damaged; unchanged, unsealed (older) and run-table stamped files
still load.  The seal's helpers are imported inside the tests that need them, so that the tests of the refusal
run, and fail, on code without a seal.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pytest

from fmu_opinf import cli, runs
from fmu_opinf.errors import FileFormatError
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.snapshots import Snapshots, record
from fmu_opinf.source import BuiltinSource

SIGNAL = "impulse:amplitude=100,t0=2,width=0.5"
#: The root attribute holding the seal (spelled out: the tests of the refusal must run on code without it).
SEAL = "attributes_sha256"
#: Masses of the chain whose names (``x[1]``, ...) exceed an object header's share and go to ``_attrs``.
LARGE_G = 2000


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A snapshot file (names in ``_attrs``), a small one and a ROM fitted from the small one."""
    from fmu_opinf.fit import fit_rom_file

    folder = tmp_path_factory.mktemp("sealed")
    large = record(BuiltinSource("anchored-msd", g=LARGE_G), SIGNAL, 0.5, 10.0, quiet=True)
    large.save(folder / "large.h5")
    small = record("builtin:anchored-msd", SIGNAL, 0.5, 100.0, quiet=True)
    small.save(folder / "small.h5")
    fit_rom_file(folder / "small.h5", folder / "rom.h5", r=3, quiet=True)
    return {"snapshots": folder / "large.h5", "small": folder / "small.h5", "rom": folder / "rom.h5"}


def changed_copy(source: Path, folder: Path, change: Callable[[h5py.File], None]) -> Path:
    """A copy of ``source`` with ``change`` applied through h5py (the seal is left as it was)."""
    target = folder / source.name
    shutil.copy(source, target)
    with h5py.File(target, "r+") as f:
        change(f)
    return target


def assert_damaged(load: Callable[[Path], object], path: Path) -> None:
    """``load(path)`` refuses the file in one line naming it as damaged."""
    with pytest.raises(FileFormatError) as caught:
        opened = load(path)
        if isinstance(opened, Snapshots):
            opened.close()
    text = str(caught.value)
    assert "\n" not in text and str(path) in text and "damaged" in text, text
    assert SEAL in text, text   # (the seal's refusal, not a later check stumbling on the change)
    assert "write it again" in text and unseal_statement(path) in text, text   # both ways out


def unseal_statement(path: Path) -> str:
    """The statement of docs/file-format.md that deletes the seal of ``path`` (spelled out, independently of the
    code's own helper)."""
    return f"with h5py.File({str(path)!r}, 'r+') as f: del f.attrs['{SEAL}']"


def load_snapshots(path: Path) -> Snapshots:
    """Open ``path`` lazily, as ``fit`` and ``compare`` do, and close it again."""
    with Snapshots.open(path) as snaps:
        return snaps


# -- changes of one attribute --------------------------------------------------------------------------


def _rename_input(f: h5py.File) -> None:
    """An input name changed by one character: compare would drive another FMU input."""
    f.attrs["input_names"] = np.array(["F3"], dtype=h5py.string_dtype())


def _run_attribute(f: h5py.File) -> None:
    f["runs/0000"].attrs["input_spec"] = str(f["runs/0000"].attrs["input_spec"]).replace("100", "900")


def _dataset_attribute(f: h5py.File) -> None:
    f["runs/0000/x"].attrs["units"] = "mm"


def _large_value(f: h5py.File) -> None:
    """One name in a large value of ``_attrs``, rewritten in place (same dataset, same type)."""
    names = f["_attrs/position_names"]
    values = names[()]
    values[7] = b"x[9]"
    names[...] = values


def _removed_attribute(f: h5py.File) -> None:
    del f.attrs["constraint"]


def _changed_seal(f: h5py.File) -> None:
    seal = str(f.attrs[SEAL])
    f.attrs[SEAL] = ("1" if seal[0] != "1" else "2") + seal[1:]


@pytest.mark.parametrize("change", [_rename_input, _run_attribute, _dataset_attribute, _large_value,
                                    _removed_attribute, _changed_seal])
def test_a_snapshot_file_with_a_changed_attribute_is_refused(files, tmp_path, change):
    path = changed_copy(files["snapshots"], tmp_path, change)
    assert_damaged(load_snapshots, path)
    assert_damaged(Snapshots.load, path)


def _rom_output_names(f: h5py.File) -> None:
    names = [str(n) for n in f.attrs["output_names"]]
    f.attrs["output_names"] = np.array(names[::-1], dtype=h5py.string_dtype())


def _rom_provenance(f: h5py.File) -> None:
    """The provenance, a large value (a text dataset in ``_attrs``), rewritten in place."""
    text = f["_attrs/provenance"]
    text[()] = text[()].decode().replace("anchored", "anchorad")


def _rom_dataset_attribute(f: h5py.File) -> None:
    f["Kr"].attrs["scale"] = 2.0


def _rom_dt(f: h5py.File) -> None:
    f.attrs["dt"] = float(f.attrs["dt"]) * 2


@pytest.mark.parametrize("change", [_rom_output_names, _rom_provenance, _rom_dataset_attribute, _rom_dt])
def test_a_rom_file_with_a_changed_attribute_is_refused(files, tmp_path, change):
    path = changed_copy(files["rom"], tmp_path, change)
    assert_damaged(SecondOrderROM.load, path)


def test_a_flipped_byte_of_an_attribute_is_refused(files, tmp_path):
    """One byte of the stored file changed (no h5py): a model name, kept as text in the file's bytes."""
    path = tmp_path / "flipped.h5"
    data = bytearray(files["small"].read_bytes())
    at = data.find(b"anchored-msd(g=600)")
    assert at > 0
    data[at + 3] ^= 0x01
    path.write_bytes(bytes(data))
    assert_damaged(load_snapshots, path)


def _annotation(f: h5py.File) -> None:
    """A harmless attribute added on purpose (audit of 2026-12-06, F6)."""
    f.attrs["zz_note"] = "my annotation"


@pytest.mark.parametrize("name, load", [("small", load_snapshots), ("rom", SecondOrderROM.load)])
def test_the_statement_in_the_refusal_accepts_a_deliberate_change(files, tmp_path, name, load):
    """The refusal's own statement, run as it is printed, deletes the seal: the annotated file then loads."""
    folder = tmp_path / "a 'quoted' folder"
    folder.mkdir()
    path = changed_copy(files[name], folder, _annotation)
    with pytest.raises(FileFormatError) as caught:
        load(path)
    text = str(caught.value)
    statement = text[text.find("with h5py.File("):]
    assert statement == unseal_statement(path), statement
    exec(statement, {"h5py": h5py})   # noqa: S102 (the message's statement, exactly as a user would paste it)
    with h5py.File(path, "r") as f:
        assert SEAL not in f.attrs and f.attrs["zz_note"] == "my annotation"
    load(path)


def test_the_command_line_says_it_in_one_line(files, tmp_path, capsys):
    path = changed_copy(files["small"], tmp_path, _rename_input)
    code = cli.main(["fit", str(path), "-o", str(tmp_path / "rom.h5"), "--r", "2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("fmu-opinf: error: "), err
    assert "damaged" in err[0] and SEAL in err[0], err
    assert not (tmp_path / "rom.h5").exists()


# -- files that load ------------------------------------------------------------------------------------


def test_new_files_carry_a_seal_of_their_attributes(files):
    from fmu_opinf._seal import attribute_digest

    for name in ("snapshots", "small", "rom"):
        with h5py.File(files[name], "r") as f:
            seal = f.attrs[SEAL]
            assert isinstance(seal, str) and len(seal) == 64 and seal == attribute_digest(f)


def test_unchanged_files_load(files):
    with Snapshots.open(files["snapshots"]) as snaps:
        assert snaps.n == LARGE_G and SEAL not in snaps.attrs   # (not carried into files saved from these)
    assert SecondOrderROM.load(files["rom"]).r == 3


@pytest.mark.parametrize("name", ["snapshots", "rom"])
def test_files_without_a_seal_load_as_before(files, tmp_path, name):
    """Files written before the seal have none: they are read as before (their attributes unchecked)."""
    def unseal(f: h5py.File) -> None:
        if SEAL in f.attrs:
            del f.attrs[SEAL]
        _rom_provenance(f) if name == "rom" else _large_value(f)

    path = changed_copy(files[name], tmp_path, unseal)
    if name == "rom":
        assert SecondOrderROM.load(path).r == 3
    else:
        assert Snapshots.load(path).n == LARGE_G


def test_a_file_saved_from_loaded_snapshots_gets_its_own_seal(files, tmp_path):
    snaps = Snapshots.load(files["small"])
    snaps.runs[0].attrs["input_spec"] = "changed in memory"
    snaps.save(tmp_path / "again.h5")
    again = Snapshots.load(tmp_path / "again.h5")
    assert again.runs[0].attrs["input_spec"] == "changed in memory"


def test_a_run_table_stamp_reseals(files, tmp_path):
    """``runs`` stamps the row into a recorded file (mode ``r+``) after the atomic write: it reseals."""
    row = runs.RunRow(1, "r1", SIGNAL)
    outcome = runs.record_row("builtin:anchored-msd", row, tmp_path, {"dt": 0.5, "t_end": 20.0}, {"g": 12},
                              isolate=False)
    assert outcome.status == "recorded", outcome
    with h5py.File(outcome.path, "r") as f:
        assert runs.ROW_ATTR in f.attrs and SEAL in f.attrs
    with Snapshots.open(outcome.path) as snaps:
        assert snaps.n == 12
    (tmp_path / "changed").mkdir()
    changed = changed_copy(Path(outcome.path), tmp_path / "changed", lambda f: f.attrs.modify(runs.ROW_ATTR, "{}"))
    assert_damaged(load_snapshots, changed)


# -- the digest ---------------------------------------------------------------------------------------------


def test_the_digest_does_not_depend_on_the_attributes_order_or_string_storage(tmp_path):
    from fmu_opinf._seal import attribute_digest

    values = {"a": "text", "b": np.array(["x", "y"], dtype=h5py.string_dtype()), "c": 1.5, "d": True,
              "e": np.arange(3)}
    with h5py.File(tmp_path / "one.h5", "w") as one, \
            h5py.File(tmp_path / "two.h5", "w", track_order=True) as two:
        for key, value in values.items():
            one.attrs[key] = value
        for key in reversed(list(values)):
            value = values[key]
            two.attrs[key] = np.bytes_(value.encode()) if key == "a" else value   # fixed-length text
        two.attrs.modify("e", np.arange(3, dtype=">i8"))   # big-endian storage of the same numbers
        assert list(two.attrs) != list(one.attrs)
        assert attribute_digest(one) == attribute_digest(two)
        two.attrs["c"] = 1.25
        assert attribute_digest(one) != attribute_digest(two)
