"""Reading rosbag2 bags (directory with ``metadata.yaml`` and MCAP files, or one MCAP file).

Reading scans each MCAP file sequentially (``mcap.stream_reader.StreamReader`` for top-level
records, no index or summary needed), so unclosed and truncated files give back everything in
their complete chunks, and every loss is reported in ``BagContents.warnings``. rosbags' reader
and mcap's indexed reader refuse such files (measured: BENCHMARKS.md, "Reading cut-off bags").
Float64 and FluidPressure messages are decoded into arrays (:mod:`.cdr`).
"""

from __future__ import annotations

import io
import os
import re
import struct
import zlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, cast

import lz4.frame  # type: ignore[import-untyped]
import numpy as np
import numpy.typing as npt
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Header, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.well_known import MessageEncoding, Profile

from pcv_sim.errors import BagError
from pcv_sim.io.bag.cdr import DECODABLE_TYPES, DECODERS, FLOAT64, FLUID_PRESSURE
from pcv_sim.io.bag.metadata import load_metadata

__all__ = ["BagContents", "TopicSeries", "read_bag"]

_MAGIC: Final = b"\x89MCAP0\r\n"
_REC_HEAD: Final = struct.Struct("<BQ")  # MCAP record: opcode, body length
_MSG_HEAD: Final = struct.Struct("<HIQQ")  # MCAP message: channel, sequence, log/publish time


@dataclass(frozen=True)
class TopicSeries:
    """Decoded messages of one topic, in the order they were written (not sorted).

    ``t_ns`` is the bag's log time (int64 ns). ``fields`` maps field names to arrays of the
    same length: ``data`` for Float64; ``fluid_pressure`` (Pa), ``variance`` (Pa²) and
    ``stamp_ns`` (header stamp) for FluidPressure.
    """

    topic: str
    msgtype: str
    t_ns: npt.NDArray[np.int64]
    fields: Mapping[str, npt.NDArray[Any]]

    @property
    def value(self) -> npt.NDArray[np.float64]:
        """The primary value: Float64 ``data`` or FluidPressure ``fluid_pressure``."""
        return cast(npt.NDArray[np.float64], self.fields[_PRIMARY[self.msgtype]])

    @property
    def stamp_ns(self) -> npt.NDArray[np.int64] | None:
        """Header stamps (ns) for stamped types, else None."""
        return cast("npt.NDArray[np.int64] | None", self.fields.get("stamp_ns"))

    def __len__(self) -> int:
        return len(self.t_ns)


@dataclass(frozen=True)
class BagContents:
    """What :func:`read_bag` returns.

    ``closed_cleanly`` is False when a writer did not finish (no MCAP footer, no
    ``metadata.yaml``) or a file is truncated; ``warnings`` then says what was lost and where.
    ``topic_types`` lists every topic seen in the bag, decoded or not.
    """

    path: Path
    files: tuple[Path, ...]
    topics: Mapping[str, TopicSeries]
    topic_types: Mapping[str, str]
    closed_cleanly: bool
    warnings: tuple[str, ...] = field(default=())

    def __getitem__(self, topic: str) -> TopicSeries:
        return self.topics[topic]


_PRIMARY: Final = {FLOAT64: "data", FLUID_PRESSURE: "fluid_pressure"}


