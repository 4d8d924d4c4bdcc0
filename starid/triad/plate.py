"""Yee's iterated six-constant plate fit: the RA/Dec of the image centre from identified stars.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from adfusion.starid.triad.angles import FloatArray, _wrap180
from numpy.typing import ArrayLike

__all__ = ["PlateDivergenceError", "PlateSolution", "plate_pointing", "plate_solution"]


@dataclass(frozen=True)
class PlateSolution:
    """Result of Yee's iterated plate-constant fit (§2.4).

    Attributes:
        ra_deg, dec_deg: the image centre (x = y = 0).
        iterations: plate fits performed until two successive centres agreed.
        initial_radec_deg: the linear-regression starting point (§2.4.3).
        constants: Yee's a, b, c, d, e, f (Eq. 2.8/2.9; x, y in radians) of the last fit.
        calc_ra_deg, calc_dec_deg: the matched stars back-projected with those constants.
        max_error_deg: the largest |calculated − catalogue| in RA (no cos δ) or Dec — the
            thesis's "±" of the centre.
    """

    ra_deg: float
    dec_deg: float
    iterations: int
    initial_radec_deg: tuple[float, float]
    constants: tuple[float, float, float, float, float, float]
    calc_ra_deg: FloatArray
    calc_dec_deg: FloatArray
    max_error_deg: float


class PlateDivergenceError(RuntimeError):
    """Yee's plate iteration did not converge (e.g. OEDIPUS-C image 24, Yee 1999 App. D)."""


def _standard(ra: FloatArray, dec: FloatArray, ra0: float, dec0: float) -> tuple[
    FloatArray, FloatArray, FloatArray
]:
    """Standard coordinates ξ, η (Eq. 2.16/2.17) and the denominator (> 0: in front)."""
    dra = ra - ra0
    den = math.sin(dec0) * np.sin(dec) + math.cos(dec0) * np.cos(dec) * np.cos(dra)
    xi = np.cos(dec) * np.sin(dra) / den
    eta = (math.cos(dec0) * np.sin(dec) - math.sin(dec0) * np.cos(dec) * np.cos(dra)) / den
    return xi, eta, den


def _equatorial(xi: FloatArray, eta: FloatArray, ra0: float, dec0: float) -> tuple[
    FloatArray, FloatArray
]:
    """Inverse gnomonic projection (Eq. 2.18/2.19). Dec uses the algebraically identical
    ``atan2(sin δ* + η cos δ*, √(ξ² + (cos δ* − η sin δ*)²))``, free of quadrant trouble."""
    den = math.cos(dec0) - eta * math.sin(dec0)
    ra = ra0 + np.arctan2(xi, den)
    dec = np.arctan2(math.sin(dec0) + eta * math.cos(dec0), np.hypot(xi, den))
    return np.mod(ra, 2 * math.pi), dec


