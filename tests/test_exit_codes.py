"""One rule of exit codes for every command (issue 33, item 7; ``adfusion.app.errors``):
0 done, 1 done in part (not identified, input problems reported, a run that failed after
its output was started, a full disk), 2 nothing done (the command line, or an input that
cannot be used at all). The same mistake gave 1 from ``replay`` and 2 from ``solve``, and an
unreadable frame exited 1 like a frame read and not identified."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest
from adfusion.logs import McapLogReader
from adfusion.sensors.scenarios import oedipus
from raising_input import raising_after

from adfusion.app.cli import main
from adfusion.app.errors import PartlyDone, UsageError, exit_code, mark_incomplete
from adfusion.app.replay import simulate


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("exit")
    (d / "junk.png").write_bytes(b"not an image at all" * 10)
    cv2.imwrite(str(d / "noise.png"),
                np.random.default_rng(3).integers(0, 30, (96, 128), np.uint8))
    (d / "junk").mkdir()
    for name in ("a.png", "b.png"):
        (d / "junk" / name).write_bytes(b"junk")
    (d / "mixed").mkdir()
    (d / "mixed" / "a.png").write_bytes(b"junk")  # the first file: no header
    for k in range(3):
        cv2.imwrite(str(d / "mixed" / f"b{k}.png"),
                    np.random.default_rng(k).integers(0, 30, (48, 64), np.uint8))
    return d


def _run(argv, capsys) -> tuple[int, list[str]]:
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize("command", [
    ["solve", "{d}/junk.png", "--fov", "10"],
    ["detect", "{d}/junk.png"],
    ["calibrate", "{d}/junk.png", "--fov", "10", "-o", "{d}/cam.yaml"],
    ["replay", "{d}/junk", "--fps", "1", "--fov", "10", "--assume-defaults", "-o",
     "{d}/o.mcap"],
])
def test_a_frame_that_cannot_be_read_is_exit_2_from_every_command(files, capsys, command):
    code, err = _run([a.format(d=files) for a in command], capsys)
    assert code == 2 and len(err) == 1 and "junk" in err[0], (command, code, err)
    assert "not a PNG, JPEG" in err[0]


@pytest.mark.parametrize("command", [
    ["solve", "{d}/noise.png", "--fov", "10"],
    ["calibrate", "{d}/noise.png", "--fov", "10", "-o", "{d}/cam.yaml"],
])
def test_a_frame_read_and_not_identified_is_exit_1(files, capsys, command):
    code, err = _run([a.format(d=files) for a in command], capsys)
    assert code == 1, (command, code, err)
    assert all("internal error" not in ln for ln in err), err
    assert not (files / "cam.yaml").exists()


def test_the_same_missing_flag_is_exit_2_from_solve_and_replay(files, capsys):
    for argv in (["solve", files / "noise.png"],
                 ["replay", files / "mixed", "--fps", "1", "--assume-defaults",
                  "-o", files / "o.mcap"]):
        code, err = _run(argv, capsys)
        assert code == 2 and len(err) == 1 and "--fov" in err[0], (argv, err)


def test_a_folder_whose_first_file_is_no_image_replays_the_rest(files, capsys):
    """The size came from the first file's header alone: one bad first file refused the
    folder. Now it is dropped and counted like any unreadable frame (exit 1)."""
    out = files / "mixed.mcap"
    code = main(["replay", str(files / "mixed"), "--fps", "1", "--fov", "10",
                 "--assume-defaults", "-o", str(out)])
    text = capsys.readouterr().out
    assert code == 1 and "frames 3," in text, text
    assert "1 of 4 frame file(s) dropped unread" in text


def test_a_replay_that_fails_after_its_output_started_is_exit_1_naming_it(
        tmp_path, capsys, monkeypatch):
    sim = tmp_path / "sim.mcap"
    simulate(oedipus(duration_s=1.0, render=False, seed=1), sim)
    raising_after(200, ValueError("the disk went away"), monkeypatch)
    out = tmp_path / "o.mcap"
    code, err = _run(["replay", sim, "-o", out], capsys)
    assert code == 1 and len(err) == 1, err
    assert "the disk went away" in err[0]
    assert f"({out} holds what was done before, marked incomplete)" in err[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert "incomplete" in McapLogReader(out).metadata


def test_exit_code_follows_the_table():
    import errno

    assert exit_code(UsageError("--fps")) == 2
    assert exit_code(ValueError("not an MCAP file")) == 2
    assert exit_code(FileNotFoundError(2, "No such file", "a.png")) == 2
    assert exit_code(PermissionError(13, "Permission denied", "a.png")) == 2
    assert exit_code(OSError(errno.ENOSPC, "No space left", "o.mcap")) == 1
    assert exit_code(PartlyDone("no frame could be identified")) == 1
    assert exit_code(RuntimeError("a bug of ours")) == 1
    e = ValueError("stopped")
    mark_incomplete(e, "o.mcap")
    assert exit_code(e) == 1


# ------------------------------------------------ found trying it as a new user would
@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    """A short simulated flight and its replay."""
    from adfusion.app.replay import replay

    d = tmp_path_factory.mktemp("replayed")
    simulate(oedipus(duration_s=1.0, render=False, seed=2), d / "sim.mcap")
    replay(d / "sim.mcap", d / "out.mcap", progress=False)
    return d


def test_a_folder_in_place_of_an_output_is_refused_before_any_work(replayed, tmp_path,
                                                                    capsys):
    """A folder named like the layout was found after the whole replay, which then said
    its complete log was "marked incomplete"; a folder in place of --csv was found after
    the AEM was written, and named the temporary file (`.adf-….tmp`), exit 2."""
    (tmp_path / "o.layout.json").mkdir()
    code, err = _run(["replay", replayed / "sim.mcap", "-o", tmp_path / "o.mcap"], capsys)
    assert code == 2 and len(err) == 1 and "o.layout.json is a folder" in err[0], err
    assert not (tmp_path / "o.mcap").exists()
    (tmp_path / "f.csv").mkdir()
    code, err = _run(["export", replayed / "out.mcap", "--aem", tmp_path / "ok.aem",
                      "--csv", tmp_path / "f.csv"], capsys)
    assert code == 2 and len(err) == 1 and "--csv" in err[0] and ".adf-" not in err[0], err
    assert not (tmp_path / "ok.aem").exists()


def test_a_command_failing_after_writing_an_output_is_exit_1_naming_it(
        replayed, tmp_path, capsys, monkeypatch):
    import adfusion.app.export as export

    def broken(history, path):
        raise ValueError("the CSV writer failed")

    monkeypatch.setattr(export, "write_csv", broken)
    aem = tmp_path / "ok.aem"
    code, err = _run(["export", replayed / "out.mcap", "--aem", aem, "--csv",
                      tmp_path / "x.csv"], capsys)
    assert code == 1 and len(err) == 1 and aem.exists(), err
    assert f"(written before it: {aem})" in err[0] and "the CSV writer failed" in err[0]


def test_a_rename_that_fails_names_the_output_not_the_temporary_file(tmp_path):
    from adfusion.outfiles import atomic_output

    out = tmp_path / "busy"
    out.mkdir()
    (out / "x").write_text("a folder that is not empty: the rename fails")
    with pytest.raises(OSError) as raised, atomic_output(out, lock=False) as tmp:
        tmp.write_text("done")
    assert raised.value.filename == str(out)
    assert [p.name for p in tmp_path.iterdir()] == ["busy"]


def test_simulate_refuses_an_existing_ros2_folder_before_simulating(tmp_path, capsys):
    (tmp_path / "bag").mkdir()
    out = tmp_path / "x.mcap"
    code, err = _run(["simulate", "leo", "-o", out, "--duration", "1", "--ros2",
                      tmp_path / "bag"], capsys)
    assert code == 2 and len(err) == 1 and "--ros2" in err[0] and not out.exists(), err
    code, err = _run(["simulate", "leo", "-o", out, "--duration", "1", "--ros2", out],
                     capsys)
    assert code == 2 and "both name" in err[0] and not out.exists(), err


def test_exporting_an_incomplete_log_says_so_and_exits_1(replayed, tmp_path, capsys):
    """It exited 0 without a word, where `report` of the same log said INCOMPLETE."""
    from adfusion.logs import LogWriter

    part = tmp_path / "part.mcap"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = McapLogReader(replayed / "out.mcap")
        w = LogWriter(part, start_utc=reader.start_utc or "2026-01-01T00:00:00Z")
        for m in reader:
            if m.topic in ("/estimate/state", "/estimate/attitude"):
                w.write_json(m.topic, m.t_s, m.payload)
        w.abort("KeyboardInterrupt")
    code = main(["export", str(part), "--csv", str(tmp_path / "p.csv")])
    out = capsys.readouterr().out
    assert code == 1 and "problem: INCOMPLETE run: KeyboardInterrupt" in out, out
    assert (tmp_path / "p.csv").exists()
    assert main(["export", str(replayed / "out.mcap"), "--csv", str(tmp_path / "q.csv")]) == 0


def test_a_folder_whose_first_file_is_a_dangling_link_replays_the_rest(files, tmp_path,
                                                                        capsys):
    import os

    folder = tmp_path / "f"
    folder.mkdir()
    os.symlink(tmp_path / "gone.png", folder / "a.png")
    for k in range(2):
        cv2.imwrite(str(folder / f"b{k}.png"),
                    np.random.default_rng(k).integers(0, 30, (48, 64), np.uint8))
    code = main(["replay", str(folder), "--fps", "1", "--fov", "10", "--assume-defaults",
                 "-o", str(tmp_path / "o.mcap")])
    assert code == 1 and "frames 2," in capsys.readouterr().out


def test_a_batch_where_no_image_reads_is_exit_2(files, capsys):
    code, err = _run(["solve", files / "junk.png", files / "junk" / "a.png", "--fov", "10"],
                     capsys)
    assert code == 2 and len(err) == 1 and "none of the 2 images could be read" in err[0]


def test_a_report_that_cannot_start_leaves_no_folder(files, tmp_path, capsys):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"x" * 100)
    code, err = _run(["report", bad, "-o", tmp_path / "rep"], capsys)
    assert code == 2 and "nothing to report" in err[-1], err  # (the reader warns first)
    assert not (tmp_path / "rep").exists()


def test_one_image_file_replayed_that_is_no_image_is_one_line(files, tmp_path, capfd):
    """OpenCV's ffmpeg reader opened it with a size of 0: two `[png @ …]` lines, then a
    camera-matrix error that said nothing of the file."""
    code = main(["replay", str(files / "junk.png"), "--fov", "10", "-o",
                 str(tmp_path / "o.mcap")])
    err = capfd.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "junk.png" in err[0], err
    assert "upper triangular" not in err[0]


def test_calibrate_names_the_frames_it_could_not_identify(files, capsys):
    code, err = _run(["calibrate", files / "noise.png", "--fov", "10", "-o",
                      files / "cam.yaml"], capsys)
    assert code == 1 and err == ["adfusion calibrate: error: no frame could be identified: "
                                 "noise.png: too few detections (0 < 3)"], err
