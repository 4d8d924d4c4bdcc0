"""Replay stages: what happens to each message between its source and the sinks.

* :class:`DetectAhead` — star detection in a worker process, a few frames ahead (a stream
  stage: it passes the messages through and answers the estimator's detection calls);
* :class:`TruthStage` — carries the latest truth attitude to each frame (for scoring);
* :class:`EstimationStage` — identification (tracking, lost-in-space fallback) and the
  filter: the :class:`~adfusion.estimation.estimator.Estimator` steps on gyro, magnetometer
  and frame messages.

Each message becomes a :class:`Step` (its kind, whether the estimator used it, the
estimator's :class:`~adfusion.estimation.estimator.StepRecord` for frames), which every
sink then takes.

Example:
    >>> from adfusion.logs import Message
    >>> step = Step.of(Message(0.0, "/imu/gyro", {"omega": [0.0, 0.0, 0.1]}))
    >>> step.kind
    'gyro'
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from adfusion.estimation.estimator import Estimator, StepRecord
from adfusion.logs import Message, topics
from adfusion.maths import rotations as rot
from adfusion.plain import listed
from adfusion.starid.camera.model import Camera

__all__ = ["DetectAhead", "EstimationStage", "InputProblems", "Step", "TruthStage", "TruthTrack"]

GYRO, MAG, TRUTH, FRAME, OTHER = "gyro", "mag", "truth", "frame", "other"
_KINDS = {topics.GYRO: (GYRO, 0), topics.MAG: (MAG, 0), topics.TRUTH_STATE: (TRUTH, 0),
          **{topics.camera_topic(k, leaf): (FRAME, k) for k in range(topics.MAX_CAMERAS)
             for leaf in ("image", "centroids")}}
_OTHER = (OTHER, 0)


def is_frame(topic: str) -> bool:
    """Whether ``topic`` carries a camera's frames (images or centroids, any camera).

    >>> is_frame("/camera2/centroids"), is_frame("/imu/gyro")
    (True, False)
    """
    return _KINDS.get(topic, _OTHER)[0] == FRAME


@dataclass(slots=True)
class Step:
    """One message on its way through the stages.

    Attributes:
        msg: the input message.
        kind: ``"gyro"``, ``"mag"``, ``"truth"``, ``"frame"`` or ``"other"`` (not replayed).
        used: the estimator took it (sensors; frames always).
        record: what the estimator did with a frame.
        truth_q: the latest truth ``q_body_icrs`` at a frame, if the input has truth.
        head: the camera of a frame (0, or k for ``/camera{k}/...`` topics).
    """

    msg: Message
    kind: str
    used: bool = False
    record: StepRecord | None = None
    truth_q: np.ndarray | None = None
    head: int = 0

    @classmethod
    def of(cls, msg: Message) -> Step:
        kind, head = _KINDS.get(msg.topic, _OTHER)
        return cls(msg, kind, head=head)


@dataclass
class InputProblems:
    """Inputs a replay could not use, counted per kind with the first reason, so that a
    run that dropped whole inputs says so (summary, output log, ``report``).

    >>> p = InputProblems()
    >>> p.drop("gyro", "not a finite 3-vector: [nan, 0, 0]"); p.drop("gyro", "x")
    >>> p.lines()
    ['2 gyro message(s) dropped (first: not a finite 3-vector: [nan, 0, 0])']
    """

    dropped: dict[str, int] = field(default_factory=dict)
    first: dict[str, str] = field(default_factory=dict)
    seen: dict[str, int] = field(default_factory=dict)

    def saw(self, kind: str) -> None:
        self.seen[kind] = self.seen.get(kind, 0) + 1

    def drop(self, kind: str, reason: str) -> None:
        self.dropped[kind] = self.dropped.get(kind, 0) + 1
        self.first.setdefault(kind, reason)

    def lines(self) -> list[str]:
        out = []
        for kind, n in self.dropped.items():
            of = f" of {self.seen[kind]}" if self.seen.get(kind) else ""
            out.append(f"{n}{of} {kind} message(s) dropped (first: {self.first[kind]})")
        return out


def _field(payload: Any, key: str, topic: str) -> Any:
    """``payload[key]`` of a JSON message, or a :class:`ValueError` naming the topic."""
    if not isinstance(payload, dict):
        raise ValueError(f"{topic}: payload is a {type(payload).__name__}, not an object "
                         f"with {key!r}")
    if key not in payload:
        raise ValueError(f"{topic}: payload has no {key!r} (has "
                         f"{listed(sorted(map(str, payload)), 6)})")
    return payload[key]


class TruthTrack:
    """Truth attitudes by time; :meth:`at` interpolates (slerp) between the two samples
    around ``t``, so the score of an estimate does not depend on whether the truth of the
    same instant came before or after the frame in the file.

    >>> tr = TruthTrack()
    >>> tr.add(0.0, [1.0, 0.0, 0.0, 0.0]); tr.add(2.0, [0.0, 0.0, 0.0, 1.0])
    >>> [round(float(v), 6) for v in tr.at(1.0)]
    [0.707107, 0.0, 0.0, 0.707107]
    >>> tr.at(3.0) is None
    True
    """

    def __init__(self) -> None:
        self.t: list[float] = []
        self.q: list[np.ndarray] = []
        self._sorted = True

    def add(self, t: float, q: Any) -> None:
        if self.t and t < self.t[-1]:
            self._sorted = False
        self.t.append(float(t))
        self.q.append(rot.normalize(np.asarray(q, dtype=np.float64)))

    def __len__(self) -> int:
        return len(self.t)

    def at(self, t: float) -> np.ndarray | None:
        """The truth at ``t`` (``None`` outside the truth's time span)."""
        if not self._sorted:
            order = sorted(range(len(self.t)), key=self.t.__getitem__)
            self.t = [self.t[i] for i in order]
            self.q = [self.q[i] for i in order]
            self._sorted = True
        if not self.t or t < self.t[0] or t > self.t[-1]:
            return None
        i = bisect.bisect_left(self.t, t)
        if self.t[i] == t:
            return self.q[i]
        t0, t1 = self.t[i - 1], self.t[i]
        q0, q1 = self.q[i - 1], self.q[i]
        if float(np.dot(q0, q1)) < 0.0:
            q1 = -q1
        delta = rot.log_map(rot.multiply(q1, rot.inverse(q0)))
        return rot.canonical(rot.multiply(rot.exp_map(delta * (t - t0) / (t1 - t0)), q0))


class TruthStage:
    """Collects the ``/truth/state`` attitudes (:attr:`track`, for scoring at the
    estimates' times) and hands the latest to each frame (``step.truth_q``)."""

    def __init__(self, problems: InputProblems | None = None) -> None:
        self.q: np.ndarray | None = None
        self.track = TruthTrack()
        self.problems = problems if problems is not None else InputProblems()

    def __call__(self, step: Step) -> None:
        if step.kind == TRUTH:
            self.problems.saw(TRUTH)
            try:
                q = np.asarray(_field(step.msg.payload, "q_body_icrs", step.msg.topic),
                               dtype=np.float64)
                q = rot.normalize(q.reshape(4))
            except (ValueError, TypeError) as exc:
                self.problems.drop(TRUTH, str(exc))
                step.kind = OTHER
                return
            self.q = q
            self.track.add(step.msg.t_s, q)
        elif step.kind == FRAME:
            step.truth_q = self.q


class EstimationStage:
    """Feeds the estimator: gyro samples (unless ``use_gyro=False``), magnetometer samples
    that carry their ICRS reference (unless ``use_mag=False``), and every frame — an image
    (detected through the estimator's ``detect``) or centroids."""

    def __init__(self, estimator: Estimator, *, use_gyro: bool = True,
                 use_mag: bool = True, cameras: dict[int, int] | None = None,
                 problems: InputProblems | None = None,
                 sizes: dict[int, tuple[int, int]] | None = None) -> None:
        self.est = estimator
        self.use_gyro = use_gyro
        self.use_mag = use_mag
        self.cameras = cameras or {0: 0}  # the input's camera → the estimator's camera
        self.sizes = sizes or {}  # the estimator's camera → its (width, height)
        self.problems = problems if problems is not None else InputProblems()

    def _rejected(self, rec: StepRecord, source: str) -> str:
        return next((why for src, why in rec.rejected if src in (source, "time")), "")

    def __call__(self, step: Step) -> None:
        kind, msg = step.kind, step.msg
        if kind in (GYRO, MAG, FRAME):
            self.problems.saw(kind)
        try:
            if kind == GYRO:
                if self.use_gyro:
                    rec = self.est.step(msg.t_s, gyro=_field(msg.payload, "omega", msg.topic))
                    why = self._rejected(rec, "gyro")
                    if why:
                        self.problems.drop(GYRO, why)
                    step.used = not why
            elif kind == MAG:
                p = msg.payload
                if self.use_mag and isinstance(p, dict) and "b_ref_icrs" in p:
                    rec = self.est.step(msg.t_s, mag=(_field(p, "b_body", msg.topic),
                                                      p["b_ref_icrs"]))
                    why = next((w for src, w in rec.rejected if src == "mag" and
                                ("non-finite" in w or "expected" in w)), "")
                    if why:
                        self.problems.drop(MAG, why)
                    step.used = not why
                elif not isinstance(p, dict) or "b_body" not in p:
                    _field(p, "b_body", msg.topic)
            elif kind == FRAME:
                camera = self.cameras.get(step.head)
                if camera is None:  # a camera left out of this replay
                    step.kind = OTHER
                    return
                if isinstance(msg.payload, np.ndarray) or msg.topic.endswith("/image"):
                    image = msg.payload
                    self._check_image(image, msg.topic, self.sizes.get(camera))
                    step.record = self.est.step(msg.t_s, frame=image, camera=camera)
                else:
                    xy = np.asarray(_field(msg.payload, "xy", msg.topic), dtype=np.float64)
                    step.record = self.est.step(msg.t_s, detections=xy, camera=camera)
                why = self._rejected(step.record, "camera")
                if why:
                    self.problems.drop(FRAME, why)
                step.used = True
        except (ValueError, TypeError) as exc:  # a payload of another tool's making
            self.problems.drop(kind, str(exc))
            step.kind, step.used, step.record = OTHER, False, None

    @staticmethod
    def _check_image(image: Any, topic: str, size: tuple[int, int] | None) -> None:
        if not isinstance(image, np.ndarray):
            raise ValueError(f"{topic}: payload is a {type(image).__name__}, not an image")
        if image.ndim != 2:
            raise ValueError(f"{topic}: image of shape {image.shape}, not a grey frame")
        if size is not None and image.shape != (size[1], size[0]):
            raise ValueError(f"{topic}: frame of {image.shape[1]}×{image.shape[0]} px, but the "
                             f"camera model is {size[0]}×{size[1]}: a wrong camera model?")


class DetectAhead:
    """Star detection in a worker process (:class:`adfusion.app.detect_worker.DetectWorker`),
    ``depth`` frames ahead of the filter, on machines with two or more cores.

    :meth:`start` launches the worker (do it early: its interpreter takes ~0.5 s to import
    ``starid``, time the caller can spend loading the catalogue). :meth:`read` passes the
    messages through unchanged, ``depth`` frames behind the submissions; frames read before
    the worker is ready are not submitted but detected here when asked for, rather than
    waited for. The estimator calls the object in place of ``starid.detection.detect`` and gets the
    result computed for that very frame (errors raised there, as a direct call would).
    """

    def __init__(self, camera: Camera | None = None, depth: int = 16) -> None:
        # 16 rather than 8 frames ahead: measured +7–13 % frames/s at a load of 3 (a deeper
        # queue rides out the moments another process takes the worker's core); 4 MB of
        # shared frames at 512×480
        self.camera = camera
        self.cameras: dict[str, Camera] = {}  # image topic → its camera (several cameras)
        self.depth = depth
        self.detect_kwargs: dict = {}  # starid.detection.detect's settings (e.g. sigma)
        self._worker = None
        self._keys: dict[int, int] = {}
        self._submitted = 0

    def start(self) -> None:
        """Launch the worker now (on two or more cores; idempotent)."""
        import os

        from adfusion.app.detect_worker import DetectWorker

        if self._worker is None and (os.cpu_count() or 1) >= 2:
            self._worker = DetectWorker(slots=self.depth + 1)  # a slot for every frame ahead

    def close(self) -> None:
        """Stop the worker (idempotent)."""
        if self._worker is not None:
            self._worker.close()
            self._worker = None

    def read(self, messages):
        from collections import deque

        self.start()
        if self._worker is None:
            yield from messages
            return
        buf: deque = deque()
        frames = 0
        try:
            for msg in messages:
                buf.append(msg)
                camera = (self.cameras.get(msg.topic) if self.cameras else
                          self.camera if msg.topic == topics.CAMERA_IMAGE else None)
                if camera is not None:
                    if self._worker.ready():
                        key = self._submitted
                        self._submitted += 1
                        self._keys[id(msg.payload)] = key
                        self._worker.submit(key, msg.payload, camera, **self.detect_kwargs)
                    frames += 1
                while frames > self.depth:
                    out = buf.popleft()
                    frames -= (out.topic in self.cameras if self.cameras
                               else out.topic == topics.CAMERA_IMAGE)
                    yield out
            yield from buf
        finally:
            self.close()

    def __call__(self, frame, camera):
        key = self._keys.pop(id(frame), None)
        if key is None or self._worker is None:  # not submitted (or not read through us)
            from adfusion.starid.detection.detect import detect

            return detect(frame, camera, **self.detect_kwargs)
        return self._worker.result(key)
