"""Camera model files: OpenCV's camera YAML, ROS ``camera_info`` YAML, our ``camera.json``.

* OpenCV (``cv2.FileStorage``, ``%YAML:1.0``): ``image_width``, ``image_height``,
  ``camera_matrix`` (3×3), ``distortion_coefficients`` (k1 k2 p1 p2 [k3]);
* ROS ``camera_info`` (``camera_calibration``'s output): ``image_width``, ``image_height``,
  ``camera_matrix: {rows, cols, data}``, ``distortion_model: plumb_bob``,
  ``distortion_coefficients: {data}``;
* JSON: :meth:`adfusion.starid.camera.Camera.to_dict` (``width``, ``height``, ``K``, ``D``).

Pixel convention: OpenCV's and ROS's (0-based pixel centres), the project's own. A missing
or malformed field is a one-line :class:`ValueError` naming it.

Example:
    >>> import os, tempfile
    >>> from adfusion.app.camera_file import load_camera, save_camera
    >>> from adfusion.starid import Camera
    >>> path = os.path.join(tempfile.mkdtemp(), "camera.yaml")
    >>> save_camera(Camera.pinhole(512, 480, 20.0), path)
    >>> cam = load_camera(path)
    >>> cam.width, cam.height, round(cam.fov_x_deg, 6)
    (512, 480, 20.0)
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from adfusion.starid.camera import Camera

__all__ = ["load_camera", "save_camera"]


def load_camera(path: str | os.PathLike[str]) -> Camera:
    """The camera model in ``path`` (format by content; see the module docstring)."""
    if not os.path.exists(path):
        raise FileNotFoundError(f"--camera {path}: no such file")
    text = open(path, encoding="utf-8", errors="replace").read()
    try:
        if text.lstrip().startswith("{"):
            d = json.loads(text)
            return _camera(path, d.get("width"), d.get("height"), d.get("K"), d.get("D", ()),
                           d.get("model", "pinhole"), int(d.get("parity", 1)))
        if text.lstrip().startswith("%YAML"):
            return _opencv(path)
        import yaml

        d = yaml.safe_load(text)
    except (ValueError, json.JSONDecodeError) as e:
        if str(e).startswith(f"--camera {path}"):
            raise
        raise ValueError(f"--camera {path}: not a camera file ({e})") from None
    except Exception as e:  # yaml errors
        raise ValueError(f"--camera {path}: not a camera file ({type(e).__name__})") from None
    if not isinstance(d, dict):
        raise ValueError(f"--camera {path}: not a camera file (no fields)")
    model = d.get("distortion_model", "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial", "pinhole"):
        raise ValueError(f"--camera {path}: distortion_model {model!r} is not supported "
                         "(plumb_bob)")
    return _camera(path, d.get("image_width"), d.get("image_height"),
                   _matrix(d.get("camera_matrix")), _matrix(d.get("distortion_coefficients")))


def _matrix(x: Any) -> Any:
    if isinstance(x, dict):
        return x.get("data")
    return x


def _opencv(path) -> Camera:
    import cv2

    fs = cv2.FileStorage(os.fspath(path), cv2.FILE_STORAGE_READ)
    try:
        def num(name):
            node = fs.getNode(name)
            return None if node.empty() else int(node.real())

        def mat(name):
            node = fs.getNode(name)
            return None if node.empty() else node.mat()

        return _camera(path, num("image_width"), num("image_height"), mat("camera_matrix"),
                       mat("distortion_coefficients"))
    finally:
        fs.release()


def _camera(path, width, height, K, D, model: str = "pinhole", parity: int = 1) -> Camera:
    for name, value in (("image_width", width), ("image_height", height),
                        ("camera_matrix", K)):
        if value is None:
            raise ValueError(f"--camera {path}: no {name}")
    K = np.asarray(K, dtype=np.float64).reshape(-1)
    if K.size != 9:
        raise ValueError(f"--camera {path}: camera_matrix has {K.size} values, not 9")
    D = np.zeros(5) if D is None else np.asarray(D, dtype=np.float64).reshape(-1)
    D = np.concatenate([D, np.zeros(max(0, 5 - D.size))])[:5]
    if not np.all(np.isfinite(K)) or K[0] <= 0 or K[4] <= 0:
        raise ValueError(f"--camera {path}: camera_matrix needs positive focal lengths")
    return Camera(K.reshape(3, 3), D, int(width), int(height), model, parity)


def save_camera(camera: Camera, path: str | os.PathLike[str]) -> None:
    """Write ``camera`` as OpenCV camera YAML (``cv2.FileStorage``)."""
    import cv2

    fs = cv2.FileStorage(os.fspath(path), cv2.FILE_STORAGE_WRITE)
    try:
        fs.write("image_width", int(camera.width))
        fs.write("image_height", int(camera.height))
        fs.write("camera_matrix", np.asarray(camera.K, dtype=np.float64))
        fs.write("distortion_coefficients", np.asarray(camera.D, dtype=np.float64).reshape(1, -1))
    finally:
        fs.release()
