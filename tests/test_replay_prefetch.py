"""Frames decoded ahead on a thread (:class:`~adfusion.app.replay.sources.FolderInput`,
:class:`~adfusion.app.replay.sources.VideoInput`): the replay gets every frame the source
decodes, in order, with the same pixels and the same reported damage as reading the source
directly (:mod:`adfusion.logs.sources`, no thread) — more frames than the look-ahead, a
consumer slower than the decoder, a corrupt frame in the middle, a truncated video, an
error raised while decoding, a consumer that stops early."""

from __future__ import annotations

import heapq
import threading
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from adfusion.logs import ImageFolderSource, VideoSource, read_sensor_csv
from adfusion.logs.reader import McapReadWarning

from adfusion.app.replay.sources import FolderInput, VideoInput, _prefetch

W, H = 40, 30
N = 40  # more than the 16 frames decoded ahead: the decoder waits for the replay


def _t(i: int) -> float:
    return 0.031 * i + 0.004 * (i % 3)  # unevenly spaced frame times


def _frame(i: int) -> np.ndarray:
    return np.random.default_rng(i).integers(0, 256, (H, W), dtype=np.uint8)


def _same(got, want) -> None:
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        assert (g.t_s, g.topic) == (w.t_s, w.topic)
        if isinstance(w.payload, np.ndarray):
            assert g.payload.dtype == w.payload.dtype and np.array_equal(g.payload, w.payload)
        else:
            assert g.payload == w.payload


def _slowly(messages):
    """The messages, with a pause after each frame: the decoder runs ahead and blocks."""
    for m in messages:
        yield m
        if m.topic == "/camera/image":
            time.sleep(0.002)


@pytest.fixture
def folder(tmp_path: Path):
    d = tmp_path / "frames"
    d.mkdir()
    times = ["filename,t_s"]
    for i in range(N):
        assert cv2.imwrite(str(d / f"f{i:03d}.png"), _frame(i))
        times.append(f"f{i:03d}.png,{_t(i)!r}")
    data = (d / "f023.png").read_bytes()
    (d / "f023.png").write_bytes(data[: len(data) // 2])  # corrupt, mid-stream
    (tmp_path / "times.csv").write_text("\n".join(times) + "\n")
    imu = ["t_s,gyro_x,gyro_y,gyro_z"] + [f"{0.01 * k!r},0.001,{k * 1e-4!r},0.5"
                                          for k in range(130)]
    (tmp_path / "imu.csv").write_text("\n".join(imu) + "\n")
    return d, tmp_path / "times.csv", tmp_path / "imu.csv"


@pytest.mark.parametrize("slow", [False, True])
def test_folder_frames_come_in_order_with_a_corrupt_one_reported_as_before(folder, slow):
    d, times, imu = folder
    direct = ImageFolderSource(d, timestamps_csv=times)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", McapReadWarning)
        want = list(heapq.merge(read_sensor_csv(imu), direct.frames(), key=lambda m: m.t_s))
        src = FolderInput(d, timestamps=times, imu=imu)
        got = list(_slowly(src) if slow else src)
    _same(got, want)
    frames = [m for m in got if m.topic == "/camera/image"]
    index = {_t(i): i for i in range(N)}
    assert [index[m.t_s] for m in frames] == [i for i in range(N) if i != 23]
    for m in frames:  # each frame is its own file's pixels
        assert np.array_equal(m.payload, _frame(index[m.t_s]))
    assert direct.problems == [f"{d / 'f023.png'}: unreadable image at t = {_t(23)!r} s; "
                               "skipped"]
    assert src.problem == direct.problems[0]


def test_truncated_video_frames_and_damage_as_read_directly(tmp_path: Path):
    path = tmp_path / "flight.mkv"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 30.0, (W, H),
                         isColor=False)
    if not vw.isOpened():
        pytest.skip("this OpenCV build cannot write FFV1")
    for i in range(N):
        vw.write(_frame(i))
    vw.release()
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(path.read_bytes()[: int(path.stat().st_size * 0.6)])
    for video, damaged in ((path, False), (cut, True)):
        direct = VideoSource(video)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", McapReadWarning)
            want = list(direct.frames())
            src = VideoInput(video)
            got = list(_slowly(src))
        _same(got, want)
        if not damaged:  # lossless: the written frames, all of them
            assert len(got) == N and direct.problems == [] and src.problem is None
            assert all(np.array_equal(m.payload, _frame(i)) for i, m in enumerate(got))
        else:
            assert 0 < len(got) < N and len(direct.problems) == 1
            assert src.problem == direct.problems[0] and "broken after frame" in src.problem


def test_an_error_while_decoding_reaches_the_replay_after_the_frames_before_it():
    def frames():
        for i in range(30):
            if i == 20:
                raise OSError("disk gone at frame 20")
            yield i

    got = []
    with pytest.raises(OSError, match="disk gone at frame 20"):
        for m in _prefetch(frames()):  # slower than the decoder: it runs ahead, then fails
            got.append(m)
            time.sleep(0.002)
    assert got == list(range(20))


def test_a_replay_that_stops_early_stops_the_decoder(folder):
    d, times, _ = folder
    src = FolderInput(d, timestamps=times)
    before = set(threading.enumerate())
    it = iter(src)
    first = [next(it) for _ in range(3)]
    assert [m.t_s for m in first] == [_t(0), _t(1), _t(2)]
    decoder = [t for t in threading.enumerate() if t.name == "frame-decode" and t not in before]
    assert len(decoder) == 1
    time.sleep(0.05)  # the decoder fills its look-ahead and waits for room
    it.close()  # what heapq.merge does on a replay that ends here (an error, Ctrl-C)
    decoder[0].join(timeout=5.0)
    assert not decoder[0].is_alive(), "the decode thread outlived its replay"
