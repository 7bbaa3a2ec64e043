// exp() of eight doubles at once, with the same bits on either path (scalar, AVX-512), so
// that the splat's grids do not depend on the CPU's vector width. The splat needs seven
// exponentials for each (point, block) piece (src/splat.cpp); one call here replaces seven
// calls of glibc's exp() (the bunny at 0.5 mm, 1 thread: splat 0.387 -> 0.376 s, 16 pairs).
//
// The usual reduction: x = k ln2 + r with k = round(x / ln2) and |r| <= ln2 / 2 (ln2 split in two
// parts as in fdlibm's exp, so that k ln2_hi is exact), exp(r) by its Taylor series to r^12 / 12!
// (truncation below 2e-16 relative) as 1 + (r + r^2 Q(r)), Q by Estrin's scheme (its terms in
// parallel: a shorter chain of dependent operations than Horner's, which one vector call
// waits on), and 2^k added to the exponent bits. Within 2 ulp of exp() for x in
// [kExp8Min, 700]; arguments below kExp8Min (and NaN, which the splat never passes) give
// exp(kExp8Min), ~1e-304. Every path makes the same double operations in the same order (no
// FMA: fp-contract is off).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "detail/simd.h"

#ifdef VDBRECON_HAVE_AVX2_PATHS
#include <immintrin.h>
#endif

namespace vdbrecon::detail {

constexpr double kExp8Min = -700.0;

namespace exp8_constants {
constexpr double kLog2e = 1.4426950408889634074;
constexpr double kLn2Hi = 6.93147180369123816490e-01;  // 0x3FE62E42FEE00000
constexpr double kLn2Lo = 1.90821492927058770002e-10;  // 0x3DEA39EF35793C76
/// 1 / n!, n = 0..12.
constexpr double kInvFactorial[13] = {
    1.0,
    1.0,
    1.0 / 2.0,
    1.0 / 6.0,
    1.0 / 24.0,
    1.0 / 120.0,
    1.0 / 720.0,
    1.0 / 5040.0,
    1.0 / 40320.0,
    1.0 / 362880.0,
    1.0 / 3628800.0,
    1.0 / 39916800.0,
    1.0 / 479001600.0,
};
}  // namespace exp8_constants

/// exp(x) by the scalar path: the lanes of exp8_avx512 bit for bit.
inline double exp8_scalar_one(double x) {
    using namespace exp8_constants;
    x = x > kExp8Min ? x : kExp8Min;  // as _mm512_max_pd(x, min): NaN gives min too
    const double k = std::nearbyint(x * kLog2e);
    const double r = (x - k * kLn2Hi) - k * kLn2Lo;
    const double* c = kInvFactorial;
    const double r2 = r * r, r4 = r2 * r2, r8 = r4 * r4;
    const double t0 = (c[2] + c[3] * r) + (c[4] + c[5] * r) * r2;
    const double t1 = (c[6] + c[7] * r) + (c[8] + c[9] * r) * r2;
    const double t2 = (c[10] + c[11] * r) + c[12] * r2;
    double p = c[0] + (r + r2 * ((t0 + t1 * r4) + t2 * r8));
    std::uint64_t bits;
    std::memcpy(&bits, &p, sizeof bits);
    bits += std::uint64_t(std::int64_t(k)) << 52;
    std::memcpy(&p, &bits, sizeof bits);
    return p;
}

#ifdef VDBRECON_HAVE_AVX2_PATHS
/// a + b x, rounded twice (no FMA), eight lanes.
__attribute__((target("avx512f"), optimize("fp-contract=off"))) inline __m512d lin_avx512(
    __m512d a, __m512d b, __m512d x) {
    return _mm512_add_pd(a, _mm512_mul_pd(b, x));
}

/// y[i] = exp(x[i]), i < 8, at once (AVX-512 F).
__attribute__((target("avx512f"), optimize("fp-contract=off"))) inline void exp8_avx512(
    const double* x, double* y) {
    using namespace exp8_constants;
    // The zero-masked forms with every lane on: the plain ones pass an undefined source that
    // GCC 12 warns about under this function's optimize attribute.
    const __mmask8 all = 0xff;
    const __m512d v = _mm512_maskz_max_pd(all, _mm512_loadu_pd(x), _mm512_set1_pd(kExp8Min));
    const __m512d k = _mm512_maskz_roundscale_pd(all, _mm512_mul_pd(v, _mm512_set1_pd(kLog2e)),
                                                 _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    const __m512d r = _mm512_sub_pd(_mm512_sub_pd(v, _mm512_mul_pd(k, _mm512_set1_pd(kLn2Hi))),
                                    _mm512_mul_pd(k, _mm512_set1_pd(kLn2Lo)));
    __m512d c[13];
    for (int n = 0; n < 13; ++n) c[n] = _mm512_set1_pd(kInvFactorial[n]);
    const auto lin = lin_avx512;
    const __m512d r2 = _mm512_mul_pd(r, r), r4 = _mm512_mul_pd(r2, r2);
    const __m512d r8 = _mm512_mul_pd(r4, r4);
    const __m512d t0 = lin(lin(c[2], c[3], r), lin(c[4], c[5], r), r2);
    const __m512d t1 = lin(lin(c[6], c[7], r), lin(c[8], c[9], r), r2);
    const __m512d t2 = lin(lin(c[10], c[11], r), c[12], r2);
    const __m512d p = _mm512_add_pd(c[0], lin(r, r2, lin(lin(t0, t1, r4), t2, r8)));
    const __m512i e = _mm512_maskz_slli_epi64(
        all, _mm512_maskz_cvtepi32_epi64(all, _mm512_maskz_cvtpd_epi32(all, k)), 52);
    _mm512_storeu_pd(y, _mm512_castsi512_pd(_mm512_add_epi64(_mm512_castpd_si512(p), e)));
}
#endif

/// y[i] = exp(x[i]) for i < 8 (see the file comment): at once where `path` is 2 (AVX-512, as
/// wide_vector_loops() allows), else one at a time; the same bits either way.
inline void exp8(const double* x, double* y, int path) {
#ifdef VDBRECON_HAVE_AVX2_PATHS
    if (path == 2) return exp8_avx512(x, y);
#endif
    (void)path;
    for (int i = 0; i < 8; ++i) y[i] = exp8_scalar_one(x[i]);
}

}  // namespace vdbrecon::detail
