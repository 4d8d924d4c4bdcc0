"""Compiled (numba) trials of the lost-in-space search: match a pattern, quick-check it.

Why compiled code: a lost-in-space frame with false stars among the brightest tries
~90–200 patterns (Renken's Not-Modus, then every 3-star combination). In numpy a trial
cost ~170–230 µs, almost all of it per-call overhead spread over many small operations
(pattern windows, window look-ups, a few 3×3 SVDs, a KD-tree query of ~20 points, the
false-match bookkeeping), not arithmetic. Compiled, a trial costs ~15–25 µs (the match,
bound by the ~10³ catalogue pairs in each window) plus ~2.5 µs per candidate checked, and
:func:`search` walks a frame's whole pattern list in one call. With the catalogue's
triangles looked up instead of scanned (:mod:`starid.triangle_index`) and the sky map
sparing the association its empty sky (:func:`sky_map`), a trial of a noise frame costs
~6 µs of matching and ~10 µs of checking. Measured (thread time,
this 2-core machine, 300 benchmark frames, Hipparcos V ≤ 6, 15° field): p95 per solve
with 8 false stars 16–20 ms → 2.4–3.1 ms, clean median 0.9 → 0.5 ms.

The functions compute what the numpy reference computes (:func:`starid.nstar.
match_indexed`, the solver's quick check with :mod:`starid.verify`'s chance estimate) —
the same rows in the same order, the same decisions; tests compare them on random
patterns. A candidate's full verification (:func:`verify_candidate`) and the final refit
(:func:`refine_pinhole`) are compiled too, equal to :mod:`starid.verify` and
:mod:`starid.refine` to rounding (docs/decisions.md). Compiled on first use and cached on
disk (:func:`starid.jit_cache.njit_cached`, keyed by this file's content and that of the
modules it compiles in): the first process after an install or
an edit spends 15–60 s compiling (once) unless :func:`prepare` (``python -m
adfusion.starid.kernels``) did it, later ones ~1 s loading.

``ix`` below is :func:`index_arrays` of a :class:`starid.index.PatternIndex`.

Example:
    >>> from adfusion.starid.kernels import binomial_tail
    >>> round(binomial_tail(3, 10, 0.01), 6)  # P(X ≥ 3), X ~ Binomial(10, 0.01): as scipy
    0.000114
"""

from __future__ import annotations

import math

import numpy as np
from adfusion.starid.index import REUSE_DRIFT_RAD
from adfusion.starid.jit_cache import njit_cached
from adfusion.starid.tracking_kernels import _inverse_information
from adfusion.starid.triangle_index import QUANTA, _cell, _sorted3
from adfusion.starid.verify import DENSITY_SAFETY
from llvmlite import ir
from numba import types
from numba.core.extending import intrinsic
from numba.typed import Dict

__all__ = ["SEARCH_START", "SKY_CELLS", "binomial_tail", "index_arrays", "match",
           "quick_checks", "scratch", "search", "sky_map", "triangle_store", "with_triangles"]

# cached on disk, keyed by this file and the modules it compiles in (starid.jit_cache)
_jit = njit_cached(nogil=True)
# small helpers called per pair or per detection, inlined: a call that passes ``ix`` (18
# members, each array reference-counted) cost ~80 ns, more than the helper's own work
_jit_inline = njit_cached(nogil=True, inline="always")
_ROWS = types.int64[:, :]  # the type of search()'s kept first-three-star assignments
#: rows search() keeps per frame (24 bytes each): a frame of noise with windows a degree
#: wide (tolerance_deg 0.3, V < 6.5, 25°) held ~2.5 million (60 MB) unbounded; a 15°
#: frame at the default tolerance keeps ~1 500
TRIANGLES_KEPT_MAX = 250_000

# search() status (state[4]) and budget-note kinds (state[5])
DONE, STRONG = 0, 1
NOTE_NONE, NOTE_WORK, NOTE_PATTERNS = 0, 1, 2
#: search()'s state at a frame's first trial: pattern 0, guess 0, none tried, no first
#: matching counter, DONE, no note (read, not written: callers copy it)
SEARCH_START = np.array([0, 0, 0, -1, DONE, NOTE_NONE, 0, 0], dtype=np.int64)
SEARCH_START.flags.writeable = False
# association: angular slack (rad) of the neighbour-row annulus, far above the rounding
# of an arccos near 0 (~1.5e-8 rad) and far below any match radius
_SLACK = 1e-7
# the pair list's stored cosines against the stars' own dot products: in an index reused
# at a later epoch the stars moved by up to REUSE_DRIFT_RAD each since; numpy's and the
# kernels' arccos may differ by an ulp. Windows are widened so far where a test on one
# stands for a test on the other: the triangle table's cells (rad), cosine prefilters
_CELL_MARGIN = 2 * REUSE_DRIFT_RAD + 1e-9
_COS_MARGIN = 2 * REUSE_DRIFT_RAD + 1e-12


def index_arrays(index, triangles: tuple | None = None,
                 sky: tuple | None = None) -> tuple:
    """The arrays of a :class:`starid.index.PatternIndex` the kernels take, as one tuple,
    with the pair list's coarse table (:func:`pair_bins`), then the catalogue triangles
    (:func:`starid.triangle_index.triangles_for`: tri, offs, cell_rad, n_cells; none —
    empty, n_cells 0 — by default: the first three stars are matched by scanning) and the
    sky map (words, cells per face edge, radius: :func:`sky_map`; none by default)."""
    if triangles is None:
        triangles = (np.zeros((0, 3), np.uint16), np.zeros(1, np.int32), 1.0, 0)
    if sky is None:
        sky = (np.zeros(1, np.uint64), 0, 0.0)
    tri, offs, cell_rad, n_cells = triangles
    words, m, sky_rad = sky
    return (index.vectors, index.pair_i, index.pair_j, index.pair_cos, index.nbr_ptr,
            index.nbr_idx, index.nbr_cos, index.nbr_bin, float(index.max_sep_rad),
            pair_bins(index.pair_cos, float(index.max_sep_rad)), tri, offs,
            float(cell_rad), int(n_cells), words, int(m), float(sky_rad),
            _cos_deviation(index.vectors, index.pair_i, index.pair_j, index.pair_cos))


def with_triangles(ix: tuple, triangles: tuple) -> tuple:
    """:func:`index_arrays`' tuple ``ix`` with the catalogue triangles
    (:func:`starid.triangle_index.triangles_for`) in place of its members 10–13, the rest
    kept as computed (the pair bins and the cosines' deviation take ~1 ms each)."""
    tri, offs, cell_rad, n_cells = triangles
    return (*ix[:10], tri, offs, float(cell_rad), int(n_cells), *ix[14:])


@_jit
def _cos_deviation(v, pair_i, pair_j, pair_cos):
    """The largest difference between a pair's stored cosine and its stars' dot product
    as the kernels compute it (:func:`_dot`): 0 for an index built from ``v`` (the build
    computes the same sums in the same order), up to the stars' drift for an index reused
    at a later epoch. A fresh dot farther than this inside a window stands for the stored
    cosine (:func:`_triangles_looked_up`)."""
    worst = 0.0
    for r in range(len(pair_cos)):
        a, b = pair_i[r], pair_j[r]
        d = v[a, 0] * v[b, 0] + v[a, 1] * v[b, 1] + v[a, 2] * v[b, 2]
        worst = max(worst, abs(d - pair_cos[r]))
    return worst


#: bins of the pair list's coarse table: ~20 pairs a bin for Hipparcos to V 6 in a 15° field
PAIR_BINS = 1 << 14


def pair_bins(pair_cos: np.ndarray, max_sep_rad: float) -> np.ndarray:
    """For the descending ``pair_cos``, the first row at an angle ≥ b·max_sep/B for every
    bin b ≤ B (:data:`PAIR_BINS`): a window's rows are then searched among a few dozen
    pairs instead of the whole list (~19 halvings, most of them cache misses, six times a
    pattern). :func:`_pair_window` checks the bracket and falls back to the whole list, so
    the rows are the same."""
    edges = np.cos(np.linspace(0.0, max_sep_rad, PAIR_BINS + 1))
    # first row with pair_cos < edge (descending list: searchsorted on the negation)
    return np.searchsorted(-pair_cos, -edges, side="right").astype(np.int64)


# --- matching (starid.nstar.match_indexed, level by level) ------------------------------


@_jit
def _first_below(pair_cos, c, a, b):
    """First row in [a, b) of the descending ``pair_cos`` with value < c (b if none)."""
    while a < b:
        h = (a + b) // 2
        if pair_cos[h] < c:
            b = h
        else:
            a = h + 1
    return a


@_jit
def _first_at_most(pair_cos, c, a, b):
    """First row in [a, b) of the descending ``pair_cos`` with value ≤ c (b if none)."""
    while a < b:
        h = (a + b) // 2
        if pair_cos[h] <= c:
            b = h
        else:
            a = h + 1
    return a


@_jit
def _bracket(bins, max_sep, c, n_rows):
    """Rows [a, b) of the pair list that hold the first row near cosine ``c`` by the coarse
    table (a bin either side of c's for rounding); the caller checks the bracket."""
    nb = len(bins) - 1
    if not c == c:  # NaN: no bracket (int(NaN) would index anywhere)
        return 0, n_rows
    k = int(math.acos(min(max(c, -1.0), 1.0)) / (max_sep / nb))
    a = bins[min(max(k - 1, 0), nb)]
    b = bins[min(k + 2, nb)] if k + 2 <= nb else n_rows
    return a, b


@_jit
def _pair_window(pair_cos, cmin, cmax, bins, max_sep):
    """Rows of the descending ``pair_cos`` with cmin < c < cmax: [lo, hi) — each edge
    searched within the coarse table's bracket (``bins``, :func:`pair_bins`) when the
    bracket holds it, else in the whole list: the same rows either way."""
    n = len(pair_cos)
    a, b = _bracket(bins, max_sep, cmax, n)
    if (a == 0 or pair_cos[a - 1] >= cmax) and (b == n or pair_cos[b] < cmax):
        lo = _first_below(pair_cos, cmax, a, b)
    else:
        lo = _first_below(pair_cos, cmax, 0, n)
    a, b = _bracket(bins, max_sep, cmin, n)
    a = max(a, lo)
    if (a == lo or pair_cos[a - 1] > cmin) and (b == n or pair_cos[b] <= cmin) and b >= a:
        hi = _first_at_most(pair_cos, cmin, a, b)
    else:
        hi = _first_at_most(pair_cos, cmin, lo, n)
    return lo, max(lo, hi)


@_jit
def _grown(a, k):
    """``a`` (rows, cols) with twice the rows, the first k copied (loops, not slices:
    slice assignment costs seconds of compile time)."""
    out = np.empty((2 * max(len(a), 8), a.shape[1]), dtype=a.dtype)
    for r in range(k):
        for c in range(a.shape[1]):
            out[r, c] = a[r, c]
    return out


