"""The wire contract in Python: ctypes mirrors of the Rust types in ``ipc_types/src``
(``graph_types/``, ``pose_types.rs``, ``health_types.rs``, ``text.rs``), numpy structured
dtypes for the node and edge records, and the constants a client needs.

Each ``ctypes.Structure`` lists its fields in the Rust order with the Rust types; the package's
test (``tests/test_layout.py``) compares every size and every field offset with what the Rust
compiler prints (``cargo run -p op3dsg-ipc-types --example wire_layout``). The ``type_name()``
of each structure is the Rust ``#[type_name(...)]``: iceoryx2 refuses to connect when they
differ ("IncompatibleTypes").

Text fields are UTF-8 in a fixed buffer, padded with NUL bytes; a text that fills the buffer has
no terminating NUL (see :func:`fixed_str`).
"""

from __future__ import annotations

import ctypes
from typing import Dict, Iterator, List, Optional

import numpy as np

#: Version of the wire contract this package reads (``SCHEMA_VERSION`` in ``ipc_types/src/lib.rs``).
SCHEMA_VERSION = 12

#: Bytes in a node label buffer.
LABEL_CAPACITY_BYTES = 48
#: Bytes in a relation phrase buffer.
PHRASE_CAPACITY_BYTES = 48
#: Bytes in a frame id, a stage, queue or model name.
NAME_CAPACITY_BYTES = 32
#: Bytes of ``TfHealth.path`` (``TF_PATH_CAPACITY_BYTES``).
TF_PATH_CAPACITY_BYTES = 192
#: Bytes of ``RemoteWorkerHealth.key`` (``REMOTE_KEY_CAPACITY_BYTES``).
REMOTE_KEY_CAPACITY_BYTES = 96
#: The most remote detection workers one health record reports.
MAX_REMOTE_WORKERS = 8
#: Default most nodes / edges of one graph sample (the profile's ``ipc.max_nodes`` / ``ipc.max_edges``).
MAX_NODES = 16_384
MAX_EDGES = 32_768
#: Node id meaning "no node" (the parent of an object node).
NO_NODE = 0xFFFF_FFFF

#: The 9 canonical affordances: bit ``i`` of ``Node.affordance_bits`` is ``AFFORDANCES[i]``.
AFFORDANCES = ("rotate", "key_press", "tip_push", "hook_pull", "pinch_pull", "hook_turn", "foot_push", "plug_in", "unplug")
#: Spatial relations: a spatial edge's ``relation_id`` is the index here.
SPATIAL_RELATIONS = ("part of", "on", "under", "above", "below", "next to", "inside")
#: Functional relations: a functional edge's ``relation_id`` is ``FUNCTIONAL_RELATION_BASE`` + the index here.
FUNCTIONAL_RELATIONS = (
    "pull to open or close",
    "control the water flow",
    "rotate to adjust the setting or temperature",
    "press to start and operate",
    "turn on or turn off",
    "remote to control",
    "press to flush",
    "provide power",
    "push or press to open",
    "operate or adjust the flow or setting",
    "rotate to open or close",
)
FUNCTIONAL_RELATION_BASE = 100

#: ``Node.kind`` values.
NODE_KINDS = ("object", "part")
NODE_KIND_OBJECT = 0
NODE_KIND_PART = 1
#: ``Edge.kind`` values.
EDGE_KINDS = ("spatial", "functional")
#: ``Edge.origin`` values (as the graph JSON spells them).
EDGE_ORIGINS = ("geometry", "knowledge", "llm", "knowledge+llm")

#: ``PoseStamped.kind`` values.
POSE_WORLD_FROM_CAMERA = 0
POSE_WORLD_FROM_BASE = 1
#: Largest accepted deviation of a pose quaternion's norm from 1.
QUATERNION_NORM_TOLERANCE = 1e-3

