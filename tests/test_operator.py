"""The operator-in-the-loop API (docs/references.md#bleif-2004, criterion 14's accept/reject) and
``Solver(method="bleif")`` through the project's verification."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from adfusion.sensors.tubsat import star_blocks
from adfusion.starid.bleif.matcher import find_matches, stars_in_frame, tubsat_camera
from adfusion.starid.bleif.operator import IdentificationSession, overlay_png, suggest_stars
from adfusion.starid.bleif.patterns import PatternCatalog
from adfusion.starid.bleif.star_angles import (
    q_cam_icrs_from_star_angles,
    star_angles_from_q_cam_icrs,
)
from adfusion.starid.catalog.stars import Catalog

from adfusion import starid
from adfusion.estimation.estimator import Estimator
from adfusion.maths import rotations as rot


@pytest.fixture(scope="module")
def cat():
    return Catalog.hipparcos(mag_limit=6.5)


@pytest.fixture(scope="module")
def pc(cat):
    return PatternCatalog.build(cat)


@pytest.fixture(scope="module")
def scene(cat):
    """The thesis's Fig. 6.4 attitude as a reduced image with hot pixels."""
    q = q_cam_icrs_from_star_angles(*np.radians([164.16, 43.53, 283.64]))
    return q, star_blocks(cat, tubsat_camera(), q, seed=3)


def test_session_steps_rejects_accepts_and_locks_into_the_estimator(pc, scene):
    q, blocks = scene
    cam = tubsat_camera()
    s = IdentificationSession(pc, cam, blocks.xy)
    marks = s.suggest(n=4)
    assert len(marks) == 4
    every = s.matches()
    assert s.count == len(every) >= 1
    truth = next(k for k, c in enumerate(every)
                 if math.degrees(rot.angle_between(c.q_cam_icrs, q)) < 1.0)
    assert len(every) > 1  # four stars: several candidates (thesis: 6)
    shown = [s.next_candidate()]
    for _ in range(len(every) - 1):
        shown.append(s.reject())  # each reject shows the next candidate, lazily
    assert [c.pattern for c in shown] == [c.pattern for c in every]
    assert s.reject() is None  # all rejected: the search is exhausted
    assert [c.pattern for c in s.rejected] == [c.pattern for c in every]
    acc = s.accept(every[truth])  # the operator goes back to the one that fitted
    assert acc.pattern == every[truth].pattern
    assert s.next_candidate() is None  # accepting stops the iteration
    est = Estimator(None)
    with pytest.raises(ValueError, match="accept"):
        IdentificationSession(pc, cam).lock(est, 0.0)
    rec = s.lock(est, 12.0)
    assert rec.fix_accepted and est.initialized and est.t == 12.0
    assert math.degrees(rot.angle_between(est.filter.q_body_icrs, acc.q_cam_icrs)) < 1e-9
    # a second, consistent fix goes through the filter's gate
    rec2 = est.add_fix(13.0, acc.q_cam_icrs, acc.covariance, source="operator fix")
    assert rec2.fix_accepted and "operator fix" in rec2.nis
    s.clear_stars()
    assert len(s.stars) == 0 and s.accepted is None


def test_suggest_prefers_multi_block_clusters_and_avoids_huge_ones():
    cam = tubsat_camera()
    single = [[50.0, 50.0]]
    pair = [[200.0, 100.0], [201.0, 101.0]]
    triple = [[376.0, 298.0], [377.0, 299.0], [375.0, 300.0]]  # at the centre
    huge = [[600.0, 400.0 + k] for k in range(20)]
    xy = suggest_stars(single + pair + triple + huge, cam, n=5)
    np.testing.assert_allclose(xy, [np.mean(triple, axis=0), np.mean(pair, axis=0)])
    assert len(suggest_stars(single, cam)) == 0


def test_suggested_stars_are_real_stars_of_the_reduced_image(cat, scene):
    q, blocks = scene
    cam = tubsat_camera()
    xy = suggest_stars(blocks.xy, cam, n=6)
    truth_xy, _ = stars_in_frame(PatternCatalog.build(cat), cam, q)
    for p in xy:
        assert np.hypot(*(truth_xy - p).T).min() < 3.0  # a star centre, not a hot pixel


