"""Replay inputs: each is a :class:`Source` — time-ordered messages plus what the input
knows about its run (camera model, configuration, damage found while reading).

Example:
    >>> import os, tempfile
    >>> from adfusion.sensors.scenarios import oedipus
    >>> from adfusion.app.replay import McapInput, simulate
    >>> path = os.path.join(tempfile.mkdtemp(), "sim.mcap")
    >>> _ = simulate(oedipus(duration_s=0.2, render=False), path)
    >>> src = McapInput(path)
    >>> src.camera_model()["width"], src.has_images, src.problem
    (512, False, None)
"""

from __future__ import annotations

import heapq
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from adfusion.app.errors import UsageError
from adfusion.imagefiles import ImageFileError, decode_frame_bytes, frame_size
from adfusion.logs import (
    ImageFolderSource,
    McapLogReader,
    Message,
    VideoSource,
    read_sensor_csv,
    topics,
)
from adfusion.logs.sources import IMAGE_SUFFIXES
from adfusion.outfiles import files_in

__all__ = ["FolderInput", "McapInput", "Ros2BagInput", "Source", "VideoInput", "open_input"]


class Source(Protocol):
    """What a replay input provides (see :class:`McapInput`).

    Attributes:
        name: the input, as named in the output's ``replay`` metadata.
        config: the run configuration (``q_body_cam``, ``gyro``, ``camera``, ``catalog``,
            ``mag_limit`` … as :func:`adfusion.app.replay.simulate` records it); ``{}`` if
            unknown.
        has_images: whether frames come as images (else as centroids).
    """

    name: str
    config: dict[str, Any]
    has_images: bool

    def camera_model(self) -> dict[str, Any] | None:
        """The camera model (:meth:`adfusion.starid.camera.model.Camera.to_dict`), if known."""

    def image_size(self) -> tuple[int, int] | None:
        """(width, height) of the frames, when the input can tell it cheaply."""

    def __iter__(self) -> Iterator[Message]:
        """The messages in time order."""

    @property
    def problem(self) -> str | None:
        """Where the input broke (``None`` for an intact one); read after iterating."""


