"""Vectorised decoding of the few ROS 2 CDR messages the topic map uses.

Decoding message by message (mcap-ros2's dynamic decoder ~57 us/msg, rosbags' ``deserialize_cdr``
~25 us/msg) is the ingest bottleneck. Messages of one topic almost always share one byte layout
(same frame_id, same joint names), so a block of them is decoded at once: the layout (byte offset of
every field) is computed from one message, every message of the block with the same length and the
same *structural bytes* (string and sequence lengths, joint names) is checked against it with one
numpy comparison, and the fields are read as strided ``float64`` views. Messages that differ get
their own layout; a message whose layout cannot be walked (truncated, garbage) is reported as
corrupt. Only little-endian CDR (``00 01`` encapsulation, what every ROS 2 middleware writes) takes
the fast path; anything else goes to rosbags' deserializer. The layout walk is
:mod:`terrainml.io.cdr_layout`; the encoders (:mod:`terrainml.io.cdr_encode`) are importable from here.

Decoded blocks are plain dicts of numpy arrays, keyed per message kind:

``imu``         t_ns, orientation (n,4 xyzw), gyro (n,3), accel (n,3)
``odometry``    t_ns, position (n,3), orientation (n,4), linear (n,3), angular (n,3), cov0 (n,)
``joint_state`` t_ns, names (tuple), position/velocity/effort (n,k) (NaN where absent)
``twist``       t_ns, linear (n,3), angular (n,3)
``scalar``      t_ns, data (n,)
``array``       t_ns, data (n, ARRAY_WIDTH) (a ``Float64MultiArray``'s data, zero-padded), width (n,)
                (how many values the message had; longer messages are cut at ``ARRAY_WIDTH``)
"""

from __future__ import annotations

import struct

import numpy as np
from rosbags.typesys import Stores, get_typestore

from terrainml.io.cdr_encode import (CdrEncoder as CdrEncoder, encode_imu as encode_imu,
                                     encode_imu_block as encode_imu_block, encode_joint_state as encode_joint_state,
                                     encode_joint_state_block as encode_joint_state_block,
                                     encode_odometry as encode_odometry,
                                     encode_odometry_block as encode_odometry_block, encode_twist as encode_twist,
                                     encode_twist_block as encode_twist_block, encode_uint8 as encode_uint8,
                                     encode_uint8_block as encode_uint8_block)
from terrainml.io.cdr_layout import (ARRAY_WIDTH, KIND_OF_TYPE as KIND_OF_TYPE, LayoutError, layout,
                                     normalize_type as normalize_type)

__all__ = ["LayoutError", "normalize_type", "KIND_OF_TYPE", "ARRAY_WIDTH", "layout", "RowView", "decode_block",
           "decode_array", "typestore", "from_object", "CdrEncoder", "encode_imu", "encode_odometry",
           "encode_joint_state", "encode_twist", "encode_uint8", "encode_imu_block", "encode_odometry_block",
           "encode_joint_state_block", "encode_twist_block", "encode_uint8_block"]


# ----------------------------------------------------------------------------- block decoding
class RowView:
    """n equal-length messages lying at ``offsets`` in a byte buffer, read column range by column
    range (only the bytes a decoder needs are gathered, never whole messages)."""

    __slots__ = ("buf", "offsets", "length")

    def __init__(self, buf: np.ndarray, offsets: np.ndarray, length: int):
        self.buf, self.offsets, self.length = buf, offsets, int(length)

    @classmethod
    def from_array(cls, arr: np.ndarray) -> "RowView":
        n, length = arr.shape
        return cls(np.ascontiguousarray(arr).reshape(-1), np.arange(n, dtype=np.int64) * length, length)

    def __len__(self) -> int:
        return len(self.offsets)

    def cols(self, a: int, b: int) -> np.ndarray:
        """(n, b - a) uint8 array of bytes a..b of every message."""
        if b - a == 1:
            return self.buf[self.offsets + a][:, None]
        # rows of a zero-copy sliding window: one contiguous copy per message, not per byte
        win = np.lib.stride_tricks.sliding_window_view(self.buf, b - a)
        return win[self.offsets + a]

    def row_bytes(self, i: int) -> bytes:
        o = int(self.offsets[i])
        return self.buf[o:o + self.length].tobytes()

    def take(self, rows: np.ndarray) -> "RowView":
        return RowView(self.buf, self.offsets[rows], self.length)


