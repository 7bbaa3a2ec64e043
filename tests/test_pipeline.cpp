#include <random>

#include "support.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/io.h"
#include "vdbrecon/knn.h"
#include "vdbrecon/normals.h"
#include "vdbrecon/outliers.h"
#include "vdbrecon/pipeline.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

TEST_CASE("file-to-file run is byte-identical for 1 and 2 threads", "[pipeline]") {
    TempDir dir;
    PointCloud c = sample_sphere(30000, 1.0);
    std::mt19937 rng(5);
    std::normal_distribution<float> noise(0.0f, 0.003f);
    for (Vec3f& p : c.positions.edit()) {
        for (float& v : p) v += noise(rng);
    }
    c.normals.clear();  // exercise normal estimation and MST orientation too
    write_points(dir.file("in.ply"), c);

    PipelineOptions o;
    o.threads = 1;
    const RunResult a = run(dir.file("in.ply"), dir.file("a.ply"), o);
    o.threads = 2;
    const RunResult b = run(dir.file("in.ply"), dir.file("b.ply"), o);
    REQUIRE(a.vdb_path == dir.file("a.splat.vdb"));
    REQUIRE(a.result.mesh.faces.size() > 10000);
    REQUIRE(read_bytes(dir.file("a.ply")) == read_bytes(dir.file("b.ply")));
    REQUIRE(read_bytes(dir.file("a.splat.vdb")) == read_bytes(dir.file("b.splat.vdb")));
    REQUIRE(mesh_topology(a.result.mesh).watertight());

    // The written volume reads back with the same grids.
    const Volume v = read_volume(a.vdb_path);
    REQUIRE(v.sdf->getGridClass() == openvdb::GRID_LEVEL_SET);
    REQUIRE(v.weight);
    REQUIRE(v.nearest);
    REQUIRE(v.voxel_size == Approx(a.result.voxel_size));
    REQUIRE(v.sdf->activeVoxelCount() == a.result.volume.sdf->activeVoxelCount());

    // The run reports the memory of the grids it wrote: the splat's and the density grid.
    const std::size_t density = std::size_t(make_density(*a.result.volume.sdf)->memUsage());
    REQUIRE(density > 0);
    REQUIRE(a.vdb_grid_bytes == a.result.volume.memory_bytes() + density);
    REQUIRE(write_volume(dir.file("c.vdb"), v) == v.memory_bytes() + density);
}

TEST_CASE("every mesher and closing mode is byte-identical for 1 and 2 threads", "[pipeline]") {
    // Issue 6 point 6: the mesh file, the splatted and the closed volume do not depend on the
    // thread count, whatever the mesher (dual, vdb, mc, dc) and closing (none, hole, solid, both).
    TempDir dir;
    write_points(dir.file("in.ply"), sample_sphere(20000, 1.0));
    for (const Mesher method : {Mesher::dual, Mesher::vdb, Mesher::mc, Mesher::dc}) {
        for (const auto& [hole, solid] : {std::pair{0, 0}, {3, 0}, {0, 2}, {3, 2}}) {
            PipelineOptions o;
            o.splat.voxel_size = 0.05;
            o.mesh.method = method;
            o.close.hole_radius = hole;
            o.close.solid_radius = solid;
            INFO("mesher " << int(method) << ", hole " << hole << ", solid " << solid);
            o.threads = 1;
            const RunResult a = run(dir.file("in.ply"), dir.file("a.ply"), o);
            o.threads = 2;
            const RunResult b = run(dir.file("in.ply"), dir.file("b.ply"), o);
            REQUIRE(a.result.mesh.faces.size() > 1000);
            REQUIRE(read_bytes(dir.file("a.ply")) == read_bytes(dir.file("b.ply")));
            REQUIRE(read_bytes(dir.file("a.splat.vdb")) == read_bytes(dir.file("b.splat.vdb")));
            REQUIRE(a.closed_vdb_path.empty() == (hole == 0 && solid == 0));
            if (!a.closed_vdb_path.empty()) {
                REQUIRE(read_bytes(a.closed_vdb_path) == read_bytes(b.closed_vdb_path));
            }
        }
    }
}

