"""Verification of a candidate identification and its false-match probability.

A geometric match of n image stars to n catalogue stars proposes an attitude. We then
project the catalogue into the frame at that attitude, match the remaining detections,
and ask how likely it is that a *wrong* identification would look this good:

``p_false = trials × E_chance × P(Binomial(M, p_hit) ≥ k)``

* ``E_chance`` — the expected number of catalogue patterns anywhere on the sky that fit
  the image pattern's windows by coincidence (:func:`expected_chance_patterns`);
* ``P(… ≥ k)`` — the chance that ``k`` or more of the ``M`` other detections land within
  the match radius of a projected catalogue star when the attitude is wrong (each does so
  with probability ``p_hit`` = projected stars × disc area / frame area);
* ``trials`` — how many patterns (and focal-length guesses) were tried before this one:
  a union bound over the whole search, so trying more never buys a false acceptance.

This is a union-bound style upper estimate (the sky density is doubled for safety); it
is what :class:`starid.Solution` reports as ``p_false``.

Example:
    >>> round(binomial_tail(3, 10, 0.01), 6)
    0.000114
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from adfusion.starid.camera.calibrate import fit_camera_model
from adfusion.starid.camera.model import Camera
from adfusion.starid.identify import kernels
from adfusion.starid.identify.check_kernels import DENSITY_SAFETY
from adfusion.starid.identify.nstar import chirality_of
from adfusion.starid.identify.solution import Candidate
from numpy.typing import NDArray
from scipy.special import bdtrc

from adfusion.maths import rotations as rot
from adfusion.maths.attitude import wahba_unit

if TYPE_CHECKING:
    from adfusion.starid.identify.catalog_view import CatalogView
    from adfusion.starid.identify.search_state import PairWindows

__all__ = [
    "Verifier",
    "binomial_tail",
    "distinct_candidates",
    "expected_chance_patterns",
    "keeps_pattern",
    "match_radius_px",
    "one_to_one",
    "quick_tuples",
    "rotation_from_pairs",
    "spot_geometry",
    "variance_factor",
]

_3_SQRT2 = 3.0 * math.sqrt(2.0)


def binomial_tail(k: int, m: int, p: float) -> float:
    """P(X ≥ k) for X ~ Binomial(m, p)."""
    if k <= 0:
        return 1.0
    if k > m:
        return 0.0
    p = min(max(p, 0.0), 1.0)
    return float(bdtrc(k - 1, m, p))


def expected_chance_patterns(
    angles: NDArray[np.float64],
    tol: NDArray[np.float64] | float,
    n_catalog: int,
    mirror_checked: bool,
    geometry: list[tuple[int, int, float]] | None = None,
) -> float:
    """Expected number of catalogue n-star patterns matching ``angles`` by chance.

    Star 1 may be any of N stars; star 2 lies in an annulus of width 2·tol around it
    (area 2π sin d₁₂ · 2tol); every further star must lie where the annuli around two
    already placed stars cross: two spots of area (2tol)² / sin γ (γ the crossing angle),
    one of them when the mirror check or a third placed star picks the side. The pair of
    placed stars crossing most steeply is used — with the closest pair first, the first
    two stars alone pin a far star only loosely, the others pin it well. Further
    distances are not credited (they tighten the spot further, so this stays an upper
    estimate). Densities are per steradian, doubled for safety (:data:`DENSITY_SAFETY`).
    ``geometry`` is :func:`spot_geometry` of ``angles``, when the caller has it already.
    """
    a = np.asarray(angles, dtype=np.float64)
    w = 2.0 * np.broadcast_to(np.asarray(tol, dtype=np.float64), a.shape)
    rho = DENSITY_SAFETY * n_catalog / (4.0 * np.pi)
    e = float(n_catalog) * rho * 2.0 * np.pi * max(np.sin(a[0, 1]), 1e-6) * w[0, 1]
    e *= 2.0  # either image star of the first pair may be either catalogue star
    for m, (s, t, sin_gamma) in enumerate(geometry or spot_geometry(a), start=2):
        spots = 1.0 if (m >= 3 or mirror_checked) else 2.0
        e *= rho * spots * w[s, m] * w[t, m] / max(sin_gamma, 0.05)
    return float(e)


def spot_geometry(angles: NDArray[np.float64]) -> list[tuple[int, int, float]]:
    """For each star m ≥ 2: the placed pair (s, t) whose arcs cross most steeply at m,
    and the sine of that crossing angle (depends on the image geometry only)."""
    a = np.asarray(angles, dtype=np.float64).tolist()
    out = []
    for m in range(2, len(a)):
        best = (0, 1, 0.0)
        for s in range(m):
            for t in range(s + 1, m):
                sg = math.sin(_crossing_angle(a[s][t], a[s][m], a[t][m]))
                if sg > best[2]:
                    best = (s, t, sg)
        out.append(best)
    return out


def _crossing_angle(d01: float, d0m: float, d1m: float) -> float:
    """Angle at star m between the arcs to stars 0 and 1 (spherical law of cosines)."""
    denom = math.sin(d0m) * math.sin(d1m)
    if denom <= 0:
        return 0.0
    c = (math.cos(d01) - math.cos(d0m) * math.cos(d1m)) / denom
    return math.acos(min(1.0, max(-1.0, c)))


# --- candidate verification (the solver's, for every search path) -----------------------


def match_radius_px(centroid_sigma_px: float) -> float:
    """The radius (px) within which a detection matches a projected star: 3·√2·σ, at
    least 1.5 px."""
    return max(_3_SQRT2 * centroid_sigma_px, 1.5)


class Verifier:
    """The :class:`starid.Solver`'s verification of candidate identifications: the quick
    check of every assignment of a pattern (compiled), the full refit of the ones that pass
    and their false-match probability.

    Args:
        view: the catalogue (:class:`~adfusion.starid.identify.catalog_view.CatalogView`:
            vectors, ids, KD-tree, index and its compiled arrays, projection).
        centroid_sigma_px: 1-σ centroid error (the match radius and the fit's weights).
        max_sep_rad: the pattern index's radius (the local star density's area).
        fov_uncertain: whether the focal length is refitted with each candidate.

    ``compiled`` (True): a known camera's candidates are verified by
    :func:`starid.identify.kernels.verify_candidate`; False: in Python.

    >>> from adfusion import starid
    >>> s = starid.Solver(starid.Catalog.hipparcos(mag_limit=4.0),
    ...                   starid.Camera.pinhole(1024, 768, 15.0))
    >>> isinstance(s.verifier, Verifier), s.verifier.match_radius_px()
    (True, 2.121320343559643)
    """

    def __init__(self, view: CatalogView, centroid_sigma_px: float, max_sep_rad: float,
                 fov_uncertain: bool) -> None:
        self.view = view
        self.centroid_sigma_px = float(centroid_sigma_px)
        self.max_sep_rad = float(max_sep_rad)
        self.fov_uncertain = bool(fov_uncertain)
        self.compiled = True

    def match_radius_px(self) -> float:
        return match_radius_px(self.centroid_sigma_px)

    def p_hit(self, anchor: int, radius_rad: float) -> float:
        """Chance that a random detection falls within the match radius of a catalogue
        star: local density (neighbours of the anchor star within the index radius), at
        least the sky mean, times a safety factor."""
        cnt = self.view.index.nbr_ptr[anchor + 1] - self.view.index.nbr_ptr[anchor]
        area = 2 * np.pi * (1 - np.cos(self.max_sep_rad))
        rho = max(cnt / area, len(self.view.vectors) / (4 * np.pi)) * DENSITY_SAFETY
        return min(1.0, rho * np.pi * radius_rad**2)

    def associate_icrs(self, b_all: NDArray, R: NDArray,
                        radius_rad: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Detections ↔ catalogue stars within a radius, at attitude R (cam ← icrs): each
        detection's nearest star, one-to-one (a star claimed twice goes to the closer)."""
        d, j = self.view.tree.query(b_all @ R, distance_upper_bound=2 * np.sin(radius_rad / 2))
        return one_to_one(d, j)

    def quick(self, b_all: NDArray, table: PairWindows | None, sel: NDArray,
               assigns: NDArray, cam: Camera, trials: int, chance: tuple | None = None,
               ) -> list[tuple[float, NDArray, float, NDArray, NDArray] | None]:
        """Cheap verification of every assignment (K, n) of one pattern
        (:func:`kernels.quick_checks`): attitude from the pattern, every detection
        rotated into ICRS and associated. Per assignment (p_false, R, e_trials,
        detection indices, catalogue indices), or None.

        ``e_trials`` is the expected number of chance patterns fitting *as well as this
        candidate does* — windows shrunk to its own pair residuals, but never below the
        centroid noise — times the trials so far (a union bound over the search). The
        pattern's angles and windows come from ``table`` (or ``chance`` = (angles, window
        half-widths, mirror checked))."""
        if chance is None:
            ix = (sel[:, None], sel)
            ang, tol = table.angles[ix], table.tol[ix]
            mirror = chirality_of(b_all[sel], 2.0 * float(tol.max())) != 0
        else:
            ang, tol, mirror = chance
        pix = cam.pixel_scale_rad

        q = kernels.quick_checks(
            self.view.ix, np.ascontiguousarray(b_all), np.asarray(sel, dtype=np.int64),
            np.ascontiguousarray(assigns, dtype=np.int64), np.ascontiguousarray(ang),
            np.ascontiguousarray(tol), bool(mirror), int(trials),
            self.match_radius_px() * pix, np.sqrt(2.0) * self.centroid_sigma_px * pix)
        return quick_tuples(q)

    def verify(self, xy: NDArray, cam: Camera, sel: NDArray, assign: NDArray,
                quick: tuple[float, NDArray, float, NDArray, NDArray],
                b_all: NDArray | None = None) -> Candidate | None:
        """Full verification of a candidate that passed the quick check: refit on all its
        matches (and the focal length when it is uncertain), re-associate if the refit
        moved the attitude noticeably, final fit with covariance, and the p_false of the
        final match count."""
        _, R, e_trials, det_i, cat_i = quick
        if b_all is None:
            b_all = cam.pixels_to_vectors(xy)
        radius = self.match_radius_px() * cam.pixel_scale_rad
        sigma = self.centroid_sigma_px * cam.pixel_scale_rad
        if not self.fov_uncertain and self.compiled:
            ok, det_i, cat_i, q, cov, res, p_false = kernels.verify_candidate(
                self.view.ix, np.ascontiguousarray(b_all), np.ascontiguousarray(R),
                float(e_trials), np.ascontiguousarray(det_i, dtype=np.int64),
                np.ascontiguousarray(cat_i, dtype=np.int64),
                np.ascontiguousarray(sel, dtype=np.int64),
                np.ascontiguousarray(assign, dtype=np.int64), len(xy), radius, sigma)
            if not ok:
                return None
            return Candidate(
                q_cam_icrs=q, matches=list(zip(det_i.tolist(), self.view.ids[cat_i].tolist(),
                                               strict=True)),
                residuals_rad=res, p_false=p_false, n_pattern=len(sel), camera=cam,
                covariance=cov, _projector=self.view.project)
        refit = False
        if self.fov_uncertain and len(det_i) >= 4:
            cam = fit_camera_model([(xy[det_i], self.view.vectors[cat_i])], cam, ("focal",),
                                   q_cam_icrs=[rot.from_matrix(R)]).camera
            b_all = cam.pixels_to_vectors(xy)
            radius = self.match_radius_px() * cam.pixel_scale_rad
            sigma = self.centroid_sigma_px * cam.pixel_scale_rad
            refit = True
        R2 = rotation_from_pairs(b_all[det_i], self.view.vectors[cat_i])
        if R2 is None:
            return None
        # rotation angle between R and R2 from the trace: 1 − cos θ = (3 − tr)/2
        moved = np.sqrt(max(0.0, 2.0 * (3.0 - float(np.sum(R * R2))) / 2.0))
        if refit or moved > 0.25 * radius:
            det_i, cat_i = self.associate_icrs(b_all, R2, radius)
            if not keeps_pattern(det_i, cat_i, sel, assign, len(b_all)):
                return None
        try:
            final = wahba_unit(b_all[det_i], self.view.vectors[cat_i], sigma)
        except ValueError:
            return None
        k_other = len(det_i) - len(sel)
        p_false = min(1.0, e_trials * binomial_tail(k_other, len(xy) - len(sel),
                                                    self.p_hit(int(assign[0]), radius)))
        return Candidate(
            q_cam_icrs=final.q_cam_icrs,
            matches=[(int(d), int(self.view.ids[c])) for d, c in zip(det_i, cat_i, strict=True)],
            residuals_rad=final.residuals_rad,
            p_false=p_false,
            n_pattern=len(sel),
            camera=cam,
            covariance=final.covariance * variance_factor(final),
            _projector=self.view.project,
        )


