// What the libraries preloaded into the ThreadSanitizer stage share (absl_mutex_tsan.cpp,
// grpc_cq_tsan.cpp; deploy/test.sh --only tsan): finding the function they stand in front of, and
// TSan's acquire/release annotations.
//
// The annotations are weak: preloaded into a process without TSan (the Python client that one
// test runs), the libraries only forward.
#pragma once

#include <dlfcn.h>

#include <cstdio>
#include <cstdlib>

extern "C" {
void __tsan_acquire(void* addr) __attribute__((weak));
void __tsan_release(void* addr) __attribute__((weak));
}

namespace tsan_preload {

// The definition of `name` that the preloaded one hides. A library loaded with RTLD_LOCAL (a
// Python extension's dependency) is not in the global scope that RTLD_NEXT searches: then
// `library` (its soname) is asked directly.
template <typename Fn>
Fn real(const char* name, const char* library) {
    void* f = dlsym(RTLD_NEXT, name);
    if (f == nullptr) {
        if (void* lib = dlopen(library, RTLD_NOW)) {
            f = dlsym(lib, name);
        }
    }
    if (f == nullptr) {
        std::fprintf(stderr, "tsan preload: %s not found (in %s)\n", name, library);
        std::abort();
    }
    return reinterpret_cast<Fn>(f);
}

inline void acquire(void* addr) {
    if (__tsan_acquire != nullptr && addr != nullptr) {
        __tsan_acquire(addr);
    }
}

inline void release(void* addr) {
    if (__tsan_release != nullptr && addr != nullptr) {
        __tsan_release(addr);
    }
}

}  // namespace tsan_preload
