"""A stand-in ROS 2 robot arm on rmw_zenoh's wire, written only with PyPI
eclipse-zenoh and rosbags (CDR codec, Jazzy definitions, RIHS01 hashes):
nothing of ours encodes or decodes here.

It behaves like ros2_control's joint_trajectory_controller: it takes
trajectory_msgs/JointTrajectory on the controller's topic, moves each joint
linearly to the last point over its time_from_start, and publishes
sensor_msgs/JointState on /joint_states at --rate Hz, with an extra joint
we do not use and the joints in a shuffled order. As rmw_zenoh does, it
drops a sample without the 33-byte attachment. It listens as a zenoh peer
(our stage connects to it as to rmw_zenohd), prints {"ready": true} once it listens,
and a JSON summary (with the liveliness tokens it saw) on stdout when stdin
closes or on SIGTERM.
"""

import argparse
import json
import random
import signal
import struct
import sys
import threading
import time

import numpy as np
import zenoh
import zenoh.ext
from rmw import STORE, Attachments, key, listening_peer

JOINT_STATE = "sensor_msgs/msg/JointState"
TRAJECTORY = "trajectory_msgs/msg/JointTrajectory"
TF = "tf2_msgs/msg/TFMessage"


class Arm:
    def __init__(self, joints, home):
        self.lock = threading.Lock()
        self.q = dict(zip(joints, home))
        self.start = dict(self.q)
        self.goal = dict(self.q)
        self.t0 = time.monotonic()
        self.duration = 0.0

    def at(self, now):
        with self.lock:
            s = 1.0 if self.duration <= 0 else min(1.0, (now - self.t0) / self.duration)
            self.q = {j: self.start[j] + s * (self.goal[j] - self.start[j]) for j in self.q}
            return dict(self.q)

    def follow(self, names, positions, duration):
        now = time.monotonic()
        current = self.at(now)
        with self.lock:
            self.start = current
            self.goal = dict(current)
            for n, p in zip(names, positions):
                if n in self.goal:
                    self.goal[n] = float(p)
            self.t0 = now
            self.duration = duration


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--listen", required=True)
    p.add_argument("--joints", required=True, help="comma-separated")
    p.add_argument("--home", default="", help="comma-separated initial positions")
    p.add_argument("--extra", default="gripper_finger_joint")
    p.add_argument("--domain", type=int, default=0)
    p.add_argument("--trajectory", default="/joint_trajectory_controller/joint_trajectory")
    p.add_argument("--joint-states", default="/joint_states")
    p.add_argument("--rate", type=float, default=100.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--tf-static", default="/tf_static")
    args = p.parse_args()

    joints = args.joints.split(",")
    home = [float(v) for v in args.home.split(",")] if args.home else [0.0] * len(joints)
    arm = Arm(joints, home)
    rng = random.Random(args.seed)
    counts = {"trajectories": 0, "without_attachment": 0, "bad_attachment": 0,
              "joint_states": 0, "sequences_ok": True}
    last_seq = {}

    session = listening_peer(args.listen, timestamping=True)
    # The graph as rmw_zenoh sees it: every liveliness token (ros2 node list).
    tokens = set()

    def on_token(sample):
        if sample.kind == zenoh.SampleKind.PUT:
            tokens.add(str(sample.key_expr))

    _graph = session.liveliness().declare_subscriber("@ros2_lv/**", on_token, history=True)

    def on_trajectory(sample):
        att = sample.attachment
        if att is None:
            counts["without_attachment"] += 1
            return
        raw = att.to_bytes()
        if len(raw) != 33 or raw[16] != 16:
            counts["bad_attachment"] += 1
            return
        seq, _stamp = struct.unpack_from("<qq", raw)
        gid = raw[17:]
        if seq != last_seq.get(gid, 0) + 1:
            counts["sequences_ok"] = False
        last_seq[gid] = seq
        msg = STORE.deserialize_cdr(sample.payload.to_bytes(), TRAJECTORY)
        point = msg.points[-1]
        duration = point.time_from_start.sec + point.time_from_start.nanosec * 1e-9
        arm.follow(list(msg.joint_names), list(point.positions), duration)
        counts["trajectories"] += 1

    _sub = session.declare_subscriber(key(args.domain, args.trajectory, TRAJECTORY), on_trajectory)

    # /tf_static, as a live subscriber sees it, and as a node started after
    # the first calibration sees it (TRANSIENT_LOCAL: rmw_zenoh's advanced
    # subscriber with history, in a session of its own).
    tf_key = key(args.domain, args.tf_static, TF)

    def transforms(sample):
        msg = STORE.deserialize_cdr(sample.payload.to_bytes(), TF)
        return [{"parent": t.header.frame_id, "child": t.child_frame_id,
                 "stamp_ns": t.header.stamp.sec * 10**9 + t.header.stamp.nanosec,
                 "t": [t.transform.translation.x, t.transform.translation.y, t.transform.translation.z],
                 "q": [t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
                       t.transform.rotation.w]} for t in msg.transforms]

    counts["tf_static"] = 0
    counts["late_joiner_tf"] = None

    def late_joiner():
        time.sleep(0.5)
        late_conf = zenoh.Config()
        late_conf.insert_json5("mode", '"client"')
        late_conf.insert_json5("connect/endpoints", json.dumps([args.listen]))
        late_conf.insert_json5("scouting/multicast/enabled", "false")
        late = zenoh.open(late_conf)
        got = threading.Event()

        def on_late(sample):
            if sample.attachment is not None and counts["late_joiner_tf"] is None:
                counts["late_joiner_tf"] = transforms(sample)
                got.set()

        sub = zenoh.ext.declare_advanced_subscriber(
            late, tf_key, on_late,
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1))
        got.wait(5.0)
        sub.undeclare()
        late.close()

    def on_tf(sample):
        if sample.attachment is None:
            counts["without_attachment"] += 1
            return
        counts["last_tf"] = transforms(sample)
        counts["tf_static"] += 1
        if counts["tf_static"] == 1:
            threading.Thread(target=late_joiner, daemon=True).start()

    _tf = session.declare_subscriber(tf_key, on_tf)
    pub = session.declare_publisher(key(args.domain, args.joint_states, JOINT_STATE))
    attachments = Attachments()
    Header = STORE.types["std_msgs/msg/Header"]
    Time = STORE.types["builtin_interfaces/msg/Time"]
    JointState = STORE.types[JOINT_STATE]

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    print(json.dumps({"ready": True}), flush=True)
    period = 1.0 / args.rate
    next_t = time.monotonic()
    while not stop.is_set():
        q = arm.at(time.monotonic())
        names = joints + [args.extra]
        values = [q[j] for j in joints] + [0.01]
        order = list(range(len(names)))
        rng.shuffle(order)
        wall = time.time_ns()
        msg = JointState(
            header=Header(stamp=Time(sec=wall // 10**9, nanosec=wall % 10**9), frame_id=""),
            name=[names[i] for i in order],
            position=np.array([values[i] for i in order], dtype=np.float64),
            velocity=np.array([], dtype=np.float64),
            effort=np.array([], dtype=np.float64),
        )
        pub.put(bytes(STORE.serialize_cdr(msg, JOINT_STATE)), attachment=attachments.next())
        counts["joint_states"] += 1
        next_t += period
        delay = next_t - time.monotonic()
        if delay > 0:
            stop.wait(delay)
        else:
            next_t = time.monotonic()
    counts["tokens"] = sorted(tokens)
    print(json.dumps(counts), flush=True)
    session.close()


if __name__ == "__main__":
    main()
