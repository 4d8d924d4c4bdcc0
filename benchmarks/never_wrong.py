"""The "never wrong" check at full size: frames of random detections must never solve.

10 000 frames (default) of 3–30 detections placed uniformly at random in a 1024×768,
15° frame, against Hipparcos to V 6.0. Any ``ok`` is a false identification. Prints JSON
with the count, the largest reported p_false among rejections, and time per frame.

    python benchmarks/never_wrong.py [--frames 10000] [--workers 2] [--json FILE]

``--json`` also writes the document (with the machine and the commit) to FILE, e.g.
``benchmarks/results/never_wrong.json`` for ``benchmarks/figures.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np


def run_chunk(job: tuple[int, int, float, float]) -> dict:
    from adfusion import starid
    seed, n_frames, fov, mag = job
    cat = starid.Catalog.hipparcos(mag_limit=mag, epoch=2025.0)
    cam = starid.Camera.pinhole(1024, 768, fov)
    solver = starid.Solver(cat, cam)
    rng = np.random.default_rng(seed)
    accepted, times = 0, []
    for _ in range(n_frames):
        n = int(rng.integers(3, 31))
        xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], (n, 2))
        sol = solver.solve(xy)
        accepted += sol.ok
        times.append(sol.time_s)
    return {"frames": n_frames, "accepted": accepted, "times": times}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=10_000)
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--fov", type=float, default=15.0)
    p.add_argument("--mag-limit", type=float, default=6.0)
    p.add_argument("--json", metavar="FILE", help="also write the document to FILE")
    args = p.parse_args(argv)
    chunks = max(args.workers * 4, 1)
    per = [args.frames // chunks + (k < args.frames % chunks) for k in range(chunks)]
    jobs = [(args.seed * 1000 + k, n, args.fov, args.mag_limit) for k, n in enumerate(per)]
    t0 = time.time()
    with ProcessPoolExecutor(args.workers) as pool:
        res = list(pool.map(run_chunk, jobs))
    times = np.concatenate([r["times"] for r in res]) * 1e3
    accepted = sum(r["accepted"] for r in res)
    from adfusion.bench.machine import code_version, machine_info

    doc = {
        "frames": int(sum(r["frames"] for r in res)), "accepted": int(accepted),
        "ms_median": round(float(np.median(times)), 2),
        "ms_p95": round(float(np.percentile(times, 95)), 2),
        "ms_max": round(float(times.max()), 2), "wall_s": round(time.time() - t0, 1),
        "config": {"workers": args.workers, "seed": args.seed, "fov_deg": args.fov,
                   "mag_limit": args.mag_limit},
        "machine": machine_info(), "code": code_version(),
    }
    text = json.dumps(doc, indent=2)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text + "\n")
    return 1 if accepted else 0


if __name__ == "__main__":
    sys.exit(main())
