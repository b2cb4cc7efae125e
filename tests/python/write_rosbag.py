"""Writes a ROS 2 bag (rosbag2, MCAP storage, CDR) from soundmap-sim recordings.

Usage:
  write_rosbag.py --out BAG_DIR --origin-ns NS [--format F32LE|S16LE|S32LE]
                  [--chunk-frames N] [--variant normal|gap|bad-definition]
                  --robot ID:WAV:TUM [--robot ...]
                  [--truth-in source.tum --truth-out truth.tum]

For each robot the bag holds, as a robot running audio_common and a SLAM stack
would record them:
- /ID/audio/audio_stamped  audio_common_msgs/msg/AudioDataStamped, chunks of
  N frames, header stamp = the chunk's first sample (origin + frame / rate);
- /ID/audio/audio_info     audio_common_msgs/msg/AudioInfo, once;
- /tf_static: map -> ID/odom (a fixed, non-trivial transform);
- /tf: ID/odom -> ID/base_link at every TUM pose, so that map -> ID/odom ->
  ID/base_link is the recorded map_from_base.
Recording times (seconds) are mapped to bag stamps as origin + t. The truth
trajectory, when given, is rewritten with stamps in Unix seconds (the bag's
clock). Variants: `gap` drops the 10th audio chunk of the first robot;
`bad-definition` declares AudioDataStamped with a different field layout.
"""

import argparse
import math
import struct

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

AUDIO_DATA = "uint8[] data\n"
AUDIO_DATA_STAMPED = "std_msgs/Header header\naudio_common_msgs/AudioData audio\n"
AUDIO_DATA_STAMPED_OTHER = "std_msgs/Header header\nfloat32[] samples\nuint32 rate\n"
AUDIO_INFO = ("uint8 channels\nuint32 sample_rate\nstring sample_format\nuint32 bitrate\n"
              "string coding_format\n")
# map -> ID/odom: 0.5 rad about z and (1, -2, 0) m.
ODOM_YAW = 0.5
ODOM_T = (1.0, -2.0, 0.0)


def read_wav(path: str):
    """Channels, rate and float32 frames (n, channels) of a RIFF WAVE file."""
    with open(path, "rb") as f:
        data = f.read()
    assert data[:4] == b"RIFF" and data[8:12] == b"WAVE", f"{path}: not a WAVE file"
    pos, fmt, samples = 12, None, None
    while pos + 8 <= len(data):
        cid, size = data[pos:pos + 4], struct.unpack("<I", data[pos + 4:pos + 8])[0]
        body = data[pos + 8:pos + 8 + size]
        if cid == b"fmt ":
            tag, channels, rate = struct.unpack("<HHI", body[:8])
            bits = struct.unpack("<H", body[14:16])[0]
            if tag == 0xFFFE:
                tag = struct.unpack("<H", body[24:26])[0]
            fmt = (tag, channels, rate, bits)
        elif cid == b"data":
            samples = body
        pos += 8 + size + (size & 1)
    tag, channels, rate, bits = fmt
    if tag == 3 and bits == 32:
        frames = np.frombuffer(samples, dtype="<f4")
    elif tag == 1 and bits == 16:
        frames = np.frombuffer(samples, dtype="<i2").astype(np.float32) / 32768.0
    else:
        raise SystemExit(f"{path}: WAVE format {tag}/{bits} bits not handled")
    return channels, rate, frames.reshape(-1, channels)


def read_tum(path: str):
    rows = []
    for line in open(path, encoding="utf-8"):
        line = line.split("#")[0].strip()
        if line:
            rows.append([float(v) for v in line.split()])
    return rows


def encode(frames: np.ndarray, fmt: str) -> bytes:
    if fmt == "F32LE":
        return frames.astype("<f4").tobytes()
    if fmt == "S16LE":
        return np.clip(np.round(frames * 32768.0), -32768, 32767).astype("<i2").tobytes()
    if fmt == "S32LE":
        return np.clip(np.round(frames.astype(np.float64) * 2147483648.0), -2147483648,
                       2147483647).astype("<i4").tobytes()
    raise SystemExit(f"unknown format {fmt}")


def quat_mul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def rotate(q, v):
    p = quat_mul(quat_mul(q, (v[0], v[1], v[2], 0.0)), (-q[0], -q[1], -q[2], q[3]))
    return p[:3]


