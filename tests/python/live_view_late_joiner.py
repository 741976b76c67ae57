"""A Foxglove WebSocket client (the `websockets` package, independent of the
server's code) that joins the live view late, when nothing flows any more:
it subscribes to the state channels and must receive each one's current
message within 1 s of subscribing, decoded with the official schemas.

Usage: live_view_late_joiner.py PORT
"""
import asyncio
import sys
import time

import websockets
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_ws import message_data, subscribe

port = int(sys.argv[1])
WANTED = {
    "/mirror/tf": FrameTransforms,
    "/mirror/scene": SceneUpdate,
    "/camera/left/calibration": CameraCalibration,
    "/camera/right/calibration": CameraCalibration,
}


async def main():
    uri = f"ws://127.0.0.1:{port}"
    async with websockets.connect(uri, subprotocols=["foxglove.sdk.v1"]) as ws:
        subs, _channels = await subscribe(ws, list(WANTED))
        subscribed = time.monotonic()
        got = {}
        while set(got) != set(WANTED):
            left = 1.0 - (time.monotonic() - subscribed)
            if left <= 0:
                break
            try:
                data = await asyncio.wait_for(ws.recv(), left)
            except asyncio.TimeoutError:
                break
            got_data = message_data(data, subs)
            if got_data is None:
                continue
            topic, payload = got_data
            got.setdefault(topic, (WANTED[topic].FromString(payload), time.monotonic() - subscribed))
        missing = set(WANTED) - set(got)
        assert not missing, f"nothing within 1 s on {sorted(missing)}"
        frames = [t.child_frame_id for t in got["/mirror/tf"][0].transforms]
        assert "mirror" in frames and "mirror_camera_left" in frames, frames
        assert got["/mirror/scene"][0].entities, "an empty mirror scene"
        assert got["/camera/left/calibration"][0].width > 0
        slowest = max(ms for _, ms in got.values())
        print(f"late joiner: {sorted(got)} within {slowest * 1000:.0f} ms of subscribing")


asyncio.run(main())
