"""Lost-in-space star identification: detections + camera → verified attitude.

The pipeline for one frame (Renken 1998 §6–§9, docs/references.md#renken-1998; with a
verification stage of our own):

1. take the brightest ``n_max`` detections (3…6) as the pattern, closest pair first;
2. enumerate every catalogue assignment consistent with all pair distances
   (:mod:`starid.identify.nstar`; the count is Renken's ``matching_counter``);
3. verify each assignment: Wahba attitude, project the catalogue, match the other
   detections, and compute the false-match probability (:mod:`starid.identify.verify`);
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

import math
import time
from dataclasses import replace
from typing import Any

import numpy as np
from adfusion.starid.bleif.bridge import BleifSearch
from adfusion.starid.camera.model import Camera
from adfusion.starid.camera.view import stars_in_view
from adfusion.starid.catalog.pair_index import PatternIndex, catalog_cache_tag
from adfusion.starid.config import SolverConfig
from adfusion.starid.identify import frame_kernels, kernels
from adfusion.starid.identify.candidates import EVIDENCE_RATIO
from adfusion.starid.identify.catalog_view import CatalogView
from adfusion.starid.identify.lost_in_space import PatternSearch, focal_scales, outside_as_nan
from adfusion.starid.identify.refine import Refiner
from adfusion.starid.identify.search_state import input_bounds
from adfusion.starid.identify.solution import Candidate, Prior, Solution
from adfusion.starid.identify.verify import (
    Verifier,
    match_radius_px,
)
from adfusion.starid.tracking.tracking import Tracker
from adfusion.starid.triad.bridge import TriadSearch
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from adfusion.maths import rotations as rot

__all__ = ["Candidate", "Prior", "Solution", "Solver", "SolverConfig"]

# a tracking fix matching fewer than this share of min(predicted, detections) is checked
# against lost-in-space on the same frame (Solver._cross_checked)
_CROSS_CHECK_SHARE = 0.5
# patterns the rest of a frame is searched with (stars left over in numbers are found in
# the first few; the full budget on a rest of noise would cost ~10× the fix)
_CHECK_PATTERNS = 20
_SKY_MAP_MAX_RAD = 0.01  # the sky map's radius at most (rad): past it, no map

# the solver's attributes its parts were made with: (part, the part's attribute) each
# (Solver.__setattr__ passes a later assignment on)
_PART_SETTINGS: dict[str, tuple[tuple[str, str], ...]] = {
    "camera": (("view", "camera"), ("refiner", "camera"), ("tracker", "camera"),
               ("search", "camera")),
    "centroid_sigma_px": (("verifier", "centroid_sigma_px"), ("refiner", "centroid_sigma_px"),
                          ("tracker", "centroid_sigma_px"), ("search", "centroid_sigma_px")),
    "tolerance_rad": (("tracker", "tolerance_rad"), ("bleif", "tolerance_rad"),
                      ("search", "tolerance_rad")),
    "max_sep_rad": (("verifier", "max_sep_rad"),),
    "_fov_uncertain": (("verifier", "fov_uncertain"), ("refiner", "fov_uncertain"),
                       ("search", "_fov_uncertain")),
    "fit_camera": (("refiner", "fit_camera"),),
    "p_false_max": (("triad", "p_false_max"), ("bleif", "p_false_max"),
                    ("search", "p_false_max")),
    "triad_params": (("triad", "params"),),
    "bleif_params": (("bleif", "params"),),
    "p_false_max_tracking": (("tracker", "p_false_max_tracking"),),
    "max_fix_sigma_px": (("tracker", "max_fix_sigma_px"),),
    "whole_streak_px": (("tracker", "whole_streak_px"),),
    **{name: (("search", name),) for name in (
        "n_min", "n_max", "max_detections", "max_patterns", "work_budget", "fov_error_deg",
        "fov_range_deg", "faithful", "n_bands", "dec_check")},
}


class Solver:
    """Lost-in-space identification against a catalogue for one camera.

    Args:
        catalog: a :class:`starid.Catalog` (anything with ``vectors`` and ``ids``).
        camera: the :class:`starid.Camera` (its focal length is the FOV estimate).
        config: the options as one :class:`~adfusion.starid.config.SolverConfig` (default:
            its defaults); ``solver.config`` is the one in use.
        **options: any field of :class:`~adfusion.starid.config.SolverConfig` by name
            (``fov_error_deg=0.5``, ``method="triad"`` …), in place of ``config``'s value.

    Its parts, each an object made with what it reads (they share no state but the
    catalogue view, and call each other only through the methods named here):

    * ``view`` — :class:`~adfusion.starid.identify.catalog_view.CatalogView` (catalogue,
      camera, vectors, ids, KD-tree, pattern index and its compiled arrays): the context
      the others share, and the projection of the catalogue into a frame;
    * ``search`` — :class:`~adfusion.starid.identify.lost_in_space.PatternSearch` (view,
      verifier, refiner, camera and the search's settings): lost-in-space, Renken's
      patterns and ours at every focal guess (``solve_at``, ``solve_refined``,
      ``solve_lean``);
    * ``verifier`` — :class:`~adfusion.starid.identify.verify.Verifier` (view, centroid
      σ, index radius, whether the FOV is uncertain): quick check, full verification,
      p_false;
    * ``refiner`` — :class:`~adfusion.starid.identify.refine.Refiner` (view, camera,
      centroid σ, ``fit_camera``, FOV uncertain): the final fit;
    * ``tracker`` — :class:`~adfusion.starid.tracking.tracking.Tracker` (view, verifier,
      camera, the tracking thresholds): identification near a prior;
    * ``triad`` — :class:`~adfusion.starid.triad.bridge.TriadSearch` and ``bleif`` —
      :class:`~adfusion.starid.bleif.bridge.BleifSearch` (view, verifier, their
      parameters, ``p_false_max``): ``method="triad"`` and ``method="bleif"``.

    The solver itself checks the input, picks the part (tracking with a prior, the
    configured method without), and cross-checks what they return: a tracking fix the
    frame contradicts, a lost-in-space fix that leaves most detections unexplained.
    Settings assigned to the solver after it was made reach the parts that read them.
    """

    def __init__(self, catalog, camera: Camera, config: SolverConfig | None = None,
                 **options: Any) -> None:
        c = self.config = SolverConfig.of(config, **options)
        method, n_min, n_max = c.method, c.n_min, c.n_max
        centroid_sigma_px, tolerance_deg, p_false_max = (c.centroid_sigma_px, c.tolerance_deg,
                                                         c.p_false_max)
        fov_error_deg, fov_range_deg, fit_camera = c.fov_error_deg, c.fov_range_deg, c.fit_camera
        faithful, n_bands, dec_check, cache = c.faithful, c.n_bands, c.dec_check, c.cache
        max_detections, max_patterns, work_budget = (c.max_detections, c.max_patterns,
                                                     c.work_budget)
        self.method = method
        self.triad_params = c.triad_params
        self.bleif_params = c.bleif_params
        self.max_tracking_cone_deg = float(c.max_tracking_cone_deg)
        self.max_fix_sigma_px = float(c.max_fix_sigma_px)
        self.p_false_max_tracking = float(c.p_false_max_tracking)
        self.whole_streak_px = float(c.whole_streak_px)
        if fov_range_deg is not None and camera.model != "pinhole":
            raise ValueError("fov_range_deg needs a pinhole camera model")
        if not 0 <= fov_error_deg < camera.fov_x_deg:
            raise ValueError(f"fov_error_deg must be in [0, {camera.fov_x_deg:.2f}) for this "
                             f"camera, got {fov_error_deg}")
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
        self.fov_range_deg = fov_range_deg
        self._fov_uncertain = bool(fov_error_deg) or fov_range_deg is not None
        self.fit_camera = fit_camera
        self.faithful = faithful
        self.n_bands = int(n_bands)
        self.dec_check = dec_check
        self.max_detections = int(max_detections)
        self.max_patterns = int(max_patterns)
        self.work_budget = int(work_budget)
        # the index must reach across the widest field any focal guess gives
        widest = (camera.scaled(min(focal_scales(camera, self.fov_error_deg, fov_range_deg)))
                  if self._fov_uncertain else camera)
        self.max_sep_rad = float(np.radians(widest.diagonal_fov_deg) + 2 * self.tolerance_rad)
        # keyed by the star set, not the epoch: a later epoch reuses the index (index.py)
        tag = catalog_cache_tag(catalog) if cache else None
        t0 = time.perf_counter()
        self.index = PatternIndex.from_vectors(self.vectors, self.max_sep_rad, cache_tag=tag)
        self.index_build_s = time.perf_counter() - t0
        self._tree = cKDTree(self.vectors)
        # the association's sky map covers the widest guess's match radius (a kernel
        # asked for more ignores it); none for pixels so coarse that it would cover the sky
        sky_rad = match_radius_px(self.centroid_sigma_px) * widest.pixel_scale_rad * 1.01
        cells = kernels.SKY_CELLS  # the map is made and read at the same cells per edge
        self._sky = ((kernels.sky_map(self.vectors, sky_rad, cells), cells, sky_rad)
                     if sky_rad < _SKY_MAP_MAX_RAD else None)
        # the parts (each told what it reads; the catalogue view is their shared context)
        self.view = CatalogView(catalog, camera, self.vectors, self.ids, self._tree,
                                self.index, kernels.index_arrays(self.index, None, self._sky))
        self.verifier = Verifier(self.view, self.centroid_sigma_px, self.max_sep_rad,
                                 self._fov_uncertain)
        self.refiner = Refiner(self.view, camera, self.centroid_sigma_px, fit_camera,
                               self._fov_uncertain)
        self.triad = TriadSearch(self.view, self.verifier, self.triad_params, p_false_max)
        self.bleif = BleifSearch(self.view, self.verifier, self.bleif_params, p_false_max,
                                 self.tolerance_rad)
        self.tracker = Tracker(self.view, self.verifier, camera, self.centroid_sigma_px,
                               self.tolerance_rad, self.p_false_max_tracking,
                               self.max_fix_sigma_px, self.whole_streak_px)
        self.search = PatternSearch(
            self.view, self.verifier, self.refiner, camera, tolerance_rad=self.tolerance_rad,
            centroid_sigma_px=self.centroid_sigma_px, cache_tag=tag, n_min=n_min, n_max=n_max,
            p_false_max=p_false_max, max_detections=self.max_detections,
            max_patterns=self.max_patterns, work_budget=self.work_budget,
            fov_error_deg=self.fov_error_deg, fov_range_deg=fov_range_deg, faithful=faithful,
            n_bands=self.n_bands, dec_check=dec_check)

    # --- public -----------------------------------------------------------------------

    def solve(self, detections, prior: Prior | None = None) -> Solution:
        """Identify the stars of one frame.

        ``detections`` is a :class:`starid.Detections`, or an (N, 2) array of pixel
        positions (brightest first), or (N, 3) with flux as the third column (sorted here).
        Problems with the data give ``ok=False`` with a ``reason``; only a wrong type or
        shape raises.
        """
        t0 = time.perf_counter()
        if prior is None and type(detections) is np.ndarray and self.method == "nstar":
            lean = self.search.solve_lean(detections, t0)
            if lean is not None:
                sol, final = lean
                if final:
                    return sol
                return self._rest_checked(sol, detections,
                                          detections[:self.max_detections], t0)
        xy, problem = self._parse(detections, min_count=2 if prior is not None else 3)
        if problem:
            return Solution(False, problem, time_s=time.perf_counter() - t0,
                            n_detections=len(xy), mode="tracking" if prior else "lost-in-space")
        fallback_note = ""
        if prior is not None:
            if prior.k * prior.sigma_deg <= self.max_tracking_cone_deg:
                sol = self.tracker.solve(xy, prior, t0)
                if sol.ok:
                    return self._cross_checked(sol, detections, xy, t0)
                fallback_note = f"tracking failed ({sol.reason}); "
            else:
                fallback_note = (f"prior too loose ({prior.k:g}σ = {prior.k * prior.sigma_deg:.3g}°"
                                 f" > {self.max_tracking_cone_deg:g}°); ")
            if len(xy) < 3:
                return Solution(False, fallback_note + "too few detections for lost-in-space",
                                mode="tracking", time_s=time.perf_counter() - t0,
                                n_detections=len(xy))
        sol = self._lost_in_space(detections, xy, t0)
        if fallback_note and not sol.ok:
            sol = replace(sol, reason=fallback_note + sol.reason)
        return self._rest_checked(sol, detections, xy, t0)

    def _lost_in_space(self, detections, xy: NDArray, t0: float,
                       cams: list[Camera] | None = None) -> Solution:
        """The frame identified without a prior (the configured method), refined; with the
        n-star method at the focal guesses ``cams`` (default: all the FOV range needs)."""
        if self.method in ("triad", "bleif"):
            sol = (self.triad if self.method == "triad" else self.bleif).solve(xy)
            sol = self.refiner.refine(sol, self._all_xy(detections, xy))
            return replace(sol, time_s=time.perf_counter() - t0, n_detections=len(xy),
                           patterns_tried=1)
        return self.search.solve_refined(xy, cams or self._focal_guesses(),
                                         self._all_xy(detections, xy, mark_outside=False), t0)

    def _focal_guesses(self) -> list[Camera]:
        return [self.camera.scaled(k) if k != 1.0 else self.camera
                for k in self.search.focal_scales()]

    def _rest_checked(self, sol: Solution, detections, xy: NDArray, t0: float) -> Solution:
        """A lost-in-space fix that explains fewer than half of the detections the search
        used, checked by searching the detections it leaves unexplained
        (docs/concepts/identification.md, "The rest of the frame").

        ``p_false`` bounds the chance that a wrong attitude fits this well, but the search
        stops at the first candidate that passes; when most detections are left over and
        they are stars, the right attitude is among them. The long fuzz run accepted a fix
        162° off at p_false 5.9e-7: a 5-star sub-pattern (4 stars and a false one) fitted
        a distant sky patch and explained 7 of 30 detections, 21 of which were stars
        (benchmarks/fuzz.py, seed 37). A distinct attitude verified on the rest decides by
        the evidence (``p_false`` :data:`EVIDENCE_RATIO` times smaller), else the frame is
        ambiguous; a rest that holds nothing leaves the fix as it was."""
        if not sol.ok or self.method != "nstar":
            return sol
        # the search's detections used: matches are one pair per detection, so with none
        # past the search's, their count (the common case: no set to build)
        n_all, n = len(detections.xy if hasattr(detections, "xy") else detections), len(xy)
        n_used = len(sol.matches) if n_all <= n else sum(d < n for d, _ in sol.matches)
        if not self.search.rest_wanted(n_used, n):
            return sol
        used = {d for d, _ in sol.matches}
        rest = np.array([i for i in range(len(xy)) if i not in used], dtype=np.int64)
        # the camera the fix fitted; the first patterns of the rest (its brightest): stars
        # left over in numbers are found there, and a rest of noise costs little
        other, tried = self.search.solve_at(np.ascontiguousarray(xy[rest]),
                                      [sol.camera or self.camera], _CHECK_PATTERNS)
        if not other.ok:
            return replace(sol, time_s=time.perf_counter() - t0,
                           patterns_tried=sol.patterns_tried + tried)
        # the rest's indices back to the frame's
        other = replace(other, matches=[(int(rest[d]), h) for d, h in other.matches],
                        candidates=[replace(c, matches=[(int(rest[d]), h) for d, h in c.matches])
                                    for c in other.candidates])
        other = self.refiner.refine(other, self._all_xy(detections, xy))
        apart = math.degrees(rot.angle_between(other.q_cam_icrs, sol.q_cam_icrs))
        total = sol.patterns_tried + tried
        if apart <= math.degrees(3 * self.tolerance_rad):  # the same attitude, found twice
            return replace(sol, time_s=time.perf_counter() - t0, patterns_tried=total)
        note = (f"two attitudes {apart:.3g}° apart fit the frame: {len(sol.matches)} stars at "
                f"p_false {sol.p_false:.2g}, {len(other.matches)} stars of the other "
                f"{len(rest)} detections at p_false {other.p_false:.2g}")
        if other.p_false * EVIDENCE_RATIO <= sol.p_false:
            best = other
        elif sol.p_false * EVIDENCE_RATIO <= other.p_false:
            best = sol
        else:
            return Solution(False, "ambiguous: " + note, mode="lost-in-space", path=sol.path,
                            matching_counter=sol.matching_counter,
                            candidates=sol.candidates + other.candidates,
                            time_s=time.perf_counter() - t0, n_detections=len(xy),
                            patterns_tried=total)
        return replace(best, note="; ".join(n for n in (best.note, note) if n),
                       time_s=time.perf_counter() - t0, n_detections=len(xy),
                       patterns_tried=total)

    def _cross_checked(self, track: Solution, detections, xy: NDArray,
                       t0: float) -> Solution:
        """A tracking fix that explains few of the frame's stars, checked against the frame
        identified without the prior (docs/concepts/tracking.md, "A prior the frame
        contradicts").

        Tracking's ``p_false`` is the chance of its matches *if the prior is right*. A
        prior many σ wrong (a filter after a missed manoeuvre or a glitched gyro) still
        finds a few chance pairs near its predictions, and a dense field fits them: the
        long fuzz run accepted fixes 0.9–1.2° off under a prior 20σ wrong, matching 2–4
        stars of 15–66 detections where the right attitude explains 10–60
        (benchmarks/fuzz.py, seed 37). When fewer than half of what could match did,
        lost-in-space runs on the same detections: a fix it accepts away from the
        tracking fix wins (the prior is contradicted, said in ``note``); otherwise, or
        when it finds nothing, the tracking fix stands only if it would pass as a
        lost-in-space fix: the looser tracking threshold is bought by the prior, which is
        what such a frame puts in doubt (seed 59: 3 of 29 detections fitted 1.14° off
        under a prior 20σ wrong, p_false 8.4e-5, where lost in space found nothing)."""
        could_match = min(track.n_predicted, track.n_detections)
        if (len(track.matches) >= _CROSS_CHECK_SHARE * could_match
                or track.n_detections < 3):
            return track
        # at the camera tracking assumed (a frame it fitted badly is no reason to search
        # the whole FOV range every frame)
        lis = self._rest_checked(self._lost_in_space(detections, xy, t0, [self.camera]),
                                 detections, xy, t0)
        if not lis.ok:
            if track.p_false <= self.p_false_max:
                return track
            return Solution(
                False, f"ambiguous: tracking fitted {len(track.matches)} of {could_match} "
                f"stars near the prior (p_false {track.p_false:.2g}, above the "
                f"{self.p_false_max:.0e} a fix that explains so little needs), and lost in "
                f"space found nothing ({lis.reason})", mode="tracking",
                matching_counter=track.matching_counter, path=track.path,
                candidates=track.candidates, n_detections=track.n_detections,
                n_predicted=track.n_predicted, time_s=time.perf_counter() - t0)
        apart = float(rot.angle_between(lis.q_cam_icrs, track.q_cam_icrs))
        both = math.sqrt(float(np.trace(lis.covariance) + np.trace(track.covariance)))
        if apart <= max(5.0 * both, self.tolerance_rad):
            return track
        note = (f"prior contradicted: tracking fitted {len(track.matches)} of "
                f"{could_match} stars near it, lost-in-space {len(lis.matches)} stars "
                f"{math.degrees(apart):.3g}° away")
        return replace(lis, note="; ".join(n for n in (lis.note, note) if n))

    def warm_up(self, triangles: bool = True) -> bool:
        """Pay the lost-in-space search's one-time costs now rather than in the first
        frames: its compiled kernels (:mod:`starid.identify.kernels`: search, verification, final
        refit) load from numba's cache in ~1 s (a wheel ships them compiled) — or, the first
        time after an editable install unless ``python -m adfusion.starid.prepare`` prepared
        it, compile in 60–120 s — on their first
        call in a process, each detection count's pattern order is computed on first
        use, and the catalogue's triangles (:mod:`starid.catalog.triangle_index`) are built —
        ~6 s the first time for V < 6 in a 15° field — or loaded from the cache
        (~0.2 s; ``triangles=False`` leaves that to the first frame that needs more than
        Renken's patterns — a command that solves a few frames may never need it). Call
        it once before a timed or real-time loop. Returns whether a synthetic
        frame (the catalogue seen at a few fixed attitudes) was solved.

        >>> from adfusion import starid
        >>> s = starid.Solver(starid.Catalog.hipparcos(mag_limit=5.0),
        ...                   starid.Camera.pinhole(1024, 768, 15.0))
        >>> s.warm_up()
        True
        """
        for dec in (0.5, -0.5, 1.2, -1.2, 0.0):
            pxy, _, idx = self.view.project_idx(rot.q_cam_icrs_from_radec_roll(1.0, dec, 0.0),
                                                self.camera)
            if len(idx) >= 4:
                break
        else:
            return False
        if self.method == "nstar":
            solved = self.search.warm_up(pxy, idx, triangles)
        else:
            solved = self.solve(pxy[:8]).ok
            self.search.warm_up_weak(pxy, idx)
        self._parse(np.ascontiguousarray(pxy[:8]))  # its input check (compiled)
        return solved

    def warm_up_tracking(self) -> bool:
        """Load the compiled tracking path (:mod:`starid.tracking.kernels`, and the window
        centroiding of :mod:`starid.detection.window_kernels`) now rather than
        in the first tracked frame: ~0.1 s from numba's cache, or — the first time after
        an install or an edit — ~5 s of CPU compiling it once. Call it (with
        :meth:`Solver.warm_up`, which loads the lost-in-space kernels) before a real-time
        loop. Returns whether a synthetic tracked frame (the catalogue seen at a fixed
        attitude, told to the solver as a 0.01° prior) was accepted.

        >>> from adfusion import starid
        >>> s = starid.Solver(starid.Catalog.hipparcos(mag_limit=5.0),
        ...                   starid.Camera.pinhole(512, 480, 25.84))
        >>> s.warm_up_tracking()
        True
        """
        from adfusion.starid.detection.windows import detect_windows  # (detect_roi: no solver)

        # the compiled window centroiding (starid.detection.window_kernels) of integer and float
        # frames, as TrackingWindows uses it
        for dtype in (np.uint16, np.float32, np.float64):
            img = np.full((32, 32), 100, dtype)
            img[15:17, 15:17] = 200
            detect_windows(img, [[15.5, 15.5]], 4)
        for dec in (0.5, -0.5, 1.2, -1.2, 0.0):
            q = rot.q_cam_icrs_from_radec_roll(1.0, dec, 0.0)
            pxy, _, idx = self.view.project_idx(q, self.camera)
            if len(idx) >= 3:
                return self.solve(pxy[:10], prior=Prior(q, 0.01)).ok
        return False

    def stars_in_view(self, q_cam_icrs) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Catalogue ids and pixel positions of the catalogue stars inside the frame at an
        attitude (``q_cam_icrs``), brightest first:
        :func:`adfusion.starid.camera.view.stars_in_view`
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
        # compiled (frame_kernels.input_problem): this runs per frame, and its half-dozen
        # numpy calls cost more than the checks
        use = xy[: self.max_detections]
        code, a, b = frame_kernels.input_problem(np.ascontiguousarray(xy), len(use),
                                                 *input_bounds(self.camera))
        if code == 1:
            return xy, f"bad input: {a} non-finite centroid(s), first at row {b}"
        if code == 2:
            return xy, f"bad input: centroid row {a} lies far outside the frame"
        if code == 3:
            return xy, f"bad input: duplicate centroids at rows {a} and {b}"
        return use, ""

    def _all_xy(self, detections, use: NDArray, mark_outside: bool = True,
                ) -> NDArray[np.float64]:
        """Every detection (not only the brightest ``max_detections`` the search uses),
        in the order of ``use``, for the final fit. Those past ``use`` that lie outside
        the frame become NaN, which the fit leaves out: dropping them instead shifted
        every later row, so matches named the wrong detections. ``mark_outside`` False:
        as given (the lost-in-space search marks them for its Python refit, and the
        one-call frame's refit leaves them out itself)."""
        if len(detections.xy if hasattr(detections, "xy") else detections) <= len(use):
            return use
        if hasattr(detections, "xy"):
            xy = np.asarray(detections.xy, dtype=np.float64)
        else:
            arr = np.asarray(detections, dtype=np.float64)
            if arr.shape[1] == 3:
                arr = arr[np.argsort(-arr[:, 2], kind="stable")]
            xy = arr[:, :2]
        if len(xy) <= len(use):
            return use
        return outside_as_nan(self.camera, xy, len(use)) if mark_outside else xy

    def __setattr__(self, name: str, value: Any) -> None:
        # a setting one of the parts was made with, set on the solver after it was made,
        # reaches that part too; and any assignment drops the search's compiled one-call
        # state (a switch of the verifier's or the refiner's reads the same way)
        object.__setattr__(self, name, value)
        d = self.__dict__
        for part, attr in _PART_SETTINGS.get(name, ()):
            held = d.get(part)
            if held is not None:
                setattr(held, attr, value)
        search = d.get("search")
        if search is not None and name != "search":
            search.settings_changed()

    # --- the compiled paths' switches (benchmarks/compiled_equivalence.py) ------------------

    @property
    def _compiled_verify(self) -> bool:
        """Whether a known camera's candidates are verified compiled (:attr:`Verifier.compiled`)."""
        return self.verifier.compiled

    @_compiled_verify.setter
    def _compiled_verify(self, value: bool) -> None:
        self.verifier.compiled = value

    @property
    def _compiled_refine(self) -> bool:
        """Whether the final refit runs compiled (:attr:`Refiner.compiled`)."""
        return self.refiner.compiled

    @_compiled_refine.setter
    def _compiled_refine(self, value: bool) -> None:
        self.refiner.compiled = value

    @property
    def _compiled(self) -> bool:
        """Whether the search runs compiled (``PatternSearch._compiled``; False with the
        matchers kept in numpy)."""
        return self.search._compiled

    @_compiled.setter
    def _compiled(self, value: bool) -> None:
        self.search._compiled = value

    @property
    def _frame_kernel(self) -> bool:
        """Whether a known ideal pinhole's search, verification and refit run as one
        compiled call (``PatternSearch._frame_kernel``; deleting it restores the default)."""
        return self.search._frame_kernel

    @_frame_kernel.setter
    def _frame_kernel(self, value: bool) -> None:
        self.search._frame_kernel = value

    @_frame_kernel.deleter
    def _frame_kernel(self) -> None:
        del self.search._frame_kernel


def _replace(sol: Solution, **kw) -> Solution:
    return replace(sol, **kw)
