"""Watches a soundmap live view the way Foxglove does: a `websockets` client
speaking the Foxglove WebSocket protocol (`foxglove.websocket.v1`, which the
Foxglove SDK serves under the subprotocol name `foxglove.sdk.v1`) subscribes to every advertised channel and
decodes what arrives (protobuf with the advertised descriptor set, JSON).

usage: foxglove_live_check.py ws://HOST:PORT SECONDS

Prints one JSON object: per topic its schema and message count, and what was
decoded (frames of /tf, entity ids of the scene updates, fields of the quality
series, a decoded soundmap.v1.SourceEstimate). Exits 1 when it cannot connect.
"""

import asyncio
import base64
import json
import struct
import sys
import time

import websockets
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory


def message_class(schema_name, schema_b64, pools):
    if schema_name not in pools:
        fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
        pool = descriptor_pool.DescriptorPool()
        for f in fds.file:
            try:
                pool.Add(f)
            except TypeError:
                pool.AddSerializedFile(f.SerializeToString())
        pools[schema_name] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))
    return pools[schema_name]


async def connect(url, deadline):
    while True:
        try:
            # Offered as current Foxglove clients do: the SDK's name for the protocol
            # (identical to foxglove.websocket.v1) and the original name.
            return await websockets.connect(url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
                                            max_size=None)
        except OSError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.1)


async def watch(url, seconds):
    deadline = time.monotonic() + 30
    ws = await connect(url, deadline)
    out = {"subprotocol": ws.subprotocol, "server": None, "topics": {}, "time_messages": 0,
           "frames": [], "entity_ids": [], "quality_fields": [], "rse_m": [], "estimate": None,
           "observation_robots": [], "log_times_monotonic": True}
    channels, subs, pools = {}, {}, {}
    next_sub = 1
    last_time = {}
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            raw = await asyncio.wait_for(ws.recv(), timeout=max(0.01, end - time.monotonic()))
        except asyncio.TimeoutError:
            break
        except websockets.ConnectionClosed:
            break
        if isinstance(raw, str):
            msg = json.loads(raw)
            if msg["op"] == "serverInfo":
                out["server"] = msg["name"]
                out["capabilities"] = msg.get("capabilities", [])
            elif msg["op"] == "advertise":
                new = []
                for ch in msg["channels"]:
                    channels[ch["id"]] = ch
                    subs[next_sub] = ch["id"]
                    new.append({"id": next_sub, "channelId": ch["id"]})
                    out["topics"].setdefault(ch["topic"], {"encoding": ch["encoding"],
                                                           "schema": ch["schemaName"], "count": 0})
                    next_sub += 1
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
            continue
        op = raw[0]
        if op == 2:
            out["time_messages"] += 1
            continue
        if op != 1:
            continue
        sub, log_time = struct.unpack_from("<IQ", raw, 1)
        payload = raw[13:]
        ch = channels[subs[sub]]
        topic = ch["topic"]
        out["topics"][topic]["count"] += 1
        if log_time < last_time.get(topic, 0):
            out["log_times_monotonic"] = False
        last_time[topic] = log_time
        if ch["encoding"] == "json":
            value = json.loads(payload)
            if topic == "/soundmap/quality":
                out["quality_fields"] = sorted(set(out["quality_fields"]) | set(value))
                if "rse_m" in value:
                    out["rse_m"].append(value["rse_m"])
            continue
        decoded = message_class(ch["schemaName"], ch["schema"], pools).FromString(payload)
        if topic == "/tf":
            for t in decoded.transforms:
                pair = [t.parent_frame_id, t.child_frame_id]
                if pair not in out["frames"]:
                    out["frames"].append(pair)
        elif ch["schemaName"] == "foxglove.SceneUpdate":
            for e in decoded.entities:
                if e.id not in out["entity_ids"]:
                    out["entity_ids"].append(e.id)
        elif topic == "/soundmap/estimates" and decoded.HasField("position_in_map_m"):
            p = decoded.position_in_map_m
            out["estimate"] = {"source_id": decoded.source_id, "x": p.x, "y": p.y, "z": p.z,
                               "robots": list(decoded.robots)}
        elif topic.endswith("/observation"):
            robot = topic.split("/")[3]
            if robot not in out["observation_robots"]:
                out["observation_robots"].append(robot)
    await ws.close()
    return out


def main():
    url, seconds = sys.argv[1], float(sys.argv[2])
    try:
        out = asyncio.run(watch(url, seconds))
    except OSError as e:
        print(f"cannot connect to {url}: {e}", file=sys.stderr)
        sys.exit(1)
    out["rse_m"] = out["rse_m"][-20:]
    print(json.dumps(out))


if __name__ == "__main__":
    main()
