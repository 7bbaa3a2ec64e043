// Generated scenes reconstructed with the default options: an airborne LiDAR tile of a city block
// (a height field with rooftops that the data does not connect to the ground, trees, birds), a
// furnished room fused from rendered depth frames, and closed objects sampled without normals.
// Each scene is checked for what a correct product must have: every roof, the ground, the
// furniture and a mug on the table present, the ground and roofs facing up, strays gone, the
// mesh on the true surface. The checks' geometry is verified on the exact surfaces first.
#include <catch2/catch.hpp>

#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <random>
#include <sstream>
#include <string>
#include <unordered_map>
#include <vector>

#include "depth_scenes.h"
#include "shapes.h"
#include "support.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/fusion.h"
#include "vdbrecon/pipeline.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

using D3 = std::array<double, 3>;

D3 add(const D3& a, const D3& b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }
D3 sub(const D3& a, const D3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
D3 mul(const D3& a, double s) { return {a[0] * s, a[1] * s, a[2] * s}; }
double dot(const D3& a, const D3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
D3 cross(const D3& a, const D3& b) {
    return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double norm(const D3& a) { return std::sqrt(dot(a, a)); }
D3 normalized(const D3& a) { return mul(a, 1.0 / norm(a)); }

/// The mesh's vertices in world coordinates (origin + vertex).
std::vector<D3> world_vertices(const Mesh& m) {
    std::vector<D3> w;
    w.reserve(m.vertices.size());
    for (const Vec3f& v : m.vertices) {
        w.push_back({m.origin[0] + double(v[0]), m.origin[1] + double(v[1]), m.origin[2] + double(v[2])});
    }
    return w;
}

/// A hash grid over points, for "is there a point in this box / within this radius" queries.
class PointGrid {
  public:
    PointGrid(const std::vector<D3>& points, double cell) : points_(points), cell_(cell) {
        for (std::size_t i = 0; i < points.size(); ++i) {
            cells_[key(index(points[i][0]), index(points[i][1]), index(points[i][2]))].push_back(
                std::uint32_t(i));
        }
    }
    /// Whether some point in the box [lo, hi] satisfies `accept`.
    template <typename F>
    bool any_in_box(const D3& lo, const D3& hi, F&& accept) const {
        for (std::int64_t i = index(lo[0]); i <= index(hi[0]); ++i) {
            for (std::int64_t j = index(lo[1]); j <= index(hi[1]); ++j) {
                for (std::int64_t k = index(lo[2]); k <= index(hi[2]); ++k) {
                    const auto it = cells_.find(key(i, j, k));
                    if (it == cells_.end()) continue;
                    for (std::uint32_t p : it->second) {
                        const D3& q = points_[p];
                        if (q[0] < lo[0] || q[0] > hi[0] || q[1] < lo[1] || q[1] > hi[1] ||
                            q[2] < lo[2] || q[2] > hi[2]) {
                            continue;
                        }
                        if (accept(q)) return true;
                    }
                }
            }
        }
        return false;
    }
    /// Whether some point lies within `r` of `q`.
    bool any_within(const D3& q, double r) const {
        return any_in_box(sub(q, {r, r, r}), add(q, {r, r, r}),
                          [&](const D3& p) { return dot(sub(p, q), sub(p, q)) <= r * r; });
    }

  private:
    std::int64_t index(double x) const { return std::int64_t(std::floor(x / cell_)); }
    static std::uint64_t key(std::int64_t i, std::int64_t j, std::int64_t k) {
        const std::int64_t o = std::int64_t(1) << 20;
        return (std::uint64_t(i + o) << 42) | (std::uint64_t(j + o) << 21) | std::uint64_t(k + o);
    }
    const std::vector<D3>& points_;
    double cell_;
    std::unordered_map<std::uint64_t, std::vector<std::uint32_t>> cells_;
};

/// Builds a mesh face by face (no welding needed by the checks; neighbours share vertices
/// within a grid patch).
struct MeshBuilder {
    Mesh mesh;
    std::int32_t vertex(const D3& p) {
        mesh.vertices.push_back({float(p[0]), float(p[1]), float(p[2])});
        return std::int32_t(mesh.vertices.size() - 1);
    }
    /// A grid patch p(s, t), s, t in [0, 1], of n x m quads; counter-clockwise seen from the
    /// side that dp/ds x dp/dt points to.
    template <typename F>
    void patch(F&& p, int n, int m) {
        const std::int32_t base = std::int32_t(mesh.vertices.size());
        for (int i = 0; i <= n; ++i) {
            for (int j = 0; j <= m; ++j) vertex(p(double(i) / n, double(j) / m));
        }
        auto at = [&](int i, int j) { return base + std::int32_t(i * (m + 1) + j); };
        for (int i = 0; i < n; ++i) {
            for (int j = 0; j < m; ++j) {
                mesh.faces.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
                mesh.faces.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
            }
        }
    }
    /// The rectangle corner + s u + t v, normal along u x v, cut into cells of at most `step`.
    void rectangle(const D3& corner, const D3& u, const D3& v, double step) {
        const int n = std::max(1, int(std::ceil(norm(u) / step)));
        const int m = std::max(1, int(std::ceil(norm(v) / step)));
        patch([&](double s, double t) { return add(corner, add(mul(u, s), mul(v, t))); }, n, m);
    }
    /// The six faces of an axis-aligned box; outward (a solid) or inward (a room seen from
    /// inside).
    void box(const D3& lo, const D3& hi, bool inward, double step) {
        const D3 e = sub(hi, lo);
        const D3 X{e[0], 0, 0}, Y{0, e[1], 0}, Z{0, 0, e[2]};
        auto face = [&](const D3& c, const D3& u, const D3& v) {  // outward = u x v
            if (inward) {
                rectangle(c, v, u, step);
            } else {
                rectangle(c, u, v, step);
            }
        };
        face(lo, Y, X);                  // bottom, -z
        face(add(lo, Z), X, Y);          // top, +z
        face(lo, X, Z);                  // front, -y
        face(add(lo, Y), Z, X);          // back, +y
        face(lo, Z, Y);                  // left, -x
        face(add(lo, X), Y, Z);          // right, +x
    }
};

/// Area-weighted shares of faces facing down (geometric normal z < 0): among the faces with
/// |n_z| > 0.5 (roughly horizontal) that `counts` accepts, and among all faces.
struct DownShare {
    double horizontal = 0.0, all = 0.0, horizontal_area = 0.0;
};
template <typename F>
DownShare down_share(const Mesh& m, const std::vector<D3>& w, F&& counts) {
    double down_h = 0.0, area_h = 0.0, down_all = 0.0, area_all = 0.0;
    for (const Triangle& t : m.faces) {
        const D3 &a = w[std::size_t(t[0])], &b = w[std::size_t(t[1])], &c = w[std::size_t(t[2])];
        const D3 n = cross(sub(b, a), sub(c, a));
        const double len = norm(n);
        if (!(len > 0.0)) continue;
        const double area = 0.5 * len, nz = n[2] / len;
        area_all += area;
        if (nz < 0.0) down_all += area;
        const D3 centroid = mul(add(a, add(b, c)), 1.0 / 3.0);
        if (std::fabs(nz) > 0.5 && counts(centroid)) {
            area_h += area;
            if (nz < 0.0) down_h += area;
        }
    }
    DownShare s;
    s.horizontal = area_h > 0.0 ? down_h / area_h : 0.0;
    s.all = area_all > 0.0 ? down_all / area_all : 0.0;
    s.horizontal_area = area_h;
    return s;
}

// ---- the city block: an airborne LiDAR tile -------------------------------------------------

double ground_height(double x, double y) { return 0.5 * std::sin(x / 15.0) + 0.3 * std::cos(y / 11.0); }

/// A box building on an axis-aligned footprint, with a flat roof at `eave` or a gable roof
/// rising from `eave` at x0 and x1 to `ridge` over the middle (ridge along y).
struct Building {
    double x0, x1, y0, y1, eave, ridge;
    bool gable() const { return ridge > eave; }
    double roof(double x, double /*y*/) const {
        if (!gable()) return eave;
        const double half = 0.5 * (x1 - x0), xm = 0.5 * (x0 + x1);
        return eave + (ridge - eave) * (1.0 - std::fabs(x - xm) / half);
    }
    bool contains(double x, double y, double margin = 0.0) const {
        return x >= x0 - margin && x <= x1 + margin && y >= y0 - margin && y <= y1 + margin;
    }
    /// Entry parameter of the ray o + t d into the solid (a convex polyhedron; its bottom well
    /// under the ground), or -1.
    double hit(const D3& o, const D3& d) const {
        std::vector<std::pair<D3, double>> planes = {  // n . p <= c
            {{-1, 0, 0}, -x0}, {{1, 0, 0}, x1}, {{0, -1, 0}, -y0}, {{0, 1, 0}, y1}, {{0, 0, -1}, 5.0}};
        if (gable()) {
            const double s = (ridge - eave) / (0.5 * (x1 - x0));
            planes.push_back({{-s, 0, 1}, eave - s * x0});
            planes.push_back({{s, 0, 1}, eave + s * x1});
        } else {
            planes.push_back({{0, 0, 1}, eave});
        }
        double tmin = 0.0, tmax = 1e30;
        for (const auto& [n, c] : planes) {
            const double den = dot(n, d), num = c - dot(n, o);
            if (den == 0.0) {
                if (num < 0.0) return -1.0;
            } else if (den < 0.0) {
                tmin = std::max(tmin, num / den);
            } else {
                tmax = std::min(tmax, num / den);
            }
        }
        return tmin <= tmax ? tmin : -1.0;
    }
};

/// A tree's canopy: an ellipsoid of semi-axes r around c.
struct Tree {
    D3 c, r;
    /// Entry and exit parameters of the ray o + t d, or false.
    bool hit(const D3& o, const D3& d, double& t0, double& t1) const {
        const D3 oo{(o[0] - c[0]) / r[0], (o[1] - c[1]) / r[1], (o[2] - c[2]) / r[2]};
        const D3 dd{d[0] / r[0], d[1] / r[1], d[2] / r[2]};
        const double a = dot(dd, dd), b = 2.0 * dot(oo, dd), cc = dot(oo, oo) - 1.0;
        const double disc = b * b - 4.0 * a * cc;
        if (disc <= 0.0) return false;
        t0 = (-b - std::sqrt(disc)) / (2.0 * a);
        t1 = (-b + std::sqrt(disc)) / (2.0 * a);
        return t0 > 0.0;
    }
    D3 lo() const { return sub(c, r); }
    D3 hi() const { return add(c, r); }
};

struct City {
    std::vector<Building> buildings;
    std::vector<Tree> trees;
    std::vector<D3> points;  ///< the samples of surfaces (ground, roofs, walls, trees)
    std::vector<D3> strays;  ///< single points and tiny clusters in the air
    std::size_t wall_points = 0, tree_points = 0;
    double extent = 110.0;
};

/// Where the ray o + t d (coming down from above) meets the ground: bisection on the height field.
double ground_hit(const D3& o, const D3& d) {
    auto f = [&](double t) {
        const D3 p = add(o, mul(d, t));
        return p[2] - ground_height(p[0], p[1]);
    };
    double a = (o[2] - 1.0) / -d[2];  // above the ground's highest point (0.8)
    const double end = (o[2] + 1.0) / -d[2];
    const double step = 0.05;
    double b = a + step;
    while (f(b) > 0.0 && b < end) {
        a = b;
        b += step;
    }
    for (int i = 0; i < 40; ++i) {
        const double m = 0.5 * (a + b);
        (f(m) > 0.0 ? a : b) = m;
    }
    return 0.5 * (a + b);
}

City make_city() {
    City city;
    // Footprints 8-25 m across, roofs 6-20 m high; the third has a gable roof (eaves 8 m, ridge
    // 12 m).
    city.buildings = {{10, 35, 10, 30, 12, 12},  {55, 70, 12, 24, 20, 20}, {15, 27, 58, 85, 8, 12},
                      {62, 70, 60, 68, 6, 6},    {75, 95, 38, 53, 15, 15}};
    // Canopies 5-8 m across, their bottoms 2-3 m above the ground; a conifer's and a shrub's
    // reach down to 0.5 m.
    auto tree = [&](double x, double y, double rxy, double rz, double bottom) {
        return Tree{{x, y, ground_height(x, y) + bottom + rz}, {rxy, rxy * 0.9, rz}};
    };
    city.trees = {tree(45, 42, 3.0, 2.5, 3.0), tree(42, 80, 2.5, 2.0, 2.0), tree(85, 80, 3.5, 4.0, 0.5),
                  tree(47, 18, 3.0, 2.5, 3.0), tree(65, 88, 2.8, 2.2, 0.5)};

    std::mt19937_64 rng(20240611);
    std::uniform_real_distribution<double> jitter(-0.3, 0.3), uni(0.0, 1.0);
    std::normal_distribution<double> range_noise(0.0, 0.03), leaf_noise(0.0, 0.15);
    const double spacing = 0.5, tilt = 15.0 * M_PI / 180.0, top = 30.0;
    const int n = int(city.extent / spacing);
    for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
            const double x = (i + 0.5 + jitter(rng)) * spacing, y = (j + 0.5 + jitter(rng)) * spacing;
            D3 d{0, 0, -1};
            if (uni(rng) < 0.05) {  // an oblique ray: 15 degrees off vertical, any azimuth
                const double az = 2.0 * M_PI * uni(rng);
                d = {std::sin(tilt) * std::cos(az), std::sin(tilt) * std::sin(az), -std::cos(tilt)};
            }
            // The ray through (x, y, 0), from z = top.
            const D3 o = sub(D3{x, y, 0.0}, mul(d, top / -d[2]));
            // Hard surfaces: the ground and the buildings' solids.
            double t_hard = ground_hit(o, d);
            bool on_building = false;
            for (const Building& b : city.buildings) {
                const double t = b.hit(o, d);
                if (t > 0.0 && t < t_hard) t_hard = t, on_building = true;
            }
            // Canopies: a first return on the canopy, up to two inside it, and (mostly) a last
            // return on what lies under it.
            double t_tree = 1e30, t_exit = 0.0;
            for (const Tree& tr : city.trees) {
                double t0, t1;
                if (tr.hit(o, d, t0, t1) && t0 < t_tree) t_tree = t0, t_exit = t1;
            }
            auto hard_return = [&] {
                const D3 p = add(o, mul(d, t_hard + range_noise(rng)));
                city.points.push_back(p);
                // On a building but below its roof (under the ridge or the eave): a wall.
                if (on_building) {
                    for (const Building& b : city.buildings) {
                        if (b.contains(p[0], p[1], 0.05) && p[2] < b.roof(p[0], p[1]) - 0.3) {
                            ++city.wall_points;
                            break;
                        }
                    }
                }
            };
            if (t_tree < t_hard) {
                auto leaf = [&](double t) {
                    const D3 p = add(o, mul(d, t));
                    city.points.push_back({p[0] + leaf_noise(rng), p[1] + leaf_noise(rng), p[2] + leaf_noise(rng)});
                    ++city.tree_points;
                };
                leaf(t_tree);
                const int inner = int(uni(rng) * 3.0);
                for (int k = 0; k < inner; ++k) leaf(t_tree + (t_exit - t_tree) * uni(rng));
                if (uni(rng) < 0.8) hard_return();
            } else {
                hard_return();
            }
        }
    }

    // Birds and noise: 10 single points and 3 clusters of 2-4, 8-40 m up, each more than 5 m
    // from any surface and from each other.
    auto far_from_everything = [&](const D3& p) {
        if (p[2] - ground_height(p[0], p[1]) < 5.5) return false;
        for (const Building& b : city.buildings) {
            if (b.contains(p[0], p[1], 5.5) && p[2] < b.ridge + 5.5) return false;
        }
        for (const Tree& t : city.trees) {
            const D3 lo = t.lo(), hi = t.hi();
            if (p[0] > lo[0] - 5.5 && p[0] < hi[0] + 5.5 && p[1] > lo[1] - 5.5 && p[1] < hi[1] + 5.5 &&
                p[2] < hi[2] + 5.5) {
                return false;
            }
        }
        for (const D3& s : city.strays) {
            if (norm(sub(s, p)) < 5.5) return false;
        }
        return true;
    };
    std::uniform_real_distribution<double> across(3.0, city.extent - 3.0), height(8.0, 40.0);
    const int sizes[] = {1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 2, 3, 4};
    for (int size : sizes) {
        D3 p;
        do {
            p = {across(rng), across(rng), height(rng)};
        } while (!far_from_everything(p));
        city.strays.push_back(p);
        for (int k = 1; k < size; ++k) {  // the cluster's others within 0.5 m
            city.strays.push_back({p[0] + 0.5 * jitter(rng), p[1] + 0.5 * jitter(rng), p[2] + 0.5 * jitter(rng)});
        }
    }
    return city;
}

/// The exact surfaces the airborne scanner sees: the ground (not under the buildings), the
/// roofs, the canopies (closed ellipsoids); no walls. Cells of about `step`.
Mesh city_surface(const City& city, double step) {
    MeshBuilder mb;
    const int n = int(std::ceil(city.extent / step));
    const double h = city.extent / n;
    for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
            const double x = (i + 0.5) * h, y = (j + 0.5) * h;
            bool under = false;
            for (const Building& b : city.buildings) under = under || b.contains(x, y);
            if (under) continue;
            mb.patch([&](double s, double t) {
                const double px = (i + s) * h, py = (j + t) * h;
                return D3{px, py, ground_height(px, py)};
            }, 1, 1);
        }
    }
    for (const Building& b : city.buildings) {
        const int nx = 2 * int(std::ceil((b.x1 - b.x0) / (2.0 * step)));  // even: a grid line on the ridge
        const int ny = int(std::ceil((b.y1 - b.y0) / step));
        mb.patch([&](double s, double t) {
            const double x = b.x0 + s * (b.x1 - b.x0), y = b.y0 + t * (b.y1 - b.y0);
            return D3{x, y, b.roof(x, y)};
        }, nx, ny);
    }
    for (const Tree& t : city.trees) {
        // (theta from the top down, phi around): d/dtheta x d/dphi points out.
        mb.patch([&](double s, double u) {
            const double th = M_PI * s, ph = 2.0 * M_PI * u;
            return D3{t.c[0] + t.r[0] * std::sin(th) * std::cos(ph), t.c[1] + t.r[1] * std::sin(th) * std::sin(ph),
                      t.c[2] + t.r[2] * std::cos(th)};
        }, 24, 48);
    }
    return mb.mesh;
}

