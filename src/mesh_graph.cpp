// Mesh connectivity helpers (see detail/mesh_graph.h).
#include "detail/mesh_graph.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <numeric>

namespace vdbrecon::detail {

std::vector<EdgeUse> undirected_edges(Span<Triangle> faces) {
    std::vector<std::uint64_t> keys;
    keys.reserve(3 * faces.size());
    for (const Triangle& t : faces) {
        for (int k = 0; k < 3; ++k) {
            std::uint32_t u = std::uint32_t(t[k]), v = std::uint32_t(t[(k + 1) % 3]);
            if (u == v) continue;
            if (u > v) std::swap(u, v);
            keys.push_back((std::uint64_t(u) << 32) | v);
        }
    }
    tbb::parallel_sort(keys.begin(), keys.end());
    std::vector<EdgeUse> edges;
    for (std::size_t i = 0; i < keys.size();) {
        std::size_t j = i;
        while (j < keys.size() && keys[j] == keys[i]) ++j;
        edges.push_back({std::int32_t(keys[i] >> 32), std::int32_t(keys[i] & 0xffffffffu),
                         std::uint32_t(j - i)});
        i = j;
    }
    return edges;
}

std::vector<std::uint64_t> border_edge_keys(Span<Triangle> faces) {
    std::vector<std::uint64_t> keys;
    for (const EdgeUse& e : undirected_edges(faces)) {
        if (e.faces == 1) keys.push_back(edge_key(e.a, e.b));
    }
    return keys;  // undirected_edges is sorted by (a, b), so are the keys
}

VertexFaces vertex_faces(Span<Triangle> faces, std::size_t vertex_count) {
    return vertex_faces(faces, 0, vertex_count);
}

VertexFaces vertex_faces(Span<Triangle> faces, std::size_t lo, std::size_t hi) {
    const auto in = [&](std::int32_t v) { return std::size_t(v) >= lo && std::size_t(v) < hi; };
    VertexFaces r;
    r.first.assign(hi - lo + 1, 0);
    for (const Triangle& t : faces) {
        for (std::int32_t i : t) {
            if (in(i)) ++r.first[std::size_t(i) - lo + 1];
        }
    }
    for (std::size_t v = 0; v < hi - lo; ++v) r.first[v + 1] += r.first[v];
    r.around.resize(r.first[hi - lo]);
    // first[v] serves as v's cursor (then holds v's end, v + 1's start) and is shifted back
    // after: no second array of offsets.
    for (std::size_t f = 0; f < faces.size(); ++f) {
        for (std::int32_t i : faces[f]) {
            if (in(i)) r.around[r.first[std::size_t(i) - lo]++] = std::int32_t(f);
        }
    }
    for (std::size_t v = hi - lo; v > 0; --v) r.first[v] = r.first[v - 1];
    r.first[0] = 0;
    return r;
}

std::vector<std::int32_t> face_components(Span<Triangle> faces, std::size_t vertex_count) {
    const std::size_t nf = faces.size();
    MinUnionFind sets(nf);
    // A face g around a that holds both ends of an edge (a, b) of face f has that edge too. The
    // faces around each vertex are listed for a range of vertices at a time (about 2^24 corners
    // a pass), so that a large mesh never holds all 3 nf of them; the labels, the smallest face
    // of each set, do not depend on the order of the unions.
    constexpr std::size_t kCornersPerPass = std::size_t(1) << 24;
    const std::size_t passes =
        std::max<std::size_t>(1, (3 * nf + kCornersPerPass - 1) / kCornersPerPass);
    const std::size_t span = std::max<std::size_t>(1, (vertex_count + passes - 1) / passes);
    for (std::size_t lo = 0; lo < vertex_count; lo += span) {
        const VertexFaces vf = vertex_faces(faces, lo, std::min(vertex_count, lo + span));
        // Each edge (a, b) of a face f around a, a in the range.
        for (std::size_t r = 0; r + 1 < vf.first.size(); ++r) {
            const auto a = std::int32_t(lo + r);
            const std::size_t end = vf.first[r + 1];
            for (std::size_t i = vf.first[r]; i < end; ++i) {
                const std::int32_t f = vf.around[i];
                if (i > vf.first[r] && vf.around[i - 1] == f) continue;  // a face listing a twice
                const Triangle& t = faces[std::size_t(f)];
                for (int k = 0; k < 3; ++k) {
                    const std::int32_t b = t[std::size_t((k + 1) % 3)];
                    if (t[std::size_t(k)] != a || b == a) continue;  // a degenerate edge joins nothing
                    for (std::size_t j = i + 1; j < end; ++j) {
                        const std::int32_t g = vf.around[j];
                        if (g == f) continue;
                        const Triangle& u = faces[std::size_t(g)];
                        if (u[0] != b && u[1] != b && u[2] != b) continue;
                        sets.unite(f, g);
                    }
                }
            }
        }
    }
    return std::move(sets).labels();
}

std::vector<std::int32_t> compact_vertices(std::vector<Triangle>& faces, std::size_t vertex_count,
                                           std::size_t* used) {
    std::vector<std::int32_t> remap(vertex_count, -1);
    for (const Triangle& t : faces) {
        for (std::int32_t i : t) remap[std::size_t(i)] = 0;
    }
    std::int32_t next = 0;
    for (std::int32_t& r : remap) {
        if (r == 0) r = next++;
    }
    for (Triangle& t : faces) {
        for (std::int32_t& i : t) i = remap[std::size_t(i)];
    }
    *used = std::size_t(next);
    return remap;
}

std::vector<std::array<double, 3>> face_normal_sums(const Mesh& mesh) {
    return face_normal_sums(mesh, 0, mesh.vertices.size());
}

std::vector<std::array<double, 3>> face_normal_sums(const Mesh& mesh, std::size_t first,
                                                    std::size_t last) {
    std::vector<std::array<double, 3>> sum(last - first, {0.0, 0.0, 0.0});
    const auto in = [&](std::int32_t i) { return std::size_t(i) >= first && std::size_t(i) < last; };
    // The faces' normals in parallel, a chunk at a time; then added to their vertices in face
    // order, so that every sum is the same bits for any thread count.
    const Span<Triangle> faces = mesh.faces;
    constexpr std::size_t kChunk = std::size_t(1) << 16, kPiece = 4096;
    std::vector<std::array<double, 3>> n(std::min(faces.size(), kChunk));
    std::vector<char> touched(kChunk / kPiece);  // per piece of a chunk: a face reaches the range
    for (std::size_t c0 = 0; c0 < faces.size(); c0 += kChunk) {
        const std::size_t c1 = std::min(faces.size(), c0 + kChunk);
        const std::size_t pieces = (c1 - c0 + kPiece - 1) / kPiece;
        tbb::parallel_for(std::size_t(0), pieces, [&](std::size_t p) {
            touched[p] = 0;
            for (std::size_t f = c0 + p * kPiece, e = std::min(c1, f + kPiece); f < e; ++f) {
                const Triangle& t = faces[f];
                if (!in(t[0]) && !in(t[1]) && !in(t[2])) continue;  // not added below either
                touched[p] = 1;
                const Vec3f &pa = mesh.vertices[std::size_t(t[0])],
                            &pb = mesh.vertices[std::size_t(t[1])],
                            &pc = mesh.vertices[std::size_t(t[2])];
                double u[3], v[3];
                for (int k = 0; k < 3; ++k) {
                    u[k] = double(pb[k]) - double(pa[k]);
                    v[k] = double(pc[k]) - double(pa[k]);
                }
                n[f - c0] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                             u[0] * v[1] - u[1] * v[0]};
            }
        });
        // Pieces no face of which reaches the range are skipped: a block of vertices (see
        // vertex_normals) is reached by few pieces when the faces come in the vertices' order.
        for (std::size_t p = 0; p < pieces; ++p) {
            if (!touched[p]) continue;
            for (std::size_t f = c0 + p * kPiece, e = std::min(c1, f + kPiece); f < e; ++f) {
                for (std::int32_t i : faces[f]) {
                    if (!in(i)) continue;
                    for (std::size_t k = 0; k < 3; ++k)
                        sum[std::size_t(i) - first][k] += n[f - c0][k];
                }
            }
        }
    }
    return sum;
}

}  // namespace vdbrecon::detail
