"""What the live-view clients share: subscribing to channels by topic over
the Foxglove WebSocket protocol, and reading message-data frames."""
import asyncio
import json
import struct


async def subscribe(ws, topics):
    """Waits until every topic in `topics` is advertised, subscribes to them,
    and returns ({subscription id: topic}, {topic: advertised channel})."""
    channels = {}
    while not set(topics) <= set(channels):
        msg = json.loads(await asyncio.wait_for(ws.recv(), 10))
        if msg.get("op") == "advertise":
            for c in msg["channels"]:
                channels[c["topic"]] = c
    subs = {i + 1: topic for i, topic in enumerate(topics)}
    await ws.send(json.dumps({
        "op": "subscribe",
        "subscriptions": [{"id": i, "channelId": channels[t]["id"]} for i, t in subs.items()],
    }))
    return subs, channels


def message_data(data, subs):
    """(topic, payload) of a binary message-data frame, else None."""
    if isinstance(data, str) or data[0] != 1:  # 1 = message data
        return None
    sub, _log_time = struct.unpack_from("<IQ", data, 1)
    return subs[sub], data[13:]
