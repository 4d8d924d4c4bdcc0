"""Benchmark adfusion in Basilisk's closed loop: figures over seeds, and the cost per step.

For each seed, the scenario (default ``leo``: 10 minutes, camera 4 Hz, gyro 10 Hz) runs with
the loop closed on adfusion's camera estimator, on Basilisk's truth, on its ``inertialUKF``
and on adfusion fed by Basilisk's star tracker (``adfusion_st``). Per seed: pointing
RMS per loop (from ``settle_s``), estimation RMS and mean NEES per estimator (adfusion on the
camera, adfusion and ``inertialUKF`` on the same star-tracker and gyro messages), camera
identification.

Over seeds (Bar-Shalom's ensemble test): at every recorder time after ``settle_s`` the NEES
of the 3-dof attitude error averaged over the M seeds, whose 95 % band is
χ²(3M)/M at 2.5 % and 97.5 %; the time mean of that ensemble NEES and the fraction of times
inside the band.

Cost per step (seed ``--cost-seed``; CPU time of the calling thread, ``time.thread_time``,
for every figure: on the shared machine wall time mostly measures the wait for a core): the
adfusion module's ``UpdateState`` as timed inside the run (gyro-only calls, calls with a
camera frame — detection, identification, filter), the frame's detection alone (the whole
frame, and the tracking windows), and — in the same process on the run's live messages — the
``UpdateState`` of Basilisk's own modules (``inertialUKF``, ``mrpFeedback``,
``attTrackingError``, ``imuSensor``, ``starTracker``, ``simpleNav``, ``rwMotorTorque``) called
from Python in a loop (their messages stale: ``inertialUKF`` takes its gyro-propagation branch),
and the adfusion module's gyro-only and tracked-frame calls in loops the same way. Each loop
runs :data:`ROUNDS` rounds; the round with the lowest median is reported, with every round's
median.

Usage (from the repository root; one process, 10 seeds of leo in ~6 min on a 2-core VM)::

    python benchmarks/bench_acs.py [--scenario leo] [--seeds 10] [--duration 600]
                                   [--out benchmarks/results/bench_acs.json]

Example:
    >>> r = run("leo", seeds=2, duration_s=4.0, settle_s=1.0, cost_seed=None, verbose=False)
    >>> len(r["per_seed"]), r["per_seed"][0]["camera"]["wrong"]
    (2, 0)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from adfusion.starid import Prior
from adfusion.starid.detection.detect import detect

from adfusion.basilisk.acs import attitude_errors_rad, nees, sky_and_solver, summarize
from adfusion.basilisk.scenarios import run_loop, scenario
from adfusion.maths import rotations as rot

ESTIMATORS = ("adfusion", "adfusion_st", "ukf")
BASILISK_MODULES = ("inertialUKF", "mrpFeedback", "attTrackingError", "imuSensor",
                    "starTracker", "simpleNav", "rwMotorTorque")


def _us(x) -> dict[str, float]:
    a = np.asarray(x, dtype=np.float64) * 1e6
    return {"calls": len(a), "median_us": float(np.median(a)),
            "p95_us": float(np.percentile(a, 95))}


# the loops below run this many rounds and report the round with the lowest median (each
# round's median is kept): on the shared machine a round can fall on a burst of other jobs
ROUNDS = 3


def _best(rounds: list[list[float]]) -> dict[str, Any]:
    """:func:`_us` of the round with the lowest median, and every round's median."""
    stats = [_us(r) for r in rounds if len(r)]
    best = min(stats, key=lambda d: d["median_us"])
    return {**best, "rounds": len(stats),
            "round_medians_us": [d["median_us"] for d in stats]}


def _module_cost(run, n: int = 2000) -> dict[str, dict[str, float]]:
    """Basilisk modules' UpdateState, called ``n`` times a round on the run's live
    messages."""
    out = {}
    t_end = round(run.t[-1] * 1e9)
    for name in BASILISK_MODULES:
        mod = run.modules[name]
        rounds = []
        for r in range(ROUNDS):
            ts = []
            for k in range(r * n + 1, (r + 1) * n + 1):
                t_ns = t_end + k * 50_000_000
                t0 = time.thread_time()
                mod.UpdateState(t_ns)
                ts.append(time.thread_time() - t0)
            rounds.append(ts)
        out[name] = _best(rounds)
    return out


