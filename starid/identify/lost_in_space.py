"""Lost-in-space search of the :class:`starid.Solver`: patterns in Renken's order (main
pattern, Not-Modus, then our combinations), each at every focal-length guess, matched
against the pattern index (compiled, :func:`starid.identify.kernels.search`, or in numpy for the
faithful and banded matchers), candidates verified (:mod:`starid.identify.verify`).

Example:
    >>> from adfusion import starid
    >>> s = starid.Solver(starid.Catalog.hipparcos(mag_limit=4.0),
    ...                   starid.Camera.pinhole(1024, 768, 15.0))
    >>> isinstance(s.search, PatternSearch), s.search.focal_scales()
    (True, [1.0])
"""

from __future__ import annotations

import bisect
import itertools
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from adfusion.starid.camera.model import Camera
from adfusion.starid.catalog.triangle_index import triangles_for
from adfusion.starid.identify import frame_kernels, kernels, search_order
from adfusion.starid.identify.candidates import (
    _accepted,
    _candidate,
    _refitted,
    resolve_by_evidence,
)
from adfusion.starid.identify.nstar import (
    Pattern,
    WorkBudgetExceeded,
    closest_pair_first,
    match_faithful,
    match_indexed,
)
from adfusion.starid.identify.refine import (
    _PRIOR_DOF,
    _RADIUS_MAX_FACTOR,
    _RADIUS_SIGMA,
    _REJECT_SIGMA,
)
from adfusion.starid.identify.search_state import PairWindows, Search, directions, input_bounds
from adfusion.starid.identify.solution import Candidate, Solution, accepted_solution
from adfusion.starid.identify.verify import distinct_candidates, quick_tuples
from numpy.typing import NDArray

if TYPE_CHECKING:
    from adfusion.starid.identify.catalog_view import CatalogView
    from adfusion.starid.identify.refine import Refiner
    from adfusion.starid.identify.verify import Verifier

__all__ = ["MAX_BUDGET_SCALES", "REST_CHECK_SHARE", "SCALE_STEP", "PatternSearch",
           "focal_scales"]


#: focal guesses the trial budget grows with (beyond, a frame gets fewer patterns per guess)
MAX_BUDGET_SCALES = 50


# the final refit's constants (starid.identify.refine), as solve_frame takes them
_REFIT_CONSTANTS = (_REJECT_SIGMA, _RADIUS_SIGMA, _RADIUS_MAX_FACTOR, float(_PRIOR_DOF))


# the search's work arrays, one per thread (PatternSearch._scratch)
_SCRATCH = threading.local()


# one table built at a time (solvers shared across threads)
_TRIANGLES_LOCK = threading.Lock()


# the bound of the warm-up's search of its synthetic frame (patterns, partial assignments)
_WARM_UP_PATTERNS, _WARM_UP_WORK = 3, 20_000

_FLOAT64 = np.dtype(np.float64)  # (an identity test: cheaper than comparing dtypes)


#: a lost-in-space fix explaining fewer than this share of the detections the search used
#: has the rest of them searched too (``Solver._rest_checked``)
REST_CHECK_SHARE = 0.5


# the lean path: a thread's work arrays before its first call (too small: the kernel asks
# for them), empty pattern lists (fewer than 3 detections), and the attributes a solve
# caches (they keep its state)
_NO_LEAN = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64),
            np.zeros(0, dtype=np.int64), np.zeros(0))


#: the lean path's result arrays' first length (a frame with more grows them)
_LEAN_OUT = 1024


_NO_PATS, _NO_COUNTS = np.zeros((0, 8), dtype=np.int64), np.zeros(0, dtype=np.int64)


_LEAN_KEEPS = frozenset({"_lean", "_frame_camera_kept", "_triangles_done"})

#: the focal-length grid's step when the field of view is searched (1 %: the pair windows
#: widen by half a step × the pair's distance)
SCALE_STEP = 0.01
NO_MATCH_P_FALSE = 0.01  # a best candidate this likely by chance: "no match", not weak


def focal_scales(camera: Camera, fov_error_deg: float, fov_range_deg: Any) -> list[float]:
    """Focal-length multipliers covering a field-of-view uncertainty (1.0 first when it is
    inside): ``fov_error_deg`` (± around ``camera``'s) or ``fov_range_deg`` (lo, hi);
    ``[1.0]`` when the field of view is known (both 0 / None).

    >>> from adfusion.starid.camera.model import Camera
    >>> ks = focal_scales(Camera.pinhole(1024, 768, 15.0), 0.5, None)
    >>> ks[0], len(ks), round(min(ks), 3), round(max(ks), 3)
    (1.0, 9, 0.967, 1.035)
    """
    if not fov_error_deg and fov_range_deg is None:
        return [1.0]
    half = np.radians(camera.fov_x_deg) / 2
    if fov_range_deg is not None:
        # focal scale k turns the nominal FOV into 2·atan(tan(half) / k)
        fov_lo, fov_hi = np.radians(fov_range_deg) / 2
        lo = np.tan(half) / np.tan(fov_hi)
        hi = np.tan(half) / np.tan(fov_lo)
    else:
        lo = np.tan(half) / np.tan(half + np.radians(fov_error_deg) / 2)
        hi = np.tan(half) / np.tan(max(half - np.radians(fov_error_deg) / 2, 1e-6))
    n = max(3, int(np.ceil(np.log(hi / lo) / np.log1p(SCALE_STEP))) + 1)
    grid = np.exp(np.linspace(np.log(lo), np.log(hi), n))
    order = np.argsort(np.abs(np.log(grid)))
    rest = [float(g) for g in grid[order] if abs(np.log(g)) > 1e-12]
    return [1.0, *rest] if lo <= 1.0 <= hi else rest


