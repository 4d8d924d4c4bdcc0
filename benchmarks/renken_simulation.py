"""Renken (1998) §8 reproduced: η and multiple matches for every (magnitude limit, tolerance).

His full simulation grid — 7 catalogues (V < 3.0 … 6.0) × 3 pair tolerances (0.1°, 0.2°,
0.3°), 2000 frames each, his 384×288 camera at 0.051°/px
(``adfusion.bench.renken_sim.simulate_cell``:
Eq. 8.1 attitudes, equidistant projection, SAO-count-matched Hipparcos merged at 2 px) —
printed as a markdown table next to his published figures (Renken 1998 §8, from Tab.
8.1–8.28): η, the multiple-match rate and the share of frames with fewer than 3 stars.

Multiple matches are counted as he does: ``matching_counter ≥ 2`` over *all* frames,
including the 2-star frames, whose "pattern" is one pair (every catalogue pair inside the
distance window is a match); ``simulate_cell`` stops at < 3 stars, so the 2-star frames are
counted here (:func:`two_star_counts`) on the same attitudes.

The cells run as a campaign on ``dask.distributed`` (:mod:`adfusion.bench.campaign`): tasks are
(cell, chunk of frames), each chunk seeded from ``(seed, cell, chunk)``, so the table is the
same for any number of workers; ``--workers 0`` runs serially without dask.

    python benchmarks/renken_simulation.py                    # full grid, 2000 frames/cell
    python benchmarks/renken_simulation.py --frames 200       # quick look
    python benchmarks/renken_simulation.py --json out.json --markdown table.md
    python benchmarks/renken_simulation.py --scheduler tcp://host:8786

Example (one small cell, in-process):
    >>> doc = run(frames=20, cells=[(5.4, 0.1)], workers=0, progress=False)
    >>> c = doc["cells"][0]
    >>> c["frames"], c["wrong_unique"], 0 <= c["eta"] <= 100
    (20, 0, True)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from adfusion.bench import campaign
from adfusion.bench.renken_sim import PUBLISHED_ETA, eq_8_1_attitudes, renken_catalog, simulate_cell
from adfusion.maths import rotations as rot

TOLERANCES = (0.1, 0.2, 0.3)

#: Renken 1998 §8 (from Tab. 8.1–8.21), counts of 2000 frames per cell:
#: (number_is < 3, matching_counter = 0, = 1, ≥ 2, clear_3_axis = η·2000)
PUBLISHED_COUNTS: dict[tuple[float, float], tuple[int, int, int, int, int]] = {
    (3.0, 0.1): (1851, 1639, 173, 188, 146), (3.0, 0.2): (1855, 1653, 158, 189, 143),
    (3.0, 0.3): (1859, 1639, 132, 229, 130), (4.0, 0.1): (1064, 619, 912, 469, 884),
    (4.0, 0.2): (1079, 622, 756, 622, 752), (4.0, 0.3): (1147, 668, 585, 747, 580),
    (4.5, 0.1): (418, 160, 1454, 386, 1439), (4.5, 0.2): (419, 184, 1294, 522, 1292),
    (4.5, 0.3): (420, 191, 1172, 637, 1172), (5.0, 0.1): (54, 12, 1882, 106, 1879),
    (5.0, 0.2): (48, 8, 1794, 198, 1786), (5.0, 0.3): (53, 16, 1677, 307, 1676),
    (5.4, 0.1): (0, 0, 1994, 6, 1994), (5.4, 0.2): (0, 0, 1926, 74, 1926),
    (5.4, 0.3): (0, 0, 1773, 227, 1773), (5.7, 0.1): (0, 0, 1992, 8, 1992),
    (5.7, 0.2): (0, 0, 1882, 118, 1881), (5.7, 0.3): (0, 0, 1625, 375, 1625),
    (6.0, 0.1): (0, 0, 1989, 11, 1983), (6.0, 0.2): (0, 0, 1838, 162, 1838),
    (6.0, 0.3): (0, 0, 1391, 609, 1391),
}
_FIELDS = ("clear", "fewer_than_3", "miss", "unique", "multiple", "wrong_unique", "critical",
           "two_star", "two_star_mc0", "two_star_mc1", "two_star_multiple")


def _catalog_and_index(mag: float, merge_px: float):
    """The cell's catalogue and pattern index, built once per worker process."""
    from adfusion.starid.catalog.pair_index import PatternIndex

    def build():
        cat = renken_catalog(mag, merge_px=merge_px)
        return cat, PatternIndex.from_vectors(cat.vectors, np.radians(25.0))

    return campaign.worker_memo(("renken", mag, merge_px), build)


