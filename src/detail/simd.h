// Whether the vectorised loops (AVX2) may run: the splat's rows and the kNN's distance loop have
// an AVX2 version, chosen at run time, that gives the scalar loop's results bit for bit.
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

}  // namespace vdbrecon::detail
