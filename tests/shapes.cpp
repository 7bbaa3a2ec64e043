// Closed test shapes (see shapes.h).
//
// Every CAD part is a stack of prisms along z over planar regions (a loop, or a ring between two
// loops star-shaped about one centre), or a loft between a loop and a scaled copy of it; the caps
// are fans from the centre and rings are zipped by angle, so every face is planar and the mesh is
// closed by construction (vertices welded by exact coordinates). Circles are 192-gons: the chord
// error of a radius-0.2 circle is 3e-5, under 1 % of the finest voxel the tests use.
#include "shapes.h"

#include "vdbrecon/eval.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <stdexcept>

namespace vdbrecon::test {
namespace {

using P2 = std::array<double, 2>;
using Loop = std::vector<P2>;  // counter-clockwise seen from +z
using P3 = std::array<double, 3>;

/// Builds a mesh from positions, welding equal coordinates into one vertex.
class Builder {
  public:
    int vertex(const P3& p) {
        auto it = index_.find(p);
        if (it != index_.end()) return it->second;
        const int i = int(points_.size());
        points_.push_back(p);
        index_.emplace(p, i);
        return i;
    }
    void triangle(const P3& a, const P3& b, const P3& c) {
        faces_.push_back({vertex(a), vertex(b), vertex(c)});
    }
    /// Quad a b c d, counter-clockwise seen from outside.
    void quad(const P3& a, const P3& b, const P3& c, const P3& d) {
        triangle(a, b, c);
        triangle(a, c, d);
    }
    Mesh mesh() const {
        Mesh m;
        std::vector<Vec3f>& v = m.vertices.edit();
        for (const P3& p : points_) v.push_back({float(p[0]), float(p[1]), float(p[2])});
        m.faces = faces_;
        return m;
    }
    std::vector<P3>& points() { return points_; }