def two_star_counts(catalog, index, tol_deg: float, n_frames: int, seed: int) -> dict[str, int]:
    """``matching_counter`` of the frames with exactly two stars, on the attitudes
    ``simulate_cell(…, n_frames, seed)`` draws: the catalogue pairs whose separation lies
    within ``tol_deg`` of the image pair's (linear pixel angle, 0.1 px centroids).

    >>> from adfusion.starid.catalog.pair_index import PatternIndex
    >>> cat = renken_catalog(3.0)
    >>> idx = PatternIndex.from_vectors(cat.vectors, np.radians(25.0))
    >>> c = two_star_counts(cat, idx, 0.1, 50, seed=1)
    >>> c["two_star"] == c["two_star_mc0"] + c["two_star_mc1"] + c["two_star_multiple"]
    True
    """
    from adfusion.starid.camera.model import Camera
    from adfusion.starid.camera.view import stars_in_view

    cam = Camera.renken()
    app, tol = np.radians(0.051), np.radians(tol_deg)
    out = dict.fromkeys(("two_star", "two_star_mc0", "two_star_mc1", "two_star_multiple"), 0)
    for a, d, w in eq_8_1_attitudes(np.random.default_rng(seed), n_frames):
        stars, xy = stars_in_view(catalog, cam, rot.q_cam_icrs_from_radec_roll(a, d, w))
        if len(stars) != 2:
            continue
        xy = np.round(xy, 1)
        ang = app * float(np.hypot(*(xy[1] - xy[0])))
        i, _ = index.pairs_in_window(np.cos(ang + tol), np.cos(max(ang - tol, 0.0)))
        mc = len(i)
        out["two_star"] += 1
        out["two_star_mc0" if mc == 0 else "two_star_mc1" if mc == 1
            else "two_star_multiple"] += 1
    return out


def run_chunk(payload: tuple[float, float, int, int, float, str]) -> dict[str, int]:
    """Campaign task: one chunk of one cell (counts; ``frames`` frames from ``seed``; the
    last item, the code's digest, only keeps a partial file from outliving the code)."""
    mag, tol, frames, seed, merge_px, _ = payload
    cat, index = _catalog_and_index(mag, merge_px)
    cell = simulate_cell(cat, mag, tol, frames, seed, index=index)
    out = {k: v for k, v in asdict(cell).items() if k in _FIELDS}
    out.update(two_star_counts(cat, index, tol, frames, seed))
    return out


def _chunk_seed(seed: int, cell: int, chunk: int) -> int:
    return int(np.random.SeedSequence([seed, cell, chunk]).generate_state(1)[0])


def run(frames: int = 2000, seed: int = 1998, merge_px: float = 2.0, chunk: int = 250,
        cells: list[tuple[float, float]] | None = None, workers: int | None = None,
        scheduler: str | None = None, partial: str | None = None,
        progress: bool = True) -> dict[str, Any]:
    """Run the grid as a campaign; the result document (counts, η, published figures)."""
    grid = cells or [(m, t) for m in PUBLISHED_ETA for t in TOLERANCES]
    code = campaign.source_digest("adfusion.starid")
    tasks = []
    for k, (mag, tol) in enumerate(grid):
        for j, start in enumerate(range(0, frames, chunk)):
            n = min(chunk, frames - start)
            tasks.append(campaign.Task(f"{mag}/{tol}/{j}",
                                       (mag, tol, n, _chunk_seed(seed, k, j), merge_px, code),
                                       n))
    res = campaign.run_campaign(run_chunk, tasks, workers=workers, scheduler=scheduler,
                                partial=partial, progress=progress, desc="renken §8",
                                unit="frame")
    out = []
    for mag, tol in grid:
        tot = dict.fromkeys(_FIELDS, 0)
        for t in tasks:
            if t.payload[:2] == (mag, tol):
                for f in _FIELDS:
                    tot[f] += res.results[t.key][f]
        few, miss, mc1, multi, clear = PUBLISHED_COUNTS[(mag, tol)]
        n01 = tot["fewer_than_3"] - tot["two_star"]
        out.append({
            "mag_limit": mag, "tol_deg": tol, "frames": frames, **tot,
            "eta": 100.0 * tot["clear"] / frames,
            # his definitions, over all frames (0/1-star frames have matching_counter 0)
            "multiple_pct": 100.0 * (tot["multiple"] + tot["two_star_multiple"]) / frames,
            "miss_pct": 100.0 * (tot["miss"] + tot["two_star_mc0"] + n01) / frames,
            "fewer_than_3_pct": 100.0 * tot["fewer_than_3"] / frames,
            "published": {"eta": 100.0 * clear / 2000, "multiple_pct": 100.0 * multi / 2000,
                          "miss_pct": 100.0 * miss / 2000, "mc1_pct": 100.0 * mc1 / 2000,
                          "fewer_than_3_pct": 100.0 * few / 2000},
        })
    return {"schema": "adfusion.bench.renken/1", "frames": frames, "seed": seed,
            "merge_px": merge_px, "chunk": chunk, "campaign": res.info(), "cells": out}