def outside_as_nan(camera: Camera, xy_all: NDArray, n_use: int) -> NDArray[np.float64]:
    """``xy_all`` with the rows past ``n_use`` that lie outside ``camera``'s frame as NaN
    (a copy when there are any: the caller's array stays as it was), which the final fit
    leaves out: dropping them instead would shift every later row.

    >>> from adfusion.starid.camera.model import Camera
    >>> outside_as_nan(Camera.pinhole(100, 80, 10.0), np.array([[5.0, 5], [500, 5]]), 1)
    array([[ 5.,  5.],
           [nan, nan]])
    """
    outside = ~camera.in_frame(xy_all[n_use:])
    if not outside.any():
        return xy_all
    xy_all = xy_all.copy()
    xy_all[n_use:][outside] = np.nan
    return xy_all


class PatternSearch:
    """The lost-in-space part of :class:`starid.Solver`: Renken's patterns (and ours) of
    a frame's detections matched against the pattern index at every focal guess, each
    match through the verifier, the accepted one through the refiner.

    Args:
        view: the catalogue (:class:`~adfusion.starid.identify.catalog_view.CatalogView`:
            vectors, ids, the pattern index and its compiled arrays, the projection).
        verifier: the :class:`~adfusion.starid.identify.verify.Verifier` of candidates.
        refiner: the :class:`~adfusion.starid.identify.refine.Refiner` of the final fit.
        camera: the solver's camera (the nominal one when the field of view is searched).
        settings: the :class:`~adfusion.starid.config.SolverConfig` fields it reads, by
            name (``n_min``, ``n_max``, ``p_false_max``, ``max_detections``,
            ``max_patterns``, ``work_budget``, ``fov_error_deg``, ``fov_range_deg``,
            ``faithful``, ``n_bands``, ``dec_check``), with ``tolerance_rad`` and
            ``centroid_sigma_px`` as the solver resolved them, and ``cache_tag`` (the
            catalogue's cache key, None: no cache).

    Any assignment to it (a setting, the index's arrays, the camera) drops the compiled
    state of its one-call path (:meth:`_lean_state`): every setting a solve reads is one
    of its attributes. :class:`starid.Solver` passes its own settings' assignments on.
    """

    def __init__(self, view: CatalogView, verifier: Verifier, refiner: Refiner,
                 camera: Camera, *, tolerance_rad: float, centroid_sigma_px: float,
                 cache_tag: str | None, **settings: Any) -> None:
        self.view = view
        self.verifier = verifier
        self.refiner = refiner
        self.camera = camera
        self.tolerance_rad = float(tolerance_rad)
        self.centroid_sigma_px = float(centroid_sigma_px)
        self._cache_tag = cache_tag
        self.n_min, self.n_max = int(settings.pop("n_min")), int(settings.pop("n_max"))
        self.p_false_max = float(settings.pop("p_false_max"))
        self.max_detections = int(settings.pop("max_detections"))
        self.max_patterns = int(settings.pop("max_patterns"))
        self.work_budget = int(settings.pop("work_budget"))
        self.fov_error_deg = float(settings.pop("fov_error_deg"))
        self.fov_range_deg = settings.pop("fov_range_deg")
        self._fov_uncertain = bool(self.fov_error_deg) or self.fov_range_deg is not None
        self.faithful = bool(settings.pop("faithful"))
        self.n_bands = int(settings.pop("n_bands"))
        self.dec_check = settings.pop("dec_check")
        if settings:
            raise TypeError(f"PatternSearch: unknown settings {', '.join(sorted(settings))}")
        # the search runs compiled, except with the matchers kept in numpy
        self._compiled = not (self.faithful or self.n_bands > 1)

    @property
    def _ix(self) -> tuple:
        """The compiled index arrays (:attr:`CatalogView.ix`); assigned here (the
        triangles joining them), the one-call path's state is made again."""
        return self.view.ix

    @_ix.setter
    def _ix(self, value: tuple) -> None:
        self.view.ix = value

    def settings_changed(self) -> None:
        """Drop the one-call path's compiled state (made again on the next solve): for a
        setting of another part (the verifier's or refiner's ``compiled``) changed."""
        self._lean_changed(lambda _self: None)

    def focal_scales(self) -> list[float]:
        """Focal-length multipliers covering the FOV uncertainty (1.0 first):
        :func:`focal_scales` of this search's camera and settings."""
        return focal_scales(self.camera, self.fov_error_deg, self.fov_range_deg)

    def _trial_budget(self, n_scales: int, per_guess: int | None = None) -> int:
        """(pattern, focal guess) trials a frame may take: ``max_patterns`` (or
        ``per_guess``) per guess, for at most :data:`MAX_BUDGET_SCALES` guesses — a wide
        FOV range (5°–40°: 200 guesses) must not make a frame without an answer cost 200×
        a known camera's."""
        return (per_guess or self.max_patterns) * min(n_scales, MAX_BUDGET_SCALES)

    @property
    def _rel_tol(self) -> float:
        """The pair windows' widening per radian of pair distance: half a focal step when
        the focal length is searched, else none."""
        return 0.5 * SCALE_STEP if self._fov_uncertain else 0.0

    def warm_up(self, pxy: NDArray, idx: NDArray, triangles: bool = True) -> bool:
        """``Solver.warm_up``'s search part, on a synthetic frame (``pxy``: the catalogue's
        projection, ``idx``: its rows): the search bounded (the kernels compile or load on
        their first call whatever it finds, and a camera whose match windows span degrees
        (32×24 px over 44°: 1.4° a pixel) spent ~110 s solving this frame in the fuzz's
        CLI cases), the triangles (``triangles``), every detection count's patterns, the
        one-call path's state and kernel, and the weak path (:meth:`warm_up_weak`).
        Returns whether the frame was solved."""
        if triangles:
            self._with_triangles()  # built or loaded now, not in a frame's budget
        xy8 = np.ascontiguousarray(pxy[:8])
        sol, _ = self.solve_at(xy8, [self.camera], _WARM_UP_PATTERNS, _WARM_UP_WORK)
        solved = self.refiner.refine(sol, xy8).ok
        for n_det in range(3, self.max_detections + 1):  # every count's patterns (~0.1 s)
            self._pattern_list(n_det, False)  # Renken's, searched first
            self._pattern_list(n_det, True)
        # the one-call path's state and kernel (solve on an array), on input its check
        # refuses: compiled or loaded whatever the camera, no search run
        self.solve_lean(np.full((3, 2), np.nan), 0.0)
        self.warm_up_weak(pxy, idx)
        return solved

    def warm_up_weak(self, pxy: NDArray, idx: NDArray) -> None:
        """The weak candidates' quick check, and its compiled form (frames of noise), on a
        synthetic frame (as :meth:`warm_up`)."""
        b_all = self.camera.pixels_to_vectors(pxy[:3])
        table = PairWindows.of(b_all, self.tolerance_rad, 0.0)
        self.verifier.quick(b_all, table, np.arange(3), idx[None, :3], self.camera, 1)
        if self._frame_path([self.camera]):
            self._weak_verified(np.ascontiguousarray(pxy[:3]), self.camera,
                                [(1.0, np.arange(3), idx[:3], "", 0, 1)])

    def _pattern_list(self, n_det: int, full: bool,
                      ) -> tuple[NDArray[np.int64], NDArray[np.int64], list[str]]:
        """The patterns for :func:`kernels.search` (:func:`search_order.pattern_arrays`)."""
        return search_order.pattern_arrays(n_det, full, self.max_patterns, self.n_max,
                                           self.n_min)

    def solve_at(self, xy: NDArray, cams: list[Camera],
                  per_guess: int | None = None,
                  work_budget: int | None = None) -> tuple[Solution, int]:
        """Try patterns in order; each pattern at every focal-length guess (so the right
        scale is found by the main pattern, not after exhausting Not-Modus at a wrong
        one). ``tried`` counts (pattern, scale) trials: the union bound of ``p_false``.
        ``per_guess`` and ``work_budget`` bound this search below the solver's own
        ``max_patterns`` and ``work_budget`` (the warm-up's small search)."""
        if self._frame_path(cams):
            return self._solve_frame(xy, cams[0], None, per_guess, work_budget)
        b_cams = [directions(cam, xy) for cam in cams]
        # in numpy every pattern's pair windows come from one table per focal guess
        # (cheaper than per pattern); compiled, each pattern computes its own
        tables = None if self._compiled else [
            PairWindows.of(b_all, self.tolerance_rad, self._rel_tol) for b_all in b_cams]
        run = Search()
        trials = self._trials_compiled if self._compiled else self._trials_numpy
        budget = self._trial_budget(len(cams), per_guess)
        work = self.work_budget if work_budget is None else min(work_budget, self.work_budget)
        for ci, sel, assignments, quicks, path in trials(xy, cams, b_cams, tables, run,
                                                         budget, work):
            cam = cams[ci]
            cands = [c for a, q in zip(assignments, quicks, strict=True)
                     if q is not None and q[0] <= self.p_false_max
                     and (c := self.verifier.verify(xy, cam, sel, a, q, b_cams[ci])) is not None]
            accepted = distinct_candidates([c for c in cands if c.p_false <= self.p_false_max],
                                 3 * self.tolerance_rad)
            if len(accepted) == 1:
                return accepted_solution(accepted[0], len(assignments), path, cands), run.tried
            if len(accepted) > 1:
                best, note = resolve_by_evidence(accepted)
                if best is not None:
                    sol = accepted_solution(best, len(assignments), path, cands)
                    return replace(sol, note=note), run.tried
                return Solution(
                    False, f"ambiguous: {len(accepted)} distinct attitudes verified",
                    matching_counter=len(assignments), path=path,
                    candidates=sorted(accepted, key=lambda c: c.p_false),
                ), run.tried
        return self._unsolved(xy, cams, b_cams, tables, run), run.tried

    def _unsolved(self, xy: NDArray, cams: list[Camera], b_cams: list[NDArray] | None,
                  tables: list[PairWindows] | None, run: Search) -> Solution:
        """The end of a search that accepted nothing: the best few weak candidates
        verified for an operator (or a filter's prior), else "no match" with the budget
        note. ``b_cams`` and ``tables`` (None: computed here) are the guesses' directions
        and pair windows."""
        tried = run.tried
        best = run.best_weak(3)
        if best:
            # nothing convincing: show the best few for an operator (or a filter's prior)
            if b_cams is None and tables is None and self._frame_path(cams):
                shown = self._weak_verified(xy, cams[0], best)  # one compiled call
            else:
                if b_cams is None:
                    b_cams = [directions(cam, xy) for cam in cams]
                if tables is None:
                    tables = [PairWindows.of(b, self.tolerance_rad, self._rel_tol)
                              for b in b_cams]
                shown = []
                for _, sel, a, _, ci, trial in best:
                    q = self.verifier.quick(b_cams[ci], tables[ci], sel, a[None], cams[ci],
                                    trial)[0]
                    if (c := self.verifier.verify(xy, cams[ci], sel, a, q, b_cams[ci])) is not None:
                        shown.append(c)
            # chance alone explains the best one (p_false near 1): nothing matched
            kind = ("no match:" if best[0][0] >= NO_MATCH_P_FALSE
                    else "ambiguous: weak evidence,")
            reason = (f"{kind} the best candidate has p_false {best[0][0]:.2g} > "
                      f"{self.p_false_max:.0e} ({tried} patterns tried)")
            return Solution(False, reason, matching_counter=run.first_counter or 0,
                            path=best[0][3],
                            candidates=distinct_candidates(shown, 3 * self.tolerance_rad))
        reason = f"no match: {run.budget_note or f'{tried} patterns tried'}"
        return Solution(False, reason, matching_counter=run.first_counter or 0)

    def _weak_verified(self, xy: NDArray, cam: Camera, best: list[tuple]) -> list[Candidate]:
        """:meth:`_unsolved`'s quick check and verification of the weak candidates ``best``
        (:meth:`Search.best_weak`'s tuples) for a known ideal pinhole, in one compiled call
        (:func:`starid.identify.frame_kernels.verify_weak`): the candidates the Python loop
        makes."""
        rows = np.zeros((len(best), 20), dtype=np.int64)
        for r, (_, sel, a, _, _, trial) in enumerate(best):
            rows[r, 2], rows[r, 3] = trial, len(sel)
            rows[r, 4:4 + len(sel)], rows[r, 12:12 + len(sel)] = sel, a
        M, off = cam._ideal_pinhole[:2]
        ok, n, det, cat, q, cov, res, p = frame_kernels.verify_weak(
            self._ix, np.ascontiguousarray(xy, dtype=np.float64), M, off, self.tolerance_rad,
            rows, self.verifier.match_radius_px(), self.centroid_sigma_px, cam.pixel_scale_rad)
        return [_candidate(det[k, :n[k]].tolist(), self.view.ids[cat[k, :n[k]]].tolist(), q[k],
                           cov[k], res[k, :n[k]], float(p[k]), len(best[k][1]), cam,
                           self.view.project)
                for k in range(len(best)) if ok[k]]

    def solve_lean(self, arr: NDArray[np.float64], t0: float) -> tuple[Solution, bool] | None:
        """``solve(arr)`` without a prior, for the common case — detections an (N, 2)
        C-contiguous float64 array, the n-star method, a known ideal pinhole refitted in
        the kernel — as one compiled call (:func:`starid.identify.frame_kernels.solve_lean`, the
        input check included) on the solver's :meth:`_lean_state`, and a few Python steps
        (about a third of a clean frame's time was Python around the kernel): the same
        solution, or None (the general path takes over) for input the check refuses or
        any other set-up. A frame whose call ends otherwise than in one refitted attitude
        continues in :meth:`_frame_solution` from that call's result. Returns the solution
        and whether it is final: False when it is a fix that explains too few of the
        detections the search used, whose rest the solver searches
        (``Solver._rest_checked``)."""
        lean = self.__dict__.get("_lean")
        if lean is None:
            changes = self.__dict__.get("_lean_changes", 0)
            lean = self._lean_state()
            if self.__dict__.get("_lean_changes", 0) == changes:  # (see __setattr__)
                self.__dict__["_lean"] = lean
        # the types lean_call's wrapper reads its arguments as (it checks none)
        if lean is False or arr.dtype is not _FLOAT64 or arr.ndim != 2 or arr.shape[1] != 2:
            return None
        flags = arr.flags
        if not (flags.c_contiguous and flags.aligned):
            return None
        st, paths, cols, call, rest_below = lean
        work, walk, out_i, out_f = getattr(_SCRATCH, "lean", _NO_LEAN)
        try:
            outcome, n_i, n_f = call(st, arr, work, walk, out_i, out_f)
            # this thread's first call (the arrays made, then the result's), or a result
            # longer than the result arrays (the call says how long): twice at most
            for _ in range(2):
                if outcome != frame_kernels.NO_ROOM:
                    break
                work, walk, out_i, out_f = _SCRATCH.lean = (
                    self._scratch(), np.zeros(frame_kernels.LEAN_WALK + cols, dtype=np.int64),
                    np.zeros(max(_LEAN_OUT, len(out_i), 2 * n_i), dtype=np.int64),
                    np.zeros(max(_LEAN_OUT, len(out_f), 2 * n_f)))
                outcome, n_i, n_f = call(st, arr, work, walk, out_i, out_f)
            if outcome == frame_kernels.NO_ROOM:
                raise RuntimeError(
                    "the lean solve asked for larger arrays after it was given them (a "
                    "bug: its work lengths disagree with PatternSearch._scratch); set "
                    "solver.search._frame_kernel = False to solve this frame the general way")
        except BaseException:
            self._drop_scratch()
            raise
        if outcome == frame_kernels.REFUSED:
            return None  # the general path says what is wrong
        # the thread's arrays are written again by its next call: the result is copied
        every, floats = out_i[:n_i].tolist(), out_f[:n_f].copy()
        n_all = len(arr)
        n = min(n_all, self.max_detections)
        cam = self.camera
        if outcome == frame_kernels.ACCEPTED and every[5] == 1:  # one attitude, refitted
            sol = _accepted(every, floats, cam, self.view.project, paths[n], n, t0)
            # the pairs of the search's detections (the refit's pairs are in detection
            # order, frame_kernels._by_detection): what _rest_checked decides, without it
            used = every[7] if n_all == n else bisect.bisect_left(sol.matches, (n,))
            if used >= rest_below[n]:
                return sol, True
        else:
            # the walk continues from the call's state (copied: the array is the thread's)
            first = (tuple(a.copy() for a in frame_kernels.walk_parts(walk, cols)),
                     frame_kernels.unpack(out_i[:n_i].copy(), floats))
            sol, tried, filled = self._frame_solution(arr[:n], cam, arr, None, None, t0,
                                                      first=first)
            if not filled:
                sol = replace(sol, time_s=time.perf_counter() - t0, n_detections=n,
                              patterns_tried=tried)
        return sol, False

    def rest_wanted(self, n_used: int, n: int) -> bool:
        """Whether a fix that explains ``n_used`` of the ``n`` detections the search used
        has the rest searched too (``Solver._rest_checked``): fewer than
        :data:`REST_CHECK_SHARE` of them, and enough left over for a pattern."""
        return n_used < REST_CHECK_SHARE * n and n - n_used >= max(self.n_min, 3)

    def _lean_state(self) -> tuple[frame_kernels.LeanState, list[list[str]], int,
                                   Callable, list[int]] | bool:
        """:meth:`solve_lean`'s compiled state of this solver's settings, index and camera
        (:func:`starid.identify.frame_kernels.lean_state`), the paths of every detection count's
        patterns (Renken's, :meth:`_pattern_list`), the length of the walk's no-match
        sets, the compiled call (:func:`starid.identify.frame_kernels.lean_call`) and, per
        detection count, the fewest pairs a fix needs to have the rest of the detections
        left unsearched (:meth:`rest_wanted`), or False where
        the lean path does not apply (the numpy
        matchers, a camera that is no ideal pinhole or is fitted, a focal range). Made on
        the first call and dropped by any assignment to the solver (:meth:`__setattr__`):
        every setting a solve reads is one of its attributes."""
        cam = self.camera
        if not (self._frame_path([cam]) and self.refiner.compiled
                and self.refiner.fit_terms() is None):
            return False
        lists = [self._pattern_list(n, False) if n >= 3 else (_NO_PATS, _NO_COUNTS, [])
                 for n in range(self.max_detections + 1)]
        start = np.cumsum([0] + [len(c) for _, c, _ in lists], dtype=np.int64)
        st = frame_kernels.lean_state(
            self.view.ids, self._ix, *self._frame_camera(cam), input_bounds(cam)[2],
            self.tolerance_rad, self.max_detections,
            np.ascontiguousarray(np.concatenate([p for p, _, _ in lists])),
            np.concatenate([c for _, c, _ in lists]), start, self._trial_budget(1),
            self.work_budget, self.max_patterns + 2, 2 * len(self._ix[0]),
            self.verifier.match_radius_px(), self.centroid_sigma_px, self.p_false_max,
            3 * self.tolerance_rad, _REFIT_CONSTANTS)
        # rest_wanted(used, n) as "used < rest_below[n]": the fewest pairs it is False
        # for (it is for every count past that one)
        rest_below = [next(u for u in range(n + 2) if not self.rest_wanted(u, n))
                      for n in range(self.max_detections + 1)]
        return (st, [paths for _, _, paths in lists], self.max_patterns + 2,
                frame_kernels.lean_call(st), rest_below)

    def __setattr__(self, name: str, value) -> None:
        # a setting, the index (the triangles joining it) or the camera changed: the lean
        # path's state is made again on its next call (the solve's own caches keep it).
        # The count goes up first and the state goes last, so a state another thread is
        # making meanwhile from the old value is not kept (solve_lean compares counts)
        if name in _LEAN_KEEPS:
            object.__setattr__(self, name, value)
        else:
            self._lean_changed(object.__setattr__, name, value)

    def __delattr__(self, name: str) -> None:
        self._lean_changed(object.__delattr__, name)

    def _lean_changed(self, change: Callable, *args) -> None:
        """``change(self, *args)`` between counting the change and dropping the state."""
        d = self.__dict__
        d["_lean_changes"] = d.get("_lean_changes", 0) + 1
        change(self, *args)
        d.pop("_lean", None)

    def __getstate__(self) -> dict:
        # a pickled or copied solver makes its compiled state again where it is used (a
        # numba structure can be neither pickled nor copied)
        state = self.__dict__.copy()
        state.pop("_lean", None)
        return state

    def solve_refined(self, xy: NDArray, cams: list[Camera], xy_all: NDArray,
                       t0: float) -> Solution:
        """:meth:`solve_at`, then the accepted fix refitted on every detection ``xy_all``
        (``Refiner.refine``; those past ``xy`` outside the frame left out), with the solve's
        time since ``t0``, detections and trials filled in: for a known ideal pinhole in one
        compiled call (:meth:`_solve_frame`)."""
        if self._frame_path(cams):
            return self._solve_frame(xy, cams[0], xy_all, t0=t0)[0]
        sol, tried = self.solve_at(xy, cams)
        return replace(self.refiner.refine(sol, outside_as_nan(self.camera, xy_all, len(xy))),
                       time_s=time.perf_counter() - t0,
                       n_detections=len(xy), patterns_tried=tried)

    _frame_kernel = True  # False: the search, verification and refit called one by one

    def _frame_camera(self, cam: Camera) -> tuple:
        """What :func:`starid.identify.frame_kernels.solve_frame` takes of an ideal pinhole ``cam``:
        its affine maps, size, the view's half-angle + 1e-3 rad (``Camera._view_half_rad``:
        the farthest corner from the optical axis) and the pixel scale
        (kept for the solver's own camera: a few µs a frame)."""
        kept = self._frame_camera_kept
        if kept is not None and kept[0] is cam:
            return kept[1]
        M, off, A, c = cam._ideal_pinhole
        out = (M, off, A, c, float(cam.width), float(cam.height),
               cam._view_half_rad + 1e-3, float(cam.pixel_scale_rad))
        if cam is self.camera:
            self._frame_camera_kept = (cam, out)
        return out

    _frame_camera_kept: tuple | None = None

    _triangles_done = False  # _with_triangles ran (whether or not it found a table)

    def _with_triangles(self) -> None:
        """From now on, match a pattern's first three stars by looking them up among the
        catalogue's triangles (:mod:`starid.catalog.triangle_index`: the same rows, ~7× cheaper a
        trial) — the table built or loaded from the cache the first time a frame needs
        more than Renken's patterns (or by :meth:`warm_up`), not by every solver made:
        it takes ~6 s to build and ~113 MiB for V < 6 in a 15° field. None past its size
        bound (``ADFUSION_TRIANGLES_MAX_MB``): the pair windows are scanned."""
        if self._triangles_done:
            return
        with _TRIANGLES_LOCK:
            if not self._triangles_done:
                table = triangles_for(self.view.index, self.tolerance_rad, self._cache_tag)
                if table is not None:
                    self._ix = kernels.with_triangles(self._ix, table)
                self._triangles_done = True

    def _scratch(self) -> NDArray[np.int64]:
        """The search's work array (:func:`kernels.scratch`: all −1, and left so), one per
        thread, shared by the thread's solvers (any array of at least twice the catalogue's
        length serves): the kernels release the GIL, and filling a catalogue-sized array
        per frame cost ~3 µs. A kernel that raises drops it (:meth:`_drop_scratch`)."""
        n = 2 * len(self._ix[0])
        work = getattr(_SCRATCH, "work", None)
        if work is None or len(work) < n:
            work = _SCRATCH.work = np.full(n, -1, dtype=np.int64)
        return work

    @staticmethod
    def _drop_scratch() -> None:
        """Forget this thread's work array: a kernel stopped by an exception may have left
        marks in it."""
        _SCRATCH.work, _SCRATCH.lean = None, _NO_LEAN

    def _frame_path(self, cams: list[Camera]) -> bool:
        """Whether a search at ``cams`` runs as one compiled call
        (:func:`starid.identify.frame_kernels.solve_frame`): the compiled search and
        verification, one focal guess, an ideal pinhole."""
        return (self._frame_kernel and self._compiled and self.verifier.compiled
                and not self._fov_uncertain and len(cams) == 1
                and cams[0]._ideal_pinhole is not None)

    def _solve_frame(self, xy: NDArray, cam: Camera, xy_all: NDArray | None,
                     per_guess: int | None = None, work_budget: int | None = None,
                     t0: float | None = None) -> tuple[Solution, int]:
        """:meth:`solve_at` (and, given ``xy_all``, ``Refiner.refine``) as one call of
        :func:`starid.identify.frame_kernels.solve_frame`: the same trials, candidates, decisions
        and refit; Python builds the :class:`Solution` (and weighs several accepted
        attitudes, or shows the weak ones, as :meth:`solve_at` does) — with ``t0``, with
        the solve's time, detections and trials filled in (as ``solve_refined``)."""
        sol, tried, filled = self._frame_solution(xy, cam, xy_all, per_guess, work_budget,
                                                  t0)
        if t0 is not None and not filled:
            sol = replace(sol, time_s=time.perf_counter() - t0, n_detections=len(xy),
                          patterns_tried=tried)
        return sol, tried

    def _frame_call(self, xy: NDArray, refit_xy: NDArray, cam: Camera, walk: tuple,
                    pats: NDArray, plen: NDArray, budget: int, work: int,
                    refine: bool) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """One call of :func:`starid.identify.frame_kernels.solve_frame_packed` on contiguous
        detections ``xy`` (and ``refit_xy``), continuing the walk ``walk`` (state, no-match
        sets, their counts: :meth:`_fresh_walk`)."""
        state, no_match, n_no_match = walk
        try:
            return frame_kernels.solve_frame_packed(
                self.view.ids, self._ix, xy, refit_xy, *self._frame_camera(cam),
                self.tolerance_rad, state, pats, plen, budget, no_match, n_no_match,
                work, self._scratch(), self.verifier.match_radius_px(), self.centroid_sigma_px,
                self.p_false_max, 3 * self.tolerance_rad, refine, _REFIT_CONSTANTS)
        except BaseException:
            self._drop_scratch()
            raise

    def _fresh_walk(self) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
        """A search's start for :meth:`_frame_call`: state, no-match sets, their counts."""
        return (kernels.SEARCH_START.copy(), np.zeros((1, self.max_patterns + 2), dtype=np.int64),
                np.zeros(1, dtype=np.int64))

    def _frame_solution(self, xy: NDArray, cam: Camera, xy_all: NDArray | None,
                        per_guess: int | None, work_budget: int | None,
                        t0: float | None, first: tuple | None = None,
                        ) -> tuple[Solution, int, bool]:
        """The work of :meth:`_solve_frame`: (solution, trials, whether the solution has its
        time, detections and trials filled in — the common outcome, one attitude refitted
        in the kernel, has when ``t0`` is given). ``first``: the walk and the result of
        the first call, already made, read by :func:`starid.identify.frame_kernels.unpack`
        (:meth:`solve_lean`)."""
        full = False
        pats, plen, paths = self._pattern_list(len(xy), full)
        walk = self._fresh_walk() if first is None else first[0]
        state = walk[0]
        budget = self._trial_budget(1, per_guess)
        work = self.work_budget if work_budget is None else min(work_budget, self.work_budget)
        refine = (xy_all is not None and self.refiner.compiled
                  and self.refiner.fit_terms() is None)
        xy = np.ascontiguousarray(xy, dtype=np.float64)
        # the detections the kernel refits on (unused without a refit); xy_all itself stays
        # what the Python refit gets (None: none, as solve_at returns the verified fit)
        refit_xy = np.ascontiguousarray(xy_all, dtype=np.float64) if refine else xy
        weak_rows = []
        while True:
            if first is None:
                read = frame_kernels.unpack(*self._frame_call(
                    xy, refit_xy, cam, walk, pats, plen, budget, work, refine))
            else:
                (_, read), first = first, None
            outcome, sel, counter, n_acc, order, cands, refit, (wp, wi), _, _ = read
            if len(wp):
                weak_rows.append((wp, wi, paths))
            if outcome != frame_kernels.NONE or full or state[0] < len(pats):
                break
            # Renken's patterns failed: on to the combinations (the same list, longer)
            full = True
            pats, plen, paths = self._pattern_list(len(xy), full)
            self._with_triangles()
        pos, _, tried, first, _, note, a, b = state.tolist()
        if outcome == frame_kernels.NONE:
            run = Search(tried=tried, weak_rows=weak_rows)
            run.first_counter = None if first < 0 else first
            if note == kernels.NOTE_WORK:
                run.budget_note = f"work budget exceeded ({a} partial assignments at level {b})"
            elif note == kernels.NOTE_PATTERNS:
                run.budget_note = f"{a} pattern trials (the budget)"
            return self._unsolved(xy, [cam], None, None, run), tried, False
        found = [_candidate(*c, len(sel), cam, self.view.project) for c in cands]
        path = paths[pos]
        accepted = [found[i] for i in order]
        if outcome == frame_kernels.SEVERAL:
            best, why = resolve_by_evidence(accepted)
            if best is None:
                return Solution(False, f"ambiguous: {n_acc} distinct attitudes verified",
                                matching_counter=counter, path=path,
                                candidates=accepted), tried, False
            sol = replace(accepted_solution(best, counter, path, found), note=why)
            return ((self.refiner.refine(sol, outside_as_nan(self.camera, xy_all, len(xy)))
                     if xy_all is not None else sol), tried, False)
        best = accepted[0]
        status = refit[0]
        if status == 1:
            done = () if t0 is None else (time.perf_counter() - t0, len(xy), tried)
            return (_refitted(refit, counter, best.p_false, path, found, cam, *done), tried,
                    t0 is not None)
        sol = accepted_solution(best, counter, path, found)
        if xy_all is not None and (status == -1 or not refine):
            # a cone the refit left, a degenerate fit, or a fitted camera: in Python
            sol = self.refiner.refine(sol, outside_as_nan(self.camera, xy_all, len(xy)))
        return sol, tried, False

    def _match(self, pattern: Pattern, work_budget: int | None = None) -> NDArray[np.int64]:
        """Every catalogue assignment of ``pattern`` (:mod:`starid.identify.nstar`): through
        the pattern index, or Renken's faithful loops, or per declination band."""
        work = self.work_budget if work_budget is None else work_budget
        if self.faithful:
            return match_faithful(self.view.vectors, pattern, self.dec_check,
                                  self._band_masks(pattern))
        if self.n_bands > 1:
            parts = [match_indexed(self.view.index, pattern, work, m)
                     for m in self._band_masks(pattern)]
            allm = np.concatenate(parts)
            return np.unique(allm, axis=0) if len(allm) else allm
        return match_indexed(self.view.index, pattern, work)

    def _band_masks(self, pattern: Pattern) -> list[NDArray[np.bool_]] | None:
        if self.n_bands <= 1:
            return None
        dec = np.arcsin(np.clip(self.view.vectors[:, 2], -1, 1))
        edges = np.arcsin(np.linspace(1.0, -1.0, self.n_bands + 1))
        o = pattern.delta_max_rad
        return [(dec <= hi + o) & (dec >= lo - o) for hi, lo in itertools.pairwise(edges)]

    def _trials_compiled(self, xy: NDArray, cams: list[Camera], b_cams: list[NDArray],
                         tables: list[PairWindows], run: Search,
                         budget: int, work: int) -> Iterator[tuple]:
        """The search of :meth:`solve_at` in compiled code (:func:`kernels.search`):
        yields (guess, sel, assignments, quick checks, path) of every trial with a
        candidate whose quick p_false passes, for :meth:`_verify`; ``run`` keeps the
        counts, the weak candidates and the budget notes."""
        full = False
        pats, plen, paths = self._pattern_list(len(xy), full)
        n_cams = len(cams)
        state = kernels.SEARCH_START.copy()
        no_match = np.zeros((n_cams, self.max_patterns + 2), dtype=np.int64)
        n_no_match = np.zeros(n_cams, dtype=np.int64)
        pix = np.array([cam.pixel_scale_rad for cam in cams])
        radius = self.verifier.match_radius_px() * pix
        floor = np.sqrt(2.0) * self.centroid_sigma_px * pix
        b_stack = b_cams[0][None] if n_cams == 1 else np.stack(b_cams)
        store = kernels.triangle_store()
        while True:
            try:
                sel, rows, q, wp, wi = kernels.search(
                    self._ix, state, pats, plen, budget, no_match, n_no_match, b_stack,
                    self.tolerance_rad, self._rel_tol, radius, floor, self.p_false_max, work,
                    self._scratch(), store)
            except BaseException:
                self._drop_scratch()
                raise
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
                self._with_triangles()
                continue
            yield ci, sel, rows, quick_tuples(q), paths[pos]
            state[:2] = (pos, ci + 1) if ci + 1 < n_cams else (pos + 1, 0)

    def _trials_numpy(self, xy: NDArray, cams: list[Camera], b_cams: list[NDArray],
                      tables: list[PairWindows], run: Search,
                      budget: int, work: int) -> Iterator[tuple]:
        """:meth:`_trials_compiled` in Python, for the matchers kept in numpy (Renken's
        faithful loops, declination bands): the same trials, counts and values."""
        # detection sets (bit masks) that matched nothing, per focal guess: a pattern
        # holding one of them matches nothing either (every window of the smaller set is
        # one of its own), so it is counted as tried but not matched — the swaps and
        # 4-star combinations after a failed Not-Modus are mostly such supersets
        no_match: list[list[int]] = [[] for _ in cams]
        for pat_idx, path in search_order.patterns(len(xy), self.n_min, self.n_max):
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
                    assignments = self._match(pattern, work)
                except WorkBudgetExceeded as e:
                    run.budget_note = f"work budget exceeded ({e})"
                    continue
                if run.first_counter is None:
                    run.first_counter = len(assignments)
                if len(assignments) == 0:
                    no_match[ci].append(mask)
                    continue
                quicks = self.verifier.quick(b_all, tables[ci], sel, assignments, cam, run.tried)
                strong = False
                for a, q in zip(assignments, quicks, strict=True):
                    if q is not None and q[0] <= self.p_false_max:
                        strong = True
                    elif q is not None:
                        run.weak.append((q[0], sel, a, path, ci, run.tried))
                if strong:
                    yield ci, sel, assignments, quicks, path