def _frames_again(run, n: int) -> list[np.ndarray]:
    """The first ``n`` frames' images, rendered again from the recorded truth (the run
    keeps none: a 10-minute run's images would be GBs)."""
    cam = run.modules["camera"]
    keepout, cam.earth_keepout_rad = cam.earth_keepout_rad, None  # no position recorded
    out = []
    for k in range(min(n, len(run.t))):
        out.append(cam.render(k, run.q_true[k], run.omega_true[k], np.zeros(3)).image)
    cam.earth_keepout_rad = keepout
    return out


def _cost(run, frame_images) -> dict[str, Any]:
    cost = {"adfusion camera module, gyro-only UpdateState": _us(run.cost_s["adfusion"]["gyro"]),
            "adfusion camera module, UpdateState with a frame (detect + identify + update)":
                _us(run.cost_s["adfusion"]["frame"]),
            "adfusion star-tracker module, gyro-only UpdateState":
                _us(run.cost_s["adfusion_st"]["gyro"])}
    steps = [r for r in run.nav_records if r["frame"] is not None]
    modes = [r["rec"].star_mode for r in steps]
    frame_calls = np.asarray(run.cost_s["adfusion"]["frame"])
    if len(frame_calls) == len(steps):
        tracking = [c for c, m in zip(frame_calls, modes, strict=True) if m == "tracking"]
        cost["adfusion camera module, UpdateState with a frame in tracking"] = _us(tracking)
        # every other frame (t = 0.5 s, 1 s, ...) comes with a gyro and a magnetometer
        # sample in the same call: the frame's own cost is that of the calls with it alone
        events = run.modules["adfusion"].frame_call_events
        alone = [c for c, m, n in zip(frame_calls, modes, events, strict=True)
                 if m == "tracking" and n == 1]
        if alone:
            cost["adfusion camera module, UpdateState with a frame in tracking and nothing "
                 "else"] = _us(alone)
    cam = run.camera
    ts, tw_ts = [], []
    windows = run.modules["adfusion"].windows
    for k, img in enumerate(frame_images):
        t0 = time.thread_time()
        detect(img, cam)
        ts.append(time.thread_time() - t0)
        if windows is not None:
            q_cam = rot.multiply(rot.inverse(run.q_body_cam_true), run.q_true[k])
            prior = Prior(q_cam, 0.002)
            t0 = time.thread_time()
            windows.detect(img, prior)
            tw_ts.append(time.thread_time() - t0)
    if ts:
        cost["starid.detection.detect alone, whole frame (same frames)"] = _us(ts)
    if tw_ts:
        cost["starid.detection.windows TrackingWindows.detect alone (same frames)"] = _us(tw_ts)
    cost["adfusion module alone, gyro-only UpdateState (hot loop, as Basilisk's below)"] = \
        _best(_gyro_loop_cost(run))
    frame_loop = _frame_loop_cost(run)
    if any(frame_loop):
        cost["adfusion camera module alone, UpdateState with a tracked frame (loop over "
             "pre-rendered frames, as Basilisk's below)"] = _best(frame_loop)
    cost.update({f"Basilisk {k}.UpdateState (from Python)": v
                 for k, v in _module_cost(run).items()})
    return cost


def _gyro_loop_cost(run, n: int = 2000) -> list[list[float]]:
    """A star-tracker AdfusionNav's gyro-only UpdateState called in a loop, each call on a
    new IMU sample (the run's gyro rates): the same conditions as Basilisk's modules in
    :func:`_module_cost` (inside the run the call follows rendering and frame work, and
    pays for the caches they evicted)."""
    from Basilisk.architecture import messaging

    from adfusion.basilisk import AdfusionNav
    from adfusion.basilisk.msgio import author

    cfg = run.config
    nav = AdfusionNav(q_body_icrs0=run.q_true[0], arw_rad_sqrt_s=cfg.arw_rad_sqrt_s,
                      rrw_rad_s_sqrt_s=1e-8, keep_records=False)
    msg = messaging.IMUSensorMsg()
    nav.imuInMsg.subscribeTo(msg)
    write = author(msg)
    imu = messaging.IMUSensorMsgPayload()
    rates = np.asarray(run.gyro["omega"])
    nav.Reset(0)
    for k in range(1, ROUNDS * n + 1):
        imu.AngVelPlatform = rates[k % len(rates)].tolist()
        write(imu, 0, k * 100_000_000)
        nav.UpdateState(k * 100_000_000)
    ts = nav.cost_s["gyro"]
    return [ts[r * n:(r + 1) * n] for r in range(ROUNDS)]


