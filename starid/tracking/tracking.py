"""Tracking of the :class:`starid.Solver`: with an attitude prior, the catalogue stars it
predicts are associated with the detections in steps (wide gate, median offset, medium
radius, Wahba, tight radius) and accepted with ≥ 2 stars when a chance coincidence is
improbable.

Example:
    >>> from adfusion import starid
    >>> s = starid.Solver(starid.Catalog.hipparcos(mag_limit=5.0),
    ...                   starid.Camera.pinhole(512, 480, 25.84))
    >>> isinstance(s.tracker, Tracker)
    True
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING

import numpy as np
from adfusion.starid.camera.model import Camera
from adfusion.starid.identify.solution import Candidate, Prior, Solution
from adfusion.starid.identify.verify import (
    binomial_tail,
    one_to_one,
    rotation_from_pairs,
    variance_factor,
)
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from adfusion.maths import rotations as rot
from adfusion.maths.attitude import (
    WahbaSolution,
    refine_streaked,
    streak_vectors,
    wahba_near,
    wahba_unit,
)

if TYPE_CHECKING:
    from adfusion.starid.identify.catalog_view import CatalogView
    from adfusion.starid.identify.verify import Verifier

__all__ = ["Tracker", "corner_sigma_px", "pair_within"]

# Gates wider than this many match radii let a two-star fit turn the frame far enough to
# pair a false detection with some catalogue star: the chance is then bounded separately.
_LOOSE_GATE = 4.0
# the compiled prediction scans the whole catalogue up to this size (2 µs for 3000 stars),
# beyond it the solver's cached cone (a tracking camera keeps it for many frames: the V <
# 6.5 catalogue of the Basilisk scenarios, ~9000 stars, took 7–13 µs a frame to scan and
# ~1 µs through its cone); its cone test is this much wider than the frame's (a superset:
# the frame test decides)
_SCAN_ALL_MAX = 2_000
_CONE_SLACK = math.radians(2.0)
_NO_ROWS = np.zeros(0, dtype=np.int64)
_NO_SMEAR = np.zeros(3)


class Tracker:
    """The tracking part of :class:`starid.Solver`: a frame identified near an attitude
    prior (:meth:`solve`).

    Args:
        view: the catalogue (:class:`~adfusion.starid.identify.catalog_view.CatalogView`:
            vectors, ids, the cached cone and the projection into a frame).
        verifier: the solver's :class:`~adfusion.starid.identify.verify.Verifier` (the
            match radius, the one-to-one association at an attitude).
        camera: the solver's camera.
        centroid_sigma_px: 1-σ centroid error (the fit's weights).
        tolerance_rad: the pair-distance tolerance (two-star fixes' alternatives).
        p_false_max_tracking: the acceptance threshold on ``p_false``.
        max_fix_sigma_px: a fix less certain than this at the frame's corners is refused.
        whole_streak_px: streaks longer than this are fitted as streaks.

    >>> from adfusion import starid
    >>> from adfusion.starid import rotations as rot
    >>> s = starid.Solver(starid.Catalog.hipparcos(mag_limit=5.0),
    ...                   starid.Camera.pinhole(512, 480, 25.84))
    >>> q = rot.q_cam_icrs_from_radec_roll(1.0, 0.5, 0.0)
    >>> ids, xy = s.stars_in_view(q)
    >>> s.tracker.solve(xy[:10], starid.Prior(q, 0.01), 0.0).ok
    True
    """

    def __init__(self, view: CatalogView, verifier: Verifier, camera: Camera,
                 centroid_sigma_px: float, tolerance_rad: float, p_false_max_tracking: float,
                 max_fix_sigma_px: float, whole_streak_px: float) -> None:
        self.view = view
        self.verifier = verifier
        self.camera = camera
        self.centroid_sigma_px = float(centroid_sigma_px)
        self.tolerance_rad = float(tolerance_rad)
        self.p_false_max_tracking = float(p_false_max_tracking)
        self.max_fix_sigma_px = float(max_fix_sigma_px)
        self.whole_streak_px = float(whole_streak_px)

    def _pairings_that_fit(self, b: NDArray, xy: NDArray, pred_xy: NDArray,
                           pred_idx: NDArray, gate_px: float) -> int:
        """How many pairs of distinct catalogue stars, one predicted within ``gate_px`` of
        each of two detections (pixels ``xy``, directions ``b``), have the detections'
        separation within the pair tolerance: 1 when the pairing is unique."""
        near = [pred_idx[np.einsum("ij,ij->i", pred_xy - p, pred_xy - p) <= gate_px**2]
                for p in xy]
        if len(near[0]) == 0 or len(near[1]) == 0:
            return 0
        sep = math.acos(min(1.0, max(-1.0, float(b[0] @ b[1]))))
        cosines = self.view.vectors[near[0]] @ self.view.vectors[near[1]].T
        ang = np.arccos(np.clip(cosines, -1.0, 1.0))
        fit = np.abs(ang - sep) <= self.tolerance_rad
        fit &= near[0][:, None] != near[1][None, :]
        return int(np.count_nonzero(fit))

    def solve(self, xy: NDArray, prior: Prior, t0: float) -> Solution:
        """Tracking: predict the catalogue stars in the prior's field, associate the
        detections inside the prior's gate, refine, and accept with ≥ 2 stars when a
        chance coincidence is improbable.

        Association runs in steps so that a prior off by more than the star spacing
        cannot pair stars crosswise: every predicted star takes its nearest detection
        within the wide gate (k·σ), the median image offset of those pairs corrects the
        prior's pointing, pairs are redone within a medium radius (what is left is roll),
        then Wahba and re-association within the tight radius, twice. With a tight prior
        (gate ≤ 2.5 match radii) the nearest pairs are taken directly. ``p_false`` is the
        chance that this many of the M detections fall within the tight radius of
        predicted stars by accident, times the number of alternative pairings the wide
        gates allowed.

        This runs once per frame in a filter loop with a few dozen stars. A tight prior
        with an undistorted pinhole camera (a running filter's steady state) takes the
        compiled path (:mod:`starid.tracking.kernels`: prediction, association and fit in
        three calls); everything else the numpy path, written for numpy's per-call
        overhead (a cached catalogue cone, one brute-force distance matrix instead of a
        KD-tree). Both give the same outcome (benchmarks/tracking_identical.py,
        tests/test_tracking_kernels.py).
        """
        cam = self.camera
        gate_rad = math.radians(prior.k * prior.sigma_deg)
        tight = self.verifier.match_radius_px()
        wide = max(gate_rad / cam.pixel_scale_rad * 1.2 + tight, tight)
        if wide <= 2.5 * tight and cam._ideal_pinhole is not None:
            sol = self.track_compiled(xy, prior, gate_rad, tight, wide, t0)
            if sol is not None:
                return sol
        return self.track_numpy(xy, prior, t0)

    def track_compiled(self, xy: NDArray, prior: Prior, gate_rad: float, tight: float,
                        wide: float, t0: float) -> Solution | None:
        """The tight prior's path for an undistorted pinhole, compiled; None when a fit's
        directions are collinear (the numpy path then says so in its words)."""
        from adfusion.starid.camera.projection_kernels import (
            predict_pinhole,  # compiled on first use
        )
        from adfusion.starid.tracking import kernels as tk

        cam = self.camera
        q0 = prior.q_cam_icrs
        R0 = rot.to_matrix(q0)
        M1, off, A, c = cam._ideal_pinhole
        # (N, 3) input with flux leaves a strided view: one memory layout, one compilation
        xy = np.ascontiguousarray(xy)
        half = cam._view_half_rad + gate_rad + 1e-3
        m = -gate_rad / cam.pixel_scale_rad
        rows, all_rows = self._tracking_rows(R0[2], half)
        pred_xy, pred_idx, b_all = predict_pinhole(
            self.view.vectors, rows, all_rows, R0, A, c, math.cos(min(half + _CONE_SLACK, math.pi)),
            -0.5 + m, cam.width - 0.5 - m, cam.height - 0.5 - m, xy, M1, off)
        if len(pred_xy) < 2:
            return Solution(False, f"{len(pred_xy)} catalogue star(s) predicted in view",
                            mode="tracking")
        j, n_within, d = tk.nearest_detections(pred_xy, xy, wide)
        n_hit = int(np.count_nonzero(n_within))
        if n_hit < 2:
            return Solution(False, f"{n_hit} predicted star(s) with a detection in the gate",
                            mode="tracking")
        # alternative pairings inside the wide gates (1 each when the prior is tight)
        n_hyp = 2.0 ** int(np.count_nonzero(n_within >= 2))
        pix_rad = cam.pixel_scale_rad
        sigma = self.centroid_sigma_px * pix_rad
        smear = prior.smear_cam_rad
        status, det_i, cat_i, b_use, q, P, res, loss, longest2 = tk.tight_fix(
            pred_idx, j, n_within, d, b_all, self.view.vectors, q0, sigma, tight * pix_rad,
            _NO_SMEAR if smear is None else smear)
        if status == tk.FIT_FEW:
            return Solution(False, f"{len(det_i)} star(s) matched within {tight:.1f} px",
                            mode="tracking")
        if status == tk.FIT_COLLINEAR:
            return None
        return self._tracking_fix(xy, prior, pred_xy, pred_idx, n_hyp, det_i, cat_i, b_use,
                                  WahbaSolution(q, P, res, loss), tight, wide, t0,
                                  longest2=longest2)

    def _tracking_rows(self, axis: NDArray, half_rad: float) -> tuple[NDArray, bool]:
        """The catalogue rows the prediction looks at: all of them for a catalogue small
        enough to scan (a few µs compiled, cheaper than a KD-tree query of a cone), else
        the solver's cached cone around ``axis``."""
        if len(self.view.vectors) <= _SCAN_ALL_MAX:
            return _NO_ROWS, True
        return self.view.cone(axis, half_rad)[0], False

    def track_numpy(self, xy: NDArray, prior: Prior, t0: float) -> Solution:
        """:meth:`solve` in numpy, for every prior and camera."""
        cam = self.camera
        q0 = prior.q_cam_icrs
        gate_rad = math.radians(prior.k * prior.sigma_deg)
        R0 = rot.to_matrix(q0)
        pred_xy, pred_idx = self.view.predict(R0, cam, gate_rad)
        if len(pred_xy) < 2:
            return Solution(False, f"{len(pred_xy)} catalogue star(s) predicted in view",
                            mode="tracking")
        pix_rad = cam.pixel_scale_rad
        tight = self.verifier.match_radius_px()
        wide = max(gate_rad / pix_rad * 1.2 + tight, tight)
        # predicted stars × detections: a few dozen each, cheaper than building a tree
        dx = pred_xy[:, :1] - xy[:, 0]
        dy = pred_xy[:, 1:] - xy[:, 1]
        d2 = dx * dx
        d2 += dy * dy
        n_within = (d2 <= wide * wide).sum(axis=1)
        hit = n_within > 0
        n_hit = int(hit.sum())
        if n_hit < 2:
            return Solution(False, f"{n_hit} predicted star(s) with a detection in the gate",
                            mode="tracking")
        j = d2.argmin(axis=1)  # the nearest detection (inside the gate where hit)
        # alternative pairings inside the wide gates (1 each when the prior is tight)
        n_hyp = 2.0 ** int(np.count_nonzero(n_within >= 2))
        tight_prior = wide <= 2.5 * tight
        if tight_prior:
            # a tight prior (the steady state of a running filter): the gates are nearly
            # the match radius, so the nearest pairs are the answer — one fit, no rounds
            p_sel = np.flatnonzero(hit)
            det_sel = j[p_sel]
            if len(set(det_sel.tolist())) < len(det_sel):  # a detection claimed twice
                d = np.where(hit, np.sqrt(d2[np.arange(len(j)), j]), np.inf)
                p_sel, det_sel = one_to_one(d, j)
            order = np.argsort(det_sel)
            det_i, cat_i = det_sel[order], pred_idx[p_sel[order]]
            b_use = cam.pixels_to_vectors(xy[det_i])
        else:
            shift = np.median(xy[j[hit]] - pred_xy[hit], axis=0)
            b_all = cam.pixels_to_vectors(xy)
            # after the shift what is left is mostly roll (largest at the edges): pair
            # within a medium radius, then tighten through two fits
            medium = max(tight, 0.3 * wide)
            det_i, cat_i = pair_within(xy, pred_xy + shift, pred_idx, medium)
            predicted = np.zeros(len(self.view.vectors), dtype=bool)
            predicted[pred_idx] = True
            for _ in range(2):
                if len(det_i) < 2:
                    break
                R = rotation_from_pairs(b_all[det_i], self.view.vectors[cat_i])
                if R is None:
                    return Solution(False, "tracked stars are collinear", mode="tracking")
                det_i, cat_i = self.verifier.associate_icrs(b_all, R, tight * pix_rad)
                # keep only stars the prior predicted (tracking never jumps elsewhere)
                keep = predicted[cat_i]
                det_i, cat_i = det_i[keep], cat_i[keep]
            b_use = b_all[det_i]
        if len(det_i) < 2:
            return Solution(False, f"{len(det_i)} star(s) matched within {tight:.1f} px",
                            mode="tracking")
        sigma = self.centroid_sigma_px * pix_rad
        try:
            # near a tight prior Gauss–Newton steps reach Wahba's optimum for less than
            # the SVD (the steady state of a filter loop)
            w = wahba_near(q0, b_use, self.view.vectors[cat_i], sigma) if tight_prior \
                else wahba_unit(b_use, self.view.vectors[cat_i], sigma)
            # pairs the fit cannot place within the match radius (a noise blob or a
            # streak's piece nearer the prediction than the star) leave; one refit,
            # from this fit (its optimum is within a pixel or so)
            keep = w.residuals_rad <= tight * pix_rad
            n_keep = int(np.count_nonzero(keep))
            if 2 <= n_keep < len(keep):
                det_i, cat_i, b_use = det_i[keep], cat_i[keep], b_use[keep]
                w = wahba_near(w.q_cam_icrs, b_use, self.view.vectors[cat_i], sigma)
        except ValueError as e:
            return Solution(False, f"tracking fit failed: {e}", mode="tracking")
        return self._tracking_fix(xy, prior, pred_xy, pred_idx, n_hyp, det_i, cat_i, b_use,
                                  w, tight, wide, t0)

    def _tracking_fix(self, xy: NDArray, prior: Prior, pred_xy: NDArray, pred_idx: NDArray,
                      n_hyp: float, det_i: NDArray, cat_i: NDArray, b_use: NDArray,
                      w: WahbaSolution, tight: float, wide: float, t0: float,
                      longest2: float | None = None) -> Solution:
        """The fit's last steps and the verdict, for both paths: the streak model, the
        gate and corner-σ checks, ``p_false``. ``longest2`` is the longest streak² (rad²)
        of the stars under the prior's smear, when the caller has it."""
        cam = self.camera
        q0 = prior.q_cam_icrs
        gate_rad = math.radians(prior.k * prior.sigma_deg)
        pix_rad = cam.pixel_scale_rad
        sigma = self.centroid_sigma_px * pix_rad
        whole = self.whole_streak_px * pix_rad
        if prior.smear_cam_rad is not None and _norm3(prior.smear_cam_rad) > whole:
            if longest2 is None:
                v = streak_vectors(b_use, prior.smear_cam_rad)
                longest2 = float(np.einsum("ij,ij->i", v, v).max())
            if longest2 > whole * whole:
                try:
                    w = refine_streaked(w.q_cam_icrs, b_use, self.view.vectors[cat_i], sigma,
                                        prior.smear_cam_rad, whole)
                except ValueError as e:
                    return Solution(False, f"tracking fit failed: {e}", mode="tracking")
        offset = float(rot.angle_between(w.q_cam_icrs, q0))
        # trace(P) ≥ its largest eigenvalue: a bound, at most √3 too wide, for free
        sigma_fix = math.sqrt(float(w.covariance.trace()))
        if offset > gate_rad + 3 * sigma_fix:
            return Solution(False, f"fix {math.degrees(offset):.3g}° from the prior, outside "
                                   f"its {prior.k:g}σ gate", mode="tracking")
        cov = w.covariance * variance_factor(w)
        corner_px = corner_sigma_px(cov, cam)
        if corner_px > self.max_fix_sigma_px:
            return Solution(False, f"fix too uncertain: 1σ {corner_px:.3g} px at the frame's "
                                   f"corners > {self.max_fix_sigma_px:g} px (stars too close "
                                   "together, or inconsistent)", mode="tracking")
        p_hit = min(1.0, len(pred_xy) * math.pi * tight**2 / (cam.width * cam.height))
        n_look = 1.0
        if wide > _LOOSE_GATE * tight:
            # look-elsewhere: under a loose prior the shift and roll rounds keep the best of
            # about (wide/tight)² image offsets × the roll steps the gate spans at the frame's
            # edge, while the binomial above is the chance of one of them. Without it, 3 of
            # 50 detections (7 false, a 30° field) fitted near a prior 10° wrong at σ 0.5°:
            # accepted 10.9° off at p_false 8.9e-5 (benchmarks/fuzz.py).
            r_edge_px = 0.5 * math.hypot(cam.width, cam.height)
            n_roll = max(1.0, 2.0 * gate_rad * r_edge_px / tight)  # roll step: tight/r_edge
            n_look = (wide / tight) ** 2 * n_roll
        p_false = min(1.0, n_look * n_hyp * binomial_tail(len(det_i), len(xy), p_hit))
        if len(det_i) == 2:
            # two stars fix an attitude whatever they are: every pair of catalogue stars in
            # the prior's cone around the two detections with their separation is an equally
            # good answer (a neighbour taken for the star turns the roll)
            n_fit = self._pairings_that_fit(b_use, xy[det_i], pred_xy, pred_idx, wide)
            if n_fit > 1:
                p_false = max(p_false, (n_fit - 1) / n_fit)
            if wide > _LOOSE_GATE * tight:
                # ... and when one detection is not a star at all, only the wrong pairing
                # is left to fit. With gates many match radii wide the fit may turn the
                # frame anywhere inside them, so the tight-radius chance above no longer
                # bounds it (within a few radii it does: the fit cannot move far): the chance
                # that some catalogue pair lies in the two gates with the detections'
                # separation, for any pair of the M detections, is the expected stars per
                # gate (this field's catalogue density) squared times the share of
                # separations within the pair tolerance (a fix 1.08° off passed at a 0.5°
                # prior before). A tight prior's gates are the match radius: covered above.
                # the density of the *other* stars: the two matched ones are not a chance
                rho = max(len(pred_xy) - 2, 0) / float(cam.width * cam.height)
                per_gate = rho * math.pi * wide * wide
                tol_px = self.tolerance_rad / cam.pixel_scale_rad
                pairs = len(xy) * (len(xy) - 1) / 2
                p_false = max(p_false, min(1.0, pairs * per_gate * per_gate
                                           * min(1.0, tol_px / wide)))
        if len(det_i) >= 3:
            # a star the others do not pin: its pairing must be the only one that fits
            n_alt = self._alternatives_of_critical_stars(xy, det_i, cat_i, b_use, w.q_cam_icrs,
                                                         cov, prior, pred_idx, tight)
            if n_alt:
                p_false = max(p_false, n_alt / (n_alt + 1.0))
        matches = list(zip(det_i.tolist(), self.view.ids[cat_i].tolist(), strict=True))
        cand = Candidate(
            q_cam_icrs=w.q_cam_icrs, matches=matches, residuals_rad=w.residuals_rad,
            p_false=p_false, n_pattern=len(det_i), camera=cam, covariance=cov,
            _projector=self.view.project,
        )
        if p_false > self.p_false_max_tracking:
            return Solution(False, f"ambiguous: {len(det_i)} tracked stars, p_false "
                                   f"{p_false:.2g} > {self.p_false_max_tracking:.0e}",
                            mode="tracking", candidates=[cand])
        return Solution(True, "", q_cam_icrs=w.q_cam_icrs, matches=matches,
                        matching_counter=1, covariance=cov, mode="tracking",
                        time_s=time.perf_counter() - t0, p_false=p_false, path="tracking",
                        candidates=[cand], residuals_rad=w.residuals_rad, camera=cam,
                        n_detections=len(xy), n_predicted=len(pred_xy))


    def _alternatives_of_critical_stars(self, xy: NDArray, det_i: NDArray, cat_i: NDArray,
                                        b_use: NDArray, q_fix: NDArray, cov: NDArray,
                                        prior: Prior, pred_idx: NDArray,
                                        tight: float) -> int:
        """Other catalogue stars that could have been paired with a star the rest of the
        fix does not pin: the 2-star rule for more stars.

        Three stars close together pin the pointing but leave the roll to a fourth, far
        one; when that star has a neighbour in the catalogue, pairing its detection with
        the neighbour turns the roll and fits as well. The long fuzz run (seed 41) accepted
        such a fix 1.67° off at p_false 3.5e-6 under a right prior of σ 0.5° (three stars
        of one group, the fourth a Pleiades member taken for the next one). For each
        matched star: where the other stars and the prior place it (1σ from the fix's
        information less its own, plus the prior's). A star placed no better than the
        match radius has as alternatives the predicted stars farther than the match radius
        (nearer ones give the same attitude) but within 3σ + the match radius. The caller
        makes ``p_false`` at least n/(n + 1)."""
        r, k = _edge_scales(self.camera)
        prior_var = math.radians(prior.sigma_deg) ** 2
        if 3.0 * corner_sigma_px(prior_var * np.eye(3), self.camera) <= tight:
            return 0  # the prior alone pins every star within the match radius
        try:
            info = np.linalg.inv(cov)
        except np.linalg.LinAlgError:
            return 0
        b = np.asarray(b_use, dtype=np.float64)
        proj = np.eye(3)[None] - b[:, :, None] * b[:, None, :]
        # the stars share one weight (one centroid σ, one variance factor)
        weight = float(np.trace(info)) / max(float(np.trace(proj.sum(axis=0))), 1e-300)
        without = info[None] - weight * proj + np.eye(3)[None] / prior_var
        try:
            c = np.linalg.inv(without)
        except np.linalg.LinAlgError:
            return 0
        # a star's direction moves by δθ × b: its covariance [b]ₓ C [b]ₓᵀ, in the image
        # (x, y) block, at the frame edge's scale
        bx = np.zeros((len(b), 3, 3))
        bx[:, 0, 1], bx[:, 0, 2], bx[:, 1, 2] = -b[:, 2], b[:, 1], -b[:, 0]
        bx -= bx.transpose(0, 2, 1)
        cb = bx @ c @ bx.transpose(0, 2, 1)
        sigma_px = k * np.sqrt(np.maximum(cb[:, 0, 0] + cb[:, 1, 1], 0.0))
        reach = 3.0 * np.minimum(sigma_px, r) + tight
        # a star pinned to within the match radius keeps its pairing: another one would
        # leave a residual the fit's rejection removes
        loose = np.flatnonzero(sigma_px >= tight)
        if not len(loose):
            return 0
        # the predicted stars where the fix puts them
        v_cam = rot.rotate(q_fix, self.view.vectors[pred_idx])
        front = v_cam[:, 2] > 0
        pxy = self.camera.vectors_to_pixels(v_cam[front])
        rows = pred_idx[front]
        n_alt = 0
        for i in loose.tolist():
            d = np.hypot(*(pxy - xy[det_i[i]]).T)
            n_alt += int(np.count_nonzero((d > tight) & (d <= reach[i]) & (rows != cat_i[i])))
        return n_alt


def pair_within(xy: NDArray, pred_xy: NDArray, pred_idx: NDArray,
                 radius_px: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Each detection to its nearest predicted star within a radius, one-to-one."""
    det, j = one_to_one(*cKDTree(pred_xy).query(xy, distance_upper_bound=radius_px))
    return det, pred_idx[j].astype(np.int64)



def corner_sigma_px(cov: NDArray, cam: Camera) -> float:
    """1-σ shift (px) of the frame's corners under an attitude covariance (camera frame):
    pointing errors (x, y axes) move a corner by f·(1 + tan²θ) per radian, roll (z) by its
    distance r from the centre; correlations ignored (an upper estimate)."""
    r, k = _edge_scales(cam)
    return math.sqrt(max(0.0, float(cov[0, 0] + cov[1, 1])) * k * k
                     + max(0.0, float(cov[2, 2])) * r * r)


def _edge_scales(cam: Camera) -> tuple[float, float]:
    """(r, k) at the frame's corner: its distance r from the centre (px), and k, the px a
    radian of pointing moves it, f·(1 + (r/f)²)."""
    f = 1.0 / cam.pixel_scale_rad
    r = 0.5 * math.hypot(cam.width, cam.height)
    return r, f * (1.0 + (r / f) ** 2)


def _norm3(v: NDArray) -> float:
    x, y, z = v.tolist()
    return math.sqrt(x * x + y * y + z * z)
