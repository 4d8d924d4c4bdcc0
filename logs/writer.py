"""MCAP writer for adfusion runs: Foxglove schemas where a person looks, JSON for internals.

Encoding decision: the Foxglove types (images, annotations, poses, transforms, calibration) are
written as **protobuf** with the schemas from ``foxglove-schemas-protobuf`` (a
``FileDescriptorSet`` per schema, as ``mcap-protobuf-support`` builds it). Images then travel as
raw bytes — the JSON encoding of ``foxglove.RawImage`` would base64 every frame (+33 % size and
a slow encode in Python) — and Foxglove decodes protobuf natively. Internals (solver and filter
state, sensor samples) are **JSON** with a draft 2020-12 JSON schema per topic
(:mod:`logs.schemas`): readable anywhere, plottable in Foxglove, easy to extend.

Durability: chunks are compressed (zstd by default) and each finished chunk goes straight to
the operating system (the file is opened unbuffered), so a writer killed mid-run — even by
SIGKILL — leaves a file that :class:`logs.reader.McapLogReader` reads up to its last complete
chunk. Times are seconds (float) in the API and integer nanoseconds in the file.

Example:
    >>> import os, tempfile
    >>> import numpy as np
    >>> from adfusion.logs import LogWriter
    >>> path = os.path.join(tempfile.mkdtemp(), "run.mcap")
    >>> with LogWriter(path) as log:
    ...     log.add_metadata("config", {"scenario": "oedipus", "seed": 1})
    ...     log.write_image(0.0, np.zeros((480, 512), np.uint8))
    ...     log.write_json("/imu/gyro", 0.0, {"omega": [0.0, 0.0, 0.1]})
    ...     log.write_pose("/estimate/pose", 0.0, [1.0, 0.0, 0.0, 0.0])
    >>> log.message_count
    3
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import struct
import zlib
from collections.abc import Iterable, Mapping
from types import TracebackType
from typing import Any, Literal, Protocol

import numpy as np
from adfusion.logs import foxglove as fg
from adfusion.logs import topics
from adfusion.logs.jsonio import dumps, dumps_bytes, encode_metadata
from adfusion.logs.schemas import GENERIC, JSON_SCHEMAS
from google.protobuf.message import Message as ProtoMessage
from mcap.records import ChunkIndex, MessageIndex
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, IndexType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from adfusion.outfiles import OutputLock, note_written, replace_into, temp_name

ArrayLike = Any

IMAGE_TOPIC = topics.CAMERA_IMAGE
ANNOTATIONS_TOPIC = topics.CAMERA_ANNOTATIONS
CALIBRATION_TOPIC = topics.CAMERA_CALIBRATION
TF_TOPIC = topics.TF

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE, None: CompressionType.NONE}


# A Message record's header (opcode 0x05, record length, channel id, sequence, log time,
# publish time) in one pack: what mcap's Message.write writes in six.
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
# A Chunk record's header up to its compression name (opcode 0x06, record length, message
# start and end times, uncompressed size and CRC, the name's length), and a u64 length.
_CHUNK_HEAD = struct.Struct("<BQQQQII")
_LENGTH = struct.Struct("<Q")


class _MessageAppender:
    """``mcap.Writer.add_message`` for a chunked writer, writing the same bytes and index
    entries with one ``struct`` pack and no record object per message (the library's path,
    a dataclass, six packs and a seek to patch the length, cost ~5 µs more a message; a
    replay writes ~25 a frame). ``add_parts`` appends a message given in pieces (a frame
    is header, pixels, trailer) straight from the caller's buffers, without first joining
    them into one ``bytes``; :meth:`finalize_chunk` ends a chunk without copying its data
    into a record buffer on the way to the file.

    It uses the writer's private chunk builder, statistics and chunk ending; :meth:`of`
    returns ``None`` (use ``Writer.add_message``) when they are not as this was written
    against (mcap 1.6), and tests/test_logs.py compares its files byte for byte with the
    library's own.
    """

    def __init__(self, writer: Writer) -> None:
        self._stats = writer._Writer__statistics
        self._chunk = writer._Writer__chunk_builder
        self._maybe_finalize = writer._Writer__maybe_finalize_chunk
        self._index = MessageIndex
        self._writer = writer

    @classmethod
    def of(cls, writer: Writer) -> _MessageAppender | None:
        try:
            appender = cls(writer)
            chunk = appender._chunk
            ok = (chunk is not None and hasattr(chunk.record_writer, "_buffer")
                  and isinstance(chunk.message_indices, dict)
                  and hasattr(chunk, "num_messages") and hasattr(chunk, "message_start_time")
                  and hasattr(appender._stats, "channel_message_counts")
                  and writer._Writer__enable_data_crcs is False
                  and isinstance(writer._Writer__chunk_indices, list)
                  and callable(writer._Writer__flush)
                  and callable(getattr(Writer, "_Writer__finalize_chunk", None)))
        except AttributeError:
            return None
        if not ok:
            return None
        # name-mangled calls inside Writer (self.__finalize_chunk()) find the instance's
        # attribute first: the writer's chunks end through finalize_chunk from now on
        writer._Writer__finalize_chunk = appender.finalize_chunk
        return appender

    def finalize_chunk(self) -> None:
        """``Writer.__finalize_chunk`` without copying the chunk's data into a record buffer
        first: the Chunk record's header, then the (compressed) data, go to the file as
        they are — a replay writes ~250 kB a frame, and the library copied it twice more."""
        w, chunk = self._writer, self._chunk
        if chunk.num_messages == 0:
            return
        self._stats.chunk_count += 1
        data = chunk.end()
        method = w._Writer__compression
        if method == CompressionType.LZ4:
            import lz4.frame

            compression, stored = "lz4", lz4.frame.compress(data)  # as the library calls them
        elif method == CompressionType.ZSTD:
            import zstandard

            compression, stored = "zstd", zstandard.compress(data)
        else:
            compression, stored = "", data
        crc = zlib.crc32(data) if w._Writer__enable_crcs else 0
        name = compression.encode()
        body = 8 + 8 + 8 + 4 + 4 + len(name) + 8 + len(stored)
        head = (_CHUNK_HEAD.pack(0x06, body, chunk.message_start_time, chunk.message_end_time,
                                 len(data), crc, len(name)) + name
                + _LENGTH.pack(len(stored)))
        flush, stream, records = w._Writer__flush, w._Writer__stream, w._Writer__record_builder
        flush()
        start = stream.tell()
        stream.write(head)
        stream.write(stored)
        index = ChunkIndex(message_start_time=chunk.message_start_time,
                           message_end_time=chunk.message_end_time, chunk_start_offset=start,
                           chunk_length=len(head) + len(stored), message_index_offsets={},
                           message_index_length=0, compression=compression,
                           compressed_size=len(stored), uncompressed_size=len(data))
        message_index_start = stream.tell()
        if w._Writer__index_types & IndexType.MESSAGE:
            for channel_id, message_index in chunk.message_indices.items():
                index.message_index_offsets[channel_id] = message_index_start + records.count
                message_index.write(records)
        index.message_index_length = records.count
        flush()
        w._Writer__chunk_indices.append(index)
        chunk.reset()

    def add_parts(self, channel_id: int, log_time: int, sequence: int,
                  parts: tuple, size: int) -> None:
        stats, chunk = self._stats, self._chunk
        if stats.message_count == 0 or log_time < stats.message_start_time:
            stats.message_start_time = log_time
        if log_time > stats.message_end_time:
            stats.message_end_time = log_time
        stats.channel_message_counts[channel_id] += 1
        stats.message_count += 1
        if chunk.num_messages == 0 or log_time < chunk.message_start_time:
            chunk.message_start_time = log_time
        if log_time > chunk.message_end_time:
            chunk.message_end_time = log_time
        buf = chunk.record_writer._buffer
        index = chunk.message_indices.get(channel_id)
        if not index:
            index = chunk.message_indices[channel_id] = self._index(channel_id=channel_id,
                                                                    records=[])
        index.records.append((log_time, buf.tell()))
        chunk.num_messages += 1
        buf.write(_MESSAGE_HEAD.pack(5, 22 + size, channel_id, sequence, log_time, log_time))
        for part in parts:
            buf.write(part)
        self._maybe_finalize()


def utc_ns(when: Any) -> int:
    """Nanoseconds since 1970-01-01 UTC of an ISO 8601 text or a timezone-aware datetime.

    Example:
        >>> utc_ns("1970-01-01T00:00:01.5Z")
        1500000000
    """
    import datetime as dt

    if isinstance(when, str):
        try:
            when = dt.datetime.fromisoformat(when.replace("Z", "+00:00"))
        except ValueError:
            raise ValueError(f"start time {when!r}: give a UTC time such as "
                             "1995-11-07T08:07:00Z") from None
    if not isinstance(when, dt.datetime) or when.tzinfo is None:
        raise ValueError(f"start time {when!r}: give a UTC time such as 1995-11-07T08:07:00Z")
    delta = when - dt.datetime(1970, 1, 1, tzinfo=dt.UTC)
    return (delta.days * 86400 + delta.seconds) * 10**9 + delta.microseconds * 1000


def utc_iso(when: Any) -> str:
    """ISO 8601 UTC text (``…Z``, nanoseconds dropped to microseconds) of ``when``.

    Example:
        >>> utc_iso("1995-11-07T08:07:00+00:00")
        '1995-11-07T08:07:00.000000Z'
    """
    import datetime as dt

    ns = utc_ns(when)
    t = dt.datetime(1970, 1, 1, tzinfo=dt.UTC) + dt.timedelta(microseconds=ns // 1000)
    return t.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
#: Name of the metadata record with the SHA-256 of every other metadata record and attachment.
DIGESTS = "digests"


def digest_metadata(encoded: Mapping[str, str]) -> str:
    """SHA-256 of a metadata record's string map (keys sorted; the reader recomputes it).

    >>> digest_metadata({"b": "1", "a": "x"}) == digest_metadata({"a": "x", "b": "1"})
    True
    """
    text = json.dumps(dict(encoded), sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return hashlib.sha256(text.encode()).hexdigest()


class _UnbufferedFile:
    """Write-through file for ``mcap.Writer``: every ``write`` reaches the OS at once.

    ``mcap.Writer`` hands over whole records (a chunk at a time), so this costs one system
    call per chunk and nothing is left in a Python buffer when the process dies.
    """

    def __init__(self, path: str | os.PathLike[str], name: str | None = None) -> None:
        self._raw = open(path, "wb", buffering=0)
        self._name = name or os.fspath(path)  # the file as the user knows it (for errors)

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data)
        try:
            while view:
                n = self._raw.write(view)
                view = view[n:]
        except OSError as exc:  # a full disk says which file it was writing
            raise OSError(exc.errno, exc.strerror, self._name) from exc
        return len(data)

    def tell(self) -> int:
        return self._raw.tell()

    def flush(self) -> None:
        pass

    def fsync(self) -> None:
        os.fsync(self._raw.fileno())

    def close(self) -> None:
        self._raw.close()


class Tee(Protocol):
    """What :class:`LogWriter` hands every channel and message to besides the file (a live
    view): :meth:`channel` once per topic, returning a handle that :meth:`message` gets back
    with each message's log time (ns) and bytes."""

    def channel(self, topic: str, message_encoding: str, schema_name: str,
                schema_encoding: str, schema_data: bytes) -> Any: ...

    def message(self, handle: Any, log_time_ns: int, data: bytes) -> None: ...


