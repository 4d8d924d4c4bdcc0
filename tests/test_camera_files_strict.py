"""Camera files are read strictly, by one loader for every command (issue 33, item 8):
integers are integers, booleans are not numbers, numbers are not strings, a key given twice
is refused — each a one-line ValueError naming the file and the key — while valid OpenCV,
ROS camera_info and camera.json files load as before, and `solve` and `replay` accept the
same files."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from adfusion.starid import Camera
from adfusion.starid.camera.files import read_camera, read_camera_yaml, write_camera_yaml

from adfusion.app.cli import main

K = [[500.5, 0.0, 31.5], [0.0, 501.0, 23.5], [0.0, 0.0, 1.0]]
D = [-0.1, 0.01, 0.0, 0.0, 0.0]
CAM = Camera(np.array(K), np.array(D), 64, 48)

OPENCV = ("%YAML:1.0\n---\nimage_width: {w}\nimage_height: 48\n"
          "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
          "   data: [ {fx}, 0., 31.5, 0., 501., 23.5, 0., 0., 1. ]\n"
          "distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n"
          "   dt: d\n   data: [ -1e-1, 1.0e-02, 0., 0., 0. ]\n{extra}")
ROS = ("image_width: {w}\nimage_height: 48\ncamera_name: narrow\ncamera_matrix:\n  rows: 3\n"
       "  cols: 3\n  data: [{fx}, 0, 31.5, 0, 501, 23.5, 0, 0, 1]\n"
       "distortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n"
       "  cols: 5\n  data: [-0.1, 0.01, 0, 0, 0]\n{extra}")


def _json(w="64", fx="500.5", extra=""):
    text = ('{"model": "pinhole", "width": W, "height": 48, "K": [[FX, 0.0, 31.5], '
            '[0.0, 501.0, 23.5], [0.0, 0.0, 1.0]], "D": [-0.1, 0.01, 0.0, 0.0, 0.0], '
            '"parity": 1EXTRA}')
    return text.replace("W", w, 1).replace("FX", fx, 1).replace("EXTRA", extra, 1)


def _yaml(template, w="64", fx="500.5", extra=""):
    return template.format(w=w, fx=fx, extra=extra)


# --- valid files load as they did ----------------------------------------------------------


def test_each_format_loads_to_the_same_camera(tmp_path):
    files = {
        "opencv.yml": _yaml(OPENCV),
        "ros.yaml": _yaml(ROS),
        "camera.json": _json(),
        "pretty.json": json.dumps(CAM.to_dict(), indent=2),
    }
    for name, text in files.items():
        (tmp_path / name).write_text(text)
        assert read_camera(tmp_path / name) == CAM, name
    assert Camera.from_dict(json.loads(files["camera.json"])) == CAM  # replay's attachments
    written = tmp_path / "written.yaml"
    write_camera_yaml(CAM.mirrored(), written, comment="t", rms_px=0.2)  # OpenCV writes it
    assert read_camera(written) == CAM.mirrored() == read_camera_yaml(written)
    (tmp_path / "integral.json").write_text(_json(w="64.0"))
    assert read_camera(tmp_path / "integral.json") == CAM  # 64.0 is the integer 64


# --- each wrong type refused, naming the file and the key ----------------------------------

WRONG = [
    ("cam.json", _json(w="512.7"), "width", "512.7 is not an integer"),
    ("cam.json", _json(w="true"), "width", "boolean, not an integer"),
    ("cam.json", _json(w='"64"'), "width", "string, not an integer"),
    ("cam.json", _json(fx='"500.5"'), "K[0][0]", "string, not a number"),
    ("cam.json", _json(fx="true"), "K[0][0]", "boolean, not a number"),
    ("cam.json", _json(extra=', "width": 64'), "width", "duplicate key"),
    ("cam.json", _json(extra=', "parity ": -1'), "parity ", "unknown key"),
    ("cam.yaml", _yaml(ROS, w="64.5"), "image_width", "64.5 is not an integer"),
    ("cam.yaml", _yaml(ROS, w="true"), "image_width", "boolean, not an integer"),
    ("cam.yaml", _yaml(ROS, w='"64"'), "image_width", "string, not an integer"),
    ("cam.yaml", _yaml(ROS, fx='"500.5"'), "camera_matrix.data[0]", "string, not a number"),
    ("cam.yaml", _yaml(ROS, extra="image_width: 64\n"), "image_width", "duplicate key"),
    ("cam.yml", _yaml(OPENCV, w="64.5"), "image_width", "64.5 is not an integer"),
    ("cam.yml", _yaml(OPENCV, w="true"), "image_width", "boolean, not an integer"),
    ("cam.yml", _yaml(OPENCV, fx='"500.5"'), "camera_matrix.data[0]", "string, not a number"),
    ("cam.yml", _yaml(OPENCV, extra="image_height: 48\n"), "image_height", "duplicate key"),
    ("cam.yml", _yaml(OPENCV, extra="parity: yes\n"), "parity", "boolean, not an integer"),
]


@pytest.mark.parametrize(("name", "text", "key", "why"), WRONG,
                         ids=[f"{n}-{k}-{w}" for n, _, k, w in WRONG])
def test_a_wrong_type_is_refused_naming_file_and_key(tmp_path, name, text, key, why):
    p = tmp_path / name
    p.write_text(text)
    with pytest.raises(ValueError) as info:
        read_camera(p)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{p}: {key}: ") and why in msg, msg


def test_the_example_message(tmp_path):
    p = tmp_path / "cam.json"
    p.write_text(_json(w="512.7"))
    with pytest.raises(ValueError, match=r"cam\.json: width: 512\.7 is not an integer "
                                         r"\(pixels\)$"):
        read_camera(p)


# --- solve and replay: one loader ------------------------------------------------------------


@pytest.fixture
def frames(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    rng = np.random.default_rng(1)
    for k in range(2):
        img = rng.integers(0, 12, (48, 64)).astype(np.uint8)
        cv2.imwrite(str(folder / f"f{k}.png"), img)
    return folder


def _commands(tmp_path, frames, camera):
    return {
        "solve": ["solve", str(frames / "f0.png"), "--camera", str(camera)],
        "replay": ["replay", str(frames), "-o", str(tmp_path / "out.mcap"), "--fps", "10",
                   "--camera", str(camera)],
    }


@pytest.mark.parametrize("name", ["camera.json", "camera.yaml", "ros.yaml"])
def test_solve_and_replay_accept_the_same_camera_files(tmp_path, frames, capsys, name):
    camera = tmp_path / name
    if name == "camera.json":
        camera.write_text(json.dumps(CAM.to_dict()))
    elif name == "camera.yaml":
        write_camera_yaml(CAM, camera)
    else:
        camera.write_text(_yaml(ROS))
    for command, argv in _commands(tmp_path, frames, camera).items():
        code = main(argv)
        err = capsys.readouterr().err
        # may be "not identified" (1), never a refused camera file
        assert code in (0, 1), (command, code, err)
        assert "error" not in err and str(camera) not in err, (command, err)


def test_solve_and_replay_refuse_the_same_bad_file_alike(tmp_path, frames, capsys):
    camera = tmp_path / "camera.json"
    camera.write_text(json.dumps({**CAM.to_dict(), "width": 64.5}))
    for command, argv in _commands(tmp_path, frames, camera).items():
        code = main(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1, (command, code, err)  # unusable input
        assert err[0].endswith(f"--camera {camera}: width: 64.5 is not an integer (pixels)"), (
            command, err)
