// The cube of one grid cell: corner and edge numbering, and the oriented loops in which the
// iso-surface crosses the cell's faces -- the common core of our marching cubes and dual
// contouring.
//
// Corner c = x | y << 1 | z << 2 sits at offset (x, y, z) from the cell's minimum voxel.
// Edge e joins corners kEdgeCorner[e][0] -> kEdgeCorner[e][1] along axis kEdgeAxis[e];
// its start corner is the lower one, so an edge is identified in the grid by (start voxel,
// axis).
//
// Loops. On every face, walking its corners counter-clockwise around the face's outward normal,
// the surface enters the negative (inside, value < iso) region at one crossing and leaves it at
// the next; each face contributes segments "enter -> leave". A face with two entering crossings
// is ambiguous; it is resolved by the asymptotic decider (G. Nielson and B. Hamann, "The
// asymptotic decider", Visualization 1991): the bilinear saddle value decides whether the two
// negative corners are connected across the face. The decision depends on the face's four values
// only, so the two cells sharing a face always agree and the surface has no cracks. Every
// crossing is the end of one segment and the start of another, so the segments close into loops;
// they are oriented so that a fan over a loop faces the positive (outside) side, and a face shared
// by two cells is walked in opposite directions by them, so orientations agree across cells.
// Without an ambiguous face the loops depend on the eight signs alone and come from a table.
#pragma once

#include <array>
#include <cstdint>

namespace vdbrecon::detail {

constexpr int kCubeCorner[8][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0},
                                   {0, 0, 1}, {1, 0, 1}, {0, 1, 1}, {1, 1, 1}};
constexpr int kEdgeCorner[12][2] = {{0, 1}, {2, 3}, {4, 5}, {6, 7},   // along x
                                    {0, 2}, {1, 3}, {4, 6}, {5, 7},   // along y
                                    {0, 4}, {1, 5}, {2, 6}, {3, 7}};  // along z
constexpr int kEdgeAxis[12] = {0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2};

/// The edge joining two corners (-1 when they are not adjacent).
constexpr int edge_between(int a, int b) {
    for (int e = 0; e < 12; ++e) {
        if ((kEdgeCorner[e][0] == a && kEdgeCorner[e][1] == b) ||
            (kEdgeCorner[e][0] == b && kEdgeCorner[e][1] == a)) {
            return e;
        }
    }
    return -1;
}

/// Faces: four corners counter-clockwise around the outward normal (right-hand rule).
constexpr int kFaceCorner[6][4] = {
    {0, 4, 6, 2},  // x = 0, normal -x
    {1, 3, 7, 5},  // x = 1, normal +x
    {0, 1, 5, 4},  // y = 0, normal -y
    {2, 6, 7, 3},  // y = 1, normal +y
    {0, 2, 3, 1},  // z = 0, normal -z
    {4, 5, 7, 6},  // z = 1, normal +z
};

/// Bit mask of the faces (kFaceCorner order) each edge lies on.
inline std::uint8_t edge_faces(int e) {
    static const auto table = [] {
        std::array<std::uint8_t, 12> t{};
        for (int edge = 0; edge < 12; ++edge) {
            for (int f = 0; f < 6; ++f) {
                for (int i = 0; i < 4; ++i) {
                    if (edge_between(kFaceCorner[f][i], kFaceCorner[f][(i + 1) % 4]) == edge) {
                        t[std::size_t(edge)] |= std::uint8_t(1u << f);
                    }
                }
            }
        }
        return t;
    }();
    return table[std::size_t(e)];
}

/// Up to four loops of up to twelve edges each.
struct CellLoops {
    int count = 0;
    std::uint8_t size[4] = {0, 0, 0, 0};
    std::uint8_t edge[4][12];
    /// Whether a face holds four crossings (two segments). Without one, every loop crosses each
    /// face at most once.
    bool ambiguous = false;
};