class _Accumulator:
    """Collects decoded values of one topic."""

    def __init__(self, topic: str, msgtype: str) -> None:
        self.topic = topic
        self.msgtype = msgtype
        self.t: list[int] = []
        self.rows: list[tuple[Any, ...]] = []
        self.bad = 0
        self.first_bad: str = ""
        self._decode = DECODERS[msgtype]

    def add(self, t: int, data: bytes) -> None:
        try:
            row = self._decode(data)
        except (struct.error, IndexError, KeyError, ValueError) as exc:
            if not self.bad:
                self.first_bad = f"log time {t} ns: {exc}"
            self.bad += 1
            return
        self.t.append(t)
        self.rows.append(row)

    def series(self) -> TopicSeries:
        t = np.asarray(self.t, dtype=np.int64)
        cols = list(zip(*self.rows, strict=True)) or [()] * 3
        fields: dict[str, npt.NDArray[Any]]
        if self.msgtype == FLOAT64:
            fields = {"data": np.asarray(cols[0], dtype=np.float64)}
        else:
            fields = {
                "fluid_pressure": np.asarray(cols[0], dtype=np.float64),
                "variance": np.asarray(cols[1], dtype=np.float64),
                "stamp_ns": np.asarray(cols[2], dtype=np.int64),
            }
        return TopicSeries(self.topic, self.msgtype, t, fields)


class _Prefix(io.RawIOBase):
    """Read-only view of the first ``end`` bytes of a file: StreamReader stops at a clean EOF."""

    def __init__(self, f: io.BufferedReader, end: int) -> None:
        self._f = f
        self._left = end

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        n = min(len(buffer), self._left)
        if n <= 0:
            return 0
        data = self._f.read(n)
        buffer[: len(data)] = data
        self._left -= len(data)
        return len(data)


@dataclass
class _Scan:
    """Where the complete records of an MCAP file end and whether it has its footer."""

    end: int
    closed: bool
    problem: str  # empty if the file is complete
    chunk_offsets: list[int]


def _scan_records(path: Path, f: io.BufferedReader, size: int) -> _Scan:
    """Walk record headers (9 bytes each, seeking over bodies) to find the readable prefix."""
    magic = f.read(8)
    if size == 0:
        msg = f"{str(path)!r} is empty (0 bytes); expected an MCAP file"
        raise BagError(msg)
    if magic != _MAGIC:
        if len(magic) < 8 and _MAGIC.startswith(magic):
            msg = (
                f"{str(path)!r} is truncated inside the MCAP magic ({size} bytes): no data can be "
                f"read; an MCAP file starts with 8 magic bytes and a Header record"
            )
        else:
            msg = (
                f"{str(path)!r} is not an MCAP file (magic {magic[:8]!r}); expected a rosbag2 "
                f"directory with metadata.yaml and .mcap files, or a single .mcap file"
            )
        raise BagError(msg)
    pos = 8
    chunks: list[int] = []
    first = True
    while True:
        head = f.read(9)
        if not head:
            if first:
                msg = f"{str(path)!r} ends right after the MCAP magic: no Header record, no data"
                raise BagError(msg)
            return _Scan(pos, False, "file ends without an MCAP footer", chunks)
        if first and (len(head) < 9 or pos + 9 + _REC_HEAD.unpack(head)[1] > size):
            msg = (
                f"{str(path)!r} is truncated inside its MCAP Header record ({size} bytes): "
                f"no data can be read"
            )
            raise BagError(msg)
        if len(head) < 9:
            return _Scan(pos, False, f"record header at byte {pos} is cut off", chunks)
        opcode, length = _REC_HEAD.unpack(head)
        if first and opcode != Opcode.HEADER:
            msg = f"{str(path)!r}: first MCAP record has opcode {opcode:#x}, expected a Header"
            raise BagError(msg)
        if pos + 9 + length > size:
            try:
                name = Opcode(opcode).name
            except ValueError:
                name = f"opcode {opcode:#x}"
            return _Scan(
                pos,
                False,
                f"{name} record at byte {pos} is cut off ({size - pos - 9} of {length} bytes)",
                chunks,
            )
        if opcode == Opcode.CHUNK:
            chunks.append(pos)
        pos += 9 + length
        first = False
        if opcode == Opcode.FOOTER:
            f.seek(pos)
            if f.read(8) == _MAGIC:
                return _Scan(pos, True, "", chunks)
            return _Scan(pos, False, "footer is not followed by the closing magic", chunks)
        f.seek(pos)


