#pragma once
// A fixed-size array whose elements are left unset when it is allocated, for per-query arrays
// that a loop fills completely before anything reads them. std::vector<T>(n) value-initialises
// every element, and the engine's geometry types (Vec3 and all built from it) zero their
// members: the self query's per-triangle arrays (corners, edge frames, the traversal's slots)
// were zero-filled and then overwritten at once, about 300 bytes per triangle of memset
// (callgrind: 3-5 % of a self query's instructions on the real frames).

#include <cstddef>
#include <memory>
#include <type_traits>

namespace proxima::detail {

template <class T>
class OverwriteArray {
    static_assert(std::is_trivially_copyable_v<T> && std::is_trivially_destructible_v<T>,
                  "only for plain data: elements are assigned, never constructed");

  public:
    OverwriteArray() = default;
    explicit OverwriteArray(std::size_t n) : m_cells(std::make_unique<Cell[]>(n)) {}

    // Assigning an element starts its lifetime (a trivial assignment to a union member).
    T& operator[](std::size_t i) { return m_cells[i].value; }
    const T& operator[](std::size_t i) const { return m_cells[i].value; }

  private:
    // A union member is not initialised unless its constructor says so, and this user-provided
    // constructor does not: make_unique's value-initialisation calls it and leaves `value` unset
    // (a defaulted one would be deleted, T's members having initialisers).
    union Cell {
        T value;
        Cell() {}  // NOLINT(modernize-use-equals-default)
    };
    std::unique_ptr<Cell[]> m_cells;
};

}  // namespace proxima::detail
