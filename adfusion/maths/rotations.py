"""Rotations: Hamilton scalar-first quaternions, matrices, exp/log maps, RA/Dec/roll.

The one place in the code base where rotation conventions live (docs/conventions.md):

* quaternions are Hamilton, scalar first ``[w, x, y, z]``, unit norm, stored with w ≥ 0;
* ``q_a_b`` rotates vectors from frame b into frame a: ``v_a = R(q_a_b) @ v_b``;
* composition ``q_a_c = q_a_b ⊗ q_b_c`` is :func:`multiply`;
* the exponential map is the right-handed rotation by ``|φ|`` about ``φ/|φ|``, so
  ``R(exp(φ)) = expm([φ]×)`` — GTSAM's ``Rot3.Expmap`` and scipy's ``from_rotvec``.

It lives in ``starid`` (not ``adfusion``) because ``starid`` sits at the bottom of the
dependency graph and needs it; the filters use it too (one implementation).

Every function accepts a single quaternion ``(4,)`` / vector ``(3,)`` or stacks
``(N, 4)`` / ``(N, 3)`` and broadcasts like numpy.

Example:
    >>> import numpy as np
    >>> from adfusion.maths import rotations as rot
    >>> q_b_a = rot.exp_map([0.0, 0.0, np.pi / 2])       # 90° about +z
    >>> np.round(rot.rotate(q_b_a, [1.0, 0.0, 0.0]), 12).tolist()
    [0.0, 1.0, 0.0]
    >>> q = rot.multiply(q_b_a, rot.inverse(q_b_a))
    >>> np.allclose(q, [1, 0, 0, 0])
    True
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:  # optional heavy dependencies, imported lazily
    import gtsam
    from scipy.spatial.transform import Rotation

__all__ = [
    "IDENTITY",
    "angle_between",
    "canonical",
    "conjugate",
    "cross",
    "exp_map",
    "exp_map_floats",
    "from_gtsam",
    "from_matrix",
    "from_scipy",
    "hamilton",
    "inverse",
    "log_map",
    "log_map_floats",
    "multiply",
    "normalize",
    "normalize_floats",
    "q_cam_icrs_from_radec_roll",
    "radec_roll_from_q_cam_icrs",
    "radec_to_vector",
    "right_matrix",
    "rotate",
    "rotate_floats",
    "skew",
    "small_angle",
    "to_gtsam",
    "to_matrix",
    "to_scipy",
    "vector_to_radec",
]

Array = NDArray[np.float64]
IDENTITY: Array = np.array([1.0, 0.0, 0.0, 0.0])
IDENTITY.setflags(write=False)


def _as_quat(q: ArrayLike) -> Array:
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1] != 4:
        raise ValueError(f"quaternion must have 4 components [w, x, y, z], got shape {q.shape}")
    return q


def _as_vec3(v: ArrayLike, what: str = "vector") -> Array:
    v = np.asarray(v, dtype=np.float64)
    if v.shape[-1] != 3:
        raise ValueError(f"{what} must have 3 components, got shape {v.shape}")
    return v


def canonical(q: ArrayLike) -> Array:
    """Return the one of ±q with w > 0 (q and −q are the same rotation).

    For w = 0 exactly (180° rotations) the first non-zero of x, y, z is made positive, so
    every rotation has one stored form.
    """
    q = _as_quat(q)
    nonzero = q != 0.0
    first = np.argmax(nonzero, axis=-1)[..., None]
    lead = np.take_along_axis(q, first, axis=-1)
    return q * np.where(lead < 0.0, -1.0, 1.0)


def normalize(q: ArrayLike) -> Array:
    """Unit-normalise and canonicalise (w ≥ 0). Raises on zero or non-finite input.

    >>> normalize([2.0, 0.0, 0.0, 0.0]).tolist()
    [1.0, 0.0, 0.0, 0.0]
    """
    q = _as_quat(q)
    if q.ndim == 1:  # scalar fast path (priors, filters: once per step)
        w, x, y, z = q.tolist()
        n = math.hypot(w, x, y, z)
        if not (math.isfinite(n) and n > 0.0):
            raise ValueError("cannot normalise a zero or non-finite quaternion")
        if w < 0.0 or (w == 0.0 and (x < 0.0 or (x == 0.0 and (y < 0.0 or (
                y == 0.0 and z < 0.0))))):
            n = -n
        return np.array([w / n, x / n, y / n, z / n])
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(q)) or np.any(n == 0.0):
        raise ValueError("cannot normalise a zero or non-finite quaternion")
    return canonical(q / n)


def multiply(p: ArrayLike, q: ArrayLike) -> Array:
    """Hamilton product p ⊗ q, so that ``R(p ⊗ q) = R(p) @ R(q)`` (q_a_c = q_a_b ⊗ q_b_c).

    The result is not re-canonicalised (keeps the product smooth for integration);
    call :func:`normalize` before storing.
    """
    p, q = _as_quat(p), _as_quat(q)
    if p.ndim == 1 and q.ndim == 1:  # one pair (per frame in the estimator): in floats
        return np.array(hamilton(p.tolist(), q.tolist()))
    return np.stack(hamilton(np.moveaxis(p, -1, 0), np.moveaxis(q, -1, 0)), axis=-1)


def hamilton(p, q) -> tuple:
    """The Hamilton product's four components from the two quaternions' [w, x, y, z]
    components — floats (the filters' hot path: no array per call) or arrays alike, with
    the same operations in the same order, so :func:`multiply` gives the same bits either
    way.

    >>> hamilton((0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0))  # i ⊗ j = k
    (0.0, 0.0, 0.0, 1.0)
    """
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)  # fmt: skip


# --- the float fast path (the filters' and tracking's hot path: no array per call) -------


def exp_map_floats(tx: float, ty: float, tz: float) -> tuple[float, float, float, float]:
    """Quaternion of the rotation vector (tx, ty, tz); exact, Taylor branch near zero.

    >>> [round(c, 6) for c in exp_map_floats(0.0, 0.0, math.pi / 2)]
    [0.707107, 0.0, 0.0, 0.707107]
    """
    n = math.sqrt(tx * tx + ty * ty + tz * tz)
    if n < 1e-6:
        k = 0.5 - n * n / 48.0
        return (1.0 - n * n / 8.0, k * tx, k * ty, k * tz)
    k = math.sin(0.5 * n) / n
    return (math.cos(0.5 * n), k * tx, k * ty, k * tz)


def normalize_floats(q: tuple[float, ...]) -> tuple[float, float, float, float]:
    """Unit quaternion with w ≥ 0 (the stored sign convention, so a state never flips)."""
    w, x, y, z = q
    s = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:  # keep the stored sign convention (w ≥ 0) so the state never flips
        s = -s
    return (w * s, x * s, y * s, z * s)


def log_map_floats(q: tuple[float, ...]) -> tuple[float, float, float]:
    """Rotation vector (angle ≤ π) of a unit quaternion."""
    w, x, y, z = q
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    if s < 1e-9:
        k = 2.0 / w * (1.0 + s * s / (6.0 * w * w))
    else:
        k = 2.0 * math.atan2(s, w) / s
    return (k * x, k * y, k * z)


def rotate_floats(q: tuple[float, ...],
                  v: tuple[float, float, float]) -> tuple[float, float, float]:
    """R(q) v for a unit quaternion: v + 2w (u × v) + 2 u × (u × v)."""
    w, x, y, z = q
    vx, vy, vz = v
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (vx + w * tx + y * tz - z * ty,
            vy + w * ty + z * tx - x * tz,
            vz + w * tz + x * ty - y * tx)  # fmt: skip


def right_matrix(q: tuple[float, ...]) -> Array:
    """4×4 M with ``p ⊗ q = M @ p`` (right multiplication by a fixed quaternion).

    >>> p, q = (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0)
    >>> (right_matrix(q) @ np.array(p)).tolist() == list(hamilton(p, q))
    True
    """
    w, x, y, z = q
    return np.array([[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]])


def conjugate(q: ArrayLike) -> Array:
    """Quaternion conjugate [w, −x, −y, −z]."""
    return _as_quat(q) * np.array([1.0, -1.0, -1.0, -1.0])


def inverse(q: ArrayLike) -> Array:
    """Inverse rotation: ``inverse(q_a_b) = q_b_a`` (conjugate over squared norm)."""
    q = _as_quat(q)
    return conjugate(q) / np.sum(q * q, axis=-1, keepdims=True)


def to_matrix(q: ArrayLike) -> Array:
    """Rotation matrix R(q), shape (3, 3) or (N, 3, 3); q need not be exactly unit."""
    q = _as_quat(q)
    if q.ndim == 1:  # scalar fast path: the solver and filters call this per frame
        w, x, y, z = (q / np.sqrt(q @ q)).tolist()
        return np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ])
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    r = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )  # fmt: skip
    return r.reshape((*q.shape[:-1], 3, 3))


def from_matrix(r: ArrayLike, orthonormalize: bool = True) -> Array:
    """Quaternion (w ≥ 0) of a rotation matrix, by Shepperd's method (stable for all angles).

    The input is first projected onto SO(3) by SVD, so a slightly non-orthogonal matrix
    (accumulated round-off) gives the nearest rotation; a reflection (det < 0) raises.
    ``orthonormalize=False`` skips that for matrices known to be rotations (hot paths).
    """
    r = np.asarray(r, dtype=np.float64)
    if r.shape[-2:] != (3, 3):
        raise ValueError(f"rotation matrix must be 3x3, got shape {r.shape}")
    if orthonormalize:
        u, _, vt = np.linalg.svd(r)
        if np.any(np.linalg.det(u @ vt) < 0):
            raise ValueError("matrix is a reflection (det < 0), not a rotation")
        r = u @ vt
    if r.ndim == 2:
        return _from_matrix_single(r)
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    trace = m00 + m11 + m22
    cand = np.stack([trace, m00, m11, m22], axis=-1)
    k = np.argmax(cand, axis=-1)
    # one branch per largest diagonal term; all computed, the stable one selected
    with np.errstate(divide="ignore", invalid="ignore"):
        q = _shepperd_branches(r, m00, m11, m22, trace, k)
    return normalize(q)


def _from_matrix_single(r: Array) -> Array:
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = r.tolist()
    tr = m00 + m11 + m22
    k = max(range(4), key=(tr, m00, m11, m22).__getitem__)
    if k == 0:
        t = 2.0 * math.sqrt(max(1.0 + tr, 0.0))
        q = [0.25 * t, (m21 - m12) / t, (m02 - m20) / t, (m10 - m01) / t]
    elif k == 1:
        t = 2.0 * math.sqrt(max(1.0 + m00 - m11 - m22, 0.0))
        q = [(m21 - m12) / t, 0.25 * t, (m01 + m10) / t, (m02 + m20) / t]
    elif k == 2:
        t = 2.0 * math.sqrt(max(1.0 - m00 + m11 - m22, 0.0))
        q = [(m02 - m20) / t, (m01 + m10) / t, 0.25 * t, (m12 + m21) / t]
    else:
        t = 2.0 * math.sqrt(max(1.0 - m00 - m11 + m22, 0.0))
        q = [(m10 - m01) / t, (m02 + m20) / t, (m12 + m21) / t, 0.25 * t]
    n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) ** 0.5
    lead = next((c for c in q if c != 0.0), 1.0)  # canonical sign, as in canonical()
    s = (1.0 if lead > 0 else -1.0) / n
    return np.array([q[0] * s, q[1] * s, q[2] * s, q[3] * s])


def cross(a: ArrayLike, b: ArrayLike) -> Array:
    """Row-wise cross product of (N, 3) arrays (several times faster than np.cross)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a, b = np.broadcast_arrays(a, b)
    out = np.empty(a.shape)
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def _shepperd_branches(r: Array, m00: Array, m11: Array, m22: Array, trace: Array,
                       k: NDArray[np.intp]) -> Array:
    t = np.sqrt(np.maximum(1.0 + trace, 0.0)) * 2
    b0 = np.stack(
        [0.25 * t, (r[..., 2, 1] - r[..., 1, 2]) / t,
         (r[..., 0, 2] - r[..., 2, 0]) / t, (r[..., 1, 0] - r[..., 0, 1]) / t], axis=-1)
    t = np.sqrt(np.maximum(1.0 + m00 - m11 - m22, 0.0)) * 2
    b1 = np.stack(
        [(r[..., 2, 1] - r[..., 1, 2]) / t, 0.25 * t,
         (r[..., 0, 1] + r[..., 1, 0]) / t, (r[..., 0, 2] + r[..., 2, 0]) / t], axis=-1)
    t = np.sqrt(np.maximum(1.0 - m00 + m11 - m22, 0.0)) * 2
    b2 = np.stack(
        [(r[..., 0, 2] - r[..., 2, 0]) / t, (r[..., 0, 1] + r[..., 1, 0]) / t,
         0.25 * t, (r[..., 1, 2] + r[..., 2, 1]) / t], axis=-1)
    t = np.sqrt(np.maximum(1.0 - m00 - m11 + m22, 0.0)) * 2
    b3 = np.stack(
        [(r[..., 1, 0] - r[..., 0, 1]) / t, (r[..., 0, 2] + r[..., 2, 0]) / t,
         (r[..., 1, 2] + r[..., 2, 1]) / t, 0.25 * t], axis=-1)  # fmt: skip
    return np.choose(k[..., None], [b0, b1, b2, b3])


def rotate(q: ArrayLike, v: ArrayLike) -> Array:
    """Rotate vectors: ``rotate(q_a_b, v_b) = v_a``. Broadcasts (4,)×(N,3) and (N,4)×(N,3)."""
    r = to_matrix(q)
    v = _as_vec3(v)
    if r.ndim == 2:
        return v @ r.T
    return np.einsum("...ij,...j->...i", r, v)


def skew(v: ArrayLike) -> Array:
    """Cross-product matrix [v]×, so ``skew(a) @ b == np.cross(a, b)``."""
    x, y, z = np.moveaxis(_as_vec3(v), -1, 0)
    zero = np.zeros_like(x)
    m = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1)
    return m.reshape((*np.shape(x), 3, 3))


