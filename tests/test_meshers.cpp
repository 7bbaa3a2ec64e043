// Our dual marching cubes, marching cubes and dual contouring against shapes with known answers:
// level-set sphere and torus (topology, volume), volumeToMesh's surface, random fields (manifold),
// boxes and a drilled block (sharp features), an open splatted patch, thread-count independence
// and colour.
#include <openvdb/tools/SignedFloodFill.h>
#include <tbb/global_control.h>

#include <atomic>
#include <functional>
#include <map>
#include <random>

#include "detail/crossings.h"
#include "support.h"
#include "support_volume.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/mesh.h"
#include "vdbrecon/splat.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

using V3 = openvdb::Vec3d;
double box_sdf(const V3& p, const V3& half) {
    const V3 q(std::fabs(p[0]) - half[0], std::fabs(p[1]) - half[1], std::fabs(p[2]) - half[2]);
    const V3 out(std::max(q[0], 0.0), std::max(q[1], 0.0), std::max(q[2], 0.0));
    return out.length() + std::min(std::max(q[0], std::max(q[1], q[2])), 0.0);
}

/// Rotation by `angle` about the unit axis `u` (Rodrigues).
openvdb::Mat3d rotation(V3 u, double angle) {
    u.normalize();
    return openvdb::math::rotation<openvdb::Mat3d>(u, angle);
}

/// A block with a cylindrical hole drilled through it along z: half extents (a, b, h), hole of
/// radius r around the z axis through (cx, cy). The exact distance to its surface is the minimum
/// over the pieces: four full side faces, the top and bottom faces minus the hole's disc, and the
/// hole's wall.
struct DrilledBlock {
    double a = 0.62, b = 0.47, h = 0.33, r = 0.21, cx = 0.07, cy = -0.04;

    bool inside(const V3& p) const {
        return std::fabs(p[0]) < a && std::fabs(p[1]) < b && std::fabs(p[2]) < h &&
               std::hypot(p[0] - cx, p[1] - cy) > r;
    }
    double distance(const V3& p) const {
        auto clampd = [](double v, double lo, double hi) { return std::max(lo, std::min(hi, v)); };
        double best = std::numeric_limits<double>::infinity();
        // Side faces x = +-a and y = +-b: full rectangles.
        for (double sx : {-a, a}) {
            const V3 q(sx, clampd(p[1], -b, b), clampd(p[2], -h, h));
            best = std::min(best, (p - q).length());
        }
        for (double sy : {-b, b}) {
            const V3 q(clampd(p[0], -a, a), sy, clampd(p[2], -h, h));
            best = std::min(best, (p - q).length());
        }
        // Top and bottom: the rectangle minus the disc (the disc lies inside the rectangle).
        const double rho = std::hypot(p[0] - cx, p[1] - cy);
        for (double sz : {-h, h}) {
            const double dz = p[2] - sz;
            double d2;
            if (std::fabs(p[0]) <= a && std::fabs(p[1]) <= b && rho < r) {
                d2 = r - rho;  // nearest point of the face is on the hole's rim
            } else {
                d2 = std::hypot(p[0] - clampd(p[0], -a, a), p[1] - clampd(p[1], -b, b));
            }
            best = std::min(best, std::hypot(d2, dz));
        }
        // The hole's wall.
        best = std::min(best, std::hypot(rho - r, std::max(std::fabs(p[2]) - h, 0.0)));
        return best;
    }
    double sdf(const V3& p) const { return inside(p) ? -distance(p) : distance(p); }
    /// Points on the exact surface, spacing about `step`, including every edge and the rims.
    std::vector<V3> surface_samples(double step) const {
        std::vector<V3> s;
        auto grid = [&](double lo, double hi) {
            std::vector<double> t;
            const int n = std::max(2, int(std::ceil((hi - lo) / step)) + 1);
            for (int i = 0; i < n; ++i) t.push_back(lo + (hi - lo) * i / (n - 1));
            return t;
        };
        for (double y : grid(-b, b))
            for (double z : grid(-h, h)) s.push_back({-a, y, z}), s.push_back({a, y, z});
        for (double x : grid(-a, a))
            for (double z : grid(-h, h)) s.push_back({x, -b, z}), s.push_back({x, b, z});
        for (double x : grid(-a, a)) {
            for (double y : grid(-b, b)) {
                if (std::hypot(x - cx, y - cy) < r) continue;
                s.push_back({x, y, -h});
                s.push_back({x, y, h});
            }
        }
        const int m = int(std::ceil(2 * M_PI * r / step));
        for (int i = 0; i < m; ++i) {
            const double t = 2 * M_PI * i / m;
            for (double z : grid(-h, h)) s.push_back({cx + r * std::cos(t), cy + r * std::sin(t), z});
        }
        return s;
    }
};

