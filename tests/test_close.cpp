// Closing (close.h): holes in a sphere and a flat patch, grooves in a solid sphere, the closed
// volume file, and thread-count independence.
#include <tbb/global_control.h>

#include "support.h"
#include "support_volume.h"
#include "vdbrecon/close.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/io.h"
#include "vdbrecon/pipeline.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

constexpr double kVoxel = 0.05;

/// Removes the points whose distance from the y axis is below `radius` on the side y > 0 (a
/// sphere's north cap, a plane patch's centre when y is replaced by z below).
PointCloud without_disc(const PointCloud& c, double radius, int axis) {
    PointCloud out;
    for (std::size_t i = 0; i < c.positions.size(); ++i) {
        const Vec3f& p = c.positions[i];
        double r2 = 0.0;
        for (int a = 0; a < 3; ++a) {
            if (a != axis) r2 += double(p[a]) * p[a];
        }
        if (p[axis] >= -1e-6f && r2 < radius * radius) continue;
        out.positions.push_back(p);
        out.normals.push_back(c.normals[i]);
    }
    return out;
}

PipelineResult reconstruct_with(PointCloud cloud, int hole_radius, int solid_radius = 0) {
    PipelineOptions o;
    o.splat.voxel_size = kVoxel;
    o.close.hole_radius = hole_radius;
    o.close.solid_radius = solid_radius;
    return reconstruct(cloud, o);
}

}  // namespace

TEST_CASE("hole closing covers a sphere's missing cap 6 voxels across", "[close]") {
    // Unit sphere = 20 voxels radius; the cap hole is 6 voxels (0.3) across.
    const PointCloud holed = without_disc(sample_sphere(40000, 1.0), 0.15, 1);
    REQUIRE(holed.positions.size() < 40000);

    const PipelineResult open = reconstruct_with(holed, 0);
    REQUIRE(boundary_loops(open.mesh) == 1);  // the hole is still there without closing
    REQUIRE(open.closed_volume.empty());

    const PipelineResult closed = reconstruct_with(holed, 4);
    const TopologyStats t = mesh_topology(closed.mesh);
    CHECK(t.boundary_edges == 0);
    CHECK(t.nonmanifold_edges == 0);
    CHECK(t.components == 1);
    REQUIRE(closed.close.filled_voxels > 0);
    REQUIRE(closed.closed_volume.fill);
    // The patch over the hole lies on the true sphere within 0.5 voxel.
    std::size_t in_cap = 0;
    double worst = 0.0;
    for (const Vec3f& p : closed.mesh.vertices) {
        if (p[1] <= 0.0f || std::hypot(p[0], p[2]) >= 0.15) continue;
        ++in_cap;
        const double r = std::sqrt(double(p[0]) * p[0] + double(p[1]) * p[1] + double(p[2]) * p[2]);
        worst = std::max(worst, std::fabs(r - 1.0));
    }
    INFO("cap vertices " << in_cap << ", worst radial error " << worst / kVoxel << " voxels");
    CHECK(in_cap > 20);
    CHECK(worst < 0.5 * kVoxel);
}

TEST_CASE("hole closing fills a hole in a flat patch and keeps its outer border", "[close]") {
    // 2 x 2 patch (40 voxels), hole 6 voxels across in the middle.
    const PointCloud holed = without_disc(sample_plane(200, 1.0), 0.15, 2);
    const PipelineResult open = reconstruct_with(holed, 0);
    const std::vector<double> before = boundary_loop_lengths(open.mesh);
    REQUIRE(before.size() == 2);  // outer border and hole
    REQUIRE(before[1] > 0.0);

    const PipelineResult closed = reconstruct_with(holed, 4);
    const std::vector<double> after = boundary_loop_lengths(closed.mesh);
    REQUIRE(after.size() == 1);  // only the outer border is left
    INFO("outer border " << before[0] << " -> " << after[0]);
    CHECK(std::fabs(after[0] - before[0]) < 0.05 * before[0]);
    // The filled patch is flat: every vertex stays on z = 0.
    for (const Vec3f& p : closed.mesh.vertices) REQUIRE(std::fabs(p[2]) < 0.1 * kVoxel);
}

