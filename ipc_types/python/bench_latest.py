#!/usr/bin/env python3
"""Times the Python client's ``latest()`` (numpy views of the shared-memory sample) on a
2,000-node graph (``--nodes 10000`` for the large one) next to the Rust client's reads of the
same samples, in one run.

    cargo build --release -p op3dsg-ipc-types --example graph_bench
    .venv/bin/python ipc_types/python/bench_latest.py [--nodes 2000] [--samples 500] [--period-ms 10]

A Rust publisher (``ipc_types/examples/graph_bench.rs publish``) serves ``<prefix>/graph`` with
the daemon's QoS and publishes a new version of a ``--nodes`` graph (two edges per node) every
period. Three readers subscribe at once and take every version after waking on
``graph_updated``, each in its own process: the Rust ``GraphSubscriber::latest_if_newer``
(receive, check, copy into the owned ``Graph``), the Rust ``GraphSubscriber::with_latest`` up to
the first node's id and label read through the zero-copy ``GraphView`` (``graph_bench read
--view``), and this process's ``GraphClient.latest_if_newer()`` (receive, check, numpy views; no
copy), then its first node's id and label, ``view.copy()`` and ``view.labels()`` timed
separately. Also publish → graph in hand for each (the header's ``publish_time_ns`` to the end of
the read, wall clock). Prints p50 / p99 in microseconds.

The binary: ``$OP3DSG_GRAPH_BENCH`` or ``target/release/examples/graph_bench`` (else the debug one).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import op3dsg

REPO = Path(__file__).resolve().parents[2]


def bench_binary() -> Path:
    if os.environ.get("OP3DSG_GRAPH_BENCH"):
        return Path(os.environ["OP3DSG_GRAPH_BENCH"])
    for profile in ("release", "debug"):
        path = REPO / "target" / profile / "examples" / "graph_bench"
        if path.exists():
            return path
    sys.exit("bench_latest.py: build it first: cargo build --release -p op3dsg-ipc-types --example graph_bench")


def percentiles(values_ns):
    values = sorted(values_ns)
    pick = lambda p: values[round((len(values) - 1) * p)] / 1e3  # noqa: E731
    return {"p50_us": round(pick(0.5), 1), "p99_us": round(pick(0.99), 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description="Python latest() vs the Rust client on one graph stream")
    parser.add_argument("--nodes", type=int, default=2000)
    parser.add_argument("--samples", type=int, default=500)
    parser.add_argument("--period-ms", type=int, default=10)
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args()

    binary = bench_binary()
    prefix = f"op3dsg-bench-py-{os.getpid()}"
    seconds = args.samples * args.period_ms / 1e3 * 2 + 10
    publisher = subprocess.Popen(
        [str(binary), "publish", "--prefix", prefix, "--nodes", str(args.nodes), "--period-ms", str(args.period_ms), "--seconds", str(seconds)],
        stdout=subprocess.DEVNULL,
    )
    try:
        client = op3dsg.GraphClient(prefix, timeout=30, node_name="op3dsg-bench-py-reader")
        readers = [
            subprocess.Popen([str(binary), "read", "--prefix", prefix, "--samples", str(args.samples), *flags], stdout=subprocess.PIPE, text=True)
            for flags in ([], ["--view"])
        ]
        latest_ns, first_node_ns, copy_ns, labels_ns, latency_ns = [], [], [], [], []
        last_seen, nodes, warmed = 0, 0, False
        deadline = time.monotonic() + seconds
        while len(latest_ns) < args.samples and time.monotonic() < deadline:
            client.wait_for_update(1.0)
            t0 = time.perf_counter_ns()
            view = client.latest_if_newer(last_seen)
            t1 = time.perf_counter_ns()
            if view is None:
                continue
            first = (int(view.nodes["id"][0]), view.label(0)) if view.node_count else None
            t1b = time.perf_counter_ns()
            node_array, edge_array = view.nodes, view.edges  # the views a planner reads
            in_hand = time.time_ns()
            t2 = time.perf_counter_ns()
            view.copy()
            t3 = time.perf_counter_ns()
            view.labels()
            t4 = time.perf_counter_ns()
            last_seen, nodes = view.version, len(node_array)
            assert len(edge_array) == view.edge_count and first is not None
            if warmed:  # the first graph may be the late history sample: not timed
                latest_ns.append(t1 - t0)
                first_node_ns.append(t1b - t0)
                latency_ns.append(in_hand - view.publish_time_ns)
                copy_ns.append(t3 - t2)
                labels_ns.append(t4 - t3)
            warmed = True
        rust_outs = [reader.communicate(timeout=180)[0] for reader in readers]
    finally:
        publisher.kill()
        publisher.wait()
    rust_result, view_result = (json.loads(out.strip().splitlines()[-1]) for out in rust_outs)
    result = {
        "nodes": nodes,
        "edges_per_node": 2,
        "period_ms": args.period_ms,
        "python": {
            "samples": len(latest_ns),
            "latest_views": percentiles(latest_ns),
            "latest_to_first_node": percentiles(first_node_ns),
            "copy": percentiles(copy_ns),
            "labels_decoded": percentiles(labels_ns),
            "publish_to_views": percentiles(latency_ns),
        },
        "rust": {
            "samples": rust_result["samples"],
            "latest_copy_into_graph": {"p50_us": rust_result["call_p50_us"], "p99_us": rust_result["call_p99_us"]},
            "publish_to_graph": {"p50_us": rust_result["latency_p50_us"], "p99_us": rust_result["latency_p99_us"]},
            "view_samples": view_result["samples"],
            "with_latest_to_first_node": {"p50_us": view_result["call_p50_us"], "p99_us": view_result["call_p99_us"]},
            "publish_to_view_first_node": {"p50_us": view_result["latency_p50_us"], "p99_us": view_result["latency_p99_us"]},
        },
        "binary": str(binary.relative_to(REPO) if binary.is_relative_to(REPO) else binary),
    }
    py, rs = result["python"], result["rust"]
    print(
        f"{nodes} nodes, {2 * nodes} edges, a version every {args.period_ms} ms; "
        f"{py['samples']} Python / {rs['samples']} Rust owned / {rs['view_samples']} Rust view reads"
    )
    print(f"{'read':<66} {'p50 us':>8} {'p99 us':>8}")
    rows = [
        ("Python GraphClient.latest_if_newer() -> numpy views", py["latest_views"]),
        ("Python latest_if_newer() + first node's id and label", py["latest_to_first_node"]),
        ("Python view.copy() (owned Graph)", py["copy"]),
        ("Python view.labels() (decode every label)", py["labels_decoded"]),
        ("Rust GraphSubscriber::latest_if_newer (copy into Graph)", rs["latest_copy_into_graph"]),
        ("Rust GraphSubscriber::with_latest to the first node (view)", rs["with_latest_to_first_node"]),
        ("publish -> Python views in hand", py["publish_to_views"]),
        ("publish -> Rust Graph in hand", rs["publish_to_graph"]),
        ("publish -> Rust view's first node read", rs["publish_to_view_first_node"]),
    ]
    for name, figures in rows:
        print(f"{name:<66} {figures['p50_us']:>8.1f} {figures['p99_us']:>8.1f}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