def odom_from_map():
    """Inverse of map_from_odom (yaw ODOM_YAW, translation ODOM_T)."""
    q_inv = (0.0, 0.0, -math.sin(ODOM_YAW / 2), math.cos(ODOM_YAW / 2))
    t = rotate(q_inv, ODOM_T)
    return q_inv, (-t[0], -t[1], -t[2])


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--out", required=True)
    p.add_argument("--origin-ns", type=int, required=True)
    p.add_argument("--format", default="F32LE")
    p.add_argument("--chunk-frames", type=int, default=1024)
    p.add_argument("--variant", default="normal")
    p.add_argument("--robot", action="append", required=True)
    p.add_argument("--truth-in")
    p.add_argument("--truth-out")
    args = p.parse_args()

    store = get_typestore(Stores.ROS2_HUMBLE)
    stamped = AUDIO_DATA_STAMPED_OTHER if args.variant == "bad-definition" else AUDIO_DATA_STAMPED
    types = {}
    types.update(get_types_from_msg(AUDIO_DATA, "audio_common_msgs/msg/AudioData"))
    types.update(get_types_from_msg(stamped, "audio_common_msgs/msg/AudioDataStamped"))
    types.update(get_types_from_msg(AUDIO_INFO, "audio_common_msgs/msg/AudioInfo"))
    store.register(types)
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    TFMessage = store.types["tf2_msgs/msg/TFMessage"]
    TransformStamped = store.types["geometry_msgs/msg/TransformStamped"]
    Transform = store.types["geometry_msgs/msg/Transform"]
    Vector3 = store.types["geometry_msgs/msg/Vector3"]
    Quaternion = store.types["geometry_msgs/msg/Quaternion"]
    AudioData = store.types["audio_common_msgs/msg/AudioData"]
    AudioDataStamped = store.types["audio_common_msgs/msg/AudioDataStamped"]
    AudioInfo = store.types["audio_common_msgs/msg/AudioInfo"]

    def header(ns: int, frame: str):
        return Header(stamp=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id=frame)

    def transform(ns, parent, child, t, q):
        return TransformStamped(
            header=header(ns, parent), child_frame_id=child,
            transform=Transform(translation=Vector3(x=t[0], y=t[1], z=t[2]),
                                rotation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])))

    messages = []  # (log time ns, connection key, message, type)
    q_om, t_om = odom_from_map()
    statics = []
    for k, spec in enumerate(args.robot):
        rid, wav, tum = spec.split(":")
        channels, rate, frames = read_wav(wav)
        chunk = args.chunk_frames
        info = AudioInfo(channels=channels, sample_rate=rate, sample_format=args.format,
                         bitrate=0, coding_format="wave")
        messages.append((args.origin_ns, f"/{rid}/audio/audio_info", info, "audio_common_msgs/msg/AudioInfo"))
        for i, start in enumerate(range(0, len(frames), chunk)):
            if args.variant == "gap" and k == 0 and i == 10:
                continue
            ns = args.origin_ns + round(start * 1e9 / rate)
            block = frames[start:start + chunk]
            if args.variant == "bad-definition":
                msg = AudioDataStamped(header=header(ns, f"{rid}/array"),
                                       samples=block.reshape(-1).astype(np.float32), rate=rate)
            else:
                data = np.frombuffer(encode(block, args.format), dtype=np.uint8)
                msg = AudioDataStamped(header=header(ns, f"{rid}/array"), audio=AudioData(data=data))
            messages.append((ns, f"/{rid}/audio/audio_stamped", msg, "audio_common_msgs/msg/AudioDataStamped"))
        statics.append(transform(args.origin_ns, "map", f"{rid}/odom", ODOM_T,
                                 (0.0, 0.0, math.sin(ODOM_YAW / 2), math.cos(ODOM_YAW / 2))))
        for t, x, y, z, qx, qy, qz, qw in read_tum(tum):
            ns = args.origin_ns + round(t * 1e9)
            # odom_from_base = odom_from_map * map_from_base
            q = quat_mul(q_om, (qx, qy, qz, qw))
            r = rotate(q_om, (x, y, z))
            pos = (r[0] + t_om[0], r[1] + t_om[1], r[2] + t_om[2])
            tf = TFMessage(transforms=[transform(ns, f"{rid}/odom", f"{rid}/base_link", pos, q)])
            messages.append((ns, "/tf", tf, "tf2_msgs/msg/TFMessage"))
    messages.append((args.origin_ns, "/tf_static", TFMessage(transforms=statics), "tf2_msgs/msg/TFMessage"))
    messages.sort(key=lambda m: m[0])

    with Writer(args.out, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for ns, topic, msg, msgtype in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], ns, store.serialize_cdr(msg, msgtype))

    if args.truth_in and args.truth_out:
        with open(args.truth_out, "w", encoding="utf-8") as out:
            for line in open(args.truth_in, encoding="utf-8"):
                fields = line.split("#")[0].split()
                if not fields:
                    continue
                ns = args.origin_ns + round(float(fields[0]) * 1e9)
                out.write(f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d} {' '.join(fields[1:])}\n")
    print(f"wrote {len(messages)} messages to {args.out}")


if __name__ == "__main__":
    main()
