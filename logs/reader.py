"""Read an MCAP log into time-ordered :class:`~logs.message.Message` events, surviving damage.

The reader walks the data section record by record (it does not trust the summary at the end,
which a killed writer never wrote), checks every chunk (decompression and CRC), and stops at the
first record that is cut short or corrupt. Everything before that point is read; the point
itself is reported as a :class:`ReadProblem` (byte offset, file size, last good time), both as
``reader.problem`` and as a :class:`McapReadWarning`. Messages are then merged across chunks in
log-time order (ties in file order), decompressing a chunk only when its turn comes.

Payloads: images → ``numpy`` arrays, Foxglove poses/transforms/calibration/annotations → dicts
(:func:`logs.foxglove.decode`; quaternions ``[w, x, y, z]``), JSON → dicts, other protobuf →
dicts (``MessageToDict``), anything else → the raw bytes.

Example:
    >>> import os, tempfile
    >>> from adfusion.logs import LogWriter, McapLogReader
    >>> path = os.path.join(tempfile.mkdtemp(), "run.mcap")
    >>> with LogWriter(path) as log:
    ...     log.write_json("/mag", 0.02, {"b_body": [1.0, 2.0, 3.0]})
    ...     log.write_json("/mag", 0.01, {"b_body": [0.0, 2.0, 3.0]})
    >>> reader = McapLogReader(path)
    >>> [(m.t_s, m.payload["b_body"][0]) for m in reader], reader.problem
    ([(0.01, 0.0), (0.02, 1.0)], None)
"""

from __future__ import annotations

import hashlib
import heapq
import io
import json
import os
import struct
import warnings
import zlib
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from adfusion.logs import foxglove as fg
from adfusion.logs.jsonio import decode_metadata
from adfusion.logs.message import Message
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, ChunkIndex, Metadata, Schema, Statistics
from mcap.records import Message as McapMessage
from mcap.stream_reader import breakup_chunk

from adfusion.plain import listed

MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEADER = struct.Struct("<BQ")
_CHUNK_TIMES = struct.Struct("<QQ")  # a chunk record starts with its message time range


class McapReadWarning(UserWarning):
    """An MCAP input was truncated or corrupt; the message says where."""


class NotMcapError(ValueError):
    """The input is not an MCAP file at all (it does not start with the MCAP magic)."""


@dataclass(frozen=True)
class ReadProblem:
    """Where an MCAP input broke, and what was lost there.

    Attributes:
        path: the file.
        offset: byte offset of the first record that could not be read (−1: a problem of
            the whole file, e.g. a message count that does not add up).
        file_size: size of the file in bytes.
        last_good_t_s: latest message time before the break (``None`` if nothing was read).
        good_chunks: complete chunks read before the break.
        reason: what was wrong there.
        resumed_at: byte offset where reading went on after the damage (``None``: it
            stopped there).
        lost_messages: messages lost here, when the file says how many (else ``None``).
        lost_t_s: ``(first, last)`` time of the messages lost here, when known.
    """

    path: str
    offset: int
    file_size: int
    last_good_t_s: float | None
    good_chunks: int
    reason: str
    resumed_at: int | None = None
    lost_messages: int | None = None
    lost_t_s: tuple[float, float] | None = None

    def __str__(self) -> str:
        if self.offset < 0:  # not at one place: a count that does not add up, and the like
            text = f"{self.path}: {self.reason}"
            if self.lost_t_s is not None:
                text += f" (t = {self.lost_t_s[0]:.6f}–{self.lost_t_s[1]:.6f} s)"
            return text
        last = ("no messages before it" if self.last_good_t_s is None
                else f"messages up to t = {self.last_good_t_s:.6f} s were read")
        text = (f"{self.path}: broken at byte {self.offset} of {self.file_size} "
                f"({self.reason}); {last} from {self.good_chunks} complete chunk(s)")
        if self.lost_messages is not None:
            text += f"; {self.lost_messages} message(s) lost"
        if self.lost_t_s is not None:
            text += f" (t = {self.lost_t_s[0]:.6f}–{self.lost_t_s[1]:.6f} s)"
        if self.resumed_at is not None:
            text += (f"; skipped {self.resumed_at - self.offset} bytes, reading resumed at "
                     f"byte {self.resumed_at}")
        return text


@dataclass(frozen=True)
class ChannelInfo:
    """A channel with its schema (``schema_name`` is e.g. ``foxglove.RawImage``)."""

    id: int
    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes = field(repr=False)


@dataclass
class _ChunkRef:
    offset: int
    length: int
    start_ns: int
    end_ns: int
    expected: int | None = None  # message count from the message index records after it
    count: int | None = None  # messages found in it (once decompressed)


