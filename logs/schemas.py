"""JSON schemas (draft 2020-12) of the internal topics, registered per channel by the writer.

Fields: docs/concepts/log-topics.md. Quaternions are Hamilton scalar-first ``[w, x, y, z]``;
numbers may be ``null`` where a value is not finite (JSON has no NaN). Extra properties are
allowed so that a component can add a diagnostic without a schema change; the listed ones are
required.

Example:
    >>> from adfusion.logs.schemas import JSON_SCHEMAS
    >>> name, schema = JSON_SCHEMAS["/estimate/state"]
    >>> name, schema["required"][:2]
    ('adfusion.FilterState', ['t', 'q_body_icrs'])
"""

from __future__ import annotations

from typing import Any

DIALECT = "https://json-schema.org/draft/2020-12/schema"

_NUM: dict[str, Any] = {"type": ["number", "null"]}


def _vec(n: int | None, description: str, item: dict[str, Any] | None = None) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "array", "items": item or _NUM, "description": description}
    if n is not None:
        schema["minItems"] = n
        schema["maxItems"] = n
    return schema


def _object(title: str, properties: dict[str, Any], required: list[str]) -> dict[str, Any]:
    return {
        "$schema": DIALECT,
        "title": title,
        "type": "object",
        "properties": properties,
        "required": required,
    }


_QUAT = "Hamilton quaternion, scalar first [w, x, y, z]"
_T = {"type": "number", "description": "run time, seconds from the start (log times are UTC "
                                        "when the start is known: see the clock metadata)"}

STARID_SOLUTION = _object(
    "adfusion.StarIdSolution",
    {
        "t": _T,
        "ok": {"type": "boolean", "description": "a unique, accepted identification"},
        "mode": {"type": ["string", "null"], "description": "'lost-in-space' or 'tracking'"},
        "q_cam_icrs": {
            **_vec(4, _QUAT + "; rotates ICRS vectors into the camera frame"),
            "type": ["array", "null"],
        },
        "matches": _vec(
            None,
            "(detection index, catalogue id) pairs",
            {"type": "array", "items": {"type": "integer"}, "minItems": 2, "maxItems": 2},
        ),
        "matching_counter": {"type": "integer", "description": "distinct candidate patterns"},
        "p_false": {**_NUM, "description": "false-match probability of the identification"},
        "cone_deg": {**_NUM, "description": "search cone half-angle (tracking), degrees"},
        "reason": {"type": "string", "description": "why not ok ('' when ok)"},
        "time_ms": {**_NUM, "description": "solve time, milliseconds"},
        "fix_accepted": {"type": "boolean", "description": "the filter took the fix"},
        "n_detections": {"type": "integer", "description": "stars detected in the frame"},
        "residuals_arcsec": _vec(None, "per match: angle between the detected star and the "
                                       "catalogue star at the solution, arcsec"),
        "camera": {"type": "string", "description": "camera name (several-camera logs)"},
    },
    ["ok", "mode", "q_cam_icrs", "matches", "matching_counter", "cone_deg", "reason", "time_ms"],
)

GYRO = _object(
    "adfusion.Gyro",
    {"t": _T, "omega": _vec(3, "measured body rate, rad/s, body frame")},
    ["omega"],
)

MAG = _object(
    "adfusion.Magnetometer",
    {"t": _T, "b_body": _vec(3, "measured magnetic field, nT, body frame"),
     "b_ref_icrs": _vec(3, "reference (model) field, nT, ICRS frame (optional)")},
    ["b_body"],
)

_REJECTED = _vec(None, "inputs not used, each with why", {
    "type": "object",
    "properties": {"input": {"type": "string", "description": "'gyro', 'mag', 'star fix', "
                                                               "'camera' or 'time'"},
                   "reason": {"type": "string"}},
    "required": ["input", "reason"]})

