"""Star-camera frame renderer: catalogue stars through a camera model onto a noisy image.

Seeded and deterministic: the same arguments give the same image bit for bit. The model
is deliberately simple and physical — a Gaussian PSF integrated over each pixel (error
functions, so sub-pixel positions render exactly), photon shot noise, Gaussian read noise,
a sky background, optional hot pixels and a saturation level.

Example:
    >>> import numpy as np
    >>> from starid import Camera
    >>> from sensors.render import render_stars
    >>> cam = Camera.pinhole(64, 48, 5.0)
    >>> img = render_stars(cam, np.array([[31.0, 23.0]]), np.array([5000.0]), seed=1)
    >>> img.shape, img.dtype.name, int(np.unravel_index(img.argmax(), img.shape)[1])
    ((48, 64), 'uint16', 31)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import erf

from starid.camera import Camera

__all__ = ["SensorModel", "magnitude_to_electrons", "render_sky", "render_stars"]


@dataclass(frozen=True)
class SensorModel:
    """Detector and optics parameters for :func:`render_stars`.

    ``zero_point_e`` is the electron count a magnitude-0 star yields in one exposure; the
    default puts a mag-6 star at ~4000 e⁻ (a small star tracker, ~0.1 s exposure).
    """

    psf_sigma_px: float = 1.0
    background_e: float = 100.0
    read_noise_e: float = 10.0
    gain_e_per_adu: float = 1.0
    bias_adu: float = 100.0
    full_well_adu: float = 65535.0
    zero_point_e: float = 1.0e6
    hot_pixels: int = 0
    hot_pixel_e: float = 20000.0
    dtype: str = "uint16"


def magnitude_to_electrons(mag: ArrayLike, zero_point_e: float) -> NDArray[np.float64]:
    """Pogson's law: a star of magnitude m gives ``zero_point_e · 10^(−0.4 m)`` electrons."""
    return zero_point_e * 10.0 ** (-0.4 * np.asarray(mag, dtype=np.float64))


def render_stars(
    camera: Camera,
    xy: ArrayLike,
    electrons: ArrayLike,
    sensor: SensorModel | None = None,
    seed: int | None = 0,
) -> NDArray:
    """Render point sources at pixel positions ``xy`` (N, 2) with total ``electrons`` (N,).

    Stars whose PSF falls partly outside the frame are rendered partly.
    """
    s = sensor or SensorModel()
    rng = np.random.default_rng(seed)
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    electrons = np.asarray(electrons, dtype=np.float64).reshape(-1)
    h, w = camera.height, camera.width
    signal = np.full((h, w), s.background_e, dtype=np.float64)
    r = int(np.ceil(5 * s.psf_sigma_px)) + 1
    k = np.sqrt(2.0) * s.psf_sigma_px
    for (x, y), e in zip(xy, electrons, strict=True):
        if not (np.isfinite(x) and np.isfinite(y)) or e <= 0:
            continue
        x0, x1 = max(int(np.floor(x)) - r, 0), min(int(np.floor(x)) + r + 2, w)
        y0, y1 = max(int(np.floor(y)) - r, 0), min(int(np.floor(y)) + r + 2, h)
        if x0 >= x1 or y0 >= y1:
            continue
        # exact pixel integrals of the Gaussian: pixel i covers [i − 0.5, i + 0.5]
        ex = erf((np.arange(x0, x1 + 1) - 0.5 - x) / k)
        ey = erf((np.arange(y0, y1 + 1) - 0.5 - y) / k)
        px = 0.5 * np.diff(ex)
        py = 0.5 * np.diff(ey)
        signal[y0:y1, x0:x1] += e * np.outer(py, px)
    electrons_img = rng.poisson(signal).astype(np.float64)
    if s.hot_pixels:
        idx = rng.choice(h * w, size=s.hot_pixels, replace=False)
        electrons_img.flat[idx] += s.hot_pixel_e
    electrons_img += rng.normal(0.0, s.read_noise_e, size=(h, w))
    adu = electrons_img / s.gain_e_per_adu + s.bias_adu
    info = np.iinfo(s.dtype) if np.dtype(s.dtype).kind in "ui" else None
    top = min(s.full_well_adu, info.max) if info else s.full_well_adu
    adu = np.clip(adu, 0, top)
    return np.round(adu).astype(s.dtype) if info else adu.astype(s.dtype)


def render_sky(
    camera: Camera,
    q_cam_icrs: ArrayLike,
    vectors_icrs: ArrayLike,
    mag: ArrayLike,
    sensor: SensorModel | None = None,
    seed: int | None = 0,
) -> tuple[NDArray, NDArray[np.float64], NDArray[np.intp]]:
    """Render catalogue stars seen at attitude ``q_cam_icrs``.

    Returns the image, the true pixel positions of the stars inside the frame, and their
    catalogue indices (so tests can score detections against truth).
    """
    from starid.rotations import rotate

    s = sensor or SensorModel()
    v_cam = rotate(q_cam_icrs, np.asarray(vectors_icrs, dtype=np.float64))
    front = v_cam[:, 2] > 0
    xy = np.full((len(v_cam), 2), np.nan)
    xy[front] = camera.vectors_to_pixels(v_cam[front])
    inside = np.flatnonzero(camera.in_frame(xy, margin=-3 * s.psf_sigma_px))
    e = magnitude_to_electrons(np.asarray(mag)[inside], s.zero_point_e)
    img = render_stars(camera, xy[inside], e, s, seed)
    in_frame = camera.in_frame(xy[inside])
    return img, xy[inside][in_frame], inside[in_frame]
