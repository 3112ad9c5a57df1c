"""The two sinks of the one ingest engine agree: the chunked Parquet file of ``ingest_to_parquet``
(``terrainml ingest --out``, bounded memory) equals the in-memory ``load_run`` table on a log whose
awkward spots straddle chunk boundaries (``*_valid`` columns included)."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from terrainml.cli import app
from terrainml.io import t265, topics
from terrainml.io.ingest import ingest_to_parquet, load_run, logs
from terrainml.io.mcap_writer import RosMcapWriter
from terrainml.schema import read_run_parquet

CHUNK_S = 0.5       # 0.5 s chunks: boundaries at 0.50, 1.00, 1.50, ... s (ticks 0.49 | 0.50)
MOUNT = (0.6685, -0.26875, 0.0)
IMU_OFFSET_S = 0.003  # IMU stamps 3 ms off the base grid: every tick interpolates between two samples


def _write_awkward_log(path, seconds=4.0):
    """3-wheel log, every awkward case placed across a chunk boundary (times in s from the start).

    IMU 100 Hz at k/100 + 3 ms, accel x = 0.1 * stamp: gap 0.47-0.56 (across 0.50), NaN sample
    at 1.233, no 2.503 sample and the 2.493 one written after 2.62 (ticks 2.49 and 2.50, on both
    sides of a boundary, are valid only with the late sample). Wheel joints 100 Hz: two stamps
    written out of order near 1.00 and one duplicate at 2.00. Motor currents at 20 Hz (slower than
    the base rate: own median period) with a gap 1.40-1.70 (across 1.50). Camera 200 Hz from 0.30,
    first three poses invalid (zero quaternion), yaw sweeping through +-pi, confidence 1 in
    1.95-2.05 (across 2.00), gap 2.96-3.07 (across 3.00). Labels: 2 at 0.0, 5 at 1.2 (held across
    chunks). cmd_vel at 10 Hz until 2.2 s only (its topic ends long before the log). Truth states.
    """
    n = int(round(seconds * 200))
    with RosMcapWriter(path, 3, chunk_size=8 * 1024) as w:
        late = []
        for k in range(n):
            t = k / 200.0
            if k % 2 == 0:
                ti = t + IMU_OFFSET_S
                if not (0.47 <= t <= 0.56) and abs(t - 2.49) > 1e-9 and abs(t - 2.5) > 1e-9:
                    acc = (np.nan, 0.0, 9.81) if abs(t - 1.23) < 1e-9 else (0.1 * ti, 0.0, 9.81)
                    w.write_imu(ti, acc, (0.0, 0.0, 0.2))
                if abs(t - 2.62) < 1e-9:                # the 2.493 IMU sample arrives 130 ms late
                    w.write_imu(2.49 + IMU_OFFSET_S, (0.1 * (2.49 + IMU_OFFSET_S), 0.0, 9.81), (0.0, 0.0, 0.2))
                if abs(t - 1.0) < 1e-9 or abs(t - 1.01) < 1e-9:
                    late.append(t)                      # written later: out of order
                else:
                    w.write_wheel_joints(t, [i + t for i in range(1, 4)], [0.1 * i for i in range(1, 4)])
                if abs(t - 1.04) < 1e-9:
                    for tl in late:
                        w.write_wheel_joints(tl, [i + tl for i in range(1, 4)], [0.1 * i for i in range(1, 4)])
                if abs(t - 2.0) < 1e-9:                 # duplicate stamp (second copy dropped)
                    w.write_wheel_joints(t, [99.0] * 3, [0.0] * 3)
                w.write_wheel_state(t, [1, 2 if t > 1.5 else 1, 3 if t > 2.5 else 0])
                w.write_ground_truth(t, t, 0.0, 0.0, 1.0, 0.0, 0.0)
            if k % 10 == 0 and not (1.40 < t < 1.70):
                w.write_motor_current(t, [2.0 + i + t for i in range(1, 4)])
            if k % 20 == 0 and t <= 2.2:
                w.write_cmd_vel(t, 1.0, 0.0, 0.3)
            if k % 100 == 0:
                w.write_terrain_label(t, 2 if t < 1.2 else 5)
            if t >= 0.30 and not (2.96 <= t <= 3.07):
                yaw = 2.5 + 1.5 * t                     # passes +pi at ~0.43 s
                m = t265.body_to_t265_odometry(t, 0.0, yaw, 1.0, 0.0, 1.5, MOUNT)
                q = m["orientation_xyzw"][0] if t >= 0.315 else np.zeros(4)
                conf = 1.0 if 1.95 <= t <= 2.05 else 3.0
                w.write_camera_odom(t, m["position_m"][0], q, m["linear_mps"][0], m["angular_radps"][0],
                                    confidence=conf)


@pytest.fixture(scope="module")
def awkward(tmp_path_factory):
    d = tmp_path_factory.mktemp("stream")
    path = d / "awkward.mcap"
    _write_awkward_log(path)
    mem = load_run(path)
    out = d / "awkward.parquet"
    with pytest.MonkeyPatch.context() as mp:   # merge every ~60 decoded rows: chunks are emitted while
        mp.setattr(logs, "DRAIN_ROWS", 60)  # reading, not only at the end of the file
        emitted_at = []
        real = logs.Producer._emit_chunk

        def spy(self, a, b):
            emitted_at.append(self.rows_seen.get(topics.IMU, 0))
            return real(self, a, b)

        mp.setattr(logs.Producer, "_emit_chunk", spy)
        rep = ingest_to_parquet(path, out, chunk_s=CHUNK_S)
    total_imu = rep.topics[topics.IMU]["decoded"]
    assert len(emitted_at) == 8 and emitted_at[0] < 0.4 * total_imu   # streamed, one row group per chunk
    return path, mem, rep, read_run_parquet(out)


def test_chunked_parquet_equals_in_memory_table(awkward):
    _, mem, rep, chunked = awkward
    assert rep.usable and rep.rows == len(mem.table) == len(chunked) and rep.rows > 6 * CHUNK_S * 100
    a, b = mem.table, chunked
    assert list(a.columns) == list(b.columns)
    for c in a.columns:
        if a[c].dtype.kind == "f":
            np.testing.assert_allclose(b[c].to_numpy(), a[c].to_numpy(), rtol=1e-9, atol=1e-9, equal_nan=True,
                                       err_msg=c)
        else:
            assert (a[c].astype(str).to_numpy() == b[c].astype(str).to_numpy()).all(), c
            assert a[c].dtype.kind == b[c].dtype.kind or c == "run_id", c
    assert a.attrs["terrainml"] == b.attrs["terrainml"]       # design §5 metadata, warnings included
    assert rep.topics == mem.report.topics and rep.warnings == mem.report.warnings
    assert rep.valid_fraction == pytest.approx(mem.report.valid_fraction)


def test_chunk_boundaries_keep_the_gap_and_hold_rules(awkward):
    """Hand-checked ticks at the boundaries (independent of load_run)."""
    _, _, rep, t = awkward
    tt = t["t_s"].round(2)

    def at(s, col):
        return t.loc[tt == s, col].iloc[0]

    # IMU gap (samples 0.463 then 0.573): invalid on both sides of the 0.50 boundary
    assert at(0.46, "imu_valid") and at(0.58, "imu_valid")
    assert not t.loc[(tt > 0.46) & (tt < 0.58), "imu_valid"].any()
    ok = t["imu_valid"].to_numpy()
    np.testing.assert_allclose(t.loc[ok, "imu_ax_mps2"], 0.1 * t.loc[ok, "t_s"], atol=1e-9)  # interpolated
    assert at(2.49, "imu_valid") and at(2.5, "imu_valid")          # the late 2.493 sample is used
    assert not at(1.23, "imu_valid") and not at(1.24, "imu_valid") and at(1.25, "imu_valid")  # NaN 1.233
    # out-of-order wheel stamps around 1.00 are sorted back in; the duplicate at 2.00 keeps the first
    assert at(1.0, "wheel2_omega_radps") == pytest.approx(3.0) and at(1.01, "wheel2_omega_radps") == pytest.approx(3.01)
    assert at(2.0, "wheel1_omega_radps") == pytest.approx(3.0)
    assert rep.topics[topics.WHEEL_JOINTS]["out_of_order"] >= 1 and rep.topics[topics.WHEEL_JOINTS]["duplicates"] == 1
    # currents at 20 Hz interpolate between their own samples (gap rule 2 x 50 ms) ...
    assert at(0.52, "current_valid") and at(0.52, "wheel1_current_a") == pytest.approx(3.52)
    # ... but not across the hole between the samples at 1.40 and 1.70, straddling 1.50
    assert at(1.4, "current_valid") and at(1.7, "current_valid")
    assert not t.loc[(tt > 1.40) & (tt < 1.70), "current_valid"].any()
    # low camera confidence 1.95-2.05 across 2.00
    assert not t.loc[(tt >= 1.95) & (tt <= 2.05), "cam_valid"].any() and at(2.1, "cam_valid")
    # camera yaw zeroed at the first valid pose (0.315 s), also in later chunks; wraps through +-pi
    yaw0 = 2.5 + 1.5 * 0.315
    assert at(3.5, "cam_yaw_rad") == pytest.approx(t265.wrap_angle(1.5 * 3.5 - 1.5 * 0.315), abs=1e-6)
    assert at(0.32, "cam_yaw_rad") == pytest.approx(t265.wrap_angle(2.5 + 1.5 * 0.32 - yaw0), abs=1e-6)
    # labels held without limit across chunks; command ends at 2.2 s
    assert at(0.99, "terrain") == 2 and at(3.99, "terrain") == 5
    assert at(2.2, "cmd_valid") and not t.loc[tt > 2.2, "cmd_valid"].any()
    assert at(3.0, "gt_state3") == "braking" and at(1.0, "gt_state2") == "steady"


def test_reports_corrupt_and_skipped_counts(tmp_path, awkward):
    from mcap.reader import make_reader

    path = awkward[0]
    with open(path, "rb") as f:
        chunks = sorted((c.chunk_start_offset, c.chunk_length)
                        for c in make_reader(f).get_summary().chunk_indexes)
    start, length = chunks[len(chunks) // 2]
    bad = tmp_path / "damaged.mcap"
    data = bytearray(path.read_bytes())
    data[start + length // 2:start + length // 2 + 64] = bytes(64)   # corrupt one chunk in the middle
    bad.write_bytes(bytes(data))
    mem = load_run(bad)
    rep = ingest_to_parquet(bad, tmp_path / "damaged.parquet", chunk_s=CHUNK_S)
    assert sum(rep.corrupt_per_topic().values()) > 0
    assert rep.corrupt_per_topic() == mem.report.corrupt_per_topic()
    assert rep.topics == mem.report.topics
    meta = read_run_parquet(tmp_path / "damaged.parquet").attrs["terrainml"]
    assert meta["corrupt_per_topic"] == rep.corrupt_per_topic()


def test_cli_ingest_streams_and_refuses_unusable(tmp_path, awkward):
    path = awkward[0]
    out = tmp_path / "cli.parquet"
    res = CliRunner().invoke(app, ["ingest", str(path), "--out", str(out), "--chunk-s", "0.7"])
    assert res.exit_code == 0, res.output
    got = read_run_parquet(out)
    np.testing.assert_allclose(got["imu_ax_mps2"], awkward[1].table["imu_ax_mps2"], atol=1e-9, equal_nan=True)
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not a log at all")
    res = CliRunner().invoke(app, ["ingest", str(junk), "--out", str(tmp_path / "j.parquet")])
    assert res.exit_code == 2 and "junk.mcap" in res.output and not (tmp_path / "j.parquet").exists()


@pytest.mark.parametrize("period_ms", [5.0, 10.0, 11.0, 50.0])
def test_streamed_gap_threshold_equals_whole_series_median(period_ms):
    """The scan's constant-memory median period == resample.gap_threshold_s on the whole series
    (jittered stamps, duplicates, a mix of periods around the base period, fed in pieces)."""
    from terrainml.io.ingest.resample import clean_times, gap_threshold_s

    rng = np.random.default_rng(int(period_ms))
    for trial in range(20):
        n = int(rng.integers(2, 400))
        steps = rng.choice([period_ms, 10.0, 12.0, 0.0], size=n, p=[0.55, 0.2, 0.2, 0.05])
        t_ns = (np.cumsum(steps + rng.normal(0, 0.3, n) * (steps > 0)) * 1e6).astype(np.int64)
        t_ns = np.maximum.accumulate(t_ns) + 1_700_000_000_000_000_000
        s = logs.Series(base_ns=1e9 / 100.0)
        for piece in np.array_split(t_ns, int(rng.integers(1, 6))):
            s.add(piece)
        order, _, dups = clean_times(t_ns)
        want = gap_threshold_s((t_ns[order] - t_ns[0]) * 1e-9, 100.0)
        assert s.in_order and s.duplicates == dups
        assert s.gap_s(100.0) == pytest.approx(want, rel=1e-9, abs=1e-12), (trial, n)