  private:
    std::vector<P3> points_;
    std::map<P3, int> index_;
    std::vector<Triangle> faces_;
};

P3 at(const P2& p, double z) { return {p[0], p[1], z}; }

/// A cap over a loop star-shaped about `c`: a fan, facing +z when `up`.
void fan(Builder& b, const Loop& loop, const P2& c, double z, bool up) {
    const std::size_t n = loop.size();
    for (std::size_t i = 0; i < n; ++i) {
        const P3 p = at(loop[i], z), q = at(loop[(i + 1) % n], z), m = at(c, z);
        if (up) {
            b.triangle(m, p, q);
        } else {
            b.triangle(m, q, p);
        }
    }
}

/// Inserts into `a` the points where rays from `c` at the angles of `b`'s vertices cross it, and
/// the other way round, so that both loops (star-shaped about c) have vertices at the same
/// angles. Done before any face is made: walls and caps must use the same vertices.
void share_angles(Loop& a, Loop& b, const P2& c) {
    const auto angle = [&](const P2& p) { return std::atan2(p[1] - c[1], p[0] - c[0]); };
    const auto insert = [&](Loop& loop, const Loop& other) {
        Loop out;
        for (std::size_t i = 0; i < loop.size(); ++i) {
            const P2 &p = loop[i], &q = loop[(i + 1) % loop.size()];
            out.push_back(p);
            // Rays strictly inside the edge's angular range, in increasing angle.
            double a0 = angle(p), a1 = angle(q);
            if (a1 <= a0) a1 += 2.0 * M_PI;
            std::vector<double> ts;
            for (const P2& o : other) {
                double t = angle(o);
                while (t <= a0) t += 2.0 * M_PI;
                if (t < a1 - 1e-12) ts.push_back(t);
            }
            std::sort(ts.begin(), ts.end());
            for (double t : ts) {
                // p + s (q - p) on the ray c + r (cos t, sin t): solve the 2x2 system.
                const double dx = std::cos(t), dy = std::sin(t);
                const double ex = q[0] - p[0], ey = q[1] - p[1];
                const double den = ex * dy - ey * dx;
                const double sp = ((c[0] - p[0]) * dy - (c[1] - p[1]) * dx) / den;
                out.push_back({p[0] + sp * ex, p[1] + sp * ey});
            }
        }
        return out;
    };
    const Loop a2 = insert(a, b), b2 = insert(b, a);
    a = a2;
    b = b2;
}

/// The ring between an outer and an inner loop, both star-shaped about `c` and with vertices at
/// the same angles (share_angles): one quad per angular wedge. Facing +z when `up`.
void ring(Builder& b, const Loop& outer, const Loop& inner, const P2& c, double z, bool up) {
    const auto angle = [&](const P2& p) { return std::atan2(p[1] - c[1], p[0] - c[0]); };
    const auto start = [&](const Loop& l) {
        std::size_t s = 0;
        for (std::size_t i = 1; i < l.size(); ++i) {
            if (angle(l[i]) < angle(l[s])) s = i;
        }
        return s;
    };
    if (outer.size() != inner.size()) throw std::logic_error("ring: loops without shared angles");
    const std::size_t n = outer.size(), so = start(outer), si = start(inner);
    for (std::size_t k = 0; k < n; ++k) {
        const P3 o0 = at(outer[(so + k) % n], z), o1 = at(outer[(so + k + 1) % n], z);
        const P3 i0 = at(inner[(si + k) % n], z), i1 = at(inner[(si + k + 1) % n], z);
        if (up) {
            b.quad(o0, o1, i1, i0);
        } else {
            b.quad(o0, i0, i1, o1);
        }
    }
}

/// Walls of a loop between z0 and z1: facing out of the loop, or into it (a hole) when `hole`.
void walls(Builder& b, const Loop& loop, double z0, double z1, bool hole) {
    const std::size_t n = loop.size();
    for (std::size_t i = 0; i < n; ++i) {
        const P2 &p = loop[i], &q = loop[(i + 1) % n];
        if (hole) {
            b.quad(at(q, z0), at(p, z0), at(p, z1), at(q, z1));
        } else {
            b.quad(at(p, z0), at(q, z0), at(q, z1), at(p, z1));
        }
    }
}

Loop rectangle(double x0, double y0, double x1, double y1) {
    return {{x0, y0}, {x1, y0}, {x1, y1}, {x0, y1}};
}

Loop circle(double cx, double cy, double r, int n = 192) {
    Loop l;
    for (int i = 0; i < n; ++i) {
        const double t = 2.0 * M_PI * i / n;
        l.push_back({cx + r * std::cos(t), cy + r * std::sin(t)});
    }
    return l;
}

/// A prism over a loop star-shaped about c.
void prism(Builder& b, const Loop& loop, const P2& c, double z0, double z1) {
    walls(b, loop, z0, z1, false);
    fan(b, loop, c, z0, false);
    fan(b, loop, c, z1, true);
}

/// A rotation from a seed (uniform random unit quaternion) and a small offset, so that no face,
/// edge or centre lines up with the grid.
void place(std::vector<P3>& points, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> g;
    double q[4] = {g(rng), g(rng), g(rng), g(rng)};
    const double len = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (double& v : q) v /= len;
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    const double R[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
                            {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
                            {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}};
    const P3 offset = {0.0123, -0.0217, 0.0071};
    for (P3& p : points) {
        P3 r{};
        for (int a = 0; a < 3; ++a) {
            r[a] = offset[a] + R[a][0] * p[0] + R[a][1] * p[1] + R[a][2] * p[2];
        }
        p = r;
    }
}

Mesh cube() {
    Builder b;
    prism(b, rectangle(-0.4, -0.4, 0.4, 0.4), {0.0, 0.0}, -0.4, 0.4);
    place(b.points(), 11);
    return b.mesh();
}

Mesh lbracket() {
    Builder b;
    const Loop l = {{-0.4, -0.4}, {0.4, -0.4}, {0.4, -0.15}, {-0.15, -0.15}, {-0.15, 0.4}, {-0.4, 0.4}};
    prism(b, l, {-0.3, -0.3}, -0.3, 0.3);
    place(b.points(), 12);
    return b.mesh();
}

Mesh cross() {
    Builder b;
    const double w = 0.15, a = 0.45;
    const Loop l = {{w, -w}, {a, -w}, {a, w}, {w, w}, {w, a}, {-w, a}, {-w, w}, {-a, w},
                    {-a, -w}, {-w, -w}, {-w, -a}, {w, -a}};
    prism(b, l, {0.0, 0.0}, -0.2, 0.2);
    place(b.points(), 13);
    return b.mesh();
}

/// A house: a prism over a gabled profile (walls, a roof of two planes meeting at the ridge,
/// two pentagonal gable ends, a floor: seven planes).
Mesh house() {
    Builder b;
    const Loop l = {{-0.4, -0.3}, {0.4, -0.3}, {0.4, 0.1}, {0.0, 0.4}, {-0.4, 0.1}};
    prism(b, l, {0.0, 0.0}, -0.35, 0.35);
    place(b.points(), 15);
    return b.mesh();
}

/// A fan-shaped ruled part: a six-bladed star loft whose top is the bottom scaled by 0.75, so
/// its sides are planar trapezoids slanted at different angles.
Mesh fan_part() {
    Builder b;
    Loop bottom, top;
    for (int k = 0; k < 12; ++k) {
        const double t = 2.0 * M_PI * k / 12.0, r = k % 2 ? 0.2 : 0.45;
        bottom.push_back({r * std::cos(t), r * std::sin(t)});
        top.push_back({0.75 * bottom.back()[0], 0.75 * bottom.back()[1]});
    }
    const double z0 = -0.2, z1 = 0.2;
    for (std::size_t i = 0; i < 12; ++i) {
        const std::size_t j = (i + 1) % 12;
        b.quad(at(bottom[i], z0), at(bottom[j], z0), at(top[j], z1), at(top[i], z1));
    }
    fan(b, bottom, {0.0, 0.0}, z0, false);
    fan(b, top, {0.0, 0.0}, z1, true);
    place(b.points(), 14);
    return b.mesh();
}

/// A block with a cylindrical hole through it (box minus cylinder).
Mesh drilled() {
    Builder b;
    Loop outer = rectangle(-0.4, -0.4, 0.4, 0.4), hole = circle(0.03, -0.02, 0.18);
    const P2 c = {0.03, -0.02};
    share_angles(outer, hole, c);
    const double z0 = -0.25, z1 = 0.25;
    walls(b, outer, z0, z1, false);
    walls(b, hole, z0, z1, true);
    ring(b, outer, hole, c, z0, false);
    ring(b, outer, hole, c, z1, true);
    place(b.points(), 15);
    return b.mesh();
}

/// A block with a cylindrical boss on top (box union cylinder).
Mesh boss() {
    Builder b;
    Loop base = rectangle(-0.4, -0.4, 0.4, 0.4), top = circle(0.02, 0.01, 0.22);
    const P2 c = {0.02, 0.01};
    share_angles(base, top, c);
    walls(b, base, -0.3, 0.0, false);
    fan(b, base, c, -0.3, false);
    ring(b, base, top, c, 0.0, true);
    walls(b, top, 0.0, 0.3, false);
    fan(b, top, c, 0.3, true);
    place(b.points(), 16);
    return b.mesh();
}

/// A block with a rectangular blind pocket (box minus box).
Mesh pocket() {
    Builder b;
    Loop outer = rectangle(-0.4, -0.4, 0.4, 0.4), hole = rectangle(-0.2, -0.15, 0.25, 0.2);
    const P2 c = {0.025, 0.025};
    share_angles(outer, hole, c);
    const double z0 = -0.3, zf = -0.05, z1 = 0.3;
    walls(b, outer, z0, z1, false);
    fan(b, outer, c, z0, false);
    ring(b, outer, hole, c, z1, true);
    walls(b, hole, zf, z1, true);
    fan(b, hole, c, zf, true);
    place(b.points(), 17);
    return b.mesh();
}

/// An icosphere subdivided `levels` times, its vertices moved to radius r(unit direction).
template <typename Radius>
Mesh star_sphere(int levels, Radius radius) {
    const double t = (1.0 + std::sqrt(5.0)) / 2.0;
    std::vector<P3> v = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                         {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
    std::vector<std::array<int, 3>> f = {
        {0, 11, 5}, {0, 5, 1}, {0, 1, 7}, {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
        {11, 10, 2}, {10, 7, 6}, {7, 1, 8}, {3, 9, 4}, {3, 4, 2}, {3, 2, 6}, {3, 6, 8},
        {3, 8, 9}, {4, 9, 5}, {2, 4, 11}, {6, 2, 10}, {8, 6, 7}, {9, 8, 1}};
    const auto unit = [](P3 p) {
        const double l = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
        return P3{p[0] / l, p[1] / l, p[2] / l};
    };
    for (P3& p : v) p = unit(p);
    for (int level = 0; level < levels; ++level) {
        std::map<std::pair<int, int>, int> mid;
        const auto middle = [&](int a, int b) {
            const auto key = std::make_pair(std::min(a, b), std::max(a, b));
            auto it = mid.find(key);
            if (it != mid.end()) return it->second;
            v.push_back(unit({v[a][0] + v[b][0], v[a][1] + v[b][1], v[a][2] + v[b][2]}));
            mid.emplace(key, int(v.size()) - 1);
            return int(v.size()) - 1;
        };
        std::vector<std::array<int, 3>> g;
        for (const auto& tri : f) {
            const int a = middle(tri[0], tri[1]), b = middle(tri[1], tri[2]),
                      c = middle(tri[2], tri[0]);
            g.push_back({tri[0], a, c});
            g.push_back({tri[1], b, a});
            g.push_back({tri[2], c, b});
            g.push_back({a, b, c});
        }
        f = std::move(g);
    }
    for (P3& p : v) {
        const double r = radius(p);
        p = {r * p[0], r * p[1], r * p[2]};
    }
    place(v, 21);
    Mesh m;
    for (const P3& p : v) m.vertices.push_back({float(p[0]), float(p[1]), float(p[2])});
    for (const auto& tri : f) m.faces.push_back({tri[0], tri[1], tri[2]});
    return m;
}

Mesh torus() {
    const int nu = 384, nv = 160;
    const double R = 0.35, r = 0.14;
    std::vector<P3> v;
    for (int i = 0; i < nu; ++i) {
        const double u = 2.0 * M_PI * i / nu;
        for (int j = 0; j < nv; ++j) {
            const double w = 2.0 * M_PI * j / nv;
            v.push_back({(R + r * std::cos(w)) * std::cos(u), (R + r * std::cos(w)) * std::sin(u),
                         r * std::sin(w)});
        }
    }
    place(v, 22);
    Mesh m;
    for (const P3& p : v) m.vertices.push_back({float(p[0]), float(p[1]), float(p[2])});
    const auto id = [&](int i, int j) { return std::int32_t(((i + nu) % nu) * nv + (j + nv) % nv); };
    for (int i = 0; i < nu; ++i) {
        for (int j = 0; j < nv; ++j) {
            m.faces.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1)});
            m.faces.push_back({id(i, j), id(i + 1, j + 1), id(i, j + 1)});
        }
    }
    return m;
}

double mesh_area(const Mesh& m) {
    double a = 0.0;
    for (const Triangle& t : m.faces) {
        const Vec3f &p = m.vertices[std::size_t(t[0])], &q = m.vertices[std::size_t(t[1])],
                    &r = m.vertices[std::size_t(t[2])];
        const double u[3] = {q[0] - p[0], q[1] - p[1], q[2] - p[2]};
        const double w[3] = {r[0] - p[0], r[1] - p[1], r[2] - p[2]};
        const double c[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2],
                             u[0] * w[1] - u[1] * w[0]};
        a += 0.5 * std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    }
    return a;
}

}  // namespace

