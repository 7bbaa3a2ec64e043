// The splat's field next to sharp creases (see creases.cpp).
#pragma once

#include <openvdb/openvdb.h>

#include <cstddef>
#include <vector>

#include "detail/kernels.h"
#include "vdbrecon/types.h"

namespace vdbrecon::detail {

struct CreaseStats {
    std::size_t candidates = 0;  ///< active voxels whose neighbourhood's normals spread widely
    std::size_t modelled = 0;    ///< voxels whose value the piecewise model replaced
};

/// How far the crease test looks from a leaf (voxels): the largest kernel radius and the one most
/// kernels (95 %) stay within; of the whole cloud, also when a tile's samples are splatted.
struct CreaseReach {
    float r_max = 0.0f;
    float r_typical = 0.0f;
};

/// The reach of kernels whose radii (voxels, 0 for a point skipped) are `radius`.
CreaseReach crease_reach(const std::vector<float>& radius);

/// Re-evaluates the signed distance of the active voxels of `sdf` (world units, index space of
/// the kernels) that lie next to a crease of the sampled surface, from the same kernels as the
/// splat but with the samples grouped by normal: each group (one face of the crease) gives its
/// own weighted field, and the groups are combined as the solid they bound (max for a convex
/// pair, min for a concave one). `crease_angle` (radians) is the least angle between two groups'
/// normals that counts as a crease. Deterministic for any thread count.
CreaseStats sharpen_creases(openvdb::FloatTree& sdf, const Kernels& kernels, std::size_t points,
                            double voxel, double crease_angle, float background,
                            const CreaseReach& reach);

}  // namespace vdbrecon::detail
