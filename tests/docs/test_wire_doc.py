"""docs/wire.md is the code's wire format: a team wires its JSON reader and CAN decoder from it.

Every JSON field the code writes is in the doc's field table and every row of it is a field the
code writes; every CAN reason code, wheel state code, flag bit and byte of the doc's frame tables
equals the code's (the byte tables are checked by decoding frames the encoder wrote).
"""

import re
import struct
from pathlib import Path

import pytest

# The code's own tables, imported in this one place (these modules move with the stream's rooms).
from terrainml.io.topics import WHEEL_STATE_CODES
from terrainml.stream.tick.message import FIELD_NAMES, OPTIONAL_FIELDS, DesiredSlip
from terrainml.stream.transports.sinks import (CAN_BASE_ID, REASON_CODES, SLIP_NA, UNKNOWN_REASON_CODE,
                                    encode_can_frames)

WIRE = Path(__file__).resolve().parents[2] / "docs" / "wire.md"
STRUCT = {"uint8": "B", "int8": "b", "uint16": "H", "int16": "h", "uint32": "I", "int32": "i"}


def section(heading: str) -> str:
    """The text under a markdown heading, up to the next heading of any level."""
    text = WIRE.read_text()
    m = re.search(rf"^#+ {re.escape(heading)}\n(.*?)(?=^#+ |\Z)", text, re.S | re.M)
    assert m, f"docs/wire.md has no section {heading!r}"
    return m.group(1)


def table(heading: str) -> list[list[str]]:
    """The body rows of the first table under a heading, as stripped cells."""
    rows = [line.strip().strip("|").split("|") for line in section(heading).splitlines()
            if line.startswith("|")]
    return [[c.strip() for c in r] for r in rows[2:]]


def first_code(cell: str) -> str:
    m = re.search(r"`([^`]*)`", cell)
    assert m, f"no `name` in {cell!r}"
    return m.group(1)


def message(**kw) -> DesiredSlip:
    d = dict(t_s=12.34, seq=70_001, slip_desired=[0.1234, -0.25, 0.0], slip_measured=[0.11, -0.2, 0.0],
             wheel_state=["traction", "braking", "idle"], terrain_class=5, terrain_name="tilled_loam",
             confidence=0.8, class_probabilities=[0.1, 0.1, 0.8], classification_age_s=1.234,
             fallback=False, fallback_reason="", estimator_ok=True)
    d.update(kw)
    return DesiredSlip(**d)


def test_json_fields_are_the_codes_fields():
    documented = [first_code(r[0]) for r in table("JSON message")]
    assert len(documented) == len(set(documented)), "a field is listed twice"
    written = set(message().to_dict()) | set(message(slip_measured_note="no reference").to_dict())
    assert set(documented) == written == set(FIELD_NAMES) | set(OPTIONAL_FIELDS)


def test_reason_codes_are_the_sinks_codes():
    listed = {}
    for code, reason in table("Reason codes"):
        if code == str(UNKNOWN_REASON_CODE):
            assert "not know" in reason
            continue
        listed["" if reason.startswith("none") else first_code(reason)] = int(code)
    assert listed == REASON_CODES
    assert int(table("Reason codes")[-1][0]) == UNKNOWN_REASON_CODE


def test_wheel_state_codes_are_the_codes():
    assert {first_code(s): int(c) for c, s in table("Wheel state codes")} == WHEEL_STATE_CODES


def bit_positions() -> dict[str, tuple[int, int]]:
    """Flag name (or "reason") -> (lowest bit, number of bits), from the doc's flags table."""
    out = {}
    for bits, content in table("Flags"):
        lo, _, hi = bits.partition("-")
        name = "reason" if "reason code" in content else first_code(content)
        out[name] = (int(lo), int(hi or lo) - int(lo) + 1)
    return out


def test_flag_bits_are_the_encoders():
    bits = bit_positions()
    assert set(bits) == {"fallback", "estimator_ok", "reason"}
    lo, width = bits["reason"]
    assert UNKNOWN_REASON_CODE == 2 ** width - 1  # the unknown code is every bit of the field set
    for fallback, ok, reason in [(True, False, "unknown_terrain"), (False, True, ""),
                                 (True, True, "uncertain_classification"), (True, False, "no_such_reason")]:
        frames = encode_can_frames(message(fallback=fallback, estimator_ok=ok, fallback_reason=reason))
        flags = frames[0][1][6]
        expected = (fallback << bits["fallback"][0]) | (ok << bits["estimator_ok"][0]) \
            | (REASON_CODES.get(reason, UNKNOWN_REASON_CODE) << lo)
        assert flags == expected
        assert all(data[6] == flags for _, data in frames[1:])


def layout(heading: str) -> str:
    """struct format of a frame from the doc's byte table; the bytes must tile 0-7 in order."""
    fmt, at = "<", 0
    for bytes_, type_, _ in table(heading):
        lo, _, hi = bytes_.partition("-")
        assert int(lo) == at, f"{heading}: byte {at} is not where the table says"
        fmt += STRUCT[type_]
        at += struct.calcsize("<" + STRUCT[type_])
        assert at == int(hi or lo) + 1, f"{heading}: {bytes_} is not the size of {type_}"
    assert at == 8
    return fmt


def test_frame_bytes_are_the_encoders():
    assert f"`BASE` is `{CAN_BASE_ID:#x}`" in section("CAN frames")
    msg = message(slip_desired=[0.1234, -5.0, 0.0])
    frames = encode_can_frames(msg)
    assert [fid for fid, _ in frames] == [CAN_BASE_ID + i for i in range(4)]
    flags = frames[0][1][6]
    seq, cls, conf, age_ms, f, n = struct.unpack(layout("Summary frame"), frames[0][1])
    assert (seq, cls, conf, age_ms, f, n) == (70_001 % 65536, 5, 200, 1234, flags, 3)
    wheel = layout("Wheel frame")
    for i, (_, data) in enumerate(frames[1:]):
        sd, sm, st, c, f, s = struct.unpack(wheel, data)
        assert sd == max(-32767, round(msg.slip_desired[i] * 1e4))
        assert sm == round(msg.slip_measured[i] * 1e4)
        assert (st, c, f, s) == (WHEEL_STATE_CODES[msg.wheel_state[i]], 5, flags, 70_001 & 0xFF)


@pytest.mark.parametrize("heading, value", [("Summary frame", "255 = none"), ("Wheel frame", "255 = none"),
                                            ("Summary frame", "65535 = none"),
                                            ("Wheel frame", f"{SLIP_NA} = not observable")])
def test_special_values_are_the_encoders(heading, value):
    assert value in section(heading)
    fallback = message(terrain_class=-1, terrain_name="none", fallback=True, confidence=0.0,
                       fallback_reason="no_classification", classification_age_s=-1.0,
                       slip_measured_note="no reference")
    summary, first_wheel = (data for _, data in encode_can_frames(fallback)[:2])
    _, cls, _, age_ms, _, _ = struct.unpack(layout("Summary frame"), summary)
    _, sm, _, wcls, _, _ = struct.unpack(layout("Wheel frame"), first_wheel)
    assert (cls, age_ms, sm, wcls) == (255, 65535, SLIP_NA, 255)
