"""Hostile input never stops the stream ("One input line can kill the stream").

The parser of ``terrainml predict``'s UDP / stdin sources counts every malformed datagram or line
by reason and skips it; ``Predictor.step`` raises only ``InvalidSample`` on what is not a sample.
Explicit cases first (each one of the issue's), then property-based tests (hypothesis).
"""

from __future__ import annotations

import io
import json
import math
import socket
from decimal import Decimal
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from stream_fakes import FakeClassifier, FakeEstimator, FakeTable, make_samples

from terrainml.estimation.online import OnlineEstimator
from terrainml.stream.tick.message import DesiredSlip
from terrainml.stream.tick.config import ServingConfig
from terrainml.stream.tick.predictor import Predictor
from terrainml.stream.app.runner import serve
from terrainml.stream.tick.sample import InvalidSample
from terrainml.stream.transports.sources import (MALFORMED_REASONS, MAX_DEPTH, MAX_SAMPLE_BYTES, SourceCounters,
                                      _EOS, iter_line_samples, iter_udp_samples, parse_sample)

# modest example counts (seconds, not minutes), no example database in the working tree
FAST = settings(max_examples=100, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

GOOD = {"t_s": 1.0, "imu_ax_mps2": 0.1}
HUGE = 10 ** 400  # an int no float can hold


def _strict(msg: DesiredSlip) -> dict:
    """The message as JSON, refusing NaN / Infinity tokens."""
    def bad(tok):
        raise AssertionError(f"non-finite token {tok}")

    d = json.loads(msg.to_json(), parse_constant=bad)
    for v in d["slip_desired"] + d["slip_measured"] + d["class_probabilities"]:
        assert math.isfinite(v)
    return d


def _reason(data) -> str | None:
    """The malformed reason parse_sample counts for ``data`` (None: accepted)."""
    c = SourceCounters()
    out = parse_sample(data, c)
    if out is None:
        assert c.malformed == 1 and sum(c.malformed_by_reason.values()) == 1
        (reason,) = c.malformed_by_reason
        return reason
    assert c.malformed == 0
    return None


# --------------------------------------------------------------------------- explicit cases
@pytest.mark.parametrize("data", [b"[" * 1100, "[" * 1100, b"{\"a\":" * 1100, b"[" * 100_000])
def test_deep_nesting_is_malformed_not_a_recursion_error(data):
    reason = _reason(data)
    assert reason in ("too_deep", "too_large")
    assert _reason(b"[" * 1100 + b"]" * 1100) == "too_deep"
    assert _reason(json.dumps({"t_s": 1.0, "x": [[[1]]]})) is None  # shallow nesting is fine
    assert _reason(json.dumps({"t_s": 1.0, "s": "[" * 5000})) is None  # brackets inside a string


@pytest.mark.parametrize("line", [
    '{"t_s": %d}' % HUGE,                                   # in t_s
    '{"t_s": 1.0, "imu_ax_mps2": %d}' % HUGE,               # in a field
    '{"t_s": 1.0, "my_extra": %d}' % HUGE,                  # in an unknown key
    '{"t_s": 1.0, "x": [1, 2, -%d]}' % HUGE,                # inside a list
    '{"t_s": 1e400}', '{"t_s": 1.0, "imu_ax_mps2": -1e999}',  # floats beyond range
    '{"t_s": 1.0, "x": %s}' % ("9" * 5000),                 # beyond int()'s digit limit
])
def test_number_beyond_float_range_is_malformed(line):
    assert _reason(line) == "number_out_of_range"
    assert _reason(line.encode()) == "number_out_of_range"


@pytest.mark.parametrize("data,reason", [
    (b'{"t_s": NaN}', "non_finite"), (b'{"t_s": 1.0, "imu_ax_mps2": Infinity}', "non_finite"),
    (b'{"t_s": 1.0, "imu_ax_mps2": -Infinity}', "non_finite"),
    (b"\xff\xfe\x00garbage", "not_utf8"), (bytes(range(256)), "not_utf8"),
    (b"not json", "not_json"), (b"", "not_json"), (b'{"t_s": 1.0', "not_json"),
    (b"[1, 2, 3]", "not_an_object"), (b"3.5", "not_an_object"), (b'"t_s"', "not_an_object"),
    (b"null", "not_an_object"),
    (b'{"imu_ax_mps2": 1}', "no_t_s"), (b'{"t_s": "1.0"}', "bad_t_s"), (b'{"t_s": true}', "bad_t_s"),
    (b'{"t_s": null}', "bad_t_s"), (b'{"t_s": [1.0]}', "bad_t_s"),
    (b'{"t_s": 1.0, "pad": "' + b"x" * MAX_SAMPLE_BYTES + b'"}', "too_large"),
])
def test_each_malformed_input_is_counted_by_reason(data, reason):
    assert reason in MALFORMED_REASONS
    assert _reason(data) == reason


def test_wrong_types_inside_a_sample_only_invalidate_their_group():
    # a string or a list where a number belongs is a well-formed sample: health invalidates it
    s = parse_sample(json.dumps({"t_s": 1.0, "imu_ax_mps2": "abc", "wheel1_omega_radps": [1]}))
    assert isinstance(s, dict) and s["imu_ax_mps2"] == "abc"
    assert parse_sample(b'{"eos": true}') is _EOS
    assert parse_sample(b"\xef\xbb\xbf" + json.dumps(GOOD).encode()) == GOOD  # UTF-8 BOM


def test_hostile_lines_on_stdin_are_skipped_and_serving_continues(robot):
    good = make_samples(robot, 1.0)
    hostile = [b"[" * 1100, b'{"t_s": %d}' % HUGE, b'{"t_s": 1.0, "imu_ax_mps2": %d}' % HUGE,
               b'{"t_s": 1.0, "zz": %d}' % HUGE, b"\x00\xff\xfe binary \x80", b'{"t_s": NaN}',
               b"x" * (5 * MAX_SAMPLE_BYTES),  # one over-long line, read in bounded pieces
               b'{"t_s": "0.5"}', b"[]"]
    lines = []
    for k, s in enumerate(good):
        lines.append(json.dumps(s).encode())
        if k % 10 == 5:
            lines.append(hostile[(k // 10) % len(hostile)])
    counters = SourceCounters()
    got = list(iter_line_samples(io.BytesIO(b"\n".join(lines) + b"\n"), counters=counters))
    assert [s.t_s for s in got] == [s["t_s"] for s in good]
    assert counters.malformed == 10 and counters.received == len(lines)
    assert set(counters.malformed_by_reason) == {"too_deep", "number_out_of_range", "not_utf8",
                                                 "non_finite", "too_large", "bad_t_s", "not_an_object"}
    pred = Predictor(robot, FakeTable(), FakeClassifier(), FakeEstimator(robot))
    assert serve(pred, got, []) == len(good)


def test_hostile_udp_datagrams_are_skipped():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 2**20)
    rx.bind(("127.0.0.1", 0))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent = [b"[" * 1100, json.dumps({"t_s": 0.0}).encode(), b'{"t_s": %d}' % HUGE,
            b'{"t_s": 0.01, "f": %d}' % HUGE, json.dumps({"t_s": 0.01}).encode(), b"\x80\x81",
            b"{" * 60000, json.dumps({"t_s": 0.02}).encode(), b'{"eos": true}']
    for d in sent:
        tx.sendto(d, rx.getsockname())
    counters = SourceCounters()
    got = list(iter_udp_samples(counters=counters, idle_timeout_s=2.0, sock=rx))
    tx.close()
    assert [s.t_s for s in got] == [0.0, 0.01, 0.02]
    assert counters.malformed == 5
    assert counters.malformed_by_reason == {"too_deep": 1, "number_out_of_range": 2, "not_utf8": 1,
                                            "too_large": 1}


@pytest.mark.parametrize("bad,reason", [
    (None, "not_a_mapping"), ("t_s=1.0", "not_a_mapping"), ([("t_s", 1.0)], "not_a_mapping"),
    (42, "not_a_mapping"), ({1: 2.0, "t_s": 1.0}, "bad_key"), ({}, "no_t_s"),
    ({"t_s": "1.0"}, "bad_t_s"), ({"t_s": True}, "bad_t_s"), ({"t_s": None}, "bad_t_s"),
    ({"t_s": Decimal("1.0")}, "bad_t_s"), ({"t_s": [1.0]}, "bad_t_s"),
    ({"t_s": math.nan}, "t_s_not_finite"), ({"t_s": -math.inf}, "t_s_not_finite"),
    ({"t_s": HUGE}, "t_s_not_finite"), ({"t_s": np.float64("nan")}, "t_s_not_finite"),
])
def test_step_raises_only_invalid_sample_and_counts_it(fake_predictor, bad, reason):
    pred = fake_predictor()
    assert pred.step({"t_s": 0.5}) is not None
    with pytest.raises(InvalidSample) as err:
        pred.step(bad)
    assert err.value.reason == reason and isinstance(err.value, ValueError)
    st_ = pred.stats()
    assert st_["bad_time"] + st_["not_a_sample"] == 1
    assert st_["bad_time" if reason.startswith(("t_s", "no_t", "bad_t")) else "not_a_sample"] == 1
    assert pred.step({"t_s": 0.51}).seq == 1  # state untouched: the next tick follows on


def test_step_accepts_numpy_and_fraction_stamps(fake_predictor):
    pred = fake_predictor()
    assert pred.step({"t_s": np.float32(0.5)}).t_s == pytest.approx(0.5)
    assert pred.step({"t_s": np.int64(1)}).t_s == 1.0
    assert pred.step({"t_s": Fraction(3, 2)}).t_s == 1.5


def test_huge_and_odd_values_in_fields_never_reach_the_output(robot, fake_predictor):
    pred = fake_predictor()
    samples = make_samples(robot, 3.0)
    odd = [HUGE, -HUGE, "1e999", [1.0], {"a": 1}, b"\x00", 1 + 2j, Decimal("sNaN"), np.array([1, 2]),
           np.float64("inf"), None, True]
    for k, s in enumerate(samples[50:62]):
        for key in ("imu_ax_mps2", "wheel2_omega_radps", "cam_vx_mps", "imu_valid", "run_id",
                    "gt_vx_mps", "terrain", "an_extra", "cmd_valid", "steer_valid"):
            s[key] = odd[k]
    out = [pred.step(s) for s in samples]
    assert all(m is not None for m in out)
    for m in out:
        _strict(m)
    assert out[-1].estimator_ok


def test_runner_counts_invalid_samples_and_goes_on(robot, fake_predictor):
    pred = fake_predictor()
    samples = make_samples(robot, 2.0)
    stream = list(samples)
    for k, bad in enumerate([None, "x", [], {"t_s": "1"}, {"t_s": math.nan}, {3: 1}]):
        stream.insert(20 * k + 7, bad)
    assert serve(pred, stream, []) == len(samples)
    st_ = pred.stats()
    assert st_["not_a_sample"] == 4 and st_["bad_time"] == 2


# --------------------------------------------------------------------------- property-based
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.integers(min_value=-HUGE, max_value=HUGE)
    | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=10), inner, max_size=5),
    max_leaves=30)