std::vector<std::string> cad_shape_names() {
    return {"cube", "lbracket", "fan", "drilled", "boss", "pocket", "cross"};
}

std::vector<std::string> organic_shape_names() { return {"sphere", "torus", "blob"}; }

Shape make_shape(const std::string& name) {
    Shape s;
    s.name = name;
    s.cad = true;
    if (name == "cube") {
        s.mesh = cube();
    } else if (name == "lbracket") {
        s.mesh = lbracket();
    } else if (name == "fan") {
        s.mesh = fan_part();
    } else if (name == "drilled") {
        s.mesh = drilled();
    } else if (name == "boss") {
        s.mesh = boss();
    } else if (name == "pocket") {
        s.mesh = pocket();
    } else if (name == "cross") {
        s.mesh = cross();
    } else if (name == "house") {
        s.mesh = house();
    } else if (name == "sphere") {
        s.cad = false;
        s.mesh = star_sphere(6, [](const P3&) { return 0.45; });
    } else if (name == "torus") {
        s.cad = false;
        s.mesh = torus();
    } else if (name == "blob") {
        s.cad = false;
        s.mesh = star_sphere(6, [](const P3& u) {
            return 0.4 * (1.0 + 0.12 * std::sin(3.0 * u[0] + 0.5) * std::cos(2.0 * u[1]) +
                          0.08 * std::sin(4.0 * u[2] + 1.0));
        });
    } else {
        throw std::invalid_argument("unknown test shape '" + name + "'");
    }
    s.area = mesh_area(s.mesh);
    return s;
}

