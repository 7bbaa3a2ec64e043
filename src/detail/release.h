// Freeing a vector's memory before it goes out of scope.
#pragma once

#if defined(__GLIBC__) || defined(__linux__)
#include <malloc.h>
#endif

namespace vdbrecon::detail {

/// Empties `v` and frees its memory. (`v = {}` would not: for a std::vector it assigns an empty
/// initializer list, which keeps the capacity.)
template <typename V>
void release(V& v) {
    V().swap(v);
}

/// Hands the heap's free memory back to the system (glibc: malloc_trim). The CLI keeps freed
/// blocks of up to 32 MB in the heap for the next stage (apps/vdbrecon.cpp, tune_heap); after a
/// phase that freed many of them, before one that allocates afresh in large blocks, this keeps
/// the freed ones out of the peak.
inline void trim_heap() {
#if defined(__GLIBC__)
    malloc_trim(0);
#endif
}

}  // namespace vdbrecon::detail
