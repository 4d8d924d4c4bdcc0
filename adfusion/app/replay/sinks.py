"""Replay sinks: each takes every :class:`~adfusion.app.replay.stages.Step` and makes one
product of the run.

* :class:`LogSink` — the output MCAP: the inputs copied as read, and per frame the solution,
  annotations, estimate, pose and transforms;
* :class:`SmootherSink` — records the frames' stars with the gyro and magnetometer samples,
  and after the run smooths the whole log into ``/smoothed/state`` and ``/smoothed/pose``;
* :class:`SummarySink` — the counters of :class:`ReplaySummary`.

A sink has ``open(run)`` (the :class:`~adfusion.app.replay.run.Run` it belongs to),
``take(step)`` and ``close()``; sinks close in reverse order of opening.

Example:
    >>> s = ReplaySummary(frames=10, identified=9)
    >>> s.as_dict()["identified"]
    9
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from adfusion.app.replay.stages import FRAME, GYRO, MAG, TRUTH, Step
from adfusion.estimation.estimator import StepRecord
from adfusion.logs import LogWriter, Message, topics
from adfusion.starid import rotations as rot
from adfusion.starid.camera import Camera
from adfusion.starid.solver import Solver

if TYPE_CHECKING:
    from adfusion.app.replay.run import Run

__all__ = ["InViewCounter", "LogSink", "ReplaySummary", "SmootherSink", "SummarySink",
           "view_radius"]


@dataclass
class ReplaySummary:
    """What a replay did; ``errors_deg`` compares each frame's estimate with the log's
    truth when it has one."""

    frames: int = 0
    identified: int = 0
    modes: dict[str, int] = field(default_factory=dict)
    rejected_fixes: int = 0
    frames_with_3_stars: int = 0
    identified_with_3_stars: int = 0
    errors_deg: list[float] = field(default_factory=list)
    sigmas_deg: list[float] = field(default_factory=list)
    wall_s: float = 0.0
    setup_s: float = 0.0  # of wall_s: before the first frame (opening, catalogue, warm-up)
    problem: str = ""  # the first of problems (kept for callers of the one-line form)
    problems: list[str] = field(default_factory=list)  # every input problem, dropped counts
    dropped: dict[str, int] = field(default_factory=dict)  # input kind → messages dropped
    smoothed_errors_deg: list[float] = field(default_factory=list)
    smoothed_sigmas_deg: list[float] = field(default_factory=list)
    smoother: dict[str, Any] = field(default_factory=dict)  # replay(smooth=True) only

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
        if len(e):
            d.update(error_rms_deg=float(np.sqrt(np.mean(e**2))), error_max_deg=float(e.max()),
                     error_p95_deg=float(np.percentile(e, 95)))
        d["frames_per_s"] = self.frames / self.wall_s if self.wall_s else None
        return d

    def __str__(self) -> str:
        d = self.as_dict()
        lines = [f"frames {self.frames}, identified {self.identified} "
                 f"({100 * self.identified / max(self.frames, 1):.1f} %), modes {self.modes}, "
                 f"rejected fixes {self.rejected_fixes}"]
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
            setup = (f", of which {self.setup_s:.1f} s setup — the first run after an install"
                     f" compiles the star-identification search; {after:.0f} frames/s after it"
                     if self.setup_s > 2.0 else "")
            lines.append(f"{d['frames_per_s']:.1f} frames/s end to end ({self.wall_s:.1f} s"
                         f"{setup})")
        lines += [f"input problem: {p}" for p in (self.problems or
                                                  ([self.problem] if self.problem else []))]
        return "\n".join(lines)


class LogSink:
    """The output MCAP (``compression`` as :func:`adfusion.app.replay.replay` documents).

    Inputs (gyro, magnetometer, truth, frames) are copied as read — no decode/encode round
    trip; each frame adds ``/starid/solution``, ``/camera/annotations``, and with an estimate
    ``/estimate/state``, ``/estimate/pose`` and ``/tf``. Other sinks write their products
    through :attr:`log` before it closes."""

    def __init__(self, path, compression: str = "lz4") -> None:
        self.path = path
        self.compression = compression
        self.log: LogWriter | None = None
        self.q_body_cam = np.asarray(rot.IDENTITY)
        self.run: Run | None = None

    def open(self, run: Run) -> None:
        self.q_body_cam = run.q_body_cam
        self.run = run
        # written under a temporary name, renamed when complete (LogWriter atomic)
        self.log = log = LogWriter(self.path, compression=self.compression, atomic=True)
        log.add_metadata("replay", run.replay_metadata)
        if run.assumptions:
            log.add_metadata("assumptions", run.assumptions)
        if run.config:
            log.add_metadata("config", run.config)
        log.add_camera_model(run.camera_model)
        cam = run.camera
        log.write_calibration(0.0, cam.width, cam.height, cam.K, cam.D, "camera")

    def take(self, step: Step) -> None:
        kind, msg = step.kind, step.msg
        if kind == FRAME and step.record is not None:
            if msg.topic == topics.CAMERA_IMAGE:
                if msg.raw is not None:  # a foxglove.RawImage: copied as read
                    self.log.write_protobuf_bytes(msg.topic, msg.t_s, "foxglove.RawImage",
                                                  msg.raw)
                else:
                    self.log.write_image(msg.t_s, msg.payload, "camera")
            self._record_frame(msg.t_s, step.record)
        elif kind in (GYRO, MAG, TRUTH):
            self._copy(msg)

    def _problems(self) -> None:
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
        """The run failed: the output is closed marked ``incomplete`` (reason)."""
        if self.log is not None:
            try:
                self._problems()
            except OSError:
                pass
            self.log.abort(reason)

    def _copy(self, msg: Message) -> None:
        """An input message into the output, as read (no decode/encode round trip)."""
        if msg.raw is not None:
            self.log.write_json_bytes(msg.topic, msg.t_s, msg.raw)
        else:
            self.log.write_json(msg.topic, msg.t_s, msg.payload)

    def _record_frame(self, t: float, rec: StepRecord) -> None:
        log, sol = self.log, rec.solution
        if sol is not None:
            predicted = None
            cand = sol.candidates[0] if sol.candidates else None
            if sol.ok and cand is not None:
                predicted = cand.predicted_xy
            log.write_json(topics.STARID_SOLUTION, t, {
                "t": t, "ok": sol.ok, "mode": sol.mode, "reason": sol.reason,
                "q_cam_icrs": sol.q_cam_icrs if sol.ok else None,
                "matches": [list(m) for m in sol.matches],
                "matching_counter": sol.matching_counter,
                "p_false": sol.p_false, "cone_deg": rec.cone_deg,
                "time_ms": sol.time_s * 1e3, "fix_accepted": rec.fix_accepted})
            det_xy = rec.detections_xy
            if det_xy is not None:
                identified = [(float(det_xy[d][0]), float(det_xy[d][1]), str(i))
                              for d, i in sol.matches if d < len(det_xy)]
                log.write_annotations(t, det_xy, identified=identified, predicted_xy=predicted)
        if rec.q_body_icrs is not None:
            log.write_json(topics.ESTIMATE_STATE, t, {
                "t": t, "q_body_icrs": rec.q_body_icrs, "bias": rec.bias_rad_s,
                "cov_diag": rec.sigma_rad**2, "nis": rec.nis,
                "rejected": [list(r) for r in rec.rejected]})
            log.write_attitude(topics.ESTIMATE_POSE, t, rec.q_body_icrs)
            log.write_tf(t, [("icrs", "body", rot.inverse(rec.q_body_icrs), (0.0, 0.0, 0.0)),
                             ("body", "camera", self.q_body_cam, (0.0, 0.0, 0.0))])


class SummarySink:
    """Counts frames, fixes and modes into :attr:`summary` and scores each estimate against
    the truth when the input has it (``errors_deg``, ``sigmas_deg``; the frames with ≥ 3
    catalogue stars in view are counted for all frames at once when the run closes).
    With ``t_start`` (a :func:`time.perf_counter` reading), ``summary.setup_s`` is the time
    from it to the opening of this sink (opening, catalogue, warm-up)."""

    def __init__(self, summary: ReplaySummary | None = None, *,
                 t_start: float | None = None) -> None:
        self.summary = summary if summary is not None else ReplaySummary()
        self.in_view: InViewCounter | None = None
        self.t_start = t_start

    def open(self, run: Run) -> None:
        if self.t_start is not None:
            self.summary.setup_s = time.perf_counter() - self.t_start
        self.in_view = InViewCounter(run.solver, run.q_body_cam)
        self.run = run
        self.frames: list[tuple[float, bool, Any, Any]] = []  # (t, accepted, q, σ)

    def take(self, step: Step) -> None:
        if step.kind != FRAME or step.record is None:
            return
        s, rec = self.summary, step.record
        s.frames += 1
        sol = rec.solution
        if sol is not None:
            s.modes[sol.mode] = s.modes.get(sol.mode, 0) + 1
        if rec.fix_accepted:
            s.identified += 1
        elif sol is not None and sol.ok:
            s.rejected_fixes += 1
        # scored at close, against the truth interpolated at the estimate's time: the file
        # order of equal-time truth and frame messages must not change the score
        sigma = None if rec.sigma_rad is None else float(np.linalg.norm(rec.sigma_rad[:3]))
        self.frames.append((rec.t, bool(rec.fix_accepted), rec.q_body_icrs, sigma))

    def close(self) -> None:
        s = self.summary
        track = self.run.truth.track if self.run is not None else None
        if track is not None and len(track):
            for t, accepted, q, sigma in self.frames:
                truth_q = track.at(t)
                if truth_q is None:
                    continue
                self.in_view.add(truth_q, accepted)
                if q is not None:
                    s.errors_deg.append(float(np.degrees(rot.angle_between(q, truth_q))))
                    s.sigmas_deg.append(float(np.degrees(sigma)))
        if self.in_view is not None:
            self.in_view.count_into(s)
        if self.run is not None:
            s.problems = self.run.problem_lines()
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
