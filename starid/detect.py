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
import warnings
from dataclasses import dataclass, field
from itertools import repeat
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np

__all__ = ["Detections", "Rejection", "detect", "read_image"]

# Blobs smaller than this have too few pixels for meaningful second moments (a 2-4 px star is
# "elongated" by pixelation alone), so the elongation test skips them.
_MIN_AREA_FOR_SHAPE = 5
# Per-pixel variance of a uniformly lit pixel; regularises the moment ratio of 1-px-wide lines.
_PIXEL_VARIANCE = 1.0 / 12.0
# P(X < median - 1 sigma) for a Gaussian: median - P15.87 is one standard deviation, estimated
# from the lower half only, which stars (always positive outliers) hardly touch.
_P_MINUS_1SIGMA = 0.15865525393145707
_CENTROIDS = ("weighted", "unweighted")
# Kept in their own type (no conversion pass; thresholds compare as integers); other integer
# types become float.
_NATIVE_INT = (np.uint8, np.uint16)


class Rejection(NamedTuple):
    """One blob that was found above threshold and then rejected.

    Example:
        >>> r = Rejection(12.0, 40.0, 1, "hot_pixel")
        >>> r.reason, tuple(r)
        ('hot_pixel', (12.0, 40.0, 1, 'hot_pixel'))
    """

    x: float
    y: float
    area: int
    reason: str


@dataclass(frozen=True, eq=False, repr=False)
class Detections:
    """Stars found in one frame, brightest first.

    Attributes:
        xy: (N, 2) float64 centroids, pixel-centre convention (x right, y down).
        flux: (N,) background-subtracted summed intensity (raw sum with a fixed ``threshold``).
        area: (N,) number of pixels above threshold.
        peak: (N,) highest background-subtracted pixel value.
        ok: False when Renken's image-quality check failed (then N = 0).
        reason: why not ok; ``""`` when ok.
        rejected: one `Rejection` (x, y, area, reason) per rejected blob; the reason is the
            first that applies of "too_large", "hot_pixel", "too_small", "saturated",
            "elongated".
        background_level: median of the background map (0 with a fixed ``threshold``).
        noise_sigma: median of the noise map (NaN with a fixed ``threshold``).
        shape: image (height, width).
        bright_pixels: number of pixels above threshold (Renken's ``number_hlp``).
        noise_model: how the noise was estimated: ``"lower-half"`` (median − P15.87 of
            the background-subtracted pixels), ``"censored"`` (some blocks' dark tail is
            clipped at the black level: the noise from the quantiles above the clip),
            ``"fixed-threshold"``; ``"+matched-filter"`` when the frame was smoothed with
            the PSF before thresholding.

    Example:
        >>> d = Detections(np.array([[1.0, 2.0]]), np.array([50.0]), np.array([3]),
        ...                np.array([20.0]), True, "", [], 10.0, 1.0, (8, 8))
        >>> len(d), d.as_array().tolist()
        (1, [[1.0, 2.0, 50.0]])
        >>> d
        Detections(1 stars, ok, 0 rejected, background 10, noise 1, shape (8, 8))
    """

    xy: np.ndarray
    flux: np.ndarray
    area: np.ndarray
    peak: np.ndarray
    ok: bool
    reason: str
    rejected: list[Rejection]
    background_level: float
    noise_sigma: float
    shape: tuple[int, int]
    bright_pixels: int = field(default=0)
    noise_model: str = field(default="lower-half")

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    def __repr__(self) -> str:
        state = "ok" if self.ok else f"not ok: {self.reason}"
        return (f"Detections({len(self)} stars, {state}, {len(self.rejected)} rejected, "
                f"background {self.background_level:.4g}, noise {self.noise_sigma:.4g}, "
                f"shape {self.shape})")

    def as_array(self) -> np.ndarray:
        """(N, 3) array of x, y, flux — the input format of ``Solver.solve``.

        Example:
            >>> Detections.empty((4, 4)).as_array().shape
            (0, 3)
        """
        return np.column_stack([self.xy, self.flux]) if len(self) else np.empty((0, 3))

    @classmethod
    def empty(
        cls,
        shape: tuple[int, int],
        *,
        ok: bool = True,
        reason: str = "",
        rejected: list[Rejection] | None = None,
        background_level: float = float("nan"),
        noise_sigma: float = float("nan"),
        bright_pixels: int = 0,
        noise_model: str = "lower-half",
    ) -> Detections:
        """No detections (a failed quality check, or an empty sky).

        Example:
            >>> len(Detections.empty((480, 512), ok=False, reason="too many bright pixels"))
            0
        """
        return cls(
            np.empty((0, 2)),
            np.empty(0),
            np.empty(0, dtype=np.int64),
            np.empty(0),
            ok,
            reason,
            [] if rejected is None else rejected,
            background_level,
            noise_sigma,
            shape,
            bright_pixels,
            noise_model,
        )


# --------------------------------------------------------------------------------------------
# Input


