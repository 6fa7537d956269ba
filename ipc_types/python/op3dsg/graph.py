"""Reading the scene graph: :class:`GraphClient` (``<prefix>/graph`` and ``<prefix>/graph_updated``),
:class:`GraphView` (numpy views of one shared-memory sample, zero copy) and :class:`Graph` (an
owned copy with the same interface).

The one-borrowed-sample rule
----------------------------
The daemon creates ``<prefix>/graph`` with ``subscriber_max_borrowed_samples = 1``: a subscriber
holds at most one sample at a time. A :class:`GraphView` *is* that borrowed sample; its
``nodes`` and ``edges`` arrays point into the daemon's shared memory. So:

- :meth:`GraphClient.latest` releases the view it returned before (``sample.delete()``) when a
  newer sample is waiting, then borrows the newest. The old view is then invalid: its methods
  raise :class:`~op3dsg.errors.SampleReleasedError`, and numpy arrays taken from it earlier
  must not be used any more (their memory may already hold a newer graph).
- Keep what you need beyond the next ``latest()`` with :meth:`GraphView.copy` (an owned
  :class:`Graph`, about 0.1 ms for 2,000 nodes) or by copying single arrays (``np.copy``).
- :meth:`GraphView.release` (or :meth:`GraphClient.release`) gives the sample back early, so a
  planner idle for a long time does not hold daemon memory.

The arrays are read-only (``writeable = False``); the shared memory belongs to the daemon.
"""

from __future__ import annotations

import ctypes
import time
from typing import List, Optional

import iceoryx2 as iox2
import numpy as np

from . import _iox
from .errors import InvalidGraphError, Op3dsgError, SampleReleasedError, SchemaVersionError
from .wire import (
    EDGE_BYTES,
    EDGE_DTYPE,
    EDGE_KINDS,
    EDGE_ORIGINS,
    HISTORY_SIZE,
    NO_NODE,
    NODE_BYTES,
    NODE_DTYPE,
    NODE_KIND_PART,
    NODE_KINDS,
    SCHEMA_VERSION,
    GraphHeader,
    affordance_bits,
    affordance_names,
    affordance_origins,
    fixed_str,
    relation_phrase,
)


def _f32(value) -> float:
    """An f32 as the float of its shortest decimal form (what the graph JSON writes), so
    ``0.7178173`` and not ``0.7178173065185547``."""
    return float(str(np.float32(value)))


