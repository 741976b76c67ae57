"""A stand-in ROS 2 stereo camera on rmw_zenoh's wire, with PyPI
eclipse-zenoh and rosbags only (nothing of ours encodes here).

It reads the grey stereo pairs in --dir (`manifest.json`: width, height,
pairs; `NNN_left.gray` / `NNN_right.gray`, raw bytes) and, once told `go`
on stdin and once it sees our subscriptions' liveliness tokens, publishes
each pair as two sensor_msgs/Image, the right stamped 1 ms after the left,
in turn mono8, rgb8 and bgr8 (grey in every channel), rows padded to a
step of width*channels + 8. Between the good pairs it publishes what a
graph may also carry: a left image with no partner, a yuv422 pair, a pair
of another size, and an image without attachment. Prints {"ready": true}
once it listens, a JSON summary when done, and exits when stdin closes.
"""

import argparse
import json
import sys
import threading
import time
from pathlib import Path

import numpy as np
from rmw import STORE, Attachments, key, listening_peer

IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
T = STORE.types

# What the camera infos say (the test compares the file written with these).
LEFT_INFO = {"width": 640, "height": 480, "model": "plumb_bob",
             "d": [-0.21, 0.035, -0.0012, 0.0008, 0.0061],
             "k": [552.4, 0.0, 317.5, 0.0, 550.9, 243.25, 0.0, 0.0, 1.0]}


def camera_info(model, d, k, width, height):
    f64 = lambda v: np.array(v, dtype=np.float64)  # noqa: E731
    p = [k[0], k[1], k[2], 0.0, k[3], k[4], k[5], 0.0, 0.0, 0.0, 1.0, 0.0]
    return bytes(STORE.serialize_cdr(T[CAMERA_INFO](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=0),
                                        frame_id="left_optical"),
        height=height, width=width, distortion_model=model, d=f64(d), k=f64(k),
        r=f64([1, 0, 0, 0, 1, 0, 0, 0, 1]), p=f64(p), binning_x=0, binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                  do_rectify=False)), CAMERA_INFO))


def publish_camera_infos(session):
    """Until stdin closes: the two camera infos at 20 Hz."""
    infos = [
        ("/left/camera_info", camera_info(LEFT_INFO["model"], LEFT_INFO["d"], LEFT_INFO["k"],
                                          LEFT_INFO["width"], LEFT_INFO["height"])),
        ("/fisheye/camera_info", camera_info("equidistant", [0.1, 0.01, 0.0, 0.0],
                                             LEFT_INFO["k"], 640, 480)),
    ]
    pubs = [(session.declare_publisher(key(0, topic, CAMERA_INFO)), payload, Attachments())
            for topic, payload in infos]
    done = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), done.set()), daemon=True).start()
    while not done.wait(0.05):
        for pub, payload, attachments in pubs:
            pub.put(payload, attachment=attachments.next())


def image(stamp_ns, encoding, grey, channels, frame):
    height, width = grey.shape
    step = width * channels + 8
    rows = np.zeros((height, step), dtype=np.uint8)
    rows[:, : width * channels] = np.repeat(grey, channels, axis=1) if channels > 1 else grey
    return bytes(STORE.serialize_cdr(T[IMAGE](
        header=T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
            frame_id=frame),
        height=height, width=width, encoding=encoding, is_bigendian=0, step=step,
        data=rows.reshape(-1)), IMAGE))


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--listen", required=True)
    p.add_argument("--dir", help="the pairs; without it, camera infos only")
    p.add_argument("--left", default="/left/image_raw")
    p.add_argument("--right", default="/right/image_raw")
    p.add_argument("--period-ms", type=float, default=40.0)
    args = p.parse_args()
    if args.dir is None:
        session = listening_peer(args.listen, timestamping=True)
        print(json.dumps({"ready": True, "left_info": LEFT_INFO}), flush=True)
        publish_camera_infos(session)
        session.close()
        return
    d = Path(args.dir)
    manifest = json.loads((d / "manifest.json").read_text())
    w, h = manifest["width"], manifest["height"]

    def grey(k, eye):
        return np.frombuffer((d / f"{k:03}_{eye}.gray").read_bytes(), dtype=np.uint8).reshape(h, w)

    session = listening_peer(args.listen, timestamping=True)
    tokens = set()
    _graph = session.liveliness().declare_subscriber(
        "@ros2_lv/**", lambda s: tokens.add(str(s.key_expr)), history=True)
    print(json.dumps({"ready": True}), flush=True)
    if sys.stdin.readline().strip() != "go":
        return
    wanted = ["%" + t.strip("/").replace("/", "%") for t in (args.left, args.right)]
    deadline = time.monotonic() + 10
    while not all(any(f"/MS/" in t and f"/{w_}/" in t for t in tokens) for w_ in wanted):
        if time.monotonic() > deadline:
            print(json.dumps({"error": "no subscription tokens", "tokens": sorted(tokens)}), flush=True)
            return
        time.sleep(0.01)

    pubs = {eye: session.declare_publisher(key(0, topic, IMAGE)) for eye, topic in
            (("left", args.left), ("right", args.right))}
    attachments = {eye: Attachments() for eye in pubs}
    sent = {"pairs": 0, "lone": 0, "yuv422": 0, "other_size": 0, "without_attachment": 0}

    def put(eye, payload, attach=True):
        pubs[eye].put(payload, attachment=attachments[eye].next() if attach else None)
        time.sleep(args.period_ms / 2000)

    encodings = [("mono8", 1), ("rgb8", 3), ("bgr8", 3)]
    for k in range(manifest["pairs"]):
        stamp = time.time_ns()
        encoding, channels = encodings[k % 3]
        left = image(stamp, encoding, grey(k, "left"), channels, "left_optical")
        right = image(stamp + 1_000_000, encoding, grey(k, "right"), channels, "right_optical")
        # Either may come first.
        for eye, payload in ((("left", left), ("right", right)) if k % 2 == 0 else
                             (("right", right), ("left", left))):
            put(eye, payload)
        sent["pairs"] += 1
        later = time.time_ns() + 10_000_000
        if k == 0:
            put("left", image(later, "mono8", grey(k, "left"), 1, "left_optical"))
            sent["lone"] += 1
        elif k == 1:
            for eye in ("left", "right"):
                put(eye, image(later, "yuv422", np.zeros((h, w * 2), dtype=np.uint8), 1, eye))
            sent["yuv422"] += 1
        elif k == 2:
            for eye in ("left", "right"):
                put(eye, image(later, "mono8", grey(k, eye)[: h // 2, : w // 2], 1, eye))
            sent["other_size"] += 1
        elif k == 3:
            put("left", left, attach=False)
            sent["without_attachment"] += 1
    print(json.dumps(sent), flush=True)
    sys.stdin.read()
    session.close()


if __name__ == "__main__":
    main()
