// Mesh decimation by quadric error metrics (M. Garland and P. Heckbert, "Surface Simplification
// Using Quadric Error Metrics", SIGGRAPH 1997): each vertex carries the sum of the squared
// distances to the planes of its original faces (area-weighted), an edge collapses to the point
// that minimises its two quadrics' sum, and the cheapest collapse goes first.
//
// Guarantees: no collapse that flips a face (turns its normal by more than max_normal_turn),
// makes the mesh non-manifold or changes its topology (the link condition of Dey et al.: the
// two vertices' common neighbours are exactly the edge's opposite vertices), so closed stays
// closed, the genus and the number of pieces stay; open borders stay put (a quadric of the
// plane through each border edge, perpendicular to its face, weighted by border_weight); vertex
// colours follow the collapses (interpolated along the edge). Serial and deterministic (ties
// broken by the edge's vertex numbers).
#pragma once

#include <cstddef>

#include "vdbrecon/types.h"

namespace vdbrecon {

struct DecimateOptions {
    /// Keep at most this fraction of the faces (0 < ratio <= 1; 1 = no face-count target).
    double ratio = 1.0;
    /// Stop before a collapse whose error (the root of its quadric error: a distance, world
    /// units) exceeds this; 0 = no limit.
    double max_error = 0.0;
    /// Border quadrics' weight against the faces' (dimensionless).
    double border_weight = 1000.0;
    /// A collapse may turn a face's normal by at most this (degrees).
    double max_normal_turn = 60.0;

    /// Throws InvalidArgument naming the field when out of range (also when neither a ratio
    /// below 1 nor a max_error is given: nothing to do).
    void validate() const;
};

struct DecimateResult {
    Mesh mesh;
    std::size_t faces_before = 0, faces_after = 0;
    std::size_t collapses = 0;
    std::size_t refused = 0;    ///< collapses refused (topology, flips), tried again later or never
    double max_error = 0.0;     ///< the largest error of a collapse made, world units
};

/// Decimates a triangle mesh (vertex normals are recomputed, colours carried).
DecimateResult decimate(const Mesh& mesh, const DecimateOptions& options);

}  // namespace vdbrecon
