"""The client against a graph publisher written here with plain iceoryx2 (no daemon): the
one-borrowed-sample rule, copies that outlive the sample, and the errors a planner sees for a
missing daemon, another schema version or a malformed sample."""

from __future__ import annotations

import ctypes

import iceoryx2 as iox2
import numpy as np
import pytest

import op3dsg
from op3dsg import wire

from conftest import raw_node


class GraphPublisher:
    """``<prefix>/graph`` and ``<prefix>/graph_updated`` with the daemon's QoS, from Python."""

    def __init__(self, prefix: str):
        self.node = raw_node()
        service = (
            self.node.service_builder(iox2.ServiceName.new(f"{prefix}/graph"))
            .publish_subscribe(iox2.Slice[ctypes.c_uint8])
            .user_header(wire.GraphHeader)
            .history_size(1)
            .enable_safe_overflow(True)
            .subscriber_max_buffer_size(2)
            .subscriber_max_borrowed_samples(1)
            .max_publishers(1)
            .create()
        )
        self.publisher = service.publisher_builder().initial_max_slice_len(1 << 16).create()
        event = self.node.service_builder(iox2.ServiceName.new(f"{prefix}/graph_updated")).event().event_id_max_value(0).create()
        self.notifier = event.notifier_builder().create()
        self._keep = (service, event)

    def send(
        self,
        version: int,
        nodes: np.ndarray,
        edges: np.ndarray,
        schema: int = wire.SCHEMA_VERSION,
        payload_extra: int = 0,
        source_kind: int = wire.SOURCE_KIND_UNKNOWN,
        world_frame: str = "",
    ):
        header = wire.GraphHeader()
        header.schema_version = schema
        header.source_kind = source_kind
        header.world_frame[:] = wire.write_fixed_str(world_frame, wire.NAME_CAPACITY_BYTES)
        header.graph_version = version
        header.instance_id = 0x1234
        header.node_count = len(nodes)
        header.edge_count = len(edges)
        header.node_capacity = wire.MAX_NODES
        header.edge_capacity = wire.MAX_EDGES
        payload = nodes.tobytes() + edges.tobytes() + b"\0" * payload_extra
        sample = self.publisher.loan_slice_uninit(len(payload))
        ctypes.memmove(sample.user_header_ptr, ctypes.addressof(header), ctypes.sizeof(header))
        ctypes.memmove(sample.payload_ptr, payload, len(payload))
        sample.assume_init().send()
        self.notifier.notify()


def make_nodes(count: int, label: str = "cabinet") -> np.ndarray:
    nodes = np.zeros(count, wire.NODE_DTYPE)
    nodes["id"] = np.arange(1, count + 1)
    nodes["parent_id"] = wire.NO_NODE
    nodes["label"] = label.encode()
    nodes["centre_m"] = np.arange(count * 3, dtype=np.float32).reshape(count, 3)
    return nodes


def received(client: op3dsg.GraphClient, version: int) -> op3dsg.GraphView:
    for _ in range(200):
        client.wait_for_update(0.05)
        view = client.latest()
        if view is not None and view.version == version:
            return view
    pytest.fail(f"graph version {version} never arrived")


def test_no_daemon_is_a_not_serving_error_naming_prefix_and_service(prefix):
    with pytest.raises(op3dsg.NotServingError) as error:
        op3dsg.GraphClient(prefix)
    assert error.value.prefix == prefix
    root, _ = op3dsg.access.resolve_root()
    assert f"no op3dsgd is serving under prefix '{prefix}' in IPC root {root} (service {prefix}/graph not found)" in str(error.value)
    with pytest.raises(op3dsg.NotServingError, match=f"{prefix}/health"):
        op3dsg.health(prefix, timeout=0.2)
    with pytest.raises(op3dsg.InvalidPrefixError, match="invalid character ' '"):
        op3dsg.GraphClient("two words")


