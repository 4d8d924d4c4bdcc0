"""The log's topic names, one constant each: writers, replay and report use these, never
string literals.

:func:`table` lists every topic with its schema, fields, units and frame (from
:mod:`adfusion.logs.schemas` for the JSON topics); ``python -m adfusion.logs.topics
--markdown`` prints it as the documentation's topic table.

Example:
    >>> from adfusion.logs import topics
    >>> topics.ESTIMATE_STATE, topics.CAMERA_IMAGE
    ('/estimate/state', '/camera/image')
    >>> row = next(r for r in topics.table() if r["topic"] == topics.ESTIMATE_ATTITUDE)
    >>> row["schema"], row["frame"]
    ('adfusion.AttitudeDeg', 'icrs → body')
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

CAMERA_IMAGE = "/camera/image"
"""Camera frames (``foxglove.RawImage`` or ``foxglove.CompressedImage``)."""
CAMERA_CENTROIDS = "/camera/centroids"
"""Star centroids in place of an image (centroid-only simulations), pixels."""
CAMERA_ANNOTATIONS = "/camera/annotations"
"""Detections, identified and predicted stars drawn on the frame."""
CAMERA_CALIBRATION = "/camera/calibration"
"""The camera model (``foxglove.CameraCalibration``)."""
GYRO = "/imu/gyro"
"""Gyro samples, rad/s, body frame."""
MAG = "/mag"
"""Magnetometer samples, nT, body frame (with the ICRS reference field when known)."""
STARID_SOLUTION = "/starid/solution"
"""One star-identification result per frame."""
ESTIMATE_STATE = "/estimate/state"
"""The filter's state after each frame."""
ESTIMATE_ATTITUDE = "/estimate/attitude"
"""The filter's attitude in degrees: RA, Dec and roll of body +z with 1σ per axis."""
ESTIMATE_ERROR = "/estimate/error"
"""The filter's error against the truth (logs with truth): body axes, deg, with 3σ."""
ESTIMATE_POSE = "/estimate/pose"
"""The filter's attitude as a ``foxglove.PoseInFrame`` in ``icrs``."""
SMOOTHED_STATE = "/smoothed/state"
"""The smoother's state per frame (``replay --smooth``)."""
SMOOTHED_POSE = "/smoothed/pose"
"""The smoother's attitude as a pose in ``icrs``."""
TRUTH_STATE = "/truth/state"
"""Simulation truth: attitude, rate, gyro bias."""
TRUTH_POSE = "/truth/pose"
"""Simulation truth attitude per frame as a pose in ``icrs``."""
LIVE_STATUS = "/live/status"
"""A live run's pace after each frame: latency from arrival to estimate, frames dropped."""
TF = "/tf"
"""Frame transforms (icrs → body → camera)."""
TUBSAT_PLAN = "/tubsat/plan"
"""A night pass (``simulate tubsat``): the best time over the target and its elevation."""
TUBSAT_BLOCKS = "/tubsat/blocks"
"""The reduced star image: block positions (px) and the star each belongs to (−1: none)."""
TUBSAT_MARKED = "/tubsat/marked"
"""The stars marked for identification (px), the reference first."""
TUBSAT_CANDIDATE = "/tubsat/candidate"
"""Each candidate shown to the operator, with its star angles and the decision."""
TUBSAT_LOCK = "/tubsat/lock"
"""The accepted attitude handed to the estimator, and the drift budget left."""
TUBSAT_COMMAND = "/tubsat/command"
"""Slew commands: send, re-send, query (axis, angle in degrees)."""
TUBSAT_POINTING = "/tubsat/pointing"
"""At the best time: the true boresight's error from the target, and the predicted σ."""

MAX_CAMERAS = 8
"""Cameras a log may hold: camera 0 on ``/camera/...``, camera k on ``/camera{k}/...``."""


def camera_topic(k: int, leaf: str = "image") -> str:
    """The topic of camera ``k``'s ``leaf`` (image, centroids, annotations, calibration).

    Example:
        >>> camera_topic(0), camera_topic(2, "annotations")
        ('/camera/image', '/camera2/annotations')
    """
    if not 0 <= k < MAX_CAMERAS:
        raise ValueError(f"camera index {k} outside 0..{MAX_CAMERAS - 1}")
    return f"/camera/{leaf}" if k == 0 else f"/camera{k}/{leaf}"


def camera_frame(k: int) -> str:
    """The transform frame of camera ``k`` (``camera``, ``camera1``, …)."""
    return "camera" if k == 0 else f"camera{k}"


