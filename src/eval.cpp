// Reconstruction metrics and mesh topology (see eval.h).
#include "vdbrecon/eval.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numeric>

#include "detail/mesh_graph.h"
#include "detail/vec3.h"
#include "vdbrecon/error.h"
#include "vdbrecon/knn.h"

namespace vdbrecon {

void EvalOptions::validate() const {
    for (double t : taus) {
        if (!(std::isfinite(t) && t > 0.0)) {
            throw InvalidArgument("eval.taus: every tau must be a positive number");
        }
    }
    if (samples < 1000 || samples > 100000000) {
        throw InvalidArgument("eval.samples = " + std::to_string(samples) +
                              ": must be in 1000..1e8");
    }
    if (!(std::isfinite(mask_distance) && mask_distance >= 0.0) ||
        (!mask_points.empty() && mask_distance == 0.0)) {
        throw InvalidArgument("eval.mask_distance = " + std::to_string(mask_distance) +
                              ": must be a positive distance when mask points are given");
    }
}

namespace {

using detail::V3;
using detail::add;
using detail::cross;
using detail::dot;
using detail::mul;
using detail::sub;

/// A number as JSON and messages print it (9 significant digits).
std::string num(double v) {
    char buf[64];
    std::snprintf(buf, sizeof(buf), "%.9g", v);
    return buf;
}


/// Closest point on triangle abc to p (C. Ericson, "Real-Time Collision Detection", 5.1.5).
V3 closest_on_triangle(const V3& p, const V3& a, const V3& b, const V3& c) {
    const V3 ab = sub(b, a), ac = sub(c, a), ap = sub(p, a);
    const double d1 = dot(ab, ap), d2 = dot(ac, ap);
    if (d1 <= 0 && d2 <= 0) return a;
    const V3 bp = sub(p, b);
    const double d3 = dot(ab, bp), d4 = dot(ac, bp);
    if (d3 >= 0 && d4 <= d3) return b;
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return add(a, mul(ab, d1 / (d1 - d3)));
    const V3 cp = sub(p, c);
    const double d5 = dot(ab, cp), d6 = dot(ac, cp);
    if (d6 >= 0 && d5 <= d6) return c;
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return add(a, mul(ac, d2 / (d2 - d6)));
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        return add(b, mul(sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6))));
    }
    const double denom = 1.0 / (va + vb + vc);
    return add(a, add(mul(ab, vb * denom), mul(ac, vc * denom)));
}