class _GraphData:
    """What a borrowed view and an owned copy share: the header, the node and edge arrays, and
    lookups on them. Subclasses provide ``_service`` (named in errors), ``_header``, ``_nodes``,
    ``_edges`` and ``restarted``."""

    _service: str
    _header: GraphHeader
    _nodes: np.ndarray
    _edges: np.ndarray
    restarted: bool

    def _check(self) -> None:
        """Raises when the data is gone (only a released view)."""

    def check_records(self) -> None:
        """Every node's kind and every edge's kind and origin within the vocabulary, the first one
        outside named (:class:`~op3dsg.errors.InvalidGraphError`): the record check the Rust
        owned decode runs on receipt, which a view skips (one vectorised pass over the records,
        as long as reading them all). :meth:`GraphView.copy` runs it."""
        _check_records(self._service, self.nodes, self.edges)

    # -- header -----------------------------------------------------------------------------
    @property
    def header(self) -> GraphHeader:
        """A copy of the sample's :class:`~op3dsg.wire.GraphHeader` (every field)."""
        self._check()
        copy = GraphHeader()
        ctypes.memmove(ctypes.addressof(copy), ctypes.addressof(self._header), ctypes.sizeof(GraphHeader))
        return copy

    @property
    def version(self) -> int:
        """Graph version: grows by one per published change while one daemon instance runs;
        compare versions only between graphs of the same :attr:`instance_id`."""
        self._check()
        return self._header.graph_version

    @property
    def instance_id(self) -> int:
        """The publishing daemon's instance, drawn anew (never 0) at every start."""
        self._check()
        return self._header.instance_id

    @property
    def stamp_ns(self) -> int:
        """Stamp of the newest keyframe fused into this version, nanoseconds."""
        self._check()
        return self._header.stamp_ns

    @property
    def publish_time_ns(self) -> int:
        """Wall-clock time the daemon wrote the sample, nanoseconds since the Unix epoch."""
        self._check()
        return self._header.publish_time_ns

    @property
    def capacity_exceeded(self) -> bool:
        """The map held more nodes or edges than the daemon publishes (its ``ipc.max_nodes`` /
        ``ipc.max_edges``); the sample then holds the most recently seen nodes."""
        self._check()
        return bool(self._header.capacity_exceeded)

    @property
    def source_kind(self) -> str:
        """What the daemon reads its frames from: ``live_camera``, ``replay``, ``synthetic``, or
        ``unknown`` (a value this package does not know, or a publisher that does not say). A
        planner about to move the robot checks it is ``live_camera``."""
        self._check()
        return self._header.source_kind_name()

    @property
    def world_frame(self) -> str:
        """Name of the frame every coordinate of this graph is in (the daemon's ``world.frame_id``:
        ``world`` by default, ``map`` on the Stretch profile)."""
        self._check()
        return self._header.world_frame_str()

    @property
    def node_count(self) -> int:
        self._check()
        return int(self._header.node_count)

    @property
    def edge_count(self) -> int:
        self._check()
        return int(self._header.edge_count)

    # -- records ----------------------------------------------------------------------------
    @property
    def nodes(self) -> np.ndarray:
        """The nodes, sorted by id, as a structured array of :data:`~op3dsg.wire.NODE_DTYPE`
        (fields ``id``, ``parent_id``, ``kind``, ``label`` (bytes), ``confidence``, ``centre_m``,
        ``box_min_m``, ``box_max_m``, ``affordance_bits``, ``affordance_knowledge_bits``,
        ``affordance_llm_bits``, ``observation_count``,
        ``last_seen_stamp_ns``, ...). A view of shared memory for a :class:`GraphView`."""
        self._check()
        return self._nodes

    @property
    def edges(self) -> np.ndarray:
        """The edges as a structured array of :data:`~op3dsg.wire.EDGE_DTYPE` (``source_id``,
        ``target_id``, ``kind``, ``origin``, ``relation_id``, ``confidence``, ``phrase``)."""
        self._check()
        return self._edges

    def label(self, index: int) -> str:
        """The label of the node at ``index`` (not id), decoded from UTF-8."""
        return fixed_str(self.nodes["label"][index])

    def labels(self) -> List[str]:
        """Every node's label, in node order."""
        return [fixed_str(raw) for raw in self.nodes["label"]]

    def phrase(self, index: int) -> str:
        """The relation phrase of the edge at ``index``."""
        return fixed_str(self.edges["phrase"][index])

    # -- lookups: the Rust GraphView's, answered by index (into ``nodes`` / ``edges``) ----------
    def index_of(self, node_id: int) -> Optional[int]:
        """Index of the node with ``node_id`` (a binary search: the contract sorts the nodes by
        id), ``None`` when absent."""
        ids = self.nodes["id"]
        i = int(np.searchsorted(ids, node_id))
        return i if i < len(ids) and ids[i] == node_id else None

    def node(self, node_id: int) -> Optional[dict]:
        """The node with ``node_id`` in the graph JSON form (:meth:`node_dict`), ``None`` when
        absent."""
        i = self.index_of(node_id)
        return None if i is None else self.node_dict(i)

    def objects(self) -> np.ndarray:
        """Indices of the object nodes."""
        return np.flatnonzero(self.nodes["kind"] != NODE_KIND_PART)

    def parts(self) -> np.ndarray:
        """Indices of the part nodes."""
        return np.flatnonzero(self.nodes["kind"] == NODE_KIND_PART)

    def parts_of(self, object_id: int) -> np.ndarray:
        """Indices of the nodes whose parent is the node ``object_id`` (its parts); empty for an id
        not in this graph."""
        if self.index_of(object_id) is None:
            return np.empty(0, np.intp)
        return np.flatnonzero(self.nodes["parent_id"] == object_id)

    def parent_of(self, part_id: int) -> Optional[int]:
        """Index of the parent object of the part ``part_id``; ``None`` for objects, unattached
        parts, parents not in this graph and unknown ids."""
        i = self.index_of(part_id)
        if i is None:
            return None
        parent = int(self.nodes["parent_id"][i])
        return None if parent == NO_NODE else self.index_of(parent)

    def edges_from(self, node_id: int) -> np.ndarray:
        """Indices of the edges whose source is ``node_id``; empty for an id not in this graph."""
        if self.index_of(node_id) is None:
            return np.empty(0, np.intp)
        return np.flatnonzero(self.edges["source_id"] == node_id)

    def edges_to(self, node_id: int) -> np.ndarray:
        """Indices of the edges whose target is ``node_id``; empty for an id not in this graph."""
        if self.index_of(node_id) is None:
            return np.empty(0, np.intp)
        return np.flatnonzero(self.edges["target_id"] == node_id)

    def find_by_label(self, label: str) -> np.ndarray:
        """Indices of the nodes labelled exactly ``label``."""
        return np.flatnonzero(self.nodes["label"] == label.encode("utf-8"))

    def find_by_label_containing(self, text: str) -> np.ndarray:
        """Indices of the nodes whose label contains ``text``, ASCII letters compared without
        case (``"handle"`` finds "Cabinet Handle" and "drawer handle")."""
        labels = self.nodes["label"]
        if not text:
            return np.arange(len(labels))
        return np.flatnonzero(np.char.find(np.char.lower(labels), text.encode("utf-8").lower()) >= 0)

    def find_by_affordance(self, name: str) -> np.ndarray:
        """Indices of the nodes that afford ``name`` (one of :data:`~op3dsg.wire.AFFORDANCES`;
        ``ValueError`` naming them for another name)."""
        return self.find_by_affordance_bits(affordance_bits([name]))

    def find_by_affordance_bits(self, bits: int) -> np.ndarray:
        """Indices of the nodes that afford every affordance in ``bits`` (a set over
        :data:`~op3dsg.wire.AFFORDANCES`, see :func:`~op3dsg.wire.affordance_bits`)."""
        return np.flatnonzero((self.nodes["affordance_bits"] & bits) == bits)

    def affordance_origins(self, index: int) -> dict:
        """The affordances of the node at ``index`` (not id), each with its origin
        (``"knowledge"``, ``"llm"``, ``"knowledge+llm"``; ``"geometry"`` where the publisher gave
        none), in canonical order: ``{"hook_pull": "knowledge+llm", "pinch_pull": "llm"}``."""
        n = self.nodes[index]
        return affordance_origins(
            int(n["affordance_bits"]), int(n["affordance_knowledge_bits"]), int(n["affordance_llm_bits"])
        )

    def node_dict(self, index: int) -> dict:
        """The node at ``index`` in the graph JSON form (``op3dsg dump --json``)."""
        n = self.nodes[index]
        parent = int(n["parent_id"])
        node = {
            "id": int(n["id"]),
            "label": fixed_str(n["label"]),
            "kind": self._name(NODE_KINDS, n, f"nodes[{index}].kind", "(0 object, 1 part)"),
            "parent": None if parent == NO_NODE else parent,
            "centre_m": [_f32(v) for v in n["centre_m"]],
            "box_min_m": [_f32(v) for v in n["box_min_m"]],
            "box_max_m": [_f32(v) for v in n["box_max_m"]],
            "obb": {
                "centre_m": [_f32(v) for v in n["obb_centre_m"]],
                "size_m": [_f32(v) for v in n["obb_size_m"]],
                "yaw_rad": _f32(n["obb_yaw_rad"]),
            },
            "affordances": list(affordance_names(int(n["affordance_bits"]))),
            "confidence": _f32(n["confidence"]),
            "observation_count": int(n["observation_count"]),
        }
        origins = self.affordance_origins(index)
        if origins:
            node["affordance_origins"] = origins
        return node

    def edge_dict(self, index: int) -> dict:
        """The edge at ``index`` in the graph JSON form."""
        e = self.edges[index]
        return {
            "source": int(e["source_id"]),
            "target": int(e["target_id"]),
            "kind": self._name(EDGE_KINDS, e, f"edges[{index}].kind", "(0 spatial, 1 functional)"),
            "relation": relation_phrase(int(e["relation_id"])),
            "confidence": _f32(e["confidence"]),
            "origin": self._name(EDGE_ORIGINS, e, f"edges[{index}].origin", "(0..=3)"),
        }

    def _name(self, names, record, field: str, known: str) -> str:
        """The name of ``record``'s value of ``field`` (``nodes[i].kind``, ...); a value outside
        ``names`` raises :class:`~op3dsg.errors.InvalidGraphError` naming it, as
        :meth:`check_records` would."""
        value = int(record[field.rsplit(".", 1)[1]])
        if value >= len(names):
            raise _invalid(self._service, f"{field}: unknown value {value} {known}")
        return names[value]

    def to_dict(self) -> dict:
        """The whole graph in the graph JSON form (``op3dsg.graph/1``, as ``op3dsg dump --json``;
        floats are the f32 values' shortest decimal form, as there)."""
        return {
            "schema": "op3dsg.graph/1",
            "source": "op3dsgd",
            "graph_version": self.version,
            "stamp_ns": self.stamp_ns,
            "source_kind": self.source_kind,
            "world_frame": self.world_frame,
            "nodes": [self.node_dict(i) for i in range(self.node_count)],
            "edges": [self.edge_dict(i) for i in range(self.edge_count)],
        }


