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

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from adfusion.app.detect_worker import keep_freed_memory
from adfusion.app.replay.sinks import LogSink, ReplaySummary, SmootherSink, SummarySink
from adfusion.app.replay.sources import McapInput, Source
from adfusion.app.replay.stages import (
    DetectAhead,
    EstimationStage,
    InputProblems,
    Step,
    TruthStage,
)
from adfusion.estimation.estimator import Estimator
from adfusion.starid import rotations as rot
from adfusion.starid.camera import Camera
from adfusion.starid.catalog import Catalog
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
    from the star fixes); ``use_mag=False`` ignores the magnetometer."""

    use_gyro: bool = True
    use_mag: bool = True
    mag_limit: float | None = None
    config: dict[str, Any] | None = None  # the run configuration, when the input lacks it
    assume_defaults: bool = False  # no configuration at all: DEFAULT_ASSUMPTIONS, recorded


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
    problems: InputProblems = field(default_factory=InputProblems)
    truth: TruthStage = field(default_factory=TruthStage)
    assumptions: dict[str, Any] = field(default_factory=dict)

    def problem_lines(self) -> list[str]:
        """Every problem of the run so far: the input's damage, then the dropped inputs."""
        found = getattr(self.source, "problems", None)
        if found is None:
            one = self.source.problem
            found = [] if one is None else [one]
        return list(found) + self.problems.lines()

    @property
    def replay_metadata(self) -> dict[str, Any]:
        return {"input": self.source.name, "use_gyro": self.options.use_gyro,
                "use_mag": self.options.use_mag, "catalog_mag_limit": self.catalog_mag_limit}


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
    2° off with a 3σ of 0.14° on a log whose camera is mounted otherwise — so it is an
    error unless the user gives it or asks for the defaults."""
    if options.config is not None:
        return dict(options.config), {}
    config = source.config
    if not isinstance(config, dict):
        raise ValueError(f"{source.name}: the config metadata is not an object")
    if config and "q_body_cam" in config:
        return config, {}
    if options.assume_defaults:
        assumed = {k: v for k, v in DEFAULT_ASSUMPTIONS.items() if k not in config}
        return {**DEFAULT_ASSUMPTIONS, **config}, assumed
    what = "no 'config' metadata" if not config else "no q_body_cam in its config metadata"
    raise ValueError(f"{source.name}: {what} (the camera mounting and sensor noise): give it "
                     "with --config FILE.json, or --assume-defaults to replay with an "
                     "identity mounting and default noise (recorded in the output)")


def _build(source: Source, options: ReplayOptions, ahead: DetectAhead) -> Run:
    """Camera, catalogue, solver and estimator from the input's model and configuration."""
    name = source.name
    model = source.camera_model()
    if model is None:
        raise ValueError(f"{name}: no camera model attachment (camera.json) in the log")
    try:
        camera = Camera.from_dict(model)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ValueError(f"{name}: the camera model (camera.json) is unusable: "
                         f"{type(exc).__name__}: {exc}") from None
    config, assumed = _configuration(source, options)
    try:
        q_body_cam = rot.normalize(np.asarray(config["q_body_cam"], dtype=np.float64).reshape(4))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: config.q_body_cam is not a quaternion: {exc}") from None
    catalog_cfg = _section(config, "catalog", name)
    cam_cfg = _section(config, "camera", name)
    gyro_cfg = _section(config, "gyro", name)
    epoch = _number(catalog_cfg, "epoch", 2000.0, "config.catalog.", name)
    limit = (options.mag_limit if options.mag_limit is not None
             else _number(config, "mag_limit", 5.5, "config.", name))
    catalog = Catalog.hipparcos(mag_limit=limit, epoch=epoch)
    sigma_px = _number(cam_cfg, "centroid_sigma_px", 0.5, "config.camera.", name)
    solver = Solver(catalog, camera, centroid_sigma_px=max(sigma_px, 0.5))
    solver.warm_up()  # its compiled search loads (or, once after an install, compiles) here
    ahead.camera = camera
    # the exposure lets tracking model motion smear (long streaks that break into pieces)
    exposure = _number(cam_cfg, "exposure_s", None, "config.camera.", name)
    est = Estimator(solver, q_body_cam,
                    arw_rad_sqrt_s=_number(gyro_cfg, "arw_rad_sqrt_s", 1e-4, "config.gyro.",
                                           name),
                    rrw_rad_s_sqrt_s=_number(gyro_cfg, "rrw_rad_s_sqrt_s", 1e-6,
                                             "config.gyro.", name),
                    video_only=not options.use_gyro, detect=ahead, exposure_s=exposure)
    return Run(source, camera, model, config, q_body_cam, limit, solver, est, options,
               assumptions=assumed)


