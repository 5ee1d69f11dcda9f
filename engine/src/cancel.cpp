#include "proxima/cancel.hpp"

#include <string>

namespace proxima {

Status stop_status(const CancelToken& cancel, std::string_view what) {
    if (cancel.expired()) {
        return {StatusCode::deadline_exceeded, std::string(what) + " stopped: deadline exceeded"};
    }
    return {StatusCode::cancelled, std::string(what) + " cancelled by the caller"};
}

}  // namespace proxima
