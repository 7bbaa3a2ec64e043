// Mesh cleanup after extraction: small connected pieces are dropped, and the surface can be
// smoothed without shrinking.
//
// Components are edge-connected sets of faces (two faces touching at an edge belong together;
// the same definition as mesh_topology()). A component is kept when it has at least
// min_component_ratio times the faces of the largest one and at least min_component_faces faces:
// the fragments that scanner noise and stray points leave around a scan go, while a second real
// object of comparable size stays.
//
// Smoothing is Taubin's lambda|mu filter (G. Taubin, "A signal processing approach to fair surface
// design", SIGGRAPH 1995): a shrinking umbrella step x += lambda L(x) followed by an inflating one
// x += mu L(x) with mu < -lambda, which removes high-frequency noise and leaves the low
// frequencies (the overall shape and its volume) nearly unchanged. L is the uniform Laplacian
// (mean of the edge neighbours minus the vertex). Boundary vertices of open scans stay where they
// are, so open borders do not creep inwards.
#pragma once

#include <cstddef>

#include "vdbrecon/types.h"

namespace vdbrecon {

struct CleanOptions {
    /// Components with fewer faces than this fraction of the largest component's are removed
    /// (0 keeps every component; 1 keeps only the largest and any of equal size).
    double min_component_ratio = 0.01;
    /// Components with fewer faces than this are removed, whatever the ratio (count).
    std::size_t min_component_faces = 0;
    /// Taubin lambda|mu iterations (0 = no smoothing); each iteration is one lambda and one mu
    /// step.
    int smooth_iterations = 0;
    /// Taubin's shrinking factor, in (0, 1).
    double smooth_lambda = 0.5;
    /// Taubin's inflating factor, negative with |mu| > lambda (pass band k_PB = 1/lambda + 1/mu
    /// ~ 0.1 with the defaults).
    double smooth_mu = -0.53;

    /// Throws InvalidArgument naming the field when out of range.
    void validate() const;
};

struct CleanResult {
    Mesh mesh;
    std::size_t components_before = 0;   ///< edge-connected components in the input
    std::size_t removed_components = 0;  ///< components dropped as too small
    std::size_t removed_faces = 0;       ///< faces in those components
    std::size_t removed_vertices = 0;    ///< vertices no longer referenced
    int smoothed_iterations = 0;         ///< Taubin iterations applied
};

/// Removes small components and optionally smooths. Vertex attributes (normals, colours) and
/// face regions follow their vertices and faces; after smoothing, normals are recomputed from
/// the faces (area-weighted). Deterministic: kept faces and vertices stay in their input order.
CleanResult clean_mesh(const Mesh& mesh, const CleanOptions& options = {});
/// The same on a mesh the caller gives up: compacted in place, without a copy.
CleanResult clean_mesh(Mesh&& mesh, const CleanOptions& options = {});

}  // namespace vdbrecon
