"""Wire a replay: a source, the stages, the sinks (see :mod:`adfusion.app.replay`).

:func:`replay` is the one-call form (an input path and an output path); :func:`run` takes a
:class:`~adfusion.app.replay.sources.Source` and any sinks, for new inputs and products.

Example:
    >>> import os, tempfile
    >>> from adfusion.sensors.scenarios import oedipus
    >>> from adfusion.app.replay import McapInput, ReplayOptions, SummarySink, run, simulate
    >>> d = tempfile.mkdtemp()
    >>> _ = simulate(oedipus(duration_s=0.5, render=False), os.path.join(d, "sim.mcap"))
    >>> counts = SummarySink()
    >>> _ = run(McapInput(os.path.join(d, "sim.mcap")), [counts], ReplayOptions(),
    ...         progress=False)
    >>> counts.summary.frames
    15
"""

from __future__ import annotations

import gc
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from adfusion.app.detect_worker import keep_freed_memory
from adfusion.app.errors import UsageError
from adfusion.app.replay.clock_check import ClockCheck
from adfusion.app.replay.clock_shift import shift_imu
from adfusion.app.replay.sinks import (
    LayoutSink,
    LogSink,
    ReplaySummary,
    Sink,
    SmootherSink,
    SummarySink,
    end_sinks,
)
from adfusion.app.replay.sources import Source
from adfusion.app.replay.stages import (
    DetectAhead,
    EstimationStage,
    InputProblems,
    Step,
    TruthStage,
)
from adfusion.estimation.estimator import Estimator
from adfusion.estimation.mekf_kernels import warm_up as warm_up_filter
from adfusion.logs import topics
from adfusion.maths import rotations as rot
from adfusion.outfiles import refuse_overwrite
from adfusion.starid.camera.model import Camera
from adfusion.starid.catalog.stars import Catalog
from adfusion.starid.solver import Solver

__all__ = ["DEFAULT_ASSUMPTIONS", "ReplayOptions", "Run", "replay", "run"]

#: What a replay assumes for a log without ``config`` metadata when asked to
#: (``assume_defaults=True``, ``adfusion replay --assume-defaults``); recorded in the output.
DEFAULT_ASSUMPTIONS = {
    "q_body_cam": [1.0, 0.0, 0.0, 0.0],  # camera axes = body axes
    "gyro": {"arw_rad_sqrt_s": 1e-4, "rrw_rad_s_sqrt_s": 1e-6},
    "mag_limit": 5.5,
}


@dataclass
class ReplayOptions:
    """Settings of a replay that are not the input's (``None``: the input's, else the
    default). ``use_gyro=False`` is the video-only mode (the filter estimates the body rate
    from the star fixes); ``use_mag=False`` ignores the magnetometer.

    ``camera`` replaces the input's camera model; ``fov_deg`` (horizontal field of view)
    makes a pinhole model of the input's frame size when there is neither; ``q_body_cam``
    the mounting; ``start_utc`` the UTC time of run time 0; ``sigma`` the detection
    threshold (noise sigmas); ``fov_error_deg`` the ± uncertainty of the focal length for
    lost-in-space; ``epoch`` the catalogue epoch (Julian year); ``exposure_s`` the camera's
    exposure (motion smear in tracking); ``arw_rad_sqrt_s`` / ``rrw_rad_s_sqrt_s`` the
    gyro's angle and rate random walks; ``heads`` the cameras of a several-camera log to
    replay (default all, fused in one estimator); ``imu_offset_s`` is added to every gyro
    and magnetometer time (the IMU's clock put on the frames', as the replay's clock check
    measures it; :mod:`adfusion.app.replay.clock_shift`)."""

    use_gyro: bool = True
    use_mag: bool = True
    mag_limit: float | None = None
    camera: Camera | None = None
    fov_deg: float | None = None
    q_body_cam: Any = None
    start_utc: str | None = None
    sigma: float | None = None
    fov_error_deg: float = 0.0
    epoch: float | None = None
    exposure_s: float | None = None
    arw_rad_sqrt_s: float | None = None
    rrw_rad_s_sqrt_s: float | None = None
    heads: list[int] | None = None
    config: dict[str, Any] | None = None  # the run configuration, when the input lacks it
    assume_defaults: bool = False  # no configuration at all: DEFAULT_ASSUMPTIONS, recorded
    imu_offset_s: float = 0.0