/// What a reconstruction of the city shows, measured against the scene's known geometry.
struct CityCheck {
    std::vector<double> roof_cover;  ///< per building, share of roof probes with mesh on the roof
    std::size_t roofs_present = 0;   ///< buildings with roof_cover >= 0.8
    double ground_cover = 0.0;       ///< share of open-ground probes with mesh within a voxel
    std::size_t ground_probes = 0;
    DownShare down;                  ///< faces facing down (horizontal ones outside the trees)
    std::size_t near_strays = 0;     ///< mesh vertices within 2 m of a stray
    std::vector<std::size_t> tree_vertices;  ///< per tree, vertices inside its canopy's box
    std::size_t trees_present = 0;
    double point_cover = 0.0;        ///< share of the surfaces' samples within a voxel of a vertex
};

CityCheck check_city(const City& city, const Mesh& mesh, double voxel) {
    CityCheck c;
    const std::vector<D3> w = world_vertices(mesh);
    const PointGrid grid(w, voxel);
    // (a) roofs: probes every metre over the footprint shrunk by 2 m; a probe is covered by a
    // vertex within 1.5 voxels horizontally whose height is within a voxel of the roof there.
    for (const Building& b : city.buildings) {
        std::size_t probes = 0, covered = 0;
        for (double x = b.x0 + 2.0; x <= b.x1 - 2.0 + 1e-9; x += 1.0) {
            for (double y = b.y0 + 2.0; y <= b.y1 - 2.0 + 1e-9; y += 1.0) {
                ++probes;
                const double r = 1.5 * voxel, z = b.roof(x, y);
                const double dz = voxel + (b.ridge - b.eave) / (0.5 * (b.x1 - b.x0)) * r;
                const bool hit = grid.any_in_box({x - r, y - r, z - dz}, {x + r, y + r, z + dz}, [&](const D3& p) {
                    return (p[0] - x) * (p[0] - x) + (p[1] - y) * (p[1] - y) <= r * r &&
                           std::fabs(p[2] - b.roof(p[0], p[1])) <= voxel;
                });
                if (hit) ++covered;
            }
        }
        const double share = probes ? double(covered) / double(probes) : 0.0;
        c.roof_cover.push_back(share);
        if (share >= 0.8) ++c.roofs_present;
    }
    // (b) the ground: probes every 2 m, 3 m or more from buildings, canopies and the tile's edge.
    std::size_t covered = 0;
    for (double x = 3.0; x <= city.extent - 3.0; x += 2.0) {
        for (double y = 3.0; y <= city.extent - 3.0; y += 2.0) {
            bool open = true;
            for (const Building& b : city.buildings) open = open && !b.contains(x, y, 3.0);
            for (const Tree& t : city.trees) {
                open = open && !(x > t.lo()[0] - 3.0 && x < t.hi()[0] + 3.0 && y > t.lo()[1] - 3.0 &&
                                 y < t.hi()[1] + 3.0);
            }
            if (!open) continue;
            ++c.ground_probes;
            if (grid.any_within({x, y, ground_height(x, y)}, voxel)) ++covered;
        }
    }
    c.ground_cover = c.ground_probes ? double(covered) / double(c.ground_probes) : 0.0;
    // (c) facing up: the canopies' undersides may face down, so the horizontal faces counted
    // are those outside the trees' boxes (grown by a metre).
    c.down = down_share(mesh, w, [&](const D3& p) {
        for (const Tree& t : city.trees) {
            const D3 lo = sub(t.lo(), {1, 1, 1}), hi = add(t.hi(), {1, 1, 1});
            if (p[0] > lo[0] && p[0] < hi[0] && p[1] > lo[1] && p[1] < hi[1] && p[2] > lo[2] && p[2] < hi[2]) {
                return false;
            }
        }
        return true;
    });
    // (d) strays
    for (const D3& p : w) {
        for (const D3& s : city.strays) {
            if (norm(sub(p, s)) <= 2.0) {
                ++c.near_strays;
                break;
            }
        }
    }
    // (e) trees
    for (const Tree& t : city.trees) {
        std::size_t k = 0;
        grid.any_in_box(t.lo(), t.hi(), [&](const D3&) {
            ++k;
            return false;
        });
        c.tree_vertices.push_back(k);
        if (k > 0) ++c.trees_present;
    }
    // The samples of surfaces within a voxel of a vertex.
    std::size_t near = 0;
    for (const D3& p : city.points) {
        if (grid.any_within(p, voxel)) ++near;
    }
    c.point_cover = city.points.empty() ? 0.0 : double(near) / double(city.points.size());
    return c;
}

