// Mesh connectivity helpers (see detail/mesh_graph.h).
#include "detail/mesh_graph.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <limits>
#include <numeric>
#include <utility>

#include "detail/radix_sort.h"

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

namespace {

/// Unites the faces [first, last) around vertex a that share an edge (a, b): every edge once,
/// at its smaller end (b > a), the faces there that hold b united pairwise. The other ends
/// are listed with their faces first and compared as a list: against scanning the later
/// faces' corners for each edge of each face, whose outcome the branch predictor missed a
/// third of the time (bunny at 0.5 mm, 674k faces, 1 thread: the unions 26 -> 19 ms).
void unite_around(Span<Triangle> faces, std::int32_t a, const std::int32_t* first,
                  const std::int32_t* last, ConcurrentMinUnionFind& sets) {
    // At most two ends a face: on the stack, but for a vertex of more than 32 faces.
    constexpr std::size_t kStack = 64;
    const std::size_t most = 2 * std::size_t(last - first);
    std::int32_t stack[2 * kStack];
    std::vector<std::int32_t> heap(most > kStack ? 2 * most : 0);
    std::int32_t* end = heap.empty() ? stack : heap.data();
    std::int32_t* face = end + std::max(most, kStack);
    std::size_t n = 0;
    for (const std::int32_t* i = first; i < last; ++i) {
        const std::int32_t f = *i;
        if (i > first && i[-1] == f) continue;  // a face listing a twice
        for (const std::int32_t v : faces[std::size_t(f)]) {
            if (v <= a) continue;
            end[n] = v;
            face[n++] = f;
        }
    }
    for (std::size_t i = 0; i < n; ++i) {
        for (std::size_t j = i + 1; j < n; ++j) {
            if (end[j] == end[i] && face[j] != face[i]) sets.unite(face[i], face[j]);
        }
    }
}

}  // namespace

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
    ConcurrentMinUnionFind sets(nf);
    // A face g around a that holds both ends of an edge (a, b) of face f has that edge too. The
    // faces around each vertex are listed for a range of vertices at a time (about 2^24 corners
    // a pass), so that a large mesh never holds all 3 nf of them; the vertices of a range are
    // visited in parallel. The labels, the smallest face of each set, do not depend on the order
    // of the unions.
    constexpr std::size_t kCornersPerPass = std::size_t(1) << 24;
    const std::size_t passes =
        std::max<std::size_t>(1, (3 * nf + kCornersPerPass - 1) / kCornersPerPass);
    const std::size_t span = std::max<std::size_t>(1, (vertex_count + passes - 1) / passes);
    for (std::size_t lo = 0; lo < vertex_count; lo += span) {
        const VertexFaces vf = vertex_faces(faces, lo, std::min(vertex_count, lo + span));
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, vf.first.size() - 1, 4096),
                          [&](const tbb::blocked_range<std::size_t>& range) {
                              for (std::size_t r = range.begin(); r < range.end(); ++r) {
                                  unite_around(faces, std::int32_t(lo + r),
                                               vf.around.data() + vf.first[r],
                                               vf.around.data() + vf.first[r + 1], sets);
                              }
                          });
    }
    return sets.labels();
}

std::vector<std::int32_t> compact_vertices(std::vector<Triangle>& faces, std::size_t vertex_count,
                                           std::size_t* used) {
    // In parallel (this was a serial tail of the mesh and clean stages): the used vertices
    // marked 0, numbered in order by chunks (their counts, then each chunk from its offset),
    // the faces rewritten.
    std::vector<std::int32_t> remap(vertex_count, -1);
    mark_used_vertices(faces, remap.data(), std::int32_t(0));
    std::size_t next = 0;
    const std::vector<std::size_t> first = chunk_offsets(
        vertex_count,
        [&](std::size_t, std::size_t begin, std::size_t end) {
            return std::size_t(std::count(remap.begin() + std::ptrdiff_t(begin),
                                          remap.begin() + std::ptrdiff_t(end), 0));
        },
        next);
    for_each_chunk(vertex_count, [&](std::size_t c, std::size_t begin, std::size_t end) {
        std::int32_t k = std::int32_t(first[c]);
        for (std::size_t i = begin; i < end; ++i) {
            if (remap[i] == 0) remap[i] = k++;
        }
    });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, faces.size(), 16384),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t f = r.begin(); f < r.end(); ++f) {
                              for (std::int32_t& i : faces[f]) i = remap[std::size_t(i)];
                          }
                      });
    *used = std::size_t(next);
    return remap;
}

