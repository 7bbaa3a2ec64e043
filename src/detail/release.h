// Freeing a vector's memory before it goes out of scope.
#pragma once

namespace vdbrecon::detail {

/// Empties `v` and frees its memory. (`v = {}` would not: for a std::vector it assigns an empty
/// initializer list, which keeps the capacity.)
template <typename V>
void release(V& v) {
    V().swap(v);
}

}  // namespace vdbrecon::detail
