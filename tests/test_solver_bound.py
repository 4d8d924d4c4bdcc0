"""The lost-in-space search's early exit (kernels.cannot_pass): a pattern is counted but
not matched only when no assignment of it could pass the quick check — checked against the
quick check itself on real matches, and on the solver's results."""

from __future__ import annotations

import numpy as np
import pytest
from adfusion.starid import kernels
from adfusion.starid.lost_in_space import PairWindows
from test_solver import sky_frame

from adfusion import starid


@pytest.fixture(scope="module")
def cat():
    return starid.Catalog.hipparcos(mag_limit=6.0, epoch=2025.0)


@pytest.fixture(scope="module")
def cam():
    return starid.Camera.pinhole(1024, 768, 15.0)


@pytest.fixture(scope="module")
def solver(cat, cam):
    return starid.Solver(cat, cam)


def test_the_bound_never_exceeds_a_quick_checks_p_false(solver, cat, cam):
    """For every pattern of real frames (stars, false stars, noise) at its trial number:
    the bound at a threshold equal to the best p_false the quick check gives its matches
    does not say "cannot pass" — so at any threshold it says so only when no match
    passes."""
    rng = np.random.default_rng(5)
    frames = [sky_frame(cat, cam, rng, n_false=k)[0][:n] for k, n in
              ((0, 4), (0, 5), (0, 8), (3, 9), (8, 14))]
    frames += [rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (n, 2)) for n in (4, 6)]
    pix = cam.pixel_scale_rad
    radius = solver._match_radius_px() * pix
    floor = np.sqrt(2.0) * solver.centroid_sigma_px * pix
    work = kernels.scratch(solver._ix)
    checked = 0
    for xy in frames:
        b = cam.pixels_to_vectors(xy)
        t = PairWindows.of(b, solver.tolerance_rad, 0.0)
        pats, plen, _ = solver._pattern_list(len(xy), True)
        for trial, (pat, n) in enumerate(zip(pats, plen, strict=True), start=1):
            sel, a, tol, lo, hi, chir = kernels.pattern_of(pat[:n], t.angles, t.tol,
                                                           t.cos_min, t.cos_max, b)
            rows, over, _ = kernels.match(solver._ix, lo, hi, chir, solver.work_budget, work)
            if over or not len(rows):
                continue
            ok, p, *_ = kernels.quick_checks(solver._ix, b, sel, rows, a, tol, chir != 0,
                                             trial, radius, floor)
            if not ok.any():
                continue
            best = float(p[ok].min())
            if best >= 1.0:
                continue  # clipped at 1: the bound may lie above (it is not clipped)
            checked += 1
            assert not kernels.cannot_pass(a, tol, chir != 0, len(solver.vectors), trial,
                                           len(xy), radius, floor, best)
    assert checked > 50


def test_a_frame_that_cannot_reach_the_threshold_stops_without_matching(solver, cam):
    """Four random detections: no pattern could pass even with every detection matched
    (one other detection at most), so none is matched — before, each was matched and its
    chance triangles verified, to end in the same refusal."""
    rng = np.random.default_rng(2)
    for _ in range(5):
        xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (4, 2))
        sol = solver.solve(xy)
        assert not sol.ok
        assert sol.reason.startswith("no match"), sol.reason
        assert sol.patterns_tried == len(solver._pattern_list(4, True)[0])
        assert sol.candidates == []


def test_frames_that_pass_are_unchanged_by_the_bound(solver, cat, cam, monkeypatch):
    """Identified frames give the same solution without the bound (the numpy search with
    it removed): path, trials, matches, matching counter, p_false."""
    rng = np.random.default_rng(9)
    frames = [sky_frame(cat, cam, rng, n_false=k)[0] for k in (0, 3, 8, 8)]
    frames += [sky_frame(cat, cam, rng)[0][:n] for n in (4, 5)]
    with_bound = [solver.solve(xy) for xy in frames]
    assert sum(s.ok for s in with_bound) >= 5
    # the numpy search without the bound (it equals the compiled one otherwise)
    monkeypatch.setattr(solver, "_compiled", False)
    monkeypatch.setattr(kernels, "cannot_pass", lambda *a: False)
    for xy, a in zip(frames, with_bound, strict=True):
        if not a.ok:
            continue
        b = solver.solve(xy)
        assert (a.ok, a.path, a.patterns_tried, a.matches, a.matching_counter, a.p_false) \
            == (b.ok, b.path, b.patterns_tried, b.matches, b.matching_counter, b.p_false)
