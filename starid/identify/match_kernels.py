"""Compiled (numba) pattern matching of the lost-in-space search: the index as arrays, pair
windows, a pattern's catalogue assignments by scan or by the triangle look-up.

Part of :mod:`adfusion.starid.identify.kernels` (why compiled, what it equals).
"""

from __future__ import annotations

import math

import numpy as np
from adfusion.starid.catalog.pair_index import REUSE_DRIFT_RAD
from adfusion.starid.catalog.triangle_index import QUANTA, _cell, _sorted3
from adfusion.starid.jit_cache import njit_cached
from llvmlite import ir
from numba import types
from numba.core.extending import intrinsic

__all__ = ['SEARCH_START', 'index_arrays', 'match', 'scratch', 'with_triangles']

# cached on disk, keyed by this file and the modules it compiles in (starid.jit_cache)
# search() status (state[4]) and budget-note kinds (state[5])
DONE, STRONG = 0, 1
NOTE_NONE, NOTE_WORK, NOTE_PATTERNS = 0, 1, 2

_jit = njit_cached(nogil=True)
# small helpers called per pair or per detection, inlined: a call that passes ``ix`` (18
# members, each array reference-counted) cost ~80 ns, more than the helper's own work
_jit_inline = njit_cached(nogil=True, inline="always")


_ROWS = types.int64[:, :]  # the type of search()'s kept first-three-star assignments


#: rows search() keeps per frame (24 bytes each): a frame of noise with windows a degree
#: wide (tolerance_deg 0.3, V < 6.5, 25°) held ~2.5 million (60 MB) unbounded; a 15°
#: frame at the default tolerance keeps ~1 500
TRIANGLES_KEPT_MAX = 250_000


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
    """The arrays of a :class:`starid.catalog.pair_index.PatternIndex` the kernels take, as one
    tuple,
    with the pair list's coarse table (:func:`pair_bins`), then the catalogue triangles
    (:func:`starid.catalog.triangle_index.triangles_for`: tri, offs, cell_rad, n_cells; none —
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
    (:func:`starid.catalog.triangle_index.triangles_for`) in place of its members 10–13, the rest
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
    # det[a, b, c], written as starid.identify.nstar._chirality_ok writes it
    det = (v[a, 0] * (v[b, 1] * v[c, 2] - v[b, 2] * v[c, 1])
           - v[a, 1] * (v[b, 0] * v[c, 2] - v[b, 2] * v[c, 0])
           + v[a, 2] * (v[b, 0] * v[c, 1] - v[b, 1] * v[c, 0]))
    return (det > 0 and chirality == 1) or (det < 0 and chirality == -1)


def scratch(ix) -> np.ndarray:
    """The work array :func:`match` takes (all −1; it leaves it so)."""
    return np.full(2 * len(ix[0]), -1, dtype=np.int64)


@_jit
def match(ix, cmin, cmax, chirality, max_partials, work):
    """:func:`starid.identify.nstar.match_indexed` of a pattern's windows (n, n) and mirror sign:
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
    """The quanta (:data:`starid.catalog.triangle_index.QUANTA` per cell) a sorted side in cell
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


@_jit
def _cross_norm(ux, uy, uz, vx, vy, vz):
    x, y, z = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    return math.sqrt(x * x + y * y + z * z)


@_jit
def chirality(b, min_altitude):
    """``starid.identify.nstar.chirality_of`` (same formula): sign of det[b0, b1, b2], 0 when
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
