"""Reads an op3dsg MCAP recording with the independent PyPI `mcap` reader and prints a JSON
summary for the cross-process tests (tests/tests/it/record_daemon.rs):

    .venv/bin/python tests/python/mcap_check.py FILE [--foxglove-schemas DIR] [--find TEXT]...

{
  "channels": {topic: {"schema", "schema_encoding", "message_encoding", "count"}},
  "log_time_ordered": bool,          # log times never decrease, whole file
  "stamps_ordered": {topic: bool},   # message timestamps never decrease, per channel
  "scene_versions_checked": int,     # SceneUpdates compared with the graph version they came from
  "scene_mismatches": [str],         # every cube that differs from its node's oriented box
  "last_graph": str | null,          # raw bytes (utf-8) of the last /op3dsg/graph message
  "metadata": {name: {key: value}},  # the profile's text is left out
  "point_clouds_checked": int,       # /op3dsg/node_points clouds decoded and matched to their graph
  "point_cloud_mismatches": [str],   # a cloud whose data or node ids do not fit its graph version
  "detections": int,                 # detection boxes on /op3dsg/detections
  "detections_off_keyframes": [str], # detection messages not stamped like a keyframe's /tf
  "compressed_formats": {fmt: int},  # foxglove.CompressedImage messages whose data is a real png/jpeg
  "llm_exchanges": [object],         # every /op3dsg/llm message, decoded
  "message_texts_with": {text: [str]},  # per --find TEXT: the messages whose data contains it
  "foxglove_validated": {schema: int},  # foxglove.* messages validated against Foxglove's schema
  "foxglove_errors": [str],          # every violation (first 50): "topic[index]: path: what"
  "embedded_validated": int,         # messages validated against the schema text in the file
  "embedded_errors": [str],          # violations of the file's own schemas (first 50), applied
                                     #   strictly like Foxglove's: a field they do not describe
                                     #   is an error
  "world_frames": {topic: [str]},    # the world frame names used: /tf parents, scene entities,
                                     #   node point clouds, health records (sorted, distinct)
  "error": str | null                # why reading stopped before the end (truncated file)
}

Foxglove's published JSON schemas come from the npm package @foxglove/schemas
(scripts/setup-foxglove-schemas.sh puts one file per type into .deps/foxglove-schemas/<version>/;
DIR overrides). They are applied strictly: every object that lists its properties is closed
(`additionalProperties: false`), so a misspelt or extra field is an error, not ignored as
Foxglove's panels would ignore it. A foxglove.* schema name with no published schema is an error.
RawImage data is also decoded (base64) and must hold `step * height` bytes.

The `foxglove.*` channels are protobuf: each message is decoded with the FileDescriptorSet its
schema embeds (google.protobuf from PyPI, not the project's code) and turned into the JSON form
Foxglove's JSON schemas describe (every field of the descriptor; time as {sec, nsec}; bytes as
base64; enums as integers), which is then validated and checked as above. Files written before
the recorder used protobuf hold these channels as JSON; both are read.

Reads records in file order (NonSeekingReader), so a file without a summary (after kill -9) is
read up to where it ends; the exception that stops it is reported in "error".
"""

import base64
import json
import math
import os
import struct
import sys
import tomllib

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.descriptor import FieldDescriptor
from jsonschema import Draft7Validator
from mcap.reader import NonSeekingReader
from mcap.stream_reader import StreamReader


def stamp(message):
    t = message.get("timestamp")
    if isinstance(t, dict):
        return t["sec"] * 1_000_000_000 + t["nsec"]
    return message.get("stamp_ns")


SCHEMA_VERSION = "2.1.0"
# world.up_axis -> (first horizontal, second horizontal, up), as daemon/runtime/src/fusion/oriented_box.rs.
HORIZONTAL_FRAMES = {
    "z": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "y": ((0, 0, 1), (1, 0, 0), (0, 1, 0)),
    "neg_y": ((1, 0, 0), (0, 0, 1), (0, -1, 0)),
}


def rotate(q, v):
    """v rotated by the unit quaternion q = (x, y, z, w)."""
    x, y, z, w = q
    # t = 2 q_vec x v; v' = v + w t + q_vec x t
    tx, ty, tz = 2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0])
    return (
        v[0] + w * tx + (y * tz - z * ty),
        v[1] + w * ty + (z * tx - x * tz),
        v[2] + w * tz + (x * ty - y * tx),
    )
MAX_ERRORS = 50


def strict(schema):
    """`schema` with every object that lists its properties closed to other properties."""
    if isinstance(schema, list):
        return [strict(s) for s in schema]
    if not isinstance(schema, dict):
        return schema
    out = {k: strict(v) for k, v in schema.items()}
    if out.get("type") == "object" and "properties" in out and "additionalProperties" not in out:
        out["additionalProperties"] = False
    return out


