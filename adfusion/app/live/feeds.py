"""Where live frames and IMU samples come from: each feed runs in a thread of its own and
hands what arrives to a :class:`~adfusion.app.live.source.LiveSource`.

* :class:`FolderFeed` — image files landing in a folder (written by another program);
* :class:`CameraFeed` — an OpenCV ``VideoCapture``: a camera index, an RTSP/HTTP URL or a
  GStreamer pipeline;
* :class:`PacedFeed` — a recorded input (a log, a folder with its times, a video) at its
  recorded pace (``adfusion live INPUT --realtime``);
* :class:`ImuFileFeed` / :class:`ImuUdpFeed` — gyro and magnetometer lines from a CSV file
  that grows, or from UDP datagrams.

A frame's time is the moment it arrived on the live clock (seconds since the run started,
:class:`LiveClock`); a recorded input keeps its own times. IMU lines carry their own times
as Unix seconds (UTC, what a logger stamps with ``time.time()``): the clock every program on
the machine shares (docs/decisions.md, "Live").

Example:
    >>> m, = parse_imu_line("1700000000.5,0.1,0,0", ("t_s", "gyro_x", "gyro_y", "gyro_z"),
    ...                     1700000000.0)
    >>> m.t_s, m.topic, m.payload
    (0.5, '/imu/gyro', {'omega': [0.1, 0.0, 0.0]})
"""

from __future__ import annotations

import datetime as dt
import math
import os
import socket
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from adfusion.app.errors import UsageError
from adfusion.app.replay.stages import is_frame
from adfusion.imagefiles import ImageFileError, read_frame_file
from adfusion.logs import Message, topics
from adfusion.logs.sources import GYRO_COLUMNS, IMAGE_SUFFIXES, MAG_COLUMNS

__all__ = ["CameraFeed", "FolderFeed", "ImuFileFeed", "ImuUdpFeed", "LiveClock", "PacedFeed",
           "parse_imu_line"]

#: how often a folder or a growing file is looked at (s): 5 ms costs ~0.1 % of a core for
#: a folder of a few hundred files and adds 2.5 ms to the mean latency
POLL_S = 0.005

#: the columns of a UDP line, and of a CSV line without a header
UDP_COLUMNS = ("t_s", *GYRO_COLUMNS, *MAG_COLUMNS)


class LiveClock:
    """The run's clock: seconds since it started (``perf_counter`` based, so it never goes
    back), with the UTC of its start (:attr:`start_utc`) and the Unix time of t = 0."""

    def __init__(self) -> None:
        self.p0 = time.perf_counter()
        self.unix0 = time.time()
        self.start_utc = dt.datetime.fromtimestamp(self.unix0, dt.UTC).isoformat().replace(
            "+00:00", "Z")

    def now(self) -> float:
        """Seconds since the start."""
        return time.perf_counter() - self.p0


class _Thread:
    """A daemon thread running ``self._loop`` until :meth:`stop`; an exception ends the
    feed with its text as the reason (said by the source, never a traceback)."""

    name = "feed"

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.sink: Any = None  # the LiveSource

    def start(self, sink: Any) -> None:
        self.sink = sink
        self._thread = threading.Thread(target=self._run, daemon=True, name=self.name)
        self._thread.start()

    def _run(self) -> None:
        try:
            self._loop()
        except Exception as exc:  # the feed ends, the run says why
            self.sink.feed_ended(self, f"{self.name}: {exc}")
            return
        finally:
            self.release()
        self.sink.feed_ended(self, None)

    def _loop(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def release(self) -> None:
        """Let go of what the feed holds (a camera, a socket); idempotent."""

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)

    def close(self) -> None:
        """:meth:`stop`, and :meth:`release` for a feed that never ran."""
        self.stop()
        if self._thread is None or not self._thread.is_alive():
            self.release()


