"""Catalogue triangles by their sorted sides: a pattern's first three stars matched by a
look-up instead of a scan of three pair windows.

Why: a lost-in-space trial begins with the assignments of its pattern's first three stars
(:func:`starid.identify.kernels._triangles`), a scan of the three pair windows — ~600, 1 200 and
1 200 catalogue pairs for Hipparcos to V 6 in a 15° field, ~37 µs a trial on the
benchmark machine. A frame of noise spends its whole budget (200 trials) so. Every
catalogue triangle whose three sides are pairs of the pattern index, filed by the cells
of its sorted side angles, turns that into a look-up of a few cells: ~5 µs, the same
rows in the same order (docs/concepts/identification.md, "Triangles looked up").

The table holds the triangles of the pattern index itself (its neighbour rows and their
stored cosines), so it depends on nothing else; it is built once per index (~6 s for
13 million triangles, ~113 MiB for V < 6 in a 15° field) and kept in the cache beside it.
Past :func:`max_bytes` (a denser catalogue, a wider field) there is none, and the search
scans the windows as before.

Example:
    >>> import numpy as np
    >>> from adfusion.starid.catalog.pair_index import PatternIndex
    >>> v = np.random.default_rng(1).normal(size=(300, 3))
    >>> v /= np.linalg.norm(v, axis=1)[:, None]
    >>> t = triangle_table(PatternIndex.from_vectors(v, 0.5), 1e-3)
    >>> t["tri"].shape[1], int(t["offs"][-1]) == len(t["tri"])
    (4, True)
"""

from __future__ import annotations

import math

import numpy as np
from adfusion.starid.catalog.cache import cached_arrays, env_size_bytes
from adfusion.starid.catalog.pair_index import INDEX_LAYOUT, PatternIndex
from adfusion.starid.jit_cache import njit_cached

__all__ = ["CELLS_MAX", "DEFAULT_MAX_MB", "cell_rad_for", "estimate_triangles", "max_bytes",
           "triangle_table", "triangles_for"]

_jit = njit_cached(nogil=True)

#: the table's bound (MiB) by default; past it, no table (the pair windows are scanned).
#: 340: the catalogues and fields that had a table at 6 bytes a row under 256 MiB keep it
#: at 8 (the sides' quanta)
DEFAULT_MAX_MB = 340.0
#: cells per side angle at most (the cell table has ~CELLS_MAX³/6 entries)
CELLS_MAX = 300
TRIANGLE_LAYOUT = 2  # bump when the stored arrays change
#: a triangle's sorted sides are stored within their cells to 1/QUANTA of a cell (5 bits
#: each, packed in the row's fourth 16-bit word): the look-up skips a triangle whose sides
#: miss the windows without reading its stars' vectors (random reads: most of a cold
#: look-up's time)
QUANTA = 32


def max_bytes() -> int:
    """The table's bound: ``$ADFUSION_TRIANGLES_MAX_MB`` MiB (default 340; 0: never a
    table).

    >>> max_bytes() > 0
    True
    """
    return env_size_bytes("ADFUSION_TRIANGLES_MAX_MB", DEFAULT_MAX_MB, "MiB", 2**20, True)


def cell_rad_for(tolerance_rad: float, max_sep_rad: float) -> float:
    """The cells' width: the match tolerance (a pattern's windows, two tolerances wide,
    then reach into ~3 cells per side), no finer than ``max_sep_rad`` / :data:`CELLS_MAX`.
    Twice the tolerance read ~8× as many triangles a cell: at σ = 2 px (wide windows) a
    look-up read thousands, and those frames took ~5 % longer in the benchmark; four and
    six tolerances were slower still (docs/benchmarks.md, "Cold and hot").

    >>> round(cell_rad_for(1e-3, 0.3), 6), round(cell_rad_for(1e-5, 0.3), 6)
    (0.001, 0.001)
    """
    return max(tolerance_rad, max_sep_rad / CELLS_MAX)


def estimate_triangles(index: PatternIndex) -> int:
    """About how many triangles ``index`` holds: every two neighbours of a star, of which
    ~59 % lie within the index's reach of each other (two random points in a disc of
    radius R are within R of each other with probability 1 − 3√3/4π), each triangle
    counted at its three corners."""
    deg = np.diff(index.nbr_ptr).astype(np.float64)
    return int(np.sum(deg * (deg - 1) / 2) * (1 - 3 * math.sqrt(3) / (4 * math.pi)) / 3)


@_jit
def _cell(c1, c2, c3):
    """The cell of sorted side cells c1 ≤ c2 ≤ c3 (a tetrahedral numbering)."""
    return c3 * (c3 + 1) * (c3 + 2) // 6 + c2 * (c2 + 1) // 2 + c1


@_jit
def _sorted3(a, b, c):
    if a > b:
        a, b = b, a
    if b > c:
        b, c = c, b
    if a > b:
        a, b = b, a
    return a, b, c


