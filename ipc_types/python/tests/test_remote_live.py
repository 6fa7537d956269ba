""":mod:`op3dsg.remote` against a live ``op3dsgd`` with Zenoh on a free loopback port (the
synthetic kitchen, its own iceoryx2 prefix and Zenoh key prefix per test): the graph followed
over Zenoh equals ``op3dsg dump --json`` (iceoryx2) at the same version, for a client there from
the start and one that joins late; a daemon killed and started again is a new instance; health,
goals and queries over Zenoh are those over iceoryx2; the occupancy map over Zenoh is the
iceoryx2 one; a malformed message is counted and the client goes on; and the five lines of
docs/remote.md run as written."""

from __future__ import annotations

import ctypes
import json
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import List, Optional

import numpy as np
import pytest

import op3dsg

from conftest import FAST, REPO, op3dsg_path, wait_for

#: Frames of a daemon whose graph must settle (1 s at FAST's 60 per second; a few seconds on a debug build).
FRAMES = 60
DOC = REPO / "docs" / "remote.md"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Remote:
    """Where a test's daemon is on Zenoh: ``endpoint``, ``key_prefix``, and the daemon arguments."""

    def __init__(self, prefix: str):
        self.port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.key_prefix = f"op3dsg/{prefix}"

    def args(self, frames: Optional[int] = FRAMES, extra: Optional[List[str]] = None) -> List[str]:
        args = [
            *FAST,
            "--set", "zenoh.enabled=true",
            "--set", f'zenoh.listen=["{self.endpoint}"]',
            "--set", f'zenoh.key_prefix="{self.key_prefix}"',
        ]  # fmt: skip
        if frames is not None:
            args += ["--set", f"run.max_frames={frames}"]
        return args + (extra or [])


@pytest.fixture
def remote(prefix) -> Remote:
    return Remote(prefix)


def op3dsg_json(prefix: str, *args: str) -> dict:
    out = subprocess.run(
        [str(op3dsg_path()), "--prefix", prefix, *args, "--json"], check=True, capture_output=True, text=True, timeout=60
    )
    return json.loads(out.stdout)


def settled(prefix: str, frames: int = FRAMES) -> dict:
    """``op3dsg dump --json`` once the daemon has read its ``frames`` and the graph stopped
    changing (two dumps half a second apart at one version)."""
    with op3dsg.HealthClient(prefix, timeout=60) as health:
        wait_for(f"all {frames} frames captured", 120, lambda: _at_least(health.latest(), frames), interval=0.1)
    last = op3dsg_json(prefix, "dump")
    deadline = time.monotonic() + 60
    while True:
        time.sleep(0.5)
        dumped = op3dsg_json(prefix, "dump")
        if dumped["graph_version"] == last["graph_version"]:
            return dumped
        assert time.monotonic() < deadline, "the graph did not settle within 60 s of the last frame"
        last = dumped


def _at_least(record, frames: int):
    return record if record is not None and record.frames_captured >= frames else None


def without_edge_order(graph: dict) -> dict:
    """The graph JSON with its edges sorted (over Zenoh a multiset, in another order)."""
    out = {k: v for k, v in graph.items() if k != "source"}
    out["edges"] = sorted(graph["edges"], key=lambda e: json.dumps(e, sort_keys=True))
    return out


def remote_at(client: op3dsg.RemoteGraphClient, version: int, instance: Optional[int] = None) -> op3dsg.Graph:
    def held():
        client.wait_for_update(0.2)
        graph = client.latest()
        ok = graph is not None and graph.version == version and instance in (None, graph.instance_id)
        return graph if ok else None

    return wait_for(f"the remote client at version {version}", 60, held)


