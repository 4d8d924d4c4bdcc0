"""A live input as a replay :class:`~adfusion.app.replay.sources.Source`: frames and IMU
samples handed over by feeds (:mod:`adfusion.app.live.feeds`) as they arrive, read by the
replay's pipeline as fast as it can.

Frames are never queued without bound: one slot holds the newest frame not yet taken, and
a frame that arrives while the slot is full replaces the older one, which is dropped and
counted (:attr:`LiveSource.dropped`) — the attitude of *now* is what a live user wants, not a
backlog. IMU samples are small and all kept, handed on in time order: those up to a frame's
time before it, the others once :data:`IMU_HOLD_S` old (a frame can arrive a little after
the samples of its moment).

Example:
    >>> import numpy as np
    >>> from adfusion.app.live.feeds import LiveClock
    >>> src = LiveSource(LiveClock(), max_frames=1)
    >>> src.offer_frame(0.1, np.zeros((4, 4), np.uint8), 0.0)
    >>> src.offer_frame(0.2, np.zeros((4, 4), np.uint8), 0.0)  # the solver was busy
    >>> [m.t_s for m in src], src.dropped
    ([0.2], 1)
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Iterator
from typing import Any

from adfusion.app.live.feeds import Feed, LiveClock
from adfusion.logs import Message, topics

__all__ = ["IMU_HOLD_S", "LiveSource"]

#: how long an IMU sample waits for a frame of an earlier time to arrive (s)
IMU_HOLD_S = 0.05


class LiveSource:
    """Frames and samples from ``feeds`` (started by :meth:`start`), until one of:
    ``stop`` is set (Ctrl-C), ``max_frames`` frames were taken, ``duration_s`` passed,
    no frame for ``idle_s``, or the frame feed ended (a stream that closed, a recording
    played to its end).

    ``inner`` is the recorded input of ``--realtime`` (its camera, configuration and start
    time are the run's); otherwise the run has no configuration and its start time is the
    clock's.
    """

    def __init__(self, clock: LiveClock, *, name: str = "live", inner: Any = None,
                 max_frames: int | None = None, duration_s: float | None = None,
                 idle_s: float | None = None, stop: threading.Event | None = None) -> None:
        self.clock = clock
        self.name = name
        self.inner = None
        self.config: dict[str, Any] = {}
        self.start_utc: str | None = clock.start_utc
        if inner is not None:
            self.use_recording(inner)
        self.max_frames = max_frames
        self.duration_s = duration_s
        self.idle_s = idle_s
        self.stop = stop or threading.Event()
        self.frame_feed: Feed | None = None
        self.imu_feed: Feed | None = None
        self._cond = threading.Condition()
        self._pending: dict[str, float] = {}  # frames seen, not yet read: their times
        self._slot: tuple[Message, float] | None = None
        self._imu: deque[Message] = deque()
        self._ended: list[str | None] = []  # the frame feed's end (its reason, or None)
        self._size: tuple[int, int] | None = None
        self._last_frame = time.perf_counter()
        #: frames that arrived, and of them dropped unsolved (the solver was busy)
        self.arrived = 0
        self.dropped = 0
        self.taken = 0
        self.feed_problems: list[str] = []
        #: arrival (``perf_counter``) of each frame handed on, by its time: the latency's start
        self.arrivals: dict[float, float] = {}
        self.ended_by = ""
        #: when the run was ready for frames (``perf_counter``; the solver built, its
        #: kernels loaded), and the frames dropped before: they waited for the setup
        self.ready_perf: float | None = None
        self.dropped_before_ready = 0
        self.on_ready = None  # called once, when the first frame is asked for
        self.on_end = None  # called once, when the frames have ended
        self.dropped_at_end = 0  # a frame still waiting when the run ended
        #: the camera is known (``--camera``): the setup does not wait for a first frame
        self.size_not_needed = False

    # ------------------------------------------------------------------ feeds side
    def use_recording(self, inner: Any) -> None:
        """A recording (``--realtime``) is the run's input: its camera, configuration and
        start time."""
        self.inner = inner
        self.config = dict(getattr(inner, "config", {}) or {})
        self.start_utc = getattr(inner, "start_utc", None)

    def start(self) -> None:
        """Start the feeds (:attr:`frame_feed`, and :attr:`imu_feed` when there is one)."""
        self.frame_feed.start(self)
        if self.imu_feed is not None:
            self.imu_feed.start(self)

    def frame_pending(self, key: str, t_s: float) -> None:
        """A frame of time ``t_s`` is being read (a file seen, not yet decoded): IMU samples
        after it wait for it, so the filter never meets its time going back."""
        with self._cond:
            self._pending[key] = t_s

    def frame_abandoned(self, key: str) -> None:
        with self._cond:
            self._pending.pop(key, None)
            self._cond.notify_all()

    def offer_frame(self, t_s: float, image: Any, arrived_perf: float, name: str = "") -> None:
        """A frame (an image array, or a recorded :class:`Message`) that arrived at
        ``arrived_perf``; replaces a frame not yet taken (counted as dropped)."""
        msg = image if isinstance(image, Message) else Message(t_s, topics.CAMERA_IMAGE, image)
        with self._cond:
            self._pending.pop(name, None)
            if self.ended_by:  # after the end: not the run's
                return
            self.arrived += 1
            if self._slot is not None:
                self.dropped += 1
            self._slot = (msg, arrived_perf)
            if self._size is None and hasattr(msg.payload, "shape"):
                self._size = (int(msg.payload.shape[1]), int(msg.payload.shape[0]))
            self._last_frame = time.perf_counter()
            self._cond.notify_all()

    def offer_other(self, msgs: list[Message]) -> None:
        """IMU samples (or a recording's other messages), in their order."""
        with self._cond:
            self._imu.extend(msgs)
            self._cond.notify_all()

    def feed_ended(self, feed: Feed, reason: str | None) -> None:
        with self._cond:
            if reason:
                self.feed_problems.append(reason)
            if feed is self.frame_feed:
                self._ended.append(reason)
            self._cond.notify_all()

    def close(self) -> None:
        """Stop the feeds and release what they hold (a camera, a socket), started or not."""
        self.stop.set()
        for feed in (self.frame_feed, self.imu_feed):
            if feed is not None:
                feed.close()

    # ------------------------------------------------------------------ Source side
    def camera_model(self) -> dict[str, Any] | None:
        return None if self.inner is None else self.inner.camera_model()

    def camera_models(self) -> list:
        return self.inner.camera_models()

    @property
    def has_images(self) -> bool:
        """Frames as images (a recording of centroids says so: their accuracy is its own)."""
        return bool(getattr(self.inner, "has_images", True))

    @property
    def has_gyro(self) -> bool:
        if self.inner is not None:  # a recording: as a replay reads it
            return bool(getattr(self.inner, "has_gyro", True))
        return self.imu_feed is not None

    @property
    def has_mag(self) -> bool:
        if self.inner is not None:
            return bool(getattr(self.inner, "has_mag", True))
        return self.imu_feed is not None

    def image_size(self) -> tuple[int, int] | None:
        """The frames' size: the recording's, else the first frame's (waited for, unless
        :attr:`size_not_needed`)."""
        if self.inner is not None:
            return self.inner.image_size()
        if self.size_not_needed:  # a camera model given: each frame's size is checked
            return self._size
        with self._cond:
            while self._size is None and not self._ended and not self.stop.is_set():
                if self.duration_s is not None and self.clock.now() >= self.duration_s:
                    break  # (--idle counts once ready: a camera may start late)
                self._cond.wait(0.05)
            if self._size is None:
                why = ("stopped" if self.stop.is_set() else
                       (self._ended[0] or "the source ended") if self._ended else
                       f"no frame in {self.clock.now():.0f} s (--duration)")
                raise ValueError(f"{self.name}: {why} before the first frame arrived (its size "
                                 "is the camera's, with --fov)")
            return self._size

    @property
    def problem(self) -> str | None:
        lines = self.problems
        return lines[0] if lines else None

    @property
    def problems(self) -> list[str]:
        """What went wrong with the input (not the frames dropped by design: those are the
        ``live`` record's)."""
        out = list(self.feed_problems)
        inner = getattr(self.inner, "problems", None)
        if inner:
            out = list(inner) + out
        for feed in (self.frame_feed, self.imu_feed):
            bad = getattr(feed, "unreadable", None) or getattr(feed, "bad", None)
            if bad:
                what = "frame file(s) dropped unread" if feed is self.frame_feed else \
                    "IMU line(s) dropped"
                out.append(f"{len(bad)} {what} (first: {bad[0]})")
        return out

    def _idle(self) -> bool:
        return time.perf_counter() - self._last_frame > self.idle_s

    def _why_end(self) -> str:
        """Why the run ends now, or ``""``."""
        if self.stop.is_set():
            return "stopped"
        if self.max_frames is not None and self.taken >= self.max_frames:
            return f"{self.max_frames} frames"
        if self.duration_s is not None and self.clock.now() >= self.duration_s:
            return f"{self.duration_s:g} s"
        if self._slot is None and self.idle_s is not None and self._idle():
            return f"no frame for {self.idle_s:g} s"
        if self._slot is None and self._ended:
            return "the source ended" if self._ended[0] is None else self._ended[0]
        return ""

    def __iter__(self) -> Iterator[Message]:
        with self._cond:
            self.ready_perf = time.perf_counter()
            self.dropped_before_ready = self.dropped
            self._last_frame = max(self._last_frame, self.ready_perf)  # idle from now
        if self.on_ready is not None:
            self.on_ready()
        while True:
            out: list[Message] = []
            with self._cond:
                while True:
                    why = self._why_end()
                    if why:
                        self.ended_by = why
                        out = list(self._imu)  # the samples already here are the run's
                        self._imu.clear()
                        if self._slot is not None:  # arrived, never taken: dropped
                            self._slot = None
                            self.dropped += 1
                            self.dropped_at_end += 1
                        break
                    if self._slot is not None:
                        msg, arrived = self._slot
                        self._slot = None
                        while self._imu and self._imu[0].t_s <= msg.t_s:
                            out.append(self._imu.popleft())
                        out.append(msg)
                        self.taken += 1
                        self.arrivals[msg.t_s] = arrived
                        break
                    old = self.clock.now() - IMU_HOLD_S if self.inner is None else None
                    if old is not None and self._pending:  # a frame being read goes first
                        old = min(old, min(self._pending.values()))
                    while self._imu and (old is None or self._imu[0].t_s <= old):
                        out.append(self._imu.popleft())
                    if out:
                        break
                    self._cond.wait(0.02)
            out.sort(key=lambda m: m.t_s)
            yield from out
            if self.ended_by:
                if self.on_end is not None:
                    self.on_end()
                return
