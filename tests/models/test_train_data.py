"""``terrainml train`` on awkward data: refusals come before the long work, a class with a single
run and class names no catalogue knows are data (trained, saved, served), the named model and
windows are fitted without selection, and the model folder appears whole.

Tiny synthetic logs (tests/synthetic_runs.py: the true class of every window is known by
construction) go through the real ingest, EKF, training and served replay.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from terrainml.schema import write_run_parquet

from synthetic_runs import make_run_table

#: our names of the synthetic classes 0, 2, 6 (ids = positions in the reference's eight)
OWN_NAMES = ["B0", "x1", "B2", "x3", "x4", "x5", "B6"]
FAST = ["--robot", "agrimaro", "--windows", "short", "--model", "svm", "--folds", "3", "--replay-s", "6",
        "--no-ablation", "-q"]


@pytest.fixture(autouse=True)
def small_svm(monkeypatch):
    """One point of the SVM grid and a small feature selector: these tests check what train does
    with the data, not the model's accuracy (seconds, not minutes)."""
    import terrainml.pipeline.train as train_lib

    real = train_lib.make_factory

    def small(kind, ds, seed=0, subset="all", n_jobs=1, params=None):
        extra = {"C_grid": (10.0,), "gamma_grid": ("scale",), "selector_trees": 50} if kind == "svm" else {}
        return real(kind, ds, seed, subset, n_jobs, {**extra, **(params or {})})

    monkeypatch.setattr(train_lib, "make_factory", small)


def _logs(folder: Path, runs: dict[int, int], names=None, seed: int = 3, duration_s: float = 12.0) -> Path:
    """``runs[c]`` runs of class ``c``; ``names``: the class names the logs carry (None: ours)."""
    folder.mkdir(parents=True, exist_ok=True)
    k = 0
    for c, n in runs.items():
        for r in range(n):
            rid = f"c{c}_r{r}"
            write_run_parquet(make_run_table(c, rid, seed * 100 + k, duration_s=duration_s), folder / f"{rid}.parquet",
                              metadata={"classes": names} if names else None)
            k += 1
    return folder


def _train(args):
    from terrainml.cli import app

    return CliRunner().invoke(app, ["train", *args])


def _no_long_work(monkeypatch):
    """Cutting windows or fitting a model is the long work: a refusal must come before either."""
    import terrainml.pipeline.dataset as dataset
    import terrainml.pipeline.train as train_lib

    def boom(*a, **k):
        raise AssertionError("long work started before the refusal")

    monkeypatch.setattr(dataset, "_from_tables", boom)
    monkeypatch.setattr(train_lib, "make_factory", boom)


@pytest.mark.parametrize("extra", [["--windows", "short", "--model", "svm"], []], ids=["fixed", "default"])
def test_a_single_class_is_refused_before_any_window_is_cut(tmp_path, monkeypatch, extra):
    logs = _logs(tmp_path / "logs", {0: 3})
    _no_long_work(monkeypatch)
    r = _train(["--data", str(logs), "--robot", "agrimaro", *extra, "--out", str(tmp_path / "m"), "-q"])
    assert r.exit_code == 2, r.output
    assert "at least 2 classes with >= 2 runs" in r.output and "'pavement': 3" in r.output
    assert "Traceback" not in r.output and not (tmp_path / "m").exists()
    assert not list(tmp_path.glob(".m.partial-*"))


def test_a_catalogue_without_the_classes_is_refused_before_any_window_is_cut(tmp_path, monkeypatch):
    logs = _logs(tmp_path / "logs", {0: 2, 2: 2})
    _no_long_work(monkeypatch)
    r = _train(["--data", str(logs), *FAST, "--catalogue", "borealtc", "--out", str(tmp_path / "m")])
    assert r.exit_code == 2, r.output
    assert "--catalogue borealtc" in r.output and "pavement" in r.output


