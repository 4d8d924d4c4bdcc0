"""``adfusion live`` (issue 36): frames solved as they arrive, recorded to MCAP and published
on a Foxglove WebSocket, frames that come faster than solved dropped and counted."""

from __future__ import annotations

import asyncio
import itertools
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from adfusion.logs import topics

from adfusion.app.live.feeds import ImuFileFeed, ImuUdpFeed, LiveClock, parse_imu_line
from adfusion.app.live.source import IMU_HOLD_S, LiveSource
from adfusion.maths import rotations as rot

REPO = Path(__file__).resolve().parents[1]
WRITER = REPO / "tests" / "live_writer.py"


class FoxgloveClient:
    """A client of the Foxglove WebSocket protocol (``foxglove.sdk.v1``, the one the
    Foxglove app speaks), written here from the protocol's text with the ``websockets``
    library: it subscribes to every advertised channel and keeps what it receives as
    ``(topic, log_time_ns, payload)``, and the channels as advertised. Only ``topics`` are
    subscribed to: a client that takes every 1 Mpx frame too is a slow client, and the
    server drops the oldest of its messages past its backlog (a slow viewer never holds
    the run back)."""

    def __init__(self, url: str, topics: tuple[str, ...]) -> None:
        self.url = url
        self.topics = topics
        self.channels: dict[int, dict] = {}
        self.received: list[tuple[str, int, bytes]] = []
        self._subs: dict[int, str] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)
        self.connected = threading.Event()

    def start(self) -> FoxgloveClient:
        self._thread.start()
        assert self.connected.wait(10), "no connection to the live view"
        return self

    async def _main(self) -> None:
        import websockets

        async with websockets.connect(self.url, subprotocols=["foxglove.sdk.v1"],
                                      max_size=None) as ws:
            self.connected.set()
            while not self._stop.is_set():
                try:
                    msg = await asyncio.wait_for(ws.recv(), 0.1)
                except TimeoutError:
                    continue
                except websockets.ConnectionClosed:
                    return
                if isinstance(msg, str):
                    op = json.loads(msg)
                    if op["op"] == "advertise":
                        subs = []
                        for ch in op["channels"]:
                            if ch["id"] in self.channels:  # advertised again: once only
                                continue
                            self.channels[ch["id"]] = ch
                            if ch["topic"] not in self.topics:
                                continue
                            sub_id = len(self._subs) + 1
                            self._subs[sub_id] = ch["topic"]
                            subs.append({"id": sub_id, "channelId": ch["id"]})
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                elif msg[0] == 0x01:  # message data: opcode, subscription id, log time
                    sub_id, log_time = struct.unpack_from("<IQ", msg, 1)
                    self.received.append((self._subs[sub_id], log_time, bytes(msg[13:])))

    def subscribed(self, topic: str) -> bool:
        return topic in self._subs.values()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)


def _mcap_messages(path: Path, topic: str) -> list[tuple[int, bytes]]:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return [(m.log_time, bytes(m.data)) for _, ch, m in
                make_reader(f).iter_messages(topics=[topic])]


def _metadata(path: Path, name: str) -> dict:
    from adfusion.logs import McapLogReader

    return McapLogReader(path).metadata.get(name)