@dataclass
class Head:
    """One star camera of the replay: its index in the input (``/camera{k}/...`` topics),
    model, mounting and solver."""

    index: int
    camera: Camera
    q_body_cam: np.ndarray
    solver: Solver


@dataclass
class Run:
    """What the stages and sinks of one replay share (built by :func:`run`)."""

    source: Source
    camera: Camera
    camera_model: dict[str, Any]
    config: dict[str, Any]
    q_body_cam: np.ndarray
    catalog_mag_limit: float
    solver: Solver
    estimator: Estimator
    options: ReplayOptions
    start_utc: str | None = None
    heads: list[Head] = field(default_factory=list)  # every camera replayed, primary first
    problems: InputProblems = field(default_factory=InputProblems)
    truth: TruthStage = field(default_factory=TruthStage)
    assumptions: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)  # found at the end (the gyro's clock)

    def problem_lines(self) -> list[str]:
        """Every problem of the run so far: the input's damage, then the dropped inputs."""
        found = getattr(self.source, "problems", None)
        if found is None:
            one = self.source.problem
            found = [] if one is None else [one]
        return list(found) + self.problems.lines() + self._outage_lines() + self.notes

    def _outage_lines(self) -> list[str]:
        """Each time the gyro fell silent past its age limit (the estimator's
        ``gyro_outages``): the filter propagated without it meanwhile."""
        out = []
        for start, end in getattr(self.estimator, "gyro_outages", []):
            until = "the end of the run" if end != end else f"{end:.6g} s ({end - start:.3g} s)"
            out.append(f"gyro silent from {start:.6g} s to {until}: the filter propagated "
                       "without it meanwhile (its rate estimated from the star fixes)")
        return out

    @property
    def replay_metadata(self) -> dict[str, Any]:
        return {"input": self.source.name, "use_gyro": self.options.use_gyro,
                "use_mag": self.options.use_mag, "catalog_mag_limit": self.catalog_mag_limit,
                "catalog_epoch": float(self.solver.catalog.epoch),
                "imu_offset_s": float(self.options.imu_offset_s)}


def _section(config: dict[str, Any], key: str, name: str) -> dict[str, Any]:
    value = config.get(key, {})
    if not isinstance(value, dict):
        raise ValueError(f"{name}: config.{key} is a {type(value).__name__}, not an object")
    return value


def _number(section: dict[str, Any], key: str, default: float | None, where: str,
            name: str) -> float | None:
    value = section.get(key, default)
    if value is None:
        return None
    try:
        out = float(value)
    except (TypeError, ValueError):
        out = float("nan")
    if not np.isfinite(out):
        raise ValueError(f"{name}: {where}{key} = {value!r} is not a finite number")
    return out


def _configuration(source: Source, options: ReplayOptions) -> tuple[dict, dict]:
    """The run configuration and what was assumed in its place (recorded in the output).

    Without one a replay would use an identity camera mount and default noise silently —
    2° off with a 3σ of 0.14° on a log whose camera is mounted otherwise — so a log with
    gyro or magnetometer data and no mounting is an error unless the user gives it
    (``--mount``, ``--config``) or asks for the defaults (``--assume-defaults``). Frames
    alone (a folder or a video without ``--imu``) need no mounting: the body frame is then
    the camera's, a definition rather than an assumption."""
    if options.config is not None:
        config = dict(options.config)
    else:
        config = source.config
        if not isinstance(config, dict):
            raise ValueError(f"{source.name}: the config metadata is not an object")
    if options.q_body_cam is not None or "q_body_cam" in config:
        return config, {}
    if not getattr(source, "has_gyro", False) and not getattr(source, "has_mag", False):
        return {**config, "q_body_cam": [1.0, 0.0, 0.0, 0.0]}, {}
    if options.assume_defaults:
        assumed = {k: v for k, v in DEFAULT_ASSUMPTIONS.items() if k not in config}
        return {**DEFAULT_ASSUMPTIONS, **config}, assumed
    what = "no 'config' metadata" if not config else "no q_body_cam in its config metadata"
    raise ValueError(f"{source.name}: {what} (the camera mounting and sensor noise): give "
                     "--mount w,x,y,z or --config FILE.json, or --assume-defaults to replay "
                     "with an identity mounting and default noise (recorded in the output)")


