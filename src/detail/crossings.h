// Edge crossings of the iso-surface and a walk over the cells it passes through, shared by our
// marching cubes, dual marching cubes and dual contouring; and the split of a cell's loops into
// the chains that get a vertex each in the two dual meshers (loop_chains).
//
// A crossing is a grid edge (voxel v, axis a) from v to v + e_a whose end voxels are both valid
// (active) and on opposite sides of the iso-value. Crossings are numbered leaf by leaf in the
// tree's leaf order, within a leaf by voxel, then axis, so the numbering does not depend on the
// thread count. Per sdf leaf, three bit masks (one per axis, eight 64-bit words in the layout of
// OpenVDB's leaf masks) mark the voxels whose edge crosses, and a count per word of the crossings
// in the words before it: a voxel's first crossing id is the leaf's first id plus the crossing
// bits before it, a few popcounts (224 bytes a leaf, against 2 kB for an id per voxel: the bunny
// at 0.5 mm, 1.6 instead of 14.7 MB of memory that the meshing would touch afresh). The walk over
// the surface cells copies each leaf's cell corners (values, active states, and the packed id:
// first id | axis mask << 29, 0 where no edge crosses) into a dense CellBlock and picks the cells
// from per-row crossing bits, without a tree lookup per cell.
#pragma once

#include <openvdb/openvdb.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include "detail/cube.h"
#include "detail/mesh_common.h"

namespace vdbrecon::detail {

constexpr std::uint32_t kIdBits = 29;

/// The number of bits set in a 3-bit axis mask. Not __builtin_popcount: the library is built for
/// baseline x86-64, where that is a call into libgcc (3 % of the mesh stage).
inline std::uint32_t bits3(std::uint32_t m) { return (m & 1u) + ((m >> 1) & 1u) + (m >> 2); }
constexpr std::uint32_t kIdMask = (1u << kIdBits) - 1;

/// Which voxels of a leaf have a crossing edge along each axis (bit b of word w: voxel offset
/// 64 w + b), and per word the number of crossings in the words before it.
struct LeafCrossingMasks {
    std::uint64_t axis[3][8];
    std::uint32_t before[8];
};

/// Leaf index by leaf origin: open addressing with linear probing in a table at most half full
/// (a lookup is a hash and a compare or two).
class LeafIndex {
  public:
    void build(const std::vector<const openvdb::FloatTree::LeafNodeType*>& leaves) {
        std::size_t size = 16;
        while (size < 2 * leaves.size()) size *= 2;
        mask_ = size - 1;
        origin_.assign(size, openvdb::Coord(kEmpty));
        index_.assign(size, 0);
        for (std::size_t L = 0; L < leaves.size(); ++L) {
            std::size_t h = hash(leaves[L]->origin()) & mask_;
            while (origin_[h][0] != kEmpty) h = (h + 1) & mask_;
            origin_[h] = leaves[L]->origin();
            index_[h] = std::uint32_t(L);
        }
    }
    /// The index of the leaf at `o`, or -1.
    std::int64_t find(const openvdb::Coord& o) const {
        for (std::size_t h = hash(o) & mask_;; h = (h + 1) & mask_) {
            if (origin_[h] == o) return index_[h];
            if (origin_[h][0] == kEmpty) return -1;
        }
    }