def _start_live(args: list[str], env=None) -> tuple[subprocess.Popen, list[str]]:
    """``adfusion live ARGS`` in a process; its stderr lines collected as they come."""
    proc = subprocess.Popen([sys.executable, "-P", "-m", "adfusion", "live", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)
    lines: list[str] = []

    def read() -> None:
        for line in proc.stderr:
            lines.append(line)

    threading.Thread(target=read, daemon=True).start()
    return proc, lines


def _wait_for(lines: list[str], text: str, proc: subprocess.Popen, timeout: float = 120):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        hit = next((ln for ln in lines if text in ln), None)
        if hit is not None:
            return hit
        if proc.poll() is not None:
            time.sleep(0.2)
            raise AssertionError(f"live ended ({proc.returncode}): {''.join(lines)}")
        time.sleep(0.05)
    proc.kill()
    raise AssertionError(f"no {text!r} in {''.join(lines)}")


def test_live_folder_written_by_another_process_streams_estimates_to_foxglove(tmp_path):
    """Issue 36's acceptance: a second process writes frames into a folder, first slowly
    (each solved), then in a burst faster than they can be solved. A Foxglove-protocol
    client receives ``/estimate/state`` with the very bytes and log times the MCAP records,
    and each estimate is the attitude its frame was rendered at (within 3σ and 0.02°);
    every frame that arrived is either solved or counted as dropped, and the burst drops
    some."""
    folder = tmp_path / "in"
    folder.mkdir()
    out = tmp_path / "live.mcap"
    camera = tmp_path / "camera.json"
    from adfusion.starid.camera.model import Camera

    camera.write_text(json.dumps(Camera.pinhole(640, 480, 20.0).to_dict()))
    writer = subprocess.Popen([sys.executable, "-P", str(WRITER), str(folder), "--slow", "6",
                               "--burst", "25"])
    proc, lines = _start_live([str(folder), "--camera", str(camera), "--port", "0",
                               "--idle", "3", "-o", str(out), "--json"])
    try:
        url = _wait_for(lines, "ws://", proc).split("live view: ")[1].split(" ")[0]
        _wait_for(lines, "ready:", proc)  # every frame topic has its channel by now
        client = FoxgloveClient(url, (topics.ESTIMATE_STATE, topics.STARID_SOLUTION,
                                      topics.LIVE_STATUS)).start()
        t0 = time.monotonic()  # the frame topics are declared before ready: subscribed to
        while not client.subscribed(topics.ESTIMATE_STATE) and time.monotonic() - t0 < 10:
            time.sleep(0.02)
        (tmp_path / "go").touch()  # the writer starts now
        assert writer.wait(120) == 0
        stdout, _ = proc.communicate(timeout=120)
    finally:
        proc.kill()
        writer.kill()
    client.stop()
    assert proc.returncode == 0, "".join(lines)
    summary = json.loads(stdout)
    live = summary["live"]
    assert live["frames_arrived"] == 31
    assert live["frames_taken"] + live["frames_dropped"] == 31
    assert live["frames_dropped"] > 0, live  # the burst came faster than it was solved
    assert live["frames_dropped_before_ready"] == 0
    assert live == _metadata(out, "live")
    # the same topics, schemas and bytes as the log
    advertised = {ch["topic"]: ch for ch in client.channels.values()}
    assert advertised[topics.ESTIMATE_STATE]["schemaName"] == "adfusion.FilterState"
    assert advertised[topics.ESTIMATE_POSE]["schemaName"] == "foxglove.PoseInFrame"
    got = [(t, data) for topic, t, data in client.received if topic == topics.ESTIMATE_STATE]
    recorded = _mcap_messages(out, topics.ESTIMATE_STATE)
    assert len(recorded) == live["frames_taken"] and got == recorded
    status = [json.loads(d) for topic, _, d in client.received if topic == topics.LIVE_STATUS]
    assert len(status) == live["frames_taken"] and status[-1]["dropped"] == live["frames_dropped"]
    # each estimate is the attitude of the frame it came from: the nearest rendered one
    truth = np.array(list(json.loads((tmp_path / "truth.json").read_text()).values()))
    for topic, _, data in client.received:
        if topic == topics.STARID_SOLUTION:  # each fix: the frame's attitude (20° camera)
            # its boresight within 20″ (1/5 px), its roll (8× less certain) within 0.05°
            q = np.asarray(json.loads(data)["q_cam_icrs"])
            k = int(np.argmin(rot.angle_between(truth, q)))
            z_true, z = rot.rotate(rot.conjugate(truth[k]), [0, 0, 1]), rot.rotate(
                rot.conjugate(q), [0, 0, 1])
            assert np.degrees(np.arccos(min(1.0, z_true @ z))) * 3600 < 20
            assert np.degrees(rot.angle_between(truth[k], q)) < 0.05
    for _, data in got:  # the filter's estimate: within its 3σ of its frame's attitude
        state = json.loads(data)
        err = np.degrees(rot.angle_between(truth, np.asarray(state["q_body_icrs"]))).min()
        sigma = np.degrees(np.sqrt(np.sum(state["cov_diag"][:3])))
        assert err < 3 * sigma, (err, sigma)
    assert summary["identified"] == live["frames_taken"]


def test_ctrl_c_ends_a_live_run_with_its_output_complete(tmp_path):
    """Ctrl-C is how a live run at the telescope ends: the output is complete (not marked
    incomplete), its layout beside it, exit 0."""
    folder = tmp_path / "in"
    folder.mkdir()
    out = tmp_path / "live.mcap"
    proc, lines = _start_live([str(folder), "--fov", "20", "--no-view", "-o", str(out)])
    try:
        _wait_for(lines, "watching", proc)
        (tmp_path / "go").touch()
        subprocess.run([sys.executable, "-P", str(WRITER), str(folder), "--slow", "2",
                        "--interval", "0.2"], check=True, timeout=120)
        _wait_for(lines, "ready:", proc)
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
    finally:
        proc.kill()
    assert proc.returncode == 0, "".join(lines)
    rec = _metadata(out, "live")
    assert rec["ended_by"] == "stopped" and rec["frames_taken"] >= 1
    from adfusion.logs import McapLogReader

    assert "incomplete" not in McapLogReader(out).metadata
    assert (tmp_path / "live.layout.json").exists()


def test_a_recording_at_its_pace_gives_the_replays_attitudes(tmp_path):
    """``--realtime``: a simulated flight played at its pace (×4) through live: every frame
    solved (the recording waits for the solver to be ready), the attitudes within 3σ of
    the flight's truth as a replay's are."""
    from adfusion.sensors.scenarios import oedipus

    from adfusion.app.replay import simulate

    sim = tmp_path / "sim.mcap"
    simulate(oedipus(duration_s=3.0, render=False), sim)
    out = tmp_path / "live.mcap"
    from adfusion.app.cli import main

    assert main(["live", str(sim), "--realtime", "--speed", "4", "--no-view", "-o",
                 str(out)]) == 0
    rec = _metadata(out, "live")
    assert rec["frames_arrived"] == 90 and rec["ended_by"] == "the source ended"
    assert rec["frames_taken"] + rec["frames_dropped"] == 90
    def scored(path):
        errors = [json.loads(d) for _, d in _mcap_messages(path, topics.ESTIMATE_ERROR)]
        inside = np.mean([all(abs(e) <= s for e, s in zip(x["error_deg"], x["sigma3_deg"],
                                                             strict=True)) for x in errors])
        return len(errors), inside, np.percentile(
            [np.linalg.norm(x["error_deg"]) for x in errors], 95)

    from adfusion.app.replay import replay

    replay(sim, tmp_path / "replay.mcap", progress=False)
    n_live, inside_live, p95_live = scored(out)
    _, inside_replay, p95_replay = scored(tmp_path / "replay.mcap")
    assert n_live == rec["frames_taken"] >= 80
    assert inside_live >= inside_replay - 0.05 and p95_live <= 1.5 * p95_replay
    # its report says it was live: the title, the live line, the latency plot
    assert main(["report", str(out), "-o", str(tmp_path / "rep")]) == 0
    summary = (tmp_path / "rep" / "summary.md").read_text()
    assert summary.startswith("# Live report") and "taken by the solver" in summary
    assert (tmp_path / "rep" / "latency.png").stat().st_size > 0
    assert main(["report", str(tmp_path / "replay.mcap"), "-o", str(tmp_path / "rep2")]) == 0
    assert not (tmp_path / "rep2" / "latency.png").exists()
    assert (tmp_path / "rep2" / "summary.md").read_text().startswith("# Replay report")


def test_the_solver_slot_keeps_the_newest_frame_and_counts_the_rest():
    clock = LiveClock()
    src = LiveSource(clock, max_frames=2)
    img = np.zeros((4, 4), np.uint8)
    for k in range(5):
        src.offer_frame(0.1 * k, img, 0.0)
    it = iter(src)
    first = next(it)
    assert first.t_s == pytest.approx(0.4) and src.dropped == 4
    src.offer_frame(0.5, img, 0.0)
    assert next(it).t_s == pytest.approx(0.5)
    assert list(it) == [] and src.ended_by == "2 frames" and src.arrived == 6


def test_imu_samples_go_before_the_frame_of_a_later_time():
    """A frame at t = 1.0 arriving after samples of t = 0.9 and 1.1: the samples up to its
    time go first, the later one after it, so the filter never meets time going back."""
    clock = LiveClock()
    src = LiveSource(clock, max_frames=1)
    src.offer_other(parse_imu_line(f"{clock.unix0 + 0.9},0,0,0.1", ["t_s", "gyro_x",
                                                                    "gyro_y", "gyro_z"],
                                   clock.unix0))
    src.offer_other(parse_imu_line(f"{clock.unix0 + 1.1},0,0,0.1", ["t_s", "gyro_x",
                                                                    "gyro_y", "gyro_z"],
                                   clock.unix0))
    src.offer_frame(1.0, np.zeros((4, 4), np.uint8), 0.0)
    assert [round(m.t_s, 6) for m in src] == [0.9, 1.0, 1.1]
    assert IMU_HOLD_S > 0


def test_imu_lines_appended_to_a_file_and_sent_over_udp_arrive_in_order(tmp_path):
    clock = LiveClock()
    path = tmp_path / "imu.csv"
    path.write_text("t_s,gyro_x,gyro_y,gyro_z,mag_x,mag_y,mag_z\n0,0,0,0,,,\n")  # old line
    src = LiveSource(clock)
    feed = ImuFileFeed(path)
    udp = ImuUdpFeed("127.0.0.1:0")
    got = []
    src.offer_other = got.extend  # what the feeds hand on
    feed.start(src)
    udp.start(src)
    try:
        now = clock.unix0 + clock.now()
        with open(path, "a") as f:
            f.write(f"{now},0.1,0,0,2e4,0,-4e4\n{now + 0.01},0.2,0,")  # the second half-written
            f.flush()
            time.sleep(0.1)
            f.write("0,,,\nnot,a,row,here\n")
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(f"{now + 0.02},0.3,0,0\n{now + 0.03},0.4,0,0,1,2,3".encode(),
                     ("127.0.0.1", udp.port))
        t0 = time.monotonic()
        while len(got) < 6 and time.monotonic() - t0 < 5:
            time.sleep(0.02)
    finally:
        feed.stop()
        udp.stop()
    gyro = sorted((m.t_s, m.payload["omega"][0]) for m in got if m.topic == topics.GYRO)
    assert [w for _, w in gyro] == [0.1, 0.2, 0.3, 0.4]
    assert [m.payload["b_body"] for m in got if m.topic == topics.MAG] == [
        [2e4, 0.0, -4e4], [1.0, 2.0, 3.0]]
    assert len(feed.bad) == 1 and "t_s 'not'" in feed.bad[0]


def test_imu_lines_not_in_unix_seconds_are_dropped_and_counted(tmp_path):
    clock = LiveClock()
    path = tmp_path / "imu.csv"
    path.write_text("t_s,gyro_x,gyro_y,gyro_z\n")
    src = LiveSource(clock)
    feed = ImuFileFeed(path)
    got = []
    src.offer_other = got.extend
    feed.start(src)
    try:
        with open(path, "a") as f:
            f.write("12.5,0.1,0,0\n")  # seconds since boot, not Unix time
        t0 = time.monotonic()
        while not feed.bad and time.monotonic() - t0 < 5:
            time.sleep(0.02)
    finally:
        feed.stop()
    assert got == [] and "not a Unix time" in feed.bad[0]
    src.imu_feed = feed
    assert any("1 IMU line(s) dropped" in p for p in src.problems)


def test_a_video_stream_through_opencv_is_a_camera(tmp_path):
    """A stream opened by URL (``file:`` here; ``rtsp://`` at a telescope) through the
    camera feed: frames arrive as grey images, stamped when grabbed, and the feed ends
    when the stream does."""
    import cv2

    from adfusion.app.live.feeds import CameraFeed

    path = tmp_path / "v.avi"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    for k in range(5):
        w.write(np.full((48, 64, 3), 20 * k, np.uint8))
    w.release()
    clock = LiveClock()
    src = LiveSource(clock)
    feed = CameraFeed(f"file:{path}")
    frames = []
    src.offer_frame = lambda t, img, arrived, name="": frames.append((t, img))
    ended = threading.Event()
    src.feed_ended = lambda f, why: ended.set()
    feed.start(src)
    assert ended.wait(10)
    assert len(frames) == 5 and frames[0][1].shape == (48, 64) and frames[0][1].ndim == 2
    assert all(b[0] >= a[0] for a, b in itertools.pairwise(frames))


@pytest.mark.parametrize("argv, says", [
    (["DIR", "--fov", "20", "--fps", "10"], "--realtime"),
    (["7", "--fov", "20"], "cannot open this camera"),
    (["DIR"], "--camera"),
    (["DIR", "--fov", "20", "--frames", "0"], "--frames 0"),
    (["nowhere/frames", "--fov", "20"], "no such folder"),
    (["FILE", "--fov", "20"], "give --realtime"),
])
def test_live_usage_errors_are_one_line_exit_2(tmp_path, capsys, argv, says):
    from adfusion.app.cli import main

    (tmp_path / "in").mkdir()
    (tmp_path / "v.avi").write_bytes(b"not really")
    argv = [str(tmp_path / "in") if a == "DIR" else str(tmp_path / "v.avi") if a == "FILE"
            else a for a in argv]
    code = main(["live", *argv, "--no-view", "-o", str(tmp_path / "o.mcap")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and says in err[0], err
    assert not (tmp_path / "o.mcap").exists()


def test_a_port_in_use_names_the_fix(tmp_path, capsys):
    from adfusion.app.cli import main

    (tmp_path / "in").mkdir()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        code = main(["live", str(tmp_path / "in"), "--fov", "20", "--port", str(port),
                     "-o", str(tmp_path / "o.mcap")])
    err = capsys.readouterr().err
    assert code == 2 and "--port" in err and "in use" in err, err
    assert not os.path.exists(tmp_path / "o.mcap")


def test_the_imu_of_a_live_run_is_used(tmp_path):
    """Review of issue 36: ``--imu`` was read and never used (the gyro switched off before
    its feed existed). A still sky and a gyro at rest, each line in Unix seconds: the
    gyro's samples are used by the filter."""
    from adfusion.starid.camera.model import Camera

    from adfusion.app.live import LiveOptions, live
    from adfusion.app.replay import ReplayOptions

    folder = tmp_path / "in"
    folder.mkdir()
    imu = tmp_path / "imu.csv"
    imu.write_text("t_s,gyro_x,gyro_y,gyro_z\n")
    stop = threading.Event()

    def log_imu() -> None:
        with open(imu, "a") as f:
            while not stop.is_set():
                f.write(f"{time.time():.6f},0,0,0\n")
                f.flush()
                time.sleep(0.01)

    def write_frames() -> None:
        time.sleep(3.0)  # after the setup
        (tmp_path / "go").touch()
        subprocess.run([sys.executable, "-P", str(WRITER), str(folder), "--slow", "4",
                        "--interval", "0.3", "--still"], check=True, timeout=120)

    threads = [threading.Thread(target=f, daemon=True) for f in (log_imu, write_frames)]
    for t in threads:
        t.start()
    try:
        s = live(str(folder), tmp_path / "live.mcap",
                 LiveOptions(imu=str(imu), idle_s=4.0, view=None),
                 ReplayOptions(camera=Camera.pinhole(640, 480, 20.0), assume_defaults=True))
    finally:
        stop.set()
    assert s.streams["gyro"]["used"] > 50, s.streams
    assert s.identified >= 3 and _metadata(tmp_path / "live.mcap", "replay")["use_gyro"]


def test_imu_samples_wait_for_a_frame_being_read():
    """Review of issue 36: a frame seen on disk at t but decoded 150 ms later met IMU
    samples of t + 100 ms already handed on, and the filter refused it ('time went
    backwards'). A frame being read holds back the samples after its time."""
    clock = LiveClock()
    src = LiveSource(clock, max_frames=1)
    t0 = clock.now()
    src.frame_pending("f.png", t0)
    src.offer_other(parse_imu_line(f"{clock.unix0 + t0 + 0.01},0,0,0.1",
                                   ["t_s", "gyro_x", "gyro_y", "gyro_z"], clock.unix0))
    got: list = []
    reader = threading.Thread(target=lambda: got.extend(src), daemon=True)
    reader.start()
    time.sleep(IMU_HOLD_S + 0.15)  # the sample is old enough to go, but the frame is not in
    assert got == []
    src.offer_frame(t0, np.zeros((4, 4), np.uint8), 0.0, "f.png")
    reader.join(5)
    assert [m.topic for m in got] == [topics.CAMERA_IMAGE, topics.GYRO]


def test_a_file_written_again_under_its_name_is_a_new_frame(tmp_path):
    """Review of issue 36: a camera program that renames each new frame onto
    ``latest.png`` gave one frame in all."""
    import cv2

    from adfusion.app.live import LiveOptions, live
    from adfusion.app.replay import ReplayOptions

    folder = tmp_path / "in"
    folder.mkdir()
    rng = np.random.default_rng(0)

    def write() -> None:
        time.sleep(3.0)
        for _ in range(3):
            tmp = folder / ".latest.png"
            cv2.imwrite(str(tmp), rng.integers(0, 30, (48, 64), np.uint8))
            os.replace(tmp, folder / "latest.png")
            time.sleep(0.5)

    threading.Thread(target=write, daemon=True).start()
    s = live(str(folder), tmp_path / "live.mcap", LiveOptions(idle_s=2.0, view=None),
             ReplayOptions(fov_deg=20.0))
    assert s.live["frames_arrived"] == 3


def test_live_with_fov_and_no_frame_ends_at_its_duration(tmp_path, capsys):
    """Review of issue 36: with --fov the setup waited for a first frame for ever, past
    --duration. It now ends there, saying so (nothing done: exit 2)."""
    from adfusion.app.cli import main

    (tmp_path / "in").mkdir()
    t0 = time.monotonic()
    code = main(["live", str(tmp_path / "in"), "--fov", "20", "--duration", "2", "--no-view",
                 "-o", str(tmp_path / "o.mcap")])
    assert code == 2 and time.monotonic() - t0 < 30
    assert "no frame in" in capsys.readouterr().err


def test_a_failed_setup_lets_go_of_the_feeds(tmp_path):
    """Review of issue 36: a feed opened before a later step failed (a port in use) kept
    its socket (or camera) open. It is released: the same UDP port binds again."""
    from adfusion.app.live import LiveOptions, live
    from adfusion.app.replay import ReplayOptions

    (tmp_path / "in").mkdir()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
        u.bind(("127.0.0.1", 0))
        udp_port = u.getsockname()[1]
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        with pytest.raises(ValueError, match="in use"):
            live(str(tmp_path / "in"), tmp_path / "o.mcap",
                 LiveOptions(imu=f"udp://127.0.0.1:{udp_port}",
                             view=("127.0.0.1", busy.getsockname()[1])),
                 ReplayOptions(fov_deg=20.0))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as again:
        again.bind(("127.0.0.1", udp_port))


def test_a_failing_tee_costs_the_log_nothing(tmp_path):
    """Review of issue 36: the log handed each message to the live view before writing
    it, so a view that failed lost it from the file too."""
    from adfusion.logs import McapLogReader
    from adfusion.logs.writer import LogWriter

    class Broken:
        def channel(self, *args):
            return "ch"

        def message(self, handle, t, data):
            raise RuntimeError("client went away")

    with LogWriter(tmp_path / "a.mcap", tee=Broken()) as log:
        for k in range(3):
            log.write_json("/imu/gyro", 0.1 * k, {"omega": [0.0, 0.0, float(k)]})
        assert log.tee_error == "RuntimeError: client went away"
    got = [m.payload["omega"][2] for m in McapLogReader(tmp_path / "a.mcap")]
    assert got == [0.0, 1.0, 2.0]


@pytest.mark.parametrize("library_path", [False, True])
def test_the_tee_gets_the_very_bytes_of_the_file(tmp_path, library_path):
    """A frame is written in pieces (header, pixels, trailer). On mcap's own writing path
    (the fallback when our appender does not fit the installed mcap) the pieces were
    joined for the file and then joined again for the tee: the view got the pixels twice."""
    from adfusion.logs.writer import LogWriter
    from mcap.reader import make_reader

    class Recording:
        def __init__(self):
            self.got = []

        def channel(self, topic, *args):
            return topic

        def message(self, topic, t, data):
            self.got.append((topic, t, bytes(data)))

    tee = Recording()
    with LogWriter(tmp_path / "a.mcap", tee=tee) as log:
        if library_path:
            log._appender = None  # as when _MessageAppender.of finds another mcap
        log.write_image(0.5, np.arange(48, dtype=np.uint8).reshape(6, 8))
    with open(tmp_path / "a.mcap", "rb") as f:
        on_file = [(ch.topic, m.log_time, bytes(m.data))
                   for _, ch, m in make_reader(f).iter_messages()]
    assert tee.got == on_file and len(on_file) == 1