std::string describe(const CityCheck& c) {
    std::ostringstream s;
    s << "roof cover per building:";
    for (double r : c.roof_cover) s << " " << r;
    s << "; roofs present " << c.roofs_present << "; ground cover " << c.ground_cover << " of "
      << c.ground_probes << " probes; down-facing share: horizontal faces outside trees "
      << c.down.horizontal << " (of " << c.down.horizontal_area << " m^2), all faces " << c.down.all
      << "; vertices near strays " << c.near_strays << "; vertices per tree:";
    for (std::size_t k : c.tree_vertices) s << " " << k;
    s << "; input points within a voxel of the mesh " << c.point_cover;
    return s.str();
}

/// The assertions every correct reconstruction of the city meets.
void require_city(const City& city, const CityCheck& c) {
    INFO(describe(c));
    CHECK(c.roofs_present == city.buildings.size());             // (a)
    CHECK(c.ground_cover >= 0.9);                                // (b)
    CHECK(c.down.horizontal <= 0.05);                            // (c)
    CHECK(c.near_strays == 0);                                   // (d)
    CHECK(c.trees_present == city.trees.size());                 // (e)
    CHECK(c.point_cover >= 0.95);
}

// ---- the room: rendered RGB-D frames ---------------------------------------------------------

struct Box {
    std::string name;
    D3 lo, hi;
};

