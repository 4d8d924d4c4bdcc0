"""One night pass as in Bleif's 27.02.2003 example (Bleif 2004 §6.2), end to end.

The thesis: docs/references.md#bleif-2004.

Before contact the best time over the target is computed; at first contact the satellite
is held inertially and takes a star image (:func:`adfusion.sensors.tubsat.star_blocks`);
stars are marked (suggested from the blocks, the thesis's 4), the candidates are stepped
through with their overlays until one fits (a simulated operator: the expected positions
of the stars the camera can see are occupied by blocks), the fix is locked into an
estimator with the drift model; after the attitude-determination time the slews to the
target at the best time are computed from the *estimate*, sent and read back one by one
(:class:`~adfusion.pointing.commands.CommandBook`), and at the best time the true
boresight is compared with the target direction.

The satellite drifts with a gyro bias drawn from the drift model (the held satellite
turns at −bias while its gyro reads zero), so the pointing error at the target is the
drift since the fix plus the fix's own error — the budget the estimator predicts.

Example:
    >>> res = run_night_pass(NightPassConfig(drift_truth=DriftModel.none()))
    >>> res.ok, res.n_candidates >= 1, res.pointing_error_deg < 0.5
    (True, True, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import numpy as np
from numpy.typing import NDArray

from adfusion.logs import topics
from adfusion.maths import rotations as rot
from adfusion.pointing.commands import CommandBook
from adfusion.pointing.drift import (
    DriftModel,
    boresight_sigma_deg,
    drift_estimator,
    time_left_s,
)
from adfusion.pointing.passplan import Orbit, best_time, earth_target_direction, plan_slews
from adfusion.sensors.tubsat import SimulatedACS, star_blocks
from adfusion.starid.bleif.matcher import BleifCandidate, Overlay, tubsat_camera
from adfusion.starid.bleif.operator import IdentificationSession
from adfusion.starid.bleif.patterns import PatternCatalog
from adfusion.starid.bleif.star_angles import (
    q_cam_icrs_from_star_angles,
    star_angles_from_q_cam_icrs,
)
from adfusion.starid.catalog.stars import Catalog

__all__ = ["NightPassConfig", "NightPassResult", "example_orbit", "operator_accepts",
           "run_night_pass"]


def example_orbit() -> Orbit:
    """A DLR-TUBSAT-like orbit (720 km, 98.4°) whose pass over Berlin peaks near the
    thesis's 23:13 UTC at ≈ 79° on 27.02.2003 — mean elements chosen for that, *not* the
    historical TLE (which is not available here)."""
    return Orbit.from_elements(datetime(2003, 2, 27, 22, 0, tzinfo=UTC), 720.0, 98.4,
                               326.0, 220.75)


@dataclass(frozen=True)
class NightPassConfig:
    """The pass: start (first contact, star image), target, true start attitude (the
    thesis's fix RA 164.16, DE 43.53, AZ 283.64), marked-star count, drift of the truth
    and of the estimator's model, the attitude-determination time (≈ 2.5 min), the slew
    order and rate, and the pointing budget (3.5°, half the 50 mm image)."""

    t0: datetime = datetime(2003, 2, 27, 23, 6, 20, tzinfo=UTC)  # timer 06:50 to 23:13:11
    orbit: Orbit | None = None
    lon_deg: float = 13.3
    lat_deg: float = 52.5
    star_angles_deg: tuple[float, float, float] = (164.16, 43.53, 283.64)
    n_marked: int = 4
    drift_truth: DriftModel = field(default_factory=DriftModel)
    drift_model: DriftModel = field(default_factory=DriftModel)
    determination_s: float = 150.0
    order: str = "ZX"
    slew_rate_deg_s: float = 2.5
    budget_deg: float = 3.5
    mag_limit: float = 5.0
    seed: int = 0


@dataclass
class NightPassResult:
    ok: bool
    reason: str = ""
    ref_time: datetime | None = None
    max_elevation_deg: float = math.nan
    marked_xy: NDArray[np.float64] | None = None
    n_candidates: int = 0  # candidates shown before one was accepted (incl. it)
    accepted: BleifCandidate | None = None
    accepted_is_truth: bool = False
    slews_deg: list[tuple[str, float]] = field(default_factory=list)
    time_left_at_fix_s: float = math.nan
    pointing_error_deg: float = math.nan  # true boresight vs target at ref_time
    predicted_sigma_deg: float = math.nan  # the estimator's boresight 1-σ at ref_time
    events: list[tuple[float, str, dict[str, Any]]] = field(default_factory=list)


def operator_accepts(ov: Overlay, mag_limit: float = 5.0, min_fraction: float = 0.7,
                     min_stars: int = 4) -> bool:
    """The operator's check (§5.6): most expected positions of stars the camera can see
    (≤ ``mag_limit``) are occupied by blocks."""
    seen = ov.mag <= mag_limit
    n = int(seen.sum())
    return n >= min_stars and float(np.mean(ov.occupied[seen])) >= min_fraction


class _Couple:
    """The CommandBook's model: sending a slew commands the simulated satellite."""

    def __init__(self, acs: SimulatedACS, clock: list[float]) -> None:
        self.acs, self.clock = acs, clock

    def apply_slew(self, axis: str, angle_rad: float) -> None:
        self.acs.command(axis, angle_rad, self.clock[0])


def run_night_pass(config: NightPassConfig = NightPassConfig(),
                   catalog: Catalog | None = None,
                   patterns: PatternCatalog | None = None) -> NightPassResult:
    """Simulate one pass (see the module docstring); times in the events are seconds
    from ``config.t0``."""
    cat = catalog if catalog is not None else Catalog.hipparcos(mag_limit=6.5)
    pc = patterns if patterns is not None else PatternCatalog.build(cat)
    cam = tubsat_camera()
    orbit = config.orbit or example_orbit()
    res = NightPassResult(ok=False)
    ev = res.events
    ref_time, el = best_time(orbit, config.t0, config.lon_deg, config.lat_deg)
    res.ref_time, res.max_elevation_deg = ref_time, el
    t_ref = (ref_time - config.t0).total_seconds()
    ev.append((0.0, topics.TUBSAT_PLAN, {"ref_time": ref_time.isoformat(), "max_elevation_deg": el,
                                     "target_lon_lat_deg": [config.lon_deg, config.lat_deg]}))

    rng = np.random.default_rng(config.seed)
    bias_cam = rng.normal(size=3) * config.drift_truth.sigma_bias_cam_rad_s()
    q0 = q_cam_icrs_from_star_angles(*np.radians(config.star_angles_deg))
    acs = SimulatedACS(q0, bias_cam_rad_s=bias_cam,
                       slew_rate_rad_s=math.radians(config.slew_rate_deg_s))
    blocks = star_blocks(cat, cam, q0, seed=config.seed, mag_limit=config.mag_limit)
    ev.append((0.0, topics.TUBSAT_BLOCKS, {"xy": blocks.xy, "star_id": blocks.star_id}))

    session = IdentificationSession(pc, cam, blocks.xy)
    marked = session.suggest(n=config.n_marked)
    res.marked_xy = marked
    ev.append((0.0, topics.TUBSAT_MARKED, {"xy": marked}))
    if len(marked) < 3:
        res.reason = f"only {len(marked)} multi-block stars in the image"
        return res
    shown = 0
    cand = session.next_candidate()
    while cand is not None:
        shown += 1
        ov = session.overlay(cand)
        ok = cand.q_cam_icrs is not None and operator_accepts(ov, config.mag_limit)
        ev.append((0.0, topics.TUBSAT_CANDIDATE, {
            "index": shown, "ref_id": cand.ref_id, "ra_de_az_deg": cand.ra_de_az_deg,
            "occupied": int(ov.occupied[ov.mag <= config.mag_limit].sum()),
            "expected": int((ov.mag <= config.mag_limit).sum()),
            "decision": "accept" if ok else "reject"}))
        if ok:
            session.accept(cand)
            break
        cand = session.reject()
    res.n_candidates = shown
    if session.accepted is None:
        res.reason = f"no candidate accepted ({shown} shown)"
        return res
    acc = session.accepted
    res.accepted = acc
    ids = blocks.star_id
    ref_block = int(np.argmin(np.hypot(*(blocks.xy - marked[0]).T)))
    res.accepted_is_truth = acc.ref_id == int(ids[ref_block])

    est = drift_estimator(config.drift_model)
    session.lock(est, 0.0)
    res.time_left_at_fix_s = time_left_s(est.filter, config.budget_deg)
    ev.append((0.0, topics.TUBSAT_LOCK, {"q_cam_icrs": est.filter.q_body_icrs,
                                     "time_left_s": res.time_left_at_fix_s}))
    clock = [0.0]

    def run_to(t_end: float) -> None:
        ticks = sorted({*np.arange(math.floor(clock[0]) + 1.0, t_end, 1.0).tolist(),
                        *acs.breakpoints(clock[0], t_end), t_end})
        for tk in ticks:
            acs.advance(tk)
            g = acs.gyro(tk)
            est.step(tk, gyro=g)
            ev.append((tk, topics.TRUTH_STATE, {
                "t": tk, "q_body_icrs": acs.q_cam_icrs,  # the body frame is the camera's
                "omega": g - acs.bias_cam_rad_s, "bias": acs.bias_cam_rad_s}))
            ev.append((tk, topics.GYRO, {"omega": g}))
        clock[0] = t_end

    run_to(config.determination_s)
    p = earth_target_direction(orbit, ref_time, config.lon_deg, config.lat_deg)
    plan = plan_slews(est.filter.q_body_icrs, p, order=config.order)
    res.slews_deg = [(a, math.degrees(x)) for a, x in plan.slews]
    book = CommandBook(_Couple(acs, clock))
    for axis, angle in plan.slews:
        i = book.add(axis, angle)
        book.send(i, clock[0])
        run_to(acs.busy_until() + 5.0)  # wait, then poll the telemetry
        book.query(i, acs.executed_rad(axis), clock[0])
        if not book.complete(i):
            res.reason = f"slew {i} ({axis}) not executed"
            return res
    ev += [(e.t, topics.TUBSAT_COMMAND, {"kind": e.kind, "index": e.index, "axis": e.axis,
                                     "angle_deg": math.degrees(e.angle_rad)})
           for e in book.log]
    if clock[0] > t_ref:
        res.reason = f"slews ended {clock[0] - t_ref:.0f} s after the best time"
        return res
    run_to(t_ref)
    b_true = rot.to_matrix(acs.q_cam_icrs)[2]
    u = p / np.linalg.norm(p)
    res.pointing_error_deg = math.degrees(math.acos(max(-1.0, min(1.0, float(b_true @ u)))))
    res.predicted_sigma_deg = boresight_sigma_deg(est.filter)
    ra, de, az = (math.degrees(a) for a in star_angles_from_q_cam_icrs(acs.q_cam_icrs))
    ev.append((t_ref, topics.TUBSAT_POINTING, {
        "error_deg": res.pointing_error_deg, "sigma_deg": res.predicted_sigma_deg,
        "budget_deg": config.budget_deg, "true_ra_de_az_deg": [ra, de, az]}))
    res.ok = True
    return res
