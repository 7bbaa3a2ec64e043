// Mesh cleanup (see clean.h).
#include "vdbrecon/clean.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <vector>

#include "detail/mesh_graph.h"
#include "detail/release.h"
#include "detail/select.h"
#include "vdbrecon/error.h"

namespace vdbrecon {

void CleanOptions::validate() const {
    if (!(std::isfinite(min_component_samples) && min_component_samples >= 0.0)) {
        throw InvalidArgument("clean.min_component_samples = " +
                              std::to_string(min_component_samples) +
                              ": must be a non-negative count");
    }
    if (!(std::isfinite(sample_spacing) && sample_spacing >= 0.0)) {
        throw InvalidArgument("clean.sample_spacing = " + std::to_string(sample_spacing) +
                              ": must be a non-negative length (0 = from the mesh)");
    }
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

/// Area-weighted unit vertex normals.
std::vector<Vec3f> vertex_normals(const Mesh& m) {
    const std::vector<std::array<double, 3>> sum = detail::face_normal_sums(m);
    std::vector<Vec3f> out(m.vertices.size(), Vec3f{0.0f, 0.0f, 0.0f});
    for (std::size_t i = 0; i < sum.size(); ++i) {
        const auto& n = sum[i];
        const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (len > 0.0) out[i] = {float(n[0] / len), float(n[1] / len), float(n[2] / len)};
    }
    return out;
}

/// Taubin lambda|mu smoothing with the uniform Laplacian; boundary vertices are fixed.
void taubin(Mesh& m, const CleanOptions& o) {
    const std::size_t nv = m.vertices.size();
    // Edges, and the vertices on a boundary (or non-manifold) edge: those stay fixed.
    const std::vector<detail::EdgeUse> edges = detail::undirected_edges(m.faces);
    std::vector<char> fixed(nv, 0);
    for (const detail::EdgeUse& e : edges) {
        if (e.faces != 2) fixed[std::size_t(e.a)] = fixed[std::size_t(e.b)] = 1;
    }
    std::vector<int> degree(nv, 0);
    for (const detail::EdgeUse& e : edges) {
        ++degree[std::size_t(e.a)];
        ++degree[std::size_t(e.b)];
    }
    std::vector<std::array<double, 3>> x(nv), sum(nv);
    for (std::size_t i = 0; i < nv; ++i) {
        for (int k = 0; k < 3; ++k) x[i][std::size_t(k)] = m.vertices[i][std::size_t(k)];
    }
    auto step = [&](double factor) {
        for (auto& s : sum) s = {0.0, 0.0, 0.0};
        for (const detail::EdgeUse& e : edges) {
            for (int k = 0; k < 3; ++k) {
                sum[std::size_t(e.a)][std::size_t(k)] += x[std::size_t(e.b)][std::size_t(k)];
                sum[std::size_t(e.b)][std::size_t(k)] += x[std::size_t(e.a)][std::size_t(k)];
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
    std::vector<Vec3f>& vertices = m.vertices.edit();
    for (std::size_t i = 0; i < nv; ++i) {
        vertices[i] = {float(x[i][0]), float(x[i][1]), float(x[i][2])};
    }
    if (!m.normals.empty()) m.normals = vertex_normals(m);
}


/// The median (rank n / 2) of non-negative `values`, without a copy of them; 0 for none.
double median_of(const std::vector<float>& values) {
    return values.empty() ? 0.0 : double(detail::select_rank(values.size() / 2, values));
}

/// The median edge length of the faces (each face's three edges), the unit of the evidence
/// when no sample spacing is given.
double median_edge(const Mesh& m) {
    std::vector<float> len;
    len.reserve(m.faces.size() * 3);
    for (const Triangle& t : m.faces) {
        for (int e = 0; e < 3; ++e) {
            const Vec3f& a = m.vertices[std::size_t(t[std::size_t(e)])];
            const Vec3f& b = m.vertices[std::size_t(t[std::size_t((e + 1) % 3)])];
            const double dx = double(a[0]) - b[0], dy = double(a[1]) - b[1],
                         dz = double(a[2]) - b[2];
            len.push_back(float(std::sqrt(dx * dx + dy * dy + dz * dz)));
        }
    }
    return median_of(len);
}

/// Renumbers face_components()' labels (each set's smallest face) in place as 0, 1, ... in
/// order of that face; returns the number of components. Arrays per component then take a
/// slot per component, not per face (on a 24.5M-face terrain, 300 MB less at the clean
/// stage's peak).
std::size_t number_components(std::vector<std::int32_t>& label) {
    std::int32_t next = 0;
    for (std::size_t f = 0; f < label.size(); ++f) {
        // A set's smallest face comes first and is renumbered before the rest of its faces.
        const auto root = std::size_t(label[f]);
        label[f] = root == f ? next++ : label[root];
    }
    return std::size_t(next);
}

/// Per component (indexed by its number, as `label` gives it per face): the samples' worth of
/// supported surface that built it, sum area_f * min(1, w_f / w_typical) / h^2 (see clean.h).
std::vector<double> component_evidence(const Mesh& m, const std::vector<std::int32_t>& label,
                                       std::size_t components, const std::vector<float>& support,
                                       double h, double& typical) {
    const bool weighted = !support.empty();
    typical = weighted ? median_of(support) : 0.0;
    const double inv_h2 = 1.0 / (h * h);
    std::vector<double> evidence(components, 0.0);
    for (std::size_t f = 0; f < m.faces.size(); ++f) {
        const Triangle& t = m.faces[f];
        const Vec3f& a = m.vertices[std::size_t(t[0])];
        const Vec3f& b = m.vertices[std::size_t(t[1])];
        const Vec3f& c = m.vertices[std::size_t(t[2])];
        const double u[3] = {double(b[0]) - a[0], double(b[1]) - a[1], double(b[2]) - a[2]};
        const double v[3] = {double(c[0]) - a[0], double(c[1]) - a[1], double(c[2]) - a[2]};
        const double x = u[1] * v[2] - u[2] * v[1], y = u[2] * v[0] - u[0] * v[2],
                     z = u[0] * v[1] - u[1] * v[0];
        double share = 1.0;
        if (weighted) {
            const double w = (double(support[std::size_t(t[0])]) + support[std::size_t(t[1])] +
                              support[std::size_t(t[2])]) / 3.0;
            share = typical > 0.0 ? std::clamp(w / typical, 0.0, 1.0) : 1.0;
        }
        evidence[std::size_t(label[f])] += 0.5 * std::sqrt(x * x + y * y + z * z) * share * inv_h2;
    }
    return evidence;
}

/// Per component (by its number): 0 kept, 1 backed by too few samples, 2 too small beside the
/// largest; the counts go into r.
std::vector<char> verdicts(const Mesh& mesh, const std::vector<std::int32_t>& label,
                           std::size_t components, const std::vector<float>& support,
                           const CleanOptions& options, CleanResult& r) {
    const std::size_t nf = mesh.faces.size();
    std::vector<std::int32_t> size(components, 0);
    for (std::size_t f = 0; f < nf; ++f) ++size[std::size_t(label[f])];
    r.components_before = components;
    std::size_t largest = 0;
    for (std::size_t c = 0; c < components; ++c) largest = std::max(largest, std::size_t(size[c]));
    const double min_faces = std::max(double(options.min_component_faces),
                                      options.min_component_ratio * double(largest));
    std::vector<double> evidence;
    if (options.min_component_samples > 0.0 && nf > 0) {
        const double h = options.sample_spacing > 0.0 ? options.sample_spacing : median_edge(mesh);
        if (h > 0.0) {
            evidence = component_evidence(mesh, label, components, support, h, r.typical_support);
        }
    }
    std::vector<char> verdict(components, 0);
    for (std::size_t c = 0; c < components; ++c) {
        if (!evidence.empty() && evidence[c] < options.min_component_samples) {
            verdict[c] = 1;
            ++r.removed_unsupported;
        } else if (double(size[c]) < min_faces) {
            verdict[c] = 2;
            ++r.removed_small;
        } else {
            continue;
        }
        ++r.removed_components;
        r.removed_faces += std::size_t(size[c]);
    }
    return verdict;
}

}  // namespace

CleanResult clean_mesh(Mesh&& mesh, const CleanOptions& options,
                       const std::vector<float>& support) {
    options.validate();
    for (const Triangle& t : mesh.faces) {
        for (std::int32_t i : t) {
            if (i < 0 || std::size_t(i) >= mesh.vertices.size()) {
                throw InvalidArgument("clean_mesh: a face refers to vertex " + std::to_string(i) +
                                      " of " + std::to_string(mesh.vertices.size()));
            }
        }
    }
    if (!support.empty() && support.size() != mesh.vertices.size()) {
        throw InvalidArgument("clean_mesh: " + std::to_string(support.size()) +
                              " support values for " + std::to_string(mesh.vertices.size()) +
                              " vertices");
    }
    CleanResult r;
    const std::size_t nf = mesh.faces.size();

    // Edge-connected components, and the verdict on each.
    std::vector<std::int32_t> label = detail::face_components(mesh.faces, mesh.vertices.size());
    const std::size_t components = number_components(label);
    std::vector<char> verdict = verdicts(mesh, label, components, support, options, r);

    // Keep the faces of kept components, then the vertices they use, in input order:
    // compacted in place (the kept ones only move down), so no second copy of the mesh joins
    // the peak.
    r.mesh = std::move(mesh);
    Mesh& out = r.mesh;
    if (r.removed_faces > 0) {
        std::vector<Triangle>& faces = out.faces.edit();
        const bool regions = out.regions.size() == nf;
        std::vector<std::int32_t>* reg = regions ? &out.regions.edit() : nullptr;
        std::size_t kept = 0;
        for (std::size_t f = 0; f < nf; ++f) {
            if (verdict[std::size_t(label[f])]) continue;
            if (reg) (*reg)[kept] = (*reg)[f];
            faces[kept++] = faces[f];
        }
        faces.resize(kept);
        if (reg) reg->resize(kept);
    }
    detail::release(label);
    detail::release(verdict);
    std::size_t nv = 0;
    const std::size_t before = out.vertices.size();
    const std::vector<std::int32_t> remap = detail::compact_vertices(out.faces.edit(), before, &nv);
    if (nv < before) {
        // remap[i] <= i (order kept): moving each vertex down in increasing i overwrites only
        // vertices already moved.
        auto compact = [&](Column<Vec3f>& column) {
            if (column.size() != before) return;
            std::vector<Vec3f>& v = column.edit();
            for (std::size_t i = 0; i < before; ++i) {
                if (remap[i] >= 0) v[std::size_t(remap[i])] = v[i];
            }
            v.resize(nv);
        };
        compact(out.vertices);
        compact(out.normals);
        compact(out.colors);
    }
    r.removed_vertices = before - out.vertices.size();

    if (options.smooth_iterations > 0 && !out.faces.empty()) {
        taubin(out, options);
        r.smoothed_iterations = options.smooth_iterations;
    }
    return r;
}

CleanResult clean_mesh(const Mesh& mesh, const CleanOptions& options,
                       const std::vector<float>& support) {
    // A borrowed array is copied only when changed.
    return clean_mesh(Mesh(mesh), options, support);
}

}  // namespace vdbrecon