def _decompress(chunk: Chunk) -> bytes:
    """Uncompressed chunk payload, checked against its size and CRC."""
    if chunk.compression == "zstd":
        data = zstandard.decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        data = lz4.frame.decompress(chunk.data)
    elif chunk.compression == "":
        data = chunk.data
    else:
        msg = f"unsupported chunk compression {chunk.compression!r} (accepted: zstd, lz4, none)"
        raise ValueError(msg)
    if len(data) != chunk.uncompressed_size:
        msg = f"chunk holds {len(data)} bytes, its record says {chunk.uncompressed_size}"
        raise ValueError(msg)
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        msg = "chunk CRC mismatch"
        raise ValueError(msg)
    return data


class _McapFile:
    """Streams one MCAP file into per-topic accumulators; every loss ends up in ``warnings``.

    Top-level records come from ``mcap.stream_reader.StreamReader`` limited to the complete
    records found by :func:`_scan_records`. Chunk payloads are walked here with ``struct``
    (about 3x faster than ``mcap.stream_reader.breakup_chunk``, which builds a record object
    per message); Schema and Channel records are still parsed by ``mcap.records``.
    """

    def __init__(
        self,
        path: Path,
        wanted: set[str] | None,
        acc: dict[str, _Accumulator],
        types: dict[str, str],
        warnings: list[str],
    ) -> None:
        self.path = path
        self.wanted = wanted
        self.acc = acc
        self.types = types
        self.warnings = warnings
        self.schemas: dict[int, Schema] = {}
        self.sinks: dict[int, _Accumulator | None] = {}
        self.orphans = 0
        self.n_messages = 0

    def read(self) -> bool:
        """Read the file; return True if it was closed properly and nothing was damaged."""
        path = self.path
        try:
            f = open(path, "rb")
        except OSError as exc:
            msg = f"cannot open {str(path)!r}: {exc.strerror}"
            raise BagError(msg) from exc
        with f:
            size = os.fstat(f.fileno()).st_size
            scan = _scan_records(path, f, size)
            f.seek(0)
            bad_chunks: list[str] = []
            chunk_offsets = iter(scan.chunk_offsets)
            reader = StreamReader(_Prefix(f, scan.end), emit_chunks=True, validate_crcs=False)
            try:
                for rec in reader.records:
                    if isinstance(rec, Chunk):
                        offset = next(chunk_offsets, -1)
                        before = self.n_messages
                        try:
                            self._chunk(rec)
                        except (ValueError, struct.error, McapError, EOFError, RuntimeError,
                                zstandard.ZstdError) as exc:
                            got = self.n_messages - before
                            bad_chunks.append(
                                f"chunk at byte {offset} ({exc}; {got} messages read before it)"
                            )
                    elif isinstance(rec, Message):
                        self._message(rec.channel_id, rec.log_time, rec.data)
                    elif isinstance(rec, Schema):
                        self.schemas[rec.id] = rec
                    elif isinstance(rec, Channel):
                        self._channel(rec)
                    elif isinstance(rec, Header) and rec.profile not in (Profile.ROS2, ""):
                        self.warnings.append(
                            f"{path.name}: MCAP profile is {rec.profile!r}, not 'ros2'; "
                            f"decoding its CDR channels anyway"
                        )
            except EndOfFile:
                pass  # the readable prefix ends at a record boundary (clean files at the footer)
            except (McapError, struct.error, ValueError) as exc:
                self.warnings.append(f"{path.name}: stopped at a damaged record ({exc})")
                scan.closed = False

        name = path.name
        if not scan.closed:
            self.warnings.append(
                f"{name}: not closed properly ({scan.problem}); read {self.n_messages} messages "
                f"from the first {scan.end} of {size} bytes; messages its writer had not flushed "
                f"(at most its flush period for a pcv_sim writer) are not in the file"
            )
        if bad_chunks:
            self.warnings.append(
                f"{name}: {len(bad_chunks)} damaged chunk(s), their remaining messages are "
                f"missing: {'; '.join(bad_chunks)}"
            )
        if self.orphans:
            self.warnings.append(
                f"{name}: {self.orphans} message(s) on channels without a Channel record skipped"
            )
        return scan.closed and not bad_chunks

    def _chunk(self, chunk: Chunk) -> None:
        data = _decompress(chunk)
        n = len(data)
        pos = 0
        sinks = self.sinks
        while pos < n:
            opcode, length = _REC_HEAD.unpack_from(data, pos)
            start = pos + 9
            pos = start + length
            if pos > n:
                msg = f"record at chunk offset {start - 9} overruns the chunk"
                raise ValueError(msg)
            if opcode == Opcode.MESSAGE:
                channel_id, _, log_time, _ = _MSG_HEAD.unpack_from(data, start)
                sink = sinks.get(channel_id, self)
                if sink is self:
                    self.orphans += 1
                    continue
                self.n_messages += 1
                if sink is not None:
                    cast(_Accumulator, sink).add(log_time, data[start + 22 : pos])
            elif opcode == Opcode.SCHEMA:
                schema = Schema.read(ReadDataStream(io.BytesIO(data[start:pos])))
                self.schemas[schema.id] = schema
            elif opcode == Opcode.CHANNEL:
                self._channel(Channel.read(ReadDataStream(io.BytesIO(data[start:pos]))))

    def _message(self, channel_id: int, log_time: int, data: bytes) -> None:
        sink = self.sinks.get(channel_id, self)
        if sink is self:
            self.orphans += 1
            return
        self.n_messages += 1
        if sink is not None:
            cast(_Accumulator, sink).add(log_time, data)

    def _channel(self, rec: Channel) -> None:
        schema = self.schemas.get(rec.schema_id)
        known = self.types.setdefault(rec.topic, schema.name if schema is not None else "")
        msgtype = schema.name if schema is not None else known  # schemaless: trust metadata
        if known != msgtype:
            msg = (
                f"topic {rec.topic!r} has two types in {str(self.path)!r}: "
                f"{known!r} and {msgtype!r}; a topic must keep one type"
            )
            raise BagError(msg)
        take = self.wanted is None or rec.topic in self.wanted
        if take and msgtype in DECODERS and rec.message_encoding == MessageEncoding.CDR:
            if rec.topic not in self.acc:
                self.acc[rec.topic] = _Accumulator(rec.topic, msgtype)
            self.sinks[rec.id] = self.acc[rec.topic]
        else:
            self.sinks[rec.id] = None