  private:
    static constexpr int kEmpty = std::numeric_limits<int>::max();
    static std::size_t hash(const openvdb::Coord& c) {
        const std::uint64_t k = (std::uint64_t(std::uint32_t(c[0] >> 3)) << 42) ^
                                (std::uint64_t(std::uint32_t(c[1] >> 3)) << 21) ^
                                std::uint64_t(std::uint32_t(c[2] >> 3));
        return std::size_t((k * 0x9E3779B97F4A7C15ull) >> 20);
    }
    std::vector<openvdb::Coord> origin_;  ///< kEmpty where free
    std::vector<std::uint32_t> index_;
    std::size_t mask_ = 0;
};

struct Crossings {
    LeafIndex leaf_index;                  ///< the sdf leaves by origin
    std::vector<LeafCrossingMasks> masks;  ///< per sdf leaf (the tree's leaf order)
    /// Per leaf, the index of the sdf leaf past its upper faces: upper[7 L + d - 1] for the
    /// neighbour at offset 8 (d & 1, d >> 1 & 1, d >> 2), d = 1..7, or -1 where there is none.
    std::vector<std::int32_t> upper;
    std::vector<openvdb::Vec3f> points;        ///< index-space crossing position, per crossing
                                               ///< (linear interpolation; empty unless asked)
    std::vector<openvdb::Coord> start;         ///< the edge's lower voxel, per crossing
    std::vector<std::uint8_t> axis;            ///< the edge's axis, per crossing
    std::vector<std::uint8_t> start_inside;    ///< 1 when the lower voxel is inside (f < iso)
    std::vector<std::size_t> leaf_begin;       ///< first id of each sdf leaf (leafCount() + 1)

    std::size_t size() const { return leaf_begin.empty() ? 0 : leaf_begin.back(); }
    /// The index of the leaf at offset d from leaf L (as in upper; 0 is L itself), or -1.
    std::int64_t neighbour(std::size_t L, int d) const {
        return d == 0 ? std::int64_t(L) : upper[7 * L + std::size_t(d - 1)];
    }
    /// The packed ids (first id | axis mask << kIdBits, or 0) of `count` consecutive voxels of
    /// leaf L from offset `pos`, within one word of its masks (pos % 64 + count <= 64).
    void packed_ids(std::size_t L, int pos, int count, std::uint32_t* out) const {
        const LeafCrossingMasks& m = masks[L];
        const int w = pos >> 6, b = pos & 63;
        const std::uint64_t a0 = m.axis[0][w], a1 = m.axis[1][w], a2 = m.axis[2][w];
        const std::uint64_t below = (std::uint64_t(1) << b) - 1;  // b < 64
        std::uint32_t id =
            std::uint32_t(leaf_begin[L]) + m.before[w] +
            std::uint32_t(__builtin_popcountll(a0 & below) + __builtin_popcountll(a1 & below) +
                          __builtin_popcountll(a2 & below));
        for (int k = 0; k < count; ++k) {
            const int bit = b + k;
            const std::uint32_t mask = std::uint32_t((a0 >> bit) & 1u) |
                                       std::uint32_t((a1 >> bit) & 1u) << 1 |
                                       std::uint32_t((a2 >> bit) & 1u) << 2;
            out[k] = mask ? id | (mask << kIdBits) : 0u;
            id += bits3(mask);
        }
    }
};

/// Finds every crossing of the active voxels of `sdf` (index space, iso-value `iso`); with
/// `with_points`, also the linearly interpolated crossing points (dual contouring places its own).
Crossings find_crossings(const openvdb::FloatTree& sdf, float iso, bool with_points);

/// The corners of a leaf's cells -- its voxels and one layer past its upper faces, origin ..
/// origin + 8 on each axis -- copied from up to eight leaves into dense arrays: sdf values,
/// active states and packed crossing ids (0 where no edge crosses).
class CellBlock {
  public:
    static constexpr int kN = 9;
    static constexpr int kX = kN * kN, kY = kN;  ///< index steps along x and y (z: 1)

