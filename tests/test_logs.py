"""logs: MCAP writer/reader round trip, damaged files, killed writers, replay sources, and an
independent reader (@mcap/core under node)."""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from adfusion.logs import (
    ImageFolderSource,
    LogWriter,
    McapLogReader,
    McapSource,
    Message,
    VideoSource,
    read_mcap,
    read_sensor_csv,
)
from adfusion.logs.reader import McapReadWarning
from adfusion.logs.schemas import JSON_SCHEMAS
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.records import Message as McapMessage
from mcap.stream_reader import breakup_chunk

REPO = Path(__file__).resolve().parents[1]
FPS = 30.0
W, H = 64, 48

CONFIG = {"scenario": "oedipus", "seed": 7, "duration_s": 2.5, "note": "42", "noise": [1, 2.5]}
CAMERA = {"width": W, "height": H, "K": [[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]],
          "D": [0.01, -0.002, 0, 0, 0]}


def _q(i: int) -> np.ndarray:
    """A unit quaternion, w ≥ 0, different per frame."""
    v = np.array([1.0, 0.1 * i, -0.05 * i, 0.02])
    return v / np.linalg.norm(v)


def _frame(i: int, dtype: type = np.uint8) -> np.ndarray:
    rng = np.random.default_rng(i)
    top = 255 if dtype == np.uint8 else 65535
    return rng.integers(0, top, size=(H, W), dtype=dtype)


def write_full_log(path: Path, n_frames: int = 6, chunk_size: int = 1024 * 1024
                   ) -> list[tuple[float, str, Any]]:
    """Every topic of docs/concepts/log-topics.md; returns what was written as (t_s, topic,
    payload) in write order."""
    written: list[tuple[float, str, Any]] = []
    k = np.array(CAMERA["K"])
    q_body_cam = np.array([0.5, 0.5, 0.5, 0.5])
    with LogWriter(path, chunk_size=chunk_size) as log:
        log.add_metadata("config", CONFIG)
        log.add_camera_model(CAMERA)
        log.write_calibration(0.0, W, H, k, CAMERA["D"], "camera")
        written.append((0.0, "/camera/calibration", (W, H, k, np.array(CAMERA["D"]))))
        for i in range(n_frames):
            t = i / FPS
            for j in range(4):  # gyro at 4x the frame rate, written before the frame
                tg = t + j / (4 * FPS)
                p = {"omega": [0.01 * i, -0.02, 0.3 + j]}
                log.write_json("/imu/gyro", tg, p)
                written.append((tg, "/imu/gyro", p))
            p = {"b_body": [2.0e4 + i, -1.5e3, -4.1e4]}
            log.write_json("/mag", t, p)
            written.append((t, "/mag", p))
            img = _frame(i)
            log.write_image(t, img)
            written.append((t, "/camera/image", img))
            img16 = _frame(i, np.uint16)
            log.write_image(t, img16, topic="/camera/image16")
            written.append((t, "/camera/image16", img16))
            log.write_image(t, img, topic="/camera/image_png", png=True)
            written.append((t, "/camera/image_png", img))
            det = np.array([[10.25, 12.5], [30.0, 40.125], [5.5, 6.75]]) + i
            ident = [(10.25 + i, 12.5 + i, f"HIP {1000 + i}"), (30.0 + i, 40.125 + i, "HIP 7")]
            pred = np.array([[11.0, 13.0], [50.0, 20.0]])
            occ = [np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 47.0]])]
            log.write_annotations(t, det, ident, pred, occ)
            written.append((t, "/camera/annotations", (det, ident, pred, occ)))
            sol = {"ok": i % 3 != 2, "mode": "tracking" if i else "lost-in-space",
                   "q_cam_icrs": _q(i).tolist() if i % 3 != 2 else None,
                   "matches": [[0, 1000 + i], [1, 7]], "matching_counter": 1,
                   "cone_deg": 2.0 if i else None, "reason": "" if i % 3 != 2 else "ambiguous",
                   "time_ms": 1.25}
            log.write_json("/starid/solution", t, sol)
            written.append((t, "/starid/solution", sol))
            state = {"t": t, "q_body_icrs": _q(i).tolist(), "bias": [1e-5, 0.0, -2e-5],
                     "cov_diag": [1e-6] * 3 + [1e-10] * 3, "nis": 1.5 if i else None}
            log.write_json("/estimate/state", t, state)
            written.append((t, "/estimate/state", state))
            log.write_json("/smoothed/state", t, state)
            written.append((t, "/smoothed/state", state))
            truth = {"t": t, "q_body_icrs": _q(i + 1).tolist(), "omega": [0.0, 0.0, 1.0]}
            log.write_json("/truth/state", t, truth)
            written.append((t, "/truth/state", truth))
            att = {"t": t, "ra_deg": 10.0 * i, "dec_deg": -5.0, "roll_deg": 270.0,
                   "sigma_deg": [1e-3, 1e-3, 5e-3], "mode": "tracking", "n_stars": 7}
            log.write_json("/estimate/attitude", t, att)
            written.append((t, "/estimate/attitude", att))
            err = {"t": t, "error_deg": [1e-3, -2e-3, 4e-3], "angle_deg": 4.6e-3,
                   "sigma3_deg": [3e-3, 3e-3, 1.5e-2]}
            log.write_json("/estimate/error", t, err)
            written.append((t, "/estimate/error", err))
            cen = {"t": t, "xy": [[10.5, 20.25], [30.0, 40.0]]}
            log.write_json("/camera/centroids", t, cen)
            written.append((t, "/camera/centroids", cen))
            live = {"t": t, "latency_ms": 12.5, "frames": i + 1, "dropped": 0}
            log.write_json("/live/status", t, live)
            written.append((t, "/live/status", live))
            log.write_attitude("/estimate/pose", t, _q(i))
            q_icrs_body = _q(i) * np.array([1, -1, -1, -1])
            written.append((t, "/estimate/pose", q_icrs_body))
            log.write_pose("/truth/pose", t, _q(i + 1))
            written.append((t, "/truth/pose", _q(i + 1)))
            tfs = [("icrs", "body", q_icrs_body, [0.0, 0.0, 0.0]),
                   ("icrs", "body_truth", _q(i + 1), [0.0, 0.0, 0.0]),
                   ("body", "camera", q_body_cam, [0.1, 0.0, 0.2])]
            log.write_tf(t, tfs)
            written.append((t, "/tf", tfs))
    return written


