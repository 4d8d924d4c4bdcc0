"""MEKF tests against an independent truth simulation (Crassidis & Junkins gyro model).

The truth model lives here, not in the filter: attitude from a constant body rate in closed
form (checked against scipy's rotation composition), gyro samples from the discrete
Farrenkopf/Crassidis model

    ω_meas(k+1) = ω(k+1) + ½(β(k+1) + β(k)) + sqrt(σv²/Δt + σu²Δt/12) N_v,
    β(k+1) = β(k) + σu √Δt N_u,

where the sample at k+1 is the average rate over [t_k, t_{k+1}] (an integrating gyro), so the
filter propagates that interval with it. The scenario numbers are Crassidis & Junkins,
*Optimal Estimation of Dynamic Systems* 2nd ed., Example 7.1.

The helpers (``simulate``, ``run_filter``, ``check_*``) are reused by ``tests/test_ukf.py``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from adfusion.estimation.mekf import (
    MEKF,
    AttitudeFilter,
    UpdateResult,
    chi2_gate,
    process_noise,
    transition_matrix,
)
from adfusion.maths import rotations as rot

# --- Crassidis & Junkins Ex. 7.1 -------------------------------------------------------
SIGMA_V = math.sqrt(10.0) * 1e-7  # rad/s^½, angle random walk
SIGMA_U = math.sqrt(10.0) * 1e-10  # rad/s^{3/2}, rate random walk
DEG_PER_H = math.radians(1.0) / 3600.0  # 1 °/h in rad/s
BIAS0 = np.full(3, 0.1 * DEG_PER_H)
W_ORBIT = np.array([0.0, 0.0011, 0.0])  # orbital-rate pitch, rad/s (body frame)
ARCSEC = math.radians(1.0 / 3600.0)
STAR_SIGMA = 6.0 * ARCSEC  # per axis, 1σ
SIGMA_ATT0 = math.radians(0.1)
SIGMA_BIAS0 = 0.2 * DEG_PER_H
Q0 = rot.normalize([0.9, 0.1, -0.3, 0.3])

Factory = Callable[..., AttitudeFilter]


@dataclass
class Truth:
    """One Monte Carlo batch: arrays indexed [run, step]; gyro[:, k] covers (k-1, k]."""

    dt: float
    q: np.ndarray  # (N, K+1, 4) q_body_icrs
    bias: np.ndarray  # (N, K+1, 3)
    gyro: np.ndarray  # (N, K+1, 3); gyro[:, 0] unused


def simulate(rng: np.random.Generator, n_runs: int, n_steps: int, dt: float = 1.0,
             omega: np.ndarray = W_ORBIT, bias0: np.ndarray = BIAS0,
             sigma_v: float = SIGMA_V, sigma_u: float = SIGMA_U,
             q0: np.ndarray = Q0) -> Truth:  # fmt: skip
    """Truth attitude (constant body rate), bias random walk and gyro samples, vectorised."""
    t = np.arange(n_steps + 1) * dt
    # body rate ω: R_body_icrs(t) = Exp(−ω t) R_body_icrs(0)
    q = rot.multiply(rot.exp_map(-t[:, None] * omega), q0)
    q = np.broadcast_to(q, (n_runs, n_steps + 1, 4)).copy()
    steps = sigma_u * math.sqrt(dt) * rng.standard_normal((n_runs, n_steps, 3))
    bias = bias0 + np.concatenate([np.zeros((n_runs, 1, 3)), np.cumsum(steps, axis=1)], axis=1)
    noise = math.sqrt(sigma_v**2 / dt + sigma_u**2 * dt / 12.0)
    gyro = np.zeros((n_runs, n_steps + 1, 3))
    gyro[:, 1:] = omega + 0.5 * (bias[:, 1:] + bias[:, :-1]) + noise * rng.standard_normal(
        (n_runs, n_steps, 3))  # fmt: skip
    return Truth(dt, q, bias, gyro)


def error_states(q_est: np.ndarray, b_est: np.ndarray, q_true: np.ndarray,
                 b_true: np.ndarray) -> np.ndarray:
    """[δθ, δβ] rows with R_true = Exp(δθ) R_est (docs/conventions.md), vectorised."""
    dtheta = rot.log_map(rot.multiply(q_true, rot.inverse(q_est)))
    return np.concatenate([dtheta, b_true - b_est], axis=-1)


def nees_of(err: np.ndarray, p: np.ndarray) -> np.ndarray:
    """eᵀ P⁻¹ e for stacks (K, 6) and (K, 6, 6)."""
    return np.einsum("ki,ki->k", err, np.linalg.solve(p, err[..., None])[..., 0])


def star_fix_run(make: Factory, truth: Truth, run: int, rng: np.random.Generator
                 ) -> tuple[np.ndarray, AttitudeFilter, list[UpdateResult]]:
    """Filter one run with a full-attitude star fix every step; returns the NEES after each
    update (K,), the filter at the end and the update results."""
    n = truth.q.shape[1] - 1
    e0 = np.concatenate([SIGMA_ATT0 * rng.standard_normal(3),
                         SIGMA_BIAS0 * rng.standard_normal(3)])  # fmt: skip
    q_est0 = rot.multiply(rot.exp_map(-e0[:3]), truth.q[run, 0])
    f = make(q_est0, SIGMA_ATT0, SIGMA_BIAS0, SIGMA_V, SIGMA_U,
             bias_rad_s=truth.bias[run, 0] - e0[3:])  # fmt: skip
    nu = STAR_SIGMA * rng.standard_normal((n + 1, 3))
    fixes = rot.multiply(rot.exp_map(nu), truth.q[run])  # R_meas = Exp(ν) R_true
    cov = np.eye(3) * STAR_SIGMA**2
    q_est, b_est, p_est = np.empty((n, 4)), np.empty((n, 3)), np.empty((n, 6, 6))
    results = []
    for k in range(1, n + 1):
        f.propagate(truth.dt, truth.gyro[run, k])
        results.append(f.update_attitude(fixes[k], cov))
        q_est[k - 1], b_est[k - 1], p_est[k - 1] = f.q_body_icrs, f.bias_rad_s, f.P
    err = error_states(q_est, b_est, truth.q[run, 1:], truth.bias[run, 1:])
    return nees_of(err, p_est), f, results


def nees_band(n_runs: int, dof: int = 6, p: float = 0.95) -> tuple[float, float]:
    """Two-sided band of the run-averaged NEES: chi2(dof·N) quantiles / N."""
    lo, hi = chi2.ppf([(1 - p) / 2, (1 + p) / 2], dof * n_runs)
    return float(lo / n_runs), float(hi / n_runs)


def monte_carlo(make: Factory, n_runs: int, n_steps: int, seed: int) -> dict[str, object]:
    rng = np.random.default_rng(seed)
    truth = simulate(rng, n_runs, n_steps)
    nees = np.empty((n_runs, n_steps))
    final_err, final_sig = np.empty((n_runs, 3)), np.empty((n_runs, 3))
    rejected = 0
    for i in range(n_runs):
        nees[i], f, res = star_fix_run(make, truth, i, rng)
        p = f.P
        rejected += sum(not r.accepted for r in res)
        final_err[i] = truth.bias[i, -1] - f.bias_rad_s
        final_sig[i] = np.sqrt(np.diag(p)[3:])
    anees = nees.mean(axis=0)
    lo, hi = nees_band(n_runs)
    return {"anees": anees, "band": (lo, hi), "inside": float(np.mean((anees > lo) & (anees < hi))),
            "mean": float(anees.mean()), "final_err": final_err, "final_sig": final_sig,
            "rejected": rejected}  # fmt: skip


# --- the long consistency test ---------------------------------------------------------


def test_mekf_monte_carlo_nees_and_bias() -> None:
    """Ex. 7.1 scenario, 20 runs × 30 min at 1 Hz: run-averaged NEES inside its 95 % band,
    bias error inside 3σ, 3σ bias bound below 0.01 °/h at the end."""
    mc = monte_carlo(MEKF, n_runs=20, n_steps=1800, seed=7)
    lo, hi = mc["band"]  # type: ignore[misc]
    # ~95 % of the per-step averages should fall in the band (they are correlated in time,
    # so allow some slack); the grand mean must sit close to 6
    assert mc["inside"] >= 0.85, mc["inside"]
    assert lo < mc["mean"] < hi, (mc["mean"], lo, hi)
    assert mc["rejected"] <= 2  # p = 0.9999 per fix: 36 000 fixes → ~3.6 expected by chance
    err, sig = mc["final_err"], mc["final_sig"]  # type: ignore[misc]
    assert np.mean(np.abs(err) < 3 * sig) >= 0.95
    assert np.all(3 * sig < 0.01 * DEG_PER_H), 3 * sig / DEG_PER_H


# --- the model: Φ, Q, propagation ------------------------------------------------------


def van_loan(omega_hat: np.ndarray, dt: float, sv: float, su: float) -> tuple[np.ndarray, ...]:
    """Exact discrete Φ and Q of δθ' = −[ω̂]×δθ + δβ + η_v, δβ' = η_u (Van Loan 1978)."""
    f = np.zeros((6, 6))
    f[:3, :3] = -rot.skew(omega_hat)
    f[:3, 3:] = np.eye(3)
    qc = np.diag([sv**2] * 3 + [su**2] * 3)
    a = np.zeros((12, 12))
    a[:6, :6], a[:6, 6:], a[6:, 6:] = -f, qc, f.T
    b = expm(a * dt)
    phi = b[6:, 6:].T
    return phi, phi @ b[:6, 6:]


@pytest.mark.parametrize("omega", [[0.0, 0.0, 0.0], [1e-7, -2e-7, 3e-8],
                                   [0.01, -0.02, 0.03], [1.0, 0.5, -2.0]])  # fmt: skip
def test_transition_and_process_noise_match_van_loan(omega: list[float]) -> None:
    dt = 0.5
    phi_ref, q_ref = van_loan(np.array(omega), dt, 3e-4, 2e-5)
    np.testing.assert_allclose(transition_matrix(omega, dt), phi_ref, atol=1e-12)
    q = process_noise(dt, 3e-4, 2e-5)
    # Farrenkopf's Q ignores the rotation of the σu part inside the step: exact at ω = 0,
    # relative error O((ω dt)² σu² dt² / σv²) otherwise
    tol = 1e-10 if np.linalg.norm(omega) * dt < 1e-3 else 1e-3
    assert np.max(np.abs(q - q_ref)) <= tol * np.max(np.abs(q_ref))
    assert q[0, 3] > 0  # +σu²Δt²/2: the cross term sign of this error convention


def test_propagation_closed_form_is_exact_and_matches_scipy() -> None:
    """Constant rate: many small steps = one big step = scipy's body-frame composition."""
    w = np.array([0.3, -0.2, 0.5])
    f1 = MEKF(Q0, 0.01, 1e-6, 0.0, 0.0)
    f2 = MEKF(Q0, 0.01, 1e-6, 0.0, 0.0)
    for _ in range(1000):
        f1.propagate(0.01, w)
    f2.propagate(10.0, w)
    r_icrs_body = Rotation.from_quat(np.roll(Q0, -1)).inv() * Rotation.from_rotvec(w * 10.0)
    q_ref = np.roll(r_icrs_body.inv().as_quat(), 1)
    for f in (f1, f2):
        assert rot.angle_between(f.q_body_icrs, q_ref) < 1e-12
    # the star fixed in ICRS turns the other way in the body frame
    star = np.array([0.0, 0.0, 1.0])
    b0, b1 = rot.rotate(Q0, star), rot.rotate(f2.q_body_icrs, star)
    np.testing.assert_allclose(b1, Rotation.from_rotvec(-w * 10.0).apply(b0), atol=1e-12)


