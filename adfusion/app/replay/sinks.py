"""Replay sinks: each takes every :class:`~adfusion.app.replay.stages.Step` and makes one
product of the run.

* :class:`LogSink` — the output MCAP: the inputs copied as read, and per frame the solution,
  annotations, estimate, pose and transforms;
* :class:`SmootherSink` — records the frames' stars with the gyro and magnetometer samples,
  and after the run smooths the whole log into ``/smoothed/state`` and ``/smoothed/pose``;
* :class:`SummarySink` — the counters of :class:`ReplaySummary`.

A sink is anything that meets the :class:`Sink` protocol: ``open(run)`` (the
:class:`~adfusion.app.replay.run.Run` it belongs to), ``take(step)`` and ``close()``; sinks
close in reverse order of opening. The protocol, beside
:class:`~adfusion.app.replay.sources.Source`, is what :func:`adfusion.app.replay.run.run`
relies on, so this module names ``Run`` for type checking only and never imports the module
that runs it.

Example:
    >>> s = ReplaySummary(frames=10, identified=9)
    >>> s.as_dict()["identified"]
    9
    >>> isinstance(SummarySink(s), Sink)
    True
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from adfusion.app.errors import UsageError, mark_incomplete
from adfusion.app.replay.stages import FRAME, GYRO, MAG, TRUTH, Step
from adfusion.estimation.estimator import StepRecord
from adfusion.logs import LogWriter, Message, topics
from adfusion.maths import rotations as rot
from adfusion.plain import listed, printable
from adfusion.starid.camera.model import Camera
from adfusion.starid.solver import Solver

if TYPE_CHECKING:
    from adfusion.app.replay.run import Run

_STREAMS = (FRAME, GYRO, MAG)  # the inputs whose coverage a summary reports

__all__ = [
    "InViewCounter",
    "LayoutSink",
    "LogSink",
    "ReplaySummary",
    "Sink",
    "SmootherSink",
    "StreamCounter",
    "SummarySink",
    "attitude_deg",
    "attitude_error",
    "end_sinks",
    "view_radius",
]


@runtime_checkable
class Sink(Protocol):
    """What a replay product provides (see :class:`SummarySink`): opened once with the run,
    given every step in order, closed at the end. A sink that also has ``abort(reason)`` is
    told why a run stopped before it is closed (:class:`LogSink` records it)."""

    def open(self, run: Run) -> None:
        """Called once before the first step, with the run's shared state."""

    def take(self, step: Step) -> None:
        """One step of the replay (a frame, a gyro or magnetometer sample, a truth)."""

    def close(self) -> None:
        """Called once after the last step (also after an abort)."""


