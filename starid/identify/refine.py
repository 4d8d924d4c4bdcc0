"""After identification: the frame's own evidence sets the final fit.

An accepted lost-in-space candidate was verified with the configured centroid noise and
camera. :class:`Refiner` then lets the frame speak (issue 14, items 2 and 3):

1. the centroid noise is estimated a posteriori from the fit residuals — corrected for
   the degrees of freedom the fit used and for the match radius that truncated them
   (:func:`noise_from_residuals`) — and the match radius follows it, so a frame 3× noisier
   than ``centroid_sigma_px`` still associates its stars;
2. with an uncertain camera, focal length, pixel aspect and OpenCV distortion are fitted
   to the matched stars (:func:`starid.camera.calibrate.fit_camera_model`), and every detection
   is associated again through the fitted camera. The principal point stays the given
   camera's: one frame cannot tell it from the attitude, and a per-frame principal point
   would turn the reported camera frame by up to 0.16° from frame to frame (measured on
   the real frames); ``adfusion calibrate`` fits it over many frames;
3. pairs whose residual the fit rejects (beyond 3.5 robust σ: a neighbour taken for the
   star, a blend) leave before the final fit;
4. the final Wahba fit's covariance uses the estimated noise (shrunk towards the
   configured one when the frame has few stars, and widened by ν/(ν − 2) for being an
   estimate), so it neither trusts the configuration nor lies to a filter.

Example:
    >>> import numpy as np
    >>> r = np.random.default_rng(1).normal(0, 2.0, (20000, 2))
    >>> round(noise_from_residuals(r, radius_px=1e9, n_params=0), 1)
    2.0
    >>> d = np.hypot(*r.T)
    >>> round(noise_from_residuals(r[d < 3.0], radius_px=3.0, n_params=0), 1)
    2.0
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
from adfusion.starid.camera.calibrate import fit_camera_model
from adfusion.starid.camera.model import Camera
from adfusion.starid.identify import kernels
from adfusion.starid.identify.solution import Solution
from adfusion.starid.identify.verify import match_radius_px
from numpy.typing import NDArray

from adfusion.maths import rotations as rot
from adfusion.maths.attitude import wahba_unit

if TYPE_CHECKING:
    from adfusion.starid.identify.catalog_view import CatalogView

__all__ = ["Refiner", "noise_from_residuals"]

# beyond this many robust σ a pair is not the star (2-D Gaussian: 0.2 % of true pairs)
_REJECT_SIGMA = 3.5
# the match radius follows the estimated noise: this many σ (wide: a small frame's first
# estimate is low, and the residual test below still cuts at 3.5σ)
_RADIUS_SIGMA = 5.0
# ... but never beyond this many times the configured radius (a runaway on a bad frame)
_RADIUS_MAX_FACTOR = 5.0
# pseudo-degrees of freedom of the configured noise in the a-posteriori estimate: a frame
# with few stars says little about its noise
_PRIOR_DOF = 0.0
# kernels.refine_pinhole's first fit made by the kernel: a verified candidate's attitude
# from the numpy verification need not be the kernel's own fit to the bit
_FIT_HERE = np.zeros(0)


def noise_from_residuals(res_px: NDArray, radius_px: float, n_params: int) -> float:
    """Per-axis centroid noise σ (px) from 2-D fit residuals (N, 2) of pairs associated
    within ``radius_px``: the residuals' mean square over the degrees of freedom left
    (2N − ``n_params``), corrected for the truncation at the radius (a 2-D Gaussian cut
    at R keeps E[r²] = 2σ²(1 − u e⁻ᵘ/(1 − e⁻ᵘ)), u = R²/2σ²). NaN without spare data."""
    res = np.asarray(res_px, dtype=np.float64).reshape(-1, 2)
    dof = 2 * len(res) - n_params
    if dof <= 0:
        return float("nan")
    s2_raw = float(np.sum(res * res)) / dof
    s2 = s2_raw
    for _ in range(30):
        u = radius_px * radius_px / (2.0 * s2) if s2 > 0 else math.inf
        keep = 1.0 if u > 50 else 1.0 - u * math.exp(-u) / -math.expm1(-u)
        new = s2_raw / max(keep, 0.05)
        if abs(new - s2) <= 1e-9 * s2:
            break
        s2 = new
    return math.sqrt(s2)


class Refiner:
    """The final-fit stage of :class:`starid.Solver`: an accepted solution refitted on
    every detection (the steps of the module docstring).

    Args:
        view: the catalogue (:class:`~adfusion.starid.identify.catalog_view.CatalogView`:
            vectors, ids, projection and cached cone).
        camera: the solver's camera (a solution without its own is refitted through it).
        centroid_sigma_px: the configured 1-σ centroid error.
        fit_camera: the :class:`~adfusion.starid.config.SolverConfig` option.
        fov_uncertain: whether the focal length is uncertain (``fit_camera="auto"`` fits
            then).

    ``compiled`` (True): a fixed undistorted pinhole is refitted by
    :func:`starid.identify.kernels.refine_pinhole`; False: in Python.

    >>> from adfusion import starid
    >>> s = starid.Solver(starid.Catalog.hipparcos(mag_limit=4.0),
    ...                   starid.Camera.pinhole(1024, 768, 15.0))
    >>> isinstance(s.refiner, Refiner), s.refiner.fit_terms()
    (True, None)
    """

    def __init__(self, view: CatalogView, camera: Camera, centroid_sigma_px: float,
                 fit_camera: str, fov_uncertain: bool) -> None:
        self.view = view
        self.camera = camera
        self.centroid_sigma_px = float(centroid_sigma_px)
        self.fit_camera = fit_camera
        self.fov_uncertain = bool(fov_uncertain)
        self.compiled = True

    def match_radius_px(self) -> float:
        return match_radius_px(self.centroid_sigma_px)

    def fit_terms(self):
        mode = self.fit_camera
        if mode == "none" or (mode == "auto" and not self.fov_uncertain):
            return None
        return ("focal",) if mode == "focal" else "auto"

    def refine(self, sol: Solution, xy_all: NDArray) -> Solution:
        """:class:`Solution` ``sol`` (accepted) refitted on all detections ``xy_all``."""
        if not sol.ok or sol.q_cam_icrs is None or len(sol.matches) < 3:
            return sol
        cam0: Camera = sol.camera or self.camera
        terms = self.fit_terms()
        if (terms is None and cam0._ideal_pinhole is not None
                and self.compiled):
            out = self.refine_pinhole(sol, xy_all, cam0)
            if out is not None:
                return out
        det = np.array([d for d, _ in sol.matches], dtype=np.int64)
        cat = self.view.catalog_index(np.array([h for _, h in sol.matches], dtype=np.int64))
        original = set(det.tolist())
        r_min = self.match_radius_px()
        sigma0 = self.centroid_sigma_px
        ok_xy = np.isfinite(xy_all).all(axis=1)
        cam, q = cam0, sol.q_cam_icrs
        radius_px, sigma_px, n_par = r_min, sigma0, 3
        trunc_px = r_min  # where the current pairs were cut off (radius or rejection)
        n_cam = 0  # camera parameters fitted so far
        note = ""
        for it in range(8):
            if len(det) < 3:
                return sol
            pix = cam0.pixel_scale_rad
            if terms is not None and len(det) >= 4 and it in (0, 2):
                # while the matches settle, a small model (fitted twice: on the verified
                # pairs, then on the widened set; in between the attitude alone is refitted);
                # the data choose the final model below
                quick = terms if terms != "auto" else (("focal", "k1") if len(det) >= 8
                                                       else ("focal",))
                try:
                    fit = fit_camera_model([(xy_all[det], self.view.vectors[cat])], cam0,
                                           quick, q_cam_icrs=[sol.q_cam_icrs])
                except ValueError:
                    return sol
                cam, q = fit.camera, fit.q_cam_icrs[0]
                res_px = fit.residuals_px[0]
                n_cam = sum(2 if t in ("principal", "tangential") else 1 for t in fit.terms)
                n_par = 3 + n_cam
            else:
                b = cam.pixels_to_vectors(xy_all[det])
                w = wahba_unit(b, self.view.vectors[cat], sigma0 * pix)
                q = w.q_cam_icrs
                pred = cam.vectors_to_pixels(self.view.vectors[cat] @ rot.to_matrix(q).T)
                res_px = pred - xy_all[det]
                n_par = 3 + (n_cam if terms is not None else 0)
            sigma_px = noise_from_residuals(res_px, trunc_px, n_par)
            if not math.isfinite(sigma_px):
                sigma_px = sigma0
            # the first pass opens wide (the verified pairs were cut at the configured radius:
            # their spread says little when the frame is noisier); the residual test below
            # cuts what does not belong, then the radius follows the estimate
            radius_px = (_RADIUS_MAX_FACTOR * r_min if it == 0 else
                         min(max(r_min, _RADIUS_SIGMA * sigma_px), _RADIUS_MAX_FACTOR * r_min))
            # every detection again, through this camera and attitude
            pred_xy, pred_idx = self.view.predict(rot.to_matrix(q), cam, 0.0)
            new_det, new_cat = _associate_px(xy_all, ok_xy, pred_xy, pred_idx, radius_px)
            if len(new_det) < 3:
                return sol
            # the residuals reject pairs a robust σ puts beyond 3.5σ
            d = np.hypot(*(xy_all[new_det] - cam.vectors_to_pixels(
                self.view.vectors[new_cat] @ rot.to_matrix(q).T)).T)
            robust = math.sqrt(float(np.median(d * d)) / (2.0 * math.log(2.0)))
            reject_px = max(_REJECT_SIGMA * robust, 0.5 * r_min)
            keep = d <= reject_px
            n_rejected = int(np.count_nonzero(~keep))
            new_det, new_cat = new_det[keep], new_cat[keep]
            note = f"{n_rejected} pair(s) rejected by the residuals" if n_rejected else ""
            same = np.array_equal(new_det, det) and np.array_equal(new_cat, cat)
            trunc_px = min(radius_px, reject_px)
            if same:
                break
            det, cat = new_det, new_cat
        if len(original & set(det.tolist())) < 0.5 * len(original) or len(det) < 3:
            return sol  # the refit walked away from the verified stars: keep the verified fit
        if terms == "auto" and len(det) >= 4:
            try:
                fit = fit_camera_model([(xy_all[det], self.view.vectors[cat])], cam0, terms,
                                       q_cam_icrs=[q], free_principal=False)
            except ValueError:
                return sol
            cam = fit.camera
            n_par = 3 + sum(2 if t in ("principal", "tangential") else 1 for t in fit.terms)
            sigma_px = noise_from_residuals(fit.residuals_px[0], trunc_px, n_par)
            if not math.isfinite(sigma_px):
                sigma_px = sigma0
        b = cam.pixels_to_vectors(xy_all[det])
        if not np.isfinite(b).all():
            return sol
        # a-posteriori noise, shrunk towards the configured value for small frames
        dof = max(2 * len(det) - n_par, 0)
        s2 = (dof * sigma_px**2 + _PRIOR_DOF * sigma0**2) / (dof + _PRIOR_DOF)
        # an estimated variance makes the error Student-t rather than Gaussian: its
        # covariance is ν/(ν − 2) times the plug-in one (ν the degrees of freedom)
        nu = dof + _PRIOR_DOF
        inflate = nu / (nu - 2.0) if nu > 4.0 else 2.0
        try:
            w = wahba_unit(b, self.view.vectors[cat],
                           math.sqrt(s2 * inflate) * cam.pixel_scale_rad)
        except ValueError:
            return sol
        order = np.argsort(det)
        matches = [(int(a), int(self.view.ids[c])) for a, c in zip(det[order], cat[order],
                                                               strict=True)]
        return replace(sol, q_cam_icrs=w.q_cam_icrs, matches=matches,
                       covariance=w.covariance, residuals_rad=w.residuals_rad[order],
                       camera=cam, sigma_px=math.sqrt(s2),
                       note="; ".join(n for n in (sol.note, note) if n))

    def refine_pinhole(self, sol: Solution, xy_all: NDArray, cam0: Camera) -> Solution | None:
        """:meth:`refine` compiled (:func:`starid.identify.kernels.refine_pinhole`) for a camera
        that is not fitted and has no distortion: the same steps and constants, the same
        pairs, the fit to ~1e-12 (a Jacobi SVD instead of LAPACK's). None when the cached
        catalogue cone does not cover an attitude of the refit (the caller runs the Python
        code then)."""
        M, off, A, c = cam0._ideal_pinhole
        det = np.array([d for d, _ in sol.matches], dtype=np.int64)
        cat = self.view.catalog_index(np.array([h for _, h in sol.matches], dtype=np.int64))
        view_half = cam0._view_half_rad + 1e-3
        idx, vec = self.view.cone(rot.to_matrix(sol.q_cam_icrs)[2], view_half)
        c_axis, c_half = self.view.cone_cache[0], self.view.cone_cache[1]
        xy = np.ascontiguousarray(xy_all, dtype=np.float64)
        status, d, k, q, cov, res, sigma_px, rejected = kernels.refine_pinhole(
            xy, np.isfinite(xy).all(axis=1), det, cat, self.view.vectors, M, off, A, c,
            float(cam0.width), float(cam0.height), idx, vec, c_axis, float(c_half),
            view_half, cam0.pixel_scale_rad, float(self.match_radius_px()),
            self.centroid_sigma_px, _REJECT_SIGMA, _RADIUS_SIGMA, _RADIUS_MAX_FACTOR,
            float(_PRIOR_DOF), _FIT_HERE, _FIT_HERE)
        if status < 0:
            return None
        if status == 0:
            return sol
        order = np.argsort(d)
        matches = list(zip(d[order].tolist(), self.view.ids[k[order]].tolist(), strict=True))
        note = f"{rejected} pair(s) rejected by the residuals" if rejected else ""
        return replace(sol, q_cam_icrs=q, matches=matches, covariance=cov,
                       residuals_rad=res[order], camera=cam0, sigma_px=float(sigma_px),
                       note="; ".join(n for n in (sol.note, note) if n))


def _associate_px(xy: NDArray, ok: NDArray, pred_xy: NDArray, pred_idx: NDArray,
                  radius_px: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Detections ↔ predicted stars within a pixel radius, one-to-one: each predicted star
    keeps its nearest detection, each detection its nearest star; sorted by detection."""
    if len(pred_xy) == 0:
        e = np.zeros(0, dtype=np.int64)
        return e, e
    d = xy[:, None, :] - pred_xy[None, :, :]
    d2 = np.einsum("ijk,ijk->ij", d, d)
    d2[~ok] = np.inf
    j = np.argmin(d2, axis=1)
    best = d2[np.arange(len(xy)), j]
    det = np.flatnonzero(best <= radius_px * radius_px)
    # a star claimed by several detections goes to the closest
    det = det[np.lexsort((det, best[det]))]
    _, first = np.unique(j[det], return_index=True)
    det = np.sort(det[first])
    return det.astype(np.int64), pred_idx[j[det]].astype(np.int64)
