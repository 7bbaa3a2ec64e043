// Point outlier removal (see outliers.h).
#include "vdbrecon/outliers.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "detail/pca.h"
#include "vdbrecon/error.h"
#include "vdbrecon/knn.h"

namespace vdbrecon {

void OutlierOptions::validate() const {
    if (k < 3 || k > 1000) {
        throw InvalidArgument("outliers.k = " + std::to_string(k) + ": must be in 3..1000");
    }
    if (!(statistical_ratio == 0.0 || (statistical_ratio >= 1.0 && std::isfinite(statistical_ratio)))) {
        throw InvalidArgument("outliers.statistical_ratio = " + std::to_string(statistical_ratio) +
                              ": must be 0 (off) or a number >= 1");
    }
    if (!(planarity_ratio >= 0.0 && planarity_ratio < 1.0)) {
        throw InvalidArgument("outliers.planarity_ratio = " + std::to_string(planarity_ratio) +
                              ": must be in [0, 1)");
    }
    if (!(planarity_spacing >= 0.0 && std::isfinite(planarity_spacing))) {
        throw InvalidArgument("outliers.planarity_spacing = " + std::to_string(planarity_spacing) +
                              ": must be a non-negative number");
    }
}

namespace {

/// Keeps the rows not removed, in place (does not throw).
template <typename T>
void compact(std::vector<T>& values, const std::vector<char>& removed, std::size_t kept) {
    std::size_t out = 0;
    for (std::size_t i = 0; i < values.size(); ++i) {
        if (!removed[i]) values[out++] = values[i];
    }
    values.resize(kept);
}

/// The same for an owned column (a borrowed one is left alone).
template <typename T>
void compact_owned(Column<T>& v, const std::vector<char>& removed, std::size_t kept) {
    if (!v.empty() && !v.borrowed()) compact(v.edit(), removed, kept);
}

/// The kept rows of a borrowed column as a new array (empty for an owned one): borrowed memory
/// is never written to.
template <typename T>
Column<T> copy_borrowed(const Column<T>& v, const std::vector<char>& removed, std::size_t kept) {
    std::vector<T> out;
    if (!v.borrowed() || v.empty()) return out;
    out.reserve(kept);
    for (std::size_t i = 0; i < v.size(); ++i) {
        if (!removed[i]) out.push_back(v[i]);
    }
    return out;
}

/// Rows per batch of the neighbour search: the lists of one batch, and of the rows still
/// waiting for their neighbours (below), are all that is held of them (unless handed over).
std::size_t batch_rows(std::size_t n) {
    return std::max<std::size_t>(std::size_t(1) << 16, n / 16);
}

/// Neighbour lists of rows that wait for something of their neighbours; resolve() drops the
/// rows whose neighbours are ready, in parallel, keeping the others in order.
struct Waiting {
    std::size_t k = 0;
    std::vector<int> rows, lists;
    std::vector<char> done;

    void add(const int* r, std::size_t count, const int* idx) {
        rows.insert(rows.end(), r, r + count);
        lists.insert(lists.end(), idx, idx + count * k);
    }
    /// `try_row(row, list)` returns whether the row was resolved; `then(row, list)` sees each
    /// resolved row before it is dropped (serially, in order).
    template <typename Try, typename Then>
    void resolve(const Try& try_row, const Then& then) {
        const std::size_t waiting = rows.size();
        done.assign(waiting, 0);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, waiting, 2048),
                          [&](const tbb::blocked_range<std::size_t>& rg) {
            for (std::size_t e = rg.begin(); e < rg.end(); ++e) {
                done[e] = try_row(std::size_t(rows[e]), lists.data() + e * k) ? 1 : 0;
            }
        });
        std::size_t out = 0;
        for (std::size_t e = 0; e < waiting; ++e) {
            if (done[e]) {
                then(rows[e], lists.data() + e * k);
                continue;
            }
            rows[out] = rows[e];
            std::copy_n(lists.data() + e * k, k, lists.data() + out * k);
            ++out;
        }
        rows.resize(out);
        lists.resize(out * k);
    }
};