def exp_map(phi: ArrayLike) -> Array:
    """Rotation vector (rad) → unit quaternion; accurate near zero (Taylor branch)."""
    phi = _as_vec3(phi, "rotation vector")
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * angle
    small = angle < 1e-6
    safe = np.where(small, 1.0, angle)
    # sin(θ/2)/θ → 1/2 − θ²/48 for small θ
    k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / safe)
    q = np.concatenate([np.cos(half), k * phi], axis=-1)
    return canonical(q)


def log_map(q: ArrayLike) -> Array:
    """Unit quaternion → rotation vector (rad) with angle in [0, π]."""
    q = canonical(_as_quat(q))
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w = np.clip(q[..., :1], -1.0, 1.0)
    xyz = q[..., 1:]
    s = np.linalg.norm(xyz, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, w)
    small = s < 1e-9
    # θ/sin(θ/2) → 2/w · (1 + s²/(6w²)) near zero
    k = np.where(small, 2.0 / w * (1.0 + s**2 / (6.0 * w**2)), angle / np.where(small, 1.0, s))
    return k * xyz


def small_angle(dtheta: ArrayLike) -> Array:
    """First-order quaternion of a small rotation, ``normalize([1, δθ/2])``.

    This is the multiplicative-filter reset form; use :func:`exp_map` for finite angles.
    """
    d = _as_vec3(dtheta, "rotation vector")
    q = np.concatenate([np.ones((*d.shape[:-1], 1)), 0.5 * d], axis=-1)
    return normalize(q)


