"""Attitude from matched directions: Wahba's problem (SVD) with its covariance.

Given unit vectors ``b`` measured in the camera frame and the same stars' catalogue
directions ``r`` in ICRS, find ``q_cam_icrs`` minimising ``Σ w_i |b_i − R r_i|²``
(Markley's SVD method, exact for any number ≥ 2 of non-parallel pairs). With
``w_i = 1/σ_i²`` for an isotropic direction error σ_i (rad), the attitude error covariance
in the camera frame is ``P = (Σ w_i (I − b_i b_iᵀ))⁻¹`` (Shuster's QUEST covariance), rad².

Example:
    >>> import numpy as np
    >>> from starid import rotations as rot
    >>> from starid.attitude import wahba
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

from starid import rotations as rot

__all__ = ["WahbaSolution", "wahba", "wahba_unit"]


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
    P = _inverse_information(S.tolist(), w_sum, scale)
    pred = r @ R.T
    pred -= b
    res = np.sqrt(np.einsum("ij,ij->i", pred, pred))  # chord, then the exact angle
    res *= 0.5
    res = 2.0 * np.arcsin(np.minimum(res, 1.0, out=res), out=res)
    q = rot.from_matrix(R, orthonormalize=False)
    loss = wres * float(res @ res) if isinstance(wres, float) else float(wres @ res**2)
    return WahbaSolution(q, P, res, loss)


def _inverse_information(S: list[list[float]], w_sum: float,
                         scale: float = 1.0) -> NDArray[np.float64]:
    """``(scale·(w_sum·I − S))⁻¹`` for the symmetric 3×3 ``S = Σ w b bᵀ`` by the adjugate, in
    plain floats (numpy's per-call overhead dominates at 3×3). Its determinant is the
    product of F's eigenvalues, each in [0, w_sum]: ``det ≤ 1e-12·tr³`` means the
    smallest is ≲ 1e-12 of the largest — collinear directions."""
    (s00, s01, s02), (_, s11, s12), (_, _, s22) = S
    f00, f11, f22 = w_sum - s00, w_sum - s11, w_sum - s22
    f01, f02, f12 = -s01, -s02, -s12
    c00 = f11 * f22 - f12 * f12
    c01 = f02 * f12 - f01 * f22
    c02 = f01 * f12 - f02 * f11
    det = f00 * c00 + f01 * c01 + f02 * c02
    tr = f00 + f11 + f22
    if not det > 1e-12 * tr**3:
        raise ValueError("matched directions are (nearly) collinear: attitude undetermined")
    c11 = f00 * f22 - f02 * f02
    c12 = f01 * f02 - f00 * f12
    c22 = f00 * f11 - f01 * f01
    k = 1.0 / (det * scale)
    return np.array([[c00 * k, c01 * k, c02 * k], [c01 * k, c11 * k, c12 * k],
                     [c02 * k, c12 * k, c22 * k]])