@_jit_inline
def _dot(v, a, b):
    return v[a, 0] * v[b, 0] + v[a, 1] * v[b, 1] + v[a, 2] * v[b, 2]


@_jit_inline
def _mirror_ok(v, a, b, c, chirality):
    # det[a, b, c], written as starid.nstar._chirality_ok writes it
    det = (v[a, 0] * (v[b, 1] * v[c, 2] - v[b, 2] * v[c, 1])
           - v[a, 1] * (v[b, 0] * v[c, 2] - v[b, 2] * v[c, 0])
           + v[a, 2] * (v[b, 0] * v[c, 1] - v[b, 1] * v[c, 0]))
    return (det > 0 and chirality == 1) or (det < 0 and chirality == -1)


def scratch(ix) -> np.ndarray:
    """The work array :func:`match` takes (all −1; it leaves it so)."""
    return np.full(2 * len(ix[0]), -1, dtype=np.int64)


@_jit
def match(ix, cmin, cmax, chirality, max_partials, work):
    """:func:`starid.nstar.match_indexed` of a pattern's windows (n, n) and mirror sign:
    (rows (K, n), over, level) — ``over`` > 0 when level ``level`` would hold ``over``
    partial assignments, more than ``max_partials`` (no rows then). ``work`` is
    :func:`scratch` (reused across calls: no per-call clearing of catalogue-sized arrays).

    The third star is not looked up in the first star's neighbour row but among its
    partners in the pair list's window (0, 2): the same stored cosines, the same strict
    test, in the same order (descending cosine, ties by index), so the same rows; only
    first pairs whose second star has some partner in window (1, 2) are extended (the
    rest extend to nothing; that mask is a superset, widened by a few ulps, since the
    link test computes its cosine afresh) — unless that window reaches past the index's
    ``max_sep``, where the pair list holds no partners. Only the first pairs' stars get
    their partner lists, and both star sets are bit sets: a frame's first match, in a
    cache other work has evicted, was mostly writes to catalogue-sized arrays. The last
    level counts against ``max_partials`` too. ``work[:N]`` is all −1 (left so)."""
    n = cmin.shape[0]
    if n == 2:
        pair_i, pair_j, pair_cos, max_sep, bins = ix[1], ix[2], ix[3], ix[8], ix[9]
        lo, hi = _pair_window(pair_cos, cmin[0, 1], cmax[0, 1], bins, max_sep)
        n_first = 2 * (hi - lo)
        if n_first > max_partials:
            return np.zeros((0, 2), dtype=np.int64), n_first, 2
        cur = np.empty((n_first, 2), dtype=np.int64)
        for r in range(lo, hi):  # every i < j pair, then the same pairs swapped
            cur[r - lo, 0], cur[r - lo, 1] = pair_i[r], pair_j[r]
            cur[r - lo + hi - lo, 0], cur[r - lo + hi - lo, 1] = pair_j[r], pair_i[r]
        return cur, 0, 0
    tri, over, level = _triangles(ix, cmin, cmax, chirality, max_partials, work)
    if over > 0:
        return np.zeros((0, n), dtype=np.int64), over, level
    return _extended(ix, tri, cmin, cmax, max_partials)


@_jit
def _triangles(ix, cmin, cmax, chirality, max_partials, work):
    """The first three levels of :func:`match`: the assignments (K, 3) of the pattern's
    first three stars — which depend only on their three windows and the mirror sign, so
    :func:`search` reuses them for every pattern that starts with the same three
    detections — and (over, level) as :func:`match` returns them for levels 2 and 3."""
    v, pair_i, pair_j, pair_cos = ix[0], ix[1], ix[2], ix[3]
    max_sep, bins = ix[8], ix[9]
    n_cat = len(v)
    lo, hi = _pair_window(pair_cos, cmin[0, 1], cmax[0, 1], bins, max_sep)
    n_first = 2 * (hi - lo)
    if n_first == 0:
        return np.zeros((0, 3), dtype=np.int64), 0, 0
    if n_first > max_partials:
        return np.zeros((0, 3), dtype=np.int64), n_first, 2
    if _looked_up(ix, cmin):
        rows = _triangles_looked_up(ix, cmin, cmax, chirality)
        if len(rows) > max_partials:
            return np.zeros((0, 3), dtype=np.int64), len(rows), 3
        return rows, 0, 0
    # the stars of the first pairs (bit set S, a few hundred bytes: in the L1 cache);
    # only they are looked up below, so only their partners in window (0, 2) are listed
    words = (n_cat + 63) >> 6
    in_first = np.zeros(words, dtype=np.uint64)
    for r in range(lo, hi):
        x, y = pair_i[r], pair_j[r]
        in_first[x >> 6] |= np.uint64(1) << np.uint64(x & 63)
        in_first[y >> 6] |= np.uint64(1) << np.uint64(y & 63)
    # window (0, 2) as linked lists per star of S in work[:N] (first entry, −1 = none),
    # built backwards so that each list runs in pair-list order
    lo2, hi2 = _pair_window(pair_cos, cmin[0, 2], cmax[0, 2], bins, max_sep)
    nxt_e = np.empty(2 * (hi2 - lo2), dtype=np.int64)
    other = np.empty(2 * (hi2 - lo2), dtype=np.int64)
    e = 0
    for r in range(hi2 - 1, lo2 - 1, -1):
        x, y = pair_i[r], pair_j[r]
        if in_first[x >> 6] & (np.uint64(1) << np.uint64(x & 63)):
            nxt_e[e], other[e], work[x] = work[x], y, e
            e += 1
        if in_first[y >> 6] & (np.uint64(1) << np.uint64(y & 63)):
            nxt_e[e], other[e], work[y] = work[y], x, e
            e += 1
    # the pair list holds pairs closer than max_sep only: when window (1, 2) reaches
    # beyond, a partner there would be missed, so every first pair is extended. The mask
    # is widened by what the link test's fresh cosine may differ from the stored one: in
    # an index reused at a later epoch (index.REUSE_DRIFT_RAD) the stars have moved
    masked = math.acos(min(max(cmin[1, 2], -1.0), 1.0)) < max_sep - _CELL_MARGIN
    lo3, hi3 = _pair_window(pair_cos, cmin[1, 2] - _COS_MARGIN, cmax[1, 2] + _COS_MARGIN,
                            bins, max_sep)
    if not masked:
        lo3 = hi3
    in_12 = np.zeros(words, dtype=np.uint64)  # the stars with a partner in window (1, 2)
    for r in range(lo3, hi3):
        x, y = pair_i[r], pair_j[r]
        in_12[x >> 6] |= np.uint64(1) << np.uint64(x & 63)
        in_12[y >> 6] |= np.uint64(1) << np.uint64(y & 63)
    cur = np.empty((16, 3), dtype=np.int64)
    k = 0
    for swap in range(2):  # every i < j pair, then the same pairs swapped
        for r in range(lo, hi):
            a, b = (pair_j[r], pair_i[r]) if swap else (pair_i[r], pair_j[r])
            if masked and not in_12[b >> 6] & (np.uint64(1) << np.uint64(b & 63)):
                continue
            e = work[a]
            while e >= 0:
                s = other[e]
                e = nxt_e[e]
                d = _dot(v, b, s)
                if s == b or not (d > cmin[1, 2] and d < cmax[1, 2]):
                    continue
                if chirality != 0 and not _mirror_ok(v, a, b, s, chirality):
                    continue
                if k == len(cur):
                    cur = _grown(cur, k)
                cur[k, 0], cur[k, 1], cur[k, 2] = a, b, s
                k += 1
    for r in range(lo, hi):  # the lists' heads back to −1 (only S's were set)
        work[pair_i[r]] = work[pair_j[r]] = -1
    if k > max_partials:  # as _extended would say of them: bounded memory for the rest
        return np.zeros((0, 3), dtype=np.int64), k, 3
    return cur[:k], 0, 0


@_jit
def _looked_up(ix, cmin):
    """Whether :func:`_triangles` looks the first three stars up in the triangle table:
    there is one, and window (1, 2) stays inside the pair list's reach (beyond, a partner
    there is no pair of the index, so no side of a stored triangle: scanned)."""
    return ix[13] > 0 and math.acos(min(max(cmin[1, 2], -1.0), 1.0)) < \
        ix[8] - _CELL_MARGIN - 1e-6


@_jit
def _angle_window(cmin, cmax):
    return (math.acos(min(max(cmax, -1.0), 1.0)) - _CELL_MARGIN,
            math.acos(min(max(cmin, -1.0), 1.0)) + _CELL_MARGIN)


@_jit_inline
def _stored_cos(nbr_ptr, nbr_idx, nbr_cos, a, b, near):
    """The pair list's stored cosine of stars a, b (their row in a's neighbour row,
    searched near the cosine ``near``; NaN if they are no pair)."""
    lo, hi = nbr_ptr[a], nbr_ptr[a + 1]
    e = _first_below(nbr_cos, near + _COS_MARGIN, lo, hi)  # descending within a row
    while e < hi and nbr_cos[e] >= near - _COS_MARGIN:
        if nbr_idx[e] == b:
            return nbr_cos[e]
        e += 1
    for e in range(lo, hi):  # not where expected: the whole row
        if nbr_idx[e] == b:
            return nbr_cos[e]
    return np.nan


@_jit_inline
def _quanta_in(lo, hi, c, n):
    """The quanta (:data:`starid.triangle_index.QUANTA` per cell) a sorted side in cell
    ``c`` of ``n`` may have to lie within [lo, hi] (in cells): (first, last). A side in
    quantum q lies in [c + q/Q, c + (q+1)/Q) — the last cell's last quantum reaches past
    it — so the bounds are rounded outwards, with a slack far above the rounding."""
    a = (lo - c) * QUANTA - 1e-6
    b = (hi - c) * QUANTA + 1e-6
    first = max(math.ceil(a) - 1, -1) if a < QUANTA else QUANTA
    if c == n - 1:
        first = min(first, QUANTA - 1)
    last = min(math.floor(b), QUANTA) if b > -1 else -1
    return first, last


@_jit
def _near_tie(cur, keys, k, gap):
    """Whether two of the ``k`` rows ``cur`` the sort keys ``keys`` order by a side's
    cosine (:func:`_triangles_looked_up`) hold different pairs on that side with keys
    within ``gap``: their stored cosines might order them otherwise."""
    for r in range(k):
        for s in range(r + 1, k):
            if keys[r, 0] != keys[s, 0]:
                continue
            if keys[r, 2] != keys[s, 2] or keys[r, 3] != keys[s, 3]:  # other first pairs
                if abs(keys[r, 1] - keys[s, 1]) <= gap:
                    return True
            elif (keys[r, 5] != keys[s, 5] or keys[r, 6] != keys[s, 6]) \
                    and abs(keys[r, 4] - keys[s, 4]) <= gap:
                return True
    return False


