"""Damaged-input suite, every input generated here, none stored: bad cells in CSV and
Parquet tables, damage counts carried in the run table's metadata, labels never carried across a
hole, a truncated ROS 1 bag, a wheel count that differs from the robot spec.

Ground truth is what the test wrote (values are simple functions of time, bad cells at known rows,
bag record offsets from rosbags' own index), never the ingest's output.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from terrainml.cli import app
from terrainml.io import topics
from terrainml.io.damage import damage_summary
from terrainml.io.ingest import ingest_to_parquet, load_run
from terrainml.io.inspect import inspect_log
from terrainml.io.mcap_writer import RosMcapWriter
from terrainml.robot import load_robot
from terrainml.schema import read_run_parquet

from mcap_damage import corrupt_middle_chunk

N = 50   # rows of a hand-made table, 100 Hz


def table(n: int = N) -> pd.DataFrame:
    """A 3-wheel run table: imu_ax = 0.1 t, omega_i = i + t, label 3 (values known at every row)."""
    t = np.arange(n) / 100.0
    d = {"t_s": t, "imu_ax_mps2": 0.1 * t, "imu_ay_mps2": 0 * t, "imu_az_mps2": 9.81 + 0 * t,
         "imu_yaw_rate_radps": 0.2 + 0 * t}
    for i in (1, 2, 3):
        d[f"wheel{i}_omega_radps"] = i + t
        d[f"wheel{i}_steer_rad"] = 0.1 * i + 0 * t
        d[f"wheel{i}_current_a"] = 2.0 + i + 0 * t
    d["terrain"] = np.full(n, 3)
    return pd.DataFrame(d)


def _warned(rep, path, column):
    return [w for w in rep.warnings if str(path) in w and f"'{column}'" in w]


# ----------------------------------------------------------------------------- bad cells
def test_csv_non_numeric_cell_is_invalid_not_the_previous_value(tmp_path):
    df = table().astype(object)
    df.loc[10, "wheel1_omega_radps"] = "abc"
    path = tmp_path / "text_cell.csv"
    df.to_csv(path, index=False)
    r = load_run(path)
    t = r.table
    assert not t["wheels_valid"].iloc[10] and np.isnan(t["wheel1_omega_radps"].iloc[10])
    ok = t["wheels_valid"].to_numpy()
    assert ok.sum() == N - 1
    np.testing.assert_allclose(t.loc[ok, "wheel1_omega_radps"], 1 + t.loc[ok, "t_s"], atol=1e-12)
    assert r.report.bad_cells == {"wheel1_omega_radps": {"unparseable": 1}}
    assert _warned(r.report, path, "wheel1_omega_radps")
    assert t.attrs["terrainml"]["damage"]["bad_cells_per_column"] == {"wheel1_omega_radps": {"unparseable": 1}}


def test_csv_bad_cell_is_never_interpolated_over(tmp_path):
    df = table().astype(object)
    df.loc[20, "imu_ax_mps2"] = "#VALUE!"
    path = tmp_path / "interp.csv"
    df.to_csv(path, index=False)
    t = load_run(path).table
    v = t["imu_valid"].to_numpy()
    assert not v[20] and v[19] and v[21] and v.sum() == N - 1
    assert t["imu_ax_mps2"].iloc[19] == pytest.approx(0.019) and t["imu_ax_mps2"].iloc[21] == pytest.approx(0.021)


def test_csv_column_of_na_text_warns_and_names_file_and_column(tmp_path):
    df = table().astype(object)
    df["imu_ax_mps2"] = "n/a"
    path = tmp_path / "na_column.csv"
    df.to_csv(path, index=False)
    r = load_run(path)
    assert r.report.valid_fraction["imu"] == 0.0 and r.report.valid_fraction["wheels"] == 1.0
    assert r.report.bad_cells["imu_ax_mps2"] == {"unparseable": N}
    msgs = _warned(r.report, path, "imu_ax_mps2")
    assert any("0% valid" in m for m in msgs)


def test_csv_inf_and_nan_cells_are_counted_and_invalid(tmp_path):
    df = table().astype(object)
    df.loc[5, "imu_ax_mps2"] = "inf"
    df.loc[6, "imu_ay_mps2"] = "-inf"
    df.loc[30, "wheel2_current_a"] = "nan"
    path = tmp_path / "nonfinite.csv"
    df.to_csv(path, index=False)
    r = load_run(path)
    assert r.report.bad_cells == {"imu_ax_mps2": {"non_finite": 1}, "imu_ay_mps2": {"non_finite": 1},
                                  "wheel2_current_a": {"non_finite": 1}}
    t = r.table
    assert not t["imu_valid"].iloc[[5, 6]].any() and t["imu_valid"].sum() == N - 2
    assert not t["current_valid"].iloc[30] and t["current_valid"].sum() == N - 1
    d = damage_summary(t)
    assert d.any and d.bad_cells == 3 and d.bad_cells_per_column["imu_ax_mps2"] == 1


def test_csv_empty_cells_of_a_sparse_table_are_not_damage(tmp_path):
    df = table()
    df.loc[1:N - 2:2, ["wheel1_current_a", "wheel2_current_a", "wheel3_current_a"]] = np.nan   # 50 Hz currents
    path = tmp_path / "sparse.csv"
    df.to_csv(path, index=False)
    r = load_run(path)
    assert not r.report.bad_cells and not damage_summary(r.table).any
    assert r.table["current_valid"].all()   # 20 ms apart: within the gap rule


def test_parquet_true_false_strings_in_validity_column(tmp_path):
    df = table()
    flags = np.arange(N) % 3 != 0
    df["imu_valid"] = np.where(flags, "True", "False")
    path = tmp_path / "tf.parquet"
    df.to_parquet(path)
    r = load_run(path)
    np.testing.assert_array_equal(r.table["imu_valid"].to_numpy(), flags)
    assert not r.report.bad_cells


def test_parquet_unreadable_validity_cell_is_invalid_and_counted(tmp_path):
    df = table()
    df["imu_valid"] = ["True"] * 10 + ["perhaps"] + ["True"] * (N - 11)
    path = tmp_path / "perhaps.parquet"
    df.to_parquet(path)
    r = load_run(path)
    assert r.report.bad_cells == {"imu_valid": {"unparseable": 1}}
    assert not r.table["imu_valid"].iloc[10] and r.table["imu_valid"].sum() == N - 1


def test_parquet_list_typed_column_warns(tmp_path):
    df = table()
    df["imu_ax_mps2"] = [[1.0, 2.0]] * N
    path = tmp_path / "list.parquet"
    df.to_parquet(path)
    r = load_run(path)
    assert r.report.bad_cells["imu_ax_mps2"] == {"wrong_type": N}
    assert any("0% valid" in m for m in _warned(r.report, path, "imu_ax_mps2"))
    assert r.report.valid_fraction["imu"] == 0.0


def test_parquet_non_null_nan_counts_and_flagged_rows_stay_invalid(tmp_path):
    df = table()
    vals = df["imu_az_mps2"].to_numpy().copy()
    vals[7] = np.nan
    arrays = {c: pa.array(df[c].to_numpy()) for c in df.columns if c != "imu_az_mps2"}
    arrays["imu_az_mps2"] = pa.array(vals, from_pandas=False)              # a NaN, not a null
    arrays["wheels_valid"] = pa.array(np.arange(N) != 40)                  # the table flags row 40
    path = tmp_path / "nan.parquet"
    pq.write_table(pa.table(arrays), path)
    r = load_run(path)
    assert r.report.bad_cells == {"imu_az_mps2": {"non_finite": 1}}
    assert not r.table["imu_valid"].iloc[7] and r.table["imu_valid"].sum() == N - 1
    assert not r.table["wheels_valid"].iloc[40] and r.table["wheels_valid"].sum() == N - 1


# ----------------------------------------------------------------------------- damage counts
def _write_labelled(path, seconds=3.0, skip=None, chunk_size=4 * 1024):
    """IMU + wheels at 100 Hz, a terrain label once a second (0 s: 3, 1 s: 3, 2 s: 3, ...)."""
    with RosMcapWriter(path, 3, chunk_size=chunk_size) as w:
        for k in range(int(seconds * 100)):
            t = k / 100
            if skip is not None and skip[0] <= t < skip[1]:
                continue
            w.write_imu(t, (0.1 * t, 0.0, 9.81), (0.0, 0.0, 0.2))
            w.write_wheel_joints(t, [i + t for i in range(1, 4)], [0.0] * 3)
            w.write_motor_current(t, [2.0] * 3)
            if k % 100 == 0:
                w.write_terrain_label(t, 3)


def test_corrupt_chunk_counts_travel_with_the_table(tmp_path):
    good, bad = tmp_path / "good.mcap", tmp_path / "bad.mcap"
    _write_labelled(good)
    corrupt_middle_chunk(good, bad)
    assert not damage_summary(load_run(good).table).any
    r = load_run(bad)
    lost = {t: d["corrupt"] for t, d in r.report.topics.items() if d["corrupt"]}
    assert lost and lost.get(topics.IMU, 0) > 0
    d = damage_summary(r.table)
    assert d.any and d.corrupt_per_topic == lost and d.corrupt_messages == sum(lost.values())
    assert d.corrupt_chunks == 1 and topics.IMU in d.text and d.text.startswith("damaged:")
    # the same counts in the Parquet file of `ingest --out`, read back two ways
    out = tmp_path / "bad.parquet"
    rep = ingest_to_parquet(bad, out, chunk_s=0.5)
    assert rep.usable
    assert damage_summary(out).corrupt_per_topic == lost
    assert damage_summary(read_run_parquet(out)).corrupt_per_topic == lost
    meta = json.loads(pq.read_schema(out).metadata[b"terrainml"])
    assert meta["damage"]["corrupt_per_topic"] == lost


def _label_expectation(t_s: np.ndarray, hole: np.ndarray, label_times=(0.0, 1.0, 2.0)) -> np.ndarray:
    """-1 from the first hole tick until the next label message, 3 elsewhere (ground truth)."""
    want = np.full(len(t_s), 3)
    for k in np.flatnonzero(hole):
        nxt = min([lt for lt in label_times if lt > t_s[k] + 1e-9] + [np.inf])
        want[(t_s >= t_s[k] - 1e-9) & (t_s < nxt - 1e-9)] = -1
    return want


def test_label_is_not_carried_across_a_corrupt_hole(tmp_path):
    good, bad = tmp_path / "good.mcap", tmp_path / "bad.mcap"
    _write_labelled(good)
    corrupt_middle_chunk(good, bad)
    for t in (load_run(bad).table, read_run_parquet(_ingested(bad, tmp_path / "bad.parquet"))):
        groups = ["wheels_valid", "imu_valid", "current_valid"]
        hole = ~t[groups].any(axis=1).to_numpy()
        assert hole.any()
        ts = t["t_s"].to_numpy()
        np.testing.assert_array_equal(t["terrain"].to_numpy(), _label_expectation(ts, hole))
        after = (ts > ts[hole].max()) & (t["terrain"].to_numpy() == -1)
        assert after.any() and t.loc[after, groups].any(axis=1).all()   # live ticks after the hole: no label


def _ingested(path, out):
    assert ingest_to_parquet(path, out, chunk_s=0.25).usable
    return out


def test_label_is_not_carried_across_a_gap_in_the_log(tmp_path):
    path = tmp_path / "gap.mcap"
    _write_labelled(path, skip=(1.2, 1.6))
    t = load_run(path).table
    ts, terrain = t["t_s"].to_numpy(), t["terrain"].to_numpy()
    # encoders hold their last sample two base periods (1.20, 1.21 s): the hole starts at 1.22 s;
    # in it and after it no label until the next label message at 2 s
    assert (terrain[ts < 1.215] == 3).all() and (terrain[(ts > 1.215) & (ts < 2.0 - 1e-9)] == -1).all()
    assert (terrain[ts >= 2.0 - 1e-9] == 3).all()


def test_label_is_not_carried_across_a_hole_in_a_table(tmp_path):
    df = table(300)
    df["terrain"] = np.where(df["t_s"] < 1.0, 2, 6)
    df.loc[df["t_s"] >= 1.0, "terrain"] = -1     # unlabelled from 1 s
    df = df[(df["t_s"] < 0.8) | (df["t_s"] >= 1.2)]   # and 0.8-1.2 s of rows missing
    path = tmp_path / "hole.csv"
    df.to_csv(path, index=False)
    t = load_run(path).table
    ts, terrain = t["t_s"].to_numpy(), t["terrain"].to_numpy()
    # encoders hold the 0.79 s row two base periods (to 0.81 s): the hole starts at 0.82 s
    assert (terrain[ts < 0.815] == 2).all() and (terrain[ts > 0.815] == -1).all()



def _write_label_stream(path, label_times, label_of, seconds=10.0):
    """IMU, wheels, current and camera at 100 Hz for ``seconds``; a label message at each of
    ``label_times`` (s) with the value ``label_of(t)``."""
    label_ticks = {int(round(t * 100)) for t in label_times}
    with RosMcapWriter(path, 3, chunk_size=4 * 1024) as w:
        for k in range(int(seconds * 100)):
            t = k / 100
            w.write_imu(t, (0.1 * t, 0.0, 9.81), (0.0, 0.0, 0.2))
            w.write_wheel_joints(t, [i + t for i in range(1, 4)], [0.0] * 3)
            w.write_motor_current(t, [2.0] * 3)
            w.write_camera_odom(t, (0.0, 0.0, -0.5 * t), (0.0, 0.0, 0.0, 1.0), (0.0, 0.0, -0.5), (0.0, 0.0, 0.0))
            if k in label_ticks:
                w.write_terrain_label(t, label_of(t))


def _held_labels(ts, label_times, label_of):
    """The label each tick holds from the complete stream (ground truth: the last message before)."""
    lt = np.asarray(sorted(label_times))
    i = np.searchsorted(lt, ts + 1e-9, side="right") - 1
    return np.array([label_of(lt[j]) if j >= 0 else -1 for j in i])


def test_label_is_not_carried_across_a_hole_in_its_own_stream(tmp_path):
    """Label messages at 3, 4 and 5 s lost (the change 2 -> 6 at 4 s with them) while every
    sensor stays valid: the 2 s label lasts its period (to 3 s), then -1 until the 6 s message."""
    label_of = lambda t: 2 if t < 4.0 - 1e-9 else 6          # noqa: E731
    full = [float(k) for k in range(10)]
    sent = [t for t in full if t not in (3.0, 4.0, 5.0)]
    path = tmp_path / "label_hole.mcap"
    _write_label_stream(path, sent, label_of)
    for t in (load_run(path).table, read_run_parquet(_ingested(path, tmp_path / "label_hole.parquet"))):
        ts, terrain = t["t_s"].to_numpy(), t["terrain"].to_numpy()
        assert t[["wheels_valid", "imu_valid", "current_valid", "cam_valid"]].to_numpy().all()
        truth = _held_labels(ts, full, label_of)
        hole = (ts > 3.0 + 1e-9) & (ts < 6.0 - 1e-9)
        assert (terrain[hole] == -1).all()
        np.testing.assert_array_equal(terrain[~hole], truth[~hole])   # never a label the truth lacks
        assert (terrain[(ts >= 2.0 - 1e-9) & (ts <= 3.0 + 1e-9)] == 2).all()


def test_label_is_not_carried_past_the_end_of_its_stream(tmp_path):
    """The label stream stops at 6 s (a cut) while the sensors go on to 10 s: held one period."""
    label_of = lambda t: 5                                    # noqa: E731
    path = tmp_path / "label_cut.mcap"
    _write_label_stream(path, [float(k) for k in range(7)], label_of)
    t = load_run(path).table
    ts, terrain = t["t_s"].to_numpy(), t["terrain"].to_numpy()
    assert (terrain[ts <= 7.0 + 1e-9] == 5).all() and (terrain[ts > 7.0 + 1e-9] == -1).all()


def test_labels_sent_on_change_are_held_between_changes(tmp_path):
    """A label stream published only on change (irregular intervals) has no holes of its own."""
    times = [0.0, 0.7, 5.0, 5.3, 9.0]
    label_of = lambda t: {0.0: 1, 0.7: 2, 5.0: 4, 5.3: 2, 9.0: 6}[round(t, 2)]   # noqa: E731
    path = tmp_path / "on_change.mcap"
    _write_label_stream(path, times, label_of)
    t = load_run(path).table
    ts = t["t_s"].to_numpy()
    np.testing.assert_array_equal(t["terrain"].to_numpy(), _held_labels(ts, times, label_of))


# ----------------------------------------------------------------------------- truncated ROS 1 bag
def _write_bag(path, n=300, compression=None):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    Imu, Header, Time = (ts.types[k] for k in ("sensor_msgs/msg/Imu", "std_msgs/msg/Header",
                                               "builtin_interfaces/msg/Time"))
    Q, V = ts.types["geometry_msgs/msg/Quaternion"], ts.types["geometry_msgs/msg/Vector3"]
    payloads = []
    w = Writer(path)
    if compression:
        w.set_compression(getattr(Writer.CompressionFormat, compression))
    w.chunk_threshold = 4096
    with w:
        conn = w.add_connection("/imu", Imu.__msgtype__, typestore=ts)
        for k in range(n):
            t = 1_000_000_000 + k * 10_000_000
            msg = Imu(Header(seq=k, stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="imu"),
                      Q(0.0, 0.0, 0.0, 1.0), np.zeros(9), V(0.0, 0.0, 0.2), np.zeros(9),
                      V(0.001 * k, 0.0, 9.81), np.zeros(9))
            raw = ts.serialize_ros1(msg, Imu.__msgtype__)
            payloads.append(bytes(raw))
            w.write(conn, t, raw)
    return payloads


def _imu_only_map():
    from terrainml.io.topicmap import load_topic_map

    m = load_topic_map().to_dict()
    m["sources"] = [s for s in m["sources"] if s["topic"] == "/imu"]
    return m


def _read_imu(path):
    from terrainml.io.readers import read_bag

    acc = []
    res = read_bag(path, lambda topic, type_name: "imu", on_part=lambda topic, p: acc.append(p["accel"][0, 0]))
    return res, np.array(acc)


@pytest.mark.parametrize("fraction", [0.15, 0.4, 0.5, 0.77, 0.93])
def test_truncated_uncompressed_bag_keeps_every_complete_message(tmp_path, fraction):
    full = tmp_path / "full.bag"
    payloads = _write_bag(full)
    data = full.read_bytes()
    cut = int(len(data) * fraction)
    # ground truth: a message is complete when its serialized bytes end before the cut
    want = sum(1 for p in payloads if data.find(p) + len(p) <= cut)
    path = tmp_path / "cut.bag"
    path.write_bytes(data[:cut])
    res, acc = _read_imu(path)
    assert res.stats["/imu"].read == want and res.stats["/imu"].decoded == want
    np.testing.assert_allclose(acc, 0.001 * np.arange(want), atol=1e-12)   # in order, exact
    tr = res.truncation()
    if want < len(payloads):
        assert res.truncated and tr["unread_bytes"] > 0 and tr["incomplete_records"] >= 1
        assert any("truncated" in w and str(path) in w for w in res.warnings)


@pytest.mark.parametrize("compression", [None, "BZ2", "LZ4"])
def test_truncated_bag_cut_inside_a_chunk(tmp_path, compression):
    from rosbags.rosbag1 import Reader

    full = tmp_path / "full.bag"
    _write_bag(full, compression=compression)
    with Reader(full) as rd:
        chunks = [(c.pos, sum(c.connection_counts.values())) for c in rd.chunk_infos]
    data = full.read_bytes()
    for j in (1, len(chunks) // 2, len(chunks) - 1):
        pos = chunks[j][0]
        path = tmp_path / f"cut{j}.bag"
        path.write_bytes(data[:pos + 10])        # 10 bytes into chunk j's record header
        res, acc = _read_imu(path)
        want = sum(n for _, n in chunks[:j])
        assert res.stats["/imu"].read == want, (compression, j)
        np.testing.assert_allclose(acc, 0.001 * np.arange(want), atol=1e-12)
        tr = res.truncation()
        assert tr["unread_bytes"] == 10 and tr["incomplete_records"] == 1 and tr["recovered_from_cut"] == 0


def test_truncated_bag_through_ingest_inspect_and_cli(tmp_path):
    full = tmp_path / "full.bag"
    payloads = _write_bag(full)
    data = full.read_bytes()
    path = tmp_path / "cut.bag"
    path.write_bytes(data[:len(data) // 2])
    want = sum(1 for p in payloads if data.find(p) + len(p) <= len(data) // 2)
    r = load_run(path, topic_map=_imu_only_map())
    assert r.report.usable and r.report.topics["/imu"]["decoded"] == want
    assert r.report.truncation["unread_bytes"] > 0
    d = damage_summary(r.table)
    assert d.any and d.truncation is not None and d.lost_bytes == r.report.truncation["unread_bytes"]
    assert "truncated" in d.text
    info = inspect_log(path)
    assert info["truncated"] and info["topics"]["/imu"]["count"] == want
    res = CliRunner().invoke(app, ["inspect", str(path), "--json"])
    assert res.exit_code == 0 and json.loads(res.stdout)["truncation"]["unread_bytes"] > 0


def test_bag_that_is_not_a_bag_beyond_its_magic_is_refused(tmp_path):
    path = tmp_path / "junk.bag"
    path.write_bytes(b"#ROSBAG V2.0\n" + b"\xff" * 64)
    r = load_run(path)
    assert not r.report.usable and str(path) in r.report.errors[0]


# ----------------------------------------------------------------------------- wheel count
def test_wheel_count_of_log_differs_from_spec(tmp_path):
    path = tmp_path / "four.mcap"
    with RosMcapWriter(path, 4) as w:
        for k in range(50):
            w.write_imu(k / 100, (0, 0, 9.81), (0, 0, 0))
            w.write_wheel_joints(k / 100, [1] * 4, [0] * 4)
    r = load_run(path)   # agrimaro: 3 wheels
    assert not r.report.usable
    msg = r.report.errors[0]
    assert str(path) in msg and "4 wheel" in msg and "3" in msg
    rep = ingest_to_parquet(path, tmp_path / "four.parquet")
    assert not rep.usable and "4 wheel" in rep.errors[0]
    assert load_run(path, robot=load_robot("husky")).report.usable


def test_wheel_count_of_table_differs_from_spec(tmp_path):
    df = table()
    df["wheel4_omega_radps"] = 4 + df["t_s"]
    path = tmp_path / "four.csv"
    df.to_csv(path, index=False)
    r = load_run(path)
    assert not r.report.usable and str(path) in r.report.errors[0] and "4 wheel" in r.report.errors[0]


def test_damage_counts_reach_the_estimate_report(tmp_path):
    """`estimate` writes the counts into its report and says them (nothing said on a clean log)."""
    good, bad = tmp_path / "good.mcap", tmp_path / "bad.mcap"
    _write_labelled(good, seconds=4.0)
    corrupt_middle_chunk(good, bad)
    lost = {t: d["corrupt"] for t, d in load_run(bad).report.topics.items() if d["corrupt"]}
    out = tmp_path / "est.parquet"
    res = CliRunner().invoke(app, ["estimate", str(bad), "--out", str(out)])
    assert res.exit_code == 0, res.output
    report = json.loads(out.with_suffix(".report.json").read_text())
    assert report["damage"]["corrupt_per_topic"] == lost
    assert "damaged:" in res.output
    res = CliRunner().invoke(app, ["estimate", str(good), "--out", str(tmp_path / "g.parquet")])
    assert res.exit_code == 0 and "damaged:" not in res.output
