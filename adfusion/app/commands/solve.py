"""``adfusion solve``: identify frames (lost in space) and print or write their solutions.
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
    _output_folder,
    _outputs_apart,
    fov_error_fits,
    parse_fov,
)
from adfusion.app.errors import UsageError
from adfusion.outfiles import atomic_output, write_atomic


class _Solvers:
    """One catalogue, and one solver per image size, for every image of a run."""

    def __init__(self, args: argparse.Namespace) -> None:
        from adfusion import starid

        _camera_or_fov(args)
        self.args = args
        self.epoch = args.epoch if args.epoch is not None else _julian_year_now()
        self.catalog = starid.Catalog.hipparcos(mag_limit=args.mag_limit, epoch=self.epoch)
        self.camera_file = None
        self.fov = parse_fov(args.fov) if args.fov is not None else None
        if getattr(args, "camera", None):
            from adfusion.app.camera_file import load_camera  # the one loader (replay's too)

            self.camera_file = load_camera(args.camera)
        elif args.fov is None:
            raise UsageError("--fov (horizontal field of view estimate, degrees) or --camera "
                             "(a camera YAML) is required")
        self._by_size: dict = {}

    def camera_for(self, width: int, height: int):
        from adfusion import starid

        if self.camera_file is not None:
            c = self.camera_file
            if (c.width, c.height) != (width, height):
                raise ValueError(f"the camera file is for {c.width}×{c.height} images, this "
                                 f"one is {width}×{height}")
            return c
        return starid.Camera.pinhole(width, height, _fov_nominal(self.fov))

    def solver_for(self, camera):
        from adfusion import starid
        from adfusion.starid.catalog.coverage import DEFAULT_STARS_PER_FOV, catalog_for_camera

        key = camera.key()
        if key not in self._by_size:
            a = self.args
            spf = a.stars_per_fov if a.stars_per_fov is not None else DEFAULT_STARS_PER_FOV
            ranged = self.camera_file is None and self.fov[0] != self.fov[1]
            narrowest = camera  # a range thins for its narrowest field: depth for all
            if ranged and self.fov[0] < camera.fov_x_deg:
                narrowest = starid.Camera.pinhole(camera.width, camera.height, self.fov[0])
            cat = catalog_for_camera(self.catalog, narrowest, spf)
            if ranged:
                if a.fov_error:
                    raise UsageError("give --fov LO:HI or --fov-error, not both")
                kw = {"fov_range_deg": self.fov}
            else:
                fov_error_fits(a.fov_error, camera)
                kw = {"fov_error_deg": a.fov_error}
            solver = starid.Solver(cat, camera, method=a.method, **kw)
            if a.method == "nstar":
                # the reported time is the solve's, not the kernels' loading; the triangle
                # table only if a frame needs it (a build of seconds, once, then cached)
                solver.warm_up(triangles=False)
            self._by_size[key] = solver
        return self._by_size[key]


def cmd_solve(args: argparse.Namespace) -> int:
    import numpy as np

    from adfusion import starid
    from adfusion.starid.detection.image import read_image

    if args.example == bool(args.images):
        raise UsageError("give IMAGE(s) or --example (one of them)")
    paths = [] if args.example else _image_paths(args.images)
    if args.overlay and len(paths) > 1:
        raise UsageError("--overlay takes one image (use --out-dir for a batch)")
    if args.overlay:
        _output_file(args.overlay, "--overlay")
    out_dir = None
    if args.out_dir or args.wcs or args.corr:
        from pathlib import Path

        out_dir = Path(args.out_dir or ".")
        _output_folder(str(out_dir), "-o")
    # every file this run writes, against every file it reads and each other, before any
    # work (two images of one name in two folders would write one product)
    _outputs_apart(([("--overlay", args.overlay)] if args.overlay else [])
                   + [(flag, out_dir / f"{p.stem}{suffix}") for p in paths
                      for flag, suffix in _products(args) if out_dir is not None],
                   [*paths, args.camera])
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    truth_q = None
    if args.example:
        from adfusion.app import examples

        ex = examples.example_frame()
        print(f"example: {ex.description}", file=sys.stderr)
        args.camera, args.fov = None, str(ex.camera.fov_x_deg)
        frames = [("example", lambda: ex.image)]
        truth_q = ex.q_cam_icrs
    else:
        frames = [(p.name, lambda p=p: read_image(p)) for p in paths]
    solvers = _Solvers(args)
    records = []
    unread: list[str] = []  # why each image that could not be read was not
    bar = None
    if len(frames) > 1:
        from tqdm import tqdm

        bar = tqdm(total=len(frames), unit="image", file=sys.stderr, disable=None)
    for name, load in frames:
        try:
            image = load()
            camera = ex.camera if args.example else solvers.camera_for(image.shape[1],
                                                                       image.shape[0])
        except (ValueError, FileNotFoundError) as e:  # this image's problem: say so, go on
            if len(frames) == 1:
                raise
            rec = {"image": name, "ok": False, "reason": str(e)}
            unread.append(str(e))
        else:
            solver = solvers.solver_for(camera)
            t0 = time.perf_counter()
            det = starid.detect(image, camera, sigma=args.sigma)
            t_detect = time.perf_counter() - t0
            sol = solver.solve(det)
            rec = {"image": name, **solution_record(sol, solver.catalog, det.xy)}
            rec["detections"] = len(det)
            rec["detect_ms"] = round(t_detect * 1e3, 2)
            rec["epoch"] = solvers.epoch
            if truth_q is not None and sol.ok:
                err = np.degrees(starid.rotations.angle_between(sol.q_cam_icrs, truth_q)) * 3600
                rec["error_vs_truth_arcsec"] = round(float(err), 2)
            if out_dir is not None:
                _write_products(out_dir, name, rec, sol, args, solvers.epoch)
            if args.overlay:
                import cv2

                from adfusion.app.overlay import draw_solution

                with atomic_output(args.overlay) as tmp:  # (keeps the suffix OpenCV reads)
                    if not cv2.imwrite(str(tmp), draw_solution(image, det.xy, sol)):
                        raise ValueError(f"could not write the overlay to {args.overlay}")
                print(f"overlay → {args.overlay}", file=sys.stderr)
        records.append(rec)
        if bar is not None:
            bar.update(1)
            bar.set_postfix_str(f"{sum(r['ok'] for r in records)} solved")
    if bar is not None:
        bar.close()
    all_ok = all(r["ok"] for r in records)
    if len(records) > 1:
        from adfusion.app.products import summary_table

        if args.json:
            print(json.dumps({"images": records, "n": len(records),
                              "solved": sum(r["ok"] for r in records)}, indent=2))
        else:
            print(summary_table(records))
            lost = sum(not r["ok"] and _no_evidence(r) for r in records)
            if lost:
                print(f"{lost} of {len(records)} frames had nothing near an identification")
                print(_FOV_HINT)
        if len(unread) == len(records):  # nothing done: no image to solve (exit 2)
            print(f"adfusion solve: error: none of the {len(records)} images could be read "
                  f"(first: {unread[0]})", file=sys.stderr)
            return 2
        return 0 if all_ok else 1
    out = records[0]
    if args.json:
        print(json.dumps(out, indent=2))
        return 0 if out["ok"] else 1
    _print_solution(out)
    return 0 if out["ok"] else 1


def _write_products(out_dir, name: str, rec: dict, sol, args: argparse.Namespace,
                    epoch: float) -> None:
    from pathlib import Path

    from adfusion.app.products import write_corr, write_wcs

    stem = Path(name).stem
    write_atomic(out_dir / f"{stem}.json", json.dumps(rec, indent=2) + "\n")
    if sol.ok and args.wcs:
        with atomic_output(out_dir / f"{stem}.wcs") as tmp:
            write_wcs(tmp, sol, epoch)
    if sol.ok and args.corr:
        with atomic_output(out_dir / f"{stem}.corr") as tmp:
            write_corr(tmp, sol, rec["matches"])


def _products(args: argparse.Namespace) -> list[tuple[str, str]]:
    """The files ``--out-dir`` gets per image: (the flag asking for it, its suffix)."""
    return ([("-o", ".json")] + ([("--wcs", ".wcs")] if args.wcs else [])
            + ([("--corr", ".corr")] if args.corr else []))


def _no_evidence(out: dict) -> bool:
    """The search found nothing near an identification (no candidate, or the best one's
    false-match probability is near 1): a wrong scale is the usual cause."""
    import re

    reason = out.get("reason", "")
    if reason.startswith("no match"):
        return True
    m = re.search(r"best candidate has p_false ([0-9.eE+-]+)", reason)
    return m is not None and float(m.group(1)) >= 0.01


# a rough field of view given as exact is the usual cause of "nothing came close" (new-user
# trial: --fov 12 for an 11.4° lens solved 0 of 8 real frames; --fov-error 1 solves them)
_FOV_TOLERANCE = ("a field of view that is only approximate needs its tolerance (--fov DEG "
                  "--fov-error DEG, or a range --fov LO:HI when the lens is not known); else "
                  "check the camera file or the detection threshold (--sigma)")


_FOV_HINT = f"hint: nothing came close to an identification — {_FOV_TOLERANCE}"


def _print_solution(out: dict) -> None:
    n_det = out.get("detections", 0)
    print(f"{n_det} star{'' if n_det == 1 else 's'} detected in {out.get('detect_ms', 0)} ms; "
          f"identification {'ok' if out['ok'] else 'NOT ok'} in {out.get('time_ms', 0)} ms "
          f"({out.get('path') or '-'})")
    if not out["ok"]:
        print(f"reason: {out['reason']}")
        cands = out.get("candidates") or []
        if cands:
            print(f"{len(cands)} weak candidate(s), none passing the false-match threshold: "
                  "--json lists them")
        if _no_evidence(out):
            print(_FOV_HINT)
        return
    print(f"boresight RA {out['ra_deg']:.5f}°  Dec {out['dec_deg']:+.5f}°  roll "
          f"{out['roll_deg']:.4f}°   (1σ {out['sigma_arcsec'][0]:.1f}″ / "
          f"{out['sigma_arcsec'][1]:.1f}″ / {out['sigma_arcsec'][2]:.1f}″ about x/y/z)")
    print(f"FOV {out['fov_x_deg']:.4f}°, {len(out['matches'])} stars matched, RMS residual "
          f"{out['rms_residual_arcsec']:.1f}″, false-match probability {out['p_false']:.1e}")
    if "error_vs_truth_arcsec" in out:
        print(f"error against the rendered truth: {out['error_vs_truth_arcsec']}″")
    print(f"{'det':>4} {'x':>8} {'y':>8} {'id':>8} {'RA°':>10} {'Dec°':>10} {'mag':>6} "
          f"{'residual″':>10}")
    for m in out["matches"]:
        print(f"{m['detection']:>4} {m['x']:>8.2f} {m['y']:>8.2f} {m['id']:>8} "
              f"{m['ra_deg']:>10.5f} {m['dec_deg']:>+10.5f} {m['mag']:>6.2f} "
              f"{m['residual_arcsec']:>10.2f}")


def solution_record(sol, cat=None, xy=None) -> dict:
    """JSON-ready summary of a :class:`starid.Solution` (the CLI's and the logs' format).

    With the catalogue and the detections' pixels, each match carries its pixel, the
    catalogue star's RA/Dec and magnitude, and the predicted pixel
    (:func:`adfusion.app.products.match_rows`)."""
    import numpy as np

    rec: dict = {
        "ok": sol.ok, "reason": sol.reason, "mode": sol.mode, "path": sol.path,
        "matching_counter": sol.matching_counter, "time_ms": round(sol.time_s * 1e3, 3),
        "p_false": sol.p_false, "patterns_tried": sol.patterns_tried,
    }
    if sol.ok:
        ra, dec, roll = sol.ra_dec_roll_deg
        rec.update(
            ra_deg=ra, dec_deg=dec, roll_deg=roll,
            q_cam_icrs=[float(x) for x in sol.q_cam_icrs],
            sigma_arcsec=[float(np.degrees(np.sqrt(v)) * 3600)
                          for v in np.diag(sol.covariance)],
            covariance_rad2=np.asarray(sol.covariance).tolist(),
            fov_x_deg=sol.camera.fov_x_deg,
            camera=sol.camera.to_dict(),
            rms_residual_arcsec=sol.rms_residual_arcsec,
            matches=[{"detection": d, "id": i,
                      "residual_arcsec": float(np.degrees(r) * 3600)}
                     for (d, i), r in zip(sol.matches, sol.residuals_rad, strict=True)],
        )
        if cat is not None and xy is not None:
            from adfusion.app.products import match_rows

            rec["matches"] = match_rows(sol, cat, xy)
    else:
        rec["candidates"] = [
            {"ra_dec_roll_deg": list(c.radec_roll_deg), "p_false": c.p_false,
             "n_matches": len(c.matches)} for c in sol.candidates]
    return rec
