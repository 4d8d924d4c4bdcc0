"""``adfusion bench starid``: lost-in-space identification benchmark against peer solvers.

Random attitudes (seeded) give synthetic centroid lists; our solver (:class:`starid.solver.
Solver`) and the peers — ``tetra3rs`` (Rust, PyPI, the ``bench`` extra) and ``cedar-solve``
(Python, pins numpy<2, so it runs in its own venv behind a JSON-lines subprocess worker) — see
the **same** centroid lists in the same run. Per condition and solver it reports the figures
the star-tracker literature uses (docs/benchmarks.md):

* **availability** — % of frames with a *correct* attitude accepted. Correct means: no point
  of the frame (corners, centre) lands more than ``max(tol_px, tol_sigma·σ)`` (default
  max(5 px, 4σ); 5 px ≈ 0.07°) from where the true attitude puts it (:func:`frame_error_px`).
  A fixed angle such as 0.1° does not work: at σ = 2 px the roll of a correct solution is
  often 0.1–0.27° off (a 2–4.7 px shift at the corners, the same for all three solvers),
  while a misidentification moves the frame by tens of pixels or more. The JSON records, per
  solver, the largest error of a correct and the smallest of a wrong solution (px and
  degrees) so the gap can be checked;
* **error rate** — % of frames where a *wrong* attitude was accepted, with its one-sided 95 %
  Clopper–Pearson upper bound (``1 − 0.05^(1/n)`` for 0 errors);
* **time per solve** — median, p95, max in ms, over all frames (failures included), measured
  with ``perf_counter`` around the solve call *inside* the solver's process (for cedar: in the
  worker, so the pipe is excluded), and the ratio of our median to each peer's; for the
  solvers in this process (ours, tetra3rs: interleaved frame by frame on the same centroid
  lists) also the CPU time of the solve (``time.thread_time``), median and p95 with their
  ratios — on a loaded machine the wall time's p95 is mostly other processes' time.

Frames (:func:`make_frame`): a uniformly random attitude; the catalogue stars brighter than
the visible limit (Hipparcos, estimated V) projected through an ideal pinhole; Gaussian
centroid noise (per axis); each star dropped with probability ``drop_frac``; ``n_false``
false stars placed uniformly in the frame with magnitudes drawn from the catalogue's own
magnitude distribution; the list ordered by magnitude plus ``mag_noise`` (Gaussian), brightest
first. The attitude of frame *i* depends only on ``(seed, i)``, so every condition sees the
same sky; the perturbations depend on ``(seed, i, condition)``. Any frame can be rebuilt with
:func:`make_frame` from the seed, the index and the condition. A :class:`Condition` may also
set the FOV, the magnitude noise, or a body rate — then the frame is *rendered* with motion
blur and its centroids come from :func:`starid.detection.detect` (:func:`render_frame_for`); the
robustness sweeps (:mod:`adfusion.bench.sweep`) are conditions of this model, scored by
:func:`score` per trial and :func:`aggregate` per condition. ``ours_tracking`` (ours with a
filter-like prior, :func:`tracking_prior`) can join the solvers.

Solver set-up (one configuration per condition, as a user would configure a camera):

* ours — ``Solver(Catalog.hipparcos(mag_limit), camera, centroid_sigma_px=max(0.5, σ))``;
  the catalogue is the simulator's own (the peers use their bundled catalogues, so ours has
  no catalogue mismatch to absorb);
* tetra3rs — a database from its bundled Gaia DR3 catalogue (``generate_from_gaia``,
  ``max_fov_deg`` = the camera's horizontal FOV, single scale, ``star_max_magnitude`` =
  visible limit + 0.5 in G), cached under the cache directory; solved with the camera's FOV
  (``fov_estimate_deg``, image size, ``fov_max_error_deg``) and ``match_max_error`` scaled
  with the centroid noise (:func:`peer_match_max_error`). Centroids are (x, y) relative to the
  geometric image centre (ours minus ``((W−1)/2, (H−1)/2)``); its ``quaternion`` is already
  ``q_cam_icrs`` (ICRS → camera, +z boresight, +x right, +y down) — both checked at start-up
  on noise-free frames (``conversion_check`` in the JSON: a ½-px centre slip alone would
  show as ≈ 37″);
* cedar-solve — its bundled ``default_database`` (Hipparcos, FOV 10–30°, to mag 8; it cannot
  build another without the ``hip_main.dat`` file it does not ship); centroids are (y, x)
  from the top-left *corner* (ours + 0.5); the attitude is rebuilt from its RA, Dec and Roll
  with ``roll_ours = −Roll`` (also checked at start-up).

Both peers get ``fov_max_error`` 0.5° (they fit the focal length; ours is told it exactly) and
a solve timeout of ``peer_timeout_ms`` (default 5 s, their default). Every solver is told the
condition's centroid σ (ours through ``centroid_sigma_px``, the peers through
``match_max_error``). All three solve single-threaded (CPU time ≈ wall time).

Layout: :mod:`adfusion.bench.starid.frames` (conditions and frames),
:mod:`adfusion.bench.starid.peers` (the solver adapters: ours, tetra3rs, cedar-solve),
:mod:`adfusion.bench.starid.report` (scoring, the figures and the table) and
:mod:`adfusion.bench.starid.driver` (the run and the command line); this package re-exports
their public names.

Example:
    >>> import argparse
    >>> from adfusion.bench import starid as bench_starid
    >>> p = argparse.ArgumentParser()
    >>> bench_starid.add_arguments(p)
    >>> args = p.parse_args(["--frames", "3", "--conditions", "clean", "--solvers", "ours",
    ...                      "--no-progress"])
    >>> res = bench_starid.run_benchmark(bench_starid.config_from_args(args))
    >>> res["conditions"][0]["results"]["ours"]["n_frames"]
    3
    >>> round(bench_starid.clopper_pearson_upper(0, 200), 5)
    0.01487
"""

