"""Magnetometer calibration without the attitude: TWOSTEP (Alonso & Shuster 2002).

A magnetometer with hard iron ``h`` and soft iron ``S`` measures ``B = S·b + h + ε`` (body
frame, nT; :class:`adfusion.sensors.magnetometer.MagnetometerModel`). Whatever the attitude,
the field's magnitude is the model's: ``|P (B − h)| = |H|`` with ``P = I + D`` the symmetric
part of ``S⁻¹`` (its polar factor; the rotation left over is the magnetometer's alignment,
which the magnitude cannot see). TWOSTEP fits ``D`` and ``h`` to ``|H|`` along the
trajectory (the IGRF at each sample's place and time):

1. the *centred* linear estimate: with ``E = 2D + D²`` and ``c = (I + E) h``,
   ``z = |B|² − |H|² = 2 Bᵀc − BᵀEB − |h|²``, and the constant ``|h|²`` drops out of the
   deviations from the (weighted) mean — a linear least-squares problem in ``(c, E)``;
2. Gauss–Newton on the whole model (``|h|² = cᵀ(I + E)⁻¹c`` kept), from step 1, each sample
   weighted by its variance ``4σ²|H|² + 2·3σ⁴`` (+ the reference's ``σ_ref``).

The covariance is the inverse of the information at the solution, carried to ``(h, D)``.
When the samples' directions span too little of the sphere (too little rotation), the soft
iron is not determined: it is then reported as unobservable, not as a value —
:attr:`MagCalibration.observable` ``False``, :attr:`MagCalibration.weak` saying what is
missing, the soft iron's σ NaN — and the hard iron is fitted alone (``P = I``).

Example:
    >>> import numpy as np
    >>> from adfusion.maths import rotations as rot
    >>> rng = np.random.default_rng(1)
    >>> H = np.array([18000.0, 2000.0, -45000.0])                  # nT, one place
    >>> q = rot.normalize(rng.standard_normal((400, 4)))           # every way round
    >>> b_body = rot.rotate(q, H)
    >>> S = np.eye(3) + np.array([[0.05, 0.01, 0], [0.01, -0.03, 0.02], [0, 0.02, 0.04]])
    >>> h = np.array([3000.0, -1500.0, 800.0])
    >>> B = b_body @ S.T + h + rng.normal(0, 30, b_body.shape)
    >>> cal = twostep(B, np.linalg.norm(H), sigma_nT=30.0)
    >>> cal.observable, bool(np.all(np.abs(cal.hard_iron_nT - h) < 4 * cal.hard_iron_sigma_nT))
    (True, True)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["MagAlignment", "MagCalibration", "attitude_aided", "twostep"]

Array = NDArray[np.float64]

#: a term whose 1σ exceeds this is not determined: soft iron (dimensionless) …
WEAK_D_SIGMA = 0.02
#: … and hard iron, as a fraction of the field's magnitude
WEAK_H_SIGMA = 0.02

_IU = np.triu_indices(3)  # the 6 independent entries of a symmetric 3×3, row by row


def _sym(v: Array) -> Array:
    """The symmetric 3×3 of its 6 upper entries (``_IU`` order)."""
    m = np.zeros((3, 3))
    m[_IU] = v
    return m + np.triu(m, 1).T


def _quad_rows(b: Array) -> Array:
    """Rows of ``∂(BᵀEB)/∂E`` for E's upper entries (off-diagonals count twice)."""
    x, y, z = b[:, 0], b[:, 1], b[:, 2]
    return np.stack([x * x, 2 * x * y, 2 * x * z, y * y, 2 * y * z, z * z], axis=1)


