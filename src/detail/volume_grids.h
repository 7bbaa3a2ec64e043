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

/// The leaves at one place of a volume's grids (see make_volume): sdf, weight, nearest and, with
/// colours, colour, as the splat and the TSDF rule make them inside parallel loops.
struct VolumeLeaves {
    using FloatLeaf = openvdb::FloatTree::LeafNodeType;
    using Vec3Leaf = openvdb::Vec3fTree::LeafNodeType;
    std::unique_ptr<FloatLeaf> sdf, weight;
    std::unique_ptr<Vec3Leaf> nearest, color;

    /// Makes them at `origin`, every voxel off and at its grid's background (sdf `background`,
    /// the others 0): allocated under detail::heap_lock() (detail/release.h), filled after it.
    /// The caller writes the active voxels' values, then activates them with set_mask().
    void make(const openvdb::Coord& origin, float background, bool colors);
    void set_mask(const openvdb::util::NodeMask<3>& mask);
    /// Hands them, when made, to the grids' trees (`color` null without colours); false when
    /// there were none.
    bool add_to(openvdb::FloatGrid& sdf_grid, openvdb::FloatGrid& weight_grid,
                openvdb::Vec3fGrid& nearest_grid, openvdb::Vec3fGrid* color_grid);
};

/// Flood-fills the sdf's signs, gives every grid the linear transform (voxel, origin), its
/// name and class (see volume.h), and puts them in a Volume (no metadata). color may be null.
Volume make_volume(openvdb::FloatGrid::Ptr sdf, openvdb::FloatGrid::Ptr weight,
                   openvdb::Vec3fGrid::Ptr nearest, openvdb::Vec3fGrid::Ptr color, double voxel,
                   const Vec3d& origin);

}  // namespace vdbrecon::detail
