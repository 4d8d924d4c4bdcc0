"""Candidates of a lost-in-space frame: made from the compiled search's packed result, and
resolved by their evidence when several verify.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from adfusion.starid.camera.model import Camera
from adfusion.starid.identify import frame_kernels
from adfusion.starid.identify.solution import Candidate, Solution, made
from numpy.typing import NDArray

__all__ = ["EVIDENCE_RATIO", "SHARED_FRACTION", "resolve_by_evidence"]


#: the best candidate wins over the others when its p_false is this many times smaller
EVIDENCE_RATIO = 1e6


#: ... or when every other shares at least this fraction of its (detection, star) pairs
SHARED_FRACTION = 0.5


def resolve_by_evidence(cands: list[Candidate]) -> tuple[Candidate | None, str]:
    """Of several verified, distinct attitudes: the best one and a note, when the evidence
    decides — each other candidate either p_false :data:`EVIDENCE_RATIO` times weaker, or
    sharing most of its star pairs with the best (a near-duplicate with a neighbour
    swapped in) — else (None, "") for genuine ambiguity.

    >>> import numpy as np
    >>> from adfusion.starid.identify.solution import Candidate
    >>> def c(p, m):
    ...     return Candidate(np.array([1.0, 0, 0, 0]), m, np.zeros(len(m)), p, 3, None,
    ...                      np.eye(3))
    >>> best, note = resolve_by_evidence([c(4e-54, [(i, i) for i in range(29)]),
    ...                                   c(2e-12, [(i, i + 100) for i in range(11)])])
    >>> best.p_false, note.split(":")[0]
    (4e-54, 'best of 2 candidates')
    >>> resolve_by_evidence([c(1e-9, [(0, 1), (1, 2), (2, 3)]), c(1e-8, [(0, 5), (1, 6),
    ...                                                               (2, 7)])])[0] is None
    True
    """
    ranked = sorted(cands, key=lambda c: c.p_false)
    best, others = ranked[0], ranked[1:]
    pairs = set(best.matches)
    reasons = []
    for o in others:
        shared = len(pairs & set(o.matches)) / max(1, min(len(pairs), len(o.matches)))
        if o.p_false >= EVIDENCE_RATIO * best.p_false:
            reasons.append(f"p_false {o.p_false:.2g} vs {best.p_false:.2g}")
        elif shared >= SHARED_FRACTION:
            reasons.append(f"{shared:.0%} of its stars shared")
        else:
            return None, ""
    return best, (f"best of {len(cands)} candidates: the others weaker by the evidence "
                  f"({'; '.join(reasons)})")


def _candidate(det: list[int], ids: list[int], q: NDArray, cov: NDArray, res: NDArray,
               p_false: float, n_pattern: int, cam: Camera, project: Callable) -> Candidate:
    """A verified candidate of the compiled path: pairs detection → catalogue id."""
    return made(Candidate, {
        "q_cam_icrs": q, "matches": list(zip(det, ids, strict=True)), "residuals_rad": res,
        "p_false": p_false, "n_pattern": n_pattern, "camera": cam, "covariance": cov,
        "_projector": project})


def _refitted(refit: tuple, counter: int, p_false: float, path: str,
              found: list[Candidate], cam: Camera, time_s: float = 0.0, n: int = 0,
              tried: int = 0) -> Solution:
    """The solution of one accepted attitude (its candidate's ``p_false``) refitted in the
    kernel (``refit``: :func:`starid.identify.frame_kernels.unpack`'s, status 1), with the solve's
    time, detections and trials when they are known."""
    _, d, h, rq, rcov, rres, sigma_px, rejected = refit
    return made(Solution, {
        "ok": True, "reason": "", "q_cam_icrs": rq, "matches": list(zip(d, h, strict=True)),
        "matching_counter": counter, "covariance": rcov, "mode": "lost-in-space",
        "time_s": time_s, "p_false": p_false, "path": path, "candidates": found,
        "residuals_rad": rres, "camera": cam, "n_detections": n, "patterns_tried": tried,
        "sigma_px": sigma_px,
        "note": f"{rejected} pair(s) rejected by the residuals" if rejected else "",
        "n_predicted": 0})


def _accepted(every: list[int], floats: NDArray[np.float64], cam: Camera,
              project: Callable, paths: list[str], n: int, t0: float) -> Solution:
    """The :class:`Solution` of a frame whose compiled call accepted one attitude and
    refitted it, read straight from :func:`starid.identify.frame_kernels.solve_frame_packed`'s
    arrays (``every``: the integers as a list) — the refit's pairs, attitude, covariance
    and residuals, the accepted candidate's p_false — without :func:`starid.identify.frame_kernels.
    unpack`'s intermediate tuples. ``paths``: the path of each of the frame's patterns.
    The candidate list is made when it is first read (:meth:`Solution.__getattr__`,
    :func:`_candidates_of`): most callers never read it, and making it was ~4 µs of a
    ~70 µs frame in cold caches (docs/benchmarks.md, "The candidate list on first use")."""
    counter, n_acc, _, n_sel, _, rejected, m, _, pattern, tried = \
        every[1:frame_kernels.PACKED_HEADER]
    o = frame_kernels.PACKED_HEADER + n_sel + n_acc  # the refit's pairs
    d, h = every[o:o + m], every[o + m:o + 2 * m]
    p_false, sigma_px = floats[13 + m:15 + m].tolist()
    return made(Solution, {
        "ok": True, "reason": "", "q_cam_icrs": floats[:4],
        "matches": list(zip(d, h, strict=True)), "matching_counter": counter,
        "covariance": floats[4:13].reshape(3, 3), "mode": "lost-in-space",
        "time_s": time.perf_counter() - t0, "p_false": p_false, "path": paths[pattern],
        "_candidates_from": (_candidates_of, every, floats, n_sel, cam, project),
        "residuals_rad": floats[13:13 + m], "camera": cam, "n_detections": n,
        "patterns_tried": tried, "sigma_px": sigma_px,
        "note": f"{rejected} pair(s) rejected by the residuals" if rejected else "",
        "n_predicted": 0})


def _candidates_of(every: list[int], floats: NDArray[np.float64], n_pattern: int,
                   cam: Camera, project: Callable) -> list[Candidate]:
    """The verified candidates of :func:`starid.identify.frame_kernels.solve_frame_packed`'s arrays
    (the integers as a list; of a pattern of ``n_pattern`` stars): a :class:`Solution`'s
    ``candidates``."""
    return [_candidate(*c, n_pattern, cam, project)
            for c in frame_kernels.unpack(np.array(every, dtype=np.int64), floats)[5]]
