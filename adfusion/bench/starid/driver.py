"""The run of ``adfusion bench starid``: its configuration, the driver and the command line.

:class:`BenchConfig` is everything that determines a run; :func:`run_benchmark` makes the
frames of each condition, has every solver solve them interleaved frame by frame and returns
the result document; :func:`add_arguments`, :func:`config_from_args`, :func:`run` and
:func:`main` are the command line (``adfusion bench starid``,
``python -m adfusion.bench.starid``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from adfusion.bench.machine import code_version, machine_info
from adfusion.bench.starid.frames import (
    CONDITIONS,
    Frame,
    FrameModel,
    camera_for,
    load_catalog,
    make_frame,
)
from adfusion.bench.starid.peers import (
    METHOD_SOLVERS,
    SOLVER_NAMES,
    Outcome,
    cache_root,
    conversion_check,
    make_adapters,
)
from adfusion.bench.starid.report import _hot_figures, format_table, summarize, time_ratios

# --- configuration -----------------------------------------------------------------------


@dataclass
class BenchConfig(FrameModel):
    """Everything that determines a run (recorded in the JSON)."""

    frames: int = 200
    per_frame: bool = False
    conditions: list[str] = field(default_factory=lambda: list(CONDITIONS))
    solvers: list[str] = field(default_factory=lambda: list(SOLVER_NAMES))
    peer_timeout_ms: float = 5000.0
    cache_dir: str | None = None
    progress: bool = True
    #: each frame solved this many more times by each in-process solver after every
    #: solver's first solve, the last of them timed: the solve with its code and data in
    #: the caches ("hot"), beside the first ("cold", the table's times); 0: not measured
    hot_repeats: int = 0


# --- the run -----------------------------------------------------------------------------


def run_benchmark(cfg: BenchConfig) -> dict[str, Any]:
    """Run the benchmark and return the result document (no printing except progress).

    >>> res = run_benchmark(BenchConfig(frames=2, conditions=["clean"], solvers=["ours"],
    ...                                 progress=False))
    >>> sorted(res)
    ['code', 'conditions', 'config', 'conversion_check', 'machine', 'schema', 'solvers', 'wall_s']
    """
    from tqdm import tqdm

    from adfusion import starid
    unknown = [c for c in cfg.conditions if c not in CONDITIONS]
    if unknown:
        raise ValueError(f"unknown condition(s) {unknown}; choose from {list(CONDITIONS)}")
    if cfg.frames < 1:
        raise ValueError("frames must be ≥ 1")
    t_start = time.perf_counter()
    camera = starid.Camera.pinhole(cfg.width, cfg.height, fov_x_deg=cfg.fov_deg)
    cache, tmp = cache_root(cfg)
    adapters, skipped = make_adapters(cfg, camera, cache)
    try:
        check = conversion_check(adapters, cfg, camera)
        conds = [CONDITIONS[c].resolved(cfg.sigma_px, cfg.mag_limit) for c in cfg.conditions]
        results = []
        bar = tqdm(total=cfg.frames * len(conds), file=sys.stderr, unit="frame",
                   disable=None if cfg.progress else True, desc="bench starid")
        for cond in conds:
            assert cond.mag_limit is not None
            cat = load_catalog(cond.mag_limit, cfg.epoch)
            cam = camera_for(cond, cfg.width, cfg.height, cfg.fov_deg)
            for a in adapters:
                a.setup(cond, cam)
            frames: list[Frame] = []
            outcomes: dict[str, list[Outcome]] = {a.name: [] for a in adapters}
            hot: dict[str, list[float | None]] = {a.name: [] for a in adapters}
            bar.set_postfix_str(cond.name)
            for i in range(cfg.frames):
                f = make_frame(cat, cam, cond, cfg.seed, i, cfg.mag_noise)
                frames.append(f)
                for a in adapters:
                    outcomes[a.name].append(a.solve(f))
                if cfg.hot_repeats > 0:
                    for a in adapters:
                        if outcomes[a.name][-1].cpu_s is None:
                            continue  # another process's solver (cedar): no CPU time here
                        for _ in range(cfg.hot_repeats):
                            o = a.solve(f)
                        hot[a.name].append(o.cpu_s)
                bar.update(1)
            tol = max(cfg.tol_px, cfg.tol_sigma * float(cond.sigma_px or 0.0))
            per = {name: summarize(frames, o, cam, tol, per_frame=cfg.per_frame)
                   for name, o in outcomes.items()}
            n_true = np.array([f.n_true for f in frames])
            entry: dict[str, Any] = {
                "name": cond.name, "description": cond.description,
                "params": cond.params(),
                "frames": cfg.frames,
                "tolerance_px": tol,
                "catalog_stars_per_frame": {
                    "median": float(np.median(n_true)), "min": int(n_true.min()),
                    "max": int(n_true.max()), "ge3": int((n_true >= 3).sum()),
                    "ge4": int((n_true >= 4).sum())},
                "centroids_per_frame_median": float(np.median([len(f.xy) for f in frames])),
                "solver_params": {a.name: a.params() for a in adapters},
                "results": per,
                "time_ratio_ours_over_peer": time_ratios(per),
                # in-process solvers' CPU time (a loaded machine's other processes left out)
                "cpu_ratio_ours_over_peer": time_ratios(per, "cpu_time_ms"),
                "cpu_p95_ratio_ours_over_peer": time_ratios(per, "cpu_time_ms", "p95"),
            }  # fmt: skip
            if cfg.hot_repeats > 0:
                entry.update(_hot_figures(hot))
            results.append(entry)
        bar.close()
    finally:
        for a in adapters:
            a.close()
        if tmp is not None:
            tmp.cleanup()
    solvers = {a.name: a.info() for a in adapters}
    solvers.update(skipped)
    doc = {
        "schema": "adfusion.bench.starid/1",
        "machine": machine_info(),
        "code": code_version(),
        "config": asdict(cfg),
        "solvers": {name: solvers[name] for name in cfg.solvers if name in solvers},
        "conversion_check": check,
        "conditions": results,
        "wall_s": round(time.perf_counter() - t_start, 2),
    }
    return doc


# --- command line --------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``bench starid`` options to ``parser``.

    >>> p = argparse.ArgumentParser()
    >>> add_arguments(p)
    >>> p.parse_args(["--json"]).json
    '-'
    """
    d = BenchConfig()
    parser.add_argument("--frames", type=int, default=d.frames,
                        help=f"frames per condition (default {d.frames})")
    parser.add_argument("--seed", type=int, default=d.seed, help="random seed (default 0)")
    parser.add_argument("--width", type=int, default=d.width, help="image width, px")
    parser.add_argument("--height", type=int, default=d.height, help="image height, px")
    parser.add_argument("--fov", type=float, default=d.fov_deg, dest="fov_deg",
                        help=f"horizontal FOV, degrees (default {d.fov_deg:g})")
    parser.add_argument("--mag-limit", type=float, default=d.mag_limit,
                        help=f"visible stars V < this (default {d.mag_limit:g})")
    parser.add_argument("--sigma", type=float, default=d.sigma_px, dest="sigma_px",
                        help=f"base centroid noise σ, px (default {d.sigma_px:g})")
    parser.add_argument("--mag-noise", type=float, default=d.mag_noise,
                        help=f"magnitude noise σ for the ordering (default {d.mag_noise:g})")
    parser.add_argument("--tol-px", type=float, default=d.tol_px,
                        help="largest shift of the frame's corners/centre (px) for an "
                             f"attitude to count as correct (default {d.tol_px:g})")
    parser.add_argument("--tol-sigma", type=float, default=d.tol_sigma,
                        help="... or this many centroid σ, if larger (default "
                             f"{d.tol_sigma:g})")
    parser.add_argument("--per-frame", action="store_true",
                        help="add per-frame outcomes (correct, error, time) to the JSON")
    parser.add_argument("--conditions", default=",".join(CONDITIONS),
                        help="comma-separated subset of: " + ", ".join(CONDITIONS))
    parser.add_argument("--solvers", default=",".join(SOLVER_NAMES),
                        help="comma-separated subset of: " + ", ".join(SOLVER_NAMES))
    parser.add_argument("--methods", default=None, metavar="LIST",
                        help="our matchers to compare, comma-separated subset of nstar, "
                             "triad, bleif (runs these instead of --solvers' 'ours'; the "
                             "peers only when --solvers names them; default: --solvers as given)")
    parser.add_argument("--peer-timeout-ms", type=float, default=d.peer_timeout_ms,
                        help="solve timeout passed to tetra3rs and cedar (default 5000)")
    parser.add_argument("--cache-dir", default=None,
                        help="where the tetra3rs database and the cedar venv are kept "
                             "(default: the adfusion cache, ~/.cache/adfusion)")
    parser.add_argument("--json", nargs="?", const="-", default=None, metavar="PATH",
                        help="write the results as JSON to PATH (or to stdout instead of "
                             "the table when no PATH is given; default: the table only)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--hot", type=int, default=0, metavar="N", dest="hot_repeats",
                        help="also solve each frame N more times per in-process solver and "
                             "report the last one's CPU time (code and data in the caches; "
                             "the main times stay each frame's first solve)")


