"""A replay's filter estimates as a ROS 2 bag (rosbag2, MCAP storage), written with
``rosbags`` — ``adfusion export LOG --ros2 DIR``.

One message per estimate (``/estimate/state``, or ``/smoothed/state`` with ``smoothed``) on
each of two topics, header stamp and bag time the estimate's UTC (the log's start plus its
run time ``t``, to the nanosecond):

* ``/adfusion/imu`` — ``sensor_msgs/msg/Imu``, ``frame_id = "body"``: the orientation of the
  body in ``icrs``, its covariance, the estimated body rate when the filter has one.
* ``/adfusion/pose`` — ``geometry_msgs/msg/PoseWithCovarianceStamped``,
  ``frame_id = "icrs"``: the same orientation, position 0, a 6×6 covariance.

Frames are the MCAP log's (its ``/tf`` is ``icrs`` → ``body``): ``icrs`` is the ICRS axes at
the body's origin (a pure rotation, no translation), ``body`` the payload's.

Conventions (see :func:`write_ros2_estimates` for the reasons):

* orientation: ROS gives the orientation of the child (``body``) in the parent (``icrs``):
  a quaternion that rotates body-frame vectors into the parent frame, ``q_icrs_body`` —
  the conjugate of the log's ``q_body_icrs`` — written ``x, y, z, w`` (w ≥ 0).
* orientation covariance: about the fixed (``icrs``) axes, rad², both topics:
  ``R_icrs_body · P_body · R_icrs_bodyᵀ`` with ``P_body`` the log's attitude block (error
  δθ about the body axes, DESIGN.md).
* position: 0 with variance :data:`POSITION_VARIANCE_M2` (not estimated).

Needs ``rosbags`` (``pip install rosbags``; in the ``test`` extra).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from adfusion.app.errors import UsageError
from adfusion.maths import rotations as rot
from adfusion.outfiles import note_written

__all__ = ["IMU_TOPIC", "POSE_TOPIC", "POSITION_VARIANCE_M2", "attitude_cov_icrs",
           "q_icrs_body_xyzw", "write_ros2_estimates"]

IMU_TOPIC = "/adfusion/imu"
POSE_TOPIC = "/adfusion/pose"
BODY_FRAME = "body"
ICRS_FRAME = "icrs"
POSITION_VARIANCE_M2 = 1e12
"""Variance of the (unestimated) position, m², on the pose's diagonal: large (σ = 1000 km),
not 0, because a consumer reads 0 as "known exactly" (infinite weight, a singular matrix to
invert) and ROS has no "unknown" mark for a pose covariance."""

MISSING = "--ros2 needs the rosbags package: pip install rosbags"


def q_icrs_body_xyzw(q_body_icrs: np.ndarray) -> np.ndarray:
    """The ROS orientation ``[x, y, z, w]`` (N, 4) of the body in ``icrs`` for the log's
    ``q_body_icrs`` ``[w, x, y, z]`` (N, 4).

    A ROS orientation (REP 103/105, tf) is that of the child frame in the parent: it rotates
    vectors given in the child (body) frame into the parent frame, i.e. ``v_icrs =
    R(q) v_body`` — ``q_icrs_body`` in our naming, the conjugate of ``q_body_icrs``
    (which rotates ICRS vectors into the body frame). Conjugating keeps ``w``, so w ≥ 0
    stays."""
    q = rot.canonical(np.atleast_2d(np.asarray(q_body_icrs, dtype=float)))
    q_icrs_body = rot.conjugate(q)
    return q_icrs_body[:, [1, 2, 3, 0]]


def attitude_cov_icrs(q_body_icrs: np.ndarray, p_body: np.ndarray) -> np.ndarray:
    """The attitude covariance (N, 3, 3) about the fixed ``icrs`` axes, from ``p_body``
    (N, 3, 3) about the body axes: ``R_body_true = Exp(δθ) R_body_est`` gives
    ``R_icrs_body_true = Exp(−R_icrs_body δθ) R_icrs_body_est``, a left (fixed-axis)
    perturbation ``−R_icrs_body δθ`` of the ROS orientation, covariance
    ``R_icrs_body P_body R_icrs_bodyᵀ``."""
    r_icrs_body = np.swapaxes(rot.to_matrix(np.atleast_2d(q_body_icrs)), -1, -2)
    return r_icrs_body @ p_body @ np.swapaxes(r_icrs_body, -1, -2)


def _blocks(h) -> tuple[np.ndarray, np.ndarray]:
    """Per estimate the body-axes 3×3 attitude block and the 3×3 block of the last three
    states: from the log's full ``cov``, else the diagonal of ``var`` (an older log, the
    smoother); NaN where neither is known."""
    cov, var, full = h.cov, h.var, h.full_cov
    att = np.where(full[:, None, None], cov[:, :3, :3],
                   np.eye(3) * var[:, None, :3])
    rest = np.where(full[:, None, None], cov[:, 3:, 3:],
                    np.eye(3) * var[:, None, 3:])
    nan_att = ~np.all(np.isfinite(var[:, :3]), axis=1) & ~full
    nan_rest = ~np.all(np.isfinite(var[:, 3:]), axis=1) & ~full
    att[nan_att] = np.nan
    rest[nan_rest] = np.nan
    return att, rest


def write_ros2_estimates(h, out_dir: str | os.PathLike[str]) -> dict[str, int]:
    """Write the estimates of ``h`` (an :class:`adfusion.app.export.AttitudeHistory`) as a
    rosbag2 folder ``out_dir`` (must not exist); returns the message count per topic.

    Decisions, and why:

    * **Orientation** is ``q_icrs_body`` (:func:`q_icrs_body_xyzw`): ROS quaternions give
      the child frame's orientation in the parent, rotating child-frame vectors into the
      parent. The Imu message has one ``frame_id``, the sensor's (``body``, where its
      angular velocity is), and REP 145 puts its orientation relative to a fixed world
      frame: here ``icrs``. The pose's ``frame_id`` is that parent, ``icrs``.
    * **Orientation covariance about the fixed axes** (:func:`attitude_cov_icrs`), on both
      topics. ``geometry_msgs/PoseWithCovariance`` says so: "the orientation parameters use
      a fixed-axis representation" (rotation about the parent's X, Y, Z), and tf2 rotates
      a pose covariance into a new parent like a vector in the header frame. The Imu
      definition only says "Row major about x, y, z axes"; its reading in ROS tools
      (``imu_pipeline``'s ``imu_transformer`` leaves the orientation covariance alone when
      changing the sensor frame: it is about the world axes) is the same, so one covariance
      serves both topics. The log's is about the body axes (δθ in the body frame), so it is
      rotated: ``R_icrs_body P R_icrs_bodyᵀ``. From ``cov`` when the log has it, else the
      diagonal ``cov_diag`` (an older log, ``--smoothed``), rotated likewise (so no longer
      diagonal); all zeros ("covariance unknown") if neither is finite.
    * **Angular velocity**: the filter's rate ``omega`` (body relative to ICRS, body axes,
      rad/s) when the estimate has one (no gyro, or a gyro outage). Its covariance is the
      state's last 3×3 block when those states are the rate (no bias in the estimate),
      else all zeros ("unknown"). Without ``omega``: zeros and
      ``angular_velocity_covariance[0] = -1`` ("no estimate", as the message says).
      Not the gyro's reading: that is the input log's, ``adfusion simulate --ros2``.
    * **Linear acceleration**: none (no accelerometer): zeros, covariance ``[0] = -1``.
    * **Pose**: position 0 (``icrs`` is placed at the body, as the log's ``/tf`` does),
      covariance (x, y, z, rot x, rot y, rot z) with the fixed-axis attitude block in rows
      and columns 3–5 and :data:`POSITION_VARIANCE_M2` on the position diagonal, cross
      terms 0.

    The bag is written into a hidden folder beside ``out_dir`` and renamed into place
    when complete (its MCAP file is named after ``out_dir``, as a direct write names it)."""
    try:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise UsageError(MISSING) from None
    out = Path(out_dir)
    if os.path.lexists(out):
        raise UsageError(f"--ros2 {out} exists: a ROS 2 bag is written as a new folder; "
                         "give a name that does not exist")
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Vec3, Quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    Imu, Pose, Point = (T["sensor_msgs/msg/Imu"], T["geometry_msgs/msg/Pose"],
                        T["geometry_msgs/msg/Point"])
    PoseCov = T["geometry_msgs/msg/PoseWithCovariance"]
    PoseCovStamped = T["geometry_msgs/msg/PoseWithCovarianceStamped"]
    imu_type, pose_type = "sensor_msgs/msg/Imu", "geometry_msgs/msg/PoseWithCovarianceStamped"

    n = len(h.t)
    q_ros = q_icrs_body_xyzw(h.q_body_icrs)
    att_body, rest = _blocks(h)
    known = np.all(np.isfinite(att_body.reshape(n, -1)), axis=1)
    att = attitude_cov_icrs(h.q_body_icrs, np.where(known[:, None, None], att_body, 0.0))
    att = 0.5 * (att + np.swapaxes(att, -1, -2))  # symmetric to the last bit
    omega, bias = h.omega, h.bias
    has_omega = np.all(np.isfinite(omega), axis=1)
    rate_states = has_omega & ~np.all(np.isfinite(bias), axis=1)
    none9 = np.array([-1.0] + [0.0] * 8)

    parent = out.parent
    try:
        tmp = Path(tempfile.mkdtemp(prefix=".adf-", suffix=".tmp", dir=parent))
    except OSError as exc:  # the folder is the output's: name the output
        raise OSError(exc.errno, exc.strerror, os.fspath(out)) from None
    try:
        bag = tmp / out.name
        with Writer(bag, version=8, storage_plugin=StoragePlugin.MCAP) as w:
            imu_c = w.add_connection(IMU_TOPIC, imu_type, typestore=ts)
            pose_c = w.add_connection(POSE_TOPIC, pose_type, typestore=ts)
            for k in range(n):
                t_ns = h.start_utc_ns + round(float(h.t[k]) * 1e9)
                stamp = Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9)
                x, y, z, qw = (float(v) for v in q_ros[k])
                quat = Quat(x=x, y=y, z=z, w=qw)
                ocov = att[k].reshape(-1) if known[k] else np.zeros(9)
                if has_omega[k]:
                    wv = Vec3(*(float(v) for v in omega[k]))
                    r = rest[k]
                    wcov = (r.reshape(-1).copy() if rate_states[k] and np.all(np.isfinite(r))
                            else np.zeros(9))
                else:
                    wv, wcov = Vec3(x=0.0, y=0.0, z=0.0), none9.copy()
                imu = Imu(header=Header(stamp=stamp, frame_id=BODY_FRAME), orientation=quat,
                          orientation_covariance=np.ascontiguousarray(ocov, dtype=float),
                          angular_velocity=wv, angular_velocity_covariance=wcov,
                          linear_acceleration=Vec3(x=0.0, y=0.0, z=0.0),
                          linear_acceleration_covariance=none9.copy())
                w.write(imu_c, t_ns, ts.serialize_cdr(imu, imu_type))
                pcov = np.zeros((6, 6))
                pcov[:3, :3] = np.eye(3) * POSITION_VARIANCE_M2
                if known[k]:
                    pcov[3:, 3:] = att[k]
                pose = PoseCovStamped(
                    header=Header(stamp=stamp, frame_id=ICRS_FRAME),
                    pose=PoseCov(pose=Pose(position=Point(x=0.0, y=0.0, z=0.0),
                                           orientation=quat), covariance=pcov.reshape(-1)))
                w.write(pose_c, t_ns, ts.serialize_cdr(pose, pose_type))
        if os.path.lexists(out):  # appeared while writing: not ours to replace
            raise UsageError(f"--ros2 {out} appeared while the bag was written; not replaced")
        os.rename(bag, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    note_written(out)
    return {IMU_TOPIC: n, POSE_TOPIC: n}
