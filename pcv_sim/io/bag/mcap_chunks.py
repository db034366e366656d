"""The one place that depends on private parts of the ``mcap`` package (its Writer's layout).

Why: the bulk path (:meth:`pcv_sim.io.bag.BagWriter.write_samples`) hands whole arrays of
message records to the current chunk at once, and indexes them from arrays. mcap's public
``Writer.add_message`` takes one message per call (~3.5 µs each with our CDR packing), which made
10 kHz recording late through the interpreter lock (BENCHMARKS.md, Recording). So the Writer's
private chunk builder (``Writer.__chunk_builder``, an ``mcap._chunk_builder.ChunkBuilder``) is
replaced with :class:`ChunkBuilder`, which writes the same bytes and also takes records in bulk,
and the Writer's private statistics are kept as ``add_message`` keeps them.

The check: :func:`attach` replaces the builder only for an mcap release in
:data:`SUPPORTED_MCAP` whose Writer has exactly that layout; otherwise it returns None and the
writer goes message by message through the public API: the same file bytes, slower
(test/io/test_bag_samples.py checks both paths).
"""

from __future__ import annotations

import importlib.metadata
from collections.abc import Mapping
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, Message, Schema
from mcap.writer import Writer as McapWriter

from pcv_sim.io.bag.cdr import ChannelRecords

try:  # private module: may move in another release (then no bulk path)
    from mcap._chunk_builder import ChunkBuilder as _McapChunkBuilder
except ImportError:  # pragma: no cover - depends on the installed mcap
    _McapChunkBuilder = None  # type: ignore[assignment,misc]

__all__ = ["MCAP_VERSION", "SUPPORTED_MCAP", "BulkChunks", "ChunkBuilder", "attach"]

#: (major, minor) releases of ``mcap`` whose Writer internals this module was checked against.
SUPPORTED_MCAP: Final = ((1, 6),)
MCAP_VERSION: str = importlib.metadata.version("mcap")

_BUILDER: Final = "_Writer__chunk_builder"   # name-mangled private attributes of mcap's Writer
_STATS: Final = "_Writer__statistics"


def _release(version: str) -> tuple[int, int] | None:
    parts = version.split(".")
    try:
        return int(parts[0]), int(parts[1])
    except (IndexError, ValueError):
        return None


class _MessageIndex:
    """An MCAP MessageIndex for one channel of the chunk being built, kept as arrays."""

    def __init__(self, channel_id: int) -> None:
        self.channel_id = channel_id
        self._parts: list[npt.NDArray[np.uint64]] = []   # (n, 2) arrays of (log_time, offset)
        self._pending: list[int] = []                    # single entries: t0, o0, t1, o1, ...

    def add(self, log_time: int, offset: int) -> None:
        self._pending += (log_time, offset)

    def add_array(self, log_times: npt.NDArray[np.uint64], offsets: npt.NDArray[np.uint64]) -> None:
        self._take_pending()
        self._parts.append(np.stack([log_times, offsets], axis=1).astype("<u8", copy=False))

    def _take_pending(self) -> None:
        if self._pending:
            self._parts.append(np.array(self._pending, dtype="<u8").reshape(-1, 2))
            self._pending = []

    def write(self, stream: RecordBuilder) -> None:
        """The record mcap's ``MessageIndex.write`` makes, from one array."""
        self._take_pending()
        pairs = np.concatenate(self._parts) if self._parts else np.empty((0, 2), "<u8")
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(pairs) * 16)
        stream.write(pairs.astype("<u8", copy=False).tobytes())
        stream.finish_record()


