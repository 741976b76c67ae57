"""Encodes one example message of each type the ros2 stage speaks with
rosbags' CDR codec (Jazzy definitions), and prints {type: hex} as JSON.
The Rust test builds the same values and compares bytes both ways."""

import json

import numpy as np
from rosbags.typesys import Stores, get_typestore

S = get_typestore(Stores.ROS2_JAZZY)
T = S.types


def header(sec, nanosec, frame):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame)


def f64(values):
    return np.array(values, dtype=np.float64)


MESSAGES = {
    "sensor_msgs/msg/JointState": T["sensor_msgs/msg/JointState"](
        header=header(1, 2, "base"), name=["j1", "j2"], position=f64([0.5, -1.0]),
        velocity=f64([]), effort=f64([3.0])),
    "trajectory_msgs/msg/JointTrajectory": T["trajectory_msgs/msg/JointTrajectory"](
        header=header(0, 0, ""), joint_names=["shoulder", "elbow", "wrist"],
        points=[T["trajectory_msgs/msg/JointTrajectoryPoint"](
            positions=f64([0.1, 0.2, 0.3]), velocities=f64([]), accelerations=f64([]), effort=f64([]),
            time_from_start=T["builtin_interfaces/msg/Duration"](sec=0, nanosec=300000000))]),
    "sensor_msgs/msg/Image": T["sensor_msgs/msg/Image"](
        header=header(1700000000, 5, "left"), height=2, width=3, encoding="mono8", is_bigendian=0, step=3,
        data=np.array([0, 1, 2, 250, 251, 255], dtype=np.uint8)),
    "sensor_msgs/msg/CameraInfo": T["sensor_msgs/msg/CameraInfo"](
        header=header(7, 8, "left"), height=480, width=640, distortion_model="plumb_bob",
        d=f64([0.1, -0.2, 0.0, 0.0, 0.05]),
        k=f64([500.0, 0, 320.0, 0, 500.0, 240.0, 0, 0, 1]),
        r=f64([1, 0, 0, 0, 1, 0, 0, 0, 1]),
        p=f64([500.0, 0, 320.0, 0, 0, 500.0, 240.0, 0, 0, 0, 1, 0]),
        binning_x=0, binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=1, y_offset=2, height=3, width=4, do_rectify=True)),
    "tf2_msgs/msg/TFMessage": T["tf2_msgs/msg/TFMessage"](transforms=[
        T["geometry_msgs/msg/TransformStamped"](
            header=header(3, 4, "world"), child_frame_id="mirror",
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=0.1, y=0.2, z=0.3),
                rotation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.6, w=0.8)))]),
    "geometry_msgs/msg/PointStamped": T["geometry_msgs/msg/PointStamped"](
        header=header(9, 10, "world"), point=T["geometry_msgs/msg/Point"](x=-0.5, y=0.25, z=1.0)),
}

print(json.dumps({name: bytes(S.serialize_cdr(msg, name)).hex() for name, msg in MESSAGES.items()}))