/// SplitMix64 (S. Vigna): a counter-based stream, so sample i is the same on any thread.
inline std::uint64_t splitmix(std::uint64_t x) {
    x += 0x9e3779b97f4a7c15ULL;
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
    return x ^ (x >> 31);
}
inline double uniform(std::uint64_t seed, std::uint64_t i, int which) {
    const std::uint64_t h = splitmix(seed * 0x100000001b3ULL + i * 4 + std::uint64_t(which));
    return double(h >> 11) * (1.0 / 9007199254740992.0);  // [0, 1)
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Bounding-volume hierarchy over triangles

struct MeshDistance::Impl {
    struct Node {
        float lo[3], hi[3];
        std::int32_t left = -1, right = -1;  // children, or -1 for a leaf
        std::int32_t begin = 0, end = 0;     // triangle range (leaves)
    };
    std::vector<V3> a, b, c;          // triangle corners, world frame relative to `origin`
    std::vector<std::int32_t> order;  // triangle index per BVH slot
    std::vector<Node> nodes;
    Vec3d origin{0, 0, 0};

    void build(const Mesh& m) {
        origin = m.origin;
        const std::size_t nf = m.faces.size();
        a.resize(nf);
        b.resize(nf);
        c.resize(nf);
        for (std::size_t f = 0; f < nf; ++f) {
            const auto& t = m.faces[f];
            auto get = [&](std::int32_t i) {
                const Vec3f& v = m.vertices[std::size_t(i)];
                return V3{double(v[0]), double(v[1]), double(v[2])};
            };
            // Corners from the one first by position (orientation kept): a face's distances
            // then do not depend on which corner the mesh lists first.
            V3 p[3] = {get(t[0]), get(t[1]), get(t[2])};
            const int first = p[1] < p[0] ? (p[2] < p[1] ? 2 : 1) : (p[2] < p[0] ? 2 : 0);
            a[f] = p[first];
            b[f] = p[(first + 1) % 3];
            c[f] = p[(first + 2) % 3];
        }
        order.resize(nf);
        std::iota(order.begin(), order.end(), 0);
        std::vector<V3> centre(nf);
        for (std::size_t f = 0; f < nf; ++f) centre[f] = mul(add(add(a[f], b[f]), c[f]), 1.0 / 3);
        nodes.reserve(2 * nf / 4 + 2);
        build_node(0, std::int32_t(nf), centre);
    }

    std::int32_t build_node(std::int32_t begin, std::int32_t end, const std::vector<V3>& centre) {
        const std::int32_t id = std::int32_t(nodes.size());
        nodes.emplace_back();
        Node nd;
        double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
        double clo[3] = {1e300, 1e300, 1e300}, chi[3] = {-1e300, -1e300, -1e300};
        for (std::int32_t i = begin; i < end; ++i) {
            const std::size_t f = std::size_t(order[std::size_t(i)]);
            for (const V3* v : {&a[f], &b[f], &c[f]}) {
                for (int k = 0; k < 3; ++k) {
                    lo[k] = std::min(lo[k], (*v)[k]);
                    hi[k] = std::max(hi[k], (*v)[k]);
                }
            }
            for (int k = 0; k < 3; ++k) {
                clo[k] = std::min(clo[k], centre[f][k]);
                chi[k] = std::max(chi[k], centre[f][k]);
            }
        }
        for (int k = 0; k < 3; ++k) {
            // Round outwards so the float box contains the double triangle.
            nd.lo[k] = std::nextafter(float(lo[k]), -std::numeric_limits<float>::infinity());
            nd.hi[k] = std::nextafter(float(hi[k]), std::numeric_limits<float>::infinity());
        }
        if (end - begin <= 4) {
            nd.begin = begin;
            nd.end = end;
            nodes[std::size_t(id)] = nd;
            return id;
        }
        int axis = 0;
        for (int k = 1; k < 3; ++k) {
            if (chi[k] - clo[k] > chi[axis] - clo[axis]) axis = k;
        }
        const std::int32_t mid = begin + (end - begin) / 2;
        std::nth_element(order.begin() + begin, order.begin() + mid, order.begin() + end,
                         [&](std::int32_t x, std::int32_t y) {
                             const double cx = centre[std::size_t(x)][axis];
                             const double cy = centre[std::size_t(y)][axis];
                             return cx != cy ? cx < cy : x < y;
                         });
        nd.left = build_node(begin, mid, centre);
        nd.right = build_node(mid, end, centre);
        nodes[std::size_t(id)] = nd;
        return id;
    }

    static double box_dist2(const Node& n, const V3& p) {
        double d2 = 0.0;
        for (int k = 0; k < 3; ++k) {
            const double v = p[k] < n.lo[k] ? n.lo[k] - p[k] : (p[k] > n.hi[k] ? p[k] - n.hi[k] : 0.0);
            d2 += v * v;
        }
        return d2;
    }

    /// Ties between faces at the same distance go to the face first by its corners' positions
    /// (then by number, for coincident faces): the same face whatever the mesh's numbering.
    bool before(std::size_t f, std::int32_t g) const {
        if (g < 0) return true;
        const std::size_t h = std::size_t(g);
        if (a[f] != a[h]) return a[f] < a[h];
        if (b[f] != b[h]) return b[f] < b[h];
        if (c[f] != c[h]) return c[f] < c[h];
        return f < h;
    }

    double query(const V3& p, std::int32_t* face) const {
        double best = std::numeric_limits<double>::infinity();
        std::int32_t best_face = -1;
        std::int32_t stack[128];
        int top = 0;
        stack[top++] = 0;
        while (top > 0) {
            const Node& n = nodes[std::size_t(stack[--top])];
            if (box_dist2(n, p) > best) continue;  // equal: a tie may be inside
            if (n.left < 0) {
                for (std::int32_t i = n.begin; i < n.end; ++i) {
                    const std::size_t f = std::size_t(order[std::size_t(i)]);
                    const V3 q = closest_on_triangle(p, a[f], b[f], c[f]);
                    const V3 d = sub(p, q);
                    const double d2 = dot(d, d);
                    if (d2 < best || (d2 == best && before(f, best_face))) {
                        best = d2;
                        best_face = std::int32_t(f);
                    }
                }
                continue;
            }
            const Node& l = nodes[std::size_t(n.left)];
            const Node& r = nodes[std::size_t(n.right)];
            const double dl = box_dist2(l, p), dr = box_dist2(r, p);
            // Push the farther child first so the nearer one is visited next.
            if (dl < dr) {
                if (dr <= best) stack[top++] = n.right;
                if (dl <= best) stack[top++] = n.left;
            } else {
                if (dl <= best) stack[top++] = n.left;
                if (dr <= best) stack[top++] = n.right;
            }
        }
        if (face) *face = best_face;
        return std::sqrt(best);
    }
};

MeshDistance::MeshDistance(const Mesh& mesh) : impl_(std::make_unique<Impl>()) {
    if (mesh.faces.empty()) throw InvalidArgument("MeshDistance: the mesh has no faces");
    impl_->build(mesh);
}

MeshDistance::~MeshDistance() = default;

double MeshDistance::distance(const Vec3f& p, std::int32_t* face) const {
    return impl_->query({double(p[0]), double(p[1]), double(p[2])}, face);
}

std::vector<double> MeshDistance::distances(const std::vector<Vec3f>& points,
                                            std::vector<std::int32_t>* faces) const {
    std::vector<double> d(points.size());
    if (faces) faces->resize(points.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, points.size(), 1024),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            d[i] = distance(points[i], faces ? &(*faces)[i] : nullptr);
        }
    });
    return d;
}

