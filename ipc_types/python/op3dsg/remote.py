"""The daemon's graph, health, language queries and occupancy map from another computer, over
Zenoh (the daemon's ``[zenoh]`` section; docs/remote.md lays out every byte)::

    import op3dsg
    with op3dsg.RemoteGraphClient("tcp/192.168.1.20:7447", "op3dsg/stretch-1", timeout=30) as remote:
        graph = remote.wait_for_graph(30)              # an op3dsg.Graph, as GraphView.copy() gives
        print(graph.version, graph.labels())

- :class:`RemoteGraphClient` connects as a Zenoh *client* to one endpoint (multicast scouting
  off), takes the full graph from the queryable ``<key_prefix>/graph``, then follows the deltas
  of ``<key_prefix>/graph/delta`` on a thread of its own: a delta that does not start at the
  version held (versions lost on the way) or a new daemon instance (a restart) makes it take a
  full graph again (it asks the queryable; the periodic full graph comes too). ``latest()``
  returns the :class:`~op3dsg.graph.Graph` a planner gets over iceoryx2 (nodes sorted by id, as
  there; edges in another order).
- :class:`RemoteQueryClient` / :func:`remote_query` / :func:`remote_goal`: ``<key_prefix>/query``
  with the request and response bytes of the iceoryx2 query service (:mod:`op3dsg.query`).
- :func:`remote_health`: the newest health record from the queryable ``<key_prefix>/health``
  (the JSON object ``op3dsg health --json`` prints).
- :class:`RemoteOccupancyClient` / :func:`remote_occupancy`: the occupancy map of
  ``<key_prefix>/occupancy`` as an :class:`~op3dsg.occupancy.OccupancyMap`.

:class:`RemoteFollower` is the graph bookkeeping alone (full graphs, deltas, gaps, restarts),
for messages however they came. This module needs the Zenoh Python binding, PyPI
``eclipse-zenoh`` (``pip install "op3dsg[zenoh]"``); ``import op3dsg`` works without it.
"""

from __future__ import annotations

import atexit
import ctypes
import json
import logging
import struct
import threading
import time
import weakref
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

import numpy as np

from .errors import (
    InvalidEndpointError,
    InvalidRemoteMessageError,
    Op3dsgError,
    RemoteError,
    RemoteTimeoutError,
    SchemaVersionError,
)
from .graph import Graph, _check_header, _check_records
from .occupancy import OCCUPANCY_HEADER_BYTES, OccupancyMap, occupancy_map
from .query import (
    Goal,
    QueryRequest,
    QueryResponse,
    QueryResult,
    decode_response,
    goal_of,
    node_request,
    text_request,
)
from .wire import EDGE_BYTES, EDGE_DTYPE, NODE_BYTES, NODE_DTYPE, GraphHeader

_log = logging.getLogger("op3dsg.remote")

#: First four bytes of every message.
MAGIC = b"O3DZ"
#: The envelope's format version this package reads.
FORMAT_VERSION = 1
#: Bytes of the envelope, of a graph header in a message, of a delta's counts.
ENVELOPE_BYTES = 40
HEADER_BYTES = 112
DELTA_COUNTS_BYTES = 16
#: The envelope's ``kind`` values.
KIND_GRAPH, KIND_DELTA, KIND_HEALTH, KIND_OCCUPANCY = 1, 2, 3, 4
MESSAGE_KINDS = {KIND_GRAPH: "graph", KIND_DELTA: "delta", KIND_HEALTH: "health", KIND_OCCUPANCY: "occupancy"}
#: How long the follower waits for the graph queryable's reply, seconds.
FULL_QUERY_TIMEOUT_S = 5.0
#: How often the follower asks the queryable again while it holds no graph, seconds.
FULL_RETRY_S = 0.5
#: Messages waiting for the follower thread; when it falls further behind the oldest give way,
#: and the next delta shows the gap.
RING_CAPACITY = 256
#: How long the constructor of :class:`RemoteGraphClient` waits for the first full graph (seconds):
#: the query goes out as soon as the session is up and is asked again every ``FULL_RETRY_S`` while
#: the route to the daemon's queryable is still being made. Only a daemon that has no graph yet
#: (or does not answer) makes it wait this long; ``latest()`` is then ``None`` until one comes.
ATTACH_WAIT_S = 3.0
#: How often a client started before the daemon retries connecting, seconds.
CONNECT_RETRY_S = 0.1

_ENVELOPE = struct.Struct("<4sHHQQQQ")
_COUNTS = struct.Struct("<4I")
_WILDCARDS = set("*$?#")


def _zenoh():
    """The ``zenoh`` module, or an ``ImportError`` that says what to install."""
    try:
        import zenoh
    except ImportError as e:
        raise ImportError(
            "op3dsg.remote needs the Zenoh Python binding (PyPI eclipse-zenoh): "
            'pip install "op3dsg[zenoh]" (or pip install eclipse-zenoh)'
        ) from e
    return zenoh