class McapInput:
    """An MCAP log of ours (or one with the same topics): messages as
    :class:`~adfusion.logs.McapLogReader` reads them, the camera model from the
    ``camera.json`` attachment, the configuration from the ``config`` metadata."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.name = str(path)
        self.reader = McapLogReader(path)
        self.config: dict[str, Any] = self.reader.metadata.get("config", {})
        # images of any camera: /camera/image, /camera1/image, … (topics.camera_topic); the
        # compression choice and the centroid σ's floor follow it
        self.has_images = any(re.fullmatch(r"/camera\d*/image", c.topic) is not None
                              for c in self.reader.channels.values())
        self.start_utc = self.reader.start_utc
        self.has_gyro = any(c.topic == topics.GYRO for c in self.reader.channels.values())

    def camera_model(self) -> dict[str, Any] | None:
        return self.reader.camera_model()

    def camera_models(self) -> list[dict[str, Any] | None]:
        """Every camera's model (``camera.json``, ``camera1.json``, …) of a several-camera
        log, in camera order."""
        n = max(len(self.config.get("heads", [])), 1)
        return [self.reader.camera_model("camera.json" if k == 0 else f"camera{k}.json")
                for k in range(n)]

    def image_size(self) -> tuple[int, int] | None:
        return None

    def __iter__(self) -> Iterator[Message]:
        return iter(self.reader)

    def __len__(self) -> int:
        return self.reader.message_count

    @property
    def problem(self) -> str | None:
        return None if self.reader.problem is None else str(self.reader.problem)

    @property
    def problems(self) -> list[str]:
        """Every problem the reader found (read after iterating: a chunk failing its CRC
        is found when reached)."""
        return [str(p) for p in self.reader.problems]

def _sensors(imu: str | os.PathLike[str] | None, problems: list[str]) -> list[Message]:
    """Gyro/magnetometer samples of a CSV (:func:`adfusion.logs.read_sensor_csv`) or a PX4
    ULog (``.ulg``, through ``pyulog``)."""
    if imu is None:
        return []
    if not os.path.exists(imu):
        raise FileNotFoundError(f"--imu {imu}: no such file")
    if str(imu).lower().endswith(".ulg"):
        return read_ulog(imu, problems)
    return read_sensor_csv(imu, problems)


def read_ulog(path: str | os.PathLike[str], problems: list[str] | None = None,
              ) -> list[Message]:
    """Gyro (``sensor_combined.gyro_rad``, rad/s) and magnetometer (``vehicle_magnetometer``
    or ``sensor_mag``, gauss → nT) samples of a PX4 ULog, on the log's clock (its
    ``timestamp``, µs since boot, in seconds): the frames' times must be on that clock
    (``--timestamps``). Needs ``pyulog`` (the ``ulog`` extra).

    A file that is not a ULog, or holds no gyro sample, is a ``ValueError`` naming it; one
    that ends mid-message (:func:`ulog_truncated_at`) or that pyulog finds corrupt is read
    as far as it goes and said so in ``problems``."""
    import contextlib
    import io

    try:
        from pyulog import ULog
    except ImportError:
        raise ValueError(f"--imu {path}: reading PX4 ULog needs pyulog "
                         "(pip install 'pyulog>=1.0')") from None
    said = io.StringIO()  # pyulog prints its findings: they become our one line
    try:
        with contextlib.redirect_stdout(said):
            ulog = ULog(os.fspath(path), ["sensor_combined", "vehicle_magnetometer",
                                          "sensor_mag"])
    except Exception as exc:  # pyulog's ULogException, struct.error, …: not a ULog
        raise ValueError(f"--imu {path}: not a readable PX4 ULog: its header or message "
                         f"definitions are damaged or missing (pyulog stopped at: "
                         f"{' '.join(str(exc).split()) or type(exc).__name__})") from None
    out = _ulog_messages(ulog)
    n_gyro = sum(m.topic == topics.GYRO for m in out)
    cut = ulog_truncated_at(path)
    damage = (f"it ends mid-message at byte {cut} of {os.path.getsize(path)} (truncated)"
              if cut is not None else "pyulog found it corrupt" if ulog.file_corruption
              else "")
    if not n_gyro:
        why = f": {damage}" if damage else " (no sensor_combined topic)"
        raise ValueError(f"--imu {path}: no gyro sample in the ULog{why}")
    if damage and problems is not None:
        last = max(m.t_s for m in out if m.topic == topics.GYRO)
        problems.append(f"--imu {path}: {damage}; {n_gyro} gyro samples read, up to "
                        f"t = {last:.6g} s")
    return out


def ulog_truncated_at(path: str | os.PathLike[str]) -> int | None:
    """Where a ULog's last message starts if the file ends inside it (None when every
    message is whole): the walk over the message headers the ULog format defines (16-byte
    file header, then per message a 2-byte size and a 1-byte type). pyulog drops such a
    message without a word.

    >>> import tempfile, os
    >>> p = os.path.join(tempfile.mkdtemp(), "x.ulg")
    >>> _ = open(p, "wb").write(b"ULog" + bytes(12) + bytes([5, 0, 66]) + b"ab")
    >>> ulog_truncated_at(p)
    16
    """
    import struct

    with open(path, "rb") as f:
        data = f.read()
    k = 16
    while k + 3 <= len(data):
        (size,) = struct.unpack_from("<H", data, k)
        if k + 3 + size > len(data):
            return k
        k += 3 + size
    return k if k < len(data) else None


def _ulog_messages(ulog) -> list[Message]:
    """The gyro and magnetometer messages of a parsed ULog, in time order."""
    out: list[Message] = []
    for d in ulog.data_list:
        f = d.data
        if d.name == "sensor_combined":
            for k in range(len(f["timestamp"])):
                out.append(Message(float(f["timestamp"][k]) / 1e6, topics.GYRO, {"omega": [
                    float(f[f"gyro_rad[{i}]"][k]) for i in range(3)]}))
        elif d.name in ("vehicle_magnetometer", "sensor_mag"):
            key = "magnetometer_ga" if "magnetometer_ga[0]" in f else None
            for k in range(len(f["timestamp"])):
                b = ([float(f[f"{key}[{i}]"][k]) for i in range(3)] if key else
                     [float(f[a][k]) for a in ("x", "y", "z")])
                out.append(Message(float(f["timestamp"][k]) / 1e6, topics.MAG,
                                   {"b_body": [1e5 * v for v in b]}))
    out.sort(key=lambda m: m.t_s)
    return out


class _FramesInput:
    """Shared parts of the inputs that hold only frames (plus an optional IMU file)."""

    name: str
    config: dict[str, Any]
    has_images = True
    start_utc: str | None = None

    def camera_model(self) -> dict[str, Any] | None:
        return None

    def image_size(self) -> tuple[int, int] | None:
        return self._size

    @property
    def problem(self) -> str | None:
        return "; ".join(self._source.problems) or None

    @property
    def has_gyro(self) -> bool:
        return self.imu is not None

    def preflight(self) -> None:
        """Read the IMU file and check its clock against the frames' before the replay
        (:func:`check_clocks`): a usage error when they cannot be one clock, a problem
        (counted in the output) when the IMU covers only part of the frames."""
        if getattr(self, "_sensors", None) is None:
            self._sensors = _sensors(self.imu, self._source.problems)
            t = self._frame_span()
            if self._sensors and t is not None:
                shift = getattr(self, "imu_offset_s", 0.0)  # --imu-offset, applied later
                note = check_clocks([m.t_s + shift for m in self._sensors
                                     if m.topic == topics.GYRO], t, f"--imu {self.imu}")
                if note:
                    self._source.problems.append(note)

    def _frame_span(self) -> tuple[float, float, float] | None:
        """The frames' first and last time and their median interval (s), if known."""
        src = self._source
        times = getattr(src, "times", None)
        if times is not None and len(times):
            t = np.sort(np.asarray(times, dtype=np.float64))
            steps = np.diff(t)
            steps = steps[steps > 0]
            return float(t[0]), float(t[-1]), float(np.median(steps)) if len(steps) else 0.0
        n = getattr(src, "frame_count", 0)
        if n > 0 and getattr(src, "fps", 0):
            return float(src.t0_s), float(src.t0_s + (n - 1) / src.fps), 1.0 / src.fps
        return None

    def __iter__(self) -> Iterator[Message]:
        self.preflight()
        sensors, self._sensors = self._sensors, None
        return heapq.merge(sensors, _prefetch(self._source.frames()), key=lambda m: m.t_s)


