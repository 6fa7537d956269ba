"""A ROS 2 consumer of op3dsg's topics, as it reaches Zenoh, without ROS: PyPI `eclipse-zenoh`,
`rosbags` and `xxhash` only, written from the published specifications, not from op3dsg's code:

- rmw_zenoh (ros2/rmw_zenoh docs/design.md): a topic is the key `<domain_id>/<topic without the
  leading '/'>/<DDS type>/<type hash>`; every message carries the 33-byte attachment (int64 LE
  sequence number, int64 LE source timestamp ns, the byte 16, the 16-byte publisher GID); nodes
  and publishers are liveliness tokens `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<NN|MP>/
  <enclave>/<namespace>/<node>[/<topic>/<type>/<hash>/<qos>]` ('/' in names written '%'), and a
  publisher's GID is XXH3-128 of its token (low 64 bits then high 64 bits, little-endian).
- zenoh-bridge-ros2dds: topic `/op3dsg/markers` is the key `op3dsg/markers` (under the bridge's
  namespace), the payload CDR only; a publisher route is announced by the token
  `@/<zid>/@ros2_lv/MP/<key with '/' as '§'>/<ROS type with '/' as '§'>/<qos>`.
- Payloads: CDR of visualization_msgs/msg/MarkerArray, nav_msgs/msg/OccupancyGrid and
  std_msgs/msg/String, decoded by rosbags' typestore of the distribution.

Subscribes to the three topics until stdin closes, then prints one JSON object: per topic the
messages received, their attachments (rmw_zenoh), the last message decoded; the liveliness
tokens seen; and what RViz would show after all the marker arrays (each applied in order by the
Marker message's ADD, DELETE and DELETEALL rules), with every (ns, id) ever added.

Usage: ros2_subscriber.py --key-style rmw_zenoh|bridge --distro humble --domain-id 0
           --namespace "" --connect tcp/127.0.0.1:7447
"""

import argparse
import json
import struct
import sys
import threading

import xxhash
import zenoh
from rosbags.typesys import Stores, get_typestore

TOPICS = {
    "/op3dsg/markers": ("visualization_msgs/msg/MarkerArray", "visualization_msgs::msg::dds_::MarkerArray_"),
    "/op3dsg/occupancy": ("nav_msgs/msg/OccupancyGrid", "nav_msgs::msg::dds_::OccupancyGrid_"),
    "/op3dsg/graph_json": ("std_msgs/msg/String", "std_msgs::msg::dds_::String_"),
}


def gid_of(token):
    h = xxhash.xxh3_128_intdigest(token.encode())
    return struct.pack("<QQ", h & (2**64 - 1), h >> 64).hex()


def attachment_of(sample):
    raw = sample.attachment
    if raw is None:
        return {"error": "no attachment"}
    b = raw.to_bytes()
    if len(b) != 33 or b[16] != 16:
        return {"error": "attachment of %d bytes: %s" % (len(b), b.hex())}
    seq, stamp = struct.unpack_from("<qq", b, 0)
    return {"seq": seq, "stamp_ns": stamp, "gid": b[17:].hex()}


def time_ns(t):
    return t.sec * 1_000_000_000 + t.nanosec