TEST_CASE("Column: borrowed memory is read in place, shared by copies, never written",
          "[pipeline]") {
    const std::vector<float> buffer = {1, 2, 3};
    auto keeper = std::make_shared<int>(0);
    Column<float> c = Column<float>::borrow(buffer.data(), buffer.size(), keeper);
    REQUIRE(c.borrowed());
    REQUIRE(c.data() == buffer.data());
    REQUIRE(keeper.use_count() == 2);
    const Column<float> copy = c;  // shares the reference
    REQUIRE(copy.data() == buffer.data());
    REQUIRE(keeper.use_count() == 3);
    c.edit()[1] = 20;  // copy on write: the buffer stays as it was
    REQUIRE(!c.borrowed());
    REQUIRE(c.data() != buffer.data());
    REQUIRE(buffer == std::vector<float>{1, 2, 3});
    REQUIRE(c.to_vector() == std::vector<float>{1, 20, 3});
    REQUIRE(keeper.use_count() == 2);
    REQUIRE(copy == Column<float>(std::vector<float>{1, 2, 3}));
    c = std::vector<float>{5};  // assignment replaces
    REQUIRE(c.size() == 1);
    REQUIRE(c[0] == 5);
    Column<float> empty = Column<float>::borrow(nullptr, 0);
    REQUIRE(empty.empty());
    REQUIRE(empty.begin() == empty.end());
}

TEST_CASE("a cloud borrowing the caller's arrays reconstructs like an owned one, untouched",
          "[pipeline]") {
    PointCloud owned = sample_sphere(20000, 1.0);
    owned.normals = std::vector<Vec3f>();  // normals are estimated: the stage must not write here
    const std::vector<Vec3f> positions = owned.positions.to_vector();
    PointCloud borrowed;
    borrowed.positions = Column<Vec3f>::borrow(positions.data(), positions.size());
    PipelineOptions o;
    o.splat.voxel_size = 0.05;
    PointCloud a = owned, b = borrowed;
    const PipelineResult ra = reconstruct(a, o);
    const PipelineResult rb = reconstruct(b, o);
    REQUIRE(ra.mesh.faces.size() > 1000);
    REQUIRE(ra.mesh.vertices == rb.mesh.vertices);
    REQUIRE(ra.mesh.faces == rb.mesh.faces);
    REQUIRE(positions == owned.positions.to_vector());
    REQUIRE(borrowed.positions.data() == positions.data());
    // Valid input normals pass through the normal stage without a copy.
    const std::vector<Vec3f> normals = sample_sphere(20000, 1.0).normals.to_vector();
    borrowed.normals = Column<Vec3f>::borrow(normals.data(), normals.size());
    NormalOptions no;
    no.scale = ScaleMode::none;
    const NormalResult n = estimate_normals(borrowed, no);
    REQUIRE(n.estimated == 0);
    REQUIRE(n.normals.data() == normals.data());
}

TEST_CASE("the cloud's normals, lent to the normal stage, come back to it, also when it fails",
          "[pipeline]") {
    PointCloud c = sample_sphere(3000, 1.0);
    const std::vector<Vec3f> before = c.normals.to_vector();
    const Vec3f* storage = c.normals.data();
    PipelineOptions o;
    o.splat.voxel_size = 0.1;
    o.outliers.enabled = false;
    REQUIRE(reconstruct(c, o).mesh.faces.size() > 100);
    CHECK_FALSE(c.normals.borrowed());
    CHECK(c.normals.data() == storage);  // the same array, never copied
    CHECK(c.normals.to_vector() == before);
    // One point: the stage cannot find its spacing and throws; the cloud keeps its normal.
    PointCloud one;
    one.positions = std::vector<Vec3f>{{0.0f, 0.0f, 0.0f}};
    one.normals = std::vector<Vec3f>{{0.0f, 0.0f, 1.0f}};
    REQUIRE_THROWS_AS(reconstruct(one, o), NumericalError);
    CHECK_FALSE(one.normals.borrowed());
    CHECK(one.normals.to_vector() == std::vector<Vec3f>{{0.0f, 0.0f, 1.0f}});
    // The same with the normal parked in a temporary file while the stage fails.
    o.outliers.park_bytes = 0;
    REQUIRE_THROWS_AS(reconstruct(one, o), NumericalError);
    CHECK(one.normals.to_vector() == std::vector<Vec3f>{{0.0f, 0.0f, 1.0f}});
}

TEST_CASE("the scales alone, searched with the normals parked, give the same mesh", "[pipeline]") {
    PointCloud c = sample_sphere(5000, 1.0);
    for (std::size_t i = 0; i < c.size(); ++i) {
        c.colors.push_back({float(i % 3) / 2.0f, 0.5f, 1.0f});
    }
    const NormalResult full = estimate_normals(c);
    const NormalResult alone = estimate_scales(c);
    CHECK(alone.normals.empty());
    CHECK(alone.scales == full.scales);
    CHECK(alone.density_spacing == full.density_spacing);
    PipelineOptions o;
    o.splat.voxel_size = 0.1;
    o.outliers.enabled = false;  // the normal stage searches the scales itself
    PointCloud kept = c, parked = c;
    const PipelineResult a = reconstruct(kept, o);
    o.outliers.park_bytes = 0;  // always park
    const PipelineResult b = reconstruct(parked, o);
    REQUIRE(a.mesh.faces.size() > 100);
    CHECK(a.mesh.vertices == b.mesh.vertices);
    CHECK(a.mesh.faces == b.mesh.faces);
    CHECK(a.mesh.colors == b.mesh.colors);
    CHECK(parked.normals == c.normals);  // back in the caller's cloud
    CHECK(parked.colors == c.colors);
}

