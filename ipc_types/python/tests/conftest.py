"""Test support: the real ``op3dsgd`` (and ``op3dsg``) binaries as child processes, each test on
its own iceoryx2 prefix, killed when the test ends.

Binaries: ``$OP3DSGD`` (default ``target/debug/op3dsgd`` of this checkout), ``$OP3DSG`` (default
``op3dsg`` next to it), ``$OP3DSG_WIRE_LAYOUT`` (default ``target/debug/examples/wire_layout``).
``cargo build -p op3dsgd && cargo build -p op3dsg-ipc-types --example wire_layout`` builds them;
a missing one fails the test with that command (never a silent skip).
"""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import time
from pathlib import Path
from typing import Callable, List, Optional, TypeVar

import pytest

REPO = Path(__file__).resolve().parents[3]
T = TypeVar("T")
_counter = itertools.count()

#: A synthetic kitchen at 60 frames/s with short health periods (as the Rust tests' FAST).
FAST = ["--set", "source.rate_hz=60", "--set", "health.period_ms=100"]


def binary(env: str, default: Path) -> Path:
    path = Path(os.environ.get(env) or default)
    if not path.is_absolute():
        path = REPO / path
    if not path.exists():
        pytest.fail(
            f"{path} not built (set ${env} or run `cargo build -p op3dsgd && "
            "cargo build -p op3dsg-ipc-types --example wire_layout` in the repository root)"
        )
    return path


def op3dsgd_path() -> Path:
    return binary("OP3DSGD", REPO / "target/debug/op3dsgd")


def op3dsg_path() -> Path:
    return binary("OP3DSG", op3dsgd_path().parent / "op3dsg")


def wire_layout_path() -> Path:
    return binary("OP3DSG_WIRE_LAYOUT", REPO / "target/debug/examples/wire_layout")


def raw_node():
    """A plain iceoryx2 node in the IPC root the clients use (made when missing), for tests that
    stand in for the daemon or its peers."""
    import iceoryx2 as iox2
    from op3dsg import access

    root, _ = access.resolve_root()
    access.prepare_root(root)
    return iox2.NodeBuilder.new().config(access.config(root)).create(iox2.ServiceType.Ipc)


def unique_prefix(name: str) -> str:
    return f"op3dsg-py-{name}-{os.getpid()}-{next(_counter)}"


class Daemon:
    """A running ``op3dsgd --prefix <prefix> <args>`` (logs at warn), killed at the test's end."""

    def __init__(self, prefix: str, args: List[str]):
        self.prefix = prefix
        env = dict(os.environ, OP3DSG_LOG=os.environ.get("OP3DSG_LOG", "warn"))
        self.process = subprocess.Popen([str(op3dsgd_path()), "--prefix", prefix, *args], env=env, stdin=subprocess.DEVNULL)

    @property
    def pid(self) -> int:
        return self.process.pid

    def kill_9(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
        self.process.wait(timeout=30)

    def running(self) -> bool:
        return self.process.poll() is None


@pytest.fixture
def prefix(request) -> str:
    return unique_prefix(request.node.name.replace("test_", "")[:40])


@pytest.fixture
def daemons():
    """Starts daemons with ``daemons(prefix, args)``; every one is killed at the test's end."""
    started: List[Daemon] = []

    def start(prefix: str, args: Optional[List[str]] = None) -> Daemon:
        daemon = Daemon(prefix, FAST if args is None else args)
        started.append(daemon)
        return daemon

    yield start
    for daemon in started:
        daemon.kill_9()


def wait_for(what: str, timeout: float, f: Callable[[], Optional[T]], interval: float = 0.02) -> T:
    """Polls ``f`` until it returns something other than ``None``; fails the test naming ``what``."""
    deadline = time.monotonic() + timeout
    while True:
        value = f()
        if value is not None:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(interval)
