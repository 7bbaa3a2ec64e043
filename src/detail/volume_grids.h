// The Volume of finished grids, as the splat and the TSDF rule both hand it on.
#pragma once

#include <openvdb/openvdb.h>

#include "vdbrecon/volume.h"

namespace vdbrecon::detail {

/// Index coordinates of the splat's and the TSDF rule's voxels stay within +-kMaxVoxelIndex
/// (2^23 less a margin): block and leaf indices then fit the 20-21 bits their packed keys give
/// each axis.
constexpr double kMaxVoxelIndex = double(1 << 23) - 64.0;

/// Flood-fills the sdf's signs, gives every grid the linear transform (voxel, origin), its
/// name and class (see volume.h), and puts them in a Volume (no metadata). color may be null.
Volume make_volume(openvdb::FloatGrid::Ptr sdf, openvdb::FloatGrid::Ptr weight,
                   openvdb::Vec3fGrid::Ptr nearest, openvdb::Vec3fGrid::Ptr color, double voxel,
                   const Vec3d& origin);

}  // namespace vdbrecon::detail
