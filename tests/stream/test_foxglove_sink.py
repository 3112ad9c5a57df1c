"""Live view in Foxglove: a WebSocket client on 127.0.0.1 receives the served stream.

The client speaks the Foxglove WebSocket protocol by hand (the subprotocol foxglove-sdk 0.30
serves is ``foxglove.sdk.v1``): JSON ``serverInfo`` and ``advertise`` text messages, a
``subscribe`` op, then binary message-data frames ``0x01 | uint32 subscription id | uint64 log
time ns | payload``. Expected values are written out from the message fields, not computed by
the sink's code. Loopback only, every wait bounded by a few seconds.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import socket
import struct
import subprocess
import sys
import threading
import time

import jsonschema
import pytest
from test_cli_e2e import _drive, _wait_ready
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from terrainml.classes import TERRAIN_CLASSES
from terrainml.stream.transports.foxglove_sink import FoxgloveSink, live_message, live_schema
from terrainml.stream.tick.message import DesiredSlip
from terrainml.stream.transports.sinks import GuardedSink, SinkError, open_sink

pytestmark = pytest.mark.timeout(60)

SUBPROTOCOL = "foxglove.sdk.v1"
WAIT_S = 5.0
TOPIC = "/terrainml/desired_slip"
NAMES = ["pavement", "short_grass", "dry_sand", "wet_mud"]


def _msg(**kw) -> DesiredSlip:
    d = dict(t_s=12.34, seq=0, slip_desired=[0.16, -0.2, 0.0], slip_measured=[0.1234, -0.05, 0.0],
             wheel_state=["traction", "braking", "idle"], terrain_class=2, terrain_name="dry_sand",
             confidence=0.8, class_probabilities=[0.0, 0.1, 0.8, 0.1], classification_age_s=0.25,
             fallback=False, fallback_reason="", estimator_ok=True, processing_ms=0.4)
    d.update(kw)
    return DesiredSlip(**d)


async def _recv_json(ws, op: str) -> dict:
    """The next text message with this op (others, e.g. status, are skipped)."""
    while True:
        m = await asyncio.wait_for(ws.recv(), WAIT_S)
        if isinstance(m, str) and json.loads(m).get("op") == op:
            return json.loads(m)


async def _wait_subscribed(channel) -> None:
    t_end = time.monotonic() + WAIT_S
    while not channel.has_sinks():
        assert time.monotonic() < t_end, "the server never registered the subscription"
        await asyncio.sleep(0.01)


async def _session(port: int, sink: GuardedSink, msgs: list[DesiredSlip]):
    """Connect, subscribe to the topic, push ``msgs`` through ``sink``; return what arrived."""
    async with connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], proxy=None,
                       open_timeout=WAIT_S, close_timeout=WAIT_S) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        info = await _recv_json(ws, "serverInfo")
        adv = await _recv_json(ws, "advertise")
        (chan,) = [c for c in adv["channels"] if c["topic"] == TOPIC]
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": chan["id"]}]}))
        await _wait_subscribed(sink.sink.channel)
        t0_ns = time.time_ns()
        for m in msgs:
            sink.send(m)
        t1_ns = time.time_ns()
        frames = []
        while len(frames) < len(msgs):
            data = await asyncio.wait_for(ws.recv(), WAIT_S)
            if isinstance(data, bytes):
                op, sub_id, log_time_ns = struct.unpack_from("<BIQ", data)
                frames.append((op, sub_id, log_time_ns, json.loads(data[13:])))
    return info, chan, frames, (t0_ns, t1_ns)


def test_client_receives_the_stream_with_a_valid_schema():
    sink = open_sink("foxglove://127.0.0.1:0", n_wheels=3, n_classes=4, class_names=NAMES)
    try:
        port = sink.sink.port
        assert port and sink.name == f"foxglove://127.0.0.1:{port}"
        msgs = [_msg(seq=0, t_s=1.00),
                _msg(seq=1, t_s=1.01, slip_desired=[0.05, 0.05, 0.05], wheel_state=["steady"] * 3),
                _msg(seq=2, t_s=1.02, fallback=True, fallback_reason="stale_classification",
                     terrain_class=0, terrain_name="pavement", confidence=0.0,
                     classification_age_s=1.5)]
        info, chan, frames, (t0_ns, t1_ns) = asyncio.run(_session(port, sink, msgs))

        # schema: valid draft 2020-12 JSON Schema with the fields the panels need
        assert info["name"] == "terrainml predict"
        assert chan["encoding"] == "json" and chan["schemaEncoding"] == "jsonschema"
        schema = json.loads(chan["schema"])
        jsonschema.Draft202012Validator.check_schema(schema)
        props = schema["properties"]
        for f in ["t_s", "seq", "slip_desired", "slip_measured", "wheel_state", "terrain_class",
                  "terrain_name", "confidence", "class_probabilities", "classification_age_s",
                  "fallback", "fallback_reason", "estimator_ok", "processing_ms", "wheels",
                  "class_probabilities_by_name"]:
            assert f in props and f in schema["required"]
        wheel = props["wheels"]["items"]["properties"]
        assert wheel["slip_desired"]["type"] == "number"
        assert wheel["slip_measured"]["type"] == ["number", "null"]   # null: slip not observable
        assert wheel["state"]["enum"] == ["idle", "steady", "traction", "braking"]
        assert wheel["state_code"]["type"] == "integer"
        assert props["wheels"]["maxItems"] == 3
        assert sorted(props["class_probabilities_by_name"]["properties"]) == sorted(NAMES)
        assert "stale_classification" in props["fallback_reason"]["enum"]
        assert props["terrain_name"]["type"] == "string"

        # frames: message data on our subscription, wall-clock log time, payload valid and right
        validator = jsonschema.Draft202012Validator(schema)
        assert [f[0] for f in frames] == [0x01] * 3 and [f[1] for f in frames] == [7] * 3
        assert all(t0_ns <= f[2] <= t1_ns for f in frames)
        got = [f[3] for f in frames]
        for d in got:
            validator.validate(d)
        assert [d["seq"] for d in got] == [0, 1, 2] and [d["t_s"] for d in got] == [1.0, 1.01, 1.02]
        assert got[0]["wheels"] == [
            {"wheel": 1, "slip_desired": 0.16, "slip_measured": 0.1234, "state": "traction", "state_code": 2},
            {"wheel": 2, "slip_desired": -0.2, "slip_measured": -0.05, "state": "braking", "state_code": 3},
            {"wheel": 3, "slip_desired": 0.0, "slip_measured": 0.0, "state": "idle", "state_code": 0}]
        assert got[0]["class_probabilities_by_name"] == {"pavement": 0.0, "short_grass": 0.1,
                                                         "dry_sand": 0.8, "wet_mud": 0.1}
        assert got[0]["terrain_name"] == "dry_sand" and got[0]["confidence"] == 0.8
        assert not got[0]["fallback"] and got[0]["fallback_reason"] == ""
        assert got[0]["classification_age_s"] == 0.25
        assert [w["state_code"] for w in got[1]["wheels"]] == [1, 1, 1]
        assert [w["slip_desired"] for w in got[1]["wheels"]] == [0.05, 0.05, 0.05]
        assert got[2]["fallback"] and got[2]["fallback_reason"] == "stale_classification"
        assert got[2]["terrain_name"] == "pavement" and got[2]["classification_age_s"] == 1.5

        # the client has gone: serving goes on without errors
        for k in range(3, 10):
            sink.send(_msg(seq=k))
        assert sink.errors == 0 and sink.sent == 10
    finally:
        sink.close()


def test_second_sink_on_the_same_port_is_counted_never_raised(caplog):
    first = open_sink("foxglove://127.0.0.1:0", n_wheels=3, n_classes=4, class_names=NAMES)
    port = first.sink.port
    second = GuardedSink(FoxgloveSink("127.0.0.1", port, n_wheels=3, class_names=NAMES, retry_s=0.05))
    try:
        with caplog.at_level(logging.WARNING, logger="terrainml.stream"):
            assert second.sink.port is None
            for k in range(5):
                second.send(_msg(seq=k))  # must not raise
        assert second.errors == 5 and second.sent == 0
        text = caplog.text
        assert f"foxglove://127.0.0.1:{port}" in text
        assert "cannot start the Foxglove WebSocket server" in text and "in use" in text
        first.send(_msg())
        assert first.errors == 0 and first.sink.port == port

        # the port frees: the second sink binds it on a retry and serves
        first.close()
        t_end = time.monotonic() + WAIT_S
        while second.sink.port is None:
            assert time.monotonic() < t_end, "the second sink never took over the freed port"
            time.sleep(0.06)
            second.send(_msg())
        assert second.sink.port == port
        errors = second.errors
        second.send(_msg())
        assert second.errors == errors
    finally:
        first.close()
        second.close()


def test_a_message_without_measured_slip_fits_the_live_schema():
    """Slip not observable: ``slip_measured`` is null per wheel, and the schema allows it."""
    msg = _msg(slip_measured=[math.nan] * 3, slip_measured_note="no body-velocity reference")
    live = live_message(msg, NAMES)
    assert [w["slip_measured"] for w in live["wheels"]] == [None, None, None]
    jsonschema.validate(live, live_schema(3, NAMES), cls=jsonschema.Draft202012Validator)


@pytest.mark.parametrize("spec", ["foxglove://127.0.0.1:notaport", "foxglove://127.0.0.1:70000"])
def test_bad_foxglove_spec_is_a_clear_error(spec):
    with pytest.raises(SinkError, match="foxglove"):
        open_sink(spec)


@pytest.mark.acceptance
def test_predict_cli_serves_foxglove_with_the_models_class_names(model_dir):
    """`terrainml predict --sink foxglove://...` end to end: samples on stdin, a client on the port."""
    with socket.socket() as s:  # a free TCP port (the CLI prints no port it picked)
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    samples = _drive(5, 6.0)
    proc = subprocess.Popen([sys.executable, "-m", "terrainml.cli", "predict", "--model", str(model_dir),
                             "--source", "-", "--sink", f"foxglove://127.0.0.1:{port}"],
                            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    subscribed = threading.Event()

    def feed():  # start once the client has subscribed, paced so that it sees the stream live
        subscribed.wait(WAIT_S)
        time.sleep(0.2)
        for s in samples:
            proc.stdin.write(json.dumps(s) + "\n")
            proc.stdin.flush()
            time.sleep(0.0005)
        proc.stdin.close()

    async def client():
        async with connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], proxy=None,
                           open_timeout=WAIT_S) as ws:
            adv = await _recv_json(ws, "advertise")
            (chan,) = [c for c in adv["channels"] if c["topic"] == TOPIC]
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": chan["id"]}]}))
            subscribed.set()
            got = []
            while len(got) < len(samples):
                try:
                    data = await asyncio.wait_for(ws.recv(), WAIT_S)
                except (TimeoutError, ConnectionClosed):  # stream over: server gone or silent
                    break
                if isinstance(data, bytes):
                    got.append(json.loads(data[13:]))
            return json.loads(chan["schema"]), got

    try:
        _wait_ready(proc)
        feeder = threading.Thread(target=feed, daemon=True)
        feeder.start()
        schema, got = asyncio.run(client())
        feeder.join(WAIT_S)
        proc.wait(timeout=60)
        err = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "sink errors: 0" in err
    assert sorted(schema["properties"]["class_probabilities_by_name"]["properties"]) == sorted(TERRAIN_CLASSES)
    assert len(got) > 100, (len(got), err)
    seqs = [d["seq"] for d in got]
    assert seqs == list(range(seqs[0], seqs[0] + len(got)))  # in order, none lost on loopback
    assert all(len(d["wheels"]) == 3 and list(d["class_probabilities_by_name"]) == list(TERRAIN_CLASSES)
               for d in got)
    last = got[-1]  # the driven class (5, tilled_loam) is served once classified
    assert last["terrain_name"] == "tilled_loam" and last["class_probabilities_by_name"]["tilled_loam"] > 0.5
