"""Explores a soundmap coordinator with gRPC server reflection only (no .proto files).

Usage: reflection_check.py HOST:PORT

With grpcio-reflection's descriptor database (reflection v1alpha) it lists the
services, resolves Monitoring.GetState to its request and response types, builds
those message classes from the reflected descriptors and calls GetState. It also
lists the services over reflection v1 (same messages, the v1 service name).
Prints one JSON object.
"""

import json
import sys

import grpc
from google.protobuf import descriptor_pool, message_factory
from grpc_reflection.v1alpha import reflection_pb2
from grpc_reflection.v1alpha.proto_reflection_descriptor_database import (
    ProtoReflectionDescriptorDatabase,
)


def list_v1(channel: grpc.Channel) -> list:
    call = channel.stream_stream(
        "/grpc.reflection.v1.ServerReflection/ServerReflectionInfo",
        request_serializer=reflection_pb2.ServerReflectionRequest.SerializeToString,
        response_deserializer=reflection_pb2.ServerReflectionResponse.FromString,
    )
    answers = call(iter([reflection_pb2.ServerReflectionRequest(list_services="")]), timeout=10)
    return sorted(s.name for a in answers for s in a.list_services_response.service)


def main() -> None:
    target = sys.argv[1]
    with grpc.insecure_channel(target) as channel:
        database = ProtoReflectionDescriptorDatabase(channel)
        services = sorted(database.get_services())
        pool = descriptor_pool.DescriptorPool(database)
        monitoring = pool.FindServiceByName("soundmap.v1.Monitoring")
        method = monitoring.FindMethodByName("GetState")
        request_class = message_factory.GetMessageClass(method.input_type)
        response_class = message_factory.GetMessageClass(method.output_type)
        get_state = channel.unary_unary(
            "/soundmap.v1.Monitoring/GetState",
            request_serializer=request_class.SerializeToString,
            response_deserializer=response_class.FromString,
        )
        state = get_state(request_class(), timeout=10)
        print(json.dumps({
            "services_v1alpha": services,
            "services_v1": list_v1(channel),
            "monitoring_methods": sorted(m.name for m in monitoring.methods),
            "get_state_input": method.input_type.full_name,
            "get_state_output": method.output_type.full_name,
            "get_state_robots": sorted(r.robot_id for r in state.robots),
            "robot_state_fields": [f.name for f in pool.FindMessageTypeByName("soundmap.v1.RobotState").fields],
        }))


if __name__ == "__main__":
    main()
