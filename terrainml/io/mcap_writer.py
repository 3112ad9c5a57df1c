"""Write ROS 2 MCAP logs (CDR) with the standard messages of the default topic map (design §5).

The simulator writes through this class, so the ingest path is exercised on real ROS 2 encoding.
Message definitions come from rosbags' ROS 2 Humble type store. The typed ``write_*`` methods encode
with :mod:`terrainml.io.cdr`'s fixed-layout CDR encoder (byte-identical to mcap-ros2-support's
dynamic encoder, tested, and several times faster); the generic :meth:`RosMcapWriter.write` of a
message dict uses mcap-ros2-support's encoder.

Every typed ``write_*`` takes one message (``t_s`` a float) or a block of n messages (``t_s`` an
(n,) array, the other arguments with a leading n axis). A block is encoded at once
(:func:`terrainml.io.cdr.encode_imu_block` and siblings) and its MCAP Message records are built at
once too (:class:`ChunkedMcapFile`), as ingest decodes them (design §5): writing the simulator's
messages one by one through mcap's writer costs ~6 us each, several times the physics.

Message conventions (documented for users reproducing them on a robot)
------------------------------------------------------------------------
``/wheels/joint_states``  sensor_msgs/msg/JointState: names ``wheel{i}_drive`` (velocity = wheel
                          angular speed, rad/s) and ``wheel{i}_steer`` (position = steering angle, rad).
``/wheels/motor_current`` sensor_msgs/msg/JointState: names ``wheel{i}_drive``; the *effort* field
                          holds the motor current in A (positive when driving forward).
``/camera/odom/sample``   nav_msgs/msg/Odometry in the T265's own frames (pose frame x right, y up,
                          z backward; twist.linear in the pose frame, as the realsense driver
                          publishes it); covariance[0] carries the tracker confidence 0..3.
``/sim/wheel_slip``       sensor_msgs/msg/JointState: names ``wheel{i}``; position = true slip
                          (design §7.1), velocity = true longitudinal wheel-centre speed (m/s),
                          effort = true wheel angular speed (rad/s).
``/sim/wheel_state``      sensor_msgs/msg/JointState: names ``wheel{i}``; position = state code
                          (0 idle, 1 steady, 2 traction, 3 braking).
``/sim/ground_truth``     nav_msgs/msg/Odometry: pose in ``world``, twist in ``body``.

:func:`write_run_mcap` writes a canonical run table back to such a log (MCAP export), so a
hand-made table round-trips through ingest.
"""

from __future__ import annotations

import math
import os
import struct
import zlib
from collections import defaultdict
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pandas as pd
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Metadata, MetadataIndex, Schema,
                          Statistics, SummaryOffset)
from mcap.well_known import SchemaEncoding
from mcap.writer import LIBRARY_IDENTIFIER, MCAP0_MAGIC
from mcap_ros2._dynamic import serialize_dynamic
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from terrainml.atomic import discard, output_error, part_path
from terrainml.io import cdr, t265, topics
from terrainml.robot import RobotSpec
from terrainml.schema import validate_run_table, valid_column, wheel_col

_MSG_HEAD = struct.Struct("<BQHIQQ")      # Message record: opcode, length, channel, sequence, log, publish
_INDEX_HEAD = struct.Struct("<BQHI")      # MessageIndex record: opcode, length, channel, entries' bytes
_U32_MOD = 1 << 32                        # Message.sequence is a uint32: it wraps
# zstd level 1: on simulator chunks the same ratio as mcap's default level 3 (~11 %) at half the time
_ZSTD_LEVEL = 1


def msgdef(datatype: str) -> str:
    """Concatenated ROS 2 message definition text for ``datatype`` (e.g. sensor_msgs/msg/Imu)."""
    text, _ = get_typestore(Stores.ROS2_HUMBLE).generate_msgdef(datatype, ros_version=2)
    return text


def _record(rec) -> bytes:
    """The bytes of one ``mcap.records`` record."""
    b = RecordBuilder()
    rec.write(b)
    return b.end()


