"""FITS world coordinates (TAN-SIP, through astropy) from a camera and an attitude.

A pinhole camera *is* a gnomonic (TAN) projection about its principal ray, so the linear
part is exact: ``CRVAL`` is the principal ray's RA/Dec, ``CRPIX`` the principal point
(FITS counts pixel centres from 1, ours from 0), and ``CD = M·K₂⁻¹`` with ``K₂`` the
upper 2×2 of the camera matrix and ``M`` the camera-frame components of the tangent
plane's east and north axes (in degrees). The lens distortion (OpenCV radial/tangential)
becomes SIP polynomials fitted by least squares on a dense pixel grid over the frame —
forward ``A``/``B`` (pixel → undistorted) and inverse ``AP``/``BP`` — at the lowest order
(2…9) that reproduces the camera model to ``tol_px`` everywhere on the grid.

Example:
    >>> import numpy as np
    >>> from adfusion.starid import Camera, rotations as rot
    >>> from adfusion.starid.camera.wcs import camera_wcs
    >>> cam = Camera.pinhole(1024, 768, 11.4)
    >>> q = rot.q_cam_icrs_from_radec_roll(*np.radians([150.0, 20.0, 30.0]))
    >>> w = camera_wcs(cam, q)
    >>> ra, dec = w.all_pix2world([[511.5, 383.5]], 0)[0]
    >>> round(float(ra), 9), round(float(dec), 9), w.wcs.ctype[0]
    (150.0, 20.0, 'RA---TAN')
"""

from __future__ import annotations

import math

import numpy as np
from adfusion.starid.camera.model import Camera
from numpy.typing import ArrayLike, NDArray

from adfusion.maths import rotations as rot

__all__ = ["camera_wcs", "wcs_header"]


def camera_wcs(camera: Camera, q_cam_icrs: ArrayLike, tol_px: float = 0.01,
               max_order: int = 9):
    """An ``astropy.wcs.WCS`` mapping this camera's pixels (0-based here, ``origin=0``
    in astropy's calls) to ICRS RA/Dec at the attitude ``q_cam_icrs``.

    Distortion-free cameras get a plain TAN; otherwise TAN-SIP. Raises ``ValueError`` for
    the angular (non-pinhole) models, or when no SIP order up to ``max_order`` reaches
    ``tol_px``.
    """
    from astropy.wcs import WCS, Sip

    if camera.model != "pinhole":
        raise ValueError(f"a TAN WCS describes pinhole cameras only, not {camera.model!r}")
    R = rot.to_matrix(rot.normalize(np.asarray(q_cam_icrs, np.float64)))  # ICRS → camera
    c = R.T @ np.array([0.0, 0.0, 1.0])
    ra0, dec0 = (float(np.degrees(a)) % 360.0 if i == 0 else float(np.degrees(a))
                 for i, a in enumerate(rot.vector_to_radec(c)))
    a0, d0 = math.radians(ra0), math.radians(dec0)
    east = np.array([-math.sin(a0), math.cos(a0), 0.0])
    north = np.array([-math.sin(d0) * math.cos(a0), -math.sin(d0) * math.sin(a0),
                      math.cos(d0)])
    e_cam, n_cam = R @ east, R @ north
    # normalised camera coordinates (x/z, y/z) → tangent-plane degrees; a mirrored image
    # flips the camera x before projection
    M = np.degrees(np.array([[e_cam[0] * camera.parity, e_cam[1]],
                             [n_cam[0] * camera.parity, n_cam[1]]]))
    K2 = np.asarray(camera.K[:2, :2], np.float64)
    w = WCS(naxis=2)
    w.wcs.crpix = [camera.K[0, 2] + 1.0, camera.K[1, 2] + 1.0]
    w.wcs.crval = [ra0, dec0]
    w.wcs.cd = M @ np.linalg.inv(K2)
    w.wcs.cunit = ["deg", "deg"]
    w.wcs.radesys = "ICRS"
    w.pixel_shape = (camera.width, camera.height)
    if camera.D.size == 0 or not np.any(camera.D):
        w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
        w.wcs.set()
        return w
    w.wcs.ctype = ["RA---TAN-SIP", "DEC--TAN-SIP"]
    uv, uv_ideal = _distortion_grid(camera, K2)
    for order in range(2, max_order + 1):
        a, b, err_fwd = _fit_poly(uv, uv_ideal - uv, order, min_degree=2)
        ap, bp, err_inv = _fit_poly(uv_ideal, uv - uv_ideal, order, min_degree=1)
        if max(err_fwd, err_inv) <= tol_px:
            w.sip = Sip(a, b, ap, bp, w.wcs.crpix)
            w.wcs.set()
            return w
    raise ValueError(f"the lens distortion needs SIP beyond order {max_order} to reach "
                     f"{tol_px} px (fit error {max(err_fwd, err_inv):.3f} px)")


def wcs_header(camera: Camera, q_cam_icrs: ArrayLike, **kw):
    """The FITS header (``astropy.io.fits.Header``) of :func:`camera_wcs`, with
    ``IMAGEW``/``IMAGEH`` as solve-field writes them.

    >>> import numpy as np
    >>> from adfusion.starid import Camera
    >>> h = wcs_header(Camera.pinhole(640, 480, 10.0), [1.0, 0, 0, 0])
    >>> h["CTYPE1"], h["IMAGEW"], h["CRPIX1"]
    ('RA---TAN', 640, 320.5)
    """
    w = camera_wcs(camera, q_cam_icrs, **kw)
    h = w.to_header(relax=True)
    h["IMAGEW"] = (camera.width, "image width, pixels")
    h["IMAGEH"] = (camera.height, "image height, pixels")
    return h


def _distortion_grid(camera: Camera, K2: NDArray) -> tuple[NDArray, NDArray]:
    """Pixel offsets from the principal point on a grid over the frame (a little
    beyond it), distorted (as imaged) and ideal (the undistorted pinhole's)."""
    w, h = camera.width, camera.height
    xs = np.linspace(-0.02 * w, 1.02 * w, 41) - 0.5
    ys = np.linspace(-0.02 * h, 1.02 * h, 31) - 0.5
    xy = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
    v = camera.pixels_to_vectors(xy)
    ok = np.all(np.isfinite(v), axis=1) & (v[:, 2] > 0)
    if not np.all(ok):
        raise ValueError("the lens model does not invert over the whole frame (it folds "
                         "over): no SIP describes it")
    xn = np.stack([v[:, 0] * camera.parity / v[:, 2], v[:, 1] / v[:, 2]], -1)
    cxy = camera.K[:2, 2]
    return xy - cxy, xn @ K2.T


def _fit_poly(uv: NDArray, target: NDArray, order: int,
              min_degree: int) -> tuple[NDArray, NDArray, float]:
    """SIP coefficient arrays (order+1, order+1) for x and y fitted to ``target``, and the
    largest residual (px)."""
    s = float(np.max(np.abs(uv)))  # scale: well-conditioned columns
    terms = [(p, q) for p in range(order + 1) for q in range(order + 1)
             if min_degree <= p + q <= order]
    u, v = uv[:, 0] / s, uv[:, 1] / s
    A = np.stack([u**p * v**q for p, q in terms], axis=1)
    coef, *_ = np.linalg.lstsq(A, target, rcond=None)
    err = float(np.max(np.linalg.norm(A @ coef - target, axis=1)))
    out = np.zeros((2, order + 1, order + 1))
    for k, (p, q) in enumerate(terms):
        out[:, p, q] = coef[k] / s ** (p + q)
    return out[0], out[1], err
