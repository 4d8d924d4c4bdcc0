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
blur and its centroids come from :func:`starid.detect` (:func:`render_frame_for`); the
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

import argparse
import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
import zlib
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from adfusion.bench.machine import code_version, machine_info

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

SOLVER_NAMES = ("ours", "tetra3rs", "cedar")
_CHECK_LIMIT_ARCSEC = 60.0  # a convention slip (½ px, axis swap, roll sign) is ≥ 30″


# --- conditions and frames ---------------------------------------------------------------


@dataclass(frozen=True)
class Condition:
    """One benchmark condition (a sweep point of ``adfusion bench sweep`` is one, too).

    ``sigma_px``, ``mag_limit``, ``mag_noise`` and ``fov_deg`` of ``None`` mean "the run's
    base value" (``--sigma``, ``--mag-limit``, ``--mag-noise``, ``--fov``); :meth:`resolved`
    fills them in. ``rate_deg_s`` set means a *rendered* frame: the stars are drawn onto an
    image streaked by a body rate of that size (random axis) over ``exposure_s``, and the
    centroids come from :func:`starid.detect` (:func:`make_frame`).

    >>> Condition("x", n_false=3).resolved(0.1, 6.0).sigma_px
    0.1
    >>> Condition("x", fov_deg=20.0).resolved(0.1, 6.0, mag_noise=0.1, fov_deg=15.0).fov_deg
    20.0
    """

    name: str
    description: str = ""
    n_false: int = 0
    drop_frac: float = 0.0
    sigma_px: float | None = None
    mag_limit: float | None = None
    coverage: bool = False  # report frames with ≥ 3 / ≥ 4 catalogue stars in the table
    mag_noise: float | None = None
    fov_deg: float | None = None
    rate_deg_s: float | None = None  # None: synthetic centroids; a value: rendered + detect
    exposure_s: float = 0.1

    def resolved(self, sigma_px: float, mag_limit: float, *, mag_noise: float | None = None,
                 fov_deg: float | None = None) -> Condition:
        """A copy with the run's base values where unset."""
        return replace(
            self,
            sigma_px=sigma_px if self.sigma_px is None else self.sigma_px,
            mag_limit=mag_limit if self.mag_limit is None else self.mag_limit,
            mag_noise=mag_noise if self.mag_noise is None else self.mag_noise,
            fov_deg=fov_deg if self.fov_deg is None else self.fov_deg,
        )

    def params(self) -> dict[str, Any]:
        """The frame model's parameters (recorded in the JSON)."""
        out = {"n_false": self.n_false, "drop_frac": self.drop_frac,
               "sigma_px": self.sigma_px, "mag_limit": self.mag_limit}
        for k in ("mag_noise", "fov_deg", "rate_deg_s"):
            if getattr(self, k) is not None:
                out[k] = getattr(self, k)
        if self.rate_deg_s is not None:
            out["exposure_s"] = self.exposure_s
        return out


#: The default conditions, by name (``--conditions`` picks a subset, in this order).
CONDITIONS: dict[str, Condition] = {
    c.name: c
    for c in (
        Condition("clean", "base centroid noise only"),
        Condition("false3", "3 false stars", n_false=3),
        Condition("false8", "8 false stars", n_false=8),
        Condition("drop30_false3", "30 % of stars dropped + 3 false", n_false=3,
                  drop_frac=0.3),
        Condition("sparse45", "sparse field: catalogue and visible stars V < 4.5",
                  mag_limit=4.5, coverage=True),
        Condition("sigma1", "centroid σ = 1 px", sigma_px=1.0),
        Condition("sigma2", "centroid σ = 2 px", sigma_px=2.0),
    )
}


@dataclass(frozen=True)
class Frame:
    """One synthetic frame: the truth and the centroid list every solver sees.

    ``xy`` is (N, 2), brightest (observed) first, pixel centres (docs/conventions.md);
    ``cat_ids`` holds the HIP number of each row, −1 for a false star.
    """

    condition: str
    index: int
    q_cam_icrs: NDArray[np.float64]
    xy: NDArray[np.float64]
    cat_ids: NDArray[np.int64]
    n_in_view: int  # catalogue stars in view before drops
    seed: int = 0
    # rendered frames: the camera's rate (rad/s, camera axes) over the exposure, during which
    # the true attitude is exp(−ω s) ⊗ q_cam_icrs, s ∈ [−T/2, T/2]
    omega_cam_rad_s: NDArray[np.float64] | None = None
    exposure_s: float = 0.0

    @property
    def n_true(self) -> int:
        """Catalogue stars among the centroids (after drops and noise)."""
        return int(np.count_nonzero(self.cat_ids >= 0))


def _cond_key(name: str) -> int:
    return zlib.crc32(name.encode())


def random_attitude(seed: int, index: int) -> NDArray[np.float64]:
    """Uniformly random ``q_cam_icrs`` for frame ``index`` (the same in every condition).

    >>> from adfusion.starid import rotations as rot
    >>> bool(np.allclose(random_attitude(0, 5), random_attitude(0, 5)))
    True
    """
    from adfusion.starid import rotations as rot

    rng = np.random.default_rng([seed, index])
    return rot.normalize(rng.normal(size=4))


def make_frame(catalog, camera, cond: Condition, seed: int, index: int,
               mag_noise: float = 0.1) -> Frame:
    """Build frame ``index`` of condition ``cond`` (resolved: ``sigma_px``, ``mag_limit`` set).

    ``catalog`` must hold the stars visible under ``cond`` (``mag < cond.mag_limit``) and
    ``camera`` be the condition's (:func:`camera_for`). ``cond.mag_noise``, when set, replaces
    ``mag_noise``. A condition with ``rate_deg_s`` is rendered (:func:`render_frame_for`).

    >>> from adfusion import starid
    >>> from adfusion.starid.catalog import Catalog
    >>> cat = Catalog.hipparcos(mag_limit=6.0, epoch=2025.0)
    >>> cam = starid.Camera.pinhole(1024, 768, fov_x_deg=15.0)
    >>> f = make_frame(cat, cam, CONDITIONS["false3"].resolved(0.1, 6.0), seed=0, index=7)
    >>> int(np.count_nonzero(f.cat_ids < 0)), f.xy.shape[1]
    (3, 2)
    """
    from adfusion.starid import rotations as rot

    if cond.rate_deg_s is not None:
        return render_frame_for(catalog, camera, cond, seed, index)
    if cond.mag_noise is not None:
        mag_noise = cond.mag_noise
    q = random_attitude(seed, index)
    rng = np.random.default_rng([seed, index, _cond_key(cond.name)])
    v = rot.rotate(q, catalog.vectors)
    front = np.flatnonzero(v[:, 2] > 0)
    xy = camera.vectors_to_pixels(v[front])
    inside = camera.in_frame(xy)
    xy, idx = xy[inside], front[inside]
    n_in_view = len(idx)
    mags = np.asarray(catalog.mag, dtype=np.float64)[idx]
    ids = np.asarray(catalog.ids, dtype=np.int64)[idx]
    keep = rng.random(len(idx)) >= cond.drop_frac
    xy, mags, ids = xy[keep], mags[keep], ids[keep]
    sigma = float(cond.sigma_px or 0.0)
    xy = xy + rng.normal(0.0, 1.0, xy.shape) * sigma
    ok = camera.in_frame(xy)  # pushed out of the frame by the noise: not detected
    xy, mags, ids = xy[ok], mags[ok], ids[ok]
    if cond.n_false:
        fx = rng.uniform(-0.5, camera.width - 0.5, cond.n_false)
        fy = rng.uniform(-0.5, camera.height - 0.5, cond.n_false)
        fmag = rng.choice(np.asarray(catalog.mag, dtype=np.float64), cond.n_false)
        xy = np.vstack([xy, np.column_stack([fx, fy])])
        mags = np.concatenate([mags, fmag])
        ids = np.concatenate([ids, np.full(cond.n_false, -1, np.int64)])
    observed = mags + rng.normal(0.0, 1.0, len(mags)) * mag_noise
    order = np.argsort(observed, kind="stable")
    return Frame(cond.name, index, q, xy[order], ids[order], n_in_view, seed)


