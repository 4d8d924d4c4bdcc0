"""Deep catalogues for narrow fields: index build time, peak memory, solve time.

Case (issue 14, item 4): a 6°×4.5° camera (1280×960) with Hipparcos to V 9, thinned to
the brightest stars per sky cell (:func:`adfusion.starid.catalog.coverage.uniform_coverage`). Each
case runs in a fresh process (so its peak RSS is its own) with an empty cache:

* ``build``: catalogue load, selection, ``Solver`` construction (the index build),
  ``warm_up``; wall and CPU seconds, the process' peak RSS, index size and pair count;
* ``solve``: lost-in-space frames at random attitudes (wall ms as ``Solution.time_s``
  and the process' CPU ms: on a shared machine the wall time is mostly waiting). Every
  Hipparcos star to the limit in the field is a detection (0.3 px centroid noise, 0.2 mag
  brightness noise before ranking, so the order is not the catalogue's), the solver sees
  the brightest 30; correct = every frame corner within 2 px of where the true attitude
  puts it. Median / p95 solve ms and counts;
* ``mag 99`` with the selection (must fit) and ``V 9`` *without* it (must fail at once
  with the one-line memory error rather than allocate).

Usage (from the repository root; a few minutes on a loaded 2-core machine)::

    python -P benchmarks/bench_deep_index.py [--frames 200] [--json]

Example:
    >>> r = run_case({"mag_limit": 4.0, "fov_x_deg": 20.0, "stars_per_fov": 20, "frames": 3})
    >>> r["ok"], r["frames"]["n"]
    (True, 3)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Any

import numpy as np

WIDTH, HEIGHT = 1280, 960


def run_case(case: dict[str, Any]) -> dict[str, Any]:
    """One case in this process (see the module docstring); returns its record."""
    from adfusion.starid.camera.view import stars_in_view
    from adfusion.starid.catalog.coverage import uniform_coverage
    from adfusion.starid.catalog.pair_index import IndexTooLarge

    from adfusion import starid
    from adfusion.maths import rotations as rot

    w0, c0 = time.perf_counter(), time.process_time()
    cam = starid.Camera.pinhole(WIDTH, HEIGHT, case["fov_x_deg"])
    full = starid.Catalog.hipparcos(mag_limit=case["mag_limit"], epoch=2026.0)
    cat = full if case.get("stars_per_fov") is None else uniform_coverage(
        full, cam, case["stars_per_fov"])
    rec: dict[str, Any] = {"case": case, "catalog_stars": len(full), "index_stars": len(cat)}
    try:
        solver = starid.Solver(cat, cam)
    except IndexTooLarge as e:
        rec.update(ok=False, error=str(e), fail_after_s=round(time.perf_counter() - w0, 3),
                   peak_rss_mb=_peak_mb())
        return rec
    build_wall, build_cpu = time.perf_counter() - w0, time.process_time() - c0
    solver.warm_up()
    rec.update(ok=True, build_wall_s=round(build_wall, 2), build_cpu_s=round(build_cpu, 2),
               warm_up_s=round(time.perf_counter() - w0 - build_wall, 2),
               index_pairs=solver.index.n_pairs,
               index_mb=round(solver.index.nbytes / 1e6, 1))
    rng = np.random.default_rng(case.get("seed", 1))
    times, cpu, outcome = [], [], {"correct": 0, "wrong": 0, "not_ok": 0, "under_3_stars": 0}
    for _ in range(case["frames"]):
        v = rng.normal(size=3)
        ra, dec = np.arctan2(v[1], v[0]), np.arcsin(v[2] / np.linalg.norm(v))
        q = rot.q_cam_icrs_from_radec_roll(ra, dec, rng.uniform(0, 2 * np.pi))
        idx, xy = stars_in_view(full, cam, q)
        if len(idx) < 3:
            outcome["under_3_stars"] += 1
            continue
        seen = full.mag[idx] + rng.normal(0, 0.2, len(idx))
        order = np.argsort(seen)
        det = xy[order] + rng.normal(0, 0.3, (len(idx), 2))
        c1 = time.process_time()
        sol = solver.solve(det)
        cpu.append((time.process_time() - c1) * 1e3)
        times.append(sol.time_s * 1e3)
        if not sol.ok:
            outcome["not_ok"] += 1
        elif _corner_error_px(cam, sol.q_cam_icrs, q) < 2.0:
            outcome["correct"] += 1
        else:
            outcome["wrong"] += 1
    rec["frames"] = {"n": case["frames"], **outcome}
    if times:
        rec["solve_ms"] = {"median": round(statistics.median(times), 2),
                           "p95": round(float(np.percentile(times, 95)), 2),
                           "max": round(max(times), 2)}
        rec["solve_cpu_ms"] = {"median": round(statistics.median(cpu), 2),
                               "p95": round(float(np.percentile(cpu, 95)), 2)}
    rec["peak_rss_mb"] = _peak_mb()
    return rec


def _corner_error_px(cam, q_sol, q_true) -> float:
    """Largest displacement of the frame's corners between two attitudes (pixels): the
    roll of a narrow field is loose about its boresight, but moves the corners little."""
    from adfusion.maths import rotations as rot

    b = cam.pixels_to_vectors(cam.corners())
    xy = cam.vectors_to_pixels(rot.rotate(q_true, rot.rotate(rot.inverse(q_sol), b)))
    return float(np.max(np.linalg.norm(xy - cam.corners(), axis=1)))


def _peak_mb() -> float:
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


def _in_child(case: dict[str, Any]) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "ADFUSION_CACHE_DIR": cache}
        out = subprocess.run([sys.executable, "-P", __file__, "--case", json.dumps(case)],
                             env=env, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        return {"case": case, "ok": False, "error": out.stderr.strip().splitlines()[-1:]}
    return json.loads(out.stdout)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--stars-per-fov", type=int, default=None,
                    help="selection density (default: the library's)")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--case", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.case:
        print(json.dumps(run_case(json.loads(args.case))))
        return 0
    from adfusion.starid.catalog.coverage import DEFAULT_STARS_PER_FOV

    spf = args.stars_per_fov or DEFAULT_STARS_PER_FOV
    cases = [
        {"name": "V9 6x4.5 deg, uniform coverage", "mag_limit": 9.0, "fov_x_deg": 6.0,
         "stars_per_fov": spf, "frames": args.frames},
        {"name": "all Hipparcos (mag 99) 6x4.5 deg, uniform coverage", "mag_limit": 99.0,
         "fov_x_deg": 6.0, "stars_per_fov": spf, "frames": min(args.frames, 50)},
        {"name": "V9 6x4.5 deg, every star (no selection)", "mag_limit": 9.0,
         "fov_x_deg": 6.0, "stars_per_fov": None, "frames": 0},
        {"name": "all Hipparcos 40 deg, every star (no selection)", "mag_limit": 99.0,
         "fov_x_deg": 40.0, "stars_per_fov": None, "frames": 0},
    ]
    report = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                          "load_avg_1min": round(os.getloadavg()[0], 2)},
              "index_max_gb": os.environ.get("ADFUSION_INDEX_MAX_GB", "1.5 (default)"),
              "cases": [_in_child(c) for c in cases]}
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    for r in report["cases"]:
        c = r["case"]
        if not r["ok"]:
            print(f"{c['name']}: FAILED after {r.get('fail_after_s')} s, peak "
                  f"{r.get('peak_rss_mb')} MB: {r['error']}")
            continue
        f = r["frames"]
        print(f"{c['name']}: {r['catalog_stars']} → {r['index_stars']} stars, "
              f"{r['index_pairs']:,} pairs ({r['index_mb']} MB); build {r['build_wall_s']} s "
              f"wall / {r['build_cpu_s']} s CPU, peak {r['peak_rss_mb']} MB; "
              f"solve {r.get('solve_ms')} ms; {f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