class Graph(_GraphData):
    """An owned graph (from :meth:`GraphView.copy`): the same interface as :class:`GraphView`,
    valid for as long as it is kept, writable arrays of its own."""

    def __init__(self, header: GraphHeader, nodes: np.ndarray, edges: np.ndarray, restarted: bool, service: str = "graph"):
        self._service = service
        self._header = header
        self._nodes = nodes
        self._edges = edges
        self.restarted = restarted

    @classmethod
    def from_bytes(cls, data, source: str = "graph bytes") -> "Graph":
        """A graph sample laid out in one buffer (the header's 112 bytes, then the payload), read
        in place: the arrays view ``data`` (read-only, no copy). Checked as a received sample is
        (the header against the length, the alignment; the records by :meth:`check_records`),
        and more: a buffer shorter than a header, or not starting on an 8-byte boundary, raises
        :class:`~op3dsg.errors.InvalidGraphError`; ``source`` names it in errors."""
        raw = np.frombuffer(data, dtype=np.uint8)
        header_bytes = ctypes.sizeof(GraphHeader)
        if raw.size < header_bytes:
            raise _invalid(source, f"header: {raw.size} bytes, but a GraphHeader has {header_bytes}")
        _check_alignment(source, "header", int(raw.ctypes.data))
        header = GraphHeader.from_buffer_copy(raw[:header_bytes].tobytes())
        nodes, edges = _records(source, header, raw[header_bytes:])
        return cls(header, _read_only(nodes), _read_only(edges), False, source)

    def __repr__(self) -> str:
        return f"Graph(version={self.version}, instance_id={self.instance_id:#018x}, nodes={self.node_count}, edges={self.edge_count})"


