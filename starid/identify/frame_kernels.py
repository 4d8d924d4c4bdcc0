"""A lost-in-space frame in one compiled call: pair windows, the pattern walk with its
quick checks (:func:`starid.identify.kernels.search`), the full verification of every candidate
that passes (:func:`starid.identify.kernels.verify_candidate`), the choice among them and the final
refit (:func:`starid.identify.kernels.refine_pinhole`) on the catalogue cone the kernel gathers
itself.

Why one call: with the search compiled, a clean frame's search took ~0.04 ms and the
Python around it ~0.13 ms — some 25 calls (pixel directions, the pair-window table, the
verification's and refit's wrappers, the catalogue cone's KD-tree query, two
``dataclasses.replace``), each a few µs of overhead. Here Python parses the detections
once, makes one call, and builds the :class:`starid.Solution` once
(docs/concepts/identification.md, "One compiled call").

The kernel is the solver's own code path for a known, undistorted pinhole camera (one
focal guess), not a copy of it: it calls the same compiled search, verification and
refit, and each pattern's windows come from the formula of
:class:`starid.identify.lost_in_space.PairWindows` (:func:`starid.identify.kernels.pair_windows`).
What it
adds — the distinct-attitude test, the cone — computes what
:func:`starid.identify.verify.distinct_candidates` and ``Solver._cone`` compute;
``benchmarks/compiled_equivalence.py --reference pieces`` compares whole solutions with the
pieces called one by one (every discrete field exactly).

Example:
    >>> import numpy as np
    >>> from adfusion.starid.identify.frame_kernels import input_problem
    >>> xy = np.array([[10.0, 10.0], [200.0, 50.0], [10.0, 10.0 + 1e-9]])
    >>> input_problem(xy, 3, 1024.0, 768.0, 512.0)  # (duplicate, rows 0 and 2)
    (3, 0, 2)
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba
import numpy as np
from adfusion.starid.identify.check_kernels import quick_checks
from adfusion.starid.identify.fit_kernels import (
    _matrix_of,
    _no_fit,
    _to_vectors,
    refine_pinhole,
    verify_candidate,
)
from adfusion.starid.identify.match_kernels import SEARCH_START, STRONG, _jit, chirality
from adfusion.starid.identify.search_kernels import _window, search, triangle_store
from numba.core import types
from numba.experimental import structref
from numpy.typing import NDArray

__all__ = ["ACCEPTED", "LEAN_WALK", "NONE", "NO_ROOM", "PACKED_HEADER", "REFUSED", "SEVERAL",
           "LeanState", "input_problem", "lean_state", "solve_frame", "solve_frame_packed",
           "solve_lean", "unpack", "verify_weak", "walk_parts"]

# solve_frame() outcome; solve_lean()'s own: the input check refused the detections, or
# the work or result arrays it was given are too small
NONE, ACCEPTED, SEVERAL = 0, 1, 2
REFUSED, NO_ROOM = -1, -2
# the cone the refit draws its stars from is this much wider than the view (rad), where the
# anchor's neighbour row reaches so far; a refit moves the attitude by arcseconds
_CONE_SPARE_RAD = math.radians(0.25)
_CONE_SPARE_MIN_RAD = 1e-4


@_jit
def _angle_between(p, q):
    """``rotations.angle_between`` of two quaternions (the same formula)."""
    ka = 1.0 / math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3])
    kb = 1.0 / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if p[0] * q[0] + p[1] * q[1] + p[2] * q[2] + p[3] * q[3] < 0:
        kb = -kb
    dm = 0.0
    dp = 0.0
    for i in range(4):
        a, b = p[i] * ka, q[i] * kb
        dm += (a - b) ** 2
        dp += (a + b) ** 2
    return 4.0 * math.atan2(math.sqrt(dm), math.sqrt(dp))


@_jit
def _cone(ix, axis, half_rad, anchor, theta):
    """Catalogue rows (ascending) and vectors of the stars within ``half_rad`` of ``axis``
    — from the neighbour row of ``anchor`` (``theta`` from the axis) when it reaches that
    far, else from every star."""
    v, nbr_idx, nbr_bin, max_sep = ix[0], ix[5], ix[7], ix[8]
    cos_half = math.cos(half_rad)
    k = 0
    if theta + half_rad < max_sep:
        nb = nbr_bin.shape[1] - 1
        b1 = min(int((theta + half_rad) / (max_sep / nb)) + 1, nb)
        lo, hi = nbr_bin[anchor, 0], nbr_bin[anchor, b1]
        idx = np.empty(hi - lo + 1, dtype=np.int64)
        if v[anchor, 0] * axis[0] + v[anchor, 1] * axis[1] + v[anchor, 2] * axis[2] \
                >= cos_half:
            idx[0] = anchor
            k = 1
        for e in range(lo, hi):
            s = nbr_idx[e]
            if v[s, 0] * axis[0] + v[s, 1] * axis[1] + v[s, 2] * axis[2] >= cos_half:
                idx[k] = s
                k += 1
        idx = np.sort(idx[:k])
    else:
        idx = np.empty(len(v), dtype=np.int64)
        for s in range(len(v)):
            if v[s, 0] * axis[0] + v[s, 1] * axis[1] + v[s, 2] * axis[2] >= cos_half:
                idx[k] = s
                k += 1
        idx = idx[:k]
    vec = np.empty((k, 3))
    for e in range(k):
        for j in range(3):
            vec[e, j] = v[idx[e], j]
    return idx, vec


@_jit
def _candidate_arrays(n_k, n_xy):
    """Room for ``n_k`` verified candidates of ``n_xy`` detections: pair counts,
    detections, catalogue rows, q, covariance, residuals, p_false (all zero) — views of
    one integer and one float allocation."""
    ints = np.zeros(n_k * (1 + 2 * n_xy), dtype=np.int64)
    floats = np.zeros(n_k * (4 + 9 + n_xy + 1))
    a, b = n_k, n_k + n_k * n_xy
    c, d, e = 4 * n_k, 13 * n_k, 13 * n_k + n_k * n_xy
    return (ints[:a], ints[a:b].reshape((n_k, n_xy)), ints[b:].reshape((n_k, n_xy)),
            floats[:c].reshape((n_k, 4)), floats[c:d].reshape((n_k, 3, 3)),
            floats[d:e].reshape((n_k, n_xy)), floats[e:])


@_jit
def _refit(ix, q, res, anchor, xy_all, ok_all, det, cat, M, off, A, c, width, height,
           view_half, pix, r_min, sigma0, consts):
    """:func:`starid.identify.kernels.refine_pinhole` of an accepted candidate (its attitude ``q``
    and residuals ``res``, its fit), on a cone around its boresight: from the anchor's
    neighbour row, or every star when the refit leaves that cone."""
    v = ix[0]
    R = _matrix_of(q)
    axis = R[2]  # the boresight (R's third row, a view)
    cth = min(max(v[anchor, 0] * axis[0] + v[anchor, 1] * axis[1] + v[anchor, 2] * axis[2],
                  -1.0), 1.0)
    theta = math.acos(cth)
    spare = min(_CONE_SPARE_RAD, ix[8] - theta - view_half - 1e-9)
    for attempt in range(2):
        if attempt == 1 or spare < _CONE_SPARE_MIN_RAD:
            spare = _CONE_SPARE_RAD
            theta = np.inf  # every star
        half = min(view_half + spare, np.pi)
        idx, vec = _cone(ix, axis, half, anchor, theta)
        out = refine_pinhole(xy_all, ok_all, det, cat, v, M, off, A, c, width, height, idx,
                             vec, axis, half, view_half, pix, r_min, sigma0, consts[0],
                             consts[1], consts[2], consts[3], q, res)
        if out[0] >= 0 or theta == np.inf:
            return out
    return out


@_jit
def solve_frame(ix, xy, xy_all, M, off, A, c, width, height, view_half, pix,
                tolerance_rad, state, pats, plen, budget, no_match, n_no_match, max_partials,
                work, r_min_px, sigma0_px, p_false_max, distinct_rad, refine, consts):
    """``PatternSearch.solve_at`` and ``Refiner.refine`` of one frame for a known ideal pinhole
    (``M``, ``off``, ``A``, ``c``: ``Camera._ideal_pinhole``; ``view_half`` the half
    diagonal + 1e-3 rad, ``pix`` the pixel scale): the pattern list ``pats`` walked from
    ``state`` (:func:`starid.identify.kernels.search`'s; ``work`` its scratch), every candidate of a
    trial that passes the quick check verified, and the walk continued while none of them
    is accepted.

    Returns (outcome, sel, counter, cands, order, n_acc, refit, weak):

    * outcome NONE (the list ended or a budget: ``state`` says which), ACCEPTED (one
      distinct attitude at p_false ≤ ``p_false_max``; refitted when ``refine``) or
      SEVERAL (the caller weighs the evidence);
    * ``counter`` the trial's assignments (Renken's matching counter);
    * cands = (n, det, cat, q, cov, res, p_false): the trial's verified candidates in
      assignment order (candidate k's pairs det[k, :n[k]] → cat[k, :n[k]]);
    * ``order[:n_acc]`` the accepted ones, distinct, by p_false;
    * refit = :func:`starid.identify.kernels.refine_pinhole`'s tuple, pairs by detection (status
      −2: not run);
    * weak = the search's weak candidates (p_false (W,), rows (W, 20))."""
    n_xy = xy.shape[0]
    b = _to_vectors(xy, M, off)
    # the refit's detections: finite, and past the search's n_xy inside the frame
    # (Camera.in_frame's test; Solver._all_xy marks them so for the Python refit)
    ok_all = np.empty(xy_all.shape[0], dtype=np.bool_)
    for i in range(xy_all.shape[0]):
        x, y = xy_all[i, 0], xy_all[i, 1]
        ok_all[i] = math.isfinite(x) and math.isfinite(y) and (
            i < n_xy or (x >= -0.5 and y >= -0.5 and x <= width - 0.5
                         and y <= height - 0.5))
    per_guess = np.array([[r_min_px * pix], [math.sqrt(2.0) * sigma0_px * pix]])
    radius, floor = per_guess[0], per_guess[1]  # (one guess)
    sigma = sigma0_px * pix
    wp_all = np.empty(0)
    wi_all = np.empty((0, 20), dtype=np.int64)
    store = triangle_store()  # kept across the walk's calls (a verification failed)
    while True:
        sel, rows, q, wp, wi = search(ix, state, pats, plen, budget, no_match, n_no_match,
                                      b.reshape(1, n_xy, 3), tolerance_rad, 0.0, radius,
                                      floor, p_false_max, max_partials, work, store)
        if len(wp):
            wp_all = np.concatenate((wp_all, wp))
            wi_all = np.concatenate((wi_all, wi))
        if state[4] != STRONG:
            empty_i = np.zeros(0, dtype=np.int64)
            cands = (empty_i, np.zeros((0, n_xy), dtype=np.int64),
                     np.zeros((0, n_xy), dtype=np.int64), np.zeros((0, 4)),
                     np.zeros((0, 3, 3)), np.zeros((0, n_xy)), np.zeros(0))
            return NONE, sel, 0, cands, empty_i, 0, _no_fit(-2), (wp_all, wi_all)
        ok, pq, rots, e_tr, det, cat, matched = q
        n_k = len(rows)
        c_n, c_det, c_cat, c_q, c_cov, c_res, c_p = _candidate_arrays(n_k, n_xy)
        c_row = np.zeros(n_k, dtype=np.int64)
        nc = 0
        for k in range(n_k):
            if not ok[k] or not pq[k] <= p_false_max:
                continue
            good, d, h, qk, cov, res, p = verify_candidate(
                ix, b, rots[k], e_tr[k], det[k, :matched[k]], cat[k, :matched[k]], sel,
                rows[k], n_xy, radius[0], sigma)
            if not good:
                continue
            m = len(d)
            c_n[nc] = m
            c_det[nc, :m] = d
            c_cat[nc, :m] = h
            c_q[nc] = qk
            c_cov[nc] = cov
            c_res[nc, :m] = res
            c_p[nc] = p
            c_row[nc] = k
            nc += 1
        # distinct_candidates of those at p_false ≤ p_false_max: by p_false (stable), each
        # kept when farther than distinct_rad from every one kept before
        order = np.empty(nc, dtype=np.int64)
        n_acc = 0
        # (one candidate, most trials: no sort to run)
        by_p = np.argsort(c_p[:nc], kind="mergesort") if nc > 1 else np.zeros(nc, np.int64)
        for t in range(nc):
            i = by_p[t]
            if not c_p[i] <= p_false_max:
                continue
            far = True
            for u in range(n_acc):
                if not _angle_between(c_q[i], c_q[order[u]]) > distinct_rad:
                    far = False
                    break
            if far:
                order[n_acc] = i
                n_acc += 1
        cands = (c_n[:nc], c_det[:nc], c_cat[:nc], c_q[:nc], c_cov[:nc], c_res[:nc],
                 c_p[:nc])
        if n_acc == 1:
            i = order[0]
            m = c_n[i]
            if refine and m >= 3:
                refit = _refit(ix, c_q[i], c_res[i, :m], rows[c_row[i], 0], xy_all, ok_all,
                               c_det[i, :m], c_cat[i, :m], M, off, A, c, width, height,
                               view_half, pix, r_min_px, sigma0_px, consts)
                if refit[0] == 1:
                    refit = _by_detection(refit)
            else:
                refit = _no_fit(-2)
            return ACCEPTED, sel, n_k, cands, order[:1], 1, refit, (wp_all, wi_all)
        if n_acc > 1:
            return (SEVERAL, sel, n_k, cands, order[:n_acc], n_acc, _no_fit(-2),
                    (wp_all, wi_all))
        # nothing accepted at this trial: on to the next one
        state[0], state[1] = state[0] + 1, 0


