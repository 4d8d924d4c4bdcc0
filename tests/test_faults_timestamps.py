"""Frame times that lie (issue 33, item 2): a timestamps CSV naming one file twice (it
silently moved a frame by 97 s), two frames at one time (both passed), or a negative time
is refused with the file, the line and the flag; frames whose names do not sort in time
order are replayed in time order."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from adfusion.logs import ImageFolderSource

from adfusion.app.cli import main


def _folder(tmp_path, names):
    folder = tmp_path / "frames"
    folder.mkdir()
    for n in names:
        assert cv2.imwrite(str(folder / n), np.zeros((8, 8), np.uint8))
    return folder


def _stamps(tmp_path, rows):
    path = tmp_path / "t.csv"
    path.write_text("filename,t_s\n" + "".join(f"{n},{t}\n" for n, t in rows))
    return path


@pytest.mark.parametrize("rows, why", [
    ([("a.png", 0.0), ("b.png", 0.1), ("a.png", 97.0)], "line 4: a.png is also at line 2"),
    ([("a.png", 0.0), ("b.png", 0.0)], "line 3: b.png has the time of a.png (line 2)"),
    ([("a.png", -1.0), ("b.png", 0.1)], "line 2: t_s -1 < 0"),
])
def test_timestamps_that_cannot_be_true_are_refused(tmp_path, capsys, rows, why):
    folder = _folder(tmp_path, ["a.png", "b.png"])
    stamps = _stamps(tmp_path, rows)
    with pytest.raises(ValueError, match=why.replace("(", r"\(").replace(")", r"\)")):
        ImageFolderSource(folder, timestamps_csv=stamps)
    out = tmp_path / "out.mcap"
    code = main(["replay", str(folder), "--timestamps", str(stamps), "--fov", "10",
                 "--assume-defaults", "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].count("--timestamps") == 1, err
    assert why in err[0] and not out.exists()


def test_frames_are_replayed_in_the_order_of_their_times(tmp_path):
    """``9.png`` sorts after ``10.png`` by name; its time says it comes first."""
    folder = _folder(tmp_path, ["9.png", "10.png", "11.png"])
    src = ImageFolderSource(folder, timestamps_csv=_stamps(
        tmp_path, [("9.png", 0.9), ("10.png", 1.0), ("11.png", 1.1)]))
    assert src.names == ["9.png", "10.png", "11.png"] and src.times == [0.9, 1.0, 1.1]
    assert [m.t_s for m in src.frames()] == [0.9, 1.0, 1.1]


def test_a_folder_replay_says_everything_it_lacks_at_once(tmp_path, capsys):
    """A folder replay took three failed tries (--fps, then --fov, then export wanted
    --start-utc), each naming one missing input (new-user trial)."""
    folder = _folder(tmp_path, ["a.png", "b.png"])
    imu = tmp_path / "imu.csv"
    imu.write_text("t_s,gyro_x,gyro_y,gyro_z\n0.0,0,0,0\n")
    assert main(["replay", str(folder), "--imu", str(imu), "-o",
                 str(tmp_path / "out.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for flag in ("--fps", "--timestamps", "--fov", "--camera", "--mount", "--assume-defaults",
                 "--start-utc"):
        assert flag in err[0], (flag, err[0])
    # given what it asked for, it runs
    assert main(["replay", str(folder), "--fps", "1", "--fov", "10", "--assume-defaults",
                 "--start-utc", "2026-01-01T00:00:00Z", "-o", str(tmp_path / "out.mcap")]) in (0, 1)
    assert (tmp_path / "out.mcap").exists()


def test_rows_and_frames_that_do_not_match_are_counted_and_said(tmp_path, capsys):
    """Rows naming files the folder does not have were ignored silently, and a frame
    without a row stopped the whole replay (new-user review): each is an input problem,
    counted, the first few named, and the frames that have a time are replayed."""
    import warnings

    from adfusion.logs import McapLogReader

    folder = _folder(tmp_path, ["a.png", "b.png", "c.png", "d.png", "e.png", "f.png"])
    stamps = _stamps(tmp_path, [("a.png", 0.0), ("x.png", 0.05), ("b.png", 0.1),
                                ("frames/y.png", 0.2), ("c.png", 0.3), ("z.png", 0.4),
                                ("w.png", 0.5)])
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        src = ImageFolderSource(folder, timestamps_csv=stamps)
    assert src.names == ["a.png", "b.png", "c.png"] and src.times == [0.0, 0.1, 0.3]
    rows, frames = src.problems
    assert ("4 row(s) name no image of the folder" in rows
            and "(line 3: x.png, line 5: y.png, line 7: z.png and 1 more)" in rows), rows
    assert frames.endswith("3 of the folder's 6 image(s) have no row, so no time, and are "
                           "not replayed: d.png, e.png, f.png"), frames
    out = tmp_path / "out.mcap"
    code = main(["replay", str(folder), "--timestamps", str(stamps), "--fov", "10",
                 "-o", str(out)])
    text = capsys.readouterr().out
    assert code == 1  # an input problem
    assert "frames 3," in text and f"input problem: {rows}" in text, text
    assert f"input problem: {frames}" in text
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        said = McapLogReader(out).metadata["problems"]["input"]
    assert rows in said and frames in said


def test_a_timestamps_csv_that_names_none_of_the_frames_is_refused(tmp_path, capsys):
    folder = _folder(tmp_path, ["a.png", "b.png"])
    stamps = _stamps(tmp_path, [("img_0001.png", 0.0), ("img_0002.png", 0.1)])
    with pytest.raises(ValueError, match=r"no time for any of the folder's 2 image\(s\) "
                                         r"\(a\.png, b\.png\); its rows name img_0001\.png, "
                                         r"img_0002\.png"):
        ImageFolderSource(folder, timestamps_csv=stamps)
    assert main(["replay", str(folder), "--timestamps", str(stamps), "--fov", "10",
                 "-o", str(tmp_path / "out.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].count("--timestamps") == 1, err