@intrinsic
def _prefetch(typingctx, arr, i):
    """A hint to the CPU to fetch ``arr[i]`` (a 1-D or 2-D array's flat element ``i``)
    into the caches now (``llvm.prefetch``: read, keep, data); nothing else happens."""
    if not isinstance(arr, types.Array):
        return None

    def codegen(context, builder, signature, args):
        aryty, idxty = signature.args
        ary = context.make_array(aryty)(context, builder, args[0])
        idx = context.cast(builder, args[1], idxty, types.intp)
        ptr = builder.bitcast(builder.gep(ary.data, [idx]), ir.IntType(8).as_pointer())
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [ptr.type, i32, i32, i32])
        fn = builder.module.declare_intrinsic("llvm.prefetch", [ptr.type], fnty)
        builder.call(fn, [ptr, i32(0), i32(3), i32(1)])
        return context.get_dummy_value()

    return types.none(arr, i), codegen


@_jit
def _triangles_looked_up(ix, cmin, cmax, chirality):
    """:func:`_triangles`'s rows (K, 3) from the triangle table: every stored triangle in
    the cells of the windows' sorted side angles, each of its six orders tested as the
    scan tests a row (windows (0, 1) and (0, 2) on the pair list's stored cosines, (1, 2)
    on the stars' dot product, the mirror sign), in the scan's order — first pairs in
    pair-list order, i < j before the same pairs swapped, then third stars in the order
    of the pairs (0, 2): descending stored cosine, ties by (i, j)."""
    v, tri, offs, h, n = ix[0], ix[10], ix[11], ix[12], ix[13]
    nbr_ptr, nbr_idx, nbr_cos, dev = ix[4], ix[5], ix[6], ix[17]
    l01, u01 = _angle_window(cmin[0, 1], cmax[0, 1])
    l02, u02 = _angle_window(cmin[0, 2], cmax[0, 2])
    l12, u12 = _angle_window(cmin[1, 2], cmax[1, 2])
    # a triangle matched in some order has its sorted sides within the sorted bounds
    lo1, lo2, lo3 = _sorted3(l01, l02, l12)
    hi1, hi2, hi3 = _sorted3(u01, u02, u12)
    a1, b1 = max(int(lo1 / h), 0), min(int(hi1 / h), n - 1)
    a2, b2 = max(int(lo2 / h), 0), min(int(hi2 / h), n - 1)
    a3, b3 = max(int(lo3 / h), 0), min(int(hi3 / h), n - 1)
    c01a, c01b, c02a, c02b = cmin[0, 1], cmax[0, 1], cmin[0, 2], cmax[0, 2]
    c12a, c12b = cmin[1, 2], cmax[1, 2]
    cur = np.empty((16, 3), dtype=np.int64)
    keys = np.empty((16, 7))
    k = 0
    # the cells come in runs of consecutive c1 (one per c2, c3), each a stretch of the
    # cell and triangle tables; first every run's bounds and its first rows asked for at
    # once — in cold caches each is a cache miss, and read one after the other (as the
    # scan below reaches them) they were most of a look-up's time
    n_runs = 0
    runs = np.empty((max(b3 - a3 + 1, 0) * max(b2 - a2 + 1, 0), 2), dtype=np.int64)
    for c3 in range(a3, b3 + 1):
        for c2 in range(a2, min(b2, c3) + 1):
            e1 = min(b1, c2)
            if e1 >= a1:
                lo_t, hi_t = offs[_cell(a1, c2, c3)], offs[_cell(e1, c2, c3) + 1]
                runs[n_runs, 0], runs[n_runs, 1] = lo_t, hi_t
                n_runs += 1
    for r in range(n_runs):
        for t in range(runs[r, 0], runs[r, 1], 8):  # 8 rows of 8 bytes: a cache line
            _prefetch(tri, 4 * t)
    for c3 in range(a3, b3 + 1):
        m3, n3 = _quanta_in(lo3 / h, hi3 / h, c3, n)
        for c2 in range(a2, min(b2, c3) + 1):
            m2, n2 = _quanta_in(lo2 / h, hi2 / h, c2, n)
            for c1 in range(a1, min(b1, c2) + 1):
                m1, n1 = _quanta_in(lo1 / h, hi1 / h, c1, n)
                cell = _cell(c1, c2, c3)
                for t in range(offs[cell], offs[cell + 1]):
                    # the sides' quanta first: most triangles of a cell miss the windows,
                    # and are passed over without reading their stars' vectors
                    qs = np.int64(tri[t, 3])
                    q1, q2, q3 = qs & 31, (qs >> 5) & 31, qs >> 10
                    if not (q1 >= m1 and q1 <= n1 and q2 >= m2 and q2 <= n2 and q3 >= m3
                            and q3 <= n3):
                        continue
                    x, y, z = np.int64(tri[t, 0]), np.int64(tri[t, 1]), np.int64(tri[t, 2])
                    dxy, dxz, dyz = _dot(v, x, y), _dot(v, x, z), _dot(v, y, z)
                    for p in range(6):
                        if p == 0:
                            a, b, c, dab, dac, dbc = x, y, z, dxy, dxz, dyz
                        elif p == 1:
                            a, b, c, dab, dac, dbc = x, z, y, dxz, dxy, dyz
                        elif p == 2:
                            a, b, c, dab, dac, dbc = y, x, z, dxy, dyz, dxz
                        elif p == 3:
                            a, b, c, dab, dac, dbc = y, z, x, dyz, dxy, dxz
                        elif p == 4:
                            a, b, c, dab, dac, dbc = z, x, y, dxz, dyz, dxy
                        else:
                            a, b, c, dab, dac, dbc = z, y, x, dyz, dxz, dxy
                        if not (dbc > c12a and dbc < c12b
                                and dab > c01a - _COS_MARGIN and dab < c01b + _COS_MARGIN
                                and dac > c02a - _COS_MARGIN and dac < c02b + _COS_MARGIN):
                            continue
                        # the stored cosines decide the windows (as in the scan), but a
                        # fresh dot farther than `dev` inside a window stands for its
                        # stored cosine: looked up only near an edge (each look-up is a
                        # search of a neighbour row, mostly cache misses)
                        sab, sac = dab, dac
                        if not (dab > c01a + dev and dab < c01b - dev):
                            sab = _stored_cos(nbr_ptr, nbr_idx, nbr_cos, a, b, dab)
                            if not (sab > c01a and sab < c01b):
                                continue
                        if not (dac > c02a + dev and dac < c02b - dev):
                            sac = _stored_cos(nbr_ptr, nbr_idx, nbr_cos, a, c, dac)
                            if not (sac > c02a and sac < c02b):
                                continue
                        if chirality != 0 and not _mirror_ok(v, a, b, c, chirality):
                            continue
                        if k == len(cur):
                            cur = _grown(cur, k)
                            keys = _grown(keys, k)
                        cur[k, 0], cur[k, 1], cur[k, 2] = a, b, c
                        keys[k, 0] = 1.0 if a > b else 0.0
                        keys[k, 1], keys[k, 2], keys[k, 3] = -sab, min(a, b), max(a, b)
                        keys[k, 4], keys[k, 5], keys[k, 6] = -sac, min(a, c), max(a, c)
                        k += 1
    if dev > 0 and _near_tie(cur, keys, k, 2 * dev):
        # two pairs' fresh cosines too close to order them as their stored ones: the
        # stored cosines of every row as sort keys
        for r in range(k):
            a, b, c = cur[r, 0], cur[r, 1], cur[r, 2]
            keys[r, 1] = -_stored_cos(nbr_ptr, nbr_idx, nbr_cos, a, b, -keys[r, 1])
            keys[r, 4] = -_stored_cos(nbr_ptr, nbr_idx, nbr_cos, a, c, -keys[r, 4])
    return _in_scan_order(cur, keys, k)


@_jit
def _in_scan_order(cur, keys, k):
    """The rows ``cur[:k]`` ordered by their sort keys ``keys`` (:func:`_row_before`; no
    two alike: they name the row's stars): by insertion for a few rows, else by a merge
    sort of their indices — at σ = 2 px a look-up finds ~180 rows (up to ~640), and
    sorting them by insertion took most of the look-up's ~150 µs."""
    if k <= 16:
        for i in range(1, k):
            j = i
            while j > 0 and _row_before(keys, j, j - 1):
                for t in range(7):
                    keys[j, t], keys[j - 1, t] = keys[j - 1, t], keys[j, t]
                for t in range(3):
                    cur[j, t], cur[j - 1, t] = cur[j - 1, t], cur[j, t]
                j -= 1
        return cur[:k]
    idx = np.empty((2, k), dtype=np.int64)
    src, dst = idx[0], idx[1]
    for i in range(k):
        src[i] = i
    width = 1
    while width < k:  # bottom-up: runs of width merged pairwise
        for lo in range(0, k, 2 * width):
            mid, hi = min(lo + width, k), min(lo + 2 * width, k)
            i, j = lo, mid
            for t in range(lo, hi):
                if j < hi and (i == mid or _row_before(keys, src[j], src[i])):
                    dst[t] = src[j]
                    j += 1
                else:
                    dst[t] = src[i]
                    i += 1
        src, dst = dst, src
        width *= 2
    out = np.empty((k, 3), dtype=np.int64)
    for r in range(k):
        for t in range(3):
            out[r, t] = cur[src[r], t]
    return out


@_jit_inline
def _row_before(keys, r, s):
    """Whether row ``r`` of the sort keys ``keys`` comes before row ``s``: the first key
    that differs decides, lower first."""
    for t in range(7):
        if keys[r, t] != keys[s, t]:
            return keys[r, t] < keys[s, t]
    return False


@_jit
def _extended(ix, cur, cmin, cmax, max_partials):
    """The levels of :func:`match` past the third: the assignments ``cur`` (K, 3) of the
    first three stars extended, star by star, through the first star's neighbour row;
    (rows (K', n), over, level) as :func:`match` returns them. ``cur`` is not written."""
    v, nbr_idx, nbr_cos, nbr_bin, max_sep = ix[0], ix[5], ix[6], ix[7], ix[8]
    n = cmin.shape[0]
    k = len(cur)
    nb = nbr_bin.shape[1] - 1
    step = max_sep / nb
    for m in range(3, n):  # further stars: the first star's neighbour row
        if k == 0:
            return np.zeros((0, n), dtype=np.int64), 0, 0
        if k > max_partials:
            return np.zeros((0, n), dtype=np.int64), k, m
        b0 = min(max(int(math.acos(cmax[0, m]) / step), 0), nb)
        b1 = min(max(int(math.acos(cmin[0, m]) / step) + 1, 0), nb)
        nxt = np.empty((max(16, 2 * k), n), dtype=np.int64)
        kn = 0
        for p in range(k):
            a = cur[p, 0]
            for e in range(nbr_bin[a, b0], nbr_bin[a, b1]):
                c = nbr_cos[e]
                if not (c > cmin[0, m] and c < cmax[0, m]):
                    continue
                s = nbr_idx[e]
                ok = True
                for t in range(1, m):
                    q = cur[p, t]
                    d = _dot(v, q, s)
                    if q == s or not (d > cmin[t, m] and d < cmax[t, m]):
                        ok = False
                        break
                if ok:
                    if kn == len(nxt):
                        nxt = _grown(nxt, kn)
                    for t in range(m):
                        nxt[kn, t] = cur[p, t]
                    nxt[kn, m] = s
                    kn += 1
        cur, k = nxt, kn
    if k > max_partials:  # the last level too: bounded memory for the quick checks
        return np.zeros((0, n), dtype=np.int64), k, n
    return _grown(cur, k)[:k], 0, 0


