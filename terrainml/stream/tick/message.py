"""The ``DesiredSlip`` message served once per base-rate tick (design §11).

Fields (units)
--------------
t_s                  float, s        time of the tick (the input sample's ``t_s``)
seq                  int             0, 1, 2, ... one per emitted tick (dropped samples emit nothing)
slip_desired         float[N]        per-wheel desired slip, signed (SAE, eq. 8.7-8.9); 0 when idle
slip_measured        float[N]        per-wheel measured slip from the estimator (design §7.1)
wheel_state          str[N]          ``idle|steady|traction|braking`` (design §7.2)
terrain_class        int             id of the served class; -1 in fallback (no class: the safe cap
                                     of design §10 is served; CAN 255)
terrain_name         str             name of that class; ``"none"`` in fallback
confidence           float, 0..1     fused (posterior) probability of the served class (0 in fallback)
class_probabilities  float[K]        probabilities of the last classification (all 0 if none)
classification_age_s float, s        age of the last classification; -1 when none exists yet
                                     (and on a ``clock_jump`` tick, whose time is off the timeline)
fallback             bool            True when the class-free safe cap is served (design §10)
fallback_reason      str             "" or one of :data:`FALLBACK_REASONS`
estimator_ok         bool            estimator healthy (no silent sensor group, finite state);
                                     false on a ``clock_jump`` tick (the estimator did not run)
processing_ms        float, ms       wall time spent on this tick inside the predictor
fallback_detail      str             for ``windows_rejected``: the window rule that rejected the
                                     most windows since the last classification, with the channels
                                     it found invalid (``"channel_valid: imu_wx"``); on a class served
                                     without terrain parameters (class-free safe cap, design §10)
                                     ``"class_free_targets: ..."``; else ""
sensors              str[]           sensor groups (``wheels``, ``currents``, ``imu``, ``cam``) of the
                                     model member serving the tick: the artifact's model, or the
                                     best member whose groups are healthy (design §11)
novelty              float           the latest classified window's novelty score over the model's
                                     threshold (> 1: unlike the training windows, the
                                     ground turns ``unknown_terrain`` after a few such windows);
                                     -1 when the model has no novelty scorer or no window is scored

slip_measured_note   str             only when slip is not observable (a live source whose topic map
                                     feeds no body-velocity reference): why; ``slip_measured`` is then
                                     null (absent) in JSON, "n/a" (-32768) on CAN, never 0.0

The last three are additions to design §11's field list (say which sensors served and
why the windows are rejected: how unlike the training windows the ground is); a
message without them (an older log) still reads. CAN carries ``unknown_terrain`` as reason code
8 but not ``novelty`` (its frames have no byte free; :mod:`terrainml.stream.transports.sinks`).

JSON never contains NaN or infinity. :meth:`DesiredSlip.to_dict` replaces any non-finite
number by its documented safe value (:data:`SAFE_VALUES`): slips 0.0, confidence 0.0,
probabilities 0.0, classification age -1.0, processing time 0.0. The predictor itself never
produces non-finite values; this is the last line of defence.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

from terrainml.schema import WHEEL_STATES

#: the fallback reason of ground unlike the model's training windows
UNKNOWN_TERRAIN = "unknown_terrain"
#: the fallback reason of a tick whose estimator cannot be trusted (its speed is not counted either)
ESTIMATOR_UNHEALTHY = "estimator_unhealthy"
#: fallback reasons; their order is the CAN reason code (1, 2, ...) and never changes. Which one a
#: tick serves when several apply: :data:`terrainml.stream.tick.policy.REASON_PRIORITY`.
FALLBACK_REASONS: tuple[str, ...] = (
    ESTIMATOR_UNHEALTHY,     # a sensor group silent > 0.2 s, or the estimator state is not finite
    "classifier_error",      # the last classification attempt raised; no usable classification
    "no_classification",     # start-up: no window has been classified yet
    "stale_classification",  # more than stale_m (default 3 m) travelled since the last classification
    "clock_jump",            # t_s off the stream's timeline, re-anchoring (tick/clock.py)
    "uncertain_classification",  # the fused posterior's maximum is below serve_p (default 0.6)
    "windows_rejected",      # moved > warn_after_m (default 5 m) healthy, every window rejected
    UNKNOWN_TERRAIN,         # the latest windows are unlike the model's training windows
)

#: value substituted for a non-finite number, per field
SAFE_VALUES: dict[str, float] = {
    "t_s": 0.0,
    "slip_desired": 0.0,
    "slip_measured": 0.0,
    "confidence": 0.0,
    "class_probabilities": 0.0,
    "classification_age_s": -1.0,
    "processing_ms": 0.0,
    "novelty": -1.0,
}

TOPIC = "/terrainml/desired_slip"


def _finite(x: Any, safe: float) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return safe
    return v if math.isfinite(v) else safe


@dataclass
class DesiredSlip:
    """One served tick. See the module docstring for fields and units."""

    t_s: float
    seq: int
    slip_desired: list[float]
    slip_measured: list[float]
    wheel_state: list[str]
    terrain_class: int
    terrain_name: str
    confidence: float
    class_probabilities: list[float]
    classification_age_s: float
    fallback: bool
    fallback_reason: str
    estimator_ok: bool
    processing_ms: float = 0.0
    fallback_detail: str = ""
    sensors: list[str] = field(default_factory=list)
    novelty: float = -1.0
    slip_measured_note: str = ""

    # ------------------------------------------------------------------ json
    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict with the design §11 field names; never NaN/inf."""
        return {
            "t_s": _finite(self.t_s, SAFE_VALUES["t_s"]),
            "seq": int(self.seq),
            "slip_desired": [_finite(v, SAFE_VALUES["slip_desired"]) for v in self.slip_desired],
            "slip_measured": [_finite(v, SAFE_VALUES["slip_measured"]) for v in self.slip_measured],
            "wheel_state": [s if s in WHEEL_STATES else "idle" for s in map(str, self.wheel_state)],
            "terrain_class": int(self.terrain_class),
            "terrain_name": str(self.terrain_name),
            "confidence": min(1.0, max(0.0, _finite(self.confidence, SAFE_VALUES["confidence"]))),
            "class_probabilities": [_finite(v, SAFE_VALUES["class_probabilities"])
                                    for v in self.class_probabilities],
            "classification_age_s": _finite(self.classification_age_s,
                                             SAFE_VALUES["classification_age_s"]),
            "fallback": bool(self.fallback),
            "fallback_reason": str(self.fallback_reason),
            "estimator_ok": bool(self.estimator_ok),
            "processing_ms": _finite(self.processing_ms, SAFE_VALUES["processing_ms"]),
            "fallback_detail": str(self.fallback_detail),
            "sensors": [str(g) for g in self.sensors],
            "novelty": max(-1.0, _finite(self.novelty, SAFE_VALUES["novelty"])),
        } | ({"slip_measured": None, "slip_measured_note": str(self.slip_measured_note)}
             if self.slip_measured_note else {})

    def to_json(self) -> str:
        """One compact JSON object (no newline); raises if anything non-finite slipped through."""
        return json.dumps(self.to_dict(), separators=(",", ":"), allow_nan=False)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "DesiredSlip":
        keys = list(cls.__dataclass_fields__)
        # the fields added after design §11's list (they have defaults) may be absent
        missing = [k for k in keys if k not in d and k not in ADDED_FIELDS + OPTIONAL_FIELDS]
        keys = [k for k in keys if k in d]
        if missing:
            raise ValueError(f"DesiredSlip: missing field(s) {', '.join(missing)}")
        kw = {k: d[k] for k in keys}
        if kw.get("slip_measured") is None:   # not observable: absent
            kw["slip_measured"] = [math.nan] * len(kw.get("slip_desired") or [])
        return cls(**kw)

    @classmethod
    def from_json(cls, text: str | bytes) -> "DesiredSlip":
        return cls.from_dict(json.loads(text))


