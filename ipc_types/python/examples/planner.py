#!/usr/bin/env python3
"""A minimal planner: waits for op3dsgd, then prints each new graph version with its counts and
every part with its parent object and affordances, each with its origin (the Python twin of
``ipc_types/examples/planner.rs``).

    .venv/bin/python ipc_types/python/examples/planner.py [--prefix P] [--versions N]

The prefix is ``--prefix``, else ``$OP3DSG_PREFIX``, else ``op3dsg``; with ``--versions N`` it
exits after N graph versions, otherwise it runs until interrupted.
"""

import argparse
import os

import op3dsg


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--prefix", default=os.environ.get("OP3DSG_PREFIX", op3dsg.DEFAULT_PREFIX))
    parser.add_argument("--versions", type=int, default=None, help="exit after this many graph versions")
    args = parser.parse_args()

    graphs = op3dsg.GraphClient(args.prefix, timeout=60)  # waits up to 60 s for the daemon
    last_seen, printed = 0, 0
    while args.versions is None or printed < args.versions:
        # Also read after a timeout: a late joiner's first graph comes without an event.
        graphs.wait_for_update(0.5)
        graph = graphs.latest_if_newer(last_seen)  # numpy views of shared memory, no copy
        if graph is None:
            continue
        if graph.restarted:
            # Versions count from 1 again; node ids stay when the daemon restored its map snapshot.
            print(f"op3dsgd restarted (instance {graph.instance_id:#018x}): versions count again from {graph.version}")
        last_seen, printed = graph.version, printed + 1
        nodes = graph.nodes
        print(f"version {graph.version} objects {graph.objects().size} parts {graph.parts().size} edges {graph.edge_count}")
        for i in graph.parts():
            parent = graph.index_of(int(nodes["parent_id"][i]))
            parent_label = graph.label(parent) if parent is not None else "(none)"
            # Each affordance with where it came from: knowledge, llm or knowledge+llm.
            affordances = [f"{name}:{origin}" for name, origin in graph.affordance_origins(i).items()]
            centre = [round(float(v), 2) for v in nodes["centre_m"][i]]
            print(f"  part {nodes['id'][i]} {graph.label(i)!r} of {parent_label!r} at {centre} m affords {affordances}")


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:
        pass
    except op3dsg.Op3dsgError as error:
        raise SystemExit(f"planner.py: {error}")