def quick_tuples(q: tuple) -> list[tuple[float, NDArray, float, NDArray, NDArray] | None]:
    """:func:`kernels.quick_checks`' arrays as one tuple (or None) per assignment."""
    ok, p, R, e, det, cat, n = q
    return [(float(p[k]), R[k], float(e[k]), det[k, :n[k]], cat[k, :n[k]]) if ok[k]
            else None for k in range(len(ok))]



def variance_factor(w) -> float:
    """A-posteriori variance factor of a Wahba fit, never below 1: when the residuals say
    the centroids are worse than ``centroid_sigma_px`` (blur, intensifier noise, lens
    residuals), the fix's covariance grows accordingly instead of lying to a filter.
    Each star gives 2 measurements; the attitude takes 3 degrees of freedom."""
    dof = 2 * len(w.residuals_rad) - 3
    return max(1.0, w.loss / dof) if dof > 0 else 1.0



def one_to_one(d: NDArray, j: NDArray) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """From a nearest-neighbour query (distance ∞ = none within the bound): detections
    with a match, each target kept by its closest detection (ties to the lower index, so
    the result does not depend on timing); returns (detection indices, targets)."""
    det = np.flatnonzero(np.isfinite(d))
    if len(det) == 0:
        return det.astype(np.int64), det.astype(np.int64)
    det = det[np.lexsort((det, d[det]))]
    _, first = np.unique(j[det], return_index=True)
    det = np.sort(det[first])
    return det.astype(np.int64), j[det].astype(np.int64)



def keeps_pattern(det_i: NDArray, cat_i: NDArray, sel: NDArray, assign: NDArray,
                   n_det: int) -> bool:
    """Whether the association kept every pattern star on its assigned catalogue star."""
    lookup = np.full(n_det, -1, dtype=np.int64)
    lookup[det_i] = cat_i
    return bool(np.all(lookup[sel] == assign))



def rotation_from_pairs(b: NDArray, r: NDArray) -> NDArray | None:
    """Least-squares rotation (cam ← icrs) from matched directions (lean SVD Wahba)."""
    u, sv, vt = np.linalg.svd(b.T @ r)
    if sv[1] < 1e-12 * max(sv[0], 1e-300):
        return None  # collinear: rotation about the common axis undetermined
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        u[:, 2] = -u[:, 2]
    return u @ vt



def distinct_candidates(cands: list[Candidate], tol_rad: float) -> list[Candidate]:
    """Collapse candidates with the same attitude (e.g. a swapped close pair)."""
    if len(cands) <= 1:
        return list(cands)
    out: list[Candidate] = []
    for c in sorted(cands, key=lambda c: c.p_false):
        if all(rot.angle_between(c.q_cam_icrs, o.q_cam_icrs) > tol_rad for o in out):
            out.append(c)
    return out