class FoxgloveSchemas:
    def __init__(self, folder):
        if not os.path.isdir(folder):
            sys.exit(f"mcap_check.py: {folder} missing: run ./scripts/setup-foxglove-schemas.sh (scripts/test.sh does)")
        self.folder = folder
        self.validators = {}

    def validator(self, name):
        if name not in self.validators:
            path = os.path.join(self.folder, name + ".json")
            if not os.path.isfile(path):
                self.validators[name] = None
            else:
                with open(path) as f:
                    self.validators[name] = Draft7Validator(strict(json.load(f)))
        return self.validators[name]


class Protobuf:
    """Decodes protobuf messages with the descriptors their schema record embeds."""

    def __init__(self):
        self.classes = {}

    def message_class(self, schema):
        if schema.id not in self.classes:
            fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
            pool = descriptor_pool.DescriptorPool()
            for file in fds.file:
                pool.Add(file)
            self.classes[schema.id] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
        return self.classes[schema.id]

    def decode(self, schema, data):
        return as_json(self.message_class(schema).FromString(data))


TIME_TYPES = ("google.protobuf.Timestamp", "google.protobuf.Duration")


def as_json(message):
    """A decoded protobuf message in Foxglove's JSON form: every field the descriptor defines
    (sub-messages only when set), time and duration as {sec, nsec}, bytes base64, enums as
    integers."""
    if message.DESCRIPTOR.full_name in TIME_TYPES:
        return {"sec": message.seconds, "nsec": message.nanos}
    out = {}
    for field in message.DESCRIPTOR.fields:
        value = getattr(message, field.name)
        if field.is_repeated:
            out[field.name] = [field_json(field, v) for v in value]
        elif field.type == FieldDescriptor.TYPE_MESSAGE and not message.HasField(field.name):
            continue
        else:
            out[field.name] = field_json(field, value)
    return out


def field_json(field, value):
    if field.type == FieldDescriptor.TYPE_MESSAGE:
        return as_json(value)
    if field.type == FieldDescriptor.TYPE_BYTES:
        return base64.b64encode(value).decode("ascii")
    return value


def violations(validator, message, where):
    for e in sorted(validator.iter_errors(message), key=lambda e: list(e.absolute_path)):
        path = "/".join(str(p) for p in e.absolute_path) or "(root)"
        text = e.message if len(e.message) < 200 else e.message[:200] + "..."
        yield f"{where}: {path}: {text}"


def check_cloud(cloud, graph, where, mismatches):
    """A node-points cloud: x, y, z float32 and node_id uint32 at the declared offsets; every
    node id one of the graph version's, each point inside its node's box."""
    fields = {f["name"]: (f["offset"], f["type"]) for f in cloud["fields"]}
    if fields != {"x": (0, 7), "y": (4, 7), "z": (8, 7), "node_id": (12, 5)} or cloud["point_stride"] != 16:
        mismatches.append(f"{where}: fields {fields}, stride {cloud['point_stride']}")
        return
    data = base64.b64decode(cloud["data"])
    if len(data) % 16:
        mismatches.append(f"{where}: {len(data)} bytes is no whole number of points")
        return
    if graph is None:
        mismatches.append(f"{where}: no graph version with the cloud's stamp")
        return
    ids = {n["id"] for n in graph["nodes"]}
    seen = set()
    for (x, y, z, node_id) in struct.iter_unpack("<fffI", data):
        seen.add(node_id)
        if node_id not in ids:
            mismatches.append(f"{where}: node id {node_id} not in graph version {graph['graph_version']}")
            return
        node = next(n for n in graph["nodes"] if n["id"] == node_id)
        lo, hi = node["box_min_m"], node["box_max_m"]
        if not all(lo[i] - 1e-4 <= v <= hi[i] + 1e-4 for i, v in enumerate((x, y, z))):
            mismatches.append(f"{where}: a point of node {node_id} outside its box")
            return
    if graph["nodes"] and not seen:
        mismatches.append(f"{where}: no points for a graph of {len(graph['nodes'])} nodes")


