"""Imports every client library the system tests use and prints its version."""

from importlib.metadata import version

import grpc  # noqa: F401
import grpc_reflection.v1alpha.reflection  # noqa: F401
import grpc_tools.protoc  # noqa: F401
import mcap.reader  # noqa: F401
import prometheus_client.parser  # noqa: F401
import rosbags.rosbag2  # noqa: F401
import websockets  # noqa: F401

for name in ["grpcio", "grpcio-tools", "grpcio-reflection", "mcap", "rosbags",
             "prometheus-client", "websockets"]:
    print(f"{name} {version(name)}")