def test_truth_simulation_kinematics() -> None:
    """The truth attitude obeys dv_body/dt = −ω × v_body for an inertially fixed vector."""
    truth = simulate(np.random.default_rng(0), 1, 10, dt=0.001, omega=np.array([0.1, 0.2, 0.3]))
    v = rot.rotate(truth.q[0], [0.3, -0.4, 0.866])
    dv = (v[2:] - v[:-2]) / 0.002
    np.testing.assert_allclose(dv, -np.cross([0.1, 0.2, 0.3], v[1:-1]), atol=1e-6)


def test_covariance_stays_symmetric_and_deterministic() -> None:
    def run() -> MEKF:
        rng = np.random.default_rng(3)
        f = MEKF(Q0, 0.05, 1e-5, SIGMA_V, SIGMA_U)
        for _ in range(300):
            f.propagate(0.1, rng.normal(0, 0.01, 3))
            f.update_vector(rng.normal(size=3), rng.normal(size=3), 0.5)
            if rng.random() < 0.1:
                f.update_attitude(rot.exp_map(rng.normal(0, 0.01, 3)), np.diag([1e-4, 2e-4, 3e-4]))
        return f

    a, b = run(), run()
    assert np.array_equal(a.P, a.P.T)
    assert np.all(np.linalg.eigvalsh(a.P) > 0)
    assert np.array_equal(a.q_body_icrs, b.q_body_icrs) and np.array_equal(a.P, b.P)
    assert a.q_body_icrs[0] >= 0 and abs(np.linalg.norm(a.q_body_icrs) - 1) < 1e-15


