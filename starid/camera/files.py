"""Camera files ⇄ :class:`starid.Camera`: OpenCV calibration YAML, ROS ``camera_info`` YAML
and our ``camera.json`` — :func:`read_camera` is the one loader every command uses.

The format is the one OpenCV's own calibration samples write with ``cv::FileStorage``
(``%YAML:1.0``, ``camera_matrix`` and ``distortion_coefficients`` as ``!!opencv-matrix``,
``image_width``/``image_height``), read and written here through OpenCV's
``cv2.FileStorage`` itself, so a file from ``cv2.calibrateCamera`` tooling loads as it
is. ROS ``camera_info`` files (the same keys as ``{rows, cols, data}`` maps) load too.
Two optional keys of ours: ``parity`` (−1 for a mirrored image) and ``model``
(``pinhole``, the OpenCV model, by default). Pixel coordinates are OpenCV's: 0-based
pixel centres, x right, y down (as docs/conventions.md). ``camera.json`` is
:meth:`Camera.to_dict` (``model``, ``width``, ``height``, ``K``, ``D``, ``parity``), the
attachment of our logs; a JSON file with the OpenCV keys (``cv2.FileStorage``'s JSON) loads
as the YAML does.

Strict: every value has the type its key needs — an integer is an integer (``512.0`` is
512, ``512.7``, ``true`` and ``"512"`` are refused), a boolean is not a number, a number is
not a string — and a key given twice is refused; each error is one ``ValueError`` naming the
file, the key and what was expected (``cam.json: width: 512.7 is not an integer
(pixels)``). YAML is read with PyYAML (OpenCV's ``%YAML:1.0`` header and ``!!opencv-matrix``
tags understood; ``1e-5`` is a number as in YAML 1.2), JSON with :mod:`json`.

Example:
    >>> import tempfile, pathlib
    >>> from adfusion.starid import Camera
    >>> from adfusion.starid.camera.files import read_camera_yaml, write_camera_yaml
    >>> cam = Camera.pinhole(1024, 768, 11.4)
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "camera.yaml"
    >>> write_camera_yaml(cam, path)
    >>> read_camera_yaml(path) == cam
    True
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
from adfusion.starid.camera.model import Camera

__all__ = ["camera_from_mapping", "read_camera", "read_camera_yaml", "write_camera_yaml"]


def write_camera_yaml(camera: Camera, path: str | os.PathLike[str],
                      comment: str | None = None, **extra: float) -> None:
    """Write ``camera`` as an OpenCV calibration YAML (``extra``: numbers to add, such as
    the fit's RMS residual; ``comment``: a line of text at the top)."""
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
    if not fs.isOpened():
        raise ValueError(f"cannot write the camera file {path}")
    try:
        if comment:
            fs.writeComment(comment)
        fs.write("image_width", int(camera.width))
        fs.write("image_height", int(camera.height))
        fs.write("camera_matrix", np.asarray(camera.K, np.float64))
        # OpenCV files always carry the coefficients: none is written as five zeros
        d = np.zeros(5) if camera.D.size == 0 else np.asarray(camera.D, np.float64)
        fs.write("distortion_coefficients", d.reshape(1, -1))
        fs.write("model", camera.model)
        fs.write("parity", int(camera.parity))
        for k, v in extra.items():
            fs.write(k, float(v))
    finally:
        fs.release()


def read_camera(path: str | os.PathLike[str]) -> Camera:
    """The camera model in ``path``: OpenCV or ROS ``camera_info`` YAML, or ``camera.json``
    (JSON by content: the first character is ``{``). A missing file is a
    :class:`FileNotFoundError`; anything else wrong a one-line :class:`ValueError` naming
    the file (and the key)."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"camera file not found: {p}")
    try:
        text = p.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{p}: not a camera file (not UTF-8 text)") from None
    data = _parse_json(text, p) if text.lstrip().startswith("{") else _parse_yaml(text, p)
    if not isinstance(data, dict):
        raise ValueError(f"{p}: not a camera file (no keys; an OpenCV camera YAML has "
                         "image_width, image_height, camera_matrix, distortion_coefficients)")
    return camera_from_mapping(data, p)


def read_camera_yaml(path: str | os.PathLike[str]) -> Camera:
    """Read an OpenCV (or ROS ``camera_info``) calibration YAML into a :class:`Camera` —
    :func:`read_camera`, kept under its old name (a ``camera.json`` loads as well)."""
    return read_camera(path)


_JSON_KEYS = ("model", "width", "height", "K", "D", "parity")


def camera_from_mapping(data: dict, path: str | os.PathLike[str]) -> Camera:
    """A :class:`Camera` from a parsed camera file (``path`` names it in errors), checking
    every value's type: the OpenCV/ROS keys (``image_width``, ``camera_matrix`` …) or those
    of :meth:`Camera.to_dict`.

    >>> camera_from_mapping({"width": 8, "height": 6, "K": [[4, 0, 3.5], [0, 4, 2.5],
    ...                      [0, 0, 1]], "D": []}, "cam.json").width
    8
    >>> camera_from_mapping({"width": 512.7, "height": 6, "K": [], "D": []}, "cam.json")
    Traceback (most recent call last):
    ...
    ValueError: cam.json: width: 512.7 is not an integer (pixels)
    """
    p = os.fspath(path)
    opencv = any(k in data for k in ("image_width", "image_height", "camera_matrix"))
    if opencv:
        w = _integer(_need(data, "image_width", p), p, "image_width", "pixels")
        h = _integer(_need(data, "image_height", p), p, "image_height", "pixels")
        K = _yaml_matrix(_need(data, "camera_matrix", p), p, "camera_matrix")
        if K.shape != (3, 3):
            raise ValueError(f"{p}: camera_matrix must be 3×3, got {K.shape[0]}×{K.shape[1]}")
        d = data.get("distortion_coefficients")
        D = np.zeros(0) if d is None else _yaml_matrix(d, p, "distortion_coefficients").ravel()
    else:
        unknown = [k for k in data if k not in _JSON_KEYS]
        if unknown:
            raise ValueError(f"{p}: {unknown[0]}: unknown key (a camera.json has "
                             f"{', '.join(_JSON_KEYS)}; an OpenCV camera YAML image_width, "
                             "image_height, camera_matrix, distortion_coefficients)")
        w = _integer(_need(data, "width", p), p, "width", "pixels")
        h = _integer(_need(data, "height", p), p, "height", "pixels")
        K = _rows(_need(data, "K", p), p, "K")
        D = _numbers(_need(data, "D", p), p, "D", "distortion coefficients")
    model = data.get("model")
    model = "pinhole" if model is None else _string(model, p, "model", "a camera model name")
    parity = data.get("parity")
    parity = 1 if parity is None else _integer(parity, p, "parity", "1, or −1 for a mirror")
    try:
        return Camera(K, D, w, h, model, parity)
    except ValueError as e:
        raise ValueError(f"{p}: {' '.join(str(e).split())}") from None


# --- parsing ------------------------------------------------------------------------------


def _parse_json(text: str, p: Path) -> Any:
    def pairs(items: list[tuple[str, Any]]) -> dict:
        out: dict = {}
        for k, v in items:
            if k in out:
                raise ValueError(f"{p}: {k}: duplicate key (given twice)")
            out[k] = v
        return out

    try:
        return json.loads(text, object_pairs_hook=pairs)
    except json.JSONDecodeError as e:
        raise ValueError(f"{p}: not valid JSON: {e.msg} (line {e.lineno}, column {e.colno})"
                         ) from None


_OPENCV_HEADER = re.compile(r"\A\s*%YAML[: ]?\d+\.\d+[^\n]*")
# YAML 1.2 numbers PyYAML's 1.1 rules read as strings: 1e-5, 1E+3, 2.5e3
_FLOAT_12 = re.compile(r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$")


class _Duplicate(Exception):
    def __init__(self, key: Any, line: int) -> None:
        super().__init__(key, line)
        self.key, self.line = key, line


def _yaml_loader():
    import yaml

    class StrictLoader(yaml.SafeLoader):
        """SafeLoader refusing duplicate keys, reading OpenCV's ``!!opencv-matrix`` maps."""

    def mapping(loader: StrictLoader, node: yaml.MappingNode) -> dict:
        loader.flatten_mapping(node)
        out: dict = {}
        for knode, vnode in node.value:
            key = loader.construct_object(knode, deep=True)
            try:
                seen = key in out
            except TypeError:  # a list or map as a key
                raise yaml.constructor.ConstructorError(
                    None, None, "a key that is not a name", knode.start_mark) from None
            if seen:
                raise _Duplicate(key, knode.start_mark.line + 1)
            out[key] = loader.construct_object(vnode, deep=True)
        return out

    StrictLoader.add_constructor("tag:yaml.org,2002:map", mapping)
    StrictLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", mapping)
    StrictLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12,
                                       list("-+0123456789."))
    return StrictLoader