def _frame_loop_cost(run, n: int = 200) -> list[list[float]]:
    """The camera AdfusionNav's UpdateState with a frame and nothing else, called in a loop
    after the run: ``n`` frames rendered beforehand at the module's own estimate (its
    fixes then pass the filter's gate), one every 0.25 s after the run's end, gyro held;
    the same images again in the later rounds, as new frames (100 MB of them: cold in
    cache every time). The conditions of Basilisk's modules in :func:`_module_cost`:
    inside the run the call follows the rendering, which evicts the caches it needs. Only
    tracked frames count."""
    from dataclasses import replace

    nav, cam = run.modules.get("adfusion"), run.modules.get("camera")
    if nav is None or cam is None or nav.est.filter is None:
        return []
    q = nav.est.filter.q_body_icrs
    t0_ns = round(nav.est.t * 1e9)
    keepout, cam.earth_keepout_rad = cam.earth_keepout_rad, None  # truth: no position
    frames = [cam.render(cam.frames + k, q, np.zeros(3), np.zeros(3),
                         t_ns=t0_ns + (k + 1) * 250_000_000) for k in range(n)]
    cam.earth_keepout_rad = keepout
    keep, nav.keep_records = nav.keep_records, False  # the run's records stay as they are
    start = len(nav.cost_s["frame"])
    rounds = []
    for r in range(ROUNDS):
        out = []
        for fr0 in frames:
            fr = replace(fr0, index=fr0.index + r * n, t_ns=fr0.t_ns + r * n * 250_000_000)
            cam.latest = fr
            misses = nav.est.misses
            nav.UpdateState(fr.t_ns)
            if misses < nav.est.max_misses:  # (a tracking prior: the frame was tracked)
                out.append(nav.cost_s["frame"][-1])
        rounds.append(out)
    del nav.cost_s["frame"][start:]
    del nav.frame_call_events[start:]
    nav.keep_records = keep
    return rounds


