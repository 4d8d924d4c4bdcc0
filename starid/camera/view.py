"""Which catalogue stars a camera sees at a given attitude, and where.

Example:
    >>> import numpy as np
    >>> from adfusion import starid
    >>> from adfusion.starid.camera.view import stars_in_view
    >>> cat = starid.Catalog.hipparcos(mag_limit=4.0)
    >>> cam = starid.Camera.pinhole(1024, 768, 15.0)
    >>> q = starid.rotations.q_cam_icrs_from_radec_roll(*np.radians([10.0, 60.0, 20.0]))
    >>> idx, xy = stars_in_view(cat, cam, q)
    >>> len(idx) == len(xy) > 3, bool(np.all(np.diff(cat.mag[idx]) >= 0))
    (True, True)
"""

from __future__ import annotations

import numpy as np
from adfusion.starid.camera.model import Camera
from numpy.typing import ArrayLike, NDArray

from adfusion.maths import rotations as rot

__all__ = ["stars_in_view"]


def stars_in_view(catalog, camera: Camera, q_cam_icrs: ArrayLike, margin_px: float = 0.0,
                  brightest_first: bool = True) -> tuple[NDArray[np.int64], NDArray]:
    """Catalogue indices and pixel positions of the stars inside the frame.

    ``margin_px`` > 0 keeps stars that far from the edges only; < 0 admits stars just
    outside. Sorted brightest first (stable, so equal magnitudes keep catalogue order).
    """
    v = rot.rotate(q_cam_icrs, np.asarray(catalog.vectors, dtype=np.float64))
    front = np.flatnonzero(v[:, 2] > 0)
    xy = camera.vectors_to_pixels(v[front])
    inside = camera.in_frame(xy, margin=margin_px)
    idx, xy = front[inside], xy[inside]
    if brightest_first:
        order = np.argsort(np.asarray(catalog.mag)[idx], kind="stable")
        idx, xy = idx[order], xy[order]
    return idx.astype(np.int64), xy