def _check_parsed(data, counters):
    before = (counters.received, counters.malformed)
    out = parse_sample(data, counters)  # must not raise, whatever data is
    assert counters.received == before[0] + 1
    if out is None:
        assert counters.malformed == before[1] + 1
        assert set(counters.malformed_by_reason) <= set(MALFORMED_REASONS)
    elif out is not _EOS:
        assert isinstance(out, dict) and isinstance(out["t_s"], (int, float))
        assert not isinstance(out["t_s"], bool) and math.isfinite(out["t_s"])
        _assert_finite_numbers(out)
    return out


def _assert_finite_numbers(v):
    if isinstance(v, float):
        assert math.isfinite(v)
    elif isinstance(v, int) and not isinstance(v, bool):
        assert math.isfinite(float(v))
    elif isinstance(v, dict):
        for x in v.values():
            _assert_finite_numbers(x)
    elif isinstance(v, list):
        for x in v:
            _assert_finite_numbers(x)


@FAST
@given(st.binary(max_size=2000))
def test_parser_never_raises_on_bytes(data):
    _check_parsed(data, SourceCounters())


@FAST
@given(st.text(max_size=2000))
def test_parser_never_raises_on_text(text):
    c = SourceCounters()
    _check_parsed(text, c)
    _check_parsed(text.encode("utf-8", "surrogatepass"), c)