#: fields present only when they say something (``slip_measured_note``: slip not observable)
OPTIONAL_FIELDS: tuple[str, ...] = ("slip_measured_note",)
FIELD_NAMES: tuple[str, ...] = tuple(f for f in DesiredSlip.__dataclass_fields__ if f not in OPTIONAL_FIELDS)
#: fields beyond design §11's list (which sensors served, why windows were rejected, how novel
#: the ground is): a message without them still reads
ADDED_FIELDS: tuple[str, ...] = ("fallback_detail", "sensors", "novelty")


def json_schema(n_wheels: int | None = None, n_classes: int | None = None) -> dict[str, Any]:
    """JSON schema (draft 2020-12) of the message, for Foxglove's ``jsonschema`` encoding."""

    def arr(items: dict, n: int | None, desc: str) -> dict:
        a: dict[str, Any] = {"type": "array", "items": items, "description": desc}
        if n is not None:
            a["minItems"] = a["maxItems"] = int(n)
        return a

    num = {"type": "number"}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "terrainml.DesiredSlip",
        "description": "Per-wheel desired slip served by terrainml predict (design §11).",
        "type": "object",
        "properties": {
            "t_s": {"type": "number", "description": "tick time, s"},
            "seq": {"type": "integer", "description": "output sequence number"},
            "slip_desired": arr(num, n_wheels, "desired slip per wheel (signed)"),
            "slip_measured": {**arr(num, n_wheels, "measured slip per wheel; null when not observable "
                                    "(slip_measured_note says why)"), "type": ["array", "null"]},
            "slip_measured_note": {"type": "string", "description": "present only when slip is not "
                                   "observable: why (no body-velocity reference)"},
            "wheel_state": arr({"type": "string", "enum": list(WHEEL_STATES)}, n_wheels,
                               "dynamic state per wheel"),
            "terrain_class": {"type": "integer", "minimum": -1,
                              "description": "served class id; -1 in fallback (no class)"},
            "terrain_name": {"type": "string", "description": "served class name; none in fallback"},
            "confidence": {"type": "number", "minimum": 0, "maximum": 1,
                           "description": "fused probability of the served class"},
            "class_probabilities": arr(num, n_classes, "last classification's probabilities"),
            "classification_age_s": {"type": "number", "description": "s; -1 when none yet"},
            "fallback": {"type": "boolean"},
            "fallback_reason": {"type": "string", "enum": ["", *FALLBACK_REASONS]},
            "estimator_ok": {"type": "boolean"},
            "processing_ms": {"type": "number", "description": "predictor time for this tick, ms"},
            "fallback_detail": {"type": "string", "description": "what the fallback reason names (or a class served "
                                "without terrain parameters: class_free_targets): for "
                                "windows_rejected the window rule (and invalid channels); else empty"},
            "sensors": arr({"type": "string"}, None, "sensor groups of the model member serving this tick"),
            "novelty": {"type": "number", "minimum": -1, "description": "latest window's novelty score "
                        "over the model's threshold (> 1: unlike the training windows); -1 when none"},
        },
        "required": list(FIELD_NAMES),
    }
