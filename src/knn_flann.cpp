// FLANN behind KnnIndex (see detail/knn_flann.h).
#include "detail/knn_flann.h"

#include <flann/flann.hpp>

#include <algorithm>
#include <utility>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace vdbrecon::detail {

using FlannIndex = flann::Index<flann::L2_Simple<float>>;

struct FlannKnn::Impl {
    std::size_t n = 0;
    float eps = 0.0f;
    std::unique_ptr<FlannIndex> index;
};

FlannKnn::FlannKnn(Span<Vec3f> points, double eps) : impl_(std::make_unique<Impl>()) {
    impl_->n = points.size();
    impl_->eps = float(eps);
    flann::Matrix<float> data(const_cast<float*>(points.data()->data()), points.size(), 3);
    impl_->index = std::make_unique<FlannIndex>(data, flann::KDTreeSingleIndexParams(15));
    impl_->index->buildIndex();
}

FlannKnn::~FlannKnn() = default;

void FlannKnn::search(Span<Vec3f> queries, const int* self, long first_self, int k, int* idx,
                      float* dist) const {
    const Impl& m = *impl_;
    const bool exclude = self || first_self >= 0;
    // One more than k where the query's own point is left out (it is among the nearest unless
    // more than k exact copies of it are), and one more to see whether the k-th distance is
    // tied with one not returned.
    const std::size_t want = std::min<std::size_t>(std::size_t(k) + (exclude ? 2 : 1), m.n);
    flann::SearchParams params(flann::FLANN_CHECKS_UNLIMITED, m.eps, true);
    params.cores = 1;  // the chunks below are the parallelism
    // Chunks of 1024 queries (a batch of the outlier stage is 65,536): each row depends on its
    // query alone, so the chunking changes nothing but the speed.
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, queries.size(), 1024),
                      [&](const tbb::blocked_range<std::size_t>& range) {
        const std::size_t begin = range.begin(), end = range.end();
        std::vector<int> fi;
        std::vector<float> fd;
        std::vector<std::pair<float, int>> row;
        // The rows of [b, e) with kq neighbours each (one knnSearch call for them all).
        auto find = [&](std::size_t b, std::size_t e, std::size_t kq) {
            fi.resize((e - b) * kq);
            fd.resize(fi.size());
            flann::Matrix<float> q(const_cast<float*>(queries[b].data()), e - b, 3);
            flann::Matrix<int> mi(fi.data(), e - b, kq);
            flann::Matrix<float> md(fd.data(), e - b, kq);
            m.index->knnSearch(q, mi, md, kq, params);
        };
        find(begin, end, want);
        for (std::size_t i = begin; i < end; ++i) {
            const int own = self ? self[i] : first_self >= 0 ? int(first_self + long(i)) : -1;
            std::size_t kq = want, r = i - begin;
            const int* ids = &fi[r * kq];
            const float* ds = &fd[r * kq];
            std::vector<int> more_i;
            std::vector<float> more_d;
            for (;;) {
                row.clear();
                for (std::size_t j = 0; j < kq; ++j) {
                    if (ids[j] >= 0 && ids[j] != own) row.emplace_back(ds[j], ids[j]);
                }
                std::sort(row.begin(), row.end());
                // Exact ties are broken by the point index, as the grid does: where the k-th
                // distance is also the last one found, the tie may go on past what FLANN
                // returned, so the query is repeated with twice as many.
                const bool cut = row.size() > std::size_t(k) && kq < m.n &&
                                 ds[kq - 1] <= row[std::size_t(k) - 1].first;
                if (!cut) break;
                kq = std::min(m.n, 2 * kq);
                more_i.resize(kq);
                more_d.resize(kq);
                flann::Matrix<float> q(const_cast<float*>(queries[i].data()), 1, 3);
                flann::Matrix<int> mi(more_i.data(), 1, kq);
                flann::Matrix<float> md(more_d.data(), 1, kq);
                m.index->knnSearch(q, mi, md, kq, params);
                ids = more_i.data();
                ds = more_d.data();
            }
            // An approximate search that found fewer repeats its farthest find.
            while (!row.empty() && row.size() < std::size_t(k)) row.push_back(row.back());
            for (int j = 0; j < k; ++j) {
                const std::pair<float, int> e = row[std::size_t(j)];
                idx[i * std::size_t(k) + std::size_t(j)] = e.second;
                if (dist) dist[i * std::size_t(k) + std::size_t(j)] = e.first;
            }
        }
    });
}

}  // namespace vdbrecon::detail
