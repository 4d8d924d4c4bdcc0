"""Compiled (numba) steps of tracking (:mod:`starid.tracking.tracking`): the catalogue predicted
at a
prior, detections paired with it, and the tight prior's fit.

Why compiled code: a tracked frame of a running filter predicts a few dozen catalogue stars,
pairs them with a few dozen detections and takes one or two Gauss–Newton steps. In numpy
that is ~40 calls of a few µs each, almost all per-call overhead (~0.15–0.2 ms a frame);
compiled, the same arithmetic is a few µs, and the frame's cost is the Python around it.

The functions compute what the numpy path computes (the solver's ``_predict``,
:meth:`Camera.pixels_to_vectors`, the nearest-detection association,
:func:`starid.identify.verify.one_to_one`, :func:`adfusion.maths.attitude.wahba_near`): the same
stars in the
same order and the same decisions; sums may run in another order than numpy's BLAS, so
floats agree to rounding (~1e-16 relative). ``benchmarks/tracking_identical.py`` compares a
run against a recorded one, and tests/test_tracking_kernels.py the compiled path with the
numpy one. Compiled on first use and cached on disk (``cache=True``), like
:mod:`starid.identify.kernels`.

Example:
    >>> import numpy as np
    >>> from adfusion.starid.tracking.kernels import nearest_detections
    >>> pred = np.array([[10.0, 10.0], [50.0, 50.0]])
    >>> xy = np.array([[11.0, 10.0], [80.0, 80.0], [50.0, 52.0]])
    >>> j, n_within, d = nearest_detections(pred, xy, 3.0)
    >>> j.tolist(), n_within.tolist(), d.tolist()
    ([0, 2], [1, 1], [1.0, 2.0])
"""

from __future__ import annotations

import math

import numpy as np
from adfusion.starid.identify.fit_kernels import _inverse_information
from adfusion.starid.jit_cache import njit_cached

__all__ = ["FIT_COLLINEAR", "FIT_FEW", "FIT_OK", "nearest_detections", "tight_fix"]

_jit = njit_cached(nogil=True)


# tight_fix() status
FIT_OK, FIT_FEW, FIT_COLLINEAR = 0, 1, 2


@_jit
def nearest_detections(pred_xy, xy, gate_px):
    """For each predicted star: its nearest detection (the first of equals), how many
    detections lie within ``gate_px``, and the nearest one's distance (px)."""
    n_pred, n_det = pred_xy.shape[0], xy.shape[0]
    j = np.zeros(n_pred, dtype=np.int64)
    n_within = np.zeros(n_pred, dtype=np.int64)
    d = np.empty(n_pred)
    g2 = gate_px * gate_px
    for p in range(n_pred):
        best, bj, cnt = np.inf, 0, 0
        for i in range(n_det):
            dx = pred_xy[p, 0] - xy[i, 0]
            dy = pred_xy[p, 1] - xy[i, 1]
            d2 = dx * dx + dy * dy
            if d2 <= g2:
                cnt += 1
            if d2 < best:
                best, bj = d2, i
        j[p], n_within[p], d[p] = bj, cnt, math.sqrt(best)
    return j, n_within, d


@_jit
def _tight_pairs(pred_idx, j, n_within, d):
    """The tight prior's pairs: every predicted star with a detection in its gate takes its
    nearest one; a detection claimed twice goes to the closer star (ties to the lower
    index: :func:`starid.identify.verify.one_to_one`). Sorted by detection: (detections, rows)."""
    n_pred = j.shape[0]
    n_det = 0
    for p in range(n_pred):
        if n_within[p] > 0:
            n_det = max(n_det, j[p] + 1)
    # each detection's owner: the hit star nearest to it, the lower index among equals
    owner = np.empty(n_det, dtype=np.int64)
    for i in range(n_det):
        owner[i] = -1
    for p in range(n_pred):  # ascending p: a later star takes over only when strictly closer
        if n_within[p] > 0:
            o = owner[j[p]]
            if o < 0 or d[p] < d[o]:
                owner[j[p]] = p
    n = 0
    for i in range(n_det):
        if owner[i] >= 0:
            n += 1
    det = np.empty(n, dtype=np.int64)
    rows = np.empty(n, dtype=np.int64)
    n = 0
    for i in range(n_det):  # ascending detection index
        if owner[i] >= 0:
            det[n], rows[n] = i, pred_idx[owner[i]]
            n += 1
    return det, rows


