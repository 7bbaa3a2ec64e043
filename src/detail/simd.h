// Whether the vectorised loops (AVX2, AVX-512) may run: the splat's rows and the kNN's distance
// loop and list insertion have an AVX2 version and an AVX-512 one, chosen at run time, that give
// the scalar loop's results bit for bit.
#pragma once

#include <cstdlib>

namespace vdbrecon::detail {

#if defined(__x86_64__) && defined(__GNUC__)
#define VDBRECON_HAVE_AVX2_PATHS 1
#endif

/// True on CPUs with AVX2 unless the environment sets VDBRECON_SCALAR (the tests compare both
/// paths; so can a benchmark). Reads the environment on every call: call it once per stage or
/// per task, not per element.
inline bool vector_loops() {
#ifdef VDBRECON_HAVE_AVX2_PATHS
    static const bool avx2 = __builtin_cpu_supports("avx2");
    return avx2 && !std::getenv("VDBRECON_SCALAR");
#else
    return false;
#endif
}

/// True where vector_loops() is and the CPU has AVX-512 (F and VL), unless the environment sets
/// VDBRECON_NO_AVX512 (the tests compare it with the AVX2 and scalar paths). The splat's rows
/// and the kNN's distance loop and list insertion have an AVX-512 version.
inline bool wide_vector_loops() {
#ifdef VDBRECON_HAVE_AVX2_PATHS
    static const bool avx512 =
        __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl");
    return avx512 && vector_loops() && !std::getenv("VDBRECON_NO_AVX512");
#else
    return false;
#endif
}

}  // namespace vdbrecon::detail
