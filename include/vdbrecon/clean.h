// Mesh cleanup after extraction: pieces the data does not support are dropped, and the surface
// can be smoothed without shrinking.
//
// Components are edge-connected sets of faces (two faces touching at an edge belong together;
// the same definition as mesh_topology()). A component goes when too few samples built it, not
// because another one is bigger: its evidence is the number of samples' worth of supported
// surface,
//
//     E = sum over its faces f of  area_f * min(1, w_f / w_typical) / h^2,
//
// where w_f is the summed kernel weight at the face (the mean of its vertices', from the splat's
// "weight" grid), w_typical the median of that weight over the mesh's vertices and h the sample
// spacing. On a surface sampled at spacing h, area / h^2 is the number of samples on it, and
// the weight ratio discounts what only a kernel's tail reaches: a single stray sample's disc
// counts about half a sample, five strays in the air a few, a rooftop, a chair or a mug on a
// table hundreds or more, whatever else the scene holds. The scale is the data's own, so a fine
// or coarse voxel, a sparse or dense scan give the same verdict. Optionally (for one object)
// pieces smaller than a fraction of the largest one also go.
//
// Smoothing is Taubin's lambda|mu filter (G. Taubin, "A signal processing approach to fair surface
// design", SIGGRAPH 1995): a shrinking umbrella step x += lambda L(x) followed by an inflating one
// x += mu L(x) with mu < -lambda, which removes high-frequency noise and leaves the low
// frequencies (the overall shape and its volume) nearly unchanged. L is the uniform Laplacian
// (mean of the edge neighbours minus the vertex). Boundary vertices of open scans stay where they
// are, so open borders do not creep inwards.
#pragma once

#include <cstddef>
#include <vector>

#include "vdbrecon/types.h"

namespace vdbrecon {

struct CleanOptions {
    /// Components backed by fewer samples than this are removed (the evidence E above, a
    /// count; 0 keeps every component whatever its evidence).
    double min_component_samples = 20.0;
    /// The sample spacing h the evidence is counted in, world units; 0 = the mesh's median edge
    /// length (the pipeline gives the median sample spacing).
    double sample_spacing = 0.0;
    /// Components with fewer faces than this fraction of the largest component's are removed
    /// too (0, the default, keeps a piece whatever its size; 1 keeps only the largest and any
    /// of equal size: for a single object).
    double min_component_ratio = 0.0;
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
    std::size_t removed_components = 0;  ///< components dropped (either reason below)
    std::size_t removed_unsupported = 0; ///< ... of them, backed by too few samples
    std::size_t removed_small = 0;       ///< ... of them, too small beside the largest (ratio,
                                         ///< faces) though well supported
    double typical_support = 0.0;        ///< w_typical, the median weight (0 without weights)
    std::size_t removed_faces = 0;       ///< faces in those components
    std::size_t removed_vertices = 0;    ///< vertices no longer referenced
    int smoothed_iterations = 0;         ///< Taubin iterations applied
};

/// Removes unsupported (and optionally small) components and optionally smooths. `support`:
/// per vertex, the summed kernel weight (MeshResult::support); empty counts every face as fully
/// supported (E = area / h^2). Vertex attributes (normals, colours) and face regions follow
/// their vertices and faces; after smoothing, normals are recomputed from the faces
/// (area-weighted). Deterministic: kept faces and vertices stay in their input order.
CleanResult clean_mesh(const Mesh& mesh, const CleanOptions& options = {},
                       const std::vector<float>& support = {});
/// The same on a mesh the caller gives up: compacted in place, without a copy.
CleanResult clean_mesh(Mesh&& mesh, const CleanOptions& options = {},
                       const std::vector<float>& support = {});

}  // namespace vdbrecon