def summarise(topic, msg):
    if topic == "/op3dsg/markers":
        return [
            {
                "frame_id": m.header.frame_id,
                "stamp_ns": time_ns(m.header.stamp),
                "ns": m.ns,
                "id": m.id,
                "type": m.type,
                "action": m.action,
                "position": [m.pose.position.x, m.pose.position.y, m.pose.position.z],
                "orientation": [m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w],
                "scale": [m.scale.x, m.scale.y, m.scale.z],
                "color": [m.color.r, m.color.g, m.color.b, m.color.a],
                "points": len(m.points),
                "text": m.text,
            }
            for m in msg.markers
        ]
    if topic == "/op3dsg/occupancy":
        o = msg.info.origin
        return {
            "frame_id": msg.header.frame_id,
            "stamp_ns": time_ns(msg.header.stamp),
            "resolution": msg.info.resolution,
            "width": msg.info.width,
            "height": msg.info.height,
            "origin": [o.position.x, o.position.y, o.position.z],
            "cells": len(msg.data),
            "known": int((msg.data >= 0).sum()),
            "occupied": int((msg.data >= 50).sum()),
        }
    return json.loads(msg.data)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--key-style", choices=["rmw_zenoh", "bridge"], required=True)
    ap.add_argument("--distro", choices=["humble", "jazzy"], default="humble")
    ap.add_argument("--domain-id", type=int, default=0)
    ap.add_argument("--namespace", default="")
    ap.add_argument("--connect", required=True)
    args = ap.parse_args()
    store = get_typestore(Stores.ROS2_HUMBLE if args.distro == "humble" else Stores.ROS2_JAZZY)

    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([args.connect]))
    config.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(config)

    lock = threading.Lock()
    seen = {t: {"received": 0, "keys": [], "attachments": [], "errors": [], "markers_actions": [], "last": None}
            for t in TOPICS}
    # What RViz shows after every array so far, by the Marker message's rules: ADD (0) adds or
    # replaces (ns, id), DELETE (2) removes it, DELETEALL (3) removes every marker (of its ns
    # when one is given).
    shown = {}
    ever_added = set()
    deletes = {"count": 0}

    def apply_markers(markers):
        for m in markers:
            if m.action == 3:
                for key in [k for k in shown if not m.ns or k[0] == m.ns]:
                    del shown[key]
            elif m.action == 2:
                deletes["count"] += shown.pop((m.ns, m.id), None) is not None
            elif m.action == 0:
                shown[(m.ns, m.id)] = m.type
                ever_added.add((m.ns, m.id))

    def subscriber(topic, ros_type, dds_type):
        name = topic.lstrip("/")
        if args.key_style == "rmw_zenoh":
            # Any type hash: Humble writes TypeHashNotSupported, Jazzy RIHS01_...
            key = "%d/%s/%s/*" % (args.domain_id, name, dds_type)
        else:
            ns = args.namespace.strip("/")
            key = "%s/%s" % (ns, name) if ns else name

        def on_sample(sample):
            entry = seen[topic]
            with lock:
                entry["received"] += 1
                k = str(sample.key_expr)
                if k not in entry["keys"]:
                    entry["keys"].append(k)
                if args.key_style == "rmw_zenoh":
                    entry["attachments"].append(attachment_of(sample))
                try:
                    msg = store.deserialize_cdr(sample.payload.to_bytes(), ros_type)
                    entry["last"] = summarise(topic, msg)
                    if topic == "/op3dsg/markers":
                        entry["markers_actions"].append(sorted({(m.ns, m.action) for m in msg.markers}))
                        apply_markers(msg.markers)
                except Exception as e:  # a payload rosbags cannot read is what the test looks for
                    entry["errors"].append(repr(e))

        return session.declare_subscriber(key, on_sample)

    subscribers = [subscriber(t, *types) for t, types in TOPICS.items()]
    print(json.dumps({"event": "ready"}), flush=True)
    sys.stdin.read()

    tokens = []
    selector = "@ros2_lv/%d/**" % args.domain_id if args.key_style == "rmw_zenoh" else "@/*/@ros2_lv/MP/**"
    for reply in session.liveliness().get(selector, timeout=5.0):
        if reply.ok is not None:
            token = str(reply.ok.key_expr)
            tokens.append({"token": token, "gid": gid_of(token)})
    with lock:
        for entry in seen.values():
            entry["markers_actions"] = [[list(p) for p in a] for a in entry["markers_actions"]]
        rviz = {"shown": sorted([ns, i, t] for (ns, i), t in shown.items()),
                "ever_added": sorted([ns, i] for ns, i in ever_added), "deleted": deletes["count"]}
        print(json.dumps({"event": "done", "topics": seen, "tokens": tokens, "rviz": rviz}), flush=True)
    for s in subscribers:
        s.undeclare()
    session.close()


if __name__ == "__main__":
    main()