from __future__ import annotations

from adfusion.bench.starid.driver import (
    BenchConfig,
    add_arguments,
    config_from_args,
    main,
    run,
    run_benchmark,
)
from adfusion.bench.starid.frames import (
    CONDITIONS,
    RENDER_SENSOR,
    Condition,
    Frame,
    FrameModel,
    camera_for,
    make_frame,
    render_frame_for,
)
from adfusion.bench.starid.frames import load_catalog as load_catalog
from adfusion.bench.starid.frames import random_attitude as random_attitude
from adfusion.bench.starid.peers import METHOD_SOLVERS as METHOD_SOLVERS
from adfusion.bench.starid.peers import (
    SOLVER_NAMES,
    peer_match_max_error,
    solver_for,
    tracking_prior,
)
from adfusion.bench.starid.peers import SOLVERS as SOLVERS
from adfusion.bench.starid.peers import Adapter as Adapter
from adfusion.bench.starid.peers import Outcome as Outcome
from adfusion.bench.starid.peers import cache_root as cache_root
from adfusion.bench.starid.peers import conversion_check as conversion_check
from adfusion.bench.starid.peers import ensure_cedar_venv as ensure_cedar_venv
from adfusion.bench.starid.peers import make_adapters as make_adapters
from adfusion.bench.starid.report import (
    Trial,
    aggregate,
    clopper_pearson_upper,
    format_table,
    frame_error_px,
    score,
)
from adfusion.bench.starid.report import summarize as summarize
from adfusion.bench.starid.report import time_ratios as time_ratios

__all__ = [
    "CONDITIONS",
    "RENDER_SENSOR",
    "SOLVER_NAMES",
    "BenchConfig",
    "Condition",
    "Frame",
    "FrameModel",
    "Trial",
    "add_arguments",
    "aggregate",
    "camera_for",
    "clopper_pearson_upper",
    "config_from_args",
    "format_table",
    "frame_error_px",
    "main",
    "make_frame",
    "peer_match_max_error",
    "render_frame_for",
    "run",
    "run_benchmark",
    "score",
    "solver_for",
    "tracking_prior",
]
