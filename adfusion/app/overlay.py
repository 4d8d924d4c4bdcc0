"""Overlay images for a person to check an identification (Bleif 2004, Fig. 4.7 style).

Drawn with OpenCV on a contrast-stretched copy of the frame:

* every detection — a thin grey circle;
* identified stars — a green circle with the catalogue id;
* the projected catalogue — a cyan cross where a catalogue star is expected; a red cross
  marks an expected position with no detection near it (a missing star is as telling as
  a found one);
* a caption with RA/Dec/roll, the number of matches and the false-match probability.

Example:
    >>> import numpy as np
    >>> from adfusion.app.overlay import stretch
    >>> stretch(np.array([[0, 10], [20, 30000]], dtype=np.uint16)).dtype.name
    'uint8'
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["draw_solution", "stretch"]


def stretch(image: NDArray) -> NDArray[np.uint8]:
    """8-bit display copy: the smooth background (vignetting, glow) removed, sky at ~20 %
    grey, stars saturating through an asinh curve."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 3:
        img = img.mean(axis=2)
    finite = np.isfinite(img)
    if not finite.any():
        return np.zeros(img.shape, np.uint8)
    img = np.where(finite, img, float(np.median(img[finite])))
    h, w = img.shape
    small = cv2.resize(img, (max(1, w // 16), max(1, h // 16)), interpolation=cv2.INTER_AREA)
    small = cv2.medianBlur(small, 5) if min(small.shape) >= 5 else small
    resid = img - cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    noise = 1.4826 * float(np.median(np.abs(resid - np.median(resid)))) + 1e-6
    x = np.arcsinh(np.clip(resid / (3 * noise), -1, None))
    x = 0.2 + 0.8 * x / max(float(np.percentile(x, 99.95)), 1e-6)
    return np.clip(x * 255, 0, 255).astype(np.uint8)


def draw_solution(image: NDArray, det_xy: NDArray, sol, radius_px: float = 6.0) -> NDArray:
    """BGR overlay of a :class:`starid.Solution` (ok or not) on ``image``."""
    canvas = cv2.cvtColor(stretch(image), cv2.COLOR_GRAY2BGR)
    grey, green, cyan, red, white = (160, 160, 160), (60, 220, 60), (230, 200, 0), \
        (40, 40, 240), (255, 255, 255)
    r = round(radius_px)
    for x, y in np.asarray(det_xy, dtype=float):
        if np.isfinite(x) and np.isfinite(y):
            cv2.circle(canvas, _pt(x, y), r, grey, 1, cv2.LINE_AA)
    cand = sol.candidates[0] if (sol.ok and sol.candidates) else None
    if sol.ok:
        cand = next((c for c in sol.candidates if c.matches == sol.matches), cand)
    if cand is not None:
        det = np.asarray(det_xy, dtype=float)
        occupied = np.zeros(len(cand.predicted_xy), dtype=bool)
        if len(det):
            d = np.hypot(cand.predicted_xy[:, None, 0] - det[None, :, 0],
                         cand.predicted_xy[:, None, 1] - det[None, :, 1])
            occupied = d.min(axis=1) < 2 * radius_px
        for (x, y), occ in zip(cand.predicted_xy, occupied, strict=True):
            _cross(canvas, x, y, 5, cyan if occ else red)
        for d_i, cid in cand.matches:
            x, y = det[d_i]
            cv2.circle(canvas, _pt(x, y), r + 3, green, 2, cv2.LINE_AA)
            cv2.putText(canvas, str(cid), _pt(x + r + 5, y - r - 2), cv2.FONT_HERSHEY_SIMPLEX,
                        0.45, green, 1, cv2.LINE_AA)
    if sol.ok:
        ra, dec, roll = sol.ra_dec_roll_deg
        text = (f"RA {ra:.4f}  Dec {dec:+.4f}  roll {roll:.3f} deg   {len(sol.matches)} stars"
                f"   p_false {sol.p_false:.1e}")
    else:
        text = f"not ok: {sol.reason}"
    cv2.rectangle(canvas, (0, 0), (canvas.shape[1], 24), (0, 0, 0), -1)
    cv2.putText(canvas, text, (6, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.5, white, 1, cv2.LINE_AA)
    return canvas


def _pt(x: float, y: float) -> tuple[int, int]:
    return round(x), round(y)


def _cross(img: NDArray, x: float, y: float, s: int, color: tuple[int, int, int]) -> None:
    cx, cy = _pt(x, y)
    cv2.line(img, (cx - s, cy), (cx + s, cy), color, 1, cv2.LINE_AA)
    cv2.line(img, (cx, cy - s), (cx, cy + s), color, 1, cv2.LINE_AA)
