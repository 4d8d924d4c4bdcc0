"""The MEKF's covariance propagation in compiled code (numba).

Why: a gyro step runs at the gyro rate, and its covariance part — Φ from the step's rotation,
P ← Φ P Φᵀ + Q, symmetrised — cost ~3.9 µs in numpy on 6×6 arrays, nearly all of it per-call
overhead, against ~0.9 µs compiled (measured in a loop of 20 000 calls on this 2-core VM).
In Basilisk's loop that is a fifth of a gyro-only ``UpdateState``. Φ and Q are
:func:`adfusion.estimation.common.phi_rows` and
:func:`~adfusion.estimation.mekf.process_noise` written out; the products exploit Φ's
``[0 I]`` bottom rows. The result agrees with the numpy expression to rounding (a few
ulp; ``tests/test_mekf.py``). Compiled on first use after an install or an edit (~0.9 s),
then loaded from numba's on-disk cache (~0.25 s); :func:`warm_up` does it at a setup step
(the replay's, ``AdfusionNav``'s) rather than in the first gyro step.

Example:
    >>> import numpy as np
    >>> from adfusion.estimation.mekf_kernels import covariance_step
    >>> p = covariance_step(np.eye(6) * 1e-6, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0)
    >>> bool(np.allclose(p[:3, :3], np.eye(3) * 1e-6 * (1 + 0.01)))  # attitude gains dt² σ_b²
    True
"""

from __future__ import annotations

import math

import numpy as np

from adfusion.starid.jit_cache import njit_cached

__all__ = ["covariance_step", "warm_up"]


def warm_up() -> None:
    """Load (or, once after an install, compile) :func:`covariance_step` now, not in the
    first gyro step: ~0.25 s from numba's cache, ~0.9 s compiling.

    >>> warm_up()
    """
    covariance_step(np.eye(6), 0.1, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit_cached(nogil=True)  # keyed by this file's contents, shipped compiled (jit_cache)
def covariance_step(P: np.ndarray, dt: float, tx: float, ty: float, tz: float,
                    sv2: float, su2: float) -> np.ndarray:
    """Φ P Φᵀ + Q, symmetrised, for a step θ = (tx, ty, tz) = ω̂·dt of length ``dt`` (s),
    with ARW² ``sv2`` and RRW² ``su2`` (Farrenkopf's Q); a new 6×6 array."""
    n2 = tx * tx + ty * ty + tz * tz
    n = math.sqrt(n2)
    if n < 1e-3:  # series_coeffs' branches, the same expressions
        a = 1.0 - n2 / 6.0 + n2 * n2 / 120.0
        c = 0.5 - n2 / 24.0 + n2 * n2 / 720.0
        d = 1.0 / 6.0 - n2 / 120.0 + n2 * n2 / 5040.0
    else:
        s, co = math.sin(n), math.cos(n)
        a, c, d = s / n, (1.0 - co) / (n * n), (n - s) / (n * n * n)
    xx, yy, zz, xy, xz, yz = tx * tx, ty * ty, tz * tz, tx * ty, tx * tz, ty * tz
    a_d = 1.0 - c * n2
    b_d = dt * (1.0 - d * n2)
    cd, dd = c * dt, d * dt
    f = np.empty((3, 6))  # Φ's top rows (phi_rows)
    f[0, 0], f[0, 1], f[0, 2] = a_d + c * xx, a * tz + c * xy, -a * ty + c * xz
    f[0, 3], f[0, 4], f[0, 5] = b_d + dd * xx, cd * tz + dd * xy, -cd * ty + dd * xz
    f[1, 0], f[1, 1], f[1, 2] = -a * tz + c * xy, a_d + c * yy, a * tx + c * yz
    f[1, 3], f[1, 4], f[1, 5] = -cd * tz + dd * xy, b_d + dd * yy, cd * tx + dd * yz
    f[2, 0], f[2, 1], f[2, 2] = a * ty + c * xz, -a * tx + c * yz, a_d + c * zz
    f[2, 3], f[2, 4], f[2, 5] = cd * ty + dd * xz, -cd * tx + dd * yz, b_d + dd * zz
    fp = np.empty((3, 6))  # the top rows of Φ P (its bottom rows are P's)
    for i in range(3):
        for j in range(6):
            acc = 0.0
            for k in range(6):
                acc += f[i, k] * P[k, j]
            fp[i, j] = acc
    out = np.empty((6, 6))
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(6):
                acc += fp[i, k] * f[j, k]
            out[i, j] = acc
            out[i, 3 + j] = fp[i, 3 + j]
            out[3 + i, j] = fp[j, 3 + i]
            out[3 + i, 3 + j] = P[3 + i, 3 + j]
    qa = sv2 * dt + su2 * dt ** 3 / 3.0
    qc = su2 * dt ** 2 / 2.0
    qd = su2 * dt
    for i in range(3):
        out[i, i] += qa
        out[i, 3 + i] += qc
        out[3 + i, i] += qc
        out[3 + i, 3 + i] += qd
    for i in range(6):
        for j in range(i + 1, 6):
            m = 0.5 * (out[i, j] + out[j, i])
            out[i, j] = m
            out[j, i] = m
    return out
