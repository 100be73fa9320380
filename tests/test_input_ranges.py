"""The source's declared input ranges travel with the data to the exported ROM FMU (audit 58, finding 6).

A source FMU declared its force input ``F`` within ``[-20, 20]`` and refused values outside; the training kept to it,
but the exported ROM FMU declared ``F`` with no ``min``/``max``, so a master learned nothing of the range the ROM is
valid in.  Now the recording stores the ranges (``input_min``, ``input_max``), the fit keeps them in the ROM's
provenance, and the ROM FMU declares them and refuses a value outside with fmi2Error / fmi3Error and a log line,
as the source does.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from fmpy import read_model_description  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402

from fmu_opinf import fmus  # noqa: E402
from fmu_opinf.errors import FileFormatError, FmuOpinfWarning  # noqa: E402
from fmu_opinf.export import export_fmu, rom_fmu_spec  # noqa: E402
from fmu_opinf.rom import SecondOrderROM, input_ranges  # noqa: E402

BOUNDED = '<Real unit="N" start="0.0" min="-20" max="20"/>'


def small_rom(snapshots: dict | None = None, **options) -> SecondOrderROM:
    """A stable two-input ROM whose provenance records ``snapshots`` as a fit from recorded snapshots does."""
    provenance = {} if snapshots is None else {"snapshots": snapshots}
    return SecondOrderROM(np.eye(2), 0.2 * np.eye(2), np.diag([1.0, 4.0]), np.array([[1.0, 0.5], [0.2, 1.0]]),
                          np.eye(2), np.zeros((2, 2)), input_names=["F", "G"], output_names=["y1", "y2"], dt=0.01,
                          provenance=provenance, **options)


def declared(path) -> dict[str, tuple[float | None, float | None]]:
    """``name -> (min, max)`` of the inputs the FMU at ``path`` declares, after fmpy's validation."""
    md = read_model_description(str(path), validate=True)
    number = lambda text: None if text is None else float(text)  # noqa: E731
    return {v.name: (number(v.min), number(v.max)) for v in md.modelVariables if v.causality == "input"}


def needs_build_tools() -> None:
    if fmus.find_build_tools() is None:
        pytest.skip("CMake and a C compiler are needed to build FMUs")


# ----------------------------------------------------------------- the ROM's ranges, read as data

def test_recorded_ranges_are_the_rom_s_and_a_rom_without_them_is_unbounded():
    low, high = small_rom({"input_min": [-20.0, "-inf"], "input_max": [20, 5.0]}).input_ranges()
    assert low.tolist() == [-20.0, -math.inf] and high.tolist() == [20.0, 5.0]
    for snapshots in (None, {}, {"input_min": [-1.0]}):   # fitted before ranges were recorded; a list that does not fit
        low, high = small_rom(snapshots).input_ranges()
        assert low.tolist() == [-math.inf] * 2 and high.tolist() == [math.inf] * 2


@pytest.mark.parametrize("entry", ['1" onload="x', None, True, float("nan"), 10**400, [1.0], {"v": 1}],
                         ids=["markup", "null", "bool", "nan", "huge-int", "list", "dict"])
def test_anything_but_a_finite_number_is_no_bound(entry):
    low, high = input_ranges({"snapshots": {"input_min": [entry, -3.0], "input_max": [entry, 3.0]}}, 2)
    assert low.tolist() == [-math.inf, -3.0] and high.tolist() == [math.inf, 3.0]


def test_a_range_whose_min_is_above_its_max_is_none():
    low, high = input_ranges({"snapshots": {"input_min": [5.0, -1.0], "input_max": [-5.0, 1.0]}}, 2)
    assert low.tolist() == [-math.inf, -1.0] and high.tolist() == [math.inf, 1.0]


