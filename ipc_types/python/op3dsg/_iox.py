"""iceoryx2 plumbing shared by the clients: prefix rules, service names, node creation, retries
while the daemon is not up, and iceoryx2 errors turned into op3dsg errors."""

from __future__ import annotations

import os
import re
import time
from typing import Callable, Optional, TypeVar

import iceoryx2 as iox2

from . import access
from .errors import (
    AccessDeniedError,
    Iceoryx2Error,
    InvalidPrefixError,
    NotServingError,
    Op3dsgError,
    SubscriberSlotsFullError,
)
from .wire import DEFAULT_PREFIX, MAX_PREFIX_LEN, PREFIX_ENV

#: How often a client started before the daemon retries opening its services (seconds).
OPEN_RETRY_INTERVAL_S = 0.1
#: How long opening a subscriber of ``graph``, ``health`` or ``occupancy`` waits for the service's
#: history, the daemon's newest sample (seconds; the Rust client's ``ATTACH_HISTORY_WAIT``). The
#: daemon hands it over within 20 ms; only a daemon that has published nothing yet makes opening
#: wait this long, and then gives none.
ATTACH_HISTORY_WAIT_S = 1.0

_PREFIX_CHARS = re.compile(r"[A-Za-z0-9_\-./]")

T = TypeVar("T")

# iceoryx2 warns at start when it finds no config file and uses its defaults (fine here); the
# environment (IOX2_LOG_LEVEL) may still ask for more.
iox2.set_log_level_from_env_or(iox2.LogLevel.Error)


def validate_prefix(prefix: str, service: str) -> None:
    """The Rust ``validate_prefix``: not empty, at most 128 bytes, ``A-Z a-z 0-9 _ - . /`` with
    inner slashes only. Raises :class:`InvalidPrefixError` naming ``service``."""

    def fail(reason: str):
        raise InvalidPrefixError(service, "open", f"invalid prefix {prefix!r}: {reason}")

    if not isinstance(prefix, str) or not prefix:
        fail("must not be empty")
    if len(prefix.encode()) > MAX_PREFIX_LEN:
        fail(f"must be at most {MAX_PREFIX_LEN} bytes, found {len(prefix.encode())}")
    for ch in prefix:
        if not _PREFIX_CHARS.fullmatch(ch):
            fail(f"invalid character {ch!r} (allowed: A-Z a-z 0-9 _ - . /)")
    if prefix.startswith("/") or prefix.endswith("/") or "//" in prefix:
        fail("must not start or end with '/' nor contain \"//\"")


def default_prefix() -> str:
    """The prefix a client uses when given none: ``$OP3DSG_PREFIX`` when set and not empty, else
    ``op3dsg`` (what ``op3dsg`` and ``op3dsgd`` do without ``--prefix``)."""
    return os.environ.get(PREFIX_ENV) or DEFAULT_PREFIX


def resolve_prefix(prefix: Optional[str]) -> str:
    """``prefix``, or :func:`default_prefix` for ``None``."""
    return default_prefix() if prefix is None else prefix


def service_name(prefix: str, suffix: str) -> str:
    return f"{prefix}/{suffix}"


def reason(error: BaseException) -> str:
    """iceoryx2's reason of an exception (its variant name, e.g. ``DoesNotExist``)."""
    return str(error.args[0]) if error.args else type(error).__name__


def client_config(service: str, make_root: bool = False):
    """The iceoryx2 configuration of a client: the root :func:`access.resolve_root` chooses,
    checked before iceoryx2 may create anything in it. A missing root means no daemon of this user
    runs (:class:`NotServingError`, so waiting clients keep waiting), unless ``make_root`` (the pose
    publisher, which may come first)."""
    root, _ = access.resolve_root()
    try:
        if make_root:
            access.prepare_root(root)
        else:
            access.check_root(root)
    except access.RootMissing:
        raise NotServingError(service, "create node") from None
    except access.RootDenied as e:
        raise AccessDeniedError(service, "create node", str(e)) from None
    return access.config(root)