def _check_payload(topic: str, got: Any, want: Any) -> None:
    if topic in ("/camera/image", "/camera/image16", "/camera/image_png"):
        assert got.dtype == want.dtype and np.array_equal(got, want)
    elif topic == "/camera/calibration":
        w, h, k, d = want
        assert (got["width"], got["height"], got["frame_id"]) == (w, h, "camera")
        assert np.array_equal(got["K"], k) and np.array_equal(got["D"], d)
        assert got["distortion_model"] == "plumb_bob"
        assert np.array_equal(got["P"][:, :3], k)
    elif topic == "/camera/annotations":
        det, ident, pred, occ = want
        assert np.array_equal(got["detections_xy"], det)
        assert got["identified"] == ident
        assert np.array_equal(got["predicted_xy"], pred)
        assert len(got["occupied"]) == 1 and np.array_equal(got["occupied"][0], occ[0])
        assert got["points"] == [] and got["circles"] == [] and got["texts"] == []
    elif topic in ("/estimate/pose", "/truth/pose"):
        assert got["frame_id"] == "icrs"
        assert np.array_equal(got["q_wxyz"], want) and np.array_equal(got["position"], 0 * want[:3])
    elif topic == "/tf":
        assert len(got["transforms"]) == len(want)
        for g, (parent, child, q, tr) in zip(got["transforms"], want, strict=True):
            assert (g["parent"], g["child"]) == (parent, child)
            assert np.array_equal(g["q_wxyz"], q) and np.array_equal(g["translation"], tr)
    else:
        assert got == want, topic


def _key(item: tuple[float, str, Any]) -> tuple[int, str]:
    return round(item[0] * 1e9), item[1]


