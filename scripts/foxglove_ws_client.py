#!/usr/bin/env python3
"""A Foxglove WebSocket protocol client written against the protocol's specification with the
`websockets` package -- not Foxglove's code, not amstack's. It offers the subprotocol
`foxglove.sdk.v1` (what the Foxglove SDK's server, 0.30, negotiates: the protocol formerly
named `foxglove.websocket.v1`, same messages, schemas inline in `advertise`).

Usage: foxglove_ws_client.py ws://HOST:PORT [--topics T1,T2,...] [--messages N]
                             [--need TOPIC=N ...] [--stall SECONDS] [--timeout SECONDS]
                             [--ready-file PATH]

Connects, waits for the server's `serverInfo` and the `advertise` of every topic asked for
(default: the 3D scene's topics), subscribes to them, and reads binary MessageData frames
(opcode 0x01: u32 subscription id, u64 log time ns, payload; little-endian) until it has N
messages on every topic (--messages, default 50). Protobuf payloads are decoded with the
message class built from the advertised schema (a base64 FileDescriptorSet) by Google's
`protobuf` package. With --stall S it subscribes, then reads nothing for S seconds (a slow
viewer: the server's queue for it fills), reads what is left for a moment and closes.
With --ready-file it creates PATH once it has subscribed (a caller starts the flight then).

Prints one JSON object: serverInfo's name, the advertised channels {topic: {schemaName,
encoding, schemaEncoding}}, per subscribed topic the messages received, the first and last
log times, the median log-time step between consecutive messages, and what the decoded
messages hold (as mcap_check.py summarises them: FrameTransforms frames; SceneUpdate entity
ids and primitive counts; JSON channels: the last message, as `last`). Exit 0 when every topic got
its messages (or, with --stall, when the connection was used and closed), 1 otherwise.
"""

import argparse
import asyncio
import base64
import json
import statistics
import struct
import sys

import websockets
from mcap_check import protobuf_message_class, summarise_protobuf as summarise

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
SCENE_TOPICS = "/scene/tf,/scene/static,/scene/dynamic,/scene/targets"
JSON = object()  # the decoder of JSON channels


def protobuf_class(name, schema_b64):
    return protobuf_message_class(name, base64.b64decode(schema_b64))


async def run(args):
    topics = [t for t in args.topics.split(",") if t]
    needs = {t: args.messages for t in topics}
    for item in args.need:
        topic, _, n = item.partition("=")
        needs[topic] = int(n)
    report = {"server": None, "advertised": {}, "received": {}, "errors": []}
    channels = {}  # channel id -> advertise entry
    subscribed = {}  # subscription id -> (topic, decoder)
    times = {}
    async with websockets.connect(args.url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        report["subprotocol"] = ws.subprotocol
        if ws.subprotocol not in SUBPROTOCOLS:
            report["errors"].append(f"server chose subprotocol {ws.subprotocol!r}")
            return report

        async def advertise_until_all():
            while not all(any(c["topic"] == t for c in channels.values()) for t in topics):
                raw = await ws.recv()
                if isinstance(raw, bytes):
                    continue
                msg = json.loads(raw)
                if msg.get("op") == "serverInfo":
                    report["server"] = msg.get("name")
                elif msg.get("op") == "advertise":
                    for c in msg["channels"]:
                        channels[c["id"]] = c
                        report["advertised"][c["topic"]] = {
                            "schemaName": c.get("schemaName"),
                            "encoding": c.get("encoding"),
                            "schemaEncoding": c.get("schemaEncoding"),
                        }

        await asyncio.wait_for(advertise_until_all(), args.timeout)
        subscriptions = []
        for sid, (cid, c) in enumerate(sorted((cid, c) for cid, c in channels.items()
                                              if c["topic"] in topics), start=1):
            decoder = None
            if c.get("encoding") == "protobuf":
                decoder = protobuf_class(c["schemaName"], c["schema"])
            elif c.get("encoding") == "json":
                decoder = JSON
            subscribed[sid] = (c["topic"], decoder)
            subscriptions.append({"id": sid, "channelId": cid})
            report["received"][c["topic"]] = {"count": 0}
            times[c["topic"]] = []
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
        if args.ready_file:
            with open(args.ready_file, "w") as f:
                f.write("subscribed\n")

        if args.stall > 0:
            await asyncio.sleep(args.stall)
            end = asyncio.get_running_loop().time() + 1.0
            try:
                while asyncio.get_running_loop().time() < end:
                    raw = await asyncio.wait_for(ws.recv(), 1.0)
                    if isinstance(raw, bytes) and raw[:1] == b"\x01":
                        sid = struct.unpack_from("<I", raw, 1)[0]
                        if sid in subscribed:
                            report["received"][subscribed[sid][0]]["count"] += 1
            except (asyncio.TimeoutError, websockets.ConnectionClosed):
                pass
            report["stalled_s"] = args.stall
            return report

        async def read_until_enough():
            while any(report["received"][t]["count"] < needs[t] for t in report["received"]):
                raw = await ws.recv()
                if not isinstance(raw, bytes) or raw[:1] != b"\x01":
                    continue
                sid, log_time = struct.unpack_from("<IQ", raw, 1)
                if sid not in subscribed:
                    continue
                topic, decoder = subscribed[sid]
                entry = report["received"][topic]
                entry["count"] += 1
                times[topic].append(log_time)
                if decoder is JSON:
                    try:
                        entry["last"] = json.loads(raw[13:])
                    except ValueError as e:
                        report["errors"].append(f"{topic}: not JSON: {e}")
                elif decoder is not None:
                    try:
                        summarise(entry, decoder.FromString(raw[13:]))
                    except Exception as e:
                        report["errors"].append(f"{topic}: does not decode: {e}")

        try:
            await asyncio.wait_for(read_until_enough(), args.timeout)
        except asyncio.TimeoutError:
            report["errors"].append("timed out before every topic had its messages")
    for topic, ts in times.items():
        entry = report["received"][topic]
        if ts:
            entry["first_log_time_ns"], entry["last_log_time_ns"] = ts[0], ts[-1]
        steps = [b - a for a, b in zip(ts, ts[1:])]
        if steps:
            entry["median_step_ns"] = statistics.median(steps)
    return report


def main(argv):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("url")
    p.add_argument("--topics", default=SCENE_TOPICS)
    p.add_argument("--messages", type=int, default=50)
    p.add_argument("--need", action="append", default=[], metavar="TOPIC=N")
    p.add_argument("--stall", type=float, default=0.0)
    p.add_argument("--timeout", type=float, default=60.0)
    p.add_argument("--ready-file", default=None)
    args = p.parse_args(argv)
    try:
        report = asyncio.run(run(args))
    except (OSError, asyncio.TimeoutError, websockets.WebSocketException) as e:
        report = {"errors": [f"{type(e).__name__}: {e}"]}
    print(json.dumps(report))
    ok = not report.get("errors") and (args.stall > 0 or bool(report.get("received")))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
