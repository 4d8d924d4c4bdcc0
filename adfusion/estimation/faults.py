"""Fault injection for robustness studies: a solver that sometimes lies.

A filter or smoother is only as good as its handling of the rare wrong star match that
passes verification. :class:`WrongMatchInjector` wraps a :class:`starid.Solver` and plants
one such match on every ``every``-th identified frame, so a study can count how often the
estimator catches it (the smoother benchmark and its tests do).

Example:
    >>> from adfusion import starid
    >>> s = WrongMatchInjector(starid.Solver(starid.Catalog.hipparcos(mag_limit=4.0),
    ...                                      starid.Camera.pinhole(1024, 768, 15.0)), every=50)
    >>> s.wrong
    []
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from adfusion.maths.attitude import wahba

__all__ = ["WrongMatchInjector"]


class WrongMatchInjector:
    """A solver whose every ``every``-th identified frame (≥ 3 matches) carries one wrong
    star match.

    The frame's first (brightest) match is re-paired with the nearest other catalogue star
    not already matched, and the fix is refitted (Wahba) with the wrong pair, keeping the
    solver's covariance — as a wrong match that passed verification would look.
    ``wrong`` lists the catalogue ids planted, in order. ``camera`` and ``catalog`` are the
    wrapped solver's, so it stands in for the solver wherever one is expected.
    """

    def __init__(self, solver: Any, every: int = 50) -> None:
        if every < 1:
            raise ValueError(f"every must be ≥ 1, got {every}")
        self.solver, self.every = solver, int(every)
        self.camera, self.catalog = solver.camera, solver.catalog
        self._vec = np.asarray(solver.catalog.vectors)
        self._ids = np.asarray(solver.catalog.ids)
        self._row = {int(i): k for k, i in enumerate(self._ids)}
        self.count = 0
        self.wrong: list[int] = []

    def solve(self, detections: Any, prior: Any = None) -> Any:
        """:meth:`starid.Solver.solve`, with the planted match on every ``every``-th
        identified frame."""
        sol = self.solver.solve(detections, prior=prior)
        if not sol.ok or len(sol.matches) < 3:
            return sol
        self.count += 1
        if self.count % self.every:
            return sol
        xy = np.asarray(getattr(detections, "xy", detections), dtype=np.float64)[:, :2]
        matches = list(sol.matches)
        d0, id0 = matches[0]
        dots = self._vec @ self._vec[self._row[int(id0)]]
        dots[[self._row[int(i)] for _, i in matches]] = -2.0
        wrong = int(self._ids[int(np.argmax(dots))])
        matches[0] = (d0, wrong)
        self.wrong.append(wrong)
        cam = sol.camera if sol.camera is not None else self.camera
        b = cam.pixels_to_vectors(xy[[d for d, _ in matches]])
        r = self._vec[[self._row[int(i)] for _, i in matches]]
        fit = wahba(b, r, sigma_rad=cam.pixel_scale_rad)
        return dataclasses.replace(sol, matches=matches, q_cam_icrs=fit.q_cam_icrs)
