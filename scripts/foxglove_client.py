#!/usr/bin/env python3
"""An independent Foxglove WebSocket client for povins' tests: connects to URL with the
`foxglove.sdk.v1` subprotocol (Python `websockets`), subscribes to every advertised channel,
decodes each message with the protobuf schema the server advertised (Python `protobuf`, from
the FileDescriptorSet), and prints one JSON line per message until the server closes the
connection or SECONDS pass.

Usage: foxglove_client.py URL SECONDS
"""
import asyncio
import base64
import json
import struct
import sys
import time

import websockets
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory


def message_class(schema_name, schema_b64):
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def pose(p):
    return [p.position.x, p.position.y, p.position.z,
            p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w]


def describe(topic, msg):
    if topic == "/povins/pose":
        return {"stamp": msg.timestamp.seconds * 10**9 + msg.timestamp.nanos,
                "frame": msg.frame_id, "pose": pose(msg.pose)}
    if topic == "/povins/path":
        return {"frame": msg.frame_id, "n": len(msg.poses),
                "last": pose(msg.poses[-1]) if msg.poses else None}
    if topic == "/povins/landmarks":
        spheres = [s for e in msg.entities for s in e.spheres]
        return {"frame": msg.entities[0].frame_id if msg.entities else None,
                "n": len(spheres),
                "lidar": sum(1 for s in spheres if s.color.r == 1.0 and s.color.b == 0.0)}
    return {}


async def main(url, seconds):
    subs, next_id = {}, 1
    deadline = time.monotonic() + seconds
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
        print(json.dumps({"op": "connected", "subprotocol": ws.subprotocol}), flush=True)
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                print(json.dumps({"op": "timeout"}), flush=True)
                return
            try:
                m = await asyncio.wait_for(ws.recv(), timeout=left)
            except asyncio.TimeoutError:
                continue
            except websockets.ConnectionClosed:
                print(json.dumps({"op": "closed"}), flush=True)
                return
            if isinstance(m, str):
                j = json.loads(m)
                if j.get("op") == "advertise":
                    new = []
                    for c in j["channels"]:
                        assert c["encoding"] == "protobuf", c
                        assert c["schemaEncoding"] == "protobuf", c
                        cls = message_class(c["schemaName"], c["schema"])
                        subs[next_id] = (c["topic"], c["schemaName"], cls)
                        new.append({"id": next_id, "channelId": c["id"]})
                        next_id += 1
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                print(json.dumps({"op": j.get("op")}), flush=True)
            elif m and m[0] == 1:
                sub, log_time = struct.unpack_from("<IQ", m, 1)
                topic, schema, cls = subs[sub]
                msg = cls.FromString(m[13:])
                out = {"topic": topic, "schema": schema, "log_time": log_time}
                out.update(describe(topic, msg))
                print(json.dumps(out), flush=True)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], float(sys.argv[2])))