    /// Copies the block of leaf L, at `origin`.
    void load(FloatAccessor& values, const Crossings& crossings, std::size_t L,
              const openvdb::Coord& origin) {
        for (int dx = 0; dx < 2; ++dx) {
            for (int dy = 0; dy < 2; ++dy) {
                for (int dz = 0; dz < 2; ++dz) {
                    // Block range along each axis: 0..7 from this leaf, 8 from the next one's 0.
                    const int nx = dx ? 1 : 8, ny = dy ? 1 : 8, nz = dz ? 1 : 8;
                    const openvdb::Coord o = origin.offsetBy(8 * dx, 8 * dy, 8 * dz);
                    const auto* leaf = values.probeConstLeaf(o);
                    if (!leaf) {
                        float tile = 0.0f;
                        const bool tile_on = values.probeValue(o, tile);
                        for (int x = 0; x < nx; ++x) {
                            for (int y = 0; y < ny; ++y) {
                                const int row = (8 * dx + x) * kX + (8 * dy + y) * kY + 8 * dz;
                                std::fill(value_ + row, value_ + row + nz, tile);
                                std::fill(on_ + row, on_ + row + nz, std::uint8_t(tile_on));
                                std::fill(id_ + row, id_ + row + nz, 0u);
                            }
                        }
                        continue;
                    }
                    const float* data = leaf->buffer().data();
                    const int d = dx | dy << 1 | dz << 2;
                    const std::size_t N = std::size_t(crossings.neighbour(L, d));
                    const auto& mask = leaf->getValueMask();
                    for (int x = 0; x < nx; ++x) {
                        for (int y = 0; y < ny; ++y) {
                            const int row = (8 * dx + x) * kX + (8 * dy + y) * kY + 8 * dz;
                            // A z-row of a leaf: 8 consecutive values, one byte of its mask.
                            const int l = (x << 6) | (y << 3);
                            const unsigned bits =
                                mask.template getWord<std::uint8_t>(openvdb::Index(l >> 3));
                            crossings.packed_ids(N, l, nz, id_ + row);
                            if (nz == 8) {  // fixed-size copies, which the compiler inlines
                                std::copy(data + l, data + l + 8, value_ + row);
                                for (int z = 0; z < 8; ++z) {
                                    on_[row + z] = std::uint8_t((bits >> z) & 1u);
                                }
                            } else {
                                value_[row] = data[l];
                                on_[row] = std::uint8_t(bits & 1u);
                            }
                        }
                    }
                }
            }
        }
        // Per (x, y) row, bit z set where the edge along each axis crosses.
        for (int x = 0; x < kN; ++x) {
            for (int y = 0; y < kN; ++y) {
                std::uint32_t r[3] = {0, 0, 0};
                const int row = x * kX + y * kY;
                for (int z = 0; z < kN; ++z) {
                    const std::uint32_t m = id_[row + z] >> kIdBits;
                    for (int a = 0; a < 3; ++a) r[a] |= ((m >> a) & 1u) << z;
                }
                for (int a = 0; a < 3; ++a) rows_[a][x][y] = std::uint16_t(r[a]);
            }
        }
    }

    /// Bit z set when the cell at offset (x, y, z) from the leaf's origin, 0 <= x, y, z < 8, has
    /// a crossing edge: x edges start at its corners (0, 0|1, 0|1), y edges at (0|1, 0, 0|1),
    /// z edges at (0|1, 0|1, 0).
    unsigned cells_with_crossings(int x, int y) const {
        const unsigned ex = rows_[0][x][y] | rows_[0][x][y + 1];
        const unsigned ey = rows_[1][x][y] | rows_[1][x + 1][y];
        const unsigned ez =
            rows_[2][x][y] | rows_[2][x + 1][y] | rows_[2][x][y + 1] | rows_[2][x + 1][y + 1];
        return (ex | (ex >> 1) | ey | (ey >> 1) | ez) & 0xFFu;
    }

    /// The block index of the voxel at offset (x, y, z) from the leaf's origin, 0 <= x, y, z <= 8.
    static int index(int x, int y, int z) { return x * kX + y * kY + z; }

    float value(int i) const { return value_[i]; }
    bool on(int i) const { return on_[i] != 0; }
    /// Bit a set when the edge (voxel i, axis a) crosses.
    unsigned crossing_mask(int i) const { return id_[i] >> kIdBits; }
    /// The id of the crossing on the edge (voxel i, axis a), or -1 when it does not cross.
    std::int64_t crossing_id(int i, int axis) const {
        const std::uint32_t mask = id_[i] >> kIdBits;
        if (!((mask >> axis) & 1u)) return -1;
        return std::int64_t(id_[i] & kIdMask) + bits3(mask & ((1u << axis) - 1u));
    }