@FAST
@given(json_values, st.one_of(st.none(), json_values))
def test_parser_never_raises_on_json(value, t_s):
    c = SourceCounters()
    obj = {"t_s": t_s, "v": value} if t_s is not None else value
    _check_parsed(json.dumps(obj), c)  # allow_nan: NaN / Infinity tokens appear too
    _check_parsed(json.dumps(obj).encode(), c)


@FAST
@given(st.integers(1, 3 * MAX_DEPTH), st.sampled_from(["[", '{"a":', '{"t_s": 1, "x":']),
       st.booleans())
def test_parser_nesting_limit(depth, opener, closed):
    closer = {"[": "]", '{"a":': "}", '{"t_s": 1, "x":': "}"}[opener]
    text = opener * depth + ("1" + closer * depth if closed else "")
    out = _check_parsed(text, SourceCounters())
    if depth > MAX_DEPTH:
        assert out is None


@FAST
@given(st.binary(min_size=1, max_size=40), st.integers(0, 200))
def test_parser_never_raises_on_damaged_samples(junk, at):
    line = json.dumps({"t_s": 1.25, "imu_ax_mps2": 0.1, "wheel1_omega_radps": 3.0}).encode()
    at = min(at, len(line))
    _check_parsed(line[:at] + junk + line[at:], SourceCounters())