def test_the_ranges_survive_the_rom_file(tmp_path):
    small_rom({"input_min": [-20.0, "-inf"], "input_max": [20.0, 5.0]}).save(tmp_path / "rom.h5")
    low, high = SecondOrderROM.load(tmp_path / "rom.h5").input_ranges()
    assert low.tolist() == [-20.0, -math.inf] and high.tolist() == [20.0, 5.0]


# ----------------------------------------------------------------- the generated model description and config.h

def test_a_rom_without_ranges_exports_as_before():
    for version in ("2.0", "3.0"):
        spec = rom_fmu_spec(small_rom(), "Plain", fmi_version=version)
        assert spec.input_ranges is None
        files, _ = fmus._source_tree(spec)
        assert b" min=" not in files["modelDescription.xml"] and b" max=" not in files["modelDescription.xml"]
        assert b"INPUT_MIN" not in files["sources/config.h"]


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_only_finite_bounds_are_written_each_as_the_repr_of_a_float(version):
    ranges = {"input_min": [-0.1, "-inf"], "input_max": [1e300, 5]}
    files, _ = fmus._source_tree(rom_fmu_spec(small_rom(ranges), "Ranged", fmi_version=version))
    xml, config = files["modelDescription.xml"].decode(), files["sources/config.h"].decode()
    assert 'min="-0.1" max="1e+300"' in xml and 'max="5.0"' in xml and xml.count("min=") == 1
    assert "#define INPUT_MIN { -0.1, (-INFINITY) }" in config and "#define INPUT_MAX { 1e+300, 5.0 }" in config


def test_hostile_recorded_ranges_reach_neither_the_xml_nor_the_c():
    payload = '0" causality="parameter'
    spec = rom_fmu_spec(small_rom({"input_min": [payload, "*/ pwn(); /*"], "input_max": [payload, 2.0]}), "Hostile")
    files, _ = fmus._source_tree(spec)
    xml, config = files["modelDescription.xml"].decode(), files["sources/config.h"].decode()
    assert "parameter" not in xml and "pwn" not in config
    assert spec.input_ranges == [(-math.inf, math.inf), (-math.inf, 2.0)]


def test_a_float32_input_s_checked_bounds_take_the_nearest_float32_outside():
    """A master sets a Float32 input to the Float32 nearest the declared bound (0.1f is 0.100000001): the FMU
    must not refuse it, while it declares the source's own bound."""
    spec = fmus.SecondOrderFmuSpec(identifier="Single", model_source="", n=1, m=1, p=1, fmi_version="3.0",
                                   input_ranges=[(-0.1, 0.1)],
                                   input_ports=[{"name": "F", "shape": [], "type": "Float32"}])
    files, _ = fmus._source_tree(spec)
    assert 'min="-0.1" max="0.1"' in files["modelDescription.xml"].decode()
    limit = float(np.float32(0.1))
    assert limit > 0.1 and f"#define INPUT_MAX {{ {limit!r} }}" in files["sources/config.h"].decode()


def test_an_array_declares_the_widest_range_of_its_elements():
    spec = fmus.SecondOrderFmuSpec(identifier="Array", model_source="", n=1, m=2, p=1, fmi_version="3.0",
                                   input_ranges=[(-5.0, 4.0), (-3.0, 6.0)],
                                   input_ports=[{"name": "F", "shape": [2], "type": "Float64"}])
    files, _ = fmus._source_tree(spec)
    assert '<Float64 name="F"' in files["modelDescription.xml"].decode()
    assert 'min="-5.0" max="6.0"' in files["modelDescription.xml"].decode()
    config = files["sources/config.h"].decode()
    assert "INPUT_MIN { -5.0, -5.0 }" in config and "INPUT_MAX { 6.0, 6.0 }" in config


