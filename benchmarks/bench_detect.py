"""Benchmark `starid.detection.detect` against tetra3rs's centroid extractors on the real frames.

For each frame of both real sets, ``shared/data/real-images`` (1024×768 uint16 TIFF) and
``shared/data/real-images-cedar`` (13 JPEG frames, grey), this times, on the same array:

* ``starid.detection.detect`` with OpenCV's default thread count and with ``cv2.setNumThreads(1)``;
* ``tetra3rs.extract_centroids`` with its default threads and ``threads=1``;
* ``tetra3rs.extract_centroids_fast`` likewise (a cruder single-pass extractor).

The methods run interleaved, round after round (default 30 rounds after 3 warm-up rounds), so
that a noisy machine slows them alike; the median per method is reported, with the ratio
ours / tetra3rs for matching thread settings. It also cross-matches the centroid lists: how many
of tetra3rs's centroids we also report within 1 px (tetra3rs reports positions relative to the
image centre; they are shifted to our 0-based pixel-centre convention first).

With ``--identify`` it also times detection + identification per frame (the frame's
reference FOV ±25 % as the range, the catalogue to V 6.5; the solver warmed up first),
the issue-14 figure (median ≤ 20 ms).

Usage (from the repository root)::

    python benchmarks/bench_detect.py [--json] [--rounds 30] [--identify] [--data DIR ...]

Example:
    >>> import numpy as np
    >>> img = np.random.default_rng(0).normal(100, 3, (96, 128)).astype(np.float32)
    >>> r = bench_frame("noise", img, rounds=2, warmup=1)
    >>> sorted(r["ms"])[:2], r["counts"]["starid"]
    (['starid', 'starid_1thread'], 0)
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from adfusion.starid.detection.detect import detect

from adfusion.bench.machine import machine_info

try:
    import tetra3rs
except ImportError:  # optional peer, the "bench" extra
    tetra3rs = None

_SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
DEFAULT_DATA = [_SHARED / "real-images", _SHARED / "real-images-cedar"]
_IMAGE_SUFFIXES = (".tiff", ".tif", ".png", ".jpg", ".jpeg")


def _tetra3rs_xy(result: Any, shape: tuple[int, int]) -> np.ndarray:
    """tetra3rs centroids in our convention (tetra3rs: relative to the image centre)."""
    h, w = shape
    xy = np.array([[c.x, c.y] for c in result.centroids], dtype=float).reshape(-1, 2)
    return xy + np.array([(w - 1) / 2.0, (h - 1) / 2.0])


def _methods(img: np.ndarray, default_threads: int) -> dict[str, Callable[[], Any]]:
    """Name → zero-argument callable; each returns (something with) a centroid list."""

    def ours(threads: int) -> Callable[[], Any]:
        def run() -> Any:
            cv2.setNumThreads(threads)
            try:
                return detect(img)
            finally:
                cv2.setNumThreads(default_threads)

        return run

    m: dict[str, Callable[[], Any]] = {"starid": ours(default_threads), "starid_1thread": ours(1)}
    if tetra3rs is not None:
        m["tetra3rs"] = lambda: tetra3rs.extract_centroids(img)
        m["tetra3rs_1thread"] = lambda: tetra3rs.extract_centroids(img, threads=1)
        m["tetra3rs_fast"] = lambda: tetra3rs.extract_centroids_fast(img)
        m["tetra3rs_fast_1thread"] = lambda: tetra3rs.extract_centroids_fast(img, threads=1)
    return m


def bench_frame(name: str, img: np.ndarray, rounds: int = 30, warmup: int = 3) -> dict[str, Any]:
    """Time every method on one frame (interleaved rounds); counts and cross-match.

    Example:
        >>> r = bench_frame("flat", np.full((64, 64), 10, np.uint16), rounds=1, warmup=0)
        >>> r["counts"]["starid"], r["frame"]
        (0, 'flat')
    """
    default_threads = cv2.getNumThreads()
    methods = _methods(img, default_threads)
    times: dict[str, list[float]] = {k: [] for k in methods}
    for i in range(warmup + rounds):
        for key, fn in methods.items():
            t0 = time.perf_counter()
            fn()
            dt = time.perf_counter() - t0
            if i >= warmup:
                times[key].append(dt * 1e3)
    ms = {k: round(statistics.median(v), 3) for k, v in times.items()}
    det = methods["starid"]()
    out: dict[str, Any] = {
        "frame": name,
        "shape": list(img.shape),
        "ms": ms,
        "counts": {"starid": len(det)},
    }
    if tetra3rs is not None:
        ref = _tetra3rs_xy(methods["tetra3rs"](), img.shape)
        fast = methods["tetra3rs_fast"]()
        out["counts"]["tetra3rs"] = len(ref)
        out["counts"]["tetra3rs_fast"] = len(fast.centroids)
        out["ratio"] = {
            "starid/tetra3rs": round(ms["starid"] / ms["tetra3rs"], 3),
            "starid/tetra3rs (1 thread each)": round(
                ms["starid_1thread"] / ms["tetra3rs_1thread"], 3
            ),
            "starid/tetra3rs_fast": round(ms["starid"] / ms["tetra3rs_fast"], 3),
        }
        if len(ref) and len(det):
            dist, _ = cKDTree(det.xy).query(ref)
            top = min(20, len(ref))  # tetra3rs sorts brightest first
            out["crossmatch"] = {
                "tetra3rs_found_by_starid_within_1px": int(np.sum(dist < 1.0)),
                "of_tetra3rs_brightest_20": int(np.sum(dist[:top] < 1.0)),
                "median_offset_px": round(float(np.median(dist[dist < 1.0])), 3),
            }
    return out


_CATALOG: Any = None


def bench_identify(path: Path, img: np.ndarray, rounds: int) -> dict[str, Any] | None:
    """Median wall time (ms) of detection + identification of one frame, with the frame's
    reference FOV (``truth.json`` beside it) ±25 % as the range; None without a reference."""
    global _CATALOG
    from adfusion import starid

    truth_file = path.parent / "truth.json"
    if not truth_file.is_file():
        return None
    t = json.loads(truth_file.read_text()).get(path.stem)
    if t is None:
        return None
    if _CATALOG is None:
        _CATALOG = starid.Catalog.hipparcos(mag_limit=6.5, epoch=2020.0)
    fov = t["fov_x_deg"]
    cam = starid.Camera.pinhole(img.shape[1], img.shape[0], fov)
    solver = starid.Solver(_CATALOG, cam, fov_range_deg=(0.75 * fov, 1.25 * fov))
    solver.warm_up()
    times, ok = [], False
    for _ in range(rounds):
        t0 = time.perf_counter()
        sol = solver.solve(detect(img, cam))
        times.append((time.perf_counter() - t0) * 1e3)
        ok = sol.ok
    return {"ms": round(statistics.median(times), 3), "ok": bool(ok),
            "stars": len(sol.matches)}


def _machine() -> dict[str, Any]:
    return machine_info(extra={
        "opencv": cv2.__version__, "opencv_default_threads": cv2.getNumThreads(),
        "tetra3rs": getattr(tetra3rs, "__version__", "installed") if tetra3rs else None})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true", help="print one JSON document")
    ap.add_argument("--rounds", type=int, default=30, help="timed rounds per frame (>= 20)")
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--data", type=Path, nargs="+", default=DEFAULT_DATA,
                    help="folders of frames (default: both shared real sets)")
    ap.add_argument("--identify", action="store_true",
                    help="also time detection + identification (FOV ±25 %%)")
    args = ap.parse_args(argv)

    frames = sorted(p for d in args.data for p in d.glob("*")
                    if p.suffix.lower() in _IMAGE_SUFFIXES)
    if not frames:
        print(f"no image frames in {[str(d) for d in args.data]}", file=sys.stderr)
        return 2
    from adfusion.starid.detection.image import read_image

    results = []
    for path in frames:
        img = read_image(path)
        r = bench_frame(f"{path.parent.name}/{path.stem}", img, args.rounds, args.warmup)
        if args.identify:
            r["identify"] = bench_identify(path, img, max(5, args.rounds // 3))
        results.append(r)

    summary: dict[str, Any] = {
        "median_ms": {
            k: round(statistics.median(r["ms"][k] for r in results), 3) for k in results[0]["ms"]
        }
    }
    if args.identify:
        ident = [r["identify"] for r in results if r.get("identify")]
        summary["detect_plus_identify_median_ms"] = round(
            statistics.median(i["ms"] for i in ident), 3)
        summary["identified"] = f"{sum(i['ok'] for i in ident)}/{len(ident)}"
    if tetra3rs is not None:
        for key in results[0]["ratio"]:
            summary.setdefault("ratio_median", {})[key] = round(
                statistics.median(r["ratio"][key] for r in results), 3
            )
    report = {
        "machine": _machine(),
        "rounds": args.rounds,
        "tetra3rs": "ok" if tetra3rs else "skipped: tetra3rs is not installed (pip install "
        "tetra3rs, the 'bench' extra)",
        "frames": results,
        "summary": summary,
    }
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    m = report["machine"]
    print(f"{m['cpu']}, {m['cores']} CPUs, OpenCV {m['opencv']}, numpy {m['numpy']}")
    cols = list(results[0]["ms"])
    print(f"{'frame':34s} " + " ".join(f"{c:>22s}" for c in cols) + "   n(ours) n(t3rs)")
    for r in results:
        times = " ".join(f"{r['ms'][c]:22.2f}" for c in cols)
        n3 = r["counts"].get("tetra3rs", "-")
        print(f"{r['frame'][:34]:34s} {times}   {r['counts']['starid']:7d} {n3!s:>7s}")
    print("median ms:", summary["median_ms"])
    if args.identify:
        for r in results:
            if r.get("identify"):
                i = r["identify"]
                print(f"  {r['frame'][:40]:40s} detect+identify {i['ms']:8.1f} ms "
                      f"{'ok' if i['ok'] else 'not ok'} {i['stars']} stars")
        print("detect+identify median ms:", summary["detect_plus_identify_median_ms"],
              "identified", summary["identified"])
    if tetra3rs is None:
        print(report["tetra3rs"])
    else:
        print("median ratio:", summary["ratio_median"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
