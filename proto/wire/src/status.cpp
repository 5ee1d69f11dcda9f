#include "proxima/wire/status.hpp"

#include <string>

namespace proxima::wire {

grpc::StatusCode to_grpc_code(StatusCode code) {
    const auto index = static_cast<std::size_t>(code);
    return index < STATUS_CODES.size() ? STATUS_CODES[index].grpc : grpc::StatusCode::UNKNOWN;
}

std::optional<StatusCode> from_grpc_code(grpc::StatusCode code) {
    for (const auto& entry : STATUS_CODES) {
        if (entry.grpc == code) {
            return entry.engine;
        }
    }
    return std::nullopt;
}

const char* grpc_code_name(grpc::StatusCode code) {
    // The engine's names are gRPC's for the codes they share.
    if (auto engine = from_grpc_code(code)) {
        return status_code_name(*engine);
    }
    switch (code) {
        case grpc::StatusCode::ALREADY_EXISTS:
            return "ALREADY_EXISTS";
        case grpc::StatusCode::ABORTED:
            return "ABORTED";
        case grpc::StatusCode::OUT_OF_RANGE:
            return "OUT_OF_RANGE";
        case grpc::StatusCode::UNIMPLEMENTED:
            return "UNIMPLEMENTED";
        default:
            return "UNKNOWN";
    }
}

grpc::Status to_grpc(const Status& status) {
    if (status.ok()) {
        return grpc::Status::OK;
    }
    return {to_grpc_code(status.code()), status.message()};
}

Status from_grpc(const grpc::Status& status) {
    if (status.ok()) {
        return {};
    }
    if (auto engine = from_grpc_code(status.error_code())) {
        return {*engine, status.error_message()};
    }
    return {StatusCode::internal, std::string("gRPC ") + grpc_code_name(status.error_code()) +
                                      ": " + status.error_message()};
}

}  // namespace proxima::wire