/// A probe point on a surface, with the normal of the side it is seen from.
struct Probe {
    D3 p, n;
    int owner;  ///< index of the object (or room surface) it belongs to
};

struct Room {
    Box room{"room", {0, 0, 0}, {5, 4, 2.6}};
    std::vector<Box> solids;      ///< furniture (boxes; some objects are several)
    std::vector<std::string> objects;  ///< names of the objects checked
    std::vector<int> solid_object;     ///< per solid, its object's index, -1 none checked
    std::vector<D3> key_points;        ///< per object, the centre of its best-seen face
    Mesh mesh;                    ///< the room and furniture, faces of at most 10 cm
};

Room make_room() {
    Room r;
    r.objects = {"mug", "table top", "chair", "shelf", "side table", "cup"};
    auto solid = [&](const std::string& name, const D3& lo, const D3& hi, int object) {
        r.solids.push_back({name, lo, hi});
        r.solid_object.push_back(object);
    };
    solid("table top", {1.9, 1.6, 0.72}, {3.1, 2.4, 0.76}, 1);
    for (double x : {1.95, 3.0}) {
        for (double y : {1.65, 2.3}) solid("table leg", {x, y, 0.0}, {x + 0.05, y + 0.05, 0.72}, -1);
    }
    solid("mug", {2.26, 1.92, 0.76}, {2.35, 2.01, 0.86}, 0);  // 9 x 9 x 10 cm
    solid("chair seat", {4.0, 0.6, 0.42}, {4.45, 1.05, 0.47}, 2);
    solid("chair back", {4.41, 0.6, 0.47}, {4.45, 1.05, 0.9}, 2);
    for (double x : {4.01, 4.41}) {
        for (double y : {0.61, 1.01}) solid("chair leg", {x, y, 0.0}, {x + 0.03, y + 0.03, 0.42}, -1);
    }
    solid("shelf", {0.8, 3.65, 0.0}, {1.6, 4.0, 1.8}, 3);  // against the wall y = 4
    // A small side table on one thin post with a cup: a piece of its own (the post is too
    // thin to join it to the floor) with about a fifth of one percent of the room's faces.
    solid("side table", {1.0, 0.7, 0.52}, {1.3, 1.0, 0.55}, 4);
    solid("side table post", {1.135, 0.835, 0.0}, {1.165, 0.865, 0.52}, -1);
    solid("cup", {1.18, 0.88, 0.55}, {1.25, 0.95, 0.64}, 5);  // 7 x 7 x 9 cm
    r.key_points = {{2.305, 1.965, 0.86}, {2.7, 2.0, 0.76}, {4.2, 0.825, 0.47}, {1.2, 3.65, 0.9},
                    {1.08, 0.78, 0.55}, {1.215, 0.915, 0.64}};
    MeshBuilder mb;
    mb.box(r.room.lo, r.room.hi, true, 0.1);
    for (const Box& b : r.solids) mb.box(b.lo, b.hi, false, 0.1);
    r.mesh = mb.mesh;
    return r;
}