def read_image(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an image file as a 2-D grey array, keeping its bit depth (8/16-bit, float TIFF).

    Colour files are converted to grey (OpenCV's BGR order is known for files). Raises
    FileNotFoundError for a missing file and ValueError when OpenCV cannot decode it.

    Example:
        >>> import tempfile
        >>> p = Path(tempfile.mkdtemp()) / "f.png"
        >>> _ = cv2.imwrite(str(p), np.full((4, 6), 1000, np.uint16))
        >>> a = read_image(p); a.shape, a.dtype.name, int(a[0, 0])
        ((4, 6), 'uint16', 1000)
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"image file not found: {str(p)!r}")
    if not p.is_file():
        raise ValueError(f"image path is not a file: {str(p)!r}")
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
    if img is None:
        raise ValueError(f"cannot read image file {str(p)!r}: OpenCV could not decode it")
    if img.ndim == 3:
        codes = {3: cv2.COLOR_BGR2GRAY, 4: cv2.COLOR_BGRA2GRAY}
        if img.shape[2] == 1:
            img = img[:, :, 0]
        elif img.shape[2] in codes:
            img = cv2.cvtColor(img, codes[img.shape[2]])
        else:
            raise ValueError(f"image file {str(p)!r} has {img.shape[2]} channels")
    return img


def _as_grey(image: Any) -> np.ndarray:
    """Validate an array (or read a file) and return a contiguous 2-D array to detect on.

    uint8/uint16 and float32/float64 pass through; other real dtypes become float32 (float64
    for 32/64-bit integers, whose values float32 cannot hold exactly).
    """
    if isinstance(image, (str, os.PathLike)):
        img = read_image(image)
    elif isinstance(image, np.ndarray):
        img = image
    else:
        raise TypeError(
            f"image must be a numpy array or a file path, not {type(image).__name__}"
        )
    if img.size == 0:
        raise ValueError(f"image is empty (shape {img.shape})")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] in (3, 4):
        # An array carries no channel order (RGB from PIL/matplotlib, BGR from OpenCV), so a
        # silent conversion could weight the channels wrongly; files are converted instead.
        raise ValueError(
            f"image is a {img.shape[2]}-channel colour array {img.shape}; pass a 2-D grey "
            "image, e.g. cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)"
        )
    if img.ndim != 2:
        raise ValueError(f"image must be 2-D (height, width), got ndim={img.ndim}, {img.shape}")
    kind = img.dtype.kind
    if kind == "b":
        raise TypeError("image has dtype bool; convert it, e.g. img.astype(np.uint8)")
    if kind not in "uif":
        raise TypeError(f"image dtype {img.dtype} is not a real number type (int or float)")
    if not img.dtype.isnative:  # FITS data are big-endian; OpenCV needs native byte order
        img = img.astype(img.dtype.newbyteorder("="))
    if img.dtype.type in _NATIVE_INT or img.dtype.type in (np.float32, np.float64):
        pass
    elif kind in "ui" and img.dtype.itemsize >= 4:
        img = img.astype(np.float64)
    else:
        img = img.astype(np.float32)
    return np.ascontiguousarray(img)


def _all_finite(img: np.ndarray) -> bool:
    """One cheap reduction instead of a full isfinite mask: the sum is finite iff every pixel
    is (barring float64 overflow, which only sends the caller down the careful path)."""
    with np.errstate(invalid="ignore", over="ignore"):
        return bool(np.isfinite(img.sum(dtype=np.float64)))


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
        raise ValueError(f"centroid must be one of {_CENTROIDS}, got {centroid!r}")
    for name, v in (("max_bright_pixels", max_bright_pixels), ("max_detections", max_detections)):
        if v is not None and v < 0:
            raise ValueError(f"{name} must be >= 0 or None, got {v!r}")
    for name, v in (("saturation", saturation), ("threshold", threshold)):
        if v is not None and not np.isfinite(v):
            raise ValueError(f"{name} must be a finite number or None, got {v!r}")
    if max_sharpness is not None and not 0 < max_sharpness <= 1:
        raise ValueError(f"max_sharpness must be in (0, 1] or None, got {max_sharpness!r}")


# --------------------------------------------------------------------------------------------
# Background and noise


def _block_layout(n: int, block: int) -> tuple[int, int]:
    """Number of blocks along an axis of n pixels, and their size; the last ``n % count``
    pixels are left over and take the values of the last block."""
    count = max(1, round(n / block))
    return count, n // count


# The smooth maps are built bicubically on a grid of _COARSE×_COARSE-pixel cells, then
# bilinearly to full size: the cubic carries the curvature between block centres, the final
# linear step over 4 px adds < 1 % of the cubic's error and is 5× cheaper than a full cubic.
_COARSE = 4