class FolderFeed(_Thread):
    """Image files that land in ``folder`` (sorted by name when several land at once).

    A file is taken once its size and modification time are the same on two looks
    :data:`POLL_S` apart and it reads as a whole image (:func:`adfusion.imagefiles.read_frame_file`
    refuses one cut short); a writer still writing is waited for, one that writes under a
    hidden name (``.name``) or a ``.tmp``/``.part`` name and renames is seen when renamed.
    A file written again under a name already taken (a camera program that overwrites
    ``latest.png``) is a new frame. Files there before the start are left alone unless
    ``include_existing``. A file that stays unreadable for ``give_up_s`` is dropped and
    counted (:attr:`unreadable`).

    The folder is listed only when its own modification time changes (a file added,
    renamed or removed), so a look costs the same with 20 000 files as with 20; the
    files being written are looked at each time. A frame's time is its file's
    modification time on the run's clock when that lies between the previous frame's and
    now (frames written in a burst keep their spacing), else when it was seen."""

    name = "folder"

    def __init__(self, folder: str | os.PathLike[str], *, include_existing: bool = False,
                 give_up_s: float = 2.0) -> None:
        super().__init__()
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise FileNotFoundError(f"{folder}: no such folder")
        self.give_up_s = give_up_s
        self.unreadable: list[str] = []
        # name → (size, mtime) of the version taken (or there at the start)
        self._done: dict[str, tuple[int, int]] = {} if include_existing else {
            n: self._key(n) for n in self._names()}
        self.existing = len(self._done)
        self._t_last = -1.0

    def _names(self) -> list[str]:
        try:
            with os.scandir(self.folder) as it:
                return sorted(e.name for e in it if e.name.lower().endswith(IMAGE_SUFFIXES)
                              and not e.name.startswith("."))
        except FileNotFoundError:
            raise FileNotFoundError(f"{self.folder}: the folder went away") from None

    def _key(self, name: str) -> tuple[int, int]:
        try:
            st = os.stat(self.folder / name)
        except FileNotFoundError:
            return (-1, -1)
        return st.st_size, st.st_mtime_ns

    def _loop(self) -> None:
        seen: dict[str, tuple[int, int, float]] = {}  # name → size, mtime, since (perf)
        clock = self.sink.clock
        listed_at = None
        while not self._stop.is_set():
            try:
                folder_mtime = os.stat(self.folder).st_mtime_ns
            except FileNotFoundError:
                raise FileNotFoundError(f"{self.folder}: the folder went away") from None
            if folder_mtime != listed_at:
                listed_at = folder_mtime
                names = self._names()
                fresh = [n for n in names if n not in self._done]
                if not fresh:  # something replaced under a name taken before
                    fresh = [n for n in names if self._key(n) != self._done[n]]
                for n in fresh:
                    seen.setdefault(n, (-2, -2, time.perf_counter()))
            for name in sorted(seen):
                key = self._key(name)
                size, mtime, since = seen[name]
                if key[0] < 0:  # gone before it was read
                    seen.pop(name)
                    self.sink.frame_abandoned(name)
                    continue
                if (size, mtime) != key:
                    seen[name] = (*key, time.perf_counter())
                    self.sink.frame_pending(name, seen[name][2] - clock.p0)
                    continue
                try:
                    image = read_frame_file(self.folder / name)
                except (ImageFileError, OSError) as exc:
                    if time.perf_counter() - since > self.give_up_s:
                        self._done[name] = key
                        seen.pop(name)
                        self.unreadable.append(str(exc))
                        self.sink.frame_abandoned(name)
                    continue
                self._done[name] = key
                seen.pop(name)
                # it arrived when it first showed its final size (one look before this)
                t_seen = since - clock.p0
                t_file = key[1] * 1e-9 - clock.unix0
                t = t_file if self._t_last < t_file <= t_seen else max(t_seen,
                                                                       self._t_last + 1e-6)
                self._t_last = t
                self.sink.offer_frame(t, image, since, name)
            self._stop.wait(POLL_S)


class CameraFeed(_Thread):
    """Frames from an OpenCV ``VideoCapture``: ``spec`` a camera index (``"0"``), a URL
    (``rtsp://…``, ``http://…``, ``file:…``) or a GStreamer pipeline (text with ``!``).
    Grabbed as fast as the camera gives them; each frame is stamped when grabbed."""

    name = "camera"

    def __init__(self, spec: str) -> None:
        super().__init__()
        import cv2

        self.spec = spec
        if spec.isdigit():
            self._cap = cv2.VideoCapture(int(spec))
        elif "!" in spec:
            self._cap = cv2.VideoCapture(spec, cv2.CAP_GSTREAMER)
        else:
            self._cap = cv2.VideoCapture(spec)
        if not self._cap.isOpened():
            self._cap.release()
            raise ValueError(f"{spec}: OpenCV cannot open this camera or stream (a camera "
                             "index such as 0, an rtsp:// or http:// URL, or a GStreamer "
                             "pipeline; `v4l2-ctl --list-devices` lists the cameras)")

    def release(self) -> None:
        self._cap.release()

    def _loop(self) -> None:
        from adfusion.logs.sources import to_grey

        clock = self.sink.clock
        misses = 0
        while not self._stop.is_set():
            ok, frame = self._cap.read()
            arrived = time.perf_counter()
            if not ok or frame is None:
                misses += 1
                if misses >= 3:  # a stream that ended, or a camera unplugged
                    return
                self._stop.wait(0.05)
                continue
            misses = 0
            self.sink.offer_frame(arrived - clock.p0, np.ascontiguousarray(to_grey(frame)),
                                  arrived)