class ChunkedMcapFile:
    """A chunked, indexed, zstd-compressed MCAP file with the layout of mcap's ``Writer`` (chunks
    with message indexes; a summary of schemas, channels, statistics, chunk and metadata indexes and
    summary offsets), whose chunks take messages one at a time or in blocks.

    A block of n equal-length messages of one channel becomes n Message records in one numpy
    structured array, and a chunk's message indexes are built as arrays. Every record but Message
    and MessageIndex is written by ``mcap.records``. Schema and Channel records go in the data
    section ahead of the first chunk that uses them, so chunks hold only messages (the case
    :func:`terrainml.io.readers.read_mcap` decodes from the message indexes alone).

    Parameters
    ----------
    stream : binary file open for writing, at its start.
    chunk_size : a chunk is closed once its uncompressed records pass this many bytes.
    profile, library : MCAP Header fields.
    """

    def __init__(self, stream: BinaryIO, *, chunk_size: int = 1024 * 1024, profile: str = "ros2",
                 library: str = f"terrainml {LIBRARY_IDENTIFIER}"):
        self._out = stream
        self.chunk_size = int(chunk_size)
        self._pos = 0
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._seq: dict[int, int] = defaultdict(int)
        self._counts: dict[int, int] = defaultdict(int)
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._t_range: list[int] | None = None        # [first, last] log time of the file
        self._zstd = zstandard.ZstdCompressor(level=_ZSTD_LEVEL)
        self._reset_chunk()
        self._write(MCAP0_MAGIC)
        self._write(_record(Header(profile=profile, library=library)))

    # ------------------------------------------------------------------ data section
    def _write(self, data: bytes) -> None:
        self._out.write(data)
        self._pos += len(data)

    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
        self._schemas.append(schema)
        self._write(_record(schema))
        return schema.id

    def add_channel(self, topic: str, message_encoding: str, schema_id: int) -> int:
        channel = Channel(id=len(self._channels) + 1, topic=topic, message_encoding=message_encoding,
                          schema_id=schema_id, metadata={})
        self._channels.append(channel)
        self._write(_record(channel))
        return channel.id

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        rec = _record(Metadata(name=name, metadata=data))
        self._metadata_indexes.append(MetadataIndex(offset=self._pos, length=len(rec), name=name))
        self._write(rec)

    def add_message(self, channel_id: int, log_time_ns: int, data: bytes) -> None:
        """One message (publish time = log time; sequence numbers count per channel)."""
        seq = self._seq[channel_id]
        self._seq[channel_id] = seq + 1
        self._single[channel_id].append((log_time_ns, self._size))
        self._records.append(_MSG_HEAD.pack(Opcode.MESSAGE, 22 + len(data), channel_id, seq % _U32_MOD,
                                            log_time_ns, log_time_ns) + data)
        self._size += _MSG_HEAD.size + len(data)
        self._widen(log_time_ns, log_time_ns)
        if self._size > self.chunk_size:
            self.flush()

    def add_messages(self, channel_id: int, log_time_ns: np.ndarray, data: np.ndarray) -> None:
        """A block of n messages of one channel: ``data`` (n, length) uint8, ``log_time_ns`` (n,).

        The block is split where the chunk passes ``chunk_size`` (where writing its messages one at
        a time would close the chunk).
        """
        t = np.asarray(log_time_ns, np.int64).reshape(-1)
        data = np.asarray(data, np.uint8)
        if data.ndim != 2 or len(data) != len(t):
            raise ValueError(f"data must be (n, length) uint8 for {len(t)} times, got shape {data.shape}")
        rec_len = _MSG_HEAD.size + data.shape[1]
        i = 0
        while i < len(t):
            k = min(len(t) - i, max((self.chunk_size - self._size) // rec_len + 1, 1))
            self._add_block(channel_id, t[i:i + k], data[i:i + k], rec_len)
            i += k
            if self._size > self.chunk_size:
                self.flush()

    def _add_block(self, channel_id: int, t: np.ndarray, data: np.ndarray, rec_len: int) -> None:
        n = len(t)
        rec = np.empty(n, np.dtype([("op", "u1"), ("len", "<u8"), ("channel", "<u2"), ("seq", "<u4"),
                                    ("log", "<u8"), ("pub", "<u8"), ("data", "u1", (data.shape[1],))]))
        seq = self._seq[channel_id]
        self._seq[channel_id] = seq + n
        rec["op"], rec["len"], rec["channel"] = Opcode.MESSAGE, rec_len - 9, channel_id
        rec["seq"] = (seq + np.arange(n, dtype=np.int64)) % _U32_MOD
        rec["log"] = rec["pub"] = t
        rec["data"] = data
        self._blocks[channel_id].append((t, self._size + rec_len * np.arange(n, dtype=np.int64)))
        self._records.append(rec.tobytes())
        self._size += rec_len * n
        self._widen(int(t.min()), int(t.max()))

    def _widen(self, lo: int, hi: int) -> None:
        """Extend the chunk's log-time range."""
        c = self._chunk_t
        self._chunk_t = [lo, hi] if c is None else [min(c[0], lo), max(c[1], hi)]

    def _reset_chunk(self) -> None:
        self._records: list[bytes] = []
        self._size = 0
        self._single: dict[int, list[tuple[int, int]]] = defaultdict(list)
        self._blocks: dict[int, list[tuple[np.ndarray, np.ndarray]]] = defaultdict(list)
        self._chunk_t: list[int] | None = None

    def flush(self) -> None:
        """Close the chunk in progress (if it holds messages): Chunk record, then its message indexes."""
        if not self._records:
            return
        data = b"".join(self._records)
        packed = self._zstd.compress(data)
        lo, hi = self._chunk_t
        start = self._pos
        self._write(_record(Chunk(compression="zstd", data=packed, message_start_time=lo, message_end_time=hi,
                                  uncompressed_crc=zlib.crc32(data), uncompressed_size=len(data))))
        chunk_length = self._pos - start
        index_start = self._pos
        offsets = {}
        for cid in sorted(set(self._single) | set(self._blocks)):
            single = np.array(self._single.get(cid, []), np.int64).reshape(-1, 2)
            t = np.concatenate([single[:, 0]] + [b[0] for b in self._blocks.get(cid, [])])
            off = np.concatenate([single[:, 1]] + [b[1] for b in self._blocks.get(cid, [])])
            order = np.argsort(off, kind="stable")          # index entries in file order
            entries = np.column_stack([t[order], off[order]]).astype("<u8")
            offsets[cid] = self._pos
            self._write(_INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 6 + entries.nbytes, cid, entries.nbytes)
                        + entries.tobytes())
            self._counts[cid] += len(entries)
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=lo, message_end_time=hi, chunk_start_offset=start, chunk_length=chunk_length,
            message_index_offsets=offsets, message_index_length=self._pos - index_start, compression="zstd",
            compressed_size=len(packed), uncompressed_size=len(data)))
        r = self._t_range
        self._t_range = [lo, hi] if r is None else [min(r[0], lo), max(r[1], hi)]
        self._reset_chunk()

    # ------------------------------------------------------------------ summary
    def finish(self) -> None:
        """Close the last chunk, then write DataEnd, the summary, the Footer and the closing magic."""
        self.flush()
        self._write(_record(DataEnd(data_section_crc=0)))   # 0: not computed (mcap's default)
        lo, hi = self._t_range or (0, 0)
        stats = Statistics(message_count=sum(self._counts.values()), schema_count=len(self._schemas),
                           channel_count=len(self._channels), attachment_count=0,
                           metadata_count=len(self._metadata_indexes), chunk_count=len(self._chunk_indexes),
                           message_start_time=lo, message_end_time=hi, channel_message_counts=dict(self._counts))
        summary_start = self._pos
        summary = bytearray()
        offsets = []
        for opcode, recs in ((Opcode.SCHEMA, self._schemas), (Opcode.CHANNEL, self._channels),
                             (Opcode.STATISTICS, [stats]), (Opcode.CHUNK_INDEX, self._chunk_indexes),
                             (Opcode.METADATA_INDEX, self._metadata_indexes)):
            if recs:
                start = len(summary)
                summary += b"".join(_record(r) for r in recs)
                offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + start,
                                             group_length=len(summary) - start))
        offset_start = summary_start + len(summary)
        summary += b"".join(_record(o) for o in offsets)
        # the summary CRC covers the summary and the Footer's fields up to the CRC itself
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offset_start), zlib.crc32(summary))
        self._write(bytes(summary))
        self._write(_record(Footer(summary_start=summary_start, summary_offset_start=offset_start,
                                   summary_crc=crc)))
        self._write(MCAP0_MAGIC)


