"""Exceptions of the op3dsg client. Every message names the service (``<prefix>/<service>``) and
what the client was doing, as the Rust ``ClientError`` does (``op3dsg/graph: open: ...``)."""

from __future__ import annotations


class Op3dsgError(Exception):
    """Base of every op3dsg client error.

    ``service`` is the full service name, ``operation`` what the client was doing (``open``,
    ``receive``, ``publish``, ...), ``cause`` the reason (iceoryx2's own, or a contract check)."""

    def __init__(self, service: str, operation: str, cause: str):
        super().__init__(f"{service}: {operation}: {cause}")
        self.service = service
        self.operation = operation
        self.cause = cause

    @property
    def prefix(self) -> str:
        return self.service.rsplit("/", 1)[0]


class NotServingError(Op3dsgError):
    """No op3dsgd serves the prefix (the service does not exist); retrying later may succeed."""

    def __init__(self, service: str, operation: str = "open"):
        from .access import foreign_service_note, resolve_root

        prefix = service.rsplit("/", 1)[0]
        root, source = resolve_root()
        cause = f"no op3dsgd is serving under prefix '{prefix}' in IPC root {root} (service {service} not found)"
        note = foreign_service_note(root, source)
        super().__init__(service, operation, f"{cause}; {note}" if note else cause)


class AccessDeniedError(Op3dsgError, PermissionError):
    """The IPC root belongs to another user (iceoryx2 lets only the daemon's own user attach), is
    open to others, or is no folder; the message names the owner and the fix."""


class InvalidPrefixError(Op3dsgError, ValueError):
    """The prefix cannot form iceoryx2 service names."""


class SchemaVersionError(Op3dsgError):
    """The daemon writes another version of the wire contract than this package reads."""

    def __init__(self, service: str, found: int, expected: int):
        super().__init__(
            service,
            "receive",
            f"invalid sample: schema_version: found {found}, this package reads {expected} "
            "(update the op3dsg Python package or the daemon so both speak one schema)",
        )
        self.found = found
        self.expected = expected


class InvalidGraphError(Op3dsgError):
    """A graph sample breaks the wire contract (a count, the payload size, a kind or origin)."""


class SubscriberSlotsFullError(Op3dsgError):
    """Every subscriber slot of a daemon service is taken (the daemon's ``ipc.max_subscribers``)."""


class SampleReleasedError(Op3dsgError):
    """A graph view was used after its shared-memory sample went back to the daemon (a newer
    :meth:`GraphClient.latest`, or :meth:`GraphView.release`). Keep :meth:`GraphView.copy` instead."""


class InvalidPoseError(Op3dsgError, ValueError):
    """A pose that the daemon would drop (unknown kind, non-finite, non-unit quaternion, frame id too long)."""


class Iceoryx2Error(Op3dsgError):
    """iceoryx2 refused an operation; ``cause`` holds its reason (``ExceedsMaxSupportedPublishers``, ...)."""


class RemoteError(Op3dsgError):
    """A request over Zenoh failed: no connection to the endpoint, an error reply, or a message
    that cannot be read. ``service`` is the Zenoh key (``<key_prefix>/graph``, ...) and
    ``endpoint`` the Zenoh endpoint (``tcp/192.168.1.20:7447``); the message names both."""

    def __init__(self, service: str, operation: str, cause: str, endpoint: str = ""):
        super().__init__(service, operation, f"{cause} (zenoh endpoint {endpoint})" if endpoint else cause)
        self.endpoint = endpoint


class RemoteTimeoutError(RemoteError, TimeoutError):
    """Nothing answered a Zenoh request in time (no daemon there, or another key prefix)."""


class InvalidRemoteMessageError(RemoteError, ValueError):
    """A message on a Zenoh key breaks the format of docs/remote.md (magic, format version, kind,
    a length, a delta that does not fit the graph held)."""


class InvalidEndpointError(RemoteError, ValueError):
    """A Zenoh endpoint or key prefix that cannot be used (``tcp/<host>:<port>`` expected; a key
    prefix without wildcards)."""
