"""Star detection: background, threshold, segmentation and centroids of a star-camera frame.

`detect` turns one grey image into a list of star centroids, brightest first:

1. a robust **local** background and noise map from blocks of ``background_block`` pixels (a
   subsample of each): the block median is the background; block outliers (a bright star
   filling a block) are replaced by the 3×3 median of the block grid; the noise is the
   lower-half spread (median − 15.87th percentile) of the pixels after subtracting the
   interpolated background, so slopes are not mistaken for noise; both are interpolated
   bicubically (``cv2.resize``). Vignetting, gradients and intensifier glow become background
   instead of detections;
2. pixels above ``background + sigma · noise`` (or above a fixed ``threshold``, Renken's mode);
3. Renken's image-quality check (too many bright pixels → ``ok=False``, no detections);
4. 8-connected components of the bright pixels;
5. per-blob filters: size, hot pixels (peak sharpness), streaks and tethers (elongation from
   intensity-weighted second moments), optional saturation; every rejected blob is kept in
   ``Detections.rejected`` with its reason;
6. centroids (intensity-weighted on background-subtracted values, or Renken's unweighted mean
   rounded to 0.1 px), flux, peak; sorted by flux, brightest first.

Only steps 1-2 and the labelling (OpenCV) touch every pixel; the measurements run on the
bright pixels alone (np.bincount over labels, no per-blob Python loops), which brings this
near the Rust extractor of tetra3rs: cheaper on 1024×768 frames and up, ~1.2–1.7× its CPU
time at 512², where numpy's per-call cost dominates (``benchmarks/bench_detect.py``,
docs/benchmarks.md).

Pixel coordinates follow the project convention: 0-based pixel centres, origin at the top-left
pixel, x to the right, y down, ``image[y, x]``.

Example:
    >>> import numpy as np
    >>> img = np.random.default_rng(0).normal(100.0, 2.0, (64, 80)).astype(np.float32)
    >>> yy, xx = np.mgrid[:64, :80]
    >>> img += 400.0 * np.exp(-((xx - 20.3) ** 2 + (yy - 30.6) ** 2) / 2.0)
    >>> det = detect(img)
    >>> len(det), det.xy.round(1).tolist()
    (1, [[20.3, 30.6]])
"""

from __future__ import annotations

import os
from typing import Any

import cv2
import numpy as np
from adfusion.starid.detection.background import (
    _FLOAT32_EXACT,
    _background,
    _block_layout,
    _Grid,
    _median,
    _threshold_mask,
)
from adfusion.starid.detection.detections import _CENTROIDS, Detections
from adfusion.starid.detection.image import _all_finite, _as_grey
from adfusion.starid.detection.measure import _label, _measure

from adfusion.plain import listed

__all__ = ["detect"]


def _check_params(
    sigma: float,
    min_area: int,
    max_area: int,
    max_elongation: float | None,
    background_block: int,
    centroid: str,
    max_bright_pixels: int | None,
    max_detections: int | None,
    saturation: float | None,
    threshold: float | None,
    max_sharpness: float | None,
) -> None:
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma must be a positive number, got {sigma!r}")
    if min_area < 1 or max_area < min_area:
        raise ValueError(f"need 1 <= min_area <= max_area, got {min_area!r}, {max_area!r}")
    if max_elongation is not None and not max_elongation >= 1:
        raise ValueError(f"max_elongation must be >= 1 or None, got {max_elongation!r}")
    if background_block < 4:
        raise ValueError(f"background_block must be >= 4 pixels, got {background_block!r}")
    if centroid not in _CENTROIDS:
        raise ValueError(f"centroid must be one of {listed(_CENTROIDS, None)}, got "
                         f"{centroid!r}")
    for name, v in (("max_bright_pixels", max_bright_pixels), ("max_detections", max_detections)):
        if v is not None and v < 0:
            raise ValueError(f"{name} must be >= 0 or None, got {v!r}")
    for name, v in (("saturation", saturation), ("threshold", threshold)):
        if v is not None and not np.isfinite(v):
            raise ValueError(f"{name} must be a finite number or None, got {v!r}")
    if max_sharpness is not None and not 0 < max_sharpness <= 1:
        raise ValueError(f"max_sharpness must be in (0, 1] or None, got {max_sharpness!r}")


