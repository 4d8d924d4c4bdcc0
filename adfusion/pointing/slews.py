"""Body-axis slews between star angles (Bleif 2004 §5.1.3, Eq. 5.23–5.28): his manoeuvres.

The thesis: docs/references.md#bleif-2004.

DLR-TUBSAT's attitude control turns about one body axis at a time, so a re-pointing is a
sequence of single-axis slews. Axes are the satellite frame S of
:mod:`adfusion.starid.bleif.star_angles` (X_S image up, Y_S image right, Z_S boresight); a slew
by ``a`` about an axis is right-handed about that axis *of the body* (so a slew about Z_S
by ``a`` increases AZ by ``a``). Attitudes are ``q_cam_icrs`` (camera x = Y_S,
y = −X_S, z = Z_S); angles are radians.

* :func:`x_then_y` — the later version (Eq. 5.23–5.26, with atan2): MX about X_S, then
  MY about the new Y_S put the boresight on the target;
* :func:`z_then_x` — the legacy order of the 2002/2003 passes: MZ about Z_S brings the
  target into the Y_S–Z_S plane, MX about X_S then swings the boresight onto it;
* :func:`az_null` — Eq. 5.27/5.28: the shortest turn about Z_S to AZ = 0 (north up);
* :func:`euler_quaternion` / :func:`star_angles_from_euler_quaternion` — the thesis's
  scalar-last quaternion of (RA, DE, AZ) (Slater's Euler angles, Eq. 5.2–5.18).

Example (Tab. 8.2, 16.12.2002: start attitude to the Cassiopeia target RA 15°, DE 60°):
    >>> import numpy as np
    >>> from adfusion.starid.bleif.star_angles import q_cam_icrs_from_star_angles
    >>> from adfusion.maths.rotations import radec_to_vector
    >>> q0 = q_cam_icrs_from_star_angles(*np.radians([147.65, -9.27, 296.21]))
    >>> mz, mx = z_then_x(q0, radec_to_vector(*np.radians([15.0, 60.0])))
    >>> round(abs(float(np.degrees(mz))), 1), round(abs(float(np.degrees(mx))), 1)
    (1.5, 118.3)
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from adfusion.maths import rotations as rot
from adfusion.starid.bleif.star_angles import star_angles_from_q_cam_icrs, t_sq_from_q_cam_icrs

__all__ = ["AXES_CAM", "az_null", "boresight", "euler_quaternion", "slew",
           "star_angles_from_euler_quaternion", "x_then_y", "z_then_x"]

# the satellite axes in the camera frame
AXES_CAM: dict[str, NDArray[np.float64]] = {
    "X": np.array([0.0, -1.0, 0.0]),
    "Y": np.array([1.0, 0.0, 0.0]),
    "Z": np.array([0.0, 0.0, 1.0]),
}


def slew(q_cam_icrs: ArrayLike, axis: str, angle_rad: float) -> NDArray[np.float64]:
    """The attitude after a right-handed body slew by ``angle_rad`` about S axis ``axis``.

    >>> import numpy as np
    >>> from adfusion.starid.bleif.star_angles import (q_cam_icrs_from_star_angles,
    ...                                          star_angles_from_q_cam_icrs)
    >>> q = slew(q_cam_icrs_from_star_angles(0.5, 0.2, 0.1), "Z", 0.3)
    >>> [round(a, 12) for a in star_angles_from_q_cam_icrs(q)]
    [0.5, 0.2, 0.4]
    """
    if axis not in AXES_CAM:
        raise ValueError(f"axis must be 'X', 'Y' or 'Z', got {axis!r}")
    # the body turns by +a about its own axis e: camera ← icrs gains Rot(e, −a) on the left
    return rot.multiply(rot.exp_map(-float(angle_rad) * AXES_CAM[axis]),
                        np.asarray(q_cam_icrs, dtype=np.float64))


def boresight(q_cam_icrs: ArrayLike) -> NDArray[np.float64]:
    """The boresight Z_S in ICRS."""
    return rot.to_matrix(q_cam_icrs)[2]


def _target_in_s(q_cam_icrs: ArrayLike, p_icrs: ArrayLike) -> NDArray[np.float64]:
    p = np.asarray(p_icrs, dtype=np.float64)
    n = float(np.linalg.norm(p))
    if not (np.isfinite(n) and n > 0):
        raise ValueError(f"target direction must be a finite non-zero vector, got {p}")
    return t_sq_from_q_cam_icrs(q_cam_icrs) @ (p / n)  # Eq. 5.23


def x_then_y(q_cam_icrs: ArrayLike, p_icrs: ArrayLike) -> tuple[float, float]:
    """(MX, MY) in rad: slew MX about X_S, then MY about the new Y_S (Eq. 5.24–5.26 with
    atan2, so targets behind the camera are reachable).

    >>> q = rot.IDENTITY
    >>> mx, my = x_then_y(q, [0.3, 0.2, 0.9])
    >>> q2 = slew(slew(q, "X", mx), "Y", my)
    >>> bool(np.degrees(np.arccos(boresight(q2) @ np.array([0.3, 0.2, 0.9])
    ...                 / np.linalg.norm([0.3, 0.2, 0.9]))) < 1e-6)
    True
    """
    u = _target_in_s(q_cam_icrs, p_icrs)
    my = math.asin(max(-1.0, min(1.0, float(u[0]))))  # Eq. 5.25
    mx = math.atan2(-float(u[1]), float(u[2]))  # Eq. 5.26 (atan2 for the full circle)
    return mx, my


def z_then_x(q_cam_icrs: ArrayLike, p_icrs: ArrayLike) -> tuple[float, float]:
    """(MZ, MX) in rad, the legacy order: MZ about Z_S turns the target into the Y_S–Z_S
    plane on +Y_S's side, then MX about X_S (minus the separation, −π…0) swings the
    boresight onto it; ``|MZ| ≤ π``. This is the branch that reproduces Tab. 8.2's
    magnitudes (|Z| 1.5, |X| 118.3 on 16.12.2002)."""
    u = _target_in_s(q_cam_icrs, p_icrs)
    mz = math.atan2(float(u[1]), float(u[0])) - math.pi / 2  # target to +Y_S after the turn
    mz = (mz + math.pi) % (2 * math.pi) - math.pi
    sep = math.acos(max(-1.0, min(1.0, float(u[2]))))
    return mz, -sep


def az_null(q_cam_icrs: ArrayLike) -> float:
    """Eq. 5.27/5.28: the slew about Z_S (rad) that brings AZ to 0 the shortest way.

    >>> from adfusion.starid.bleif.star_angles import q_cam_icrs_from_star_angles
    >>> round(float(np.degrees(az_null(q_cam_icrs_from_star_angles(1.0, 0.5,
    ...       np.radians(283.64))))), 9)
    76.36
    """
    az = math.degrees(star_angles_from_q_cam_icrs(q_cam_icrs)[2])
    alpha = -az if az <= 180.0 else 360.0 - az
    return math.radians(alpha)


def euler_quaternion(ra_rad: float, de_rad: float, az_rad: float,
                     scalar_last: bool = True) -> NDArray[np.float64]:
    """The thesis's quaternion of star angles: ``q_z(RA) ⊗ q_y(−DE) ⊗ q_x(AZ)``, mapping
    the Euler body frame B (x_B = Z_S, y_B = −Y_S, z_B = X_S) into Q; scalar last
    ``(q1, q2, q3, q4)`` as Eq. 5.9–5.12, or scalar first with ``scalar_last=False``.

    >>> np.round(euler_quaternion(0.0, 0.0, 0.0), 12).tolist()
    [0.0, 0.0, 0.0, 1.0]
    """
    q = rot.multiply(rot.multiply(rot.exp_map([0.0, 0.0, ra_rad]),
                                  rot.exp_map([0.0, -de_rad, 0.0])),
                     rot.exp_map([az_rad, 0.0, 0.0]))
    return np.r_[q[1:], q[0]] if scalar_last else q


def star_angles_from_euler_quaternion(q: ArrayLike,
                                      scalar_last: bool = True) -> tuple[float, float, float]:
    """Eq. 5.16–5.18: (RA, DE, AZ) in rad (RA, AZ in [0, 2π)) of the thesis's quaternion.

    >>> [round(a, 12) for a in star_angles_from_euler_quaternion(
    ...     euler_quaternion(1.0, -0.3, 2.0))]
    [1.0, -0.3, 2.0]
    """
    q = np.asarray(q, dtype=np.float64)
    q1, q2, q3, q4 = (q if scalar_last else np.r_[q[1:], q[0]]).tolist()
    de = math.asin(max(-1.0, min(1.0, 2 * (q1 * q3 - q4 * q2))))
    ra = math.atan2(2 * (q1 * q2 + q4 * q3), q4 * q4 + q1 * q1 - q2 * q2 - q3 * q3)
    az = math.atan2(2 * (q2 * q3 + q4 * q1), q4 * q4 - q1 * q1 - q2 * q2 + q3 * q3)
    return ra % (2 * math.pi), de, az % (2 * math.pi)
