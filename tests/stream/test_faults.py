"""Fault handling of the online predictor (each fault a test)."""

from __future__ import annotations

import json
import logging
import math
import socket

import numpy as np
import pytest
from stream_fakes import FakeClassifier, FakeEstimator, make_samples

from terrainml.stream.app.runner import serve
from terrainml.stream.tick.sample import InvalidSample
from terrainml.stream.transports.sinks import GuardedSink
from terrainml.stream.transports.sources import SourceCounters, iter_udp_samples


def _strict_json(msg):
    """Serialise and parse back, refusing NaN/Infinity tokens."""
    text = msg.to_json()

    def bad(tok):
        raise AssertionError(f"non-finite token {tok} in {text}")

    return json.loads(text, parse_constant=bad)


def _run(pred, samples):
    return [m for m in (pred.step(s) for s in samples) if m is not None]


def test_startup_fallback_until_first_steady_window(robot, fake_predictor):
    pred = fake_predictor()
    # 1 s standing still (no steady window possible), then 4 s cruising on class 3
    samples = make_samples(robot, 1.0, speed_mps=0.0, slip=0.0) + make_samples(robot, 4.0, t0=1.0)
    out = _run(pred, samples)
    first_ok = next(m for m in out if not m.fallback)
    before = [m for m in out if m.t_s < first_ok.t_s]
    assert before and all(m.fallback and m.fallback_reason == "no_classification" for m in before)
    assert all(m.classification_age_s == -1.0 for m in before)
    # the first classification needs a full 2 s window of cruising: not before t = 1 + 2 s
    assert first_ok.t_s >= 2.99
    assert first_ok.terrain_class == 3 and first_ok.terrain_name == "gravel_on_firm_soil"
    assert all(not m.fallback for m in out if m.t_s >= first_ok.t_s)


@pytest.mark.parametrize("group,cols", [
    ("imu", ["imu_ax_mps2", "imu_ay_mps2", "imu_az_mps2", "imu_yaw_rate_radps"]),
    ("cam", ["cam_vx_mps", "cam_vy_mps", "cam_yaw_rate_radps", "cam_yaw_rad"]),
    ("current", ["wheel1_current_a", "wheel2_current_a", "wheel3_current_a"]),
])
def test_silent_group_marks_unhealthy_within_0p2s(robot, fake_predictor, group, cols):
    pred = fake_predictor()
    samples = make_samples(robot, 8.0)
    t_off, t_on = 5.0, 5.5  # the group is silent for 0.5 s
    for s in samples:
        if t_off <= s["t_s"] < t_on:
            for c in cols:
                s.pop(c, None)  # the topic stops publishing: the columns are absent
    out = _run(pred, samples)
    ok_before = [m for m in out if 4.0 <= m.t_s < t_off]
    assert ok_before and all(m.estimator_ok and not m.fallback for m in ok_before)
    # last fresh sample at 4.99 s; unhealthy must be flagged no later than 0.2 s into the silence
    flagged = [m for m in out if t_off <= m.t_s < t_on and not m.estimator_ok]
    assert flagged, "silence never detected"
    assert flagged[0].t_s <= t_off + 0.2 + 1e-9
    assert all(not m.estimator_ok and m.fallback and m.fallback_reason == "estimator_unhealthy"
               and m.terrain_class == -1 and m.terrain_name == "none"
               for m in out if t_off + 0.2 <= m.t_s < t_on)
    # short of the 0.2 s threshold the estimator is still trusted
    assert all(m.estimator_ok for m in out if t_off <= m.t_s < t_off + 0.18)
    # the safe cap is what is served while unhealthy: in steady, the largest traction target of
    # the classes (FakeTable: 0.1 + 0.05 * 7 = 0.45)
    m = next(m for m in out if t_off + 0.3 <= m.t_s)
    assert m.slip_desired == pytest.approx([0.45] * robot.n_wheels)
    # health returns when the group publishes again
    assert all(m.estimator_ok for m in out if m.t_s >= t_on + 0.01)


