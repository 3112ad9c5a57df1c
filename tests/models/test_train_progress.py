"""``train`` is never silent: typed progress per stage, plain lines off a terminal; fits on Dask.

The CLI runs here under CliRunner, which is not a terminal, so the reporter writes plain lines:
one when a stage starts, then per unit done (at most one a second) and always the last ``n/n``.
"""

from __future__ import annotations

import io
import json
import os
import re

import pytest
from rich.console import Console
from typer.testing import CliRunner

from logs_synth import write_logs

SEL = re.compile(r"^train: selection (\d+)/(\d+) fits")
#: small models (one SVM grid point, few trees): the selection's logic at a fraction of the cost
SMALL = {"svm": {"C_grid": (10.0,), "gamma_grid": ("scale",), "selector_trees": 40}, "hgb": {"max_iter": 40}}


@pytest.fixture(scope="module")
def small_models():
    """Small models, and one OpenMP thread (the trees' threads spin on a loaded machine)."""
    from threadpoolctl import threadpool_limits

    from terrainml.pipeline import train as train_mod

    real = train_mod.make_factory
    with pytest.MonkeyPatch.context() as mp, threadpool_limits(1):
        mp.setattr(train_mod, "make_factory",
                   lambda kind, ds, seed=0, subset="all", n_jobs=1, params=None:
                   real(kind, ds, seed, subset, n_jobs, {**SMALL.get(kind, {}), **(params or {})}))
        yield


@pytest.fixture(scope="module")
def windows_file(tmp_path_factory):
    from terrainml.cli import app

    tmp = tmp_path_factory.mktemp("progress")
    logs = write_logs(tmp / "logs", runs_per_class=3, seed=5)
    w = tmp / "w.parquet"
    r = CliRunner().invoke(app, ["dataset", "build", str(logs), "--robot", "agrimaro", "--out", str(w), "-q"])
    assert r.exit_code == 0, r.output
    return w


def _train(w, out, *extra):
    from terrainml.cli import app

    r = CliRunner().invoke(app, ["train", "--data", str(w), "--model", "auto", "--folds", "3", "--out", str(out),
                                 *extra])
    assert r.exit_code == 0, r.output
    return r.output.splitlines(), json.loads((out / "report.json").read_text())


@pytest.fixture(scope="module")
def plain_run(windows_file, small_models, tmp_path_factory):
    """``train`` with the defaults (no Dask) on the windows: (output lines, report.json)."""
    return _train(windows_file, tmp_path_factory.mktemp("plain") / "m")


def _stages(lines):
    """The stages in the order their first line appears."""
    out = []
    for ln in lines:
        m = re.match(r"^train: ([a-z -]+?) \d+/\d+", ln)
        if m and m.group(1) not in out:
            out.append(m.group(1))
    return out


def test_train_names_its_budget_first_and_counts_every_fit_to_n_of_n(plain_run):
    lines, rep = plain_run
    assert "time budget 30 min (--budget-min)" in lines[0] and "only the best spec" in lines[0]
    assert _stages(lines) == ["selection", "final fit"]
    counts = [tuple(map(int, m.groups())) for m in map(SEL.match, lines) if m]
    done, total = counts[-1]
    # the planned total is the fits the selection made (report.json, counted by the selection itself)
    assert done == total == rep["selection"]["timing_s"]["fits"] > 0
    assert [d for d, _ in counts] == sorted(d for d, _ in counts)
    assert any(f"final fit {n}/{n} models" in ln for ln in lines for n in (1, 2))


def test_single_spec_train_counts_its_cv_fits_per_stage(windows_file, small_models, tmp_path):
    from terrainml.cli import app

    r = CliRunner().invoke(app, ["train", "--data", str(windows_file), "--model", "hgb", "--folds", "3",
                                 "--out", str(tmp_path / "m")])
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert "no time budget" in lines[0]
    assert _stages(lines) == ["cross-validation", "final fit", "members"]
    assert any(ln.startswith("train: cross-validation 3/3 fits") for ln in lines)
    n = len(json.loads((tmp_path / "m" / "manifest.json").read_text()).get("sensor_members", []))
    assert n > 0 and any(ln.startswith(f"train: members {n}/{n} members") for ln in lines)