@pytest.mark.parametrize("ranges", [[(1.0, 2.0)], [(2.0, -2.0)], [(float("nan"), 1.0)], [(-1.0,)], [(-1, 1), (0, 1)]])
def test_a_range_must_hold_the_start_value_and_be_a_pair_of_numbers(ranges):
    with pytest.raises(fmus.FmuBuildError, match="input range|input ranges"):
        fmus.SecondOrderFmuSpec(identifier="Bad", model_source="", n=1, m=1, p=1, input_ranges=ranges)


def test_a_recorded_range_that_does_not_hold_the_start_value_is_left_out_with_a_warning():
    rom = small_rom({"input_min": [1.0, -1.0], "input_max": [2.0, 1.0]})
    with pytest.warns(FmuOpinfWarning, match=r"input F within \[1, 2\], which does not hold its start value 0"):
        spec = rom_fmu_spec(rom, "Shifted")
    assert spec.input_ranges == [(-math.inf, math.inf), (-1.0, 1.0)]


def test_a_snapshot_file_with_a_nan_bound_is_refused(tmp_path):
    import h5py

    from fmu_opinf.snapshots import Snapshots, record
    from fmu_opinf.source import open_source

    record(open_source("builtin:anchored-msd", g=4), "impulse:amplitude=1,t0=0.1,width=0.2", dt=0.1, t_end=1.0,
           path=tmp_path / "s.h5", quiet=True)
    with h5py.File(tmp_path / "s.h5", "a") as f:
        f.attrs["input_min"], f.attrs["input_max"] = np.array([np.nan]), np.array([np.inf])
    with pytest.raises(FileFormatError, match="input min do not give one number for each of its 1 columns"):
        Snapshots.load(tmp_path / "s.h5")


# ----------------------------------------------------------------- the built FMU refuses what its source refuses

@pytest.mark.fmu
@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_the_rom_fmu_refuses_an_input_outside_its_range_with_a_log_line(tmp_path, version):
    needs_build_tools()
    path = export_fmu(small_rom({"input_min": [-20.0, "-inf"], "input_max": [20.0, "inf"]}),
                      tmp_path / "Ranged.fmu", fmi_version=version)
    assert declared(path) == {"F": (-20.0, 20.0), "G": (None, None)}
    held = lambda value: np.array([(0.0, value, -1e6), (1.0, value, -1e6)],  # noqa: E731
                                  dtype=[("time", float), ("F", float), ("G", float)])
    on_bound = fmpy.simulate_fmu(str(path), stop_time=0.5, output_interval=0.01, input=held(20.0))
    assert np.all(np.isfinite(on_bound["y1"]))   # the bound itself, and far out on the open input, are accepted
    log = []
    with pytest.raises(FMICallException, match="failed with status 3"):
        fmpy.simulate_fmu(str(path), stop_time=0.5, output_interval=0.01, input=held(20.5),
                          logger=lambda *args: log.append(args[-1].decode()))
    assert any("value 20.5 of input 1 (value reference 1) is outside its declared range [-20, 20]" in line
               for line in log), log


@pytest.mark.fmu
def test_a_float32_input_takes_the_float32_of_its_bound_and_refuses_the_next_one(tmp_path):
    from fmpy.fmi3 import FMU3Slave

    needs_build_tools()
    scalar = lambda name, kind: {"name": name, "shape": [], "type": kind}  # noqa: E731
    ports = {"inputs": [scalar("F", "Float32"), scalar("G", "Float64")],
             "outputs": [scalar("y1", "Float64"), scalar("y2", "Float64")]}
    rom = small_rom({"input_min": [-0.1, -1.0], "input_max": [0.1, 1.0], "fmi3_ports": ports})
    path = export_fmu(rom, tmp_path / "Single.fmu", fmi_version="3.0")
    assert declared(path) == {"F": (-0.1, 0.1), "G": (-1.0, 1.0)}
    md, log = read_model_description(str(path)), []
    fmu3 = FMU3Slave(guid=md.guid, unzipDirectory=fmpy.extract(str(path), str(tmp_path / "unzipped")),
                     modelIdentifier=md.coSimulation.modelIdentifier, instanceName="single")
    fmu3.instantiate(loggingOn=True, logMessage=lambda *args: log.append(args[-1].decode()))
    fmu3.enterInitializationMode(startTime=0.0)
    fmu3.exitInitializationMode()
    fmu3.setFloat32([1], [0.1])      # 0.1f, above 0.1 in double precision
    fmu3.setFloat32([1], [-0.1])
    with pytest.raises(FMICallException):
        fmu3.setFloat32([1], [float(np.nextafter(np.float32(0.1), np.float32(1)))])
    assert any("of input 1 (value reference 1) is outside its declared range [-0.1, 0.1]" in line for line in log)
    fmu3.freeInstance()


