"""Basilisk's attitude conventions ↔ the project's (docs/conventions.md).

Basilisk writes the body attitude as the MRP ``sigma_BN`` of the DCM ``[BN]`` (``v_B = [BN]
v_N``), and its Euler-parameter helpers build ``[BN] = EP2C(β)`` — the transpose of the
Hamilton ``R(q)`` used here. So the same rotation is ``β_BN`` in Basilisk and its conjugate
``q_body_icrs`` in adfusion; Basilisk's inertial frame N is taken as ICRS (no SPICE: the
stars and the dynamics share one inertial frame).

Example:
    >>> import numpy as np
    >>> from adfusion.starid import rotations as rot
    >>> sigma = np.array([0.1, -0.2, 0.3])
    >>> q = q_body_icrs_from_sigma_bn(sigma)
    >>> bool(np.allclose(sigma_bn_from_q_body_icrs(q), sigma))
    True
    >>> bool(np.allclose(rot.to_matrix(q), dcm_bn_from_sigma_bn(sigma)))
    True
    >>> v_body = (0.0, 0.6, 0.8)
    >>> bool(np.allclose(icrs_from_body_sigma_bn(sigma, v_body),
    ...                  dcm_bn_from_sigma_bn(sigma).T @ v_body))
    True
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from adfusion.maths import rotations as rot

__all__ = ["dcm_bn_from_sigma_bn", "icrs_from_body_sigma_bn", "q_body_icrs_from_sigma_bn",
           "sigma_bn_from_q_body_icrs"]


def dcm_bn_from_sigma_bn(sigma_bn: ArrayLike) -> NDArray[np.float64]:
    """``[BN]`` of an MRP (Schaub & Junkins eq. 3.153), written out so the conversion is
    checked against a formula independent of the quaternion path."""
    s = np.asarray(sigma_bn, dtype=np.float64).reshape(3)
    s2 = float(s @ s)
    sk = rot.skew(s)
    return np.eye(3) + (8.0 * sk @ sk - 4.0 * (1.0 - s2) * sk) / (1.0 + s2) ** 2


def q_body_icrs_from_sigma_bn(sigma_bn: ArrayLike) -> NDArray[np.float64]:
    """``q_body_icrs`` (Hamilton, w ≥ 0) of Basilisk's ``sigma_BN``."""
    s = np.asarray(sigma_bn, dtype=np.float64).reshape(3)
    s2 = float(s @ s)
    # β_BN = [1 − s², 2s]/(1 + s²); q_body_icrs is its conjugate
    q = np.concatenate([[1.0 - s2], -2.0 * s]) / (1.0 + s2)
    return rot.canonical(q)


def sigma_bn_from_q_body_icrs(q_body_icrs: ArrayLike) -> NDArray[np.float64]:
    """Basilisk's ``sigma_BN`` (the short MRP, |σ| ≤ 1) of ``q_body_icrs``."""
    q = rot.canonical(rot.normalize(q_body_icrs))
    return -q[1:] / (1.0 + q[0])


def icrs_from_body_sigma_bn(sigma_bn, v_body) -> tuple[float, float, float]:
    """A body-frame vector in ICRS, ``[BN]ᵀ v_body``, for Basilisk's ``sigma_BN`` — in floats
    (Schaub & Junkins eq. 3.153 transposed: ``v + (8 σ×(σ×v) + 4(1 − σ²) σ×v) / (1 + σ²)²``),
    for modules that run every step."""
    s1, s2, s3 = (float(c) for c in sigma_bn)
    v1, v2, v3 = (float(c) for c in v_body)
    ss = s1 * s1 + s2 * s2 + s3 * s3
    c1, c2, c3 = s2 * v3 - s3 * v2, s3 * v1 - s1 * v3, s1 * v2 - s2 * v1  # σ × v
    d1, d2, d3 = s2 * c3 - s3 * c2, s3 * c1 - s1 * c3, s1 * c2 - s2 * c1  # σ × (σ × v)
    a, k = 4.0 * (1.0 - ss), 1.0 / (1.0 + ss) ** 2
    return (v1 + k * (8.0 * d1 + a * c1), v2 + k * (8.0 * d2 + a * c2),
            v3 + k * (8.0 * d3 + a * c3))
