"""Helpers for the 8 real frames in ``shared/data/real-images`` and their reference solutions.

``truth.json`` gives, per frame, a 3×3 grid of pixels with the ICRS RA/Dec that an
independent astrometry.net solution assigns. Fitting our camera model (attitude and
focal length) to that grid gives a reference attitude to score detection and
identification against, with no roll-convention bookkeeping.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
from adfusion.starid import Camera
from adfusion.starid.camera.calibrate import CameraFit, fit_camera
from adfusion.starid.camera.view import stars_in_view

from adfusion.maths import rotations as rot

OBS_EPOCH = 2019.575  # 2019-07-29


@dataclass(frozen=True)
class RealFrame:
    name: str
    path: Path
    grid_xy: np.ndarray
    grid_icrs: np.ndarray
    fov_x_deg: float
    fit: CameraFit


@cache
def load_frames(shared: Path) -> tuple[RealFrame, ...]:
    root = shared / "data" / "real-images"
    truth = json.loads((root / "truth.json").read_text())
    frames = []
    for name, t in sorted(truth.items()):
        xy = np.array([[g["x"], g["y"]] for g in t["grid"]])
        icrs = rot.radec_to_vector(np.radians([g["ra_deg"] for g in t["grid"]]),
                                   np.radians([g["dec_deg"] for g in t["grid"]]))
        cam0 = Camera.pinhole(t["width"], t["height"], t["fov_x_deg"])
        fit = fit_camera(xy, icrs, cam0, fit_focal=True)
        frames.append(RealFrame(name, root / f"{name}.tiff", xy, icrs, t["fov_x_deg"], fit))
    return tuple(frames)


def grid_errors_deg(frame: RealFrame, camera: Camera, q_cam_icrs: np.ndarray) -> np.ndarray:
    """Angle between each grid pixel's line of sight (our solution) and the reference."""
    b = camera.pixels_to_vectors(frame.grid_xy)
    r_ours = rot.rotate(rot.inverse(q_cam_icrs), b)
    cosang = np.clip(np.sum(r_ours * frame.grid_icrs, axis=1), -1, 1)
    return np.degrees(np.arccos(cosang))


def projected_stars(frame: RealFrame, catalog) -> tuple[np.ndarray, np.ndarray]:
    """Indices and pixel positions of catalogue stars inside the frame at the reference fit."""
    return stars_in_view(catalog, frame.fit.camera, frame.fit.q_cam_icrs)


# --- both shared real sets with astrometry.net's matched stars (corr.json) ------------------

REAL_SETS = ("real-images", "real-images-cedar")


@dataclass(frozen=True)
class CorrFrame:
    """A real frame with astrometry.net's reference: FOV, matched stars (pixel ↔ ICRS)."""

    set: str
    name: str
    path: Path
    width: int
    height: int
    fov_x_deg: float
    corr_xy: np.ndarray
    corr_icrs: np.ndarray


@cache
def corr_frames(shared: Path) -> tuple[CorrFrame, ...]:
    """Every frame of both real sets (8 TIFF + 13 JPEG)."""
    out = []
    for sub in REAL_SETS:
        root = shared / "data" / sub
        truth = json.loads((root / "truth.json").read_text())
        corr = json.loads((root / "corr.json").read_text())
        for name, t in sorted(truth.items()):
            path = next(p for p in root.glob(name + ".*") if p.suffix != ".json")
            c = corr[name]
            icrs = rot.radec_to_vector(np.radians(c["ra_deg"]), np.radians(c["dec_deg"]))
            out.append(CorrFrame(sub, name, path, t["width"], t["height"], t["fov_x_deg"],
                                 np.column_stack([c["x"], c["y"]]), icrs))
    return tuple(out)


def corr_offsets_px(frame: CorrFrame, camera: Camera, q_cam_icrs: np.ndarray) -> np.ndarray:
    """Pixel distance of each astrometry.net matched star, projected through our solution
    (attitude and camera), from the pixel astrometry.net matched it to."""
    xy = camera.vectors_to_pixels(rot.rotate(q_cam_icrs, frame.corr_icrs))
    return np.hypot(*(xy - frame.corr_xy).T)


def clipped_8bit(img: np.ndarray) -> np.ndarray:
    """The frame as 8 bits (16-bit data: the top byte) with the black level at its median:
    half the sky becomes 0 — a camera with a black-level offset, a dark-subtracted PNG."""
    a = img.astype(np.int64)
    if img.dtype == np.uint16:
        a = a >> 8
    return np.clip(a - int(np.median(a)), 0, 255).astype(np.uint8)