@dataclass
class ReplaySummary:
    """What a replay did; ``errors_deg`` compares each frame's estimate with the log's
    truth when it has one."""

    frames: int = 0
    identified: int = 0
    modes: dict[str, int] = field(default_factory=dict)
    rejected_fixes: int = 0
    restarts: int = 0  # frames whose fix restarted the filter (its own history discarded)
    frames_with_3_stars: int = 0
    identified_with_3_stars: int = 0
    errors_deg: list[float] = field(default_factory=list)
    sigmas_deg: list[float] = field(default_factory=list)
    wall_s: float = 0.0
    setup_s: float = 0.0  # of wall_s: before the first frame (opening, catalogue, warm-up)
    problem: str = ""  # the first of problems (kept for callers of the one-line form)
    problems: list[str] = field(default_factory=list)  # every input problem, dropped counts
    dropped: dict[str, int] = field(default_factory=dict)  # input kind → messages dropped
    not_identified: dict[str, int] = field(default_factory=dict)  # why → frames
    smoothed_errors_deg: list[float] = field(default_factory=list)
    smoothed_sigmas_deg: list[float] = field(default_factory=list)
    smoother: dict[str, Any] = field(default_factory=dict)  # replay(smooth=True) only
    # kind ("frame", "gyro", "mag") → messages, used, first_s, last_s: how much of each
    # stream the run had and used
    streams: dict[str, dict[str, float]] = field(default_factory=dict)
    frames_without_gyro: int = 0  # frames met during a gyro outage (gyro_max_age_s)
    live: dict[str, Any] = field(default_factory=dict)  # adfusion live's record (LiveSink)

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        e = np.asarray(self.errors_deg)
        d.pop("errors_deg")
        d.pop("sigmas_deg")
        es, ss = np.asarray(d.pop("smoothed_errors_deg")), np.asarray(d.pop("smoothed_sigmas_deg"))
        if len(es):
            d.update(smoothed_error_rms_deg=float(np.sqrt(np.mean(es**2))),
                     smoothed_error_max_deg=float(es.max()),
                     smoothed_error_p95_deg=float(np.percentile(es, 95)),
                     smoothed_inside_3sigma=float(np.mean(es <= 3 * ss)))
        if not self.smoother:
            d.pop("smoother")
        if not self.live:
            d.pop("live")
        if len(e):
            d.update(error_rms_deg=float(np.sqrt(np.mean(e**2))), error_max_deg=float(e.max()),
                     error_p95_deg=float(np.percentile(e, 95)))
        d["frames_per_s"] = self.frames / self.wall_s if self.wall_s else None
        return _printable(d)  # names that are not UTF-8 as \\xNN: strict JSON (--json)

    def __str__(self) -> str:
        d = self.as_dict()
        modes = listed((f"{m} {n}" for m, n in self.modes.items()), None)
        lines = [f"frames {self.frames}, identified {self.identified} "
                 f"({100 * self.identified / max(self.frames, 1):.1f} %), modes {modes}, "
                 f"rejected fixes {self.rejected_fixes}"]
        if self.not_identified:  # every frame without an accepted fix, by reason
            lines.append(f"not identified: {sum(self.not_identified.values())} frame(s) — "
                         + "; ".join(f"{why}: {n}" for why, n in sorted(
                             self.not_identified.items(), key=lambda kv: -kv[1])))
        if self.restarts:
            lines.append(f"filter restarted from a lost-in-space fix at {self.restarts} of "
                         f"{self.frames} frames (no rate between frames, or fixes its gate kept"
                         " rejecting): rates and NIS across a restart mean nothing; frames "
                         "that are not a sequence are solved one by one with `adfusion solve "
                         "DIR`")
        if self.frames_with_3_stars:
            pct = 100 * self.identified_with_3_stars / self.frames_with_3_stars
            lines.append(f"frames with ≥ 3 catalogue stars in view: {self.frames_with_3_stars},"
                         f" identified {pct:.1f} %")
        if "error_rms_deg" in d:
            lines.append(f"attitude error vs truth: RMS {d['error_rms_deg']:.4f}°, p95 "
                         f"{d['error_p95_deg']:.4f}°, max {d['error_max_deg']:.4f}°")
        if self.smoother.get("error"):
            lines.append(f"smoother failed: {self.smoother['error']}")
        elif self.smoother:
            sm = self.smoother
            line = (f"smoothed ({sm['mode']}, {sm['states']} states, "
                    f"{sm['build_s'] + sm['optimize_s'] + sm['covariance_s']:.1f} s)")
            if "smoothed_error_rms_deg" in d:
                line += (f": RMS {d['smoothed_error_rms_deg']:.4f}°, p95 "
                         f"{d['smoothed_error_p95_deg']:.4f}°, max "
                         f"{d['smoothed_error_max_deg']:.4f}°, inside 3σ "
                         f"{100 * d['smoothed_inside_3sigma']:.1f} %")
            lines.append(line)
            lines += [f"smoother: {p}" for p in sm["problems"]]
        if d["frames_per_s"]:
            after = self.frames / max(self.wall_s - self.setup_s, 1e-9)
            setup = (f", of which {self.setup_s:.1f} s setup: catalogue, solver and detection "
                     "worker, longer on the first run after an editable install, which "
                     f"compiles the star-identification search; {after:.0f} frames/s after it"
                     if self.setup_s > 2.0 else "")
            lines.append(f"{d['frames_per_s']:.1f} frames/s end to end ({self.wall_s:.1f} s"
                         f"{setup})")
        lines += streams_lines(self.streams, self.frames_without_gyro, self.frames)
        if self.live:
            lines.append(live_line(self.live))
        lines += [f"input problem: {p}" for p in (self.problems or
                                                  ([self.problem] if self.problem else []))]
        return printable("\n".join(lines))  # a name that is not UTF-8 as \\xNN


