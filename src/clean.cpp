// Mesh cleanup (see clean.h).
#include "vdbrecon/clean.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <string>
#include <vector>

#include "vdbrecon/error.h"

namespace vdbrecon {

void CleanOptions::validate() const {
    if (!(min_component_ratio >= 0.0 && min_component_ratio <= 1.0)) {
        throw InvalidArgument("clean.min_component_ratio = " + std::to_string(min_component_ratio) +
                              ": must be in 0..1");
    }
    if (smooth_iterations < 0 || smooth_iterations > 10000) {
        throw InvalidArgument("clean.smooth_iterations = " + std::to_string(smooth_iterations) +
                              ": must be in 0..10000");
    }
    if (!(smooth_lambda > 0.0 && smooth_lambda < 1.0)) {
        throw InvalidArgument("clean.smooth_lambda = " + std::to_string(smooth_lambda) +
                              ": must be in (0, 1)");
    }
    if (!(smooth_mu < -smooth_lambda && smooth_mu > -1.0)) {
        throw InvalidArgument("clean.smooth_mu = " + std::to_string(smooth_mu) +
                              ": must be in (-1, -lambda)");
    }
}

namespace {

/// Union-find with path halving; the representative is the smallest index, so labels do not
/// depend on the order of the unions.
struct DisjointSets {
    std::vector<std::int32_t> parent;
    explicit DisjointSets(std::size_t n) : parent(n) {
        std::iota(parent.begin(), parent.end(), std::int32_t(0));
    }
    std::int32_t find(std::int32_t x) {
        while (parent[std::size_t(x)] != x) {
            parent[std::size_t(x)] = parent[std::size_t(parent[std::size_t(x)])];
            x = parent[std::size_t(x)];
        }
        return x;
    }
    void unite(std::int32_t a, std::int32_t b) {
        a = find(a);
        b = find(b);
        if (a == b) return;
        if (a < b) std::swap(a, b);
        parent[std::size_t(a)] = b;
    }
};

/// Undirected edges of the mesh as (low vertex, high vertex, face), sorted.
std::vector<std::array<std::int32_t, 3>> sorted_edges(const std::vector<Triangle>& faces) {
    std::vector<std::array<std::int32_t, 3>> edges;
    edges.reserve(3 * faces.size());
    for (std::size_t f = 0; f < faces.size(); ++f) {
        const Triangle& t = faces[f];
        for (int k = 0; k < 3; ++k) {
            const std::int32_t a = t[k], b = t[(k + 1) % 3];
            edges.push_back({std::min(a, b), std::max(a, b), std::int32_t(f)});
        }
    }
    std::sort(edges.begin(), edges.end());
    return edges;
}

/// Area-weighted vertex normals of a mesh.
std::vector<Vec3f> face_normals_at_vertices(const Mesh& m) {
    std::vector<std::array<double, 3>> acc(m.vertices.size(), {0.0, 0.0, 0.0});
    for (const Triangle& t : m.faces) {
        const Vec3f &a = m.vertices[std::size_t(t[0])], &b = m.vertices[std::size_t(t[1])],
                    &c = m.vertices[std::size_t(t[2])];
        const double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        const double v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        const double n[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                             u[0] * v[1] - u[1] * v[0]};
        for (std::int32_t i : t) {
            for (int k = 0; k < 3; ++k) acc[std::size_t(i)][std::size_t(k)] += n[k];
        }
    }
    std::vector<Vec3f> out(m.vertices.size(), Vec3f{0.0f, 0.0f, 0.0f});
    for (std::size_t i = 0; i < acc.size(); ++i) {
        const double len = std::sqrt(acc[i][0] * acc[i][0] + acc[i][1] * acc[i][1] + acc[i][2] * acc[i][2]);
        if (len > 0.0) {
            out[i] = {float(acc[i][0] / len), float(acc[i][1] / len), float(acc[i][2] / len)};
        }
    }
    return out;
}

/// Taubin lambda|mu smoothing with the uniform Laplacian; boundary vertices are fixed.
void taubin(Mesh& m, const CleanOptions& o) {
    const std::size_t nv = m.vertices.size();
    const auto edges = sorted_edges(m.faces);
    // Unique undirected edges, and which vertices lie on a boundary edge (used by one face).
    std::vector<std::pair<std::int32_t, std::int32_t>> unique;
    std::vector<char> fixed(nv, 0);
    for (std::size_t i = 0; i < edges.size();) {
        std::size_t j = i;
        while (j < edges.size() && edges[j][0] == edges[i][0] && edges[j][1] == edges[i][1]) ++j;
        unique.push_back({edges[i][0], edges[i][1]});
        if (j - i != 2) fixed[std::size_t(edges[i][0])] = fixed[std::size_t(edges[i][1])] = 1;
        i = j;
    }
    std::vector<int> degree(nv, 0);
    for (const auto& e : unique) {
        ++degree[std::size_t(e.first)];
        ++degree[std::size_t(e.second)];
    }
    std::vector<std::array<double, 3>> x(nv), sum(nv);
    for (std::size_t i = 0; i < nv; ++i) {
        for (int k = 0; k < 3; ++k) x[i][std::size_t(k)] = m.vertices[i][std::size_t(k)];
    }
    auto step = [&](double factor) {
        for (auto& s : sum) s = {0.0, 0.0, 0.0};
        for (const auto& e : unique) {
            for (int k = 0; k < 3; ++k) {
                sum[std::size_t(e.first)][std::size_t(k)] += x[std::size_t(e.second)][std::size_t(k)];
                sum[std::size_t(e.second)][std::size_t(k)] += x[std::size_t(e.first)][std::size_t(k)];
            }
        }
        for (std::size_t i = 0; i < nv; ++i) {
            if (fixed[i] || degree[i] == 0) continue;
            for (int k = 0; k < 3; ++k) {
                const double lap = sum[i][std::size_t(k)] / degree[i] - x[i][std::size_t(k)];
                x[i][std::size_t(k)] += factor * lap;
            }
        }
    };
    for (int it = 0; it < o.smooth_iterations; ++it) {
        step(o.smooth_lambda);
        step(o.smooth_mu);
    }
    for (std::size_t i = 0; i < nv; ++i) {
        m.vertices[i] = {float(x[i][0]), float(x[i][1]), float(x[i][2])};
    }
    if (!m.normals.empty()) m.normals = face_normals_at_vertices(m);
}

}  // namespace

CleanResult clean_mesh(const Mesh& mesh, const CleanOptions& options) {
    options.validate();
    for (const Triangle& t : mesh.faces) {
        for (std::int32_t i : t) {
            if (i < 0 || std::size_t(i) >= mesh.vertices.size()) {
                throw InvalidArgument("clean_mesh: a face refers to vertex " + std::to_string(i) +
                                      " of " + std::to_string(mesh.vertices.size()));
            }
        }
    }
    CleanResult r;
    const std::size_t nf = mesh.faces.size();

    // Edge-connected components of faces: faces around each vertex (counting sort, linear), then
    // every face is joined to the faces that share one of its edges (both end vertices).
    DisjointSets sets(nf);
    {
        const std::size_t nv = mesh.vertices.size();
        std::vector<std::size_t> first(nv + 1, 0);
        for (const Triangle& t : mesh.faces) {
            for (std::int32_t i : t) ++first[std::size_t(i) + 1];
        }
        for (std::size_t v = 0; v < nv; ++v) first[v + 1] += first[v];
        std::vector<std::int32_t> around(first[nv]);
        std::vector<std::size_t> fill(first.begin(), first.end() - 1);
        for (std::size_t f = 0; f < nf; ++f) {
            for (std::int32_t i : mesh.faces[f]) around[fill[std::size_t(i)]++] = std::int32_t(f);
        }
        for (std::size_t f = 0; f < nf; ++f) {
            const Triangle& t = mesh.faces[f];
            for (int k = 0; k < 3; ++k) {
                const std::size_t a = std::size_t(t[k]);
                const std::int32_t b = t[(k + 1) % 3];
                for (std::size_t j = first[a]; j < first[a + 1]; ++j) {
                    const std::int32_t g = around[j];
                    if (std::size_t(g) <= f) continue;  // each pair once
                    const Triangle& u = mesh.faces[std::size_t(g)];
                    if (u[0] == b || u[1] == b || u[2] == b) sets.unite(std::int32_t(f), g);
                }
            }
        }
    }
    std::vector<std::size_t> size(nf, 0);
    for (std::size_t f = 0; f < nf; ++f) ++size[std::size_t(sets.find(std::int32_t(f)))];
    std::size_t largest = 0;
    for (std::size_t f = 0; f < nf; ++f) {
        if (size[f] > 0) {
            ++r.components_before;
            largest = std::max(largest, size[f]);
        }
    }
    const double min_faces = std::max(double(options.min_component_faces),
                                      options.min_component_ratio * double(largest));
    for (std::size_t f = 0; f < nf; ++f) {
        if (size[f] > 0 && double(size[f]) < min_faces) {
            ++r.removed_components;
            r.removed_faces += size[f];
        }
    }

    // Keep faces of large components, then the vertices they use, in input order.
    Mesh& out = r.mesh;
    out.origin = mesh.origin;
    std::vector<std::int32_t> remap(mesh.vertices.size(), -1);
    for (std::size_t f = 0; f < nf; ++f) {
        if (double(size[std::size_t(sets.find(std::int32_t(f)))]) < min_faces) continue;
        out.faces.push_back(mesh.faces[f]);
        for (std::int32_t i : mesh.faces[f]) remap[std::size_t(i)] = 0;
    }
    const bool normals = mesh.normals.size() == mesh.vertices.size();
    const bool colors = mesh.colors.size() == mesh.vertices.size();
    std::int32_t next = 0;
    for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
        if (remap[i] < 0) continue;
        remap[i] = next++;
        out.vertices.push_back(mesh.vertices[i]);
        if (normals) out.normals.push_back(mesh.normals[i]);
        if (colors) out.colors.push_back(mesh.colors[i]);
    }
    for (Triangle& t : out.faces) {
        for (std::int32_t& i : t) i = remap[std::size_t(i)];
    }
    r.removed_vertices = mesh.vertices.size() - out.vertices.size();

    if (options.smooth_iterations > 0 && !out.faces.empty()) {
        taubin(out, options);
        r.smoothed_iterations = options.smooth_iterations;
    }
    return r;
}

}  // namespace vdbrecon