std::vector<double> MeshDistance::distances(const PointCloud& cloud,
                                            std::vector<std::int32_t>* faces) const {
    const Vec3d& o = impl_->origin;
    const double shift[3] = {cloud.origin[0] - o[0], cloud.origin[1] - o[1], cloud.origin[2] - o[2]};
    std::vector<Vec3f> p(cloud.positions.begin(), cloud.positions.end());
    for (Vec3f& q : p) {
        for (int k = 0; k < 3; ++k) q[std::size_t(k)] = float(q[std::size_t(k)] + shift[k]);
    }
    return distances(p, faces);
}

// ---------------------------------------------------------------------------------------------
// Sampling and topology

std::vector<Vec3f> sample_surface(const Mesh& mesh, std::size_t count, std::uint64_t seed,
                                  std::vector<std::int32_t>* faces) {
    const std::size_t nf = mesh.faces.size();
    if (nf == 0) throw InvalidArgument("sample_surface: the mesh has no faces");
    std::vector<double> cdf(nf);
    double total = 0.0;
    for (std::size_t f = 0; f < nf; ++f) {
        const auto& t = mesh.faces[f];
        const Vec3f &p = mesh.vertices[std::size_t(t[0])], &q = mesh.vertices[std::size_t(t[1])],
                    &r = mesh.vertices[std::size_t(t[2])];
        const V3 e1{double(q[0]) - p[0], double(q[1]) - p[1], double(q[2]) - p[2]};
        const V3 e2{double(r[0]) - p[0], double(r[1]) - p[1], double(r[2]) - p[2]};
        const V3 cr = cross(e1, e2);
        total += 0.5 * std::sqrt(dot(cr, cr));
        cdf[f] = total;
    }
    if (!(total > 0.0)) throw InvalidArgument("sample_surface: the mesh has zero area");
    std::vector<Vec3f> out(count);
    if (faces) faces->resize(count);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 4096),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t i = rg.begin(); i < rg.end(); ++i) {
            const double u = uniform(seed, i, 0) * total;
            std::size_t f = std::size_t(std::upper_bound(cdf.begin(), cdf.end(), u) - cdf.begin());
            f = std::min(f, nf - 1);
            // Uniform barycentrics (W. Turk, "Generating random points in triangles", 1990).
            const double s = std::sqrt(uniform(seed, i, 1)), t = uniform(seed, i, 2);
            const double wa = 1.0 - s, wb = s * (1.0 - t), wc = s * t;
            const auto& tri = mesh.faces[f];
            const Vec3f &p = mesh.vertices[std::size_t(tri[0])],
                        &q = mesh.vertices[std::size_t(tri[1])],
                        &r = mesh.vertices[std::size_t(tri[2])];
            for (int k = 0; k < 3; ++k) out[i][k] = float(wa * p[k] + wb * q[k] + wc * r[k]);
            if (faces) (*faces)[i] = std::int32_t(f);
        }
    });
    return out;
}