class ChunkBuilder:
    """Stands in for ``mcap._chunk_builder.ChunkBuilder`` (mcap 1.6) inside the mcap Writer:
    the same records and message indexes byte for byte, plus :meth:`add_records` for message
    records serialised in bulk, and message indexes written from arrays (a chunk of 30 000
    messages is indexed in well under a millisecond instead of ~30 ms of per-entry packing)."""

    def __init__(self) -> None:
        self.message_end_time = 0
        self.message_indices: dict[int, _MessageIndex] = {}
        self.message_start_time = 0
        self.record_writer = RecordBuilder()
        self.num_messages = 0

    @property
    def count(self) -> int:
        return self.record_writer.count

    def end(self) -> bytes:
        return bytes(self.record_writer.end())    # the same object: end() returns bytes, unannotated

    def add_channel(self, channel: Channel) -> None:
        channel.write(self.record_writer)

    def add_schema(self, schema: Schema) -> None:
        schema.write(self.record_writer)

    def _index(self, channel_id: int) -> _MessageIndex:
        index = self.message_indices.get(channel_id)
        if index is None:
            index = self.message_indices[channel_id] = _MessageIndex(channel_id)
        return index

    def _times(self, t_min: int, t_max: int) -> None:
        if self.num_messages == 0:
            self.message_start_time = t_min
        else:
            self.message_start_time = min(self.message_start_time, t_min)
        self.message_end_time = max(self.message_end_time, t_max)

    def add_message(self, message: Message) -> None:
        self._times(message.log_time, message.log_time)
        self._index(message.channel_id).add(message.log_time, self.record_writer.count)
        self.num_messages += 1
        message.write(self.record_writer)

    def add_records(self, data: bytes, entries: ChannelRecords, t_min: int, t_max: int, n: int) -> None:
        """Append ``n`` message records serialised together; ``entries`` holds, per channel,
        log times and record offsets relative to the start of ``data``."""
        base = self.record_writer.count
        self._times(t_min, t_max)
        for channel_id, times, offsets in entries:
            self._index(channel_id).add_array(times, offsets + np.uint64(base))
        self.num_messages += n
        self.record_writer.write(data)

    def reset(self) -> None:
        self.message_end_time = 0
        self.message_indices.clear()
        self.message_start_time = 0
        self.record_writer.end()
        self.num_messages = 0


class BulkChunks:
    """Bulk access to one mcap Writer whose chunk builder :func:`attach` replaced."""

    def __init__(self, builder: ChunkBuilder, stats: Any) -> None:
        self._builder = builder
        self._stats = stats

    def add_records(self, data: bytes, entries: ChannelRecords, t_min: int, t_max: int,
                    per_channel: Mapping[int, int]) -> None:
        """Append message records to the current chunk; ``per_channel``: messages per channel.
        The Writer's statistics are updated as its ``add_message`` would."""
        n = sum(per_channel.values())
        self._builder.add_records(data, entries, t_min, t_max, n)
        stats = self._stats
        if stats.message_count == 0:
            stats.message_start_time = t_min
        else:
            stats.message_start_time = min(stats.message_start_time, t_min)
        stats.message_end_time = max(stats.message_end_time, t_max)
        stats.message_count += n
        for channel_id, count in per_channel.items():
            stats.channel_message_counts[channel_id] += count


def attach(writer: McapWriter, version: str | None = None) -> BulkChunks | None:
    """Replace ``writer``'s chunk builder before ``writer.start()``; None when the installed
    mcap (``version``, default :data:`MCAP_VERSION`) is not a checked release or its Writer is
    laid out differently: the caller then writes message by message."""
    if _release(version or MCAP_VERSION) not in SUPPORTED_MCAP or _McapChunkBuilder is None:
        return None
    builder = getattr(writer, _BUILDER, None)
    stats = getattr(writer, _STATS, None)
    if not isinstance(builder, _McapChunkBuilder) or builder.num_messages or stats is None:
        return None
    if not all(hasattr(stats, a) for a in ("message_count", "message_start_time",
                                           "message_end_time", "channel_message_counts")):
        return None
    ours = ChunkBuilder()
    setattr(writer, _BUILDER, ours)
    return BulkChunks(ours, stats)
