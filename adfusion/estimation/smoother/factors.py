"""GTSAM pieces: symbols, Rot3 ↔ quaternion, robust kernels, the gyro preintegration and
the constant-rate (white-noise-on-acceleration) factor of video-only logs."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from adfusion.maths import rotations as rot

Array = NDArray[np.float64]


def symbols():
    import gtsam

    return (lambda k: gtsam.symbol("r", k), lambda k: gtsam.symbol("b", k),
            lambda k: gtsam.symbol("w", k))


def rot3(q_body_icrs: Array):
    """GTSAM Rot3 ``R_icrs_body`` (nRb) of a ``q_body_icrs``."""
    import gtsam

    w, x, y, z = rot.normalize(q_body_icrs)
    return gtsam.Rot3.Quaternion(float(w), float(-x), float(-y), float(-z))


def q_of(r3) -> Array:
    """``q_body_icrs`` of a GTSAM ``R_icrs_body``."""
    g = r3.toQuaternion()
    return rot.canonical(np.array([g.w(), -g.x(), -g.y(), -g.z()]))


def robust_noise(base, kind: str, k: float):
    import gtsam

    if kind == "none":
        return base
    est = {"huber": gtsam.noiseModel.mEstimator.Huber,
           "cauchy": gtsam.noiseModel.mEstimator.Cauchy}[kind].Create(k)
    return gtsam.noiseModel.Robust.Create(est, base)


def wnoa_factor(keys: list[int], dt: float, q: float):
    """White-noise-on-acceleration prior between (R_i, ω_i) and (R_j, ω_j)
    (docs/concepts/smoother.md)."""
    import gtsam

    i3 = np.eye(3)
    cov = np.kron(np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]) * q, i3)
    model = gtsam.noiseModel.Gaussian.Covariance(cov)
    logmap, dlog = gtsam.Rot3.Logmap, gtsam.Rot3.LogmapDerivative
    k_ri, k_wi, k_rj, k_wj = keys

    def error(this, values, H):
        ri, rj = values.atRot3(k_ri), values.atRot3(k_rj)
        wi, wj = values.atVector(k_wi), values.atVector(k_wj)
        xi = logmap(ri.between(rj))
        jr_inv = dlog(xi)
        e = np.concatenate([xi - dt * wi, jr_inv @ wj - wi])
        if H is not None:
            jl_inv = dlog(-xi)
            x, y, z = 0.5 * wj
            half = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])  # ½[ω_j]×
            H[0] = np.vstack([-jl_inv, half @ jl_inv])
            H[1] = np.vstack([-dt * i3, -i3])
            H[2] = np.vstack([jr_inv, -half @ jr_inv])
            H[3] = np.vstack([np.zeros((3, 3)), jr_inv])
        return e

    return gtsam.CustomFactor(model, keys, error)


def preintegrate(t: Array, g_t: Array, g_w: Array, bias0: Array, arw: float,
                  max_gap: float, problems: list[str]) -> list[Any]:
    """One ``PreintegratedAhrsMeasurements`` per frame interval (index k: from k−1 to k)."""
    import gtsam

    params = gtsam.PreintegratedRotationParams()
    params.setGyroscopeCovariance(max(arw, 1e-12) ** 2 * np.eye(3))
    out: list[Any] = [None] * len(t)
    gaps = []
    for k in range(1, len(t)):
        a, b = t[k - 1], t[k]
        inside = g_t[(g_t > a) & (g_t < b)]
        knots = np.concatenate([[a], inside, [b]])
        lo = np.searchsorted(g_t, a, side="right") - 1
        hi = np.searchsorted(g_t, b, side="left")
        # the gyro must cover the interval: samples at or around both ends, no long hole
        before = g_t[lo] if lo >= 0 else -np.inf
        after = g_t[hi] if hi < len(g_t) else np.inf
        span = np.diff(np.concatenate([[before], inside, [after]]))
        if not np.all(span <= max_gap):
            gaps.append((a, b))
            continue
        rates = np.column_stack([np.interp(knots, g_t, g_w[:, i]) for i in range(3)])
        pim = gtsam.PreintegratedAhrsMeasurements(params, bias0[k - 1])
        for j in range(len(knots) - 1):
            dt = knots[j + 1] - knots[j]
            if dt > 0:
                pim.integrateMeasurement(0.5 * (rates[j] + rates[j + 1]), dt)
        out[k] = pim
    if gaps:
        problems.append(f"no gyro over {len(gaps)} frame interval(s), first "
                        f"{gaps[0][0]:.3f}–{gaps[0][1]:.3f} s: no motion constraint there")
    return out
