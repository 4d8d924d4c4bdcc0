"""``adfusion acs SCENARIO``: the loop closed three ways, compared, reported and logged.

:func:`run_acs` runs the scenario with the loop closed on adfusion (camera frames in the
loop; the MCAP log is written from this run), on Basilisk's truth (``simpleNav`` without
noise), on Basilisk's ``inertialUKF`` and on adfusion fed by the same star tracker as the UKF
(``adfusion_st``), all from one seed (the same sensor-noise draws).
In each run the other estimators run beside the one in the loop on the same messages, so
:func:`summarize` compares estimation errors on identical inputs: adfusion on the camera,
adfusion on the star tracker's quaternions, and ``inertialUKF`` on those same quaternions.

Figures (:class:`AcsReport`):

* pointing error — the angle between the true body and the reference attitude (3 axes), and
  between the camera's true and reference lines of sight (roll about it left out), RMS and
  95th percentile from ``settle_s`` on (the initial acquisition is the same in all loops);
* estimation error — the angle between estimate and truth, RMS / p95 over the same window,
  and the mean NEES of the attitude error (3 dof; the 95 % band of a time average is not
  given here — successive errors are correlated — see benchmarks/bench_acs.py for the
  ensemble band over seeds);
* camera — frames with ≥ 3 catalogue stars in view and not blinded, identified (accepted
  fixes), wrong fixes (a solution off the truth by more than ``wrong_deg``), the outage and
  the mode of the first frame after it;
* cost — wall time per call of the adfusion module by kind (gyro-only, frame).

Example:
    >>> rep = run_acs("leo", None, seed=1, duration_s=3.0, loops=("adfusion",))
    >>> rep.camera["frames_3_stars"], rep.camera["wrong"]
    (13, 0)
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from adfusion.basilisk.scenarios import LOOPS, LoopRun, run_loop, scenario
from adfusion.logs import LogWriter
from adfusion.maths import rotations as rot
from adfusion.plain import listed
from adfusion.starid.camera.model import Camera
from adfusion.starid.catalog.stars import Catalog
from adfusion.starid.solver import Solver

__all__ = ["AcsReport", "attitude_errors_rad", "nees", "run_acs", "summarize"]

LOOP_NAMES = {"truth": "truth (simpleNav)", "ukf": "inertialUKF (star tracker)",
              "adfusion_st": "adfusion (star tracker)", "adfusion": "adfusion (camera)"}
ESTIMATORS = {"adfusion": "adfusion (camera + gyro + mag)",
              "adfusion_st": "adfusion (star tracker + gyro)",
              "ukf": "inertialUKF (star tracker + gyro)"}


def attitude_errors_rad(q_true, q_est) -> np.ndarray:
    """(N, 3) left (body-frame) attitude errors: ``R_true = Exp(δθ) R_est``, the filters'
    convention.

    >>> e = attitude_errors_rad([[1.0, 0, 0, 0]], rot.exp_map([[0.0, 0.0, 1e-3]]))
    >>> np.round(e * 1e3, 6).tolist()
    [[0.0, 0.0, -1.0]]
    """
    dq = rot.multiply(np.atleast_2d(q_true), rot.inverse(np.atleast_2d(q_est)))
    return rot.log_map(rot.canonical(dq))


def nees(err_rad: np.ndarray, P_att: np.ndarray) -> np.ndarray:
    """Per-sample ``δθᵀ P⁻¹ δθ`` of (N, 3) errors with (N, 3, 3) covariances.

    >>> round(float(nees(np.array([[1e-3, 0, 0]]), np.eye(3)[None] * 1e-6)[0]), 12)
    1.0
    """
    return np.einsum("ni,ni->n", err_rad, np.linalg.solve(P_att, err_rad[..., None])[..., 0])


def _stats_deg(x_rad: np.ndarray) -> dict[str, float]:
    x = np.degrees(np.asarray(x_rad))
    if len(x) == 0:
        return {"rms_arcsec": float("nan"), "p95_arcsec": float("nan"),
                "max_arcsec": float("nan")}
    return {"rms_arcsec": float(np.sqrt(np.mean(x**2)) * 3600),
            "p95_arcsec": float(np.percentile(x, 95) * 3600),
            "max_arcsec": float(np.max(x) * 3600)}


@dataclass
class AcsReport:
    """The figures of one ``adfusion acs`` run (JSON-ready via :meth:`as_dict`)."""

    scenario: str
    seed: int
    duration_s: float
    settle_s: float
    pointing: dict[str, dict[str, float]] = field(default_factory=dict)  # loop → stats
    estimation: dict[str, dict[str, float]] = field(default_factory=dict)  # estimator → stats
    camera: dict[str, Any] = field(default_factory=dict)
    cost_us: dict[str, dict[str, float]] = field(default_factory=dict)
    # estimation error inside the scenario's events (the slew's first 120 s, each outage
    # window and 10 s after it): window name → estimator → stats
    windows: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    wall_s: dict[str, float] = field(default_factory=dict)
    log_path: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return dict(vars(self))

    def table(self) -> str:
        """The comparison as a Markdown table."""
        lines = [f"## adfusion acs {self.scenario} (seed {self.seed}, {self.duration_s:g} s; "
                 f"statistics from t = {self.settle_s:g} s)", "",
                 "| loop closed on | pointing RMS (″) | p95 (″) | max (″) | "
                 "line of sight RMS (″) | p95 (″) |", "|---|---|---|---|---|---|"]
        for loop, s in self.pointing.items():
            lines.append(f"| {LOOP_NAMES.get(loop, loop)} | {s['rms_arcsec']:.2f} | "
                         f"{s['p95_arcsec']:.2f} | {s['max_arcsec']:.2f} | "
                         f"{s['los_rms_arcsec']:.2f} | {s['los_p95_arcsec']:.2f} |")
        lines += ["", "| estimator (same messages) | error RMS (″) | p95 (″) | max (″) | "
                      "mean NEES (3 dof) |", "|---|---|---|---|---|"]
        for name, s in self.estimation.items():
            lines.append(f"| {ESTIMATORS.get(name, name)} | {s['rms_arcsec']:.2f} | "
                         f"{s['p95_arcsec']:.2f} | {s['max_arcsec']:.2f} | "
                         f"{s['mean_nees']:.2f} |")
        for label, per in self.windows.items():
            lines += ["", f"| estimation error, {label} | RMS (″) | p95 (″) | max (″) |",
                      "|---|---|---|---|"]
            for name, st in per.items():
                lines.append(f"| {ESTIMATORS.get(name, name)} | {st['rms_arcsec']:.2f} | "
                             f"{st['p95_arcsec']:.2f} | {st['max_arcsec']:.2f} |")
        if self.camera:
            c = self.camera
            modes = listed((f"{m} {n}" for m, n in c["modes"].items()), None)
            lines += ["", f"camera: {c['frames']} frames, {c['frames_3_stars']} with ≥ 3 stars "
                          f"in view and not blinded, {c['identified_3_stars']} identified "
                          f"({100 * c['identified_fraction']:.2f} %), {c['wrong']} wrong "
                          f"fixes; modes {modes}"]
            if c.get("outage"):
                o = c["outage"]
                lines.append(f"outage: {o['frames']} frames from t = {o['start_s']:.2f} s to "
                             f"{o['end_s']:.2f} s ({o['end_s'] - o['start_s']:.1f} s); first "
                             f"frame after it: {o['first_after_mode']}, accepted "
                             f"{o['first_after_accepted']}")
        if self.cost_us:
            lines += ["", "| module call | calls | median (µs) | p95 (µs) |", "|---|---|---|---|"]
            for k, s in self.cost_us.items():
                lines.append(f"| {k} | {s['calls']} | {s['median_us']:.1f} | "
                             f"{s['p95_us']:.1f} |")
        return "\n".join(lines)


def summarize(runs: dict[str, LoopRun], settle_s: float = 60.0,
              wrong_deg: float = 0.05) -> AcsReport:
    """The figures of :class:`AcsReport` from runs keyed by loop name."""
    any_run = next(iter(runs.values()))
    cfg = any_run.config
    rep = AcsReport(cfg.name, any_run.seed, cfg.duration_s, settle_s)
    for loop in LOOPS:
        if loop in runs:
            r = runs[loop]
            w = r.t >= settle_s
            rep.pointing[loop] = _stats_deg(rot.angle_between(r.q_true[w], r.q_ref[w]))
            # the camera's line of sight alone (the roll about it left out)
            z_body = rot.to_matrix(r.q_body_cam_fsw)[:, 2]
            los_true = np.einsum("nji,j->ni", rot.to_matrix(r.q_true[w]), z_body)
            los_ref = np.einsum("nji,j->ni", rot.to_matrix(r.q_ref[w]), z_body)
            cosang = np.clip(np.einsum("ni,ni->n", los_true, los_ref), -1.0, 1.0)
            los = _stats_deg(np.arccos(cosang))
            rep.pointing[loop].update({f"los_{k}": v for k, v in los.items()})
    base = runs.get("adfusion", any_run)
    w = base.t >= settle_s
    for name in ("adfusion", "adfusion_st", "ukf"):
        est = base.estimates.get(name)
        if est is None:
            continue
        ok = w & est["valid"]
        err = attitude_errors_rad(base.q_true[ok], est["q"][ok])
        s = _stats_deg(np.linalg.norm(err, axis=1))
        s["mean_nees"] = float(np.mean(nees(err, est["P"][ok][:, :3, :3]))) if ok.any() \
            else float("nan")
        rep.estimation[name] = s
    events = []
    if cfg.slew_at_s is not None:
        events.append((f"slew ({cfg.slew_at_s:g}–{cfg.slew_at_s + 120:g} s)",
                       cfg.slew_at_s, cfg.slew_at_s + 120.0))
    for a, b in cfg.blind_windows:
        events.append((f"outage ({a:g}–{b:g} s, +10 s)", a, b + 10.0))
    for label, a, b in events:
        w_ev = (base.t >= a) & (base.t < b)
        rep.windows[label] = {}
        for name in ("adfusion", "adfusion_st", "ukf"):
            est = base.estimates.get(name)
            if est is not None and (w_ev & est["valid"]).any():
                ok = w_ev & est["valid"]
                rep.windows[label][name] = _stats_deg(rot.angle_between(base.q_true[ok],
                                                                        est["q"][ok]))
    if base.camera_steps:
        rep.camera = _camera_figures(base, wrong_deg)
        for kind in ("gyro", "frame"):
            c = np.asarray(base.cost_s["adfusion"][kind]) * 1e6
            if len(c):
                rep.cost_us[f"adfusion camera nav: {kind}"] = {
                    "calls": len(c), "median_us": float(np.median(c)),
                    "p95_us": float(np.percentile(c, 95))}
    c = np.asarray(base.cost_s["adfusion_st"]["gyro"]) * 1e6
    if len(c):
        rep.cost_us["adfusion star-tracker nav: gyro"] = {
            "calls": len(c), "median_us": float(np.median(c)),
            "p95_us": float(np.percentile(c, 95))}
    return rep


def _camera_figures(run: LoopRun, wrong_deg: float) -> dict[str, Any]:
    steps = run.camera_steps
    usable = [s for s in steps if s["n_in_view"] >= 3 and not s["blinded"] and not s["skipped"]]
    ident = sum(s["accepted"] for s in usable)
    wrong = sum(1 for s in steps if s["fix_error_deg"] is not None
                and s["fix_error_deg"] > wrong_deg)
    modes: dict[str, int] = {}
    for s in steps:
        key = "skipped (keep-out)" if s["skipped"] else (s["mode"] or "none")
        modes[key] = modes.get(key, 0) + 1
    out: dict[str, Any] = {
        "frames": len(steps), "frames_3_stars": len(usable), "identified_3_stars": ident,
        "identified_fraction": ident / max(len(usable), 1), "wrong": wrong,
        "wrong_threshold_deg": wrong_deg, "modes": modes,
        "fix_error_rms_arcsec": float(np.sqrt(np.mean(np.square(
            [s["fix_error_deg"] for s in steps if s["fix_error_deg"] is not None]))) * 3600)
        if any(s["fix_error_deg"] is not None for s in steps) else None,
    }
    dark = [i for i, s in enumerate(steps) if s["blinded"] or s["skipped"]]
    if dark:
        i0, i1 = dark[0], dark[-1]
        after = next((s for s in steps[i1 + 1:] if s["mode"]), None)
        out["outage"] = {"start_s": steps[i0]["t"], "end_s": steps[i1]["t"],
                         "frames": len(dark),
                         "blinded": sum(s["blinded"] for s in steps),
                         "skipped": sum(s["skipped"] for s in steps),
                         "first_after_t": None if after is None else after["t"],
                         "first_after_mode": None if after is None else after["mode"],
                         "first_after_accepted": None if after is None else after["accepted"]}
    return out


def sky_and_solver(cfg: Any) -> tuple[Catalog, Catalog, Solver]:
    """The rendered sky, the solver's catalogue and the warmed-up solver of a scenario's
    camera (``cfg`` from :func:`adfusion.basilisk.scenarios.scenario`): what every loop of a
    run shares."""
    sky = Catalog.hipparcos(mag_limit=cfg.render_mag_limit, epoch=cfg.catalog_epoch)
    cat = Catalog.hipparcos(mag_limit=cfg.solver_mag_limit, epoch=cfg.catalog_epoch)
    solver = Solver(cat, Camera.pinhole(cfg.width_px, cfg.width_px, cfg.fov_deg),
                    centroid_sigma_px=cfg.centroid_sigma_px)
    solver.warm_up()
    solver.warm_up_tracking()  # the compiled tracking path, before the loop
    return sky, cat, solver


def run_acs(name: str, out_path: str | Path | None, seed: int = 0, *,
            duration_s: float | None = None, loops: tuple[str, ...] = LOOPS,
            images: str = "preview", settle_s: float = 150.0,
            plot: bool = True, progress: Callable[[str], None] | None = None) -> AcsReport:
    """Run scenario ``name`` with the loop closed on each of ``loops``; with ``out_path``
    write the adfusion run's MCAP there and the report beside it (``.report.md``,
    ``.report.json``, ``.png``). ``progress`` is called with a line as each loop starts."""
    overrides = {} if duration_s is None else {"duration_s": float(duration_s)}
    cfg = scenario(name, **overrides)
    walls: dict[str, float] = {}
    t0 = time.perf_counter()
    sky, cat, solver = sky_and_solver(cfg)
    walls["setup"] = time.perf_counter() - t0
    runs: dict[str, LoopRun] = {}
    order = [loop for loop in ("adfusion", "truth", "ukf", "adfusion_st") if loop in loops]
    for loop in order:
        if progress is not None:
            progress(f"{name}: loop {len(runs) + 1} of {len(order)}, closed on {loop} "
                     f"({cfg.duration_s:g} s simulated)")
        t1 = time.perf_counter()
        if loop == "adfusion" and out_path is not None:
            with LogWriter(out_path, atomic=True) as log:
                runs[loop] = run_loop(cfg, loop, seed, catalogs=(sky, cat), solver=solver,
                                      log=log, images=images)
        else:
            runs[loop] = run_loop(cfg, loop, seed, catalogs=(sky, cat), solver=solver)
        walls[loop] = time.perf_counter() - t1
    rep = summarize(runs, settle_s=min(settle_s, cfg.duration_s / 2))
    rep.wall_s = walls
    if out_path is not None:
        out = Path(out_path)
        rep.log_path = str(out)
        base = out.with_suffix("")
        Path(f"{base}.report.md").write_text(rep.table() + "\n")
        Path(f"{base}.report.json").write_text(json.dumps(rep.as_dict(), indent=2) + "\n")
        if plot:
            plot_runs(runs, f"{base}.png")
    return rep


def plot_runs(runs: dict[str, LoopRun], path: str | Path) -> None:
    """Pointing error per loop and estimation error per estimator against time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for loop, r in runs.items():
        a1.semilogy(r.t, np.degrees(rot.angle_between(r.q_true, r.q_ref)) * 3600,
                    label=f"loop on {loop}", lw=0.8)
    a1.set_ylabel("pointing error (″)")
    a1.legend()
    base = runs.get("adfusion", next(iter(runs.values())))
    for name, est in base.estimates.items():
        ok = est["valid"]
        e = np.degrees(rot.angle_between(base.q_true[ok], est["q"][ok])) * 3600
        a2.semilogy(base.t[ok], e, label=ESTIMATORS.get(name, name), lw=0.8)
    a2.set_ylabel("estimation error (″)")
    a2.set_xlabel("t (s)")
    a2.legend()
    fig.suptitle(f"adfusion acs {base.config.name}, seed {base.seed}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
