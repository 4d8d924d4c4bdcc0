"""Write one of our logs as a ROS 2 bag (rosbag2, MCAP storage) with ``rosbags``, an
independent writer: ``sensor_msgs/msg/Image`` (mono8/mono16) on ``/camera/image_raw``,
``CameraInfo`` on ``/camera/camera_info``, ``Imu`` (angular velocity, rad/s) on
``/imu/data`` and ``MagneticField`` (tesla) on ``/imu/mag``; header stamps and log times
are UTC (the log's start plus run time). ``adfusion simulate … --ros2 DIR`` uses it.

Needs ``rosbags`` (``pip install 'rosbags>=0.10,<1'``; in the ``test`` extra).

Example:
    >>> import os, tempfile
    >>> from adfusion.sensors.scenarios import oedipus
    >>> from adfusion.app.replay import simulate
    >>> from adfusion.app.ros2bag import write_ros2_bag
    >>> d = tempfile.mkdtemp()
    >>> _ = simulate(oedipus(duration_s=0.1, render=True), os.path.join(d, "s.mcap"))
    >>> write_ros2_bag(os.path.join(d, "s.mcap"), os.path.join(d, "bag"))
    {'/imu/data': 20, '/imu/mag': 5, '/camera/image_raw': 3, '/camera/camera_info': 1}
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from adfusion.logs import McapLogReader, topics

__all__ = ["write_ros2_bag"]


def write_ros2_bag(mcap_path: str | os.PathLike[str], out_dir: str | os.PathLike[str]) -> dict:
    """Convert ``mcap_path`` (images, gyro, magnetometer, camera model) into a rosbag2
    folder ``out_dir`` (must not exist); returns the message count per topic."""
    try:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise ValueError("writing a ROS 2 bag needs rosbags (pip install 'rosbags>=0.10,<1')") \
            from None
    if Path(out_dir).exists():
        raise ValueError(f"{out_dir} exists: rosbag2 writes a new folder")
    reader = McapLogReader(mcap_path)
    model = reader.camera_model()
    offset = reader.clock_offset_ns
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Vec3, Quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    zeros9 = np.zeros(9)

    def header(t_ns: int, frame: str):
        return Header(stamp=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id=frame)

    counts: dict[str, int] = {}
    with Writer(out_dir, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {}

        def write(topic: str, msgtype: str, msg, t_ns: int) -> None:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=ts)
            w.write(conns[topic], t_ns, ts.serialize_cdr(msg, msgtype))
            counts[topic] = counts.get(topic, 0) + 1

        for m in reader:
            t_ns = offset + round(m.t_s * 1e9)
            if m.topic == topics.CAMERA_IMAGE:
                img = np.ascontiguousarray(m.payload)
                enc = "mono16" if img.dtype == np.uint16 else "mono8"
                write("/camera/image_raw", "sensor_msgs/msg/Image", T["sensor_msgs/msg/Image"](
                    header=header(t_ns, "camera"), height=img.shape[0], width=img.shape[1],
                    encoding=enc, is_bigendian=0, step=img.shape[1] * img.itemsize,
                    data=img.view(np.uint8).reshape(-1)), t_ns)
            elif m.topic == topics.GYRO:
                write("/imu/data", "sensor_msgs/msg/Imu", T["sensor_msgs/msg/Imu"](
                    header=header(t_ns, "body"),
                    orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.array([-1.0] + [0.0] * 8),  # not measured
                    angular_velocity=Vec3(*(float(v) for v in m.payload["omega"])),
                    angular_velocity_covariance=zeros9,
                    linear_acceleration=Vec3(x=0.0, y=0.0, z=0.0),
                    linear_acceleration_covariance=np.array([-1.0] + [0.0] * 8)), t_ns)
            elif m.topic == topics.MAG:
                b = [1e-9 * float(v) for v in m.payload["b_body"]]
                write("/imu/mag", "sensor_msgs/msg/MagneticField",
                      T["sensor_msgs/msg/MagneticField"](
                          header=header(t_ns, "body"), magnetic_field=Vec3(*b),
                          magnetic_field_covariance=zeros9), t_ns)
        if model is not None:
            K = np.asarray(model["K"], float)
            P = np.hstack([K, np.zeros((3, 1))]).reshape(-1)
            write("/camera/camera_info", "sensor_msgs/msg/CameraInfo",
                  T["sensor_msgs/msg/CameraInfo"](
                      header=header(offset, "camera"), height=int(model["height"]),
                      width=int(model["width"]), distortion_model="plumb_bob",
                      d=np.asarray(model["D"], float), k=K.reshape(-1),
                      r=np.eye(3).reshape(-1), p=P, binning_x=0, binning_y=0,
                      roi=T["sensor_msgs/msg/RegionOfInterest"](
                          x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)),
                  offset)
    return counts