class GraphView(_GraphData):
    """One borrowed graph sample: the header and numpy views of its node and edge records in
    shared memory (no copy). Valid until the next :meth:`GraphClient.latest` that finds a newer
    sample, or :meth:`release`; see the module docs for the one-borrowed-sample rule.

    ``restarted`` is ``True`` when the graph received before this one by the same client came
    from another daemon instance: the daemon restarted in between, its versions started again
    at 1 and its node ids mean other nodes. Forget version bookkeeping and cached ids."""

    def __init__(self, service: str, sample, header: GraphHeader, nodes: np.ndarray, edges: np.ndarray, restarted: bool):
        self._service = service
        self._sample = sample
        self._header = header
        self._nodes = nodes
        self._edges = edges
        self.restarted = restarted

    @property
    def valid(self) -> bool:
        """``False`` once the sample went back to the daemon."""
        return self._sample is not None

    def _check(self) -> None:
        if self._sample is None:
            raise SampleReleasedError(
                self._service,
                "read",
                "this graph view's sample was released (a newer latest() or release()); "
                "keep view.copy() to read a graph after the next latest()",
            )

    def copy(self) -> Graph:
        """An owned copy of this graph (header, nodes, edges), valid after the sample is released.
        The records are checked first (:meth:`check_records`), as the Rust owned copy checks them."""
        self.check_records()
        return Graph(self.header, self.nodes.copy(), self.edges.copy(), self.restarted, self._service)

    def release(self) -> None:
        """Gives the sample back to the daemon now (``sample.delete()``); the view and every array
        taken from it are invalid afterwards. Calling it twice does nothing."""
        sample, self._sample = self._sample, None
        if sample is not None:
            sample.delete()

    def __enter__(self) -> "GraphView":
        return self

    def __exit__(self, *exc) -> None:
        """Leaving a ``with`` block gives the sample back (:meth:`release`)."""
        self.release()

    def __repr__(self) -> str:
        if not self.valid:
            return "GraphView(released)"
        return (
            f"GraphView(version={self.version}, instance_id={self.instance_id:#018x}, "
            f"nodes={self.node_count}, edges={self.edge_count}, restarted={self.restarted})"
        )


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


