"""The DesiredSlip message and the sinks: JSON never NaN, CAN layout, MCAP for Foxglove, UDP."""

from __future__ import annotations

import io
import json
import math
import socket

import pytest

from terrainml.stream.tick.message import FIELD_NAMES, DesiredSlip, json_schema
from terrainml.stream.transports.sinks import (decode_can_frames, encode_can_frames, open_sink, SinkError)

DESIGN_11_FIELDS = ["t_s", "seq", "slip_desired", "slip_measured", "wheel_state", "terrain_class",
                    "terrain_name", "confidence", "class_probabilities", "classification_age_s",
                    "fallback", "fallback_reason", "estimator_ok", "processing_ms"]
#: the fields that say which sensors served and why windows are rejected (design §11),
#: and the novelty score of the latest window
ADDED = ["fallback_detail", "sensors", "novelty"]


def _msg(**kw):
    d = dict(t_s=12.34, seq=7, slip_desired=[0.16, -0.2, 0.0], slip_measured=[0.1234, -0.05, 0.0],
             wheel_state=["traction", "braking", "idle"], terrain_class=2, terrain_name="short_grass",
             confidence=0.8, class_probabilities=[0.0, 0.1, 0.8, 0.1, 0, 0, 0, 0],
             classification_age_s=0.25, fallback=False, fallback_reason="", estimator_ok=True,
             processing_ms=0.4)
    d.update(kw)
    return DesiredSlip(**d)


def test_fields_are_those_of_system_11_and_the_three_added():
    assert list(FIELD_NAMES) == DESIGN_11_FIELDS + ADDED
    assert list(json.loads(_msg().to_json())) == DESIGN_11_FIELDS + ADDED
    assert json_schema(3, 8)["required"] == DESIGN_11_FIELDS + ADDED
    # a message written before they were added still reads, with their defaults
    old = {k: v for k, v in json.loads(_msg().to_json()).items() if k not in ADDED}
    back = DesiredSlip.from_dict(old)
    assert back.fallback_detail == "" and back.sensors == [] and back.novelty == -1.0


def test_windows_rejected_has_its_own_can_code_and_an_unknown_reason_is_63():
    for reason, code in (("windows_rejected", 7), ("uncertain_classification", 6), ("bogus", 63)):
        d = _msg(fallback=True, fallback_reason=reason).to_dict()
        flags = encode_can_frames(d)[0][1][6]
        assert flags >> 2 == code and flags & 1
    frames = encode_can_frames(_msg(fallback=True, fallback_reason="windows_rejected"))
    assert decode_can_frames(frames)["fallback_reason"] == "windows_rejected"


def test_unknown_terrain_is_can_code_8_and_its_novelty_is_in_the_json_only():
    m = _msg(fallback=True, fallback_reason="unknown_terrain", terrain_class=-1, terrain_name="none",
             novelty=3.25)
    frames = encode_can_frames(m)
    assert frames[0][1][6] >> 2 == 8 and frames[1][1][6] >> 2 == 8  # summary and wheel frames
    assert decode_can_frames(frames)["fallback_reason"] == "unknown_terrain"
    d = json.loads(m.to_json())
    assert d["fallback_reason"] == "unknown_terrain" and d["novelty"] == 3.25
    assert "unknown_terrain" in json_schema()["properties"]["fallback_reason"]["enum"]
    assert json.loads(_msg(novelty=math.nan).to_json())["novelty"] == -1.0  # never NaN


def test_non_finite_values_replaced_by_documented_safe_values():
    m = _msg(slip_desired=[math.nan, math.inf, 0.1], slip_measured=[-math.inf, 0.0, math.nan],
             confidence=math.nan, class_probabilities=[math.nan] * 8,
             classification_age_s=math.inf, processing_ms=math.nan, t_s=math.nan)
    text = m.to_json()
    assert "NaN" not in text and "Infinity" not in text
    d = json.loads(text)
    assert d["slip_desired"] == [0.0, 0.0, 0.1]
    assert d["slip_measured"] == [0.0, 0.0, 0.0]
    assert d["confidence"] == 0.0 and d["classification_age_s"] == -1.0
    assert d["class_probabilities"] == [0.0] * 8 and d["processing_ms"] == 0.0
    assert DesiredSlip.from_json(text).slip_desired == [0.0, 0.0, 0.1]


def test_can_frames_roundtrip_through_a_virtual_bus():
    import can

    m = _msg(fallback=True, fallback_reason="stale_classification", estimator_ok=True)
    sink = open_sink("can://virtual/test_can_roundtrip", n_wheels=3, n_classes=8)
    rx = can.Bus(interface="virtual", channel="test_can_roundtrip")
    sink.send(m)
    frames = []
    for _ in range(4):
        f = rx.recv(timeout=1.0)
        assert f is not None and not f.is_extended_id and len(f.data) == 8
        frames.append((f.arbitration_id, bytes(f.data)))
    sink.close()
    rx.shutdown()
    assert [fid for fid, _ in frames] == [0x300, 0x301, 0x302, 0x303]
    d = decode_can_frames(frames)
    assert d["slip_desired"] == [0.16, -0.2, 0.0]
    assert d["slip_measured"] == [0.1234, -0.05, 0.0]  # int16 x 1e4 keeps 4 decimals
    assert d["wheel_state"] == ["traction", "braking", "idle"]
    assert d["terrain_class"] == 2 and d["seq"] == 7
    assert d["fallback"] and d["estimator_ok"] and d["fallback_reason"] == "stale_classification"
    assert d["classification_age_s"] == 0.25 and d["confidence"] == pytest.approx(0.8)


def test_can_slip_saturates_instead_of_wrapping():
    frames = encode_can_frames(_msg(slip_desired=[5.0, -5.0, 1.0]))
    d = decode_can_frames(frames)
    assert d["slip_desired"] == [3.2767, -3.2767, 1.0]


def test_mcap_sink_writes_jsonschema_topic_foxglove_can_plot(tmp_path):
    from mcap.reader import make_reader

    path = tmp_path / "served.mcap"
    sink = open_sink(f"mcap:{path}", n_wheels=3, n_classes=8)
    for k in range(5):
        sink.send(_msg(seq=k, t_s=1.0 + 0.01 * k))
    sink.close()
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        msgs = list(reader.iter_messages())
    assert len(msgs) == 5
    schema, channel, message = msgs[0]
    assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
    assert channel.topic == "/terrainml/desired_slip"
    js = json.loads(schema.data)
    assert js["properties"]["slip_desired"]["maxItems"] == 3
    assert [json.loads(m[2].data)["seq"] for m in msgs] == list(range(5))
    assert msgs[1][2].log_time == 1_010_000_000


def test_udp_and_stdout_sinks():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(2.0)
    port = rx.getsockname()[1]
    sink = open_sink(f"udp://127.0.0.1:{port}")
    sink.send(_msg())
    assert json.loads(rx.recv(65535))["terrain_name"] == "short_grass"
    sink.close()
    rx.close()
    buf = io.StringIO()
    s = open_sink("stdout", stdout=buf)
    s.send(_msg(seq=1))
    s.send(_msg(seq=2))
    lines = buf.getvalue().splitlines()
    assert [json.loads(x)["seq"] for x in lines] == [1, 2]


@pytest.mark.parametrize("spec", ["tcp://x", "udp://host:notaport", "can://virtual", "mcap:"])
def test_bad_sink_spec_is_a_clear_error(spec):
    with pytest.raises(SinkError, match="sink|can://"):
        open_sink(spec)
