"""The Python client against a live ``op3dsgd`` (the synthetic kitchen, its own prefix per test):
values equal ``op3dsg dump --json`` at the same version, a kill -9 and restart seen as
``restarted``, a pose publisher created before the daemon whose poses the daemon takes, and
health read without a graph subscriber."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import op3dsg
from op3dsg import wire

from conftest import FAST, op3dsg_path, wait_for

#: Poses from the pose service, frames at 10 per second, short health periods (as the Rust pose tests).
IPC_POSES = ["--set", 'pose.source="ipc"', "--set", "source.rate_hz=10", "--set", "health.period_ms=100"]
#: Frame ``k`` of the synthetic source is stamped ``k * FRAME_PERIOD_NS`` (scene time, 30 Hz).
FRAME_PERIOD_NS = 33_333_333


def dump_json(prefix: str) -> dict:
    out = subprocess.run(
        [str(op3dsg_path()), "--prefix", prefix, "dump", "--json"],
        check=True,
        capture_output=True,
        text=True,
        timeout=60,
    )
    return json.loads(out.stdout)


def graph_with_parts(client: op3dsg.GraphClient, timeout: float = 60) -> op3dsg.GraphView:
    def ready():
        client.wait_for_update(0.2)
        view = client.latest()
        return view if view is not None and view.parts().size > 0 and view.edge_count > 0 else None

    return wait_for("a graph with parts and edges", timeout, ready)


def test_numpy_views_equal_op3dsg_dump_json_at_the_same_version(prefix, daemons):
    # The source stops after 150 frames and the daemon keeps serving its last graph, so the
    # client and `op3dsg dump` can meet at one version.
    daemons(prefix, FAST + ["--set", "run.max_frames=150"])
    client = op3dsg.GraphClient(prefix, timeout=30)
    graph_with_parts(client)
    for _ in range(20):
        client.wait_for_update(0.2)
        view = client.latest()
        dumped = dump_json(prefix)
        view = client.latest()
        if view.version == dumped["graph_version"]:
            break
    else:
        raise AssertionError(f"never met op3dsg dump at one version (last {view.version} vs {dumped['graph_version']})")

    nodes, edges = view.nodes, view.edges
    assert len(dumped["nodes"]) == view.node_count == len(nodes) > 0
    assert len(dumped["edges"]) == view.edge_count == len(edges) > 0
    assert dumped["stamp_ns"] == view.stamp_ns
    for i, expected in enumerate(dumped["nodes"]):
        n = nodes[i]
        assert int(n["id"]) == expected["id"]
        assert view.label(i) == expected["label"]
        assert wire.NODE_KINDS[n["kind"]] == expected["kind"]
        assert (None if n["parent_id"] == wire.NO_NODE else int(n["parent_id"])) == expected["parent"]
        for field in ("centre_m", "box_min_m", "box_max_m"):
            # JSON holds the f32 values' shortest decimal form: back to f32 they are equal bit for bit.
            assert np.array_equal(n[field], np.array(expected[field], dtype=np.float32)), (i, field)
        assert n["confidence"] == np.float32(expected["confidence"])
        assert list(wire.affordance_names(int(n["affordance_bits"]))) == expected["affordances"]
        assert int(n["observation_count"]) == expected["observation_count"]
    for i, expected in enumerate(dumped["edges"]):
        e = edges[i]
        assert (int(e["source_id"]), int(e["target_id"])) == (expected["source"], expected["target"])
        assert wire.EDGE_KINDS[e["kind"]] == expected["kind"]
        assert wire.EDGE_ORIGINS[e["origin"]] == expected["origin"]
        assert wire.relation_phrase(int(e["relation_id"])) == expected["relation"]
        assert view.phrase(i) == expected["relation"], "the phrase buffer carries the canonical phrase"
        assert e["confidence"] == np.float32(expected["confidence"])
    # The plain-Python form is the dump's form too.
    mine = view.to_dict()
    assert {k: v for k, v in mine.items() if k != "source"} == {k: v for k, v in dumped.items() if k != "source"}
    # What the graph is of, from the daemon itself: the synthetic rooms, in the default frame.
    assert (view.source_kind, view.world_frame) == ("synthetic", "world")
    assert (dumped["source_kind"], dumped["world_frame"]) == ("synthetic", "world")
    header = view.header
    assert header.object_count + header.part_count == view.node_count
    assert header.object_count == view.objects().size


def test_kill_9_and_restart_on_the_same_prefix_is_seen_as_restarted_with_the_new_graphs(prefix, daemons):
    first = daemons(prefix)
    client = op3dsg.GraphClient(prefix, timeout=30)
    old = graph_with_parts(client)
    old_instance, old_version = old.instance_id, old.version
    assert old_instance != 0 and not old.restarted and not client.restarted
    # Let the old daemon's versions run ahead of what the new one will publish first.
    def ahead():
        client.wait_for_update(0.2)
        view = client.latest()
        return view.version if view.version > old_version + 3 else None

    seen_version = wait_for("a few more versions of the first daemon", 60, ahead)

    first.kill_9()
    daemons(prefix)

    def new_graph():
        client.wait_for_update(0.2)
        view = client.latest_if_newer(seen_version)
        return view if view is not None and view.instance_id != old_instance else None

    new = wait_for("the attached client to take the restarted daemon's graph", 90, new_graph)
    assert new.restarted and client.restarted, "the first graph of the new instance says it"
    assert new.version < seen_version, "versions started again (which is why the instance id matters)"
    new_instance, new_version = new.instance_id, new.version
    assert new_instance not in (0, old_instance)

    # The new daemon's later graphs: same instance, growing versions, no restart flag.
    def later_graph():
        client.wait_for_update(0.2)
        return client.latest_if_newer(new_version)

    later = wait_for("a later graph of the new daemon", 60, later_graph)
    assert later.instance_id == new_instance and later.version > new_version
    assert not later.restarted and not client.restarted
    assert later.node_count > 0


def test_pose_publisher_created_before_the_daemon_has_its_poses_taken(prefix, daemons):
    poses = op3dsg.PosePublisher(prefix)
    assert poses.created, "nobody had created the pose service: the client creates it with op3dsg's QoS"
    daemons(prefix, IPC_POSES)
    monitor = op3dsg.HealthClient(prefix, timeout=30)
    def with_frames():
        record = monitor.latest()
        return record if record is not None and record.frames_captured > 3 else None

    started = wait_for("a health record with frames", 60, with_frames)
    assert started.keyframes == 0, "no pose sent yet: frames wait for one"
    # One pose of each wire rejection the daemon counts, sent around the client's own checks.
    monitor_before = started.pose.counters()
    nan_pose = op3dsg.make_pose(0, [math.nan, 0.0, 1.2], [0.0, 0.0, 0.0, 1.0])
    long_quaternion = op3dsg.make_pose(0, [0.0, 0.0, 1.2], [0.0, 0.0, 0.0, 2.0])
    assert poses.publish_unchecked(nan_pose) == 1 and poses.publish_unchecked(long_quaternion) == 1

    next_stamp = (started.frames_captured - 1) * FRAME_PERIOD_NS

    def posed():
        nonlocal next_stamp
        record = monitor.latest()
        ahead = (record.frames_captured - 1) * FRAME_PERIOD_NS + 300_000_000
        while next_stamp < ahead:
            poses.publish(next_stamp, [next_stamp * 1e-9, 0.0, 1.2], [0.0, 0.0, 0.0, 1.0], kind=op3dsg.POSE_WORLD_FROM_CAMERA)
            next_stamp += 10_000_000
        counts = record.pose
        return record if record.keyframes > 0 and counts.accepted > 0 and counts.non_finite > 0 and counts.non_unit_quaternion > 0 else None

    record = wait_for("keyframes posed from the Python publisher's poses", 60, posed)
    assert record.pose.non_finite == monitor_before["non_finite"] + 1
    assert record.pose.non_unit_quaternion == monitor_before["non_unit_quaternion"] + 1
    assert record.pose.out_of_order + record.pose.future == 0, record.pose.counters()


def test_health_is_readable_with_every_graph_subscriber_slot_taken_and_matches_op3dsg_health(prefix, daemons):
    daemons(prefix, FAST + ["--set", "ipc.max_subscribers=2", "--set", 'world.frame_id="map"'])
    planners = [op3dsg.GraphClient(prefix, timeout=30), op3dsg.GraphClient(prefix)]
    with pytest.raises(op3dsg.SubscriberSlotsFullError, match=f"{prefix}/graph: create subscriber: ExceedsMaxSupportedSubscribers"):
        op3dsg.GraphClient(prefix)

    def with_frames():
        record = op3dsg.health(prefix, timeout=30)
        return record if record.frames_captured > 0 else None

    record = wait_for("health with frames", 60, with_frames)
    assert record.schema_version == wire.SCHEMA_VERSION
    names = [op3dsg.fixed_str(s.name) for s in record.valid_stages()]
    for stage in ("capture", "keyframe", "detect/0", "detect/1", "fusion", "publish"):
        assert stage in names
    assert record.stage("capture").processed > 0
    report = json.loads(
        subprocess.run(
            [str(op3dsg_path()), "--prefix", prefix, "health", "--json", "--timeout-s", "30"],
            check=True,
            capture_output=True,
            text=True,
            timeout=60,
        ).stdout
    )
    assert [s["name"] for s in report["stages"]] == names
    assert [q["name"] for q in report["queues"]] == [q["name"] for q in record.to_dict()["queues"]]
    assert report["schema_version"] == record.schema_version
    # The profile's world frame and the opened source's kind, in the record and in op3dsg health.
    assert (record.source_kind_name(), record.world_frame_str()) == ("synthetic", "map")
    assert (report["source_kind"], report["world_frame"]) == ("synthetic", "map")
    # The planners holding the slots read graphs meanwhile.
    for planner in planners:
        assert graph_with_parts(planner).node_count > 0


def test_the_example_planner_prints_live_graph_versions_with_parts_and_parents(prefix, daemons):
    daemons(prefix)
    example = Path(__file__).resolve().parents[1] / "examples" / "planner.py"
    out = subprocess.run(
        [sys.executable, str(example), "--prefix", prefix, "--versions", "6"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    versions = [int(line.split()[1]) for line in out.stdout.splitlines() if line.startswith("version ")]
    assert len(versions) == 6, out.stdout
    assert versions == sorted(set(versions)), f"each version newer than the last: {versions}"
    assert any(line.strip().startswith("part ") and "of '(none)'" not in line for line in out.stdout.splitlines()), out.stdout


def test_the_occupancy_map_is_a_grid_of_the_daemon_with_its_counts_and_the_robot_on_it(prefix, daemons):
    daemons(prefix, FAST + ["--set", "run.max_frames=150"])
    with op3dsg.OccupancyClient(prefix, timeout=30) as client:

        def integrated():
            grid = client.latest()
            return grid if grid is not None and grid.keyframes_integrated > 0 and grid.robot_pose is not None else None

        grid = wait_for("an occupancy map with keyframes integrated", 60, integrated)
    h = grid.header
    assert h.schema_version == op3dsg.occupancy.OCCUPANCY_SCHEMA_VERSION and h.instance_id != 0
    assert grid.cells.dtype == np.int8 and grid.cells.shape == (h.height_cells, h.width_cells)
    assert 0 < h.width_cells <= 2048 and 0 < h.height_cells <= 2048 and h.cell_size_m > 0
    assert not grid.cells.flags.writeable
    values = np.unique(grid.cells)
    assert values.min() >= -1 and values.max() <= 100, values
    assert grid.free().sum() == h.free_cells > 0 and grid.occupied().sum() == h.occupied_cells > 0
    assert grid.unknown().sum() + grid.free().sum() + grid.occupied().sum() <= grid.cells.size
    x, y, _ = grid.robot_pose
    row, col = grid.cell_of(x, y)
    assert np.allclose(grid.centre_of(row, col), (x, y), atol=h.cell_size_m)
    assert grid.up_axis == "z" and h.obstacle_max_height_m > h.obstacle_min_height_m
