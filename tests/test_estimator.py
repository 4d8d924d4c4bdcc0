"""The step API on a spinning payload: tracking star ID driven by the filter's prediction."""

from __future__ import annotations

import numpy as np
import pytest
from adfusion.sensors.dynamics import simulate_rate_profile
from adfusion.sensors.gyro import GyroModel
from adfusion.starid.camera.view import stars_in_view

from adfusion import starid
from adfusion.estimation.estimator import Estimator
from adfusion.maths import rotations as rot

FPS = 30.0
GYRO_HZ = 200.0


@pytest.fixture(scope="module")
def scenario():
    """OEDIPUS-like: 512×480, 25.84° wide, stars ≤ V 5, spin 30°/s about an axis 10°
    from the boresight, 200 Hz gyro; 12 s of truth."""
    cat = starid.Catalog.hipparcos(mag_limit=5.0, epoch=2025.0)
    cam = starid.Camera.pinhole(512, 480, 25.84)
    q_body_cam = rot.IDENTITY  # camera along the body axes
    axis = np.array([np.sin(np.radians(10)), 0.0, np.cos(np.radians(10))])
    omega = np.radians(30.0) * axis
    q0 = rot.q_cam_icrs_from_radec_roll(np.radians(15.0), np.radians(62.0), 0.3)
    t_gyro = np.arange(0.0, 12.0, 1 / GYRO_HZ)
    truth = simulate_rate_profile(omega, q0, t_gyro)
    gyro = GyroModel(arw_rad_sqrt_s=np.radians(0.01), rrw_rad_s_sqrt_s=np.radians(1e-4),
                     bias_rad_s=np.radians([0.05, -0.03, 0.02]), rate_hz=GYRO_HZ, seed=3)
    meas = gyro.measure_many(truth.t, truth.omega_body_rad_s)
    return cat, cam, q_body_cam, truth, meas.omega_meas


def centroids(cat, cam, q_cam_icrs, rng, sigma_px=0.3):
    _, xy = stars_in_view(cat, cam, q_cam_icrs)
    return xy + rng.normal(0, sigma_px, xy.shape), len(xy)


def run(scenario, wrong_frame: int | None = None):
    cat, cam, q_body_cam, truth, omega_meas = scenario
    est = Estimator(starid.Solver(cat, cam), q_body_cam,
                    arw_rad_sqrt_s=np.radians(0.01), rrw_rad_s_sqrt_s=np.radians(1e-4))
    rng = np.random.default_rng(1)
    frame_every = round(GYRO_HZ / FPS)
    records = []
    for k, t in enumerate(truth.t):
        if k % frame_every == 0:
            q_cam = rot.multiply(rot.inverse(q_body_cam), truth.q_body_icrs[k])
            if wrong_frame is not None and len(records) == wrong_frame:
                q_cam = rot.q_cam_icrs_from_radec_roll(np.radians(200), np.radians(-30), 1.0)
            xy, n_view = centroids(cat, cam, q_cam, rng)
            rec = est.step(t, gyro=omega_meas[k], detections=xy)
            records.append((rec, n_view, truth.q_body_icrs[k]))
        else:
            est.step(t, gyro=omega_meas[k])
    return est, records


def test_tracking_on_a_spinning_payload(scenario):
    est, records = run(scenario)
    eligible = [r for r in records[1:] if r[1] >= 2]
    accepted = [r for r in eligible if r[0].fix_accepted]
    assert len(eligible) > 300
    assert len(accepted) >= 0.99 * len(eligible)
    modes = [r[0].star_mode for r in records[1:] if r[0].fix_accepted]
    assert modes.count("tracking") >= 0.95 * len(modes)
    # no wrong fix passed the gate: every accepted fix agrees with truth
    for rec, _, q_true in records:
        if rec.fix_accepted:
            q_fix = rot.multiply(est.q_body_cam, rec.solution.q_cam_icrs)
            assert np.degrees(rot.angle_between(q_fix, q_true)) < 0.2
    final = records[-1]
    assert np.degrees(rot.angle_between(final[0].q_body_icrs, final[2])) < 0.05


def test_a_wrong_fix_is_rejected_by_the_gate_and_reported(scenario):
    _est, records = run(scenario, wrong_frame=150)
    rec = records[150][0]
    assert not rec.fix_accepted
    assert any(src == "star fix" and "gate" in why for src, why in rec.rejected), rec.rejected
    # and the filter carries on tracking afterwards
    assert all(r[0].fix_accepted for r in records[152:170])


def test_bad_inputs_are_rejected_with_reasons_and_state_stays_finite(scenario):
    est, _records = run(scenario)
    t = est.t
    rec = est.step(t + 0.01, gyro=[np.nan, 0, 0])
    assert rec.rejected and rec.rejected[0][0] == "gyro"
    rec = est.step(t - 1.0, gyro=[0, 0, 0])
    assert "backwards" in rec.rejected[0][1]
    rec = est.step(t + 0.02, mag=([0, 0, 0], [1, 0, 0]))
    assert rec.rejected[0][0] == "mag"
    rec = est.step(t + 0.03, gyro=[np.inf, 0, 0])
    assert np.all(np.isfinite(est.filter.q_body_icrs)) and np.all(np.isfinite(est.filter.P))