FILTER_STATE = _object(
    "adfusion.FilterState",
    {
        "t": {"type": "number", "description": "state time, seconds"},
        "q_body_icrs": _vec(4, _QUAT + "; rotates ICRS vectors into the body frame"),
        "bias": {**_vec(3, "gyro bias estimate, rad/s, body frame (null: no gyro)"),
                 "type": ["array", "null"]},
        "omega": _vec(3, "body rate estimate, rad/s, body frame (without a gyro: "
                         "video-only, or a gyro outage)"),
        "cov_diag": _vec(None, "covariance diagonal: attitude error (rad^2, body axes), then "
                               "bias or rate ((rad/s)^2)"),
        "cov": _vec(36, "full error covariance, 6×6 row-major: attitude error (rad^2, body "
                        "axes), then bias or rate ((rad/s)^2), cross terms rad^2/s; its "
                        "diagonal is cov_diag (filter only: /smoothed/state has cov_diag "
                        "alone; optional, absent in older logs)"),
        "nis": {**_NUM, "description": "normalised innovation squared of this frame's star "
                                       "fix (3 dof; null: no fix was tested)"},
        "rejected": _REJECTED,
        "n_stars": {"type": "integer", "description": "stars used (smoother)"},
        "chi2_stars": {**_NUM, "description": "star residual chi-square (smoother)"},
        "downweighted": _vec(None, "catalogue ids down-weighted as outliers (smoother)",
                             {"type": "integer"}),
    },
    ["t", "q_body_icrs", "bias", "cov_diag", "nis"],
)

ATTITUDE_DEG = _object(
    "adfusion.AttitudeDeg",
    {
        "t": _T,
        "ra_deg": {"type": "number", "description": "right ascension of body +z, ICRS, deg"},
        "dec_deg": {"type": "number", "description": "declination of body +z, ICRS, deg"},
        "roll_deg": {"type": "number", "description": "roll about body +z, deg, in [0, 360): "
                                                      "0 when body -y points north "
                                                      "(rotations.radec_roll_from_q_cam_icrs "
                                                      "of q_body_icrs)"},
        "sigma_deg": _vec(3, "1σ attitude error about body x, y (cross-boresight) and z "
                             "(roll), deg"),
        "mode": {"type": ["string", "null"], "description": "star-ID mode of the frame"},
        "n_stars": {"type": "integer", "description": "stars matched in the frame"},
    },
    ["t", "ra_deg", "dec_deg", "roll_deg", "sigma_deg"],
)

ATTITUDE_ERROR = _object(
    "adfusion.AttitudeError",
    {
        "t": _T,
        "error_deg": _vec(3, "estimate ⊗ truth⁻¹ as a rotation vector about body x, y "
                             "(cross-boresight) and z (roll), deg"),
        "angle_deg": {"type": "number", "description": "total error angle, deg"},
        "sigma3_deg": _vec(3, "the filter's 3σ about body x, y, z, deg"),
    },
    ["t", "error_deg", "angle_deg", "sigma3_deg"],
)

TRUTH_STATE = _object(
    "adfusion.TruthState",
    {
        "t": {"type": "number", "description": "time, seconds"},
        "q_body_icrs": _vec(4, _QUAT + "; rotates ICRS vectors into the body frame"),
        "omega": _vec(3, "true body rate, rad/s, body frame (optional)"),
        "bias": _vec(3, "true gyro bias, rad/s (optional)"),
    },
    ["t", "q_body_icrs"],
)

CENTROIDS = _object(
    "adfusion.Centroids",
    {"t": _T, "xy": _vec(None, "star centroids, pixels (0-based centres, x right, y down)",
                         _vec(None, "x, y[, flux]"))},
    ["xy"],
)

LIVE_STATUS = _object(
    "adfusion.LiveStatus",
    {
        "t": _T,
        "latency_ms": {"type": "number", "description": "this frame's arrival (file complete "
                       "on disk, or grabbed from the camera) to its estimate published, "
                       "milliseconds"},
        "frames": {"type": "integer", "description": "frames solved so far"},
        "dropped": {"type": "integer", "description": "frames dropped so far: they arrived "
                    "while the solver was busy with an earlier one"},
    },
    ["t", "latency_ms", "frames", "dropped"],
)

GENERIC = {"$schema": DIALECT, "title": "adfusion.Json", "type": "object"}

JSON_SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    "/starid/solution": ("adfusion.StarIdSolution", STARID_SOLUTION),
    "/imu/gyro": ("adfusion.Gyro", GYRO),
    "/mag": ("adfusion.Magnetometer", MAG),
    "/estimate/state": ("adfusion.FilterState", FILTER_STATE),
    "/estimate/attitude": ("adfusion.AttitudeDeg", ATTITUDE_DEG),
    "/estimate/error": ("adfusion.AttitudeError", ATTITUDE_ERROR),
    "/smoothed/state": ("adfusion.FilterState", FILTER_STATE),
    "/truth/state": ("adfusion.TruthState", TRUTH_STATE),
    "/camera/centroids": ("adfusion.Centroids", CENTROIDS),
    "/live/status": ("adfusion.LiveStatus", LIVE_STATUS),
}
"""Topic → (schema name, JSON schema) for the JSON topics (docs/concepts/log-topics.md)."""
