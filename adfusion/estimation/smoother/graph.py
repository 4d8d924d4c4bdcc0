"""The factor graph of a log: which frames get states, initial values from the filter or
the gyro, and one frame's factors at a time (batch or iSAM2)."""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from adfusion.estimation.smoother.factors import q_of, robust_noise, rot3, symbols, wnoa_factor
from adfusion.estimation.smoother.inputs import FrameData, SmootherError, SmootherInput
from adfusion.estimation.smoother.noise import star_covariances
from adfusion.maths import rotations as rot

Array = NDArray[np.float64]


class GraphModel:
    """Builds the factors and initial values of :func:`smooth`, one frame at a time."""

    def __init__(self, inp: SmootherInput, t: Array, q0: list, bias0: Array, omega: Array,
                 pims: list, sigma0: float, kstreak: float, star_model: str, robust: str,
                 robust_k: float, sigma_bias0: float, rate_walk: float,
                 sigma_rate0: float) -> None:
        import gtsam

        self.inp, self.t, self.q0, self.bias0, self.omega = inp, t, q0, bias0, omega
        self.pims, self.sigma0, self.kstreak = pims, sigma0, kstreak
        self.star_model, self.robust, self.robust_k = star_model, robust, robust_k
        self.sigma_bias0, self.rate_walk, self.sigma_rate0 = sigma_bias0, rate_walk, sigma_rate0
        n = len(t)
        self.star_factors: list[list[tuple[Any, Any, int]]] = [[] for _ in range(n)]
        self.n_star = np.zeros(n, dtype=np.int64)  # star factors per frame (a fix: none)
        self.m_t, self.m_b, self.m_r = inp.mag
        self.m_frame = nearest_frame(t, self.m_t)
        self.mag_model = robust_noise(gtsam.noiseModel.Isotropic.Sigma(2, inp.sigma_mag_rad),
                                       robust, robust_k)

    def steps(self, keep: NDArray[np.bool_]) -> list[tuple[Any, Any]]:
        """(new factors, new values) per kept frame, in time order (iSAM2's updates)."""
        out, prev = [], None
        for k in np.flatnonzero(keep):
            out.append(self.frame(int(k), prev))
            prev = int(k)
        return out

    def frame(self, k: int, prev: int | None) -> tuple[Any, Any]:
        import gtsam

        R_key, B_key, W_key = symbols()
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        f, t = self.inp.frames[k], self.t
        R0 = rot3(self.q0[k])
        values.insert(R_key(k), R0)
        if self.inp.video_only:
            values.insert(W_key(k), self.omega[k])
            if prev is None:
                graph.add(gtsam.PriorFactorVector(W_key(k), self.omega[k], gtsam.noiseModel.
                                                  Isotropic.Sigma(3, self.sigma_rate0)))
            else:
                graph.add(wnoa_factor([R_key(prev), W_key(prev), R_key(k), W_key(k)],
                                       t[k] - t[prev], self.rate_walk**2))
        else:
            values.insert(B_key(k), self.bias0[k])
            if prev is None:
                graph.add(gtsam.PriorFactorVector(B_key(k), self.bias0[k], gtsam.noiseModel.
                                                  Isotropic.Sigma(3, self.sigma_bias0)))
            else:
                sigma = max(self.inp.rrw * math.sqrt(t[k] - t[prev]), 1e-12)
                graph.add(gtsam.BetweenFactorVector(B_key(prev), B_key(k), np.zeros(3),
                                                    gtsam.noiseModel.Isotropic.Sigma(3, sigma)))
                if prev == k - 1 and self.pims[k] is not None:
                    graph.add(gtsam.AHRSFactor(R_key(prev), R_key(k), B_key(prev),
                                               self.pims[k]))
        self._stars(graph, k, f, R0)
        for j in np.flatnonzero(self.m_frame == k):
            # the field direction carried to the frame time: R(t_m) = R(t_k)·Exp(ω Δt)
            bm = rot.rotate(rot.exp_map(-self.omega[k] * (self.m_t[j] - t[k])), self.m_b[j])
            graph.add(gtsam.AttitudeFactorRot3(R_key(k), gtsam.Unit3(self.m_r[j]),
                                               self.mag_model, gtsam.Unit3(bm)))
        return graph, values

    def _stars(self, graph: Any, k: int, f: FrameData, R0: Any) -> None:
        import gtsam

        key = symbols()[0](k)
        if f.q_fix is not None and f.cov_fix is not None and (
                self.star_model == "fix" or f.n_stars < 2):
            base = gtsam.noiseModel.Gaussian.Covariance(f.cov_fix)
            fac = gtsam.PriorFactorRot3(key, rot3(f.q_fix),
                                        robust_noise(base, self.robust, self.robust_k))
            graph.add(fac)
            self.star_factors[k].append((fac, base, -1))
            return
        if not f.n_stars:
            return
        R0m = R0.matrix()
        covs = star_covariances(f.b_body, self.omega[k], self.sigma0, self.kstreak)
        for b, r, sid, cov in zip(f.b_body, f.r_icrs, f.ids, covs, strict=True):
            u = gtsam.Unit3(r)
            basis = u.basis()  # the factor's 2-D error lives in nRef's tangent basis
            base = gtsam.noiseModel.Gaussian.Covariance(basis.T @ R0m @ cov @ R0m.T @ basis)
            fac = gtsam.AttitudeFactorRot3(key, u, robust_noise(base, self.robust, self.robust_k),
                                           gtsam.Unit3(b))
            graph.add(fac)
            self.star_factors[k].append((fac, base, int(sid)))
        self.n_star[k] = f.n_stars


