"""A Foxglove WebSocket client written from Foxglove's published protocol specification
(https://github.com/foxglove/ws-protocol, docs/spec.md, protocol v1), with only PyPI
`websockets` and `protobuf`: not the project's code, not the Foxglove SDK.

The spec names the v1 subprotocol `foxglove.websocket.v1`; Foxglove's SDK servers (the
`foxglove` crate, foxglove_bridge 3) negotiate the same v1 messages under the name
`foxglove.sdk.v1`. The daemon takes both (and `foxglove.sdk.v1.1`); the new name is the one
offered here unless `--offer` says otherwise.

What it speaks: the server's text messages are JSON with an `op` (`serverInfo`, `advertise`,
`unadvertise`, `status`, ...); the client subscribes with `{"op": "subscribe", "subscriptions":
[{"id", "channelId"}]}`; message data arrives as binary frames: opcode 0x01, uint32 LE
subscription id, uint64 LE receive timestamp in nanoseconds, then the message. A channel with
`encoding` "protobuf" advertises its schema as a base64 FileDescriptorSet (`schemaEncoding`
"protobuf"), from which the message class is built.

Modes:
  scene --url URL [--count N] [--timeout-s T]
      subscribes to /op3dsg/scene, decodes N SceneUpdates against the advertised schema and
      prints each as one JSON line: graph_version, the message's size in bytes, deletions, and
      per node entity its cube (centre, size, orientation, colour), label and metadata; per edge
      entity its lines.
  stall --url URL
      subscribes to every channel and never reads again (prints "subscribed" once); runs until
      killed.
  churn --url URL --clients K --cycles C
      C times: K clients connect, subscribe to every channel, each reads one message, all close;
      prints one JSON line with the messages read.
  handshake --url URL --offer NAMES
      connects offering the comma-separated subprotocols NAMES (empty: no header) and prints one
      JSON line: the HTTP status, the subprotocol the server picked, the first text message's
      `op` and the topics of the first `advertise` (or, when refused, the answer's body).
"""

import argparse
import asyncio
import base64
import json
import struct
import sys
import time

import websockets
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

SUBPROTOCOL = "foxglove.sdk.v1"
OP_MESSAGE_DATA = 0x01


async def advertised(ws, timeout_s):
    """Reads text messages until the first `advertise`; returns its channels by topic."""
    deadline = time.monotonic() + timeout_s
    channels = {}
    while not channels:
        raw = await asyncio.wait_for(ws.recv(), max(0.1, deadline - time.monotonic()))
        if isinstance(raw, bytes):
            continue
        msg = json.loads(raw)
        if msg.get("op") == "advertise":
            for channel in msg["channels"]:
                channels[channel["topic"]] = channel
    return channels


def message_class(channel):
    """The protobuf class of a channel's schema, built from its advertised FileDescriptorSet."""
    if channel.get("encoding") != "protobuf" or channel.get("schemaEncoding", "protobuf") != "protobuf":
        raise SystemExit(f"channel {channel['topic']}: encoding {channel.get('encoding')!r}, expected protobuf")
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for file in fds.file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


def split_message_data(raw):
    """(subscription id, timestamp ns, payload) of a binary message-data frame."""
    if raw[0] != OP_MESSAGE_DATA:
        return None
    sub_id, stamp_ns = struct.unpack_from("<IQ", raw, 1)
    return sub_id, stamp_ns, raw[13:]


def xyz(v):
    return [v.x, v.y, v.z]


def colour(c):
    return [c.r, c.g, c.b, c.a]


def scene_json(update, stamp_ns):
    entities = []
    versions = set()
    for e in update.entities:
        metadata = {kv.key: kv.value for kv in e.metadata}
        versions.add(metadata.get("graph_version"))
        entities.append(
            {
                "id": e.id,
                "frame_id": e.frame_id,
                "metadata": metadata,
                "cubes": [
                    {
                        "centre": xyz(c.pose.position),
                        "orientation": [c.pose.orientation.x, c.pose.orientation.y, c.pose.orientation.z, c.pose.orientation.w],
                        "size": xyz(c.size),
                        "colour": colour(c.color),
                    }
                    for c in e.cubes
                ],
                "texts": [t.text for t in e.texts],
                "lines": [{"type": l.type, "points": [xyz(p) for p in l.points], "colour": colour(l.color)} for l in e.lines],
            }
        )
    if len(versions) != 1:
        raise SystemExit(f"one scene update holds entities of versions {versions}")
    return {
        "graph_version": int(versions.pop()),
        "receive_stamp_ns": stamp_ns,
        "deletions": [{"type": d.type, "id": d.id} for d in update.deletions],
        "entities": entities,
    }


