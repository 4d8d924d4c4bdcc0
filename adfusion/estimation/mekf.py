"""Multiplicative extended Kalman filter (MEKF) for attitude and gyro bias.

The estimator of docs/concepts/filter.md: a unit quaternion ``q_body_icrs`` and a gyro bias
are the state; the filter carries a 6-dimensional *error* state in the convention fixed there —

* attitude error δθ in the **body** frame, ``R_body_icrs_true = Exp(δθ) · R_body_icrs_est``,
* gyro bias error ``β_true − β_est`` (rad/s),

with the covariance ``P`` (6×6) in that order. Gyro model: ``omega_meas = omega_body + bias +
noise`` (rad/s, body frame).

Error dynamics in this convention (derived from ``Ṙ_body_icrs = −[ω]× R_body_icrs`` and
``ω = ω_meas − β − η_v``)::

    δθ' = −[ω̂]× δθ + δβ + η_v          δβ' = η_u

so the coupling of the bias error into the attitude error is **+I**. Crassidis & Junkins
(*Optimal Estimation of Dynamic Systems*, 2nd ed., §7.2) write the same filter with the
opposite attitude-error sign (their attitude matrix is passive, ``A(δq) ≈ I − [δα×]``, so
``δθ = −δα``): Φ₁₂ and the cross term Q₁₂ of Eqs. 7.43/7.45 change sign here, everything else
is identical. :func:`transition_matrix` and :func:`process_noise` implement the closed forms
in *this* convention (tested against a Van Loan matrix exponential of the continuous model).

Measurements:

* :meth:`MEKF.update_attitude` — a full attitude fix (a star-camera solution) with a 3×3
  covariance of its rotation-vector error in the body frame; :meth:`MEKF.update_camera_attitude`
  takes ``q_cam_icrs`` and a camera-frame covariance and applies the body-to-camera mounting.
* :meth:`MEKF.update_vector` — one unit direction (a star, or the magnetometer field direction)
  measured in the body frame against its ICRS reference. The residual is taken in the 2-D
  tangent plane of the predicted direction, so the innovation has exactly two degrees of
  freedom (the along-the-line component carries no attitude information).

Every update is gated on its normalised innovation squared (NIS) against a chi-square
quantile and returns an :class:`UpdateResult`; a rejected or invalid measurement leaves the
state untouched and says why. The covariance update is the Joseph form, and P is
re-symmetrised after every step. A correction that is large against the measurement (a start
tens of degrees off) is relinearised and its covariance carried across the reset with the
SO(3) left Jacobian (see :class:`MEKF`), so that the search cone stays honest in the transient.

:class:`AttitudeFilter` holds what the MEKF and the UKF (:mod:`adfusion.estimation.ukf`) share — the
interface, input validation, gating, the camera mounting — so scripts swap one for the other.
The hot path works on Python floats for 3- and 4-vectors and on numpy only for the 6×6
algebra: a numpy call on a 4-vector costs about a microsecond, more than the arithmetic.

Example:
    >>> import numpy as np
    >>> from adfusion.estimation.mekf import MEKF
    >>> f = MEKF([1.0, 0.0, 0.0, 0.0], sigma_attitude_rad=0.01, sigma_bias_rad_s=1e-5,
    ...          arw_rad_sqrt_s=1e-6, rrw_rad_s_sqrt_s=1e-9)
    >>> f.propagate(1.0, [0.0, 0.0, 0.001])
    >>> r = f.update_vector([1.0, 0.0, 0.0], [1.0, 0.0, 0.0], sigma_rad=1e-3)
    >>> r.accepted, r.dof
    (True, 2)
    >>> np.sqrt(np.diag(f.P)[:3]).round(4).tolist()  # the roll about the direction stays unknown
    [0.01, 0.001, 0.001]
    >>> round(f.search_cone_deg(k=3.0), 2)               # 3σ of the worst axis, degrees
    1.72
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from adfusion.estimation.common import (
    check_dt_omega,
    phi_rows,
    symmetrize,
    tangent_basis,
    tangent_residual,
)
from adfusion.estimation.mekf_kernels import covariance_step
from adfusion.maths import rotations as rot

__all__ = [
    "MEKF",
    "AttitudeFilter",
    "UpdateResult",
    "chi2_gate",
    "left_jacobian",
    "process_noise",
    "transition_matrix",
]

Array = NDArray[np.float64]
_EYE6 = np.eye(6)
_EYE6.setflags(write=False)


class UpdateResult(NamedTuple):
    """What a measurement update did (an immutable record).

    Attributes:
        accepted: True when the measurement was applied to the state.
        nis: normalised innovation squared ``yᵀ S⁻¹ y`` (NaN when the input was invalid).
        dof: degrees of freedom of the innovation (2 for a direction, 3 for an attitude fix).
        reason: ``""`` when accepted; otherwise why not (NIS gate, invalid input, ...).

    A NamedTuple rather than a frozen dataclass: it is built on every update, and costs a
    third as much. Test ``.accepted``, not the record itself (a tuple is always truthy).

    Example:
        >>> UpdateResult(False, 812.3, 3, "NIS 812.3 > gate 21.1 (3 dof)").accepted
        False
    """

    accepted: bool
    nis: float
    dof: int
    reason: str = ""


def chi2_gate(probability: float, dof: int) -> float:
    """The chi-square quantile with ``dof`` degrees of freedom at ``probability``.

    ``scipy.special.chdtri`` is the inverse of the *upper* tail, hence ``1 − probability``.

    >>> round(chi2_gate(0.95, 2), 4)
    5.9915
    """
    from scipy.special import chdtri

    if not 0.0 < probability < 1.0:
        raise ValueError(f"gate probability must be in (0, 1), got {probability}")
    return float(chdtri(dof, 1.0 - probability))


# --- closed-form discrete model ---------------------------------------------------------


def left_jacobian(phi: ArrayLike) -> Array:
    """Left Jacobian of SO(3): ``Log(Exp(φ + ε) Exp(−φ)) ≈ J_l(φ) ε``.

    J_l(φ) = I + (1 − cos n)/n² [φ]× + (n − sin n)/n³ [φ]×², n = |φ|. It carries a covariance
    of the left (body-frame) error across a large reset ``q ← Exp(φ) ⊗ q``.

    >>> np.allclose(left_jacobian([0.0, 0.0, 0.0]), np.eye(3))
    True
    """
    px, py, pz = (float(v) for v in np.asarray(phi, dtype=np.float64))
    # phi_rows(−φ, dt=1)[:, 3:] is ∫₀¹ Exp(φ s) ds = J_l(φ)
    return np.array([row[3:] for row in phi_rows(-px, -py, -pz, 1.0)])


def transition_matrix(omega_hat_rad_s: ArrayLike, dt: float) -> Array:
    """Discrete error-state transition Φ (6×6) over ``dt`` at constant bias-corrected rate.

    Crassidis & Junkins Eq. 7.45 in this module's error convention (Φ₁₂ has the opposite
    sign to the book's): exact for a constant rate over the step.

    >>> phi = transition_matrix([0.0, 0.0, 0.0], 2.0)
    >>> phi[:3, 3:].tolist() == (2.0 * np.eye(3)).tolist()
    True
    """
    tx, ty, tz = (float(v) * dt for v in np.asarray(omega_hat_rad_s, dtype=np.float64))
    phi = np.eye(6)
    phi[:3] = phi_rows(tx, ty, tz, dt)
    return phi


def process_noise(dt: float, arw_rad_sqrt_s: float, rrw_rad_s_sqrt_s: float) -> Array:
    """Farrenkopf's discrete process noise (6×6) for the [δθ, δβ] error state.

    Crassidis & Junkins Eq. 7.43: Q₁₁ = (σv²Δt + σu²Δt³/3) I, Q₂₂ = σu²Δt I; the cross block
    is **+**σu²Δt²/2 I here (the book's −σu²Δt²/2 I belongs to its opposite attitude-error
    sign; see the module docstring).

    >>> q = process_noise(1.0, 1e-3, 1e-4)
    >>> [float(q[0, 0]), float(q[0, 3]), float(q[3, 3])] == [1e-6 + 1e-8 / 3, 0.5e-8, 1e-8]
    True
    """
    sv2, su2 = arw_rad_sqrt_s**2, rrw_rad_s_sqrt_s**2
    q = np.zeros((6, 6))
    i3 = np.eye(3)
    q[:3, :3] = (sv2 * dt + su2 * dt**3 / 3.0) * i3
    q[:3, 3:] = q[3:, :3] = (su2 * dt**2 / 2.0) * i3
    q[3:, 3:] = su2 * dt * i3
    return q






def _unit3(v: ArrayLike, what: str) -> tuple[float, float, float] | str:
    """A finite non-zero 3-vector as unit floats, or the reason it is not one.

    Wrong shapes raise (a programming error); bad values return a reason string (a data
    problem the caller reports as a rejected update).
    """
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,):
        raise ValueError(f"{what} must have shape (3,), got {a.shape}")
    x, y, z = a.tolist()
    if not math.isfinite(x + y + z):
        return f"{what} is not finite"
    n = math.sqrt(x * x + y * y + z * z)
    if not n > 1e-300 or not math.isfinite(n):
        return f"{what} has zero (or non-finite) norm"
    return (x / n, y / n, z / n)


def _unit_quat(q: ArrayLike, what: str) -> tuple[float, float, float, float] | str:
    a = np.asarray(q, dtype=np.float64)
    if a.shape != (4,):
        raise ValueError(f"{what} must have shape (4,) [w, x, y, z], got {a.shape}")
    w, x, y, z = a.tolist()
    if not math.isfinite(w + x + y + z):
        return f"{what} is not finite"
    n2 = w * w + x * x + y * y + z * z
    if not n2 > 1e-300 or not math.isfinite(n2):
        return f"{what} has zero (or non-finite) norm"
    return rot.normalize_floats((w, x, y, z))


def _sym_pd_3x3(cov: ArrayLike, what: str) -> Array | str:
    """A finite, symmetric, positive-definite 3×3 covariance, or the reason it is not one.

    In floats (it runs at every star fix): the tests of ``np.allclose(c, c.T, rtol=1e-9,
    atol=1e-12·max|c|)`` and of a Cholesky factorisation of the lower triangle (LAPACK's
    ``potrf`` fails exactly when a pivot is not > 0), element by element.

    >>> _sym_pd_3x3([[1.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]], "c").tolist()
    [[1.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]]
    >>> _sym_pd_3x3(np.diag([1.0, -1.0, 1.0]), "c"), _sym_pd_3x3(np.triu(np.ones((3, 3))), "c")
    ('c is not positive definite', 'c is not symmetric')
    """
    c = np.asarray(cov, dtype=np.float64)
    if c.shape != (3, 3):
        raise ValueError(f"{what} must have shape (3, 3), got {c.shape}")
    a = c.ravel().tolist()
    for v in a:
        if not math.isfinite(v):
            return f"{what} is not finite"
    atol = 1e-12 * max(abs(v) for v in a)
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = a
    for u, v in ((c01, c10), (c02, c20), (c12, c21)):
        if abs(u - v) > atol + 1e-9 * abs(v) or abs(v - u) > atol + 1e-9 * abs(u):
            return f"{what} is not symmetric"
    # Cholesky of the lower triangle, as np.linalg.cholesky reads it
    if not c00 > 0.0:
        return f"{what} is not positive definite"
    l00 = math.sqrt(c00)
    l10, l20 = c10 / l00, c20 / l00
    d1 = c11 - l10 * l10
    if not d1 > 0.0:
        return f"{what} is not positive definite"
    l21 = (c21 - l20 * l10) / math.sqrt(d1)
    if not c22 - l20 * l20 - l21 * l21 > 0.0:
        return f"{what} is not positive definite"
    s01, s02, s12 = 0.5 * (c01 + c10), 0.5 * (c02 + c20), 0.5 * (c12 + c21)
    return np.array([[c00, s01, s02], [s01, c11, s12], [s02, s12, c22]])


def _sigma3(value: ArrayLike, what: str) -> Array:
    s = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()
    if not np.all(np.isfinite(s)) or np.any(s < 0.0):
        raise ValueError(f"{what} must be finite and ≥ 0, got {value}")
    return s


class AttitudeFilter:
    """The interface MEKF and UKF share (docs/concepts/filter.md).

    Holds what does not depend on the filter algorithm: the reference quaternion, the
    body-to-camera mounting, input validation, the NIS gate and the camera-frame helpers.
    Subclasses implement :meth:`propagate`, ``_vector_update``, ``_attitude_update``,
    ``bias_rad_s`` and ``_cov`` (the internal 6×6 covariance in the error convention of the
    module docstring).

    Args:
        q_body_icrs: initial attitude ``[w, x, y, z]`` (ICRS → body).
        sigma_attitude_rad: initial 1σ attitude error per body axis (scalar or 3-vector).
        sigma_bias_rad_s: initial 1σ gyro-bias error per axis (scalar or 3-vector).
        arw_rad_sqrt_s: angle random walk σv (rad/√s).
        rrw_rad_s_sqrt_s: rate random walk σu (rad/s^{3/2}).
        bias_rad_s: initial bias estimate (default zero).
        q_body_cam: body-to-camera mounting ``q_body_cam`` (camera → body), used by the
            ``update_camera_*`` helpers (camera fixes are ``q_cam_icrs``). Default identity.
        gate_probability: chi-square probability of the NIS gate, per update and its dof;
            ``None`` disables gating (every valid measurement is applied).
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
    ) -> None:
        q = _unit_quat(q_body_icrs, "q_body_icrs")
        if isinstance(q, str):
            raise ValueError(q)
        self._q = q
        b = np.zeros(3) if bias_rad_s is None else np.asarray(bias_rad_s, dtype=np.float64)
        if b.shape != (3,) or not np.all(np.isfinite(b)):
            raise ValueError(f"bias_rad_s must be a finite 3-vector, got {bias_rad_s}")
        self._b0 = b.copy()
        self._sv = float(arw_rad_sqrt_s)
        self._su = float(rrw_rad_s_sqrt_s)
        if not (0.0 <= self._sv < math.inf and 0.0 <= self._su < math.inf):
            raise ValueError("arw_rad_sqrt_s and rrw_rad_s_sqrt_s must be finite and ≥ 0")
        sa = _sigma3(sigma_attitude_rad, "sigma_attitude_rad")
        sb = _sigma3(sigma_bias_rad_s, "sigma_bias_rad_s")
        self._P0: Array = np.diag(np.concatenate([sa, sb]) ** 2)
        if q_body_cam is None:
            q_bc: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
        else:
            qc = _unit_quat(q_body_cam, "q_body_cam")
            if isinstance(qc, str):
                raise ValueError(qc)
            q_bc = qc
        self._q_bc = q_bc
        self._r_bc = rot.to_matrix(np.array(q_bc))
        self._gate_p = gate_probability
        self._gates: dict[int, float] = {}
        if gate_probability is not None:
            self._gates = {k: chi2_gate(gate_probability, k) for k in (1, 2, 3, 6)}

    # --- state ---------------------------------------------------------------------------

    @property
    def q_body_icrs(self) -> Array:
        """Attitude estimate ``[w, x, y, z]`` (w ≥ 0), rotating ICRS vectors into the body."""
        return np.array(self._q)

    @property
    def q_cam_icrs(self) -> Array:
        """Camera attitude implied by the mounting: ``q_cam_icrs = q_body_cam⁻¹ ⊗ q_body_icrs``
        (the prior a tracking star solver wants)."""
        w, x, y, z = self._q_bc
        return np.array(rot.normalize_floats(rot.hamilton((w, -x, -y, -z), self._q)))

    @property
    def q_body_cam(self) -> Array:
        """The body-to-camera mounting ``q_body_cam`` (camera → body)."""
        return np.array(self._q_bc)

    @property
    def bias_rad_s(self) -> Array:
        """Gyro bias estimate (rad/s, body frame)."""
        raise NotImplementedError

    @property
    def P(self) -> Array:
        """Error covariance (6×6): [δθ body (rad), δβ (rad/s)] — a copy."""
        return self._cov().copy()

    @property
    def gate_probability(self) -> float | None:
        """Chi-square probability of the NIS gate (``None``: no gating)."""
        return self._gate_p

    def search_cone_deg(self, k: float = 3.0) -> float:
        """k·σ of the attitude in degrees: ``k·sqrt(λmax(P[:3, :3]))`` — the radius of the
        cone a tracking star identification has to search around the predicted boresight."""
        if not (math.isfinite(k) and k >= 0):
            raise ValueError(f"search_cone_deg: k (sigmas) must be finite and ≥ 0, got {k}")
        lam = float(np.linalg.eigvalsh(self._cov()[:3, :3])[-1])
        return k * math.degrees(math.sqrt(max(lam, 0.0)))

    def state_dict(self) -> dict[str, Any]:
        """Plain-Python snapshot (for logs): q_body_icrs, bias_rad_s, P as nested lists."""
        return {"q_body_icrs": list(self._q), "bias_rad_s": self.bias_rad_s.tolist(),
                "P": self._cov().tolist()}  # fmt: skip

    def __repr__(self) -> str:
        q = ", ".join(f"{v:.6f}" for v in self._q)
        return (f"{type(self).__name__}(q_body_icrs=[{q}], "
                f"cone_3sigma={self.search_cone_deg():.4g} deg)")  # fmt: skip

    # --- the algorithm (subclasses) ------------------------------------------------------

    def propagate(self, dt: float, omega_meas_rad_s: ArrayLike) -> None:
        """Advance the state by ``dt`` seconds with one gyro sample (rad/s, body frame)."""
        raise NotImplementedError

    def _cov(self) -> Array:
        raise NotImplementedError

    def _set_bias(self, bias_rad_s: ArrayLike) -> None:
        """Set the bias estimate (a filter resuming after a gyro outage)."""
        raise NotImplementedError

    def _vector_update(
        self, bm: tuple[float, float, float], rr: tuple[float, float, float], sigma: float
    ) -> UpdateResult:
        raise NotImplementedError

    def _attitude_update(self, qm: tuple[float, ...], cov: Array) -> UpdateResult:
        raise NotImplementedError

    # --- updates -------------------------------------------------------------------------

    def update_vector(
        self, b_meas_body: ArrayLike, r_ref_icrs: ArrayLike, sigma_rad: float
    ) -> UpdateResult:
        """Update with one measured unit direction in the body frame and its ICRS reference.

        ``sigma_rad`` is the 1σ angular error of the direction per tangent axis (a star's
        centroid error, or the magnetometer's direction error). Inputs need not be unit
        length; zero-norm or non-finite ones are rejected with a reason. The residual lives
        in the tangent plane of the predicted direction: 2 degrees of freedom.
        """
        bm = _unit3(b_meas_body, "b_meas_body")
        if isinstance(bm, str):
            return UpdateResult(False, math.nan, 2, bm)
        rr = _unit3(r_ref_icrs, "r_ref_icrs")
        if isinstance(rr, str):
            return UpdateResult(False, math.nan, 2, rr)
        sigma = float(sigma_rad)
        if not 0.0 < sigma < math.inf:
            return UpdateResult(False, math.nan, 2, f"sigma_rad must be finite and > 0: {sigma}")
        return self._vector_update(bm, rr, sigma)

    def update_attitude(self, q_meas_body_icrs: ArrayLike, cov_rad2: ArrayLike) -> UpdateResult:
        """Update with a full attitude fix ``q_meas_body_icrs`` and the 3×3 covariance (rad²)
        of its rotation-vector error in the body frame
        (``R_meas = Exp(ν) R_true``, ν ~ N(0, cov)): 3 degrees of freedom."""
        qm = _unit_quat(q_meas_body_icrs, "q_meas_body_icrs")
        if isinstance(qm, str):
            return UpdateResult(False, math.nan, 3, qm)
        cov = _sym_pd_3x3(cov_rad2, "cov_rad2")
        if isinstance(cov, str):
            return UpdateResult(False, math.nan, 3, cov)
        return self._attitude_update(qm, cov)

    def widen_attitude(self, disagreement_rad: ArrayLike) -> None:
        """Admit an attitude error the model did not foresee: add ``δ δᵀ`` to the attitude
        block of P, ``δ`` the rotation vector (rad, body axes) by which a trusted fix
        disagreed with the estimate (``R_fix = Exp(δ) R_est``). The state does not move;
        its 1σ along ``δ`` now reaches the fix, so an estimate the fix contradicts claims
        no more than it knows, and the next fix that agrees with this one passes the gate.

        >>> f = MEKF([1.0, 0.0, 0.0, 0.0], 1e-4, 1e-6, 1e-5, 1e-7)
        >>> f.widen_attitude([0.0, 0.0, 1e-3])
        >>> round(float(np.sqrt(f.P[2, 2])), 6)
        0.001005
        """
        d = np.asarray(disagreement_rad, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(d)):
            raise ValueError(f"widen_attitude: disagreement must be finite, got {d}")
        p = self._cov()
        p[:3, :3] += np.outer(d, d)  # in place: the filter's own covariance

    def update_camera_attitude(
        self, q_cam_icrs: ArrayLike, cov_cam_rad2: ArrayLike
    ) -> UpdateResult:
        """Update with a star-camera fix ``q_cam_icrs`` and its 3×3 covariance in the camera
        frame (``starid`` ``Solution.q_cam_icrs``/``.covariance``), through the mounting:
        ``q_body_icrs = q_body_cam ⊗ q_cam_icrs`` and ``cov_body = R_body_cam cov R_body_camᵀ``.
        """
        qc = _unit_quat(q_cam_icrs, "q_cam_icrs")
        if isinstance(qc, str):
            return UpdateResult(False, math.nan, 3, qc)
        cov = _sym_pd_3x3(cov_cam_rad2, "cov_cam_rad2")
        if isinstance(cov, str):
            return UpdateResult(False, math.nan, 3, cov)
        qb = rot.normalize_floats(rot.hamilton(self._q_bc, qc))
        return self._attitude_update(qb, self._r_bc @ cov @ self._r_bc.T)

    def update_camera_vector(
        self, b_meas_cam: ArrayLike, r_ref_icrs: ArrayLike, sigma_rad: float
    ) -> UpdateResult:
        """:meth:`update_vector` for one star direction measured in the camera frame."""
        bm = _unit3(b_meas_cam, "b_meas_cam")
        if isinstance(bm, str):
            return UpdateResult(False, math.nan, 2, bm)
        return self.update_vector(rot.rotate_floats(self._q_bc, bm), r_ref_icrs, sigma_rad)

    def _gate(self, nis: float, dof: int) -> UpdateResult | None:
        """None when the innovation passes; otherwise the rejected result."""
        if not math.isfinite(nis):
            return UpdateResult(False, nis, dof, "NIS is not finite")
        if self._gate_p is None:
            return None
        g = self._gates.get(dof)
        if g is None:
            g = self._gates[dof] = chi2_gate(self._gate_p, dof)
        if nis > g:
            return UpdateResult(
                False, nis, dof, f"NIS {nis:.4g} > gate {g:.4g} ({dof} dof, p={self._gate_p})"
            )
        return None