class _Spans:
    """The byte ranges a decoder needs, merged and gathered once per block."""

    def __init__(self, view: RowView, ranges: list[tuple[int, int]]):
        merged: list[list[int]] = []
        for a, b in sorted(r for r in ranges if r[1] > r[0]):
            if merged and a <= merged[-1][1] + 16:
                merged[-1][1] = max(merged[-1][1], b)
            else:
                merged.append([a, b])
        self.spans = [(a, b, view.cols(a, b)) for a, b in merged]

    def get(self, a: int, b: int) -> np.ndarray:
        for s0, s1, data in self.spans:
            if s0 <= a and b <= s1:
                return data[:, a - s0:b - s0]
        raise KeyError((a, b))


def _stamp_ns(sp: _Spans, off: int) -> np.ndarray:
    raw = sp.get(off, off + 8)
    sec = np.ascontiguousarray(raw[:, 0:4]).view("<i4")[:, 0].astype(np.int64)
    nsec = np.ascontiguousarray(raw[:, 4:8]).view("<u4")[:, 0].astype(np.int64)
    return sec * 1_000_000_000 + nsec


def _field_range(spec) -> tuple[int, int]:
    off, dt, count = spec
    return off, off + np.dtype(dt).itemsize * count


def _read_field(sp: _Spans, spec) -> np.ndarray:
    a, b = _field_range(spec)
    return np.ascontiguousarray(sp.get(a, b)).view(spec[1]).astype(np.float64)


def decode_block(kind: str, type_name: str, datas: list[bytes], log_ns: np.ndarray,
                 use_header_stamp: bool = True) -> tuple[list[dict], int]:
    """Decode a block of raw CDR messages of one topic.

    Returns (list of decoded parts, number of corrupt messages). Each part is a dict of arrays
    (see module docstring) with ``t_ns``; a JointState block with several joint-name sets gives one
    part per set.
    """
    lengths = np.fromiter((len(d) for d in datas), dtype=np.int64, count=len(datas))
    log_ns = np.asarray(log_ns, np.int64)
    parts: list[dict] = []
    corrupt = 0
    for length in np.unique(lengths):
        idx = np.flatnonzero(lengths == length)
        raw = b"".join(datas[i] for i in idx)
        arr = np.frombuffer(raw, dtype=np.uint8).reshape(len(idx), int(length))
        p, bad = decode_array(kind, type_name, arr, log_ns[idx], use_header_stamp)
        parts += p
        corrupt += bad
    return parts, corrupt


def decode_array(kind: str, type_name: str, arr: np.ndarray | RowView, log_ns: np.ndarray,
                 use_header_stamp: bool = True) -> tuple[list[dict], int]:
    """Decode n messages of equal length, a (n, length) uint8 array or a :class:`RowView`."""
    view = arr if isinstance(arr, RowView) else RowView.from_array(arr)
    parts: list[dict] = []
    corrupt = 0
    remaining = np.arange(len(view))
    while remaining.size:
        ref = int(remaining[0])
        ref_bytes = view.row_bytes(ref)
        try:
            lay = layout(kind, ref_bytes, type_name)
        except (LayoutError, UnicodeDecodeError, struct.error):
            lay = None
        if lay is None:
            # rosbags fallback (big-endian or odd layout), else corrupt
            part, bad = _slow_decode(kind, type_name, [ref_bytes], log_ns[[ref]], use_header_stamp)
            parts += part
            corrupt += bad
            remaining = remaining[1:]
            continue
        sub = view.take(remaining) if len(remaining) < len(view) else view
        ranges = list(lay.checks) + [_field_range(f) for f in lay.fields.values()]
        if lay.stamp is not None:
            ranges.append((lay.stamp, lay.stamp + 8))
        sp = _Spans(sub, ranges)
        same = np.ones(len(remaining), bool)
        for a, b in lay.checks:
            if b > a:
                c = sp.get(a, b)
                same &= (c == c[0]).all(axis=1)
        rows = remaining[same]
        if not same.all():
            sp = _Spans(sub.take(np.flatnonzero(same)), ranges)
        part = {k: _read_field(sp, spec) for k, spec in lay.fields.items()}
        if use_header_stamp and lay.stamp is not None:
            t = _stamp_ns(sp, lay.stamp)
            t = np.where(t > 0, t, log_ns[rows])
        else:
            t = np.asarray(log_ns[rows], np.int64)
        part["t_ns"] = t
        if kind == "joint_state":
            part["names"] = lay.names
        parts.append(_finish(kind, part))
        remaining = remaining[~same]
    return parts, corrupt


