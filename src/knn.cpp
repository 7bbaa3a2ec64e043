// kNN queries with FLANN's exact single kd-tree (M. Muja and D. Lowe, "Scalable nearest
// neighbor algorithms for high dimensional data", PAMI 2014). Queries run in TBB chunks on one
// built index, which FLANN allows; each query's answer does not depend on the chunking.
#include <flann/flann.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>

#include "vdbrecon/error.h"
#include "vdbrecon/knn.h"

namespace vdbrecon {

struct KnnIndex::Impl {
    std::vector<Vec3f> points;
    std::unique_ptr<flann::Index<flann::L2_Simple<float>>> index;

    void search(const Vec3f* queries, std::size_t count, int k, int* idx, float* dist) const {
        constexpr std::size_t kChunk = 2048;
        tbb::parallel_for(
            tbb::blocked_range<std::size_t>(0, count, kChunk),
            [&](const tbb::blocked_range<std::size_t>& r) {
                const std::size_t m = r.size();
                flann::Matrix<float> q(const_cast<float*>(queries[r.begin()].data()), m, 3);
                flann::Matrix<int> mi(idx + r.begin() * std::size_t(k), m, std::size_t(k));
                flann::Matrix<float> md(dist + r.begin() * std::size_t(k), m, std::size_t(k));
                flann::SearchParams params(flann::FLANN_CHECKS_UNLIMITED, 0.0f, true);
                index->knnSearch(q, mi, md, std::size_t(k), params);
            });
    }
};

KnnIndex::KnnIndex(const std::vector<Vec3f>& points) : impl_(std::make_unique<Impl>()) {
    if (points.empty()) throw InvalidArgument("kNN index: no points");
    impl_->points = points;
    flann::Matrix<float> data(impl_->points[0].data(), impl_->points.size(), 3);
    impl_->index = std::make_unique<flann::Index<flann::L2_Simple<float>>>(
        data, flann::KDTreeSingleIndexParams(15));
    impl_->index->buildIndex();
}

KnnIndex::~KnnIndex() = default;

std::size_t KnnIndex::size() const { return impl_->points.size(); }

KnnResult KnnIndex::query(const std::vector<Vec3f>& queries, int k) const {
    KnnResult r;
    r.k = std::max(0, std::min<int>(k, int(size())));
    if (r.k == 0 || queries.empty()) return r;
    r.indices.resize(queries.size() * std::size_t(r.k));
    r.sq_distances.resize(r.indices.size());
    impl_->search(queries.data(), queries.size(), r.k, r.indices.data(), r.sq_distances.data());
    return r;
}

KnnResult KnnIndex::self_neighbours(int k) const {
    const std::size_t n = size();
    KnnResult out;
    out.k = std::max(0, std::min<int>(k, int(n) - 1));
    if (out.k == 0) return out;
    const int kq = out.k + 1;
    std::vector<int> idx(n * std::size_t(kq));
    std::vector<float> dist(idx.size());
    impl_->search(impl_->points.data(), n, kq, idx.data(), dist.data());
    out.indices.resize(n * std::size_t(out.k));
    out.sq_distances.resize(out.indices.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            const int* src = &idx[i * std::size_t(kq)];
            const float* sd = &dist[i * std::size_t(kq)];
            // Drop the point itself (it may not come first among exact duplicates); when it is
            // missing from the list, drop the farthest entry instead.
            int self = kq - 1;
            for (int j = 0; j < kq; ++j) {
                if (src[j] == int(i)) {
                    self = j;
                    break;
                }
            }
            int* dst = &out.indices[i * std::size_t(out.k)];
            float* dd = &out.sq_distances[i * std::size_t(out.k)];
            for (int j = 0, o = 0; j < kq; ++j) {
                if (j == self) continue;
                dst[o] = src[j];
                dd[o] = sd[j];
                ++o;
            }
        }
    });
    return out;
}

}  // namespace vdbrecon
