"""ROS 2 messages in CDR by an independent implementation: PyPI `rosbags`, whose typestores hold
the message definitions of each ROS 2 distribution.

    rosbags_cdr.py golden DIR         write the golden payloads the Rust tests decode
    rosbags_cdr.py decode TYPE FILE   print the message in FILE (CDR with its header) as JSON,
                                      decoded with the Humble and the Jazzy definitions
    rosbags_cdr.py rihs01 TYPE...     print {TYPE: RIHS01 hash} as Jazzy and Kilted compute them

Used by drivers/ros2/tests/it/golden.rs. Written from the ROS 2 message definitions, not from the
Rust code.
"""

import dataclasses
import json
import sys
from importlib.metadata import version
from pathlib import Path

import numpy as np
from rosbags.typesys import Stores, get_typestore

HUMBLE = get_typestore(Stores.ROS2_HUMBLE)
JAZZY = get_typestore(Stores.ROS2_JAZZY)
KILTED = get_typestore(Stores.ROS2_KILTED)


def to_plain(store, value):
    """A message as JSON-ready dicts and lists: the fields of its definition (not its constants)."""
    if dataclasses.is_dataclass(value):
        _constants, fields = store.fielddefs[value.__msgtype__]
        return {name: to_plain(store, getattr(value, name)) for name, _kind in fields}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [to_plain(store, v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def golden_tf(store):
    t = store.types
    stamp = t["builtin_interfaces/msg/Time"]

    def transform(parent, child, sec, nanosec, xyz, xyzw):
        return t["geometry_msgs/msg/TransformStamped"](
            header=t["std_msgs/msg/Header"](stamp=stamp(sec=sec, nanosec=nanosec), frame_id=parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
                rotation=t["geometry_msgs/msg/Quaternion"](x=xyzw[0], y=xyzw[1], z=xyzw[2], w=xyzw[3]),
            ),
        )

    return t["tf2_msgs/msg/TFMessage"](
        transforms=[
            transform("map", "odom", 1_700_000_000, 123_456_789, (1.5, -2.25, 0.0), (0.0, 0.0, 0.6, 0.8)),
            transform("odom", "base_link", 1_700_000_000, 123_456_789, (0.1, 0.2, 0.3), (0.0, 0.0, 0.0, 1.0)),
            transform("camera_link", "camera_color_optical_frame", 0, 0, (0.0, 0.015, 0.0), (-0.5, 0.5, -0.5, 0.5)),
        ]
    )


def golden_marker(store):
    t = store.types
    color = t["std_msgs/msg/ColorRGBA"]
    point = t["geometry_msgs/msg/Point"]
    header = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=12, nanosec=500), frame_id="map")
    return t["visualization_msgs/msg/Marker"](
        header=header,
        ns="objects",
        id=42,
        type=1,
        action=0,
        pose=t["geometry_msgs/msg/Pose"](
            position=point(x=1.0, y=2.0, z=0.5),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
        scale=t["geometry_msgs/msg/Vector3"](x=0.5, y=0.25, z=0.75),
        color=color(r=1.0, g=0.5, b=0.25, a=0.75),
        lifetime=t["builtin_interfaces/msg/Duration"](sec=2, nanosec=250_000_000),
        frame_locked=True,
        points=[point(x=0.0, y=0.0, z=0.0), point(x=1.0, y=-1.0, z=2.0)],
        colors=[color(r=0.0, g=1.0, b=0.0, a=1.0)],
        texture_resource="package://op3dsg/texture.png",
        texture=t["sensor_msgs/msg/CompressedImage"](
            header=header, format="png", data=np.array([137, 80, 78, 71], dtype=np.uint8)
        ),
        uv_coordinates=[t["visualization_msgs/msg/UVCoordinate"](u=0.5, v=0.25)],
        text="chair (part of: table)",
        mesh_resource="",
        mesh_file=t["visualization_msgs/msg/MeshFile"](filename="box.stl", data=np.array([1, 2, 3], dtype=np.uint8)),
        mesh_use_embedded_materials=False,
    )


def golden(directory):
    out = Path(directory)
    payloads = {
        "tfmessage_le.cdr": lambda s: s.serialize_cdr(golden_tf(s), "tf2_msgs/msg/TFMessage"),
        "tfmessage_be.cdr": lambda s: s.serialize_cdr(golden_tf(s), "tf2_msgs/msg/TFMessage", little_endian=False),
        "marker.cdr": lambda s: s.serialize_cdr(golden_marker(s), "visualization_msgs/msg/Marker"),
    }
    for name, make in payloads.items():
        humble, jazzy = bytes(make(HUMBLE)), bytes(make(JAZZY))
        # The two distributions define these types alike, so the bytes are the same.
        assert humble == jazzy, name
        (out / name).write_bytes(jazzy)
    (out / "GENERATED_BY").write_text(
        f"rosbags {version('rosbags')} (typestores ROS2_HUMBLE and ROS2_JAZZY, identical bytes),\n"
        "by drivers/ros2/tests/rosbags_cdr.py golden drivers/ros2/tests/data\n"
    )


def decode(typename, path):
    raw = Path(path).read_bytes()
    stores = (("humble", HUMBLE), ("jazzy", JAZZY))
    plain = {name: to_plain(store, store.deserialize_cdr(raw, typename)) for name, store in stores}
    # Check what was decoded re-encodes to the same bytes (nothing left over, nothing skipped).
    reencoded = bytes(JAZZY.serialize_cdr(JAZZY.deserialize_cdr(raw, typename), typename))
    plain["reencoded_equal"] = reencoded == raw
    print(json.dumps(plain))


def rihs01(typenames):
    hashes = {name: {"jazzy": JAZZY.hash_rihs01(name), "kilted": KILTED.hash_rihs01(name)} for name in typenames}
    print(json.dumps(hashes))


def main(argv):
    if len(argv) == 2 and argv[0] == "golden":
        golden(argv[1])
    elif len(argv) == 3 and argv[0] == "decode":
        decode(argv[1], argv[2])
    elif len(argv) >= 2 and argv[0] == "rihs01":
        rihs01(argv[1:])
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main(sys.argv[1:])
