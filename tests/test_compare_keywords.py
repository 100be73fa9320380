"""compare takes the source's options as keywords, as record and record_to_file do (api84, item 3).

Before, ``compare`` took them only in the dict ``source_options`` (its fixes named ``source_options['inputs']``, its
report ``chosen without --input``), while ``record``, ``record_to_file`` and ``runs.compare_runs`` took ``inputs=``,
``outputs=``, ``parameters=``, ...: one vocabulary everywhere but one function.  Now ``compare(..., outputs=...,
parameters=...)`` does what ``fmu-opinf compare --outputs ... --set ...`` does (checked against the command line's
``metrics.json`` and the exact model, ``lti_fmus.zoh_response`` of the model with the parameter set), is refused with
an opened source as ``record`` refuses its keywords, and ``source_options`` is still taken.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from fmu_opinf import compare, snapshots
from fmu_opinf.errors import FmuOpinfWarning, InputSpecError
from fmu_opinf.fit import fit_rom
from fmu_opinf.signals import parse_signal
from fmu_opinf.sources import BuiltinSource, open_source

TRAIN = "impulse:amplitude=100,t0=2,width=0.5"
TEST = "harmonic:amplitude=1,omega=0.2"


def _one_line(error: BaseException, *parts: str) -> None:
    text = str(error)
    assert "\n" not in text and all(part in text for part in parts), text


@pytest.fixture(scope="module")
def anchored_rom(tmp_path_factory):
    """The file of a ROM of the anchored chain (g = 4, the order fit chooses)."""
    snaps = snapshots.record(BuiltinSource("anchored-msd", g=4), TRAIN, 0.5, 40.0, quiet=True)
    return fit_rom(snaps, quiet=True).save(tmp_path_factory.mktemp("keywords") / "rom.h5")


def test_size_keywords_are_the_source_options_sizes(anchored_rom):
    """``g=4`` as a keyword and in ``source_options`` compare the same model, the one the ROM was trained on (the
    default g = 12 has other outputs): bit-equal sources, and the ROM exact there."""
    by_keyword = compare.compare(anchored_rom, "builtin:anchored-msd", TEST, t_end=10.0, quiet=True, g=4,
                                 isolate=False)
    by_dict = compare.compare(anchored_rom, "builtin:anchored-msd", TEST, t_end=10.0, quiet=True,
                              source_options={"g": 4, "isolate": False})
    assert np.array_equal(by_keyword.y_fom, by_dict.y_fom) and by_keyword.metrics()["max_error"] < 1e-20
    other = compare.compare(anchored_rom, "builtin:anchored-msd", TEST, t_end=10.0, quiet=True, g=4, isolate=False,
                            source_options={"g": 4})   # (one value given both ways)
    assert np.array_equal(other.y_fom, by_dict.y_fom)


def test_a_key_given_both_ways_with_two_values_is_refused(anchored_rom):
    with pytest.raises(InputSpecError) as caught:
        compare.compare(anchored_rom, "builtin:anchored-msd", TEST, t_end=10.0, quiet=True, g=4,
                        source_options={"g": 12})
    _one_line(caught.value, "compare got g=4 and source_options['g']=12; give g= alone")


def test_an_unknown_keyword_is_refused_naming_the_right_one(anchored_rom):
    with pytest.raises(InputSpecError) as caught:
        compare.compare(anchored_rom, "builtin:anchored-msd", TEST, t_end=10.0, quiet=True, set={"k": 1})
    _one_line(caught.value, "compare takes no keyword 'set'; the command line's --set is 'parameters' in Python")
    with pytest.raises(InputSpecError) as caught:
        compare.compare(anchored_rom, "builtin:anchored-msd", TEST, t_end=10.0, quiet=True, output="y[1]")
    _one_line(caught.value, "compare takes no keyword 'output'; did you mean 'outputs'?")


def test_an_opened_source_refuses_them_as_record_does(anchored_rom):
    """An opened source is compared (and recorded) as opened: a keyword that opens it is refused in one line by
    both, not dropped without a word (before: compare dropped its source_options with an opened source)."""
    opened = BuiltinSource("anchored-msd", g=4)
    with pytest.raises(InputSpecError) as caught:
        compare.compare(anchored_rom, opened, TEST, t_end=10.0, quiet=True, g=12)
    _one_line(caught.value, "g= applies where the source is given as a path or spec, but", "is an opened source, "
              "compared as opened; give the source as its path or spec, or open it with open_source(spec, g=...)")
    with pytest.raises(InputSpecError) as caught:
        compare.compare(anchored_rom, opened, TEST, t_end=10.0, quiet=True, source_options={"g": 12})
    _one_line(caught.value, "g= applies where the source is given as a path or spec")
    with pytest.raises(InputSpecError) as caught:
        snapshots.record(opened, TRAIN, 0.5, 5.0, quiet=True, parameters={"k": 1})
    _one_line(caught.value, "parameters= applies where the source is given as a path or spec, but")
    as_opened = compare.compare(anchored_rom, opened, TEST, t_end=10.0, quiet=True, isolate=False)
    assert as_opened.metrics()["max_error"] < 1e-20   # (without such a keyword it compares; measured 4.5e-31)


# ----------------------------------------------------------------------------- an FMU source, against the CLI

@pytest.mark.slow   # an FMU compiled, one recording, two comparisons of two runs each (about 10 s, 2 cores)
def test_outputs_and_parameters_do_what_the_command_line_options_do(tmp_path):
    """``compare(..., outputs="y[2]", parameters={"stiffness_scale": 1.5})`` and ``fmu-opinf compare ... --outputs
    y[2] --set stiffness_scale=1.5``: the same metrics, and the source side is the exact model with K * 1.5."""
    from fmu_opinf import lti_fmus
    from fmu_opinf.cli import main
    from fmu_opinf.fmus import find_build_tools

    if find_build_tools() is None:
        pytest.skip("needs a C compiler")
    model = lti_fmus.chain_model(inputs=(1,), name="Keywords")
    fmu = lti_fmus.build_lti_fmu(model, tmp_path / "Keywords.fmu").path
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)
        recorded = snapshots.record(str(fmu), TRAIN, 0.05, 30.0, quiet=True, outputs="y[1]")
        rom_file = fit_rom(recorded, quiet=True).save(tmp_path / "rom.h5")
    options = {"outputs": "y[2]", "parameters": {"stiffness_scale": 1.5}}
    with pytest.warns(FmuOpinfWarning, match=r"compared with stiffness_scale=1.5, but the ROM was trained with "
                                             r"stiffness_scale=1.0 \(its start value\)"):
        result = compare.compare(rom_file, str(fmu), TEST, t_end=20.0, quiet=True, **options)
    exact = lti_fmus.zoh_response(model.scaled(stiffness_scale=1.5), result.t,
                                  parse_signal(TEST, 1).sample(result.t)).y[1]
    assert result.output_names == ["y[2]"]
    assert np.abs(result.y_fom[0] - exact).max() < 2e-10 * np.ptp(exact)   # the FMU's RK4: measured 3.3e-11 (0.39 at
    # the trained stiffness: the parameter reached the source)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)
        assert main(["compare", str(rom_file), str(fmu), "--input", TEST, "--t-end", "20", "--outputs", "y[2]",
                     "--set", "stiffness_scale=1.5", "-o", str(tmp_path / "report"), "-q"]) == 0
    on_the_command_line = json.loads((tmp_path / "report" / "metrics.json").read_text())
    in_python = json.loads(json.dumps(result.metrics()))
    for key in ("max_error", "l2_error", "per_output", "input"):
        assert on_the_command_line[key] == in_python[key], key
    for call in (lambda: compare.compare(rom_file, open_source(fmu), TEST, t_end=20.0, quiet=True, **options),
                 lambda: snapshots.record(open_source(fmu), TEST, 0.05, 1.0, quiet=True, **options)):
        with pytest.raises(InputSpecError) as caught:   # (an opened FMU: refused by both, not dropped)
            call()
        _one_line(caught.value, "outputs= applies where the source is given as a path or spec, but")
    settings = [{name: float(value) for name, value in side["fom"].pop("fmu_settings").items()}
                for side in (on_the_command_line, in_python)]   # (the command line's as typed: '1.5')
    assert settings[0] == settings[1] == {"stiffness_scale": 1.5}
    assert on_the_command_line["fom"] == in_python["fom"]
