"""A star camera as a Basilisk sensor: frames rendered from the spacecraft's true state.

:class:`StarCameraModule` reads ``SCStatesMsg`` each time its task runs (the task period is
the camera's frame period) and renders one frame with :func:`sensors.render.render_frame`:
the attitude at the call time is the mid-exposure attitude, the true body rate (``omega_BN_B``
turned into the camera frame) smears the stars over the exposure, and the detector model
adds its noise. The frame, with its truth (attitude, stars in view), is kept on the module
(``latest``) for the navigation module to take; images are not Basilisk messages.

Stray light: a frame is flooded (the sky background rises past the full well, the way the
Sun or the Earth in view blinds a real tracker) inside any of ``blind_windows`` (time
intervals, s), or with ``earth_keepout_deg`` while the Earth's limb is within that angle of
the boresight (the baffle's exclusion angle). :func:`is_flooded` tells such a frame from its
pixels, as flight software would.

Determinism: frame ``k``'s noise is seeded from ``(seed, k)`` only.

Example (a camera staring from a fixed attitude; no Basilisk simulation needed to render):
    >>> import numpy as np
    >>> from adfusion.starid import Camera, Catalog
    >>> cam = StarCameraModule(Camera.pinhole(256, 256, 10.0), Catalog.hipparcos(6.0))
    >>> fr = cam.render(0, [1.0, 0.0, 0.0, 0.0], np.zeros(3), np.array([7e6, 0, 0]))
    >>> fr.image.shape, fr.blinded
    ((256, 256), False)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from Basilisk.architecture import messaging, sysModel
from numpy.typing import ArrayLike, NDArray

from adfusion.basilisk.frames import q_body_icrs_from_sigma_bn
from adfusion.maths import rotations as rot
from adfusion.sensors.render import SensorModel, render_frame
from adfusion.starid.camera.model import Camera
from adfusion.starid.catalog.stars import Catalog

__all__ = ["CameraFrame", "StarCameraModule", "earth_limb_angle_rad", "is_flooded"]

R_EARTH_M = 6378137.0
# the detector's ceiling of the common integer frame types (np.iinfo per frame is slow)
_CEILING = {np.dtype(t): np.iinfo(t).max for t in (np.uint8, np.uint16, np.int16, np.uint32)}


def earth_limb_angle_rad(boresight_icrs: ArrayLike, r_bn_n_m: ArrayLike) -> float:
    """Angle (rad) from a direction to the Earth's limb seen from ``r_bn_n_m`` (negative:
    the direction hits the Earth). In floats: it runs every step of the camera and the
    star-tracker blinding.

    >>> round(float(np.degrees(earth_limb_angle_rad([1.0, 0, 0], [7e6, 0, 0]))), 2)
    114.33
    """
    b1, b2, b3 = (float(c) for c in boresight_icrs)
    r1, r2, r3 = (float(c) for c in r_bn_n_m)
    d = math.sqrt(r1 * r1 + r2 * r2 + r3 * r3)
    nb = math.sqrt(b1 * b1 + b2 * b2 + b3 * b3)
    c = -(b1 * r1 + b2 * r2 + b3 * r3) / (nb * d)
    to_centre = math.acos(min(max(c, -1.0), 1.0))
    return to_centre - math.asin(min(R_EARTH_M / d, 1.0))


def is_flooded(image: NDArray, saturated_fraction: float = 0.5) -> bool:
    """True when most of the frame sits at the detector's ceiling (the dtype's maximum):
    stray light, not stars. Checked on every 8th pixel of every 8th row (cheap).

    >>> is_flooded(np.full((64, 64), 65535, np.uint16)), is_flooded(np.zeros((64, 64), np.uint16))
    (True, False)
    """
    sub = np.asarray(image)[::8, ::8]
    dt = sub.dtype
    top = _CEILING.get(dt)
    if top is None:
        top = np.iinfo(dt).max if np.issubdtype(dt, np.integer) else np.max(sub)
    # (the count over the size: np.mean's value, without its per-call overhead)
    return int(np.count_nonzero(sub >= top)) / sub.size >= saturated_fraction


@dataclass
class CameraFrame:
    """One rendered frame and its truth."""

    index: int
    t_ns: int
    image: NDArray
    q_cam_icrs: NDArray[np.float64]  # true, at mid-exposure
    star_xy: NDArray[np.float64]  # true positions of the catalogue stars in view
    hip: NDArray[np.int64]
    blinded: bool

    @property
    def n_in_view(self) -> int:
        return len(self.hip)


class StarCameraModule(sysModel.SysModel):
    """Basilisk sensor module: a star camera rendering frames at its task's rate.

    Args:
        camera: the camera model (:class:`starid.Camera`).
        catalog: the stars rendered (the sky; a fainter limit than the solver's is fine).
        q_body_cam: the true mounting, ``v_body = R(q_body_cam) v_cam``.
        sensor: detector model (default: the leo tracker's CCD).
        exposure_s: exposure; motion during it smears the stars.
        seed: noise seed of the frames.
        earth_keepout_deg: flood frames with the Earth's limb this close to the boresight
            (None: never).
        blind_windows: time intervals ``(t0_s, t1_s)`` in which frames are flooded.

    Input message: ``scStateInMsg`` (``SCStatesMsg``). Output: :attr:`latest` (a
    :class:`CameraFrame`, or None before the first frame), :attr:`frames` (a count).
    """

    def __init__(self, camera: Camera, catalog: Catalog, q_body_cam: ArrayLike = rot.IDENTITY,
                 *, sensor: SensorModel | None = None, exposure_s: float = 0.1, seed: int = 0,
                 earth_keepout_deg: float | None = None,
                 blind_windows: tuple[tuple[float, float], ...] = ()) -> None:
        super().__init__()
        self.ModelTag = "starCamera"
        self.scStateInMsg = messaging.SCStatesMsgReader()
        self.camera = camera
        self.catalog = catalog
        self.q_body_cam = rot.canonical(rot.normalize(q_body_cam))
        self.q_cam_body = rot.inverse(self.q_body_cam)
        self.R_cam_body = rot.to_matrix(self.q_body_cam).T
        self.sensor = sensor or SensorModel(psf_sigma_px=1.2, noise="gaussian")
        self.exposure_s = float(exposure_s)
        self.seed = int(seed)
        self.earth_keepout_rad = None if earth_keepout_deg is None else \
            float(np.radians(earth_keepout_deg))
        self.blind_windows = tuple((float(a), float(b)) for a, b in blind_windows)
        self._flooded = SensorModel(**{**vars(self.sensor), "background_e":
                                       2.0 * self.sensor.full_well_adu *
                                       self.sensor.gain_e_per_adu})
        self.latest: CameraFrame | None = None
        self.frames = 0

    def Reset(self, CurrentSimNanos: int) -> None:
        self.latest, self.frames = None, 0

    def UpdateState(self, CurrentSimNanos: int) -> None:
        st = self.scStateInMsg()
        self.latest = self.render(self.frames, q_body_icrs_from_sigma_bn(st.sigma_BN),
                                  np.asarray(st.omega_BN_B), np.asarray(st.r_BN_N),
                                  t_ns=int(CurrentSimNanos))
        self.frames += 1

    def render(self, index: int, q_body_icrs: ArrayLike, omega_body_rad_s: ArrayLike,
               r_bn_n_m: ArrayLike, t_ns: int = 0) -> CameraFrame:
        """Frame ``index`` at the given true state (the module's step, callable alone)."""
        q_cam = rot.canonical(rot.multiply(self.q_cam_body, q_body_icrs))
        boresight = rot.to_matrix(q_cam)[2]
        t_s = t_ns * 1e-9
        blinded = (any(a <= t_s < b for a, b in self.blind_windows)
                   or (self.earth_keepout_rad is not None
                       and earth_limb_angle_rad(boresight, r_bn_n_m) < self.earth_keepout_rad))
        ss = np.random.SeedSequence(entropy=self.seed, spawn_key=(2, int(index)))
        fr = render_frame(self.camera, q_cam, self.catalog.vectors, self.catalog.mag,
                          self._flooded if blinded else self.sensor,
                          int(ss.generate_state(1)[0]),
                          omega_cam_rad_s=self.R_cam_body @ np.asarray(omega_body_rad_s),
                          exposure_s=self.exposure_s)
        hip = np.asarray(self.catalog.ids)[fr.star_index]
        return CameraFrame(int(index), int(t_ns), fr.image, q_cam, fr.star_xy, hip, blinded)
