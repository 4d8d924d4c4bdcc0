"""Lost-in-space search of the :class:`starid.Solver`: patterns in Renken's order (main
pattern, Not-Modus, then our combinations), each at every focal-length guess, matched
against the pattern index (compiled, :func:`starid.kernels.search`, or in numpy for the
faithful and banded matchers), candidates verified (:mod:`starid.verify`).

Example:
    >>> from adfusion.starid.solver import Solver
    >>> issubclass(Solver, LostInSpace)
    True
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np
from adfusion.starid import kernels
from adfusion.starid.camera import Camera
from adfusion.starid.nstar import Pattern, WorkBudgetExceeded, chirality_of, closest_pair_first
from adfusion.starid.search_order import combination_order
from adfusion.starid.solution import Candidate, Solution
from adfusion.starid.verify import distinct_candidates, quick_tuples
from numpy.typing import NDArray

__all__ = ["EVIDENCE_RATIO", "MAX_BUDGET_SCALES", "SHARED_FRACTION", "LostInSpace",
           "PairWindows", "Search", "resolve_by_evidence"]


#: focal guesses the trial budget grows with (beyond, a frame gets fewer patterns per guess)
MAX_BUDGET_SCALES = 50

#: the best candidate wins over the others when its p_false is this many times smaller
EVIDENCE_RATIO = 1e6
#: ... or when every other shares at least this fraction of its (detection, star) pairs
SHARED_FRACTION = 0.5


def resolve_by_evidence(cands: list[Candidate]) -> tuple[Candidate | None, str]:
    """Of several verified, distinct attitudes: the best one and a note, when the evidence
    decides — each other candidate either p_false :data:`EVIDENCE_RATIO` times weaker, or
    sharing most of its star pairs with the best (a near-duplicate with a neighbour
    swapped in) — else (None, "") for genuine ambiguity.

    >>> import numpy as np
    >>> from adfusion.starid.solution import Candidate
    >>> def c(p, m):
    ...     return Candidate(np.array([1.0, 0, 0, 0]), m, np.zeros(len(m)), p, 3, None,
    ...                      np.eye(3))
    >>> best, note = resolve_by_evidence([c(4e-54, [(i, i) for i in range(29)]),
    ...                                   c(2e-12, [(i, i + 100) for i in range(11)])])
    >>> best.p_false, note.split(":")[0]
    (4e-54, 'best of 2 candidates')
    >>> resolve_by_evidence([c(1e-9, [(0, 1), (1, 2), (2, 3)]), c(1e-8, [(0, 5), (1, 6),
    ...                                                               (2, 7)])])[0] is None
    True
    """
    ranked = sorted(cands, key=lambda c: c.p_false)
    best, others = ranked[0], ranked[1:]
    pairs = set(best.matches)
    reasons = []
    for o in others:
        shared = len(pairs & set(o.matches)) / max(1, min(len(pairs), len(o.matches)))
        if o.p_false >= EVIDENCE_RATIO * best.p_false:
            reasons.append(f"p_false {o.p_false:.2g} vs {best.p_false:.2g}")
        elif shared >= SHARED_FRACTION:
            reasons.append(f"{shared:.0%} of its stars shared")
        else:
            return None, ""
    return best, (f"best of {len(cands)} candidates: the others weaker by the evidence "
                  f"({'; '.join(reasons)})")


class LostInSpace:
    """The lost-in-space half of :class:`starid.Solver` (a mixin: it uses the solver's
    index, settings and verification)."""

    def _trial_budget(self, n_scales: int, per_guess: int | None = None) -> int:
        """(pattern, focal guess) trials a frame may take: ``max_patterns`` (or
        ``per_guess``) per guess, for at most :data:`MAX_BUDGET_SCALES` guesses — a wide
        FOV range (5°–40°: 200 guesses) must not make a frame without an answer cost 200×
        a known camera's."""
        return (per_guess or self.max_patterns) * min(n_scales, MAX_BUDGET_SCALES)

    def _focal_scales(self) -> list[float]:
        """Focal-length multipliers covering the FOV uncertainty (1.0 first)."""
        if not self._fov_uncertain:
            return [1.0]
        half = np.radians(self.camera.fov_x_deg) / 2
        if self.fov_range_deg is not None:
            # focal scale k turns the nominal FOV into 2·atan(tan(half) / k)
            fov_lo, fov_hi = np.radians(self.fov_range_deg) / 2
            lo = np.tan(half) / np.tan(fov_hi)
            hi = np.tan(half) / np.tan(fov_lo)
        else:
            lo = np.tan(half) / np.tan(half + np.radians(self.fov_error_deg) / 2)
            hi = np.tan(half) / np.tan(max(half - np.radians(self.fov_error_deg) / 2, 1e-6))
        n = max(3, int(np.ceil(np.log(hi / lo) / np.log1p(self._scale_step))) + 1)
        grid = np.exp(np.linspace(np.log(lo), np.log(hi), n))
        order = np.argsort(np.abs(np.log(grid)))
        rest = [float(g) for g in grid[order] if abs(np.log(g)) > 1e-12]
        return [1.0, *rest] if lo <= 1.0 <= hi else rest

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

    def _solve_at(self, xy: NDArray, cams: list[Camera],
                  per_guess: int | None = None,
                  work_budget: int | None = None) -> tuple[Solution, int]:
        """Try patterns in order; each pattern at every focal-length guess (so the right
        scale is found by the main pattern, not after exhausting Not-Modus at a wrong
        one). ``tried`` counts (pattern, scale) trials: the union bound of ``p_false``.
        ``per_guess`` and ``work_budget`` bound this search below the solver's own
        ``max_patterns`` and ``work_budget`` (the warm-up's small search)."""
        b_cams = [cam.pixels_to_vectors(xy) for cam in cams]
        rel_tol = 0.5 * self._scale_step if self._fov_uncertain else 0.0
        # every pattern's pair windows come from one table per focal guess: cheaper than
        # building them per pattern
        tables = [PairWindows.of(b_all, self.tolerance_rad, rel_tol) for b_all in b_cams]
        run = Search()
        trials = self._trials_compiled if self._compiled else self._trials_numpy
        budget = self._trial_budget(len(cams), per_guess)
        work = self.work_budget if work_budget is None else min(work_budget, self.work_budget)
        for ci, sel, assignments, quicks, path in trials(xy, cams, b_cams, tables, run,
                                                         budget, work):
            cam = cams[ci]
            cands = [c for a, q in zip(assignments, quicks, strict=True)
                     if q is not None and q[0] <= self.p_false_max
                     and (c := self._verify(xy, cam, sel, a, q, b_cams[ci])) is not None]
            accepted = distinct_candidates([c for c in cands if c.p_false <= self.p_false_max],
                                 3 * self.tolerance_rad)
            if len(accepted) == 1:
                return self._solution(accepted[0], len(assignments), path, cands), run.tried
            if len(accepted) > 1:
                best, note = resolve_by_evidence(accepted)
                if best is not None:
                    sol = self._solution(best, len(assignments), path, cands)
                    return replace(sol, note=note), run.tried
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
                            candidates=distinct_candidates(shown, 3 * self.tolerance_rad)), tried
        reason = f"no match: {run.budget_note or f'{tried} patterns tried'}"
        return Solution(False, reason, matching_counter=run.first_counter or 0), tried

    def _trials_compiled(self, xy: NDArray, cams: list[Camera], b_cams: list[NDArray],
                         tables: list[PairWindows], run: Search,
                         budget: int, work: int) -> Iterator[tuple]:
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
        if n_cams == 1:  # views, not copies (the common case: a known camera)
            stack = [b_cams[0][None]] + [getattr(tables[0], f)[None]
                                         for f in ("angles", "tol", "cos_min", "cos_max")]
        else:
            stack = [np.stack(b_cams)] + [np.stack([getattr(t, f) for t in tables])
                                          for f in ("angles", "tol", "cos_min", "cos_max")]
        while True:
            sel, rows, q, wp, wi = kernels.search(
                self._ix, state, pats, plen, budget, no_match,
                n_no_match, *stack, radius, floor, self.p_false_max, work)
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
                    assignments = self._match(pattern, work)
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


@dataclass(frozen=True)
class PairWindows:
    """The matching windows of every detection pair at one focal guess: a pattern's are a
    sub-matrix (the same values :func:`_pattern` computes, without per-pattern work)."""

    angles: NDArray[np.float64]  # (N, N) pair angles, 0 on the diagonal
    tol: NDArray[np.float64]  # (N, N) window half-widths
    hi: NDArray[np.float64]  # (N, N) upper window edges (angles)
    cos_min: NDArray[np.float64]
    cos_max: NDArray[np.float64]

    @classmethod
    def of(cls, b_all: NDArray, tolerance_rad: float, rel_tol: float) -> PairWindows:
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
class Search:
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
