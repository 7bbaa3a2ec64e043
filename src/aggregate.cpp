// Presumming samples before the splat (see splat.h: aggregate_samples).
//
// The splat's numerator is linear in each sample's plane, so samples whose kernels are nearly
// the same Gaussian add up to one sample:
//
//     C = sum c_i,  p = sum c_i p_i / C,  m = sum c_i n_i / C
//     sum_i c_i w_i(x) n_i . (x - p_i)  ~=  C w(x - p) m . (x - p)
//
// The Gaussians' centres move to their mean (an error of second order in the group's spread
// over sigma), and the planes become the plane through the mean with the mean normal. That
// plane, not the mean of the tangent planes (m . x = sum c_i n_i . p_i / C), is the right one
// on a curved surface: the tangent planes of a convex patch lie outside it by about
// spread^2 / 2R at the patch's centre, the mean position inside by as much, and the kernels'
// own blend of tangent planes already has the first bias (bunny sequence at 1 mm, cells of one
// sigma: Chamfer 38.6 um with the tangent-plane mean, 35.6 um with this, 36.5 um without
// presumming). Range-image fusion sees every patch from many frames with several pixels per
// voxel: the bunny sequence's 1.19 M samples become 84 k kernels in cells of 1.5 sigma.
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "detail/radix_sort.h"
#include "vdbrecon/splat.h"

namespace vdbrecon {

namespace {

constexpr std::uint64_t kNoGroup = std::numeric_limits<std::uint64_t>::max();
constexpr int kLevels = 15;  ///< sigma levels, half octaves above min_sigma_voxels (< 15:
                             ///< kNoGroup is no cell's key)
constexpr int kCellBits = 20;
constexpr std::int64_t kCellBias = std::int64_t(1) << (kCellBits - 1);

struct Keyed {
    std::uint64_t key;
    std::uint32_t index;
    float sigma;  ///< the sample's sigma, voxels
};

double length(const Vec3f& n) {
    return std::sqrt(double(n[0]) * n[0] + double(n[1]) * n[1] + double(n[2]) * n[2]);
}

/// Bits that hold 0..n.
int bits_for(std::uint64_t n) {
    int b = 0;
    while (b < 64 && (n >> b) != 0) ++b;
    return b;
}

/// The cell keys (sigma level, cell on a grid fixed in the cloud's frame, so that groups of
/// groups fall into the same cells) of the samples, kNoGroup for a sample the splat would skip;
/// an empty vector when some sample lies more than 2^19 cells from the origin.
std::vector<Keyed> cell_keys(const PointCloud& cloud, const SplatOptions& o, double cell) {
    const std::size_t n = cloud.size();
    const double edge0 = cell * o.min_sigma_voxels * o.voxel_size;  // level 0's cell
    std::vector<Keyed> keys(n);
    const bool use_conf = cloud.has_confidences(), use_scale = cloud.has_scales();
    std::atomic<bool> outside{false};
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1 << 14),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            keys[i] = {kNoGroup, std::uint32_t(i), 0.0f};
            const Vec3f& p = cloud.positions[i];
            const double len = length(cloud.normals[i]);
            const float c = use_conf ? cloud.confidences[i] : 1.0f;
            if (!(std::isfinite(len) && len > 1e-12 && c > 0.0f && std::isfinite(c)) ||
                !(std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]))) {
                continue;
            }
            const double s = kernel_sigma_voxels(o, use_scale ? cloud.scales[i] : 0.0f);
            const int level =
                s <= o.min_sigma_voxels
                    ? 0
                    : std::min(int(std::lround(2.0 * std::log2(s / o.min_sigma_voxels))), kLevels - 1);
            const double edge = edge0 * std::exp2(0.5 * level);
            std::uint64_t key = std::uint64_t(level);
            for (int a = 2; a >= 0; --a) {
                double q = std::floor(double(p[a]) / edge) + double(kCellBias);
                if (!(q >= 0.0 && q < double(2 * kCellBias))) {
                    outside = true;
                    q = 0.0;
                }
                key = key << kCellBits | std::uint64_t(q);
            }
            keys[i].key = key;
            keys[i].sigma = float(s);
        }
    });
    if (outside) return {};
    return keys;
}

/// One group's sums, in double, in increasing sample order.
struct GroupSums {
    double c = 0.0, sigma = 0.0;
    std::array<double, 3> p{0, 0, 0}, n{0, 0, 0}, rgb{0, 0, 0};
};

