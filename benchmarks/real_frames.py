#!/usr/bin/env python3
"""Identify the real frame sets of ../shared/data from the image file and a field-of-view
range, and score each solution against astrometry.net's matched stars (corr.json): the
projection of every matched star through our attitude and fitted camera, median and 95th
percentile of the pixel offsets. JSON out (``-o``), a line per frame on stdout.

    python benchmarks/real_frames.py                  # FOV range ±25 % around the reference
    python benchmarks/real_frames.py --fov 5:40       # 5°–40°, nothing else known
    python benchmarks/real_frames.py --clip8          # 8-bit, background clipped at 0

A frame counts as good when the matched stars land within 1.0 px median and 3 px p95.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from adfusion.starid.detection.image import read_image

from adfusion import starid
from adfusion.maths import rotations as rot

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
SETS = ("real-images", "real-images-cedar")


def clipped_8bit(img: np.ndarray) -> np.ndarray:
    """The frame as 8 bits (16-bit data: the top byte, as image viewers and OpenCV's
    grey reader convert) with the black level at its median: half the sky becomes 0, as
    from a camera with a black-level offset or a dark-subtracted PNG."""
    a = img.astype(np.int64)
    if img.dtype == np.uint16:
        a = a >> 8
    a = a - int(np.median(a))
    return np.clip(a, 0, 255).astype(np.uint8)


def frames(data: Path = DATA):
    """(set, name, image path, truth record, corr record) of every shared real frame."""
    for sub in SETS:
        d = data / sub
        if not (d / "corr.json").is_file():
            continue
        truth = json.loads((d / "truth.json").read_text())
        corr = json.loads((d / "corr.json").read_text())
        for name, t in sorted(truth.items()):
            path = next(p for p in d.glob(name + ".*") if p.suffix != ".json")
            yield sub, name, path, t, corr[name]


def offsets_px(sol, corr: dict) -> np.ndarray:
    """Pixel offsets of astrometry.net's matched stars projected through a solution."""
    r = rot.radec_to_vector(np.radians(corr["ra_deg"]), np.radians(corr["dec_deg"]))
    xy = sol.camera.vectors_to_pixels(rot.rotate(sol.q_cam_icrs, r))
    return np.hypot(xy[:, 0] - np.asarray(corr["x"]), xy[:, 1] - np.asarray(corr["y"]))


def solve_frame(cat, path: Path, t: dict, fov_range, clip8: bool = False, **solver_kw):
    img = read_image(path)
    if clip8:
        img = clipped_8bit(img)
    fov = t["fov_x_deg"]
    cam = starid.Camera.pinhole(img.shape[1], img.shape[0], fov)
    lo, hi = fov_range(fov)
    solver = starid.Solver(cat, cam, fov_range_deg=(lo, hi), **solver_kw)
    t0 = time.perf_counter()
    det = starid.detect(img, cam)
    t1 = time.perf_counter()
    sol = solver.solve(det)
    t2 = time.perf_counter()
    return sol, det, 1e3 * (t1 - t0), 1e3 * (t2 - t1)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--range", type=float, default=0.25, help="FOV ± this fraction")
    ap.add_argument("--fov", help="FOV range LO:HI in degrees (overrides --range)")
    ap.add_argument("--mag", type=float, default=6.5)
    ap.add_argument("--clip8", action="store_true", help="8-bit frames, black level at the median")
    ap.add_argument("--only", help="substring of the frame names to run")
    ap.add_argument("-o", "--output", help="JSON results")
    a = ap.parse_args(argv)
    if a.fov:
        lo, hi = (float(v) for v in a.fov.split(":"))
        fov_range = lambda fov: (lo, hi)  # noqa: E731
    else:
        fov_range = lambda fov: ((1 - a.range) * fov, (1 + a.range) * fov)  # noqa: E731
    cat = starid.Catalog.hipparcos(mag_limit=a.mag, epoch=2020.0)
    rows, good = [], 0
    for sub, name, path, t, corr in frames():
        if a.only and a.only not in name:
            continue
        sol, det, ms_det, ms_id = solve_frame(cat, path, t, fov_range, a.clip8)
        row = {"set": sub, "frame": name, "ok": sol.ok, "detections": len(det),
               "detect_ms": ms_det, "identify_ms": ms_id}
        if sol.ok:
            off = offsets_px(sol, corr)
            med, p95 = float(np.median(off)), float(np.percentile(off, 95))
            row.update(stars=len(sol.matches), median_px=med, p95_px=p95,
                       fov_x_deg=sol.camera.fov_x_deg, good=med <= 1.0 and p95 <= 3.0,
                       wrong=med > 10)
            note = "good" if row["good"] else "WRONG" if med > 10 else "inaccurate"
            print(f"{sub}/{name}: {len(sol.matches)} stars, a.net stars off {med:.2f} px "
                  f"median, {p95:.2f} px p95, FOV {sol.camera.fov_x_deg:.3f}° "
                  f"(ref {t['fov_x_deg']:.3f}°), {ms_det:.1f}+{ms_id:.1f} ms {note}")
        else:
            row.update(good=False, wrong=False, reason=sol.reason)
            print(f"{sub}/{name}: not ok ({sol.reason[:100]}), {ms_det:.1f}+{ms_id:.1f} ms")
        good += row["good"]
        rows.append(row)
    print(f"{good}/{len(rows)} frames within 1 px median / 3 px p95, "
          f"{sum(r['wrong'] for r in rows)} wrong")
    if a.output:
        Path(a.output).write_text(json.dumps({"args": vars(a), "frames": rows}, indent=1))
    return 0 if good == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
