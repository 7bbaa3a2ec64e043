// Edge crossings of the iso-surface (see detail/crossings.h).
#include "detail/crossings.h"

#include <numeric>

#include "vdbrecon/error.h"

namespace vdbrecon::detail {

Crossings find_crossings(const openvdb::FloatTree& sdf, float iso) {
    Crossings out;
    out.ids = std::make_shared<openvdb::UInt32Tree>(sdf, 0u, openvdb::TopologyCopy());
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    sdf.getNodes(leaves);
    const std::size_t n = leaves.size();

    // Pass 1: per voxel, which of its +x/+y/+z edges cross (kept in the id tree), per leaf count.
    std::vector<std::size_t> count(n + 1, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 8),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        openvdb::tree::ValueAccessor<const openvdb::FloatTree> acc(sdf);
        for (std::size_t L = r.begin(); L < r.end(); ++L) {
            const auto& leaf = *leaves[L];
            auto* ids = out.ids->probeLeaf(leaf.origin());
            std::size_t k = 0;
            const auto& on = leaf.getValueMask();
            const float* data = leaf.buffer().data();
            for (auto it = leaf.cbeginValueOn(); it; ++it) {
                const bool in = *it < iso;
                const openvdb::Index pos = it.pos();
                std::uint32_t mask = 0;
                for (int a = 0; a < 3; ++a) {
                    // +x, +y, +z neighbours: offset 64, 8, 1 inside the leaf.
                    const int shift = 6 - 3 * a;
                    float fw;
                    bool active;
                    if (((pos >> shift) & 7) != 7) {
                        const openvdb::Index o = pos + (openvdb::Index(1) << shift);
                        active = on.isOn(o);
                        fw = data[o];
                    } else {
                        openvdb::Coord w = it.getCoord();
                        w[a] += 1;
                        active = acc.probeValue(w, fw);
                    }
                    if (active && (fw < iso) != in) mask |= 1u << a;
                }
                ids->setValueOnly(it.pos(), mask);
                k += std::size_t(__builtin_popcount(mask));
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
    out.points.resize(total);
    out.start.resize(total);
    out.axis.resize(total);
    out.start_inside.resize(total);

    // Pass 2: ids and crossing positions (linear interpolation along the edge).
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 8),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        openvdb::tree::ValueAccessor<const openvdb::FloatTree> acc(sdf);
        for (std::size_t L = r.begin(); L < r.end(); ++L) {
            const auto& leaf = *leaves[L];
            auto* ids = out.ids->probeLeaf(leaf.origin());
            std::size_t id = count[L];
            for (auto it = leaf.cbeginValueOn(); it; ++it) {
                const std::uint32_t mask = ids->getValue(it.pos());
                ids->setValueOnly(it.pos(), std::uint32_t(id) | (mask << kIdBits));
                if (!mask) continue;
                const openvdb::Coord v = it.getCoord();
                const float fv = *it;
                for (int a = 0; a < 3; ++a) {
                    if (!((mask >> a) & 1u)) continue;
                    openvdb::Coord w = v;
                    w[a] += 1;
                    const float fw = acc.getValue(w);
                    const float t = (iso - fv) / (fw - fv);
                    openvdb::Vec3f p{float(v[0]), float(v[1]), float(v[2])};
                    p[a] += t;
                    out.points[id] = p;
                    out.start[id] = v;
                    out.axis[id] = std::uint8_t(a);
                    out.start_inside[id] = fv < iso;
                    ++id;
                }
            }
        }
    });
    return out;
}

}  // namespace vdbrecon::detail