def test_overlay_png_draws_the_candidate(pc, scene, tmp_path):
    _q, blocks = scene
    cam = tubsat_camera()
    s = IdentificationSession(pc, cam, blocks.xy)
    s.suggest(n=5)
    c = s.next_candidate()
    ov = s.overlay(c)
    path = overlay_png(ov, cam, tmp_path / "cand.png", blocks.xy)
    img = cv2.imread(str(path))
    assert img.shape == (cam.height, cam.width, 3)
    paths = s.overlay_pngs(tmp_path / "steps")
    assert [p.name for p in paths][:1] == ["candidate-01.png"] and len(paths) == s.count
    # the reference's circle is light green: pixels of that colour near its position
    x, y = ov.xy[ov.is_reference][0]
    win = img[int(y) - 15:int(y) + 16, int(x) - 15:int(x) + 16].reshape(-1, 3)
    assert np.any(np.all(win == (144, 238, 144), axis=1))


def test_faithful_mode_finds_the_truth_and_flags_what_the_thesis_gets_wrong(pc, cat):
    pcf = PatternCatalog.build(cat, faithful=True)
    cam = tubsat_camera()
    rng = np.random.default_rng(5)
    found, flagged_or_close = 0, 0
    for _ in range(12):
        q = rot.q_cam_icrs_from_radec_roll(rng.uniform(0, 2 * np.pi), rng.uniform(-1.0, 1.0),
                                           rng.uniform(0, 2 * np.pi))
        xy, idx = stars_in_frame(pcf, cam, q)
        keep = pcf.mag[idx] <= 5.0
        xy, idx = xy[keep], idx[keep]
        if len(xy) < 6:
            continue
        c = int(np.argmin(np.hypot(*(xy - cam.K[:2, 2]).T)))
        sel = [c, *[k for k in range(len(xy)) if k != c][:5]]
        got = [g for g in find_matches(pcf, xy[sel], cam, faithful=True, attitude="thesis")
               if g.pattern == int(idx[c])]
        found += bool(got)
        if got:
            g = got[0]
            if g.q_cam_icrs is None:  # a near-collinear Dreibein triple, reported
                flagged_or_close += bool(g.problem)
                continue
            bs = float(rot.to_matrix(g.q_cam_icrs)[2] @ rot.to_matrix(q)[2])
            assert math.degrees(math.acos(min(1.0, bs))) < 0.1  # Dreibein: the boresight
            # CalcAzimut's AZ belongs to the reference star (Bleif 2004 §4.2.6): either close
            # or flagged because it misses a mark
            az = math.remainder(star_angles_from_q_cam_icrs(g.q_cam_icrs)[2]
                                - star_angles_from_q_cam_icrs(q)[2], 2 * math.pi)
            flagged_or_close += abs(math.degrees(az)) < 2.0 or bool(g.problem)
    assert found >= 10 and flagged_or_close == found


def test_solver_method_bleif_identifies_and_never_accepts_noise(cat):
    cam = tubsat_camera()
    solver = starid.Solver(Catalog.hipparcos(mag_limit=6.0), cam, method="bleif")
    q = q_cam_icrs_from_star_angles(*np.radians([97.38, 49.07, 144.57]))  # Fig. 4.7
    _, xy = solver.stars_in_view(q)  # brightest first
    rng = np.random.default_rng(2)
    det = xy[:15] + rng.normal(0, 0.5, (min(15, len(xy)), 2))
    det = np.vstack([det[:2], [[40.0, 500.0]], det[2:]])  # a false star among the brightest
    sol = solver.solve(det)
    assert sol.ok, sol.reason
    assert math.degrees(rot.angle_between(sol.q_cam_icrs, q)) < 0.05
    assert sol.p_false is not None and sol.p_false < 1e-6 and sol.covariance is not None
    assert 2 not in [d for d, _ in sol.matches]  # the false star matched nothing
    for _ in range(1):  # random detections: no attitude, a reason
        noise = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (12, 2))
        bad = solver.solve(noise)
        assert not bad.ok and bad.reason
