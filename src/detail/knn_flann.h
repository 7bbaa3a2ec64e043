// FLANN's kd-trees behind KnnIndex (knn.h: KnnBackend::flann), in a translation unit of their
// own (src/knn_flann.cpp): FLANN's headers are heavy templates and need only be compiled once.
#pragma once

#include <memory>

#include "vdbrecon/types.h"

namespace vdbrecon::detail {

/// Nearest-neighbour search over fixed points with FLANN (M. Muja and D. G. Lowe, "Scalable
/// Nearest Neighbor Algorithms for High Dimensional Data", PAMI 2014).
class FlannKnn {
  public:
    /// FLANN's single kd-tree (leaves of at most 15 points), searched exactly (`eps` = 0) or
    /// eps-approximately (a branch is skipped when it cannot hold a point closer than the k-th
    /// found / (1 + eps)). Not FLANN's randomized kd-trees: Debian's FLANN 1.9.2 shuffles their
    /// points with std::random_device (kdtree_index.h), so their answers change from run to
    /// run. The points are not copied: they must outlive the index.
    FlannKnn(Span<Vec3f> points, double eps);
    ~FlannKnn();
    FlannKnn(const FlannKnn&) = delete;
    FlannKnn& operator=(const FlannKnn&) = delete;

    /// The k nearest indexed points of each query (k <= the points less one when excluding):
    /// row i of idx (and of dist, squared distances, unless null) nearest first, exact ties by
    /// index. Query i excludes indexed point self[i] when `self` is given (-1: none), point
    /// first_self + i when `first_self` >= 0. Runs in parallel; the same for any thread count.
    void search(Span<Vec3f> queries, const int* self, long first_self, int k, int* idx,
                float* dist) const;

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace vdbrecon::detail