# -- messages -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Envelope:
    """The 40 bytes in front of every message."""

    kind: int
    instance_id: int
    version: int
    base_version: int
    publish_time_ns: int

    @property
    def kind_name(self) -> str:
        return MESSAGE_KINDS.get(self.kind, f"unknown({self.kind})")


def read_envelope(key: str, message: bytes) -> Envelope:
    """The envelope of ``message`` (received on ``key``); :class:`InvalidRemoteMessageError`
    for a short message, another magic or format version, or an unknown kind."""
    if len(message) < ENVELOPE_BYTES:
        raise _bad(key, f"message of {len(message)} bytes, shorter than the {ENVELOPE_BYTES}-byte envelope")
    magic, format_version, kind, instance_id, version, base_version, publish_time_ns = _ENVELOPE.unpack_from(message, 0)
    if magic != MAGIC or format_version != FORMAT_VERSION:
        raise _bad(key, f"not an op3dsg message of format {FORMAT_VERSION} (magic {magic!r}, format {format_version})")
    if kind not in MESSAGE_KINDS:
        raise _bad(key, f"unknown message kind {kind} (1 graph, 2 delta, 3 health, 4 occupancy)")
    return Envelope(kind, instance_id, version, base_version, publish_time_ns)


def _bad(key: str, what: str) -> InvalidRemoteMessageError:
    return InvalidRemoteMessageError(key, "receive", f"invalid message: {what}")


def _header_of(key: str, envelope: Envelope, message: bytes) -> GraphHeader:
    if len(message) < ENVELOPE_BYTES + HEADER_BYTES:
        raise _bad(key, f"{envelope.kind_name} message of {len(message)} bytes, shorter than envelope and graph header ({ENVELOPE_BYTES + HEADER_BYTES})")
    header = GraphHeader.from_buffer_copy(message, ENVELOPE_BYTES)
    if (header.instance_id, header.graph_version) != (envelope.instance_id, envelope.version):
        raise _bad(
            key,
            f"envelope (instance {envelope.instance_id:#x}, version {envelope.version}) and graph header "
            f"(instance {header.instance_id:#x}, version {header.graph_version}) disagree",
        )
    return header


def _records(message: bytes, at: int, count: int, size: int) -> Tuple[List[bytes], int]:
    end = at + count * size
    return [message[i : i + size] for i in range(at, end, size)], end


def _check_new_records(key: str, nodes: List[bytes], edges: List[bytes]) -> None:
    """Node kinds, edge kinds and origins of records about to be taken (as a full graph's)."""
    node_array = np.frombuffer(b"".join(nodes), NODE_DTYPE) if nodes else np.empty(0, NODE_DTYPE)
    edge_array = np.frombuffer(b"".join(edges), EDGE_DTYPE) if edges else np.empty(0, EDGE_DTYPE)
    try:
        _check_records(key, node_array, edge_array)
    except Op3dsgError as e:
        raise _bad(key, e.cause) from None


#: What :meth:`RemoteFollower.apply` did with a message.
APPLIED_FULL, APPLIED_DELTA, APPLIED_STALE, APPLIED_NEED_FULL = "full", "delta", "stale", "need_full"


