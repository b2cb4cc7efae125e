"""Reads a soundmap recording with the `mcap` Python reader, as a user's
tools would, and reports what is in it.

usage: mcap_check.py FILE.mcap

Prints one JSON object: the profile, schemas (name, encoding), channels
(topic, message encoding, schema), message counts per topic, the chunk
compressions, whether log times never go back in file order, and decoded
samples (a soundmap.v1.Observation and SourceEstimate via the recorded
protobuf descriptor set, a foxglove.SceneUpdate).
"""

import json
import sys

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

_classes = {}


def decode(schema, data):
    if schema.name not in _classes:
        fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
        pool = descriptor_pool.DescriptorPool()
        for f in fds.file:
            pool.AddSerializedFile(f.SerializeToString())
        _classes[schema.name] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
    return _classes[schema.name].FromString(data)


def main():
    path = sys.argv[1]
    out = {"schemas": {}, "channels": {}, "counts": {}, "compression": [], "monotonic": True,
           "first_log_time": None, "last_log_time": None, "observation": None, "estimate": None,
           "scene_entities": []}
    with open(path, "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        out["profile"] = header.profile
        summary = reader.get_summary()
        out["compression"] = sorted({c.compression for c in summary.chunk_indexes.values()}
                                    if isinstance(summary.chunk_indexes, dict)
                                    else {c.compression for c in summary.chunk_indexes})
        out["statistics_message_count"] = summary.statistics.message_count
        last = 0
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema is not None:
                out["schemas"][schema.name] = schema.encoding
            out["channels"][channel.topic] = {"encoding": channel.message_encoding,
                                              "schema": schema.name if schema else ""}
            out["counts"][channel.topic] = out["counts"].get(channel.topic, 0) + 1
            if message.log_time < last:
                out["monotonic"] = False
            last = message.log_time
            if out["first_log_time"] is None:
                out["first_log_time"] = message.log_time
            out["last_log_time"] = message.log_time
            if channel.topic.endswith("/observation") and out["observation"] is None:
                # The first observation that heard something (a robot's first hops may be silent).
                o = decode(schema, message.data)
                if len(o.doas) > 0:
                    out["observation"] = {"topic": channel.topic, "stamp_ns": o.stamp_ns, "doas": len(o.doas)}
            elif channel.topic == "/soundmap/estimates" and o_is_positioned(schema, message.data):
                e = decode(schema, message.data)
                p = e.position_in_map_m
                out["estimate"] = {"source_id": e.source_id, "x": p.x, "y": p.y, "z": p.z}
            elif schema is not None and schema.name == "foxglove.SceneUpdate":
                for e in decode(schema, message.data).entities:
                    if e.id not in out["scene_entities"]:
                        out["scene_entities"].append(e.id)
    print(json.dumps(out))


def o_is_positioned(schema, data):
    return decode(schema, data).HasField("position_in_map_m")


if __name__ == "__main__":
    main()
