"""Reads a pipeline recording with the PyPI `mcap` reader (independent of
our Rust code) and checks its channels, schemas, message counts and that the
Foxglove channels decode with the official Foxglove protobuf schemas.

Usage: check_recording.py RECORDING.mcap EXPECTED_COUNTS_JSON
"""
import json
import sys
from collections import Counter

from mcap.reader import make_reader
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

path, expected = sys.argv[1], json.loads(sys.argv[2])

LOSSLESS = {
    "frames": "mirror.StereoFrame.v2",
    "detections": "mirror.StereoDetections.v2",
    "joint_state": "mirror.JointState.v1",
    "samples": "mirror.MirrorSample.v1",
    "calibration": "mirror.Calibration.v3",
    "predictions": "mirror.Prediction.v1",
    "located": "mirror.LocatedObject.v2",
    "joint_positions": "mirror.JointPositions.v1",
    "pose_goal": "mirror.PoseGoal.v1",
}
VIEW = {
    "/camera/left/image": RawImage,
    "/camera/right/image": RawImage,
    "/camera/left/detections": ImageAnnotations,
    "/camera/right/detections": ImageAnnotations,
    "/camera/left/predictions": ImageAnnotations,
    "/camera/right/predictions": ImageAnnotations,
    "/camera/left/calibration": CameraCalibration,
    "/camera/right/calibration": CameraCalibration,
    "/tf": FrameTransforms,
    "/mirror/tf": FrameTransforms,
    "/scene": SceneUpdate,
    "/mirror/scene": SceneUpdate,
}

with open(path, "rb") as f:
    reader = make_reader(f)
    summary = reader.get_summary()
    assert summary is not None, "no summary section"
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == set(LOSSLESS) | set(VIEW), sorted(channels)
    for topic, type_name in LOSSLESS.items():
        c = channels[topic]
        schema = summary.schemas[c.schema_id]
        assert (schema.name, schema.encoding, c.message_encoding) == (
            type_name, "x-mirror-layout+json", "x-mirror-repr-c"), (topic, schema.name)
        layout = json.loads(schema.data)
        assert layout["type_name"] == type_name and layout["size"] > 0, layout
    for topic, cls in VIEW.items():
        c = channels[topic]
        schema = summary.schemas[c.schema_id]
        official = cls.DESCRIPTOR.full_name
        assert (schema.name, schema.encoding, c.message_encoding) == (
            official, "protobuf", "protobuf"), (topic, schema.name, official)
    assert all(ci.compression == "zstd" for ci in summary.chunk_indexes), "chunks not zstd"
    assert len(summary.chunk_indexes) > 1, "not chunked"
    metadata = {m.name for m in summary.metadata_indexes}
    assert {"run", "layouts", "rig"} <= metadata, metadata
    attachments = {a.name for a in summary.attachment_indexes}
    assert {"rig.toml", "plan.csv"} <= attachments, attachments

    counts = Counter()
    decoded = Counter()
    images = annotated = 0
    for schema, channel, message in reader.iter_messages():
        counts[channel.topic] += 1
        cls = VIEW.get(channel.topic)
        if cls is None:
            continue
        m = cls.FromString(message.data)
        decoded[channel.topic] += 1
        if cls is RawImage:
            assert (m.width, m.height, m.encoding) == (640, 480, "mono8"), (m.width, m.height, m.encoding)
            assert len(m.data) == m.step * m.height
            assert m.timestamp.seconds * 10**9 + m.timestamp.nanos == message.log_time
            images += 1
        elif cls is ImageAnnotations and "detections" in channel.topic:
            annotated += len(m.points)
            for p in m.points:
                assert len(p.points) == 4
        elif cls is CameraCalibration:
            assert len(m.K) == 9 and m.K[0] > 0 and m.distortion_model == "plumb_bob"
        elif cls is FrameTransforms:
            for t in m.transforms:
                q = t.rotation
                assert abs(q.x**2 + q.y**2 + q.z**2 + q.w**2 - 1) < 1e-9

for topic, n in expected.items():
    assert counts[topic] == n, f"{topic}: {counts[topic]} in the file, {n} published"
assert counts["located"] > 0
stats = summary.statistics.channel_message_counts
for cid, n in stats.items():
    topic = summary.channels[cid].topic
    assert counts[topic] == n, f"{topic}: statistics say {n}, read {counts[topic]}"
assert counts["/camera/left/image"] == counts["frames"] == images / 2
assert annotated > 0
print(f"independent reader: {sum(counts.values())} messages on {len(counts)} channels; "
      f"{sum(decoded.values())} Foxglove messages decoded with the official schemas; "
      f"counts equal to the stages' own: {json.dumps(expected)}")
