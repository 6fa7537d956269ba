"""An off-robot consumer of op3dsg's graph over Zenoh, written from docs/remote.md alone.

It uses only PyPI `eclipse-zenoh` and numpy (not the project's Python package): connects as a
client to one endpoint with scouting off, fetches the full graph from the `<prefix>/graph`
queryable, then follows `<prefix>/graph/delta`, falling back to a full graph on a gap or a new
daemon instance (a restart).

Driven by the test on stdin, one JSON command per line; it answers each on stdout, one JSON line:
  {"cmd": "state", "instance_id": I, "min_version": V, "timeout_s": T}
      waits until it holds a graph of instance I (any instance when I is 0) at version >= V,
      then answers with that graph and its counters
  {"cmd": "quit"}

Usage: zenoh_consumer.py --connect tcp/127.0.0.1:7447 --prefix op3dsg/test
"""

import argparse
import json
import queue
import sys
import threading
import time

import numpy as np
import zenoh

MAGIC = b"O3DZ"
FORMAT_VERSION = 1
KIND_GRAPH, KIND_DELTA, KIND_HEALTH = 1, 2, 3
NO_NODE = 0xFFFFFFFF

ENVELOPE = np.dtype(
    [
        ("magic", "S4"),
        ("format_version", "<u2"),
        ("kind", "<u2"),
        ("instance_id", "<u8"),
        ("version", "<u8"),
        ("base_version", "<u8"),
        ("publish_time_ns", "<u8"),
    ]
)
HEADER = np.dtype(
    {
        "names": ["schema_version", "node_count", "graph_version", "instance_id", "stamp_ns",
                  "publish_time_ns", "edge_count", "object_count", "part_count",
                  "capacity_exceeded", "source_kind", "total_node_count", "total_edge_count",
                  "node_capacity", "edge_capacity", "world_frame"],
        "formats": ["<u4", "<u4", "<u8", "<u8", "<u8", "<u8", "<u4", "<u4", "<u4", "u1", "u1",
                    "<u4", "<u4", "<u4", "<u4", "S32"],
        "offsets": [0, 4, 8, 16, 24, 32, 40, 44, 48, 52, 53, 56, 60, 64, 68, 72],
        "itemsize": 112,
    }
)
DELTA_COUNTS = np.dtype(
    [("nodes_upserted", "<u4"), ("nodes_removed", "<u4"), ("edges_added", "<u4"), ("edges_removed", "<u4")]
)
NODE = np.dtype(
    {
        "names": ["id", "parent_id", "kind", "affordance_knowledge_bits", "observation_count", "label",
                  "confidence", "centre_m", "box_min_m", "box_max_m", "affordance_bits",
                  "affordance_llm_bits", "obb_yaw_rad", "last_seen_stamp_ns", "obb_centre_m",
                  "obb_size_m"],
        "formats": ["<u4", "<u4", "u1", "<u2", "<u4", "S48", "<f4", ("<f4", 3), ("<f4", 3), ("<f4", 3),
                    "<u2", "<u2", "<f4", "<u8", ("<f4", 3), ("<f4", 3)],
        "offsets": [0, 4, 8, 10, 12, 16, 64, 68, 80, 92, 104, 106, 108, 112, 120, 132],
        "itemsize": 144,
    }
)
EDGE = np.dtype(
    {
        "names": ["source_id", "target_id", "kind", "origin", "relation_id", "confidence", "phrase"],
        "formats": ["<u4", "<u4", "u1", "u1", "<u2", "<f4", "S48"],
        "offsets": [0, 4, 8, 9, 10, 12, 16],
        "itemsize": 64,
    }
)
NODE_KINDS = ["object", "part"]
EDGE_KINDS = ["spatial", "functional"]
EDGE_ORIGINS = ["geometry", "knowledge", "llm", "knowledge+llm"]


def records(buf, at, count, size):
    """`count` records of `size` bytes from `at`, as a list of bytes, and the offset after them."""
    end = at + count * size
    return [buf[i:i + size] for i in range(at, end, size)], end