def test_steps_are_deterministic(scenario):
    _, a = run(scenario)
    _, b = run(scenario)
    for (ra, _, _), (rb, _, _) in zip(a, b, strict=True):
        assert np.array_equal(ra.q_body_icrs, rb.q_body_icrs)
        assert np.array_equal(ra.sigma_rad, rb.sigma_rad)


def test_step_gyro_is_step_without_the_record(scenario):
    # the gyro-rate fast path must leave the filter bit-identical to step(t, gyro=...) and
    # refuse the same samples for the same reasons
    _, _, _, truth, omega_meas = scenario
    kw = {"q_body_icrs0": truth.q_body_icrs[0], "arw_rad_sqrt_s": np.radians(0.01),
          "rrw_rad_s_sqrt_s": np.radians(1e-4)}
    a, b = Estimator(None, **kw), Estimator(None, **kw)
    omega = omega_meas[:400].copy()
    omega[100] = [40.0, 0.0, 0.0]  # over the full scale
    omega[200] = omega[199] + [0.5, 0.0, 0.0]  # a 0.5 rad/s jump in 5 ms
    omega[300] = [0.0, np.nan, 0.0]
    times = truth.t[:400].copy()
    times[350] = times[349] - 1e-3  # backwards
    for t, g in zip(times, omega, strict=True):
        rec = a.step(t, gyro=g)
        refused = b.step_gyro(t, g)
        assert (refused is None) == (not rec.rejected)
        if refused is not None:
            assert [refused] == rec.rejected
    assert np.array_equal(a.filter.q_body_icrs, b.filter.q_body_icrs)
    assert np.array_equal(a.filter.P, b.filter.P)
    assert np.array_equal(a.filter.bias_rad_s, b.filter.bias_rad_s)
    assert a.t == b.t
    reasons = [b.step_gyro(times[-1] + 0.1, [0.0, 0.0, 1e3]),
               b.step_gyro(times[-1] + 0.2, [0.0, 0.0, 0.0, 0.0])]
    assert reasons[0][0] == "gyro" and "gyro_max_rate_rad_s" in reasons[0][1]
    assert reasons[1] == ("gyro", "not a finite 3-vector: [0.0, 0.0, 0.0, 0.0]")


def test_tracking_frames_detected_around_the_prior_the_solver_tracks_from() -> None:
    # detect_tracking gets the one prior of the frame — the filter propagated to the
    # frame's time, as the solver then uses it — and the record says how stars were found
    import copy

    from adfusion.sensors.render import SensorModel, render_frame
    from adfusion.starid.detection.windows import TrackingWindows

    cat = starid.Catalog.hipparcos(mag_limit=6.0)
    cam = starid.Camera.pinhole(512, 512, 20.0)
    solver = starid.Solver(cat, cam, centroid_sigma_px=0.05)
    windows = TrackingWindows(solver)
    q0 = rot.q_cam_icrs_from_radec_roll(1.0, 0.5, 0.2)
    w = np.array([0.0, 2e-3, 0.0])  # rad/s: 0.1 s of it moves the stars 2.9 px
    seen = []

    def spy(image, prior):
        seen.append(prior)
        return mode[0](image, prior)

    def refuse(image, prior):
        raise ValueError("bad window")

    mode = [windows.detect]
    est = Estimator(solver, q_body_icrs0=q0, sigma_attitude0_rad=1e-5, exposure_s=0.05,
                    detect_tracking=spy)
    est.step(0.0, gyro=w)
    for k, (how, want) in enumerate([(windows.detect, "windows"),
                                     (lambda image, prior: None, "frame"),
                                     (refuse, "frame")]):
        t = 0.1 * (k + 1)
        q_t = rot.multiply(rot.exp_map(-w * t), q0)  # the true camera attitude at t
        img = render_frame(cam, q_t, cat.vectors, cat.mag,
                           SensorModel(psf_sigma_px=1.2, noise="gaussian"), seed=k).image
        expected = copy.deepcopy(est)
        expected.step(t)  # propagated to the frame's time, no frame
        want_prior = expected.tracking_prior(0.05)
        mode[0] = how
        rec = est.step(t, frame=img)
        assert len(seen) == k + 1
        assert np.array_equal(seen[-1].q_cam_icrs, want_prior.q_cam_icrs)
        assert rec.cone_deg == seen[-1].k * seen[-1].sigma_deg
        assert rec.detection == want and rec.star_mode == "tracking" and rec.fix_accepted
        assert rot.angle_between(rec.solution.q_cam_icrs, q_t) < np.radians(30 / 3600)
        if k == 2:
            assert any("windows failed: bad window" in why for _, why in rec.rejected)
    rec = est.step(0.4, detections=rec.detections_xy)
    assert rec.detection == "given" and len(seen) == 3
