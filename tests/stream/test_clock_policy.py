"""The clock policy ("One bad timestamp wedges or silences it"): stream/tick/clock.py.

A wild stamp costs one ``clock_jump`` tick; an absurd first stamp, a forward jump and a backward
step re-anchor after K consistent samples; the stream never wedges, every tick is served with
finite numbers, and a warning is logged when the jump happens. The real ``OnlineEstimator`` runs
here (the wedge of the issue was its state after a huge ``dt``).
"""

from __future__ import annotations

import json
import logging
import math

import pytest
from stream_fakes import FakeClassifier, FakeTable, make_samples

from terrainml.stream.tick.clock import ACCEPT, DUPLICATE, JUMP, LATE, REANCHOR, ClockGate
from terrainml.stream.tick.message import DesiredSlip
from terrainml.stream.tick.config import ServingConfig
from terrainml.stream.tick.predictor import Predictor
from terrainml.stream.transports.sinks import REASON_CODES, decode_can_frames, encode_can_frames

K = 5  # the default reanchor_after


@pytest.fixture
def real_predictor(robot):
    """The real estimator (built by the predictor, so re-anchoring gets a fresh one)."""
    def make(**kw):
        return Predictor(robot, FakeTable(), FakeClassifier(), config=ServingConfig(**kw))

    return make


def _finite(m: DesiredSlip) -> None:
    def bad(tok):
        raise AssertionError(f"non-finite token {tok}")

    d = json.loads(m.to_json(), parse_constant=bad)
    assert all(math.isfinite(v) for v in d["slip_desired"] + d["slip_measured"] + d["class_probabilities"])


def _serve_all(pred, stream):
    out = []
    for s in stream:
        m = pred.step(s)
        if m is not None:
            _finite(m)
            out.append(m)
    return out


def _recovered(out, t_from):
    """Every tick from t_from on is healthy and serves the driven class (3) without fallback."""
    tail = [m for m in out if m.t_s >= t_from]
    assert tail, "nothing served after recovery time"
    assert all(m.estimator_ok and not m.fallback and m.terrain_class == 3 for m in tail)


def test_a_single_wild_stamp_costs_one_clock_jump_tick(robot, real_predictor, caplog):
    pred = real_predictor()
    samples = make_samples(robot, 20.0)
    stream = samples[:101] + [{**samples[100], "t_s": 1e12}] + samples[101:]
    assert len(stream) == 2001
    with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
        out = []
        for k, s in enumerate(stream):
            out.append(pred.step(s))
            if k == 100:
                assert "clock jump" not in caplog.text
            if k == 101:  # said when it happens, not at exit
                assert "clock jump: t=1e+12 s" in caplog.text
    assert all(m is not None for m in out)  # 2001 of 2001 served (was 101)
    for m in out:
        _finite(m)
    spike = out[101]
    assert spike.t_s == 1e12 and spike.fallback and spike.fallback_reason == "clock_jump"
    assert not spike.estimator_ok and spike.terrain_class == -1 and spike.classification_age_s == -1.0
    assert [m.fallback_reason for m in out].count("clock_jump") == 1
    st = pred.stats()
    assert st["clock_jump"] == 1 and st["reanchors"] == 0 and st["out_of_order"] == 0
    assert st["emitted"] == 2001 and [m.seq for m in out] == list(range(2001))
    _recovered(out[:101] + out[102:], 4.0)


@pytest.mark.parametrize("first_t", [-1e12, 1e12, -5.0])
def test_an_absurd_first_stamp_reanchors_after_k_samples(robot, real_predictor, caplog, first_t):
    pred = real_predictor()
    samples = make_samples(robot, 8.0)
    with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
        out = _serve_all(pred, [{**samples[0], "t_s": first_t}] + samples)
    assert len(out) == 1 + len(samples)  # one message per tick throughout
    assert [m.fallback_reason for m in out[1:K]] == ["clock_jump"] * (K - 1)
    assert out[K].fallback_reason != "clock_jump" and out[K].t_s == samples[K - 1]["t_s"]
    assert pred.stats()["reanchors"] == 1 and pred.stats()["clock_jump"] == K - 1
    assert "re-anchored" in caplog.text
    _recovered(out[1:], samples[K - 1]["t_s"] + 3.0)  # estimator fresh, a window classified


