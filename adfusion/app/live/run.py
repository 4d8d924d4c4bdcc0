"""``adfusion live``: frames solved as they arrive — detection, identification and the
filter of a replay (:func:`adfusion.app.replay.run.run`), fed by a live source, recorded to
MCAP and published on a Foxglove WebSocket as they are written.

Example (a folder that another program fills; here the frames are already there)::

    >>> import os, tempfile
    >>> from adfusion.app.live import LiveOptions, live
    >>> out = os.path.join(tempfile.mkdtemp(), "live.mcap")
    >>> s = live("frames/", out, LiveOptions(fov="11.4", idle_s=5))  # doctest: +SKIP
    >>> s.live["frames_taken"], s.live["latency_ms"]["median"]  # doctest: +SKIP
    (12, 14.2)
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from adfusion.app.live.feeds import LiveClock, PacedFeed, frame_feed, imu_feed
from adfusion.app.live.source import LiveSource
from adfusion.app.replay.run import ReplayOptions, run
from adfusion.app.replay.sinks import LayoutSink, LogSink, ReplaySummary, SummarySink
from adfusion.app.replay.stages import FRAME, DetectAhead, Step
from adfusion.logs import topics

__all__ = ["LiveOptions", "LiveSink", "live"]


@dataclass
class LiveOptions:
    """How a live run gets its frames and when it ends.

    ``realtime``: SOURCE is a recording (a log, a folder with its times, a video) handed on
    at its recorded pace × ``speed``; ``imu``: a growing CSV file or ``udp://HOST:PORT``
    (``--realtime``: the recording's own, or an IMU file as ``replay --imu``);
    ``include_existing``: a folder's files already there are solved too; ``max_frames``,
    ``duration_s``, ``idle_s`` (no new frame for so long) end the run, as does Ctrl-C or
    the source's end; ``view``: ``(host, port)`` of the Foxglove server, ``None`` for none;
    ``input_args``: ``open_input``'s (``fps``, ``timestamps``) for a recording."""

    realtime: bool = False
    speed: float = 1.0
    imu: str | None = None
    include_existing: bool = False
    max_frames: int | None = None
    duration_s: float | None = None
    idle_s: float | None = None
    view: tuple[str, int] | None = ("127.0.0.1", 8765)
    input_args: dict[str, Any] | None = None


class _Inline(DetectAhead):
    """Detection in the run's own thread, on each frame as it comes: a worker running
    frames ahead would hold each one back until the next arrived."""

    def start(self) -> None:
        pass


#: what a frame of a single-camera run writes (:class:`LogSink`), by topic and schema
_FRAME_TOPICS = ((topics.CAMERA_IMAGE, "foxglove.RawImage"),
                 (topics.CAMERA_ANNOTATIONS, "foxglove.ImageAnnotations"),
                 (topics.STARID_SOLUTION, "json"), (topics.ESTIMATE_STATE, "json"),
                 (topics.ESTIMATE_ATTITUDE, "json"), (topics.ESTIMATE_POSE, "foxglove.PoseInFrame"),
                 (topics.TF, "foxglove.FrameTransforms"), (topics.LIVE_STATUS, "json"))


#: how often the camera model is published again (s): Foxglove draws the annotations
#: with it, and a viewer that connected late would never get the one of the start
CALIBRATION_EVERY_S = 5.0


class LiveSink:
    """The live record: after each frame, ``/live/status`` (its latency from arrival to the
    estimate written and published, frames solved and dropped so far); at the end, the
    ``live`` metadata (what arrived, was dropped and taken, the latency's median, p95 and
    maximum, why the run ended). Given after the :class:`LogSink`, so a frame's estimate is
    out before its latency is taken."""

    def __init__(self, log: LogSink, source: LiveSource) -> None:
        self.log = log
        self.source = source
        self.latency_ms: list[float] = []
        self.record: dict[str, Any] = {}

    def open(self, run: Any) -> None:
        # every topic of a frame declared now: a client that connects before the first
        # frame subscribes to them all, and misses none of the first messages
        imu = ((topics.GYRO, "json"), (topics.MAG, "json")) if self.source.has_gyro else ()
        for topic, kind in (*_FRAME_TOPICS, *imu):
            self.log.log.declare(topic, kind)
        self.camera = run.camera
        self._calibration_t = 0.0

    def take(self, step: Step) -> None:
        if step.kind != FRAME:
            return
        src = self.source
        arrived = src.arrivals.pop(step.msg.t_s, None)
        if arrived is None:
            return
        ms = (time.perf_counter() - arrived) * 1e3
        if src.ready_perf is not None and arrived >= src.ready_perf:
            self.latency_ms.append(ms)  # a frame that waited for the setup is not the pace
        self.log.log.write_json(topics.LIVE_STATUS, step.msg.t_s, {
            "t": step.msg.t_s, "latency_ms": ms, "frames": src.taken, "dropped": src.dropped})
        if step.msg.t_s - self._calibration_t >= CALIBRATION_EVERY_S and step.head == 0:
            # the camera model again: a viewer that connected after the start has none
            self._calibration_t = step.msg.t_s
            cam = self.camera
            self.log.log.write_calibration(step.msg.t_s, cam.width, cam.height, cam.K, cam.D,
                                           "camera")

    def _record(self) -> dict[str, Any]:
        src = self.source
        lat = np.asarray(self.latency_ms)
        stats = ({"median": float(np.median(lat)), "p95": float(np.percentile(lat, 95)),
                  "max": float(lat.max())} if lat.size else {})
        self.record = {"source": src.name, "frames_arrived": src.arrived,
                       "frames_dropped": src.dropped,
                       "frames_dropped_before_ready": src.dropped_before_ready,
                       "frames_dropped_at_end": src.dropped_at_end,
                       "frames_taken": src.taken,
                       "latency_ms": stats, "ended_by": src.ended_by or "a failure"}
        return self.record

    def close(self) -> None:
        self.log.log.add_metadata("live", self._record())

    def abort(self, reason: str) -> None:
        try:
            self.close()
        except Exception:  # the run's own failure is the one to raise
            pass


class _LiveLayout(LayoutSink):
    """The layout beside the output from the start (the live view needs it now), with the
    latency plot; removed again when the run fails, as a replay leaves none beside an
    incomplete output."""

    def open(self, run: Any) -> None:
        self.write()

    def close(self) -> None:
        pass

    def abort(self, reason: str) -> None:
        Path(self.path).unlink(missing_ok=True)


class _Stop:
    """Ctrl-C (and SIGTERM) end the run as its source's end does: the output complete. A
    second Ctrl-C interrupts as usual (the output then marked incomplete) — except once the
    frames have ended and the output is being finished (:meth:`finishing`): an interrupt
    there could cut the log's closing and lose it all, so it is said and ignored."""

    def __init__(self, stop: threading.Event) -> None:
        self.stop = stop
        self.old: dict[int, Any] = {}
        self.closing = False

    def finishing(self) -> None:
        self.closing = True

    def _handle(self, signum: int, frame: Any) -> None:
        if self.closing:
            print("adfusion live: finishing the output, a moment", file=sys.stderr)
            return
        if self.stop.is_set() and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.stop.set()

    def __enter__(self) -> _Stop:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc: Any) -> None:
        for sig, old in self.old.items():
            signal.signal(sig, old)