def _julian_year(start_utc) -> float:
    """Julian year of a UTC start time (ISO text or aware datetime); 2000.0 without one or
    for one that does not parse (the start time is checked, with its own message, later).

    >>> round(_julian_year("1995-11-07T08:07:00Z"), 3), _julian_year(None)
    (1995.849, 2000.0)
    """
    from adfusion.logs.writer import utc_ns

    if not start_utc:
        return 2000.0
    try:
        ns = utc_ns(start_utc)
    except (TypeError, ValueError):
        return 2000.0
    j2000_ns = 946_728_000 * 10**9  # 2000-01-01T12:00:00 UTC
    return 2000.0 + (ns - j2000_ns) / (365.25 * 86400 * 1e9)


def _build(source: Source, options: ReplayOptions, ahead: DetectAhead) -> Run:
    """Camera, catalogue, solver and estimator from the input's model and configuration."""
    name = source.name
    config, assumed = _configuration(source, options)
    camera = _camera(source, options)
    model = camera.to_dict()
    mount = options.q_body_cam if options.q_body_cam is not None else config["q_body_cam"]
    try:
        q_body_cam = np.asarray(mount, dtype=np.float64).reshape(4)
    except (TypeError, ValueError):
        q_body_cam = np.zeros(4)
    if not np.all(np.isfinite(q_body_cam)) or not np.any(q_body_cam):
        raise UsageError(f"mounting {mount!r}: give --mount as a quaternion q_body_cam "
                         "'w,x,y,z' (or config.q_body_cam)")
    q_body_cam = rot.normalize(q_body_cam)
    catalog_cfg = _section(config, "catalog", name)
    cam_cfg = _section(config, "camera", name)
    gyro_cfg = _section(config, "gyro", name)
    start = options.start_utc or getattr(source, "start_utc", None) or config.get("start_utc")
    # the stars where they were when the log was taken: its own epoch, else its start time,
    # else J2000 (proper motion moves a few stars by arcseconds per decade)
    epoch = float(options.epoch if options.epoch is not None
                  else _number(catalog_cfg, "epoch", _julian_year(start), "config.catalog.",
                               name))
    limit = (options.mag_limit if options.mag_limit is not None
             else _number(config, "mag_limit", 6.5, "config.", name))  # as adfusion solve
    catalog = Catalog.hipparcos(mag_limit=limit, epoch=epoch)
    sigma_px = _number(cam_cfg, "centroid_sigma_px", 0.5, "config.camera.", name)
    if not sigma_px > 0:
        raise ValueError(f"{name}: config.camera.centroid_sigma_px = {sigma_px!r} must be > 0 "
                         "(the centroids' 1-σ error in pixels)")
    if getattr(source, "has_images", True):
        # stars we detect ourselves in whole frames are good to ~0.3–0.5 px, whatever the
        # log says its own centroids were; a log of centroids (a centroid-only simulation,
        # `adfusion acs`'s tracking windows at ~0.03 px) carries its own accuracy
        sigma_px = max(sigma_px, 0.5)
    extra = {"fov_error_deg": options.fov_error_deg} if options.fov_error_deg else {}
    if extra:
        from adfusion.app.commands.args import fov_error_fits

        fov_error_fits(options.fov_error_deg, camera)  # in the flag's words
    solver = Solver(catalog, camera, centroid_sigma_px=sigma_px, **extra)
    solver.warm_up()  # its compiled search loads (or, once after an install, compiles) here
    # and the tracking path: the first tracked frame's solve time was the kernels' loading
    # (3.6 s in a newcomer's demo summary, as that frame's identification time)
    solver.warm_up_tracking()
    warm_up_filter()  # and the filter's compiled propagation
    ahead.camera = camera
    if options.sigma is not None:
        ahead.detect_kwargs = {"sigma": float(options.sigma)}
    # the exposure lets tracking model motion smear (long streaks that break into pieces)
    exposure = (options.exposure_s if options.exposure_s is not None
                else _number(cam_cfg, "exposure_s", None, "config.camera.", name))
    arw = (options.arw_rad_sqrt_s if options.arw_rad_sqrt_s is not None
           else _number(gyro_cfg, "arw_rad_sqrt_s", 1e-4, "config.gyro.", name))
    rrw = (options.rrw_rad_s_sqrt_s if options.rrw_rad_s_sqrt_s is not None
           else _number(gyro_cfg, "rrw_rad_s_sqrt_s", 1e-6, "config.gyro.", name))
    est = Estimator(solver, q_body_cam, arw_rad_sqrt_s=float(arw), rrw_rad_s_sqrt_s=float(rrw),
                    video_only=not options.use_gyro, detect=ahead,
                    exposure_s=None if exposure is None else float(exposure),
                    gyro_stream=options.use_gyro)
    r = Run(source, camera, model, config, q_body_cam, limit, solver, est, options, start,
            assumptions=assumed)
    r.heads = [Head(0, camera, q_body_cam, solver)]
    n_heads = len(config.get("heads", [])) or 1
    selected = list(range(n_heads)) if options.heads is None else list(options.heads)
    if any(not 0 <= k < n_heads for k in selected) or not selected:
        raise UsageError(f"--heads {selected}: the log has cameras 0..{n_heads - 1}")
    if selected != [0]:
        models = source.camera_models()
        r.heads = []
        for k in selected:
            cam_k = _logged_camera(models[k], source.name, k)
            q_k = np.asarray(config["heads"][k]["q_body_cam"], dtype=np.float64)
            solver_k = (solver if k == 0 and cam_k == camera else
                        Solver(catalog, cam_k, centroid_sigma_px=sigma_px, **extra))
            r.heads.append(Head(k, cam_k, q_k, solver_k))
        first = r.heads[0]
        r.camera, r.camera_model, r.q_body_cam, r.solver = (first.camera, first.camera.to_dict(),
                                                             first.q_body_cam, first.solver)
        est = Estimator(first.solver, first.q_body_cam, arw_rad_sqrt_s=float(arw),
                        rrw_rad_s_sqrt_s=float(rrw), video_only=not options.use_gyro,
                        detect=ahead, exposure_s=None if exposure is None else float(exposure),
                        gyro_stream=options.use_gyro)
        for h in r.heads[1:]:
            est.add_camera(h.solver, h.q_body_cam)
        r.estimator = est
        ahead.cameras = {topics.camera_topic(h.index): h.camera for h in r.heads}
    return r


