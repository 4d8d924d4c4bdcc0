"""Replay sources: every one is an iterable of :class:`~logs.message.Message` in time order.

* :class:`McapSource` — an MCAP log (ours, or another with a topic map);
* :class:`ImageFolderSource` — a folder of images (sorted by name) with timestamps from a CSV
  or a fixed frame rate, plus an optional sensor CSV (:func:`read_sensor_csv`);
* :class:`VideoSource` — a video file through OpenCV at a given frame rate.

Images come out on ``/camera/image`` as grey ``uint8`` (``uint16`` kept for 16-bit files), gyro
samples on ``/imu/gyro`` as ``{"omega": [x, y, z]}`` (rad/s, body) and magnetometer samples on
``/mag`` as ``{"b_body": [x, y, z]}`` (nT, body) — the same payloads ``LogWriter`` records.
Damaged input never raises mid-run: a :class:`~logs.reader.McapReadWarning` says where it broke,
the text is appended to ``source.problems``, and everything before it is yielded.

Example:
    >>> import os, tempfile
    >>> import cv2, numpy as np
    >>> from adfusion.logs import ImageFolderSource
    >>> folder = tempfile.mkdtemp()
    >>> for i in range(2):
    ...     _ = cv2.imwrite(os.path.join(folder, f"f{i:03d}.png"), np.zeros((4, 4), np.uint8))
    >>> [(m.t_s, m.topic) for m in ImageFolderSource(folder, fps=10.0)]
    [(0.0, '/camera/image'), (0.1, '/camera/image')]
"""

from __future__ import annotations

import csv
import heapq
import io
import itertools
import math
import os
import warnings
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from adfusion.logs import topics
from adfusion.logs.message import Message
from adfusion.logs.name_times import times_from_names
from adfusion.logs.reader import McapLogReader, McapReadWarning

from adfusion.imagefiles import ImageFileError, max_image_pixels, read_frame_file, shown_path
from adfusion.plain import listed

IMAGE_TOPIC = topics.CAMERA_IMAGE
GYRO_TOPIC = topics.GYRO
MAG_TOPIC = topics.MAG
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp", ".pgm", ".pnm", ".fits")

GYRO_COLUMNS = ("gyro_x", "gyro_y", "gyro_z")
MAG_COLUMNS = ("mag_x", "mag_y", "mag_z")


def _report(problems: list[str], text: str) -> None:
    problems.append(text)
    warnings.warn(text, McapReadWarning, stacklevel=3)


def to_grey(image: np.ndarray) -> np.ndarray:
    """Single-channel view of an OpenCV image (BGR/BGRA → grey; depth kept)."""
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3:
        return image[:, :, 0]
    return image


def _finite(cell: str, what: str) -> float:
    """A CSV cell as a finite float; the error names the column."""
    try:
        value = float(cell)
    except ValueError:
        raise ValueError(f"{what}: {cell!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{what}: {cell!r} is not a finite number")
    return value


