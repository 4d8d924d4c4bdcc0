"""Yee's angles: image and catalogue position angles, rotation angles, planar and spherical
triangle angles (degrees).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "catalog_angle_deg", "circular_mean_deg", "image_angle_deg", "planar_angles_deg",
    "rotation_angles_deg", "spherical_angles_deg",
]


FloatArray = NDArray[np.float64]


IntArray = NDArray[np.int64]


def _wrap180(a: ArrayLike) -> FloatArray:
    """Angle(s) in degrees wrapped to (−180, 180]."""
    return 180.0 - np.mod(180.0 - np.asarray(a, dtype=np.float64), 360.0)


def image_angle_deg(xy_from: ArrayLike, xy_to: ArrayLike) -> FloatArray:
    """Direction of the image vector ``from → to`` in [0, 360), counter-clockwise from +x.

    Raw pixel offsets in Yee's centred y-up frame, *not* scaled to degrees ([VERIFIED]
    Yee 1999 §2.3.4.1: scaling changes the thesis's rotation angles by up to 0.75°).

    >>> round(float(image_angle_deg([0, 0], [-1, -1])), 6)
    225.0
    """
    d = np.asarray(xy_to, dtype=np.float64) - np.asarray(xy_from, dtype=np.float64)
    return np.mod(np.degrees(np.arctan2(d[..., 1], d[..., 0])), 360.0)


def catalog_angle_deg(radec_from_deg: ArrayLike, radec_to_deg: ArrayLike) -> FloatArray:
    """Direction of the catalogue vector ``from → to`` as on a sky map (§2.6), in [0, 360).

    ``atan2(Δδ, −Δα)`` in raw degrees, Δα wrapped to (−180°, 180°] and without a cos δ
    factor (the thesis's planar treatment, [VERIFIED]); −Δα because east is to the left.

    >>> round(float(catalog_angle_deg([359.0, 10.0], [1.0, 10.0])), 6)   # 2° east, across 0h
    180.0
    """
    a = np.asarray(radec_from_deg, dtype=np.float64)
    b = np.asarray(radec_to_deg, dtype=np.float64)
    d_ra = _wrap180(b[..., 0] - a[..., 0])
    d_dec = b[..., 1] - a[..., 1]
    return np.mod(np.degrees(np.arctan2(d_dec, -d_ra)), 360.0)


def rotation_angles_deg(xy_centred_yup: ArrayLike, radec_deg: ArrayLike) -> tuple[float, float]:
    """Yee's rotation angles 1 and 2 for one triad (§2.6), each in [0, 360).

    ``xy_centred_yup``: (3, 2) image stars 1, 2, 3 (Yee's frame); ``radec_deg``: (3, 2) the
    catalogue stars HR1, HR2, HR3. Rotation n is the counter-clockwise angle taking image
    vector 1→(n+1) onto catalogue vector HR1→HR(n+1): ``(cat − img) mod 360``. The triad
    passes when ``|wrap180(rot1 − rot2)| ≤ tol_rot``.

    >>> rotation_angles_deg([[0, 0], [1, 0], [0, 1]], [[10, 0], [9, 0], [10, 1]])
    (0.0, 0.0)
    """
    p = np.asarray(xy_centred_yup, dtype=np.float64).reshape(3, 2)
    s = np.asarray(radec_deg, dtype=np.float64).reshape(3, 2)
    img = image_angle_deg(p[[0, 0]], p[[1, 2]])
    cat = catalog_angle_deg(s[[0, 0]], s[[1, 2]])
    rot = np.mod(cat - img, 360.0)
    return float(rot[0]), float(rot[1])


def circular_mean_deg(angles_deg: ArrayLike, axis: int = -1) -> FloatArray:
    """Mean direction of angles in degrees, in [0, 360) (wraps correctly across 0°).

    >>> round(float(circular_mean_deg([350.0, 20.0])), 6)
    5.0
    """
    a = np.radians(np.asarray(angles_deg, dtype=np.float64))
    m = np.degrees(np.arctan2(np.sin(a).sum(axis=axis), np.cos(a).sum(axis=axis)))
    return np.mod(m, 360.0)


def planar_angles_deg(p1: ArrayLike, p2: ArrayLike, p3: ArrayLike) -> FloatArray:
    """Inner angles (…, 3) in degrees at the vertices of planar triangle(s) p1 p2 p3.

    >>> np.round(planar_angles_deg([0, 0], [1, 0], [0, 1]), 6).tolist()
    [90.0, 45.0, 45.0]
    """
    pts = [np.asarray(p, dtype=np.float64) for p in (p1, p2, p3)]
    out = []
    for k in range(3):
        o, u, v = pts[k], pts[(k + 1) % 3], pts[(k + 2) % 3]
        a, b = u - o, v - o
        cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        out.append(np.degrees(np.arctan2(np.abs(cross), np.sum(a * b, axis=-1))))
    return np.stack(out, axis=-1)


def _side_angles_rad(v1: FloatArray, v2: FloatArray) -> FloatArray:
    cr = np.cross(v1, v2)
    return np.arctan2(np.linalg.norm(cr, axis=-1), np.sum(v1 * v2, axis=-1))


def spherical_angles_deg(v1: ArrayLike, v2: ArrayLike, v3: ArrayLike) -> FloatArray:
    """Inner angles (…, 3) in degrees at vertices v1, v2, v3 of spherical triangle(s).

    Spherical cosine rule (Eq. 2.5–2.7): ``A = acos((cos a − cos b cos c)/(sin b sin c))``
    with a, b, c the arcs opposite A, B, C.

    >>> np.round(spherical_angles_deg([1, 0, 0], [0, 1, 0], [0, 0, 1]), 6).tolist()
    [90.0, 90.0, 90.0]
    """
    u = [np.asarray(v, dtype=np.float64) for v in (v1, v2, v3)]
    u = [v / np.linalg.norm(v, axis=-1, keepdims=True) for v in u]
    a = _side_angles_rad(u[1], u[2])
    b = _side_angles_rad(u[0], u[2])
    c = _side_angles_rad(u[0], u[1])
    return _cosine_rule_deg(a, b, c)


def _cosine_rule_deg(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """Inner angles at the vertices opposite the arcs a, b, c (radians in, degrees out)."""

    def angle(x: FloatArray, y: FloatArray, z: FloatArray) -> FloatArray:
        with np.errstate(divide="ignore", invalid="ignore"):
            cos_x = (np.cos(x) - np.cos(y) * np.cos(z)) / (np.sin(y) * np.sin(z))
        return np.degrees(np.arccos(np.clip(cos_x, -1.0, 1.0)))

    return np.stack([angle(a, b, c), angle(b, a, c), angle(c, a, b)], axis=-1)
