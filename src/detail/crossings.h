// Edge crossings of the iso-surface and a walk over the cells it passes through, shared by our
// marching cubes and dual contouring.
//
// A crossing is a grid edge (voxel v, axis a) from v to v + e_a whose end voxels are both valid
// (active) and on opposite sides of the iso-value. Crossings are numbered leaf by leaf in the
// tree's leaf order, so the numbering does not depend on the thread count. A UInt32 tree with
// the sdf's topology stores, for every voxel, the id of its first crossing (low 29 bits) and
// which of its three edges cross (high 3 bits): a lookup is one accessor read.
#pragma once

#include <openvdb/openvdb.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cstdint>
#include <memory>
#include <vector>

#include "detail/cube.h"
#include "detail/mesh_common.h"

namespace vdbrecon::detail {

struct Crossings {
    openvdb::UInt32Tree::Ptr ids;              ///< per voxel: first id | axis mask << 29
    std::vector<openvdb::Vec3f> points;        ///< index-space crossing position, per crossing
    std::vector<openvdb::Coord> start;         ///< the edge's lower voxel, per crossing
    std::vector<std::uint8_t> axis;            ///< the edge's axis, per crossing
    std::vector<std::uint8_t> start_inside;    ///< 1 when the lower voxel is inside (f < iso)
    std::vector<std::size_t> leaf_begin;       ///< first id of each sdf leaf (leafCount() + 1)

    std::size_t size() const { return points.size(); }
};

constexpr std::uint32_t kIdBits = 29;
constexpr std::uint32_t kIdMask = (1u << kIdBits) - 1;

/// Finds every crossing of the active voxels of `sdf` (index space, iso-value `iso`).
Crossings find_crossings(const openvdb::FloatTree& sdf, float iso);

/// The ids of the crossings on the three edges (v, axis 0..2) with one lookup: id[axis] is -1
/// where that edge does not cross. Returns false when none does.
inline bool crossing_ids(openvdb::tree::ValueAccessor<const openvdb::UInt32Tree>& acc,
                         const openvdb::Coord& v, std::int64_t id[3]) {
    std::uint32_t value;
    if (!acc.probeValue(v, value) || (value >> kIdBits) == 0) return false;
    const std::uint32_t mask = value >> kIdBits;
    std::int64_t next = std::int64_t(value & kIdMask);
    for (int axis = 0; axis < 3; ++axis) id[axis] = (mask >> axis) & 1u ? next++ : -1;
    return true;
}

/// The id of the crossing on edge (v, axis), or -1 when that edge does not cross.
inline std::int64_t crossing_id(openvdb::tree::ValueAccessor<const openvdb::UInt32Tree>& acc,
                                const openvdb::Coord& v, int axis) {
    std::int64_t id[3];
    return crossing_ids(acc, v, id) ? id[axis] : -1;
}

/// A cell the surface passes through: its minimum voxel, corner values and loops.
struct SurfaceCell {
    openvdb::Coord origin;
    float value[8];
    CellLoops loops;
    std::int64_t edge_id[12];  ///< crossing id of each cube edge (-1 when it does not cross)
};

/// Calls visit(leaf_index, cell, block) for every valid cell (eight active corners) that the
/// surface crosses, in parallel over the sdf's leaves; `block` holds the sdf around the cell's leaf
/// for the visitor's own stencils. Each leaf visits its cells in index order, so a visitor that
/// appends to per-leaf storage produces a thread-count independent result.
template <typename Visit>
void for_each_surface_cell(const openvdb::FloatTree& sdf, const Crossings& crossings, float iso,
                           Visit&& visit) {
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    sdf.getNodes(leaves);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size(), 8),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        FloatAccessor acc(sdf);
        openvdb::tree::ValueAccessor<const openvdb::UInt32Tree> ids(*crossings.ids);
        auto block = std::make_unique<LeafBlock>(acc);
        SurfaceCell cell;
        for (std::size_t L = r.begin(); L < r.end(); ++L) {
            const auto& leaf = *leaves[L];
            // Without a crossing starting in the leaf, a cell of it whose corners are all in the
            // leaf has no sign change (its edges all start in the leaf): only cells on the leaf's
            // upper faces need a look, and the block is loaded when one of them is a surface cell.
            const bool any = crossings.leaf_begin[L] != crossings.leaf_begin[L + 1];
            bool loaded = any;
            if (loaded) block->load(leaf.origin());
            for (auto it = leaf.cbeginValueOn(); it; ++it) {
                const openvdb::Index p = it.pos();
                if (!any && (p & 7) != 7 && ((p >> 3) & 7) != 7 && (p >> 6) != 7) continue;
                const openvdb::Coord c = it.getCoord();
                bool valid = true, neg = false, pos = false;
                for (int k = 0; k < 8 && valid; ++k) {
                    const openvdb::Coord q =
                        c.offsetBy(kCubeCorner[k][0], kCubeCorner[k][1], kCubeCorner[k][2]);
                    valid = loaded ? block->probeValue(q, cell.value[k])
                                   : acc.probeValue(q, cell.value[k]);
                    (cell.value[k] < iso ? neg : pos) = true;
                }
                if (!valid || !neg || !pos) continue;
                if (!loaded) {
                    block->load(leaf.origin());
                    loaded = true;
                }
                cell.origin = c;
                cell_loops(cell.value, iso, cell.loops);
                for (int e = 0; e < 12; ++e) {
                    const int* s = kCubeCorner[kEdgeCorner[e][0]];
                    cell.edge_id[e] = crossing_id(ids, c.offsetBy(s[0], s[1], s[2]), kEdgeAxis[e]);
                }
                visit(L, cell, *block);
            }
        }
    });
}

}  // namespace vdbrecon::detail
