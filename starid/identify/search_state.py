"""A lost-in-space search's state: detections as directions, their pair windows
(:class:`PairWindows`), the search's progress (:class:`Search`) and the input check's bounds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from adfusion.starid.camera.model import Camera
from adfusion.starid.identify import kernels
from adfusion.starid.identify.nstar import (
    Pattern,
    chirality_of,
)
from numpy.typing import NDArray

__all__ = ["PairWindows", "Search"]


def input_bounds(cam: Camera) -> tuple[float, float, float]:
    """The input check's frame (:func:`starid.identify.frame_kernels.input_problem`): width, height
    and how far outside it (px) a detection the search uses is refused as far outside —
    half the longer side."""
    return float(cam.width), float(cam.height), 0.5 * max(cam.width, cam.height)


def directions(cam: Camera, xy: NDArray) -> NDArray[np.float64]:
    """``cam.pixels_to_vectors(xy)``, for an ideal pinhole compiled (the arithmetic of
    :func:`starid.identify.frame_kernels.solve_frame` and the final refit, to the last bit; numpy's
    matrix product may round differently).

    >>> import numpy as np
    >>> cam = Camera.pinhole(1024, 768, 15.0)
    >>> xy = np.array([[0.0, 0.0], [511.5, 383.5]])
    >>> bool(np.allclose(directions(cam, xy), cam.pixels_to_vectors(xy), atol=1e-15))
    True
    """
    ideal = cam._ideal_pinhole
    if ideal is None:
        return cam.pixels_to_vectors(xy)
    return kernels._to_vectors(np.ascontiguousarray(xy, dtype=np.float64), ideal[0],
                               ideal[1])


@dataclass(frozen=True)
class PairWindows:
    """The matching windows of every detection pair at one focal guess: a pattern's are a
    sub-matrix (the same values :func:`_pattern` computes, without per-pattern work)."""

    angles: NDArray[np.float64]  # (N, N) pair angles, 0 on the diagonal
    tol: NDArray[np.float64]  # (N, N) window half-widths
    hi: NDArray[np.float64]  # (N, N) upper window edges (angles)
    cos_min: NDArray[np.float64]
    cos_max: NDArray[np.float64]

    @classmethod
    def of(cls, b_all: NDArray, tolerance_rad: float, rel_tol: float) -> PairWindows:
        # compiled (kernels.pair_windows): the compiled search computes each pattern's
        # windows with the same formula, so the two agree to the last bit
        return cls(*kernels.pair_windows(np.ascontiguousarray(b_all, dtype=np.float64),
                                         float(tolerance_rad), float(rel_tol)))

    def pattern(self, sel: NDArray, b_all: NDArray) -> tuple[Pattern, NDArray[np.float64]]:
        """The :class:`Pattern` of detections ``sel`` (in matching order) and its windows'
        half-widths."""
        ix = (sel[:, None], sel)
        tol = self.tol[ix]
        chir = chirality_of(b_all[sel], 2.0 * float(tol.max())) if len(sel) >= 3 else 0
        return Pattern(self.angles[ix], self.cos_min[ix], self.cos_max[ix], chir,
                       float(self.hi[ix].max())), tol


@dataclass
class Search:
    """What a solve's search has counted so far (see :meth:`PatternSearch.solve_at`)."""

    tried: int = 0  # (pattern, focal guess) trials
    first_counter: int | None = None  # matching_counter of the first pattern matched
    budget_note: str = ""  # the last budget event
    # (quick p_false, sel, assignment, path, focal guess, trial) of candidates too weak
    weak: list[tuple] = field(default_factory=list)
    # the same from kernels.search: (p_false (W,), rows (W, 20), paths), unpacked on demand
    weak_rows: list[tuple] = field(default_factory=list)

    def best_weak(self, k: int) -> list[tuple]:
        """The ``k`` weak candidates with the lowest quick p_false (ties: first found)."""
        if not self.weak_rows:
            return sorted(self.weak, key=lambda w: w[0])[:k]
        p = np.concatenate([w[0] for w in self.weak_rows])
        rows = np.concatenate([w[1] for w in self.weak_rows])
        paths = self.weak_rows[-1][2]  # the latest list: the longest, the others its prefixes
        out = []
        for o in np.argsort(p, kind="stable")[:k].tolist():
            pos, ci, trial, n = rows[o, :4].tolist()
            out.append((float(p[o]), rows[o, 4:4 + n].copy(), rows[o, 12:12 + n].copy(),
                        paths[pos], ci, trial))
        return out
