"""Lost-in-space star identification: detections + camera → verified attitude.

The pipeline for one frame (renken.md §4–§9, with a verification stage of our own):

1. take the brightest ``n_max`` detections (3…6) as the pattern, closest pair first;
2. enumerate every catalogue assignment consistent with all pair distances
   (:mod:`starid.nstar`; the count is Renken's ``matching_counter``);
3. verify each assignment: Wahba attitude, project the catalogue, match the other
   detections, and compute the false-match probability (:mod:`starid.verify`);
4. accept when exactly one attitude survives below ``p_false_max``; several surviving
   attitudes → ``not ok``, reason ``ambiguous``, all listed in ``candidates``;
5. otherwise Renken's Not-Modus: every (n−1)-star sub-pattern, then every (n−2)-star one
   (never fewer than 3 stars), then fainter detections swapped in — in a fixed order, with
   the path that succeeded recorded in ``Solution.path``.

An unknown focal length (``fov_error_deg``) is handled by a grid of focal scales whose
spacing the windows absorb, then a least-squares refinement of the focal length from all
matched stars.

Example:
    >>> import numpy as np
    >>> from adfusion import starid
    >>> from adfusion.starid import rotations as rot
    >>> cat = starid.Catalog.hipparcos(mag_limit=5.5)
    >>> cam = starid.Camera.pinhole(1024, 768, 15.0)
    >>> q = rot.q_cam_icrs_from_radec_roll(*np.radians([10.0, 60.0, 20.0]))
    >>> v = rot.rotate(q, cat.vectors)
    >>> xy = cam.vectors_to_pixels(v[v[:, 2] > 0])
    >>> xy = xy[cam.in_frame(xy)]
    >>> order = np.argsort(cat.mag[v[:, 2] > 0][cam.in_frame(cam.vectors_to_pixels(
    ...     v[v[:, 2] > 0]))])
    >>> sol = starid.Solver(cat, cam).solve(xy[order])
    >>> sol.ok, bool(np.degrees(rot.angle_between(sol.q_cam_icrs, q)) < 1e-6)
    (True, True)
"""

from __future__ import annotations

import hashlib
import itertools
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from adfusion.starid import kernels
from adfusion.starid import rotations as rot
from adfusion.starid.attitude import refine_streaked, streak_vectors, wahba_near, wahba_unit
from adfusion.starid.calibrate import fit_camera
from adfusion.starid.camera import Camera
from adfusion.starid.index import PatternIndex
from adfusion.starid.nstar import (
    Pattern,
    WorkBudgetExceeded,
    chirality_of,
    closest_pair_first,
    match_faithful,
    match_indexed,
)
from adfusion.starid.search_order import combination_order
from adfusion.starid.verify import DENSITY_SAFETY, binomial_tail
from adfusion.starid.view import stars_in_view
from numpy.typing import NDArray
from scipy.spatial import cKDTree

__all__ = ["Candidate", "Prior", "Solution", "Solver"]

_3_SQRT2 = 3.0 * math.sqrt(2.0)
_CONE_SPARE_RAD = math.radians(2.0)  # extra radius of the cached catalogue cone


@dataclass(frozen=True)
class Prior:
    """An attitude prior for tracking: ``q_cam_icrs`` with a 1-σ uncertainty (deg).

    ``sigma_deg`` is the largest 1-σ attitude error about any axis (a filter's
    ``search_cone_deg(k=1)``). ``k`` sets the gate in σ. ``smear_cam_rad``, when known
    (a gyro's rate times the exposure), is the rotation vector (rad, camera axes) the
    camera turns through during the exposure: stars are then streaks, and a detection may
    be any piece of one, so tracking trusts it only across the streak
    (:func:`starid.attitude.refine_streaked`) and its covariance says so.

    >>> p = Prior([1.0, 0.0, 0.0, 0.0], 0.05, smear_cam_rad=[0.0, 0.0, 0.01])
    >>> p.smear_cam_rad.tolist()
    [0.0, 0.0, 0.01]
    """

    q_cam_icrs: NDArray[np.float64]
    sigma_deg: float
    k: float = 3.0
    smear_cam_rad: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        q = np.asarray(self.q_cam_icrs, dtype=np.float64)
        if q.shape != (4,):
            raise ValueError("Prior.q_cam_icrs must be a quaternion [w,x,y,z]")
        try:
            q = rot.normalize(q)
        except ValueError:
            raise ValueError("Prior.q_cam_icrs must be a finite, non-zero quaternion "
                             "[w,x,y,z]") from None
        if not (math.isfinite(self.sigma_deg) and self.sigma_deg > 0):
            raise ValueError(f"Prior.sigma_deg must be positive, got {self.sigma_deg}")
        if not (isinstance(self.k, int | float | np.floating | np.integer)
                and math.isfinite(self.k) and self.k > 0):
            raise ValueError(f"Prior.k (the gate in σ) must be a finite number > 0, "
                             f"got {self.k!r}")
        object.__setattr__(self, "q_cam_icrs", q)
        if self.smear_cam_rad is not None:
            sm = np.asarray(self.smear_cam_rad, dtype=np.float64)
            if sm.shape != (3,) or not np.isfinite(sm).all():
                raise ValueError("Prior.smear_cam_rad must be a finite rotation vector (3,), "
                                 f"got {self.smear_cam_rad!r}")
            object.__setattr__(self, "smear_cam_rad", sm)


@dataclass(frozen=True)
class Candidate:
    """One verified geometric match (an entry of the operator-confirmation list).

    ``predicted_xy`` / ``predicted_ids`` — the catalogue projected into the frame at this
    attitude, for overlays — are computed on first use, not in the solve's hot path.
    """

    q_cam_icrs: NDArray[np.float64]
    matches: list[tuple[int, int]]  # (detection index, catalogue id)
    residuals_rad: NDArray[np.float64]
    p_false: float
    n_pattern: int
    camera: Camera
    covariance: NDArray[np.float64]  # 3×3, camera frame, rad²
    _projector: Callable[[NDArray, Camera], tuple[NDArray, NDArray]] = field(
        repr=False, compare=False, default=None)

    @cached_property
    def _predicted(self) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        return self._projector(self.q_cam_icrs, self.camera)

    @property
    def predicted_xy(self) -> NDArray[np.float64]:
        return self._predicted[0]

    @property
    def predicted_ids(self) -> NDArray[np.int64]:
        return self._predicted[1]

    @property
    def radec_roll_deg(self) -> tuple[float, float, float]:
        return tuple(float(np.degrees(a)) for a in rot.radec_roll_from_q_cam_icrs(
            self.q_cam_icrs))  # type: ignore[return-value]


@dataclass(frozen=True)
class Solution:
    """Result of :meth:`Solver.solve` (DESIGN.md "Public API")."""

    ok: bool
    reason: str = ""
    q_cam_icrs: NDArray[np.float64] | None = None
    matches: list[tuple[int, int]] = field(default_factory=list)
    matching_counter: int = 0
    covariance: NDArray[np.float64] | None = None
    mode: str = "lost-in-space"
    time_s: float = 0.0
    p_false: float | None = None
    path: str = ""
    candidates: list[Candidate] = field(default_factory=list)
    residuals_rad: NDArray[np.float64] | None = None
    camera: Camera | None = None
    n_detections: int = 0
    patterns_tried: int = 0

    @property
    def ra_dec_roll_deg(self) -> tuple[float, float, float] | None:
        """Boresight RA, Dec and roll (deg; roll as in :mod:`starid.rotations`)."""
        if self.q_cam_icrs is None:
            return None
        return tuple(float(np.degrees(a)) for a in rot.radec_roll_from_q_cam_icrs(
            self.q_cam_icrs))  # type: ignore[return-value]

    @property
    def rms_residual_arcsec(self) -> float | None:
        if self.residuals_rad is None or len(self.residuals_rad) == 0:
            return None
        return float(np.degrees(np.sqrt(np.mean(self.residuals_rad**2))) * 3600)


