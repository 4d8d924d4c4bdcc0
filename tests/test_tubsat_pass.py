"""One operator pass end to end (issue 18): four marked stars → candidates stepped
through → the right one accepted → locked into the estimator → slews to Berlin at the
best time → the simulated boresight within the drift budget of the target; and the
``adfusion simulate tubsat`` log.

The truth is the simulated satellite (its attitude, drifting with a gyro bias its gyro
cannot see), independent of the estimate the slews are computed from."""

from __future__ import annotations

import math

import numpy as np
import pytest
from adfusion.logs import McapLogReader
from adfusion.starid.bleif.matcher import tubsat_camera
from adfusion.starid.bleif.operator import IdentificationSession
from adfusion.starid.bleif.patterns import PatternCatalog
from adfusion.starid.catalog.stars import Catalog

from adfusion.maths import rotations as rot
from adfusion.pointing.drift import DriftModel
from adfusion.pointing.night_pass import (
    NightPassConfig,
    example_orbit,
    operator_accepts,
    run_night_pass,
)
from adfusion.pointing.passplan import earth_target_direction, elevation_deg


@pytest.fixture(scope="module")
def cat():
    return Catalog.hipparcos(mag_limit=6.5)


@pytest.fixture(scope="module")
def pc(cat):
    return PatternCatalog.build(cat)


def test_operator_pass_four_stars_to_berlin_within_the_drift_budget(cat, pc):
    cfg = NightPassConfig(seed=0)
    res = run_night_pass(cfg, cat, pc)
    assert res.ok, res.reason
    assert len(res.marked_xy) == 4
    # the operator stepped through the candidates in catalogue order and took the truth
    assert res.accepted_is_truth
    session = IdentificationSession(pc, tubsat_camera(),
                                    next(e for e in res.events if e[1] == "/tubsat/blocks")[2]
                                    ["xy"])
    session.select(res.marked_xy)
    every = session.matches()
    assert session.count >= res.n_candidates >= 1
    assert every[res.n_candidates - 1].pattern == res.accepted.pattern
    assert all(not operator_accepts(session.overlay(c)) for c in every[: res.n_candidates - 1])
    # the accepted fix's star angles are the satellite's (thesis: 164.16, 43.53, 283.64)
    ra, de, az = res.accepted.ra_de_az_deg
    assert (ra, de) == pytest.approx(cfg.star_angles_deg[:2], abs=0.1)
    assert az == pytest.approx(cfg.star_angles_deg[2], abs=0.5)
    # the best time is an elevation maximum of the pass over Berlin
    assert res.max_elevation_deg > 60
    # at the best time the true boresight points at Berlin within the budgets
    assert res.pointing_error_deg < cfg.budget_deg
    assert res.pointing_error_deg < 3 * math.sqrt(2) * res.predicted_sigma_deg
    # the budget left at the fix is the drift model's (X_S: 0.51 °/min)
    assert res.time_left_at_fix_s / 60 == pytest.approx(3.5 / 0.51, abs=0.2)


def test_without_drift_the_pass_ends_on_the_target(cat, pc):
    res = run_night_pass(NightPassConfig(drift_truth=DriftModel.none(), seed=1), cat, pc)
    assert res.ok, res.reason
    assert res.pointing_error_deg < 0.3  # the star fix's own error only
    # independent check of the geometry: the true line of sight at the best time
    truth = [e for e in res.events if e[1] == "/truth/state"][-1][2]["q_body_icrs"]
    orb = example_orbit()  # the config's default orbit
    p = earth_target_direction(orb, res.ref_time, 13.3, 52.5)
    b = rot.to_matrix(truth)[2]
    assert math.degrees(math.acos(float(b @ p / np.linalg.norm(p)))) < 0.3
    r_sat = orb.position_km(res.ref_time)
    assert float(elevation_deg(r_sat, r_sat + p)) == pytest.approx(res.max_elevation_deg,
                                                                   abs=1e-6)


def test_predicted_drift_budget_matches_the_simulated_drift(cat, pc):
    """Over many passes (bias drawn from Tab. 8.1) the true boresight errors at the target
    are distributed as the estimator's covariance says."""
    ratios = []
    for seed in range(30):
        res = run_night_pass(NightPassConfig(seed=seed), cat, pc)
        assert res.ok, res.reason
        ratios.append(res.pointing_error_deg / res.predicted_sigma_deg)
    r = np.array(ratios)
    # the larger cross-axis σ bounds both: E[r²] ≤ 2, and ≥ 1 if both axes are similar
    assert 0.5 < np.mean(r**2) < 2.5
    assert np.mean(r < 3.0) >= 0.9


def test_simulate_tubsat_writes_the_pass_to_mcap(tmp_path):
    from adfusion.app.tubsat_log import simulate_tubsat

    path = tmp_path / "pass.mcap"
    res = simulate_tubsat(path, seed=0)
    reader = McapLogReader(path)
    msgs = list(reader.messages())
    topics = {m.topic for m in msgs}
    assert {"/tubsat/plan", "/tubsat/blocks", "/tubsat/marked", "/tubsat/candidate",
            "/tubsat/lock", "/tubsat/command", "/imu/gyro", "/truth/state", "/truth/pose",
            "/tubsat/pointing"} <= topics
    commands = [m for m in msgs if m.topic == "/tubsat/command"]
    assert [c.payload["kind"] for c in commands] == ["send", "query"] * 3
    from adfusion.logs.schemas import JSON_SCHEMAS
    from jsonschema import validate

    for m in msgs:  # the shared topics follow the log's schemas
        if m.topic in JSON_SCHEMAS:
            validate(m.payload, JSON_SCHEMAS[m.topic][1])
    final = next(m for m in msgs if m.topic == "/tubsat/pointing")
    assert final.payload["error_deg"] == pytest.approx(res.pointing_error_deg)
    assert reader.metadata["config"]["t0"].startswith("2003-02-27T23:06:20")


def test_operator_rejects_two_candidates_and_accepts_the_third(cat, pc):
    """As in the thesis's example pass ("6 candidates, the 3rd correct"): at this attitude
    the first two candidates' overlays leave expected stars without blocks; the third is
    the truth."""
    res = run_night_pass(NightPassConfig(star_angles_deg=(330.18, 14.98, 185.08), seed=0),
                         cat, pc)
    assert res.ok, res.reason
    decisions = [e[2]["decision"] for e in res.events if e[1] == "/tubsat/candidate"]
    assert decisions == ["reject", "reject", "accept"]
    assert res.accepted_is_truth
    assert res.pointing_error_deg < res.predicted_sigma_deg * 3 * math.sqrt(2)