MAX_WORKERS = 64
FIXED_STAGES = 8
MAX_STAGES = MAX_WORKERS + FIXED_STAGES
MAX_QUEUES = 16
MAX_MODELS = 8
FUTURE_POSE_LIMIT_NS = 1_000_000_000
EXECUTION_PROVIDERS = ("unknown", "cpu", "cuda", "openvino")
REFINER_STATES = ("off", "idle", "calling", "backoff", "breaker_open", "budget_exhausted")
RECORDER_STATES = ("off", "recording", "failed", "finished")
SNAPSHOT_STATES = ("off", "started_empty", "restored", "moved_aside")
#: ``Health.pose_source`` values: where the keyframe gate takes poses from (the profile's
#: ``pose.source``). With ``frame`` the daemon does not read ``<prefix>/pose``.
POSE_SOURCES = ("unknown", "frame", "ipc", "ros2")
#: ``GraphHeader.source_kind`` / ``Health.source_kind`` values: what the daemon reads its frames
#: from. ``unknown`` (0) is also what a value this package does not know reads as.
SOURCE_KINDS = ("unknown", "live_camera", "replay", "synthetic")
SOURCE_KIND_UNKNOWN = 0
SOURCE_KIND_LIVE_CAMERA = 1
SOURCE_KIND_REPLAY = 2
SOURCE_KIND_SYNTHETIC = 3
REFINER_ERRORS = ("none", "timeout", "refused", "dns", "tls", "connect", "transport", "http_status", "rate_limited", "not_chat")
REFINER_FORMATS = ("json_schema", "json_object", "json_object_fallback")
REFINER_REJECTIONS = (
    "malformed",
    "unknown_node",
    "wrong_kind",
    "non_canonical",
    "stale",
    "implausible_geometry",
    "implausible_relation",
    "implausible_affordance",
)
#: Why a remote detection worker's reply was not used (``RemoteWorkerHealth.rejections`` order).
REMOTE_REJECTIONS = ("garbage", "wrong_id", "mask_size", "embedding_dim", "refused", "failed")

# QoS of the services (``ipc_types/src/services.rs``).
DEFAULT_PREFIX = "op3dsg"
#: The environment variable a client takes its prefix from when given none (as ``op3dsg`` does).
PREFIX_ENV = "OP3DSG_PREFIX"
MAX_PREFIX_LEN = 128
HISTORY_SIZE = 1
SAFE_OVERFLOW = True
DEFAULT_MAX_SUBSCRIBERS = 8
DEFAULT_GRAPH_SUBSCRIBER_BUFFER = 2
SUBSCRIBER_MAX_BORROWED_SAMPLES = 1
GRAPH_UPDATED_EVENT_ID = 0
EVENT_ID_MAX_VALUE = 0
DEFAULT_POSE_BUFFER = 64
POSE_MAX_PUBLISHERS = 4
POSE_MAX_SUBSCRIBERS = 4

_u8, _u16, _u32, _u64 = ctypes.c_uint8, ctypes.c_uint16, ctypes.c_uint32, ctypes.c_uint64
_f32, _f64 = ctypes.c_float, ctypes.c_double


def fixed_str(buffer: bytes) -> str:
    """Text of a NUL-padded UTF-8 buffer, cut at the first NUL; invalid UTF-8 is cut at the first
    invalid byte (as the Rust ``fixed_str``)."""
    raw = bytes(buffer)
    end = raw.find(b"\0")
    if end >= 0:
        raw = raw[:end]
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        return raw[: e.start].decode("utf-8")


def write_fixed_str(text: str, capacity: int) -> bytes:
    """``text`` as a NUL-padded buffer of ``capacity`` bytes; raises ``ValueError`` when it does not fit."""
    raw = text.encode("utf-8")
    if len(raw) > capacity:
        raise ValueError(f"{text!r} is {len(raw)} bytes, longer than {capacity}")
    return raw + b"\0" * (capacity - len(raw))


class _Wire(ctypes.Structure):
    """Base of the mirrors: a readable ``repr`` and the field names in order."""

    @classmethod
    def field_names(cls) -> List[str]:
        return [name for name, _ in cls._fields_]

    def __repr__(self) -> str:
        parts = []
        for name, ctype in self._fields_:
            value = getattr(self, name)
            if isinstance(value, ctypes.Array):
                value = list(value)
            parts.append(f"{name}={value!r}")
        return f"{type(self).__name__}({', '.join(parts)})"