def _invalid(service: str, what: str) -> InvalidGraphError:
    return InvalidGraphError(service, "receive", f"invalid sample: {what}")


def _check_header(service: str, header: GraphHeader, payload_len: int) -> None:
    """The header half of the Rust ``check_message``: schema, counts within capacity, payload size."""
    if header.schema_version != SCHEMA_VERSION:
        raise SchemaVersionError(service, header.schema_version, SCHEMA_VERSION)
    node_count, edge_count = header.node_count, header.edge_count
    if node_count > header.node_capacity:
        raise _invalid(service, f"header.node_count: {node_count} exceeds the capacity {header.node_capacity}")
    if edge_count > header.edge_capacity:
        raise _invalid(service, f"header.edge_count: {edge_count} exceeds the capacity {header.edge_capacity}")
    expected = node_count * NODE_BYTES + edge_count * EDGE_BYTES
    if payload_len != expected:
        raise _invalid(
            service,
            f"payload: {payload_len} bytes, but the header's counts need {expected} ({NODE_BYTES} per node, {EDGE_BYTES} per edge)",
        )


#: The alignment of the node records (their ``u64`` field): where a payload must start to be
#: read in place, as the Rust client requires.
RECORD_ALIGNMENT = 8


def _check_alignment(service: str, field: str, address: int) -> None:
    if address % RECORD_ALIGNMENT:
        raise _invalid(
            service,
            f"{field}: starts at address {address:#x}, not a multiple of {RECORD_ALIGNMENT} (its records' alignment), "
            "so it cannot be read in place",
        )


def _records(service: str, header: GraphHeader, payload: np.ndarray):
    """The node and edge arrays viewing ``payload`` (a ``uint8`` array) after the constant-time
    checks of the Rust ``GraphView``: the header against the payload's length, the payload's
    alignment (when it holds records). The records are not scanned (:func:`_check_records`)."""
    _check_header(service, header, payload.size)
    node_count, edge_count = int(header.node_count), int(header.edge_count)
    if not payload.size:
        return np.empty(0, NODE_DTYPE), np.empty(0, EDGE_DTYPE)
    _check_alignment(service, "payload", int(payload.ctypes.data))
    nodes = np.frombuffer(payload, dtype=NODE_DTYPE, count=node_count, offset=0)
    edges = np.frombuffer(payload, dtype=EDGE_DTYPE, count=edge_count, offset=node_count * NODE_BYTES)
    return nodes, edges


def _check_records(service: str, nodes: np.ndarray, edges: np.ndarray) -> None:
    """The record half of ``check_message``: every node's kind, every edge's kind and origin
    (one vectorised pass each; the index of the first bad one only on failure)."""
    for records, field, limit, what in (
        (nodes, "kind", 1, "nodes[{}].kind: unknown value {} (0 object, 1 part)"),
        (edges, "kind", 1, "edges[{}].kind: unknown value {} (0 spatial, 1 functional)"),
        (edges, "origin", 3, "edges[{}].origin: unknown value {} (0..=3)"),
    ):
        values = records[field]
        if values.size and values.max() > limit:
            first = int(np.argmax(values > limit))
            raise _invalid(service, what.format(first, values[first]))