def _odd_values():
    return (st.none() | st.booleans() | st.integers() | st.integers(min_value=-HUGE, max_value=HUGE)
            | st.floats() | st.text(max_size=8) | st.binary(max_size=8)
            | st.complex_numbers(allow_nan=True) | st.decimals() | st.fractions()
            | st.lists(st.floats(), max_size=3) | st.dictionaries(st.text(max_size=3), st.floats(), max_size=2)
            | st.floats().map(np.float64) | st.integers(-2**63, 2**63 - 1).map(np.int64)
            | st.lists(st.floats(), max_size=3).map(np.array) | st.sampled_from([np.bool_(True), np.nan]))


_KEYS = ["t_s", "imu_ax_mps2", "imu_ay_mps2", "imu_az_mps2", "imu_yaw_rate_radps", "cam_vx_mps",
         "cam_vy_mps", "cam_yaw_rate_radps", "cam_yaw_rad", "wheel1_omega_radps", "wheel2_steer_rad",
         "wheel3_current_a", "imu_valid", "cam_valid", "wheels_valid", "steer_valid", "cmd_valid",
         "run_id", "gt_vx_mps", "gt_state1", "terrain", "cam_confidence", "eos"]
samples_or_junk = st.one_of(
    st.dictionaries(st.sampled_from(_KEYS) | st.text(max_size=6), _odd_values(), max_size=12),
    st.dictionaries(st.integers() | st.none() | st.text(max_size=3), _odd_values(), max_size=3),
    st.fixed_dictionaries({"t_s": st.floats(-1e12, 1e12) | st.integers(-2**70, 2**70)},
                          optional={k: _odd_values() for k in _KEYS[1:]}),
    _odd_values(), st.text(max_size=5), st.lists(_odd_values(), max_size=3))


def _step_all(pred, samples) -> None:
    """Step ``pred`` through ``samples``: only InvalidSample may escape, every message served is strict."""
    for x in samples:
        try:
            m = pred.step(x)
        except InvalidSample:
            continue
        if m is not None:
            _strict(m)


@settings(max_examples=40, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.lists(samples_or_junk, min_size=1, max_size=25))
def test_step_raises_nothing_but_invalid_sample(robot, junk):
    """Arbitrary inputs, then a clean stream: only InvalidSample escapes, never a wedge."""
    pred = Predictor(robot, FakeTable(), FakeClassifier(), FakeEstimator(robot),
                     config=ServingConfig(reanchor_after=3))
    _step_all(pred, junk)
    clean = make_samples(robot, 2.5, t0=1e6)
    out = [pred.step(s) for s in clean]
    # at most max_clock_gap_s (1 s) of late samples is dropped, then every sample is a tick;
    # clock_jump only until K = 3 consistent samples re-anchor
    assert sum(m is None for m in out) <= 100 and out[-1] is not None
    served = [m for m in out if m is not None]
    for m in served:
        _strict(m)
    assert all(m.fallback_reason != "clock_jump" for m in served[2:])
    assert served[-1].estimator_ok


@settings(max_examples=25, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.lists(samples_or_junk, min_size=1, max_size=10))
def test_step_with_the_real_estimator_raises_nothing_but_invalid_sample(robot, junk):
    pred = Predictor(robot, FakeTable(), FakeClassifier(), OnlineEstimator(robot))
    _step_all(pred, junk + make_samples(robot, 0.1))


