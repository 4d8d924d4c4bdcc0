"""``adfusion bench sweep``: LOST-style robustness sweeps, ours against the peers.

Each sweep varies one thing away from the base camera of ``adfusion bench starid``
(1024×768, 15° FOV, Hipparcos V < 6, centroid σ 0.1 px, magnitude noise 0.1):

=============  ==========================================  ===============================
sweep          values (default grid)                       frame model
=============  ==========================================  ===============================
n_false        0, 1, …, 10 false stars per frame           synthetic centroids
sigma_px       centroid σ 0, 0.25, 0.5, 1, 1.5, 2 px       synthetic centroids
drop_frac      0, 10, …, 50 % of the stars dropped         synthetic centroids
mag_noise      magnitude noise 0, 0.25, …, 1 mag           synthetic (ordering only)
mag_limit      limiting magnitude 3.5, 4, …, 6.5           synthetic; sparse fields
fov_deg        10°, 20°, 45°                               synthetic
rate_deg_s     0, 0.5, 1, 2, 5, 10 °/s, 0.1 s exposure     rendered, streaked, ``detect``
=============  ==========================================  ===============================

A sweep point *is* a :class:`adfusion.bench.starid.Condition` (named ``"n_false=3"`` …):
frames, solver set-up, the correctness test and the statistics are those of ``bench
starid`` (:func:`~adfusion.bench.starid.make_frame`, :func:`~adfusion.bench.starid.score`,
:func:`~adfusion.bench.starid.aggregate`). Frame *i* of every point has the same attitude
(``(seed, i)``); its perturbations come from ``(seed, i, point)``. Per point and solver:
availability, error rate with its 95 % Clopper–Pearson upper bound, time p50 (``median``)
/ p95 / max, for

* ``ours`` — lost-in-space;
* ``ours_tracking`` — the same solver with a filter-like prior (the true attitude tilted
  by N(0, 0.1°) per axis, ``sigma_deg`` 0.1: :func:`~adfusion.bench.starid.tracking_prior`);
* ``tetra3rs`` and ``cedar`` (cedar-solve in its own venv), on the identical centroid lists,
  timed inside their own process.

The campaign runs on ``dask.distributed`` (:mod:`adfusion.bench.campaign`): tasks are (point,
chunk of trial indices); ``--workers N`` local processes (default: the CPU count) or
``--scheduler tcp://HOST:PORT``; results are identical for any worker count, finished
chunks go to a partial file as they arrive (a rerun resumes).

Example:
    >>> cfg = SweepConfig(trials=2, sweeps=["n_false"], values={"n_false": (0.0, 5.0)},
    ...                   solvers=["ours"], workers=0, progress=False)
    >>> doc = run_sweep(cfg)
    >>> [p["name"] for p in doc["sweeps"][0]["points"]]
    ['n_false=0', 'n_false=5']
    >>> doc["sweeps"][0]["points"][1]["results"]["ours"]["n_frames"]
    2
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from adfusion.bench import campaign
from adfusion.bench import starid as bs
from adfusion.bench.machine import code_version, machine_info
from adfusion.bench.starid import Condition

__all__ = [
    "SOLVERS",
    "SWEEPS",
    "Sweep",
    "SweepConfig",
    "add_arguments",
    "cli",
    "config_from_args",
    "estimate_seconds",
    "format_table",
    "main",
    "markdown_tables",
    "points",
    "run",
    "run_chunk",
    "run_sweep",
    "write_plots",
]

SOLVERS = ("ours", "ours_tracking", "tetra3rs", "cedar")
PEERS = ("tetra3rs", "cedar")


@dataclass(frozen=True)
class Sweep:
    """One swept variable: its values (default and ``--quick`` grid) and its points."""

    name: str
    label: str
    values: tuple[float, ...]
    quick: tuple[float, ...]
    build: Callable[[str, float, float], Condition]  # (point name, value, exposure_s)
    scale: float = 1.0  # plotted and tabulated as value × scale (fractions as %)

    def condition(self, value: float, exposure_s: float = 0.1) -> Condition:
        """The (unresolved) condition of one point.

        >>> SWEEPS["drop_frac"].condition(0.3).drop_frac
        0.3
        """
        return self.build(f"{self.name}={value:g}", float(value), exposure_s)


def _sweep(name: str, label: str, values: Sequence[float], quick: Sequence[float],
           build: Callable[[str, float, float], Condition], scale: float = 1.0) -> Sweep:
    return Sweep(name, label, tuple(float(v) for v in values),
                 tuple(float(v) for v in quick), build, scale)


#: The sweeps, in report order.
SWEEPS: dict[str, Sweep] = {s.name: s for s in (
    _sweep("n_false", "false stars per frame", range(11), (0, 2, 5, 10),
           lambda n, v, e: Condition(n, f"{v:g} false stars", n_false=int(v))),
    _sweep("sigma_px", "centroid σ (px)", (0, 0.25, 0.5, 1, 1.5, 2), (0, 1, 2),
           lambda n, v, e: Condition(n, f"centroid σ = {v:g} px", sigma_px=v)),
    _sweep("drop_frac", "dropped stars (%)", (0, 0.1, 0.2, 0.3, 0.4, 0.5), (0, 0.3, 0.5),
           lambda n, v, e: Condition(n, f"{100 * v:g} % of stars dropped", drop_frac=v),
           scale=100.0),
    _sweep("mag_noise", "magnitude noise σ (mag)", (0, 0.25, 0.5, 0.75, 1), (0, 0.5, 1),
           lambda n, v, e: Condition(n, f"magnitude noise {v:g} mag", mag_noise=v)),
    _sweep("mag_limit", "limiting magnitude (V)", (3.5, 4, 4.5, 5, 5.5, 6, 6.5),
           (3.5, 4.5, 5.5, 6.5),
           lambda n, v, e: Condition(n, f"catalogue and visible stars V < {v:g}",
                                     mag_limit=v, coverage=True)),
    _sweep("fov_deg", "horizontal FOV (°)", (10, 20, 45), (10, 20, 45),
           lambda n, v, e: Condition(n, f"FOV {v:g}°", fov_deg=v)),
    _sweep("rate_deg_s", "angular rate (°/s), rendered with motion blur",
           (0, 0.5, 1, 2, 5, 10), (0, 2, 5, 10),
           lambda n, v, e: Condition(n, f"{v:g} °/s over {e:g} s, rendered + detect",
                                     rate_deg_s=v, exposure_s=e)),
)}


@dataclass
class SweepConfig(bs.FrameModel):
    """Everything that determines a sweep run (recorded in the JSON).

    ``values`` overrides the grid of a sweep (name → values). ``workers``: local dask
    worker processes (None: the CPU count; 0: serial in this process); ``scheduler``: an
    existing dask scheduler's address.
    """

    trials: int = 1000
    quick: bool = False
    sweeps: list[str] = field(default_factory=lambda: list(SWEEPS))
    values: dict[str, tuple[float, ...]] = field(default_factory=dict)
    solvers: list[str] = field(default_factory=lambda: list(SOLVERS))
    prior_sigma_deg: float = 0.1
    exposure_s: float = 0.1
    peer_timeout_ms: float = 5000.0
    chunk: int = 50
    workers: int | None = None
    scheduler: str | None = None
    cache_dir: str | None = None
    partial: str | None = None
    keep_partial: bool = False
    progress: bool = True

    def job(self, solvers: Sequence[str], cache_dir: str | None) -> Job:
        """The part of the configuration a task needs (and that its results depend on,
        including the code: a partial file is not reused after it changed)."""
        code = campaign.source_digest("adfusion.starid", "adfusion.sensors",
                                      "adfusion.bench.starid", "adfusion.bench.sweep")
        return Job(self.seed, self.width, self.height, self.fov_deg, self.mag_limit,
                   self.sigma_px, self.mag_noise, self.tol_px, self.tol_sigma, self.epoch,
                   tuple(solvers), self.prior_sigma_deg, self.peer_timeout_ms, cache_dir,
                   code)


@dataclass(frozen=True)
class Job:
    """What every task of a sweep shares; also the per-worker adapter cache key."""

    seed: int
    width: int
    height: int
    fov_deg: float
    mag_limit: float
    sigma_px: float
    mag_noise: float
    tol_px: float
    tol_sigma: float
    epoch: float
    solvers: tuple[str, ...]
    prior_sigma_deg: float
    peer_timeout_ms: float
    cache_dir: str | None
    code: str = ""  # campaign.source_digest of the code the results depend on


def points(cfg: SweepConfig) -> list[tuple[Sweep, float, Condition]]:
    """Every (sweep, value, resolved condition) of the run, in report order.

    >>> [c.name for _, _, c in points(SweepConfig(quick=True, sweeps=["fov_deg"]))]
    ['fov_deg=10', 'fov_deg=20', 'fov_deg=45']
    """
    unknown = [s for s in cfg.sweeps if s not in SWEEPS]
    if unknown:
        raise ValueError(f"unknown sweep(s) {unknown}; choose from {list(SWEEPS)}")
    out = []
    for name in cfg.sweeps:
        sw = SWEEPS[name]
        vals = cfg.values.get(name) or (sw.quick if cfg.quick else sw.values)
        for v in vals:
            cond = sw.condition(v, cfg.exposure_s).resolved(
                cfg.sigma_px, cfg.mag_limit, mag_noise=cfg.mag_noise, fov_deg=cfg.fov_deg)
            out.append((sw, float(v), cond))
    return out


def _tolerance(job: Job | SweepConfig, cond: Condition) -> float:
    return max(job.tol_px, job.tol_sigma * float(cond.sigma_px or 0.0))


# --- the task (runs on the workers) -------------------------------------------------------


def _adapters(job: Job) -> list[bs.Adapter]:
    from pathlib import Path as _Path

    cache = _Path(job.cache_dir) if job.cache_dir else bs.cache_root(job)[0]
    adapters, skipped = bs.make_adapters(job, None, cache)  # type: ignore[arg-type]
    if skipped:  # on a worker: the client checked these, so this is a broken worker
        raise RuntimeError(f"solvers unavailable on this worker: {skipped}")
    return adapters


def run_chunk(payload: tuple[Job, Condition, int, int]) -> dict[str, Any]:
    """The campaign task: trials ``[start, stop)`` of one point, every solver, scored.

    Returns ``{"frames": [[n_true, n_centroids, n_in_view], …], "trials": {solver: [row,
    …]}}`` (rows of :class:`adfusion.bench.starid.Trial`). Runs on a dask worker (or in this
    process); solvers, catalogues and indexes are built once per worker process.
    """
    job, cond, start, stop = payload
    t0 = time.perf_counter()
    adapters = campaign.worker_memo(("bench_sweep.adapters", job), lambda: _adapters(job))
    warm = campaign.worker_memo(("bench_sweep.warm", job), set)
    cam = bs.camera_for(cond, job.width, job.height, job.fov_deg)
    assert cond.mag_limit is not None
    cat = bs.load_catalog(cond.mag_limit, job.epoch)
    tol = _tolerance(job, cond)
    for a in adapters:
        a.setup(cond, cam)
        if (a.name, cond) not in warm:  # first-call costs stay out of the timings
            a.solve(bs.make_frame(cat, cam, cond, job.seed + 10_007, 0, job.mag_noise))
            warm.add((a.name, cond))
    frames: list[list[int]] = []
    trials: dict[str, list[list[Any]]] = {a.name: [] for a in adapters}
    for i in range(start, stop):
        f = bs.make_frame(cat, cam, cond, job.seed, i, job.mag_noise)
        frames.append([f.n_true, len(f.xy), f.n_in_view])
        for a in adapters:
            t = bs.score(f, a.solve(f), cam, tol, cat)
            row = t.row()
            row[5] = row[5][:80]  # status: the reason's head is enough for the statistics
            trials[a.name].append(row)
    return {"frames": frames, "trials": trials, "wall_s": time.perf_counter() - t0}


# --- the run (client side) ----------------------------------------------------------------

#: Measured cost of one trial (all four solvers, frame generation, scoring; ms of worker
#: time on this workplace's shared 2-core AMD EPYC VM, between a loaded and a quiet
#: 1000-trial run — load changes them by up to 2×) and the one-off set-up (indexes and peer
#: databases loaded on every worker); used only for the estimate printed before a run.
COST_MS: dict[str, float] = {
    "n_false": 33.0, "sigma_px": 20.0, "drop_frac": 14.0, "mag_noise": 11.0,
    "mag_limit": 11.0, "fov_deg": 24.0, "rate_deg_s": 110.0,
}
SETUP_S = 60.0


def estimate_seconds(cfg: SweepConfig, workers: int) -> float:
    """Rough wall time of a run from :data:`COST_MS` (this machine, all four solvers).

    >>> round(estimate_seconds(SweepConfig(trials=1000, sweeps=["fov_deg"]), 2))
    96
    """
    share = max(0.25, len(cfg.solvers) / len(SOLVERS))
    ms = sum(COST_MS.get(sw.name, 100.0) for sw, _, _ in points(cfg)) * cfg.trials * share
    return SETUP_S + ms / 1e3 / max(1, workers)


def _prepare(cfg: SweepConfig, pts: list[tuple[Sweep, float, Condition]], cache: Path,
             in_process: bool) -> tuple[Job, dict[str, Any], dict[str, Any]]:
    """Client side, before the campaign: which solvers work, the conversion check, and
    every index and peer database built once (so workers only load them)."""
    probe = cfg.job(cfg.solvers, str(cache))
    adapters, skipped = bs.make_adapters(probe, None, cache)  # type: ignore[arg-type]
    names = [a.name for a in adapters]
    job = cfg.job(names, str(cache))
    try:
        camera = bs.camera_for(Condition("base"), cfg.width, cfg.height, cfg.fov_deg)
        check = bs.conversion_check(adapters, job, camera)  # type: ignore[arg-type]
        for _, _, cond in pts:
            cam = bs.camera_for(cond, cfg.width, cfg.height, cfg.fov_deg)
            for a in adapters:
                a.setup(cond, cam)
        info = {a.name: a.info() for a in adapters}
    finally:
        for a in adapters:
            a.close()
    if not in_process:
        bs.SOLVERS.clear()  # the workers load their own (from the cache just filled)
    info.update(skipped)
    return job, info, check


def run_sweep(cfg: SweepConfig) -> dict[str, Any]:
    """Run the sweep campaign and return the result document (progress on stderr)."""
    if cfg.trials < 1:
        raise ValueError("trials must be ≥ 1")
    if cfg.chunk < 1:
        raise ValueError("chunk must be ≥ 1")
    t_start = time.perf_counter()
    pts = points(cfg)
    in_process = cfg.scheduler is None and (cfg.workers == 0 or not campaign.dask_available())
    cache, tmp = bs.cache_root(cfg)  # tmp: caching is off, a folder for this run only
    try:
        job, solver_info, check = _prepare(cfg, pts, cache, in_process)
        res = _campaign(cfg, pts, job)
    finally:
        if tmp is not None:
            tmp.cleanup()
    return _document(cfg, pts, job, res, solver_info, check, t_start)


def _tasks(cfg: SweepConfig, pts: list[tuple[Sweep, float, Condition]],
           job: Job) -> list[campaign.Task]:
    tasks = []
    for _, _, cond in pts:
        for start in range(0, cfg.trials, cfg.chunk):
            stop = min(cfg.trials, start + cfg.chunk)
            tasks.append(campaign.Task(f"{cond.name}/{start}", (job, cond, start, stop),
                                       stop - start))
    return tasks


def _campaign(cfg: SweepConfig, pts: list[tuple[Sweep, float, Condition]],
              job: Job) -> campaign.CampaignResult:
    return campaign.run_campaign(run_chunk, _tasks(cfg, pts, job), workers=cfg.workers,
                                 scheduler=cfg.scheduler, partial=cfg.partial,
                                 progress=cfg.progress, desc="bench sweep", unit="trial",
                                 keep_partial=cfg.keep_partial)


def _document(cfg: SweepConfig, pts: list[tuple[Sweep, float, Condition]], job: Job,
              res: campaign.CampaignResult, solver_info: dict[str, Any],
              check: dict[str, Any], t_start: float) -> dict[str, Any]:
    tasks = _tasks(cfg, pts, job)
    sweeps: list[dict[str, Any]] = []
    for sw, value, cond in pts:
        chunks = [res.results[t.key] for t in tasks if t.payload[1] == cond]
        entry = _point(job, sw, value, cond, chunks)
        if not sweeps or sweeps[-1]["name"] != sw.name:
            sweeps.append({"name": sw.name, "label": sw.label, "scale": sw.scale,
                           "points": []})
        sweeps[-1]["points"].append(entry)
    doc = {
        "schema": "adfusion.bench.sweep/1",
        "machine": machine_info(),
        "code": code_version(),
        "config": {k: v for k, v in asdict(cfg).items()
                   if k not in ("workers", "scheduler", "progress", "partial", "cache_dir",
                                "keep_partial")},
        "solvers": solver_info,
        "conversion_check": check,
        "campaign": res.info(),
        "sweeps": sweeps,
    }
    doc["summary"] = _summary(doc)
    doc["wall_s"] = round(time.perf_counter() - t_start, 2)
    return doc


def _point(job: Job, sw: Sweep, value: float, cond: Condition,
           chunks: list[dict[str, Any]]) -> dict[str, Any]:
    frames = np.array([f for c in chunks for f in c["frames"]], dtype=np.int64).reshape(-1, 3)
    n_true = frames[:, 0]
    results: dict[str, Any] = {}
    for name in job.solvers:
        trials = [bs.Trial(*r) for c in chunks for r in c["trials"][name]]
        r = bs.aggregate(trials, list_max=10)
        for w in r["wrong_frames"]:  # enough to rebuild the frame: make_frame(seed, index, point)
            w.update(seed=job.seed, point=cond.name)
        results[name] = r
    return {
        "name": cond.name, "value": value, "description": cond.description,
        "params": cond.params(), "trials": len(frames),
        "tolerance_px": _tolerance(job, cond),
        "catalog_stars_per_frame": {
            "median": float(np.median(n_true)), "min": int(n_true.min()),
            "max": int(n_true.max()), "ge3": int((n_true >= 3).sum()),
            "ge4": int((n_true >= 4).sum())},
        "centroids_per_frame_median": float(np.median(frames[:, 1])),
        "results": results,
        "time_ratio_ours_over_peer": bs.time_ratios(
            {k: v for k, v in results.items() if k != "ours_tracking"}),
        "wall_s": round(sum(c["wall_s"] for c in chunks), 2),  # task time, all workers
    }  # fmt: skip


def _summary(doc: dict[str, Any]) -> dict[str, Any]:
    """Wrong attitudes of ours (all of them, with their frames) and every point where a
    peer's availability beats ours."""
    wrong: list[dict[str, Any]] = []
    off_mid: list[dict[str, Any]] = []
    peer_better: list[dict[str, Any]] = []
    worst_bound = {}
    for sw in doc["sweeps"]:
        for p in sw["points"]:
            res = p["results"]
            for name in ("ours", "ours_tracking"):
                if name in res:
                    wrong += [{"solver": name, **w} for w in res[name]["wrong_frames"]]
                    off_mid += [{"solver": name, "point": p["name"],
                                 "seed": doc["config"]["seed"], **w}
                                for w in res[name].get("off_mid_exposure_frames", [])]
                    worst_bound[name] = max(worst_bound.get(name, 0.0),
                                            res[name]["error_rate_upper95_pct"])
            if "ours" not in res:
                continue
            ours = res["ours"]["availability_pct"] or 0.0
            for peer in PEERS:
                if peer in res and (res[peer]["availability_pct"] or 0.0) > ours:
                    peer_better.append({
                        "sweep": sw["name"], "point": p["name"], "peer": peer,
                        "ours_pct": ours, "peer_pct": res[peer]["availability_pct"],
                        "ours_tracking_pct": res.get("ours_tracking", {}).get(
                            "availability_pct")})
    return {"ours_wrong": wrong, "ours_max_error_rate_upper95_pct": worst_bound,
            "ours_off_mid_exposure": off_mid,
            "points_where_a_peer_is_better": peer_better}


