"""rmw_zenoh's wire as the test stand-ins speak it, written from rmw_zenoh's
docs/design.md with PyPI eclipse-zenoh and rosbags only (nothing of ours):
topic keys, the 33-byte attachment, and a zenoh peer that our stages
connect to as they would to rmw_zenohd."""

import json
import os
import struct
import time

import zenoh
from rosbags.typesys import Stores, get_typestore

STORE = get_typestore(Stores.ROS2_JAZZY)


def dds_name(name):
    """`sensor_msgs/msg/Image` -> `sensor_msgs::msg::dds_::Image_`."""
    namespace, short = name.rsplit("/", 1)
    return namespace.replace("/", "::") + "::dds_::" + short + "_"


def key(domain, topic, name, type_hash=None):
    """`<domain>/<topic>/<dds type name>/<RIHS01 hash>`."""
    return f"{domain}/{topic.strip('/')}/{dds_name(name)}/{type_hash or STORE.hash_rihs01(name)}"


def listening_peer(endpoint, timestamping=False, tls_dir=None):
    """A zenoh peer listening on `endpoint`, multicast scouting off. With
    `tls_dir`: TLS as a router configured for it, with `router.pem`/`.key`,
    requiring client certificates signed by `ca.pem` (mutual TLS)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if tls_dir:
        conf.insert_json5("transport/link/tls", json.dumps({
            "root_ca_certificate": os.path.join(tls_dir, "ca.pem"),
            "listen_certificate": os.path.join(tls_dir, "router.pem"),
            "listen_private_key": os.path.join(tls_dir, "router.key"),
            "enable_mtls": True,
        }))
    if timestamping:
        conf.insert_json5("timestamping/enabled", "{router: true, peer: true, client: true}")
    return zenoh.open(conf)


class Attachments:
    """One publisher's attachments: sequence from 1, wall-clock source
    timestamp, its GID (zenoh-ext serialisation: i64, i64, length 16, bytes)."""

    def __init__(self, gid=None):
        self.gid = gid or os.urandom(16)
        self.seq = 0

    def next(self):
        self.seq += 1
        return struct.pack("<qqB16s", self.seq, time.time_ns(), 16, self.gid)
