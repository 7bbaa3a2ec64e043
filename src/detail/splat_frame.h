// What a splat takes from its whole cloud rather than from each voxel's own samples: the
// statistics of all kernels. A tile of a tiled run (tiles.cpp) splats only the samples near it,
// and gets these from the whole cloud, so that its voxels are summed exactly as the untiled
// splat sums them.
#pragma once

#include <cstddef>
#include <vector>

#include "vdbrecon/splat.h"
#include "vdbrecon/types.h"

namespace vdbrecon::detail {

struct KernelFrame {
    double sigma_median = 0.0;  ///< median sigma of the usable kernels, world units (area weights)
    float max_r = 0.0f;         ///< largest support radius, voxels (the band's half width)
    float r_typical = 0.0f;     ///< the 95th percentile radius, voxels (the crease test's reach)
    std::size_t skipped = 0;    ///< points without a usable kernel (kernel_frame only)
};

/// The frame of a whole cloud (throws as splat() does for a cloud it refuses).
KernelFrame kernel_frame(const PointCloud& cloud, const SplatOptions& options);

/// What kernel_frame takes its statistics from, per point of `cloud`: its kernel's sigma
/// (voxels; -1 for a point without a usable kernel) and support radius (voxels; 0 without);
/// max_index is raised to the largest |coordinate| of a kernel centre (index space).
void kernel_sizes(const PointCloud& cloud, const SplatOptions& options, std::vector<float>& sigma,
                  std::vector<float>& radius, double& max_index);

/// The splat's refusals of a cloud's kernels: none usable (skipped == n), a grid too large for
/// OpenVDB's index range, a voxel below SplatOptions::kMinVoxelSize.
void check_kernel_range(double max_index, float max_r, std::size_t skipped, std::size_t n,
                        double voxel);

/// The cloud presummed as splat() presums it (SplatOptions::aggregate, aggregate_max_cell).
PointCloud presum(const PointCloud& cloud, const SplatOptions& options);

/// splat() in a given frame instead of the cloud's own: every voxel whose kernels are all in
/// `cloud` gets the value the whole cloud's splat gives it, bit for bit. Splats the kernels it
/// is given: no presumming (a presummed splat() is this of presum() in the samples' frame,
/// `samples` the samples themselves, which the crease model reads).
SplatResult splat_in_frame(const PointCloud& cloud, const SplatOptions& options,
                           const KernelFrame& frame, const PointCloud* samples = nullptr);

}  // namespace vdbrecon::detail