def _printable(value: Any) -> Any:
    """``value`` with every string and key :func:`~adfusion.plain.printable`."""
    if isinstance(value, str):
        return printable(value)
    if isinstance(value, dict):
        return {printable(k) if isinstance(k, str) else k: _printable(v)
                for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(_printable(v) for v in value)
    return value


def live_line(record: dict[str, Any]) -> str:
    """The summary's line of an ``adfusion live`` run (its ``live`` record).

    >>> live_line({"frames_arrived": 12, "frames_dropped": 2, "frames_taken": 10,
    ...            "latency_ms": {"median": 14.2, "p95": 21.0, "max": 30.0},
    ...            "ended_by": "no frame for 5 s"})  # doctest: +NORMALIZE_WHITESPACE
    'live: 12 frame(s) arrived, 10 taken by the solver, 2 dropped (they came while the solver
     was busy);
     latency 14.2 ms median, 21.0 ms p95 (arrival to estimate published); ended: no frame
     for 5 s'
    """
    lat = record.get("latency_ms") or {}
    pace = (f"; latency {lat['median']:.1f} ms median, {lat['p95']:.1f} ms p95 (arrival to "
            "estimate published)" if lat else "")
    early = record.get("frames_dropped_before_ready", 0)
    early = f", {early} of them before it was ready" if early else ""
    dropped = (f"{record['frames_dropped']} dropped (they came while the solver was busy"
               f"{early})" if record["frames_dropped"] else "none dropped")
    return (f"live: {record['frames_arrived']} frame(s) arrived, {record['frames_taken']} "
            f"taken by the solver, {dropped}{pace}; ended: {record['ended_by']}")


def streams_lines(streams: dict[str, dict[str, float]], frames_without_gyro: int = 0,
                  frames: int = 0) -> list[str]:
    """How much of each input stream a run had and used, as the replay's summary and
    ``adfusion report`` say it (from :attr:`ReplaySummary.streams`, or the output's
    ``streams`` metadata that :class:`LogSink` records).

    >>> streams_lines({"frame": {"messages": 3, "used": 3, "first_s": 0.0, "last_s": 0.2},
    ...                "gyro": {"messages": 30, "used": 28, "first_s": 0.0, "last_s": 0.29}},
    ...               1, 3)  # doctest: +NORMALIZE_WHITESPACE
    ['streams: frame 3, 0–0.2 s; gyro 30 (28 used), 0–0.29 s',
     'frames without the gyro (outage): 1 of 3']
    """
    lines = []
    if streams:
        lines.append("streams: " + "; ".join(
            f"{kind} {int(v['messages'])}"
            + (f" ({int(v['used'])} used)" if v["used"] != v["messages"] else "")
            + f", {v['first_s']:.6g}–{v['last_s']:.6g} s"
            for kind, v in streams.items()))
    if frames_without_gyro:
        lines.append(f"frames without the gyro (outage): {frames_without_gyro} of {frames}")
    return lines


class StreamCounter:
    """Counts each input stream of a run (``frame``, ``gyro``, ``mag``): messages, how many
    were used, first and last time (s) — :attr:`ReplaySummary.streams` — and the frames met
    while the gyro was out (past its age limit). :class:`SummarySink` and :class:`LogSink`
    each hold one, so the summary and the output's ``streams`` metadata say the same."""

    def __init__(self, streams: dict[str, dict[str, float]] | None = None) -> None:
        self.streams = streams if streams is not None else {}
        self.frames = 0
        self.frames_without_gyro = 0

    def take(self, step: Step, estimator: Any = None) -> None:
        """Count ``step`` (other kinds than the streams' are not counted)."""
        if step.kind not in _STREAMS:
            return
        t = float(step.msg.t_s)
        v = self.streams.setdefault(step.kind, {"messages": 0, "used": 0,
                                                "first_s": t, "last_s": t})
        v["messages"] += 1
        v["used"] += bool(step.used or step.kind == FRAME)
        v["first_s"], v["last_s"] = min(v["first_s"], t), max(v["last_s"], t)
        if step.kind == FRAME and step.record is not None:
            self.frames += 1
            if (estimator is not None and estimator.without_gyro
                    and not estimator.video_only):
                self.frames_without_gyro += 1

    def metadata(self) -> dict[str, Any]:
        """The output's ``streams`` metadata record: one entry per stream, and
        ``frames_without_gyro`` (with ``frames``) when the gyro was ever out."""
        out: dict[str, Any] = {kind: dict(v) for kind, v in self.streams.items()}
        if self.frames_without_gyro:
            out["frames_without_gyro"] = self.frames_without_gyro
            out["frames"] = self.frames
        return out


def _why(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


def end_sinks(opened: list[Any], failure: BaseException | None) -> None:
    """End a run's ``opened`` sinks (:func:`adfusion.app.replay.run.run`): close them in
    reverse order — or, after a ``failure``, abort those that can be (the log is closed
    marked incomplete). A sink whose close fails makes it a failed run for the sinks still
    open (each is ended all the same: no temporary file or lock is left behind), and its
    error is raised after them; after a ``failure``, that failure is the one raised."""
    reason = None if failure is None else _why(failure)
    raised: BaseException | None = None
    for sink in reversed(opened):
        try:
            if reason is None:
                sink.close()
            elif hasattr(sink, "abort"):
                sink.abort(reason)
        except BaseException as exc:
            if reason is None:
                reason, raised = _why(exc), exc
    ended = failure if failure is not None else raised
    if ended is not None:  # the output, if it could be finished, holds the run so far
        for sink in opened:
            if (isinstance(sink, LogSink) and sink.aborted and sink.log is not None
                    and sink.log.written):  # closed marked incomplete, not complete
                mark_incomplete(ended, sink.path)
    if raised is not None:
        raise raised


class LogSink:
    """The output MCAP (``compression`` as :func:`adfusion.app.replay.replay` documents).

    Inputs (gyro, magnetometer, truth, frames) are copied as read — no decode/encode round
    trip; each frame adds ``/starid/solution``, ``/camera/annotations``, and with an
    estimate ``/estimate/state``, ``/estimate/attitude`` (degrees), ``/estimate/pose`` and
    ``/tf``. With a known start time (``Run.start_utc``) the log times are UTC. Other sinks
    write their products through :attr:`log` before it closes. ``tee`` (a
    :class:`~adfusion.logs.writer.Tee`, the live view) receives every message as written."""

    def __init__(self, path, compression: str = "lz4", tee=None) -> None:
        self.path = path
        self.compression = compression
        self.tee = tee
        self.log: LogWriter | None = None
        self.q_body_cam = np.asarray(rot.IDENTITY)
        self.estimator = None
        self.multi = False
        self.mounts: list[tuple] = []
        self.run: Run | None = None
        self.streams = StreamCounter()  # recorded as the output's `streams` metadata
        self.aborted = False  # ended by abort: the output is marked incomplete

    def open(self, run: Run) -> None:
        self.q_body_cam = run.q_body_cam
        self.estimator = run.estimator
        self.run = run
        # written under a temporary name, renamed when complete (LogWriter atomic)
        self.log = LogWriter(self.path, compression=self.compression,
                             start_utc=run.start_utc, atomic=True, tee=self.tee)
        try:
            self._start(run)
        except BaseException as exc:  # not opened, so never closed: end the log here
            self.abort(_why(exc))
            raise

    def _start(self, run: Run) -> None:
        log = self.log
        log.add_metadata("replay", run.replay_metadata)
        if run.assumptions:
            log.add_metadata("assumptions", run.assumptions)
        if run.config:
            log.add_metadata("config", run.config)
        self.multi = len(run.heads) > 1 or run.heads[0].index != 0
        if not self.multi:
            log.add_camera_model(run.camera_model)
            cam = run.camera
            log.write_calibration(0.0, cam.width, cam.height, cam.K, cam.D, "camera")
            self.mounts = [("body", "camera", self.q_body_cam, (0.0, 0.0, 0.0))]
            return
        self.mounts = []
        for h in run.heads:  # several cameras: each on its own topics and frame
            name = topics.camera_frame(h.index)
            log.add_camera_model(h.camera.to_dict(),
                                 "camera.json" if h.index == 0 else f"{name}.json")
            log.write_calibration(0.0, h.camera.width, h.camera.height, h.camera.K, h.camera.D,
                                  name, topic=topics.camera_topic(h.index, "calibration"))
            self.mounts.append(("body", name, h.q_body_cam, (0.0, 0.0, 0.0)))

    def take(self, step: Step) -> None:
        kind, msg = step.kind, step.msg
        self.streams.take(step, self.estimator)
        if kind == FRAME and step.record is not None:
            if isinstance(msg.payload, np.ndarray):
                if msg.raw is not None:  # a foxglove.RawImage: copied as read
                    self.log.write_protobuf_bytes(msg.topic, msg.t_s, "foxglove.RawImage",
                                                  msg.raw)
                else:
                    self.log.write_image(msg.t_s, msg.payload, topics.camera_frame(step.head),
                                         topic=msg.topic)
            else:
                self._copy(msg)
            self._record_frame(msg.t_s, step.record, step.truth_q, step.head)
        elif kind in (GYRO, MAG, TRUTH):
            self._copy(msg)
        elif msg.topic == topics.TRUTH_POSE:  # the truth's pose, and its frame for the 3D view
            q_icrs_body = np.asarray(msg.payload["q_wxyz"], dtype=float)
            if msg.raw is not None:  # copied as read
                self.log.write_protobuf_bytes(topics.TRUTH_POSE, msg.t_s,
                                              "foxglove.PoseInFrame", msg.raw)
            else:
                self.log.write_pose(topics.TRUTH_POSE, msg.t_s, q_icrs_body, "icrs")
            self.log.write_tf(msg.t_s, [("icrs", "body_truth", q_icrs_body, (0.0, 0.0, 0.0))])

    def _problems(self) -> None:
        if self.streams.streams:
            self.log.add_metadata("streams", self.streams.metadata())
        if self.run is not None:
            problems = self.run.problem_lines()
            if problems:
                self.log.add_metadata("problems", {"input": problems,
                                                   "dropped": self.run.problems.dropped})

    def close(self) -> None:
        if self.log is not None:
            self._problems()
            self.log.close()

    def abort(self, reason: str) -> None:
        """The run failed: the output is closed marked ``incomplete`` (reason) — or, when
        even that fails, removed; never left as a temporary file and a lock."""
        self.aborted = True
        if self.log is not None:
            try:
                self._problems()
            except Exception:  # the run's own failure is the one to raise
                pass
            self.log.abort(reason)

    def _copy(self, msg: Message) -> None:
        """An input message into the output, as read (no decode/encode round trip)."""
        if msg.raw is not None:
            self.log.write_json_bytes(msg.topic, msg.t_s, msg.raw)
        else:
            self.log.write_json(msg.topic, msg.t_s, msg.payload)

    def _record_frame(self, t: float, rec: StepRecord, truth_q=None, head: int = 0) -> None:
        log, sol = self.log, rec.solution
        if sol is not None:
            predicted = None
            cand = sol.candidates[0] if sol.candidates else None
            if sol.ok and cand is not None:
                predicted = cand.predicted_xy
            det_xy = rec.detections_xy
            res = sol.residuals_rad if sol.ok and sol.residuals_rad is not None else ()
            solution = {
                "t": t, "ok": sol.ok, "mode": sol.mode, "reason": sol.reason,
                "q_cam_icrs": sol.q_cam_icrs if sol.ok else None,
                "matches": [list(m) for m in sol.matches],
                "matching_counter": sol.matching_counter,
                "p_false": sol.p_false, "cone_deg": rec.cone_deg,
                "time_ms": sol.time_s * 1e3, "fix_accepted": rec.fix_accepted,
                "n_detections": 0 if det_xy is None else len(det_xy),
                "residuals_arcsec": np.degrees(np.asarray(res, dtype=float)) * 3600}
            if self.multi:
                solution["camera"] = topics.camera_frame(head)
            log.write_json(topics.STARID_SOLUTION, t, solution)
            if det_xy is not None:
                identified = [(float(det_xy[d][0]), float(det_xy[d][1]), str(i))
                              for d, i in sol.matches if d < len(det_xy)]
                log.write_annotations(t, det_xy, identified=identified, predicted_xy=predicted,
                                      topic=topics.camera_topic(head, "annotations"))
        if rec.q_body_icrs is not None:
            state = {"t": t, "q_body_icrs": rec.q_body_icrs, "bias": rec.bias_rad_s,
                     "cov_diag": rec.sigma_rad**2, "nis": rec.nis.get("star fix"),
                     "rejected": [{"input": i, "reason": r} for i, r in rec.rejected]}
            if rec.cov is not None:  # the full P, row-major (cov_diag is its diagonal)
                state["cov"] = rec.cov.reshape(-1)
            if self.estimator.without_gyro:  # no gyro (now): the filter's rate as well
                state["omega"] = np.asarray(self.estimator.filter.omega_rad_s)
            if self.estimator.video_only:  # no gyro, no bias
                state["bias"] = None
            log.write_json(topics.ESTIMATE_STATE, t, state)
            log.write_json(topics.ESTIMATE_ATTITUDE, t, attitude_deg(
                t, rec.q_body_icrs, rec.sigma_rad[:3], rec.star_mode or None, rec.n_stars))
            if truth_q is not None:
                log.write_json(topics.ESTIMATE_ERROR, t, attitude_error(
                    t, rec.q_body_icrs, truth_q, rec.sigma_rad[:3]))
            log.write_attitude(topics.ESTIMATE_POSE, t, rec.q_body_icrs)
            log.write_tf(t, [("icrs", "body", rot.inverse(rec.q_body_icrs), (0.0, 0.0, 0.0)),
                             *self.mounts])


def attitude_error(t: float, q_body_icrs, q_true_body_icrs, sigma_rad) -> dict[str, Any]:
    """An ``/estimate/error`` record: the estimate's error against the truth as a rotation
    vector in body axes (x, y cross-boresight, z roll), deg, its angle, and the 3σ bounds.
    (Float arithmetic: per frame, numpy's per-call overhead was most of the cost.)

    Example:
        >>> import numpy as np
        >>> from adfusion.starid import rotations as rot
        >>> q_err = rot.exp_map([0.0, 0.0, np.radians(0.1)])
        >>> e = attitude_error(0.0, q_err, [1.0, 0.0, 0.0, 0.0], [1e-3] * 3)
        >>> [round(v, 6) for v in e["error_deg"]], round(e["angle_deg"], 6)
        ([0.0, 0.0, 0.1], 0.1)
    """
    tw, tx, ty, tz = (float(v) for v in q_true_body_icrs)
    w, x, y, z = rot.hamilton(tuple(float(v) for v in q_body_icrs), (tw, -tx, -ty, -tz))
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    angle = 2.0 * math.atan2(s, w)
    k = angle / s if s > 1e-12 else 2.0 / max(w, 1e-300)
    deg = math.degrees(1.0)
    sig = [3.0 * deg * float(v) for v in sigma_rad]
    return {"t": t, "error_deg": [k * x * deg, k * y * deg, k * z * deg],
            "angle_deg": angle * deg, "sigma3_deg": sig}


class LayoutSink:
    """A Foxglove layout beside the output, ``OUT.layout.json``
    (:func:`adfusion.app.layout.foxglove_layout`): the image with its annotations, a 3D view
    of the body, camera and truth frames in ``icrs``, plots of the attitude error with its
    3σ bounds, the NIS, the stars per frame and the star-ID mode.

    Written when the run closes, and only then: a failed run (:meth:`abort`) leaves its
    output marked ``incomplete`` and nothing else. Given before the :class:`LogSink` in a
    run's sinks it is closed after it, so the layout comes once the log is complete."""

    def __init__(self, out_path, *, live: bool = False) -> None:
        self.path = self.path_for(out_path)
        self.live = live  # adfusion live's: no truth panels, a latency plot

    @staticmethod
    def path_for(out_path):
        """The layout's file for the output ``out_path``: ``OUT.layout.json`` beside it.

        >>> LayoutSink.path_for("runs/flight.mcap").as_posix()
        'runs/flight.layout.json'
        """
        from pathlib import Path

        out = Path(out_path)
        return out.with_name(out.stem + ".layout.json")

    def open(self, run: Run) -> None:
        pass

    def take(self, step: Step) -> None:
        pass

    def close(self) -> None:
        self.write()

    def write(self) -> None:
        """Write the layout file now."""
        import json

        from adfusion.app.layout import foxglove_layout
        from adfusion.outfiles import write_atomic

        write_atomic(self.path, json.dumps(foxglove_layout(truth=not self.live,
                                                           live=self.live), indent=2))

    def abort(self, reason: str) -> None:
        """The run failed: no layout (the output it would open is incomplete)."""


def attitude_deg(t: float, q_body_icrs, sigma_rad, mode: str | None = None,
                 n_stars: int = 0) -> dict[str, Any]:
    """An ``/estimate/attitude`` record: RA, Dec, roll of body +z (deg) with 1σ per axis —
    :func:`adfusion.maths.rotations.radec_roll_from_q_cam_icrs` of ``q_body_icrs``, in
    float arithmetic.

    Example:
        >>> import numpy as np
        >>> a = attitude_deg(0.0, [1.0, 0.0, 0.0, 0.0], np.radians([0.01, 0.01, 0.1]))
        >>> round(a["dec_deg"], 6), [round(s, 6) for s in a["sigma_deg"]]
        (90.0, [0.01, 0.01, 0.1])
    """
    w, x, y, z = (float(v) for v in q_body_icrs)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    # rows 1 and 2 of R(q) (ICRS → body): body +y and +z in ICRS
    r1 = (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x))
    b = (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))
    up = (-r1[0], -r1[1], -r1[2])
    ra = math.atan2(b[1], b[0]) % (2 * math.pi)
    dec = math.asin(max(-1.0, min(1.0, b[2])))
    e = (-b[1], b[0], 0.0)  # z × b
    ne = math.hypot(e[0], e[1])
    e = (0.0, 1.0, 0.0) if ne < 1e-12 else (e[0] / ne, e[1] / ne, 0.0)
    north = (b[1] * e[2] - b[2] * e[1], b[2] * e[0] - b[0] * e[2], b[0] * e[1] - b[1] * e[0])
    roll = math.atan2(sum(u * v for u, v in zip(up, e, strict=True)),
                      sum(u * v for u, v in zip(up, north, strict=True))) % (2 * math.pi)
    deg = math.degrees(1.0)
    return {"t": t, "ra_deg": ra * deg, "dec_deg": dec * deg, "roll_deg": roll * deg,
            "sigma_deg": [deg * float(v) for v in sigma_rad], "mode": mode,
            "n_stars": int(n_stars)}