class GraphClient:
    """The planner's reader of ``<prefix>/graph``, woken by ``<prefix>/graph_updated``.

    ::

        client = op3dsg.GraphClient("op3dsg", timeout=30)   # waits up to 30 s for the daemon
        while True:
            client.wait_for_update(0.5)
            graph = client.latest()                        # GraphView or None, zero copy
            if graph is not None:
                handles = graph.find_by_label("cabinet handle")
                print(graph.version, graph.nodes["centre_m"][handles])

    The constructor waits for the service's history, the daemon's newest graph (up to
    ``ATTACH_HISTORY_WAIT_S``, one second; the daemon hands it over within 20 ms), so the first
    :meth:`latest` returns it. Only a daemon that has published no graph yet gives none; its
    first one then comes with an update event.

    ``prefix``: the daemon's service prefix; ``None`` takes ``$OP3DSG_PREFIX``, else ``op3dsg``
    (as the ``op3dsg`` command does). ``timeout`` (seconds): how long the constructor waits for a
    daemon that is not up yet (0: fail at once with :class:`~op3dsg.errors.NotServingError`).
    A view can be used in a ``with`` block, which gives its sample back at the end::

        with client.latest() as graph:
            print(graph.node(graph.nodes["id"][0]))
    """

    def __init__(self, prefix: Optional[str] = None, timeout: float = 0.0, node_name: Optional[str] = None):
        self.prefix = prefix = _iox.resolve_prefix(prefix)
        self.service = _iox.service_name(prefix, "graph")
        self.event_service = _iox.service_name(prefix, "graph_updated")
        deadline = _iox.deadline_after(timeout)
        name = node_name or _iox.default_node_name("graph")
        self._node = _iox.retry_while_not_serving(timeout, lambda: _iox.create_node(prefix, self.service, name))
        self._subscriber, self._listener = _iox.retry_while_not_serving(_iox.left_until(deadline), self._open_ports)
        _iox.await_history(self.service, self._subscriber)
        self._view: Optional[GraphView] = None
        self._last_instance = 0
        self._if_newer_instance = 0

    def _open_ports(self):
        try:
            service = (
                self._node.service_builder(iox2.ServiceName.new(self.service))
                .publish_subscribe(iox2.Slice[ctypes.c_uint8])
                .user_header(GraphHeader)
                .open()
            )
        except Exception as e:
            raise _iox.open_error(self.service, e) from e
        try:
            subscriber = service.subscriber_builder().history_request(HISTORY_SIZE).create()
        except Exception as e:
            raise _iox.open_error(self.service, e, "create subscriber") from e
        try:
            event = self._node.service_builder(iox2.ServiceName.new(self.event_service)).event().open()
        except Exception as e:
            raise _iox.open_error(self.event_service, e) from e
        try:
            listener = event.listener_builder().create()
        except Exception as e:
            raise _iox.open_error(self.event_service, e, "create listener") from e
        return subscriber, listener

    # -- waiting ----------------------------------------------------------------------------
    def wait_for_update(self, timeout: float) -> bool:
        """Waits up to ``timeout`` seconds for a new graph; ``True`` when one is waiting (a
        ``graph_updated`` event came, or a sample is already queued), ``False`` on timeout."""
        queued = self._has_samples()
        try:
            if queued:
                self._listener.try_wait()
                return True
            if timeout <= 0:
                # iceoryx2's timed wait takes a zero duration as no limit: only look.
                return len(self._listener.try_wait()) > 0
            return len(self._listener.timed_wait(_iox.duration(timeout))) > 0
        except Exception as e:
            if _iox.reason(e) == "InterruptSignal":
                return queued
            raise _iox.open_error(self.event_service, e, "wait") from e

    def _has_samples(self) -> bool:
        try:
            return self._subscriber.has_samples()
        except Exception as e:
            raise _iox.open_error(self.service, e, "receive") from e

    # -- reading ----------------------------------------------------------------------------
    def latest(self) -> Optional[GraphView]:
        """The newest graph as a :class:`GraphView` (zero copy), or ``None`` while the daemon
        has published nothing this client could receive.

        When a newer sample is queued, the view returned before is released first (one borrowed
        sample at most), older queued samples are released unread, and the newest is checked
        against the contract in constant time, as the Rust view is (schema version, counts
        within capacity, payload size, alignment): a bad one raises
        :class:`~op3dsg.errors.SchemaVersionError` or :class:`~op3dsg.errors.InvalidGraphError`
        and is released. The records' kinds and origins are checked by
        :meth:`GraphView.check_records` and :meth:`GraphView.copy`, and a value outside the
        vocabulary raises when :meth:`GraphView.node_dict` or :meth:`GraphView.edge_dict` reads
        it. Without a newer sample the current view is returned again."""
        if not self._has_samples():
            return self._view if self._view is not None and self._view.valid else None
        self.release()
        newest = None
        while self._has_samples():
            if newest is not None:
                newest.delete()
            try:
                newest = self._subscriber.receive()
            except Exception as e:
                raise _iox.open_error(self.service, e, "receive") from e
        if newest is None:
            return None
        try:
            view = self._wrap(newest)
        except Op3dsgError:
            newest.delete()
            raise
        self._view = view
        return view

    def latest_if_newer(self, last_seen_version: int) -> Optional[GraphView]:
        """Like :meth:`latest`, but ``None`` also when the newest graph has version
        ``last_seen_version`` and comes from the same daemon instance as the graph this call
        returned last (pass 0 before the first graph). A restarted daemon's graphs count as new
        whatever their version (their ``restarted`` flag then says so)."""
        view = self.latest()
        if view is None:
            return None
        if view.instance_id == self._if_newer_instance and view.version == last_seen_version:
            return None
        self._if_newer_instance = view.instance_id
        return view

    @property
    def restarted(self) -> bool:
        """``restarted`` of the graph :meth:`latest` returned last: it came from another daemon
        instance than the graph this client received before it."""
        return self._view is not None and self._view.restarted

    def release(self) -> None:
        """Gives the borrowed sample back to the daemon (the current view becomes invalid)."""
        if self._view is not None:
            self._view.release()
            self._view = None

    def close(self) -> None:
        """Releases the sample and the ports; the client is unusable afterwards."""
        self.release()
        for port in (getattr(self, "_subscriber", None), getattr(self, "_listener", None)):
            if port is not None:
                port.delete()
        self._subscriber = self._listener = None

    def __enter__(self) -> "GraphClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _wrap(self, sample) -> GraphView:
        header = GraphHeader()
        ctypes.memmove(ctypes.addressof(header), sample.user_header_ptr, ctypes.sizeof(GraphHeader))
        # The slice length in bytes (the payload is u8, so elements are bytes): the iceoryx2
        # header's count, since Python's Slice.len() is unreliable in 0.10.
        payload_len = int(sample.header.number_of_elements)
        _check_header(self.service, header, payload_len)
        if payload_len:
            buffer = (ctypes.c_uint8 * payload_len).from_address(sample.payload_ptr)
            # The arrays keep the sample object alive (so it is not released while they exist).
            buffer._op3dsg_sample = sample
            nodes, edges = _records(self.service, header, np.frombuffer(buffer, dtype=np.uint8))
        else:
            nodes, edges = np.empty(0, NODE_DTYPE), np.empty(0, EDGE_DTYPE)
        restarted = self._last_instance not in (0, header.instance_id)
        self._last_instance = header.instance_id
        return GraphView(self.service, sample, header, _read_only(nodes), _read_only(edges), restarted)

    def __repr__(self) -> str:
        return f"GraphClient(prefix={self.prefix!r})"


def wait_for_graph(client: GraphClient, timeout: float, min_nodes: int = 0) -> GraphView:
    """Waits up to ``timeout`` seconds for a graph with at least ``min_nodes`` nodes; raises
    ``TimeoutError`` naming the service otherwise."""
    deadline = time.monotonic() + timeout
    while True:
        view = client.latest()
        if view is not None and view.node_count >= min_nodes:
            return view
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError(f"{client.service}: no graph with at least {min_nodes} nodes within {timeout:.1f} s")
        client.wait_for_update(min(left, 0.2))

