"""JSON schemas (draft 2020-12) of the internal topics, registered per channel by the writer.

Fields follow DESIGN.md's MCAP table. Quaternions are Hamilton scalar-first ``[w, x, y, z]``;
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

STARID_SOLUTION = _object(
    "adfusion.StarIdSolution",
    {
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
        "cone_deg": {**_NUM, "description": "search cone half-angle (tracking), degrees"},
        "reason": {"type": "string", "description": "why not ok ('' when ok)"},
        "time_ms": {**_NUM, "description": "solve time, milliseconds"},
    },
    ["ok", "mode", "q_cam_icrs", "matches", "matching_counter", "cone_deg", "reason", "time_ms"],
)

GYRO = _object(
    "adfusion.Gyro",
    {"omega": _vec(3, "measured body rate, rad/s, body frame")},
    ["omega"],
)

MAG = _object(
    "adfusion.Magnetometer",
    {"b_body": _vec(3, "measured magnetic field, nT, body frame")},
    ["b_body"],
)

FILTER_STATE = _object(
    "adfusion.FilterState",
    {
        "t": {"type": "number", "description": "state time, seconds"},
        "q_body_icrs": _vec(4, _QUAT + "; rotates ICRS vectors into the body frame"),
        "bias": _vec(3, "gyro bias estimate, rad/s, body frame"),
        "cov_diag": _vec(None, "covariance diagonal: attitude error (rad^2), bias ((rad/s)^2)"),
        "nis": {**_NUM, "description": "normalised innovation squared of the last update"},
    },
    ["t", "q_body_icrs", "bias", "cov_diag", "nis"],
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

GENERIC = {"$schema": DIALECT, "title": "adfusion.Json", "type": "object"}

JSON_SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    "/starid/solution": ("adfusion.StarIdSolution", STARID_SOLUTION),
    "/imu/gyro": ("adfusion.Gyro", GYRO),
    "/mag": ("adfusion.Magnetometer", MAG),
    "/estimate/state": ("adfusion.FilterState", FILTER_STATE),
    "/smoothed/state": ("adfusion.FilterState", FILTER_STATE),
    "/truth/state": ("adfusion.TruthState", TRUTH_STATE),
}
"""Topic → (schema name, JSON schema) for the JSON topics of DESIGN.md."""
