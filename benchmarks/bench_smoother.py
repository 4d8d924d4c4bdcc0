"""Benchmark the GTSAM smoother against the filter on the same simulated logs.

Each run simulates a seeded scenario (rendered frames by default), steps the estimator over
it exactly as ``adfusion replay`` does (detection → tracking identification → MEKF, or the
rate filter with ``--no-gyro``), records what the smoother needs, smooths, and scores the
filter and the smoother against the truth at the frame times:

* RMS / max attitude error, filter vs smoother, on OEDIPUS-like and LEO logs, gyro and
  video-only;
* consistency: NEES of the attitude (3 dof) averaged over ``--runs`` seeds at every frame
  and over the log, against the two-sided 95 % band of a mean of that many χ²(3);
* robustness: one wrong star match injected every 50 identified frames (the first match of
  the frame re-paired with the nearest other catalogue star and the fix refitted with it,
  i.e. a wrong match that slipped past verification), filter vs smoother;
* time: batch (Levenberg–Marquardt + marginals) per 1000 frames, iSAM2 per-frame update.

Usage (from the repository root; prints JSON)::

    python benchmarks/bench_smoother.py [--runs 10] [--duration 60]
        [--nees-duration 20] [--no-render]

Example:
    >>> r = score(record(scenarios.oedipus(duration_s=1.0, seed=1, render=False)))
    >>> r["frames"], r["smoother_rms_deg"] < 0.05
    (30, True)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from typing import Any

import numpy as np
from adfusion.sensors import scenarios
from adfusion.starid.catalog.stars import Catalog
from adfusion.starid.solver import Solver
from scipy.stats import chi2

from adfusion.estimation.estimator import Estimator
from adfusion.estimation.faults import WrongMatchInjector
from adfusion.estimation.smoother import SmootherInput, smooth
from adfusion.maths import rotations as rot


def _attitude_error(q_est: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """Body-frame δθ with ``R_true = Exp(δθ)·R_est`` (docs/conventions.md), rows of (K, 3)."""
    return rot.log_map(rot.multiply(q_true, rot.inverse(q_est)))


@dataclasses.dataclass
class Recording:
    """One filter pass over a scenario: the smoother's input and the filter's answers."""

    name: str
    inp: SmootherInput
    q_true: np.ndarray  # (K, 4) at the frame times
    q_filter: list  # per frame, None before the filter starts
    p_filter: list  # per frame, the filter's 3×3 attitude covariance
    filter_s: float
    injected: int = 0


def record(sc: scenarios.Scenario, *, video_only: bool = False,
           inject_every: int | None = None) -> Recording:
    """Step the estimator over a scenario as ``adfusion replay`` does; keep what the smoother
    needs and the filter's estimate at every frame."""
    print(f"recording {sc!r}{' video-only' if video_only else ''}"
          f"{f', a wrong match every {inject_every}' if inject_every else ''}", file=sys.stderr)
    cfg = sc.config
    cat = Catalog.hipparcos(mag_limit=float(cfg.get("mag_limit", 5.5)),
                            epoch=float(cfg["catalog"]["epoch"]))
    solver: Any = Solver(cat, sc.camera, centroid_sigma_px=max(sc.centroid_sigma_px, 0.5))
    if inject_every:
        solver = WrongMatchInjector(solver, inject_every)
    g = cfg["gyro"]
    est = Estimator(solver, sc.q_body_cam, arw_rad_sqrt_s=g["arw_rad_sqrt_s"],
                    rrw_rad_s_sqrt_s=g["rrw_rad_s_sqrt_s"], video_only=video_only)
    inp = SmootherInput(sc.q_body_cam, arw_rad_sqrt_s=g["arw_rad_sqrt_s"],
                        rrw_rad_s_sqrt_s=g["rrw_rad_s_sqrt_s"],
                        sigma_mag_rad=est.sigma_mag_rad, video_only=video_only)
    truth = None
    q_true, q_filt, p_filt = [], [], []
    t0 = time.perf_counter()
    for ev in sc.events():
        d = ev.data
        if ev.kind == "truth":
            truth = d["q_body_icrs"]
        elif ev.kind == "gyro":
            if not video_only:
                est.step(ev.t_s, gyro=d["omega_meas_rad_s"])
                inp.add_gyro(ev.t_s, d["omega_meas_rad_s"])
        elif ev.kind == "mag":
            est.step(ev.t_s, mag=(d["b_body_nT"], d["b_ref_icrs_nT"]))
            inp.add_mag(ev.t_s, d["b_body_nT"], d["b_ref_icrs_nT"])
        else:
            rec = (est.step(ev.t_s, frame=d["image"]) if "image" in d
                   else est.step(ev.t_s, detections=d["xy"]))
            inp.add_step(ev.t_s, rec, est.solver)
            q_true.append(truth)
            q_filt.append(rec.q_body_icrs)
            p_filt.append(None if est.filter is None else est.filter.P[:3, :3])
    name = f"{sc.name}{' video-only' if video_only else ''}"
    return Recording(name, inp, np.array(q_true), q_filt, p_filt, time.perf_counter() - t0,
                     len(solver.wrong) if inject_every else 0)


