// Whether the data supports a surface at a point of a volume: the test behind the mesher's trims
// (finish_mesh) and the hole closing's supported voxels (close_volume), so that both agree.
//
//  - relative weight: the summed kernel weight at the point over the weight at its nearest
//    sample. On a sampled patch it is about 1 whatever the density; past the border of an open
//    scan it falls with the distance to the last samples (to 1/2 about 0.8 sigma out). Below
//    MeshOptions::min_surface_weight the point is `weak`. Relative, so a sparse or dense
//    sampling, a fine or coarse voxel, all cut the border at the same place, and the random dips
//    of a uniform random sample (down to ~40 % of the mean at one voxel per spacing) are no
//    border (weak points are only trimmed from an open border inwards, see finish_mesh).
//  - gap: the distance to the nearest sample. Farther than MeshOptions::max_gap voxels and
//    max_gap_spacings sample spacings, the point is `far`: no surface is invented across gaps.
#pragma once

#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <memory>
#include <optional>
#include <type_traits>

#include "detail/mesh_common.h"
#include "vdbrecon/mesh.h"
#include "vdbrecon/volume.h"

namespace vdbrecon::detail {

enum class Support : std::uint8_t { ok, weak, far };

/// The SDF's central-difference gradient at voxel c (world units per voxel).
inline openvdb::Vec3d central_gradient(const FloatAccessor& acc, const openvdb::Coord& c) {
    openvdb::Vec3d g;
    for (int k = 0; k < 3; ++k) {
        openvdb::Coord lo = c, hi = c;
        --lo[k];
        ++hi[k];
        g[k] = 0.5 * (double(acc.getValue(hi)) - double(acc.getValue(lo)));
    }
    return g;
}

/// The values and active states (bit 4 dx + 2 dy + dz) of the eight corners (dx, dy, dz) of
/// the cell at voxel c, as eight probeValue() calls would give them, into v[4 dx + 2 dy + dz].
/// A cell inside one leaf (c on none of its leaf's last planes: 343 of 512 cells) takes one
/// leaf probe and eight reads of its buffer.
template <typename Accessor, typename ValueT>
std::uint32_t cell_corners(Accessor& acc, const openvdb::Coord& c, ValueT (&v)[8]) {
    using Leaf = typename std::remove_const_t<typename Accessor::TreeType>::LeafNodeType;
    std::uint32_t on = 0;
    if ((c[0] & 7) != 7 && (c[1] & 7) != 7 && (c[2] & 7) != 7) {
        if (const Leaf* leaf = acc.probeConstLeaf(c)) {
            static constexpr openvdb::Index kStep[8] = {0, 1, 8, 9, 64, 65, 72, 73};
            const openvdb::Index o = Leaf::coordToOffset(c);
            const ValueT* data = leaf->buffer().data();
            for (int k = 0; k < 8; ++k) {
                v[k] = data[o + kStep[k]];
                on |= std::uint32_t(leaf->valueMask().isOn(o + kStep[k])) << k;
            }
            return on;
        }
    }
    for (int k = 0; k < 8; ++k) {
        on |= std::uint32_t(acc.probeValue(c.offsetBy(k >> 2, (k >> 1) & 1, k & 1), v[k])) << k;
    }
    return on;
}

/// openvdb::tools::BoxSampler::sample(acc, p), bit for bit, with the corners read by
/// cell_corners().
template <typename Accessor>
double box_sample(Accessor& acc, const openvdb::Vec3d& p) {
    const openvdb::Coord c(int(std::floor(p[0])), int(std::floor(p[1])), int(std::floor(p[2])));
    float v[8];
    cell_corners(acc, c, v);
    float data[2][2][2];
    for (int k = 0; k < 8; ++k) data[k >> 2][(k >> 1) & 1][k & 1] = v[k];
    return openvdb::tools::BoxSampler::trilinearInterpolation(data, p - c.asVec3d());
}

class SupportTest {
  public:
    SupportTest(const Volume& v, const MeshOptions& o)
        : volume_(v),
          voxel_(v.sdf->voxelSize()[0]),
          min_ratio_(o.min_surface_weight),
          weight_(v.weight && v.nearest && o.min_surface_weight > 0.0),
          gap_(v.nearest && std::isfinite(o.max_gap)) {
        max_gap_ = std::max(o.max_gap * voxel_, o.max_gap_spacings * spacing(v, o));
    }

    /// MeshOptions::sample_spacing, else the volume's "sample_spacing" metadata (the pipeline
    /// records it), else 0.
    static double spacing(const Volume& v, const MeshOptions& o) {
        if (o.sample_spacing > 0.0) return o.sample_spacing;
        const auto it = v.metadata.find("sample_spacing");
        if (it == v.metadata.end()) return 0.0;
        const double h = std::strtod(it->second.c_str(), nullptr);
        return std::isfinite(h) && h > 0.0 ? h : 0.0;
    }

