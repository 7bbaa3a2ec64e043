// Splatting (fusion): every oriented point adds a Gaussian-weighted signed distance to a sparse
// grid, as in floating scale surface reconstruction (S. Fuhrmann and M. Goesele, "Floating Scale
// Surface Reconstruction", SIGGRAPH 2014), with a Gaussian weight and a linear basis:
//
//     w_i(x)   = exp(-|x - p_i|^2 / sigma_i^2)   for |x - p_i| <= support * sigma_i, else 0
//     phi_i(x) = n_i . (x - p_i)                 (signed distance to the point's tangent plane)
//     u_i(x)   = a_i w_i(x),  a_i = (sigma_median / sigma_i)^2
//     sdf(x)   = sum_i u_i(x) phi_i(x) / sum_i u_i(x)
//     weight(x)= sum_i w_i(x)
//
// sigma_i = clamp(scale_factor * scale_i, min_sigma_voxels * voxel, max_sigma_voxels * voxel)
// for points with a scale, sigma_voxels * voxel for points without.
//
// The averaging weight u_i gives every sample the same kernel mass (pi sigma_median^2), so where
// fine and coarse samples overlap, the fine ones (small footprint; coarse ones are typically
// grazing-angle or far-range samples) dominate -- FSSR's scale weighting. With a uniform sigma
// u_i = w_i and this is the plain Gaussian average. `weight` keeps the plain sum of w_i: since
// sigma follows the local spacing it is a scale-free coverage measure (about pi (sigma/h)^2 on a
// uniformly sampled patch of spacing h), used as the confidence. On the Stanford bunny scans at
// voxel 0.5 mm the split raised F(0.5 mm) from 0.9972 to 0.9984 and lowered the Chamfer distance
// from 61.6 to 56.8 um against the plain average.
//
// A voxel is valid (active) where weight >= min_weight, or within two voxels of the surface
// (|sdf| <= 2 voxels) where weight >= min_weight / 5 (the surface past a convex corner, where
// the kernels overlap thinly); everything else is background, so nothing is ever meshed where
// no data supports it.
//
// Parallel and deterministic: points are bucketed by the 16^3 block (2x2x2 leaves) they touch,
// each block is summed by one task in increasing point order, so the grids are bit-identical
// for any number of threads.
#pragma once

#include <cmath>
#include <cstddef>
#include <memory>

#include "vdbrecon/types.h"
#include "vdbrecon/volume.h"

namespace vdbrecon {

struct SplatOptions {
    /// Voxel edge, world units. Must be > 0 (the pipeline picks one from the spacing when 0).
    double voxel_size = 0.0;
    /// sigma_i = scale_factor * scale_i for points with a per-point scale (dimensionless).
    double scale_factor = 1.0;
    /// sigma for points without a scale, in voxels.
    double sigma_voxels = 1.0;
    /// Lower bound on sigma, in voxels. A cell the surface crosses has corners up to sqrt(3)
    /// voxels off the surface, and it is meshed only when all eight are valid: at sigma >= 1
    /// voxel those corners still carry >= e^-3 (5 %) of the on-surface weight.
    double min_sigma_voxels = 1.0;
    /// Upper bound on sigma, in voxels (bounds the work of isolated points).
    double max_sigma_voxels = 4.0;
    /// Support radius of the kernel, in sigmas. 2.5 makes 42 % fewer updates but opens sparse
    /// sharp tips (docs/how-it-works.md, Splat).
    double support = 3.0;
    /// Voxels with summed weight below this are invalid (inactive), but for those within two
    /// voxels of the surface, which need a fifth of it; dimensionless. A uniformly sampled
    /// surface has weight about pi (sigma/h)^2 >= pi on it (h = spacing).
    double min_weight = 0.05;
    /// Creases: next to edges where the sample normals fall into groups at least this far apart
    /// (degrees), the field is each face's own field combined as the solid they bound (max for a
    /// convex pair of faces, min for a concave one), not their blend: edges and corners stay
    /// sharp and the sign stays right where few samples reach. 0 = off.
    double crease_angle = 30.0;
    /// Presumming (aggregate_samples below): splat() first sums the samples of one cell of
    /// this many sigmas into one kernel; 0 (the default) = every sample its own kernel, FSSR's
    /// sum as it is. A group: one sigma level, normals within crease_angle of the group's (90
    /// degrees without a crease model), and cells sized by the samples' own sigma before the
    /// clamp to min_sigma_voxels, so that samples much denser than the voxel get small cells
    /// (with cells of the clamped sigma a dense patch's open border came out ragged: the
    /// mesher's support test measures from the groups). The sum is linear in the samples'
    /// planes, so what changes is that a group's Gaussians share one centre; the crease model
    /// still reads the samples. Stanford bunny at 0.5 mm with 1.5: 193k kernels for 361k
    /// samples, 41M kernel updates instead of 66M, the same F-scores. Not the default: a hole
    /// that --close fills in an open sphere (7 voxels across) got a cap 1.1 voxel high
    /// (0.2 without). Range-image fusion presums its frames by DepthOptions::aggregate (on by
    /// default; SplatAccumulator does not presum).
    double aggregate = 0.0;
    /// ... with cells no wider than this, voxels (0 = no cap): a sampled surface then stays
    /// within the mesher's gap test (MeshOptions::max_gap, 2 voxels) of its groups. Uncapped,
    /// the bunny's sparser patches (larger sigmas, larger cells) got about 90 more holes.
    double aggregate_max_cell = 1.25;
    /// Memory budget of the run, bytes; 0 = half the physical memory. Before it allocates the
    /// grids, splat() counts the 8^3 leaves the kernels touch and refuses (InvalidArgument, with
    /// a voxel size that would fit) when about kBytesPerLeaf per leaf plus the points exceed it.
    std::size_t max_memory = 0;
    /// (Kernel, block) pairs listed and sorted at once, at most (0: automatic, half a pair per
    /// point and at least 4M); more are summed a slab of blocks at a time. Only memory and time
    /// depend on it, never the grids.
    std::size_t slab_pairs = 0;

