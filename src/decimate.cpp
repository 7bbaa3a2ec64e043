// Quadric error metric decimation (see decimate.h).
#include "vdbrecon/decimate.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <queue>
#include <sstream>
#include <vector>

#include "detail/mesh_graph.h"
#include "detail/vec3.h"
#include "vdbrecon/error.h"

namespace vdbrecon {

void DecimateOptions::validate() const {
    if (!(ratio > 0.0 && ratio <= 1.0)) {
        throw InvalidArgument("decimate.ratio = " + std::to_string(ratio) + ": must be in (0, 1]");
    }
    if (!(std::isfinite(max_error) && max_error >= 0.0)) {
        throw InvalidArgument("decimate.max_error must be a non-negative number (0 = no limit)");
    }
    if (ratio == 1.0 && max_error == 0.0) {
        throw InvalidArgument("decimate: give a ratio below 1 or a max_error");
    }
    if (!(std::isfinite(border_weight) && border_weight >= 0.0)) {
        throw InvalidArgument("decimate.border_weight must be a non-negative number");
    }
    if (!(max_normal_turn > 0.0 && max_normal_turn <= 180.0)) {
        throw InvalidArgument("decimate.max_normal_turn must be in (0, 180] degrees");
    }
}

namespace {

using detail::V3;
using detail::cross;
using detail::dot;
using detail::sub;

/// A symmetric 4x4 quadric: sum of w (n.x + d)^2 over planes (n, d), and the sum of the
/// weights, so that Q(x) / w is the weighted mean squared distance to the planes.
struct Quadric {
    double a2 = 0, ab = 0, ac = 0, ad = 0, b2 = 0, bc = 0, bd = 0, c2 = 0, cd = 0, d2 = 0;
    double w = 0;

