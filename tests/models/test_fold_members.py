"""The served replay serves a fold's held-out runs as ``predict`` serves the saved folder: with the
sensor members those runs call on, each fitted on the fold's training windows alone.

Hand-made truth: two classes told apart by the motor current alone (2 A or 6 A on every wheel),
Husky runs cut with the ``chunks`` spec (IMU, currents, wheel speeds). One held-out run at 6 A has
no IMU data: the fold's model cannot serve it; its member without the IMU must, and right.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from terrainml.features.windows import window_spec
from terrainml.pipeline.dataset import build_from_tables
from terrainml.pipeline.fold_replay import replay_folds
from terrainml.pipeline.sensor_subsets import flagged_groups
from terrainml.pipeline.train import fold_model, make_factory
from terrainml.pipeline.train_options import ReplayOptions
from terrainml.robot import load_robot
from terrainml.testing import kinematic_run, trapezoid_speed

HUSKY = load_robot("husky")
IMU_DATA = ("imu_ax_mps2", "imu_ay_mps2", "imu_az_mps2", "imu_yaw_rate_radps", "imu_yaw_rad")


def _run(k: int, terrain: int, imu: bool = True) -> pd.DataFrame:
    t = kinematic_run(HUSKY, duration_s=16.0, seed=k, terrain=terrain, run_id=f"r{k}",
                      vx=lambda tt: trapezoid_speed(tt, 1.0, 0.5, 0.5))
    rng = np.random.default_rng(k)
    for i in range(1, HUSKY.n_wheels + 1):
        t[f"wheel{i}_current_a"] = (6.0 if terrain else 2.0) + rng.normal(0, 0.1, len(t))
    t["imu_roll_rate_radps"] = 0.0
    t["imu_pitch_rate_radps"] = 0.0
    if not imu:  # as a log without the IMU topic is ingested: no values, flagged invalid
        t[list(IMU_DATA)] = np.nan
        t["imu_valid"] = False
    return t


@pytest.fixture(scope="module")
def fold():
    tables = [_run(k, k % 2, imu=k != 5) for k in range(8)]
    ds = build_from_tables(tables, HUSKY, spec=window_spec("chunks"))
    held = ["r4", "r5"]  # r5: 6 A, no IMU data (so no window of the model's spec)
    groups = np.asarray(ds.windows.groups).astype(str)
    train = ds.windows.subset(np.flatnonzero(~np.isin(groups, held)))
    model = make_factory("hgb", ds, 0, params={"max_iter": 20})().fit(train, train.y)
    return tables, ds, held, train, model


def test_flagged_groups_are_those_invalid_somewhere():
    with_imu, without = _run(0, 0), _run(1, 1, imu=False)
    assert "imu" not in flagged_groups([with_imu]) and "imu" in flagged_groups([with_imu, without])
    assert "currents" not in flagged_groups([with_imu, without])


def test_a_held_out_run_without_imu_is_served_by_the_fold_member_without_it(fold):
    tables, ds, held, train, model = fold
    plain = fold_model(ds, held, {"hgb": model}, "hgb", train, tables, ReplayOptions(segment_s=16.0), 0)
    served = fold_model(ds, held, {"hgb": model}, "hgb", train, tables, ReplayOptions(segment_s=16.0, members=True), 0)
    assert plain.members == [] and [m.name for m in served.members] == ["no_imu"]
    (member,) = served.members
    assert len(member.windows) == len(train) and not any(c.startswith("imu_") for c in member.windows.channels)
    notes: list = []
    without, with_members = replay_folds([plain, served], None, 0, notes.append)
    assert without["members"] == [] and with_members["members"] == ["no_imu"]
    # the member served the run without IMU data (16 s at 100 Hz), the model nothing of it
    assert without["member_ticks"] == {} and 1400 <= with_members["member_ticks"]["no_imu"] <= 1600
    # the run without IMU: the fold's model falls back on it, its member serves it right
    assert without["fallback_reasons"].get("estimator_unhealthy", 0) > 0.3 * without["moving_ticks"]
    assert with_members["fallback_reasons"].get("estimator_unhealthy", 0) == 0
    assert with_members["right_share"] > without["right_share"] + 0.3
    assert with_members["right_share"] > 0.8
    assert any("member no_imu" in str(n) for n in notes)
    from terrainml.evaluation.report import replay_markdown

    table = "\n".join(replay_markdown({"folds": [without, with_members], "pooled": {}, "segment_s": 16.0}))
    assert f"| no_imu ({with_members['member_ticks']['no_imu']} ticks) |" in table and "| - |" in table


@pytest.mark.parametrize("extra, members", [((), True), (("--no-members",), False),
                                            (("--sensors", "wheels,currents"), False)])
def test_the_replay_serves_fold_members_exactly_when_the_folder_gets_members(tmp_path, monkeypatch, extra, members):
    from typer.testing import CliRunner

    from terrainml.cli import app
    from terrainml.commands import train_cmd

    seen = []
    monkeypatch.setattr(train_cmd, "_run", seen.append)
    (tmp_path / "logs").mkdir()
    for windows in ("auto", "short"):
        r = CliRunner().invoke(app, ["train", "--data", str(tmp_path / "logs"), "--windows", windows, "--model", "svm",
                                     "--out", str(tmp_path / "m"), *extra])
        assert r.exit_code == 0, r.output
    assert [req.serve.members for req in seen] == [members, members]
    assert [req.members and req.source.sensors is None for req in seen] == [members, members]


def test_a_member_is_replayed_without_members_of_its_own(fold, monkeypatch, tmp_path):
    from terrainml.pipeline import members as members_mod
    from terrainml.pipeline.train_options import ReplayOptions, TrainOptions

    tables, ds, *_ = fold
    seen = []
    monkeypatch.setattr(members_mod, "train", lambda sub, folder, kinds, options, serve, **kw: seen.append(serve))
    fit = members_mod.fixed_fit(ds, ("hgb",), TrainOptions(), ReplayOptions(members=True), tables)
    fit(["wheels", "currents"], tmp_path / "no_imu")
    assert [s.members for s in seen] == [False]
