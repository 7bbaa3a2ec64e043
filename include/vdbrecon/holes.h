// Mesh hole filling (P. Liepa, "Filling Holes in Meshes", SGP 2003): each boundary loop is
// triangulated by dynamic programming over the loop (the triangulation that minimises the
// largest dihedral angle to its neighbours, then the area), refined until its triangles match
// the edge lengths around the hole, and faired: the new vertices solve the uniform
// bi-Laplacian with the mesh fixed around them, so the patch continues the surface's slope
// into the hole instead of spanning it flat. Serves `--watertight` (every loop) and
// `--fill-holes N` (loops of at most N edges).
#pragma once

#include <cstddef>

#include "vdbrecon/types.h"

namespace vdbrecon {

struct HoleFillOptions {
    /// Loops with more boundary edges than this stay open; 0 fills every loop.
    std::size_t max_edges = 0;
    /// Split the patch's triangles to the density of the mesh around the hole (Liepa's
    /// refinement); without it the patch has no interior vertex and cannot be faired.
    bool refine = true;
    /// Move the patch's new vertices to the bi-Laplacian (thin plate) surface.
    bool fair = true;

    /// Throws InvalidArgument naming the field when out of range.
    void validate() const;
};

struct HoleFillResult {
    Mesh mesh;
    std::size_t loops = 0;           ///< boundary loops found
    std::size_t filled = 0;          ///< loops filled
    std::size_t added_faces = 0;
    std::size_t added_vertices = 0;
    std::size_t largest_filled = 0;  ///< edges of the longest loop filled
    std::size_t largest_open = 0;    ///< edges of the longest loop left open (0: none)
};

/// Fills the mesh's boundary loops (see above). Vertex normals of new vertices are their patch
/// faces' area-weighted normal; colours are interpolated from the loop. A mesh that is not
/// edge-manifold along a loop (a vertex where two loops touch is fine) keeps that loop open.
HoleFillResult fill_holes(const Mesh& mesh, const HoleFillOptions& options = {});

}  // namespace vdbrecon
