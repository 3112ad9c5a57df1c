"""train --windows auto --model auto (terrainml.pipeline.autotrain) and the served replay it runs."""

import json

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from logs_synth import write_logs
from terrainml.pipeline.replay import make_course, pooled_replay, replay_refusal
from terrainml.stream.app.scoring import score_served


def test_replay_score_of_a_hand_worked_course():
    # 200 ticks at 100 Hz driving at 1 m/s; class 0 then class 1 from tick 100; the predictor
    # serves 0 on the first 100 ticks, falls back for 50, then serves 1
    n = 200
    t = np.arange(n) * 0.01
    odo = np.arange(n) * 0.01
    lab = np.r_[np.zeros(100), np.ones(100)].astype(int)
    served = np.r_[np.zeros(100), -np.ones(50), np.ones(50)].astype(int)
    reasons = [""] * 100 + ["stale_classification"] * 50 + [""] * 50
    st = {"classifications": 40, "distance_m": float(odo[-1])}
    s = score_served(t, lab, served, odo, reasons, 0.3, st)
    assert s["moving_ticks"] == 199  # the first tick has no speed yet
    assert s["right_share"] == pytest.approx(149 / 199)
    assert s["fallback_share"] == pytest.approx(50 / 199)
    assert s["classified_share"] == pytest.approx(149 / 199)
    assert s["changes"] == 1 and s["changes_never_right"] == 0
    assert s["median_change_m"] == pytest.approx(0.5)  # from tick 100 to tick 150 at 0.01 m per tick
    # 0.3 s after the change left out: ticks 100-129 go, 20 fallback ticks remain of 169
    assert s["right_share_settled"] == pytest.approx(149 / 169)
    assert s["classifications_per_m"] == pytest.approx(40 / 1.99)
    assert s["fallback_reasons"] == {"stale_classification": 50}


def test_refusal_names_the_share_and_pooling_weights_by_ticks():
    assert "no moving" in replay_refusal({"moving_ticks": 0})
    why = replay_refusal({"moving_ticks": 1000, "classified_share": 0.3})
    assert "30%" in why and "1000 moving ticks" in why
    assert replay_refusal({"moving_ticks": 1000, "classified_share": 0.8}) == ""
    f = [{"moving_ticks": 100, "right_share": 1.0, "fallback_share": 0.0, "classified_share": 1.0,
          "classifications": 10, "distance_m": 5.0, "median_change_m": 1.0, "changes": 1, "changes_never_right": 0},
         {"moving_ticks": 300, "right_share": 0.5, "fallback_share": 0.5, "classified_share": 0.5,
          "classifications": 10, "distance_m": 15.0, "median_change_m": 3.0, "changes": 2, "changes_never_right": 1}]
    p = pooled_replay(f)
    assert p["right_share"] == pytest.approx((100 + 150) / 400) and p["classifications_per_m"] == pytest.approx(1.0)
    assert p["changes_never_right"] == 1


def _run(rid, cls, n=300, rate=100.0):
    df = pd.DataFrame({"t_s": np.arange(n) / rate + 7.0, "terrain": cls, "run_id": rid, "x": np.arange(n)})
    df.attrs["terrainml"] = {"rate_hz": rate}
    return df


def test_course_interleaves_classes_and_keeps_time_continuous():
    tables = [_run("a0", 0), _run("a1", 0), _run("b0", 1)]
    c = make_course(tables, segment_s=1.0, drop_columns=["x"])
    assert c["terrain"].tolist() == [0] * 100 + [1] * 100 + [0] * 100
    assert np.allclose(np.diff(c["t_s"]), 0.01) and "x" not in c.columns
    assert c["run_id"].unique().tolist() == ["course"]
    with pytest.raises(ValueError, match="zz"):
        make_course(tables, ["zz"])