# --- output ---------------------------------------------------------------------------------


def _f(x: float | None, fmt: str) -> str:
    return "—" if x is None else format(x, fmt)


def _value(sw: dict[str, Any], v: float) -> str:
    return f"{v * sw['scale']:g}"


def format_table(doc: dict[str, Any]) -> str:
    """The human-readable report of :func:`run_sweep`'s result."""
    cfg, m, c = doc["config"], doc["machine"], doc["campaign"]
    solvers = [s for s in SOLVERS if any(s in p["results"] for sw in doc["sweeps"]
                                         for p in sw["points"])]
    lines = [
        f"Robustness sweeps: {cfg['trials']} trials per point, seed {cfg['seed']}, base "
        f"{cfg['width']}x{cfg['height']} px, FOV {cfg['fov_deg']:g}°, V < "
        f"{cfg['mag_limit']:g}, σ {cfg['sigma_px']:g} px, magnitude noise "
        f"{cfg['mag_noise']:g}; tracking prior σ {cfg['prior_sigma_deg']:g}°",
        f"machine: {m['cpu']} ({m['cores']} cores), Python {m['python']}; {c['backend']} "
        f"with {c['workers']} worker(s), {c['wall_s']:.0f} s"
        + (f"; {c['note']}" if c["note"] else ""),
    ]
    chk = ", ".join(f"{k} {_f(v['max_error_arcsec'], '.2f')}″"
                    f"{'' if v['passed'] else ' FAILED'}"
                    for k, v in doc["conversion_check"].items())
    lines.append(f"conversion check (noise-free frames, max attitude error): {chk}")
    for name, s in doc["solvers"].items():
        if isinstance(s, dict) and s.get("status") == "skipped":
            lines.append(f"  {name}: SKIPPED — {s.get('reason')}")
    short = {"ours": "ours", "ours_tracking": "tracking", "tetra3rs": "tetra3rs",
             "cedar": "cedar"}
    head = f"{'value':<8}" + "".join(f"{short[s]:>20}" for s in solvers) + \
        f"{'ours p50/p95/max ms':>22}"
    for sw in doc["sweeps"]:
        lines += ["", f"{sw['label']} — availability % / 95 % bound of the error rate %",
                  head, "-" * len(head)]
        for p in sw["points"]:
            cells = []
            for s in solvers:
                r = p["results"].get(s)
                cell = "—" if r is None else \
                    f"{_f(r['availability_pct'], '.1f')} / {_f(r['error_rate_upper95_pct'], '.2f')}"
                cells.append(f"{cell:>20}")
            t = p["results"].get("ours", {}).get("time_ms", {})
            tt = f"{_f(t.get('median'), '.2f')}/{_f(t.get('p95'), '.1f')}/" \
                 f"{_f(t.get('max'), '.0f')}"
            lines.append(f"{_value(sw, p['value']):<8}" + "".join(cells) + f"{tt:>22}")
    s = doc["summary"]
    lines.append("")
    lines.append(f"ours: {len(s['ours_wrong'])} wrong attitudes accepted; largest 95 % bound "
                 f"on the error rate {s['ours_max_error_rate_upper95_pct']} %")
    for w in s["ours_wrong"]:
        right = "" if w.get("stars_right") is None else \
            f", {100 * w['stars_right']:.0f} % of {w['n_matches']} matched stars right"
        sig = "" if w.get("error_sigmas") is None else \
            f", {w['error_sigmas']:.1f}σ of its own covariance"
        lines.append(f"  WRONG {w['solver']}: point {w['point']}, seed {w['seed']}, frame "
                     f"{w['index']}, {w['error_deg']}°{right}{sig}")
    if s["ours_off_mid_exposure"]:
        lines.append(f"ours: {len(s['ours_off_mid_exposure'])} streaked frames accepted with the "
                     "attitude of another instant of the exposure (counted correct, listed in "
                     "the JSON: summary.ours_off_mid_exposure)")
    pb = s["points_where_a_peer_is_better"]
    lines.append(f"points where a peer's availability beats ours (lost-in-space): {len(pb)}")
    for b in pb:
        lines.append(f"  {b['point']}: {b['peer']} {b['peer_pct']} % vs ours {b['ours_pct']}"
                     f" % (tracking {b['ours_tracking_pct']} %)")
    lines.append("avail = correct attitude accepted (% of trials); ≤err = one-sided 95 % "
                 "Clopper–Pearson upper bound of the wrong-attitude rate.")
    return "\n".join(lines)