def anchored_components(anchored: list[bool], linked: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Frames in a run of motion-linked frames (``linked[k]``: k−1 → k) holding an anchor.

    >>> anchored_components([False, True, False, False], np.array([True, True, False, True]))
    array([ True,  True, False, False])
    """
    keep = np.zeros(len(anchored), dtype=bool)
    start = 0
    for k in range(1, len(anchored) + 1):
        if k == len(anchored) or not linked[k]:
            keep[start:k] = any(anchored[start:k])
            start = k
    return keep


def initial_attitudes(frames: list[FrameData], t: Array) -> tuple[list, Array]:
    """Per frame the filter's estimate, else the fix, else a Wahba fit of its stars (None
    where there is nothing); biases from the nearest frame that has one (else zero)."""
    from adfusion.maths.attitude import wahba_unit

    q0: list[Array | None] = []
    for f in frames:
        q = f.q_init if f.q_init is not None else f.q_fix
        if q is None and f.n_stars >= 2:
            try:
                q = wahba_unit(f.b_body, f.r_icrs, 1.0).q_cam_icrs  # "camera" = body here
            except (ValueError, np.linalg.LinAlgError):
                q = None  # collinear: this frame cannot start itself
        q0.append(q)
    if all(q is None for q in q0):
        raise SmootherError("no frame has an estimate, a fix or two non-collinear stars to "
                            "start from")
    have_b = [k for k, f in enumerate(frames) if f.bias_init is not None]
    bias = np.zeros((len(frames), 3))
    if have_b:
        idx = np.array(have_b)
        near = idx[np.clip(np.searchsorted(t[idx], t), 0, len(idx) - 1)]
        bias = np.array([frames[j].bias_init for j in near])
    return q0, bias


def fill_by_gyro(frames: list[FrameData], q0: list, pims: list) -> list:
    """Frames without a filter estimate start from a neighbour carried by the gyro."""
    q = list(q0)
    if all(x is not None for x in q):
        return q
    for k in range(1, len(q)):  # forward: R_k = R_{k−1} ΔR
        if q[k] is None and q[k - 1] is not None and pims[k] is not None:
            q[k] = q_of(rot3(q[k - 1]).compose(pims[k].deltaRij()))
    for k in range(len(q) - 2, -1, -1):  # backward: R_k = R_{k+1} ΔRᵀ
        if q[k] is None and q[k + 1] is not None and pims[k + 1] is not None:
            q[k] = q_of(rot3(q[k + 1]).compose(pims[k + 1].deltaRij().inverse()))
    for k in range(len(q)):  # cut off by a gyro gap: the nearest known attitude
        if q[k] is None:
            known = [j for j in range(len(q)) if q[j] is not None]
            q[k] = q[min(known, key=lambda j: abs(j - k))]
    return q


def frame_rates(t: Array, q0: list, bias0: Array, g_t: Array, g_w: Array,
                 video: bool) -> Array:
    """Body rate at each frame: the gyro minus bias, or (video-only) differences of the
    starting attitudes."""
    n = len(t)
    if not video:
        return np.column_stack([np.interp(t, g_t, g_w[:, i]) for i in range(3)]) - bias0
    known = [k for k in range(n) if q0[k] is not None]
    w = np.zeros((n, 3))
    if len(known) < 2:
        return w
    ws = []
    for a, b in itertools.pairwise(known):
        # R_icrs_body_b = R_icrs_body_a · Exp(ω Δt)  ⇔  q_a ⊗ q_b⁻¹ = Exp(ω Δt)
        ws.append(rot.log_map(rot.multiply(q0[a], rot.inverse(q0[b]))) / (t[b] - t[a]))
    ws = np.array(ws)
    tm = np.array([0.5 * (t[a] + t[b]) for a, b in itertools.pairwise(known)])
    return np.column_stack([np.interp(t, tm, ws[:, i]) for i in range(3)])


def fill_by_rate(frames: list[FrameData], t: Array, q0: list, omega: Array) -> list:
    """Video-only: frames without an estimate start from the nearest one, turned at its rate."""
    known = [k for k in range(len(q0)) if q0[k] is not None]
    q = list(q0)
    for k in range(len(q)):
        if q[k] is None:
            j = min(known, key=lambda i: abs(t[i] - t[k]))
            q[k] = rot.multiply(rot.exp_map(-omega[j] * (t[k] - t[j])), q0[j])
    return q


def nearest_frame(t: Array, tm: Array) -> NDArray[np.int64]:
    """Index of the frame nearest each time; −1 beyond half a frame spacing of the ends."""
    if len(tm) == 0:
        return np.empty(0, dtype=np.int64)
    i = np.clip(np.searchsorted(t, tm), 1, max(len(t) - 1, 1)) if len(t) > 1 else \
        np.zeros(len(tm), dtype=np.int64)
    if len(t) > 1:
        i = np.where(np.abs(t[i - 1] - tm) <= np.abs(t[i] - tm), i - 1, i)
        half = 0.5 * float(np.median(np.diff(t)))
    else:
        half = 0.5
    return np.where(np.abs(t[i] - tm) <= half + 1e-9, i, -1).astype(np.int64)
