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
// colours follow the collapses (interpolated along the edge). Deterministic, also under
// renumbering: ties between equal costs go by the collapse's position, an edge collapses onto
// its endpoint that comes first by position, and quadrics are summed in the order of the
// faces' centroids. A ratio-only decimation of a mesh of 2^17 faces or more runs in parallel:
// slabs of equal face counts along the longest axis (by the faces' centroids; 2-16 of them by
// the mesh's size, not by the threads) decimate with the vertices they share locked, then the
// whole mesh with the seams to the target -- the same mesh for any thread count.
#pragma once

#include <cstddef>

#include "vdbrecon/types.h"

namespace vdbrecon {

/// Where a collapsed edge's vertex goes.
enum class Placement {
    edge,  ///< the quadric's minimum on the edge (a parabola in the edge parameter): the new
           ///< vertex stays on the surface's chords; on scans the lower distance to the truth
    free,  ///< the quadric's unconstrained minimum (Garland and Heckbert's optimal position;
           ///< the best point of the edge where it is ill-conditioned)
};

struct DecimateOptions {
    /// Keep at most this fraction of the faces (0 < ratio <= 1; 1 = no face-count target).
    double ratio = 1.0;
    /// Stop before a collapse whose error exceeds this (world units; 0 = no limit): the larger
    /// of the root mean square distances of the new vertex to the planes of the faces, and of
    /// the open border's edges, that its two vertices stand for (the quadrics), and of its
    /// distance to the planes through the border's and the regions' outline edges around them
    /// now (so that a corner of the border does not vanish in a mean). A mean is not a
    /// maximum: a wavy sheet decimated with max_error E stays within 1.5-2.2 E (Hausdorff),
    /// its border within 1.6 E (tested).
    double max_error = 0.0;
    /// With planar regions (Mesh::regions): no collapse moves a vertex off the plane of a
    /// region face around it by more than this (world units; 0 = max_error). The planes stage
    /// keeps its regions, creases and corners within a hundredth of a voxel so, while the rest
    /// of the mesh (and the regions' outlines within their planes) may move by max_error.
    double region_error = 0.0;
    /// Where the merged vertex goes. Bunny at 0.5 mm, ratio 0.1: edge Chamfer 51.3 um,
    /// free 55.6 um (Open3D's simplify_quadric_decimation 52.3 um) against the reference.
    Placement placement = Placement::edge;
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
