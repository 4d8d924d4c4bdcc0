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
    >>> from adfusion.starid.index import PatternIndex
    >>> v = np.array([[1, 0, 0], [np.cos(0.1), np.sin(0.1), 0], [0, 1, 0.0]])
    >>> idx = PatternIndex.from_vectors(v, max_sep_rad=0.5)
    >>> idx.pairs_in_window(np.cos(0.11), np.cos(0.09))
    (array([0]), array([1]))
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from adfusion.starid.cache import cached_arrays
from numpy.typing import NDArray
from scipy.spatial import cKDTree

__all__ = ["PatternIndex"]

IntArray = NDArray[np.int64]
N_BINS = 512  # angle bins per neighbour row (≈ 0.04° for a 20° field)
INDEX_LAYOUT = 2  # bump when the stored arrays change: old cache entries are then ignored


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
    nbr_bin: NDArray[np.int32]  # (N, B + 1): first CSR entry at angle ≥ b·max_sep/B

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
            params = {"max_sep_rad": float(max_sep_rad), "catalog": cache_tag, "n": len(v),
                      "layout": INDEX_LAYOUT}
            arrays = cached_arrays("pattern-index", params, [], build)
        return cls(v, float(max_sep_rad), **arrays)

    @property
    def n_pairs(self) -> int:
        return len(self.pair_cos)

    @property
    def nbytes(self) -> int:
        """Memory held by the index arrays (the catalogue vectors excluded)."""
        return sum(a.nbytes for a in (self.pair_i, self.pair_j, self.pair_cos, self.nbr_ptr,
                                      self.nbr_idx, self.nbr_cos, self.nbr_bin))

    def pairs_in_window(self, cos_min: float, cos_max: float) -> tuple[IntArray, IntArray]:
        """Pairs with ``cos_min < cos < cos_max`` (strict, renken.md AC-12), i < j."""
        neg = self._neg_pair_cos
        lo = int(np.searchsorted(neg, -cos_max, side="right"))
        hi = max(lo, int(np.searchsorted(neg, -cos_min, side="left")))
        return self.pair_i[lo:hi].astype(np.int64), self.pair_j[lo:hi].astype(np.int64)

    def neighbours_in_window(
        self, stars: IntArray, cos_min: NDArray[np.float64] | float,
        cos_max: NDArray[np.float64] | float,
    ) -> tuple[IntArray, IntArray]:
        """For each star k of ``stars``, its neighbours with ``cos_min < cos < cos_max``.

        Returns ``(parent, neighbour)``: ``parent`` indexes into ``stars``. Windows may be
        scalars or one per star. Vectorised over all stars: two table look-ups and one
        exact filter, no per-star search.
        """
        stars = np.asarray(stars, dtype=np.int64)
        if len(stars) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        # the bin table gives, per star, where its (angle-sorted) row crosses each bin
        # edge: the bins covering the window are a superset, filtered exactly below
        nb = self.nbr_bin.shape[1] - 1
        step = self.max_sep_rad / nb
        scalar = np.ndim(cos_min) == 0 and np.ndim(cos_max) == 0
        if scalar:  # the matcher's case: one window for all stars, no per-star arrays
            # windows are cosines of angles in [0, π], already inside [−1, 1]
            b0 = min(max(int(math.acos(cos_max) / step), 0), nb)
            b1 = min(max(int(math.acos(cos_min) / step) + 1, 0), nb)
            lo = self.nbr_bin[stars, b0]
            hi = self.nbr_bin[stars, b1]
        else:
            cmin_a = np.broadcast_to(np.asarray(cos_min, dtype=np.float64), stars.shape)
            cmax_a = np.broadcast_to(np.asarray(cos_max, dtype=np.float64), stars.shape)
            b0 = np.clip((np.arccos(cmax_a) / step).astype(np.int64), 0, nb)
            b1 = np.clip((np.arccos(cmin_a) / step).astype(np.int64) + 1, 0, nb)
            lo = self.nbr_bin[stars, b0]
            hi = self.nbr_bin[stars, b1]
        counts = (hi - lo).astype(np.int64)
        total = int(counts.sum())
        if total == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        parent = np.repeat(np.arange(len(stars)), counts)
        # position of each candidate in the CSR arrays: its row start plus its rank
        pos = np.arange(total) + (lo.astype(np.int64) - np.cumsum(counts) + counts)[parent]
        c = self.nbr_cos[pos]
        if scalar:
            keep = (c > cos_min) & (c < cos_max)
        else:
            keep = (c > cmin_a[parent]) & (c < cmax_a[parent])
        return parent[keep], self.nbr_idx[pos[keep]].astype(np.int64)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_neg_pair_cos", -self.pair_cos)  # ascending search key


#: Star pairs an index may hold (~100 bytes each while it is built): 2× what a 45° field
#: at V 6.5 needs. Beyond it the pair search runs out of memory after tens of seconds
#: (``std::bad_alloc``), so the estimate below refuses it at once.
MAX_PAIRS = 20_000_000


def _build(v: NDArray[np.float64], max_sep_rad: float) -> dict[str, np.ndarray]:
    chord = 2.0 * np.sin(0.5 * max_sep_rad)
    # pairs of N stars spread over the sphere that lie within max_sep of each other
    expected = 0.5 * len(v) * (len(v) - 1) * 0.5 * (1.0 - np.cos(max_sep_rad))
    if expected > MAX_PAIRS:
        raise ValueError(
            f"{len(v)} catalogue stars within {np.degrees(max_sep_rad):.1f}° of each other "
            f"make ~{expected:.2g} pairs (at most {MAX_PAIRS:.0e} fit in memory): use a lower "
            "magnitude limit or a narrower field")
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
    # bin table: one sorted global key (row·4 + angle) searched for every (row, edge)
    edges = np.linspace(0.0, max_sep_rad, N_BINS + 1)
    key = rows * 4.0 + np.arccos(np.clip(cc, -1.0, 1.0))
    queries = (np.arange(len(v))[:, None] * 4.0 + edges[None, :]).ravel()
    table = np.searchsorted(key, queries, side="left").reshape(len(v), N_BINS + 1)
    table[:, -1] = ptr[1:]  # the last edge closes the row (max_sep itself may round)
    return {
        "pair_i": pi.astype(np.int32),
        "pair_j": pj.astype(np.int32),
        "pair_cos": pc,
        "nbr_ptr": ptr,
        "nbr_idx": cols.astype(np.int32),
        "nbr_cos": cc,
        "nbr_bin": table.astype(np.int32),
    }