def check_clocks(gyro_t_s: list[float], frames_s: tuple[float, float, float],
                 what: str) -> str:
    """Whether gyro times ``gyro_t_s`` and frames ``frames_s`` (first, last, median
    interval; s) can be one clock. Raises :class:`UsageError` when they cannot — a gyro
    whose samples come more than 30× slower than the frames, or 1000× faster (its times
    milliseconds or microseconds, or kiloseconds, given as seconds) — or no overlap at all
    (another clock's origin); returns a note (else "") when the gyro covers only part of
    the frames. A gyro log longer than the frames is fine.

    >>> check_clocks([0.0, 0.01, 0.02, 5.0], (0.0, 10.0, 0.1), "--imu imu.csv").split(": ")[1]
    "the gyro covers 0–5 s of the frames' 0–10 s (50 %)"
    >>> try:
    ...     check_clocks([0.0, 10.0, 20.0, 10000.0], (0.0, 10.0, 0.1), "--imu imu.csv")
    ... except UsageError as e:
    ...     print(str(e).split(": ")[1])
    the gyro's samples come every 10 s, 100× the frames' 0.1 s
    """
    if not gyro_t_s:
        return ""
    g = np.sort(np.asarray(gyro_t_s, dtype=np.float64))
    g0, g1 = float(g[0]), float(g[-1])
    f0, f1, frame_dt = frames_s
    span_f = f1 - f0
    steps = np.diff(g)
    steps = steps[steps > 0]
    if len(steps) and frame_dt > 0:
        gyro_dt = float(np.median(steps))
        ratio = gyro_dt / frame_dt
        unit = ("milliseconds" if ratio <= 3e3 else "microseconds") if ratio > 30 else (
            "kiloseconds (or the frames' milliseconds)" if ratio < 1e-3 / 3 else "")
        if unit:
            raise UsageError(f"{what}: the gyro's samples come every {gyro_dt:.3g} s, "
                             f"{ratio:.3g}× the frames' {frame_dt:.3g} s: are its times "
                             f"{unit}? Its times must be seconds on the frames' clock")
    overlap = min(g1, f1) - max(g0, f0)
    if overlap < 0 or (overlap == 0 and span_f > 0):
        raise UsageError(f"{what}: the gyro's times {g0:.6g}–{g1:.6g} s and the frames' "
                         f"{f0:.6g}–{f1:.6g} s do not overlap: put them on one clock "
                         "(--imu-offset S adds S s to the IMU's times; the frames' come "
                         "from --fps or --timestamps)")
    if span_f > 0 and overlap < span_f:
        return (f"{what}: the gyro covers {max(g0, f0):.6g}–{min(g1, f1):.6g} s of the "
                f"frames' {f0:.6g}–{f1:.6g} s ({100 * overlap / span_f:.0f} %): frames "
                "outside it are propagated without the gyro")
    return ""