def test_reporter_lines_carry_rich_estimate_of_the_time_left():
    """Hand-worked: 2 fits in the 4 s between the samples at 4 s and 8 s -> 0.5 fit/s; 6 fits
    left -> 12 s. Lines come at most once a second within a stage, the last (n/n) always."""
    from terrainml.commands._progress import StageReporter
    from terrainml.pipeline.progress import Step

    now = [0.0]
    buf = io.StringIO()
    con = Console(file=buf, width=200)
    with StageReporter(con, clock=lambda: now[0]) as rep:
        rep(Step("selection", 0, 10, "fits"))
        now[0] = 4.0
        rep(Step("selection", 2, 10, "fits", "short/svm"))
        rep(Step("selection", 3, 10, "fits", "short/svm"))  # same second: no line
        now[0] = 8.0
        rep(Step("selection", 4, 10, "fits", "short/svm"))
        rep("warning: a class has one run")
        rep("a note for the live display only")
        now[0] = 8.5
        rep(Step("selection", 10, 10, "fits", "short/hgb"))
        rep(Step("final fit", 0, 1, "models", "hgb"))
    lines = buf.getvalue().splitlines()
    assert lines == ["train: selection 0/10 fits; 0:00:00 elapsed",
                     "train: selection 2/10 fits (short/svm); 0:00:04 elapsed",
                     "train: selection 4/10 fits (short/svm); 0:00:08 elapsed, about 0:00:12 left",
                     "warning: a class has one run",
                     "train: selection 10/10 fits (short/hgb); 0:00:08 elapsed",
                     "train: final fit 0/1 models (hgb); 0:00:00 elapsed"]


def test_train_on_a_dask_cluster_gives_the_same_selection(windows_file, plain_run, tmp_path):
    from distributed import LocalCluster

    plain = plain_run[1]
    with LocalCluster(n_workers=1, processes=False, threads_per_worker=2, dashboard_address=":0") as cluster:
        lines, dask = _train(windows_file, tmp_path / "dask", "--dask-address", cluster.scheduler_address,
                             "--budget-min", "45")
    assert "time budget 45 min" in lines[0]
    assert any("fits run on the Dask cluster" in ln and "2 thread(s)" in ln for ln in lines)
    for key in ("chosen", "nested_balanced_accuracy", "nested_balanced_accuracy_pooled"):
        assert dask[key] == plain[key]
    sel_p, sel_d = plain["selection"], dask["selection"]
    assert sel_d["candidates"] == sel_p["candidates"] and sel_d["outer"] == sel_p["outer"]
    assert sel_d["temperature"] == sel_p["temperature"]
    assert sel_d["timing_s"]["fits"] == sel_p["timing_s"]["fits"]


def test_workers_that_set_dasks_trim_threshold_are_named_with_the_setting_that_unsets_it():
    import dask
    from distributed import Client, LocalCluster

    from terrainml.pipeline.cluster import MALLOC_TRIM_VAR, worker_env_note

    def note_of_a_fresh_worker() -> str:
        with LocalCluster(n_workers=1, processes=True, threads_per_worker=1, dashboard_address=":0") as cluster, \
                Client(cluster) as client:
            return worker_env_note(client)

    before = os.environ.get(MALLOC_TRIM_VAR)
    try:
        with dask.config.set({f"distributed.nanny.pre-spawn-environ.{MALLOC_TRIM_VAR}": None}):
            assert note_of_a_fresh_worker() == ""
        # Dask's nanny sets it by default (in its own process too, so this case comes second)
        note = note_of_a_fresh_worker()
        assert note.startswith(f"note: 1 of 1 Dask workers run with {MALLOC_TRIM_VAR} set")
        assert f"distributed.nanny.pre-spawn-environ.{MALLOC_TRIM_VAR} set to null" in note
    finally:  # the processes this test process starts later keep glibc's default
        if before is None:
            os.environ.pop(MALLOC_TRIM_VAR, None)
        else:
            os.environ[MALLOC_TRIM_VAR] = before


def test_an_unreachable_scheduler_is_named(windows_file, tmp_path, monkeypatch):
    from terrainml.cli import app
    from terrainml.pipeline import cluster

    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 0.5)  # a refused connection is retried until then
    r = CliRunner().invoke(app, ["train", "--data", str(windows_file), "--model", "auto", "--folds", "3",
                                 "--out", str(tmp_path / "m"), "--dask-address", "tcp://127.0.0.1:9"])
    assert r.exit_code == 2 and "--dask-address" in r.output and "127.0.0.1:9" in r.output
    assert "Traceback" not in r.output and not (tmp_path / "m" / "manifest.json").exists()


@pytest.mark.acceptance
def test_train_from_logs_reports_every_stage_in_order(tmp_path, small_models):
    """From logs: logs, windows, selection, served replay, final fit, members (minutes)."""
    from terrainml.cli import app

    logs = write_logs(tmp_path / "logs", runs_per_class=3, seed=5)
    r = CliRunner().invoke(app, ["train", "--data", str(logs), "--robot", "agrimaro", "--windows", "short",
                                 "--model", "auto", "--folds", "3", "--replay-s", "8", "--out", str(tmp_path / "m")])
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert "--budget-min" in lines[0]
    assert _stages(lines) == ["logs", "windows", "selection", "served replay", "final fit", "members"]
    assert any(re.match(r"^train: members 3/3 members", ln) for ln in lines)  # no_imu, no_currents, no_cam