def markdown(doc: dict[str, Any]) -> str:
    """The side-by-side table (ours vs Renken's Tab. 8.1–8.28), markdown.

    >>> doc = {"cells": [{"mag_limit": 5.4, "tol_deg": 0.1, "eta": 99.6, "multiple_pct": 0.3,
    ...          "fewer_than_3_pct": 0.0, "wrong_unique": 0, "published": {"eta": 99.7,
    ...          "multiple_pct": 0.3, "fewer_than_3_pct": 0.0}}]}
    >>> markdown(doc).splitlines()[2]
    '| < 5.4 | 0.1° | 99.70 | 99.60 | -0.10 | 0.30 | 0.30 | 0.00 | 0.00 | 0 |'
    """
    lines = ["| mag limit | tol | η thesis % | η ours % | Δ pp | multiple thesis % | "
             "multiple ours % | <3 stars thesis % | <3 stars ours % | wrong unique |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for c in doc["cells"]:
        p = c["published"]
        lines.append(
            f"| < {c['mag_limit']} | {c['tol_deg']}° | {p['eta']:.2f} | {c['eta']:.2f} | "
            f"{c['eta'] - p['eta']:+.2f} | {p['multiple_pct']:.2f} | {c['multiple_pct']:.2f} "
            f"| {p['fewer_than_3_pct']:.2f} | {c['fewer_than_3_pct']:.2f} | "
            f"{c['wrong_unique']} |")
    return "\n".join(lines)


def worst_delta(doc: dict[str, Any], min_eta: float = 85.0) -> float:
    """Largest |Δη| (pp) over the cells where the thesis has η ≥ ``min_eta``."""
    return max((abs(c["eta"] - c["published"]["eta"]) for c in doc["cells"]
                if c["published"]["eta"] >= min_eta), default=0.0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=2000, help="frames per cell (default 2000)")
    p.add_argument("--seed", type=int, default=1998)
    p.add_argument("--merge-px", type=float, default=2.0)
    p.add_argument("--chunk", type=int, default=250, help="frames per task (default 250)")
    p.add_argument("--workers", type=int, default=None,
                   help="local dask workers (default: the CPU count; 0: serial, no dask)")
    p.add_argument("--scheduler", metavar="URL", help="an existing dask scheduler")
    p.add_argument("--partial", metavar="PATH",
                   help="finished chunks, resumed by a rerun (default: --json PATH + "
                        "'.partial.jsonl')")
    p.add_argument("--json", metavar="PATH")
    p.add_argument("--markdown", metavar="PATH", help="also write the table to PATH")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    t0 = time.time()
    doc = run(args.frames, args.seed, args.merge_px, args.chunk, workers=args.workers,
              scheduler=args.scheduler,
              partial=args.partial or (f"{args.json}.partial.jsonl" if args.json else None),
              progress=not args.no_progress)
    c = doc["campaign"]
    print(f"Renken §8 simulation: {args.frames} frames per cell, Eq. 8.1 attitudes, "
          f"equidistant 384×288 camera at 0.051°/px, SAO-count-matched Hipparcos merged at "
          f"{args.merge_px} px; {time.time() - t0:.0f} s, {c['backend']} with {c['workers']} "
          f"worker(s) on {os.cpu_count()} cores\n")
    table = markdown(doc)
    print(table)
    print(f"\nlargest |Δη| where the thesis has η ≥ 85 %: {worst_delta(doc):.2f} pp")
    if args.markdown:
        Path(args.markdown).write_text(table + "\n")
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
