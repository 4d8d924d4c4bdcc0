"""Star-camera frame renderer: catalogue stars through a camera model onto a noisy image.

Seeded and deterministic: the same arguments give the same image bit for bit. The model
is deliberately simple and physical:

* **optics**: a Gaussian PSF integrated over each pixel (error functions, so sub-pixel
  positions render exactly);
* **motion**: with a body rate, each source's image path during the exposure is integrated in
  sub-steps no longer than the PSF sigma (the summed PSFs then equal the continuous streak
  to 2·exp(−2π²) ≈ 5e-9 relative), each sub-step a pixel-integrated Gaussian. The attitude
  passed in is the one at **mid-exposure**; the camera turns at the constant rate
  ``omega_cam_rad_s`` (camera frame) over ``[−T/2, +T/2]``, so
  ``q_cam_icrs(s) = exp(−ω s) ⊗ q_cam_icrs(0)``;
* **false objects**: planets (point sources at ICRS directions, streaked like stars) and
  tethers (bright lines in the camera frame, entering from a frame edge, see :class:`Tether`);
* **detector**: sky background, photon shot noise, Gaussian read noise, hot pixels, gain,
  bias, saturation (full well) and the output integer type;
* **intensifier** (optional, :class:`Intensifier`): each photo-event is amplified by a
  gamma-distributed gain (so the shot noise gets heavy, Poisson-gamma tails), spread by the
  phosphor into a blob (bloom), on top of a broad low-frequency glow — the look of an
  intensified video camera (OEDIPUS-C).

Noise models (``SensorModel.noise``): ``"poisson"`` draws exact Poisson photon counts for
every pixel; ``"gaussian"`` keeps exact Poisson counts for the sources but draws the smooth
background's shot noise together with the read noise as one Gaussian, N(0, √(sky + read²)) —
indistinguishable for backgrounds above a few tens of electrons and ~4× faster (a full-frame
Poisson draw dominates the cost). Measured on a shared 2-core AMD EPYC VM (512×480, 66 stars
of V < 5.6, best of 40 / median): static ``"gaussian"`` 3.8 / 4.4 ms (the float32 normal draw
alone is ~2.3 ms), static ``"poisson"`` 16 / 20 ms, an 18-px streak (0.5 rad/s, 33 ms
exposure) 8 / 11 ms, 110-px streaks (3 rad/s) 33 / 50 ms, the intensifier mode 26 / 34 ms.

Example:
    >>> import numpy as np
    >>> from adfusion.starid import Camera
    >>> from adfusion.sensors.render import render_stars
    >>> cam = Camera.pinhole(64, 48, 5.0)
    >>> img = render_stars(cam, np.array([[31.0, 23.0]]), np.array([5000.0]), seed=1)
    >>> img.shape, img.dtype.name, int(np.unravel_index(img.argmax(), img.shape)[1])
    ((48, 64), 'uint16', 31)

A streaked frame with a planet and a tether:

    >>> from adfusion.sensors.render import Planet, SensorModel, Tether, render_frame
    >>> from adfusion.maths.rotations import q_cam_icrs_from_radec_roll, radec_to_vector
    >>> cam = Camera.pinhole(512, 480, 25.8)
    >>> q = q_cam_icrs_from_radec_roll(*np.radians([10.0, 60.0, 0.0]))
    >>> stars = radec_to_vector(np.radians([10.0, 12.0]), np.radians([60.0, 62.0]))
    >>> fr = render_frame(cam, q, stars, [3.0, 4.0], SensorModel(noise="gaussian"), seed=2,
    ...                   omega_cam_rad_s=[0.0, 0.5, 0.0], exposure_s=0.02,
    ...                   planets=[Planet(radec_to_vector(np.radians(8.0), np.radians(58.0)),
    ...                                   -2.0, "Jupiter")],
    ...                   tethers=[Tether.from_edge(cam, "bottom", 0.3, 20.0, 150.0)])
    >>> fr.image.shape, len(fr.star_xy), fr.planet_xy.shape
    ((480, 512), 2, (1, 2))
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from adfusion.starid.camera.model import Camera
from numpy.typing import ArrayLike, NDArray
from scipy.special import erf

from adfusion.plain import listed

__all__ = [
    "Frame",
    "Intensifier",
    "Planet",
    "SensorModel",
    "Tether",
    "magnitude_to_electrons",
    "render_frame",
    "render_sky",
    "render_stars",
]

Array = NDArray[np.float64]
_NOISE_MODELS = ("poisson", "gaussian")


@dataclass(frozen=True)
class Intensifier:
    """Image-intensifier stage (photocathode → MCP → phosphor) in front of the detector.

    The sensor's electron counts (``zero_point_e``, ``background_e``) are then
    **photo-events** per exposure. Each event is multiplied by a gamma-distributed gain of
    mean ``gain_e`` (detector electrons) and shape ``gain_shape`` (1 = the exponential
    pulse-height distribution of a single MCP; larger = less gain noise), then spread by a
    Gaussian of ``bloom_sigma_px`` (phosphor and fibre-optic coupling: bloomy blobs and
    correlated noise). A broad glow of ``glow_events`` photo-events per pixel at its peak,
    Gaussian with sigma ``glow_sigma_frac`` × the image diagonal, centred at
    ``glow_center`` (fractions of width and height; None = drawn from the seed), is added
    to the sky before the events are drawn.
    """

    gain_e: float = 40.0
    gain_shape: float = 1.0
    bloom_sigma_px: float = 1.0
    glow_events: float = 5.0
    glow_sigma_frac: float = 0.3
    glow_center: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not (self.gain_e > 0 and self.gain_shape > 0):
            raise ValueError("gain_e and gain_shape must be > 0")
        if self.bloom_sigma_px < 0 or self.glow_events < 0 or self.glow_sigma_frac <= 0:
            raise ValueError("bloom_sigma_px, glow_events must be >= 0, glow_sigma_frac > 0")


@dataclass(frozen=True)
class SensorModel:
    """Detector and optics parameters for the renderers.

    ``zero_point_e`` is the electron count a magnitude-0 star yields in one exposure; the
    default puts a mag-6 star at ~4000 e⁻ (a small star tracker, ~0.1 s exposure).
    ``hot_pixel_seed`` fixes the hot-pixel positions (a property of the chip, the same in
    every frame); None draws them from each frame's seed. ``noise``: ``"poisson"`` (exact)
    or ``"gaussian"`` (the background's shot noise as a Gaussian; ~3× faster), see the module
    docstring. ``intensifier``: an :class:`Intensifier` stage, or None (with one, photo-events
    are always drawn from the Poisson distribution and ``noise`` is ignored).
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
    hot_pixel_seed: int | None = None
    noise: str = "poisson"
    intensifier: Intensifier | None = field(default=None)

    def __post_init__(self) -> None:
        if self.noise not in _NOISE_MODELS:
            raise ValueError(f"noise must be one of {listed(_NOISE_MODELS, None)}, got "
                             f"{self.noise!r}")
        if not self.psf_sigma_px > 0:
            raise ValueError(f"psf_sigma_px must be > 0, got {self.psf_sigma_px!r}")
        if self.background_e < 0 or self.read_noise_e < 0 or self.hot_pixels < 0:
            raise ValueError("background_e, read_noise_e and hot_pixels must be >= 0")
        if not self.gain_e_per_adu > 0:
            raise ValueError(f"gain_e_per_adu must be > 0, got {self.gain_e_per_adu!r}")


@dataclass(frozen=True)
class Planet:
    """A bright point source fixed in ICRS (a planet, or any false star): unit direction,
    magnitude on the catalogue's scale, and a name for the record."""

    direction_icrs: ArrayLike
    mag: float
    name: str = ""


@dataclass(frozen=True)
class Tether:
    """A bright straight line in the image (a tether, boom or antenna in the field of view),
    fixed in the camera frame, so not streaked by the body rate.

    The line runs from ``start_xy`` to ``end_xy`` (pixels) with ``electrons_per_px`` per
    pixel of length and a Gaussian cross-section of ``sigma_px`` (sampled at pixel centres).
    Use :meth:`from_edge` for one entering from a frame edge.
    """

    start_xy: tuple[float, float]
    end_xy: tuple[float, float]
    electrons_per_px: float = 3000.0
    sigma_px: float = 1.0

    @classmethod
    def from_edge(
        cls,
        camera: Camera,
        edge: str = "bottom",
        position: float = 0.5,
        angle_deg: float = 0.0,
        length_px: float = 150.0,
        electrons_per_px: float = 3000.0,
        sigma_px: float = 1.0,
    ) -> Tether:
        """A tether entering through ``edge`` ("top", "bottom", "left", "right") at the
        fraction ``position`` along it, pointing ``angle_deg`` away from the inward normal
        (positive = clockwise on the image), ``length_px`` of it inside the frame. It starts
        4 sigma outside the frame, so no end is visible at the edge.

        >>> t = Tether.from_edge(Camera.pinhole(100, 80, 10.0), "bottom", 0.5, 0.0, 30.0)
        >>> np.round(t.end_xy, 6).tolist()
        [49.5, 49.5]
        """
        w, h = camera.width, camera.height
        edges = {
            "top": ((-0.5 + position * w, -0.5), (0.0, 1.0)),
            "bottom": ((-0.5 + position * w, h - 0.5), (0.0, -1.0)),
            "left": ((-0.5, -0.5 + position * h), (1.0, 0.0)),
            "right": ((w - 0.5, -0.5 + position * h), (-1.0, 0.0)),
        }
        if edge not in edges:
            raise ValueError(f"edge must be one of {listed(edges, None)}, got {edge!r}")
        (x0, y0), (nx, ny) = edges[edge]
        a = np.radians(angle_deg)
        # rotate the inward normal by +a (clockwise on an image with y down)
        ux, uy = nx * np.cos(a) - ny * np.sin(a), nx * np.sin(a) + ny * np.cos(a)
        out = 4.0 * sigma_px
        start = (x0 - out * ux, y0 - out * uy)
        end = (x0 + length_px * ux, y0 + length_px * uy)
        return cls(start, end, electrons_per_px, sigma_px)


@dataclass(frozen=True)
class Frame:
    """A rendered frame and its truth.

    Attributes:
        image: (height, width) of ``sensor.dtype``.
        star_xy: (N, 2) mid-exposure pixel positions of the catalogue stars inside the frame.
        star_index: (N,) their indices into the catalogue arrays passed in.
        planet_xy: (P, 2) mid-exposure pixel positions of the planets (NaN when not imaged).
        hot_pixel_xy: (H, 2) positions of the hot pixels.
    """

    image: NDArray
    star_xy: Array
    star_index: NDArray[np.intp]
    planet_xy: Array
    hot_pixel_xy: NDArray[np.intp]


def magnitude_to_electrons(mag: ArrayLike, zero_point_e: float) -> NDArray[np.float64]:
    """Pogson's law: a star of magnitude m gives ``zero_point_e · 10^(−0.4 m)`` electrons."""
    return zero_point_e * 10.0 ** (-0.4 * np.asarray(mag, dtype=np.float64))


# --------------------------------------------------------------------------------------------
# Sources


def _psf_radius(sigma: float) -> int:
    return int(np.ceil(5 * sigma)) + 1


class _Canvas:
    """The noiseless source image (electrons) and a mask of the pixels sources touched (so
    the sparse Poisson draw need not scan the float image)."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.img = np.zeros(shape)
        self.touched = np.zeros(shape, dtype=bool)

    def add(self, flat: NDArray[np.intp], values: Array) -> None:
        if not len(flat):
            return
        # np.bincount sums in input order like np.add.at, at a tenth of its cost here
        lo = int(flat.min())
        acc = np.bincount(flat - lo, values)
        img = self.img.reshape(-1)
        img[lo:lo + len(acc)] += acc
        self.touched.reshape(-1)[flat] = True


def _add_points(canvas: _Canvas, xy: Array, electrons: Array, sigma: float) -> None:
    """Add pixel-integrated Gaussians at (N, 2) positions, all at once (no per-star loop)."""
    ok = np.isfinite(xy).all(axis=1) & (electrons > 0)
    xy, electrons = xy[ok], electrons[ok]
    if len(xy) == 0:
        return
    h, w = canvas.img.shape
    r = _psf_radius(sigma)
    size = 2 * r + 2
    k = np.sqrt(2.0) * sigma
    grid = np.arange(size + 1) - 0.5
    fx, fy = np.floor(xy[:, 0]), np.floor(xy[:, 1])
    x0, y0 = (fx - r).astype(np.intp), (fy - r).astype(np.intp)
    # exact pixel integrals of the Gaussian: pixel i covers [i − 0.5, i + 0.5]
    px = 0.5 * np.diff(erf((grid + (x0 - xy[:, 0])[:, None]) / k), axis=1)
    py = 0.5 * np.diff(erf((grid + (y0 - xy[:, 1])[:, None]) / k), axis=1)
    gx = x0[:, None] + np.arange(size)
    gy = y0[:, None] + np.arange(size)
    vx, vy = (gx >= 0) & (gx < w), (gy >= 0) & (gy < h)
    val = electrons[:, None, None] * py[:, :, None] * px[:, None, :]
    valid = vy[:, :, None] & vx[:, None, :]
    flat = gy[:, :, None] * w + gx[:, None, :]
    canvas.add(flat[valid], val[valid])


def _add_paths(canvas: _Canvas, xs: Array, ys: Array, electrons: Array, sigma: float) -> None:
    """Add streaks: (K, N) sub-step positions of N sources, each sub-step a pixel-integrated
    Gaussian of electrons/K. All sources at once: per source a box
    ``PYᵀ · diag(e/K) · PX`` (a batched matrix product over the sub-steps), where row k of
    PX/PY holds the sub-step's erf pixel integrals in a window around it."""
    keep = np.isfinite(xs).all(axis=0) & np.isfinite(ys).all(axis=0) & (electrons > 0)
    xs, ys, electrons = xs[:, keep].T, ys[:, keep].T, electrons[keep]  # (N, K)
    if len(electrons) == 0:
        return
    # bound the (n, K, box) work arrays to ~16 MB: long streaks go a few sources at a time
    n_sub = xs.shape[1]
    extent = max(np.ptp(xs, axis=1).max(), np.ptp(ys, axis=1).max()) + 2 * _psf_radius(sigma)
    chunk = max(1, int(2_000_000 // (n_sub * extent)))
    for i in range(0, len(electrons), chunk):
        sl = slice(i, i + chunk)
        _add_paths_chunk(canvas, xs[sl], ys[sl], electrons[sl], sigma)


def _add_paths_chunk(canvas: _Canvas, xs: Array, ys: Array, electrons: Array,
                     sigma: float) -> None:
    h, w = canvas.img.shape
    n, n_sub = xs.shape
    r = _psf_radius(sigma)
    size = 2 * r + 2
    k = np.sqrt(2.0) * sigma
    win = np.arange(size)
    grid = np.arange(size + 1) - 0.5

    def axis_rows(c: Array) -> tuple[Array, NDArray[np.intp]]:
        """(N, K, box) erf rows and the (N,) box origins along one axis."""
        fl = np.floor(c).astype(np.intp) - r           # window start per sub-step
        origin = fl.min(axis=1)
        box = int((fl.max(axis=1) - origin).max()) + size
        local = 0.5 * np.diff(erf((grid + (fl - c)[..., None]) / k), axis=-1)  # (N, K, S)
        rows = np.zeros((n, n_sub, box))
        col = (fl - origin[:, None])[..., None] + win
        rows[np.arange(n)[:, None, None], np.arange(n_sub)[None, :, None], col] = local
        return rows, origin

    px, x0 = axis_rows(xs)
    py, y0 = axis_rows(ys)
    py *= (electrons / n_sub)[:, None, None]
    boxes = np.matmul(py.transpose(0, 2, 1), px)  # (N, Hb, Wb)
    gx = x0[:, None] + np.arange(px.shape[2])
    gy = y0[:, None] + np.arange(py.shape[2])
    valid = ((gy >= 0) & (gy < h))[:, :, None] & ((gx >= 0) & (gx < w))[:, None, :]
    flat = gy[:, :, None] * w + gx[:, None, :]
    canvas.add(flat[valid], boxes[valid])


def _add_tether(canvas: _Canvas, t: Tether) -> None:
    """Line of density λ e⁻/px with a Gaussian cross-section, sampled at pixel centres:
    ``λ φ_σ(d) · [Φ((L − s)/σ) − Φ(−s/σ)]`` (d across, s along the segment of length L)."""
    h, w = canvas.img.shape
    a, b = np.asarray(t.start_xy, np.float64), np.asarray(t.end_xy, np.float64)
    length = float(np.hypot(*(b - a)))
    if length == 0 or t.electrons_per_px <= 0:
        return
    u = (b - a) / length
    pad = 5.0 * t.sigma_px
    x0 = max(int(np.floor(min(a[0], b[0]) - pad)), 0)
    x1 = min(int(np.ceil(max(a[0], b[0]) + pad)) + 1, w)
    y0 = max(int(np.floor(min(a[1], b[1]) - pad)), 0)
    y1 = min(int(np.ceil(max(a[1], b[1]) + pad)) + 1, h)
    if x0 >= x1 or y0 >= y1:
        return
    dx = np.arange(x0, x1) - a[0]
    dy = (np.arange(y0, y1) - a[1])[:, None]
    along = dx * u[0] + dy * u[1]
    across = -dx * u[1] + dy * u[0]
    s2 = np.sqrt(2.0) * t.sigma_px
    ends = 0.5 * (erf((length - along) / s2) + erf(along / s2))
    dens = t.electrons_per_px / (np.sqrt(2 * np.pi) * t.sigma_px)
    canvas.img[y0:y1, x0:x1] += dens * np.exp(-0.5 * (across / t.sigma_px) ** 2) * ends
    canvas.touched[y0:y1, x0:x1] = True


# --------------------------------------------------------------------------------------------
# Detector


def _hot_pixels(s: SensorModel, shape: tuple[int, int], rng: np.random.Generator) -> NDArray:
    if not s.hot_pixels:
        return np.empty(0, np.intp)
    g = rng if s.hot_pixel_seed is None else np.random.default_rng(s.hot_pixel_seed)
    return np.sort(g.choice(shape[0] * shape[1], size=s.hot_pixels, replace=False))


def _glow(it: Intensifier, shape: tuple[int, int], rng: np.random.Generator) -> Array:
    h, w = shape
    if it.glow_events <= 0:
        return np.zeros(shape)
    cx, cy = it.glow_center if it.glow_center is not None else rng.uniform(0.2, 0.8, 2)
    s = it.glow_sigma_frac * np.hypot(w, h)
    gx = np.exp(-0.5 * ((np.arange(w) - cx * (w - 1)) / s) ** 2)
    gy = np.exp(-0.5 * ((np.arange(h) - cy * (h - 1)) / s) ** 2)
    return it.glow_events * np.outer(gy, gx)


def _detect_electrons(
    s: SensorModel, sky: Array | float, canvas: _Canvas, rng: np.random.Generator
) -> NDArray:
    """Photon (or photo-event) noise on sky + sources: electrons at the detector. In the
    ``"gaussian"`` model the sky's shot noise is left to :func:`_to_adu`."""
    it = s.intensifier
    sources = canvas.img
    if it is not None:
        events = rng.poisson(sources + sky)
        out = np.zeros(events.shape, dtype=np.float32)
        hit = np.flatnonzero(events)  # a sum of n gamma(k) gains is gamma(n k)
        out.flat[hit] = rng.standard_gamma(events.flat[hit] * it.gain_shape,
                                           dtype=np.float32)
        out *= np.float32(it.gain_e / it.gain_shape)
        if it.bloom_sigma_px > 0:
            import cv2

            out = cv2.GaussianBlur(out, (0, 0), it.bloom_sigma_px,
                                   borderType=cv2.BORDER_REFLECT)
        return out
    if s.noise == "poisson":
        return rng.poisson(sources + sky).astype(np.float32)
    # gaussian: exact Poisson counts for the sources (sparse); the sky stays noiseless here
    idx = np.flatnonzero(canvas.touched)
    out = np.full(sources.shape, sky, dtype=np.float32)
    out.flat[idx] += rng.poisson(sources.flat[idx])
    return out


def _to_adu(s: SensorModel, electrons: NDArray, sky: Array | float,
            rng: np.random.Generator) -> NDArray:
    """Read noise (plus, for ``"gaussian"``, the sky's shot noise), gain, bias, full well,
    rounding to the output type. ``electrons`` (float32) is overwritten."""
    h, w = electrons.shape
    var = np.float32(s.read_noise_e) ** 2
    if s.noise == "gaussian" and s.intensifier is None:
        var = var + np.asarray(sky, dtype=np.float32)
    noise = rng.standard_normal((h, w), dtype=np.float32)
    noise *= np.sqrt(var)
    electrons += noise
    info = np.iinfo(s.dtype) if np.dtype(s.dtype).kind in "ui" else None
    # + 0.5 then truncation rounds half up, one pass cheaper than rint
    if s.gain_e_per_adu != 1.0:  # (× 1 is exact: skip the pass)
        electrons *= np.float32(1.0 / s.gain_e_per_adu)
    electrons += np.float32(s.bias_adu + (0.5 if info else 0.0))
    if info:
        top = min(s.full_well_adu, info.max)
        np.clip(electrons, 0.0, np.floor(top) + 0.5, out=electrons)
        return electrons.astype(s.dtype)
    np.clip(electrons, 0.0, s.full_well_adu, out=electrons)
    return electrons.astype(s.dtype)


def _expose(
    camera: Camera,
    s: SensorModel,
    rng: np.random.Generator,
    draw: Callable[[_Canvas], None],
) -> tuple[NDArray, NDArray[np.intp]]:
    """Common detector chain: sky (+ glow), sources drawn by ``draw(canvas)``, noise, hot
    pixels, read noise, ADU. Returns the image and the flat indices of the hot pixels."""
    shape = (camera.height, camera.width)
    sky: Array | float = float(s.background_e)
    if s.intensifier is not None:
        sky = s.background_e + _glow(s.intensifier, shape, rng)
    canvas = _Canvas(shape)
    draw(canvas)
    electrons = _detect_electrons(s, sky, canvas, rng)
    hot = _hot_pixels(s, shape, rng)
    if hot.size:
        electrons.flat[hot] += s.hot_pixel_e
    return _to_adu(s, electrons, sky, rng), hot


# --------------------------------------------------------------------------------------------
# Public renderers


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
    e = np.asarray(electrons, dtype=np.float64).reshape(-1)
    if len(e) != len(xy):
        raise ValueError(f"{len(xy)} positions but {len(e)} electron counts")
    img, _ = _expose(camera, s, rng, lambda src: _add_points(src, xy, e, s.psf_sigma_px))
    return img


def _sub_times(exposure_s: float, n: int) -> Array:
    """Mid-points of n equal sub-intervals of [−T/2, T/2]."""
    return (np.arange(n) + 0.5) / n * exposure_s - 0.5 * exposure_s


def render_frame(
    camera: Camera,
    q_cam_icrs: ArrayLike,
    vectors_icrs: ArrayLike,
    mag: ArrayLike,
    sensor: SensorModel | None = None,
    seed: int | None = 0,
    *,
    omega_cam_rad_s: ArrayLike | None = None,
    exposure_s: float = 0.0,
    planets: Sequence[Planet] = (),
    tethers: Sequence[Tether] = (),
) -> Frame:
    """Render catalogue stars (and false objects) seen at attitude ``q_cam_icrs``.

    Args:
        camera: the camera model (projection, size).
        q_cam_icrs: attitude at mid-exposure.
        vectors_icrs: (N, 3) unit star directions; mag: (N,) their magnitudes.
        sensor: detector model (default :class:`SensorModel`).
        seed: seed of the frame's noise generator.
        omega_cam_rad_s: camera angular rate w.r.t. ICRS in camera axes (``R_cam_body @
            omega_body``), constant over the exposure; None = no motion.
        exposure_s: exposure time over which motion smears the image (the brightness is
            ``sensor.zero_point_e`` per exposure regardless).
        planets: bright point sources at ICRS directions (:class:`Planet`).
        tethers: lines in the image (:class:`Tether`).
    """
    from adfusion.maths.rotations import exp_map, rotate, to_matrix

    s = sensor or SensorModel()
    rng = np.random.default_rng(seed)
    vec = np.asarray(vectors_icrs, dtype=np.float64).reshape(-1, 3)
    mags = np.asarray(mag, dtype=np.float64).reshape(-1)
    if len(vec) != len(mags):
        raise ValueError(f"{len(vec)} star vectors but {len(mags)} magnitudes")
    n_star = len(vec)
    if planets:
        vec = np.vstack([vec, [np.asarray(p.direction_icrs, np.float64) for p in planets]])
        mags = np.concatenate([mags, [p.mag for p in planets]])
    omega = np.zeros(3) if omega_cam_rad_s is None else np.asarray(omega_cam_rad_s, np.float64)
    if omega.shape != (3,) or not np.all(np.isfinite(omega)):
        raise ValueError("omega_cam_rad_s must be a finite 3-vector")
    if not (np.isfinite(exposure_s) and exposure_s >= 0):
        raise ValueError(f"exposure_s must be >= 0, got {exposure_s!r}")
    sweep = float(np.linalg.norm(omega)) * exposure_s  # rad turned during the exposure

    # stars that can touch the frame during the exposure: a cone around the boresight
    r_cam_icrs = to_matrix(q_cam_icrs)
    boresight = r_cam_icrs[2]
    half_diag = np.radians(camera.diagonal_fov_deg) / 2
    margin = (_psf_radius(s.psf_sigma_px) + 2) * camera.pixel_scale_rad + 0.5 * sweep
    near = np.flatnonzero(vec @ boresight > np.cos(min(half_diag + margin, np.pi)))
    v_mid = vec[near] @ r_cam_icrs.T
    xy_mid = np.full((len(near), 2), np.nan)
    front = v_mid[:, 2] > 0
    xy_mid[front] = camera.vectors_to_pixels(v_mid[front])
    electrons = magnitude_to_electrons(mags[near], s.zero_point_e)

    if sweep > 0:
        # sub-steps: the image of a star moves at most |ω|·|dx/dθ| px per rad; bound it by the
        # mid-exposure end-point displacement over the two halves (convex enough at these FOVs)
        ends = np.stack([rotate(exp_map(-omega * u), v_mid) for u in
                         (-0.5 * exposure_s, 0.5 * exposure_s)])
        xy_ends = np.full((2, len(near), 2), np.nan)
        ok = (ends[..., 2] > 0).all(axis=0) & front
        for i in range(2):
            xy_ends[i, ok] = camera.vectors_to_pixels(ends[i, ok])
        travel = np.nansum([np.hypot(*(xy_ends[i] - xy_mid).T) for i in range(2)], axis=0)
        step = s.psf_sigma_px
        n_sub = int(np.clip(np.ceil(np.max(travel, initial=0.0) / step), 1, 20_000))
    else:
        n_sub = 1

    def draw(canvas: _Canvas) -> None:
        if n_sub == 1:
            _add_points(canvas, xy_mid, electrons, s.psf_sigma_px)
        else:
            q_sub = exp_map(-np.outer(_sub_times(exposure_s, n_sub), omega))  # (K, 4)
            v_sub = np.einsum("kij,nj->kni", to_matrix(q_sub), v_mid)
            xy_sub = np.full((n_sub, len(near), 2), np.nan)
            vis = v_sub[..., 2] > 0
            xy_sub[vis] = camera.vectors_to_pixels(v_sub[vis])
            # only sources whose path comes near the frame
            near_frame = camera.in_frame(xy_sub.reshape(-1, 2),
                                         margin=-float(_psf_radius(s.psf_sigma_px)))
            use = near_frame.reshape(n_sub, -1).any(axis=0)
            _add_paths(canvas, xy_sub[:, use, 0], xy_sub[:, use, 1], electrons[use],
                       s.psf_sigma_px)
        for t in tethers:
            _add_tether(canvas, t)

    img, hot = _expose(camera, s, rng, draw)

    is_star = near < n_star
    inside = camera.in_frame(xy_mid) & is_star
    planet_xy = np.full((len(planets), 2), np.nan)
    if planets:
        pl = ~is_star & camera.in_frame(xy_mid)
        planet_xy[near[pl] - n_star] = xy_mid[pl]
    hot_xy = np.column_stack([hot % camera.width, hot // camera.width]).astype(np.intp)
    return Frame(img, xy_mid[inside], near[inside], planet_xy, hot_xy)


def render_sky(
    camera: Camera,
    q_cam_icrs: ArrayLike,
    vectors_icrs: ArrayLike,
    mag: ArrayLike,
    sensor: SensorModel | None = None,
    seed: int | None = 0,
    **kwargs: object,
) -> tuple[NDArray, NDArray[np.float64], NDArray[np.intp]]:
    """Render catalogue stars seen at attitude ``q_cam_icrs``.

    Returns the image, the true pixel positions of the stars inside the frame, and their
    catalogue indices (so tests can score detections against truth). Keyword arguments
    (motion, planets, tethers) are those of :func:`render_frame`.
    """
    fr = render_frame(camera, q_cam_icrs, vectors_icrs, mag, sensor, seed,
                      **kwargs)  # type: ignore[arg-type]
    return fr.image, fr.star_xy, fr.star_index
