#!/usr/bin/env python3
"""A soundmap operator client in Python: watch estimates, print the sound map,
switch active positioning.

    python soundmap_client.py --target 127.0.0.1:50051 watch --count 10
    python soundmap_client.py --target 127.0.0.1:50051 map
    python soundmap_client.py --target 127.0.0.1:50051 positioning --enable --theta-min 40 --theta-max 140

Stubs come from the repository's protos (generate.py), generated into
./generated on first use unless --stubs names a directory that has them.
--token sends `authorization: Bearer TOKEN` (an operator token of [auth]);
--json prints one JSON object a line instead of text.
"""

import argparse
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))


def load_stubs(stubs_dir: str):
    if not os.path.exists(os.path.join(stubs_dir, "soundmap", "v1", "monitoring_pb2_grpc.py")):
        sys.path.insert(0, HERE)
        from generate import generate

        generate(stubs_dir)
    sys.path.insert(0, stubs_dir)
    from soundmap.v1 import monitoring_pb2, monitoring_pb2_grpc

    return monitoring_pb2, monitoring_pb2_grpc


def vec(v) -> list:
    return [round(v.x, 3), round(v.y, 3), round(v.z, 3)]


def watch(stub, pb, args, metadata) -> None:
    seen = 0
    for e in stub.WatchEstimates(pb.WatchEstimatesRequest(), metadata=metadata, timeout=args.timeout):
        position = vec(e.position_in_map_m) if e.HasField("position_in_map_m") else None
        row = {"source_id": e.source_id, "stamp_ns": e.stamp_ns, "position_m": position,
               "trusted": e.trusted, "theta_deg": round(e.theta_deg, 2), "gdop": round(e.gdop, 3),
               "robots": list(e.robots)}
        if args.json:
            print(json.dumps(row), flush=True)
        else:
            print(f"source {e.source_id}: {position} m, trusted {e.trusted}, "
                  f"θ {e.theta_deg:.1f}°, GDOP {e.gdop:.2f}, robots {', '.join(e.robots)}", flush=True)
        seen += 1
        if args.count and seen >= args.count:
            return


def sound_map(stub, pb, args, metadata) -> None:
    state = stub.GetState(pb.GetStateRequest(), metadata=metadata, timeout=args.timeout)
    liveness = pb.Liveness.Name
    robots = [{"robot_id": r.robot_id, "liveness": liveness(r.liveness),
               "position_m": vec(r.map_from_base.translation_m) if r.HasField("map_from_base") else None,
               "observations_accepted": r.observations_accepted} for r in state.robots]
    sources = [{"source_id": s.source_id, "position_m": vec(s.position_in_map_m), "trusted": s.trusted}
               for s in state.sources if s.HasField("position_in_map_m")]
    mapped = [{"source_id": m.source_id, "position_m": vec(m.position_m), "live": m.live}
              for m in state.sound_map]
    positioning = state.active_positioning
    summary = {"robots": robots, "sources": sources, "sound_map": mapped,
               "active_positioning": {"enabled": positioning.enabled,
                                      "theta_min_deg": positioning.theta_min_deg,
                                      "theta_max_deg": positioning.theta_max_deg}}
    if args.json:
        print(json.dumps(summary))
        return
    print(f"{len(robots)} robot(s):")
    for r in robots:
        print(f"  {r['robot_id']}: {r['liveness']} at {r['position_m']} m, "
              f"{r['observations_accepted']} observations")
    print(f"{len(sources)} source estimate(s):")
    for s in sources:
        print(f"  source {s['source_id']}: {s['position_m']} m, trusted {s['trusted']}")
    print(f"sound map: {len(mapped)} source(s)")
    for m in mapped:
        print(f"  source {m['source_id']}: {m['position_m']} m, {'live' if m['live'] else 'remembered'}")
    print(f"active positioning: {'on' if positioning.enabled else 'off'}, "
          f"θ band [{positioning.theta_min_deg:.0f}°, {positioning.theta_max_deg:.0f}°]")


def positioning(stub, pb, args, metadata) -> None:
    request = pb.SetActivePositioningRequest()
    if args.enable is not None:
        request.enabled = args.enable
    if args.theta_min is not None:
        request.theta_min_deg = args.theta_min
    if args.theta_max is not None:
        request.theta_max_deg = args.theta_max
    answer = stub.SetActivePositioning(request, metadata=metadata, timeout=args.timeout)
    row = {"enabled": answer.enabled, "theta_min_deg": answer.theta_min_deg,
           "theta_max_deg": answer.theta_max_deg}
    if args.json:
        print(json.dumps(row))
    else:
        print(f"active positioning {'on' if answer.enabled else 'off'}, "
              f"θ band [{answer.theta_min_deg:.0f}°, {answer.theta_max_deg:.0f}°]")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--target", default="127.0.0.1:50051", help="coordinator HOST:PORT")
    parser.add_argument("--token", help="operator bearer token")
    parser.add_argument("--stubs", default=os.path.join(HERE, "generated"), help="generated stubs directory")
    parser.add_argument("--timeout", type=float, default=None, help="call deadline, seconds")
    parser.add_argument("--json", action="store_true", help="JSON output")
    commands = parser.add_subparsers(dest="command", required=True)
    w = commands.add_parser("watch", help="print estimates as they are published")
    w.add_argument("--count", type=int, default=0, help="stop after this many (0: never)")
    commands.add_parser("map", help="print robots, source estimates and the sound map")
    p = commands.add_parser("positioning", help="switch active positioning and set its θ band")
    switch = p.add_mutually_exclusive_group()
    switch.add_argument("--enable", dest="enable", action="store_true", default=None)
    switch.add_argument("--disable", dest="enable", action="store_false")
    p.add_argument("--theta-min", type=float)
    p.add_argument("--theta-max", type=float)
    args = parser.parse_args()

    import grpc

    pb, pb_grpc = load_stubs(os.path.abspath(args.stubs))
    metadata = [("authorization", f"Bearer {args.token}")] if args.token else None
    with grpc.insecure_channel(args.target) as channel:
        stub = pb_grpc.MonitoringStub(channel)
        try:
            {"watch": watch, "map": sound_map, "positioning": positioning}[args.command](
                stub, pb, args, metadata)
        except grpc.RpcError as e:
            sys.exit(f"{args.command}: {e.code().name}: {e.details()}")


if __name__ == "__main__":
    main()