double spacing_of(double area, std::size_t n) { return std::sqrt(area / double(n)); }

PointCloud sample_uniform(const Mesh& mesh, std::size_t n, std::uint64_t seed) {
    std::vector<double> cumulative;
    std::vector<Vec3f> normal;
    double total = 0.0;
    for (const Triangle& t : mesh.faces) {
        const Vec3f &p = mesh.vertices[std::size_t(t[0])], &q = mesh.vertices[std::size_t(t[1])],
                    &r = mesh.vertices[std::size_t(t[2])];
        const double u[3] = {double(q[0]) - p[0], double(q[1]) - p[1], double(q[2]) - p[2]};
        const double w[3] = {double(r[0]) - p[0], double(r[1]) - p[1], double(r[2]) - p[2]};
        const double c[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2],
                             u[0] * w[1] - u[1] * w[0]};
        const double len = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
        total += 0.5 * len;
        cumulative.push_back(total);
        normal.push_back(len > 0 ? Vec3f{float(c[0] / len), float(c[1] / len), float(c[2] / len)}
                                 : Vec3f{0.0f, 0.0f, 0.0f});
    }
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    PointCloud cloud;
    std::vector<Vec3f>& pos = cloud.positions.edit();
    std::vector<Vec3f>& nor = cloud.normals.edit();
    pos.reserve(n);
    nor.reserve(n);
    for (std::size_t i = 0; i < n; ++i) {
        const double pick = uni(rng) * total;
        const std::size_t f = std::size_t(
            std::upper_bound(cumulative.begin(), cumulative.end(), pick) - cumulative.begin());
        const Triangle& t = mesh.faces[std::min(f, cumulative.size() - 1)];
        double a = uni(rng), b = uni(rng);
        if (a + b > 1.0) {
            a = 1.0 - a;
            b = 1.0 - b;
        }
        const Vec3f &p = mesh.vertices[std::size_t(t[0])], &q = mesh.vertices[std::size_t(t[1])],
                    &r = mesh.vertices[std::size_t(t[2])];
        Vec3f x;
        for (int k = 0; k < 3; ++k) x[k] = float(p[k] + a * (double(q[k]) - p[k]) + b * (double(r[k]) - p[k]));
        pos.push_back(x);
        nor.push_back(normal[std::min(f, normal.size() - 1)]);
    }
    return cloud;
}