    void add_plane(const V3& n, double d, double w) {
        a2 += w * n[0] * n[0]; ab += w * n[0] * n[1]; ac += w * n[0] * n[2]; ad += w * n[0] * d;
        b2 += w * n[1] * n[1]; bc += w * n[1] * n[2]; bd += w * n[1] * d;
        c2 += w * n[2] * n[2]; cd += w * n[2] * d;
        d2 += w * d * d;
        this->w += w;
    }
    Quadric& operator+=(const Quadric& q) {
        a2 += q.a2; ab += q.ab; ac += q.ac; ad += q.ad; b2 += q.b2;
        bc += q.bc; bd += q.bd; c2 += q.c2; cd += q.cd; d2 += q.d2;
        w += q.w;
        return *this;
    }
    double operator()(const V3& v) const {
        const double x = v[0], y = v[1], z = v[2];
        return a2 * x * x + 2 * ab * x * y + 2 * ac * x * z + 2 * ad * x + b2 * y * y +
               2 * bc * y * z + 2 * bd * y + c2 * z * z + 2 * cd * z + d2;
    }
    /// A v + b: half the gradient of Q at v.
    V3 gradient(const V3& v) const {
        return {a2 * v[0] + ab * v[1] + ac * v[2] + ad, ab * v[0] + b2 * v[1] + bc * v[2] + bd,
                ac * v[0] + bc * v[1] + c2 * v[2] + cd};
    }
    /// d^T A d: Q's curvature along d.
    double along(const V3& d) const {
        return a2 * d[0] * d[0] + 2 * ab * d[0] * d[1] + 2 * ac * d[0] * d[2] + b2 * d[1] * d[1] +
               2 * bc * d[1] * d[2] + c2 * d[2] * d[2];
    }
    /// The point minimising the quadric, when its 3x3 part is well conditioned.
    bool minimum(V3& v) const {
        const double det = a2 * (b2 * c2 - bc * bc) - ab * (ab * c2 - bc * ac) + ac * (ab * bc - b2 * ac);
        const double scale = a2 * b2 * c2 + 1e-300;
        if (!(std::fabs(det) > 1e-10 * std::fabs(scale)) || !std::isfinite(det)) return false;
        // Cramer's rule on A v = -(ad, bd, cd).
        const double r0 = -ad, r1 = -bd, r2 = -cd;
        v[0] = (r0 * (b2 * c2 - bc * bc) - ab * (r1 * c2 - bc * r2) + ac * (r1 * bc - b2 * r2)) / det;
        v[1] = (a2 * (r1 * c2 - bc * r2) - r0 * (ab * c2 - bc * ac) + ac * (ab * r2 - r1 * ac)) / det;
        v[2] = (a2 * (b2 * r2 - r1 * bc) - ab * (ab * r2 - r1 * ac) + r0 * (ab * bc - b2 * ac)) / det;
        return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
    }
};

/// A key of a collapse's place: a hash of the bits of its target and of its edge's midpoint
/// (several edges of a vertex can have it as their target). Equal keys for two collapses are as
/// good as impossible; they would fall back to the vertex numbers.
inline std::uint64_t place_key(const V3& target, const V3& mid) {
    std::uint64_t h = 0x9e3779b97f4a7c15ull;
    for (const V3* p : {&target, &mid}) {
        for (double x : *p) {
            std::uint64_t bits;
            std::memcpy(&bits, &x, sizeof bits);
            h ^= bits + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
            h *= 0xff51afd7ed558ccdull;
            h ^= h >> 33;
        }
    }
    return h;
}

struct Candidate {
    double cost;                // Q(target): the heap's order (Garland and Heckbert's)
    double error;               // sqrt(Q(target) / weights): a distance, world units
    std::int32_t a, b;          // a before b by position (Decimator::before)
    std::uint32_t va, vb;       // the vertices' versions when it was made
    V3 target;
    std::uint64_t place;        // place_key(target, the edge's midpoint)
    // Ties go by where the collapse is, not by vertex numbers: a mesh numbered otherwise (a
    // tiled run's) collapses the same edges in the same order.
    bool operator>(const Candidate& o) const {
        if (cost != o.cost) return cost > o.cost;
        if (place != o.place) return place > o.place;
        return a != o.a ? a > o.a : b > o.b;
    }
};

class Decimator {
  public:
    Decimator(const Mesh& m, const DecimateOptions& o) : o_(o) {
        const std::size_t nv = m.vertices.size();
        p_.resize(nv);
        for (std::size_t i = 0; i < nv; ++i) {
            for (int k = 0; k < 3; ++k) p_[i][std::size_t(k)] = double(m.vertices[i][std::size_t(k)]);
        }
        if (m.colors.size() == nv) {
            colors_.assign(m.colors.begin(), m.colors.end());
        }
        faces_.assign(m.faces.begin(), m.faces.end());
        alive_face_.assign(faces_.size(), 1);
        around_.resize(nv);
        for (std::size_t f = 0; f < faces_.size(); ++f) {
            for (std::int32_t v : faces_[f]) around_[std::size_t(v)].push_back(std::int32_t(f));
        }
        version_.assign(nv, 0);
        border_.assign(nv, 0);
        q_.resize(nv);
        cos_turn_ = std::cos(o.max_normal_turn * M_PI / 180.0);
        build_quadrics();
    }

    DecimateResult run(std::size_t target, double max_error) {
        DecimateResult r;
        r.faces_before = faces_.size();
        std::size_t alive = faces_.size();
        for (const detail::EdgeUse& e : detail::undirected_edges(faces_)) push(e.a, e.b);
        const double limit = max_error > 0.0 ? max_error : HUGE_VAL;
        while (alive > target && !heap_.empty()) {
            const Candidate c = heap_.top();
            heap_.pop();
            if (version_[std::size_t(c.a)] != c.va || version_[std::size_t(c.b)] != c.vb) continue;
            if (c.error > limit) continue;  // never made; cheaper ones may still come
            const int removed = collapse(c);
            if (removed < 0) {
                ++r.refused;
                continue;
            }
            alive -= std::size_t(removed);
            ++r.collapses;
            r.max_error = std::max(r.max_error, c.error);
        }
        r.faces_after = alive;
        return r;
    }

