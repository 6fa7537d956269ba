"""Language queries: :func:`query` / :class:`QueryClient` ask the daemon's ``<prefix>/query``
service (iceoryx2 request-response) for the nodes that serve a need in words::

    import op3dsg
    for hit in op3dsg.query("somewhere to wash my hands", k=3):
        print(hit.node_id, hit.kind, hit.label, round(hit.score, 3), hit.matched, hit.matched_text)

The ctypes mirrors of the Rust ``op3dsg_ipc_types::query_types`` (``QueryRequest`` 264 bytes,
``QueryHit`` 160, ``QueryResponse`` 2784) are here; their ``type_name()`` are the Rust
``#[type_name]``. The daemon needs ``text_encoder.enabled = true``; otherwise, or when it is
busy, :class:`QueryError` carries its status and message.
"""

from __future__ import annotations

import ctypes
import time
from dataclasses import dataclass
from typing import List, Optional

import iceoryx2 as iox2

from . import _iox
from .errors import Op3dsgError
from .wire import DEFAULT_PREFIX, LABEL_CAPACITY_BYTES, NO_NODE, NODE_KINDS, _Wire, fixed_str, write_fixed_str

QUERY_SCHEMA_VERSION = 1
QUERY_TEXT_CAPACITY_BYTES = 256
QUERY_MAX_K = 16
QUERY_MATCHED_TEXT_CAPACITY_BYTES = 96
QUERY_MESSAGE_CAPACITY_BYTES = 160
#: Requests one client may have in flight (the service's ``max_active_requests_per_client``).
QUERY_MAX_ACTIVE_REQUESTS_PER_CLIENT = 4
#: ``QueryResponse.status`` values, by wire value.
QUERY_STATUSES = ("ok", "busy", "encoder_off", "no_graph", "bad_request", "encoder_failed", "shutting_down")
#: ``QueryHit.matched`` values, by wire value.
QUERY_MATCHES = ("label", "parent_label", "affordance", "functional")

_u8, _u32, _u64, _f32 = ctypes.c_uint8, ctypes.c_uint32, ctypes.c_uint64, ctypes.c_float


class QueryRequest(_Wire):
    _fields_ = [("schema_version", _u32), ("k", _u32), ("text", _u8 * QUERY_TEXT_CAPACITY_BYTES)]

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


class QueryClient:
    """A client of ``<prefix>/query``. ``timeout`` (seconds): how long the constructor waits for
    a daemon that is not up yet."""

    def __init__(self, prefix: str = DEFAULT_PREFIX, timeout: float = 0.0, node_name: Optional[str] = None):
        self.prefix = prefix
        self.service = _iox.service_name(prefix, "query")
        self._node = _iox.create_node(prefix, self.service, node_name or _iox.default_node_name("query"))
        self._client = _iox.retry_while_not_serving(timeout, self._open)

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
        if not 1 <= int(k) <= QUERY_MAX_K:
            raise ValueError(f"k: must be within [1, {QUERY_MAX_K}], got {k}")
        request = QueryRequest(schema_version=QUERY_SCHEMA_VERSION, k=int(k))
        raw = write_fixed_str(text, QUERY_TEXT_CAPACITY_BYTES)
        ctypes.memmove(request.text, raw, len(raw))
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
                    return self._result(reply)
                if time.monotonic() >= deadline:
                    raise TimeoutError(f"{self.service}: query: no reply within {timeout} s (daemon stopped or stuck?)")
                time.sleep(0.0005)
        finally:
            pending.delete()

    def _result(self, reply: QueryResponse) -> QueryResult:
        if reply.schema_version != QUERY_SCHEMA_VERSION:
            raise QueryError(
                self.service, "schema", f"reply has query schema {reply.schema_version}, this package reads {QUERY_SCHEMA_VERSION}"
            )
        status = _name(QUERY_STATUSES, reply.status)
        if status != "ok":
            raise QueryError(self.service, status, fixed_str(bytes(reply.message)))
        hits = [
            Hit(
                node_id=h.node_id,
                parent_id=None if h.parent_id == NO_NODE else h.parent_id,
                kind=_name(NODE_KINDS, h.kind),
                label=fixed_str(bytes(h.label)),
                score=float(h.score),
                matched=_name(QUERY_MATCHES, h.matched),
                matched_text=fixed_str(bytes(h.matched_text)),
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


def query(text: str, k: int = 5, prefix: str = DEFAULT_PREFIX, timeout: float = 5.0) -> QueryResult:
    """One query with a client made for it (waiting up to ``timeout`` for the daemon too)."""
    started = time.monotonic()
    client = QueryClient(prefix, timeout=timeout)
    return client.query(text, k, max(0.1, timeout - (time.monotonic() - started)))
