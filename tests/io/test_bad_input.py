"""Bad input: every case keeps the readable messages, counts the rest per topic, names the
file and topic, and gives exit 0 (usable, with warnings) or 2 (not usable) without a traceback."""

from __future__ import annotations


import numpy as np
import pytest
from typer.testing import CliRunner

from terrainml.cli import app
from terrainml.io import topics
from terrainml.io.ingest import load_run

runner = CliRunner()


def _cli(path, tmp_path):
    res = runner.invoke(app, ["ingest", str(path), "--out", str(tmp_path / "out.parquet")])
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)
    return res


def test_good_log_is_exact(good_log, tmp_path):
    path, counts = good_log
    r = load_run(path)
    t = r.table
    assert r.report.usable and not r.report.warnings
    assert len(t) == 300 and t["t_s"].iloc[-1] == pytest.approx(2.99)
    np.testing.assert_allclose(t["wheel2_omega_radps"], 2 + t["t_s"], atol=1e-9)
    np.testing.assert_allclose(t["imu_ax_mps2"], 0.1 * t["t_s"], atol=1e-9)
    np.testing.assert_allclose(t["cam_vx_mps"], 1.0, atol=1e-9)
    assert (t["terrain"] == 3).all() and (t["run_id"] == "good_run").all()
    assert _cli(path, tmp_path).exit_code == 0


def test_truncated_mcap_keeps_messages_before_the_cut(good_log, tmp_path):
    path, counts = good_log
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    r = load_run(cut)
    assert r.report.usable
    assert any("truncated" in w and str(cut) in w for w in r.report.warnings)
    # roughly the first 60 % of the run survives, every surviving tick is exact
    span = r.table["t_s"].iloc[-1]
    assert 1.0 < span < 2.99
    ok = r.table["wheels_valid"].to_numpy()
    np.testing.assert_allclose(r.table["wheel1_omega_radps"][ok], 1 + r.table["t_s"][ok], atol=1e-9)
    assert ok.mean() > 0.9
    assert _cli(cut, tmp_path).exit_code == 0


def _chunk_offsets(path):
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return sorted((c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes)


def test_corrupted_chunk_loses_only_that_chunk(good_log, tmp_path):
    path, counts = good_log
    chunks = _chunk_offsets(path)
    assert len(chunks) >= 4
    start, length = chunks[1]
    data = bytearray(path.read_bytes())
    mid = start + length // 2
    data[mid:mid + 64] = bytes(64)  # zero 64 bytes inside the compressed records
    bad = tmp_path / "bad_chunk.mcap"
    bad.write_bytes(bytes(data))
    r = load_run(bad)
    rep = r.report
    assert rep.usable
    assert any("corrupt chunk" in w and str(bad) in w for w in rep.warnings)
    for topic in (topics.IMU, topics.WHEEL_JOINTS):
        d = rep.topics[topic]
        assert d["corrupt"] > 0, topic
        assert d["decoded"] + d["corrupt"] == counts[topic]  # every message accounted for
        assert any(topic in w and "corrupt" in w for w in rep.warnings)
    # messages after the damaged chunk are kept: the table reaches the end of the run
    assert r.table["t_s"].iloc[-1] == pytest.approx(2.99)
    assert r.table["imu_valid"].iloc[-1]
    assert not r.table["imu_valid"].all()
    assert _cli(bad, tmp_path).exit_code == 0


def test_unknown_message_type_on_mapped_topic(tmp_path, make_log):
    path = tmp_path / "wrong_type.mcap"
    counts = make_log(path, seconds=1.0, imu_type="std_msgs/msg/String")
    r = load_run(path)
    assert r.report.usable  # wheels and camera still fine
    assert r.report.topics[topics.IMU]["skipped"] == counts[topics.IMU]
    msg = [w for w in r.report.warnings if topics.IMU in w and "std_msgs/msg/String" in w]
    assert msg and str(path) in msg[0]
    assert not r.table["imu_valid"].any()
    assert r.table["wheels_valid"].all()
    res = _cli(path, tmp_path)
    assert res.exit_code == 0 and "std_msgs/msg/String" in res.output


def test_nan_and_inf_fields_mark_only_their_ticks_invalid(tmp_path, make_log):
    path = tmp_path / "nan.mcap"
    make_log(path, seconds=1.0, imu_bad={40, 41, 70})
    r = load_run(path)
    assert r.report.topics[topics.IMU]["non_finite"] == 3
    v = r.table["imu_valid"].to_numpy()
    assert not v[[40, 41, 70]].any()
    assert v.sum() == len(v) - 3
    assert np.isfinite(r.table.loc[v, ["imu_ax_mps2", "imu_ay_mps2"]].to_numpy()).all()
    assert any(topics.IMU in w and "NaN/Inf" in w for w in r.report.warnings)
    assert _cli(path, tmp_path).exit_code == 0


def test_out_of_order_and_duplicate_timestamps(tmp_path, make_log):
    rng = np.random.default_rng(0)
    times = list(np.arange(100) / 100.0)
    shuffled = list(rng.permutation(times)) + [0.5, 0.5, 0.25]  # 3 duplicates
    path = tmp_path / "disorder.mcap"
    make_log(path, seconds=1.0, wheel_times=shuffled)
    r = load_run(path)
    d = r.report.topics[topics.WHEEL_JOINTS]
    assert d["duplicates"] == 3 and d["out_of_order"] > 10
    t = r.table
    assert np.all(np.diff(t["t_s"]) > 0)
    np.testing.assert_allclose(t["wheel3_omega_radps"], 3 + t["t_s"], atol=1e-9)  # sorted correctly
    assert any(topics.WHEEL_JOINTS in w and "duplicate" in w for w in r.report.warnings)
    assert _cli(path, tmp_path).exit_code == 0


def test_mapped_topic_missing(tmp_path, make_log):
    path = tmp_path / "nocam.mcap"
    make_log(path, seconds=1.0, camera=False)
    r = load_run(path)
    assert r.report.usable
    assert any(topics.CAMERA_ODOM in w and "not in the log" in w and str(path) in w for w in r.report.warnings)
    assert not r.table["cam_valid"].any()
    res = _cli(path, tmp_path)
    assert res.exit_code == 0 and topics.CAMERA_ODOM in res.output


@pytest.mark.parametrize("content,name", [(b"", "empty.mcap"), (b"hello, I am not a log\n" * 10, "text.mcap"),
                                          (b"\x89MCAP0\r\n", "only_magic.mcap")])
def test_empty_or_not_a_log(tmp_path, content, name):
    path = tmp_path / name
    path.write_bytes(content)
    r = load_run(path)
    assert not r.report.usable and len(r.table) == 0
    assert r.report.errors and str(path) in r.report.errors[0]
    res = _cli(path, tmp_path)
    assert res.exit_code == 2 and name in res.output
    res = runner.invoke(app, ["inspect", str(path)])
    assert res.exit_code == 2 and "Traceback" not in res.output


def test_missing_file_and_bad_topic_map(tmp_path, good_log):
    r = load_run(tmp_path / "nope.mcap")
    assert not r.report.usable and "not found" in r.report.errors[0]
    bad_map = tmp_path / "map.yaml"
    bad_map.write_text("sources:\n  - {topic: /imu, kind: teleporter}\n")
    r = load_run(good_log[0], topic_map=bad_map)
    assert not r.report.usable and "teleporter" in r.report.errors[0] and str(bad_map) in r.report.errors[0]
