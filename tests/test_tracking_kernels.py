"""Tracking's compiled path (starid.tracking.kernels) gives what the numpy path gives: the
same outcome, reason, matches and p_false, the same attitude to rounding — on clean
frames, two- and three-star frames, false detections, detections claimed twice, streaked
frames and a catalogue too large to scan (the solver's cone instead)."""

from __future__ import annotations

import time

import numpy as np
import pytest
from adfusion.starid.camera.view import stars_in_view
from adfusion.starid.tracking import tracking

from adfusion import starid
from adfusion.maths import rotations as rot


@pytest.fixture(scope="module")
def wide():
    cat = starid.Catalog.hipparcos(mag_limit=5.5, epoch=2025.0)
    cam = starid.Camera.pinhole(512, 480, 25.84)
    return cat, cam, starid.Solver(cat, cam)


def _cases(cat, cam, rng, n):
    """(xy, prior) of random skies: clean, the first 2 or 3, false stars, a ghost beside
    a star (two detections in one gate), a streaked prior, a prior off by ~its σ."""
    for k in range(n):
        q = rot.q_cam_icrs_from_radec_roll(rng.uniform(0, 2 * np.pi),
                                           np.arcsin(rng.uniform(-1, 1)),
                                           rng.uniform(0, 2 * np.pi))
        _, xy = stars_in_view(cat, cam, q)
        if len(xy) < 2:
            continue
        xy = xy + rng.normal(0, 0.4, xy.shape)
        sigma = float(rng.uniform(0.005, 0.04))
        err = rng.normal(0, np.radians(sigma) / np.sqrt(3), 3)
        prior = starid.Prior(rot.multiply(rot.exp_map(err), q), sigma)
        kind = k % 6
        if kind == 1:
            xy = xy[: 2 + k % 2]
        elif kind == 2:
            xy = np.vstack([xy, rng.uniform((0, 0), (cam.width, cam.height), (8, 2))])
        elif kind == 3:
            xy = np.vstack([xy, xy[:3] + rng.normal(0, 1.2, (3, 2))])
        elif kind == 4:
            prior = starid.Prior(prior.q_cam_icrs, sigma,
                                 smear_cam_rad=rng.normal(0, 0.02, 3))
        elif kind == 5:
            prior = starid.Prior(rot.multiply(rot.exp_map(2.5 * err), q), sigma)
        yield np.ascontiguousarray(xy), prior


def _same(a, b):
    assert (a.ok, a.reason, a.mode, a.path, a.matches, a.p_false) == \
        (b.ok, b.reason, b.mode, b.path, b.matches, b.p_false)
    assert len(a.candidates) == len(b.candidates)
    for x, y in [(a, b), *zip(a.candidates, b.candidates, strict=True)]:
        if x.q_cam_icrs is None:
            assert y.q_cam_icrs is None
            continue
        np.testing.assert_allclose(x.q_cam_icrs, y.q_cam_icrs, rtol=0, atol=1e-13)
        np.testing.assert_allclose(x.residuals_rad, y.residuals_rad, rtol=0, atol=1e-13)
        np.testing.assert_allclose(x.covariance, y.covariance, rtol=1e-9,
                                   atol=1e-9 * np.abs(y.covariance).max())


def _compare(solver, cases):
    compiled = accepted = 0
    tight = solver.verifier.match_radius_px()
    for xy, prior in cases:
        gate = np.radians(prior.k * prior.sigma_deg)
        wide = max(gate / solver.camera.pixel_scale_rad * 1.2 + tight, tight)
        assert wide <= 2.5 * tight  # every case is a tight prior: the compiled path's
        a = solver.tracker.track_compiled(xy, prior, gate, tight, wide, time.perf_counter())
        b = solver.tracker.track_numpy(xy, prior, time.perf_counter())
        if a is None:  # collinear: the numpy path's words
            assert "collinear" in b.reason
            continue
        compiled += 1
        accepted += a.ok
        _same(a, b)
    return compiled, accepted


def test_compiled_tracking_equals_the_numpy_path(wide):
    cat, cam, s = wide
    compiled, accepted = _compare(s, _cases(cat, cam, np.random.default_rng(3), 240))
    assert compiled >= 200 and accepted >= 150


def test_compiled_tracking_equals_the_numpy_path_through_the_cone(wide, monkeypatch):
    """A catalogue larger than the scan limit: the compiled prediction takes the solver's
    cached cone's rows instead of every row, with the same stars."""
    cat, cam, s = wide
    monkeypatch.setattr(tracking, "_SCAN_ALL_MAX", 0)
    compiled, accepted = _compare(s, _cases(cat, cam, np.random.default_rng(4), 60))
    assert compiled >= 50 and accepted >= 35


def test_solve_takes_the_compiled_path_for_a_tight_prior(wide, monkeypatch):
    """``solve`` with a filter's tight prior goes through the compiled path (and, with a
    distorted camera, through numpy, with the same answer)."""
    cat, cam, s = wide
    calls = []
    real = tracking.Tracker.track_compiled
    monkeypatch.setattr(tracking.Tracker, "track_compiled",
                        lambda self, *a: calls.append(1) or real(self, *a))
    q = rot.q_cam_icrs_from_radec_roll(1.0, 0.4, 0.3)
    _, xy = stars_in_view(cat, cam, q)
    sol = s.solve(xy, prior=starid.Prior(q, 0.02))
    assert sol.ok and sol.mode == "tracking" and calls == [1]
    bent = starid.Camera(cam.K, np.array([1e-9, 0.0, 0.0, 0.0, 0.0]), cam.width, cam.height)
    other = starid.Solver(cat, bent).solve(xy, prior=starid.Prior(q, 0.02))
    assert calls == [1] and other.ok and other.matches == sol.matches


@pytest.mark.parametrize("parity", [1, -1])
def test_compiled_tracking_equals_the_numpy_path_for_a_skewed_mirrored_camera(wide, parity):
    """Skew, non-square pixels, an off-centre principal point, a mirrored image: the
    compiled projection and bearings follow the camera's affine maps like numpy's."""
    cat, cam, _ = wide
    K = cam.K.copy()
    K[0, 1], K[1, 1], K[0, 2] = 3.0, 1.01 * K[1, 1], K[0, 2] + 7.0
    odd = starid.Camera(K, np.zeros(5), cam.width, cam.height, parity=parity)
    compiled, accepted = _compare(starid.Solver(cat, odd),
                                  _cases(cat, odd, np.random.default_rng(7 + parity), 40))
    assert compiled >= 35 and accepted >= 25
