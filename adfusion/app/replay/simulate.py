"""Record a simulated flight: a :mod:`adfusion.sensors.scenarios` stream into an MCAP log
with the topics of docs/concepts/log-topics.md (the run configuration as metadata, the camera
model as an attachment) — the input :func:`adfusion.app.replay.replay` takes.

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

from adfusion.logs import LogWriter, topics
from adfusion.maths import rotations as rot
from adfusion.plain import to_jsonable

__all__ = ["simulate"]


def simulate(scenario, out_path: str | Path, progress: bool = False) -> int:
    """Write a scenario's events to ``out_path``; returns the number of frames.
    ``progress`` shows a bar of rendered frames on stderr. A
    :class:`~adfusion.sensors.scenarios.MultiHeadScenario` writes camera ``k``'s frames,
    model (attachment ``camera{k}.json``) and calibration on its own topics
    (:func:`adfusion.logs.topics.camera_topic`)."""
    frames = 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(scenario.t_frame), unit="frame", desc="simulate",
                   mininterval=0.5)
    heads = getattr(scenario, "heads", [scenario])
    # locked, written under a temporary name, renamed when complete; a failure marks it
    # incomplete (LogWriter atomic)
    with LogWriter(out_path, start_utc=scenario.start_utc, atomic=True) as log:
        log.add_metadata("config", to_jsonable(scenario.config))
        mounts = []
        for k, head in enumerate(heads):
            cam = head.camera
            log.add_camera_model(cam.to_dict(), camera_model_name(k))
            log.write_calibration(0.0, cam.width, cam.height, cam.K, cam.D,
                                  topics.camera_frame(k),
                                  topic=topics.camera_topic(k, "calibration"))
            mounts.append(np.asarray(head.q_body_cam, dtype=np.float64))
        for ev in scenario.events():
            d, t = ev.data, ev.t_s
            if ev.kind == "truth":
                log.write_json(topics.TRUTH_STATE, t, {
                    "t": t, "q_body_icrs": d["q_body_icrs"], "omega": d["omega_body_rad_s"],
                    "bias": d["bias_rad_s"]})
            elif ev.kind == "gyro":
                log.write_json(topics.GYRO, t, {"t": t, "omega": d["omega_meas_rad_s"]})
            elif ev.kind == "mag":
                log.write_json(topics.MAG, t, {"t": t, "b_body": d["b_body_nT"],
                                               "b_ref_icrs": d["b_ref_icrs_nT"]})
            else:
                frames += 1
                if bar is not None:
                    bar.update()
                k = int(d.get("head", 0))
                if "image" in d:
                    log.write_image(t, d["image"], topics.camera_frame(k),
                                    topic=topics.camera_topic(k))
                else:  # a centroid-only simulation: the detections are the "image"
                    log.write_json(topics.camera_topic(k, "centroids"), t,
                                   {"t": t, "xy": d["xy"]})
                if k == 0:
                    q_body_true = rot.multiply(mounts[0], d["q_cam_icrs"])
                    log.write_attitude(topics.TRUTH_POSE, t, q_body_true)
                    log.write_tf(t, [("body_truth", topics.camera_frame(j), q, (0.0, 0.0, 0.0))
                                     for j, q in enumerate(mounts)])
    if bar is not None:
        bar.close()
    return frames


def camera_model_name(k: int) -> str:
    """The attachment holding camera ``k``'s model: ``camera.json``, ``camera1.json``, …"""
    return "camera.json" if k == 0 else f"camera{k}.json"
