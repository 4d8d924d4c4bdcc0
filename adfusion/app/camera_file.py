"""``--camera FILE``: an OpenCV camera YAML (as ``adfusion calibrate -o`` writes it), a ROS
``camera_info`` YAML — all read by :func:`adfusion.starid.camera.files.read_camera` —
or our ``camera.json`` (:meth:`adfusion.starid.camera.model.Camera.to_dict`, the attachment of
our logs). A missing or malformed file is a one-line :class:`ValueError` naming the flag.

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

import os

from adfusion.starid.camera.files import read_camera, write_camera_yaml
from adfusion.starid.camera.model import Camera

__all__ = ["load_camera", "save_camera"]


def load_camera(path: str | os.PathLike[str]) -> Camera:
    """The camera model in ``path``: :func:`adfusion.starid.camera.files.read_camera` (the
    one loader of every command: JSON by content, else YAML, every value type-checked),
    its errors naming the flag."""
    if not os.path.isfile(path):
        raise FileNotFoundError(f"--camera {path}: no such file")
    try:
        return read_camera(path)
    except ValueError as e:  # "FILE: key: what was expected"
        raise ValueError(f"--camera {e}") from None


def save_camera(camera: Camera, path: str | os.PathLike[str]) -> None:
    """Write ``camera`` as OpenCV camera YAML (what ``--camera`` and ``adfusion calibrate``
    share)."""
    write_camera_yaml(camera, path)
