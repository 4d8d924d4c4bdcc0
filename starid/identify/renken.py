"""Renken (1998) reproduction pieces: his image geometry and attitude method.

What the thesis does differently from the product path, kept here so it can be
reproduced exactly (§6.6, §6.7, §6.9; docs/references.md#renken-1998):

* image pair angles are ``angle_per_pixel × pixel distance`` (linear, no lens model);
* the image triangle's handedness is the 2-D cross product in pixel coordinates;
* the attitude is the affine (barycentric) interpolation of the image centre and the
  right-edge pixel over star triangles, averaged over all well-shaped triangles;

Angles are radians inside; ``omega`` is his "third angle". In ``"exact"`` mode it is
the great-circle bearing (north through east) of the centre → edge direction plus 90°,
the rigorous form of ``atan2(Δδ, −wrap(Δα)·cos δ)`` (the thesis leaves the exact form open);
it equals our roll (:mod:`adfusion.maths.rotations`). ``"thesis"`` mode is his printed
``atan2(Δδ, Δα)``.
His §8 simulation driver (Eq. 8.1 attitudes, the grid) is :mod:`adfusion.bench.renken_sim`.

Example (Renken 1998 Eq. 6.16–6.20):
    >>> a, b = affine_coefficients([100, 100], [200, 100], [100, 200], [192, 144])
    >>> round(a, 6), round(b, 6)
    (0.92, 0.44)
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from adfusion.starid.identify.nstar import Pattern
from numpy.typing import ArrayLike, NDArray

from adfusion.maths import rotations as rot

__all__ = [
    "SAO_COUNTS",
    "RenkenAttitude",
    "affine_attitude",
    "affine_coefficients",
    "linear_pattern",
    "renken_count_table",
    "triangle_ok",
]

DEFAULT_CENTER = (191.0, 143.0)  # his 1-based (192, 144) as 0-based pixels
DEFAULT_EDGE = (383.0, 143.0)  # his 1-based (384, 144)


def linear_pattern(xy: ArrayLike, angle_per_pixel_rad: float, tol_rad: float,
                   handedness: int = 1) -> Pattern:
    """Renken's image pattern: linear pixel-distance angles and the pixel-triangle chirality.

    With pixel x right, y down and the camera +z forward, a non-mirrored image has the
    same handedness as the sky triangle; ``handedness=-1`` declares a mirrored read-out.
    """
    p = np.asarray(xy, dtype=np.float64)
    d = np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1])
    chir = 0
    if len(p) >= 3:
        cp = (p[1, 0] - p[0, 0]) * (p[2, 1] - p[0, 1]) - (p[1, 1] - p[0, 1]) * (p[2, 0] - p[0, 0])
        chir = int(np.sign(cp)) * handedness
    return Pattern.from_angles(d * angle_per_pixel_rad, tol_rad, chir)


def affine_coefficients(p1: ArrayLike, p2: ArrayLike, p3: ArrayLike,
                        target: ArrayLike) -> tuple[float, float]:
    """Cramer's rule for ``target − p1 = a (p2 − p1) + b (p3 − p1)`` (Eq. 6.13–6.20)."""
    (x1, y1), (x2, y2), (x3, y3), (xt, yt) = (np.asarray(p, float) for p in (p1, p2, p3, target))
    d0 = (x2 - x1) * (y3 - y1) - (x3 - x1) * (y2 - y1)
    if d0 == 0:
        raise ValueError("degenerate (collinear) image triangle")
    d1 = (y3 - y1) * (xt - x1) - (x3 - x1) * (yt - y1)
    d2 = (x2 - x1) * (yt - y1) - (y2 - y1) * (xt - x1)
    return float(d1 / d0), float(d2 / d0)


def triangle_ok(xy3: NDArray, v3: NDArray, angle_per_pixel_rad: float,
                min_len_px: float = 5.0, min_angle_deg: float = 5.0,
                min_cat_angle_deg: float = 2.0) -> bool:
    """Cond. 8.1: image legs ≥ 5 px and opening angle in (5°, 175°); catalogue legs ≥
    4 px worth of angle and opening angle ≥ 2° (the thesis's arcsin bug fixed: atan2)."""
    u, w = xy3[1] - xy3[0], xy3[2] - xy3[0]
    if min(np.hypot(*u), np.hypot(*w)) <= min_len_px:
        return False
    ang = np.degrees(np.arctan2(abs(u[0] * w[1] - u[1] * w[0]), u @ w))
    if not min_angle_deg < ang < 180.0 - min_angle_deg:
        return False
    a, b = v3[1] - v3[0], v3[2] - v3[0]
    sep = np.arccos(np.clip([v3[0] @ v3[1], v3[0] @ v3[2]], -1, 1))
    if sep.min() < 4 * angle_per_pixel_rad:
        return False
    cang = np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b))
    return bool(min_cat_angle_deg <= cang <= 180.0 - min_cat_angle_deg)