def run(name: str = "leo", seeds: int = 10, duration_s: float = 600.0, settle_s: float = 150.0,
        cost_seed: int | None = 0, verbose: bool = True) -> dict[str, Any]:
    load_before = os.getloadavg()[0]
    cfg = scenario(name, duration_s=duration_s)
    sky, cat, solver = sky_and_solver(cfg)
    per_seed, ens, cost = [], {k: [] for k in ESTIMATORS}, None
    t_grid = None
    for seed in range(seeds):
        t0 = time.perf_counter()
        c0 = time.process_time()
        keep = cost_seed is not None and seed == cost_seed
        runs = {"adfusion": run_loop(cfg, "adfusion", seed, catalogs=(sky, cat), solver=solver,
                                     )}
        wall_adf = time.perf_counter() - t0
        cpu_adf = time.process_time() - c0
        runs["truth"] = run_loop(cfg, "truth", seed)
        runs["ukf"] = run_loop(cfg, "ukf", seed)
        runs["adfusion_st"] = run_loop(cfg, "adfusion_st", seed)
        rep = summarize(runs, settle_s=settle_s)
        base = runs["adfusion"]
        w = base.t >= settle_s
        t_grid = base.t[w]
        for k in ESTIMATORS:
            est = base.estimates[k]
            e = attitude_errors_rad(base.q_true[w], est["q"][w])
            v = nees(e, est["P"][w][:, :3, :3])
            v[~est["valid"][w]] = np.nan
            ens[k].append(v)
        ratio = rep.pointing["adfusion"]["rms_arcsec"] / rep.pointing["truth"]["rms_arcsec"]
        ratio_st = (rep.pointing["adfusion_st"]["rms_arcsec"]
                    / rep.pointing["truth"]["rms_arcsec"])
        per_seed.append({"seed": seed, "pointing": rep.pointing, "estimation": rep.estimation,
                         "camera": rep.camera, "pointing_ratio_adfusion_truth": ratio,
                         "pointing_ratio_adfusion_st_truth": ratio_st,
                         "wall_s": {"adfusion_loop": wall_adf,
                                    "all_four": time.perf_counter() - t0},
                         "cpu_s": {"adfusion_loop": cpu_adf,
                                   "all_four": time.process_time() - c0}})
        if verbose:
            print(f"seed {seed}: pointing RMS truth {rep.pointing['truth']['rms_arcsec']:.2f}″, "
                  f"ukf {rep.pointing['ukf']['rms_arcsec']:.2f}″, adfusion "
                  f"{rep.pointing['adfusion']['rms_arcsec']:.2f}″ (×{ratio:.2f}), adfusion_st "
                  f"{rep.pointing['adfusion_st']['rms_arcsec']:.2f}″ (×{ratio_st:.2f}); "
                  "estimation RMS "
                  + ", ".join(f"{k} {rep.estimation[k]['rms_arcsec']:.2f}″ NEES "
                              f"{rep.estimation[k]['mean_nees']:.2f}" for k in ESTIMATORS)
                  + f"; camera {rep.camera['identified_3_stars']}/{rep.camera['frames_3_stars']} "
                  f"wrong {rep.camera['wrong']}; {time.perf_counter() - t0:.1f} s", flush=True)
        if keep:
            cost = _cost(base, _frames_again(base, 200))
    m = len(per_seed)
    lo, hi = chi2.ppf([0.025, 0.975], 3 * m) / m
    ensemble = {}
    for k in ESTIMATORS:
        a = np.nanmean(np.vstack(ens[k]), axis=0)
        ensemble[k] = {"mean_ensemble_nees": float(np.nanmean(a)),
                       "fraction_of_times_inside_band": float(np.nanmean((a >= lo) & (a <= hi))),
                       "mean_of_seed_means": float(np.mean(
                           [s["estimation"][k]["mean_nees"] for s in per_seed]))}
    ratios = [s["pointing_ratio_adfusion_truth"] for s in per_seed]
    ratios_st = [s["pointing_ratio_adfusion_st_truth"] for s in per_seed]
    return {
        "scenario": name, "seeds": m, "duration_s": duration_s, "settle_s": settle_s,
        "nees_band_95": [float(lo), float(hi)], "nees_dof": 3, "ensemble_nees": ensemble,
        "times": int(0 if t_grid is None else len(t_grid)),
        # the criterion (pointing error ≤ 1.2 × the truth-fed loop's) is judged on the mean
        # over the seeds; each seed's ratio is kept too
        "pointing_ratio_adfusion_truth": {"mean": float(np.mean(ratios)),
                                          "max": float(np.max(ratios)),
                                          "per_seed": [float(r) for r in ratios],
                                          "seeds_above_1_2": int(np.sum(np.asarray(ratios)
                                                                        > 1.2)),
                                          "judged": "mean"},
        "pointing_ratio_adfusion_st_truth": {"mean": float(np.mean(ratios_st)),
                                             "max": float(np.max(ratios_st))},
        "pointing_rms_arcsec_mean": {k: float(np.mean([s["pointing"][k]["rms_arcsec"]
                                                       for s in per_seed]))
                                     for k in per_seed[0]["pointing"]},
        "estimation_rms_arcsec_mean": {k: float(np.mean([s["estimation"][k]["rms_arcsec"]
                                                         for s in per_seed]))
                                       for k in ESTIMATORS},
        "camera": {"frames_3_stars": int(sum(s["camera"]["frames_3_stars"] for s in per_seed)),
                   "identified": int(sum(s["camera"]["identified_3_stars"] for s in per_seed)),
                   "wrong": int(sum(s["camera"]["wrong"] for s in per_seed))},
        "cost": cost, "per_seed": per_seed,
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "python": platform.python_version(),
                    "load_average_1min_before": load_before,
                    "load_average_1min_after": os.getloadavg()[0],
                    "when": time.strftime("%Y-%m-%d", time.gmtime())},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default="leo")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--settle", type=float, default=150.0)
    ap.add_argument("--cost-seed", type=int, default=0)
    ap.add_argument("--out", default="benchmarks/results/bench_acs.json")
    a = ap.parse_args()
    r = run(a.scenario, a.seeds, a.duration, a.settle, a.cost_seed)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(r, indent=2) + "\n")
    print(json.dumps({k: v for k, v in r.items() if k != "per_seed"}, indent=2))


if __name__ == "__main__":
    main()
