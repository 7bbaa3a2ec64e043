// Surface extraction from a Volume.
//
// `vdb`: OpenVDB's tools::volumeToMesh (dual marching cubes) on the "sdf" grid; quads are split
// into counter-clockwise (outward-facing) triangles along the shorter diagonal. Faces are kept
// only inside valid cells (cells whose eight corner voxels are all active), so an open scan
// stays open and nothing appears where the data is silent; faces whose vertices carry little
// summed weight (MeshOptions::min_surface_weight) are trimmed too. Vertex normals are the normalised
// SDF gradient (central differences, trilinearly interpolated).
#pragma once

#include <cstddef>

#include "vdbrecon/types.h"
#include "vdbrecon/volume.h"

namespace vdbrecon {

enum class Mesher {
    vdb,  ///< OpenVDB volumeToMesh
};

struct MeshOptions {
    /// Which mesher extracts the surface.
    Mesher method = Mesher::vdb;
    /// Iso-value of the surface, world units (0 = the zero crossing of the SDF).
    double isovalue = 0.0;
    /// volumeToMesh adaptivity, 0 (uniform) .. 1 (coarsest); keep 0 for open scans.
    double adaptivity = 0.0;
    /// Faces with a vertex whose interpolated summed weight (the "weight" grid) is below this
    /// are dropped: the surface ends where the data ends instead of extrapolating tangent
    /// planes past hole and scan borders. 0 keeps everything; dimensionless, like
    /// SplatOptions::min_weight.
    double min_surface_weight = 2.0;
    /// Faces with a vertex farther than this from every sample (the "distance" grid) are
    /// dropped: no surface is invented across gaps or past borders wider than this. In voxels;
    /// infinity disables the test.
    double max_gap = 2.0;
    /// Compute per-vertex normals from the SDF gradient.
    bool normals = true;

    /// Throws InvalidArgument naming the field when out of range.
    void validate() const;
};

struct MeshResult {
    Mesh mesh;
    std::size_t dropped_faces = 0;  ///< faces removed because they touched an invalid cell
    std::size_t trimmed_faces = 0;  ///< faces removed for low surface weight
};

/// Extracts the iso-surface of volume.sdf. Throws InvalidArgument when the volume has no sdf.
MeshResult extract_mesh(const Volume& volume, const MeshOptions& options = {});

}  // namespace vdbrecon
