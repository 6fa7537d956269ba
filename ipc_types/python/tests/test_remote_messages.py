"""The Zenoh message format of docs/remote.md against :mod:`op3dsg.remote`'s reader, without a
daemon: messages written here byte by byte as the document lays them out (full graphs, deltas,
health, occupancy), then the follower's rules (stale, gaps, restarts) and a clear error for
every malformed message. The live daemon's messages: ``test_remote_live.py``."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import op3dsg
from op3dsg import remote, wire
from op3dsg.occupancy import OccupancyHeader

KEY = "op3dsg/test/graph"
INSTANCE = 0x1234_5678_9ABC_DEF0


def envelope(kind: int, instance: int, version: int, base: int = 0, magic: bytes = b"O3DZ", fmt: int = 1) -> bytes:
    # docs/remote.md, "Envelope (40 bytes)".
    return magic + struct.pack("<HHQQQQ", fmt, kind, instance, version, base, 1_700_000_000_000_000_000)


def header(instance: int, version: int, nodes: int, edges: int, schema: int = wire.SCHEMA_VERSION) -> bytes:
    # docs/remote.md, "Graph header (112 bytes)".
    out = struct.pack("<IIQQQQIII", schema, nodes, version, instance, 42 * version, 7, edges, nodes, 0)
    out += bytes([0, 3, 0, 0])  # capacity_exceeded, source_kind synthetic, reserved
    out += struct.pack("<IIII", nodes, edges, 16384, 32768)
    out += b"world".ljust(32, b"\0") + bytes(8)
    assert len(out) == 112
    return out


def node(node_id: int, label: str, x: float = 0.0, kind: int = 0, parent: int = wire.NO_NODE) -> bytes:
    # docs/remote.md, "Node record (144 bytes)": the fields this test sets, the rest zero.
    out = bytearray(144)
    struct.pack_into("<IIB", out, 0, node_id, parent, kind)
    out[16 : 16 + len(label)] = label.encode()
    struct.pack_into("<f3f", out, 64, 0.9, x, 1.0, 2.0)
    return bytes(out)


def edge(source: int, target: int, phrase: str = "on", confidence: float = 1.0, kind: int = 0, origin: int = 0) -> bytes:
    out = bytearray(64)
    struct.pack_into("<IIBBHf", out, 0, source, target, kind, origin, 1, confidence)
    out[16 : 16 + len(phrase)] = phrase.encode()
    return bytes(out)


def full(instance: int, version: int, nodes, edges) -> bytes:
    return envelope(1, instance, version) + header(instance, version, len(nodes), len(edges)) + b"".join(nodes) + b"".join(edges)


def delta(instance, version, base, node_count, edge_count, upserted=(), removed=(), added=(), gone=()) -> bytes:
    # docs/remote.md, "Delta (kind 2)": counts, nodes upserted, edges added, edges removed, nodes removed.
    out = envelope(2, instance, version, base) + header(instance, version, node_count, edge_count)
    out += struct.pack("<4I", len(upserted), len(removed), len(added), len(gone))
    out += b"".join(upserted) + b"".join(added) + b"".join(gone)
    return out + struct.pack(f"<{len(removed)}I", *removed)


CABINET, HANDLE, SINK = node(3, "cabinet", 1.0), node(5, "handle", 1.5, kind=1, parent=3), node(9, "sink", 2.0)
PART_OF = edge(5, 3, "part of")
NEXT_TO = edge(9, 3, "next to", 0.5)


def follower_at_version_1() -> remote.RemoteFollower:
    f = remote.RemoteFollower(KEY)
    assert f.apply(full(INSTANCE, 1, [CABINET, HANDLE], [PART_OF])) == "full"
    return f


def test_a_full_graph_then_deltas_give_the_graph_of_each_version():
    f = follower_at_version_1()
    assert f.held() == (INSTANCE, 1)
    graph = f.graph()
    assert isinstance(graph, op3dsg.Graph) and (graph.version, graph.instance_id) == (1, INSTANCE)
    assert graph.labels() == ["cabinet", "handle"] and graph.edge_count == 1
    assert graph.to_dict()["nodes"][1]["parent"] == 3 and graph.world_frame == "world" and graph.source_kind == "synthetic"

    # Version 2: the sink is new, the handle moved, a second edge; one delta.
    moved = node(5, "handle", 1.75, kind=1, parent=3)
    assert f.apply(delta(INSTANCE, 2, 1, 3, 2, upserted=[moved, SINK], added=[NEXT_TO])) == "delta"
    graph = f.graph()
    assert graph.version == 2 and list(graph.nodes["id"]) == [3, 5, 9], "nodes sorted by id, as over iceoryx2"
    assert graph.nodes["centre_m"][graph.index_of(5)][0] == np.float32(1.75)
    assert sorted(graph.phrase(i) for i in range(graph.edge_count)) == ["next to", "part of"]

    # Version 3: the edge's confidence changed (old record out, new in), the cabinet's handle gone.
    surer = edge(9, 3, "next to", 0.75)
    assert f.apply(delta(INSTANCE, 3, 2, 2, 1, removed=[5], added=[surer], gone=[NEXT_TO, PART_OF])) == "delta"
    graph = f.graph()
    assert graph.labels() == ["cabinet", "sink"] and graph.edge_count == 1
    assert graph.edges["confidence"][0] == np.float32(0.75)
    assert f.counters == {"fulls": 1, "deltas_applied": 2, "stale": 0, "gaps": 0, "restarts": 0}


def test_two_equal_edges_stay_two_and_one_removal_removes_one():
    f = remote.RemoteFollower(KEY)
    f.apply(full(INSTANCE, 1, [CABINET, SINK], [NEXT_TO, NEXT_TO]))
    assert f.graph().edge_count == 2
    f.apply(delta(INSTANCE, 2, 1, 2, 1, gone=[NEXT_TO]))
    assert f.graph().edge_count == 1


def test_old_and_repeated_messages_are_stale_and_change_nothing():
    f = follower_at_version_1()
    f.apply(delta(INSTANCE, 2, 1, 3, 1, upserted=[SINK]))
    assert f.apply(full(INSTANCE, 2, [CABINET], [])) == "stale", "a full graph of the version held"
    assert f.apply(delta(INSTANCE, 2, 1, 3, 1, upserted=[SINK])) == "stale"
    assert f.held() == (INSTANCE, 2) and f.graph().node_count == 3 and f.counters["stale"] == 2


def test_a_gap_drops_the_graph_until_the_next_full_graph():
    f = follower_at_version_1()
    assert f.apply(delta(INSTANCE, 4, 3, 3, 1, upserted=[SINK])) == "need_full", "versions 2 and 3 were lost"
    assert f.held() is None and f.graph() is None and f.counters["gaps"] == 1
    assert f.apply(full(INSTANCE, 4, [CABINET, HANDLE, SINK], [PART_OF])) == "full"
    assert f.held() == (INSTANCE, 4) and f.counters["restarts"] == 0


def test_a_new_instance_is_a_restart_whatever_its_versions():
    f = follower_at_version_1()
    f.apply(delta(INSTANCE, 2, 1, 3, 1, upserted=[SINK]))
    other = INSTANCE + 1
    # The new daemon's first delta comes before its full graph: not a gap, but no base either.
    assert f.apply(delta(other, 2, 1, 1, 0, removed=[5])) == "need_full"
    assert f.counters["gaps"] == 0 and f.held() is None
    assert f.apply(full(other, 1, [SINK], [])) == "full", "version 1 < 2, but of another instance"
    assert f.held() == (other, 1) and f.instances == [INSTANCE, other] and f.counters["restarts"] == 1


@pytest.mark.parametrize(
    "message,error",
    [
        (b"O3DZ", "message of 4 bytes, shorter than the 40-byte envelope"),
        (envelope(1, INSTANCE, 1, magic=b"NOPE") + bytes(112), "not an op3dsg message of format 1 (magic b'NOPE', format 1)"),
        (envelope(1, INSTANCE, 1, fmt=2) + bytes(112), "not an op3dsg message of format 1 (magic b'O3DZ', format 2)"),
        (envelope(9, INSTANCE, 1) + bytes(112), "unknown message kind 9"),
        (envelope(3, INSTANCE, 1) + b"{}", "a health message, not a graph or a delta"),
        (envelope(1, INSTANCE, 1) + bytes(50), "graph message of 90 bytes, shorter than envelope and graph header (152)"),
        (envelope(1, INSTANCE, 2) + header(INSTANCE, 1, 0, 0), "envelope (instance 0x123456789abcdef0, version 2) and graph header"),
        (full(INSTANCE, 1, [CABINET], [])[:-1], "payload: 143 bytes, but the header's counts need 144"),
        (full(INSTANCE, 1, [node(1, "x", kind=7)], []), "nodes[0].kind: unknown value 7"),
        (full(INSTANCE, 1, [CABINET], [edge(3, 3, origin=9)]), "edges[0].origin: unknown value 9"),
    ],
)
def test_a_malformed_message_is_a_clear_error_naming_the_key(message, error):
    f = remote.RemoteFollower(KEY)
    with pytest.raises(op3dsg.InvalidRemoteMessageError) as raised:
        f.apply(message)
    assert str(raised.value).startswith(f"{KEY}: receive: invalid message: ")
    assert error in str(raised.value)
    assert f.held() is None


def test_another_schema_version_is_a_schema_version_error():
    f = remote.RemoteFollower(KEY)
    message = envelope(1, INSTANCE, 1) + header(INSTANCE, 1, 0, 0, schema=wire.SCHEMA_VERSION + 1)
    with pytest.raises(op3dsg.SchemaVersionError, match=f"found {wire.SCHEMA_VERSION + 1}, this package reads {wire.SCHEMA_VERSION}"):
        f.apply(message)


@pytest.mark.parametrize(
    "bad,error",
    [
        (delta(INSTANCE, 2, 1, 2, 1, upserted=[SINK])[:-1], "its counts describe"),
        (delta(INSTANCE, 2, 1, 2, 0, gone=[NEXT_TO]), "removes an edge the graph of version 1 lacks"),
        (delta(INSTANCE, 2, 1, 1, 1, removed=[9]), "removes node 9, absent from version 1"),
        (delta(INSTANCE, 2, 1, 5, 1, upserted=[SINK]), "after the delta to version 2: 3 nodes and 1 edges, its header says 5 and 1"),
    ],
)
def test_a_delta_that_does_not_fit_is_an_error_and_leaves_no_half_applied_graph(bad, error):
    f = follower_at_version_1()
    with pytest.raises(op3dsg.InvalidRemoteMessageError, match=error):
        f.apply(bad)
    if "counts describe" in error:
        assert f.held() == (INSTANCE, 1), "a message cut short is refused before anything is applied"
    else:
        assert f.held() is None, "a delta that does not fit its base drops the graph: the next full graph starts again"
    assert f.apply(full(INSTANCE, 3, [CABINET], [])) == "full"


def test_health_and_occupancy_messages_decode_and_refuse_bad_bodies():
    record = {"schema_version": wire.SCHEMA_VERSION, "stages": [{"name": "capture", "processed": 3}]}
    health = remote.decode_health("p/health", envelope(3, INSTANCE, 12) + json.dumps(record).encode())
    assert (health.instance_id, health.graph_version, health.stage("capture")["processed"]) == (INSTANCE, 12, 3)
    with pytest.raises(op3dsg.InvalidRemoteMessageError, match="p/health: receive: invalid message: health record is not UTF-8 JSON"):
        remote.decode_health("p/health", envelope(3, INSTANCE, 12) + b"{not json")

    h = OccupancyHeader(schema_version=1, width_cells=4, height_cells=3, cell_size_m=0.5, origin_x_m=-1.0, origin_y_m=-2.0, instance_id=INSTANCE)
    cells = np.arange(12, dtype=np.int8) * 10 - 1
    message = envelope(4, INSTANCE, 5) + bytes(h) + cells.tobytes()
    grid = remote.decode_occupancy("p/occupancy", message)
    assert grid.version == 5 and grid.cells.shape == (3, 4) and grid.cells[2, 3] == 109
    assert not grid.cells.flags.writeable
    assert grid.cell_of(-0.9, -1.9) == (0, 0) and grid.cell_of(0.9, -0.6) == (2, 3) and grid.cell_of(1.1, 0.0) is None
    assert grid.centre_of(0, 0) == (-0.75, -1.75) and grid.width_cells == 4 and grid.up_axis == "z"
    assert grid.unknown().sum() == 1 and grid.occupied().sum() == 5 and grid.free().sum() == 3
    with pytest.raises(op3dsg.InvalidRemoteMessageError, match=r"11 cell bytes, but width_cells \* height_cells = 4 \* 3 = 12"):
        remote.decode_occupancy("p/occupancy", message[:-1])
    with pytest.raises(op3dsg.InvalidRemoteMessageError, match="occupancy header instance"):
        remote.decode_occupancy("p/occupancy", envelope(4, INSTANCE + 1, 5) + bytes(h) + cells.tobytes())


def test_the_occupancy_header_has_the_rust_layout():
    # ipc_types/src/occupancy_types.rs, test layout_is_the_documented_one.
    assert (OccupancyHeader.up_axis.offset, OccupancyHeader.instance_id.offset) == (36, 40)
    assert (OccupancyHeader.robot_x_m.offset, OccupancyHeader.reserved2.offset) == (80, 108)
    import ctypes

    assert ctypes.sizeof(OccupancyHeader) == 112 and ctypes.alignment(OccupancyHeader) == 8


def test_bad_endpoints_and_key_prefixes_are_refused_naming_them():
    with pytest.raises(op3dsg.InvalidEndpointError, match="'127.0.0.1:7447' is not a Zenoh endpoint"):
        op3dsg.RemoteGraphClient("127.0.0.1:7447", "op3dsg/x")
    with pytest.raises(op3dsg.InvalidEndpointError, match="key_prefix 'op3dsg/\\*\\*': has the wildcard characters"):
        op3dsg.RemoteGraphClient("tcp/127.0.0.1:7447", "op3dsg/**")
    with pytest.raises(op3dsg.InvalidEndpointError, match="key_prefix 'op3dsg/': must not start or end with '/'"):
        op3dsg.remote_health("tcp/127.0.0.1:7447", "op3dsg/")


def test_nothing_listening_fails_in_time_naming_the_endpoint():
    import socket

    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(op3dsg.RemoteError) as raised:
        op3dsg.RemoteGraphClient(f"tcp/127.0.0.1:{port}", "op3dsg/x", timeout=0.3)
    assert f"nothing answered at tcp/127.0.0.1:{port} within 0.3 s" in str(raised.value)
    assert str(raised.value).startswith("op3dsg/x/graph: connect: ")


def test_without_zenoh_the_package_imports_and_a_remote_client_says_what_to_install():
    script = (
        "import sys; sys.modules['zenoh'] = None\n"  # what a missing module looks like to import
        "import op3dsg\n"
        "try:\n"
        "    op3dsg.RemoteGraphClient('tcp/127.0.0.1:7447', 'op3dsg/x')\n"
        "except ImportError as e:\n"
        "    print(e)\n"
    )
    package = str(Path(op3dsg.__file__).resolve().parents[1])
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, env=dict(os.environ, PYTHONPATH=package))
    assert out.returncode == 0, out.stderr
    assert 'pip install "op3dsg[zenoh]"' in out.stdout, out.stdout