class RemoteFollower:
    """A graph kept up to date from the daemon's full graphs and deltas, whatever carried them
    (docs/remote.md, "Following the graph"): node records by id, edge records as a multiset, the
    header of the version held.

    :meth:`apply` takes one message; after a gap or a new daemon instance it holds nothing
    (:meth:`held` is ``None``) until a full graph comes. ``counters`` counts ``fulls``,
    ``deltas_applied``, ``stale`` (older than what is held), ``gaps`` (a delta whose base is not
    the version held), ``restarts`` (a full graph of another instance than the one before)."""

    def __init__(self, key: str = "graph"):
        self.key = key
        self._header: Optional[GraphHeader] = None
        self._instance = 0
        self._nodes: Dict[int, bytes] = {}
        self._edges: Dict[bytes, int] = {}
        #: Daemon instances whose graphs were taken, in order.
        self.instances: List[int] = []
        self.counters = {"fulls": 0, "deltas_applied": 0, "stale": 0, "gaps": 0, "restarts": 0}

    def held(self) -> Optional[Tuple[int, int]]:
        """``(instance_id, version)`` of the graph held, ``None`` before the first full graph and
        after a gap or a restart until the next."""
        return None if self._header is None else (self._instance, int(self._header.graph_version))

    def apply(self, message: bytes) -> str:
        """Applies one message: ``"full"``, ``"delta"``, ``"stale"`` (ignored: not newer than the
        graph held) or ``"need_full"`` (a gap or a restart: the graph held was dropped). Raises
        :class:`~op3dsg.errors.InvalidRemoteMessageError` (or a ``SchemaVersionError``) for a
        message it cannot read; a delta that does not fit the graph held drops it too."""
        message = bytes(message)
        envelope = read_envelope(self.key, message)
        if envelope.kind not in (KIND_GRAPH, KIND_DELTA):
            raise _bad(self.key, f"a {envelope.kind_name} message, not a graph or a delta")
        header = _header_of(self.key, envelope, message)
        held = self.held()
        same_instance = held is not None and held[0] == envelope.instance_id
        if same_instance and envelope.version <= held[1]:
            self.counters["stale"] += 1
            return APPLIED_STALE
        if envelope.kind == KIND_GRAPH:
            self._full(envelope, header, message)
            return APPLIED_FULL
        if not same_instance or envelope.base_version != held[1]:
            if same_instance:
                self.counters["gaps"] += 1
            self._drop()
            return APPLIED_NEED_FULL
        self._delta(envelope, header, message)
        self.counters["deltas_applied"] += 1
        return APPLIED_DELTA

    def _full(self, envelope: Envelope, header: GraphHeader, message: bytes) -> None:
        body = len(message) - ENVELOPE_BYTES - HEADER_BYTES
        try:
            _check_header(self.key, header, body)
        except SchemaVersionError:
            raise
        except Op3dsgError as e:
            raise _bad(self.key, e.cause.replace("invalid sample: ", "")) from None
        at = ENVELOPE_BYTES + HEADER_BYTES
        nodes, at = _records(message, at, int(header.node_count), NODE_BYTES)
        edges, _ = _records(message, at, int(header.edge_count), EDGE_BYTES)
        _check_new_records(self.key, nodes, edges)
        if self.instances and self.instances[-1] != envelope.instance_id:
            self.counters["restarts"] += 1
        if not self.instances or self.instances[-1] != envelope.instance_id:
            self.instances.append(envelope.instance_id)
        self._nodes = {struct.unpack_from("<I", r)[0]: r for r in nodes}
        self._edges = {}
        for r in edges:
            self._edges[r] = self._edges.get(r, 0) + 1
        self._header = header
        self._instance = envelope.instance_id
        self.counters["fulls"] += 1

    def _delta(self, envelope: Envelope, header: GraphHeader, message: bytes) -> None:
        key = self.key
        if header.schema_version != self._header.schema_version:
            self._drop()
            raise _bad(key, f"delta to version {envelope.version} has schema {header.schema_version}, the graph held {self._header.schema_version}")
        at = ENVELOPE_BYTES + HEADER_BYTES
        if len(message) < at + DELTA_COUNTS_BYTES:
            raise _bad(key, f"delta of {len(message)} bytes, shorter than envelope, header and counts ({at + DELTA_COUNTS_BYTES})")
        upserted_n, removed_n, added_n, gone_n = _COUNTS.unpack_from(message, at)
        at += DELTA_COUNTS_BYTES
        described = at + upserted_n * NODE_BYTES + (added_n + gone_n) * EDGE_BYTES + removed_n * 4
        if len(message) != described:
            raise _bad(key, f"delta of {len(message)} bytes, its counts describe {described}")
        upserted, at = _records(message, at, upserted_n, NODE_BYTES)
        added, at = _records(message, at, added_n, EDGE_BYTES)
        gone, at = _records(message, at, gone_n, EDGE_BYTES)
        removed = struct.unpack_from(f"<{removed_n}I", message, at)
        _check_new_records(key, upserted, added)
        # Applied to copies, so a delta that does not fit leaves nothing half done.
        nodes, edges = dict(self._nodes), dict(self._edges)
        for r in upserted:
            nodes[struct.unpack_from("<I", r)[0]] = r
        for r in added:
            edges[r] = edges.get(r, 0) + 1
        for r in gone:
            left = edges.get(r, 0) - 1
            if left < 0:
                self._drop()
                raise _bad(key, f"delta to version {envelope.version} removes an edge the graph of version {envelope.base_version} lacks")
            if left:
                edges[r] = left
            else:
                del edges[r]
        for node_id in removed:
            if nodes.pop(node_id, None) is None:
                self._drop()
                raise _bad(key, f"delta to version {envelope.version} removes node {node_id}, absent from version {envelope.base_version}")
        edge_count = sum(edges.values())
        if (len(nodes), edge_count) != (header.node_count, header.edge_count):
            self._drop()
            raise _bad(
                key,
                f"after the delta to version {envelope.version}: {len(nodes)} nodes and {edge_count} edges, "
                f"its header says {header.node_count} and {header.edge_count}",
            )
        self._nodes, self._edges, self._header = nodes, edges, header

    def _drop(self) -> None:
        self._header = None
        self._nodes, self._edges = {}, {}

    def graph(self, restarted: bool = False) -> Optional[Graph]:
        """The graph held as an owned :class:`~op3dsg.graph.Graph` (nodes sorted by id, edges in
        the order they came: a full graph's, then those deltas added), ``None`` when none is held."""
        if self._header is None:
            return None
        header = GraphHeader.from_buffer_copy(self._header)
        node_bytes = b"".join(self._nodes[i] for i in sorted(self._nodes))
        edge_bytes = b"".join(r * n for r, n in self._edges.items())
        nodes = np.frombuffer(node_bytes, NODE_DTYPE).copy()
        edges = np.frombuffer(edge_bytes, EDGE_DTYPE).copy()
        return Graph(header, nodes, edges, restarted)