    bool enabled() const { return weight_ || gap_; }

    /// Per-thread accessors of the grids it reads.
    struct Accessors {
        std::unique_ptr<FloatAccessor> weight;
        std::unique_ptr<Vec3Accessor> nearest;
        std::unique_ptr<FloatAccessor> sdf;
    };
    Accessors accessors() const {
        Accessors a;
        if (weight_) a.weight = std::make_unique<FloatAccessor>(volume_.weight->tree());
        if (weight_ || gap_) a.nearest = std::make_unique<Vec3Accessor>(volume_.nearest->tree());
        if (weight_) a.sdf = std::make_unique<FloatAccessor>(volume_.sdf->tree());
        return a;
    }

    /// The support at the index-space point p. When the test samples the weight grid at p
    /// (box_sample), it leaves that value in `*weight_at_p` if given.
    Support at(Accessors& a, const openvdb::Vec3d& p,
               std::optional<double>* weight_at_p = nullptr) const {
        if (!enabled()) return Support::ok;
        openvdb::Vec3d sample(p);
        const double gap = nearest_sample(*a.nearest, p, sample);
        if (gap_ && gap > max_gap_) return Support::far;
        if (weight_ && std::isfinite(gap)) {
            const double w = box_sample(*a.weight, p);
            if (weight_at_p) *weight_at_p = w;
            const double w_sample = box_sample(*a.weight, sample);
            if (!(w >= min_ratio_ * w_sample)) return Support::weak;
        }
        return Support::ok;
    }

    /// The support at voxel c judged where the surface is: at c moved along the SDF gradient
    /// (central differences) onto the zero level (at most 8 voxels). The summed weight falls off
    /// the surface as it does past a border, so a voxel a voxel off a well-sampled surface would
    /// look weak.
    Support at_voxel(Accessors& a, const openvdb::Coord& c) const {
        if (!enabled()) return Support::ok;
        openvdb::Vec3d p = c.asVec3d();
        if (weight_) {
            const openvdb::Vec3d g = central_gradient(*a.sdf, c);
            // phi / |g| is the distance in voxels (g is per voxel, phi in world units). The whole
            // band is judged at its surface, so that the supported voxels are as thick as the
            // band: a closing bridges a hole in a thick shell (its outer and inner faces curve
            // into the hole less than a thin shell's).
            const double len2 = g.lengthSqr();
            if (len2 > 0.04 * voxel_ * voxel_) {
                const double phi = double(a.sdf->getValue(c));
                const double most = 8.0 / std::sqrt(len2);  // steps of |g| voxels
                const double step = std::clamp(phi / len2, -most, most);
                p -= g * step;
            }
        }
        return at(a, p);
    }

    /// Distance (world units) from the index-space point p to the nearest of the samples
    /// recorded at the eight corners of its cell, and that sample (index space): an upper bound
    /// of the distance to the data that is exact whenever p's nearest sample is some corner's
    /// nearest sample (the usual case). Infinity when no corner records one.
    double nearest_sample(Vec3Accessor& acc, const openvdb::Vec3d& p,
                          openvdb::Vec3d& sample) const {
        const openvdb::Coord c(int(std::floor(p[0])), int(std::floor(p[1])), int(std::floor(p[2])));
        openvdb::Vec3f e[8];
        const std::uint32_t on = cell_corners(acc, c, e);
        // sample = corner + e (world); point = p * voxel
        const auto sample_of = [&](int k) {
            return c.offsetBy(k >> 2, (k >> 1) & 1, k & 1).asVec3d() +
                   openvdb::Vec3d(e[k]) / voxel_;
        };
        // Squared distances, one square root at the end. The first corner with the least is
        // chosen by selects, not branches: which corner wins is data, and mispredicted branches
        // made this search most of the mesh stage's support test.
        constexpr double inf = std::numeric_limits<double>::infinity();
        double best = inf;
        int best_k = -1;
        for (int k = 0; k < 8; ++k) {
            const double d2 = (on >> k) & 1u ? (sample_of(k) - p).lengthSqr() : inf;
            const bool less = d2 < best;
            best = less ? d2 : best;
            best_k = less ? k : best_k;
        }
        if (best_k >= 0) sample = sample_of(best_k);
        return std::sqrt(best) * voxel_;
    }

  private:
    const Volume& volume_;
    double voxel_, min_ratio_, max_gap_;
    bool weight_, gap_;
};

}  // namespace vdbrecon::detail