/// Probes on the six faces of a box every `step` (at least 3 x 3 per face), `inset` from the
/// face's edges; normals outward, or inward for the room.
void box_probes(const Box& b, bool inward, double step, double inset, std::vector<Probe>& out,
                const std::function<int(int face)>& owner) {
    for (int axis = 0; axis < 3; ++axis) {
        for (int side = 0; side < 2; ++side) {
            const int u = (axis + 1) % 3, v = (axis + 2) % 3;
            D3 n{0, 0, 0};
            n[std::size_t(axis)] = (side ? 1.0 : -1.0) * (inward ? -1.0 : 1.0);
            const double lu = b.hi[std::size_t(u)] - b.lo[std::size_t(u)] - 2.0 * inset;
            const double lv = b.hi[std::size_t(v)] - b.lo[std::size_t(v)] - 2.0 * inset;
            const int nu = std::max(3, int(std::ceil(lu / step)) + 1);
            const int nv = std::max(3, int(std::ceil(lv / step)) + 1);
            for (int i = 0; i < nu; ++i) {
                for (int j = 0; j < nv; ++j) {
                    D3 p;
                    p[std::size_t(axis)] = side ? b.hi[std::size_t(axis)] : b.lo[std::size_t(axis)];
                    p[std::size_t(u)] = b.lo[std::size_t(u)] + inset + lu * i / (nu - 1);
                    p[std::size_t(v)] = b.lo[std::size_t(v)] + inset + lv * j / (nv - 1);
                    out.push_back({p, n, owner(axis * 2 + side)});
                }
            }
        }
    }
}