def test_nan_bursts_never_reach_output(robot, fake_predictor):
    rng = np.random.default_rng(1)
    pred = fake_predictor(estimator=FakeEstimator(robot, nan_at=range(300, 320)))
    samples = make_samples(robot, 6.0)
    keys = [k for k in samples[0] if k not in ("t_s", "terrain")]
    samples[200]["imu_yaw_rad"] = "garbage"  # an optional column with a string
    for start in (150, 410, 480):  # three 10-tick bursts of NaN / inf / strings in random columns
        for s in samples[start:start + 10]:
            for k in rng.choice(keys, size=5, replace=False):
                s[k] = rng.choice([math.nan, math.inf, -math.inf, "nan", None])
    out = _run(pred, samples)
    assert len(out) == len(samples)
    for m in out:
        d = _strict_json(m)
        for v in d["slip_desired"] + d["slip_measured"] + d["class_probabilities"]:
            assert math.isfinite(v)
        assert math.isfinite(d["confidence"]) and math.isfinite(d["classification_age_s"])
    # the estimator's own NaN output (ticks 300-319) is replaced, and flagged
    assert all(m.slip_measured == [0.0] * 3 for m in out[299:319])


def test_out_of_order_and_duplicate_timestamps_dropped_and_counted(robot, fake_predictor):
    pred = fake_predictor()
    samples = make_samples(robot, 3.0)
    stream = list(samples)
    stream.insert(100, dict(samples[99]))          # duplicate
    stream.insert(200, dict(samples[150]))         # late (out of order)
    stream.insert(250, dict(samples[248]))         # late
    stream.insert(251, dict(samples[249]))         # duplicate of a sample just accepted
    stream.insert(10, {**samples[5], "t_s": float("nan")})  # unusable time stamp
    out = []
    for s in stream:
        try:
            m = pred.step(s)
        except InvalidSample as exc:  # the documented error, counted as bad_time
            assert math.isnan(s["t_s"]) and exc.reason == "t_s_not_finite"
            continue
        if m is not None:
            out.append(m)
    ts = [m.t_s for m in out]
    assert ts == [s["t_s"] for s in samples]  # every original tick once, in order
    assert [m.seq for m in out] == list(range(len(samples)))
    st = pred.stats()
    assert st["out_of_order"] == 2
    assert st["duplicate"] == 2
    assert st["bad_time"] == 1


def test_classifier_raising_gives_fallback_not_crash(robot, fake_predictor, caplog):
    clf = FakeClassifier(raise_on_calls={3, 4})
    pred = fake_predictor(classifier=clf)
    with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
        out = _run(pred, make_samples(robot, 6.0))
    assert len(out) == 600
    bad = [m for m in out if m.fallback_reason == "classifier_error"]
    assert bad and all(m.fallback and m.terrain_class == -1 for m in bad)
    # calls 1, 2 succeed (t = 1.99, 2.49), 3 and 4 raise (t = 2.99, 3.49), 5 succeeds (t = 3.99)
    assert bad[0].t_s == pytest.approx(2.99) and bad[-1].t_s == pytest.approx(3.98)
    assert not out[-1].fallback and out[-1].terrain_class == 3
    assert "classification failed" in caplog.text


def test_classifier_returning_garbage_is_a_classifier_error(robot, fake_predictor):
    class Garbage(FakeClassifier):
        def classify(self, window):
            return np.full(8, np.nan)

    pred = fake_predictor(classifier=Garbage())
    out = _run(pred, make_samples(robot, 3.0))
    assert out[-1].fallback_reason == "classifier_error"
    assert all(math.isfinite(p) for p in out[-1].class_probabilities)


def test_classification_is_held_while_standing_still(robot, fake_predictor):
    """Cruise 3 s (classified), stand still 10 s, drive on: the class is served throughout.

    The terrain under a standing robot does not change, so the classification ages by distance
    travelled, not time (design §11); no window exists while standing still.
    """
    pred = fake_predictor()
    samples = (make_samples(robot, 3.0)
               + make_samples(robot, 10.0, speed_mps=0.0, slip=0.0, t0=3.0)
               + make_samples(robot, 3.0, t0=13.0))
    out = _run(pred, samples)
    first_ok = next(m for m in out if not m.fallback)
    after = [m for m in out if m.t_s >= first_ok.t_s]
    assert all(not m.fallback and m.terrain_class == 3 for m in after)
    standing = [m for m in out if 4.0 <= m.t_s < 13.0]
    assert standing and max(m.classification_age_s for m in standing) > 9.0  # 9 s old, still served


