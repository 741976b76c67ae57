"""A Foxglove WebSocket client (the `websockets` package, independent of the
server's code): connects to the live view, checks the advertised channels
and their schemas, subscribes to the detection overlays and the transforms,
and decodes what arrives with the official Foxglove protobuf schemas.

Usage: live_view_client.py PORT
"""
import asyncio
import sys

import websockets
from foxglove_ws import message_data, subscribe
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations

port = int(sys.argv[1])
WANTED = {"/camera/left/detections": ImageAnnotations, "/tf": FrameTransforms}


async def main():
    uri = f"ws://127.0.0.1:{port}"
    async with websockets.connect(uri, subprotocols=["foxglove.sdk.v1"]) as ws:
        subs, channels = await subscribe(ws, list(WANTED))
        for topic, cls in WANTED.items():
            c = channels[topic]
            assert c["encoding"] == "protobuf", c
            assert c["schemaName"] == cls.DESCRIPTOR.full_name, c
        got = {t: 0 for t in WANTED}
        markers = 0
        while min(got.values()) < 5:
            got_data = message_data(await asyncio.wait_for(ws.recv(), 10), subs)
            if got_data is None:
                continue
            topic, payload = got_data
            m = WANTED[topic].FromString(payload)
            got[topic] += 1
            if topic == "/camera/left/detections":
                markers += len(m.points)
        assert markers > 0, "no marker outlines arrived"
        print(f"live view: {got} messages decoded, {markers} marker outlines")


asyncio.run(main())