/// A camera at `eye` looking at `target`, z up: OpenCV axes (x right, y down, z forward),
/// camera to world.
Pose look_at(const D3& eye, const D3& target) {
    const D3 z = normalized(sub(target, eye));
    const D3 x = normalized(cross(z, {0, 0, 1}));
    const D3 y = cross(z, x);
    return {x[0], y[0], z[0], eye[0], x[1], y[1], z[1], eye[1], x[2], y[2], z[2], eye[2], 0, 0, 0, 1};
}

/// Whether the probe is seen in the frame: in front of the camera, inside the image, facing
/// it at a cosine of at least 0.3, and the rendered depth there is its own (not occluded).
bool seen(const Probe& pr, const DepthImage& depth, const Intrinsics& K, const Pose& m) {
    const D3 eye{m[3], m[7], m[11]};
    const D3 to_eye = sub(eye, pr.p);
    if (dot(pr.n, to_eye) < 0.3 * norm(to_eye)) return false;
    const D3 q = sub(pr.p, eye);
    const D3 c{m[0] * q[0] + m[4] * q[1] + m[8] * q[2], m[1] * q[0] + m[5] * q[1] + m[9] * q[2],
               m[2] * q[0] + m[6] * q[1] + m[10] * q[2]};
    if (c[2] < 0.05) return false;
    const int u = int(std::lround(K.fx * c[0] / c[2] + K.cx)), v = int(std::lround(K.fy * c[1] / c[2] + K.cy));
    if (u < 0 || v < 0 || u >= K.width || v >= K.height) return false;
    const double d = depth.at(u, v);
    return d > 0.0 && std::fabs(d - c[2]) <= 0.01 + 4.0 * c[2] / K.fx;
}

}  // namespace

