"""Star detection in windows around predicted star positions: what a star tracker does once
it tracks.

A tracker that knows its attitude to a fraction of a pixel need not search the whole frame:
it reads a small window around each catalogue star its prediction puts in view and
centroids the star there. On a 512×512 frame that touches ~5 % of the pixels, and the
flight software's catalogue lets it leave out the stars it cannot centroid well:

* **crowded** — another catalogue star predicted within ``isolation_px``: the two blend
  into one blob, or the neighbour's wing drags the centroid (on the ``leo`` scenario of
  :mod:`adfusion.basilisk` two such pairs, 4.5 and 5.9 px apart, put 0.4 and 2.4 px
  errors into otherwise 0.03 px centroids, and through them a 9″ roll bias into every fix
  of the same stars);
* **edge** — a centroid within ``edge_px`` of the frame's border (the PSF is cut: 0.26 px
  of bias 1.2 px from the border);
* **clipped** — the star's blob reaches the window's border (a star brighter or further
  off its prediction than the window allows);
* **elongated** — blobs of ≥ 5 px whose second moments are more than ``max_elongation``
  times longer than wide (a blend of two stars, a trail), as in :func:`starid.detection.detect`;
* **not_found** — nothing above threshold in the window (the star is below the camera's
  limit, or not where it was predicted).

Each window's background is the median of its border pixels and its noise their lower-half
spread (median − 15.87th percentile, as in :func:`starid.detection.detect`); pixels above background
+ ``sigma`` · noise form 8-connected blobs, and the window's star is the blob whose peak is
nearest the prediction. Centroids are intensity-weighted over the blob and the ring of its
8-neighbours, on background-subtracted values clipped at 0 — :func:`starid.detection.detect`'s
centroid. Everything is vectorised over the windows (one OpenCV labelling of all of them
stacked), so the cost hardly depends on the number of stars.

:class:`TrackingWindows` places the windows from a tracking :class:`starid.Prior` (the
solver's catalogue and camera, the prior's 3σ cone and smear) and says when not to: a
prior too loose for windows of ``max_half_px``, or too few windows holding a star (the
prior may be wrong) — then the caller detects the whole frame.

Why a module of its own rather than an option of :func:`starid.detection.detect`: the full-frame
detector estimates a background map, thresholds and labels the frame; windows share none
of that machinery, only the conventions (pixel centres, the centroid, the
:class:`starid.Detections` result the solver reads).

Example (three stars rendered at known positions; a fourth prediction finds nothing):
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> img = rng.normal(100.0, 3.0, (96, 128)).astype(np.float32)
    >>> yy, xx = np.mgrid[:96, :128]
    >>> for x, y, peak in [(30.3, 40.6, 3000.0), (70.8, 20.2, 2000.0), (100.1, 70.5, 1000.0)]:
    ...     img += peak * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 1.2**2))
    >>> det = detect_windows(img, [[30.0, 41.0], [71.0, 20.0], [100.0, 70.0], [50.0, 60.0]])
    >>> det.xy.round(2).tolist()
    [[30.3, 40.6], [70.8, 20.2], [100.1, 70.5]]
    >>> [r.reason for r in det.rejected]
    ['not_found']
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
from adfusion.starid.detection.detections import Detections, Rejection
from adfusion.starid.detection.window_kernels import window_centroids
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike

from adfusion.maths import rotations as rot

__all__ = ["TrackingWindows", "detect_windows"]

# P(X < median − 1σ) for a Gaussian (as in starid.detection.detect)
_P_MINUS_1SIGMA = 0.15865525393145707
# second moments are not trusted below this blob size (as in starid.detection.detect)
_MIN_AREA_FOR_SHAPE = 5
_PIXEL_VARIANCE = 1.0 / 12.0
_RING = np.ones((3, 3), np.uint8)
_NOT_FOUND, _CLIPPED, _ELONGATED, _EDGE = 1, 2, 3, 4
_REASONS = {_NOT_FOUND: "not_found", _CLIPPED: "clipped", _ELONGATED: "elongated",
            _EDGE: "edge"}


def detect_windows(
    image: np.ndarray,
    xy_predicted: ArrayLike,
    half_px: int = 6,
    *,
    sigma: float = 5.0,
    min_area: int = 2,
    isolation_px: float | None = None,
    edge_px: float = 3.0,
    max_elongation: float | None = 3.0,
    compiled: bool = True,
) -> Detections:
    """Centroid the star in a (2·``half_px`` + 1)² window around each predicted position.

    Args:
        image: 2-D frame (any real dtype), ``image[y, x]``.
        xy_predicted: (N, 2) predicted positions (pixel centres, x right, y down); those
            outside the frame are ignored.
        half_px: window half-size; the window must hold the prediction's error plus the
            star's blob.
        sigma: detection threshold in units of the window's noise above its background.
        min_area: smallest blob (pixels above threshold) taken for a star.
        isolation_px: predictions with another prediction closer than this are left out
            ("crowded"); None: none are.
        edge_px: centroids closer than this to the frame's border are rejected ("edge").
        max_elongation: reject blobs of ≥ 5 px elongated beyond this ("elongated"); None:
            off.
        compiled: centroid with the compiled kernel
            (:func:`starid.detection.window_kernels.window_centroids`, the same results); False:
            the numpy reference path.

    Returns:
        :class:`starid.Detections`, brightest first; one :class:`starid.Rejection` per
        window without a usable star (at its prediction, area 0 unless a blob was found).
    """
    img = np.asarray(image)
    if img.ndim != 2 or img.dtype.kind not in "uif":
        raise ValueError(f"image must be a 2-D array of real numbers, got {img.dtype} "
                         f"{img.shape}")
    h_img, w_img = img.shape
    half = int(half_px)
    side = 2 * half + 1
    if half < 2 or side > min(h_img, w_img):
        raise ValueError(f"half_px must be ≥ 2 and the window ({side} px) fit the "
                         f"{w_img}×{h_img} frame, got {half_px!r}")
    if not (math.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma must be a positive number, got {sigma!r}")
    pred = np.asarray(xy_predicted, dtype=np.float64).reshape(-1, 2)
    inside = np.isfinite(pred).all(axis=1)
    inside[inside] = ((pred[inside, 0] >= -0.5) & (pred[inside, 0] < w_img - 0.5)
                      & (pred[inside, 1] >= -0.5) & (pred[inside, 1] < h_img - 0.5))
    pred = pred[inside]
    rejected: list[Rejection] = []
    if isolation_px is not None and len(pred) > 1:
        dx = pred[:, 0, None] - pred[None, :, 0]
        dy = pred[:, 1, None] - pred[None, :, 1]
        d2 = dx * dx
        d2 += dy * dy
        np.fill_diagonal(d2, np.inf)
        crowded = d2.min(axis=1) < float(isolation_px) ** 2
        rejected += [Rejection(x, y, 0, "crowded") for x, y in pred[crowded].tolist()]
        pred = pred[~crowded]
    n = len(pred)
    if n == 0:
        return Detections.empty((h_img, w_img), rejected=rejected, noise_model="windows")
    if compiled:
        return _detect_compiled(img, pred, half, sigma, min_area, edge_px, max_elongation,
                                rejected)

    # the windows, stacked: (n, side, side), clamped inside the frame
    x0 = np.clip(np.rint(pred[:, 0]).astype(np.intp) - half, 0, w_img - side)
    y0 = np.clip(np.rint(pred[:, 1]).astype(np.intp) - half, 0, h_img - side)
    ar = np.arange(side)
    win = sliding_window_view(img, (side, side))[y0, x0].astype(np.float32)
    border = np.sort(np.concatenate([win[:, 0, :], win[:, -1, :], win[:, 1:-1, 0],
                                     win[:, 1:-1, -1]], axis=1), axis=1)
    bg = _sorted_quantile(border, 0.5)
    noise = bg - _sorted_quantile(border, _P_MINUS_1SIGMA)
    floor = 0.5 if img.dtype.kind in "ui" else 1e-12  # quantised data: at least half a step
    noise = np.maximum(noise, floor).astype(np.float32)
    val = win - bg.astype(np.float32)[:, None, None]
    mask = val > (sigma * noise)[:, None, None]

    # one labelling of all windows: a zero row after each keeps them apart
    stack = np.zeros((n, side + 1, side), np.uint8)
    stack[:, :side] = mask
    n_lab, labels = cv2.connectedComponents(stack.reshape(-1, side), connectivity=8,
                                            ltype=cv2.CV_32S)
    labels = labels.reshape(n, side + 1, side)[:, :side]
    flat = np.flatnonzero(labels)
    lab = labels.reshape(-1)[flat]
    v = val.reshape(-1)[flat].astype(np.float64)
    wi, rest = np.divmod(flat, side * side)
    yy, xx = np.divmod(rest, side)
    area = np.bincount(lab, minlength=n_lab)
    owner = np.full(n_lab, -1, np.intp)
    owner[lab] = wi
    peak = np.full(n_lab, -np.inf)
    np.maximum.at(peak, lab, v)
    at_peak = np.flatnonzero(v == peak[lab])
    ipk = np.zeros(n_lab, np.intp)
    np.maximum.at(ipk, lab[at_peak], at_peak)
    edge = (yy == 0) | (yy == side - 1) | (xx == 0) | (xx == side - 1)
    if ((x0 == 0) | (x0 == w_img - side) | (y0 == 0) | (y0 == h_img - side)).any():
        # a window edge on the frame's edge is not a clipped window (the "edge" test is)
        edge &= ~(((xx == 0) & (x0[wi] == 0)) | ((xx == side - 1) & (x0[wi] == w_img - side))
                  | ((yy == 0) & (y0[wi] == 0)) | ((yy == side - 1) & (y0[wi] == h_img - side)))
    clipped = np.bincount(lab, edge, n_lab) > 0
    flux = np.bincount(lab, v, n_lab)

    # each window's star: the blob (≥ min_area) whose peak is nearest the prediction
    px = xx[ipk] + x0[owner]
    py = yy[ipk] + y0[owner]
    d2 = (px - pred[owner, 0]) ** 2 + (py - pred[owner, 1]) ** 2
    usable = (area >= min_area) & (owner >= 0)
    cand = np.flatnonzero(usable)
    chosen = np.zeros(n, np.intp)  # label per window, 0 = none
    if len(cand):
        order = cand[np.lexsort((d2[cand], owner[cand]))]
        first = np.unique(owner[order], return_index=True)
        chosen[first[0]] = order[first[1]]
    found = chosen > 0

    # centroids over each chosen blob and its ring of 8-neighbours
    m = np.zeros((n, side + 1, side), np.uint8)
    m[:, :side] = labels == chosen[:, None, None]
    m[~found] = 0
    ring = cv2.dilate(m.reshape(-1, side), _RING).reshape(n, side + 1, side)[:, :side]
    w = np.maximum(val, 0.0)
    w *= ring
    wx = w.sum(axis=1).astype(np.float64)  # (n, side): the weights summed down the columns
    wy = w.sum(axis=2).astype(np.float64)
    arf = ar.astype(np.float64)
    sw = wx.sum(axis=1)
    sw_safe = np.where(sw > 0, sw, 1.0)
    gx = wx @ arf / sw_safe
    gy = wy @ arf / sw_safe
    cx, cy = gx + x0, gy + y0

    # why each window has no usable star (0: it has one), first reason wins
    code = np.where(found, 0, _NOT_FOUND)
    code[found & clipped[chosen]] = _CLIPPED
    if max_elongation is not None:
        cxx = wx @ (arf * arf) / sw_safe - gx * gx
        cyy = wy @ (arf * arf) / sw_safe - gy * gy
        cxy = np.einsum("nij,i,j->n", w, arf, arf) / sw_safe - gx * gy
        half_trace = 0.5 * (cxx + cyy)
        disc = np.sqrt(np.maximum(0.25 * (cxx - cyy) ** 2 + cxy * cxy, 0.0))
        ratio = np.sqrt((half_trace + disc + _PIXEL_VARIANCE)
                        / (np.maximum(half_trace - disc, 0.0) + _PIXEL_VARIANCE))
        big = found & (area[chosen] >= _MIN_AREA_FOR_SHAPE)
        code[(code == 0) & big & (ratio > max_elongation)] = _ELONGATED
    near_edge = ((cx + 0.5 < edge_px) | (w_img - 0.5 - cx < edge_px)
                 | (cy + 0.5 < edge_px) | (h_img - 0.5 - cy < edge_px))
    code[(code == 0) & near_edge] = _EDGE
    # two windows on one blob (a prediction with no star of its own next to one that has):
    # the blob goes to the nearer prediction, the other window found nothing
    ok = np.flatnonzero(code == 0)
    if len(ok) > 1:
        at = (py[chosen[ok]] * w_img + px[chosen[ok]]).astype(np.int64)
        order = ok[np.lexsort((d2[chosen[ok]], at))]
        at = at[np.lexsort((d2[chosen[ok]], at))]
        dup = np.zeros(len(order), bool)
        dup[1:] = at[1:] == at[:-1]
        code[order[dup]] = _NOT_FOUND
    out_area = np.where(found, area[chosen], 0)
    bad = np.flatnonzero(code)
    rx = np.where(found, cx, pred[:, 0])[bad].tolist()
    ry = np.where(found, cy, pred[:, 1])[bad].tolist()
    rejected += [Rejection(x, y, a, _REASONS[c]) for x, y, a, c in
                 zip(rx, ry, out_area[bad].tolist(), code[bad].tolist(), strict=True)]
    good = np.flatnonzero(code == 0)
    good = good[np.lexsort((cx[good], cy[good], -flux[chosen[good]]))]
    return Detections(
        xy=np.column_stack([cx[good], cy[good]]).astype(np.float64),
        flux=flux[chosen[good]],
        area=out_area[good].astype(np.int64),
        peak=peak[chosen[good]],
        ok=True,
        reason="",
        rejected=rejected,
        background_level=float(np.median(bg)),
        noise_sigma=float(np.median(noise)),
        shape=(h_img, w_img),
        bright_pixels=int(mask.sum()),
        noise_model="windows",
    )


def _detect_compiled(img: np.ndarray, pred: np.ndarray, half: int, sigma: float,
                     min_area: int, edge_px: float, max_elongation: float | None,
                     rejected: list[Rejection]) -> Detections:
    """:func:`detect_windows` after its checks, in one compiled pass over the windows."""
    h_img, w_img = img.shape
    floor = 0.5 if img.dtype.kind in "ui" else 1e-12  # quantised data: at least half a step
    (code, cx, cy, area, flux, peak, good, bg_med, noise_med,
     bright) = window_centroids(img, pred, half, float(sigma), np.float32(floor),
                                int(min_area), float(edge_px),
                                0.0 if max_elongation is None else float(max_elongation),
                                max_elongation is not None)
    bad = np.flatnonzero(code)
    if len(bad):
        px, py = pred[bad].T.tolist()
        for x, y, a, c, i in zip(cx[bad].tolist(), cy[bad].tolist(), area[bad].tolist(),
                                 code[bad].tolist(), range(len(bad)), strict=True):
            # at the blob's centroid when one was found, else at the prediction
            rejected.append(Rejection(x, y, a, _REASONS[c]) if a > 0 else
                            Rejection(px[i], py[i], a, _REASONS[c]))
    xy = np.empty((len(good), 2))
    xy[:, 0] = cx[good]
    xy[:, 1] = cy[good]
    return Detections(
        xy=xy,
        flux=flux[good],
        area=area[good],
        peak=peak[good],
        ok=True,
        reason="",
        rejected=rejected,
        background_level=float(bg_med),
        noise_sigma=float(noise_med),
        shape=(h_img, w_img),
        bright_pixels=int(bright),
        noise_model="windows",
    )


def _sorted_quantile(rows: np.ndarray, q: float) -> np.ndarray:
    """Quantile ``q`` of each sorted row, linearly interpolated (numpy's default method)."""
    pos = q * (rows.shape[1] - 1)
    i = math.floor(pos)
    f = pos - i
    if i + 1 >= rows.shape[1]:
        return rows[:, i].astype(np.float64)
    return rows[:, i] * (1.0 - f) + rows[:, i + 1] * f


class TrackingWindows:
    """Windows around the stars a tracking prior predicts, for a solver's catalogue and
    camera (see the module docstring).

    Args:
        solver: the :class:`starid.Solver` whose catalogue and camera predict the stars.
        max_half_px: the largest window half-size; a prior whose 3σ cone plus smear
            needs more goes to full-frame detection (``detect`` returns None).
        star_px: the window's room for the star's blob around the predicted position.
        isolation_px, edge_px, sigma, min_area, max_elongation: as in
            :func:`detect_windows`.
        min_found, min_found_fraction: fewer stars than this many, or than this share of
            the windows, and ``detect`` returns None: the prior may be off by more than a
            window.
        max_windows: windows around at most this many predicted stars, the brightest in
            the catalogue (None: the solver's ``max_detections`` + 10). The solver
            identifies from its brightest ``max_detections`` detections only, so windows
            on fainter stars cost time and change nothing; the 10 spare cover stars not
            found, clipped or at the edge.

    Example:
        >>> from adfusion import starid
        >>> from adfusion.sensors.render import render_frame
        >>> cat = starid.Catalog.hipparcos(mag_limit=6.0)
        >>> cam = starid.Camera.pinhole(512, 512, 20.0)
        >>> q = rot.q_cam_icrs_from_radec_roll(1.0, 0.5, 0.2)
        >>> fr = render_frame(cam, q, cat.vectors, cat.mag, seed=1)
        >>> tw = TrackingWindows(starid.Solver(cat, cam))
        >>> det = tw.detect(fr.image, starid.Prior(q, 0.002))
        >>> len(det) > 10, tw.detect(fr.image, starid.Prior(q, 1.0))
        (True, None)
    """

    def __init__(self, solver: Any, *, max_half_px: int = 12, star_px: float = 4.0,
                 isolation_px: float | None = 6.0, edge_px: float = 3.0, sigma: float = 5.0,
                 min_area: int = 2, max_elongation: float | None = 3.0, min_found: int = 3,
                 min_found_fraction: float = 0.25, max_windows: int | None = None) -> None:
        if not (math.isfinite(sigma) and sigma > 0):
            raise ValueError(f"sigma must be a positive number, got {sigma!r}")
        self.camera = solver.camera
        self.vectors = np.asarray(solver.catalog.vectors, dtype=np.float64)
        self._catalog = solver.catalog
        self.max_half_px = int(max_half_px)
        self.star_px = float(star_px)
        self.kw = {"edge_px": edge_px, "sigma": sigma, "min_area": min_area,
                   "max_elongation": max_elongation}
        # the catalogue's crowded stars, once: a neighbour within isolation_px (at the
        # centre's pixel scale) — the flag a tracker's onboard catalogue carries
        self.crowded = np.zeros(len(self.vectors), bool)
        if isolation_px is not None:
            i, j, _ = solver.catalog.pairs_within(isolation_px * self.camera.pixel_scale_rad)
            self.crowded[i] = self.crowded[j] = True
        self.min_found = int(min_found)
        if max_windows is None:
            max_windows = int(getattr(solver, "max_detections", 30)) + 10
        if not (isinstance(max_windows, int | np.integer) and max_windows >= 1):
            raise ValueError(f"max_windows must be an integer ≥ 1, got {max_windows!r}")
        self.max_windows = int(max_windows)
        self._mag = np.asarray(solver.catalog.mag, dtype=np.float64)
        self.min_found_fraction = float(min_found_fraction)
        cam = self.camera
        self._half_diag = cam._view_half_rad  # the farthest corner from the axis
        self._cone_margin = math.radians(1.0)
        self._cone_axis: np.ndarray | None = None
        self._cone: np.ndarray = np.zeros(0, np.int64)
        # an undistorted pinhole projects with the tracking path's compiled kernel
        self._ideal = cam._ideal_pinhole
        self._no_xy = np.zeros((0, 2))

    def half_px(self, prior: Any) -> int:
        """The window half-size a prior needs: its 3σ (``k``·σ) cone and half its smear in
        pixels, plus ``star_px``."""
        pix = self.camera.pixel_scale_rad
        err = math.radians(prior.k * prior.sigma_deg) / pix
        if prior.smear_cam_rad is not None:
            x, y, z = prior.smear_cam_rad.tolist()
            err += 0.5 * math.sqrt(x * x + y * y + z * z) / pix
        return math.ceil(err + self.star_px)

    def predict(self, q_cam_icrs: ArrayLike) -> np.ndarray:
        """(N, 2) pixel positions of the catalogue stars in the frame at ``q_cam_icrs``,
        brightest first."""
        return self._predict(rot.to_matrix(q_cam_icrs))[0]

    def _predict(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and crowded flags of the catalogue stars in the frame (``r``: R_cam_icrs),
        brightest first; the catalogue cone around the boresight is kept until it moves by
        ``_cone_margin``."""
        axis = r[2]
        if self._cone_axis is None or float(axis @ self._cone_axis) < math.cos(self._cone_margin):
            cone = self._catalog.cone(axis, self._half_diag + 2 * self._cone_margin)
            # brightest first: the stars in view come out in that order (max_windows)
            self._cone = cone[np.argsort(self._mag[cone], kind="stable")]
            self._cone_axis = axis
        if self._ideal is not None:
            # (u·z, v·z, z) = H R r over the cone's rows, compiled (the frame test included)
            from adfusion.starid.camera.projection_kernels import (
                predict_pinhole,  # compiled on first use
            )

            m1, off, a, c = self._ideal
            cam = self.camera
            xy, rows, _ = predict_pinhole(self.vectors, self._cone, False, r, a, c, 0.0,
                                             -0.5, cam.width - 0.5, cam.height - 0.5,
                                             self._no_xy, m1, off)
            return xy, self.crowded[rows]
        v = self.vectors[self._cone] @ r.T
        front = v[:, 2] > 0
        xy = self.camera.vectors_to_pixels(v[front])
        inside = self.camera.in_frame(xy)
        return xy[inside], self.crowded[self._cone[front][inside]]

    def detect(self, image: np.ndarray, prior: Any) -> Detections | None:
        """Detections in the windows ``prior`` predicts, or None (detect the whole frame):
        the prior is too loose for ``max_half_px``, or too few windows held a star."""
        half = self.half_px(prior)
        if half > self.max_half_px:
            return None
        xy, crowded = self._predict(rot.to_matrix(prior.q_cam_icrs))
        if not len(xy) or crowded.all():
            return None
        img = image if isinstance(image, np.ndarray) else np.asarray(image)
        side = 2 * half + 1
        if img.ndim != 2 or img.dtype.kind not in "uif" or half < 2 or side > min(img.shape):
            # what detect_windows refuses, in its words
            return detect_windows(img, xy[~crowded][: self.max_windows], half, **self.kw)
        # the predictions are finite and inside the frame (``_predict``): straight to the
        # compiled centroiding, without detect_windows' checks of arbitrary input
        use = np.ascontiguousarray(xy[~crowded][: self.max_windows])
        kw = self.kw
        det = _detect_compiled(img, use, half, kw["sigma"], kw["min_area"], kw["edge_px"],
                               kw["max_elongation"], [])
        if len(det) < max(self.min_found, self.min_found_fraction * len(use)):
            return None
        if crowded.any():
            det.rejected.extend(Rejection(x, y, 0, "crowded") for x, y in xy[crowded].tolist())
        return det
