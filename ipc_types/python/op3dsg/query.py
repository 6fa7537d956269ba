"""Language queries: :func:`query` / :class:`QueryClient` ask the daemon's ``<prefix>/query``
service (iceoryx2 request-response) for the nodes that serve a need in words::

    import op3dsg
    for hit in op3dsg.query("somewhere to wash my hands", k=3):
        print(hit.node_id, hit.kind, hit.label, round(hit.score, 3), hit.matched, hit.matched_text)

Every hit carries a navigation target (:class:`Approach`: where to stand on the daemon's
occupancy map, facing the node, reachable from the robot's latest pose by A*), or the reason
there is none (``approach_status``). :func:`goal` asks for one node's target, by id or by a
need in words (the query's top hit)::

    g = op3dsg.goal(12)                      # or op3dsg.goal("somewhere to wash my hands")
    print(g.x_m, g.y_m, g.yaw_rad, g.standoff_m, g.path_m)

The ctypes mirrors of the Rust ``op3dsg_ipc_types::query_types`` (query schema 2:
``QueryRequest`` 272 bytes, ``QueryHit`` 192, ``QueryResponse`` 3296) are here; their
``type_name()`` are the Rust ``#[type_name]``. Text queries need the daemon's
``text_encoder.enabled = true``; otherwise, or when it is busy, :class:`QueryError` carries its
status and message. Queries by node id need no encoder.
"""

from __future__ import annotations

import ctypes
import time
from dataclasses import dataclass
from typing import List, Optional

import iceoryx2 as iox2

from . import _iox
from .errors import Op3dsgError
from .wire import LABEL_CAPACITY_BYTES, NO_NODE, NODE_KINDS, _Wire, fixed_str, write_fixed_str

QUERY_SCHEMA_VERSION = 2
QUERY_TEXT_CAPACITY_BYTES = 256
QUERY_MAX_K = 16
QUERY_MATCHED_TEXT_CAPACITY_BYTES = 96
QUERY_MESSAGE_CAPACITY_BYTES = 160
#: Requests one client may have in flight (the service's ``max_active_requests_per_client``).
QUERY_MAX_ACTIVE_REQUESTS_PER_CLIENT = 4
#: Clients (planners, ``op3dsg query``) that may hold a ``query`` port at once (``QUERY_MAX_CLIENTS``).
QUERY_MAX_CLIENTS = 16
#: ``QueryResponse.status`` values, by wire value.
QUERY_STATUSES = ("ok", "busy", "encoder_off", "no_graph", "bad_request", "encoder_failed", "shutting_down")
#: ``QueryHit.matched`` values, by wire value.
QUERY_MATCHES = ("label", "parent_label", "affordance", "functional")
#: ``QueryHit.approach_status`` values, by wire value.
APPROACH_STATUSES = ("off", "ok", "no_free_cell", "unreachable", "no_map", "robot_not_on_map")
#: What each approach status means, for people.
APPROACH_REASONS = {
    "off": "the daemon builds no occupancy map (occupancy.enabled = false)",
    "ok": "approach pose found",
    "no_free_cell": "no free cell within the standoff band",
    "unreachable": "unreachable from the robot's pose",
    "no_map": "no occupancy map yet (no keyframe integrated)",
    "robot_not_on_map": "the robot's latest position is not on a free cell of the map",
}
#: ``QueryRequest.node_id`` of a text query.
NO_NODE_REQUEST = 0xFFFF_FFFF

_u8, _u32, _u64, _f32 = ctypes.c_uint8, ctypes.c_uint32, ctypes.c_uint64, ctypes.c_float


