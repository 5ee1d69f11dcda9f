// LD_PRELOADed into the ThreadSanitizer stage (deploy/test.sh --only tsan; docs/reliability.md,
// "Sanitizers"): makes Debian's uninstrumented absl::Mutex visible to TSan.
//
// gRPC 1.51 hands a call's state from thread to thread under absl::Mutex: grpc::internal::Mutex
// in the C++ headers (a reactor's Finish or StartWrite before the reactor is bound, the backlog
// read in InternalBindWriter) and gpr_mu in the core library. Debian's Abseil is not built with
// TSan, so those locks are invisible and every handoff reads as a race, in gRPC's inlined header
// code and in our reactors alike. This library interposes the Mutex and CondVar entry points,
// calls the real ones (dlsym RTLD_NEXT) and tells TSan the acquire/release they stand for. It
// adds synchronization TSan did not see, never removes any, so it hides no race of ours.
#include <cstdint>

#include "preload.hpp"

namespace {

// absl::Duration and absl::Time (a Duration) by value: two integers, passed in two registers.
struct Duration {
    std::int64_t hi;
    std::uint32_t lo;
};

template <typename Fn>
Fn real(const char* name) {
    return tsan_preload::real<Fn>(name, "libabsl_synchronization.so.20220623");
}

void acquired(void* mu) {
    tsan_preload::acquire(mu);
}

void releasing(void* mu) {
    tsan_preload::release(mu);
}

}  // namespace

// Each function below has the mangled name of the absl::debian3 member it stands for.
#define LOCK(sym)                                           \
    extern "C" void sym(void* mu) {                         \
        static const auto fn = real<void (*)(void*)>(#sym); \
        fn(mu);                                             \
        acquired(mu);                                       \
    }
#define UNLOCK(sym)                                         \
    extern "C" void sym(void* mu) {                         \
        static const auto fn = real<void (*)(void*)>(#sym); \
        releasing(mu);                                      \
        fn(mu);                                             \
    }
#define TRY_LOCK(sym)                                       \
    extern "C" bool sym(void* mu) {                         \
        static const auto fn = real<bool (*)(void*)>(#sym); \
        const bool ok = fn(mu);                             \
        if (ok) {                                           \
            acquired(mu);                                   \
        }                                                   \
        return ok;                                          \
    }
// Mutex::LockWhen(const Condition&) and its reader variant: held on return.
#define LOCK_WHEN(sym)                                                   \
    extern "C" void sym(void* mu, const void* cond) {                    \
        static const auto fn = real<void (*)(void*, const void*)>(#sym); \
        fn(mu, cond);                                                    \
        acquired(mu);                                                    \
    }
// The timed variants: held on return whatever the bool says.
#define LOCK_WHEN_TIMED(sym)                                                       \
    extern "C" bool sym(void* mu, const void* cond, Duration t) {                  \
        static const auto fn = real<bool (*)(void*, const void*, Duration)>(#sym); \
        const bool r = fn(mu, cond, t);                                            \
        acquired(mu);                                                              \
        return r;                                                                  \
    }
// Mutex::Await*: held on entry and on return, released while waiting.
#define AWAIT(sym)                                                       \
    extern "C" void sym(void* mu, const void* cond) {                    \
        static const auto fn = real<void (*)(void*, const void*)>(#sym); \
        releasing(mu);                                                   \
        fn(mu, cond);                                                    \
        acquired(mu);                                                    \
    }
#define AWAIT_TIMED(sym)                                                           \
    extern "C" bool sym(void* mu, const void* cond, Duration t) {                  \
        static const auto fn = real<bool (*)(void*, const void*, Duration)>(#sym); \
        releasing(mu);                                                             \
        const bool r = fn(mu, cond, t);                                            \
        acquired(mu);                                                              \
        return r;                                                                  \
    }
// CondVar::Wait*(Mutex*): the mutex is released while waiting.
#define CV_WAIT(sym)                                               \
    extern "C" void sym(void* cv, void* mu) {                      \
        static const auto fn = real<void (*)(void*, void*)>(#sym); \
        releasing(mu);                                             \
        fn(cv, mu);                                                \
        acquired(mu);                                              \
    }
#define CV_WAIT_TIMED(sym)                                                   \
    extern "C" bool sym(void* cv, void* mu, Duration t) {                    \
        static const auto fn = real<bool (*)(void*, void*, Duration)>(#sym); \
        releasing(mu);                                                       \
        const bool r = fn(cv, mu, t);                                        \
        acquired(mu);                                                        \
        return r;                                                            \
    }

LOCK(_ZN4absl7debian35Mutex4LockEv)
LOCK(_ZN4absl7debian35Mutex10ReaderLockEv)
UNLOCK(_ZN4absl7debian35Mutex6UnlockEv)
UNLOCK(_ZN4absl7debian35Mutex12ReaderUnlockEv)
TRY_LOCK(_ZN4absl7debian35Mutex7TryLockEv)
TRY_LOCK(_ZN4absl7debian35Mutex13ReaderTryLockEv)
LOCK_WHEN(_ZN4absl7debian35Mutex8LockWhenERKNS0_9ConditionE)
LOCK_WHEN(_ZN4absl7debian35Mutex14ReaderLockWhenERKNS0_9ConditionE)
LOCK_WHEN_TIMED(_ZN4absl7debian35Mutex19LockWhenWithTimeoutERKNS0_9ConditionENS0_8DurationE)
LOCK_WHEN_TIMED(_ZN4absl7debian35Mutex20LockWhenWithDeadlineERKNS0_9ConditionENS0_4TimeE)
LOCK_WHEN_TIMED(_ZN4absl7debian35Mutex25ReaderLockWhenWithTimeoutERKNS0_9ConditionENS0_8DurationE)
LOCK_WHEN_TIMED(_ZN4absl7debian35Mutex26ReaderLockWhenWithDeadlineERKNS0_9ConditionENS0_4TimeE)
AWAIT(_ZN4absl7debian35Mutex5AwaitERKNS0_9ConditionE)
AWAIT_TIMED(_ZN4absl7debian35Mutex16AwaitWithTimeoutERKNS0_9ConditionENS0_8DurationE)
AWAIT_TIMED(_ZN4absl7debian35Mutex17AwaitWithDeadlineERKNS0_9ConditionENS0_4TimeE)
CV_WAIT(_ZN4absl7debian37CondVar4WaitEPNS0_5MutexE)
CV_WAIT_TIMED(_ZN4absl7debian37CondVar15WaitWithTimeoutEPNS0_5MutexENS0_8DurationE)
CV_WAIT_TIMED(_ZN4absl7debian37CondVar16WaitWithDeadlineEPNS0_5MutexENS0_4TimeE)
