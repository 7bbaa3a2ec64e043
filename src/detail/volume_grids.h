// The Volume of finished grids, as the splat and the TSDF rule both hand it on.
#pragma once

#include <openvdb/openvdb.h>

#include <memory>
#include <optional>

#include "vdbrecon/volume.h"

namespace vdbrecon::detail {

/// Index coordinates of the splat's and the TSDF rule's voxels stay within +-kMaxVoxelIndex
/// (2^23 less a margin): block and leaf indices then fit the 20-21 bits their packed keys give
/// each axis.
constexpr double kMaxVoxelIndex = double(1 << 23) - 64.0;

/// The grids a volume's leaves go into (VolumeLeaves::add_to), each through an accessor:
/// leaves handed over in block or leaf order share their internal nodes, which the accessors
/// keep (the bunny's splat at 0.5 mm: its 7,278 places' leaves 4.3 -> 3.6 ms, median of 8,
/// against each tree's addLeaf from the root).
class VolumeTrees {
  public:
    /// `color` null without colours.
    VolumeTrees(openvdb::FloatGrid& sdf, openvdb::FloatGrid& weight, openvdb::Vec3fGrid& nearest,
                openvdb::Vec3fGrid* color)
        : sdf_(sdf.tree()), weight_(weight.tree()), nearest_(nearest.tree()) {
        if (color) color_.emplace(color->tree());
    }

  private:
    friend struct VolumeLeaves;
    openvdb::tree::ValueAccessor<openvdb::FloatTree> sdf_, weight_;
    openvdb::tree::ValueAccessor<openvdb::Vec3fTree> nearest_;
    std::optional<openvdb::tree::ValueAccessor<openvdb::Vec3fTree>> color_;
};

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
    /// Hands them, when made, to the grids' trees; false when there were none.
    bool add_to(VolumeTrees& trees);
};

/// Flood-fills the sdf's signs, gives every grid the linear transform (voxel, origin), its
/// name and class (see volume.h), and puts them in a Volume (no metadata). color may be null.
Volume make_volume(openvdb::FloatGrid::Ptr sdf, openvdb::FloatGrid::Ptr weight,
                   openvdb::Vec3fGrid::Ptr nearest, openvdb::Vec3fGrid::Ptr color, double voxel,
                   const Vec3d& origin);

}  // namespace vdbrecon::detail
