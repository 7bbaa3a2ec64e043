// Edge crossings of the iso-surface (see detail/crossings.h).
//
// Both passes work on a leaf's 512 voxels as eight 64-bit words (word x, bit y << 3 | z, the
// layout of OpenVDB's leaf masks): the edges that cross along z, y and x are found for a whole
// word at once by shifting the active and inside bits by 1, 8 and one word, with the neighbouring
// leaf's face supplying the bits past the leaf's upper faces.
#include "detail/crossings.h"

#include <array>
#include <limits>
#include <numeric>

#include "vdbrecon/error.h"

namespace vdbrecon::detail {
namespace {

using Leaf = openvdb::FloatTree::LeafNodeType;
using Words = std::array<std::uint64_t, 8>;

/// Bits with z < 7 and with y < 7 in a word.
constexpr std::uint64_t kNotZ7 = 0x7F7F7F7F7F7F7F7Full;
constexpr std::uint64_t kNotY7 = 0x00FFFFFFFFFFFFFFull;

/// Active and inside (value < iso) bits of a leaf, or of the tile in its place.
struct Sides {
    Words active{}, inside{};

    /// Loads the leaf at `origin`; with face = 0, 1 or 2 only the voxels at local coordinate 0
    /// along that axis (the face a lower neighbour touches) get their inside bits.
    void load(openvdb::tree::ValueAccessor<const openvdb::FloatTree>& acc,
              const openvdb::Coord& origin, float iso, int face = -1) {
        if (const Leaf* leaf = acc.probeConstLeaf(origin)) {
            const float* data = leaf->buffer().data();
            for (int w = 0; w < 8; ++w) {
                active[w] = leaf->getValueMask().template getWord<std::uint64_t>(openvdb::Index(w));
                const float* row = data + 64 * w;
                std::uint64_t in = 0;
                if (face < 0 || (face == 0 && w == 0)) {
                    for (int b = 0; b < 64; ++b) in |= std::uint64_t(row[b] < iso) << b;
                } else if (face == 1) {
                    for (int b = 0; b < 8; ++b) in |= std::uint64_t(row[b] < iso) << b;
                } else if (face == 2) {
                    for (int b = 0; b < 64; b += 8) in |= std::uint64_t(row[b] < iso) << b;
                }
                inside[w] = in;
            }
            return;
        }
        float tile = 0.0f;
        const bool on = acc.probeValue(origin, tile);
        active.fill(on ? ~std::uint64_t(0) : 0);
        inside.fill(tile < iso ? ~std::uint64_t(0) : 0);
    }
};

}  // namespace

Crossings find_crossings(const openvdb::FloatTree& sdf, float iso, bool with_points) {
    Crossings out;
    std::vector<const Leaf*> leaves;
    sdf.getNodes(leaves);
    const std::size_t n = leaves.size();
    if (n > std::size_t(std::numeric_limits<std::int32_t>::max())) {
        throw NumericalError("meshing: too many leaves (" + std::to_string(n) + ")");
    }

    // Each leaf's upper neighbours.
    out.leaf_index.build(leaves);
    out.upper.resize(7 * n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 64),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t L = r.begin(); L < r.end(); ++L) {
            const openvdb::Coord origin = leaves[L]->origin();
            for (int d = 1; d < 8; ++d) {
                out.upper[7 * L + std::size_t(d - 1)] = std::int32_t(out.leaf_index.find(
                    origin.offsetBy(8 * (d & 1), 8 * (d >> 1 & 1), 8 * (d >> 2))));
            }
        }
    });

    // Pass 1: per leaf, the crossing edges along each axis, and their count.
    std::vector<LeafCrossingMasks>& found = out.masks;
    found.resize(n);
    std::vector<std::size_t> count(n + 1, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 8),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        openvdb::tree::ValueAccessor<const openvdb::FloatTree> acc(sdf);
        Sides self, next;
        for (std::size_t L = r.begin(); L < r.end(); ++L) {
            const openvdb::Coord origin = leaves[L]->origin();
            self.load(acc, origin, iso);
            std::uint64_t(*axis)[8] = found[L].axis;
            // z: the next bit (z < 7) or the +z neighbour's z = 0 bit (7 bits down, 8 rows).
            next.load(acc, origin.offsetBy(0, 0, 8), iso, 2);
            for (int w = 0; w < 8; ++w) {
                const std::uint64_t a = self.active[w], in = self.inside[w];
                const std::uint64_t na = ((a >> 1) & kNotZ7) | ((next.active[w] << 7) & ~kNotZ7);
                const std::uint64_t ni = ((in >> 1) & kNotZ7) | ((next.inside[w] << 7) & ~kNotZ7);
                axis[2][w] = a & na & (in ^ ni);
            }
            // y: the bit 8 up (y < 7) or the +y neighbour's y = 0 row (56 bits down).
            next.load(acc, origin.offsetBy(0, 8, 0), iso, 1);
            for (int w = 0; w < 8; ++w) {
                const std::uint64_t a = self.active[w], in = self.inside[w];
                const std::uint64_t na = ((a >> 8) & kNotY7) | (next.active[w] << 56);
                const std::uint64_t ni = ((in >> 8) & kNotY7) | (next.inside[w] << 56);
                axis[1][w] = a & na & (in ^ ni);
            }
            // x: the next word (x < 7) or the +x neighbour's word 0.
            next.load(acc, origin.offsetBy(8, 0, 0), iso, 0);
            for (int w = 0; w < 8; ++w) {
                const std::uint64_t na = w < 7 ? self.active[w + 1] : next.active[0];
                const std::uint64_t ni = w < 7 ? self.inside[w + 1] : next.inside[0];
                axis[0][w] = self.active[w] & na & (self.inside[w] ^ ni);
            }
            std::uint32_t k = 0;
            for (int w = 0; w < 8; ++w) {
                found[L].before[w] = k;
                for (int a = 0; a < 3; ++a) k += std::uint32_t(__builtin_popcountll(axis[a][w]));
            }
            count[L + 1] = k;
        }
    });
    std::partial_sum(count.begin(), count.end(), count.begin());
    const std::size_t total = count[n];
    if (total > kIdMask) {
        throw NumericalError("meshing: " + std::to_string(total) +
                             " edge crossings exceed the limit of 2^29. Hint: a larger --voxel");
    }
    out.leaf_begin = count;
    if (with_points) out.points.resize(total);
    out.start.resize(total);
    out.axis.resize(total);
    out.start_inside.resize(total);

    // Pass 2: per crossing (voxel order, then axis), its edge and position (linear interpolation
    // along the edge).
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 8),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        openvdb::tree::ValueAccessor<const openvdb::FloatTree> acc(sdf);
        for (std::size_t L = r.begin(); L < r.end(); ++L) {
            if (count[L] == count[L + 1]) continue;
            const Leaf& leaf = *leaves[L];
            const openvdb::Coord origin = leaf.origin();
            const float* data = leaf.buffer().data();
            const std::uint64_t(*axis)[8] = found[L].axis;
            // The neighbours past the upper faces (+x, +y, +z), for edges leaving the leaf.
            const Leaf* up[3];
            for (int a = 0; a < 3; ++a) {
                const std::int64_t j = out.neighbour(L, 1 << a);
                up[a] = j < 0 ? nullptr : leaves[std::size_t(j)];
            }
            std::size_t id = count[L];
            for (int w = 0; w < 8; ++w) {
                for (std::uint64_t any = axis[0][w] | axis[1][w] | axis[2][w]; any;
                     any &= any - 1) {
                    const int b = __builtin_ctzll(any);
                    const openvdb::Index pos = openvdb::Index(64 * w + b);
                    std::uint32_t mask = 0;
                    for (int a = 0; a < 3; ++a) mask |= std::uint32_t((axis[a][w] >> b) & 1u) << a;
                    const openvdb::Coord v = Leaf::offsetToLocalCoord(pos) + origin;
                    const float fv = data[pos];
                    for (int a = 0; a < 3; ++a) {
                        if (!((mask >> a) & 1u)) continue;
                        if (with_points) {
                            const int shift = 6 - 3 * a;  // +x, +y, +z: offset 64, 8, 1 in a leaf
                            float fw;
                            if (((pos >> shift) & 7) != 7) {
                                fw = data[pos + (openvdb::Index(1) << shift)];
                            } else {
                                const openvdb::Index o = pos - (openvdb::Index(7) << shift);
                                openvdb::Coord w1 = v;
                                w1[a] += 1;
                                fw = up[a] ? up[a]->buffer().data()[o] : acc.getValue(w1);
                            }
                            const float t = (iso - fv) / (fw - fv);
                            openvdb::Vec3f p{float(v[0]), float(v[1]), float(v[2])};
                            p[a] += t;
                            out.points[id] = p;
                        }
                        out.start[id] = v;
                        out.axis[id] = std::uint8_t(a);
                        out.start_inside[id] = fv < iso;
                        ++id;
                    }
                }
            }
        }
    });
    return out;
}

}  // namespace vdbrecon::detail
