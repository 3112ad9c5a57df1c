"""The CLI helpers written once (``terrainml.commands._common``): refusals are one ``error:`` line
naming the file, exit code 2, no traceback; outputs and ``--n-jobs`` are checked before the work,
by the helpers and by the commands that use them (``ingest``, ``train``, ``evaluate``, ``dataset
build``, ``evaluate-protocol``); ``dataset build`` says which runs are damaged.

The tests run as root in CI, and root ignores permission bits, so an unwritable output is made
in ways that fail for root too: a path below a regular file, and a path inside ``/proc``.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
import typer

import terrainml.commands._common as common
from terrainml.commands._common import (check_n_jobs, check_output_writable, fail, is_windows_file,
                                        open_dataset, open_robot, open_run)
from terrainml.testing import kinematic_run
from terrainml.schema import write_run_parquet

IS_ROOT = getattr(os, "geteuid", lambda: -1)() == 0
HAS_PROC = Path("/proc/self").is_dir()


def _refused(capsys, call, *args, **kwargs) -> str:
    """Run ``call``; assert it exits with code 2; return what it printed on stderr."""
    with pytest.raises(typer.Exit) as exc:
        call(*args, **kwargs)
    assert exc.value.exit_code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Traceback" not in err
    return err.replace("\n", "")


def test_fail_prints_one_error_line_and_exits_2(capsys):
    err = _refused(capsys, fail, "runs/[red]x.parquet: broken")
    # markup-like text in a path is printed as is, not swallowed by rich
    assert err == "error: runs/[red]x.parquet: broken"


# ----------------------------------------------------------------- outputs
def test_writable_outputs_pass_and_create_nothing(tmp_path):
    before = sorted(tmp_path.rglob("*"))
    assert check_output_writable(tmp_path / "a" / "b" / "est.parquet") == tmp_path / "a" / "b" / "est.parquet"
    assert check_output_writable(tmp_path / "new_folder", folder=True) == tmp_path / "new_folder"
    assert check_output_writable(tmp_path, folder=True) == tmp_path
    assert sorted(tmp_path.rglob("*")) == before  # no folder, no probe file left behind


def test_existing_output_file_is_kept_unchanged(tmp_path):
    f = tmp_path / "est.parquet"
    f.write_bytes(b"old content")
    mtime = f.stat().st_mtime_ns
    check_output_writable(f)
    assert f.read_bytes() == b"old content" and f.stat().st_mtime_ns == mtime


def test_output_below_a_regular_file_is_refused(tmp_path, capsys):
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, not a folder")
    target = blocker / "sub" / "est.parquet"
    err = _refused(capsys, check_output_writable, target)
    assert str(target) in err and f"{blocker} is not a folder" in err
    err = _refused(capsys, check_output_writable, blocker / "ds", folder=True)
    assert str(blocker / "ds") in err and "output folder" in err


def test_output_of_the_wrong_kind_is_refused(tmp_path, capsys):
    f = tmp_path / "file.txt"
    f.write_text("x")
    assert str(f) in _refused(capsys, check_output_writable, f, folder=True)
    assert "is not a file" in _refused(capsys, check_output_writable, tmp_path)


@pytest.mark.skipif(not HAS_PROC, reason="needs Linux /proc")
def test_output_in_proc_is_refused_even_for_root(capsys):
    # /proc is a folder in which nobody, root included, can create a file
    err = _refused(capsys, check_output_writable, Path("/proc/terrainml_est.parquet"))
    assert "/proc/terrainml_est.parquet" in err and "cannot write" in err


@pytest.mark.skipif(IS_ROOT, reason="root ignores permission bits")
def test_read_only_folder_is_refused(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(stat.S_IRUSR | stat.S_IXUSR)
    try:
        err = _refused(capsys, check_output_writable, ro / "est.parquet")
        assert str(ro / "est.parquet") in err
        assert str(ro) in _refused(capsys, check_output_writable, ro, folder=True)
    finally:
        ro.chmod(stat.S_IRWXU)


def test_read_only_folder_is_refused_as_root_too(tmp_path, capsys, monkeypatch):
    # what a read-only folder answers to a non-root user (EACCES), simulated because root ignores
    # the permission bits; the chmod test above checks the real thing when not run as root
    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(common.tempfile, "TemporaryFile", denied)
    err = _refused(capsys, check_output_writable, tmp_path / "sub" / "est.parquet")
    assert f"{tmp_path / 'sub' / 'est.parquet'}: cannot write the output file in {tmp_path}" in err
    assert "Permission denied" in err
    assert "Permission denied" in _refused(capsys, check_output_writable, tmp_path, folder=True)


# ----------------------------------------------------------------- --n-jobs
@pytest.mark.parametrize("n", [1, 2, 64, -1])
def test_n_jobs_accepted(n):
    assert check_n_jobs(n) == n


@pytest.mark.parametrize("n", [0, -2, -100])
def test_n_jobs_refused(n, capsys):
    err = _refused(capsys, check_n_jobs, n, "--jobs")
    assert "--jobs" in err and f"got {n}" in err and "-1 for all cores" in err


# ----------------------------------------------------------------- inputs
def test_open_run_reads_a_run_parquet(tmp_path):
    run = kinematic_run(duration_s=1.0)
    path = write_run_parquet(run, tmp_path / "run.parquet")
    table = open_run(path)
    assert len(table) == len(run) and "wheel1_omega_radps" in table.columns


@pytest.mark.parametrize("name,content", [
    ("missing.parquet", None),
    ("junk.parquet", b"not parquet at all"),
    ("junk.mcap", os.urandom(512)),
    ("junk.csv", b"a,b\n1,2\n"),
])
def test_open_run_refuses_unusable_inputs_naming_them(tmp_path, capsys, name, content):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    assert str(path) in _refused(capsys, open_run, path)


def test_open_run_refuses_a_folder(tmp_path, capsys):
    assert f"{tmp_path}: not a file" in _refused(capsys, open_run, tmp_path)


def test_open_robot_refuses_a_missing_spec(tmp_path, capsys):
    assert open_robot("husky").name == "husky"
    assert "nope.yaml" in _refused(capsys, open_robot, str(tmp_path / "nope.yaml"))


def test_open_dataset_refuses_a_run_table(tmp_path, capsys):
    path = write_run_parquet(kinematic_run(duration_s=1.0), tmp_path / "run.parquet")
    assert not is_windows_file(path) and not is_windows_file(tmp_path / "missing.parquet")
    err = _refused(capsys, open_dataset, path)
    assert str(path) in err and "not a terrainml windows file" in err


# ----------------------------------------------------------------- commands check outputs first
# Each command is given an output below a regular file (unwritable for root too) and must refuse
# it, naming it, before its long work starts: the work function is replaced by a recorder.
def _blocked(tmp_path: Path) -> Path:
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, not a folder")
    return blocker


def _invoke(args: list[str]):
    from typer.testing import CliRunner

    from terrainml.cli import app

    return CliRunner().invoke(app, args)


def _refused_cli(args: list[str], *named: object) -> str:
    r = _invoke(args)
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output and r.output.startswith("error: ")
    for n in named:
        assert str(n) in r.output, r.output
    return r.output


@pytest.fixture
def never_reached(monkeypatch):
    """``never_reached(module, name)`` swaps a command's long work for a recorder; the
    test fails if the command reached it instead of refusing first."""
    calls = []

    def stub(module, name: str) -> None:
        monkeypatch.setattr(module, name, lambda *a, **k: calls.append(name))

    yield stub
    assert calls == [], f"the command reached {calls} before refusing"


@pytest.fixture
def run_parquet(tmp_path) -> Path:
    return write_run_parquet(kinematic_run(duration_s=1.0), tmp_path / "run.parquet")


def test_ingest_refuses_an_unwritable_output_before_reading(tmp_path, run_parquet, never_reached):
    import terrainml.io.ingest as ingest_mod

    never_reached(ingest_mod, "ingest_to_parquet")
    out = _blocked(tmp_path) / "run.parquet"
    _refused_cli(["ingest", str(run_parquet), "--out", str(out)], out, "is not a folder")


def test_train_refuses_an_unwritable_output_folder_before_loading_data(tmp_path, run_parquet, never_reached):
    import terrainml.commands.train_cmd as train_cmd

    never_reached(train_cmd, "load_data")
    out = _blocked(tmp_path) / "runs" / "svm"
    _refused_cli(["train", "--data", str(tmp_path), "--out", str(out)], out, "output folder")
    _refused_cli(["train", "--data", str(tmp_path), "--out", str(tmp_path / "ok"), "--n-jobs", "0"], "--n-jobs")


def test_evaluate_refuses_an_unwritable_output_before_reading_the_model(tmp_path, never_reached):
    # today's failure: a traceback after all the work; now a refusal before the manifest is read
    import terrainml.models.artifacts as artifacts_mod

    never_reached(artifacts_mod, "read_manifest")
    out = _blocked(tmp_path) / "eval.json"
    _refused_cli(["evaluate", str(tmp_path / "runs" / "svm"), "--data", str(tmp_path), "--out", str(out)],
                 out, "is not a folder")
    _refused_cli(["evaluate", str(tmp_path / "runs" / "svm"), "--data", str(tmp_path), "-j", "-3"], "got -3")


def test_dataset_build_refuses_an_unwritable_output_before_building(tmp_path, never_reached):
    import terrainml.commands.dataset_cmds as dataset_cmds

    never_reached(dataset_cmds, "build_with_progress")
    out = _blocked(tmp_path) / "windows.parquet"
    _refused_cli(["dataset", "build", str(tmp_path), "--out", str(out)], out, "is not a folder")
    _refused_cli(["dataset", "build", str(tmp_path), "--out", str(tmp_path / "w.parquet"), "-j", "0"], "--n-jobs")


def test_evaluate_protocol_refuses_bad_robot_jobs_and_output_before_reading(tmp_path, never_reached):
    import terrainml.experiments.borealtc as borealtc_mod

    never_reached(borealtc_mod, "load_protocol_data")
    out = _blocked(tmp_path) / "r.json"
    _refused_cli(["evaluate-protocol", str(tmp_path), "--json", str(out)], out, "is not a folder")
    _refused_cli(["evaluate-protocol", str(tmp_path), "-j", "0"], "--n-jobs")
    _refused_cli(["evaluate-protocol", str(tmp_path), "--robot", str(tmp_path / "nope.yaml")], "nope.yaml")


def test_dataset_show_refuses_a_run_table_naming_it(run_parquet):
    _refused_cli(["dataset", "show", str(run_parquet)], run_parquet, "not a terrainml windows file")


# ----------------------------------------------------------------- damage reaches dataset build
def test_dataset_build_per_run_status_and_summary_carry_damage(tmp_path):
    """A log with bad cells is kept (its windows are usable) but its status says what it lost."""
    from synthetic_runs import make_run_table
    from terrainml.pipeline.dataset import build_dataset

    logs = tmp_path / "logs"
    logs.mkdir()
    make_run_table(0, "clean", 1, duration_s=6.0).to_csv(logs / "clean.csv", index=False)
    damaged = make_run_table(2, "damaged", 2, duration_s=6.0).astype(object)
    damaged.loc[100, "wheel1_omega_radps"] = "abc"   # unparseable
    damaged.loc[200, "imu_ax_mps2"] = "inf"          # non-finite
    damaged.loc[201, "imu_ax_mps2"] = "n/a"          # unparseable
    damaged.to_csv(logs / "damaged.csv", index=False)

    ds = build_dataset(logs, "agrimaro")
    runs = ds.runs.set_index("source")
    assert runs.loc["clean.csv", "status"] == "ok" and runs.loc["clean.csv", "message"] == ""
    assert runs.loc["damaged.csv", "status"] == "damaged"
    msg = runs.loc["damaged.csv", "message"]
    assert "3 bad cell(s)" in msg and "imu_ax_mps2 2" in msg and "wheel1_omega_radps 1" in msg
    assert runs.loc["damaged.csv", "n_kept"] > 0   # still used: damage is said, not fatal

    out = tmp_path / "w.parquet"
    r = _invoke(["dataset", "build", str(logs), "--out", str(out)])
    assert r.exit_code == 0, r.output
    text = " ".join(r.output.split())
    assert "warning: damaged.csv: damaged: 3 bad cell(s)" in text
    assert "clean.csv:" not in text   # a clean log gets no warning
    assert "from 2 logs (1 damaged)" in text and is_windows_file(out)
