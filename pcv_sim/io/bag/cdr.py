"""CDR (de)serialisation of the message types bags carry at high rate, without rclpy.

``std_msgs/msg/Float64`` and ``sensor_msgs/msg/FluidPressure`` are packed and unpacked with
``struct`` (one message) or numpy (:func:`message_records`: a whole batch as MCAP message records,
about 0.1 µs per message instead of ~3.5 µs; BENCHMARKS.md, Recording). Every other type goes
through rosbags' type store (:func:`serialize`), which also gives message definitions and type
hashes. The bytes are those of rosbags' serializer (little-endian CDR; test/io/test_bag.py).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Final, TypeAlias, cast

import numpy as np
import numpy.typing as npt
from mcap.opcode import Opcode
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from pcv_sim.errors import BagError
from pcv_sim.units import NS_PER_S

__all__ = [
    "DECODABLE_TYPES",
    "DECODERS",
    "FLOAT64",
    "FLUID_PRESSURE",
    "MESSAGE_OVERHEAD",
    "NS_PER_S",
    "ChannelRecords",
    "float64_cdr",
    "fluid_pressure_cdr",
    "message_records",
    "serialize",
    "store",
]

FLOAT64: Final = "std_msgs/msg/Float64"
FLUID_PRESSURE: Final = "sensor_msgs/msg/FluidPressure"
#: Message types :func:`pcv_sim.io.bag.read_bag` decodes into arrays.
DECODABLE_TYPES: Final = (FLOAT64, FLUID_PRESSURE)

#: Per channel: (channel id, log times, offsets of its records in bytes serialised together).
ChannelRecords: TypeAlias = list[tuple[int, npt.NDArray[np.uint64], npt.NDArray[np.uint64]]]
MESSAGE_OVERHEAD: Final = 9 + 22  # MCAP record opcode+length, then the message fields
_INT32_MAX: Final = (1 << 31) - 1
_CDR_LE: Final = b"\x00\x01\x00\x00"
_CDR_LE_U32: Final = int.from_bytes(_CDR_LE, "little")
_FLOAT64_LE: Final = struct.Struct("<4sd")

_typestore: Typestore | None = None


def store() -> Typestore:
    """rosbags' Jazzy type store, built once (building it takes a few ms). Its Float64 and
    FluidPressure definitions and hashes are the same in Kilted."""
    global _typestore
    if _typestore is None:
        _typestore = get_typestore(Stores.ROS2_JAZZY)
    return _typestore


# -- writing --------------------------------------------------------------------------------


def float64_cdr(topic: str, value: float) -> bytes:
    """``std_msgs/msg/Float64`` as little-endian CDR."""
    try:
        return _FLOAT64_LE.pack(_CDR_LE, value)
    except struct.error as exc:
        msg = f"Float64 value for {topic!r} must be a real number, got {value!r}"
        raise BagError(msg) from exc


_fp_layouts: dict[str, tuple[struct.Struct, bytes]] = {}


def _fluid_layout(frame_id: str) -> tuple[struct.Struct, bytes]:
    """CDR layout of FluidPressure for one frame_id: the string length fixes the padding."""
    layout = _fp_layouts.get(frame_id) if isinstance(frame_id, str) else None
    if layout is None:
        if not isinstance(frame_id, str):
            msg = f"frame_id must be a str, got {frame_id!r}"
            raise BagError(msg)
        raw = frame_id.encode() + b"\x00"
        end = 12 + len(raw)  # offsets relative to the CDR body (after the 4-byte header)
        pad = -end % 8
        layout = (struct.Struct(f"<4siII{len(raw)}s{pad}xdd"), raw)
        _fp_layouts[frame_id] = layout
    return layout


def fluid_pressure_cdr(
    topic: str, t_ns: int, pressure_pa: float, variance: float, frame_id: str = ""
) -> bytes:
    """``sensor_msgs/msg/FluidPressure`` with header stamp ``t_ns`` as little-endian CDR."""
    st, raw = _fluid_layout(frame_id)
    try:
        sec, nanosec = divmod(t_ns, NS_PER_S)
        if not 0 <= sec <= _INT32_MAX:
            msg = f"t_ns={t_ns!r} does not fit a builtin_interfaces/Time stamp (int32 seconds)"
            raise BagError(msg)
        return st.pack(_CDR_LE, sec, nanosec, len(raw), raw, pressure_pa, variance)
    except (struct.error, TypeError) as exc:
        msg = (
            f"FluidPressure for {topic!r} needs an integer t_ns and real pressure/variance, "
            f"got {t_ns!r}, {pressure_pa!r}, {variance!r}"
        )
        raise BagError(msg) from exc


def serialize(topic: str, msgtype: str, msg: object) -> bytes:
    """Any type the store knows: a rosbags message object or a dict of its fields (slow path)."""
    ts = store()
    if isinstance(msg, Mapping):
        obj = _build_message(ts, msgtype, msg, topic)
    else:
        got = getattr(msg, "__msgtype__", type(msg).__name__)
        if got != msgtype:
            msg_ = f"topic {topic!r} is declared as {msgtype!r}, got a {got!r} message"
            raise BagError(msg_)
        obj = msg
    try:
        return bytes(ts.serialize_cdr(obj, msgtype, little_endian=True))
    except (TypeError, ValueError, AttributeError, struct.error) as exc:
        msg_ = f"cannot serialize message for {topic!r} as {msgtype!r}: {exc}"
        raise BagError(msg_) from exc


def _build_message(ts: Typestore, msgtype: str, fields: Mapping[str, Any], where: str) -> object:
    """Build a rosbags message from a dict; nested messages may be dicts too."""
    cls = ts.types[msgtype]
    _, fielddefs = ts.fielddefs[msgtype]
    known = {name for name, _ in fielddefs}
    if unknown := set(fields) - known:
        msg = f"{where}: {msgtype} has no field(s) {sorted(unknown)}; fields: {sorted(known)}"
        raise BagError(msg)
    if missing := known - set(fields):
        msg = f"{where}: {msgtype} needs field(s) {sorted(missing)}"
        raise BagError(msg)
    kwargs: dict[str, Any] = {}
    for name, (nodetype, desc) in fielddefs:
        value = fields[name]
        if nodetype == Nodetype.NAME and isinstance(value, Mapping):
            value = _build_message(ts, cast(str, desc), value, f"{where}.{name}")
        elif nodetype in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            (subtype, sub), _ = cast("tuple[tuple[Nodetype, Any], int]", desc)
            if subtype != Nodetype.NAME:
                kwargs[name] = value
                continue
            value = [
                _build_message(ts, sub, v, f"{where}.{name}[{i}]") if isinstance(v, Mapping) else v
                for i, v in enumerate(value)
            ]
        kwargs[name] = value
    return cls(**kwargs)


def message_records(
    t: npt.NDArray[np.int64],
    columns: Sequence[tuple[int, str, int, npt.NDArray[np.float64]]],
    frame_id: str,
) -> tuple[bytes, ChannelRecords]:
    """MCAP message records for a batch, serialised together by numpy.

    ``columns`` holds, per topic, (channel id, message type, sequence number of the first
    message, values). Records go row by row (every topic at ``t[0]``, then at ``t[1]``...), with
    the bytes :func:`float64_cdr` / :func:`fluid_pressure_cdr` and mcap's ``Message.write`` make.
    Returns the records and, per channel, (channel id, log times, record offsets in the bytes).
    """
    n = len(t)
    sec, nanosec = np.divmod(t, NS_PER_S)
    if any(c[1] == FLUID_PRESSURE for c in columns) and n and int(sec.max()) > _INT32_MAX:
        msg = f"t_ns={int(t.max())!r} does not fit a builtin_interfaces/Time stamp (int32 seconds)"
        raise BagError(msg)
    raw = frame_id.encode() + b"\x00"
    pad = -(12 + len(raw)) % 8
    fields: list[tuple[str, Any]] = []
    for k, (_, msgtype, _, _) in enumerate(columns):
        fields += [(f"op{k}", "u1"), (f"len{k}", "<u8"), (f"ch{k}", "<u2"), (f"seq{k}", "<u4"),
                   (f"log{k}", "<u8"), (f"pub{k}", "<u8"), (f"cdr{k}", "<u4")]
        if msgtype == FLUID_PRESSURE:
            fields += [(f"sec{k}", "<i4"), (f"ns{k}", "<u4"), (f"slen{k}", "<u4"),
                       (f"frame{k}", f"S{len(raw)}")]
            if pad:
                fields.append((f"pad{k}", f"V{pad}"))
            fields += [(f"v{k}", "<f8"), (f"var{k}", "<f8")]
        else:
            fields.append((f"v{k}", "<f8"))
    row = np.dtype(fields)                      # packed: exactly the records' bytes
    rows = np.zeros(n, dtype=row)
    ut = t.astype(np.uint64)
    starts = []
    offsets = row.fields
    assert offsets is not None                  # a structured dtype has fields
    for k, (channel_id, msgtype, first_seq, v) in enumerate(columns):
        start = offsets[f"op{k}"][1]
        end = offsets[f"op{k + 1}"][1] if k + 1 < len(columns) else row.itemsize
        starts.append(start)
        rows[f"op{k}"] = Opcode.MESSAGE
        rows[f"len{k}"] = end - start - 9
        rows[f"ch{k}"] = channel_id
        rows[f"seq{k}"] = (np.arange(n, dtype=np.uint64) + np.uint64(first_seq)) & np.uint64(0xFFFFFFFF)
        rows[f"log{k}"] = ut
        rows[f"pub{k}"] = ut
        rows[f"cdr{k}"] = _CDR_LE_U32
        rows[f"v{k}"] = v
        if msgtype == FLUID_PRESSURE:
            rows[f"sec{k}"] = sec
            rows[f"ns{k}"] = nanosec
            rows[f"slen{k}"] = len(raw)
            rows[f"frame{k}"] = raw
    row_offsets = np.arange(n, dtype=np.uint64) * np.uint64(row.itemsize)
    entries = [(c[0], ut, row_offsets + np.uint64(s)) for c, s in zip(columns, starts)]
    return rows.tobytes(), entries


# -- reading --------------------------------------------------------------------------------

# CDR encapsulation byte 1 says the endianness: 1 little, 0 big (rosbags writes either).
_F64_BODY = {1: struct.Struct("<d"), 0: struct.Struct(">d")}
_FP_HEAD = {1: struct.Struct("<iII"), 0: struct.Struct(">iII")}
_FP_TAIL = {1: struct.Struct("<dd"), 0: struct.Struct(">dd")}


def _decode_float64(data: bytes) -> tuple[float]:
    return cast("tuple[float]", _F64_BODY[data[1]].unpack_from(data, 4))


def _decode_fluid_pressure(data: bytes) -> tuple[float, float, int]:
    little = data[1]
    sec, nanosec, slen = _FP_HEAD[little].unpack_from(data, 4)
    if slen == 0 or 16 + slen > len(data):
        msg = f"bad frame_id length {slen}"
        raise ValueError(msg)
    body_end = 12 + slen
    off = 4 + body_end + (-body_end % 8)
    p, var = _FP_TAIL[little].unpack_from(data, off)
    return (p, var, sec * NS_PER_S + nanosec)


#: Message type -> CDR bytes to a row: (data,) or (fluid_pressure, variance, stamp_ns).
DECODERS: Final[dict[str, Callable[[bytes], tuple[Any, ...]]]] = {
    FLOAT64: _decode_float64,
    FLUID_PRESSURE: _decode_fluid_pressure,
}