def score(r: Recording, **smooth_kw: Any) -> dict[str, Any]:
    """Smooth a recording; errors (deg), 3σ, NEES and times of filter and smoother."""
    res = smooth(r.inp, **smooth_kw)
    have = np.array([q is not None for q in r.q_filter])
    if len(res.t) != len(r.q_true):
        raise RuntimeError(f"{r.name}: {len(r.q_true) - len(res.t)} frames left out: "
                           f"{res.problems}")
    e_s = _attitude_error(res.q_body_icrs, r.q_true)
    e_f = _attitude_error(np.array([q for q in r.q_filter if q is not None]), r.q_true[have])
    err_s = np.degrees(np.linalg.norm(e_s, axis=1))
    err_f = np.degrees(np.linalg.norm(e_f, axis=1))
    pf = np.array([p for p in r.p_filter if p is not None])
    nees_s = np.einsum("ki,kij,kj->k", e_s, np.linalg.inv(res.cov_attitude), e_s)
    nees_f = np.einsum("ki,kij,kj->k", e_f, np.linalg.inv(pf), e_f)
    sm = res.as_dict()
    total = sm["build_s"] + sm["optimize_s"] + sm["covariance_s"]
    out = {
        "log": r.name, "frames": len(r.q_true), "filter_frames": int(have.sum()),
        "filter_rms_deg": float(np.sqrt(np.mean(err_f**2))),
        "filter_max_deg": float(err_f.max()),
        "smoother_rms_deg": float(np.sqrt(np.mean(err_s**2))),
        "smoother_max_deg": float(err_s.max()),
        "ratio_rms": float(np.sqrt(np.mean(err_s[have] ** 2)) / np.sqrt(np.mean(err_f**2))),
        "filter_inside_3sigma": float(np.mean(
            err_f <= 3 * np.degrees(np.sqrt(np.trace(pf, axis1=1, axis2=2))))),
        "smoother_inside_3sigma": float(np.mean(err_s <= 3 * np.degrees(res.sigma_rad))),
        "filter_nees_mean": float(np.mean(nees_f)),
        "smoother_nees_mean": float(np.mean(nees_s)),
        "smoother_mean_error_body_deg": np.degrees(e_s.mean(axis=0)).round(5).tolist(),
        "smoother_s_per_1000_frames": total / len(res.t) * 1000,
        "filter_pass_s": r.filter_s,
        "smoother": sm,
        "_nees_s": nees_s,
    }
    if r.injected:
        out["injected_wrong_matches"] = r.injected
    return out


def nees_band(runs: int, dof: int = 3, p: float = 0.95) -> tuple[float, float]:
    """Two-sided band of the mean of ``runs`` χ²(dof) values."""
    a = (1 - p) / 2
    return (float(chi2.ppf(a, dof * runs) / runs), float(chi2.ppf(1 - a, dof * runs) / runs))


def _public(r: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in r.items() if not k.startswith("_")}


def _nees_runs(name: str, duration: float, seeds: range, render: bool) -> dict[str, Any]:
    nees, ratios = [], []
    for seed in seeds:
        sc = getattr(scenarios, name)(duration_s=duration, seed=seed, render=render)
        r = score(record(sc))
        nees.append(r["_nees_s"])
        ratios.append(round(r["ratio_rms"], 3))
    k = min(len(x) for x in nees)
    per_frame = np.mean([x[:k] for x in nees], axis=0)
    lo, hi = nees_band(len(seeds))
    return {"scenario": name, "render": render, "runs": len(seeds), "duration_s": duration,
            "mean_nees": float(per_frame.mean()), "band95": [lo, hi],
            "frames_inside_band": float(np.mean((per_frame >= lo) & (per_frame <= hi))),
            "per_run_mean_nees": [round(float(np.mean(x)), 2) for x in nees],
            "rms_ratio_per_run": ratios}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=10, help="seeds for the NEES (default 10)")
    ap.add_argument("--duration", type=float, default=60.0, help="main runs, s (default 60)")
    ap.add_argument("--nees-duration", type=float, default=20.0,
                    help="OEDIPUS NEES runs, s (default 20; LEO runs use --duration)")
    ap.add_argument("--no-render", action="store_true", help="centroid-only simulation")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    render = not args.no_render
    out: dict[str, Any] = {"render": render, "seed": args.seed}

    def scenario(name: str, seed: int = args.seed, duration: float = args.duration):
        return getattr(scenarios, name)(duration_s=duration, seed=seed, render=render)

    for name in ("oedipus", "leo"):  # accuracy and time: batch and iSAM2 on the same log
        rec = record(scenario(name))
        out[name] = _public(score(rec))
        out[f"{name}_isam2"] = _public(score(rec, mode="isam2"))
        out[f"{name}_batch_no_covariance"] = _public(score(rec, covariances=False))
    rec = record(scenario("oedipus"), video_only=True)
    out["oedipus_video_only"] = _public(score(rec))
    out["oedipus_video_only_isam2"] = _public(score(rec, mode="isam2"))
    for name in ("oedipus", "leo"):  # one wrong star match per 50 identified frames
        rec = record(scenario(name), inject_every=50)
        for kernel in ("cauchy", "huber", "none"):
            out[f"{name}_wrong_matches_{kernel}"] = _public(score(rec, robust=kernel))
    seeds = range(args.seed, args.seed + args.runs)
    out["nees_oedipus"] = _nees_runs("oedipus", args.nees_duration, seeds, render)
    out["nees_oedipus_centroids"] = _nees_runs("oedipus", args.nees_duration, seeds, False)
    out["nees_leo"] = _nees_runs("leo", args.duration, seeds, render)
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
