"""Compiled (numba) projection of the catalogue into an undistorted pinhole's frame at an
attitude (:func:`predict_pinhole`), used by tracking and by the windowed detection.
"""

from __future__ import annotations

import math

import numpy as np
from adfusion.starid.jit_cache import njit_cached

__all__ = ["predict_pinhole"]

_jit = njit_cached(nogil=True)


@_jit
def predict_pinhole(vectors, rows, all_rows, R, A, c, cos_cone, lo, hi_x, hi_y, xy, M1, off):
    """The catalogue stars in the frame of an undistorted pinhole at attitude ``R`` (cam ←
    icrs), and the detections' unit vectors.

    Stars: rows of ``vectors`` (every row when ``all_rows``, else those in ``rows``,
    ascending) within ``cos_cone`` of the boresight ``R[2]`` (a superset of the frame) whose
    projection ``(u, v) = (A·(x/z, y/z) + c)`` lies in [lo, hi_x] × [lo, hi_y] with z > 0 —
    the solver's ``_predict``: (u·z, v·z, z) = H R r, H = [[A, c], [0, 0, 1]]. Detections:
    ``(xy @ M1 + off)`` normalised (:meth:`Camera.pixels_to_vectors`). Returns (pixel
    positions (P, 2), catalogue rows (P,), detection vectors (M, 3))."""
    # H R, row by row (H's last row is (0, 0, 1): z is r·R[2] exactly); in scalars, so
    # the loop keeps them in registers (as array reads it ran ~15× slower)
    a00, a01, a10, a11, c0, c1 = A[0, 0], A[0, 1], A[1, 0], A[1, 1], c[0], c[1]
    h00 = a00 * R[0, 0] + a10 * R[1, 0] + c0 * R[2, 0]
    h01 = a00 * R[0, 1] + a10 * R[1, 1] + c0 * R[2, 1]
    h02 = a00 * R[0, 2] + a10 * R[1, 2] + c0 * R[2, 2]
    h10 = a01 * R[0, 0] + a11 * R[1, 0] + c1 * R[2, 0]
    h11 = a01 * R[0, 1] + a11 * R[1, 1] + c1 * R[2, 1]
    h12 = a01 * R[0, 2] + a11 * R[1, 2] + c1 * R[2, 2]
    h20, h21, h22 = R[2, 0], R[2, 1], R[2, 2]
    n_rows = vectors.shape[0] if all_rows else rows.shape[0]
    out_xy = np.empty((n_rows, 2))
    out_idx = np.empty(n_rows, dtype=np.int64)
    n = 0
    for k in range(n_rows):
        r = k if all_rows else rows[k]
        v0, v1, v2 = vectors[r, 0], vectors[r, 1], vectors[r, 2]
        z = v0 * h20 + v1 * h21 + v2 * h22
        if z < cos_cone or not z > 0.0:
            continue
        u = (v0 * h00 + v1 * h01 + v2 * h02) / z
        w = (v0 * h10 + v1 * h11 + v2 * h12) / z
        if u >= lo and u <= hi_x and w >= lo and w <= hi_y:
            out_xy[n, 0], out_xy[n, 1], out_idx[n] = u, w, r
            n += 1
    b = np.empty((xy.shape[0], 3))
    for i in range(xy.shape[0]):
        x, y = xy[i, 0], xy[i, 1]
        b0 = x * M1[0, 0] + y * M1[1, 0] + off[0]
        b1 = x * M1[0, 1] + y * M1[1, 1] + off[1]
        b2 = x * M1[0, 2] + y * M1[1, 2] + off[2]
        nb = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
        b[i, 0], b[i, 1], b[i, 2] = b0 / nb, b1 / nb, b2 / nb
    return out_xy[:n], out_idx[:n], b