/// The rules of remove_outliers: fills r.removed, the counts, and what is handed over
/// (r.neighbours; r.spacing for every input point, compacted by the caller).
///
/// One neighbour search, visited a batch at a time (in the index's spatial order). Each batch
/// gives its points' d_i. A point's local average is taken as soon as all its neighbours have
/// their d_j, so its list waits until then (few wait long). The planarity rule needs the median
/// d first, so its candidates' lists are searched again at the end: a few per cent of the
/// points, and the same lists (the search is exact and breaks ties by index).
///
/// The spacing handed over is the mean distance to the spacing_k nearest *kept* points. It is
/// taken from the point's own list, whose first spacing_k points are its nearest kept ones
/// unless one of them goes. Which ones go is known only at the end, so the list waits a second
/// time, until its first spacing_k neighbours have their local averages: it then records
/// whether one of them fails the statistical rule and the largest d_j among them (a planarity
/// removal needs d_j above planarity_spacing x median). Those points are searched again at the
/// end, as KnnResult::subset does: the first spacing_k kept points of their list, or a search
/// among the kept points when fewer than spacing_k of their k are kept.
void classify(const PointCloud& cloud, const OutlierOptions& options,
              const OutlierHandOver& hand_over, OutlierResult& r) {
    const std::size_t n = cloud.size();
    const Span<Vec3f> pts = cloud.positions;
    const KnnIndex index(pts);
    const int k = options.k;  // < n (checked by the caller)
    const std::size_t ku = std::size_t(k);
    const int ks = hand_over.spacing_k <= k ? hand_over.spacing_k : 0;  // 0: none to hand over
    if (hand_over.lists) {
        r.neighbours.k = k;
        r.neighbours.indices.resize(n * ku);
    }
    const double nan = std::numeric_limits<double>::quiet_NaN();
    std::vector<double> spacing(n, -1.0);  // d_i (-1 until its batch is searched)
    std::vector<double> local(n, nan);     // the mean d_j of i's neighbours (NaN until known)
    const auto stat_fails = [&](std::size_t j) {
        return local[j] > 0.0 && options.statistical_ratio > 0.0 &&
               spacing[j] / local[j] > options.statistical_ratio;
    };
    // For the spacing: its value from the first ks of all points, whether one of those fails
    // the statistical rule, and their largest d_j (rounded up).
    std::vector<float> first_spacing(ks > 0 ? n : 0), largest(ks > 0 ? n : 0);
    std::vector<char> touched(ks > 0 ? n : 0, 0);
    const auto mean_distance = [&](std::size_t i, const int* nb, int count) {
        double s = 0.0;
        for (int j = 0; j < count; ++j) {
            s += std::sqrt(double(KnnResult::squared_distance(pts[i], pts[std::size_t(nb[j])])));
        }
        return s;
    };
    Waiting for_spacing{ku, {}, {}, {}}, for_local{ku, {}, {}, {}};
    index.visit_self_neighbours(k, batch_rows(n), [&](const int* rows, std::size_t count, int,
                                                      const int* idx) {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 4096),
                          [&](const tbb::blocked_range<std::size_t>& rg) {
            for (std::size_t t = rg.begin(); t < rg.end(); ++t) {
                const std::size_t i = std::size_t(rows[t]);
                const int* nb = idx + t * ku;
                spacing[i] = mean_distance(i, nb, k) / k;
                if (ks > 0) first_spacing[i] = float(mean_distance(i, nb, ks) / double(ks));
                if (hand_over.lists) std::copy_n(nb, ku, r.neighbours.indices.data() + i * ku);
            }
        });
        for_spacing.add(rows, count, idx);
        for_spacing.resolve(
            [&](std::size_t i, const int* nb) {
                double sum = 0.0;
                for (int j = 0; j < k; ++j) {
                    const double d = spacing[std::size_t(nb[j])];
                    if (d < 0.0) return false;
                    sum += d;
                }
                local[i] = sum / k;
                return true;
            },
            [&](int i, const int* nb) {
                if (ks > 0) for_local.add(&i, 1, nb);
            });
        if (ks == 0) return;
        for_local.resolve(
            [&](std::size_t i, const int* nb) {
                double most = 0.0;
                bool fails = false;
                for (int j = 0; j < ks; ++j) {
                    const std::size_t m = std::size_t(nb[j]);
                    if (std::isnan(local[m])) return false;
                    fails = fails || stat_fails(m);
                    most = std::max(most, spacing[m]);
                }
                touched[i] = fails ? 1 : 0;
                largest[i] = std::nextafter(float(most), std::numeric_limits<float>::infinity());
                return true;
            },
            [](int, const int*) {});
    });
    // After the last batch every d_j, and then every local average, is known: nothing waits.
    if (!for_spacing.rows.empty() || !for_local.rows.empty()) {
        throw Error("outliers: internal error: unresolved neighbour lists");
    }
    for_spacing = {};
    for_local = {};

    std::vector<double> sorted = spacing;
    std::nth_element(sorted.begin(), sorted.begin() + std::ptrdiff_t(n / 2), sorted.end());
    const double median = sorted[n / 2];
    sorted = {};
    // 1 = statistical, 2 = planarity (0 = kept); 3 = a planarity candidate, decided below.
    std::vector<char> rule(n, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t i = rg.begin(); i < rg.end(); ++i) {
            if (!(local[i] > 0.0)) continue;  // coincident points: nothing to compare with
            if (stat_fails(i)) {
                rule[i] = 1;
            } else if (options.planarity_ratio > 0.0 &&
                       spacing[i] > options.planarity_spacing * median) {
                rule[i] = 3;
            }
        }
    });
    std::vector<std::size_t> candidates;
    for (std::size_t i = 0; i < n; ++i) {
        if (rule[i] == 3) candidates.push_back(i);
    }
    KnnResult searched;
    if (!hand_over.lists) searched = index.self_neighbours_of(candidates, k);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, candidates.size(), 256),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t c = rg.begin(); c < rg.end(); ++c) {
            const std::size_t i = candidates[c];
            const int* nb = hand_over.lists ? r.neighbours.neighbours(i) : searched.neighbours(c);
            Eigen::Vector3d ev, dir;
            const bool scattered = detail::neighbourhood_pca(pts, i, nb, k, ev, dir) &&
                                   ev[1] > 0.0 && ev[0] / ev[1] > options.planarity_ratio;
            rule[i] = scattered ? 2 : 0;
        }
    });
    for (std::size_t i = 0; i < n; ++i) {
        if (rule[i] == 1) ++r.statistical;
        if (rule[i] == 2) ++r.planarity;
        r.removed[i] = rule[i] != 0;
    }
    const std::size_t kept_count = n - r.statistical - r.planarity;
    if (ks == 0 || kept_count <= std::size_t(ks)) return;  // too few kept: no spacing

    // The spacing: kept points whose first ks neighbours may have lost one are searched again.
    std::vector<std::size_t> again;
    for (std::size_t i = 0; i < n; ++i) {
        const bool planar_near = options.planarity_ratio > 0.0 &&
                                 double(largest[i]) > options.planarity_spacing * median;
        if (rule[i] == 0 && (touched[i] || planar_near)) again.push_back(i);
    }
    touched = {};
    largest = {};
    // Their spacing from the first ks kept points of their K nearest: the nearest ks kept ones,
    // ties broken by index as among the kept points alone. K grows (from k) for the few rows
    // whose K nearest hold fewer than ks kept points; with K = n - 1 all do, as more than ks
    // points are kept.
    std::vector<std::size_t> rows = std::move(again);
    for (int K = k; !rows.empty(); K = int(std::min<std::size_t>(2 * std::size_t(K), n - 1))) {
        const KnnResult lists = index.self_neighbours_of(rows, K);
        std::vector<char> short_row(rows.size(), 0);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, rows.size(), 1024),
                          [&](const tbb::blocked_range<std::size_t>& rg) {
            std::vector<int> kept_nb(std::size_t(ks), 0);
            for (std::size_t a = rg.begin(); a < rg.end(); ++a) {
                int m = 0;
                for (int j = 0; j < lists.k && m < ks; ++j) {
                    const int nb = lists.neighbours(a)[j];
                    if (!r.removed[std::size_t(nb)]) kept_nb[std::size_t(m++)] = nb;
                }
                if (m < ks) {
                    short_row[a] = 1;
                } else {
                    first_spacing[rows[a]] =
                        float(mean_distance(rows[a], kept_nb.data(), ks) / double(ks));
                }
            }
        });
        std::size_t out = 0;
        for (std::size_t a = 0; a < rows.size(); ++a) {
            if (short_row[a]) rows[out++] = rows[a];
        }
        rows.resize(out);
        if (!rows.empty() && std::size_t(K) >= n - 1) {
            throw Error("outliers: internal error: too few kept neighbours for the spacing");
        }
    }
    r.spacing = std::move(first_spacing);  // input order; compacted with the cloud
}

}  // namespace