class RosMcapWriter:
    """Typed writer for the default topic map; use as a context manager.

    Parameters
    ----------
    path : output ``.mcap`` file.
    n_wheels : number of wheels (joint names ``wheel{i}_drive``/``wheel{i}_steer``).
    start_time_ns : UNIX time of t = 0; message times are ``start_time_ns + t_s * 1e9``.
    topic_names : optional override of default topic names, keyed by the defaults in
        :mod:`terrainml.io.topics`.
    metadata : optional string key-value metadata written as an MCAP metadata record ``terrainml``.
    chunk_size : uncompressed bytes after which a chunk is closed (:meth:`flush` closes one early).

    Every typed ``write_*`` method writes one message (``t_s`` a float, vectors of their natural
    length) or a block of n (``t_s`` an (n,) array in s, vectors (n, k), scalars (n,)).
    """

    def __init__(self, path: str | Path, n_wheels: int, *, start_time_ns: int = 1_700_000_000_000_000_000,
                 topic_names: dict[str, str] | None = None, metadata: dict[str, str] | None = None,
                 chunk_size: int = 1024 * 1024):
        self.path = Path(path)
        self._tmp = part_path(self.path)  # renamed onto path by close(): never a partial log
        self.n_wheels = int(n_wheels)
        self.t0_ns = int(start_time_ns)
        self._names = dict(topic_names or {})
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self._tmp, "wb")
        except OSError as exc:
            raise output_error(exc, self.path) from None
        try:
            self._mcap = ChunkedMcapFile(self._file, chunk_size=chunk_size)
        except OSError as exc:
            self.abort()
            raise output_error(exc, self.path) from None
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._encoders: dict[str, object] = {}
        self._drive_names = [f"wheel{i}_drive" for i in range(1, self.n_wheels + 1)]
        self._steer_names = [f"wheel{i}_steer" for i in range(1, self.n_wheels + 1)]
        self._truth_names = [f"wheel{i}" for i in range(1, self.n_wheels + 1)]
        self._drive_names_b = [n.encode() for n in self._drive_names]
        self._joint_names_b = [n.encode() for n in self._drive_names + self._steer_names]
        self._truth_names_b = [n.encode() for n in self._truth_names]
        if metadata:
            self._mcap.add_metadata("terrainml", {str(k): str(v) for k, v in metadata.items()})

    # ------------------------------------------------------------------ plumbing
    def __enter__(self) -> "RosMcapWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        """Close a complete log; after a failure remove it, an ``OSError`` named by the log."""
        if exc_type is None:
            self.close()
            return
        self.abort()
        if isinstance(exc, OSError):  # e.g. ENOSPC from a write: name the log, leave nothing
            raise output_error(exc, self.path) from None

    def close(self) -> None:
        """Finish the log (summary, footer) and move it onto ``path``; a failure leaves nothing
        and raises :class:`terrainml.atomic.OutputWriteError` naming ``path``."""
        if self._file.closed:
            return
        try:
            self._mcap.finish()
            self._file.close()
            os.replace(self._tmp, self.path)
        except OSError as exc:
            self.abort()
            raise output_error(exc, self.path) from None

    def abort(self) -> None:
        """Stop writing and remove the unfinished log (nothing is left at ``path``)."""
        try:
            self._file.close()
        except OSError:
            pass
        discard(self._tmp)

    def flush(self) -> None:
        """Close the chunk in progress (e.g. after each time window of blocks, so that chunks cover
        disjoint time spans)."""
        self._mcap.flush()

    def _t_ns(self, t_s: float) -> int:
        return self.t0_ns + int(round(t_s * 1e9))

    def _t_ns_block(self, t_s: np.ndarray) -> np.ndarray:
        # np.rint rounds half to even like round(); exact below 2**53 ns
        return self.t0_ns + np.rint(np.asarray(t_s, np.float64) * 1e9).astype(np.int64)

    def _channel(self, default_topic: str, datatype: str | None = None) -> tuple[int, str]:
        """Channel id (registered on first use) and type of a (possibly remapped) topic."""
        topic = self._names.get(default_topic, default_topic)
        datatype = datatype or topics.MESSAGE_TYPES[default_topic]
        cid = self._channels.get(topic)
        if cid is None:
            sid = self._schemas.get(datatype)
            if sid is None:
                sid = self._schemas[datatype] = self._mcap.add_schema(datatype, SchemaEncoding.ROS2,
                                                                      msgdef(datatype).encode())
            cid = self._channels[topic] = self._mcap.add_channel(topic, "cdr", sid)
        return cid, datatype

    def write(self, default_topic: str, t_s: float, message: dict, datatype: str | None = None) -> None:
        """Write one message dict on a (possibly remapped) topic at time ``t_s`` (mcap-ros2's encoder)."""
        cid, datatype = self._channel(default_topic, datatype)
        encode = self._encoders.get(datatype)
        if encode is None:
            encode = self._encoders[datatype] = serialize_dynamic(datatype, msgdef(datatype))[datatype]
        self._mcap.add_message(cid, self._t_ns(t_s), encode(message))

    def _write_cdr(self, default_topic: str, t_ns, data) -> None:
        """Write CDR-encoded message(s) of the default type of ``default_topic``: one (``t_ns`` int,
        ``data`` bytes) or a block (``t_ns`` (n,), ``data`` (n, length) uint8)."""
        cid, _ = self._channel(default_topic)
        if isinstance(data, np.ndarray):
            self._mcap.add_messages(cid, t_ns, data)
        else:
            self._mcap.add_message(cid, t_ns, data)

    # ------------------------------------------------------------------ typed messages
    def write_imu(self, t_s, accel_mps2, gyro_radps, orientation_xyzw=(0.0, 0.0, 0.0, 1.0),
                  frame_id: str = "imu_link") -> None:
        """sensor_msgs/Imu in the IMU's own axes (the topic map's mount rotation maps them to body)."""
        if np.ndim(t_s):
            t_ns = self._t_ns_block(t_s)
            return self._write_cdr(topics.IMU, t_ns, cdr.encode_imu_block(
                t_ns, frame_id.encode(), orientation_xyzw, gyro_radps, accel_mps2))
        t_ns = self._t_ns(t_s)
        self._write_cdr(topics.IMU, t_ns, cdr.encode_imu(
            t_ns, frame_id.encode(), [float(v) for v in orientation_xyzw], [float(v) for v in gyro_radps],
            [float(v) for v in accel_mps2]))

    def write_odometry(self, default_topic: str, t_s, position_m, orientation_xyzw, linear_mps, angular_radps,
                       *, frame_id: str, child_frame_id: str, confidence=None) -> None:
        """nav_msgs/Odometry; ``confidence`` (if given) is stored in pose covariance[0]."""
        conf = 0.0 if confidence is None else confidence
        if np.ndim(t_s):
            t_ns = self._t_ns_block(t_s)
            return self._write_cdr(default_topic, t_ns, cdr.encode_odometry_block(
                t_ns, frame_id.encode(), child_frame_id.encode(), position_m, orientation_xyzw, linear_mps,
                angular_radps, conf))
        t_ns = self._t_ns(t_s)
        self._write_cdr(default_topic, t_ns, cdr.encode_odometry(
            t_ns, frame_id.encode(), child_frame_id.encode(), [float(v) for v in position_m],
            [float(v) for v in orientation_xyzw], [float(v) for v in linear_mps],
            [float(v) for v in angular_radps], float(conf)))

    def write_camera_odom(self, t_s, position_m, orientation_xyzw, linear_mps, angular_radps,
                          confidence=3.0) -> None:
        """T265 odometry in its own pose frame (x right, y up, z backward)."""
        self.write_odometry(topics.CAMERA_ODOM, t_s, position_m, orientation_xyzw, linear_mps, angular_radps,
                            frame_id="camera_odom_frame", child_frame_id="camera_pose_frame",
                            confidence=confidence)

    def _joints(self, default_topic: str, t_s, names: list[bytes], position, velocity, effort) -> None:
        """sensor_msgs/JointState: per-wheel fields, None for an empty one."""
        if np.ndim(t_s):
            t_ns = self._t_ns_block(t_s)
            return self._write_cdr(default_topic, t_ns, cdr.encode_joint_state_block(
                t_ns, b"base_link", names, position, velocity, effort))
        t_ns = self._t_ns(t_s)
        f = [() if v is None else [float(x) for x in v] for v in (position, velocity, effort)]
        self._write_cdr(default_topic, t_ns, cdr.encode_joint_state(t_ns, b"base_link", names, *f))

    def write_wheel_joints(self, t_s, omega_radps, steer_rad) -> None:
        omega, steer = np.asarray(omega_radps, float), np.asarray(steer_rad, float)
        self._joints(topics.WHEEL_JOINTS, t_s, self._joint_names_b,
                     np.concatenate([np.zeros_like(steer), steer], axis=-1),
                     np.concatenate([omega, np.zeros_like(omega)], axis=-1), None)

    def write_motor_current(self, t_s, current_a) -> None:
        self._joints(topics.MOTOR_CURRENT, t_s, self._drive_names_b, None, None, current_a)

    def write_cmd_vel(self, t_s, vx_mps, vy_mps, yaw_rate_radps) -> None:
        if np.ndim(t_s):
            zero = np.zeros(len(t_s))
            return self._write_cdr(topics.CMD_VEL, self._t_ns_block(t_s), cdr.encode_twist_block(
                np.column_stack([vx_mps + zero, vy_mps + zero, zero]),
                np.column_stack([zero, zero, yaw_rate_radps + zero])))
        self._write_cdr(topics.CMD_VEL, self._t_ns(t_s), cdr.encode_twist(
            (float(vx_mps), float(vy_mps), 0.0), (0.0, 0.0, float(yaw_rate_radps))))

    def write_terrain_label(self, t_s, class_id) -> None:
        if np.ndim(t_s):
            return self._write_cdr(topics.TERRAIN_LABEL, self._t_ns_block(t_s), cdr.encode_uint8_block(class_id))
        self._write_cdr(topics.TERRAIN_LABEL, self._t_ns(t_s), cdr.encode_uint8(int(class_id)))

    def write_ground_truth(self, t_s, x_m, y_m, yaw_rad, vx_mps, vy_mps, yaw_rate_radps) -> None:
        """Pose in ``world`` (yaw only), twist in body axes (``base_link``)."""
        if np.ndim(t_s):
            zero = np.zeros(len(t_s))
            half = 0.5 * np.asarray(yaw_rad, float)
            return self.write_odometry(
                topics.SIM_GROUND_TRUTH, t_s, np.column_stack([x_m, y_m, zero]),
                np.column_stack([zero, zero, np.sin(half), np.cos(half)]), np.column_stack([vx_mps, vy_mps, zero]),
                np.column_stack([zero, zero, yaw_rate_radps]), frame_id="world", child_frame_id="base_link")
        half = 0.5 * yaw_rad
        self.write_odometry(topics.SIM_GROUND_TRUTH, t_s, (x_m, y_m, 0.0),
                            (0.0, 0.0, math.sin(half), math.cos(half)),
                            (vx_mps, vy_mps, 0.0), (0.0, 0.0, yaw_rate_radps),
                            frame_id="world", child_frame_id="base_link")

    def write_wheel_slip(self, t_s, slip, v_long_mps, omega_radps) -> None:
        self._joints(topics.SIM_WHEEL_SLIP, t_s, self._truth_names_b, slip, v_long_mps, omega_radps)

    def write_wheel_state(self, t_s, state_codes) -> None:
        self._joints(topics.SIM_WHEEL_STATE, t_s, self._truth_names_b, state_codes, None, None)


# ----------------------------------------------------------------------------- export
def _column(df: pd.DataFrame, name: str, default: float = np.nan) -> np.ndarray:
    """Column ``name`` as floats, or ``default`` on every row when the table has none."""
    return df[name].to_numpy(float) if name in df else np.full(len(df), default)


def _imu_messages(df: pd.DataFrame, robot: RobotSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(acceleration (n, 3), angular rate (n, 3), orientation xyzw (n, 4)) in the IMU's own axes:
    the body vectors rotated back through the mount; the yaw, when the table has it, as the
    orientation (:func:`_imu_orientation`), else identity."""
    mount = Rotation.from_euler("xyz", [robot.imu.roll_rad, robot.imu.pitch_rad, robot.imu.yaw_rad])
    rot_inv = mount.inv()
    acc = rot_inv.apply(np.column_stack([_column(df, f"imu_a{a}_mps2") for a in "xyz"]))
    gyr = rot_inv.apply(np.column_stack([_column(df, "imu_roll_rate_radps", 0.0),
                                         _column(df, "imu_pitch_rate_radps", 0.0), _column(df, "imu_yaw_rate_radps")]))
    imu_q = _imu_orientation(_column(df, "imu_yaw_rad"), mount) if "imu_yaw_rad" in df else \
        np.tile([0.0, 0.0, 0.0, 1.0], (len(df), 1))
    return acc, gyr, imu_q


def _camera_messages(df: pd.DataFrame, t: np.ndarray, robot: RobotSpec) -> tuple[dict, np.ndarray]:
    """(T265 odometry fields per row, confidence (n,)) of the camera rows: the robot pose
    integrated from the camera yaw and velocities, through the camera mount."""
    mount = (robot.camera.x_m, robot.camera.y_m, robot.camera.z_m)  # type: ignore[union-attr]
    yaw = np.nan_to_num(_column(df, "cam_yaw_rad"))
    yaw_rate = np.nan_to_num(_column(df, "cam_yaw_rate_radps"))
    vx, vy = t265.robot_velocity_from_mount(np.nan_to_num(_column(df, "cam_vx_mps")),
                                            np.nan_to_num(_column(df, "cam_vy_mps")), yaw_rate, mount[:2])
    dt = np.diff(t, prepend=t[0])
    xw = np.cumsum(dt * (vx * np.cos(yaw) - vy * np.sin(yaw)))
    yw = np.cumsum(dt * (vx * np.sin(yaw) + vy * np.cos(yaw)))
    return t265.body_to_t265_odometry(xw, yw, yaw, vx, vy, yaw_rate, mount), _column(df, "cam_confidence", 3.0)


def write_run_mcap(table: pd.DataFrame, path: str | Path, robot: RobotSpec, *,
                   start_time_ns: int = 1_700_000_000_000_000_000, metadata: dict | None = None) -> Path:
    """Write a canonical run table to a ROS 2 MCAP with the default topic map's messages.

    One message per row and sensor group where that group is valid (rows that are invalid are not
    written, so gaps survive the round trip). IMU vectors are rotated back to the IMU's own axes
    (inverse of the spec's mount rotation); ``imu_yaw_rad``, when the table has it, becomes the IMU
    message's orientation (yaw about body z, then the mount: ingest reads the same yaw back; NaN
    where the yaw is not finite), else the orientation is identity (ingest then makes no
    ``imu_yaw_rad``); camera rows are turned into T265 messages with
    :func:`terrainml.io.t265.body_to_t265_odometry` (robot pose integrated from the camera yaw and
    velocities); labels are written when they change and once a second. Columns the default topic
    map has no topic for (``wheel{i}_cmd_omega_radps``) are not written.

    Parameters
    ----------
    table : a canonical run table (design §5).
    path : the MCAP to write (whole or not at all: a hidden ``.NAME.part`` renamed when complete).
    robot : the spec the table was recorded with (its IMU and camera mounts).
    start_time_ns : the log time (ns) of ``t_s`` = 0: a message's log time is
        ``start_time_ns + round(t_s * 1e9)``.
    metadata : optional ``{key: value}`` written as the MCAP metadata record ``terrainml``
        (values as strings).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    n = robot.n_wheels
    df = validate_run_table(table, n)
    t = df["t_s"].to_numpy(float)

    def col(name, default=np.nan):
        return _column(df, name, default)

    def valid(g):
        c = valid_column(g).name
        return df[c].to_numpy(bool) if c in df else np.zeros(len(df), bool)

    acc, gyr, imu_q = _imu_messages(df, robot)
    has_cam = "cam_vx_mps" in df and valid("cam").any() and robot.camera is not None
    if has_cam:
        msg, conf = _camera_messages(df, t, robot)
    wv, sv, cv, iv, camv, cmdv = (valid(g) for g in ("wheels", "steer", "current", "imu", "cam", "cmd"))
    omega = np.column_stack([col(wheel_col("omega", i)) for i in range(1, n + 1)])
    steer = np.column_stack([col(wheel_col("steer", i), 0.0) for i in range(1, n + 1)])
    cur = np.column_stack([col(wheel_col("current", i)) for i in range(1, n + 1)])
    terrain = df["terrain"].to_numpy() if "terrain" in df else None
    has_gt = "gt_vx_mps" in df
    has_slip = "gt_slip1" in df
    has_state = "gt_state1" in df
    last_label, last_label_t = None, -1e9
    with RosMcapWriter(path, n, start_time_ns=start_time_ns, metadata=metadata) as w:
        for k in range(len(df)):
            tk = float(t[k])
            if iv[k]:
                w.write_imu(tk, acc[k], gyr[k], imu_q[k])
            if has_cam and camv[k]:
                w.write_camera_odom(tk, msg["position_m"][k], msg["orientation_xyzw"][k], msg["linear_mps"][k],
                                    msg["angular_radps"][k], confidence=float(np.nan_to_num(conf[k], nan=3.0)))
            if wv[k] or sv[k]:
                w.write_wheel_joints(tk, omega[k] if wv[k] else np.full(n, np.nan),
                                     steer[k] if sv[k] else np.full(n, np.nan))
            if cv[k]:
                w.write_motor_current(tk, cur[k])
            if cmdv[k]:
                w.write_cmd_vel(tk, df["cmd_vx_mps"].iat[k], df["cmd_vy_mps"].iat[k], df["cmd_yaw_rate_radps"].iat[k])
            if terrain is not None and terrain[k] >= 0 and (terrain[k] != last_label or tk - last_label_t >= 1.0):
                w.write_terrain_label(tk, int(terrain[k]))
                last_label, last_label_t = terrain[k], tk
            if has_gt:
                w.write_ground_truth(tk, df["gt_x_m"].iat[k], df["gt_y_m"].iat[k], df["gt_yaw_rad"].iat[k],
                                     df["gt_vx_mps"].iat[k], df["gt_vy_mps"].iat[k], df["gt_yaw_rate_radps"].iat[k])
            if has_slip:
                w.write_wheel_slip(tk, [df[f"gt_slip{i}"].iat[k] for i in range(1, n + 1)], [0.0] * n, omega[k])
            if has_state:
                w.write_wheel_state(tk, [topics.WHEEL_STATE_CODES.get(str(df[f"gt_state{i}"].iat[k]), -1)
                                         for i in range(1, n + 1)])
    return Path(path)


def _imu_orientation(yaw_rad: np.ndarray, mount: Rotation) -> np.ndarray:
    """(n, 4) xyzw orientations of the IMU whose body yaws ``yaw_rad`` (body = IMU after ``mount``);
    NaN rows where the yaw is not finite (ingest reads no yaw there)."""
    ok = np.isfinite(yaw_rad)
    q = (Rotation.from_euler("z", np.where(ok, yaw_rad, 0.0)[:, None]) * mount).as_quat()
    q[~ok] = np.nan
    return q