#: The detector model of rendered frames: the renderer's default small star tracker (a
#: V = 6 star gives ~4000 e⁻ per exposure over 100 e⁻ of sky per pixel, 10 e⁻ read noise).
RENDER_SENSOR: dict[str, Any] = {"psf_sigma_px": 1.0, "noise": "gaussian"}


def render_frame_for(catalog, camera, cond: Condition, seed: int, index: int) -> Frame:
    """A rendered frame: ``sensors.render.render_frame`` + :func:`starid.detect`.

    The attitude is :func:`random_attitude` ``(seed, index)`` at mid-exposure; the body turns
    at ``cond.rate_deg_s`` about a random axis (camera frame) during ``cond.exposure_s``, so
    every star is a streak of rate × exposure. ``catalog``'s stars are rendered (the visible
    set, as for synthetic frames) and the detections — all of them, brightest first — are
    the centroid list; ``detect`` runs with ``max_elongation=None`` because streaks are the
    point of the condition (its default rejects blobs longer than 3:1 as satellite trails).
    A detection within 3 px of a star's mid-exposure position is that star (``cat_ids``).

    >>> from adfusion import starid
    >>> from adfusion.starid.catalog import Catalog
    >>> cat = Catalog.hipparcos(mag_limit=5.0, epoch=2025.0)
    >>> cam = starid.Camera.pinhole(256, 192, fov_x_deg=15.0)
    >>> f = render_frame_for(cat, cam, Condition("r", rate_deg_s=1.0), seed=0, index=3)
    >>> f.n_true >= 1, f.xy.shape[1]
    (True, 2)
    """
    from scipy.spatial import cKDTree

    from adfusion import starid
    from adfusion.sensors.render import SensorModel, render_frame

    if cond.n_false or cond.drop_frac:  # (sigma_px only tells the solvers what to expect)
        raise ValueError(f"{cond.name}: a rendered condition takes no synthetic perturbations")
    q = random_attitude(seed, index)
    rng = np.random.default_rng([seed, index, _cond_key(cond.name)])
    axis = rng.normal(size=3)
    omega = np.radians(float(cond.rate_deg_s or 0.0)) * axis / np.linalg.norm(axis)
    fr = render_frame(camera, q, catalog.vectors, catalog.mag, SensorModel(**RENDER_SENSOR),
                      seed=int(rng.integers(2**31)), omega_cam_rad_s=omega,
                      exposure_s=cond.exposure_s)
    det = starid.detect(fr.image, camera, max_elongation=None)
    xy = np.asarray(det.xy, dtype=np.float64).reshape(-1, 2)
    ids = np.full(len(xy), -1, np.int64)
    if len(xy) and len(fr.star_xy):
        d, j = cKDTree(fr.star_xy).query(xy, distance_upper_bound=3.0)
        hit = np.isfinite(d)
        ids[hit] = np.asarray(catalog.ids, dtype=np.int64)[fr.star_index[j[hit]]]
    return Frame(cond.name, index, q, xy, ids, len(fr.star_xy), seed, omega, cond.exposure_s)


def camera_for(cond: Condition, width: int, height: int, fov_deg: float = 15.0):
    """The pinhole camera of a condition (its ``fov_deg``, else ``fov_deg``).

    >>> round(camera_for(Condition("x", fov_deg=20.0), 1024, 768).fov_x_deg, 9)
    20.0
    """
    from adfusion import starid
    fov = fov_deg if cond.fov_deg is None else cond.fov_deg
    return starid.Camera.pinhole(width, height, fov_x_deg=float(fov))


# --- statistics --------------------------------------------------------------------------


def clopper_pearson_upper(k: int, n: int, confidence: float = 0.95) -> float:
    """One-sided Clopper–Pearson upper bound of a binomial proportion (k of n).

    >>> round(clopper_pearson_upper(0, 100), 6) == round(1 - 0.05 ** (1 / 100), 6)
    True
    >>> clopper_pearson_upper(5, 5)
    1.0
    """
    from scipy.stats import beta

    if n <= 0:
        return 1.0
    if k >= n:
        return 1.0
    return float(beta.ppf(confidence, k + 1, n - k))


def _r(fn: Any, x: NDArray[np.float64], nd: int = 3) -> float | None:
    if len(x) == 0:
        return None
    v = float(fn(x))
    return round(v, nd) if np.isfinite(v) else None


def _pct(k: int, n: int) -> float | None:
    return None if n == 0 else round(100.0 * k / n, 3)


def _time_stats(t_s: Sequence[float]) -> dict[str, float | None]:
    if len(t_s) == 0:
        return {"median": None, "p95": None, "max": None}
    t = np.asarray(t_s) * 1e3
    return {"median": round(float(np.median(t)), 4), "p95": round(float(np.percentile(t, 95)), 4),
            "max": round(float(np.max(t)), 4)}


@dataclass
class Outcome:
    ok: bool
    q: NDArray[np.float64] | None
    time_s: float
    status: str = ""
    own_time_s: float | None = None  # the solver's self-reported time, if any
    matches: list[tuple[int, int]] | None = None  # (detection, catalogue id), ours only
    covariance: NDArray[np.float64] | None = None  # 3×3 rad², camera frame, ours only
    #: the solve's CPU time (this thread), for solvers running in this process: unlike the
    #: wall time it leaves out what other processes on a loaded machine take
    cpu_s: float | None = None


def frame_error_px(q_est: NDArray[np.float64], q_true: NDArray[np.float64], camera) -> float:
    """Largest pixel shift of the frame's corners and centre between two attitudes.

    The directions the true attitude puts at the four corners and the centre are projected
    with the estimate; ``inf`` if one falls behind the camera.

    >>> from adfusion import starid
    >>> from adfusion.starid import rotations as rot
    >>> cam = starid.Camera.pinhole(1024, 768, fov_x_deg=15.0)
    >>> q = rot.q_cam_icrs_from_radec_roll(0.1, 0.2, 0.3)
    >>> dq = rot.exp_map([0.0, 0.0, np.radians(0.1)])      # 0.1° of roll
    >>> round(frame_error_px(rot.multiply(dq, q), q, cam), 2)
    1.12
    """
    from adfusion.starid import rotations as rot

    xy = np.vstack([camera.corners(), [[camera.K[0, 2], camera.K[1, 2]]]])
    v_icrs = rot.rotate(rot.inverse(q_true), camera.pixels_to_vectors(xy))
    moved = camera.vectors_to_pixels(rot.rotate(q_est, v_icrs))
    d = np.linalg.norm(moved - xy, axis=1)
    return float(np.max(d)) if np.all(np.isfinite(d)) else float("inf")


@dataclass(frozen=True)
class Trial:
    """One solver on one frame, scored: the unit a campaign task returns (JSON-able row).

    ``verdict`` is ``"correct"``, ``"wrong"`` (a wrong attitude accepted) or ``"failed"``
    (nothing accepted); errors are ``None`` unless something was accepted (``inf`` px when a
    frame corner falls behind the camera).
    """

    index: int
    verdict: str
    error_px: float | None
    error_deg: float | None
    time_s: float
    status: str
    own_time_s: float | None
    n_true: int
    n_centroids: int
    error_path_px: float | None = None  # rendered frames: closest instant of the exposure
    # wrong attitudes (ours): share of the matches that are right, how many, the largest 1σ
    # the solver reported and the error in units of that covariance (√ of δθᵀ C⁻¹ δθ) — a
    # misidentification, or the right stars badly fitted, and did the solver say so?
    stars_right: float | None = None
    n_matches: int | None = None
    sigma_max_deg: float | None = None
    error_sigmas: float | None = None

    def row(self) -> list[Any]:
        """As a list (JSON lines; ``Trial(*row)`` rebuilds it)."""
        return [self.index, self.verdict, self.error_px, self.error_deg, self.time_s,
                self.status, self.own_time_s, self.n_true, self.n_centroids,
                self.error_path_px, self.stars_right, self.n_matches, self.sigma_max_deg,
                self.error_sigmas]