class SummarySink:
    """Counts frames, fixes and modes into :attr:`summary` and scores each estimate against
    the truth when the input has it (``errors_deg``, ``sigmas_deg``; the frames with ≥ 3
    catalogue stars in view are counted for all frames at once when the run closes).
    With ``t_start`` (a :func:`time.perf_counter` reading), ``summary.setup_s`` is the time
    from it to the opening of this sink (opening, catalogue, warm-up)."""

    def __init__(self, summary: ReplaySummary | None = None, *,
                 t_start: float | None = None) -> None:
        self.summary = summary if summary is not None else ReplaySummary()
        self.streams = StreamCounter(self.summary.streams)
        self.in_view: InViewCounter | None = None
        self.t_start = t_start
        self.primary = 0

    def open(self, run: Run) -> None:
        if self.t_start is not None:
            self.summary.setup_s = time.perf_counter() - self.t_start
        self.in_view = InViewCounter(run.solver, run.q_body_cam)
        self.primary = run.heads[0].index if run.heads else 0
        self.run = run
        # (t, accepted, q, σ, of the first camera: the batch count knows its view only)
        self.frames: list[tuple[float, bool, Any, Any, bool]] = []

    def take(self, step: Step) -> None:
        self.streams.take(step, self.run.estimator)
        if step.kind != FRAME or step.record is None:
            return
        s, rec = self.summary, step.record
        s.frames += 1
        s.frames_without_gyro = self.streams.frames_without_gyro
        sol = rec.solution
        if sol is not None:
            s.modes[sol.mode] = s.modes.get(sol.mode, 0) + 1
        if any("re-initialised" in why for _, why in rec.rejected):
            s.restarts += 1
        if rec.fix_accepted:
            s.identified += 1
        else:
            if sol is not None and sol.ok:
                s.rejected_fixes += 1
                why = "fix rejected by the filter's gate"
            elif sol is not None:
                why = sol.reason.split(":")[0].strip() or "no solution"
            else:
                why = next((w for src, w in rec.rejected if src == "camera"), "no frame")
                why = why.split(":")[0].strip()
            s.not_identified[why[:60]] = s.not_identified.get(why[:60], 0) + 1
        # scored at close, against the truth interpolated at the estimate's time: the file
        # order of equal-time truth and frame messages must not change the score
        sigma = None if rec.sigma_rad is None else float(np.linalg.norm(rec.sigma_rad[:3]))
        self.frames.append((rec.t, bool(rec.fix_accepted), rec.q_body_icrs, sigma,
                            step.head == self.primary))

    def close(self) -> None:
        s = self.summary
        track = self.run.truth.track if self.run is not None else None
        if track is not None and len(track):
            for t, accepted, q, sigma, primary in self.frames:
                truth_q = track.at(t)
                if truth_q is None:
                    continue
                if primary:
                    self.in_view.add(truth_q, accepted)
                if q is not None:
                    s.errors_deg.append(float(np.degrees(rot.angle_between(q, truth_q))))
                    s.sigmas_deg.append(float(np.degrees(sigma)))
        if self.in_view is not None:
            self.in_view.count_into(s)
        if self.run is not None:
            s.problems = [printable(p) for p in self.run.problem_lines()]
            s.dropped = dict(self.run.problems.dropped)
            s.problem = s.problems[0] if s.problems else ""