# -- sessions -------------------------------------------------------------------------------


def check_key_prefix(key_prefix: str, key: str) -> None:
    """The daemon's ``zenoh.key_prefix`` rules: a key expression without wildcards, no empty
    chunk, no leading or trailing ``/``. Raises :class:`~op3dsg.errors.InvalidEndpointError`."""

    def fail(why: str):
        raise InvalidEndpointError(key, "connect", f"key_prefix {key_prefix!r}: {why}")

    if not isinstance(key_prefix, str) or not key_prefix:
        fail("must not be empty (the daemon's zenoh.key_prefix, e.g. op3dsg/stretch-1)")
    wild = sorted(_WILDCARDS.intersection(key_prefix))
    if wild:
        fail(f"has the wildcard characters {''.join(wild)!r}; the daemon's zenoh.key_prefix is a plain key")
    if key_prefix.startswith("/") or key_prefix.endswith("/") or "//" in key_prefix:
        fail("must not start or end with '/' nor contain '//'")


def open_session(endpoint: str, key: str, timeout: float):
    """A Zenoh session in client mode to ``endpoint`` alone, multicast scouting off, retrying
    for up to ``timeout`` seconds while nothing listens there."""
    zenoh = _zenoh()
    if not isinstance(endpoint, str) or "/" not in endpoint:
        raise InvalidEndpointError(
            key, "connect", f"{endpoint!r} is not a Zenoh endpoint (<protocol>/<address>, e.g. tcp/192.168.1.20:7447)"
        )
    config = zenoh.Config()
    try:
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints", json.dumps([endpoint]))
        config.insert_json5("scouting/multicast/enabled", "false")
    except zenoh.ZError as e:
        raise InvalidEndpointError(key, "connect", f"{endpoint!r} is not a Zenoh endpoint: {e}") from None
    deadline = time.monotonic() + max(0.0, timeout)
    while True:
        try:
            return zenoh.open(config)
        except zenoh.ZError as e:
            left = deadline - time.monotonic()
            if left <= 0:
                raise RemoteError(
                    key,
                    "connect",
                    f"nothing answered at {endpoint} within {timeout:.1f} s (is op3dsgd running there with "
                    f"zenoh.enabled = true and {endpoint} in zenoh.listen, or a Zenoh router?): {str(e).split(' at /')[0]}",
                ) from None
            time.sleep(min(CONNECT_RETRY_S, left))


#: Clients not closed yet: closed at interpreter exit, before Python stops its threads (a
#: follower thread that Python stops while it waits in Zenoh aborts the process).
_open_clients: "weakref.WeakSet[_RemoteSession]" = weakref.WeakSet()


@atexit.register
def _close_open_clients() -> None:
    for client in list(_open_clients):
        client.close()


class _RemoteSession:
    """A client session to one daemon's endpoint under its key prefix."""

    def __init__(self, endpoint: str, key_prefix: str, timeout: float, key_suffix: str):
        self.endpoint = endpoint
        self.key_prefix = key_prefix
        self.key = f"{key_prefix}/{key_suffix}"
        check_key_prefix(key_prefix, self.key)
        self._session = open_session(endpoint, self.key, timeout)
        _open_clients.add(self)

    def _first_reply(self, key: str, payload: Optional[bytes], timeout: float) -> bytes:
        """The payload of the first reply to a query on ``key``, asked with congestion control
        drop (so is the reply), waiting at most ``timeout`` seconds."""
        zenoh = _zenoh()
        try:
            replies = self._session.get(
                key, payload=payload, timeout=max(0.001, float(timeout)), congestion_control=zenoh.CongestionControl.DROP
            )
            for reply in replies:
                if reply.ok is not None:
                    return reply.ok.payload.to_bytes()
                raise RemoteError(key, "query", f"error reply: {reply.err.payload.to_string()}", self.endpoint)
        except zenoh.ZError as e:
            raise RemoteError(key, "query", str(e).split(" at /")[0], self.endpoint) from None
        raise RemoteTimeoutError(
            key,
            "query",
            f"no daemon answered within {timeout:.1f} s (is op3dsgd running there with zenoh.enabled = true, "
            f"and is its zenoh.key_prefix {self.key_prefix!r}?)",
            self.endpoint,
        )

    def close(self) -> None:
        _open_clients.discard(self)
        session, self._session = getattr(self, "_session", None), None
        if session is not None:
            try:
                session.close()
            except Exception:  # closing twice, or at interpreter exit
                pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# -- the graph ------------------------------------------------------------------------------