/// Samples on the surface of a box (all six faces including edges and corners), then rotated.
std::vector<V3> box_samples(const V3& half, double step, const openvdb::Mat3d& rot) {
    std::vector<V3> s;
    auto grid = [&](double e) {
        std::vector<double> t;
        const int n = std::max(2, int(std::ceil(2 * e / step)) + 1);
        for (int i = 0; i < n; ++i) t.push_back(-e + 2 * e * i / (n - 1));
        return t;
    };
    for (int axis = 0; axis < 3; ++axis) {
        const int u = (axis + 1) % 3, w = (axis + 2) % 3;
        for (double su : grid(half[u])) {
            for (double sw : grid(half[w])) {
                for (double sign : {-1.0, 1.0}) {
                    V3 p;
                    p[axis] = sign * half[axis];
                    p[u] = su;
                    p[w] = sw;
                    s.push_back(rot * p);
                }
            }
        }
    }
    return s;
}

/// Two-sided Hausdorff distance between a mesh and an exact surface: mesh samples (and vertices)
/// against the exact distance function, exact surface samples against the mesh.
double hausdorff(const Mesh& mesh, const Field& distance, const std::vector<V3>& exact) {
    double worst = 0.0;
    std::vector<Vec3f> pts = sample_surface(mesh, 200000, 3);
    pts.insert(pts.end(), mesh.vertices.begin(), mesh.vertices.end());
    for (const Vec3f& p : pts) worst = std::max(worst, distance(V3(p[0], p[1], p[2])));
    std::vector<Vec3f> q;
    for (const V3& p : exact) q.push_back({float(p[0]), float(p[1]), float(p[2])});
    for (double d : MeshDistance(mesh).distances(q)) worst = std::max(worst, d);
    return worst;
}

double max_vertex_distance(const Mesh& mesh, const Field& distance) {
    double worst = 0.0;
    for (const Vec3f& p : mesh.vertices) worst = std::max(worst, distance(V3(p[0], p[1], p[2])));
    return worst;
}

/// Distance from an exact point to the nearest mesh vertex.
double nearest_vertex(const Mesh& mesh, const V3& c) {
    double best = std::numeric_limits<double>::infinity();
    for (const Vec3f& p : mesh.vertices) best = std::min(best, (V3(p[0], p[1], p[2]) - c).length());
    return best;
}

Mesh mesh_with(const Volume& v, Mesher method) {
    MeshOptions o;
    o.method = method;
    return extract_mesh(v, o).mesh;
}

}  // namespace

TEST_CASE("dual, mc and dc: level-set sphere and torus are closed with the right genus and volume",
          "[mesh]") {
    const double voxel = 0.04;
    const Volume sphere = sphere_volume(1.0f, {0.13f, -0.21f, 0.05f}, float(voxel));
    const double R = 0.8, r = 0.3;
    const Volume torus = analytic_volume(
        [&](const V3& p) { return std::hypot(std::hypot(p[0], p[2]) - R, p[1]) - r; }, 1.3, voxel);
    for (Mesher m : {Mesher::dual, Mesher::mc, Mesher::dc}) {
        CAPTURE(int(m));
        const TopologyStats s = mesh_topology(mesh_with(sphere, m));
        REQUIRE(s.faces > 5000);
        REQUIRE(s.boundary_edges == 0);
        REQUIRE(s.nonmanifold_edges == 0);
        REQUIRE(s.components == 1);
        REQUIRE(s.euler == 2);
        REQUIRE(s.signed_volume == Approx(4.0 / 3.0 * M_PI).epsilon(0.01));
        const TopologyStats t = mesh_topology(mesh_with(torus, m));
        REQUIRE(t.boundary_edges == 0);
        REQUIRE(t.nonmanifold_edges == 0);
        REQUIRE(t.components == 1);
        REQUIRE(t.euler == 0);
        REQUIRE(t.signed_volume == Approx(2.0 * M_PI * M_PI * R * r * r).epsilon(0.01));
    }
}