@dataclass
class MagCalibration:
    """The fitted calibration: ``b = P (B − h)`` is the corrected field (up to the
    magnetometer's alignment, a rotation the magnitude cannot see).

    Attributes:
        hard_iron_nT: ``h``, nT, body frame.
        soft_iron_inv: ``P = I + D`` (symmetric), the polar factor of ``S⁻¹``.
        cov: 9×9 covariance of ``(h (nT), D's upper entries d11 d12 d13 d22 d23 d33)``.
        residual_before_nT / residual_after_nT: RMS of ``|B| − |H|`` raw and of
            ``|P (B − h)| − |H|`` corrected.
        observable: every term determined (else :attr:`weak` says what is not).
        weak: the reasons the geometry is weak (empty when observable).
        samples: how many samples were used.
    """

    hard_iron_nT: Array
    soft_iron_inv: Array
    cov: Array
    residual_before_nT: float
    residual_after_nT: float
    observable: bool
    weak: list[str] = field(default_factory=list)
    samples: int = 0

    @property
    def hard_iron_sigma_nT(self) -> Array:
        return np.sqrt(np.diag(self.cov)[:3])

    @property
    def soft_iron_sigma(self) -> Array:
        """1σ of ``D``, as a symmetric 3×3."""
        return _sym(np.sqrt(np.diag(self.cov)[3:]))

    def correct(self, b_meas_nT: ArrayLike) -> Array:
        """The corrected field ``P (B − h)`` of measurement(s) (3,) or (N, 3), nT."""
        b = np.asarray(b_meas_nT, dtype=np.float64)
        return (b - self.hard_iron_nT) @ self.soft_iron_inv.T


def twostep(b_meas_nT: ArrayLike, b_ref_norm_nT: ArrayLike, *, sigma_nT: float,
            sigma_ref_nT: float = 0.0, soft_iron: bool = True,
            iterations: int = 20) -> MagCalibration:
    """Hard and soft iron from measurements ``b_meas_nT`` (N, 3) and the reference field's
    magnitude ``b_ref_norm_nT`` (N,) or one value (the IGRF along the trajectory);
    ``sigma_nT`` is the magnetometer's noise per axis, ``sigma_ref_nT`` the reference
    magnitude's error (the IGRF's, tens to hundreds of nT near the ground);
    ``soft_iron=False`` fits the hard iron alone (``P = I``). When the samples do not
    determine the soft iron, the hard iron is fitted alone and the result says so
    (:attr:`MagCalibration.weak`; ``observable`` False, the soft iron's σ NaN). See the
    module's text for the method and the example."""
    b = np.asarray(b_meas_nT, dtype=np.float64).reshape(-1, 3)
    n = len(b)
    ref = np.broadcast_to(np.asarray(b_ref_norm_nT, dtype=np.float64), (n,))
    if n < 9:
        raise ValueError(f"TWOSTEP needs 9 samples or more (9 unknowns), got {n}")
    if not (np.all(np.isfinite(b)) and np.all(np.isfinite(ref)) and sigma_nT > 0):
        raise ValueError("measurements and reference must be finite, sigma_nT > 0")
    z = np.einsum("ij,ij->i", b, b) - 3 * sigma_nT**2 - ref**2  # E|ε|² = 3σ²: not field
    var = 4 * sigma_nT**2 * ref**2 + 6 * sigma_nT**4 + 4 * sigma_ref_nT**2 * ref**2
    w = 1.0 / var
    lin = np.hstack([2 * b, -_quad_rows(b)])
    field_nT = float(np.median(ref))
    weak: list[str] = []
    if soft_iron:
        theta, cov_theta = _fit(lin, z, w, iterations)
        vals = np.linalg.eigvalsh(np.eye(3) + _sym(theta[3:]))
        if vals.min() > 0:
            cov = _to_h_d(theta, cov_theta)
            weak = _weak(cov, field_nT)
        else:
            weak = ["soft iron: the fit is not a positive-definite matrix"]
        if not weak:
            p, h = _from_c_e(theta[:3], _sym(theta[3:]))
            return _result(b, ref, h, p, cov, [], n)
    theta3, cov3 = _fit(lin[:, :3], z, w, iterations)
    h = theta3[:3]  # with E = 0, c = h
    cov = np.full((9, 9), np.nan)
    cov[:3, :3] = cov3
    if soft_iron:
        weak = [f"{why}: not determined by these samples, so the hard iron was fitted alone "
                "(soft iron taken as none)" for why in weak]
    if np.sqrt(np.diag(cov3)).max() > WEAK_H_SIGMA * field_nT:
        weak.append(f"hard iron 1σ up to {np.sqrt(np.diag(cov3)).max():.0f} nT")
    if weak:
        weak.append(_spread(b - h))
    return _result(b, ref, h, np.eye(3), cov, weak, n)


