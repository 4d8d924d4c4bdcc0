"""``adfusion detect``: the stars detected in frames, as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from adfusion.app.commands.args import _input_file
from adfusion.app.errors import UsageError


def cmd_detect(args: argparse.Namespace) -> int:
    from adfusion import starid
    if args.example == bool(args.image):
        raise UsageError("give an IMAGE or --example (one of them)")
    if args.image:
        _input_file(args.image, "image")
    truth_xy = None
    if args.example:
        from adfusion.app import examples

        ex = examples.example_frame()
        image, camera, truth_xy = ex.image, ex.camera, ex.star_xy
        print(f"example: {ex.description}", file=sys.stderr)
    else:
        image, camera = args.image, None
    t0 = time.perf_counter()
    det = starid.detect(image, camera, sigma=args.sigma)
    dt = time.perf_counter() - t0
    out = {
        "ok": det.ok,
        "reason": det.reason,
        "n": len(det),
        "time_ms": round(dt * 1e3, 2),
        "background": float(det.background_level),
        "noise_sigma": float(det.noise_sigma),
        "rejected": len(det.rejected),
        "stars": [
            {"x": round(float(x), 3), "y": round(float(y), 3), "flux": round(float(f), 1)}
            for (x, y), f in zip(det.xy[: args.max], det.flux[: args.max], strict=True)
        ],
    }
    if truth_xy is not None:
        from adfusion.app.examples import count_found

        out["truth_found"] = count_found(det.xy, truth_xy, radius_px=1.0)
        out["truth_total"] = len(truth_xy)
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(f"{out['n']} stars ({out['rejected']} blobs rejected) in {out['time_ms']} ms; "
          f"background {out['background']:.1f}, noise σ {out['noise_sigma']:.2f}")
    if not det.ok:
        print(f"not ok: {det.reason}")
    if truth_xy is not None:
        print(f"rendered stars recovered within 1 px: {out['truth_found']}/{out['truth_total']}")
    print(f"{'#':>3} {'x':>9} {'y':>9} {'flux':>10}")
    for i, s in enumerate(out["stars"]):
        print(f"{i:>3} {s['x']:>9.2f} {s['y']:>9.2f} {s['flux']:>10.1f}")
    return 0
