"""Reading a recording back, trusting only what is intact.

Every MCAP file (a recording, a rosbag2's storage) is read linearly, each record's structure
checked; each chunk's content is checked against its CRC and, when the file has an intact
summary (its own CRC checked), its header against the summary's index of it. A chunk that
fails any check is skipped whole, never half-used; reading goes on at the next chunk (the
index says where; without one, the next place where a chunk starts whose CRC holds). What
was skipped is :attr:`RecordingReader.damage`: each stretch with its bytes, its chunk and the
log-time span of the messages lost. A file cut short (a hard kill) is read up to its last
complete record; a record cut off at the end counts as damage too.

Decompression is bounded by the chunk's declared size (at most :data:`MAX_CHUNK_BYTES`), and
the search for the next chunk after damage by a multiple of the file's size, so a hostile
file costs time and memory linear in its size.
"""

from __future__ import annotations

import bisect
import importlib
import io
import mmap
import os
import struct
import zlib
from collections.abc import Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fpgalink.recording.files import RecordingError

__all__ = ["MAX_CHUNK_BYTES", "Channel", "Damage", "Message", "NotARecording",
           "RecordingReader", "Schema"]

MAGIC = b"\x89MCAP0\r\n"
#: The largest chunk read (its content, uncompressed): larger is taken for damage.
MAX_CHUNK_BYTES = 256 * 1024 * 1024
_HEADER, _FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _MESSAGE_INDEX, _CHUNK_INDEX = range(1, 9)
_ATTACHMENT, _ATTACHMENT_INDEX, _STATISTICS, _METADATA, _METADATA_INDEX = range(9, 14)
_SUMMARY_OFFSET, _DATA_END = 14, 15
_COMPRESSIONS = ("", "zstd", "lz4")
_FOOTER_BYTES = 1 + 8 + 20  # opcode, length, summary start, summary offset start, CRC


class NotARecording(RecordingError):
    """The file is not an MCAP file at all (or ends before its first record)."""


class _Malformed(Exception):
    """A record whose bytes do not make one."""


@dataclass(frozen=True, slots=True)
class Schema:
    id: int
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True, slots=True)
class Channel:
    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]


@dataclass(frozen=True, slots=True)
class Message:
    channel_id: int
    sequence: int
    log_time: int  #: ns
    publish_time: int  #: ns
    data: bytes


@dataclass(slots=True)
class Damage:
    """A stretch of the file that was skipped."""

    offset: int  #: where it starts, bytes
    end: int  #: where reading went on (the file's size when it did not)
    reason: str
    chunk: int | None = None  #: the chunk it is (1-based), when it is one
    start_ns: int | None = None  #: the log times of what was lost: the chunk's own …
    end_ns: int | None = None
    exact: bool = False  #: … (True), or between the intact chunks around it (False)

    def describe(self, origin_ns: int | None) -> str:
        where = (f"chunk {self.chunk} (bytes {self.offset}–{self.end})" if self.chunk
                 else f"bytes {self.offset}–{self.end}")
        return f"{where}{self._span(origin_ns)}: {self.reason}"

    def _span(self, origin_ns: int | None) -> str:
        if origin_ns is None or (self.start_ns is None and self.end_ns is None):
            return ""

        def at(ns: int | None, default: str) -> str:
            return default if ns is None else f"{(ns - origin_ns) / 1e9:.3f} s"

        if self.exact:
            return f", log time {at(self.start_ns, '?')}–{at(self.end_ns, '?')}"
        return (f", log time between {at(self.start_ns, 'the start')} and "
                f"{at(self.end_ns, 'the end')}")


class _Cursor:
    """Reads little-endian fields from ``buf[pos:end]``; :class:`_Malformed` past the end."""

    __slots__ = ("buf", "end", "pos")

    def __init__(self, buf: Any, pos: int, end: int) -> None:
        self.buf, self.pos, self.end = buf, pos, end

    def take(self, size: int) -> int:
        start = self.pos
        if size < 0 or start + size > self.end:
            raise _Malformed
        self.pos = start + size
        return start

    def u16(self) -> int:
        return int(struct.unpack_from("<H", self.buf, self.take(2))[0])

    def u32(self) -> int:
        return int(struct.unpack_from("<I", self.buf, self.take(4))[0])

    def u64(self) -> int:
        return int(struct.unpack_from("<Q", self.buf, self.take(8))[0])

    def raw(self, size: int) -> bytes:
        start = self.take(size)
        return bytes(self.buf[start:start + size])

    def text(self) -> str:
        try:
            return self.raw(self.u32()).decode("utf-8")
        except UnicodeDecodeError:
            raise _Malformed from None

    def sub(self, size: int) -> _Cursor:
        """The next ``size`` bytes as a cursor of their own."""
        start = self.take(size)
        return _Cursor(self.buf, start, start + size)

    def text_map(self) -> dict[str, str]:
        inner = self.sub(self.u32())
        pairs = {}
        while inner.pos < inner.end:
            key = inner.text()
            pairs[key] = inner.text()
        return pairs

    def done(self) -> None:
        if self.pos != self.end:
            raise _Malformed


