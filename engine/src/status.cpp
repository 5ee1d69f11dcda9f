#include "proxima/status.hpp"

namespace proxima {

const char* status_code_name(StatusCode code) {
    switch (code) {
        case StatusCode::ok:
            return "OK";
        case StatusCode::invalid_argument:
            return "INVALID_ARGUMENT";
        case StatusCode::not_found:
            return "NOT_FOUND";
        case StatusCode::failed_precondition:
            return "FAILED_PRECONDITION";
        case StatusCode::resource_exhausted:
            return "RESOURCE_EXHAUSTED";
        case StatusCode::cancelled:
            return "CANCELLED";
        case StatusCode::deadline_exceeded:
            return "DEADLINE_EXCEEDED";
        case StatusCode::unavailable:
            return "UNAVAILABLE";
        case StatusCode::internal:
            return "INTERNAL";
        case StatusCode::data_loss:
            return "DATA_LOSS";
        case StatusCode::unauthenticated:
            return "UNAUTHENTICATED";
        case StatusCode::permission_denied:
            return "PERMISSION_DENIED";
    }
    return "UNKNOWN";
}

std::string Status::to_string() const {
    if (ok()) {
        return "OK";
    }
    return std::string(status_code_name(m_code)) + ": " + m_message;
}

}  // namespace proxima