class Graph:
    """The graph as the consumer holds it: node records by id, edge records as a multiset."""

    def __init__(self, envelope, header, nodes, edges):
        self.instance_id = int(envelope["instance_id"])
        self.version = int(envelope["version"])
        self.header = header
        self.nodes = {int(np.frombuffer(r, "<u4", 1)[0]): r for r in nodes}
        self.edges = {}
        for r in edges:
            self.edges[r] = self.edges.get(r, 0) + 1

    def apply(self, envelope, header, buf, at):
        """Applies a delta that names this graph's version as its base."""
        counts = np.frombuffer(buf, DELTA_COUNTS, 1, at)[0]
        at += DELTA_COUNTS.itemsize
        upserted, at = records(buf, at, int(counts["nodes_upserted"]), NODE.itemsize)
        added, at = records(buf, at, int(counts["edges_added"]), EDGE.itemsize)
        removed, at = records(buf, at, int(counts["edges_removed"]), EDGE.itemsize)
        gone = np.frombuffer(buf, "<u4", int(counts["nodes_removed"]), at)
        at += 4 * len(gone)
        if at != len(buf):
            raise ValueError(f"delta of {len(buf)} bytes, {at} described")
        for r in upserted:
            self.nodes[int(np.frombuffer(r, "<u4", 1)[0])] = r
        for r in added:
            self.edges[r] = self.edges.get(r, 0) + 1
        for r in removed:
            left = self.edges[r] - 1  # KeyError: the delta removes an edge this graph lacks
            if left:
                self.edges[r] = left
            else:
                del self.edges[r]
        for node_id in gone:
            del self.nodes[int(node_id)]
        self.version = int(envelope["version"])
        self.header = header
        if len(self.nodes) != int(header["node_count"]) or sum(self.edges.values()) != int(header["edge_count"]):
            raise ValueError("after the delta the counts differ from its header")

    def to_json(self):
        nodes = np.frombuffer(b"".join(self.nodes[k] for k in sorted(self.nodes)), NODE)
        edge_bytes = b"".join(r * n for r, n in self.edges.items())
        edges = np.frombuffer(edge_bytes, EDGE)
        return {
            "instance_id": self.instance_id,
            "graph_version": self.version,
            "world_frame": self.header["world_frame"].decode(),
            "nodes": [
                {
                    "id": int(n["id"]),
                    "label": n["label"].decode(),
                    "kind": NODE_KINDS[n["kind"]],
                    "parent": None if n["parent_id"] == NO_NODE else int(n["parent_id"]),
                    "centre_m": [float(v) for v in n["centre_m"]],
                }
                for n in nodes
            ],
            "edges": [
                {
                    "source": int(e["source_id"]),
                    "target": int(e["target_id"]),
                    "kind": EDGE_KINDS[e["kind"]],
                    "relation": e["phrase"].decode(),
                    "origin": EDGE_ORIGINS[e["origin"]],
                }
                for e in edges
            ],
        }


def parse(buf):
    """The envelope, the graph header (None for health) and the offset after them."""
    envelope = np.frombuffer(buf, ENVELOPE, 1)[0]
    if envelope["magic"] != MAGIC or envelope["format_version"] != FORMAT_VERSION:
        raise ValueError(f"not an op3dsg message of format {FORMAT_VERSION}: {bytes(buf[:8])!r}")
    if envelope["kind"] == KIND_HEALTH:
        return envelope, None, ENVELOPE.itemsize
    header = np.frombuffer(buf, HEADER, 1, ENVELOPE.itemsize)[0]
    return envelope, header, ENVELOPE.itemsize + HEADER.itemsize