def test_search_cone_deg() -> None:
    f = MEKF(Q0, [0.01, 0.02, 0.03], 1e-6, 0.0, 0.0)
    assert f.search_cone_deg() == pytest.approx(3 * math.degrees(0.03))
    assert f.search_cone_deg(k=1.0) == pytest.approx(math.degrees(0.03))


# --- magnetometer-only convergence -----------------------------------------------------

ORBIT_PERIOD = 2 * math.pi / 0.0011  # ≈ 95 min
MAG_SIGMA = math.radians(0.5)


def dipole_direction(t: np.ndarray) -> np.ndarray:
    """ICRS-like unit field direction along a 51.6° orbit: tilted dipole (11°) that turns
    with the Earth, B ∝ 3(m·r̂)r̂ − m. It sweeps round twice per orbit."""
    n, inc, tilt, w_e = 0.0011, math.radians(51.6), math.radians(11.0), 7.292e-5
    r = np.stack([np.cos(n * t), np.sin(n * t) * math.cos(inc), np.sin(n * t) * math.sin(inc)], -1)
    m = np.stack([math.sin(tilt) * np.cos(w_e * t), math.sin(tilt) * np.sin(w_e * t),
                  np.full_like(t, math.cos(tilt))], -1)  # fmt: skip
    b = 3 * np.sum(m * r, -1, keepdims=True) * r - m
    return b / np.linalg.norm(b, axis=-1, keepdims=True)