def _fit(lin: Array, z: Array, w: Array, iterations: int) -> tuple[Array, Array]:
    """``(θ, cov θ)`` of the model ``z = lin θ − |h|²``: the centred linear estimate, then
    Gauss–Newton with ``|h|² = cᵀ(I + E)⁻¹c`` (``θ = c`` alone: ``E = 0``)."""
    sw = np.sqrt(w)
    mean_lin = (w @ lin) / w.sum()
    mean_z = (w @ z) / w.sum()
    a = (lin - mean_lin) * sw[:, None]
    theta, *_ = np.linalg.lstsq(a, (z - mean_z) * sw, rcond=None)
    info = a.T @ a
    k = len(theta)
    for _ in range(iterations):
        c = theta[:3]
        e = _sym(theta[3:]) if k == 9 else np.zeros((3, 3))
        try:
            hh = np.linalg.solve(np.eye(3) + e, c)
        except np.linalg.LinAlgError:
            break
        model = lin @ theta - c @ hh
        # ∂|h|²/∂c = 2(I+E)⁻¹c; ∂|h|²/∂E_ij = −h_i h_j (×2 off the diagonal)
        d_norm = np.concatenate([2 * hh, -_quad_rows(hh[None])[0]])[:k]
        jw = (lin - d_norm) * sw[:, None]
        info = jw.T @ jw
        step = np.linalg.lstsq(jw, (z - model) * sw, rcond=None)[0]
        theta = theta + step
        if np.all(np.abs(step) <= 1e-10 * (1 + np.abs(theta))):
            break
    return theta, np.linalg.pinv(info)


def _to_h_d(theta: Array, cov_theta: Array) -> Array:
    """The covariance of ``(h, D)`` from that of ``θ = (c, E)``, through the map's Jacobian
    (numerical: a 9×9 of small steps)."""
    c, e = theta[:3], _sym(theta[3:])
    p, h = _from_c_e(c, e)
    base = np.concatenate([h, (p - np.eye(3))[_IU]])
    jmap = np.empty((9, 9))
    for k in range(9):
        dt = np.zeros(9)
        dt[k] = 1e-6 * max(1.0, abs(theta[k]))
        p_k, h_k = _from_c_e(c + dt[:3], e + _sym(dt[3:]))
        jmap[:, k] = (np.concatenate([h_k, (p_k - np.eye(3))[_IU]]) - base) / dt[k]
    return jmap @ cov_theta @ jmap.T


def _result(b: Array, ref: Array, h: Array, p: Array, cov: Array, weak: list[str],
            n: int) -> MagCalibration:
    before = np.sqrt(np.mean((np.linalg.norm(b, axis=1) - ref) ** 2))
    after = np.sqrt(np.mean((np.linalg.norm((b - h) @ p.T, axis=1) - ref) ** 2))
    return MagCalibration(h, p, cov, float(before), float(after), not weak, weak, n)


def _from_c_e(c: Array, e: Array) -> tuple[Array, Array]:
    """``(P, h)`` of ``(c, E)``: ``P = (I + E)^½`` (symmetric), ``h = (I + E)⁻¹ c``."""
    vals, vecs = np.linalg.eigh(np.eye(3) + e)
    if vals.min() <= 0:
        raise ValueError("TWOSTEP: the fitted soft iron is not positive definite (too "
                         "little rotation, or a reference that is not this field's)")
    p = (vecs * np.sqrt(vals)) @ vecs.T
    return p, np.linalg.solve(np.eye(3) + e, c)


def _weak(cov: Array, field_nT: float) -> list[str]:
    """The terms the samples do not determine, in words (empty: all of them)."""
    out = []
    sd = np.sqrt(np.maximum(np.diag(cov), 0))
    if sd[:3].max() > WEAK_H_SIGMA * field_nT:
        out.append(f"hard iron 1σ up to {sd[:3].max():.0f} nT (> {WEAK_H_SIGMA:.0%} of the "
                   f"{field_nT:.0f} nT field)")
    if sd[3:].max() > WEAK_D_SIGMA:
        out.append(f"soft iron 1σ up to {sd[3:].max():.3g} (> {WEAK_D_SIGMA:g})")
    return out


def _spread(centred: Array) -> str:
    """How much of the sphere the field's directions cover, as advice."""
    u = centred / np.linalg.norm(centred, axis=1, keepdims=True)
    spread = np.linalg.eigvalsh(u.T @ u / len(u))
    return (f"the field was seen along too few directions (spread {spread.round(3)} of 1/3 "
            "each for a full sphere): rotate the vehicle through more attitudes")


