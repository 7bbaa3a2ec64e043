// Planar regions with crisp edges (issue 25 point 2): on generated CAD parts (a rotated cube,
// an L-bracket, a gabled house; uniform random samples with exact normals, dual contouring) the regions are
// the parts' faces, their planes within 0.1 degree of the true ones, the corners within 0.1
// voxel, and the re-triangulation keeps a tenth of the faces or fewer, closed and one piece;
// curved shapes move by at most the distance tolerance.
#include <cmath>
#include <algorithm>
#include <map>

#include "shapes.h"
#include "support.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/pipeline.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

struct TruePlane {
    Vec3d n;
    double d;
};

/// The distinct face planes of an exact polyhedral mesh.
std::vector<TruePlane> true_planes(const Mesh& m) {
    std::vector<TruePlane> out;
    for (const Triangle& t : m.faces) {
        const Vec3f &a = m.vertices[std::size_t(t[0])], &b = m.vertices[std::size_t(t[1])],
                    &c = m.vertices[std::size_t(t[2])];
        double n[3] = {(double(b[1]) - a[1]) * (double(c[2]) - a[2]) - (double(b[2]) - a[2]) * (double(c[1]) - a[1]),
                       (double(b[2]) - a[2]) * (double(c[0]) - a[0]) - (double(b[0]) - a[0]) * (double(c[2]) - a[2]),
                       (double(b[0]) - a[0]) * (double(c[1]) - a[1]) - (double(b[1]) - a[1]) * (double(c[0]) - a[0])};
        const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (!(len > 0.0)) continue;
        const Vec3d u{n[0] / len, n[1] / len, n[2] / len};
        const double d = u[0] * a[0] + u[1] * a[1] + u[2] * a[2];
        bool known = false;
        for (const TruePlane& p : out) {
            known |= u[0] * p.n[0] + u[1] * p.n[1] + u[2] * p.n[2] > 1.0 - 1e-9 &&
                     std::fabs(d - p.d) < 1e-6;
        }
        if (!known) out.push_back({u, d});
    }
    return out;
}

double angle_degrees(const Vec3d& a, const Vec3d& b) {
    const double c = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    return std::acos(std::clamp(c, -1.0, 1.0)) * 180.0 / M_PI;
}

PipelineResult with_planes(const std::string& name, bool planes, double* voxel) {
    const Shape shape = make_shape(name);
    PointCloud sample = sample_uniform(shape.mesh, 60000, 9);
    PipelineOptions o;
    o.splat.voxel_size = *voxel = spacing_of(shape.area, 60000);
    o.mesh.method = Mesher::dc;
    o.planes.enabled = planes;
    return reconstruct(sample, o);
}

/// Edges inside a region (both faces in it) whose far corner lies strictly inside the other
/// face's circumcircle in the region's plane, and the smallest angle of the regions' faces.
struct DelaunayCheck {
    int violations = 0, interior_edges = 0;
    double min_angle = 180.0;  // degrees
};

DelaunayCheck delaunay_check(const Mesh& m, const std::vector<Plane>& planes) {
    DelaunayCheck out;
    std::map<std::pair<std::int32_t, std::int32_t>, std::vector<std::size_t>> edges;
    for (std::size_t f = 0; f < m.faces.size(); ++f) {
        for (int k = 0; k < 3; ++k) {
            const std::int32_t a = m.faces[f][std::size_t(k)], b = m.faces[f][std::size_t((k + 1) % 3)];
            edges[{std::min(a, b), std::max(a, b)}].push_back(f);
        }
    }
    // Points in a region's plane: (u, v) with u x v = normal.
    const auto in_plane = [&](const Plane& p, std::int32_t i) {
        const Vec3d& n = p.normal;
        Vec3d e{0, 0, 0};
        e[std::fabs(n[0]) < 0.5 ? 0 : (std::fabs(n[1]) < 0.5 ? 1 : 2)] = 1.0;
        Vec3d u{e[1] * n[2] - e[2] * n[1], e[2] * n[0] - e[0] * n[2], e[0] * n[1] - e[1] * n[0]};
        const double l = std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
        for (double& c : u) c /= l;
        const Vec3d v{n[1] * u[2] - n[2] * u[1], n[2] * u[0] - n[0] * u[2], n[0] * u[1] - n[1] * u[0]};
        const Vec3f& q = m.vertices[std::size_t(i)];
        return std::array<double, 2>{u[0] * q[0] + u[1] * q[1] + u[2] * q[2],
                                     v[0] * q[0] + v[1] * q[1] + v[2] * q[2]};
    };
    for (const auto& [edge, faces] : edges) {
        if (faces.size() != 2) continue;
        const std::int32_t g = m.regions[faces[0]];
        if (g < 0 || m.regions[faces[1]] != g) continue;
        ++out.interior_edges;
        const Plane& pl = planes[std::size_t(g)];
        std::int32_t c = -1, d = -1;
        std::array<std::int32_t, 3> t = m.faces[faces[0]];
        while (!(t[0] == edge.first && t[1] == edge.second) && !(t[0] == edge.second && t[1] == edge.first)) {
            std::rotate(t.begin(), t.begin() + 1, t.end());
        }
        c = t[2];
        for (std::int32_t x : m.faces[faces[1]]) {
            if (x != edge.first && x != edge.second) d = x;
        }
        const auto pa = in_plane(pl, t[0]), pb = in_plane(pl, t[1]), pc = in_plane(pl, c),
                   pd = in_plane(pl, d);
        const double ax = pa[0] - pd[0], ay = pa[1] - pd[1], bx = pb[0] - pd[0], by = pb[1] - pd[1],
                     cx = pc[0] - pd[0], cy = pc[1] - pd[1];
        const double det = (ax * ax + ay * ay) * (bx * cy - by * cx) -
                           (bx * bx + by * by) * (ax * cy - ay * cx) +
                           (cx * cx + cy * cy) * (ax * by - ay * bx);
        const double scale = std::max({ax * ax + ay * ay, bx * bx + by * by, cx * cx + cy * cy});
        out.violations += det > 1e-6 * scale * scale;
    }
    for (std::size_t f = 0; f < m.faces.size(); ++f) {
        if (m.regions[f] < 0) continue;
        for (int k = 0; k < 3; ++k) {
            const Vec3f &p = m.vertices[std::size_t(m.faces[f][std::size_t(k)])],
                        &q = m.vertices[std::size_t(m.faces[f][std::size_t((k + 1) % 3)])],
                        &r = m.vertices[std::size_t(m.faces[f][std::size_t((k + 2) % 3)])];
            const double u[3] = {double(q[0]) - p[0], double(q[1]) - p[1], double(q[2]) - p[2]};
            const double w[3] = {double(r[0]) - p[0], double(r[1]) - p[1], double(r[2]) - p[2]};
            const double c = (u[0] * w[0] + u[1] * w[1] + u[2] * w[2]) /
                             std::sqrt((u[0] * u[0] + u[1] * u[1] + u[2] * u[2]) *
                                       (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]));
            out.min_angle = std::min(out.min_angle, std::acos(std::clamp(c, -1.0, 1.0)) * 180.0 / M_PI);
        }
    }
    return out;
}

}  // namespace