@dataclass(slots=True)
class _ChunkHeader:
    start_ns: int
    end_ns: int
    uncompressed_size: int
    crc: int
    compression: str
    data_at: int
    data_size: int


@dataclass(slots=True)
class _Index:
    start_ns: int
    end_ns: int
    offset: int
    length: int
    compression: str
    compressed_size: int
    uncompressed_size: int


@dataclass
class _Summary:
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunks: list[_Index] = field(default_factory=list)
    start_ns: int | None = None


class RecordingReader:
    """An MCAP file, read back with every chunk checked (``with`` closes it). Iterate
    :meth:`messages`; then :attr:`damage` lists what was skipped, :attr:`complete` says
    whether the file was finished (an intact summary), :attr:`skipped_messages` counts
    messages of an intact chunk whose channel was lost with a damaged one, and
    :attr:`metadata` holds the metadata records read on the way (by name; they stand between
    chunks, covered by the data section's CRC, not a chunk's)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.damage: list[Damage] = []
        self.complete = False
        self.skipped_messages = 0
        self.chunks = 0  #: intact chunks read
        self.chunks_without_crc = 0  #: of them, those whose content had no CRC to check
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.metadata: dict[str, dict[str, str]] = {}
        self._origin: int | None = None
        self._header_ok = False
        self._file = path.open("rb")
        try:
            size = os.fstat(self._file.fileno()).st_size
            self._buf: Any = (mmap.mmap(self._file.fileno(), 0, access=mmap.ACCESS_READ)
                              if size else b"")
        except BaseException:
            self._file.close()
            raise
        self.size = len(self._buf)
        self._data_end = self.size  #: where the data section ends (the summary's start)
        if self.size < len(MAGIC) or bytes(self._buf[:len(MAGIC)]) != MAGIC:
            self.close()
            raise NotARecording(f"{path}: not a readable MCAP file (no MCAP magic at its "
                                "start)")
        self._summary = self._read_summary()

    def __enter__(self) -> RecordingReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if isinstance(self._buf, mmap.mmap):
            self._buf.close()
        self._file.close()

    @property
    def origin_ns(self) -> int | None:
        """The earliest log time known: what damage's times are counted from."""
        return self._origin

    def _seen(self, ns: int) -> None:
        self._origin = ns if self._origin is None else min(self._origin, ns)

    # --- the summary --------------------------------------------------------------------------

    def _read_summary(self) -> _Summary | None:
        """The summary, if the file has one and it is intact (else a damage entry)."""
        at = self.size - len(MAGIC) - _FOOTER_BYTES
        if at < len(MAGIC) or bytes(self._buf[self.size - len(MAGIC):]) != MAGIC:
            return None  # not finished: no footer
        cursor = _Cursor(self._buf, at, self.size - len(MAGIC))
        try:
            if cursor.raw(1)[0] != _FOOTER or cursor.u64() != 20:
                return None
            start, _offsets, crc = cursor.u64(), cursor.u64(), cursor.u32()
        except _Malformed:
            return None
        if start == 0:
            return None  # finished without a summary
        if not len(MAGIC) <= start <= at or (
                crc and zlib.crc32(self._buf[start:at + 1 + 8 + 16]) != crc):
            self.damage.append(Damage(start if start <= at else at, self.size,
                                      "the summary (the file's index) is damaged: read "
                                      "without it"))
            return None
        summary = _Summary()
        try:
            self._parse_summary(summary, start, at)
        except _Malformed:
            self.damage.append(Damage(start, self.size, "the summary (the file's index) does "
                                      "not parse: read without it"))
            return None
        self.complete = True
        self._data_end = start
        self.schemas.update(summary.schemas)
        self.channels.update(summary.channels)
        for index in summary.chunks:
            self._seen(index.start_ns)
        return summary

    def _parse_summary(self, summary: _Summary, start: int, end: int) -> None:
        pos = start
        while pos < end:
            cursor = _Cursor(self._buf, pos, end)
            opcode = cursor.raw(1)[0]
            body = cursor.sub(cursor.u64())
            if opcode == _SCHEMA:
                schema = _schema(body)
                summary.schemas[schema.id] = schema
            elif opcode == _CHANNEL:
                channel = _channel(body)
                summary.channels[channel.id] = channel
            elif opcode == _CHUNK_INDEX:
                summary.chunks.append(_chunk_index(body))
            elif opcode == _STATISTICS:
                body.take(8 + 2 + 4 + 4 + 4 + 4)
                summary.start_ns = body.u64()
            pos = cursor.pos
        summary.chunks.sort(key=lambda index: index.offset)

    # --- the data section ---------------------------------------------------------------------

    def messages(self, topics: Collection[str] | None = None
                 ) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """Every message of every intact chunk (of ``topics``, when given), in file order.
        :class:`NotARecording` at the end when the file had neither an MCAP header record
        nor any intact chunk."""
        yield from self._messages(topics)
        if not self._header_ok and not self.chunks:
            raise NotARecording(f"{self.path}: not a readable MCAP file (after its magic, "
                                "neither a header record nor any intact chunk)")

    def _messages(self, topics: Collection[str] | None
                  ) -> Iterator[tuple[Schema | None, Channel, Message]]:
        wanted = None if topics is None else set(topics)
        indexes = {i.offset: (n, i) for n, i in enumerate(self._summary.chunks, 1)} \
            if self._summary else {}
        offsets = sorted(indexes)
        budget = 4 * self.size + (64 << 20)  # decompression while searching after damage
        chunks_seen = 0
        pos = len(MAGIC)
        open_damage: Damage | None = None  # its span ends where the next intact chunk starts
        last_good_end: int | None = None
        while pos < self._data_end:
            problem, length, opcode = self._record_at(pos, offsets)
            if pos == len(MAGIC) and problem is None and opcode == _HEADER:
                self._header_ok = True
            number, index = indexes.get(pos, (None, None))
            if not indexes and opcode == _CHUNK:
                chunks_seen += 1
                number = chunks_seen
            if problem is None and index is not None and opcode != _CHUNK:
                problem = "not a chunk where the file's index has one (damaged)"
            framed = False  # whether the record's own length can be trusted
            if problem is None and opcode == _CHUNK:
                found, header = self._read_chunk(pos, length, index)
                if not isinstance(found, str):
                    assert header is not None
                    if open_damage is not None:
                        open_damage.end_ns = header.start_ns
                        open_damage = None
                    last_good_end = header.end_ns
                    self._seen(header.start_ns)
                    yield from self._deliver(found, wanted)
                    pos += 9 + length
                    continue
                problem = found
                # Its header parsed whole (and agrees with the index on its length): the
                # damage is inside it, and reading goes on right after it.
                framed = header is not None and (index is None or index.length == 9 + length)
            elif problem is None:
                if opcode == _DATA_END:
                    if not any(d.offset < pos for d in self.damage):  # else it says nothing new
                        self._check_data_crc(pos)
                    return
                if opcode == _METADATA:  # its fields were checked against its length
                    cursor = _Cursor(self._buf, pos + 9, pos + 9 + length)
                    name = cursor.text()
                    self.metadata[name] = cursor.text_map()
                pos += 9 + length
                continue
            # Damage: skipped up to the end of a chunk whose framing holds, else to the next
            # place a chunk is known (or found) to start.
            if framed:
                resume = pos + 9 + length
            else:
                resume, budget = self._resume(pos, offsets, budget)
            damage = Damage(pos, resume if index is None else pos + index.length, problem,
                            number)
            if index is not None:
                damage.start_ns, damage.end_ns, damage.exact = (index.start_ns, index.end_ns,
                                                                True)
            else:
                damage.start_ns = last_good_end
                open_damage = damage
            self.damage.append(damage)
            pos = resume

    def _record_at(self, pos: int, offsets: list[int]) -> tuple[str | None, int, int]:
        """(what is wrong with the record at ``pos`` or ``None``, its length, its opcode)."""
        if pos + 9 > self._data_end:
            return "cut short: the file ends inside it", 0, 0
        opcode = self._buf[pos]
        length = int(struct.unpack_from("<Q", self._buf, pos + 1)[0])
        if not _HEADER <= opcode <= _DATA_END:
            return "not a record (damaged)", length, opcode
        if pos + 9 + length > self._data_end:
            torn = not self.complete and length < self.size
            return ("cut short: the file ends inside it" if torn else
                    "a record running past the data's end (damaged)"), length, opcode
        # A known chunk start inside this record: its length is wrong.
        if offsets and opcode != _CHUNK and _crosses(offsets, pos, pos + 9 + length):
            return "a record overlapping the next chunk (damaged)", length, opcode
        if opcode != _CHUNK:
            try:
                _check_structure(opcode, _Cursor(self._buf, pos + 9, pos + 9 + length))
            except _Malformed:
                return "a record whose fields do not fit its length (damaged)", length, opcode
        return None, length, opcode

    def _read_chunk(self, pos: int, length: int, index: _Index | None
                    ) -> tuple[list[Any] | str, _ChunkHeader | None]:
        """The chunk's records, or why it is damaged."""
        try:
            header = _chunk_header(_Cursor(self._buf, pos + 9, pos + 9 + length))
        except _Malformed:
            return "its header does not parse", None
        if index is not None and (
                index.length != 9 + length or index.start_ns != header.start_ns
                or index.end_ns != header.end_ns or index.compression != header.compression
                or index.compressed_size != header.data_size
                or index.uncompressed_size != header.uncompressed_size):
            return "its header differs from the file's index of it", header
        content = self._content(header)
        if isinstance(content, str):
            return content, header
        if header.crc:
            if zlib.crc32(content) != header.crc:
                return "its content fails its CRC", header
        else:
            self.chunks_without_crc += 1
        try:
            records = _chunk_records(content)
        except _Malformed:
            return "its records do not parse", header
        self.chunks += 1
        return records, header

    def _content(self, header: _ChunkHeader) -> bytes | str:
        if header.compression not in _COMPRESSIONS:
            return f"an unknown compression {header.compression[:20]!r}"
        if header.uncompressed_size > MAX_CHUNK_BYTES:
            return "it says it is larger than a chunk can be"
        data = self._buf[header.data_at:header.data_at + header.data_size]
        size = header.uncompressed_size
        try:
            if header.compression == "zstd":
                import zstandard

                with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data)) as stream:
                    content: bytes = stream.read(size + 1)
            elif header.compression == "lz4":
                try:
                    lz4: Any = importlib.import_module("lz4.frame")  # optional, untyped
                except ImportError:
                    return "lz4 compression (the lz4 package is not installed)"
                content = lz4.LZ4FrameDecompressor().decompress(bytes(data),
                                                                max_length=size + 1)
            else:
                content = bytes(data)
        except Exception:  # the codecs' own errors on damaged input
            return "its content does not decompress"
        if len(content) != size:
            return "its content is not the size it says"
        return content

    def _resume(self, pos: int, offsets: list[int], budget: int) -> tuple[int, int]:
        """Where reading goes on after damage at ``pos``: the next chunk the index knows, or
        the next place a chunk with a good CRC starts; the file's end when there is none.
        ``budget``: decompression left for searching."""
        if offsets:
            later = bisect.bisect_right(offsets, pos)
            return (offsets[later] if later < len(offsets) else self._data_end), budget
        at = pos + 1
        while budget > 0:
            at = self._buf.find(b"\x06", at)
            if at < 0 or at + 9 > self._data_end:
                return self._data_end, budget
            length = int(struct.unpack_from("<Q", self._buf, at + 1)[0])
            if at + 9 + length <= self._data_end:
                try:
                    header = _chunk_header(_Cursor(self._buf, at + 9, at + 9 + length))
                except _Malformed:
                    header = None
                if header is not None and header.compression in _COMPRESSIONS \
                        and header.crc and header.uncompressed_size <= MAX_CHUNK_BYTES:
                    budget -= header.uncompressed_size + header.data_size
                    content = self._content(header)
                    if not isinstance(content, str) and zlib.crc32(content) == header.crc:
                        return at, budget
            at += 1
        return self._data_end, budget

    def _deliver(self, records: list[Any], wanted: set[str] | None
                 ) -> Iterator[tuple[Schema | None, Channel, Message]]:
        for record in records:
            if isinstance(record, Schema):
                self.schemas.setdefault(record.id, record)
            elif isinstance(record, Channel):
                self.channels.setdefault(record.id, record)
            else:
                channel = self.channels.get(record.channel_id)
                if channel is None:
                    self.skipped_messages += 1
                elif wanted is None or channel.topic in wanted:
                    yield self.schemas.get(channel.schema_id), channel, record

    def _check_data_crc(self, at: int) -> None:
        crc = int(struct.unpack_from("<I", self._buf, at + 9)[0])
        if crc and zlib.crc32(self._buf[:at]) != crc:
            self.damage.append(Damage(0, at, "the data section fails its CRC: damage "
                                      "outside the chunks (their indexes or metadata)"))