def _file_index(p: Path) -> tuple[int, str]:
    m = re.search(r"_(\d+)\.mcap$", p.name)
    return (int(m.group(1)) if m else -1, p.name)


def read_bag(path: str | os.PathLike[str], topics: Iterable[str] | None = None) -> BagContents:
    """Read Float64 and FluidPressure topics of a bag into arrays.

    Args:
        path: rosbag2 directory (``metadata.yaml`` + ``.mcap``; written by pcv_sim, rosbags or
            ``ros2 bag``) or a single ``.mcap`` file.
        topics: Topics to decode; ``None`` decodes every topic of a decodable type and lists
            the others in ``warnings``.

    Raises:
        BagError: The path is missing or not a bag, no file is readable, a requested topic is
            absent or of a type not in :data:`DECODABLE_TYPES`.
    """
    root = Path(path)
    wanted: set[str] | None = None
    if topics is not None:
        wanted = {topics} if isinstance(topics, str) else set(topics)
    if not root.exists():
        msg = (
            f"bag path {str(root)!r} does not exist; expected a rosbag2 directory "
            f"(metadata.yaml + .mcap files) or a single .mcap file"
        )
        raise BagError(msg)

    warnings: list[str] = []
    meta: dict[str, Any] | None = None
    if root.is_dir():
        on_disk = sorted(root.glob("*.mcap"), key=_file_index)
        if (root / "metadata.yaml").is_file():
            meta = load_metadata(root)
            listed = [root / Path(str(p)).name for p in meta.get("relative_file_paths") or []]
            files = [p for p in listed if p.is_file()]
            if missing := [p.name for p in listed if not p.is_file()]:
                warnings.append(f"metadata.yaml lists missing file(s): {missing}")
            if extra := [p for p in on_disk if p not in listed]:
                warnings.append(
                    f"file(s) not listed in metadata.yaml were read too: {[p.name for p in extra]}"
                )
                files += extra
        else:
            files = on_disk
            if files:
                warnings.append(
                    "no metadata.yaml (the writer did not finish); read the .mcap files directly"
                )
        if not files:
            msg = (
                f"{str(root)!r} is not a bag: it contains no readable .mcap file"
                f"{'' if meta is not None else ' and no metadata.yaml'}; expected a rosbag2 "
                f"directory (metadata.yaml + .mcap files) or a single .mcap file"
            )
            raise BagError(msg)
    else:
        files = [root]

    acc: dict[str, _Accumulator] = {}
    types: dict[str, str] = {}
    meta_counts: dict[str, int] = {}
    if meta is not None:
        for entry in meta.get("topics_with_message_count") or []:
            tm = entry.get("topic_metadata", {})
            if "name" in tm:
                types.setdefault(str(tm["name"]), str(tm.get("type", "")))
                meta_counts[str(tm["name"])] = int(entry.get("message_count", 0))

    closed = meta is not None or not root.is_dir()
    readable = 0
    errors: list[str] = []
    for p in files:
        try:
            file_closed = _McapFile(p, wanted, acc, types, warnings).read()
        except BagError as exc:
            if len(files) == 1:
                raise
            errors.append(str(exc))
            closed = False
            continue
        readable += 1
        closed = closed and file_closed
    if errors:
        if not readable:
            msg = "no file of the bag is readable: " + "; ".join(errors)
            raise BagError(msg)
        warnings.extend(f"unreadable file skipped: {e}" for e in errors)

    accepted = ", ".join(DECODABLE_TYPES)
    if wanted is not None:
        if absent := sorted(wanted - set(types)):
            listing = ", ".join(f"{t} ({types[t]})" for t in sorted(types)) or "none"
            msg = f"topic(s) {absent} not in bag {str(root)!r}; topics in the bag: {listing}"
            raise BagError(msg)
        if foreign := sorted(t for t in wanted if types[t] not in DECODERS):
            listing = ", ".join(f"{t} is {types[t]!r}" for t in foreign)
            msg = f"cannot decode {listing}; decodable types: {accepted}"
            raise BagError(msg)
        selected = wanted
    else:
        selected = {t for t, ty in types.items() if ty in DECODERS}
        if others := sorted(set(types) - selected):
            listing = ", ".join(f"{t} ({types[t]})" for t in others)
            warnings.append(f"not decoded (type not in {accepted}): {listing}")
        if types and not selected:
            listing = ", ".join(f"{t} is {types[t]!r}" for t in sorted(types))
            msg = f"no topic of {str(root)!r} can be decoded: {listing}; decodable: {accepted}"
            raise BagError(msg)

    series: dict[str, TopicSeries] = {}
    for topic in sorted(selected):
        a = acc.get(topic) or _Accumulator(topic, types[topic])
        if a.bad:
            warnings.append(
                f"{topic}: {a.bad} message(s) could not be decoded as {a.msgtype} "
                f"(first at {a.first_bad})"
            )
        series[topic] = a.series()
        expected = meta_counts.get(topic)
        if closed and expected is not None and expected != len(a.t) + a.bad:
            warnings.append(
                f"{topic}: metadata.yaml says {expected} messages, the files hold "
                f"{len(a.t) + a.bad}"
            )

    return BagContents(
        path=root,
        files=tuple(files),
        topics=series,
        topic_types=dict(sorted(types.items())),
        closed_cleanly=closed,
        warnings=tuple(warnings),
    )