@pytest.mark.parametrize("column,value,group", [
    ("wheel2_current_a", 1e308, "current"), ("wheel1_current_a", -1e308, "current"),
    ("wheel3_current_a", 1001.0, "current"), ("wheel1_omega_radps", 5e3, "wheels"),
    ("imu_ax_mps2", -2e3, "imu"), ("cam_vx_mps", 150.0, "cam"), ("wheel2_steer_rad", 1e5, "steer"),
])
def test_a_finite_value_beyond_physics_invalidates_its_group(robot, column, value, group):
    """A finite ±1e308 current passed the sample check; each channel has a
    physical limit (1000 A, 1000 rad/s, 1000 m/s^2, 100 m/s, 1e4 rad) past which its group is
    invalid, counted per column; a value inside the limit passes."""
    from terrainml.stream.tick.health import HealthMonitor, InputCounters

    mon = HealthMonitor(robot)
    mon.counters = InputCounters()
    s = make_samples(robot, 0.01)[0]
    s[column] = value
    clean, fresh = mon.sanitise(s)
    assert not fresh[group] and clean[f"{group}_valid"] is False and math.isnan(clean[column])
    assert all(fresh[g] for g in ("wheels", "steer", "current", "imu", "cam") if g != group)
    assert mon.counters.out_of_range == {column: 1}
    s[column] = math.copysign(999.0 if group in ("current", "wheels", "imu") else 99.0, value)
    assert mon.sanitise(s)[1][group]


def test_huge_current_never_reaches_the_features(model_dir):
    """The real chain (EKF, windows, features, SVM): currents of ±1e308 for 1 s of a 6 s drive give
    no numpy warning, every message finite, and classifications before and after."""
    import warnings

    from terrainml.testing import kinematic_run, trapezoid_speed
    from terrainml.robot import load_robot
    from terrainml.stream.tick.predictor import Predictor
    from terrainml.stream.transports.sources import iter_table_samples

    robot = load_robot()
    table = kinematic_run(robot, duration_s=8.0, slip=0.12, terrain=2, seed=3, imu_acc_noise=0.005,
                          vx=lambda t: trapezoid_speed(t, 1.0, 1.0, 0.5), run_id="huge")
    samples = [dict(s.columns) for s in iter_table_samples(table)]   # altered below
    for s in samples:
        if 3.0 <= s["t_s"] < 4.0:
            s["wheel1_current_a"], s["wheel2_current_a"] = 1e308, -1e308
    pred = Predictor.from_model_dir(model_dir)
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # an overflow in the features would raise here
        out = [pred.step(s) for s in samples]
    for m in out:
        _strict(m)
    st_ = pred.stats()
    assert st_["out_of_range"] == {"wheel1_current_a": 100}
    assert st_["classifier_errors"] == 0 and st_["classifications"] > 0


def test_wheel_keys_beyond_the_robot_are_counted_and_warned(robot, fake_predictor, caplog):
    """A stream with ``wheel4_*`` keys was served as three wheels silently."""
    import logging

    pred = fake_predictor()
    samples = make_samples(robot, 1.0)
    for s in samples:
        s["wheel4_omega_radps"], s["wheel4_current_a"] = 6.0, 3.0
        s["wheel" + "9" * 5000 + "_x"] = 1.0   # too many digits for int(): still just a key
    with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
        out = [pred.step(s) for s in samples]
    assert all(m is not None for m in out)
    said = [r.getMessage() for r in caplog.records if "names a wheel" in r.getMessage()]
    assert len(said) == 3 and "'wheel4_omega_radps'" in said[0] and "(3 wheels)" in said[0]
    assert pred.stats()["unknown_wheel_keys"]["wheel4_current_a"] == 100
    assert len(out[-1].slip_desired) == robot.n_wheels


def test_serving_robot_that_differs_from_the_training_robot_is_warned(model_dir, tmp_path, caplog):
    """Twice the wheel radius and three times the mass were served silently."""
    import logging

    from terrainml.robot import RobotSpec, load_robot
    from terrainml.stream.tick.classify import load_serving_model

    trained = load_robot()
    d = trained.to_dict()
    d.update(name="bigger", wheel_radius_m=2 * trained.wheel_radius_m, mass_kg=3 * trained.mass_kg)
    with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
        load_serving_model(model_dir, robot=RobotSpec.from_dict(d))
        said = [r.getMessage() for r in caplog.records if "differs from the model's" in r.getMessage()]
        assert len(said) == 1
        assert f"mass_kg {3 * trained.mass_kg} vs {trained.mass_kg} (x3)" in said[0]
        assert f"wheel_radius_m {2 * trained.wheel_radius_m} vs {trained.wheel_radius_m} (x2)" in said[0]
        assert str(model_dir) in said[0] and "'bigger'" in said[0]
        caplog.clear()
        load_serving_model(model_dir, robot=load_robot())   # the same robot: nothing said
        assert not [r for r in caplog.records if "differs" in r.getMessage()]
