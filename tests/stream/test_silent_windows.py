"""`predict` never goes silent: windows the rules reject while the robot moves are named.

The hand-made log is a Husky drive without the roll and pitch gyro rates; the model reads the
side channels, which include them (``imu_wx``, ``imu_wy``). Every tick is healthy (the IMU
group's required columns are there), yet no window can ever pass ``channel_valid``. The truth
of "within the set distance" is the log's own ground-truth position (``gt_x_m``).
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from terrainml.testing import kinematic_run, trapezoid_speed
from terrainml.features.side_channel import SideChannelFeatures, track_of
from terrainml.features.windows import SIDE_CHANNEL_NAMES, Windows, window_spec
from terrainml.models.artifacts import TrainingProvenance, save_artifact
from terrainml.models.trees import BoostedTrees
from terrainml.robot import load_robot
from terrainml.stream.tick.config import ServingConfig
from terrainml.stream.tick.predictor import Predictor
from terrainml.stream.transports.sources import iter_table_samples

HUSKY = load_robot("husky")
NAMES = ["ASPHALT", "SNOW"]
WARN_M = 5.0


@pytest.fixture(scope="module")
def side_model(tmp_path_factory):
    """A tiny side-channel model (hgb) on random windows of two 'classes' (mean current 2 A or 6 A)."""
    rng = np.random.default_rng(0)
    spec = replace(window_spec("chunks"), channels=SIDE_CHANNEL_NAMES)
    n, C, T = 40, len(SIDE_CHANNEL_NAMES), spec.n_samples
    X = rng.normal(0.0, 0.1, (n, C, T))
    y = np.repeat([0, 1], n // 2)
    cur = [SIDE_CHANNEL_NAMES.index(c) for c in ("current_left", "current_right")]
    X[:, cur, :] += np.where(y == 0, 2.0, 6.0)[:, None, None]
    meta = pd.DataFrame({"run_id": [f"r{k % 4}" for k in range(n)], "terrain": y,
                         "t_start_s": 0.0, "t_end_s": 1.7, "start_index": 0})
    W = Windows(X, SIDE_CHANNEL_NAMES, meta, spec.rate_hz)
    model = BoostedTrees(SideChannelFeatures(rate_hz=100.0, track_m=track_of(HUSKY)), random_state=0,
                         max_iter=10).fit(W, y)
    out = tmp_path_factory.mktemp("side") / "m"
    save_artifact(out, {"hgb": model}, TrainingProvenance(
        classes=[0, 1], class_names=NAMES, channels=SIDE_CHANNEL_NAMES, window_spec=spec, robot=HUSKY,
        training_fingerprint="test", sensors=["wheels", "currents", "imu"], feature_family="side_channel"))
    return out


def _drive(duration_s: float = 20.0):
    """A Husky at 1 m/s (0.5 s ramps), with the IMU's required columns but no roll/pitch rates."""
    table = kinematic_run(HUSKY, duration_s=duration_s, seed=3,
                          vx=lambda t: trapezoid_speed(t, 1.0, 0.5, 0.5), run_id="no_gyro_rp")
    assert "imu_roll_rate_radps" not in table.columns and "imu_pitch_rate_radps" not in table.columns
    return table


def test_windows_that_can_never_pass_fall_back_naming_the_channel_within_the_set_distance(side_model, caplog):
    table = _drive()
    pred = Predictor.from_model_dir(side_model, config=ServingConfig(warn_after_m=WARN_M))
    travelled = np.hypot(np.diff(table["gt_x_m"], prepend=table["gt_x_m"].iloc[0]),
                         np.diff(table["gt_y_m"], prepend=table["gt_y_m"].iloc[0])).cumsum()
    with caplog.at_level("WARNING", logger="terrainml.stream"):
        msgs = [pred.step(s) for s in iter_table_samples(table)]
    assert all(m is not None for m in msgs)
    assert not any(m.fallback_reason == "estimator_unhealthy" for m in msgs[100:])  # healthy drive
    rejected = [k for k, m in enumerate(msgs) if m.fallback_reason == "windows_rejected"]
    assert rejected, {m.fallback_reason for m in msgs}
    first = rejected[0]
    # within the set distance: by the log's truth, once 5 m are covered (plus one 0.5 s hop at 1 m/s)
    assert WARN_M - 0.3 <= travelled[first] <= WARN_M + 0.6, travelled[first]
    assert rejected == list(range(first, len(msgs)))  # it stays so: nothing is ever classified
    assert {m.fallback_detail for m in msgs[first:]} == {"channel_valid: imu_wx, imu_wy"}
    assert all(m.fallback and m.terrain_class == -1 for m in msgs[first:])
    assert all(m.fallback_detail == "" for m in msgs[:first])
    warnings = [r.getMessage() for r in caplog.records if "no classification" in r.getMessage()]
    assert len(warnings) == 1 and "channel_valid: imu_wx, imu_wy" in warnings[0], warnings
    st = pred.stats()
    assert st["classifications"] == 0 and st["rejections"]["channel_valid"] == st["unsteady_windows"] > 0
    assert st["rejected_channels"] == {"imu_wx": st["unsteady_windows"], "imu_wy": st["unsteady_windows"]}


def test_a_classified_window_ends_the_warning_stretch(side_model):
    """With the gyro rates logged, the same model classifies and never says windows_rejected."""
    table = _drive(12.0)
    table["imu_roll_rate_radps"] = 0.0
    table["imu_pitch_rate_radps"] = 0.0
    pred = Predictor.from_model_dir(side_model, config=ServingConfig(warn_after_m=WARN_M))
    msgs = [pred.step(s) for s in iter_table_samples(table)]
    assert pred.stats()["classifications"] > 0
    assert not any(m.fallback_reason == "windows_rejected" for m in msgs)


def test_predict_warns_on_stderr_and_counts_rejections_per_rule(side_model, tmp_path):
    log = tmp_path / "no_gyro_rp.parquet"
    _drive(12.0).to_parquet(log)
    res = subprocess.run([sys.executable, "-m", "terrainml.cli", "predict", "--model", str(side_model),
                          "--source", str(log), "--sink", "stdout"],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    msgs = [json.loads(line) for line in res.stdout.splitlines() if line.startswith("{")]
    assert msgs[-1]["fallback_reason"] == "windows_rejected"
    assert msgs[-1]["fallback_detail"] == "channel_valid: imu_wx, imu_wy"
    assert msgs[-1]["sensors"] == ["wheels", "currents", "imu"]
    err = res.stderr
    assert "WARNING no classification over" in err and "'channel_valid: imu_wx, imu_wy'" in err, err
    assert "windows rejected:" in err and "channel_valid" in err and "invalid channels: imu_wx" in err, err