class RemoteGraphClient(_RemoteSession):
    """The daemon's graph from another computer: :class:`GraphClient
    <op3dsg.graph.GraphClient>` over Zenoh.

    ::

        with op3dsg.RemoteGraphClient("tcp/192.168.1.20:7447", "op3dsg/stretch-1", timeout=30) as remote:
            while True:
                remote.wait_for_update(1.0)
                graph = remote.latest()                 # op3dsg.Graph or None
                if graph is not None:
                    print(graph.version, graph.labels())

    ``endpoint``: the daemon's ``zenoh.listen`` endpoint (or a Zenoh router's); ``key_prefix``:
    its ``zenoh.key_prefix``; ``timeout`` (seconds): how long the constructor waits for something
    to listen at the endpoint (0: fail at once with :class:`~op3dsg.errors.RemoteError`). Once
    connected, it waits for the daemon's current graph (up to ``ATTACH_WAIT_S``, 3 s), so the first
    :meth:`latest` returns it.

    A thread of the client follows the messages (:class:`RemoteFollower`). A message it cannot
    read is counted (``counters()["errors"]``), kept as :attr:`last_error` and logged on the
    ``op3dsg.remote`` logger; the thread goes on, taking a full graph when a delta did not fit.
    """

    def __init__(self, endpoint: str, key_prefix: str, timeout: float = 0.0):
        super().__init__(endpoint, key_prefix, timeout, "graph")
        #: The key of the full graph (as ``GraphClient.service``; errors name it).
        self.service = self.key
        self._follower = RemoteFollower(self.key)
        self._changed = threading.Condition()
        self._stop = threading.Event()
        self._counters = {"queries": 0, "errors": 0}
        self.last_error: Optional[Exception] = None
        self._graph: Optional[Graph] = None
        self._next_fetch = 0.0
        self._last_instance = 0
        self._if_newer_instance = 0
        self._keys = (self.key, f"{self.key}/delta")
        zenoh = _zenoh()
        try:
            # One subscriber for full graphs and deltas, so they arrive in the order they were
            # sent, into a ring channel: no Python callback runs on Zenoh's threads (one there
            # keeps the interpreter from exiting while a session is open), and when the follower
            # falls behind the oldest messages give way, which the next delta shows as a gap.
            self._subscriber = self._session.declare_subscriber(f"{self.key}/**", zenoh.handlers.RingChannel(RING_CAPACITY))
        except zenoh.ZError as e:
            self.close()
            raise RemoteError(self.key, "subscribe", str(e).split(" at /")[0], endpoint) from None
        self._thread = threading.Thread(target=self._run, name=f"op3dsg-remote {self.key}", daemon=True)
        self._thread.start()
        # The first read after connecting returns the daemon's graph: wait for the first full one.
        with self._changed:
            self._changed.wait_for(lambda: self._follower.held() is not None, timeout=ATTACH_WAIT_S)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                if self._follower.held() is None:
                    # No graph yet: ask the queryable every FULL_RETRY_S (a daemon that publishes
                    # no new version sends nothing to wait for), looking for messages between.
                    if time.monotonic() >= self._next_fetch:
                        self._next_fetch = time.monotonic() + FULL_RETRY_S
                        self._fetch_full()
                    sample = self._subscriber.try_recv()
                    if sample is None:
                        time.sleep(0.02)
                        continue
                else:
                    try:
                        sample = self._subscriber.recv()  # ends with an error when the session closes
                    except Exception:
                        if self._stop.is_set():
                            return
                        raise
                if str(sample.key_expr) in self._keys:
                    self._apply(sample.payload.to_bytes())
            except Exception as e:  # the thread must outlive anything a message or Zenoh does
                if self._stop.is_set():
                    return
                self._error(e)
                time.sleep(0.05)

    def _fetch_full(self) -> None:
        zenoh = _zenoh()
        self._counters["queries"] += 1
        replies = self._session.get(self.key, timeout=FULL_QUERY_TIMEOUT_S, congestion_control=zenoh.CongestionControl.DROP)
        for reply in replies:
            if self._stop.is_set():
                return
            if reply.ok is not None:
                self._apply(reply.ok.payload.to_bytes())
            else:
                self._error(RemoteError(self.key, "query", f"error reply: {reply.err.payload.to_string()}", self.endpoint))

    def _apply(self, message: bytes) -> None:
        with self._changed:
            try:
                applied = self._follower.apply(message)
            except Op3dsgError as e:
                self._error(e)
                return
            if applied in (APPLIED_FULL, APPLIED_DELTA):
                self._changed.notify_all()

    def _error(self, error: Exception) -> None:
        self._counters["errors"] += 1
        repeated = self.last_error is not None and str(self.last_error) == str(error)
        self.last_error = error
        if not repeated:
            _log.warning("zenoh endpoint %s: %s", self.endpoint, error)

    # -- reading ----------------------------------------------------------------------------
    def latest(self) -> Optional[Graph]:
        """The newest graph held, as an owned :class:`~op3dsg.graph.Graph` (``None`` before the
        first). The same object again until a newer version is held; after a gap the graph
        returned before stays the answer until the next full graph."""
        with self._changed:
            held = self._follower.held()
            current = self._graph
            if held is None or (current is not None and (current.instance_id, current.version) == held):
                return current
            graph = self._follower.graph()
        graph.restarted = self._last_instance not in (0, graph.instance_id)
        self._last_instance = graph.instance_id
        self._graph = graph
        return graph

    def latest_if_newer(self, last_seen_version: int) -> Optional[Graph]:
        """Like :meth:`latest`, but ``None`` also when the newest graph has version
        ``last_seen_version`` and comes from the same daemon instance as the graph this call
        returned last (pass 0 before the first graph). A restarted daemon's graphs count as new
        whatever their version."""
        graph = self.latest()
        if graph is None:
            return None
        if graph.instance_id == self._if_newer_instance and graph.version == last_seen_version:
            return None
        self._if_newer_instance = graph.instance_id
        return graph

    def wait_for_update(self, timeout: float) -> bool:
        """Waits up to ``timeout`` seconds until the client holds a graph newer than the one
        :meth:`latest` returned last; ``True`` when it does."""

        def newer() -> bool:
            held = self._follower.held()
            current = self._graph
            return held is not None and (current is None or (current.instance_id, current.version) != held)

        with self._changed:
            return self._changed.wait_for(newer, max(0.0, timeout))

    def wait_for_graph(self, timeout: float, min_nodes: int = 0) -> Graph:
        """The newest graph once one with at least ``min_nodes`` nodes is held, waiting up to
        ``timeout`` seconds; :class:`~op3dsg.errors.RemoteTimeoutError` naming the key and
        endpoint otherwise."""
        deadline = time.monotonic() + timeout
        while True:
            graph = self.latest()
            if graph is not None and graph.node_count >= min_nodes:
                return graph
            left = deadline - time.monotonic()
            if left <= 0:
                wanted = f"no graph with at least {min_nodes} nodes" if min_nodes else "no graph"
                cause = f"{wanted} within {timeout:.1f} s"
                if self.last_error is not None:
                    cause += f" (last error: {self.last_error})"
                elif self._counters["queries"] and not self._follower.counters["fulls"]:
                    cause += f" (is the daemon's zenoh.key_prefix {self.key_prefix!r}, and has it published a graph?)"
                raise RemoteTimeoutError(self.key, "receive", cause, self.endpoint)
            self.wait_for_update(min(left, 0.2))

    @property
    def restarted(self) -> bool:
        """``restarted`` of the graph :meth:`latest` returned last: it came from another daemon
        instance than the graph returned before it (the daemon restarted; versions started again)."""
        return self._graph is not None and self._graph.restarted

    def counters(self) -> Dict[str, int]:
        """``fulls`` (full graphs taken), ``deltas_applied``, ``stale`` (messages older than the
        graph held), ``gaps`` (deltas that showed lost versions), ``restarts`` (new daemon
        instances), ``queries`` (full graphs asked for), ``errors`` (messages that could not be
        read, failed queries)."""
        with self._changed:
            return dict(self._follower.counters, **self._counters)

    @property
    def instances(self) -> List[int]:
        """Daemon instances whose graphs were taken, in order (more than one: restarts)."""
        with self._changed:
            return list(self._follower.instances)

    def close(self) -> None:
        """Stops the follower thread and closes the session; the client is unusable afterwards."""
        stop = getattr(self, "_stop", None)
        if stop is not None:
            stop.set()
        super().close()  # undeclares the subscriber, which ends the follower's wait
        thread = getattr(self, "_thread", None)
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=FULL_QUERY_TIMEOUT_S + 1)

    def __enter__(self) -> "RemoteGraphClient":
        return self

    def __repr__(self) -> str:
        return f"RemoteGraphClient(endpoint={self.endpoint!r}, key_prefix={self.key_prefix!r})"