def _parse_yaml(text: str, p: Path) -> Any:
    import yaml

    text = _OPENCV_HEADER.sub("", text, count=1)  # OpenCV's "%YAML:1.0": not YAML syntax
    try:
        return yaml.load(text, Loader=_yaml_loader())  # a SafeLoader subclass
    except _Duplicate as e:
        raise ValueError(f"{p}: {e.key}: duplicate key (given twice; line {e.line})") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        what = getattr(e, "problem", None) or type(e).__name__
        raise ValueError(f"{p}: not a YAML camera file OpenCV can read: "
                         f"{' '.join(str(what).split())}{where}") from None


# --- typed values ---------------------------------------------------------------------------


def _need(data: dict, key: str, p: str) -> Any:
    if key not in data or data[key] is None:
        raise ValueError(f"{p}: missing {key!r} (an OpenCV camera YAML has image_width, "
                         "image_height, camera_matrix, distortion_coefficients; a camera.json "
                         f"{', '.join(_JSON_KEYS)})")
    return data[key]


def _kind(v: Any) -> str | None:
    """What a value is when it is not a number: for the error."""
    if isinstance(v, bool):
        return f"{str(v).lower()} is a boolean"
    if isinstance(v, str):
        return f"{json.dumps(v, ensure_ascii=False)} is a string"
    if v is None:
        return "null is empty"
    if isinstance(v, dict):
        return "a mapping"
    if isinstance(v, list | tuple):
        return "a list"
    if not isinstance(v, int | float):
        return f"{v!r} is a {type(v).__name__}"
    return None