Features sharp_features(const Mesh& mesh, double angle_degrees) {
    std::map<std::pair<int, int>, std::vector<std::size_t>> edge_faces;
    std::vector<std::array<double, 3>> fn(mesh.faces.size());
    for (std::size_t i = 0; i < mesh.faces.size(); ++i) {
        const Triangle& t = mesh.faces[i];
        const Vec3f &p = mesh.vertices[std::size_t(t[0])], &q = mesh.vertices[std::size_t(t[1])],
                    &r = mesh.vertices[std::size_t(t[2])];
        const double u[3] = {double(q[0]) - p[0], double(q[1]) - p[1], double(q[2]) - p[2]};
        const double w[3] = {double(r[0]) - p[0], double(r[1]) - p[1], double(r[2]) - p[2]};
        double c[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2],
                       u[0] * w[1] - u[1] * w[0]};
        const double len = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
        fn[i] = {c[0] / len, c[1] / len, c[2] / len};
        for (int k = 0; k < 3; ++k) {
            const int a = t[k], b = t[(k + 1) % 3];
            edge_faces[{std::min(a, b), std::max(a, b)}].push_back(i);
        }
    }
    const double cos_max = std::cos(angle_degrees * M_PI / 180.0);
    Features f;
    std::map<int, int> sharp_count;
    for (const auto& [e, faces] : edge_faces) {
        if (faces.size() != 2) continue;
        const auto &a = fn[faces[0]], &b = fn[faces[1]];
        if (a[0] * b[0] + a[1] * b[1] + a[2] * b[2] > cos_max) continue;
        f.edges.push_back({mesh.vertices[std::size_t(e.first)], mesh.vertices[std::size_t(e.second)]});
        ++sharp_count[e.first];
        ++sharp_count[e.second];
    }
    for (const auto& [v, count] : sharp_count) {
        if (count >= 3) f.corners.push_back(mesh.vertices[std::size_t(v)]);
    }
    return f;
}

