"""One behaviour for Bleif's method: ``Solver(method="bleif")`` and the operator's
:class:`~adfusion.starid.bleif.operator.IdentificationSession` give the same candidates
for the same stars (docs/references.md#bleif-2004).

The trials are made as ``benchmarks/bench_bleif.py`` and ``tests/test_bleif.py`` make
them: a random attitude, the Hipparcos stars ≤ mag 5 in the TUBSAT 16 mm frame, 5–7 of
them marked (the operator's reference — the star nearest the image centre — first, then
the brightest others), clicks off by up to ±3 px. The session gets the marks in the
operator's order; the solver gets the same stars as detections, brightest first, and
must pick the same reference itself.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from adfusion.starid.bleif.matcher import stars_in_frame, tubsat_camera
from adfusion.starid.bleif.operator import IdentificationSession
from adfusion.starid.bleif.patterns import PatternCatalog
from adfusion.starid.catalog.stars import Catalog

from adfusion import starid
from adfusion.maths import rotations as rot


@pytest.fixture(scope="module")
def cat():
    return Catalog.hipparcos(mag_limit=6.5)


@pytest.fixture(scope="module")
def pc(cat):
    return PatternCatalog.build(cat)


@pytest.fixture(scope="module")
def cam():
    return tubsat_camera()


@pytest.fixture(scope="module")
def solver(cat, cam):
    return starid.Solver(cat, cam, method="bleif")


def trial(pc, cam, rng, n, mag_limit=5.0, noise_px=3.0):
    """(truth attitude, detections brightest first, the operator's marking order as
    indices into the detections, true star-list index per detection)."""
    while True:
        q = rot.q_cam_icrs_from_radec_roll(rng.uniform(0, 2 * np.pi),
                                           np.arcsin(rng.uniform(-1, 1)),
                                           rng.uniform(0, 2 * np.pi))
        xy, idx = stars_in_frame(pc, cam, q)  # brightest first
        keep = pc.mag[idx] <= mag_limit
        xy, idx = xy[keep], idx[keep]
        if len(xy) >= n:
            break
    c = int(np.argmin(np.hypot(*(xy - cam.K[:2, 2]).T)))  # the operator's reference
    # the central star and the n − 1 brightest others (bench_bleif), brightest first
    sel = sorted([c, *[k for k in range(len(xy)) if k != c][:n - 1]])
    r = noise_px * np.sqrt(rng.uniform(0, 1, n))
    th = rng.uniform(0, 2 * np.pi, n)
    det = xy[sel] + np.c_[r * np.cos(th), r * np.sin(th)]
    ref = sel.index(c)
    order = [ref, *[k for k in range(n) if k != ref]]
    return q, np.ascontiguousarray(det), order, idx[sel]


def session_answer(s: IdentificationSession, order: list[int]) -> list[dict[int, int]]:
    """The session's candidates as {detection index: catalogue id}, in its order."""
    return [{order[d]: h for d, h in c.matches} for c in s.matches()]


def is_truth(q_est, q, max_err_deg) -> bool:
    return q_est is not None and math.degrees(rot.angle_between(q_est, q)) < max_err_deg


def run_trials(pc, cam, solver, rng, counts, noise_px):
    """Per trial: (session's first candidate is the truth, solution, truth attitude),
    after checking that both doors list the same candidates."""
    out = []
    for n in counts:
        q, det, order, true_idx = trial(pc, cam, rng, n, noise_px=noise_px)
        s = IdentificationSession(pc, cam)
        s.select(det[order])  # the operator marks the reference first
        want = session_answer(s, order)
        sol = solver.solve(det)  # brightest first: the solver picks the reference itself
        got = [dict(c.matches) for c in sol.candidates]
        assert got == want, (n, sol.reason, sol.path)
        assert sol.path == f"bleif ref {order[0]}"  # the operator's reference
        first = s.matches()[0] if s.count else None
        first_true = (first is not None and first.pattern == int(true_idx[order[0]])
                      and is_truth(first.q_cam_icrs, q, 2.0))
        if first is not None:  # the same attitude for the first candidate, too
            assert math.degrees(rot.angle_between(sol.candidates[0].q_cam_icrs,
                                                  first.q_cam_icrs)) < 0.5
        out.append((first_true, sol, q))
    return out


def test_clicks_as_bench_bleif_same_candidates_and_never_a_wrong_attitude(pc, cam, solver):
    """Bench conditions (±3 px clicks): the same candidate list through both doors; the
    solver accepts only the truth (whether 5–7 clicks that coarse are evidence enough
    for p_false ≤ 1e-6 is the solver's verification's call, and mostly they are not)."""
    res = run_trials(pc, cam, solver, np.random.default_rng(2004), (5, 6, 7) * 3, 3.0)
    assert sum(t for t, _, _ in res) >= 8  # bench_bleif: the truth first in ~98.5 %
    for first_true, sol, q in res:
        if sol.ok:
            assert first_true and is_truth(sol.q_cam_icrs, q, 0.5), sol.path
            assert sol.p_false is not None and sol.p_false <= solver.p_false_max
        else:
            assert sol.reason and all(c.p_false > solver.p_false_max
                                      for c in sol.candidates)


def test_detections_same_candidates_and_the_solver_accepts_the_truth(pc, cam, solver):
    """Detector-grade centroids (0.5 px, the solver's default σ), 6–7 stars: whenever the
    session's first candidate is the truth, the solver accepts it."""
    res = run_trials(pc, cam, solver, np.random.default_rng(2005), (6, 7) * 4, 0.5)
    assert sum(t for t, _, _ in res) >= 7
    for first_true, sol, q in res:
        if first_true:
            assert sol.ok, sol.reason
            assert is_truth(sol.q_cam_icrs, q, 0.05)
            assert sol.p_false is not None and sol.p_false <= solver.p_false_max
        else:
            assert not sol.ok or is_truth(sol.q_cam_icrs, q, 0.05)


def test_the_operators_reference_is_the_star_nearest_the_centre(pc, cam):
    from adfusion.starid.bleif.matcher import operator_marks

    rng = np.random.default_rng(7)
    for n in (5, 6, 7):
        _q, det, order, _ = trial(pc, cam, rng, n)
        assert operator_marks(det, cam).tolist() == order
        s = IdentificationSession(pc, cam)
        s.mark_detections(det)  # the session's door for detections: the same marks
        np.testing.assert_array_equal(s.stars, det[order])
