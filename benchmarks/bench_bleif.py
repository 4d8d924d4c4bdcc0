"""Bleif's MusterPr matcher at full size: synthetic lost-in-space on the thesis camera.

Random attitudes over the sky; the stars ≤ ``--mag-limit`` in the 22.0° × 16.8° frame
(k_x = 0.0292, k_y = 0.0282 °/px) are projected, ``n`` of them marked (the reference the
star nearest the centre, the others the brightest) with clicks off by up to ±3 px
(uniform in a disc). Per marked-star count: how often the truth (right reference, attitude
within 2°) is among the candidates, the candidate-count distribution, the share with a
unique candidate, the truth's rank, and the time per search. Also the pattern catalogue's
build and load times (docs/references.md#bleif-2004). Single process (the machine is shared).

    python benchmarks/bench_bleif.py [--trials 500] [--out benchmarks/results/bleif.json]
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
from adfusion.starid.bleif.matcher import find_matches, stars_in_frame, tubsat_camera
from adfusion.starid.bleif.patterns import PatternCatalog
from adfusion.starid.catalog.stars import Catalog

from adfusion.bench.machine import machine_info
from adfusion.maths import rotations as rot


def trial(pc, cam, rng, n, mag_limit, noise_px):
    while True:
        q = rot.q_cam_icrs_from_radec_roll(rng.uniform(0, 2 * np.pi),
                                           np.arcsin(rng.uniform(-1, 1)),
                                           rng.uniform(0, 2 * np.pi))
        xy, idx = stars_in_frame(pc, cam, q)
        keep = pc.mag[idx] <= mag_limit
        xy, idx = xy[keep], idx[keep]
        if len(xy) >= n:
            break
    c = int(np.argmin(np.hypot(*(xy - cam.K[:2, 2]).T)))
    sel = [c, *[k for k in range(len(xy)) if k != c][: n - 1]]
    r = noise_px * np.sqrt(rng.uniform(0, 1, n))
    th = rng.uniform(0, 2 * np.pi, n)
    clicks = xy[sel] + np.c_[r * np.cos(th), r * np.sin(th)]
    t0 = time.perf_counter()
    cands = list(find_matches(pc, clicks, cam))
    dt = time.perf_counter() - t0
    rank = next((k + 1 for k, cd in enumerate(cands) if cd.pattern == int(idx[c])
                 and math.degrees(rot.angle_between(cd.q_cam_icrs, q)) < 2.0), None)
    return len(cands), rank, dt


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=500, help="per marked-star count")
    p.add_argument("--counts", default="4,5,6,7,8,10")
    p.add_argument("--mag-limit", type=float, default=5.0)
    p.add_argument("--noise-px", type=float, default=3.0)
    p.add_argument("--seed", type=int, default=18)
    p.add_argument("--out", default="benchmarks/results/bleif.json")
    args = p.parse_args(argv)
    cat = Catalog.hipparcos(mag_limit=6.5)
    t0 = time.perf_counter()
    pc = PatternCatalog.build(cat, cache=False)
    build_s = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "patterns.npz"
        pc.save(path)
        t0 = time.perf_counter()
        PatternCatalog.load(path)
        load_s = time.perf_counter() - t0
    cam = tubsat_camera()
    rng = np.random.default_rng(args.seed)
    out = {"machine": machine_info(), "catalogue": {
        "patterns": len(pc), "mean_size": float(pc.size.mean()),
        "capped": int((pc.size == 150).sum()), "build_s": round(build_s, 3),
        "load_s": round(load_s, 4)}, "mag_limit": args.mag_limit,
        "noise_px": args.noise_px, "by_marked_stars": {}}
    for n in [int(x) for x in args.counts.split(",")]:
        res = [trial(pc, cam, rng, n, args.mag_limit, args.noise_px)
               for _ in range(args.trials)]
        counts = np.array([r[0] for r in res])
        ranks = [r[1] for r in res]
        ms = np.array([r[2] for r in res]) * 1e3
        out["by_marked_stars"][str(n)] = {
            "trials": args.trials,
            "truth_found": round(float(np.mean([r is not None for r in ranks])), 4),
            "unique": round(float(np.mean(counts == 1)), 4),
            "candidates_median": float(np.median(counts)),
            "candidates_max": int(counts.max()),
            "candidates_hist": {str(k): v for k, v in sorted(Counter(counts.tolist()).items())},
            "truth_rank_hist": {str(k): v for k, v in sorted(Counter(
                [r for r in ranks if r is not None]).items())},
            "ms_median": round(float(np.median(ms)), 1),
            "ms_p95": round(float(np.percentile(ms, 95)), 1)}
        print(n, json.dumps(out["by_marked_stars"][str(n)]), flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out["catalogue"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