std::vector<Vec3f> points_on_edges(const Features& f, double step) {
    std::vector<Vec3f> out;
    for (const auto& e : f.edges) {
        const double d[3] = {double(e[1][0]) - e[0][0], double(e[1][1]) - e[0][1],
                             double(e[1][2]) - e[0][2]};
        const double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        const int n = std::max(1, int(std::ceil(len / step)));
        for (int k = 0; k <= n; ++k) {
            const double t = double(k) / n;
            out.push_back({float(e[0][0] + t * d[0]), float(e[0][1] + t * d[1]),
                           float(e[0][2] + t * d[2])});
        }
    }
    return out;
}

Deviation deviation(const Shape& shape, const Mesh& mesh, double voxel) {
    Deviation out;
    for (double d : MeshDistance(shape.mesh).distances(mesh.vertices.to_vector())) {
        out.vertex = std::max(out.vertex, d / voxel);
    }
    if (!shape.cad) return out;
    const Features f = sharp_features(shape.mesh);
    for (double d : MeshDistance(mesh).distances(points_on_edges(f, 0.25 * voxel))) {
        out.edge = std::max(out.edge, d / voxel);
    }
    for (const Vec3f& c : f.corners) {
        double best = 1e30;
        for (const Vec3f& v : mesh.vertices) {
            const double dx = double(v[0]) - c[0], dy = double(v[1]) - c[1],
                         dz = double(v[2]) - c[2];
            best = std::min(best, dx * dx + dy * dy + dz * dz);
        }
        out.corner = std::max(out.corner, std::sqrt(best) / voxel);
    }
    return out;
}

