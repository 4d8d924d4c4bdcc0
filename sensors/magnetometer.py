"""Magnetometer model and the geomagnetic reference field (IGRF) in ICRS.

Reference field
---------------
:func:`field_icrs_nT` evaluates the International Geomagnetic Reference Field (IGRF-14, via
``ppigrf``) at a geodetic position (WGS-84 latitude, longitude, height above the ellipsoid)
and UTC time, then rotates it local ENU → ECEF → ICRS:

* **ENU → ECEF**: the geodetic east/north/up axes (up = ellipsoid normal), the frame ppigrf's
  geodetic components are given in.
* **ECEF → mean equator and equinox of date**: a rotation about the pole by the Greenwich
  mean sidereal time, IAU 1982 (Aoki et al. 1982; :func:`gmst_rad`), with UT1 taken as UTC.
* **mean of date → ICRS**: IAU 1976 precession (Lieske et al. 1977; :func:`precession_matrix`),
  with TT taken as UTC.

Neglected, with their size (angles on the sky, i.e. errors of the field *direction*):

=================================  ==========================================
nutation (IAU 1980)                ≤ ~17″ in longitude (≤ 16″ about the pole,
                                   the equation of the equinoxes), ≤ ~9.2″ in
                                   obliquity
UT1 − UTC                          ≤ 0.9 s of Earth rotation → ≤ 13.5″
polar motion                       ≤ ~0.5″
ICRS ↔ FK5 J2000 frame bias        0.02″
TT − UTC in the precession angle   ~69 s of 50″/yr → 1e-4″
=================================  ==========================================

so the rotation is good to about 30″ (< 0.01°) — far below the IGRF's own error at the
surface (tens to hundreds of nT of crustal and external field, i.e. ~0.1°-1° of direction).
The IGRF coefficients are evaluated per UTC day (secular variation ≤ ~0.3 nT/day).

Magnetometer
------------
:class:`MagnetometerModel`: ``b_meas = S · b_true + h + n`` in the body frame, nT, with the
soft-iron matrix ``S`` (3×3; includes scale factors and misalignment), the hard-iron bias
``h`` and white Gaussian noise ``n``; :meth:`MagnetometerModel.correct` inverts the
deterministic part.

Example:
    >>> from datetime import datetime
    >>> import numpy as np
    >>> from adfusion.sensors.magnetometer import MagnetometerModel, field_icrs_nT
    >>> b = field_icrs_nT(69.29, 16.02, 0.0, datetime(2025, 1, 1, 12))   # Andøya
    >>> bool(50_000 < np.linalg.norm(b) < 56_000)
    True
    >>> mag = MagnetometerModel(noise_nT=50.0, hard_iron_nT=[200.0, 0.0, -100.0], seed=3)
    >>> m = mag.measure(b)
    >>> bool(np.linalg.norm(mag.correct(m) - b) < 300)
    True
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime, timedelta

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "MagnetometerModel",
    "field_ecef_nT",
    "field_enu_nT",
    "field_icrs_nT",
    "gmst_rad",
    "precession_matrix",
    "r_ecef_enu",
    "r_icrs_ecef",
]

Array = NDArray[np.float64]
Times = datetime | Sequence[datetime]

_J2000 = datetime(2000, 1, 1, 12, 0, 0)  # J2000.0 (taken in UT1 ≈ UTC and TT ≈ UTC)
_ARCSEC = np.pi / (180.0 * 3600.0)


def _naive_utc(t: datetime) -> datetime:
    if not isinstance(t, datetime):
        raise TypeError(f"times must be datetime objects, got {type(t).__name__}")
    return t.astimezone(UTC).replace(tzinfo=None) if t.tzinfo is not None else t


def _as_times(t_utc: Times) -> tuple[list[datetime], bool]:
    """(list of naive UTC datetimes, whether the input was a single time)."""
    if isinstance(t_utc, datetime):
        return [_naive_utc(t_utc)], True
    times = [_naive_utc(t) for t in t_utc]
    if not times:
        raise ValueError("no times given")
    return times, False


def _days_since_j2000(times: list[datetime]) -> Array:
    return np.array([(t - _J2000) / timedelta(days=1) for t in times])


def _rot_z(a: Array) -> Array:
    """Passive rotation about z by angle(s) a: coordinates in a frame turned by +a."""
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([c, s, z, -s, c, z, z, z, o], axis=-1).reshape((*np.shape(a), 3, 3))


def _rot_y(a: Array) -> Array:
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([c, z, -s, z, o, z, s, z, c], axis=-1).reshape((*np.shape(a), 3, 3))


def gmst_rad(t_utc: Times) -> Array | float:
    """Greenwich mean sidereal time (IAU 1982, Aoki et al.), rad in [0, 2π), UT1 = UTC.

    GMST at 0h UT1 is ``24110.54841 s + 8640184.812866 T + 0.093104 T² − 6.2e-6 T³`` with T
    in Julian centuries of UT1 from J2000.0 at that 0h; the time of day adds at the ratio of
    sidereal to solar time, ``1.002737909350795 + 5.9006e-11 T − 5.9e-15 T²``.

    >>> round(float(np.degrees(gmst_rad(datetime(2000, 1, 1, 12)))), 8)
    280.46061837
    """
    times, single = _as_times(t_utc)
    midnight = [datetime(t.year, t.month, t.day) for t in times]
    d0 = _days_since_j2000(midnight)
    tu = d0 / 36525.0
    secs = np.array([(t - m) / timedelta(seconds=1) for t, m in zip(times, midnight,
                                                                     strict=True)])
    gmst0 = 24110.54841 + tu * (8640184.812866 + tu * (0.093104 - 6.2e-6 * tu))
    ratio = 1.002737909350795 + tu * (5.9006e-11 - 5.9e-15 * tu)
    sec = np.mod(gmst0 + ratio * secs, 86400.0)
    out = sec * (2.0 * np.pi / 86400.0)
    return float(out[0]) if single else out


def precession_matrix(t_utc: Times) -> Array:
    """IAU 1976 precession (Lieske et al. 1977): ``r_mean_of_date = P @ r_J2000``.

    ``P = R3(−z_A) · R2(θ_A) · R3(−ζ_A)`` with the angles in arcseconds, t in Julian
    centuries from J2000.0 (TT taken as UTC):
    ζ_A = 2306.2181 t + 0.30188 t² + 0.017998 t³,
    z_A = 2306.2181 t + 1.09468 t² + 0.018203 t³,
    θ_A = 2004.3109 t − 0.42665 t² − 0.041833 t³.
    Returns (3, 3) for one time, (N, 3, 3) for a sequence.
    """
    times, single = _as_times(t_utc)
    t = _days_since_j2000(times) / 36525.0
    zeta = (2306.2181 + (0.30188 + 0.017998 * t) * t) * t * _ARCSEC
    z = (2306.2181 + (1.09468 + 0.018203 * t) * t) * t * _ARCSEC
    theta = (2004.3109 + (-0.42665 - 0.041833 * t) * t) * t * _ARCSEC
    p = _rot_z(-z) @ _rot_y(theta) @ _rot_z(-zeta)
    return p[0] if single else p


def r_icrs_ecef(t_utc: Times) -> Array:
    """Rotation matrix ECEF → ICRS at a UTC time: ``v_icrs = r_icrs_ecef(t) @ v_ecef``.

    ``Pᵀ · R3(−GMST)``: Earth rotation by :func:`gmst_rad` and precession by
    :func:`precession_matrix`; nutation, polar motion and UT1 − UTC are neglected (≤ ~30″
    in total, see the module docstring). (3, 3), or (N, 3, 3) for a sequence of times.
    """
    times, single = _as_times(t_utc)
    g = np.atleast_1d(gmst_rad(times))
    r = np.swapaxes(precession_matrix(times), -1, -2) @ _rot_z(-g)
    return r[0] if single else r


def r_ecef_enu(lat_deg: ArrayLike, lon_deg: ArrayLike) -> Array:
    """Rotation local geodetic east-north-up → ECEF at a geodetic latitude/longitude
    (columns: east, north, up in ECEF): ``v_ecef = r_ecef_enu(lat, lon) @ v_enu``.

    >>> r_ecef_enu(0.0, 0.0).round(12) + 0.0   # at (0°, 0°): east = y, north = z, up = x
    array([[0., 0., 1.],
           [1., 0., 0.],
           [0., 1., 0.]])
    """
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    z = np.zeros_like(sl * so)
    east = np.stack([-so + z, co + z, z], axis=-1)
    north = np.stack([-sl * co, -sl * so, cl + z], axis=-1)
    up = np.stack([cl * co, cl * so, sl + z], axis=-1)
    return np.stack([east, north, up], axis=-1)


def field_enu_nT(
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
    alt_m: ArrayLike,
    t_utc: Times,
    max_degree: int = 13,
) -> Array:
    """IGRF field (nT) in local geodetic east-north-up axes.

    Positions are scalars or arrays broadcast together; with a sequence of N times, position
    arrays of length N are paired with the times (a moving platform). Output shape: (3,) for
    one position and time, else (N, 3). Coefficients are taken per UTC day (noon).
    """
    import ppigrf

    times, single = _as_times(t_utc)
    lat, lon, alt = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in
                                         (lat_deg, lon_deg, alt_m)))
    if lat.ndim > 1:
        raise ValueError("positions must be scalars or 1-D arrays")
    if not single and lat.ndim == 1 and lat.size != len(times):
        raise ValueError(f"{lat.size} positions for {len(times)} times")
    if np.any(np.abs(lat) > 90):
        raise ValueError("latitude must be within ±90°")
    n = len(times) if not single else max(lat.size, 1)
    lat, lon, alt = (np.broadcast_to(a, (n,)) for a in (lat, lon, alt))
    days = [datetime(t.year, t.month, t.day, 12) for t in times]
    unique = sorted(set(days))
    which = np.array([unique.index(d) for d in days]) if not single else np.zeros(n, int)
    # one ppigrf call for all positions and distinct days: output (days, positions)
    be, bn, bu = ppigrf.igrf(lon, lat, alt / 1000.0, unique, max_degree=max_degree)
    cols = np.arange(n)
    out = np.stack([np.asarray(c).reshape(len(unique), n)[which, cols] for c in (be, bn, bu)],
                   axis=-1)
    return out[0] if single and np.ndim(lat_deg) == 0 else out


def field_ecef_nT(
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
    alt_m: ArrayLike,
    t_utc: Times,
    max_degree: int = 13,
) -> Array:
    """IGRF field (nT) in ECEF axes; arguments and shapes as :func:`field_enu_nT`."""
    b_enu = field_enu_nT(lat_deg, lon_deg, alt_m, t_utc, max_degree)
    n = 1 if b_enu.ndim == 1 else b_enu.shape[0]
    r = np.broadcast_to(r_ecef_enu(np.broadcast_to(lat_deg, (n,)),
                                   np.broadcast_to(lon_deg, (n,))), (n, 3, 3))
    out = np.einsum("nij,nj->ni", r, b_enu.reshape(n, 3))
    return out.reshape(b_enu.shape)


def field_icrs_nT(
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
    alt_m: ArrayLike,
    t_utc: Times,
    max_degree: int = 13,
) -> Array:
    """IGRF field (nT) in ICRS axes at a geodetic position and UTC time(s).

    Args:
        lat_deg, lon_deg: geodetic (WGS-84) latitude and east longitude, degrees.
        alt_m: height above the WGS-84 ellipsoid, m.
        t_utc: a ``datetime`` (naive = UTC; aware ones are converted) or a sequence of them.
        max_degree: highest spherical-harmonic degree (1 = the dipole).

    Returns:
        (3,) for one time and position, else (N, 3). Rotation accuracy ≤ ~30″ (module
        docstring).
    """
    b_ecef = field_ecef_nT(lat_deg, lon_deg, alt_m, t_utc, max_degree)
    times, _ = _as_times(t_utc)
    r = r_icrs_ecef(times)  # (N, 3, 3): one per time
    if b_ecef.ndim == 1:
        return r[0] @ b_ecef
    return np.einsum("nij,nj->ni", np.broadcast_to(r, (b_ecef.shape[0], 3, 3)), b_ecef)


class MagnetometerModel:
    """Three-axis magnetometer: ``b_meas = S · b_true + h + n`` (body frame, nT).

    Args:
        noise_nT: white-noise standard deviation per axis (scalar or (3,)), nT.
        hard_iron_nT: constant bias h in the body frame, nT.
        soft_iron: 3×3 matrix S (identity = none); must be invertible.
        seed: seed of the ``np.random.Generator`` (or a Generator).

    Example:
        >>> mag = MagnetometerModel(soft_iron=np.diag([1.1, 1.0, 0.9]))
        >>> mag.measure([100.0, 100.0, 100.0]).round(6).tolist()
        [110.0, 100.0, 90.0]
    """

    def __init__(
        self,
        noise_nT: ArrayLike = 0.0,
        hard_iron_nT: ArrayLike = 0.0,
        soft_iron: ArrayLike | None = None,
        seed: int | np.random.Generator | None = 0,
    ) -> None:
        self.noise_nT = np.broadcast_to(np.asarray(noise_nT, np.float64), (3,)).copy()
        self.hard_iron_nT = np.broadcast_to(np.asarray(hard_iron_nT, np.float64), (3,)).copy()
        s = np.eye(3) if soft_iron is None else np.asarray(soft_iron, np.float64)
        if s.shape != (3, 3) or not np.all(np.isfinite(s)):
            raise ValueError(f"soft_iron must be a finite 3x3 matrix, got shape {s.shape}")
        if abs(np.linalg.det(s)) < 1e-9:
            raise ValueError("soft_iron must be invertible")
        if np.any(self.noise_nT < 0) or not np.all(np.isfinite(self.noise_nT)):
            raise ValueError("noise_nT must be finite and >= 0")
        if not np.all(np.isfinite(self.hard_iron_nT)):
            raise ValueError("hard_iron_nT must be finite")
        self.soft_iron = s
        self._seed = seed
        self.reset()

    def reset(self) -> None:
        """Re-seed the noise generator (a run is then reproduced exactly)."""
        seed = self._seed
        self._rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)

    def measure(self, b_true_body_nT: ArrayLike) -> Array:
        """Measured field for true body-frame field(s) (3,) or (N, 3), nT."""
        b = np.asarray(b_true_body_nT, dtype=np.float64)
        if b.shape[-1] != 3:
            raise ValueError(f"field must have 3 components, got shape {b.shape}")
        noise = self._rng.standard_normal(b.shape) * self.noise_nT
        return b @ self.soft_iron.T + self.hard_iron_nT + noise

    def correct(self, b_meas_nT: ArrayLike) -> Array:
        """Remove hard and soft iron: ``S⁻¹ (b_meas − h)`` (the noise stays)."""
        b = np.asarray(b_meas_nT, dtype=np.float64)
        return np.linalg.solve(self.soft_iron, (b - self.hard_iron_nT).T).T
