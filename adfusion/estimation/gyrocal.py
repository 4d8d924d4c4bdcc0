"""Gyro calibration from the star fixes: scale factors, misalignment and bias over a whole
log (issue 35).

A gyro measures ``ω_m = (I + K) ω + β + η``: ``K`` holds the scale-factor errors (its
diagonal, 10³–10⁴ ppm on real units) and the axis misalignment (off the diagonal, mrad),
``β`` the bias (taken constant over the log), ``η`` the angle random walk's white rate.
Between two star fixes the gyro, corrected by ``(K, β)``, must turn the body as the fixes
say. :func:`gyro_calibration` fits the 12 terms to that, by Gauss–Newton over every
interval between consecutive fixes at once, and weighs the residuals as they are
correlated: the interval ``k``'s residual is ``e_{k+1} − e_k + w_k`` (each fix's error
``e`` is shared by the two intervals it ends and starts), so their covariance is
tridiagonal, ``2σ_fix² + σ_arw²·Δt`` on the diagonal and ``−σ_fix²`` beside it, and the
least squares is generalised by it (not the plain sum of squares, which would claim
twice the information).

A term the motion does not excite (the scale of an axis about which the vehicle never
turned, the misalignment between two axes never turned about together, the scale of a
spin axis at a constant rate, which looks like a bias) has a 1σ as large as its plausible
range: it is reported as unobservable (:attr:`GyroCalibration.weak`, its value NaN), and
the others are fitted without it — taken out one at a time, the least determined scale or
misalignment first, a bias only when no such term is left. The bias fitted then holds
what the unexcited terms did: at a constant spin ``ω_z``, ``β + K[·2]·ω_z``, the offset
the gyro had in this log.

Example:
    >>> import numpy as np
    >>> from adfusion.maths import rotations as rot
    >>> t = np.arange(0, 120, 0.02)                                   # 50 Hz, 2 min
    >>> omega = np.stack([0.05 * np.sin(0.11 * t), 0.04 * np.cos(0.07 * t),
    ...                   0.06 * np.sin(0.05 * t + 1)], 1)            # rad/s, body
    >>> K = np.array([[4e-3, 2e-3, 0], [-1e-3, -3e-3, 1e-3], [0, 2e-3, 5e-3]])
    >>> meas = omega @ (np.eye(3) + K).T + [1e-4, -2e-4, 5e-5]
    >>> q = [np.array([1.0, 0, 0, 0])]
    >>> for a, b in zip(omega[:-1], omega[1:]):                       # the true attitude
    ...     q.append(rot.multiply(rot.exp_map(-(a + b) * 0.01), q[-1]))
    >>> fix = slice(0, None, 50)                                      # a fix a second
    >>> cal = gyro_calibration(t, meas, t[fix], np.array(q)[fix], sigma_fix_rad=1e-6,
    ...                        arw_rad_sqrt_s=1e-7)
    >>> cal.observable, bool(np.abs(cal.K - K).max() < 1e-4)
    (True, True)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import solveh_banded

from adfusion.maths import rotations as rot

__all__ = ["GyroCalibration", "gyro_calibration"]

Array = NDArray[np.float64]

#: a scale or misalignment term whose 1σ exceeds this is not determined (2 %: above any
#: real gyro's error, so a value that uncertain says nothing)
WEAK_K_SIGMA = 0.02
#: a bias whose 1σ exceeds this (rad/s, ~40°/h) is not determined
WEAK_BIAS_SIGMA = 2e-4

_NAMES = [f"K[{i}{j}]" for i in range(3) for j in range(3)] + ["bias x", "bias y", "bias z"]


@dataclass
class GyroCalibration:
    """``ω = (I + K)⁻¹ (ω_m − β)``: the fitted gyro (body axes, rad/s).

    Attributes:
        K: scale factors (diagonal) and misalignment (off-diagonal), 3×3; NaN where not
            determined.
        bias_rad_s: ``β``; NaN where not determined.
        cov: 12×12 covariance of (K row by row, β); NaN rows for undetermined terms.
        residual_before_rad / residual_after_rad: RMS interval residual with ``K = 0``
            and the log's mean bias fitted alone, and with the whole fit.
        observable: every term determined; weak: those that are not, by name.
        intervals: intervals between fixes used.
    """

    K: Array
    bias_rad_s: Array
    cov: Array
    residual_before_rad: float
    residual_after_rad: float
    observable: bool
    weak: list[str] = field(default_factory=list)
    intervals: int = 0

    @property
    def scale_ppm(self) -> Array:
        return np.diag(self.K) * 1e6

    def correct(self, omega_meas_rad_s: ArrayLike) -> Array:
        """``(I + K)⁻¹ (ω_m − β)`` (undetermined terms taken as 0)."""
        k = np.nan_to_num(self.K)
        b = np.nan_to_num(self.bias_rad_s)
        w = np.asarray(omega_meas_rad_s, dtype=np.float64)
        return np.linalg.solve(np.eye(3) + k, (w - b).T).T


def _intervals(t_gyro: Array, omega: Array, t_fix: Array) -> tuple[Array, Array, Array]:
    """The gyro's rate at the nodes of each interval between consecutive fixes (the fix
    times and the samples between, the rate at a fix interpolated), padded to one length:
    ``(ω (n, m + 1, 3), dt (n, m), kept)``; ``kept`` the intervals the samples cover."""
    n = len(t_fix) - 1
    lo = np.searchsorted(t_gyro, t_fix, side="right")  # the first sample after each fix
    m = int(np.max(lo[1:] - lo[:-1])) + 1
    w = np.zeros((n, m + 1, 3))
    dt = np.zeros((n, m))
    kept = (t_fix[:-1] >= t_gyro[0]) & (t_fix[1:] <= t_gyro[-1])
    for k in np.flatnonzero(kept):
        times = np.concatenate([[t_fix[k]], t_gyro[lo[k]:lo[k + 1]], [t_fix[k + 1]]])
        times = times[np.concatenate([[True], np.diff(times) > 0])]  # a sample at a fix
        nodes = np.stack([np.interp(times, t_gyro, omega[:, i]) for i in range(3)], 1)
        w[k, :len(times)] = nodes
        w[k, len(times):] = nodes[-1]
        dt[k, :len(times) - 1] = np.diff(times)
    return w, dt, kept


def _turns(w: Array, dt: Array, k: Array, bias: Array) -> Array:
    """The body's turn over each interval from the corrected gyro, ``R_{k+1} R_kᵀ``
    (P, n, 3, 3), for ``P`` parameter sets ``k`` (P, 3, 3) and ``bias`` (P, 3); ``w``
    (n, m + 1, 3) and ``dt`` (n, m) as :func:`_intervals` gives them. Each step takes the
    mean of its two rates and the coning term ``(ω_j × ω_{j+1}) dt² / 12`` (Bortz): a
    spinning, coning body turns ~1 mrad a second away from a held rate at 200 Hz."""
    inv = np.linalg.inv(np.eye(3) + k)  # (P, 3, 3)
    corr = np.einsum("pab,pnmb->pnma", inv, w[None] - bias[:, None, None, :])
    # R_body_icrs turns as dR/dt = −[ω×] R: over a step, R ← exp(−φ) R
    r = np.broadcast_to(np.eye(3), (len(k), len(w), 3, 3)).copy()
    for j in range(dt.shape[1]):
        a, b = corr[:, :, j, :], corr[:, :, j + 1, :]
        h = dt[None, :, j, None]
        phi = 0.5 * (a + b) * h + np.cross(a, b) * h**2 / 12.0
        r = rot.to_matrix(rot.exp_map(-phi)) @ r
    return r


def _least_determined(active: Array, ratio: Array, cov: Array, sd: Array) -> int:
    """Which undetermined term to take out (an index into ``active``): the least
    determined scale or misalignment term; when only a bias is undetermined, the scale or
    misalignment term it cannot be told from (correlation > 0.9: a constant spin about z
    makes ``K[i2]·ω_z`` a bias on axis i), else that bias. Every gyro has a bias; not
    every log excites a scale."""
    k_weak = (active < 9) & (ratio > 1)
    if k_weak.any():
        pick = np.flatnonzero(k_weak)
        return int(pick[np.argmax(ratio[pick])])
    worst = int(np.argmax(ratio))
    corr = np.abs(cov[worst]) / np.maximum(sd[worst] * sd, 1e-300)
    corr[active >= 9] = 0.0
    partner = int(np.argmax(corr))
    return partner if corr[partner] > 0.9 else worst


def gyro_calibration(t_gyro_s: ArrayLike, omega_meas_rad_s: ArrayLike, t_fix_s: ArrayLike,
                     q_fix_body_icrs: ArrayLike, *, sigma_fix_rad: float,
                     arw_rad_sqrt_s: float, iterations: int = 24) -> GyroCalibration:
    """Scale factors, misalignment and bias of a gyro (``omega_meas_rad_s`` (N, 3) at
    ``t_gyro_s``) from star fixes (``q_fix_body_icrs`` (M, 4) at ``t_fix_s``, each good
    to ``sigma_fix_rad`` per axis), the gyro's angle random walk ``arw_rad_sqrt_s`` given.
    See the module's text for the method and an example."""
    tg = np.asarray(t_gyro_s, dtype=np.float64)
    wm = np.asarray(omega_meas_rad_s, dtype=np.float64).reshape(-1, 3)
    tf = np.asarray(t_fix_s, dtype=np.float64)
    qf = rot.normalize(np.asarray(q_fix_body_icrs, dtype=np.float64).reshape(-1, 4))
    if len(tf) < 6 or len(qf) != len(tf):
        raise ValueError(f"gyro calibration needs ≥ 6 fixes with their times, got {len(qf)} "
                         f"and {len(tf)}")
    if len(tg) != len(wm) or np.any(np.diff(tg) <= 0) or np.any(np.diff(tf) <= 0):
        raise ValueError("gyro and fix times must increase, one per sample")
    w, dt, kept = _intervals(tg, wm, tf)
    r_fix = rot.to_matrix(qf)
    target = r_fix[1:] @ np.swapaxes(r_fix[:-1], -1, -2)  # R_{k+1} R_kᵀ, per the fixes
    w, dt, target = w[kept], dt[kept], target[kept]
    n = len(w)
    span = dt.sum(axis=1)
    # the residuals' covariance per axis: tridiagonal (consecutive intervals share a fix)
    diag = 2 * sigma_fix_rad**2 + arw_rad_sqrt_s**2 * span
    band = np.zeros((2, n))
    band[1] = diag
    band[0, 1:] = -sigma_fix_rad**2
    contiguous = np.flatnonzero(kept)
    band[0, 1:][np.diff(contiguous) != 1] = 0.0  # a gap: the two share no fix

    def residual(theta: Array) -> Array:
        """(P, n, 3) rotation-vector residuals for P parameter sets (P, 12)."""
        est = _turns(w, dt, theta[:, :9].reshape(-1, 3, 3), theta[:, 9:])
        return rot.log_map(rot.from_matrix(target[None] @ np.swapaxes(est, -1, -2)))

    def gls(j: Array, r: Array) -> tuple[Array, Array]:
        """``JᵀΣ⁻¹J`` and ``JᵀΣ⁻¹r`` (axes independent, one band for all)."""
        cols = j.shape[-1]
        sj = solveh_banded(band, j.reshape(n, 3 * cols))
        sr = solveh_banded(band, r)
        info = np.einsum("nac,nad->cd", j, sj.reshape(n, 3, cols))
        return info, np.einsum("nac,na->c", j, sr)

    theta = np.zeros(12)
    # the log's mean bias alone first (K = 0): where it starts, and the "before" residual
    r0 = residual(theta[None])[0]
    theta[9:] = -r0.sum(0) / span.sum()
    r_before = residual(theta[None])[0]
    active = np.arange(12)
    info = np.eye(12)
    for _ in range(iterations):
        eps = np.where(active >= 9, 1e-7, 1e-5)
        probes = np.repeat(theta[None], len(active) + 1, axis=0)
        probes[np.arange(1, len(active) + 1), active] += eps
        res = residual(probes)
        jac = (res[1:] - res[0]).transpose(1, 2, 0) / eps  # (n, 3, P)
        info, g = gls(jac, -res[0])
        cov_now = np.linalg.pinv(info)
        sd = np.sqrt(np.maximum(np.diag(cov_now), 0))
        ratio = sd / np.where(active >= 9, WEAK_BIAS_SIGMA, WEAK_K_SIGMA)
        if np.any(ratio > 1):  # before any step: a step along an undetermined term is noise
            out = _least_determined(active, ratio, cov_now, sd)
            theta[active[out]] = 0.0
            active = np.delete(active, out)
            continue
        step = np.linalg.solve(info, g)
        theta[active] += step
        if np.all(np.abs(step) < 1e-9):
            break
    cov = np.full((12, 12), np.nan)
    cov[np.ix_(active, active)] = np.linalg.pinv(info)
    values = np.full(12, np.nan)
    values[active] = theta[active]
    r_after = residual(np.nan_to_num(values)[None])[0]
    weak = [f"{_NAMES[i]}: not excited by this motion" for i in range(12) if i not in active]
    return GyroCalibration(values[:9].reshape(3, 3), values[9:], cov,
                           float(np.sqrt(np.mean(r_before**2))),
                           float(np.sqrt(np.mean(r_after**2))), not weak, weak, n)
