"""Compiled (numba) window centroiding for :func:`starid.detection.windows.detect_windows`.

Why compiled code: a tracked frame centroids ~50–80 small windows. The numpy path does it in
~80 whole-array operations of a few µs each — per-call overhead, ~1 ms a frame; one compiled
pass over the windows is a few tens of µs.

The kernel computes what the numpy path (``detect_windows(..., compiled=False)``, kept as
the reference) computes, in the same arithmetic: float32 windows, background and noise from
the sorted border (numpy's linear quantile, in float32), the float32 threshold, 8-connected
blobs numbered as OpenCV's block-based labelling numbers them (by each blob's first 2×2
block in raster order: the order breaks ties between blobs equally near a prediction), the
float32 sums over rows (sequential) and columns (numpy's pairwise sum: 8 accumulators) of
the ring-weighted values, and the same rejection reasons in the same order of precedence.
The float64 sums after that are exact for integer images (their terms are multiples of the
background's float32 step, well inside 53 bits), so their order does not matter there.
tests/test_detect_roi.py compares the two paths on rendered frames. Compiled on first use
and cached on disk (``cache=True``), like :mod:`starid.tracking.kernels`;
:func:`starid.identify.kernels.prepare` compiles it with the others.

Example:
    >>> import numpy as np
    >>> from adfusion.starid.detection.window_kernels import pairwise_sum32
    >>> float(pairwise_sum32(np.arange(10, dtype=np.float32)))
    45.0
"""

from __future__ import annotations

import math

import numpy as np
from adfusion.starid.jit_cache import njit_cached

__all__ = ["pairwise_sum32", "window_centroids"]

_jit = njit_cached(nogil=True)

# P(X < median − 1σ) for a Gaussian (as in starid.detection.detect)
_P_MINUS_1SIGMA = 0.15865525393145707
_MIN_AREA_FOR_SHAPE = 5
_PIXEL_VARIANCE = 1.0 / 12.0
_NOT_FOUND, _CLIPPED, _ELONGATED, _EDGE = 1, 2, 3, 4


@_jit
def pairwise_sum32(a):
    """numpy's float32 ``sum`` of a short contiguous row (≤ 128): sequential below 8
    values, else 8 interleaved accumulators combined pairwise, then the tail."""
    n = a.shape[0]
    if n < 8:
        res = np.float32(0.0)
        for i in range(n):
            res = np.float32(res + a[i])
        return res
    r0, r1, r2, r3 = a[0], a[1], a[2], a[3]
    r4, r5, r6, r7 = a[4], a[5], a[6], a[7]
    i = 8
    stop = n - n % 8
    while i < stop:
        r0 = np.float32(r0 + a[i])
        r1 = np.float32(r1 + a[i + 1])
        r2 = np.float32(r2 + a[i + 2])
        r3 = np.float32(r3 + a[i + 3])
        r4 = np.float32(r4 + a[i + 4])
        r5 = np.float32(r5 + a[i + 5])
        r6 = np.float32(r6 + a[i + 6])
        r7 = np.float32(r7 + a[i + 7])
        i += 8
    res = np.float32(np.float32(np.float32(r0 + r1) + np.float32(r2 + r3))
                     + np.float32(np.float32(r4 + r5) + np.float32(r6 + r7)))
    while i < n:
        res = np.float32(res + a[i])
        i += 1
    return res


@_jit
def _pairwise_sum64(a):
    """numpy's float64 ``sum`` of a short contiguous row (as :func:`pairwise_sum32`)."""
    n = a.shape[0]
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[i]
        return res
    r = a[:8].copy()
    i = 8
    stop = n - n % 8
    while i < stop:
        for j in range(8):
            r[j] += a[i + j]
        i += 8
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        res += a[i]
        i += 1
    return res


@_jit
def _sorted_quantile32(row, q):
    """numpy's linear quantile of a sorted float32 row, in float32 (as detect_roi's)."""
    pos = q * (row.shape[0] - 1)
    i = math.floor(pos)
    f = pos - i
    if i + 1 >= row.shape[0]:
        return row[i]
    return np.float32(np.float32(row[i] * np.float32(1.0 - f))
                      + np.float32(row[i + 1] * np.float32(f)))


