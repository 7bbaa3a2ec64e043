// The splat's per-point kernels (see splat.h), shared by the splat and the crease pass that
// re-evaluates the field near sharp features (detail/creases.h).
#pragma once

#include <openvdb/openvdb.h>

#include <algorithm>
#include <cmath>

#include "vdbrecon/splat.h"
#include "vdbrecon/types.h"

namespace vdbrecon::detail {

/// Per-point kernel parameters in index space.
struct Kernel {
    double cx, cy, cz;  // centre, index units
    float nx, ny, nz;   // unit normal
    float s;            // sigma, voxels
    float r;            // support radius, voxels (0 = point skipped)
    float amp;          // (sigma_median / sigma)^2: equal kernel mass per sample
    float conf;         // the sample's confidence (1 without one): scales w and u alike
    double inv_s2;      // 1 / sigma^2
};

/// Makes a point's kernel from the cloud each time it is needed (once per piece): the cloud
/// holds everything a kernel derives from, and an array of kernels added 64 bytes per point to
/// the splat's peak memory (320 MB for 5 million points). Same arithmetic as that array had, so
/// the grids are the same bit for bit.
class Kernels {
  public:
    Kernels(const PointCloud& cloud, const SplatOptions& options)
        : cloud_(cloud), options_(options), use_scale_(cloud.has_scales()),
          use_conf_(cloud.has_confidences()) {}

    std::size_t size() const { return cloud_.size(); }
    /// Asks for point i's data ahead of its kernel (a hint: the splat's pieces take their
    /// points in block order, which is not memory order).
    void prefetch(std::size_t i) const {
        __builtin_prefetch(cloud_.positions.data() + i);
        __builtin_prefetch(cloud_.normals.data() + i);
        if (use_scale_) __builtin_prefetch(cloud_.scales.data() + i);
    }
    /// Point i's kernel centre, index units.
    openvdb::Vec3d centre(std::size_t i) const {
        const Vec3f& p = cloud_.positions[i];
        const double voxel = options_.voxel_size;
        return {double(p[0]) / voxel, double(p[1]) / voxel, double(p[2]) / voxel};
    }
    /// The median sigma, voxels: sets every kernel's amp (called before the summation).
    void set_median_sigma(double voxels) { median_sigma_ = voxels; }

    /// The length of point i's normal, double.
    double normal_length(std::size_t i) const {
        const Vec3f& nr = cloud_.normals[i];
        return std::sqrt(double(nr[0]) * nr[0] + double(nr[1]) * nr[1] + double(nr[2]) * nr[2]);
    }
    /// Point i's unit normal, as its kernel has it (a point with a usable normal).
    openvdb::Vec3f unit_normal(std::size_t i) const { return unit_normal(i, normal_length(i)); }

    /// Point i's kernel. Its shape (centre, sigma, support; r = 0 for a point without a usable
    /// normal) always; with `full` also the unit normal, inv_s2 and amp, which the summation
    /// and the crease model use. (The splat's Gaussian recurrence step exp(-2 inv_s2) is made
    /// where it is used: the crease model's evaluations do not need it.)
    Kernel operator()(std::size_t i, bool full = true) const {
        Kernel k;
        const double len = normal_length(i);
        const openvdb::Vec3d c = centre(i);
        k.cx = c[0];
        k.cy = c[1];
        k.cz = c[2];
        const double s = kernel_sigma_voxels(options_, use_scale_ ? cloud_.scales[i] : 0.0f);
        k.s = float(s);
        k.conf = use_conf_ ? cloud_.confidences[i] : 1.0f;
        if (!kernel_usable(len, k.conf)) {
            k.r = 0.0f;  // no usable normal (or no confidence): skipped
            return k;
        }
        k.r = float(options_.support * s);
        if (full) {
            const openvdb::Vec3f n = unit_normal(i, len);
            k.nx = n[0];
            k.ny = n[1];
            k.nz = n[2];
            k.inv_s2 = 1.0 / (double(k.s) * double(k.s));
            const double sm = median_sigma_;
            k.amp = float((sm / double(k.s)) * (sm / double(k.s)));
        }
        return k;
    }

  private:
    openvdb::Vec3f unit_normal(std::size_t i, double len) const {
        const Vec3f& nr = cloud_.normals[i];
        return {float(nr[0] / len), float(nr[1] / len), float(nr[2] / len)};
    }

    const PointCloud& cloud_;
    const SplatOptions& options_;
    bool use_scale_;
    bool use_conf_;
    double median_sigma_ = 0.0;
};

}  // namespace vdbrecon::detail