class FolderInput(_FramesInput):
    """A folder of images (sorted by name: PNG, TIFF, JPEG, PGM, FITS …) with frame times
    from a ``timestamps`` CSV (``filename, t_s``) or a frame rate ``fps``, and an optional
    ``imu`` file (CSV as :func:`adfusion.logs.read_sensor_csv` defines, or a PX4 ULog)."""

    def __init__(self, folder: str | os.PathLike[str], *, fps: float | None = None,
                 timestamps: str | os.PathLike[str] | None = None,
                 imu: str | os.PathLike[str] | None = None) -> None:
        self.name = str(folder)
        if fps is not None and not fps > 0:
            raise UsageError(f"--fps {fps}: a frame rate must be positive")
        if timestamps is not None and not os.path.exists(timestamps):
            raise FileNotFoundError(f"--timestamps {timestamps}: no such file")
        try:
            self._source = ImageFolderSource(folder, fps=fps, timestamps_csv=timestamps)
        except KeyError as e:
            raise ValueError(f"--timestamps {timestamps}: no {e} column (need filename,t_s)") \
                from None
        except ValueError as e:  # name the flag that gave the file
            if timestamps is None and not fps and "frame times unknown" in str(e):
                raise UsageError(str(e).replace("give fps or a timestamps CSV",
                                                "give --fps HZ or --timestamps CSV (columns "
                                                "filename,t_s)")) from None
            if timestamps is None or str(e).startswith("--"):
                raise
            raise ValueError(f"--timestamps {e}") from None
        if not self._source.names:
            raise ValueError(f"{folder}: no images (.png, .tif, .jpg, .pgm, ...) in the folder")
        self.imu = imu
        self.config = {}
        #: the UTC of t = 0 from the file names, when they give the frames' times
        self.start_utc = self._source.start_utc
        # the size from the first frame whose header reads (nothing decoded; a frame that
        # cannot be read is dropped and counted when it is read, with the others); a
        # folder where no file has an image header is no frame folder
        self._size = _first_frame_size(Path(folder), self._source.names)

    @property
    def problems(self) -> list[str]:
        """The folder's damage, then how many frame files were dropped unread (the first
        reason: truncated, over the pixel cap, not decodable)."""
        lines = list(self._source.problems)
        dropped = self._source.unreadable
        if dropped:
            lines.append(f"{len(dropped)} of {len(self._source.names)} frame file(s) "
                         f"dropped unread (first: {dropped[0]})")
        return lines



