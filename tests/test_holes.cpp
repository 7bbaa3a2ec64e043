// Mesh hole filling (holes.h) and --watertight: a sphere with its cap cut off comes back closed
// and round, a hole in a flat face is filled flat, --fill-holes N leaves longer loops open, the
// pipeline's --watertight gives one closed piece and its volume, and the bunny comes out
// watertight.
#include <cmath>
#include <functional>

#include "shapes.h"
#include "support.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/holes.h"
#include "vdbrecon/io.h"
#include "vdbrecon/pipeline.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

/// The mesh without the faces whose centroid `cut` accepts (unreferenced vertices stay).
Mesh without_faces(const Mesh& m, const std::function<bool(const Vec3d&)>& cut) {
    Mesh out = m;
    std::vector<Triangle> kept;
    for (const Triangle& t : m.faces) {
        Vec3d c{0, 0, 0};
        for (std::int32_t v : t) {
            for (int a = 0; a < 3; ++a) c[a] += m.vertices[std::size_t(v)][a] / 3.0;
        }
        if (!cut(c)) kept.push_back(t);
    }
    out.faces = std::move(kept);
    return out;
}

Vec3d centroid(const Mesh& m) {
    Vec3d c{0, 0, 0};
    for (const Vec3f& v : m.vertices) {
        for (int a = 0; a < 3; ++a) c[a] += v[a] / double(m.vertices.size());
    }
    return c;
}

double distance(const Vec3f& a, const Vec3d& b) {
    return std::sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                     (a[2] - b[2]) * (a[2] - b[2]));
}

}  // namespace

TEST_CASE("a sphere's cut-off cap is filled closed and round", "[holes]") {
    const Mesh sphere = make_shape("sphere").mesh;  // radius 0.45
    const Vec3d c = centroid(sphere);
    const double radius = 0.45;
    // A cap 0.6 radius across (about 25 edges around).
    const Mesh cut = without_faces(sphere, [&](const Vec3d& p) { return p[1] - c[1] > 0.8 * radius; });
    REQUIRE(mesh_topology(cut).boundary_edges > 20);
    const HoleFillResult r = fill_holes(cut);
    const TopologyStats t = mesh_topology(r.mesh);
    CHECK(r.loops == 1);
    CHECK(r.filled == 1);
    CHECK(r.added_vertices > 10);  // refined
    CHECK(t.watertight());
    CHECK(t.euler == 2);
    CHECK(t.signed_volume > 0.0);  // patch oriented like the mesh
    double worst = 0.0;
    for (std::size_t v = cut.vertices.size(); v < r.mesh.vertices.size(); ++v) {
        worst = std::max(worst, std::fabs(distance(r.mesh.vertices[v], c) - radius));
    }
    // Faired, the patch follows the sphere's curvature (a flat patch would be 0.2 radius below
    // the cap's top): within 6 % of the radius.
    INFO("worst radial error of the patch " << worst / radius << " radii");
    CHECK(worst < 0.06 * radius);
    // Without fairing (refined, flat) the error is several times larger: the fairing bites.
    HoleFillOptions flat;
    flat.fair = false;
    const HoleFillResult f = fill_holes(cut, flat);
    double worst_flat = 0.0;
    for (std::size_t v = cut.vertices.size(); v < f.mesh.vertices.size(); ++v) {
        worst_flat = std::max(worst_flat, std::fabs(distance(f.mesh.vertices[v], c) - radius));
    }
    INFO("unfaired: " << worst_flat / radius << " radii");
    CHECK(worst_flat > 2.5 * worst);
}