@dataclass
class MagRun:
    err_deg: np.ndarray  # attitude error per step
    sig3_deg: np.ndarray  # search_cone_deg per step
    bias_err: np.ndarray  # final β_true − β_est
    filt: AttitudeFilter


def mag_run(make: Factory, n_steps: int, seed: int = 11, **kw: object) -> MagRun:
    """Gyro + magnetometer only, 1 Hz, 30° initial error with a 30° 1σ prior."""
    rng = np.random.default_rng(seed)
    truth = simulate(rng, 1, n_steps)
    ref = dipole_direction(np.arange(n_steps + 1) * truth.dt)
    meas = rot.rotate(rot.multiply(rot.exp_map(MAG_SIGMA * rng.standard_normal((n_steps + 1, 3))),
                                   truth.q[0]), ref)  # fmt: skip
    q0 = rot.multiply(rot.exp_map(math.radians(30.0) * np.array([1.0, -2.0, 2.0]) / 3.0),
                      truth.q[0, 0])  # fmt: skip
    f = make(q0, math.radians(30.0), SIGMA_BIAS0, SIGMA_V, SIGMA_U, **kw)
    err, sig = np.empty(n_steps), np.empty(n_steps)
    for k in range(1, n_steps + 1):
        f.propagate(truth.dt, truth.gyro[0, k])
        f.update_vector(meas[k], ref[k], MAG_SIGMA)
        err[k - 1] = math.degrees(rot.angle_between(truth.q[0, k], f.q_body_icrs))
        sig[k - 1] = f.search_cone_deg()
    return MagRun(err, sig, truth.bias[0, -1] - f.bias_rad_s, f)


