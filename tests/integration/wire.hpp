#pragma once
// Talking to proximad with the generated stub directly: for requests the client library would
// never produce (truncated buffers, NaN, unknown ids, oversized messages), for the health service
// (no generated stub in the project: a generic call with hand-encoded bytes) and for checks that
// look at the wire format itself.

#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>

#include <chrono>
#include <cstring>
#include <future>
#include <memory>
#include <string>
#include <vector>

#include "proxima/scene.hpp"
#include "proxima/v1/proxima.grpc.pb.h"

namespace proxima::test {

inline std::shared_ptr<grpc::Channel> make_channel(const std::string& address) {
    grpc::ChannelArguments args;
    // Larger than any daemon limit used in the tests: the daemon's limit is what is under test.
    args.SetMaxReceiveMessageSize(512 << 20);
    args.SetMaxSendMessageSize(512 << 20);
    // A fresh connection per channel, so tests that close one do not disturb another.
    args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
    return grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args);
}

inline std::unique_ptr<v1::Proximity::Stub> make_stub(const std::string& address) {
    return v1::Proximity::NewStub(make_channel(address));
}

inline void deadline_in(grpc::ClientContext& context, std::chrono::milliseconds ms) {
    context.set_deadline(std::chrono::system_clock::now() + ms);
}

inline std::string float64_bytes(const std::vector<Vec3>& vertices) {
    std::string out(vertices.size() * 24, '\0');
    std::memcpy(out.data(), vertices.data(), out.size());
    return out;
}

inline std::string index_bytes(const std::vector<TriangleIndices>& triangles) {
    std::string out(triangles.size() * 12, '\0');
    std::memcpy(out.data(), triangles.data(), out.size());
    return out;
}

inline void set_vertices(const std::vector<Vec3>& vertices, v1::VertexBuffer* out) {
    out->set_type(v1::SCALAR_TYPE_FLOAT64);
    out->set_data(float64_bytes(vertices));
}

inline void set_mesh(const NamedMesh& mesh, v1::Mesh* out) {
    out->set_name(mesh.name);
    set_vertices(mesh.mesh.vertices, out->mutable_vertices());
    out->set_indices(index_bytes(mesh.mesh.triangles));
}

// grpc.health.v1.Health/Check for `service`: the ServingStatus number (1 SERVING, 2 NOT_SERVING)
// or -1 with the call's status code in `code`. HealthCheckRequest is field 1 (string);
// HealthCheckResponse is field 1 (enum): both small enough to encode by hand.
inline int health_check(const std::string& address, const std::string& service,
                        grpc::StatusCode* code = nullptr) {
    grpc::GenericStub stub(make_channel(address));
    std::string request;
    if (!service.empty()) {
        request.push_back(0x0a);
        request.push_back(static_cast<char>(service.size()));
        request += service;
    }
    grpc::Slice slice(request);
    grpc::ByteBuffer request_buffer(&slice, 1);
    grpc::ByteBuffer response_buffer;
    grpc::ClientContext context;
    deadline_in(context, std::chrono::seconds(5));
    std::promise<grpc::Status> done;
    stub.UnaryCall(&context, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request_buffer,
                   &response_buffer, [&](grpc::Status s) { done.set_value(std::move(s)); });
    const grpc::Status status = done.get_future().get();
    if (code != nullptr) {
        *code = status.error_code();
    }
    if (!status.ok()) {
        return -1;
    }
    std::vector<grpc::Slice> slices;
    if (!response_buffer.Dump(&slices).ok()) {
        return -1;
    }
    std::string bytes;
    for (const auto& s : slices) {
        bytes.append(reinterpret_cast<const char*>(s.begin()), s.size());
    }
    if (bytes.empty()) {
        return 0;  // UNKNOWN, the proto3 default
    }
    if (bytes.size() != 2 || bytes[0] != 0x08) {
        return -1;
    }
    return bytes[1];
}

}  // namespace proxima::test
