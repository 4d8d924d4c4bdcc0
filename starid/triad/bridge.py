"""The ``method="triad"`` bridge of :class:`starid.Solver`: Yee's triad identification
(:mod:`starid.triad.identify`) followed by the solver's own verification.

Example:
    >>> from adfusion.starid.solver import Solver
    >>> issubclass(Solver, TriadBridge)
    True
"""

from __future__ import annotations

import numpy as np
from adfusion.starid.identify.solution import Solution
from numpy.typing import NDArray

__all__ = ["TriadBridge"]


class TriadBridge:
    """``method="triad"`` (a mixin of :class:`starid.Solver`)."""

    def _solve_triad(self, xy: NDArray) -> Solution:
        """Yee's triad method (:mod:`starid.triad.identify`), then our verification: Yee's voting
        can accept a false 3-star match (a mirror image, a close double), so the result
        must also pass the false-match probability test like any n-star candidate."""
        from adfusion.starid.triad.database import SeparationDatabase, TriadParams
        from adfusion.starid.triad.identify import identify_triads

        params = self.triad_params or TriadParams()
        if self._triad_db is None:
            self._triad_db = SeparationDatabase.build(
                self.catalog, self.camera.diagonal_fov_deg + params.tol_sep_deg)
        res = identify_triads(xy, self.camera, self.catalog, params, self._triad_db)
        if not res.ok:
            return Solution(False, f"triad: {res.reason}", path="triad")
        pos = {int(h): k for k, h in enumerate(self.ids)}
        pairs = sorted({(int(d), pos[int(h)]) for d, h in res.matches})
        used_cat: set[int] = set()
        sel_l, assign_l = [], []
        for d, c in pairs:  # a resolved double maps twice onto a merged star: keep one
            if c not in used_cat:
                used_cat.add(c)
                sel_l.append(d)
                assign_l.append(c)
        if len(sel_l) < 3:
            return Solution(False, "triad: fewer than 3 distinct matched stars", path="triad")
        sel, assign = np.array(sel_l), np.array(assign_l)
        b_all = self.camera.pixels_to_vectors(xy)
        b = b_all[sel]
        ang = np.arccos(np.clip(b @ b.T, -1, 1))
        np.fill_diagonal(ang, 0.0)
        n_img = min(len(xy), params.max_stars)
        trials = max(1, n_img * (n_img - 1) * (n_img - 2) // 6)  # every image triangle
        chance = (ang, np.full(ang.shape, np.radians(params.tol_sep_deg)), True)
        quick = self._quick(b_all, None, sel, assign[None], self.camera, trials, chance)[0]
        if quick is None:
            return Solution(False, "triad: match not confirmed by the projected catalogue",
                            path="triad")
        if quick[0] > self.p_false_max:
            return Solution(False, f"insufficient evidence: triad match p_false "
                                   f"{quick[0]:.2g} > {self.p_false_max:.0e}", path="triad")
        cand = self._verify(xy, self.camera, sel, assign, quick)
        if cand is None or cand.p_false > self.p_false_max:
            return Solution(False, "triad: match failed full verification", path="triad")
        return self._solution(cand, 1, "triad", [cand])