TopologyStats mesh_topology(const Mesh& mesh) {
    TopologyStats s;
    const std::size_t nf = mesh.faces.size();
    s.faces = nf;
    std::vector<char> used(mesh.vertices.size(), 0);
    for (const Triangle& t : mesh.faces) {
        for (std::int32_t i : t) used[std::size_t(i)] = 1;
        if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) ++s.degenerate_faces;
    }
    for (char u : used) s.vertices += u;

    const std::vector<detail::EdgeUse> edges = detail::undirected_edges(mesh.faces);
    for (const detail::EdgeUse& e : edges) {
        if (e.faces == 1) ++s.boundary_edges;
        if (e.faces > 2) ++s.nonmanifold_edges;
    }
    const std::vector<std::int32_t> label = detail::face_components(mesh.faces, mesh.vertices.size());
    for (std::size_t f = 0; f < nf; ++f) s.components += std::size_t(label[f]) == f;
    s.euler = std::int64_t(s.vertices) - std::int64_t(edges.size()) + std::int64_t(nf);

    for (const Triangle& t : mesh.faces) {
        const Vec3f &p = mesh.vertices[std::size_t(t[0])], &q = mesh.vertices[std::size_t(t[1])],
                    &r = mesh.vertices[std::size_t(t[2])];
        const V3 a{p[0], p[1], p[2]}, b{q[0], q[1], q[2]}, c{r[0], r[1], r[2]};
        const V3 cr = cross(sub(b, a), sub(c, a));
        s.area += 0.5 * std::sqrt(dot(cr, cr));
        s.signed_volume += dot(a, cross(b, c)) / 6.0;
    }
    return s;
}

// ---------------------------------------------------------------------------------------------
// Evaluation

namespace {

/// Moves a mesh's vertices into another origin's frame (in double, then float).
Mesh in_frame(const Mesh& m, const Vec3d& origin) {
    if (m.origin == origin) return m;
    Mesh out = m;
    out.origin = origin;
    for (Vec3f& v : out.vertices.edit()) {
        for (int k = 0; k < 3; ++k) v[k] = float(double(v[k]) + m.origin[k] - origin[k]);
    }
    return out;
}

std::vector<V3> face_normals(const Mesh& m) {
    std::vector<V3> n(m.faces.size());
    for (std::size_t f = 0; f < m.faces.size(); ++f) {
        const auto& t = m.faces[f];
        const Vec3f &p = m.vertices[std::size_t(t[0])], &q = m.vertices[std::size_t(t[1])],
                    &r = m.vertices[std::size_t(t[2])];
        const V3 cr = cross(V3{double(q[0]) - p[0], double(q[1]) - p[1], double(q[2]) - p[2]},
                            V3{double(r[0]) - p[0], double(r[1]) - p[1], double(r[2]) - p[2]});
        const double l = std::sqrt(dot(cr, cr));
        n[f] = l > 0 ? mul(cr, 1.0 / l) : V3{0, 0, 0};
    }
    return n;
}

/// Keeps the reference samples (and their faces) within `mask_distance` of a mask point, in
/// place; `frame` is the origin the samples are relative to.
void keep_masked(std::vector<Vec3f>& samples, std::vector<std::int32_t>& faces,
                 const EvalOptions& o, const Vec3d& frame) {
    std::vector<Vec3f> mask(o.mask_points.size());
    for (std::size_t i = 0; i < mask.size(); ++i) {
        for (int k = 0; k < 3; ++k) {
            mask[i][k] = float(double(o.mask_points[i][k]) + o.mask_origin[k] - frame[k]);
        }
    }
    const KnnResult nearest = KnnIndex(mask).query(samples, 1);
    const double r2 = o.mask_distance * o.mask_distance;
    std::size_t kept = 0;
    for (std::size_t i = 0; i < samples.size(); ++i) {
        if (double(nearest.sq_distances[i]) <= r2) {
            samples[kept] = samples[i];
            faces[kept] = faces[i];
            ++kept;
        }
    }
    if (kept == 0) {
        throw InvalidArgument("evaluate: no reference sample lies within mask_distance = " +
                              num(o.mask_distance) + " of the " + std::to_string(mask.size()) +
                              " mask points. Hint: the mask must share the reference's frame "
                              "and units");
    }
    samples.resize(kept);
    faces.resize(kept);
}

}  // namespace

