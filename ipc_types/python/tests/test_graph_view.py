"""The lookups of ``GraphView`` (the Rust ``GraphView``'s, by index) against ``op3dsg dump --json``
of a live daemon; the refusal of malformed samples (crafted bytes: a short header, counts past the
end, a misaligned block, another schema version) and the record check naming unknown kinds; the
``OP3DSG_PREFIX`` default; ``with`` for views and query clients; the ``py.typed`` marker."""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np
import pytest

import op3dsg
from op3dsg import wire
from op3dsg.query import QUERY_MAX_CLIENTS

from conftest import FAST, wait_for
from test_live_daemon import dump_json, graph_with_parts

HEADER_BYTES = ctypes.sizeof(wire.GraphHeader)


# -- crafted bytes ---------------------------------------------------------------------------
def kitchen_bytes(schema: int = wire.SCHEMA_VERSION) -> bytes:
    """A small kitchen as one sample (header, nodes, edges): a cabinet (1) with two handles (2, 3),
    a stove (10) with a knob (11), an unattached button (20)."""
    nodes = np.zeros(6, wire.NODE_DTYPE)
    rows = [
        (1, wire.NO_NODE, 0, "cabinet", []),
        (2, 1, 1, "Cabinet Handle", ["hook_pull"]),
        (3, 1, 1, "drawer handle", ["hook_pull", "pinch_pull"]),
        (10, wire.NO_NODE, 0, "stove", []),
        (11, 10, 1, "knob", ["rotate"]),
        (20, wire.NO_NODE, 1, "button", ["tip_push"]),
    ]
    for i, (node_id, parent, kind, label, affordances) in enumerate(rows):
        nodes["id"][i], nodes["parent_id"][i], nodes["kind"][i] = node_id, parent, kind
        nodes["label"][i] = label.encode()
        nodes["affordance_bits"][i] = wire.affordance_bits(affordances)
    edges = np.zeros(4, wire.EDGE_DTYPE)
    for i, (source, target, phrase) in enumerate([(2, 1, "part of"), (3, 1, "part of"), (11, 10, "part of"), (1, 10, "next to")]):
        edges["source_id"][i], edges["target_id"][i] = source, target
        edges["relation_id"][i] = wire.SPATIAL_RELATIONS.index(phrase)
        edges["phrase"][i] = phrase.encode()
    header = wire.GraphHeader()
    header.schema_version = schema
    header.graph_version = 7
    header.node_count, header.edge_count = len(nodes), len(edges)
    header.node_capacity, header.edge_capacity = wire.MAX_NODES, wire.MAX_EDGES
    return bytes(header) + nodes.tobytes() + edges.tobytes()


