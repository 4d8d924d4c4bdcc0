"""Pattern index: every catalogue pair closer than the field's diagonal, for range look-ups.

Two views of the same pairs, both sorted so that a window of separations is a contiguous
slice found with ``np.searchsorted``:

* ``pair_*`` — each unordered pair once (i < j), sorted by ascending separation: the first
  pair of a pattern is looked up here;
* a CSR neighbour list — for each star, its neighbours sorted by ascending separation:
  extending a partial pattern by one star is a window look-up in the first star's row.

Separations are stored as cosines (dot products), as in Renken's matcher (renken.md §4.3):
descending cosine = ascending angle. Built once per (catalogue, max separation) and cached
on disk (:mod:`starid.cache`).

Example:
    >>> import numpy as np
    >>> from starid.index import PatternIndex
    >>> v = np.array([[1, 0, 0], [np.cos(0.1), np.sin(0.1), 0], [0, 1, 0.0]])
    >>> idx = PatternIndex.from_vectors(v, max_sep_rad=0.5)
    >>> idx.pairs_in_window(np.cos(0.11), np.cos(0.09))
    (array([0]), array([1]))
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from starid.cache import cached_arrays

__all__ = ["PatternIndex"]

IntArray = NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class PatternIndex:
    """Sorted catalogue pairs within ``max_sep_rad`` (see module docstring)."""

    vectors: NDArray[np.float64]  # (N, 3) catalogue unit vectors
    max_sep_rad: float
    pair_i: NDArray[np.int32]  # (P,) i < j, sorted by descending cosine
    pair_j: NDArray[np.int32]
    pair_cos: NDArray[np.float64]
    nbr_ptr: IntArray  # (N + 1,) CSR row pointers
    nbr_idx: NDArray[np.int32]  # neighbours of each star, descending cosine within a row
    nbr_cos: NDArray[np.float64]

    @classmethod
    def from_vectors(
        cls, vectors: NDArray[np.float64], max_sep_rad: float, cache_tag: str | None = None
    ) -> PatternIndex:
        """Build (or load from the cache, when ``cache_tag`` names the catalogue) the index."""
        v = np.ascontiguousarray(vectors, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
            raise ValueError("catalogue vectors must be a finite (N, 3) array")
        if not 0 < max_sep_rad <= np.pi:
            raise ValueError(f"max_sep_rad must be in (0, π], got {max_sep_rad}")

        def build() -> dict[str, np.ndarray]:
            return _build(v, max_sep_rad)

        if cache_tag is None:
            arrays = build()
        else:
            params = {"max_sep_rad": float(max_sep_rad), "catalog": cache_tag, "n": len(v)}
            arrays = cached_arrays("pattern-index", params, [], build)
        return cls(v, float(max_sep_rad), **arrays)

    @property
    def n_pairs(self) -> int:
        return len(self.pair_cos)

    @property
    def nbytes(self) -> int:
        """Memory held by the index arrays (the catalogue vectors excluded)."""
        return sum(a.nbytes for a in (self.pair_i, self.pair_j, self.pair_cos, self.nbr_ptr,
                                      self.nbr_idx, self.nbr_cos))

    def pairs_in_window(self, cos_min: float, cos_max: float) -> tuple[IntArray, IntArray]:
        """Pairs with ``cos_min < cos < cos_max`` (strict, renken.md AC-12), i < j."""
        lo, hi = _slice_desc(self.pair_cos, cos_min, cos_max)
        return self.pair_i[lo:hi].astype(np.int64), self.pair_j[lo:hi].astype(np.int64)

    def neighbours_in_window(
        self, stars: IntArray, cos_min: NDArray[np.float64] | float,
        cos_max: NDArray[np.float64] | float,
    ) -> tuple[IntArray, IntArray]:
        """For each star k of ``stars``, its neighbours with ``cos_min < cos < cos_max``.

        Returns ``(parent, neighbour)``: ``parent`` indexes into ``stars``. Windows may be
        scalars or one per star. Vectorised: one searchsorted per bound for all stars.
        """
        stars = np.asarray(stars, dtype=np.int64)
        if len(stars) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        start = self.nbr_ptr[stars]
        stop = self.nbr_ptr[stars + 1]
        cmin = np.broadcast_to(cos_min, stars.shape)
        cmax = np.broadcast_to(cos_max, stars.shape)
        # rows are sorted by descending cosine; search on the negated values (ascending),
        # offset per row so one global searchsorted serves every row
        neg = self._neg_cos_offset
        row_off = 4.0 * stars  # rows live in disjoint intervals [4k − 1, 4k + 1]
        lo = np.searchsorted(neg, row_off - cmax, side="right")
        hi = np.searchsorted(neg, row_off - cmin, side="left")
        lo = np.clip(lo, start, stop)
        hi = np.clip(hi, start, stop)
        counts = np.maximum(hi - lo, 0)
        total = int(counts.sum())
        if total == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        parent = np.repeat(np.arange(len(stars)), counts)
        offs = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
        pos = np.repeat(lo, counts) + offs
        return parent, self.nbr_idx[pos].astype(np.int64)

    @property
    def _neg_cos_offset(self) -> NDArray[np.float64]:
        cached = self.__dict__.get("_neg_cache")
        if cached is None:
            rows = np.repeat(np.arange(len(self.nbr_ptr) - 1), np.diff(self.nbr_ptr))
            cached = 4.0 * rows - self.nbr_cos
            object.__setattr__(self, "_neg_cache", cached)
        return cached


def _slice_desc(values_desc: NDArray[np.float64], cmin: float, cmax: float) -> tuple[int, int]:
    """Index range of a descending array with cmin < value < cmax."""
    neg = -values_desc
    lo = int(np.searchsorted(neg, -cmax, side="right"))
    hi = int(np.searchsorted(neg, -cmin, side="left"))
    return lo, max(lo, hi)


def _build(v: NDArray[np.float64], max_sep_rad: float) -> dict[str, np.ndarray]:
    chord = 2.0 * np.sin(0.5 * max_sep_rad)
    tree = cKDTree(v)
    pairs = tree.query_pairs(chord, output_type="ndarray").astype(np.int64)
    if len(pairs) == 0:
        pairs = np.zeros((0, 2), np.int64)
    i, j = pairs[:, 0], pairs[:, 1]
    swap = i > j
    i, j = np.where(swap, j, i), np.where(swap, i, j)
    cos = np.einsum("ij,ij->i", v[i], v[j])
    order = np.lexsort((j, i, -cos))  # descending cosine, ties by index: deterministic
    pi, pj, pc = i[order], j[order], cos[order]
    # CSR over both directions, each row sorted by descending cosine
    rows = np.concatenate([pi, pj])
    cols = np.concatenate([pj, pi])
    cc = np.concatenate([pc, pc])
    o = np.lexsort((cols, -cc, rows))
    rows, cols, cc = rows[o], cols[o], cc[o]
    ptr = np.zeros(len(v) + 1, np.int64)
    np.add.at(ptr, rows + 1, 1)
    ptr = np.cumsum(ptr)
    return {
        "pair_i": pi.astype(np.int32),
        "pair_j": pj.astype(np.int32),
        "pair_cos": pc,
        "nbr_ptr": ptr,
        "nbr_idx": cols.astype(np.int32),
        "nbr_cos": cc,
    }
