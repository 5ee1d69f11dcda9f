// LD_PRELOADed into the ThreadSanitizer stage with absl_mutex_tsan.cpp (deploy/test.sh --only
// tsan; docs/reliability.md, "Sanitizers"): makes the hand-over of a gRPC operation's tag through
// Debian's uninstrumented completion queue visible to TSan.
//
// gRPC 1.51's C++ API starts an operation with grpc_call_start_batch(call, ops, n, tag) on the
// thread that asks for it (a reactor's Finish or StartWrite on one of our worker threads), after
// storing the operation's completion callback in the tag (CallbackWithSuccessTag::Set writes its
// std::function). Another thread takes the finished operation from the completion queue
// (grpc_completion_queue_next in the callback queue's "nexting_thread") and runs the callback the
// tag holds. Everything between the two happens inside libgrpc, whose atomics TSan does not see,
// so the callback's read of the std::function read as a race with Set's write (CI of 2026-11-29,
// Sessions.MoveOnlyFramesInterleavedWithQueriesMatchInProcess; the writer's stack was lost to
// history, so the `race:...CallbackWithSuccessTag::Set` suppression could not match it).
//
// This library interposes the entry points that take a tag (starting a batch, requesting a call)
// and the two that hand one back (next, pluck): a release on the tag's address before the
// operation starts, an acquire on it after the queue returns it. That is the order gRPC itself
// guarantees (a tag is returned only after its operation was started), so it adds only
// synchronization that exists and hides no race of ours. Both libgrpc++ and our binaries call
// these functions through the PLT, so the preloaded definitions are the ones that run.
#include <grpc/grpc.h>

#include "preload.hpp"

namespace {

template <typename Fn>
Fn real(const char* name) {
    return tsan_preload::real<Fn>(name, "libgrpc.so.29");
}

grpc_event acquired(grpc_event ev) {
    if (ev.type == GRPC_OP_COMPLETE) {
        tsan_preload::acquire(ev.tag);
    }
    return ev;
}

}  // namespace

extern "C" {

grpc_call_error grpc_call_start_batch(grpc_call* call, const grpc_op* ops, size_t nops, void* tag,
                                      void* reserved) {
    using Fn = grpc_call_error (*)(grpc_call*, const grpc_op*, size_t, void*, void*);
    static const auto fn = real<Fn>("grpc_call_start_batch");
    tsan_preload::release(tag);
    return fn(call, ops, nops, tag, reserved);
}

grpc_call_error grpc_server_request_call(grpc_server* server, grpc_call** call,
                                         grpc_call_details* details,
                                         grpc_metadata_array* request_metadata,
                                         grpc_completion_queue* cq_bound_to_call,
                                         grpc_completion_queue* cq_for_notification, void* tag) {
    using Fn =
        grpc_call_error (*)(grpc_server*, grpc_call**, grpc_call_details*, grpc_metadata_array*,
                            grpc_completion_queue*, grpc_completion_queue*, void*);
    static const auto fn = real<Fn>("grpc_server_request_call");
    tsan_preload::release(tag);
    return fn(server, call, details, request_metadata, cq_bound_to_call, cq_for_notification, tag);
}

grpc_call_error grpc_server_request_registered_call(grpc_server* server, void* registered_method,
                                                    grpc_call** call, gpr_timespec* deadline,
                                                    grpc_metadata_array* request_metadata,
                                                    grpc_byte_buffer** optional_payload,
                                                    grpc_completion_queue* cq_bound_to_call,
                                                    grpc_completion_queue* cq_for_notification,
                                                    void* tag) {
    using Fn = grpc_call_error (*)(grpc_server*, void*, grpc_call**, gpr_timespec*,
                                   grpc_metadata_array*, grpc_byte_buffer**, grpc_completion_queue*,
                                   grpc_completion_queue*, void*);
    static const auto fn = real<Fn>("grpc_server_request_registered_call");
    tsan_preload::release(tag);
    return fn(server, registered_method, call, deadline, request_metadata, optional_payload,
              cq_bound_to_call, cq_for_notification, tag);
}

grpc_event grpc_completion_queue_next(grpc_completion_queue* cq, gpr_timespec deadline,
                                      void* reserved) {
    using Fn = grpc_event (*)(grpc_completion_queue*, gpr_timespec, void*);
    static const auto fn = real<Fn>("grpc_completion_queue_next");
    return acquired(fn(cq, deadline, reserved));
}

grpc_event grpc_completion_queue_pluck(grpc_completion_queue* cq, void* tag, gpr_timespec deadline,
                                       void* reserved) {
    using Fn = grpc_event (*)(grpc_completion_queue*, void*, gpr_timespec, void*);
    static const auto fn = real<Fn>("grpc_completion_queue_pluck");
    return acquired(fn(cq, tag, deadline, reserved));
}

}  // extern "C"
