"""Operator-in-the-loop identification (Bleif's "StarPatternRecognition" window, §5.2, §5.6).

The operator marks stars in the reduced image (the first is the reference), presses
*Find Match*, and steps through the candidates with their overlays until one fits; the
accepted attitude is *locked* into an estimator. :func:`suggest_stars` picks the stars
from the block list when no operator is at hand (clusters of ≥ 2 adjacent blocks, not the
very large ones, the one nearest the image centre as reference, by
:func:`~starid.bleif.matcher.operator_marks`); :meth:`IdentificationSession.mark_detections`
marks detections (brightest first) by the same rule. ``Solver(method="bleif")`` runs this
session on its detections (``mark_detections``, then :meth:`IdentificationSession.matches`)
and verifies the candidates: both doors give one list.

Example:
    >>> import numpy as np
    >>> from adfusion.starid import rotations as rot
    >>> from adfusion.starid.bleif.matcher import stars_in_frame, tubsat_camera
    >>> from adfusion.starid.bleif.patterns import PatternCatalog
    >>> from adfusion.starid.catalog.stars import Catalog
    >>> pc = PatternCatalog.build(Catalog.hipparcos(mag_limit=6.5))
    >>> cam = tubsat_camera()
    >>> q = rot.q_cam_icrs_from_radec_roll(*np.radians([164.16, 43.53, 76.36]))
    >>> xy, idx = stars_in_frame(pc, cam, q)
    >>> s = IdentificationSession(pc, cam)
    >>> s.select(xy[[np.argmin(np.hypot(*(xy - cam.K[:2, 2]).T)), 0, 1, 2, 3]])
    >>> first = s.next_candidate()                 # the lazy search stops at the first fit
    >>> s.count >= 1, s.accept(first).pattern == first.pattern
    (True, True)
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
from adfusion.starid.bleif.matcher import (
    T_PIX,
    BleifCandidate,
    Overlay,
    find_matches,
    operator_marks,
    overlay,
)
from adfusion.starid.bleif.patterns import PatternCatalog
from adfusion.starid.camera.model import Camera
from numpy.typing import ArrayLike, NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["IdentificationSession", "overlay_png", "suggest_stars"]


class IdentificationSession:
    """One image's identification: marked stars, candidates, the operator's decision.

    ``find_matches()`` is the lazy iterator in catalogue order; :meth:`matches` the
    complete list (:attr:`count` its length). :meth:`next_candidate` / :meth:`reject`
    step through the candidates one at a time, :meth:`accept` ends the search."""

    def __init__(self, patterns: PatternCatalog, camera: Camera,
                 blocks_xy: ArrayLike | None = None, **match_kwargs) -> None:
        self.patterns = patterns
        self.camera = camera
        self.blocks_xy = (np.zeros((0, 2)) if blocks_xy is None
                          else np.asarray(blocks_xy, dtype=np.float64).reshape(-1, 2))
        self.match_kwargs = match_kwargs
        self.stars = np.zeros((0, 2))
        self.accepted: BleifCandidate | None = None
        self.rejected: list[BleifCandidate] = []
        self._reset()

    def _reset(self) -> None:
        self._iter: Iterator[BleifCandidate] | None = None
        self._all: list[BleifCandidate] | None = None
        self.current: BleifCandidate | None = None
        self.accepted = None
        self.rejected = []

    # --- stars -------------------------------------------------------------------------

    def select(self, xy: ArrayLike) -> None:
        """Mark stars (pixels); the first is the reference. Replaces any earlier marks."""
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if not np.isfinite(pts).all():
            raise ValueError("marked star positions must be finite pixel coordinates")
        self.stars = pts
        self._reset()

    def add_star(self, x: float, y: float) -> None:
        """Mark one more star (a mouse click)."""
        self.select(np.vstack([self.stars, [[x, y]]]))

    def clear_stars(self) -> None:
        """"Clear Stars"."""
        self.select(np.zeros((0, 2)))

    def mark_detections(self, xy: ArrayLike, n: int = 10) -> NDArray[np.int64]:
        """Mark star images ``xy`` (brightest first, e.g. detections) as the operator
        would (:func:`~starid.bleif.matcher.operator_marks`: the ``n`` brightest, the
        one nearest the image centre first as the reference); returns the marked
        indices into ``xy`` in marking order (``self.stars`` is ``xy`` at them)."""
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        marks = operator_marks(pts, self.camera, n)
        self.select(pts[marks])
        return marks

    def suggest(self, n: int = 6, **kwargs) -> NDArray[np.float64]:
        """Mark the stars :func:`suggest_stars` picks from the blocks; returns them."""
        xy = suggest_stars(self.blocks_xy, self.camera, n=n, **kwargs)
        self.select(xy)
        return xy

    # --- candidates --------------------------------------------------------------------

    def find_matches(self) -> Iterator[BleifCandidate]:
        """A fresh lazy iterator over the candidates, in catalogue order."""
        return find_matches(self.patterns, self.stars, self.camera, **self.match_kwargs)

    def matches(self) -> list[BleifCandidate]:
        """Every candidate (the search run to the end, once)."""
        if self._all is None:
            self._all = list(self.find_matches())
        return self._all

    @property
    def count(self) -> int:
        return len(self.matches())

    def next_candidate(self) -> BleifCandidate | None:
        """The next candidate to show (None when there are no more)."""
        if self.accepted is not None:
            return None
        if self._iter is None:
            self._iter = self.find_matches()
        self.current = next(self._iter, None)
        return self.current

    def reject(self) -> BleifCandidate | None:
        """Reject the candidate on show and move to the next one."""
        if self.current is not None:
            self.rejected.append(self.current)
        return self.next_candidate()

    def accept(self, candidate: BleifCandidate | None = None) -> BleifCandidate:
        """Confirm a candidate (default: the one on show); the search stops."""
        c = candidate if candidate is not None else self.current
        if c is None:
            raise ValueError("no candidate to accept: call next_candidate() or pass one")
        if c.q_cam_icrs is None:
            raise ValueError(f"candidate has no attitude: {c.problem}")
        self.accepted = c
        self._iter = None
        return c

    def overlay(self, candidate: BleifCandidate | None = None) -> Overlay:
        """The overlay of a candidate (default: the one on show) over this image's blocks."""
        c = candidate if candidate is not None else self.current
        if c is None:
            raise ValueError("no candidate on show")
        return overlay(c, self.patterns, self.camera, self.blocks_xy)

    def overlay_pngs(self, folder: str | Path, limit: int | None = None) -> list[Path]:
        """One overlay PNG per candidate (``candidate-01.png`` …, catalogue order, at most
        ``limit``) in ``folder``, for stepping through them in a notebook or a viewer."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        paths = []
        for k, c in enumerate(self.matches()[:limit]):
            if c.q_cam_icrs is None:
                continue
            paths.append(overlay_png(self.overlay(c), self.camera,
                                     folder / f"candidate-{k + 1:02d}.png", self.blocks_xy))
        return paths

    def lock(self, estimator, t: float):
        """Hand the accepted attitude to an estimator (``adfusion.Estimator.add_fix``) as a
        star fix at time ``t`` with its covariance; returns the estimator's record."""
        c = self.accepted
        if c is None:
            raise ValueError("nothing accepted yet: accept() a candidate before lock()")
        if c.covariance is None:
            raise ValueError("the accepted candidate carries no covariance")
        return estimator.add_fix(t, c.q_cam_icrs, c.covariance, source="operator fix")