# --------------------------------------------------------------------------- round trip
def test_round_trip_every_topic(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    written = write_full_log(path)
    reader = McapLogReader(path)
    assert reader.problem is None
    got = list(reader)
    assert all(isinstance(m, Message) for m in got)
    assert len(got) == len(written) == reader.message_count
    times = [m.t_s for m in got]
    assert times == sorted(times)
    # match by (time, topic): several topics share a timestamp
    expect: dict[tuple[int, str], list[Any]] = {}
    for item in written:
        expect.setdefault(_key(item), []).append(item[2])
    for m in got:
        _check_payload(m.topic, m.payload, expect[_key((m.t_s, m.topic, None))].pop(0))
    assert all(not v for v in expect.values())
    assert {c.topic for c in reader.channels.values()} == {t for _, t, _ in written}
    assert reader.metadata == {"config": CONFIG}
    assert reader.camera_model() == CAMERA
    assert reader.attachments["camera.json"][0] == "application/json"


def test_times_are_integer_nanoseconds_and_schemas_named(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_full_log(path, n_frames=2)
    with open(path, "rb") as f:
        r = make_reader(f)
        summary = r.get_summary()
        assert summary is not None and summary.chunk_indexes
        assert all(ci.compression == "zstd" for ci in summary.chunk_indexes)
        log_times = {m.log_time for _, _, m in r.iter_messages()}
        names = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert round(1 / FPS * 1e9) in log_times
    assert names["/camera/image"] == "foxglove.RawImage"
    assert names["/camera/image_png"] == "foxglove.CompressedImage"
    assert names["/camera/annotations"] == "foxglove.ImageAnnotations"
    assert names["/estimate/pose"] == "foxglove.PoseInFrame"
    assert names["/tf"] == "foxglove.FrameTransforms"
    assert names["/camera/calibration"] == "foxglove.CameraCalibration"
    for topic, (schema_name, _) in JSON_SCHEMAS.items():
        assert names[topic] == schema_name


def test_out_of_order_writes_come_back_sorted(tmp_path: Path) -> None:
    path = tmp_path / "late.mcap"
    with LogWriter(path, chunk_size=256) as log:
        for i in range(10):
            log.write_json("/mag", 1.0 + i, {"b_body": [i, 0, 0]})
        for i in range(10):  # a late batch, earlier in time, in later chunks
            log.write_json("/imu/gyro", 0.5 + i, {"omega": [i, 0, 0]})
    got = [m.t_s for m in read_mcap(path)]
    assert got == sorted(got) and len(got) == 20


def test_non_finite_json_becomes_null_and_validates(tmp_path: Path) -> None:
    jsonschema = pytest.importorskip("jsonschema")
    path = tmp_path / "nan.mcap"
    state = {"t": 0.0, "q_body_icrs": np.array([1.0, 0, 0, 0]), "bias": np.zeros(3),
             "cov_diag": np.array([np.inf, 1, 1, 1, 1, 1.0]), "nis": float("nan")}
    with LogWriter(path) as log:
        log.write_json("/estimate/state", 0.0, state)
    (m,) = list(read_mcap(path))
    assert m.payload["nis"] is None and m.payload["cov_diag"][0] is None
    jsonschema.Draft202012Validator(JSON_SCHEMAS["/estimate/state"][1]).validate(m.payload)


def test_topic_map_for_foreign_logs(tmp_path: Path) -> None:
    path = tmp_path / "theirs.mcap"
    with LogWriter(path) as log:
        log.write_image(0.0, _frame(0), topic="/cam0/image_raw")
        log.write_json("/imu/data", 0.001, {"omega": [0.0, 0.0, 0.5]})
        log.write_json("/diagnostics", 0.002, {"cpu": 0.5})
    got = list(read_mcap(path, topic_map={"/camera/image": "/cam0/image_raw",
                                          "/imu/gyro": "/imu/data"}))
    assert [m.topic for m in got] == ["/camera/image", "/imu/gyro"]
    assert np.array_equal(got[0].payload, _frame(0))
    assert [m.topic for m in read_mcap(path)] == ["/cam0/image_raw", "/imu/data", "/diagnostics"]


def test_other_protobuf_types_decode_to_dicts(tmp_path: Path) -> None:
    from foxglove_schemas_protobuf.Log_pb2 import Log
    from mcap_protobuf.writer import Writer

    path = tmp_path / "log.mcap"
    with open(path, "wb") as f, Writer(f) as w:
        w.write_message("/rosout", Log(message="hello", name="node"), log_time=5, publish_time=5)
    (m,) = list(read_mcap(path))
    assert (m.t_s, m.topic) == (5e-9, "/rosout")
    assert m.payload["message"] == "hello" and m.payload["name"] == "node"


# --------------------------------------------------------------------------- damage
def _chunks(path: Path) -> list[tuple[int, int, int]]:
    """(start offset, end offset, message count) of every chunk, via mcap's own summary."""
    out = []
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        for ci in summary.chunk_indexes:
            f.seek(ci.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(io.BytesIO(f.read(ci.chunk_length - 9))))
            n = sum(isinstance(r, McapMessage) for r in breakup_chunk(chunk))
            out.append((ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length, n))
    return out


def test_truncated_file_reads_up_to_last_complete_chunk(tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    write_full_log(path, n_frames=12, chunk_size=16 * 1024)
    data = path.read_bytes()
    chunks = _chunks(path)
    assert len(chunks) >= 6
    total = sum(n for _, _, n in chunks)
    assert total == McapLogReader(path).message_count
    cuts = [20, chunks[0][0] + 5, chunks[2][0] + 100, chunks[3][1], chunks[-1][1] - 1,
            chunks[-1][1] + 3, len(data) - 10]
    for cut in cuts:
        broken = tmp_path / f"cut{cut}.mcap"
        broken.write_bytes(data[:cut])
        with pytest.warns(McapReadWarning, match=r"broken at byte \d+ of " + str(cut)):
            reader = McapLogReader(broken)
        complete = [(s, e, n) for s, e, n in chunks if e <= cut]
        want = sum(n for _, _, n in complete)
        msgs = list(reader)
        assert len(msgs) == want == reader.message_count, cut
        problem = reader.problem
        assert problem is not None and problem.file_size == cut
        assert problem.good_chunks == len(complete)
        assert problem.offset <= cut
        if complete:
            assert problem.offset >= complete[-1][1]
            assert problem.last_good_t_s == max(m.t_s for m in msgs)
            assert f"t = {problem.last_good_t_s:.6f} s" in str(problem)
        else:
            assert problem.last_good_t_s is None
        times = [m.t_s for m in msgs]
        assert times == sorted(times)
        if cut >= chunks[0][1] and reader.camera_model() is not None:
            assert reader.metadata["config"] == CONFIG


KILLED_WRITER = """
import sys
import numpy as np
from adfusion.logs import LogWriter
log = LogWriter(sys.argv[1], chunk_size=100_000)
log.add_metadata("config", {"run": "killed"})
i = 0
while True:
    img = np.full((480, 512), i % 256, np.uint8)
    log.write_image(i / 30, img)
    log.write_json("/estimate/state", i / 30, {"t": i / 30, "q_body_icrs": [1, 0, 0, 0],
                   "bias": [0, 0, 0], "cov_diag": [0] * 6, "nis": float(i)})
    if i == 40:
        print("ready", flush=True)
    i += 1
"""


def test_writer_killed_by_sigkill_leaves_readable_file(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(path)], cwd=tmp_path,
                            env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
        time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        if proc.stdout is not None:
            proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    with pytest.warns(McapReadWarning, match="broken at byte"):
        reader = McapLogReader(path)
    assert reader.metadata == {"config": {"run": "killed"}}
    msgs = list(reader)
    frames = [m for m in msgs if m.topic == "/camera/image"]
    states = [m for m in msgs if m.topic == "/estimate/state"]
    assert len(frames) >= 40 - 1  # at most the chunk in progress (< 1 frame here) is lost
    for k, m in enumerate(frames):
        assert m.t_s == pytest.approx(k / 30, abs=1e-9)
        assert m.payload.shape == (480, 512) and int(m.payload[0, 0]) == k % 256
    assert len(frames) - 1 <= len(states) <= len(frames)  # a frame's state may be in the lost chunk
    assert [s.payload["nis"] for s in states] == list(range(len(states)))


# --------------------------------------------------------------------------- other sources
def _write_sensor_csv(path: Path, bad_line: bool = False) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t_s", "gyro_x", "gyro_y", "gyro_z", "mag_x", "mag_y", "mag_z"])
        for k in range(20):
            t = k * 0.01
            mag = [2e4, 0.0, -4e4 + k] if k % 5 == 0 else ["", "", ""]
            w.writerow([t, 0.001 * k, 0.0, 0.5, *mag])
            if bad_line and k == 9:
                f.write("0.095,abc,0,0,,,\n")


def test_image_folder_with_csvs(tmp_path: Path) -> None:
    folder = tmp_path / "frames"
    folder.mkdir()
    names = [f"img_{i:03d}.png" for i in range(4)]
    for i, name in enumerate(names):
        assert cv2.imwrite(str(folder / name), _frame(i))
    cv2.imwrite(str(folder / "img_004.tif"), _frame(4, np.uint16))
    (folder / "notes.txt").write_text("not an image")
    stamps = tmp_path / "frames.csv"
    stamps.write_text("filename,t_s\n" + "".join(
        f"{n},{0.05 * i + 0.001}\n" for i, n in enumerate([*names, "img_004.tif"])))
    sensors = tmp_path / "imu.csv"
    _write_sensor_csv(sensors)
    src = ImageFolderSource(folder, timestamps_csv=stamps, sensors_csv=sensors)
    msgs = list(src)
    assert src.problems == []
    times = [m.t_s for m in msgs]
    assert times == sorted(times)
    imgs = [m for m in msgs if m.topic == "/camera/image"]
    assert [m.t_s for m in imgs] == pytest.approx([0.05 * i + 0.001 for i in range(5)])
    for i, m in enumerate(imgs[:4]):
        assert np.array_equal(m.payload, _frame(i))
    assert imgs[4].payload.dtype == np.uint16 and np.array_equal(imgs[4].payload,
                                                                  _frame(4, np.uint16))
    gyro = [m for m in msgs if m.topic == "/imu/gyro"]
    mag = [m for m in msgs if m.topic == "/mag"]
    assert len(gyro) == 20 and len(mag) == 4
    assert gyro[3].payload == {"omega": [0.003, 0.0, 0.5]}
    assert mag[1] == Message(0.05, "/mag", {"b_body": [2e4, 0.0, -4e4 + 5]})
    fixed = list(ImageFolderSource(folder, fps=10.0, t0_s=2.0))
    assert [m.t_s for m in fixed] == pytest.approx([2.0, 2.1, 2.2, 2.3, 2.4])


def test_broken_csv_and_image_are_reported(tmp_path: Path) -> None:
    sensors = tmp_path / "imu.csv"
    _write_sensor_csv(sensors, bad_line=True)
    problems: list[str] = []
    with pytest.warns(McapReadWarning, match=r"broken at line 12 .*12 samples read "
                      r"\(t = 0–0.09 s\), 10 line\(s\) after it not read"):
        msgs = read_sensor_csv(sensors, problems)
    assert len([m for m in msgs if m.topic == "/imu/gyro"]) == 10 and len(problems) == 1
    folder = tmp_path / "frames"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), _frame(0))
    (folder / "b.png").write_bytes(b"\x89PNG truncated")
    cv2.imwrite(str(folder / "c.png"), _frame(2))
    src = ImageFolderSource(folder, fps=1.0)
    with pytest.warns(McapReadWarning, match=r"b\.png: unreadable image at t = 1.0 s"):
        msgs = list(src)
    assert [m.t_s for m in msgs] == [0.0, 2.0]


@pytest.mark.opencv
def test_video_source(tmp_path: Path) -> None:
    path = tmp_path / "flight.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (W, H))
    if not vw.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG/avi")
    levels = [20 * i + 10 for i in range(10)]
    for level in levels:
        img = np.full((H, W, 3), level, np.uint8)
        img[10:20, 10:20] = 255
        vw.write(img)
    vw.release()
    sensors = tmp_path / "imu.csv"
    _write_sensor_csv(sensors)
    src = VideoSource(path, fps=30.0, t0_s=1.0)
    frames = list(src.frames())
    assert src.problems == []
    assert len(frames) == 10
    assert [m.t_s for m in frames] == pytest.approx([1.0 + i / 30 for i in range(10)])
    for m, level in zip(frames, levels, strict=True):
        assert m.topic == "/camera/image" and m.payload.dtype == np.uint8
        assert m.payload.shape == (H, W)
        assert abs(float(np.median(m.payload)) - level) <= 3
        assert m.payload[15, 15] >= 240
    assert VideoSource(path).fps == pytest.approx(25.0)  # the container's rate
    merged = list(VideoSource(path, fps=30.0, sensors_csv=sensors))
    assert len(merged) == 10 + 24 and [m.t_s for m in merged] == sorted(m.t_s for m in merged)


def test_grey_video_is_read_as_decoded_and_colour_video_as_before(tmp_path: Path) -> None:
    """A grey 8-bit stream (FFV1 of a star camera) is read without OpenCV's grey → BGR
    conversion and gives the written pixels exactly; a colour/YUV stream keeps the
    conversion (its luma plane is not what BGR → grey gives, so the frames stay those of
    earlier replays)."""
    from adfusion.logs.sources import _open_video

    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 256, (H, W), dtype=np.uint8) for _ in range(4)]
    grey = tmp_path / "grey.mkv"
    vw = cv2.VideoWriter(str(grey), cv2.VideoWriter_fourcc(*"FFV1"), 30.0, (W, H),
                         isColor=False)
    if not vw.isOpened():
        pytest.skip("this OpenCV build cannot write FFV1")
    for f in frames:
        vw.write(f)
    vw.release()
    cap = _open_video(str(grey))
    assert cap.get(cv2.CAP_PROP_CONVERT_RGB) == 0  # read as decoded
    cap.release()
    got = [m.payload for m in VideoSource(grey, fps=30.0).frames()]
    assert len(got) == 4 and all(np.array_equal(a, b) for a, b in zip(got, frames, strict=True))

    colour = tmp_path / "colour.avi"
    vw = cv2.VideoWriter(str(colour), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (W, H))
    if not vw.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG/avi")
    for f in frames:
        vw.write(cv2.merge([f, f // 2, 255 - f]))
    vw.release()
    cap = _open_video(str(colour))
    assert cap.get(cv2.CAP_PROP_CONVERT_RGB) != 0
    cap.release()
    plain = cv2.VideoCapture(str(colour))  # the reference: OpenCV's BGR, then BGR → grey
    want = []
    while (read := plain.read())[0]:
        want.append(cv2.cvtColor(read[1], cv2.COLOR_BGR2GRAY))
    got = [m.payload for m in VideoSource(colour, fps=30.0).frames()]
    assert len(got) == len(want) == 4
    assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True))


# --------------------------------------------------------------------------- independent reader
NODE_CACHE = Path(os.environ.get("ADFUSION_NODE_CACHE",
                                 Path.home() / ".cache" / "adfusion" / "node-mcap"))
NODE_PACKAGES = ["@mcap/core@2", "fzstd@0.1", "lz4js@0.2"]


def _node_mcap() -> Path:
    """Cache dir holding node_modules/@mcap/core (installed on first use); skips without it."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("node/npm not on PATH")
    if not all((NODE_CACHE / "node_modules" / p.rsplit("@", 1)[0]).is_dir()
               for p in NODE_PACKAGES):
        NODE_CACHE.mkdir(parents=True, exist_ok=True)
        pkg = NODE_CACHE / "package.json"
        if not pkg.exists():
            pkg.write_text('{"name": "adfusion-node-mcap", "private": true}\n')
        try:
            subprocess.run([npm, "install", "--no-audit", "--no-fund", *NODE_PACKAGES],
                           cwd=NODE_CACHE, check=True, capture_output=True, timeout=240)
        except (subprocess.SubprocessError, OSError) as exc:
            pytest.skip(f"npm install of {NODE_PACKAGES} failed: {exc}")
    return NODE_CACHE


def test_independent_typescript_reader(tmp_path: Path) -> None:
    jsonschema = pytest.importorskip("jsonschema")
    from google.protobuf.descriptor_pb2 import FileDescriptorSet

    cache = _node_mcap()
    path = tmp_path / "run.mcap"
    written = write_full_log(path, n_frames=8, chunk_size=32 * 1024)
    out = subprocess.run(["node", str(REPO / "tests" / "node" / "read_mcap.cjs"), str(cache),
                          str(path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)

    ours: dict[str, int] = {}
    for m in McapLogReader(path):
        ours[m.topic] = ours.get(m.topic, 0) + 1
    want = {}
    for _, topic, _ in written:
        want[topic] = want.get(topic, 0) + 1
    assert report["counts"] == ours == want
    assert report["statisticsMessageCount"] == len(written)
    assert report["ordered"]
    config, digests = report["metadata"]
    assert config == {"name": "config", "metadata": {
        "scenario": "oedipus", "seed": "7", "duration_s": "2.5", "note": '"42"',
        "noise": "[1,2.5]"}}
    # the digests record (written at close): SHA-256 of the config's sorted string map,
    # recomputed here from what the independent reader returned
    import hashlib

    config_sha = hashlib.sha256(json.dumps(config["metadata"], sort_keys=True,
                                           separators=(",", ":")).encode()).hexdigest()
    assert digests["name"] == "digests"
    assert digests["metadata"]["metadata:config"] == config_sha
    assert set(digests["metadata"]) == {"metadata:config", "attachment:camera.json"}
    assert report["attachments"] == [{"name": "camera.json", "mediaType": "application/json",
                                      "size": len(json.dumps(CAMERA, separators=(",", ":")))}]

    for ch in report["channels"]:
        name, enc = ch["schemaName"], ch["schemaEncoding"]
        if name.startswith("foxglove."):
            assert enc == "protobuf" and ch["messageEncoding"] == "protobuf"
            fds = FileDescriptorSet.FromString(__import__("base64").b64decode(ch["schemaData"]))
            types = {f"{fd.package}.{m.name}" for fd in fds.file for m in fd.message_type}
            assert name in types, name
        else:
            assert enc == "jsonschema" and ch["messageEncoding"] == "json", ch["topic"]
            schema = json.loads(ch["schemaData"])
            jsonschema.Draft202012Validator.check_schema(schema)
            validator = jsonschema.Draft202012Validator(schema)
            texts = report["jsonMessages"][ch["topic"]]
            assert len(texts) == want[ch["topic"]]
            for text in texts:
                validator.validate(json.loads(text))


def test_no_warning_for_intact_file(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_full_log(path, n_frames=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(list(McapSource(path))) == McapLogReader(path).message_count


@pytest.mark.parametrize("case", range(5))
def test_annotation_bytes_parse_to_the_message_built_object_by_object(case):
    from adfusion.logs import foxglove as fg
    from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations

    rng = np.random.default_rng(case)
    det = rng.uniform(-1.0, 600.0, (int(rng.integers(0, 40)), 2))
    det[:2] = 0.0  # zeros are omitted by the protobuf library, written explicitly here
    ident = [(float(x), float(y), f"HIP {i}") for i, (x, y) in enumerate(det[::3])]
    ident.append((-0.0, 1e-300, 12345))  # labels are str()-ed; an int, a non-ASCII text:
    ident.append((3.5, 2.25, "étoile"))
    args = [(case * 10**9 + 123, det, ident, rng.uniform(0, 500, (7, 2)), [det[:4]]),
            (0, None, (), None, ()),
            (2**40, np.zeros((0, 2)), [], np.zeros((0, 2)), []),
            (5, det, (), None, [det[:3], det[3:9]]),
            # layers longer than the varint table (2¹¹ bytes: ≥ 103 points)
            (7, rng.uniform(0, 500, (300, 2)), ident, rng.uniform(0, 500, (120, 2)), [])][case]
    data = fg.encode_annotations_bytes(*args)
    assert ImageAnnotations.FromString(data) == fg._encode_annotations_by_objects(*args)
    assert fg.encode_annotations(*args) == fg._encode_annotations_by_objects(*args)


def test_protobuf_bytes_are_written_as_given_and_raw_frames_read_back(tmp_path):
    from adfusion.logs import foxglove as fg

    path = tmp_path / "copy.mcap"
    img = _frame(3)
    data = fg.encode_raw_image(2_000_000_000, img, "camera").SerializeToString()
    with LogWriter(path) as log:
        log.write_protobuf_bytes("/camera/image", 2.0, "foxglove.RawImage", data)
        log.write_image(3.0, img)
        with pytest.raises(ValueError, match="unknown Foxglove schema"):
            log.write_protobuf_bytes("/x", 1.0, "foxglove.Nope", data)
    got = list(McapLogReader(path))
    assert [m.raw for m in got] == [data, fg.encode_raw_image(3_000_000_000, img,
                                                              "camera").SerializeToString()]
    assert all(np.array_equal(m.payload, img) for m in got)


def test_json_dumps_equals_the_converted_copy():
    # dumps skips to_jsonable's copy unless a non-finite float needs it: the text is the same
    import json

    from adfusion.logs.jsonio import dumps, to_jsonable

    rng = np.random.default_rng(3)
    cases = [
        {"q": rng.normal(size=4), "n": np.int64(7), "f32": np.float32(0.1), "ok": np.bool_(True)},
        {"m": [[1, 2], (3, 4)], "x": None, "s": "étoile", "t": 0.1, 3: "int key"},
        {"nis": float("nan"), "cov": np.array([1.0, np.inf, 2.0]), "e": np.float64(-np.inf)},
        [np.arange(3), {"deep": [np.float64(1e-300), np.uint8(255)]}],
    ]
    for value in cases:
        slow = json.dumps(to_jsonable(value), separators=(",", ":"), allow_nan=False)
        assert dumps(value) == slow
    assert json.loads(dumps(cases[2])) == {"nis": None, "cov": [1.0, None, 2.0], "e": None}
    with pytest.raises(TypeError, match="cannot write object"):
        dumps({"o": object()})


def _mixed_log(path: Path, compression: str) -> None:
    with LogWriter(path, chunk_size=3000, compression=compression) as log:
        for t in (2.0, 0.5, 3.0, 0.1, 0.1):  # times out of order: chunk and file time bounds
            log.write_json("/imu/gyro", t, {"omega": [t, 0.0, 0.0]})
            log.write_image(t, _frame(int(10 * t)))
            log.write_annotations(t, [[1.0, 2.0]], [(1.0, 2.0, "HIP 7")])
        log.flush()  # a chunk ended by hand, then an empty one
        log.flush()
        log.write_image(4.0, _frame(4, np.uint16))


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_messages_are_written_as_the_mcap_library_writes_them(tmp_path, monkeypatch,
                                                              compression):
    """LogWriter appends messages to the chunk itself (one pack, frames straight from the
    array) and writes each chunk's data to the file without copying it into a record
    first; the file is byte for byte the one mcap's own ``Writer`` writes — small chunks,
    so that many end mid-run, with out-of-order times, every topic, each compression."""
    import adfusion.logs.writer as writer

    fast, stock = tmp_path / "fast.mcap", tmp_path / "stock.mcap"
    with LogWriter(tmp_path / "probe.mcap") as probe:
        assert probe._appender is not None  # the fast path is in use (mcap as expected)
    if compression == "zstd":
        write_full_log(fast, n_frames=5, chunk_size=3000)
    _mixed_log(fast.with_suffix(".mixed.mcap"), compression)
    monkeypatch.setattr(writer._MessageAppender, "of", classmethod(lambda cls, w: None))
    with LogWriter(tmp_path / "probe2.mcap") as probe:
        assert probe._appender is None
    if compression == "zstd":
        write_full_log(stock, n_frames=5, chunk_size=3000)
        assert fast.read_bytes() == stock.read_bytes()
    _mixed_log(stock.with_suffix(".mixed.mcap"), compression)
    mixed = fast.with_suffix(".mixed.mcap")
    assert mixed.read_bytes() == stock.with_suffix(".mixed.mcap").read_bytes()
    times = [m.t_s for m in McapLogReader(mixed) if m.topic == "/camera/image"]
    assert times == [0.1, 0.1, 0.5, 2.0, 3.0, 4.0]


@pytest.mark.parametrize("case", ["mono8", "mono16", "bgr8", "strided", "transposed",
                                  "empty", "tall", "no frame id"])
def test_raw_image_parts_are_the_protobuf_librarys_bytes(case):
    from adfusion.logs import foxglove as fg

    rng = np.random.default_rng(7)
    img = {"mono8": rng.integers(0, 256, (48, 64), dtype=np.uint8),
           "mono16": rng.integers(0, 65536, (48, 64), dtype=np.uint16),
           "bgr8": rng.integers(0, 256, (9, 7, 3), dtype=np.uint8),
           "strided": rng.integers(0, 256, (20, 30), dtype=np.uint8)[:, 3::2],
           "transposed": rng.integers(0, 256, (20, 30), dtype=np.uint8).T,
           "empty": np.zeros((0, 5), np.uint8),
           "tall": rng.integers(0, 256, (70000, 3), dtype=np.uint8),
           "no frame id": rng.integers(0, 256, (4, 4), dtype=np.uint8)}[case]
    frame_id = "" if case == "no frame id" else "camera2"
    for t_ns in (0, 999_999_999, 1_700_000_000_123_456_789):
        parts = fg.encode_raw_image_parts(t_ns, img, frame_id)
        want = fg.encode_raw_image(t_ns, img, frame_id).SerializeToString()
        assert b"".join(parts) == want
        assert np.array_equal(fg.decode("foxglove.RawImage", b"".join(parts)), img)
