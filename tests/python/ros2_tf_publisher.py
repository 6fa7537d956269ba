"""A ROS 2 robot's tf, as it reaches Zenoh, without ROS: PyPI `eclipse-zenoh` and `rosbags` only.

Written from the published specifications, not from op3dsg's code:
- rmw_zenoh (ros2/rmw_zenoh docs/design.md): key `<domain_id>/<topic without leading '/'>/
  <DDS type>/<type hash>` (`RIHS01_...` on Jazzy and later, `TypeHashNotSupported` on Humble);
  every message carries the 33-byte attachment (int64 LE sequence number from 1, int64 LE
  source timestamp in ns since the epoch, the byte 16, a 16-byte publisher GID); the node and
  each publisher declare liveliness tokens `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<NN|MP>/
  <enclave>/<namespace>/<node>[/<topic>/<type>/<hash>/<qos>]` with '/' mangled to '%'.
- zenoh-bridge-ros2dds: topic `/tf` is key `tf` under the bridge's namespace, CDR payload only.
- /tf_static is TRANSIENT_LOCAL: in both styles a Zenoh AdvancedPublisher keeps the last message
  in a cache with publisher detection, so a subscriber that comes later (an AdvancedSubscriber
  with history and late-publisher detection) still gets it. It is published once, as tf2's
  static broadcaster does.
- Payloads: tf2_msgs/msg/TFMessage serialised by rosbags' typestore of the chosen distribution.

The trajectory (a file, or '-' for stdin) is JSON: a list, or one object per line, of
{"stamp_ns": int, "translation_m": [x, y, z], "rotation_xyzw": [x, y, z, w]}, each
`world_from_camera` (map <- camera_color_optical_frame). Each pose is split into the chain
map -> odom -> base_link -> link_head_tilt -> camera_link -> camera_color_optical_frame: the last
two edges are static (/tf_static), map -> odom drifts slowly and the head pans and tilts with time,
and odom -> base_link is solved so that the chain's product is the given pose at its stamp. The
three dynamic edges go out in one /tf message per pose, paced at --rate.

Prints JSON lines on stdout: {"event": "ready", ...keys and tokens} once declared, then
{"event": "done", "published": N, "first_stamp_ns": ..., "last_stamp_ns": ...}; then keeps the
session (and the static cache) for --linger-s and exits.

With --static-only it publishes /tf_static alone and keeps it cached for --linger-s (a robot's
static broadcaster started before the daemon); with --no-static, /tf alone.

Faults for tests: --omit-frame CHILD (never publish the transform into CHILD; repeatable),
--stamp-offset-ns N (added to every /tf stamp), --malformed N (N truncated /tf payloads first).

Usage: ros2_tf_publisher.py --key-style rmw_zenoh --distro jazzy --domain-id 0 --namespace ""
           --connect tcp/127.0.0.1:7447 --trajectory poses.json [--rate 30]
"""

import argparse
import hashlib
import json
import math
import signal
import struct
import sys
import time

import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_typestore

CHAIN = ["map", "odom", "base_link", "link_head_tilt", "camera_link", "camera_color_optical_frame"]
TF_TYPE = "tf2_msgs/msg/TFMessage"
TF_DDS_TYPE = "tf2_msgs::msg::dds_::TFMessage_"


# Rigid transforms as (quaternion xyzw, translation xyz), `a_from_b`.
def q_mul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def q_rotate(q, v):
    x, y, z, _w = q_mul(q_mul(q, (v[0], v[1], v[2], 0.0)), (-q[0], -q[1], -q[2], q[3]))
    return (x, y, z)


def compose(a, b):
    (qa, ta), (qb, tb) = a, b
    rotated = q_rotate(qa, tb)
    return (q_mul(qa, qb), tuple(r + t for r, t in zip(rotated, ta)))


def inverse(a):
    q, t = a
    qi = (-q[0], -q[1], -q[2], q[3])
    return (qi, tuple(-c for c in q_rotate(qi, t)))


def axis_angle(axis, angle):
    s = math.sin(angle / 2)
    return (axis[0] * s, axis[1] * s, axis[2] * s, math.cos(angle / 2))


# camera_link <- camera_color_optical_frame: optical z forward (link x), x right (-y), y down (-z).
CAMERA_LINK_FROM_OPTICAL = ((-0.5, 0.5, -0.5, 0.5), (0.0, 0.015, 0.0))
HEAD_TILT_FROM_CAMERA_LINK = (axis_angle((0, 1, 0), 0.02), (0.03, -0.01, 0.05))


def map_from_odom(t):
    return (axis_angle((0, 0, 1), 0.002 * t), (0.01 * t, -0.005 * t, 0.0))


def base_from_head_tilt(t):
    pan = axis_angle((0, 0, 1), 0.4 * math.sin(0.5 * t))
    tilt = axis_angle((0, 1, 0), -0.3 + 0.1 * math.sin(0.3 * t))
    return (q_mul(pan, tilt), (-0.04, 0.13, 1.25))