def score(frame: Frame, outcome: Outcome, camera, tol_px: float, catalog=None) -> Trial:
    """Judge one outcome against the frame's truth: correct when the frame's corners and
    centre move by less than ``tol_px`` (:func:`frame_error_px`).

    A streaked (rendered, moving) frame has no single true attitude: the camera turned by
    rate × exposure while it was taken, and a streak broken into fragments yields centroids
    of *other instants* than mid-exposure — all stars of a frame alike, so the fit is tight
    and the identification right, yet the attitude is that of another instant (up to
    rate × exposure / 2 off mid-exposure). Such an outcome is correct when it is within
    ``tol_px`` of the true attitude at some instant of the exposure (41 instants tried);
    ``error_path_px`` records that distance, ``error_px`` stays the mid-exposure one, and
    :func:`aggregate` counts and lists these frames (``off_mid_exposure``).

    For a wrong attitude with its matches (ours), ``stars_right`` tells a misidentification
    from a bad fit of the right stars: the share of matched detections that are the claimed
    star — by the frame's truth ids, or, on a streaked frame (``catalog`` needed), lying
    within 2 px of that star's path during the exposure.

    >>> from adfusion import starid
    >>> cam = starid.Camera.pinhole(1024, 768, fov_x_deg=15.0)
    >>> f = Frame("x", 0, random_attitude(0, 0), np.zeros((5, 2)), np.arange(5), 5)
    >>> score(f, Outcome(True, f.q_cam_icrs, 0.001), cam, 5.0).verdict
    'correct'
    """
    from adfusion.starid import rotations as rot

    err_px = err_deg = path_px = None
    verdict = "failed"
    if outcome.ok and outcome.q is not None:
        err_deg = float(np.degrees(rot.angle_between(outcome.q, frame.q_cam_icrs)))
        err_px = frame_error_px(outcome.q, frame.q_cam_icrs, camera)
        verdict = "correct" if err_px < tol_px else "wrong"
        if verdict == "wrong" and frame.omega_cam_rad_s is not None and frame.exposure_s > 0:
            s = np.linspace(-0.5, 0.5, 41) * frame.exposure_s
            q_path = rot.multiply(rot.exp_map(-np.outer(s, frame.omega_cam_rad_s)),
                                  frame.q_cam_icrs)
            path_px = min(frame_error_px(outcome.q, q, camera) for q in q_path)
            verdict = "correct" if path_px < tol_px else "wrong"
    right = n_match = sigma = n_sigma = None
    if verdict == "wrong" and outcome.matches:
        right = _stars_right(frame, outcome.matches, camera, catalog)
        n_match = len(outcome.matches)
    if verdict == "wrong" and outcome.covariance is not None and outcome.q is not None:
        c = np.asarray(outcome.covariance, dtype=np.float64)
        sigma = float(np.degrees(np.sqrt(np.max(np.diag(c)))))
        d = rot.log_map(rot.multiply(frame.q_cam_icrs, rot.inverse(outcome.q)))
        with contextlib.suppress(np.linalg.LinAlgError):
            n_sigma = float(np.sqrt(d @ np.linalg.solve(c, d)))
    return Trial(frame.index, verdict, err_px, err_deg, float(outcome.time_s),
                 outcome.status, outcome.own_time_s, frame.n_true, len(frame.xy), path_px,
                 right, n_match, sigma, n_sigma)


def _stars_right(frame: Frame, matches: Sequence[tuple[int, int]], camera,
                 catalog) -> float | None:
    """Share of (detection, catalogue id) matches that are right (see :func:`score`)."""
    from adfusion.starid import rotations as rot

    if frame.omega_cam_rad_s is None:
        return float(np.mean([frame.cat_ids[d] == c for d, c in matches]))
    if catalog is None:
        return None
    row = {int(i): k for k, i in enumerate(np.asarray(catalog.ids))}
    v = np.asarray(catalog.vectors)[[row[int(c)] for _, c in matches]]
    s = np.linspace(-0.5, 0.5, 41) * frame.exposure_s
    q_path = rot.multiply(rot.exp_map(-np.outer(s, frame.omega_cam_rad_s)), frame.q_cam_icrs)
    xy = frame.xy[[d for d, _ in matches]]
    best = np.full(len(matches), np.inf)
    for q in q_path:
        d = np.hypot(*(camera.vectors_to_pixels(rot.rotate(q, v)) - xy).T)
        best = np.minimum(best, d)
    return float(np.mean(best <= 2.0))


def summarize(frames: Sequence[Frame], outcomes: Sequence[Outcome], camera, tol_px: float,
              list_max: int = 50, per_frame: bool = False) -> dict[str, Any]:
    """Availability, error rate (+ 95 % bound), times (wall, and CPU where measured) and
    the frames worth a look."""
    out = aggregate([score(f, o, camera, tol_px)
                     for f, o in zip(frames, outcomes, strict=True)], list_max, per_frame)
    cpu = [o.cpu_s for o in outcomes]
    if cpu and all(c is not None for c in cpu):
        out["cpu_time_ms"] = _time_stats(cpu)
    return out


def aggregate(trials: Sequence[Trial], list_max: int = 50,
              per_frame: bool = False) -> dict[str, Any]:
    """The figures of one solver over scored trials (order matters only for the lists).

    >>> t = [Trial(i, "correct", 0.5, 0.001, 0.002, "", None, 8, 10) for i in range(3)]
    >>> a = aggregate(t + [Trial(3, "failed", None, None, 0.004, "ambiguous: 2", None, 3, 4)])
    >>> a["availability_pct"], a["n_failed"], a["failure_reasons"]
    (75.0, 1, {'ambiguous': 1})
    """
    n = len(trials)
    nan = float("nan")
    err_px = np.array([nan if t.error_px is None else t.error_px for t in trials], float)
    err_deg = np.array([nan if t.error_deg is None else t.error_deg for t in trials], float)
    verdict = np.array([t.verdict for t in trials], dtype=object)
    accepted = verdict != "failed"
    correct = verdict == "correct"
    wrong = verdict == "wrong"
    n_true = np.array([t.n_true for t in trials], dtype=np.int64)
    times = [t.time_s for t in trials]
    out: dict[str, Any] = {
        "n_frames": n,
        "n_correct": int(correct.sum()),
        "n_wrong": int(wrong.sum()),
        "n_failed": int((~accepted).sum()),
        "availability_pct": _pct(int(correct.sum()), n),
        "error_rate_pct": _pct(int(wrong.sum()), n),
        "error_rate_upper95_pct": round(100 * clopper_pearson_upper(int(wrong.sum()), n), 3),
        "time_ms": _time_stats(times),
        "time_ms_correct": _time_stats([t for t, c in zip(times, correct, strict=True) if c]),
        "median_error_correct_arcsec": _r(np.median, err_deg[correct] * 3600),
        "max_error_correct_deg": _r(np.max, err_deg[correct], 4),
        "max_error_correct_px": _r(np.max, err_px[correct]),
        "min_error_wrong_deg": _r(np.min, err_deg[wrong], 4),
        "min_error_wrong_px": _r(np.min, err_px[wrong]),
    }
    for k in (3, 4):
        sel = n_true >= k
        out[f"frames_ge{k}_stars"] = int(sel.sum())
        out[f"availability_ge{k}_pct"] = _pct(int((correct & sel).sum()), int(sel.sum()))
    own = [t.own_time_s for t in trials if t.own_time_s is not None]
    if own:
        out["own_reported_time_ms"] = _time_stats(own)
    statuses: dict[str, int] = {}
    for t in trials:
        if t.verdict == "failed":
            key = t.status.split(":")[0] or "not ok"
            statuses[key] = statuses.get(key, 0) + 1
    out["failure_reasons"] = dict(sorted(statuses.items(), key=lambda kv: -kv[1]))
    off_mid = [t for t in trials if t.verdict == "correct" and t.error_path_px is not None]
    if off_mid:  # streaked frames: right stars, the attitude of another instant (see score)
        out["n_off_mid_exposure"] = len(off_mid)
        out["off_mid_exposure_frames"] = [
            {"index": t.index, "error_px": round(float(t.error_px or 0.0), 2),
             "error_deg": round(float(t.error_deg or 0.0), 4),
             "error_path_px": round(float(t.error_path_px or 0.0), 2)} for t in off_mid]
    out["wrong_frames"] = [
        {"index": trials[i].index, "error_deg": round(float(err_deg[i]), 4),
         "error_px": round(float(err_px[i]), 2) if np.isfinite(err_px[i]) else "inf",
         "n_centroids": trials[i].n_centroids, "n_true": int(n_true[i]),
         **({} if trials[i].error_path_px is None else
            {"error_path_px": round(trials[i].error_path_px, 2)}),
         **({} if trials[i].stars_right is None else
            {"stars_right": round(trials[i].stars_right, 3), "n_matches": trials[i].n_matches}),
         **({} if trials[i].sigma_max_deg is None else
            {"sigma_max_deg": round(trials[i].sigma_max_deg, 4),
             "error_sigmas": None if trials[i].error_sigmas is None else
             round(trials[i].error_sigmas, 2)})}
        for i in np.flatnonzero(wrong)
    ]
    out["failed_frames"] = [
        {"index": trials[i].index, "status": trials[i].status[:120],
         "n_centroids": trials[i].n_centroids, "n_true": int(n_true[i])}
        for i in np.flatnonzero(~accepted)[:list_max]
    ]
    slow = np.argsort(times)[::-1][:5]
    out["slowest_frames"] = [{"index": trials[i].index, "time_ms": round(times[i] * 1e3, 3),
                              "ok": bool(correct[i])} for i in slow]
    if per_frame:
        out["per_frame"] = {
            "accepted": accepted.tolist(), "correct": correct.tolist(),
            "error_px": [round(float(e), 3) if np.isfinite(e) else None for e in err_px],
            "time_ms": [round(t * 1e3, 4) for t in times],
            "status": [t.status[:80] for t in trials],
        }  # fmt: skip
    return out


