"""Renken's n-star pattern matching: every catalogue assignment consistent with the image.

Given the pairwise angular distances of n image stars (n = 2…6, the closest pair first)
and an angular tolerance, enumerate every ordered assignment (is_1 → cs_a1, …, is_n →
cs_an) of distinct catalogue stars whose c(n,2) dot products all lie strictly inside
the image windows, and which is not the mirror image of the pattern (Renken 1998 §6.1–6.6,
§6.9; docs/references.md#renken-1998). ``len(result)`` is Renken's ``matching_counter``.

Two implementations with identical results (tested: the same match sets):

* :func:`match_faithful` — the §4.12 reference: nested loops over the catalogue (the
  innermost one vectorised), optional declination-difference pre-check and declination
  bands, duplicates suppressed;
* :func:`match_indexed` — the fast path: window look-ups in a :class:`PatternIndex`,
  vectorised level by level over all partial assignments, mirror check at level 3.

Example:
    >>> import numpy as np
    >>> from adfusion.starid.catalog.pair_index import PatternIndex
    >>> from adfusion.starid.identify.nstar import Pattern, match_indexed
    >>> rng = np.random.default_rng(1)
    >>> cat = rng.normal(size=(300, 3)); cat /= np.linalg.norm(cat, axis=1, keepdims=True)
    >>> true = [5, 17, 42]                       # pretend the camera saw these three
    >>> pat = Pattern.from_vectors(cat[true], tol_rad=1e-6)
    >>> idx = PatternIndex.from_vectors(cat, max_sep_rad=np.pi)
    >>> [int(i) for i in match_indexed(idx, pat)[0]]
    [5, 17, 42]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from adfusion.starid.catalog.pair_index import PatternIndex
from numpy.typing import NDArray

__all__ = [
    "Pattern",
    "closest_pair_first",
    "extend_indexed",
    "first_pair_indexed",
    "match_faithful",
    "match_indexed",
]

IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class Pattern:
    """An image pattern ready for matching.

    ``angles`` (n, n) are the image-pair angular distances (rad), already in matching order
    (closest pair first); ``cos_min`` / ``cos_max`` the strict cosine windows (Renken 1998
    Eq. 6.30–6.33; the lower angle is clamped at 0, so ``cos_max`` ≤ 1); ``chirality`` the
    sign of det[b1, b2, b3] of the first three camera-frame vectors (0 when they are too
    close to collinear for the mirror check to decide).
    """

    angles: NDArray[np.float64]
    cos_min: NDArray[np.float64]
    cos_max: NDArray[np.float64]
    chirality: int
    delta_max_rad: float

    @property
    def n(self) -> int:
        return len(self.angles)

    @classmethod
    def from_angles(
        cls, angles: NDArray[np.float64], tol_rad: float, chirality: int = 0
    ) -> Pattern:
        a = np.asarray(angles, dtype=np.float64)
        n = len(a)
        if a.shape != (n, n) or n < 2:
            raise ValueError(f"pattern needs an (n, n) angle matrix with n ≥ 2, got {a.shape}")
        if not np.all(np.isfinite(a)) or tol_rad <= 0:
            raise ValueError("pattern angles must be finite and the tolerance positive")
        lo = np.maximum(a - tol_rad, 0.0)
        hi = np.minimum(a + tol_rad, np.pi)
        # δ_max: the largest pair distance plus the tolerance, so the declination
        # pre-check can never reject a pair the window would accept (Renken 1998 §6.9)
        # (the diagonal's hi is the bare tolerance, never the maximum)
        return cls(a, np.cos(hi), np.cos(lo), int(chirality), float(hi.max()))

    @classmethod
    def from_vectors(cls, b: NDArray[np.float64], tol_rad: float) -> Pattern:
        """Pattern of camera-frame unit vectors (in the given order)."""
        b = np.asarray(b, dtype=np.float64)
        ang = np.arccos(np.clip(b @ b.T, -1.0, 1.0))
        np.fill_diagonal(ang, 0.0)
        chir = chirality_of(b, 2.0 * tol_rad) if len(b) >= 3 else 0
        return cls.from_angles(ang, tol_rad, chir)


def chirality_of(b: NDArray[np.float64], min_altitude_rad: float = 0.0) -> int:
    """Sign of det[b0, b1, b2] (the triangle's handedness); 0 if undecidable.

    A proper rotation preserves it, so an image triangle and its true catalogue triangle
    have the same sign and the mirror image the opposite one (Renken 1998 §6.6). When the
    triangle's smallest altitude is below ``min_altitude_rad`` measurement noise could flip
    the sign, so the mirror check is skipped (verification still catches a mirror).
    """
    (ax, ay, az), (bx, by, bz), (cx, cy, cz) = np.asarray(b[:3], dtype=np.float64).tolist()
    det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)

    def cross_norm(ux: float, uy: float, uz: float, vx: float, vy: float, vz: float) -> float:
        return float(np.sqrt((uy * vz - uz * vy) ** 2 + (uz * vx - ux * vz) ** 2
                             + (ux * vy - uy * vx) ** 2))

    longest = max(cross_norm(ax, ay, az, bx, by, bz), cross_norm(bx, by, bz, cx, cy, cz),
                  cross_norm(cx, cy, cz, ax, ay, az))
    if longest == 0.0 or abs(det) / longest <= min_altitude_rad:
        return 0
    return 1 if det > 0 else -1


def closest_pair_first(angles: NDArray[np.float64]) -> NDArray[np.int64]:
    """Renken's closest-stars order: the closest pair first (the brighter of the two
    first), the others in their original (brightness) order (Renken 1998 §6.8)."""
    # plain Python over at most 8 stars: a solve calls this once per pattern tried, and
    # the numpy version spent ~80 µs per call in overhead. Ties go to the first pair in
    # row-major order, as an argmin over the upper triangle would.
    rows = np.asarray(angles, dtype=np.float64).tolist()
    n = len(rows)
    best, bi, bj = math.inf, 0, 1
    for i in range(n):
        row = rows[i]
        for j in range(i + 1, n):
            if row[j] < best:
                best, bi, bj = row[j], i, j
    return np.array([bi, bj, *[m for m in range(n) if m not in (bi, bj)]], dtype=np.int64)


def _in_window(c: NDArray[np.float64], cmin: float, cmax: float) -> NDArray[np.bool_]:
    return (c > cmin) & (c < cmax)


# --- the fast path ----------------------------------------------------------------------


def match_indexed(
    index: PatternIndex,
    pattern: Pattern,
    max_partials: int = 200_000,
    star_subset: NDArray[np.bool_] | None = None,
) -> IntArray:
    """All assignments (K, n) of catalogue indices, via the index (see module docstring).

    ``max_partials`` bounds the work: if a level would hold more partial assignments the
    search stops and raises :class:`WorkBudgetExceeded` (results never depend on speed).
    ``star_subset`` restricts every star of the assignment to a mask (a declination band).
    """
    return extend_indexed(index, pattern, first_pair_indexed(index, pattern, star_subset),
                          max_partials, star_subset)


def first_pair_indexed(
    index: PatternIndex, pattern: Pattern, star_subset: NDArray[np.bool_] | None = None,
) -> IntArray:
    """Level 1 of :func:`match_indexed`: the catalogue pairs in the first pair's window,
    both ways round — (K, 2), every i < j pair first, then the same pairs swapped."""
    i, j = index.pairs_in_window(pattern.cos_min[0, 1], pattern.cos_max[0, 1])
    if star_subset is not None:
        keep = star_subset[i] & star_subset[j]
        i, j = i[keep], j[keep]
    assign = np.empty((2 * len(i), 2), dtype=np.int64)
    assign[: len(i), 0] = i
    assign[: len(i), 1] = j
    assign[len(i):, 0] = j
    assign[len(i):, 1] = i
    return assign


def extend_indexed(
    index: PatternIndex,
    pattern: Pattern,
    assign: IntArray,
    max_partials: int = 200_000,
    star_subset: NDArray[np.bool_] | None = None,
    upto: int | None = None,
) -> IntArray:
    """Levels ``assign.shape[1]`` … ``upto − 1`` (default: to the pattern's end) of
    :func:`match_indexed`, from the partial assignments of the first stars.

    (Partials of a pattern head, extended, give what :func:`match_indexed` gives: same
    rows, same order.) The solver's compiled matcher (:func:`starid.identify.kernels.match`)
    reproduces these rows.
    """
    n = pattern.n if upto is None else upto
    v = index.vectors
    for m in range(assign.shape[1], n):
        if len(assign) == 0:
            return np.zeros((0, n), dtype=np.int64)
        if len(assign) > max_partials:
            raise WorkBudgetExceeded(f"{len(assign)} partial assignments at level {m}")
        parent, cand = index.neighbours_in_window(
            assign[:, 0], pattern.cos_min[0, m], pattern.cos_max[0, m]
        )
        if star_subset is not None:
            keep = star_subset[cand]
            parent, cand = parent[keep], cand[keep]
        # all links of the new star to the stars already placed, in one product
        prev = assign[parent, 1:m]  # (K, m − 1)
        c = np.einsum("kmj,kj->km", v[prev], v[cand])
        ok = np.all((c > pattern.cos_min[1:m, m]) & (c < pattern.cos_max[1:m, m])
                    & (prev != cand[:, None]), axis=1)
        parent, cand = parent[ok], cand[ok]
        assign = np.concatenate([assign[parent], cand[:, None]], axis=1)
        if m == 2 and pattern.chirality != 0 and len(assign):
            assign = assign[_chirality_ok(v, assign, pattern.chirality)]
    if len(assign) > max_partials:  # the last level too: bounded memory for the checks
        raise WorkBudgetExceeded(f"{len(assign)} partial assignments at level {n}")
    return assign


def _chirality_ok(v: NDArray[np.float64], assign: IntArray,
                  chirality: int) -> NDArray[np.bool_]:
    # det[a, b, c] = a · (b × c), written out: np.cross costs ~50 µs of overhead per call
    a, b, c = v[assign[:, 0]].T, v[assign[:, 1]].T, v[assign[:, 2]].T
    det = (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
           + a[2] * (b[0] * c[1] - b[1] * c[0]))
    return np.sign(det) == chirality


class WorkBudgetExceeded(RuntimeError):
    """The search would exceed its work budget; the caller reports `not ok`."""


# --- the reference implementation (Renken 1998 §6.9) ---------------------------------------


def match_faithful(
    vectors: NDArray[np.float64],
    pattern: Pattern,
    dec_check: bool = True,
    band_masks: list[NDArray[np.bool_]] | None = None,
) -> IntArray:
    """Renken's general formulation, literally: i1 < i2 over the (sub-)catalogue, both
    assignments of the first pair, each further star searched over the whole
    (sub-)catalogue, strict windows, optional declination pre-check, distinctness, mirror
    check and duplicate suppression. Only the innermost loop is vectorised.
    """
    v = np.asarray(vectors, dtype=np.float64)
    dec = np.arcsin(np.clip(v[:, 2], -1.0, 1.0))
    masks = band_masks if band_masks is not None else [np.ones(len(v), dtype=bool)]
    found: dict[tuple[int, ...], None] = {}  # insertion-ordered set
    n = pattern.n
    dmax = pattern.delta_max_rad
    for mask in masks:
        members = np.flatnonzero(mask)
        vm, dm = v[members], dec[members]

        def extend(assign: list[int], m: int, vm=vm, dm=dm, members=members) -> None:
            if m == n:
                _accept(assign)
                return
            ok = np.ones(len(members), dtype=bool)
            for s in range(m):
                a = assign[s]
                if dec_check:
                    ok &= np.abs(dec[a] - dm) < dmax
                ok &= _in_window(vm @ v[a], pattern.cos_min[s, m], pattern.cos_max[s, m])
            for im in members[ok]:
                extend([*assign, int(im)], m + 1)

        def _accept(assign: list[int]) -> None:
            if len(set(assign)) != n:
                return
            if n >= 3 and pattern.chirality != 0:
                if not _chirality_ok(v, np.array([assign]), pattern.chirality)[0]:
                    return
            found.setdefault(tuple(assign), None)

        for k1, i1 in enumerate(members):
            rest = members[k1 + 1 :]
            ok = np.ones(len(rest), dtype=bool)
            if dec_check:
                ok &= np.abs(dec[i1] - dec[rest]) < dmax
            ok &= _in_window(v[rest] @ v[i1], pattern.cos_min[0, 1], pattern.cos_max[0, 1])
            for i2 in rest[ok]:
                for a, b in ((int(i1), int(i2)), (int(i2), int(i1))):
                    extend([a, b], 2)
    if not found:
        return np.zeros((0, n), dtype=np.int64)
    return np.array(list(found), dtype=np.int64)