def test_stale_after_distance_without_classification(robot, fake_predictor):
    """With no new classification the class goes stale after stale_m metres, not seconds."""

    class OnlyFirst(FakeClassifier):  # classifies the first windows, then never again
        def classify(self, window):
            return super().classify(window) if self.calls < 2 else None

    pred = fake_predictor(classifier=OnlyFirst(), stale_m=3.0)
    out = _run(pred, make_samples(robot, 12.0, speed_mps=1.0))
    last_ok = max(m.t_s for m in out if not m.fallback)
    first_stale = next(m for m in out if m.fallback_reason == "stale_classification")
    # the last classification is at t = 1.99 (window end) or 2.49 s, 1 m/s: stale 3 m later
    assert first_stale.t_s == pytest.approx(last_ok + 0.01)
    assert 4.9 <= first_stale.t_s <= 5.6
    assert first_stale.terrain_class == -1 and first_stale.terrain_name == "none"



def test_malformed_udp_datagrams_counted_and_skipped():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    port = rx.getsockname()[1]
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    good = [json.dumps({"t_s": k * 0.01, "imu_ax_mps2": 0.1}).encode() for k in range(5)]
    bad = [b"not json", b"[1, 2, 3]", b'{"imu_ax_mps2": 1}', b'{"t_s": NaN}', b'{"t_s": "x"}',
           b"\xff\xfe\x00", b""]
    for d in [good[0], bad[0], good[1], bad[1], bad[2], good[2], bad[3], bad[4], good[3], bad[5],
              bad[6], good[4], b'{"eos": true}']:
        tx.sendto(d, ("127.0.0.1", port))
    counters = SourceCounters()
    got = list(iter_udp_samples(counters=counters, idle_timeout_s=2.0, sock=rx))
    assert [s.t_s for s in got] == [k * 0.01 for k in range(5)]
    assert counters.malformed == len(bad)
    tx.close()


def test_sink_down_is_logged_and_predictor_continues(robot, fake_predictor, caplog):
    import can

    from terrainml.stream.transports.sinks import CanSink

    received = []

    class ListSink:
        name = "list"

        def send(self, m, sample=None):
            received.append(m)

        def close(self):
            pass

    down = CanSink("virtual", "test_sink_down")
    down.bus.shutdown()  # the bus goes away: every send raises
    with pytest.raises(can.CanError):
        down.bus.send(can.Message(arbitration_id=1, data=b"\0"))
    guarded = GuardedSink(down)
    pred = fake_predictor()
    with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
        n = serve(pred, make_samples(robot, 2.0), [guarded, GuardedSink(ListSink())])
    assert n == 200 and len(received) == 200
    assert guarded.errors == 200
    assert "sink can://virtual/test_sink_down failed" in caplog.text


def test_background_classification_is_deterministic_and_lagged(robot, fake_predictor):
    """classify_lag_ticks=L: same decisions as inline, applied exactly L ticks later."""
    samples = make_samples(robot, 1.0, speed_mps=0.0, slip=0.0) + make_samples(robot, 5.0, t0=1.0)
    inline = _run(fake_predictor(), samples)
    pred = fake_predictor(classifier=FakeClassifier(raise_on_calls={4}), classify_lag_ticks=10)
    lagged = _run(pred, samples)
    pred.close()
    first_inline = next(m.seq for m in inline if not m.fallback)
    first_lagged = next(m.seq for m in lagged if not m.fallback)
    assert first_lagged == first_inline + 10
    # the age counts from the window's last tick, so it is >= the lag when applied
    assert lagged[first_lagged].classification_age_s == pytest.approx(0.10)
    err = [m for m in lagged if m.fallback_reason == "classifier_error"]
    # calls at 1.99, 2.49 (unsteady), 2.99 (ok), 3.49 (raises) -> error served from 3.59 s
    assert err and err[0].t_s == pytest.approx(3.49 + 0.10)
    assert not lagged[-1].fallback and lagged[-1].terrain_class == 3


