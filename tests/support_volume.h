// Test helpers that build volumes (OpenVDB headers: included only by the tests that need them).
#pragma once

#include <openvdb/tools/LevelSetSphere.h>

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

}  // namespace vdbrecon::test
