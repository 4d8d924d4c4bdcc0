"""GTSAM smoother: factor algebra, noise calibration, failure modes, and short seeded flights
(centroid-only, so they run in seconds) scored against the simulated truth."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from adfusion.logs import McapLogReader
from adfusion.sensors.scenarios import leo, oedipus
from adfusion.starid.catalog.stars import Catalog
from adfusion.starid.solver import Solver

from adfusion.app.pipeline import replay, simulate
from adfusion.estimation.estimator import Estimator
from adfusion.estimation.faults import WrongMatchInjector
from adfusion.estimation.smoother import (
    SmootherError,
    SmootherInput,
    calibrate_star_noise,
    smooth,
)
from adfusion.estimation.smoother.factors import wnoa_factor
from adfusion.maths import rotations as rot

# --- pieces ------------------------------------------------------------------------------


def test_constant_rate_factor_jacobians_match_finite_differences():
    rng = np.random.default_rng(0)
    keys = [gtsam.symbol("r", 0), gtsam.symbol("w", 0), gtsam.symbol("r", 1),
            gtsam.symbol("w", 1)]
    f = wnoa_factor(keys, 1 / 30, 1e-4)
    v = gtsam.Values()
    v.insert(keys[0], gtsam.Rot3.Expmap(rng.normal(0, 1, 3)))
    v.insert(keys[1], np.array([0.1, -0.05, 3.1]))
    v.insert(keys[2], v.atRot3(keys[0]).compose(gtsam.Rot3.Expmap([0.004, -0.002, 0.105])))
    v.insert(keys[3], np.array([0.11, -0.04, 3.12]))
    A_white, _ = f.linearize(v).jacobian()
    A = np.linalg.solve(f.noiseModel().R(), A_white)  # un-whiten: A_white = R·A
    e0 = f.unwhitenedError(v)
    eps = 1e-7
    num = []
    for k in keys:
        for i in range(3):
            d = np.zeros(3)
            d[i] = eps
            v2 = gtsam.Values(v)
            if k in (keys[0], keys[2]):
                v2.update(k, v.atRot3(k).retract(d))
            else:
                v2.update(k, v.atVector(k) + d)
            num.append((f.unwhitenedError(v2) - e0) / eps)
    num = np.column_stack(num)
    # analytic Jacobians of the rate term are first order in ξ (module docstring): 1 % here
    np.testing.assert_allclose(A[:3], num[:3], atol=1e-5)
    assert np.abs(A[3:] - num[3:]).max() < 0.02 * np.abs(num[3:]).max()


def test_star_noise_calibration_recovers_an_anisotropic_model():
    # OEDIPUS-like geometry: stars within 12° of a 3 rad/s spin axis near the boresight,
    # the along-motion error up to ~3× the across-motion one
    rng = np.random.default_rng(2)
    s0, k_true = 3e-4, 1.5e-3  # rad; s (along-motion σ² = s0² + (k·|ω × b|)²)
    omega = np.array([0.0, 0.0, 3.0])
    b_list, r_list = [], []
    for _ in range(400):
        r = rot.radec_to_vector(rng.uniform(0, 2 * np.pi, 12),
                                np.radians(90.0 - rng.uniform(1.0, 12.0, 12)))
        v = -np.cross(omega, r)
        s = np.linalg.norm(v, axis=1, keepdims=True)
        u = np.cross(r, v / s)
        along = rng.normal(0, 1, (12, 1)) * np.sqrt(s0**2 + (k_true * s) ** 2)
        b = r + rng.normal(0, s0, (12, 1)) * u + along * v / s
        b_list.append(b / np.linalg.norm(b, axis=1, keepdims=True))
        r_list.append(r)
    sigma0, k, n = calibrate_star_noise(b_list, r_list, [omega] * 400)
    assert n > 4700
    assert sigma0 == pytest.approx(s0, rel=0.05)
    assert k == pytest.approx(k_true, rel=0.1)


def test_no_stars_no_answer_and_it_says_why():
    inp = SmootherInput(arw_rad_sqrt_s=1e-4, rrw_rad_s_sqrt_s=1e-6)
    for t in np.arange(0.0, 1.0, 0.01):
        inp.add_gyro(t, [0.0, 0.0, 0.1])
    for t in np.arange(0.0, 1.0, 0.1):
        inp.add_frame(t, b_body=[[0.0, 0.0, 1.0]], r_icrs=[[1.0, 0.0, 0.0]])
    with pytest.raises(SmootherError, match="nothing anchors"):
        smooth(inp)
    with pytest.raises(ValueError, match="increase"):
        inp.add_frame(0.5)


def test_frames_cut_off_from_all_star_data_are_left_out_and_reported():
    # frames 3..6 have no stars and the gyro stops between frames 2 and 7: nothing ties them
    rng = np.random.default_rng(3)
    stars = rot.radec_to_vector(rng.uniform(0, 6, 8), rng.uniform(-1, 1, 8))
    inp = SmootherInput(arw_rad_sqrt_s=1e-4, rrw_rad_s_sqrt_s=1e-6)
    for t in np.arange(0.0, 1.0, 0.01):
        if not 0.25 < t < 0.65:
            inp.add_gyro(t, [0.0, 0.0, 0.0])
    for k, t in enumerate(np.arange(0.0, 1.0, 0.1)):
        inp.add_frame(t, **({} if 3 <= k <= 6 else {"b_body": stars, "r_icrs": stars}))
    res = smooth(inp, sigma_star_rad=1e-4, streak_s=0.0)
    np.testing.assert_allclose(res.t, [0.0, 0.1, 0.2, 0.7, 0.8, 0.9])
    assert any("no gyro over" in p for p in res.problems)
    assert any("4 frame(s) left out, first at t = 0.300 s" in p for p in res.problems)
    assert np.degrees(rot.angle_between(res.q_body_icrs, rot.IDENTITY)).max() < 0.01


def test_an_unobservable_attitude_raises_instead_of_guessing():
    # every frame sees the same star twice: the rotation about it is never observed
    inp = SmootherInput(arw_rad_sqrt_s=1e-4, rrw_rad_s_sqrt_s=1e-6)
    for t in np.arange(0.0, 1.0, 0.01):
        inp.add_gyro(t, [0.0, 0.0, 0.0])
    star = [[0.0, 0.6, 0.8]] * 2
    for t in np.arange(0.0, 1.0, 0.1):
        inp.add_frame(t, b_body=star, r_icrs=star, q_init=rot.IDENTITY)
    with pytest.raises(SmootherError, match=r"could not be optimised|indeterminate"):
        smooth(inp, sigma_star_rad=1e-4, streak_s=0.0)


# --- short flights, scored against the truth ----------------------------------------------


def fly(sc, *, video_only=False, wrong_every=None, **smooth_kw):
    """Filter + smoother over a scenario; per-frame errors (deg) and attitude NEES."""
    cfg = sc.config
    cat = Catalog.hipparcos(mag_limit=cfg["mag_limit"], epoch=cfg["catalog"]["epoch"])
    solver = Solver(cat, sc.camera, centroid_sigma_px=0.5)
    if wrong_every:
        solver = WrongMatchInjector(solver, wrong_every)
    g = cfg["gyro"]
    est = Estimator(solver, sc.q_body_cam, arw_rad_sqrt_s=g["arw_rad_sqrt_s"],
                    rrw_rad_s_sqrt_s=g["rrw_rad_s_sqrt_s"], video_only=video_only)
    inp = SmootherInput(sc.q_body_cam, arw_rad_sqrt_s=g["arw_rad_sqrt_s"],
                        rrw_rad_s_sqrt_s=g["rrw_rad_s_sqrt_s"], video_only=video_only)
    truth, q_true, q_filter = None, [], []
    for ev in sc.events():
        d = ev.data
        if ev.kind == "truth":
            truth = d["q_body_icrs"]
        elif ev.kind == "gyro" and not video_only:
            est.step(ev.t_s, gyro=d["omega_meas_rad_s"])
            inp.add_gyro(ev.t_s, d["omega_meas_rad_s"])
        elif ev.kind == "mag":
            est.step(ev.t_s, mag=(d["b_body_nT"], d["b_ref_icrs_nT"]))
            inp.add_mag(ev.t_s, d["b_body_nT"], d["b_ref_icrs_nT"])
        elif ev.kind == "frame":
            rec = est.step(ev.t_s, detections=d["xy"])
            inp.add_step(ev.t_s, rec, est.solver)
            q_true.append(truth)
            q_filter.append(rec.q_body_icrs)
    res = smooth(inp, **smooth_kw)
    q_true = np.array(q_true)
    assert all(q is not None for q in q_filter[1:])
    err_f = np.degrees(rot.angle_between(np.array(q_filter[1:]), q_true[1:]))
    d = rot.log_map(rot.multiply(q_true, rot.inverse(res.q_body_icrs)))
    nees = np.einsum("ki,kij,kj->k", d, np.linalg.inv(res.cov_attitude), d)
    return err_f, np.degrees(np.linalg.norm(d, axis=1)), nees, res, solver


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.fixture(scope="module")
def oedipus_flight(tmp_path_factory):
    d = tmp_path_factory.mktemp("smooth")
    sim = d / "flight.mcap"
    simulate(oedipus(duration_s=12.0, seed=5, render=False), sim)
    return d, sim


def test_replay_smooth_writes_the_smoothed_history_and_beats_the_filter(oedipus_flight):
    d, sim = oedipus_flight
    s = replay(sim, d / "out.mcap", progress=False, smooth=True)
    r = s.as_dict()
    assert s.smoother["states"] == s.frames == 360 and not s.smoother["problems"]
    assert r["smoothed_error_rms_deg"] <= 0.7 * r["error_rms_deg"], r
    assert r["smoothed_inside_3sigma"] >= 0.95
    states = [m for m in McapLogReader(d / "out.mcap") if m.topic == "/smoothed/state"]
    poses = [m for m in McapLogReader(d / "out.mcap") if m.topic == "/smoothed/pose"]
    assert len(states) == len(poses) == 360
    p = states[100].payload
    assert {"t", "q_body_icrs", "bias", "cov_diag", "nis"} <= set(p)
    assert len(p["q_body_icrs"]) == 4 and len(p["cov_diag"]) == 6 and p["n_stars"] >= 3
    # the gyro bias is estimated (true: 2, −1.5, 1 mrad/s) within its own 3σ
    b, sb = np.array(p["bias"]), np.sqrt(p["cov_diag"][3:])
    assert np.all(np.abs(b - [2e-3, -1.5e-3, 1e-3]) < 3 * sb + 2e-5), (b, sb)


def test_cli_replay_smooth_and_report_draw_both_histories(oedipus_flight, tmp_path, capsys):
    from adfusion.app.cli import main

    _, sim = oedipus_flight
    out = tmp_path / "rep.mcap"
    assert main(["replay", str(sim), "-o", str(out), "--smooth", "--smoother", "isam2"]) == 0
    assert "smoothed (isam2, 360 states" in capsys.readouterr().out
    assert main(["report", str(out), "-o", str(tmp_path / "report")]) == 0
    summary = (tmp_path / "report" / "summary.md").read_text()
    assert "smoothed attitude error" in summary and "- attitude error" in summary


def test_isam2_gives_the_batch_answer_frame_by_frame():
    sc = oedipus(duration_s=6.0, seed=6, render=False)
    _, err_b, _, res_b, _ = fly(sc)
    _, err_i, _, res_i, _ = fly(sc, mode="isam2")
    assert len(res_i.update_s) == len(res_i.t) == 180
    assert rms(err_i) == pytest.approx(rms(err_b), rel=0.1)
    np.testing.assert_allclose(res_i.sigma_rad, res_b.sigma_rad, rtol=0.05)


def test_leo_smoother_beats_the_filter_and_is_consistent():
    err_f, err_s, nees, res, _ = fly(leo(duration_s=40.0, seed=2, render=False))
    assert rms(err_s) <= 0.7 * rms(err_f), (rms(err_s), rms(err_f))
    assert 1.0 < nees.mean() < 6.0  # one run; the 10-run band is in the benchmark
    assert res.iterations < 20


def test_video_only_smoothing_without_a_gyro():
    err_f, err_s, nees, res, _ = fly(oedipus(duration_s=10.0, seed=7, render=False),
                                     video_only=True)
    assert res.video_only and res.omega_rad_s is not None
    assert err_s.max() < 0.1
    assert rms(err_s) < rms(err_f)
    # the spin (0.5 rev/s about body z) comes out of the stars alone
    assert np.median(res.omega_rad_s[:, 2]) == pytest.approx(np.pi, rel=0.01)
    assert 1.0 < nees.mean() < 6.0


def test_wrong_star_matches_are_down_weighted_not_obeyed():
    sc = oedipus(duration_s=10.0, seed=8, render=False)
    err_f, err_s, _, res, solver = fly(sc, wrong_every=50)
    assert len(solver.wrong) >= 5
    assert rms(err_s) < rms(err_f) and err_s.max() < err_f.max()
    # the wrong matches are among the down-weighted residuals, and few good stars are
    flagged = [sid for _, sid, _ in res.outliers]
    assert sum(w in flagged for w in solver.wrong) >= 0.8 * len(solver.wrong)
    good_flagged = sum(sid not in solver.wrong for sid in flagged)
    assert good_flagged < 0.03 * res.n_stars.sum()
    # and without a robust kernel the same log is visibly worse
    _, err_plain, _, _, _ = fly(sc, wrong_every=50, robust="none")
    assert rms(err_plain) > 1.5 * rms(err_s)
