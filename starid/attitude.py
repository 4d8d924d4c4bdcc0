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

__all__ = ["WahbaSolution", "wahba"]


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
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    r = r / np.linalg.norm(r, axis=1, keepdims=True)
    sigma = np.broadcast_to(np.asarray(sigma_rad, dtype=np.float64), (len(b),))
    if np.any(~np.isfinite(sigma)) or np.any(sigma <= 0):
        raise ValueError("sigma_rad must be positive and finite")
    w = 1.0 / sigma**2
    B = (w[:, None] * b).T @ r  # attitude profile matrix Σ w b rᵀ
    u, _, vt = np.linalg.svd(B)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        u[:, 2] = -u[:, 2]
    R = u @ vt
    F = np.sum(w) * np.eye(3) - (w[:, None] * b).T @ b  # Σ w (I − b bᵀ)
    ev = np.linalg.eigvalsh(F)
    if ev[0] <= 1e-12 * ev[-1]:
        raise ValueError("matched directions are (nearly) collinear: attitude undetermined")
    P = np.linalg.inv(F)
    pred = r @ R.T
    chord = np.sqrt(np.sum((pred - b) ** 2, axis=1))
    res = 2.0 * np.arcsin(np.minimum(0.5 * chord, 1.0))  # exact, and cheaper than atan2
    q = rot.from_matrix(R, orthonormalize=False)
    return WahbaSolution(q, 0.5 * (P + P.T), res, float(np.sum(w * res**2)))