class _Grid:
    """A block grid (one value per block) and its smooth extension to every pixel.

    Bicubic rather than bilinear between block centres: the interpolation error on a curved
    background (a glow's peak) is what a threshold sees; with 32-px blocks a bilinear map
    sagged by ~2.6 sigma on a 100-sigma glow of 70 px radius and let noise through.
    Block centres sit at block centres (``cv2.resize`` conventions); pixels past the last
    whole block take the values of the last row/column.
    """

    def __init__(self, values: np.ndarray, shape: tuple[int, int], block: int) -> None:
        self.values = values.astype(np.float32)
        self.shape = shape
        gh, bh = _block_layout(shape[0], block)
        gw, bw = _block_layout(shape[1], block)
        self.covered = (gh * bh, gw * bw)
        self.coarse_shape = (-(-gh * bh // _COARSE), -(-gw * bw // _COARSE))
        self.coarse = self._coarse(self.values)
        self._c64 = self.coarse.astype(np.float64)
        self._tables: tuple[tuple[np.ndarray, ...], ...] | None = None

    def _coarse(self, v: np.ndarray) -> np.ndarray:
        ch, cw = self.coarse_shape
        return cv2.resize(v, (cw, ch), interpolation=cv2.INTER_CUBIC)

    def full(self, values: np.ndarray | None = None, dtype: Any = np.float32) -> np.ndarray:
        """The grid (or another grid of the same layout) as a full-size map of ``dtype``;
        integer maps hold the floor of the smooth map at the coarse nodes (within 1 level)."""
        c = self.coarse if values is None else self._coarse(values.astype(np.float32))
        if np.dtype(dtype).kind in "ui":
            info = np.iinfo(dtype)
            c = np.clip(np.floor(c), info.min, info.max).astype(dtype)
        (h, w), (ch, cw) = self.shape, self.covered
        if (ch, cw) == (h, w):
            return cv2.resize(c, (cw, ch), interpolation=cv2.INTER_LINEAR)
        # resized into the covered part of the full map, the leftover rows and columns
        # replicated (as cv2.copyMakeBorder would, without copying the whole map again)
        out = np.empty((h, w), c.dtype)
        part = cv2.resize(c, (cw, ch), dst=out[:ch, :cw], interpolation=cv2.INTER_LINEAR)
        if not np.shares_memory(part, out):  # a binding that would not write in place
            out[:ch, :cw] = part
        out[:ch, cw:] = out[:ch, cw - 1: cw]
        out[ch:] = out[ch - 1]
        return out

    def at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Values of the float map at integer pixels (x, y), without building the full map."""
        if self._tables is None:  # per-column and per-row weights, once per frame
            cw = self.coarse_shape[1]
            tx, x0, x1 = self._linear(np.arange(self.shape[1]), cw, self.covered[1])
            ty, y0, y1 = self._linear(np.arange(self.shape[0]), self.coarse_shape[0],
                                      self.covered[0])
            self._tables = ((tx, x0, x1), (ty, y0 * cw, y1 * cw))  # rows as flat offsets
        (tx, x0, x1), (ty, r0, r1) = self._tables
        # 1-D takes on the flat coarse map: ~3× cheaper than 2-D fancy indexing
        fx, i0, i1 = tx.take(x), x0.take(x), x1.take(x)
        r0, r1 = r0.take(y), r1.take(y)
        c = self._c64.ravel()
        c00, c01, c10, c11 = c.take(r0 + i0), c.take(r0 + i1), c.take(r1 + i0), c.take(r1 + i1)
        top = c00 + (c01 - c00) * fx
        bottom = c10 + (c11 - c10) * fx
        return top + (bottom - top) * ty.take(y)

    @staticmethod
    def _linear(p: np.ndarray, n_src: int, n_dst: int) -> tuple[np.ndarray, ...]:
        """cv2.resize INTER_LINEAR weight and source indices along one axis."""
        f = (np.minimum(p, n_dst - 1) + 0.5) * (n_src / n_dst) - 0.5
        i0 = np.floor(f).astype(np.intp)
        t = np.where((i0 < 0) | (i0 >= n_src - 1), 0.0, f - i0)
        i0 = np.clip(i0, 0, n_src - 1)
        return t, i0, np.minimum(i0 + 1, n_src - 1)


def _quantiles(
    samples: np.ndarray, step: float, interpolate_lo: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Row-wise P15.87 and median of (blocks, samples). NaN-aware. Sorts ``samples`` in place
    (callers pass a scratch copy: large temporaries cost page faults, measurably).

    Data on a lattice of ``step`` grey levels (integers; 12-bit data stored as multiples of
    16) are interpolated within the level the quantile falls on, else an 8-bit noise estimate
    is quantised to whole levels; ``step=0`` for continuous data.
    """
    n = samples.shape[1]
    if samples.dtype.kind == "f" and np.isnan(samples).any():
        with warnings.catch_warnings():  # all-NaN blocks come out NaN; the caller fills them
            warnings.simplefilter("ignore", RuntimeWarning)
            lo, med = np.nanquantile(samples, [_P_MINUS_1SIGMA, 0.5], axis=1)
        return lo, med
    k_med = (n - 1) // 2
    k_lo = min(round(_P_MINUS_1SIGMA * (n - 1)), max(k_med - 1, 0))
    if samples.dtype.kind in "ui" and samples.size:
        first, last = int(samples.min()), int(samples.max())
        if _SIMD_SORT16 and last - first <= _SORT16_MAX_RANGE:
            return _quantiles_by_sort16(samples, first, k_lo, k_med, step, interpolate_lo)
        if last - first < _HIST_MAX_LEVELS:
            return _quantiles_by_clipped_histogram(samples, first, last, k_lo, k_med, step,
                                                   interpolate_lo)
    # A full row sort: numpy's SIMD sorts beat even one np.partition here (and a multi-kth
    # partition by ~10×).
    samples.sort(axis=1)
    med = samples[:, k_med].astype(np.float64)
    lo = samples[:, k_lo].astype(np.float64)
    if step:
        med = _interpolated_quantile(samples, med, k_med, step)
        if interpolate_lo:
            lo = _interpolated_quantile(samples, lo, k_lo, step)
    return lo, med


def _has_simd_sort16() -> bool:
    """Whether numpy sorts 16-bit integers with its AVX-512 (Ice Lake level) SIMD sort."""
    try:
        from numpy._core._multiarray_umath import __cpu_features__
    except ImportError:  # a numpy without the table: assume the plain sort
        return False
    return bool(__cpu_features__.get("AVX512_ICL"))


# With numpy's SIMD 16-bit sort, integer samples spanning at most this many levels are
# shifted into uint16 and sorted: 2040 blocks × 256 samples sort in ~0.3 ms against ~1.5 ms
# for the histogram (AMD EPYC, numpy 2.4); without it a 16-bit sort is ~50× slower and the
# histogram below is the fast path.
_SIMD_SORT16 = _has_simd_sort16()
_SORT16_MAX_RANGE = 65535


def _within_level(value, below, equal, n: int, k: int, step):
    """The k-th of n samples interpolated inside its quantisation level of width ``step``
    (``below`` samples under the level, ``equal`` in it), as the sort and the histogram
    paths both need it."""
    m = n
    if n >= 128:  # as _interpolated_quantile: every other sorted sample
        m = (n + 1) // 2
        below_h = (below + 1) // 2
        equal, below = (below + equal + 1) // 2 - below_h, below_h
    rank = (k + 0.5) / n * m
    return value - 0.5 * step + step * (rank - below) / np.maximum(equal, 1)


def _quantiles_by_sort16(
    samples: np.ndarray, first: int, k_lo: int, k_med: int, step: float, interpolate_lo: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_quantiles` of integer data spanning at most 65535 levels from ``first``:
    the same order statistics and in-level interpolation, sorted as uint16 after the shift
    (wrap-around subtraction is exact modulo 2¹⁶, and the differences fit). The counts of
    samples below and at a level come from binary searches in the sorted rows (made one
    sorted array by a row offset), with the every-other-sample count of
    :func:`_interpolated_quantile` as in :func:`_quantiles_by_histogram`."""
    s = np.subtract(samples, samples.dtype.type(first), dtype=np.uint16, casting="unsafe")
    s.sort(axis=1)
    rows, n = s.shape
    if step:
        wide = np.int32 if rows < 2**15 else np.int64
        offset = np.arange(rows, dtype=wide) << 16
        keys = (s + offset[:, None]).ravel()  # ascending: row by row, each row sorted
        start = np.arange(rows, dtype=np.intp) * n
    out = []
    for k, interpolate in ((k_lo, interpolate_lo), (k_med, True)):
        v = s[:, k]
        value = v.astype(np.float64) + first
        if step and interpolate:
            key = offset + v
            below = np.searchsorted(keys, key, "left") - start
            equal = np.searchsorted(keys, key, "right") - start - below
            value = _within_level(value, below, equal, n, k, step)
        out.append(value)
    return out[0], out[1]


# Without the SIMD 16-bit sort, integer data spanning fewer grey levels than this take the
# histogram path (8-bit video, residuals of it): a counting pass instead of a sort, ~8×
# faster than numpy's plain sort for 240 blocks × 256.
_HIST_MAX_LEVELS = 1024


# A histogram spanning more levels than this is first tried on the samples clipped to the
# levels where nearly all of them lie (stars and dark pixels stretch the range 5–10×)
_HIST_CLIP_MIN_LEVELS = 64
_HIST_CLIP_SUBSAMPLE = 37  # every this-many-th sample locates that range


def _quantiles_by_clipped_histogram(
    samples: np.ndarray, first: int, last: int, k_lo: int, k_med: int, step: float,
    interpolate_lo: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_quantiles_by_histogram` over ``first..last``, exactly, on fewer levels:
    clipping the samples to [a, b] changes no count of samples ≤ v for a ≤ v < b, so an
    order statistic found strictly inside (a, b) is the unclipped one; the rows whose
    statistic lands on a clipped end are recomputed over the full range."""
    levels = last - first + 1
    if levels > _HIST_CLIP_MIN_LEVELS:
        sub = samples.ravel()[:: _HIST_CLIP_SUBSAMPLE]
        n_sub = sub.size
        i_lo, i_hi = int(0.002 * (n_sub - 1)), int(0.998 * (n_sub - 1))
        part = np.partition(sub, (i_lo, i_hi))
        margin = 2 * max(int(step), 1)
        a = max(int(part[i_lo]) - margin, first)
        b = min(int(part[i_hi]) + margin, last)
        if 2 * (b - a + 1) < levels:
            clipped = np.clip(samples, a, b)
            lo, med, at_end = _quantiles_by_histogram(clipped, a, b - a + 1, k_lo, k_med, step,
                                                      interpolate_lo, ends=True)
            if at_end.any():
                rows = np.flatnonzero(at_end)
                lo[rows], med[rows] = _quantiles_by_histogram(
                    samples[rows], first, levels, k_lo, k_med, step, interpolate_lo)
            return lo, med
    return _quantiles_by_histogram(samples, first, levels, k_lo, k_med, step, interpolate_lo)


def _quantiles_by_histogram(
    samples: np.ndarray, first: int, levels: int, k_lo: int, k_med: int, step: float,
    interpolate_lo: bool, ends: bool = False,
) -> tuple[np.ndarray, ...]:
    """:func:`_quantiles` for integer data on ``levels`` grey levels from ``first``, from one
    row-wise histogram; gives exactly what the sort gives, including the every-other-sample
    count of :func:`_interpolated_quantile` (the even ranks of a sorted row below a value v
    number ⌈below/2⌉)."""
    rows, n = samples.shape
    idx = samples.astype(np.int32)
    idx += (np.arange(rows, dtype=np.int32) * levels - first)[:, None]
    hist = np.bincount(idx.ravel(), minlength=rows * levels).reshape(rows, levels)
    cum = hist.cumsum(axis=1)  # samples ≤ level
    r = np.arange(rows)

    at_end = np.zeros(rows, bool)

    def order_stat(k: int, interpolate: bool) -> np.ndarray:
        b = np.count_nonzero(cum <= k, axis=1)  # the level holding the k-th smallest
        at_end[(b == 0) | (b == levels - 1)] = True
        value = (b + first).astype(np.float64)
        if not (step and interpolate):
            return value
        equal = hist[r, b]
        below = cum[r, b] - equal
        return _within_level(value, below, equal, n, k, step)

    lo, med = order_stat(k_lo, interpolate_lo), order_stat(k_med, True)
    return (lo, med, at_end) if ends else (lo, med)


def _interpolated_quantile(
    samples: np.ndarray, value: np.ndarray, k: int, step: float
) -> np.ndarray:
    """The k-th order statistic of lattice data as if each level v were spread uniformly over
    [v - step/2, v + step/2] (the order of samples within a row does not matter)."""
    n = samples.shape[1]
    if n >= 128:  # every other sample locates the quantile within its level well enough
        samples = samples[:, ::2]
    v = value.astype(samples.dtype)[:, None]
    below = np.count_nonzero(samples < v, axis=1)
    equal = np.count_nonzero(samples == v, axis=1)
    rank = (k + 0.5) / n * samples.shape[1]
    return value - 0.5 * step + step * (rank - below) / np.maximum(equal, 1)


def _median(v: np.ndarray) -> float:
    """``float(np.median(v))`` by the same arithmetic (the mean of the two middle values in
    the array's float type, or in float64 for integers; NaN if any is NaN), without its
    ~20 µs of call overhead — it is called six times per frame on small grids."""
    a = v.ravel()
    n = a.size
    if n == 0 or (a.dtype.kind == "f" and np.isnan(a).any()):
        return float("nan")
    k = n // 2
    if n % 2:
        return float(np.partition(a, k)[k])
    part = np.partition(a, (k - 1, k))
    if a.dtype.kind == "f":
        return float((part[k - 1] + part[k]) / 2)
    return (float(part[k - 1]) + float(part[k])) / 2


def _grey_step(samples: np.ndarray, integer_dtype: bool) -> int:
    """Grey-level step of the data (1 for plain integers, 16 for 12-bit data stored in 16
    bits), or 0 for continuous data. Float images holding whole numbers count as integer
    data, so that the same values give the same result in any dtype."""
    # The darker half of a few blocks' samples: saturated pixels (off the lattice) never are.
    few = samples[:4].ravel()
    few = few[few <= _median(few)]
    if not integer_dtype:
        if not (np.isfinite(few).all() and np.array_equal(few, np.round(few))):
            return 0
        if not np.array_equal(samples, np.round(samples)):  # all of them, then
            return 0
    few = few.astype(np.int64)
    step = int(np.gcd.reduce(few - few.min()))
    if integer_dtype:
        return step or 1
    return step  # 0 for a flat float patch: it says nothing about the step


# A block whose samples are more often than this exactly at the frame's lowest value has its
# dark tail clipped (a black level, a dark-subtracted PNG): P15.87 is then the clip, not the
# noise, and the noise comes from quantiles above the clip (:func:`_censored_noise`).
_CENSORED_FRACTION = 0.08
# float32 holds whole numbers exactly up to here; a float64 frame offset beyond it is
# measured relative to its median
_FLOAT32_EXACT = 2.0**24
# Fewer blobs than this never count as an unreliable threshold (small frames)
_MIN_BLOBS_UNRELIABLE = 500
# Blocks with fewer finite samples than this fraction say nothing reliable about the noise
# (a mostly-NaN frame): they are filled from the others, or the frame is not ok.
_MIN_FINITE_FRACTION = 0.5


def _background(img: np.ndarray, block: int) -> tuple[_Grid, np.ndarray, bool]:
    """Background (block medians, as a smooth `_Grid`) and noise (grid of median - P15.87 of
    the background-subtracted pixels, float32 (blocks_y, blocks_x)), from a subsample; and
    whether the censored-noise estimate was used for some blocks.

    Two passes: the medians give the background; the noise is then measured on the residual
    after subtracting the interpolated background, so that a slope across a block (vignetting,
    a glow's flank) does not pass for noise — a 50-sigma glow of 70 px radius otherwise
    inflated the noise 4× on its flanks and lost a tenth of the 8-sigma stars.
    Blocks whose dark tail is clipped (more than 8 % of samples at the frame's minimum) take
    mean and noise from the quantiles above the clip instead (:func:`_censored_noise`).
    """
    h, w = img.shape
    gh, bh = _block_layout(h, block)
    gw, bw = _block_layout(w, block)
    # ~16×16 samples per block: the median of 256 samples is good to ~0.08 sigma, and the
    # subsample keeps the statistics cheap (a quarter of the pixels for 32-px blocks).
    # (rounded: a 31-px block — 1080 rows in 34 blocks — took all 31×31 samples at ``//``,
    # four times the work, on six of the 21 shared real frames)
    step = max(1, round(min(bh, bw) / 16))
    view = img[: gh * bh, : gw * bw].reshape(gh, bh, gw, bw)[:, ::step, :, ::step]
    _, nr, _, nc = view.shape
    by_block = view.transpose(0, 2, 1, 3)  # (gh, gw, nr, nc): one row of samples per block

    samples = by_block.reshape(gh * gw, nr * nc)  # a copy: the view is strided
    q = _grey_step(samples, integer_dtype=img.dtype.kind in "ui")
    sparse = None
    if samples.dtype.kind == "f":
        finite = np.count_nonzero(np.isfinite(samples), axis=1)
        if finite.min() < _MIN_FINITE_FRACTION * samples.shape[1]:
            sparse = finite < _MIN_FINITE_FRACTION * samples.shape[1]
    lowest = np.nanmin(samples)
    # a row sum of the bool as uint8 into uint16 (rows hold ~256 samples) is ~3× cheaper
    # than np.count_nonzero(axis=1)
    at_floor = (samples == lowest).view(np.uint8).sum(
        axis=1, dtype=np.uint16 if samples.shape[1] < 2**16 else np.intp)
    censored = at_floor > _CENSORED_FRACTION * samples.shape[1]
    if sparse is not None:
        censored &= ~sparse
    cens_mu = cens_sigma = None
    if censored.any():
        cens_mu, cens_sigma = _censored_noise(samples[censored], at_floor[censored], q)
    lo, med = _quantiles(samples, q, interpolate_lo=False)
    if cens_mu is not None:
        med[censored], lo[censored] = cens_mu, cens_mu - cens_sigma
    if sparse is not None:
        med[sparse] = lo[sparse] = np.nan
    bg, noise = _clean_grid(med.reshape(gh, gw), (med - lo).reshape(gh, gw))
    grid = _Grid(bg, (h, w), block)

    # Pass 2: noise of the residual. The model on the sample lattice comes from the grid's
    # coarse map (good to a fraction of a pixel's slope); one fused pass subtracts it, in
    # int32 for integer data (exact; sorts faster than float).
    model = cv2.resize(grid.coarse, (gw * nc, gh * nr), interpolation=cv2.INTER_LINEAR)
    if q:  # subtract whole grey levels: the residual stays on the data's lattice
        model *= 1.0 / q
        np.rint(model, out=model)
        model *= q
    resid = np.empty((gh * gw, nr * nc), np.int32 if img.dtype.kind in "ui" else np.float32)
    np.subtract(by_block, model.reshape(gh, nr, gw, nc).transpose(0, 2, 1, 3),
                out=resid.reshape(gh, gw, nr, nc), casting="unsafe")
    lo_r, med_r = _quantiles(resid, q)
    noise2 = med_r - lo_r
    if cens_sigma is not None:  # the clip is not a level of the residual: keep pass 1's
        noise2[censored] = cens_sigma
    if sparse is not None:
        noise2[sparse] = np.nan
    noise2 = noise2.reshape(gh, gw)
    noise2 = np.where(np.isfinite(noise2), noise2, noise).astype(np.float32)
    if min(noise2.shape) >= 3:
        noise2 = cv2.medianBlur(noise2, 3)  # the noise varies slowly; damp estimation scatter
    floor = max(0.5 * q, 0.25 * _median(noise2))
    return grid, np.maximum(noise2, floor), bool(censored.any())


def _censored_noise(samples: np.ndarray, at_floor: np.ndarray, step: float,
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Mean and σ per row of samples whose lower tail is clipped (``at_floor`` of them at
    the clip): a Gaussian's quantiles above the clip, ``Q(p) = μ + σ Φ⁻¹(p)``, at
    p_a = max(0.5, clipped fraction + 0.05) and p_b = p_a + 0.3 (at most 0.95) — the
    upper tail is where the stars are, so no higher than needed. Lattice data are
    interpolated within their levels (as :func:`_quantiles`)."""
    from scipy.special import ndtri

    s = np.sort(samples.astype(np.float64), axis=1)
    rows, n = s.shape
    f0 = at_floor / n
    p_a = np.clip(np.maximum(0.5, f0 + 0.05), None, 0.9)
    p_b = np.minimum(p_a + 0.3, 0.95)
    r = np.arange(rows)

    def quantile(p: np.ndarray) -> np.ndarray:
        k = np.clip(np.round(p * (n - 1)).astype(np.intp), 0, n - 1)
        v = s[r, k]
        if not step:
            return v
        below = np.count_nonzero(s < v[:, None], axis=1)
        equal = np.count_nonzero(s == v[:, None], axis=1)
        return v - 0.5 * step + step * ((k + 0.5) - below) / np.maximum(equal, 1)

    qa, qb = quantile(p_a), quantile(p_b)
    za, zb = ndtri(p_a), ndtri(p_b)
    sigma = np.maximum((qb - qa) / (zb - za), 0.0)
    return qa - sigma * za, sigma


def _clean_grid(bg: np.ndarray, noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fill missing (all-NaN) blocks and replace star-dominated ones; float32 grids."""
    bg = bg.astype(np.float32)
    noise = noise.astype(np.float32)
    missing = ~np.isfinite(bg)
    if missing.all():
        raise ValueError("image has no finite pixels (all NaN or inf)")
    if missing.any():
        bg = np.where(missing, np.median(bg[~missing]), bg).astype(np.float32)
        noise = np.where(missing, np.median(noise[~missing]), noise).astype(np.float32)
    if min(bg.shape) >= 3:
        # A block is an outlier (a bright star or its halo fills it) when it stands above the
        # 3×3 median by more than 3× the spread of its 8 neighbours: a smooth glow peak is only
        # about as high above its neighbours as they differ among themselves; a star block is
        # not. (An unconditional 3×3 median would flatten a glow peak by ~13 % of its height.)
        ring = np.ones((3, 3), np.uint8)
        ring[1, 1] = 0
        spread = cv2.dilate(bg, ring) - cv2.erode(bg, ring)
        med = cv2.medianBlur(bg, 3)
        outlier = bg - med > 3.0 * np.maximum(spread, noise)
        if outlier.any():
            bg = np.where(outlier, med, bg)
            noise = np.where(outlier, cv2.medianBlur(noise, 3), noise)
    return bg, noise


def _threshold_mask(img: np.ndarray, grid: _Grid, thr: np.ndarray, min_step: float) -> np.ndarray:
    """Boolean mask of pixels strictly above the smooth threshold map of grid ``thr``."""
    if img.dtype.type in _NATIVE_INT and min_step >= 20:
        # Compare in the image's own integer type: half the memory of a float32 map and no
        # conversion pass. Rounding moves the threshold by <= 1 grey level, i.e. <= 5 % of
        # its height above the background (hence min_step >= 20 levels).
        return np.greater(img, grid.full(thr, img.dtype))
    return np.greater(img, grid.full(thr))


# --------------------------------------------------------------------------------------------
# Detection


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


def _label(mask: np.ndarray, idx: np.ndarray) -> tuple[int, np.ndarray]:
    """8-connected components of the bright pixels: (count, 0-based label of each idx),
    numbered in the order of each component's first pixel in ``idx`` (row-major).

    OpenCV labels the whole frame in ~0.25 ms (512×480), half the time of linking the ~2000
    bright pixels of a star field as a sparse graph; but it numbers components in its own
    scan order (two rows at a time, stripes when threaded), and the ring centroid breaks
    ties between blobs by label, so the labels are renumbered here.
    """
    n, labels = cv2.connectedComponents(mask.view(np.uint8), connectivity=8, ltype=cv2.CV_32S)
    lab = labels.ravel()[idx] - 1
    first = np.full(n - 1, idx.size, np.intp)  # position in idx of each label's first pixel
    np.minimum.at(first, lab, np.arange(idx.size))
    rank = np.empty(n - 1, np.intp)
    rank[np.argsort(first)] = np.arange(n - 1)
    return n - 1, rank[lab]


def _measure(
    img: np.ndarray,
    bg: _Grid | None,
    mask: np.ndarray,
    idx: np.ndarray,
    n: int,
    lab: np.ndarray,
    background_level: float,
    noise_sigma: float,
    *,
    pedestal: float,
    min_area: int,
    max_area: int,
    max_elongation: float | None,
    centroid: str,
    max_detections: int | None,
    saturation: float | None,
    max_sharpness: float | None,
    noise_model: str = "lower-half",
) -> Detections:
    """Measure, filter and sort the n blobs (bright pixels idx of ``mask``, labels lab in
    0..n-1).

    Centroid and moment weights are the values above ``pedestal``: the background (0 after
    subtraction), or a fixed threshold, for want of a background — then the sky level does not
    drag centroids to the blob's middle, and a binary image gets plain means.
    """
    shape = (int(img.shape[0]), int(img.shape[1]))
    ys, xs = np.divmod(idx, shape[1])
    raw = img.ravel()[idx].astype(np.float64)
    val = raw - bg.at(xs, ys) if bg is not None else raw

    area = np.bincount(lab, minlength=n)
    # Peak pixel of each blob (of equal maxima, the last in scan order).
    peak = np.full(n, -np.inf)
    np.maximum.at(peak, lab, val)
    at_peak = np.flatnonzero(val == peak[lab])
    ipk = np.zeros(n, np.intp)
    np.maximum.at(ipk, lab[at_peak], at_peak)  # idx is in scan order
    px, py = xs[ipk], ys[ipk]
    flux = np.bincount(lab, val, n)

    # Intensity-weighted second moments about the peak pixel (small numbers: no cancellation)
    # for the elongation test.
    dx = (xs - px[lab]).astype(np.float64)
    dy = (ys - py[lab]).astype(np.float64)
    wpos = np.maximum(val - pedestal, 0.0)
    sw = np.bincount(lab, wpos, n)
    sw = np.where(sw > 0, sw, 1.0)
    mx = np.bincount(lab, wpos * dx, n) / sw
    my = np.bincount(lab, wpos * dy, n) / sw
    cxx = np.bincount(lab, wpos * dx * dx, n) / sw - mx * mx
    cyy = np.bincount(lab, wpos * dy * dy, n) / sw - my * my
    cxy = np.bincount(lab, wpos * dx * dy, n) / sw - mx * my

    if centroid == "unweighted":
        cx = np.bincount(lab, xs.astype(np.float64), n) / area
        cy = np.bincount(lab, ys.astype(np.float64), n) / area
        # Renken keeps one decimal; round half up (Pascal's Round, positive values).
        cx, cy = np.floor(cx * 10 + 0.5) / 10, np.floor(cy * 10 + 0.5) / 10
    else:
        cx, cy = _ring_centroid(img, bg, mask, xs, ys, lab, wpos, px, py, n, pedestal)

    # ---- filters; the first matching reason wins ----
    # (small integer codes, not an object array of strings: comparing Python strings per
    # blob cost ~1 ms on a frame of 2000 blobs)
    code = np.zeros(n, np.int8)
    whys: list[str] = [""]

    def flag(cond: np.ndarray, why: str) -> None:
        whys.append(why)
        code[(code == 0) & cond] = len(whys) - 1

    flag(area > max_area, "too_large")
    if max_sharpness is not None:
        sharp = (peak - _neighbour_mean(img, bg, px, py)) / np.where(peak > 0, peak, 1.0)
        flag((peak > 0) & (sharp > max_sharpness), "hot_pixel")
    flag(area < min_area, "too_small")
    if saturation is not None:
        flag(np.bincount(lab, raw >= saturation, n) > 0, "saturated")
    if max_elongation is not None:
        half_trace = 0.5 * (cxx + cyy)
        disc = np.sqrt(np.maximum(0.25 * (cxx - cyy) ** 2 + cxy * cxy, 0.0))
        major = np.maximum(half_trace + disc, 0.0) + _PIXEL_VARIANCE
        minor = np.maximum(half_trace - disc, 0.0) + _PIXEL_VARIANCE
        flag((area >= _MIN_AREA_FOR_SHAPE) & (np.sqrt(major / minor) > max_elongation),
             "elongated")

    bad = code != 0
    # tuple.__new__ straight from C (Rejection._make is a Python call per blob)
    rejected = list(map(tuple.__new__, repeat(Rejection), zip(
        cx[bad].tolist(), cy[bad].tolist(), area[bad].tolist(),
        np.array(whys, dtype=object)[code[bad]].tolist(), strict=True,
    )))
    keep = np.flatnonzero(~bad)
    # Brightest first; equal fluxes in scan order (y, then x) so the output is deterministic.
    keep = keep[np.lexsort((cx[keep], cy[keep], -flux[keep]))]
    if max_detections is not None:
        keep = keep[:max_detections]
    return Detections(
        xy=np.column_stack([cx[keep], cy[keep]]).astype(np.float64),
        flux=flux[keep],
        area=area[keep].astype(np.int64),
        peak=peak[keep],
        ok=True,
        reason="",
        rejected=rejected,
        background_level=background_level,
        noise_sigma=noise_sigma,
        shape=shape,
        bright_pixels=int(idx.size),
        noise_model=noise_model,
    )


_NEIGHBOURS = np.array(
    [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)], dtype=np.intp
)


def _residual_at(img: np.ndarray, bg: _Grid | None, x: np.ndarray, y: np.ndarray,
                 lin: np.ndarray | None = None) -> np.ndarray:
    """Background-subtracted values at pixels (x, y) (flat indices ``lin``, if known: a 1-D
    take is cheaper than 2-D fancy indexing)."""
    v = (img[y, x] if lin is None else img.ravel().take(lin)).astype(np.float64)
    return v - bg.at(x, y) if bg is not None else v


def _neighbour_mean(
    img: np.ndarray, bg: _Grid | None, px: np.ndarray, py: np.ndarray
) -> np.ndarray:
    """Mean background-subtracted value of the in-image 8-neighbours of each (px, py)."""
    h, w = img.shape
    nx = px[:, None] + _NEIGHBOURS[:, 0]
    ny = py[:, None] + _NEIGHBOURS[:, 1]
    inside = (nx >= 0) & (nx < w) & (ny >= 0) & (ny < h)
    vals = _residual_at(img, bg, np.clip(nx, 0, w - 1), np.clip(ny, 0, h - 1))
    return np.where(inside, vals, 0.0).sum(axis=1) / np.maximum(inside.sum(axis=1), 1)


def _ring_centroid(
    img: np.ndarray,
    bg: _Grid | None,
    mask: np.ndarray,
    xs: np.ndarray,
    ys: np.ndarray,
    lab: np.ndarray,
    wpos: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    n: int,
    pedestal: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Intensity-weighted centroid over each blob plus the ring of its 8-neighbours below
    threshold; weights are background-subtracted values (less ``pedestal``) clipped at 0.

    Why the ring: the threshold cuts the PSF wings, which pulls a blob-only centroid towards
    its peak pixel (pixel locking). On pixel-integrated Gaussian stars (PSF sigma 0.7-2 px) the
    ring lowered the RMS error from 0.30 to 0.19 px at a peak of 8 sigma and from 0.14 to 0.11
    px at 15 sigma, and made no difference at high SNR; clipping the ring's noise at 0 did as
    well as or better than signed weights.
    """
    h, w = img.shape
    nx = (xs[:, None] + _NEIGHBOURS[:, 0]).ravel()
    ny = (ys[:, None] + _NEIGHBOURS[:, 1]).ravel()
    nl = np.repeat(lab, len(_NEIGHBOURS))
    ok = (nx >= 0) & (nx < w) & (ny >= 0) & (ny < h)
    lin = (ny * w + nx)[ok]
    nl = nl[ok]
    dim = ~mask.ravel()[lin]
    # Each dim neighbour once (a pixel next to two blobs goes to the lower label): sort
    # (pixel, label) packed in one int64 and keep the first of each pixel — a plain sort is
    # ~2× cheaper than np.unique(return_index=True).
    bits = max(int(n).bit_length(), 1)
    key = np.sort((lin[dim] << bits) | nl[dim])
    pix = key >> bits
    first = np.ones(key.size, bool)
    first[1:] = pix[1:] != pix[:-1]
    nl = key[first] & ((1 << bits) - 1)
    pix = pix[first]
    ry, rx = np.divmod(pix, w)
    all_lab = np.concatenate([lab, nl])
    all_w = np.concatenate([wpos, np.maximum(_residual_at(img, bg, rx, ry, pix) - pedestal,
                                             0.0)])
    dx = np.concatenate([xs, rx]) - px[all_lab]
    dy = np.concatenate([ys, ry]) - py[all_lab]
    s = np.bincount(all_lab, all_w, n)
    s = np.where(s > 0, s, 1.0)  # all weights 0 (cannot happen above threshold): peak pixel
    cx = px + np.bincount(all_lab, all_w * dx, n) / s
    cy = py + np.bincount(all_lab, all_w * dy, n) / s
    return cx, cy
