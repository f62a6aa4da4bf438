"""Byte-exact CDR (XCDR1, little endian) for the twin's message types.

The twin records what its nodes publish at the moment they publish it, so it needs the exact
wire bytes without a subscription per topic (a raw subscription costs a delivery per message,
as much as the publication itself). These encoders produce the bytes rmw_fastrtps puts on the
wire -- the tests compare them with raw subscriptions byte for byte -- whereas
``rclpy.serialization.serialize_message`` pads some types (JointState) with stale bytes.

Alignment is relative to the payload after the 4-byte encapsulation header ``00 01 00 00``;
padding bytes are zero.
"""

from __future__ import annotations

import struct
from typing import Any, Callable

CDR_HEADER = _HEADER = b'\x00\x01\x00\x00'   # CDR, little endian, no options
_F64 = struct.Struct('<d')


def _pad(buf: bytearray, align: int) -> None:
    n = (len(buf) - 4) % align
    if n:
        buf.extend(b'\x00' * (align - n))


def _string(buf: bytearray, s: str) -> None:
    data = s.encode('utf-8') + b'\x00'
    _pad(buf, 4)
    buf.extend(struct.pack('<I', len(data)))
    buf.extend(data)


def _f64_seq(buf: bytearray, values) -> None:
    _pad(buf, 4)
    buf.extend(struct.pack('<I', len(values)))
    if len(values):
        _pad(buf, 8)
        buf.extend(struct.pack(f'<{len(values)}d', *values))


def _time(buf: bytearray, stamp) -> None:
    _pad(buf, 4)
    buf.extend(struct.pack('<iI', stamp.sec, stamp.nanosec))


def _std_header(buf: bytearray, header) -> None:
    """std_msgs/Header: stamp, then frame_id."""
    _time(buf, header.stamp)
    _string(buf, header.frame_id)


def encode_float64(msg) -> bytes:
    return _HEADER + _F64.pack(msg.data)


def encode_float64_value(value: float) -> bytes:
    """:func:`encode_float64` of a message holding ``value``."""
    return _HEADER + _F64.pack(value)


def encode_clock(msg) -> bytes:
    return _HEADER + struct.pack('<iI', msg.clock.sec, msg.clock.nanosec)


# The jack's joint state (frame_id '', one joint named 'jack', one value of each): its layout
# is fixed, so one struct call encodes it; the general path below gives the same bytes.
_JACK = struct.Struct('<4siII4xII5s3xI4xdI4xdI4xd')
_JACK_NAME = b'jack\x00'


def encode_joint_state(msg) -> bytes:
    if (len(msg.name) == 1 and msg.name[0] == 'jack' and not msg.header.frame_id
            and len(msg.position) == len(msg.velocity) == len(msg.effort) == 1):
        st = msg.header.stamp
        return _JACK.pack(_HEADER, st.sec, st.nanosec, 1, 1, 5, _JACK_NAME, 1, msg.position[0],
                          1, msg.velocity[0], 1, msg.effort[0])
    return encode_joint_state_general(msg)


def encode_jack_state(stamp_ns: int, xj: float, dxj: float, force: float) -> bytes:
    """:func:`encode_joint_state` of :func:`~..nodes.topics.joint_state`'s message, without
    building it (the twin's recorder, when nothing on DDS subscribes to the joint state)."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return _JACK.pack(_HEADER, sec, nanosec, 1, 1, 5, _JACK_NAME, 1, float(xj), 1, float(dxj),
                      1, float(force))


def encode_joint_state_general(msg) -> bytes:
    buf = bytearray(_HEADER)
    _std_header(buf, msg.header)
    _pad(buf, 4)
    buf.extend(struct.pack('<I', len(msg.name)))
    for name in msg.name:
        _string(buf, name)
    for seq in (msg.position, msg.velocity, msg.effort):
        _f64_seq(buf, seq)
    return bytes(buf)


def encode_diagnostic_array(msg) -> bytes:
    buf = bytearray(_HEADER)
    _std_header(buf, msg.header)
    _pad(buf, 4)
    buf.extend(struct.pack('<I', len(msg.status)))
    for st in msg.status:
        level = st.level if isinstance(st.level, int) else st.level[0]
        buf.extend(struct.pack('<B', level))
        _string(buf, st.name)
        _string(buf, st.message)
        _string(buf, st.hardware_id)
        _pad(buf, 4)
        buf.extend(struct.pack('<I', len(st.values)))
        for kv in st.values:
            _string(buf, kv.key)
            _string(buf, kv.value)
    return bytes(buf)


ENCODERS: dict[str, Callable[[Any], bytes]] = {
    'diagnostic_msgs/msg/DiagnosticArray': encode_diagnostic_array,
    'std_msgs/msg/Float64': encode_float64,
    'rosgraph_msgs/msg/Clock': encode_clock,
    'sensor_msgs/msg/JointState': encode_joint_state,
}


def decode_float64(data: bytes) -> float:
    if len(data) < 12 or data[:2] != b'\x00\x01':
        raise ValueError(f'not a little-endian CDR std_msgs/Float64 ({len(data)} bytes)')
    return _F64.unpack_from(data, 4)[0]
