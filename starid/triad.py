"""Yee (1999) triad star identification and plate-constant pointing (seeds/yee.md §2.2–§2.12).

Lost-in-space identification without magnitudes, in the thesis's steps:

1. :class:`SeparationDatabase` — every catalogue pair up to the largest camera angle, sorted
   by separation; image separations are looked up with a binary search, ``±tol_sep``.
2. Triads — every image triangle ``i < j < k`` of the first ``max_stars`` stars (brightest
   first) against every catalogue triad consistent with the three pair lists.
3. Rotation-angle test (rejects mirror images) and enclosed-angle test.
4. Grouping of the surviving triads by their mean rotation (a vote on the image roll).
5. Per-star vote in the largest group, with close candidates merged, then a pairwise
   separation check; at least three matched stars make an identification.
6. :func:`plate_solution` — Yee's iterated six-constant plate fit for the RA/Dec of the image
   centre; as our addition, ``q_cam_icrs`` from Wahba's problem on the matched stars (Yee
   gives no roll).

Conventions. The API takes DESIGN.md pixels (origin top-left, y down). The geometric tests
run, as Yee's did, in his centred, y-up image frame: ``x_c = parity·(x − cx)``,
``y_c = cy − y`` with ``cx, cy`` from ``camera.K`` (the parity flip un-mirrors a mirrored
camera, so the sky is seen as from inside the sphere: north up, east left). Angles in the
public signatures are degrees where the name says ``_deg``, as in the thesis's tables.

The conventions marked [VERIFIED] in yee.md are followed exactly; the choices made where
yee.md says [AMBIGUOUS] are marked "AMBIGUOUS:" in comments below.

Example:
    >>> import numpy as np
    >>> from adfusion.starid import rotations as rot
    >>> from adfusion.starid.camera import Camera
    >>> from adfusion.starid.catalog import Catalog
    >>> rng = np.random.default_rng(1)
    >>> cam = Camera.yee(400, 300, 10.0, 7.5)
    >>> q = rot.q_cam_icrs_from_radec_roll(np.radians(40.0), np.radians(20.0), 0.5)
    >>> xy = rng.uniform([20, 20], [380, 280], size=(6, 2))     # six "image stars"
    >>> r = rot.rotate(rot.inverse(q), cam.pixels_to_vectors(xy))
    >>> cat = Catalog(np.arange(1, 507), np.vstack([r, rng.normal(size=(500, 3))]),
    ...               np.full(506, 5.0))
    >>> res = identify_triads(xy, cam, cat)
    >>> res.ok, [hr for _, hr in res.matches]
    (True, [1, 2, 3, 4, 5, 6])
    >>> bool(rot.angle_between(res.q_cam_icrs, q) < 1e-9)
    True
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from itertools import combinations

import numpy as np
from adfusion.starid.attitude import wahba
from adfusion.starid.camera import Camera
from adfusion.starid.catalog import Catalog
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "YEE_MERGED_OFFSET",
    "PlateDivergenceError",
    "PlateSolution",
    "SeparationDatabase",
    "Triad",
    "TriadGroup",
    "TriadParams",
    "TriadResult",
    "catalog_angle_deg",
    "circular_mean_deg",
    "identify_triads",
    "image_angle_deg",
    "planar_angles_deg",
    "plate_pointing",
    "plate_solution",
    "rotation_angles_deg",
    "spherical_angles_deg",
    "yee_label",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Yee labels a merged candidate "HR 1xxxx": 10000 + the id of its brightest member.
YEE_MERGED_OFFSET = 10000


# --- parameters ------------------------------------------------------------------------------


@dataclass(frozen=True)
class TriadParams:
    """Tolerances of Yee's triad method; defaults are the Vega/Deneb/Sadr set (yee.md §2.13).

    Attributes:
        tol_sep_deg: pair matching, ``|θ_cat − θ_img| ≤ tol`` (also the final check).
        tol_rot_deg: the two rotation angles of a triad must agree within this.
        tol_encl_deg: every inner angle must agree within this; ``None`` disables the test
            (Yee's fixed-point version B, yee.md AC-14).
        tol_group_deg: a triad joins the first group whose running mean rotation is this close.
        vote_number: minimum frequency of the winning candidate of a star (unique maximum).
        max_stars: only the first (brightest) image stars are used.
        cluster_radius_px: the detector's clustering radius τ; sets the default merge distance.
        merge_distance_deg: candidates of one image star closer than this are merged into
            one "HR 1xxxx" candidate; ``None`` means ``max(τ·s_x, τ·s_y)`` (yee.md AC-07).
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
        """The OEDIPUS-C set (yee.md §4.6): "found through trial and error".

        The merge distance is the thesis's 0.8693°, τ = 15 px times the x scale of the
        *uncorrected* 29.6716° FOV (yee.md App. D.1) — not τ times the corrected scale.
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


# --- separation database ---------------------------------------------------------------------


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


# --- geometry of the tests ----------------------------------------------------------------------


def _wrap180(a: ArrayLike) -> FloatArray:
    """Angle(s) in degrees wrapped to (−180, 180]."""
    return 180.0 - np.mod(180.0 - np.asarray(a, dtype=np.float64), 360.0)


def image_angle_deg(xy_from: ArrayLike, xy_to: ArrayLike) -> FloatArray:
    """Direction of the image vector ``from → to`` in [0, 360), counter-clockwise from +x.

    Raw pixel offsets in Yee's centred y-up frame, *not* scaled to degrees ([VERIFIED]
    yee.md §2.6: scaling changes the thesis's rotation angles by up to 0.75°).

    >>> round(float(image_angle_deg([0, 0], [-1, -1])), 6)
    225.0
    """
    d = np.asarray(xy_to, dtype=np.float64) - np.asarray(xy_from, dtype=np.float64)
    return np.mod(np.degrees(np.arctan2(d[..., 1], d[..., 0])), 360.0)


def catalog_angle_deg(radec_from_deg: ArrayLike, radec_to_deg: ArrayLike) -> FloatArray:
    """Direction of the catalogue vector ``from → to`` as on a sky map (§2.6), in [0, 360).

    ``atan2(Δδ, −Δα)`` in raw degrees, Δα wrapped to (−180°, 180°] and without a cos δ
    factor (the thesis's planar treatment, [VERIFIED]); −Δα because east is to the left.

    >>> round(float(catalog_angle_deg([359.0, 10.0], [1.0, 10.0])), 6)   # 2° east, across 0h
    180.0
    """
    a = np.asarray(radec_from_deg, dtype=np.float64)
    b = np.asarray(radec_to_deg, dtype=np.float64)
    d_ra = _wrap180(b[..., 0] - a[..., 0])
    d_dec = b[..., 1] - a[..., 1]
    return np.mod(np.degrees(np.arctan2(d_dec, -d_ra)), 360.0)


def rotation_angles_deg(xy_centred_yup: ArrayLike, radec_deg: ArrayLike) -> tuple[float, float]:
    """Yee's rotation angles 1 and 2 for one triad (§2.6), each in [0, 360).

    ``xy_centred_yup``: (3, 2) image stars 1, 2, 3 (Yee's frame); ``radec_deg``: (3, 2) the
    catalogue stars HR1, HR2, HR3. Rotation n is the counter-clockwise angle taking image
    vector 1→(n+1) onto catalogue vector HR1→HR(n+1): ``(cat − img) mod 360``. The triad
    passes when ``|wrap180(rot1 − rot2)| ≤ tol_rot``.

    >>> rotation_angles_deg([[0, 0], [1, 0], [0, 1]], [[10, 0], [9, 0], [10, 1]])
    (0.0, 0.0)
    """
    p = np.asarray(xy_centred_yup, dtype=np.float64).reshape(3, 2)
    s = np.asarray(radec_deg, dtype=np.float64).reshape(3, 2)
    img = image_angle_deg(p[[0, 0]], p[[1, 2]])
    cat = catalog_angle_deg(s[[0, 0]], s[[1, 2]])
    rot = np.mod(cat - img, 360.0)
    return float(rot[0]), float(rot[1])


def circular_mean_deg(angles_deg: ArrayLike, axis: int = -1) -> FloatArray:
    """Mean direction of angles in degrees, in [0, 360) (wraps correctly across 0°).

    >>> round(float(circular_mean_deg([350.0, 20.0])), 6)
    5.0
    """
    a = np.radians(np.asarray(angles_deg, dtype=np.float64))
    m = np.degrees(np.arctan2(np.sin(a).sum(axis=axis), np.cos(a).sum(axis=axis)))
    return np.mod(m, 360.0)


def planar_angles_deg(p1: ArrayLike, p2: ArrayLike, p3: ArrayLike) -> FloatArray:
    """Inner angles (…, 3) in degrees at the vertices of planar triangle(s) p1 p2 p3.

    >>> np.round(planar_angles_deg([0, 0], [1, 0], [0, 1]), 6).tolist()
    [90.0, 45.0, 45.0]
    """
    pts = [np.asarray(p, dtype=np.float64) for p in (p1, p2, p3)]
    out = []
    for k in range(3):
        o, u, v = pts[k], pts[(k + 1) % 3], pts[(k + 2) % 3]
        a, b = u - o, v - o
        cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        out.append(np.degrees(np.arctan2(np.abs(cross), np.sum(a * b, axis=-1))))
    return np.stack(out, axis=-1)


def _side_angles_rad(v1: FloatArray, v2: FloatArray) -> FloatArray:
    cr = np.cross(v1, v2)
    return np.arctan2(np.linalg.norm(cr, axis=-1), np.sum(v1 * v2, axis=-1))


def spherical_angles_deg(v1: ArrayLike, v2: ArrayLike, v3: ArrayLike) -> FloatArray:
    """Inner angles (…, 3) in degrees at vertices v1, v2, v3 of spherical triangle(s).

    Spherical cosine rule (Eq. 2.5–2.7): ``A = acos((cos a − cos b cos c)/(sin b sin c))``
    with a, b, c the arcs opposite A, B, C.

    >>> np.round(spherical_angles_deg([1, 0, 0], [0, 1, 0], [0, 0, 1]), 6).tolist()
    [90.0, 90.0, 90.0]
    """
    u = [np.asarray(v, dtype=np.float64) for v in (v1, v2, v3)]
    u = [v / np.linalg.norm(v, axis=-1, keepdims=True) for v in u]
    a = _side_angles_rad(u[1], u[2])
    b = _side_angles_rad(u[0], u[2])
    c = _side_angles_rad(u[0], u[1])
    return _cosine_rule_deg(a, b, c)


def _cosine_rule_deg(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """Inner angles at the vertices opposite the arcs a, b, c (radians in, degrees out)."""

    def angle(x: FloatArray, y: FloatArray, z: FloatArray) -> FloatArray:
        with np.errstate(divide="ignore", invalid="ignore"):
            cos_x = (np.cos(x) - np.cos(y) * np.cos(z)) / (np.sin(y) * np.sin(z))
        return np.degrees(np.arccos(np.clip(cos_x, -1.0, 1.0)))

    return np.stack([angle(a, b, c), angle(b, a, c), angle(c, a, b)], axis=-1)


# --- results -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Triad:
    """A catalogue triad that passed both tests (one row of yee.md T4.2).

    ``stars``: image star indices (0-based, ascending); ``ids``: the catalogue ids assigned
    to them; ``rotation_deg``: rotation angles 1 and 2; ``mean_rotation_deg``: their circular
    mean; ``group``: index into :attr:`TriadResult.groups`.
    """

    stars: tuple[int, int, int]
    ids: tuple[int, int, int]
    rotation_deg: tuple[float, float]
    mean_rotation_deg: float
    group: int
    cat_index: tuple[int, int, int] = field(repr=False, default=(-1, -1, -1))


@dataclass(frozen=True)
class TriadGroup:
    """Triads sharing a rotation: ``mean_rotation_deg`` is the (circular) running mean of
    their mean rotations; ``triads`` indexes :attr:`TriadResult.triads`, in creation order."""

    index: int
    mean_rotation_deg: float
    triads: tuple[int, ...]


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


@dataclass(frozen=True)
class TriadResult:
    """Outcome of :func:`identify_triads`.

    Attributes:
        ok: at least ``min_matches`` stars identified and an attitude found.
        reason: why not ok ("" on success; a note if only the plate pointing failed).
        matches: (image star index, catalogue id) — for a merged candidate the id of its
            brightest member, whose position Yee uses; see ``members``.
        members: per matched image star, all catalogue ids of its candidate, brightest first
            (one id unless merged). :meth:`yee_labels` gives the thesis's "HR 1xxxx" labels.
        triads: every surviving triad, in creation order.
        groups: the triad groups, in creation order.
        chosen_group: the group the matches came from (the last one tried if none worked).
        votes: per image star, the candidate frequencies in that group, keyed by the
            candidate's member ids (brightest first; a 1-tuple for a single star).
        pair_counts: per image pair (i, j), the number of catalogue pairs within tol_sep.
        pointing_radec_deg: Yee's plate-constant image centre, or None.
        plate: the full plate solution, or None.
        q_cam_icrs: Wahba's attitude from the matched stars (our addition), or None.
    """

    ok: bool
    reason: str
    matches: list[tuple[int, int]] = field(default_factory=list)
    members: dict[int, tuple[int, ...]] = field(default_factory=dict)
    triads: list[Triad] = field(default_factory=list)
    groups: list[TriadGroup] = field(default_factory=list)
    chosen_group: int | None = None
    votes: dict[int, dict[tuple[int, ...], int]] = field(default_factory=dict)
    pair_counts: dict[tuple[int, int], int] = field(default_factory=dict)
    pointing_radec_deg: tuple[float, float] | None = None
    plate: PlateSolution | None = None
    q_cam_icrs: FloatArray | None = None

    def yee_labels(self) -> dict[int, int]:
        """Image star → the thesis's label: the id, or 10000 + id for a merged candidate."""
        return {s: yee_label(self.members[s]) for s, _ in self.matches}


def yee_label(members: tuple[int, ...]) -> int:
    """Yee's label of a candidate: its id, or ``10000 + brightest id`` when merged (HR only).

    >>> yee_label((7001,)), yee_label((7139, 7131))
    (7001, 17139)
    """
    return int(members[0]) if len(members) == 1 else YEE_MERGED_OFFSET + int(members[0])


# --- identification -----------------------------------------------------------------------------


def identify_triads(
    xy: ArrayLike,
    camera: Camera,
    catalog: Catalog,
    params: TriadParams | None = None,
    db: SeparationDatabase | None = None,
) -> TriadResult:
    """Identify image stars with Yee's triad method (yee.md §2.4–§2.9, flowcharts B.1–B.3).

    Args:
        xy: (N, 2) DESIGN pixels, brightest first (an (N, 3) xy+flux array is accepted);
            only the first ``params.max_stars`` are used.
        camera: gives the scales (1/fx, 1/fy), the centre (cx, cy) and the image
            separations (``camera.separation_rad``: Yee's Eq. 2.4 for the linear-angle model).
        catalog: the (sub-)catalogue; ids are reported as catalogue ids (HR for BSC5).
        params: tolerances (default: the thesis's Vega/Deneb/Sadr set).
        db: a prebuilt :class:`SeparationDatabase` of ``catalog`` (built here if None, up to
            the camera's largest image separation plus ``tol_sep``).

    See the module docstring for an example.
    """
    params = params or TriadParams()
    pts = np.asarray(xy, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise ValueError(f"xy must have shape (N, 2) or (N, 3), got {pts.shape}")
    pts = pts[: params.max_stars, :2]
    if not np.all(np.isfinite(pts)):
        raise ValueError("xy must be finite")
    n = len(pts)
    if n < 3:
        return TriadResult(False, f"need at least 3 image stars, got {n}")
    if db is None:
        db = SeparationDatabase.build(catalog, _max_image_sep_deg(camera) + params.tol_sep_deg)
    elif db.catalog is not catalog and not np.array_equal(db.catalog.ids, catalog.ids):
        raise ValueError("db was built from a different catalogue")

    xc = camera.parity * (pts[:, 0] - camera.K[0, 2])
    yc = camera.K[1, 2] - pts[:, 1]  # y up, as Yee's printed centroids
    pc = np.stack([xc, yc], axis=1)
    cat_vec = catalog.vectors
    radec = np.stack([db.ra_deg, db.dec_deg], axis=1)

    # pair lists (§2.4): image separations (Eq. 2.4) against the database
    sep_img = np.zeros((n, n))
    partners: dict[tuple[int, int], dict[int, list[int]]] = {}
    pair_keys: dict[tuple[int, int], set[tuple[int, int]]] = {}
    pair_counts: dict[tuple[int, int], int] = {}
    for i, j in combinations(range(n), 2):
        th = float(np.degrees(camera.separation_rad(pts[i], pts[j])[0]))
        sep_img[i, j] = sep_img[j, i] = th
        a, b = db.pairs_within(th, params.tol_sep_deg)
        pair_counts[(i, j)] = len(a)
        # catalogue pairs are unordered: either star may be either image star
        part: dict[int, list[int]] = {}
        for p, q in zip(a.tolist(), b.tolist(), strict=True):
            part.setdefault(p, []).append(q)
            part.setdefault(q, []).append(p)
        partners[(i, j)] = part
        pair_keys[(i, j)] = {(p, q) for p, q in zip(a.tolist(), b.tolist(), strict=True)} | {
            (q, p) for p, q in zip(a.tolist(), b.tolist(), strict=True)
        }

    # [INFERRED, yee.md §2.5] candidates in ascending catalogue id of HR1, then HR2, HR3;
    # only the group numbering depends on it (through the running-mean grouping)
    rank = np.empty(len(catalog), dtype=np.int64)
    rank[np.argsort(catalog.ids, kind="stable")] = np.arange(len(catalog))

    triads: list[Triad] = []
    group_sum: list[list[float]] = []  # per group: Σ cos, Σ sin of member mean rotations
    group_members: list[list[int]] = []
    for i, j, k in combinations(range(n), 3):
        cand = _candidate_triads(partners[(i, j)], partners[(i, k)], pair_keys[(j, k)])
        if not cand:
            continue
        c = np.array(cand, dtype=np.int64)
        c = c[np.lexsort((rank[c[:, 2]], rank[c[:, 1]], rank[c[:, 0]]))]
        # rotation-angle test (§2.6)
        img = image_angle_deg(pc[[i, i]], pc[[j, k]])
        rot1 = np.mod(catalog_angle_deg(radec[c[:, 0]], radec[c[:, 1]]) - img[0], 360.0)
        rot2 = np.mod(catalog_angle_deg(radec[c[:, 0]], radec[c[:, 2]]) - img[1], 360.0)
        ok = np.abs(_wrap180(rot1 - rot2)) <= params.tol_rot_deg
        # enclosed-angle test (§2.7): planar angles from raw pixels vs spherical catalogue
        # angles — the only combination that reproduces the thesis's counts [VERIFIED]
        if params.tol_encl_deg is not None and np.any(ok):
            img_in = planar_angles_deg(pc[i], pc[j], pc[k])
            v = cat_vec[c]
            cat_in = spherical_angles_deg(v[:, 0], v[:, 1], v[:, 2])
            ok &= np.all(np.abs(cat_in - img_in) <= params.tol_encl_deg, axis=1)
        for t in np.flatnonzero(ok):
            r1, r2 = float(rot1[t]), float(rot2[t])
            mean = float(circular_mean_deg([r1, r2]))
            g = _join_group(mean, group_sum, params.tol_group_deg)
            if g == len(group_sum):
                group_sum.append([0.0, 0.0])
                group_members.append([])
            group_sum[g][0] += math.cos(math.radians(mean))
            group_sum[g][1] += math.sin(math.radians(mean))
            group_members[g].append(len(triads))
            ci = (int(c[t, 0]), int(c[t, 1]), int(c[t, 2]))
            ids = (int(catalog.ids[ci[0]]), int(catalog.ids[ci[1]]), int(catalog.ids[ci[2]]))
            triads.append(Triad((i, j, k), ids, (r1, r2), mean, g, ci))

    groups = [
        TriadGroup(g, _mean_of(group_sum[g]), tuple(m)) for g, m in enumerate(group_members)
    ]
    base = {"triads": triads, "groups": groups, "pair_counts": pair_counts}
    if not groups:
        return TriadResult(False, "no catalogue triad passed the rotation and enclosed tests",
                           **base)

    # matching (B.2): the largest group(s) in creation order, until ≥ min_matches survive
    biggest = max(len(g.triads) for g in groups)
    merge_deg = params.merge_distance_for(camera)
    votes: dict[int, dict[tuple[int, ...], int]] = {}
    chosen: int | None = None
    matched: dict[int, tuple[int, ...]] = {}
    for g in (g for g in groups if len(g.triads) == biggest):
        chosen = g.index
        votes_idx, picks = _vote(g, triads, n, catalog, merge_deg, params.vote_number)
        votes = {s: {_ids(catalog, m): f for m, f in d.items()} for s, d in votes_idx.items()}
        matched = _separation_check(picks, votes_idx, sep_img, cat_vec, params.tol_sep_deg)
        if len(matched) >= params.min_matches:
            break
    base.update(chosen_group=chosen, votes=votes)
    if len(matched) < params.min_matches:
        return TriadResult(
            False,
            f"only {len(matched)} star(s) matched in the largest group(s) of {biggest} "
            f"triad(s); need {params.min_matches}",
            **base,
        )

    stars = sorted(matched)
    matches = [(s, int(catalog.ids[matched[s][0]])) for s in stars]
    members = {s: _ids(catalog, matched[s]) for s in stars}
    bright = np.array([matched[s][0] for s in stars])
    # Wahba on the brightest member's direction, the position Yee uses for merged stars
    try:
        sol = wahba(camera.pixels_to_vectors(pts[stars]), cat_vec[bright],
                    sigma_rad=camera.pixel_scale_rad)
        q = sol.q_cam_icrs
    except ValueError as e:
        return TriadResult(False, f"attitude undetermined: {e}", matches, members, **base)
    reason = ""
    plate = None
    try:
        sx, sy = _scales_deg(camera)
        plate = plate_solution(pc[stars], radec[bright], sx, sy)
    except (PlateDivergenceError, ValueError) as e:
        reason = f"plate pointing failed: {e}"
    pointing = (plate.ra_deg, plate.dec_deg) if plate is not None else None
    return TriadResult(True, reason, matches, members, **base, pointing_radec_deg=pointing,
                       plate=plate, q_cam_icrs=q)


def _candidate_triads(
    p_ij: dict[int, list[int]], p_ik: dict[int, list[int]], keys_jk: set[tuple[int, int]]
) -> list[tuple[int, int, int]]:
    """Catalogue triads (H1, H2, H3) with H1H2 in list(i,j), H1H3 in list(i,k), H2H3 in
    list(j,k), three distinct stars (§2.5)."""
    out = []
    for h1 in p_ij.keys() & p_ik.keys():
        for h2 in p_ij[h1]:
            for h3 in p_ik[h1]:
                if h3 != h2 and (h2, h3) in keys_jk:
                    out.append((h1, h2, h3))
    return out


def _join_group(mean: float, sums: list[list[float]], tol: float) -> int:
    """Index of the first group (creation order) whose running mean is within ``tol``.

    [VERIFIED, yee.md §2.8] first match in creation order, against the running mean of the
    members' mean rotations. AMBIGUOUS: mean as plain or circular average — circular here,
    so groups near 0°/360° work; within a 5–10° group the two differ by < 0.001°.
    """
    for g, s in enumerate(sums):
        if abs(float(_wrap180(mean - _mean_of(s)))) <= tol:
            return g
    return len(sums)


def _mean_of(s: list[float]) -> float:
    return float(np.mod(math.degrees(math.atan2(s[1], s[0])), 360.0))


def _ids(catalog: Catalog, members: tuple[int, ...]) -> tuple[int, ...]:
    return tuple(int(catalog.ids[m]) for m in members)


def _vote(
    group: TriadGroup,
    triads: list[Triad],
    n: int,
    catalog: Catalog,
    merge_deg: float,
    vote_number: int,
) -> tuple[dict[int, dict[tuple[int, ...], int]], dict[int, tuple[int, ...]]]:
    """Per-star candidate frequencies with merged candidates, and the winners (B.3).

    Keys are tuples of catalogue indices, brightest first. Returns (votes, picks).
    """
    votes: dict[int, dict[tuple[int, ...], int]] = {}
    picks: dict[int, tuple[int, ...]] = {}
    for s in range(n):
        freq: Counter[int] = Counter()
        for t in group.triads:
            tr = triads[t]
            if s in tr.stars:
                freq[tr.cat_index[tr.stars.index(s)]] += 1
        if not freq:
            continue
        cands = sorted(freq, key=lambda m: int(catalog.ids[m]))
        entry: dict[tuple[int, ...], int] = {(m,): freq[m] for m in cands}
        # the originals stay in the list; each cluster of ≥ 2 adds one combined candidate
        for cl in _clusters(cands, catalog, merge_deg):
            entry[cl] = sum(freq[m] for m in cl)
        votes[s] = entry
        best = max(entry.values())
        winners = [m for m, f in entry.items() if f == best]
        if best >= vote_number and len(winners) == 1:
            picks[s] = winners[0]
    return votes, picks


def _clusters(cands: list[int], catalog: Catalog, merge_deg: float) -> list[tuple[int, ...]]:
    """Groups (≥ 2) of candidates close enough to be imaged as one star, brightest first.

    AMBIGUOUS (yee.md §2.9): how clusters of ≥ 3 form. Transitive linking (connected
    components of "separation ≤ merge distance") — it reproduces 17051 = {7051, 7053, 7054}.
    Brightest = smallest magnitude, ties to the smaller id.
    """
    if len(cands) < 2:
        return []
    v = catalog.vectors[cands]
    close = np.degrees(_side_angles_rad(v[:, None, :], v[None, :, :])) <= merge_deg
    label = list(range(len(cands)))

    def root(a: int) -> int:
        while label[a] != a:
            label[a] = label[label[a]]
            a = label[a]
        return a

    for a, b in zip(*np.nonzero(np.triu(close, 1)), strict=True):
        label[root(int(a))] = root(int(b))
    comps: dict[int, list[int]] = {}
    for a in range(len(cands)):
        comps.setdefault(root(a), []).append(cands[a])
    out = []
    for members in comps.values():
        if len(members) >= 2:
            members.sort(key=lambda m: (float(catalog.mag[m]), int(catalog.ids[m])))
            out.append(tuple(members))
    return out


def _separation_check(
    picks: dict[int, tuple[int, ...]],
    votes: dict[int, dict[tuple[int, ...], int]],
    sep_img: FloatArray,
    cat_vec: FloatArray,
    tol_deg: float,
) -> dict[int, tuple[int, ...]]:
    """Final check (B.2): every matched pair's catalogue separation within ``tol_deg``.

    AMBIGUOUS (yee.md §2.9 #4): a merged candidate passes if *any* member does — taken
    literally the thesis's own Vega result (17139–6872, Δ = 0.186°) would fail.
    AMBIGUOUS: which star to drop on a conflict. We drop, one at a time, the star in the
    most failing pairs (ties: the lower vote, then the fainter i.e. later image star), so a
    single wrong match does not take its correct partners with it.
    """
    kept = dict(picks)
    while True:
        stars = sorted(kept)
        bad: Counter[int] = Counter()
        for s, t in combinations(stars, 2):
            va, vb = cat_vec[list(kept[s])], cat_vec[list(kept[t])]
            cat = np.degrees(_side_angles_rad(va[:, None, :], vb[None, :, :]))
            if not np.any(np.abs(cat - sep_img[s, t]) <= tol_deg):
                bad[s] += 1
                bad[t] += 1
        if not bad:
            return kept
        worst = max(bad, key=lambda s: (bad[s], -votes[s][kept[s]], s))
        del kept[worst]


# --- pointing (§2.4) ---------------------------------------------------------------------------


class PlateDivergenceError(RuntimeError):
    """Yee's plate iteration did not converge (e.g. OEDIPUS-C image 24, yee.md AC-19)."""


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


# --- helpers -----------------------------------------------------------------------------------


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