def _first_frame_size(folder: Path, names: list[str]) -> tuple[int, int]:
    """``(width, height)`` of the first of ``names`` whose header reads; the first file's
    error, with how many others failed, when none does."""
    first: Exception | None = None
    for name in names:
        try:
            return frame_size(folder / name)
        except (ImageFileError, OSError) as exc:  # not an image, cut, a dangling link
            first = first or exc
    others = f" (nor any of the other {len(names) - 1} file(s))" if len(names) > 1 else ""
    if isinstance(first, OSError) and not isinstance(first, ImageFileError):
        first = ImageFileError(f"{folder / names[0]}: {first.strerror or first}")
    raise ImageFileError(f"{first}{others}") from None


class VideoInput(_FramesInput):
    """A video file (anything OpenCV opens) at ``fps`` (default: the container's rate), with
    an optional ``imu`` file as :class:`FolderInput`."""

    def __init__(self, path: str | os.PathLike[str], *, fps: float | None = None,
                 imu: str | os.PathLike[str] | None = None) -> None:
        self.name = str(path)
        if fps is not None and not fps > 0:
            raise UsageError(f"--fps {fps}: a frame rate must be positive")
        if Path(path).suffix.lower() in IMAGE_SUFFIXES:
            # one frame file, read by OpenCV's video reader: its header first, so a file
            # that is no image is said as such (OpenCV opens it with a size of 0)
            frame_size(path)
        try:
            self._source = VideoSource(path, fps=fps)
        except ValueError as e:
            if "frame rate" in str(e):
                raise UsageError(f"{path}: no frame rate in the container: give --fps HZ") \
                    from None
            raise
        self.imu = imu
        self.config = {}
        cap = cv2.VideoCapture(os.fspath(path))
        self._size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
                      int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        cap.release()
        if min(self._size) <= 0:
            raise ValueError(f"{path}: OpenCV opens it but finds no frame size: not a video "
                             "it can read (a folder of frames, an MCAP log or a ROS 2 bag "
                             "are the other inputs)")



