// Test helpers that build volumes (OpenVDB headers: included only by the tests that need them).
#pragma once

#include <openvdb/tools/LevelSetSphere.h>
#include <openvdb/tools/SignedFloodFill.h>

#include <cmath>
#include <functional>

#include "vdbrecon/volume.h"

namespace vdbrecon::test {

/// A narrow-band level-set sphere as a Volume (grid "sdf", half width 3 voxels).
inline Volume sphere_volume(float radius, const openvdb::Vec3f& centre, float voxel) {
    initialize_openvdb();
    Volume v;
    v.sdf = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(radius, centre, voxel, 3.0f);
    v.sdf->setName("sdf");
    v.voxel_size = voxel;
    return v;
}

/// An analytic signed distance (negative inside), world units.
using Field = std::function<double(const openvdb::Vec3d&)>;

/// A level-set volume sampled from an analytic signed distance over [-extent, extent]^3: every
/// voxel within `half_width` voxels of the surface is active, the rest is signed background.
inline Volume analytic_volume(const Field& sdf, double extent, double voxel,
                              double half_width = 3.0) {
    initialize_openvdb();
    const float bg = float(half_width * voxel);
    auto grid = openvdb::FloatGrid::create(bg);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(voxel));
    grid->setGridClass(openvdb::GRID_LEVEL_SET);
    grid->setName("sdf");
    auto acc = grid->getAccessor();
    const int n = int(std::ceil(extent / voxel));
    for (int i = -n; i <= n; ++i) {
        for (int j = -n; j <= n; ++j) {
            for (int k = -n; k <= n; ++k) {
                const double d = sdf(openvdb::Vec3d(i, j, k) * voxel);
                if (std::fabs(d) < bg) acc.setValue(openvdb::Coord(i, j, k), float(d));
            }
        }
    }
    openvdb::tools::signedFloodFill(grid->tree());
    Volume v;
    v.sdf = grid;
    v.voxel_size = voxel;
    return v;
}

}  // namespace vdbrecon::test
