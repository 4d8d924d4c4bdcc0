"""Pieces the filters share (MEKF, UKF, RateMEKF): the closed-form error-state transition,
the gyro-step check, the tangent basis of a direction update and the fast symmetrisation.

Written in plain floats where they sit on the hot path (numpy's per-call overhead is ~1 µs
on 3- and 6-vectors); the quaternion maths itself is :mod:`adfusion.maths.rotations`
(``hamilton``, ``exp_map_floats`` …), one implementation for every module.

Example:
    >>> import numpy as np
    >>> [round(c, 6) for c in series_coeffs(0.0)]
    [1.0, 0.5, 0.166667]
    >>> e1, e2 = tangent_basis(0.0, 0.0, 1.0)
    >>> float(np.dot(e1, [0, 0, 1])), float(np.dot(e2, [0, 0, 1]))
    (0.0, 0.0)
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["check_dt_omega", "phi_rows", "series_coeffs", "symmetrize", "tangent_basis",
           "tangent_residual"]

Array = NDArray[np.float64]

_HALF6 = np.full((6, 6), 0.5)
_HALF6.setflags(write=False)


def series_coeffs(n: float) -> tuple[float, float, float]:
    """sin(n)/n, (1 − cos n)/n², (n − sin n)/n³ — with Taylor branches near n = 0.

    The closed forms lose all their digits to cancellation for small n (a gyro at 1 kHz
    turns by microradians per step), so below 1e-3 rad the series is used (truncation
    error ~n⁶, far below double precision there).
    """
    if n < 1e-3:
        n2 = n * n
        return (1.0 - n2 / 6.0 + n2 * n2 / 120.0,
                0.5 - n2 / 24.0 + n2 * n2 / 720.0,
                1.0 / 6.0 - n2 / 120.0 + n2 * n2 / 5040.0)  # fmt: skip
    s, c = math.sin(n), math.cos(n)
    return s / n, (1.0 - c) / (n * n), (n - s) / (n * n * n)


def phi_rows(tx: float, ty: float, tz: float, dt: float) -> list[list[float]]:
    """Top three rows of Φ (the bottom three are ``[0 I]``) for a step θ = ω̂·dt.

    Φ₁₁ = Exp(−θ) = I − a[θ]× + c[θ]×²,  Φ₁₂ = ∫₀^dt Exp(−ω̂ s) ds = dt (I − c[θ]× + d[θ]×²),
    with [θ]×² = θθᵀ − |θ|² I; written out entry by entry because a 6×6 numpy assembly from
    3×3 pieces costs more than the arithmetic.
    """
    n2 = tx * tx + ty * ty + tz * tz
    a, c, d = series_coeffs(math.sqrt(n2))
    xx, yy, zz, xy, xz, yz = tx * tx, ty * ty, tz * tz, tx * ty, tx * tz, ty * tz
    a_d = 1.0 - c * n2
    b_d = dt * (1.0 - d * n2)
    cd, dd = c * dt, d * dt
    return [
        [a_d + c * xx, a * tz + c * xy, -a * ty + c * xz,
         b_d + dd * xx, cd * tz + dd * xy, -cd * ty + dd * xz],
        [-a * tz + c * xy, a_d + c * yy, a * tx + c * yz,
         -cd * tz + dd * xy, b_d + dd * yy, cd * tx + dd * yz],
        [a * ty + c * xz, -a * tx + c * yz, a_d + c * zz,
         cd * ty + dd * xz, -cd * tx + dd * yz, b_d + dd * zz],
    ]  # fmt: skip


def check_dt_omega(dt: float, omega_meas_rad_s: ArrayLike) -> tuple[float, float, float, float]:
    """Validated (dt, ωx, ωy, ωz) for a propagation step; raises ValueError on bad input.

    Propagation cannot "reject" a sample the way an update can: time has to advance, and
    only the caller knows whether to bridge a gap with the previous rate or to stop. So a
    bad gyro sample or step is an exception and the state is left as it was.
    """
    dt = float(dt)
    if not 0.0 < dt < math.inf:
        raise ValueError(f"dt must be a finite positive number of seconds, got {dt}")
    w = np.asarray(omega_meas_rad_s, dtype=np.float64)
    if w.shape != (3,):
        raise ValueError(f"omega_meas_rad_s must have shape (3,), got {w.shape}")
    wx, wy, wz = w.tolist()
    if not math.isfinite(wx + wy + wz):
        raise ValueError(f"gyro sample is not finite: {[wx, wy, wz]}")
    if not math.isfinite((wx * wx + wy * wy + wz * wz) * dt * dt):
        raise ValueError(f"gyro sample × dt overflows: {[wx, wy, wz]} × {dt}")
    return dt, wx, wy, wz


def tangent_basis(
    px: float, py: float, pz: float
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Orthonormal e1, e2 ⟂ the unit vector p, with e2 = p × e1.

    e1 is p crossed with the coordinate axis p is least aligned with, so it never degenerates.
    """
    ax, ay, az = abs(px), abs(py), abs(pz)
    if ax <= ay and ax <= az:
        e1 = (0.0, pz, -py)  # p × x̂
    elif ay <= az:
        e1 = (-pz, 0.0, px)  # p × ŷ
    else:
        e1 = (py, -px, 0.0)  # p × ẑ
    s = 1.0 / math.sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2])
    e1x, e1y, e1z = e1[0] * s, e1[1] * s, e1[2] * s
    return (e1x, e1y, e1z), (py * e1z - pz * e1y, pz * e1x - px * e1z, px * e1y - py * e1x)


def tangent_residual(
    e1: tuple[float, float, float], e2: tuple[float, float, float],
    p: tuple[float, float, float], b: tuple[float, float, float],
) -> tuple[float, float]:  # fmt: skip
    """Residual of the unit direction ``b`` against the prediction ``p`` in the tangent basis
    (e1, e2) of ``p``: the log map, so its length is the angle between them.

    Why not the plain projections (e1·b, e2·b): they are sin θ long, which is 0 again at
    180° — an exactly reversed vector (a magnetometer of flipped polarity) would pass with
    NIS 0. At θ = π the direction is undefined; any one of length π says "180° off".

    >>> e1, e2 = tangent_basis(0.0, 0.0, 1.0)
    >>> [round(abs(v), 6) for v in tangent_residual(e1, e2, (0.0, 0.0, 1.0), (0.0, 0.0, -1.0))]
    [3.141593, 0.0]
    """
    y0 = e1[0] * b[0] + e1[1] * b[1] + e1[2] * b[2]
    y1 = e2[0] * b[0] + e2[1] * b[1] + e2[2] * b[2]
    sin_t = math.hypot(y0, y1)
    cos_t = p[0] * b[0] + p[1] * b[1] + p[2] * b[2]
    if sin_t < 1e-12:
        return (y0, y1) if cos_t > 0.0 else (math.pi, 0.0)
    scale = math.atan2(sin_t, cos_t) / sin_t
    return y0 * scale, y1 * scale


def symmetrize(p: Array) -> Array:
    """(p + pᵀ)/2 as a new array.

    Written for speed on a 6×6, where call overhead is everything: an in-place ``p += p.T``
    (exact: numpy buffers the overlapping operand) and ``p + p.T`` take the slow strided
    path, and multiplying by a scalar converts it first; copying the transpose and scaling by
    a constant array is about twice as fast.
    """
    s = p.T.copy()
    s += p
    s *= _HALF6
    return s
