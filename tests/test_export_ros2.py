"""``adfusion export LOG --ros2 DIR``: the filter's estimates as a ROS 2 bag, read back with
``rosbags``' own reader and typestore (not our writer's code) to the log's numbers."""

from __future__ import annotations

import dataclasses
import importlib.util

import numpy as np
import pytest
from adfusion.logs import McapLogReader, topics
from adfusion.logs.writer import utc_ns
from adfusion.sensors.scenarios import oedipus

from adfusion.app.cli import main
from adfusion.app.export import read_attitude_history
from adfusion.app.export_ros2 import POSITION_VARIANCE_M2, write_ros2_estimates
from adfusion.app.replay import replay, simulate

pytest.importorskip("rosbags")
Rotation = pytest.importorskip("scipy.spatial.transform").Rotation


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A 2 s OEDIPUS flight (no rendering: star fixes from the catalogue), replayed."""
    d = tmp_path_factory.mktemp("ros2x")
    simulate(oedipus(duration_s=2.0, render=False, seed=1), d / "sim.mcap")
    replay(d / "sim.mcap", d / "out.mcap", progress=False)
    return d, _states(d / "out.mcap")


def _states(log):
    reader = McapLogReader(log)
    start = utc_ns(reader.start_utc or reader.metadata["config"]["start_utc"])
    states = [m.payload for m in reader if m.topic == topics.ESTIMATE_STATE]
    assert len(states) > 10
    return start, states


def _bag(path) -> dict[str, list[tuple[int, object]]]:
    """Every message of the bag per topic: (bag time, deserialized message)."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    out: dict[str, list] = {}
    with Reader(path) as r:
        assert r.connections and all(c.msgtype for c in r.connections)
        assert {f.suffix for f in path.iterdir()} == {".yaml", ".mcap"}
        for conn, t_ns, raw in r.messages():
            out.setdefault(conn.topic, []).append(
                (t_ns, conn.msgtype, ts.deserialize_cdr(raw, conn.msgtype)))
    return out


def _q_wxyz(q) -> np.ndarray:
    return np.array([q.w, q.x, q.y, q.z])


def _r_icrs_body(q_body_icrs) -> np.ndarray:
    """R_icrs_body by scipy (scalar last, active): the transpose of R(q_body_icrs)."""
    w, x, y, z = q_body_icrs
    return Rotation.from_quat([x, y, z, w]).as_matrix().T


def _close_up_to_sign(a, b) -> float:
    return min(np.abs(a - b).max(), np.abs(a + b).max())


def _stamp(header) -> int:
    return header.stamp.sec * 10**9 + header.stamp.nanosec


def _check_common(msgs, start, states, frame):
    assert len(msgs) == len(states)
    for (t_bag, _, m), s in zip(msgs, states, strict=True):
        want_ns = start + round(s["t"] * 1e9)
        assert _stamp(m.header) == want_ns and t_bag == want_ns
        assert m.header.frame_id == frame


def _orientation(m, s):
    """The ROS orientation is that of body in icrs: it takes body vectors into ICRS."""
    q = _q_wxyz(m.orientation if hasattr(m, "orientation") else m.pose.pose.orientation)
    q_body_icrs = np.array(s["q_body_icrs"])
    conj = q_body_icrs * [1, -1, -1, -1]
    assert _close_up_to_sign(q, conj) <= 1e-9
    v_body = np.array([0.3, -0.5, 0.8])
    ros = Rotation.from_quat([q[1], q[2], q[3], q[0]])  # scipy: x, y, z, w
    assert np.allclose(ros.apply(v_body), _r_icrs_body(q_body_icrs) @ v_body, atol=1e-9)


def _att_icrs(s, full=True) -> np.ndarray:
    p = (np.array(s["cov"], float).reshape(6, 6)[:3, :3] if full
         else np.diag(s["cov_diag"][:3]))
    r = _r_icrs_body(s["q_body_icrs"])
    return r @ p @ r.T


def _close_cov(got, want):
    assert np.allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())


def test_ros2_imu_orientation_covariance_and_stamps_are_the_logs(flight, tmp_path, capsys):
    d, (start, states) = flight
    bag = tmp_path / "bag"
    assert main(["export", str(d / "out.mcap"), "--ros2", str(bag)]) == 0
    assert "ROS 2 bag" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]  # no temporary left
    msgs = _bag(bag)
    assert set(msgs) == {"/adfusion/imu", "/adfusion/pose"}
    imu = msgs["/adfusion/imu"]
    assert {t for _, t, _ in imu} == {"sensor_msgs/msg/Imu"}
    _check_common(imu, start, states, "body")
    for (_, _, m), s in zip(imu, states, strict=True):
        _orientation(m, s)
        got = np.array(m.orientation_covariance).reshape(3, 3)
        _close_cov(got, _att_icrs(s))
        # a rotation of the body-axes block: the same trace
        body = np.array(s["cov"]).reshape(6, 6)[:3, :3]
        assert np.allclose(np.trace(got), np.trace(body), rtol=1e-12)
        # a gyro replay: the filter has no rate estimate; no accelerometer
        assert "omega" not in s or s["omega"] is None
        assert m.angular_velocity_covariance[0] == -1.0
        assert m.linear_acceleration_covariance[0] == -1.0
    # the rotation matters: some estimate's covariance is not isotropic, and differs
    aniso = [s for s in states
             if np.ptp(np.linalg.eigvalsh(np.array(s["cov"]).reshape(6, 6)[:3, :3]))
             > 1e-3 * np.array(s["cov"][0])]
    assert aniso
    s = aniso[-1]
    assert not np.allclose(_att_icrs(s), np.array(s["cov"]).reshape(6, 6)[:3, :3],
                           rtol=1e-3, atol=0.0)


