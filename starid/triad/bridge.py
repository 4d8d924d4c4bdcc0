"""The ``method="triad"`` bridge of :class:`starid.Solver`: Yee's triad identification
(:mod:`starid.triad.identify`) followed by the solver's own verification.

Example:
    >>> from adfusion import starid
    >>> s = starid.Solver(starid.Catalog.hipparcos(mag_limit=4.0),
    ...                   starid.Camera.pinhole(1024, 768, 15.0), method="triad")
    >>> isinstance(s.triad, TriadSearch)
    True
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from adfusion.starid.identify.solution import Solution, accepted_solution
from numpy.typing import NDArray

if TYPE_CHECKING:
    from adfusion.starid.identify.catalog_view import CatalogView
    from adfusion.starid.identify.verify import Verifier

__all__ = ["TriadSearch"]


class TriadSearch:
    """``method="triad"``: Yee's triad identification, then the solver's verification.

    Args:
        view: the catalogue (:class:`~adfusion.starid.identify.catalog_view.CatalogView`:
            the catalogue itself, its ids and the camera).
        verifier: the solver's :class:`~adfusion.starid.identify.verify.Verifier`.
        params: the triad's parameters (:class:`~adfusion.starid.triad.database.TriadParams`;
            ``None``: its defaults).
        p_false_max: the acceptance threshold on the false-match probability.

    The separation database is built on the first :meth:`solve`.
    """

    def __init__(self, view: CatalogView, verifier: Verifier, params: Any,
                 p_false_max: float) -> None:
        self.view = view
        self.verifier = verifier
        self.params = params
        self.p_false_max = p_false_max
        self.db = None

    def solve(self, xy: NDArray) -> Solution:
        """Yee's triad method (:mod:`starid.triad.identify`), then our verification: Yee's voting
        can accept a false 3-star match (a mirror image, a close double), so the result
        must also pass the false-match probability test like any n-star candidate."""
        from adfusion.starid.triad.database import SeparationDatabase, TriadParams
        from adfusion.starid.triad.identify import identify_triads

        params = self.params or TriadParams()
        catalog, camera = self.view.catalog, self.view.camera
        if self.db is None:
            self.db = SeparationDatabase.build(
                catalog, camera.diagonal_fov_deg + params.tol_sep_deg)
        res = identify_triads(xy, camera, catalog, params, self.db)
        if not res.ok:
            return Solution(False, f"triad: {res.reason}", path="triad")
        pos = {int(h): k for k, h in enumerate(self.view.ids)}
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
        b_all = camera.pixels_to_vectors(xy)
        b = b_all[sel]
        ang = np.arccos(np.clip(b @ b.T, -1, 1))
        np.fill_diagonal(ang, 0.0)
        n_img = min(len(xy), params.max_stars)
        trials = max(1, n_img * (n_img - 1) * (n_img - 2) // 6)  # every image triangle
        chance = (ang, np.full(ang.shape, np.radians(params.tol_sep_deg)), True)
        quick = self.verifier.quick(b_all, None, sel, assign[None], camera, trials,
                                    chance)[0]
        if quick is None:
            return Solution(False, "triad: match not confirmed by the projected catalogue",
                            path="triad")
        if quick[0] > self.p_false_max:
            return Solution(False, f"insufficient evidence: triad match p_false "
                                   f"{quick[0]:.2g} > {self.p_false_max:.0e}", path="triad")
        cand = self.verifier.verify(xy, camera, sel, assign, quick)
        if cand is None or cand.p_false > self.p_false_max:
            return Solution(False, "triad: match failed full verification", path="triad")
        return accepted_solution(cand, 1, "triad", [cand])