def test_estimator_raising_is_an_unhealthy_tick_not_a_crash(robot, fake_predictor):
    class Flaky(FakeEstimator):
        def step(self, s):
            if 400 <= self.k < 410:
                self.k += 1
                raise FloatingPointError("singular covariance (test)")
            return super().step(s)

    pred = fake_predictor(estimator=Flaky(robot))
    out = _run(pred, make_samples(robot, 6.0))
    assert len(out) == 600
    bad = out[400:410]
    assert all(not m.estimator_ok and m.fallback_reason == "estimator_unhealthy" for m in bad)
    assert out[-1].estimator_ok and not out[-1].fallback
    assert pred.stats()["estimator_errors"] == 10


class _DriftingLateralEstimator(FakeEstimator):
    """A wheels-only EKF on fixed wheels: v_x right, the unobserved lateral speed drifting away."""

    def step(self, s):
        row = super().step({**s, "cam_vx_mps": 0.5})        # v_x = 0.5 m/s, observed
        row["ekf_vy_mps"] = 50.0 * self.k / 100.0   # grows 50 m/s per second of log
        return row


def test_odometer_ignores_an_unobserved_lateral_speed():
    """Husky (fixed wheels) served without IMU: 10 s at 0.5 m/s is 5 m of travel (hand value),
    not the drifting v_y's kilometres; with the IMU monitored v_y counts again."""
    from terrainml.robot import load_robot
    from terrainml.stream.tick.predictor import Predictor
    from stream_fakes import FakeTable

    husky = load_robot("husky")
    samples = [{"t_s": k / 100.0,
                **{f"wheel{i}_omega_radps": 0.5 / husky.wheel_radius_m for i in range(1, 5)},
                **{f"wheel{i}_current_a": 1.0 for i in range(1, 5)},
                "imu_ax_mps2": 0.0, "imu_ay_mps2": 0.0, "imu_az_mps2": 9.81,
                "imu_yaw_rate_radps": 0.0} for k in range(1001)]
    wheels_only = Predictor(husky, FakeTable(), FakeClassifier(), _DriftingLateralEstimator(husky),
                            sensors=["wheels", "currents"])
    _run(wheels_only, samples)
    assert wheels_only.odometer_m == pytest.approx(5.0, rel=1e-6)
    with_imu = Predictor(husky, FakeTable(), FakeClassifier(), _DriftingLateralEstimator(husky),
                         sensors=["wheels", "currents", "imu"])
    _run(with_imu, samples)
    assert with_imu.odometer_m > 100.0


@pytest.mark.parametrize("gap_s,rate_hz", [(1.0, 100.0), (60.0, 100.0), (600.0, 10.0)])
def test_recovers_from_an_all_null_gap_of_any_length(robot, gap_s, rate_hz):
    """Every sensor null for 1 s, 60 s or 10 min (past ~55 s the EKF covariance
    stayed past the health limit for good): good samples are served healthy within 2 s, and
    classified again once a full window of them is in."""
    from stream_fakes import FakeTable

    from terrainml.stream.tick.predictor import Predictor

    pred = Predictor(robot, FakeTable(), FakeClassifier())  # the real OnlineEstimator
    good = make_samples(robot, 5.0)
    out = _run(pred, good)
    assert out[-1].estimator_ok and not out[-1].fallback
    n_gap = int(round(gap_s * rate_hz))
    sensors = [k for k in good[0] if k not in ("t_s", "terrain")]
    for k in range(n_gap):  # the 10 min gap at 10 Hz: the clock policy allows steps up to 1 s
        s = dict.fromkeys(sensors)
        s.update(t_s=round(5.0 + k / rate_hz, 6), terrain=3)
        pred.step(s)
    t_back = round(5.0 + n_gap / rate_hz, 6)
    after = _run(pred, make_samples(robot, 6.0, t0=t_back, seed=1))
    healthy = [m for m in after if m.t_s <= t_back + 2.0 and m.estimator_ok]
    assert healthy, f"not healthy within 2 s after a {gap_s} s gap"
    # once healthy it stays healthy, and measured slip is the simulated 0.1 again
    first = healthy[0].t_s
    assert all(m.estimator_ok for m in after if m.t_s >= first)
    late = [m for m in after if m.t_s >= t_back + 1.0]
    assert all(m.slip_measured == pytest.approx([0.1] * robot.n_wheels, abs=0.02) for m in late)
    # a full 2 s window later the terrain is served again
    assert any(not m.fallback and m.terrain_class == 3 for m in after if m.t_s >= t_back + 3.0)


