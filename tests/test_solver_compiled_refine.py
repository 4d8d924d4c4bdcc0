"""A candidate's verification and the final refit, compiled (kernels.verify_candidate,
kernels.refine_pinhole), against the Python code they replace (verify.Verifier.verify,
refine.Refiner.refine): the same identifications, paths, trials, pairs and notes,
p_false to 1e-12, the fit to rounding — on frames with noise, false stars, dropped stars,
blurred centroids and sparse fields. benchmarks/compiled_equivalence.py runs the same
comparison on the benchmark's frames."""

from __future__ import annotations

import numpy as np
import pytest
from test_solver import sky_frame

from adfusion import starid


@pytest.fixture(scope="module")
def cat():
    return starid.Catalog.hipparcos(mag_limit=6.0, epoch=2025.0)


@pytest.mark.parametrize("sigma_px, n_false, drop, n_max", [
    (0.3, 0, 0.0, 99), (0.3, 8, 0.0, 99), (0.3, 3, 0.3, 99), (2.0, 0, 0.0, 99),
    (0.3, 0, 0.0, 0)])
def test_the_compiled_verification_equals_the_python_code(cat, sigma_px, n_false, drop,
                                                          n_max):
    cam = starid.Camera.pinhole(1024, 768, 15.0)
    solver = starid.Solver(cat, cam, centroid_sigma_px=max(0.5, sigma_px))
    rng = np.random.default_rng(40 + n_false + n_max)
    notes = shown = 0
    for _ in range(12):
        xy, _ = sky_frame(cat, cam, rng, sigma_px=sigma_px, n_false=n_false, drop=drop)
        if not n_max:  # noise: weak candidates, verified to be shown
            xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (8, 2))
        solver._compiled_verify = solver._compiled_refine = True
        a = solver.solve(xy)
        solver._compiled_verify = solver._compiled_refine = False
        b = solver.solve(xy)
        assert (a.ok, a.reason, a.path, a.patterns_tried, a.matches, a.matching_counter,
                a.note) == (b.ok, b.reason, b.path, b.patterns_tried, b.matches,
                            b.matching_counter, b.note)
        assert [c.matches for c in a.candidates] == [c.matches for c in b.candidates]
        for x, y in zip([a.p_false] + [c.p_false for c in a.candidates],
                        [b.p_false] + [c.p_false for c in b.candidates], strict=True):
            assert x == y or x == pytest.approx(y, rel=1e-12)
        notes += "rejected" in a.note
        shown += len(a.candidates) if not a.ok else 0
        if a.ok:
            assert np.max(np.abs(a.q_cam_icrs - b.q_cam_icrs)) < 1e-12
            assert np.max(np.abs(a.residuals_rad - b.residuals_rad)) < 1e-13
            assert np.max(np.abs(a.covariance - b.covariance)) < 1e-11 * np.max(
                np.abs(b.covariance))
            assert a.sigma_px == pytest.approx(b.sigma_px, rel=1e-11)
            assert a.camera is b.camera
    if sigma_px > 1:
        assert notes > 0  # the residual rejection ran
    if not n_max:
        assert shown > 10


def test_an_uncertain_camera_keeps_the_python_refit(cat, monkeypatch):
    """A camera being fitted (FOV uncertain) is refitted in Python, not by the kernels (the
    refit's own, or the one-call frame's that runs it)."""
    from adfusion.starid.identify import frame_kernels, kernels
    calls = []
    real, real_frame = kernels.refine_pinhole, frame_kernels.solve_frame_packed
    monkeypatch.setattr(kernels, "refine_pinhole", lambda *a: calls.append(1) or real(*a))
    monkeypatch.setattr(frame_kernels, "solve_frame_packed",
                        lambda *a: calls.append(a[-2]) or real_frame(*a))  # a[-2]: refine
    real_lean = frame_kernels.lean_call  # the lean path's call refits in the kernel
    monkeypatch.setattr(frame_kernels, "lean_call", lambda st: (
        lambda *a: calls.append(True) or real_lean(st)(*a)))
    xy, _ = sky_frame(cat, starid.Camera.pinhole(1024, 768, 15.2), np.random.default_rng(3))
    s = starid.Solver(cat, starid.Camera.pinhole(1024, 768, 15.0), fov_error_deg=0.6,
                      max_patterns=40)
    assert s.solve(xy).ok and not calls
    s2 = starid.Solver(cat, starid.Camera.pinhole(1024, 768, 15.0))
    assert s2.solve(sky_frame(cat, s2.camera, np.random.default_rng(4))[0]).ok and calls


def test_a_principal_point_off_the_centre_keeps_the_far_corners_stars(cat):
    """With the principal point 100 px and 60 px off the frame's centre, the farthest corner
    is ~0.6° beyond half the diagonal field: the compiled refit's catalogue cone (and the
    tracking path's prediction) must reach it. The compiled refit (lean path), the Python
    refit and tracking from the true attitude match the same stars, among them stars
    beyond half the diagonal."""
    from adfusion.starid.camera.view import stars_in_view
    from adfusion.starid.identify.solution import Prior

    from adfusion.maths import rotations as rot

    K = starid.Camera.pinhole(1024, 768, 15.0).K.copy()
    K[0, 2] += 100.0
    K[1, 2] += 60.0
    cam = starid.Camera(K, np.zeros(5), 1024, 768)
    half_diagonal = 0.5 * np.radians(cam.diagonal_fov_deg)
    assert cam._view_half_rad > half_diagonal + np.radians(0.5)
    fast, slow = starid.Solver(cat, cam), starid.Solver(cat, cam)
    slow._compiled_refine = False
    rng = np.random.default_rng(0)
    beyond = [0, 0]  # matched stars beyond half the diagonal: lost in space, tracking
    for _ in range(60):
        q = rot.q_cam_icrs_from_radec_roll(rng.uniform(0, 2 * np.pi),
                                           np.arcsin(rng.uniform(-1, 1)),
                                           rng.uniform(0, 2 * np.pi))
        _, xy = stars_in_view(cat, cam, q, brightest_first=True)
        if len(xy) < 5:
            continue
        xy = np.ascontiguousarray(xy + rng.normal(0, 0.3, xy.shape))
        a, b = fast.solve(xy), slow.solve(xy.tolist())
        t = fast.solve(xy, prior=Prior(q, 0.01))
        assert a.ok and b.ok and t.ok
        assert sorted(a.matches) == sorted(b.matches)
        for sol, k in ((a, 0), (t, 1)):
            off_axis = np.arccos(cam.pixels_to_vectors(xy[[d for d, _ in sol.matches]])[:, 2])
            beyond[k] += int((off_axis > half_diagonal + 1e-3).sum())
    assert min(beyond) > 0
