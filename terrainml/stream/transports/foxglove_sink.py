"""Live view of the served stream in Foxglove: a WebSocket server from foxglove-sdk (design §11).

``terrainml predict --sink foxglove://HOST:PORT`` (default ``127.0.0.1:8765``) serves every tick
on one channel, topic ``/terrainml/desired_slip``, JSON with a JSON schema (draft 2020-12, name
``terrainml.DesiredSlipLive``). The message is the MCAP sink's :class:`DesiredSlip` object (so a
layout made on a recording plots the same paths live) plus two views made for Foxglove's
standard panels::

    wheels                       [{wheel: 1.., slip_desired, slip_measured, state, state_code}]
    class_probabilities_by_name  {class name: probability of the last classification}

e.g. Plot ``/terrainml/desired_slip.wheels[0].slip_desired`` or
``/terrainml/desired_slip.class_probabilities_by_name.dry_sand``; State Transitions
``/terrainml/desired_slip.fallback_reason``, ``.terrain_name`` or ``.wheels[0].state``.
``state_code`` is the CAN sink's wheel state code (0 idle, 1 steady, 2 traction, 3 braking).

Log time is the wall clock when the tick is sent, not ``t_s``: a live view follows the
machine's clock, and a ``clock_jump`` tick (``t_s`` off the timeline) would otherwise throw the
viewer's timeline years ahead. ``t_s`` stays in the message (use it as the Plot's x axis).

A live view must never stop serving: if the port cannot be bound (in use, no such address) the
sink logs it, raises on every ``send`` (which :class:`~terrainml.stream.transports.sinks.GuardedSink`
counts) and retries binding every ``retry_s`` seconds. A client that connects, lags or drops is
the SDK's business: a slow client loses the oldest messages, never the predictor's time. With no
client subscribed a tick costs one call (nothing is serialised).
"""

from __future__ import annotations

import json
import logging
import time
from typing import Any, Callable, Sequence

import foxglove

from terrainml.classes import TERRAIN_CLASSES
from terrainml.io.topics import WHEEL_STATE_CODES
from terrainml.schema import WHEEL_STATES
from terrainml.stream.tick.message import TOPIC, DesiredSlip, json_schema
from terrainml.stream.tick.sample import NO_SAMPLE, Sample

log = logging.getLogger("terrainml.stream")

DEFAULT_FOXGLOVE_SINK = ("127.0.0.1", 8765)
SCHEMA_NAME = "terrainml.DesiredSlipLive"
RETRY_S = 2.0


class FoxgloveServerError(RuntimeError):
    """The Foxglove WebSocket server is not running (the message says why)."""


def class_names_for(n_classes: int | None, class_names: Sequence[str] | None = None) -> list[str]:
    """Names of class ids ``0..K-1``: ``class_names``, else the eight default classes.

    Ids without a name are called ``class_<id>``.
    """
    names = list(class_names) if class_names is not None else list(TERRAIN_CLASSES)
    k = len(names) if n_classes is None else int(n_classes)
    return [str(names[i]) if i < len(names) else f"class_{i}" for i in range(k)]


def live_schema(n_wheels: int | None = None, class_names: Sequence[str] | None = None) -> dict[str, Any]:
    """JSON schema of the live message: :func:`json_schema` plus ``wheels`` and the named probabilities."""
    names = class_names_for(None, class_names)
    schema = json_schema(n_wheels, len(names))
    schema["title"] = SCHEMA_NAME
    schema["description"] = "Per-wheel desired slip served by terrainml predict, live view (design §11)."
    wheel = {
        "type": "object",
        "properties": {
            "wheel": {"type": "integer", "minimum": 1, "description": "wheel number (wheel1 = 1)"},
            "slip_desired": {"type": "number", "description": "desired slip (signed)"},
            "slip_measured": {"type": ["number", "null"],
                              "description": "measured slip; null when not observable"},
            "state": {"type": "string", "enum": list(WHEEL_STATES), "description": "dynamic state"},
            "state_code": {"type": "integer", "enum": sorted(WHEEL_STATE_CODES.values()),
                           "description": "0 idle, 1 steady, 2 traction, 3 braking"},
        },
        "required": ["wheel", "slip_desired", "slip_measured", "state", "state_code"],
    }
    wheels: dict[str, Any] = {"type": "array", "items": wheel, "description": "one entry per wheel"}
    if n_wheels is not None:
        wheels["minItems"] = wheels["maxItems"] = int(n_wheels)
    schema["properties"]["wheels"] = wheels
    schema["properties"]["class_probabilities_by_name"] = {
        "type": "object",
        "properties": {n: {"type": "number", "minimum": 0, "maximum": 1} for n in names},
        "required": list(dict.fromkeys(names)),
        "description": "last classification's probabilities by class name (all 0 if none)",
    }
    schema["required"] = [*schema["required"], "wheels", "class_probabilities_by_name"]
    return schema