def dynamic_edges(stamp_ns, world_from_camera):
    """The three /tf edges (parent, child, parent_from_child) whose chain gives the pose."""
    t = stamp_ns * 1e-9
    base_from_camera = compose(compose(base_from_head_tilt(t), HEAD_TILT_FROM_CAMERA_LINK), CAMERA_LINK_FROM_OPTICAL)
    odom_from_base = compose(compose(inverse(map_from_odom(t)), world_from_camera), inverse(base_from_camera))
    return [("map", "odom", map_from_odom(t)), ("odom", "base_link", odom_from_base),
            ("base_link", "link_head_tilt", base_from_head_tilt(t))]


STATIC_EDGES = [("link_head_tilt", "camera_link", HEAD_TILT_FROM_CAMERA_LINK),
                ("camera_link", "camera_color_optical_frame", CAMERA_LINK_FROM_OPTICAL)]


def read_trajectory(source):
    text = sys.stdin.read() if source == "-" else open(source, encoding="utf-8").read()
    text = text.strip()
    if text.startswith("["):
        items = json.loads(text)
    else:
        items = [json.loads(line) for line in text.splitlines() if line.strip()]
    poses = []
    for i, item in enumerate(items):
        q = tuple(float(c) for c in item["rotation_xyzw"])
        n = math.sqrt(sum(c * c for c in q))
        if len(q) != 4 or abs(n - 1) > 1e-3:
            sys.exit(f"trajectory pose {i}: rotation_xyzw {q} is not a unit quaternion")
        poses.append((int(item["stamp_ns"]), (tuple(c / n for c in q), tuple(float(c) for c in item["translation_m"]))))
    if not poses:
        sys.exit("the trajectory holds no pose")
    return poses


def check_chain(stamp_ns, world_from_camera):
    """The chain's product equals the pose (a self-check of the split)."""
    chain = None
    for _parent, _child, t in dynamic_edges(stamp_ns, world_from_camera) + STATIC_EDGES:
        chain = t if chain is None else compose(chain, t)
    (q, v), (q0, v0) = chain, world_from_camera
    dot = abs(sum(a * b for a, b in zip(q, q0)))
    assert max(abs(a - b) for a, b in zip(v, v0)) < 1e-9 and dot > 1 - 1e-12, (chain, world_from_camera)


def resolve(namespace, topic):
    """A topic's fully qualified ROS name: absolute as given, relative under the namespace."""
    if topic.startswith("/"):
        return topic
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{topic}"


class Publisher:
    """One topic in one key style: key, QoS, attachment and token."""

    def __init__(self, session, args, typestore, topic, entity_id, static):
        self.session, self.typestore, self.static = session, typestore, static
        self.sequence = 0
        self.token = None
        fq = resolve(args.namespace if args.key_style == "rmw_zenoh" else "", topic)
        if args.key_style == "rmw_zenoh":
            type_hash = "TypeHashNotSupported" if args.distro == "humble" else typestore.hash_rihs01(TF_TYPE)
            self.key = f"{args.domain_id}/{fq[1:]}/{TF_DDS_TYPE}/{type_hash}"
            # QoS as rmw_zenoh writes it (empty = its default: reliable, volatile, keep last 42):
            # tf2's static broadcaster is transient local, depth 1; its broadcaster depth 100.
            qos = ":1:,1:,:,:,," if static else "::,100:,:,:,,"
            self.token_key = (f"{node_token_prefix(session, args, entity_id, 'MP')}/{fq.replace('/', '%')}/"
                              f"{TF_DDS_TYPE}/{type_hash}/{qos}")
            self.gid = hashlib.sha256(self.token_key.encode()).digest()[:16]
        else:
            ns = args.namespace.strip("/")
            self.key = f"{ns}/{fq[1:]}" if ns else fq[1:]
            self.token_key = None
        if static:
            self.publisher = zenoh.ext.declare_advanced_publisher(
                session, self.key,
                cache=zenoh.ext.CacheConfig(max_samples=1),
                publisher_detection=True,
                sample_miss_detection=zenoh.ext.MissDetectionConfig(sporadic_heartbeat=0.5),
            )
        else:
            self.publisher = session.declare_publisher(self.key, reliability=zenoh.Reliability.RELIABLE)
        if self.token_key:
            self.token = session.liveliness().declare_token(self.token_key)

    def wait_matched(self, timeout_s):
        """Waits until a subscriber of the topic is known (Zenoh drops puts nobody matches), at
        most timeout_s; False when none came."""
        end = time.monotonic() + timeout_s
        while not self.publisher.matching_status.matching:
            if time.monotonic() > end:
                return False
            time.sleep(0.02)
        return True

    def put(self, payload):
        attachment = None
        if self.token_key:
            self.sequence += 1
            attachment = struct.pack("<qqB16s", self.sequence, time.time_ns(), 16, self.gid)
        self.publisher.put(payload, attachment=attachment)

    def message(self, stamp_ns, edges):
        t = self.typestore.types
        transforms = []
        for parent, child, (q, v) in edges:
            transforms.append(t["geometry_msgs/msg/TransformStamped"](
                header=t["std_msgs/msg/Header"](
                    stamp=t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
                    frame_id=parent),
                child_frame_id=child,
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](x=v[0], y=v[1], z=v[2]),
                    rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])),
            ))
        return bytes(self.typestore.serialize_cdr(t[TF_TYPE](transforms=transforms), TF_TYPE))


