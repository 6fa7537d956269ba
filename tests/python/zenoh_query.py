"""Asks op3dsg's language query service over Zenoh, written from docs/remote.md alone.

It uses only PyPI `eclipse-zenoh` and the standard library (not the project's Python package):
connects as a client to one endpoint with scouting off, sends a 272-byte query request to the
queryable `<prefix>/query` (with congestion control drop), decodes the 3296-byte response and
prints it as one JSON line; with --health it prints the newest health record from the queryable
`<prefix>/health` instead.

Usage: zenoh_query.py --connect tcp/127.0.0.1:7447 --prefix op3dsg/test (--text T [--k K] | --node-id N | --health)
"""

import argparse
import json
import struct
import sys

import zenoh

QUERY_SCHEMA_VERSION = 2
NO_NODE = 0xFFFFFFFF
REQUEST_BYTES, RESPONSE_BYTES, HIT_BYTES, HITS_AT = 272, 3296, 192, 224
STATUS = ["ok", "busy", "encoder_off", "no_graph", "bad_request", "encoder_failed", "shutting_down"]


def text(raw):
    return raw.split(b"\0", 1)[0].decode("utf-8")


def request_bytes(query_text, k, node_id):
    encoded = query_text.encode("utf-8")
    assert len(encoded) <= 256, "text longer than 256 bytes"
    out = struct.pack("<II256sII", QUERY_SCHEMA_VERSION, k, encoded, node_id, 0)
    assert len(out) == REQUEST_BYTES
    return out


def decode_response(buf):
    assert len(buf) == RESPONSE_BYTES, f"a response is {RESPONSE_BYTES} bytes, got {len(buf)}"
    (schema, status, graph_version, instance_id, hit_count, queue_capacity, served, refused, encode_us,
     score_us, scored) = struct.unpack_from("<IB3xQQIIQQIII4x", buf, 0)
    out = {"schema_version": schema, "status": STATUS[status] if status < len(STATUS) else status,
           "message": text(buf[64:224]), "graph_version": graph_version, "instance_id": instance_id,
           "scored_nodes": scored, "hits": []}
    for i in range(min(hit_count, 16)):
        at = HITS_AT + i * HIT_BYTES
        node_id, parent_id, kind, matched, score = struct.unpack_from("<IIBB2xf", buf, at)
        approach_status = buf[at + 160]
        x, y, yaw, standoff, path = struct.unpack_from("<5f", buf, at + 164)
        out["hits"].append({"node_id": node_id, "parent_id": None if parent_id == NO_NODE else parent_id,
                            "kind": kind, "matched": matched, "score": score,
                            "label": text(buf[at + 16:at + 64]), "matched_text": text(buf[at + 64:at + 160]),
                            "approach_status": approach_status,
                            "approach": [x, y, yaw, standoff, path] if approach_status == 1 else None})
    return out


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--connect", required=True)
    parser.add_argument("--prefix", required=True)
    parser.add_argument("--text", default="")
    parser.add_argument("--k", type=int, default=5)
    parser.add_argument("--node-id", type=int, default=NO_NODE)
    parser.add_argument("--health", action="store_true")
    parser.add_argument("--timeout-s", type=float, default=10.0)
    args = parser.parse_args()
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([args.connect]))
    config.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(config)
    if args.health:
        key, payload = f"{args.prefix}/health", None
    else:
        key, payload = f"{args.prefix}/query", request_bytes(args.text, args.k, args.node_id)
    replies = session.get(key, payload=payload, timeout=args.timeout_s,
                          congestion_control=zenoh.CongestionControl.DROP)
    for reply in replies:
        if reply.ok is None:
            print(json.dumps({"error": reply.err.payload.to_string()}))
            return 1
        buf = reply.ok.payload.to_bytes()
        if args.health:
            magic, format_version, kind = struct.unpack_from("<4sHH", buf, 0)
            assert (magic, format_version, kind) == (b"O3DZ", 1, 3), (magic, format_version, kind)
            print(json.dumps(json.loads(buf[40:].decode("utf-8"))))
        else:
            print(json.dumps(decode_response(buf)))
        session.close()
        return 0
    print(json.dumps({"error": f"no reply on {key} within {args.timeout_s} s"}))
    return 1


if __name__ == "__main__":
    sys.exit(main())