TEST_CASE("planes: CAD parts come out as their faces with crisp edges and corners", "[planes]") {
    for (const std::string name : {"cube", "lbracket", "house"}) {
        INFO(name);
        const Shape shape = make_shape(name);
        const std::vector<TruePlane> truth = true_planes(shape.mesh);
        double voxel = 0.0;
        const PipelineResult plain = with_planes(name, false, &voxel);
        const PipelineResult r = with_planes(name, true, &voxel);
        // One region per face of the part, each plane the true one.
        REQUIRE(r.planes.planes.size() == truth.size());
        for (const Plane& p : r.planes.planes) {
            double best = 180.0, offset = 1e30;  // the nearest true plane of the same direction
            for (const TruePlane& t : truth) {
                const double a = angle_degrees(p.normal, t.n);
                if (a < 1.0 && std::fabs(p.offset - t.d) < offset) {
                    best = a;
                    offset = std::fabs(p.offset - t.d);
                }
            }
            CHECK(best < 0.1);
            CHECK(offset < 0.1 * voxel);
        }
        // Every face in a region; few faces; still closed, manifold, one piece.
        REQUIRE(r.mesh.regions.size() == r.mesh.faces.size());
        for (std::int32_t g : r.mesh.regions) CHECK(g >= 0);
        CHECK(r.mesh.faces.size() * 10 <= plain.mesh.faces.size());
        const TopologyStats t = mesh_topology(r.mesh);
        CHECK(t.boundary_edges == 0);
        CHECK(t.nonmanifold_edges == 0);
        CHECK(t.components == 1);
        // Each region's triangulation is Delaunay inside its border (Lawson's flips).
        const DelaunayCheck dc = delaunay_check(r.mesh, r.planes.planes);
        INFO(dc.interior_edges << " edges inside regions, smallest angle " << dc.min_angle
                               << " degrees, " << r.planes.flips << " flips");
        CHECK(dc.violations == 0);
        // Corners within 0.1 voxel of a vertex.
        for (const Vec3f& c : sharp_features(shape.mesh).corners) {
            double nearest = 1e30;
            for (const Vec3f& v : r.mesh.vertices) {
                const double dx = double(v[0]) - c[0], dy = double(v[1]) - c[1],
                             dz = double(v[2]) - c[2];
                nearest = std::min(nearest, std::sqrt(dx * dx + dy * dy + dz * dz));
            }
            CHECK(nearest < 0.1 * voxel);
        }
    }
}

// A curved surface flat to within the distance tolerance over the minimum area becomes facets
// (as in LVR): the mesh moves by at most that tolerance, and its topology stays.
TEST_CASE("planes: curved shapes move by at most the tolerance and keep their topology",
          "[planes]") {
    for (const std::string name : {"sphere", "torus"}) {
        INFO(name);
        double voxel = 0.0;
        const PipelineResult plain = with_planes(name, false, &voxel);
        const PipelineResult r = with_planes(name, true, &voxel);
        const TopologyStats t = mesh_topology(r.mesh), t0 = mesh_topology(plain.mesh);
        CHECK(t.boundary_edges == 0);
        CHECK(t.nonmanifold_edges == 0);
        CHECK(t.components == 1);
        CHECK(t.euler == t0.euler);
        EvalOptions e;
        e.samples = 200000;
        const EvalResult d = evaluate(r.mesh, plain.mesh, e);
        const PlaneOptions o;
        CHECK(d.hausdorff < (o.distance + 2.0 * o.max_error) * voxel);
    }
}

TEST_CASE("planes: options out of range are refused", "[planes]") {
    PlaneOptions o;
    o.angle = 95.0;
    CHECK_THROWS_AS(o.validate(), InvalidArgument);
    o = PlaneOptions{};
    o.distance = 0.0;
    CHECK_THROWS_AS(o.validate(), InvalidArgument);
    CHECK_THROWS_AS(planar_regions(Mesh{}, PlaneOptions{}, 0.0), InvalidArgument);
}