def test_ros2_pose_holds_the_orientation_and_attitude_block(flight, tmp_path, capsys):
    d, (start, states) = flight
    bag = tmp_path / "bag"
    assert main(["export", str(d / "out.mcap"), "--ros2", str(bag)]) == 0
    capsys.readouterr()
    pose = _bag(bag)["/adfusion/pose"]
    assert {t for _, t, _ in pose} == {"geometry_msgs/msg/PoseWithCovarianceStamped"}
    _check_common(pose, start, states, "icrs")
    for (_, _, m), s in zip(pose, states, strict=True):
        _orientation(m, s)
        p = m.pose.pose.position
        assert (p.x, p.y, p.z) == (0.0, 0.0, 0.0)
        c = np.array(m.pose.covariance).reshape(6, 6)
        _close_cov(c[3:, 3:], _att_icrs(s))
        assert np.array_equal(c[:3, :3], np.eye(3) * POSITION_VARIANCE_M2)
        assert not c[:3, 3:].any() and not c[3:, :3].any()


def test_ros2_of_a_log_without_cov_rotates_the_diagonal(flight, tmp_path):
    d, (start, states) = flight
    h = read_attitude_history(d / "out.mcap")
    h = dataclasses.replace(h, cov=None)  # a log written before /estimate/state had cov
    write_ros2_estimates(h, tmp_path / "old")
    msgs = _bag(tmp_path / "old")
    _check_common(msgs["/adfusion/pose"], start, states, "icrs")
    for (_, _, m), (_, _, p), s in zip(msgs["/adfusion/imu"], msgs["/adfusion/pose"], states,
                                       strict=True):
        want = _att_icrs(s, full=False)
        _close_cov(np.array(m.orientation_covariance).reshape(3, 3), want)
        _close_cov(np.array(p.pose.covariance).reshape(6, 6)[3:, 3:], want)


def test_ros2_of_a_video_only_replay_carries_the_rate_and_its_covariance(flight, tmp_path,
                                                                         capsys):
    d, _ = flight
    out = tmp_path / "video.mcap"
    replay(d / "sim.mcap", out, progress=False, use_gyro=False)
    start, states = _states(out)
    assert all(s["bias"] is None and len(s["omega"]) == 3 for s in states)
    assert main(["export", str(out), "--ros2", str(tmp_path / "vbag")]) == 0
    capsys.readouterr()
    imu = _bag(tmp_path / "vbag")["/adfusion/imu"]
    _check_common(imu, start, states, "body")
    for (_, _, m), s in zip(imu, states, strict=True):
        w = m.angular_velocity
        assert np.array_equal([w.x, w.y, w.z], s["omega"])
        _close_cov(np.array(m.angular_velocity_covariance).reshape(3, 3),
                   np.array(s["cov"]).reshape(6, 6)[3:, 3:])
        _close_cov(np.array(m.orientation_covariance).reshape(3, 3), _att_icrs(s))


def test_ros2_onto_an_existing_folder_is_refused_before_any_work(flight, tmp_path, capsys):
    d, _ = flight
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "keep.txt").write_text("mine")
    csv = tmp_path / "o.csv"
    assert main(["export", str(d / "out.mcap"), "--csv", str(csv), "--ros2", str(bag)]) == 2
    err = capsys.readouterr().err
    assert "--ros2" in err and "exists" in err and len(err.strip().splitlines()) == 1
    assert [p.name for p in bag.iterdir()] == ["keep.txt"]
    assert (bag / "keep.txt").read_text() == "mine"
    assert not csv.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]
    # refused before the log is read: a log that does not exist is not even opened
    assert main(["export", str(tmp_path / "nolog.mcap"), "--ros2", str(bag)]) == 2
    assert "exists" in capsys.readouterr().err
    # a file there is refused alike
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["export", str(d / "out.mcap"), "--ros2", str(f)]) == 2
    assert f.read_text() == "x"
    capsys.readouterr()


def test_ros2_without_rosbags_is_one_line_naming_the_install(flight, tmp_path, capsys,
                                                             monkeypatch):
    d, _ = flight
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "rosbags" else real(name, *a))
    assert main(["export", str(d / "out.mcap"), "--ros2", str(tmp_path / "bag")]) == 2
    err = capsys.readouterr().err.strip()
    assert "pip install rosbags" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "bag").exists()
