"""Compiled (numba) quick checks of a candidate assignment: its rotation, the sky map that
spares the association its empty sky, the chance of a match (binomial tail, spot geometry).

Example:
    >>> from adfusion.starid.identify.check_kernels import binomial_tail
    >>> round(binomial_tail(3, 10, 0.01), 6)  # P(X ≥ 3), X ~ Binomial(10, 0.01): as scipy
    0.000114
"""

from __future__ import annotations

import math

import numpy as np
from adfusion.starid.identify.match_kernels import _SLACK, _dot
from adfusion.starid.jit_cache import njit_cached

__all__ = ['SKY_CELLS', 'binomial_tail', 'quick_checks', 'sky_map']

# cached on disk, keyed by this file and the modules it compiles in (starid.jit_cache)
# mean catalogue density is doubled: the Milky Way holds several times the mean at V ~ 6
DENSITY_SAFETY = 2.0
_jit = njit_cached(nogil=True)
# small helpers called per pair or per detection, inlined: a call that passes ``ix`` (18
# members, each array reference-counted) cost ~80 ns, more than the helper's own work
_jit_inline = njit_cached(nogil=True, inline="always")


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
    """sin of ``starid.identify.verify._crossing_angle`` from the cosines and sines of its angles
    (d01, d0m, d1m)."""
    denom = s0m * s1m
    if denom <= 0:
        return 0.0
    c = (c01 - c0m * c1m) / denom
    return math.sin(math.acos(min(1.0, max(-1.0, c))))


@_jit
def _spot_geometry(a):
    """:func:`starid.identify.verify.spot_geometry`: rows (s, t) and sin γ per star m ≥ 2 — each
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
    """:func:`starid.identify.verify.expected_chance_patterns` (``w`` = 2 × the windows), the
    same operations in the same order."""
    rho = DENSITY_SAFETY * n_catalog / (4.0 * np.pi)
    e = float(n_catalog) * rho * 2.0 * np.pi * max(math.sin(a[0, 1]), 1e-6) * w[0, 1]
    e *= 2.0
    for r in range(len(sg)):
        m = r + 2
        spots = 1.0 if (m >= 3 or mirror_checked) else 2.0
        e *= rho * spots * w[st[r, 0], m] * w[st[r, 1], m] / max(sg[r], 0.05)
    return e


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
    ``starid.identify.verify.rotation_from_pairs`` (SVD of B = Σ b cᵀ, reflection excluded);
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