def main(path, schema_dir, needles=()):
    foxglove = FoxgloveSchemas(schema_dir)
    embedded = {}
    out = {
        "channels": {},
        "log_time_ordered": True,
        "stamps_ordered": {},
        "scene_versions_checked": 0,
        "scene_mismatches": [],
        "last_graph": None,
        "metadata": {},
        "point_clouds_checked": 0,
        "point_cloud_mismatches": [],
        "detections": 0,
        "detections_off_keyframes": [],
        "llm_exchanges": [],
        "compressed_formats": {},
        "message_texts_with": {},
        "foxglove_validated": {},
        "foxglove_errors": [],
        "embedded_validated": 0,
        "embedded_errors": [],
        "world_frames": {},
        "error": None,
    }

    def report(key, errors):
        for e in errors:
            if len(out[key]) < MAX_ERRORS:
                out[key].append(e)

    graphs = {}
    graph_by_stamp = {}
    keyframe_stamps = set()
    detection_stamps = []
    clouds = []
    scenes = []
    up_axis = "z"
    protobuf = Protobuf()
    last_log = -1
    last_stamp = {}
    with open(path, "rb") as f:
        reader = NonSeekingReader(f, validate_crcs=True)
        try:
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                topic = channel.topic
                entry = out["channels"].setdefault(
                    topic,
                    {
                        "schema": schema.name if schema else "",
                        "schema_encoding": schema.encoding if schema else "",
                        "message_encoding": channel.message_encoding,
                        "count": 0,
                    },
                )
                entry["count"] += 1
                if message.log_time < last_log:
                    out["log_time_ordered"] = False
                last_log = message.log_time
                if channel.message_encoding == "protobuf":
                    decoded = protobuf.decode(schema, message.data)
                else:
                    decoded = json.loads(message.data)
                where = f"{topic}[{entry['count'] - 1}]"
                name = schema.name if schema else ""
                if name.startswith("foxglove."):
                    validator = foxglove.validator(name)
                    if validator is None:
                        report("foxglove_errors", [f"{where}: schema {name} is not one Foxglove publishes"])
                    else:
                        report("foxglove_errors", violations(validator, decoded, where))
                        out["foxglove_validated"][name] = out["foxglove_validated"].get(name, 0) + 1
                    if name == "foxglove.CompressedImage" and isinstance(decoded.get("data"), str):
                        fmt = decoded.get("format", "")
                        try:
                            head = base64.b64decode(decoded["data"], validate=True)[:8]
                            magic = {"png": b"\x89PNG\r\n\x1a\n", "jpeg": b"\xff\xd8\xff"}.get(fmt)
                            if magic is None or not head.startswith(magic):
                                report("foxglove_errors", [f"{where}: data is not a {fmt!r} image"])
                            else:
                                out["compressed_formats"][fmt] = out["compressed_formats"].get(fmt, 0) + 1
                        except ValueError as e:
                            report("foxglove_errors", [f"{where}: data: not base64: {e}"])
                    if name == "foxglove.RawImage" and isinstance(decoded.get("data"), str):
                        try:
                            size = len(base64.b64decode(decoded["data"], validate=True))
                            if size != decoded.get("step", 0) * decoded.get("height", 0):
                                report("foxglove_errors", [f"{where}: data: {size} bytes, step * height differs"])
                        except ValueError as e:
                            report("foxglove_errors", [f"{where}: data: not base64: {e}"])
                if schema is not None and schema.encoding == "jsonschema":
                    if schema.id not in embedded:
                        embedded[schema.id] = Draft7Validator(strict(json.loads(schema.data)))
                    report("embedded_errors", violations(embedded[schema.id], decoded, where))
                    out["embedded_validated"] += 1
                s = stamp(decoded)
                frame = None
                if topic == "/tf":
                    frame = decoded.get("parent_frame_id")
                elif topic == "/op3dsg/node_points":
                    frame = decoded.get("frame_id")
                elif topic == "/op3dsg/health":
                    frame = decoded.get("world_frame")
                frames = [frame] if frame is not None else []
                if topic == "/op3dsg/scene":
                    frames = [e["frame_id"] for e in decoded.get("entities", [])]
                for frame in frames:
                    seen = out["world_frames"].setdefault(topic, [])
                    if frame not in seen:
                        seen.append(frame)
                        seen.sort()
                if topic == "/op3dsg/graph":
                    graphs[decoded["graph_version"]] = decoded
                    graph_by_stamp.setdefault(decoded["stamp_ns"], []).append(decoded)
                    out["last_graph"] = message.data.decode("utf-8")
                elif topic == "/op3dsg/scene":
                    scenes.append(decoded)
                elif topic == "/tf":
                    keyframe_stamps.add(s)
                elif topic == "/op3dsg/detections":
                    out["detections"] += len(decoded["points"])
                    detection_stamps.append((where, s))
                elif topic == "/op3dsg/node_points":
                    clouds.append((where, s, decoded))
                elif topic == "/op3dsg/llm":
                    out["llm_exchanges"].append(decoded)
                for needle in needles:
                    if needle.encode("utf-8") in message.data:
                        hits = out["message_texts_with"].setdefault(needle, [])
                        if len(hits) < MAX_ERRORS:
                            hits.append(where)
                if s is not None:
                    out["stamps_ordered"].setdefault(topic, True)
                    if s < last_stamp.get(topic, -1):
                        out["stamps_ordered"][topic] = False
                    last_stamp[topic] = s
        except Exception as e:  # noqa: BLE001 - the test reports what stopped the reader
            out["error"] = f"{type(e).__name__}: {e}"
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f).records:  # metadata records in file order
                if type(record).__name__ == "Metadata":
                    out["metadata"][record.name] = {k: v for k, v in record.metadata.items() if k != "toml"}
                    if "toml" in record.metadata:
                        world = tomllib.loads(record.metadata["toml"]).get("world", {})
                        up_axis = world.get("up_axis", up_axis)
        except Exception:  # noqa: BLE001 - truncated: metadata up to the cut
            pass
    for where, s, cloud in clouds:
        # The fusion thread offers a version's points as it publishes it; the graph message may
        # be written before or after: any graph version with the cloud's stamp must fit it.
        problems = []
        for graph in graph_by_stamp.get(s, [None]):
            found = []
            check_cloud(cloud, graph, where, found)
            problems.append(found)
            if not found:
                break
        if problems[-1]:
            out["point_cloud_mismatches"].extend(problems[0])
        out["point_clouds_checked"] += 1
    for where, s in detection_stamps:
        if s not in keyframe_stamps:
            out["detections_off_keyframes"].append(f"{where}: stamp {s} ns is no keyframe's")
    for scene in scenes:
        nodes = [e for e in scene["entities"] if e["id"].startswith("node/")]
        meta = {kv["key"]: kv["value"] for e in scene["entities"] for kv in e["metadata"] if kv["key"] == "graph_version"}
        version = int(meta["graph_version"]) if "graph_version" in meta else None
        graph = graphs.get(version)
        if graph is None:
            continue
        out["scene_versions_checked"] += 1
        by_id = {n["id"]: n for n in graph["nodes"]}
        if len(nodes) != len(by_id):
            out["scene_mismatches"].append(f"version {version}: {len(nodes)} cubes, {len(by_id)} nodes")
        for entity in nodes:
            node = by_id.get(int(entity["id"].split("/")[1]))
            if node is None:
                out["scene_mismatches"].append(f"version {version}: {entity['id']} not in the graph")
                continue
            cube = entity["cubes"][0]
            obb = node["obb"]
            position = [cube["pose"]["position"][a] for a in "xyz"]
            size = [cube["size"][a] for a in "xyz"]
            for i, axis in enumerate("xyz"):
                if abs(position[i] - obb["centre_m"][i]) > 1e-6 or abs(size[i] - obb["size_m"][i]) > 1e-6:
                    out["scene_mismatches"].append(f"version {version}: {entity['id']} {axis} differs from the oriented box")
            # The cube's x axis is the box's first axis: the world's first horizontal axis turned
            # by the yaw towards the second, about up (world.up_axis of the recorded profile).
            first, second, up = HORIZONTAL_FRAMES[up_axis]
            c, s_ = math.cos(obb["yaw_rad"]), math.sin(obb["yaw_rad"])
            want = [c * first[i] + s_ * second[i] for i in range(3)]
            q = cube["pose"]["orientation"]
            got = rotate((q["x"], q["y"], q["z"], q["w"]), (1.0, 0.0, 0.0))
            got_z = rotate((q["x"], q["y"], q["z"], q["w"]), (0.0, 0.0, 1.0))
            if any(abs(got[i] - want[i]) > 1e-5 or abs(got_z[i] - up[i]) > 1e-5 for i in range(3)):
                out["scene_mismatches"].append(f"version {version}: {entity['id']} orientation {got} is not yaw {obb['yaw_rad']}")
            if entity["texts"][0]["text"] != node["label"]:
                out["scene_mismatches"].append(f"version {version}: {entity['id']} label differs")
    print(json.dumps(out))


if __name__ == "__main__":
    args = sys.argv[1:]
    # --find TEXT (repeatable): list the messages whose decompressed data contains TEXT.
    needles = []
    while "--find" in args:
        i = args.index("--find")
        needles.append(args[i + 1])
        del args[i : i + 2]
    here = os.path.dirname(os.path.abspath(__file__))
    schemas = os.path.join(here, "..", "..", ".deps", "foxglove-schemas", SCHEMA_VERSION)
    if len(args) == 3 and args[1] == "--foxglove-schemas":
        schemas = args[2]
    elif len(args) != 1:
        sys.exit("usage: mcap_check.py FILE [--foxglove-schemas DIR]")
    main(args[0], os.path.normpath(schemas), needles)
