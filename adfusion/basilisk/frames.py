"""Basilisk's attitude conventions ↔ the project's (DESIGN.md).

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
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from adfusion.starid import rotations as rot

__all__ = ["dcm_bn_from_sigma_bn", "q_body_icrs_from_sigma_bn", "sigma_bn_from_q_body_icrs"]


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