    Mesh result(const Mesh& in) const {
        Mesh m;
        m.origin = in.origin;
        std::vector<Triangle> faces;
        std::vector<std::int32_t> regions;  // the faces' planar regions, when the mesh has them
        const bool with_regions = in.regions.size() == faces_.size() && !faces_.empty();
        for (std::size_t f = 0; f < faces_.size(); ++f) {
            if (!alive_face_[f]) continue;
            faces.push_back(faces_[f]);
            if (with_regions) regions.push_back(in.regions[f]);
        }
        std::size_t used = 0;
        const std::vector<std::int32_t> map = detail::compact_vertices(faces, p_.size(), &used);
        std::vector<Vec3f> v(used), c;
        if (!colors_.empty()) c.resize(used);
        for (std::size_t i = 0; i < p_.size(); ++i) {
            if (map[i] < 0) continue;
            v[std::size_t(map[i])] = {float(p_[i][0]), float(p_[i][1]), float(p_[i][2])};
            if (!colors_.empty()) c[std::size_t(map[i])] = colors_[i];
        }
        m.vertices = std::move(v);
        m.faces = std::move(faces);
        if (with_regions) m.regions = std::move(regions);
        if (!c.empty()) m.colors = std::move(c);
        if (!in.normals.empty()) {
            std::vector<Vec3f> n;
            for (const auto& s : detail::face_normal_sums(m)) {
                const double l = std::sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
                n.push_back(l > 0 ? Vec3f{float(s[0] / l), float(s[1] / l), float(s[2] / l)}
                                  : Vec3f{0, 0, 0});
            }
            m.normals = std::move(n);
        }
        return m;
    }

  private:
    /// Face planes (area-weighted) and, along the open border, planes through each border edge
    /// perpendicular to its face. Each vertex sums its faces' planes in the order of the faces'
    /// centroids (not their numbers), so that the sums do not depend on how the mesh is
    /// numbered.
    void build_quadrics() {
        const std::vector<std::uint64_t> border = detail::border_edge_keys(faces_);
        // Per face its plane (unit normal, offset, weight = area; weight 0 when degenerate) and
        // the sum of its corners, the key its vertices order it by.
        struct FacePlane {
            V3 n, centre;
            double d, w;
        };
        std::vector<FacePlane> plane(faces_.size());
        for (std::size_t f = 0; f < faces_.size(); ++f) {
            const Triangle& t = faces_[f];
            const V3 &p0 = p_[std::size_t(t[0])], &p1 = p_[std::size_t(t[1])],
                     &p2 = p_[std::size_t(t[2])];
            FacePlane& fp = plane[f];
            for (int k = 0; k < 3; ++k) {
                fp.centre[std::size_t(k)] =
                    p0[std::size_t(k)] + p1[std::size_t(k)] + p2[std::size_t(k)];
            }
            const V3 n2 = cross(sub(p1, p0), sub(p2, p0));
            const double l = std::sqrt(dot(n2, n2));
            fp.w = l > 0.0 ? 0.5 * l : 0.0;
            fp.n = l > 0.0 ? V3{n2[0] / l, n2[1] / l, n2[2] / l} : V3{0.0, 0.0, 0.0};
            fp.d = -dot(fp.n, p0);
        }
        std::vector<std::int32_t> faces;
        for (std::size_t v = 0; v < p_.size(); ++v) {
            faces = around_[v];
            std::sort(faces.begin(), faces.end(), [&](std::int32_t f, std::int32_t g) {
                const V3 &cf = plane[std::size_t(f)].centre, &cg = plane[std::size_t(g)].centre;
                return cf != cg ? cf < cg : f < g;
            });
            for (std::int32_t f : faces) {
                const FacePlane& fp = plane[std::size_t(f)];
                if (fp.w > 0.0) q_[v].add_plane(fp.n, fp.d, fp.w);
                add_border_quadrics(std::int32_t(v), faces_[std::size_t(f)], border);
            }
        }
    }

    /// Adds to v's quadric the border planes of face t's edges at v.
    void add_border_quadrics(std::int32_t v, const Triangle& t,
                             const std::vector<std::uint64_t>& border) {
        for (int k = 0; k < 3; ++k) {
            const std::int32_t a = t[std::size_t(k)], b = t[std::size_t((k + 1) % 3)];
            if (a != v && b != v) continue;
            if (!std::binary_search(border.begin(), border.end(), detail::edge_key(a, b))) continue;
            border_[std::size_t(v)] = 1;
            const V3 e = sub(p_[std::size_t(b)], p_[std::size_t(a)]);
            const V3 fn = cross(e, sub(p_[std::size_t(t[std::size_t((k + 2) % 3)])], p_[std::size_t(a)]));
            V3 m = cross(e, fn);
            const double lm = std::sqrt(dot(m, m));
            if (!(lm > 0.0)) continue;
            m = {m[0] / lm, m[1] / lm, m[2] / lm};
            q_[std::size_t(v)].add_plane(m, -dot(m, p_[std::size_t(a)]), o_.border_weight * dot(e, e));
        }
    }