@dataclass
class _Summary:
    """What the summary section says (trusted only when its CRC and layout check out)."""

    start: int  # offset of the summary section: the data section ends there
    chunks: dict[int, ChunkIndex]  # chunk offset → index entry
    message_count: int | None
    schemas: list[Schema]
    channels: list[Channel]


# Opcodes a reader may meet at the top level; 0x80 and above are user records (skipped).
_TOP_LEVEL = {int(o) for o in Opcode}
_FOOTER_LEN = _RECORD_HEADER.size + 20


def _record_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower()
    except ValueError:
        return f"record 0x{opcode:02x}"


def _message_index_count(body: bytes) -> int:
    """Entries of a message index record (channel id u16, records length u32, 16 B each)."""
    (n,) = struct.unpack_from("<I", body, 2)
    return n // 16


class McapLogReader:
    """Scan an MCAP file; iterate it for time-ordered :class:`~logs.message.Message` events.

    Args:
        path: the MCAP file.
        topic_map: ``{our_topic: their_topic}`` for logs from elsewhere; messages on
            ``their_topic`` come out as ``our_topic`` and **only mapped topics are read**.
        topics: keep only these (output) topics.
        warn: emit a :class:`McapReadWarning` for every problem found.

    Damage costs only the damaged part: a corrupt chunk whose record is intact is skipped
    and reading goes on with the next one; a record whose header is destroyed is skipped by
    resuming at the next chunk of the summary's chunk index (when the summary checks out),
    or at the next chunk found intact (CRC-checked) after it. The message count the file
    states, its chunk index and the message index after each chunk are checked against
    what was read, so a chunk that was cut out or zeroed is reported, not silently missed.

    Raises:
        NotMcapError: the file is not MCAP at all.

    Attributes:
        problems: every :class:`ReadProblem` found (opening finds most; a chunk that fails
            its CRC is found when iteration reaches it).
        problem: the first of them, or ``None`` for an intact file.
        channels: channel id → :class:`ChannelInfo` (those seen before any break).
        metadata: metadata name → dict (values decoded as written by ``LogWriter``).
        clock_offset_ns: what ``LogWriter(start_utc=...)`` added to every log time (0 without
            a ``clock`` metadata record); message times are run seconds, this subtracted.
        start_utc: the run's start (ISO 8601 UTC text), ``None`` if the log does not say.
        attachments: attachment name → ``(media_type, data)`` (only those whose CRC holds).
        message_count: messages readable (all topics), as far as opening can tell.
        stated_message_count: the count the file's statistics record states (or ``None``).
    """

    def __init__(self, path: str | os.PathLike[str], *,
                 topic_map: Mapping[str, str] | None = None,
                 topics: Iterable[str] | None = None, warn: bool = True) -> None:
        self.path = os.fspath(path)
        self.problems: list[ReadProblem] = []
        self.channels: dict[int, ChannelInfo] = {}
        self.metadata: dict[str, dict[str, Any]] = {}
        self.attachments: dict[str, tuple[str, bytes]] = {}
        self.message_count = 0
        self.stated_message_count: int | None = None
        self._schemas: dict[int, Schema] = {}
        self._chunks: list[_ChunkRef] = []
        self._loose: list[McapMessage] = []  # messages outside chunks (unchunked files)
        self._rename = {theirs: ours for ours, theirs in (topic_map or {}).items()}
        self._mapped_only = topic_map is not None
        self._topics = None if topics is None else set(topics)
        self._decoders: dict[int, Callable[[bytes], Any] | None] = {}
        self._last_good_ns: int | None = None
        self._warn = warn
        self._lazy = False  # chunks checked when read (the summary vouched for the layout)
        self._walked_index: list[ChunkIndex] = []
        self._walked_count: int | None = None
        # after a corrupt chunk whose record length was taken on trust (a cut-out span
        # makes it point into the middle of a later chunk), records that carry no
        # checksum are not used until a chunk passes its CRC again: garbage parsed as a
        # top-level message record was once delivered as a message (benchmarks/fuzz.py)
        self._suspect_since: int | None = None
        self._suspect_skipped = 0
        self._reported: set[tuple[int, str]] = set()
        self._raw_metadata: dict[str, tuple[int, dict[str, str]]] = {}
        self._undecodable: dict[str, tuple[int, str]] = {}  # topic → (count, first reason)
        self._attachment_at: dict[str, int] = {}
        self._scan()
        self._check_digests()
        clock = self.metadata.get("clock", {})
        self.clock_offset_ns = int(clock.get("offset_ns", 0))
        self.start_utc: str | None = clock.get("start_utc")

    @property
    def problem(self) -> ReadProblem | None:
        """The first problem found, or ``None``."""
        return self.problems[0] if self.problems else None

    # ------------------------------------------------------------------ pass 1: scan
    def _report(self, offset: int, reason: str, *, resumed_at: int | None = None,
                lost_messages: int | None = None,
                lost_ns: tuple[int, int] | None = None, stacklevel: int = 3) -> None:
        key = (offset, reason)
        if key in self._reported:
            return
        self._reported.add(key)
        last = None if self._last_good_ns is None else self._last_good_ns / 1e9
        lost_t = None if lost_ns is None else (lost_ns[0] / 1e9, lost_ns[1] / 1e9)
        problem = ReadProblem(self.path, offset, os.path.getsize(self.path), last,
                              len(self._chunks), reason, resumed_at, lost_messages, lost_t)
        self.problems.append(problem)
        if self._warn:
            warnings.warn(str(problem), McapReadWarning, stacklevel=stacklevel + 1)

    def _seen(self, t_ns: int) -> None:
        if self._last_good_ns is None or t_ns > self._last_good_ns:
            self._last_good_ns = t_ns

    def _take(self, record: Any) -> None:
        if isinstance(record, Schema):
            self._schemas[record.id] = record
        elif isinstance(record, Channel):
            schema = self._schemas.get(record.schema_id)
            self.channels[record.id] = ChannelInfo(
                record.id, record.topic, record.message_encoding,
                schema.name if schema else "", schema.encoding if schema else "",
                schema.data if schema else b"")

    def _scan(self) -> None:
        size = os.path.getsize(self.path)
        with open(self.path, "rb") as f:
            head = f.read(len(MAGIC))
            if head != MAGIC:
                if len(head) < len(MAGIC) and MAGIC.startswith(head):
                    self._report(0, "file ends inside the MCAP magic: truncated")
                    return
                raise NotMcapError(f"{self.path}: not an MCAP file (it does not start with "
                                   "the MCAP magic bytes)")
            summary = self._read_summary(f, size)
            self._lazy = summary is not None
            if summary is not None:
                for schema in summary.schemas:
                    self._take(schema)
                for channel in summary.channels:
                    self._take(channel)
                self.stated_message_count = summary.message_count
            self._walk(f, size, summary)
        self._end_suspect()
        self._cross_check(summary)

    def _read_summary(self, f: Any, size: int) -> _Summary | None:
        """The summary section through the footer, or ``None`` when there is none or
        anything in it does not check out (CRC, record layout, chunk offsets)."""
        if size < 2 * len(MAGIC) + _FOOTER_LEN:
            return None
        try:
            f.seek(size - len(MAGIC) - _FOOTER_LEN)
            tail = f.read(_FOOTER_LEN + len(MAGIC))
            if tail[-len(MAGIC):] != MAGIC:
                return None
            opcode, length = _RECORD_HEADER.unpack_from(tail)
            if opcode != Opcode.FOOTER or length != 20:
                return None
            start, _offset_start, crc = struct.unpack_from("<QQI", tail, _RECORD_HEADER.size)
            footer_at = size - len(MAGIC) - _FOOTER_LEN
            if start == 0 or not len(MAGIC) < start <= footer_at:
                return None
            f.seek(start)
            data = f.read(footer_at - start)
            if crc:
                calc = zlib.crc32(tail[:_FOOTER_LEN - 4], zlib.crc32(data))
                if calc != crc:
                    return None
            chunks: dict[int, ChunkIndex] = {}
            schemas, channels, count = [], [], None
            pos = 0
            while pos < len(data):
                op, n = _RECORD_HEADER.unpack_from(data, pos)
                body = data[pos + _RECORD_HEADER.size:pos + _RECORD_HEADER.size + n]
                if len(body) != n:
                    return None
                stream = ReadDataStream(io.BytesIO(body))
                if op == Opcode.CHUNK_INDEX:
                    ci = ChunkIndex.read(stream)
                    chunks[ci.chunk_start_offset] = ci
                elif op == Opcode.SCHEMA:
                    schemas.append(Schema.read(stream))
                elif op == Opcode.CHANNEL:
                    channels.append(Channel.read(stream))
                elif op == Opcode.STATISTICS:
                    count = Statistics.read(stream).message_count
                pos += _RECORD_HEADER.size + n
            for off, ci in chunks.items():  # every indexed chunk lies in the data section
                if not len(MAGIC) <= off < start or off + ci.chunk_length > start:
                    return None
            return _Summary(start, chunks, count, schemas, channels)
        except Exception:
            return None

    def _resume_point(self, f: Any, pos: int, end: int, summary: _Summary | None
                      ) -> int | None:
        """Where to go on after damage at ``pos``: the next indexed chunk, or without an
        index the next offset that holds a complete chunk record passing its CRC."""
        if summary is not None:
            later = [off for off in summary.chunks if off > pos]
            return min(later) if later else None
        import mmap

        try:
            view = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except (ValueError, OSError):
            return None
        try:
            i = pos + 1
            while True:
                i = view.find(bytes([Opcode.CHUNK]), i, end)
                if i < 0 or i + _RECORD_HEADER.size + _CHUNK_HEAD.size > end:
                    return None
                (length,) = _LENGTH.unpack_from(view, i + 1)
                if length <= end - i - _RECORD_HEADER.size:
                    body = view[i + _RECORD_HEADER.size:i + _RECORD_HEADER.size + length]
                    try:
                        chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
                        if chunk.uncompressed_crc:
                            breakup_chunk(chunk, validate_crc=True)
                            return i
                    except Exception:
                        pass
                i += 1
        finally:
            view.close()

    def _lost(self, f: Any, pos: int, end: int, summary: _Summary | None, reason: str
              ) -> int | None:
        """Report damage at ``pos`` with what the index says was lost; where to resume."""
        nxt = self._resume_point(f, pos, end, summary)
        lost_n, lost_ns = None, None
        if summary is not None:
            stop = end if nxt is None else nxt
            gone = [ci for off, ci in summary.chunks.items() if pos <= off < stop]
            if gone:
                lost_ns = (min(ci.message_start_time for ci in gone),
                           max(ci.message_end_time for ci in gone))
                reason += f"; {len(gone)} indexed chunk(s) lost"
        self._report(pos, reason, resumed_at=nxt, lost_messages=lost_n, lost_ns=lost_ns,
                     stacklevel=4)
        return nxt

    def _walk(self, f: Any, size: int, summary: _Summary | None) -> None:
        """Walk the top-level records from the start; with a trusted summary only the data
        section, reading chunk headers and seeking over their data (chunk contents are
        checked when read); without, every chunk is decompressed and checked here.

        Why lazy: decompressing every chunk twice (here and in :meth:`messages`) cost a
        replay of 512×480 video ~1 ms per frame."""
        end = summary.start if summary is not None else size
        pos = len(MAGIC)
        last_chunk: _ChunkRef | None = None
        while True:
            if pos >= end:
                if summary is None:
                    self._report(pos, "file ends without a footer: truncated")
                return
            f.seek(pos)
            head = f.read(_RECORD_HEADER.size)
            if len(head) < _RECORD_HEADER.size:
                self._report(pos, "record header cut: truncated")
                return
            opcode, length = _RECORD_HEADER.unpack(head)
            name = _record_name(opcode)
            if length > end - pos - _RECORD_HEADER.size:
                what = ("cut short: truncated" if summary is None and opcode in _TOP_LEVEL
                        else "overruns the data section: corrupt")
                nxt = self._lost(f, pos, end, summary, f"{name} of {length} bytes {what}")
                if nxt is None:
                    return
                pos, last_chunk = nxt, None
                continue
            if opcode not in _TOP_LEVEL and opcode < 0x80:
                nxt = self._lost(f, pos, end, summary,
                                 f"corrupt record: opcode 0x{opcode:02x} is not MCAP's")
                if nxt is None:
                    return
                pos, last_chunk = nxt, None
                continue
            following = pos + _RECORD_HEADER.size + length
            try:
                if opcode == Opcode.CHUNK and self._lazy:
                    start_ns, end_ns = _CHUNK_TIMES.unpack(f.read(_CHUNK_TIMES.size))
                    # the header's times lie outside the chunk's CRC: a damaged time once
                    # sorted a whole chunk last (out of time order, unreported); the
                    # summary's chunk index (CRC-checked with the summary) is the check
                    ci = summary.chunks.get(pos) if summary is not None else None
                    if ci is not None and (start_ns, end_ns) != (ci.message_start_time,
                                                                 ci.message_end_time):
                        self._report(pos, f"chunk header's message times ({start_ns}, "
                                     f"{end_ns} ns) disagree with the chunk index "
                                     f"({ci.message_start_time}, {ci.message_end_time} ns):"
                                     " header damaged, the index's used")
                        start_ns, end_ns = ci.message_start_time, ci.message_end_time
                    if start_ns > end_ns:
                        raise ValueError(f"message times {start_ns} > {end_ns}")
                    last_chunk = _ChunkRef(pos, length, start_ns, end_ns)
                    self._chunks.append(last_chunk)
                    self._seen(end_ns)
                    pos = following
                    continue
                body = f.read(length)
                if opcode == Opcode.MESSAGE_INDEX:
                    if last_chunk is not None:
                        last_chunk.expected = ((last_chunk.expected or 0)
                                               + _message_index_count(body))
                    pos = following
                    continue
                last_chunk = None
                done = self._parse(opcode, body, pos)
                if opcode == Opcode.CHUNK and self._chunks and self._chunks[-1].offset == pos:
                    last_chunk = self._chunks[-1]
            except Exception as exc:  # any parse failure marks the damage
                reason = f"corrupt {name}: {type(exc).__name__}: {exc}"
                if opcode == Opcode.CHUNK:  # its record is intact: the next one follows
                    self._report(pos, reason, resumed_at=following)
                    if self._suspect_since is None:
                        self._suspect_since = pos
                    pos, last_chunk = following, None
                    continue
                nxt = self._lost(f, pos, end, summary, reason)
                if nxt is None:
                    return
                pos, last_chunk = nxt, None
                continue
            if done:
                f.seek(following)
                if f.read(len(MAGIC) + 1) != MAGIC:
                    self._report(following, "no closing magic after the footer")
                return
            pos = following

    def _cross_check(self, summary: _Summary | None) -> None:
        """What the file says it holds against what was found."""
        if summary is not None:
            found = {c.offset for c in self._chunks}
            for off, ci in sorted(summary.chunks.items()):
                if off in found or any(p.offset <= off < (p.resumed_at or 1 << 62)
                                       for p in self.problems):
                    continue  # read, or lost in damage already reported
                self._report(off, "chunk listed in the index is not in the data section",
                             lost_ns=(ci.message_start_time, ci.message_end_time))
            expected = [c.expected for c in self._chunks]
            if self._loose or None in expected:  # no per-chunk counts: trust the statistics
                self.message_count = summary.message_count or 0
                return
            self.message_count = sum(e for e in expected if e is not None)
        # a full scan: the summary, when walked, is only a cross-check
        if self._walked_count is not None:
            self.stated_message_count = self._walked_count
        if self._walked_index:
            have: dict[tuple[int, int], int] = {}
            for c in self._chunks:
                have[(c.start_ns, c.end_ns)] = have.get((c.start_ns, c.end_ns), 0) + 1
            for ci in self._walked_index:
                key = (ci.message_start_time, ci.message_end_time)
                if have.get(key, 0) > 0:
                    have[key] -= 1
                    continue
                self._report(ci.chunk_start_offset, "chunk listed in the index is missing "
                             "from the data section (cut out or destroyed)",
                             lost_ns=key)
        for c in self._chunks:
            if None not in (c.expected, c.count) and c.expected != c.count:
                self._report(c.offset, f"chunk holds {c.count} messages, its message index "
                             f"lists {c.expected}")
        stated = self.stated_message_count
        if stated is not None and stated != self.message_count:
            self._report(-1, f"the file states {stated} messages, {self.message_count} "
                         "could be read", lost_messages=stated - self.message_count)

    def _end_suspect(self) -> None:
        if self._suspect_since is not None and self._suspect_skipped:
            self._report(self._suspect_since, f"{self._suspect_skipped} record(s) without a "
                         "checksum after this corrupt chunk, before the next intact one: not "
                         "used (they may be the damaged chunk's bytes)",
                         lost_messages=None, stacklevel=4)
        self._suspect_since, self._suspect_skipped = None, 0

    def _parse(self, opcode: int, body: bytes, offset: int) -> bool:
        """Take one top-level record; ``True`` at the footer. The summary section is walked too
        (its records repeat what the data section held), so a cut there is reported exactly."""
        stream = ReadDataStream(io.BytesIO(body))
        if self._suspect_since is not None and opcode in (
                Opcode.MESSAGE, Opcode.SCHEMA, Opcode.CHANNEL):
            self._suspect_skipped += 1
            return False
        if opcode == Opcode.CHUNK:
            chunk = Chunk.read(stream)
            records = breakup_chunk(chunk, validate_crc=True)
            if chunk.uncompressed_crc:  # checked: what follows is in step again
                self._end_suspect()
            times = []
            for record in records:
                if isinstance(record, McapMessage):
                    times.append(record.log_time)
                else:
                    self._take(record)
            if times:
                self._chunks.append(_ChunkRef(offset, len(body), min(times), max(times),
                                              count=len(times)))
                self.message_count += len(times)
                self._seen(max(times))
        elif opcode == Opcode.MESSAGE:
            msg = McapMessage.read(stream, len(body))
            self._loose.append(msg)
            self.message_count += 1
            self._seen(msg.log_time)
        elif opcode == Opcode.SCHEMA:
            self._take(Schema.read(stream))
        elif opcode == Opcode.CHANNEL:
            self._take(Channel.read(stream))
        elif opcode == Opcode.METADATA:
            meta = Metadata.read(stream)
            self._raw_metadata[meta.name] = (offset, dict(meta.metadata))
            self.metadata[meta.name] = decode_metadata(meta.metadata)
        elif opcode == Opcode.ATTACHMENT:
            att = Attachment.read(stream)
            (crc,) = struct.unpack_from("<I", body, len(body) - 4)
            if crc and zlib.crc32(body[:-4]) != crc:
                self._report(-1, f"attachment {att.name!r} (byte {offset}) fails its CRC: "
                             "not used", stacklevel=5)
            else:
                self.attachments[att.name] = (att.media_type, att.data)
                self._attachment_at[att.name] = offset
        elif opcode == Opcode.CHUNK_INDEX and not self._lazy:
            self._walked_index.append(ChunkIndex.read(stream))
        elif opcode == Opcode.STATISTICS and not self._lazy:
            self._walked_count = Statistics.read(stream).message_count
        elif opcode == Opcode.FOOTER:
            return True
        return False

    def _check_digests(self) -> None:
        """Metadata and attachments against the ``digests`` record the writer left (when it
        closed): one that was changed since is reported and dropped, never used."""
        from adfusion.logs.writer import DIGESTS, digest_metadata

        entry = self._raw_metadata.get(DIGESTS)
        if entry is None:
            return
        digests = entry[1]
        for name, (offset, raw) in self._raw_metadata.items():
            want = digests.get(f"metadata:{name}")
            if name == DIGESTS or want is None:
                continue
            if digest_metadata(raw) != want:
                self.metadata.pop(name, None)
                self._report(-1, f"metadata {name!r} (byte {offset}) does not match its "
                             "recorded digest (changed after recording): not used")
        for name, (_, data) in list(self.attachments.items()):
            want = digests.get(f"attachment:{name}")
            if want is not None and hashlib.sha256(data).hexdigest() != want:
                self.attachments.pop(name)
                self._report(-1, f"attachment {name!r} (byte {self._attachment_at.get(name)})"
                             " does not match its recorded digest (changed after recording): "
                             "not used")
        self.metadata.pop(DIGESTS, None)

    # ------------------------------------------------------------------ decoding
    def _output_topic(self, channel: ChannelInfo) -> str | None:
        topic = self._rename.get(channel.topic)
        if topic is None:
            if self._mapped_only:
                return None
            topic = channel.topic
        if self._topics is not None and topic not in self._topics:
            return None
        return topic

    def _decoder(self, channel: ChannelInfo) -> Callable[[bytes], Any] | None:
        if channel.id in self._decoders:
            return self._decoders[channel.id]
        decoder: Callable[[bytes], Any] | None
        if channel.message_encoding == "json":
            decoder = json.loads
        elif channel.message_encoding == "protobuf" and channel.schema_name in fg.MESSAGE_TYPES:
            name = channel.schema_name
            decoder = lambda data: fg.decode(name, data)  # noqa: E731
        elif channel.message_encoding == "protobuf":
            from google.protobuf.json_format import MessageToDict
            from mcap_protobuf.decoder import DecoderFactory

            schema = Schema(id=0, data=channel.schema_data, encoding=channel.schema_encoding,
                            name=channel.schema_name)
            try:
                proto = DecoderFactory().decoder_for("protobuf", schema)
            except Exception as exc:  # a schema we cannot build: its messages are undecodable
                reason = f"schema {channel.schema_name!r} unusable: {type(exc).__name__}: {exc}"

                def decoder(data: bytes, reason: str = reason) -> Any:
                    raise ValueError(reason)
            else:
                decoder = None if proto is None else (lambda data: MessageToDict(proto(data)))
        else:
            warnings.warn(f"{self.path}: {channel.topic} uses {channel.message_encoding!r}, "
                          "which is not decoded; payloads are raw bytes", McapReadWarning,
                          stacklevel=3)
            decoder = bytes
        self._decoders[channel.id] = decoder
        return decoder

    def _message(self, record: McapMessage) -> Message | None:
        channel = self.channels.get(record.channel_id)
        if channel is None:
            return None
        topic = self._output_topic(channel)
        if topic is None:
            return None
        decoder = self._decoder(channel)
        try:
            payload = record.data if decoder is None else decoder(record.data)
        except Exception as exc:
            n, first = self._undecodable.get(channel.topic, (0, ""))
            self._undecodable[channel.topic] = (n + 1, first or (
                f"t = {record.log_time / 1e9:.6f} s: {type(exc).__name__}: {exc}"))
            if n == 0:
                warnings.warn(f"{self.path}: cannot decode {channel.topic} at t = "
                              f"{record.log_time / 1e9:.6f} s ({exc}); skipped",
                              McapReadWarning, stacklevel=3)
            return None
        # JSON and raw frames keep their bytes, so that a replay copies them as read
        keep = decoder is json.loads or channel.schema_name in _KEEP_RAW
        return Message((record.log_time - self.clock_offset_ns) / 1e9, topic, payload,
                       record.data if keep else None)

    # ------------------------------------------------------------------ pass 2: merge
    def _chunk_messages(self, data: bytes | memoryview) -> list[McapMessage]:
        """The messages of a chunk's decompressed records (see :func:`_chunk_records`); its
        schemas and channels, which a summary need not repeat, are taken on the way.

        One ``struct`` call per message instead of mcap's stream reads (five per message):
        a replay of 512×480 video parsed ~19 messages per frame here."""
        view = memoryview(data)
        out = []
        pos, end = 0, len(view)
        while pos < end:
            opcode, length = _RECORD_HEADER.unpack_from(view, pos)
            pos += _RECORD_HEADER.size
            stop = pos + length
            if stop > end:
                raise ValueError(f"a record of {length} bytes overruns its chunk")
            if opcode == Opcode.MESSAGE:
                if length < _MESSAGE_HEAD.size:
                    raise ValueError(f"a message record of {length} bytes")
                channel_id, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(
                    view, pos)
                out.append(McapMessage(channel_id=channel_id, log_time=log_time,
                                       data=bytes(view[pos + _MESSAGE_HEAD.size:stop]),
                                       publish_time=publish_time, sequence=sequence))
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                stream = ReadDataStream(io.BytesIO(view[pos:stop]))
                self._take((Schema if opcode == Opcode.SCHEMA else Channel).read(stream))
            pos = stop
        return out

    def _broken_chunk(self, ref: _ChunkRef, exc: Exception) -> None:
        """A chunk of a file indexed by its headers turned out corrupt while reading: it
        alone is dropped (reported with what its message index said it held)."""
        self._chunks = [c for c in self._chunks if c is not ref]
        if ref.expected is not None:
            self.message_count -= ref.expected
        self._report(ref.offset, f"corrupt chunk: {type(exc).__name__}: {exc}",
                     resumed_at=ref.offset + _RECORD_HEADER.size + ref.length,
                     lost_messages=ref.expected, lost_ns=(ref.start_ns, ref.end_ns),
                     stacklevel=4)

    def raw_records(self) -> Iterator[tuple[ChannelInfo, McapMessage]]:
        """Undecoded ``(channel, mcap message)`` pairs in log-time order (all topics).

        Chunks are read, decompressed and CRC-checked :data:`_PREFETCH` ahead by a thread:
        those steps release the GIL, so they overlap the caller's work (a replay spent
        ~0.4 ms per 512×480 frame in them, on the thread that runs the filter). A chunk that
        fails there is reported and skipped; at the end, the messages delivered are checked
        against the count the file states."""
        pending = sorted(self._chunks, key=lambda c: (c.start_ns, c.offset))
        heap: list[tuple[int, int, int, McapMessage]] = [
            (m.log_time, -1, i, m) for i, m in enumerate(self._loose)]
        heapq.heapify(heap)
        nxt = 0
        delivered = 0
        orphans: dict[int, int] = {}  # channel id → messages whose channel is unknown
        last_ns, late = -1, 0
        with open(self.path, "rb") as f, ThreadPoolExecutor(1, "mcap-read") as pool:
            loader = _ChunkLoader(f.fileno())
            loads = deque(pool.submit(loader.records, ref) for ref in pending[:_PREFETCH])
            while heap or nxt < len(pending):
                while nxt < len(pending) and (not heap or pending[nxt].start_ns <= heap[0][0]):
                    ref = pending[nxt]
                    if nxt + _PREFETCH < len(pending):
                        loads.append(pool.submit(loader.records, pending[nxt + _PREFETCH]))
                    nxt += 1
                    try:
                        msgs = self._chunk_messages(loads.popleft().result())
                    except Exception as exc:
                        self._broken_chunk(ref, exc)
                        continue
                    outside = [m for m in msgs
                               if not ref.start_ns <= m.log_time <= ref.end_ns]
                    if outside:  # its place in the merge is wrong: the order breaks
                        self._report(ref.offset, f"{len(outside)} message(s) of the chunk lie"
                                     f" outside its stated times ({ref.start_ns}, "
                                     f"{ref.end_ns} ns): chunk header or index damaged",
                                     stacklevel=3)
                    if ref.expected is not None and len(msgs) != ref.expected:
                        self._report(ref.offset, f"chunk holds {len(msgs)} messages, its "
                                     f"message index lists {ref.expected}", stacklevel=3)
                        self.message_count += len(msgs) - ref.expected
                    for i, m in enumerate(msgs):
                        heapq.heappush(heap, (m.log_time, ref.offset, i, m))
                if not heap:
                    break
                t_ns, _, _, record = heapq.heappop(heap)
                if t_ns < last_ns:  # from a chunk merged too late (reported above)
                    late += 1
                    continue
                last_ns = t_ns
                delivered += 1
                channel = self.channels.get(record.channel_id)
                if channel is not None:
                    yield channel, record
                else:
                    orphans[record.channel_id] = orphans.get(record.channel_id, 0) + 1
        if late:
            self._report(-1, f"{late} message(s) came after later ones (a chunk's stated "
                         "times were damaged): skipped to keep time order",
                         lost_messages=late, stacklevel=3)
        if orphans:
            n = sum(orphans.values())
            self._report(-1, f"{n} message(s) on channel(s) {listed(sorted(orphans), 8)} "
                         "whose channel record was lost with the damage: skipped",
                         lost_messages=n, stacklevel=3)
        stated = self.stated_message_count
        if stated is not None and delivered != stated and delivered != self.message_count:
            self._report(-1, f"the file states {stated} messages, {delivered} could be read",
                         lost_messages=stated - delivered, stacklevel=3)

    def messages(self) -> Iterator[Message]:
        """Decoded messages in log-time order, up to the break if the file is damaged."""
        self._undecodable: dict[str, tuple[int, str]] = {}
        for _, record in self.raw_records():
            msg = self._message(record)
            if msg is not None:
                yield msg
        for topic, (n, first) in self._undecodable.items():
            self._report(-1, f"{n} message(s) on {topic} could not be decoded (first at {first})"
                         ": skipped", lost_messages=n, stacklevel=2)

    __iter__ = messages

    def camera_model(self, name: str = "camera.json") -> dict[str, Any] | None:
        """The camera-model attachment written by ``LogWriter.add_camera_model``, if any."""
        if name not in self.attachments:
            return None
        return json.loads(self.attachments[name][1])


