"""Calibrate one camera from many star frames: identify, associate, fit jointly.

What ``adfusion calibrate FRAMES… -o camera.yaml`` runs:

1. every frame is identified lost-in-space with the nominal camera (a FOV estimate);
2. with its attitude, the catalogue (deeper than the identification's: fainter stars
   fill the frame's corners, where distortion shows) is projected into the frame and
   each star paired with the nearest detection, one to one, within a radius;
3. :func:`starid.camera.calibrate.fit_camera_model` fits focal length, principal point, pixel
   aspect and OpenCV distortion jointly over all frames (one attitude per frame);
4. steps 2–3 repeat with the fitted camera, the radius shrinking to 5 σ of the
   residuals (never below 1.5 px), so wrong pairs drop out and stars the nominal camera
   put too far off come in.

Frames that cannot be identified are left out (and listed). The fit is over pixel
residuals; ``sigma_px`` is the a-posteriori centroid noise of the final fit.

Example (synthetic: the same lens seen at three attitudes):
    >>> import numpy as np
    >>> from adfusion.starid import Camera, rotations as rot
    >>> from adfusion.starid.catalog.stars import Catalog
    >>> from adfusion.starid.joint_calibration import calibrate_frames
    >>> from adfusion.starid.camera.view import stars_in_view
    >>> cat, bright = Catalog.hipparcos(mag_limit=6.0), Catalog.hipparcos(mag_limit=5.0)
    >>> true = Camera(np.array([[1500.0, 0, 500], [0, 1500.0, 390], [0, 0, 1]]),
    ...               [-0.2, 0.05, 0.0, 0.0, 0.0], 1024, 768)
    >>> frames = []
    >>> for ra in (1.0, 2.0, 3.0):
    ...     _, xy = stars_in_view(cat, true, rot.q_cam_icrs_from_radec_roll(ra, 0.3, 0.5))
    ...     frames.append(xy)
    >>> res = calibrate_frames(frames, Camera.pinhole(1024, 768, 37.0), cat,
    ...                        id_catalog=bright, fov_error_deg=2.0)
    >>> res.n_frames, round(float(res.camera.K[0, 0])), round(float(res.camera.D[0]), 3)
    (3, 1500, -0.2)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from adfusion.starid.camera.calibrate import CameraModelFit, fit_camera_model
from adfusion.starid.camera.model import Camera
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from adfusion.maths import rotations as rot

__all__ = ["DEFAULT_TERMS", "JointCalibration", "NoFrameIdentified", "calibrate_frames"]


class NoFrameIdentified(ValueError):
    """None of the frames given to :func:`calibrate_frames` could be identified (the
    message says why, frame by frame; :attr:`failed` maps each frame's index to its
    reason): nothing to fit."""

    def __init__(self, message: str, failed: dict[int, str] | None = None) -> None:
        super().__init__(message)
        self.failed = dict(failed or {})

#: What ``adfusion calibrate`` fits by default: focal length, principal point, and OpenCV
#: radial k1, k2 and tangential p1, p2.
DEFAULT_TERMS = ("focal", "principal", "k1", "k2", "tangential")
_MIN_RADIUS_PX = 1.5


@dataclass(frozen=True)
class JointCalibration:
    """Result of :func:`calibrate_frames`."""

    camera: Camera
    fit: CameraModelFit
    frames_used: list[int]  # indices into the input frames
    frames_failed: dict[int, str] = field(default_factory=dict)  # index → reason
    stars_per_frame: list[int] = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        return len(self.frames_used)

    @property
    def sigma_px(self) -> float:
        return self.fit.sigma_px

    @property
    def q_cam_icrs(self) -> list[NDArray[np.float64]]:
        """The fitted attitude of each used frame (in ``frames_used`` order)."""
        return self.fit.q_cam_icrs


def calibrate_frames(
    detections: list,
    camera: Camera,
    catalog,
    *,
    id_catalog=None,
    terms: tuple[str, ...] | str = DEFAULT_TERMS,
    radius_px: float = 6.0,
    iterations: int = 4,
    **solver_kw,
) -> JointCalibration:
    """Fit ``camera`` (the nominal model) to many frames of star detections.

    ``detections``: per frame a :class:`starid.Detections` or an (N, 2) pixel array,
    brightest first. ``catalog`` supplies the stars paired in the fit; ``id_catalog``
    (default: the same) the identification's. ``solver_kw`` go to :class:`starid.Solver`
    (``fov_error_deg``, ``fov_range_deg``, …). Raises ``ValueError`` when fewer than one
    frame is identified.
    """
    from adfusion.starid.solver import Solver

    solver = Solver(id_catalog if id_catalog is not None else catalog, camera,
                    fit_camera="none", **solver_kw)
    xys, qs, cams, used, failed = [], [], [], [], {}
    for k, det in enumerate(detections):
        xy = np.asarray(det.xy if hasattr(det, "xy") else det, np.float64).reshape(-1, 2)
        sol = solver.solve(det)
        if not sol.ok:
            failed[k] = sol.reason
            continue
        xys.append(xy)
        qs.append(sol.q_cam_icrs)
        cams.append(sol.camera)
        used.append(k)
    if not used:
        raise NoFrameIdentified("no frame could be identified: "
                                + "; ".join(f"frame {k}: {r}" for k, r in failed.items()),
                                failed)
    # start from the median focal length of the frames' own solutions
    scale = float(np.median([c.K[0, 0] for c in cams])) / camera.K[0, 0]
    cam = camera.scaled(scale) if abs(scale - 1) > 1e-12 else camera
    vectors = np.asarray(catalog.vectors, np.float64)
    radius = float(radius_px)
    fit = None
    for _ in range(max(1, iterations)):
        pairs = [_associate(xy, q, cam, vectors, radius) for xy, q in zip(xys, qs,
                                                                           strict=True)]
        frames = [(xy[d], vectors[c]) for xy, (d, c) in zip(xys, pairs, strict=True)]
        keep = [i for i, (a, _) in enumerate(frames) if len(a) >= 3]
        if not keep:
            raise ValueError("no frame kept 3 or more paired stars")
        fit = fit_camera_model([frames[i] for i in keep], cam, terms,
                               q_cam_icrs=[qs[i] for i in keep])
        # the next round from this fit, every frame with its new attitude
        cam = fit.camera
        for j, i in enumerate(keep):
            qs[i] = fit.q_cam_icrs[j]
        radius = max(_MIN_RADIUS_PX, 5.0 * fit.sigma_px)
    used_final = [used[i] for i in keep]
    for i in range(len(used)):
        if i not in keep:
            failed[used[i]] = "fewer than 3 stars paired"
    return JointCalibration(cam, fit, used_final, failed,
                            [len(frames[i][0]) for i in keep])


def _associate(xy: NDArray, q: NDArray, cam: Camera, vectors: NDArray,
               radius_px: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Detection and catalogue indices paired one to one (nearest, within the radius)."""
    v = rot.rotate(q, vectors)
    front = np.flatnonzero(v[:, 2] > 0.5)
    pxy = cam.vectors_to_pixels(v[front])
    inside = np.all(np.isfinite(pxy), axis=1) & cam.in_frame(pxy, margin=-radius_px)
    front, pxy = front[inside], pxy[inside]
    if len(pxy) == 0 or len(xy) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    d, j = cKDTree(pxy).query(xy, distance_upper_bound=radius_px)
    det = np.flatnonzero(np.isfinite(d))
    # one to one: each catalogue star keeps its closest detection
    order = det[np.argsort(d[det], kind="stable")]
    _, first = np.unique(j[order], return_index=True)
    det = np.sort(order[first])
    # and a detection with a second catalogue star nearly as close is ambiguous: dropped
    if len(det):
        d2, _ = cKDTree(pxy).query(xy[det], k=2)
        d2 = np.atleast_2d(d2)
        det = det[~(d2[:, 1] < 2.0 * d2[:, 0] + 0.5)] if d2.shape[1] > 1 else det
    return det, front[j[det]]
