"""Camera mounts from the fixes (issue 35): the rotation between two star heads, measured
directly whenever both see stars at once.

Two heads ``a`` and ``b`` fixed to one body give, at the same instant, ``q_a_icrs`` and
``q_b_icrs``; their relative rotation ``q_a_b = q_a_icrs ⊗ q_b_icrs⁻¹`` is the same at every
instant, whatever the body does — the body's own motion and the gyro do not enter. Its
estimate is the rotation nearest to all the measured ones (the chordal mean: the SVD of the
sum of their matrices, as in Wahba's problem), and its covariance, per axis of head ``a``,
that of the mean of ``n`` independent errors, ``(Σ_a + R Σ_b Rᵀ) / n`` — each fix's
covariance given per camera axis (a star camera's roll about its boresight is several
times less certain than its pointing).

Example:
    >>> import numpy as np
    >>> from adfusion.maths import rotations as rot
    >>> rng = np.random.default_rng(0)
    >>> q_ab = rot.exp_map(np.radians([0.0, 90.0, 0.0]))            # b looks along a's +x
    >>> q_b = rot.normalize(rng.standard_normal((200, 4)))           # the body turning
    >>> q_a = rot.multiply(q_ab, q_b)
    >>> fit = relative_mount(q_a, q_b, sigma_a_rad=[1e-5, 1e-5, 5e-5],
    ...                      sigma_b_rad=[1e-5, 1e-5, 5e-5])
    >>> bool(np.degrees(rot.angle_between(fit.q_a_b, q_ab)) * 3600 < 0.01)
    True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from adfusion.maths import rotations as rot

__all__ = ["RelativeMount", "relative_mount"]

Array = NDArray[np.float64]


@dataclass
class RelativeMount:
    """The rotation from head ``b``'s camera frame to head ``a``'s (``q_a_b``,
    Hamilton scalar-first), its 3×3 covariance about ``a``'s axes (rad²), the RMS angle of
    the pairs about it, and the pairs used."""

    q_a_b: Array
    cov: Array
    residual_rad: float
    pairs: int

    @property
    def sigma_rad(self) -> Array:
        return np.sqrt(np.diag(self.cov))

    @property
    def angle_rad(self) -> float:
        """The angle between the two boresights (+z of each camera)."""
        z_b_in_a = rot.to_matrix(self.q_a_b) @ np.array([0.0, 0.0, 1.0])
        return float(np.arccos(np.clip(z_b_in_a[2], -1.0, 1.0)))


def relative_mount(q_a_icrs: ArrayLike, q_b_icrs: ArrayLike, *, sigma_a_rad: ArrayLike,
                   sigma_b_rad: ArrayLike) -> RelativeMount:
    """The relative mount of two heads from simultaneous fixes ``q_a_icrs``, ``q_b_icrs``
    (N, 4; pair k taken at one instant), each fix's 1σ per camera axis (3,) given. See the
    module's text for the method and the example."""
    qa = rot.normalize(np.asarray(q_a_icrs, dtype=np.float64).reshape(-1, 4))
    qb = rot.normalize(np.asarray(q_b_icrs, dtype=np.float64).reshape(-1, 4))
    if len(qa) != len(qb) or len(qa) < 2:
        raise ValueError(f"relative_mount needs ≥ 2 simultaneous pairs, got {len(qa)} and "
                         f"{len(qb)} fixes")
    sa = np.broadcast_to(np.asarray(sigma_a_rad, dtype=np.float64), (3,))
    sb = np.broadcast_to(np.asarray(sigma_b_rad, dtype=np.float64), (3,))
    r = rot.to_matrix(qa) @ np.swapaxes(rot.to_matrix(qb), -1, -2)  # R_a_b per pair
    u, _, vt = np.linalg.svd(r.sum(axis=0))
    mean = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    q_ab = rot.from_matrix(mean)
    resid = rot.log_map(rot.from_matrix(r @ mean.T))
    n = len(qa)
    cov = (np.diag(sa**2) + mean @ np.diag(sb**2) @ mean.T) / n
    return RelativeMount(q_ab, cov, float(np.sqrt(np.mean(np.sum(resid**2, axis=1)))), n)