def _csv_rows(path: str | os.PathLike[str]) -> tuple[list[str], Iterator[dict[str, str]], Any]:
    """``(fieldnames, rows, reader)`` of a UTF-8 CSV; non-UTF-8 text or a missing header
    is a :class:`ValueError` naming the file."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            text = f.read()
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at "
                         f"offset {exc.start}); save the CSV as UTF-8") from None
    except IsADirectoryError:
        raise ValueError(f"{path}: is a directory, not a CSV file") from None
    reader = csv.DictReader(io.StringIO(text, newline=""))
    try:
        fields = [f.strip() for f in (reader.fieldnames or ())]
    except csv.Error as exc:
        raise ValueError(f"{path}: not a CSV file ({exc})") from None
    reader.fieldnames = fields
    return fields, reader, reader


def read_sensor_csv(path: str | os.PathLike[str],
                    problems: list[str] | None = None) -> list[Message]:
    """Gyro and magnetometer samples from a CSV file, sorted by time.

    Columns (header row required, any order, extra columns ignored):

    ``t_s``
        sample time, seconds (same clock as the images);
    ``gyro_x, gyro_y, gyro_z``
        body rate, rad/s, body frame → ``/imu/gyro`` ``{"omega": [...]}``;
    ``mag_x, mag_y, mag_z``
        magnetic field, nT, body frame → ``/mag`` ``{"b_body": [...]}``.

    Either group may be absent from the file or empty in a row (sensors at different rates
    share one file). A malformed row (a cell that is not a finite number, a partly empty
    group) stops the reading there with a warning naming the line and column and counting
    the lines not read; the rows before it are returned (a logger cut off mid-line). A
    malformed first row, a stream whose time does not increase (a repeated sample, a clock
    that went back), a file that is not UTF-8 text, or one that lacks ``t_s``, is a
    :class:`ValueError` naming the file and line.

    Example:
        >>> import os, tempfile
        >>> from pathlib import Path
        >>> path = Path(tempfile.mkdtemp()) / "imu.csv"
        >>> _ = path.write_text("t_s,gyro_x,gyro_y,gyro_z,mag_x,mag_y,mag_z\\n"
        ...                     "0.0,0.1,0,0,,,\\n0.01,0.1,0,0,2e4,0,-4e4\\n")
        >>> [(m.t_s, m.topic) for m in read_sensor_csv(path)]
        [(0.0, '/imu/gyro'), (0.01, '/imu/gyro'), (0.01, '/mag')]
    """
    problems = [] if problems is None else problems
    out: list[Message] = []
    names, reader, _ = _csv_rows(path)
    fields = set(names)
    if "t_s" not in fields:
        raise ValueError(f"{path}: no 't_s' column (have {listed(sorted(fields), 8)})")
    groups = [(cols, topic, key) for cols, topic, key in
              ((GYRO_COLUMNS, GYRO_TOPIC, "omega"), (MAG_COLUMNS, MAG_TOPIC, "b_body"))
              if set(cols) <= fields]
    if not groups:
        raise ValueError(f"{path}: neither the columns {', '.join(GYRO_COLUMNS)} nor "
                         f"{', '.join(MAG_COLUMNS)}")
    last_t: dict[str, tuple[float, int]] = {}  # topic → (time, line) of its last sample
    line = 0
    for row in reader:
        line = reader.line_num
        try:
            t_s = _finite((row.get("t_s") or "").strip(), "t_s")
            if t_s < 0:
                raise ValueError(f"t_s: {t_s} < 0 (times are seconds ≥ 0)")
            rows = []
            for cols, topic, key in groups:
                cells = [(row.get(c) or "").strip() for c in cols]
                if all(cells):
                    rows.append(Message(t_s, topic, {key: [_finite(c, n)
                                                           for c, n in zip(cells, cols,
                                                                           strict=True)]}))
                elif any(cells):
                    empty = [c for c, cell in zip(cols, cells, strict=True) if not cell]
                    raise ValueError(f"{', '.join(empty)} empty where the rest of "
                                     f"{', '.join(cols)} is given")
        except (TypeError, ValueError, csv.Error) as exc:
            if not out:  # not one sample: the file is not an IMU log to replay
                raise ValueError(f"{path}: line {line}: {exc}; no sample before it") from None
            rest = sum(1 for _ in _lines_after(reader))
            _report(problems, f"{path}: broken at line {line} ({exc}); {len(out)} samples "
                    f"read (t = {out[0].t_s:g}–{out[-1].t_s:g} s), {rest} line(s) after it "
                    "not read")
            break
        for m in rows:  # a stream's times only go forward: a clock that went back, or a
            if m.topic in last_t and m.t_s <= last_t[m.topic][0]:  # sample twice
                t0, l0 = last_t[m.topic]
                raise ValueError(f"{path}: line {line}: t_s {m.t_s:g} is not after line "
                                 f"{l0}'s {t0:g} ({m.topic} samples): times must increase "
                                 "(sort the file by t_s, or remove the repeated rows)")
            last_t[m.topic] = (m.t_s, line)
        out.extend(rows)
    out.sort(key=lambda m: m.t_s)
    return out


def _lines_after(reader: Any) -> Iterator[Any]:
    """The rows left in ``reader``, however broken (counted, not read)."""
    while True:
        try:
            yield next(reader)
        except StopIteration:
            return
        except csv.Error:
            yield None


def _check_fps(fps: Any, missing: str) -> None:
    if fps is None:
        raise ValueError(missing)
    try:
        ok = math.isfinite(fps) and fps > 0
    except TypeError:
        ok = False
    if not ok:
        raise ValueError(f"fps must be a finite frame rate > 0, got {fps!r}")


def _check_t0(t0_s: Any) -> None:
    try:
        ok = math.isfinite(t0_s) and t0_s >= 0
    except TypeError:
        ok = False
    if not ok:
        raise ValueError(f"t0_s must be a finite time ≥ 0, got {t0_s!r}")


def _frame_times(names: list[str], folder: Path, fps: float | None, t0_s: float,
                 timestamps_csv: str | os.PathLike[str] | None,
                 problems: list[str] | None = None) -> list[float]:
    """The time of each frame of ``names``: ``t0_s + i / fps``, or a timestamps CSV's
    (``filename, t_s``; then ``names`` is put in time order, in place). A CSV's negative
    time, second time for one file, or one time for two files is a ``ValueError`` naming
    the file and line.

    Nothing of a CSV that does not match the folder is dropped silently: rows naming no
    image of the folder, and images without a row (removed from ``names``: they have no
    time, so they are not replayed), are each counted and said in ``problems``, the first
    few by name; a CSV that names none of the folder's images is a ``ValueError``."""
    _check_t0(t0_s)
    if timestamps_csv is None:
        _check_fps(fps, "give fps (> 0) or a timestamps CSV")
        return [t0_s + i / fps for i in range(len(names))]
    problems = [] if problems is None else problems
    times: dict[str, tuple[float, int]] = {}  # file name → (t_s, line)
    fields, rows, reader = _csv_rows(timestamps_csv)
    if not {"filename", "t_s"} <= set(fields):
        raise ValueError(f"{timestamps_csv}: needs the columns 'filename' and 't_s' (have "
                         f"{listed(sorted(fields), 8)})")
    try:
        for row in rows:
            t_s = _finite((row.get("t_s") or "").strip(), "t_s")
            if t_s < 0:
                raise ValueError(f"t_s {t_s:g} < 0: times are seconds ≥ 0 (shift them all "
                                 "by the same amount)")
            name = os.path.basename(row.get("filename") or "")
            if name in times:  # a second time for one frame: which one is true?
                raise ValueError(f"{name} is also at line {times[name][1]}: give each "
                                 "frame one time")
            times[name] = (t_s, reader.line_num)
    except (ValueError, csv.Error) as exc:
        raise ValueError(f"{timestamps_csv}: line {reader.line_num}: {exc}") from None
    present = set(names)
    strays = [(line, n) for n, (_, line) in times.items() if n not in present]
    missing = [n for n in names if n not in times]
    if len(missing) == len(names):
        said = (f"; its rows name {listed(n or '(empty)' for _, n in strays)}" if strays
                else "; it has no rows")
        raise ValueError(f"{timestamps_csv}: no time for any of the folder's {len(names)} "
                         f"image(s) ({listed(shown_path(n) for n in names)}){said}: the "
                         "filename column names each image's file in the folder")
    if strays:
        _report(problems, f"{timestamps_csv}: {len(strays)} row(s) name no image of the "
                f"folder {shown_path(folder)} ("
                + listed(f"line {line}: {n or '(empty)'}" for line, n in strays)
                + "): their times are not used")
    if missing:
        _report(problems, f"{timestamps_csv}: {len(missing)} of the folder's {len(names)} "
                f"image(s) have no row, so no time, and are not replayed: "
                + listed(shown_path(n) for n in missing))
        names[:] = [n for n in names if n in times]
    # the frames are replayed in the order of their times (the file's truth, whatever
    # the names' order); two frames at one time cannot both be true
    names.sort(key=lambda n: times[n][0])
    for a, b in itertools.pairwise(names):
        (ta, la), (tb, lb) = times[a], times[b]
        if tb == ta:
            raise ValueError(f"{timestamps_csv}: line {lb}: {b} has the time of {a} (line "
                             f"{la}): t_s {tb:g} for both; give each frame its own time")
    return [times[n][0] for n in names]


