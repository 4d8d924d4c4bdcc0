"""Unscented attitude filter (USQUE) on ``filterpy.kalman.UnscentedKalmanFilter``.

Crassidis & Markley, "Unscented Filtering for Spacecraft Attitude Estimation" (J. Guidance,
Control, and Dynamics 26(4), 2003): the filter state is ``[δp, β]`` — the generalised
Rodrigues parameters (a = 1, f = 4) of the attitude error relative to a reference quaternion,
and the gyro bias itself. The quaternion never enters the unscented transform directly:

* **propagate** — each sigma point's error δp is turned into a quaternion around the
  reference, ``q_i = δq(δp_i) ⊗ q̂``, integrated with its own bias-corrected rate, and expressed
  again as GRPs relative to the propagated *mean* quaternion (that of the central sigma point);
  the weighted mean of the propagated δp is then folded into the reference and zeroed;
* **update** — the measurement of each sigma point is predicted from its quaternion; after the
  update the error estimate is folded into the reference the same way (the reset).

Conventions are the MEKF's (see :mod:`adfusion.estimation.mekf`): the attitude error is on
the left in the body frame, ``q_true = δq ⊗ q̂``, and with a = 1, f = 4 the GRP vector equals
the rotation vector to first order (δp = 4 tan(θ/4) n̂), so the filterpy covariance *is* the MEKF's
``P`` of [δθ, δβ] at the reset point. Process noise: the same Farrenkopf Q as the MEKF
(:func:`adfusion.estimation.mekf.process_noise`); sigma points: Julier's with κ = 1 (all weights
positive; Crassidis & Markley's λ = 1).

Measurements mirror the MEKF's exactly: a direction is compared in the 2-D tangent plane of its
predicted value, an attitude fix as the rotation vector of ``q_meas ⊗ q̂⁻¹``; each update is
NIS-gated and returns an :class:`~adfusion.estimation.mekf.UpdateResult`.

Example:
    >>> import numpy as np
    >>> from adfusion.estimation.ukf import UKF
    >>> f = UKF([1.0, 0.0, 0.0, 0.0], np.radians(1.0), 1e-6, 1e-6, 1e-9)
    >>> f.propagate(1.0, [0.0, 0.0, 0.01])
    >>> r = f.update_vector([1.0, 0.0, 0.0], [1.0, 0.0, 0.0], sigma_rad=1e-3)
    >>> r.accepted, r.dof
    (True, 2)
    >>> np.sqrt(np.diag(f.P)[:3]).round(4).tolist()  # the roll about the direction stays unknown
    [0.0175, 0.001, 0.001]
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from filterpy.kalman import JulierSigmaPoints, UnscentedKalmanFilter
from numpy.typing import ArrayLike, NDArray

from adfusion.estimation.common import (
    check_dt_omega,
    symmetrize,
    tangent_basis,
    tangent_residual,
)
from adfusion.estimation.mekf import AttitudeFilter, UpdateResult, process_noise
from adfusion.maths import rotations as rot

__all__ = ["UKF", "grp_from_quaternion", "quaternion_from_grp"]

Array = NDArray[np.float64]
_A = 1.0  # GRP parameters of USQUE: a = 1, f = 2(a + 1) = 4 makes δp ≈ δθ for small errors
_F = 4.0


def quaternion_from_grp(p: ArrayLike) -> Array:
    """Error quaternion ``[w, x, y, z]`` of GRP vector(s) (a = 1, f = 4); (…, 3) → (…, 4).

    >>> q = quaternion_from_grp([0.0, 0.0, 4.0 * np.tan(np.pi / 8)])  # 90° about z
    >>> np.allclose(q, [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    True
    """
    p = np.asarray(p, dtype=np.float64)
    p2 = np.sum(p * p, axis=-1, keepdims=True)
    # general form: w = (−a|p|² + f √(f² + (1 − a²)|p|²)) / (f² + |p|²), xyz = (a + w) p / f
    w = (-_A * p2 + _F * np.sqrt(_F * _F + (1.0 - _A * _A) * p2)) / (_F * _F + p2)
    return np.concatenate([w, (_A + w) * p / _F], axis=-1)


def grp_from_quaternion(q: ArrayLike) -> Array:
    """GRP vector(s) (a = 1, f = 4) of error quaternion(s), taken with w ≥ 0 (angle ≤ 180°).

    >>> p = grp_from_quaternion(quaternion_from_grp([0.1, -0.2, 0.3]))
    >>> np.allclose(p, [0.1, -0.2, 0.3])
    True
    """
    q = np.asarray(q, dtype=np.float64)
    q = q * np.where(q[..., :1] < 0.0, -1.0, 1.0)  # the short way round
    return _F * q[..., 1:] / (_A + q[..., :1])


def _grp_to_quat_f(px: float, py: float, pz: float) -> tuple[float, float, float, float]:
    """:func:`quaternion_from_grp` for one vector in plain floats (the per-sigma-point hx)."""
    p2 = px * px + py * py + pz * pz
    w = (_F * _F - p2) / (_F * _F + p2)  # the a = 1 case of the general form
    k = (_A + w) / _F
    return (w, k * px, k * py, k * pz)


class _USQUE(UnscentedKalmanFilter):  # type: ignore[misc]
    """filterpy's UKF with the process model applied to all sigma points at once.

    ``compute_process_sigmas`` is the hook filterpy documents for producing ``sigmas_f``; the
    only change is calling ``fx`` once on the (2n+1, n) array instead of once per row (the
    quaternion algebra vectorises; thirteen Python calls per step would dominate the cost).
    """

    def compute_process_sigmas(self, dt: float, fx: Any = None, **fx_args: Any) -> None:
        fx = self.fx if fx is None else fx
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        self.sigmas_f = fx(sigmas, dt, **fx_args)


def _fx(
    sigmas: Array, dt: float, omega: Array, right_ref: Array, right_next_inv: Array
) -> Array:
    """USQUE process model for all sigma points [δp, β] (rows).

    q_i = δq(δp_i) ⊗ q̂, q_i⁺ = Exp(−(ω − β_i) dt) ⊗ q_i, δp_i⁺ = GRP(q_i⁺ ⊗ q̂⁺⁻¹) where q̂⁺ is
    the propagated central sigma point; the bias is a random walk (mean unchanged). The two
    products with a fixed quaternion are matrix products (``right_*`` from
    :func:`rot.right_matrix`), rows at a time.
    """
    q_i = quaternion_from_grp(sigmas[:, :3]) @ right_ref.T
    q_i = rot.multiply(rot.exp_map(-(omega - sigmas[:, 3:]) * dt), q_i)
    out = sigmas.copy()
    out[:, :3] = grp_from_quaternion(q_i @ right_next_inv.T)
    return out


def _hx_vector(
    s: Array, q_ref: tuple[float, ...], r: tuple[float, float, float],
    e1: tuple[float, float, float], e2: tuple[float, float, float],
    p: tuple[float, float, float],
) -> Array:  # fmt: skip
    """Predicted direction of one sigma point, in the tangent basis (e1, e2) of the mean's
    prediction ``p`` (through the log map, as the measurement)."""
    px, py, pz = s[:3].tolist()
    b = rot.rotate_floats(rot.hamilton(_grp_to_quat_f(px, py, pz), q_ref), r)
    return np.array(tangent_residual(e1, e2, p, b))


def _hx_attitude(s: Array) -> Array:
    """Predicted attitude-fix residual of one sigma point: the rotation vector of δq(δp)."""
    px, py, pz = s[:3].tolist()
    return np.array(rot.log_map_floats(_grp_to_quat_f(px, py, pz)))


class UKF(AttitudeFilter):
    """USQUE unscented attitude filter; same interface as :class:`adfusion.estimation.mekf.MEKF`.

    Constructor arguments: see :class:`adfusion.estimation.mekf.AttitudeFilter`; ``kappa`` sets the
    Julier sigma-point spread (√(n + κ) σ). ``P`` is in the MEKF's error convention
    ([δθ body, δβ]); the underlying ``filterpy`` filter is available as ``.filterpy``.

    Example:
        >>> import numpy as np
        >>> f = UKF([1.0, 0, 0, 0], np.radians(1.0), 1e-6, 1e-6, 1e-9)
        >>> for _ in range(10):
        ...     f.propagate(0.1, [0.0, 0.0, 0.01])
        >>> f.update_attitude(f.q_body_icrs, np.eye(3) * 1e-8).accepted
        True
        >>> bool(f.search_cone_deg() < 0.02)  # 3σ ≈ 3 × 1e-4 rad
        True
    """

    def __init__(
        self,
        q_body_icrs: ArrayLike,
        sigma_attitude_rad: ArrayLike,
        sigma_bias_rad_s: ArrayLike,
        arw_rad_sqrt_s: float,
        rrw_rad_s_sqrt_s: float,
        bias_rad_s: ArrayLike | None = None,
        q_body_cam: ArrayLike | None = None,
        *,
        gate_probability: float | None = 0.9999,
        kappa: float = 1.0,
    ) -> None:
        super().__init__(q_body_icrs, sigma_attitude_rad, sigma_bias_rad_s, arw_rad_sqrt_s,
                         rrw_rad_s_sqrt_s, bias_rad_s, q_body_cam,
                         gate_probability=gate_probability)  # fmt: skip
        points = JulierSigmaPoints(6, kappa=kappa)
        u = _USQUE(dim_x=6, dim_z=3, dt=1.0, hx=_hx_attitude, fx=_fx, points=points)
        u.x = np.concatenate([np.zeros(3), self._b0])
        u.P = self._P0.copy()
        self.filterpy: UnscentedKalmanFilter = u
        self._q_dt = math.nan
        self._R2 = np.eye(2)

    @property
    def bias_rad_s(self) -> Array:
        """Gyro bias estimate (rad/s, body frame)."""
        return self.filterpy.x[3:].copy()

    def _cov(self) -> Array:
        return self.filterpy.P

    def _set_bias(self, bias_rad_s: ArrayLike) -> None:
        self.filterpy.x[3:] = np.asarray(bias_rad_s, dtype=np.float64).reshape(3)

    def propagate(self, dt: float, omega_meas_rad_s: ArrayLike) -> None:
        """Advance the state by ``dt`` seconds with one gyro sample (rad/s, body frame).

        Every sigma point is integrated in closed form with its own bias (exact for a
        constant rate over the step). Raises ValueError (state unchanged) on a non-finite
        sample or a step that is not a finite positive number.
        """
        dt, wx, wy, wz = check_dt_omega(dt, omega_meas_rad_s)
        u = self.filterpy
        b = u.x[3:].tolist()
        q_ref = self._q
        step = rot.exp_map_floats(-(wx - b[0]) * dt, -(wy - b[1]) * dt, -(wz - b[2]) * dt)
        q_next = rot.normalize_floats(rot.hamilton(step, q_ref))
        if dt != self._q_dt:
            u.Q = process_noise(dt, self._sv, self._su)
            self._q_dt = dt
        w, x, y, z = q_next
        u.predict(dt=dt, omega=np.array([wx, wy, wz]), right_ref=rot.right_matrix(q_ref),
                  right_next_inv=rot.right_matrix((w, -x, -y, -z)))  # fmt: skip
        u.P = symmetrize(u.P)
        self._q = q_next
        self._fold()

    def _vector_update(
        self, bm: tuple[float, float, float], rr: tuple[float, float, float], sigma: float
    ) -> UpdateResult:
        p = rot.rotate_floats(self._q, rr)
        e1, e2 = tangent_basis(*p)
        z = np.array(tangent_residual(e1, e2, p, bm))  # its length is the angle, to 180°
        return self._ut_update(z, (sigma * sigma) * self._R2, 2, _hx_vector,
                               {"q_ref": self._q, "r": rr, "e1": e1, "e2": e2, "p": p})

    def _attitude_update(self, qm: tuple[float, ...], cov: Array) -> UpdateResult:
        w, x, y, z = self._q
        z_res = np.array(rot.log_map_floats(rot.hamilton(qm, (w, -x, -y, -z))))
        return self._ut_update(z_res, cov, 3, _hx_attitude, {})

    def _ut_update(
        self, z: Array, r_cov: Array, dof: int, hx: Any, hx_args: dict[str, Any]
    ) -> UpdateResult:
        """filterpy's unscented update, then the NIS gate (undone if rejected), then reset."""
        u = self.filterpy
        x0, p0 = u.x.copy(), u.P.copy()
        # sigma points of the *current* state: filterpy keeps those of the last predict,
        # which are stale after an earlier update in the same step
        u.sigmas_f = u.points_fn.sigma_points(u.x, u.P)
        try:
            u.update(z, R=r_cov, hx=hx, **hx_args)
        except np.linalg.LinAlgError:
            u.x, u.P = x0, p0
            return UpdateResult(False, math.nan, dof, "innovation covariance is singular")
        y = u.y
        nis = float(y @ u.SI @ y)
        gated = self._gate(nis, dof)
        if gated is None and not np.all(np.isfinite(u.P)):
            gated = UpdateResult(False, nis, dof, "update produced a non-finite state")
        if gated is not None:  # rejected: the state is exactly what it was before
            u.x, u.P = x0, p0
            return gated
        u.P = symmetrize(u.P)
        self._fold()
        return UpdateResult(True, nis, dof)

    def _fold(self) -> None:
        """Reset: move the mean GRP error into the reference quaternion and zero it
        (``q̂ ← δq(δp̂) ⊗ q̂``); the bias is a state of its own and stays as estimated."""
        u = self.filterpy
        px, py, pz = u.x[:3].tolist()
        self._q = rot.normalize_floats(rot.hamilton(_grp_to_quat_f(px, py, pz), self._q))
        u.x[:3] = 0.0