  private:
    float value_[kN * kN * kN];
    std::uint8_t on_[kN * kN * kN];
    std::uint32_t id_[kN * kN * kN];
    std::uint16_t rows_[3][kN][kN];
};

/// Whether an edge starting just past the upper faces of the leaf at `origin` (in one of its
/// seven upper neighbours, on the layer next to the leaf) crosses: the cells of a leaf without
/// crossings of its own can only have such ones.
inline bool has_upper_crossing(const Crossings& crossings, std::size_t L) {
    for (int d = 1; d < 8; ++d) {
        const int dx = d & 1, dy = (d >> 1) & 1, dz = d >> 2;
        const std::int64_t N = crossings.neighbour(L, d);
        if (N < 0) continue;
        // The neighbour's layer 0 along each axis it is offset on, all of it along the others:
        // word 0 only (x), bits y = 0 of each word (the low byte), bits z = 0 (every eighth).
        const std::uint64_t layer = (dy ? 0xFFull : ~0ull) & (dz ? 0x0101010101010101ull : ~0ull);
        const LeafCrossingMasks& m = crossings.masks[std::size_t(N)];
        for (int w = 0; w < (dx ? 1 : 8); ++w) {
            if ((m.axis[0][w] | m.axis[1][w] | m.axis[2][w]) & layer) return true;
        }
    }
    return false;
}

/// A cell the surface passes through: its minimum voxel, corner values and loops.
struct SurfaceCell {
    openvdb::Coord origin;
    float value[8];
    CellLoops loops;
    std::int64_t edge_id[12];  ///< crossing id of each cube edge (-1 when it does not cross)
};

/// The face (kFaceCorner index) on which two cube edges meet, or -1.
inline int common_face(int a, int b) {
    const unsigned m = edge_faces(a) & edge_faces(b);
    return m ? __builtin_ctz(m) : -1;
}

/// Bit mask of the faces loop l walks across twice. A face holds at most four crossings, so a
/// loop crosses it at most twice; a loop of a cell with no ambiguous face crosses every face at
/// most once, the common case.
inline unsigned twice_visited_faces(const CellLoops& loops, int l) {
    const int n = loops.size[l];
    unsigned once = 0, twice = 0;
    for (int k = 0; k < n; ++k) {
        const unsigned bit = 1u << common_face(loops.edge[l][k], loops.edge[l][(k + 1) % n]);
        twice |= once & bit;
        once |= bit;
    }
    return twice;
}

/// Splits a loop into the chains that get one vertex each. A loop that crosses a face twice, while
/// the loop on the other side of that face crosses it twice too, would give the two cells' vertices
/// an edge shared by four quads; cutting both loops at that face's two segments gives each
/// (chain, chain) pair exactly two quads -- the vertex split of manifold dual contouring. Returns
/// the number of chains; chain c holds loop positions [start[c], start[c] + size[c]) (mod n).
template <typename Field>
int loop_chains(const SurfaceCell& cell, int l, Field& acc, float iso, int start[12],
                int size[12]) {
    const CellLoops& loops = cell.loops;
    const int n = loops.size[l];
    bool cut[12] = {};  // cut after position k (between edge k and k + 1)
    int cuts = 0;
    const unsigned twice_faces = loops.ambiguous ? twice_visited_faces(loops, l) : 0u;
    for (int f = 0; f < 6; ++f) {
        if (!((twice_faces >> f) & 1u)) continue;
        // The neighbour across face f, and the loop there that holds one of this face's crossings.
        const int axis = f / 2, dir = f % 2 ? 1 : -1;
        openvdb::Coord nb = cell.origin;
        nb[axis] += dir;
        float values[8];
        bool valid = true;
        for (int k = 0; k < 8 && valid; ++k) {
            valid = acc.probeValue(
                nb.offsetBy(kCubeCorner[k][0], kCubeCorner[k][1], kCubeCorner[k][2]), values[k]);
        }
        if (!valid) continue;
        CellLoops other;
        if (!cell_loops(values, iso, other)) continue;
        int mine = -1;  // one of our edges on face f
        for (int k = 0; k < n && mine < 0; ++k) {
            if (common_face(loops.edge[l][k], loops.edge[l][(k + 1) % n]) == f)
                mine = loops.edge[l][k];
        }
        // The same grid edge in the neighbour's numbering: start corner shifted by -dir.
        int s[3] = {kCubeCorner[kEdgeCorner[mine][0]][0], kCubeCorner[kEdgeCorner[mine][0]][1],
                    kCubeCorner[kEdgeCorner[mine][0]][2]};
        s[axis] -= dir;
        int theirs = -1;
        for (int e = 0; e < 12; ++e) {
            const int* t = kCubeCorner[kEdgeCorner[e][0]];
            if (kEdgeAxis[e] == kEdgeAxis[mine] && t[0] == s[0] && t[1] == s[1] && t[2] == s[2]) {
                theirs = e;
            }
        }
        bool twice = false;
        for (int m = 0; m < other.count && !twice; ++m) {
            for (int k = 0; k < other.size[m]; ++k) {
                if (other.edge[m][k] == theirs)
                    twice = (twice_visited_faces(other, m) >> (f ^ 1)) & 1u;
            }
        }
        if (!twice) continue;
        for (int k = 0; k < n; ++k) {
            if (common_face(loops.edge[l][k], loops.edge[l][(k + 1) % n]) == f && !cut[k]) {
                cut[k] = true;
                ++cuts;
            }
        }
    }
    if (cuts == 0) {
        start[0] = 0;
        size[0] = n;
        return 1;
    }
    int chains = 0;
    for (int k = 0; k < n; ++k) {
        if (!cut[k]) continue;
        // A chain starts after a cut and runs to the next cut.
        int len = 1;
        while (!cut[(k + len) % n]) ++len;
        start[chains] = (k + 1) % n;
        size[chains] = len;
        ++chains;
    }
    return chains;
}

/// Calls visit(leaf_index, cell, acc) for every valid cell (eight active corners) that the surface
/// crosses, in parallel over the sdf's leaves; `acc` is an accessor to the sdf for the visitor's
/// own lookups. Each leaf visits its cells in index order, so a visitor that appends to per-leaf
/// storage produces a thread-count independent result.
///
/// A valid cell has corners on both sides of the iso-value exactly when one of its twelve edges
/// crosses, so the crossing masks select the cells before their corners are read.
template <typename Visit>
void for_each_surface_cell(const openvdb::FloatTree& sdf, const Crossings& crossings, float iso,
                           Visit&& visit) {
    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    sdf.getNodes(leaves);
    // Block offsets of the cube's corners.
    int corner[8];
    for (int k = 0; k < 8; ++k) {
        corner[k] = CellBlock::index(kCubeCorner[k][0], kCubeCorner[k][1], kCubeCorner[k][2]);
    }
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size(), 8),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        FloatAccessor acc(sdf);
        auto block = std::make_unique<CellBlock>();
        SurfaceCell cell;
        for (std::size_t L = r.begin(); L < r.end(); ++L) {
            const openvdb::Coord origin = leaves[L]->origin();
            // Without a crossing starting in the leaf, only cells on its upper faces can have one
            // (on an edge starting in a neighbour).
            const bool any = crossings.leaf_begin[L] != crossings.leaf_begin[L + 1];
            if (!any && !has_upper_crossing(crossings, L)) continue;
            block->load(acc, crossings, L, origin);
            for (int x = 0; x < 8; ++x) {
                for (int y = 0; y < 8; ++y) {
                    for (unsigned cells = block->cells_with_crossings(x, y); cells;
                         cells &= cells - 1) {
                        const int z = __builtin_ctz(cells);
                        const int i = CellBlock::index(x, y, z);
                        bool valid = true;
                        for (int k = 0; k < 8 && valid; ++k) {
                            valid = block->on(i + corner[k]);
                            cell.value[k] = block->value(i + corner[k]);
                        }
                        if (!valid) continue;
                        cell.origin = origin.offsetBy(x, y, z);
                        cell_loops(cell.value, iso, cell.loops);
                        for (int e = 0; e < 12; ++e) {
                            cell.edge_id[e] =
                                block->crossing_id(i + corner[kEdgeCorner[e][0]], kEdgeAxis[e]);
                        }
                        visit(L, cell, acc);
                    }
                }
            }
        }
    });
}

}  // namespace vdbrecon::detail
