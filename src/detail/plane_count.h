// How many of a neighbourhood's points lie within a band of a plane: the inner loop of the
// normal stage's plane searches (the deterministic RANSAC over triples and pairs of neighbours,
// normals.cpp), written for two and four lanes. Every path computes each distance with the same
// products and sums in the same order as the scalar loop, ((ux x + uy y) + uz z) - offset
// (what Eigen's u.dot(q) - offset gives), and compares it the same way, so the counts agree
// exactly.
#pragma once

#include <cmath>

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define VDBRECON_PLANE_COUNT_X86 1
#endif

namespace vdbrecon::detail {

/// A neighbourhood's points by axis, x[j] = q[j][0] and so on, and a weight per point (1.0 for
/// a point taking part, 0.0 for one left out), at most kPlanePoints of them.
constexpr int kPlanePoints = 64;
struct PlanePoints {
    alignas(32) double x[kPlanePoints];
    alignas(32) double y[kPlanePoints];
    alignas(32) double z[kPlanePoints];
    int m = 0;
};

/// The weights of the points j with take[j] (1.0, else 0.0).
inline void plane_weights(const bool* take, int m, double* w) {
    for (int j = 0; j < m; ++j) w[j] = take[j] ? 1.0 : 0.0;
}

/// The reference loop over the points from `first` on: the sum of w[j] over those within
/// `band` of u . x = offset.
inline double count_on_plane_from(const PlanePoints& p, int first, const double* w,
                                  const double u[3], double offset, double band) {
    double count = 0.0;
    for (int j = first; j < p.m; ++j) {
        const double d = u[0] * p.x[j] + u[1] * p.y[j] + u[2] * p.z[j] - offset;
        count += std::fabs(d) <= band ? w[j] : 0.0;
    }
    return count;
}

/// The sum of w[j] over the points within `band` of u . x = offset, one point at a time.
inline int count_on_plane_scalar(const PlanePoints& p, const double* w, const double u[3],
                                 double offset, double band) {
    return int(count_on_plane_from(p, 0, w, u, offset, band));
}

#ifdef VDBRECON_PLANE_COUNT_X86
/// count_on_plane_scalar two points at a time (SSE2, every x86-64 CPU).
inline int count_on_plane_sse2(const PlanePoints& p, const double* w, const double u[3],
                               double offset, double band) {
    const __m128d ux = _mm_set1_pd(u[0]), uy = _mm_set1_pd(u[1]), uz = _mm_set1_pd(u[2]);
    const __m128d off = _mm_set1_pd(offset), lim = _mm_set1_pd(band);
    const __m128d sign = _mm_set1_pd(-0.0);
    __m128d acc = _mm_setzero_pd();
    int j = 0;
    for (; j + 2 <= p.m; j += 2) {
        __m128d d =
            _mm_add_pd(_mm_mul_pd(ux, _mm_load_pd(p.x + j)), _mm_mul_pd(uy, _mm_load_pd(p.y + j)));
        d = _mm_sub_pd(_mm_add_pd(d, _mm_mul_pd(uz, _mm_load_pd(p.z + j))), off);
        const __m128d in = _mm_cmple_pd(_mm_andnot_pd(sign, d), lim);
        acc = _mm_add_pd(acc, _mm_and_pd(in, _mm_loadu_pd(w + j)));
    }
    double lanes[2];
    _mm_storeu_pd(lanes, acc);
    // Whole numbers: exact in any order.
    return int(lanes[0] + lanes[1] + count_on_plane_from(p, j, w, u, offset, band));
}

/// count_on_plane_scalar four points at a time (AVX2's 256-bit registers; AVX suffices).
__attribute__((target("avx"))) inline int count_on_plane_avx(const PlanePoints& p, const double* w,
                                                             const double u[3], double offset,
                                                             double band) {
    const __m256d ux = _mm256_set1_pd(u[0]), uy = _mm256_set1_pd(u[1]), uz = _mm256_set1_pd(u[2]);
    const __m256d off = _mm256_set1_pd(offset), lim = _mm256_set1_pd(band);
    const __m256d sign = _mm256_set1_pd(-0.0);
    __m256d acc = _mm256_setzero_pd();
    int j = 0;
    for (; j + 4 <= p.m; j += 4) {
        __m256d d = _mm256_add_pd(_mm256_mul_pd(ux, _mm256_load_pd(p.x + j)),
                                  _mm256_mul_pd(uy, _mm256_load_pd(p.y + j)));
        d = _mm256_sub_pd(_mm256_add_pd(d, _mm256_mul_pd(uz, _mm256_load_pd(p.z + j))), off);
        const __m256d in = _mm256_cmp_pd(_mm256_andnot_pd(sign, d), lim, _CMP_LE_OQ);
        acc = _mm256_add_pd(acc, _mm256_and_pd(in, _mm256_loadu_pd(w + j)));
    }
    double lanes[4];
    _mm256_storeu_pd(lanes, acc);
    return int((lanes[0] + lanes[1]) + (lanes[2] + lanes[3]) +
               count_on_plane_from(p, j, w, u, offset, band));
}
#endif

/// Whether count_on_plane takes four lanes at a time (the CPU has AVX).
inline bool plane_count_avx() {
#ifdef VDBRECON_PLANE_COUNT_X86
    static const bool avx = __builtin_cpu_supports("avx");
    return avx;
#else
    return false;
#endif
}

/// The sum of w[j] over the points within `band` of the plane u . x = offset.
inline int count_on_plane(const PlanePoints& p, const double* w, const double u[3], double offset,
                          double band) {
#ifdef VDBRECON_PLANE_COUNT_X86
    return plane_count_avx() ? count_on_plane_avx(p, w, u, offset, band)
                             : count_on_plane_sse2(p, w, u, offset, band);
#else
    return count_on_plane_scalar(p, w, u, offset, band);
#endif
}

}  // namespace vdbrecon::detail
