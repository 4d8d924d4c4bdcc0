"""Outputs never replace inputs, one writer per output, names at the file-system limit
(issue 33, items 3 and 6): every command that writes, run with an input as its own output,
stops before any work with exit 2 and one line, and the input is untouched."""

from __future__ import annotations

import hashlib
import os
import threading

import cv2
import numpy as np
import pytest
from adfusion.logs import LogWriter, McapLogReader

from adfusion.app.cli import main
from adfusion.outfiles import OutputBusy, OutputLock


def _png(path):
    rng = np.random.default_rng(len(str(path)))
    assert cv2.imwrite(str(path), rng.integers(0, 40, (48, 64), dtype=np.uint8))
    return path


def _digest(paths):
    return {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in paths}


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """A simulated flight and its replay (tiny: 1 s, centroids only)."""
    d = tmp_path_factory.mktemp("flight")
    flight, replayed = d / "flight.mcap", d / "replayed.mcap"
    assert main(["simulate", "oedipus", "-o", str(flight), "--duration", "1",
                 "--no-render"]) == 0
    assert main(["replay", str(flight), "-o", str(replayed)]) == 0
    return flight, replayed


def test_every_command_refuses_an_input_as_its_output(tmp_path, logs, capsys):
    flight, replayed = logs
    frames = tmp_path / "frames"
    frames.mkdir()
    a, b = _png(frames / "a.png"), _png(frames / "b.png")
    cam = tmp_path / "a.json"  # a camera file named as solve's product for a.png
    cam.write_text('{"model": "pinhole", "width": 64, "height": 48, "fov_x_deg": 10.0}')
    log_copy = tmp_path / "summary.md"  # a log under the name of a report's file
    log_copy.write_bytes(replayed.read_bytes())
    other = tmp_path / "other"
    other.mkdir()
    b2 = _png(other / "b.png")
    imu_as_layout = tmp_path / "x.layout.json"
    imu_as_layout.write_text("t_s,gyro_x,gyro_y,gyro_z\n0.0,0,0,0\n")
    inputs = [a, b, b2, cam, log_copy, flight, replayed, imu_as_layout]
    before = _digest(inputs)
    cases = [
        # the case: calibrate replaced a 1.57 MB frame by a 595-byte YAML
        (["calibrate", str(a), str(b), "--fov", "10", "-o", str(a)], "is the input"),
        (["calibrate", str(a), "--camera", str(cam), "-o", str(cam)], "is the input"),
        (["solve", str(a), "--fov", "10", "--overlay", str(frames / "." / "a.png")],
         "is the input"),
        (["solve", str(a), "--camera", str(cam), "-o", str(tmp_path)], "is the input"),
        (["solve", str(b), str(b2), "--fov", "10", "-o", str(tmp_path / "out")], "both name"),
        (["replay", str(flight), "-o", str(flight)], "is the input"),
        (["replay", str(frames), "--fps", "1", "--fov", "10", "-o", str(a)], "is the input"),
        (["export", str(replayed), "--csv", str(replayed)], "is the input"),
        # the layout written beside the log replaced an --imu file of its name (review)
        (["replay", str(frames), "--fps", "1", "--fov", "10", "--assume-defaults", "--imu",
          str(imu_as_layout), "-o", str(tmp_path / "x.mcap")], "the layout"),
        (["report", str(log_copy), "-o", str(tmp_path)], "is the input"),
    ]
    for argv, why in cases:
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
        assert len(err) == 1 and why in err[0], (argv, err)
    assert _digest(inputs) == before
    assert not (tmp_path / "out").exists() and not list(tmp_path.rglob(".adf-*"))


def test_a_second_writer_of_one_output_is_refused_at_once(tmp_path, capsys):
    """Two replays given one -o shared one temporary file: the output held the other run's
    metadata, and both exited 0. Now the output is locked while it is written."""
    out = tmp_path / "run.mcap"
    with LogWriter(out, atomic=True) as first:
        first.add_metadata("run", {"who": "first"})
        with pytest.raises(OutputBusy, match="being written by another run"):
            LogWriter(out, atomic=True)
        assert main(["simulate", "leo", "-o", str(out), "--duration", "1",
                     "--no-render"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(out) in err[0] and str(os.getpid()) in err[0]
    assert McapLogReader(out).metadata["run"] == {"who": "first"}
    # released when the writer closed: the next run writes it
    with LogWriter(out, atomic=True) as second:
        second.add_metadata("run", {"who": "second"})
    assert McapLogReader(out).metadata["run"] == {"who": "second"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]


def test_writers_racing_for_one_output_leave_one_whole_run(tmp_path):
    """Eight threads start writing one output at once: exactly one gets it, the others are
    refused, and the output is the winner's whole log."""
    import time

    out = tmp_path / "race.mcap"
    won, refused = [], []
    start, others_done = threading.Barrier(8), threading.Event()

    def write(k: int) -> None:
        start.wait()
        try:
            log = LogWriter(out, atomic=True)
        except OutputBusy:
            refused.append(k)
            return
        won.append(k)
        with log:
            log.add_metadata("run", {"who": k})
            others_done.wait(10)  # hold the output until every other writer has tried

    threads = [threading.Thread(target=write, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    deadline = time.time() + 10
    while len(won) + len(refused) < 8 and time.time() < deadline:
        time.sleep(0.01)
    others_done.set()
    for t in threads:
        t.join(10)
    assert len(won) == 1 and len(refused) == 7
    assert McapLogReader(out).metadata["run"] == {"who": won[0]}


def test_an_output_name_at_the_file_system_limit_works(tmp_path):
    """A 255-byte output name was refused because of the writer's ``.partial`` suffix."""
    name = "x" * (255 - len(".mcap")) + ".mcap"
    out = tmp_path / name
    assert main(["simulate", "leo", "-o", str(out), "--duration", "1", "--no-render"]) == 0
    assert out.exists() and len(McapLogReader(out).metadata) > 0
    assert [p.name for p in tmp_path.iterdir()] == [name]


def test_report_files_are_the_ones_it_writes(tmp_path, logs):
    """The guard of ``report`` compares the files it writes: its list is the real one (a
    replay's log: all but the live run's latency plot)."""
    from adfusion.app.report import LIVE_REPORT_FILES, REPORT_FILES, report

    written = report(logs[1], tmp_path / "r")
    assert sorted(p.name for p in written) == sorted(set(REPORT_FILES) - set(LIVE_REPORT_FILES))


def test_a_lock_held_by_a_dead_writer_does_not_block(tmp_path):
    """The lock is the kernel's (flock): a writer that dies releases it, so a killed run
    never blocks the next one (a lock file left by it is taken over)."""
    import subprocess
    import sys

    out = tmp_path / "run.mcap"
    code = ("import os, sys\nfrom adfusion.outfiles import OutputLock\n"
            "OutputLock(sys.argv[1]).acquire()\nos._exit(0)\n")  # dies holding it
    subprocess.run([sys.executable, "-c", code, str(out)], check=True, timeout=60)
    with OutputLock(out):
        pass
    with LogWriter(out, atomic=True):
        pass
    assert out.exists()
