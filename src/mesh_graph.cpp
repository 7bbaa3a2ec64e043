// Mesh connectivity helpers (see detail/mesh_graph.h).
#include "detail/mesh_graph.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <atomic>

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

std::vector<std::int32_t> face_components(Span<Triangle> faces,
                                          std::size_t vertex_count) {
    const std::size_t nf = faces.size();
    // Concurrent union-find whose roots are the smallest index of their set: a union links the
    // larger root below the smaller one by compare-and-swap, retrying when another thread moved
    // either root first (R. J. Anderson and H. Woll, "Wait-free parallel algorithms for the
    // union-find problem", STOC 1991). The final labels (each face's smallest-index face of its
    // component) do not depend on the order of the unions, so not on the thread count.
    std::vector<std::atomic<std::int32_t>> parent(nf);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nf, 16384),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t f = r.begin(); f < r.end(); ++f) {
            parent[f].store(std::int32_t(f), std::memory_order_relaxed);
        }
    });
    auto find = [&](std::int32_t x) {
        for (;;) {
            const std::int32_t p = parent[std::size_t(x)].load(std::memory_order_relaxed);
            if (p == x) return x;
            const std::int32_t g = parent[std::size_t(p)].load(std::memory_order_relaxed);
            if (g != p) {  // path halving: an ancestor is always a valid parent
                std::int32_t expect = p;
                parent[std::size_t(x)].compare_exchange_weak(expect, g, std::memory_order_relaxed);
            }
            x = g;
        }
    };
    auto unite = [&](std::int32_t a, std::int32_t b) {
        for (;;) {
            a = find(a);
            b = find(b);
            if (a == b) return;
            if (a > b) std::swap(a, b);
            std::int32_t expect = b;  // b is still a root: link it below a
            if (parent[std::size_t(b)].compare_exchange_strong(expect, a,
                                                               std::memory_order_relaxed)) {
                return;
            }
        }
    };
    // Faces around each vertex (counting sort); a face g that holds both ends of an edge (a, b)
    // of face f has that edge too. The order within a vertex's list does not matter.
    std::vector<std::atomic<std::uint32_t>> count(vertex_count);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nf, 16384),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t f = r.begin(); f < r.end(); ++f) {
            for (std::int32_t i : faces[f]) {
                count[std::size_t(i)].fetch_add(1, std::memory_order_relaxed);
            }
        }
    });
    std::vector<std::size_t> first(vertex_count + 1, 0);
    for (std::size_t v = 0; v < vertex_count; ++v) {
        first[v + 1] = first[v] + count[v].load(std::memory_order_relaxed);
        count[v].store(0, std::memory_order_relaxed);
    }
    std::vector<std::int32_t> around(first[vertex_count]);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nf, 16384),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t f = r.begin(); f < r.end(); ++f) {
            for (std::int32_t i : faces[f]) {
                const std::size_t v = std::size_t(i);
                around[first[v] + count[v].fetch_add(1, std::memory_order_relaxed)] =
                    std::int32_t(f);
            }
        }
    });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nf, 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t f = r.begin(); f < r.end(); ++f) {
            const Triangle& t = faces[f];
            for (int k = 0; k < 3; ++k) {
                const std::size_t a = std::size_t(t[k]);
                const std::int32_t b = t[(k + 1) % 3];
                if (std::int32_t(a) == b) continue;  // a degenerate edge joins nothing
                for (std::size_t j = first[a]; j < first[a + 1]; ++j) {
                    const std::int32_t g = around[j];
                    if (std::size_t(g) <= f) continue;  // each pair once
                    const Triangle& u = faces[std::size_t(g)];
                    if (u[0] != b && u[1] != b && u[2] != b) continue;
                    unite(std::int32_t(f), g);
                }
            }
        }
    });
    std::vector<std::int32_t> label(nf);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, nf, 16384),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t f = r.begin(); f < r.end(); ++f) label[f] = find(std::int32_t(f));
    });
    return label;
}

std::vector<std::array<double, 3>> face_normal_sums(const Mesh& mesh) {
    std::vector<std::array<double, 3>> sum(mesh.vertices.size(), {0.0, 0.0, 0.0});
    for (const Triangle& t : mesh.faces) {
        const Vec3f &pa = mesh.vertices[std::size_t(t[0])], &pb = mesh.vertices[std::size_t(t[1])],
                    &pc = mesh.vertices[std::size_t(t[2])];
        double u[3], v[3];
        for (int k = 0; k < 3; ++k) {
            u[k] = double(pb[k]) - double(pa[k]);
            v[k] = double(pc[k]) - double(pa[k]);
        }
        const double n[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                             u[0] * v[1] - u[1] * v[0]};
        for (std::int32_t i : t) {
            for (int k = 0; k < 3; ++k) sum[std::size_t(i)][std::size_t(k)] += n[k];
        }
    }
    return sum;
}

}  // namespace vdbrecon::detail
