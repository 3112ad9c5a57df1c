"""The per-tick producer (live streams) against the ingest engine's chunk producer, column by column.

Both are fed the same decoded messages of a simulated log, damaged on purpose (a sensor gap, a
hole of every sensor, swapped and duplicated stamps, low T265 confidence, non-finite wheel speeds,
a turning drive whose yaw wraps); the per-tick rows must equal the ingest table's to 1e-9 (floats;
validity, labels and wheel states exactly), whatever the delivery pattern (message by message,
bursts).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from terrainml.io.ingest.logs import Scan, plan, produce
from terrainml.io.ingest.ingest_report import IngestReport
from terrainml.io.ingest.resample import at_tick, resample
from terrainml.io.ingest.ticks import TickProducer
from terrainml.io.readers import read_mcap
from terrainml.io.topicmap import load_topic_map
from terrainml.robot import load_robot
from terrainml.sim.generate import simulate
from terrainml.sim.output import write_mcap

RATE = 100.0


class _Parts:
    """Decoded messages as the engine's log interface (as the live aligner's warm-up log)."""

    kept = True

    def __init__(self, parts):
        self.path, self.parts = "sim", parts

    def read(self, on_part, topics=None):
        for topic, p in self.parts:
            if topics is None or topic in topics:
                on_part(topic, p)

    def release(self):
        pass


class _Frames:
    def __init__(self):
        self.chunks = []

    def write(self, chunk):
        self.chunks.append(chunk)


def _plan(parts, tmap, robot):
    scan = Scan(tmap, robot, RATE, None)
    for topic, p in parts:
        scan.on_part(topic, p)
    scan.drain()
    rep = IngestReport(source="sim", format="mcap", rate_hz=RATE)
    for topic in scan.topics:
        rep.topics[topic] = {"read": 0, "out_of_order": 0, "duplicates": 0, "non_finite": 0}
    return plan(scan, _Parts(parts), tmap, robot, RATE, rep)


def _messages(path, tmap):
    """One-row parts in log order (what the ROS 2 source hands the aligner)."""
    parts = []
    read_mcap(path, lambda topic, type_name: tmap.by_topic()[topic].decode_kind if topic in tmap.by_topic()
              else None, use_header_stamp=True, on_part=lambda topic, p: parts.append((topic, p)))
    rows = []
    for topic, p in parts:
        for i in range(len(p["t_ns"])):
            rows.append((topic, {k: (v[i:i + 1].copy() if isinstance(v, np.ndarray) else v) for k, v in p.items()}))
    rows.sort(key=lambda r: int(r[1]["t_ns"][0]))
    return rows


def _near_the_wrap(rows):
    """The IMU and ground-truth orientations turned about z so that their yaw crosses +-pi."""
    yaw = [Rotation.from_quat(p["orientation"][0]).as_euler("ZYX")[0] for tp, p in rows if tp == "/imu"]
    turn = Rotation.from_euler("z", (math.pi - 0.2) * np.sign(yaw[-1] - yaw[0]) - yaw[0])
    return [(tp, {**p, "orientation": (turn * Rotation.from_quat(p["orientation"])).as_quat()})
            if tp in ("/imu", "/sim/ground_truth") else (tp, p) for tp, p in rows]


def _damage(rows):
    """Gap, hole, swapped and duplicated stamps, low confidence, non-finite wheel speeds, yaw wrap."""
    rows = _near_the_wrap(rows)
    t0 = int(rows[0][1]["t_ns"][0])
    rel = [(int(p["t_ns"][0]) - t0) * 1e-9 for _, p in rows]
    out = []
    for (topic, p), t in zip(rows, rel):
        if topic == "/imu" and 2.0 < t < 2.3:
            continue                                          # an IMU gap
        if 4.0 < t < 4.4 and topic != "/terrain/label":
            continue                                          # every sensor silent: a hole
        if topic == "/camera/odom/sample" and 5.0 < t < 5.5:
            p = {**p, "cov0": np.zeros_like(p["cov0"])}       # low T265 confidence
        if topic == "/wheels/joint_states" and 6.0 < t < 6.05:
            p = {**p, "velocity": np.full_like(p["velocity"], np.nan)}
        out.append((topic, p))
        if topic == "/imu" and 7.0 < t < 7.05:
            out.append((topic, {**p, "accel": p["accel"] + 1.0}))   # a duplicate stamp: first kept
    for i in range(len(out) - 1):                             # swapped IMU pairs (out of order)
        if out[i][0] == "/imu" and i % 97 == 0:
            j = next((k for k in range(i + 1, min(i + 12, len(out))) if out[k][0] == "/imu"), None)
            if j is not None:
                out[i], out[j] = out[j], out[i]
    return out


@pytest.fixture(scope="module")
def arc_rows(tmp_path_factory):
    path = tmp_path_factory.mktemp("ticks") / "arc.mcap"
    write_mcap(simulate("dry_sand", "arc", duration_s=12.0, seed=5), path)
    return _messages(path, load_topic_map(None))


def _table(rows, tmap, robot):
    frames = _Frames()
    p = _plan(rows, tmap, robot)
    produce(_Parts(rows), p, tmap, robot, RATE, frames)
    assert len(frames.chunks) == 1
    return frames.chunks[0]


def _ticks(rows, tmap, robot, burst):
    p = _plan(rows, tmap, robot)
    out = []
    prod = TickProducer(p, tmap, robot, RATE, out)
    for k, (topic, part) in enumerate(rows):
        prod.on_part(topic, part)
        if k % burst == 0:
            prod.drain(final=False)
    prod.drain(final=True)
    return out


def _assert_same(table, samples):
    assert len(samples) == len(table)
    assert list(samples[0]) == [str(c) for c in table.columns]
    for c in table.columns:
        want = table[c].to_numpy()
        got = np.array([s[c] for s in samples], dtype=want.dtype)
        if want.dtype.kind == "f":
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-9, equal_nan=True, err_msg=c)
        else:
            assert (got == want).all(), c


@pytest.mark.parametrize("burst", [1, 7, 400])
def test_tick_rows_equal_the_ingest_table_column_by_column(arc_rows, burst):
    tmap, robot = load_topic_map(None), load_robot()
    rows = _damage(arc_rows)
    table = _table(rows, tmap, robot)
    samples = _ticks(rows, tmap, robot, burst)
    _assert_same(table, samples)
    # the damage is there: an IMU gap, a hole with no label held, low confidence, yaw wrapping
    t = table["t_s"].to_numpy()
    assert not table["imu_valid"].to_numpy()[(t > 2.1) & (t < 2.2)].any()
    assert (table["terrain"].to_numpy()[(t > 4.2) & (t < 4.3)] == -1).all()
    assert not table["cam_valid"].to_numpy()[(t > 5.1) & (t < 5.4)].any()
    yaw = table["imu_yaw_rad"].to_numpy()
    assert np.nanmax(np.abs(np.diff(yaw))) > math.pi


def test_one_tick_rules_equal_resample():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.002, 0.05, 60))
    v = rng.uniform(-4, 4, 60)
    v[[5, 17]] = np.nan
    grid = np.linspace(t[0] - 0.05, t[-1] + 0.05, 700)
    grid = np.concatenate([grid, t[:10]])          # ticks exactly on samples
    for method in ("linear", "previous", "angle"):
        want, ok = resample(t, v, grid, method=method, max_gap_s=0.03)
        for g, w, k in zip(grid, want, ok):
            i = int(np.searchsorted(t, g + 1e-9, side="right"))
            got, gok = at_tick(float(g), float(t[i - 1]) if i else None, float(v[i - 1]) if i else math.nan,
                               float(t[i]) if i < len(t) else None, float(v[i]) if i < len(t) else math.nan,
                               method, 0.03)
            assert gok == k, (method, g)
            if method == "angle":   # the array's unwrap accumulates multiples of 2 pi: rounding differs
                assert (math.isnan(got) and math.isnan(w)) or abs(got - w) <= 1e-12, (method, g)
            else:                   # the same floating-point operations: bit for bit
                assert got == w or (math.isnan(got) and math.isnan(w)), (method, g)

