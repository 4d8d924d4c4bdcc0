"""``--camera FILE``: an OpenCV camera YAML (as ``adfusion calibrate -o`` writes it), a ROS
``camera_info`` YAML — both read by :func:`adfusion.starid.camera.files.read_camera_yaml` —
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

import json
import os

from adfusion.starid.camera.files import read_camera_yaml, write_camera_yaml
from adfusion.starid.camera.model import Camera

__all__ = ["load_camera", "save_camera"]


def load_camera(path: str | os.PathLike[str]) -> Camera:
    """The camera model in ``path`` (JSON by content, else YAML)."""
    if not os.path.isfile(path):
        raise FileNotFoundError(f"--camera {path}: no such file")
    with open(path, encoding="utf-8", errors="replace") as f:
        head = f.read(64).lstrip()
    try:
        if head.startswith("{"):
            with open(path, encoding="utf-8") as f:
                return Camera.from_dict(json.load(f))
        return read_camera_yaml(path)
    except (KeyError, TypeError, ValueError) as e:
        text = str(e) if isinstance(e, ValueError) else f"missing {e}"
        raise ValueError(f"--camera {path}: {text}") from None


def save_camera(camera: Camera, path: str | os.PathLike[str]) -> None:
    """Write ``camera`` as OpenCV camera YAML (what ``--camera`` and ``adfusion calibrate``
    share)."""
    write_camera_yaml(camera, path)
