"""Truth attitude dynamics: torque-free rigid bodies (spin with coning) and prescribed rates.

Both integrate, with scipy's DOP853 (8th-order Dormand-Prince) at tight tolerances
(``rtol=1e-12``, ``atol=1e-14`` by default, dense output), the attitude kinematics of
``q_body_icrs`` (docs/conventions.md: ``v_body = R(q_body_icrs) v_icrs``) driven by the body rate ω
(rad/s, body frame):

    d/dt q_icrs_body = ½ q_icrs_body ⊗ [0, ω]   ⇔   d/dt q_body_icrs = −½ [0, ω] ⊗ q_body_icrs

and, for :func:`simulate_rigid_body`, Euler's equations with a full inertia tensor J,

    J ω̇ = −ω × (J ω) + τ_body(t).

Quaternions are re-normalised (and made w ≥ 0) at the output times only; the integrator's own
error keeps the norm to ~1e-13. Over a minute of spin the inertial angular momentum is
conserved to ~1e-12 relative — truth errors far below any sensor's noise.

Example:
    >>> import numpy as np
    >>> from adfusion.sensors.dynamics import simulate_rigid_body
    >>> traj = simulate_rigid_body(np.diag([10.0, 12.0, 4.0]), [1, 0, 0, 0],
    ...                            [0.05, 0.0, 3.0], np.linspace(0.0, 10.0, 101))
    >>> traj.q_body_icrs.shape, traj.omega_body_rad_s.shape
    ((101, 4), (101, 3))
    >>> h = traj.angular_momentum_icrs(np.diag([10.0, 12.0, 4.0]))
    >>> bool(np.ptp(h, axis=0).max() < 1e-9 * np.linalg.norm(h[0]))
    True
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import solve_ivp

from adfusion.maths.rotations import normalize, rotate, to_matrix

__all__ = ["Trajectory", "simulate_rate_profile", "simulate_rigid_body"]

Array = NDArray[np.float64]
RateFn = Callable[[float], ArrayLike]


@dataclass(frozen=True)
class Trajectory:
    """Truth attitude history.

    Attributes:
        t: (N,) times, s.
        q_body_icrs: (N, 4) unit quaternions ``[w, x, y, z]``, w ≥ 0.
        omega_body_rad_s: (N, 3) body rate in the body frame, rad/s.
    """

    t: Array
    q_body_icrs: Array
    omega_body_rad_s: Array

    def __len__(self) -> int:
        return int(self.t.size)

    def angular_momentum_icrs(self, inertia: ArrayLike) -> Array:
        """(N, 3) angular momentum ``R(q_body_icrs)ᵀ J ω`` in ICRS (kg m²/s for J in kg m²)."""
        h_body = self.omega_body_rad_s @ np.asarray(inertia, np.float64).T
        return np.einsum("nji,nj->ni", to_matrix(self.q_body_icrs), h_body)

    def kinetic_energy(self, inertia: ArrayLike) -> Array:
        """(N,) rotational kinetic energy ``½ ωᵀ J ω``."""
        j = np.asarray(inertia, np.float64)
        return 0.5 * np.einsum("ni,ij,nj->n", self.omega_body_rad_s, j, self.omega_body_rad_s)

    def vectors_in_body(self, v_icrs: ArrayLike) -> Array:
        """One inertial vector (3,) seen in the body frame at every time: (N, 3)."""
        v = np.broadcast_to(np.asarray(v_icrs, np.float64), (len(self), 3))
        return rotate(self.q_body_icrs, v)


def _check_times(times: ArrayLike) -> Array:
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if t.size == 0 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ValueError("times must be a non-empty, finite, strictly increasing sequence")
    return t


def _qdot(q: Array, w: Array) -> Array:
    """d/dt q_body_icrs = −½ [0, ω] ⊗ q."""
    qw, qx, qy, qz = q
    wx, wy, wz = w
    return -0.5 * np.array([
        -wx * qx - wy * qy - wz * qz,
        wx * qw + wy * qz - wz * qy,
        wy * qw - wx * qz + wz * qx,
        wz * qw + wx * qy - wy * qx,
    ])


def _integrate(
    rhs: Callable[[float, Array], Array], y0: Array, t: Array, rtol: float, atol: float
) -> Array:
    if t.size == 1:
        return y0[None, :]
    sol = solve_ivp(rhs, (t[0], t[-1]), y0, method="DOP853", t_eval=t, rtol=rtol, atol=atol)
    if not sol.success:  # pragma: no cover - DOP853 on smooth problems does not fail
        raise RuntimeError(f"integration failed: {sol.message}")
    return sol.y.T


def simulate_rigid_body(
    inertia: ArrayLike,
    q0_body_icrs: ArrayLike,
    omega0_body_rad_s: ArrayLike,
    times: ArrayLike,
    torque_body: Callable[[float, Array, Array], ArrayLike] | None = None,
    rtol: float = 1e-12,
    atol: float = 1e-14,
) -> Trajectory:
    """Rigid-body attitude from Euler's equations (torque-free unless ``torque_body`` given).

    Args:
        inertia: 3×3 symmetric positive-definite inertia tensor in body axes (any unit; only
            ratios matter without torque). A spin about a non-principal axis cones.
        q0_body_icrs: attitude at ``times[0]``.
        omega0_body_rad_s: body rate at ``times[0]``, rad/s.
        times: strictly increasing output times, s (the first is the initial time).
        torque_body: optional ``f(t, q_body_icrs, omega_body) -> (3,)`` torque in body axes,
            in the inertia's units × rad/s².
        rtol, atol: DOP853 tolerances.
    """
    j = np.asarray(inertia, dtype=np.float64)
    if j.shape != (3, 3) or not np.allclose(j, j.T, rtol=0, atol=1e-12 * np.abs(j).max()):
        raise ValueError("inertia must be a symmetric 3x3 matrix")
    if np.linalg.eigvalsh(j).min() <= 0:
        raise ValueError("inertia must be positive definite")
    j_inv = np.linalg.inv(j)
    t = _check_times(times)
    q0 = normalize(np.asarray(q0_body_icrs, dtype=np.float64).reshape(4))
    w0 = np.asarray(omega0_body_rad_s, dtype=np.float64).reshape(3)

    def rhs(tt: float, y: Array) -> Array:
        q, w = y[:4], y[4:]
        h = j @ w
        wdot = -np.cross(w, h)
        if torque_body is not None:
            wdot = wdot + np.asarray(torque_body(tt, q, w), dtype=np.float64)
        return np.concatenate([_qdot(q, w), j_inv @ wdot])

    y = _integrate(rhs, np.concatenate([q0, w0]), t, rtol, atol)
    return Trajectory(t, normalize(y[:, :4]), y[:, 4:].copy())


def simulate_rate_profile(
    omega_body_rad_s: RateFn | ArrayLike,
    q0_body_icrs: ArrayLike,
    times: ArrayLike,
    rtol: float = 1e-12,
    atol: float = 1e-14,
) -> Trajectory:
    """Attitude driven by a prescribed body rate: a callable ``ω(t) -> (3,)`` rad/s, or a
    constant (3,) rate (then the closed form ``q_icrs_body(t) = q_icrs_body(0) ⊗ exp(ω t)``
    is used, exact to round-off).

    The callable should be smooth between output times (a step in ω is integrated as
    accurately as the tolerances allow; put output times at the steps for exactness).
    """
    from adfusion.maths.rotations import exp_map, multiply

    t = _check_times(times)
    q0 = normalize(np.asarray(q0_body_icrs, dtype=np.float64).reshape(4))
    if not callable(omega_body_rad_s):
        w = np.asarray(omega_body_rad_s, dtype=np.float64).reshape(3)
        q = multiply(exp_map(-np.outer(t - t[0], w)), q0)
        return Trajectory(t, normalize(q), np.tile(w, (t.size, 1)))
    fn = omega_body_rad_s

    def rhs(tt: float, y: Array) -> Array:
        return _qdot(y, np.asarray(fn(tt), dtype=np.float64).reshape(3))

    y = _integrate(rhs, q0, t, rtol, atol)
    omega = np.array([np.asarray(fn(tt), dtype=np.float64).reshape(3) for tt in t])
    return Trajectory(t, normalize(y), omega)
