"""The project's MCAP log of a Basilisk run, written by a Basilisk module as the run goes.

:class:`McapLogModule` runs last in the flight-software process and writes, in time order,
the topics of docs/concepts/log-topics.md that ``adfusion replay`` and Foxglove read:

* ``/imu/gyro`` (body-frame rate), ``/mag`` (``b_body``, ``b_ref_icrs`` in nT);
* ``/truth/state`` and ``/truth/pose`` — Basilisk's spacecraft state (at the gyro rate);
* per camera frame: ``/camera/centroids`` (the detections, so a replay re-identifies them),
  ``/starid/solution``, ``/camera/annotations``, ``/estimate/state``, ``/estimate/pose``,
  ``/tf``; the image itself on ``/camera/image`` when ``images="all"`` (then no centroids:
  a replay detects the images), else on ``/camera/preview`` every ``preview_every`` frames
  (1024² 16-bit frames at 4 Hz would be 2 GB per 10 minutes);
* ``/ukf/pose`` — Basilisk's ``inertialUKF`` estimate, when given.

Metadata ``config`` carries what a replay needs (camera mounting, catalogue epoch and limit,
gyro noise, exposure); the camera model is attached as ``camera.json``. Nothing time- or
machine-dependent is written: the same seed gives the same file, byte for byte.

Example (:func:`adfusion.basilisk.scenarios.run_loop` adds the module when given a log):
    >>> import os, tempfile
    >>> from adfusion.basilisk.scenarios import run_loop, scenario
    >>> from adfusion.logs import LogWriter, McapLogReader
    >>> path = os.path.join(tempfile.mkdtemp(), "acs.mcap")
    >>> with LogWriter(path) as log:
    ...     _ = run_loop(scenario("leo", duration_s=1.0), "adfusion", seed=1, log=log)
    >>> sorted(c.topic for c in McapLogReader(path).channels.values())[:4]
    ['/camera/annotations', '/camera/calibration', '/camera/centroids', '/camera/preview']
"""

from __future__ import annotations

from typing import Any

import numpy as np
from Basilisk.architecture import messaging, sysModel

from adfusion.basilisk.frames import q_body_icrs_from_sigma_bn
from adfusion.basilisk.msgio import live_view
from adfusion.logs import LogWriter
from adfusion.maths import rotations as rot

__all__ = ["McapLogModule"]

_NT_PER_T = 1e9