class MEKF(AttitudeFilter):
    """Multiplicative EKF: quaternion ``q_body_icrs`` and gyro bias, 6-state error covariance.

    Constructor arguments: see :class:`AttitudeFilter`; in addition ``relinearize_tol``.
    A large correction (a start 30° off on a magnetometer alone) makes the linearisation
    matter: the first update's Jacobian, taken at the wrong attitude, puts the unobservable
    axis in the wrong place, the next updates then shrink P far below the real error and the
    search cone becomes overconfident. So when an update's attitude correction δθ is large
    against the measurement — ``|δθ|·sqrt(tr P_θθ) > relinearize_tol · σ_meas``, the size of
    the change of H times the prior spread it acts on — a direction update is iterated
    (Gauss-Newton relinearisation of H at the corrected attitude: an iterated EKF), and the
    covariance of either update is carried across the reset with the SO(3) left Jacobian.
    Steady-state updates never take this path. ``relinearize_tol=math.inf`` gives the plain
    MEKF. Attributes ``q_body_icrs``, ``q_cam_icrs``, ``bias_rad_s`` and ``P`` return copies.

    Example:
        >>> import numpy as np
        >>> f = MEKF([1.0, 0, 0, 0], np.radians(1.0), 1e-6, 1e-6, 1e-9)
        >>> for _ in range(10):
        ...     f.propagate(0.1, [0.0, 0.0, 0.01])
        >>> fix = f.q_body_icrs                       # a perfect star fix
        >>> f.update_attitude(fix, np.eye(3) * 1e-8).accepted
        True
        >>> bad = f.update_attitude([0.0, 1.0, 0.0, 0.0], np.eye(3) * 1e-8)  # 180° off
        >>> bad.accepted, bad.reason.startswith("NIS")
        (False, True)
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
        relinearize_tol: float = 0.1,
    ) -> None:
        super().__init__(q_body_icrs, sigma_attitude_rad, sigma_bias_rad_s, arw_rad_sqrt_s,
                         rrw_rad_s_sqrt_s, bias_rad_s, q_body_cam,
                         gate_probability=gate_probability)  # fmt: skip
        self._relin = float(relinearize_tol)
        self._b: list[float] = self._b0.tolist()
        self._P: Array = self._P0.copy()
        self._h = np.zeros((2, 6))

    @property
    def bias_rad_s(self) -> Array:
        """Gyro bias estimate (rad/s, body frame)."""
        return np.array(self._b)

    def _cov(self) -> Array:
        return self._P

    def _set_bias(self, bias_rad_s: ArrayLike) -> None:
        self._b = [float(v) for v in np.asarray(bias_rad_s, dtype=np.float64).reshape(3)]

    def propagate(self, dt: float, omega_meas_rad_s: ArrayLike) -> None:
        """Advance the state by ``dt`` seconds with one gyro sample (rad/s, body frame).

        The bias-corrected rate ω̂ = ω_meas − β̂ is held constant over the step and the
        quaternion is integrated in closed form, ``q ← Exp(−ω̂ dt) ⊗ q`` (exact for a constant
        rate); the covariance goes through Φ (:func:`transition_matrix`) and Farrenkopf's Q
        (:func:`process_noise`). Raises ValueError (state unchanged) on a non-finite sample
        or a step that is not a finite positive number.
        """
        dt, wx, wy, wz = check_dt_omega(dt, omega_meas_rad_s)
        b = self._b
        tx, ty, tz = (wx - b[0]) * dt, (wy - b[1]) * dt, (wz - b[2]) * dt
        # body rates turn R_body_icrs by −θ on the left (Ṙ_body_icrs = −[ω]× R_body_icrs)
        self._q = rot.normalize_floats(rot.hamilton(rot.exp_map_floats(-tx, -ty, -tz), self._q))
        self._P = covariance_step(self._P, dt, tx, ty, tz, self._sv**2, self._su**2)

    def _vector_update(
        self, bm: tuple[float, float, float], rr: tuple[float, float, float], sigma: float
    ) -> UpdateResult:
        px, py, pz = rot.rotate_floats(self._q, rr)  # predicted direction b̂ = R(q̂) r
        (e1x, e1y, e1z), (e2x, e2y, e2z) = tangent_basis(px, py, pz)
        # b = Exp(δθ) b̂ ≈ b̂ + δθ × b̂, so e1·b = δθ·e2 and e2·b = −δθ·e1 (b̂ × e2 = −e1);
        # taken through the log map, so that the residual's length is the angle (to 180°)
        y0, y1 = tangent_residual((e1x, e1y, e1z), (e2x, e2y, e2z), (px, py, pz), bm)
        h = self._h  # H (2×6); the bias columns stay zero
        h[0, 0], h[0, 1], h[0, 2], h[1, 0], h[1, 1], h[1, 2] = e2x, e2y, e2z, -e1x, -e1y, -e1z
        p = self._P
        pht = p.dot(h.T)  # P Hᵀ (6×2)
        (s00, s01), (s10, s11) = h.dot(pht).tolist()
        r = sigma * sigma
        s00 += r
        s11 += r
        s01 = 0.5 * (s01 + s10)
        det = s00 * s11 - s01 * s01
        if not det > 0.0:
            return UpdateResult(False, math.nan, 2, "innovation covariance is not positive")
        i00, i01, i11 = s11 / det, -s01 / det, s00 / det  # closed-form 2×2 inverse
        nis = y0 * (i00 * y0 + i01 * y1) + y1 * (i01 * y0 + i11 * y1)
        gated = self._gate(nis, 2)
        if gated is not None:
            return gated
        k = pht.dot(np.array([[i00, i01], [i01, i11]]))  # 6×2 gain
        dx = k.dot(np.array([y0, y1]))
        d0, d1, d2 = dx[:3].tolist()
        tr = p.item(0) + p.item(7) + p.item(14)  # tr P_θθ ≥ λmax
        if (d0 * d0 + d1 * d1 + d2 * d2) * tr > self._relin * self._relin * r:
            self._iterated_vector_update(bm, rr, r, dx)
            return UpdateResult(True, nis, 2)
        ikh = _EYE6 - k.dot(h)
        new_p = ikh.dot(p).dot(ikh.T)  # Joseph form: stays PSD whatever the rounding in K
        kr = pht.dot(np.array([[sigma * i00, sigma * i01], [sigma * i01, sigma * i11]]))  # K σ
        new_p += kr.dot(kr.T)  # K R Kᵀ with R = σ² I₂
        self._apply(dx, new_p)
        return UpdateResult(True, nis, 2)

    def _iterated_vector_update(
        self, bm: tuple[float, float, float], rr: tuple[float, float, float], r: float,
        dx: Array, max_iter: int = 10,
    ) -> None:  # fmt: skip
        """Iterated EKF for a large correction, in the coordinates of the prior.

        x_{i+1} = K_i (y_i + H_i x_i), with the residual y_i and H_i = [−[b̂_i]× J_l(δθ_i), 0]
        (in the tangent basis of b̂_i) taken at q_i = Exp(δθ_i) ⊗ q̄ — Gauss-Newton on the
        posterior. The final Joseph-form covariance is then moved to the new reference with
        G = diag(J_l(δθ), I) (``Log(Exp(δθ + ε) Exp(−δθ)) ≈ J_l(δθ) ε``).
        """
        p = self._P
        q_bar = self._q
        for _ in range(max_iter):
            jl = left_jacobian(dx[:3])
            q_i = rot.normalize_floats(rot.hamilton(rot.exp_map_floats(*dx[:3].tolist()), q_bar))
            px, py, pz = rot.rotate_floats(q_i, rr)
            e1, e2 = tangent_basis(px, py, pz)
            y = np.array(tangent_residual(e1, e2, (px, py, pz), bm))
            h = np.zeros((2, 6))
            h[:, :3] = np.array([e2, [-e1[0], -e1[1], -e1[2]]]) @ jl
            k = p @ h.T @ np.linalg.inv(h @ p @ h.T + r * np.eye(2))
            dx_new = k @ (y + h @ dx)
            step = float(np.linalg.norm(dx_new[:3] - dx[:3]))
            dx = dx_new
            if step < 1e-10:
                break
        ikh = _EYE6 - k @ h
        new_p = ikh @ p @ ikh.T + r * (k @ k.T)
        g = _EYE6.copy()
        g[:3, :3] = left_jacobian(dx[:3])
        self._apply(dx, g @ new_p @ g.T)

    def _attitude_update(self, qm: tuple[float, ...], cov: Array) -> UpdateResult:
        w, x, y, z = self._q
        # residual δz = Log(q_meas ⊗ q̂⁻¹): the fix's error rotation in the body frame, H = [I 0]
        y0, y1, y2 = rot.log_map_floats(rot.hamilton(qm, (w, -x, -y, -z)))
        p = self._P
        # S = P_θθ + R and its inverse in closed form (floats: this runs at every fix)
        (p00, p01, p02), (p10, p11, p12), (p20, p21, p22) = p[:3, :3].tolist()
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = cov.tolist()
        a, b, c = p00 + r00, p01 + r01, p02 + r02
        d, e, f = p10 + r10, p11 + r11, p12 + r12
        g, h, i = p20 + r20, p21 + r21, p22 + r22
        c00, c01, c02 = e * i - f * h, f * g - d * i, d * h - e * g  # cofactors, first row
        det = a * c00 + b * c01 + c * c02
        if det == 0.0 or not math.isfinite(det):
            return UpdateResult(False, math.nan, 3, "innovation covariance is singular")
        # S⁻¹ = adj(S) / det, symmetrised (as 0.5·(S⁻¹ + S⁻ᵀ) before)
        i00, i11, i22 = c00 / det, (a * i - c * g) / det, (a * e - b * d) / det
        i01 = 0.5 * (c01 + (c * h - b * i)) / det
        i02 = 0.5 * (c02 + (b * f - c * e)) / det
        i12 = 0.5 * ((b * g - a * h) + (c * d - a * f)) / det
        nis = (y0 * (i00 * y0 + i01 * y1 + i02 * y2) + y1 * (i01 * y0 + i11 * y1 + i12 * y2)
               + y2 * (i02 * y0 + i12 * y1 + i22 * y2))
        gated = self._gate(nis, 3)
        if gated is not None:
            return gated
        s_inv = np.array([[i00, i01, i02], [i01, i11, i12], [i02, i12, i22]])
        k = p[:, :3].dot(s_inv)  # P Hᵀ is the first three columns of P
        ikh = _EYE6.copy()
        ikh[:, :3] -= k
        new_p = ikh.dot(p).dot(ikh.T)  # Joseph form
        new_p += k.dot(cov).dot(k.T)
        dx = k.dot(np.array([y0, y1, y2]))
        d0, d1, d2 = dx[:3].tolist()
        if (d0 * d0 + d1 * d1 + d2 * d2) * (p00 + p11 + p22) > self._relin**2 * min(r00, r11,
                                                                                     r22):
            # H = I is exact in the prior's coordinates (Log(Exp(δθ)) = δθ), so no iteration;
            # only move the covariance to the new reference (see _iterated_vector_update)
            g = _EYE6.copy()
            g[:3, :3] = left_jacobian(dx[:3])
            new_p = g @ new_p @ g.T
        self._apply(dx, new_p)
        return UpdateResult(True, nis, 3)

    def _apply(self, dx: Array, new_p: Array) -> None:
        """Reset: fold the error estimate into the reference state and zero it.

        The attitude error is on the left (``R_true = Exp(δθ) R_est``), so q ← Exp(δθ) ⊗ q;
        the bias correction is *added* to the estimate (dropping it is the classic MEKF bug
        that leaves the bias unobserved). The error state is implicitly zero afterwards.
        (The first-order reset Jacobian I − ½[δθ]× is omitted, as usual: δθ is tiny.)
        """
        d = dx.tolist()
        b = self._b
        self._q = rot.normalize_floats(rot.hamilton(rot.exp_map_floats(d[0], d[1], d[2]), self._q))
        self._b = [b[0] + d[3], b[1] + d[4], b[2] + d[5]]
        self._P = symmetrize(new_p)