def test_views_read_shared_memory_until_the_next_sample_and_copies_outlive_it(prefix):
    publisher = GraphPublisher(prefix)
    client = op3dsg.GraphClient(prefix, timeout=5)
    publisher.send(1, make_nodes(3, "drawer handle"), np.zeros(0, wire.EDGE_DTYPE))
    first = received(client, 1)
    assert first.labels() == ["drawer handle"] * 3
    assert first.nodes["centre_m"][2].tolist() == [6.0, 7.0, 8.0]
    assert not first.nodes.flags.writeable, "views of the daemon's memory are read-only"
    assert client.latest() is first, "no newer sample: the same view"
    kept = first.copy()

    publisher.send(2, make_nodes(5, "stove knob"), np.zeros(0, wire.EDGE_DTYPE))
    second = received(client, 2)
    assert not first.valid
    with pytest.raises(op3dsg.SampleReleasedError, match=f"{prefix}/graph"):
        _ = first.nodes
    assert (kept.version, kept.node_count, kept.labels()) == (1, 3, ["drawer handle"] * 3)
    assert second.node_count == 5 and second.label(4) == "stove knob"
    assert second.index_of(5) == 4 and second.index_of(99) is None
    second.release()
    assert client.latest() is None, "released and nothing newer"


def test_each_affordance_carries_its_origin_from_the_two_masks(prefix):
    publisher = GraphPublisher(prefix)
    client = op3dsg.GraphClient(prefix, timeout=5)
    nodes = make_nodes(2, "cabinet handle")
    nodes["affordance_bits"][0] = wire.affordance_bits(["tip_push", "hook_pull", "pinch_pull", "unplug"])
    nodes["affordance_knowledge_bits"][0] = wire.affordance_bits(["hook_pull", "unplug"])
    # "rotate" is not among the node's affordances: an origin bit outside them means nothing.
    nodes["affordance_llm_bits"][0] = wire.affordance_bits(["rotate", "pinch_pull", "unplug"])
    publisher.send(1, nodes, np.zeros(0, wire.EDGE_DTYPE))
    view = received(client, 1)
    record = view.nodes[0:1].tobytes()
    assert int.from_bytes(record[10:12], "little") == wire.affordance_bits(["hook_pull", "unplug"]), "knowledge bits at 10"
    assert int.from_bytes(record[106:108], "little") == wire.affordance_bits(["rotate", "pinch_pull", "unplug"]), "llm bits at 106"
    expected = {"tip_push": "geometry", "hook_pull": "knowledge", "pinch_pull": "llm", "unplug": "knowledge+llm"}
    assert view.affordance_origins(0) == expected
    assert list(view.affordance_origins(0)) == list(view.node_dict(0)["affordances"]), "canonical order"
    assert view.node_dict(0)["affordance_origins"] == expected
    assert "affordance_origins" not in view.node_dict(1), "no affordances, no origins (as op3dsg dump --json)"
    assert op3dsg.affordance_origin(0b1000, 0b1000, 0, 3) == "knowledge"
    assert op3dsg.affordance_origin(0b1000, 0b1000, 0, 0) is None
    assert op3dsg.affordance_origin(0xFFFF, 0, 0xFFFF, 9) is None, "past the 9 canonical affordances"


