"""The compiled final refit (starid.kernels.refine_pinhole) against the Python one
(starid.refine.Refinement._refine) on the `adfusion bench starid` frames.

Every frame is solved twice by one solver — compiled refit, then the Python code — and the
solutions compared (:func:`differences`): ok, reason, path, patterns tried, matches,
matching counter, note and p_false exactly; the attitude, residuals, covariance and noise
estimate to rounding (the compiled Wahba fit uses a Jacobi SVD, not LAPACK's). Prints
JSON; exit 1 on a difference.

    python -P benchmarks/compiled_equivalence.py [--frames 1000] [--conditions clean,...]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def differences(a, b) -> list[str]:
    """What differs between two solutions (empty: equivalent): the discrete fields
    exactly; p_false (the solution's and its candidates') to 1e-12 relative (the compiled
    binomial tail against scipy's ``bdtrc``: ~1e-15); the attitude to 1e-12 and the
    residuals to 1e-13 rad absolute (chords of unit vectors: ~1e-16 rounding, cancelled
    down to ~1e-4 rad); the covariance and the noise estimate, which come from those
    residuals, to 1e-11 relative."""
    out = []
    for f in ("ok", "reason", "path", "patterns_tried", "matches", "matching_counter",
              "note"):
        if getattr(a, f) != getattr(b, f):
            out.append(f"{f}: {getattr(a, f)!r} vs {getattr(b, f)!r}")
    pa = [a.p_false] + [c.p_false for c in a.candidates]
    pb = [b.p_false] + [c.p_false for c in b.candidates]
    if len(pa) != len(pb) or any((x is None) != (y is None) or (
            x is not None and abs(x - y) > 1e-12 * abs(y)) for x, y in zip(pa, pb, strict=True)):
        out.append(f"p_false: {pa!r} vs {pb!r}")
    if [c.matches for c in a.candidates] != [c.matches for c in b.candidates]:
        out.append("candidates' matches differ")
    if not (a.ok and b.ok):
        return out
    dq = float(np.max(np.abs(np.asarray(a.q_cam_icrs) - b.q_cam_icrs)))
    if dq > 1e-12:
        out.append(f"q differs by {dq:.2g}")
    dr = float(np.max(np.abs(a.residuals_rad - b.residuals_rad), initial=0.0))
    if dr > 1e-13:
        out.append(f"residuals differ by {dr:.2g} rad")
    dc = float(np.max(np.abs(a.covariance - b.covariance)) / np.max(np.abs(b.covariance)))
    if dc > 1e-11:
        out.append(f"covariance differs by {dc:.2g} (relative)")
    if abs(a.sigma_px - b.sigma_px) > 1e-11 * b.sigma_px:
        out.append(f"sigma_px {a.sigma_px!r} vs {b.sigma_px!r}")
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--conditions",
                   default="clean,false3,false8,drop30_false3,sparse45,sigma1,sigma2")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    from adfusion.bench import starid as bench

    report, bad = {}, 0
    t0 = time.time()
    for name in args.conditions.split(","):
        cond = bench.CONDITIONS[name].resolved(0.1, 6.0)
        cat = bench.load_catalog(cond.mag_limit, 2025.0)
        cam = bench.camera_for(cond, 1024, 768, 15.0)
        solver = bench.solver_for(cond.mag_limit, float(cond.sigma_px or 0.0), cam)
        n_ok = n_diff = 0
        first = None
        for i in range(args.frames):
            xy = bench.make_frame(cat, cam, cond, args.seed, i).xy
            solver._compiled_verify = solver._compiled_refine = True
            a = solver.solve(xy)
            solver._compiled_verify = solver._compiled_refine = False
            b = solver.solve(xy)
            d = differences(a, b)
            n_ok += a.ok
            if d:
                n_diff += 1
                first = first or {"frame": i, "differences": d}
        report[name] = {"frames": args.frames, "identified": n_ok, "different": n_diff,
                        "first_difference": first}
        bad += n_diff
    print(json.dumps({"conditions": report, "wall_s": round(time.time() - t0, 1)}, indent=2))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
