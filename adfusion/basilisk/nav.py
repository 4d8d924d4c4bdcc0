"""adfusion as a Basilisk flight-software module: gyro + magnetometer + star camera (or
Basilisk's quaternion star tracker) → :class:`adfusion.Estimator` → ``NavAttMsg``.

:class:`AdfusionNav` runs in a Basilisk task. Each call it takes what is new since the last:

* ``imuInMsg`` (``IMUSensorMsg``): the platform rate ``AngVelPlatform`` turned into the body
  frame (``dcm_PB``) — a gyro step of the estimator at the message's write time;
* a camera frame from a :class:`adfusion.basilisk.camera.StarCameraModule` (``camera``):
  detection → identification (tracking from the filter's cone, lost-in-space fallback,
  both inside :meth:`adfusion.Estimator.step`) → MEKF update. A flooded frame (stray light,
  :func:`~adfusion.basilisk.camera.is_flooded`) is not used, and neither is one that the
  *estimated* boresight puts inside ``earth_keepout_deg`` of the Earth's limb (with
  ``navTransInMsg``, the position): both are recorded as rejected but not counted as
  misses, so the first frame after an outage is tracked from the gyro-propagated cone;
* or ``stInMsg`` (``STSensorMsg``, Basilisk's ``starTracker``): ``qInrtl2Case`` through the
  case mounting ``dcm_CB`` as an attitude update of ``st_sigma_rad`` per axis;
* ``tamInMsg`` (``TAMSensorMsg``) with ``magFieldInMsg`` (``MagneticFieldMsg``, the model
  field in N): a direction update (the sensor frame through ``dcm_SB``).

Measurements are applied in time order. It then writes ``navAttOutMsg`` (``NavAttMsg``:
``sigma_BN``, ``omega_BN_B`` = gyro − estimated bias) and ``filtDataOutMsg``
(``InertialFilterMsg``: ``state`` = [sigma_BN, bias (rad/s)], ``covar`` = the filter's 6×6
covariance of [attitude error (rad, body axes), bias (rad/s)], ``numObs`` = measurements used
this call), time-tagged
with the estimate's time (the latest measurement's; like Basilisk's own filters, the module
does not extrapolate between measurements). A call with nothing new re-writes the last
payloads.

Every camera frame's and star-tracker sample's :class:`adfusion.StepRecord` is kept in
``records`` (with the frame's truth, without its image, and the covariance after the step)
when ``keep_records``; ``cost_s`` keeps each call's CPU time (``time.thread_time``: on a
shared machine the wall time mostly measures the wait for a core) by kind for benchmarks
(a call with a frame is a ``"frame"`` call, whatever else it took: ``frame_call_events``
says how many inputs each had), never written to logs (a log must be identical for a
seed).

Example (a gyro-only module in a bare Basilisk simulation, IMU messages written by hand):
    >>> from Basilisk.architecture import messaging
    >>> from Basilisk.utilities import SimulationBaseClass, macros
    >>> sim = SimulationBaseClass.SimBaseClass()
    >>> sim.CreateNewProcess("p").addTask(sim.CreateNewTask("t", macros.sec2nano(0.1)))
    >>> nav = AdfusionNav(q_body_icrs0=[1.0, 0.0, 0.0, 0.0])
    >>> imu = messaging.IMUSensorMsgPayload()
    >>> imu.AngVelPlatform = [0.0, 0.0, 0.01]
    >>> imu_msg = messaging.IMUSensorMsg()
    >>> nav.imuInMsg.subscribeTo(imu_msg)
    >>> sim.AddModelToTask("t", nav)
    >>> sim.InitializeSimulation()
    >>> for k in range(11):  # 0.01 rad/s about z for 1 s
    ...     _ = imu_msg.write(imu, int(macros.sec2nano(0.1 * k)))
    ...     sim.ConfigureStopTime(macros.sec2nano(0.1 * k))
    ...     sim.ExecuteSimulation()
    >>> out = nav.navAttOutMsg.read()
    >>> angle_deg = np.degrees(4 * np.arctan(np.linalg.norm(out.sigma_BN)))
    >>> round(out.timeTag, 6), round(float(angle_deg), 3)
    (1.0, 0.573)
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from Basilisk.architecture import messaging, sysModel
from numpy.typing import ArrayLike

from adfusion.basilisk.camera import CameraFrame, earth_limb_angle_rad, is_flooded
from adfusion.basilisk.frames import q_body_icrs_from_sigma_bn
from adfusion.basilisk.msgio import author, live_view, setters
from adfusion.estimation.estimator import Estimator, StepRecord
from adfusion.estimation.mekf_kernels import warm_up as warm_up_filter
from adfusion.maths import rotations as rot
from adfusion.starid.detection.windows import TrackingWindows

__all__ = ["AdfusionNav"]


class AdfusionNav(sysModel.SysModel):
    """Basilisk module wrapping :class:`adfusion.Estimator` (see the module docstring).

    Args:
        solver: a :class:`starid.Solver` for the camera (None: no camera).
        camera: the :class:`StarCameraModule` whose frames to use (None: none).
        q_body_cam: the camera mounting as the flight software knows it.
        q_body_icrs0, sigma_attitude0_rad: a prior attitude (otherwise the first star fix
            or star-tracker quaternion initialises the filter).
        st_sigma_rad: 1-σ per-axis error of the star tracker's quaternion.
        earth_keepout_deg: skip frames whose estimated boresight has the Earth's limb this
            close (needs ``navTransInMsg``).
        keep_records: keep every step's record in :attr:`records`.
        rate_lowpass_hz: a first-order low-pass (this corner) on the output rate
            ``omega_BN_B`` (gyro − bias): the gyro's white noise otherwise reaches the
            controller's rate term unfiltered (None: no filter). The attitude is not
            filtered.
        windows: detect tracking frames in windows around the stars the filter predicts
            (:class:`adfusion.starid.detection.windows.TrackingWindows`; a dict: its arguments),
            the whole frame otherwise — lost, a loose prior, too few stars found. False:
            always the whole frame. Each frame's record says which (``"detection"``).
        estimator_kw: passed to :class:`adfusion.Estimator` (gyro noise, gates, ...).
    """

    def __init__(self, solver=None, camera=None, q_body_cam: ArrayLike = rot.IDENTITY, *,
                 q_body_icrs0: ArrayLike | None = None, sigma_attitude0_rad: float = 0.02,
                 st_sigma_rad: float = 1e-4, earth_keepout_deg: float | None = None,
                 keep_records: bool = True, rate_lowpass_hz: float | None = None,
                 windows: bool | dict[str, Any] = True, **estimator_kw: Any) -> None:
        super().__init__()
        self.ModelTag = "adfusionNav"
        self.imuInMsg = messaging.IMUSensorMsgReader()
        self.tamInMsg = messaging.TAMSensorMsgReader()
        self.magFieldInMsg = messaging.MagneticFieldMsgReader()
        self.stInMsg = messaging.STSensorMsgReader()
        self.navTransInMsg = messaging.NavTransMsgReader()
        self.navAttOutMsg = messaging.NavAttMsg()
        self.filtDataOutMsg = messaging.InertialFilterMsg()
        self.dcm_PB = np.eye(3)  # IMU platform from body
        self.dcm_SB = np.eye(3)  # magnetometer sensor from body
        self.dcm_CB = np.eye(3)  # star-tracker case from body
        self.solver = solver
        self.camera = camera
        self.q_body_cam = rot.canonical(rot.normalize(q_body_cam))
        self.R_body_cam = rot.to_matrix(self.q_body_cam)
        self._boresight_body = self.R_body_cam[:, 2].copy()  # camera +z in the body frame
        self.st_sigma_rad = float(st_sigma_rad)
        self.earth_keepout_rad = None if earth_keepout_deg is None else \
            float(np.radians(earth_keepout_deg))
        self.keep_records = bool(keep_records)
        self.rate_lowpass_hz = None if rate_lowpass_hz is None else float(rate_lowpass_hz)
        self._est_kw = dict(estimator_kw)
        # tracking frames are detected in windows around the predicted stars (full frame
        # when lost, when the prior is loose or when the windows find too few stars)
        self.windows = None
        if solver is not None and windows is not False:
            self.windows = TrackingWindows(solver, **({} if windows is True else windows))
        self._q0 = None if q_body_icrs0 is None else rot.normalize(q_body_icrs0)
        self._sigma0 = float(sigma_attitude0_rad)
        self.Reset(0)

    # --- Basilisk interface ------------------------------------------------------------

    def Reset(self, CurrentSimNanos: int) -> None:
        warm_up_filter()  # the compiled propagation loads here, not in the first gyro call
        self.est = self._estimator(self._q0, self._sigma0)
        self._seen = {"imu": -1, "st": -1, "tam": -1, "frame": -1}
        self._gyro_body: list[float] | None = None
        self.records: list[dict[str, Any]] = []
        self.gyro_rejected: list[tuple[float, str, str]] = []  # (t, input, why)
        self.cost_s: dict[str, list[float]] = {"gyro": [], "frame": [], "st": [], "mag": [],
                                               "idle": []}
        # per "frame" call: how many inputs it took (the frame alone, or with a gyro or
        # magnetometer sample of the same time)
        self.frame_call_events: list[int] = []
        self._att = self._filt = None
        self._rate_lp: list[float] | None = None
        self._q_body_case: np.ndarray | None = None
        self._t_rate: float | None = None
        self._inputs: dict[str, Any] | None = None  # bound at the first call (see _bind)

    def UpdateState(self, CurrentSimNanos: int) -> None:
        t0 = time.thread_time()
        if self._inputs is None:
            self._bind()
        events = []  # (time ns, order at equal times, kind, data)
        seen = self._seen
        if self._view("imu") is not None:
            tw = self.imuInMsg.timeWritten()
            if tw != seen["imu"]:
                seen["imu"] = tw
                w_p = self._views["imu"].AngVelPlatform
                events.append((tw, 0, "gyro", w_p if self._R_BP is None else
                               (self._R_BP @ np.asarray(w_p, dtype=np.float64)).tolist()))
        if self.camera is not None and self.camera.latest is not None:
            fr = self.camera.latest
            if fr.index != seen["frame"]:
                seen["frame"] = fr.index
                events.append((fr.t_ns, 1, "frame", fr))
        if self._view("st") is not None:
            tw = self.stInMsg.timeWritten()
            if tw != seen["st"]:
                seen["st"] = tw
                events.append((tw, 2, "st", np.asarray(self._views["st"].qInrtl2Case)))
        if self._view("tam") is not None and self._view("field") is not None:
            tw = self.tamInMsg.timeWritten()
            if tw != seen["tam"]:
                seen["tam"] = tw
                b_body = self.dcm_SB.T @ np.asarray(self._views["tam"].tam_S, dtype=np.float64)
                b_n = np.asarray(self._views["field"].magField_N, dtype=np.float64)
                events.append((tw, 3, "mag", (b_body, b_n)))
        n_obs = 0
        if len(events) > 1:
            events.sort(key=lambda e: e[:2])
        for tw, _, kind, data in events:
            t = tw * 1e-9
            if kind == "gyro":
                self._gyro_body = data
                refused = self.est.step_gyro(t, data)
                if refused is not None:
                    self.gyro_rejected.append((t, *refused))
                self._filter_rate(t)
            elif kind == "frame":
                n_obs += self._frame_step(data)
            elif kind == "st":
                n_obs += self._st_step(t, data)
            else:
                rec = self.est.step(t, mag=data)
                n_obs += "mag" in rec.sensors and not any(k == "mag" for k, _ in rec.rejected)
        if events or self._att is None:
            self._write_new(n_obs)
        self._write_att(self._att, self.moduleID, CurrentSimNanos)
        self._write_filt(self._filt, self.moduleID, CurrentSimNanos)
        if not events:
            kind = "idle"
        elif len(events) == 1:
            kind = events[0][2]
        else:
            kinds = {e[2] for e in events}
            kind = "frame" if "frame" in kinds else "st" if "st" in kinds else "mag"
        self.cost_s[kind].append(time.thread_time() - t0)
        if kind == "frame":
            self.frame_call_events.append(len(events))

    def _bind(self) -> None:
        """The linked inputs, the output writers and the payload setters, once after
        ``Reset`` (Basilisk's subscriptions are made before the simulation initialises).
        Inputs are then read through live views (:mod:`adfusion.basilisk.msgio`): a
        payload copy per read, a new writer per write and a checked ``setattr`` per field
        were most of a gyro step's cost."""
        readers = {"imu": self.imuInMsg, "st": self.stInMsg, "tam": self.tamInMsg,
                   "field": self.magFieldInMsg, "trans": self.navTransInMsg}
        self._inputs = {k: r for k, r in readers.items() if r.isLinked()}
        self._views: dict[str, Any] = {}
        dcm_pb = np.asarray(self.dcm_PB, dtype=np.float64)
        self._R_BP = None if np.array_equal(dcm_pb, np.eye(3)) else dcm_pb.T
        self._write_att = author(self.navAttOutMsg)
        self._write_filt = author(self.filtDataOutMsg)

    def _view(self, name: str) -> Any:
        """The live view of input ``name`` once it is linked and written (else None)."""
        view = self._views.get(name)
        if view is None:
            reader = self._inputs.get(name)
            if reader is None or not reader.isWritten():
                return None
            view = self._views[name] = live_view(reader)
        return view

    # --- pieces ------------------------------------------------------------------------

    def _estimator(self, q_body_icrs0, sigma_attitude0_rad: float) -> Estimator:
        """The estimator; tracking frames detected in the windows (when on), placed from
        the prior the solver then tracks from (one prior per frame, after propagating to
        the frame's time)."""
        kw = dict(self._est_kw)
        if self.windows is not None:
            kw["detect_tracking"] = self.windows.detect
        return Estimator(self.solver, self.q_body_cam, q_body_icrs0=q_body_icrs0,
                         sigma_attitude0_rad=sigma_attitude0_rad, **kw)

    def _frame_step(self, fr) -> int:
        t = fr.t_ns * 1e-9
        if is_flooded(fr.image):
            rec = self.est.step(t)
            rec.rejected.append(("camera", "frame flooded (stray light: most pixels "
                                           "saturated): blinded, not used"))
            self._keep(rec, fr)
            return 0
        if self.earth_keepout_rad is not None and self.est.initialized \
                and self._view("trans") is not None:
            # the estimated boresight in ICRS: R_body_icrsᵀ (camera +z in the body)
            boresight = self._boresight_body @ rot.to_matrix(self.est.filter.q_body_icrs)
            limb = earth_limb_angle_rad(boresight, self._views["trans"].r_BN_N)
            if limb < self.earth_keepout_rad:
                rec = self.est.step(t)
                rec.rejected.append(("camera", f"Earth's limb {np.degrees(limb):.1f}° from "
                                               "the boresight, inside the keep-out: frame "
                                               "not used"))
                self._keep(rec, fr)
                return 0
        rec = self.est.step(t, frame=fr.image)  # windows or whole frame: rec.detection
        self._keep(rec, fr, rec.detection)
        return int(rec.fix_accepted)

    def _st_step(self, t: float, q_inrtl2case: np.ndarray) -> int:
        # Basilisk's β_CN is the conjugate of q_case_icrs (see frames.py)
        q_case_icrs = rot.canonical(rot.conjugate(rot.normalize(q_inrtl2case)))
        if self._q_body_case is None:  # dcm_CB is set after construction, read it once
            self._q_body_case = rot.from_matrix(np.asarray(self.dcm_CB, dtype=np.float64).T)
        q_body_icrs = rot.multiply(self._q_body_case, q_case_icrs)
        cov = self.st_sigma_rad**2 * np.eye(3)
        if not self.est.initialized:
            self._q0 = q_body_icrs
            self.est = self._estimator(q_body_icrs, 3 * self.st_sigma_rad)
            rec = self.est.step(t, gyro=self._gyro_body)
            rec.sensors.append("star tracker")
            self._keep(rec)
            return 1
        rec = self.est.step(t)
        res = self.est.filter.update_attitude(q_body_icrs, cov)
        rec.sensors.append("star tracker")
        rec.nis["star tracker"] = float(res.nis)
        if not res.accepted:
            rec.rejected.append(("star tracker", res.reason))
        rec.fix_accepted = bool(res.accepted)
        rec.q_body_icrs = np.array(self.est.filter.q_body_icrs)
        self._keep(rec)
        return int(res.accepted)

    def _keep(self, rec: StepRecord, frame=None, detection: str | None = None) -> None:
        if self.keep_records:
            # the frame's truth without its image (a 10-minute run's images would be GBs)
            light = None if frame is None else CameraFrame(
                frame.index, frame.t_ns, None, frame.q_cam_icrs, frame.star_xy, frame.hip,
                frame.blinded)
            self.records.append({"rec": rec, "frame": light, "detection": detection,
                                 "P": None if self.est.filter is None
                                 else np.array(self.est.filter.P)})

    def _filter_rate(self, t: float) -> None:
        """The output rate at a gyro sample: gyro − bias, low-passed if asked (floats: this
        runs at the gyro rate)."""
        f = self.est.filter
        if f is None:
            return
        bx, by, bz = f.bias_rad_s.tolist()
        gx, gy, gz = self._gyro_body
        w = [gx - bx, gy - by, gz - bz]
        if self.rate_lowpass_hz is None or self._rate_lp is None or self._t_rate is None:
            self._rate_lp = w
        else:
            a = 1.0 - math.exp(-2.0 * math.pi * self.rate_lowpass_hz * max(t - self._t_rate, 0.0))
            self._rate_lp = [lp + a * (wi - lp) for lp, wi in zip(self._rate_lp, w, strict=True)]
        self._t_rate = t

    def _write_new(self, n_obs: int) -> None:
        """New output payloads from the filter (the estimate's own time as ``timeTag``: the
        module does not extrapolate between measurements, as Basilisk's filters)."""
        if self._att is None:
            self._att = messaging.NavAttMsgPayload()
            self._filt = messaging.InertialFilterMsgPayload()
            self._set_att = setters(self._att, "timeTag", "sigma_BN", "omega_BN_B")
            self._set_filt = setters(self._filt, "timeTag", "state", "covar", "numObs")
            self._n_obs = 0  # a new payload's numObs
        att, filt = self._att, self._filt
        set_time, set_sigma, set_omega = self._set_att
        set_ftime, set_state, set_covar, set_nobs = self._set_filt
        f = self.est.filter
        if f is not None:
            t = float(self.est.t)
            set_time(att, t)
            set_ftime(filt, t)
            # sigma_BN of the filter's unit q_body_icrs (frames.sigma_bn_from_q_body_icrs,
            # inline in floats: this runs at the gyro rate)
            w, x, y, z = f.q_body_icrs.tolist()
            k = (-1.0 if w >= 0.0 else 1.0) / (1.0 + abs(w))
            sigma = [k * x, k * y, k * z]
            set_sigma(att, sigma)
            if self._rate_lp is not None:
                set_omega(att, self._rate_lp)
            set_state(filt, sigma + f.bias_rad_s.tolist())
            set_covar(filt, f.P.reshape(-1).tolist())
        if n_obs != self._n_obs:  # the payload keeps it: set only when it changes
            set_nobs(filt, int(n_obs))
            self._n_obs = n_obs

    @staticmethod
    def q_body_icrs(payload) -> np.ndarray:
        """``q_body_icrs`` of a ``NavAttMsgPayload`` / ``SCStatesMsgPayload``."""
        return q_body_icrs_from_sigma_bn(payload.sigma_BN)