def suggest_stars(blocks_xy: ArrayLike, camera: Camera, n: int = 6, link_px: float = 5.0,
                  min_blocks: int = 2, max_blocks: int = 12) -> NDArray[np.float64]:
    """Star positions from a block list (§5.2): blocks closer than ``link_px`` form a
    cluster; clusters of ``min_blocks`` … ``max_blocks`` blocks (single blocks are often
    hot pixels, very large ones have ill-defined centres) are ranked by size, the ``n``
    largest kept, and the one nearest the image centre goes first as the reference
    (:func:`~starid.bleif.matcher.operator_marks`, where the rule's reason is given).

    >>> import numpy as np
    >>> from adfusion.starid.bleif.matcher import tubsat_camera
    >>> b = [[100, 100], [100, 102], [300, 310], [301, 312], [302, 314], [500, 50]]
    >>> suggest_stars(b, tubsat_camera()).round(1).tolist()
    [[301.0, 312.0], [100.0, 101.0]]
    """
    b = np.asarray(blocks_xy, dtype=np.float64).reshape(-1, 2)
    if len(b) == 0:
        return np.zeros((0, 2))
    pairs = cKDTree(b).query_pairs(link_px, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                       shape=(len(b), len(b)))
    k, label = connected_components(graph, directed=False)
    sizes = np.bincount(label, minlength=k)
    good = [c for c in np.argsort(-sizes, kind="stable").tolist()
            if min_blocks <= sizes[c] <= max_blocks][:n]
    if not good:
        return np.zeros((0, 2))
    cent = np.array([b[label == c].mean(axis=0) for c in good])
    return cent[operator_marks(cent, camera, len(cent))]


def overlay_png(ov: Overlay, camera: Camera, path: str | Path,
                blocks_xy: ArrayLike | None = None, image: NDArray | None = None,
                block_size: tuple[int, int] = (4, 1)) -> Path:
    """Draw an overlay (Fig. 4.7) as a PNG: blocks in grey (false blocks red), expected
    star circles sized by brightness — reference light green, other marked stars dark
    green, occupied positions yellow, unoccupied ones blue."""
    import cv2

    h, w = camera.height, camera.width
    canvas = (np.zeros((h, w, 3), np.uint8) if image is None
              else cv2.cvtColor(np.asarray(image, np.uint8), cv2.COLOR_GRAY2BGR))
    blocks = (np.zeros((0, 2)) if blocks_xy is None
              else np.asarray(blocks_xy, dtype=np.float64).reshape(-1, 2))
    false = set(ov.false_blocks.tolist())
    for i, (x, y) in enumerate(blocks.tolist()):
        col = (0, 0, 255) if i in false else (160, 160, 160)
        cv2.rectangle(canvas, (int(x), int(y)), (int(x) + block_size[0] - 1,
                                                 int(y) + block_size[1] - 1), col, -1)
    for (x, y), r, ref, marked, occ in zip(ov.xy.tolist(), ov.radius_px.tolist(),
                                          ov.is_reference.tolist(), ov.is_marked.tolist(),
                                          ov.occupied.tolist(), strict=True):
        col = ((144, 238, 144) if ref else (0, 100, 0) if marked
               else (0, 255, 255) if occ else (255, 128, 0))
        cv2.circle(canvas, (round(x), round(y)), max(1, round(r + T_PIX)), col, 1)
    path = Path(path)
    if not cv2.imwrite(str(path), canvas):
        raise OSError(f"could not write {path}")
    return path