# --- configuration -----------------------------------------------------------------------


@dataclass
class FrameModel:
    """The synthetic camera, sky and scoring every benchmark frame comes from — one set
    of defaults for ``bench starid`` (:class:`BenchConfig`) and ``bench sweep``."""

    seed: int = 0
    width: int = 1024
    height: int = 768
    fov_deg: float = 15.0
    mag_limit: float = 6.0
    sigma_px: float = 0.1
    mag_noise: float = 0.1
    tol_px: float = 5.0
    tol_sigma: float = 4.0
    epoch: float = 2025.0


@dataclass
class BenchConfig(FrameModel):
    """Everything that determines a run (recorded in the JSON)."""

    frames: int = 200
    per_frame: bool = False
    conditions: list[str] = field(default_factory=lambda: list(CONDITIONS))
    solvers: list[str] = field(default_factory=lambda: list(SOLVER_NAMES))
    peer_timeout_ms: float = 5000.0
    cache_dir: str | None = None
    progress: bool = True
    #: each frame solved this many more times by each in-process solver after every
    #: solver's first solve, the last of them timed: the solve with its code and data in
    #: the caches ("hot"), beside the first ("cold", the table's times); 0: not measured
    hot_repeats: int = 0


def peer_match_max_error(sigma_px: float, width: int) -> float | None:
    """``match_max_error`` (edge-ratio tolerance) for the tetra3 family at centroid noise σ.

    Their database defaults (tetra3rs 0.001, cedar 0.002) suit σ ≲ 0.5 px: above that,
    patterns whose edge ratios moved by more than the tolerance are never looked up, and
    too large a tolerance makes every lookup slow. Tuned on 30–40 frames (seed 0, 1024 px)
    to ``5·σ/width`` (0.005 at σ = 1 px, 0.01 at 2 px): tetra3rs σ = 1: default 19/40
    correct, 0.003 39/40, 0.005 40/40; σ = 2: default 2/40, 0.005–0.012 37–38/40; cedar
    σ = 1: default 29/30, 0.005 30/30 (fastest); σ = 2: default 22/30, 0.008–0.012 30/30.
    ``None`` = keep the peer's default.

    >>> peer_match_max_error(0.1, 1024) is None, round(peer_match_max_error(2.0, 1024), 4)
    (True, 0.0098)
    """
    if sigma_px <= 0.5:
        return None
    return 5.0 * sigma_px / width


# --- solver adapters ---------------------------------------------------------------------


class Adapter:
    name = ""

    def setup(self, cond: Condition, camera) -> None:
        """Prepare for a (resolved) condition seen by ``camera``: catalogue, database, …"""

    def solve(self, frame: Frame) -> Outcome:
        raise NotImplementedError

    def info(self) -> dict[str, Any]:
        return {}

    def params(self) -> dict[str, Any]:
        """The settings used for the current condition (recorded per condition)."""
        return {}

    def close(self) -> None:
        pass


SOLVERS: dict[tuple[Any, ...], Any] = {}


def solver_for(mag_limit: float, sigma_px: float, camera, epoch: float = 2025.0,
               method: str = "nstar"):
    """Our :class:`starid.solver.Solver` for a visible limit, centroid σ and camera
    (memoised per process: the tracking and lost-in-space runs share one index).

    ``centroid_sigma_px`` is ``max(0.5, σ)``, as a user would configure a camera;
    ``method`` is the solver's matcher (``nstar``, ``triad``, ``bleif``).
    """
    from adfusion.starid.solver import Solver

    sigma = max(0.5, float(sigma_px))
    key = (float(mag_limit), sigma, camera.width, camera.height, round(camera.fov_x_deg, 9),
           float(epoch), method)
    if key not in SOLVERS:
        SOLVERS[key] = Solver(load_catalog(float(mag_limit), epoch), camera,
                               centroid_sigma_px=sigma, method=method)
    return SOLVERS[key]


class _Ours(Adapter):
    name = "ours"
    method = "nstar"

    def __init__(self, cfg: BenchConfig, camera=None) -> None:
        self.cfg = cfg
        self._builds: dict[str, dict[str, Any]] = {}
        self.solver = None
        self._params: dict[str, Any] = {}

    def setup(self, cond: Condition, camera) -> None:
        from adfusion.starid.index import PatternIndex

        limit = float(cond.mag_limit if cond.mag_limit is not None else self.cfg.mag_limit)
        s = solver_for(limit, float(cond.sigma_px or 0.0), camera, self.cfg.epoch,
                       self.method)
        base = getattr(self.cfg, "fov_deg", None)
        fov = "" if base is not None and abs(camera.fov_x_deg - base) < 1e-6 else \
            f", FOV {camera.fov_x_deg:.4g}°"
        label = f"V<{limit:g}, sigma={s.centroid_sigma_px:g}px{fov}"
        if label not in self._builds:
            t0 = time.perf_counter()  # the solver may have loaded its index from the cache
            PatternIndex.from_vectors(s.vectors, s.max_sep_rad, cache_tag=None)
            fresh = time.perf_counter() - t0
            self._builds[label] = {
                "catalog_stars": len(s.vectors), "index_build_s": round(s.index_build_s, 4),
                "index_build_fresh_s": round(fresh, 4),
                "index_nbytes": int(s.index.nbytes), "index_pairs": int(s.index.n_pairs)}
        s.warm_up()  # kernels loaded (or compiled) here, not in the first timed frames
        self.solver = s
        self._params = {"catalog": f"hipparcos V<{limit:g}",
                        "centroid_sigma_px": s.centroid_sigma_px}

    def params(self) -> dict[str, Any]:
        return self._params

    def _prior(self, frame: Frame):
        return None

    def solve(self, frame: Frame) -> Outcome:
        assert self.solver is not None
        prior = self._prior(frame)
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            sol = self.solver.solve(frame.xy, prior=prior)
        except Exception as e:  # a crash is a finding, not a reason to stop the run
            return Outcome(False, None, time.perf_counter() - t0, f"exception: {e!r}")
        dt, cpu = time.perf_counter() - t0, time.thread_time() - c0
        return Outcome(bool(sol.ok), sol.q_cam_icrs, dt, sol.reason, sol.time_s, sol.matches,
                        sol.covariance, cpu)

    def info(self) -> dict[str, Any]:
        return {"status": "ok", "indexes": self._builds}


