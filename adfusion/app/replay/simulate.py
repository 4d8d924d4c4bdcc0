"""Record a simulated flight: a :mod:`adfusion.sensors.scenarios` stream into an MCAP log
with the DESIGN topics (the run configuration as metadata, the camera model as an
attachment) — the input :func:`adfusion.app.replay.replay` takes.

Example:
    >>> import os, tempfile
    >>> from adfusion.sensors.scenarios import oedipus
    >>> from adfusion.app.replay.simulate import simulate
    >>> simulate(oedipus(duration_s=0.2, render=False), os.path.join(tempfile.mkdtemp(), "s.mcap"))
    6
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from adfusion.logs import LogWriter
from adfusion.plain import to_jsonable
from adfusion.starid import rotations as rot

__all__ = ["simulate"]


def simulate(scenario, out_path: str | Path, progress: bool = False) -> int:
    """Write a scenario's events to ``out_path``; returns the number of frames.
    ``progress`` shows a bar of rendered frames on stderr."""
    frames = 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(scenario.t_frame), unit="frame", desc="simulate",
                   mininterval=0.5)
    # written as out_path + ".partial", renamed when complete; a failure marks it incomplete
    with LogWriter(out_path, atomic=True) as log:
        log.add_metadata("config", to_jsonable(scenario.config))
        log.add_camera_model(scenario.camera.to_dict())
        cam = scenario.camera
        log.write_calibration(0.0, cam.width, cam.height, cam.K, cam.D, "camera")
        q_body_cam = np.asarray(scenario.q_body_cam, dtype=np.float64)
        for ev in scenario.events():
            d, t = ev.data, ev.t_s
            if ev.kind == "truth":
                log.write_json("/truth/state", t, {
                    "t": t, "q_body_icrs": d["q_body_icrs"], "omega": d["omega_body_rad_s"],
                    "bias": d["bias_rad_s"]})
            elif ev.kind == "gyro":
                log.write_json("/imu/gyro", t, {"t": t, "omega": d["omega_meas_rad_s"]})
            elif ev.kind == "mag":
                log.write_json("/mag", t, {"t": t, "b_body": d["b_body_nT"],
                                           "b_ref_icrs": d["b_ref_icrs_nT"]})
            else:
                frames += 1
                if bar is not None:
                    bar.update()
                if "image" in d:
                    log.write_image(t, d["image"], "camera")
                else:  # a centroid-only simulation: the detections are the "image"
                    log.write_json("/camera/centroids", t, {"t": t, "xy": d["xy"]})
                q_body_true = rot.multiply(q_body_cam, d["q_cam_icrs"])
                log.write_attitude("/truth/pose", t, q_body_true)
                log.write_tf(t, [("body_truth", "camera", q_body_cam, (0.0, 0.0, 0.0))])
    if bar is not None:
        bar.close()
    return frames