def plate_solution(
    xy_centred_yup: ArrayLike,
    radec_deg: ArrayLike,
    scale_x_deg: float,
    scale_y_deg: float,
    tol_arcsec: float = 1.0,
    max_iterations: int = 50,
) -> PlateSolution:
    """Yee's iterated plate-constant solution for the RA/Dec of the image centre (§2.4).

    Args:
        xy_centred_yup: (N ≥ 3, 2) matched stars in pixels from the image centre (Yee's frame).
        radec_deg: (N, 2) their catalogue RA/Dec in degrees.
        scale_x_deg, scale_y_deg: degrees per pixel; x, y enter the fit in radians. (The
            affine fit makes the centre independent of this choice [VERIFIED]; it keeps the
            normal equations well scaled.)
        tol_arcsec: stop when two successive centres agree within this in RA and in Dec.
        max_iterations: give up (raise) after this many plate fits.

    Start (§2.4.3): least-squares lines RA(x) and RA(y) evaluated at 0 and averaged; the same
    for Dec. RA is unwrapped about the first star (stars across 0h, as in OEDIPUS-C).
    Iterate: ξ, η about the current centre (Eq. 2.16/2.17), the six plate constants by
    linear least squares (Eq. 2.8–2.15), the new centre from ``(ξ, η) = (c, f)``
    (Eq. 2.18–2.21). The stars are back-projected with the last iteration's constants about
    the tangent point they were fitted at.

    Raises ValueError for < 3 stars or collinear stars; :class:`PlateDivergenceError` when
    the iteration does not settle (steps growing, a star ≥ 90° from the centre, or
    ``max_iterations`` reached).

    >>> xy = [[-100.0, 0.0], [100.0, 50.0], [0.0, -80.0]]     # 0.02°/px, north up, east left
    >>> radec = [[12.0, 20.0], [8.0, 21.0], [10.0, 18.4]]
    >>> sol = plate_solution(xy, radec, 0.02, 0.02)
    >>> round(sol.ra_deg, 1), round(sol.dec_deg, 1), sol.iterations
    (10.0, 20.0, 2)
    """
    p = np.asarray(xy_centred_yup, dtype=np.float64).reshape(-1, 2)
    s = np.asarray(radec_deg, dtype=np.float64).reshape(-1, 2)
    if len(p) != len(s):
        raise ValueError(f"{len(p)} positions but {len(s)} catalogue coordinates")
    if len(p) < 3:
        raise ValueError(f"the plate fit needs at least 3 stars, got {len(p)}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(s))):
        raise ValueError("inputs must be finite")
    x = p[:, 0] * math.radians(scale_x_deg)
    y = p[:, 1] * math.radians(scale_y_deg)
    A = np.stack([x, y, np.ones_like(x)], axis=1)
    sv = np.linalg.svd(A - np.r_[A[:, :2].mean(axis=0), 1.0], compute_uv=False)[:2]
    if sv[1] <= 1e-9 * max(sv[0], 1e-300):
        raise ValueError("matched stars are collinear: the plate constants are undetermined")

    ra_u = s[0, 0] + _wrap180(s[:, 0] - s[0, 0])
    dec_d = s[:, 1]

    def at_zero(coord: FloatArray, val: FloatArray) -> float:
        line = np.stack([coord, np.ones_like(coord)], axis=1)
        return float(np.linalg.lstsq(line, val, rcond=None)[0][1])

    ra0 = 0.5 * (at_zero(x, ra_u) + at_zero(y, ra_u))
    dec0 = 0.5 * (at_zero(x, dec_d) + at_zero(y, dec_d))
    init = (float(np.mod(ra0, 360.0)), dec0)
    ra_r, dec_r = np.radians(s[:, 0]), np.radians(s[:, 1])
    cur = (math.radians(ra0), math.radians(dec0))
    tol = math.radians(tol_arcsec / 3600.0)
    steps: list[float] = []
    for it in range(1, max_iterations + 1):
        xi, eta, den = _standard(ra_r, dec_r, *cur)
        if np.any(den <= 0) or not abs(cur[1]) < math.pi / 2:
            raise PlateDivergenceError(f"diverged at iteration {it}: a star is ≥ 90° from "
                                       f"the centre estimate")
        cx = np.linalg.lstsq(A, xi, rcond=None)[0]
        ce = np.linalg.lstsq(A, eta, rcond=None)[0]
        new_ra, new_dec = _equatorial(np.array(cx[2]), np.array(ce[2]), *cur)
        new = (float(new_ra), float(new_dec))
        d_ra = abs(float(_wrap180(math.degrees(new[0] - cur[0]))))
        d_dec = abs(math.degrees(new[1] - cur[1]))
        fitted_at, cur = cur, new
        if not (math.isfinite(d_ra) and math.isfinite(d_dec)):
            raise PlateDivergenceError(f"non-finite centre at iteration {it}")
        if math.radians(d_ra) <= tol and math.radians(d_dec) <= tol:
            calc_ra, calc_dec = _equatorial(A @ cx, A @ ce, *fitted_at)
            calc_ra_deg = np.degrees(calc_ra)
            calc_dec_deg = np.degrees(calc_dec)
            err = max(
                float(np.max(np.abs(_wrap180(calc_ra_deg - s[:, 0])))),
                float(np.max(np.abs(calc_dec_deg - s[:, 1]))),
            )
            consts = (cx[0] - 1.0, cx[1], cx[2], ce[0], ce[1] - 1.0, ce[2])
            return PlateSolution(
                float(np.mod(math.degrees(cur[0]), 360.0)), math.degrees(cur[1]), it, init,
                tuple(float(c) for c in consts), calc_ra_deg, calc_dec_deg, err,
            )  # fmt: skip
        steps.append(max(d_ra, d_dec))
        # a fixed-point iteration that converges shrinks its step; three growing steps in a
        # row mean it is running away (Yee's image 24 "diverged")
        if len(steps) >= 4 and steps[-1] > steps[-2] > steps[-3] > steps[-4]:
            raise PlateDivergenceError(f"diverging: steps grew to {steps[-1]:.3g}° by "
                                       f"iteration {it}")
    raise PlateDivergenceError(f"no convergence to {tol_arcsec}″ in {max_iterations} iterations")


def plate_pointing(
    xy_centred_yup: ArrayLike,
    radec_deg: ArrayLike,
    scale_x_deg: float,
    scale_y_deg: float,
    tol_arcsec: float = 1.0,
) -> tuple[float, float]:
    """RA/Dec (degrees) of the image centre from :func:`plate_solution`.

    >>> plate_pointing([[-100.0, 0.0], [100.0, 50.0], [0.0, -80.0]],
    ...                [[12.0, 20.0], [8.0, 21.0], [10.0, 18.4]], 0.02, 0.02)[0].__round__(2)
    10.0
    """
    sol = plate_solution(xy_centred_yup, radec_deg, scale_x_deg, scale_y_deg, tol_arcsec)
    return sol.ra_deg, sol.dec_deg