TEST_CASE("dual makes volumeToMesh's surface: the same vertices and as many faces", "[mesh]") {
    // Smooth shapes (no ambiguous cell): one vertex per surface cell, at the mean of its
    // crossings, in both; and one quad per crossed edge.
    const double voxel = 0.1, R = 0.8, r = 0.3;
    const Volume sphere = sphere_volume(0.9f, {0.13f, -0.21f, 0.05f}, float(voxel));
    const Volume torus = analytic_volume(
        [&](const V3& p) { return std::hypot(std::hypot(p[0], p[2]) - R, p[1]) - r; }, 1.3, voxel);
    for (const Volume* v : {&sphere, &torus}) {
        const Mesh dual = mesh_with(*v, Mesher::dual), vdb = mesh_with(*v, Mesher::vdb);
        REQUIRE(dual.vertices.size() > 500);
        REQUIRE(dual.vertices.size() == vdb.vertices.size());
        REQUIRE(dual.faces.size() == vdb.faces.size());
        for (const Vec3f& p : dual.vertices) {
            REQUIRE(nearest_vertex(vdb, V3(p[0], p[1], p[2])) < 1e-5 * voxel);
        }
    }
}

TEST_CASE("dual and dc are manifold on random fields, where cells' ambiguous faces meet",
          "[mesh]") {
    // Values uniform in [-1, 1] on a 24^3 block: most cells are ambiguous. Where two cells'
    // loops both cross their shared face twice, one vertex per loop would give their two
    // vertices an edge of four quads; the loops are split there (loop_chains).
    for (unsigned seed : {1u, 2u, 3u}) {
        CAPTURE(seed);
        std::mt19937 rng(seed);
        std::uniform_real_distribution<float> value(-1.0f, 1.0f);
        Volume v;
        v.sdf = openvdb::FloatGrid::create(2.0f);
        v.sdf->setGridClass(openvdb::GRID_LEVEL_SET);
        v.sdf->setTransform(openvdb::math::Transform::createLinearTransform(0.1));
        auto acc = v.sdf->getAccessor();
        for (int x = 0; x < 24; ++x)
            for (int y = 0; y < 24; ++y)
                for (int z = 0; z < 24; ++z) acc.setValueOn({x, y, z}, value(rng));
        std::size_t loops = 0;
        {
            const auto& tree = v.sdf->tree();
            const detail::Crossings c = detail::find_crossings(tree, 0.0f, false);
            std::atomic<std::size_t> n{0};
            detail::for_each_surface_cell(
                tree, c, 0.0f,
                [&](std::size_t, const detail::SurfaceCell& cell, detail::FloatAccessor&) {
                    n += std::size_t(cell.loops.count);
                });
            loops = n;
        }
        MeshOptions o;
        o.min_surface_weight = 0.0;  // no weight grid: keep every face
        o.max_gap = std::numeric_limits<double>::infinity();
        for (Mesher m : {Mesher::dual, Mesher::dc}) {
            CAPTURE(int(m));
            o.method = m;
            const MeshResult r = extract_mesh(v, o);
            const TopologyStats t = mesh_topology(r.mesh);
            REQUIRE(t.faces > 10000);
            REQUIRE(t.nonmanifold_edges == 0);
            // Not vacuous: some loops were split (more vertices than loops).
            REQUIRE(r.mesh.vertices.size() > loops);
        }
    }
}