# ----------------------------------------------------------------- from the source FMU to the ROM FMU

@pytest.mark.fmu
@pytest.mark.slow  # 4 s on a loaded 2-core machine (2026-12-06)
def test_the_source_s_range_reaches_the_rom_fmu_through_the_files(tmp_path):
    """The audit's chain, snapshots -> fit -> export on the command line, with a source declaring F in [-20, 20]."""
    from conftest import rewrite_description

    from fmu_opinf import lti_fmus
    from fmu_opinf.cli import main
    from fmu_opinf.snapshots import Snapshots

    needs_build_tools()
    model = lti_fmus.chain_model(name="Bounded")
    built = lti_fmus.build_lti_fmu(model, tmp_path / "built.fmu", interfaces=("cs",))
    fmu = rewrite_description(built.path, tmp_path / "bounded.fmu",
                              lambda text: text.replace('<Real unit="N" start="0.0"/>', BOUNDED))
    train, rom = tmp_path / "train.h5", tmp_path / "rom.h5"
    assert main(["snapshots", str(fmu), "-o", str(train), "--dt", "0.1", "--t-end", "20", "-q"]) == 0
    attrs = Snapshots.load(train).attrs
    assert list(attrs["input_min"]) == [-20.0] and list(attrs["input_max"]) == [20.0]
    assert main(["fit", str(train), "-o", str(rom), "--r", "4", "-q"]) == 0
    for version in ("2.0", "3.0"):
        out = tmp_path / f"rom{version[0]}.fmu"
        assert main(["export", str(rom), "-o", str(out), "--fmi-version", version, "-q"]) == 0
        assert declared(out) == {"F": (-20.0, 20.0)}


@pytest.mark.fmu
@pytest.mark.slow  # 7 s on a loaded 2-core machine (2026-12-06)
def test_an_fmi3_array_input_s_range_is_declared_on_the_array_and_on_each_fmi2_element(tmp_path):
    from conftest import rewrite_description
    from fmpy.fmi3 import FMU3Slave

    from fmu_opinf import lti_fmus
    from fmu_opinf.cli import main

    needs_build_tools()
    model = lti_fmus.chain_model(inputs=(1, -1), name="RangedArray")
    built = lti_fmus.build_lti_fmu(model, tmp_path / "built.fmu", fmi_version="3.0", input_array=True,
                                   output_array=True)
    fmu = rewrite_description(built.path, tmp_path / "array.fmu", lambda text: text.replace(
        'causality="input" variability="continuous" unit="N"', 'causality="input" variability="continuous" '
        'unit="N" min="-5" max="5"'))
    train, rom = tmp_path / "train.h5", tmp_path / "rom.h5"
    assert main(["snapshots", str(fmu), "-o", str(train), "--dt", "0.05", "--t-end", "20", "-q"]) == 0
    assert main(["fit", str(train), "-o", str(rom), "--r", "5", "-q"]) == 0
    paths = {version: tmp_path / f"rom{version[0]}.fmu" for version in ("3.0", "2.0")}
    for version, out in paths.items():
        assert main(["export", str(rom), "-o", str(out), "--fmi-version", version, "-q"]) == 0
    assert declared(paths["3.0"]) == {"F": (-5.0, 5.0)}
    assert declared(paths["2.0"]) == {"F[1]": (-5.0, 5.0), "F[2]": (-5.0, 5.0)}
    md, log = read_model_description(str(paths["3.0"])), []
    folder = fmpy.extract(str(paths["3.0"]), str(tmp_path / "unzipped"))
    fmu3 = FMU3Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                     instanceName="ranged")
    fmu3.instantiate(loggingOn=True, logMessage=lambda *args: log.append(args[-1].decode()))
    fmu3.enterInitializationMode(startTime=0.0)
    fmu3.exitInitializationMode()
    fmu3.setFloat64([1], [5.0, -5.0])
    with pytest.raises(FMICallException):
        fmu3.setFloat64([1], [1.0, -6.0])   # the array's second element
    assert any("value -6 of input 2" in line and "[-5, 5]" in line for line in log), log
    fmu3.freeInstance()   # (after an error FMI 3 allows no fmi3Terminate)