# protobuf messages whose bytes a replay copies to its output as read
_KEEP_RAW = frozenset({"foxglove.RawImage", "foxglove.PoseInFrame"})

# Chunks read ahead of the one being merged (each ~1 MB of records).
_PREFETCH = 2
_CHUNK_HEAD = struct.Struct("<QQQII")  # times, uncompressed size and CRC, compression length
_LENGTH = struct.Struct("<Q")
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


class _ChunkLoader:
    """Chunk records from the file, decompressed and CRC-checked, for one reading thread
    (it keeps a zstd context; ``os.pread`` leaves the file position alone)."""

    def __init__(self, fd: int) -> None:
        self._fd = fd
        self._zstd: Any = None

    def records(self, ref: _ChunkRef) -> bytes | memoryview:
        body = os.pread(self._fd, ref.length, ref.offset + _RECORD_HEADER.size)
        if len(body) != ref.length:
            raise EOFError(f"chunk cut short: {len(body)} of {ref.length} bytes")
        _, _, size, crc, n = _CHUNK_HEAD.unpack_from(body)
        pos = _CHUNK_HEAD.size + n
        compression = body[_CHUNK_HEAD.size:pos].decode()
        (length,) = _LENGTH.unpack_from(body, pos)
        pos += _LENGTH.size
        if pos + length > len(body):
            raise EOFError(f"chunk data of {length} bytes overruns its record")
        data: bytes | memoryview = memoryview(body)[pos:pos + length]
        if compression == "zstd":
            if self._zstd is None:
                import zstandard

                self._zstd = zstandard.ZstdDecompressor()
            data = self._zstd.decompress(data, max_output_size=size)
        elif compression == "lz4":
            import lz4.frame

            data = lz4.frame.decompress(data)
        elif compression:
            raise ValueError(f"unsupported chunk compression {compression!r}")
        if crc and zlib.crc32(data) != crc:  # 0: the writer computed none
            raise ValueError(f"chunk CRC mismatch: expected {crc}, calculated "
                             f"{zlib.crc32(data)}")
        return data


def read_mcap(path: str | os.PathLike[str], *, topic_map: Mapping[str, str] | None = None,
              topics: Iterable[str] | None = None) -> Iterator[Message]:
    """Time-ordered messages of an MCAP file (see :class:`McapLogReader`); warns on damage.

    Example:
        >>> import os, tempfile
        >>> from adfusion.logs import LogWriter, read_mcap
        >>> path = os.path.join(tempfile.mkdtemp(), "theirs.mcap")
        >>> with LogWriter(path) as log:
        ...     log.write_json("/imu/data", 1.0, {"omega": [0.0, 0.0, 0.2]})
        >>> [m.topic for m in read_mcap(path, topic_map={"/imu/gyro": "/imu/data"})]
        ['/imu/gyro']
    """
    return McapLogReader(path, topic_map=topic_map, topics=topics).messages()