TEST_CASE("solid closing removes grooves 2 voxels wide and 8 deep, the rest stays", "[close]") {
    const double voxel = kVoxel, radius = 1.0, half_width = 1.0 * voxel, depth = 8 * voxel;
    // Sphere minus two grooves (around the equator z = 0 and the meridian x = 0).
    auto groove = [&](double across, const openvdb::Vec3d& p) {
        return std::max(std::fabs(across) - half_width, (radius - depth) - p.length());
    };
    const Field grooved = [&](const openvdb::Vec3d& p) {
        return std::max(p.length() - radius, -std::min(groove(p[2], p), groove(p[0], p)));
    };
    const Volume v = analytic_volume(grooved, radius + 0.3, voxel);
    const double sphere_volume = 4.0 / 3.0 * M_PI * radius * radius * radius;

    CloseOptions o;
    const Mesh as_is = extract_mesh(v).mesh;
    const double grooved_volume = mesh_topology(as_is).signed_volume;
    INFO("grooved volume " << grooved_volume / sphere_volume);
    REQUIRE(grooved_volume < 0.96 * sphere_volume);  // the grooves are there to close

    o.solid_radius = 3;
    const CloseResult c = close_volume(v, o);
    const Mesh m = extract_mesh(c.volume).mesh;
    const TopologyStats t = mesh_topology(m);
    INFO("closed volume " << t.signed_volume / sphere_volume << ", inside voxels " << c.solid_voxels_before << " -> " << c.solid_voxels_after << " of " << sphere_volume / (voxel * voxel * voxel));
    CHECK(t.watertight());
    CHECK(t.signed_volume == Approx(sphere_volume).epsilon(0.02));
    CHECK(c.solid_voxels_after > c.solid_voxels_before);
    // Away from the grooves the surface has not moved: within 0.25 voxel of the sphere.
    double worst = 0.0;
    for (const Vec3f& p : m.vertices) {
        if (std::fabs(p[0]) < 6 * voxel || std::fabs(p[2]) < 6 * voxel) continue;
        const double r = std::sqrt(double(p[0]) * p[0] + double(p[1]) * p[1] + double(p[2]) * p[2]);
        worst = std::max(worst, std::fabs(r - radius));
    }
    INFO("worst radial error away from the grooves " << worst / voxel << " voxels");
    CHECK(worst < 0.25 * voxel);
}

TEST_CASE("solid closing refuses an open surface with a hint", "[close]") {
    PointCloud c = without_disc(sample_sphere(40000, 1.0), 0.15, 1);
    PipelineOptions o;
    o.splat.voxel_size = kVoxel;
    o.close.solid_radius = 2;
    REQUIRE_THROWS_WITH(reconstruct(c, o), Catch::Contains("--close R"));
    o.close.hole_radius = 4;  // holes first, then the solid closing has a closed surface
    const PipelineResult r = reconstruct(c, o);
    CHECK(mesh_topology(r.mesh).watertight());
}

TEST_CASE("close options are validated", "[close]") {
    CloseOptions o;
    o.hole_radius = -1;
    REQUIRE_THROWS_AS(o.validate(), InvalidArgument);
    o.hole_radius = 65;
    REQUIRE_THROWS_AS(o.validate(), InvalidArgument);
    o.hole_radius = 0;
    o.solid_radius = 100;
    REQUIRE_THROWS_AS(o.validate(), InvalidArgument);
}

TEST_CASE("closed volume file: same grids, byte-identical for 1 and 2 threads", "[close]") {
    TempDir dir;
    write_points(dir.file("in.ply"), without_disc(sample_sphere(40000, 1.0), 0.15, 1));
    PipelineOptions o;
    o.splat.voxel_size = kVoxel;
    o.close.hole_radius = 4;
    o.close.solid_radius = 2;
    o.threads = 1;
    const RunResult a = run(dir.file("in.ply"), dir.file("a.ply"), o);
    o.threads = 2;
    const RunResult b = run(dir.file("in.ply"), dir.file("b.ply"), o);
    REQUIRE(a.closed_vdb_path == dir.file("a.closed.vdb"));
    REQUIRE(read_bytes(dir.file("a.ply")) == read_bytes(dir.file("b.ply")));
    REQUIRE(read_bytes(dir.file("a.closed.vdb")) == read_bytes(dir.file("b.closed.vdb")));
    REQUIRE(read_bytes(dir.file("a.splat.vdb")) == read_bytes(dir.file("b.splat.vdb")));

    const Volume v = read_volume(a.closed_vdb_path);
    REQUIRE(v.sdf->getGridClass() == openvdb::GRID_LEVEL_SET);
    REQUIRE(v.fill);
    REQUIRE(v.voxel_size == Approx(kVoxel));
    REQUIRE(v.sdf->activeVoxelCount() == a.result.closed_volume.sdf->activeVoxelCount());
    REQUIRE(v.metadata.at("close_hole_radius") == "4");
    // Meshing the file gives the same mesh as meshing the volume in memory.
    REQUIRE(extract_mesh(v).mesh.vertices == extract_mesh(a.result.closed_volume).mesh.vertices);
}
