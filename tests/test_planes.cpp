// Planar regions with crisp edges (issue 25 point 2): on generated CAD parts (a rotated cube,
// an L-bracket; uniform random samples with exact normals, dual contouring) the regions are
// the parts' faces, their planes within 0.1 degree of the true ones, the corners within 0.1
// voxel, and the re-triangulation keeps a tenth of the faces or fewer, closed and one piece;
// curved shapes move by at most the distance tolerance.
#include <cmath>
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

}  // namespace

TEST_CASE("planes: CAD parts come out as their faces with crisp edges and corners", "[planes]") {
    for (const std::string name : {"cube", "lbracket"}) {
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