def node_token_prefix(session, args, entity_id, kind):
    namespace = "/" + args.namespace.strip("/")
    return (f"@ros2_lv/{args.domain_id}/{session.info.zid()}/0/{entity_id}/{kind}/%/"
            f"{namespace.replace('/', '%')}/{args.node_name}")


def parse_args(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--key-style", choices=["rmw_zenoh", "bridge"], required=True)
    parser.add_argument("--distro", choices=["humble", "jazzy"], default="jazzy")
    parser.add_argument("--domain-id", type=int, default=0)
    parser.add_argument("--namespace", default="", help="rmw_zenoh: the node's namespace; bridge: the bridge's")
    parser.add_argument("--node-name", default="robot_state_publisher")
    parser.add_argument("--tf-topic", default="/tf")
    parser.add_argument("--tf-static-topic", default="/tf_static")
    parser.add_argument("--connect", required=True, help="e.g. tcp/127.0.0.1:7447 (client mode, scouting off)")
    parser.add_argument("--trajectory", required=True, help="JSON file, or - for stdin")
    parser.add_argument("--rate", type=float, default=30.0, help="poses per second (0: as fast as possible)")
    parser.add_argument("--start-delay-s", type=float, default=0.5, help="after declaring, before publishing")
    parser.add_argument("--linger-s", type=float, default=1.0, help="keep the session after the last pose")
    parser.add_argument("--wait-subscriber-s", type=float, default=10.0,
                        help="before /tf, wait at most this long for a subscriber to be known")
    parser.add_argument("--omit-frame", action="append", default=[], help="never publish the transform into it")
    parser.add_argument("--stamp-offset-ns", type=int, default=0, help="added to every /tf stamp")
    parser.add_argument("--malformed", type=int, default=0, help="truncated /tf payloads published first")
    parts = parser.add_mutually_exclusive_group()
    parts.add_argument("--static-only", action="store_true",
                       help="publish /tf_static only, then keep it in the cache for --linger-s")
    parts.add_argument("--no-static", action="store_true",
                       help="publish /tf only (the static transforms come from another publisher)")
    return parser.parse_args(argv)


def main(argv):
    args = parse_args(argv)
    poses = read_trajectory(args.trajectory)
    for stamp_ns, pose in poses[:3]:
        check_chain(stamp_ns, pose)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    typestore = get_typestore(Stores.ROS2_HUMBLE if args.distro == "humble" else Stores.ROS2_JAZZY)

    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([args.connect]))
    config.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(config) as session:
        node_token = None
        if args.key_style == "rmw_zenoh":
            node_token_key = node_token_prefix(session, args, 0, "NN")
            node_token = session.liveliness().declare_token(node_token_key)
        tf = None if args.static_only else Publisher(session, args, typestore, args.tf_topic, 1, static=False)
        tf_static = None if args.no_static else Publisher(session, args, typestore, args.tf_static_topic, 2, static=True)
        tokens = [k for k in (node_token and node_token_key, tf and tf.token_key, tf_static and tf_static.token_key)
                  if k]
        print(json.dumps({"event": "ready", "tf_key": tf and tf.key, "tf_static_key": tf_static and tf_static.key,
                          "tokens": tokens, "zid": str(session.info.zid())}), flush=True)
        time.sleep(args.start_delay_s)
        if tf is not None and not tf.wait_matched(args.wait_subscriber_s):
            print(f"no subscriber of {tf.key} after {args.wait_subscriber_s} s; publishing anyway",
                  file=sys.stderr, flush=True)

        omit = set(args.omit_frame)
        statics = [e for e in STATIC_EDGES if e[1] not in omit]
        if statics and tf_static:
            tf_static.put(tf_static.message(poses[0][0], statics))
        if tf is None:
            print(json.dumps({"event": "done", "published": 0, "static": len(statics)}), flush=True)
            time.sleep(args.linger_s)
            return
        for _ in range(args.malformed):
            good = tf.message(poses[0][0], dynamic_edges(*poses[0]))
            tf.put(good[: len(good) // 2])
        period = 1.0 / args.rate if args.rate > 0 else 0.0
        start = time.monotonic()
        for i, (stamp_ns, pose) in enumerate(poses):
            edges = [e for e in dynamic_edges(stamp_ns, pose) if e[1] not in omit]
            if edges:
                tf.put(tf.message(stamp_ns + args.stamp_offset_ns, edges))
            delay = start + (i + 1) * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        print(json.dumps({"event": "done", "published": len(poses), "first_stamp_ns": poses[0][0],
                          "last_stamp_ns": poses[-1][0]}), flush=True)
        time.sleep(args.linger_s)


if __name__ == "__main__":
    main(sys.argv[1:])
