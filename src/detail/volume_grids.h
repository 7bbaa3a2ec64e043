// The Volume of finished grids, as the splat and the TSDF rule both hand it on.
#pragma once

#include <openvdb/openvdb.h>

#include <memory>

#include "vdbrecon/volume.h"

namespace vdbrecon::detail {

/// Index coordinates of the splat's and the TSDF rule's voxels stay within +-kMaxVoxelIndex
/// (2^23 less a margin): block and leaf indices then fit the 20-21 bits their packed keys give
/// each axis.
constexpr double kMaxVoxelIndex = double(1 << 23) - 64.0;

/// A leaf at `origin`, all voxels off, with its buffer allocated but not filled. (Output
/// leaves made inside a parallel loop are allocated under detail::heap_lock(), filled after.)
template <typename Leaf>
std::unique_ptr<Leaf> unfilled_leaf(const openvdb::Coord& origin) {
    auto leaf = std::make_unique<Leaf>(openvdb::PartialCreate(), origin,
                                       typename Leaf::ValueType(0), false);
    leaf->buffer().allocate();
    return leaf;
}

/// Flood-fills the sdf's signs, gives every grid the linear transform (voxel, origin), its
/// name and class (see volume.h), and puts them in a Volume (no metadata). color may be null.
Volume make_volume(openvdb::FloatGrid::Ptr sdf, openvdb::FloatGrid::Ptr weight,
                   openvdb::Vec3fGrid::Ptr nearest, openvdb::Vec3fGrid::Ptr color, double voxel,
                   const Vec3d& origin);

}  // namespace vdbrecon::detail