async def scene(url, count, timeout_s):
    async with websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None) as ws:
        if ws.subprotocol != SUBPROTOCOL:
            raise SystemExit(f"server chose subprotocol {ws.subprotocol!r}")
        channels = await advertised(ws, timeout_s)
        channel = channels["/op3dsg/scene"]
        if channel["schemaName"] != "foxglove.SceneUpdate":
            raise SystemExit(f"/op3dsg/scene has schema {channel['schemaName']!r}")
        cls = message_class(channel)
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channel["id"]}]}))
        deadline = time.monotonic() + timeout_s
        got = 0
        while got < count:
            raw = await asyncio.wait_for(ws.recv(), max(0.1, deadline - time.monotonic()))
            if isinstance(raw, str):
                continue
            parts = split_message_data(raw)
            if parts is None or parts[0] != 7:
                continue
            update = cls.FromString(parts[2])
            print(json.dumps({**scene_json(update, parts[1]), "bytes": len(parts[2])}), flush=True)
            got += 1


async def subscribe_all(ws, timeout_s):
    channels = await advertised(ws, timeout_s)
    subs = [{"id": i, "channelId": c["id"]} for i, c in enumerate(channels.values())]
    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))


async def stall(url):
    # max_queue=1: the library stops reading the socket once one message waits, so the server's
    # send buffer and then its per-client backlog fill up.
    async with websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None, max_queue=1) as ws:
        await subscribe_all(ws, 30)
        print("subscribed", flush=True)
        while True:
            await asyncio.sleep(3600)


async def churn(url, clients, cycles):
    read = 0
    for _ in range(cycles):
        sockets = [await websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None) for _ in range(clients)]
        for ws in sockets:
            await subscribe_all(ws, 30)
        for ws in sockets:
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                raw = await asyncio.wait_for(ws.recv(), max(0.1, deadline - time.monotonic()))
                if isinstance(raw, bytes) and split_message_data(raw) is not None:
                    read += 1
                    break
        for ws in sockets:
            await ws.close()
    print(json.dumps({"cycles": cycles, "clients": clients, "messages_read": read}), flush=True)


async def handshake(url, offer, timeout_s):
    offered = [name for name in offer.split(",") if name] or None
    try:
        ws = await websockets.connect(url, subprotocols=offered, max_size=None)
    except websockets.exceptions.InvalidStatus as refused:
        response = refused.response
        print(json.dumps({"status": response.status_code, "body": response.body.decode(errors="replace")}), flush=True)
        return
    async with ws:
        first = json.loads(await asyncio.wait_for(ws.recv(), timeout_s))
        channels = await advertised(ws, timeout_s) if first.get("op") != "advertise" else {
            c["topic"]: c for c in first["channels"]
        }
        print(
            json.dumps({"status": 101, "subprotocol": ws.subprotocol, "first_op": first.get("op"),
                        "topics": sorted(channels)}),
            flush=True,
        )


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("mode", choices=["scene", "stall", "churn", "handshake"])
    parser.add_argument("--offer", default=SUBPROTOCOL)
    parser.add_argument("--url", required=True)
    parser.add_argument("--count", type=int, default=1)
    parser.add_argument("--timeout-s", type=float, default=30.0)
    parser.add_argument("--clients", type=int, default=5)
    parser.add_argument("--cycles", type=int, default=10)
    args = parser.parse_args()
    if args.mode == "scene":
        asyncio.run(scene(args.url, args.count, args.timeout_s))
    elif args.mode == "stall":
        asyncio.run(stall(args.url))
    elif args.mode == "handshake":
        asyncio.run(handshake(args.url, args.offer, args.timeout_s))
    else:
        asyncio.run(churn(args.url, args.clients, args.cycles))


if __name__ == "__main__":
    sys.exit(main())