TEST_CASE("mc vertices lie on the surface and its normals point outwards", "[mesh]") {
    const double voxel = 0.05;
    const Volume v = analytic_volume([](const V3& p) { return p.length() - 0.77; }, 1.0, voxel);
    const Mesh m = mesh_with(v, Mesher::mc);
    REQUIRE(m.normals.size() == m.vertices.size());
    for (std::size_t i = 0; i < m.vertices.size(); ++i) {
        const V3 p(m.vertices[i][0], m.vertices[i][1], m.vertices[i][2]);
        // Linear interpolation along an edge of an exact distance: a small chordal error only.
        REQUIRE(std::fabs(p.length() - 0.77) < 0.02 * voxel);
        const V3 n(m.normals[i][0], m.normals[i][1], m.normals[i][2]);
        REQUIRE(n.dot(p) / p.length() > 0.99);
    }
}

TEST_CASE("dc normals: radial on a sphere, the face's own on a rotated box", "[mesh]") {
    // DC hands its patch normals (mean of the crossings' robust gradients) to finish_mesh as the
    // vertex normals.
    const double voxel = 0.05;
    const Mesh sphere = mesh_with(
        analytic_volume([](const V3& p) { return p.length() - 0.77; }, 1.0, voxel), Mesher::dc);
    REQUIRE(sphere.normals.size() == sphere.vertices.size());
    double worst = 1.0;
    for (std::size_t i = 0; i < sphere.vertices.size(); ++i) {
        const V3 p(sphere.vertices[i][0], sphere.vertices[i][1], sphere.vertices[i][2]);
        const V3 n(sphere.normals[i][0], sphere.normals[i][1], sphere.normals[i][2]);
        REQUIRE(std::fabs(n.length() - 1.0) < 1e-5);
        worst = std::min(worst, n.dot(p) / p.length());
    }
    CAPTURE(worst);
    REQUIRE(worst > 0.995);  // measured 0.9989 (2.6 degrees)

    const V3 half(0.61, 0.43, 0.37);
    const openvdb::Mat3d rot = rotation(V3(1.0, 2.0, 0.5), 0.61), inv = rot.transpose();
    const Mesh box =
        mesh_with(analytic_volume([&](const V3& p) { return box_sdf(inv * p, half); }, 1.0, voxel),
                  Mesher::dc);
    REQUIRE(box.normals.size() == box.vertices.size());
    int on_faces = 0;
    for (std::size_t i = 0; i < box.vertices.size(); ++i) {
        const V3 q = inv * V3(box.vertices[i][0], box.vertices[i][1], box.vertices[i][2]);
        const V3 n = inv * V3(box.normals[i][0], box.normals[i][1], box.normals[i][2]);
        // The face the vertex lies on, and how far it is from the face's edges.
        int axis = 0;
        for (int a = 1; a < 3; ++a) {
            if (std::fabs(q[a]) - half[a] > std::fabs(q[axis]) - half[axis]) axis = a;
        }
        double to_edge = std::numeric_limits<double>::infinity();
        for (int a = 0; a < 3; ++a) {
            if (a != axis) to_edge = std::min(to_edge, half[a] - std::fabs(q[a]));
        }
        // Outward everywhere: towards the side of the face it lies on.
        REQUIRE(n[axis] * q[axis] > 0.0);
        if (to_edge < 2.0 * voxel) continue;  // next to an edge the normal is a blend
        ++on_faces;
        REQUIRE(std::fabs(n[axis]) > std::cos(0.5 * M_PI / 180.0));
    }
    REQUIRE(on_faces > 500);
}

