"""Compiled (numba) fits: pixels to directions, Wahba's attitude with its covariance, a
candidate's full verification (:func:`verify_candidate`) and the final refit of an
undistorted pinhole (:func:`refine_pinhole`).
"""

from __future__ import annotations

import math

import numpy as np
from adfusion.starid.identify.check_kernels import (
    DENSITY_SAFETY,
    _nearest_in,
    _rotation,
    binomial_tail,
)
from adfusion.starid.jit_cache import njit_cached

# cached on disk, keyed by this file and the modules it compiles in (starid.jit_cache)
_jit = njit_cached(nogil=True)
# small helpers called per pair or per detection, inlined: a call that passes ``ix`` (18
# members, each array reference-counted) cost ~80 ns, more than the helper's own work
_jit_inline = njit_cached(nogil=True, inline="always")


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
    by the tracking path's one formula (:func:`starid.tracking.kernels._inverse_information`):
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
    """:meth:`starid.identify.refine.Refiner.refine` for a camera that is not fitted and is an
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
    """:meth:`starid.identify.verify.Verifier.verify` for a known camera: the attitude refitted
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


@_jit
def _inverse_information(b, wres):
    """(wres·(n·I − Σ b bᵀ))⁻¹ by the adjugate
    (:func:`adfusion.maths.attitude._inverse_information`);
    (ok, P): not ok when (nearly) singular — collinear directions."""
    n = b.shape[0]
    s00 = s01 = s02 = s11 = s12 = s22 = 0.0
    for i in range(n):
        x, y, z = b[i, 0], b[i, 1], b[i, 2]
        s00 += x * x
        s01 += x * y
        s02 += x * z
        s11 += y * y
        s12 += y * z
        s22 += z * z
    w_sum = float(n)
    f00, f01, f02 = wres * (w_sum - s00), -wres * s01, -wres * s02
    f11, f12, f22 = wres * (w_sum - s11), -wres * s12, wres * (w_sum - s22)
    c00 = f11 * f22 - f12 * f12
    c01 = f02 * f12 - f01 * f22
    c02 = f01 * f12 - f02 * f11
    det = f00 * c00 + f01 * c01 + f02 * c02
    P = np.empty((3, 3))
    if not det > 1e-12 * (f00 + f11 + f22) ** 3:
        return False, P
    k = 1.0 / det
    c11 = (f00 * f22 - f02 * f02) * k
    c12 = (f01 * f02 - f00 * f12) * k
    c22 = (f00 * f11 - f01 * f01) * k
    c00, c01, c02 = c00 * k, c01 * k, c02 * k
    P[0, 0], P[0, 1], P[0, 2] = c00, c01, c02
    P[1, 0], P[1, 1], P[1, 2] = c01, c11, c12
    P[2, 0], P[2, 1], P[2, 2] = c02, c12, c22
    return True, P