def _logged_camera(model: Any, name: str, k: int) -> Camera:
    """Camera ``k``'s model as the input holds it (``camera.json``, ``camera1.json`` …),
    read as strictly as a camera file (:func:`adfusion.starid.camera.files.camera_from_mapping`)."""
    from adfusion.starid.camera.files import camera_from_mapping

    what = "camera.json" if k == 0 else f"camera{k}.json"
    if not isinstance(model, dict):
        raise ValueError(f"{name}: the camera model ({what}) is unusable: not an object")
    try:
        return camera_from_mapping(model, what)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ValueError(f"{name}: the camera model ({what}) is unusable: {exc}") from None


def _camera(source: Source, options: ReplayOptions) -> Camera:
    """The camera: ``options.camera``, else the input's model, else a pinhole of
    ``options.fov_deg`` over the input's frame size — or a one-line error naming the flag."""
    if options.camera is not None:
        camera = options.camera
    elif (model := source.camera_model()) is not None:
        camera = _logged_camera(model, source.name, 0)
    elif options.fov_deg is not None:
        size = source.image_size()
        if size is None:
            raise ValueError(f"{source.name}: no frames to take the image size from")
        if not 0 < options.fov_deg < 180:
            raise UsageError(f"--fov {options.fov_deg}: a horizontal field of view in degrees,"
                             " between 0 and 180")
        camera = Camera.pinhole(size[0], size[1], float(options.fov_deg))
    else:
        damaged = [p for p in getattr(source, "problems", []) or [] if "camera" in p]
        if damaged:  # the input had one, damaged or changed since: an input problem
            raise ValueError(f"{source.name}: no camera model in the input ({damaged[0]}); "
                             "give --camera FILE to replay it")
        raise UsageError(f"{source.name}: no camera model in the input: give --camera FILE "
                         "(OpenCV or ROS camera_info YAML, or camera.json) or --fov DEG")
    size = source.image_size()
    if size is not None and tuple(size) != (camera.width, camera.height):
        raise ValueError(f"the camera model is {camera.width}×{camera.height} px but the frames "
                         f"are {size[0]}×{size[1]}: give the matching --camera FILE")
    return camera


