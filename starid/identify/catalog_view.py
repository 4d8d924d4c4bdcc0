"""The catalogue as the solver's parts see it: one explicit, shared context.

A :class:`CatalogView` holds what the :class:`starid.Solver`'s parts (its
:class:`~adfusion.starid.identify.verify.Verifier`, its
:class:`~adfusion.starid.identify.refine.Refiner`, the triad search …) read of the
catalogue and the camera: the star directions and ids, the KD-tree, the pattern index and
its compiled arrays, and the projection of the catalogue into a frame at an attitude. It
is made once by the solver and shared read-only, with two exceptions that do not change
any result: the compiled index arrays ``ix`` gain the catalogue's triangles once
(:meth:`Solver._with_triangles`), and :meth:`cone` keeps the last catalogue cone it
queried (a cache: callers keep only the stars in the frame).

Example:
    >>> import numpy as np
    >>> from adfusion import starid
    >>> from adfusion.starid import rotations as rot
    >>> s = starid.Solver(starid.Catalog.hipparcos(mag_limit=4.0),
    ...                   starid.Camera.pinhole(1024, 768, 15.0))
    >>> pxy, ids = s.view.project(rot.q_cam_icrs_from_radec_roll(0.2, 1.0, 0.0), s.camera)
    >>> len(pxy) == len(ids)
    True
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from adfusion.starid.camera.model import Camera
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from adfusion.maths import rotations as rot

__all__ = ["CONE_SPARE_RAD", "CatalogView"]

CONE_SPARE_RAD = math.radians(2.0)  # extra radius of the cached catalogue cone


class CatalogView:
    """The catalogue arrays, index and camera the solver's parts share.

    Args:
        catalog: the solver's catalogue (anything with ``vectors`` and ``ids``).
        camera: the solver's camera.
        vectors, ids: the catalogue's unit vectors (N, 3) float64 and ids (N,) int64.
        tree: a KD-tree of ``vectors``.
        index: the :class:`~adfusion.starid.catalog.pair_index.PatternIndex`.
        ix: its compiled arrays (:func:`starid.identify.kernels.index_arrays`).
    """

    def __init__(self, catalog: Any, camera: Camera, vectors: NDArray[np.float64],
                 ids: NDArray[np.int64], tree: cKDTree, index: Any, ix: tuple) -> None:
        self.catalog = catalog
        self.camera = camera
        self.vectors = vectors
        self.ids = ids
        self.tree = tree
        self.index = index
        self.ix = ix
        self.cone_cache: tuple[NDArray, float, NDArray[np.int64], NDArray] | None = None
        self._id_order: NDArray[np.int64] | None = None
        self._ids_sorted: NDArray[np.int64] | None = None

    def project(self, q: NDArray, cam: Camera) -> tuple[NDArray, NDArray[np.int64]]:
        """Catalogue stars inside the frame at attitude q: pixel positions and catalogue ids."""
        pxy, ids, _ = self.project_idx(q, cam)
        return pxy, ids

    def project_idx(self, q: NDArray, cam: Camera, margin_rad: float = 0.0,
                    ) -> tuple[NDArray, NDArray[np.int64], NDArray[np.int64]]:
        """As :meth:`project`, plus catalogue indices; ``margin_rad`` widens the cone and
        lets stars just outside the frame in (a prior's error can bring them in)."""
        pxy, idx = self.predict(rot.to_matrix(q), cam, margin_rad)
        return pxy, self.ids[idx], idx

    def predict(self, R: NDArray, cam: Camera, margin_rad: float,
                ) -> tuple[NDArray, NDArray[np.int64]]:
        """Pixel positions and catalogue indices of the stars in the frame at attitude R
        (cam ← icrs), ``margin_rad`` beyond its edges."""
        half = cam._view_half_rad + margin_rad + 1e-3
        idx, vec = self.cone(R[2], half)  # R[2]: the camera +z axis in ICRS
        ideal = cam._ideal_pinhole
        if ideal is None:
            pxy = cam.vectors_to_pixels(vec @ R.T)
            inside = cam.in_frame(pxy, margin=-margin_rad / cam.pixel_scale_rad)
            return pxy[inside], idx[inside]
        # an undistorted pinhole: rotation and projection as one homogeneous matrix
        # (u·z, v·z, z) = H R r — per frame, a few numpy calls instead of a dozen
        (a00, a01), (a10, a11) = ideal[2].tolist()
        c0, c1 = ideal[3].tolist()
        H = np.array([[a00, a10, c0], [a01, a11, c1], [0.0, 0.0, 1.0]])
        h = vec @ (H @ R).T
        z = h[:, 2]
        pxy = h[:, :2] / z[:, None]
        m = -margin_rad / cam.pixel_scale_rad
        lo, hi_x, hi_y = -0.5 + m, cam.width - 0.5 - m, cam.height - 0.5 - m
        u, v = pxy[:, 0], pxy[:, 1]
        inside = (z > 0) & (u >= lo) & (u <= hi_x) & (v >= lo) & (v <= hi_y)
        return pxy[inside], idx[inside]

    def cone(self, axis: NDArray, half_rad: float) -> tuple[NDArray[np.int64], NDArray]:
        """Catalogue stars (indices, vectors) within at least ``half_rad`` of ``axis``: a
        superset from a cached cone 2° wider, reused while it still covers the request — a
        tracking camera moves little between frames, so one KD-tree query serves many.
        Callers keep only the stars in the frame, so results do not depend on the cache
        (indices stay sorted, as the tree returns them)."""
        cache = self.cone_cache
        if cache is not None:
            c_axis, c_half, idx, vec = cache
            spare = c_half - half_rad
            if spare >= 0 and float(axis @ c_axis) >= math.cos(spare):
                return idx, vec
        c_half = min(half_rad + CONE_SPARE_RAD, math.pi)
        idx = np.array(self.tree.query_ball_point(axis, 2 * math.sin(c_half / 2)),
                       dtype=np.int64)
        idx.sort()  # (a single point's query is not sorted by the tree)
        vec = self.vectors[idx]
        self.cone_cache = (np.array(axis, dtype=np.float64), c_half, idx, vec)
        return idx, vec

    def catalog_index(self, ids: NDArray[np.int64]) -> NDArray[np.int64]:
        """Catalogue row of each id."""
        if self._id_order is None:
            self._id_order = np.argsort(self.ids, kind="stable")
            self._ids_sorted = self.ids[self._id_order]
        return self._id_order[np.searchsorted(self._ids_sorted, ids)]