class Node(_Wire):
    """One node of the scene graph (144 bytes, alignment 8): ``op3dsg::Node``. Besides the
    axis-aligned box, a gravity-aligned oriented box: ``obb_centre_m``, ``obb_size_m`` (extent
    along the box's own axes) and ``obb_yaw_rad`` (rotation about the world's up axis). Each
    affordance's origin follows from ``affordance_knowledge_bits`` and ``affordance_llm_bits``
    (schema 7, :func:`affordance_origin`)."""

    _fields_ = [
        ("id", _u32),
        ("parent_id", _u32),
        ("kind", _u8),
        ("reserved", _u8),
        ("affordance_knowledge_bits", _u16),
        ("observation_count", _u32),
        ("label", _u8 * LABEL_CAPACITY_BYTES),
        ("confidence", _f32),
        ("centre_m", _f32 * 3),
        ("box_min_m", _f32 * 3),
        ("box_max_m", _f32 * 3),
        ("affordance_bits", _u16),
        ("affordance_llm_bits", _u16),
        ("obb_yaw_rad", _f32),
        ("last_seen_stamp_ns", _u64),
        ("obb_centre_m", _f32 * 3),
        ("obb_size_m", _f32 * 3),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::Node"


class Edge(_Wire):
    """One directed edge (64 bytes, alignment 4): ``op3dsg::Edge``. The source relates to the
    target as the phrase says (handle ``part of`` cabinet)."""

    _fields_ = [
        ("source_id", _u32),
        ("target_id", _u32),
        ("kind", _u8),
        ("origin", _u8),
        ("relation_id", _u16),
        ("confidence", _f32),
        ("phrase", _u8 * PHRASE_CAPACITY_BYTES),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::Edge"


class GraphHeader(_Wire):
    """The user header of every ``<prefix>/graph`` sample (112 bytes): ``op3dsg::GraphHeader``.

    The payload is ``node_count`` node records, then ``edge_count`` edge records, exactly
    :meth:`payload_bytes` bytes. ``instance_id`` is drawn anew every time the daemon starts:
    a different value than the last one seen means a restart (versions start again at 1).
    ``source_kind`` says what the daemon reads (:data:`SOURCE_KINDS`: a live camera, a replay,
    the synthetic rooms) and ``world_frame`` names the frame every coordinate is in (the
    profile's ``world.frame_id``); :meth:`source_kind_name` and :meth:`world_frame_str` decode them."""

    _fields_ = [
        ("schema_version", _u32),
        ("node_count", _u32),
        ("graph_version", _u64),
        ("instance_id", _u64),
        ("stamp_ns", _u64),
        ("publish_time_ns", _u64),
        ("edge_count", _u32),
        ("object_count", _u32),
        ("part_count", _u32),
        ("capacity_exceeded", _u8),
        ("source_kind", _u8),
        ("reserved", _u8 * 2),
        ("total_node_count", _u32),
        ("total_edge_count", _u32),
        ("node_capacity", _u32),
        ("edge_capacity", _u32),
        ("world_frame", _u8 * NAME_CAPACITY_BYTES),
        ("reserved2", _u64),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::GraphHeader"

    def payload_bytes(self) -> int:
        return self.node_count * NODE_BYTES + self.edge_count * EDGE_BYTES

    def source_kind_name(self) -> str:
        """``source_kind`` by name (:data:`SOURCE_KINDS`); a value this package does not know is ``unknown``."""
        return source_kind_name(self.source_kind)

    def world_frame_str(self) -> str:
        """``world_frame`` as text (``""`` from a publisher that does not say)."""
        return fixed_str(self.world_frame)


class PoseStamped(_Wire):
    """A pose sent to the daemon on ``<prefix>/pose`` (104 bytes): ``op3dsg::PoseStamped``."""

    _fields_ = [
        ("stamp_ns", _u64),
        ("kind", _u8),
        ("reserved", _u8 * 7),
        ("translation_m", _f64 * 3),
        ("rotation_xyzw", _f64 * 4),
        ("frame_id", _u8 * NAME_CAPACITY_BYTES),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::PoseStamped"


class StageHealth(_Wire):
    """One pipeline stage (64 bytes): ``op3dsg::StageHealth``."""

    _fields_ = [
        ("name", _u8 * NAME_CAPACITY_BYTES),
        ("processed", _u64),
        ("rate_hz", _f32),
        ("latency_p50_us", _f32),
        ("latency_p99_us", _f32),
        ("errors", _u32),
        ("reserved", _u8 * 8),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::StageHealth"


class QueueHealth(_Wire):
    """One bounded queue (56 bytes): ``op3dsg::QueueHealth``."""

    _fields_ = [
        ("name", _u8 * NAME_CAPACITY_BYTES),
        ("depth", _u32),
        ("capacity", _u32),
        ("dropped", _u64),
        ("pushed", _u64),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::QueueHealth"


class RefinerHealth(_Wire):
    """The LLM refiner (128 bytes): ``op3dsg::RefinerHealth``."""

    _fields_ = [
        ("state", _u8),
        ("breaker_open", _u8),
        ("last_error", _u8),
        ("response_format", _u8),
        ("last_latency_us", _u32),
        ("refreshes", _u64),
        ("calls", _u64),
        ("failures", _u64),
        ("timeouts", _u64),
        ("rate_limited", _u64),
        ("accepted", _u64),
        ("last_graph_version", _u64),
        ("rejections", _u64 * 8),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::RefinerHealth"


class PoseHealth(_Wire):
    """What became of the poses received on ``<prefix>/pose`` (96 bytes): ``op3dsg::PoseHealth``."""

    _fields_ = [
        ("accepted", _u64),
        ("unknown_kind", _u64),
        ("non_finite", _u64),
        ("non_unit_quaternion", _u64),
        ("no_base_from_camera", _u64),
        ("out_of_order", _u64),
        ("stale", _u64),
        ("future", _u64),
        ("queue_full", _u64),
        ("no_transform_path", _u64),
        ("frame_not_found", _u64),
        ("extrapolation", _u64),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::PoseHealth"

    def counters(self) -> dict:
        """Every counter by name (the reserved words left out)."""
        return {name: getattr(self, name) for name, _ in self._fields_ if name != "reserved"}


class ModelHealth(_Wire):
    """One model's sessions on one execution provider (40 bytes): ``op3dsg::ModelHealth``."""

    _fields_ = [
        ("name", _u8 * NAME_CAPACITY_BYTES),
        ("sessions", _u32),
        ("provider", _u8),
        ("requested_provider", _u8),
        ("reserved", _u8 * 2),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::ModelHealth"


class RecorderHealth(_Wire):
    """The MCAP recorder's state and counters (40 bytes): ``op3dsg::RecorderHealth``."""

    _fields_ = [
        ("state", _u8),
        ("reserved", _u8 * 3),
        ("files", _u32),
        ("messages_written", _u64),
        ("messages_dropped", _u64),
        ("bytes_written", _u64),
        ("cpu_ns", _u64),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::RecorderHealth"


class SnapshotHealth(_Wire):
    """The map snapshots' state and counters (64 bytes): ``op3dsg::SnapshotHealth``."""

    _fields_ = [
        ("state", _u8),
        ("reserved", _u8 * 3),
        ("write_p99_us", _u32),
        ("restored_version", _u64),
        ("version", _u64),
        ("last_written_unix_ms", _u64),
        ("last_bytes", _u64),
        ("written", _u64),
        ("failures", _u64),
        ("skipped", _u64),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::SnapshotHealth"


class TfHealth(_Wire):
    """The tf input's state with ``pose.source = "ros2"`` (256 bytes): ``op3dsg::TfHealth``.

    ``path`` is the chain of the last lookup (world frame first, ``" -> "`` between frames);
    ``stamp_ns`` of the health record minus ``newest_data_ns`` is the age of its ``/tf`` data."""

    _fields_ = [
        ("path", _u8 * TF_PATH_CAPACITY_BYTES),
        ("lookup_stamp_ns", _u64),
        ("newest_data_ns", _u64),
        ("dynamic_messages", _u64),
        ("static_messages", _u64),
        ("transforms_refused", _u64),
        ("time_jumps", _u64),
        ("active", _u8),
        ("reserved", _u8 * 15),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::TfHealth"

    def path_str(self) -> str:
        """``path`` as text (``""`` before the first lookup)."""
        return fixed_str(self.path)


class RemoteWorkerHealth(_Wire):
    """One remote detection worker as the robot sees it (216 bytes): ``op3dsg::RemoteWorkerHealth``.

    Counters are since the daemon started; ``rejections`` counts by :data:`REMOTE_REJECTIONS`."""

    _fields_ = [
        ("key", _u8 * REMOTE_KEY_CAPACITY_BYTES),
        ("requests", _u64),
        ("replies", _u64),
        ("timeouts", _u64),
        ("late", _u64),
        ("unreachable", _u64),
        ("rejections", _u64 * 6),
        ("bytes_out", _u64),
        ("bytes_in", _u64),
        ("round_trip_p50_us", ctypes.c_float),
        ("round_trip_p99_us", ctypes.c_float),
        ("in_flight", _u32),
        ("alive", _u8),
        ("reserved", _u8 * 3),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::RemoteWorkerHealth"

    def key_str(self) -> str:
        """``key`` as text: the worker's Zenoh key."""
        return fixed_str(self.key)

    def bytes_per_keyframe(self) -> int:
        """Bytes both ways per request sent (0 before the first)."""
        return (self.bytes_out + self.bytes_in) // self.requests if self.requests else 0


class RemoteHealth(_Wire):
    """Remote detection (``detector.kind = "remote"``; 1,752 bytes): ``op3dsg::RemoteHealth``.

    Only the first ``worker_count`` workers are valid: use :meth:`valid_workers`."""

    _fields_ = [
        ("active", _u8),
        ("fallback_active", _u8),
        ("worker_count", _u16),
        ("workers_not_reported", _u32),
        ("fallback_keyframes", _u64),
        ("fallback_switches", _u64),
        ("workers", RemoteWorkerHealth * MAX_REMOTE_WORKERS),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::RemoteHealth"

    def valid_workers(self) -> List[RemoteWorkerHealth]:
        return list(self.workers[: min(self.worker_count, MAX_REMOTE_WORKERS)])


class Health(_Wire):
    """Daemon health, published on ``<prefix>/health`` every health period: ``op3dsg::Health``.

    Only the first ``stage_count`` stages, ``queue_count`` queues and ``model_count`` models are
    valid: use :meth:`valid_stages`, :meth:`valid_queues`, :meth:`valid_models`."""

    _fields_ = [
        ("schema_version", _u32),
        ("stage_count", _u32),
        ("stamp_ns", _u64),
        ("uptime_ns", _u64),
        ("frames_captured", _u64),
        ("keyframes", _u64),
        ("frames_without_pose", _u64),
        ("detections_fused", _u64),
        ("graph_version", _u64),
        ("map_memory_bytes", _u64),
        ("map_node_count", _u32),
        ("queue_count", _u32),
        ("source_connected", _u8),
        ("source_kind", _u8),
        ("graph_subscribers", _u16),
        ("dead_nodes_cleaned", _u32),
        ("stages", StageHealth * MAX_STAGES),
        ("queues", QueueHealth * MAX_QUEUES),
        ("refiner", RefinerHealth),
        ("pose", PoseHealth),
        ("model_count", _u32),
        ("pose_source", _u8),
        ("reserved_models", _u8 * 3),
        ("models", ModelHealth * MAX_MODELS),
        ("recorder", RecorderHealth),
        ("snapshot", SnapshotHealth),
        ("world_frame", _u8 * NAME_CAPACITY_BYTES),
        ("tf", TfHealth),
        ("remote", RemoteHealth),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::Health"

    def source_kind_name(self) -> str:
        """``source_kind`` by name, as in the graph header (:data:`SOURCE_KINDS`)."""
        return source_kind_name(self.source_kind)

    def world_frame_str(self) -> str:
        """``world_frame`` as text: the frame the graph's coordinates are in."""
        return fixed_str(self.world_frame)

    def valid_stages(self) -> List[StageHealth]:
        return list(self.stages[: min(self.stage_count, MAX_STAGES)])

    def valid_queues(self) -> List[QueueHealth]:
        return list(self.queues[: min(self.queue_count, MAX_QUEUES)])

    def valid_models(self) -> List[ModelHealth]:
        return list(self.models[: min(self.model_count, MAX_MODELS)])

    def stage(self, name: str) -> StageHealth:
        """The stage called ``name`` (``capture``, ``detect/0``, ``fusion``, ...); ``KeyError`` if absent."""
        for stage in self.valid_stages():
            if fixed_str(stage.name) == name:
                return stage
        raise KeyError(f"no stage {name!r} in health (stages: {[fixed_str(s.name) for s in self.valid_stages()]})")

    def to_dict(self) -> dict:
        """The record as plain Python values (names decoded, only valid entries)."""
        return {
            "schema_version": self.schema_version,
            "stamp_ns": self.stamp_ns,
            "uptime_ns": self.uptime_ns,
            "frames_captured": self.frames_captured,
            "keyframes": self.keyframes,
            "frames_without_pose": self.frames_without_pose,
            "detections_fused": self.detections_fused,
            "graph_version": self.graph_version,
            "map_memory_bytes": self.map_memory_bytes,
            "map_node_count": self.map_node_count,
            "source_connected": bool(self.source_connected),
            "source_kind": self.source_kind_name(),
            "world_frame": self.world_frame_str(),
            "graph_subscribers": self.graph_subscribers,
            "dead_nodes_cleaned": self.dead_nodes_cleaned,
            "stages": [
                {
                    "name": fixed_str(s.name),
                    "processed": s.processed,
                    "rate_hz": s.rate_hz,
                    "latency_p50_us": s.latency_p50_us,
                    "latency_p99_us": s.latency_p99_us,
                    "errors": s.errors,
                }
                for s in self.valid_stages()
            ],
            "queues": [
                {"name": fixed_str(q.name), "depth": q.depth, "capacity": q.capacity, "dropped": q.dropped, "pushed": q.pushed}
                for q in self.valid_queues()
            ],
            "pose": self.pose.counters(),
            "pose_source": _name_of(POSE_SOURCES, self.pose_source),
            "recorder": {
                "state": _name_of(RECORDER_STATES, self.recorder.state),
                "files": self.recorder.files,
                "messages_written": self.recorder.messages_written,
                "messages_dropped": self.recorder.messages_dropped,
                "bytes_written": self.recorder.bytes_written,
                "cpu_ns": self.recorder.cpu_ns,
            },
            "snapshot": {
                "state": _name_of(SNAPSHOT_STATES, self.snapshot.state),
                "restored_version": self.snapshot.restored_version,
                "version": self.snapshot.version,
                "last_written_unix_ms": self.snapshot.last_written_unix_ms,
                "last_bytes": self.snapshot.last_bytes,
                "written": self.snapshot.written,
                "failures": self.snapshot.failures,
                "skipped": self.snapshot.skipped,
                "write_p99_us": self.snapshot.write_p99_us,
            },
            "models": [
                {
                    "name": fixed_str(m.name),
                    "sessions": m.sessions,
                    "provider": _name_of(EXECUTION_PROVIDERS, m.provider),
                    "requested_provider": _name_of(EXECUTION_PROVIDERS, m.requested_provider),
                }
                for m in self.valid_models()
            ],
            "refiner": {
                "state": _name_of(REFINER_STATES, self.refiner.state),
                "breaker_open": bool(self.refiner.breaker_open),
                "response_format": _name_of(REFINER_FORMATS, self.refiner.response_format),
                "calls": self.refiner.calls,
                "failures": self.refiner.failures,
                "accepted": self.refiner.accepted,
                "rejections": dict(zip(REFINER_REJECTIONS, list(self.refiner.rejections))),
            },
            "remote": {
                "active": bool(self.remote.active),
                "fallback_active": bool(self.remote.fallback_active),
                "fallback_keyframes": self.remote.fallback_keyframes,
                "fallback_switches": self.remote.fallback_switches,
                "workers_not_reported": self.remote.workers_not_reported,
                "workers": [
                    {
                        "key": w.key_str(),
                        "alive": bool(w.alive),
                        "requests": w.requests,
                        "replies": w.replies,
                        "timeouts": w.timeouts,
                        "late": w.late,
                        "unreachable": w.unreachable,
                        "rejections": dict(zip(REMOTE_REJECTIONS, list(w.rejections))),
                        "in_flight": w.in_flight,
                        "round_trip_p50_us": w.round_trip_p50_us,
                        "round_trip_p99_us": w.round_trip_p99_us,
                        "bytes_out": w.bytes_out,
                        "bytes_in": w.bytes_in,
                        "bytes_per_keyframe": w.bytes_per_keyframe(),
                    }
                    for w in self.remote.valid_workers()
                ],
            },
        }


def _name_of(names, index: int) -> str:
    return names[index] if index < len(names) else f"unknown({index})"


def source_kind_name(value: int) -> str:
    """The name of a ``source_kind`` value (:data:`SOURCE_KINDS`); a value newer than this
    package reads as ``unknown``, as the Rust client's ``SourceKind::Unknown``."""
    return SOURCE_KINDS[value] if 0 <= value < len(SOURCE_KINDS) else SOURCE_KINDS[SOURCE_KIND_UNKNOWN]


#: Every mirrored structure, by its Rust name.
WIRE_TYPES = {
    cls.__name__: cls
    for cls in (Node, Edge, GraphHeader, PoseStamped, StageHealth, QueueHealth, RefinerHealth, PoseHealth, ModelHealth, RecorderHealth, SnapshotHealth, TfHealth,
                RemoteWorkerHealth, RemoteHealth, Health)
}

NODE_BYTES = ctypes.sizeof(Node)
EDGE_BYTES = ctypes.sizeof(Edge)

_NUMPY_SCALARS = {
    ctypes.c_uint8: "<u1",
    ctypes.c_uint16: "<u2",
    ctypes.c_uint32: "<u4",
    ctypes.c_uint64: "<u8",
    ctypes.c_float: "<f4",
    ctypes.c_double: "<f8",
}

#: Fields whose bytes are text: viewed as ``S<n>`` (numpy strips the NUL padding).
_TEXT_FIELDS = {"label", "phrase", "name", "frame_id"}


def _numpy_format(name: str, ctype) -> object:
    if ctype in _NUMPY_SCALARS:
        return _NUMPY_SCALARS[ctype]
    if issubclass(ctype, ctypes.Array):
        element = ctype._type_
        if name in _TEXT_FIELDS and element is ctypes.c_uint8:
            return f"S{ctype._length_}"
        return (_numpy_format(name, element), (ctype._length_,))
    raise TypeError(f"no numpy format for field {name} of type {ctype}")


def dtype_of(structure) -> np.dtype:
    """The numpy structured dtype of a mirrored record: every field at its ctypes offset, the
    item size of the structure (so arrays of it step record by record). Text buffers are ``S<n>``."""
    names, formats, offsets = [], [], []
    for name, ctype in structure._fields_:
        names.append(name)
        formats.append(_numpy_format(name, ctype))
        offsets.append(getattr(structure, name).offset)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": ctypes.sizeof(structure)})


#: Structured dtype of a node record in the graph payload.
NODE_DTYPE = dtype_of(Node)
#: Structured dtype of an edge record in the graph payload.
EDGE_DTYPE = dtype_of(Edge)


def relation_phrase(relation_id: int) -> str:
    """The canonical phrase of a relation id; ``ValueError`` for an unknown one."""
    if relation_id >= FUNCTIONAL_RELATION_BASE:
        index = relation_id - FUNCTIONAL_RELATION_BASE
        if index < len(FUNCTIONAL_RELATIONS):
            return FUNCTIONAL_RELATIONS[index]
    elif relation_id < len(SPATIAL_RELATIONS):
        return SPATIAL_RELATIONS[relation_id]
    raise ValueError(f"unknown relation id {relation_id}")


def affordance_names(bits: int) -> Iterator[str]:
    """Names of the affordances set in ``bits``, in canonical order."""
    return (name for i, name in enumerate(AFFORDANCES) if bits & (1 << i))


def affordance_origin(bits: int, knowledge_bits: int, llm_bits: int, index: int) -> Optional[str]:
    """Where affordance ``AFFORDANCES[index]`` of a node came from, as the edge origins name it:
    its bit in ``knowledge_bits`` only ``"knowledge"``, in ``llm_bits`` only ``"llm"``, in both
    ``"knowledge+llm"``, in neither ``"geometry"``; ``None`` when ``bits`` lacks it."""
    if not 0 <= index < len(AFFORDANCES) or not bits & (1 << index):
        return None
    knowledge, llm = bool(knowledge_bits & (1 << index)), bool(llm_bits & (1 << index))
    return EDGE_ORIGINS[(1 if knowledge else 0) + (2 if llm else 0)]


def affordance_origins(bits: int, knowledge_bits: int, llm_bits: int) -> Dict[str, str]:
    """Each affordance in ``bits`` with its origin (:func:`affordance_origin`), in canonical order."""
    return {
        name: affordance_origin(bits, knowledge_bits, llm_bits, i)
        for i, name in enumerate(AFFORDANCES)
        if bits & (1 << i)
    }


def affordance_bits(names) -> int:
    """Bit set over :data:`AFFORDANCES` of ``names``; ``ValueError`` naming an unknown one."""
    bits = 0
    for name in names:
        if name not in AFFORDANCES:
            raise ValueError(f"unknown affordance {name!r} (known: {', '.join(AFFORDANCES)})")
        bits |= 1 << AFFORDANCES.index(name)
    return bits