TEST_CASE("the city block checks accept the exact surfaces", "[scenes]") {
    // The checks of the test below on the scene's own exact surfaces (no walls): every
    // assertion holds, so a failure there is the reconstruction's.
    const City city = make_city();
    const double voxel = 0.5;
    const Mesh exact = city_surface(city, 0.25);
    const CityCheck c = check_city(city, exact, voxel);
    INFO(city.points.size() << " points (" << city.wall_points << " on walls, " << city.tree_points
                            << " in canopies), " << city.strays.size() << " strays");
    CHECK(city.wall_points >= 20);
    require_city(city, c);
    // Every roof fully, nothing facing down but the canopies' undersides.
    for (double r : c.roof_cover) CHECK(r == 1.0);
    CHECK(c.ground_cover == 1.0);
    CHECK(c.down.horizontal == 0.0);
    CHECK(c.down.all > 0.0);
}

TEST_CASE("a city block sampled from above", "[scenes]") {
    // An airborne LiDAR tile, z up, in metres: 110 m x 110 m at 0.5 m spacing, each sample the
    // highest surface under a vertical ray (5 % of the rays 15 degrees off vertical, so the
    // walls get a few samples); no normals. The roofs are not connected to the ground in the
    // data. Trees give several returns per ray; birds and noise float in the air.
    const City city = make_city();
    PointCloud cloud;
    for (const D3& p : city.points) cloud.positions.push_back({float(p[0]), float(p[1]), float(p[2])});
    for (const D3& p : city.strays) cloud.positions.push_back({float(p[0]), float(p[1]), float(p[2])});
    PipelineOptions o;
    o.splat.voxel_size = 0.5;
    const PipelineResult r = reconstruct(cloud, o);
    REQUIRE(!r.mesh.empty());
    const CityCheck c = check_city(city, r.mesh, o.splat.voxel_size);
    const TopologyStats t = mesh_topology(r.mesh);
    INFO(t.faces << " faces, " << t.components << " pieces; clean removed " << r.clean_stats.removed_components
                 << " pieces of " << r.clean_stats.components_before << " (" << r.clean_stats.removed_faces
                 << " faces); outliers kept " << cloud.size() << " of " << city.points.size() + city.strays.size()
                 << " points; normals flipped " << r.normals.flipped);
    require_city(city, c);
}

