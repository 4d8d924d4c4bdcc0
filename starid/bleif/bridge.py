"""The ``method="bleif"`` bridge of :class:`starid.Solver`: Bleif's MusterPr reference-star
matcher run as the operator's :class:`~adfusion.starid.bleif.operator.IdentificationSession`
on the detections, every candidate through the solver's own verification, as the triad
bridge does.

One behaviour for both doors: the solver marks the detections as the operator would
(:meth:`IdentificationSession.mark_detections`, the rule in
:func:`~adfusion.starid.bleif.matcher.operator_marks`) and takes that session's candidate
list (:meth:`IdentificationSession.matches`); ``Solution.candidates`` is that list, in its
order, each entry with the catalogue ids the session gives its detections and the
solver's p_false (1.0 for a candidate the projected catalogue does not confirm). The
solver accepts when exactly one distinct attitude among them verifies.

Example:
    >>> from adfusion import starid
    >>> s = starid.Solver(starid.Catalog.hipparcos(mag_limit=4.0),
    ...                   starid.Camera.pinhole(1024, 768, 15.0), method="bleif")
    >>> isinstance(s.bleif, BleifSearch)
    True
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from adfusion.starid.identify.solution import Candidate, Solution, accepted_solution
from adfusion.starid.identify.verify import distinct_candidates
from numpy.typing import NDArray

if TYPE_CHECKING:
    from adfusion.starid.identify.catalog_view import CatalogView
    from adfusion.starid.identify.verify import Verifier

__all__ = ["BleifSearch"]


class BleifSearch:
    """``method="bleif"``: Bleif's reference-star matcher as the operator runs it, then the
    solver's verification.

    Args:
        view: the catalogue (:class:`~adfusion.starid.identify.catalog_view.CatalogView`:
            the catalogue itself, its ids and the camera).
        verifier: the solver's :class:`~adfusion.starid.identify.verify.Verifier`.
        params: Bleif's parameters (:class:`~adfusion.starid.bleif.matcher.BleifParams`;
            ``None``: its defaults).
        p_false_max: the acceptance threshold on the false-match probability.
        tolerance_rad: the pair-distance tolerance (two candidates this close, ×3, are one
            attitude).

    The pattern catalogue is built on the first :meth:`solve`.
    """

    def __init__(self, view: CatalogView, verifier: Verifier, params: Any,
                 p_false_max: float, tolerance_rad: float) -> None:
        self.view = view
        self.verifier = verifier
        self.params = params
        self.p_false_max = p_false_max
        self.tolerance_rad = float(tolerance_rad)
        self.patterns = None

    @property
    def camera(self):
        return self.view.camera

    def solve(self, xy: NDArray) -> Solution:
        """Bleif's MusterPr matcher on the brightest detections, each candidate through
        the same verification as a triad match.

        First the operator's selection (:class:`IdentificationSession` marking the
        detections, strict mode): when it gives candidates, the answer is about them —
        accepted when exactly one distinct attitude verifies, otherwise not ``ok`` with
        the session's list. Only when it gives none (a false star among the marks, which
        the strict mode cannot survive) does the solver re-mark as an operator would:
        other references and tolerant mode (:func:`detection_selections`).

        ``p_false``'s union bound counts the *image-side* selections tried (one per
        reference and set of stars that may be left out), as the n-star search counts
        its detection patterns: the expected number of chance patterns of the
        verification already sums over every catalogue star as the reference."""
        from adfusion.starid.bleif.matcher import BleifParams, detection_selections, selection_of
        from adfusion.starid.bleif.operator import IdentificationSession
        from adfusion.starid.bleif.patterns import PatternCatalog

        params = self.params or BleifParams()
        if self.patterns is None:
            self.patterns = PatternCatalog.build(self.view.catalog, params.n_stars)
        pc = self.patterns
        n = min(params.n_marked, len(xy))
        if n < 3:
            return Solution(False, f"bleif: need ≥ 3 detections to mark, got {len(xy)}",
                            path="bleif")
        b_all = self.camera.pixels_to_vectors(xy)
        session = IdentificationSession(pc, self.camera, t_pix=params.t_pix)
        marks = session.mark_detections(xy, n)
        cands = session.matches()
        path = f"bleif ref {int(marks[0])}"
        trials = 1
        if cands:
            return self._decide(xy, b_all, marks, cands, trials, params, len(cands),
                                      path)
        n_fit = 0
        for ref, k_miss, more, _ in detection_selections(pc, xy, self.camera, params,
                                                         operator_round=False):
            trials += sum(math.comb(n - 1, j) for j in range(k_miss + 1))
            n_fit += len(more)
            if not more:
                continue
            marked = np.array(selection_of(ref, len(xy), params))
            sol = self._decide(xy, b_all, marked, more, trials, params, n_fit,
                                     f"bleif ref {ref} k_miss {k_miss}")
            if sol.ok or sol.reason.startswith("ambiguous"):
                return sol
        return Solution(False, f"bleif: no verified match ({n_fit} pattern candidates "
                               "after the operator's selection gave none)",
                        matching_counter=n_fit, path="bleif")

    def _decide(self, xy: NDArray, b_all: NDArray, marked: NDArray, cands: list,
                      trials: int, params, n_fit: int, path: str) -> Solution:
        """The solver's verification of one selection's candidates (``marked``: the
        detection of each marked star, in marking order) and its answer, the candidates
        listed in the selection's order."""
        pos = {int(h): k for k, h in enumerate(self.view.ids)}
        pc = self.patterns
        tol = np.radians(2.0 * np.degrees(1.0 / self.camera.K[0, 0]) * params.t_pix)
        listed: list[Candidate] = []
        for c in cands:
            keep = c.star_index >= 0
            sel = marked[keep]
            assign = np.array([pos[int(pc.ids[i])] for i in c.star_index[keep]])
            ang = np.arccos(np.clip(b_all[sel] @ b_all[sel].T, -1, 1))
            np.fill_diagonal(ang, 0.0)
            chance = (ang, np.full(ang.shape, tol), True)
            quick = self.verifier.quick(b_all, None, sel, assign[None], self.camera, trials,
                                chance)[0]
            v, p_false = None, 1.0 if quick is None else float(quick[0])
            if quick is not None and p_false <= self.p_false_max:
                v = self.verifier.verify(xy, self.camera, sel, assign, quick, b_all)
                if v is None or v.p_false > self.p_false_max:
                    v, p_false = None, 1.0 if v is None else v.p_false
            if v is None:  # not verified: the session's candidate, as the session gives it
                v = Candidate(
                    q_cam_icrs=c.q_cam_icrs,
                    matches=[(int(marked[d]), h) for d, h in c.matches],
                    residuals_rad=c.residuals_rad[keep], p_false=p_false,
                    n_pattern=len(sel), camera=self.camera, covariance=c.covariance,
                    _projector=self.view.project)
            listed.append(v)
        good = [v for v in listed if v.p_false <= self.p_false_max]
        found = distinct_candidates(good, 3 * self.tolerance_rad)
        if len(found) == 1:
            return accepted_solution(found[0], n_fit, path, listed)
        if len(found) > 1:
            return Solution(False, f"ambiguous: {len(found)} distinct attitudes verified",
                            matching_counter=n_fit, path=path, candidates=listed)
        best = min(v.p_false for v in listed)
        return Solution(False, f"bleif: none of the {len(listed)} candidates of the "
                               f"selection verified (best p_false {best:.2g} > "
                               f"{self.p_false_max:.0e})",
                        matching_counter=n_fit, path=path, candidates=listed)
