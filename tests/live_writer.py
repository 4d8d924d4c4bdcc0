"""A second process that fills a folder with star frames, as a camera's program would:
``python -P tests/live_writer.py DIR --slow N --burst M`` renders frames of a slowly
turning sky (640×480, 20°), writes each under a hidden name and renames it (a whole file
appears at once), ``N`` of them 0.4 s apart, then ``M`` as fast as it can, and writes
``DIR/../truth.json``: each file's q_cam_icrs. Waits for ``DIR/../go`` to exist first."""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import cv2
import numpy as np
from adfusion.sensors.render import render_sky
from adfusion.starid.camera.model import Camera
from adfusion.starid.catalog.stars import Catalog

from adfusion.maths import rotations as rot

CAMERA = Camera.pinhole(640, 480, 20.0)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("folder")
    ap.add_argument("--slow", type=int, default=4)
    ap.add_argument("--burst", type=int, default=0)
    ap.add_argument("--interval", type=float, default=0.4)
    ap.add_argument("--still", action="store_true", help="the sky does not turn")
    args = ap.parse_args()
    folder = Path(args.folder)
    cat = Catalog.hipparcos(mag_limit=6.5)
    n = args.slow + args.burst
    # boresight near Orion, turning 0.3° a frame about the boresight and across it
    q0 = rot.q_cam_icrs_from_radec_roll(np.radians(84.0), np.radians(-2.0), np.radians(10.0))
    frames = []
    for k in range(n):
        turn = 0.0 if args.still else 1.0
        q = rot.multiply(rot.exp_map(np.radians([0.2 * k, 0.1 * k, 0.3 * k]) * turn), q0)
        img, _, _ = render_sky(CAMERA, q, cat.vectors, cat.mag, seed=k)
        frames.append((f"f{k:03d}.png", q, img))
    truth = {name: [float(v) for v in q] for name, q, _ in frames}
    (folder.parent / "truth.json").write_text(json.dumps(truth))
    go = folder.parent / "go"
    while not go.exists():
        time.sleep(0.02)
    encoded = [(name, cv2.imencode(".png", img)[1].tobytes()) for name, _, img in frames]
    for k, (name, data) in enumerate(encoded):  # the burst: files land within milliseconds
        tmp = folder / f".{name}"
        tmp.write_bytes(data)
        os.replace(tmp, folder / name)
        if k < args.slow:
            time.sleep(args.interval)


if __name__ == "__main__":
    main()
