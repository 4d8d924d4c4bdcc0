"""Bleif's star angles (RA, DE, AZ) of a camera attitude, and his transformation T_SQ.

DLR-TUBSAT (Bleif 2004 §4.2.1, docs/references.md#bleif-2004) describes an attitude by the
boresight's right ascension RA and
declination DE and by AZ, the rotation about the boresight: the angle of the image "up"
axis X_S from celestial north towards *west*. The satellite frame S has X_S = image up,
Y_S = image right, Z_S = boresight; in our camera frame (x right, y down, z boresight)
that is X_S = −y_cam, Y_S = x_cam, Z_S = z_cam. So AZ is our roll
(:func:`starid.rotations.radec_roll_from_q_cam_icrs`, north towards *east*) with the
opposite sign: ``AZ = −roll (mod 360°)``.

``T_SQ`` (Eq. 4.1, rebuilt from the thesis) has the S axes, expressed in the inertial
frame Q (= ICRS here), as rows. Angles are radians, as everywhere inside the library.

Example:
    >>> import numpy as np
    >>> T = t_sq(0.0, 0.0, 0.0)            # zero attitude: boresight to the equinox
    >>> (np.round(T, 12) + 0.0).tolist()
    [[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]]
    >>> q = q_cam_icrs_from_star_angles(*np.radians([147.65, -9.27, 296.21]))
    >>> [round(float(np.degrees(a)), 9) for a in star_angles_from_q_cam_icrs(q)]
    [147.65, -9.27, 296.21]
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from adfusion.maths import rotations as rot

__all__ = ["q_cam_icrs_from_star_angles", "q_cam_icrs_from_t_sq",
           "star_angles_from_q_cam_icrs", "t_sq", "t_sq_from_q_cam_icrs"]


def t_sq(ra_rad: float, de_rad: float, az_rad: float) -> NDArray[np.float64]:
    """Eq. 4.1: the rows are X_S, Y_S, Z_S in the inertial frame Q (3×3, orthonormal).

    >>> bool(np.allclose(t_sq(0.3, 0.2, 0.1)[2], [np.cos(.2) * np.cos(.3),
    ...                                             np.cos(.2) * np.sin(.3), np.sin(.2)]))
    True
    """
    sr, cr = np.sin(ra_rad), np.cos(ra_rad)
    sd, cd = np.sin(de_rad), np.cos(de_rad)
    sa, ca = np.sin(az_rad), np.cos(az_rad)
    return np.array([
        [sa * sr - ca * sd * cr, -sa * cr - ca * sd * sr, ca * cd],
        [ca * sr + sa * sd * cr, -ca * cr + sa * sd * sr, -sa * cd],
        [cd * cr, cd * sr, sd],
    ])


def q_cam_icrs_from_t_sq(T: NDArray[np.float64]) -> NDArray[np.float64]:
    """``q_cam_icrs`` of a T_SQ matrix (camera rows: x = Y_S, y = −X_S, z = Z_S).

    >>> q = q_cam_icrs_from_t_sq(t_sq(0.0, 0.0, 0.0))
    >>> np.round(rot.rotate(q, [1.0, 0.0, 0.0]), 12).tolist()    # equinox on the boresight
    [0.0, 0.0, 1.0]
    """
    T = np.asarray(T, dtype=np.float64)
    return rot.from_matrix(np.stack([T[1], -T[0], T[2]]))


def t_sq_from_q_cam_icrs(q_cam_icrs) -> NDArray[np.float64]:
    """Inverse of :func:`q_cam_icrs_from_t_sq`.

    >>> T = t_sq(1.0, 0.5, 2.0)
    >>> bool(np.allclose(t_sq_from_q_cam_icrs(q_cam_icrs_from_t_sq(T)), T))
    True
    """
    R = rot.to_matrix(q_cam_icrs)
    return np.stack([-R[1], R[0], R[2]])


def q_cam_icrs_from_star_angles(ra_rad: float, de_rad: float,
                                az_rad: float) -> NDArray[np.float64]:
    """Camera attitude from star angles (RA, DE of the boresight, AZ north → west).

    >>> q = q_cam_icrs_from_star_angles(0.0, 0.0, np.pi / 2)    # up points west
    >>> (np.round(rot.rotate(rot.inverse(q), [0.0, -1.0, 0.0]), 12) + 0.0).tolist()
    [0.0, -1.0, 0.0]
    """
    return q_cam_icrs_from_t_sq(t_sq(ra_rad, de_rad, az_rad))


def star_angles_from_q_cam_icrs(q_cam_icrs) -> tuple[float, float, float]:
    """(RA, DE, AZ) in rad, RA and AZ in [0, 2π), from ``q_cam_icrs``.

    >>> q = rot.q_cam_icrs_from_radec_roll(0.5, 0.2, 0.3)       # roll is north → east
    >>> round(star_angles_from_q_cam_icrs(q)[2], 12) == round(2 * np.pi - 0.3, 12)
    True
    """
    T = t_sq_from_q_cam_icrs(q_cam_icrs)
    z, x_s = T[2], T[0]
    ra = float(np.mod(np.arctan2(z[1], z[0]), 2 * np.pi))
    de = float(np.arcsin(np.clip(z[2], -1.0, 1.0)))
    # AZ: X_S against the local north and west at the boresight (T_SQ row 1 at AZ = 0 is
    # north, and row 1 at AZ = 90° is west)
    north = t_sq(ra, de, 0.0)[0]
    west = t_sq(ra, de, np.pi / 2)[0]
    az = float(np.mod(np.arctan2(x_s @ west, x_s @ north), 2 * np.pi))
    return ra, de, az
