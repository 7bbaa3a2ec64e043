// Mesh hole filling (see holes.h).
#include "vdbrecon/holes.h"

#include <Eigen/Dense>
#include <Eigen/Sparse>
#include <Eigen/SparseLU>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <deque>
#include <limits>
#include <map>
#include <string>
#include <unordered_map>
#include <vector>

#include "detail/mesh_graph.h"
#include "vdbrecon/error.h"

namespace vdbrecon {

void HoleFillOptions::validate() const {
    if (max_edges > std::size_t(1) << 30) {
        throw InvalidArgument("holes.max_edges = " + std::to_string(max_edges) +
                              ": must be at most 2^30 (0 = every loop)");
    }
}

namespace {

using V3 = Eigen::Vector3d;

std::uint64_t key(std::int32_t a, std::int32_t b) {
    return (std::uint64_t(std::uint32_t(a)) << 32) | std::uint32_t(b);
}

/// The directed edges of a set of faces, sorted, with each edge's face's third vertex:
/// lookups by binary search (a hash map of a million-face mesh's edges cost more than the
/// filling).
class DirectedEdges {
  public:
    explicit DirectedEdges(const std::vector<Triangle>& faces) {
        edges_.reserve(3 * faces.size());
        for (const Triangle& t : faces) {
            for (int k = 0; k < 3; ++k) edges_.push_back({key(t[k], t[(k + 1) % 3]), t[(k + 2) % 3]});
        }
        tbb::parallel_sort(edges_.begin(), edges_.end());
    }
    /// How many faces use the directed edge a -> b.
    std::size_t count(std::uint64_t e) const {
        const auto range = std::equal_range(edges_.begin(), edges_.end(), Entry{e, kMin},
                                            [](const Entry& x, const Entry& y) { return x.first < y.first; });
        return std::size_t(range.second - range.first);
    }
    bool contains(std::int32_t a, std::int32_t b) const {
        return count(key(a, b)) > 0 || count(key(b, a)) > 0;
    }