# ----------------------------------------------------------------- compare refuses an input outside before running

@pytest.mark.fmu
def test_compare_refuses_an_input_outside_the_source_s_declared_range_before_running(tmp_path):
    """Audit 61, finding 6: a source that enforces F in [0, 30] refused compare's harmonic about 0 at the step it
    went below 0 ("... returned an error setting the input at step 106"), naming neither the input, the value
    nor the range.  compare refuses it before the run in one line with all of them.  The source here does not
    enforce its range, so the old code compared without a word.  Reference: 5 sin(3 t) first falls below 0 at
    the first sample past pi/3 = 1.0472 on the 0.01 grid, t = 1.05, where it is 5 sin(3.15) = -0.0420 (by hand)."""
    from conftest import rewrite_description

    from fmu_opinf import lti_fmus
    from fmu_opinf.compare import compare
    from fmu_opinf.errors import InputSpecError

    needs_build_tools()
    built = lti_fmus.build_lti_fmu(lti_fmus.chain_model(name="PushOnly"), tmp_path / "built.fmu", interfaces=("cs",))
    fmu = rewrite_description(built.path, tmp_path / "push.fmu", lambda text: text.replace(
        '<Real unit="N" start="0.0"/>', '<Real unit="N" start="0.0" min="0" max="30"/>'))
    rom = SecondOrderROM(np.eye(1), 0.2 * np.eye(1), np.eye(1), np.ones((1, 1)), np.ones((2, 1)), np.zeros((2, 1)),
                         input_names=["F"], dt=0.01)
    with pytest.raises(InputSpecError) as info:
        compare(rom, fmu, "harmonic:amplitude=5,omega=3", dt=0.01, t_end=2.0, quiet=True)
    text = str(info.value)
    assert "\n" not in text and "at t=1.05;" in text, text
    assert "input F is -0.0420362 there, below its declared min 0: give an input within [0, 30]" in text, text
    within = compare(rom, fmu, "harmonic:amplitude=5,omega=3,offset=5", dt=0.01, t_end=2.0, quiet=True)
    assert within.y_fom.shape == (2, 201)


@pytest.mark.parametrize("low, high", [(5.0, 30.0), (5.0, math.inf), (-30.0, -5.0), (-math.inf, -2.0), (5.0, 5.0),
                                       (0.0, 30.0), (-20.0, 20.0), (-20.0, 0.0)])
def test_the_example_input_of_a_range_refusal_lies_within_the_range(low, high):
    """The example a refusal offers (``--input '...'``) must itself be accepted: sampled finely, it stays within the
    range, also where the range leaves out 0 (audit 60: for ``[5, 30]`` the example rose from 0 and was refused at
    step 0 like the input it replaced), and it moves the input where the range has room."""
    from fmu_opinf.signals import parse_signal
    from fmu_opinf.sources._cosimulation import _pulse_within

    spec = _pulse_within(low, high, 100.0)
    u = parse_signal(spec, 1).sample(np.linspace(0.0, 5.0, 50_001))
    assert low <= u.min() and u.max() <= high, spec
    assert (u.max() - u.min() > 0) == (high > low), spec


