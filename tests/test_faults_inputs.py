"""Unchecked inputs (issue 16, item 14): every one is refused with a message naming what is
wrong, or reported as a problem — never taken as a number it is not."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from adfusion.logs import ImageFolderSource, VideoSource, read_sensor_csv
from adfusion.logs.reader import McapReadWarning
from adfusion.starid.solver import Prior

from adfusion.estimation.estimator import Estimator
from adfusion.estimation.mekf import MEKF

HEADER = "t_s,gyro_x,gyro_y,gyro_z\n"


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf", "a"])
@pytest.mark.parametrize("column", ["t_s", "gyro_y"])
def test_csv_non_finite_or_non_numeric_cells_stop_the_reading_there(tmp_path, bad, column):
    rows = [[0.00, 0.1, 0.0, 0.0], [0.01, 0.1, 0.0, 0.0], [0.02, 0.1, 0.0, 0.0]]
    cells = [[str(v) for v in r] for r in rows]
    cells[1][0 if column == "t_s" else 2] = bad
    path = tmp_path / "imu.csv"
    path.write_text(HEADER + "".join(",".join(r) + "\n" for r in cells))
    problems: list[str] = []
    with pytest.warns(McapReadWarning, match=rf"broken at line 3 \({column}: '{bad}'"):
        msgs = read_sensor_csv(path, problems)
    assert [m.t_s for m in msgs] == [0.0] and len(problems) == 1
    assert all(math.isfinite(v) for m in msgs for v in m.payload["omega"])


def test_non_utf8_csv_is_a_message_not_a_decode_error(tmp_path):
    path = tmp_path / "imu.csv"
    path.write_bytes(HEADER.encode() + b"0.0,0.1,0,0\n0.01,\xff\xfe,0,0\n")
    with pytest.raises(ValueError, match=r"imu\.csv: not UTF-8 text"):
        read_sensor_csv(path)


def test_timestamps_csv_without_t_s_names_the_columns(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), np.zeros((4, 4), np.uint8))
    stamps = tmp_path / "stamps.csv"
    stamps.write_text("filename,time\na.png,0.0\n")
    with pytest.raises(ValueError, match=r"'filename' and 't_s'"):
        ImageFolderSource(folder, timestamps_csv=stamps)
    stamps.write_text("filename,t_s\na.png,nan\n")
    with pytest.raises(ValueError, match=r"line 2: t_s: 'nan' is not a finite number"):
        ImageFolderSource(folder, timestamps_csv=stamps)


@pytest.mark.parametrize("fps", [math.nan, math.inf, -1.0, 0.0])
def test_frame_rates_must_be_finite_and_positive(tmp_path, fps):
    folder = tmp_path / "frames"
    folder.mkdir()
    cv2.imwrite(str(folder / "a.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match="fps"):
        ImageFolderSource(folder, fps=fps)
    video = tmp_path / "v.avi"
    vw = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (16, 16))
    if not vw.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG/avi")
    for _ in range(3):
        vw.write(np.zeros((16, 16, 3), np.uint8))
    vw.release()
    with pytest.raises(ValueError, match="fps"):
        VideoSource(video, fps=fps)


@pytest.mark.parametrize("k", [-1.0, 0.0, math.nan, math.inf])
def test_prior_k_is_checked(k):
    with pytest.raises(ValueError, match=r"Prior\.k"):
        Prior([1.0, 0.0, 0.0, 0.0], 0.1, k=k)


@pytest.mark.parametrize("k", [-1.0, math.nan])
def test_search_cone_with_negative_k_is_refused(k):
    f = MEKF([1.0, 0.0, 0.0, 0.0], 1e-3, 1e-5, 1e-6, 1e-8)
    with pytest.raises(ValueError, match="k"):
        f.search_cone_deg(k=k)


def test_negative_exposure_is_refused():
    from adfusion.sensors import scenarios

    with pytest.raises(ValueError, match="exposure_s"):
        scenarios.oedipus(duration_s=1.0, render=False, exposure_s=-0.01)
    with pytest.raises(ValueError, match="exposure_s"):
        Estimator(None, exposure_s=-1.0)
    est = Estimator(None, q_body_icrs0=[1.0, 0.0, 0.0, 0.0])
    rec = est.step(0.0, detections=np.zeros((3, 2)), exposure_s=-0.1)
    assert any("exposure_s" in why for _, why in rec.rejected)


@pytest.mark.parametrize("gyro", [["a", 0.0, 0.0], {"x": 1}, "fast", [1.0, 2.0]])
def test_step_names_the_input_it_cannot_read(gyro):
    est = Estimator(None, q_body_icrs0=[1.0, 0.0, 0.0, 0.0])
    rec = est.step(0.0, gyro=gyro)
    assert [src for src, _ in rec.rejected] == ["gyro"]
    rec = est.step("soon", gyro=[0.0, 0.0, 0.0])
    assert [src for src, _ in rec.rejected] == ["time"]


def test_folder_that_is_not_one(tmp_path):
    f = tmp_path / "x.png"
    f.write_bytes(b"")
    with pytest.raises(ValueError, match="not a folder"):
        ImageFolderSource(f, fps=1.0)


def test_video_source_keeps_the_container_rate_without_fps(tmp_path):
    video = tmp_path / "v.avi"
    vw = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (16, 16))
    if not vw.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG/avi")
    vw.write(np.zeros((16, 16, 3), np.uint8))
    vw.release()
    assert VideoSource(video).fps == pytest.approx(25.0)
    assert Path(video).exists()


@pytest.mark.parametrize("times, why", [
    ([0.0, 0.01, 0.01, 0.02], r"line 4: t_s 0.01 is not after line 3's 0.01"),  # repeated
    ([0.0, 0.02, 0.01, 0.03], r"line 4: t_s 0.01 is not after line 3's 0.02"),  # backwards
])
def test_an_imu_stream_whose_time_does_not_increase_is_refused(tmp_path, times, why):
    """A repeated sample or a clock that went back was sorted into the stream silently
    (review of issue 33): the file and line are named."""
    path = tmp_path / "imu.csv"
    path.write_text(HEADER + "".join(f"{t},0.1,0,0\n" for t in times))
    with pytest.raises(ValueError, match=r"imu\.csv: " + why):
        read_sensor_csv(path)


def test_a_gyro_and_a_magnetometer_at_one_time_are_two_streams_not_a_repeat(tmp_path):
    path = tmp_path / "imu.csv"
    path.write_text("t_s,gyro_x,gyro_y,gyro_z,mag_x,mag_y,mag_z\n"
                    "0.0,0.1,0,0,,,\n0.0,,,,2e4,0,-4e4\n0.01,0.1,0,0,,,\n")
    assert [m.topic for m in read_sensor_csv(path)] == ["/imu/gyro", "/mag", "/imu/gyro"]


def test_an_imu_file_broken_before_its_first_sample_is_refused(tmp_path):
    """It replayed on without a gyro, with a warning saying "read up to no samples"."""
    path = tmp_path / "imu.csv"
    path.write_text(HEADER + "0.0,0.1,,0\n0.01,0.1,0,0\n")
    with pytest.raises(ValueError, match=r"imu\.csv: line 2: gyro_y empty where the rest "
                                         r"of gyro_x, gyro_y, gyro_z is given; no sample "
                                         r"before it"):
        read_sensor_csv(path)