class SmootherSink:
    """Records every frame's identified stars with the gyro and magnetometer samples the
    estimator used; on close smooths the whole log (:mod:`adfusion.estimation.smoother`,
    ``mode`` "batch" or "isam2") into ``/smoothed/state`` and ``/smoothed/pose`` of the
    ``log`` sink, and scores it into ``summary``. A smoother failure is reported in
    ``summary.smoother["error"]``; the filter's output stands."""

    def __init__(self, log: LogSink, summary: ReplaySummary, mode: str = "batch") -> None:
        self.log_sink = log
        self.summary = summary
        self.mode = mode
        self.recording = None
        self.truth_frames: list[tuple[float, Any]] = []
        self.solver: Solver | None = None

    def open(self, run: Run) -> None:
        from adfusion.estimation.smoother import SmootherInput

        if len(run.heads) > 1:
            raise UsageError("--smooth smooths one camera's log: choose one with --heads K")
        est = run.estimator
        self.solver = run.solver
        self.run = run
        self.recording = SmootherInput(run.q_body_cam, arw_rad_sqrt_s=est.arw,
                                       rrw_rad_s_sqrt_s=est.rrw,
                                       sigma_mag_rad=est.sigma_mag_rad,
                                       video_only=est.video_only)

    def take(self, step: Step) -> None:
        if not step.used:
            return
        msg = step.msg
        if step.kind == GYRO:
            self.recording.add_gyro(msg.t_s, msg.payload["omega"])
        elif step.kind == MAG:
            self.recording.add_mag(msg.t_s, msg.payload["b_body"], msg.payload["b_ref_icrs"])
        elif step.kind == FRAME:
            self.recording.add_step(msg.t_s, step.record, self.solver)
            self.truth_frames.append((msg.t_s, None))

    def close(self) -> None:
        """Smooth the recorded log; write ``/smoothed/state`` and ``/smoothed/pose``; score."""
        from adfusion.estimation.smoother import SmootherError
        from adfusion.estimation.smoother import smooth as run_smoother

        if self.recording is None:
            return
        track = self.run.truth.track
        self.truth_frames = [(t, track.at(t)) for t, _ in self.truth_frames]
        s, log = self.summary, self.log_sink.log
        try:
            res = run_smoother(self.recording, mode=self.mode)
        except SmootherError as e:
            s.smoother = {"error": str(e)}
            return
        s.smoother = res.as_dict()
        down: dict[float, list[int]] = {}
        for t_o, star, _ in res.outliers:
            down.setdefault(t_o, []).append(star)
        truth = dict(self.truth_frames)  # frame time → truth (None without)
        for k, t in enumerate(res.t.tolist()):
            q = res.q_body_icrs[k]
            state = {"t": t, "q_body_icrs": q, "bias": res.bias_rad_s[k],
                     "cov_diag": res.cov_diag[k], "nis": None,  # a smoother has no innovations
                     "n_stars": int(res.n_stars[k]), "chi2_stars": res.chi2_stars[k],
                     "downweighted": down.get(t, [])}
            if res.omega_rad_s is not None:
                state["omega"] = res.omega_rad_s[k]
            log.write_json(topics.SMOOTHED_STATE, t, state)
            log.write_attitude(topics.SMOOTHED_POSE, t, q)
            if truth.get(t) is not None:
                s.smoothed_errors_deg.append(float(np.degrees(rot.angle_between(q, truth[t]))))
                s.smoothed_sigmas_deg.append(float(np.degrees(res.sigma_rad[k])))


