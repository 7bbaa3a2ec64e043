// The fused volume: sparse OpenVDB grids shared by the splat, close and mesh stages, and their
// .vdb files.
//
// Grid conventions (what Houdini, Blender and pyopenvdb expect):
//  - "sdf":     FloatGrid, GRID_LEVEL_SET, world units, negative inside, background = +half_width
//               * voxel. Active voxels are exactly the *valid* voxels (enough data weight).
//  - "weight":  FloatGrid, GRID_UNKNOWN, the summed kernel weight over the splatted voxels
//               (voxels a closing filled are not in it: no data weighs there).
//  - "nearest": Vec3fGrid, world units, the vector from the voxel to the nearest sample whose
//               kernel reaches it, over the splatted voxels. The mesher uses it to keep the
//               surface near the data.
//  - "color":   Vec3fGrid (optional), weighted mean linear RGB, same active voxels as "sdf".
//  - "fill":    FloatGrid (optional, made by close_volume()), 1 on the voxels the closing
//               vouches for: faces in cells whose corners are all in it skip the mesher's
//               weight and gap trims.
//  - "density": FloatGrid, GRID_FOG_VOLUME, written to files only: 0 outside, ramping to 1 one
//               half-width inside the surface (Blender renders a grid named "density").
// The index-to-world transform is linear: world = origin + voxel_size * ijk.
#pragma once

#include <map>
#include <string>

#include <openvdb/openvdb.h>

#include "vdbrecon/types.h"

namespace vdbrecon {

struct Volume {
    openvdb::FloatGrid::Ptr sdf;     ///< signed distance (level set), see above
    openvdb::FloatGrid::Ptr weight;  ///< summed kernel weight
    openvdb::Vec3fGrid::Ptr nearest;  ///< vector to the nearest sample, world units
    openvdb::Vec3fGrid::Ptr color;   ///< weighted mean colour, or null
    openvdb::FloatGrid::Ptr fill;    ///< voxels a closing vouches for, or null
    double voxel_size = 0.0;         ///< world units
    Vec3d origin{0.0, 0.0, 0.0};     ///< world position of index (0,0,0)
    /// Free-form key/value pairs stored as file metadata (kernel, sigma, options, ...).
    std::map<std::string, std::string> metadata;

    bool empty() const { return !sdf || sdf->activeVoxelCount() == 0; }
    /// Memory of its grids (Grid::memUsage: tree nodes, values, masks), bytes.
    std::size_t memory_bytes() const;
};

/// Calls openvdb::initialize() once (thread-safe); every entry point that touches grids does.
void initialize_openvdb();

/// The fog grid written as "density": 0 outside, rising linearly to 1 at one half-width inside.
openvdb::FloatGrid::Ptr make_density(const openvdb::FloatGrid& sdf);

/// Writes the volume's grids (sdf, weight, nearest, density, color, fill) with metadata to a .vdb
/// file, atomically (temp file + rename). Throws IoError. Returns the memory of the grids written
/// (the volume's and the density grid made for the file), bytes.
std::size_t write_volume(const std::string& path, const Volume& volume);

/// Reads a volume written by write_volume (or any file with a level-set "sdf" grid; "weight"
/// "color" and "fill" are optional). Throws IoError / FormatError.
Volume read_volume(const std::string& path);

}  // namespace vdbrecon
