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

from dataclasses import dataclass

import numpy as np

from adfusion.estimation.estimator import Estimator, StepRecord
from adfusion.logs import Message, topics
from adfusion.starid.camera import Camera

__all__ = ["DetectAhead", "EstimationStage", "Step", "TruthStage"]

GYRO, MAG, TRUTH, FRAME, OTHER = "gyro", "mag", "truth", "frame", "other"
_KINDS = {topics.GYRO: GYRO, topics.MAG: MAG, topics.TRUTH_STATE: TRUTH,
          topics.CAMERA_IMAGE: FRAME, topics.CAMERA_CENTROIDS: FRAME}


@dataclass(slots=True)
class Step:
    """One message on its way through the stages.

    Attributes:
        msg: the input message.
        kind: ``"gyro"``, ``"mag"``, ``"truth"``, ``"frame"`` or ``"other"`` (not replayed).
        used: the estimator took it (sensors; frames always).
        record: what the estimator did with a frame.
        truth_q: the latest truth ``q_body_icrs`` at a frame, if the input has truth.
    """

    msg: Message
    kind: str
    used: bool = False
    record: StepRecord | None = None
    truth_q: np.ndarray | None = None

    @classmethod
    def of(cls, msg: Message) -> Step:
        return cls(msg, _KINDS.get(msg.topic, OTHER))


class TruthStage:
    """Keeps the latest ``/truth/state`` attitude and hands it to each frame."""

    def __init__(self) -> None:
        self.q: np.ndarray | None = None

    def __call__(self, step: Step) -> None:
        if step.kind == TRUTH:
            self.q = np.asarray(step.msg.payload["q_body_icrs"], dtype=np.float64)
        elif step.kind == FRAME:
            step.truth_q = self.q


class EstimationStage:
    """Feeds the estimator: gyro samples (unless ``use_gyro=False``), magnetometer samples
    that carry their ICRS reference (unless ``use_mag=False``), and every frame — an image
    (detected through the estimator's ``detect``) or centroids."""

    def __init__(self, estimator: Estimator, *, use_gyro: bool = True,
                 use_mag: bool = True) -> None:
        self.est = estimator
        self.use_gyro = use_gyro
        self.use_mag = use_mag

    def __call__(self, step: Step) -> None:
        kind, msg = step.kind, step.msg
        if kind == GYRO:
            if self.use_gyro:
                self.est.step(msg.t_s, gyro=msg.payload["omega"])
                step.used = True
        elif kind == MAG:
            p = msg.payload
            if self.use_mag and "b_ref_icrs" in p:
                self.est.step(msg.t_s, mag=(p["b_body"], p["b_ref_icrs"]))
                step.used = True
        elif kind == FRAME:
            if msg.topic == topics.CAMERA_IMAGE:
                step.record = self.est.step(msg.t_s, frame=msg.payload)
            else:
                step.record = self.est.step(
                    msg.t_s, detections=np.asarray(msg.payload["xy"], dtype=np.float64))
            step.used = True


class DetectAhead:
    """Star detection in a worker process (:class:`adfusion.app.detect_worker.DetectWorker`),
    ``depth`` frames ahead of the filter, on machines with two or more cores.

    :meth:`start` launches the worker (do it early: its interpreter takes ~0.5 s to import
    ``starid``, time the caller can spend loading the catalogue). :meth:`read` passes the
    messages through unchanged, ``depth`` frames behind the submissions; frames read before
    the worker is ready are not submitted but detected here when asked for, rather than
    waited for. The estimator calls the object in place of ``starid.detect`` and gets the
    result computed for that very frame (errors raised there, as a direct call would).
    """

    def __init__(self, camera: Camera | None = None, depth: int = 8) -> None:
        self.camera = camera
        self.depth = depth
        self._worker = None
        self._keys: dict[int, int] = {}
        self._submitted = 0

    def start(self) -> None:
        """Launch the worker now (on two or more cores; idempotent)."""
        import os

        from adfusion.app.detect_worker import DetectWorker

        if self._worker is None and (os.cpu_count() or 1) >= 2:
            self._worker = DetectWorker()

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
                if msg.topic == topics.CAMERA_IMAGE:
                    if self._worker.ready():
                        key = self._submitted
                        self._submitted += 1
                        self._keys[id(msg.payload)] = key
                        self._worker.submit(key, msg.payload, self.camera)
                    frames += 1
                while frames > self.depth:
                    out = buf.popleft()
                    frames -= out.topic == topics.CAMERA_IMAGE
                    yield out
            yield from buf
        finally:
            self.close()

    def __call__(self, frame, camera):
        key = self._keys.pop(id(frame), None)
        if key is None or self._worker is None:  # not submitted (or not read through us)
            from adfusion.starid import detect

            return detect(frame, camera)
        return self._worker.result(key)