class LogWriter:
    """Write one adfusion run to an MCAP file (use as a context manager, or call :meth:`close`).

    Args:
        path: output file (overwritten).
        chunk_size: uncompressed bytes per chunk; a crash loses at most the chunk in progress.
        compression: ``"zstd"`` (default), ``"lz4"`` or ``"none"``.
        fsync: also ``fsync`` after every chunk (survives power loss, not just a killed process).
        start_utc: UTC time of run time 0 (ISO 8601 text or a timezone-aware ``datetime``).
            Given, the file's log times are UTC (nanoseconds since 1970) while the API keeps
            run seconds: every time is stored ``+ clock_offset_ns``, recorded in the
            ``clock`` metadata (``start_utc``, ``offset_ns``), which
            :class:`~adfusion.logs.reader.McapLogReader` subtracts again.
        atomic: hold an exclusive lock on ``path`` (a second writer of it gets
            :class:`~adfusion.outfiles.OutputBusy` at once), write to a temporary name of
            this writer's own beside it (:attr:`partial_path`, ``.adf-<random>.tmp.mcap``)
            and rename that to ``path`` when :meth:`close` completes, so ``path`` is never a
            half-written file nor another run's (a killed writer leaves the temporary file,
            readable up to its last chunk). A run that fails calls :meth:`abort`: the log is
            closed with an ``incomplete`` metadata record saying why and renamed all the
            same (or removed when the disk is full).
        tee: an object that also receives every channel and message as written (a live
            view: :class:`Tee`); it sees the same topics, schemas and bytes as the file.

    Topics are registered on first use: the Foxglove ones by the typed methods, the JSON ones by
    :meth:`write_json` with the schema from :data:`logs.schemas.JSON_SCHEMAS` (or one given to
    :meth:`register_json_topic`).
    """

    def __init__(self, path: str | os.PathLike[str], *, chunk_size: int = 1024 * 1024,
                 compression: Literal["zstd", "lz4", "none"] | None = "zstd",
                 fsync: bool = False, start_utc: Any = None, atomic: bool = False,
                 tee: Tee | None = None) -> None:
        self.path = os.fspath(path)
        self._tee = tee
        self._tee_channels: dict[int, Any] = {}
        self.tee_error: str | None = None  # why the tee was dropped, if it was
        self.clock_offset_ns = 0 if start_utc is None else utc_ns(start_utc)
        self._lock = OutputLock(self.path).acquire() if atomic else None
        try:
            self.partial_path = os.fspath(temp_name(self.path)) if atomic else self.path
            self._file = _UnbufferedFile(self.partial_path, self.path)
        except BaseException:
            self._release()
            raise
        self._fsync = fsync
        self._writer = Writer(
            self._file,  # type: ignore[arg-type]
            chunk_size=chunk_size,
            compression=_COMPRESSION[compression],
            index_types=IndexType.ALL,
        )
        self._writer.start(profile="", library="adfusion logs")
        self._appender = _MessageAppender.of(self._writer)
        self._digests: dict[str, str] = {}  # record name → sha256 (see digest_metadata)
        if start_utc is not None:
            clock = encode_metadata({"start_utc": utc_iso(start_utc),
                                     "offset_ns": self.clock_offset_ns})
            self._writer.add_metadata("clock", clock)
            self._digests["metadata:clock"] = digest_metadata(clock)
        self._channels: dict[str, tuple[int, str]] = {}
        self._json_schemas: dict[str, tuple[str, dict[str, Any]]] = dict(JSON_SCHEMAS)
        self._proto_schemas: dict[str, tuple[int, tuple[str, str, bytes]]] = {}
        self._closed = False
        #: the log is complete at :attr:`path` (closed; with ``atomic``, renamed there)
        self.written = False
        self.message_count = 0

    # ------------------------------------------------------------------ plumbing
    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc is not None:
            self.abort(f"{exc_type.__name__}: {exc}" if str(exc) else exc_type.__name__)
        else:
            self.close()

    def close(self) -> None:
        """Finish the last chunk, write the summary and indexes, close the file (idempotent);
        with ``atomic``, then rename it to :attr:`path` — or, when finishing fails (a full
        disk), remove the temporary file, which could not be completed, and raise."""
        if self._closed:
            return
        self._closed = True
        try:
            try:
                if self._digests:
                    self._writer.add_metadata(DIGESTS, dict(self._digests))
                self._writer.finish()
                if self._fsync:
                    self._file.fsync()
            finally:
                self._file.close()
            if self.partial_path != self.path:
                replace_into(self.partial_path, self.path)
            else:
                note_written(self.path)
            self.written = True
        except BaseException:
            if self.partial_path != self.path:
                with contextlib.suppress(OSError):
                    os.remove(self.partial_path)
            raise
        finally:
            self._release()  # the lock outlives the rename: no one sees a half-there file

    def _release(self) -> None:
        if self._lock is not None:
            self._lock.release()

    def abort(self, reason: str) -> None:
        """End a run that failed: an ``incomplete`` metadata record (``reason``, messages
        written), then :meth:`close`. When even that fails (a full disk, a writer left
        broken by the failure), the partial file is removed and the original error stands:
        an aborted writer leaves its log marked ``incomplete``, or nothing — never its
        temporary file or its lock (a Ctrl-C meanwhile is raised after the cleanup)."""
        if self._closed:
            return
        try:
            self.add_metadata("incomplete", {"reason": reason,
                                             "messages_written": self.message_count})
            self.close()
        except BaseException as exc:
            self._closed = True
            with contextlib.suppress(Exception):
                self._file.close()
            if self.partial_path != self.path:
                with contextlib.suppress(OSError):
                    os.remove(self.partial_path)
            self._release()
            if not isinstance(exc, Exception):  # KeyboardInterrupt, SystemExit: not ours
                raise

    def flush(self) -> None:
        """End the chunk in progress now (it becomes readable after a crash)."""
        self._writer.flush()
        if self._fsync:
            self._file.fsync()

    def _ns(self, t_s: float) -> int:
        t_ns = round(float(t_s) * 1e9) + self.clock_offset_ns
        if t_ns < 0:
            raise ValueError(f"MCAP times are unsigned: t_s={t_s} < 0")
        return t_ns

    def _channel(self, topic: str, kind: str) -> int:
        """Channel id for ``topic``; ``kind`` is the Foxglove schema name or ``"json"``."""
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != kind:
                raise ValueError(f"topic {topic!r} carries {known[1]}, not {kind}")
            return known[0]
        if kind == "json":
            name, schema = self._json_schemas.get(topic, ("adfusion.Json", GENERIC))
            parts = (name, SchemaEncoding.JSONSchema, dumps(schema).encode())
            schema_id = self._writer.register_schema(name=parts[0], encoding=parts[1],
                                                     data=parts[2])
            encoding = MessageEncoding.JSON
        else:
            schema_id, parts = self._proto_schemas.get(kind, (0, None))
            if not schema_id:
                fds = build_file_descriptor_set(fg.MESSAGE_TYPES[kind])
                parts = (kind, SchemaEncoding.Protobuf, fds.SerializeToString())
                schema_id = self._writer.register_schema(name=parts[0], encoding=parts[1],
                                                         data=parts[2])
                self._proto_schemas[kind] = (schema_id, parts)
            encoding = MessageEncoding.Protobuf
        channel_id = self._writer.register_channel(
            topic=topic, message_encoding=encoding, schema_id=schema_id)
        self._channels[topic] = (channel_id, kind)
        if self._tee is not None:
            self._tee_channels[channel_id] = self._to_tee("channel", topic, encoding, *parts)
        return channel_id

    def _to_tee(self, what: str, *args: Any) -> Any:
        """Hand ``args`` to the tee's ``what``; a tee that fails is dropped, its error kept
        in :attr:`tee_error` (the live view stops, the log goes on)."""
        try:
            return getattr(self._tee, what)(*args)
        except Exception as exc:  # the log is the record; the view is a convenience
            self.tee_error = f"{type(exc).__name__}: {exc}"
            self._tee = None
            return None

    def _add(self, channel_id: int, t_ns: int, data: bytes, *parts: Any) -> None:
        """One message: ``data`` (with ``parts``, buffers that follow it in the message)."""
        if self._closed:
            raise ValueError("write to a closed LogWriter")
        if self._appender is not None:
            if parts:
                pieces = (data, *parts)
                self._appender.add_parts(channel_id, t_ns, self.message_count, pieces,
                                         sum(len(p) for p in pieces))
            else:
                self._appender.add_parts(channel_id, t_ns, self.message_count, (data,),
                                         len(data))
        else:
            if parts:
                data, parts = b"".join((data, *parts)), ()
            self._writer.add_message(channel_id=channel_id, log_time=t_ns, data=data,
                                     publish_time=t_ns, sequence=self.message_count)
        self.message_count += 1
        handle = self._tee_channels.get(channel_id) if self._tee is not None else None
        if handle is not None:  # after the file: a tee that fails costs the file nothing
            self._to_tee("message", handle, t_ns, b"".join((data, *parts)) if parts else data)

    def _write_proto(self, topic: str, t_ns: int, msg: ProtoMessage) -> None:
        kind = msg.DESCRIPTOR.full_name
        self._add(self._channel(topic, kind), t_ns, msg.SerializeToString())

    def declare(self, topic: str, kind: str) -> None:
        """Register ``topic``'s channel now, before its first message (``kind``: a Foxglove
        schema name of :data:`logs.foxglove.MESSAGE_TYPES`, or ``"json"``), so that a live
        view's client can subscribe to it before the first message is published."""
        if kind != "json" and kind not in fg.MESSAGE_TYPES:
            raise ValueError(f"unknown Foxglove schema {kind!r}")
        self._channel(topic, kind)

    def write_protobuf_bytes(self, topic: str, t_s: float, schema_name: str,
                             data: bytes) -> None:
        """One Foxglove message already serialized (``schema_name`` one of
        :data:`logs.foxglove.MESSAGE_TYPES`), e.g. an input frame copied as read
        (``Message.raw``): no decode/encode round trip of 245 kB per frame."""
        if schema_name not in fg.MESSAGE_TYPES:
            raise ValueError(f"unknown Foxglove schema {schema_name!r}")
        self._add(self._channel(topic, schema_name), self._ns(t_s), bytes(data))

    # ------------------------------------------------------------------ Foxglove topics
    def write_image(self, t_s: float, image: np.ndarray, frame_id: str = "camera", *,
                    topic: str = IMAGE_TOPIC, png: bool = False) -> None:
        """One camera frame: ``foxglove.RawImage`` (mono8 / mono16), or with ``png=True`` a
        lossless ``foxglove.CompressedImage`` (smaller, slower to write)."""
        t_ns = self._ns(t_s)
        if png:
            self._write_proto(topic, t_ns, fg.encode_png_image(t_ns, image, frame_id))
        else:  # the pixels go from the array into the chunk, not through two copies first
            self._add(self._channel(topic, "foxglove.RawImage"), t_ns,
                      *fg.encode_raw_image_parts(t_ns, image, frame_id))

    def write_annotations(self, t_s: float, detections_xy: ArrayLike | None = None,
                          identified: Iterable[tuple[float, float, Any]] = (),
                          predicted_xy: ArrayLike | None = None,
                          occupied: Iterable[ArrayLike] = (), *,
                          topic: str = ANNOTATIONS_TOPIC) -> None:
        """Overlay for the frame at ``t_s`` (``foxglove.ImageAnnotations``), pixels 0-based.

        Args:
            detections_xy: (N, 2) detected centroids (yellow points).
            identified: ``(x, y, label)`` per identified star, e.g. the HIP number (green
                circle and text; the label is stored as text).
            predicted_xy: (M, 2) catalogue stars projected with the estimate (cyan points).
            occupied: closed polygons (K, 2) of excluded regions, e.g. the tether (red).
        """
        t_ns = self._ns(t_s)
        data = fg.encode_annotations_bytes(t_ns, detections_xy, identified, predicted_xy,
                                           occupied)
        self._add(self._channel(topic, "foxglove.ImageAnnotations"), t_ns, data)

    def write_pose(self, topic: str, t_s: float, q_wxyz: ArrayLike, frame_id: str = "icrs",
                   position: ArrayLike = (0.0, 0.0, 0.0)) -> None:
        """``foxglove.PoseInFrame``: ``q_wxyz`` is the body's orientation *in* ``frame_id``,
        i.e. ``q_icrs_body`` (rotates body vectors into ICRS). From a filter's
        ``q_body_icrs`` use :meth:`write_attitude`."""
        t_ns = self._ns(t_s)
        self._write_proto(topic, t_ns, fg.encode_pose(t_ns, q_wxyz, frame_id, position))

    def write_attitude(self, topic: str, t_s: float, q_body_icrs: ArrayLike) -> None:
        """:meth:`write_pose` in ``icrs`` from ``q_body_icrs`` (docs/conventions.md),
        conjugating."""
        w, x, y, z = np.asarray(q_body_icrs, dtype=float).reshape(4)
        self.write_pose(topic, t_s, [w, -x, -y, -z], "icrs")

    def write_tf(self, t_s: float,
                 transforms: Iterable[tuple[str, str, ArrayLike, ArrayLike]], *,
                 topic: str = TF_TOPIC) -> None:
        """``foxglove.FrameTransforms`` from ``(parent, child, q_parent_child, translation)``.

        ``q_parent_child`` maps child vectors into the parent frame: for icrs→body pass
        ``conj(q_body_icrs)``; for body→camera pass ``q_body_cam``.
        """
        t_ns = self._ns(t_s)
        self._write_proto(topic, t_ns, fg.encode_transforms(t_ns, transforms))

    def write_calibration(self, t_s: float, width: int, height: int, K: ArrayLike,
                          D: ArrayLike = (), frame_id: str = "camera", *,
                          topic: str = CALIBRATION_TOPIC) -> None:
        """``foxglove.CameraCalibration`` from OpenCV's ``K`` (3×3) and ``D``."""
        t_ns = self._ns(t_s)
        self._write_proto(topic, t_ns,
                          fg.encode_calibration(t_ns, width, height, K, D, frame_id))

    # ------------------------------------------------------------------ JSON topics
    def register_json_topic(self, topic: str, schema_name: str,
                            schema: Mapping[str, Any]) -> None:
        """Use ``schema`` (a JSON schema) for ``topic``; call before its first message."""
        if topic in self._channels:
            raise ValueError(f"topic {topic!r} already has a channel")
        self._json_schemas[topic] = (schema_name, dict(schema))

    def write_json(self, topic: str, t_s: float, payload: Mapping[str, Any]) -> None:
        """One JSON message (numpy values become lists, NaN/inf become ``null``). Topics of
        :data:`logs.schemas.JSON_SCHEMAS` carry their schema; others a generic object one."""
        self._add(self._channel(topic, "json"), self._ns(t_s), dumps_bytes(payload))

    def write_json_bytes(self, topic: str, t_s: float, data: bytes) -> None:
        """One JSON message already encoded (``Message.raw`` of an input being copied)."""
        self._add(self._channel(topic, "json"), self._ns(t_s), bytes(data))

    # ------------------------------------------------------------------ file-level records
    def add_metadata(self, name: str, data: Mapping[str, Any]) -> None:
        """MCAP metadata record (e.g. ``"config"``, the run configuration). Non-string values
        are stored as JSON text; :meth:`logs.reader.McapLogReader.metadata` restores them.

        Its SHA-256 goes into the ``digests`` record written at :meth:`close`, which the
        reader checks: a calibration edited after recording is refused, not used."""
        encoded = encode_metadata(data)
        self._digests[f"metadata:{name}"] = digest_metadata(encoded)
        self._writer.add_metadata(name, encoded)

    def add_attachment(self, name: str, data: bytes, media_type: str = "application/octet-stream",
                       t_s: float = 0.0) -> None:
        """MCAP attachment (a file carried along with the log)."""
        t_ns = self._ns(t_s)
        self._digests[f"attachment:{name}"] = hashlib.sha256(bytes(data)).hexdigest()
        self._writer.add_attachment(create_time=t_ns, log_time=t_ns, name=name,
                                    media_type=media_type, data=bytes(data))

    def add_camera_model(self, model: Mapping[str, Any], name: str = "camera.json") -> None:
        """The camera model (a dict: K, D, width, height, ...) as a JSON attachment."""
        self.add_attachment(name, dumps(model).encode(), "application/json")