@pytest.mark.acceptance
def test_cli_train_auto_selects_replays_and_saves_a_calibrated_model(tmp_path):
    from terrainml.cli import app
    from terrainml.models.calibration import CalibratedModel
    from terrainml.stream.tick.classify import load_serving_model

    logs = write_logs(tmp_path / "logs", runs_per_class=3, seed=5)
    out = tmp_path / "m"
    r = CliRunner().invoke(app, ["train", "--data", str(logs), "--robot", "agrimaro", "--windows", "short,state",
                                 "--model", "hgb", "--folds", "3", "--replay-s", "8", "--out", str(out), "-q"])
    assert r.exit_code == 0, r.output
    rep = json.loads((out / "report.json").read_text())
    assert rep["chosen"] == "short/hgb" and "state" in rep["selection"]["infeasible"]
    assert len(rep["replay"]["folds"]) == 3 and rep["replay"]["pooled"]["moving_ticks"] > 1000
    assert rep["replay"]["refusal"] == ""
    md = (out / "report.md").read_text()
    assert "nested CV" in md and "Served replay" in md and "ECE before" in md
    served = load_serving_model(out)
    assert isinstance(served.classifier.model, CalibratedModel)
    entry = json.loads((out / "manifest.json").read_text())["models"]["hgb"]
    assert entry["calibration"]["temperature"] == pytest.approx(rep["selection"]["temperature"])
    # the default path saves the served model's novelty score (threshold from its
    # training runs, one held out at a time),
    # so unknown ground is served unknown_terrain with no option given
    nov = json.loads((out / "manifest.json").read_text())["novelty"]
    assert nov["model"] == "hgb" and nov["threshold"] > 0
    assert served.classifier.novelty is not None
    # the sensor members: the chosen spec and model again without the IMU, without the
    # currents and without the camera, each validated like the model, listed in the manifest, served
    members = json.loads((out / "manifest.json").read_text()).get("sensor_members", [])
    assert members, "default train made no sensor member"
    for m in members:
        dropped = {"no_imu": "imu", "no_currents": "currents", "no_cam": "cam"}[m["name"]]
        assert dropped not in m["sensors"] and "wheels" in m["sensors"]
        chans = json.loads((out / m["path"] / "manifest.json").read_text())["channels"]
        # without the camera, the EKF's body velocity is another signal: no body channel either
        assert ("vx" in chans) == (m["name"] != "no_cam"), (m["name"], chans)
        mrep = json.loads((out / m["path"] / "report.json").read_text())
        assert mrep["chosen"] == "short/hgb" and mrep["replay"]["refusal"] == ""
    assert sorted(s.name for s in served.members) == sorted(m["name"] for m in members)
    assert all(s.classifier.novelty is not None for s in served.members)


@pytest.mark.acceptance  # 15 s on the quiet 2-core machine: four replays and two worker processes
def test_folds_replayed_in_parallel_give_the_serial_figures_in_fold_order(log_dir):
    from terrainml.io.ingest import load_run
    from terrainml.pipeline.dataset import build_from_tables, find_logs
    from terrainml.pipeline.fold_replay import replay_folds
    from terrainml.pipeline.train import fold_model, make_factory
    from terrainml.pipeline.train_options import ReplayOptions
    from terrainml.robot import load_robot

    robot = load_robot("agrimaro")
    tables = [load_run(p, robot=robot).table for p in find_logs(log_dir)]
    ds = build_from_tables(tables, robot)
    W = ds.windows
    runs = sorted(set(np.asarray(W.groups).astype(str)))
    folds = []
    for held in (runs[0::2], runs[1::2]):
        train = W.subset(np.flatnonzero(~np.isin(np.asarray(W.groups).astype(str), held)))
        model = make_factory("hgb", ds, 0, params={"max_iter": 20})().fit(train, train.y)
        folds.append(fold_model(ds, held, {"hgb": model}, "hgb", train, tables, ReplayOptions(segment_s=4.0), 0))
    notes1, notes2 = [], []
    serial = replay_folds(folds, None, 0, notes1.append, n_jobs=1)
    parallel = replay_folds(folds, None, 0, notes2.append, n_jobs=2)
    for a, b in zip(serial, parallel):
        assert {k: v for k, v in a.items() if k != "replay_s"} == {k: v for k, v in b.items() if k != "replay_s"}
    assert [f["fold"] for f in parallel] == [0, 1] and parallel[0]["moving_ticks"] > 0
    assert [n for n in notes1 if isinstance(n, str)] == [n for n in notes2 if isinstance(n, str)]