def _crosses(offsets: list[int], start: int, end: int) -> bool:
    """Whether a chunk offset lies strictly inside ``(start, end)``."""
    i = bisect.bisect_right(offsets, start)
    return i < len(offsets) and offsets[i] < end


def _schema(body: _Cursor) -> Schema:
    schema = Schema(body.u16(), body.text(), body.text(), body.raw(body.u32()))
    body.done()
    return schema


def _channel(body: _Cursor) -> Channel:
    channel = Channel(body.u16(), body.u16(), body.text(), body.text(), body.text_map())
    body.done()
    return channel


def _chunk_index(body: _Cursor) -> _Index:
    start, end, offset, length = body.u64(), body.u64(), body.u64(), body.u64()
    body.take(body.u32())  # message index offsets
    body.u64()
    index = _Index(start, end, offset, length, body.text(), body.u64(), body.u64())
    body.done()
    return index


def _chunk_header(body: _Cursor) -> _ChunkHeader:
    start, end, size, crc = body.u64(), body.u64(), body.u64(), body.u32()
    compression = body.raw(min(body.u32(), 64)).decode("ascii", "replace")
    data_size = body.u64()
    data_at = body.take(data_size)
    body.done()
    return _ChunkHeader(start, end, size, crc, compression, data_at, data_size)


