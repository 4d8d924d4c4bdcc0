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

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from adfusion.app.detect_worker import keep_freed_memory
from adfusion.app.replay.sinks import LogSink, ReplaySummary, SmootherSink, SummarySink
from adfusion.app.replay.sources import McapInput, Source
from adfusion.app.replay.stages import DetectAhead, EstimationStage, Step, TruthStage
from adfusion.estimation.estimator import Estimator
from adfusion.starid import rotations as rot
from adfusion.starid.camera import Camera
from adfusion.starid.catalog import Catalog
from adfusion.starid.solver import Solver

__all__ = ["ReplayOptions", "Run", "replay", "run"]


@dataclass
class ReplayOptions:
    """Settings of a replay that are not the input's (``None``: the input's, else the
    default). ``use_gyro=False`` is the video-only mode (the filter estimates the body rate
    from the star fixes); ``use_mag=False`` ignores the magnetometer."""

    use_gyro: bool = True
    use_mag: bool = True
    mag_limit: float | None = None


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

    @property
    def replay_metadata(self) -> dict[str, Any]:
        return {"input": self.source.name, "use_gyro": self.options.use_gyro,
                "use_mag": self.options.use_mag, "catalog_mag_limit": self.catalog_mag_limit}


def _build(source: Source, options: ReplayOptions, ahead: DetectAhead) -> Run:
    """Camera, catalogue, solver and estimator from the input's model and configuration."""
    model = source.camera_model()
    if model is None:
        raise ValueError(f"{source.name}: no camera model attachment (camera.json) in the log")
    camera = Camera.from_dict(model)
    config = source.config
    q_body_cam = np.asarray(config.get("q_body_cam", rot.IDENTITY), dtype=np.float64)
    epoch = float(config.get("catalog", {}).get("epoch", 2000.0))
    limit = (options.mag_limit if options.mag_limit is not None
             else float(config.get("mag_limit", 5.5)))
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
                    video_only=not options.use_gyro, detect=ahead,
                    exposure_s=None if exposure is None else float(exposure))
    return Run(source, camera, model, config, q_body_cam, limit, solver, est, options)


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
        stages = (TruthStage(), EstimationStage(r.estimator, use_gyro=options.use_gyro,
                                                use_mag=options.use_mag))
        messages = ahead.read(source if not progress else _progress(source))
        opened: list[Any] = []
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
        finally:
            for sink in reversed(opened):
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

    Process-wide side effect: :func:`adfusion.app.detect_worker.keep_freed_memory` (glibc
    keeps freed blocks of up to 4 MB for reuse instead of returning them to the kernel)."""
    t_start = time.perf_counter()
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
        run(source, sinks, ReplayOptions(use_gyro, use_mag, mag_limit), progress=progress,
            ahead=ahead)
    finally:
        ahead.close()
    summary.wall_s = time.perf_counter() - t_start
    if source.problem is not None:
        summary.problem = source.problem
    return summary


def _progress(source):
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return source
    return tqdm(source, unit="msg", mininterval=0.5, desc="replay")