# Fewer blobs than this never count as an unreliable threshold (small frames)
_MIN_BLOBS_UNRELIABLE = 500


def detect(
    image: np.ndarray | str | os.PathLike[str],
    camera: Any = None,
    *,
    sigma: float = 5.0,
    min_area: int = 2,
    max_area: int = 2000,
    max_elongation: float | None = 3.0,
    background_block: int = 32,
    centroid: str = "weighted",
    max_bright_pixels: int | None = None,
    max_detections: int | None = None,
    saturation: float | None = None,
    threshold: float | None = None,
    max_sharpness: float | None = 0.9,
    matched_filter: float | None = None,
    max_blob_density: float | None = 0.005,
    clutter_noise_factor: float | None = 1.3,
    max_diffuseness: float | None = 6.0,
) -> Detections:
    """Find the stars in a frame: centroids, flux, area, peak, brightest first.

    Args:
        image: 2-D array (uint8, uint16, int16, float32/64, ...; (H, W, 1) is accepted) or a
            path to an image file (16-bit TIFF, PNG, JPEG, ...; colour files become grey).
            NaN and ±inf pixels count as missing: they are left out of the background and never
            detected (a star touching them gets a biased centroid).
        camera: optional; only its ``width``/``height`` are checked against the image.
        sigma: detection threshold in units of the local noise above the local background.
        min_area, max_area: accepted blob sizes in pixels (8-connected, above threshold).
        max_elongation: reject blobs of >= 5 px whose major/minor axis ratio (intensity-
            weighted second moments) exceeds this (satellite trails, tethers); None = off.
        background_block: block size in pixels of the background/noise grid; choose it a few
            times larger than a star and smaller than the scale of the background's variation.
        centroid: "weighted" (intensity-weighted on background-subtracted values, including
            the ring of pixels just below threshold around the blob) or "unweighted" (Renken:
            mean of the above-threshold pixel coordinates, rounded to 0.1 px).
        max_bright_pixels: Renken's image-quality check (Cond. 5.1): more pixels above threshold
            than this → ``ok=False`` and no detections. None (default) disables it: with a
            local background a bright sky does not flood the threshold, so the check mainly
            serves the fixed-``threshold`` mode (Renken used 150).
        max_detections: keep only the brightest this many.
        saturation: pixel value at which the sensor saturates; blobs reaching it are rejected
            ("saturated": flux and centroid are unreliable). None (default) keeps them.
        threshold: a fixed absolute threshold instead of ``sigma``: no background is estimated
            or subtracted, flux and peak are raw grey values (Renken's segmentation); weighted
            centroids weigh each pixel by its excess over the threshold.
        max_sharpness: reject blobs whose peak sharpness ``(peak - mean of its 8 neighbours) /
            peak`` exceeds this: hot pixels and cosmic rays (≈1), not stars (≈0.3-0.85 even
            undersampled). None = off (for 1-pixel stars, e.g. binary images).
        matched_filter: the PSF's Gaussian σ in pixels to smooth the frame with before the
            background, noise and threshold (the matched filter for faint stars: a star of
            PSF σ ≈ 1 px gains ~2× in SNR over single pixels); centroids, flux and peak are
            still measured on the frame itself. None (default) = off.
        max_blob_density: more blobs above the ``sigma`` threshold than this per pixel
            (default 1 per 200 px, and more than 500) means the threshold sits in the
            noise, not on stars: ``ok=False`` with a reason naming the remedy, instead of
            thousands of "stars". None = off.
        clutter_noise_factor: detections on structured foreground — where the local noise
            exceeds this many times the frame's median noise and blobs crowd (a lit tree,
            a roof edge: structure, not sky) — are listed after all others, brightest
            first among themselves, so that the stars on clean sky lead the list the solver
            reads. None = flux order only.
        max_diffuseness: blobs whose effective area (flux / peak) exceeds this many times
            that of the frame's compact blobs (the lower quartile of the brightest 30) are
            listed after all others — lit foliage, a roof's texture, a comet's coma: far
            broader than the stars' PSF — unless their peak reaches 90 % of the frame's
            highest (a saturated star is flat-topped: its effective area grows with its
            flux). On the 21 shared real frames no unsaturated star exceeds 6.6× (the
            broadest are the brightest, their wings above the threshold); a lit tree's
            leaves among its brightest 30 reach 6–17×. None = off.

    Returns:
        `Detections` (``bright_pixels`` counts the pixels above threshold, Renken's
        ``number_hlp``).

    Raises:
        TypeError: the image is neither an array nor a path, or has a non-numeric dtype.
        ValueError: empty, not 2-D, colour array, no finite pixels, shape != camera, a bad
            parameter, or an unreadable file.
        FileNotFoundError: the path does not exist.

    Example:
        >>> img = np.zeros((20, 20), np.uint8)
        >>> img[5, 5:7] = img[12, 14] = 200
        >>> det = detect(img, threshold=100, min_area=1, max_sharpness=None,
        ...              centroid="unweighted")
        >>> det.xy.tolist(), det.flux.tolist()
        ([[5.5, 5.0], [14.0, 12.0]], [400.0, 200.0])
    """
    _check_params(
        sigma, min_area, max_area, max_elongation, background_block, centroid,
        max_bright_pixels, max_detections, saturation, threshold, max_sharpness,
    )
    if matched_filter is not None and not (np.isfinite(matched_filter) and
                                           0 < matched_filter <= 10):
        raise ValueError(f"matched_filter must be a PSF σ in (0, 10] px or None, got "
                         f"{matched_filter!r}")
    if max_blob_density is not None and not 0 < max_blob_density <= 1:
        raise ValueError(f"max_blob_density must be in (0, 1] or None, got {max_blob_density!r}")
    if clutter_noise_factor is not None and not clutter_noise_factor > 1:
        raise ValueError(f"clutter_noise_factor must be > 1 or None, got "
                         f"{clutter_noise_factor!r}")
    if max_diffuseness is not None and not max_diffuseness > 1:
        raise ValueError(f"max_diffuseness must be > 1 or None, got {max_diffuseness!r}")
    img = _as_grey(image)
    shape = (int(img.shape[0]), int(img.shape[1]))
    if camera is not None:
        cam_shape = (int(camera.height), int(camera.width))
        if cam_shape != shape:
            raise ValueError(
                f"image is {shape[1]}x{shape[0]} (width x height) but the camera is "
                f"{cam_shape[1]}x{cam_shape[0]}"
            )

    missing = None
    if img.dtype.kind == "f" and not _all_finite(img):
        missing = np.flatnonzero(~np.isfinite(img))
        if missing.size == img.size:
            raise ValueError("image has no finite pixels (all NaN or inf)")
        img = img.copy()  # never modify the caller's array
        img.flat[missing] = np.nan

    offset = 0.0
    if threshold is None and img.dtype == np.float64:
        # the maps are float32: measure relative to a typical pixel, so that a large offset
        # (1e12 + stars) keeps the float64 image's precision
        sub = img[:: max(1, shape[0] // 64), :: max(1, shape[1] // 64)]
        finite = sub[np.isfinite(sub)]
        offset = float(np.round(np.median(finite))) if finite.size else 0.0
        if abs(offset) >= _FLOAT32_EXACT:
            img = img - offset  # a whole number: integer-valued data stay on their lattice
        else:
            offset = 0.0

    bg: _Grid | None
    noise_model = "lower-half"
    noise_grid = None
    if threshold is None:
        work = img
        if matched_filter is not None:
            work = cv2.GaussianBlur(img.astype(np.float32) if img.dtype != np.float64 else img,
                                    (0, 0), matched_filter)
        try:
            bg, noise_grid, censored = _background(work, background_block)
        except ValueError:  # no block with enough finite pixels
            n_finite = img.size - (0 if missing is None else missing.size)
            return Detections.empty(
                shape, ok=False, noise_model=noise_model,
                reason=f"too few finite pixels ({n_finite / img.size:.2%} of the frame): no "
                       "background block has enough to measure the sky and its noise on")
        noise_model = "censored" if censored else "lower-half"
        if matched_filter is not None:
            noise_model += "+matched-filter"
        bg_grid = bg.values
        if missing is not None:  # missing pixels sit exactly on the background: never detected
            img.flat[missing] = bg.at(missing % shape[1], missing // shape[1])
            if work is not img:
                work.flat[missing] = img.flat[missing]
        mask = _threshold_mask(
            work, bg, bg_grid + sigma * noise_grid, sigma * float(noise_grid.min())
        )
        background_level = _median(bg_grid) + offset
        noise_sigma = _median(noise_grid)
    else:
        noise_model = "fixed-threshold"
        bg = None
        if missing is not None:
            img.flat[missing] = min(float(np.nanmin(img)), threshold)
        mask = np.greater(img, threshold)
        background_level, noise_sigma = 0.0, float("nan")

    idx = np.flatnonzero(mask)  # the bright pixels, row-major: everything below is sparse
    n_bright = int(idx.size)
    if max_bright_pixels is not None and n_bright > max_bright_pixels:
        return Detections.empty(
            shape,
            ok=False,
            reason=f"{n_bright} pixels above threshold > max_bright_pixels={max_bright_pixels} "
            "(over-exposed or defective image)",
            background_level=background_level,
            noise_sigma=noise_sigma,
            bright_pixels=n_bright,
            noise_model=noise_model,
        )
    if n_bright == 0:
        return Detections.empty(shape, background_level=background_level,
                                noise_sigma=noise_sigma, noise_model=noise_model)
    n_blobs, lab = _label(mask, idx)
    if (threshold is None and max_blob_density is not None
            and n_blobs > max(max_blob_density * img.size, _MIN_BLOBS_UNRELIABLE)):
        return Detections.empty(
            shape, ok=False,
            reason=f"unreliable threshold: {n_blobs} blobs above it (1 per "
                   f"{img.size / n_blobs:.0f} px), noise estimated {noise_sigma:.3g} "
                   f"({noise_model}); the threshold sits in the noise — raise sigma, or "
                   "pass threshold=",
            background_level=background_level, noise_sigma=noise_sigma,
            bright_pixels=n_bright, noise_model=noise_model)
    det = _measure(
        img, bg, mask, idx, n_blobs, lab, background_level, noise_sigma,
        pedestal=0.0 if threshold is None else float(threshold),
        min_area=min_area, max_area=max_area, max_elongation=max_elongation,
        centroid=centroid, max_detections=None, saturation=saturation,
        max_sharpness=max_sharpness, noise_model=noise_model,
    )
    if noise_grid is not None and clutter_noise_factor is not None and len(det) > 1:
        det = _clutter_last(det, noise_grid, background_block, clutter_noise_factor)
    if threshold is None and max_diffuseness is not None and len(det) >= _DIFFUSE_MIN_BLOBS:
        det = _diffuse_last(det, max_diffuseness)
    if max_detections is not None and len(det) > max_detections:
        det = _first(det, max_detections)
    return det


def _first(det: Detections, n: int | np.ndarray) -> Detections:
    """``det`` with its detections reduced to the first ``n`` (or reordered by an index)."""
    from dataclasses import replace

    k = slice(None, n) if isinstance(n, int) else n
    return replace(det, xy=det.xy[k], flux=det.flux[k], area=det.area[k], peak=det.peak[k])


def _clutter_last(det: Detections, noise: np.ndarray, block: int, factor: float,
                  ) -> Detections:
    """Detections on structured foreground after the others (order within each group
    kept). Foreground is where the local noise exceeds ``factor`` × the frame's median
    *and* blobs crowd: the 3×3 blocks around hold more than twice (and at least 3) the
    mean number of blobs (accepted or rejected) of the clean sky's blocks — a lit tree or a
    roof edge, not a glow (which raises the noise but not the number of things in it) nor
    a rich star field (which crowds on clean sky)."""
    gh, bh = _block_layout(det.shape[0], block)
    gw, bw = _block_layout(det.shape[1], block)

    def blocks(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        by = np.clip((xy[:, 1] + 0.5) // bh, 0, gh - 1).astype(np.intp)
        bx = np.clip((xy[:, 0] + 0.5) // bw, 0, gw - 1).astype(np.intp)
        return by, bx

    by, bx = blocks(det.xy)
    noisy_block = noise > factor * _median(noise)
    noisy = noisy_block[by, bx]
    if not noisy.any():
        return det
    every = det.xy
    if det.rejected:
        rx, ry = list(zip(*det.rejected, strict=True))[:2]  # transposed in C, not per blob
        every = np.concatenate([every, np.column_stack([rx, ry])])
    count = np.zeros((gh, gw), np.float32)
    np.add.at(count, blocks(every), 1.0)
    crowd = cv2.boxFilter(count, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    # the crowding of clean sky is the reference (the foreground may fill much of the frame)
    sky = count[~noisy_block] if (~noisy_block).any() else count
    mean = 9.0 * float(sky.mean())
    clutter = noisy & (crowd[by, bx] > max(2.0 * mean, 3.0))
    if not clutter.any() or clutter.all():
        return det
    return _first(det, np.concatenate([np.flatnonzero(~clutter), np.flatnonzero(clutter)]))


# the compact blobs' effective area: the lower quartile over the brightest this many
_DIFFUSE_REFERENCE_COUNT = 30


_DIFFUSE_MIN_BLOBS = 4


# a blob whose peak reaches this fraction of the frame's highest counts as saturated
_SATURATED_PEAK_FRACTION = 0.9


def _diffuse_last(det: Detections, factor: float) -> Detections:
    """Detections far broader than the frame's stars after the others (order within each
    group kept): effective area flux/peak above ``factor`` × the lower quartile of the
    brightest :data:`_DIFFUSE_REFERENCE_COUNT`, peak below 90 % of the frame's highest."""
    peak = np.maximum(det.peak, 1e-30)
    a_eff = det.flux / peak
    ref = _lower_quartile(a_eff[:_DIFFUSE_REFERENCE_COUNT])
    diffuse = (a_eff > factor * ref) & (det.peak < _SATURATED_PEAK_FRACTION * det.peak.max())
    if not diffuse.any() or diffuse.all():
        return det
    return _first(det, np.concatenate([np.flatnonzero(~diffuse), np.flatnonzero(diffuse)]))


def _lower_quartile(v: np.ndarray) -> float:
    """``np.percentile(v, 25)`` (linear method) of a few finite values, by the same
    arithmetic without its ~80 µs of call overhead (a twentieth of a 512² frame)."""
    if not np.isfinite(v).all():
        return float(np.percentile(v, 25))
    s = np.sort(v).tolist()
    pos = (len(s) - 1) * 0.25
    i = int(pos)
    a, b, t = s[i], s[min(i + 1, len(s) - 1)], pos - i
    d = b - a
    return b - d * (1 - t) if t >= 0.5 else a + d * t  # numpy's _lerp
