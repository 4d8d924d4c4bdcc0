"""Start-up of `adfusion solve` on one real frame: cold, then warm (issue 14, item 5).

Runs ``adfusion solve FRAME --fov 11.4 --fov-error 0.5`` ``--runs`` times in fresh
processes against one empty cache directory and reports each call's wall time and how
many pattern indexes the cache holds afterwards (the epoch defaults to "now", different
on every call). Then, in one process, the phases of a warm call: the imports, reading
and detecting, the catalogue, the index load, ``Solver.warm_up`` (numba kernels loaded
from their cache) and the solve, each in wall and CPU ms.

Usage (from the repository root)::

    python -P benchmarks/bench_startup.py [--runs 5] [--json] [--frame PATH]

Example:
    >>> sorted(phases(None))[:3]
    ['catalogue', 'detect', 'import adfusion.starid']
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_FRAME = (ROOT.parent / "shared" / "data" / "real-images"
                 / "2019-07-29T204726_Alt40_Azi135_Try1.tiff")


def phases(frame: Path | None) -> dict[str, dict[str, float]]:
    """Wall and CPU ms of each start-up phase in this process (``frame=None``: only the
    imports; the rest reported as 0)."""
    out: dict[str, dict[str, float]] = {}
    t, c = time.perf_counter(), time.process_time()

    def lap(name: str) -> None:
        nonlocal t, c
        t2, c2 = time.perf_counter(), time.process_time()
        out[name] = {"wall_ms": round((t2 - t) * 1e3, 1), "cpu_ms": round((c2 - c) * 1e3, 1)}
        t, c = t2, c2

    import numpy  # noqa: F401

    lap("import numpy")
    from adfusion import starid

    lap("import adfusion.starid")
    from adfusion.starid import solver  # noqa: F401  (numba, scipy.spatial)

    lap("import the solver")
    if frame is None:
        for k in ("detect", "catalogue", "index load", "warm_up (kernels)", "solve"):
            out[k] = {"wall_ms": 0.0, "cpu_ms": 0.0}
        return out
    cam = starid.Camera.pinhole(1024, 768, 11.4)
    det = starid.detect(frame, cam)
    lap("detect")
    cat = starid.Catalog.hipparcos(mag_limit=6.5, epoch=2026.9)
    lap("catalogue")
    s = starid.Solver(cat, cam, fov_error_deg=0.5)
    lap("index load")
    s.warm_up()
    lap("warm_up (kernels)")
    assert s.solve(det).ok
    lap("solve")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--frame", type=Path, default=DEFAULT_FRAME)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--phases", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.phases:
        print(json.dumps(phases(args.frame)))
        return 0
    if not args.frame.is_file():
        print(f"no frame at {args.frame}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "ADFUSION_CACHE_DIR": cache}
        calls = []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            r = subprocess.run([sys.executable, "-P", "-m", "adfusion.app.cli", "solve",
                                str(args.frame), "--fov", "11.4", "--fov-error", "0.5",
                                "--json"], env=env, capture_output=True, text=True,
                               check=False)
            wall = time.perf_counter() - t0
            ok = r.returncode == 0 and json.loads(r.stdout)["ok"]
            n_idx = len(list(Path(cache).glob("pattern-index-*.npz")))
            calls.append({"wall_s": round(wall, 3), "ok": ok, "pattern_indexes": n_idx})
        ph = subprocess.run([sys.executable, "-P", __file__, "--phases", "--frame",
                             str(args.frame)], env=env, capture_output=True, text=True,
                            check=True)
    report = {"load_avg_1min": round(os.getloadavg()[0], 2), "calls": calls,
              "warm_median_s": round(statistics.median(c["wall_s"] for c in calls[1:]), 3)
              if len(calls) > 1 else None,
              "phases_warm": json.loads(ph.stdout)}
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    for k, c in enumerate(calls):
        print(f"call {k + 1}: {c['wall_s']:.2f} s wall, ok {c['ok']}, "
              f"{c['pattern_indexes']} pattern index(es) in the cache")
    print(f"warm median {report['warm_median_s']} s (load {report['load_avg_1min']})")
    for name, v in report["phases_warm"].items():
        print(f"  {name:24s} {v['wall_ms']:8.1f} ms wall {v['cpu_ms']:8.1f} ms CPU")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