@dataclass(frozen=True)
class RenkenAttitude:
    """Boresight (α, δ) and third angle ω (rad); ``n_triangles`` averaged (0 = critical)."""

    alpha: float
    delta: float
    omega: float
    n_triangles: int

    @property
    def ok(self) -> bool:
        return self.n_triangles > 0


def affine_attitude(
    xy: ArrayLike,
    v_icrs: ArrayLike,
    angle_per_pixel_rad: float,
    center: tuple[float, float] = DEFAULT_CENTER,
    edge: tuple[float, float] = DEFAULT_EDGE,
    omega_mode: str = "exact",
    max_triangles: int | None = None,
) -> RenkenAttitude:
    """Renken's §6.7 attitude averaged over every triangle passing Cond. 8.1.

    Boresight directions are averaged as unit vectors and ω circularly (the thesis's
    arithmetic mean breaks at the 0/360° wrap; Renken 1998 §6.7).
    """
    if omega_mode not in ("exact", "thesis"):
        raise ValueError("omega_mode must be 'exact' or 'thesis'")
    p = np.asarray(xy, dtype=np.float64)
    v = np.asarray(v_icrs, dtype=np.float64)
    ws, om = [], []
    tris = list(itertools.combinations(range(len(p)), 3))[:max_triangles]
    for t in tris:
        t = list(t)
        if not triangle_ok(p[t], v[t], angle_per_pixel_rad):
            continue
        w_c = _affine_point(p[t], v[t], center)
        w_e = _affine_point(p[t], v[t], edge)
        ac, dc = rot.vector_to_radec(w_c)
        ae, de = rot.vector_to_radec(w_e)
        dalpha = (ae - ac + np.pi) % (2 * np.pi) - np.pi
        if omega_mode == "exact":
            # initial great-circle bearing of the edge point (north through east) + 90°:
            # over 10° of arc at high declination the raw (Δα, Δδ) direction is off by
            # degrees, the bearing is not
            bearing = np.arctan2(np.sin(dalpha) * np.cos(de),
                                 np.cos(dc) * np.sin(de) - np.sin(dc) * np.cos(de)
                                 * np.cos(dalpha))
            om.append(bearing + np.pi / 2)
        else:
            om.append(np.arctan2(de - dc, ae - ac))
        ws.append(w_c)
    if not ws:
        return RenkenAttitude(np.nan, np.nan, np.nan, 0)
    w = np.sum(ws, axis=0)
    alpha, delta = rot.vector_to_radec(w / np.linalg.norm(w))
    omega = np.arctan2(np.mean(np.sin(om)), np.mean(np.cos(om))) % (2 * np.pi)
    return RenkenAttitude(float(alpha), float(delta), float(omega), len(ws))


def _affine_point(p3: NDArray, v3: NDArray, target: tuple[float, float]) -> NDArray:
    a, b = affine_coefficients(p3[0], p3[1], p3[2], target)
    w = v3[0] + a * (v3[1] - v3[0]) + b * (v3[2] - v3[0])
    return w / np.linalg.norm(w)


# Tab. A.2: star counts of the SAO "uptomag" catalogues
SAO_COUNTS = {1.0: 12, 2.0: 36, 3.0: 136, 4.0: 427, 4.5: 764, 5.0: 1370, 5.4: 2526, 5.7: 3581,
              6.0: 4480}


def renken_count_table(merge_sep_deg: float | None = None) -> list[tuple[float, int, int, int]]:
    """Hipparcos star counts against Renken's SAO catalogues (Tab. A.2), all ``mag < L``.

    Rows ``(L, sao, ours_V, ours_Hp)`` for L = 1.0 … 6.0, ours from :meth:`Catalog.hipparcos`
    (estimated V, and Hp). Star counts do not depend on the epoch unless stars are merged.

    >>> renken_count_table()[2]
    (3.0, 136, 176, 165)
    """
    from adfusion.starid.catalog.stars import Catalog

    top = max(SAO_COUNTS)
    mags = {
        system: Catalog.hipparcos(
            mag_limit=top + 1.0, mag_system=system, merge_sep_deg=merge_sep_deg
        ).mag
        for system in ("V", "Hp")
    }
    return [
        (limit, sao, int(np.sum(mags["V"] < limit)), int(np.sum(mags["Hp"] < limit)))
        for limit, sao in SAO_COUNTS.items()
    ]