    /// Whether vertex i comes before j by position (by number only where they coincide).
    bool before(std::int32_t i, std::int32_t j) const {
        const V3& pi = p_[std::size_t(i)];
        const V3& pj = p_[std::size_t(j)];
        return pi != pj ? pi < pj : i < j;
    }

    void push(std::int32_t a, std::int32_t b) {
        if (before(b, a)) std::swap(a, b);
        Quadric q = q_[std::size_t(a)];
        q += q_[std::size_t(b)];
        Candidate c{0.0, 0.0, a, b, version_[std::size_t(a)], version_[std::size_t(b)], {}, 0};
        const V3& pa = p_[std::size_t(a)];
        const V3& pb = p_[std::size_t(b)];
        const V3 d = sub(pb, pa);
        const V3 mid = {pa[0] + 0.5 * d[0], pa[1] + 0.5 * d[1], pa[2] + 0.5 * d[2]};

        // Placement::free: the optimum, unless the quadric is (nearly) singular and it slides
        // away along a flat region (farther from the edge's midpoint than the edge is long).
        // Otherwise the best point of the edge, Q(a + t d) being a parabola in t.
        const bool optimum = o_.placement == Placement::free && q.minimum(c.target) &&
                             dot(sub(c.target, mid), sub(c.target, mid)) <= dot(d, d);
        if (!optimum) {
            const V3 g = q.gradient(pa);
            const double curv = q.along(d);
            const double t = curv > 0.0 ? std::clamp(-dot(g, d) / curv, 0.0, 1.0) : 0.5;
            c.target = {pa[0] + t * d[0], pa[1] + t * d[1], pa[2] + t * d[2]};
        }
        c.cost = q(c.target);
        c.place = place_key(c.target, mid);
        c.error = std::sqrt(std::max(0.0, c.cost) / std::max(q.w, 1e-300));
        heap_.push(c);
    }

    /// The vertices sharing a face with v.
    std::vector<std::int32_t> neighbours(std::int32_t v) const {
        std::vector<std::int32_t> n;
        for (std::int32_t f : around_[std::size_t(v)]) {
            for (std::int32_t w : faces_[std::size_t(f)]) {
                if (w != v) n.push_back(w);
            }
        }
        std::sort(n.begin(), n.end());
        n.erase(std::unique(n.begin(), n.end()), n.end());
        return n;
    }

