// k-nearest-neighbour queries over a fixed point set: an exact search on a Morton-ordered cell
// grid (knn.cpp), or FLANN's kd-trees (knn_flann.cpp), hidden behind one class.
#pragma once

#include <functional>
#include <memory>
#include <vector>

#include "vdbrecon/types.h"

namespace vdbrecon {

/// The k nearest neighbours of a set of query points, `k` entries per query, nearest first.
struct KnnResult {
    int k = 0;
    std::vector<int> indices;       ///< #Q*k point indices
    /// #Q*k squared distances, world units squared; empty when they were not kept
    /// (KnnIndex::self_neighbours(k, false)): sq_dist() computes them then.
    std::vector<float> sq_distances;

    const int* neighbours(std::size_t q) const { return indices.data() + q * std::size_t(k); }
    const float* sq_dists(std::size_t q) const { return sq_distances.data() + q * std::size_t(k); }
    bool has_distances() const { return sq_distances.size() == indices.size(); }
    /// The squared distance from self-neighbour query q of `points` (the indexed points) to
    /// its j-th neighbour: the kept value, or the same float computed anew.
    float sq_dist(Span<Vec3f> points, std::size_t q, int j) const {
        const std::size_t r = q * std::size_t(k) + std::size_t(j);
        if (has_distances()) return sq_distances[r];
        return squared_distance(points[q], points[std::size_t(indices[r])]);
    }
    /// |c - q|^2 in float, as the search computes it (the kept distances are these values).
    static float squared_distance(const Vec3f& q, const Vec3f& c) {
        const float ex = c[0] - q[0], ey = c[1] - q[1], ez = c[2] - q[2];
        return ex * ex + ey * ey + ez * ez;
    }
    /// The self-neighbours of the points left after removing those with removed[i] != 0
    /// (renumbered in order), k_sub each, from these self-neighbours of all of them: a kept
    /// point's nearest kept points are the first kept ones of its list, which is exact wherever
    /// the list holds at least k_sub kept points. The rows where it does not are queried anew
    /// on a kd-tree of `kept_points` (built only then); their count goes to *requeried.
    KnnResult subset(const std::vector<char>& removed, Span<Vec3f> kept_points,
                     int k_sub, std::size_t* requeried = nullptr) const&;
    /// The same, made in place from these lists (left empty): no second copy of the lists.
    /// Without kept distances the result has none either (`kept_points` are the indexed ones).
    KnnResult subset(const std::vector<char>& removed, Span<Vec3f> kept_points,
                     int k_sub, std::size_t* requeried = nullptr) &&;
};

/// The search behind KnnIndex. FLANN is the library the design first named; bench/knn.sh
/// measures it 1.1-5.6x slower than the grid on every cloud tried (k = 16, 2 threads), exact
/// copies included (the room scan, half its points doubled: 0.117 vs 0.247 s; 20 copies of
/// every point: 0.066 vs 0.074 s; a 20M-point terrain: 12.0 vs 66.9 s), so the grid is the
/// default everywhere.
enum class KnnBackend {
    grid,   ///< our exact search on a Morton-ordered cell grid (knn.cpp)
    flann,  ///< FLANN's kd-tree (knn_flann.cpp): exact, or approximate with KnnOptions::eps
};

struct KnnOptions {
    KnnBackend backend = KnnBackend::grid;
    /// flann: 0 = exact; > 0 = eps-approximate search (FLANN skips a branch that cannot hold a
    /// point closer than the k-th found by more than the factor 1 + eps on squared distances:
    /// a few neighbours may be missed, none returned is farther than sqrt(1 + eps) times the
    /// true k-th). Deterministic, unlike FLANN's randomized kd-trees (src/detail/knn_flann.h
    /// says why they are not offered).
    double eps = 0.0;

    /// Throws InvalidArgument naming the field when out of range.
    void validate() const;
};

/// Exact (or, with FLANN's eps, approximate) k-nearest-neighbour search over fixed
/// points; build once, query many times from any number of threads.
class KnnIndex {
public:
    /// Builds the index over `points`, which are not copied: they must outlive the index.
    explicit KnnIndex(Span<Vec3f> points, const KnnOptions& options = {});
    /// The search in use.
    KnnBackend backend() const;
    ~KnnIndex();
    KnnIndex(const KnnIndex&) = delete;
    KnnIndex& operator=(const KnnIndex&) = delete;

    std::size_t size() const;

    /// For every indexed point, its k nearest *other* points (the point itself is excluded, even
    /// when exact duplicates exist). Runs in parallel; the result does not depend on the thread
    /// count. `k` is clamped to size() - 1. Without `distances` only the indices are kept (half
    /// the memory; KnnResult::sq_dist computes a distance when asked).
    KnnResult self_neighbours(int k, bool distances = true) const;

    /// Called with a batch of self-neighbour rows: `count` point indices (`rows`) and their k
    /// neighbours each (`idx`, row-major, nearest first).
    using BatchVisitor =
        std::function<void(const int* rows, std::size_t count, int k, const int* idx)>;

    /// The same lists as self_neighbours(k), handed to `visit` a batch at a time and not kept:
    /// batches of whole cells of at least `batch` points (0: 1/32 of them, at least 65536), in
    /// the index's spatial order, each searched in parallel, visited one after the other in a
    /// fixed order (so what the visitor computes does not depend on the thread count). Memory:
    /// one batch of lists, not #P.
    void visit_self_neighbours(int k, const BatchVisitor& visit, std::size_t batch = 0) const;

    /// The self-neighbour rows of the given points only (row j for point rows[j]), with
    /// distances: the same lists as those rows of self_neighbours(k).
    KnnResult self_neighbours_of(const std::vector<std::size_t>& rows, int k) const;

    /// The k nearest indexed points of arbitrary query points, in parallel.
    KnnResult query(Span<Vec3f> queries, int k) const;

    /// Recomputes the given rows of self-neighbours `r` (r.k per row) of the indexed points.
    void fill_rows(KnnResult& r, const std::vector<std::size_t>& rows) const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

/// The median sample spacing of a surface from its points' squared distances to their k-th
/// nearest neighbour (`kth_sq`; 0 when empty), world units.
///
/// A point's spacing is taken from the local density: with lambda samples per unit area, the
/// disc out to the k-th neighbour holds about k of them, so lambda ~ k / (pi r_k^2) and the
/// spacing lambda^(-1/2) = r_k sqrt(pi / k). Unlike the mean distance to the k nearest, this
/// hardly depends on how regular the sampling is: at k = 10 the mean distance is 1.37
/// spacings on a square raster but 1.23 on a random sample of the same density, which
/// clusters. On the Stanford bunny scans, a 10 % random subsample's value is 3.08x the whole
/// scan's with k = 16 (sqrt(10) = 3.16 would be exact); the mean distance gives 2.84x.
double median_density_spacing(const std::vector<float>& kth_sq, int k);

/// The spacing one squared distance to the k-th neighbour stands for (see above), world units.
double density_spacing(float kth_sq, int k);

}  // namespace vdbrecon