TEST_CASE("a lean run (volumes not kept, cloud given up) makes the same mesh", "[pipeline]") {
    // What the CLI does to lower its peak memory: the volumes are freed once meshed and written
    // (keep_volumes = false), the cloud after the splat (reconstruct(PointCloud&&)).
    PointCloud c = sample_sphere(20000, 1.0);
    PipelineOptions o;
    o.splat.voxel_size = 0.03;
    std::vector<std::string> handed;
    const VolumeCallback seen = [&](const std::string& stage, const Volume& v) {
        REQUIRE(v.sdf);  // alive while the callback runs
        handed.push_back(stage);
    };
    PointCloud copy = c;
    const PipelineResult kept = reconstruct(c, o);
    o.keep_volumes = false;
    const PipelineResult lean = reconstruct(std::move(copy), o, {}, seen);
    REQUIRE(handed == std::vector<std::string>{"splat"});
    REQUIRE(copy.empty());
    REQUIRE(!lean.volume.sdf);
    REQUIRE(!lean.closed_volume.sdf);
    REQUIRE(kept.volume.sdf);
    REQUIRE(lean.splat.memory_bytes == kept.volume.memory_bytes());
    REQUIRE(lean.mesh.vertices == kept.mesh.vertices);
    REQUIRE(lean.mesh.faces == kept.mesh.faces);
    REQUIRE((!c.empty() && c.has_scales()));  // the lvalue overload hands the cloud back
}

TEST_CASE("automatic voxel follows the spacing; --no-vdb writes only the mesh", "[pipeline]") {
    TempDir dir;
    write_points(dir.file("s.ply"), sample_sphere(20000, 1.0));
    PipelineOptions o;
    o.write_vdb = false;
    const RunResult r = run(dir.file("s.ply"), dir.file("m.obj"), o);
    REQUIRE(r.result.voxel_chosen);
    REQUIRE(r.result.spacing == r.result.outliers.density_spacing);
    REQUIRE(r.result.voxel_size == Approx(o.auto_voxel_factor * r.result.spacing));
    REQUIRE(r.vdb_path.empty());
    REQUIRE(count_files(dir.path()) == 2);  // input + mesh, nothing else
    REQUIRE(read_mesh(dir.file("m.obj")).faces.size() == r.result.mesh.faces.size());
}

namespace {

/// `n` x `n` points of the plane z = 0 on a square raster of pitch h (normal +z), or, with a
/// seed, as many uniform random points over the same square: the same density, 1 / h^2.
PointCloud plane_samples(int n, double h, unsigned seed = 0) {
    PointCloud c;
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0.0, h * n);
    for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
            c.positions.push_back(seed == 0 ? Vec3f{float(h * i), float(h * j), 0.0f}
                                            : Vec3f{float(u(rng)), float(u(rng)), 0.0f});
            c.normals.push_back({0.0f, 0.0f, 1.0f});
        }
    }
    return c;
}

/// A random `fraction` of the points (with their normals).
PointCloud random_subset(const PointCloud& c, double fraction, unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    PointCloud s;
    for (std::size_t i = 0; i < c.size(); ++i) {
        if (u(rng) >= fraction) continue;
        s.positions.push_back(c.positions[i]);
        s.normals.push_back(c.normals[i]);
    }
    return s;
}

}  // namespace

TEST_CASE("automatic voxel: the sample density decides it, not how regular the sampling is",
          "[pipeline]") {
    // The same density as a raster, as random points, and a random tenth of the raster (a
    // tenth of the density): the voxel must follow the density alone, so the tenth's is
    // sqrt(10) times the raster's. The mean distance to the k nearest, the voxel's source
    // before, gave the tenth only 2.84x the raster's (random points cluster).
    const double h = 0.01;
    const PointCloud raster = plane_samples(300, h), random = plane_samples(300, h, 3);
    const PointCloud tenth = random_subset(raster, 0.1, 4);
    OutlierOptions o;
    const double s_raster = remove_outliers(raster, o).density_spacing;
    const double s_random = remove_outliers(random, o).density_spacing;
    const double s_tenth = remove_outliers(tenth, o).density_spacing;
    CHECK(s_raster == Approx(h).epsilon(0.03));
    CHECK(s_random == Approx(h).epsilon(0.03));
    CHECK(s_tenth / s_raster == Approx(std::sqrt(10.0)).epsilon(0.03));

    // Without the outlier stage, the normal stage measures it from its own neighbours (k = 10):
    // exact for random points; on a raster its tenth neighbour sits on a shell edge (12 % high).
    PipelineOptions p;
    p.outliers.enabled = false;
    p.write_vdb = false;
    const PipelineResult r = reconstruct(random_subset(random, 0.25, 5), p);
    REQUIRE(r.voxel_chosen);
    CHECK(r.outliers.density_spacing == 0.0);
    CHECK(r.spacing == r.normals.density_spacing);
    CHECK(r.spacing == Approx(2.0 * h).epsilon(0.03));
    CHECK(r.voxel_size == Approx(p.auto_voxel_factor * r.spacing));
}

