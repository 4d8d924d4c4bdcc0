"""Camera files: OpenCV-style calibration YAML ⇄ :class:`starid.Camera`.

The format is the one OpenCV's own calibration samples write with ``cv::FileStorage``
(``%YAML:1.0``, ``camera_matrix`` and ``distortion_coefficients`` as ``!!opencv-matrix``,
``image_width``/``image_height``), read and written here through OpenCV's
``cv2.FileStorage`` itself, so a file from ``cv2.calibrateCamera`` tooling loads as it
is. ROS ``camera_info`` files (the same keys as ``{rows, cols, data}`` maps) load too.
Two optional keys of ours: ``parity`` (−1 for a mirrored image) and ``model``
(``pinhole``, the OpenCV model, by default). Pixel coordinates are OpenCV's: 0-based
pixel centres, x right, y down (as docs/conventions.md).

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

import os
from pathlib import Path

import numpy as np
from adfusion.starid.camera.model import Camera

__all__ = ["read_camera_yaml", "write_camera_yaml"]


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


def read_camera_yaml(path: str | os.PathLike[str]) -> Camera:
    """Read an OpenCV (or ROS ``camera_info``) calibration YAML into a :class:`Camera`."""
    import cv2

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"camera file not found: {p}")
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):  # SystemError: OpenCV's parser failed (Markdown, empty)
        fs = None
    if fs is None or not fs.isOpened():
        raise ValueError(f"{p}: not a YAML camera file OpenCV can read")
    try:
        w, h = _number(fs, "image_width", p), _number(fs, "image_height", p)
        K = _matrix(fs, "camera_matrix", p)
        if K.shape != (3, 3):
            raise ValueError(f"{p}: camera_matrix must be 3×3, got {K.shape}")
        dnode = fs.getNode("distortion_coefficients")
        D = np.zeros(0) if dnode.empty() else _matrix(fs, "distortion_coefficients", p).ravel()
        model = fs.getNode("model").string() or "pinhole"
        parity_node = fs.getNode("parity")
        parity = 1 if parity_node.empty() else int(parity_node.real())
    finally:
        fs.release()
    try:
        return Camera(K, D, int(w), int(h), model, parity)
    except ValueError as e:
        raise ValueError(f"{p}: {e}") from None


def _number(fs, key: str, p: Path) -> float:
    node = fs.getNode(key)
    if node.empty() or (not node.isReal() and not node.isInt()):
        raise ValueError(f"{p}: missing number {key!r} (an OpenCV camera YAML has "
                         f"image_width, image_height, camera_matrix, distortion_coefficients)")
    return node.real()


def _matrix(fs, key: str, p: Path) -> np.ndarray:
    node = fs.getNode(key)
    if node.empty():
        raise ValueError(f"{p}: missing {key!r}")
    if node.isMap():  # ROS camera_info style: {rows, cols, data: [...]}
        rows, cols = int(node.getNode("rows").real()), int(node.getNode("cols").real())
        data = node.getNode("data")
        vals = [data.at(i).real() for i in range(data.size())]
        if len(vals) != rows * cols:
            raise ValueError(f"{p}: {key} has {len(vals)} values for {rows}×{cols}")
        return np.array(vals, np.float64).reshape(rows, cols)
    m = node.mat()
    if m is None:
        raise ValueError(f"{p}: {key!r} is not a matrix")
    return np.asarray(m, np.float64)
