#pragma once
// Whether this test binary is built with AddressSanitizer or ThreadSanitizer: ASan's quarantine
// holds freed memory and TSan's shadow memory follows the heap's history, so checks of a
// process's RSS only mean something without them.

namespace proxima::test {

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
inline constexpr bool SANITIZED = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
inline constexpr bool SANITIZED = true;
#else
inline constexpr bool SANITIZED = false;
#endif
#else
inline constexpr bool SANITIZED = false;
#endif

}  // namespace proxima::test
