"""Renken (1998) §8: his simulation loop, the Eq. 8.1 sampler and his published η table.

A benchmark driver, not part of the matcher: ``benchmarks/renken_simulation.py`` runs the
full grid; ``tests/test_renken.py`` runs one reduced cell.

Example:
    >>> import numpy as np
    >>> eq_8_1_attitudes(np.random.default_rng(0), 3).shape
    (3, 3)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from adfusion.maths import rotations as rot
from adfusion.starid.identify.renken import SAO_COUNTS, affine_attitude, linear_pattern

__all__ = ["PUBLISHED_ETA", "SimulationCell", "eq_8_1_attitudes", "renken_catalog",
           "simulate_cell"]

# Tab. 8.22–8.28: η (%) per magnitude limit at tolerance 0.1°, 0.2°, 0.3°
PUBLISHED_ETA = {
    3.0: (7.3, 7.15, 6.5), 4.0: (44.2, 37.6, 29.0), 4.5: (71.95, 64.6, 58.6),
    5.0: (93.95, 89.3, 83.8), 5.4: (99.7, 96.3, 88.65), 5.7: (99.6, 94.05, 81.25),
    6.0: (99.15, 91.9, 69.55),
}

def eq_8_1_attitudes(rng: np.random.Generator, n: int,
                     uniform: bool = False) -> NDArray[np.float64]:
    """Random (α, δ, ω) in rad: Renken's Eq. 8.1 declinations
    ``δ = ±90°·(1 − cos U[0°, 90°])`` by default, or uniform on the sphere."""
    alpha = rng.uniform(0, 2 * np.pi, n)
    if uniform:
        delta = np.arcsin(rng.uniform(-1, 1, n))
    else:
        sign = rng.choice([-1.0, 1.0], n)
        delta = sign * np.pi / 2 * (1 - np.cos(rng.uniform(0, np.pi / 2, n)))
    omega = rng.uniform(0, 2 * np.pi, n)
    return np.stack([alpha, delta, omega], axis=1)


@dataclass(frozen=True)
class SimulationCell:
    """Outcome counts of one (catalogue, tolerance) cell of Renken's §8 simulation."""

    mag_limit: float
    tol_deg: float
    frames: int
    clear: int  # unique, correct, attitude computed: his clear_3_axis_attitude_counter
    fewer_than_3: int
    miss: int  # matching_counter = 0
    unique: int  # matching_counter = 1
    multiple: int  # matching_counter ≥ 2
    wrong_unique: int  # matching_counter = 1 but the wrong stars
    critical: int  # unique but no triangle passes Cond. 8.1

    @property
    def eta(self) -> float:
        return 100.0 * self.clear / self.frames


def renken_catalog(mag_limit: float, epoch: float = 2000.0, merge_px: float = 2.0):
    """An "SAO-like" catalogue for the simulation: Hipparcos with close pairs merged
    (faint stars included, Renken 1998 §8) and cut to the brightest ``SAO_COUNTS`` objects
    (SAO photometry runs ~0.15 mag fainter than V, so equal counts reproduce his
    catalogues better than equal limits — see tests/test_renken.py AC-17).

    The merge radius is not in the thesis. 2 px (0.102°) is our choice: his stars were
    1–3 px blobs, so two stars closer than ~2 px segment as one object. With 1 px the
    mag < 5.4, 0.1° cell gives η ≈ 96.8 % (3 % multiple matches from close pairs the
    camera could not have resolved); with 2 px it gives 99.75 % against his 99.7 %."""
    from adfusion.starid.catalog.stars import Catalog

    merged = Catalog.hipparcos(mag_limit=8.0, epoch=epoch).merged(np.radians(0.051 * merge_px))
    return merged.brightest(SAO_COUNTS[mag_limit])


def simulate_cell(catalog, mag_limit: float, tol_deg: float, n_frames: int, seed: int,
                  index=None) -> SimulationCell:
    """Renken's §8 loop for one cell: Eq. 8.1 attitudes, his equidistant 384×288 camera,
    every catalogue object in the frame as an image star (0.1 px centroids, brightness
    order), the n = min(number_is, 6) brightest, closest pair first, linear pixel
    angles, all matches enumerated. A unique match counts as clear when it is the true
    star set and a triangle passes Cond. 8.1 (success Cond. 8.2)."""
    from adfusion.starid.camera.model import Camera
    from adfusion.starid.camera.view import stars_in_view
    from adfusion.starid.catalog.pair_index import PatternIndex
    from adfusion.starid.identify.nstar import closest_pair_first, match_indexed

    cam = Camera.renken()
    app = np.radians(0.051)
    if index is None:
        index = PatternIndex.from_vectors(catalog.vectors, np.radians(25.0))
    rng = np.random.default_rng(seed)
    counts = dict.fromkeys(("clear", "few", "miss", "unique", "multiple", "wrong", "crit"), 0)
    for a, d, w in eq_8_1_attitudes(rng, n_frames):
        q = rot.q_cam_icrs_from_radec_roll(a, d, w)
        stars, xy = stars_in_view(catalog, cam, q)
        xy = np.round(xy, 1)  # his centroids have 0.1 px resolution
        if len(stars) < 3:
            counts["few"] += 1
            continue
        n = min(len(stars), 6)
        p, s = xy[:n], stars[:n]
        ang = np.hypot(*(p[:, None] - p[None]).transpose(2, 0, 1))
        o = closest_pair_first(ang)
        found = match_indexed(index, linear_pattern(p[o], app, np.radians(tol_deg)),
                              max_partials=10**8)
        if len(found) == 0:
            counts["miss"] += 1
        elif len(found) > 1:
            counts["multiple"] += 1
        else:
            counts["unique"] += 1
            if not np.array_equal(found[0], s[o]):
                counts["wrong"] += 1
            elif not affine_attitude(p[o], catalog.vectors[found[0]], app).ok:
                counts["crit"] += 1
            else:
                counts["clear"] += 1
    return SimulationCell(mag_limit, tol_deg, n_frames, counts["clear"], counts["few"],
                          counts["miss"], counts["unique"], counts["multiple"],
                          counts["wrong"], counts["crit"])
