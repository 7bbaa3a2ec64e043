// The outlier rules of outliers.h on one point, shared by the stage on a whole cloud
// (outliers.cpp) and the streamed one that runs on a region at a time (stream_tiles.cpp), so
// that both decide every point alike, bit for bit.
#pragma once

#include <cmath>
#include <cstddef>

#include "detail/pca.h"
#include "vdbrecon/knn.h"
#include "vdbrecon/outliers.h"

namespace vdbrecon::detail {

/// A point's statistical verdict; kUnknown until its neighbours' d_j are known.
enum : char { kUnknown, kFails, kPasses, kNoLocal };  // kNoLocal: coincident neighbours

/// d_i: the mean distance of point i to its neighbours nb[0..k), summed in list order. With
/// `prefix` (k_first <= k), also the mean over the first k_first of them (the kNN scale).
inline float mean_distance(Span<Vec3f> pts, std::size_t i, const int* nb, int k,
                           int k_first = 0, float* prefix = nullptr) {
    double s = 0.0;
    for (int j = 0; j < k; ++j) {
        if (j == k_first && prefix) *prefix = float(s / double(k_first));
        s += std::sqrt(double(KnnResult::squared_distance(pts[i], pts[std::size_t(nb[j])])));
    }
    if (k_first == k && prefix) *prefix = float(s / double(k_first));
    return float(s / k);
}

/// The statistical rule: d_i against the mean of its neighbours' d_j (their sum given, in list
/// order).
inline char statistical_verdict(float d_i, double sum_of_neighbours, int k,
                                const OutlierOptions& options) {
    const double local = sum_of_neighbours / k;
    if (!(local > 0.0)) return kNoLocal;  // nothing to compare with
    return options.statistical_ratio > 0.0 && d_i / local > options.statistical_ratio ? kFails
                                                                                         : kPasses;
}

/// Whether the planarity rule looks at a point (its d_i against the median d of the cloud).
inline bool planarity_candidate(char verdict, float d_i, double median,
                                const OutlierOptions& options) {
    return verdict == kPasses && options.planarity_ratio > 0.0 &&
           d_i > options.planarity_spacing * median;
}

/// The planarity rule on a candidate: its neighbourhood is a scattered blob, not a surface.
inline bool scattered(Span<Vec3f> pts, std::size_t i, const int* nb, int k,
                      const OutlierOptions& options) {
    Eigen::Vector3d ev, dir;
    return neighbourhood_pca(pts, i, nb, k, ev, dir) && ev[1] > 0.0 &&
           ev[0] / ev[1] > options.planarity_ratio;
}

}  // namespace vdbrecon::detail
