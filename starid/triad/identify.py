"""Yee (1999) triad star identification and plate-constant pointing (docs/references.md#yee-1999).

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

Conventions. The API takes docs/conventions.md pixels (origin top-left, y down). The geometric tests
run, as Yee's did, in his centred, y-up image frame: ``x_c = parity·(x − cx)``,
``y_c = cy − y`` with ``cx, cy`` from ``camera.K`` (the parity flip un-mirrors a mirrored
camera, so the sky is seen as from inside the sphere: north up, east left). Angles in the
public signatures are degrees where the name says ``_deg``, as in the thesis's tables.

The conventions the thesis verifiably uses are followed exactly; the choices made where
the thesis leaves open are marked "AMBIGUOUS:" in comments below.

Example:
    >>> import numpy as np
    >>> from adfusion.starid import rotations as rot
    >>> from adfusion.starid.camera.model import Camera
    >>> from adfusion.starid.catalog.stars import Catalog
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
from adfusion.starid.camera.model import Camera
from adfusion.starid.catalog.stars import Catalog
from adfusion.starid.triad.angles import (
    FloatArray,
    _side_angles_rad,
    _wrap180,
    catalog_angle_deg,
    circular_mean_deg,
    image_angle_deg,
    planar_angles_deg,
    spherical_angles_deg,
)
from adfusion.starid.triad.database import (
    YEE_MERGED_OFFSET,
    SeparationDatabase,
    TriadParams,
    _max_image_sep_deg,
    _scales_deg,
)
from adfusion.starid.triad.plate import PlateDivergenceError, PlateSolution, plate_solution
from numpy.typing import ArrayLike

from adfusion.maths.attitude import wahba

__all__ = ["Triad", "TriadGroup", "TriadResult", "identify_triads", "yee_label"]


@dataclass(frozen=True)
class Triad:
    """A catalogue triad that passed both tests (one row of Yee 1999 T4.2).

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


def identify_triads(
    xy: ArrayLike,
    camera: Camera,
    catalog: Catalog,
    params: TriadParams | None = None,
    db: SeparationDatabase | None = None,
) -> TriadResult:
    """Identify image stars with Yee's triad method (Yee 1999 §2.3.4, flowcharts B.1–B.3).

    Args:
        xy: (N, 2) pixels (docs/conventions.md), brightest first (an (N, 3) xy+flux array is
            accepted);
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

    # [INFERRED from Yee 1999 §2.3.4] candidates in ascending catalogue id of HR1, then HR2, HR3;
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

    [as Yee 1999 §2.3.4.2] first match in creation order, against the running mean of the
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

    AMBIGUOUS (Yee 1999 §2.3.4.3): how clusters of ≥ 3 form. Transitive linking (connected
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

    AMBIGUOUS (Yee 1999 §2.3.4.3): a merged candidate passes if *any* member does — taken
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
