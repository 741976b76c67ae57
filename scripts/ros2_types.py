"""Writes ros2_proc/ros2_types.json: for each ROS 2 message type the ros2
stage speaks, its RIHS01 type hash and its ros2msg definition (with its
dependencies, as rosbag2 stores it), both computed by rosbags from the
Jazzy message definitions. The hashes are never typed by hand.

    target/pyenv/bin/python scripts/ros2_types.py > ros2_proc/ros2_types.json
"""

import json
import sys

from rosbags.typesys import Stores, get_typestore

TYPES = [
    "sensor_msgs/msg/JointState",
    "trajectory_msgs/msg/JointTrajectory",
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/CameraInfo",
    "tf2_msgs/msg/TFMessage",
    "geometry_msgs/msg/PointStamped",
]


def main():
    store = get_typestore(Stores.ROS2_JAZZY)
    table = {
        name: {
            "rihs01": store.hash_rihs01(name),
            "ros2msg": store.generate_msgdef(name, ros_version=2)[0],
        }
        for name in TYPES
    }
    json.dump({"source": "rosbags Stores.ROS2_JAZZY", "types": table}, sys.stdout, indent=1, sort_keys=True)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