def _integer(v: Any, p: str, key: str, what: str) -> int:
    kind = _kind(v)
    if kind is not None:
        raise ValueError(f"{p}: {key}: {kind}, not an integer ({what})")
    if isinstance(v, float) and not (math.isfinite(v) and v.is_integer()):
        raise ValueError(f"{p}: {key}: {v!r} is not an integer ({what})")
    return int(v)


def _number(v: Any, p: str, key: str, what: str) -> float:
    kind = _kind(v)
    if kind is not None:
        raise ValueError(f"{p}: {key}: {kind}, not a number ({what})")
    if not math.isfinite(v):
        raise ValueError(f"{p}: {key}: {v!r} is not a finite number ({what})")
    return float(v)


def _string(v: Any, p: str, key: str, what: str) -> str:
    if not isinstance(v, str):
        shown = str(v).lower() if isinstance(v, bool) else repr(v)
        raise ValueError(f"{p}: {key}: {shown} is not a string ({what})")
    return v


def _numbers(v: Any, p: str, key: str, what: str) -> np.ndarray:
    if not isinstance(v, list):
        raise ValueError(f"{p}: {key}: {_kind(v) or repr(v)}, not a list of numbers ({what})")
    return np.array([_number(x, p, f"{key}[{i}]", what) for i, x in enumerate(v)], np.float64)


def _rows(v: Any, p: str, key: str) -> np.ndarray:
    """``K`` of a camera.json: three rows of three numbers."""
    what = "the 3×3 camera matrix, in pixels"
    if not isinstance(v, list) or len(v) != 3 or not all(isinstance(r, list) for r in v):
        raise ValueError(f"{p}: {key}: not three rows of three numbers ({what})")
    rows = [_numbers(r, p, f"{key}[{i}]", what) for i, r in enumerate(v)]
    if any(len(r) != 3 for r in rows):
        raise ValueError(f"{p}: {key}: not three rows of three numbers ({what})")
    return np.stack(rows)


def _yaml_matrix(v: Any, p: str, key: str) -> np.ndarray:
    """An OpenCV ``!!opencv-matrix`` or ROS ``{rows, cols, data}`` map as an array."""
    if not isinstance(v, dict):
        raise ValueError(f"{p}: {key!r} is not a matrix (a map of rows, cols and data)")
    rows = _integer(_need(v, "rows", f"{p}: {key}"), p, f"{key}.rows", "a count")
    cols = _integer(_need(v, "cols", f"{p}: {key}"), p, f"{key}.cols", "a count")
    if "dt" in v:
        _string(v["dt"], p, f"{key}.dt", "an OpenCV element type such as d")
    vals = _numbers(_need(v, "data", f"{p}: {key}"), p, f"{key}.data", "matrix elements")
    if rows < 0 or cols < 0 or len(vals) != rows * cols:
        raise ValueError(f"{p}: {key} has {len(vals)} values for {rows}×{cols}")
    return vals.reshape(rows, cols)