def angle_between(p: ArrayLike, q: ArrayLike) -> NDArray[np.float64] | float:
    """Angle (rad) of the rotation taking q to p: ``|log(p ⊗ q⁻¹)|``, in [0, π]."""
    p, q = _as_quat(p), _as_quat(q)
    if p.ndim == 1 and q.ndim == 1:  # scalar fast path (per frame in tracking, filters)
        (a0, a1, a2, a3), (b0, b1, b2, b3) = p.tolist(), q.tolist()
        ka = 1.0 / math.sqrt(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3)
        kb = 1.0 / math.sqrt(b0 * b0 + b1 * b1 + b2 * b2 + b3 * b3)
        if a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3 < 0:
            kb = -kb
        a0, a1, a2, a3 = a0 * ka, a1 * ka, a2 * ka, a3 * ka
        b0, b1, b2, b3 = b0 * kb, b1 * kb, b2 * kb, b3 * kb
        dm = math.sqrt((a0 - b0) ** 2 + (a1 - b1) ** 2 + (a2 - b2) ** 2 + (a3 - b3) ** 2)
        dp = math.sqrt((a0 + b0) ** 2 + (a1 + b1) ** 2 + (a2 + b2) ** 2 + (a3 + b3) ** 2)
        return 4.0 * math.atan2(dm, dp)
    p = p / np.linalg.norm(p, axis=-1, keepdims=True)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = q * np.where(np.sum(p * q, axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
    # 4·atan2(|p−q|, |p+q|) keeps full precision near 0, where 2·acos(p·q) loses half
    return 4.0 * np.arctan2(np.linalg.norm(p - q, axis=-1), np.linalg.norm(p + q, axis=-1))


# --- sky directions ---------------------------------------------------------------


def radec_to_vector(ra_rad: ArrayLike, dec_rad: ArrayLike) -> Array:
    """Unit vector(s) in the equatorial frame: x to (0, 0), y to (90°, 0), z to the pole.

    >>> np.round(radec_to_vector(np.pi / 2, 0.0), 12).tolist()
    [0.0, 1.0, 0.0]
    """
    ra = np.asarray(ra_rad, dtype=np.float64)
    dec = np.asarray(dec_rad, dtype=np.float64)
    cd = np.cos(dec)
    return np.stack([cd * np.cos(ra), cd * np.sin(ra), np.sin(dec)], axis=-1)


def vector_to_radec(v: ArrayLike) -> tuple[Array, Array]:
    """(ra, dec) in rad of direction vector(s); ra in [0, 2π). Need not be unit length."""
    v = _as_vec3(v)
    ra = np.mod(np.arctan2(v[..., 1], v[..., 0]), 2 * np.pi)
    dec = np.arctan2(v[..., 2], np.hypot(v[..., 0], v[..., 1]))
    return ra, dec


def _north_east(boresight: Array) -> tuple[Array, Array]:
    """Local north and east unit vectors at a direction (east = z × b, north = b × east)."""
    z = np.array([0.0, 0.0, 1.0])
    east = np.cross(z, boresight)
    n = np.linalg.norm(east, axis=-1, keepdims=True)
    # at the poles "north" is undefined: take the direction of ra = 0 as reference
    pole = n[..., 0] < 1e-12
    if np.any(pole):
        east = np.where(pole[..., None], np.array([0.0, 1.0, 0.0]), east)
        n = np.where(pole[..., None], 1.0, n)
    east = east / n
    north = np.cross(boresight, east)
    return north, east


def q_cam_icrs_from_radec_roll(ra_rad: ArrayLike, dec_rad: ArrayLike, roll_rad: ArrayLike) -> Array:
    """Camera attitude from boresight RA/Dec and roll.

    Camera frame (docs/conventions.md): +z boresight, +x image right, +y image down. Roll is the
    angle from celestial north to the image "up" direction (−y), positive towards east.
    At roll 0, north is up and east is to the *left*, as the sky looks from inside.

    >>> q = q_cam_icrs_from_radec_roll(np.radians(30), np.radians(20), np.radians(10))
    >>> [float(np.degrees(a)).__round__(9) for a in radec_roll_from_q_cam_icrs(q)]
    [30.0, 20.0, 10.0]
    """
    b = radec_to_vector(ra_rad, dec_rad)
    north, east = _north_east(b)
    roll = np.asarray(roll_rad, dtype=np.float64)[..., None]
    up = np.cos(roll) * north + np.sin(roll) * east
    y_cam = -up
    x_cam = np.cross(y_cam, b)
    r_icrs_cam = np.stack([x_cam, y_cam, b], axis=-1)  # columns: camera axes in ICRS
    return from_matrix(np.swapaxes(r_icrs_cam, -1, -2))


def radec_roll_from_q_cam_icrs(q_cam_icrs: ArrayLike) -> tuple[Array, Array, Array]:
    """Inverse of :func:`q_cam_icrs_from_radec_roll`: (ra, dec, roll) in rad, ra and roll
    in [0, 2π)."""
    r = to_matrix(q_cam_icrs)  # rows: camera axes in ICRS
    b = r[..., 2, :]
    up = -r[..., 1, :]
    ra, dec = vector_to_radec(b)
    north, east = _north_east(b)
    roll = np.mod(np.arctan2(np.sum(up * east, -1), np.sum(up * north, -1)), 2 * np.pi)
    return ra, dec, roll


# --- other libraries ------------------------------------------------------------------


def to_scipy(q: ArrayLike) -> Rotation:
    """scipy ``Rotation`` with the same active rotation (``as_matrix() == to_matrix(q)``)."""
    from scipy.spatial.transform import Rotation

    q = _as_quat(q)
    return Rotation.from_quat(q[..., [1, 2, 3, 0]])  # scipy is scalar-last


def from_scipy(r: Rotation) -> Array:
    """Quaternion (w ≥ 0) of a scipy ``Rotation``."""
    return normalize(np.asarray(r.as_quat())[..., [3, 0, 1, 2]])


def to_gtsam(q: ArrayLike) -> gtsam.Rot3:
    """GTSAM ``Rot3`` of a single quaternion (``Rot3.Quaternion(w, x, y, z)``: same convention)."""
    import gtsam

    w, x, y, z = normalize(q).reshape(4)
    return gtsam.Rot3.Quaternion(float(w), float(x), float(y), float(z))


def from_gtsam(r: Any) -> Array:
    """Quaternion (w ≥ 0) of a GTSAM ``Rot3``."""
    g = r.toQuaternion()
    return normalize(np.array([g.w(), g.x(), g.y(), g.z()]))
