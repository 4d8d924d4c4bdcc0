"""Attitude from matched directions: Wahba's problem (SVD) with its covariance.

Given unit vectors ``b`` measured in the camera frame and the same stars' catalogue
directions ``r`` in ICRS, find ``q_cam_icrs`` minimising ``Σ w_i |b_i − R r_i|²``
(Markley's SVD method, exact for any number ≥ 2 of non-parallel pairs). With
``w_i = 1/σ_i²`` for an isotropic direction error σ_i (rad), the attitude error covariance
in the camera frame is ``P = (Σ w_i (I − b_i b_iᵀ))⁻¹`` (Shuster's QUEST covariance), rad².

Example:
    >>> import numpy as np
    >>> from adfusion.maths import rotations as rot
    >>> from adfusion.maths.attitude import wahba
    >>> q_true = rot.q_cam_icrs_from_radec_roll(1.0, 0.5, 0.2)
    >>> r = rot.radec_to_vector([1.0, 1.02, 0.98], [0.5, 0.51, 0.52])
    >>> sol = wahba(rot.rotate(q_true, r), r, sigma_rad=1e-5)
    >>> bool(rot.angle_between(sol.q_cam_icrs, q_true) < 1e-12)
    True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from adfusion.maths import rotations as rot

__all__ = ["WahbaSolution", "refine_streaked", "streak_vectors", "wahba", "wahba_near",
           "wahba_unit"]


@dataclass(frozen=True)
class WahbaSolution:
    """Attitude, covariance (camera frame, rad²) and per-star residuals (rad)."""

    q_cam_icrs: NDArray[np.float64]
    covariance: NDArray[np.float64]
    residuals_rad: NDArray[np.float64]
    loss: float


def wahba(
    b_cam: ArrayLike,
    r_icrs: ArrayLike,
    sigma_rad: ArrayLike = 1e-4,
) -> WahbaSolution:
    """Solve Wahba's problem for ``q_cam_icrs`` (``b ≈ R(q) r``).

    Args:
        b_cam: (N, 3) measured directions, camera frame (normalised here).
        r_icrs: (N, 3) reference directions, ICRS.
        sigma_rad: direction error per star (scalar or (N,)), sets weights and covariance.

    Raises ValueError for fewer than 2 pairs, non-finite input or collinear geometry
    (the attitude about the common axis is then undetermined).
    """
    b = np.asarray(b_cam, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(r_icrs, dtype=np.float64).reshape(-1, 3)
    if len(b) != len(r):
        raise ValueError(f"b_cam and r_icrs differ in length: {len(b)} vs {len(r)}")
    if len(b) < 2:
        raise ValueError(f"Wahba's problem needs at least 2 direction pairs, got {len(b)}")
    if not (np.all(np.isfinite(b)) and np.all(np.isfinite(r))):
        raise ValueError("direction vectors must be finite")
    sigma = np.asarray(sigma_rad, dtype=np.float64)
    if np.any(~np.isfinite(sigma)) or np.any(sigma <= 0):
        raise ValueError("sigma_rad must be positive and finite")
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    r = r / np.linalg.norm(r, axis=1, keepdims=True)
    return wahba_unit(b, r, sigma)


def wahba_unit(b: NDArray[np.float64], r: NDArray[np.float64],
               sigma_rad: float | NDArray[np.float64]) -> WahbaSolution:
    """:func:`wahba` without input checks, for unit vectors already validated (the
    solver's hot path). ``sigma_rad`` is a scalar or one value per pair."""
    if isinstance(sigma_rad, float) or np.ndim(sigma_rad) == 0:
        wres = 1.0 / float(sigma_rad) ** 2
        B = b.T @ r  # attitude profile matrix, up to the weight (the SVD ignores scale)
        S = b.T @ b  # F = wres·(n·I − S)
        w_sum, scale = float(len(b)), wres
    else:
        wres = 1.0 / np.asarray(sigma_rad, dtype=np.float64) ** 2
        wb = wres[:, None] * b
        B = wb.T @ r
        S = wb.T @ b
        w_sum, scale = float(np.sum(wres)), 1.0
    u, _, vt = np.linalg.svd(B)
    R = u @ vt
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = R.tolist()
    if a0 * (b1 * c2 - b2 * c1) - a1 * (b0 * c2 - b2 * c0) + a2 * (b0 * c1 - b1 * c0) < 0:
        u[:, 2] = -u[:, 2]  # nearest proper rotation, not a reflection
        R = u @ vt
    P = np.array(_inverse_information(S.tolist(), w_sum, scale))
    pred = r @ R.T
    pred -= b
    res = np.sqrt(np.einsum("ij,ij->i", pred, pred))  # chord, then the exact angle
    res *= 0.5
    res = 2.0 * np.arcsin(np.minimum(res, 1.0, out=res), out=res)
    q = rot.from_matrix(R, orthonormalize=False)
    loss = wres * float(res @ res) if isinstance(wres, float) else float(wres @ res**2)
    return WahbaSolution(q, P, res, loss)


def wahba_near(q_cam_icrs: NDArray[np.float64], b: NDArray[np.float64],
               r: NDArray[np.float64], sigma_rad: float, *,
               converged_rad: float = 1e-3, max_steps: int = 4) -> WahbaSolution:
    """:func:`wahba_unit` started from an attitude near the answer (a tracking prior, or
    the same stars' fit before a few pairs were dropped): Gauss–Newton steps instead of
    the SVD, cheaper at numpy's per-call overhead. A step's error is second order in its
    size, so steps repeat until one is shorter than ``converged_rad`` (1e-3 rad: the
    next would move the answer by ≲ 1e-6 rad, a hundredth of a pixel of a 25° camera);
    from a filter's prior that is one step. Raises ValueError when the directions are
    (nearly) collinear, like :func:`wahba_unit`.

    >>> from adfusion.maths import rotations as rot
    >>> q = rot.q_cam_icrs_from_radec_roll(1.0, 0.5, 0.2)
    >>> r = rot.radec_to_vector([1.0, 1.02, 0.98], [0.5, 0.51, 0.52])
    >>> near = rot.multiply(rot.exp_map([2e-3, -1e-3, 3e-3]), q)
    >>> bool(rot.angle_between(wahba_near(near, rot.rotate(q, r), r, 1e-5).q_cam_icrs, q) < 1e-8)
    True
    """
    wres = 1.0 / sigma_rad**2
    P = _inverse_information((b.T @ b).tolist(), float(len(b)), wres)
    (p00, p01, p02), (p10, p11, p12), (p20, p21, p22) = P
    qw, qx, qy, qz = q_cam_icrs.tolist()
    for _ in range(max_steps):
        p = r @ _matrix_t(qw, qx, qy, qz)
        M = p.T @ b  # Σ p bᵀ: its antisymmetric part is Σ p × b, the gradient
        (_, m01, m02), (m10, _, m12), (m20, m21, _) = M.tolist()
        g0, g1, g2 = wres * (m12 - m21), wres * (m20 - m02), wres * (m01 - m10)
        x = p00 * g0 + p01 * g1 + p02 * g2
        y = p10 * g0 + p11 * g1 + p12 * g2
        z = p20 * g0 + p21 * g1 + p22 * g2
        qw, qx, qy, qz = _exp_times(x, y, z, qw, qx, qy, qz)
        if x * x + y * y + z * z < converged_rad * converged_rad:
            break
    pred = r @ _matrix_t(qw, qx, qy, qz)
    pred -= b
    res = np.sqrt(np.einsum("ij,ij->i", pred, pred))
    res *= 0.5
    res = 2.0 * np.arcsin(np.minimum(res, 1.0, out=res), out=res)
    return WahbaSolution(np.array([qw, qx, qy, qz]), np.array(P), res,
                         wres * float(res @ res))


def _matrix_t(w: float, x: float, y: float, z: float) -> NDArray[np.float64]:
    """R(q)ᵀ of a (near-)unit quaternion, built in floats (for ``r @ R.T``)."""
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    return np.array([[1.0 - 2.0 * (yy + zz), 2.0 * (xy + wz), 2.0 * (xz - wy)],
                     [2.0 * (xy - wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz + wx)],
                     [2.0 * (xz + wy), 2.0 * (yz - wx), 1.0 - 2.0 * (xx + yy)]])


def _inverse_information(S: list[list[float]], w_sum: float,
                         scale: float = 1.0) -> list[list[float]]:
    """``(scale·(w_sum·I − S))⁻¹`` for the symmetric 3×3 ``S = Σ w b bᵀ`` by the adjugate, in
    plain floats (numpy's per-call overhead dominates at 3×3). Its determinant is the
    product of F's eigenvalues, each in [0, w_sum]: ``det ≤ 1e-12·tr³`` means the
    smallest is ≲ 1e-12 of the largest — collinear directions."""
    (s00, s01, s02), (_, s11, s12), (_, _, s22) = S
    return _inverse_symmetric([[scale * (w_sum - s00), -scale * s01, -scale * s02],
                               [-scale * s01, scale * (w_sum - s11), -scale * s12],
                               [-scale * s02, -scale * s12, scale * (w_sum - s22)]])


def refine_streaked(q_cam_icrs: ArrayLike, b: NDArray[np.float64], r: NDArray[np.float64],
                    sigma_rad: float, smear_cam_rad: ArrayLike, whole_rad: float = 0.0,
                    iterations: int = 1) -> WahbaSolution:
    """Attitude at mid-exposure from stars smeared by the camera's rotation.

    During an exposure the camera turns through the rotation vector ``smear_cam_rad``
    (ω·T, camera axes), so each star draws a streak of angular length
    ``L = |smear × b|`` along ``smear × b``. A detection is the centroid of the streak, or
    of a *piece* of it when a long streak breaks up in the noise. Streaks up to
    ``whole_rad`` long are taken to be detected whole (centroid at mid-exposure), and the
    pieces of a longer one to span at least ``whole_rad``: a piece's centroid then lies
    anywhere within ``L − whole_rad`` along the streak (uniformly), so a detection is good
    to ``sigma_rad`` across the streak and to ``√(σ² + (L − whole_rad)²/12)`` along it.
    This Gauss–Newton
    fit starts from ``q_cam_icrs`` (an isotropic fit), weighs each star with that 2×2
    information, and returns the covariance that goes with it (camera frame, rad²) —
    honest along the streaks, where an isotropic fit claims the centroid noise.

    ``loss`` is the weighted sum of squared residuals (for a variance factor) and
    ``residuals_rad`` the plain angular residuals.

    Example:
        >>> import numpy as np
        >>> from adfusion.maths import rotations as rot
        >>> q = rot.q_cam_icrs_from_radec_roll(1.0, 0.5, 0.2)
        >>> r = rot.radec_to_vector([1.0, 1.02, 0.98, 1.01], [0.5, 0.51, 0.52, 0.49])
        >>> b = rot.rotate(q, r)
        >>> s = refine_streaked(q, b, r, 1e-5, [0.0, 0.01, 0.0])
        >>> bool(rot.angle_between(s.q_cam_icrs, q) < 1e-9)
        True
        >>> # turning about y smears the stars along x: the y-axis error is the loose one
        >>> bool(s.covariance[1, 1] > 1e4 * s.covariance[0, 0])
        True
    """
    q = rot.normalize(np.asarray(q_cam_icrs, dtype=np.float64))
    sx, sy, sz = np.asarray(smear_cam_rad, dtype=np.float64).reshape(3).tolist()
    # written for numpy's per-call overhead (this runs per streaked frame in tracking):
    # cross products as one matmul with a skew matrix, 3×3 algebra in plain floats
    v = streak_vectors(b, (sx, sy, sz))
    length = np.sqrt(np.einsum("ij,ij->i", v, v))
    still = length < 1e-300
    u_a = v / np.where(still, 1.0, length)[:, None]
    if still.any():
        u_a[still] = _any_tangent(b[still])
    u_c = np.empty_like(b)  # b × u_a
    u_c[:, 0] = b[:, 1] * u_a[:, 2] - b[:, 2] * u_a[:, 1]
    u_c[:, 1] = b[:, 2] * u_a[:, 0] - b[:, 0] * u_a[:, 2]
    u_c[:, 2] = b[:, 0] * u_a[:, 1] - b[:, 1] * u_a[:, 0]
    w_c = 1.0 / sigma_rad**2
    spread = np.maximum(length - whole_rad, 0.0)
    w_a = 1.0 / (sigma_rad**2 + spread * spread / 12.0)
    # residual e = b − R r ≈ δθ × p: along u_a it reads δθ·u_c, across (u_c) −δθ·u_a
    wu_c = w_a[:, None] * u_c
    cov = _inverse_symmetric((wu_c.T @ u_c + w_c * (u_a.T @ u_a)).tolist())
    for step in range(iterations + 1):
        e = r @ rot.to_matrix(q).T
        np.subtract(b, e, out=e)
        ea = np.einsum("ij,ij->i", e, u_a)
        ec = np.einsum("ij,ij->i", e, u_c)
        if step == iterations:  # the residuals of the final attitude
            break
        g = (ea @ wu_c - w_c * (ec @ u_a)).tolist()
        d = [sum(cov[k][m] * g[m] for m in range(3)) for k in range(3)]
        q = _rotate_small(d, q)
    res = np.sqrt(ea * ea + ec * ec)
    return WahbaSolution(q, np.array(cov), res, float(w_a @ (ea * ea) + w_c * (ec @ ec)))


def streak_vectors(b: NDArray[np.float64], smear_cam_rad: ArrayLike) -> NDArray[np.float64]:
    """Each star's streak (rad, tangent at ``b``) when the camera turns through the rotation
    vector ``smear_cam_rad`` (camera axes): ``smear × b``, as one matmul.

    >>> streak_vectors(np.array([[0.0, 0.0, 1.0]]), [0.0, 0.01, 0.0]).round(6).tolist()
    [[0.01, 0.0, 0.0]]
    """
    sx, sy, sz = np.asarray(smear_cam_rad, dtype=np.float64).reshape(3).tolist()
    return b @ np.array([[0.0, sz, -sy], [-sz, 0.0, sx], [sy, -sx, 0.0]])


def _inverse_symmetric(F: list[list[float]]) -> list[list[float]]:
    """Inverse of a symmetric positive 3×3 information matrix by the adjugate; raises for a
    (nearly) singular one (collinear directions)."""
    (f00, f01, f02), (_, f11, f12), (_, _, f22) = F
    c00 = f11 * f22 - f12 * f12
    c01 = f02 * f12 - f01 * f22
    c02 = f01 * f12 - f02 * f11
    det = f00 * c00 + f01 * c01 + f02 * c02
    if not det > 1e-12 * (f00 + f11 + f22) ** 3:
        raise ValueError("matched directions are (nearly) collinear: attitude undetermined")
    k = 1.0 / det
    c11 = (f00 * f22 - f02 * f02) * k
    c12 = (f01 * f02 - f00 * f12) * k
    c22 = (f00 * f11 - f01 * f01) * k
    c00, c01, c02 = c00 * k, c01 * k, c02 * k
    return [[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]]


def _rotate_small(d: list[float], q: NDArray[np.float64]) -> NDArray[np.float64]:
    """exp(d) ⊗ q for a rotation vector d (rad, the left frame)."""
    return np.array(_exp_times(*d, *q.tolist()))


def _exp_times(x: float, y: float, z: float, qw: float, qx: float, qy: float,
               qz: float) -> tuple[float, float, float, float]:
    """exp((x, y, z)) ⊗ q in plain floats, normalised (numpy's per-call overhead would
    dominate at this size)."""
    return rot.normalize_floats(rot.hamilton(rot.exp_map_floats(x, y, z), (qw, qx, qy, qz)))


def _any_tangent(b: NDArray[np.float64]) -> NDArray[np.float64]:
    """A unit vector perpendicular to each row of ``b`` (for stars that do not move)."""
    t = np.cross(b, [1.0, 0.0, 0.0])
    small = np.linalg.norm(t, axis=1) < 0.5
    t[small] = np.cross(b[small], [0.0, 1.0, 0.0])
    return t / np.linalg.norm(t, axis=1, keepdims=True)