# --- the quick check (Solver: rotation, association, false-match probability) ----------


@_jit
def binomial_tail(k, m, p):
    """P(X ≥ k) for X ~ Binomial(m, p) (scipy's ``bdtrc(k − 1, m, p)``, to ~1e-14
    relative for the m ≤ 30 detections used): the terms summed from the smallest."""
    if k <= 0:
        return 1.0
    if k > m:
        return 0.0
    p = min(max(p, 0.0), 1.0)
    q = 1.0 - p
    total = 0.0
    coef = 1.0  # C(m, i), from i = m down
    for i in range(m, k - 1, -1):
        total += coef * p ** i * q ** (m - i)
        coef = coef * i / (m - i + 1)
    return total


@_jit_inline
def _crossing_sin(c01, c0m, c1m, s0m, s1m):
    """sin of ``starid.verify._crossing_angle`` from the cosines and sines of its angles
    (d01, d0m, d1m)."""
    denom = s0m * s1m
    if denom <= 0:
        return 0.0
    c = (c01 - c0m * c1m) / denom
    return math.sin(math.acos(min(1.0, max(-1.0, c))))


@_jit
def _spot_geometry(a):
    """:func:`starid.verify.spot_geometry`: rows (s, t) and sin γ per star m ≥ 2 — each
    pair's cosine and sine taken once, not once per crossing it is part of (an 8-star
    pattern has 56 crossings of 28 pairs)."""
    n = a.shape[0]
    st = np.zeros((max(n - 2, 0), 2), dtype=np.int64)
    sg = np.zeros(max(n - 2, 0))
    trig = np.empty((2, n, n))
    ca, sa = trig[0], trig[1]
    for s in range(n):
        for t in range(s + 1, n):
            ca[s, t], sa[s, t] = math.cos(a[s, t]), math.sin(a[s, t])
    for m in range(2, n):
        bs, bt, best = 0, 1, 0.0
        for s in range(m):
            for t in range(s + 1, m):
                g = _crossing_sin(ca[s, t], ca[s, m], ca[t, m], sa[s, m], sa[t, m])
                if g > best:
                    bs, bt, best = s, t, g
        st[m - 2, 0], st[m - 2, 1], sg[m - 2] = bs, bt, best
    return st, sg


@_jit
def _chance(a, w, n_catalog, mirror_checked, st, sg):
    """:func:`starid.verify.expected_chance_patterns` (``w`` = 2 × the windows), the
    same operations in the same order."""
    rho = DENSITY_SAFETY * n_catalog / (4.0 * np.pi)
    e = float(n_catalog) * rho * 2.0 * np.pi * max(math.sin(a[0, 1]), 1e-6) * w[0, 1]
    e *= 2.0
    for r in range(len(sg)):
        m = r + 2
        spots = 1.0 if (m >= 3 or mirror_checked) else 2.0
        e *= rho * spots * w[st[r, 0], m] * w[st[r, 1], m] / max(sg[r], 0.05)
    return e


# --- the sky map: where no catalogue star lies near (starid.Solver's association) ------

#: cells per cube-face edge of the sky map (6 × 1024² bits: 768 KiB, and a coarse copy)
SKY_CELLS = 1024
# the map's coarse copy, in front of it: a cell of 2³ × 2³ fine cells, marked when any of
# them is (6 × 128² bits, 12 KiB: it stays in the L1 cache, where a probe of the fine map
# is mostly a cache miss — and most probes of a wrong attitude end in the coarse map)
_COARSE_SHIFT = 3
_FACE_Z_MIN = 1.0 / math.sqrt(3.0)  # a direction's largest |component| is at least this


@_jit_inline
def _face_bin(u, m):
    """The cell row (or column) of gnomonic coordinate u ∈ [−1, 1] on a face of m cells —
    one formula for the map's marks and its queries."""
    return min(max(int((u + 1.0) * 0.5 * m), 0), m - 1)


@_jit_inline
def _sky_cell(x, y, z, m):
    """The cube-map cell of direction (x, y, z) (any length > 0): the face of its largest
    component, then the gnomonic coordinates on that face in m × m cells: (face, row,
    column)."""
    ax, ay, az = abs(x), abs(y), abs(z)
    if ax >= ay and ax >= az:
        f, u, w = (0 if x > 0 else 1), y / ax, z / ax
    elif ay >= az:
        f, u, w = (2 if y > 0 else 3), x / ay, z / ay
    else:
        f, u, w = (4 if z > 0 else 5), x / az, y / az
    return f, _face_bin(u, m), _face_bin(w, m)


@_jit_inline
def _bit(words, c):
    return (words[c >> 6] >> np.uint64(c & 63)) & np.uint64(1) != 0


@_jit_inline
def _set_bit(words, c):
    words[c >> 6] |= np.uint64(1) << np.uint64(c & 63)


@_jit_inline
def _sky_bits(f, iu, iw, m):
    """The bits of cell (face, row, column) of a map of m cells per face edge: in the
    coarse copy (2³ × 2³ cells to a bit, first in the words), and its own (after it)."""
    mc = m >> _COARSE_SHIFT
    coarse = (f * mc + (iu >> _COARSE_SHIFT)) * mc + (iw >> _COARSE_SHIFT)
    return coarse, ((6 * mc * mc + 63) >> 6) * 64 + (f * m + iu) * m + iw


@_jit_inline
def _sky_marked(words, m, r):
    """Whether direction r's cell of the map ``words`` (:func:`sky_map`, m cells per face
    edge) is marked: the coarse copy first (m being a multiple of 2³, a fine cell's
    coarse cell is its row and column shifted — :func:`_face_bin` scales by a power of
    two exactly)."""
    f, iu, iw = _sky_cell(r[0], r[1], r[2], m)
    coarse, fine = _sky_bits(f, iu, iw, m)
    return _bit(words, coarse) and _bit(words, fine)


@_jit
def sky_map(v, radius_rad, m=SKY_CELLS):
    """The cube-map cells (bits, :func:`_sky_cell`) within ``radius_rad`` of some star
    ``v`` (N, 3) — a superset: on a face, where a direction's component along the face
    axis is z ≥ 1/√3, the gnomonic map stretches angles by at most 1/z², so a star's
    cap lies inside a square of half-width radius / (1/√3 − radius)² around its image.
    An unmarked cell holds no direction within ``radius_rad`` of any star: there the
    association (:func:`_nearest`) finds nothing, without looking.

    >>> import numpy as np
    >>> v = np.array([[0.0, 0.0, 1.0]])
    >>> w = sky_map(v, 1e-3, 64)
    >>> near, far = np.array([0.0, 5e-4, 1.0]), np.array([0.0, 0.2, 1.0])
    >>> bool(_sky_marked(w, 64, near)), bool(_sky_marked(w, 64, far))
    (True, False)

    The words hold the coarse copy (:func:`_sky_marked`), then the cells; ``m`` must be a
    multiple of 8.
    """
    if m <= 0 or m % (1 << _COARSE_SHIFT):
        raise ValueError("the sky map's cells per face edge must be a multiple of 8")
    mc = m >> _COARSE_SHIFT
    words = np.zeros(((6 * mc * mc + 63) >> 6) + ((6 * m * m + 63) >> 6), dtype=np.uint64)
    z_min = _FACE_Z_MIN - radius_rad  # along a cap's geodesics, on the face
    rho = radius_rad / (z_min * z_min) * (1.0 + 1e-6) + 1e-9
    for s in range(len(v)):
        for f in range(6):
            ax = f // 2
            sign = 1.0 if f % 2 == 0 else -1.0
            z = sign * v[s, ax]
            if z < _FACE_Z_MIN - 2.0 * radius_rad:  # the cap does not reach this face
                continue
            o1, o2 = (1, 2) if ax == 0 else ((0, 2) if ax == 1 else (0, 1))
            u, w = v[s, o1] / z, v[s, o2] / z
            for iu in range(_face_bin(u - rho, m), _face_bin(u + rho, m) + 1):
                for iw in range(_face_bin(w - rho, m), _face_bin(w + rho, m) + 1):
                    coarse, fine = _sky_bits(f, iu, iw, m)
                    _set_bit(words, coarse)
                    _set_bit(words, fine)
    return words


@_jit
def _nearest(ix, r, anchor, radius, bound2):
    """The catalogue star nearest to ``r`` (ICRS, ~unit) with squared chord < bound2, or
    −1: the anchor itself, then the anchor's neighbour row in the annulus of r's angle to
    the anchor ± radius — or every star, when that annulus leaves the row's reach
    (:func:`_nearest_in` of ``ix``'s arrays)."""
    return _nearest_in(ix[0], ix[5], ix[7], ix[8], ix[14], ix[15], ix[16], r, anchor,
                       radius, bound2)