@_jit
def _matrix_t(q):
    """R(q)ᵀ (:func:`adfusion.maths.attitude._matrix_t`)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    m = np.empty((3, 3))
    m[0, 0], m[0, 1], m[0, 2] = 1.0 - 2.0 * (yy + zz), 2.0 * (xy + wz), 2.0 * (xz - wy)
    m[1, 0], m[1, 1], m[1, 2] = 2.0 * (xy - wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz + wx)
    m[2, 0], m[2, 1], m[2, 2] = 2.0 * (xz + wy), 2.0 * (yz - wx), 1.0 - 2.0 * (xx + yy)
    return m


@_jit
def _exp_times(x, y, z, q):
    """exp((x, y, z)) ⊗ q, normalised with w ≥ 0 (:func:`adfusion.maths.attitude._exp_times`)."""
    n = math.sqrt(x * x + y * y + z * z)
    if n < 1e-6:
        k = 0.5 - n * n / 48.0
        pw, px, py, pz = 1.0 - n * n / 8.0, k * x, k * y, k * z
    else:
        k = math.sin(0.5 * n) / n
        pw, px, py, pz = math.cos(0.5 * n), k * x, k * y, k * z
    qw, qx, qy, qz = q[0], q[1], q[2], q[3]
    w = pw * qw - px * qx - py * qy - pz * qz
    a = pw * qx + px * qw + py * qz - pz * qy
    b = pw * qy - px * qz + py * qw + pz * qx
    c = pw * qz + px * qy - py * qx + pz * qw
    s = 1.0 / math.sqrt(w * w + a * a + b * b + c * c)
    if w < 0.0:
        s = -s
    out = np.empty(4)
    out[0], out[1], out[2], out[3] = w * s, a * s, b * s, c * s
    return out


@_jit
def _residuals(q, b, r):
    """Angle (rad) between each b and R(q) r: 2·asin(|R r − b| / 2)."""
    m = _matrix_t(q)
    res = np.empty(b.shape[0])
    for i in range(b.shape[0]):
        e0 = r[i, 0] * m[0, 0] + r[i, 1] * m[1, 0] + r[i, 2] * m[2, 0] - b[i, 0]
        e1 = r[i, 0] * m[0, 1] + r[i, 1] * m[1, 1] + r[i, 2] * m[2, 1] - b[i, 1]
        e2 = r[i, 0] * m[0, 2] + r[i, 1] * m[1, 2] + r[i, 2] * m[2, 2] - b[i, 2]
        h = 0.5 * math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        res[i] = 2.0 * math.asin(min(h, 1.0))
    return res


@_jit
def wahba_near(q0, b, r, sigma_rad, converged_rad, max_steps):
    """:func:`adfusion.maths.attitude.wahba_near`: Gauss–Newton steps from ``q0``. Returns (ok,
    q (4,), P (3, 3), residuals (n,), loss); not ok when the directions are collinear."""
    wres = 1.0 / sigma_rad ** 2
    ok, P = _inverse_information(b, wres)
    q = q0.copy()
    if not ok:
        return False, q, P, np.empty(0), 0.0
    for _ in range(max_steps):
        m = _matrix_t(q)
        # M = Σ p bᵀ with p = R r: its antisymmetric part is the gradient
        m01 = m02 = m10 = m12 = m20 = m21 = 0.0
        for i in range(b.shape[0]):
            p0 = r[i, 0] * m[0, 0] + r[i, 1] * m[1, 0] + r[i, 2] * m[2, 0]
            p1 = r[i, 0] * m[0, 1] + r[i, 1] * m[1, 1] + r[i, 2] * m[2, 1]
            p2 = r[i, 0] * m[0, 2] + r[i, 1] * m[1, 2] + r[i, 2] * m[2, 2]
            m01 += p0 * b[i, 1]
            m02 += p0 * b[i, 2]
            m10 += p1 * b[i, 0]
            m12 += p1 * b[i, 2]
            m20 += p2 * b[i, 0]
            m21 += p2 * b[i, 1]
        g0, g1, g2 = wres * (m12 - m21), wres * (m20 - m02), wres * (m01 - m10)
        x = P[0, 0] * g0 + P[0, 1] * g1 + P[0, 2] * g2
        y = P[1, 0] * g0 + P[1, 1] * g1 + P[1, 2] * g2
        z = P[2, 0] * g0 + P[2, 1] * g1 + P[2, 2] * g2
        q = _exp_times(x, y, z, q)
        if x * x + y * y + z * z < converged_rad * converged_rad:
            break
    res = _residuals(q, b, r)
    loss = 0.0
    for i in range(res.shape[0]):
        loss += res[i] * res[i]
    return True, q, P, res, wres * loss


@_jit
def tight_fix(pred_idx, j, n_within, d, b_all, vectors, q0, sigma_rad, cut_rad, smear):
    """The tight prior's fix (:meth:`Tracker.solve`): the nearest pairs, one
    Gauss–Newton fit from the prior, pairs beyond ``cut_rad`` dropped and one refit from
    that fit. Returns (status, detections, catalogue rows, their vectors (n, 3),
    q, P, residuals, loss, the longest streak² (rad²) of the kept stars under ``smear``).
    Status :data:`FIT_FEW`: fewer than 2 pairs (no fit); :data:`FIT_COLLINEAR`: a fit's
    directions are collinear (the caller's numpy fit says so in its words)."""
    det, rows = _tight_pairs(pred_idx, j, n_within, d)
    n = det.shape[0]
    b = np.empty((n, 3))
    r = np.empty((n, 3))
    for i in range(n):
        for k in range(3):
            b[i, k] = b_all[det[i], k]
            r[i, k] = vectors[rows[i], k]
    P = np.zeros((3, 3))
    empty = np.empty(0)
    if n < 2:
        return FIT_FEW, det, rows, b, q0.copy(), P, empty, 0.0, 0.0
    ok, q, P, res, loss = wahba_near(q0, b, r, sigma_rad, 1e-3, 4)
    if not ok:
        return FIT_COLLINEAR, det, rows, b, q, P, empty, 0.0, 0.0
    n_keep = 0
    for i in range(n):
        if res[i] <= cut_rad:
            n_keep += 1
    if 2 <= n_keep < n:
        det2 = np.empty(n_keep, dtype=np.int64)
        rows2 = np.empty(n_keep, dtype=np.int64)
        b2 = np.empty((n_keep, 3))
        r2 = np.empty((n_keep, 3))
        k = 0
        for i in range(n):
            if res[i] <= cut_rad:
                det2[k], rows2[k] = det[i], rows[i]
                for c in range(3):
                    b2[k, c], r2[k, c] = b[i, c], r[i, c]
                k += 1
        det, rows, b = det2, rows2, b2
        ok, q, P, res, loss = wahba_near(q, b, r2, sigma_rad, 1e-3, 4)
        if not ok:
            return FIT_COLLINEAR, det, rows, b, q, P, empty, 0.0, 0.0
    # streak length |smear × b|² (adfusion.maths.attitude.streak_vectors)
    sx, sy, sz = smear[0], smear[1], smear[2]
    longest = 0.0
    for i in range(b.shape[0]):
        v0 = b[i, 2] * sy - b[i, 1] * sz
        v1 = b[i, 0] * sz - b[i, 2] * sx
        v2 = b[i, 1] * sx - b[i, 0] * sy
        longest = max(longest, v0 * v0 + v1 * v1 + v2 * v2)
    return FIT_OK, det, rows, b, q, P, res, loss, longest