def _utc_minus(start_utc: str, seconds: float) -> str:
    """ISO 8601 UTC ``seconds`` before ``start_utc``."""
    import datetime as dt

    t = dt.datetime.fromisoformat(start_utc.replace("Z", "+00:00"))
    return (t - dt.timedelta(seconds=seconds)).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def image_names(folder: str | os.PathLike[str]) -> list[str]:
    """The names of the frame files in ``folder`` (by :data:`IMAGE_SUFFIXES`), sorted."""
    return sorted(p.name for p in Path(folder).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


class ImageFolderSource:
    """Images of a folder in name order (in time order with a timestamps CSV), with a sensor
    CSV merged in by time.

    Args:
        folder: directory of images (``.png``, ``.tif``, ``.jpg``, ``.pgm``, ... ).
        fps: frame rate when there is no timestamps CSV; frame ``i`` is at ``t0_s + i / fps``.
            Without either, the times the file names give
            (:mod:`adfusion.logs.name_times`), when every name gives one; with ``fps`` or
            without, names that give times set :attr:`start_utc`.
        t0_s: time of the first frame with ``fps``.
        timestamps_csv: CSV with columns ``filename, t_s`` (file name without folder); the
            frames are then replayed in the order of their times.
        sensors_csv: gyro/magnetometer CSV, see :func:`read_sensor_csv`.

    Frames are read by :func:`adfusion.imagefiles.read_frame_file` (names of any bytes,
    the pixel cap ``ADFUSION_MAX_IMAGE_PIXELS``, FITS through astropy). An unreadable image
    — truncated, over the cap, not decodable — is skipped with a warning naming it (the
    frames around it are fine).
    """

    def __init__(self, folder: str | os.PathLike[str], *, fps: float | None = None,
                 t0_s: float = 0.0, timestamps_csv: str | os.PathLike[str] | None = None,
                 sensors_csv: str | os.PathLike[str] | None = None) -> None:
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise ValueError(f"{self.folder}: not a folder of images")
        self.names = image_names(self.folder)
        #: the UTC of t = 0 when the file names give the frames' times (else None)
        self.start_utc: str | None = None
        named = times_from_names(self.names) if timestamps_csv is None and self.names else None
        if named is not None and not named.why:
            self.start_utc = _utc_minus(named.start_utc, t0_s)
        #: what the input has wrong (a timestamps CSV that does not match the folder, a
        #: frame that could not be read, the sensor CSV's damage), one line each
        self.problems: list[str] = []
        if not self.names:
            self.times = []  # nothing to time: the caller says the folder has no images
        elif fps is None and timestamps_csv is None and named is not None:
            if named.why:
                raise ValueError(f"{self.folder}: frame times unknown: give fps or a "
                                 f"timestamps CSV (the file names give none: {named.why})")
            self.names[:] = [n for _, n in sorted(zip(named.t_s, self.names, strict=True))]
            self.times = [t0_s + t for t in sorted(named.t_s)]
        else:
            self.times = _frame_times(self.names, self.folder, fps, t0_s, timestamps_csv,
                                      self.problems)
        self.sensors_csv = sensors_csv
        self.unreadable: list[str] = []  # why each skipped frame was not read, in time order
        max_image_pixels()  # a bad ADFUSION_MAX_IMAGE_PIXELS is said once, here

    def frames(self) -> Iterator[Message]:
        """The images alone, in time order."""
        for t_s, name in sorted(zip(self.times, self.names, strict=True)):
            try:
                image = read_frame_file(self.folder / name)
            except (ImageFileError, OSError) as exc:  # truncated, too big, not decodable
                self.unreadable.append(str(exc))
                _report(self.problems, f"{shown_path(self.folder / name)}: unreadable image "
                        f"at t = {t_s} s; skipped")
                continue
            yield Message(t_s, IMAGE_TOPIC, image)

    def __iter__(self) -> Iterator[Message]:
        sensors = ([] if self.sensors_csv is None
                   else read_sensor_csv(self.sensors_csv, self.problems))
        return heapq.merge(sensors, self.frames(), key=lambda m: m.t_s)


_GREY8 = int.from_bytes(b"Y800", "little")  # FFmpeg's gray8 pixel format, as OpenCV says it


def _open_video(path: str) -> cv2.VideoCapture:
    """``VideoCapture`` of ``path``; a grey 8-bit stream (FFV1 or raw ``Y800`` of a star
    camera) is read as it is decoded, without OpenCV's grey → BGR conversion that
    :func:`to_grey` would then undo — the same pixels for 0.5–1 ms less CPU per 512×480 frame.
    Any other stream (colour, YUV, 16-bit) is converted as before: its luma plane is not
    what BGR → grey gives."""
    cap = cv2.VideoCapture(path)
    if not cap.isOpened() or int(cap.get(cv2.CAP_PROP_CODEC_PIXEL_FORMAT)) != _GREY8:
        return cap
    size = (int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)), int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)))
    cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
    ok, first = cap.read()  # the unconverted frame must be the grey image itself
    cap.release()
    cap = cv2.VideoCapture(path)
    if ok and first.shape == size and first.dtype == np.uint8:
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
    return cap


