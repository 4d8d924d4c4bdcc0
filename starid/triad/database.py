"""Yee's angular-separation database and the triad method's parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from adfusion.starid.camera.model import Camera
from adfusion.starid.catalog.stars import Catalog
from adfusion.starid.triad.angles import IntArray
from numpy.typing import ArrayLike

__all__ = ["YEE_MERGED_OFFSET", "SeparationDatabase", "TriadParams"]


#: Yee labels a merged candidate "HR 1xxxx": 10000 + the id of its brightest member.
YEE_MERGED_OFFSET = 10000


@dataclass(frozen=True)
class TriadParams:
    """Tolerances of Yee's triad method; defaults are the Vega/Deneb/Sadr set (Yee 1999 §4.2).

    Attributes:
        tol_sep_deg: pair matching, ``|θ_cat − θ_img| ≤ tol`` (also the final check).
        tol_rot_deg: the two rotation angles of a triad must agree within this.
        tol_encl_deg: every inner angle must agree within this; ``None`` disables the test
            (Yee's fixed-point version B, Yee 1999 §4.2.4).
        tol_group_deg: a triad joins the first group whose running mean rotation is this close.
        vote_number: minimum frequency of the winning candidate of a star (unique maximum).
        max_stars: only the first (brightest) image stars are used.
        cluster_radius_px: the detector's clustering radius τ; sets the default merge distance.
        merge_distance_deg: candidates of one image star closer than this are merged into
            one "HR 1xxxx" candidate; ``None`` means ``max(τ·s_x, τ·s_y)`` (Yee 1999 §2.3.4.3).
        min_matches: fewest matched stars that count as an identification (the plate fit
            needs three).

    >>> TriadParams().vote_number, TriadParams.oedipus().max_stars
    (2, 7)
    """

    tol_sep_deg: float = 0.15
    tol_rot_deg: float = 5.0
    tol_encl_deg: float | None = 1.0
    tol_group_deg: float = 5.0
    vote_number: int = 2
    max_stars: int = 12
    cluster_radius_px: float = 8.0
    merge_distance_deg: float | None = None
    min_matches: int = 3

    def __post_init__(self) -> None:
        for name in ("tol_sep_deg", "tol_rot_deg", "tol_group_deg", "cluster_radius_px"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and ≥ 0, got {v}")
        for name in ("tol_encl_deg", "merge_distance_deg"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be None or finite and ≥ 0, got {v}")
        if self.vote_number < 1:
            raise ValueError(f"vote_number must be ≥ 1, got {self.vote_number}")
        if self.max_stars < 3 or self.min_matches < 3:
            raise ValueError("max_stars and min_matches must be ≥ 3 (a triad, a plate fit)")

    @classmethod
    def oedipus(cls) -> TriadParams:
        """The OEDIPUS-C set (Yee 1999 §4.3): "found through trial and error".

        The merge distance is the thesis's 0.8693°, τ = 15 px times the x scale of the
        *uncorrected* 29.6716° FOV (Yee 1999 App. D.1) — not τ times the corrected scale.
        """
        return cls(
            tol_sep_deg=0.35, tol_rot_deg=10.0, tol_encl_deg=5.0, tol_group_deg=10.0,
            vote_number=2, max_stars=7, cluster_radius_px=15.0,
            merge_distance_deg=15.0 * 29.6716 / 512,
        )  # fmt: skip

    def merge_distance_for(self, camera: Camera) -> float:
        """Merge distance in degrees: the explicit value, or ``max(τ·s_x, τ·s_y)``.

        >>> round(TriadParams().merge_distance_for(Camera.yee(427, 319, 9.0130, 6.9049)), 4)
        0.1732
        """
        if self.merge_distance_deg is not None:
            return float(self.merge_distance_deg)
        sx, sy = _scales_deg(camera)
        return max(self.cluster_radius_px * sx, self.cluster_radius_px * sy)


class SeparationDatabase:
    """All catalogue pairs with separation ≤ ``max_sep_deg``, sorted by separation (§2.2).

    Attributes (read-only arrays): ``sep_deg`` ascending, ``idx_a < idx_b`` catalogue
    indices of each pair; ``catalog``, ``max_sep_deg``.

    >>> cat = Catalog([1, 2, 3], [[1, 0, 0], [1, 0.05, 0], [1, 0, 0.1]], [1.0, 2.0, 3.0])
    >>> db = SeparationDatabase.build(cat, 10.0)
    >>> np.round(db.sep_deg, 4).tolist(), cat.ids[db.idx_a].tolist(), cat.ids[db.idx_b].tolist()
    ([2.8624, 5.7106, 6.3857], [1, 1, 2], [2, 3, 3])
    >>> [a.tolist() for a in db.pairs_within(5.8, 0.1)]
    [[0], [2]]
    """

    def __init__(
        self,
        catalog: Catalog,
        max_sep_deg: float,
        sep_deg: ArrayLike,
        idx_a: ArrayLike,
        idx_b: ArrayLike,
    ) -> None:
        self.catalog = catalog
        self.max_sep_deg = float(max_sep_deg)
        self.sep_deg = _readonly(np.asarray(sep_deg, dtype=np.float64))
        self.idx_a = _readonly(np.asarray(idx_a, dtype=np.int64))
        self.idx_b = _readonly(np.asarray(idx_b, dtype=np.int64))
        if not (len(self.sep_deg) == len(self.idx_a) == len(self.idx_b)):
            raise ValueError("sep_deg, idx_a and idx_b must have the same length")
        if np.any(np.diff(self.sep_deg) < 0):
            raise ValueError("sep_deg must be sorted ascending")
        ra, dec = catalog.ra_rad, catalog.dec_rad
        # per-star quantities the triad tests need, computed once per catalogue
        self.ra_deg = _readonly(np.degrees(ra))
        self.dec_deg = _readonly(np.degrees(dec))

    @classmethod
    def build(cls, catalog: Catalog, max_sep_deg: float) -> SeparationDatabase:
        """Every pair of ``catalog`` closer than ``max_sep_deg`` (inclusive), sorted by θ."""
        if not (math.isfinite(max_sep_deg) and 0 <= max_sep_deg < 180):
            raise ValueError(f"max_sep_deg must be in [0, 180), got {max_sep_deg}")
        i, j, sep = catalog.pairs_within(math.radians(max_sep_deg))
        return cls(catalog, max_sep_deg, np.degrees(sep), i, j)

    def __len__(self) -> int:
        return len(self.sep_deg)

    def __repr__(self) -> str:
        return f"SeparationDatabase(n_pairs={len(self)}, max_sep_deg={self.max_sep_deg})"

    def pairs_within(self, theta_deg: float, tol_deg: float) -> tuple[IntArray, IntArray]:
        """Catalogue index pairs with ``|θ_cat − theta_deg| ≤ tol_deg`` (inclusive, as Yee).

        Two binary searches bound the slice, as in the thesis (§2.3.4).
        """
        lo = int(np.searchsorted(self.sep_deg, theta_deg - tol_deg, side="left"))
        hi = int(np.searchsorted(self.sep_deg, theta_deg + tol_deg, side="right"))
        return self.idx_a[lo:hi], self.idx_b[lo:hi]


def _scales_deg(camera: Camera) -> tuple[float, float]:
    """Degrees per pixel along x and y at the centre (Yee: FOV / pixels)."""
    return math.degrees(1.0 / camera.K[0, 0]), math.degrees(1.0 / camera.K[1, 1])


def _max_image_sep_deg(camera: Camera) -> float:
    """Largest separation two image points can have under the camera's separation model."""
    c = camera.corners()
    return float(np.degrees(np.max(camera.separation_rad(c[[0, 1]], c[[2, 3]]))))


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a