def test_the_header_says_what_the_graph_is_of_and_its_frame(prefix):
    publisher = GraphPublisher(prefix)
    client = op3dsg.GraphClient(prefix, timeout=5)
    publisher.send(1, make_nodes(1), np.zeros(0, wire.EDGE_DTYPE), source_kind=wire.SOURCE_KIND_LIVE_CAMERA, world_frame="map")
    view = received(client, 1)
    assert (view.source_kind, view.world_frame) == ("live_camera", "map")
    raw = bytes(view.header)
    assert (raw[53], raw[72:76], raw[76]) == (1, b"map\0", 0), "source_kind at 53, world_frame at 72"
    assert (view.to_dict()["source_kind"], view.to_dict()["world_frame"]) == ("live_camera", "map")
    # A kind newer than this package reads as unknown; a frame filling the field has no NUL.
    publisher.send(2, make_nodes(1), np.zeros(0, wire.EDGE_DTYPE), source_kind=200, world_frame="m" * 32)
    view = received(client, 2)
    assert (view.source_kind, view.world_frame) == ("unknown", "m" * 32)
    assert [wire.source_kind_name(v) for v in range(5)] == ["unknown", "live_camera", "replay", "synthetic", "unknown"]
    health = wire.Health()
    health.source_kind = wire.SOURCE_KIND_REPLAY
    health.world_frame[:] = wire.write_fixed_str("world", wire.NAME_CAPACITY_BYTES)
    assert (health.to_dict()["source_kind"], health.to_dict()["world_frame"]) == ("replay", "world")


def test_another_schema_version_and_a_short_payload_are_named_errors(prefix):
    publisher = GraphPublisher(prefix)
    client = op3dsg.GraphClient(prefix, timeout=5)
    publisher.send(1, make_nodes(2), np.zeros(0, wire.EDGE_DTYPE), schema=3)
    client.wait_for_update(2.0)
    with pytest.raises(op3dsg.SchemaVersionError) as error:
        for _ in range(100):
            client.latest()
            client.wait_for_update(0.05)
    assert (error.value.found, error.value.expected) == (3, wire.SCHEMA_VERSION)
    assert f"{prefix}/graph: receive: invalid sample: schema_version: found 3, this package reads {wire.SCHEMA_VERSION}" in str(error.value)

    publisher.send(2, make_nodes(2), np.zeros(0, wire.EDGE_DTYPE), payload_extra=7)
    client.wait_for_update(2.0)
    need = 2 * wire.NODE_BYTES
    with pytest.raises(op3dsg.InvalidGraphError, match=f"payload: {need + 7} bytes, but the header's counts need {need}"):
        for _ in range(100):
            client.latest()
            client.wait_for_update(0.05)

    # An unknown kind (which only a broken publisher of this schema writes) is not scanned for on
    # receipt, as in the Rust view: the record check, the copy and the record's decoding name it.
    bad = make_nodes(2)
    bad["kind"][1] = 7
    publisher.send(3, bad, np.zeros(0, wire.EDGE_DTYPE))
    view = received(client, 3)
    for read in (view.check_records, view.copy, lambda: view.node_dict(1), view.to_dict):
        with pytest.raises(op3dsg.InvalidGraphError, match=rf"{prefix}/graph: receive: invalid sample: nodes\[1\].kind: unknown value 7"):
            read()
    assert view.node_dict(0)["kind"] == "object", "the other records read as ever"


def test_pose_publisher_opens_a_service_created_first_with_iceoryx2_defaults_as_it_is(prefix):
    node = raw_node()
    service = node.service_builder(iox2.ServiceName.new(f"{prefix}/pose")).publish_subscribe(wire.PoseStamped).create()
    subscriber = service.subscriber_builder().create()
    poses = op3dsg.PosePublisher(prefix)
    assert not poses.created
    assert poses.pose_service.smaller_buffer, "iceoryx2's default buffer (2) is below op3dsg's 64"
    assert poses.publish(7, [1.0, 2.0, 0.0], [0.0, 0.0, 0.0, 1.0], frame_id="camera_color_optical_frame") == 1
    sample = subscriber.receive()
    pose = sample.payload().contents
    assert (pose.stamp_ns, list(pose.translation_m), op3dsg.fixed_str(pose.frame_id)) == (7, [1.0, 2.0, 0.0], "camera_color_optical_frame")
    sample.delete()
    with pytest.raises(op3dsg.InvalidPoseError, match="non-finite translation"):
        poses.publish(8, [float("nan"), 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    with pytest.raises(op3dsg.InvalidPoseError, match="frame_id is 33 bytes, longer than 32"):
        poses.publish(8, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], frame_id="x" * 33)
