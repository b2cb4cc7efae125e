#!/usr/bin/env python3
"""Generates the Python gRPC stubs of soundmap.v1 from the repository's protos.

Usage: generate.py [OUT_DIR]   (default: ./generated beside this file)

Runs grpcio-tools' protoc on proto/soundmap/v1/*.proto. The stubs land in
OUT_DIR/soundmap/v1/{common,robot_link,monitoring}_pb2{,_grpc}.py; put OUT_DIR
on sys.path (soundmap_client.py does) and import soundmap.v1.monitoring_pb2.
"""

import glob
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
PROTO_ROOT = os.path.normpath(os.path.join(HERE, "..", "..", "proto"))


def generate(out_dir: str) -> None:
    from grpc_tools import protoc  # grpcio-tools
    import grpc_tools

    protos = sorted(glob.glob(os.path.join(PROTO_ROOT, "soundmap", "v1", "*.proto")))
    if not protos:
        sys.exit(f"no .proto files under {PROTO_ROOT}/soundmap/v1")
    os.makedirs(out_dir, exist_ok=True)
    well_known = os.path.join(os.path.dirname(grpc_tools.__file__), "_proto")
    args = ["protoc", f"-I{PROTO_ROOT}", f"-I{well_known}", f"--python_out={out_dir}",
            f"--grpc_python_out={out_dir}", *protos]
    if protoc.main(args) != 0:
        sys.exit(f"protoc failed on {', '.join(protos)}")


if __name__ == "__main__":
    generate(os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "generated")))
