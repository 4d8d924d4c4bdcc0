"""Pattern index: every catalogue pair closer than the field's diagonal, for range look-ups.

Two views of the same pairs, both sorted so that a window of separations is a contiguous
slice found with ``np.searchsorted``:

* ``pair_*`` — each unordered pair once (i < j), sorted by ascending separation: the first
  pair of a pattern is looked up here;
* a CSR neighbour list — for each star, its neighbours sorted by ascending separation:
  extending a partial pattern by one star is a window look-up in the first star's row.

Separations are stored as cosines (dot products), as in Renken's matcher (Eq. 6.34–6.37):
descending cosine = ascending angle. Built once per (catalogue, max separation) and cached
on disk (:mod:`starid.catalog.cache`).

Deep catalogues: the build estimates its memory from a sample of the stars *before*
allocating anything and refuses, with a one-line :class:`IndexTooLarge`, an index whose
build would exceed ``max_bytes`` (``$ADFUSION_INDEX_MAX_GB``, default 1.5 GB). Select the
brightest stars per sky cell first (:func:`adfusion.starid.catalog.coverage.uniform_coverage`) to
bound it for any magnitude limit.

The epoch: a cache entry is keyed by the catalogue's stars (ids and magnitudes), not by
their positions, and keeps the positions it was built from. A catalogue of the same stars
at another epoch reuses it while no star has moved more than ``reuse_drift_rad`` (5″ by
default), with the current positions in ``vectors`` (what the matchers' link tests and the
verification use) and the pair cosines of the build epoch (stale by at most twice the
drift, a tenth of the narrowest pair window); beyond that it is rebuilt in place, so the
cache holds one entry per star set and camera.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np
from adfusion.starid.catalog.cache import cached_arrays, env_size_bytes
from numpy.typing import NDArray
from scipy.spatial import cKDTree

__all__ = ["IndexTooLarge", "PatternIndex", "catalog_cache_tag", "estimate_build_bytes",
           "estimate_pairs", "max_index_bytes"]

IntArray = NDArray[np.int64]
N_BINS = 512  # angle bins per neighbour row (≈ 0.04° for a 20° field)
INDEX_LAYOUT = 3  # bump when the stored arrays change: old cache entries are then ignored
DEFAULT_MAX_GB = 1.5
# 5″: a tenth of the smallest pair tolerance in use (≥ 0.003° + the centroid term), so a
# reused index's pair cosines are stale by far less than its windows; α Cen (3.7″/yr) and
# Groombridge 1830 (7″/yr, V 6.4) trigger a rebuild every year or so, nothing else does
REUSE_DRIFT_RAD = math.radians(5.0 / 3600.0)
# peak bytes of the build per pair and per star (measured: benchmarks/bench_deep_index.py;
# the stored arrays take 40 B a pair and 2 kB a star, the sorts' temporaries the rest)
_BUILD_BYTES_PER_PAIR = 88
_BUILD_BYTES_PER_STAR = 4 * (N_BINS + 1) + 200
_BIN_BLOCK = 4096  # rows per block of the bin-table build


class IndexTooLarge(ValueError):
    """The pattern index would need more memory than allowed (raised before allocating)."""


def max_index_bytes() -> int:
    """The build's memory bound: ``$ADFUSION_INDEX_MAX_GB`` gigabytes (default 1.5).

    >>> max_index_bytes() > 0
    True
    """
    return env_size_bytes("ADFUSION_INDEX_MAX_GB", DEFAULT_MAX_GB, "gigabytes", 1e9, False)


def estimate_pairs(vectors: NDArray[np.float64], max_sep_rad: float,
                   sample: int = 2000) -> int:
    """Expected number of pairs closer than ``max_sep_rad``, from a fixed sample of stars.

    Exact up to ``sample`` stars; beyond, the neighbour count of an evenly strided sample
    scaled up (a few per cent, never allocating the pairs themselves).

    >>> v = np.array([[1, 0, 0], [np.cos(0.1), np.sin(0.1), 0], [0, 1, 0.0]])
    >>> estimate_pairs(v, 0.5)
    1
    """
    v = np.asarray(vectors, dtype=np.float64)
    n = len(v)
    if n < 2:
        return 0
    tree = cKDTree(v)
    chord = 2.0 * math.sin(0.5 * min(max_sep_rad, math.pi))
    pick = np.unique(np.linspace(0, n - 1, min(n, sample)).astype(np.int64))
    counts = tree.query_ball_point(v[pick], chord, return_length=True) - 1
    return round(float(np.mean(counts)) * n / 2.0)


def estimate_build_bytes(n_stars: int, n_pairs: int) -> int:
    """Peak memory (bytes) of building an index of ``n_pairs`` pairs over ``n_stars``.

    >>> estimate_build_bytes(10_000, 1_000_000) // 10**6
    110
    """
    return int(n_pairs) * _BUILD_BYTES_PER_PAIR + int(n_stars) * _BUILD_BYTES_PER_STAR


def catalog_cache_tag(catalog) -> str:
    """Cache identity of a catalogue's star set: its ids and magnitudes, not its epoch.

    Anything with ``ids`` (and optionally ``mag``) works; positions are checked on load
    (see the module docstring), so two catalogues that share ids but not positions never
    share an index.

    >>> from adfusion.starid.catalog.stars import Catalog
    >>> a = Catalog.hipparcos(mag_limit=3.0, epoch=2020.0)
    >>> b = Catalog.hipparcos(mag_limit=3.0, epoch=2030.0)
    >>> catalog_cache_tag(a) == catalog_cache_tag(b)
    True
    """
    h = hashlib.sha1(np.ascontiguousarray(np.asarray(catalog.ids, np.int64)).tobytes())
    mag = getattr(catalog, "mag", None)
    if mag is not None:
        h.update(np.ascontiguousarray(np.asarray(mag, np.float64)).tobytes())
    return h.hexdigest()


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
        cls, vectors: NDArray[np.float64], max_sep_rad: float, cache_tag: str | None = None,
        *, max_bytes: int | None = None, reuse_drift_rad: float = REUSE_DRIFT_RAD,
    ) -> PatternIndex:
        """Build (or load from the cache, when ``cache_tag`` names the catalogue) the index.

        ``max_bytes`` bounds the build's memory (default :func:`max_index_bytes`): a
        larger index raises :class:`IndexTooLarge` before anything is allocated.
        """
        v = np.ascontiguousarray(vectors, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
            raise ValueError("catalogue vectors must be a finite (N, 3) array")
        if not 0 < max_sep_rad <= np.pi:
            raise ValueError(f"max_sep_rad must be in (0, π], got {max_sep_rad}")
        limit = max_index_bytes() if max_bytes is None else int(max_bytes)

        def build() -> dict[str, np.ndarray]:
            _check_size(v, max_sep_rad, limit)
            return {**_build(v, max_sep_rad), "built_vectors": v}

        if cache_tag is None:
            arrays = build()
        else:
            params = {"max_sep_rad": float(max_sep_rad), "catalog": cache_tag, "n": len(v),
                      "layout": INDEX_LAYOUT}

            def fresh(a: dict[str, np.ndarray]) -> bool:  # the entry's stars still in place
                old = a.get("built_vectors")
                return (old is not None and old.shape == v.shape
                        and float(np.max(np.linalg.norm(old - v, axis=1), initial=0.0))
                        <= reuse_drift_rad)

            arrays = cached_arrays("pattern-index", params, [], build, valid=fresh)
        arrays = {k: a for k, a in arrays.items() if k != "built_vectors"}
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
        """Pairs with ``cos_min < cos < cos_max`` (strict, Renken 1998 §6.9), i < j."""
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


def _check_size(v: NDArray[np.float64], max_sep_rad: float, limit: int) -> None:
    n_pairs = estimate_pairs(v, max_sep_rad)
    need = estimate_build_bytes(len(v), n_pairs)
    if need > limit:
        raise IndexTooLarge(
            f"the pattern index of {len(v)} stars within {math.degrees(max_sep_rad):.2f}° "
            f"(~{n_pairs:,} pairs) needs ~{need / 1e9:.1f} GB to build, over the "
            f"{limit / 1e9:.1f} GB bound: keep the brightest stars per sky cell "
            f"(--stars-per-fov / starid.catalog.coverage.uniform_coverage), lower the magnitude "
            f"limit, or raise ADFUSION_INDEX_MAX_GB")


def _build(v: NDArray[np.float64], max_sep_rad: float) -> dict[str, np.ndarray]:
    chord = 2.0 * np.sin(0.5 * max_sep_rad)
    tree = cKDTree(v)
    pairs = tree.query_pairs(chord, output_type="ndarray")
    del tree
    if len(pairs) == 0:
        pairs = np.zeros((0, 2), np.int64)
    # int32 throughout (a catalogue has < 2³¹ stars): half the memory of int64
    a, b = pairs[:, 0].astype(np.int32), pairs[:, 1].astype(np.int32)
    del pairs
    i, j = np.minimum(a, b), np.maximum(a, b)
    del a, b
    cos = _dots(v, i, j)
    # descending cosine; exact ties (synthetic catalogues) by (i, j), for determinism
    order = np.argsort(-cos)
    if len(cos) > 1 and np.any(np.diff(cos[order]) == 0):
        order = np.lexsort((j, i, -cos))
    pi, pj, pc = i[order], j[order], cos[order]
    del i, j, cos, order
    # CSR over both directions, each row in the pairs' order (descending cosine): both
    # directions of a pair side by side, then sorted by (row, position) — distinct keys,
    # so a plain (fast) sort gives the stable order
    rows = np.stack([pi, pj], axis=1).ravel()
    key = rows.astype(np.int64) * max(2 * len(pi), 1)
    key += np.arange(2 * len(pi))
    o = np.argsort(key)
    del key
    rows = rows[o]
    cols = np.stack([pj, pi], axis=1).ravel()[o]
    cc = np.repeat(pc, 2)[o]
    del o
    counts = np.bincount(rows, minlength=len(v))
    ptr = np.zeros(len(v) + 1, np.int64)
    np.cumsum(counts, out=ptr[1:])
    # bin table: entries per (row, angle bin) counted, then running sums within each row,
    # a block of rows at a time so the counts never take more than a few MB
    step = max_sep_rad / N_BINS
    table = np.empty((len(v), N_BINS + 1), np.int32)
    for r0 in range(0, len(v), _BIN_BLOCK):
        r1 = min(r0 + _BIN_BLOCK, len(v))
        e0, e1 = int(ptr[r0]), int(ptr[r1])
        ang = np.arccos(np.clip(cc[e0:e1], -1.0, 1.0))
        b = np.minimum((ang / step).astype(np.int64), N_BINS - 1)
        b += (rows[e0:e1].astype(np.int64) - r0) * N_BINS
        per_bin = np.bincount(b, minlength=(r1 - r0) * N_BINS).reshape(r1 - r0, N_BINS)
        table[r0:r1, 0] = ptr[r0:r1]
        table[r0:r1, 1:] = np.cumsum(per_bin, axis=1) + ptr[r0:r1, None]
    table[:, -1] = ptr[1:]  # the last edge closes the row (max_sep itself may round)
    return {
        "pair_i": pi, "pair_j": pj, "pair_cos": pc, "nbr_ptr": ptr,
        "nbr_idx": cols, "nbr_cos": cc, "nbr_bin": table,
    }


def _dots(v: NDArray[np.float64], i: NDArray, j: NDArray) -> NDArray[np.float64]:
    """``v[i] · v[j]`` row by row, a block at a time (no (P, 3) temporaries)."""
    out = np.empty(len(i))
    for k in range(0, len(i), 1 << 20):
        a, b = v[i[k:k + (1 << 20)]], v[j[k:k + (1 << 20)]]
        out[k:k + len(a)] = a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]
    return out