class VideoSource:
    """Frames of a video file (anything OpenCV's ``VideoCapture`` opens) as grey ``uint8``.

    Args:
        path: the video.
        fps: frame rate; frame ``i`` is at ``t0_s + i / fps``. ``None`` uses the container's
            rate (often wrong for digitised analogue video — pass it when known).
        t0_s: time of the first frame.
        sensors_csv: optional gyro/magnetometer CSV, see :func:`read_sensor_csv`.

    A video that ends before the frame count its container announces is reported as
    truncated (frames decoded, last good time).
    """

    def __init__(self, path: str | os.PathLike[str], *, fps: float | None = None,
                 t0_s: float = 0.0, sensors_csv: str | os.PathLike[str] | None = None) -> None:
        self.path = os.fspath(path)
        if not os.path.exists(self.path):
            raise FileNotFoundError(self.path)
        cap = cv2.VideoCapture(self.path)
        try:
            if not cap.isOpened():
                raise ValueError(f"{self.path}: OpenCV cannot open this video")
            self.frame_count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            container_fps = float(cap.get(cv2.CAP_PROP_FPS))
        finally:
            cap.release()
        _check_t0(t0_s)
        if fps is not None:
            _check_fps(fps, "")
            self.fps = float(fps)
        else:
            self.fps = container_fps
            if not (math.isfinite(self.fps) and self.fps > 0):
                raise ValueError(f"{self.path}: no frame rate in the container; pass fps")
        self.t0_s = float(t0_s)
        self.sensors_csv = sensors_csv
        self.problems: list[str] = []

    def frames(self) -> Iterator[Message]:
        """The frames alone, in order."""
        cap = _open_video(self.path)
        i = 0
        try:
            while True:
                ok, frame = cap.read()
                if not ok:
                    break
                grey = to_grey(frame)
                if grey.dtype != np.uint8:
                    grey = cv2.convertScaleAbs(grey, alpha=255.0 / float(np.iinfo(grey.dtype).max))
                yield Message(self.t0_s + i / self.fps, IMAGE_TOPIC, grey)
                i += 1
        finally:
            cap.release()
        if 0 < i < self.frame_count:
            _report(self.problems, f"{self.path}: broken after frame {i} of {self.frame_count} "
                    f"(last good t = {self.t0_s + (i - 1) / self.fps:.6f} s)")
        elif i == 0:
            _report(self.problems, f"{self.path}: no frame could be decoded")

    def __iter__(self) -> Iterator[Message]:
        sensors = ([] if self.sensors_csv is None
                   else read_sensor_csv(self.sensors_csv, self.problems))
        return heapq.merge(sensors, self.frames(), key=lambda m: m.t_s)


class McapSource:
    """An MCAP log as a replay source (see :class:`~logs.reader.McapLogReader`).

    Example:
        >>> import os, tempfile
        >>> import numpy as np
        >>> from adfusion.logs import LogWriter, McapSource
        >>> path = os.path.join(tempfile.mkdtemp(), "run.mcap")
        >>> with LogWriter(path) as log:
        ...     log.write_image(0.0, np.zeros((4, 4), np.uint8))
        ...     log.write_json("/imu/gyro", 0.0, {"omega": [0, 0, 1]})
        >>> src = McapSource(path, topics=["/camera/image", "/imu/gyro", "/mag"])
        >>> [m.topic for m in src], src.problems
        (['/camera/image', '/imu/gyro'], [])
    """

    def __init__(self, path: str | os.PathLike[str], *,
                 topic_map: Mapping[str, str] | None = None,
                 topics: Iterable[str] | None = None) -> None:
        self.reader = McapLogReader(path, topic_map=topic_map, topics=topics, warn=True)

    @property
    def problems(self) -> list[str]:
        """Every problem the reader found so far (iteration can add a chunk's CRC failure)."""
        return [str(p) for p in self.reader.problems]

    def __iter__(self) -> Iterator[Message]:
        return self.reader.messages()