@_jit_inline
def _nearest_in(v, nbr_idx, nbr_bin, max_sep, sky, m, sky_rad, r, anchor, radius, bound2):
    """:func:`_nearest` on the arrays it reads — the per-detection loops call this, not
    :func:`_nearest`: passing ``ix`` cost more than the look-up; first the sky map
    (``sky``, ``m`` cells per face edge, ``sky_rad``: :func:`sky_map`; m = 0: none)."""
    best, bj = bound2, -1
    if m > 0 and radius <= sky_rad and not _sky_marked(sky, m, r):
        return bj, best  # no star within the sky map's radius: none within radius
    dx, dy, dz = r[0] - v[anchor, 0], r[1] - v[anchor, 1], r[2] - v[anchor, 2]
    d2 = dx * dx + dy * dy + dz * dz
    if d2 < best:
        best, bj = d2, anchor
    c = r[0] * v[anchor, 0] + r[1] * v[anchor, 1] + r[2] * v[anchor, 2]
    theta = math.acos(min(1.0, max(-1.0, c)))
    if theta + radius + 2 * _SLACK < max_sep:
        nb = nbr_bin.shape[1] - 1
        step = max_sep / nb
        b0 = min(max(int((theta - radius - _SLACK) / step), 0), nb)
        b1 = min(max(int((theta + radius + _SLACK) / step) + 1, 0), nb)
        for e in range(nbr_bin[anchor, b0], nbr_bin[anchor, b1]):
            s = nbr_idx[e]
            dx, dy, dz = r[0] - v[s, 0], r[1] - v[s, 1], r[2] - v[s, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < best:
                best, bj = d2, s
    else:
        for s in range(len(v)):
            dx, dy, dz = r[0] - v[s, 0], r[1] - v[s, 1], r[2] - v[s, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < best:
                best, bj = d2, s
    return bj, best


@_jit
def _rotation(b, vc):
    """Least-squares rotation (cam ← icrs) of matched directions, as
    ``starid.solver._rotation_from_pairs`` (SVD of B = Σ b cᵀ, reflection excluded);
    (R, proper) — proper False if collinear. The 3×3 SVD is one-sided Jacobi (columns
    of B orthogonalised by plane rotations): no LAPACK call per candidate. B, the
    rotations V and R share one allocation (a frame makes a dozen of these, and in cold
    caches each allocation costs)."""
    blk = np.zeros((3, 3, 3))
    A, V, R = blk[0], blk[1], blk[2]
    for s in range(b.shape[0]):
        for i in range(3):
            for j in range(3):
                A[i, j] += b[s, i] * vc[s, j]
    V[0, 0] = V[1, 1] = V[2, 2] = 1.0
    for _ in range(30):
        done = True
        for p, q in ((0, 1), (0, 2), (1, 2)):
            alpha = A[0, p] * A[0, p] + A[1, p] * A[1, p] + A[2, p] * A[2, p]
            beta = A[0, q] * A[0, q] + A[1, q] * A[1, q] + A[2, q] * A[2, q]
            gamma = A[0, p] * A[0, q] + A[1, p] * A[1, q] + A[2, p] * A[2, q]
            if abs(gamma) <= 1e-15 * math.sqrt(alpha * beta):
                continue
            done = False
            zeta = (beta - alpha) / (2.0 * gamma)
            t = math.copysign(1.0, zeta) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
            c = 1.0 / math.sqrt(1.0 + t * t)
            s = c * t
            for i in range(3):
                ap, aq = A[i, p], A[i, q]
                A[i, p], A[i, q] = c * ap - s * aq, s * ap + c * aq
                vp, vq = V[i, p], V[i, q]
                V[i, p], V[i, q] = c * vp - s * vq, s * vp + c * vq
        if done:
            break
    # singular values: the column norms; the two largest (scalar code: numpy calls
    # inside kernels cost compile time)
    s0 = math.sqrt(A[0, 0] * A[0, 0] + A[1, 0] * A[1, 0] + A[2, 0] * A[2, 0])
    s1 = math.sqrt(A[0, 1] * A[0, 1] + A[1, 1] * A[1, 1] + A[2, 1] * A[2, 1])
    s2 = math.sqrt(A[0, 2] * A[0, 2] + A[1, 2] * A[1, 2] + A[2, 2] * A[2, 2])
    if s0 >= s1 and s0 >= s2:
        i0, i1 = (0, 1) if s1 >= s2 else (0, 2)
    elif s1 >= s2:
        i0, i1 = (1, 0) if s0 >= s2 else (1, 2)
    else:
        i0, i1 = (2, 0) if s0 >= s1 else (2, 1)
    sa = max(s0, s1, s2)
    sb = s1 if i1 == 1 else (s0 if i1 == 0 else s2)
    if sb < 1e-12 * max(sa, 1e-300):
        return R, False
    # R = U diag(1, 1, det U · det V) Vᵀ: the third singular pair is the cross products
    # of the first two
    for i in range(3):
        A[i, i0] /= sa
        A[i, i1] /= sb
    u0x, u0y, u0z, u1x, u1y, u1z = A[0, i0], A[1, i0], A[2, i0], A[0, i1], A[1, i1], A[2, i1]
    v0x, v0y, v0z, v1x, v1y, v1z = V[0, i0], V[1, i0], V[2, i0], V[0, i1], V[1, i1], V[2, i1]
    u2 = (u0y * u1z - u0z * u1y, u0z * u1x - u0x * u1z, u0x * u1y - u0y * u1x)
    v2 = (v0y * v1z - v0z * v1y, v0z * v1x - v0x * v1z, v0x * v1y - v0y * v1x)
    for i in range(3):
        for j in range(3):
            R[i, j] = A[i, i0] * V[j, i0] + A[i, i1] * V[j, i1] + u2[i] * v2[j]
    return R, True


@_jit
def quick_checks(ix, b_all, sel, assigns, angles, tol, mirror_checked, trials, radius,
                 floor):
    """The solver's quick check of every assignment (K, n) of one pattern (detections
    ``sel`` in matching order, image pair ``angles`` and window half-widths ``tol``):
    the rotation from the pattern, every detection rotated into ICRS and associated
    one-to-one to its nearest catalogue star within ``radius`` (the closest detection
    keeps a star, ties to the lower index), and — where the pattern kept its stars —
    p_false = min(1, trials × E_chance(windows shrunk to the fit, ≥ floor) ×
    P(Binomial(other detections, p_hit) ≥ other matches)).

    Returns (ok (K,), p_false, R (K, 3, 3), e_trials, det (K, N), cat (K, N), matched
    (K,)): candidate k's matches are det[k, :matched[k]] (ascending) → cat[k, ...]."""
    v, nbr_ptr, max_sep = ix[0], ix[4], ix[8]
    nbr_idx, nbr_bin, sky, m_sky, sky_rad = ix[5], ix[7], ix[14], ix[15], ix[16]
    n_k, n = assigns.shape
    n_det = len(b_all)
    n_cat = len(v)
    # arrays of one type share an allocation (each costs, in cold caches)
    ok = np.zeros(n_k, dtype=np.bool_)
    floats = np.zeros((2, n_k))
    pf, e_tr = floats[0], floats[1]
    rots = np.zeros((n_k, 3, 3))
    pairs = np.zeros((2, n_k, n_det), dtype=np.int64)
    det, cat = pairs[0], pairs[1]
    matched = np.zeros(n_k, dtype=np.int64)
    bound = 2 * math.sin(radius / 2)
    bound2 = bound * bound
    st, sg = _spot_geometry(angles)
    dirs = np.empty((2, n, 3))
    bs, vc = dirs[0], dirs[1]
    for s in range(n):
        for j in range(3):
            bs[s, j] = b_all[sel[s], j]
    ints = np.empty((2, n_det), dtype=np.int64)
    tgt, own = ints[0], ints[1]
    scratch = np.empty(n_det + 3 + n * n)
    dist, r, w = scratch[:n_det], scratch[n_det:n_det + 3], \
        scratch[n_det + 3:].reshape((n, n))
    w[:, :] = 0.0
    area = 2 * np.pi * (1 - math.cos(max_sep))
    in_pattern = np.zeros(n_det, dtype=np.bool_)
    for s in range(n):
        in_pattern[sel[s]] = True
    for k in range(n_k):
        anchor = assigns[k, 0]
        for s in range(n):
            for j in range(3):
                vc[s, j] = v[assigns[k, s], j]
        R, proper = _rotation(bs, vc)
        if not proper:
            continue
        # the pattern's own detections first: one whose nearest star (within the radius)
        # is not its assigned star cannot keep it, whatever the others find — about half
        # of a noise frame's candidates end here, before the other detections are looked at
        lost = False
        for s in range(n + n_det):
            d = sel[s] if s < n else s - n
            if s >= n and in_pattern[d]:
                continue
            for j in range(3):
                r[j] = b_all[d, 0] * R[0, j] + b_all[d, 1] * R[1, j] + b_all[d, 2] * R[2, j]
            tgt[d], d2 = _nearest_in(v, nbr_idx, nbr_bin, max_sep, sky, m_sky, sky_rad, r,
                                     anchor, radius, bound2)
            dist[d] = math.sqrt(d2)
            if s < n and tgt[d] != assigns[k, s]:
                lost = True
                break
        if lost:
            continue
        # one-to-one: a star claimed twice stays with the closer detection (ties: the
        # lower index); own[d] the star detection d keeps, or −1
        nm = 0
        for d in range(n_det):
            own[d] = tgt[d]
            if tgt[d] < 0:
                continue
            for e in range(n_det):
                if e != d and tgt[e] == tgt[d] and (
                        dist[e] < dist[d] or (dist[e] == dist[d] and e < d)):
                    own[d] = -1
                    break
            if own[d] >= 0:
                det[k, nm], cat[k, nm] = d, own[d]
                nm += 1
        kept = True  # every pattern star on its assigned star
        for s in range(n):
            if own[sel[s]] != assigns[k, s]:
                kept = False
        if not kept:
            continue
        for s in range(n):
            for t in range(s + 1, n):
                c = min(1.0, max(-1.0, _dot(v, assigns[k, s], assigns[k, t])))
                resid = abs(angles[s, t] - math.acos(c))
                w[s, t] = 2.0 * min(max(resid, floor), tol[s, t])
        e_trials = trials * _chance(angles, w, n_cat, mirror_checked, st, sg)
        cnt = nbr_ptr[anchor + 1] - nbr_ptr[anchor]
        rho = max(cnt / area, n_cat / (4 * np.pi)) * DENSITY_SAFETY
        p_hit = min(1.0, rho * np.pi * (radius * radius))
        p = e_trials * binomial_tail(nm - n, n_det - n, p_hit)
        ok[k], pf[k], e_tr[k], matched[k] = True, min(1.0, p), e_trials, nm
        for i in range(3):
            for j in range(3):
                rots[k, i, j] = R[i, j]
    return ok, pf, rots, e_tr, det, cat, matched


# --- a frame's whole search -------------------------------------------------------------


@_jit
def _closest_pair_first(ang, pat):
    """``starid.nstar.closest_pair_first`` of the detections ``pat`` (ties: row-major)."""
    n = len(pat)
    best, bi, bj = np.inf, 0, 1
    for i in range(n):
        for j in range(i + 1, n):
            if ang[pat[i], pat[j]] < best:
                best, bi, bj = ang[pat[i], pat[j]], i, j
    sel = np.empty(n, dtype=np.int64)
    sel[0], sel[1] = pat[bi], pat[bj]
    k = 2
    for m in range(n):
        if m != bi and m != bj:
            sel[k] = pat[m]
            k += 1
    return sel


@_jit
def _cross_norm(ux, uy, uz, vx, vy, vz):
    x, y, z = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    return math.sqrt(x * x + y * y + z * z)


@_jit
def chirality(b, min_altitude):
    """``starid.nstar.chirality_of`` (same formula): sign of det[b0, b1, b2], 0 when
    the triangle's smallest altitude is ≤ ``min_altitude``."""
    ax, ay, az = b[0, 0], b[0, 1], b[0, 2]
    bx, by, bz = b[1, 0], b[1, 1], b[1, 2]
    cx, cy, cz = b[2, 0], b[2, 1], b[2, 2]
    det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    longest = max(_cross_norm(ax, ay, az, bx, by, bz), _cross_norm(bx, by, bz, cx, cy, cz),
                  _cross_norm(cx, cy, cz, ax, ay, az))
    if longest == 0.0 or abs(det) / longest <= min_altitude:
        return 0
    return 1 if det > 0 else -1


@_jit
def _window(b, i, j, tolerance_rad, rel_tol):
    """The matching window of detections i, j (directions ``b``): (angle, half-width
    ``tolerance_rad + rel_tol × angle``, upper edge, cos of the upper edge, cos of the
    lower edge). The one formula of every pair window (:func:`pair_windows`,
    :func:`pattern_windows`), so that a table and a pattern's own windows agree bit for
    bit."""
    a = 0.0
    if i != j:
        c = b[i, 0] * b[j, 0] + b[i, 1] * b[j, 1] + b[i, 2] * b[j, 2]
        a = math.acos(min(max(c, -1.0), 1.0))
    t = tolerance_rad + rel_tol * a
    hi = min(a + t, np.pi)
    return a, t, hi, math.cos(hi), math.cos(max(a - t, 0.0))


@_jit
def pair_windows(b, tolerance_rad, rel_tol):
    """The pair windows of :class:`starid.lost_in_space.PairWindows`: pair angles of the
    directions ``b`` (N, 3), window half-widths, upper edges and the windows' cosine
    bounds (N, N each; :func:`_window`)."""
    n = b.shape[0]
    ang, tol, hi = np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    cmin, cmax = np.empty((n, n)), np.empty((n, n))
    for i in range(n):
        for j in range(n):
            ang[i, j], tol[i, j], hi[i, j], cmin[i, j], cmax[i, j] = _window(
                b, i, j, tolerance_rad, rel_tol)
    return ang, tol, hi, cmin, cmax


@_jit
def pattern_windows(pat, b_all, tolerance_rad, rel_tol):
    """A pattern's detections in matching order (closest pair first, ties row-major) and
    its windows at one focal guess — only its own pairs computed (a frame's first pattern
    is usually its last: 15 pairs, not the table's 435): (sel, angles, tol, cos_min,
    cos_max, chirality)."""
    n_det = len(b_all)
    return pattern_windows_kept(pat, b_all, tolerance_rad, rel_tol,
                                np.empty((4, n_det, n_det)),
                                np.zeros((n_det, n_det), dtype=np.bool_))


@_jit
def pattern_windows_kept(pat, b_all, tolerance_rad, rel_tol, kept, done):
    """:func:`pattern_windows` with the pair windows kept for the frame's later patterns:
    ``kept`` (4, N, N) the angle, half-width and cosine bounds of detections (x, y) where
    ``done[x, y]`` (N, N), filled here where not. The Not-Modus trials of a frame with
    false stars drop or swap one star of the pattern before, so most of their pairs were
    windowed already; :func:`_window` is symmetric to the bit (its dot product sums the
    same products in the same order), so one call fills (x, y) and (y, x)."""
    n = len(pat)
    for i in range(n):
        x = pat[i]
        for j in range(i, n):
            y = pat[j]
            if not done[x, y]:
                a, t, _, lo, hi = _window(b_all, x, y, tolerance_rad, rel_tol)
                kept[0, x, y], kept[1, x, y], kept[2, x, y], kept[3, x, y] = a, t, lo, hi
                kept[0, y, x], kept[1, y, x], kept[2, y, x], kept[3, y, x] = a, t, lo, hi
                done[x, y] = done[y, x] = True
    sel = _closest_pair_first(kept[0], pat)
    w = np.empty((4, n, n))  # one block: angles, half-widths, cosine bounds
    a, t, lo, hi = w[0], w[1], w[2], w[3]
    bs = np.empty((n, 3))
    t_max = -np.inf
    for i in range(n):
        x = sel[i]
        for j in range(3):
            bs[i, j] = b_all[x, j]
        for j in range(n):
            y = sel[j]
            t_max = max(t_max, kept[1, x, y])
            a[i, j], t[i, j], lo[i, j], hi[i, j] = kept[0, x, y], kept[1, x, y], \
                kept[2, x, y], kept[3, x, y]
    chir = chirality(bs, 2.0 * t_max) if n >= 3 else 0
    return sel, a, t, lo, hi, chir


@_jit
def triangle_store(max_rows=TRIANGLES_KEPT_MAX):
    """An empty store of a frame's first-three-star assignments for :func:`search`: (the
    assignments — keys: guess, detections and mirror sign; values: row 0 (over, level, 0),
    then the rows — and [rows kept, ``max_rows``]). Past ``max_rows`` rows, no more are
    kept (they are matched afresh)."""
    return (Dict.empty(key_type=types.int64, value_type=_ROWS),
            np.array([0, max_rows], dtype=np.int64))


@_jit
def search(ix, state, pats, plen, budget, no_match, n_no_match, b_cams, tolerance_rad,
           rel_tol, radius, floor, p_false_max, max_partials, work, store):
    """Walk the pattern list ``pats`` (P, 8; ``plen`` stars each) × focal guesses (the
    directions ``b_cams`` (C, N, 3), ``radius`` and ``floor`` per guess; each pattern's
    windows :func:`pattern_windows` of ``tolerance_rad`` and ``rel_tol``) as
    ``Solver._solve_at`` does, from the trial at
    ``state`` = [pattern, guess, tried, first matching counter (−1: none), …], and stop
    after the first trial with a candidate whose quick p_false ≤ ``p_false_max``.

    Updates ``state``: [pattern, guess of the stopping trial (or P, 0), tried, first
    counter, its own status (DONE / STRONG), note kind, note a, note b], where the note is
    the last budget event (NOTE_WORK: ``a`` partials at level ``b``; NOTE_PATTERNS: the
    trial budget reached at ``a`` trials), and the no-match sets (bit masks per guess).
    Returns the stopping trial's (sel, assignments, quick checks) and the weak candidates
    met on the way: p_false (W,) and (W, 20) rows of pattern, guess, trial, n, sel (8),
    assignment (8). ``work`` is :func:`scratch` (all −1; left so).

    Each pattern is matched as :func:`match` matches it, with its first three stars'
    assignments (:func:`_triangles`) kept in ``store`` (:func:`triangle_store`, one per
    frame, for every call of its walk): a pattern that starts with the same three
    detections at the same guess and mirror sign — most Not-Modus trials — extends them
    (:func:`_extended`) instead of scanning the pair list again; more than
    ``max_partials`` of them are kept as that count alone (:func:`_triangles` returns no
    rows then), and no more than the store's ``max_rows`` in all."""
    n_cams = b_cams.shape[0]
    n_det = b_cams.shape[1]
    triangles, kept = store
    pos, ci, tried, first = state[0], state[1], state[2], state[3]
    wp = np.empty((16, 1))
    wi = np.empty((16, 20), dtype=np.int64)  # pattern, guess, trial, n, sel, assignment
    nw = 0
    # the pair windows of this call's patterns, per guess (pattern_windows_kept)
    win_kept = np.empty((n_cams, 4, n_det, n_det))
    win_done = np.zeros((n_cams, n_det, n_det), dtype=np.bool_)
    while pos < len(pats):
        if ci == 0 and tried >= budget:
            state[5], state[6] = NOTE_PATTERNS, tried
            break
        n = plen[pos]
        pat = pats[pos, :n]
        mask = 0
        for i in range(n):
            mask |= 1 << pat[i]
        tried += 1
        skip = False
        for e in range(n_no_match[ci]):
            if no_match[ci, e] & mask == no_match[ci, e]:
                skip = True
                break
        if not skip:
            sel, a, t, lo, hi, chir = pattern_windows_kept(
                pat, b_cams[ci], tolerance_rad, rel_tol, win_kept[ci], win_done[ci])
            # the first three stars' assignments, kept per (guess, detections, mirror
            # sign): most trials after the first drop or swap a later star (Not-Modus)
            key = (((ci * n_det + sel[0]) * n_det + sel[1]) * n_det + sel[2]) * 3 + chir + 1
            if key in triangles:
                tri = triangles[key]
            else:
                rows3, over, level = _triangles(ix, lo, hi, chir, max_partials, work)
                k3 = len(rows3)
                tri = np.empty((k3 + 1, 3), dtype=np.int64)
                tri[0, 0], tri[0, 1], tri[0, 2] = over, level, 0  # row 0: over, level
                for r in range(k3):
                    tri[r + 1, 0], tri[r + 1, 1], tri[r + 1, 2] = rows3[r, 0], rows3[r, 1], \
                        rows3[r, 2]
                if kept[0] + k3 <= kept[1]:  # bounded memory: past it, not kept
                    kept[0] += k3
                    triangles[key] = tri
            if tri[0, 0] > 0:
                rows, over, level = np.zeros((0, n), dtype=np.int64), tri[0, 0], tri[0, 1]
            else:
                rows, over, level = _extended(ix, tri[1:], lo, hi, max_partials)
            if over > 0:
                state[5], state[6], state[7] = NOTE_WORK, over, level
            else:
                if first < 0:
                    first = len(rows)
                if len(rows) == 0:
                    no_match[ci, n_no_match[ci]] = mask
                    n_no_match[ci] += 1
                else:
                    q = quick_checks(ix, b_cams[ci], sel, rows, a, t, chir != 0, tried,
                                     radius[ci], floor[ci])
                    strong = False
                    for k in range(len(rows)):
                        if not q[0][k]:
                            continue
                        if q[1][k] <= p_false_max:
                            strong = True
                            continue
                        if nw == len(wi):
                            wi = _grown(wi, nw)
                            wp = _grown(wp, nw)
                        wp[nw, 0] = q[1][k]
                        wi[nw, 0], wi[nw, 1], wi[nw, 2], wi[nw, 3] = pos, ci, tried, n
                        for i in range(n):
                            wi[nw, 4 + i], wi[nw, 12 + i] = sel[i], rows[k, i]
                        nw += 1
                    if strong:
                        state[0], state[1], state[2], state[3], state[4] = (
                            pos, ci, tried, first, STRONG)
                        return sel, rows, q, wp[:nw, 0], wi[:nw]
        ci += 1
        if ci == n_cams:
            pos, ci = pos + 1, 0
    state[0], state[1], state[2], state[3], state[4] = pos, ci, tried, first, DONE
    q = (np.zeros(0, dtype=np.bool_), np.zeros(0), np.zeros((0, 3, 3)), np.zeros(0),
         np.zeros((0, n_det), dtype=np.int64), np.zeros((0, n_det), dtype=np.int64),
         np.zeros(0, dtype=np.int64))
    return (np.zeros(0, dtype=np.int64), np.zeros((0, 3), dtype=np.int64), q,
            wp[:nw, 0], wi[:nw])

# --- the final refit of an accepted identification (starid.refine, a fixed pinhole) ----


@_jit
def _to_vectors(xy, M, off):
    """``Camera.pixels_to_vectors`` of an ideal pinhole (``_ideal_pinhole``'s M, off)."""
    n = xy.shape[0]
    v = np.empty((n, 3))
    for i in range(n):
        _pixel_direction(xy[i, 0], xy[i, 1], M, off, v, i)
    return v


@_jit
def _to_vectors_of(xy, rows, M, off):
    """:func:`_to_vectors` of ``xy[rows]``, without the copy of those rows."""
    n = len(rows)
    v = np.empty((n, 3))
    for i in range(n):
        _pixel_direction(xy[rows[i], 0], xy[rows[i], 1], M, off, v, i)
    return v


@_jit_inline
def _pixel_direction(x, y, M, off, v, i):
    """The unit direction of pixel (x, y) into ``v[i]`` (the one formula of both)."""
    s = 0.0
    for j in range(3):
        v[i, j] = x * M[0, j] + y * M[1, j] + off[j]
        s += v[i, j] * v[i, j]
    s = math.sqrt(s)
    for j in range(3):
        v[i, j] /= s


@_jit
def _matrix_of(q):
    """``rotations.to_matrix`` of one quaternion (normalised first)."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    w, x, y, z = q[0] / n, q[1] / n, q[2] / n, q[3] / n
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    R[1, 0], R[1, 1], R[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    R[2, 0], R[2, 1], R[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return R


@_jit
def _quaternion_of(R):
    """``rotations.from_matrix(R, orthonormalize=False)`` (Shepperd, canonical sign)."""
    m00, m01, m02 = R[0, 0], R[0, 1], R[0, 2]
    m10, m11, m12 = R[1, 0], R[1, 1], R[1, 2]
    m20, m21, m22 = R[2, 0], R[2, 1], R[2, 2]
    tr = m00 + m11 + m22
    k, best = 0, tr
    if m00 > best:
        k, best = 1, m00
    if m11 > best:
        k, best = 2, m11
    if m22 > best:
        k = 3
    q = np.empty(4)
    if k == 0:
        t = 2.0 * math.sqrt(max(1.0 + tr, 0.0))
        q[0], q[1], q[2], q[3] = 0.25 * t, (m21 - m12) / t, (m02 - m20) / t, (m10 - m01) / t
    elif k == 1:
        t = 2.0 * math.sqrt(max(1.0 + m00 - m11 - m22, 0.0))
        q[0], q[1], q[2], q[3] = (m21 - m12) / t, 0.25 * t, (m01 + m10) / t, (m02 + m20) / t
    elif k == 2:
        t = 2.0 * math.sqrt(max(1.0 - m00 + m11 - m22, 0.0))
        q[0], q[1], q[2], q[3] = (m02 - m20) / t, (m01 + m10) / t, 0.25 * t, (m12 + m21) / t
    else:
        t = 2.0 * math.sqrt(max(1.0 - m00 - m11 + m22, 0.0))
        q[0], q[1], q[2], q[3] = (m10 - m01) / t, (m02 + m20) / t, (m12 + m21) / t, 0.25 * t
    n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) ** 0.5
    lead = 1.0
    for i in range(4):
        if q[i] != 0.0:
            lead = q[i]
            break
    s = (1.0 if lead > 0 else -1.0) / n
    for i in range(4):
        q[i] *= s
    return q


@_jit
def _wahba(b, r, sigma):
    """``attitude.wahba_unit`` with one sigma: (ok, q, covariance, residuals, loss); ok
    False where it raises (collinear directions)."""
    R, proper = _rotation(b, r)
    return _wahba_at(b, r, sigma, R, proper)


@_jit
def _wahba_at(b, r, sigma, R, proper):
    """:func:`_wahba` with ``_rotation(b, r)`` already computed (R, proper)."""
    n = b.shape[0]
    res = np.zeros(n)
    if not proper:
        return False, np.zeros(4), np.zeros((3, 3)), res, 0.0
    good, cov, wres = _covariance(b, sigma)
    if not good:
        return False, np.zeros(4), cov, res, 0.0
    loss = 0.0
    for s in range(n):
        d2 = 0.0
        for i in range(3):
            p = r[s, 0] * R[i, 0] + r[s, 1] * R[i, 1] + r[s, 2] * R[i, 2] - b[s, i]
            d2 += p * p
        res[s] = 2.0 * math.asin(min(0.5 * math.sqrt(d2), 1.0))
        loss += res[s] * res[s]
    return True, _quaternion_of(R), cov, res, wres * loss


@_jit
def _covariance(b, sigma):
    """The attitude covariance of :func:`_wahba` for directions ``b`` at centroid
    ``sigma`` (rad) — it depends on neither the catalogue directions nor the rotation —
    by the tracking path's one formula (:func:`starid.tracking_kernels._inverse_information`):
    (ok, covariance, 1/σ²); ok False (and zeros) where the information matrix is
    singular."""
    wres = 1.0 / sigma ** 2
    good, cov = _inverse_information(b, wres)
    if not good:
        return False, np.zeros((3, 3)), wres
    return True, cov, wres


@_jit
def _to_pixels(v, R, A, c, out, row):
    """Pixel position of ICRS direction ``v`` at attitude R through an ideal pinhole
    (``Camera.vectors_to_pixels``: NaN behind the camera) into ``out[row]``."""
    x = R[0, 0] * v[0] + R[0, 1] * v[1] + R[0, 2] * v[2]
    y = R[1, 0] * v[0] + R[1, 1] * v[1] + R[1, 2] * v[2]
    z = R[2, 0] * v[0] + R[2, 1] * v[1] + R[2, 2] * v[2]
    if not z > 0:
        out[row, 0] = out[row, 1] = np.nan
        return
    u, w = x / z, y / z
    out[row, 0] = u * A[0, 0] + w * A[1, 0] + c[0]
    out[row, 1] = u * A[0, 1] + w * A[1, 1] + c[1]


@_jit
def _noise(res, radius_px, n_params):
    """``refine.noise_from_residuals`` of (N, 2) residuals."""
    dof = 2 * res.shape[0] - n_params
    if dof <= 0:
        return np.nan
    tot = 0.0
    for i in range(res.shape[0]):
        tot += res[i, 0] * res[i, 0] + res[i, 1] * res[i, 1]
    s2_raw = tot / dof
    s2 = s2_raw
    for _ in range(30):
        u = radius_px * radius_px / (2.0 * s2) if s2 > 0 else np.inf
        keep = 1.0 if u > 50 else 1.0 - u * math.exp(-u) / -math.expm1(-u)
        new = s2_raw / max(keep, 0.05)
        if abs(new - s2) <= 1e-9 * s2:
            break
        s2 = new
    return math.sqrt(s2)


@_jit
def _median_of_squares(d):
    """``np.median(d * d)`` (an insertion sort: a few dozen values, and numba's median
    would cost seconds of compile time)."""
    n = len(d)
    a = np.empty(n)
    for i in range(n):
        x = d[i] * d[i]
        j = i
        while j > 0 and a[j - 1] > x:
            a[j] = a[j - 1]
            j -= 1
        a[j] = x
    return a[n // 2] if n % 2 else (a[n // 2 - 1] + a[n // 2]) / 2


@_jit
def _no_fit(status):
    """A refit's result without a fit (:func:`refine_pinhole`'s tuple: ``status``, no
    pairs, zero attitude and covariance), made where it is returned: made up front, its
    four arrays were allocated on every call that then fitted.

    >>> _no_fit(-1)[0], len(_no_fit(0)[1])
    (-1, 0)
    """
    empty_i = np.zeros(0, dtype=np.int64)
    return status, empty_i, empty_i, np.zeros(4), np.zeros((3, 3)), np.zeros(0), 0.0, 0


@_jit
def refine_pinhole(xy, ok_xy, det, cat, v, M, off, A, c, width, height, cone_idx, cone_vec,
                   cone_axis, cone_half, view_half, pix, r_min, sigma0, reject_sigma,
                   radius_sigma, radius_max_factor, prior_dof, q_fit, res_fit):
    """:meth:`starid.refine.Refinement._refine` for a camera that is not fitted and is an
    ideal pinhole (``M``, ``off``, ``A``, ``c``: ``Camera._ideal_pinhole``): from the
    verified pairs (detections ``det`` → catalogue rows ``cat``) the attitude refitted, the
    noise estimated from the residuals, every detection associated again within the radius
    that follows it, pairs beyond ``reject_sigma`` robust σ rejected, until the pairs
    settle; then the final fit with the estimated noise.

    The stars in view come from the cone (``cone_idx``, ``cone_vec`` around ``cone_axis``,
    half-angle ``cone_half``) the solver cached; ``view_half`` is the half-angle a frame
    needs. Returns (status, det, cat, q, covariance, residuals, sigma_px, rejected):
    status 1 refined, 0 keep the verified fit (where the Python code returns it unchanged),
    −1 the cone does not cover an attitude (the caller runs the Python code).

    ``q_fit``, ``res_fit``: the first round's fit of ``det`` → ``cat`` at ``sigma0`` (its
    attitude and residuals) when the caller has it — :func:`verify_candidate`'s is that
    fit, the same operations on the same values — or empty (fitted here). The final fit
    of pairs that settled is the last round's rotation and residuals, with the
    covariance at the estimated noise (:func:`_final_fit`)."""
    n_xy = xy.shape[0]
    det0 = det
    trunc_px = r_min
    sigma_px = sigma0
    n_par = 3
    rejected = 0
    q = np.zeros(4)
    best = np.empty(n_xy)
    near = np.empty(n_xy, dtype=np.int64)
    spare_cos = math.cos(cone_half - view_half) if cone_half >= view_half else 2.0
    for it in range(8):
        k = len(det)
        if k < 3:
            return _no_fit(0)
        r = np.empty((k, 3))
        for s in range(k):
            for j in range(3):
                r[s, j] = v[cat[s], j]
        if it == 0 and len(q_fit) == 4:
            q, res_q = q_fit, res_fit
        else:
            good, q, _, res_q, _ = _wahba(_to_vectors_of(xy, det, M, off), r, sigma0 * pix)
            if not good:
                return _no_fit(-1)
        R = _matrix_of(q)
        res = np.empty((k, 2))
        for s in range(k):
            _to_pixels(r[s], R, A, c, res, s)
            res[s, 0] -= xy[det[s], 0]
            res[s, 1] -= xy[det[s], 1]
        sigma_px = _noise(res, trunc_px, n_par)
        if not math.isfinite(sigma_px):
            sigma_px = sigma0
        radius_px = (radius_max_factor * r_min if it == 0 else
                     min(max(r_min, radius_sigma * sigma_px), radius_max_factor * r_min))
        # the stars in the frame (Solver._predict): from the cached cone while it covers
        if R[2, 0] * cone_axis[0] + R[2, 1] * cone_axis[1] + R[2, 2] * cone_axis[2] \
                < spare_cos:
            return _no_fit(-1)
        m = len(cone_idx)
        pxy = np.empty((m, 2))
        pidx = np.empty(m, dtype=np.int64)
        n_in = 0
        for e in range(m):
            _to_pixels(cone_vec[e], R, A, c, pxy, n_in)
            u, w = pxy[n_in, 0], pxy[n_in, 1]
            if u >= -0.5 and u <= width - 0.5 and w >= -0.5 and w <= height - 0.5:
                pidx[n_in] = cone_idx[e]
                n_in += 1
        # every detection's nearest star within the radius, one-to-one (refine._associate_px)
        if n_in == 0:
            return _no_fit(0)
        r2 = radius_px * radius_px
        for d in range(n_xy):
            near[d], best[d] = -1, np.inf
            if not ok_xy[d]:
                continue
            bj, bd = 0, np.inf
            for e in range(n_in):
                dx, dy = xy[d, 0] - pxy[e, 0], xy[d, 1] - pxy[e, 1]
                d2 = dx * dx + dy * dy
                if d2 < bd:
                    bd, bj = d2, e
            if bd <= r2:
                near[d], best[d] = bj, bd
        new_det = np.empty(n_xy, dtype=np.int64)
        new_cat = np.empty(n_xy, dtype=np.int64)
        dist = np.empty(n_xy)
        nn = 0
        for d in range(n_xy):
            if near[d] < 0:
                continue
            own = True
            for e in range(n_xy):
                if e != d and near[e] == near[d] and (
                        best[e] < best[d] or (best[e] == best[d] and e < d)):
                    own = False
                    break
            if own:
                # the pair's distance from the star's projection above (the same
                # function of the same vector, so the same pixels)
                e = near[d]
                new_det[nn], new_cat[nn] = d, pidx[e]
                dist[nn] = math.hypot(xy[d, 0] - pxy[e, 0], xy[d, 1] - pxy[e, 1])
                nn += 1
        if nn < 3:
            return _no_fit(0)
        dist = dist[:nn]
        robust = math.sqrt(_median_of_squares(dist) / (2.0 * math.log(2.0)))
        reject_px = max(reject_sigma * robust, 0.5 * r_min)
        nk = 0
        for s in range(nn):
            if dist[s] <= reject_px:
                new_det[nk], new_cat[nk] = new_det[s], new_cat[s]
                nk += 1
        rejected = nn - nk
        same = nk == k
        if same:
            for s in range(k):
                if new_det[s] != det[s] or new_cat[s] != cat[s]:
                    same = False
                    break
        trunc_px = min(radius_px, reject_px)
        if same:
            return _final_fit(xy, det, cat, v, M, off, pix, sigma_px, sigma0, prior_dof,
                              n_par, det0, rejected, q, res_q)
        det, cat = new_det[:nk].copy(), new_cat[:nk].copy()
    return _final_fit(xy, det, cat, v, M, off, pix, sigma_px, sigma0, prior_dof, n_par,
                      det0, rejected, np.zeros(0), np.zeros(0))


@_jit
def _final_fit(xy, det, cat, v, M, off, pix, sigma_px, sigma0, prior_dof, n_par, det0,
               rejected, q_at, res_at):
    """The end of :func:`refine_pinhole`: the verified fit kept when the pairs walked away
    from the verified stars (fewer than half of ``det0`` left), else the final fit —
    ``q_at``, ``res_at`` the attitude and residuals of these pairs' rotation when known
    (their fit at another σ: the rotation and residuals do not depend on σ), else empty."""
    k = len(det)
    kept = 0
    for s in range(k):
        for e in range(len(det0)):
            if det0[e] == det[s]:
                kept += 1
                break
    if kept < 0.5 * len(det0) or k < 3:
        return _no_fit(0)
    b = _to_vectors_of(xy, det, M, off)
    for s in range(k):
        for j in range(3):
            if not math.isfinite(b[s, j]):
                return _no_fit(0)
    dof = max(2 * k - n_par, 0)
    s2 = (dof * sigma_px ** 2 + prior_dof * sigma0 ** 2) / (dof + prior_dof)
    nu = dof + prior_dof
    inflate = nu / (nu - 2.0) if nu > 4.0 else 2.0
    if len(q_at) == 4:
        good, cov, _ = _covariance(b, math.sqrt(s2 * inflate) * pix)
        q, res = q_at, res_at
    else:
        r = np.empty((k, 3))
        for s in range(k):
            for j in range(3):
                r[s, j] = v[cat[s], j]
        good, q, cov, res, _ = _wahba(b, r, math.sqrt(s2 * inflate) * pix)
    if not good:
        return _no_fit(0)
    return 1, det, cat, q, cov, res, math.sqrt(s2), rejected


def prepare() -> float:
    """Compile every kernel a solve uses now — lost-in-space, tracking
    (:mod:`starid.tracking_kernels`) and the tracking windows' centroiding
    (:mod:`starid.detect_roi_kernels`) — into numba's on-disk cache, and return the seconds
    it took: run once after an install (``python -m
    adfusion.starid.kernels``), and the first solve of every later process loads the
    compiled code (~1 s) instead of compiling it (10–40 s). The cache is keyed by the
    source's content (SHA-256), the numba version and the CPU, so it stays valid until
    one of them changes (docs/decisions.md, "First use")."""
    import time

    from adfusion.starid.camera import Camera
    from adfusion.starid.catalog import Catalog
    from adfusion.starid.solver import Solver

    t0 = time.perf_counter()
    solver = Solver(Catalog.hipparcos(mag_limit=5.0), Camera.pinhole(1024, 768, 15.0),
                    cache=False)
    solver.warm_up()
    solver.warm_up_tracking()
    return time.perf_counter() - t0


if __name__ == "__main__":
    # the kernels of the imported module (not this __main__ copy) are the ones cached
    from adfusion.starid import kernels as _kernels

    print(f"adfusion.starid.kernels: compiled code ready in {_kernels.prepare():.1f} s")


# --- the full verification of a candidate (starid.verify.Verification._verify) ---------


@_jit_inline
def _pair_directions(b_all, v, det, cat):
    """The directions of pairs ``det`` → ``cat``: the detections' (camera) and the
    catalogue stars' (ICRS), (k, 3) each, in one allocation."""
    k = len(det)
    br = np.empty((2, k, 3))
    for s in range(k):
        for j in range(3):
            br[0, s, j], br[1, s, j] = b_all[det[s], j], v[cat[s], j]
    return br[0], br[1]


