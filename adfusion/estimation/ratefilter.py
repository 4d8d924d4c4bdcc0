"""Rate-estimating MEKF for logs with no gyro (video-only attitude, the OEDIPUS-C case).

The state is the attitude ``q_body_icrs`` and the body rate ``omega_body_rad_s``; the rate
follows a constant-rate model driven by a random walk of spectral density
``q = sigma_rate_walk_rad_s_sqrt_s²`` (rad²/s³). The 6-dimensional error state is

* attitude error δθ in the **body** frame, ``R_body_icrs_true = Exp(δθ) · R_body_icrs_est``
  (docs/conventions.md),
* rate error ``δω = ω_true − ω̂`` (rad/s, body frame),

and ``P`` (6×6) is in that order. From ``Ṙ_body_icrs = −[ω]× R_body_icrs`` with
``ω = ω̂ + δω``, to first order::

    δθ' = −[ω̂]× δθ − δω          δω' = w,   E[w wᵀ] = q I δ(t)

The coupling of the rate error into the attitude error is **−I** (in the MEKF it is +I,
because there ``ω = ω_meas − β``: a bias error enters the rate with the opposite sign). For
a constant ω̂ over a step of length Δt, θ = ω̂Δt, the discrete model is exact in closed form
(:func:`rate_transition_matrix`, :func:`rate_process_noise`; tested against a Van Loan matrix
exponential of the continuous model)::

    Φ₁₁ = Exp(−θ)                      Φ₁₂ = −∫₀^Δt Exp(−ω̂s) ds       Φ₂₂ = I
    Q₁₁ = qΔt³ (I/3 + f[θ]×²)          Q₁₂ = −qΔt² (I/2 − d[θ]× + e[θ]×²)   Q₂₂ = qΔt I

with d = (n − sin n)/n³, e = (½ − (1 − cos n)/n²)/n², f = (⅓ − 2d)/n², n = |θ|. At ω̂ = 0
these reduce to the textbook Q₁₁ = qΔt³/3, Q₁₂ = −qΔt²/2, Q₂₂ = qΔt (the cross term is
negative because of the −I coupling); at 180°/s and 30 Hz the rotation terms change Q by
~0.1 %, so the textbook form would do, but the exact one costs nothing.

Propagation integrates the quaternion exactly for the constant estimated rate,
``q ← Exp(−ω̂Δt) ⊗ q``; it needs no measurement (a gyro sample passed in is ignored, so the
:class:`~adfusion.estimation.estimator.Estimator` can drive this filter like the MEKF). Measurement
updates (attitude fixes, star or magnetometer directions, their camera-frame variants), the
NIS gate, the Joseph form, the iterated/left-Jacobian handling of large corrections and the
reset are the MEKF's, inherited unchanged: the measurements do not depend on the second
error block, and the reset adds δω to ω̂ just as the MEKF adds δβ to β̂.

There is no gyro, hence no gyro bias: :attr:`RateMEKF.bias_rad_s` is always zeros (kept so
code written against the MEKF interface runs); the estimated rate is
:attr:`RateMEKF.omega_rad_s`.

Example:
    >>> import numpy as np
    >>> from adfusion.estimation.ratefilter import RateMEKF
    >>> f = RateMEKF([1.0, 0.0, 0.0, 0.0], sigma_attitude_rad=1e-3, sigma_rate_rad_s=1.0,
    ...              sigma_rate_walk_rad_s_sqrt_s=1e-3)
    >>> cov = np.eye(3) * 1e-8
    >>> for k in range(1, 31):                 # fixes of a spin at 0.5 rad/s about body z
    ...     f.propagate(0.1)
    ...     t = 0.1 * k
    ...     q_true = [np.cos(0.25 * t), 0.0, 0.0, -np.sin(0.25 * t)]
    ...     _ = f.update_attitude(q_true, cov)
    >>> f.omega_rad_s.round(3).tolist()
    [0.0, 0.0, 0.5]
    >>> f.bias_rad_s.tolist()                  # no gyro, no bias
    [0.0, 0.0, 0.0]
    >>> bad = f.update_attitude([0.0, 1.0, 0.0, 0.0], cov)   # 180° off
    >>> bad.accepted, bad.reason.startswith("NIS")
    (False, True)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from adfusion.estimation.common import phi_rows, series_coeffs, symmetrize
from adfusion.estimation.mekf import MEKF
from adfusion.maths import rotations as rot

__all__ = ["RateMEKF", "rate_process_noise", "rate_transition_matrix"]

Array = NDArray[np.float64]


def _rate_coeffs(n: float) -> tuple[float, float]:
    """e = (½ − (1 − cos n)/n²)/n² and f = (⅓ − 2(n − sin n)/n³)/n², series near n = 0.

    Both lose digits to cancellation as n → 0 (relative error ~1e-16/n²), so below 0.02 rad
    the Taylor series is used (truncation ~n⁶/10⁷, below double precision there).
    """
    if n < 2e-2:
        n2 = n * n
        return (1.0 / 24.0 - n2 / 720.0 + n2 * n2 / 40320.0,
                1.0 / 60.0 - n2 / 2520.0 + n2 * n2 / 181440.0)  # fmt: skip
    n2 = n * n
    s, c = math.sin(n), math.cos(n)
    return (0.5 - (1.0 - c) / n2) / n2, (1.0 / 3.0 - 2.0 * (n - s) / (n2 * n)) / n2


def _skew(x: float, y: float, z: float) -> Array:
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rate_transition_matrix(omega_rad_s: ArrayLike, dt: float) -> Array:
    """Discrete error-state transition Φ (6×6) of [δθ, δω] over ``dt`` at constant rate ω̂.

    The MEKF's closed form (:func:`adfusion.estimation.mekf.transition_matrix`) with Φ₁₂
    negated: the
    rate error enters the attitude error with −I (see the module docstring).

    >>> phi = rate_transition_matrix([0.0, 0.0, 0.0], 2.0)
    >>> phi[:3, 3:].tolist() == (-2.0 * np.eye(3)).tolist()
    True
    """
    w = np.asarray(omega_rad_s, dtype=np.float64)
    if w.shape != (3,):
        raise ValueError(f"omega_rad_s must have shape (3,), got {w.shape}")
    dt = float(dt)
    tx, ty, tz = (float(v) * dt for v in w)
    phi = np.eye(6)
    phi[:3] = phi_rows(tx, ty, tz, dt)
    phi[:3, 3:] *= -1.0
    return phi


def rate_process_noise(omega_rad_s: ArrayLike, dt: float, sigma_rate_walk: float) -> Array:
    """Exact discrete process noise (6×6) of [δθ, δω] for a rate random walk at constant ω̂.

    ``Q = ∫₀^Δt Φ(s) G q Gᵀ Φ(s)ᵀ ds`` with G = [0; I], q = ``sigma_rate_walk``² (rad²/s³);
    closed form in the module docstring. At ω̂ = 0: Q₁₁ = qΔt³/3, Q₁₂ = −qΔt²/2, Q₂₂ = qΔt.

    >>> q = rate_process_noise([0.0, 0.0, 0.0], 1.0, 1e-2)
    >>> [float(q[0, 0]), float(q[0, 3]), float(q[3, 3])] == [1e-4 / 3, -0.5e-4, 1e-4]
    True
    """
    w = np.asarray(omega_rad_s, dtype=np.float64)
    if w.shape != (3,):
        raise ValueError(f"omega_rad_s must have shape (3,), got {w.shape}")
    dt = float(dt)
    qc = float(sigma_rate_walk) ** 2
    tx, ty, tz = (float(v) * dt for v in w)
    n = math.sqrt(tx * tx + ty * ty + tz * tz)
    _, _, d = series_coeffs(n)
    e, f = _rate_coeffs(n)
    k = _skew(tx, ty, tz)
    k2 = k @ k
    i3 = np.eye(3)
    q = np.zeros((6, 6))
    q[:3, :3] = qc * dt**3 * (i3 / 3.0 + f * k2)
    q[:3, 3:] = -qc * dt**2 * (0.5 * i3 - d * k + e * k2)
    q[3:, :3] = q[:3, 3:].T
    q[3:, 3:] = qc * dt * i3
    return q


class RateMEKF(MEKF):
    """Multiplicative EKF of attitude and body rate, for attitude fixes without a gyro.

    Args:
        q_body_icrs: initial attitude ``[w, x, y, z]`` (ICRS → body), e.g. the first fix.
        sigma_attitude_rad: initial 1σ attitude error per body axis (scalar or 3-vector).
        sigma_rate_rad_s: initial 1σ rate error per body axis (scalar or 3-vector); with no
            rate guess make it cover the largest plausible spin.
        sigma_rate_walk_rad_s_sqrt_s: rate random-walk density σ (rad/s^{3/2}, isotropic):
            how fast the true rate may wander from constant (nutation, coning, torques).
            Roughly σ² ≈ |ω̇|²·Δt for a rate changing at |ω̇| between fixes Δt apart.
        omega0_rad_s: initial rate estimate (rad/s, body frame); default zero.
        q_body_cam: body-to-camera mounting (camera → body); default identity.
        gate_probability: chi-square probability of the NIS gate; ``None`` disables it.
        relinearize_tol: as in :class:`~adfusion.estimation.mekf.MEKF`.

    Interface: the MEKF's (:meth:`propagate`, ``update_attitude``, ``update_vector``,
    ``update_camera_attitude``, ``update_camera_vector``, ``q_body_icrs``, ``q_cam_icrs``,
    ``P``, ``search_cone_deg``), plus :attr:`omega_rad_s`. ``bias_rad_s`` is zeros.

    Example:
        >>> f = RateMEKF([1.0, 0, 0, 0], 1e-3, 0.1, 1e-3, omega0_rad_s=[0.0, 0.0, 0.1])
        >>> f.propagate(1.0)                   # turns 0.1 rad about z on its own rate
        >>> round(float(2 * np.arccos(f.q_body_icrs[0])), 6)
        0.1
        >>> f.P.shape
        (6, 6)
    """

    def __init__(
        self,
        q_body_icrs: ArrayLike,
        sigma_attitude_rad: ArrayLike,
        sigma_rate_rad_s: ArrayLike,
        sigma_rate_walk_rad_s_sqrt_s: float,
        omega0_rad_s: ArrayLike | None = None,
        q_body_cam: ArrayLike | None = None,
        *,
        gate_probability: float | None = 0.9999,
        relinearize_tol: float = 0.1,
    ) -> None:
        # the base stores sigma_rate as the "bias" block of P0 and the walk density as rrw
        super().__init__(q_body_icrs, sigma_attitude_rad, sigma_rate_rad_s, 0.0,
                         sigma_rate_walk_rad_s_sqrt_s, None, q_body_cam,
                         gate_probability=gate_probability,
                         relinearize_tol=relinearize_tol)  # fmt: skip
        w = np.zeros(3) if omega0_rad_s is None else np.asarray(omega0_rad_s, dtype=np.float64)
        if w.shape != (3,) or not np.all(np.isfinite(w)):
            raise ValueError(f"omega0_rad_s must be a finite 3-vector, got {omega0_rad_s}")
        self._w: list[float] = w.tolist()
        self._b = [0.0, 0.0, 0.0]  # unused: no gyro, no bias
        self._phi = np.eye(6)  # its own transition, rows filled per step

    # --- state ---------------------------------------------------------------------------

    @property
    def omega_rad_s(self) -> Array:
        """Body-rate estimate (rad/s, body frame)."""
        return np.array(self._w)

    @property
    def bias_rad_s(self) -> Array:
        """Always zeros: there is no gyro, so no gyro bias (kept for the MEKF interface)."""
        return np.zeros(3)

    @property
    def P(self) -> Array:
        """Error covariance (6×6): [δθ body (rad), δω = ω_true − ω̂ (rad/s)] — a copy."""
        return self._P.copy()

    def state_dict(self) -> dict[str, Any]:
        """Plain-Python snapshot: q_body_icrs, omega_rad_s, bias_rad_s (zeros), P."""
        d = super().state_dict()
        d["omega_rad_s"] = list(self._w)
        return d

    # --- the algorithm -------------------------------------------------------------------

    def propagate(self, dt: float, omega_meas_rad_s: ArrayLike | None = None) -> None:
        """Advance the state by ``dt`` seconds on the filter's own rate estimate.

        ``omega_meas_rad_s`` is accepted and ignored (there is no gyro in this model; the
        argument exists so callers written for the MEKF work). The quaternion is integrated
        exactly for the constant rate, ``q ← Exp(−ω̂ dt) ⊗ q``; the covariance goes through
        :func:`rate_transition_matrix` and :func:`rate_process_noise`. Raises ValueError
        (state unchanged) when ``dt`` is not a finite positive number or ω̂·dt overflows.
        """
        dt = float(dt)
        if not 0.0 < dt < math.inf:
            raise ValueError(f"dt must be a finite positive number of seconds, got {dt}")
        wx, wy, wz = self._w
        tx, ty, tz = wx * dt, wy * dt, wz * dt
        if not math.isfinite(tx * tx + ty * ty + tz * tz):
            raise ValueError(f"rate estimate × dt overflows: {self._w} × {dt}")
        phi = self._phi
        phi[:3] = phi_rows(tx, ty, tz, dt)
        phi[:3, 3:] *= -1.0  # δθ' = −[ω̂]× δθ − δω
        q_noise = rate_process_noise(self._w, dt, self._su)
        self._q = rot.normalize_floats(rot.hamilton(rot.exp_map_floats(-tx, -ty, -tz), self._q))
        p = phi.dot(self._P).dot(phi.T)
        p += q_noise
        self._P = symmetrize(p)

    def _apply(self, dx: Array, new_p: Array) -> None:
        """Reset: ``q ← Exp(δθ) ⊗ q``, ``ω̂ ← ω̂ + δω``, error state zeroed."""
        d = dx.tolist()
        w = self._w
        self._q = rot.normalize_floats(rot.hamilton(rot.exp_map_floats(d[0], d[1], d[2]), self._q))
        self._w = [w[0] + d[3], w[1] + d[4], w[2] + d[5]]
        self._P = symmetrize(new_p)