class Consumer:
    def __init__(self, connect, prefix):
        self.prefix = prefix
        self.inbox = queue.Queue()
        self.graph = None
        self.instances = []
        self.stats = {"fulls": 0, "deltas_applied": 0, "deltas_skipped": 0, "gaps": 0, "queries": 0,
                      "health": 0, "full_bytes": 0, "delta_bytes": 0}
        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints", json.dumps([connect]))
        config.insert_json5("scouting/multicast/enabled", "false")
        deadline = time.monotonic() + 60
        while True:
            try:
                self.session = zenoh.open(config)
                break
            except zenoh.ZError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        self.lock = threading.Lock()
        put = self.inbox.put
        self.subs = [
            self.session.declare_subscriber(f"{prefix}/graph", lambda s: put(s.payload.to_bytes())),
            self.session.declare_subscriber(f"{prefix}/graph/delta", lambda s: put(s.payload.to_bytes())),
            self.session.declare_subscriber(f"{prefix}/health", lambda s: put(s.payload.to_bytes())),
        ]
        threading.Thread(target=self.follow, daemon=True).start()

    def follow(self):
        """Applies what arrives, and fetches a full graph whenever it holds none."""
        while True:
            with self.lock:
                if self.graph is None:
                    self.fetch_full()
            try:
                buf = self.inbox.get(timeout=0.2)
            except queue.Empty:
                continue
            with self.lock:
                self.handle(buf)

    def seen(self, instance_id):
        if instance_id not in self.instances:
            self.instances.append(instance_id)

    def fetch_full(self):
        """The full graph from the queryable (nothing before the daemon's first version)."""
        self.stats["queries"] += 1
        for reply in self.session.get(f"{self.prefix}/graph", timeout=5.0):
            if reply.ok is not None:
                self.handle(reply.ok.payload.to_bytes())

    def handle(self, buf):
        envelope, header, at = parse(buf)
        kind, instance = int(envelope["kind"]), int(envelope["instance_id"])
        self.seen(instance)
        if kind == KIND_HEALTH:
            json.loads(bytes(buf[at:]))
            self.stats["health"] += 1
            return
        restarted = self.graph is not None and instance != self.graph.instance_id
        if kind == KIND_GRAPH:
            newer = self.graph is None or restarted or int(envelope["version"]) > self.graph.version
            if newer:
                nodes, at = records(buf, at, int(header["node_count"]), NODE.itemsize)
                edges, at = records(buf, at, int(header["edge_count"]), EDGE.itemsize)
                self.graph = Graph(envelope, header, nodes, edges)
                self.stats["fulls"] += 1
                self.stats["full_bytes"] = len(buf)
            return
        if kind != KIND_DELTA or self.graph is None:
            return
        if not restarted and int(envelope["base_version"]) == self.graph.version:
            self.graph.apply(envelope, header, buf, at)
            self.stats["deltas_applied"] += 1
            self.stats["delta_bytes"] += len(buf)
        elif not restarted and int(envelope["version"]) <= self.graph.version:
            self.stats["deltas_skipped"] += 1  # older than what we hold
        else:
            # A gap (a version lost on the way) or a new daemon instance: start again from a
            # full graph.
            self.stats["gaps"] += 1
            self.graph = None

    def state(self, instance_id, min_version, timeout_s):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                g = self.graph
                if g is not None and (instance_id in (0, g.instance_id)) and g.version >= min_version:
                    out = g.to_json()
                    out["stats"] = dict(self.stats, restarts=max(0, len(self.instances) - 1))
                    return out
            time.sleep(0.05)
        with self.lock:
            held = None if self.graph is None else [self.graph.instance_id, self.graph.version]
            return {"error": f"no graph of instance {instance_id} at version >= {min_version} within {timeout_s} s",
                    "held": held, "stats": self.stats}


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--connect", required=True)
    parser.add_argument("--prefix", required=True)
    args = parser.parse_args()
    consumer = Consumer(args.connect, args.prefix)
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        command = json.loads(line)
        if command["cmd"] == "quit":
            break
        if command["cmd"] == "state":
            answer = consumer.state(int(command["instance_id"]), int(command["min_version"]),
                                    float(command.get("timeout_s", 120)))
            print(json.dumps(answer), flush=True)
    consumer.session.close()


if __name__ == "__main__":
    main()