def _check_structure(opcode: int, body: _Cursor) -> None:
    """A record outside the chunks, its fields against its length: a damaged length or
    opcode (a chunk's, turned into another record's) is found here, and never carries the
    reading over a chunk unseen."""
    if opcode == _MESSAGE_INDEX:
        body.u16()
        entries = body.u32()
        if entries % 16:
            raise _Malformed
        body.take(entries)
    elif opcode == _DATA_END:
        body.u32()
    elif opcode == _METADATA:
        body.text()
        body.text_map()
    elif opcode == _HEADER:
        body.text()
        body.text()
    elif opcode == _SCHEMA:
        _schema(body)
        return
    elif opcode == _CHANNEL:
        _channel(body)
        return
    elif opcode == _CHUNK_INDEX:
        _chunk_index(body)
        return
    elif opcode == _ATTACHMENT:
        body.take(16)
        body.text()
        body.text()
        body.take(body.u64())
        body.take(4)
    elif opcode == _ATTACHMENT_INDEX:
        body.take(40)
        body.text()
        body.text()
    elif opcode == _STATISTICS:
        body.take(8 + 2 + 4 * 4 + 16)
        body.take(body.u32())
    elif opcode == _METADATA_INDEX:
        body.take(16)
        body.text()
    elif opcode == _SUMMARY_OFFSET:
        body.take(17)
    elif opcode == _FOOTER:
        body.take(20)
    body.done()


