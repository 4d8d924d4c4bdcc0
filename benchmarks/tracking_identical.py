"""Same tracking results before and after a change: record every tracking outcome on a
fixed set of OEDIPUS-like frames, then compare a later run against the record.

What a speed-up of the tracking path (:mod:`starid.tracking.tracking`) must keep: for every frame
and prior, the same accepted or refused outcome with the same reason, the same matches
(detection index, catalogue id), the same ``p_false`` (bit for bit: it is a function of
counts), and the same attitude, covariance and residuals up to rounding (a compiled
loop sums in another order than numpy's BLAS): quaternion and residuals within 1e-13
(rad), covariance within 1e-9 of its largest entry. Measured with the compiled tracking
path against the numpy one: ≤ 4e-15, ≤ 9e-16 rad and ≤ 3e-13.

The frames are :func:`bench_tracking._frames` (rendered, detected, the filter's recorded
priors) for each seed, solved under these priors:

* ``filter`` — the running estimator's priors (the tight path);
* ``filter_2``, ``filter_3`` — the same, with only the first 2 or 3 detections (the
  two-star bounds, the corner-σ refusal);
* ``filter_false`` — the same with 6 uniformly random false detections appended (the
  one-to-one and the residual cut);
* ``sigma_0.05``, ``sigma_0.2``, ``sigma_0.5`` — the truth turned by a random error of
  that RMS angle (degrees), told to the solver (the loose path: median shift, rounds).

``solver.tracker.solve`` is called directly (no lost-in-space fallback: the record is of the
tracking path alone).

Usage (from the repository root)::

    python benchmarks/tracking_identical.py record before.json [--seeds 1 2] [--duration 10]
    # ... change starid/tracking/tracking.py ...
    python benchmarks/tracking_identical.py compare before.json

``compare`` exits 1 and lists the first differences when any outcome differs.

Example:
    >>> recs = records(seeds=(1,), duration_s=0.2)
    >>> sorted({r["condition"] for r in recs})[:2]
    ['filter', 'filter_2']
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from adfusion.starid.solver import Prior
from bench_tracking import _frames, _synthetic_prior

# attitude, covariance and residuals may differ by rounding only: the quaternion and the
# residuals (rad) by this much, the covariance by this share of its largest entry
ATOL = {"q": 1e-13, "res": 1e-13, "cov": 0.0}
RTOL = {"q": 0.0, "res": 0.0, "cov": 1e-9}


def _conditions(frames: list[dict[str, Any]], seed: int, width: int,
                height: int) -> dict[str, list[tuple[np.ndarray, Prior | None]]]:
    rng = np.random.default_rng(1000 + seed)
    filt = [(f["xy"], f["prior"]) for f in frames]
    out: dict[str, list[tuple[np.ndarray, Prior | None]]] = {
        "filter": filt,
        "filter_2": [(xy[:2], p) for xy, p in filt],
        "filter_3": [(xy[:3], p) for xy, p in filt],
        "filter_false": [(np.concatenate([xy, rng.uniform((0, 0), (width, height), (6, 2))]),
                          p) for xy, p in filt],
    }
    for s in (0.05, 0.2, 0.5):
        out[f"sigma_{s:g}"] = [(f["xy"], _synthetic_prior(f["q_true"], s, rng))
                               for f in frames]
    return out


def _record(sol) -> dict[str, Any]:
    r: dict[str, Any] = {"ok": bool(sol.ok), "reason": sol.reason, "path": sol.path,
                         "mode": sol.mode, "p_false": sol.p_false,
                         "matches": [list(m) for m in sol.matches]}
    if sol.q_cam_icrs is not None:
        r["q"] = np.asarray(sol.q_cam_icrs).tolist()
        r["cov"] = np.asarray(sol.covariance).ravel().tolist()
        r["res"] = np.asarray(sol.residuals_rad).tolist()
    r["candidates"] = [{"p_false": c.p_false, "matches": [list(m) for m in c.matches],
                        "q": np.asarray(c.q_cam_icrs).tolist(),
                        "cov": np.asarray(c.covariance).ravel().tolist(),
                        "res": np.asarray(c.residuals_rad).tolist()}
                       for c in sol.candidates]
    return r


def records(seeds: tuple[int, ...] = (1, 2), duration_s: float = 10.0) -> list[dict[str, Any]]:
    """Every tracking outcome on the frames of ``seeds`` (one dict per frame and prior)."""
    out: list[dict[str, Any]] = []
    for seed in seeds:
        solver, frames = _frames(duration_s, seed)
        cam = solver.camera
        for name, cases in _conditions(frames, seed, cam.width, cam.height).items():
            for i, (xy, prior) in enumerate(cases):
                if prior is None:
                    continue
                sol = solver.tracker.solve(np.ascontiguousarray(xy, dtype=np.float64),
                                           prior, time.perf_counter())
                out.append({"seed": seed, "condition": name, "frame": i, **_record(sol)})
    return out


def _differences(a: dict[str, Any], b: dict[str, Any], where: str) -> list[str]:
    diffs = []
    for key in ("ok", "reason", "path", "mode", "p_false", "matches"):
        if a.get(key) != b.get(key):
            diffs.append(f"{where}: {key} {a.get(key)!r} → {b.get(key)!r}")
    for key in ("q", "cov", "res"):
        if (key in a) != (key in b):
            diffs.append(f"{where}: {key} present {key in a} → {key in b}")
        elif key in a and not _close(a[key], b[key], key):
            diffs.append(f"{where}: {key} {a[key]} → {b[key]}")
    ca, cb = a.get("candidates", []), b.get("candidates", [])
    if len(ca) != len(cb):
        diffs.append(f"{where}: {len(ca)} → {len(cb)} candidates")
    else:
        for k, (x, y) in enumerate(zip(ca, cb, strict=True)):
            diffs += _differences(x, y, f"{where} candidate {k}")
    return diffs


def _close(x: list[float], y: list[float], key: str) -> bool:
    x, y = np.asarray(x), np.asarray(y)
    if x.shape != y.shape:
        return False
    scale = float(np.max(np.abs(x), initial=0.0))
    return bool(np.all(np.abs(x - y) <= ATOL[key] + RTOL[key] * scale))


def compare(old: list[dict[str, Any]], new: list[dict[str, Any]]) -> list[str]:
    """Differences between two :func:`records` (empty when the same)."""
    key = lambda r: (r["seed"], r["condition"], r["frame"])  # noqa: E731
    a, b = {key(r): r for r in old}, {key(r): r for r in new}
    diffs = [f"{k}: only in the record" for k in a.keys() - b.keys()]
    diffs += [f"{k}: only in this run" for k in b.keys() - a.keys()]
    for k in sorted(a.keys() & b.keys()):
        diffs += _differences(a[k], b[k], str(k))
    return diffs


def _summary(recs: list[dict[str, Any]]) -> dict[str, str]:
    out: dict[str, list[int]] = {}
    for r in recs:
        n = out.setdefault(r["condition"], [0, 0])
        n[0] += 1
        n[1] += int(r["ok"])
    return {k: f"{ok} of {n} accepted" for k, (n, ok) in out.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("mode", choices=("record", "compare"))
    p.add_argument("file", type=Path)
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    p.add_argument("--duration", type=float, default=10.0, help="flight seconds (30 fps)")
    a = p.parse_args(argv)
    if a.mode == "record":
        recs = records(tuple(a.seeds), a.duration)
        a.file.write_text(json.dumps({"seeds": a.seeds, "duration_s": a.duration,
                                      "records": recs}))
        print(json.dumps(_summary(recs), indent=1))
        return 0
    saved = json.loads(a.file.read_text())
    recs = records(tuple(saved["seeds"]), saved["duration_s"])
    diffs = compare(saved["records"], recs)
    print(json.dumps(_summary(recs), indent=1))
    for d in diffs[:20]:
        print(d)
    print(f"{len(recs)} outcomes compared, {len(diffs)} differences")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
