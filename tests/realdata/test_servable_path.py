"""BorealTC through the servable path: window specs, per-class report, sensor subsets,
models saved as verified artifacts, classes matched by name, and a served course of held-out runs.
"""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from terrainml.experiments.borealtc import course_runs, course_score, make_course
from terrainml.features.windows import window_spec
from terrainml.lookup.table import DesiredSlipTable
from terrainml.models.artifacts import load_artifact, write_manifest
from terrainml.pipeline.dataset import build_from_tables
from terrainml.pipeline.evaluate import ClassMismatchError, evaluate
from terrainml.pipeline.train_options import TrainOptions
from terrainml.pipeline.train import train
from terrainml.robot import load_robot
from terrainml.stream.tick.classify import ModelLoadError, load_serving_model
from terrainml.stream.tick.predictor import Predictor

pytestmark = pytest.mark.acceptance  # BorealTC builds and serves: `make test-all`

HUSKY = load_robot("husky")
NAMES = ["ASPHALT", "FLOORING", "ICE", "SANDY_LOAM", "SNOW"]


def _wheel_spec(**kw):
    return window_spec("chunks", **kw).resolve(HUSKY, ["wheels", "currents"])


def test_chunks_spec_gives_the_protocols_windows_and_keeps_every_class(boreal_tables, boreal_windows):
    tables, _ = boreal_tables
    _, W = boreal_windows  # experiments.borealtc: 5 s chunks, 1.7 s windows, 6 per chunk
    ds = build_from_tables(tables, HUSKY, spec=window_spec("chunks", windows_per_chunk=6))
    assert ds.class_names == NAMES
    assert np.array_equal(ds.windows.X, W.X) and np.array_equal(ds.windows.y, W.meta["terrain"].to_numpy())
    rep = ds.class_report.set_index("class")
    assert list(rep.index) == NAMES and (rep["kept"] > 0).all()
    # runs without IMU file lose their chunks to channel_valid, and the hint says what to do
    assert rep.loc["ICE", "channel_valid"] > 0 and "--sensors wheels,currents" in rep.loc["ICE", "hint"]


def test_steady_rules_report_the_classes_they_starve(boreal_tables):
    tables, _ = boreal_tables
    short = {}
    for t in tables:  # the two shortest runs of each class: enough to see the loss, fast
        short.setdefault(int(t["terrain"].iloc[0]), []).append(t)
    pick = [t for c in sorted(short) for t in sorted(short[c], key=len)[:2]]
    ds = build_from_tables(pick, HUSKY, spec=window_spec("steady"))
    rep = ds.class_report
    assert len(rep) == 5
    starved = rep[rep["kept_share"] < 0.5]
    assert len(starved) >= 1  # the steady rules throw most real data away
    for row in starved.itertuples(index=False):
        assert "most rejected by" in row.hint and "--windows" in row.hint or "--sensors" in row.hint


@pytest.fixture(scope="module")
def wheel_model(boreal_tables, tmp_path_factory):
    """hgb + svm+hgb on wheels and currents, 3 runs per class (one class with a single run)."""
    tables, _ = boreal_tables
    by = {}
    for t in tables:
        by.setdefault(int(t["terrain"].iloc[0]), []).append(t)
    pick = [t for c in sorted(by) for t in by[c][: (1 if c == 3 else 3)]]
    ds = build_from_tables(pick, HUSKY, spec=_wheel_spec(windows_per_chunk=2))
    out = tmp_path_factory.mktemp("m") / "wheel"
    res = train(ds, out, ["hgb", "svm+hgb"], TrainOptions(
        folds=2, seed=0, model_params={"hgb": {"max_iter": 30}, "svm": {"C_grid": (10.0,), "gamma_grid": ("scale",)}}))
    return out, ds, res