/// Removes the reconstruction samples whose closest reference point lies on an open border of
/// the reference (on a boundary edge of the closest face, within 1e-9 of the mesh's size), with
/// their faces, closest faces and distances, keeping the order.
void drop_over_holes(const Mesh& reference, const std::vector<Vec3f>& rs, std::vector<std::int32_t>& rf,
                     std::vector<std::int32_t>& rcl, std::vector<double>& dr) {
    const std::vector<std::uint64_t> border = detail::border_edge_keys(reference.faces);
    if (border.empty()) return;
    const double eps = 1e-9 * std::max(1.0, bounding_box(reference.vertices).diagonal());
    auto vertex = [&](std::int32_t v) {
        const Vec3f& p = reference.vertices[std::size_t(v)];
        return V3{p[0], p[1], p[2]};
    };
    std::size_t kept = 0;
    for (std::size_t i = 0; i < dr.size(); ++i) {
        const Triangle& t = reference.faces[std::size_t(rcl[i])];
        const V3 p{rs[i][0], rs[i][1], rs[i][2]};
        bool over_hole = false;
        for (int k = 0; k < 3 && !over_hole; ++k) {
            const std::int32_t a = t[k], b = t[(k + 1) % 3];
            if (!std::binary_search(border.begin(), border.end(), detail::edge_key(a, b))) continue;
            // The closest point of the edge.
            const V3 u = vertex(a), w = vertex(b);
            const V3 e{w[0] - u[0], w[1] - u[1], w[2] - u[2]};
            const double ee = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
            double s = ee > 0.0 ? ((p[0] - u[0]) * e[0] + (p[1] - u[1]) * e[1] + (p[2] - u[2]) * e[2]) / ee
                                : 0.0;
            s = std::clamp(s, 0.0, 1.0);
            const V3 d{p[0] - u[0] - s * e[0], p[1] - u[1] - s * e[1], p[2] - u[2] - s * e[2]};
            over_hole = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) <= dr[i] + eps;
        }
        if (over_hole) continue;
        rf[kept] = rf[i];
        rcl[kept] = rcl[i];
        dr[kept] = dr[i];
        ++kept;
    }
    rf.resize(kept);
    rcl.resize(kept);
    dr.resize(kept);
}

