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


def test_solver_and_session_give_the_same_candidates_and_the_truth(pc, cam, solver):
    rng = np.random.default_rng(2004)
    agreed = first_true = 0
    for n in (5, 6, 7, 5, 6, 7, 5, 6, 7):
        q, det, order, true_idx = trial(pc, cam, rng, n)
        s = IdentificationSession(pc, cam)
        s.select(det[order])  # the operator marks the reference first
        want = session_answer(s, order)
        sol = solver.solve(det)  # brightest first: the solver picks the reference itself
        got = [dict(c.matches) for c in sol.candidates]
        assert got == want, (n, sol.reason, sol.path)
        agreed += 1
        first = s.matches()[0] if s.count else None
        if (first is not None and first.pattern == int(true_idx[order[0]])
                and math.degrees(rot.angle_between(first.q_cam_icrs, q)) < 2.0):
            first_true += 1
            assert sol.ok, (n, sol.reason)
            assert math.degrees(rot.angle_between(sol.q_cam_icrs, q)) < 0.5
            assert sol.p_false is not None and sol.p_false <= solver.p_false_max
    assert agreed == 9 and first_true >= 8  # bench_bleif: the truth first in ~98.5 %


def test_the_operators_reference_is_the_star_nearest_the_centre(pc, cam):
    from adfusion.starid.bleif.matcher import operator_marks

    rng = np.random.default_rng(7)
    for n in (5, 6, 7):
        _q, det, order, _ = trial(pc, cam, rng, n)
        assert operator_marks(det, cam).tolist() == order
        s = IdentificationSession(pc, cam)
        s.mark_detections(det)  # the session's door for detections: the same marks
        np.testing.assert_array_equal(s.stars, det[order])