OutlierResult remove_outliers(const PointCloud& cloud, const OutlierOptions& options,
                              const OutlierHandOver& hand_over) {
    PointCloud copy = cloud;  // copies owned arrays, shares borrowed ones (never written)
    return remove_outliers(std::move(copy), options, hand_over);
}

OutlierResult remove_outliers(PointCloud&& cloud, const OutlierOptions& options,
                              const OutlierHandOver& hand_over) {
    options.validate();
    OutlierResult r;
    r.removed.assign(cloud.size(), 0);
    if (options.enabled && cloud.size() >= std::size_t(options.k) + 1) {  // else nothing goes
        classify(cloud, options, hand_over, r);
        const std::size_t kept = cloud.size() - r.statistical - r.planarity;
        // Borrowed columns are copied first: if a copy fails, the cloud is still whole.
        Column<Vec3f> positions = copy_borrowed(cloud.positions, r.removed, kept);
        Column<Vec3f> normals = copy_borrowed(cloud.normals, r.removed, kept);
        Column<Vec3f> colors = copy_borrowed(cloud.colors, r.removed, kept);
        Column<float> scales = copy_borrowed(cloud.scales, r.removed, kept);
        Column<float> confidences = copy_borrowed(cloud.confidences, r.removed, kept);
        const auto place = [&](auto& column, auto& copy) {
            if (column.borrowed()) {
                column = std::move(copy);
            } else {
                compact_owned(column, r.removed, kept);
            }
        };
        place(cloud.positions, positions);
        place(cloud.normals, normals);
        place(cloud.colors, colors);
        place(cloud.scales, scales);
        place(cloud.confidences, confidences);
        if (!r.spacing.empty()) compact(r.spacing, r.removed, kept);
    }
    r.cloud = std::move(cloud);
    return r;
}

}  // namespace vdbrecon
