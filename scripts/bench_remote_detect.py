"""Local against remote detection on the ICL-NUIM replay: keyframes/s, capture -> graph latency,
the capture and fusion stages' p99, and (remote) bytes per keyframe and round trip.

Each run starts `op3dsgd` with profiles/replay-icl.toml (YOLOX-nano, CPU), looping the sequence
at --rate-hz frames/s. The local run detects in the daemon; the remote run sends every keyframe
to one `op3dsg-detectd` (the same profile's detector, two threads) over Zenoh on loopback, with
no fallback. After --warmup-s it reads the health record once a second for --seconds through
the Python client and prints one Markdown row per run: keyframes/s from the health record's
keyframe count, the median over the window of each health period's p50 and the largest p99 of
`end_to_end` (capture -> first graph holding the keyframe, periods with a new graph only),
`capture` and `fusion`, and the remote worker's figures at the end.

Both processes share this machine's cores: the remote row shows the protocol's cost and the
pipeline's behaviour with detection elsewhere, not a GPU's speed-up.

Usage: .venv/bin/python scripts/bench_remote_detect.py --bin target/release [--seconds 30]
"""

import argparse
import os
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "ipc_types" / "python"))
from op3dsg.health import HealthClient  # noqa: E402


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stage(h, name):
    return h.stage(name)


def run(bin_dir, remote, seconds, warmup_s, rate_hz):
    prefix = f"bench_remote_{os.getpid()}_{int(remote)}"
    profile = str(ROOT / "profiles" / "replay-icl.toml")
    common = ["--set", "source.replay.loop=true", "--set", f"source.rate_hz={rate_hz}", "--set", "run.exit_at_end=false"]
    env = {**os.environ, "OP3DSG_LOG": "warn"}
    procs = []
    try:
        args = [str(Path(bin_dir) / "op3dsgd"), "--prefix", prefix, "--profile", profile, *common]
        if remote:
            port, key_prefix = free_port(), f"bench{os.getpid()}"
            args += [
                "--set", 'detector.kind="remote"',
                "--set", f'zenoh.key_prefix="{key_prefix}"',
                "--set", f'zenoh.listen=["tcp/127.0.0.1:{port}"]',
                "--set", f'detector.remote.workers=["{key_prefix}/detect/w1"]',
                "--set", "detector.remote.wait_for_workers_ms=60000",
                "--set", "detector.remote.timeout_ms=5000",
            ]
            procs.append(
                subprocess.Popen(
                    [
                        str(Path(bin_dir) / "op3dsg-detectd"), "--profile", profile, "--id", "w1",
                        "--set", f'zenoh.key_prefix="{key_prefix}"',
                        "--set", f'zenoh.connect=["tcp/127.0.0.1:{port}"]',
                    ],
                    env=env,
                    stdin=subprocess.DEVNULL,
                )
            )
        procs.append(subprocess.Popen(args, env=env, stdin=subprocess.DEVNULL))
        health = HealthClient(prefix, timeout=60.0)
        first = health.wait(60.0)
        time.sleep(warmup_s)
        start = health.wait(5.0, newer_than_ns=first.stamp_ns)
        e2e_p50, e2e_p99, cap_p99, fus_p99, det_p50 = [], [], [], [], []
        last = start
        while last.stamp_ns - start.stamp_ns < seconds * 1e9:
            last = health.wait(5.0, newer_than_ns=last.stamp_ns)
            e2e = stage(last, "end_to_end")
            if e2e.rate_hz > 0:
                e2e_p50.append(e2e.latency_p50_us / 1e3)
                e2e_p99.append(e2e.latency_p99_us / 1e3)
            cap_p99.append(stage(last, "capture").latency_p99_us / 1e3)
            fus_p99.append(stage(last, "fusion").latency_p99_us / 1e3)
            det = stage(last, "detect/0")
            if det.rate_hz > 0:
                det_p50.append(det.latency_p50_us / 1e3)
        window = (last.stamp_ns - start.stamp_ns) / 1e9
        keyframes = (last.keyframes - start.keyframes) / window
        row = {
            "run": "remote (1 worker, png)" if remote else "local",
            "keyframes_per_s": keyframes,
            "e2e_p50": statistics.median(e2e_p50) if e2e_p50 else float("nan"),
            "e2e_p99": max(e2e_p99) if e2e_p99 else float("nan"),
            "detect_p50": statistics.median(det_p50) if det_p50 else float("nan"),
            "capture_p99": max(cap_p99),
            "fusion_p99": max(fus_p99),
            "remote": "",
        }
        if remote:
            w = last.remote.valid_workers()[0]
            row["remote"] = (
                f"{w.bytes_per_keyframe() / 1e3:.0f} kB/keyframe, round trip p50 {w.round_trip_p50_us / 1e3:.0f} ms "
                f"p99 {w.round_trip_p99_us / 1e3:.0f} ms, {last.remote.fallback_keyframes} to the fallback"
            )
        return row
    finally:
        for p in reversed(procs):
            p.terminate()
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                p.kill()


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bin", required=True, help="folder with op3dsgd and op3dsg-detectd")
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--warmup-s", type=float, default=5.0)
    parser.add_argument("--rate-hz", type=float, default=15.0, help="frames/s of the replay")
    args = parser.parse_args()
    print(
        "| detection | keyframes/s | capture -> graph p50 / p99 ms | detect p50 ms | capture p99 ms "
        "| fusion p99 ms | remote |"
    )
    print("|---|---|---|---|---|---|---|")
    for remote in (False, True):
        r = run(args.bin, remote, args.seconds, args.warmup_s, args.rate_hz)
        print(
            f"| {r['run']} | {r['keyframes_per_s']:.2f} | {r['e2e_p50']:.0f} / {r['e2e_p99']:.0f} "
            f"| {r['detect_p50']:.0f} | {r['capture_p99']:.2f} | {r['fusion_p99']:.2f} | {r['remote']} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
