"""Logs in, logs out: record a simulated flight, and replay a log through the estimator.

``simulate`` turns a :mod:`sensors.scenarios` stream into an MCAP file with the DESIGN
topics (the run configuration as metadata, the camera model as an attachment). ``replay``
reads a log (ours, or any with the same topics), runs every frame through detection,
identification (tracking, with lost-in-space fallback) and the filter, and writes the
inputs plus every result — detections, solutions, estimates, poses, transforms — so the
run opens in Foxglove. Both are deterministic: the same input gives identical output.

Example:
    >>> import os, tempfile
    >>> from adfusion.sensors.scenarios import oedipus
    >>> from adfusion.app.pipeline import simulate, replay
    >>> d = tempfile.mkdtemp()
    >>> simulate(oedipus(duration_s=0.5, render=False), os.path.join(d, "sim.mcap"))
    15
    >>> s = replay(os.path.join(d, "sim.mcap"), os.path.join(d, "out.mcap"), progress=False)
    >>> s.frames, s.identified >= 14
    (15, True)
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from adfusion.app.detect_worker import keep_freed_memory
from adfusion.estimation.estimator import Estimator, StepRecord
from adfusion.logs import LogWriter, McapLogReader
from adfusion.starid import rotations as rot
from adfusion.starid.camera import Camera
from adfusion.starid.catalog import Catalog
from adfusion.starid.solver import Solver

__all__ = ["ReplaySummary", "replay", "simulate"]


def simulate(scenario, out_path: str | Path, progress: bool = False) -> int:
    """Write a scenario's events to ``out_path``; returns the number of frames.
    ``progress`` shows a bar of rendered frames on stderr."""
    frames = 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(scenario.t_frame), unit="frame", desc="simulate",
                   mininterval=0.5)
    with LogWriter(out_path) as log:
        log.add_metadata("config", _jsonable(scenario.config))
        log.add_camera_model(scenario.camera.to_dict())
        cam = scenario.camera
        log.write_calibration(0.0, cam.width, cam.height, cam.K, cam.D, "camera")
        q_body_cam = np.asarray(scenario.q_body_cam, dtype=np.float64)
        for ev in scenario.events():
            d, t = ev.data, ev.t_s
            if ev.kind == "truth":
                log.write_json("/truth/state", t, {
                    "t": t, "q_body_icrs": d["q_body_icrs"], "omega": d["omega_body_rad_s"],
                    "bias": d["bias_rad_s"]})
            elif ev.kind == "gyro":
                log.write_json("/imu/gyro", t, {"t": t, "omega": d["omega_meas_rad_s"]})
            elif ev.kind == "mag":
                log.write_json("/mag", t, {"t": t, "b_body": d["b_body_nT"],
                                           "b_ref_icrs": d["b_ref_icrs_nT"]})
            else:
                frames += 1
                if bar is not None:
                    bar.update()
                if "image" in d:
                    log.write_image(t, d["image"], "camera")
                else:  # a centroid-only simulation: the detections are the "image"
                    log.write_json("/camera/centroids", t, {"t": t, "xy": d["xy"]})
                q_body_true = rot.multiply(q_body_cam, d["q_cam_icrs"])
                log.write_attitude("/truth/pose", t, q_body_true)
                log.write_tf(t, [("body_truth", "camera", q_body_cam, (0.0, 0.0, 0.0))])
    if bar is not None:
        bar.close()
    return frames


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
    problem: str = ""
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
        if self.problem:
            lines.append(f"input problem: {self.problem}")
        return "\n".join(lines)


def replay(
    in_path: str | Path,
    out_path: str | Path,
    *,
    use_gyro: bool = True,
    use_mag: bool = True,
    mag_limit: float | None = None,
    progress: bool = True,
    smooth: bool = False,
    smooth_mode: str = "batch",
    compression: str = "auto",
) -> ReplaySummary:
    """Replay ``in_path`` through detection → identification → filter into ``out_path``.

    ``use_gyro=False`` is the video-only mode (the real OEDIPUS-C case: no gyro was
    digitised): the filter estimates the body rate from the star fixes themselves.

    ``smooth=True`` records every frame's identified stars with the gyro and magnetometer
    samples and, after the filter pass, smooths the whole log (:mod:`adfusion.estimation.smoother`,
    ``smooth_mode`` "batch" or "isam2"); the smoothed history goes to ``/smoothed/state``
    and ``/smoothed/pose`` next to the filter's topics. A smoother failure is reported in
    ``summary.smoother["error"]``; the filter's output stands.

    ``compression`` of the output's chunks: ``"auto"`` (default) writes a log with camera
    images uncompressed and any other with LZ4, because replay is about speed and noisy
    video does not compress: on the 60 s OEDIPUS-like log LZ4 saved 2 % of 460 MB for
    ~0.4 ms of the main process per frame, zstd 1.5× for 1.9 ms; ``"lz4"``, ``"zstd"``
    (smallest) and ``"none"`` choose explicitly.

    Process-wide side effect: :func:`adfusion.app.detect_worker.keep_freed_memory` (glibc keeps
    freed blocks of up to 4 MB for reuse instead of returning them to the kernel)."""
    t_start = time.perf_counter()
    keep_freed_memory()
    ahead = _DetectAhead()
    ahead.start()
    try:
        return _replay(in_path, out_path, ahead, t_start, use_gyro=use_gyro, use_mag=use_mag,
                       mag_limit=mag_limit, progress=progress, smooth=smooth,
                       smooth_mode=smooth_mode, compression=compression)
    finally:
        ahead.close()


def _replay(in_path, out_path, ahead: _DetectAhead, t_start: float, *, use_gyro: bool,
            use_mag: bool, mag_limit: float | None, progress: bool, smooth: bool,
            smooth_mode: str, compression: str) -> ReplaySummary:
    reader = McapLogReader(in_path)
    model = reader.camera_model()
    if model is None:
        raise ValueError(f"{in_path}: no camera model attachment (camera.json) in the log")
    camera = Camera.from_dict(model)
    config = reader.metadata.get("config", {})
    q_body_cam = np.asarray(config.get("q_body_cam", rot.IDENTITY), dtype=np.float64)
    epoch = float(config.get("catalog", {}).get("epoch", 2000.0))
    limit = mag_limit if mag_limit is not None else float(config.get("mag_limit", 5.5))
    catalog = Catalog.hipparcos(mag_limit=limit, epoch=epoch)
    gyro_cfg = config.get("gyro", {})
    sigma_px = float(config.get("camera", {}).get("centroid_sigma_px", 0.5))
    solver = Solver(catalog, camera, centroid_sigma_px=max(sigma_px, 0.5))
    solver.warm_up()  # its compiled search loads (or, once after an install, compiles) here
    ahead.camera = camera
    # the exposure lets tracking model motion smear (long streaks that break into pieces)
    exposure = config.get("camera", {}).get("exposure_s")
    est = Estimator(solver, q_body_cam,
                    arw_rad_sqrt_s=float(gyro_cfg.get("arw_rad_sqrt_s", 1e-4)),
                    rrw_rad_s_sqrt_s=float(gyro_cfg.get("rrw_rad_s_sqrt_s", 1e-6)),
                    video_only=not use_gyro, detect=ahead,
                    exposure_s=None if exposure is None else float(exposure))
    summary = ReplaySummary()
    truth_q: np.ndarray | None = None
    in_view = _InViewCounter(solver, q_body_cam)
    recording, truth_frames = None, []  # for the smoother
    if smooth:
        from adfusion.estimation.smoother import SmootherInput

        recording = SmootherInput(q_body_cam, arw_rad_sqrt_s=est.arw, rrw_rad_s_sqrt_s=est.rrw,
                                  sigma_mag_rad=est.sigma_mag_rad, video_only=not use_gyro)
    messages = ahead.read(reader if not progress else _progress(reader))
    if compression == "auto":
        images = any(c.topic == "/camera/image" for c in reader.channels.values())
        compression = "none" if images else "lz4"
    summary.setup_s = time.perf_counter() - t_start
    with LogWriter(out_path, compression=compression) as log:
        log.add_metadata("replay", {"input": str(in_path), "use_gyro": use_gyro,
                                    "use_mag": use_mag, "catalog_mag_limit": limit})
        if config:
            log.add_metadata("config", config)
        log.add_camera_model(model)
        log.write_calibration(0.0, camera.width, camera.height, camera.K, camera.D, "camera")
        for msg in messages:
            t, topic, p = msg.t_s, msg.topic, msg.payload
            if topic == "/imu/gyro":
                if use_gyro:
                    est.step(t, gyro=p["omega"])
                    if recording is not None:
                        recording.add_gyro(t, p["omega"])
                _copy(log, msg)
            elif topic == "/mag":
                if use_mag and "b_ref_icrs" in p:
                    est.step(t, mag=(p["b_body"], p["b_ref_icrs"]))
                    if recording is not None:
                        recording.add_mag(t, p["b_body"], p["b_ref_icrs"])
                _copy(log, msg)
            elif topic == "/truth/state":
                truth_q = np.asarray(p["q_body_icrs"], dtype=np.float64)
                _copy(log, msg)
            elif topic in ("/camera/image", "/camera/centroids"):
                if topic == "/camera/image":
                    if msg.raw is not None:  # a foxglove.RawImage: copied as read
                        log.write_protobuf_bytes(topic, t, "foxglove.RawImage", msg.raw)
                    else:
                        log.write_image(t, p, "camera")
                    rec = est.step(t, frame=p)
                else:
                    rec = est.step(t, detections=np.asarray(p["xy"], dtype=np.float64))
                _record_frame(log, t, rec, est, q_body_cam)
                _count(summary, rec, truth_q, in_view)
                if recording is not None:
                    recording.add_step(t, rec, solver)
                    truth_frames.append((t, truth_q))
        in_view.count_into(summary)
        if recording is not None:
            _smooth_into(log, recording, smooth_mode, summary, truth_frames)
    summary.wall_s = time.perf_counter() - t_start
    if reader.problem is not None:
        summary.problem = str(reader.problem)
    return summary


def _copy(log: LogWriter, msg) -> None:
    """An input message into the output, as read (no decode/encode round trip)."""
    if msg.raw is not None:
        log.write_json_bytes(msg.topic, msg.t_s, msg.raw)
    else:
        log.write_json(msg.topic, msg.t_s, msg.payload)


class _DetectAhead:
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
                if msg.topic == "/camera/image":
                    if self._worker.ready():
                        key = self._submitted
                        self._submitted += 1
                        self._keys[id(msg.payload)] = key
                        self._worker.submit(key, msg.payload, self.camera)
                    frames += 1
                while frames > self.depth:
                    out = buf.popleft()
                    frames -= out.topic == "/camera/image"
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


def _record_frame(log: LogWriter, t: float, rec: StepRecord, est: Estimator,
                  q_body_cam: np.ndarray) -> None:
    sol = rec.solution
    det_xy = None
    if sol is not None:
        identified, predicted = [], None
        cand = sol.candidates[0] if sol.candidates else None
        if sol.ok and cand is not None:
            predicted = cand.predicted_xy
        log.write_json("/starid/solution", t, {
            "t": t, "ok": sol.ok, "mode": sol.mode, "reason": sol.reason,
            "q_cam_icrs": sol.q_cam_icrs if sol.ok else None,
            "matches": [list(m) for m in sol.matches], "matching_counter": sol.matching_counter,
            "p_false": sol.p_false, "cone_deg": rec.cone_deg,
            "time_ms": sol.time_s * 1e3, "fix_accepted": rec.fix_accepted})
        det_xy = getattr(rec, "detections_xy", None)
        if det_xy is not None:
            identified = [(float(det_xy[d][0]), float(det_xy[d][1]), str(i))
                          for d, i in sol.matches if d < len(det_xy)]
            log.write_annotations(t, det_xy, identified=identified, predicted_xy=predicted)
    if rec.q_body_icrs is not None:
        log.write_json("/estimate/state", t, {
            "t": t, "q_body_icrs": rec.q_body_icrs, "bias": rec.bias_rad_s,
            "cov_diag": rec.sigma_rad**2, "nis": rec.nis,
            "rejected": [list(r) for r in rec.rejected]})
        log.write_attitude("/estimate/pose", t, rec.q_body_icrs)
        log.write_tf(t, [("icrs", "body", rot.inverse(rec.q_body_icrs), (0.0, 0.0, 0.0)),
                         ("body", "camera", q_body_cam, (0.0, 0.0, 0.0))])


def _count(s: ReplaySummary, rec: StepRecord, truth_q, in_view: _InViewCounter) -> None:
    s.frames += 1
    sol = rec.solution
    if sol is not None:
        s.modes[sol.mode] = s.modes.get(sol.mode, 0) + 1
    if rec.fix_accepted:
        s.identified += 1
    elif sol is not None and sol.ok:
        s.rejected_fixes += 1
    if truth_q is not None:
        in_view.add(truth_q, rec.fix_accepted)
        if rec.q_body_icrs is not None:
            s.errors_deg.append(float(np.degrees(rot.angle_between(rec.q_body_icrs, truth_q))))
            s.sigmas_deg.append(float(np.degrees(np.linalg.norm(rec.sigma_rad[:3]))))


class _InViewCounter:
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
        cos_radius = np.cos(_view_radius(cam))
        out = np.zeros(len(R), np.int64)
        for b in range(0, len(R), block):  # (stars, frames) products, a block at a time
            Rb = R[b:b + block]
            i, k = np.nonzero(stars @ Rb[:, 2].T >= cos_radius)
            v_cam = np.einsum("pij,pj->pi", Rb[k], stars[i])
            inside = cam.in_frame(cam.vectors_to_pixels(v_cam))
            out[b:b + len(Rb)] = np.bincount(k[inside], minlength=len(Rb))
        return out


def _view_radius(cam: Camera, margin_rad: float = 0.02) -> float:
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


def _smooth_into(log: LogWriter, recording, mode: str, s: ReplaySummary,
                 truth_frames: list[tuple[float, Any]]) -> None:
    """Smooth the recorded log; write ``/smoothed/state`` and ``/smoothed/pose``; score."""
    from adfusion.estimation.smoother import SmootherError
    from adfusion.estimation.smoother import smooth as run_smoother

    try:
        res = run_smoother(recording, mode=mode)
    except SmootherError as e:
        s.smoother = {"error": str(e)}
        return
    s.smoother = res.as_dict()
    down: dict[float, list[int]] = {}
    for t_o, star, _ in res.outliers:
        down.setdefault(t_o, []).append(star)
    truth = dict(truth_frames)  # frame time → truth (None without): frames may be left out
    for k, t in enumerate(res.t.tolist()):
        q = res.q_body_icrs[k]
        state = {"t": t, "q_body_icrs": q, "bias": res.bias_rad_s[k],
                 "cov_diag": res.cov_diag[k], "nis": None,  # a smoother has no innovations
                 "n_stars": int(res.n_stars[k]), "chi2_stars": res.chi2_stars[k],
                 "downweighted": down.get(t, [])}
        if res.omega_rad_s is not None:
            state["omega"] = res.omega_rad_s[k]
        log.write_json("/smoothed/state", t, state)
        log.write_attitude("/smoothed/pose", t, q)
        if truth.get(t) is not None:
            s.smoothed_errors_deg.append(float(np.degrees(rot.angle_between(q, truth[t]))))
            s.smoothed_sigmas_deg.append(float(np.degrees(res.sigma_rad[k])))


def _progress(reader):
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return reader
    return tqdm(reader, unit="msg", mininterval=0.5, desc="replay")


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x