def _pushed_at_a_bound(tmp_path, model):
    """``model`` as an ME FMU whose first force input declares ``[-30, -5]`` with start 0 (held at -5), opened."""
    from conftest import rewrite_description

    from fmu_opinf import lti_fmus
    from fmu_opinf.sources import open_source

    built = lti_fmus.build_lti_fmu(model, tmp_path / "built.fmu", interfaces=("me",))
    fmu = rewrite_description(built.path, tmp_path / "pushed.fmu", lambda text: text.replace(
        '<Real unit="N" start="0.0"/>', '<Real unit="N" start="0.0" min="-30" max="-5"/>', 1))
    return open_source(str(fmu))


@pytest.mark.slow  # about 10 s
def test_a_free_body_pushed_by_an_input_held_at_its_bound_gets_the_window_of_the_body_at_rest(tmp_path):
    """Audit 63, finding 5: a free body whose force input declares ``[-30, -5]`` (start 0, outside) is held at
    -5 N by the default training, a constant push under which it drifts: the impulse was widened to 500000 s and
    the refusal asked for a wider one still; then it was refused naming the held input.  Since audit 70 (finding
    2) the window sees the drift and judges the pulse response net of it: the pushed body gets the window of the
    same body without the range (held at its start 0, no push): the same step, its end within 1 %."""
    from fmu_opinf import lti_fmus
    from fmu_opinf.snapshots._default_training import _default_training_window
    from fmu_opinf.sources import open_source

    needs_build_tools()
    K = np.array([[20.0, -20.0, 0.0], [-20.0, 45.0, -25.0], [0.0, -25.0, 25.0]])   # free-free: K @ 1 = 0
    free = lti_fmus.LinearMechanicalModel(M=np.diag([1.0, 1.5, 0.8]), D=0.05 * K, K=K, B=np.eye(3)[:, [0, 2]],
                                          Cp=np.eye(3)[[0, 2]], name="Free")
    windows = []
    for source in (_pushed_at_a_bound(tmp_path, free), open_source(str(tmp_path / "built.fmu"))):
        try:
            window, signals = _default_training_window(source, {"quiet": True, "max_steps": 20_000})
        finally:
            source.close()
        windows.append((window.dt, window.t_end, [signal.spec for signal in signals]))
    # (the pushed input's pulse is -25 N, what its range allows, against +100: the fade differs by 0.6 %)
    assert windows[0][0] == windows[1][0] and windows[0][1] == pytest.approx(windows[1][1], rel=0.01), windows
    assert "offset=-5" in windows[0][2][0] and "offset" not in windows[1][2][0], windows


@pytest.mark.slow  # 10-20 s
def test_an_anchored_slow_model_pushed_at_a_bound_gets_a_wider_impulse(tmp_path):
    """Audit 65, finding 1: an anchored chain with periods of 700-4583 s, its input held at -5 N (a static
    preload it settles under) was refused at the first try as a drifting free body; before, and now again, the
    default training widens its impulse and records it."""
    from dataclasses import replace

    from fmu_opinf import lti_fmus
    from fmu_opinf.snapshots._default_training import _default_training_window

    needs_build_tools()
    base = lti_fmus.chain_model(5, inputs=(0, 4), name="Slow")
    slow = replace(base, M=base.M * 1e6, D=0.0005 * base.M * 1e6 + 0.01 * base.K)
    source = _pushed_at_a_bound(tmp_path, slow)
    try:
        window, signals = _default_training_window(source, {"quiet": True})
    finally:
        source.close()
    assert "width=50" in signals[1].spec and window.stopped_by == "fade", (signals[1].spec, window)
