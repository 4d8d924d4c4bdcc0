"""Sensor models and simulators (DESIGN.md): truth dynamics, gyro, magnetometer with the IGRF
reference field in ICRS, and the star-camera frame renderer.

* :mod:`sensors.dynamics` — torque-free rigid body (Euler's equations, coning) and prescribed
  rate profiles → :class:`Trajectory` (``t``, ``q_body_icrs``, ``omega_body_rad_s``).
* :mod:`sensors.gyro` — :class:`GyroModel`: ARW, RRW, bias, scale factor, misalignment,
  saturation, quantisation (Farrenkopf's exact discrete model); :func:`allan_deviation`.
* :mod:`sensors.magnetometer` — :func:`field_icrs_nT` (IGRF-14 via ppigrf, GMST IAU 1982 +
  IAU 1976 precession, ≤ ~30″) and :class:`MagnetometerModel` (noise, hard and soft iron).
* :mod:`sensors.render` — :func:`render_frame` / :func:`render_sky` / :func:`render_stars`:
  Gaussian PSF, shot and read noise, hot pixels, motion streaks, an intensifier mode, planets
  and tethers.

Everything is seeded and deterministic; nothing here writes files (DESIGN.md). Only
``starid`` (camera, catalogue, rotations) is imported from this project.

Example — a spinning payload seen by all three sensors:
    >>> from datetime import datetime
    >>> import numpy as np
    >>> from adfusion import sensors
    >>> from adfusion.starid import Camera, rotations as rot
    >>> J = np.diag([10.0, 10.5, 3.0])                         # kg m², spin about z
    >>> traj = sensors.simulate_rigid_body(J, [1, 0, 0, 0], [0.02, 0.0, 1.0],
    ...                                    np.arange(0.0, 1.0, 0.01))
    >>> gyro = sensors.GyroModel(arw_rad_sqrt_s=1e-4, rrw_rad_s_sqrt_s=1e-6,
    ...                          bias_rad_s=[2e-3, 0, 0], rate_hz=100.0, seed=1)
    >>> omega_meas, bias = gyro.measure_many(traj.t + 0.01, traj.omega_body_rad_s)
    >>> b_icrs = sensors.field_icrs_nT(69.29, 16.02, 2e5, datetime(2025, 1, 20, 22, 0))
    >>> mag = sensors.MagnetometerModel(noise_nT=30.0, hard_iron_nT=[100.0, 0, 0], seed=2)
    >>> b_meas = mag.measure(traj.vectors_in_body(b_icrs))
    >>> cam = Camera.pinhole(512, 480, 25.8)
    >>> q_cam_icrs = traj.q_body_icrs[50]                    # camera = body axes here
    >>> stars = rot.rotate(rot.inverse(q_cam_icrs),
    ...                    cam.pixels_to_vectors([[100.0, 200.0], [300.0, 50.0]]))
    >>> frame = sensors.render_frame(cam, q_cam_icrs, stars, [2.0, 3.0],
    ...                              sensors.SensorModel(noise="gaussian"), seed=3,
    ...                              omega_cam_rad_s=traj.omega_body_rad_s[50],
    ...                              exposure_s=1 / 30)
    >>> omega_meas.shape, b_meas.shape, frame.image.shape, frame.star_xy.round(1).tolist()
    ((100, 3), (100, 3), (480, 512), [[100.0, 200.0], [300.0, 50.0]])
"""

from adfusion.sensors.dynamics import Trajectory, simulate_rate_profile, simulate_rigid_body
from adfusion.sensors.gyro import GyroModel, GyroSample, allan_deviation
from adfusion.sensors.magnetometer import (
    MagnetometerModel,
    field_ecef_nT,
    field_enu_nT,
    field_icrs_nT,
    gmst_rad,
    precession_matrix,
    r_ecef_enu,
    r_icrs_ecef,
)
from adfusion.sensors.render import (
    Frame,
    Intensifier,
    Planet,
    SensorModel,
    Tether,
    magnitude_to_electrons,
    render_frame,
    render_sky,
    render_stars,
)
from adfusion.sensors.scenarios import Event, FrameTruth, Scenario, leo, oedipus

__all__ = [
    "Event",
    "Frame",
    "FrameTruth",
    "GyroModel",
    "GyroSample",
    "Intensifier",
    "MagnetometerModel",
    "Planet",
    "Scenario",
    "SensorModel",
    "Tether",
    "Trajectory",
    "allan_deviation",
    "field_ecef_nT",
    "field_enu_nT",
    "field_icrs_nT",
    "gmst_rad",
    "leo",
    "magnitude_to_electrons",
    "oedipus",
    "precession_matrix",
    "r_ecef_enu",
    "r_icrs_ecef",
    "render_frame",
    "render_sky",
    "render_stars",
    "simulate_rate_profile",
    "simulate_rigid_body",
]
