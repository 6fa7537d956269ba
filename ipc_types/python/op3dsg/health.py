"""Reading the daemon's health: :class:`HealthClient` on ``<prefix>/health`` and the one-shot
:func:`health`. Neither opens a graph subscriber, so a monitor works while every graph
subscriber slot is taken."""

from __future__ import annotations

import ctypes
import time
from typing import Optional

import iceoryx2 as iox2

from . import _iox
from .errors import SchemaVersionError
from .wire import HISTORY_SIZE, SCHEMA_VERSION, Health


class HealthClient(_iox.LatestClient):
    """Reads the daemon's :class:`~op3dsg.wire.Health` records.

    The constructor waits for the service's history, the daemon's newest record (up to one
    second; it comes within 20 ms), so the first :meth:`latest` returns it. ``timeout`` (seconds): how long the
    constructor waits for a daemon that is not up yet."""

    def __init__(self, prefix: Optional[str] = None, timeout: float = 0.0, node_name: Optional[str] = None):
        self.prefix = prefix = _iox.resolve_prefix(prefix)
        self.service = _iox.service_name(prefix, "health")
        deadline = _iox.deadline_after(timeout)
        name = node_name or _iox.default_node_name("health")
        self._node = _iox.retry_while_not_serving(timeout, lambda: _iox.create_node(prefix, self.service, name))
        self._subscriber = _iox.retry_while_not_serving(_iox.left_until(deadline), self._open)
        _iox.await_history(self.service, self._subscriber)
        self._latest: Optional[Health] = None

    def _open(self):
        try:
            service = self._node.service_builder(iox2.ServiceName.new(self.service)).publish_subscribe(Health).open()
        except Exception as e:
            raise _iox.open_error(self.service, e) from e
        try:
            return service.subscriber_builder().history_request(HISTORY_SIZE).create()
        except Exception as e:
            raise _iox.open_error(self.service, e, "create subscriber") from e

    def latest(self) -> Optional[Health]:
        """Takes every queued record and returns a copy of the newest received so far (``None``
        while none came). Compare ``stamp_ns`` to tell a fresh record from the last one. A record
        of another schema version raises :class:`~op3dsg.errors.SchemaVersionError`."""
        newest = None
        while True:
            try:
                sample = self._subscriber.receive()
            except Exception as e:
                raise _iox.open_error(self.service, e, "receive") from e
            if sample is None:
                break
            newest = Health()
            ctypes.memmove(ctypes.addressof(newest), sample.payload_ptr, ctypes.sizeof(Health))
            sample.delete()
        if newest is not None:
            if newest.schema_version != SCHEMA_VERSION:
                raise SchemaVersionError(self.service, newest.schema_version, SCHEMA_VERSION)
            self._latest = newest
        return self._latest

    def wait(self, timeout: float, newer_than_ns: int = 0) -> Health:
        """The newest record stamped after ``newer_than_ns``, waiting up to ``timeout`` seconds;
        ``TimeoutError`` naming the service otherwise."""
        return self._wait_newer(
            timeout, newer_than_ns, lambda r: r.stamp_ns, f"health record within {timeout:.1f} s (is op3dsgd running?)"
        )


def health(prefix: Optional[str] = None, timeout: float = 5.0) -> Health:
    """The daemon's newest health record, waiting up to ``timeout`` seconds for the daemon and
    its record (:class:`~op3dsg.errors.NotServingError` when no daemon serves the prefix).
    ``prefix`` ``None``: ``$OP3DSG_PREFIX``, else ``op3dsg``."""
    deadline = time.monotonic() + timeout
    with HealthClient(prefix, timeout=timeout) as client:
        return client.wait(max(0.0, deadline - time.monotonic()))
