"""Serving on the sensors that are there: a model with IMU carries a member without it.

Hand-made truth: two classes told apart by the motor current alone (2 A or 6 A on every wheel);
the model reads the side channels with the IMU, its member ``no_imu`` the wheel speeds and
currents only. A Husky log at 6 A must be served the 6 A class by whichever serves, and the
message must name the sensors used.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from terrainml.testing import kinematic_run, trapezoid_speed
from terrainml.features.side_channel import SideChannelFeatures, track_of
from terrainml.features.windows import SIDE_CHANNEL_NAMES, Windows, window_spec
from terrainml.models.artifacts import (ArtifactError, TrainingProvenance, attach_members, load_artifact,
                                        save_artifact)
from terrainml.models.trees import BoostedTrees
from terrainml.pipeline.members import train_members
from terrainml.pipeline.sensor_subsets import member_subsets
from terrainml.robot import CameraSpec, load_robot
from terrainml.stream.tick.classify import ModelLoadError, load_serving_model
from terrainml.stream.tick.predictor import Predictor
from terrainml.stream.transports.sources import iter_table_samples

HUSKY = load_robot("husky")
NAMES = ["ASPHALT", "SNOW"]  # BorealTC names: the borealtc catalogue gives their table
WHEEL_CHANNELS = ("current_left", "current_right", "speed_left_mps", "speed_right_mps")
IMU_COLUMNS = ("imu_ax_mps2", "imu_ay_mps2", "imu_az_mps2", "imu_yaw_rate_radps", "imu_yaw_rad",
               "imu_roll_rate_radps", "imu_pitch_rate_radps", "imu_valid")


def _windows(channels, seed=0, n=120):
    """Windows of two classes: currents 2 A or 6 A; every other channel broad noise (uninformative)."""
    rng = np.random.default_rng(seed)
    spec = replace(window_spec("chunks"), channels=tuple(channels))
    X = rng.normal(0.0, 1.0, (n, len(channels), spec.n_samples))
    y = np.repeat([0, 1], n // 2)
    for c in ("current_left", "current_right"):
        X[:, channels.index(c), :] = np.where(y == 0, 2.0, 6.0)[:, None] + rng.normal(0, 0.1, (n, spec.n_samples))
    for c in ("speed_left_mps", "speed_right_mps"):
        X[:, channels.index(c), :] = rng.uniform(0.0, 2.0, (n, 1)) + rng.normal(0, 0.02, (n, spec.n_samples))
    meta = pd.DataFrame({"run_id": [f"r{k % 6}" for k in range(n)], "terrain": y,
                         "t_start_s": 0.0, "t_end_s": 1.7, "start_index": 0})
    return Windows(X, tuple(channels), meta, spec.rate_hz), spec


def _save(folder, channels, sensors, seed=0, robot=HUSKY):
    W, spec = _windows(list(channels), seed)
    model = BoostedTrees(SideChannelFeatures(rate_hz=100.0, track_m=track_of(robot)), random_state=0,
                         max_iter=20).fit(W, W.y)
    save_artifact(folder, {"hgb": model}, TrainingProvenance(
                      classes=[0, 1], class_names=NAMES, channels=channels, window_spec=spec, robot=robot,
                      training_fingerprint="test", sensors=sensors, feature_family="side_channel"),
                  metrics_summary={"hgb": {"balanced_accuracy": {"mean": 0.9, "std": 0.0}}})


@pytest.fixture(scope="module")
def with_member(tmp_path_factory):
    out = tmp_path_factory.mktemp("members") / "m"
    _save(out, SIDE_CHANNEL_NAMES, ["wheels", "currents", "imu"])
    names = train_members(out, ["wheels", "currents", "imu"],
                          lambda subset, folder: _save(folder, WHEEL_CHANNELS, subset)
                          if "imu" not in subset else (_ for _ in ()).throw(ValueError("only no_imu here")))
    assert names == ["no_imu"]
    return out


def _save_or_refuse(subset, folder):
    """The ``no_imu`` member, saved; the ``no_currents`` member refused (a ValueError)."""
    if "currents" not in subset:
        raise ValueError("no window for this subset")
    _save(folder, WHEEL_CHANNELS, subset)


def test_members_trained_side_by_side_are_those_trained_one_at_a_time(tmp_path):
    sensors = ["wheels", "currents", "imu"]
    said = {1: [], 2: []}
    for n_jobs in (1, 2):
        out = tmp_path / f"m{n_jobs}"
        _save(out, SIDE_CHANNEL_NAMES, sensors)
        assert train_members(out, sensors, _save_or_refuse, progress=lambda m: said[n_jobs].append(str(m)),
                             n_jobs=n_jobs) == ["no_imu"]
        assert not (out / "members" / "no_currents").exists()
    one, two = (json.loads((tmp_path / f"m{k}" / "manifest.json").read_text()) for k in (1, 2))
    hashless = lambda doc: [{k: v for k, v in m.items() if k != "manifest_sha256"}  # noqa: E731
                            for m in doc["sensor_members"]]  # (saved files carry their save time)
    assert hashless(one) == hashless(two)
    W, _ = _windows(list(WHEEL_CHANNELS), seed=3)
    probs = [load_artifact(tmp_path / f"m{k}" / "members" / "no_imu").model.predict_proba(W) for k in (1, 2)]
    np.testing.assert_array_equal(*probs)
    for lines in said.values():
        assert "warning: member no_currents (wheels,imu) not trained: no window for this subset" in lines
        assert lines[-1] == "members 2/2 members (no_currents)"


def _drive(duration_s=15.0, current_a=6.0, imu=True, imu_gone_s=None, robot=HUSKY, cam_dropouts=()):
    table = kinematic_run(robot, duration_s=duration_s, seed=5, vx=lambda t: trapezoid_speed(t, 1.0, 0.5, 0.5),
                          run_id="drive", cam_dropouts=cam_dropouts)
    rng = np.random.default_rng(1)
    for i in range(1, 5):
        table[f"wheel{i}_current_a"] = current_a + rng.normal(0, 0.1, len(table))
    table["imu_roll_rate_radps"] = 0.0
    table["imu_pitch_rate_radps"] = 0.0
    if not imu:
        table = table.drop(columns=[c for c in IMU_COLUMNS if c in table.columns])
    elif imu_gone_s is not None:
        gone = table["t_s"].to_numpy() >= imu_gone_s
        table.loc[gone, "imu_valid"] = False
    return table


def _serve(folder, table):
    p = Predictor.from_model_dir(folder)
    return p, [p.step(s) for s in iter_table_samples(table)]


def test_member_subsets_drop_the_imu_the_currents_or_the_camera_and_keep_a_signature():
    assert member_subsets(["wheels", "currents", "imu"]) == {"no_imu": ["wheels", "currents"],
                                                              "no_currents": ["wheels", "imu"]}
    assert member_subsets(["wheels", "currents", "imu", "cam"]) == {
        "no_imu": ["wheels", "currents", "cam"], "no_currents": ["wheels", "imu", "cam"],
        "no_cam": ["wheels", "currents", "imu"]}
    assert member_subsets(["wheels", "currents"]) == {}  # wheel speeds alone: no member
    assert member_subsets(["wheels", "imu"]) == {}


def test_the_manifest_lists_the_member_and_hashes_its_files(with_member):
    doc = json.loads((with_member / "manifest.json").read_text())
    (entry,) = doc["sensor_members"]
    assert entry["name"] == "no_imu" and entry["sensors"] == ["wheels", "currents"]
    assert entry["channels"] == list(WHEEL_CHANNELS) and entry["path"] == "members/no_imu"
    assert "members/no_imu/manifest.json" in doc["files"] and "members/no_imu/hgb/model.skops" in doc["files"]
    assert not (with_member / "members" / "no_currents").exists()  # its fit failed: nothing left
    art = load_artifact(with_member, members=True)
    assert [m.sensors for m in art.members] == [["wheels", "currents"]]


def test_a_changed_member_file_or_foreign_member_is_refused(with_member, tmp_path):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(with_member, bad)
    skops = bad / "members" / "no_imu" / "hgb" / "model.skops"
    raw = bytearray(skops.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    skops.write_bytes(bytes(raw))
    with pytest.raises(ModelLoadError, match="model.skops"):
        load_serving_model(bad)
    other = tmp_path / "other"
    shutil.copytree(with_member, other)
    shutil.rmtree(other / "members" / "no_imu")
    _save(other / "members" / "no_imu", WHEEL_CHANNELS, ["wheels", "currents"])
    doc = json.loads((other / "members" / "no_imu" / "manifest.json").read_text())
    doc["class_names"] = ["A", "B"]
    from terrainml.models.artifacts import write_manifest
    write_manifest(other / "members" / "no_imu", doc)
    with pytest.raises(ArtifactError, match="class_names"):
        attach_members(other, ["no_imu"])


def test_with_the_imu_the_model_serves_on_all_its_sensors(with_member):
    p, msgs = _serve(with_member, _drive())
    assert p.stats()["classifications"] > 0 and p.stats()["member_switches"] == 0
    served = [m for m in msgs if not m.fallback]
    assert served and {m.terrain_name for m in served} == {"SNOW"}
    assert {tuple(m.sensors) for m in msgs} == {("wheels", "currents", "imu")}


def test_without_the_imu_file_the_member_serves_and_says_so(with_member):
    p, msgs = _serve(with_member, _drive(imu=False))
    assert p.stats()["classifications"] > 0
    late = msgs[50:]  # after the IMU's 0.2 s silence the member serves every tick
    assert {tuple(m.sensors) for m in late} == {("wheels", "currents")}
    assert not any(m.fallback_reason == "estimator_unhealthy" for m in late)
    served = [m for m in msgs if not m.fallback]
    assert len(served) > 0.5 * len(msgs) and {m.terrain_name for m in served} == {"SNOW"}
    assert p.stats()["member_ticks"]["no_imu"] >= len(late)


def test_an_imu_lost_midway_hands_over_to_the_member_without_a_gap(with_member):
    p, msgs = _serve(with_member, _drive(duration_s=20.0, imu_gone_s=10.0))
    t = np.array([m.t_s for m in msgs])
    before = [m for m, tt in zip(msgs, t) if 5.0 <= tt < 10.0]
    after = [m for m, tt in zip(msgs, t) if tt >= 10.3]
    assert {tuple(m.sensors) for m in before} == {("wheels", "currents", "imu")}
    assert {tuple(m.sensors) for m in after} == {("wheels", "currents")}
    # the fused class carries over the switch: no tick after it falls back
    assert all(not m.fallback and m.terrain_name == "SNOW" for m in after)
    assert p.stats()["member_switches"] == 1


def test_a_camera_dropout_hands_over_to_the_member_without_camera(tmp_path):
    """A tracking camera lost for 1.5 s (a confidence drop on wet ground): the model needs the
    camera, its member ``no_cam`` does not. The EKF's own health flag needs the camera fresh, so
    the member, which does without it, must not read that flag: it serves the class through the
    dropout instead of ``estimator_unhealthy``, and the model serves again once the camera is back."""
    robot = replace(HUSKY, camera=CameraSpec(x_m=0.3, y_m=0.0))
    every = ["wheels", "currents", "imu", "cam"]
    out = tmp_path / "m"
    _save(out, SIDE_CHANNEL_NAMES, every, robot=robot)

    def only_no_cam(subset, folder):
        if "cam" in subset:
            raise ValueError("only no_cam here")
        _save(folder, SIDE_CHANNEL_NAMES, subset, robot=robot)

    assert train_members(out, every, only_no_cam) == ["no_cam"]
    p, msgs = _serve(out, _drive(duration_s=20.0, robot=robot, cam_dropouts=((10.0, 11.5),)))
    t = np.array([m.t_s for m in msgs])
    during = [m for m, tt in zip(msgs, t) if 10.25 <= tt < 11.5]
    after = [m for m, tt in zip(msgs, t) if tt >= 11.75]
    assert {tuple(m.sensors) for m in during} == {("wheels", "currents", "imu")}
    assert all(not m.fallback and m.terrain_name == "SNOW" for m in during), \
        {m.fallback_reason for m in during}
    assert {tuple(m.sensors) for m in after} == {tuple(every)}
    assert all(not m.fallback for m in after)
    assert p.stats()["member_switches"] == 2


def test_predict_on_a_log_without_the_imu_serves_the_member_from_the_first_tick(with_member, tmp_path, capsys):
    """A replayed log with no IMU row at all: the group is not mapped (said once), never a silent
    episode, and the member serves every message from the first tick."""
    from terrainml.schema import write_run_parquet
    from terrainml.stream.app.options import ServeOptions
    from terrainml.stream.app.runner import run_predict

    log = write_run_parquet(_drive(imu=False), tmp_path / "no_imu.parquet")
    assert run_predict(ServeOptions(model=with_member, source=str(log), sinks=("stdout",))) == 0
    out, err = capsys.readouterr()
    msgs = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    assert msgs and {tuple(m["sensors"]) for m in msgs} == {("wheels", "currents")}
    assert "sensor group 'imu' not mapped" in err and "'imu' silent" not in err
