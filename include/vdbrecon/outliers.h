// Point outlier removal before splatting, with two rules over each point's k nearest neighbours:
//
//  - statistical: d_i, the mean distance of point i to its k neighbours, compared with the local
//    average, the mean of d_j over those neighbours. A point with d_i > statistical_ratio times
//    that average sits apart from a surface that is otherwise densely sampled around it (the
//    local form of R. B. Rusu et al.'s statistical outlier removal, "Towards 3D point cloud based
//    object maps for household environments", RAS 2008, which compares d_i with the global
//    mean; the local average keeps varying scan densities, e.g. LiDAR range fall-off, intact).
//  - planarity: lambda_0 / lambda_1, the ratio of the two smallest eigenvalues of the
//    neighbourhood covariance, is near 0 on a surface (one thin direction) and near 1 for a
//    blob of scattered points. Points above planarity_ratio whose d_i is also above
//    planarity_spacing times the median d over the cloud are removed: this catches clusters of
//    stray points (whose neighbours are strays too, so the statistical rule sees nothing odd),
//    while sharp corners and thin ridges of real geometry, which are non-planar too but densely
//    sampled, stay.
//
// Both rules look at the cloud as given (one neighbour search), so the result does not depend
// on the order in which points are tested, nor on the thread count.
#pragma once

#include <cstddef>
#include <vector>

#include "vdbrecon/knn.h"
#include "vdbrecon/types.h"

namespace vdbrecon {

struct OutlierOptions {
    /// Run the removal at all. On by default: on the Stanford bunny scans (voxel 0.5 mm) it
    /// removes 1163 of 362272 points and raises F(0.5 mm) from 0.99754 to 0.99787 (Chamfer-L1
    /// 57.7 -> 56.7 um, 25 -> 7 components before cleanup).
    bool enabled = true;
    /// Neighbours per point (count).
    int k = 16;
    /// Statistical rule: remove when d_i > ratio x the neighbours' mean d_j (dimensionless;
    /// 0 disables the rule).
    double statistical_ratio = 3.0;
    /// Planarity rule: lambda_0 / lambda_1 above this (0..1; 0 disables the rule) ...
    double planarity_ratio = 0.3;
    /// ... and d_i above this times the cloud's median d (dimensionless).
    double planarity_spacing = 1.5;
    /// The neighbour search (the normal stage reuses its lists: give both the same).
    KnnOptions knn;
    /// Memory only: while the search runs, the cloud's own columns it does not read (normals,
    /// colours, scales, confidences) wait in an unnamed temporary file ($TMPDIR, else /tmp)
    /// when they hold at least this many bytes (a 20M-point cloud's normals: 229 MiB; 0:
    /// always, SIZE_MAX: never). Where no file can be made they stay in memory, with a warning.
    std::size_t park_bytes = std::size_t(64) << 20;

    /// Throws InvalidArgument naming the field when out of range.
    void validate() const;
};

/// What remove_outliers hands on from its neighbour search, so that the normal stage need not
/// search again.
struct OutlierHandOver {
    /// Every input point's k nearest neighbours (OutlierResult::neighbours): 64 bytes per point
    /// at k = 16, 320 MB for 5 million points. A normal estimation needs them.
    bool lists = false;
    /// > 0 (and <= k): each kept point's mean distance to its spacing_k nearest kept points
    /// (OutlierResult::spacing), the kNN scale of normals.h. Costs no lists.
    int spacing_k = 0;
};

struct OutlierResult {
    PointCloud cloud;                ///< the kept points, all attributes, input order
    std::size_t statistical = 0;     ///< removed by the statistical rule
    std::size_t planarity = 0;       ///< removed by the planarity rule (and not the first)
    std::vector<char> removed;       ///< #P flags of the input points, 1 = removed
    /// With OutlierHandOver::lists: the k nearest neighbours of every point of the input,
    /// indices only (KnnResult::sq_dist gives a distance), for the normal stage to take its own
    /// from (KnnResult::subset). Empty otherwise, or when the removal did not run.
    KnnResult neighbours;
    /// With OutlierHandOver::spacing_k: one value per kept point (cloud order). Empty otherwise,
    /// or when the removal did not run.
    std::vector<float> spacing;
    /// The kept points' median sample spacing from the density of their k nearest (see
    /// median_density_spacing in knn.h), world units; 0 when the removal did not run. The
    /// pipeline's automatic voxel is taken from it.
    double density_spacing = 0.0;
};

/// Removes outliers (see above). With fewer than k + 1 points nothing is removed.
///
/// The neighbour lists are searched a batch at a time and, unless handed over, not kept: they
/// are the stage's largest memory.
OutlierResult remove_outliers(const PointCloud& cloud, const OutlierOptions& options = {},
                              const OutlierHandOver& hand_over = {});
/// The same, keeping the points in the given cloud's own arrays (compacted in place; borrowed
/// ones are copied): no second copy of the cloud. If it throws, the cloud is as it was.
OutlierResult remove_outliers(PointCloud&& cloud, const OutlierOptions& options = {},
                              const OutlierHandOver& hand_over = {});

}  // namespace vdbrecon
