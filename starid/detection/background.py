"""A frame's background and noise on a grid of blocks (robust quantiles, a censored noise
estimate where the sensor clips), and the threshold mask of pixels above it.
"""

from __future__ import annotations

import warnings
from typing import Any

import cv2
import numpy as np
from adfusion.starid.detection.image import _NATIVE_INT

# P(X < median - 1 sigma) for a Gaussian: median - P15.87 is one standard deviation, estimated
# from the lower half only, which stars (always positive outliers) hardly touch.
_P_MINUS_1SIGMA = 0.15865525393145707


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