@_jit
def _not_verified():
    """:func:`verify_candidate`'s result for a candidate that fails, made where it is
    returned (made up front, its arrays were allocated for every candidate)."""
    empty_i = np.zeros(0, dtype=np.int64)
    return False, empty_i, empty_i, np.zeros(4), np.zeros((3, 3)), np.zeros(0), 1.0


@_jit
def verify_candidate(ix, b_all, R, e_trials, det, cat, sel, assign, n_xy, radius, sigma):
    """:meth:`starid.verify.Verification._verify` for a known camera: the attitude refitted
    on the quick check's pairs (``det`` → ``cat``, at rotation ``R``), every detection
    associated again when that moved it by more than a quarter of the match ``radius``
    (the pattern must keep its stars), the final Wahba fit with centroid ``sigma`` (rad),
    and p_false = min(1, ``e_trials`` × P(Binomial(other detections, p_hit) ≥ other
    matches)). Returns (ok, det, cat, q, covariance × variance factor, residuals,
    p_false); ok False where the Python code returns None."""
    v, nbr_ptr, max_sep = ix[0], ix[4], ix[8]
    nbr_idx, nbr_bin, sky, m_sky, sky_rad = ix[5], ix[7], ix[14], ix[15], ix[16]
    n = len(sel)
    k = len(det)
    b, r = _pair_directions(b_all, v, det, cat)
    R2, proper = _rotation(b, r)
    if not proper:
        return _not_verified()
    tr = 0.0
    for i in range(3):
        for j in range(3):
            tr += R[i, j] * R2[i, j]
    moved = math.sqrt(max(0.0, 2.0 * (3.0 - tr) / 2.0))
    again = moved > 0.25 * radius  # associated again: other pairs, another rotation
    if again:
        n_det = b_all.shape[0]
        bound = 2 * math.sin(radius / 2)
        bound2 = bound * bound
        tgt = np.empty(n_det, dtype=np.int64)
        dist = np.empty(n_det)
        x = np.empty(3)
        for d in range(n_det):
            for j in range(3):
                x[j] = b_all[d, 0] * R2[0, j] + b_all[d, 1] * R2[1, j] + b_all[d, 2] * R2[2, j]
            tgt[d], d2 = _nearest_in(v, nbr_idx, nbr_bin, max_sep, sky, m_sky, sky_rad, x,
                                     assign[0], radius, bound2)
            dist[d] = math.sqrt(d2)
        det = np.empty(n_det, dtype=np.int64)
        cat = np.empty(n_det, dtype=np.int64)
        k = 0
        for d in range(n_det):
            if tgt[d] < 0:
                continue
            own = True
            for e in range(n_det):
                if e != d and tgt[e] == tgt[d] and (
                        dist[e] < dist[d] or (dist[e] == dist[d] and e < d)):
                    own = False
                    break
            if own:
                det[k], cat[k] = d, tgt[d]
                k += 1
        det, cat = det[:k].copy(), cat[:k].copy()
        for s in range(n):  # keeps_pattern
            found = False
            for e in range(k):
                if det[e] == sel[s]:
                    found = cat[e] == assign[s]
                    break
            if not found:
                return _not_verified()
        b, r = _pair_directions(b_all, v, det, cat)
    if k < 2:
        return _not_verified()
    if again:
        good, q, cov, res, loss = _wahba(b, r, sigma)
    else:  # the same pairs: R2 is their rotation
        good, q, cov, res, loss = _wahba_at(b, r, sigma, R2, proper)
    if not good:
        return _not_verified()
    dof = 2 * k - 3
    vf = max(1.0, loss / dof) if dof > 0 else 1.0
    for i in range(3):
        for j in range(3):
            cov[i, j] *= vf
    a0 = assign[0]
    cnt = nbr_ptr[a0 + 1] - nbr_ptr[a0]
    area = 2 * np.pi * (1 - math.cos(max_sep))
    rho = max(cnt / area, len(v) / (4 * np.pi)) * DENSITY_SAFETY
    p_hit = min(1.0, rho * np.pi * radius ** 2)
    p_false = min(1.0, e_trials * binomial_tail(k - n, n_xy - n, p_hit))
    return True, det, cat, q, cov, res, p_false
