"""Verification of a candidate identification and its false-match probability.

A geometric match of n image stars to n catalogue stars proposes an attitude. We then
project the catalogue into the frame at that attitude, match the remaining detections,
and ask how likely it is that a *wrong* identification would look this good:

``p_false = trials × E_chance × P(Binomial(M, p_hit) ≥ k)``

* ``E_chance`` — the expected number of catalogue patterns anywhere on the sky that fit
  the image pattern's windows by coincidence (:func:`expected_chance_patterns`);
* ``P(… ≥ k)`` — the chance that ``k`` or more of the ``M`` other detections land within
  the match radius of a projected catalogue star when the attitude is wrong (each does so
  with probability ``p_hit`` = projected stars × disc area / frame area);
* ``trials`` — how many patterns (and focal-length guesses) were tried before this one:
  a union bound over the whole search, so trying more never buys a false acceptance.

This is a union-bound style upper estimate (the sky density is doubled for safety); it
is what :class:`starid.Solution` reports as ``p_false``.

Example:
    >>> round(binomial_tail(3, 10, 0.01), 6)
    0.000114
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.special import bdtrc

__all__ = [
    "binomial_tail",
    "expected_chance_patterns",
    "spot_geometry",
]

# mean catalogue density is doubled: the Milky Way holds several times the mean at V ~ 6
DENSITY_SAFETY = 2.0


def binomial_tail(k: int, m: int, p: float) -> float:
    """P(X ≥ k) for X ~ Binomial(m, p)."""
    if k <= 0:
        return 1.0
    if k > m:
        return 0.0
    p = min(max(p, 0.0), 1.0)
    return float(bdtrc(k - 1, m, p))


def expected_chance_patterns(
    angles: NDArray[np.float64],
    tol: NDArray[np.float64] | float,
    n_catalog: int,
    mirror_checked: bool,
    geometry: list[tuple[int, int, float]] | None = None,
) -> float:
    """Expected number of catalogue n-star patterns matching ``angles`` by chance.

    Star 1 may be any of N stars; star 2 lies in an annulus of width 2·tol around it
    (area 2π sin d₁₂ · 2tol); every further star must lie where the annuli around two
    already placed stars cross: two spots of area (2tol)² / sin γ (γ the crossing angle),
    one of them when the mirror check or a third placed star picks the side. The pair of
    placed stars crossing most steeply is used — with the closest pair first, the first
    two stars alone pin a far star only loosely, the others pin it well. Further
    distances are not credited (they tighten the spot further, so this stays an upper
    estimate). Densities are per steradian, doubled for safety (:data:`DENSITY_SAFETY`).
    ``geometry`` is :func:`spot_geometry` of ``angles``, when the caller has it already.
    """
    a = np.asarray(angles, dtype=np.float64)
    w = 2.0 * np.broadcast_to(np.asarray(tol, dtype=np.float64), a.shape)
    rho = DENSITY_SAFETY * n_catalog / (4.0 * np.pi)
    e = float(n_catalog) * rho * 2.0 * np.pi * max(np.sin(a[0, 1]), 1e-6) * w[0, 1]
    e *= 2.0  # either image star of the first pair may be either catalogue star
    for m, (s, t, sin_gamma) in enumerate(geometry or spot_geometry(a), start=2):
        spots = 1.0 if (m >= 3 or mirror_checked) else 2.0
        e *= rho * spots * w[s, m] * w[t, m] / max(sin_gamma, 0.05)
    return float(e)


def spot_geometry(angles: NDArray[np.float64]) -> list[tuple[int, int, float]]:
    """For each star m ≥ 2: the placed pair (s, t) whose arcs cross most steeply at m,
    and the sine of that crossing angle (depends on the image geometry only)."""
    a = np.asarray(angles, dtype=np.float64).tolist()
    out = []
    for m in range(2, len(a)):
        best = (0, 1, 0.0)
        for s in range(m):
            for t in range(s + 1, m):
                sg = math.sin(_crossing_angle(a[s][t], a[s][m], a[t][m]))
                if sg > best[2]:
                    best = (s, t, sg)
        out.append(best)
    return out


def _crossing_angle(d01: float, d0m: float, d1m: float) -> float:
    """Angle at star m between the arcs to stars 0 and 1 (spherical law of cosines)."""
    denom = math.sin(d0m) * math.sin(d1m)
    if denom <= 0:
        return 0.0
    c = (math.cos(d01) - math.cos(d0m) * math.cos(d1m)) / denom
    return math.acos(min(1.0, max(-1.0, c)))
