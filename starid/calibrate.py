"""Fit a camera model and attitude to reference pixel ↔ sky-direction pairs.

Used to check a camera against an independent solution (astrometry.net's grid in
``shared/data/real-images/truth.json``) and to refine the focal length of a camera from
identified stars. Least squares on the angle between predicted and reference directions
(scipy ``least_squares``), starting from the Wahba solution.

Example:
    >>> import numpy as np
    >>> from adfusion.starid import Camera, rotations as rot
    >>> from adfusion.starid.calibrate import fit_camera
    >>> true_cam = Camera.pinhole(1024, 768, 11.4)
    >>> q = rot.q_cam_icrs_from_radec_roll(3.0, 0.4, 1.0)
    >>> xy = np.array([[100.0, 80], [512, 80], [900, 700], [512, 384], [50, 700]])
    >>> r = rot.rotate(rot.inverse(q), true_cam.pixels_to_vectors(xy))
    >>> fit = fit_camera(xy, r, Camera.pinhole(1024, 768, 11.0))
    >>> round(fit.camera.fov_x_deg, 9), bool(fit.rms_rad < 1e-12)
    (11.4, True)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from adfusion.starid import rotations as rot
from adfusion.starid.attitude import wahba
from adfusion.starid.camera import Camera
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

__all__ = ["CameraFit", "fit_camera"]


@dataclass(frozen=True)
class CameraFit:
    """Result of :func:`fit_camera`: the camera, ``q_cam_icrs`` and residuals (rad)."""

    camera: Camera
    q_cam_icrs: NDArray[np.float64]
    residuals_rad: NDArray[np.float64]

    @property
    def rms_rad(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_rad**2)))


def fit_camera(
    xy: ArrayLike,
    r_icrs: ArrayLike,
    camera: Camera,
    fit_focal: bool = True,
    fit_k1: bool = False,
    try_mirror: bool = True,
) -> CameraFit:
    """Fit attitude (and focal scale, and optionally radial k1) to pixel/direction pairs.

    With ``try_mirror`` both parities are fitted and the better one returned, so an
    image of unknown handedness is handled.
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    r = np.asarray(r_icrs, dtype=np.float64).reshape(-1, 3)
    need = 2 + int(fit_focal) + int(fit_k1)
    if len(xy) < need or len(xy) != len(r):
        raise ValueError(f"need ≥ {need} matching pixel/direction pairs, got {len(xy)}/{len(r)}")
    if fit_k1 and camera.model != "pinhole":
        raise ValueError("k1 can only be fitted for the pinhole model")
    cams = [camera, camera.mirrored()] if try_mirror else [camera]
    fits = [_fit_one(xy, r, c, fit_focal, fit_k1) for c in cams]
    return min(fits, key=lambda f: f.rms_rad)


def _fit_one(xy: NDArray, r: NDArray, cam0: Camera, fit_focal: bool, fit_k1: bool) -> CameraFit:
    q0 = wahba(cam0.pixels_to_vectors(xy), r).q_cam_icrs

    def make_camera(p: NDArray) -> Camera:
        cam = cam0.scaled(float(np.exp(p[3]))) if fit_focal else cam0
        if fit_k1:
            d = np.zeros(5)
            d[: cam.D.size] = cam.D[:5]
            d[0] = p[4]
            cam = Camera(cam.K, d, cam.width, cam.height, cam.model, cam.parity)
        return cam

    def residuals(p: NDArray) -> NDArray:
        cam = make_camera(p)
        q = rot.multiply(rot.exp_map(p[:3]), q0)
        b = cam.pixels_to_vectors(xy)
        pred = rot.rotate(q, r)
        return np.cross(pred, b).ravel()  # ≈ angle × axis, smooth near the optimum

    p0 = np.zeros(3 + int(fit_focal) + int(fit_k1))
    sol = least_squares(residuals, p0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    cam = make_camera(sol.x)
    q = rot.normalize(rot.multiply(rot.exp_map(sol.x[:3]), q0))
    b = cam.pixels_to_vectors(xy)
    pred = rot.rotate(q, r)
    res = np.arctan2(np.linalg.norm(np.cross(pred, b), axis=1), np.sum(pred * b, axis=1))
    return CameraFit(cam, q, res)
