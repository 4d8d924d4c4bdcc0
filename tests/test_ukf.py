"""USQUE UKF tests: the MEKF's scenarios (``tests/test_mekf.py``) and agreement with the MEKF."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_mekf import (
    DEG_PER_H,
    ORBIT_PERIOD,
    bias_guard_run,
    check_bad_input,
    check_camera_mounting,
    check_wrong_fix_rejected,
    mag_run,
    monte_carlo,
)

from adfusion.estimation.mekf import MEKF
from adfusion.estimation.ukf import UKF, grp_from_quaternion, quaternion_from_grp
from adfusion.maths import rotations as rot


def test_grp_round_trip_and_small_angle_equals_rotation_vector() -> None:
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(50, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = rng.uniform(0, math.pi * 0.999, (50, 1))
    q = rot.exp_map(axes * angles)
    p = grp_from_quaternion(q)
    np.testing.assert_allclose(p, 4 * np.tan(angles / 4) * axes, rtol=1e-12)  # |p| = 4 tan(θ/4)
    np.testing.assert_allclose(quaternion_from_grp(p), q, atol=1e-14)
    np.testing.assert_allclose(grp_from_quaternion(-q), p, atol=1e-14)  # same rotation
    small = np.array([1e-5, -2e-5, 3e-6])
    np.testing.assert_allclose(grp_from_quaternion(rot.exp_map(small)), small, rtol=1e-9)


def test_ukf_short_monte_carlo_consistency() -> None:
    """10 runs × 5 min of the Ex. 7.1 scenario: run-averaged NEES inside its 95 % band."""
    mc = monte_carlo(UKF, n_runs=10, n_steps=300, seed=8)
    lo, hi = mc["band"]  # type: ignore[misc]
    assert mc["inside"] >= 0.85, mc["inside"]
    assert lo < mc["mean"] < hi, (mc["mean"], lo, hi)
    err, sig = mc["final_err"], mc["final_sig"]  # type: ignore[misc]
    assert np.mean(np.abs(err) < 3 * sig) >= 0.9


def test_ukf_and_mekf_agree_on_the_same_magnetometer_run() -> None:
    """Gyro + magnetometer from 30° off, one orbit: both converge below 2°, and the two
    estimates stay within each other's 3σ bounds throughout."""
    n = int(ORBIT_PERIOD)
    u = mag_run(UKF, n)
    m = mag_run(MEKF, n)
    assert np.max(u.err_deg[n // 2:]) < 2.0 and u.err_deg[-1] < 1.0
    assert np.mean(u.err_deg < u.sig3_deg * math.sqrt(3)) > 0.99
    # the difference between the estimates is bounded by the sum of their errors, each
    # inside its own 3σ cone; after the first minute it is far inside
    diff = np.abs(u.err_deg - m.err_deg)
    assert np.all(diff[60:] < np.minimum(u.sig3_deg, m.sig3_deg)[60:]), np.max(diff[60:])
    d = rot.angle_between(u.filt.q_body_icrs, m.filt.q_body_icrs)
    assert math.degrees(d) < min(u.filt.search_cone_deg(), m.filt.search_cone_deg())
    sig_b = np.sqrt(np.diag(m.filt.P)[3:])
    assert np.all(np.abs(u.filt.bias_rad_s - m.filt.bias_rad_s) < 3 * sig_b)
    np.testing.assert_allclose(np.sqrt(np.diag(u.filt.P)), np.sqrt(np.diag(m.filt.P)), rtol=0.1)


def test_ukf_wrong_fix_rejected_by_nis_gate() -> None:
    check_wrong_fix_rejected(UKF)


def test_ukf_bias_estimate_converges_to_constant_bias() -> None:
    bias = np.array([5.0, -3.0, 2.0]) * DEG_PER_H
    np.testing.assert_allclose(bias_guard_run(UKF, steps=300), bias, atol=0.02 * DEG_PER_H)


def test_ukf_bad_input_is_an_error_or_a_reported_rejection() -> None:
    check_bad_input(UKF)


def test_ukf_camera_mounting_equivalent_to_body_fix() -> None:
    check_camera_mounting(UKF)


@pytest.mark.parametrize("cls", [MEKF, UKF])
def test_same_interface(cls: type) -> None:
    f = cls(rot.IDENTITY, 0.01, 1e-5, 1e-6, 1e-9, bias_rad_s=[1e-5, 0, 0],
            q_body_cam=rot.exp_map([0, 0.1, 0]), gate_probability=0.999)  # fmt: skip
    f.propagate(0.5, [0.0, 0.0, 0.01])
    assert f.update_vector([0, 0, 1.0], rot.rotate(rot.inverse(f.q_body_icrs), [0, 0, 1.0]),
                           1e-3).accepted  # fmt: skip
    assert f.update_camera_attitude(f.q_cam_icrs, np.eye(3) * 1e-6).accepted
    assert f.P.shape == (6, 6) and f.bias_rad_s.shape == (3,) and f.q_body_icrs.shape == (4,)
    assert f.search_cone_deg() > 0 and set(f.state_dict()) == {"q_body_icrs", "bias_rad_s", "P"}
    assert type(f).__name__ in repr(f)
