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
    if np.ndim(sigma_rad) == 0:
        w = 1.0 / float(sigma_rad) ** 2
        B = w * (b.T @ r)  # attitude profile matrix Σ w b rᵀ
        F = w * (len(b) * np.eye(3) - b.T @ b)  # Σ w (I − b bᵀ)
        wres = w
    else:
        wv = 1.0 / np.asarray(sigma_rad, dtype=np.float64) ** 2
        wb = wv[:, None] * b
        B = wb.T @ r
        F = np.sum(wv) * np.eye(3) - wb.T @ b
        wres = wv
    u, _, vt = np.linalg.svd(B)
    R = u @ vt
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = R.tolist()
    if a0 * (b1 * c2 - b2 * c1) - a1 * (b0 * c2 - b2 * c0) + a2 * (b0 * c1 - b1 * c0) < 0:
        u[:, 2] = -u[:, 2]  # nearest proper rotation, not a reflection
        R = u @ vt
    lam, vec = np.linalg.eigh(F)
    if lam[0] <= 1e-12 * lam[-1]:
        raise ValueError("matched directions are (nearly) collinear: attitude undetermined")
    P = (vec / lam) @ vec.T  # F⁻¹ from its eigendecomposition, symmetric by construction
    pred = r @ R.T
    chord = np.sqrt(np.sum((pred - b) ** 2, axis=1))
    res = 2.0 * np.arcsin(np.minimum(0.5 * chord, 1.0))  # exact, and cheaper than atan2
    q = rot.from_matrix(R, orthonormalize=False)
    return WahbaSolution(q, P, res, float(np.sum(wres * res**2)))