def run(source: Source, sinks: Sequence[Any], options: ReplayOptions | None = None, *,
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
    try:
        r = _build(source, options, ahead)
        r.truth = TruthStage(r.problems)
        stages = (r.truth, EstimationStage(r.estimator, use_gyro=options.use_gyro,
                                           use_mag=options.use_mag, problems=r.problems))
        messages = ahead.read(source if not progress else _progress(source))
        opened: list[Any] = []
        failure: BaseException | None = None
        try:
            for sink in sinks:
                sink.open(r)
                opened.append(sink)
            takes = [sink.take for sink in sinks]
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
            reason = None if failure is None else (
                f"{type(failure).__name__}: {failure}" if str(failure)
                else type(failure).__name__)
            for sink in reversed(opened):
                if reason is not None and hasattr(sink, "abort"):
                    sink.abort(reason)
                elif reason is None:
                    sink.close()
        return r
    finally:
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
    config: dict[str, Any] | None = None,
    assume_defaults: bool = False,
) -> ReplaySummary:
    """Replay ``in_path`` through detection → identification → filter into ``out_path``.

    ``use_gyro=False`` is the video-only mode (the real OEDIPUS-C case: no gyro was
    digitised): the filter estimates the body rate from the star fixes themselves.

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
    (smallest) and ``"none"`` choose explicitly.

    ``out_path`` is never the input (the same file by inode: a symlink or ``./X`` too);
    it is written as ``out_path + ".partial"`` and renamed when complete. A replay stopped
    by an exception or Ctrl-C leaves it closed and marked ``incomplete`` (metadata). Every
    input problem and every dropped input is in ``summary.problems`` and in the output's
    ``problems`` metadata. ``config`` supplies the run configuration for a log without one;
    ``assume_defaults`` replays such a log with :data:`DEFAULT_ASSUMPTIONS` (recorded as
    ``assumptions`` metadata) — without either, a log without configuration is an error.

    Process-wide side effect: :func:`adfusion.app.detect_worker.keep_freed_memory` (glibc
    keeps freed blocks of up to 4 MB for reuse instead of returning them to the kernel)."""
    t_start = time.perf_counter()
    _refuse_to_overwrite(in_path, out_path)
    keep_freed_memory()
    ahead = DetectAhead()
    ahead.start()
    try:
        source = McapInput(in_path)
        summary = ReplaySummary()
        if compression == "auto":
            compression = "none" if source.has_images else "lz4"
        log = LogSink(out_path, compression)
        sinks: list[Any] = [log]
        if smooth:
            sinks.append(SmootherSink(log, summary, smooth_mode))
        sinks.append(SummarySink(summary, t_start=t_start))
        run(source, sinks, ReplayOptions(use_gyro, use_mag, mag_limit, config, assume_defaults),
            progress=progress, ahead=ahead)
    finally:
        ahead.close()
    summary.wall_s = time.perf_counter() - t_start
    return summary


def _refuse_to_overwrite(in_path: str | Path, out_path: str | Path) -> None:
    """The output must not be the input: same file by device and inode (so ``./X``, a
    symlink or a hard link to X count), or the partial file's name."""
    if os.path.exists(out_path) and os.path.exists(in_path) and os.path.samefile(in_path,
                                                                                 out_path):
        raise ValueError(f"the output {out_path} is the input {in_path}: give another name "
                         "(a replay never overwrites its input)")
    partial = str(out_path) + ".partial"
    if os.path.exists(partial) and os.path.exists(in_path) and os.path.samefile(in_path,
                                                                                partial):
        raise ValueError(f"the output's temporary name {partial} is the input: give "
                         "another output name")


def _progress(source):
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return source
    return tqdm(source, unit="msg", mininterval=0.5, desc="replay")
