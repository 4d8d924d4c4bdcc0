"""The ``method="bleif"`` bridge of :class:`starid.Solver`: Bleif's MusterPr reference-star
matcher (:mod:`adfusion.starid.bleif.matcher`), every candidate through the solver's own
verification, as the triad bridge does.

Example:
    >>> from adfusion.starid.solver import Solver
    >>> issubclass(Solver, BleifBridge)
    True
"""

from __future__ import annotations

import numpy as np
from adfusion.starid.identify.solution import Solution
from adfusion.starid.identify.verify import distinct_candidates
from numpy.typing import NDArray

__all__ = ["BleifBridge"]


class BleifBridge:
    """``method="bleif"`` (a mixin of :class:`starid.Solver`)."""

    def _solve_bleif(self, xy: NDArray) -> Solution:
        """Bleif's MusterPr matcher on the brightest detections, each candidate through
        the same verification as a triad match."""
        from adfusion.starid.bleif.matcher import BleifParams, detection_selections, selection_of
        from adfusion.starid.bleif.patterns import PatternCatalog

        params = self.bleif_params or BleifParams()
        if self._bleif_patterns is None:
            self._bleif_patterns = PatternCatalog.build(self.catalog, params.n_stars)
        pc = self._bleif_patterns
        pos = {int(h): k for k, h in enumerate(self.ids)}
        b_all = self.camera.pixels_to_vectors(xy)
        tol = np.radians(2.0 * np.degrees(1.0 / self.camera.K[0, 0]) * params.t_pix)
        n_fit = 0
        for ref, cands, examined in detection_selections(pc, xy, self.camera, params):
            marked = np.array(selection_of(ref, len(xy), params))
            found = []
            for c in cands:
                keep = c.star_index >= 0
                sel, assign = marked[keep], np.array([pos[int(pc.ids[i])]
                                                      for i in c.star_index[keep]])
                ang = np.arccos(np.clip(b_all[sel] @ b_all[sel].T, -1, 1))
                np.fill_diagonal(ang, 0.0)
                chance = (ang, np.full(ang.shape, tol), True)
                quick = self._quick(b_all, None, sel, assign[None], self.camera,
                                    max(1, examined), chance)[0]
                if quick is None or quick[0] > self.p_false_max:
                    continue
                v = self._verify(xy, self.camera, sel, assign, quick, b_all)
                if v is not None and v.p_false <= self.p_false_max:
                    found.append(v)
            n_fit += len(cands)
            found = distinct_candidates(found, 3 * self.tolerance_rad)
            if len(found) == 1:
                return self._solution(found[0], n_fit, f"bleif ref {ref}", found)
            if len(found) > 1:
                return Solution(False, f"ambiguous: {len(found)} distinct attitudes verified",
                                matching_counter=n_fit, path=f"bleif ref {ref}",
                                candidates=sorted(found, key=lambda c: c.p_false))
        return Solution(False, f"bleif: no verified match ({n_fit} pattern candidates)",
                        matching_counter=n_fit, path="bleif")