TEST_CASE("a room with furniture from rendered RGB-D frames", "[scenes]") {
    // A 5 x 4 x 2.6 m room (floor, walls, ceiling) with a table, a mug on it, a chair, a
    // shelf against a wall and a small side table with a cup, rendered from 28 poses inside the room at 1.4 m (320 x 240, 65
    // degrees, 2.5 mm depth noise), fused at 2 cm and meshed with the default options.
    const Room room = make_room();
    const double voxel = 0.02;
    const Intrinsics K = camera_intrinsics(320, 240, 65.0);
    const D3 centre{2.5, 2.0, 1.4};
    std::vector<Pose> poses;
    for (int i = 0; i < 16; ++i) {  // outward, toward the walls, tilted up and down
        const double a = 2.0 * M_PI * i / 16.0;
        const double pitch = std::array<double, 4>{-15.0, -45.0, 25.0, -30.0}[std::size_t(i % 4)] * M_PI / 180.0;
        const D3 eye = add(centre, {std::cos(a), std::sin(a), 0.0});
        const D3 dir{std::cos(a) * std::cos(pitch), std::sin(a) * std::cos(pitch), std::sin(pitch)};
        poses.push_back(look_at(eye, add(eye, dir)));
    }
    for (int i = 0; i < 8; ++i) {  // inward, down at the table
        const double a = 2.0 * M_PI * (i + 0.5) / 8.0;
        poses.push_back(look_at(add(centre, {std::cos(a), std::sin(a), 0.0}), {2.5, 2.0, 0.76}));
    }
    for (int i = 0; i < 4; ++i) {  // from the middle toward the corners
        const double a = 2.0 * M_PI * (i + 0.5) / 4.0;
        poses.push_back(look_at(centre, add(centre, {2.5 * std::cos(a), 2.0 * std::sin(a), -0.6})));
    }
    std::vector<DepthImage> clean;
    for (const Pose& p : poses) clean.push_back(render_depth(room.mesh, K, p));

    // Probes on what the cameras see: the objects' faces and the room's six surfaces.
    std::vector<Probe> probes;
    for (std::size_t s = 0; s < room.solids.size(); ++s) {
        if (room.solid_object[s] < 0) continue;
        box_probes(room.solids[s], false, 0.05, 1.5 * voxel, probes, [&](int) { return room.solid_object[s]; });
    }
    const int first_surface = int(room.objects.size());
    const char* surfaces[] = {"wall x=0", "wall x=5", "wall y=0", "wall y=4", "floor", "ceiling"};
    box_probes(room.room, true, 0.1, 0.05, probes, [&](int face) { return first_surface + face; });
    std::vector<Probe> visible;
    for (const Probe& pr : probes) {
        for (std::size_t f = 0; f < poses.size(); ++f) {
            if (seen(pr, clean[f], K, poses[f])) {
                visible.push_back(pr);
                break;
            }
        }
    }
    const int owners = first_surface + 6;
    auto coverage = [&](const Mesh& m, std::vector<std::size_t>& seen_count, std::vector<double>& share) {
        const std::vector<D3> w = world_vertices(m);
        const PointGrid grid(w, voxel);
        std::vector<std::size_t> covered(std::size_t(owners), 0);
        seen_count.assign(std::size_t(owners), 0);
        for (const Probe& pr : visible) {
            ++seen_count[std::size_t(pr.owner)];
            if (grid.any_within(pr.p, 1.5 * voxel)) ++covered[std::size_t(pr.owner)];
        }
        share.assign(std::size_t(owners), 0.0);
        for (int k = 0; k < owners; ++k) {
            if (seen_count[std::size_t(k)]) share[std::size_t(k)] = double(covered[std::size_t(k)]) / double(seen_count[std::size_t(k)]);
        }
    };
    auto key_point_present = [&](const Mesh& m, std::size_t object) {
        const std::vector<D3> w = world_vertices(m);
        return PointGrid(w, voxel).any_within(room.key_points[object], 1.5 * voxel);
    };
    auto describe_room = [&](const std::vector<std::size_t>& n, const std::vector<double>& share) {
        std::ostringstream s;
        for (int k = 0; k < owners; ++k) {
            s << (k ? "; " : "") << (k < first_surface ? room.objects[std::size_t(k)] : surfaces[k - first_surface])
              << " " << share[std::size_t(k)] << " of " << n[std::size_t(k)];
        }
        return s.str();
    };

    // The probes on the exact surfaces (cut at the voxel): every object's key point and every
    // visible probe are found, so the checks below measure the reconstruction.
    {
        MeshBuilder fine;
        fine.box(room.room.lo, room.room.hi, true, voxel);
        for (const Box& b : room.solids) fine.box(b.lo, b.hi, false, voxel);
        std::vector<std::size_t> n;
        std::vector<double> share;
        coverage(fine.mesh, n, share);
        INFO("exact surfaces, share of visible probes covered: " << describe_room(n, share));
        for (int k = 0; k < owners; ++k) {
            CHECK(n[std::size_t(k)] >= 9);
            CHECK(share[std::size_t(k)] == 1.0);
        }
        for (std::size_t k = 0; k < room.objects.size(); ++k) CHECK(key_point_present(fine.mesh, k));
    }

    PipelineOptions o;
    o.splat.voxel_size = voxel;
    Fusion fusion(o);
    for (std::size_t f = 0; f < poses.size(); ++f) {
        DepthImage d = clean[f];
        add_depth_noise(d, 0.0025, 100 + f);
        fusion.integrate(d, K, poses[f]);
    }
    const PipelineResult r = reconstruct_volume(fusion.take_splat().volume, o);
    REQUIRE(!r.mesh.empty());
    std::vector<std::size_t> n;
    std::vector<double> share;
    coverage(r.mesh, n, share);
    // The vertices' distances to the true surfaces (whose mesh has its origin at 0).
    const MeshDistance truth(room.mesh);
    std::vector<Vec3f> world;
    for (const D3& p : world_vertices(r.mesh)) world.push_back({float(p[0]), float(p[1]), float(p[2])});
    const std::vector<double> d_world = truth.distances(world);
    std::size_t close = 0;
    for (double d : d_world) close += d <= 2.0 * voxel ? 1 : 0;
    const double accurate = d_world.empty() ? 0.0 : double(close) / double(d_world.size());
    const TopologyStats t = mesh_topology(r.mesh);
    std::ostringstream keys;
    for (std::size_t k = 0; k < room.objects.size(); ++k) {
        keys << room.objects[k] << (key_point_present(r.mesh, k) ? " yes" : " NO") << "; ";
    }
    INFO(t.faces << " faces, " << t.components << " pieces; clean removed " << r.clean_stats.removed_components
                 << " pieces of " << r.clean_stats.components_before << " (" << r.clean_stats.removed_faces << " faces)");
    INFO("share of visible probes covered: " << describe_room(n, share));
    INFO("mesh at the key point (centre of the best-seen face): " << keys.str());
    INFO("share of mesh vertices within 2 voxels of the true surfaces: " << accurate);
    for (std::size_t k = 0; k < room.objects.size(); ++k) {
        CAPTURE(room.objects[k]);
        CHECK(key_point_present(r.mesh, k));
        CHECK(share[k] >= 0.5);
    }
    for (int k = first_surface; k < owners; ++k) {
        CAPTURE(surfaces[k - first_surface]);
        CHECK(share[std::size_t(k)] >= 0.9);
    }
    CHECK(accurate >= 0.95);
}

TEST_CASE("closed objects keep their orientation", "[scenes]") {
    // Closed shapes sampled without normals: the estimated normals' orientation must come out
    // outward, so the mesh is closed and encloses a positive volume.
    for (const char* name : {"sphere", "lbracket"}) {
        const Shape shape = make_shape(name);
        PointCloud cloud = sample_uniform(shape.mesh, 30000, 3);
        cloud.normals.clear();
        const PipelineResult r = reconstruct(cloud, PipelineOptions{});
        const TopologyStats t = mesh_topology(r.mesh);
        INFO(name << ": " << t.faces << " faces, " << t.components << " pieces, " << t.boundary_edges
                  << " boundary edges, signed volume " << t.signed_volume << " (the shape's "
                  << mesh_topology(shape.mesh).signed_volume << ")");
        CHECK(t.faces > 1000);
        CHECK(t.boundary_edges == 0);
        CHECK(t.signed_volume > 0.0);
    }
}