class InViewCounter:
    """The frames with ≥ 3 catalogue stars in view at the true attitude, counted after the
    replay for all frames at once: ``Solver.stars_in_view`` per frame cost ~3 % of the
    replay's main process. The batch projects only the catalogue stars in a cone around each
    boresight; the few frames whose count lies next to the threshold (2 or 3, where rounding
    at a frame edge could tip it) are counted again by ``stars_in_view``, the reference."""

    def __init__(self, solver: Solver, q_body_cam: np.ndarray) -> None:
        self.solver = solver
        self.q_cam_body = rot.inverse(q_body_cam)
        self.truth: list[np.ndarray] = []
        self.accepted: list[bool] = []

    def add(self, truth_q: np.ndarray, fix_accepted: bool) -> None:
        self.truth.append(truth_q)
        self.accepted.append(bool(fix_accepted))

    def count_into(self, s: ReplaySummary) -> None:
        if not self.truth:
            return
        q_cam = rot.multiply(self.q_cam_body, np.array(self.truth))
        n_view = self._counts(rot.to_matrix(q_cam))
        for k in np.flatnonzero((n_view == 2) | (n_view == 3)).tolist():
            q = rot.multiply(self.q_cam_body, self.truth[k])  # as the per-frame count did
            n_view[k] = len(self.solver.stars_in_view(q)[0])
        enough = n_view >= 3
        s.frames_with_3_stars += int(enough.sum())
        s.identified_with_3_stars += int((enough & np.array(self.accepted)).sum())

    def _counts(self, R: np.ndarray, block: int = 256) -> np.ndarray:
        """Catalogue stars inside the frame at each attitude R (N, 3, 3), cam ← icrs."""
        cam, stars = self.solver.camera, self.solver.vectors
        cos_radius = np.cos(view_radius(cam))
        out = np.zeros(len(R), np.int64)
        for b in range(0, len(R), block):  # (stars, frames) products, a block at a time
            Rb = R[b:b + block]
            i, k = np.nonzero(stars @ Rb[:, 2].T >= cos_radius)
            v_cam = np.einsum("pij,pj->pi", Rb[k], stars[i])
            inside = cam.in_frame(cam.vectors_to_pixels(v_cam))
            out[b:b + len(Rb)] = np.bincount(k[inside], minlength=len(Rb))
        return out


def view_radius(cam: Camera, margin_rad: float = 0.02) -> float:
    """An angle from the boresight that holds the whole frame (its border sampled), with a
    margin."""
    t = np.linspace(0.0, 1.0, 65)
    w, h = cam.width - 0.5, cam.height - 0.5
    border = np.concatenate([
        np.column_stack([-0.5 + (w + 0.5) * t, np.full_like(t, -0.5)]),
        np.column_stack([-0.5 + (w + 0.5) * t, np.full_like(t, h)]),
        np.column_stack([np.full_like(t, -0.5), -0.5 + (h + 0.5) * t]),
        np.column_stack([np.full_like(t, w), -0.5 + (h + 0.5) * t])])
    z = cam.pixels_to_vectors(border)[:, 2]
    return min(float(np.arccos(np.clip(z.min(), -1.0, 1.0))) + margin_rad, np.pi)