@_jit
def _quantum(u, c):
    """Where side u (in cells) lies within its cell c: 0 … QUANTA − 1."""
    return min(max(int((u - c) * QUANTA), 0), QUANTA - 1)


@_jit
def _walk(nbr_ptr, nbr_idx, nbr_ang, h, n, counts, tri, fill):
    """Every triangle i < j < k of the index's pairs, by the cell of its sorted stored side
    angles: counted into ``counts[cell + 1]`` or, with ``fill``, written at
    ``counts[cell]`` (advanced) with its sides' quanta (:data:`QUANTA`)."""
    n_star = len(nbr_ptr) - 1
    ang_i = np.full(n_star, -1.0)  # angle (i, k) of star i's neighbours k
    for i in range(n_star):
        for e in range(nbr_ptr[i], nbr_ptr[i + 1]):
            ang_i[nbr_idx[e]] = nbr_ang[e]
        for e in range(nbr_ptr[i], nbr_ptr[i + 1]):
            j = nbr_idx[e]
            if j <= i:
                continue
            for f in range(nbr_ptr[j], nbr_ptr[j + 1]):
                k = nbr_idx[f]
                if k <= j or ang_i[k] < 0:
                    continue
                s1, s2, s3 = _sorted3(nbr_ang[e], ang_i[k], nbr_ang[f])
                c1, c2, c3 = (min(int(s1 / h), n - 1), min(int(s2 / h), n - 1),
                              min(int(s3 / h), n - 1))
                cell = _cell(c1, c2, c3)
                if fill:
                    p = counts[cell]
                    tri[p, 0], tri[p, 1], tri[p, 2] = i, j, k
                    tri[p, 3] = (_quantum(s1 / h, c1) | (_quantum(s2 / h, c2) << 5)
                                 | (_quantum(s3 / h, c3) << 10))
                    counts[cell] = p + 1
                else:
                    counts[cell + 1] += 1
        for e in range(nbr_ptr[i], nbr_ptr[i + 1]):
            ang_i[nbr_idx[e]] = -1.0


def _build(index: PatternIndex, cell_rad: float) -> dict[str, np.ndarray]:
    n = int(index.max_sep_rad / cell_rad) + 1
    counts = np.zeros(n * (n + 1) * (n + 2) // 6 + 1, dtype=np.int64)
    ang = np.arccos(np.clip(index.nbr_cos, -1.0, 1.0))
    _walk(index.nbr_ptr, index.nbr_idx, ang, cell_rad, n, counts,
          np.zeros((0, 4), np.uint16), False)
    offs = np.cumsum(counts)
    tri = np.empty((int(offs[-1]), 4), dtype=np.uint16)
    _walk(index.nbr_ptr, index.nbr_idx, ang, cell_rad, n, offs[:-1].copy(), tri, True)
    return {"tri": tri, "offs": offs.astype(np.int32), "cell_rad": np.array(cell_rad),
            "n_cells": np.array(n), "pairs_sum": np.array(float(index.pair_cos.sum()))}


def triangle_table(index: PatternIndex, cell_rad: float,
                   cache_tag: str | None = None) -> dict[str, np.ndarray]:
    """The triangles of ``index`` (``tri`` (T, 4): each row the stars i < j < k and the
    quanta of its sorted sides, :data:`QUANTA`; ``offs`` the cells' first rows,
    ``cell_rad``, ``n_cells``), built or — with ``cache_tag`` naming the catalogue,
    as for the index — loaded from the cache."""
    if cache_tag is None:
        return _build(index, cell_rad)
    params = {"max_sep_rad": float(index.max_sep_rad), "catalog": cache_tag,
              "n": len(index.vectors), "pairs": index.n_pairs, "cell_rad": float(cell_rad),
              "layout": (INDEX_LAYOUT, TRIANGLE_LAYOUT)}
    pairs_sum = float(index.pair_cos.sum())
    return cached_arrays("triangle-index", params, [], lambda: _build(index, cell_rad),
                         valid=lambda a: float(a["pairs_sum"]) == pairs_sum)


def triangles_for(index: PatternIndex, tolerance_rad: float,
                  cache_tag: str | None = None) -> tuple | None:
    """What :func:`starid.identify.kernels.index_arrays` takes for the look-up — (tri, offs,
    cell_rad, n_cells) — or None when the table would pass :func:`max_bytes` or the
    catalogue has more stars than 16-bit rows hold."""
    n_est = estimate_triangles(index)
    cell_rad = cell_rad_for(tolerance_rad, index.max_sep_rad)
    n = int(index.max_sep_rad / cell_rad) + 1
    need = 8 * n_est * 1.2 + 4 * n ** 3 / 6
    if len(index.vectors) > np.iinfo(np.uint16).max or n_est == 0 or need > max_bytes():
        return None
    t = triangle_table(index, cell_rad, cache_tag)
    return t["tri"], t["offs"], float(t["cell_rad"]), int(t["n_cells"])
