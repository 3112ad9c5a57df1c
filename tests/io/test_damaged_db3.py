"""Damaged ROS 2 ``.db3`` bags: the readable rows are kept, the lost counted.

Every bag is written here with rosbags' rosbag2 Writer and then damaged: cut at 60 % of its size,
or 20 pages (4096-byte blocks) in its middle overwritten with random bytes, or its first pages
(the SQLite header and schema) overwritten. Ground truth is the undamaged file: each message's
serialized bytes are found in it, so the page every row lives on is known (a row of ~300 bytes
never spans pages); a row survives exactly when its page does.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore
from typer.testing import CliRunner

from terrainml.cli import app
from terrainml.io import cdr
from terrainml.io.damage import damage_summary
from terrainml.io.ingest import load_run
from terrainml.io.readers import read_bag

T0_NS = 1_700_000_000_000_000_000
PAGE = 4096
IMU, JOINTS = "/imu", "/wheels/joint_states"


def _imu(T, tn):
    h = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=tn // 10**9, nanosec=tn % 10**9),
                                 frame_id="imu")
    v3 = T["geometry_msgs/msg/Vector3"]
    return h, T["sensor_msgs/msg/Imu"](
        header=h, orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.zeros(9), angular_velocity=v3(x=0.0, y=0.0, z=0.1),
        angular_velocity_covariance=np.zeros(9), linear_acceleration=v3(x=0.0, y=0.0, z=9.81),
        linear_acceleration_covariance=np.zeros(9))


@pytest.fixture(scope="module")
def db3(tmp_path_factory):
    """20 s: IMU at 100 Hz (yaw rate 0.1), wheel joints of a 3-wheel robot at 20 Hz (2 rad/s).
    Returns (bag folder, {topic: [(log time ns, serialized bytes), ...]})."""
    ts = get_typestore(Stores.LATEST)
    T = ts.types
    path = tmp_path_factory.mktemp("db3") / "run"
    written = {IMU: [], JOINTS: []}
    names = [f"wheel{i}_drive" for i in (1, 2, 3)] + [f"wheel{i}_steer" for i in (1, 2, 3)]
    with Writer(path, version=9) as w:
        ci = w.add_connection(IMU, "sensor_msgs/msg/Imu", typestore=ts)
        cj = w.add_connection(JOINTS, "sensor_msgs/msg/JointState", typestore=ts)
        for k in range(2000):
            tn = T0_NS + k * 10_000_000
            h, imu = _imu(T, tn)
            raw = bytes(ts.serialize_cdr(imu, "sensor_msgs/msg/Imu"))
            w.write(ci, tn, raw)
            written[IMU].append((tn, raw))
            if k % 5 == 0:
                js = T["sensor_msgs/msg/JointState"](header=h, name=names, position=np.zeros(6),
                                                     velocity=np.array([2.0, 2.0, 2.0, 0, 0, 0]), effort=np.zeros(6))
                raw = bytes(ts.serialize_cdr(js, "sensor_msgs/msg/JointState"))
                w.write(cj, tn, raw)
                written[JOINTS].append((tn, raw))
    return path, written


def _damaged(db3, tmp_path, how):
    """A copy of the bag with its .db3 damaged; returns (folder, file, {topic: set of pages per row})."""
    src, written = db3
    dst = tmp_path / "run"
    shutil.copytree(src, dst)
    f = dst / "run.db3"
    data = bytearray(f.read_bytes())
    pages = {t: [] for t in written}
    for t, rows in written.items():
        for _, raw in rows:
            at = data.find(raw)
            assert at > 0 and data.find(raw, at + 1) < 0 and at // PAGE == (at + len(raw) - 1) // PAGE
            pages[t].append(at // PAGE)
    how(data)
    f.write_bytes(bytes(data))
    return dst, f, pages


def _cut(data):
    del data[int(len(data) * 0.6):]


def _garbage(first_page, n_pages):
    def damage(data):
        data[first_page * PAGE:(first_page + n_pages) * PAGE] = \
            np.random.default_rng(7).integers(0, 256, n_pages * PAGE, dtype=np.uint8).tobytes()
    return damage


def _recovered(path):
    """(ReadResult, {topic: sorted log times read}) of a damaged bag folder."""
    times = {}
    res = read_bag(path, lambda topic, type_name: cdr.KIND_OF_TYPE.get(type_name),
                   on_times=lambda topic, t: times.setdefault(topic, []).extend(t.tolist()),
                   on_part=lambda topic, part: None)
    return res, {t: sorted(v) for t, v in times.items()}


def _check_ingest(path, lost, span_s):
    """load_run keeps the intact part and reports ``lost`` per topic in the MCAP fields."""
    r = load_run(path)
    rep = r.report
    assert rep.usable, rep.errors
    assert {t: d["corrupt"] for t, d in rep.topics.items() if d["corrupt"]} == lost
    assert rep.corrupt_chunks >= 1
    d = damage_summary(r.table)
    assert d.any and d.corrupt_per_topic == lost and d.corrupt_messages == sum(lost.values())
    assert rep.span_s == pytest.approx(span_s, abs=0.011)
    assert r.table["imu_yaw_rate_radps"][r.table["imu_valid"]].mean() == pytest.approx(0.1)
    return rep


def test_truncated_db3_keeps_every_row_before_the_cut(db3, tmp_path):
    path, f, pages = _damaged(db3, tmp_path, _cut)
    cut_page = int(f.stat().st_size) // PAGE     # the page the cut falls in
    res, got = _recovered(path)
    written = db3[1]
    lost = {}
    for t, rows in written.items():
        stamps = [tn for tn, _ in rows]
        surely = {tn for tn, p in zip(stamps, pages[t]) if p < cut_page}
        maybe = {tn for tn, p in zip(stamps, pages[t]) if p <= cut_page}
        assert surely and surely <= set(got[t]) <= maybe, t
        assert got[t][0] == stamps[0]          # the readable span starts where the undamaged one does
        lost[t] = len(stamps) - len(got[t])
        assert lost[t] > 0 and res.stats[t].corrupt == lost[t]
    assert res.truncated and res.truncation()["missing_bytes"] > 0
    assert any(str(f) in w and "truncated" in w for w in res.warnings)
    span = (max(max(v) for v in got.values()) - T0_NS) * 1e-9
    rep = _check_ingest(path, lost, span)
    assert rep.truncation["missing_bytes"] == res.truncation()["missing_bytes"]


def test_db3_with_20_garbage_pages_keeps_the_rest(db3, tmp_path):
    size = db3[0].joinpath("run.db3").stat().st_size
    first = size // PAGE // 2
    path, f, pages = _damaged(db3, tmp_path, _garbage(first, 20))
    bad = set(range(first, first + 20))
    res, got = _recovered(path)
    lost = {}
    for t, rows in db3[1].items():
        want = [tn for (tn, _), p in zip(rows, pages[t]) if p not in bad]
        assert 0 < len(want) < len(rows)
        assert got[t] == want, t                 # exactly the rows on intact pages
        assert got[t][0] == rows[0][0] and got[t][-1] == rows[-1][0]   # the undamaged span
        lost[t] = len(rows) - len(want)
        assert res.stats[t].corrupt == lost[t]
    assert not res.truncated
    _check_ingest(path, lost, (db3[1][IMU][-1][0] - T0_NS) * 1e-9)
    out = tmp_path / "run.parquet"
    cli = CliRunner().invoke(app, ["ingest", str(path), "--out", str(out)])
    assert cli.exit_code == 0, cli.output
    n = sum(lost.values())
    assert [ln for ln in cli.output.splitlines() if ln.startswith("warning:") and str(path) in ln
            and "run.db3" in ln and f"{n:,} message(s) lost" in ln and f"{IMU} {lost[IMU]:,}" in ln]
    assert out.is_file() and damage_summary(out).corrupt_per_topic == lost


def test_db3_without_a_readable_schema_is_refused_naming_it(db3, tmp_path):
    path, f, _ = _damaged(db3, tmp_path, _garbage(0, 2))   # the SQLite header and schema pages
    r = load_run(path)
    assert not r.report.usable and str(f) in r.report.errors[0]
    cli = CliRunner().invoke(app, ["ingest", str(path), "--out", str(tmp_path / "x.parquet")])
    assert cli.exit_code == 2 and str(f) in cli.output and "Traceback" not in cli.output
    assert not (tmp_path / "x.parquet").exists()