def live(source: str, out_path: str | Path, options: LiveOptions | None = None,
         replay_options: ReplayOptions | None = None, *,
         say: Callable[[str], None] | None = None) -> ReplaySummary:
    """Solve the frames of ``source`` as they arrive into ``out_path`` (MCAP, with
    ``OUT.layout.json`` beside it): a folder being filled, a camera (index, URL, GStreamer
    pipeline) or, with ``options.realtime``, a recording at its pace. ``replay_options``
    are a replay's (camera or field of view, mounting, noise). ``say`` gets the lines a
    person at the console wants (where to connect, what is watched).

    Returns the replay's summary with :attr:`live` set (the ``live`` metadata record)."""
    from adfusion.app.replay.sources import input_files, open_input
    from adfusion.outfiles import refuse_overwrite

    options = options or LiveOptions()
    replay_options = replay_options or ReplayOptions()
    say = say or (lambda text: None)
    layout_path = LayoutSink.path_for(out_path)
    inputs = [source, *input_files(source)] if Path(source).exists() else []
    refuse_overwrite([("-o", out_path), ("the layout", layout_path)],
                     inputs + ([options.imu] if options.imu and Path(options.imu).exists()
                               else []))
    clock = LiveClock()
    stop = threading.Event()
    inner = None
    src = LiveSource(clock, name=str(source), max_frames=options.max_frames,
                     duration_s=options.duration_s, idle_s=options.idle_s, stop=stop)
    view = None
    summary = ReplaySummary()
    guard = _Stop(stop)
    try:  # every feed made is closed again, whatever fails after it
        if options.realtime:
            args = dict(options.input_args or {})
            if options.imu:
                args["imu"] = options.imu
            inner = open_input(source, **args)
            if hasattr(inner, "preflight"):
                inner.preflight()
            src.use_recording(inner)
            src.frame_feed = PacedFeed(inner, options.speed)
        else:
            src.frame_feed = frame_feed(source, include_existing=options.include_existing)
            src.imu_feed = imu_feed(options.imu) if options.imu else None
        src.size_not_needed = replay_options.camera is not None
        if not src.has_gyro and replay_options.use_gyro:
            replay_options.use_gyro = False  # frames alone: the filter estimates the rate
        if options.view is not None:
            from adfusion.app.live.view import FoxgloveView

            view = FoxgloveView(*options.view)
            say(f"live view: {view.url} (Foxglove: Open connection → Foxglove WebSocket; "
                f"layout: {layout_path})")
        existing = getattr(src.frame_feed, "existing", 0)
        say((f"playing {source} at {options.speed:g}× its recorded pace" if options.realtime
             else f"watching {source}")
            + (f" (its {existing} file(s) already there left alone: --include-existing "
               "solves them)" if existing else "")
            + ("; the setup waits for the first frame (its size is the camera's: --camera "
               "FILE is ready before it)" if not (options.realtime or src.size_not_needed)
               else "") + "; Ctrl-C ends the run")
        log = LogSink(out_path, "none", tee=view)
        sink = LiveSink(log, src)
        sinks = [_LiveLayout(out_path, live=True), log, sink,
                 SummarySink(summary, t_start=clock.p0)]

        def ready() -> None:
            if options.realtime:  # a recording waits for the solver: nothing is lost to it
                src.start()
            say("ready: frames are solved as they arrive")

        src.on_ready = ready
        src.on_end = guard.finishing  # a second Ctrl-C must not cut the output's closing
        with guard:
            if not options.realtime:  # frames land whether we are ready or not
                src.start()
            run(src, sinks, replay_options, progress=False, ahead=_Inline())
        summary.live = sink.record
    finally:
        src.close()
        if view is not None:
            view.close()
    summary.wall_s = clock.now()
    return summary
