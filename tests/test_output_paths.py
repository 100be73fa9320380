"""Where outputs go: an ``-o`` that is not a plain file (audit 55)."""

import os
import stat

import pytest

from fmu_opinf import snapshots
from fmu_opinf.fit import fit_rom
from fmu_opinf.errors import FileFormatError

from test_cli import run_cli

SPEC = dict(signal="impulse:amplitude=100,t0=2,width=0.5", dt=0.5, t_end=20.0, quiet=True)


def test_an_output_named_by_a_pipe_is_refused_and_the_pipe_stays(tmp_path):
    """``--force`` renamed the new file over a device or a pipe: as root, ``-o /dev/null --force`` replaced the
    system's /dev/null with an HDF5 file.  Refused in one line; the pipe is still a pipe."""
    fifo = tmp_path / "pipe.h5"
    os.mkfifo(fifo)
    with pytest.raises(FileFormatError, match="is a device, a pipe or a socket, not a file; give the name of a file"):
        snapshots.record_to_file("builtin:anchored-msd", fifo, overwrite=True, **SPEC)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe.h5"]   # no temporary file left


@pytest.mark.parametrize("verb, suffix", [("snapshots", ".h5"), ("fit", ".h5"), ("export", ".fmu")])
def test_the_command_line_refuses_a_pipe_before_the_work(tmp_path, verb, suffix):
    snaps = tmp_path / "s.h5"
    snapshots.record_to_file("builtin:anchored-msd", snaps, **SPEC)
    fifo = tmp_path / f"pipe{suffix}"
    os.mkfifo(fifo)
    args = {"snapshots": ["builtin:anchored-msd", "--input", SPEC["signal"], "--dt", "0.5", "--t-end", "20"],
            "fit": [str(snaps), "--r", "2"], "export": [str(snaps)]}[verb]
    done = run_cli(verb, *args, "-o", str(fifo), "--force")
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"fmu-opinf: error: {fifo} is a device, a pipe or a socket, not a file; give the name of a file to write"]
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


@pytest.mark.slow
def test_an_output_named_by_a_link_is_written_to_the_file_it_points_to(tmp_path):
    """A symbolic link was replaced by the new file; the new file now replaces the one the link points to, and
    the link stays (snapshots, and the exported FMU)."""

    from fmu_opinf.export import export_fmu
    import fmpy

    real = tmp_path / "data" / "train.h5"
    real.parent.mkdir()
    real.write_bytes(b"old")
    link = tmp_path / "train.h5"
    link.symlink_to(real)
    snapshots.record_to_file("builtin:anchored-msd", link, overwrite=True, **SPEC)
    assert link.is_symlink() and snapshots.Snapshots.load(real).runs[0].t[-1] == 20.0
    assert sorted(p.name for p in real.parent.iterdir()) == ["train.h5"]

    fitted = fit_rom(snapshots.Snapshots.load(real), r=2)
    (real.parent / "rom.fmu").write_bytes(b"old")
    (tmp_path / "rom.fmu").symlink_to(real.parent / "rom.fmu")
    export_fmu(fitted, tmp_path / "rom.fmu", overwrite=True)
    assert (tmp_path / "rom.fmu").is_symlink()
    assert len(fmpy.simulate_fmu(str(real.parent / "rom.fmu"), stop_time=1.0, output_interval=0.5)) == 3


@pytest.mark.parametrize("args", [["build-fmus", "-o", ""], ["fit", "s.h5", "-o", ""],
                                  ["fit", "s.h5", "-o", "r.h5", "--figures", ""]])
def test_an_empty_output_path_is_refused(tmp_path, args):
    """``build-fmus -o ""`` wrote into the package's own fmus/ folder, ``--figures ""`` into the current one."""
    done = run_cli(*args, cwd=tmp_path)
    flag = "--figures" if "--figures" in args else "-o"
    assert done.returncode == 2 and done.stderr.strip() == f"fmu-opinf: error: {flag} is empty; give a path"
    assert list(tmp_path.iterdir()) == []


def test_build_fmus_interrupted_after_one_fmu_names_it(tmp_path, monkeypatch, capsys):
    """Interrupted between its two FMUs, ``build-fmus`` said that no output file was written or replaced, but the
    first was (audit 55).  It names what it replaced."""
    from fmu_opinf import cli, fmus

    built = []
    real = fmus.build_second_order_fmu

    def second_interrupted(spec, path, **options):
        if built:
            raise KeyboardInterrupt
        built.append(real(spec, path, **options))
        return built[-1]

    monkeypatch.setattr(fmus, "build_second_order_fmu", second_interrupted)
    assert cli.main(["build-fmus", "-o", str(tmp_path), "--g", "4", "--n1", "4"]) == 130
    assert capsys.readouterr().err.strip() == (f"fmu-opinf: interrupted (Ctrl-C); written before it: {built[0]}; "
                                               "every other output was left as it was")
    assert [p.name for p in tmp_path.iterdir()] == [built[0].name]


