"""Pass planning (tubsat.md §6.2–§6.4): where the satellite is, where the target is, the
best time to record, and the slews that point the boresight there at that time.

* :class:`Orbit` — SGP4 (the ``sgp4`` package) from a TLE or from mean elements; positions
  in the TEME frame, which the thesis (and its SGP4 library) used as the inertial frame Q;
* :func:`gmst_rad` — the Greenwich sidereal angle θ_G (``sgp4``'s IAU-82 ``gstime``);
* :func:`earth_target_icrs_km` — Eq. 5.21: ``B_Q = R·(cosβ·cos(θ_G+λ), cosβ·sin(θ_G+λ),
  sinβ)`` on a sphere of radius R = 6378 km (configurable);
* :func:`best_time` — from t0 in 1 s steps, the **first** local maximum of the target's
  elevation of the satellite (= minimum slant range);
* :func:`plan_slews` — the slew angles at that time, X-then-Y or legacy Z-then-X, plus the
  AZ-nulling turn.

Example (a DLR-TUBSAT-like sun-synchronous orbit from mean elements):
    >>> from datetime import UTC, datetime
    >>> orb = Orbit.from_elements(datetime(2003, 2, 27, 22, 0, tzinfo=UTC), altitude_km=720,
    ...                           inclination_deg=98.4, raan_deg=150.0, mean_anomaly_deg=0.0)
    >>> t, el = best_time(orb, datetime(2003, 2, 27, 22, 0, tzinfo=UTC), 13.3, 52.5)
    >>> t.tzinfo is UTC and el > 0
    True
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

import numpy as np
from numpy.typing import ArrayLike, NDArray
from sgp4.api import WGS72, Satrec, jday
from sgp4.propagation import gstime

from adfusion.pointing.slews import az_null, slew, x_then_y, z_then_x

__all__ = ["EARTH_RADIUS_KM", "Orbit", "PassPlan", "best_time", "earth_target_direction",
           "earth_target_icrs_km",
           "elevation_deg", "gmst_rad", "plan_slews", "sky_target_direction"]

EARTH_RADIUS_KM = 6378.0  # the thesis's "mean" radius (really the equatorial one)
_MU_KM3_S2 = 398600.8  # WGS-72, as SGP4


def _utc(t: datetime) -> datetime:
    if t.tzinfo is None:
        raise ValueError(f"times must be timezone-aware UTC datetimes, got naive {t}")
    return t.astimezone(UTC)


def _jd(t: datetime) -> tuple[float, float]:
    t = _utc(t)
    return jday(t.year, t.month, t.day, t.hour, t.minute, t.second + t.microsecond * 1e-6)


def gmst_rad(t: datetime) -> float:
    """Greenwich mean sidereal angle θ_G (rad, [0, 2π)) at UTC ``t`` (UT1 ≈ UTC).

    >>> round(math.degrees(gmst_rad(datetime(2000, 1, 1, 12, tzinfo=UTC))), 3)
    280.461
    """
    jd, fr = _jd(t)
    return float(gstime(jd + fr))


class Orbit:
    """An SGP4 satellite; :meth:`position_km` is TEME (≈ the thesis's inertial Q)."""

    def __init__(self, sat: Satrec) -> None:
        self.sat = sat

    @classmethod
    def from_tle(cls, line1: str, line2: str) -> Orbit:
        """From the two lines of a NORAD TLE."""
        return cls(Satrec.twoline2rv(line1.strip(), line2.strip()))

    @classmethod
    def from_elements(cls, epoch: datetime, altitude_km: float, inclination_deg: float,
                      raan_deg: float, mean_anomaly_deg: float, eccentricity: float = 1e-4,
                      arg_perigee_deg: float = 0.0, bstar: float = 0.0) -> Orbit:
        """A near-circular orbit of mean altitude ``altitude_km`` (SGP4 mean elements)."""
        a = EARTH_RADIUS_KM + float(altitude_km)
        n_rad_min = math.sqrt(_MU_KM3_S2 / a**3) * 60.0
        jd, fr = _jd(epoch)
        sat = Satrec()
        sat.sgp4init(WGS72, "i", 99999, jd + fr - 2433281.5, bstar, 0.0, 0.0, eccentricity,
                     math.radians(arg_perigee_deg), math.radians(inclination_deg),
                     math.radians(mean_anomaly_deg), n_rad_min, math.radians(raan_deg))
        return cls(sat)

    def position_km(self, t: datetime) -> NDArray[np.float64]:
        """Satellite position (km, TEME) at UTC ``t``."""
        jd, fr = _jd(t)
        err, r, _ = self.sat.sgp4(jd, fr)
        if err:
            raise ValueError(f"SGP4 error {err} at {t.isoformat()} (decayed or bad TLE?)")
        return np.asarray(r, dtype=np.float64)

    def positions_km(self, t0: datetime, seconds: ArrayLike) -> NDArray[np.float64]:
        """Positions (N, 3) at ``t0 + seconds`` (vectorised SGP4)."""
        jd, fr = _jd(t0)
        s = np.asarray(seconds, dtype=np.float64)
        err, r, _ = self.sat.sgp4_array(np.full(s.shape, jd), fr + s / 86400.0)
        if np.any(err):
            raise ValueError(f"SGP4 error {int(err[err != 0][0])} after {t0.isoformat()}")
        return r


def earth_target_icrs_km(lon_deg: float, lat_deg: float, gmst: float,
                         radius_km: float = EARTH_RADIUS_KM) -> NDArray[np.float64]:
    """Eq. 5.19–5.21: an Earth-fixed target (east longitude, latitude) in Q (km) at θ_G.

    >>> np.round(earth_target_icrs_km(0.0, 90.0, 1.0), 9).tolist()
    [0.0, 0.0, 6378.0]
    """
    lam, beta = math.radians(lon_deg), math.radians(lat_deg)
    return radius_km * np.array([math.cos(beta) * math.cos(gmst + lam),
                                 math.cos(beta) * math.sin(gmst + lam), math.sin(beta)])


def sky_target_direction(ra_deg: float, de_deg: float) -> NDArray[np.float64]:
    """A sky target (§6.2, the Cassiopeia tests): its direction from Eq. 4.2, the same at
    any time and from any orbit position.

    >>> np.round(sky_target_direction(90.0, 0.0), 12).tolist()
    [0.0, 1.0, 0.0]
    """
    ra, de = math.radians(ra_deg), math.radians(de_deg)
    return np.array([math.cos(de) * math.cos(ra), math.cos(de) * math.sin(ra), math.sin(de)])


def elevation_deg(r_sat_km: ArrayLike, target_km: ArrayLike) -> NDArray[np.float64]:
    """Elevation (deg) of satellite position(s) above a target's horizon (spherical
    Earth: the local vertical is the target's radius vector)."""
    r = np.asarray(r_sat_km, dtype=np.float64)
    b = np.asarray(target_km, dtype=np.float64)
    los = r - b
    up = b / np.linalg.norm(b, axis=-1, keepdims=True)
    s = np.sum(los * up, axis=-1) / np.linalg.norm(los, axis=-1)
    return np.degrees(np.arcsin(np.clip(s, -1.0, 1.0)))


def _elevations(orbit: Orbit, t0: datetime, lon_deg: float, lat_deg: float,
                seconds: NDArray, radius_km: float) -> NDArray[np.float64]:
    r = orbit.positions_km(t0, seconds)
    jd, fr = _jd(t0)
    theta = np.array([gstime(jd + fr + s / 86400.0) for s in seconds.tolist()])
    lam, beta = math.radians(lon_deg), math.radians(lat_deg)
    b = radius_km * np.stack([math.cos(beta) * np.cos(theta + lam),
                              math.cos(beta) * np.sin(theta + lam),
                              np.full(len(theta), math.sin(beta))], -1)
    return elevation_deg(r, b)


def best_time(orbit: Orbit, t0: datetime, lon_deg: float, lat_deg: float, *,
              step_s: float = 1.0, horizon_s: float = 6 * 3600.0,
              min_elevation_deg: float = 0.0,
              radius_km: float = EARTH_RADIUS_KM) -> tuple[datetime, float]:
    """"calc best": the first local maximum of elevation from ``t0`` on, at ``step_s``
    steps, among maxima above ``min_elevation_deg`` (the thesis searched from the current
    time to the coming pass). Returns (UTC time, elevation in deg)."""
    t0 = _utc(t0)
    chunk = 1800.0
    start = 0.0
    prev2 = prev1 = None
    while start < horizon_s:
        s = start + np.arange(0.0, chunk, step_s)
        el = _elevations(orbit, t0, lon_deg, lat_deg, s, radius_km)
        seq = ([] if prev2 is None else [prev2, prev1]) + el.tolist()
        times = ([] if prev2 is None else [s[0] - 2 * step_s, s[0] - step_s]) + s.tolist()
        for k in range(1, len(seq) - 1):
            if seq[k] > seq[k - 1] and seq[k] >= seq[k + 1] and seq[k] > min_elevation_deg:
                return t0 + timedelta(seconds=times[k]), float(seq[k])
        prev2, prev1 = seq[-2], seq[-1]
        start += chunk
    raise ValueError(f"no elevation maximum above {min_elevation_deg}° within "
                     f"{horizon_s / 3600:g} h of {t0.isoformat()}")


@dataclass(frozen=True)
class PassPlan:
    """Slews (axis, angle rad) that point the boresight at ``target_dir_icrs`` and null AZ,
    computed for ``ref_time``; ``q_after`` is the dead-reckoned attitude at the end."""

    ref_time: datetime | None
    target_dir_icrs: NDArray[np.float64]
    slews: list[tuple[str, float]]
    q_after: NDArray[np.float64]


def plan_slews(q_cam_icrs: ArrayLike, target_dir_icrs: ArrayLike, order: str = "XY",
               null_az: bool = True, ref_time: datetime | None = None) -> PassPlan:
    """The slews from ``q_cam_icrs`` to a target direction (Eq. 5.22's ``p``, any length):
    ``order="XY"`` (Eq. 5.23–5.26) or ``"ZX"`` (the legacy order), then AZ nulled."""
    p = np.asarray(target_dir_icrs, dtype=np.float64)
    p = p / np.linalg.norm(p)
    if order == "XY":
        mx, my = x_then_y(q_cam_icrs, p)
        seq = [("X", mx), ("Y", my)]
    elif order == "ZX":
        mz, mx = z_then_x(q_cam_icrs, p)
        seq = [("Z", mz), ("X", mx)]
    else:
        raise ValueError(f"order must be 'XY' or 'ZX', got {order!r}")
    q = np.asarray(q_cam_icrs, dtype=np.float64)
    for axis, a in seq:
        q = slew(q, axis, a)
    if null_az:
        a = az_null(q)
        seq.append(("Z", a))
        q = slew(q, "Z", a)
    return PassPlan(ref_time, p, seq, q)


def earth_target_direction(orbit: Orbit, t: datetime, lon_deg: float, lat_deg: float,
                           radius_km: float = EARTH_RADIUS_KM) -> NDArray[np.float64]:
    """Eq. 5.22: ``p = B_Q − r_sat`` at ``t`` (km, TEME)."""
    return earth_target_icrs_km(lon_deg, lat_deg, gmst_rad(t), radius_km) - orbit.position_km(t)

