"""Motion smear: tracking with a prior that knows the exposure's rotation.

Long streaks break into pieces in the noise, and a piece's centroid lies anywhere along
its star's streak. An isotropic fit then claims the centroid noise along the streaks and
accepts attitudes 10 px off (the rate sweep before this model); with the smear known
(gyro × exposure) the fit trusts the stars only across their streaks and says so.
"""

from __future__ import annotations

import numpy as np
import pytest
from adfusion.starid.camera.model import Camera
from adfusion.starid.solver import Prior

from adfusion.maths import rotations as rot
from adfusion.maths.attitude import refine_streaked, streak_vectors, wahba_unit


def _pieces(rng, q, r, smear, sigma, whole):
    """Detections of streaked stars: a random piece of each streak (its centroid uniform
    over the length the piece can slide), plus isotropic centroid noise."""
    b_mid = rot.rotate(q, r)
    v = streak_vectors(b_mid, smear)
    length = np.linalg.norm(v, axis=1)
    slide = np.maximum(length - whole, 0.0)
    tau = rng.uniform(-0.5, 0.5, len(r)) * slide / np.maximum(length, 1e-300)
    b = b_mid + tau[:, None] * v + rng.normal(0.0, sigma, b_mid.shape)
    return b / np.linalg.norm(b, axis=1, keepdims=True)


def _nees(q_est, q_true, cov):
    e = rot.log_map(rot.multiply(q_est, rot.inverse(q_true)))
    return float(e @ np.linalg.solve(cov, e))


def test_streaked_fit_covariance_is_consistent_where_an_isotropic_fit_is_not():
    rng = np.random.default_rng(7)
    cam = Camera.pinhole(1024, 768, 15.0)
    pix = cam.pixel_scale_rad
    sigma, whole = 0.5 * pix, 20 * pix
    ours, iso = [], []
    for _ in range(300):
        q = rot.normalize(rng.normal(size=4))
        xy = np.column_stack([rng.uniform(0, 1023, 8), rng.uniform(0, 767, 8)])
        r = rot.rotate(rot.inverse(q), cam.pixels_to_vectors(xy))
        axis = rng.normal(size=3)
        smear = np.radians(1.0) * axis / np.linalg.norm(axis)  # 10 °/s over 0.1 s
        b = _pieces(rng, q, r, smear, sigma, whole)
        w = wahba_unit(b, r, sigma)
        s = refine_streaked(w.q_cam_icrs, b, r, sigma, smear, whole)
        ours.append(_nees(s.q_cam_icrs, q, s.covariance))
        iso.append(_nees(w.q_cam_icrs, q, w.covariance))
    # χ²(3): mean 3; 300 samples put the mean within ±0.6 at ~3σ
    assert 2.4 < np.mean(ours) < 3.6
    assert np.mean(iso) > 30  # the isotropic fit is badly overconfident on pieces


def test_streaks_shorter_than_whole_give_the_isotropic_fit():
    rng = np.random.default_rng(3)
    q = rot.q_cam_icrs_from_radec_roll(0.3, -0.4, 1.0)
    r = rot.radec_to_vector(0.3 + rng.normal(0, 0.05, 6), -0.4 + rng.normal(0, 0.05, 6))
    b = rot.rotate(q, r) + rng.normal(0, 1e-4, (6, 3))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    w = wahba_unit(b, r, 1e-4)
    s = refine_streaked(w.q_cam_icrs, b, r, 1e-4, [0.0, 0.0, 1e-3], whole_rad=1.0)
    assert rot.angle_between(s.q_cam_icrs, w.q_cam_icrs) < 1e-9
    np.testing.assert_allclose(s.covariance, w.covariance, rtol=1e-6)


def test_prior_rejects_a_bad_smear_vector():
    with pytest.raises(ValueError, match="smear_cam_rad"):
        Prior([1.0, 0.0, 0.0, 0.0], 0.1, smear_cam_rad=[0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="smear_cam_rad"):
        Prior([1.0, 0.0, 0.0, 0.0], 0.1, smear_cam_rad=[0.0, 1.0])


def test_tracking_on_rendered_streaks_accepts_no_wrong_attitude():
    """Rendered frames at 10 °/s over 0.1 s (1° streaks, 68 px), through ``detect``, with
    the rate sweep's filter-like prior — which carries the smear. Frames 139, 163, 203,
    223 and 346 were accepted 9–19 px off by the isotropic tracking fit."""
    from adfusion.bench import starid as bs
    from adfusion.bench.sweep import SWEEPS

    cond = SWEEPS["rate_deg_s"].condition(10.0).resolved(0.1, 6.0, mag_noise=0.1,
                                                           fov_deg=15.0)
    cam = bs.camera_for(cond, 1024, 768, 15.0)
    cat = bs.load_catalog(6.0, 2025.0)
    solver = bs.solver_for(6.0, 0.1, cam)
    verdicts = []
    for index in [139, 163, 203, 223, 346, *range(12)]:
        frame = bs.make_frame(cat, cam, cond, 0, index)
        prior = bs.tracking_prior(frame, 0.1)
        assert prior.smear_cam_rad is not None
        sol = solver.solve(frame.xy, prior=prior)
        outcome = bs.Outcome(sol.ok, sol.q_cam_icrs, sol.time_s, sol.reason)
        verdicts.append(bs.score(frame, outcome, cam, 5.0, cat).verdict)
    assert "wrong" not in verdicts
    assert verdicts.count("correct") >= 5


def test_estimator_hands_the_exposure_rotation_to_tracking():
    """The prior's smear is the rate estimate (gyro less bias) in camera axes × exposure."""
    from adfusion.estimation.estimator import Estimator

    with pytest.raises(ValueError, match="exposure_s"):
        Estimator(None, exposure_s=-0.01)
    q_body_cam = rot.exp_map([0.0, 0.3, 0.0])  # camera tilted about body y
    est = Estimator(None, q_body_cam, q_body_icrs0=rot.IDENTITY, exposure_s=0.02)
    omega_body = np.array([0.1, -0.2, 3.0])
    est.step(0.0, gyro=omega_body)
    expected = rot.to_matrix(q_body_cam).T @ (omega_body - est.filter.bias_rad_s) * 0.02
    np.testing.assert_allclose(est._smear(0.02), expected, rtol=1e-12)
    assert est._smear(None) is None and est._smear(0.0) is None