_FOXGLOVE: dict[str, tuple[str, str, str, str]] = {
    # topic: (schema, fields, units, frame)
    CAMERA_IMAGE: ("foxglove.RawImage", "timestamp, frame_id, width, height, encoding "
                   "(mono8/mono16), step, data", "pixel values (ADU)", "camera"),
    CAMERA_ANNOTATIONS: ("foxglove.ImageAnnotations", "points: detections (yellow), "
                         "predicted catalogue stars (cyan), identified stars (green circles, "
                         "HIP labels)", "pixels, 0-based centres", "camera image"),
    CAMERA_CALIBRATION: ("foxglove.CameraCalibration", "width, height, distortion_model, D, "
                         "K, R, P", "pixels", "camera"),
    ESTIMATE_POSE: ("foxglove.PoseInFrame", "timestamp, frame_id, pose.orientation "
                    "(q_icrs_body)", "unit quaternion", "icrs → body"),
    SMOOTHED_POSE: ("foxglove.PoseInFrame", "as /estimate/pose", "unit quaternion",
                    "icrs → body"),
    TRUTH_POSE: ("foxglove.PoseInFrame", "as /estimate/pose (the true attitude)",
                 "unit quaternion", "icrs → body_truth"),
    TF: ("foxglove.FrameTransforms", "transforms: icrs → body, body → camera, icrs → "
         "body_truth", "unit quaternions, metres", "icrs, body, camera, body_truth"),
}

_FRAMES = {GYRO: "body", MAG: "body (b_ref_icrs: icrs)", STARID_SOLUTION: "icrs → camera",
           ESTIMATE_STATE: "icrs → body", ESTIMATE_ATTITUDE: "icrs → body", ESTIMATE_ERROR: "body",
           SMOOTHED_STATE: "icrs → body", TRUTH_STATE: "icrs → body",
           CAMERA_CENTROIDS: "camera image"}


def _units(description: str) -> list[str]:
    found = []
    for unit in ("(rad/s)^2", "rad/s", "rad^2", "nT", "arcsec", "milliseconds", "seconds",
                 "deg", "pixels"):
        if unit in description:
            found.append({"milliseconds": "ms", "seconds": "s"}.get(unit, unit))
            description = description.replace(unit, "")
    return found


def table() -> list[dict[str, Any]]:
    """Every topic the project writes: ``topic``, ``schema``, ``fields``, ``units``,
    ``frame`` (JSON topics from :data:`adfusion.logs.schemas.JSON_SCHEMAS`)."""
    from adfusion.logs.schemas import JSON_SCHEMAS

    rows = []
    for topic, (schema_name, schema) in JSON_SCHEMAS.items():
        props = schema["properties"]
        units = sorted({u for p in props.values() for u in _units(p.get("description", ""))})
        rows.append({"topic": topic, "schema": schema_name, "fields": ", ".join(props),
                     "units": ", ".join(units), "frame": _FRAMES.get(topic, "")})
    for topic, (schema_name, fields, units, frame) in _FOXGLOVE.items():
        rows.append({"topic": topic, "schema": schema_name, "fields": fields, "units": units,
                     "frame": frame})
    return sorted(rows, key=lambda r: r["topic"])


def markdown() -> str:
    """:func:`table` as a Markdown table, with one section per JSON schema's fields."""
    from adfusion.logs.schemas import JSON_SCHEMAS

    lines = ["| topic | schema | fields | units | frame |", "|---|---|---|---|---|"]
    lines += [f"| `{r['topic']}` | {r['schema']} | {r['fields']} | {r['units']} | "
              f"{r['frame']} |" for r in table()]
    seen = set()
    for _, (name, schema) in JSON_SCHEMAS.items():
        if name in seen:
            continue
        seen.add(name)
        lines += ["", f"### {name}", "", "| field | required | description |",
                  "|---|---|---|"]
        for field, p in schema["properties"].items():
            req = "yes" if field in schema["required"] else ""
            lines.append(f"| `{field}` | {req} | {p.get('description', '')} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """``python -m adfusion.logs.topics [--markdown]``: the topic table."""
    p = argparse.ArgumentParser(prog="python -m adfusion.logs.topics",
                                description="the log topics, schemas, fields, units, frames")
    p.add_argument("--markdown", action="store_true", help="a Markdown table (default: TSV)")
    args = p.parse_args(argv)
    if args.markdown:
        sys.stdout.write(markdown())
    else:
        for r in table():
            print("\t".join(r[k] for k in ("topic", "schema", "fields", "units", "frame")))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