@_jit
def _select(a, lo, hi, k):
    """Rearrange ``a[lo:hi]`` so that ``a[k]`` holds its sorted value there, with nothing
    larger before it and nothing smaller after (quickselect with a three-way partition:
    integer frames repeat border values a lot; no nans)."""
    hi -= 1
    while hi > lo:
        x, y, z = a[lo], a[(lo + hi) // 2], a[hi]  # median-of-three pivot
        pivot = max(min(x, y), min(max(x, y), z))
        lt, i, gt = lo, lo, hi  # a[lo:lt] < pivot, a[lt:i] == pivot, a[gt + 1:hi + 1] > pivot
        while i <= gt:
            v = a[i]
            if v < pivot:
                a[i], a[lt] = a[lt], v
                lt += 1
                i += 1
            elif v > pivot:
                a[i], a[gt] = a[gt], v
                gt -= 1
            else:
                i += 1
        if k < lt:
            hi = lt - 1
        elif k > gt:
            lo = gt + 1
        else:
            return


@_jit
def _border_quantiles(border, q_hi, q_lo):
    """The linear quantiles ``q_hi`` > ``q_lo`` of ``border`` as of its sorted copy
    (:func:`_sorted_quantile32`), from the four order statistics they need (quickselect:
    sorting the ~50–100 border pixels of every window was most of the kernel's time).
    ``border`` is rearranged."""
    n = border.shape[0]
    for i in range(n):
        if border[i] != border[i]:  # a nan: numpy sorts it last
            border.sort()
            return _sorted_quantile32(border, q_hi), _sorted_quantile32(border, q_lo)
    out = np.empty(2, np.float32)
    top = n
    for j in range(2):
        q = q_hi if j == 0 else q_lo
        pos = q * (n - 1)
        i = math.floor(pos)
        f = pos - i
        _select(border, 0, top, i)
        if i + 1 >= n:
            out[j] = border[i]
        else:
            nxt = border[i + 1]  # the smallest after a[i] (up to the previous selection)
            for m in range(i + 2, min(top + 1, n)):
                if border[m] < nxt:
                    nxt = border[m]
            out[j] = np.float32(np.float32(border[i] * np.float32(1.0 - f))
                                + np.float32(nxt * np.float32(f)))
        top = i + 1  # the lower quantile is among these (a[:i + 1] ≤ the rest)
    return out[0], out[1]


@_jit
def _median32(a):
    """``np.median`` of a float32 vector, in float32 (nan if any is nan)."""
    s = np.sort(a)
    n = s.shape[0]
    if np.isnan(s[n - 1]):
        return np.float32(np.nan)
    if n % 2:
        return s[n // 2]
    return np.float32(np.float32(s[n // 2 - 1] + s[n // 2]) / np.float32(2.0))


@_jit
def window_centroids(img, pred, half, sigma, floor, min_area, edge_px, max_elongation,
                     check_elongation):
    """The windows' stars (see the module docstring). ``pred``: (n, 2) predictions inside
    the frame; ``floor``: the noise floor. Returns (code (n,): 0 or the rejection reason,
    cx, cy, area (0 where nothing was found), flux, peak, good: the accepted windows
    brightest first, background median, noise median, pixels above threshold).

    >>> img = np.full((20, 20), 100, np.uint16)
    >>> img[9, 9:11] = 300
    >>> code, cx, cy, area, *_ = window_centroids(img, np.array([[9.4, 9.2]]), 4, 5.0,
    ...                                           np.float32(0.5), 2, 3.0, 3.0, True)
    >>> code.tolist(), cx.tolist(), cy.tolist(), area.tolist()
    ([0], [9.5], [9.0], [2])
    """
    h_img, w_img = img.shape
    n = pred.shape[0]
    side = 2 * half + 1
    nb = 4 * side - 4
    sig32 = np.float32(sigma)
    code = np.zeros(n, np.int64)
    cx = np.zeros(n)
    cy = np.zeros(n)
    area_out = np.zeros(n, np.int64)
    flux_out = np.zeros(n)
    peak_out = np.zeros(n)
    px_out = np.zeros(n, np.int64)
    py_out = np.zeros(n, np.int64)
    d2_out = np.zeros(n)
    bgs = np.empty(n, np.float32)
    noises = np.empty(n, np.float32)
    bright = 0
    val = np.empty((side, side), np.float32)
    border = np.empty(nb, np.float32)
    lab = np.zeros((side, side), np.int64)
    stack_y = np.empty(side * side, np.int64)
    stack_x = np.empty(side * side, np.int64)
    ring = np.zeros((side, side), np.bool_)
    wcol = np.empty(side, np.float32)
    wrow = np.empty(side, np.float32)
    rowbuf = np.zeros(side, np.float32)
    area = np.empty(side * side + 1, np.int64)  # per blob (label), reused by each window
    flux = np.empty(side * side + 1)
    peak = np.empty(side * side + 1)
    ipk = np.empty(side * side + 1, np.int64)
    clipped = np.empty(side * side + 1, np.bool_)
    wx = np.empty(side)
    wy = np.empty(side)
    for k in range(n):
        x0 = min(max(int(np.rint(pred[k, 0])) - half, 0), w_img - side)
        y0 = min(max(int(np.rint(pred[k, 1])) - half, 0), h_img - side)
        # the border, straight from the image (float32, in the order the window's copy
        # gave it)
        m = 0
        for x in range(side):
            border[m] = np.float32(img[y0, x0 + x])
            border[m + side] = np.float32(img[y0 + side - 1, x0 + x])
            m += 1
        m = 2 * side
        for y in range(1, side - 1):
            border[m] = np.float32(img[y0 + y, x0])
            border[m + side - 2] = np.float32(img[y0 + y, x0 + side - 1])
            m += 1
        bg, q_lo = _border_quantiles(border, 0.5, _P_MINUS_1SIGMA)
        noise = np.float32(bg - q_lo)
        if noise < floor:  # np.maximum (a nan noise stays nan)
            noise = floor
        bgs[k], noises[k] = bg, noise
        thr = np.float32(sig32 * noise)
        # the pixels above threshold, and their bounding box: every later pass over the
        # window runs inside it (one pixel wider for the ring), in the same raster order
        # and so with the same sums (outside it every term was zero)
        y_lo, y_hi, x_lo, x_hi = side, -1, side, -1
        for y in range(side):
            for x in range(side):
                v = np.float32(np.float32(img[y0 + y, x0 + x]) - bg)
                val[y, x] = v
                if v > thr:
                    lab[y, x] = -1
                    bright += 1
                    y_lo, y_hi = min(y_lo, y), max(y_hi, y)
                    x_lo, x_hi = min(x_lo, x), max(x_hi, x)
                else:
                    lab[y, x] = 0
        if y_hi < 0:
            code[k] = _NOT_FOUND
            continue
        # 8-connected blobs by flood fill, numbered by their first 2×2 block in raster
        # order (OpenCV's block-based labelling of the stacked windows: windows start on
        # even rows, so the blocks line up with each window's); blocks outside the box
        # hold no such pixel
        n_lab = 0
        for by in range(y_lo - y_lo % 2, y_hi + 1, 2):
            for bx in range(x_lo - x_lo % 2, x_hi + 1, 2):
                for y in range(by, min(by + 2, side)):
                    for x in range(bx, min(bx + 2, side)):
                        if lab[y, x] != -1:
                            continue
                        n_lab += 1
                        lab[y, x] = n_lab
                        stack_y[0], stack_x[0] = y, x  # (rows and columns apart:
                        top = 1  # no division per pixel)
                        while top:
                            top -= 1
                            py, px = stack_y[top], stack_x[top]
                            for yy in range(max(py - 1, 0), min(py + 2, side)):
                                for xx in range(max(px - 1, 0), min(px + 2, side)):
                                    if lab[yy, xx] == -1:
                                        lab[yy, xx] = n_lab
                                        stack_y[top], stack_x[top] = yy, xx
                                        top += 1
        # per blob, in raster order: area, flux (float64, sequential), peak (the last pixel
        # at the maximum), clipped (touches a window edge that is not the frame's)
        for lb in range(n_lab + 1):
            area[lb], flux[lb], peak[lb], ipk[lb], clipped[lb] = 0, 0.0, -np.inf, 0, False
        for y in range(y_lo, y_hi + 1):
            for x in range(x_lo, x_hi + 1):
                lb = lab[y, x]
                if lb <= 0:
                    continue
                v = np.float64(val[y, x])
                area[lb] += 1
                flux[lb] += v
                if v >= peak[lb]:
                    peak[lb] = v
                    ipk[lb] = y * side + x
                # (as the numpy path: a pixel on the frame's edge is exempt, corners too)
                if ((y == 0 or y == side - 1 or x == 0 or x == side - 1)
                        and not ((x == 0 and x0 == 0) or (x == side - 1 and x0 == w_img - side)
                                 or (y == 0 and y0 == 0)
                                 or (y == side - 1 and y0 == h_img - side))):
                    clipped[lb] = True
        best, best_d2 = 0, np.inf
        for lb in range(1, n_lab + 1):
            if area[lb] < min_area:
                continue
            dx = (ipk[lb] % side + x0) - pred[k, 0]
            dy = (ipk[lb] // side + y0) - pred[k, 1]
            d2 = dx * dx + dy * dy
            if d2 < best_d2:
                best, best_d2 = lb, d2
        if best == 0:
            code[k] = _NOT_FOUND
            continue
        # centroid over the blob and its ring of 8-neighbours, background-subtracted, ≥ 0;
        # ``ring`` and ``rowbuf`` are all False / zero between windows
        ry_lo, ry_hi = max(y_lo - 1, 0), min(y_hi + 1, side - 1)
        rx_lo, rx_hi = max(x_lo - 1, 0), min(x_hi + 1, side - 1)
        for y in range(y_lo, y_hi + 1):
            for x in range(x_lo, x_hi + 1):
                if lab[y, x] == best:
                    for yy in range(max(y - 1, 0), min(y + 2, side)):
                        for xx in range(max(x - 1, 0), min(x + 2, side)):
                            ring[yy, xx] = True
        for x in range(side):
            wcol[x] = np.float32(0.0)
        for y in range(side):
            if y < ry_lo or y > ry_hi:
                wrow[y] = np.float32(0.0)  # a row of zeros (adds nothing to the columns)
                continue
            for x in range(rx_lo, rx_hi + 1):
                v = val[y, x] if ring[y, x] and val[y, x] > 0 else np.float32(0.0)
                rowbuf[x] = v
                wcol[x] = np.float32(wcol[x] + v)  # numpy: sequential down the rows
            wrow[y] = pairwise_sum32(rowbuf)  # numpy: pairwise along the whole row
        for x in range(rx_lo, rx_hi + 1):
            rowbuf[x] = np.float32(0.0)
        for i in range(side):
            wx[i] = np.float64(wcol[i])
            wy[i] = np.float64(wrow[i])
        sw = _pairwise_sum64(wx)
        sw_safe = sw if sw > 0 else 1.0
        sx = sy = sxx = syy = 0.0
        for i in range(side):
            sx += wx[i] * i
            sy += wy[i] * i
            sxx += wx[i] * (i * i)
            syy += wy[i] * (i * i)
        gx, gy = sx / sw_safe, sy / sw_safe
        cx[k], cy[k] = gx + x0, gy + y0
        area_out[k], flux_out[k], peak_out[k] = area[best], flux[best], peak[best]
        px_out[k] = ipk[best] % side + x0
        py_out[k] = ipk[best] // side + y0
        d2_out[k] = best_d2
        sxy = 0.0
        shape_test = check_elongation and area[best] >= _MIN_AREA_FOR_SHAPE \
            and not clipped[best]
        for y in range(ry_lo, ry_hi + 1):
            for x in range(rx_lo, rx_hi + 1):
                if shape_test and ring[y, x] and val[y, x] > 0:
                    sxy += np.float64(val[y, x]) * y * x
                ring[y, x] = False
        if clipped[best]:
            code[k] = _CLIPPED
            continue
        if shape_test:
            cxx = sxx / sw_safe - gx * gx
            cyy = syy / sw_safe - gy * gy
            cxy = sxy / sw_safe - gx * gy
            half_trace = 0.5 * (cxx + cyy)
            disc = math.sqrt(max(0.25 * (cxx - cyy) ** 2 + cxy * cxy, 0.0))
            ratio = math.sqrt((half_trace + disc + _PIXEL_VARIANCE)
                              / (max(half_trace - disc, 0.0) + _PIXEL_VARIANCE))
            if ratio > max_elongation:
                code[k] = _ELONGATED
                continue
        c_x, c_y = cx[k], cy[k]
        if (c_x + 0.5 < edge_px or w_img - 0.5 - c_x < edge_px or c_y + 0.5 < edge_px
                or h_img - 0.5 - c_y < edge_px):
            code[k] = _EDGE
    # two windows on one blob (the same peak pixel): the nearer prediction keeps it (the
    # lower window among equals), the other found nothing
    dup = np.zeros(n, np.bool_)
    for i in range(n):
        if code[i] != 0:
            continue
        for j in range(n):
            if j == i or code[j] != 0:
                continue
            if px_out[j] == px_out[i] and py_out[j] == py_out[i] and (
                    d2_out[j] < d2_out[i] or (d2_out[j] == d2_out[i] and j < i)):
                dup[i] = True
                break
    n_good = 0
    for i in range(n):
        if dup[i]:
            code[i] = _NOT_FOUND
        elif code[i] == 0:
            n_good += 1
    # brightest first, then by y, then x (a stable insertion sort: few dozen windows)
    good = np.empty(n_good, np.int64)
    m = 0
    for i in range(n):
        if code[i] == 0:
            j = m
            while j > 0:
                g = good[j - 1]
                if (flux_out[g] > flux_out[i] or (flux_out[g] == flux_out[i] and (
                        cy[g] < cy[i] or (cy[g] == cy[i] and cx[g] <= cx[i])))):
                    break
                good[j] = g
                j -= 1
            good[j] = i
            m += 1
    return (code, cx, cy, area_out, flux_out, peak_out, good, _median32(bgs),
            _median32(noises), bright)