class Solver:
    """Lost-in-space identification against a catalogue for one camera.

    Args:
        catalog: a :class:`starid.Catalog` (anything with ``vectors`` and ``ids``).
        camera: the :class:`starid.Camera` (its focal length is the FOV estimate).
        tolerance_deg: pair-distance tolerance; default from the camera and
            ``centroid_sigma_px``: 3·√2·σ·pixel scale plus 0.003° for lens residuals.
        centroid_sigma_px: 1-σ centroid error, used for the tolerance, match radius and
            covariance.
        n_max, n_min: pattern sizes (renken.md: 3…6).
        p_false_max: acceptance threshold on the false-match probability.
        fov_error_deg: ± uncertainty of the camera's horizontal FOV (0 = known).
        faithful: use Renken's reference nested loops instead of the index (slow).
        n_bands: Renken's declination sub-catalogues (1 = none); results are identical.
        dec_check: Renken's declination-difference pre-check (faithful mode only).
        max_detections: the brightest detections considered (the rest are ignored).
        max_patterns: Not-Modus budget (patterns tried per focal scale).
        max_fix_sigma_px: a tracking fix less certain than this is refused: its 1-σ
            error moves the frame's corners by more than this many pixels (two stars close
            together leave the roll open; such a fix would misplace the frame's edges).
        max_tracking_cone_deg: a prior looser than this (k·σ) goes straight to
            lost-in-space: beyond it, associating by prediction is no longer safe.
        p_false_max_tracking: acceptance threshold with a prior. Tracking asks a much
            narrower question than lost-in-space (are these the predicted stars?), a
            filter's innovation gate checks the fix again, and two-star frames must be
            usable: 1e-4 by default.
        whole_streak_px: with a prior's ``smear_cam_rad``, streaks up to this long (px)
            are taken as detected whole and a longer one's pieces as at least this long
            (:func:`starid.attitude.refine_streaked`). 20 px keeps the arcs of a spinning
            payload (up to 18 px on the OEDIPUS-like log, detected whole: with 8 px the
            60 s replay's RMS error grew from 0.0202° to 0.0224°) and catches the 34–68 px
            streaks of the rate sweep, which break into pieces (an isotropic fit accepted
            pieces 10 px off; with this model, 0 wrong in 6000 rendered frames).
        work_budget: maximum partial assignments per matching level.
    """

    def __init__(
        self,
        catalog,
        camera: Camera,
        *,
        tolerance_deg: float | None = None,
        centroid_sigma_px: float = 0.5,
        n_max: int = 6,
        n_min: int = 3,
        p_false_max: float = 1e-6,
        fov_error_deg: float = 0.0,
        faithful: bool = False,
        n_bands: int = 1,
        dec_check: bool = True,
        max_detections: int = 30,
        max_patterns: int = 200,
        work_budget: int = 200_000,
        cache: bool = True,
        method: str = "nstar",
        triad_params=None,
        max_tracking_cone_deg: float = 3.0,
        max_fix_sigma_px: float = 5.0,
        p_false_max_tracking: float = 1e-4,
        whole_streak_px: float = 20.0,
    ) -> None:
        if method not in ("nstar", "triad"):
            raise ValueError(f"method must be 'nstar' or 'triad', got {method!r}")
        self.method = method
        self.triad_params = triad_params
        self.max_tracking_cone_deg = float(max_tracking_cone_deg)
        self.max_fix_sigma_px = float(max_fix_sigma_px)
        self.p_false_max_tracking = float(p_false_max_tracking)
        if not (np.isfinite(whole_streak_px) and whole_streak_px >= 0):
            raise ValueError(f"whole_streak_px must be ≥ 0, got {whole_streak_px}")
        self.whole_streak_px = float(whole_streak_px)
        self._triad_db = None
        if not 2 <= n_min <= n_max <= 8:
            raise ValueError(f"need 2 ≤ n_min ≤ n_max ≤ 8, got {n_min}, {n_max}")
        if centroid_sigma_px <= 0 or not np.isfinite(centroid_sigma_px):
            raise ValueError("centroid_sigma_px must be positive")
        if not 0 <= fov_error_deg < camera.fov_x_deg:
            raise ValueError(f"fov_error_deg must be in [0, {camera.fov_x_deg:.2f}) for this "
                             f"camera, got {fov_error_deg}")
        if not 0 < p_false_max < 1:
            raise ValueError("p_false_max must be in (0, 1)")
        if not 3 <= max_detections <= 64:
            # the search marks a pattern's detections in a 64-bit mask
            raise ValueError(f"max_detections must be in [3, 64], got {max_detections}")
        if max_patterns < 1 or work_budget < 1:
            raise ValueError(f"max_patterns and work_budget must be ≥ 1, got {max_patterns}"
                             f" and {work_budget}")
        self.catalog = catalog
        self.camera = camera
        self.vectors = np.asarray(catalog.vectors, dtype=np.float64)
        self.ids = np.asarray(catalog.ids, dtype=np.int64)
        if len(self.vectors) < 3:
            raise ValueError(f"the catalogue holds {len(self.vectors)} stars; need ≥ 3")
        self.centroid_sigma_px = float(centroid_sigma_px)
        sigma_rad = self.centroid_sigma_px * camera.pixel_scale_rad
        self.tolerance_rad = (np.radians(tolerance_deg) if tolerance_deg is not None
                              else 3.0 * np.sqrt(2.0) * sigma_rad + np.radians(0.003))
        self.n_max, self.n_min = n_max, n_min
        self.p_false_max = p_false_max
        self.fov_error_deg = float(fov_error_deg)
        self.faithful = faithful
        self.n_bands = int(n_bands)
        self.dec_check = dec_check
        self.max_detections = int(max_detections)
        self.max_patterns = int(max_patterns)
        self.work_budget = int(work_budget)
        # the index must reach across the widest field any focal guess gives
        widest = camera.scaled(min(self._focal_scales())) if fov_error_deg else camera
        self.max_sep_rad = float(np.radians(widest.diagonal_fov_deg) + 2 * self.tolerance_rad)
        tag = _catalog_tag(self.vectors) if cache else None
        t0 = time.perf_counter()
        self.index = PatternIndex.from_vectors(self.vectors, self.max_sep_rad, cache_tag=tag)
        self.index_build_s = time.perf_counter() - t0
        self._tree = cKDTree(self.vectors)
        self._ix = kernels.index_arrays(self.index)
        self._pattern_lists: dict[tuple[int, ...], tuple] = {}
        # the search runs compiled, except with the matchers kept in numpy
        self._compiled = not (faithful or self.n_bands > 1)
        self._cone_cache: tuple[NDArray, float, NDArray[np.int64], NDArray] | None = None

    # --- public -----------------------------------------------------------------------

    def solve(self, detections, prior: Prior | None = None) -> Solution:
        """Identify the stars of one frame.

        ``detections`` is a :class:`starid.Detections`, or an (N, 2) array of pixel
        positions (brightest first), or (N, 3) with flux as the third column (sorted here).
        Problems with the data give ``ok=False`` with a ``reason``; only a wrong type or
        shape raises.
        """
        t0 = time.perf_counter()
        xy, problem = self._parse(detections, min_count=2 if prior is not None else 3)
        if problem:
            return Solution(False, problem, time_s=time.perf_counter() - t0,
                            n_detections=len(xy), mode="tracking" if prior else "lost-in-space")
        fallback_note = ""
        if prior is not None:
            if prior.k * prior.sigma_deg <= self.max_tracking_cone_deg:
                sol = self._solve_tracking(xy, prior, t0)
                if sol.ok:
                    return sol
                fallback_note = f"tracking failed ({sol.reason}); "
            else:
                fallback_note = (f"prior too loose ({prior.k:g}σ = {prior.k * prior.sigma_deg:.3g}°"
                                 f" > {self.max_tracking_cone_deg:g}°); ")
            if len(xy) < 3:
                return Solution(False, fallback_note + "too few detections for lost-in-space",
                                mode="tracking", time_s=time.perf_counter() - t0,
                                n_detections=len(xy))
        if self.method == "triad":
            sol = self._solve_triad(xy)
            return _replace(sol, time_s=time.perf_counter() - t0, n_detections=len(xy),
                            patterns_tried=1)
        cams = [self.camera.scaled(k) if k != 1.0 else self.camera
                for k in self._focal_scales()]
        sol, tried = self._solve_at(xy, cams)
        if fallback_note and not sol.ok:
            sol = _replace(sol, reason=fallback_note + sol.reason)
        return _replace(sol, time_s=time.perf_counter() - t0, n_detections=len(xy),
                        patterns_tried=tried)

    def warm_up(self) -> bool:
        """Pay the lost-in-space search's one-time costs now rather than in the first
        frames: its compiled kernels (:mod:`starid.kernels`) load from numba's cache in
        ~0.3 s — or, the first time after an install, compile in ~10 s — on their first
        call in a process, and each detection count's pattern order is computed on first
        use. Call it once before a timed or real-time loop. Returns whether a synthetic
        frame (the catalogue seen at a few fixed attitudes) was solved.

        >>> from adfusion import starid
        >>> s = starid.Solver(starid.Catalog.hipparcos(mag_limit=5.0),
        ...                   starid.Camera.pinhole(1024, 768, 15.0))
        >>> s.warm_up()
        True
        """
        for dec in (0.5, -0.5, 1.2, -1.2, 0.0):
            pxy, _, idx = self._project_idx(rot.q_cam_icrs_from_radec_roll(1.0, dec, 0.0),
                                            self.camera)
            if len(idx) >= 4:
                break
        else:
            return False
        solved = self.solve(pxy[:8]).ok  # the search
        if self.method == "nstar":  # every detection count's pattern list (~0.1 s)
            for n_det in range(3, self.max_detections + 1):
                self._pattern_list(n_det, True)
        b_all = self.camera.pixels_to_vectors(pxy[:3])  # the weak path's quick check
        table = _PairWindows.of(b_all, self.tolerance_rad, 0.0)
        self._quick(b_all, table, np.arange(3), idx[None, :3], self.camera, 1)
        return solved

    def stars_in_view(self, q_cam_icrs) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Catalogue ids and pixel positions of the catalogue stars inside the frame at an
        attitude (``q_cam_icrs``), brightest first: :func:`adfusion.starid.view.stars_in_view`
        for this solver's catalogue and camera, with ids instead of row indices.

        >>> from adfusion import starid
        >>> from adfusion.starid import rotations as rot
        >>> s = starid.Solver(starid.Catalog.hipparcos(mag_limit=4.0),
        ...                   starid.Camera.pinhole(1024, 768, 15.0))
        >>> ids, xy = s.stars_in_view(rot.q_cam_icrs_from_radec_roll(0.2, 1.0, 0.0))
        >>> len(xy) == len(ids) > 0
        True
        """
        idx, xy = stars_in_view(self.catalog, self.camera, q_cam_icrs)
        return self.catalog.ids[idx], xy

    # --- internals ----------------------------------------------------------------------

    def _parse(self, detections, min_count: int = 3) -> tuple[NDArray[np.float64], str]:
        if hasattr(detections, "xy"):
            xy = np.asarray(detections.xy, dtype=np.float64)
            if getattr(detections, "ok", True) is False:
                return xy, f"detection not ok: {detections.reason}"
        else:
            arr = np.asarray(detections, dtype=np.float64)
            if arr.ndim != 2 or arr.shape[1] not in (2, 3):
                raise ValueError(f"detections must be (N, 2) xy or (N, 3) xy+flux, got "
                                 f"shape {arr.shape}")
            if arr.shape[1] == 3:
                arr = arr[np.argsort(-arr[:, 2], kind="stable")]
            xy = arr[:, :2]
        if len(xy) < min_count:
            return xy, f"too few detections ({len(xy)} < {min_count})"
        # cheap tests first, details only when they fail (this runs per frame in the
        # tracking loop): all coordinates within the frame plus a slack — a NaN fails
        # every comparison, so it lands in the detailed checks too
        slack = 0.5 * max(self.camera.width, self.camera.height)
        lo_x, lo_y = xy.min(axis=0).tolist()
        hi_x, hi_y = xy.max(axis=0).tolist()
        use = xy[: self.max_detections]
        if not (lo_x >= -0.5 - slack and lo_y >= -0.5 - slack
                and hi_x <= self.camera.width - 0.5 + slack
                and hi_y <= self.camera.height - 0.5 + slack):
            if not np.isfinite(xy).all():
                bad = ~np.isfinite(xy).all(axis=1)
                return xy, f"bad input: {int(bad.sum())} non-finite centroid(s), first at " \
                           f"row {int(np.flatnonzero(bad)[0])}"
            outside = ~self.camera.in_frame(use, margin=-slack)
            if outside.any():
                return xy, f"bad input: centroid row {int(np.flatnonzero(outside)[0])} lies " \
                           "far outside the frame"
        xs = np.sort(use[:, 0])
        # (inside the frame no difference overflows: no errstate needed on this hot path)
        gap = float(np.min(xs[1:] - xs[:-1])) if len(xs) > 1 else np.inf
        if gap < 1e-6:
            # some x coincide: look for pairs closer than 1e-6 px in both coordinates
            diff = use[:, None, :] - use[None, :, :]
            d2 = np.einsum("ijk,ijk->ij", diff, diff)
            d2.flat[:: len(use) + 1] = np.inf
            if d2.min() < 1e-12:
                dup = np.argwhere(d2 < 1e-12)
                return xy, f"bad input: duplicate centroids at rows {int(dup[0, 0])} and " \
                           f"{int(dup[0, 1])}"
        return use, ""

    def _focal_scales(self) -> list[float]:
        """Focal-length multipliers covering the FOV uncertainty (1.0 first)."""
        if self.fov_error_deg == 0:
            return [1.0]
        half = np.radians(self.camera.fov_x_deg) / 2
        lo = np.tan(half) / np.tan(half + np.radians(self.fov_error_deg) / 2)
        hi = np.tan(half) / np.tan(max(half - np.radians(self.fov_error_deg) / 2, 1e-6))
        n = max(3, int(np.ceil(np.log(hi / lo) / np.log1p(self._scale_step))) + 1)
        grid = np.exp(np.linspace(np.log(lo), np.log(hi), n))
        order = np.argsort(np.abs(np.log(grid)))
        return [1.0, *[float(g) for g in grid[order] if abs(np.log(g)) > 1e-12]]

    _scale_step = 0.01  # 1 % focal steps; windows widen by half a step × distance

    def _patterns(self, n_det: int) -> Iterator[tuple[tuple[int, ...], str]]:
        """Patterns in a fixed order: Renken's main pattern, his Not-Modus ((n−1)- and
        (n−2)-star sub-patterns, then fainter detections swapped in), then — our
        extension for frames with several false objects among the brightest — every
        3-star combination of the brightest ``max_detections``, the most probably clean
        first given the failures so far (:func:`starid.search_order.combination_order`),
        then every 4-star one by its faintest member. Verification against all
        other detections is what makes a 3-star pattern trustworthy."""
        seen: set[tuple[int, ...]] = set()
        yield from self._renken_patterns(n_det, seen)

        # 3-star patterns first: among false objects they are more often clean; most
        # probably clean first, given that every pattern so far held a false object
        if self.n_min <= 3:
            for pat in combination_order(n_det, list(seen)):
                if self._fresh(pat, seen):
                    yield pat, f"combination {list(pat)}"
        for last in range(3, n_det):
            for head in itertools.combinations(range(last), 3):
                pat = (*head, last)
                if self._fresh(pat, seen):
                    yield pat, f"combination {list(pat)}"

    def _renken_patterns(self, n_det: int, seen: set[tuple[int, ...]],
                         ) -> Iterator[tuple[tuple[int, ...], str]]:
        """The first part of :meth:`_patterns`: Renken's main pattern and Not-Modus
        (adding each to ``seen``)."""
        n = min(self.n_max, n_det)
        base = tuple(range(n))

        if self._fresh(base, seen):
            yield base, f"n={n}"
        for k in (n - 1, n - 2):
            # drop the faintest stars first: false objects are more often faint
            for keep in sorted(itertools.combinations(base, k), key=lambda c: sorted(
                    set(base) - set(c), reverse=True), reverse=True):
                if self._fresh(keep, seen):
                    yield keep, f"not-modus {k}-of-{n} {list(keep)}"
        for extra in range(n, min(n_det, 2 * n)):  # the next n fainter detections
            for out in reversed(base):
                pat = tuple(sorted((set(base) - {out}) | {extra}))
                if self._fresh(pat, seen):
                    yield pat, f"not-modus swap {extra} for {out}"

    def _fresh(self, p: tuple[int, ...], seen: set[tuple[int, ...]]) -> bool:
        """Whether ``p`` is a pattern not yet tried, of at least ``n_min`` (and 3) stars;
        notes it in ``seen``."""
        if p in seen or len(p) < max(self.n_min, 3):
            return False
        seen.add(p)
        return True

    def _pattern_list(self, n_det: int, full: bool,
                      ) -> tuple[NDArray[np.int64], NDArray[np.int64], list[str]]:
        """Patterns of :meth:`_patterns` for :func:`kernels.search` — Renken's
        (:meth:`_renken_patterns`) or, with ``full``, all up to the budget
        (``max_patterns`` + 1) — as detections (P, 8), their counts (P,) and the paths.

        The order is a function of the detection count alone (the search reaches a
        pattern only after every earlier one failed), so each list is computed once per
        count; the combinations' order (a few ms) only when a frame first gets there."""
        key = (n_det, full, self.max_patterns, self.n_max, self.n_min)
        if key not in self._pattern_lists:
            it = self._patterns(n_det) if full else self._renken_patterns(n_det, set())
            pats = list(itertools.islice(it, self.max_patterns + 1))
            arr = np.zeros((len(pats), 8), dtype=np.int64)
            for r, (p, _) in enumerate(pats):
                arr[r, :len(p)] = p
            self._pattern_lists[key] = (arr, np.array([len(p) for p, _ in pats],
                                                      dtype=np.int64),
                                        [path for _, path in pats])
        return self._pattern_lists[key]

    def _solve_at(self, xy: NDArray, cams: list[Camera]) -> tuple[Solution, int]:
        """Try patterns in order; each pattern at every focal-length guess (so the right
        scale is found by the main pattern, not after exhausting Not-Modus at a wrong
        one). ``tried`` counts (pattern, scale) trials: the union bound of ``p_false``."""
        b_cams = [cam.pixels_to_vectors(xy) for cam in cams]
        rel_tol = 0.5 * self._scale_step if self.fov_error_deg else 0.0
        # every pattern's pair windows come from one table per focal guess: cheaper than
        # building them per pattern
        tables = [_PairWindows.of(b_all, self.tolerance_rad, rel_tol) for b_all in b_cams]
        run = _Search()
        trials = self._trials_compiled if self._compiled else self._trials_numpy
        for ci, sel, assignments, quicks, path in trials(xy, cams, b_cams, tables, run):
            cam = cams[ci]
            cands = [c for a, q in zip(assignments, quicks, strict=True)
                     if q is not None and q[0] <= self.p_false_max
                     and (c := self._verify(xy, cam, sel, a, q, b_cams[ci])) is not None]
            accepted = _distinct([c for c in cands if c.p_false <= self.p_false_max],
                                 3 * self.tolerance_rad)
            if len(accepted) == 1:
                return self._solution(accepted[0], len(assignments), path, cands), run.tried
            if len(accepted) > 1:
                return Solution(
                    False, f"ambiguous: {len(accepted)} distinct attitudes verified",
                    matching_counter=len(assignments), path=path,
                    candidates=sorted(accepted, key=lambda c: c.p_false),
                ), run.tried
        tried = run.tried
        best = run.best_weak(3)
        if best:
            # nothing convincing: show the best few for an operator (or a filter's prior)
            shown = []
            for _, sel, a, _, ci, trial in best:
                q = self._quick(b_cams[ci], tables[ci], sel, a[None], cams[ci], trial)[0]
                if (c := self._verify(xy, cams[ci], sel, a, q, b_cams[ci])) is not None:
                    shown.append(c)
            reason = (f"ambiguous: weak evidence, the best candidate has p_false "
                      f"{best[0][0]:.2g} > {self.p_false_max:.0e} ({tried} patterns tried)")
            return Solution(False, reason, matching_counter=run.first_counter or 0,
                            path=best[0][3],
                            candidates=_distinct(shown, 3 * self.tolerance_rad)), tried
        reason = f"no match: {run.budget_note or f'{tried} patterns tried'}"
        return Solution(False, reason, matching_counter=run.first_counter or 0), tried

    def _trials_compiled(self, xy: NDArray, cams: list[Camera], b_cams: list[NDArray],
                         tables: list[_PairWindows], run: _Search) -> Iterator[tuple]:
        """The search of :meth:`_solve_at` in compiled code (:func:`kernels.search`):
        yields (guess, sel, assignments, quick checks, path) of every trial with a
        candidate whose quick p_false passes, for :meth:`_verify`; ``run`` keeps the
        counts, the weak candidates and the budget notes."""
        full = False
        pats, plen, paths = self._pattern_list(len(xy), full)
        n_cams = len(cams)
        state = np.array([0, 0, 0, -1, 0, kernels.NOTE_NONE, 0, 0], dtype=np.int64)
        no_match = np.zeros((n_cams, self.max_patterns + 2), dtype=np.int64)
        n_no_match = np.zeros(n_cams, dtype=np.int64)
        pix = np.array([cam.pixel_scale_rad for cam in cams])
        radius = self._match_radius_px() * pix
        floor = np.sqrt(2.0) * self.centroid_sigma_px * pix
        stack = [np.stack(b_cams)] + [np.stack([getattr(t, f) for t in tables])
                                      for f in ("angles", "tol", "cos_min", "cos_max")]
        while True:
            sel, rows, q, wp, wi = kernels.search(
                self._ix, state, pats, plen, self.max_patterns * n_cams, no_match,
                n_no_match, *stack, radius, floor, self.p_false_max, self.work_budget)
            if len(wp):
                run.weak_rows.append((wp, wi, paths))
            pos, ci, run.tried, first, status, note, a, b = state.tolist()
            run.first_counter = None if first < 0 else first
            if note == kernels.NOTE_WORK:
                run.budget_note = (f"work budget exceeded ({a} partial assignments at "
                                   f"level {b})")
            elif note == kernels.NOTE_PATTERNS:
                run.budget_note = f"{a} pattern trials (the budget)"
            if status != kernels.STRONG:
                if full or pos < len(pats):
                    return
                # Renken's patterns failed: on to the combinations (the same list, longer)
                full = True
                pats, plen, paths = self._pattern_list(len(xy), full)
                continue
            yield ci, sel, rows, _quick_tuples(q), paths[pos]
            state[:2] = (pos, ci + 1) if ci + 1 < n_cams else (pos + 1, 0)

    def _trials_numpy(self, xy: NDArray, cams: list[Camera], b_cams: list[NDArray],
                      tables: list[_PairWindows], run: _Search) -> Iterator[tuple]:
        """:meth:`_trials_compiled` in Python, for the matchers kept in numpy (Renken's
        faithful loops, declination bands): the same trials, counts and values."""
        budget = self.max_patterns * len(cams)
        # detection sets (bit masks) that matched nothing, per focal guess: a pattern
        # holding one of them matches nothing either (every window of the smaller set is
        # one of its own), so it is counted as tried but not matched — the swaps and
        # 4-star combinations after a failed Not-Modus are mostly such supersets
        no_match: list[list[int]] = [[] for _ in cams]
        for pat_idx, path in self._patterns(len(xy)):
            if run.tried >= budget:
                run.budget_note = f"{run.tried} pattern trials (the budget)"
                return
            mask = sum(1 << i for i in pat_idx)
            for ci, (cam, b_all) in enumerate(zip(cams, b_cams, strict=True)):
                run.tried += 1
                if any(e & mask == e for e in no_match[ci]):
                    continue
                sel = np.array(pat_idx)
                sel = sel[closest_pair_first(tables[ci].angles[sel[:, None], sel])]
                pattern, _ = tables[ci].pattern(sel, b_all)
                try:
                    assignments = self._match(pattern)
                except WorkBudgetExceeded as e:
                    run.budget_note = f"work budget exceeded ({e})"
                    continue
                if run.first_counter is None:
                    run.first_counter = len(assignments)
                if len(assignments) == 0:
                    no_match[ci].append(mask)
                    continue
                quicks = self._quick(b_all, tables[ci], sel, assignments, cam, run.tried)
                strong = False
                for a, q in zip(assignments, quicks, strict=True):
                    if q is not None and q[0] <= self.p_false_max:
                        strong = True
                    elif q is not None:
                        run.weak.append((q[0], sel, a, path, ci, run.tried))
                if strong:
                    yield ci, sel, assignments, quicks, path

    def _solve_tracking(self, xy: NDArray, prior: Prior, t0: float) -> Solution:
        """Tracking: predict the catalogue stars in the prior's field, associate the
        detections inside the prior's gate, refine, and accept with ≥ 2 stars when a
        chance coincidence is improbable.

        Association runs in steps so that a prior off by more than the star spacing
        cannot pair stars crosswise: every predicted star takes its nearest detection
        within the wide gate (k·σ), the median image offset of those pairs corrects the
        prior's pointing, pairs are redone within a medium radius (what is left is roll),
        then Wahba and re-association within the tight radius, twice. With a tight prior
        (gate ≤ 2.5 match radii) the nearest pairs are taken directly. ``p_false`` is the
        chance that this many of the M detections fall within the tight radius of
        predicted stars by accident, times the number of alternative pairings the wide
        gates allowed.

        This runs once per frame in a filter loop with a few dozen stars, so it is written
        for numpy's per-call overhead: a cached catalogue cone, one brute-force distance
        matrix instead of a KD-tree, and no intermediate copies of the result.
        """
        cam = self.camera
        q0 = prior.q_cam_icrs
        gate_rad = math.radians(prior.k * prior.sigma_deg)
        R0 = rot.to_matrix(q0)
        pred_xy, pred_idx = self._predict(R0, cam, gate_rad)
        if len(pred_xy) < 2:
            return Solution(False, f"{len(pred_xy)} catalogue star(s) predicted in view",
                            mode="tracking")
        pix_rad = cam.pixel_scale_rad
        tight = self._match_radius_px()
        wide = max(gate_rad / pix_rad * 1.2 + tight, tight)
        # predicted stars × detections: a few dozen each, cheaper than building a tree
        dx = pred_xy[:, :1] - xy[:, 0]
        dy = pred_xy[:, 1:] - xy[:, 1]
        d2 = dx * dx
        d2 += dy * dy
        n_within = (d2 <= wide * wide).sum(axis=1)
        hit = n_within > 0
        n_hit = int(hit.sum())
        if n_hit < 2:
            return Solution(False, f"{n_hit} predicted star(s) with a detection in the gate",
                            mode="tracking")
        j = d2.argmin(axis=1)  # the nearest detection (inside the gate where hit)
        # alternative pairings inside the wide gates (1 each when the prior is tight)
        n_hyp = 2.0 ** int(np.count_nonzero(n_within >= 2))
        tight_prior = wide <= 2.5 * tight
        if tight_prior:
            # a tight prior (the steady state of a running filter): the gates are nearly
            # the match radius, so the nearest pairs are the answer — one fit, no rounds
            p_sel = np.flatnonzero(hit)
            det_sel = j[p_sel]
            if len(set(det_sel.tolist())) < len(det_sel):  # a detection claimed twice
                d = np.where(hit, np.sqrt(d2[np.arange(len(j)), j]), np.inf)
                p_sel, det_sel = _one_to_one(d, j)
            order = np.argsort(det_sel)
            det_i, cat_i = det_sel[order], pred_idx[p_sel[order]]
            b_use = cam.pixels_to_vectors(xy[det_i])
        else:
            shift = np.median(xy[j[hit]] - pred_xy[hit], axis=0)
            b_all = cam.pixels_to_vectors(xy)
            # after the shift what is left is mostly roll (largest at the edges): pair
            # within a medium radius, then tighten through two fits
            medium = max(tight, 0.3 * wide)
            det_i, cat_i = _pair_within(xy, pred_xy + shift, pred_idx, medium)
            predicted = np.zeros(len(self.vectors), dtype=bool)
            predicted[pred_idx] = True
            for _ in range(2):
                if len(det_i) < 2:
                    break
                R = _rotation_from_pairs(b_all[det_i], self.vectors[cat_i])
                if R is None:
                    return Solution(False, "tracked stars are collinear", mode="tracking")
                det_i, cat_i = self._associate_icrs(b_all, R, tight * pix_rad)
                # keep only stars the prior predicted (tracking never jumps elsewhere)
                keep = predicted[cat_i]
                det_i, cat_i = det_i[keep], cat_i[keep]
            b_use = b_all[det_i]
        if len(det_i) < 2:
            return Solution(False, f"{len(det_i)} star(s) matched within {tight:.1f} px",
                            mode="tracking")
        sigma = self.centroid_sigma_px * pix_rad
        try:
            # near a tight prior Gauss–Newton steps reach Wahba's optimum for less than
            # the SVD (the steady state of a filter loop)
            w = wahba_near(q0, b_use, self.vectors[cat_i], sigma) if tight_prior \
                else wahba_unit(b_use, self.vectors[cat_i], sigma)
            # pairs the fit cannot place within the match radius (a noise blob or a
            # streak's piece nearer the prediction than the star) leave; one refit,
            # from this fit (its optimum is within a pixel or so)
            keep = w.residuals_rad <= tight * pix_rad
            n_keep = int(np.count_nonzero(keep))
            if 2 <= n_keep < len(keep):
                det_i, cat_i, b_use = det_i[keep], cat_i[keep], b_use[keep]
                w = wahba_near(w.q_cam_icrs, b_use, self.vectors[cat_i], sigma)
            whole = self.whole_streak_px * pix_rad
            if prior.smear_cam_rad is not None and _norm3(prior.smear_cam_rad) > whole:
                v = streak_vectors(b_use, prior.smear_cam_rad)
                if float(np.einsum("ij,ij->i", v, v).max()) > whole * whole:
                    w = refine_streaked(w.q_cam_icrs, b_use, self.vectors[cat_i], sigma,
                                        prior.smear_cam_rad, whole)
        except ValueError as e:
            return Solution(False, f"tracking fit failed: {e}", mode="tracking")
        offset = float(rot.angle_between(w.q_cam_icrs, q0))
        # trace(P) ≥ its largest eigenvalue: a bound, at most √3 too wide, for free
        sigma_fix = math.sqrt(float(w.covariance.trace()))
        if offset > gate_rad + 3 * sigma_fix:
            return Solution(False, f"fix {math.degrees(offset):.3g}° from the prior, outside "
                                   f"its {prior.k:g}σ gate", mode="tracking")
        cov = w.covariance * _variance_factor(w)
        corner_px = _corner_sigma_px(cov, cam)
        if corner_px > self.max_fix_sigma_px:
            return Solution(False, f"fix too uncertain: 1σ {corner_px:.3g} px at the frame's "
                                   f"corners > {self.max_fix_sigma_px:g} px (stars too close "
                                   "together, or inconsistent)", mode="tracking")
        p_hit = min(1.0, len(pred_xy) * math.pi * tight**2 / (cam.width * cam.height))
        p_false = min(1.0, n_hyp * binomial_tail(len(det_i), len(xy), p_hit))
        matches = list(zip(det_i.tolist(), self.ids[cat_i].tolist(), strict=True))
        cand = Candidate(
            q_cam_icrs=w.q_cam_icrs, matches=matches, residuals_rad=w.residuals_rad,
            p_false=p_false, n_pattern=len(det_i), camera=cam, covariance=cov,
            _projector=self._project,
        )
        if p_false > self.p_false_max_tracking:
            return Solution(False, f"ambiguous: {len(det_i)} tracked stars, p_false "
                                   f"{p_false:.2g} > {self.p_false_max_tracking:.0e}",
                            mode="tracking", candidates=[cand])
        return Solution(True, "", q_cam_icrs=w.q_cam_icrs, matches=matches,
                        matching_counter=1, covariance=cov, mode="tracking",
                        time_s=time.perf_counter() - t0, p_false=p_false, path="tracking",
                        candidates=[cand], residuals_rad=w.residuals_rad, camera=cam,
                        n_detections=len(xy))

    def _solve_triad(self, xy: NDArray) -> Solution:
        """Yee's triad method (:mod:`starid.triad`), then our verification: Yee's voting
        can accept a false 3-star match (a mirror image, a close double), so the result
        must also pass the false-match probability test like any n-star candidate."""
        from adfusion.starid.triad import SeparationDatabase, TriadParams, identify_triads

        params = self.triad_params or TriadParams()
        if self._triad_db is None:
            self._triad_db = SeparationDatabase.build(
                self.catalog, self.camera.diagonal_fov_deg + params.tol_sep_deg)
        res = identify_triads(xy, self.camera, self.catalog, params, self._triad_db)
        if not res.ok:
            return Solution(False, f"triad: {res.reason}", path="triad")
        pos = {int(h): k for k, h in enumerate(self.ids)}
        pairs = sorted({(int(d), pos[int(h)]) for d, h in res.matches})
        used_cat: set[int] = set()
        sel_l, assign_l = [], []
        for d, c in pairs:  # a resolved double maps twice onto a merged star: keep one
            if c not in used_cat:
                used_cat.add(c)
                sel_l.append(d)
                assign_l.append(c)
        if len(sel_l) < 3:
            return Solution(False, "triad: fewer than 3 distinct matched stars", path="triad")
        sel, assign = np.array(sel_l), np.array(assign_l)
        b_all = self.camera.pixels_to_vectors(xy)
        b = b_all[sel]
        ang = np.arccos(np.clip(b @ b.T, -1, 1))
        np.fill_diagonal(ang, 0.0)
        n_img = min(len(xy), params.max_stars)
        trials = max(1, n_img * (n_img - 1) * (n_img - 2) // 6)  # every image triangle
        chance = (ang, np.full(ang.shape, np.radians(params.tol_sep_deg)), True)
        quick = self._quick(b_all, None, sel, assign[None], self.camera, trials, chance)[0]
        if quick is None:
            return Solution(False, "triad: match not confirmed by the projected catalogue",
                            path="triad")
        if quick[0] > self.p_false_max:
            return Solution(False, f"insufficient evidence: triad match p_false "
                                   f"{quick[0]:.2g} > {self.p_false_max:.0e}", path="triad")
        cand = self._verify(xy, self.camera, sel, assign, quick)
        if cand is None or cand.p_false > self.p_false_max:
            return Solution(False, "triad: match failed full verification", path="triad")
        return self._solution(cand, 1, "triad", [cand])

    def _match_radius_px(self) -> float:
        return max(_3_SQRT2 * self.centroid_sigma_px, 1.5)

    def _p_hit(self, anchor: int, radius_rad: float) -> float:
        """Chance that a random detection falls within the match radius of a catalogue
        star: local density (neighbours of the anchor star within the index radius), at
        least the sky mean, times a safety factor."""
        cnt = self.index.nbr_ptr[anchor + 1] - self.index.nbr_ptr[anchor]
        area = 2 * np.pi * (1 - np.cos(self.max_sep_rad))
        rho = max(cnt / area, len(self.vectors) / (4 * np.pi)) * DENSITY_SAFETY
        return min(1.0, rho * np.pi * radius_rad**2)

    def _associate_icrs(self, b_all: NDArray, R: NDArray,
                        radius_rad: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Detections ↔ catalogue stars within a radius, at attitude R (cam ← icrs): each
        detection's nearest star, one-to-one (a star claimed twice goes to the closer)."""
        d, j = self._tree.query(b_all @ R, distance_upper_bound=2 * np.sin(radius_rad / 2))
        return _one_to_one(d, j)

    def _quick(self, b_all: NDArray, table: _PairWindows | None, sel: NDArray,
               assigns: NDArray, cam: Camera, trials: int, chance: tuple | None = None,
               ) -> list[tuple[float, NDArray, float, NDArray, NDArray] | None]:
        """Cheap verification of every assignment (K, n) of one pattern
        (:func:`kernels.quick_checks`): attitude from the pattern, every detection
        rotated into ICRS and associated. Per assignment (p_false, R, e_trials,
        detection indices, catalogue indices), or None.

        ``e_trials`` is the expected number of chance patterns fitting *as well as this
        candidate does* — windows shrunk to its own pair residuals, but never below the
        centroid noise — times the trials so far (a union bound over the search). The
        pattern's angles and windows come from ``table`` (or ``chance`` = (angles, window
        half-widths, mirror checked))."""
        if chance is None:
            ix = (sel[:, None], sel)
            ang, tol = table.angles[ix], table.tol[ix]
            mirror = chirality_of(b_all[sel], 2.0 * float(tol.max())) != 0
        else:
            ang, tol, mirror = chance
        pix = cam.pixel_scale_rad
        q = kernels.quick_checks(
            self._ix, np.ascontiguousarray(b_all), np.asarray(sel, dtype=np.int64),
            np.ascontiguousarray(assigns, dtype=np.int64), np.ascontiguousarray(ang),
            np.ascontiguousarray(tol), bool(mirror), int(trials),
            self._match_radius_px() * pix, np.sqrt(2.0) * self.centroid_sigma_px * pix)
        return _quick_tuples(q)

    def _verify(self, xy: NDArray, cam: Camera, sel: NDArray, assign: NDArray,
                quick: tuple[float, NDArray, float, NDArray, NDArray],
                b_all: NDArray | None = None) -> Candidate | None:
        """Full verification of a candidate that passed the quick check: refit on all its
        matches (and the focal length when it is uncertain), re-associate if the refit
        moved the attitude noticeably, final fit with covariance, and the p_false of the
        final match count."""
        _, R, e_trials, det_i, cat_i = quick
        if b_all is None:
            b_all = cam.pixels_to_vectors(xy)
        radius = self._match_radius_px() * cam.pixel_scale_rad
        sigma = self.centroid_sigma_px * cam.pixel_scale_rad
        refit = False
        if self.fov_error_deg > 0 and len(det_i) >= 4:
            cam = fit_camera(xy[det_i], self.vectors[cat_i], cam, fit_focal=True,
                             try_mirror=False).camera
            b_all = cam.pixels_to_vectors(xy)
            radius = self._match_radius_px() * cam.pixel_scale_rad
            sigma = self.centroid_sigma_px * cam.pixel_scale_rad
            refit = True
        R2 = _rotation_from_pairs(b_all[det_i], self.vectors[cat_i])
        if R2 is None:
            return None
        # rotation angle between R and R2 from the trace: 1 − cos θ = (3 − tr)/2
        moved = np.sqrt(max(0.0, 2.0 * (3.0 - float(np.sum(R * R2))) / 2.0))
        if refit or moved > 0.25 * radius:
            det_i, cat_i = self._associate_icrs(b_all, R2, radius)
            if not _keeps_pattern(det_i, cat_i, sel, assign, len(b_all)):
                return None
        try:
            final = wahba_unit(b_all[det_i], self.vectors[cat_i], sigma)
        except ValueError:
            return None
        k_other = len(det_i) - len(sel)
        p_false = min(1.0, e_trials * binomial_tail(k_other, len(xy) - len(sel),
                                                    self._p_hit(int(assign[0]), radius)))
        return Candidate(
            q_cam_icrs=final.q_cam_icrs,
            matches=[(int(d), int(self.ids[c])) for d, c in zip(det_i, cat_i, strict=True)],
            residuals_rad=final.residuals_rad,
            p_false=p_false,
            n_pattern=len(sel),
            camera=cam,
            covariance=final.covariance * _variance_factor(final),
            _projector=self._project,
        )

    def _match(self, pattern: Pattern) -> NDArray[np.int64]:
        if self.faithful:
            return match_faithful(self.vectors, pattern, self.dec_check, self._band_masks(
                pattern))
        if self.n_bands > 1:
            parts = [match_indexed(self.index, pattern, self.work_budget, m)
                     for m in self._band_masks(pattern)]
            allm = np.concatenate(parts)
            return np.unique(allm, axis=0) if len(allm) else allm
        return match_indexed(self.index, pattern, self.work_budget)

    def _band_masks(self, pattern: Pattern) -> list[NDArray[np.bool_]] | None:
        if self.n_bands <= 1:
            return None
        dec = np.arcsin(np.clip(self.vectors[:, 2], -1, 1))
        edges = np.arcsin(np.linspace(1.0, -1.0, self.n_bands + 1))
        o = pattern.delta_max_rad
        return [(dec <= hi + o) & (dec >= lo - o) for hi, lo in itertools.pairwise(edges)]

    def _project(self, q: NDArray, cam: Camera) -> tuple[NDArray, NDArray[np.int64]]:
        """Catalogue stars inside the frame at attitude q: pixel positions and catalogue ids."""
        pxy, ids, _ = self._project_idx(q, cam)
        return pxy, ids

    def _project_idx(self, q: NDArray, cam: Camera, margin_rad: float = 0.0,
                     ) -> tuple[NDArray, NDArray[np.int64], NDArray[np.int64]]:
        """As :meth:`_project`, plus catalogue indices; ``margin_rad`` widens the cone and
        lets stars just outside the frame in (a prior's error can bring them in)."""
        pxy, idx = self._predict(rot.to_matrix(q), cam, margin_rad)
        return pxy, self.ids[idx], idx

    def _predict(self, R: NDArray, cam: Camera, margin_rad: float,
                 ) -> tuple[NDArray, NDArray[np.int64]]:
        """Pixel positions and catalogue indices of the stars in the frame at attitude R
        (cam ← icrs), ``margin_rad`` beyond its edges."""
        half = 0.5 * math.radians(cam.diagonal_fov_deg) + margin_rad + 1e-3
        idx, vec = self._cone(R[2], half)  # R[2]: the camera +z axis in ICRS
        ideal = cam._ideal_pinhole
        if ideal is None:
            pxy = cam.vectors_to_pixels(vec @ R.T)
            inside = cam.in_frame(pxy, margin=-margin_rad / cam.pixel_scale_rad)
            return pxy[inside], idx[inside]
        # an undistorted pinhole: rotation and projection as one homogeneous matrix
        # (u·z, v·z, z) = H R r — per frame, a few numpy calls instead of a dozen
        (a00, a01), (a10, a11) = ideal[2].tolist()
        c0, c1 = ideal[3].tolist()
        H = np.array([[a00, a10, c0], [a01, a11, c1], [0.0, 0.0, 1.0]])
        h = vec @ (H @ R).T
        z = h[:, 2]
        pxy = h[:, :2] / z[:, None]
        m = -margin_rad / cam.pixel_scale_rad
        lo, hi_x, hi_y = -0.5 + m, cam.width - 0.5 - m, cam.height - 0.5 - m
        u, v = pxy[:, 0], pxy[:, 1]
        inside = (z > 0) & (u >= lo) & (u <= hi_x) & (v >= lo) & (v <= hi_y)
        return pxy[inside], idx[inside]

    def _cone(self, axis: NDArray, half_rad: float) -> tuple[NDArray[np.int64], NDArray]:
        """Catalogue stars (indices, vectors) within at least ``half_rad`` of ``axis``: a
        superset from a cached cone 2° wider, reused while it still covers the request — a
        tracking camera moves little between frames, so one KD-tree query serves many.
        Callers keep only the stars in the frame, so results do not depend on the cache
        (indices stay sorted, as the tree returns them)."""
        cache = self._cone_cache
        if cache is not None:
            c_axis, c_half, idx, vec = cache
            spare = c_half - half_rad
            if spare >= 0 and float(axis @ c_axis) >= math.cos(spare):
                return idx, vec
        c_half = min(half_rad + _CONE_SPARE_RAD, math.pi)
        idx = np.array(self._tree.query_ball_point(axis, 2 * math.sin(c_half / 2)),
                       dtype=np.int64)
        vec = self.vectors[idx]
        self._cone_cache = (np.array(axis, dtype=np.float64), c_half, idx, vec)
        return idx, vec

    def _solution(self, c: Candidate, counter: int, path: str,
                  cands: list[Candidate]) -> Solution:
        return Solution(
            True, "", q_cam_icrs=c.q_cam_icrs, matches=c.matches, matching_counter=counter,
            covariance=c.covariance, p_false=c.p_false, path=path, candidates=cands,
            residuals_rad=c.residuals_rad, camera=c.camera,
        )


@dataclass(frozen=True)
class _PairWindows:
    """The matching windows of every detection pair at one focal guess: a pattern's are a
    sub-matrix (the same values :func:`_pattern` computes, without per-pattern work)."""

    angles: NDArray[np.float64]  # (N, N) pair angles, 0 on the diagonal
    tol: NDArray[np.float64]  # (N, N) window half-widths
    hi: NDArray[np.float64]  # (N, N) upper window edges (angles)
    cos_min: NDArray[np.float64]
    cos_max: NDArray[np.float64]

    @classmethod
    def of(cls, b_all: NDArray, tolerance_rad: float, rel_tol: float) -> _PairWindows:
        ang = np.arccos(np.clip(b_all @ b_all.T, -1, 1))
        np.fill_diagonal(ang, 0.0)
        tol = tolerance_rad + rel_tol * ang
        lo = np.maximum(ang - tol, 0.0)
        hi = np.minimum(ang + tol, np.pi)
        return cls(ang, tol, hi, np.cos(hi), np.cos(lo))

    def pattern(self, sel: NDArray, b_all: NDArray) -> tuple[Pattern, NDArray[np.float64]]:
        """The :class:`Pattern` of detections ``sel`` (in matching order) and its windows'
        half-widths."""
        ix = (sel[:, None], sel)
        tol = self.tol[ix]
        chir = chirality_of(b_all[sel], 2.0 * float(tol.max())) if len(sel) >= 3 else 0
        return Pattern(self.angles[ix], self.cos_min[ix], self.cos_max[ix], chir,
                       float(self.hi[ix].max())), tol


@dataclass
class _Search:
    """What a solve's search has counted so far (see :meth:`Solver._solve_at`)."""

    tried: int = 0  # (pattern, focal guess) trials
    first_counter: int | None = None  # matching_counter of the first pattern matched
    budget_note: str = ""  # the last budget event
    # (quick p_false, sel, assignment, path, focal guess, trial) of candidates too weak
    weak: list[tuple] = field(default_factory=list)
    # the same from kernels.search: (p_false (W,), rows (W, 20), paths), unpacked on demand
    weak_rows: list[tuple] = field(default_factory=list)

    def best_weak(self, k: int) -> list[tuple]:
        """The ``k`` weak candidates with the lowest quick p_false (ties: first found)."""
        if not self.weak_rows:
            return sorted(self.weak, key=lambda w: w[0])[:k]
        p = np.concatenate([w[0] for w in self.weak_rows])
        rows = np.concatenate([w[1] for w in self.weak_rows])
        paths = self.weak_rows[-1][2]  # the latest list: the longest, the others its prefixes
        out = []
        for o in np.argsort(p, kind="stable")[:k].tolist():
            pos, ci, trial, n = rows[o, :4].tolist()
            out.append((float(p[o]), rows[o, 4:4 + n].copy(), rows[o, 12:12 + n].copy(),
                        paths[pos], ci, trial))
        return out


def _quick_tuples(q: tuple) -> list[tuple[float, NDArray, float, NDArray, NDArray] | None]:
    """:func:`kernels.quick_checks`' arrays as one tuple (or None) per assignment."""
    ok, p, R, e, det, cat, n = q
    return [(float(p[k]), R[k], float(e[k]), det[k, :n[k]], cat[k, :n[k]]) if ok[k]
            else None for k in range(len(ok))]


def _pair_within(xy: NDArray, pred_xy: NDArray, pred_idx: NDArray,
                 radius_px: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Each detection to its nearest predicted star within a radius, one-to-one."""
    det, j = _one_to_one(*cKDTree(pred_xy).query(xy, distance_upper_bound=radius_px))
    return det, pred_idx[j].astype(np.int64)


def _corner_sigma_px(cov: NDArray, cam: Camera) -> float:
    """1-σ shift (px) of the frame's corners under an attitude covariance (camera frame):
    pointing errors (x, y axes) move a corner by f·(1 + tan²θ) per radian, roll (z) by its
    distance r from the centre; correlations ignored (an upper estimate)."""
    f = 1.0 / cam.pixel_scale_rad
    r = 0.5 * math.hypot(cam.width, cam.height)
    k = f * (1.0 + (r / f) ** 2)
    return math.sqrt(max(0.0, float(cov[0, 0] + cov[1, 1])) * k * k
                     + max(0.0, float(cov[2, 2])) * r * r)


def _norm3(v: NDArray) -> float:
    x, y, z = v.tolist()
    return math.sqrt(x * x + y * y + z * z)


def _variance_factor(w) -> float:
    """A-posteriori variance factor of a Wahba fit, never below 1: when the residuals say
    the centroids are worse than ``centroid_sigma_px`` (blur, intensifier noise, lens
    residuals), the fix's covariance grows accordingly instead of lying to a filter.
    Each star gives 2 measurements; the attitude takes 3 degrees of freedom."""
    dof = 2 * len(w.residuals_rad) - 3
    return max(1.0, w.loss / dof) if dof > 0 else 1.0


def _one_to_one(d: NDArray, j: NDArray) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """From a nearest-neighbour query (distance ∞ = none within the bound): detections
    with a match, each target kept by its closest detection (ties to the lower index, so
    the result does not depend on timing); returns (detection indices, targets)."""
    det = np.flatnonzero(np.isfinite(d))
    if len(det) == 0:
        return det.astype(np.int64), det.astype(np.int64)
    det = det[np.lexsort((det, d[det]))]
    _, first = np.unique(j[det], return_index=True)
    det = np.sort(det[first])
    return det.astype(np.int64), j[det].astype(np.int64)


def _keeps_pattern(det_i: NDArray, cat_i: NDArray, sel: NDArray, assign: NDArray,
                   n_det: int) -> bool:
    """Whether the association kept every pattern star on its assigned catalogue star."""
    lookup = np.full(n_det, -1, dtype=np.int64)
    lookup[det_i] = cat_i
    return bool(np.all(lookup[sel] == assign))


def _rotation_from_pairs(b: NDArray, r: NDArray) -> NDArray | None:
    """Least-squares rotation (cam ← icrs) from matched directions (lean SVD Wahba)."""
    u, sv, vt = np.linalg.svd(b.T @ r)
    if sv[1] < 1e-12 * max(sv[0], 1e-300):
        return None  # collinear: rotation about the common axis undetermined
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        u[:, 2] = -u[:, 2]
    return u @ vt


def _distinct(cands: list[Candidate], tol_rad: float) -> list[Candidate]:
    """Collapse candidates with the same attitude (e.g. a swapped close pair)."""
    if len(cands) <= 1:
        return list(cands)
    out: list[Candidate] = []
    for c in sorted(cands, key=lambda c: c.p_false):
        if all(rot.angle_between(c.q_cam_icrs, o.q_cam_icrs) > tol_rad for o in out):
            out.append(c)
    return out


def _catalog_tag(vectors: NDArray) -> str:
    return hashlib.sha1(np.ascontiguousarray(vectors).tobytes()).hexdigest()


def _replace(sol: Solution, **kw) -> Solution:
    from dataclasses import replace

    return replace(sol, **kw)
