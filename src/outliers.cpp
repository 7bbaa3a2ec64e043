// Point outlier removal (see outliers.h).
#include "vdbrecon/outliers.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
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

/// Keeps the rows of an owned column not removed, in place (does not throw).
template <typename T>
void compact_owned(Column<T>& v, const std::vector<char>& removed, std::size_t kept) {
    if (v.empty() || v.borrowed()) return;
    std::vector<T>& values = v.edit();
    std::size_t out = 0;
    for (std::size_t i = 0; i < values.size(); ++i) {
        if (!removed[i]) values[out++] = values[i];
    }
    values.resize(kept);
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

/// The rules of remove_outliers: fills r.removed, the counts and r.neighbours (not r.cloud).
void classify(const PointCloud& cloud, const OutlierOptions& options, OutlierResult& r) {
    const std::size_t n = cloud.size();

    // Indices only: the distances are computed where needed, the same floats the search found
    // (at 5M points and k = 16 keeping them would take another 320 MB).
    r.neighbours = KnnIndex(cloud.positions).self_neighbours(options.k, false);
    const KnnResult& knn = r.neighbours;
    const int k = knn.k;
    std::vector<double> spacing(n);  // d_i
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t i = rg.begin(); i < rg.end(); ++i) {
            double s = 0.0;
            for (int j = 0; j < k; ++j) s += std::sqrt(double(knn.sq_dist(cloud.positions, i, j)));
            spacing[i] = s / k;
        }
    });
    std::vector<double> sorted = spacing;
    std::nth_element(sorted.begin(), sorted.begin() + std::ptrdiff_t(n / 2), sorted.end());
    const double median = sorted[n / 2];
    sorted = {};
    // 1 = statistical, 2 = planarity (0 = kept).
    std::vector<char> rule(n, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1024),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t i = rg.begin(); i < rg.end(); ++i) {
            const int* nb = knn.neighbours(i);
            double local = 0.0;
            for (int j = 0; j < k; ++j) local += spacing[std::size_t(nb[j])];
            local /= k;
            if (!(local > 0.0)) continue;  // coincident points: nothing to compare with
            const double ratio = spacing[i] / local;
            if (options.statistical_ratio > 0.0 && ratio > options.statistical_ratio) {
                rule[i] = 1;
                continue;
            }
            if (options.planarity_ratio > 0.0 && spacing[i] > options.planarity_spacing * median) {
                Eigen::Vector3d ev, dir;
                if (detail::neighbourhood_pca(cloud.positions, i, nb, k, ev, dir) &&
                    ev[1] > 0.0 && ev[0] / ev[1] > options.planarity_ratio) {
                    rule[i] = 2;
                }
            }
        }
    });
    for (std::size_t i = 0; i < n; ++i) {
        if (rule[i] == 1) ++r.statistical;
        if (rule[i] == 2) ++r.planarity;
        r.removed[i] = rule[i] != 0;
    }
}

}  // namespace

OutlierResult remove_outliers(const PointCloud& cloud, const OutlierOptions& options) {
    PointCloud copy = cloud;  // copies owned arrays, shares borrowed ones (never written)
    return remove_outliers(std::move(copy), options);
}

OutlierResult remove_outliers(PointCloud&& cloud, const OutlierOptions& options) {
    options.validate();
    OutlierResult r;
    r.removed.assign(cloud.size(), 0);
    if (options.enabled && cloud.size() >= std::size_t(options.k) + 1) {  // else nothing goes
        classify(cloud, options, r);
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
    }
    r.cloud = std::move(cloud);
    return r;
}

}  // namespace vdbrecon