_NAMES = {"ours": "ours (LIS)", "ours_tracking": "ours (tracking)", "tetra3rs": "tetra3rs",
          "cedar": "cedar-solve"}


def markdown_tables(doc: dict[str, Any]) -> str:
    """One markdown table per sweep: availability (and wrong count) per solver, our times.

    >>> "| " in markdown_tables({"sweeps": [], "config": {"trials": 1}})
    False
    """
    out = []
    for sw in doc["sweeps"]:
        solvers = [s for s in SOLVERS if any(s in p["results"] for p in sw["points"])]
        out.append(f"*{sw['label']}* — availability % (wrong attitudes accepted)\n")
        out.append("| " + " | ".join([sw["name"], *[_NAMES[s] for s in solvers],
                                       "ours p50 / p95 / max ms"]) + " |")
        out.append("|" + "---|" * (len(solvers) + 2))
        for p in sw["points"]:
            cells = [_value(sw, p["value"])]
            best_peer = max((p["results"][s]["availability_pct"] or 0.0 for s in PEERS
                             if s in p["results"]), default=None)
            for s in solvers:
                r = p["results"].get(s)
                if r is None:
                    cells.append("—")
                    continue
                a = _f(r["availability_pct"], ".1f")
                if s == "ours" and best_peer is not None and \
                        (r["availability_pct"] or 0.0) < best_peer:
                    a = f"**{a}**"  # a peer is better here
                cells.append(f"{a} ({r['n_wrong']})")
            t = p["results"].get("ours", {}).get("time_ms", {})
            cells.append(f"{_f(t.get('median'), '.2f')} / {_f(t.get('p95'), '.1f')} / "
                         f"{_f(t.get('max'), '.0f')}")
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out)


