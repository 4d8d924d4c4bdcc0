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

from adfusion.app.cli import main
from adfusion.app.errors import PartlyDone, UsageError, exit_code, mark_incomplete
from adfusion.app.replay import simulate
from adfusion.app.replay import sources as replay_sources


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
    opened = replay_sources.open_input

    class Raising:
        def __init__(self, source):
            self._source = source

        def __getattr__(self, name):
            return getattr(self._source, name)

        def __iter__(self):
            for k, msg in enumerate(self._source):
                if k == 200:
                    raise ValueError("the disk went away")
                yield msg

    monkeypatch.setattr(replay_sources, "open_input",
                        lambda path, **kw: Raising(opened(path, **kw)))
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