# -- requests -------------------------------------------------------------------------------


class RemoteQueryClient(_RemoteSession):
    """:class:`~op3dsg.query.QueryClient` over Zenoh: ``<key_prefix>/query`` with the same
    request and response bytes. ``timeout`` (seconds): how long the constructor waits for
    something to listen at the endpoint."""

    def __init__(self, endpoint: str, key_prefix: str, timeout: float = 0.0):
        super().__init__(endpoint, key_prefix, timeout, "query")
        self.service = self.key

    def query(self, text: str, k: int = 5, timeout: float = 5.0) -> QueryResult:
        """The nodes that serve a need in words (see :meth:`op3dsg.QueryClient.query`)."""
        return self._send(text_request(text, k), timeout)

    def query_node(self, node_id: int, timeout: float = 5.0) -> QueryResult:
        """Node ``node_id`` alone, with its approach pose; needs no text encoder."""
        return self._send(node_request(node_id), timeout)

    def goal(self, target, timeout: float = 5.0) -> Goal:
        """Where to stand to reach ``target``, a node id or a need in words (see
        :meth:`op3dsg.QueryClient.goal`)."""
        if isinstance(target, int):
            result = self.query_node(target, timeout)
        else:
            result = self.query(str(target), 1, timeout)
        return goal_of(self.key, target, result)

    def _send(self, request: QueryRequest, timeout: float) -> QueryResult:
        reply = self._first_reply(self.key, bytes(request), timeout)
        if len(reply) != ctypes.sizeof(QueryResponse):
            raise _bad(self.key, f"a reply of {len(reply)} bytes is no query response ({ctypes.sizeof(QueryResponse)} bytes)")
        return decode_response(self.key, QueryResponse.from_buffer_copy(reply))

    def __enter__(self) -> "RemoteQueryClient":
        return self

    def __repr__(self) -> str:
        return f"RemoteQueryClient(endpoint={self.endpoint!r}, key_prefix={self.key_prefix!r})"


