// The heap: freeing a vector's memory before it goes out of scope, handing free memory back,
// and one lock for the allocations made inside parallel loops.
#pragma once

#include <tbb/spin_mutex.h>

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

/// Taken around a burst of allocations inside a parallel loop (a splat block's output leaves).
/// The CLI runs with one glibc arena for all threads (apps/vdbrecon.cpp, tune_heap), and
/// glibc's arena lock puts a thread that finds it taken to sleep at once; on the 2-core VM the
/// wake-up took 0.05-3 ms, a few hundred times a run. With this spin lock the threads take
/// turns at the heap by spinning for the ~1 us a burst holds it instead.
inline tbb::spin_mutex& heap_lock() {
    static tbb::spin_mutex lock;
    return lock;
}

}  // namespace vdbrecon::detail
