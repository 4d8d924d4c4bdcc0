"""Deterministic simulation scenarios: time-ordered gyro, magnetometer, star-camera and truth
samples, the streams behind ``adfusion simulate``.

Two generators, each returning a :class:`Scenario`:

* :func:`oedipus` — an OEDIPUS-C-like sounding rocket (Poker Flat, night of 1995-11-07 UTC):
  a spinning, coning payload on a ballistic arc to ~800 km, an intensified 512×480 video camera
  looking near Cassiopeia/Cepheus with the tether in view, a 200 Hz gyro and a 50 Hz
  magnetometer;
* :func:`leo` — an Earth-pointing satellite in a circular 500 km sun-synchronous orbit with a
  1024×1024, 20° star tracker at 4 Hz, a 10 Hz gyro and a 2 Hz magnetometer.

:meth:`Scenario.events` yields :class:`Event` objects in time order (ties: truth, gyro, mag,
frame). Everything is computed from ``seed``: two runs give the same samples bit for bit.
Truth and the (small) gyro and magnetometer streams are computed up front; frames are
rendered one at a time as the iterator reaches them, so a 1800-frame run never holds more
than one image. Nothing here writes files (docs/decisions.md): the caller records the events.

Event kinds and their ``data`` (NumPy arrays, SI units, docs/conventions.md):

* ``"truth"`` — at every distinct sample time: ``q_body_icrs`` (4,), ``omega_body_rad_s``
  (3,), ``bias_rad_s`` (3,) (the gyro's true bias at its latest sample; the initial bias
  before the first).
* ``"gyro"`` — ``omega_meas_rad_s`` (3,) = ω + bias + noise, ``bias_rad_s`` (3,) (true).
* ``"mag"`` — ``b_body_nT`` (3,) measured, ``b_ref_icrs_nT`` (3,) the IGRF field at the
  vehicle in ICRS (what a filter compares against), ``lat_deg``, ``lon_deg``, ``alt_m``.
* ``"frame"`` — ``index``, ``exposure_s``, and either ``image`` ((H, W) ``uint8`` /
  ``uint16``, ``render=True``) or ``xy`` ((N, 2) noisy centroids of the stars in view,
  brightest first, ``render=False``); with both, the truth of the frame: ``true_xy``,
  ``star_index`` (into ``Scenario.catalog``), ``hip`` (catalogue ids), ``q_cam_icrs``.

Example:
    >>> from adfusion.sensors.scenarios import oedipus
    >>> sc = oedipus(duration_s=0.1, render=False)
    >>> sc.camera.width, sc.camera.height, round(sc.camera.fov_y_deg, 2)
    (512, 480, 20.33)
    >>> [e.kind for e in sc.events()][:5]
    ['truth', 'gyro', 'mag', 'frame', 'truth']
    >>> sum(e.kind == "gyro" for e in sc.events()), sc.config["gyro"]["rate_hz"]
    (20, 200.0)
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from functools import cached_property
from typing import Any

import numpy as np
from adfusion.sensors.dynamics import Trajectory, simulate_rate_profile, simulate_rigid_body
from adfusion.sensors.gyro import GyroModel
from adfusion.sensors.magnetometer import MagnetometerModel, field_icrs_nT, r_icrs_ecef
from adfusion.sensors.render import Intensifier, SensorModel, Tether, render_frame
from adfusion.starid.camera.model import Camera
from adfusion.starid.catalog.stars import Catalog
from numpy.typing import ArrayLike, NDArray

from adfusion.maths import rotations as rot
from adfusion.plain import to_jsonable

__all__ = [
    "KINDS",
    "Event",
    "FrameTruth",
    "MultiHeadScenario",
    "Scenario",
    "ballistic_position",
    "ecef_to_geodetic",
    "leo",
    "leo_three_heads",
    "oedipus",
]

Array = NDArray[np.float64]

#: Event kinds, in the order they are emitted at equal times.
KINDS = ("truth", "gyro", "mag", "frame")

_WGS84_A = 6378137.0
_WGS84_F = 1.0 / 298.257223563
_MU_EARTH = 3.986004418e14  # m³/s²

# Poker Flat Research Range, Alaska
POKER_FLAT_LAT_DEG = 65.12
POKER_FLAT_LON_DEG = -147.43


@dataclass(frozen=True)
class Event:
    """One sample: time from the scenario start (s), kind (one of :data:`KINDS`), payload.

    ``t_ns`` is the same time in integer nanoseconds (exact: sample k of a stream at rate r
    is at ``round(k · 1e9 / r)`` ns), for MCAP log times relative to ``Scenario.start_utc``.
    """

    t_s: float
    kind: str
    data: dict[str, Any]
    t_ns: int = 0


@dataclass(frozen=True)
class FrameTruth:
    """The truth behind one frame: attitude at mid-exposure and the catalogue stars whose
    mid-exposure images fall inside the frame, brightest first.

    Attributes:
        t_s: frame time (mid-exposure), s from the scenario start.
        q_cam_icrs: (4,) camera attitude.
        xy: (N, 2) true pixel positions; star_index: (N,) indices into the catalogue;
        hip: (N,) catalogue ids; mag: (N,) magnitudes.
    """

    t_s: float
    q_cam_icrs: Array
    xy: Array
    star_index: NDArray[np.intp]
    hip: NDArray[np.int64]
    mag: Array

    @property
    def n_in_view(self) -> int:
        """How many catalogue stars are in view (the replay acceptance counts frames with
        ≥ 3)."""
        return len(self.star_index)


def _sample_times(duration_s: float, rate_hz: float) -> tuple[Array, NDArray[np.int64]]:
    """Times ``k / rate`` in ``[0, duration)`` (s) and the same in integer ns."""
    n = int(np.ceil(duration_s * rate_hz - 1e-9))
    k = np.arange(max(n, 0))
    return k / rate_hz, np.array([round(i * 1e9 / rate_hz) for i in k], dtype=np.int64)


def _seed_for(seed: int, stream: int, index: int = 0) -> int:
    """An independent 32-bit seed per (stream, index), from the scenario seed."""
    ss = np.random.SeedSequence(entropy=seed, spawn_key=(stream, index))
    return int(ss.generate_state(1)[0])


class Scenario:
    """A deterministic multi-sensor simulation (use :func:`oedipus` or :func:`leo`).

    Attributes:
        name: scenario name.
        camera: the star camera (:class:`starid.Camera`).
        q_body_cam: (4,) camera mounting, ``v_body = R(q_body_cam) v_cam``.
        config: JSON-ready dict of every parameter (seed included), for MCAP metadata.
        catalog: the catalogue the frames are rendered from.
        sensor: the detector model (:class:`SensorModel`).
        start_utc: UTC time of ``t = 0`` (timezone-aware).
        duration_s, seed, render: as given.
        gyro_hz, mag_hz, fps, exposure_s: sample rates and the frame exposure.
    """

    def __init__(
        self,
        *,
        name: str,
        camera: Camera,
        q_body_cam: ArrayLike,
        catalog: Catalog,
        sensor: SensorModel,
        start_utc: datetime,
        duration_s: float,
        seed: int,
        render: bool,
        gyro_hz: float,
        mag_hz: float,
        fps: float,
        exposure_s: float,
        gyro_kw: dict[str, Any],
        mag_kw: dict[str, Any],
        truth_fn: Callable[[Array], Trajectory],
        position_fn: Callable[[Array], tuple[Array, Array, Array]],
        tethers: tuple[Tether, ...] = (),
        centroid_sigma_px: float = 0.3,
        config: dict[str, Any] | None = None,
    ) -> None:
        if not (np.isfinite(duration_s) and duration_s > 0):
            raise ValueError(f"duration_s must be > 0, got {duration_s!r}")
        for what, rate in (("gyro_hz", gyro_hz), ("mag_hz", mag_hz), ("fps", fps)):
            if not (np.isfinite(rate) and rate > 0):
                raise ValueError(f"{what} must be a finite rate > 0, got {rate!r}")
        if not (np.isfinite(exposure_s) and exposure_s >= 0):
            raise ValueError(f"exposure_s must be a finite duration ≥ 0, got {exposure_s!r}")
        self.name = name
        self.camera = camera
        self.q_body_cam = rot.canonical(rot.normalize(np.asarray(q_body_cam, np.float64)))
        self.catalog = catalog
        self.sensor = sensor
        self.start_utc = start_utc
        self.duration_s = float(duration_s)
        self.seed = int(seed)
        self.render = bool(render)
        self.gyro_hz, self.mag_hz, self.fps = float(gyro_hz), float(mag_hz), float(fps)
        self.exposure_s = float(exposure_s)
        self.tethers = tuple(tethers)
        self.centroid_sigma_px = float(centroid_sigma_px)
        self._gyro_kw = dict(gyro_kw)
        self._mag_kw = dict(mag_kw)
        self._truth_fn = truth_fn
        self._position_fn = position_fn
        self.t_gyro, self._ns_gyro = _sample_times(duration_s, gyro_hz)
        self.t_mag, self._ns_mag = _sample_times(duration_s, mag_hz)
        self.t_frame, self._ns_frame = _sample_times(duration_s, fps)
        self.config: dict[str, Any] = to_jsonable({
            "scenario": name,
            "seed": self.seed,
            "duration_s": self.duration_s,
            "render": self.render,
            "start_utc": start_utc,
            "camera": {**camera.to_dict(), "fov_x_deg": camera.fov_x_deg,
                       "fov_y_deg": camera.fov_y_deg, "fps": self.fps,
                       "exposure_s": self.exposure_s,
                       "centroid_sigma_px": self.centroid_sigma_px},
            "q_body_cam": self.q_body_cam,
            "catalog": {"source": catalog.source, "epoch": catalog.epoch,
                        "n_stars": len(catalog), "faintest_mag": float(np.max(catalog.mag))},
            "sensor": {k: (v if k != "intensifier" else (None if v is None else vars(v)))
                       for k, v in vars(sensor).items()},
            "tethers": [vars(t) for t in self.tethers],
            "gyro": {"rate_hz": self.gyro_hz, **self._gyro_kw},
            "mag": {"rate_hz": self.mag_hz, **self._mag_kw},
            **(config or {}),
        })

    def __repr__(self) -> str:
        return (f"Scenario({self.name!r}, {self.duration_s:g} s, seed {self.seed}, "
                f"{len(self.t_frame)} frames, {len(self.t_gyro)} gyro, {len(self.t_mag)} mag)")

    # --- truth -------------------------------------------------------------------------

    @cached_property
    def _times(self) -> tuple[Array, NDArray[np.int64]]:
        """All distinct sample times (s, ns), increasing."""
        ns, first = np.unique(np.concatenate([self._ns_gyro, self._ns_mag, self._ns_frame]),
                              return_index=True)
        t = np.concatenate([self.t_gyro, self.t_mag, self.t_frame])[first]
        return t, ns

    @cached_property
    def truth(self) -> Trajectory:
        """Truth attitude and rate at every distinct sample time (``truth.t``)."""
        return self._truth_fn(self._times[0])

    def _truth_index(self, ns: NDArray[np.int64]) -> NDArray[np.intp]:
        return np.searchsorted(self._times[1], ns)

    @cached_property
    def _mag_reference(self) -> tuple[Array, Array, Array, Array]:
        """(b_ref_icrs_nT (M, 3), lat, lon, alt) at the magnetometer times."""
        lat, lon, alt = self._position_fn(self.t_mag)
        if len(self.t_mag) == 0:
            return np.empty((0, 3)), lat, lon, alt
        utc = [self.start_utc + timedelta(seconds=float(t)) for t in self.t_mag]
        b = field_icrs_nT(lat, lon, alt, utc).reshape(-1, 3)
        return b, lat, lon, alt

    def frame_q_cam_icrs(self, index: int) -> Array:
        """True camera attitude at frame ``index`` (mid-exposure)."""
        i = self._truth_index(self._ns_frame[index : index + 1])[0]
        return rot.canonical(rot.multiply(rot.inverse(self.q_body_cam),
                                          self.truth.q_body_icrs[i]))

    def frame_index(self, t_s: float) -> int:
        """Index of the frame at time ``t_s`` (must be a frame time to within 1 µs)."""
        k = round(t_s * self.fps)
        if not (0 <= k < len(self.t_frame)) or abs(self.t_frame[k] - t_s) > 1e-6:
            raise ValueError(f"no frame at t = {t_s} s")
        return k

    def frame_truth(self, t_s: float) -> FrameTruth:
        """Which catalogue stars are in view at the frame time ``t_s``, brightest first.

        >>> sc = oedipus(duration_s=0.1, render=False)
        >>> ft = sc.frame_truth(sc.t_frame[1])
        >>> ft.n_in_view >= 3, ft.xy.shape == (ft.n_in_view, 2)
        (True, True)
        """
        k = self.frame_index(t_s)
        q = self.frame_q_cam_icrs(k)
        v = rot.rotate(q, self.catalog.vectors)
        front = np.flatnonzero(v[:, 2] > 0)
        xy = self.camera.vectors_to_pixels(v[front])
        inside = self.camera.in_frame(xy)
        idx, xy = front[inside], xy[inside]
        order = np.argsort(self.catalog.mag[idx], kind="stable")
        idx = idx[order]
        return FrameTruth(float(self.t_frame[k]), q, xy[order], idx,
                          np.asarray(self.catalog.ids)[idx], self.catalog.mag[idx])

    # --- sensors -----------------------------------------------------------------------

    def gyro_samples(self) -> tuple[Array, Array]:
        """(omega_meas (G, 3), true bias (G, 3)) at ``t_gyro``; re-seeded on every call."""
        gyro = GyroModel(rate_hz=self.gyro_hz, seed=_seed_for(self.seed, 0), **self._gyro_kw)
        i = self._truth_index(self._ns_gyro)
        s = gyro.measure_many(self.t_gyro, self.truth.omega_body_rad_s[i])
        return s.omega_meas, s.bias

    def mag_samples(self) -> Array:
        """Measured body-frame field (M, 3) nT at ``t_mag``; re-seeded on every call."""
        mag = MagnetometerModel(seed=_seed_for(self.seed, 1), **self._mag_kw)
        b_ref = self._mag_reference[0]
        i = self._truth_index(self._ns_mag)
        return mag.measure(rot.rotate(self.truth.q_body_icrs[i], b_ref))

    def frame(self, index: int) -> dict[str, Any]:
        """The payload of frame ``index`` (see the module docstring), rendered on demand."""
        q_cam = self.frame_q_cam_icrs(index)
        i = self._truth_index(self._ns_frame[index : index + 1])[0]
        seed = _seed_for(self.seed, 2, index)
        out: dict[str, Any] = {"index": int(index), "exposure_s": self.exposure_s}
        if self.render:
            r_cam_body = rot.to_matrix(self.q_body_cam).T
            fr = render_frame(self.camera, q_cam, self.catalog.vectors, self.catalog.mag,
                              self.sensor, seed,
                              omega_cam_rad_s=r_cam_body @ self.truth.omega_body_rad_s[i],
                              exposure_s=self.exposure_s, tethers=self.tethers)
            order = np.argsort(self.catalog.mag[fr.star_index], kind="stable")
            out["image"] = fr.image
            true_xy, idx = fr.star_xy[order], fr.star_index[order]
        else:
            ft = self.frame_truth(float(self.t_frame[index]))
            rng = np.random.default_rng(seed)
            true_xy, idx = ft.xy, ft.star_index
            out["xy"] = true_xy + rng.normal(0.0, self.centroid_sigma_px, true_xy.shape)
        out["true_xy"] = true_xy
        out["star_index"] = idx
        out["hip"] = np.asarray(self.catalog.ids)[idx]
        out["q_cam_icrs"] = q_cam
        return out

    def events(self) -> Iterator[Event]:
        """All samples in time order (ties: truth, gyro, mag, frame); frames are rendered
        lazily. Each call starts afresh and yields the same events."""
        t_all, ns_all = self._times
        omega_meas, bias = self.gyro_samples()
        b_meas = self.mag_samples()
        b_ref, lat, lon, alt = self._mag_reference
        bias0 = np.broadcast_to(np.asarray(self._gyro_kw.get("bias_rad_s", 0.0),
                                           np.float64), (3,))
        # true bias at every truth time: the latest gyro sample's (bias0 before the first)
        last = np.searchsorted(self._ns_gyro, ns_all, side="right") - 1
        truth_bias = np.vstack([bias0, bias])[last + 1] if len(bias) else \
            np.tile(bias0, (len(ns_all), 1))
        streams = [(ns_all, t_all), (self._ns_gyro, self.t_gyro), (self._ns_mag, self.t_mag),
                   (self._ns_frame, self.t_frame)]
        ns = np.concatenate([s[0] for s in streams])
        ts = np.concatenate([s[1] for s in streams])
        kind = np.concatenate([np.full(len(s[0]), j) for j, s in enumerate(streams)])
        idx = np.concatenate([np.arange(len(s[0])) for s in streams])
        order = np.lexsort((kind, ns))
        tr = self.truth
        for o in order:
            k, i, t, n = int(kind[o]), int(idx[o]), float(ts[o]), int(ns[o])
            if k == 0:
                data = {"q_body_icrs": tr.q_body_icrs[i].copy(),
                        "omega_body_rad_s": tr.omega_body_rad_s[i].copy(),
                        "bias_rad_s": truth_bias[i].copy()}
            elif k == 1:
                data = {"omega_meas_rad_s": omega_meas[i].copy(), "bias_rad_s": bias[i].copy()}
            elif k == 2:
                data = {"b_body_nT": b_meas[i].copy(), "b_ref_icrs_nT": b_ref[i].copy(),
                        "lat_deg": float(lat[i]), "lon_deg": float(lon[i]),
                        "alt_m": float(alt[i])}
            else:
                data = self.frame(i)
            yield Event(t, KINDS[k], data, n)


# --------------------------------------------------------------------------------------------
# OEDIPUS-C-like sounding rocket


def ballistic_position(
    met_s: ArrayLike,
    apogee_m: float = 800e3,
    t_apogee_s: float = 440.0,
    ground_speed_m_s: float = 550.0,
    azimuth_deg: float = 0.0,
    lat0_deg: float = POKER_FLAT_LAT_DEG,
    lon0_deg: float = POKER_FLAT_LON_DEG,
) -> tuple[Array, Array, Array]:
    """A simple ballistic arc from the launcher: (lat_deg, lon_deg, alt_m) at mission
    elapsed times ``met_s``.

    Altitude is a parabola through the launcher at ``t = 0`` and ``apogee_m`` at
    ``t_apogee_s``: ``h(t) = apogee − ½ g_eff (t − t_apogee)²`` with ``g_eff = 2 apogee /
    t_apogee²`` (8.26 m/s² for 800 km at 440 s, the mean gravity over the arc); the
    boost phase is not modelled. The ground track leaves the launcher along ``azimuth_deg``
    (0 = north) at a constant ``ground_speed_m_s`` on a sphere of the WGS-84 equatorial
    radius.

    >>> lat, lon, alt = ballistic_position([0.0, 440.0])
    >>> alt.round(3).tolist(), bool(lat[1] - lat[0] > 2.0)
    ([0.0, 800000.0], True)
    """
    t = np.asarray(met_s, dtype=np.float64).reshape(-1)
    g_eff = 2.0 * apogee_m / t_apogee_s**2
    alt = apogee_m - 0.5 * g_eff * (t - t_apogee_s) ** 2
    d = ground_speed_m_s * t / _WGS84_A  # angular distance along the great circle, rad
    lat0, lon0, az = np.radians([lat0_deg, lon0_deg, azimuth_deg])
    lat = np.arcsin(np.sin(lat0) * np.cos(d) + np.cos(lat0) * np.sin(d) * np.cos(az))
    lon = lon0 + np.arctan2(np.sin(az) * np.sin(d) * np.cos(lat0),
                            np.cos(d) - np.sin(lat0) * np.sin(lat))
    return np.degrees(lat), np.degrees(lon), alt


def _frame_from(z: Array, x_hint: Array) -> Array:
    """Columns (x, y, z) of a right-handed frame with z given and x nearest ``x_hint``."""
    z = z / np.linalg.norm(z)
    x = x_hint - (x_hint @ z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def oedipus(
    duration_s: float = 60.0,
    seed: int = 0,
    render: bool = True,
    *,
    spin_rev_s: float = 0.5,
    coning_deg: float = 3.0,
    camera_tilt_deg: float = 2.0,
    target_ra_deg: float = 350.0,
    target_dec_deg: float = 62.0,
    exposure_s: float = 1.0 / 60.0,
    met_start_s: float = 420.0,
    mag_limit: float = 5.0,
) -> Scenario:
    """An OEDIPUS-C-like flight: spinning, coning payload; intensified video; gyro; mag.

    Physical model (every value is also in ``Scenario.config``):

    * **Launch and trajectory**: Poker Flat (65.12° N, 147.43° W) at 1995-11-07 08:00 UTC
      (23:00 local on 6 November; the target is circumpolar there, ≥ 37° above the horizon).
      :func:`ballistic_position`: a parabolic altitude profile with 800 km apogee 440 s after
      launch, drifting north at 550 m/s. ``t = 0`` of the scenario is ``met_start_s``
      (default 420 s, ~800 km) after launch; the magnetometer's IGRF reference is taken at
      this position.
    * **Attitude**: torque-free rigid body (:func:`simulate_rigid_body`), inertia
      diag(40, 41, 4) kg m² (a long payload: body +z the long, minimum-inertia axis), spin
      ``spin_rev_s`` (0.5 rev/s = 3.14 rad/s) about +z with a transverse rate giving a
      ``coning_deg`` (3°) half-angle between +z and the angular momentum; the momentum
      points at (``target_ra_deg``, ``target_dec_deg``) = (350°, +62°), between Cassiopeia
      and Cepheus. Coning period ≈ 2π·I_t/(I_s·ω_s) ≈ 20 s.
    * **Camera**: ``Camera.pinhole(512, 480, 25.84, fov_y_deg=20.33)`` (non-square pixels, as
      the digitised video of the real camera), boresight tilted
      ``camera_tilt_deg`` (2°) from the spin axis towards body +x (a rotation about body +y),
      so it stays within coning + tilt ≈ 5° of the target; 30 fps, ``exposure_s`` = 1/60 s
      (one video field), stars of V < ``mag_limit`` (5.0) from Hipparcos at epoch 1995.85.
      Intensified detector: photo-events at 2e4 per exposure for V = 0, 1.5 px PSF, gamma
      MCP gain, bloom and glow, 8-bit output. The tether: a bright line (300 events/px)
      entering from the bottom edge, fixed in the camera frame.
    * **Gyro** 200 Hz: ARW 2e-4 rad/√s, RRW 2e-6 rad/s^1.5, bias (2, −1.5, 1) mrad/s, no
      scale-factor or misalignment errors. **Magnetometer** 50 Hz: 30 nT noise.

    Spin and blur: at 1/60 s a star r px from the spin centre streaks ≈ 0.052·r px at
    0.5 rev/s; ``starid.detection.detect`` rejects streaks of ≳ 10 px as elongated, so faster spins
    leave only the centre of the frame usable. Measured over 30 frames (seed 2; fraction of
    the stars in view detected within 2 px / frames identified by
    ``Solver(Catalog.hipparcos(5.5), camera)``): 0.5 rev/s 0.69 / 30 of 30 at 1/60 s and
    0.25 / 12 at 1/30 s; 0.8 rev/s 0.32 / 20 and 0.14 / 1; 1.0 rev/s 0.23 / 11 and
    0.10 / 0. (Yee's thesis reports ≈ 25 frames per revolution, 1.2 rev/s, for the real
    flight — harder still.) Rendering takes ~35 ms per frame (intensifier mode, exact
    Poisson events; a 60 s run, 1800 frames, in ~77 s on a shared 2-core VM).

    >>> sc = oedipus(duration_s=0.2, render=False)
    >>> len(sc.t_frame), len(sc.t_gyro), len(sc.t_mag)
    (6, 40, 10)
    """
    camera = Camera.pinhole(512, 480, 25.84, fov_y_deg=20.33)
    inertia = np.diag([40.0, 41.0, 4.0])
    i_t, i_s = inertia[0, 0], inertia[2, 2]
    w_s = 2.0 * np.pi * spin_rev_s
    w_t = i_s * w_s * np.tan(np.radians(coning_deg)) / i_t
    omega0 = np.array([w_t, 0.0, w_s])
    target = rot.radec_to_vector(np.radians(target_ra_deg), np.radians(target_dec_deg))
    north = np.cross(target, np.cross([0.0, 0.0, 1.0], target))
    # body frame with its momentum axis at the target: R_body_icrs = A Bᵀ
    a = _frame_from(inertia @ omega0, np.array([1.0, 0.0, 0.0]))
    b = _frame_from(target, north)
    q0 = rot.from_matrix(a @ b.T)
    tilt = np.radians(camera_tilt_deg)
    r_body_cam = np.array([[np.cos(tilt), 0.0, np.sin(tilt)], [0.0, 1.0, 0.0],
                           [-np.sin(tilt), 0.0, np.cos(tilt)]])
    q_body_cam = rot.from_matrix(r_body_cam)
    launch = datetime(1995, 11, 7, 8, 0, 0, tzinfo=UTC)
    start = launch + timedelta(seconds=met_start_s)
    catalog = Catalog.hipparcos(mag_limit=mag_limit, epoch=1995.85)
    sensor = SensorModel(psf_sigma_px=1.5, zero_point_e=2e4, background_e=1.5,
                         read_noise_e=3.0, gain_e_per_adu=6.0, bias_adu=8.0,
                         full_well_adu=255.0, dtype="uint8",
                         intensifier=Intensifier(glow_events=8.0))
    tether = Tether.from_edge(camera, "bottom", 0.35, 20.0, 140.0, electrons_per_px=300.0,
                              sigma_px=1.5)
    gyro_kw = {"arw_rad_sqrt_s": 2e-4, "rrw_rad_s_sqrt_s": 2e-6,
               "bias_rad_s": [2e-3, -1.5e-3, 1e-3]}
    mag_kw = {"noise_nT": 30.0}
    traj_kw = {"apogee_m": 800e3, "t_apogee_s": 440.0, "ground_speed_m_s": 550.0,
               "azimuth_deg": 0.0}

    def truth_fn(t: Array) -> Trajectory:
        return simulate_rigid_body(inertia, q0, omega0, t)

    def position_fn(t: Array) -> tuple[Array, Array, Array]:
        return ballistic_position(met_start_s + t, **traj_kw)

    config = {
        "launch_utc": launch, "met_start_s": met_start_s,
        "launch_site": {"lat_deg": POKER_FLAT_LAT_DEG, "lon_deg": POKER_FLAT_LON_DEG},
        "trajectory": {"model": "parabolic altitude, constant ground speed", **traj_kw},
        "dynamics": {"model": "torque-free rigid body", "inertia_kg_m2": inertia,
                     "spin_rev_s": spin_rev_s, "coning_deg": coning_deg,
                     "omega0_body_rad_s": omega0, "q0_body_icrs": q0,
                     "momentum_radec_deg": [target_ra_deg, target_dec_deg]},
        "camera_tilt_deg": camera_tilt_deg, "mag_limit": mag_limit,
    }
    return Scenario(
        name="oedipus", camera=camera, q_body_cam=q_body_cam, catalog=catalog, sensor=sensor,
        start_utc=start, duration_s=duration_s, seed=seed, render=render, gyro_hz=200.0,
        mag_hz=50.0, fps=30.0, exposure_s=exposure_s, gyro_kw=gyro_kw, mag_kw=mag_kw,
        truth_fn=truth_fn, position_fn=position_fn, tethers=(tether,), config=config)


# --------------------------------------------------------------------------------------------
# LEO star-tracker satellite


def ecef_to_geodetic(r_ecef: ArrayLike) -> tuple[Array, Array, Array]:
    """WGS-84 geodetic (lat_deg, lon_deg, alt_m) of ECEF positions (N, 3) m (Bowring's
    method with two refinements: sub-millimetre in LEO).

    >>> lat, lon, alt = ecef_to_geodetic([[6378137.0 + 500e3, 0.0, 0.0]])
    >>> lat.round(9).tolist(), lon.tolist(), alt.round(3).tolist()
    ([0.0], [0.0], [500000.0])
    """
    r = np.asarray(r_ecef, dtype=np.float64).reshape(-1, 3)
    a, f = _WGS84_A, _WGS84_F
    e2 = f * (2 - f)
    b = a * (1 - f)
    ep2 = (a**2 - b**2) / b**2
    p = np.hypot(r[:, 0], r[:, 1])
    lon = np.arctan2(r[:, 1], r[:, 0])
    beta = np.arctan2(r[:, 2] * a, p * b)
    for _ in range(3):
        lat = np.arctan2(r[:, 2] + ep2 * b * np.sin(beta) ** 3,
                         p - e2 * a * np.cos(beta) ** 3)
        beta = np.arctan2((1 - f) * np.sin(lat), np.cos(lat))
    n = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    alt = p * np.cos(lat) + r[:, 2] * np.sin(lat) - a**2 / n
    return np.degrees(lat), np.degrees(lon), alt


def leo(
    duration_s: float = 60.0,
    seed: int = 0,
    render: bool = True,
    *,
    altitude_m: float = 500e3,
    inclination_deg: float = 97.4,
    raan_deg: float = 0.0,
    tracker_tilt_deg: float = 30.0,
    exposure_s: float = 0.1,
    mag_limit: float = 6.0,
    q_body_cam: ArrayLike | None = None,
) -> Scenario:
    """An Earth-pointing satellite in a circular orbit with a star tracker.

    ``q_body_cam`` replaces the tracker's mounting described below (see
    :func:`leo_three_heads`).

    Physical model (also in ``Scenario.config``):

    * **Orbit**: circular, ``altitude_m`` (500 km) above the equatorial radius,
      sun-synchronous inclination 97.4°, RAAN 0° in ICRS, argument of latitude 0 at
      ``t = 0`` = 2025-06-01 00:00 UTC; period ≈ 5677 s.
    * **Attitude**: Earth-pointing (LVLH): body +z nadir, +y the negative orbit normal,
      +x ≈ velocity; a constant body rate (0, −n, 0) at the orbital rate
      n ≈ 1.107e-3 rad/s (:func:`simulate_rate_profile`, closed form).
    * **Star tracker**: ``Camera.pinhole(1024, 1024, 20.0)``, boresight at zenith tilted
      ``tracker_tilt_deg`` (30°) towards the orbit normal (far from the Earth's limb,
      68° from nadir), 4 Hz, ``exposure_s`` 0.1 s, stars V < ``mag_limit`` (6.0),
      Hipparcos at epoch 2025.4; a CCD with Gaussian background noise.
    * **Gyro** 10 Hz: ARW 5e-5 rad/√s, RRW 1e-7 rad/s^1.5, bias (30, −20, 10) µrad/s.
      **Magnetometer** 2 Hz: 50 nT noise.

    >>> sc = leo(duration_s=1.0, render=False)
    >>> len(sc.t_frame), len(sc.t_gyro), len(sc.t_mag), sc.camera.width
    (4, 10, 2, 1024)
    """
    camera = Camera.pinhole(1024, 1024, 20.0)
    start = datetime(2025, 6, 1, 0, 0, 0, tzinfo=UTC)
    a = _WGS84_A + altitude_m
    n = float(np.sqrt(_MU_EARTH / a**3))
    inc, raan = np.radians(inclination_deg), np.radians(raan_deg)
    p_hat = np.array([np.cos(raan), np.sin(raan), 0.0])
    q_hat = np.array([-np.cos(inc) * np.sin(raan), np.cos(inc) * np.cos(raan), np.sin(inc)])
    h_hat = np.cross(p_hat, q_hat)
    # LVLH at t = 0 (u = 0): z = −r̂, y = −ĥ, x = y × z
    z_b, y_b = -p_hat, -h_hat
    r_body_icrs = np.vstack([np.cross(y_b, z_b), y_b, z_b])
    q0 = rot.from_matrix(r_body_icrs)
    omega = np.array([0.0, -n, 0.0])
    tilt = np.radians(tracker_tilt_deg)
    z_c = np.array([0.0, -np.sin(tilt), -np.cos(tilt)])
    x_c = np.array([1.0, 0.0, 0.0])
    if q_body_cam is None:
        q_body_cam = rot.from_matrix(np.column_stack([x_c, np.cross(z_c, x_c), z_c]))
    catalog = Catalog.hipparcos(mag_limit=mag_limit, epoch=2025.4)
    sensor = SensorModel(psf_sigma_px=1.2, noise="gaussian")
    gyro_kw = {"arw_rad_sqrt_s": 5e-5, "rrw_rad_s_sqrt_s": 1e-7,
               "bias_rad_s": [3e-5, -2e-5, 1e-5]}
    mag_kw = {"noise_nT": 50.0}

    def truth_fn(t: Array) -> Trajectory:
        return simulate_rate_profile(omega, q0, t)

    def position_icrs(t: Array) -> Array:
        u = n * np.asarray(t)[:, None]
        return a * (np.cos(u) * p_hat + np.sin(u) * q_hat)

    def position_fn(t: Array) -> tuple[Array, Array, Array]:
        if len(t) == 0:
            return np.empty(0), np.empty(0), np.empty(0)
        utc = [start + timedelta(seconds=float(s)) for s in t]
        r_ecef = np.einsum("nji,nj->ni", r_icrs_ecef(utc).reshape(-1, 3, 3),
                           position_icrs(t))
        return ecef_to_geodetic(r_ecef)

    config = {
        "orbit": {"model": "circular", "altitude_m": altitude_m, "semi_major_axis_m": a,
                  "inclination_deg": inclination_deg, "raan_deg": raan_deg,
                  "arg_latitude0_deg": 0.0, "mean_motion_rad_s": n,
                  "period_s": 2 * np.pi / n},
        "dynamics": {"model": "Earth-pointing LVLH, constant body rate",
                     "omega_body_rad_s": omega, "q0_body_icrs": q0},
        "tracker_tilt_deg": tracker_tilt_deg, "mag_limit": mag_limit,
    }
    return Scenario(
        name="leo", camera=camera, q_body_cam=q_body_cam, catalog=catalog, sensor=sensor,
        start_utc=start, duration_s=duration_s, seed=seed, render=render, gyro_hz=10.0,
        mag_hz=2.0, fps=4.0, exposure_s=exposure_s, gyro_kw=gyro_kw, mag_kw=mag_kw,
        truth_fn=truth_fn, position_fn=position_fn, config=config)


# --------------------------------------------------------------------------------------------
# several star cameras on one body


class MultiHeadScenario:
    """Several star cameras on one body: ``heads`` are scenarios of the same flight (same
    truth, seed and sensors) differing in camera and mounting. :meth:`events` yields the
    first head's truth, gyro and magnetometer samples and every head's frames, each frame's
    data carrying ``head`` (its index). ``camera``, ``q_body_cam`` and ``start_utc`` are the
    first head's; ``config`` is its configuration plus ``heads`` (each head's camera and
    ``q_body_cam``).

    >>> sc = leo_three_heads(duration_s=0.5, render=False)
    >>> sorted({e.data.get("head") for e in sc.events() if e.kind == "frame"})
    [0, 1, 2]
    """

    def __init__(self, heads: list[Scenario]) -> None:
        if not heads:
            raise ValueError("a multi-head scenario needs at least one head")
        self.heads = list(heads)
        first = heads[0]
        self.name = first.name + f"-{len(heads)}heads"
        self.camera, self.q_body_cam, self.start_utc = first.camera, first.q_body_cam, \
            first.start_utc
        self.t_frame = np.concatenate([h.t_frame for h in heads])
        self.config = {**first.config, "scenario": self.name, "heads": [
            {"camera": h.config["camera"], "q_body_cam": h.config["q_body_cam"]}
            for h in heads]}

    def events(self) -> Iterator[Event]:
        def tagged(k: int, h: Scenario) -> Iterator[tuple[int, int, Event]]:
            for e in h.events():
                if e.kind == "frame":
                    e.data["head"] = k
                    yield (e.t_ns, 1, e)
                elif k == 0:
                    yield (e.t_ns, 0, e)

        import heapq

        merged = heapq.merge(*(tagged(k, h) for k, h in enumerate(self.heads)),
                             key=lambda x: (x[0], x[1]))
        for _, _, e in merged:
            yield e


def leo_three_heads(duration_s: float = 30.0, seed: int = 0, render: bool = True,
                    **leo_kw: Any) -> MultiHeadScenario:
    """The :func:`leo` satellite with three star-tracker heads 90° apart, as on satellites
    with three tracker heads: boresights along the edges of a cube corner pointed at the
    zenith (each 54.7° from it, 35.3° above the local horizontal, far from the Earth's
    limb 22° below it), so every head's poorly observed roll is another head's well
    observed cross-boresight axis.

    >>> sc = leo_three_heads(duration_s=1.0, render=False)
    >>> len(sc.heads), len(sc.t_frame)
    (3, 12)
    """
    heads = []
    for k in range(3):
        a = 2 * np.pi * k / 3
        z_c = np.array([np.sqrt(2 / 3) * np.cos(a), np.sqrt(2 / 3) * np.sin(a), -np.sqrt(1 / 3)])
        x_c = np.cross([0.0, 0.0, 1.0], z_c)
        x_c /= np.linalg.norm(x_c)
        q = rot.from_matrix(np.column_stack([x_c, np.cross(z_c, x_c), z_c]))
        heads.append(leo(duration_s, seed, render, q_body_cam=q, **leo_kw))
    return MultiHeadScenario(heads)
