"""The ``adfusion`` command line.

Each sub-command lives in its own function; heavy imports happen inside them so that
``adfusion --help`` is instant.

Example:
    >>> from adfusion.cli import build_parser
    >>> sorted(build_parser()._subparsers._group_actions[0].choices)[:2]
    ['catalog', 'detect']
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence

from adfusion import examples


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="adfusion",
        description="Star-camera attitude determination: detection, identification, fusion.",
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)

    d = sub.add_parser("detect", help="find stars in an image (or the built-in example)")
    d.add_argument("image", nargs="?", help="image file (TIFF, PNG, JPEG)")
    d.add_argument("--example", action="store_true",
                   help="render and use the built-in synthetic example frame")
    d.add_argument("--sigma", type=float, default=5.0, help="threshold in noise sigmas")
    d.add_argument("--max", type=int, default=20, help="rows to print (default 20)")
    d.add_argument("--json", action="store_true", help="print JSON instead of a table")
    d.set_defaults(func=cmd_detect)

    c = sub.add_parser("catalog", help="star counts of the built-in catalogues per magnitude")
    c.add_argument("--json", action="store_true", help="print JSON instead of a table")
    c.set_defaults(func=cmd_catalog)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``adfusion`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as e:
        print(f"adfusion {args.command}: error: {e}", file=sys.stderr)
        return 2


def cmd_detect(args: argparse.Namespace) -> int:
    import starid

    if args.example == bool(args.image):
        raise ValueError("give an IMAGE or --example (one of them)")
    truth_xy = None
    if args.example:
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
        out["truth_found"] = examples.count_found(det.xy, truth_xy, radius_px=1.0)
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


def cmd_catalog(args: argparse.Namespace) -> int:
    from starid.catalog import renken_count_table

    rows = renken_count_table()
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print("Full-sky star counts: Renken Tab. A.2 (SAO, mag < L) vs Hipparcos (this catalogue)")
    print(f"{'limit':>6} {'SAO':>6} {'Hip V':>7} {'Hip Hp':>7}")
    for r in rows:
        print(f"{r['limit']:>6.1f} {r['sao']:>6} {r['ours_V']:>7} {r['ours_Hp']:>7}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
