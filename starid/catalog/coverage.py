"""Uniform sky coverage: the brightest stars of each sky cell, for deep catalogues.

A deep catalogue (Hipparcos to V 9 holds 83 000 stars, 5× denser in the Milky Way than
near the galactic poles) makes the pattern index grow with the square of the local
density. A camera only needs the stars it can tell apart from the background of chance
matches: some tens per field of view. :func:`uniform_coverage` keeps the brightest
``stars_per_fov`` per field-sized patch of sky, so the index is bounded for any
magnitude limit (≈ ``stars_per_fov`` × fields on the sky stars, each with about
``6.5 × stars_per_fov`` neighbours within a 4:3 field's diagonal, π·diag² over the field's
area: 6.4 M pairs for 30 a field of 6°×4.5°), and fields in sparse
regions keep every star they have — the same idea as tetra3's and cedar-solve's
"uniform" catalogue selection, done here with fixed cells instead of a greedy pass.

Cells: an equiangular cubed sphere (each cube face divided evenly in angle, so cells vary
in area by less than ±30 %), about half a field high, so that any field covers four or
more of them and its star count varies little with where it falls on the grid.

Example:
    >>> from adfusion.starid import Camera
    >>> from adfusion.starid.catalog.stars import Catalog
    >>> from adfusion.starid.catalog.coverage import uniform_coverage
    >>> cat = Catalog.hipparcos(mag_limit=9.0)
    >>> sel = uniform_coverage(cat, Camera.pinhole(1280, 960, 6.0), stars_per_fov=30)
    >>> len(cat), len(sel)
    (83393, 54499)
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["DEFAULT_STARS_PER_FOV", "catalog_for_camera", "coverage_indices", "sky_cells",
           "uniform_coverage"]

#: Stars kept per field of view: as many as the detections the solver considers (30);
#: benchmarks/bench_deep_index.py measures identification against it (0 wrong).
DEFAULT_STARS_PER_FOV = 30
_CELLS_PER_FIELD_SIDE = 2  # cells along the field's short side


def sky_cells(vectors: ArrayLike, n_side: int) -> NDArray[np.int64]:
    """Cell number (0 … 6·n_side² − 1) of each unit vector on an equiangular cubed sphere.

    >>> sky_cells([[1, 0, 0], [0, 0, -1], [1, 1e-9, 0]], 4).tolist()
    [10, 90, 10]
    """
    v = np.asarray(vectors, dtype=np.float64).reshape(-1, 3)
    if not isinstance(n_side, int | np.integer) or n_side < 1:
        raise ValueError(f"n_side must be a positive integer, got {n_side!r}")
    axis = np.argmax(np.abs(v), axis=1)
    rows = np.arange(len(v))
    major = v[rows, axis]
    face = axis * 2 + (major < 0)  # +x, −x, +y, −y, +z, −z
    # the two other components over the major one: the tangent of the angle on the face
    ua = v[rows, (axis + 1) % 3] / np.abs(major)
    ub = v[rows, (axis + 2) % 3] / np.abs(major)
    # equal steps in angle (atan) give cells of nearly equal area
    ia = np.clip(((np.arctan(ua) / (math.pi / 4) + 1) / 2 * n_side).astype(np.int64), 0,
                 n_side - 1)
    ib = np.clip(((np.arctan(ub) / (math.pi / 4) + 1) / 2 * n_side).astype(np.int64), 0,
                 n_side - 1)
    return (face * n_side + ia) * n_side + ib


def coverage_indices(vectors: ArrayLike, mag: ArrayLike, cell_side_rad: float,
                     per_cell: int) -> NDArray[np.int64]:
    """Ascending indices of the ``per_cell`` brightest stars of each sky cell.

    Cells are about ``cell_side_rad`` across (:func:`sky_cells`); ties in magnitude keep
    the earlier star.

    >>> import numpy as np
    >>> v = [[1, 0, 0], [1, 0.001, 0], [1, 0.002, 0], [0, 1, 0]]
    >>> coverage_indices(v, [3.0, 1.0, 2.0, 5.0], np.radians(5), 2).tolist()
    [1, 2, 3]
    """
    m = np.asarray(mag, dtype=np.float64).ravel()
    if not (cell_side_rad > 0 and math.isfinite(cell_side_rad)):
        raise ValueError(f"cell_side_rad must be positive, got {cell_side_rad}")
    if per_cell < 1:
        raise ValueError(f"per_cell must be ≥ 1, got {per_cell}")
    n_side = max(1, math.ceil((math.pi / 2) / cell_side_rad))
    cell = sky_cells(vectors, n_side)
    if len(cell) != len(m):
        raise ValueError(f"{len(cell)} vectors but {len(m)} magnitudes")
    order = np.lexsort((np.arange(len(m)), m, cell))  # by cell, brightest first
    c = cell[order]
    start = np.r_[0, np.flatnonzero(c[1:] != c[:-1]) + 1]  # first entry of each cell
    rank = np.arange(len(c)) - np.repeat(start, np.diff(np.r_[start, len(c)]))
    return np.sort(order[rank < per_cell])


def uniform_coverage(catalog, camera, stars_per_fov: int = DEFAULT_STARS_PER_FOV):
    """The catalogue's brightest stars, about ``stars_per_fov`` per field of ``camera``.

    ``catalog`` is a :class:`starid.Catalog` (its :meth:`~starid.Catalog.select` makes
    the result), ``camera`` anything with ``fov_x_deg`` and ``fov_y_deg``. Fields with
    fewer stars keep all of them; the result never exceeds ``6·n² · per_cell`` stars
    whatever the magnitude limit (n cells along a cube edge).

    >>> from adfusion.starid import Camera
    >>> from adfusion.starid.catalog.stars import Catalog
    >>> cam = Camera.pinhole(1280, 960, 6.0)
    >>> deep = uniform_coverage(Catalog.hipparcos(mag_limit=99.0), cam, 40)
    >>> len(deep) <= len(uniform_coverage(Catalog.hipparcos(mag_limit=99.0), cam, 80))
    True
    """
    if isinstance(stars_per_fov, bool) or int(stars_per_fov) != stars_per_fov \
            or stars_per_fov < 1:
        raise ValueError(f"stars_per_fov must be a positive integer, got {stars_per_fov!r}")
    fx, fy = math.radians(camera.fov_x_deg), math.radians(camera.fov_y_deg)
    side = min(fx, fy) / _CELLS_PER_FIELD_SIDE
    cells_per_field = fx * fy / side**2
    per_cell = max(1, math.ceil(stars_per_fov / cells_per_field))
    return catalog.select(coverage_indices(catalog.vectors, catalog.mag, side, per_cell))


def catalog_for_camera(catalog, camera, stars_per_fov: int = DEFAULT_STARS_PER_FOV):
    """``catalog`` thinned by :func:`uniform_coverage` when it is deep for this field —
    more than ``stars_per_fov`` stars in an average field — else unchanged.

    The command line's default: a shallow catalogue keeps every star (the behaviour and
    figures of a V 6.5 catalogue on an 11° camera do not change), a deep one is bounded.

    >>> from adfusion.starid import Camera
    >>> from adfusion.starid.catalog.stars import Catalog
    >>> cat = Catalog.hipparcos(mag_limit=6.5)
    >>> len(catalog_for_camera(cat, Camera.pinhole(1024, 768, 11.4))) == len(cat)
    True
    >>> len(catalog_for_camera(cat, Camera.pinhole(1024, 768, 40.0))) < len(cat)
    True
    """
    fx, fy = math.radians(camera.fov_x_deg), math.radians(camera.fov_y_deg)
    per_field = len(catalog) * fx * fy / (4 * math.pi)
    if per_field <= stars_per_fov:
        return catalog
    return uniform_coverage(catalog, camera, stars_per_fov)