def test_train_saves_every_model_with_its_sensors_and_names_a_single_run_class(wheel_model):
    out, ds, res = wheel_model
    doc = json.loads((out / "manifest.json").read_text())
    assert doc["sensors"] == ["wheels", "currents"] and doc["feature_family"] == "side_channel"
    assert doc["class_names"] == NAMES
    assert set(doc["models"]) == {"hgb", "svm+hgb", "svm"}
    assert doc["models"]["svm+hgb"] == {"kind": "average", "files": [], "members": ["svm", "hgb"]}
    report = json.loads((out / "report.json").read_text())
    assert [e["class"] for e in report["excluded_classes"]] == ["SANDY_LOAM"]
    assert np.isfinite(report["balanced_accuracy"])
    # the CV left SANDY_LOAM out; the final models know all five classes
    assert res.models["hgb"]["cv"].class_names == ["ASPHALT", "FLOORING", "ICE", "SNOW"]
    for name in ("hgb", "svm+hgb"):
        art = load_artifact(out, name)
        assert art.class_names == NAMES and list(art.model.classes_) == [0, 1, 2, 3, 4]
        p = art.model.predict_proba(ds.windows.subset([0, 1]))
        assert p.shape == (2, 5) and np.allclose(p.sum(axis=1), 1.0)
    # BorealTC's catalogue table is stored, rows by the model's class names
    table = DesiredSlipTable.from_json((out / "desired_slip_table.json").read_text(), robot=HUSKY)
    assert list(table.class_names) == NAMES
    # adjacent-class accuracy is not reported for an unordered class set
    assert not np.isfinite(res.models["hgb"]["cv"].pooled["adjacent_accuracy"])


def test_evaluate_matches_classes_by_name_and_refuses_a_mismatch(wheel_model):
    out, ds, _ = wheel_model
    m = evaluate(out, ds)
    assert m["n_windows"] == len(ds.windows)
    ds.windows.attrs["all_class_names"] = ["CONCRETE", *NAMES[1:]]
    try:
        with pytest.raises(ClassMismatchError) as err:
            evaluate(out, ds)
        msg = str(err.value)
        assert "CONCRETE" in msg and "ASPHALT" in msg and "--class-map" in msg
        mapped = evaluate(out, ds, class_map={"CONCRETE": "ASPHALT"})
        assert mapped["balanced_accuracy"] == pytest.approx(m["balanced_accuracy"])
    finally:
        ds.windows.attrs["all_class_names"] = NAMES


def test_serving_refuses_a_table_of_other_classes(wheel_model, tmp_path):
    out, _, _ = wheel_model
    served = load_serving_model(out)
    assert served.class_names == NAMES and served.sensors == ["wheels", "currents"]
    bad = tmp_path / "bad"
    shutil.copytree(out, bad)
    (bad / "desired_slip_table.json").write_text(DesiredSlipTable.build(HUSKY).to_json() + "\n")
    write_manifest(bad)  # a consistent folder, but its table is the reference robot's classes
    with pytest.raises(ModelLoadError, match="not the model's"):
        load_serving_model(bad)


def test_predict_serves_a_borealtc_csv_without_imu_through_its_dataset_spec(wheel_model, tmp_path):
    """`predict --source pro_XX.csv --format borealtc`: the spec's units and sides, no IMU file."""
    from typer.testing import CliRunner

    from terrainml.cli import app

    out, _, _ = wheel_model
    boreal = Path(__file__).resolve().parents[2].parent / "shared" / "datasets" / "borealtc"
    run = tmp_path / "SANDY_LOAM" / "pro_00.csv"  # 9.4 s; its imu_00.csv left behind
    run.parent.mkdir()
    shutil.copy(boreal / "SANDY_LOAM" / "pro_00.csv", run)
    res = CliRunner().invoke(app, ["predict", "--model", str(out), "--source", str(run), "--format", "borealtc",
                                   "--sink", "stdout"])
    assert res.exit_code == 0, res.output
    msgs = [json.loads(line) for line in res.stdout.splitlines() if line.startswith("{")]
    assert len(msgs) > 800  # one per 10 ms tick of the run's ~9.4 s
    assert not any(m["fallback_reason"] == "estimator_unhealthy" for m in msgs)
    assert {m["terrain_name"] for m in msgs} <= {*NAMES, "none"}
    assert any(m["terrain_name"] != "none" for m in msgs)  # it classifies