EvalResult evaluate(const Mesh& recon_in, const Mesh& reference, const EvalOptions& options) {
    options.validate();
    if (recon_in.faces.empty()) throw InvalidArgument("evaluate: the reconstruction has no faces");
    if (reference.faces.empty()) throw InvalidArgument("evaluate: the reference has no faces");
    const Mesh recon = in_frame(recon_in, reference.origin);

    EvalResult r;
    r.samples = options.samples;
    r.recon = mesh_topology(recon);
    r.reference = mesh_topology(reference);

    std::vector<std::int32_t> rf, gf, rcl, gcl;
    const std::vector<Vec3f> rs = sample_surface(recon, options.samples, options.seed, &rf);
    std::vector<Vec3f> gs = sample_surface(reference, options.samples, options.seed + 1, &gf);
    if (!options.mask_points.empty()) keep_masked(gs, gf, options, reference.origin);
    r.reference_samples = gs.size();
    const MeshDistance to_ref(reference), to_recon(recon);
    std::vector<double> dr = to_ref.distances(rs, &rcl);
    if (options.ignore_reference_holes) drop_over_holes(reference, rs, rf, rcl, dr);
    r.recon_samples = dr.size();
    if (dr.empty()) {
        throw InvalidArgument("evaluate: every reconstruction sample lies over a hole of the "
                              "reference (ignore_reference_holes)");
    }
    const std::vector<double> dg = to_recon.distances(gs, &gcl);
    const std::vector<V3> rn = face_normals(recon), gn = face_normals(reference);

    auto mean = [](const std::vector<double>& v) {
        double s = 0.0;
        for (double x : v) s += x;
        return s / double(v.size());
    };
    r.accuracy = mean(dr);
    r.completeness = mean(dg);
    r.chamfer_l1 = 0.5 * (r.accuracy + r.completeness);
    r.hausdorff = std::max(*std::max_element(dr.begin(), dr.end()),
                           *std::max_element(dg.begin(), dg.end()));
    double nc = 0.0;
    for (std::size_t i = 0; i < dr.size(); ++i) {
        nc += std::fabs(dot(rn[std::size_t(rf[i])], gn[std::size_t(rcl[i])]));
    }
    for (std::size_t i = 0; i < gs.size(); ++i) {
        nc += std::fabs(dot(gn[std::size_t(gf[i])], rn[std::size_t(gcl[i])]));
    }
    r.normal_consistency = nc / double(dr.size() + gs.size());

    std::vector<double> taus = options.taus;
    if (taus.empty()) {
        BBox b = bounding_box(reference.vertices);
        taus.push_back(0.002 * b.diagonal());
    }
    for (double tau : taus) {
        FScore f;
        f.tau = tau;
        f.precision = double(std::count_if(dr.begin(), dr.end(), [&](double d) { return d < tau; })) /
                      double(dr.size());
        f.recall = double(std::count_if(dg.begin(), dg.end(), [&](double d) { return d < tau; })) /
                   double(dg.size());
        f.fscore = f.precision + f.recall > 0
                       ? 2.0 * f.precision * f.recall / (f.precision + f.recall)
                       : 0.0;
        r.fscores.push_back(f);
    }
    return r;
}

namespace {

std::string topology_json(const TopologyStats& t, const std::string& indent) {
    std::string s = "{\n";
    s += indent + "  \"vertices\": " + std::to_string(t.vertices) + ",\n";
    s += indent + "  \"faces\": " + std::to_string(t.faces) + ",\n";
    s += indent + "  \"components\": " + std::to_string(t.components) + ",\n";
    s += indent + "  \"boundary_edges\": " + std::to_string(t.boundary_edges) + ",\n";
    s += indent + "  \"nonmanifold_edges\": " + std::to_string(t.nonmanifold_edges) + ",\n";
    s += indent + "  \"degenerate_faces\": " + std::to_string(t.degenerate_faces) + ",\n";
    s += indent + "  \"euler\": " + std::to_string(t.euler) + ",\n";
    s += indent + "  \"watertight\": " + (t.watertight() ? "true" : "false") + ",\n";
    s += indent + "  \"area\": " + num(t.area) + ",\n";
    s += indent + "  \"signed_volume\": " + num(t.signed_volume) + "\n";
    s += indent + "}";
    return s;
}

}  // namespace

std::string to_json(const EvalResult& r) {
    std::string s = "{\n";
    s += "  \"accuracy\": " + num(r.accuracy) + ",\n";
    s += "  \"completeness\": " + num(r.completeness) + ",\n";
    s += "  \"chamfer_l1\": " + num(r.chamfer_l1) + ",\n";
    s += "  \"hausdorff\": " + num(r.hausdorff) + ",\n";
    s += "  \"normal_consistency\": " + num(r.normal_consistency) + ",\n";
    s += "  \"fscore\": [";
    for (std::size_t i = 0; i < r.fscores.size(); ++i) {
        const FScore& f = r.fscores[i];
        s += (i ? ", " : "") + std::string("{\"tau\": ") + num(f.tau) +
             ", \"precision\": " + num(f.precision) + ", \"recall\": " + num(f.recall) +
             ", \"fscore\": " + num(f.fscore) + "}";
    }
    s += "],\n";
    s += "  \"samples\": " + std::to_string(r.samples) + ",\n";
    s += "  \"reference_samples\": " + std::to_string(r.reference_samples) + ",\n";
    s += "  \"recon_samples\": " + std::to_string(r.recon_samples) + ",\n";
    s += "  \"recon\": " + topology_json(r.recon, "  ") + ",\n";
    s += "  \"reference\": " + topology_json(r.reference, "  ") + "\n";
    s += "}\n";
    return s;
}

}  // namespace vdbrecon
