"""The byte layout of a little-endian CDR message of the kinds the topic map uses: the offset of
every field, walked from one message (:func:`layout`); what the block decoder
(:mod:`terrainml.io.cdr`) and encoder (:mod:`terrainml.io.cdr_encode`) share."""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

__all__ = ["LayoutError", "normalize_type", "KIND_OF_TYPE", "ARRAY_WIDTH", "MessageLayout", "layout"]

_U32 = struct.Struct("<I")


class LayoutError(ValueError):
    """A message's bytes do not fit its declared type."""


def normalize_type(name: str) -> str:
    """``sensor_msgs/Imu`` and ``sensor_msgs/msg/Imu`` are the same type."""
    parts = name.strip().split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name.strip()


KIND_OF_TYPE = {
    "sensor_msgs/msg/Imu": "imu",
    "nav_msgs/msg/Odometry": "odometry",
    "sensor_msgs/msg/JointState": "joint_state",
    "geometry_msgs/msg/Twist": "twist",
    "geometry_msgs/msg/TwistStamped": "twist",
    "std_msgs/msg/UInt8": "scalar", "std_msgs/msg/Int8": "scalar", "std_msgs/msg/UInt16": "scalar",
    "std_msgs/msg/Int16": "scalar", "std_msgs/msg/UInt32": "scalar", "std_msgs/msg/Int32": "scalar",
    "std_msgs/msg/Int64": "scalar", "std_msgs/msg/UInt64": "scalar", "std_msgs/msg/Float32": "scalar",
    "std_msgs/msg/Float64": "scalar",
    "std_msgs/msg/Float64MultiArray": "array",
}
#: values of an ``array`` part per message (a topic map indexes below it)
ARRAY_WIDTH = 64
_SCALAR_DTYPE = {"UInt8": "<u1", "Int8": "<i1", "UInt16": "<u2", "Int16": "<i2", "UInt32": "<u4",
                 "Int32": "<i4", "Int64": "<i8", "UInt64": "<u8", "Float32": "<f4", "Float64": "<f8"}


# ----------------------------------------------------------------------------- layout walking
@dataclass
class MessageLayout:
    fields: dict          # name -> (abs offset, dtype, count)
    checks: list          # (start, end) byte ranges that must equal the reference message
    stamp: int | None     # abs offset of builtin_interfaces/Time or None
    names: tuple = ()


def _align(p: int, n: int) -> int:
    return p + (-p) % n


def _u32(buf: bytes, p: int) -> int:
    if p + 4 > len(buf):
        raise LayoutError("message ends inside a length field")
    return _U32.unpack_from(buf, p)[0]


def _string(buf: bytes, p: int) -> tuple[int, str]:
    """Payload-relative CDR string at p (abs offset = p + 4); returns (new p, text)."""
    p = _align(p, 4)
    n = _u32(buf, p + 4)
    end = p + 4 + n
    if end + 4 > len(buf):
        raise LayoutError("string runs past the end of the message")
    return end, buf[p + 8:p + 8 + max(n - 1, 0)].decode("utf-8", "replace")


def _header(buf: bytes, checks: list) -> int:
    # stamp (int32 sec, uint32 nanosec) at payload 0; frame_id string at payload 8
    p, _ = _string(buf, 8)
    checks.append((12, p + 4))
    return p


def _f64(p: int, count: int, end: int, total: int) -> tuple[int, int]:
    p = _align(p, 8)
    if p + 4 + 8 * count > total:
        raise LayoutError("message shorter than its type")
    return p, p + 8 * count


def layout(kind: str, buf: bytes, type_name: str = "") -> MessageLayout:
    """Byte layout of one little-endian CDR message of ``kind``."""
    if len(buf) < 4 or buf[1] != 1:
        raise LayoutError("not little-endian CDR")
    total = len(buf)
    checks: list = []
    f: dict = {}
    if kind == "imu":
        p = _header(buf, checks)
        o, _ = _f64(p, 4 + 9 + 3 + 9 + 3 + 9, 0, total)
        f = {"orientation": (o + 4, "<f8", 4), "gyro": (o + 4 + 104, "<f8", 3),
             "accel": (o + 4 + 200, "<f8", 3)}
        return MessageLayout(f, checks, 4)
    if kind == "odometry":
        p = _header(buf, checks)
        p, _ = _string(buf, p)
        checks.append((12, p + 4))
        o, _ = _f64(p, 3 + 4 + 36 + 3 + 3 + 36, 0, total)
        f = {"position": (o + 4, "<f8", 3), "orientation": (o + 28, "<f8", 4),
             "cov0": (o + 60, "<f8", 1), "linear": (o + 348, "<f8", 3), "angular": (o + 372, "<f8", 3)}
        return MessageLayout(f, checks, 4)
    if kind == "twist":
        stamped = type_name.endswith("TwistStamped")
        p = _header(buf, checks) if stamped else 0
        o, _ = _f64(p, 6, 0, total)
        return MessageLayout({"linear": (o + 4, "<f8", 3), "angular": (o + 28, "<f8", 3)}, checks,
                       4 if stamped else None)
    if kind == "scalar":
        dt = _SCALAR_DTYPE.get(type_name.rsplit("/", 1)[-1], "<u1")
        size = np.dtype(dt).itemsize
        o = _align(0, size)
        if 4 + o + size > total:
            raise LayoutError("message shorter than its type")
        return MessageLayout({"data": (o + 4, dt, 1)}, checks, None)
    if kind == "array":   # MultiArrayLayout (dims: label, size, stride; data_offset), sequence<double>
        ndim = _u32(buf, 4)
        if ndim > 64:
            raise LayoutError("implausible dimension count")
        p = 4
        for _ in range(ndim):
            p, _ = _string(buf, p)
            p = _align(p, 4) + 8                 # size, stride
        p = _align(p, 4) + 4                     # data_offset
        p = _align(p, 4)
        n = _u32(buf, p + 4)
        p += 4
        checks.append((4, p + 4))                # the layout and the data length: structural bytes
        if not n:
            return MessageLayout({}, checks, None)
        o, _ = _f64(p, n, 0, total)
        return MessageLayout({"data": (o + 4, "<f8", n)}, checks, None)
    if kind == "joint_state":
        p = _header(buf, checks)
        p = _align(p, 4)
        n = _u32(buf, p + 4)
        if n > 10_000:
            raise LayoutError("implausible joint count")
        p += 4
        names = []
        for _ in range(n):
            p, s = _string(buf, p)
            names.append(s)
        checks.append((12, p + 4))
        for field in ("position", "velocity", "effort"):
            p = _align(p, 4)
            k = _u32(buf, p + 4)
            checks.append((p + 4, p + 8))
            p += 4
            if k and k != n:
                raise LayoutError(f"JointState {field} has {k} values for {n} names")
            if k:  # no alignment padding before an empty sequence's (absent) elements
                o, p = _f64(p, k, 0, total)
                f[field] = (o + 4, "<f8", k)
        return MessageLayout(f, checks, 4, tuple(names))
    raise LayoutError(f"no decoder for kind {kind!r}")
