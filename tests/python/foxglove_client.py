#!/usr/bin/env python3
"""A real client of Foxglove's WebSocket protocol, for the live view's tests.

Connects to a Foxglove WebSocket server with the `foxglove.sdk.v1` subprotocol (or
those given with --subprotocol, in one offer: Lichtblick offers `foxglove.websocket.v1`
and `foxglove.sdk.v1`, its releases before December 2025 the first alone; the
`websockets` package, which answers the server's pings as a browser does), reads `serverInfo` and the advertised channels, subscribes to
every channel whose topic starts with --prefix, decodes each binary `Message Data`
frame (opcode 1: subscription id u32, log time u64, payload, little-endian) with the
protobuf schema the server advertised for its channel (a base64 FileDescriptorSet,
loaded into a descriptor pool as Foxglove does), and prints one JSON object:
the negotiated protocol, the advertised channels, and every message decoded
(topic, log time, fields by their proto names, enums by name).

Writes --ready FILE once subscribed; stops after --quiet-s seconds without a message
on a topic starting with --quiet-prefix (once one came; heartbeats go on while a
system runs) or after --max-s seconds.

With --count-only it decodes nothing and prints the messages per topic (`counts`).
With --stall-s S the client is a stalled viewer: once subscribed it reads nothing for
S seconds (the library's receive queue is one frame, so the server's writes back up
into its own per-client queue), then reads what is left as usual.

Usage:
    python3 tests/python/foxglove_client.py ws://127.0.0.1:PORT --ready FILE

Requires: pip install -r tests/python/requirements.txt
"""

import argparse
import asyncio
import base64
import json
import socket
import struct
import sys
import time

try:
    import websockets
    from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory
except ImportError as e:  # pragma: no cover - the message is the point
    print(
        f"foxglove_client.py: missing Python package ({e}); "
        "run `pip install -r tests/python/requirements.txt`",
        file=sys.stderr,
    )
    sys.exit(3)

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01


def message_class(schema_name, schema_b64):
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


async def run(
    url, prefix, ready, quiet_s, quiet_prefix, max_s, stall_s=0.0, count_only=False, subprotocols=None
):
    out = {"protocol": None, "server": None, "channels": [], "messages": [], "status": []}
    counts = {}
    classes, topics = {}, {}
    stalled = False
    sock = None
    if stall_s:
        # A small receive buffer, so that the stall backs up into the server quickly.
        host, port = url.split("//", 1)[1].rsplit(":", 1)
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        sock.connect((host, int(port)))
    async with websockets.connect(
        url,
        subprotocols=subprotocols or [SUBPROTOCOL],
        max_size=None,
        max_queue=1 if stall_s else 16,
        sock=sock,
    ) as ws:
        out["protocol"] = ws.subprotocol
        start = time.monotonic()
        last = None
        next_sub = 1
        while True:
            now = time.monotonic()
            if now - start > max_s or (last is not None and now - last > quiet_s):
                break
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=0.2)
            except asyncio.TimeoutError:
                continue
            if isinstance(frame, str):
                msg = json.loads(frame)
                op = msg.get("op")
                if op == "serverInfo":
                    out["server"] = {k: msg.get(k) for k in ("name", "capabilities")}
                elif op == "status":
                    out["status"].append({k: msg.get(k) for k in ("level", "message", "id")})
                elif op == "advertise":
                    subs = []
                    for ch in msg["channels"]:
                        out["channels"].append(
                            {k: ch.get(k) for k in ("topic", "encoding", "schemaName", "schemaEncoding")}
                        )
                        if not ch["topic"].startswith(prefix):
                            continue
                        if ch.get("encoding") != "protobuf":
                            raise RuntimeError(f"channel {ch['topic']} is not protobuf")
                        classes[next_sub] = message_class(ch["schemaName"], ch["schema"])
                        topics[next_sub] = ch["topic"]
                        subs.append({"id": next_sub, "channelId": ch["id"]})
                        next_sub += 1
                    if subs:
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                        if ready:
                            with open(ready, "w") as f:
                                f.write("subscribed\n")
                        if stall_s and not stalled:
                            stalled = True
                            await asyncio.sleep(stall_s)
                            start = time.monotonic()
                continue
            if not frame or frame[0] != MESSAGE_DATA:
                continue
            sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
            if count_only:
                counts[topics[sub_id]] = counts.get(topics[sub_id], 0) + 1
                if topics[sub_id].startswith(quiet_prefix):
                    last = time.monotonic()
                continue
            payload = frame[13:]
            decoded = classes[sub_id].FromString(payload)
            out["messages"].append(
                {
                    "topic": topics[sub_id],
                    "log_time_ns": log_time,
                    "fields": json_format.MessageToDict(
                        decoded,
                        preserving_proto_field_name=True,
                        always_print_fields_with_no_presence=True,
                    ),
                }
            )
            if topics[sub_id].startswith(quiet_prefix):
                last = time.monotonic()
    if count_only:
        out["counts"] = counts
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("url")
    p.add_argument("--prefix", default="/view/", help="subscribe to topics starting with this")
    p.add_argument("--ready", help="file written once subscribed")
    p.add_argument("--quiet-s", type=float, default=3.0)
    p.add_argument("--quiet-prefix", default="/view/", help="topics whose silence ends the run")
    p.add_argument("--max-s", type=float, default=60.0)
    p.add_argument("--stall-s", type=float, default=0.0, help="read nothing for S s once subscribed")
    p.add_argument(
        "--count-only", action="store_true", help="count the messages per topic, decode none"
    )
    p.add_argument(
        "--subprotocol",
        action="append",
        help=f"a subprotocol to offer (repeatable; {SUBPROTOCOL} unless given)",
    )
    a = p.parse_args()
    out = asyncio.run(
        run(
            a.url,
            a.prefix,
            a.ready,
            a.quiet_s,
            a.quiet_prefix,
            a.max_s,
            a.stall_s,
            a.count_only,
            a.subprotocol,
        )
    )
    json.dump(out, sys.stdout)
    print()


if __name__ == "__main__":
    main()
