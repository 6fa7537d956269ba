"""Reads an op3dsg MCAP recording with the independent PyPI `mcap` reader and prints a JSON
summary for the cross-process tests (tests/tests/record_daemon.rs):

    .venv/bin/python tests/python/mcap_check.py FILE

{
  "channels": {topic: {"schema", "schema_encoding", "message_encoding", "count"}},
  "log_time_ordered": bool,          # log times never decrease, whole file
  "stamps_ordered": {topic: bool},   # message timestamps never decrease, per channel
  "scene_versions_checked": int,     # SceneUpdates compared with the graph version they came from
  "scene_mismatches": [str],         # every cube that differs from its node's box
  "last_graph": str | null,          # raw bytes (utf-8) of the last /op3dsg/graph message
  "metadata": {name: {key: value}},  # the profile's text is left out
  "error": str | null                # why reading stopped before the end (truncated file)
}

Reads records in file order (NonSeekingReader), so a file without a summary (after kill -9) is
read up to where it ends; the exception that stops it is reported in "error".
"""

import json
import sys

from mcap.reader import NonSeekingReader
from mcap.stream_reader import StreamReader


def stamp(message):
    t = message.get("timestamp")
    if isinstance(t, dict):
        return t["sec"] * 1_000_000_000 + t["nsec"]
    return message.get("stamp_ns")


def main(path):
    out = {
        "channels": {},
        "log_time_ordered": True,
        "stamps_ordered": {},
        "scene_versions_checked": 0,
        "scene_mismatches": [],
        "last_graph": None,
        "metadata": {},
        "error": None,
    }
    graphs = {}
    scenes = []
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
                if topic in ("/camera/colour", "/camera/depth", "/sim/instance_ids"):
                    # Parse only the head of big images.
                    head = message.data[:200].decode("utf-8", "replace")
                    sec = int(head.split('"sec":')[1].split(",")[0])
                    nsec = int(head.split('"nsec":')[1].split("}")[0])
                    s = sec * 1_000_000_000 + nsec
                else:
                    decoded = json.loads(message.data)
                    s = stamp(decoded)
                    if topic == "/op3dsg/graph":
                        graphs[decoded["graph_version"]] = decoded
                        out["last_graph"] = message.data.decode("utf-8")
                    elif topic == "/op3dsg/scene":
                        scenes.append(decoded)
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
        except Exception:  # noqa: BLE001 - truncated: metadata up to the cut
            pass
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
            for i, axis in enumerate("xyz"):
                centre = (node["box_min_m"][i] + node["box_max_m"][i]) / 2
                size = node["box_max_m"][i] - node["box_min_m"][i]
                if abs(cube["pose"]["position"][axis] - centre) > 1e-6 or abs(cube["size"][axis] - size) > 1e-6:
                    out["scene_mismatches"].append(f"version {version}: {entity['id']} {axis} differs")
            if entity["texts"][0]["text"] != node["label"]:
                out["scene_mismatches"].append(f"version {version}: {entity['id']} label differs")
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1])