def create_node(prefix: str, service: str, node_name: str, make_root: bool = False):
    """The client's iceoryx2 node in the IPC root (signal handling off: Ctrl-C stays Python's),
    after checking the prefix and the root; removes the shared-memory leftovers of dead processes,
    as the Rust client does."""
    validate_prefix(prefix, service)
    cfg = client_config(service, make_root)
    try:
        name = iox2.NodeName.new(node_name)
        node = (
            iox2.NodeBuilder.new()
            .name(name)
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .config(cfg)
            .create(iox2.ServiceType.Ipc)
        )
    except Exception as e:  # iceoryx2 raises its own exception classes
        raise Iceoryx2Error(service, "create node", f"{type(e).__name__}: {reason(e)}") from e
    try:
        node.try_cleanup_dead_nodes()
    except Exception:
        # Leftovers are the daemon's to report; a client loses nothing but a faster start.
        pass
    return node


def default_node_name(role: str) -> str:
    return f"op3dsg-py-{role}-{os.getpid()}"


def open_error(service: str, error: BaseException, operation: str = "open") -> Op3dsgError:
    """An op3dsg error for a failed iceoryx2 open or port creation."""
    why = reason(error)
    if why == "DoesNotExist":
        return NotServingError(service, operation)
    if why == "IncompatibleTypes":
        return Iceoryx2Error(
            service,
            operation,
            "IncompatibleTypes: the service carries another payload type or layout than this package "
            "(wire contract schema 4); update the op3dsg Python package or the daemon",
        )
    if why == "ExceedsMaxSupportedSubscribers":
        return SubscriberSlotsFullError(
            service, operation, f"{why}: every subscriber slot of the service is taken (the daemon's ipc.max_subscribers)"
        )
    return Iceoryx2Error(service, operation, f"{type(error).__name__}: {why}")


def deadline_after(timeout_s: float) -> float:
    return time.monotonic() + max(0.0, timeout_s)


def left_until(deadline: float) -> float:
    return max(0.0, deadline - time.monotonic())


def await_history(service: str, subscriber) -> None:
    """Waits until a newly connected ``subscriber`` holds the service's history sample, up to
    :data:`ATTACH_HISTORY_WAIT_S`, so a first ``latest()`` after opening returns it."""
    deadline = time.monotonic() + ATTACH_HISTORY_WAIT_S
    while time.monotonic() < deadline:
        try:
            if subscriber.has_samples():
                return
        except Exception as e:
            raise open_error(service, e, "receive") from e
        time.sleep(0.002)


def retry_while_not_serving(timeout_s: float, open_fn: Callable[[], T]) -> T:
    """Calls ``open_fn`` until it succeeds, fails with another error than :class:`NotServingError`,
    or ``timeout_s`` has passed (then the last :class:`NotServingError` is raised)."""
    deadline = time.monotonic() + max(0.0, timeout_s)
    while True:
        try:
            return open_fn()
        except NotServingError:
            left = deadline - time.monotonic()
            if left <= 0:
                raise
            time.sleep(min(OPEN_RETRY_INTERVAL_S, left))


def duration(seconds: float):
    return iox2.Duration.from_secs_f64(max(0.0, float(seconds)))


class LatestClient:
    """What the clients of one publish-subscribe service share (``self.service``, an iceoryx2
    ``self._subscriber`` and ``latest()``): waiting for a newer sample, closing, ``with``."""

    def _wait_newer(self, timeout: float, newer_than_ns: int, stamp_of: Callable, missing: str):
        """``latest()`` until ``stamp_of`` it is after ``newer_than_ns``, at most ``timeout``
        seconds; ``TimeoutError`` naming the service and ``missing`` otherwise."""
        deadline = time.monotonic() + timeout
        while True:
            sample = self.latest()
            if sample is not None and stamp_of(sample) > newer_than_ns:
                return sample
            if time.monotonic() >= deadline:
                raise TimeoutError(f"{self.service}: no {missing}")
            time.sleep(0.02)

    def close(self) -> None:
        if getattr(self, "_subscriber", None) is not None:
            self._subscriber.delete()
            self._subscriber = None

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
