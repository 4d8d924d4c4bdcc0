"""Bleif's MusterPr pattern catalogue (Bleif 2004 §4.2.4): one pattern per reference star.

For each of the ``n_stars`` brightest stars (default 5000), every other star of the list
closer than ``radius`` (20°) joins its pattern in list order until ``cap`` (150) are in;
the members are then sorted by distance ``d`` and carry their direction angle AzRef at
the reference: the position angle measured from celestial north towards *west*
(Eq. 4.4–4.10; α = 0 north, 90° west, 270° east).

The thesis's quadrant rule (Eq. 4.9/4.10: "RA_pattern > RA_reference → 360° − α")
breaks across RA 0/360°; the default uses the wrapped RA difference (an atan2 on the
tangent plane); ``faithful=True`` keeps the literal comparison (docs/references.md#bleif-2004).

The arrays are built once and cached (:func:`starid.catalog.cache.cached_arrays`); a catalogue
saves to and loads from an ``.npz`` file bit-exactly.

Example:
    >>> import numpy as np
    >>> round(direction_angle_deg(0.0, 0.0, 355.0, 0.0), 9)     # west of the reference
    90.0
    >>> round(direction_angle_deg(0.0, 0.0, 355.0, 0.0, faithful=True), 9)
    270.0
    >>> from adfusion.starid.catalog.stars import Catalog
    >>> pc = PatternCatalog.build(Catalog.hipparcos(mag_limit=4.0), n_stars=300)
    >>> len(pc), bool(np.all(np.diff(pc.dist_rad[0, :pc.size[0]]) >= 0))
    (300, True)
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from adfusion.starid.catalog.cache import cached_arrays
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

__all__ = [
    "N_PATTERN_STARS",
    "PATTERN_CAP",
    "PATTERN_RADIUS_DEG",
    "PatternCatalog",
    "direction_angle_deg",
    "direction_angles_rad",
]

N_PATTERN_STARS = 5000  # Bleif 2004 §4.2.4: the 5000 brightest stars
PATTERN_RADIUS_DEG = 20.0
PATTERN_CAP = 150


def direction_angles_rad(ref: NDArray[np.float64], stars: NDArray[np.float64],
                         faithful: bool = False) -> NDArray[np.float64]:
    """Direction angles (rad, [0, 2π), north → west) of unit vectors ``stars`` (N, 3) at
    the reference unit vector ``ref`` (3,)."""
    ref = np.asarray(ref, dtype=np.float64)
    stars = np.atleast_2d(np.asarray(stars, dtype=np.float64))
    east = np.cross([0.0, 0.0, 1.0], ref)
    n = np.linalg.norm(east)
    east = east / n if n > 1e-12 else np.array([0.0, 1.0, 0.0])  # at a pole: ra = 0 up
    north = np.cross(ref, east)
    if not faithful:
        return np.mod(np.arctan2(-(stars @ east), stars @ north), 2 * np.pi)
    # Eq. 4.5: the angle at the reference in the triangle (reference, star, pole), then
    # Eq. 4.9/4.10 on the raw right ascensions
    de_ref = math.asin(max(-1.0, min(1.0, float(ref[2]))))
    ra_ref = math.atan2(ref[1], ref[0]) % (2 * math.pi)
    cos_c = np.clip(stars @ ref, -1.0, 1.0)
    sin_b, sin_c = math.cos(de_ref), np.sqrt(1.0 - cos_c**2)
    cos_alpha = (stars[:, 2] - math.sin(de_ref) * cos_c) / np.maximum(sin_b * sin_c, 1e-300)
    alpha = np.arccos(np.clip(cos_alpha, -1.0, 1.0))
    ra = np.mod(np.arctan2(stars[:, 1], stars[:, 0]), 2 * np.pi)
    return np.where(ra > ra_ref, 2 * np.pi - alpha, alpha)


def direction_angle_deg(ra_ref_deg: float, de_ref_deg: float, ra_deg: float, de_deg: float,
                        faithful: bool = False) -> float:
    """One direction angle in degrees (docs/references.md#bleif-2004).

    >>> [round(direction_angle_deg(0, 0, *s), 9) for s in ((0, 5), (0, -5), (5, 0))]
    [0.0, 180.0, 270.0]
    """
    def vec(ra, de):
        ra, de = math.radians(ra), math.radians(de)
        return np.array([math.cos(de) * math.cos(ra), math.cos(de) * math.sin(ra),
                         math.sin(de)])
    a = direction_angles_rad(vec(ra_ref_deg, de_ref_deg), vec(ra_deg, de_deg)[None],
                             faithful)
    return math.degrees(float(a[0]))


@dataclass(frozen=True)
class PatternCatalog:
    """The patterns as padded arrays (P patterns, up to ``cap`` members each).

    Attributes:
        ids, vectors, mag: the star list (the brightest ``n_stars``, brightest first).
        member: (P, cap) indices into the star list, −1 beyond ``size``.
        dist_rad: (P, cap) distances to the reference, ascending; +inf beyond ``size``.
        az_rad: (P, cap) direction angles AzRef in [0, 2π); NaN beyond ``size``.
        size: (P,) members per pattern. Pattern p's reference is star p.
    """

    ids: NDArray[np.int64]
    vectors: NDArray[np.float64]
    mag: NDArray[np.float64]
    member: NDArray[np.int64]
    dist_rad: NDArray[np.float64]
    az_rad: NDArray[np.float64]
    size: NDArray[np.int64]
    radius_rad: float
    faithful: bool = False

    def __len__(self) -> int:
        return len(self.ids)

    @classmethod
    def build(cls, catalog, n_stars: int = N_PATTERN_STARS,
              radius_deg: float = PATTERN_RADIUS_DEG, cap: int = PATTERN_CAP,
              faithful: bool = False, cache: bool = True) -> PatternCatalog:
        """Patterns of the ``n_stars`` brightest stars of ``catalog`` (a
        :class:`starid.Catalog`), cached by the stars' bytes and the parameters."""
        if n_stars < 2 or cap < 1 or not 0 < radius_deg < 180:
            raise ValueError(f"need n_stars ≥ 2, cap ≥ 1, 0 < radius_deg < 180; got "
                             f"{n_stars}, {cap}, {radius_deg}")
        # the star list brightest first: the cap then keeps a dense pattern's brightest
        # members (the thesis's list order is not stated; docs/references.md#bleif-2004)
        order = np.argsort(np.asarray(catalog.mag), kind="stable")[: int(n_stars)]
        ids = np.asarray(catalog.ids, dtype=np.int64)[order]
        vec = np.ascontiguousarray(np.asarray(catalog.vectors, dtype=np.float64)[order])
        mag = np.asarray(catalog.mag, dtype=np.float64)[order]
        radius = math.radians(radius_deg)

        def make() -> dict[str, np.ndarray]:
            return _build_arrays(vec, radius, int(cap), faithful)

        tag = hashlib.sha1(vec.tobytes() + ids.tobytes()).hexdigest()
        params = {"stars": tag, "radius_deg": float(radius_deg), "cap": int(cap),
                  "faithful": bool(faithful)}
        arrays = cached_arrays("bleif-patterns", params, [], make) if cache else make()
        return cls(ids, vec, mag, arrays["member"], arrays["dist_rad"], arrays["az_rad"],
                   arrays["size"], radius, bool(faithful))

    def save(self, path: str | Path) -> None:
        """Write every array to an ``.npz`` file (:meth:`load` restores it bit-exactly)."""
        np.savez(path, ids=self.ids, vectors=self.vectors, mag=self.mag, member=self.member,
                 dist_rad=self.dist_rad, az_rad=self.az_rad, size=self.size,
                 radius_rad=np.float64(self.radius_rad), faithful=np.bool_(self.faithful))

    @classmethod
    def load(cls, path: str | Path) -> PatternCatalog:
        """Read a catalogue written by :meth:`save`."""
        with np.load(path, allow_pickle=False) as z:
            return cls(z["ids"], z["vectors"], z["mag"], z["member"], z["dist_rad"],
                       z["az_rad"], z["size"], float(z["radius_rad"]), bool(z["faithful"]))

    def members_of(self, p: int) -> NDArray[np.int64]:
        """Star-list indices of pattern ``p``'s members (ascending distance)."""
        return self.member[p, : self.size[p]]

    def ra_dec_deg(self, idx: ArrayLike) -> tuple[NDArray, NDArray]:
        """RA (in [0, 360)) and DE in degrees of star-list entries."""
        v = self.vectors[np.asarray(idx, dtype=np.int64)]
        ra = np.degrees(np.mod(np.arctan2(v[..., 1], v[..., 0]), 2 * np.pi))
        return ra, np.degrees(np.arcsin(np.clip(v[..., 2], -1, 1)))


def _build_arrays(vec: NDArray, radius: float, cap: int,
                  faithful: bool) -> dict[str, np.ndarray]:
    n = len(vec)
    tree = cKDTree(vec)
    member = np.full((n, cap), -1, dtype=np.int64)
    dist = np.full((n, cap), np.inf)
    az = np.full((n, cap), np.nan)
    size = np.zeros(n, dtype=np.int64)
    chord = 2.0 * math.sin(radius / 2)
    for r, near in enumerate(tree.query_ball_point(vec, chord)):
        near = np.sort(np.asarray(near, dtype=np.int64))  # the list order, as the thesis
        d = np.arccos(np.clip(vec[near] @ vec[r], -1.0, 1.0))
        keep = (near != r) & (d < radius) & (d > 0)
        near, d = near[keep][:cap], d[keep][:cap]  # stop at the cap (list order)
        order = np.argsort(d, kind="stable")
        near, d = near[order], d[order]
        k = len(near)
        member[r, :k], dist[r, :k], size[r] = near, d, k
        az[r, :k] = direction_angles_rad(vec[r], vec[near], faithful) if k else []
    return {"member": member, "dist_rad": dist, "az_rad": az, "size": size}