def tracking_prior(frame: Frame, sigma_deg: float):
    """A filter-like prior for tracking: the true attitude tilted by a random error drawn
    from N(0, σ²) per axis, with that σ (deterministic per seed, frame and condition).
    On a rendered (streaked) frame the prior also carries the exposure's rotation
    (``smear_cam_rad`` = ω·T), as a filter with a gyro knows it.

    >>> f = Frame("x", 4, random_attitude(0, 4), np.zeros((0, 2)), np.zeros(0, np.int64), 0)
    >>> p = tracking_prior(f, 0.1)
    >>> from adfusion.starid import rotations as rot
    >>> float(np.degrees(rot.angle_between(p.q_cam_icrs, f.q_cam_icrs))) < 0.6, p.sigma_deg
    (True, 0.1)
    """
    from adfusion.starid import rotations as rot
    from adfusion.starid.solver import Prior

    rng = np.random.default_rng([frame.seed, frame.index, _cond_key(frame.condition), 1])
    dtheta = np.radians(sigma_deg) * rng.normal(size=3)
    smear = None
    if frame.omega_cam_rad_s is not None and frame.exposure_s > 0:
        smear = np.asarray(frame.omega_cam_rad_s, dtype=np.float64) * frame.exposure_s
    return Prior(rot.multiply(rot.exp_map(dtheta), frame.q_cam_icrs), float(sigma_deg),
                 smear_cam_rad=smear)


class _OursTracking(_Ours):
    """Ours with a prior (:func:`tracking_prior`): the tracking path, falling back to
    lost-in-space when it fails, as in a filter loop."""

    name = "ours_tracking"

    def __init__(self, cfg, camera=None, sigma_deg: float = 0.1) -> None:
        super().__init__(cfg, camera)
        self.sigma_deg = float(sigma_deg)

    def _prior(self, frame: Frame):
        return tracking_prior(frame, self.sigma_deg)

    def params(self) -> dict[str, Any]:
        return {**self._params, "prior_sigma_deg": self.sigma_deg}


class _OursMethod(_Ours):
    """Ours with another matcher (``Solver(method=...)``): ``ours_triad`` (Yee's triads),
    ``ours_bleif`` (Bleif's MusterPr reference-star patterns) — the same verification."""

    def __init__(self, cfg, camera=None, method: str = "triad") -> None:
        super().__init__(cfg, camera)
        self.method = method
        self.name = f"ours_{method}"

    def params(self) -> dict[str, Any]:
        return {**self._params, "method": self.method}


# ``--methods`` names → solver names
METHOD_SOLVERS = {"nstar": "ours", "triad": "ours_triad", "bleif": "ours_bleif"}


