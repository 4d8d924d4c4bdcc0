"""A Foxglove layout for a replayed log (``OUT.layout.json`` beside every replay output).

Import it in Foxglove (Layouts → Import from file) with the log open: the camera image with
its annotations (detections yellow, identified stars green, predicted cyan); a 3D view of
the ``body``, ``camera`` and ``body_truth`` frames in ``icrs``; plots of the attitude error
per body axis with its ±3σ bounds, the star-fix NIS, the stars matched per frame, and the
star-ID mode as a state timeline.

Example:
    >>> from adfusion.app.layout import foxglove_layout
    >>> layout = foxglove_layout()
    >>> sorted(layout["configById"])[:2]
    ['3D!body', 'Image!camera']
"""

from __future__ import annotations

from typing import Any

from adfusion.logs import topics

__all__ = ["foxglove_layout"]


def _plot(title: str, paths: list[tuple[str, str]], y_label: str) -> dict[str, Any]:
    return {"title": title, "paths": [
        {"value": value, "label": label, "enabled": True, "timestampMethod": "receiveTime"}
        for value, label in paths], "showLegend": True, "legendDisplay": "floating",
        "xAxisVal": "timestamp", "showXAxisLabels": True, "showYAxisLabels": True,
        "yAxisLabel": y_label}


def foxglove_layout(truth: bool = True, live: bool = False) -> dict[str, Any]:
    """The layout as a dict (JSON-ready); ``truth`` adds the error plot and truth frame,
    ``live`` a plot of each frame's latency and the frames dropped (``/live/status``)."""
    err, att = topics.ESTIMATE_ERROR, topics.ESTIMATE_ATTITUDE
    error_paths = [(f"{err}.error_deg[0]", "x error [deg]"), (f"{err}.sigma3_deg[0]", "x 3σ"),
                   (f"{err}.error_deg[1]", "y error [deg]"), (f"{err}.sigma3_deg[1]", "y 3σ"),
                   (f"{err}.error_deg[2]", "roll error [deg]"),
                   (f"{err}.sigma3_deg[2]", "roll 3σ")]
    sigma_paths = [(f"{att}.sigma_deg[0]", "1σ x [deg]"), (f"{att}.sigma_deg[1]", "1σ y [deg]"),
                   (f"{att}.sigma_deg[2]", "1σ roll [deg]")]
    config: dict[str, Any] = {
        "Image!camera": {"imageMode": {
            "imageTopic": topics.CAMERA_IMAGE, "calibrationTopic": topics.CAMERA_CALIBRATION,
            "annotations": {topics.CAMERA_ANNOTATIONS: {"visible": True}}}},
        "3D!body": {"followTf": "icrs", "followMode": "follow-pose",
                    "scene": {"transforms": {"showLabel": True, "axisScale": 1.0}},
                    "transforms": {f"frame:{f}": {"visible": True}
                                   for f in ("icrs", "body", "camera", "body_truth")},
                    "topics": {topics.ESTIMATE_POSE: {"visible": True},
                               topics.TRUTH_POSE: {"visible": truth}}},
        "Plot!error": _plot("Attitude error per body axis, ±3σ" if truth else
                            "Attitude 1σ per body axis",
                            error_paths if truth else sigma_paths, "deg"),
        "Plot!nis": _plot("Star-fix NIS (3 dof; 95 % bounds 0.22–9.35)",
                          [(f"{topics.ESTIMATE_STATE}.nis", "NIS")], "NIS"),
        "Plot!stars": _plot("Stars per frame", [
            (f"{topics.STARID_SOLUTION}.n_detections", "detected"),
            (f"{att}.n_stars", "matched")], "stars"),
        "StateTransitions!mode": {"paths": [
            {"value": f"{topics.STARID_SOLUTION}.mode", "timestampMethod": "receiveTime"},
            {"value": f"{topics.STARID_SOLUTION}.fix_accepted",
             "timestampMethod": "receiveTime"}]},
    }
    layout = {
        "direction": "row", "splitPercentage": 45,
        "first": {"direction": "column", "first": "Image!camera", "second": "3D!body",
                  "splitPercentage": 60},
        "second": {"direction": "column", "splitPercentage": 30, "first": "Plot!error",
                   "second": {"direction": "column", "splitPercentage": 33,
                              "first": "Plot!nis",
                              "second": {"direction": "column", "first": "Plot!stars",
                                         "second": "StateTransitions!mode",
                                         "splitPercentage": 60}}},
    }
    if live:  # the latency beside the stars per frame
        config["Plot!latency"] = _plot("Latency, arrival → estimate (ms); frames dropped", [
            (f"{topics.LIVE_STATUS}.latency_ms", "latency [ms]"),
            (f"{topics.LIVE_STATUS}.dropped", "dropped")], "ms")
        stars = layout["second"]["second"]["second"]
        stars["first"] = {"direction": "row", "first": "Plot!stars", "second": "Plot!latency"}
    return {"configById": config, "globalVariables": {}, "userNodes": {},
            "playbackConfig": {"speed": 1.0}, "layout": layout}
