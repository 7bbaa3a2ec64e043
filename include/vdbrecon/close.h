// Morphological closing of the volume before meshing: dilate > fill > erode.
//
// Hole closing (`hole_radius` R, voxels) keeps open borders: it closes the *supported* voxels --
// valid voxels that would survive the mesher's trims (weight >= MeshOptions::min_surface_weight
// and at most MeshOptions::max_gap voxels from a sample) -- with a cube of side 2R+1: dilate by
// R, erode by R (26-neighbour steps). Holes up to about 2R voxels across are covered; a straight
// or convex outer border of an open scan is a fixed point of the closing, so it stays where it
// was. The voxels this adds that have no splatted value are filled by extending the field
// layer by layer from the valid voxels around them: each new voxel gets the mean of its known
// 26-neighbours' first-order predictions phi_j + grad_j . (x - x_j) (weights 1/|x - x_j|^2), so
// planes continue exactly and curved patches continue along their tangents.
//
// Solid closing (`solid_radius` R, voxels) is for watertight objects: the surface is meshed (dual
// contouring, whatever MeshOptions::method says: it keeps the sharp rims of grooves),
// rebuilt as an exact narrow-band signed distance field (tools::meshToVolume; voxels the exterior
// cannot reach -- enclosed cavities -- come out inside), offset outwards by R voxels and back
// inwards by R (each offset re-extracts the shifted iso-surface and rebuilds the distance field,
// tools::levelSetRebuild). Concavities narrower than about 2R disappear; convex parts return to
// where they were (up to the rebuilds' sub-voxel resampling).
//
// With both, holes are closed first. The result's `fill` grid marks the voxels the closing vouches
// for: the mesher keeps faces there whatever their weight or distance to the samples. Colours are
// extended into new voxels the same way as the field (plain weighted mean).
#pragma once

#include <cstddef>

#include "vdbrecon/mesh.h"
#include "vdbrecon/volume.h"

namespace vdbrecon {

struct CloseOptions {
    /// Hole closing radius, voxels (0 = off). Holes up to about 2R voxels across close.
    int hole_radius = 0;
    /// Solid closing radius, voxels (0 = off). Concavities narrower than about 2R close.
    int solid_radius = 0;

    bool enabled() const { return hole_radius > 0 || solid_radius > 0; }
    /// Throws InvalidArgument naming the field when out of range (0..64).
    void validate() const;
};

struct CloseResult {
    Volume volume;
    std::size_t supported_voxels = 0;  ///< hole closing: voxels the mesher's trims would keep
    std::size_t closed_voxels = 0;     ///< hole closing: supported voxels after the closing
    std::size_t filled_voxels = 0;     ///< voxels that had no splatted value and were filled
    std::size_t solid_voxels_before = 0;  ///< solid closing: voxels inside the surface, before
    std::size_t solid_voxels_after = 0;   ///< ... and after
};

/// Closes the volume (see above). `mesh` gives the trims that define the supported voxels (hole
/// closing and the surface solid closing starts from). Returns the input
/// unchanged when no closing is enabled. Throws InvalidArgument for a volume without sdf, and
/// NumericalError when solid closing finds no closed surface to work on.
CloseResult close_volume(const Volume& volume, const CloseOptions& options,
                         const MeshOptions& mesh = {});

/// The signed distance field of a closed mesh (in the local frame of `frame`'s meshes, as
/// extract_mesh gives them) as a volume in `frame`'s grid frame: a level set "sdf" `half_width`
/// voxels to each side and a "fill" grid over its band (what `--watertight` writes to
/// <out>.closed.vdb). Throws InvalidArgument for an empty mesh or frame.
Volume mesh_volume(const Mesh& mesh, const Volume& frame, float half_width = 3.0f);

}  // namespace vdbrecon