def remote_query(endpoint: str, key_prefix: str, text: str, k: int = 5, timeout: float = 5.0) -> QueryResult:
    """One language query over Zenoh with a session made for it (``timeout`` covers connecting
    and the reply)."""
    started = time.monotonic()
    with RemoteQueryClient(endpoint, key_prefix, timeout) as client:
        return client.query(text, k, max(0.1, timeout - (time.monotonic() - started)))


def remote_goal(endpoint: str, key_prefix: str, target, timeout: float = 5.0) -> Goal:
    """The approach pose of ``target`` (node id or need in words) over Zenoh."""
    started = time.monotonic()
    with RemoteQueryClient(endpoint, key_prefix, timeout) as client:
        return client.goal(target, max(0.1, timeout - (time.monotonic() - started)))


@dataclass(frozen=True)
class RemoteHealth:
    """The daemon's health over Zenoh: ``record`` is the JSON object ``op3dsg health --json``
    prints (stages, queues, source, map, ...); the envelope says which daemon instance sent it,
    its newest graph version and when."""

    instance_id: int
    graph_version: int
    publish_time_ns: int
    record: dict

    def stage(self, name: str) -> dict:
        """The stage called ``name`` (``capture``, ``fusion``, ``zenoh``, ...); ``KeyError`` otherwise."""
        for stage in self.record.get("stages", []):
            if stage.get("name") == name:
                return stage
        raise KeyError(f"no stage {name!r} in the health record")

    def to_dict(self) -> dict:
        return self.record


def decode_health(key: str, message: bytes) -> RemoteHealth:
    """A health message (envelope of kind 3, then the JSON record)."""
    envelope = read_envelope(key, message)
    if envelope.kind != KIND_HEALTH:
        raise _bad(key, f"a {envelope.kind_name} message, not health")
    try:
        record = json.loads(message[ENVELOPE_BYTES:].decode("utf-8"))
    except ValueError as e:  # UnicodeDecodeError and JSONDecodeError alike
        raise _bad(key, f"health record is not UTF-8 JSON: {e}") from None
    return RemoteHealth(envelope.instance_id, envelope.version, envelope.publish_time_ns, record)


def remote_health(endpoint: str, key_prefix: str, timeout: float = 5.0) -> RemoteHealth:
    """The daemon's newest health record from the queryable ``<key_prefix>/health``."""
    started = time.monotonic()
    with _RemoteSession(endpoint, key_prefix, timeout, "health") as session:
        message = session._first_reply(session.key, None, max(0.1, timeout - (time.monotonic() - started)))
        return decode_health(session.key, message)


# -- occupancy ------------------------------------------------------------------------------