def _prefetch(frames: Iterator[Message], depth: int = 16) -> Iterator[Message]:
    """Decode frames in a thread, ``depth`` ahead (OpenCV's decoders release the GIL); 16
    rather than 4 kept the decoder from starving the detection look-ahead when another
    process took its core (folder replay +4 % alone, +10 % with the look-ahead at 16)."""
    import queue
    import threading

    q: queue.Queue = queue.Queue(depth)
    end = object()
    stop = threading.Event()

    def fill() -> None:
        try:
            for m in frames:
                while not stop.is_set():
                    try:
                        q.put(m, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
        except BaseException as e:  # raised again in the reader
            q.put(e)
        q.put(end)

    thread = threading.Thread(target=fill, daemon=True, name="frame-decode")
    thread.start()
    try:
        while (m := q.get()) is not end:
            if isinstance(m, BaseException):
                raise m
            yield m
    finally:
        stop.set()


ROS_IMAGE = ("sensor_msgs/msg/Image", "sensor_msgs/Image")
ROS_COMPRESSED = ("sensor_msgs/msg/CompressedImage", "sensor_msgs/CompressedImage")
ROS_IMU = ("sensor_msgs/msg/Imu", "sensor_msgs/Imu")
ROS_MAG = ("sensor_msgs/msg/MagneticField", "sensor_msgs/MagneticField")
ROS_INFO = ("sensor_msgs/msg/CameraInfo", "sensor_msgs/CameraInfo")
_ROS_ENCODINGS = {"mono8": np.uint8, "8UC1": np.uint8, "mono16": np.uint16, "16UC1": np.uint16,
                  "rgb8": np.uint8, "bgr8": np.uint8, "rgba8": np.uint8, "bgra8": np.uint8}


def is_ros2_bag(path: str | os.PathLike[str]) -> bool:
    """A rosbag2 folder (``metadata.yaml`` + ``.mcap``), or an MCAP file of ``ros2msg``
    schemas (CDR messages)."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").exists() and any(p.glob("*.mcap"))
    if p.suffix.lower() != ".mcap":
        return False
    try:
        reader = McapLogReader(p, warn=False)
    except Exception:
        return False
    return any(c.message_encoding == "cdr" for c in reader.channels.values())


class Ros2BagInput:
    """A ROS 2 bag in MCAP (a rosbag2 folder or its ``.mcap``), decoded with
    ``mcap-ros2-support``: ``sensor_msgs/Image`` or ``CompressedImage`` frames, ``Imu``
    (``angular_velocity``, rad/s, body), ``MagneticField`` (tesla → nT, body) and
    ``CameraInfo`` (the camera model). Topics are found by type, or named with
    ``image_topic`` / ``imu_topic`` / ``mag_topic``. Times are the messages' header stamps
    (the log time where a stamp is zero), as run seconds from the first message, whose
    UTC time becomes the run's ``start_utc``."""

    def __init__(self, path: str | os.PathLike[str], *, image_topic: str | None = None,
                 imu_topic: str | None = None, mag_topic: str | None = None,
                 imu: str | os.PathLike[str] | None = None) -> None:
        p = Path(path)
        if p.is_dir():
            files = sorted(p.glob("*.mcap"))
            if not files:
                raise ValueError(f"{path}: a rosbag2 folder without an .mcap file (only the "
                                 "MCAP storage is read; convert with 'ros2 bag convert')")
            p = files[0]
        self.name, self.path = str(path), p
        self.imu = imu
        self.config: dict[str, Any] = {}
        self.has_images = True
        self._problems: list[str] = []
        from mcap.reader import make_reader

        with open(p, "rb") as f:
            summary = make_reader(f).get_summary()
        if summary is None:
            raise ValueError(f"{path}: no MCAP summary (a bag still being recorded?)")
        by_type: dict[str, list[str]] = {}
        for ch in summary.channels.values():
            schema = summary.schemas.get(ch.schema_id)
            by_type.setdefault(schema.name if schema else "", []).append(ch.topic)

        def pick(names: tuple[str, ...], given: str | None, flag: str) -> str | None:
            if given is not None:
                if not any(given in by_type.get(n, []) for n in names + tuple(by_type)):
                    raise UsageError(f"{path}: no topic {given!r} ({flag}); topics: "
                                     f"{sorted(t for ts in by_type.values() for t in ts)}")
                return given
            found = [t for n in names for t in by_type.get(n, [])]
            if len(found) > 1:
                raise ValueError(f"{path}: several {names[0]} topics {found}: choose one "
                                 f"with {flag}")
            return found[0] if found else None

        self.image_topic = (pick(ROS_IMAGE, image_topic, "--image-topic")
                            or pick(ROS_COMPRESSED, None, "--image-topic"))
        if self.image_topic is None:
            raise ValueError(f"{path}: no sensor_msgs/Image or CompressedImage topic")
        self.imu_topic = pick(ROS_IMU, imu_topic, "--imu-topic")
        self.mag_topic = pick(ROS_MAG, mag_topic, "--mag-topic")
        self.has_gyro = self.imu_topic is not None or imu is not None
        self.info_topic = pick(ROS_INFO, None, "--camera")
        self._t0_ns: int | None = None
        self._model: dict[str, Any] | None = None
        self._size: tuple[int, int] | None = None
        for topic, msg, _t_ns in self._decoded([self.image_topic] + (
                [self.info_topic] if self.info_topic else []), limit=2):
            if topic == self.info_topic and self._model is None and len(msg.k) == 9:
                self._model = {"model": "pinhole", "width": int(msg.width),
                               "height": int(msg.height),
                               "K": np.asarray(msg.k, float).reshape(3, 3).tolist(),
                               "D": [float(x) for x in msg.d][:5] or [0.0] * 5, "parity": 1}
            elif topic == self.image_topic and self._size is None:
                img = self._image(msg)
                self._size = (int(img.shape[1]), int(img.shape[0]))
        self._t0_ns = min((self._first_ns(t) for t in (self.image_topic, self.imu_topic,
                                                       self.mag_topic) if t), default=0)
        from adfusion.logs.writer import utc_iso

        self.start_utc = utc_iso(_ns_datetime(self._t0_ns))

    def _decoded(self, topics_: list[str], limit: int | None = None):
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        seen: dict[str, int] = {}
        with open(self.path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _, channel, message, msg in reader.iter_decoded_messages(topics=topics_):
                if limit is not None:
                    seen[channel.topic] = seen.get(channel.topic, 0) + 1
                    if seen[channel.topic] > limit:
                        if all(seen.get(t, 0) > limit for t in topics_):
                            return
                        continue
                yield channel.topic, msg, message.log_time

    def _first_ns(self, topic: str) -> int:
        for _, msg, t_ns in self._decoded([topic], limit=1):
            return _stamp_ns(msg, t_ns)
        return 2**63

    def camera_model(self) -> dict[str, Any] | None:
        return self._model

    def image_size(self) -> tuple[int, int] | None:
        return self._size

    @staticmethod
    def _image(msg) -> np.ndarray:
        if hasattr(msg, "encoding"):  # sensor_msgs/Image
            dtype = _ROS_ENCODINGS.get(msg.encoding)
            if dtype is None:
                raise ValueError(f"image encoding {msg.encoding!r} is not read (mono8, "
                                 "mono16, rgb8, bgr8)")
            data = np.frombuffer(bytes(msg.data), dtype=np.dtype(dtype).newbyteorder(
                ">" if msg.is_bigendian else "<"))
            row = msg.step // np.dtype(dtype).itemsize
            img = data.reshape(msg.height, row)[:, : msg.width * max(1, row // msg.width)]
            channels = row // msg.width if msg.width else 1
            if channels > 1:
                img = img.reshape(msg.height, msg.width, channels)[..., :3]
                code = cv2.COLOR_RGB2GRAY if msg.encoding.startswith("rgb") else \
                    cv2.COLOR_BGR2GRAY
                return cv2.cvtColor(np.ascontiguousarray(img), code)
            return np.ascontiguousarray(img[:, : msg.width].astype(dtype, copy=False))
        return decode_frame_bytes(bytes(msg.data), f"a {msg.format!r} CompressedImage")

    def __iter__(self) -> Iterator[Message]:
        wanted = [t for t in (self.image_topic, self.imu_topic, self.mag_topic) if t]
        sensors = _sensors(self.imu, self._problems)
        return heapq.merge(sensors, self._messages(wanted), key=lambda m: m.t_s)

    def _messages(self, wanted: list[str]) -> Iterator[Message]:
        t0 = self._t0_ns
        out = []
        for topic, msg, t_ns in self._decoded(wanted):
            t_s = (_stamp_ns(msg, t_ns) - t0) / 1e9
            if topic == self.image_topic:
                out.append(Message(t_s, topics.CAMERA_IMAGE, self._image(msg)))
            elif topic == self.imu_topic:
                w = msg.angular_velocity
                out.append(Message(t_s, topics.GYRO, {"omega": [w.x, w.y, w.z]}))
            else:
                b = msg.magnetic_field
                out.append(Message(t_s, topics.MAG, {"b_body": [1e9 * b.x, 1e9 * b.y,
                                                                1e9 * b.z]}))
            if len(out) >= 64:  # keep time order when stamps and log times disagree a little
                out.sort(key=lambda m: m.t_s)
                yield from out[:32]
                out = out[32:]
        out.sort(key=lambda m: m.t_s)
        yield from out

    @property
    def problem(self) -> str | None:
        return "; ".join(self._problems) or None


def _stamp_ns(msg, log_time_ns: int) -> int:
    stamp = getattr(getattr(msg, "header", None), "stamp", None)
    if stamp is None:
        return log_time_ns
    ns = int(stamp.sec) * 10**9 + int(stamp.nanosec)
    return ns if ns > 0 else log_time_ns


def _ns_datetime(ns: int):
    import datetime as dt

    return dt.datetime(1970, 1, 1, tzinfo=dt.UTC) + dt.timedelta(microseconds=ns // 1000)


VIDEO_SUFFIXES = (".avi", ".mp4", ".mkv", ".mov", ".mpg", ".mpeg", ".m4v", ".webm", ".wmv")


def input_files(path: str | os.PathLike[str]) -> list[Path]:
    """The files a replay of ``path`` reads (besides ``--imu``, ``--camera`` …): the file
    itself, or those of a folder — every file of a rosbag2 folder, the images of a frame
    folder — for the output guard (:func:`adfusion.outfiles.refuse_overwrite`).

    >>> input_files("flight.mcap")
    [PosixPath('flight.mcap')]
    """
    p = Path(path)
    if not p.is_dir():
        return [p]
    return files_in([p], None if is_ros2_bag(p) else IMAGE_SUFFIXES)


def open_input(path: str | os.PathLike[str], *, fps: float | None = None,
               timestamps: str | os.PathLike[str] | None = None,
               imu: str | os.PathLike[str] | None = None,
               image_topic: str | None = None, imu_topic: str | None = None,
               mag_topic: str | None = None) -> Source:
    """The source for ``path``: a folder of images (or a rosbag2 folder), a ROS 2 bag in
    MCAP, one of our MCAP logs, or a video file — with one-line errors naming the flag
    that supplies what is missing."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    if imu is not None and not os.path.exists(imu):  # before any complaint about config
        raise FileNotFoundError(f"--imu {imu}: no such file")
    if p.is_dir():
        if is_ros2_bag(p):
            return Ros2BagInput(p, image_topic=image_topic, imu_topic=imu_topic,
                                mag_topic=mag_topic, imu=imu)
        return FolderInput(p, fps=fps, timestamps=timestamps, imu=imu)
    if p.suffix.lower() == ".mcap":
        if is_ros2_bag(p):
            return Ros2BagInput(p, image_topic=image_topic, imu_topic=imu_topic,
                                mag_topic=mag_topic, imu=imu)
        if imu is not None:
            raise UsageError(f"--imu {imu}: {path} is a log of ours, which holds its sensors")
        return McapInput(p)
    what = (f"{path}: not an MCAP file, a ROS 2 bag, a folder of images or a video file "
            "OpenCV can open")
    with open(p, "rb") as f:
        if f.read(8) == b"\x89MCAP0\r\n":  # an MCAP log under another name
            return McapInput(p)
    if p.suffix.lower() in VIDEO_SUFFIXES:
        return VideoInput(p, fps=fps, imu=imu)
    if p.suffix.lower() in (".csv", ".json", ".yaml", ".yml", ".txt"):
        raise ValueError(what)
    try:  # an unusual suffix: a video if OpenCV can open it
        return VideoInput(p, fps=fps, imu=imu)
    except ValueError:
        raise ValueError(what) from None