/// The oriented loops of the iso-surface in a cell with corner values f (inside: f < iso).
/// Returns false (no loops) when all corners are on the same side. Computed from scratch; see
/// cell_loops() for the tabulated version.
inline bool cell_loops_direct(const float f[8], float iso, CellLoops& out) {
    int mask = 0;
    for (int c = 0; c < 8; ++c) mask |= (f[c] < iso ? 1 : 0) << c;
    out.count = 0;
    out.ambiguous = false;
    if (mask == 0 || mask == 255) return false;
    auto inside = [&](int c) { return (mask >> c) & 1; };
    int next[12];
    for (int& n : next) n = -1;
    for (const auto& face : kFaceCorner) {
        // Crossings in walk order, and whether the walk enters the negative region there.
        int edges[4], enters[4], n = 0;
        for (int i = 0; i < 4; ++i) {
            const int a = face[i], b = face[(i + 1) % 4];
            if (inside(a) != inside(b)) {
                edges[n] = edge_between(a, b);
                enters[n] = inside(b);
                ++n;
            }
        }
        if (n == 2) {
            const int in = enters[0] ? 0 : 1;
            next[edges[in]] = edges[1 - in];
        } else if (n == 4) {
            out.ambiguous = true;
            // Two negative corners on a diagonal. Walk order: enter, leave, enter, leave (after
            // a rotation). Pair each entry with the following exit (negative corners cut off
            // separately) unless the saddle of the bilinear interpolant is negative, in which
            // case the negative corners are connected and each entry pairs with the other exit.
            const int s = enters[0] ? 0 : 1;
            const int e0 = edges[s], x0 = edges[s + 1], e1 = edges[(s + 2) % 4],
                      x1 = edges[(s + 3) % 4];
            // The neighbour walks this face from another corner and the other way round, but
            // with the same diagonals: sums are grouped by diagonal so both compute the same bits.
            const float v0 = f[face[0]], v1 = f[face[1]], v2 = f[face[2]], v3 = f[face[3]];
            const float d02 = v0 + v2, d13 = v1 + v3;
            const float den = d02 - d13;
            const float saddle = den != 0.0f ? (v0 * v2 - v1 * v3) / den : 0.25f * (d02 + d13);
            if (saddle < iso) {
                next[e0] = x1;
                next[e1] = x0;
            } else {
                next[e0] = x0;
                next[e1] = x1;
            }
        }
    }
    bool used[12] = {};
    for (int start = 0; start < 12; ++start) {
        if (next[start] < 0 || used[start]) continue;
        const int l = out.count++;
        out.size[l] = 0;
        for (int e = start; !used[e]; e = next[e]) {
            used[e] = true;
            out.edge[l][out.size[l]++] = std::uint8_t(e);
        }
    }
    return true;
}

/// Whether some face of a cell with inside-corner mask `mask` has its two inside corners on a
/// diagonal (the asymptotic decider then needs the values).
constexpr bool has_ambiguous_face(int mask) {
    for (const auto& face : kFaceCorner) {
        const int a = (mask >> face[0]) & 1, b = (mask >> face[1]) & 1, c = (mask >> face[2]) & 1,
                  d = (mask >> face[3]) & 1;
        if (a == c && b == d && a != b) return true;
    }
    return false;
}

/// As cell_loops_direct(), from a table of the 256 sign patterns where no face is ambiguous (the
/// loops then depend on the signs alone).
inline bool cell_loops(const float f[8], float iso, CellLoops& out) {
    struct Entry {
        bool tabulated;
        CellLoops loops;
    };
    static const auto table = [] {
        std::array<Entry, 256> t{};
        for (int mask = 0; mask < 256; ++mask) {
            if (has_ambiguous_face(mask)) continue;
            float v[8];
            for (int c = 0; c < 8; ++c) v[c] = (mask >> c) & 1 ? -1.0f : 1.0f;
            t[std::size_t(mask)].tabulated = true;
            cell_loops_direct(v, 0.0f, t[std::size_t(mask)].loops);
        }
        return t;
    }();
    int mask = 0;
    for (int c = 0; c < 8; ++c) mask |= (f[c] < iso ? 1 : 0) << c;
    const Entry& e = table[std::size_t(mask)];
    if (!e.tabulated) return cell_loops_direct(f, iso, out);
    out = e.loops;
    return mask != 0 && mask != 255;
}

/// The apex for fanning loop `l` into triangles such that no diagonal joins two crossings on a
/// common cube face. Such a diagonal could be chosen by the neighbour across that face too, and
/// the edge would then carry four triangles; crossings on a face are joined only by the face's
/// own segments, which each cell beside the face uses once. Returns -1 when every apex has such
/// a diagonal (the caller then fans around a centre point).
inline int fan_apex(const CellLoops& loops, int l) {
    const int n = loops.size[l];
    for (int apex = 0; apex < n; ++apex) {
        bool ok = true;
        for (int j = 2; j + 1 < n && ok; ++j) {  // diagonals apex -> apex + j
            const int a = loops.edge[l][apex], b = loops.edge[l][(apex + j) % n];
            ok = (edge_faces(a) & edge_faces(b)) == 0;
        }
        if (ok) return apex;
    }
    return -1;
}

}  // namespace vdbrecon::detail