_LAST_RUNS_COURSE = pytest.mark.xfail(strict=True, reason=(
    "a hard course outside the rotation of benchmarks/bench_course_sweep.py (k = 0..6): "
    "the last run of every class (ASPHALT_06, FLOORING_09, ICE_12, SANDY_LOAM_13, SNOW_26, 30 s "
    "each) is served the labelled class on 36% of moving ticks (ASPHALT 60%, FLOORING 90%, ICE "
    "0%, SNOW 0%; SANDY_LOAM_13's segment turns in place below 0.2 m/s). The served class is the "
    "offline model's (online probabilities equal the offline classifier's, max difference 0.0); "
    "ICE_12 is driven at 0.79 m/s, faster than any other ICE run, and scores 0% offline even with "
    "the other 70 runs in training (with the IMU too: the course scores 68.7%). Offline ceiling "
    "of wheels+currents: run-grouped 5-fold CV on all 71 runs, hgb, balanced accuracy 74.8%."))


@pytest.mark.parametrize("k", [0, pytest.param(-1, marks=_LAST_RUNS_COURSE)],
                         ids=["first-run-of-each-class", "last-run-of-each-class"])
def test_a_course_of_held_out_runs_without_imu_is_served(boreal_tables, tmp_path, k):
    """Wheels-and-currents model, trained without the course's runs, serves their classes.

    The course holds out the k-th run (by id) of every class. Over the whole rotation
    k = 0..6 (benchmarks/bench_course_sweep.py, BENCHMARKS.md "Real robots") the served share is
    82.3% of 53,155 moving ticks (4 of 7 courses >= 80% alone); k = 0 is its first course."""
    tables, rep = boreal_tables
    held = course_runs(tables, k)
    ds = build_from_tables([t for t in tables if str(t["run_id"].iloc[0]) not in held], HUSKY,
                           spec=_wheel_spec())
    train(ds, tmp_path / "m", ["hgb"], TrainOptions(folds=2, seed=0, ablation=False))
    course = make_course(tables, held, segment_s=30.0)
    assert not any(c.startswith("imu_") for c in course.columns)
    p = Predictor.from_model_dir(tmp_path / "m")
    assert "imu" not in p.health.monitored
    cols = list(course.columns)
    served = [p.step(dict(zip(cols, row))).to_dict() for row in course.itertuples(index=False)]
    assert all(len(m["class_probabilities"]) == 5 for m in served)
    score = course_score(course, served, rep.classes, HUSKY)
    assert score["estimator_unhealthy"] == 0, score
    assert score["share"] >= 0.8, score


def test_a_model_on_all_sensors_serves_a_course_without_imu_through_its_member(boreal_tables, tmp_path):
    """A course of held-out runs with the IMU file dropped, served by a model
    trained on every sensor (the chunks spec and hgb, as default ``train`` chooses on BorealTC),
    is served by its ``no_imu`` member (trained by :func:`train_members` as ``train`` does):
    >= 80% of moving ticks right (course_score leaves out 3 s after each label change)."""
    from terrainml.pipeline.members import train_members

    tables, rep = boreal_tables
    held = course_runs(tables, 0)
    kept = [t for t in tables if str(t["run_id"].iloc[0]) not in held]
    spec = window_spec("chunks").resolve(HUSKY)
    ds = build_from_tables(kept, HUSKY, spec=spec)
    assert "imu" in ds.sensors
    out = tmp_path / "all"
    options = TrainOptions(folds=2, seed=0, ablation=False)
    train(ds, out, ["hgb"], options)

    def fit(subset, folder):
        train(build_from_tables(kept, HUSKY, spec=window_spec("chunks").resolve(HUSKY, subset)), folder,
              ["hgb"], options)

    assert "no_imu" in train_members(out, ds.sensors, fit)
    course = make_course(tables, held, segment_s=30.0)
    assert not any(c.startswith("imu_") for c in course.columns)   # the IMU file left out
    p = Predictor.from_model_dir(out)
    cols = list(course.columns)
    served = [p.step(dict(zip(cols, row))).to_dict() for row in course.itertuples(index=False)]
    moving = [m for m in served if m["terrain_name"] != "none"]
    assert moving and all(m["sensors"] == ["wheels", "currents"] for m in moving)   # the member served
    score = course_score(course, served, rep.classes, HUSKY)
    assert score["share"] >= 0.8, score