def aligned(data: bytes, shift: int = 0) -> np.ndarray:
    """``data`` in a buffer that starts ``shift`` bytes past an 8-byte boundary."""
    words = np.zeros(len(data) // 8 + 2, np.uint64).view(np.uint8)
    assert words.ctypes.data % 8 == 0
    words[shift : shift + len(data)] = np.frombuffer(data, np.uint8)
    return words[shift : shift + len(data)]


def with_header(data: bytes, **fields) -> bytes:
    header = wire.GraphHeader.from_buffer_copy(data[:HEADER_BYTES])
    for name, value in fields.items():
        setattr(header, name, value)
    return bytes(header) + data[HEADER_BYTES:]


def test_lookups_by_index_on_a_sample_read_in_place():
    graph = op3dsg.Graph.from_bytes(aligned(kitchen_bytes()))
    ids = lambda indices: [int(graph.nodes["id"][i]) for i in indices]  # noqa: E731
    edge_ends = lambda indices: [(int(graph.edges["source_id"][i]), int(graph.edges["target_id"][i])) for i in indices]  # noqa: E731
    assert (graph.version, graph.node_count, graph.edge_count) == (7, 6, 4)
    assert not graph.nodes.flags.writeable, "read in place, read-only"
    assert graph.node(2)["label"] == "Cabinet Handle" and graph.node(2)["parent"] == 1
    assert graph.node(4) is None and graph.index_of(20) == 5
    assert ids(graph.parts_of(1)) == [2, 3] and ids(graph.parts_of(99)) == []
    assert graph.parent_of(11) == graph.index_of(10)
    assert graph.parent_of(20) is None and graph.parent_of(1) is None and graph.parent_of(99) is None
    assert edge_ends(graph.edges_from(2)) == [(2, 1)] and edge_ends(graph.edges_to(10)) == [(11, 10), (1, 10)]
    assert graph.edges_from(99).size == 0
    assert ids(graph.find_by_label("knob")) == [11] and ids(graph.find_by_label("handle")) == []
    assert ids(graph.find_by_label_containing("HANDLE")) == [2, 3]
    assert ids(graph.find_by_label_containing("")) == [1, 2, 3, 10, 11, 20]
    assert ids(graph.find_by_affordance("hook_pull")) == [2, 3]
    assert ids(graph.find_by_affordance_bits(wire.affordance_bits(["hook_pull", "pinch_pull"]))) == [3]
    with pytest.raises(ValueError, match="unknown affordance 'fly'"):
        graph.find_by_affordance("fly")


def test_a_short_header_counts_past_the_end_and_a_misaligned_block_are_refused():
    data = kitchen_bytes()
    for cut in (0, 50, HEADER_BYTES - 1):
        with pytest.raises(op3dsg.InvalidGraphError, match=f"header: {cut} bytes, but a GraphHeader has 112"):
            op3dsg.Graph.from_bytes(aligned(data[:cut]))
    payload = len(data) - HEADER_BYTES
    more = with_header(data, node_count=7)
    with pytest.raises(op3dsg.InvalidGraphError, match=f"payload: {payload} bytes, but the header's counts need {payload + 144}"):
        op3dsg.Graph.from_bytes(aligned(more))
    with pytest.raises(op3dsg.InvalidGraphError, match=f"payload: {payload - 10} bytes"):
        op3dsg.Graph.from_bytes(aligned(data[:-10]))
    huge = with_header(data, node_count=2**32 - 1, edge_count=2**32 - 1, node_capacity=2**32 - 1, edge_capacity=2**32 - 1)
    with pytest.raises(op3dsg.InvalidGraphError, match=f"payload: {payload} bytes"):
        op3dsg.Graph.from_bytes(aligned(huge))
    with pytest.raises(op3dsg.InvalidGraphError, match="header.edge_count: 4 exceeds the capacity 2"):
        op3dsg.Graph.from_bytes(aligned(with_header(data, edge_capacity=2)))
    shifted = aligned(data, shift=1)
    with pytest.raises(op3dsg.InvalidGraphError) as error:
        op3dsg.Graph.from_bytes(shifted)
    assert f"header: starts at address {shifted.ctypes.data:#x}, not a multiple of 8" in str(error.value)
    assert "cannot be read in place" in str(error.value)


def test_another_schema_version_is_refused_and_unknown_kinds_are_named_by_the_record_check():
    with pytest.raises(op3dsg.SchemaVersionError) as error:
        op3dsg.Graph.from_bytes(aligned(kitchen_bytes(schema=wire.SCHEMA_VERSION + 1)))
    assert (error.value.found, error.value.expected) == (wire.SCHEMA_VERSION + 1, wire.SCHEMA_VERSION)
    op3dsg.Graph.from_bytes(aligned(kitchen_bytes())).check_records()
    data = bytearray(kitchen_bytes())
    data[HEADER_BYTES + 4 * wire.NODE_BYTES + 8] = 9  # nodes[4].kind
    graph = op3dsg.Graph.from_bytes(aligned(bytes(data)), source="kitchen.bin")
    with pytest.raises(op3dsg.InvalidGraphError, match=r"kitchen.bin: receive: invalid sample: nodes\[4\].kind: unknown value 9"):
        graph.check_records()
    with pytest.raises(op3dsg.InvalidGraphError, match=r"nodes\[4\].kind: unknown value 9"):
        graph.node(11)
    data = bytearray(kitchen_bytes())
    data[HEADER_BYTES + 6 * wire.NODE_BYTES + 3 * wire.EDGE_BYTES + 9] = 4  # edges[3].origin
    graph = op3dsg.Graph.from_bytes(aligned(bytes(data)))
    with pytest.raises(op3dsg.InvalidGraphError, match=r"edges\[3\].origin: unknown value 4"):
        graph.check_records()
    with pytest.raises(op3dsg.InvalidGraphError, match=r"edges\[3\].origin: unknown value 4"):
        graph.edge_dict(3)


def test_the_prefix_defaults_to_op3dsg_prefix_then_op3dsg(monkeypatch):
    monkeypatch.delenv(wire.PREFIX_ENV, raising=False)
    assert op3dsg.default_prefix() == "op3dsg"
    monkeypatch.setenv(wire.PREFIX_ENV, "")
    assert op3dsg.default_prefix() == "op3dsg", "empty is unset"
    monkeypatch.setenv(wire.PREFIX_ENV, "lab/robot-1")
    assert op3dsg.default_prefix() == "lab/robot-1"
    monkeypatch.setenv(wire.PREFIX_ENV, "two words")
    with pytest.raises(op3dsg.InvalidPrefixError, match="invalid character ' '"):
        op3dsg.GraphClient()


def test_the_package_carries_its_type_hints():
    package = Path(op3dsg.__file__).parent
    assert (package / "py.typed").is_file()
    pyproject = (package.parent / "pyproject.toml").read_text()
    assert '[tool.setuptools.package-data]\n' in pyproject and 'op3dsg = ["py.typed"]' in pyproject


# -- a live daemon ----------------------------------------------------------------------------
def test_view_lookups_equal_op3dsg_dump_json_at_the_same_version(prefix, daemons):
    daemons(prefix, FAST + ["--set", "run.max_frames=150"])
    client = op3dsg.GraphClient(prefix, timeout=30)
    graph_with_parts(client)
    for _ in range(20):
        client.wait_for_update(0.2)
        dumped = dump_json(prefix)
        view = client.latest()
        if view.version == dumped["graph_version"]:
            break
    else:
        raise AssertionError(f"never met op3dsg dump at one version (last {view.version} vs {dumped['graph_version']})")

    with view:
        node_ids = [int(i) for i in view.nodes["id"]]
        edge_ids = lambda indices: [(int(view.edges["source_id"][i]), int(view.edges["target_id"][i])) for i in indices]  # noqa: E731
        for expected in dumped["nodes"]:
            node_id = expected["id"]
            assert view.node(node_id) == expected, node_id
            parent = view.parent_of(node_id)
            assert (None if parent is None else node_ids[parent]) == expected["parent"], node_id
            assert [node_ids[i] for i in view.parts_of(node_id)] == [n["id"] for n in dumped["nodes"] if n["parent"] == node_id]
            assert edge_ids(view.edges_from(node_id)) == [(e["source"], e["target"]) for e in dumped["edges"] if e["source"] == node_id]
            assert edge_ids(view.edges_to(node_id)) == [(e["source"], e["target"]) for e in dumped["edges"] if e["target"] == node_id]
            assert [node_ids[i] for i in view.find_by_label(expected["label"])] == [
                n["id"] for n in dumped["nodes"] if n["label"] == expected["label"]
            ]
        for name in wire.AFFORDANCES:
            assert [node_ids[i] for i in view.find_by_affordance(name)] == [n["id"] for n in dumped["nodes"] if name in n["affordances"]]
        assert [node_ids[i] for i in view.find_by_label_containing("HANDLE")] == [
            n["id"] for n in dumped["nodes"] if "handle" in n["label"].lower()
        ]
        assert view.node(max(node_ids) + 1) is None
    assert not view.valid, "the with block gave the sample back"
    with pytest.raises(op3dsg.SampleReleasedError):
        _ = view.nodes


def test_clients_take_their_prefix_from_op3dsg_prefix(prefix, daemons, monkeypatch):
    daemons(prefix)
    monkeypatch.setenv(wire.PREFIX_ENV, prefix)
    with op3dsg.GraphClient(timeout=30) as graphs:
        assert graphs.service == f"{prefix}/graph"
        assert graph_with_parts(graphs).node_count > 0
    assert op3dsg.health(timeout=30).graph_version >= 0
    with op3dsg.OccupancyClient(timeout=30) as maps, op3dsg.QueryClient(timeout=30) as queries:
        assert (maps.service, queries.service) == (f"{prefix}/occupancy", f"{prefix}/query")
    with op3dsg.PosePublisher() as poses:
        assert poses.service == f"{prefix}/pose"
    # An explicit prefix wins over the environment.
    with pytest.raises(op3dsg.NotServingError, match=f"{prefix}-other/graph"):
        op3dsg.GraphClient(f"{prefix}-other")


def test_query_clients_close_and_free_their_slot(prefix, daemons):
    daemons(prefix)
    graphs = op3dsg.GraphClient(prefix, timeout=30)
    node_id = int(graph_with_parts(graphs).nodes["id"][0])
    with op3dsg.QueryClient(prefix, timeout=30) as client:
        assert client.query_node(node_id, timeout=20).hits[0].node_id == node_id
    assert client.closed
    with pytest.raises(op3dsg.Op3dsgError, match=f"{prefix}/query: query: the client is closed"):
        client.query_node(node_id)
    client.close()  # twice: nothing

    # Every client slot taken: one more is refused, until one is closed.
    held = [op3dsg.QueryClient(prefix, timeout=5) for _ in range(QUERY_MAX_CLIENTS)]
    with pytest.raises(op3dsg.Op3dsgError, match=f"{prefix}/query"):
        op3dsg.QueryClient(prefix)
    held.pop().close()
    with op3dsg.QueryClient(prefix, timeout=5) as again:
        assert wait_for("an answer on the freed slot", 30, lambda: again.query_node(node_id, timeout=20)).hits
    for client in held:
        client.close()
