"""The log-topic tables of ``docs/concepts/log-topics.md``, generated from the code.

A MkDocs hook (``hooks:`` in ``mkdocs.yml``): at build time it replaces the
``<!-- topics:table -->`` and ``<!-- topics:fields -->`` markers of that page with tables
built from the code: ``adfusion.logs.topics.table()`` where the code has it, and
:data:`adfusion.logs.schemas.JSON_SCHEMAS` for the fields. Without a topics table, the
Foxglove topics come from the ``*_TOPIC`` constants of :mod:`adfusion.logs`, and what the
code does not say (their frames, the fields a replay adds beyond a schema's) from
:data:`NOTES` below, and any other topic of ``adfusion.logs.topics`` from the docstring
under its constant; the build then fails when a topic of the code has neither, so the page
cannot drift from the code.

Run it as a script to print the tables::

    python docs/gen_topics.py
"""

from __future__ import annotations

import ast
import importlib
import inspect
import itertools
from typing import Any

TABLE_MARK = "<!-- topics:table -->"
FIELDS_MARK = "<!-- topics:fields -->"
PAGE = "concepts/log-topics.md"

# Per topic: who writes it, the frame its vectors are in, and what a person finds in it.
# JSON topics take their schema and fields from adfusion.logs.schemas; the Foxglove ones
# name their schema here. ``extra`` lists fields written beyond the JSON schema's.
NOTES: dict[str, dict[str, Any]] = {
    "/camera/image": {
        "schema": "foxglove.RawImage", "by": "simulate, replay (copied)", "frame": "camera",
        "content": "every frame: mono8 or mono16, pixel (0, 0) the top-left pixel's centre",
    },
    "/camera/calibration": {
        "schema": "foxglove.CameraCalibration", "by": "simulate, replay", "frame": "camera",
        "content": "the camera model: width, height, K (px), D (OpenCV distortion)",
    },
    "/camera/annotations": {
        "schema": "foxglove.ImageAnnotations", "by": "replay", "frame": "camera (pixels)",
        "content": "detections (yellow points), identified stars (green circles labelled "
                   "with the catalogue id), catalogue stars predicted at the fix (cyan "
                   "points); 0-based pixel centres",
    },
    "/camera/centroids": {
        "schema": "adfusion.Json", "by": "simulate --no-render", "frame": "camera (pixels)",
        "content": "a frame as star centroids instead of an image",
        "fields": [("t", "number", "frame time, s"),
                   ("xy", "array", "(N, 2) centroids, pixels, brightest first")],
    },
    "/starid/solution": {
        "by": "replay", "frame": "camera",
        "content": "each frame's identification: ok, mode, attitude, matches, reason, time",
        "extra": [("t", "number", "frame time, s"),
                  ("p_false", "number or null", "false-match probability of the fix"),
                  ("fix_accepted", "boolean", "whether the filter accepted the fix")],
    },
    "/imu/gyro": {
        "by": "simulate, sensor CSV", "frame": "body",
        "content": "gyro samples (measured rate: true rate + bias + noise)",
        "extra": [("t", "number", "sample time, s")],
    },
    "/mag": {
        "by": "simulate, sensor CSV", "frame": "body",
        "content": "magnetometer samples",
        "extra": [("t", "number", "sample time, s"),
                  ("b_ref_icrs", "array (3)", "the reference (IGRF) field at the vehicle, nT, "
                   "ICRS; replay uses a sample only when it has this")],
    },
    "/estimate/state": {
        "by": "replay", "frame": "ICRS → body",
        "content": "the filter state after each frame",
        "extra": [("rejected", "array", "(input, reason) pairs the estimator rejected")],
    },
    "/estimate/pose": {
        "schema": "foxglove.PoseInFrame", "by": "replay", "frame": "icrs",
        "content": "the estimated body orientation in icrs (q_icrs_body, x y z w)",
    },
    "/smoothed/state": {
        "by": "replay --smooth", "frame": "ICRS → body",
        "content": "the smoother's state per frame; nis is null (a smoother has no "
                   "innovations)",
        "extra": [("n_stars", "integer", "stars in the frame's factors"),
                  ("chi2_stars", "number or null", "sum of squared whitened star residuals"),
                  ("downweighted", "array", "ids of stars the robust kernel down-weighted"),
                  ("omega", "array (3)", "estimated body rate, rad/s, body (video-only)")],
    },
    "/smoothed/pose": {
        "schema": "foxglove.PoseInFrame", "by": "replay --smooth", "frame": "icrs",
        "content": "the smoothed body orientation in icrs",
    },
    "/truth/state": {
        "by": "simulate", "frame": "ICRS → body",
        "content": "the simulated truth at every sample time (simulations only)",
    },
    "/truth/pose": {
        "schema": "foxglove.PoseInFrame", "by": "simulate", "frame": "icrs",
        "content": "the true body orientation in icrs (simulations only)",
    },
    "/tf": {
        "schema": "foxglove.FrameTransforms", "by": "simulate, replay", "frame": "icrs, body, "
        "camera, body_truth",
        "content": "icrs → body (estimate), body → camera (mounting), body_truth → camera "
                   "(simulations)",
    },
}


