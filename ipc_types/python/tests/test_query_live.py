"""``op3dsg.query`` against a live ``op3dsgd`` with the text encoder: the hits name nodes of the
graph the daemon publishes (same instance), best first, objects and parts; without the encoder
the daemon's "encoder off" answer is raised as :class:`op3dsg.QueryError`."""

from __future__ import annotations

import ctypes

import pytest

import op3dsg
from op3dsg.query import QueryHit, QueryRequest, QueryResponse

from conftest import FAST, wait_for


def test_layouts_are_the_rust_ones():
    assert (ctypes.sizeof(QueryRequest), ctypes.sizeof(QueryHit), ctypes.sizeof(QueryResponse)) == (272, 192, 3296)
    assert (QueryResponse.message.offset, QueryResponse.hits.offset) == (64, 224)
    assert (QueryRequest.node_id.offset, QueryHit.approach_status.offset, QueryHit.approach_x_m.offset) == (264, 160, 164)


def test_query_hits_are_nodes_of_the_published_graph(prefix, daemons):
    daemons(prefix, [*FAST, "--set", "text_encoder.enabled=true"])
    client = op3dsg.QueryClient(prefix, timeout=60)
    graphs = op3dsg.GraphClient(prefix, timeout=60)

    def answered():
        try:
            result = client.query("somewhere to wash my hands", k=5, timeout=20)
        except op3dsg.QueryError as e:
            assert e.status == "no_graph", e
            return None
        graph = graphs.latest()
        if graph is None or graph.version != result.graph_version:
            return None
        return result, graph.copy()

    result, graph = wait_for("a reply about a graph version also received", 120, answered)
    ids = set(int(i) for i in graph.nodes["id"])
    assert 1 <= len(result) <= 5
    assert all(hit.node_id in ids for hit in result), (result, sorted(ids))
    scores = [hit.score for hit in result]
    assert scores == sorted(scores, reverse=True)
    assert all(hit.matched in ("label", "parent_label", "affordance", "functional") for hit in result)
    assert all(hit.kind in ("object", "part") for hit in result)


def test_without_the_encoder_the_reply_says_so(prefix, daemons):
    daemons(prefix)
    with pytest.raises(op3dsg.QueryError) as raised:
        op3dsg.query("somewhere to wash my hands", prefix=prefix, timeout=60)
    assert raised.value.status == "encoder_off"
    assert "text_encoder.enabled = true" in raised.value.message