TEST_CASE("dc keeps the sharp edges and corners of boxes that mc rounds off", "[mesh]") {
    const double voxel = 0.05;
    const V3 half(0.61, 0.43, 0.37);
    struct Case {
        const char* name;
        openvdb::Mat3d rot;
    };
    // Two rotations so that features do not align with the grid; the second puts corners in
    // "pockets" between grid points that no cell around them sees all three faces of.
    for (const Case& c : {Case{"axis-aligned", openvdb::Mat3d::identity()},
                          Case{"rotated", rotation(V3(1.0, 2.0, 0.5), 0.61)},
                          Case{"rotated again", rotation(V3(-0.3, 0.7, 1.1), 1.13)}}) {
        CAPTURE(c.name);
        const openvdb::Mat3d inv = c.rot.transpose();
        const Field sdf = [&](const V3& p) { return box_sdf(inv * p, half); };
        const Field dist = [&](const V3& p) { return std::fabs(box_sdf(inv * p, half)); };
        const Volume v = analytic_volume(sdf, 1.0, voxel);
        const Mesh dc = mesh_with(v, Mesher::dc), mc = mesh_with(v, Mesher::mc);
        for (const Mesh* m : {&dc, &mc}) {
            const TopologyStats t = mesh_topology(*m);
            REQUIRE(t.boundary_edges == 0);
            REQUIRE(t.nonmanifold_edges == 0);
            REQUIRE(t.euler == 2);
            REQUIRE(t.signed_volume == Approx(8 * half[0] * half[1] * half[2]).epsilon(0.01));
        }
        REQUIRE(max_vertex_distance(dc, dist) < 0.05 * voxel);
        const std::vector<V3> exact = box_samples(half, 0.25 * voxel, c.rot);
        const double h_dc = hausdorff(dc, dist, exact), h_mc = hausdorff(mc, dist, exact);
        CAPTURE(h_dc / voxel, h_mc / voxel);
        int corners = 0;
        for (int k = 0; k < 8; ++k) {
            const V3 corner = c.rot * V3(k & 1 ? half[0] : -half[0], k & 2 ? half[1] : -half[1],
                                         k & 4 ? half[2] : -half[2]);
            corners += nearest_vertex(dc, corner) < 0.1 * voxel;
        }
        // Issue 3: Hausdorff distance at least 3x below MC's, all corners within 0.1 voxel.
        // Measured: DC 0.005 / 0.015 / 0.018 voxel (MC 0.52 / 0.77 / 0.72), corners within
        // 0.005 / 0.015 / 0.018 voxel.
        REQUIRE(h_dc < 0.05 * voxel);
        REQUIRE(3.0 * h_dc <= h_mc);
        REQUIRE(corners == 8);
    }
}

TEST_CASE("dc keeps the edges of a drilled block (box minus cylinder)", "[mesh]") {
    const double voxel = 0.04;
    const DrilledBlock part;
    const Volume v = analytic_volume([&](const V3& p) { return part.sdf(p); }, 0.8, voxel);
    const Field dist = [&](const V3& p) { return part.distance(p); };
    const Mesh dc = mesh_with(v, Mesher::dc), mc = mesh_with(v, Mesher::mc);
    for (const Mesh* m : {&dc, &mc}) {
        const TopologyStats t = mesh_topology(*m);
        REQUIRE(t.boundary_edges == 0);
        REQUIRE(t.nonmanifold_edges == 0);
        REQUIRE(t.components == 1);
        REQUIRE(t.euler == 0);  // genus 1
        const double volume = 8 * part.a * part.b * part.h - M_PI * part.r * part.r * 2 * part.h;
        REQUIRE(t.signed_volume == Approx(volume).epsilon(0.01));
    }
    REQUIRE(max_vertex_distance(dc, dist) < 0.05 * voxel);
    const std::vector<V3> exact = part.surface_samples(0.25 * voxel);
    const double h_dc = hausdorff(dc, dist, exact), h_mc = hausdorff(mc, dist, exact);
    CAPTURE(h_dc / voxel, h_mc / voxel);
    // Issue 3: at least 3x below MC. Measured: DC 0.12 voxel (worst at the hole's rim, a
    // curved sharp edge), MC 0.61.
    REQUIRE(h_dc < 0.15 * voxel);
    REQUIRE(3.0 * h_dc <= h_mc);
    for (int k = 0; k < 8; ++k) {
        const V3 corner(k & 1 ? part.a : -part.a, k & 2 ? part.b : -part.b, k & 4 ? part.h : -part.h);
        REQUIRE(nearest_vertex(dc, corner) < 0.1 * voxel);
    }
}