def run(source: Source, sinks: Sequence[Sink], options: ReplayOptions | None = None, *,
        progress: bool = True, ahead: DetectAhead | None = None) -> Run:
    """Replay ``source`` into ``sinks``: every message becomes a
    :class:`~adfusion.app.replay.stages.Step`, goes through the truth and estimation stages
    (detection running ahead in a worker), and is taken by each sink in order. Sinks are
    opened once the estimator is built, and closed in reverse order (the log last, so the
    others can still write into it). Returns the :class:`Run`."""
    options = options or ReplayOptions()
    own = ahead is None
    if own:
        ahead = DetectAhead()
        ahead.start()
    collection = _SetupOutOfCollection()
    try:
        r = _build(source, options, ahead)
        r.truth = TruthStage(r.problems)
        stages = (r.truth, EstimationStage(
            r.estimator, use_gyro=options.use_gyro, use_mag=options.use_mag,
            cameras={h.index: i for i, h in enumerate(r.heads)}, problems=r.problems,
            sizes={i: (h.camera.width, h.camera.height) for i, h in enumerate(r.heads)}))
        feed = source if not progress else _progress(source)
        if options.imu_offset_s:
            feed = shift_imu(feed, options.imu_offset_s)
        messages = ahead.read(feed)
        opened: list[Any] = []
        failure: BaseException | None = None
        try:
            for sink in sinks:
                sink.open(r)
                opened.append(sink)
            takes = [sink.take for sink in sinks]
            collection.loop_starts()
            for msg in messages:
                step = Step.of(msg)
                for stage in stages:
                    stage(step)
                for take in takes:
                    take(step)
        except BaseException as exc:  # Ctrl-C too: the output says it is incomplete
            failure = exc
            raise
        finally:
            end_sinks(opened, failure)
        return r
    finally:
        collection.restore()
        if own:
            ahead.close()


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
    options: ReplayOptions | None = None,
    layout: bool = True,
    config: dict[str, Any] | None = None,
    assume_defaults: bool = False,
    **input_args: Any,
) -> ReplaySummary:
    """Replay ``in_path`` through detection → identification → filter into ``out_path``.

    ``in_path``: one of our MCAP logs, a ROS 2 bag in MCAP, a folder of images or a video
    file (:func:`adfusion.app.replay.sources.open_input`, which takes ``input_args``: ``fps``,
    ``timestamps``, ``imu``, ``image_topic``, ``imu_topic``, ``mag_topic``). ``options``
    (:class:`ReplayOptions`) replaces ``use_gyro``, ``use_mag`` and ``mag_limit`` and adds
    the camera, mounting, start time and detection/solver settings.

    ``use_gyro=False`` is the video-only mode (the real OEDIPUS-C case: no gyro was
    digitised): the filter estimates the body rate from the star fixes themselves; an input
    without gyro samples is replayed so.

    ``smooth=True`` records every frame's identified stars with the gyro and magnetometer
    samples and, after the filter pass, smooths the whole log
    (:mod:`adfusion.estimation.smoother`, ``smooth_mode`` "batch" or "isam2"); the smoothed
    history goes to ``/smoothed/state`` and ``/smoothed/pose`` next to the filter's topics.
    A smoother failure is reported in ``summary.smoother["error"]``; the filter's output
    stands.

    ``compression`` of the output's chunks: ``"auto"`` (default) writes a log with camera
    images uncompressed and any other with LZ4, because replay is about speed and noisy
    video does not compress: on the 60 s OEDIPUS-like log LZ4 saved 2 % of 460 MB for
    ~0.4 ms of the main process per frame, zstd 1.5× for 1.9 ms; ``"lz4"``, ``"zstd"``
    (smallest) and ``"none"`` choose explicitly. ``layout=True`` writes a Foxglove layout
    beside the output (``OUT.layout.json``, :class:`~adfusion.app.replay.sinks.LayoutSink`).

    ``out_path`` is never the input nor a file of an input folder (the same file by inode:
    a symlink or ``./X`` too; :class:`~adfusion.outfiles.OutputClash`); it is locked
    against a second writer (:class:`~adfusion.outfiles.OutputBusy`), written under a
    temporary name of its own and renamed when complete (:class:`adfusion.logs.LogWriter`,
    ``atomic``). A replay stopped
    by an exception or Ctrl-C leaves it closed and marked ``incomplete`` (metadata). Every
    input problem and every dropped input is in ``summary.problems`` and in the output's
    ``problems`` metadata. ``config`` supplies the run configuration for a log without one;
    ``assume_defaults`` replays such a log with :data:`DEFAULT_ASSUMPTIONS` (recorded as
    ``assumptions`` metadata) — without either, a log without configuration is an error.

    Process-wide side effect: :func:`adfusion.app.detect_worker.keep_freed_memory` (glibc
    keeps freed blocks of up to 4 MB for reuse instead of returning them to the kernel)."""
    t_start = time.perf_counter()
    from adfusion.app.replay.sources import input_files, open_input

    # before any work: the output (and its layout) against the input, and against every
    # file of an input folder (a frame folder, a rosbag2 folder)
    refuse_overwrite([("-o", out_path)]
                     + ([("the layout", LayoutSink.path_for(out_path))] if layout else []),
                     [in_path, *input_files(in_path)])
    keep_freed_memory()
    if options is None:
        options = ReplayOptions(use_gyro, use_mag, mag_limit)
    if config is not None:
        options.config = config
    if assume_defaults:
        options.assume_defaults = True
    ahead = DetectAhead()
    ahead.start()
    try:
        source = open_input(in_path, **input_args)
        source.imu_offset_s = float(options.imu_offset_s)  # the clocks as they will be
        if hasattr(source, "preflight"):  # the IMU file's clock against the frames', first
            source.preflight()
        if not getattr(source, "has_gyro", True) and options.use_gyro:
            options.use_gyro = False  # nothing to propagate with: the rate filter (video only)
        summary = ReplaySummary()
        if compression == "auto":
            compression = "none" if source.has_images else "lz4"
        log = LogSink(out_path, compression)
        # the layout first, so closed last: written once the log is complete, never for
        # a failed run
        sinks: list[Sink] = [LayoutSink(out_path)] if layout else []
        sinks.append(log)
        if smooth:
            sinks.append(SmootherSink(log, summary, smooth_mode))
        sinks.append(SummarySink(summary, t_start=t_start))
        if options.use_gyro:  # last, so closed first: what it finds is in every problem list
            sinks.append(ClockCheck())
        run(source, sinks, options, progress=progress, ahead=ahead)
    finally:
        ahead.close()
    summary.wall_s = time.perf_counter() - t_start
    return summary


class _SetupOutOfCollection:
    """Keeps the cyclic garbage collector off the setup's objects (the catalogue, index,
    solver, numba's and the newly imported modules' ~100 000 objects, which live as long as
    the run): paused from creation while the run is built, then at :meth:`loop_starts`
    frozen (:func:`gc.freeze`: left out of every later scan) and resumed for the message
    loop. Without, one full collection during the setup walked them all: 0.12–0.29 s of a
    600-frame replay on the shared 2-core machine, time the end-to-end rate pays. Nothing
    is lost: cycles made in the loop are collected as before, and :meth:`restore` hands
    every object back to the collector (:func:`gc.unfreeze`), in the state found."""

    def __init__(self) -> None:
        self.enabled = gc.isenabled()
        self.frozen = False
        gc.disable()

    def loop_starts(self) -> None:
        gc.freeze()
        self.frozen = True
        if self.enabled:
            gc.enable()

    def restore(self) -> None:
        if self.frozen:
            gc.unfreeze()
            self.frozen = False
        if self.enabled:
            gc.enable()


def _progress(source):
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return source
    total = len(source) if hasattr(source, "__len__") else None
    return tqdm(source, total=total, unit="msg", mininterval=0.5, desc="replay")