def test_a_class_with_one_run_trains_saves_and_serves_and_the_report_names_the_rule(tmp_path, monkeypatch):
    import terrainml.pipeline.select as select_mod
    from terrainml.pipeline.replay import make_course, replay_course
    from terrainml.schema import read_run_parquet
    from terrainml.stream.tick.classify import load_serving_model

    def no_selection(*a, **k):
        raise AssertionError("the named model and windows went through the selection")

    monkeypatch.setattr(select_mod, "select", no_selection)
    logs = _logs(tmp_path / "logs", {0: 3, 2: 3, 6: 1})
    out = tmp_path / "m"
    r = _train(["--data", str(logs), *FAST, "--no-members", "--out", str(out)])
    assert r.exit_code == 0, r.output
    rep = json.loads((out / "report.json").read_text())
    assert [e["class"] for e in rep["excluded_classes"]] == ["dry_sand"]
    assert "trained on, not scored" in rep["preflight"]["rules"]["dry_sand"]
    assert "`dry_sand`: 1 run: trained on, not scored" in (out / "report.md").read_text()
    # grouped CV and the served replay of every fold's held-out runs, none of them the single run
    folds = rep["replay"]["folds"]
    assert len(folds) == 3 and rep["replay"]["pooled"]["moving_ticks"] > 500 and rep["replay"]["refusal"] == ""
    assert sum(f["runs"] for f in folds) == 6
    # the final model knows the class and serves it on its run
    assert json.loads((out / "manifest.json").read_text())["classes"] == [0, 2, 6]
    served = load_serving_model(out)
    assert 6 in [int(c) for c in served.classifier.model.classes_]
    course = make_course([read_run_parquet(logs / "c6_r0.parquet")], segment_s=None)
    res = replay_course(out, course)
    assert res["moving_ticks"] > 500 and res["right_share"] > 0.5, res


def test_class_names_no_catalogue_knows_train_and_serve_the_class_free_safe_cap_flagged(tmp_path):
    from terrainml.lookup.table import CLASS_FREE_DETAIL, ClassFreeTargets, DesiredSlipTable
    from terrainml.robot import load_robot
    from terrainml.schema import read_run_parquet
    from terrainml.stream.tick.predictor import Predictor

    logs = _logs(tmp_path / "logs", {0: 2, 2: 2, 6: 2}, names=OWN_NAMES)
    out = tmp_path / "m"
    r = _train(["--data", str(logs), *FAST, "--no-members", "--folds", "2", "--out", str(out)])
    assert r.exit_code == 0, r.output
    rep = json.loads((out / "report.json").read_text())
    assert rep["preflight"]["class_free"] is True and "class-free safe cap" in rep["preflight"]["desired_slip"]
    assert "Desired slip: no terrain parameters" in (out / "report.md").read_text()
    assert not (out / "desired_slip_table.json").exists()
    # the independent figure: the largest traction target of the reference catalogue's classes
    robot = load_robot("agrimaro")
    cap = max(row.traction for row in DesiredSlipTable.build(robot).rows)
    p = Predictor.from_model_dir(out)
    assert isinstance(p.table, ClassFreeTargets)
    served = []
    for row in read_run_parquet(logs / "c2_r1.parquet").to_dict("records"):
        msg = p.step(row)
        if msg is not None and not msg.fallback:
            served.append(msg)
    p.close()
    assert len(served) > 100 and {m.terrain_name for m in served} >= {"B2"}
    assert all(m.fallback_detail == CLASS_FREE_DETAIL for m in served)
    moving = [m for m in served if "traction" in m.wheel_state or "steady" in m.wheel_state]
    assert moving and all(np.isclose(abs(s), cap) for m in moving for s, st in zip(m.slip_desired, m.wheel_state)
                          if st in ("steady", "traction"))


def test_the_model_folder_appears_whole_and_a_refusal_leaves_its_report_beside_it(tmp_path, monkeypatch):
    import terrainml.pipeline.members as members_mod
    import terrainml.pipeline.train as train_lib

    logs = _logs(tmp_path / "logs", {0: 2, 2: 2})
    out = tmp_path / "m"
    seen = {}
    real = members_mod.train_members

    def spy(folder, *a, **k):  # the model is saved, its members not yet: --out must not exist
        seen["out_exists"] = out.exists()
        seen["staged"] = [p.name for p in tmp_path.glob(".m.partial-*")]
        return real(folder, *a, **k)

    monkeypatch.setattr(members_mod, "train_members", spy)
    r = _train(["--data", str(logs), *FAST, "--folds", "2", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert seen["out_exists"] is False and len(seen["staged"]) == 1
    assert (out / "manifest.json").exists() and not list(tmp_path.glob(".m.*"))
    assert json.loads((out / "manifest.json").read_text()).get("sensor_members")
    # a refused model: --out keeps the earlier model, the report goes to m.refused
    monkeypatch.setattr(train_lib, "replay_refusal", lambda pooled, share: "forced refusal")
    before = (out / "manifest.json").read_text()
    r = _train(["--data", str(logs), *FAST, "--no-members", "--folds", "2", "--out", str(out)])
    assert r.exit_code == 2 and "forced refusal" in r.output
    refused = tmp_path / "m.refused"
    assert str(refused / "report.md") in r.output.replace("\n", "")
    assert "**Refused:** forced refusal" in (refused / "report.md").read_text()
    assert not (refused / "manifest.json").exists()
    assert (out / "manifest.json").read_text() == before and not list(tmp_path.glob(".m.*"))
