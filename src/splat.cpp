// Splatting oriented points into sparse grids (see splat.h for the kernel and references).
//
// Determinism: every (leaf, point) pair is listed, the list is sorted by (leaf key, point
// index), and each leaf is then summed by exactly one task in increasing point order. No
// floating-point sum depends on scheduling, so the grids are bit-identical for any thread count.
//
// Cost: the Gaussian is separable, exp(-|d|^2/s^2) = gx(dx) gy(dy) gz(dz), and the linear basis
// is additive, n.d = nx dx + ny dy + nz dz; per point only (2r+1) exponentials per axis are
// evaluated and the voxel loop is a handful of multiply-adds.
#include "vdbrecon/splat.h"

#include <openvdb/tools/SignedFloodFill.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>

#include "vdbrecon/error.h"

namespace vdbrecon {

void SplatOptions::validate() const {
    auto positive = [](double v, const char* name) {
        if (!(std::isfinite(v) && v > 0.0)) {
            std::ostringstream s;
            s << "splat." << name << " = " << v << ": must be a positive number";
            throw InvalidArgument(s.str());
        }
    };
    positive(voxel_size, "voxel_size");
    positive(scale_factor, "scale_factor");
    positive(sigma_voxels, "sigma_voxels");
    positive(min_sigma_voxels, "min_sigma_voxels");
    positive(max_sigma_voxels, "max_sigma_voxels");
    if (min_sigma_voxels > max_sigma_voxels) {
        throw InvalidArgument("splat.min_sigma_voxels must not exceed splat.max_sigma_voxels");
    }
    if (!(support >= 1.0 && support <= 6.0)) {
        throw InvalidArgument("splat.support = " + std::to_string(support) +
                              ": must be in 1..6 (sigmas)");
    }
    if (!(std::isfinite(min_weight) && min_weight >= 0.0)) {
        throw InvalidArgument("splat.min_weight = " + std::to_string(min_weight) +
                              ": must be a non-negative number");
    }
}

namespace {

constexpr int kLeafLog2 = 3;  // 8^3 leaves, OpenVDB's default FloatTree leaf
constexpr int kLeafDim = 1 << kLeafLog2;
constexpr int kLeafVoxels = kLeafDim * kLeafDim * kLeafDim;
constexpr int kKeyBits = 21;
constexpr std::int64_t kKeyBias = std::int64_t(1) << (kKeyBits - 1);
// Keep index coordinates well inside what a 21-bit leaf key can address (+-2^23 voxels).
constexpr double kMaxIndex = double(kKeyBias) * kLeafDim - 64.0;

inline int floor_div_leaf(int v) { return v >= 0 ? v >> kLeafLog2 : -((-v + kLeafDim - 1) >> kLeafLog2); }

inline std::uint64_t leaf_key(int lx, int ly, int lz) {
    return (std::uint64_t(lx + kKeyBias) << (2 * kKeyBits)) |
           (std::uint64_t(ly + kKeyBias) << kKeyBits) | std::uint64_t(lz + kKeyBias);
}

inline openvdb::Coord leaf_origin(std::uint64_t key) {
    const std::uint64_t mask = (std::uint64_t(1) << kKeyBits) - 1;
    const int lx = int(std::int64_t((key >> (2 * kKeyBits)) & mask) - kKeyBias);
    const int ly = int(std::int64_t((key >> kKeyBits) & mask) - kKeyBias);
    const int lz = int(std::int64_t(key & mask) - kKeyBias);
    return openvdb::Coord(lx * kLeafDim, ly * kLeafDim, lz * kLeafDim);
}

struct Pair {
    std::uint64_t key;
    std::uint32_t point;
    bool operator<(const Pair& o) const { return key != o.key ? key < o.key : point < o.point; }
};

/// Per-point kernel parameters in index space.
struct Kernel {
    double cx, cy, cz;  // centre, index units
    float nx, ny, nz;   // unit normal
    float s;            // sigma, voxels
    float r;            // support radius, voxels (0 = point skipped)
    float amp;          // (sigma_median / sigma)^2: equal kernel mass per sample
};

struct Box {
    int lo[3], hi[3];
};

inline Box support_box(const Kernel& k) {
    Box b;
    const double c[3] = {k.cx, k.cy, k.cz};
    for (int a = 0; a < 3; ++a) {
        b.lo[a] = int(std::ceil(c[a] - k.r));
        b.hi[a] = int(std::floor(c[a] + k.r));
    }
    return b;
}

inline std::size_t leaves_touched(const Box& b) {
    std::size_t n = 1;
    for (int a = 0; a < 3; ++a) {
        if (b.hi[a] < b.lo[a]) return 0;
        n *= std::size_t(floor_div_leaf(b.hi[a]) - floor_div_leaf(b.lo[a]) + 1);
    }
    return n;
}

}  // namespace

SplatResult splat(const PointCloud& cloud, const SplatOptions& options) {
    options.validate();
    initialize_openvdb();
    if (cloud.empty()) throw InvalidArgument("splat: the point cloud is empty");
    if (!cloud.has_normals()) {
        throw InvalidArgument("splat: the points have no normals. Hint: estimate them first "
                              "(--normals estimate)");
    }
    const std::size_t n = cloud.size();
    const double voxel = options.voxel_size;
    const bool use_scale = cloud.has_scales();
    const bool colors = cloud.has_colors();
    SplatResult result;

    // Per-point kernels.
    std::vector<Kernel> kernels(n);
    const double smin = options.min_sigma_voxels, smax = options.max_sigma_voxels;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t i = rg.begin(); i < rg.end(); ++i) {
            Kernel& k = kernels[i];
            const Vec3f& p = cloud.positions[i];
            const Vec3f& nr = cloud.normals[i];
            const double len = std::sqrt(double(nr[0]) * nr[0] + double(nr[1]) * nr[1] +
                                         double(nr[2]) * nr[2]);
            k.cx = double(p[0]) / voxel;
            k.cy = double(p[1]) / voxel;
            k.cz = double(p[2]) / voxel;
            double s = options.sigma_voxels;
            if (use_scale && cloud.scales[i] > 0.0f) {
                s = options.scale_factor * double(cloud.scales[i]) / voxel;
            }
            s = std::clamp(s, smin, smax);
            k.s = float(s);
            if (!(std::isfinite(len) && len > 1e-12)) {
                k.r = 0.0f;  // no usable normal: skipped
                continue;
            }
            k.nx = float(nr[0] / len);
            k.ny = float(nr[1] / len);
            k.nz = float(nr[2] / len);
            k.r = float(options.support * s);
        }
    });

    // Range check before any big allocation.
    double max_index = 0.0;
    float max_r = 0.0f;
    for (const Kernel& k : kernels) {
        max_index = std::max({max_index, std::fabs(k.cx), std::fabs(k.cy), std::fabs(k.cz)});
        max_r = std::max(max_r, k.r);
        if (k.r == 0.0f) ++result.skipped_points;
    }
    if (result.skipped_points == n) {
        throw InvalidArgument("splat: none of the " + std::to_string(n) +
                              " points has a usable (non-zero, finite) normal");
    }
    if (max_index + max_r > kMaxIndex) {
        std::ostringstream s;
        s << "splat: voxel size " << voxel << " is too small for this scan: it would need "
          << std::ceil(max_index + max_r) << " voxels from the origin along one axis (limit "
          << kMaxIndex << "). Hint: use a larger --voxel";
        throw InvalidArgument(s.str());
    }

    // Sigma statistics (world units).
    {
        std::vector<float> s;
        s.reserve(n);
        for (const Kernel& k : kernels) {
            if (k.r > 0.0f) s.push_back(k.s);
        }
        std::nth_element(s.begin(), s.begin() + std::ptrdiff_t(s.size() / 2), s.end());
        result.sigma_median = double(s[s.size() / 2]) * voxel;
        const auto mm = std::minmax_element(s.begin(), s.end());
        result.sigma_min = double(*mm.first) * voxel;
        result.sigma_max = double(*mm.second) * voxel;
    }

    // Area normalisation: every sample's kernel carries the same mass, so where fine and coarse
    // samples overlap the fine ones (smaller footprint, usually the more accurate, e.g. not at a
    // grazing angle) dominate -- the scale weighting of FSSR.
    {
        const double sm = result.sigma_median / voxel;
        for (Kernel& k : kernels) k.amp = float((sm / double(k.s)) * (sm / double(k.s)));
    }

    // (leaf, point) pairs: count, prefix-sum, fill, sort.
    std::vector<std::size_t> first_pair(n + 1, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t i = rg.begin(); i < rg.end(); ++i) {
            first_pair[i + 1] = kernels[i].r > 0.0f ? leaves_touched(support_box(kernels[i])) : 0;
        }
    });
    std::partial_sum(first_pair.begin(), first_pair.end(), first_pair.begin());
    std::vector<Pair> pairs(first_pair[n]);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t i = rg.begin(); i < rg.end(); ++i) {
            if (kernels[i].r == 0.0f) continue;
            const Box b = support_box(kernels[i]);
            std::size_t o = first_pair[i];
            for (int lx = floor_div_leaf(b.lo[0]); lx <= floor_div_leaf(b.hi[0]); ++lx) {
                for (int ly = floor_div_leaf(b.lo[1]); ly <= floor_div_leaf(b.hi[1]); ++ly) {
                    for (int lz = floor_div_leaf(b.lo[2]); lz <= floor_div_leaf(b.hi[2]); ++lz) {
                        pairs[o++] = {leaf_key(lx, ly, lz), std::uint32_t(i)};
                    }
                }
            }
        }
    });
    first_pair = {};
    tbb::parallel_sort(pairs.begin(), pairs.end());

    // Leaf ranges.
    std::vector<std::size_t> leaf_begin;
    for (std::size_t i = 0; i < pairs.size(); ++i) {
        if (i == 0 || pairs[i].key != pairs[i - 1].key) leaf_begin.push_back(i);
    }
    leaf_begin.push_back(pairs.size());
    const std::size_t num_leaves = leaf_begin.size() - 1;

    // Narrow-band half width: no |sdf| can exceed the largest support radius.
    const double half_width = std::max(3.0, std::ceil(double(max_r)));
    const float background = float(half_width * voxel);

    using FloatLeaf = openvdb::FloatTree::LeafNodeType;
    using Vec3Leaf = openvdb::Vec3fTree::LeafNodeType;
    std::vector<FloatLeaf*> sdf_leaves(num_leaves, nullptr), weight_leaves(num_leaves, nullptr);
    std::vector<Vec3Leaf*> nearest_leaves(num_leaves, nullptr);
    std::vector<Vec3Leaf*> color_leaves(colors ? num_leaves : 0, nullptr);
    std::vector<std::size_t> leaf_updates(num_leaves, 0), leaf_touched(num_leaves, 0),
        leaf_active(num_leaves, 0);
    const double min_weight = options.min_weight;

    // Per-voxel sums, voxel-major: w, then with the averaging weight u = amp * w: u, u*phi,
    // the smallest squared distance to a sample and the vector to that sample (index units; the
    // first sample in point order wins ties), and u*rgb (3) with colours.
    const int fields = colors ? 10 : 7;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, num_leaves, 4),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        std::vector<double> acc(std::size_t(kLeafVoxels) * std::size_t(fields));
        double gx[kLeafDim], gy[kLeafDim], gz[kLeafDim];
        double dx2[kLeafDim], dy2[kLeafDim], dz2[kLeafDim];
        double px[kLeafDim], py[kLeafDim], pz[kLeafDim];
        double ex[kLeafDim], ey[kLeafDim], ez[kLeafDim];
        for (std::size_t L = rg.begin(); L < rg.end(); ++L) {
            const openvdb::Coord o = leaf_origin(pairs[leaf_begin[L]].key);
            for (std::size_t v = 0; v < std::size_t(kLeafVoxels); ++v) {
                double* a = &acc[v * std::size_t(fields)];
                std::fill(a, a + fields, 0.0);
                a[3] = std::numeric_limits<double>::infinity();
            }
            std::size_t updates = 0;
            for (std::size_t q = leaf_begin[L]; q < leaf_begin[L + 1]; ++q) {
                const std::uint32_t i = pairs[q].point;
                const Kernel& k = kernels[i];
                const Box b = support_box(k);
                int lo[3], hi[3];
                for (int a = 0; a < 3; ++a) {
                    lo[a] = std::max(b.lo[a], o[a]) - o[a];
                    hi[a] = std::min(b.hi[a], o[a] + kLeafDim - 1) - o[a];
                }
                if (hi[0] < lo[0] || hi[1] < lo[1] || hi[2] < lo[2]) continue;
                const double inv_s = 1.0 / double(k.s);
                const double amp = double(k.amp);
                const double r2 = double(k.r) * double(k.r);
                auto axis = [&](int a, double c, float nc, double* g, double* d2, double* ph,
                                double* e) {
                    for (int t = lo[a]; t <= hi[a]; ++t) {
                        const double d = double(o[a] + t) - c;  // index units
                        d2[t] = d * d;
                        g[t] = std::exp(-d * d * inv_s * inv_s);
                        ph[t] = double(nc) * d * voxel;  // world units
                        e[t] = -d;                       // voxel -> sample, index units
                    }
                };
                axis(0, k.cx, k.nx, gx, dx2, px, ex);
                axis(1, k.cy, k.ny, gy, dy2, py, ey);
                axis(2, k.cz, k.nz, gz, dz2, pz, ez);
                const float* col = colors ? cloud.colors[i].data() : nullptr;
                for (int x = lo[0]; x <= hi[0]; ++x) {
                    for (int y = lo[1]; y <= hi[1]; ++y) {
                        const double dxy2 = dx2[x] + dy2[y];
                        if (dxy2 > r2) continue;
                        const double wxy = gx[x] * gy[y];
                        const double pxy = px[x] + py[y];
                        const int row = (x << (2 * kLeafLog2)) | (y << kLeafLog2);
                        for (int z = lo[2]; z <= hi[2]; ++z) {
                            const double d2 = dxy2 + dz2[z];
                            if (d2 > r2) continue;
                            const double w = wxy * gz[z];
                            const double u = amp * w;
                            double* a = &acc[std::size_t(row | z) * std::size_t(fields)];
                            a[0] += w;
                            a[1] += u;
                            a[2] += u * (pxy + pz[z]);
                            if (d2 < a[3]) {
                                a[3] = d2;
                                a[4] = ex[x];
                                a[5] = ey[y];
                                a[6] = ez[z];
                            }
                            if (col) {
                                a[7] += u * col[0];
                                a[8] += u * col[1];
                                a[9] += u * col[2];
                            }
                            ++updates;
                        }
                    }
                }
            }
            leaf_updates[L] = updates;
            std::size_t touched = 0, active = 0;
            auto valid = [&](int v) {
                const double w = acc[std::size_t(v) * std::size_t(fields)];
                return w > 0.0 && w >= min_weight;
            };
            for (int v = 0; v < kLeafVoxels; ++v) {
                touched += acc[std::size_t(v) * std::size_t(fields)] > 0.0;
                active += valid(v);
            }
            leaf_touched[L] = touched;
            leaf_active[L] = active;
            if (active == 0) continue;
            auto* sl = new FloatLeaf(o, background, false);
            auto* wl = new FloatLeaf(o, 0.0f, false);
            auto* nl = new Vec3Leaf(o, openvdb::Vec3f(0.0f), false);
            Vec3Leaf* cl = colors ? new Vec3Leaf(o, openvdb::Vec3f(0.0f), false) : nullptr;
            for (int v = 0; v < kLeafVoxels; ++v) {
                if (!valid(v)) continue;
                const double* a = &acc[std::size_t(v) * std::size_t(fields)];
                const double inv_u = 1.0 / a[1];
                const auto idx = openvdb::Index(v);
                sl->setValueOn(idx, float(std::clamp(a[2] * inv_u, -double(background),
                                                     double(background))));
                wl->setValueOn(idx, float(a[0]));
                nl->setValueOn(idx, openvdb::Vec3f(float(a[4] * voxel), float(a[5] * voxel),
                                                   float(a[6] * voxel)));
                if (cl) {
                    cl->setValueOn(idx, openvdb::Vec3f(float(a[7] * inv_u), float(a[8] * inv_u),
                                                       float(a[9] * inv_u)));
                }
            }
            sdf_leaves[L] = sl;
            weight_leaves[L] = wl;
            nearest_leaves[L] = nl;
            if (cl) color_leaves[L] = cl;
        }
    });
    pairs = {};
    kernels = {};

    // Assemble the trees (serial; leaves are disjoint, so the order does not matter).
    auto sdf = openvdb::FloatGrid::create(background);
    auto weight = openvdb::FloatGrid::create(0.0f);
    auto nearest = openvdb::Vec3fGrid::create(openvdb::Vec3f(0.0f));
    openvdb::Vec3fGrid::Ptr color = colors ? openvdb::Vec3fGrid::create(openvdb::Vec3f(0.0f))
                                           : nullptr;
    for (std::size_t L = 0; L < num_leaves; ++L) {
        result.updates += leaf_updates[L];
        result.touched_voxels += leaf_touched[L];
        result.active_voxels += leaf_active[L];
        if (!sdf_leaves[L]) continue;
        ++result.leaves;
        sdf->tree().addLeaf(sdf_leaves[L]);
        weight->tree().addLeaf(weight_leaves[L]);
        nearest->tree().addLeaf(nearest_leaves[L]);
        if (colors) color->tree().addLeaf(color_leaves[L]);
    }
    if (result.active_voxels == 0) {
        std::ostringstream s;
        s << "splat: no voxel reached the minimum weight " << options.min_weight
          << " (the points are too sparse for voxel " << voxel
          << "). Hint: a larger --voxel or a smaller --min-weight";
        throw NumericalError(s.str());
    }
    // Inactive values take the sign of their neighbourhood (a proper narrow-band level set).
    openvdb::tools::signedFloodFill(sdf->tree());

    openvdb::math::Transform::Ptr xform = openvdb::math::Transform::createLinearTransform(voxel);
    xform->postTranslate(openvdb::Vec3d(cloud.origin[0], cloud.origin[1], cloud.origin[2]));
    sdf->setTransform(xform);
    sdf->setName("sdf");
    sdf->setGridClass(openvdb::GRID_LEVEL_SET);
    weight->setTransform(xform->copy());
    weight->setName("weight");
    nearest->setTransform(xform->copy());
    nearest->setName("nearest");
    nearest->setVectorType(openvdb::VEC_CONTRAVARIANT_RELATIVE);
    if (color) {
        color->setTransform(xform->copy());
        color->setName("color");
        color->setVectorType(openvdb::VEC_INVARIANT);
    }

    Volume& vol = result.volume;
    vol.sdf = sdf;
    vol.weight = weight;
    vol.nearest = nearest;
    vol.color = color;
    vol.voxel_size = voxel;
    vol.origin = cloud.origin;
    std::ostringstream k;
    k << "gaussian w = exp(-d^2/sigma^2), support " << options.support
      << " sigma, linear basis n.(x-p), averaged with (sigma_median/sigma)^2 w";
    vol.metadata["kernel"] = k.str();
    vol.metadata["sigma_median"] = std::to_string(result.sigma_median);
    vol.metadata["sigma_min"] = std::to_string(result.sigma_min);
    vol.metadata["sigma_max"] = std::to_string(result.sigma_max);
    vol.metadata["scale_factor"] = std::to_string(options.scale_factor);
    vol.metadata["min_weight"] = std::to_string(options.min_weight);
    vol.metadata["points"] = std::to_string(n);
    return result;
}

}  // namespace vdbrecon
