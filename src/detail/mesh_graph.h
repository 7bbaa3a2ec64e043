// Connectivity of indexed triangle meshes, shared by topology statistics (eval), cleanup and the
// meshers' normals: undirected edges with their use counts, edge-connected face components, and
// area-weighted vertex normals.
#pragma once

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "detail/fill_later.h"
#include "detail/radix_sort.h"
#include "detail/union_find.h"
#include "vdbrecon/types.h"

namespace vdbrecon::detail {

/// An undirected edge (a < b) and how many faces use it (1: boundary, 2: manifold, > 2:
/// non-manifold).
struct EdgeUse {
    std::int32_t a, b;
    std::uint32_t faces;
};

/// Every undirected edge of the faces, sorted by (a, b); degenerate edges (a == b) are skipped.
std::vector<EdgeUse> undirected_edges(Span<Triangle> faces);

/// The key of the undirected edge (a, b): (min << 32) | max.
inline std::uint64_t edge_key(std::int32_t a, std::int32_t b) {
    if (a > b) std::swap(a, b);
    return (std::uint64_t(std::uint32_t(a)) << 32) | std::uint32_t(b);
}

/// One face's edge (its corners slot and slot + 1), under the undirected edge's key.
struct EdgeSide {
    std::uint64_t key;
    std::int32_t face, slot;
};

/// Sides listed in memory that is not zeroed first (their listing and the radix sort's copy
/// fill it; see detail/fill_later.h).
using EdgeSides = FillLater<EdgeSide>;

/// The edges of the faces that `take(f)` accepts, sorted by (key, face, slot): the faces that
/// share an edge come together, in face order. Listed in face and slot order by chunks of faces
/// in parallel (their counts, then each chunk from its offset), then sorted stably by the key
/// with its two ends packed in the bits the largest vertex index needs: a radix sort (std::sort
/// took 25 ms of one thread for the 340k sides of a Kinect frame's unsupported faces; listed
/// on one thread, into a vector grown by doubling and zero-filled, 10 ms of the mesh stage of
/// 30 such frames fused at 1 cm ran on one thread).
template <typename Take>
EdgeSides sorted_sides(Span<Triangle> faces, Take take) {
    const std::size_t nf = faces.size();
    std::vector<std::uint32_t> largest(chunk_count(nf), 0);  // per chunk, vertex index
    std::size_t total = 0;
    const std::vector<std::size_t> first = chunk_offsets(
        nf,
        [&](std::size_t c, std::size_t begin, std::size_t end) {
            std::size_t count = 0;
            std::uint32_t most = 0;
            for (std::size_t f = begin; f < end; ++f) {
                if (!take(f)) continue;
                count += 3;
                for (std::int32_t v : faces[f]) most = std::max(most, std::uint32_t(v));
            }
            largest[c] = most;
            return count;
        },
        total);
    EdgeSides sides(total);
    for_each_chunk(nf, [&](std::size_t c, std::size_t begin, std::size_t end) {
        EdgeSide* out = sides.data() + first[c];
        for (std::size_t f = begin; f < end; ++f) {
            if (!take(f)) continue;
            const Triangle& t = faces[f];
            for (int k = 0; k < 3; ++k) {
                *out++ = {edge_key(t[std::size_t(k)], t[std::size_t((k + 1) % 3)]), std::int32_t(f),
                          k};
            }
        }
    });
    const std::uint32_t most =
        largest.empty() ? 0 : *std::max_element(largest.begin(), largest.end());
    const int end_bits = most == 0 ? 0 : 32 - __builtin_clz(most);
    radix_sort(sides, 2 * end_bits, [&](const EdgeSide& e) {
        return (e.key >> 32) << end_bits | (e.key & 0xffffffffu);
    });
    return sides;
}

/// Calls visit(first, second) for each edge that exactly two of the sorted sides share.
template <typename Visit>
void manifold_pairs(const EdgeSides& sides, Visit visit) {
    for (std::size_t i = 0; i < sides.size();) {
        std::size_t j = i;
        while (j < sides.size() && sides[j].key == sides[i].key) ++j;
        if (j - i == 2) visit(sides[i], sides[i + 1]);
        i = j;
    }
}

/// The keys (edge_key) of the open border's edges, those one face uses, sorted.
std::vector<std::uint64_t> border_edge_keys(Span<Triangle> faces);

/// The faces around each vertex, in face order (counting sort): those around v are
/// around[first[v] .. first[v + 1]).
struct VertexFaces {
    std::vector<std::size_t> first;
    FillLater<std::int32_t> around;  ///< not zeroed first: every entry is written
};
VertexFaces vertex_faces(Span<Triangle> faces, std::size_t vertex_count);

/// The same for the vertices lo .. hi - 1 only: those around v are around[first[v - lo] ..
/// first[v - lo + 1]).
VertexFaces vertex_faces(Span<Triangle> faces, std::size_t lo, std::size_t hi);

/// Edge-connected components of the faces (two faces that share an edge belong together): per
/// face, its component's label, the smallest face index in it. Linear time (a few passes over
/// the faces for a large mesh, a range of vertices at a time).
std::vector<std::int32_t> face_components(Span<Triangle> faces, std::size_t vertex_count);

/// Sets marks[v] = value for every vertex v the faces use, in parallel (the threads' stores of
/// the same value to one vertex are relaxed atomic stores).
template <typename T>
void mark_used_vertices(Span<Triangle> faces, T* marks, T value) {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, faces.size(), 16384),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t f = r.begin(); f < r.end(); ++f) {
                              for (std::int32_t v : faces[f])
                                  __atomic_store_n(&marks[std::size_t(v)], value, __ATOMIC_RELAXED);
                          }
                      });
}

/// The vertices the faces use, renumbered in their original order: rewrites the faces to the new
/// numbers and returns, per old vertex, its new index (-1 where no face uses it); *used gets
/// their count.
std::vector<std::int32_t> compact_vertices(std::vector<Triangle>& faces, std::size_t vertex_count,
                                           std::size_t* used);

/// Per vertex, the sum of the (unnormalised, so area-weighted) normals of the faces around it.
std::vector<std::array<double, 3>> face_normal_sums(const Mesh& mesh);

/// The same sums a block of vertices at a time, for a large mesh: operator()(first, last) gives
/// those of the vertices first .. last - 1 (entry v - first), each summed in face order as
/// above, bit for bit. Made once per mesh (it notes which vertices each run of faces reaches).
class FaceNormalSums {
  public:
    explicit FaceNormalSums(const Mesh& mesh);
    std::vector<std::array<double, 3>> operator()(std::size_t first, std::size_t last) const;

  private:
    const Mesh& mesh_;
    std::vector<std::array<std::int32_t, 2>> bounds_;  ///< per run of faces, least/greatest vertex
};

}  // namespace vdbrecon::detail
