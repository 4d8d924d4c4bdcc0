"""Closed-loop attitude-control scenarios on Basilisk with adfusion in the loop.

One spacecraft in a circular 500 km sun-synchronous orbit (Earth point-mass gravity and the
gravity-gradient torque), three Honeywell HR16 reaction wheels, ``inertial3D`` →
``attTrackingError`` → ``mrpFeedback`` → ``rwMotorTorque``. Sensors, all Basilisk's except
the camera: ``imuSensor`` (10 Hz, white rate noise and a constant bias), ``starTracker``
(4 Hz quaternion), ``magnetometer`` on ``magneticFieldCenteredDipole`` (2 Hz), ``simpleNav``
without noise (the truth), and :class:`~adfusion.basilisk.camera.StarCameraModule` (4 Hz
rendered frames, 0.1 s exposure).

Three estimators run side by side on the same messages: :class:`AdfusionNav` on the camera
frames (+ gyro + magnetometer), :class:`AdfusionNav` on the star tracker's quaternions
(+ gyro), and Basilisk's ``inertialUKF`` on the same star tracker and gyro. ``loop`` chooses
which one ``attTrackingError`` reads: ``"adfusion"`` (the camera one), ``"adfusion_st"``
(adfusion on the star tracker), ``"ukf"`` or ``"truth"`` (``simpleNav``).

Scenarios (:data:`SCENARIOS`): ``leo`` — inertial pointing at the orbit normal (the Earth's
limb stays 22° from the boresight, outside the 15° keep-out); ``slew`` — a 10° slew to a
second target at 120 s (wheel-torque limited, settling over the rest of the run);
``outage`` — the Sun or the Earth in view from 240 s to 300 s: camera frames flooded and
star-tracker samples lost (a prescribed window: in an inertially pointed LEO orbit the
Earth's limb sweeps so slowly past its closest approach that a geometric 60 s grazing pass
would need one 0.004° deep); the estimators bridge on the gyro; ``misaligned`` —
a gyro bias of (0.01, −0.008, 0.006) °/s and the camera mounted 0.05° off its nominal
orientation (the flight software does not know it).

Example:
    >>> run = run_loop(AcsConfig(duration_s=2.0), loop="adfusion", seed=1)
    >>> len(run.camera_steps), run.camera_steps[0]["mode"]
    (9, 'lost-in-space')
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from Basilisk.architecture import messaging, sysModel
from Basilisk.fswAlgorithms import (
    attTrackingError,
    inertial3D,
    inertialUKF,
    mrpFeedback,
    rwMotorTorque,
    stComm,
)
from Basilisk.simulation import (
    GravityGradientEffector,
    imuSensor,
    magneticFieldCenteredDipole,
    magnetometer,
    reactionWheelStateEffector,
    simpleNav,
    spacecraft,
    starTracker,
)
from Basilisk.utilities import (
    SimulationBaseClass,
    macros,
    orbitalMotion,
    simIncludeGravBody,
    simIncludeRW,
    simSetPlanetEnvironment,
)

from adfusion.basilisk.camera import R_EARTH_M, StarCameraModule, earth_limb_angle_rad
from adfusion.basilisk.frames import (
    icrs_from_body_sigma_bn,
    q_body_icrs_from_sigma_bn,
    sigma_bn_from_q_body_icrs,
)
from adfusion.basilisk.log import McapLogModule
from adfusion.basilisk.msgio import author, live_view, setters
from adfusion.basilisk.nav import AdfusionNav
from adfusion.logs import LogWriter
from adfusion.maths import rotations as rot
from adfusion.plain import listed
from adfusion.sensors.render import SensorModel
from adfusion.starid.camera.model import Camera
from adfusion.starid.catalog.stars import Catalog
from adfusion.starid.solver import Solver

__all__ = ["LOOPS", "SCENARIOS", "AcsConfig", "LoopRun", "run_loop", "scenario"]

LOOPS = ("truth", "ukf", "adfusion_st", "adfusion")
MU_EARTH = 3.986004418e14


@dataclass(frozen=True)
class AcsConfig:
    """Every parameter of a closed-loop run (SI units; ``_deg`` where named)."""

    name: str = "leo"
    duration_s: float = 600.0
    altitude_m: float = 500e3
    inclination_deg: float = 97.4
    dt_dyn_s: float = 0.05
    gyro_hz: float = 10.0
    camera_hz: float = 4.0
    mag_hz: float = 2.0
    control_hz: float = 10.0
    # gyro (imuSensor): white rate noise of this ARW (5e-6 rad/√s = 0.017°/√h, a fibre-optic
    # gyro of a precision-pointing bus), a constant bias
    arw_rad_sqrt_s: float = 5e-6
    gyro_bias_rad_s: tuple[float, float, float] = (3e-5, -2e-5, 1e-5)
    # star tracker (starTracker): per-axis white noise
    st_sigma_rad: float = 1e-4
    mag_noise_t: float = 50e-9
    # camera
    width_px: int = 512
    fov_deg: float = 20.0
    exposure_s: float = 0.1
    render_mag_limit: float = 6.0
    solver_mag_limit: float = 6.5
    catalog_epoch: float = 2025.4
    earth_keepout_deg: float = 15.0
    camera_misalignment_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # stray light: camera and star tracker blinded in these intervals (s)
    blind_windows: tuple[tuple[float, float], ...] = ()
    # pointing: boresight tilt from the orbit normal towards nadir at t_tilt_s
    tilt_deg: float = 0.0
    t_tilt_s: float = 270.0
    slew_at_s: float | None = None
    slew_deg: float = 20.0
    initial_error_deg: float = 0.1
    rate_lowpass_hz: float | None = None  # on adfusion's output rate (AdfusionNav)
    # the adfusion filters' gyro-bias random walk (Estimator rrw_rad_s_sqrt_s). The simulated
    # bias is constant, but mrpFeedback damps on gyro − bias: a walk of 1e-7 lets the bias
    # estimate follow the gyro's slow noise, which the 4 Hz fixes see far better than the
    # gyro itself, and the controller gets a better rate where its loop responds (pointing
    # 1.30× → 1.12× truth-fed on seed 0, 1.31× → 1.15× on seed 5; at 1e-8 the bias estimate
    # erred 3–7e-7 rad/s and the loop settled 3–6″ off). 3e-7 points better still (1.07×)
    # but puts the mean NEES at the 95 % band's lower edge (1.70 of 1.68): docs/basilisk.md
    filter_rrw_rad_s_sqrt_s: float = 1e-7
    # tracking frames detected in windows around the predicted stars (AdfusionNav.windows)
    windows: bool = True
    # the solver's a-priori 1-σ centroid error (Solver.centroid_sigma_px): a fix's covariance
    # grows with its residuals above it, never below. Window centroids of this camera are
    # good to ~0.03 px (median against the renderer's truth); the solver's default 0.5 px
    # made every fix's covariance ~100× too large, the filter leaned on the gyro and the
    # estimate erred 4× more (2.6″ → 8.9″ RMS on leo, seeds 0–3, 300 s)
    centroid_sigma_px: float = 0.05
    # star-fix covariance multiplier of the camera estimator (Estimator.fix_covariance_scale).
    # 1: with blended pairs left out of the windows, fixes no longer share a per-star bias
    # that the scale had to cover (it was 4); mean NEES 1.78 over seeds 0–3 (300 s) at 1,
    # 1.54 at 4 — inside the 3-dof band either way, lower error at 1 (2.0″ against 2.6″)
    fix_covariance_scale: float = 1.0
    # inertialUKF process noise, 1-σ per step of [MRP, rate (rad/s)]
    ukf_process_sigma: tuple[float, float] = (1.25e-6, 1e-6)
    # spacecraft and control
    inertia_kg_m2: tuple[float, float, float] = (900.0, 800.0, 600.0)
    mass_kg: float = 750.0
    K: float = 3.5
    P: float = 30.0
    extra: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(self).items()}


def scenario(name: str, **overrides: Any) -> AcsConfig:
    """The named scenario's configuration (see the module docstring).

    >>> scenario("slew").slew_at_s, scenario("outage", duration_s=60.0).duration_s
    (120.0, 60.0)
    """
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; choose one of "
                         f"{listed(sorted(SCENARIOS), None)}")
    return replace(SCENARIOS[name], **overrides)


SCENARIOS: dict[str, AcsConfig] = {
    "leo": AcsConfig(name="leo"),
    "slew": AcsConfig(name="slew", slew_at_s=120.0, slew_deg=10.0),
    "outage": AcsConfig(name="outage", blind_windows=((240.0, 300.0),)),
    "misaligned": AcsConfig(name="misaligned",
                            gyro_bias_rad_s=tuple(np.radians([0.01, -0.008, 0.006])),
                            camera_misalignment_deg=(0.05, 0.0, 0.0)),
}


@dataclass
class LoopRun:
    """What one closed-loop run recorded (arrays over the recorder times ``t``)."""

    config: AcsConfig
    loop: str
    seed: int
    t: np.ndarray
    q_true: np.ndarray  # (N, 4) q_body_icrs
    omega_true: np.ndarray  # (N, 3)
    q_ref: np.ndarray  # (N, 4) reference (target) attitude
    estimates: dict[str, dict[str, np.ndarray]]  # name → {"q": (N, 4), "P": (N, 6, 6)}
    camera_steps: list[dict[str, Any]]
    nav_records: list[dict[str, Any]]  # the camera AdfusionNav's records
    cost_s: dict[str, dict[str, list[float]]]  # module → kind → per-call wall time
    q_body_cam_true: np.ndarray
    q_body_cam_fsw: np.ndarray
    camera: Camera
    gyro: dict[str, np.ndarray]  # t, omega (body), for the log
    mag: dict[str, np.ndarray]  # t, b_body_T, b_ref_n_T
    frames: list[Any]  # CameraFrame objects when keep_frames
    modules: dict[str, Any] = field(default_factory=dict)  # the run's Basilisk modules (and
    # "sim"), alive after the run: benchmarks time their UpdateState on the live messages


class _ImuToAccData(sysModel.SysModel):
    """``IMUSensorMsg`` → ``AccDataMsg``, the gyro buffer ``inertialUKF`` reads (no Basilisk
    module fills it from the simulated IMU). Keeps the last 20 samples, oldest first, in
    the first slots of the 120-packet buffer; the rest stay zero.

    One payload is kept and its packets are written in place through live views (building
    120 packet objects per sample cost ~0.4 ms in Basilisk's Python layer, a fifth of a
    whole ``adfusion acs leo`` run)."""

    N_KEEP = 20

    def __init__(self) -> None:
        super().__init__()
        self.ModelTag = "imuToAccData"
        self.imuInMsg = messaging.IMUSensorMsgReader()
        self.accOutMsg = messaging.AccDataMsg()
        self._out = messaging.AccDataMsgPayload()
        self._slots = self._out.accPkts  # live views of the payload's packets
        self._set_time, self._set_gyro = setters(self._slots[0], "measTime", "gyro_B")
        self._write = author(self.accOutMsg)
        self._pkts: list[tuple[int, list[float]]] = []
        self._imu = None

    def Reset(self, CurrentSimNanos: int) -> None:
        for slot in self._slots[:len(self._pkts)]:
            self._set_time(slot, 0)
            self._set_gyro(slot, [0.0, 0.0, 0.0])
        self._pkts = []
        self._imu = None

    def UpdateState(self, CurrentSimNanos: int) -> None:
        if self._imu is None:
            if not self.imuInMsg.isWritten():
                return
            self._imu = live_view(self.imuInMsg)
        tw = self.imuInMsg.timeWritten()
        pkts = self._pkts
        if not pkts or pkts[-1][0] != tw:
            pkts.append((tw, self._imu.AngVelPlatform))
            if len(pkts) > self.N_KEEP:
                del pkts[0]
            set_time, set_gyro = self._set_time, self._set_gyro
            for slot, (t_pkt, w) in zip(self._slots[:len(pkts)], pkts, strict=True):
                set_time(slot, t_pkt)
                set_gyro(slot, w)
        self._write(self._out, self.moduleID, CurrentSimNanos)


class _BlindedStarTracker(sysModel.SysModel):
    """Passes ``STSensorMsg`` on unless the tracker is blinded: inside ``blind_windows`` or
    with the Earth's limb within ``keepout_rad`` of its true boresight (it looks where the
    camera looks; Basilisk's ``starTracker`` models neither). Blinded samples are not
    written."""

    def __init__(self, keepout_rad: float, q_body_case: np.ndarray,
                 blind_windows: tuple[tuple[float, float], ...] = ()) -> None:
        super().__init__()
        self.ModelTag = "starTrackerBlinding"
        self.stInMsg = messaging.STSensorMsgReader()
        self.scStateInMsg = messaging.SCStatesMsgReader()
        self.stOutMsg = messaging.STSensorMsg()
        self.keepout_rad = float(keepout_rad)
        self.R_body_case = rot.to_matrix(q_body_case)
        self._boresight_body = tuple(self.R_body_case[:, 2].tolist())
        self.blind_windows = tuple(blind_windows)
        self.blinded = 0
        self._write = author(self.stOutMsg)
        self._views = None

    def Reset(self, CurrentSimNanos: int) -> None:
        self._views = None

    def UpdateState(self, CurrentSimNanos: int) -> None:
        t_s = CurrentSimNanos * 1e-9
        if any(a <= t_s < b for a, b in self.blind_windows):
            self.blinded += 1
            return
        if self._views is None:
            self._views = (live_view(self.scStateInMsg), live_view(self.stInMsg))
        sc, st = self._views
        boresight = icrs_from_body_sigma_bn(sc.sigma_BN, self._boresight_body)
        if earth_limb_angle_rad(boresight, sc.r_BN_N) < self.keepout_rad:
            self.blinded += 1
            return
        self._write(st, self.moduleID, CurrentSimNanos)


def _orbit(cfg: AcsConfig) -> tuple[np.ndarray, np.ndarray, float]:
    """(r, v) at t = 0 (argument of latitude 0, RAAN 0) and the mean motion."""
    oe = orbitalMotion.ClassicElements()
    oe.a = R_EARTH_M + cfg.altitude_m
    oe.e, oe.i, oe.Omega, oe.omega, oe.f = 0.0, np.radians(cfg.inclination_deg), 0.0, 0.0, 0.0
    r, v = orbitalMotion.elem2rv(MU_EARTH, oe)
    return np.asarray(r), np.asarray(v), float(np.sqrt(MU_EARTH / oe.a**3))


def _target_q_body_icrs(cfg: AcsConfig) -> np.ndarray:
    """The reference attitude: body +z (the boresight) at the orbit normal, tilted
    ``tilt_deg`` towards nadir at ``t_tilt_s``; body +x in the orbit plane."""
    r0, v0, n = _orbit(cfg)
    h = np.cross(r0, v0)
    h /= np.linalg.norm(h)
    r_hat0, t_hat0 = r0 / np.linalg.norm(r0), v0 / np.linalg.norm(v0)
    u = n * cfg.t_tilt_s
    nadir = -(np.cos(u) * r_hat0 + np.sin(u) * t_hat0)
    g = np.radians(cfg.tilt_deg)
    z = np.cos(g) * h + np.sin(g) * nadir
    x = np.cross(h, nadir)
    x -= (x @ z) * z
    x /= np.linalg.norm(x)
    r_body_icrs = np.vstack([x, np.cross(z, x), z])
    return rot.from_matrix(r_body_icrs)


def _slew_target(cfg: AcsConfig, q0: np.ndarray) -> np.ndarray:
    """The second target: ``slew_deg`` about an axis between body x and y."""
    axis = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    return rot.canonical(rot.multiply(rot.exp_map(np.radians(cfg.slew_deg) * axis), q0))


def _log_config(cfg: AcsConfig, seed: int, loop: str, solver: Solver,
                q_body_cam_fsw: np.ndarray, est_kw: dict[str, Any]) -> dict[str, Any]:
    """Metadata ``config``: the run, and what ``adfusion replay`` reads from it."""
    return {
        "scenario": cfg.name, "seed": int(seed), "loop": loop, "simulator": "basilisk",
        "acs": cfg.as_dict(), "q_body_cam": q_body_cam_fsw.tolist(),
        "mag_limit": cfg.solver_mag_limit,
        "catalog": {"source": "hipparcos", "epoch": cfg.catalog_epoch,
                    "n_stars": len(solver.catalog)},
        "camera": {**solver.camera.to_dict(), "fps": cfg.camera_hz,
                   "exposure_s": cfg.exposure_s, "centroid_sigma_px": cfg.centroid_sigma_px},
        "gyro": {"rate_hz": cfg.gyro_hz, "arw_rad_sqrt_s": est_kw["arw_rad_sqrt_s"],
                 "rrw_rad_s_sqrt_s": est_kw["rrw_rad_s_sqrt_s"],
                 "bias_rad_s": list(cfg.gyro_bias_rad_s)},
        "mag": {"rate_hz": cfg.mag_hz, "noise_nT": cfg.mag_noise_t * 1e9,
                "model": "Basilisk magneticFieldCenteredDipole (IGRF 2020 dipole)"},
    }


def _sec(x: float) -> int:
    return int(macros.sec2nano(x))


def run_loop(cfg: AcsConfig, loop: str = "adfusion", seed: int = 0, *,
             camera_in_sim: bool | None = None, keep_frames: bool = False,
             catalogs: tuple[Catalog, Catalog] | None = None,
             solver: Solver | None = None, log: LogWriter | None = None,
             images: str = "preview", preview_every: int = 40) -> LoopRun:
    """Build and run one closed loop; everything seeded from ``seed``.

    ``camera_in_sim``: render frames and run the camera estimator (default: only when the
    loop is closed on it). ``catalogs``/``solver``: reuse across runs (the sky and the
    solver's catalogue; built from the configuration otherwise). ``log``: an open
    :class:`adfusion.logs.LogWriter` for the run's MCAP log (camera loops only; see
    :mod:`adfusion.basilisk.log` for ``images`` and ``preview_every``).
    """
    if loop not in LOOPS:
        raise ValueError(f"loop must be one of {listed(LOOPS, None)}, got {loop!r}")
    use_camera = (loop == "adfusion") if camera_in_sim is None else bool(camera_in_sim)
    ss = np.random.SeedSequence(entropy=int(seed), spawn_key=(19,))
    s_imu, s_st, s_tam, s_cam, s_init = (int(x) for x in ss.generate_state(5))
    rng = np.random.default_rng(s_init)

    sim = SimulationBaseClass.SimBaseClass()
    dyn = sim.CreateNewProcess("dynamics", 100)
    fsw = sim.CreateNewProcess("fsw", 10)
    dyn.addTask(sim.CreateNewTask("dyn", _sec(cfg.dt_dyn_s)), 100)
    dyn.addTask(sim.CreateNewTask("imu", _sec(1 / cfg.gyro_hz)), 90)
    dyn.addTask(sim.CreateNewTask("cam", _sec(1 / cfg.camera_hz)), 80)
    dyn.addTask(sim.CreateNewTask("tam", _sec(1 / cfg.mag_hz)), 70)
    fsw.addTask(sim.CreateNewTask("nav", _sec(cfg.dt_dyn_s)), 100)
    fsw.addTask(sim.CreateNewTask("ctl", _sec(1 / cfg.control_hz)), 50)
    fsw.addTask(sim.CreateNewTask("rec", _sec(0.5)), 10)

    # --- spacecraft, gravity, wheels ------------------------------------------------
    sc = spacecraft.Spacecraft()
    sc.ModelTag = "sc"
    inertia = np.diag(cfg.inertia_kg_m2)
    sc.hub.mHub = cfg.mass_kg
    sc.hub.IHubPntBc_B = inertia.tolist()
    grav = simIncludeGravBody.gravBodyFactory()
    earth = grav.createEarth()
    earth.isCentralBody = True
    grav.addBodiesTo(sc)
    gg = GravityGradientEffector.GravityGradientEffector()
    gg.ModelTag = "gravityGradient"
    gg.addPlanetName(earth.planetName)
    sc.addDynamicEffector(gg)
    r0, v0, _ = _orbit(cfg)
    sc.hub.r_CN_NInit = r0.tolist()
    sc.hub.v_CN_NInit = v0.tolist()
    q_ref0 = _target_q_body_icrs(cfg)
    err = rng.normal(size=3)
    err *= np.radians(cfg.initial_error_deg) / np.linalg.norm(err)
    q_init = rot.multiply(rot.exp_map(err), q_ref0)
    sc.hub.sigma_BNInit = sigma_bn_from_q_body_icrs(q_init).tolist()
    sc.hub.omega_BN_BInit = [0.0, 0.0, 0.0]
    sim.AddModelToTask("dyn", sc, 100)
    sim.AddModelToTask("dyn", gg, 99)

    rw_factory = simIncludeRW.rwFactory()
    for axis in np.eye(3):
        rw_factory.create("Honeywell_HR16", axis.tolist(), maxMomentum=50.0, Omega=100.0)
    rw_eff = reactionWheelStateEffector.ReactionWheelStateEffector()
    rw_eff.ModelTag = "rw"
    rw_factory.addToSpacecraft(sc.ModelTag, rw_eff, sc)
    sim.AddModelToTask("dyn", rw_eff, 98)
    rw_params = rw_factory.getConfigMessage()

    # --- sensors --------------------------------------------------------------------
    snav = simpleNav.SimpleNav()
    snav.ModelTag = "truthNav"
    snav.scStateInMsg.subscribeTo(sc.scStateOutMsg)
    sim.AddModelToTask("dyn", snav, 90)

    imu = imuSensor.ImuSensor()
    imu.ModelTag = "imu"
    imu.scStateInMsg.subscribeTo(sc.scStateOutMsg)
    imu.RNGSeed = s_imu
    sigma_w = cfg.arw_rad_sqrt_s * np.sqrt(cfg.gyro_hz)  # per-sample rate noise
    imu.PMatrixGyro = (sigma_w * np.eye(3)).tolist()
    imu.setAMatrixGyro(np.zeros((3, 3)).tolist())  # white noise, not a random walk
    imu.setWalkBoundsGyro([1.0, 1.0, 1.0])
    imu.senRotBias = list(cfg.gyro_bias_rad_s)
    imu.senRotMax = 1.0
    sim.AddModelToTask("imu", imu, 100)

    st = starTracker.StarTracker()
    st.ModelTag = "starTracker"
    st.scStateInMsg.subscribeTo(sc.scStateOutMsg)
    st.RNGSeed = s_st
    st.PMatrix = (cfg.st_sigma_rad * np.eye(3)).tolist()
    st.setAMatrix(np.zeros((3, 3)).tolist())
    st.setWalkBounds([1.0, 1.0, 1.0])
    st.dcm_CB = np.eye(3).tolist()
    sim.AddModelToTask("cam", st, 100)
    blind = _BlindedStarTracker(np.radians(cfg.earth_keepout_deg), rot.IDENTITY,
                                cfg.blind_windows)
    blind.stInMsg.subscribeTo(st.sensorOutMsg)
    blind.scStateInMsg.subscribeTo(sc.scStateOutMsg)
    sim.AddModelToTask("cam", blind, 95)
    st_msg = blind.stOutMsg

    mag_env = magneticFieldCenteredDipole.MagneticFieldCenteredDipole()
    mag_env.ModelTag = "magField"
    simSetPlanetEnvironment.centeredDipoleMagField(mag_env, "earth")
    mag_env.addSpacecraftToModel(sc.scStateOutMsg)
    sim.AddModelToTask("tam", mag_env, 100)
    tam = magnetometer.Magnetometer()
    tam.ModelTag = "tam"
    tam.stateInMsg.subscribeTo(sc.scStateOutMsg)
    tam.magInMsg.subscribeTo(mag_env.envOutMsgs[0])
    tam.senNoiseStd = [cfg.mag_noise_t] * 3
    tam.RNGSeed = s_tam
    tam.scaleFactor = 1.0
    sim.AddModelToTask("tam", tam, 90)

    q_body_cam_fsw = np.array([1.0, 0.0, 0.0, 0.0])
    q_body_cam_true = rot.canonical(rot.multiply(
        q_body_cam_fsw, rot.exp_map(np.radians(cfg.camera_misalignment_deg))))
    cam_mod = None
    if use_camera:
        if catalogs is None:
            catalogs = (Catalog.hipparcos(mag_limit=cfg.render_mag_limit,
                                          epoch=cfg.catalog_epoch),
                        Catalog.hipparcos(mag_limit=cfg.solver_mag_limit,
                                          epoch=cfg.catalog_epoch))
        camera = Camera.pinhole(cfg.width_px, cfg.width_px, cfg.fov_deg)
        if solver is None:
            solver = Solver(catalogs[1], camera, centroid_sigma_px=cfg.centroid_sigma_px)
        cam_mod = StarCameraModule(camera, catalogs[0], q_body_cam_true,
                                   sensor=SensorModel(psf_sigma_px=1.2, noise="gaussian"),
                                   exposure_s=cfg.exposure_s, seed=s_cam,
                                   earth_keepout_deg=cfg.earth_keepout_deg,
                                   blind_windows=cfg.blind_windows)
        cam_mod.scStateInMsg.subscribeTo(sc.scStateOutMsg)
        sim.AddModelToTask("cam", cam_mod, 90)
    else:
        camera = Camera.pinhole(cfg.width_px, cfg.width_px, cfg.fov_deg)

    # --- flight software: estimators ------------------------------------------------
    veh = messaging.VehicleConfigMsgPayload()
    veh.ISCPntB_B = inertia.reshape(-1).tolist()
    veh_msg = messaging.VehicleConfigMsg().write(veh)
    bias_sigma0 = max(float(np.max(np.abs(cfg.gyro_bias_rad_s))) * 2.0, 1e-4)
    # fix_covariance_scale and the solver's centroid_sigma_px: see AcsConfig
    est_kw = {"arw_rad_sqrt_s": cfg.arw_rad_sqrt_s, "rrw_rad_s_sqrt_s": cfg.filter_rrw_rad_s_sqrt_s,
              "sigma_bias0_rad_s": bias_sigma0, "exposure_s": cfg.exposure_s}
    navs: dict[str, AdfusionNav] = {}
    if use_camera:
        nav_cam = AdfusionNav(solver, cam_mod, q_body_cam_fsw,
                              fix_covariance_scale=cfg.fix_covariance_scale,
                              earth_keepout_deg=cfg.earth_keepout_deg,
                              rate_lowpass_hz=cfg.rate_lowpass_hz, windows=cfg.windows,
                              **est_kw)
        nav_cam.ModelTag = "adfusionCamera"
        nav_cam.imuInMsg.subscribeTo(imu.sensorOutMsg)
        nav_cam.tamInMsg.subscribeTo(tam.tamDataOutMsg)
        nav_cam.magFieldInMsg.subscribeTo(mag_env.envOutMsgs[0])
        nav_cam.navTransInMsg.subscribeTo(snav.transOutMsg)
        sim.AddModelToTask("nav", nav_cam, 100)
        navs["adfusion"] = nav_cam
    nav_st = AdfusionNav(None, None, st_sigma_rad=cfg.st_sigma_rad, keep_records=False,
                         **{**est_kw, "exposure_s": None})
    nav_st.ModelTag = "adfusionStarTracker"
    nav_st.imuInMsg.subscribeTo(imu.sensorOutMsg)
    nav_st.stInMsg.subscribeTo(st_msg)
    sim.AddModelToTask("nav", nav_st, 90)
    navs["adfusion_st"] = nav_st

    stc = stComm.stComm()
    stc.ModelTag = "stComm"
    stc.dcm_BP = np.eye(3).reshape(-1).tolist()
    stc.stSensorInMsg.subscribeTo(st_msg)
    sim.AddModelToTask("nav", stc, 80)
    acc = _ImuToAccData()
    acc.imuInMsg.subscribeTo(imu.sensorOutMsg)
    sim.AddModelToTask("nav", acc, 79)
    ukf = inertialUKF.inertialUKF()
    ukf.ModelTag = "inertialUKF"
    st_in = inertialUKF.STMessage()
    st_in.noise = (cfg.st_sigma_rad / 4.0) ** 2 * np.eye(3).reshape(-1)  # MRP ≈ angle / 4
    st_in.stInMsg.subscribeTo(stc.stAttOutMsg)
    ukf.STDatasStruct.STMessages = [st_in]
    ukf.STDatasStruct.numST = 1
    ukf.alpha, ukf.beta, ukf.kappa, ukf.switchMag = 0.02, 2.0, 0.0, 1.2
    ukf.stateInit = [*sigma_bn_from_q_body_icrs(q_init).tolist(), 0.0, 0.0, 0.0]
    ukf.covarInit = np.diag([1e-4] * 3 + [1e-6] * 3).reshape(-1).tolist()
    q_att, q_rate = cfg.ukf_process_sigma
    qn = np.diag([q_att**2] * 3 + [q_rate**2] * 3)
    ukf.qNoise = qn.reshape(-1).tolist()
    lp = inertialUKF.LowPassFilterData()
    lp.hStep, lp.omegCutoff = 1.0 / cfg.gyro_hz, 15.0 / (2.0 * np.pi)
    ukf.gyroFilt = [lp, lp, lp]
    ukf.massPropsInMsg.subscribeTo(veh_msg)
    ukf.rwParamsInMsg.subscribeTo(rw_params)
    ukf.rwSpeedsInMsg.subscribeTo(rw_eff.rwSpeedOutMsg)
    ukf.gyrBuffInMsg.subscribeTo(acc.accOutMsg)
    sim.AddModelToTask("nav", ukf, 70)

    # --- flight software: guidance and control --------------------------------------
    guid = inertial3D.inertial3D()
    guid.ModelTag = "inertial3D"
    guid.sigma_R0N = sigma_bn_from_q_body_icrs(q_ref0).tolist()
    sim.AddModelToTask("ctl", guid, 100)
    track = attTrackingError.attTrackingError()
    track.ModelTag = "attTrackingError"
    nav_msg = {"truth": snav.attOutMsg, "ukf": ukf.navStateOutMsg,
               "adfusion_st": nav_st.navAttOutMsg}.get(loop)
    track.attNavInMsg.subscribeTo(nav_msg if nav_msg is not None
                                  else navs["adfusion"].navAttOutMsg)
    track.attRefInMsg.subscribeTo(guid.attRefOutMsg)
    sim.AddModelToTask("ctl", track, 90)
    ctrl = mrpFeedback.mrpFeedback()
    ctrl.ModelTag = "mrpFeedback"
    ctrl.guidInMsg.subscribeTo(track.attGuidOutMsg)
    ctrl.vehConfigInMsg.subscribeTo(veh_msg)
    ctrl.rwParamsInMsg.subscribeTo(rw_params)
    ctrl.rwSpeedsInMsg.subscribeTo(rw_eff.rwSpeedOutMsg)
    ctrl.K, ctrl.Ki, ctrl.P = cfg.K, -1.0, cfg.P
    sim.AddModelToTask("ctl", ctrl, 80)
    alloc = rwMotorTorque.rwMotorTorque()
    alloc.ModelTag = "rwMotorTorque"
    alloc.controlAxes_B = np.eye(3).reshape(-1).tolist()
    alloc.vehControlInMsg.subscribeTo(ctrl.cmdTorqueOutMsg)
    alloc.rwParamsInMsg.subscribeTo(rw_params)
    sim.AddModelToTask("ctl", alloc, 70)
    rw_eff.rwMotorCmdInMsg.subscribeTo(alloc.rwMotorTorqueOutMsg)

    if log is not None:
        if not use_camera:
            raise ValueError("an MCAP log is written for runs with the camera in the loop")
        logger = McapLogModule(log, navs["adfusion"], _log_config(cfg, seed, loop, solver,
                                                                  q_body_cam_fsw, est_kw),
                               images=images, preview_every=preview_every)
        logger.scStateInMsg.subscribeTo(sc.scStateOutMsg)
        logger.imuInMsg.subscribeTo(imu.sensorOutMsg)
        logger.tamInMsg.subscribeTo(tam.tamDataOutMsg)
        logger.magFieldInMsg.subscribeTo(mag_env.envOutMsgs[0])
        logger.ukfInMsg.subscribeTo(ukf.navStateOutMsg)
        sim.AddModelToTask("nav", logger, 1)

    # --- recorders --------------------------------------------------------------------
    rec_truth = sc.scStateOutMsg.recorder()
    rec_ref = guid.attRefOutMsg.recorder()
    rec_ukf = ukf.navStateOutMsg.recorder()
    rec_ukf_f = ukf.filtDataOutMsg.recorder()
    recs = {name: (nav.navAttOutMsg.recorder(), nav.filtDataOutMsg.recorder())
            for name, nav in navs.items()}
    for r in [rec_truth, rec_ref, rec_ukf, rec_ukf_f, *[x for p in recs.values() for x in p]]:
        sim.AddModelToTask("rec", r)
    rec_imu = imu.sensorOutMsg.recorder()
    sim.AddModelToTask("imu", rec_imu, 0)
    rec_tam = tam.tamDataOutMsg.recorder()
    rec_field = mag_env.envOutMsgs[0].recorder()
    sim.AddModelToTask("tam", rec_tam, 0)
    sim.AddModelToTask("tam", rec_field, 0)

    frames: list[Any] = []
    camera_steps: list[dict[str, Any]] = []

    sim.InitializeSimulation()
    stops = [cfg.duration_s]
    if cfg.slew_at_s is not None and cfg.slew_at_s < cfg.duration_s:
        stops = [cfg.slew_at_s, cfg.duration_s]
    for k, t_stop in enumerate(stops):
        if k == 1:  # the slew: a new target for inertial3D
            guid.sigma_R0N = sigma_bn_from_q_body_icrs(_slew_target(cfg, q_ref0)).tolist()
        sim.ConfigureStopTime(_sec(t_stop))
        sim.ExecuteSimulation()

    t = np.asarray(rec_truth.times()) * 1e-9
    q_true = np.array([q_body_icrs_from_sigma_bn(s) for s in rec_truth.sigma_BN])
    q_ref = np.array([q_body_icrs_from_sigma_bn(s) for s in rec_ref.sigma_RN])
    estimates: dict[str, dict[str, np.ndarray]] = {}
    for name, (ra, rf) in recs.items():
        estimates[name] = {"q": np.array([q_body_icrs_from_sigma_bn(s) for s in ra.sigma_BN]),
                           "P": np.asarray(rf.covar).reshape(-1, 6, 6),
                           "valid": np.asarray(rf.covar).reshape(-1, 36)[:, 0] > 0}
    # inertialUKF: covariance of [σ (MRP), ω]; δθ ≈ 4 δσ
    P_ukf = np.asarray(rec_ukf_f.covar).reshape(-1, 6, 6)
    J = np.diag([4.0, 4.0, 4.0, 1.0, 1.0, 1.0])
    estimates["ukf"] = {"q": np.array([q_body_icrs_from_sigma_bn(s)
                                       for s in rec_ukf.sigma_BN]),
                        "P": J @ P_ukf @ J,
                        "valid": P_ukf[:, 0, 0] > 0}

    nav_records: list[dict[str, Any]] = []
    cost = {name: nav.cost_s for name, nav in navs.items()}
    if use_camera:
        nav_records = navs["adfusion"].records
        for r in nav_records:
            fr = r["frame"]
            if fr is None:
                continue
            rec = r["rec"]
            if keep_frames:
                frames.append(fr)
            sol = rec.solution
            err_deg = None
            if sol is not None and sol.ok:
                err_deg = float(np.degrees(rot.angle_between(sol.q_cam_icrs,
                                                             fr.q_cam_icrs)))
            camera_steps.append({
                "t": rec.t, "index": fr.index, "n_in_view": fr.n_in_view,
                "blinded": fr.blinded, "mode": rec.star_mode, "ok": rec.star_ok,
                "accepted": rec.fix_accepted, "n_stars": rec.n_stars,
                "skipped": any("keep-out" in why for _, why in rec.rejected),
                "detection": r.get("detection"),
                "fix_error_deg": err_deg,
                "sol_sigma_deg": None if sol is None or not sol.ok else
                float(np.degrees(np.sqrt(np.max(np.linalg.eigvalsh(sol.covariance))))),
            })
    gyro = {"t": np.asarray(rec_imu.times()) * 1e-9,
            "omega": np.asarray(rec_imu.AngVelPlatform)}
    mag = {"t": np.asarray(rec_tam.times()) * 1e-9, "b_body_T": np.asarray(rec_tam.tam_S),
           "b_ref_n_T": np.asarray(rec_field.magField_N)}
    return LoopRun(cfg, loop, int(seed), t, q_true, np.asarray(rec_truth.omega_BN_B), q_ref,
                   estimates, camera_steps, nav_records, cost, q_body_cam_true,
                   q_body_cam_fsw, camera, gyro, mag, frames,
                   modules={"sim": sim, "spacecraft": sc, "imuSensor": imu, "starTracker": st,
                            "simpleNav": snav, "inertialUKF": ukf, "stComm": stc,
                            "inertial3D": guid, "attTrackingError": track,
                            "mrpFeedback": ctrl, "rwMotorTorque": alloc, **navs,
                            "camera": cam_mod})