PointCloud sample_thin_walled_block(double wall, std::size_t n, std::uint64_t seed,
                                    double* area) {
    struct Ball {
        double c[3], r;
    };
    // A: opens through -x. B: opens through +y and meets A. C: closed inside, `wall` below the
    // +z face and `wall` from A.
    const Ball A{{-0.45, -0.05, 0.05}, 0.3}, B{{-0.1, 0.35, 0.0}, 0.28};
    const double rc = 0.2, zc = 0.5 - wall - rc;
    const double dz = zc - A.c[2], dy = -0.15 - A.c[1];
    const double dx = std::sqrt((A.r + rc + wall) * (A.r + rc + wall) - dy * dy - dz * dz);
    const Ball C{{A.c[0] + dx, -0.15, zc}, rc};
    const Ball balls[3] = {A, B, C};
    const auto inside_ball = [&](const double p[3], int skip) {
        for (int k = 0; k < 3; ++k) {
            if (k == skip) continue;
            const double d[3] = {p[0] - balls[k].c[0], p[1] - balls[k].c[1], p[2] - balls[k].c[2]};
            if (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < balls[k].r * balls[k].r) return true;
        }
        return false;
    };
    // Candidates proportional to the primitives' whole areas, kept where they are on the
    // final surface.
    double prim_area[4] = {6.0, 0, 0, 0};
    for (int k = 0; k < 3; ++k) prim_area[k + 1] = 4.0 * M_PI * balls[k].r * balls[k].r;
    const double total = prim_area[0] + prim_area[1] + prim_area[2] + prim_area[3];
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    std::normal_distribution<double> gauss;
    PointCloud cloud;
    std::size_t tried = 0;
    while (cloud.size() < n) {
        ++tried;
        double pick = uni(rng) * total;
        int prim = 0;
        while (prim < 3 && pick >= prim_area[prim]) pick -= prim_area[prim++];
        double p[3], nrm[3];
        if (prim == 0) {
            const int face = std::min(5, int(uni(rng) * 6.0));
            const int axis = face / 2;
            const double side = face % 2 ? 0.5 : -0.5;
            for (int a = 0; a < 3; ++a) {
                p[a] = a == axis ? side : uni(rng) - 0.5;
                nrm[a] = a == axis ? (side > 0 ? 1.0 : -1.0) : 0.0;
            }
            if (inside_ball(p, -1)) continue;
        } else {
            const Ball& b = balls[prim - 1];
            double d[3] = {gauss(rng), gauss(rng), gauss(rng)};
            const double l = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            for (int a = 0; a < 3; ++a) {
                d[a] /= l;
                p[a] = b.c[a] + b.r * d[a];
                nrm[a] = -d[a];  // the solid is outside the cavity
            }
            if (std::max({std::fabs(p[0]), std::fabs(p[1]), std::fabs(p[2])}) >= 0.5) continue;
            if (inside_ball(p, prim - 1)) continue;
        }
        cloud.positions.push_back({float(p[0]), float(p[1]), float(p[2])});
        cloud.normals.push_back({float(nrm[0]), float(nrm[1]), float(nrm[2])});
    }
    if (area) *area = total * double(n) / double(tried);
    return cloud;
}

std::vector<Vec3f> punch_holes(PointCloud& cloud, int count, double radius, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::vector<Vec3f> centres;
    const auto d2 = [](const Vec3f& a, const Vec3f& b) {
        return double(a[0] - b[0]) * (a[0] - b[0]) + double(a[1] - b[1]) * (a[1] - b[1]) +
               double(a[2] - b[2]) * (a[2] - b[2]);
    };
    for (int attempt = 0; attempt < 10000 && int(centres.size()) < count; ++attempt) {
        const Vec3f c = cloud.positions[std::size_t(rng() % cloud.size())];
        bool far = true;
        for (const Vec3f& o : centres) far = far && d2(c, o) >= 16.0 * radius * radius;
        if (far) centres.push_back(c);
    }
    PointCloud out;
    for (std::size_t i = 0; i < cloud.size(); ++i) {
        bool keep = true;
        for (const Vec3f& c : centres) keep = keep && d2(cloud.positions[i], c) > radius * radius;
        if (!keep) continue;
        out.positions.push_back(cloud.positions[i]);
        if (cloud.has_normals()) out.normals.push_back(cloud.normals[i]);
    }
    cloud = std::move(out);
    return centres;
}

}  // namespace vdbrecon::test