/// The groups of one cell: its samples, in order, each joining the first group whose summed
/// normal is less than 90 degrees from its own (opposite sides of a thin wall never mix).
/// Normals are summed as they are (a group's mean normal is shorter than 1 where they
/// disagree), so that groups of groups sum exactly what their samples would.
void cell_groups(const PointCloud& cloud, const Keyed* first, const Keyed* last,
                 std::vector<GroupSums>& out) {
    const std::size_t begin = out.size();
    const bool use_conf = cloud.has_confidences(), colors = cloud.has_colors();
    for (const Keyed* k = first; k != last; ++k) {
        const std::size_t i = k->index;
        const Vec3f& p = cloud.positions[i];
        const Vec3f& n = cloud.normals[i];
        std::size_t g = begin;
        while (g < out.size() &&
               out[g].n[0] * n[0] + out[g].n[1] * n[1] + out[g].n[2] * n[2] <= 0.0) {
            ++g;
        }
        if (g == out.size()) out.emplace_back();
        GroupSums& s = out[g];
        const double c = use_conf ? double(cloud.confidences[i]) : 1.0;
        for (int a = 0; a < 3; ++a) {
            s.p[a] += c * double(p[a]);
            s.n[a] += c * double(n[a]);
            if (colors) s.rgb[a] += c * double(cloud.colors[i][a]);
        }
        s.c += c;
        s.sigma += c * double(k->sigma);
    }
}

}  // namespace

PointCloud aggregate_samples(PointCloud cloud, const SplatOptions& options, double cell) {
    if (!(cell > 0.0) || cloud.size() < 2 || !cloud.has_normals()) return cloud;
    options.validate();
    if (cloud.size() > std::numeric_limits<std::uint32_t>::max()) return cloud;
    std::vector<Keyed> keys = cell_keys(cloud, options, cell);
    if (keys.empty()) return cloud;
    // Sorted on the bits in which the keys differ (kNoGroup last).
    std::uint64_t lo = kNoGroup, hi = 0;
    for (const Keyed& k : keys) {
        if (k.key == kNoGroup) continue;
        lo = std::min(lo, k.key);
        hi = std::max(hi, k.key);
    }
    if (lo == kNoGroup) return PointCloud{};  // nothing the splat would use
    const int bits = bits_for(hi - lo) + 1;
    const std::uint64_t last = (std::uint64_t(1) << bits) - 1;
    detail::radix_sort(keys, bits,
                       [&](const Keyed& k) { return k.key == kNoGroup ? last : k.key - lo; });
    std::size_t end = keys.size();
    while (end > 0 && keys[end - 1].key == kNoGroup) --end;

    // Cells in fixed chunks of the sorted keys (a chunk starts at the first cell that begins
    // in it), each chunk's groups in order: the same groups for any thread count.
    const std::size_t chunks = detail::chunk_count(end);
    std::vector<std::vector<GroupSums>> parts(chunks);
    detail::for_each_chunk(end, [&](std::size_t c, std::size_t b, std::size_t e) {
        while (b < e && b > 0 && keys[b].key == keys[b - 1].key) ++b;
        while (b < e) {
            std::size_t j = b + 1;
            while (j < end && keys[j].key == keys[b].key) ++j;
            cell_groups(cloud, &keys[b], &keys[j], parts[c]);
            b = j;
        }
    });
    keys = std::vector<Keyed>{};
    std::size_t groups = 0;
    for (const auto& part : parts) groups += part.size();

    const bool colors = cloud.has_colors();
    std::vector<Vec3f> positions, normals, rgb;
    std::vector<float> scales, confidences;
    positions.reserve(groups);
    normals.reserve(groups);
    rgb.reserve(colors ? groups : 0);
    scales.reserve(groups);
    confidences.reserve(groups);
    for (const auto& part : parts) {
        for (const GroupSums& s : part) {
            const double nn = std::sqrt(s.n[0] * s.n[0] + s.n[1] * s.n[1] + s.n[2] * s.n[2]);
            if (!(nn > 1e-6 * s.c)) continue;  // normals that cancel: no plane
            Vec3f x, nu, col;
            for (int a = 0; a < 3; ++a) {
                x[a] = float(s.p[a] / s.c);
                nu[a] = float(s.n[a] / s.c);
                col[a] = float(s.rgb[a] / s.c);
            }
            positions.push_back(x);
            normals.push_back(nu);
            if (colors) rgb.push_back(col);
            confidences.push_back(float(s.c));
            // The scale whose sigma is the group's mean sigma (within the clamp, which the mean
            // of clamped sigmas never leaves).
            scales.push_back(float(s.sigma / s.c * options.voxel_size / options.scale_factor));
        }
    }
    PointCloud out;
    out.origin = cloud.origin;
    out.positions = std::move(positions);
    out.normals = std::move(normals);
    if (colors) out.colors = std::move(rgb);
    out.scales = std::move(scales);
    out.confidences = std::move(confidences);
    return out;
}

}  // namespace vdbrecon