@dataclass
class MagAlignment:
    """The full magnetometer model fitted against known attitudes: ``B = S·b + h``, where
    ``b`` is the reference field in the body frame (the star-fixed attitude applied to the
    IGRF). ``S`` holds the soft iron and the alignment: ``S⁻¹ = O·P`` with ``P`` the
    symmetric factor (what TWOSTEP sees) and ``O`` the rotation from the magnetometer's
    axes to the body's (:attr:`alignment`).

    Attributes:
        soft_iron: ``S`` (3×3). hard_iron_nT: ``h``.
        cov: 12×12 covariance of (S row by row, h).
        residual_nT: RMS of ``B − S b − h`` per axis.
        observable / weak: as :class:`MagCalibration`.
    """

    soft_iron: Array
    hard_iron_nT: Array
    cov: Array
    residual_nT: float
    observable: bool
    weak: list[str] = field(default_factory=list)

    @property
    def alignment(self) -> Array:
        """``O``, the rotation of ``S⁻¹ = O·P`` (magnetometer axes → body axes)."""
        u, _, vt = np.linalg.svd(np.linalg.inv(self.soft_iron))
        return u @ vt

    @property
    def alignment_angle_rad(self) -> float:
        o = self.alignment
        return float(np.arccos(np.clip((np.trace(o) - 1) / 2, -1.0, 1.0)))

    def correct(self, b_meas_nT: ArrayLike) -> Array:
        """``S⁻¹ (B − h)``: the field in the body frame, nT."""
        b = np.asarray(b_meas_nT, dtype=np.float64)
        return np.linalg.solve(self.soft_iron, (b - self.hard_iron_nT).T).T


def attitude_aided(b_meas_nT: ArrayLike, b_ref_body_nT: ArrayLike, *, sigma_nT: float,
                   sigma_ref_nT: float = 0.0) -> MagAlignment:
    """``S`` and ``h`` of ``B = S·b + h`` by linear least squares, with ``b_ref_body_nT``
    (N, 3) the reference field in the body frame at each sample (the filter's star-fixed
    attitude applied to the IGRF): 12 unknowns, the alignment included. ``sigma_ref_nT``
    adds the reference's error (the IGRF's, and the attitude's: |b|·σ_θ) per axis. A
    design that does not determine every term (too little rotation) is reported weak.

    Example:
        >>> import numpy as np
        >>> rng = np.random.default_rng(0)
        >>> b = rng.normal(0, 30000, (300, 3))          # the field seen every way round
        >>> S = np.eye(3) + 0.02 * rng.standard_normal((3, 3))
        >>> fit = attitude_aided(b @ S.T + [500, -200, 90] + rng.normal(0, 20, b.shape), b,
        ...                      sigma_nT=20)
        >>> fit.observable, bool(np.abs(fit.soft_iron - S).max() < 1e-3)
        (True, True)
    """
    bm = np.asarray(b_meas_nT, dtype=np.float64).reshape(-1, 3)
    br = np.asarray(b_ref_body_nT, dtype=np.float64).reshape(-1, 3)
    if len(bm) != len(br) or len(bm) < 4:
        raise ValueError(f"attitude_aided needs ≥ 4 paired samples, got {len(bm)} and "
                         f"{len(br)}")
    if not (np.all(np.isfinite(bm)) and np.all(np.isfinite(br)) and sigma_nT > 0):
        raise ValueError("measurements and reference must be finite, sigma_nT > 0")
    x = np.hstack([br, np.ones((len(br), 1))])  # each axis of B: a row of S and h_i
    xtx = x.T @ x
    coef, *_ = np.linalg.lstsq(x, bm, rcond=None)  # (4, 3): column i = (S_i·, h_i)
    s_mat, h = coef[:3].T, coef[3]
    resid = bm - x @ coef
    # the reference's error reaches B through S (≈ I): the same variance on each axis
    var = sigma_nT**2 + sigma_ref_nT**2
    inv = np.linalg.pinv(xtx) * var
    cov = np.zeros((12, 12))
    for i in range(3):  # S's row i and h_i share the design's inverse
        idx = [3 * i, 3 * i + 1, 3 * i + 2, 9 + i]
        cov[np.ix_(idx, idx)] = inv
    weak = []
    sd_s = np.sqrt(np.diag(inv)[:3])
    if sd_s.max() > WEAK_D_SIGMA:
        weak.append(f"soft iron and alignment 1σ up to {sd_s.max():.3g} (> {WEAK_D_SIGMA:g})"
                    ": " + _spread(br))
    return MagAlignment(s_mat, h, cov, float(np.sqrt(np.mean(resid**2))), not weak, weak)
