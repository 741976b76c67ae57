"""Publishes what a ROS 2 graph may throw at the arm stage, with PyPI
eclipse-zenoh and rosbags only, then falls silent.

--case humble: joint states on a Humble key (type hash TypeHashNotSupported).
--case mixed:  for --seconds, each of: a joint state lacking joint4, one
               with another type hash, one without attachment, a malformed
               payload; then silence.
--tls-dir DIR: listen on TLS requiring client certificates, as a router
               configured for it.
Prints {"ready": true} once it listens; exits when stdin closes.
"""

import argparse
import json
import sys
import time

import numpy as np
from rmw import STORE as S, Attachments, key, listening_peer

JS = "sensor_msgs/msg/JointState"


def state(names):
    T = S.types
    return bytes(S.serialize_cdr(T[JS](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""),
        name=names, position=np.zeros(len(names)), velocity=np.array([], dtype=np.float64),
        effort=np.array([], dtype=np.float64)), JS))


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--listen", required=True)
    p.add_argument("--case", choices=["humble", "mixed"], required=True)
    p.add_argument("--seconds", type=float, default=1.5)
    p.add_argument("--tls-dir", help="listen as a TLS router (rmw.listening_peer)")
    args = p.parse_args()
    session = listening_peer(args.listen, tls_dir=args.tls_dir)
    print(json.dumps({"ready": True}), flush=True)
    good_key = key(0, "/joint_states", JS)
    attachment = Attachments(b"\x01" * 16).next

    joints = ["joint1", "joint2", "joint3", "joint4"]
    end = time.monotonic() + args.seconds
    while time.monotonic() < end:
        if args.case == "humble":
            session.put(key(0, "/joint_states", JS, "TypeHashNotSupported"), state(joints), attachment=attachment())
        else:
            session.put(good_key, state(joints[:3]), attachment=attachment())
            session.put(key(0, "/joint_states", JS, f"RIHS01_{'ab' * 32}"), state(joints), attachment=attachment())
            session.put(good_key, state(joints))
            session.put(good_key, b"\x00\x01\x00\x00\x07", attachment=attachment())
        time.sleep(0.02)
    sys.stdin.read()
    session.close()


if __name__ == "__main__":
    main()
