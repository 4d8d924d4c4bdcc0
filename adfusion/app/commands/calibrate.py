"""``adfusion calibrate``: one camera fitted to many star frames, written as a camera file.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from adfusion.app.commands.args import (
    _camera_or_fov,
    _fov_nominal,
    _image_paths,
    _julian_year_now,
    _output_file,
    _outputs_apart,
    parse_fov,
)
from adfusion.app.errors import PartlyDone, UsageError
from adfusion.outfiles import atomic_output


def cmd_calibrate(args: argparse.Namespace) -> int:
    import numpy as np

    from adfusion import starid
    from adfusion.starid.camera.files import read_camera_yaml, write_camera_yaml
    from adfusion.starid.detection.image import read_image
    from adfusion.starid.joint_calibration import NoFrameIdentified, calibrate_frames

    _camera_or_fov(args)
    paths = _image_paths(args.images)
    _output_file(args.output)
    _outputs_apart([("-o", args.output)], [*paths, args.camera])  # before any work
    if args.camera:
        camera = read_camera_yaml(args.camera)
    elif args.fov is None:
        raise UsageError("--fov (horizontal field of view estimate, degrees) or --camera "
                         "(a starting camera YAML) is required")
    fov = parse_fov(args.fov) if args.fov is not None else None
    terms = "auto" if args.terms.strip() == "auto" else tuple(
        t.strip() for t in args.terms.split(",") if t.strip())
    epoch = args.epoch if args.epoch is not None else _julian_year_now()
    dets: list = []
    shape: tuple = ()
    from tqdm import tqdm

    for p in tqdm(paths, desc="detect", unit="image", file=sys.stderr, disable=None):
        img = read_image(p)
        if not args.camera:
            if dets and img.shape[:2] != shape:
                raise ValueError(f"{p.name} is {img.shape[1]}×{img.shape[0]}, the first frame "
                                 f"{shape[1]}×{shape[0]}: one camera, one image size")
            shape = img.shape[:2]
            camera = starid.Camera.pinhole(shape[1], shape[0], _fov_nominal(fov))
        dets.append(starid.detect(img, camera, sigma=args.sigma))
    if fov is not None and fov[0] != fov[1] and not args.camera:
        fov_kw: dict = {"fov_range_deg": fov}
    else:
        fov_kw = {"fov_error_deg": args.fov_error if args.fov_error is not None
                  else 0.05 * camera.fov_x_deg}
    deep = starid.Catalog.hipparcos(mag_limit=args.mag_limit, epoch=epoch)
    ident = starid.Catalog.hipparcos(mag_limit=min(args.mag_limit, 6.5), epoch=epoch)
    t0 = time.perf_counter()
    try:
        res = calibrate_frames(dets, camera, deep, id_catalog=ident, terms=terms, **fov_kw)
    except NoFrameIdentified as e:  # read, but not identified: exit 1, as solve's
        raise PartlyDone("no frame could be identified: " + "; ".join(
            f"{paths[k].name}: {why}" for k, why in e.failed.items())) from None
    cam = res.camera
    with atomic_output(args.output) as tmp:
        write_camera_yaml(cam, tmp,
                          comment=f"adfusion calibrate: {res.n_frames} frames, "
                                  f"{sum(res.stars_per_frame)} stars, "
                                  f"terms {','.join(res.fit.terms)}",
                          sigma_px=res.sigma_px, rms_px=res.fit.rms_px, frames=res.n_frames)
    per_frame = [{"image": paths[k].name, "stars": n,
                  "rms_px": round(float(np.sqrt(np.mean(np.sum(r * r, axis=1)))), 3)}
                 for k, n, r in zip(res.frames_used, res.stars_per_frame, res.fit.residuals_px,
                                    strict=True)]
    out = {"output": str(args.output), "frames_used": res.n_frames,
           "frames_failed": {paths[k].name: r for k, r in res.frames_failed.items()},
           "terms": list(res.fit.terms), "sigma_px": round(res.sigma_px, 4),
           "rms_px": round(res.fit.rms_px, 4), "fov_x_deg": cam.fov_x_deg,
           "K": cam.K.tolist(), "D": cam.D.tolist(), "frames": per_frame,
           "time_s": round(time.perf_counter() - t0, 2)}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0 if not res.frames_failed else 1
    print(f"camera from {res.n_frames} frames, {sum(res.stars_per_frame)} stars "
          f"({', '.join(res.fit.terms)}): RMS {res.fit.rms_px:.3f} px, σ {res.sigma_px:.3f} px "
          f"→ {args.output}")
    print(f"fx {cam.K[0, 0]:.2f}  fy {cam.K[1, 1]:.2f}  cx {cam.K[0, 2]:.2f}  "
          f"cy {cam.K[1, 2]:.2f}  (FOV {cam.fov_x_deg:.4f}°)")
    print("D (k1 k2 p1 p2 k3): " + " ".join(f"{d:+.5f}" for d in cam.D))
    for f in per_frame:
        print(f"  {f['image']:40s} {f['stars']:4d} stars  RMS {f['rms_px']:.3f} px")
    for name, reason in out["frames_failed"].items():
        print(f"  {name:40s} left out: {reason}")
    return 0 if not res.frames_failed else 1