TEST_CASE("dual, mc and dc on an open splatted patch: one boundary loop, nothing outside the data",
          "[mesh]") {
    const PointCloud plane = sample_plane(61, 0.3);  // [-0.3, 0.3]^2, spacing 0.01
    SplatOptions so;
    so.voxel_size = 0.01;
    const SplatResult sr = splat(plane, so);
    const double gap = MeshOptions{}.max_gap * so.voxel_size;
    for (Mesher m : {Mesher::dual, Mesher::mc, Mesher::dc}) {
        CAPTURE(int(m));
        const MeshResult r = extract_mesh(sr.volume, [&] {
            MeshOptions o;
            o.method = m;
            return o;
        }());
        const TopologyStats t = mesh_topology(r.mesh);
        REQUIRE(t.faces > 1000);
        REQUIRE(t.components == 1);
        REQUIRE(t.nonmanifold_edges == 0);
        REQUIRE(t.euler == 1);
        REQUIRE(boundary_loops(r.mesh) == 1);
        for (const Vec3f& v : r.mesh.vertices) {
            REQUIRE(std::fabs(v[2]) < 1e-4);
            REQUIRE(std::fabs(v[0]) <= 0.3 + gap);
            REQUIRE(std::fabs(v[1]) <= 0.3 + gap);
        }
    }
}

TEST_CASE("dual, mc and dc drop faces in invalid cells", "[mesh]") {
    Volume v = analytic_volume([](const V3& p) { return p.length() - 0.8; }, 1.0, 0.05);
    for (auto it = v.sdf->beginValueOn(); it; ++it) {
        if (v.sdf->indexToWorld(it.getCoord()).x() > 0.4) it.setValueOff();
    }
    for (Mesher m : {Mesher::dual, Mesher::mc, Mesher::dc}) {
        CAPTURE(int(m));
        const Mesh mesh = mesh_with(v, m);
        for (const Vec3f& p : mesh.vertices) REQUIRE(p[0] <= 0.4 + 1e-6);
        const TopologyStats t = mesh_topology(mesh);
        REQUIRE(t.boundary_edges > 0);
        REQUIRE(t.nonmanifold_edges == 0);
        REQUIRE(boundary_loops(mesh) == 1);
    }
}

TEST_CASE("every mesher is identical for any thread count and carries colours", "[mesh]") {
    PointCloud s = sample_sphere(30000, 0.5);
    for (const Vec3f& p : s.positions) {
        s.colors.push_back(p[1] > 0 ? Vec3f{1.0f, 0.0f, 0.0f} : Vec3f{0.0f, 0.0f, 1.0f});
    }
    SplatOptions so;
    so.voxel_size = 0.02;
    const SplatResult sr = splat(s, so);
    REQUIRE(sr.volume.color);
    for (Mesher m : {Mesher::dual, Mesher::vdb, Mesher::mc, Mesher::dc}) {
        CAPTURE(int(m));
        MeshOptions o;
        o.method = m;
        Mesh one, two;
        {
            tbb::global_control c(tbb::global_control::max_allowed_parallelism, 1);
            one = extract_mesh(sr.volume, o).mesh;
        }
        {
            tbb::global_control c(tbb::global_control::max_allowed_parallelism, 2);
            two = extract_mesh(sr.volume, o).mesh;
        }
        REQUIRE(one.vertices == two.vertices);
        REQUIRE(one.faces == two.faces);
        REQUIRE(one.colors == two.colors);
        REQUIRE(one.colors.size() == one.vertices.size());
        std::size_t away = 0, right = 0;
        for (std::size_t i = 0; i < one.vertices.size(); ++i) {
            const float y = one.vertices[i][1];
            if (std::fabs(y) < 0.05f) continue;  // within 2.5 voxels of the equator
            ++away;
            const Vec3f& c = one.colors[i];
            right += y > 0 ? (c[0] > 0.9f && c[2] < 0.1f) : (c[2] > 0.9f && c[0] < 0.1f);
        }
        REQUIRE(away > 1000);
        REQUIRE(double(right) >= 0.99 * double(away));
    }
}