    /// Collapses b into a at c.target; returns the faces removed, or -1 when refused.
    int collapse(const Candidate& c) {
        std::int32_t a = c.a, b = c.b;
        // The faces on the edge, and their third vertices.
        std::vector<std::int32_t> shared, opposite;
        for (std::int32_t f : around_[std::size_t(a)]) {
            const Triangle& t = faces_[std::size_t(f)];
            if (t[0] == b || t[1] == b || t[2] == b) {
                shared.push_back(f);
                for (std::int32_t w : t) {
                    if (w != a && w != b) opposite.push_back(w);
                }
            }
        }
        if (shared.empty() || shared.size() > 2) return -1;
        // An interior edge between two border vertices would pinch the border.
        if (shared.size() == 2 && border_[std::size_t(a)] && border_[std::size_t(b)]) return -1;
        // Link condition: the common neighbours are exactly the opposite vertices.
        const std::vector<std::int32_t> na = neighbours(a), nb = neighbours(b);
        std::vector<std::int32_t> common;
        std::set_intersection(na.begin(), na.end(), nb.begin(), nb.end(), std::back_inserter(common));
        std::sort(opposite.begin(), opposite.end());
        if (common != opposite) return -1;
        // A closed piece must keep at least a tetrahedron.
        if (shared.size() == 2 && na.size() + nb.size() <= 6) return -1;
        // No face may flip or degenerate.
        for (std::int32_t v : {a, b}) {
            for (std::int32_t f : around_[std::size_t(v)]) {
                if (std::find(shared.begin(), shared.end(), f) != shared.end()) continue;
                const Triangle& t = faces_[std::size_t(f)];
                V3 before[3], after[3];
                for (int k = 0; k < 3; ++k) {
                    before[k] = p_[std::size_t(t[std::size_t(k)])];
                    after[k] = t[std::size_t(k)] == v ? c.target : before[k];
                }
                const V3 n0 = cross(sub(before[1], before[0]), sub(before[2], before[0]));
                const V3 n1 = cross(sub(after[1], after[0]), sub(after[2], after[0]));
                const double l0 = std::sqrt(dot(n0, n0)), l1 = std::sqrt(dot(n1, n1));
                if (!(l1 > 1e-12 * (l0 + 1e-300))) return -1;
                if (l0 > 0.0 && dot(n0, n1) < cos_turn_ * l0 * l1) return -1;
            }
        }
        // Collapse: b's faces move to a; the shared faces go.
        const V3 pa = p_[std::size_t(a)], pb = p_[std::size_t(b)];
        if (!colors_.empty()) {
            const V3 e = sub(pb, pa);
            const double ee = dot(e, e);
            const double t = ee > 0.0 ? std::clamp(dot(sub(c.target, pa), e) / ee, 0.0, 1.0) : 0.5;
            Vec3f& ca = colors_[std::size_t(a)];
            const Vec3f& cb = colors_[std::size_t(b)];
            for (int k = 0; k < 3; ++k) {
                ca[std::size_t(k)] = float((1.0 - t) * ca[std::size_t(k)] + t * cb[std::size_t(k)]);
            }
        }
        p_[std::size_t(a)] = c.target;
        q_[std::size_t(a)] += q_[std::size_t(b)];
        border_[std::size_t(a)] = border_[std::size_t(a)] || border_[std::size_t(b)];
        // The shared faces go, also from the lists of their third vertices (a dead face left
        // there made later collapses at those vertices see a third face on an edge, or
        // neighbours that are not, and refuse).
        for (std::int32_t f : shared) {
            alive_face_[std::size_t(f)] = 0;
            for (std::int32_t w : faces_[std::size_t(f)]) {
                if (w == a || w == b) continue;
                auto& list = around_[std::size_t(w)];
                list.erase(std::remove(list.begin(), list.end(), f), list.end());
            }
        }
        std::vector<std::int32_t> merged;
        for (std::int32_t f : around_[std::size_t(a)]) {
            if (alive_face_[std::size_t(f)]) merged.push_back(f);
        }
        for (std::int32_t f : around_[std::size_t(b)]) {
            if (!alive_face_[std::size_t(f)]) continue;
            for (std::int32_t& w : faces_[std::size_t(f)]) {
                if (w == b) w = a;
            }
            merged.push_back(f);
        }
        std::sort(merged.begin(), merged.end());
        around_[std::size_t(a)] = std::move(merged);
        around_[std::size_t(b)].clear();
        ++version_[std::size_t(a)];
        version_[std::size_t(b)] = ~0u;  // never valid again
        for (std::int32_t n : neighbours(a)) push(a, n);
        return int(shared.size());
    }

    const DecimateOptions& o_;
    std::vector<V3> p_;
    std::vector<Vec3f> colors_;
    std::vector<Triangle> faces_;
    std::vector<char> alive_face_, border_;
    std::vector<std::vector<std::int32_t>> around_;
    std::vector<std::uint32_t> version_;
    std::vector<Quadric> q_;
    double cos_turn_ = 0.5;
    std::priority_queue<Candidate, std::vector<Candidate>, std::greater<Candidate>> heap_;
};

}  // namespace

DecimateResult decimate(const Mesh& mesh, const DecimateOptions& options) {
    options.validate();
    const std::size_t target =
        std::size_t(std::ceil(options.ratio * double(mesh.faces.size())));
    Decimator d(mesh, options);
    DecimateResult r = d.run(options.ratio < 1.0 ? target : 0, options.max_error);
    r.mesh = d.result(mesh);
    return r;
}

}  // namespace vdbrecon