@pytest.mark.parametrize("jump_s", [1.7e9, 60.0, 1.5, -1.7e9, -60.0, -3.0])
def test_a_clock_jump_either_way_reanchors_and_recovers(robot, real_predictor, caplog, jump_s):
    pred = real_predictor()
    before = make_samples(robot, 6.0)
    after = make_samples(robot, 8.0, t0=6.0 + jump_s, seed=1)
    with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
        out = _serve_all(pred, before + after)
    assert len(out) == len(before) + len(after)
    assert all(m.fallback_reason != "clock_jump" for m in out[:len(before)])
    jumped = out[len(before):]
    assert [m.fallback_reason for m in jumped[:K - 1]] == ["clock_jump"] * (K - 1)
    assert all(not m.estimator_ok and m.fallback for m in jumped[:K - 1])
    assert all(m.fallback_reason != "clock_jump" for m in jumped[K - 1:])
    st = pred.stats()
    assert st["reanchors"] == 1 and st["clock_jump"] == K - 1 and st["out_of_order"] == 0
    assert "clock jump" in caplog.text and "re-anchored" in caplog.text
    # never wedged: healthy and classified again once a new window has filled
    _recovered(jumped, after[K - 1]["t_s"] + 3.0)


def test_a_small_backward_step_drops_at_most_max_gap_and_never_reanchors(robot, real_predictor):
    pred = real_predictor()
    before = make_samples(robot, 6.0)
    after = make_samples(robot, 6.0, t0=5.5, seed=1)  # the source steps back 0.5 s
    out = _serve_all(pred, before + after)
    st = pred.stats()
    assert st["out_of_order"] + st["duplicate"] == 50 and st["reanchors"] == 0
    assert st["clock_jump"] == 0
    assert len(out) == len(before) + len(after) - 50
    _recovered(out, 8.0)


def test_alternating_wild_stamps_never_wedge(robot, real_predictor):
    pred = real_predictor()
    samples = make_samples(robot, 6.0)
    stream = []
    for k, s in enumerate(samples):
        stream.append(s)
        if k % 7 == 3:
            stream.append({**s, "t_s": (-1) ** k * 10.0 ** (3 + k % 9)})
    out = _serve_all(pred, stream)
    assert len(out) == len(stream)
    assert pred.stats()["reanchors"] == 0
    normal = [m for m in out if m.fallback_reason != "clock_jump"]
    assert [m.t_s for m in normal] == [s["t_s"] for s in samples]
    assert normal[-1].estimator_ok and normal[-1].terrain_class == 3


def test_k_is_configurable(robot, fake_predictor):
    samples = make_samples(robot, 1.0)
    for k_ in (1, 3, 10):
        pred = fake_predictor(reanchor_after=k_)
        out = _serve_all(pred, samples[:10] + make_samples(robot, 1.0, t0=500.0))
        assert [m.fallback_reason for m in out[10:10 + k_]].count("clock_jump") == k_ - 1
        assert pred.stats()["reanchors"] == 1
    for bad in (0, -1, 2.5, True):
        with pytest.raises(ValueError, match="reanchor_after"):
            fake_predictor(reanchor_after=bad)
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="max_gap_s"):
            fake_predictor(max_clock_gap_s=bad)


def test_clock_gate_verdicts():
    g = ClockGate(max_gap_s=1.0, reanchor_after=3)
    assert [g.check(t) for t in (0.0, 0.01, 0.01, 0.005, 1.01, 1.0)] == [
        ACCEPT, ACCEPT, DUPLICATE, LATE, ACCEPT, LATE]
    # off the timeline: jump, duplicate of the candidate, jump, re-anchor on the 3rd
    assert [g.check(t) for t in (50.0, 50.0, 50.5, 51.0, 51.1)] == [
        JUMP, DUPLICATE, JUMP, REANCHOR, ACCEPT]
    # an inconsistent candidate starts over; a stamp back on the timeline ends it
    assert [g.check(t) for t in (-9.0, 99.0, 51.2, -5.0, -4.9, -4.8)] == [
        JUMP, JUMP, ACCEPT, JUMP, JUMP, REANCHOR]
    c = g.counters
    assert (c.clock_jump, c.reanchors, c.duplicate, c.out_of_order) == (6, 2, 2, 2)


def test_clock_jump_has_a_can_reason_code():
    assert REASON_CODES["clock_jump"] == 5
    assert [REASON_CODES[r] for r in ("estimator_unhealthy", "classifier_error", "no_classification",
                                      "stale_classification")] == [1, 2, 3, 4]  # codes never move
    msg = DesiredSlip(t_s=1e12, seq=7, slip_desired=[0.005, 0.0, -0.005], slip_measured=[0.0] * 3,
                      wheel_state=["steady", "idle", "steady"], terrain_class=0, terrain_name="pavement",
                      confidence=0.0, class_probabilities=[0.0] * 8, classification_age_s=-1.0,
                      fallback=True, fallback_reason="clock_jump", estimator_ok=False)
    back = decode_can_frames(encode_can_frames(msg))
    assert back["fallback_reason"] == "clock_jump" and back["fallback"] and not back["estimator_ok"]