class _Tetra3rs(Adapter):
    name = "tetra3rs"

    def __init__(self, cfg: BenchConfig, camera, cache: Path) -> None:
        import tetra3rs

        self.t3 = tetra3rs
        self.cfg, self.camera, self.cache = cfg, camera, cache
        self._dbs: dict[tuple[float, float], Any] = {}
        self._db_info: dict[str, dict[str, Any]] = {}
        self.db = None
        self.kw: dict[str, Any] = {}

    def _database(self, mag_limit: float, fov_deg: float):
        key = (mag_limit, round(fov_deg, 6))
        if key in self._dbs:
            return self._dbs[key]
        from adfusion.starid.cache import cache_key

        params = {
            "tetra3rs": self.t3.__version__, "max_fov_deg": key[1],
            "star_max_magnitude": mag_limit + 0.5, "epoch": self.cfg.epoch,
        }  # fmt: skip
        path = self.cache / f"tetra3rs-db-{cache_key('tetra3rs-db', params)}.bin"
        t0 = time.perf_counter()
        built = not path.exists()
        if built:
            db = self.t3.SolverDatabase.generate_from_gaia(
                max_fov_deg=params["max_fov_deg"],
                star_max_magnitude=params["star_max_magnitude"],
                epoch_proper_motion_year=self.cfg.epoch)
            tmp = path.with_suffix(f".tmp{os.getpid()}")
            db.save_to_file(str(tmp))
            os.replace(tmp, path)
        else:
            db = self.t3.SolverDatabase.load_from_file(str(path))
        label = f"G<{params['star_max_magnitude']:g}"
        if key[1] != round(getattr(self.cfg, "fov_deg", key[1]), 6):
            label += f", FOV {key[1]:g}°"
        self._db_info[label] = {
            "path": str(path), "file_bytes": path.stat().st_size,
            "built_now": built, "build_or_load_s": round(time.perf_counter() - t0, 3),
            "num_stars": int(db.num_stars), "num_patterns": int(db.num_patterns),
            "params": params}
        self._dbs[key] = db
        return db

    def setup(self, cond: Condition, camera) -> None:
        limit = self.cfg.mag_limit if cond.mag_limit is None else cond.mag_limit
        self.camera = camera
        self.centre = np.array([(camera.width - 1) / 2, (camera.height - 1) / 2])
        self.db = self._database(float(limit), camera.fov_x_deg)
        self.kw = {
            "fov_estimate_deg": self.camera.fov_x_deg, "image_width": self.camera.width,
            "image_height": self.camera.height, "fov_max_error_deg": 0.5,
            "solve_timeout_ms": int(self.cfg.peer_timeout_ms),
        }  # fmt: skip
        mme = peer_match_max_error(float(cond.sigma_px or 0.0), self.camera.width)
        if mme is not None:
            self.kw["match_max_error"] = mme

    def to_peer(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Our pixel centres → tetra3rs (x, y) from the geometric image centre."""
        return np.ascontiguousarray(xy - self.centre)

    def solve(self, frame: Frame) -> Outcome:
        assert self.db is not None
        c = self.to_peer(frame.xy)
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            r = self.db.solve_from_centroids(c, **self.kw)
        except Exception as e:
            return Outcome(False, None, time.perf_counter() - t0, f"exception: {e!r}")
        dt, cpu = time.perf_counter() - t0, time.thread_time() - c0
        if not r:
            return Outcome(False, None, dt, str(r.status), r.solve_time_ms / 1e3, cpu_s=cpu)
        q = np.asarray(r.quaternion, dtype=np.float64)  # already q_cam_icrs (checked)
        return Outcome(True, q / np.linalg.norm(q), dt, "", r.solve_time_ms / 1e3, cpu_s=cpu)

    def info(self) -> dict[str, Any]:
        return {"status": "ok", "version": self.t3.__version__, "databases": self._db_info}

    def params(self) -> dict[str, Any]:
        return {"database": f"G<{self.db.parameters.get('star_max_magnitude', '?')}"
                if self.db is not None else None, **self.kw}


_CEDAR_WORKER = textwrap.dedent('''
    import json, logging, sys, time
    out = sys.stdout
    sys.stdout = sys.stderr  # anything the library prints must not corrupt the protocol
    lg = logging.getLogger("tetra3.Tetra3")
    lg.addHandler(logging.NullHandler())
    lg.setLevel(logging.WARNING)
    lg.propagate = False
    import numpy as np
    import tetra3
    from importlib.metadata import version
    t0 = time.perf_counter()
    t3 = tetra3.Tetra3()
    props = {k: (v.tolist() if hasattr(v, "tolist") else v)
             for k, v in t3.database_properties.items()}
    out.write(json.dumps({"ready": True, "version": version("cedar-solve"),
                          "numpy": np.__version__, "load_s": time.perf_counter() - t0,
                          "database": props}) + "\\n")
    out.flush()
    for line in sys.stdin:
        msg = json.loads(line)
        yx = np.asarray(msg["yx"], dtype=np.float64).reshape(-1, 2)
        t0 = time.perf_counter()
        try:
            r = t3.solve_from_centroids(yx, msg["size"], **msg["kw"])
            err = ""
        except Exception as e:
            r, err = {"status": -1}, repr(e)
        dt = time.perf_counter() - t0
        res = {"id": msg["id"], "t_s": dt, "status": int(r.get("status") or -1), "error": err}
        for k in ("RA", "Dec", "Roll", "FOV", "Prob", "Matches", "T_solve"):
            v = r.get(k)
            res[k] = None if v is None else float(v)
        out.write(json.dumps(res) + "\\n")
        out.flush()
''')

_CEDAR_STATUS = {1: "match_found", 2: "no_match", 3: "timeout", 4: "cancelled", 5: "too_few",
                 -1: "error"}


def ensure_cedar_venv(cache: Path, timeout_s: float = 900.0) -> Path:
    """The Python of a venv with ``cedar-solve`` (created on first use); raises on failure.

    A ``.ok`` stamp marks a complete install, so an interrupted one is redone.
    """
    venv = cache / "cedar-venv"
    py = venv / "bin" / "python"
    stamp = venv / ".ok"
    if stamp.exists() and py.exists():
        return py
    if venv.exists():
        shutil.rmtree(venv)
    print(f"bench starid: creating the cedar-solve venv in {venv} (once) …", file=sys.stderr)
    base = sys.executable  # the running Python: its version is known to work here
    steps = [[base, "-m", "venv", str(venv)],
             [str(py), "-m", "pip", "install", "--disable-pip-version-check", "-q",
              "cedar-solve"]]
    for cmd in steps:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
        if p.returncode != 0:
            tail = (p.stderr or p.stdout).strip().splitlines()[-3:]
            raise RuntimeError(f"{' '.join(cmd[:3])} … failed: {' | '.join(tail)}")
    stamp.write_text("ok\n")
    return py


class _Cedar(Adapter):
    name = "cedar"

    def __init__(self, cfg: BenchConfig, camera, cache: Path) -> None:
        self.cfg, self.camera = cfg, camera
        py = ensure_cedar_venv(cache)
        self._log = tempfile.TemporaryFile(mode="w+")
        self.proc = subprocess.Popen(
            [str(py), "-u", "-c", _CEDAR_WORKER], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=self._log, text=True, bufsize=1)
        self.hello = self._read()
        self.kw: dict[str, Any] = {}
        self._n = 0
        self._dead = ""

    def _read(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            self._log.seek(0)
            tail = self._log.read().strip().splitlines()[-3:]
            raise RuntimeError(f"cedar worker exited: {' | '.join(tail)}")
        return json.loads(line)

    def setup(self, cond: Condition, camera) -> None:
        self.camera = camera
        self.kw = {"fov_estimate": self.camera.fov_x_deg, "fov_max_error": 0.5,
                   "solve_timeout": self.cfg.peer_timeout_ms}
        mme = peer_match_max_error(float(cond.sigma_px or 0.0), self.camera.width)
        if mme is not None:
            self.kw["match_max_error"] = mme

    @staticmethod
    def to_peer(xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Our pixel centres → tetra3 (y, x) from the top-left corner of the image."""
        return xy[:, ::-1] + 0.5

    def solve(self, frame: Frame) -> Outcome:
        from adfusion.starid import rotations as rot

        assert self.proc.stdin is not None
        if self._dead:
            return Outcome(False, None, 0.0, f"error: {self._dead}")
        self._n += 1
        msg = {"id": self._n, "yx": self.to_peer(frame.xy).tolist(),
               "size": [self.camera.height, self.camera.width], "kw": self.kw}
        try:
            self.proc.stdin.write(json.dumps(msg) + "\n")
            self.proc.stdin.flush()
            r = self._read()
        except (OSError, RuntimeError, json.JSONDecodeError) as e:
            self._dead = f"cedar worker died: {e}"
            return Outcome(False, None, 0.0, f"error: {self._dead}")
        if r.get("id") != self._n:
            raise RuntimeError(f"cedar worker out of step: sent {self._n}, got {r.get('id')}")
        status = _CEDAR_STATUS.get(r["status"], str(r["status"]))
        own = None if r["T_solve"] is None else r["T_solve"] / 1e3
        if r["status"] != 1 or r["RA"] is None:
            return Outcome(False, None, r["t_s"], status + (f": {r['error']}" if r["error"]
                                                             else ""), own)
        q = rot.q_cam_icrs_from_radec_roll(*np.radians([r["RA"], r["Dec"], -r["Roll"]]))
        return Outcome(True, q, r["t_s"], "", own)

    def info(self) -> dict[str, Any]:
        return {"status": "ok", "version": self.hello.get("version"),
                "numpy": self.hello.get("numpy"), "database": self.hello.get("database"),
                "database_load_s": round(self.hello.get("load_s", 0.0), 3),
                "worker_error": self._dead or None}

    def params(self) -> dict[str, Any]:
        return {"database": "default_database", **self.kw}

    def close(self) -> None:
        with contextlib.suppress(Exception):
            if self.proc.stdin:
                self.proc.stdin.close()
            self.proc.wait(timeout=10)
        if self.proc.poll() is None:
            self.proc.kill()
        self._log.close()


_CATALOGS: dict[tuple[float, float], Any] = {}


def load_catalog(mag_limit: float, epoch: float):
    from adfusion.starid.catalog import Catalog

    key = (mag_limit, epoch)
    if key not in _CATALOGS:
        _CATALOGS[key] = Catalog.hipparcos(mag_limit=mag_limit, epoch=epoch)
    return _CATALOGS[key]


def cache_root(cfg: BenchConfig) -> tuple[Path, tempfile.TemporaryDirectory | None]:
    if cfg.cache_dir:
        p = Path(cfg.cache_dir).expanduser()
        p.mkdir(parents=True, exist_ok=True)
        return p, None
    from adfusion.starid.cache import cache_dir

    root = cache_dir()
    if root is not None:
        return root, None
    tmp = tempfile.TemporaryDirectory(prefix="adfusion-bench-")
    return Path(tmp.name), tmp


# --- the run -----------------------------------------------------------------------------


def conversion_check(adapters: Sequence[Adapter], cfg: BenchConfig, camera,
                      n: int = 3) -> dict[str, dict[str, Any]]:
    """Noise-free frames at the base settings: every solver's error must be ≈ 0.

    Doubles as the warm-up, so first-call costs stay out of the timings.
    """
    from adfusion.starid import rotations as rot

    cond = Condition("conversion-check", sigma_px=0.0, mag_limit=cfg.mag_limit)
    cat = load_catalog(cfg.mag_limit, cfg.epoch)
    frames = [make_frame(cat, camera, cond, seed=cfg.seed + 10_007, index=i, mag_noise=0.0)
              for i in range(n)]
    out: dict[str, dict[str, Any]] = {}
    for a in adapters:
        a.setup(cond, camera)
        errs = []
        for f in frames:
            o = a.solve(f)
            if o.ok and o.q is not None:
                errs.append(float(np.degrees(rot.angle_between(o.q, f.q_cam_icrs))) * 3600)
        worst = max(errs) if errs else None
        out[a.name] = {"frames": n, "solved": len(errs),
                       "max_error_arcsec": None if worst is None else round(worst, 3),
                       "passed": worst is not None and worst < _CHECK_LIMIT_ARCSEC}
    return out


def make_adapters(cfg: BenchConfig, camera, cache: Path) -> tuple[list[Adapter],
                                                                     dict[str, Any]]:
    adapters: list[Adapter] = []
    skipped: dict[str, Any] = {}
    for name in cfg.solvers:
        try:
            if name == "ours":
                adapters.append(_Ours(cfg, camera))
            elif name == "ours_tracking":
                adapters.append(_OursTracking(cfg, camera,
                                              getattr(cfg, "prior_sigma_deg", 0.1)))
            elif name in ("ours_triad", "ours_bleif"):
                adapters.append(_OursMethod(cfg, camera, name.removeprefix("ours_")))
            elif name == "tetra3rs":
                adapters.append(_Tetra3rs(cfg, camera, cache))
            elif name == "cedar":
                adapters.append(_Cedar(cfg, camera, cache))
            else:
                raise ValueError(f"unknown solver {name!r} (choose from "
                                 f"{(*SOLVER_NAMES, 'ours_tracking', 'ours_triad', 'ours_bleif')})")
        except ImportError as e:
            skipped[name] = {"status": "skipped", "reason": f"not importable: {e}"}
        except (RuntimeError, OSError, subprocess.SubprocessError, json.JSONDecodeError) as e:
            skipped[name] = {"status": "skipped", "reason": str(e)}
    return adapters, skipped


def run_benchmark(cfg: BenchConfig) -> dict[str, Any]:
    """Run the benchmark and return the result document (no printing except progress).

    >>> res = run_benchmark(BenchConfig(frames=2, conditions=["clean"], solvers=["ours"],
    ...                                 progress=False))
    >>> sorted(res)
    ['code', 'conditions', 'config', 'conversion_check', 'machine', 'schema', 'solvers', 'wall_s']
    """
    from tqdm import tqdm

    from adfusion import starid
    unknown = [c for c in cfg.conditions if c not in CONDITIONS]
    if unknown:
        raise ValueError(f"unknown condition(s) {unknown}; choose from {list(CONDITIONS)}")
    if cfg.frames < 1:
        raise ValueError("frames must be ≥ 1")
    t_start = time.perf_counter()
    camera = starid.Camera.pinhole(cfg.width, cfg.height, fov_x_deg=cfg.fov_deg)
    cache, tmp = cache_root(cfg)
    adapters, skipped = make_adapters(cfg, camera, cache)
    try:
        check = conversion_check(adapters, cfg, camera)
        conds = [CONDITIONS[c].resolved(cfg.sigma_px, cfg.mag_limit) for c in cfg.conditions]
        results = []
        bar = tqdm(total=cfg.frames * len(conds), file=sys.stderr, unit="frame",
                   disable=None if cfg.progress else True, desc="bench starid")
        for cond in conds:
            assert cond.mag_limit is not None
            cat = load_catalog(cond.mag_limit, cfg.epoch)
            cam = camera_for(cond, cfg.width, cfg.height, cfg.fov_deg)
            for a in adapters:
                a.setup(cond, cam)
            frames: list[Frame] = []
            outcomes: dict[str, list[Outcome]] = {a.name: [] for a in adapters}
            hot: dict[str, list[float | None]] = {a.name: [] for a in adapters}
            bar.set_postfix_str(cond.name)
            for i in range(cfg.frames):
                f = make_frame(cat, cam, cond, cfg.seed, i, cfg.mag_noise)
                frames.append(f)
                for a in adapters:
                    outcomes[a.name].append(a.solve(f))
                if cfg.hot_repeats > 0:
                    for a in adapters:
                        if outcomes[a.name][-1].cpu_s is None:
                            continue  # another process's solver (cedar): no CPU time here
                        for _ in range(cfg.hot_repeats):
                            o = a.solve(f)
                        hot[a.name].append(o.cpu_s)
                bar.update(1)
            tol = max(cfg.tol_px, cfg.tol_sigma * float(cond.sigma_px or 0.0))
            per = {name: summarize(frames, o, cam, tol, per_frame=cfg.per_frame)
                   for name, o in outcomes.items()}
            n_true = np.array([f.n_true for f in frames])
            entry: dict[str, Any] = {
                "name": cond.name, "description": cond.description,
                "params": cond.params(),
                "frames": cfg.frames,
                "tolerance_px": tol,
                "catalog_stars_per_frame": {
                    "median": float(np.median(n_true)), "min": int(n_true.min()),
                    "max": int(n_true.max()), "ge3": int((n_true >= 3).sum()),
                    "ge4": int((n_true >= 4).sum())},
                "centroids_per_frame_median": float(np.median([len(f.xy) for f in frames])),
                "solver_params": {a.name: a.params() for a in adapters},
                "results": per,
                "time_ratio_ours_over_peer": time_ratios(per),
                # in-process solvers' CPU time (a loaded machine's other processes left out)
                "cpu_ratio_ours_over_peer": time_ratios(per, "cpu_time_ms"),
                "cpu_p95_ratio_ours_over_peer": time_ratios(per, "cpu_time_ms", "p95"),
            }  # fmt: skip
            if cfg.hot_repeats > 0:
                entry.update(_hot_figures(hot))
            results.append(entry)
        bar.close()
    finally:
        for a in adapters:
            a.close()
        if tmp is not None:
            tmp.cleanup()
    solvers = {a.name: a.info() for a in adapters}
    solvers.update(skipped)
    doc = {
        "schema": "adfusion.bench.starid/1",
        "machine": machine_info(),
        "code": code_version(),
        "config": asdict(cfg),
        "solvers": {name: solvers[name] for name in cfg.solvers if name in solvers},
        "conversion_check": check,
        "conditions": results,
        "wall_s": round(time.perf_counter() - t_start, 2),
    }
    return doc


def _hot_figures(hot: dict[str, list[float | None]]) -> dict[str, Any]:
    """The hot CPU times of the solvers that measure one (:attr:`BenchConfig.hot_repeats`)
    and our ratios to them, as a condition's entry holds them.

    >>> f = _hot_figures({"ours": [1e-3, 3e-3], "tetra3rs": [2e-3, 2e-3], "cedar": [None]})
    >>> f["hot_cpu_time_ms"]["ours"]["median"], f["hot_cpu_ratio_ours_over_peer"]
    (2.0, {'tetra3rs': 1.0})
    """
    per = {name: {"cpu_time_ms": _time_stats(t)} for name, t in hot.items()
           if t and all(x is not None for x in t)}
    return {"hot_cpu_time_ms": {name: r["cpu_time_ms"] for name, r in per.items()},
            "hot_cpu_ratio_ours_over_peer": time_ratios(per, "cpu_time_ms")}


def time_ratios(per: dict[str, dict[str, Any]], key: str = "time_ms",
                stat: str = "median") -> dict[str, float | None]:
    """Our ``stat`` of ``key`` (``time_ms``, or ``cpu_time_ms`` where both have it) over
    each peer's."""
    if "ours" not in per or key not in per["ours"]:
        return {}
    ours = per["ours"][key][stat]
    out: dict[str, float | None] = {}
    for name, r in per.items():
        if name == "ours" or key not in r:
            continue
        peer = r[key][stat]
        out[name] = None if not ours or not peer else round(ours / peer, 3)
    return out


# --- output ------------------------------------------------------------------------------


def _f(x: float | None, fmt: str) -> str:
    return "—" if x is None else format(x, fmt)


def format_table(doc: dict[str, Any]) -> str:
    """The human-readable report of :func:`run_benchmark`'s result."""
    cfg, m = doc["config"], doc["machine"]
    lines = [
        f"Star identification benchmark: {cfg['frames']} frames per condition, seed "
        f"{cfg['seed']}, {cfg['width']}x{cfg['height']} px, FOV {cfg['fov_deg']:g}°, "
        f"stars V < {cfg['mag_limit']:g}, base σ {cfg['sigma_px']:g} px, "
        f"correct = frame shift < max({cfg['tol_px']:g} px, {cfg['tol_sigma']:g}σ)",
        f"machine: {m['cpu']} ({m['cores']} cores), Python {m['python']}; starid "
        f"{doc['code']['git_commit']}{' + local changes' if doc['code']['git_dirty'] else ''}"
        f" (sources {doc['code']['sources_sha256']})",
    ]
    for name, s in doc["solvers"].items():
        if s.get("status") != "ok":
            lines.append(f"  {name}: SKIPPED — {s.get('reason')}")
        elif name == "ours":
            for key, b in s["indexes"].items():
                lines.append(f"  ours [{key}]: index {b['index_nbytes'] / 2**20:.1f} MiB "
                             f"({b['index_pairs']} pairs, {b['catalog_stars']} stars); "
                             f"build {b['index_build_fresh_s'] * 1e3:.0f} ms uncached, "
                             f"{b['index_build_s'] * 1e3:.0f} ms in this run (cache)")
        elif name == "tetra3rs":
            for key, b in s["databases"].items():
                lines.append(f"  tetra3rs {s['version']} [{key}]: database "
                             f"{b['file_bytes'] / 2**20:.1f} MiB ({b['num_stars']} stars, "
                             f"{b['num_patterns']} patterns), "
                             f"{'built' if b['built_now'] else 'loaded'} in "
                             f"{b['build_or_load_s']:.2f} s")
        elif name == "cedar":
            db = s.get("database") or {}
            lines.append(f"  cedar-solve {s['version']} (numpy {s['numpy']}): default "
                         f"database, FOV {db.get('min_fov')}–{db.get('max_fov')}°, "
                         f"{db.get('num_patterns')} patterns, mag ≤ "
                         f"{_f(db.get('star_max_magnitude'), '.2f')}")
    chk = ", ".join(f"{k} {_f(v['max_error_arcsec'], '.2f')}″"
                            f"{'' if v['passed'] else ' FAILED'}"
                    for k, v in doc["conversion_check"].items())
    lines.append(f"conversion check (noise-free frames, max attitude error): {chk}")
    head = (f"{'condition':<14} {'solver':<13} {'avail %':>8} {'err %':>6} {'err ≤95%':>8} "
            f"{'t med ms':>9} {'t p95':>8} {'t max':>8} {'ours/peer':>9}")
    lines += ["", head, "-" * len(head)]
    for c in doc["conditions"]:
        for k, (name, r) in enumerate(c["results"].items()):
            ratio = c["time_ratio_ours_over_peer"].get(name)
            lines.append(
                f"{c['name'] if k == 0 else '':<14} {name:<13} "
                f"{_f(r['availability_pct'], '.1f'):>8} {_f(r['error_rate_pct'], '.1f'):>6} "
                f"{_f(r['error_rate_upper95_pct'], '.2f'):>8} "
                f"{_f(r['time_ms']['median'], '.2f'):>9} {_f(r['time_ms']['p95'], '.2f'):>8} "
                f"{_f(r['time_ms']['max'], '.1f'):>8} {_f(ratio, '.2f'):>9}")
        cs = c["catalog_stars_per_frame"]
        if CONDITIONS.get(c["name"], Condition("")).coverage:
            avail = "; ".join(
                f"{name} {_f(r['availability_ge3_pct'], '.1f')} / "
                f"{_f(r['availability_ge4_pct'], '.1f')} %"
                for name, r in c["results"].items())
            lines.append(f"{'':<14} frames with ≥3 / ≥4 catalogue stars: {cs['ge3']} / "
                         f"{cs['ge4']} of {c['frames']} (median {cs['median']:g}); "
                         f"availability on those: {avail}")
    cpu_rows = [(c["name"], name, r["cpu_time_ms"], c.get("cpu_ratio_ours_over_peer", {}),
                 c.get("cpu_p95_ratio_ours_over_peer", {}))
                for c in doc["conditions"] for name, r in c["results"].items()
                if "cpu_time_ms" in r]
    if cpu_rows:
        head = (f"{'condition':<14} {'solver':<13} {'cpu med ms':>10} {'cpu p95':>8} "
                f"{'ours/peer med':>13} {'ours/peer p95':>13}")
        lines += ["", "CPU time of the solve (this thread; solvers in this process):", head,
                  "-" * len(head)]
        last = None
        for cond, name, t, rm, rp in cpu_rows:
            lines.append(f"{cond if cond != last else '':<14} {name:<13} "
                         f"{_f(t['median'], '.3f'):>10} {_f(t['p95'], '.3f'):>8} "
                         f"{_f(rm.get(name), '.2f'):>13} {_f(rp.get(name), '.2f'):>13}")
            last = cond
    hot_rows = [(c["name"], name, t, c["hot_cpu_ratio_ours_over_peer"].get(name))
                for c in doc["conditions"] for name, t in c.get("hot_cpu_time_ms", {}).items()]
    if hot_rows:
        lines += ["", f"CPU time of the same frame solved again ({cfg['hot_repeats']}×, the "
                  "last timed: code and data in the caches):"]
        for cond, name, t, r in hot_rows:
            lines.append(f"{cond:<14} {name:<13} {_f(t['median'], '.3f'):>10} "
                         f"{_f(t['p95'], '.3f'):>8} {_f(r, '.2f'):>13}")
    lines.append("")
    lines.append("avail = correct attitude accepted; err = wrong attitude accepted, with its "
                 "one-sided 95 % Clopper–Pearson bound; times over all frames, the solvers "
                 "interleaved frame by frame, measured in each solver's own process; "
                 "ours/peer = ratio of median times (< 1: ours faster).")
    return "\n".join(lines)


# --- command line --------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``bench starid`` options to ``parser``.

    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> p.parse_args(["--json"]).json
    '-'
    """
    d = BenchConfig()
    parser.add_argument("--frames", type=int, default=d.frames,
                        help=f"frames per condition (default {d.frames})")
    parser.add_argument("--seed", type=int, default=d.seed, help="random seed (default 0)")
    parser.add_argument("--width", type=int, default=d.width, help="image width, px")
    parser.add_argument("--height", type=int, default=d.height, help="image height, px")
    parser.add_argument("--fov", type=float, default=d.fov_deg, dest="fov_deg",
                        help=f"horizontal FOV, degrees (default {d.fov_deg:g})")
    parser.add_argument("--mag-limit", type=float, default=d.mag_limit,
                        help=f"visible stars V < this (default {d.mag_limit:g})")
    parser.add_argument("--sigma", type=float, default=d.sigma_px, dest="sigma_px",
                        help=f"base centroid noise σ, px (default {d.sigma_px:g})")
    parser.add_argument("--mag-noise", type=float, default=d.mag_noise,
                        help=f"magnitude noise σ for the ordering (default {d.mag_noise:g})")
    parser.add_argument("--tol-px", type=float, default=d.tol_px,
                        help="largest shift of the frame's corners/centre (px) for an "
                             f"attitude to count as correct (default {d.tol_px:g})")
    parser.add_argument("--tol-sigma", type=float, default=d.tol_sigma,
                        help="... or this many centroid σ, if larger (default "
                             f"{d.tol_sigma:g})")
    parser.add_argument("--per-frame", action="store_true",
                        help="add per-frame outcomes (correct, error, time) to the JSON")
    parser.add_argument("--conditions", default=",".join(CONDITIONS),
                        help="comma-separated subset of: " + ", ".join(CONDITIONS))
    parser.add_argument("--solvers", default=",".join(SOLVER_NAMES),
                        help="comma-separated subset of: " + ", ".join(SOLVER_NAMES))
    parser.add_argument("--methods", default=None, metavar="LIST",
                        help="our matchers to compare, comma-separated subset of nstar, "
                             "triad, bleif (runs these instead of --solvers' 'ours'; the "
                             "peers only when --solvers names them)")
    parser.add_argument("--peer-timeout-ms", type=float, default=d.peer_timeout_ms,
                        help="solve timeout passed to tetra3rs and cedar (default 5000)")
    parser.add_argument("--cache-dir", default=None,
                        help="where the tetra3rs database and the cedar venv are kept "
                             "(default: the adfusion cache, ~/.cache/adfusion)")
    parser.add_argument("--json", nargs="?", const="-", default=None, metavar="PATH",
                        help="write the results as JSON to PATH (or to stdout instead of "
                             "the table when no PATH is given)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--hot", type=int, default=0, metavar="N", dest="hot_repeats",
                        help="also solve each frame N more times per in-process solver and "
                             "report the last one's CPU time (code and data in the caches; "
                             "the main times stay each frame's first solve)")


def config_from_args(args: argparse.Namespace) -> BenchConfig:
    """A :class:`BenchConfig` from parsed :func:`add_arguments` options."""
    return BenchConfig(
        frames=args.frames, seed=args.seed, width=args.width, height=args.height,
        fov_deg=args.fov_deg, mag_limit=args.mag_limit, sigma_px=args.sigma_px,
        mag_noise=args.mag_noise, tol_px=args.tol_px, tol_sigma=args.tol_sigma,
        per_frame=args.per_frame,
        conditions=[c.strip() for c in args.conditions.split(",") if c.strip()],
        solvers=_solver_names(args),
        peer_timeout_ms=args.peer_timeout_ms, cache_dir=args.cache_dir,
        progress=not args.no_progress, hot_repeats=getattr(args, "hot_repeats", 0),
    )  # fmt: skip


def _solver_names(args: argparse.Namespace) -> list[str]:
    """``--solvers``, with ``--methods`` (if given) in place of ``ours`` and the default
    peers left out."""
    named = [s.strip() for s in args.solvers.split(",") if s.strip()]
    methods = getattr(args, "methods", None)
    if not methods:
        return named
    out = []
    for m in (x.strip() for x in methods.split(",") if x.strip()):
        if m not in METHOD_SOLVERS:
            raise ValueError(f"--methods: unknown method {m!r} (choose from "
                             f"{', '.join(METHOD_SOLVERS)})")
        out.append(METHOD_SOLVERS[m])
    explicit = args.solvers != ",".join(SOLVER_NAMES)
    return out + [s for s in named if explicit and s != "ours"]


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Run from parsed options: the table on stdout, JSON per ``--json``; returns the result."""
    doc = run_benchmark(config_from_args(args))
    text = json.dumps(doc, indent=2)
    if args.json == "-":
        print(text)
    else:
        print(format_table(doc))
        if args.json:
            Path(args.json).write_text(text + "\n")
    return doc


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m adfusion.bench.starid [options]``."""
    p = argparse.ArgumentParser(prog="adfusion bench starid",
                                description="Lost-in-space star identification benchmark: "
                                            "ours vs tetra3rs vs cedar-solve.")
    add_arguments(p)
    args = p.parse_args(argv)
    try:
        run(args)
    except ValueError as e:
        print(f"adfusion bench starid: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