class McapLogModule(sysModel.SysModel):
    """Basilisk module writing the run's MCAP log (see the module docstring).

    Args:
        log: an open :class:`adfusion.logs.LogWriter` (the caller closes it).
        nav: the :class:`~adfusion.basilisk.nav.AdfusionNav` whose records to log.
        config: JSON-ready run configuration (metadata ``config``).
        images: ``"preview"`` or ``"all"``.
        preview_every: with ``"preview"``, one image in this many frames.

    Input messages: ``scStateInMsg``, ``imuInMsg``, ``tamInMsg``, ``magFieldInMsg``, and
    optionally ``ukfInMsg`` (``NavAttMsg``).
    """

    def __init__(self, log: LogWriter, nav, config: dict[str, Any], *,
                 images: str = "preview", preview_every: int = 40) -> None:
        super().__init__()
        if images not in ("preview", "all"):
            raise ValueError(f"images must be 'preview' or 'all', got {images!r}")
        self.ModelTag = "mcapLog"
        self.scStateInMsg = messaging.SCStatesMsgReader()
        self.imuInMsg = messaging.IMUSensorMsgReader()
        self.tamInMsg = messaging.TAMSensorMsgReader()
        self.magFieldInMsg = messaging.MagneticFieldMsgReader()
        self.ukfInMsg = messaging.NavAttMsgReader()
        self.log, self.nav = log, nav
        self.images, self.preview_every = images, int(preview_every)
        self._seen = {"imu": -1, "tam": -1}
        self._n_records = 0
        self._views: dict[str, Any] = {}
        cam = nav.camera.camera
        q_body_cam = nav.q_body_cam
        log.add_metadata("config", config)
        log.add_camera_model(cam.to_dict())
        log.write_calibration(0.0, cam.width, cam.height, cam.K, cam.D, "camera")
        self._q_body_cam = q_body_cam

    def Reset(self, CurrentSimNanos: int) -> None:
        self._seen = {"imu": -1, "tam": -1}
        self._n_records = 0
        self._views: dict[str, Any] = {}

    def _view(self, name: str, reader: Any) -> Any:
        """A live view of ``reader``'s payload once it is written (msgio), else None."""
        view = self._views.get(name)
        if view is None and reader.isLinked() and reader.isWritten():
            view = self._views[name] = live_view(reader)
        return view

    def UpdateState(self, CurrentSimNanos: int) -> None:
        log = self.log
        t_now = CurrentSimNanos * 1e-9
        imu = self._view("imu", self.imuInMsg)
        if imu is not None and self.imuInMsg.timeWritten() != self._seen["imu"]:
            tw = self.imuInMsg.timeWritten()
            self._seen["imu"] = tw
            t = tw * 1e-9
            w = self.nav.dcm_PB.T @ np.asarray(imu.AngVelPlatform)
            log.write_json("/imu/gyro", t, {"t": t, "omega": w})
            st = self._view("sc", self.scStateInMsg)
            q = q_body_icrs_from_sigma_bn(st.sigma_BN)
            log.write_json("/truth/state", t_now, {"t": t_now, "q_body_icrs": q,
                                                   "omega": np.asarray(st.omega_BN_B)})
            log.write_attitude("/truth/pose", t_now, q)
            ukf = self._view("ukf", self.ukfInMsg)
            if ukf is not None:
                log.write_attitude("/ukf/pose", t_now, q_body_icrs_from_sigma_bn(ukf.sigma_BN))
        tam = self._view("tam", self.tamInMsg)
        field = self._view("field", self.magFieldInMsg)
        if tam is not None and field is not None \
                and self.tamInMsg.timeWritten() != self._seen["tam"]:
            tw = self.tamInMsg.timeWritten()
            self._seen["tam"] = tw
            t = tw * 1e-9
            b = self.nav.dcm_SB.T @ np.asarray(tam.tam_S) * _NT_PER_T
            b_ref = np.asarray(field.magField_N) * _NT_PER_T
            log.write_json("/mag", t, {"t": t, "b_body": b, "b_ref_icrs": b_ref})
        records = self.nav.records
        for r in records[self._n_records:]:
            if r["frame"] is not None:
                self._frame(r)
        self._n_records = len(records)

    def _frame(self, r: dict[str, Any]) -> None:
        log, rec, fr = self.log, r["rec"], r["frame"]
        t = rec.t
        latest = self.nav.camera.latest
        image = latest.image if latest is not None and latest.index == fr.index else None
        if self.images == "all" and image is not None:
            log.write_image(t, image, "camera")
        else:
            if fr.index % self.preview_every == 0 and image is not None:
                log.write_image(t, image, "camera", topic="/camera/preview")
            xy = rec.detections_xy
            if xy is not None or any("keep-out" in why for _, why in rec.rejected):
                log.write_json("/camera/centroids", t,
                               {"t": t, "xy": np.empty((0, 2)) if xy is None else xy})
        sol = rec.solution
        if sol is not None:
            xy = rec.detections_xy
            cand = sol.candidates[0] if sol.candidates else None
            predicted = cand.predicted_xy if sol.ok and cand is not None else None
            log.write_json("/starid/solution", t, {
                "t": t, "ok": sol.ok, "mode": sol.mode, "reason": sol.reason,
                "q_cam_icrs": sol.q_cam_icrs if sol.ok else None,
                "matches": [list(m) for m in sol.matches],
                "matching_counter": sol.matching_counter, "p_false": sol.p_false,
                # no solve time: the log of a seed is the same bytes on every run
                "cone_deg": rec.cone_deg, "time_ms": None, "fix_accepted": rec.fix_accepted,
                "n_detections": 0 if xy is None else len(xy),
                "truth_q_cam_icrs": fr.q_cam_icrs, "n_in_view": fr.n_in_view})
            if xy is not None:
                ident = [(float(xy[d][0]), float(xy[d][1]), str(i))
                         for d, i in sol.matches if d < len(xy)]
                log.write_annotations(t, xy, identified=ident, predicted_xy=predicted)
        if rec.q_body_icrs is not None:
            nis = rec.nis.get("star fix")
            state = {"t": t, "q_body_icrs": rec.q_body_icrs, "bias": rec.bias_rad_s,
                     "cov_diag": rec.sigma_rad**2, "nis": nis, "mode": rec.star_mode,
                     "rejected": [list(x) for x in rec.rejected]}
            if rec.cov is not None:  # the full P, row-major, as a replay's log has it
                state["cov"] = rec.cov.reshape(-1)
            log.write_json("/estimate/state", t, state)
            log.write_attitude("/estimate/pose", t, rec.q_body_icrs)
            log.write_tf(t, [("icrs", "body", rot.inverse(rec.q_body_icrs), (0.0, 0.0, 0.0)),
                             ("body", "camera", self._q_body_cam, (0.0, 0.0, 0.0))])