def _module(name: str):
    """``adfusion.logs.<name>`` (ImportError when there is none)."""
    return importlib.import_module(f"adfusion.logs.{name}")


def code_topics() -> dict[str, str]:
    """Every topic the code names: topic → where (JSON schemas and ``*_TOPIC`` constants)."""
    found: dict[str, str] = {t: "schemas.JSON_SCHEMAS" for t in _module("schemas").JSON_SCHEMAS}
    for mod in ("writer", "sources", "topics"):
        try:
            m = _module(mod)
        except ImportError:
            continue
        for k, v in vars(m).items():
            if k.isupper() and isinstance(v, str) and v.startswith("/"):
                found.setdefault(v, f"{mod}.{k}")
    return found


def topic_docs() -> dict[str, str]:
    """Topic → the docstring under its constant in ``adfusion.logs.topics`` (read from the
    source: attribute docstrings do not exist at run time)."""
    try:
        tree = ast.parse(inspect.getsource(_module("topics")))
    except ImportError:
        return {}
    docs: dict[str, str] = {}
    for node, after in itertools.pairwise(tree.body):
        if (isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant)
                and isinstance(node.value.value, str) and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str)):
            docs[node.value.value] = " ".join(after.value.value.split())
    return docs


def notes() -> dict[str, dict[str, Any]]:
    """:data:`NOTES`, plus a row for every other topic of ``adfusion.logs.topics`` made from
    its docstring (generic JSON unless the schemas know it)."""
    out = dict(NOTES)
    for topic, doc in topic_docs().items():
        out.setdefault(topic, {"schema": "adfusion.Json", "by": "—", "frame": "—",
                               "content": doc.replace("``", "`")})
    return out


def check() -> None:
    """Raise when a topic of the code has neither an entry in :data:`NOTES` nor a docstring
    in ``adfusion.logs.topics``, or NOTES names a topic the code does not have."""
    code = code_topics()
    missing = sorted(set(code) - set(notes()))
    if missing:
        raise RuntimeError(f"docs/gen_topics.py: topics in the code without an entry in NOTES: "
                           f"{', '.join(f'{t} ({code[t]})' for t in missing)}")
    try:  # once the code keeps every topic name in one module, check the other way too
        _module("topics")
    except ImportError:
        pass
    else:
        unknown = sorted(set(NOTES) - set(code))
        if unknown:
            raise RuntimeError(f"docs/gen_topics.py: NOTES has topics the code does not: "
                               f"{', '.join(unknown)}")
    schemas = _module("schemas").JSON_SCHEMAS
    for topic, note in notes().items():
        if topic not in schemas and "schema" not in note:
            raise RuntimeError(f"docs/gen_topics.py: {topic} is neither in JSON_SCHEMAS nor "
                               "given a schema in NOTES")


def _type(prop: dict[str, Any]) -> str:
    t = prop.get("type", "")
    types = list(t) if isinstance(t, list) else [str(t)]
    n = prop.get("minItems")
    if n is not None and n == prop.get("maxItems"):  # a fixed-length array: say its length
        types = [f"{x} ({n})" if x == "array" else x for x in types]
    return " or ".join(types)  # not "|": the cell is inside a markdown table