#: A message record's start: opcode, length, channel, sequence, log and publish time.
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
_RECORD_HEAD = struct.Struct("<BQ")


def _chunk_records(content: bytes) -> list[Any]:
    """The records of a chunk's content (messages read in one unpack each: a chunk holds
    hundreds)."""
    records: list[Any] = []
    pos, end = 0, len(content)
    message_head, record_head = _MESSAGE_HEAD, _RECORD_HEAD
    while pos < end:
        if content[pos] == _MESSAGE and pos + 31 <= end:
            _, length, channel_id, sequence, log_time, publish_time = \
                message_head.unpack_from(content, pos)
            stop = pos + 9 + length
            if length < 22 or stop > end:
                raise _Malformed
            records.append(Message(channel_id, sequence, log_time, publish_time,
                                   content[pos + 31:stop]))
            pos = stop
            continue
        if pos + 9 > end:
            raise _Malformed
        opcode, length = record_head.unpack_from(content, pos)
        cursor = _Cursor(content, pos + 9, pos + 9 + length)
        if cursor.end > end:
            raise _Malformed
        if opcode == _SCHEMA:
            records.append(_schema(cursor))
        elif opcode == _CHANNEL:
            records.append(_channel(cursor))
        elif not _HEADER <= opcode <= _DATA_END:
            raise _Malformed
        pos = cursor.end
    return records
