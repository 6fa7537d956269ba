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
        # The first versions can be published before fusion has made a node: wait for a
        # graph with nodes to score.
        if graph is None or graph.version != result.graph_version or result.scored_node_count == 0:
            return None
        return result, graph.copy()

    result, graph = wait_for("a reply about a non-empty graph version also received", 120, answered)
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


def test_goal_gives_approach_poses_by_node_id_without_the_encoder(prefix, daemons):
    daemons(prefix, ["--set", "source.rate_hz=15", "--set", "health.period_ms=100"])
    client = op3dsg.QueryClient(prefix, timeout=60)
    graphs = op3dsg.GraphClient(prefix, timeout=60)

    def mapped():
        graph = graphs.latest()
        return graph.copy() if graph is not None and len(graph.nodes) >= 5 and graph.version >= 10 else None

    graph = wait_for("a graph of at least 5 nodes", 120, mapped)

    def some_goals():
        goals, reasons = [], []
        for node_id in (int(i) for i in graph.nodes["id"]):
            try:
                goals.append(client.goal(node_id, timeout=10))
            except op3dsg.GoalError as e:
                assert e.status in ("no_free_cell", "unreachable", "no_map"), e
                assert e.node_id == node_id and e.reason, e
                reasons.append(e.status)
            except op3dsg.QueryError as e:
                assert e.status == "bad_request" and e.message.startswith("node_id:"), e  # merged away since
        return goals or None

    goals = wait_for("approach poses for some nodes", 60, some_goals, interval=0.5)
    ids = set(int(i) for i in graph.nodes["id"])
    for g in goals:
        assert g.node_id in ids and g.kind in ("object", "part")
        assert 0.4 - 1e-3 <= g.standoff_m <= 0.8 + 1e-3, g
        assert g.path_m >= 0.0 and -3.2 <= g.yaw_rad <= 3.2, g
    # The module-level helper, and an unknown node's clear refusal.
    first = op3dsg.goal(goals[0].node_id, prefix=prefix, timeout=10)
    assert first.node_id == goals[0].node_id
    with pytest.raises(op3dsg.QueryError) as raised:
        client.goal(9_999_999, timeout=10)
    assert raised.value.status == "bad_request" and raised.value.message.startswith("node_id:")
    # A need in words needs the encoder: the daemon says so.
    with pytest.raises(op3dsg.QueryError) as raised:
        client.goal("somewhere to wash my hands", timeout=10)
    assert raised.value.status == "encoder_off"