def config_from_args(args: argparse.Namespace) -> BenchConfig:
    """A :class:`BenchConfig` from parsed :func:`add_arguments` options."""
    return BenchConfig(
        frames=args.frames, seed=args.seed, width=args.width, height=args.height,
        fov_deg=args.fov_deg, mag_limit=args.mag_limit, sigma_px=args.sigma_px,
        mag_noise=args.mag_noise, tol_px=args.tol_px, tol_sigma=args.tol_sigma,
        per_frame=args.per_frame,
        conditions=[c.strip() for c in args.conditions.split(",") if c.strip()],
        solvers=_solver_names(args),
        peer_timeout_ms=args.peer_timeout_ms, cache_dir=args.cache_dir,
        progress=not args.no_progress, hot_repeats=getattr(args, "hot_repeats", 0),
    )  # fmt: skip


def _solver_names(args: argparse.Namespace) -> list[str]:
    """``--solvers``, with ``--methods`` (if given) in place of ``ours`` and the default
    peers left out."""
    named = [s.strip() for s in args.solvers.split(",") if s.strip()]
    methods = getattr(args, "methods", None)
    if not methods:
        return named
    out = []
    for m in (x.strip() for x in methods.split(",") if x.strip()):
        if m not in METHOD_SOLVERS:
            raise ValueError(f"--methods: unknown method {m!r} (choose from "
                             f"{', '.join(METHOD_SOLVERS)})")
        out.append(METHOD_SOLVERS[m])
    explicit = args.solvers != ",".join(SOLVER_NAMES)
    return out + [s for s in named if explicit and s != "ours"]


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Run from parsed options: the table on stdout, JSON per ``--json``; returns the result."""
    doc = run_benchmark(config_from_args(args))
    text = json.dumps(doc, indent=2)
    if args.json == "-":
        print(text)
    else:
        print(format_table(doc))
        if args.json:
            Path(args.json).write_text(text + "\n")
    return doc


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m adfusion.bench.starid [options]``."""
    p = argparse.ArgumentParser(prog="adfusion bench starid",
                                description="Lost-in-space star identification benchmark: "
                                            "ours vs tetra3rs vs cedar-solve.")
    add_arguments(p)
    args = p.parse_args(argv)
    try:
        run(args)
    except ValueError as e:
        print(f"adfusion bench starid: error: {e}", file=sys.stderr)
        return 2
    return 0