@pytest.mark.slow
def test_a_link_or_a_pipe_among_a_report_s_or_the_figures_files_is_refused_before_the_work(tmp_path):
    """Audit 56: a report's outputs.png linked to the ROM being compared overwrote the ROM (written through the
    link), ``fit --figures`` wrote through a link into its input, and a pipe among the figures ended the fit in
    a traceback after its work."""
    from fmu_opinf import compare

    snaps = tmp_path / "s.h5"
    snapshots.record_to_file("builtin:anchored-msd", snaps, **SPEC)
    fit_rom(snapshots.Snapshots.load(snaps), r=2).save(tmp_path / "rom.h5")
    before = (tmp_path / "rom.h5").read_bytes()
    report = tmp_path / "report"
    report.mkdir()
    (report / "metrics.json").write_text("{}")
    (report / "outputs.png").symlink_to(tmp_path / "rom.h5")
    done = run_cli("compare", str(tmp_path / "rom.h5"), "builtin:anchored-msd", "-o", str(report), "--input",
                   "harmonic:amplitude=1,omega=0.2", "--dt", "0.5", "--t-end", "20")
    assert done.returncode == 2 and done.stderr.strip().splitlines() == [
        f"fmu-opinf: error: {report / 'outputs.png'} is a symbolic link; the files of {report} are written there: "
        "remove it or choose another folder"]
    with pytest.raises(FileFormatError, match="is a symbolic link"):   # the API, with its work done
        compare.write_report(compare.compare(tmp_path / "rom.h5", "builtin:anchored-msd", "harmonic:amplitude=1,"
                                             "omega=0.2", dt=0.5, t_end=20.0, quiet=True), report)
    assert (tmp_path / "rom.h5").read_bytes() == before

    figures = tmp_path / "figures"
    figures.mkdir()
    os.mkfifo(figures / "singular_values.png")
    done = run_cli("fit", str(snaps), "-o", str(tmp_path / "r2.h5"), "--r", "2", "--figures", str(figures))
    assert done.returncode == 2 and "Traceback" not in done.stderr and done.stderr.strip().splitlines()[-1] == (
        f"fmu-opinf: error: {figures / 'singular_values.png'} is not a plain file; the files of {figures} are "
        "written there: remove it or choose another folder")
    assert not (tmp_path / "r2.h5").exists()


@pytest.mark.slow  # 6 s in the fast set of 2026-12-06
def test_links_in_a_run_table_s_or_the_demo_s_folder_and_dangling_links_are_refused_before_the_work(tmp_path):
    """Audit 57: ``compare --runs`` wrote its table's index.html through a link into the ROM it compared; the demo
    wrote summary.json through a link, or refused a linked figure only after its work; ``--figures`` naming a
    link to nothing failed after the fit with "File exists"; a link elsewhere in the figures' folder is no
    concern of the fit's."""


    snaps = tmp_path / "s.h5"
    snapshots.record_to_file("builtin:anchored-msd", snaps, **SPEC)
    fit_rom(snapshots.Snapshots.load(snaps), r=2).save(tmp_path / "rom.h5")
    before = (tmp_path / "rom.h5").read_bytes()
    table = tmp_path / "t.csv"
    table.write_text('name,input\nr1,"harmonic:amplitude=1,omega=0.5"\n')
    (tmp_path / "rr").mkdir()
    (tmp_path / "rr" / "index.html").symlink_to(tmp_path / "rom.h5")
    done = run_cli("compare", str(tmp_path / "rom.h5"), "builtin:anchored-msd", "--runs", str(table), "-o",
                   str(tmp_path / "rr"), "--dt", "0.5", "--t-end", "20")
    assert done.returncode == 2 and done.stderr.strip().splitlines()[-1].endswith(
        "rr/index.html is a symbolic link; the files of " + str(tmp_path / "rr") + " are written there: remove it "
        "or choose another folder"), done.stderr
    assert (tmp_path / "rom.h5").read_bytes() == before and not (tmp_path / "rr" / "r1").exists()

    (tmp_path / "demo" / "anchored-msd" / "report").mkdir(parents=True)
    (tmp_path / "demo" / "anchored-msd" / "report" / "outputs.png").symlink_to(tmp_path / "rom.h5")
    done = run_cli("demo", "--quick", "-o", str(tmp_path / "demo"))
    assert done.returncode == 2 and "outputs.png is a symbolic link" in done.stderr.strip().splitlines()[-1]
    assert (tmp_path / "rom.h5").read_bytes() == before
    assert sorted(p.name for p in (tmp_path / "demo").rglob("*")) == ["anchored-msd", "outputs.png", "report"]

    (tmp_path / "figd").symlink_to(tmp_path / "nowhere")
    done = run_cli("fit", str(snaps), "-o", str(tmp_path / "r.h5"), "--r", "2", "--figures", str(tmp_path / "figd"))
    assert done.returncode == 2 and done.stderr.strip() == (
        f"fmu-opinf: error: --figures {tmp_path / 'figd'} is a symbolic link to nothing ({tmp_path / 'nowhere'}); "
        "give an existing path or a new name")
    (tmp_path / "figs").mkdir()
    (tmp_path / "figs" / "alias.h5").symlink_to(snaps)
    done = run_cli("fit", str(snaps), "-o", str(tmp_path / "r.h5"), "--r", "2", "--figures", str(tmp_path / "figs"))
    assert done.returncode == 0 and (tmp_path / "figs" / "singular_values.png").is_file(), done.stderr
