"""The compiled lost-in-space frame (starid.identify.frame_kernels.solve_frame: search,
verification and final refit in one call) against the Python code on the `adfusion bench
starid` frames.

Every frame is solved twice by one solver — in one compiled call, then with the reference
(``--reference python``: the compiled search with the verification and the refit in Python,
starid.identify.verify and starid.identify.refine; ``--reference pieces``: the compiled search,
verification
and refit called one by one from Python, as before solve_frame) — and the solutions
compared (:func:`differences`): ok, reason, path, patterns tried, matches,
matching counter, note and p_false exactly; the attitude, residuals, covariance and noise
estimate to rounding (the compiled Wahba fit uses a Jacobi SVD, not LAPACK's). Prints
JSON; exit 1 on a difference.

    python -P benchmarks/compiled_equivalence.py [--frames 1000] [--conditions clean,...]
        [--reference python|pieces]
    python -P benchmarks/compiled_equivalence.py --record FILE.json   # solutions, any version
    python -P benchmarks/compiled_equivalence.py --against FILE.json  # this code against them

``--record`` writes each frame's solution (the discrete fields, p_false and the attitude)
so that another version of the code — the one before a change — can be compared with this
one on the same frames: ``--against`` solves them again and reports every frame whose
discrete fields differ or whose attitude moved by more than 1e-12, the largest relative
p_false difference and the largest attitude difference.
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
    p.add_argument("--reference", choices=("python", "pieces"), default="python",
                   help="what the one-call path is compared with (default python)")
    p.add_argument("--record", metavar="FILE", help="write the solutions to FILE (JSON)")
    p.add_argument("--against", metavar="FILE",
                   help="compare this code's solutions with a --record FILE")
    args = p.parse_args(argv)
    if args.record or args.against:
        return record_or_compare(args)
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
            solver._compiled_verify = solver._compiled_refine = solver._frame_kernel = True
            a = solver.solve(xy)
            if args.reference == "python":
                solver._compiled_verify = solver._compiled_refine = False
            else:
                solver._frame_kernel = False
            b = solver.solve(xy)
            d = differences(a, b)
            n_ok += a.ok
            if d:
                n_diff += 1
                first = first or {"frame": i, "differences": d}
        report[name] = {"frames": args.frames, "identified": n_ok, "different": n_diff,
                        "first_difference": first}
        bad += n_diff
    solver._compiled_verify = solver._compiled_refine = solver._frame_kernel = True
    print(json.dumps({"reference": args.reference, "conditions": report,
                      "wall_s": round(time.time() - t0, 1)}, indent=2))
    return 1 if bad else 0


def summary(sol) -> dict:
    """A solution's discrete fields and p_false (its own and its candidates'), as JSON."""
    return {"ok": bool(sol.ok), "reason": sol.reason, "path": sol.path,
            "patterns_tried": int(sol.patterns_tried),
            "matching_counter": int(sol.matching_counter), "note": sol.note,
            "matches": [list(map(int, m)) for m in sol.matches],
            "candidates": [[list(map(int, m)) for m in c.matches] for c in sol.candidates],
            "p_false": [sol.p_false] + [float(c.p_false) for c in sol.candidates],
            "q": None if sol.q_cam_icrs is None else [float(x) for x in sol.q_cam_icrs]}


def record_or_compare(args) -> int:
    """``--record`` / ``--against``: see the module's docstring."""
    from adfusion.bench import starid as bench

    t0 = time.time()
    old = json.load(open(args.against))["conditions"] if args.against else {}
    out, report, bad = {}, {}, 0
    for name in args.conditions.split(","):
        cond = bench.CONDITIONS[name].resolved(0.1, 6.0)
        cat = bench.load_catalog(cond.mag_limit, 2025.0)
        cam = bench.camera_for(cond, 1024, 768, 15.0)
        solver = bench.solver_for(cond.mag_limit, float(cond.sigma_px or 0.0), cam)
        sols = [summary(solver.solve(bench.make_frame(cat, cam, cond, args.seed, i).xy))
                for i in range(args.frames)]
        out[name] = sols
        if not args.against:
            continue
        n_diff, worst, worst_q, first = 0, 0.0, 0.0, None
        for i, (a, b) in enumerate(zip(sols, old[name], strict=True)):
            pa, pb = a.pop("p_false"), b.pop("p_false")
            qa, qb = a.pop("q", None), b.pop("q", None)
            same = a == b and len(pa) == len(pb) and all(
                (x is None) == (y is None) for x, y in zip(pa, pb, strict=True))
            if same and qa is not None and qb is not None:
                # the attitude to rounding (another version may sum in another order)
                dq = max(abs(x - y) for x, y in zip(qa, qb, strict=True))
                worst_q = max(worst_q, dq)
                same = dq <= 1e-12
            if not same:
                n_diff += 1
                first = first or {"frame": i, "this": a, "recorded": b}
                continue
            for x, y in zip(pa, pb, strict=True):
                if x is not None and y:
                    worst = max(worst, abs(x - y) / abs(y))
        report[name] = {"frames": args.frames, "identified": sum(s["ok"] for s in sols),
                        "different": n_diff, "p_false_max_rel_difference": worst,
                        "q_max_difference": worst_q,
                        "first_difference": first}
        bad += n_diff
    if args.record:
        with open(args.record, "w") as f:
            json.dump({"conditions": out}, f)
    if args.against:
        print(json.dumps({"against": args.against, "conditions": report,
                          "wall_s": round(time.time() - t0, 1)}, indent=2))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
