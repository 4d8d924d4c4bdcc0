"""The log's topic names, one constant each: writers, replay and report use these, never
string literals.

Example:
    >>> from adfusion.logs import topics
    >>> topics.ESTIMATE_STATE, topics.CAMERA_IMAGE
    ('/estimate/state', '/camera/image')
"""

from __future__ import annotations

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