def _cell(text: Any) -> str:
    return str(text).replace("|", "or").replace("\n", " ")


def _code_table() -> list[dict[str, Any]] | None:
    """``adfusion.logs.topics.table()`` (topic, schema, fields, units, frame) when the code
    has one; then it is the single source and :data:`NOTES` is not used."""
    try:
        return list(_module("topics").table())
    except (ImportError, AttributeError):
        return None


def topics_table() -> str:
    """One row per topic: schema, encoding, frame, writer, content."""
    rows = _code_table()
    if rows is not None:
        out = ["| topic | schema | fields | units | frame |", "|---|---|---|---|---|"]
        out += [f"| `{r['topic']}` | `{r['schema']}` | {_cell(r['fields'])} | "
                f"{_cell(r['units'])} | {_cell(r['frame'])} |" for r in rows]
        # topics the module names but its table leaves out: described by their docstrings
        listed = {r["topic"] for r in rows}
        for topic, doc in sorted(topic_docs().items()):
            if topic not in listed:
                out.append(f"| `{topic}` | `adfusion.Json` | {_cell(doc.replace('``', '`'))} "
                           "| — | — |")
        missing = sorted(set(code_topics()) - listed - set(topic_docs()))
        if missing:
            raise RuntimeError(f"docs/gen_topics.py: topics neither in topics.table() nor "
                               f"documented in adfusion.logs.topics: {', '.join(missing)}")
        return "\n".join(out)
    check()
    schemas = _module("schemas").JSON_SCHEMAS
    rows = ["| topic | schema | encoding | frame | written by | content |",
            "|---|---|---|---|---|---|"]
    table = notes()
    for topic in sorted(table):
        note = table[topic]
        if topic in schemas:
            schema, encoding = schemas[topic][0], "JSON (jsonschema)"
        else:
            schema = note["schema"]
            encoding = "JSON" if schema == "adfusion.Json" else "protobuf"
        rows.append(f"| `{topic}` | `{schema}` | {encoding} | {note['frame']} | {note['by']} | "
                    f"{note['content']} |")
    return "\n".join(rows)


def fields_table() -> str:
    """One row per field of every JSON topic: type, required, description (unit, frame)."""
    schemas = _module("schemas").JSON_SCHEMAS
    if _code_table() is not None:
        rows = ["| topic | field | type | status | description (unit, frame) |",
                "|---|---|---|---|---|"]
        for topic in sorted(schemas):
            schema = schemas[topic][1]
            required = set(schema.get("required", ()))
            for name, prop in schema["properties"].items():
                status = "required" if name in required else "optional"
                rows.append(f"| `{topic}` | `{name}` | {_type(prop)} | {status} | "
                            f"{_cell(prop.get('description', ''))} |")
        return "\n".join(rows)
    check()
    rows = ["| topic | field | type | in the schema | description (unit, frame) |",
            "|---|---|---|---|---|"]
    table = notes()
    for topic in sorted(table):
        note = table[topic]
        if topic in schemas:
            schema = schemas[topic][1]
            required = set(schema.get("required", ()))
            for name, prop in schema["properties"].items():
                status = "required" if name in required else "optional"
                rows.append(f"| `{topic}` | `{name}` | {_type(prop)} | {status} | "
                            f"{prop.get('description', '')} |")
        for name, typ, text in note.get("fields", []) + note.get("extra", []):
            rows.append(f"| `{topic}` | `{name}` | {typ} | not in the schema | {text} |")
    return "\n".join(rows)


def on_page_markdown(markdown: str, page: Any, **kwargs: Any) -> str:
    """MkDocs hook: fill the markers of the log-topics page."""
    if page.file.src_uri != PAGE:
        return markdown
    for mark in (TABLE_MARK, FIELDS_MARK):
        if mark not in markdown:
            raise RuntimeError(f"docs/{PAGE}: the marker {mark} is missing")
    return (markdown.replace(TABLE_MARK, topics_table())
            .replace(FIELDS_MARK, fields_table()))


if __name__ == "__main__":
    print(topics_table(), fields_table(), sep="\n\n")