def test_gyro_magnetometer_converges_from_30_degrees() -> None:
    n = int(ORBIT_PERIOD)
    run = mag_run(MEKF, n)
    assert np.max(run.err_deg[n // 2:]) < 2.0, np.max(run.err_deg[n // 2:])
    assert np.max(run.err_deg[120:]) < 2.0  # within two minutes (measured: 70 s)
    assert run.err_deg[-1] < 1.0
    # the search cone (3σ of the worst axis) contains the error throughout, the transient too
    assert np.all(run.err_deg < run.sig3_deg), np.max(run.err_deg / run.sig3_deg)


def test_plain_linearisation_would_be_overconfident_after_a_30_degree_start() -> None:
    """Why the MEKF relinearises large corrections: without it (relinearize_tol=inf) the
    cone shrinks to a few degrees while the error is still ~15° (search cones too small)."""
    plain = mag_run(MEKF, 60, relinearize_tol=math.inf)
    assert np.max(plain.err_deg / plain.sig3_deg) > 2.0
    default = mag_run(MEKF, 60)
    assert np.max(default.err_deg / default.sig3_deg) < 1.0


# --- gating ----------------------------------------------------------------------------


def converged(make: Factory = MEKF, steps: int = 60) -> tuple[AttitudeFilter, Truth]:
    rng = np.random.default_rng(5)
    truth = simulate(rng, 1, steps)
    f = make(truth.q[0, 0], SIGMA_ATT0, SIGMA_BIAS0, SIGMA_V, SIGMA_U, bias_rad_s=BIAS0)
    for k in range(1, steps + 1):
        f.propagate(1.0, truth.gyro[0, k])
        assert f.update_attitude(truth.q[0, k], np.eye(3) * STAR_SIGMA**2).accepted
    return f, truth


def check_wrong_fix_rejected(make: Factory) -> None:
    f, _ = converged(make)
    q, b, p = f.q_body_icrs, f.bias_rad_s, f.P
    wrong = rot.multiply(rot.exp_map(math.radians(20.0) * np.array([0.0, 0.6, 0.8])), q)
    res = f.update_attitude(wrong, np.eye(3) * STAR_SIGMA**2)
    assert isinstance(res, UpdateResult)
    assert not res.accepted and res.dof == 3 and res.nis > 1e6
    assert "NIS" in res.reason and "gate" in res.reason
    assert np.array_equal(f.q_body_icrs, q) and np.array_equal(f.bias_rad_s, b)
    assert np.array_equal(f.P, p)
    # a star direction 20° off is rejected the same way (2 dof)
    r = np.array([0.0, 0.0, 1.0])
    b_wrong = rot.rotate(rot.multiply(rot.exp_map([math.radians(20.0), 0, 0]), q), r)
    res = f.update_vector(b_wrong, r, 10 * ARCSEC)
    assert not res.accepted and res.dof == 2 and "NIS" in res.reason
    # the gate is configurable; None switches it off
    g = make(q, SIGMA_ATT0, SIGMA_BIAS0, SIGMA_V, SIGMA_U, gate_probability=None)
    assert g.gate_probability is None
    assert g.update_attitude(wrong, np.eye(3) * STAR_SIGMA**2).accepted


def test_wrong_fix_rejected_by_nis_gate() -> None:
    check_wrong_fix_rejected(MEKF)


def test_chi2_gate_values() -> None:
    for dof in (1, 2, 3, 6):
        assert chi2_gate(0.9999, dof) == pytest.approx(chi2.ppf(0.9999, dof), rel=1e-10)
    with pytest.raises(ValueError):
        chi2_gate(1.0, 2)


def test_gate_probability_controls_rejection_rate() -> None:
    """With p = 0.5, about half of correctly modelled fixes fail the gate."""
    rng = np.random.default_rng(2)
    truth = simulate(rng, 1, 400)
    f = MEKF(truth.q[0, 0], SIGMA_ATT0, SIGMA_BIAS0, SIGMA_V, SIGMA_U, bias_rad_s=BIAS0,
             gate_probability=0.5)  # fmt: skip
    nu = STAR_SIGMA * rng.standard_normal((401, 3))
    accepted = []
    for k in range(1, 401):
        f.propagate(1.0, truth.gyro[0, k])
        fix = rot.multiply(rot.exp_map(nu[k]), truth.q[0, k])
        accepted.append(f.update_attitude(fix, np.eye(3) * STAR_SIGMA**2).accepted)
    assert 0.35 < np.mean(accepted) < 0.7


# --- the bias reset ----------------------------------------------------------------------


class _ForgetsBiasCorrection(MEKF):
    """The classic bug, for the guard below: the reset drops δβ."""

    def _apply(self, dx: np.ndarray, new_p: np.ndarray) -> None:
        dx = dx.copy()
        dx[3:] = 0.0
        super()._apply(dx, new_p)


def bias_guard_run(make: Factory, steps: int = 600) -> np.ndarray:
    """Noise-free gyro with a constant bias and exact star fixes; returns β_est at the end."""
    bias = np.array([5.0, -3.0, 2.0]) * DEG_PER_H
    truth = simulate(np.random.default_rng(0), 1, steps, bias0=bias, sigma_v=0.0, sigma_u=0.0)
    f = make(truth.q[0, 0], SIGMA_ATT0, 10 * DEG_PER_H, SIGMA_V, SIGMA_U)
    for k in range(1, steps + 1):
        f.propagate(1.0, truth.gyro[0, k])
        f.update_attitude(truth.q[0, k], np.eye(3) * ARCSEC**2)
    return f.bias_rad_s


def test_bias_estimate_converges_to_constant_bias() -> None:
    bias = np.array([5.0, -3.0, 2.0]) * DEG_PER_H
    est = bias_guard_run(MEKF)
    np.testing.assert_allclose(est, bias, rtol=0, atol=0.01 * DEG_PER_H)
    buggy = bias_guard_run(_ForgetsBiasCorrection)
    assert np.all(np.abs(buggy - bias) > 1.0 * DEG_PER_H)  # the guard catches the bug


def test_update_applies_bias_correction_from_cross_covariance() -> None:
    """One fix through a correlated P moves the bias by exactly K[3:] y."""
    f = MEKF(rot.IDENTITY, 1e-3, 1e-5, SIGMA_V, SIGMA_U)
    for _ in range(5):  # builds attitude-bias correlation
        f.propagate(10.0, [0.0, 0.0, 0.0])
    p = f.P
    cov = np.eye(3) * 1e-8
    dtheta = np.array([1e-4, -2e-4, 5e-5])
    y = rot.log_map(rot.multiply(rot.exp_map(dtheta), rot.inverse(f.q_body_icrs)))
    k = p[:, :3] @ np.linalg.inv(p[:3, :3] + cov)
    f.update_attitude(rot.exp_map(dtheta), cov)
    np.testing.assert_allclose(f.bias_rad_s, (k @ y)[3:], rtol=1e-9)
    assert np.all(np.abs(f.bias_rad_s) > 0)


# --- bad input ---------------------------------------------------------------------------


def check_bad_input(make: Factory) -> None:
    f = make(Q0, 0.01, 1e-5, SIGMA_V, SIGMA_U)
    f.propagate(1.0, [0.0, 0.001, 0.0])
    snapshot = (f.q_body_icrs, f.bias_rad_s, f.P)

    def unchanged() -> None:
        for a, b in zip((f.q_body_icrs, f.bias_rad_s, f.P), snapshot, strict=True):
            assert np.all(np.isfinite(a)) and np.array_equal(a, b)

    for gyro in ([np.nan, 0, 0], [0, np.inf, 0], [0, 0, -np.inf], [1e300, 0, 0]):
        with pytest.raises(ValueError, match="gyro"):
            f.propagate(1.0, gyro)
        unchanged()
    for dt in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="dt"):
            f.propagate(dt, [0.0, 0.0, 0.0])
        unchanged()
    with pytest.raises(ValueError, match="shape"):
        f.propagate(1.0, [0.0, 0.0])
    bad_updates = [
        (f.update_vector, ([0.0, 0.0, 0.0], [1.0, 0, 0], 0.01), "zero"),
        (f.update_vector, ([1.0, 0, 0], [0.0, 0.0, 0.0], 0.01), "zero"),
        (f.update_vector, ([np.nan, 0, 1.0], [1.0, 0, 0], 0.01), "finite"),
        (f.update_vector, ([1.0, 0, 0], [1.0, 0, 0], 0.0), "sigma"),
        (f.update_vector, ([1.0, 0, 0], [1.0, 0, 0], np.nan), "sigma"),
        (f.update_attitude, ([0.0, 0, 0, 0], np.eye(3) * 1e-6), "zero"),
        (f.update_attitude, ([np.nan, 0, 0, 1.0], np.eye(3) * 1e-6), "finite"),
        (f.update_attitude, (Q0, np.diag([1e-6, -1e-6, 1e-6])), "positive definite"),
        (f.update_attitude, (Q0, np.zeros((3, 3))), "positive definite"),
        (f.update_attitude, (Q0, np.full((3, 3), np.nan)), "finite"),
        (f.update_attitude, (Q0, np.array([[1e-6, 1e-7, 0], [0, 1e-6, 0], [0, 0, 1e-6]])),
         "symmetric"),
        (f.update_camera_attitude, (Q0, np.diag([1e-6, -1e-6, 1e-6])), "positive definite"),
        (f.update_camera_vector, ([0.0, 0.0, 0.0], [1.0, 0, 0], 0.01), "zero"),
    ]
    for method, args, why in bad_updates:
        res = method(*args)
        assert isinstance(res, UpdateResult) and not res.accepted, (method, args)
        assert why in res.reason, (res.reason, why)
        unchanged()
    with pytest.raises(ValueError, match="shape"):
        f.update_vector([1.0, 0.0], [1.0, 0.0, 0.0], 0.01)
    with pytest.raises(ValueError, match="shape"):
        f.update_attitude(Q0, np.eye(2))
    with pytest.raises(ValueError):
        make([0.0, 0.0, 0.0, 0.0], 0.01, 1e-5, SIGMA_V, SIGMA_U)
    with pytest.raises(ValueError):
        make(Q0, -0.01, 1e-5, SIGMA_V, SIGMA_U)
    # and the filter still works afterwards
    assert f.update_vector([0.0, 1.0, 0.0], rot.rotate(rot.inverse(f.q_body_icrs), [0, 1.0, 0]),
                           0.01).accepted  # fmt: skip


def test_bad_input_is_an_error_or_a_reported_rejection() -> None:
    check_bad_input(MEKF)


# --- camera mounting -----------------------------------------------------------------------


def check_camera_mounting(make: Factory) -> None:
    """A camera fix through a non-identity mounting = the equivalent body fix."""
    q_body_cam = rot.normalize([0.5, -0.5, 0.5, 0.5])  # a 120° mounting
    r_bc = rot.to_matrix(q_body_cam)
    rng = np.random.default_rng(4)
    truth = simulate(rng, 1, 30)
    kw = {"bias_rad_s": BIAS0}
    body = make(truth.q[0, 0], 1e-3, SIGMA_BIAS0, SIGMA_V, SIGMA_U, **kw)
    cam = make(truth.q[0, 0], 1e-3, SIGMA_BIAS0, SIGMA_V, SIGMA_U, q_body_cam=q_body_cam, **kw)
    cov_cam = np.diag([1.0, 1.0, 25.0]) * STAR_SIGMA**2  # roll about the boresight is weak
    a = rng.normal(size=(3, 3)) * 0.1
    cov_cam = cov_cam + STAR_SIGMA**2 * (a @ a.T)
    cov_body = r_bc @ cov_cam @ r_bc.T
    stars = rng.normal(size=(31, 3))
    for k in range(1, 31):
        for f in (body, cam):
            f.propagate(1.0, truth.gyro[0, k])
        nu = rng.multivariate_normal(np.zeros(3), cov_body)
        q_meas_body = rot.multiply(rot.exp_map(nu), truth.q[0, k])
        q_meas_cam = rot.multiply(rot.inverse(q_body_cam), q_meas_body)
        r1 = body.update_attitude(q_meas_body, cov_body)
        r2 = cam.update_camera_attitude(q_meas_cam, cov_cam)
        assert r1.accepted and r2.accepted and r1.nis == pytest.approx(r2.nis, rel=1e-6)
        s = stars[k] / np.linalg.norm(stars[k])
        b_body = rot.rotate(truth.q[0, k], s)
        r1 = body.update_vector(b_body, s, 5 * ARCSEC)
        r2 = cam.update_camera_vector(r_bc.T @ b_body, s, 5 * ARCSEC)
        assert r1.accepted and r2.accepted
        assert rot.angle_between(body.q_body_icrs, cam.q_body_icrs) < 1e-12
    np.testing.assert_allclose(cam.P, body.P, rtol=1e-6, atol=1e-24)
    np.testing.assert_allclose(cam.bias_rad_s, body.bias_rad_s, rtol=1e-6, atol=1e-16)
    np.testing.assert_allclose(cam.q_body_cam, q_body_cam)
    q_cam = rot.multiply(rot.inverse(q_body_cam), cam.q_body_icrs)
    assert rot.angle_between(cam.q_cam_icrs, q_cam) < 1e-14


def test_camera_mounting_equivalent_to_body_fix() -> None:
    check_camera_mounting(MEKF)


def test_attitude_update_equals_the_textbook_kalman_update() -> None:
    # the closed-form S⁻¹ and the float checks against a Kalman update written with
    # numpy's inverse: H = [I 0], K = P Hᵀ S⁻¹, Joseph form, residual Log(q_meas ⊗ q̂⁻¹)
    rng = np.random.default_rng(11)
    for _ in range(20):
        f = MEKF(rot.exp_map(rng.normal(0, 0.3, 3)), rng.uniform(1e-6, 1e-3, 3),
                 rng.uniform(1e-8, 1e-5, 3), 5e-6, 1e-8)
        for _ in range(3):
            f.propagate(0.1, rng.normal(0, 1e-3, 3))
        a = rng.normal(size=(3, 3)) * rng.uniform(1e-6, 1e-4)
        cov = a @ a.T + 1e-12 * np.eye(3)
        nu = np.linalg.cholesky(cov) @ rng.normal(size=3)  # a fix with that covariance
        q_meas = rot.multiply(rot.exp_map(nu), f.q_body_icrs)
        p, q0, b0 = f.P, f.q_body_icrs, f.bias_rad_s
        y = rot.log_map(rot.multiply(q_meas, rot.inverse(q0)))
        s = p[:3, :3] + cov
        nis = float(y @ np.linalg.inv(s) @ y)
        k = p[:, :3] @ np.linalg.inv(s)
        ikh = np.eye(6)
        ikh[:, :3] -= k
        p_new = ikh @ p @ ikh.T + k @ cov @ k.T
        dx = k @ y
        res = f.update_attitude(q_meas, cov)
        assert res.accepted and math.isclose(res.nis, nis, rel_tol=1e-9)
        assert np.allclose(f.bias_rad_s, b0 + dx[3:], rtol=1e-9, atol=1e-18)
        assert rot.angle_between(f.q_body_icrs, rot.multiply(rot.exp_map(dx[:3]), q0)) < 1e-12
        if float(dx[:3] @ dx[:3]) * np.trace(p[:3, :3]) <= 0.01 * np.min(np.diag(cov)):
            assert np.allclose(f.P, p_new, rtol=1e-9, atol=1e-30)  # (no reset Jacobian)


def test_covariance_checks_agree_with_numpy() -> None:
    # an update's covariance checks (in floats) give numpy's verdicts: np.allclose for
    # symmetry, np.linalg.cholesky for positive definiteness
    rng = np.random.default_rng(5)
    cases = [np.diag([1.0, 1.0, -1e-30]), np.diag([1e-20, 1e-20, 1e-20]), np.zeros((3, 3)),
             np.full((3, 3), np.nan), np.diag([np.inf, 1.0, 1.0]),
             np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])]
    for _ in range(300):
        a = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-8, 0)
        c = a @ a.T if rng.random() < 0.5 else a + a.T
        if rng.random() < 0.3:
            c[0, 1] *= 1 + 10.0 ** rng.uniform(-12, -6)  # just (a)symmetric
        cases.append(c)
    verdicts = set()
    for c in cases:
        if not np.all(np.isfinite(c)):
            want = "cov_rad2 is not finite"
        elif not np.allclose(c, c.T, rtol=1e-9, atol=1e-12 * np.max(np.abs(c))):
            want = "cov_rad2 is not symmetric"
        else:
            try:
                np.linalg.cholesky(c)
                want = ""
            except np.linalg.LinAlgError:
                want = "cov_rad2 is not positive definite"
        f = MEKF([1.0, 0.0, 0.0, 0.0], 1e-3, 1e-6, 5e-6, 1e-8)
        res = f.update_attitude(f.q_body_icrs, c)  # a zero residual: only the checks decide
        assert res.reason == want and res.accepted == (want == ""), c
        verdicts.add(want)
    assert len(verdicts) == 4


@pytest.mark.parametrize("turn_rad", [0.0, 3e-7, 4e-4, 2e-3, 0.3, 2.5])
def test_compiled_covariance_step_is_phi_p_phi_t_plus_q(turn_rad: float) -> None:
    # the compiled propagation against the textbook expression built from this module's
    # transition_matrix and process_noise, on both sides of the series branch (1e-3 rad)
    from adfusion.estimation.mekf_kernels import covariance_step

    rng = np.random.default_rng(int(turn_rad * 1e7) + 1)
    for _ in range(20):
        a = rng.normal(size=(6, 6)) * np.r_[1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6]
        p = a @ a.T
        dt = float(rng.uniform(1e-3, 1.0))
        axis = rng.normal(size=3)
        omega = axis / np.linalg.norm(axis) * turn_rad / dt
        arw, rrw = 10 ** rng.uniform(-7, -4), 10 ** rng.uniform(-10, -6)
        phi = transition_matrix(omega, dt)
        want = phi @ p @ phi.T + process_noise(dt, arw, rrw)
        want = 0.5 * (want + want.T)
        got = covariance_step(p, dt, *(omega * dt), arw**2, rrw**2)
        assert np.array_equal(got, got.T)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-13 * np.abs(want).max())