class PacedFeed(_Thread):
    """A recorded input (:func:`adfusion.app.replay.sources.open_input`) handed on at its
    recorded pace: message ``k`` when ``t_k - t_0`` seconds have passed. Frames go to the
    frame slot (dropped when the solver is behind, as a camera's would be), everything else
    in order."""

    name = "realtime"

    def __init__(self, source: Any, speed: float = 1.0) -> None:
        super().__init__()
        self.source = source
        self.speed = speed

    def _loop(self) -> None:
        t0 = None
        p0 = time.perf_counter()
        for msg in self.source:
            if self._stop.is_set():
                return
            if t0 is None:
                t0 = msg.t_s
            due = p0 + (msg.t_s - t0) / self.speed
            wait = due - time.perf_counter()
            if wait > 0:
                if self._stop.wait(wait):
                    return
            if is_frame(msg.topic):
                self.sink.offer_frame(msg.t_s, msg, time.perf_counter())
            else:
                self.sink.offer_other([msg])


def parse_imu_line(line: str, columns: Sequence[str], unix0: float) -> list[Message]:
    """The gyro and magnetometer samples of one CSV line (``columns`` its header), times
    turned from Unix seconds into seconds after ``unix0``. An empty group gives no sample;
    a cell that is not a finite number is a :class:`ValueError` naming its column.

    >>> [m.topic for m in parse_imu_line("10.0,0,0,0.1,,,", UDP_COLUMNS, 9.5)]
    ['/imu/gyro']
    """
    cells = [c.strip() for c in line.split(",")]
    row = dict(zip(columns, cells, strict=False))
    try:
        t = float(row.get("t_s", ""))
    except ValueError:
        raise ValueError(f"t_s {row.get('t_s')!r} is not a number") from None
    out = []
    for cols, topic, key in ((GYRO_COLUMNS, topics.GYRO, "omega"),
                             (MAG_COLUMNS, topics.MAG, "b_body")):
        got = [row.get(c, "") for c in cols]
        if not any(got):
            continue
        try:
            values = [float(v) for v in got]
        except ValueError:
            bad = next(c for c, v in zip(cols, got, strict=True) if not _is_number(v))
            raise ValueError(f"{bad} {row.get(bad)!r} is not a number") from None
        if not all(math.isfinite(v) for v in values) or not math.isfinite(t):
            raise ValueError("a value that is not finite")
        out.append(Message(t - unix0, topic, {key: values}))
    return out


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


class _ImuFeed(_Thread):
    """Lines of IMU samples handed on as they come; a line that does not parse, or whose
    time is over an hour from the clock's (not Unix seconds), is dropped and counted."""

    def __init__(self) -> None:
        super().__init__()
        self.bad: list[str] = []
        self.lines = 0

    def _bad(self, why: str) -> None:
        """A line dropped: counted, and said at once the first time (not only at the end)."""
        if not self.bad:
            import warnings

            warnings.warn(f"{self.name}: {why}; such lines are dropped and counted",
                          stacklevel=2)
        self.bad.append(why)

    def _take(self, lines: Iterable[str], columns: Sequence[str]) -> None:
        clock = self.sink.clock
        out: list[Message] = []
        for line in lines:
            if not line.strip() or line.lstrip().startswith("t_s"):
                continue
            self.lines += 1
            try:
                msgs = parse_imu_line(line, columns, clock.unix0)
            except ValueError as exc:
                shown = line.strip()[:60]
                self._bad(f"{exc} in the line '{shown}'")
                continue
            if msgs and abs(msgs[0].t_s - clock.now()) > 3600:
                self._bad(f"t_s {msgs[0].t_s + clock.unix0:.6g} is not a Unix time within "
                          "the hour (IMU lines carry Unix seconds, UTC)")
                continue
            out.extend(msgs)
        if out:
            self.sink.offer_other(out)