def _finish(kind: str, part: dict) -> dict:
    n = len(part["t_ns"])
    if kind == "joint_state":
        k = len(part["names"])
        for field in ("position", "velocity", "effort"):
            if field not in part:
                part[field] = np.full((n, k), np.nan)
    elif kind == "odometry":
        part["cov0"] = part["cov0"].reshape(n)
    elif kind == "scalar":
        part["data"] = part["data"].reshape(n)
    elif kind == "array":
        part["data"], part["width"] = _array_rows(part.get("data", np.zeros((n, 0))).reshape(n, -1))
    return part


def _array_rows(data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, k) values -> (n, ARRAY_WIDTH) zero-padded or cut, and each row's width (n,)."""
    n, k = data.shape
    out = np.zeros((n, ARRAY_WIDTH))
    out[:, :min(k, ARRAY_WIDTH)] = data[:, :ARRAY_WIDTH]
    return out, np.full(n, min(k, ARRAY_WIDTH), np.int64)


# ----------------------------------------------------------------------------- object path
_TYPESTORES: dict = {}


def typestore(ros_version: int = 2):
    key = ros_version
    if key not in _TYPESTORES:
        _TYPESTORES[key] = get_typestore(Stores.ROS2_HUMBLE if ros_version == 2 else Stores.ROS1_NOETIC)
    return _TYPESTORES[key]


def _xyz(v) -> list[float]:
    return [float(v.x), float(v.y), float(v.z)]


def from_object(kind: str, msg, log_ns: int, use_header_stamp: bool = True) -> dict:
    """One deserialised message (rosbags object, ROS 1 or ROS 2) to a one-row part."""
    t = int(log_ns)
    header = getattr(msg, "header", None)
    if use_header_stamp and header is not None:
        st = header.stamp
        sec = getattr(st, "sec", None)
        nsec = getattr(st, "nanosec", None)
        if nsec is None:
            nsec = getattr(st, "nsec", 0)
        stamp = int(sec) * 1_000_000_000 + int(nsec) if sec is not None else 0
        if stamp > 0:
            t = stamp
    part: dict = {"t_ns": np.array([t], np.int64)}
    if kind == "imu":
        o = msg.orientation
        part["orientation"] = np.array([[o.x, o.y, o.z, o.w]], float)
        part["gyro"] = np.array([_xyz(msg.angular_velocity)])
        part["accel"] = np.array([_xyz(msg.linear_acceleration)])
    elif kind == "odometry":
        pose, tw = msg.pose.pose, msg.twist.twist
        o = pose.orientation
        part["position"] = np.array([_xyz(pose.position)])
        part["orientation"] = np.array([[o.x, o.y, o.z, o.w]], float)
        part["cov0"] = np.array([float(msg.pose.covariance[0])])
        part["linear"] = np.array([_xyz(tw.linear)])
        part["angular"] = np.array([_xyz(tw.angular)])
    elif kind == "twist":
        tw = getattr(msg, "twist", msg)
        part["linear"] = np.array([_xyz(tw.linear)])
        part["angular"] = np.array([_xyz(tw.angular)])
    elif kind == "scalar":
        part["data"] = np.array([float(msg.data)])
    elif kind == "array":
        part["data"], part["width"] = _array_rows(np.asarray(msg.data, float).reshape(1, -1))
    elif kind == "joint_state":
        names = tuple(str(s) for s in msg.name)
        part["names"] = names
        k = len(names)
        for field in ("position", "velocity", "effort"):
            v = np.asarray(getattr(msg, field), float).reshape(-1)
            if len(v) not in (0, k):
                raise LayoutError(f"JointState {field} has {len(v)} values for {k} names")
            part[field] = v.reshape(1, k) if len(v) else np.full((1, k), np.nan)
    else:
        raise LayoutError(f"no decoder for kind {kind!r}")
    return part


def _slow_decode(kind: str, type_name: str, datas: list[bytes], log_ns: np.ndarray,
                 use_header_stamp: bool) -> tuple[list[dict], int]:
    store = typestore(2)
    parts, bad = [], 0
    for d, t in zip(datas, log_ns):
        try:
            msg = store.deserialize_cdr(d, type_name)
            parts.append(from_object(kind, msg, int(t), use_header_stamp))
        except Exception:  # noqa: BLE001 - any decoding failure is a corrupt message
            bad += 1
    return parts, bad
