"""Compiled (numba) walk of a frame's pattern list: pattern windows (closest pair first) and
:func:`search`, which matches and quick-checks pattern after pattern in one call.
"""

from __future__ import annotations

import math

import numpy as np
from adfusion.starid.identify.check_kernels import quick_checks
from adfusion.starid.identify.match_kernels import (
    _ROWS,
    DONE,
    NOTE_PATTERNS,
    NOTE_WORK,
    STRONG,
    TRIANGLES_KEPT_MAX,
    _extended,
    _grown,
    _triangles,
    chirality,
)
from adfusion.starid.jit_cache import njit_cached
from numba import types
from numba.typed import Dict

__all__ = ['search', 'triangle_store']

# cached on disk, keyed by this file and the modules it compiles in (starid.jit_cache)
_jit = njit_cached(nogil=True)
# small helpers called per pair or per detection, inlined: a call that passes ``ix`` (18
# members, each array reference-counted) cost ~80 ns, more than the helper's own work
_jit_inline = njit_cached(nogil=True, inline="always")


@_jit
def _closest_pair_first(ang, pat):
    """``starid.identify.nstar.closest_pair_first`` of the detections ``pat`` (ties: row-major)."""
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
    """The pair windows of :class:`starid.identify.lost_in_space.PairWindows`: pair angles of the
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
    ``PatternSearch.solve_at`` does, from the trial at
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
