"""Star noise from the log itself: the anisotropic (along / across the image motion) model
and its calibration without the truth (docs/concepts/smoother.md says why)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from adfusion.maths import rotations as rot

Array = NDArray[np.float64]


def calibrate_star_noise(
    b_list: list[Array], r_list: list[Array], omega_list: list[Array],
) -> tuple[float, float, int]:
    """Fit the star-direction noise model ``σ0²·(I − bbᵀ) + (k·s)²·v̂v̂ᵀ`` from per-frame fits.

    ``b_list``/``r_list``: per frame, the body and ICRS unit vectors of its stars;
    ``omega_list``: per frame, the body rate (rad/s) that moves the stars across the image
    (``v = −ω × b``, speed ``s = |v|``). Each frame with ≥ 3 stars is fitted (Wahba), its
    residuals split along and across each star's motion. The fit absorbs part of the noise,
    and with anisotropic noise an equal-weight fit also leaks along-motion error into the
    across-motion residuals, so the fits are redone with the model's weights (one
    Gauss–Newton step from the equal-weight solution), and each squared residual is divided
    by ``1 − h`` (its leverage in that weighted fit). Then, trimming at 4σ of the current
    model, ``σ0²`` is the mean across-motion square and ``k²`` the least-squares slope of
    (along² − σ0²) on ``s²``; three rounds.

    Returns (σ0 rad, k s, number of residuals used); NaNs and 0 without a usable frame.

    >>> import numpy as np
    >>> from adfusion.starid import rotations as rot
    >>> rng = np.random.default_rng(1)
    >>> r = [rot.radec_to_vector(rng.uniform(0, 0.3, 12), rng.uniform(0, 0.3, 12))
    ...      for _ in range(200)]
    >>> b = [v + rng.normal(0, 2e-4, v.shape) for v in r]
    >>> s0, k, n = calibrate_star_noise(b, r, [np.zeros(3)] * 200)
    >>> round(s0 / 2e-4, 1), k, n
    (1.0, 0.0, 2400)
    """
    from adfusion.maths.attitude import wahba_unit

    rows = []  # per star: frame, predicted direction, residual, motion basis, speed
    nf = 0
    for b, r, w in zip(b_list, r_list, omega_list, strict=True):
        if len(b) < 3:
            continue
        try:
            q = wahba_unit(b, r, 1.0).q_cam_icrs  # "camera" = body here
        except (ValueError, np.linalg.LinAlgError):
            continue  # collinear stars: this frame says nothing about the noise
        pred = rot.rotate(q, r)
        rows.append((np.full(len(b), nf), pred, b - pred, -np.cross(w, b)))
        nf += 1
    if not rows:
        return float("nan"), float("nan"), 0
    fidx = np.concatenate([x[0] for x in rows])
    pred = np.concatenate([x[1] for x in rows])
    e = np.concatenate([x[2] for x in rows])
    v = np.concatenate([x[3] for x in rows])
    s = np.linalg.norm(v, axis=1)
    # motion direction; for a still star any tangent direction will do
    other = np.where(np.abs(pred[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    vhat = np.where(s[:, None] > 1e-12, v, np.cross(pred, other))
    vhat /= np.linalg.norm(vhat, axis=1, keepdims=True)
    uhat = np.cross(pred, vhat)
    basis = np.stack([vhat, uhat], axis=1)  # (M, 2, 3): along, across
    y0 = np.einsum("mci,mi->mc", basis, e)
    jac = np.einsum("mci,mij->mcj", basis, rot.skew(pred))  # e ← e + [p]× δ for R ← Exp(δ)R
    w8 = np.ones_like(y0)
    s0sq, k2, keep = float("nan"), 0.0, np.ones(len(s), dtype=bool)
    for _ in range(3):
        jw = jac * w8[:, :, None]
        a = np.zeros((nf, 3, 3))
        g = np.zeros((nf, 3))
        np.add.at(a, fidx, np.einsum("mci,mcj->mij", jw, jac))
        np.add.at(g, fidx, np.einsum("mci,mc->mi", jw, y0))
        a_inv = np.linalg.pinv(a)
        y = y0 - np.einsum("mci,mi->mc", jac, np.einsum("fij,fj->fi", a_inv, g)[fidx])
        lev = w8 * np.einsum("mci,mij,mcj->mc", jac, a_inv[fidx], jac)
        y2 = y**2 / np.clip(1.0 - lev, 0.05, 1.0)
        if not np.isfinite(s0sq):
            s0sq = float(np.median(y2[:, 1]) / 0.4549)  # median of χ²(1): a robust start
        for _ in range(3):
            keep = (y2[:, 1] < 16 * s0sq) & (y2[:, 0] < 16 * (s0sq + k2 * s**2))
            s0sq = float(np.mean(y2[keep, 1]))
            s4 = float(np.sum(s[keep] ** 4))
            k2 = max(0.0, float(np.sum((y2[keep, 0] - s0sq) * s[keep] ** 2)) / s4) \
                if s4 > 0 else 0.0
        w8 = keep[:, None] / np.column_stack([s0sq + k2 * s**2, np.full(len(s), s0sq)])
    return math.sqrt(s0sq), math.sqrt(k2), int(np.sum(keep))


def star_covariances(b: Array, omega: Array, sigma0: float, k: float) -> Array:
    """Per-star 3×3 body-frame direction covariances ``σ0²(I − bbᵀ) + k²·v vᵀ``, with
    ``v = −ω × b`` the star's image motion (so ``k²vvᵀ = (k s)² v̂v̂ᵀ``). Singular along b
    (a direction has no radial error); the factor sees its 2×2 tangent projection."""
    v = -np.cross(omega, b)
    cov = sigma0**2 * (np.eye(3)[None] - b[:, :, None] * b[:, None, :])
    if k > 0:
        cov = cov + (k * k) * v[:, :, None] * v[:, None, :]
    return cov
