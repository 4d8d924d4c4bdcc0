"""Bleif's MusterPr reference-star matcher (DLR-TUBSAT, Bleif 2004 §4.2.5).

The operator marks stars in the image; the first is the *reference*. Every pattern of a
:class:`~starid.bleif.patterns.PatternCatalog` (one per catalogue star as reference) is
tried in catalogue order, in two stages with early exits:

1. **distances** — each other marked star needs a pattern star whose distance to the
   reference differs by at most ``2·k_x·T_pix`` (Eq. 4.14; 0.1752° with the thesis's
   k_x = 0.0292°/px and T_pix = 3 px); the first marked star without one rejects the
   pattern;
2. **intermediate angles** — each pair (i, j) of marked stars needs a pattern pair whose
   direction-angle difference matches the image's within ``k_tol·σ_φ,ij``; σ_φ is the
   Gauss-propagated marking error of the angle at the reference (Eq. 4.17–4.27, closed
   form in :func:`sigma_phi_rad`); the first pair without one rejects the pattern.

``k_miss > 0`` is the tolerant (k-of-n) mode: up to ``k_miss`` marked stars may stay
without a partner (a hot-pixel block, a planet); the thesis's strict mode is ``k_miss = 0``.
The default (modern) assignment is one-to-one and consistent over all pairs; with
``faithful=True`` the thesis's single PATCP slots are overwritten pair by pair
(docs/references.md#bleif-2004) and image distances and angles use the plane formulas Eq. 4.11–4.13
with the camera's k_x, k_y — otherwise they come from the camera model.

Attitude per candidate: ``attitude="wahba"`` (default) fits all marked stars (with
covariance); ``attitude="thesis"`` is CalcAzimut (a *circular* distance-weighted mean,
Eq. 4.29/4.30) plus the Dreibein tripod (Eq. 4.31–4.41) on the first three stars, which
refuses a near-collinear triple (:class:`CollinearTripleError`) instead of solving it.

Example (a synthetic selection of five stars; the truth is the only candidate):
    >>> import numpy as np
    >>> from adfusion.starid import rotations as rot
    >>> from adfusion.starid.catalog.stars import Catalog
    >>> from adfusion.starid.bleif.patterns import PatternCatalog
    >>> pc = PatternCatalog.build(Catalog.hipparcos(mag_limit=6.5))
    >>> cam = tubsat_camera()
    >>> q = rot.q_cam_icrs_from_radec_roll(*np.radians([97.4, 49.1, 30.0]))
    >>> xy, idx = stars_in_frame(pc, cam, q)
    >>> sel = np.r_[np.argmin(np.hypot(*(xy - cam.K[:2, 2]).T)), 0:5]
    >>> sel = list(dict.fromkeys(sel.tolist()))[:5]
    >>> cands = list(find_matches(pc, xy[sel], cam))
    >>> len(cands), cands[0].pattern == int(idx[sel[0]])
    (1, True)
    >>> bool(np.degrees(rot.angle_between(cands[0].q_cam_icrs, q)) < 1e-6)
    True
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from adfusion.starid.bleif.patterns import PatternCatalog, direction_angles_rad
from adfusion.starid.bleif.star_angles import (
    q_cam_icrs_from_star_angles,
    star_angles_from_q_cam_icrs,
)
from adfusion.starid.camera.model import Camera
from numpy.typing import ArrayLike, NDArray

from adfusion.maths import rotations as rot
from adfusion.maths.attitude import wahba

__all__ = [
    "KX_DEG",
    "KY_DEG",
    "T_PIX",
    "BleifCandidate",
    "BleifParams",
    "CollinearTripleError",
    "MatchCounters",
    "Overlay",
    "attitude_thesis",
    "calc_azimut_deg",
    "detection_selections",
    "distance_tolerance_deg",
    "dreibein",
    "find_matches",
    "operator_marks",
    "overlay",
    "selection_of",
    "sigma_phi_numeric_rad",
    "sigma_phi_rad",
    "stars_in_frame",
    "tubsat_camera",
]

KX_DEG = 0.0292  # Bleif 2004 §3.1.1: measured scale factors of the 16 mm head (deg/px)
KY_DEG = 0.0282
T_PIX = 3.0  # px: the allowed marking offset (Eq. 4.14, "3 gave good results")
_CHUNK = 512  # patterns per vectorised distance stage (keeps the iterator lazy)
# a thesis attitude that misses a mark by more than twice the distance tolerance (0.35°,
# 12 px) contradicts the marks: flagged
_THESIS_RESIDUAL_MAX_DEG = 0.35


def tubsat_camera(parity: int = 1) -> Camera:
    """The 16 mm star-sensor head: constant k_x = 0.0292, k_y = 0.0282 °/px over the chip
    (the thesis found distortion negligible), 753 × 596 px = 22.0° × 16.8°.

    >>> cam = tubsat_camera()
    >>> round(cam.fov_x_deg, 1), round(cam.fov_y_deg, 1)
    (22.0, 16.8)
    """
    w, h = 753, 596
    return Camera.yee(w, h, w * KX_DEG, h * KY_DEG, parity=parity)


def distance_tolerance_deg(kx_deg: float = KX_DEG, t_pix: float = T_PIX) -> float:
    """Eq. 4.14: ±2·k_x·T_pix (the factor 2: both marked stars may be off by T_pix).

    >>> round(distance_tolerance_deg(), 10)
    0.1752
    """
    return 2.0 * kx_deg * t_pix


def sigma_phi_rad(p_ref: ArrayLike, p_i: ArrayLike, p_j: ArrayLike,
                  sigma_p: float = T_PIX) -> float:
    """σ of the angle at ``p_ref`` between ``p_i`` and ``p_j`` (pixels), every coordinate
    with error ``sigma_p`` (Eq. 4.27, closed form: σ_p·√(2/d_i² + 2/d_j² − 2cosφ/(d_i d_j))).

    >>> round(sigma_phi_rad((0, 0), (100, 0), (0, 100), 1.0), 6)
    0.02
    """
    r, a, b = (np.asarray(p, dtype=np.float64) for p in (p_ref, p_i, p_j))
    vi, vj = a - r, b - r
    di, dj = float(np.hypot(*vi)), float(np.hypot(*vj))
    cos_phi = float(vi @ vj) / (di * dj)
    return sigma_p * math.sqrt(max(0.0, 2 / di**2 + 2 / dj**2 - 2 * cos_phi / (di * dj)))


def sigma_phi_numeric_rad(p_ref: ArrayLike, p_i: ArrayLike, p_j: ArrayLike,
                          sigma_p: float = T_PIX, h: float = 1e-6) -> float:
    """The same σ by Gauss propagation (Eq. 4.17) of Eq. 4.19 with central differences.

    >>> round(sigma_phi_numeric_rad((0, 0), (50, 0), (0, 200), 1.0), 6)
    0.029155
    """
    x = np.concatenate([np.asarray(p, dtype=np.float64) for p in (p_ref, p_i, p_j)])

    def phi(x: NDArray) -> float:
        vi, vj = x[2:4] - x[0:2], x[4:6] - x[0:2]
        return math.acos(float(vi @ vj) / (np.hypot(*vi) * np.hypot(*vj)))

    grad = []
    for k in range(6):
        e = np.zeros(6)
        e[k] = h
        grad.append((phi(x + e) - phi(x - e)) / (2 * h))
    return sigma_p * math.sqrt(sum(g * g for g in grad))


class CollinearTripleError(ValueError):
    """The Dreibein triple is too close to collinear for a trustworthy boresight."""


@dataclass
class MatchCounters:
    """What the search did (docs/references.md#bleif-2004): the marked stars and pairs the
    thesis's sequential loops examine before a pattern is rejected — its early exits. The
    stages run vectorised over many patterns at once; the counts are those of the
    sequential algorithm, which the vectorised one reproduces decision for decision
    (``pair_checks`` is counted in strict mode only)."""

    patterns: int = 0  # patterns examined
    rejected_distance: int = 0
    distance_checks: int = 0  # marked stars examined in the distance stage, in total
    rejected_angle: int = 0
    pair_checks: int = 0  # pairs examined in the angle stage, in total
    rejected_assignment: int = 0  # every pair had a partner, no consistent assignment
    candidates: int = 0


@dataclass(frozen=True)
class BleifCandidate:
    """One pattern that fits the marked stars.

    ``assignment`` pairs each marked star (index into the clicks) with a catalogue id
    (``None``: left out in tolerant mode); ``star_index`` holds the same as indices into
    the pattern catalogue's star list (−1 = none). ``ra_de_az_deg`` are Bleif's star
    angles (AZ: image up from north towards west). ``residuals_rad``: per marked star, the
    angle between its line of sight and its catalogue star at this attitude (NaN for a
    star left out). ``problem`` is non-empty when no attitude could be computed (then
    ``q_cam_icrs`` is None, e.g. a near-collinear Dreibein triple) or when the thesis
    attitude misses a marked star by more than 0.35° (kept, but flagged).
    """

    pattern: int
    ref_id: int
    assignment: list[tuple[int, int | None]]
    star_index: NDArray[np.int64]
    q_cam_icrs: NDArray[np.float64] | None
    covariance: NDArray[np.float64] | None
    residuals_rad: NDArray[np.float64]
    n_missing: int = 0
    method: str = "wahba"
    problem: str = ""
    camera: Camera | None = field(default=None, repr=False)

    @property
    def ra_de_az_deg(self) -> tuple[float, float, float] | None:
        if self.q_cam_icrs is None:
            return None
        return tuple(math.degrees(a) for a in star_angles_from_q_cam_icrs(
            self.q_cam_icrs))  # type: ignore[return-value]

    @property
    def matches(self) -> list[tuple[int, int]]:
        """(click index, catalogue id) of the assigned stars (as ``Solution.matches``)."""
        return [(d, c) for d, c in self.assignment if c is not None]


@dataclass(frozen=True)
class _Marked:
    """The marked stars prepared as in §5.5: reference first, the others by distance."""

    xy: NDArray[np.float64]  # (n, 2) clicks as given
    order: NDArray[np.int64]  # non-reference clicks, ascending distance
    dist: NDArray[np.float64]  # (n−1,) rad, in ``order``
    alpha: NDArray[np.float64]  # (n−1,) rad, direction angles at the reference
    sigma: NDArray[np.float64]  # (n−1, n−1) σ_φ of every pair (rad)
    vectors: NDArray[np.float64]  # (n, 3) camera-frame lines of sight


def _prepare(xy: NDArray, cam: Camera, faithful: bool, sigma_p: float) -> _Marked:
    b = cam.pixels_to_vectors(xy)
    ref = xy[0]
    if faithful:  # Eq. 4.11–4.13 in the C frame (x right, y up), k constant on the chip
        kx, ky = 1.0 / cam.K[0, 0], 1.0 / cam.K[1, 1]
        dx = cam.parity * (xy[1:, 0] - ref[0]) * kx
        dy = -(xy[1:, 1] - ref[1]) * ky
        dist = np.hypot(dx, dy)
        alpha = np.mod(np.arctan2(dx, dy), 2 * np.pi)
    else:  # exact: separations and the angle at the reference on the sphere
        r = b[0]
        dist = np.arccos(np.clip(b[1:] @ r, -1.0, 1.0))
        up = np.array([0.0, -1.0, 0.0]) - r * (-r[1])  # image up in r's tangent plane
        up /= np.linalg.norm(up)
        right = np.cross(r, up)  # first × second = r, as north × west = r on the sky
        alpha = np.mod(np.arctan2(b[1:] @ right, b[1:] @ up), 2 * np.pi)
    order = np.argsort(dist, kind="stable")
    n = len(order)
    sig = np.zeros((n, n))
    p = xy[1:][order]
    for i in range(n):
        for j in range(i + 1, n):
            sig[i, j] = sig[j, i] = sigma_phi_rad(ref, p[i], p[j], sigma_p)
    return _Marked(xy, order + 1, dist[order], alpha[order], sig, b)


def _wrap(a: NDArray | float) -> NDArray | float:
    """Angle difference wrapped to (−π, π]."""
    return np.pi - np.mod(np.pi - a, 2 * np.pi)


def find_matches(
    patterns: PatternCatalog,
    xy: ArrayLike,
    camera: Camera,
    *,
    k_miss: int = 0,
    faithful: bool = False,
    attitude: str = "wahba",
    t_pix: float = T_PIX,
    sigma_p: float | None = None,
    k_tol: float = 2.0,
    click_sigma_px: float = 1.5,
    counters: MatchCounters | None = None,
) -> Iterator[BleifCandidate]:
    """Candidates for the marked stars ``xy`` (pixels, the reference first), lazily and in
    catalogue order (see the module docstring). ``sigma_p`` defaults to ``t_pix``
    (Eq. 4.26); ``click_sigma_px`` is the 1-σ marking error per axis behind the Wahba
    covariance (±3 px uniformly in a disc has 1.5 px)."""
    pts = np.asarray(xy, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3:
        raise ValueError(f"mark at least 3 stars as an (n, 2) pixel array, got shape "
                         f"{pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("marked star positions must be finite")
    if len(pts) > 10 + k_miss:
        raise ValueError(f"at most 10 marked stars (+ k_miss), got {len(pts)}")
    if attitude not in ("wahba", "thesis"):
        raise ValueError(f"attitude must be 'wahba' or 'thesis', got {attitude!r}")
    if not 0 <= k_miss <= len(pts) - 3:
        raise ValueError(f"k_miss must be in [0, {len(pts) - 3}] for {len(pts)} marked "
                         f"stars (at least two besides the reference must match)")
    counters = counters if counters is not None else MatchCounters()
    m = _prepare(pts, camera, faithful, t_pix if sigma_p is None else sigma_p)
    dtol = math.radians(distance_tolerance_deg(math.degrees(1.0 / camera.K[0, 0]), t_pix))
    n_other = len(m.dist)
    for start in range(0, len(patterns), _CHUNK):
        D = patterns.dist_rad[start:start + _CHUNK]
        # stage 1, vectorised over the chunk: hit[j, p] = marked star j has a partner
        hit = np.stack([np.any(np.abs(D - d) <= dtol, axis=1) for d in m.dist])
        miss = np.cumsum(~hit, axis=0)  # misses among the first j + 1 stars
        over = miss > k_miss
        fails = over.any(axis=0)
        first_fail = np.where(fails, np.argmax(over, axis=0) + 1, n_other)
        counters.patterns += len(D)
        counters.distance_checks += int(first_fail.sum())
        counters.rejected_distance += int(fails.sum())
        surv = np.flatnonzero(~fails)
        if len(surv) and n_other >= 2:
            # stage 2, vectorised over the survivors: has[s, q] = pair q has a partner pair
            stage = _PairStage(D[surv], patterns.az_rad[start:start + _CHUNK][surv], m,
                               dtol, k_tol)
            if k_miss == 0:  # strict: the first pair without a partner rejects the pattern
                rows = np.arange(len(surv))
                for q in range(len(stage.iu)):  # pair by pair, on the survivors only
                    counters.pair_checks += len(rows)
                    ok = stage.pair(q, rows)
                    counters.rejected_angle += int((~ok).sum())
                    rows = rows[ok]
                    if not len(rows):
                        break
                surv = surv[rows]
            else:  # k-of-n: n − k stars, each with partner pairs to the n − k − 1 others
                has = stage.table()
                need = n_other - k_miss
                iu, ju = np.triu_indices(n_other, 1)
                deg = np.zeros((len(surv), n_other), dtype=np.int64)
                np.add.at(deg, (slice(None), iu), has)
                np.add.at(deg, (slice(None), ju), has)
                keep = (deg >= need - 1).sum(axis=1) >= need
                counters.rejected_angle += int((~keep).sum())
                surv = surv[keep]
        for off in surv.tolist():
            p = start + off
            cand = _try_pattern(patterns, p, m, dtol, k_miss, k_tol, faithful, counters)
            if cand is None:
                continue
            counters.candidates += 1
            yield _with_attitude(patterns, p, m, cand, camera, attitude, click_sigma_px)


def _try_pattern(pc: PatternCatalog, p: int, m: _Marked, dtol: float, k_miss: int,
                 k_tol: float, faithful: bool, counters: MatchCounters,
                 ) -> tuple[NDArray[np.int64], int] | None:
    """Stage 2 and the assignment for pattern ``p``: member positions per marked star
    (sorted order, −1 = left out) and the number left out, or None."""
    size = int(pc.size[p])
    d, az = pc.dist_rad[p, :size], pc.az_rad[p, :size]
    lo = np.searchsorted(d, m.dist - dtol, side="left")
    hi = np.searchsorted(d, m.dist + dtol, side="right")
    # CCDCP: each marked star's distance partners, the closest distance first (the
    # assignment then prefers them: a close double's wrong component comes second)
    cp = []
    for j, (a, b) in enumerate(zip(lo.tolist(), hi.tolist(), strict=True)):
        k = np.arange(a, b)
        cp.append(k[np.argsort(np.abs(d[k] - m.dist[j]), kind="stable")])
    n = len(cp)
    phi = _wrap(m.alpha[:, None] - m.alpha[None, :])  # Eq. 4.15
    # every candidate pair at once: pattern pair (l, k) fits image pair (label l, label k)
    allc = np.concatenate(cp)
    offs = np.r_[0, np.cumsum([len(c) for c in cp])]
    lab = np.repeat(np.arange(n), np.diff(offs))
    diff = _wrap(az[allc][:, None] - az[allc][None, :])  # Eq. 4.16
    ok = np.abs(_wrap(diff - phi[lab[:, None], lab[None, :]])) < (
        k_tol * m.sigma[lab[:, None], lab[None, :]])  # Eq. 4.28
    ok &= allc[:, None] != allc[None, :]
    if k_miss == 0 and faithful:  # the thesis's PATCP slots, overwritten pair by pair
        patcp = np.full(n, -1, dtype=np.int64)
        for i in range(n):
            for j in range(i + 1, n):
                hit = np.argwhere(ok[offs[i]:offs[i + 1], offs[j]:offs[j + 1]])
                if len(hit) == 0:
                    return None
                patcp[i], patcp[j] = cp[i][hit[0, 0]], cp[j][hit[0, 1]]
        return patcp, 0
    choice = _consistent_assignment([list(range(offs[j], offs[j + 1])) for j in range(n)],
                                    allc.tolist(), ok.tolist(), k_miss)
    if choice is None:
        counters.rejected_assignment += 1
        return None
    assign = np.array([allc[g] if g >= 0 else -1 for g in choice], dtype=np.int64)
    return assign, int(np.sum(assign < 0))


class _PairStage:
    """Stage 2 vectorised over patterns: their distance partners per marked star (as a
    padded window of member positions) and, per image pair, whether a partner pair's
    direction-angle difference fits (Eq. 4.28)."""

    def __init__(self, D: NDArray, AZ: NDArray, m: _Marked, dtol: float, k_tol: float):
        lo = np.stack([(D < d - dtol).sum(axis=1) for d in m.dist], axis=1)  # (S, n)
        hi = np.stack([(D <= d + dtol).sum(axis=1) for d in m.dist], axis=1)
        width = hi - lo
        w = max(int(width.max()), 1)
        self.idx = lo[:, :, None] + np.arange(w)  # (S, n, w) member positions
        self.valid = np.arange(w) < width[:, :, None]
        self.az = np.take_along_axis(AZ[:, None, :], np.minimum(self.idx, AZ.shape[1] - 1),
                                     axis=2)
        self.phi = _wrap(m.alpha[:, None] - m.alpha[None, :])
        self.tol = k_tol * m.sigma
        self.iu, self.ju = np.triu_indices(len(m.dist), 1)

    def pair(self, q: int, rows: NDArray | slice = slice(None)) -> NDArray[np.bool_]:
        """Pair number ``q`` (``np.triu_indices`` order) for the patterns ``rows``."""
        i, j = int(self.iu[q]), int(self.ju[q])
        az, valid, idx = self.az[rows], self.valid[rows], self.idx[rows]
        ok = np.abs(_wrap(az[:, i, :, None] - az[:, j, None, :] - self.phi[i, j])) \
            < self.tol[i, j]
        ok &= valid[:, i, :, None] & valid[:, j, None, :]
        ok &= idx[:, i, :, None] != idx[:, j, None, :]
        return ok.any(axis=(1, 2))

    def table(self) -> NDArray[np.bool_]:
        """Every pair for every pattern, (S, n_pairs)."""
        return np.stack([self.pair(q) for q in range(len(self.iu))], axis=1)


def _consistent_assignment(cand: list[list[int]], member: list[int], ok: list[list[bool]],
                           k_miss: int) -> list[int] | None:
    """A one-to-one assignment of marked stars to pattern stars that fits every pair
    (``cand[j]``: star j's candidates, as indices into ``member`` and the pair table
    ``ok``), with as few stars left out as possible (at most ``k_miss``); depth-first.
    Returns each star's candidate (−1: left out)."""
    n = len(cand)
    out = [-1] * n

    def extend(j: int, skips: int, allowed: int) -> bool:
        if j == n:
            return True
        chosen = [g for g in out[:j] if g >= 0]
        used = {member[g] for g in chosen}
        for g in cand[j]:
            if member[g] not in used and all(ok[h][g] for h in chosen):
                out[j] = g
                if extend(j + 1, skips, allowed):
                    return True
        out[j] = -1
        return skips < allowed and extend(j + 1, skips + 1, allowed)

    for allowed in range(k_miss + 1):
        if extend(0, 0, allowed):
            return out
    return None


def _with_attitude(pc: PatternCatalog, p: int, m: _Marked, found: tuple[NDArray, int],
                   cam: Camera, attitude: str, click_sigma_px: float) -> BleifCandidate:
    pos, n_missing = found
    members = pc.members_of(p)
    star_index = np.full(len(m.xy), -1, dtype=np.int64)
    star_index[0] = p
    for j, k in enumerate(pos.tolist()):
        if k >= 0:
            star_index[m.order[j]] = members[k]
    assignment = [(d, int(pc.ids[s]) if s >= 0 else None) for d, s in
                  enumerate(star_index.tolist())]
    used = np.flatnonzero(star_index >= 0)
    b, r = m.vectors[used], pc.vectors[star_index[used]]
    q = cov = None
    problem = ""
    # the Wahba fit of the assigned stars: the attitude (modern) and, for both modes, the
    # covariance — inflated when the residuals say the marks are worse than assumed
    try:
        w = wahba(b, r, click_sigma_px * cam.pixel_scale_rad)
        dof = 2 * len(used) - 3
        cov = w.covariance * max(1.0, w.loss / dof if dof > 0 else 1.0)
        if attitude == "wahba":
            q = w.q_cam_icrs
    except ValueError as e:
        problem = f"wahba: {e}"
    if attitude == "thesis":
        # the thesis uses the first three stars of the sorted list: reference, nearest two
        first = [0, *[int(m.order[j]) for j in range(len(pos)) if pos[j] >= 0][:2]]
        try:
            ra, de, az = attitude_thesis(m.xy, star_index, pc, cam, first)
            q = q_cam_icrs_from_star_angles(ra, de, az)
        except CollinearTripleError as e:
            problem = str(e)
    res = np.full(len(m.xy), np.nan)
    if q is not None:
        pred = rot.rotate(q, r)
        res[used] = np.arccos(np.clip(np.sum(pred * b, axis=1), -1.0, 1.0))
        worst = math.degrees(float(np.nanmax(res)))
        if attitude == "thesis" and worst > _THESIS_RESIDUAL_MAX_DEG:
            # CalcAzimut's AZ belongs to the reference star, not the boresight, and the
            # Dreibein amplifies marking errors: say so rather than hand it on silently
            problem = (f"thesis attitude misses a marked star by {worst:.2f}° (> "
                       f"{_THESIS_RESIDUAL_MAX_DEG:g}°); attitude='wahba' fits all marks")
    return BleifCandidate(p, int(pc.ids[p]), assignment, star_index, q, cov, res, n_missing,
                          attitude, problem, cam)


def calc_azimut_deg(alpha_cat_deg: ArrayLike, alpha_ccd_deg: ArrayLike,
                    weights: ArrayLike) -> float:
    """Eq. 4.29/4.30 as a *circular* weighted mean of (catalogue − image) direction
    angles (the plain mean of the thesis breaks across 0/360°), in [0, 360).

    >>> round(calc_azimut_deg([20.0, 350.0], [0.0, 0.0], [1.0, 1.0]), 9)
    5.0
    """
    a = np.radians(np.asarray(alpha_cat_deg, float) - np.asarray(alpha_ccd_deg, float))
    w = np.asarray(weights, dtype=np.float64)
    return float(np.degrees(np.arctan2(w @ np.sin(a), w @ np.cos(a))) % 360.0)


def dreibein(u: NDArray[np.float64], psi_rad: ArrayLike,
             max_gain: float = 20.0) -> NDArray[np.float64]:
    """The tripod approach (Eq. 4.32–4.39): the unit vector at angles ``psi_rad`` from the
    three unit vectors ``u`` (3, 3). Raises :class:`CollinearTripleError` when an error in
    ψ would be amplified more than ``max_gain`` times in the result (a near-collinear
    triple), rather than return a wild answer.

    >>> import numpy as np
    >>> u = np.eye(3)
    >>> np.round(dreibein(u, np.arccos([1, 1, 1] / np.sqrt(3))) * np.sqrt(3), 12).tolist()
    [1.0, 1.0, 1.0]
    """
    u = np.asarray(u, dtype=np.float64)
    psi = np.asarray(psi_rad, dtype=np.float64)
    G = u @ u.T  # cos ψ_ij (Eq. 4.36–4.38)
    try:
        c = np.linalg.solve(G, np.cos(psi))
        Ginv = np.linalg.inv(G)
    except np.linalg.LinAlgError:
        raise CollinearTripleError("Dreibein: the three stars are collinear (singular "
                                   "system); mark a better spread triple") from None
    v = u.T @ c
    nv = float(np.linalg.norm(v))
    # sensitivity of the direction to the ψ's: J = Uᵀ G⁻¹ diag(−sin ψ), across v
    J = u.T @ Ginv @ np.diag(-np.sin(psi)) / nv
    v_hat = v / nv
    J -= np.outer(v_hat, v_hat @ J)
    gain = float(np.linalg.norm(J, 2))
    if not np.isfinite(gain) or gain > max_gain:
        raise CollinearTripleError(f"Dreibein: near-collinear star triple (an error in the "
                                   f"star distances is amplified {gain:.3g}× > {max_gain:g}"
                                   "×); mark a better spread triple or use attitude='wahba'")
    return v_hat


def attitude_thesis(xy: NDArray, star_index: NDArray, pc: PatternCatalog, cam: Camera,
                    first: list[int]) -> tuple[float, float, float]:
    """CalcAzimut + CalcChipCenter (Dreibein) as in the thesis: (RA, DE, AZ) in rad.

    ``first`` are the click indices of the reference and the two stars of the Dreibein
    triple; AZ averages every assigned star; distances and direction angles are the plane
    formulas Eq. 4.11–4.13/4.31 with the camera's k_x, k_y."""
    kx, ky = 1.0 / cam.K[0, 0], 1.0 / cam.K[1, 1]
    cx, cy = cam.K[0, 2], cam.K[1, 2]
    X = cam.parity * (xy[:, 0] - cx) * kx  # C frame, origin at the image centre, y up
    Y = -(xy[:, 1] - cy) * ky
    used = [k for k in range(1, len(xy)) if star_index[k] >= 0]
    ref = int(star_index[0])
    dx, dy = X[used] - X[0], Y[used] - Y[0]
    alpha_ccd = np.degrees(np.arctan2(dx, dy))
    alpha_cat = np.degrees(direction_angles_rad(pc.vectors[ref], pc.vectors[star_index[used]],
                                                pc.faithful))
    az = calc_azimut_deg(alpha_cat, alpha_ccd, np.hypot(dx, dy))
    if len(first) < 3:
        raise CollinearTripleError("Dreibein needs three assigned stars")
    u = pc.vectors[star_index[first]]
    psi = np.hypot(X[first], Y[first])  # Eq. 4.31
    v = dreibein(u, psi)
    ra = math.atan2(v[1], v[0]) % (2 * math.pi)
    de = math.asin(max(-1.0, min(1.0, float(v[2]))))
    return ra, de, math.radians(az)


def stars_in_frame(pc: PatternCatalog, cam: Camera, q_cam_icrs: ArrayLike,
                   ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Pixel positions and star-list indices of the pattern catalogue's stars inside the
    frame at an attitude, brightest first."""
    v = rot.rotate(np.asarray(q_cam_icrs, dtype=np.float64), pc.vectors)
    front = np.flatnonzero(v[:, 2] > 0)
    xy = cam.vectors_to_pixels(v[front])
    ok = cam.in_frame(xy)
    idx, xy = front[ok], xy[ok]
    o = np.argsort(pc.mag[idx], kind="stable")
    return xy[o], idx[o]


@dataclass(frozen=True)
class Overlay:
    """What the operator sees over the image for one candidate (Fig. 4.7).

    ``xy`` expected positions of the pattern's stars in the frame (the reference and its
    members), ``ids`` and ``mag`` theirs; ``radius_px`` grows with brightness;
    ``is_reference`` / ``is_marked`` flag the reference and the other marked stars;
    ``occupied`` says whether a block lies at the expected position; ``false_blocks``
    indexes blocks near no catalogue star (hot pixels, city lights, planets).
    """

    xy: NDArray[np.float64]
    ids: NDArray[np.int64]
    mag: NDArray[np.float64]
    radius_px: NDArray[np.float64]
    is_reference: NDArray[np.bool_]
    is_marked: NDArray[np.bool_]
    occupied: NDArray[np.bool_]
    false_blocks: NDArray[np.int64]


def overlay(cand: BleifCandidate, pc: PatternCatalog, cam: Camera,
            blocks_xy: ArrayLike | None = None, occupied_px: float = 2 * T_PIX,
            ) -> Overlay:
    """Project the candidate's pattern (reference + members) into the frame."""
    if cand.q_cam_icrs is None:
        raise ValueError(f"candidate has no attitude ({cand.problem})")
    idx = np.r_[cand.pattern, pc.members_of(cand.pattern)]
    v = rot.rotate(cand.q_cam_icrs, pc.vectors[idx])
    front = v[:, 2] > 0
    xy = np.full((len(idx), 2), np.nan)
    xy[front] = cam.vectors_to_pixels(v[front])
    keep = np.flatnonzero(front & cam.in_frame(xy))
    idx, xy = idx[keep], xy[keep]
    mag = pc.mag[idx]
    radius = 2.0 + 1.5 * np.clip(6.5 - mag, 0.0, None)  # brighter → larger, monotonic
    marked = set(cand.star_index[1:][cand.star_index[1:] >= 0].tolist())
    is_ref = idx == cand.pattern
    is_marked = np.array([i in marked for i in idx.tolist()], dtype=bool)
    blocks = (np.zeros((0, 2)) if blocks_xy is None
              else np.asarray(blocks_xy, dtype=np.float64).reshape(-1, 2))
    if len(blocks) and len(xy):
        dd = np.hypot(*(xy[:, None, :] - blocks[None, :, :]).transpose(2, 0, 1))
        occupied = dd.min(axis=1) <= occupied_px
    else:
        occupied = np.zeros(len(xy), dtype=bool)
    # false blocks: near no catalogue star at all (the whole pattern list, not only the
    # pattern), so a faint real star is not called false
    if len(blocks):
        all_xy, _ = stars_in_frame(pc, cam, cand.q_cam_icrs)
        if len(all_xy):
            db = np.hypot(*(blocks[:, None, :] - all_xy[None, :, :]).transpose(2, 0, 1))
            false_blocks = np.flatnonzero(db.min(axis=1) > occupied_px)
        else:
            false_blocks = np.arange(len(blocks))
    else:
        false_blocks = np.zeros(0, dtype=np.int64)
    return Overlay(xy, pc.ids[idx], mag, radius, is_ref, is_marked, occupied,
                   false_blocks.astype(np.int64))


def operator_marks(xy: ArrayLike, camera: Camera, n_marked: int = 10) -> NDArray[np.int64]:
    """The stars an operator marks among ``xy`` (star images, brightest first), in the
    order of the clicks: indices into ``xy``, the reference first.

    **Rule.** The operator marks the ``n_marked`` brightest (at most 10, Bleif 2004
    §4.2.2); the *reference* — the first click — is the one nearest the image centre
    (the principal point; a tie goes to the brighter); the others follow brightest first.

    **Why the centre** (Bleif 2004 §4.2.4–4.2.6; docs/references.md#bleif-2004): the
    first marked star is the reference, and every other marked star must be found in the
    reference's pattern, which holds only the catalogue neighbours within 20° (at most
    150, the nearest kept). From the centre every star of the 22.0° × 16.8° frame lies
    within the half diagonal, 13.8°; from a corner the far corner is 27.7° away, outside
    any pattern, and in dense regions the 150 cap drops the far neighbours first. And
    the thesis's azimuth (CalcAzimut) is the position angle *at the reference*: it
    describes the boresight only when the reference is near the centre (median error
    0.24° within 50 px). This is the operator that :func:`~starid.bleif.operator.suggest_stars`
    plays and the one ``benchmarks/bench_bleif.py`` measures (the truth first in about
    98.5 % of 5–7-star trials); :class:`~starid.bleif.operator.IdentificationSession`
    (``mark_detections``, ``suggest``) and ``Solver(method="bleif")`` both mark by it.

    >>> import numpy as np
    >>> cam = tubsat_camera()
    >>> operator_marks([[10, 10], [370, 290], [700, 50], [380, 300]], cam).tolist()
    [3, 0, 1, 2]
    """
    pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    n = min(int(n_marked), len(pts))
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    ref = int(_centre_ranking(pts[:n], camera)[0])
    return np.array([ref, *[k for k in range(n) if k != ref]], dtype=np.int64)


def _centre_ranking(pts: NDArray, camera: Camera) -> NDArray[np.int64]:
    """Indices of ``pts`` nearest the principal point first (stable: ties keep the order)."""
    return np.argsort(np.hypot(*(pts - camera.K[:2, 2]).T), kind="stable")


@dataclass(frozen=True)
class BleifParams:
    """Settings of ``Solver(method="bleif")``: the brightest ``n_marked`` detections play
    the marked stars and the reference is the operator's (:func:`operator_marks`); only
    when that selection gives no candidate at all (a false star among the marks, as the
    strict thesis mode cannot survive one) does the solver re-mark as an operator would:
    up to ``n_refs`` references (nearest the centre first) in turn, tolerant mode with up
    to ``k_miss`` misses; ``t_pix`` as Eq. 4.14."""

    n_marked: int = 8
    n_refs: int = 3
    k_miss: int = 2
    t_pix: float = T_PIX
    n_stars: int = 5000


def detection_selections(patterns: PatternCatalog, xy: ArrayLike, camera: Camera,
                         params: BleifParams = BleifParams(), *, operator_round: bool = True,
                         ) -> Iterator[tuple[int, int, list[BleifCandidate], int]]:
    """For a solver: per (misses allowed, reference) tried, (reference detection, misses
    allowed, its candidates, patterns examined so far). The detections are ``xy``
    brightest first; a candidate's ``star_index`` is per marked star, with the marked
    stars being ``selection_of(ref, len(xy), params)``. The first selection is the
    operator's (:func:`operator_marks`, strict); ``operator_round=False`` leaves it out
    (a caller that has run it already)."""
    pts = np.asarray(xy, dtype=np.float64)
    n = min(params.n_marked, len(pts))
    refs = _centre_ranking(pts[:n], camera)[: params.n_refs].tolist()
    examined = 0
    # strict first (fast, and enough for a clean selection), then more misses allowed
    for k_miss in range(min(params.k_miss, n - 3) + 1):
        for ref in refs:
            if k_miss == 0 and ref == refs[0] and not operator_round:
                continue
            sel = selection_of(ref, len(pts), params)
            counters = MatchCounters()
            cands = list(find_matches(patterns, pts[sel], camera, k_miss=k_miss,
                                      t_pix=params.t_pix, counters=counters))
            examined += counters.patterns
            yield ref, k_miss, cands, examined


def selection_of(ref: int, n_det: int, params: BleifParams = BleifParams()) -> list[int]:
    """The detections marked when detection ``ref`` is the reference: it, then the other
    brightest ``n_marked − 1`` (for the operator's reference, :func:`operator_marks`)."""
    n = min(params.n_marked, n_det)
    return [ref, *[k for k in range(n) if k != ref]]