def test_the_remote_graph_equals_op3dsg_dump_and_a_late_joiner_converges(prefix, daemons, remote):
    daemons(prefix, remote.args())
    early = op3dsg.RemoteGraphClient(remote.endpoint, remote.key_prefix, timeout=60)
    dumped = settled(prefix)
    graph = remote_at(early, dumped["graph_version"])
    assert graph.node_count == len(dumped["nodes"]) > 0 and graph.edge_count == len(dumped["edges"]) > 0
    assert without_edge_order(graph.to_dict()) == without_edge_order(dumped), "nodes, labels, centres, boxes, edges"
    # The same records as over iceoryx2, byte for byte: nodes in the same order, edges as a multiset.
    with op3dsg.GraphClient(prefix, timeout=10) as local:
        view = wait_for("the iceoryx2 graph of that version", 30, lambda: _version(local, graph.version))
        assert view.nodes.tobytes() == graph.nodes.tobytes()
        assert sorted(view.edges.tobytes()[i : i + 64] for i in range(0, view.edges.nbytes, 64)) == sorted(
            graph.edges.tobytes()[i : i + 64] for i in range(0, graph.edges.nbytes, 64)
        )
        assert (graph.instance_id, graph.stamp_ns, graph.header.object_count) == (
            view.instance_id,
            view.stamp_ns,
            view.header.object_count,
        )
    counters = early.counters()
    assert counters["fulls"] >= 1 and counters["deltas_applied"] > 0, f"it followed deltas: {counters}"
    assert counters["errors"] == 0 and early.last_error is None, early.last_error
    assert not graph.restarted and early.instances == [graph.instance_id]
    assert early.latest() is graph, "nothing newer: the same graph again"
    assert early.latest_if_newer(0) is graph and early.latest_if_newer(graph.version) is None

    with op3dsg.RemoteGraphClient(remote.endpoint, remote.key_prefix, timeout=10) as late:
        joined = late.wait_for_graph(30)
        assert joined.version == graph.version, "the queryable's full graph is the newest version"
        assert without_edge_order(joined.to_dict()) == without_edge_order(dumped)
        assert late.counters()["fulls"] >= 1 and late.counters()["errors"] == 0
    early.close()


def _version(client: op3dsg.GraphClient, version: int):
    client.wait_for_update(0.2)
    view = client.latest()
    return view if view is not None and view.version == version else None


def test_a_daemon_killed_and_started_again_is_a_new_instance(prefix, daemons, remote):
    first = daemons(prefix, remote.args(frames=None))
    client = op3dsg.RemoteGraphClient(remote.endpoint, remote.key_prefix, timeout=60)
    old = client.wait_for_graph(60, min_nodes=1)

    def ahead():
        client.wait_for_update(0.2)
        graph = client.latest()
        return graph if graph.version > old.version + 3 else None

    old_instance, seen_version = old.instance_id, wait_for("a few more versions", 60, ahead).version

    first.kill_9()
    daemons(prefix, remote.args(frames=FRAMES))

    def new_instance():
        client.wait_for_update(0.2)
        graph = client.latest_if_newer(seen_version)
        return graph if graph is not None and graph.instance_id != old_instance else None

    new = wait_for("the client to take the restarted daemon's graph", 90, new_instance)
    assert new.restarted and client.restarted, "the first graph of the new instance says so"
    assert new.instance_id not in (0, old_instance)
    assert client.counters()["restarts"] == 1 and client.instances == [old_instance, new.instance_id]

    # It follows the new daemon to its settled graph, which is what op3dsg dump prints.
    dumped = settled(prefix)
    graph = remote_at(client, dumped["graph_version"], new.instance_id)
    assert without_edge_order(graph.to_dict()) == without_edge_order(dumped)
    assert not client.restarted and client.counters()["errors"] == 0, client.last_error
    client.close()


