"""Replay and the CLI under faults (issue 16, items 1, 4–7, 12, 13): inputs are never
overwritten, a changed calibration or a missing one is refused, every dropped input is
counted and shown, the score does not depend on file order, foreign content is a message,
and every failure the CLI meets is one line with exit code 1 (input) or 2 (usage)."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from adfusion.logs import LogWriter, McapLogReader
from adfusion.sensors.scenarios import oedipus

from adfusion.app.cli import main
from adfusion.app.replay import replay, simulate


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    """A 3 s OEDIPUS-like flight as star centroids (90 frames, gyro, magnetometer, truth)."""
    path = tmp_path_factory.mktemp("sim") / "sim.mcap"
    simulate(oedipus(duration_s=3.0, render=False, seed=1), path)
    return path


def _read(path: Path) -> McapLogReader:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return McapLogReader(path)


def _messages(path: Path) -> list:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return list(McapLogReader(path))


def copy_log(src: Path, dst: Path, *, config="same", camera="same", edit=None,
             truth_after_frames: bool | None = None) -> Path:
    """Re-write ``src`` (the topics a replay uses) with our writer: ``config``/``camera``
    replaced (``None`` leaves them out), ``edit(msg) → [(topic, t, payload)]`` per
    message, and equal-time truth moved after (or before) the frames of that time."""
    reader = _read(src)
    msgs = [m for m in _messages(src)
            if m.topic in ("/imu/gyro", "/mag", "/camera/centroids", "/truth/state")]
    if truth_after_frames is not None:
        rank = {"/truth/state": 1 if truth_after_frames else -1}
        msgs.sort(key=lambda m: (m.t_s, rank.get(m.topic, 0)))
    with LogWriter(dst, compression="none") as log:
        cfg = reader.metadata["config"] if config == "same" else config
        if cfg is not None:
            log.add_metadata("config", cfg)
        cam = reader.camera_model() if camera == "same" else camera
        if cam is not None:
            log.add_camera_model(cam)
        for m in msgs:
            out = [(m.topic, m.t_s, m.payload)] if edit is None else edit(m)
            for topic, t, payload in out:
                if isinstance(payload, bytes):
                    log.write_json_bytes(topic, t, payload)
                else:
                    log.write_json(topic, t, payload)
    return dst


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --------------------------------------------------------------------------- item 1
def test_replay_never_overwrites_its_input(sim, tmp_path, monkeypatch, capsys):
    inp = tmp_path / "in.mcap"
    inp.write_bytes(sim.read_bytes())
    before = _sha(inp)
    link = tmp_path / "link.mcap"
    link.symlink_to(inp)
    hard = tmp_path / "hard.mcap"
    os.link(inp, hard)
    monkeypatch.chdir(tmp_path)
    for out in (str(inp), "./in.mcap", "in.mcap", str(link), str(hard)):
        with pytest.raises(ValueError, match="is the input"):
            replay(inp, out, progress=False)
        assert main(["replay", str(inp), "-o", out]) == 2  # a usage error, as in solve
        err = capsys.readouterr().err
        assert "is the input" in err and len(err.strip().splitlines()) == 1
    assert _sha(inp) == before and inp.stat().st_size == sim.stat().st_size
    # a complete output appears under its name only at the end: no temporary file or lock
    # left behind
    s = replay(inp, tmp_path / "out.mcap", progress=False)
    assert s.frames == 90 and not list(tmp_path.glob(".adf-*"))


# --------------------------------------------------------------------------- item 4
def test_a_changed_calibration_is_refused(sim, tmp_path, capsys):
    data = sim.read_bytes()
    # one digit of q_body_cam in the config metadata (stored as JSON text, uncompressed)
    at = data.index(b"q_body_cam")
    i = at + data[at:].index(b"0.") + 3
    digit = data[i:i + 1]
    assert digit.isdigit()
    bad = tmp_path / "q.mcap"
    bad.write_bytes(data[:i] + (b"7" if digit != b"7" else b"3") + data[i + 1:])
    reader = _read(bad)
    assert "config" not in reader.metadata
    assert any("digest" in p.reason and "config" in p.reason for p in reader.problems)
    with pytest.raises(ValueError, match="--config"):
        replay(bad, tmp_path / "o.mcap", progress=False)
    # fx in the camera model attachment: its CRC fails, the model is not used
    j = data.index(b'"K":[[', data.index(b"camera.json")) + 6
    bad2 = tmp_path / "fx.mcap"
    bad2.write_bytes(data[:j] + (b"9" if data[j:j + 1] != b"9" else b"8") + data[j + 1:])
    assert _read(bad2).camera_model() is None
    assert main(["replay", str(bad2), "-o", str(tmp_path / "o2.mcap")]) == 2
    assert "no camera model" in capsys.readouterr().err


# --------------------------------------------------------------------------- item 5
def test_a_log_without_config_is_an_error_naming_the_flag(sim, tmp_path, capsys):
    bare = copy_log(sim, tmp_path / "bare.mcap", config=None)
    with pytest.raises(ValueError, match=r"no 'config' metadata.*--config.*--assume-defaults"):
        replay(bare, tmp_path / "o.mcap", progress=False)
    assert main(["replay", str(bare), "-o", str(tmp_path / "o.mcap")]) == 2
    assert "--config" in capsys.readouterr().err
    # the configuration given on the command line: the same result as the original log
    cfg = tmp_path / "config.json"
    cfg.write_text(json.dumps(_read(sim).metadata["config"]))
    assert main(["replay", str(bare), "-o", str(tmp_path / "given.mcap"), "--config",
                 str(cfg), "--json"]) == 0
    given = json.loads(capsys.readouterr().out)
    original = replay(sim, tmp_path / "orig.mcap", progress=False).as_dict()
    assert given["error_rms_deg"] == pytest.approx(original["error_rms_deg"], rel=1e-9)
    # defaults only when asked for, and recorded
    s = replay(bare, tmp_path / "assumed.mcap", progress=False, assume_defaults=True)
    assert s.frames == 90
    assumed = _read(tmp_path / "assumed.mcap").metadata["assumptions"]
    assert assumed["q_body_cam"] == [1.0, 0.0, 0.0, 0.0]


# --------------------------------------------------------------------------- item 6
def test_dropped_inputs_are_counted_recorded_and_reported(sim, tmp_path, capsys):
    def nan_gyro(m):
        if m.topic == "/imu/gyro":
            return [(m.topic, m.t_s, {"omega": [float("nan"), 0.0, 0.0]})]
        return [(m.topic, m.t_s, m.payload)]

    bad = copy_log(sim, tmp_path / "nan.mcap", edit=nan_gyro)
    s = replay(bad, tmp_path / "o.mcap", progress=False)
    assert s.dropped.get("gyro") == 600
    assert any("600 of 600 gyro message(s) dropped" in p for p in s.problems)
    assert "input problem: 600 of 600 gyro" in str(s)
    meta = _read(tmp_path / "o.mcap").metadata["problems"]
    assert meta["dropped"]["gyro"] == 600
    assert main(["replay", str(bad), "-o", str(tmp_path / "o2.mcap")]) == 1
    capsys.readouterr()
    assert main(["report", str(tmp_path / "o2.mcap"), "-o", str(tmp_path / "rep")]) == 1
    out = capsys.readouterr().out
    assert "600 of 600 gyro message(s) dropped" in out
    assert "600 of 600 gyro" in (tmp_path / "rep" / "summary.md").read_text()


def test_undecodable_and_mis_sized_frames_are_reported(tmp_path):
    from adfusion.starid.camera.model import Camera

    cam = Camera.pinhole(64, 48, 20.0)
    cfg = {"q_body_cam": [1.0, 0.0, 0.0, 0.0], "mag_limit": 5.0}
    garbage = tmp_path / "garbage.mcap"
    with LogWriter(garbage) as log:
        log.add_metadata("config", cfg)
        log.add_camera_model(cam.to_dict())
        for i in range(5):
            log.write_protobuf_bytes("/camera/image", 0.1 * i, "foxglove.RawImage",
                                     b"\xff\x00 not a protobuf message \x12\x99")
    s = replay(garbage, tmp_path / "o.mcap", progress=False)
    assert s.frames == 0
    assert any("5 message(s) on /camera/image could not be decoded" in p for p in s.problems)
    wrong = tmp_path / "wrong.mcap"
    with LogWriter(wrong) as log:
        log.add_metadata("config", cfg)
        log.add_camera_model(Camera.pinhole(512, 480, 20.0).to_dict())
        for i in range(4):
            log.write_image(0.1 * i, np.zeros((48, 64), np.uint8))
    s = replay(wrong, tmp_path / "o2.mcap", progress=False)
    assert s.dropped == {"frame": 4}
    assert any("64×48 px, but the camera model is 512×480" in p for p in s.problems)


def test_a_failed_replay_leaves_its_output_marked_incomplete(sim, tmp_path):
    from adfusion.app.replay import LogSink, McapInput, ReplayOptions, SummarySink, run

    class Interrupt:  # Ctrl-C after the 30th frame, as a user would press it
        n = 0

        def open(self, run):
            pass

        def take(self, step):
            if step.kind == "frame":
                self.n += 1
                if self.n == 30:
                    raise KeyboardInterrupt

        def close(self):
            pass

    out = tmp_path / "o.mcap"
    with pytest.raises(KeyboardInterrupt):
        run(McapInput(sim), [LogSink(out), SummarySink(), Interrupt()], ReplayOptions(),
            progress=False)
    reader = _read(out)
    assert reader.metadata["incomplete"]["reason"] == "KeyboardInterrupt"
    assert reader.problems == []  # closed properly: readable to the end
    assert 25 <= sum(m.topic == "/estimate/state" for m in reader) <= 30


# --------------------------------------------------------------------------- item 7
def test_the_score_does_not_depend_on_the_order_of_equal_time_messages(sim, tmp_path):
    a = copy_log(sim, tmp_path / "a.mcap", truth_after_frames=False)
    b = copy_log(sim, tmp_path / "b.mcap", truth_after_frames=True)
    sa = replay(a, tmp_path / "oa.mcap", progress=False)
    sb = replay(b, tmp_path / "ob.mcap", progress=False)
    assert sa.frames == sb.frames == 90
    # identical estimates (truth is not an input of the filter) ...
    est = [[m.payload["q_body_icrs"] for m in _messages(tmp_path / o)
            if m.topic == "/estimate/state"] for o in ("oa.mcap", "ob.mcap")]
    assert est[0] == est[1]
    # ... score the same
    assert sa.errors_deg == pytest.approx(sb.errors_deg, abs=1e-12)
    assert sa.as_dict()["error_rms_deg"] < 0.1


# --------------------------------------------------------------------------- item 12
def _edited(topic, make):
    def edit(m):
        if m.topic == topic:
            return [(m.topic, m.t_s, make(m.payload))]
        return [(m.topic, m.t_s, m.payload)]
    return edit


@pytest.mark.parametrize("topic,make,kind", [
    ("/imu/gyro", lambda p: {"w": p["omega"]}, "gyro"),
    ("/imu/gyro", lambda p: p["omega"], "gyro"),                 # a list payload
    ("/imu/gyro", lambda p: 3.5, "gyro"),                        # a number payload
    ("/imu/gyro", lambda p: {"omega": ["a", 0, 0]}, "gyro"),     # a string in the vector
    ("/mag", lambda p: {"b_ref_icrs": p["b_ref_icrs"]}, "mag"),  # no b_body
    ("/camera/centroids", lambda p: {"uv": p["xy"]}, "frame"),   # no xy
    ("/truth/state", lambda p: {"q": p["q_body_icrs"]}, "truth"),
])
def test_foreign_payloads_are_counted_not_tracebacks(sim, tmp_path, topic, make, kind):
    bad = copy_log(sim, tmp_path / "f.mcap", edit=_edited(topic, make))
    s = replay(bad, tmp_path / "o.mcap", progress=False)
    assert s.dropped.get(kind, 0) > 0
    assert any(topic in p or kind in p for p in s.problems)


def test_foreign_configuration_and_camera_are_messages(sim, tmp_path):
    cfg = _read(sim).metadata["config"]
    for name, config, camera, match in [
        ("cam_str", {**cfg, "camera": "PCO edge"}, "same", "config.camera is a str"),
        ("no_k", "same", {"width": 512, "height": 480, "D": []}, "camera model.*unusable"),
        ("gyro_str", {**cfg, "gyro": {"arw_rad_sqrt_s": "low"}}, "same", "arw_rad_sqrt_s"),
        ("q_str", {**cfg, "q_body_cam": "identity"}, "same", "q_body_cam"),
        # a log's own centroid σ is used as it stands now (no 0.5 px floor for centroids)
        ("sigma0", {**cfg, "camera": {**cfg["camera"], "centroid_sigma_px": 0.0}}, "same",
         "config.camera.centroid_sigma_px = 0.0 must be > 0"),
    ]:
        bad = copy_log(sim, tmp_path / f"{name}.mcap", config=config, camera=camera)
        with pytest.raises(ValueError, match=match):
            replay(bad, tmp_path / "o.mcap", progress=False)


def test_an_unknown_protobuf_schema_and_json_images_are_reported(sim, tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "proto.mcap"
    reader = _read(sim)
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("config", {k: json.dumps(v) if not isinstance(v, str) else v
                                  for k, v in reader.metadata["config"].items()})
        w.add_attachment(0, 0, "camera.json", "application/json",
                         json.dumps(reader.camera_model()).encode())
        sid = w.register_schema("acme.Gyro", "protobuf", b"\x0a\x05junk!")
        gid = w.register_channel("/imu/gyro", "protobuf", sid)
        jid = w.register_channel("/camera/image", "json",
                                 w.register_schema("img", "jsonschema", b"{}"))
        for i in range(10):
            w.add_message(gid, i * 10_000_000, b"\x08\x01", i * 10_000_000)
            w.add_message(jid, i * 10_000_000, b'{"data": [1, 2, 3]}', i * 10_000_000)
        w.finish()
    s = replay(path, tmp_path / "o.mcap", progress=False)
    text = "\n".join(s.problems)
    assert "10 message(s) on /imu/gyro could not be decoded" in text
    assert s.dropped.get("frame") == 10 and "not an image" in text


# --------------------------------------------------------------------------- item 13
def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if not ln.startswith("usage:")
             and not ln.startswith(" ")]
    assert len(lines) == 1, err
    return lines[0]


def test_cli_failures_are_one_line_with_exit_codes(sim, tmp_path, capsys):
    afile = tmp_path / "file.txt"
    afile.write_text("x")
    cases = [
        (["replay", str(sim), "-o", str(tmp_path)], 2, "is a folder"),
        # a folder is an input (of images): without frame times it names the flag
        (["replay", str(tmp_path), "-o", str(tmp_path / "o.mcap")], 2, "give --fps"),
        (["replay", str(afile), "-o", str(tmp_path / "o.mcap")], 2, "not an MCAP file"),
        (["report", str(sim), "-o", str(afile)], 2, "not a folder"),
        (["simulate", "leo", "-o", str(tmp_path / "x.mcap"), "--duration", "1e9",
          "--no-render"], 2, "out of memory"),  # a request too large: usage
        (["solve", "--example", "--mag-limit", "-5"], 2, "brighter than every star"),
        (["solve", "--example", "--overlay", str(tmp_path / "o.txt")], 2, "image file name"),
        (["simulate", "leo", "-o", str(tmp_path / "none" / "x.mcap")], 2, "does not exist"),
        (["replay", str(sim), "-o", str(tmp_path / "o.mcap"), "--mag-limit", "nan"], 2,
         "finite"),
    ]
    for argv, code, text in cases:
        assert main(argv) == code, argv
        line = _one_line_error(capsys)
        assert text in line, (argv, line)


def test_a_full_disk_is_one_line_and_leaves_no_partial_file(tmp_path):
    """The file-size limit makes writes fail as a full disk would (EFBIG instead of
    ENOSPC, the same path through the writer and the CLI)."""
    code = ("import resource, signal, sys\n"
            "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
            "resource.setrlimit(resource.RLIMIT_FSIZE, (65536, 65536))\n"
            "from adfusion.app.cli import main\n"
            "sys.exit(main(sys.argv[1:]))\n")
    out = tmp_path / "x.mcap"
    p = subprocess.run([sys.executable, "-c", code, "simulate", "leo", "-o", str(out),
                        "--duration", "200", "--no-render"], capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 1, p.stderr
    assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1
    assert "x.mcap" in p.stderr and "too large" in p.stderr.lower()
    assert not out.exists() and not list(tmp_path.glob(".adf-*"))  # nor a temporary file


def test_a_logged_camera_model_is_read_as_strictly_as_a_camera_file(sim, tmp_path):
    """The model inside a log went through the lenient ``Camera.from_dict``: a width of
    1024.5 became 1024. It is read as a camera file is (issue 33, item 8)."""
    good = _read(sim).camera_model()
    bad = copy_log(sim, tmp_path / "bad.mcap", camera={**good, "width": good["width"] + 0.5})
    with pytest.raises(ValueError, match=r"camera model \(camera\.json\) is unusable: "
                                         r"camera\.json: width: .* is not an integer"):
        replay(bad, tmp_path / "out.mcap", progress=False)


@pytest.mark.parametrize("at_step", [2, 25])
def test_a_replay_failing_mid_run_exits_1_with_its_one_line(tmp_path, at_step):
    """Issue 33 saw a failing replay end by SIGABRT from a worker thread. In a fresh
    process (its threads and shutdown real), a folder replay whose estimation fails at a
    step while detection runs ahead in its worker exits 1 with one line, no abort."""
    import cv2

    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for k in range(40):
        cv2.imwrite(str(frames / f"f{k:03d}.png"), rng.integers(0, 40, (96, 128), np.uint8))
    code = ("import sys\n"
            "from adfusion.app.replay import stages\n"
            "orig, n = stages.EstimationStage.__call__, [0]\n"
            "def failing(self, step):\n"
            "    n[0] += 1\n"
            f"    if n[0] == {at_step}:\n"
            "        raise RuntimeError('estimation failed')\n"
            "    return orig(self, step)\n"
            "stages.EstimationStage.__call__ = failing\n"
            "from adfusion.app.cli import main\n"
            "sys.exit(main(sys.argv[1:]))\n")
    p = subprocess.run([sys.executable, "-P", "-c", code, "replay", str(frames), "--fps", "10",
                        "--fov", "20", "-o", str(tmp_path / "out.mcap")],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 1, (p.returncode, p.stderr[-500:])
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "estimation failed" in lines[0], p.stderr[-500:]