def write_plots(doc: dict[str, Any], folder: str | Path) -> list[Path]:
    """One PNG per sweep: availability, error rate (with its 95 % bound) and median time
    against the swept variable, every solver. Returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    style = {"ours": ("C0", "o", "-"), "ours_tracking": ("C0", "s", "--"),
             "tetra3rs": ("C1", "^", "-"), "cedar": ("C2", "v", "-")}
    files = []
    for sw in doc["sweeps"]:
        fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
        x = [p["value"] * sw["scale"] for p in sw["points"]]
        for s in SOLVERS:
            if not any(s in p["results"] for p in sw["points"]):
                continue
            col, mk, ls = style[s]
            rs = [p["results"].get(s) for p in sw["points"]]
            kw = {"color": col, "marker": mk, "ls": ls, "label": _NAMES[s]}
            axes[0].plot(x, [math.nan if r is None else r["availability_pct"] for r in rs],
                         **kw)
            axes[1].plot(x, [math.nan if r is None else r["error_rate_pct"] for r in rs],
                         **kw)
            axes[1].plot(x, [math.nan if r is None else r["error_rate_upper95_pct"]
                             for r in rs], color=col, ls=":", lw=1)
            axes[2].plot(x, [math.nan if r is None else r["time_ms"]["median"] for r in rs],
                         **kw)
        axes[0].set_ylabel("availability %")
        axes[0].set_ylim(-2, 102)
        axes[1].set_ylabel("error rate % (dotted: 95 % upper bound)")
        axes[2].set_ylabel("time per solve, median ms")
        axes[2].set_yscale("log")
        for ax in axes:
            ax.set_xlabel(sw["label"])
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=8)
        fig.suptitle(f"{sw['label']}: {doc['config']['trials']} trials per point")
        fig.tight_layout()
        path = out / f"sweep-{sw['name']}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        files.append(path)
    return files


# --- command line ----------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``bench sweep`` options to ``parser``.

    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> p.parse_args(["--quick", "--workers", "2"]).workers
    2
    """
    d = SweepConfig()
    parser.add_argument("--quick", action="store_true",
                        help="24 points instead of 44 (a subset; each still --trials)")
    parser.add_argument("--trials", type=int, default=d.trials,
                        help=f"trials per point (default {d.trials})")
    parser.add_argument("--sweeps", default=",".join(SWEEPS),
                        help="comma-separated subset of: " + ", ".join(SWEEPS))
    parser.add_argument("--solvers", default=",".join(SOLVERS),
                        help="comma-separated subset of: " + ", ".join(SOLVERS))
    parser.add_argument("--seed", type=int, default=d.seed, help="random seed (default 0)")
    parser.add_argument("--workers", type=int, default=None,
                        help="local dask worker processes (default: the CPU count; 0: "
                             "serially in this process)")
    parser.add_argument("--scheduler", default=None, metavar="URL",
                        help="run on an existing dask scheduler, e.g. tcp://host:8786 "
                             "(default: local workers, --workers)")
    parser.add_argument("--chunk", type=int, default=d.chunk,
                        help=f"trials per task (default {d.chunk})")
    parser.add_argument("--prior-sigma", type=float, default=d.prior_sigma_deg,
                        dest="prior_sigma_deg",
                        help=f"tracking prior 1σ, degrees (default {d.prior_sigma_deg:g})")
    parser.add_argument("--exposure", type=float, default=d.exposure_s, dest="exposure_s",
                        help=f"exposure of the rendered frames, s (default {d.exposure_s:g})")
    parser.add_argument("--peer-timeout-ms", type=float, default=d.peer_timeout_ms,
                        help="solve timeout passed to tetra3rs and cedar (default 5000)")
    parser.add_argument("--cache-dir", default=None,
                        help="where the tetra3rs databases and the cedar venv are kept "
                             "(default: the adfusion cache, ~/.cache/adfusion)")
    parser.add_argument("--partial", default=None, metavar="PATH",
                        help="JSON-lines file of finished tasks (default: PATH of --json + "
                             "'.partial.jsonl'); an interrupted run resumes from it, a "
                             "bigger run reuses its finished tasks (same code only)")
    parser.add_argument("--keep-partial", action="store_true",
                        help="keep the partial file after a complete run (e.g. --quick first, "
                             "then the full grid on top of it)")
    parser.add_argument("--json", default=None, metavar="PATH",
                        help="write the results as JSON to PATH (default: the table only)")
    parser.add_argument("--plots", default=None, metavar="DIR",
                        help="write one PNG per sweep into DIR (default: none)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def config_from_args(args: argparse.Namespace) -> SweepConfig:
    """A :class:`SweepConfig` from parsed :func:`add_arguments` options."""
    partial = args.partial or (f"{args.json}.partial.jsonl" if args.json else None)
    return SweepConfig(
        trials=args.trials, quick=args.quick, seed=args.seed,
        sweeps=[s.strip() for s in args.sweeps.split(",") if s.strip()],
        solvers=[s.strip() for s in args.solvers.split(",") if s.strip()],
        prior_sigma_deg=args.prior_sigma_deg, exposure_s=args.exposure_s,
        peer_timeout_ms=args.peer_timeout_ms, chunk=args.chunk, workers=args.workers,
        scheduler=args.scheduler, cache_dir=args.cache_dir, partial=partial,
        keep_partial=args.keep_partial, progress=not args.no_progress,
    )  # fmt: skip


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Run from parsed options: estimate first, then the table; JSON and plots per options."""
    import os

    cfg = config_from_args(args)
    workers = cfg.workers if cfg.workers is not None else (os.cpu_count() or 1)
    pts = points(cfg)
    est = estimate_seconds(cfg, max(1, workers) if not cfg.scheduler else 1)
    msg = (f"bench sweep: {len(pts)} points × {cfg.trials} trials; estimated "
           f"{est / 60:.0f} min on {'the scheduler' if cfg.scheduler else f'{workers} worker(s)'}"
           f" of this workplace's 2-core VM")
    if not cfg.quick:
        quick = SweepConfig(**{**asdict(cfg), "quick": True})
        msg += f" (--quick: {len(points(quick))} points, ~{estimate_seconds(quick, max(1, workers)) / 60:.0f} min)"  # noqa: E501
    print(msg, file=sys.stderr)
    doc = run_sweep(cfg)
    print(format_table(doc))
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=1) + "\n")
    if args.plots:
        files = write_plots(doc, args.plots)
        print(f"plots: {', '.join(str(f) for f in files)}")
    return doc


def cli(args: argparse.Namespace) -> int:
    """``adfusion bench sweep``: :func:`run`, with errors as a message and exit status 2."""
    try:
        run(args)
    except (ValueError, campaign.CampaignError) as e:
        print(f"adfusion bench sweep: error: {e}", file=sys.stderr)
        return 2
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m adfusion.bench.sweep [options]``."""
    p = argparse.ArgumentParser(prog="adfusion bench sweep",
                                description="Robustness sweeps: ours vs tetra3rs vs "
                                            "cedar-solve, on dask.distributed.")
    add_arguments(p)
    return cli(p.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
