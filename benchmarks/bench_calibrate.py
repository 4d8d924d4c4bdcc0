"""`adfusion calibrate` on the 8 real frames, scored two ways against astrometry.net.

For the camera the joint calibration recovers (:func:`adfusion.starid.joint_calibration.
calibrate_frames`, the command's defaults) and for the pinhole with only a fitted focal
length (the solver's figures in the README's "Real frames" table), per frame:

* ``grid``: the largest angle between our line of sight and astrometry.net's at the 3×3
  reference grid of ``truth.json`` (its SIP order-2 polynomial evaluated there);
* ``corr``: median / 95th percentile / max pixel distance of astrometry.net's own matched
  stars (``corr.json``: its centroids, its Tycho-2 positions) from where our camera and
  attitude project them.

Also a fit of focal length and k1 to astrometry.net's matched stars alone (no detection or
catalogue of ours), as an independent measurement of the lens' radial distortion.

Usage (from the repository root, ~30 s)::

    python -P benchmarks/bench_calibrate.py [--json] [--data DIR]

Example:
    >>> sorted(score_frame(np.zeros((2, 2)), np.array([[0, 0, 1.0]] * 2),
    ...                    _cam(), np.array([1.0, 0, 0, 0]))[1])
    ['max', 'median', 'p95']
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real-images"
OBS_EPOCH = 2019.575  # 2019-07-29


def _cam():
    from adfusion.starid import Camera

    return Camera.pinhole(1024, 768, 11.4)


def score_frame(corr_xy: np.ndarray, corr_icrs: np.ndarray, camera, q) -> tuple:
    """(projected − measured) pixel distances of the reference stars: (array, summary)."""
    from adfusion.maths import rotations as rot

    d = np.linalg.norm(camera.vectors_to_pixels(rot.rotate(q, corr_icrs)) - corr_xy, axis=1)
    return d, {"median": round(float(np.median(d)), 3),
               "p95": round(float(np.percentile(d, 95)), 3), "max": round(float(d.max()), 3)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "tests"))
    from adfusion.starid.camera.calibrate import fit_camera_model
    from adfusion.starid.joint_calibration import calibrate_frames
    from real_frames import grid_errors_deg, load_frames

    from adfusion import starid
    from adfusion.maths import rotations as rot

    frames = load_frames(args.data.parents[1])
    corr = json.loads((args.data / "corr.json").read_text())
    dets = [starid.detect(f.path) for f in frames]
    ident = starid.Catalog.hipparcos(mag_limit=6.5, epoch=OBS_EPOCH)
    deep = starid.Catalog.hipparcos(mag_limit=7.5, epoch=OBS_EPOCH)
    res = calibrate_frames(dets, _cam(), deep, id_catalog=ident, fov_error_deg=0.57)
    pinhole = starid.Solver(ident, _cam(), fov_error_deg=0.5, fit_camera="focal")
    with_cam = starid.Solver(ident, res.camera, fit_camera="none")
    rows = []
    for k, (f, det) in enumerate(zip(frames, dets, strict=True)):
        c = corr[f.name]
        xy = np.stack([c["x"], c["y"]], 1)
        r = rot.radec_to_vector(np.radians(c["ra_deg"]), np.radians(c["dec_deg"]))
        row = {"frame": f.name, "reference_stars": len(xy)}
        for key, solver in (("pinhole", pinhole), ("calibrated", with_cam)):
            sol = solver.solve(det)
            row[key] = {"grid_max_deg": round(float(grid_errors_deg(
                f, sol.camera, sol.q_cam_icrs).max()), 4),
                "corr_px": score_frame(xy, r, sol.camera, sol.q_cam_icrs)[1]}
        q_joint = res.q_cam_icrs[res.frames_used.index(k)]
        row["calibrated_joint_attitude"] = {
            "grid_max_deg": round(float(grid_errors_deg(f, res.camera, q_joint).max()), 4),
            "corr_px": score_frame(xy, r, res.camera, q_joint)[1]}
        rows.append(row)
    ref_frames = [(np.stack([c["x"], c["y"]], 1),
                   rot.radec_to_vector(np.radians(c["ra_deg"]), np.radians(c["dec_deg"])))
                  for _, c in sorted(corr.items())]
    ref = {t: fit_camera_model(ref_frames, _cam(), t) for t in (("focal",), ("focal", "k1"))}
    cam = res.camera
    report = {
        "camera": {"K": cam.K.round(3).tolist(), "D": cam.D.round(5).tolist(),
                   "fov_x_deg": round(cam.fov_x_deg, 4), "terms": list(res.fit.terms),
                   "stars": sum(res.stars_per_frame), "sigma_px": round(res.sigma_px, 4)},
        "astrometry_net_stars_alone": {
            "k1": round(float(ref[("focal", "k1")].camera.D[0]), 4),
            "sigma_px_focal_only": round(ref[("focal",)].sigma_px, 4),
            "sigma_px_focal_k1": round(ref[("focal", "k1")].sigma_px, 4)},
        "frames": rows,
        "summary": {
            "grid_below_pinhole": sum(r["calibrated"]["grid_max_deg"]
                                      < r["pinhole"]["grid_max_deg"] for r in rows),
            "corr_median_below_pinhole": sum(r["calibrated"]["corr_px"]["median"]
                                             < r["pinhole"]["corr_px"]["median"]
                                             for r in rows),
            "corr_p95_below_pinhole": sum(r["calibrated"]["corr_px"]["p95"]
                                          < r["pinhole"]["corr_px"]["p95"] for r in rows),
            "corr_median_px": {k: round(statistics.median(r[k]["corr_px"]["median"]
                                                          for r in rows), 3)
                               for k in ("pinhole", "calibrated")}},
    }
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"camera: {report['camera']}")
    print(f"astrometry.net's stars alone: {report['astrometry_net_stars_alone']}")
    print(f"{'frame':24s} {'grid max° pinhole':>17s} {'calibrated':>10s}   "
          f"{'corr px med/p95 pinhole':>24s} {'calibrated':>12s}")
    for r in rows:
        p, c = r["pinhole"], r["calibrated"]
        print(f"{r['frame'][18:]:24s} {p['grid_max_deg']:17.4f} {c['grid_max_deg']:10.4f}   "
              f"{p['corr_px']['median']:>14.3f}/{p['corr_px']['p95']:.3f} "
              f"{c['corr_px']['median']:>8.3f}/{c['corr_px']['p95']:.3f}")
    print(report["summary"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