namespace {

constexpr std::size_t kPiece = 4096;  ///< faces per piece, the unit a range of vertices skips

/// Per piece of kPiece faces, the least and the greatest vertex index its faces use.
std::vector<std::array<std::int32_t, 2>> piece_bounds(Span<Triangle> faces) {
    std::vector<std::array<std::int32_t, 2>> bounds((faces.size() + kPiece - 1) / kPiece);
    tbb::parallel_for(std::size_t(0), bounds.size(), [&](std::size_t p) {
        std::int32_t lo = std::numeric_limits<std::int32_t>::max(), hi = -1;
        for (std::size_t f = p * kPiece, e = std::min(faces.size(), f + kPiece); f < e; ++f) {
            for (std::int32_t i : faces[f]) {
                lo = std::min(lo, i);
                hi = std::max(hi, i);
            }
        }
        bounds[p] = {lo, hi};
    });
    return bounds;
}

/// Whether a piece whose faces use the vertices bound[0] .. bound[1] reaches first .. last - 1.
bool reaches(const std::array<std::int32_t, 2>& bound, std::size_t first, std::size_t last) {
    return std::size_t(bound[1]) >= first && std::size_t(bound[0]) < last;
}

/// The faces the vertices first .. last - 1 make a pass over: those of the pieces that reach
/// the range.
std::size_t faces_to_scan(Span<Triangle> faces,
                          const std::vector<std::array<std::int32_t, 2>>& bounds, std::size_t first,
                          std::size_t last) {
    std::size_t n = 0;
    for (std::size_t p = 0; p < bounds.size(); ++p) {
        if (reaches(bounds[p], first, last)) {
            n += std::min(faces.size(), (p + 1) * kPiece) - p * kPiece;
        }
    }
    return n;
}

/// Adds each face's normal to sum[v - first] of its vertices v in first .. last - 1, in face
/// order; pieces that do not reach the range are skipped.
void add_face_normals(const Mesh& mesh, const std::vector<std::array<std::int32_t, 2>>& bounds,
                      std::size_t first, std::size_t last, std::array<double, 3>* sum) {
    const auto in = [&](std::int32_t i) {
        return std::size_t(i) >= first && std::size_t(i) < last;
    };
    const Span<Triangle> faces = mesh.faces;
    for (std::size_t p = 0; p < bounds.size(); ++p) {
        if (!reaches(bounds[p], first, last)) continue;
        for (std::size_t f = p * kPiece, e = std::min(faces.size(), f + kPiece); f < e; ++f) {
            const Triangle& t = faces[f];
            if (!in(t[0]) && !in(t[1]) && !in(t[2])) continue;
            const Vec3f &pa = mesh.vertices[std::size_t(t[0])],
                        &pb = mesh.vertices[std::size_t(t[1])],
                        &pc = mesh.vertices[std::size_t(t[2])];
            double u[3], v[3];
            for (int k = 0; k < 3; ++k) {
                u[k] = double(pb[k]) - double(pa[k]);
                v[k] = double(pc[k]) - double(pa[k]);
            }
            const double n[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                                 u[0] * v[1] - u[1] * v[0]};
            for (std::int32_t i : t) {
                if (!in(i)) continue;
                for (int k = 0; k < 3; ++k) sum[std::size_t(i) - first][k] += n[k];
            }
        }
    }
}

}  // namespace

std::vector<std::array<double, 3>> face_normal_sums(const Mesh& mesh) {
    return FaceNormalSums(mesh)(0, mesh.vertices.size());
}

FaceNormalSums::FaceNormalSums(const Mesh& mesh) : mesh_(mesh), bounds_(piece_bounds(mesh.faces)) {}

std::vector<std::array<double, 3>> FaceNormalSums::operator()(std::size_t first,
                                                              std::size_t last) const {
    std::vector<std::array<double, 3>> sum(last - first, {0.0, 0.0, 0.0});
    const Span<Triangle> faces = mesh_.faces;
    // The range split in parts summed in parallel, each over the faces that reach it in face
    // order: every sum is the same bits for any split and thread count. As many parts as keep
    // the passes to about one over the faces: faces in their vertices' order (a mesher's) reach
    // few parts each, faces in no order every part, and then one part is best.
    const std::size_t n = last - first;
    std::size_t parts = std::min(4 * std::size_t(tbb::this_task_arena::max_concurrency()),
                                 std::max<std::size_t>(1, n / 4096));
    for (; parts > 1; parts /= 2) {
        std::size_t scanned = 0;
        for (std::size_t k = 0; k < parts; ++k) {
            scanned +=
                faces_to_scan(faces, bounds_, first + n * k / parts, first + n * (k + 1) / parts);
        }
        if (scanned <= 2 * faces.size()) break;
    }
    tbb::parallel_for(std::size_t(0), parts, [&](std::size_t k) {
        const std::size_t a = first + n * k / parts, b = first + n * (k + 1) / parts;
        add_face_normals(mesh_, bounds_, a, b, sum.data() + (a - first));
    });
    return sum;
}

}  // namespace vdbrecon::detail
