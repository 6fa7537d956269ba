"""The live view's CPU share at camera rate with one viewer, images off and on.

For each setting it starts `op3dsgd` (the synthetic default scene at its camera rate, the live
view on a free loopback port), lets it warm up, connects one Foxglove viewer (the test client's
protocol code: tests/python/foxglove_client.py) subscribed to every channel and reading all it
gets, and over the window reads the CPU time of the live view's threads (`op3dsg-live-view`,
`op3dsg-live-ws`) and of the whole daemon from /proc. Prints one table row per setting.

Usage: .venv/bin/python scripts/bench_live_view.py --bin target/debug [--seconds 20] [--warmup-s 8]
"""

import argparse
import asyncio
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "python"))
import foxglove_client  # noqa: E402
import websockets  # noqa: E402

TICKS = os.sysconf("SC_CLK_TCK")


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_ticks(pid, prefix=None):
    """utime + stime of the process's threads whose name starts with `prefix` (all: None)."""
    total = 0
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            stat = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        if prefix is not None and not name.startswith(prefix):
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        total += int(fields[11]) + int(fields[12])
    return total


async def view(url, seconds, pid):
    """Reads every message for `seconds`; returns (messages, bytes, live ticks, process ticks)."""
    async with websockets.connect(url, subprotocols=[foxglove_client.SUBPROTOCOL], max_size=None) as ws:
        await foxglove_client.subscribe_all(ws, 30)
        live0, all0 = cpu_ticks(pid, "op3dsg-live"), cpu_ticks(pid)
        messages = size = 0
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                raw = await asyncio.wait_for(ws.recv(), max(0.05, end - time.monotonic()))
            except asyncio.TimeoutError:
                break
            if isinstance(raw, bytes):
                messages += 1
                size += len(raw)
        return messages, size, cpu_ticks(pid, "op3dsg-live") - live0, cpu_ticks(pid) - all0


def run(bin_dir, images, seconds, warmup_s):
    port = free_port()
    prefix = f"bench_live_{os.getpid()}_{int(images)}"
    daemon = subprocess.Popen(
        [
            str(Path(bin_dir) / "op3dsgd"),
            "--prefix", prefix,
            "--set", "live_view.enabled=true",
            "--set", f'live_view.bind="127.0.0.1:{port}"',
            "--set", f"live_view.images={'true' if images else 'false'}",
        ],
        env={**os.environ, "OP3DSG_LOG": "warn"},
        stdin=subprocess.DEVNULL,
    )
    try:
        time.sleep(warmup_s)
        messages, size, live, total = asyncio.run(view(f"ws://127.0.0.1:{port}", seconds, daemon.pid))
    finally:
        daemon.terminate()
        daemon.wait(timeout=60)
    return {
        "images": "on" if images else "off",
        "messages_per_s": messages / seconds,
        "mb_per_s": size / seconds / 1e6,
        "live_share": live / TICKS / seconds,
        "daemon_share": total / TICKS / seconds,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bin", required=True, help="folder with op3dsgd")
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--warmup-s", type=float, default=8.0)
    args = parser.parse_args()
    print("| images | messages/s to the viewer | MB/s | live view CPU (share of one core) | whole daemon CPU |")
    print("|---|---|---|---|---|")
    for images in (False, True):
        r = run(args.bin, images, args.seconds, args.warmup_s)
        print(
            f"| {r['images']} | {r['messages_per_s']:.1f} | {r['mb_per_s']:.2f} | {100 * r['live_share']:.1f} % "
            f"| {100 * r['daemon_share']:.0f} % |",
            flush=True,
        )


if __name__ == "__main__":
    main()
