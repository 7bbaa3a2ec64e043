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

namespace {

/// Where point `self` stands in its own list of `kq` neighbours (it may not come first among
/// exact duplicates); when it is missing, the last (farthest) entry, which is dropped instead.
int self_position(const int* list, int kq, std::size_t self) {
    for (int j = 0; j < kq; ++j) {
        if (std::size_t(list[j]) == self) return j;
    }
    return kq - 1;
}

/// Copies the kq - 1 entries of a list other than the one at `skip`.
void copy_without(const int* idx, const float* dist, int kq, int skip, int* out_idx,
                  float* out_dist) {
    for (int j = 0, o = 0; j < kq; ++j) {
        if (j == skip) continue;
        out_idx[o] = idx[j];
        out_dist[o] = dist[j];
        ++o;
    }
}

}  // namespace

struct KnnIndex::Impl {
    Span<Vec3f> points;
    std::unique_ptr<flann::Index<flann::L2_Simple<float>>> index;

    static constexpr std::size_t kChunk = 2048;

    /// The k nearest of queries [begin, begin + m), into idx/dist (m x k, row-major).
    void search_chunk(const Vec3f* queries, std::size_t m, int k, int* idx, float* dist) const {
        flann::Matrix<float> q(const_cast<float*>(queries[0].data()), m, 3);
        flann::Matrix<int> mi(idx, m, std::size_t(k));
        flann::Matrix<float> md(dist, m, std::size_t(k));
        flann::SearchParams params(flann::FLANN_CHECKS_UNLIMITED, 0.0f, true);
        index->knnSearch(q, mi, md, std::size_t(k), params);
    }

    void search(const Vec3f* queries, std::size_t count, int k, int* idx, float* dist) const {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, kChunk),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            const std::size_t at = r.begin() * std::size_t(k);
            search_chunk(queries + r.begin(), r.size(), k, idx + at, dist + at);
        });
    }
};

KnnIndex::KnnIndex(Span<Vec3f> points) : impl_(std::make_unique<Impl>()) {
    if (points.empty()) throw InvalidArgument("kNN index: no points");
    impl_->points = points;
    // FLANN only reads the points (with `reorder` it keeps its own reordered copy for the
    // queries; ours are needed only while building and for fill_rows).
    flann::Matrix<float> data(const_cast<float*>(points[0].data()), points.size(), 3);
    impl_->index = std::make_unique<flann::Index<flann::L2_Simple<float>>>(
        data, flann::KDTreeSingleIndexParams(15));
    impl_->index->buildIndex();
}

KnnIndex::~KnnIndex() = default;

std::size_t KnnIndex::size() const { return impl_->points.size(); }

KnnResult KnnIndex::query(Span<Vec3f> queries, int k) const {
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
    out.indices.resize(n * std::size_t(out.k));
    out.sq_distances.resize(out.indices.size());
    // k + 1 neighbours per chunk into a chunk-sized buffer, then each list without the point
    // itself into the result: no #P x (k + 1) temporary.
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, Impl::kChunk),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        std::vector<int> idx(r.size() * std::size_t(kq));
        std::vector<float> dist(idx.size());
        impl_->search_chunk(impl_->points.data() + r.begin(), r.size(), kq, idx.data(),
                            dist.data());
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            const std::size_t row = (i - r.begin()) * std::size_t(kq);
            const int self = self_position(&idx[row], kq, i);
            copy_without(&idx[row], &dist[row], kq, self, &out.indices[i * std::size_t(out.k)],
                         &out.sq_distances[i * std::size_t(out.k)]);
        }
    });
    return out;
}

KnnResult KnnResult::subset(const std::vector<char>& removed,
                            Span<Vec3f> kept_points, int k_sub,
                            std::size_t* requeried) const {
    if (requeried) *requeried = 0;
    const std::size_t n = removed.size();
    KnnResult out;
    if (k_sub <= 0 || k_sub > k || indices.size() != n * std::size_t(k)) return out;
    if (kept_points.empty() || std::size_t(k_sub) >= kept_points.size()) return out;
    std::vector<int> renumber(n, -1);
    std::size_t m = 0;
    for (std::size_t i = 0; i < n; ++i) {
        if (!removed[i]) renumber[i] = int(m++);
    }
    out.k = k_sub;
    out.indices.resize(m * std::size_t(k_sub));
    out.sq_distances.resize(out.indices.size());
    std::vector<char> short_row(m, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            if (removed[i]) continue;
            const std::size_t row = std::size_t(renumber[i]) * std::size_t(k_sub);
            int o = 0;
            for (int j = 0; j < k && o < k_sub; ++j) {
                const int nb = renumber[std::size_t(neighbours(i)[j])];
                if (nb < 0) continue;
                out.indices[row + std::size_t(o)] = nb;
                out.sq_distances[row + std::size_t(o)] = sq_dists(i)[j];
                ++o;
            }
            if (o < k_sub) short_row[std::size_t(renumber[i])] = 1;
        }
    });
    std::vector<std::size_t> incomplete;
    for (std::size_t j = 0; j < m; ++j) {
        if (short_row[j]) incomplete.push_back(j);
    }
    if (m != kept_points.size()) throw InvalidArgument("kNN subset: kept point count mismatch");
    if (!incomplete.empty()) KnnIndex(kept_points).fill_rows(out, incomplete);
    if (requeried) *requeried = incomplete.size();
    return out;
}

void KnnIndex::fill_rows(KnnResult& r, const std::vector<std::size_t>& rows) const {
    if (rows.empty() || r.k == 0) return;
    std::vector<Vec3f> queries(rows.size());
    for (std::size_t j = 0; j < rows.size(); ++j) queries[j] = impl_->points[rows[j]];
    const int kq = r.k + 1;  // <= size(): r.k is at most size() - 1
    const KnnResult q = query(queries, kq);
    for (std::size_t j = 0; j < rows.size(); ++j) {
        // As in self_neighbours: drop the point itself (or, when absent, the farthest entry).
        copy_without(q.neighbours(j), q.sq_dists(j), kq,
                     self_position(q.neighbours(j), kq, rows[j]),
                     &r.indices[rows[j] * std::size_t(r.k)],
                     &r.sq_distances[rows[j] * std::size_t(r.k)]);
    }
}

}  // namespace vdbrecon
