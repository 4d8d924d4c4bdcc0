"""Bleif's MusterPr matcher against docs/references.md#bleif-2004 (catalogue, matching,
attitude, overlay) and the synthetic lost-in-space acceptance test of issue 18.

Truth is independent of the matcher: attitudes are drawn at random, the Hipparcos stars
are projected with the camera model, clicks get ±3 px noise (uniform in a disc), and
each candidate is judged by its reference star and its attitude error against the draw.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from adfusion.starid.bleif.matcher import (
    KX_DEG,
    T_PIX,
    CollinearTripleError,
    MatchCounters,
    distance_tolerance_deg,
    dreibein,
    find_matches,
    overlay,
    sigma_phi_numeric_rad,
    sigma_phi_rad,
    stars_in_frame,
    tubsat_camera,
)
from adfusion.starid.bleif.patterns import PatternCatalog, direction_angle_deg
from adfusion.starid.bleif.star_angles import star_angles_from_q_cam_icrs
from adfusion.starid.catalog.stars import Catalog

from adfusion.maths import rotations as rot


@pytest.fixture(scope="module")
def hip():
    return Catalog.hipparcos(mag_limit=6.5)


@pytest.fixture(scope="module")
def pc(hip):
    return PatternCatalog.build(hip)


@pytest.fixture(scope="module")
def cam():
    return tubsat_camera()


def random_attitude(rng, max_dec_deg=90.0):
    s = math.sin(math.radians(max_dec_deg))
    return rot.q_cam_icrs_from_radec_roll(rng.uniform(0, 2 * np.pi),
                                          np.arcsin(rng.uniform(-s, s)),
                                          rng.uniform(0, 2 * np.pi))


def marked_stars(pc, cam, rng, n, mag_limit=5.0, noise_px=3.0, q=None):
    """A random attitude and ``n`` marked stars (≤ mag_limit): the reference is the star
    nearest the centre (an operator's choice), then the brightest others; clicks off by
    up to ``noise_px`` (uniform in a disc). Returns (q, clicks, true star-list indices)."""
    fixed = q is not None
    while True:
        if not fixed:
            q = random_attitude(rng)
        xy, idx = stars_in_frame(pc, cam, q)
        keep = pc.mag[idx] <= mag_limit
        xy, idx = xy[keep], idx[keep]
        if len(xy) >= n:
            break
        if fixed:
            raise AssertionError("too few stars at the given attitude")
    c = int(np.argmin(np.hypot(*(xy - cam.K[:2, 2]).T)))
    sel = [c, *[k for k in range(len(xy)) if k != c][:n - 1]]
    r = noise_px * np.sqrt(rng.uniform(0, 1, n))
    th = rng.uniform(0, 2 * np.pi, n)
    return q, xy[sel] + np.c_[r * np.cos(th), r * np.sin(th)], idx[sel]


def is_truth(cand, q, true_idx, max_err_deg=2.0):
    return (cand.pattern == int(true_idx[0]) and cand.q_cam_icrs is not None
            and math.degrees(rot.angle_between(cand.q_cam_icrs, q)) < max_err_deg)


# --- catalogue (criteria 7–9) ----------------------------------------------------------


def test_catalogue_has_one_pattern_per_star_within_radius_sorted_and_capped(pc, hip):
    assert len(pc) == 5000
    assert pc.mag.max() <= np.sort(hip.mag)[4999]  # the 5000 brightest
    for p in range(0, 5000, 7):
        m = pc.members_of(p)
        d = pc.dist_rad[p, : pc.size[p]]
        assert len(m) <= 150 and p not in m
        assert np.all((d > 0) & (d < math.radians(20.0)))
        assert np.all(np.diff(d) >= 0)
        az = pc.az_rad[p, : pc.size[p]]
        assert np.all((az >= 0) & (az < 2 * np.pi))
        # independent distances from the vectors
        np.testing.assert_allclose(np.arccos(np.clip(pc.vectors[m] @ pc.vectors[p], -1, 1)),
                                   d, atol=1e-12)
    # uncapped patterns hold every star of the list within 20°
    p = int(np.flatnonzero(pc.size < 150)[0])
    within = np.flatnonzero((pc.vectors @ pc.vectors[p] > math.cos(math.radians(20.0)))
                            & (np.arange(5000) != p))
    assert set(within.tolist()) == set(pc.members_of(p).tolist())
    assert (pc.size == 150).any()  # the cap truncates dense regions (Bleif 2004 §4.2.4)


def test_direction_angle_north_south_east_and_the_wrap():
    assert direction_angle_deg(0, 0, 0, 5) == pytest.approx(0.0, abs=1e-9)
    assert direction_angle_deg(0, 0, 0, -5) == pytest.approx(180.0, abs=1e-9)
    assert direction_angle_deg(0, 0, 5, 0) == pytest.approx(270.0, abs=1e-9)
    assert direction_angle_deg(0, 0, 355, 0) == pytest.approx(90.0, abs=1e-9)
    # the literal Eq. 4.9/4.10 gets the wrap wrong; the flag reproduces it
    assert direction_angle_deg(0, 0, 355, 0, faithful=True) == pytest.approx(270.0, abs=1e-9)
    # away from the wrap both agree
    assert direction_angle_deg(40, 20, 35, 25, faithful=True) == pytest.approx(
        direction_angle_deg(40, 20, 35, 25), abs=1e-9)


def test_catalogue_round_trips_bit_exactly_and_the_cache_returns_the_build(pc, hip,
                                                                             tmp_path):
    path = tmp_path / "patterns.npz"
    pc.save(path)
    back = PatternCatalog.load(path)
    for f in dataclasses.fields(PatternCatalog):
        a, b = getattr(pc, f.name), getattr(back, f.name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), f.name
        else:
            assert a == b, f.name
    fresh = PatternCatalog.build(hip, cache=False)
    assert fresh.az_rad.tobytes() == pc.az_rad.tobytes()
    assert fresh.member.tobytes() == pc.member.tobytes()


# --- tolerances (criterion 10) ---------------------------------------------------------


def test_distance_tolerance_is_the_thesis_0_1752_deg():
    assert distance_tolerance_deg(KX_DEG, T_PIX) == pytest.approx(0.1752, abs=1e-12)


def test_sigma_phi_closed_form_matches_thesis_and_numeric_gauss_propagation():
    tri1 = ((0, 0), (100, 0), (0, 100))
    tri2 = ((0, 0), (50, 0), (0, 200))
    assert sigma_phi_rad(*tri1, sigma_p=1.0) == pytest.approx(0.0200, abs=5e-7)
    assert math.degrees(sigma_phi_rad(*tri1, sigma_p=3.0)) == pytest.approx(3.438, abs=1e-3)
    assert sigma_phi_rad(*tri2, sigma_p=1.0) == pytest.approx(0.029155, abs=5e-7)
    rng = np.random.default_rng(0)
    for _ in range(50):
        p = rng.uniform(-300, 300, (3, 2))
        if min(np.hypot(*(p[1] - p[0])), np.hypot(*(p[2] - p[0]))) < 5:
            continue
        assert sigma_phi_rad(*p, sigma_p=3.0) == pytest.approx(
            sigma_phi_numeric_rad(*p, sigma_p=3.0), abs=1e-6)


# --- matching (criteria 11–14) ---------------------------------------------------------


def test_synthetic_lost_in_space_truth_among_candidates(pc, cam):
    """Issue 18: 5–10 marked stars, ±3 px clicks: the truth in ≥ 99 % of trials (the
    full-size run with the count distribution is benchmarks/bench_bleif.py)."""
    rng = np.random.default_rng(18)
    found, unique, trials = 0, 0, 0
    for n in (5, 6, 7, 8, 9, 10):
        for _ in range(10):
            q, clicks, true_idx = marked_stars(pc, cam, rng, n)
            cands = list(find_matches(pc, clicks, cam))
            trials += 1
            found += any(is_truth(c, q, true_idx) for c in cands)
            unique += len(cands) == 1
    assert found / trials >= 0.99, f"truth found in {found}/{trials}"
    # "with ≥ 5 stars the first hit is usually the right one": measured, not just hoped
    assert unique / trials >= 0.8, f"unique in {unique}/{trials}"


def test_four_stars_give_several_candidates_including_the_truth(pc, cam):
    rng = np.random.default_rng(4)
    counts, found = [], 0
    for _ in range(15):
        q, clicks, true_idx = marked_stars(pc, cam, rng, 4)
        cands = list(find_matches(pc, clicks, cam))
        counts.append(len(cands))
        found += any(is_truth(c, q, true_idx) for c in cands)
    assert found == 15
    assert np.median(counts) > 1  # thesis example: 6 candidates, the 3rd correct


def test_strict_mode_fails_with_a_false_star_tolerant_mode_finds_the_truth(pc, cam):
    rng = np.random.default_rng(12)
    for _ in range(3):
        q, clicks, true_idx = marked_stars(pc, cam, rng, 6, noise_px=1.0)
        xy_all, _ = stars_in_frame(pc, cam, q)
        while True:  # a hot-pixel block, far from every catalogue star
            fake = rng.uniform([20, 20], [cam.width - 20, cam.height - 20])
            if np.hypot(*(xy_all - fake).T).min() > 30:
                break
        with_false = np.vstack([clicks, fake])
        strict = list(find_matches(pc, with_false, cam))
        assert not any(is_truth(c, q, true_idx) for c in strict)
        assert all(c.n_missing == 0 for c in strict)
        tolerant = list(find_matches(pc, with_false, cam, k_miss=1))
        hits = [c for c in tolerant if is_truth(c, q, true_idx, 0.5)]
        assert hits and hits[0].assignment[-1] == (6, None)  # the fake left out


def _single_pattern(pc, p):
    """The catalogue cut down to pattern ``p`` (members still index the full star list)."""
    s = slice(p, p + 1)
    return dataclasses.replace(pc, member=pc.member[s], dist_rad=pc.dist_rad[s],
                               az_rad=pc.az_rad[s], size=pc.size[s])


def test_early_exit_at_the_first_star_without_a_distance_partner(pc, cam):
    rng = np.random.default_rng(13)
    _q, clicks, true_idx = marked_stars(pc, cam, rng, 6, noise_px=0.0)
    one = _single_pattern(pc, int(true_idx[0]))
    c = MatchCounters()
    assert len(list(find_matches(one, clicks, cam, counters=c))) == 1
    assert (c.patterns, c.distance_checks, c.pair_checks) == (1, 5, 10)
    # move the nearest star to a distance no member has: rejected after one star
    d = np.hypot(*(clicks[1:] - clicks[0]).T)
    nearest = 1 + int(np.argmin(d))
    bad = clicks.copy()
    direction = (bad[nearest] - bad[0]) / d[nearest - 1]
    member_d = np.degrees(one.dist_rad[0, : one.size[0]])
    for r_px in np.arange(2.0, d.min(), 0.5):  # closer than all, off every member distance
        if np.abs(member_d - r_px * KX_DEG).min() > 0.3:
            break
    else:
        pytest.skip("no free distance for this draw")
    bad[nearest] = bad[0] + direction * r_px
    c = MatchCounters()
    assert list(find_matches(one, bad, cam, counters=c)) == []
    assert (c.rejected_distance, c.distance_checks, c.pair_checks) == (1, 1, 0)


def test_early_exit_at_the_first_pair_without_an_angle_partner(pc, cam):
    rng = np.random.default_rng(14)
    _q, clicks, true_idx = marked_stars(pc, cam, rng, 6, noise_px=0.0)
    one = _single_pattern(pc, int(true_idx[0]))
    # mirror the image about the reference's column: distances kept, angles reversed
    mirrored = clicks.copy()
    mirrored[:, 0] = 2 * clicks[0, 0] - clicks[:, 0]
    c = MatchCounters()
    assert list(find_matches(one, mirrored, cam, counters=c)) == []
    assert c.rejected_distance == 0 and c.rejected_angle == 1
    assert c.pair_checks == 1  # the first pair already has no partner


def test_candidates_lazy_in_catalogue_order_and_complete_with_count(pc, cam):
    rng = np.random.default_rng(15)
    _q, clicks, _true_idx = marked_stars(pc, cam, rng, 4)
    c = MatchCounters()
    it = find_matches(pc, clicks, cam, counters=c)
    first = next(it)
    assert c.patterns < len(pc)  # nothing beyond the first candidate's chunk yet
    rest = list(it)
    every = [first, *rest]
    assert [x.pattern for x in every] == sorted(x.pattern for x in every)
    assert [x.pattern for x in every] == [x.pattern for x in find_matches(pc, clicks, cam)]
    for x in every:
        assert x.assignment[0] == (0, int(pc.ids[x.pattern]))
        assert len(x.residuals_rad) == 4 and x.ra_de_az_deg is not None
        assert x.covariance.shape == (3, 3)
        ov = overlay(x, pc, cam)
        assert ov.is_reference.sum() == 1


# --- attitude (criteria 15–17) ---------------------------------------------------------


def test_dreibein_noise_free_and_the_near_collinear_triple(pc):
    rng = np.random.default_rng(16)
    errs = []
    for _ in range(200):
        b = rot.radec_to_vector(rng.uniform(0, 2 * np.pi), rng.uniform(-1.2, 1.2))
        u = b + rng.normal(0, 0.08, (3, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        psi = np.arccos(np.clip(u @ b, -1, 1))
        try:
            v = dreibein(u, psi)
        except CollinearTripleError:
            continue
        errs.append(math.degrees(math.acos(min(1.0, float(v @ b)))))
    assert len(errs) > 150 and max(errs) < 0.2
    # three stars on one great circle (plus 0.01° off it): refused, not solved
    t = np.radians([0.0, 4.0, 9.0])
    u = np.stack([np.cos(t), np.sin(t), np.radians([0.0, 0.01, 0.0])], -1)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    b = rot.radec_to_vector(math.radians(3.0), math.radians(5.0))
    with pytest.raises(CollinearTripleError, match="near-collinear"):
        dreibein(u, np.arccos(u @ b))


def test_thesis_attitude_near_the_centre_and_the_modern_attitude_anywhere(pc, cam):
    rng = np.random.default_rng(17)
    thesis_err, modern_az, modern_bs = [], [], []
    while len(thesis_err) < 15:
        q = random_attitude(rng, 30.0)
        q, clicks, true_idx = marked_stars(pc, cam, rng, 5, noise_px=0.0, q=q)
        if np.hypot(*(clicks[0] - cam.K[:2, 2])) > 50:
            continue
        cands = [c for c in find_matches(pc, clicks, cam, attitude="thesis")
                 if c.pattern == int(true_idx[0])]
        if not cands or cands[0].q_cam_icrs is None:
            continue  # a near-collinear triple: reported, tested above
        _, _, az_true = star_angles_from_q_cam_icrs(q)
        _, _, az = star_angles_from_q_cam_icrs(cands[0].q_cam_icrs)
        thesis_err.append(abs(math.degrees(math.remainder(az - az_true, 2 * math.pi))))
    assert max(thesis_err) < 0.5
    for _ in range(15):
        q = random_attitude(rng, 85.0)
        q, clicks, true_idx = marked_stars(pc, cam, rng, 5, noise_px=0.0, q=q)
        c = next(c for c in find_matches(pc, clicks, cam) if c.pattern == int(true_idx[0]))
        _, _, az_true = star_angles_from_q_cam_icrs(q)
        _, _, az = star_angles_from_q_cam_icrs(c.q_cam_icrs)
        modern_az.append(abs(math.degrees(math.remainder(az - az_true, 2 * math.pi))))
        bs = rot.to_matrix(c.q_cam_icrs)[2] @ rot.to_matrix(q)[2]
        modern_bs.append(math.degrees(math.acos(min(1.0, float(bs)))))
    assert max(modern_az) < 0.2 and max(modern_bs) < 0.05


def test_noisy_modern_attitude_comes_with_a_covariance_that_covers_its_error(pc, cam):
    rng = np.random.default_rng(19)
    nis = []
    for _ in range(40):
        q, clicks, true_idx = marked_stars(pc, cam, rng, 5)
        c = next((c for c in find_matches(pc, clicks, cam) if is_truth(c, q, true_idx)),
                 None)
        assert c is not None
        e = rot.log_map(rot.multiply(q, rot.inverse(c.q_cam_icrs)))  # camera frame
        nis.append(float(e @ np.linalg.solve(c.covariance, e)))
    # χ²(3): mean 3; a covariance off by 2× in σ would put the mean near 0.75 or 12
    assert 1.0 < np.mean(nis) < 6.0
    assert np.mean(np.array(nis) < 11.34) >= 0.9  # 99 % point of χ²(3)


# --- overlay (criterion 18) ------------------------------------------------------------


def test_overlay_projects_the_pattern_onto_the_clicks_and_classifies_blocks(pc, cam):
    rng = np.random.default_rng(20)
    q, clicks, true_idx = marked_stars(pc, cam, rng, 5, noise_px=0.0)
    c = next(c for c in find_matches(pc, clicks, cam) if c.pattern == int(true_idx[0]))
    xy_all, idx_all = stars_in_frame(pc, cam, q)
    fake = np.array([[5.0, 5.0]])  # a block far from every star (corner)
    assert np.hypot(*(xy_all - fake).T).min() > 10
    blocks = np.vstack([clicks, xy_all[5:8], fake])
    ov = overlay(c, pc, cam, blocks)
    pos = {int(i): k for k, i in enumerate(ov.ids.tolist())}
    for k, s in enumerate(true_idx.tolist()):
        j = pos[int(pc.ids[s])]
        assert np.hypot(*(ov.xy[j] - clicks[k])) < T_PIX
        assert ov.is_reference[j] == (k == 0) and ov.is_marked[j] == (k > 0)
        assert ov.occupied[j]
    members_in_frame = set(idx_all.tolist()) & set(pc.members_of(c.pattern).tolist())
    assert len(ov.xy) == len(members_in_frame) + 1
    assert (~ov.occupied).any()  # expected stars without a block
    order = np.argsort(ov.mag)
    assert np.all(np.diff(ov.radius_px[order]) <= 0)  # brighter → never smaller
    assert ov.false_blocks.tolist() == [len(blocks) - 1]
