// Quadric error metric decimation (see decimate.h).
#include "vdbrecon/decimate.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <queue>
#include <sstream>
#include <memory>
#include <vector>

#include <tbb/parallel_for.h>

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
    if (!(std::isfinite(region_error) && region_error >= 0.0)) {
        throw InvalidArgument("decimate.region_error must be a non-negative number (0 = max_error)");
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
    /// Adds s q (weights included).
    void add_scaled(const Quadric& q, double s) {
        a2 += s * q.a2; ab += s * q.ab; ac += s * q.ac; ad += s * q.ad; b2 += s * q.b2;
        bc += s * q.bc; bd += s * q.bd; c2 += s * q.c2; cd += s * q.cd; d2 += s * q.d2;
        w += s * q.w;
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

/// The unit normal of the plane through the edge (a, b) perpendicular to the triangle (a, b, c):
/// the plane an open border or a region's outline keeps its vertices to. Zero where the
/// triangle is degenerate.
V3 across_edge(const V3& a, const V3& b, const V3& c) {
    const V3 e = sub(b, a);
    const V3 m = cross(e, cross(e, sub(c, a)));
    const double l = std::sqrt(dot(m, m));
    return l > 0.0 ? V3{m[0] / l, m[1] / l, m[2] / l} : V3{0.0, 0.0, 0.0};
}

class Decimator {
  public:
    /// `locked`: per vertex, whether it must stay (no collapse touches it); null: none.
    Decimator(const Mesh& m, const DecimateOptions& o, const std::vector<char>* locked = nullptr)
        : o_(o) {
        const std::size_t nv = m.vertices.size();
        if (locked) locked_ = *locked;
        p_.resize(nv);
        for (std::size_t i = 0; i < nv; ++i) {
            for (int k = 0; k < 3; ++k) p_[i][std::size_t(k)] = double(m.vertices[i][std::size_t(k)]);
        }
        if (m.colors.size() == nv) {
            colors_.assign(m.colors.begin(), m.colors.end());
        }
        faces_.assign(m.faces.begin(), m.faces.end());
        if (m.regions.size() == faces_.size() && !faces_.empty()) {
            regions_.assign(m.regions.begin(), m.regions.end());
        }
        alive_face_.assign(faces_.size(), 1);
        around_.resize(nv);
        for (std::size_t f = 0; f < faces_.size(); ++f) {
            for (std::int32_t v : faces_[f]) around_[std::size_t(v)].push_back(std::int32_t(f));
        }
        version_.assign(nv, 0);
        border_.assign(nv, 0);
        faces_q_.resize(nv);
        border_q_.resize(nv);
        cos_turn_ = std::cos(o.max_normal_turn * M_PI / 180.0);
        build_quadrics(outline_edges());
    }

    /// Collapses the cheapest edges while more than `target` faces are alive. With a
    /// max_error, passes over the edges left repeat while one makes a collapse: whether a
    /// collapse stays within the bounds depends on the faces around its vertices, which later
    /// collapses around them change (the heap only hears of those at the collapsed vertex).
    DecimateResult run(std::size_t target, double max_error) {
        DecimateResult r;
        r.faces_before = faces_.size();
        std::size_t alive = faces_.size();
        limit_ = max_error > 0.0 ? max_error : HUGE_VAL;
        for (int pass = 0; pass < 8; ++pass) {
            std::vector<Triangle> live;
            for (std::size_t f = 0; f < faces_.size(); ++f) {
                if (alive_face_[f]) live.push_back(faces_[f]);
            }
            for (const detail::EdgeUse& e : detail::undirected_edges(live)) push(e.a, e.b);
            const std::size_t before = r.collapses;
            collapse_cheapest(target, alive, r);
            if (max_error == 0.0 || alive <= target || r.collapses == before) break;
        }
        r.faces_after = alive;
        return r;
    }

    void collapse_cheapest(std::size_t target, std::size_t& alive, DecimateResult& r) {
        const bool bounded = limit_ < HUGE_VAL;
        while (alive > target && !heap_.empty()) {
            Candidate c = heap_.top();
            heap_.pop();
            if (version_[std::size_t(c.a)] != c.va || version_[std::size_t(c.b)] != c.vb) continue;
            if (bounded && !local_move_within(c) && !onto_endpoint(c)) continue;
            const int removed = collapse(c);
            if (removed < 0) {
                ++r.refused;
                continue;
            }
            alive -= std::size_t(removed);
            ++r.collapses;
            r.max_error = std::max(r.max_error, c.error);
        }
    }

    /// Writes this decimator's vertices (numbered by `global` in `whole`) into `whole` and
    /// appends its faces left, numbered so, to `faces`.
    void write_back(const std::vector<std::int32_t>& global, Mesh& whole,
                    std::vector<Triangle>& faces) const {
        std::vector<Vec3f>& v = whole.vertices.edit();
        for (std::size_t i = 0; i < p_.size(); ++i) {
            if (!locked_.empty() && locked_[i]) continue;
            v[std::size_t(global[i])] = position(i);
            if (!colors_.empty()) whole.colors.edit()[std::size_t(global[i])] = colors_[i];
        }
        for (std::size_t f = 0; f < faces_.size(); ++f) {
            if (!alive_face_[f]) continue;
            const Triangle& t = faces_[f];
            faces.push_back({global[std::size_t(t[0])], global[std::size_t(t[1])],
                             global[std::size_t(t[2])]});
        }
    }

    /// The mesh left, in `in`'s frame, with vertex normals when `in` has them.
    Mesh result(const Mesh& in) const {
        Mesh m;
        m.origin = in.origin;
        std::vector<Triangle> faces;
        std::vector<std::int32_t> regions;  // the faces' planar regions, when the mesh has them
        for (std::size_t f = 0; f < faces_.size(); ++f) {
            if (!alive_face_[f]) continue;
            faces.push_back(faces_[f]);
            if (!regions_.empty()) regions.push_back(regions_[f]);
        }
        std::size_t used = 0;
        const std::vector<std::int32_t> map = detail::compact_vertices(faces, p_.size(), &used);
        std::vector<Vec3f> v(used), c;
        if (!colors_.empty()) c.resize(used);
        for (std::size_t i = 0; i < p_.size(); ++i) {
            if (map[i] < 0) continue;
            v[std::size_t(map[i])] = position(i);
            if (!colors_.empty()) c[std::size_t(map[i])] = colors_[i];
        }
        m.vertices = std::move(v);
        m.faces = std::move(faces);
        if (!regions_.empty()) m.regions = std::move(regions);
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
    Vec3f position(std::size_t i) const {
        return {float(p_[i][0]), float(p_[i][1]), float(p_[i][2])};
    }

    /// The keys of the edges between two planar regions or a region and the rest (when the
    /// mesh has regions, planes.h), sorted: a region's outline and its creases. They get border
    /// planes like the open border, so that the outline moves by no more than the bound (its
    /// straight stretches still collapse) and the rest cannot eat into a region where it is
    /// nearly coplanar with it; but they are no border (a region may come to touch itself).
    std::vector<std::uint64_t> outline_edges() const {
        std::vector<std::uint64_t> keys;
        if (regions_.empty()) return keys;
        const auto sides = detail::sorted_sides(faces_, [](std::size_t) { return true; });
        detail::manifold_pairs(sides, [&](const detail::EdgeSide& x, const detail::EdgeSide& y) {
            if (regions_[std::size_t(x.face)] != regions_[std::size_t(y.face)]) {
                keys.push_back(x.key);
            }
        });
        std::sort(keys.begin(), keys.end());
        return keys;
    }

    /// A face's plane n.x + d = 0 (unit normal; weight w = area, 0 when degenerate) and the sum
    /// of its corners, the key its vertices order it by.
    struct FacePlane {
        V3 n, centre;
        double d, w;
    };

    /// Each planar region's plane: its faces' area-weighted mean normal and offset (the faces
    /// lie in it; a sliver's own plane is noise), summed in the order of the faces' centroids.
    void region_planes(const std::vector<FacePlane>& plane) {
        std::vector<std::int32_t> order;
        std::int32_t count = 0;
        for (std::size_t f = 0; f < faces_.size(); ++f) {
            if (regions_[f] < 0) continue;
            order.push_back(std::int32_t(f));
            count = std::max(count, regions_[f] + 1);
        }
        std::sort(order.begin(), order.end(), [&](std::int32_t f, std::int32_t g) {
            const std::int32_t rf = regions_[std::size_t(f)], rg = regions_[std::size_t(g)];
            const V3 &cf = plane[std::size_t(f)].centre, &cg = plane[std::size_t(g)].centre;
            return rf != rg ? rf < rg : (cf != cg ? cf < cg : f < g);
        });
        std::vector<V3> normal(std::size_t(count), V3{0.0, 0.0, 0.0});
        for (const std::int32_t f : order) {
            const FacePlane& fp = plane[std::size_t(f)];
            V3& n = normal[std::size_t(regions_[std::size_t(f)])];
            for (int k = 0; k < 3; ++k) n[std::size_t(k)] += fp.w * fp.n[std::size_t(k)];
        }
        region_plane_.assign(std::size_t(count), {V3{0.0, 0.0, 0.0}, 0.0});
        std::vector<double> area(std::size_t(count), 0.0);
        for (std::size_t r = 0; r < normal.size(); ++r) {
            const double l = std::sqrt(dot(normal[r], normal[r]));
            if (l > 0.0) region_plane_[r].first = {normal[r][0] / l, normal[r][1] / l, normal[r][2] / l};
        }
        for (const std::int32_t f : order) {
            const FacePlane& fp = plane[std::size_t(f)];
            const std::size_t r = std::size_t(regions_[std::size_t(f)]);
            region_plane_[r].second -= fp.w * dot(region_plane_[r].first, fp.centre) / 3.0;
            area[r] += fp.w;
        }
        for (std::size_t r = 0; r < area.size(); ++r) {
            if (area[r] > 0.0) region_plane_[r].second /= area[r];
        }
    }

    /// Face planes (area-weighted) and, along the open border, planes through each border edge
    /// perpendicular to its face (weighted by the edge's squared length; border_weight applies
    /// in push). Each vertex sums its faces' planes in the order of the faces' centroids (not
    /// their numbers), so that the sums do not depend on how the mesh is numbered.
    void build_quadrics(const std::vector<std::uint64_t>& outline) {
        const std::vector<std::uint64_t> border = detail::border_edge_keys(faces_);
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
        if (!regions_.empty()) region_planes(plane);
        std::vector<std::int32_t> faces;
        for (std::size_t v = 0; v < p_.size(); ++v) {
            faces = around_[v];
            std::sort(faces.begin(), faces.end(), [&](std::int32_t f, std::int32_t g) {
                const V3 &cf = plane[std::size_t(f)].centre, &cg = plane[std::size_t(g)].centre;
                return cf != cg ? cf < cg : f < g;
            });
            for (std::int32_t f : faces) {
                const FacePlane& fp = plane[std::size_t(f)];
                if (fp.w > 0.0) faces_q_[v].add_plane(fp.n, fp.d, fp.w);
                add_border_quadrics(std::int32_t(v), faces_[std::size_t(f)], border, outline);
            }
        }
    }

    /// Adds to v's quadric the border planes of face t's edges at v.
    void add_border_quadrics(std::int32_t v, const Triangle& t,
                             const std::vector<std::uint64_t>& border,
                             const std::vector<std::uint64_t>& outline) {
        for (int k = 0; k < 3; ++k) {
            const std::int32_t a = t[std::size_t(k)], b = t[std::size_t((k + 1) % 3)];
            if (a != v && b != v) continue;
            const std::uint64_t key = detail::edge_key(a, b);
            if (std::binary_search(border.begin(), border.end(), key)) {
                border_[std::size_t(v)] = 1;
            } else if (!std::binary_search(outline.begin(), outline.end(), key)) {
                continue;
            }
            const V3 &pa = p_[std::size_t(a)], &pb = p_[std::size_t(b)];
            const V3 m = across_edge(pa, pb, p_[std::size_t(t[std::size_t((k + 2) % 3)])]);
            if (m == V3{0.0, 0.0, 0.0}) continue;
            const V3 e = sub(pb, pa);
            border_q_[std::size_t(v)].add_plane(m, -dot(m, pa), dot(e, e));
        }
    }

    static Quadric sum(const std::vector<Quadric>& q, std::int32_t a, std::int32_t b) {
        Quadric s = q[std::size_t(a)];
        s += q[std::size_t(b)];
        return s;
    }

    /// The root mean square distance of x to q's planes (0 without planes).
    static double rms(const Quadric& q, const V3& x) {
        return q.w > 0.0 ? std::sqrt(std::max(0.0, q(x)) / q.w) : 0.0;
    }

    /// A collapse's error at x: the larger of the root mean square distances to the faces'
    /// planes and to the border's (see candidate()).
    static double error(const Quadric& faces, const Quadric& border, const V3& x) {
        return std::max(rms(faces, x), rms(border, x));
    }

    /// Whether vertex i comes before j by position (by number only where they coincide).
    bool before(std::int32_t i, std::int32_t j) const {
        const V3& pi = p_[std::size_t(i)];
        const V3& pj = p_[std::size_t(j)];
        return pi != pj ? pi < pj : i < j;
    }

    void push(std::int32_t a, std::int32_t b) {
        if (!locked_.empty() && (locked_[std::size_t(a)] || locked_[std::size_t(b)])) return;
        const Candidate c = candidate(a, b);
        if (c.error <= limit_) heap_.push(c);  // never made otherwise; cheaper ones may come
    }

    /// The collapse of the edge (a, b): its target, cost and error.
    Candidate candidate(std::int32_t a, std::int32_t b) const {
        if (before(b, a)) std::swap(a, b);
        // The order of collapses goes by q: the faces' planes plus the border's weighted by
        // border_weight. The error is the larger of two root mean square distances: to the
        // faces' planes (area-weighted) and to the border's (each counted by its edge's squared
        // length). Mixing the two in one mean let the border sag far beyond max_error: the
        // border_weight in the divisor made a border vertex's mean ~1000x smaller, and the
        // merged faces' area dilutes the few border planes.
        const Quadric faces = sum(faces_q_, a, b), border = sum(border_q_, a, b);
        Quadric q = faces;
        q.add_scaled(border, o_.border_weight);
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
        c.error = error(faces, border, c.target);
        return c;
    }

    /// c moved to one of its two vertices (a first) when its own target is not within the
    /// bounds there: where one vertex lies on a crease or a region's outline and the other
    /// beside it, the quadrics' best point of the edge leaves the crease, the vertex does not.
    bool onto_endpoint(Candidate& c) const {
        const Quadric faces = sum(faces_q_, c.a, c.b), border = sum(border_q_, c.a, c.b);
        for (const std::int32_t v : {c.a, c.b}) {
            Candidate e = c;
            e.target = p_[std::size_t(v)];
            e.error = error(faces, border, e.target);
            if (e.error <= limit_ && local_move_within(e)) {
                c = e;
                return true;
            }
        }
        return false;
    }

    /// Whether c's target lies within the bound (limit_) of the planes through the open border's and the
    /// regions' outline edges at its two vertices (each perpendicular to its face), and within
    /// region_error of the planes of the region faces around them (or as far as their corners
    /// already are). The quadrics' root mean squares are means over every plane a vertex
    /// stands for, and a few planes far off (the third face at a region's corner, the other
    /// side of an outline's corner) vanish in them. Only with a max_error.
    bool local_move_within(const Candidate& c) const {
        const double on_region = o_.region_error > 0.0 ? o_.region_error : limit_;
        std::vector<std::pair<std::int32_t, std::int32_t>> sides;  // (far vertex, face)
        for (const std::int32_t v : {c.a, c.b}) {
            sides.clear();
            for (const std::int32_t f : around_[std::size_t(v)]) {
                const Triangle& t = faces_[std::size_t(f)];
                if (!regions_.empty() && regions_[std::size_t(f)] >= 0) {
                    // Off the region's plane by no more than the face's corners are already
                    // (a vertex the planes stage could not put onto every plane around it).
                    const auto& [rn, rd] = region_plane_[std::size_t(regions_[std::size_t(f)])];
                    double allowed = on_region;
                    for (const std::int32_t w : t) {
                        allowed = std::max(allowed, std::fabs(dot(rn, p_[std::size_t(w)]) + rd));
                    }
                    if (std::fabs(dot(rn, c.target) + rd) > allowed) return false;
                }
                for (const std::int32_t w : t) {
                    if (w != v) sides.push_back({w, f});
                }
            }
            // The edges at v one face has (open border) or two faces of two regions have
            // (outline): c's target within the bound of the plane through the edge perpendicular
            // to each such face.
            std::sort(sides.begin(), sides.end());
            for (std::size_t i = 0; i < sides.size();) {
                std::size_t j = i + 1;
                while (j < sides.size() && sides[j].first == sides[i].first) ++j;
                const bool kept = j - i == 1 ||
                                  (j - i == 2 && !regions_.empty() &&
                                   regions_[std::size_t(sides[i].second)] !=
                                       regions_[std::size_t(sides[i + 1].second)]);
                for (; kept && i < j; ++i) {
                    if (off_edge(v, sides[i].first, sides[i].second, c.target) > limit_) return false;
                }
                i = j;
            }
        }
        return true;
    }

    /// The distance of x from the plane through the edge (v, w) perpendicular to face f.
    double off_edge(std::int32_t v, std::int32_t w, std::int32_t f, const V3& x) const {
        std::int32_t u = v;  // f's third corner
        for (const std::int32_t k : faces_[std::size_t(f)]) {
            if (k != v && k != w) u = k;
        }
        const V3& pv = p_[std::size_t(v)];
        return std::fabs(dot(across_edge(pv, p_[std::size_t(w)], p_[std::size_t(u)]), sub(x, pv)));
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

    /// Why c may not collapse (0: it may): 1 the edge has no face or more than two, 2 it would
    /// pinch the border, 3 the link condition, 4 it would leave less than a tetrahedron or no
    /// face of an open piece, 5 a face
    /// would flip or degenerate. `shared` receives the edge's faces.
    int refusal(const Candidate& c, std::vector<std::int32_t>& shared) const {
        const std::int32_t a = c.a, b = c.b;
        // The faces on the edge, and their third vertices.
        std::vector<std::int32_t> opposite;
        shared.clear();
        for (std::int32_t f : around_[std::size_t(a)]) {
            const Triangle& t = faces_[std::size_t(f)];
            if (t[0] == b || t[1] == b || t[2] == b) {
                shared.push_back(f);
                for (std::int32_t w : t) {
                    if (w != a && w != b) opposite.push_back(w);
                }
            }
        }
        if (shared.empty() || shared.size() > 2) return 1;
        // An interior edge between two border vertices would pinch the border.
        if (shared.size() == 2 && border_[std::size_t(a)] && border_[std::size_t(b)]) return 2;
        // Link condition: the common neighbours are exactly the opposite vertices.
        const std::vector<std::int32_t> na = neighbours(a), nb = neighbours(b);
        std::vector<std::int32_t> common;
        std::set_intersection(na.begin(), na.end(), nb.begin(), nb.end(), std::back_inserter(common));
        std::sort(opposite.begin(), opposite.end());
        if (common != opposite) return 3;
        // A closed piece must keep at least a tetrahedron, an open one a face: no collapse
        // removes every face around a and b (a lone triangle, a two-face strip's last pair).
        if (shared.size() == 2 && na.size() + nb.size() <= 6) return 4;
        if (around_[std::size_t(a)].size() + around_[std::size_t(b)].size() ==
            2 * shared.size()) {
            return 4;
        }
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
                if (!(l1 > 1e-12 * (l0 + 1e-300))) return 5;
                if (l0 > 0.0 && dot(n0, n1) < cos_turn_ * l0 * l1) return 5;
            }
        }
        return 0;
    }

    /// Collapses b into a at c.target; returns the faces removed, or -1 when refused.
    int collapse(const Candidate& c) {
        std::vector<std::int32_t> shared;
        if (refusal(c, shared) != 0) return -1;
        const std::int32_t a = c.a, b = c.b;
        // b's faces move to a; the shared faces go.
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
        faces_q_[std::size_t(a)] += faces_q_[std::size_t(b)];
        border_q_[std::size_t(a)] += border_q_[std::size_t(b)];
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
    std::vector<std::int32_t> regions_;  // per face, when the mesh has planar regions
    std::vector<std::pair<V3, double>> region_plane_;  // per region: n.x + d = 0
    std::vector<char> alive_face_, border_, locked_;
    std::vector<std::vector<std::int32_t>> around_;
    std::vector<std::uint32_t> version_;
    std::vector<Quadric> faces_q_, border_q_;  // per vertex: its faces' planes, its border's
    double cos_turn_ = 0.5;
    double limit_ = HUGE_VAL;  // run()'s max_error, or no limit
    std::priority_queue<Candidate, std::vector<Candidate>, std::greater<Candidate>> heap_;
};

/// The slabs of a large mesh for decimate_in_slabs: `count` runs of faces of equal length
/// along the bounding box's longest axis, by the faces' centroids (not their numbers).
std::vector<std::int32_t> slab_of_faces(const Mesh& mesh, std::size_t count) {
    const std::size_t nf = mesh.faces.size();
    std::vector<std::array<double, 3>> centre(nf);
    std::array<double, 3> lo{HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi{-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
    for (std::size_t f = 0; f < nf; ++f) {
        for (int k = 0; k < 3; ++k) {
            double c = 0.0;
            for (const std::int32_t v : mesh.faces[f]) c += double(mesh.vertices[std::size_t(v)][std::size_t(k)]);
            centre[f][std::size_t(k)] = c;
            lo[std::size_t(k)] = std::min(lo[std::size_t(k)], c);
            hi[std::size_t(k)] = std::max(hi[std::size_t(k)], c);
        }
    }
    int axis = 0;
    for (int k = 1; k < 3; ++k) {
        if (hi[std::size_t(k)] - lo[std::size_t(k)] > hi[std::size_t(axis)] - lo[std::size_t(axis)]) axis = k;
    }
    std::vector<std::int32_t> order(nf);
    for (std::size_t f = 0; f < nf; ++f) order[f] = std::int32_t(f);
    std::sort(order.begin(), order.end(), [&](std::int32_t f, std::int32_t g) {
        const auto &cf = centre[std::size_t(f)], &cg = centre[std::size_t(g)];
        if (cf[std::size_t(axis)] != cg[std::size_t(axis)]) return cf[std::size_t(axis)] < cg[std::size_t(axis)];
        return cf != cg ? cf < cg : f < g;
    });
    std::vector<std::int32_t> slab(nf);
    for (std::size_t i = 0; i < nf; ++i) slab[std::size_t(order[i])] = std::int32_t(i * count / nf);
    return slab;
}

/// Ratio-only decimation of a large mesh, in parallel: the slabs (slab_of_faces; their number
/// follows the mesh's size, not the threads, so the result does not depend on them) are
/// decimated each, the vertices two slabs share locked, until the faces off the seam are down
/// to the ratio; then the whole mesh once more to the target, seams included (its quadrics
/// made anew from the slabs' result).
DecimateResult decimate_in_slabs(const Mesh& mesh, const DecimateOptions& options,
                                 std::size_t target, std::size_t count) {
    const std::vector<std::int32_t> slab = slab_of_faces(mesh, count);
    const std::size_t nv = mesh.vertices.size();
    std::vector<std::int32_t> first(nv, -1);
    std::vector<char> shared(nv, 0);
    for (std::size_t f = 0; f < mesh.faces.size(); ++f) {
        for (const std::int32_t v : mesh.faces[f]) {
            std::int32_t& s = first[std::size_t(v)];
            if (s < 0) s = slab[f];
            else if (s != slab[f]) shared[std::size_t(v)] = 1;
        }
    }
    struct Part {
        Mesh mesh;
        std::vector<std::int32_t> global;  // the part's vertex -> the mesh's
        std::vector<char> locked;
        std::size_t seam = 0;  // faces with a locked vertex
        std::unique_ptr<Decimator> d;
        DecimateResult r;
    };
    std::vector<std::vector<Triangle>> faces_of(count);
    for (std::size_t f = 0; f < mesh.faces.size(); ++f) faces_of[std::size_t(slab[f])].push_back(mesh.faces[f]);
    std::vector<Part> parts(count);
    for (std::size_t s = 0; s < count; ++s) {
        Part& p = parts[s];
        std::vector<Triangle>& faces = faces_of[s];
        for (const Triangle& t : faces) {
            p.seam += shared[std::size_t(t[0])] || shared[std::size_t(t[1])] || shared[std::size_t(t[2])];
        }
        std::size_t used = 0;
        const std::vector<std::int32_t> map = detail::compact_vertices(faces, nv, &used);
        p.global.resize(used);
        std::vector<Vec3f> v(used), c(mesh.colors.size() == nv ? used : 0);
        p.locked.resize(used);
        for (std::size_t g = 0; g < nv; ++g) {
            if (map[g] < 0) continue;
            const std::size_t i = std::size_t(map[g]);
            p.global[i] = std::int32_t(g);
            p.locked[i] = shared[g];
            v[i] = mesh.vertices[g];
            if (!c.empty()) c[i] = mesh.colors[g];
        }
        p.mesh.vertices = std::move(v);
        p.mesh.colors = std::move(c);
        p.mesh.faces = std::move(faces);
    }
    tbb::parallel_for(std::size_t(0), count, [&](std::size_t s) {
        Part& p = parts[s];
        p.d = std::make_unique<Decimator>(p.mesh, options, &p.locked);
        // The seam's faces stay for the last pass: the rest of the slab to the ratio.
        const double rest = double(p.mesh.faces.size() - p.seam);
        p.r = p.d->run(p.seam + std::size_t(std::ceil(options.ratio * rest)), 0.0);
    });
    Mesh whole;
    whole.origin = mesh.origin;
    whole.vertices = std::vector<Vec3f>(mesh.vertices.begin(), mesh.vertices.end());
    if (mesh.colors.size() == nv) whole.colors = std::vector<Vec3f>(mesh.colors.begin(), mesh.colors.end());
    std::vector<Triangle> faces;
    DecimateResult r;
    for (Part& p : parts) {
        p.d->write_back(p.global, whole, faces);
        r.collapses += p.r.collapses;
        r.refused += p.r.refused;
        r.max_error = std::max(r.max_error, p.r.max_error);
        p.d.reset();
    }
    whole.faces = std::move(faces);
    Decimator d(whole, options);
    const DecimateResult last = d.run(target, 0.0);
    r.mesh = d.result(mesh);  // in its frame, with normals when it has them
    r.faces_before = mesh.faces.size();
    r.faces_after = last.faces_after;
    r.collapses += last.collapses;
    r.refused += last.refused;
    r.max_error = std::max(r.max_error, last.max_error);
    return r;
}

}  // namespace

DecimateResult decimate(const Mesh& mesh, const DecimateOptions& options) {
    options.validate();
    const std::size_t target =
        std::size_t(std::ceil(options.ratio * double(mesh.faces.size())));
    // Ratio-only decimation of a large mesh without planar regions goes slab by slab, in
    // parallel; below ~2^17 faces (or with a max_error, whose bound the slabs' memoryless last
    // pass would not keep, or regions, whose planes are the whole region's) one pass.
    const std::size_t slabs = std::min<std::size_t>(16, mesh.faces.size() >> 16);
    if (options.ratio < 1.0 && options.max_error == 0.0 && mesh.regions.empty() && slabs >= 2) {
        return decimate_in_slabs(mesh, options, target, slabs);
    }
    Decimator d(mesh, options);
    DecimateResult r = d.run(options.ratio < 1.0 ? target : 0, options.max_error);
    r.mesh = d.result(mesh);
    return r;
}

}  // namespace vdbrecon