TEST_CASE("run refuses to overwrite its input and reports bad paths", "[pipeline]") {
    TempDir dir;
    write_points(dir.file("s.ply"), sample_sphere(2000, 1.0));
    const std::string before = read_bytes(dir.file("s.ply"));
    REQUIRE_THROWS_AS(run(dir.file("s.ply"), dir.file("s.ply"), {}), InvalidArgument);
    REQUIRE(read_bytes(dir.file("s.ply")) == before);
    REQUIRE_THROWS_AS(run(dir.file("s.ply"), dir.file("out.stl"), {}), InvalidArgument);
    REQUIRE_THROWS_AS(run(dir.file("s.ply"), dir.file("no/such/dir/out.ply"), {}), IoError);
    REQUIRE(count_files(dir.path()) == 1);
}

TEST_CASE("stage volume paths", "[pipeline]") {
    REQUIRE(stage_volume_path("out/scan.ply", "splat") == "out/scan.splat.vdb");
    REQUIRE(stage_volume_path("a.b/scan", "closed") == "a.b/scan.closed.vdb");
}

namespace {

struct BunnyScore {
    EvalResult eval;
    PipelineResult result;
};

BunnyScore reconstruct_bunny(const std::string& scans, const std::string& gt, double voxel,
                             NormalMode normals) {
    PointCloud c = read_points(scans).cloud;
    PipelineOptions o;
    o.splat.voxel_size = voxel;
    o.normals.mode = normals;
    BunnyScore s;
    s.result = reconstruct(c, o);
    EvalOptions e;
    e.taus = {0.0005};
    e.samples = 500000;
    s.eval = evaluate(s.result.mesh, read_mesh(gt), e);
    return s;
}

}  // namespace

TEST_CASE("end to end: Stanford bunny scans against the zippered mesh", "[pipeline][data]") {
    const std::string scans = shared_data("stanford_bunny/bun_scans_aligned.ply");
    const std::string gt = shared_data("stanford_bunny/bun_zipper_gt.ply");
    if (scans.empty() || gt.empty()) return;

    SECTION("voxel 0.5 mm") {
        const BunnyScore s = reconstruct_bunny(scans, gt, 0.0005, NormalMode::automatic);
        INFO(to_json(s.eval));
        REQUIRE(s.eval.fscores[0].fscore >= 0.997);
        REQUIRE(s.eval.chamfer_l1 <= 0.00006);
        REQUIRE(s.eval.recon.nonmanifold_edges == 0);
    }
    SECTION("voxel 0.25 mm, finer than the sample spacing: the per-point scale closes it") {
        const BunnyScore s = reconstruct_bunny(scans, gt, 0.00025, NormalMode::automatic);
        INFO(to_json(s.eval));
        REQUIRE(s.eval.fscores[0].fscore >= 0.99);
    }
    SECTION("normals estimated from the points") {
        const BunnyScore s = reconstruct_bunny(scans, gt, 0.0005, NormalMode::estimate);
        INFO(to_json(s.eval));
        REQUIRE(s.eval.fscores[0].fscore >= 0.99);
    }
}

TEST_CASE("Kinect frame: every vertex lies within 2 voxels of an input point", "[pipeline][data]") {
    const std::string path = shared_data("pcl_kinect/capture0001.ply");
    if (path.empty()) return;
    PointCloud c = read_points(path).cloud;
    const std::vector<Vec3f> points = c.positions.to_vector();
    PipelineOptions o;
    o.normals.viewpoint = Vec3d{0, 0, 0};
    const PipelineResult r = reconstruct(c, o);
    REQUIRE(r.mesh.faces.size() > 100000);
    const KnnIndex index(points);
    const KnnResult nn = index.query(r.mesh.vertices, 1);
    float worst = 0.0f;
    for (float d2 : nn.sq_distances) worst = std::max(worst, d2);
    INFO("voxel " << r.voxel_size << ", farthest vertex " << std::sqrt(worst));
    REQUIRE(std::sqrt(double(worst)) <= 2.0 * r.voxel_size * (1 + 1e-5));
}