def test_health_queries_and_goals_over_zenoh_are_those_over_iceoryx2(prefix, daemons, remote):
    daemons(prefix, remote.args(extra=["--set", 'world.frame_id="map"']))
    dumped = settled(prefix)

    record = op3dsg.remote_health(remote.endpoint, remote.key_prefix, timeout=30)
    local = op3dsg_json(prefix, "health")
    names = [s["name"] for s in local["stages"]]
    assert [s["name"] for s in record.record["stages"]] == names and "zenoh" in names
    assert [q["name"] for q in record.record["queues"]] == [q["name"] for q in local["queues"]]
    for key in ("schema_version", "source_kind", "world_frame"):
        assert record.record[key] == local[key], key
    assert (record.record["source_kind"], record.record["world_frame"]) == ("synthetic", "map")
    assert record.stage("capture")["processed"] >= FRAMES
    assert record.graph_version == dumped["graph_version"] and record.instance_id != 0

    ids = [n["id"] for n in dumped["nodes"]]
    with op3dsg.RemoteQueryClient(remote.endpoint, remote.key_prefix, timeout=10) as client:
        answered = 0
        for node_id in ids:
            try:
                local_goal = op3dsg.goal(node_id, prefix=prefix, timeout=10)
            except op3dsg.GoalError as e:
                with pytest.raises(op3dsg.GoalError) as raised:
                    client.goal(node_id, timeout=10)
                assert (raised.value.status, raised.value.node_id) == (e.status, e.node_id)
                assert str(raised.value).replace("/query", "") == str(e).replace("/query", "").replace(prefix, remote.key_prefix)
                continue
            assert client.goal(node_id, timeout=10) == local_goal
            answered += 1
        assert answered > 0, "some nodes have approach poses"
        assert client.query_node(ids[0]).graph_version == dumped["graph_version"]
        # Without the text encoder the daemon says so, over Zenoh as over iceoryx2.
        with pytest.raises(op3dsg.QueryError) as raised:
            client.query("somewhere to wash my hands")
        assert raised.value.status == "encoder_off" and "text_encoder.enabled = true" in raised.value.message
        with pytest.raises(op3dsg.QueryError) as raised:
            client.goal(9_999_999)
        assert raised.value.status == "bad_request" and raised.value.message.startswith("node_id:")
        assert str(raised.value).startswith(f"{remote.key_prefix}/query: query: bad_request: ")
    first = op3dsg.remote_goal(remote.endpoint, remote.key_prefix, ids[0], timeout=10) if answered else None
    assert first is None or first.node_id == ids[0]

    # Another key prefix: nothing answers, and the error says where it asked.
    with pytest.raises(op3dsg.RemoteTimeoutError) as raised:
        op3dsg.remote_health(remote.endpoint, "op3dsg/nobody-here", timeout=1.0)
    message = str(raised.value)
    assert message.startswith("op3dsg/nobody-here/health: query: no daemon answered within") and remote.endpoint in message


def test_a_malformed_message_is_counted_and_the_client_goes_on(prefix, daemons, remote):
    # No frame limit: versions keep coming after the bad message.
    daemons(prefix, remote.args(frames=None))
    client = op3dsg.RemoteGraphClient(remote.endpoint, remote.key_prefix, timeout=60)
    before = client.wait_for_graph(60)
    # Another client of the daemon's session puts a message that is no op3dsg message on the
    # delta key; the daemon's peer routes it to every subscriber.
    sender = op3dsg.remote.open_session(remote.endpoint, remote.key_prefix, 10)
    try:

        def counted():
            sender.put(f"{remote.key_prefix}/graph/delta", b"NOPE" + bytes(60))
            time.sleep(0.1)
            return client.counters()["errors"] or None

        wait_for("the malformed message counted", 30, counted)
    finally:
        sender.close()
    assert isinstance(client.last_error, op3dsg.InvalidRemoteMessageError)
    assert str(client.last_error).startswith(f"{remote.key_prefix}/graph: receive: invalid message: not an op3dsg message")

    def newer():
        client.wait_for_update(0.2)
        graph = client.latest()
        return graph if graph.version > before.version else None

    after = wait_for("newer graphs after it", 30, newer)
    assert after.instance_id == before.instance_id and client.counters()["fulls"] >= 1
    client.close()


def test_a_program_that_never_closes_its_clients_still_exits(prefix, daemons, remote):
    daemons(prefix, remote.args(frames=None))
    code = (
        "import op3dsg\n"
        f"graphs = op3dsg.RemoteGraphClient({remote.endpoint!r}, {remote.key_prefix!r}, timeout=60)\n"
        f"maps = op3dsg.RemoteOccupancyClient({remote.endpoint!r}, {remote.key_prefix!r}, timeout=60)\n"
        "print(graphs.wait_for_graph(60).version, maps.wait(60).version)\n"
    )
    package = str(Path(op3dsg.__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=package)
    # Three times: the exit that went wrong (a hang, or an abort when Python stopped the
    # follower thread inside Zenoh) depended on what arrived while the interpreter finished.
    for _ in range(3):
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=90, env=env)
        assert out.returncode == 0 and len(out.stdout.split()) == 2, out.stderr


