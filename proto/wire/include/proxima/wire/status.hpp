#pragma once
// The one mapping between engine status codes and gRPC status codes, used by the daemon (to
// answer) and by the client (to read answers). Every engine code has a gRPC namesake; the table
// lists each once, in the enum's order, which the static_assert below and tests/wire check.

#include <array>
#include <cstddef>
#include <optional>

#include <grpcpp/support/status.h>

#include "proxima/status.hpp"

namespace proxima::wire {

struct StatusCodeMapping {
    StatusCode engine;
    grpc::StatusCode grpc;
};

inline constexpr std::array<StatusCodeMapping, 12> STATUS_CODES = {{
    {StatusCode::ok, grpc::StatusCode::OK},
    {StatusCode::invalid_argument, grpc::StatusCode::INVALID_ARGUMENT},
    {StatusCode::not_found, grpc::StatusCode::NOT_FOUND},
    {StatusCode::failed_precondition, grpc::StatusCode::FAILED_PRECONDITION},
    {StatusCode::resource_exhausted, grpc::StatusCode::RESOURCE_EXHAUSTED},
    {StatusCode::cancelled, grpc::StatusCode::CANCELLED},
    {StatusCode::deadline_exceeded, grpc::StatusCode::DEADLINE_EXCEEDED},
    {StatusCode::unavailable, grpc::StatusCode::UNAVAILABLE},
    {StatusCode::internal, grpc::StatusCode::INTERNAL},
    {StatusCode::data_loss, grpc::StatusCode::DATA_LOSS},
    {StatusCode::unauthenticated, grpc::StatusCode::UNAUTHENTICATED},
    {StatusCode::permission_denied, grpc::StatusCode::PERMISSION_DENIED},
}};

// Entry k maps engine code k, and the last engine code is the table's last entry (a code added
// after permission_denied must be added here too: tests/wire walks status_code_name to be sure).
constexpr bool status_table_in_enum_order() {
    for (std::size_t i = 0; i < STATUS_CODES.size(); ++i) {
        if (static_cast<std::size_t>(STATUS_CODES[i].engine) != i) {
            return false;
        }
    }
    return STATUS_CODES.back().engine == StatusCode::permission_denied;
}
static_assert(status_table_in_enum_order(), "STATUS_CODES must list every StatusCode in order");

grpc::StatusCode to_grpc_code(StatusCode code);
// None for the gRPC codes the engine has no name for (UNKNOWN, ALREADY_EXISTS, ABORTED,
// OUT_OF_RANGE, UNIMPLEMENTED).
std::optional<StatusCode> from_grpc_code(grpc::StatusCode code);
// The gRPC name of any gRPC code ("UNIMPLEMENTED"); "UNKNOWN" for values gRPC does not define.
const char* grpc_code_name(grpc::StatusCode code);

// Engine status -> gRPC status; the message goes through unchanged.
grpc::Status to_grpc(const Status& status);
// gRPC status -> engine status, one-to-one by code. Codes the engine has no name for become
// internal, their gRPC name kept in front of the message ("gRPC UNIMPLEMENTED: ...") so nothing
// is lost.
Status from_grpc(const grpc::Status& status);

}  // namespace proxima::wire
