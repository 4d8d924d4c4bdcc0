"""Built-in example inputs: synthetic frames rendered from the bundled Hipparcos catalogue.

They need no download, so the README's first command works on a new machine.

Example:
    >>> from adfusion.app.examples import example_frame
    >>> ex = example_frame()
    >>> ex.image.shape, len(ex.star_xy) > 20
    ((768, 1024), True)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from adfusion.maths.rotations import q_cam_icrs_from_radec_roll
from adfusion.sensors.render import SensorModel, render_sky
from adfusion.starid.camera.model import Camera

__all__ = ["ExampleFrame", "count_found", "example_frame"]


@dataclass(frozen=True)
class ExampleFrame:
    """A rendered frame with everything needed to check a result against truth."""

    image: NDArray
    camera: Camera
    q_cam_icrs: NDArray[np.float64]
    star_xy: NDArray[np.float64]
    star_ids: NDArray[np.int64]
    description: str


def example_frame(
    ra_deg: float = 10.0,
    dec_deg: float = 60.0,
    roll_deg: float = 20.0,
    fov_x_deg: float = 15.0,
    mag_limit: float = 6.5,
    seed: int = 7,
) -> ExampleFrame:
    """Cassiopeia by default: a 1024×768 star tracker with a 15° field, stars to V 6.5."""
    from adfusion.starid.catalog.stars import Catalog

    cat = Catalog.hipparcos(mag_limit=mag_limit, epoch=2025.0)
    cam = Camera.pinhole(1024, 768, fov_x_deg)
    q = q_cam_icrs_from_radec_roll(*np.radians([ra_deg, dec_deg, roll_deg]))
    sensor = SensorModel(psf_sigma_px=1.2, hot_pixels=30, zero_point_e=4e6)
    img, xy, idx = render_sky(cam, q, cat.vectors, cat.mag, sensor, seed=seed)
    desc = (f"synthetic {cam.width}x{cam.height} frame, FOV {fov_x_deg}°, boresight "
            f"RA {ra_deg}° Dec {dec_deg}° roll {roll_deg}°, Hipparcos V < {mag_limit}, "
            f"{len(xy)} stars, 30 hot pixels, seed {seed}")
    return ExampleFrame(img, cam, q, xy, cat.ids[idx], desc)


def count_found(found_xy: ArrayLike, truth_xy: ArrayLike, radius_px: float) -> int:
    """How many truth positions have a found position within ``radius_px``."""
    found = np.asarray(found_xy, dtype=np.float64).reshape(-1, 2)
    truth = np.asarray(truth_xy, dtype=np.float64).reshape(-1, 2)
    if len(found) == 0 or len(truth) == 0:
        return 0
    d, _ = cKDTree(found).query(truth, distance_upper_bound=radius_px)
    return int(np.sum(np.isfinite(d)))
