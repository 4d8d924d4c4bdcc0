"""Renken (1998) reproduction pieces: his image geometry, attitude method and sampler.

What the thesis does differently from the product path, kept here so it can be
reproduced exactly (renken.md §4.2, §4.9, §4.10, §8.1):

* image pair angles are ``angle_per_pixel × pixel distance`` (linear, no lens model);
* the image triangle's handedness is the 2-D cross product in pixel coordinates;
* the attitude is the affine (barycentric) interpolation of the image centre and the
  right-edge pixel over star triangles, averaged over all well-shaped triangles;
* random attitudes follow his Eq. 8.1 (not uniform on the sphere).

Angles are radians inside; ``omega`` is his "third angle". In ``"exact"`` mode it is
the great-circle bearing (north through east) of the centre → edge direction plus 90°,
the rigorous form of ``atan2(Δδ, −wrap(Δα)·cos δ)`` (renken.md §11 #21); it equals our
roll (:mod:`starid.rotations`). ``"thesis"`` mode is his printed ``atan2(Δδ, Δα)``.

Example (renken.md AC-20):
    >>> a, b = affine_coefficients([100, 100], [200, 100], [100, 200], [192, 144])
    >>> round(a, 6), round(b, 6)
    (0.92, 0.44)
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from starid import rotations as rot
from starid.nstar import Pattern

__all__ = [
    "PUBLISHED_ETA",
    "SAO_COUNTS",
    "RenkenAttitude",
    "SimulationCell",
    "affine_attitude",
    "affine_coefficients",
    "eq_8_1_attitudes",
    "linear_pattern",
    "renken_catalog",
    "simulate_cell",
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
    arithmetic mean breaks at the 0/360° wrap; renken.md §4.10 item 6).
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


def eq_8_1_attitudes(rng: np.random.Generator, n: int,
                     uniform: bool = False) -> NDArray[np.float64]:
    """Random (α, δ, ω) in rad: Renken's Eq. 8.1 declinations
    ``δ = ±90°·(1 − cos U[0°, 90°])`` by default, or uniform on the sphere."""
    alpha = rng.uniform(0, 2 * np.pi, n)
    if uniform:
        delta = np.arcsin(rng.uniform(-1, 1, n))
    else:
        sign = rng.choice([-1.0, 1.0], n)
        delta = sign * np.pi / 2 * (1 - np.cos(rng.uniform(0, np.pi / 2, n)))
    omega = rng.uniform(0, 2 * np.pi, n)
    return np.stack([alpha, delta, omega], axis=1)


# --- §8 simulation --------------------------------------------------------------------------

# Tab. 8.22–8.28: η (%) per magnitude limit at tolerance 0.1°, 0.2°, 0.3°
PUBLISHED_ETA = {
    3.0: (7.3, 7.15, 6.5), 4.0: (44.2, 37.6, 29.0), 4.5: (71.95, 64.6, 58.6),
    5.0: (93.95, 89.3, 83.8), 5.4: (99.7, 96.3, 88.65), 5.7: (99.6, 94.05, 81.25),
    6.0: (99.15, 91.9, 69.55),
}
# Tab. A.2: star counts of the SAO "uptomag" catalogues
SAO_COUNTS = {1.0: 12, 2.0: 36, 3.0: 136, 4.0: 427, 4.5: 764, 5.0: 1370, 5.4: 2526, 5.7: 3581,
              6.0: 4480}


@dataclass(frozen=True)
class SimulationCell:
    """Outcome counts of one (catalogue, tolerance) cell of Renken's §8 simulation."""

    mag_limit: float
    tol_deg: float
    frames: int
    clear: int  # unique, correct, attitude computed: his clear_3_axis_attitude_counter
    fewer_than_3: int
    miss: int  # matching_counter = 0
    unique: int  # matching_counter = 1
    multiple: int  # matching_counter ≥ 2
    wrong_unique: int  # matching_counter = 1 but the wrong stars
    critical: int  # unique but no triangle passes Cond. 8.1

    @property
    def eta(self) -> float:
        return 100.0 * self.clear / self.frames


def renken_catalog(mag_limit: float, epoch: float = 2000.0, merge_px: float = 2.0):
    """An "SAO-like" catalogue for the simulation: Hipparcos with close pairs merged
    (faint stars included, renken.md §8.1) and cut to the brightest ``SAO_COUNTS`` objects
    (SAO photometry runs ~0.15 mag fainter than V, so equal counts reproduce his
    catalogues better than equal limits — see tests/test_renken.py AC-17).

    The merge radius is not in the thesis. 2 px (0.102°) is our choice: his stars were
    1–3 px blobs, so two stars closer than ~2 px segment as one object. With 1 px the
    mag < 5.4, 0.1° cell gives η ≈ 96.8 % (3 % multiple matches from close pairs the
    camera could not have resolved); with 2 px it gives 99.75 % against his 99.7 %."""
    from starid.catalog import Catalog

    merged = Catalog.hipparcos(mag_limit=8.0, epoch=epoch).merged(np.radians(0.051 * merge_px))
    return merged.brightest(SAO_COUNTS[mag_limit])


def simulate_cell(catalog, mag_limit: float, tol_deg: float, n_frames: int, seed: int,
                  index=None) -> SimulationCell:
    """Renken's §8 loop for one cell: Eq. 8.1 attitudes, his equidistant 384×288 camera,
    every catalogue object in the frame as an image star (0.1 px centroids, brightness
    order), the n = min(number_is, 6) brightest, closest pair first, linear pixel
    angles, all matches enumerated. A unique match counts as clear when it is the true
    star set and a triangle passes Cond. 8.1 (success Cond. 8.2)."""
    from starid.camera import Camera
    from starid.index import PatternIndex
    from starid.nstar import closest_pair_first, match_indexed
    from starid.view import stars_in_view

    cam = Camera.renken()
    app = np.radians(0.051)
    if index is None:
        index = PatternIndex.from_vectors(catalog.vectors, np.radians(25.0))
    rng = np.random.default_rng(seed)
    counts = dict.fromkeys(("clear", "few", "miss", "unique", "multiple", "wrong", "crit"), 0)
    for a, d, w in eq_8_1_attitudes(rng, n_frames):
        q = rot.q_cam_icrs_from_radec_roll(a, d, w)
        stars, xy = stars_in_view(catalog, cam, q)
        xy = np.round(xy, 1)  # his centroids have 0.1 px resolution
        if len(stars) < 3:
            counts["few"] += 1
            continue
        n = min(len(stars), 6)
        p, s = xy[:n], stars[:n]
        ang = np.hypot(*(p[:, None] - p[None]).transpose(2, 0, 1))
        o = closest_pair_first(ang)
        found = match_indexed(index, linear_pattern(p[o], app, np.radians(tol_deg)),
                              max_partials=10**8)
        if len(found) == 0:
            counts["miss"] += 1
        elif len(found) > 1:
            counts["multiple"] += 1
        else:
            counts["unique"] += 1
            if not np.array_equal(found[0], s[o]):
                counts["wrong"] += 1
            elif not affine_attitude(p[o], catalog.vectors[found[0]], app).ok:
                counts["crit"] += 1
            else:
                counts["clear"] += 1
    return SimulationCell(mag_limit, tol_deg, n_frames, counts["clear"], counts["few"],
                          counts["miss"], counts["unique"], counts["multiple"],
                          counts["wrong"], counts["crit"])