def test_the_occupancy_map_over_zenoh_is_the_iceoryx2_one(prefix, daemons, remote):
    daemons(prefix, remote.args())
    settled(prefix)
    with op3dsg.OccupancyClient(prefix, timeout=30) as local, op3dsg.RemoteOccupancyClient(
        remote.endpoint, remote.key_prefix, timeout=30
    ) as far:
        local.wait(30)
        far.wait(30)  # RemoteTimeoutError naming <key_prefix>/occupancy while the daemon publishes none

        def same_keyframes():
            mine, theirs = local.latest(), far.latest()
            same = theirs.keyframes_integrated == mine.keyframes_integrated and theirs.stamp_ns == mine.stamp_ns
            return (mine, theirs) if same else None

        mine, theirs = wait_for("both maps of the same keyframes", 30, same_keyframes)
        assert theirs.version >= 1 and theirs.instance_id == mine.instance_id != 0
        # The same header, field for field, but for what belongs to each send: its wall-clock
        # time and the integration cost since the sample before (iceoryx2 sends every period,
        # Zenoh only a changed map).
        timings = ("publish_time_ns", "integrate_p50_us", "integrate_p99_us")
        for field in op3dsg.OccupancyHeader.field_names():
            if field not in timings:
                assert _plain(getattr(theirs.header, field)) == _plain(getattr(mine.header, field)), field
        assert theirs.cells.dtype == np.int8 and theirs.cells.shape == (mine.height_cells, mine.width_cells)
        assert np.array_equal(theirs.cells, mine.cells)
        assert theirs.occupied().sum() == theirs.occupied_cells > 0 and theirs.free().sum() == theirs.free_cells > 0
    once = op3dsg.remote_occupancy(remote.endpoint, remote.key_prefix, timeout=10)
    assert once.keyframes_integrated == mine.keyframes_integrated and np.array_equal(once.cells, mine.cells)


def _plain(value):
    return bytes(value) if isinstance(value, ctypes.Array) else value


def five_lines() -> str:
    """The fenced python block of docs/remote.md's section "From a laptop, in five lines of Python"."""
    text = DOC.read_text()
    at = text.index("## From a laptop, in five lines of Python")
    block = re.search(r"```python\n(.*?)```", text[at:], re.S)
    assert block, "the section has a ```python block"
    return block.group(1)


def test_the_five_lines_of_docs_remote_md_print_the_graph(prefix, daemons, remote):
    code = five_lines()
    assert len(code.splitlines()) <= 5, code
    # The doc's example endpoint and key prefix, once each, are what a reader replaces.
    for example in ("tcp/192.168.1.20:7447", "op3dsg/stretch-1"):
        assert code.count(example) == 1, f"{example} once in the five lines"
    code = code.replace("tcp/192.168.1.20:7447", remote.endpoint).replace("op3dsg/stretch-1", remote.key_prefix)
    daemons(prefix, remote.args())
    package = str(Path(op3dsg.__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([package, os.environ.get("PYTHONPATH", "")]))
    for _ in range(3):
        dumped = settled(prefix)
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
        assert out.returncode == 0, out.stderr
        lines = out.stdout.splitlines()
        versions = {int(line.split()[0]) for line in lines}
        if versions == {dumped["graph_version"]}:
            break
    else:
        raise AssertionError(f"the snippet never printed the settled version {dumped['graph_version']}: {out.stdout}")
    objects = [n for n in dumped["nodes"] if n["kind"] == "object"]
    assert len(lines) == len(objects) > 0, out.stdout
    for line, node in zip(lines, objects):
        # "<version> <label> [x y z]", the centre rounded to centimetres.
        match = re.fullmatch(r"(\d+) (.+) \[\s*(\S+)\s+(\S+)\s+(\S+)\s*\]", line)
        assert match, line
        assert match.group(2) == node["label"]
        centre = [float(v) for v in match.group(3, 4, 5)]
        assert np.allclose(centre, node["centre_m"], atol=0.006), (line, node["centre_m"])