class QueryRequest(_Wire):
    _fields_ = [
        ("schema_version", _u32),
        ("k", _u32),
        ("text", _u8 * QUERY_TEXT_CAPACITY_BYTES),
        ("node_id", _u32),
        ("reserved", _u32),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::QueryRequest"


class QueryHit(_Wire):
    _fields_ = [
        ("node_id", _u32),
        ("parent_id", _u32),
        ("kind", _u8),
        ("matched", _u8),
        ("reserved", _u8 * 2),
        ("score", _f32),
        ("label", _u8 * LABEL_CAPACITY_BYTES),
        ("matched_text", _u8 * QUERY_MATCHED_TEXT_CAPACITY_BYTES),
        ("approach_status", _u8),
        ("reserved2", _u8 * 3),
        ("approach_x_m", _f32),
        ("approach_y_m", _f32),
        ("approach_yaw_rad", _f32),
        ("approach_standoff_m", _f32),
        ("approach_path_m", _f32),
        ("reserved3", _u32 * 2),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::QueryHit"


class QueryResponse(_Wire):
    _fields_ = [
        ("schema_version", _u32),
        ("status", _u8),
        ("reserved", _u8 * 3),
        ("graph_version", _u64),
        ("instance_id", _u64),
        ("hit_count", _u32),
        ("queue_capacity", _u32),
        ("served_count", _u64),
        ("refused_count", _u64),
        ("encode_us", _u32),
        ("score_us", _u32),
        ("scored_node_count", _u32),
        ("reserved2", _u32),
        ("message", _u8 * QUERY_MESSAGE_CAPACITY_BYTES),
        ("hits", QueryHit * QUERY_MAX_K),
    ]

    @staticmethod
    def type_name() -> str:
        return "op3dsg::QueryResponse"


class QueryError(Op3dsgError):
    """The daemon answered, but with no hits: ``status`` (``busy``, ``encoder_off``,
    ``no_graph``, ``bad_request``, ``encoder_failed``, ``shutting_down``) and its ``message``."""

    def __init__(self, service: str, status: str, message: str):
        super().__init__(service, "query", f"{status}: {message}")
        self.status = status
        self.message = message


class GoalError(Op3dsgError):
    """The node exists but has no approach pose: ``status`` (``no_free_cell``, ``unreachable``,
    ``no_map``, ``robot_not_on_map``, ``off``) and ``reason`` (a sentence), with the node."""

    def __init__(self, service: str, node_id: int, label: str, status: str):
        self.status = status
        self.reason = APPROACH_REASONS.get(status, f"unknown approach status {status}")
        self.node_id = node_id
        self.label = label
        super().__init__(service, "goal", f"node {node_id} ({label}): no approach pose: {self.reason}")


@dataclass(frozen=True)
class Approach:
    """Where to stand to reach a node, on the floor plane of the world frame (x, y with z up)."""

    x_m: float
    y_m: float
    #: Heading facing the node's centre, ``atan2(dy, dx)``, radians.
    yaw_rad: float
    #: Distance to the node's footprint (its box on the floor), metres.
    standoff_m: float
    #: Length of the A* path from the robot's latest position, metres.
    path_m: float


@dataclass(frozen=True)
class Goal:
    """The answer of :func:`goal`: the node and where to stand."""

    node_id: int
    kind: str
    label: str
    graph_version: int
    approach: Approach

    @property
    def x_m(self) -> float:
        return self.approach.x_m

    @property
    def y_m(self) -> float:
        return self.approach.y_m

    @property
    def yaw_rad(self) -> float:
        return self.approach.yaw_rad

    @property
    def standoff_m(self) -> float:
        return self.approach.standoff_m

    @property
    def path_m(self) -> float:
        return self.approach.path_m


@dataclass(frozen=True)
class Hit:
    """One node of a reply, best first."""

    node_id: int
    parent_id: Optional[int]
    kind: str
    label: str
    score: float
    #: Which text matched best: ``label``, ``parent_label``, ``affordance`` or ``functional``.
    matched: str
    matched_text: str
    #: ``ok`` or why there is no approach pose (see ``APPROACH_REASONS``).
    approach_status: str = "off"
    #: Where to stand, with ``approach_status == "ok"``.
    approach: Optional[Approach] = None


@dataclass(frozen=True)
class QueryResult:
    """A reply: the hits and the graph they come from."""

    hits: List[Hit]
    graph_version: int
    instance_id: int
    scored_node_count: int
    encode_us: int
    score_us: int

    def __iter__(self):
        return iter(self.hits)

    def __len__(self) -> int:
        return len(self.hits)


def _name(names, index: int) -> str:
    return names[index] if 0 <= index < len(names) else f"unknown({index})"


def _approach(h: QueryHit) -> Optional[Approach]:
    if _name(APPROACH_STATUSES, h.approach_status) != "ok":
        return None
    return Approach(
        x_m=float(h.approach_x_m),
        y_m=float(h.approach_y_m),
        yaw_rad=float(h.approach_yaw_rad),
        standoff_m=float(h.approach_standoff_m),
        path_m=float(h.approach_path_m),
    )


class QueryClient:
    """A client of ``<prefix>/query``. ``prefix`` ``None``: ``$OP3DSG_PREFIX``, else ``op3dsg``.
    ``timeout`` (seconds): how long the constructor waits for a daemon that is not up yet.
    :meth:`close` (or leaving a ``with`` block) gives its client port back to the daemon's
    service (16 clients at most)::

        with op3dsg.QueryClient("op3dsg", timeout=5) as client:
            hits = client.query("somewhere to wash my hands", k=3)
    """

    def __init__(self, prefix: Optional[str] = None, timeout: float = 0.0, node_name: Optional[str] = None):
        self.prefix = prefix = _iox.resolve_prefix(prefix)
        self.service = _iox.service_name(prefix, "query")
        deadline = _iox.deadline_after(timeout)
        name = node_name or _iox.default_node_name("query")
        self._node = _iox.retry_while_not_serving(timeout, lambda: _iox.create_node(prefix, self.service, name))
        self._client = _iox.retry_while_not_serving(_iox.left_until(deadline), self._open)

    def _open(self):
        try:
            service = (
                self._node.service_builder(iox2.ServiceName.new(self.service))
                .request_response(QueryRequest, QueryResponse)
                .max_active_requests_per_client(QUERY_MAX_ACTIVE_REQUESTS_PER_CLIENT)
                .open()
            )
        except Exception as e:
            raise _iox.open_error(self.service, e) from e
        try:
            return service.client_builder().create()
        except Exception as e:
            raise _iox.open_error(self.service, e, "create client") from e

    def query(self, text: str, k: int = 5, timeout: float = 5.0) -> QueryResult:
        """Sends ``text`` asking for ``k`` nodes (1..16) and waits up to ``timeout`` seconds for
        the reply. Raises :class:`QueryError` when the daemon answers without hits (busy, encoder
        off, ...), ``TimeoutError`` when it does not answer, ``ValueError`` for a text over 256
        bytes or a bad ``k``."""
        return self._send(text_request(text, k), timeout)

    def query_node(self, node_id: int, timeout: float = 5.0) -> QueryResult:
        """Asks for node ``node_id`` alone (with its approach pose); needs no text encoder.
        Raises :class:`QueryError` (``bad_request``) when the current graph has no such node."""
        return self._send(node_request(node_id), timeout)

    def goal(self, target, timeout: float = 5.0) -> Goal:
        """The approach pose of ``target``: a node id (``int``) or a need in words (``str``,
        answered by the query's top hit). Raises :class:`GoalError` when the node has no pose
        (no free cell within the standoff band, unreachable, no map yet), :class:`QueryError`
        when the daemon cannot answer."""
        if isinstance(target, int):
            result = self.query_node(target, timeout)
        else:
            result = self.query(str(target), 1, timeout)
        return goal_of(self.service, target, result)

    def close(self) -> None:
        """Gives the client port back and lets go of the client's iceoryx2 node, so the slot
        is free for another client; the client is unusable afterwards (its calls raise
        :class:`~op3dsg.errors.Op3dsgError` naming the service). Calling it twice does nothing."""
        client, self._client = getattr(self, "_client", None), None
        if client is not None:
            client.delete()
        self._node = None

    @property
    def closed(self) -> bool:
        return self._client is None

    def __enter__(self) -> "QueryClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"QueryClient(prefix={self.prefix!r}{', closed' if self.closed else ''})"

    def _send(self, request: QueryRequest, timeout: float) -> QueryResult:
        if self._client is None:
            raise Op3dsgError(self.service, "query", "the client is closed (close() or the end of its with block)")
        try:
            pending = self._client.send_copy(request)
        except Exception as e:
            raise _iox.open_error(self.service, e, "send") from e
        deadline = time.monotonic() + max(0.0, timeout)
        try:
            while True:
                try:
                    response = pending.receive()
                except Exception as e:
                    raise _iox.open_error(self.service, e, "receive") from e
                if response is not None:
                    reply = QueryResponse()
                    ctypes.memmove(ctypes.addressof(reply), response.payload_ptr, ctypes.sizeof(QueryResponse))
                    response.delete()
                    return decode_response(self.service, reply)
                if time.monotonic() >= deadline:
                    raise TimeoutError(f"{self.service}: query: no reply within {timeout} s (daemon stopped or stuck?)")
                time.sleep(0.0005)
        finally:
            pending.delete()


# The request and response bytes are the same over iceoryx2 and over Zenoh (``<prefix>/query``,
# docs/remote.md): the functions below serve both transports.


def text_request(text: str, k: int) -> QueryRequest:
    """The request of a text query for ``k`` nodes; ``ValueError`` for a bad ``k`` or a text
    over 256 bytes."""
    if not 1 <= int(k) <= QUERY_MAX_K:
        raise ValueError(f"k: must be within [1, {QUERY_MAX_K}], got {k}")
    request = QueryRequest(schema_version=QUERY_SCHEMA_VERSION, k=int(k), node_id=NO_NODE_REQUEST)
    raw = write_fixed_str(text, QUERY_TEXT_CAPACITY_BYTES)
    ctypes.memmove(request.text, raw, len(raw))
    return request


def node_request(node_id: int) -> QueryRequest:
    """The request for node ``node_id`` alone (its approach pose)."""
    node_id = int(node_id)
    if not 0 <= node_id < NO_NODE_REQUEST:
        raise ValueError(f"node_id: must be within [0, {NO_NODE_REQUEST - 1}], got {node_id}")
    return QueryRequest(schema_version=QUERY_SCHEMA_VERSION, k=1, node_id=node_id)


def decode_response(service: str, reply: QueryResponse) -> QueryResult:
    """The :class:`QueryResult` of a response; :class:`QueryError` when it has another schema or
    a status other than ``ok``."""
    if reply.schema_version != QUERY_SCHEMA_VERSION:
        raise QueryError(service, "schema", f"reply has query schema {reply.schema_version}, this package reads {QUERY_SCHEMA_VERSION}")
    status = _name(QUERY_STATUSES, reply.status)
    if status != "ok":
        raise QueryError(service, status, fixed_str(bytes(reply.message)))
    hits = [
        Hit(
            node_id=h.node_id,
            parent_id=None if h.parent_id == NO_NODE else h.parent_id,
            kind=_name(NODE_KINDS, h.kind),
            label=fixed_str(bytes(h.label)),
            score=float(h.score),
            matched=_name(QUERY_MATCHES, h.matched),
            matched_text=fixed_str(bytes(h.matched_text)),
            approach_status=_name(APPROACH_STATUSES, h.approach_status),
            approach=_approach(h),
        )
        for h in reply.hits[: min(reply.hit_count, QUERY_MAX_K)]
    ]
    return QueryResult(
        hits=hits,
        graph_version=reply.graph_version,
        instance_id=reply.instance_id,
        scored_node_count=reply.scored_node_count,
        encode_us=reply.encode_us,
        score_us=reply.score_us,
    )


def goal_of(service: str, target, result: QueryResult) -> Goal:
    """The :class:`Goal` of the top hit of ``result`` (the answer about ``target``);
    :class:`GoalError` when that node has no approach pose."""
    if not result.hits:
        raise QueryError(service, "no_hit", f"graph version {result.graph_version} has no node for {target!r}")
    hit = result.hits[0]
    if hit.approach is None:
        raise GoalError(service, hit.node_id, hit.label, hit.approach_status)
    return Goal(node_id=hit.node_id, kind=hit.kind, label=hit.label, graph_version=result.graph_version, approach=hit.approach)


def query(text: str, k: int = 5, prefix: Optional[str] = None, timeout: float = 5.0) -> QueryResult:
    """One query with a client made for it and closed after (waiting up to ``timeout`` for the
    daemon too). ``prefix`` ``None``: ``$OP3DSG_PREFIX``, else ``op3dsg``."""
    started = time.monotonic()
    with QueryClient(prefix, timeout=timeout) as client:
        return client.query(text, k, max(0.1, timeout - (time.monotonic() - started)))


def goal(target, prefix: Optional[str] = None, timeout: float = 5.0) -> Goal:
    """The approach pose of ``target`` (node id or need in words) with a client made for it and
    closed after (waiting up to ``timeout`` for the daemon too); see :meth:`QueryClient.goal`."""
    started = time.monotonic()
    with QueryClient(prefix, timeout=timeout) as client:
        return client.goal(target, max(0.1, timeout - (time.monotonic() - started)))