  private:
    using Entry = std::pair<std::uint64_t, std::int32_t>;
    static constexpr std::int32_t kMin = std::numeric_limits<std::int32_t>::min();
    std::vector<Entry> edges_;
};

/// A hole: its vertices in order (hole edges v[i] -> v[i+1], the reverse of the mesh's boundary
/// edges, so that patch triangles using them are oriented like the mesh) and, per hole edge,
/// the third vertex of the mesh face on its other side.
struct Loop {
    std::vector<std::int32_t> v, opposite;
};

/// The boundary loops of an edge-manifold mesh. A directed edge used twice (non-manifold or
/// inconsistently oriented) keeps the loops through it out.
std::vector<Loop> boundary_loops(const std::vector<Triangle>& faces, const DirectedEdges& edges) {
    // Hole edges b -> a, ordered by their start (a multimap: two loops may touch at a vertex).
    std::multimap<std::int32_t, std::pair<std::int32_t, std::int32_t>> out;  // b -> (a, opposite)
    for (const Triangle& t : faces) {
        for (int k = 0; k < 3; ++k) {
            const std::int32_t a = t[k], b = t[(k + 1) % 3];
            if (a == b || edges.count(key(b, a)) > 0) continue;
            if (edges.count(key(a, b)) != 1) return {};  // not edge-manifold: fill nothing
            out.emplace(b, std::make_pair(a, t[(k + 2) % 3]));
        }
    }
    std::vector<Loop> loops;
    while (!out.empty()) {
        Loop loop;
        auto it = out.begin();
        const std::int32_t start = it->first;
        std::int32_t at = start;
        bool closed = false;
        while (it != out.end()) {
            loop.v.push_back(at);
            loop.opposite.push_back(it->second.second);
            const std::int32_t next = it->second.first;
            out.erase(it);
            if (next == start) {
                closed = true;
                break;
            }
            at = next;
            it = out.find(at);
        }
        if (closed && loop.v.size() >= 3) loops.push_back(std::move(loop));
    }
    return loops;
}

/// The unit normal of triangle (a, b, c) and twice its area.
V3 normal_of(const V3& a, const V3& b, const V3& c, double* twice_area = nullptr) {
    const V3 n = (b - a).cross(c - a);
    const double len = n.norm();
    if (twice_area) *twice_area = len;
    return len > 0.0 ? V3(n / len) : V3(0.0, 0.0, 0.0);
}

/// Liepa's weight of a triangulation: the largest dihedral angle (as 1 - cos) first, then the
/// area.
struct Weight {
    double angle = 0.0, area = 0.0;
    bool operator<(const Weight& o) const {
        return angle < o.angle || (angle == o.angle && area < o.area);
    }
};

/// Minimum-weight triangulation of the loop by dynamic programming over its sub-polygons
/// (O(n^3)); returns triangles of loop indices.
std::vector<Triangle> triangulate(const Loop& loop, const std::vector<V3>& p,
                                  const DirectedEdges& mesh_edges) {
    const int n = int(loop.v.size());
    // Chords that are edges of the mesh already (two loop vertices joined across the mesh)
    // would be non-manifold edges: such triangles are taken only when nothing else is left.
    std::vector<char> taken(std::size_t(n) * n, 0);
    for (int i = 0; i < n; ++i) {
        for (int j = i + 2; j < n; ++j) {
            const std::int32_t a = loop.v[std::size_t(i)], b = loop.v[std::size_t(j)];
            taken[std::size_t(i) * n + j] = mesh_edges.contains(a, b);
        }
    }
    std::vector<Weight> w(std::size_t(n) * n);
    std::vector<std::int32_t> best(std::size_t(n) * n, -1);
    auto at = [n](int i, int j) { return std::size_t(i) * std::size_t(n) + std::size_t(j); };
    auto pos = [&](int i) -> const V3& { return p[std::size_t(loop.v[std::size_t(i)])]; };
    // The normal of the triangle across edge (i, j) of sub-polygon i..j: the mesh face for a
    // hole edge, else the sub-polygon's chosen triangle.
    auto across = [&](int i, int j) {
        if (j == i + 1) return normal_of(pos(i), pos(j), p[std::size_t(loop.opposite[std::size_t(i)])]);
        const int k = best[at(i, j)];
        return normal_of(pos(i), pos(k), pos(j));
    };
    for (int len = 2; len < n; ++len) {
        for (int i = 0; i + len < n; ++i) {
            const int j = i + len;
            Weight chosen{std::numeric_limits<double>::infinity(), 0.0};
            int arg = -1;
            for (int k = i + 1; k < j; ++k) {
                double a2 = 0.0;
                const V3 nt = normal_of(pos(i), pos(k), pos(j), &a2);
                double angle = std::max(1.0 - nt.dot(across(i, k)), 1.0 - nt.dot(across(k, j)));
                if (i == 0 && j == n - 1) {  // the closing hole edge j -> i
                    const V3 last = normal_of(pos(j), pos(i),
                                              p[std::size_t(loop.opposite[std::size_t(j)])]);
                    angle = std::max(angle, 1.0 - nt.dot(last));
                }
                const Weight& l = w[at(i, k)];
                const Weight& r = w[at(k, j)];
                const bool clash = (k > i + 1 && taken[at(i, k)]) || (j > k + 1 && taken[at(k, j)]);
                const Weight c{std::max({angle, l.angle, r.angle}) + (clash ? 1e6 : 0.0),
                               l.area + r.area + 0.5 * a2};
                if (arg < 0 || c < chosen) {
                    chosen = c;
                    arg = k;
                }
            }
            w[at(i, j)] = chosen;
            best[at(i, j)] = arg;
        }
    }
    std::vector<Triangle> tris;
    std::vector<std::pair<int, int>> stack{{0, n - 1}};
    while (!stack.empty()) {
        const auto [i, j] = stack.back();
        stack.pop_back();
        if (j - i < 2) continue;
        const int k = best[at(i, j)];
        tris.push_back({i, k, j});
        stack.push_back({i, k});
        stack.push_back({k, j});
    }
    return tris;
}

/// State of the patches being built: positions (mesh vertices first, then new ones), the
/// target edge length sigma per vertex (Liepa), and the patch triangles (global indices).
struct Patch {
    std::vector<V3> p;
    std::vector<double> sigma;
    std::vector<Triangle> tris;
    std::size_t first_new = 0;
};

/// Liepa's edge relaxation: flips an edge shared by two patch triangles when the two angles
/// opposite it sum to more than pi (the Delaunay criterion) and the flipped edge is new.
/// Lawson's flip algorithm: every face is checked once, and the faces a flip changes or faces
/// across from are checked again (first in, first out: deterministic); at most 20 flips per
/// face in all, in case non-planar loops would cycle.
void relax(Patch& s, const DirectedEdges& mesh_edges) {
    std::unordered_map<std::uint64_t, std::int32_t> owner;  // directed edge -> patch face
    owner.reserve(3 * s.tris.size());
    for (std::size_t f = 0; f < s.tris.size(); ++f) {
        for (int k = 0; k < 3; ++k) owner[key(s.tris[f][k], s.tris[f][(k + 1) % 3])] = std::int32_t(f);
    }
    std::deque<std::int32_t> queue;
    std::vector<char> queued(s.tris.size(), 1);
    for (std::size_t f = 0; f < s.tris.size(); ++f) queue.push_back(std::int32_t(f));
    auto push = [&](std::int32_t f) {
        if (f >= 0 && !queued[std::size_t(f)]) {
            queued[std::size_t(f)] = 1;
            queue.push_back(f);
        }
    };
    auto across = [&](std::int32_t u, std::int32_t v) {  // the face holding v -> u
        const auto it = owner.find(key(v, u));
        return it == owner.end() ? std::int32_t(-1) : it->second;
    };
    auto angle = [](const V3& o, const V3& u, const V3& v) {
        return std::atan2((u - o).cross(v - o).norm(), (u - o).dot(v - o));
    };
    std::size_t budget = 20 * s.tris.size();
    while (!queue.empty() && budget > 0) {
        const std::int32_t f = queue.front();
        queue.pop_front();
        queued[std::size_t(f)] = 0;
        for (int k = 0; k < 3; ++k) {
            const std::int32_t a = s.tris[std::size_t(f)][k], b = s.tris[std::size_t(f)][(k + 1) % 3],
                               c = s.tris[std::size_t(f)][(k + 2) % 3];
            const std::int32_t g = across(a, b);
            if (g < 0) continue;
            std::int32_t d = -1;
            for (std::int32_t x : s.tris[std::size_t(g)]) {
                if (x != a && x != b) d = x;
            }
            if (d < 0 || owner.count(key(c, d)) || owner.count(key(d, c)) ||
                mesh_edges.contains(c, d)) {
                continue;
            }
            const V3 &pa = s.p[std::size_t(a)], &pb = s.p[std::size_t(b)];
            const V3 &pc = s.p[std::size_t(c)], &pd = s.p[std::size_t(d)];
            if (angle(pc, pa, pb) + angle(pd, pa, pb) <= M_PI + 1e-9) continue;
            // f = (a, b, c), g = (b, a, d)  ->  f = (c, a, d), g = (d, b, c).
            owner.erase(key(a, b));
            owner.erase(key(b, a));
            s.tris[std::size_t(f)] = {c, a, d};
            s.tris[std::size_t(g)] = {d, b, c};
            for (std::int32_t h : {f, g}) {
                const Triangle& t = s.tris[std::size_t(h)];
                for (int e = 0; e < 3; ++e) owner[key(t[e], t[(e + 1) % 3])] = h;
            }
            --budget;
            push(f);
            push(g);
            for (const auto& [u, v] : {std::pair{c, a}, std::pair{a, d}, std::pair{d, b}, std::pair{b, c}}) {
                push(across(u, v));
            }
            break;  // f changed: its edges are checked when it comes up again
        }
    }
}

/// Liepa's refinement: splits a patch triangle at its centroid while the centroid is farther
/// than sigma / sqrt(2) from each corner, relaxing the edges after each round.
void refine(Patch& s, const DirectedEdges& mesh_edges) {
    const double alpha = std::sqrt(2.0);
    relax(s, mesh_edges);
    for (int round = 0; round < 60; ++round) {
        std::vector<Triangle> next;
        next.reserve(s.tris.size() * 3);
        bool split = false;
        for (const Triangle& t : s.tris) {
            const V3 m = (s.p[std::size_t(t[0])] + s.p[std::size_t(t[1])] + s.p[std::size_t(t[2])]) / 3.0;
            const double sm = (s.sigma[std::size_t(t[0])] + s.sigma[std::size_t(t[1])] +
                               s.sigma[std::size_t(t[2])]) / 3.0;
            bool ok = true;
            for (std::int32_t v : t) {
                const double d = alpha * (m - s.p[std::size_t(v)]).norm();
                ok = ok && d > sm && d > s.sigma[std::size_t(v)];
            }
            if (!ok) {
                next.push_back(t);
                continue;
            }
            const std::int32_t c = std::int32_t(s.p.size());
            s.p.push_back(m);
            s.sigma.push_back(sm);
            next.push_back({t[0], t[1], c});
            next.push_back({t[1], t[2], c});
            next.push_back({t[2], t[0], c});
            split = true;
        }
        s.tris = std::move(next);
        if (!split) break;
        relax(s, mesh_edges);
    }
}

/// Moves the new vertices to the solution of the uniform bi-Laplacian equation L(L(x)) = 0 with
/// every other vertex fixed (a thin-plate patch that meets the mesh with its slope).
void fair(Patch& s, const std::vector<Triangle>& mesh_faces) {
    const std::size_t nv = s.p.size(), first = s.first_new;
    if (nv == first) return;
    // Neighbours of the new vertices and of their neighbours.
    std::vector<char> need(nv, 0);
    std::vector<std::vector<std::int32_t>> nb(nv);
    auto link = [&](const std::vector<Triangle>& tris, bool only_needed) {
        for (const Triangle& t : tris) {
            for (int k = 0; k < 3; ++k) {
                const std::int32_t a = t[k], b = t[(k + 1) % 3];
                if (only_needed && !need[std::size_t(a)] && !need[std::size_t(b)]) continue;
                nb[std::size_t(a)].push_back(b);
                nb[std::size_t(b)].push_back(a);
            }
        }
    };
    for (const Triangle& t : s.tris) {  // the new vertices are in patch faces only
        if (std::size_t(t[0]) >= first || std::size_t(t[1]) >= first || std::size_t(t[2]) >= first) {
            for (std::int32_t v : t) need[std::size_t(v)] = 1;
        }
    }
    link(s.tris, false);
    link(mesh_faces, true);
    for (auto& l : nb) {
        std::sort(l.begin(), l.end());
        l.erase(std::unique(l.begin(), l.end()), l.end());
    }
    const int n = int(nv - first);
    std::vector<Eigen::Triplet<double>> coef;
    Eigen::MatrixXd rhs = Eigen::MatrixXd::Zero(n, 3);
    auto add = [&](int row, std::int32_t k, double c) {
        if (std::size_t(k) >= first) {
            coef.emplace_back(row, int(std::size_t(k) - first), c);
        } else {
            rhs.row(row) -= c * s.p[std::size_t(k)].transpose();
        }
    };
    // L_j(x) = mean over N(j) of x - x_j;  row i: mean over N(i) of L_j - L_i = 0.
    auto add_laplacian = [&](int row, std::int32_t j, double scale) {
        const auto& l = nb[std::size_t(j)];
        for (std::int32_t k : l) add(row, k, scale / double(l.size()));
        add(row, j, -scale);
    };
    for (int r = 0; r < n; ++r) {
        const std::int32_t i = std::int32_t(first + std::size_t(r));
        const auto& l = nb[std::size_t(i)];
        for (std::int32_t j : l) add_laplacian(r, j, 1.0 / double(l.size()));
        add_laplacian(r, i, -1.0);
    }
    Eigen::SparseMatrix<double> a(n, n);
    a.setFromTriplets(coef.begin(), coef.end());
    Eigen::SparseLU<Eigen::SparseMatrix<double>> lu;
    lu.compute(a);
    if (lu.info() != Eigen::Success) return;  // keep the refined positions
    const Eigen::MatrixXd x = lu.solve(rhs);
    if (lu.info() != Eigen::Success || !x.allFinite()) return;
    for (int r = 0; r < n; ++r) s.p[first + std::size_t(r)] = x.row(r).transpose();
}

/// Per mesh vertex, the mean length of its edges (Liepa's sigma).
std::vector<double> mean_edge_lengths(const std::vector<V3>& p, const std::vector<Triangle>& faces) {
    std::vector<double> sum(p.size(), 0.0);
    std::vector<int> count(p.size(), 0);
    for (const Triangle& t : faces) {
        for (int k = 0; k < 3; ++k) {
            const std::int32_t a = t[k], b = t[(k + 1) % 3];
            const double l = (p[std::size_t(a)] - p[std::size_t(b)]).norm();
            sum[std::size_t(a)] += l;
            ++count[std::size_t(a)];
            sum[std::size_t(b)] += l;
            ++count[std::size_t(b)];
        }
    }
    for (std::size_t v = 0; v < p.size(); ++v) {
        if (count[v] > 0) sum[v] /= count[v];
    }
    return sum;
}

/// The loop's triangulation: by dynamic programming up to kMaxDynamic vertices, else a fan
/// around a new vertex at the loop's centroid (refinement and fairing then shape it).
constexpr std::size_t kMaxDynamic = 600;

void triangulate_loop(const Loop& loop, Patch& s,
                      const DirectedEdges& mesh_edges) {
    if (loop.v.size() <= kMaxDynamic) {
        for (const Triangle& t : triangulate(loop, s.p, mesh_edges)) {
            s.tris.push_back({loop.v[std::size_t(t[0])], loop.v[std::size_t(t[1])],
                              loop.v[std::size_t(t[2])]});
        }
        return;
    }
    V3 c(0.0, 0.0, 0.0);
    double sigma = 0.0;
    for (std::int32_t v : loop.v) {
        c += s.p[std::size_t(v)];
        sigma += s.sigma[std::size_t(v)];
    }
    const std::int32_t centre = std::int32_t(s.p.size());
    s.p.push_back(c / double(loop.v.size()));
    s.sigma.push_back(sigma / double(loop.v.size()));
    for (std::size_t i = 0; i < loop.v.size(); ++i) {
        s.tris.push_back({loop.v[i], loop.v[(i + 1) % loop.v.size()], centre});
    }
}

/// Appends the patch's new vertices and faces to the mesh: normals from the patch's faces,
/// colours the mean of the loop vertices' colours.
void append_patch(Mesh& m, const Patch& s, const std::vector<Loop>& filled) {
    const std::size_t nv0 = s.first_new, nv = s.p.size();
    std::vector<Vec3f>& verts = m.vertices.edit();
    verts.resize(nv);
    for (std::size_t v = nv0; v < nv; ++v) {
        verts[v] = {float(s.p[v][0]), float(s.p[v][1]), float(s.p[v][2])};
    }
    std::vector<Triangle>& faces = m.faces.edit();
    faces.insert(faces.end(), s.tris.begin(), s.tris.end());
    if (!m.normals.empty()) {
        const std::vector<std::array<double, 3>> sum = detail::face_normal_sums(m);
        std::vector<Vec3f>& normals = m.normals.edit();
        normals.resize(nv);
        for (std::size_t v = nv0; v < nv; ++v) {
            V3 n(sum[v][0], sum[v][1], sum[v][2]);
            n = n.norm() > 0.0 ? V3(n.normalized()) : V3(0, 0, 1);
            normals[v] = {float(n[0]), float(n[1]), float(n[2])};
        }
    }
    if (!m.colors.empty()) {
        std::vector<Vec3f>& colors = m.colors.edit();
        double rgb[3] = {0.0, 0.0, 0.0};
        std::size_t count = 0;
        for (const Loop& l : filled) {
            for (std::int32_t v : l.v) {
                for (int c = 0; c < 3; ++c) rgb[c] += colors[std::size_t(v)][c];
                ++count;
            }
        }
        const Vec3f mean{float(rgb[0] / double(std::max<std::size_t>(count, 1))),
                         float(rgb[1] / double(std::max<std::size_t>(count, 1))),
                         float(rgb[2] / double(std::max<std::size_t>(count, 1)))};
        colors.resize(nv, mean);
    }
}

}  // namespace

HoleFillResult fill_holes(const Mesh& mesh, const HoleFillOptions& options) {
    options.validate();
    HoleFillResult r;
    r.mesh = mesh;
    const std::vector<Triangle> faces = mesh.faces.to_vector();
    const DirectedEdges mesh_edges(faces);
    const std::vector<Loop> loops = boundary_loops(faces, mesh_edges);
    r.loops = loops.size();
    if (loops.empty()) return r;

    Patch s;
    s.p.reserve(mesh.vertices.size());
    for (const Vec3f& v : mesh.vertices) s.p.emplace_back(v[0], v[1], v[2]);
    s.first_new = s.p.size();
    s.sigma = mean_edge_lengths(s.p, faces);
    std::vector<Loop> filled;
    for (const Loop& loop : loops) {
        if (options.max_edges > 0 && loop.v.size() > options.max_edges) {
            r.largest_open = std::max(r.largest_open, loop.v.size());
            continue;
        }
        triangulate_loop(loop, s, mesh_edges);
        r.largest_filled = std::max(r.largest_filled, loop.v.size());
        filled.push_back(loop);
    }
    r.filled = filled.size();
    if (s.tris.empty()) return r;
    if (options.refine) refine(s, mesh_edges);
    if (options.fair) fair(s, faces);
    r.added_faces = s.tris.size();
    r.added_vertices = s.p.size() - s.first_new;
    append_patch(r.mesh, s, filled);
    return r;
}

}  // namespace vdbrecon