def decode_occupancy(key: str, message: bytes) -> OccupancyMap:
    """An occupancy message (envelope of kind 4, the 112-byte occupancy header, then
    ``width_cells * height_cells`` int8 cells, row-major) as an
    :class:`~op3dsg.occupancy.OccupancyMap` whose ``version`` is the envelope's (the count of
    maps the daemon published); the cells are a read-only view of ``message``."""
    envelope = read_envelope(key, message)
    if envelope.kind != KIND_OCCUPANCY:
        raise _bad(key, f"a {envelope.kind_name} message, not an occupancy map")
    at = ENVELOPE_BYTES + OCCUPANCY_HEADER_BYTES
    if len(message) < at:
        raise _bad(key, f"occupancy message of {len(message)} bytes, shorter than envelope and header ({at})")
    try:
        grid = occupancy_map(key, message[ENVELOPE_BYTES:at], memoryview(message)[at:], envelope.version)
    except SchemaVersionError:
        raise
    except Op3dsgError as e:
        raise _bad(key, e.cause.replace("invalid map: ", "")) from None
    if grid.header.instance_id != envelope.instance_id:
        raise _bad(key, f"envelope instance {envelope.instance_id:#x}, occupancy header instance {grid.header.instance_id:#x}")
    return grid


class RemoteOccupancyClient(_RemoteSession):
    """:class:`~op3dsg.occupancy.OccupancyClient` over Zenoh: the newest map published on
    ``<key_prefix>/occupancy``, or asked of its queryable while none came yet."""

    def __init__(self, endpoint: str, key_prefix: str, timeout: float = 0.0):
        super().__init__(endpoint, key_prefix, timeout, "occupancy")
        self.service = self.key
        self._latest: Optional[OccupancyMap] = None
        self._last_fetch = -FULL_RETRY_S
        zenoh = _zenoh()
        try:
            # The newest map only (a ring of one), no Python callback on Zenoh's threads.
            self._subscriber = self._session.declare_subscriber(self.key, zenoh.handlers.RingChannel(1))
        except zenoh.ZError as e:
            self.close()
            raise RemoteError(self.key, "subscribe", str(e).split(" at /")[0], endpoint) from None

    def latest(self) -> Optional[OccupancyMap]:
        """The newest map received (``None`` while none came); asks the queryable while none
        did (at most every half second). A message that breaks the format raises
        :class:`~op3dsg.errors.InvalidRemoteMessageError`."""
        message = None
        while True:
            sample = self._subscriber.try_recv()
            if sample is None:
                break
            message = sample.payload.to_bytes()
        if message is None and self._latest is None and time.monotonic() - self._last_fetch >= FULL_RETRY_S:
            self._last_fetch = time.monotonic()
            try:
                message = self._first_reply(self.key, None, 2.0)
            except RemoteTimeoutError:
                message = None
        if message is not None:
            grid = decode_occupancy(self.key, message)
            current = self._latest
            newer = current is None or current.header.instance_id != grid.header.instance_id or grid.version > current.version
            if newer:
                self._latest = grid
        return self._latest

    def wait(self, timeout: float, newer_than_version: int = 0) -> OccupancyMap:
        """The newest map with a ``version`` above ``newer_than_version`` (or of another daemon
        instance than the map held), waiting up to ``timeout`` seconds;
        :class:`~op3dsg.errors.RemoteTimeoutError` otherwise."""
        deadline = time.monotonic() + timeout
        first = self._latest
        while True:
            grid = self.latest()
            if grid is not None and (
                grid.version > newer_than_version or (first is not None and grid.header.instance_id != first.header.instance_id)
            ):
                return grid
            if time.monotonic() >= deadline:
                raise RemoteTimeoutError(
                    self.key,
                    "receive",
                    f"no occupancy map within {timeout:.1f} s (is the daemon's occupancy.enabled true, and its zenoh.key_prefix {self.key_prefix!r}?)",
                    self.endpoint,
                )
            time.sleep(0.02)

    def __enter__(self) -> "RemoteOccupancyClient":
        return self

    def __repr__(self) -> str:
        return f"RemoteOccupancyClient(endpoint={self.endpoint!r}, key_prefix={self.key_prefix!r})"


def remote_occupancy(endpoint: str, key_prefix: str, timeout: float = 5.0) -> OccupancyMap:
    """The daemon's newest occupancy map from the queryable ``<key_prefix>/occupancy``."""
    started = time.monotonic()
    with _RemoteSession(endpoint, key_prefix, timeout, "occupancy") as session:
        message = session._first_reply(session.key, None, max(0.1, timeout - (time.monotonic() - started)))
        return decode_occupancy(session.key, message)


__all__ = [
    "Envelope",
    "RemoteFollower",
    "RemoteGraphClient",
    "RemoteHealth",
    "RemoteOccupancyClient",
    "RemoteQueryClient",
    "check_key_prefix",
    "decode_health",
    "decode_occupancy",
    "open_session",
    "read_envelope",
    "remote_goal",
    "remote_health",
    "remote_occupancy",
    "remote_query",
]
