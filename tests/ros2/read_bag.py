"""Reads a rosbag2 bag with PyPI rosbags only (its rosbag2 reader: the
bag's metadata.yaml and its MCAP storage; its CDR codec) and prints what
it holds as JSON: per topic the type, hash, offered QoS and messages, the
images as their size, encoding and the CRC-32 of their pixels."""

import json
import sys
import zlib
from pathlib import Path

from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

STORE = get_typestore(Stores.ROS2_JAZZY)


def stamp(header):
    return header.stamp.sec * 10**9 + header.stamp.nanosec


def summary(msgtype, msg):
    if msgtype == "sensor_msgs/msg/JointState":
        return {"stamp": stamp(msg.header), "name": list(msg.name), "position": msg.position.tolist()}
    if msgtype == "sensor_msgs/msg/Image":
        return {"stamp": stamp(msg.header), "frame": msg.header.frame_id, "width": msg.width,
                "height": msg.height, "encoding": msg.encoding, "step": msg.step,
                "crc32": zlib.crc32(msg.data.tobytes())}
    if msgtype == "sensor_msgs/msg/CameraInfo":
        return {"stamp": stamp(msg.header), "k": msg.k.tolist(), "d": msg.d.tolist(),
                "model": msg.distortion_model, "width": msg.width, "height": msg.height}
    if msgtype == "tf2_msgs/msg/TFMessage":
        return [{"stamp": stamp(t.header), "parent": t.header.frame_id, "child": t.child_frame_id,
                 "t": [t.transform.translation.x, t.transform.translation.y, t.transform.translation.z],
                 "q": [t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
                       t.transform.rotation.w]} for t in msg.transforms]
    if msgtype == "geometry_msgs/msg/PointStamped":
        return {"stamp": stamp(msg.header), "p": [msg.point.x, msg.point.y, msg.point.z]}
    return None


def main():
    out = {"topics": {}}
    with Reader(Path(sys.argv[1])) as reader:
        out["message_count"] = reader.message_count
        for c in reader.connections:
            out["topics"][c.topic] = {
                "type": c.msgtype, "hash": c.digest, "count": c.msgcount,
                "durability": [str(q.durability.name).lower() for q in c.ext.offered_qos_profiles],
                "messages": [], "log_times": []}
        for connection, timestamp, raw in reader.messages():
            msg = STORE.deserialize_cdr(raw, connection.msgtype)
            topic = out["topics"][connection.topic]
            topic["messages"].append(summary(connection.msgtype, msg))
            topic["log_times"].append(timestamp)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