    /// Smallest voxel splat() accepts: OpenVDB's linear transforms refuse voxel^3 < 3e-15.
    static constexpr double kMinVoxelSize = 1.5e-5;
    /// Memory of the whole run per 8^3 leaf of the splatted volume, bytes: the grids (sdf,
    /// weight, nearest, colour), the mesher's and the volume writer's copies and the mesh of the
    /// surface crossing the leaf. Measured: 269 MB peak for 7,202 leaves and 362k points on the
    /// Stanford bunny at 0.5 mm, about 29 kB per leaf once the points are taken off.
    static constexpr std::size_t kBytesPerLeaf = 32 * 1024;

    /// Throws InvalidArgument naming the field when out of range.
    void validate() const;
};

/// The memory budget `max_memory` stands for, bytes (half the physical memory when it is 0).
std::size_t memory_budget(const SplatOptions& options);

struct SplatResult {
    Volume volume;
    std::size_t active_voxels = 0;   ///< valid voxels
    std::size_t touched_voxels = 0;  ///< voxels with any weight (valid or not)
    std::size_t leaves = 0;          ///< 8^3 leaves allocated
    std::size_t memory_bytes = 0;    ///< memory of the grids (Volume::memory_bytes)
    std::size_t points = 0;          ///< kernels splatted (samples, or their presummed groups)
    std::size_t samples = 0;         ///< samples given (the same as points without presumming)
    std::size_t updates = 0;         ///< point-voxel kernel evaluations inside the support
    double sigma_min = 0, sigma_median = 0, sigma_max = 0;  ///< world units
    std::size_t skipped_points = 0;  ///< points without a usable normal (zero/NaN), not splatted
    std::size_t crease_voxels = 0;   ///< voxels next to creases whose value the crease model set
};

/// A sample's sigma in voxels before the clamp: scale_factor * scale / voxel for a scale > 0,
/// else sigma_voxels.
inline double raw_sigma_voxels(const SplatOptions& options, float scale) {
    return scale > 0.0f ? options.scale_factor * double(scale) / options.voxel_size
                        : options.sigma_voxels;
}

/// A sample's sigma in voxels by the rule above: raw_sigma_voxels clamped to
/// [min_sigma_voxels, max_sigma_voxels].
inline double kernel_sigma_voxels(const SplatOptions& options, float scale) {
    const double s = raw_sigma_voxels(options, scale);
    return s < options.min_sigma_voxels ? options.min_sigma_voxels
                                        : (s > options.max_sigma_voxels ? options.max_sigma_voxels : s);
}

/// Whether the splat uses a sample with this normal length and confidence: a finite normal
/// longer than 1e-12 and a finite confidence > 0 (FSSR's weight carries the confidence; a
/// sample of confidence <= 0 or NaN weighs nothing and is skipped like one without a normal).
inline bool kernel_usable(double normal_length, float confidence) {
    return std::isfinite(normal_length) && normal_length > 1e-12 && confidence > 0.0f &&
           std::isfinite(confidence);
}

/// Samples summed into fewer before a splat ("presumming"): the samples of one sigma level
/// (half octaves of kernel_sigma_voxels) and one cell (`cell` x the level's sigma, on a grid
/// fixed in the cloud's frame) whose normals lie within 90 degrees of the group's become one
/// sample at their confidence-weighted mean position, with their confidence-weighted mean
/// normal (not unit length: shorter where the normals disagree; the splat uses its
/// direction), confidence sum c_i, the scale of their mean sigma and their mean colour. The
/// splat's numerator is linear in the samples' planes, so what changes is only that a group's
/// Gaussians share one centre (an error of second order in cell/sigma); aggregating aggregates
/// sums what their samples would (src/aggregate.cpp). Samples the splat would skip (no normal,
/// confidence <= 0, not finite) are left out. `cell` <= 0 returns the cloud as it is. `max_cell`
/// > 0 caps a cell's edge, in voxels; `max_angle` < 90 degrees narrows the normals a group
/// takes (the samples' normals within max_angle of its summed normal); `raw_levels` sizes the
/// cells by the sigma before the clamp (raw_sigma_voxels; levels down to 1/16 of
/// min_sigma_voxels), not the kernel's. Deterministic: each group
/// sums its samples in increasing order, in double, and the groups come cells in (level, z, y, x)
/// order, a cell's in the order they were opened; samples 2^18 cells or more from the origin
/// follow, each a group of its own. Sorted by cell and summed by chunks of cells in parallel.
PointCloud aggregate_samples(PointCloud cloud, const SplatOptions& options, double cell,
                             double max_cell = 0.0, double max_angle = 90.0,
                             bool raw_levels = false);

/// Splats an oriented cloud (normals required) into a Volume. Throws InvalidArgument when the
/// cloud has no normals or the options are out of range.
SplatResult splat(const PointCloud& cloud, const SplatOptions& options);

namespace detail {
struct SplatState;
}

/// Splats clouds one after another onto the same sums: range-image fusion adds one frame at a
/// time, so memory follows the grid, not the number of frames. result() is the volume of all
/// clouds added so far, by the rules of splat(); adding the same clouds in the same order gives
/// the same grids bit for bit for any thread count. What differs from one splat() of all of
/// them at once: the sums are kept in grids between clouds (the first cloud is held until a
/// second comes, so the volume of one cloud is made from its block sums, without grids of
/// sums) and the nearest sample's distance is read back from the `nearest` grid, the area
/// normalisation's reference sigma is the voxel (a constant factor of every u that cancels in
/// sdf = sum u phi / sum u), and there is no crease model (it needs every sample of a leaf at
/// once).
class SplatAccumulator {
  public:
    /// Throws InvalidArgument when the options are out of range. Clouds added must have
    /// `origin` as their origin.
    explicit SplatAccumulator(const SplatOptions& options, const Vec3d& origin = {0.0, 0.0, 0.0});
    ~SplatAccumulator();
    SplatAccumulator(SplatAccumulator&&) noexcept;
    SplatAccumulator& operator=(SplatAccumulator&&) noexcept;

    /// Adds an oriented cloud (normals required; confidences, scales and colours used as by
    /// splat(): every cloud has colours or none). Throws InvalidArgument as splat() does.
    void add(PointCloud cloud);
    /// The volume of everything added so far (NumericalError when no voxel is valid).
    SplatResult result() const;
    /// The same, leaving the accumulator empty: the sums are freed as the volume is made, so
    /// that it takes their memory instead of more (the last result of a fusion).
    SplatResult take_result();

    const SplatOptions& options() const;
    const Vec3d& origin() const;
    std::size_t clouds() const;  ///< clouds added
    std::size_t points() const;  ///< their points
    /// Memory of the accumulated sums, bytes.
    std::size_t memory_bytes() const;

  private:
    std::unique_ptr<detail::SplatState> state_;
};

}  // namespace vdbrecon