class ImuFileFeed(_ImuFeed):
    """A CSV file that another program appends to (``t_s`` in Unix seconds, ``gyro_x..z``
    rad/s, ``mag_x..z`` nT; the header as :func:`adfusion.logs.read_sensor_csv`); lines
    already there at the start are skipped, a line being written is waited for."""

    name = "imu file"

    def __init__(self, path: str | os.PathLike[str]) -> None:
        super().__init__()
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"--imu {path}: no such file (create it, even empty, "
                                    "before the run: lines are read as they are added)")
        self._had = self.path.stat().st_size  # what is there at the start is the past
        self._skip_partial = False

    def _loop(self) -> None:
        with open(self.path, "rb") as f:
            data = b""
            while b"\n" not in data and not self._stop.is_set():
                data += f.read()  # an empty file: its header comes first
                if b"\n" not in data:
                    self._stop.wait(POLL_S)
            header = data.partition(b"\n")[0]
            columns = [c.strip() for c in header.decode("utf-8", "replace").split(",")]
            start = len(header) + 1
            if "t_s" not in columns:  # no header: the UDP order
                columns = list(UDP_COLUMNS)
                start = 0 if self._had == 0 else start  # written after the start: data
            # what was there at the start is the past: read on from where the file ended,
            # after the rest of a line being written then
            pos = max(self._had, start)
            partial = data[pos:]
            self._skip_partial = pos > 0 and data[pos - 1:pos] != b"\n"
            while not self._stop.is_set():
                *lines, partial = partial.split(b"\n")
                if lines and self._skip_partial:  # the rest of the line being written
                    lines, self._skip_partial = lines[1:], False
                if lines:
                    self._take([ln.decode("utf-8", "replace") for ln in lines], columns)
                chunk = f.read()
                if not chunk:
                    self._stop.wait(POLL_S)
                partial += chunk


class ImuUdpFeed(_ImuFeed):
    """UDP datagrams on ``host:port``, each one or more lines ``t_s,gyro_x,gyro_y,gyro_z``
    (``,mag_x,mag_y,mag_z`` optional; Unix seconds, rad/s, nT)."""

    name = "imu udp"

    def __init__(self, address: str) -> None:
        super().__init__()
        host, _, port = address.rpartition(":")
        try:
            self.address = (host or "127.0.0.1", int(port))
        except ValueError:
            raise ValueError(f"--imu udp://{address}: give udp://HOST:PORT, e.g. "
                             "udp://0.0.0.0:9870") from None
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind(self.address)
        except OSError as exc:
            self._sock.close()
            raise ValueError(f"--imu udp://{address}: cannot listen there ({exc.strerror})") \
                from None
        self._sock.settimeout(0.05)

    @property
    def port(self) -> int:
        return self._sock.getsockname()[1]

    def release(self) -> None:
        self._sock.close()

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                data = self._sock.recv(65536)
            except TimeoutError:
                continue
            self._take(data.decode("utf-8", "replace").splitlines(), UDP_COLUMNS)


def imu_feed(spec: str) -> _ImuFeed:
    """The IMU feed of ``--imu SPEC``: ``udp://HOST:PORT`` or a CSV file's path."""
    if spec.startswith("udp://"):
        return ImuUdpFeed(spec[len("udp://"):])
    return ImuFileFeed(spec)


def frame_feed(spec: str, *, include_existing: bool = False) -> _Thread:
    """The frame feed of ``SOURCE`` (not ``--realtime``): a folder, else a camera; a file
    (a recording) or a path that is not there is said as such."""
    if os.path.isdir(spec):
        return FolderFeed(spec, include_existing=include_existing)
    if os.path.isfile(spec):
        raise UsageError(f"{spec}: a file is a recording: give --realtime to play it at its "
                         "pace (or `adfusion replay` to solve it as fast as it goes)")
    if not (spec.isdigit() or "://" in spec or spec.startswith("file:") or "!" in spec):
        raise FileNotFoundError(f"{spec}: no such folder (a live SOURCE is a folder, a "
                                "camera index, a stream URL or a GStreamer pipeline)")
    return CameraFeed(spec)


#: for type hints of callers
Feed = _Thread