def test_a_missing_group_is_named_live_at_start_and_when_it_goes(robot, fake_predictor, caplog):
    """A group absent from the start, and one that stops later, are each
    named on the log the tick they pass the 0.2 s limit, and again when they return."""
    imu = ["imu_ax_mps2", "imu_ay_mps2", "imu_az_mps2", "imu_yaw_rate_radps"]
    cur = [f"wheel{i}_current_a" for i in range(1, robot.n_wheels + 1)]
    samples = make_samples(robot, 3.0)
    for s in samples:
        if s["t_s"] < 1.0:
            for c in imu:
                s.pop(c)          # no IMU for the first second
        if 2.0 <= s["t_s"] < 2.5:
            for c in cur:
                s.pop(c)          # currents stop for 0.5 s
    pred = fake_predictor()
    with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
        out = _run(pred, samples)
    said = [r.getMessage() for r in caplog.records if "sensor group" in r.getMessage()]
    assert len(said) == 4, said
    assert "'imu' silent at t=0.210 s" in said[0] and "never seen" in said[0] and "imu_ax_mps2" in said[0]
    assert "'imu' fresh again at t=1.000 s" in said[1]
    assert "'current' silent at t=2.200 s" in said[2] and "last fresh at t=1.990 s" in said[2]
    assert "'current' fresh again at t=2.500 s" in said[3]
    assert pred.stats()["silent_episodes"] == {"imu": 1, "current": 1}
    assert not any(m.estimator_ok for m in out if 0.21 <= m.t_s < 1.0)


def test_a_group_its_source_flags_invalid_is_said_flagged_not_silent(robot, fake_predictor, caplog):
    """Tracking-camera values that arrive finite with ``cam_valid`` false (a T265 confidence below
    the map's ``min_confidence``) make the estimator unhealthy as any invalid group does, but the
    log says the source flagged them: the topic is publishing, it is not silent."""
    samples = make_samples(robot, 2.0)
    for s in samples:
        s["cam_valid"] = not (0.5 <= s["t_s"] < 1.2)
    pred = fake_predictor()
    with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
        out = _run(pred, samples)
    said = [r.getMessage() for r in caplog.records if "sensor group" in r.getMessage()]
    assert len(said) == 2, said
    assert "'cam' flagged invalid by its source at t=0.700 s" in said[0] and "silent" not in said[0]
    assert "'cam' valid again at t=1.200 s" in said[1]
    assert not any(m.estimator_ok for m in out if 0.71 <= m.t_s < 1.2)
    assert all(m.estimator_ok for m in out if m.t_s >= 1.2)


def test_predict_on_a_log_without_imu_names_the_missing_topic(tmp_path, model_dir, capsys):
    """A log with wheels but no IMU was served as 3,001 estimator_unhealthy
    ticks with nothing on stderr naming /imu."""
    from terrainml.io import topics
    from terrainml.io.mcap_writer import RosMcapWriter
    from terrainml.stream.app.options import ServeOptions
    from terrainml.stream.app.runner import run_predict

    path = tmp_path / "noimu.mcap"
    with RosMcapWriter(path, 3) as w:
        for k in range(300):
            t = k / 100
            w.write_wheel_joints(t, [1.0 / 0.165] * 3, [0.0] * 3)
            w.write_motor_current(t, [1.0] * 3)
    assert run_predict(ServeOptions(model=model_dir, source=str(path), sinks=("stdout",))) == 0
    err = capsys.readouterr().err
    assert topics.IMU in err and "not in the log" in err
    assert "sensor group 'imu' silent" in err and "never seen" in err
