#pragma once
// Status and StatusOr at the engine boundary: every error carries a code the server maps to a
// gRPC status once, and a message a user can act on (which object, which index, what limit).
// The engine never throws across its public API for bad input; exceptions are reserved for
// programming errors and std::bad_alloc.

#include <optional>
#include <string>
#include <utility>
#include <variant>

namespace proxima {

enum class StatusCode {
    ok = 0,
    invalid_argument,     // the caller's input is wrong (NaN coordinate, index out of range)
    not_found,            // unknown object, scene or file
    failed_precondition,  // valid input in the wrong state (vertex count differs from topology)
    resource_exhausted,   // a configured limit was reached
    cancelled,            // the caller cancelled
    deadline_exceeded,    // the caller's deadline passed
    unavailable,          // a backend (GPU context, file system) cannot serve now
    internal,             // a bug: an invariant did not hold
    data_loss,            // stored data is corrupt (a checksum mismatch): reported, never served
    unauthenticated,      // the caller presented no valid credentials (the daemon's tokens)
    permission_denied,    // valid credentials that do not grant this (a review room)
};

const char* status_code_name(StatusCode code);

class [[nodiscard]] Status {
  public:
    Status() = default;
    Status(StatusCode code, std::string message) : m_code(code), m_message(std::move(message)) {}

    static Status ok_status() { return {}; }
    bool ok() const { return m_code == StatusCode::ok; }
    StatusCode code() const { return m_code; }
    const std::string& message() const { return m_message; }
    // "INVALID_ARGUMENT: object 'a.ply': triangle 12 index 40 out of range (40 vertices)".
    std::string to_string() const;

  private:
    StatusCode m_code = StatusCode::ok;
    std::string m_message;
};

inline Status invalid_argument(std::string m) {
    return {StatusCode::invalid_argument, std::move(m)};
}
inline Status not_found(std::string m) {
    return {StatusCode::not_found, std::move(m)};
}
inline Status failed_precondition(std::string m) {
    return {StatusCode::failed_precondition, std::move(m)};
}
inline Status data_loss(std::string m) {
    return {StatusCode::data_loss, std::move(m)};
}

template <class T>
class [[nodiscard]] StatusOr {
  public:
    StatusOr(T value) : m_value(std::move(value)) {}          // NOLINT(google-explicit-constructor)
    StatusOr(Status status) : m_status(std::move(status)) {}  // NOLINT(google-explicit-constructor)

    bool ok() const { return m_status.ok(); }
    const Status& status() const { return m_status; }
    T& value() & { return *m_value; }
    const T& value() const& { return *m_value; }
    T&& value() && { return std::move(*m_value); }
    T& operator*() & { return *m_value; }
    const T& operator*() const& { return *m_value; }
    T&& operator*() && { return std::move(*m_value); }
    T* operator->() { return &*m_value; }
    const T* operator->() const { return &*m_value; }

  private:
    Status m_status;
    std::optional<T> m_value;
};

}  // namespace proxima
