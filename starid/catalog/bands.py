"""Renken §6.10 equal-area declination sub-catalogues: band boundaries and :class:`Band`.

Example:
    >>> band_boundaries_deg(2).round(1).tolist()
    [90.0, 0.0, -90.0]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Band", "band_boundaries_deg", "band_boundaries_rad"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def band_boundaries_deg(n_bands: int) -> FloatArray:
    """Equal-area declination band boundaries in degrees, north to south (Renken Eq. 6.46).

    Band k spans ``[b[k+1], b[k]]``; ``sin δ`` is equally spaced, so every band covers
    ``4π / n_bands`` sr.

    >>> band_boundaries_deg(4).round(2).tolist()
    [90.0, 30.0, 0.0, -30.0, -90.0]
    >>> band_boundaries_deg(8).round(2).tolist()
    [90.0, 48.59, 30.0, 14.48, 0.0, -14.48, -30.0, -48.59, -90.0]
    """
    return np.degrees(band_boundaries_rad(n_bands))


def band_boundaries_rad(n_bands: int) -> FloatArray:
    """As :func:`band_boundaries_deg`, in radians.

    >>> float(band_boundaries_rad(1)[0]) == float(np.pi / 2)
    True
    """
    if isinstance(n_bands, bool) or not isinstance(n_bands, int | np.integer):
        raise TypeError(f"n_bands must be an integer, got {n_bands!r}")
    if n_bands < 1:
        raise ValueError(f"n_bands must be ≥ 1, got {n_bands}")
    s = 1.0 - 2.0 * np.arange(n_bands + 1) / n_bands
    b = np.arcsin(np.clip(s, -1.0, 1.0))
    b[0], b[-1] = np.pi / 2, -np.pi / 2
    return b


@dataclass(frozen=True, eq=False)
class Band:
    """One declination sub-catalogue (Renken §6.10).

    ``dec_lo_rad``/``dec_hi_rad`` are the core boundaries; ``indices`` (ascending catalogue
    indices) are the stars with ``dec_lo_rad − overlap ≤ δ ≤ dec_hi_rad + overlap``, the
    extended band clamped to ±90°. Overlap decision (Renken §11 #28): the band is extended by
    the overlap on **both** sides, so every pattern whose stars are pairwise within the
    overlap lies completely in the band whose core holds *any* one of its stars. To count a
    match once, accept it only in the band whose core holds its anchor star — see
    :meth:`in_core`; the cores partition the sphere, so the count equals the one-catalogue
    count (Renken AC-13).

    >>> import numpy as np
    >>> b = Band(0.0, np.pi / 6, np.array([3, 4]))
    >>> b.in_core(np.radians([0.0, 29.0, 30.0])).tolist()
    [True, True, False]
    """

    dec_lo_rad: float
    dec_hi_rad: float
    indices: IntArray

    def in_core(self, dec_rad: ArrayLike) -> NDArray[np.bool_]:
        """True where δ is in this band's core ``[lo, hi)`` (``[lo, 90°]`` for the top band).

        Every declination is in exactly one core of a :meth:`Catalog.declination_bands` set.
        """
        d = np.asarray(dec_rad, dtype=np.float64)
        top = self.dec_hi_rad >= np.pi / 2
        return (d >= self.dec_lo_rad) & ((d < self.dec_hi_rad) | top)

    def __len__(self) -> int:
        return len(self.indices)