def live_message(msg: DesiredSlip, class_names: Sequence[str]) -> dict[str, Any]:
    """The live message of one tick (never NaN: built on :meth:`DesiredSlip.to_dict`)."""
    d = msg.to_dict()
    d["wheels"] = [
        {"wheel": i + 1, "slip_desired": sd, "slip_measured": sm, "state": st,
         "state_code": WHEEL_STATE_CODES.get(st, 0)}
        for i, (sd, sm, st) in enumerate(zip(d["slip_desired"], d["slip_measured"] or [None] * len(d["slip_desired"]),
                                             d["wheel_state"]))
    ]
    names = class_names_for(len(d["class_probabilities"]), class_names)
    d["class_probabilities_by_name"] = dict(zip(names, d["class_probabilities"]))
    return d


class FoxgloveSink:
    """DesiredSlip served live over the Foxglove WebSocket protocol (foxglove-sdk).

    Parameters
    ----------
    host, port : address to bind; port 0 picks a free one (read it back from ``port``).
    n_wheels : N, fixes the length of the per-wheel arrays in the schema (None: any).
    class_names : names of class ids 0..K-1 (default: the eight classes of design §6.1).
    retry_s : s, wall time between attempts to bind the port while it fails.
    clock_ns : wall clock for the log time, ns (injectable for tests).
    """

    def __init__(self, host: str = DEFAULT_FOXGLOVE_SINK[0], port: int = DEFAULT_FOXGLOVE_SINK[1],
                 n_wheels: int | None = None, class_names: Sequence[str] | None = None,
                 retry_s: float = RETRY_S, clock_ns: Callable[[], int] = time.time_ns):
        self.host, self.requested_port = host, int(port)
        self.class_names = class_names_for(None, class_names)
        self.retry_s = float(retry_s)
        self.clock_ns = clock_ns
        self.name = f"foxglove://{host}:{self.requested_port}"
        # a context of its own: the SDK's global context would mix our channel with any other
        # user of foxglove in the process (and with a second sink's)
        self.context = foxglove.Context()
        self.channel = foxglove.Channel(TOPIC, schema=live_schema(n_wheels, self.class_names),
                                        context=self.context)
        self.server: Any = None
        self._error = ""
        self._next_try = 0.0
        try:
            self._start()
        except FoxgloveServerError as exc:
            log.warning("%s (the predictor goes on)", exc)

    @property
    def port(self) -> int | None:
        """The bound port, None while the server is down."""
        return None if self.server is None else int(self.server.port)

    def _start(self) -> None:
        now = time.monotonic()
        if now < self._next_try:
            raise FoxgloveServerError(self._error)
        try:
            self.server = foxglove.start_server(name="terrainml predict", host=self.host,
                                                port=self.requested_port, context=self.context)
        except Exception as exc:  # noqa: BLE001 - the SDK raises RuntimeError(FoxgloveError: ...)
            self._next_try = now + self.retry_s
            self._error = (f"{self.name}: cannot start the Foxglove WebSocket server ({exc}); "
                           f"retrying every {self.retry_s:g} s")
            raise FoxgloveServerError(self._error) from None
        self.name = f"foxglove://{self.host}:{self.server.port}"
        log.info("%s: Foxglove live view ready (open connection -> Foxglove WebSocket -> ws://%s:%d)",
                 self.name, self.host, self.server.port)

    def send(self, msg: DesiredSlip, sample: Sample = NO_SAMPLE) -> None:
        if self.server is None:
            self._start()
        if not self.channel.has_sinks():  # nobody subscribed: skip the serialisation
            return
        data = json.dumps(live_message(msg, self.class_names), separators=(",", ":"), allow_nan=False)
        self.channel.log(data.encode(), log_time=int(self.clock_ns()))

    def close(self) -> None:
        self.channel.close()
        if self.server is not None:
            self.server.stop()
            self.server = None