#: the header of :func:`solve_frame_packed`'s integers: outcome, counter, n_acc, candidates,
#: pattern stars, refit status, pairs rejected, refit pairs, weak rows, the walk's pattern
#: and trials (its state's 0 and 2)
PACKED_HEADER = 11
_NO_FLOATS, _NO_ROWS = np.zeros(0), np.zeros((0, 20), dtype=np.int64)
_NO_FLOATS.flags.writeable = _NO_ROWS.flags.writeable = False


@_jit
def solve_frame_packed(ids, ix, xy, xy_all, M, off, A, c, width, height, view_half, pix,
                       tolerance_rad, state, pats, plen, budget, no_match, n_no_match,
                       max_partials, work, r_min_px, sigma0_px, p_false_max, distinct_rad,
                       refine, consts):
    """:func:`solve_frame` with its result in two flat arrays (integers, floats) and the
    catalogue rows as the catalogue's ``ids``: returning its ~20 arrays cost ~1 µs each
    to hand to Python, more than the Python that reads them (:func:`unpack` reads these).
    The refit comes first: an accepted frame's solution is read from the front of both
    arrays (``PatternSearch.solve_lean``), the candidates only when asked for.

    Integers: the header (:data:`PACKED_HEADER`: outcome, counter, n_acc, candidates C,
    pattern stars, refit status, pairs rejected, refit pairs m, weak rows W, pattern,
    trials), sel, order, the refit's detections and ids, each candidate's pair count,
    then per candidate its detections and ids, the weak rows (W × 20). Floats: the
    refit's q (4), covariance (9) and residuals (m); the first accepted candidate's
    p_false (0 for none) and the refit's σ (px); each candidate's p_false; per candidate
    q (4), covariance (9), residuals; the weak p_false (W)."""
    outcome, sel, counter, cands, order, n_acc, refit, weak = solve_frame(
        ix, xy, xy_all, M, off, A, c, width, height, view_half, pix, tolerance_rad, state,
        pats, plen, budget, no_match, n_no_match, max_partials, work, r_min_px, sigma0_px,
        p_false_max, distinct_rad, refine, consts)
    c_n, c_det, c_cat, c_q, c_cov, c_res, c_p = cands
    status, d, k, q, cov, res, sigma_px, rejected = refit
    wp, wi = weak
    n_c, m, n_w = len(c_n), len(d), len(wp)
    pairs = 0
    for i in range(n_c):
        pairs += c_n[i]
    ints = np.empty(PACKED_HEADER + len(sel) + n_acc + 2 * m + n_c + 2 * pairs + 20 * n_w,
                    dtype=np.int64)
    floats = np.empty(13 + m + 2 + n_c + 13 * n_c + pairs + n_w)
    ints[0], ints[1], ints[2], ints[3], ints[4] = outcome, counter, n_acc, n_c, len(sel)
    ints[5], ints[6], ints[7], ints[8] = status, rejected, m, n_w
    ints[9], ints[10] = state[0], state[2]
    o = PACKED_HEADER
    for i in range(len(sel)):
        ints[o + i] = sel[i]
    o += len(sel)
    for i in range(n_acc):
        ints[o + i] = order[i]
    o += n_acc
    for e in range(m):
        ints[o + e], ints[o + m + e] = d[e], ids[k[e]]
        floats[13 + e] = res[e]
    o += 2 * m
    for j in range(4):
        floats[j] = q[j]
    for j in range(9):
        floats[4 + j] = cov[j // 3, j % 3]
    f = 13 + m
    floats[f] = c_p[order[0]] if n_acc > 0 else 0.0
    floats[f + 1] = sigma_px
    f += 2
    for i in range(n_c):
        ints[o + i] = c_n[i]
        floats[f + i] = c_p[i]
    o += n_c
    f += n_c
    for i in range(n_c):
        for e in range(c_n[i]):
            ints[o + e], ints[o + c_n[i] + e] = c_det[i, e], ids[c_cat[i, e]]
            floats[f + 13 + e] = c_res[i, e]
        o += 2 * c_n[i]
        for j in range(4):
            floats[f + j] = c_q[i, j]
        for j in range(9):
            floats[f + 4 + j] = c_cov[i, j // 3, j % 3]
        f += 13 + c_n[i]
    for r in range(n_w):
        for j in range(20):
            ints[o + 20 * r + j] = wi[r, j]
        floats[f + r] = wp[r]
    return ints, floats


def unpack(ints: NDArray[np.int64], floats: NDArray[np.float64]) -> tuple:
    """:func:`solve_frame_packed`'s arrays read back: (outcome, sel, counter, n_acc, order,
    candidates, refit, weak, pattern, trials) with candidates a list of (detections, ids,
    q, covariance, residuals, p_false) — detections and ids as lists — refit (status,
    detections, ids, q, covariance, residuals, σ px, rejected; only the status and
    rejected count unless the status is 1) and weak (p_false (W,), rows (W, 20)); the
    arrays are views of ``floats`` and ``ints`` (with no weak rows: shared empty arrays,
    not to be written to). ``pattern`` and ``trials``: the walk's state 0 and 2.

    >>> import numpy as np
    >>> ints = np.array([0, 0, 0, 0, 3, -2, 0, 0, 0, 5, 9, 4, 1, 2])
    >>> unpack(ints, np.zeros(15))[:3]
    (0, [4, 1, 2], 0)
    """
    every = ints.tolist()  # one call: cheaper than slicing the array piece by piece
    outcome, counter, n_acc, n_c, n_sel, status, rejected, m, n_w, pattern, tried = \
        every[:PACKED_HEADER]
    o = PACKED_HEADER
    sel = every[o:o + n_sel]
    o += n_sel
    order = every[o:o + n_acc]
    o += n_acc
    if status == 1:
        refit = (status, every[o:o + m], every[o + m:o + 2 * m], floats[:4],
                 floats[4:13].reshape(3, 3), floats[13:13 + m], float(floats[14 + m]),
                 rejected)
    else:
        refit = (status, [], [], None, None, None, 0.0, rejected)
    o += 2 * m
    f = 15 + m
    counts = every[o:o + n_c]
    o += n_c
    p_false = floats[f:f + n_c].tolist()
    f += n_c
    cands = []
    for i, n in enumerate(counts):
        cands.append((every[o:o + n], every[o + n:o + 2 * n], floats[f:f + 4],
                      floats[f + 4:f + 13].reshape(3, 3), floats[f + 13:f + 13 + n],
                      p_false[i]))
        o += 2 * n
        f += 13 + n
    if n_w:  # the weak rows close the integers (a NONE frame's too)
        weak = (floats[f:f + n_w], ints[len(ints) - 20 * n_w:].reshape(n_w, 20))
    else:
        weak = (_NO_FLOATS, _NO_ROWS)
    return outcome, sel, counter, n_acc, order, cands, refit, weak, pattern, tried


@_jit
def verify_weak(ix, xy, M, off, tolerance_rad, rows, r_min_px, sigma0_px, pix):
    """``Solver._unsolved``'s look at the weak candidates of a frame without an answer
    (rows of :func:`solve_frame`'s weak list: pattern, guess, trial, n, sel (8),
    assignment (8)), for a known ideal pinhole: each quick-checked again at its own trial
    — the pattern's windows by :func:`starid.identify.kernels._window`, its mirror sign by
    :func:`starid.identify.kernels.chirality`, as the search computed them — and fully verified
    (:func:`starid.identify.kernels.verify_candidate`). One call instead of a dozen a candidate.

    Returns (ok (K,), n (K,), det (K, N), cat (K, N), q (K, 4), covariance (K, 3, 3),
    residuals (K, N), p_false (K,)): candidate k's pairs det[k, :n[k]] → cat[k, :n[k]]
    (catalogue rows), where ok[k]."""
    n_xy = xy.shape[0]
    b = _to_vectors(xy, M, off)
    radius = r_min_px * pix
    floor = math.sqrt(2.0) * sigma0_px * pix
    sigma = sigma0_px * pix
    k_all = rows.shape[0]
    good = np.zeros(k_all, dtype=np.bool_)
    counts, c_det, c_cat, c_q, c_cov, c_res, c_p = _candidate_arrays(k_all, n_xy)
    for k in range(k_all):
        trial, n = rows[k, 2], rows[k, 3]
        sel = np.empty(n, dtype=np.int64)
        assign = np.empty((1, n), dtype=np.int64)
        bs = np.empty((n, 3))
        for s in range(n):
            sel[s], assign[0, s] = rows[k, 4 + s], rows[k, 12 + s]
            for j in range(3):
                bs[s, j] = b[sel[s], j]
        ang, tol = np.empty((n, n)), np.empty((n, n))
        t_max = -np.inf
        for s in range(n):
            for t in range(n):
                ang[s, t], tol[s, t], _, _, _ = _window(b, sel[s], sel[t], tolerance_rad, 0.0)
                t_max = max(t_max, tol[s, t])
        mirror = chirality(bs, 2.0 * t_max) != 0
        ok, _, rots, e_tr, det, cat, matched = quick_checks(
            ix, b, sel, assign, ang, tol, mirror, trial, radius, floor)
        if not ok[0]:
            continue
        fine, d, h, q, cov, res, p = verify_candidate(
            ix, b, rots[0], e_tr[0], det[0, :matched[0]], cat[0, :matched[0]], sel,
            assign[0], n_xy, radius, sigma)
        if not fine:
            continue
        m = len(d)
        good[k], counts[k], c_p[k] = True, m, p
        c_det[k, :m] = d
        c_cat[k, :m] = h
        c_res[k, :m] = res
        c_q[k] = q
        c_cov[k] = cov
    return good, counts, c_det, c_cat, c_q, c_cov, c_res, c_p


@_jit
def _by_detection(refit):
    """A refit's pairs and residuals sorted by detection (``np.argsort``, as
    ``Refiner.refine_pinhole`` sorts them) — as they are when they come so already,
    which the refit's association and the verification's make them (a detection pairs
    once, so the order is strict and the sort would be the identity)."""
    status, d, k, q, cov, res, sigma_px, rejected = refit
    for i in range(1, len(d)):
        if d[i] <= d[i - 1]:
            o = np.argsort(d)
            return status, d[o], k[o], q, cov, res[o], sigma_px, rejected
    return refit


@_jit
def input_problem(xy, n_use, width, height, slack):
    """What ``Solver._parse`` refuses in detections ``xy`` (N, 2), the first ``n_use`` of
    which the search uses: (0, 0, 0) none; (1, count, first row) non-finite centroids;
    (2, row, 0) a used centroid more than ``slack`` px outside the frame; (3, row, row) two
    used centroids closer than 1e-6 px. The cheap test first (every position within the
    frame plus the slack), the details only when it fails."""
    n = xy.shape[0]
    lo, hi_x, hi_y = -0.5 - slack, width - 0.5 + slack, height - 0.5 + slack
    for i in range(n):
        x, y = xy[i, 0], xy[i, 1]
        if not (x >= lo and y >= lo and x <= hi_x and y <= hi_y):  # NaN fails too
            bad, first = 0, -1
            for r in range(n):
                if not (math.isfinite(xy[r, 0]) and math.isfinite(xy[r, 1])):
                    bad += 1
                    if first < 0:
                        first = r
            if bad:
                return 1, bad, first
            for r in range(min(n_use, n)):
                x, y = xy[r, 0], xy[r, 1]
                if not (x >= lo and y >= lo and x <= hi_x and y <= hi_y):
                    return 2, r, 0
            break
    m = min(n_use, n)
    if m > 1:
        xs = np.empty(m)
        for i in range(m):
            xs[i] = xy[i, 0]
        xs.sort()
        gap = np.inf
        for i in range(m - 1):
            gap = min(gap, xs[i + 1] - xs[i])
        if gap < 1e-6:  # some x coincide: a pair closer than 1e-6 px in both coordinates?
            for i in range(m):
                for j in range(m):
                    dx, dy = xy[i, 0] - xy[j, 0], xy[i, 1] - xy[j, 1]
                    if i != j and dx * dx + dy * dy < 1e-12:
                        return 3, i, j
    return 0, 0, 0


# --- one solver's constant arguments, held once (solve_lean) ---------------------------


@structref.register
class _LeanStateType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class LeanState(structref.StructRefProxy):
    """A solver's constant arguments of :func:`solve_frame_packed` — catalogue ids, index
    arrays, camera, tolerances, every detection count's pattern list — held in one
    compiled object (:func:`lean_state` makes it), so that :func:`solve_lean` takes six
    arguments instead of 27 (and the arrays): handing numba the 27, one of them a tuple of
    18 arrays, cost ~8 µs of a ~90 µs frame (docs/concepts/identification.md, "One
    compiled call")."""


_LEAN_FIELDS = ("ids", "ix", "M", "off", "A", "c", "width", "height", "view_half", "pix",
                "slack", "tolerance_rad", "max_det", "pats", "plen", "pat_start", "budget",
                "max_partials", "no_match_len", "work_len", "r_min_px", "sigma0_px",
                "p_false_max", "distinct_rad", "consts")
structref.define_proxy(LeanState, _LeanStateType, list(_LEAN_FIELDS))

#: :func:`solve_lean`'s walk array: the search's state (8), the no-match sets' count (1),
#: then the no-match sets (``no_match_len``): :func:`walk_parts`
LEAN_WALK = 9


@_jit
def walk_parts(walk, no_match_len):
    """Views of :func:`solve_lean`'s walk array as the search's (state (8,), no-match sets
    (1, ``no_match_len``), their count (1,)) — :func:`solve_frame`'s arguments.

    >>> import numpy as np
    >>> [p.shape for p in walk_parts(np.zeros(LEAN_WALK + 5, dtype=np.int64), 5)]
    [(8,), (1, 5), (1,)]
    """
    return (walk[:8], walk[LEAN_WALK:LEAN_WALK + no_match_len].reshape((1, no_match_len)),
            walk[8:9])


@_jit
def lean_state(ids, ix, M, off, A, c, width, height, view_half, pix, slack, tolerance_rad,
               max_det, pats, plen, pat_start, budget, max_partials, no_match_len,
               work_len, r_min_px, sigma0_px, p_false_max, distinct_rad, consts):
    """A :class:`LeanState` of these values (:func:`solve_frame_packed`'s arguments, plus
    the input check's ``slack``, ``max_det`` detections used at most, the patterns of
    every count n at rows ``pat_start[n]:pat_start[n + 1]`` of ``pats`` and ``plen``, and
    the lengths :func:`solve_lean`'s work arrays need). Compiled and cached here: the
    class's own constructor compiles in every process (~0.3 s)."""
    return LeanState(ids, ix, M, off, A, c, width, height, view_half, pix, slack,
                     tolerance_rad, max_det, pats, plen, pat_start, budget, max_partials,
                     no_match_len, work_len, r_min_px, sigma0_px, p_false_max,
                     distinct_rad, consts)


# the types lean_call compiles solve_lean for: C-contiguous float64 detections, int64 work
# arrays, the int64 and float64 arrays it writes its result into
_LEAN_XY, _LEAN_INTS, _LEAN_FLOATS = types.float64[:, ::1], types.int64[::1], types.float64[::1]


def lean_call(st: LeanState) -> Callable:
    """:func:`solve_lean` for ``st``'s type, (N, 2) C-contiguous float64 detections, int64
    work arrays and the int64 and float64 arrays it writes into: numba's wrapper of that
    one compiled signature (compiled, or loaded from the cache, now), to be called without
    the dispatcher. The dispatcher works out every argument's type on every call, and a
    StructRef's type is found by Python code: ~2.4 µs of a frame in cold caches, ~0.5 µs
    in warm ones (docs/benchmarks.md, "One call, four arguments"). The wrapper checks
    nothing: the caller hands it only those types (``PatternSearch.solve_lean``), which it
    reads as them.

    >>> import numpy as np
    >>> from adfusion.starid import Camera, Catalog, Solver
    >>> s = Solver(Catalog.hipparcos(mag_limit=4.0), Camera.pinhole(640, 480, 20.0))
    >>> st, _, _, call, _ = s.search._lean_state()
    >>> none = np.zeros(0, np.int64)
    >>> call(st, np.zeros((2, 2)), none, none, none, np.zeros(0))[0] == NO_ROOM
    True
    """
    return solve_lean.compile((numba.typeof(st), _LEAN_XY, _LEAN_INTS, _LEAN_INTS,
                               _LEAN_INTS, _LEAN_FLOATS))


@_jit
def solve_lean(st, xy, work, walk, out_ints, out_floats):
    """``Solver.solve(xy)`` without a prior for a solver's :class:`LeanState` ``st``: the
    input check (:func:`input_problem`) and :func:`solve_frame_packed` on the first
    ``max_det`` detections, refitted on all of them, in one call. ``work`` is the search's
    scratch (all −1, at least ``work_len`` long), ``walk`` (at least :data:`LEAN_WALK` +
    ``no_match_len`` long) receives the walk's state, no-match count and sets, for a caller
    that continues it. :func:`solve_frame_packed`'s arrays are written to the front of
    ``out_ints`` and ``out_floats``: handing two new arrays to Python cost ~1 µs warm
    (numba finds the array type by unpickling it for each), more in cold caches.

    Returns (outcome, integers written, floats written), or (:data:`REFUSED`, 0, 0) —
    fewer than 3 detections or the check refused them: the caller's general path says
    why — or (:data:`NO_ROOM`, integers, floats): an array too small (``work``, ``walk``:
    0, 0; ``out_*``: the lengths the result needs; the call leaves the walk to start
    again)."""
    n = min(xy.shape[0], st.max_det)
    if len(work) < st.work_len or len(walk) < LEAN_WALK + st.no_match_len:
        return NO_ROOM, 0, 0
    if n < 3 or input_problem(xy, n, st.width, st.height, st.slack)[0] != 0:
        return REFUSED, 0, 0
    state, no_match, n_no_match = walk_parts(walk, st.no_match_len)
    state[:] = SEARCH_START
    no_match[:] = 0
    n_no_match[0] = 0
    lo, hi = st.pat_start[n], st.pat_start[n + 1]
    ints, floats = solve_frame_packed(
        st.ids, st.ix, xy[:n], xy, st.M, st.off, st.A, st.c, st.width, st.height,
        st.view_half, st.pix, st.tolerance_rad, state, st.pats[lo:hi], st.plen[lo:hi],
        st.budget, no_match, n_no_match, st.max_partials, work, st.r_min_px, st.sigma0_px,
        st.p_false_max, st.distinct_rad, True, st.consts)
    n_i, n_f = len(ints), len(floats)
    if n_i > len(out_ints) or n_f > len(out_floats):
        return NO_ROOM, n_i, n_f
    out_ints[:n_i] = ints
    out_floats[:n_f] = floats
    return ints[0], n_i, n_f