TEST_CASE("a hole in a flat face is filled flat; max_edges leaves longer loops open", "[holes]") {
    const Mesh cube = make_shape("cube").mesh;
    // The cube's faces are rotated: cut a disc out of the face the first triangle lies on.
    const Triangle& t0 = cube.faces[0];
    Vec3d a, b, n;
    for (int k = 0; k < 3; ++k) {
        a[k] = cube.vertices[std::size_t(t0[1])][k] - cube.vertices[std::size_t(t0[0])][k];
        b[k] = cube.vertices[std::size_t(t0[2])][k] - cube.vertices[std::size_t(t0[0])][k];
    }
    n = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (double& x : n) x /= len;
    const Vec3f& p0 = cube.vertices[std::size_t(t0[0])];
    const double offset = n[0] * p0[0] + n[1] * p0[1] + n[2] * p0[2];
    // The whole face goes: its border is the hole.
    const Mesh cut = without_faces(cube, [&](const Vec3d& p) {
        return std::fabs(n[0] * p[0] + n[1] * p[1] + n[2] * p[2] - offset) < 1e-6;
    });
    const std::size_t loop_edges = mesh_topology(cut).boundary_edges;
    REQUIRE(loop_edges >= 4);

    const HoleFillResult r = fill_holes(cut);
    CHECK(mesh_topology(r.mesh).watertight());
    for (std::size_t v = cut.vertices.size(); v < r.mesh.vertices.size(); ++v) {
        const Vec3f& p = r.mesh.vertices[v];
        REQUIRE(std::fabs(n[0] * p[0] + n[1] * p[1] + n[2] * p[2] - offset) < 1e-5);
    }
    HoleFillOptions small;
    small.max_edges = loop_edges - 1;
    const HoleFillResult s = fill_holes(cut, small);
    CHECK(s.filled == 0);
    CHECK(s.largest_open == loop_edges);
    CHECK(mesh_topology(s.mesh).boundary_edges == loop_edges);
    small.max_edges = loop_edges;
    CHECK(fill_holes(cut, small).filled == 1);
}

TEST_CASE("watertight: one closed piece and its volume from a sample with a large hole", "[holes][pipeline]") {
    const Shape blob = make_shape("blob");
    PointCloud cloud = sample_uniform(blob.mesh, 60000, 2);
    const double voxel = 1.5 * spacing_of(blob.area, 60000);
    punch_holes(cloud, 1, 12 * voxel, 3);  // 24 voxels across: no closing reaches it
    PipelineOptions o;
    o.splat.voxel_size = voxel;
    const PipelineResult open = reconstruct(cloud, o);
    REQUIRE(mesh_topology(open.mesh).boundary_edges > 50);
    o.watertight = true;
    const PipelineResult r = reconstruct(cloud, o);
    const TopologyStats t = mesh_topology(r.mesh);
    CHECK(t.boundary_edges == 0);
    CHECK(t.nonmanifold_edges == 0);
    CHECK(t.components == 1);
    CHECK(r.holes.filled >= 1);
    REQUIRE(r.closed_volume.sdf);
    REQUIRE(r.closed_volume.fill);
    // The closed volume's surface is the mesh: meshing it gives the same enclosed volume.
    const TopologyStats back = mesh_topology(extract_mesh(r.closed_volume).mesh);
    CHECK(back.watertight());
    CHECK(back.signed_volume == Approx(t.signed_volume).epsilon(0.01));
    // The fill stays near the true surface (a smooth blob): within 1.5 voxels everywhere.
    const MeshDistance truth(blob.mesh);
    double worst = 0.0;
    for (double d : truth.distances(r.mesh.vertices.to_vector())) worst = std::max(worst, d);
    INFO("worst vertex distance " << worst / voxel << " voxels");
    CHECK(worst < 1.5 * voxel);
}

TEST_CASE("the bunny at 0.5 mm comes out watertight", "[holes][pipeline][data]") {
    const std::string scan = shared_data("stanford_bunny/bun_scans_aligned.ply");
    const std::string truth = shared_data("stanford_bunny/bun_zipper_gt.ply");
    if (scan.empty() || truth.empty()) return;
    PipelineOptions o;
    o.splat.voxel_size = 0.0005;
    o.watertight = true;
    o.keep_volumes = false;
    const RunResult r = [&] {
        TempDir dir;
        o.write_vdb = false;
        return run(scan, dir.file("bunny.ply"), o);
    }();
    const TopologyStats t = mesh_topology(r.result.mesh);
    CHECK(t.boundary_edges == 0);
    CHECK(t.nonmanifold_edges == 0);
    CHECK(t.components == 1);
    EvalOptions e;
    e.taus = {0.0005};
    const Mesh reference = read_mesh(truth);
    const EvalResult f = evaluate(r.result.mesh, reference, e);
    // The reference mesh has five open holes underneath where the fill adds surface: precision
    // there is lost against it (0.9815 measured), recall stays. Where the reference has
    // surface to compare with, F is that of the open reconstruction.
    INFO("F " << f.fscores[0].fscore << " precision " << f.fscores[0].precision << " recall "
              << f.fscores[0].recall);
    CHECK(f.fscores[0].recall > 0.998);
    CHECK(f.fscores[0].fscore > 0.985);
    e.ignore_reference_holes = true;
    const EvalResult g = evaluate(r.result.mesh, reference, e);
    INFO("over the reference's surface: F " << g.fscores[0].fscore);
    CHECK(g.fscores[0].fscore >= 0.997);
}
