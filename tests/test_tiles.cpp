// Tiled reconstruction (issue 24 point 1): splat > close > mesh tile by tile gives the untiled
// mesh -- the same faces on the same vertices -- for any tile size, mesher and thread count, on
// generated CAD parts (creases), smooth shapes with colours, a holed sphere closed by --close,
// and the Stanford bunny scans.
#include <fcntl.h>
#include <sys/file.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <numeric>
#include <optional>
#include <random>

#include "shapes.h"
#include "support.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/io.h"
#include "vdbrecon/log.h"
#include "vdbrecon/pipeline.h"
#include "vdbrecon/tiles.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

/// A mesh in an order of its own: vertices sorted by position, each face starting at its
/// smallest vertex (orientation kept), faces sorted.
struct Canonical {
    std::vector<Vec3f> vertices, normals, colors;
    std::vector<Triangle> faces;
};

Canonical canonical(const Mesh& m) {
    const std::size_t nv = m.vertices.size();
    std::vector<std::size_t> order(nv);
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(),
              [&](std::size_t a, std::size_t b) { return m.vertices[a] < m.vertices[b]; });
    std::vector<std::int32_t> rank(nv);
    Canonical c;
    for (std::size_t j = 0; j < nv; ++j) {
        rank[order[j]] = std::int32_t(j);
        c.vertices.push_back(m.vertices[order[j]]);
        if (!m.normals.empty()) c.normals.push_back(m.normals[order[j]]);
        if (!m.colors.empty()) c.colors.push_back(m.colors[order[j]]);
    }
    for (const Triangle& f : m.faces) {
        Triangle t{rank[std::size_t(f[0])], rank[std::size_t(f[1])], rank[std::size_t(f[2])]};
        std::rotate(t.begin(), std::min_element(t.begin(), t.end()), t.end());
        c.faces.push_back(t);
    }
    std::sort(c.faces.begin(), c.faces.end());
    return c;
}

float max_difference(const std::vector<Vec3f>& a, const std::vector<Vec3f>& b) {
    float d = 0.0f;
    for (std::size_t i = 0; i < a.size(); ++i) {
        for (int k = 0; k < 3; ++k) d = std::max(d, std::fabs(a[i][k] - b[i][k]));
    }
    return d;
}

/// The tiled mesh is the untiled one: same counts, same faces, vertices within 1e-6 voxel,
/// the same normals and colours.
void check_same_mesh(const Mesh& untiled, const Mesh& tiled, double voxel) {
    REQUIRE(untiled.faces.size() > 0);
    REQUIRE(tiled.vertices.size() == untiled.vertices.size());
    REQUIRE(tiled.faces.size() == untiled.faces.size());
    const Canonical a = canonical(untiled), b = canonical(tiled);
    CHECK(max_difference(a.vertices, b.vertices) <= 1e-6 * voxel);
    CHECK(a.faces == b.faces);
    REQUIRE(a.normals.size() == b.normals.size());
    CHECK(max_difference(a.normals, b.normals) <= 1e-6f);
    REQUIRE(a.colors.size() == b.colors.size());
    CHECK(max_difference(a.colors, b.colors) <= 1e-6f);
}

/// reconstruct() on a copy (it removes the outliers from the cloud it is given and fills in
/// normals and scales).
PipelineResult run_on(PointCloud cloud, const PipelineOptions& o) { return reconstruct(cloud, o); }

PipelineOptions options_at(double voxel, Mesher mesher, int tile) {
    PipelineOptions o;
    o.splat.voxel_size = voxel;
    o.mesh.method = mesher;
    o.tile = tile;
    return o;
}

}  // namespace

TEST_CASE("tiles give the untiled mesh on CAD parts and smooth shapes with every mesher", "[tiles]") {
    constexpr std::size_t kPoints = 12000;
    // Tile edges 8 (every kernel crosses tiles) to 40, voxels of 1x and 2x the spacing.
    const struct {
        const char* shape;
        Mesher mesher;
        double factor;
        int tile;
    } cases[] = {{"cube", Mesher::dc, 1.0, 32},    {"fan", Mesher::dc, 1.0, 40},
                 {"lbracket", Mesher::mc, 2.0, 8}, {"torus", Mesher::mc, 1.0, 24},
                 {"blob", Mesher::dual, 1.0, 40},  {"boss", Mesher::dual, 1.0, 16},
                 {"drilled", Mesher::vdb, 2.0, 16}};
    for (const auto& c : cases) {
        const Shape shape = make_shape(c.shape);
        PointCloud sample = sample_uniform(shape.mesh, kPoints, 11);
        // Colours, to follow them through the tiles.
        std::vector<Vec3f>& colors = sample.colors.edit();
        for (std::size_t i = 0; i < sample.size(); ++i) {
            const Vec3f& p = sample.positions[i];
            colors.push_back({0.5f + 0.5f * p[0], 0.5f + 0.5f * p[1], 0.5f + 0.5f * p[2]});
        }
        const double voxel = c.factor * spacing_of(shape.area, kPoints);
        INFO(c.shape << ", tile " << c.tile << ", voxel " << c.factor << "x the spacing");
        const PipelineResult whole = run_on(sample, options_at(voxel, c.mesher, 0));
        const PipelineResult tiled = run_on(sample, options_at(voxel, c.mesher, c.tile));
        CHECK(tiled.tiles > 1);
        CHECK(tiled.tile == (c.tile + 7) / 8 * 8);
        check_same_mesh(whole.mesh, tiled.mesh, voxel);
        if (shape.cad) CHECK(whole.splat.crease_voxels > 0);  // the crease model was at work
    }
}

TEST_CASE("tiles presum whole cells: wide presumming cells and samples beyond their range too",
          "[tiles][aggregate]") {
    // Cells of up to 3 voxels (a cell's samples reach into several tiles) and of the default
    // cap, and a patch of samples 2^19 cells or more from the origin, splat each on its own.
    const Shape shape = make_shape("boss");
    PointCloud sample = sample_uniform(shape.mesh, 12000, 5);
    const double voxel = spacing_of(shape.area, 12000);
    PointCloud far = sample_uniform(make_shape("cube").mesh, 400, 6);
    for (std::size_t i = 0; i < far.size(); ++i) {
        const Vec3f& p = far.positions[i];  // a cube a few voxels wide
        const float k = float(10.0 * voxel);
        sample.positions.push_back({k * p[0] + float(voxel * 1.3e6), k * p[1], k * p[2]});
        sample.normals.push_back(far.normals[i]);
    }
    for (const auto& [aggregate, cap] : {std::pair{2.0, 3.0}, std::pair{1.5, 1.25}}) {
        INFO("cells of " << aggregate << " sigmas, cap " << cap << ", tiles of 16 voxels");
        PipelineOptions o = options_at(voxel, Mesher::dual, 0);
        o.outliers.enabled = false;  // the far patch stays
        o.splat.aggregate = aggregate;
        o.splat.aggregate_max_cell = cap;
        const PipelineResult whole = run_on(sample, o);
        CHECK(whole.splat.points < whole.splat.samples);
        o.tile = 16;
        const PipelineResult tiled = run_on(sample, o);
        CHECK(tiled.tiles > 1);
        check_same_mesh(whole.mesh, tiled.mesh, voxel);
    }
}

TEST_CASE("tiles with hole closing give the untiled mesh", "[tiles][close]") {
    PointCloud sample = sample_sphere(8000, 1.0);
    punch_holes(sample, 4, 0.1, 5);
    const double voxel = 0.05;  // holes 4 voxels across
    for (const Mesher m : {Mesher::dual, Mesher::vdb, Mesher::dc}) {
        PipelineOptions o = options_at(voxel, m, 0);
        o.close.hole_radius = 2;
        const PipelineResult whole = run_on(sample, o);
        o.tile = 24;
        const PipelineResult tiled = run_on(sample, o);
        CHECK(whole.close.filled_voxels > 0);
        check_same_mesh(whole.mesh, tiled.mesh, voxel);
    }
}

TEST_CASE("tiled meshes do not depend on the thread count", "[tiles]") {
    const Shape shape = make_shape("boss");
    const PointCloud sample = sample_uniform(shape.mesh, 10000, 2);
    PipelineOptions o = options_at(spacing_of(shape.area, 10000), Mesher::dc, 24);
    o.threads = 1;
    const PipelineResult one = run_on(sample, o);
    o.threads = 2;
    const PipelineResult two = run_on(sample, o);
    REQUIRE(one.mesh.vertices.size() == two.mesh.vertices.size());
    REQUIRE(one.mesh.faces.size() == two.mesh.faces.size());
    CHECK(std::equal(one.mesh.vertices.begin(), one.mesh.vertices.end(), two.mesh.vertices.begin()));
    CHECK(std::equal(one.mesh.faces.begin(), one.mesh.faces.end(), two.mesh.faces.begin()));
}

TEST_CASE("tiles: estimated normals and outlier removal run on the whole cloud", "[tiles]") {
    PointCloud sample = sample_sphere(20000, 1.0);
    sample.normals.clear();
    // Strays around the sphere for the outlier stage.
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(-1.5f, 1.5f);
    std::vector<Vec3f>& p = sample.positions.edit();
    for (int i = 0; i < 200; ++i) p.push_back({u(rng), u(rng), u(rng)});
    PipelineOptions o = options_at(0.04, Mesher::dual, 0);
    const PipelineResult whole = run_on(sample, o);
    o.tile = 16;
    const PipelineResult tiled = run_on(sample, o);
    CHECK(tiled.outliers.statistical + tiled.outliers.planarity ==
          whole.outliers.statistical + whole.outliers.planarity);
    check_same_mesh(whole.mesh, tiled.mesh, 0.04);
}

TEST_CASE("tiles are refused with a solid closing and out of range", "[tiles]") {
    PointCloud sample = sample_sphere(2000, 1.0);
    PipelineOptions o = options_at(0.1, Mesher::dual, 16);
    o.close.solid_radius = 2;
    CHECK_THROWS_AS(run_on(sample, o), InvalidArgument);
    o.close.solid_radius = 0;
    o.tile = -2;
    CHECK_THROWS_AS(run_on(sample, o), InvalidArgument);
}

TEST_CASE("tiles: no temporary directory for the pieces is a clear error", "[tiles]") {
    const PointCloud sample = sample_sphere(4000, 1.0);
    const ScopedEnv tmpdir("TMPDIR", "/nonexistent-vdbrecon-dir");
    try {
        run_on(sample, options_at(0.1, Mesher::mc, 16));
        FAIL("no error");
    } catch (const IoError& e) {
        CHECK(std::string(e.what()).find("/nonexistent-vdbrecon-dir") != std::string::npos);
    }
}

TEST_CASE("bunny scans: tiles of 48 voxels give the untiled mesh", "[tiles][data]") {
    const std::string path = shared_data("stanford_bunny/bun_scans_aligned.ply");
    if (path.empty()) return;
    PipelineOptions o = options_at(0.001, Mesher::dual, 0);
    ReadResult read = read_points(path);
    const PipelineResult whole = run_on(read.cloud, o);
    o.tile = 48;
    const PipelineResult tiled = run_on(read.cloud, o);
    CHECK(tiled.tiles >= 8);
    check_same_mesh(whole.mesh, tiled.mesh, 0.001);
}

TEST_CASE("tile auto fits the memory budget that refuses the untiled run", "[tiles]") {
    const PointCloud sample = sample_sphere(20000, 1.0);
    PipelineOptions o = options_at(0.01, Mesher::dual, 0);  // 200 voxels across
    o.splat.max_memory = std::size_t(100) << 20;
    o.auto_tile = false;  // --tile 0: refuse, do not tile
    try {
        run_on(sample, o);
        FAIL("the untiled run fitted the budget");
    } catch (const InvalidArgument& e) {
        CHECK(std::string(e.what()).find("--tile auto") != std::string::npos);
    }
    o.auto_tile = true;
    o.tile = -1;
    const PipelineResult tiled = run_on(sample, o);
    CHECK(tiled.tile >= 32);
    CHECK(tiled.tile % 8 == 0);
    CHECK(tiled.tiles > 1);
    CHECK(tiled.auto_tiled.empty());  // asked for
    // No --tile at all: over the budget the run tiles itself, as --tile auto, and says why.
    o.tile = 0;
    const PipelineResult itself = run_on(sample, o);
    CHECK(itself.tile == tiled.tile);
    CHECK_THAT(itself.auto_tiled, Catch::Contains("more than the budget"));
    check_same_mesh(itself.mesh, tiled.mesh, 0.0);
    o.splat.max_memory = 0;
    const PipelineResult whole = run_on(sample, o);
    CHECK(whole.tile == 0);
    CHECK(whole.auto_tiled.empty());
    check_same_mesh(whole.mesh, tiled.mesh, 0.01);
}

TEST_CASE("a file whose points would not fit the memory budget tiles itself before reading",
          "[tiles][cli]") {
    TempDir dir;
    PointCloud bare = sample_sphere(100000, 1.0);
    bare.normals.clear();
    write_points(dir.file("in.ply"), bare);
    PipelineOptions o = options_at(0.05, Mesher::dual, 0);
    // The file is 1.2 MB: its points take about six times that in memory with the neighbour
    // lists for their normals, more than half of 12 MB.
    o.splat.max_memory = std::size_t(12) << 20;
    const RunResult r = run(dir.file("in.ply"), dir.file("out.ply"), o);
    CHECK(r.result.tile > 0);
    CHECK_THAT(r.result.auto_tiled, Catch::Contains("over half of --max-memory"));
    CHECK(r.vdb_path.empty());  // no stage volume was whole
    CHECK_FALSE(file_exists(dir.file("out.splat.vdb")));
    o.splat.max_memory = 0;
    o.write_vdb = false;
    const RunResult whole = run(dir.file("in.ply"), dir.file("whole.ply"), o);
    CHECK(whole.result.tile == 0);
    check_same_mesh(whole.result.mesh, r.result.mesh, 0.01);
    o.splat.max_memory = std::size_t(1) << 20;
    o.auto_tile = false;  // --tile 0: refused as before (a budget this small fits no volume)
    CHECK_THROWS_AS(run(dir.file("in.ply"), dir.file("refused.ply"), o), InvalidArgument);
}

TEST_CASE("tile jobs: prepared, run in any order and finished give the bytes of run --tile", "[tiles]") {
    TempDir dir;
    const Shape shape = make_shape("boss");
    write_points(dir.file("in.ply"), sample_uniform(shape.mesh, 12000, 4));
    PipelineOptions o;
    o.tile = 32;
    o.close.hole_radius = 1;
    o.mesh.method = Mesher::dc;
    o.write_vdb = false;
    const RunResult whole = run(dir.file("in.ply"), dir.file("run.ply"), o);
    REQUIRE(::mkdir(dir.file("job").c_str(), 0755) == 0);
    const TileJob job = prepare_tiles(dir.file("in.ply"), dir.file("job"), o);
    CHECK(job.tiles > 4);
    CHECK(job.tile == 32);
    CHECK(job.voxel_size == whole.result.voxel_size);
    std::vector<std::string> pieces(job.tiles);
    for (std::size_t i = job.tiles; i-- > 0;) pieces[i] = run_tile(dir.file("job"), i, o);
    const RunResult finished = finish_tiles(dir.file("in.ply"), dir.file("job.ply"),
                                            dir.file("job"), pieces, o);
    CHECK(finished.result.tiles == whole.result.tiles);
    CHECK(read_bytes(dir.file("job.ply")) == read_bytes(dir.file("run.ply")));

    // Options that would cut other halos, a piece out of place or cut short: refused.
    PipelineOptions other = o;
    other.close.hole_radius = 3;
    CHECK_THROWS_AS(run_tile(dir.file("job"), 0, other), InvalidArgument);
    CHECK_THROWS_AS(run_tile(dir.file("job"), job.tiles, o), InvalidArgument);
    std::vector<std::string> bad = pieces;
    std::swap(bad[0], bad[1]);
    CHECK_THROWS_AS(finish_tiles(dir.file("in.ply"), dir.file("bad.ply"), dir.file("job"), bad, o),
                    InvalidArgument);
    bad = pieces;
    bad[0].resize(bad[0].size() / 2);
    CHECK_THROWS_AS(finish_tiles(dir.file("in.ply"), dir.file("bad.ply"), dir.file("job"), bad, o),
                    FormatError);
    CHECK_FALSE(file_exists(dir.file("bad.ply")));
}

TEST_CASE("tiles: planes and decimation after the tiles give the untiled mesh too", "[tiles]") {
    const Shape shape = make_shape("lbracket");
    const PointCloud sample = sample_uniform(shape.mesh, 15000, 6);
    const double voxel = spacing_of(shape.area, 15000);
    PipelineOptions o = options_at(voxel, Mesher::dc, 0);
    for (const int variant : {0, 1, 2}) {
        INFO("variant " << variant);
        o.tile = 0;
        o.planes.enabled = variant != 1;  // collapses of no cost everywhere inside the regions
        o.decimate.ratio = variant != 0 ? 0.5 : 1.0;
        const PipelineResult whole = run_on(sample, o);
        o.tile = 24;
        const PipelineResult tiled = run_on(sample, o);
        if (o.planes.enabled) CHECK(whole.planes.planes.size() == 8);
        check_same_mesh(whole.mesh, tiled.mesh, voxel);
    }
}

namespace {

/// A random unit vector.
Vec3f random_direction(std::mt19937& rng) {
    std::normal_distribution<double> g(0.0, 1.0);
    const double x = g(rng), y = g(rng), z = g(rng);
    const double len = std::max(1e-9, std::sqrt(x * x + y * y + z * z));
    return {float(x / len), float(y / len), float(z / len)};
}

/// A cloud a tiled run streams (its points read a chunk at a time, the point stages run a
/// region at a time): a sphere and a plane below it sampled at random with exact normals, a
/// sparse plane above, strays in the volume around them, a tight cluster of strays (the
/// planarity rule's), exact copies of surface points, all shuffled. With `scales`, a per-point
/// scale of which every tenth is 0 (unknown: the kNN scale replaces it).
PointCloud streamable_cloud(std::uint32_t seed, bool scales) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(-1.6f, 1.6f);
    std::normal_distribution<float> g(0.0f, 1.0f);
    std::vector<Vec3f> p, n;
    for (int i = 0; i < 30000; ++i) {
        const Vec3f d = random_direction(rng);
        p.push_back(d);
        n.push_back(d);
    }
    for (int i = 0; i < 10000; ++i) {
        p.push_back({u(rng), u(rng), -1.3f});
        n.push_back({0.0f, 0.0f, 1.0f});
    }
    for (int i = 0; i < 400; ++i) {
        p.push_back({u(rng), u(rng), u(rng)});
        n.push_back(random_direction(rng));
    }
    for (int i = 0; i < 20; ++i) {  // a sparse plane: its neighbours are about a cell away
        p.push_back({u(rng), u(rng), 2.5f});
        n.push_back({0.0f, 0.0f, 1.0f});
    }
    for (int i = 0; i < 40; ++i) {
        p.push_back({1.3f + 0.02f * g(rng), 1.3f + 0.02f * g(rng), 1.3f + 0.02f * g(rng)});
        n.push_back({1.0f, 0.0f, 0.0f});
    }
    for (int i = 0; i < 300; ++i) {
        const std::size_t j = std::size_t(rng()) % 40000;
        p.push_back(p[j]);
        n.push_back(n[j]);
    }
    std::vector<std::size_t> order(p.size());
    std::iota(order.begin(), order.end(), std::size_t(0));
    std::shuffle(order.begin(), order.end(), rng);
    PointCloud out;
    for (std::size_t i : order) {
        out.positions.push_back(p[i]);
        out.normals.push_back(n[i]);
    }
    if (scales) {
        std::vector<float> s(out.size());
        for (std::size_t i = 0; i < s.size(); ++i) {
            s[i] = i % 10 == 0 ? 0.0f : 0.01f + 0.001f * float(i % 7);
        }
        out.scales = std::move(s);
    }
    return out;
}

}  // namespace

TEST_CASE("streamed tiles: outliers, scales and the voxel a region at a time give the untiled mesh",
          "[tiles][stream]") {
    TempDir dir;
    struct Case {
        const char* name;
        bool outliers, scales;
        ScaleMode scale;
        double voxel;
    };
    for (const Case& k : {Case{"defaults", true, false, ScaleMode::automatic, 0.03},
                          Case{"no outliers", false, false, ScaleMode::automatic, 0.03},
                          Case{"file scales", true, true, ScaleMode::automatic, 0.03},
                          Case{"file scales, no outliers", false, true, ScaleMode::automatic, 0.03},
                          Case{"knn scales over the file's", true, true, ScaleMode::knn, 0.03},
                          Case{"no scales", true, true, ScaleMode::none, 0.03},
                          Case{"automatic voxel", true, false, ScaleMode::automatic, 0.0}}) {
        INFO(k.name);
        write_points(dir.file("in.ply"), streamable_cloud(7, k.scales));
        PipelineOptions o;
        o.write_vdb = false;
        o.outliers.enabled = k.outliers;
        o.normals.scale = k.scale;
        o.splat.voxel_size = k.voxel;
        const RunResult whole = run(dir.file("in.ply"), dir.file("whole.ply"), o);
        CHECK(whole.result.stream_units == 0);
        o.tile = 48;
        const RunResult fits = run(dir.file("in.ply"), dir.file("fits.ply"), o);
        CHECK(fits.result.stream_units == 0);  // automatic: the points fit in memory
        o.stream = StreamMode::always;
        const RunResult tiled = run(dir.file("in.ply"), dir.file("tiled.ply"), o);
        CHECK(read_bytes(dir.file("fits.ply")) == read_bytes(dir.file("tiled.ply")));
        CHECK(tiled.result.tiles > 1);
        CHECK(tiled.result.stream_units >= 8);  // regions, each with its halo
        CHECK(tiled.result.stream_largest < 41040);
        CHECK(tiled.result.outliers.statistical == whole.result.outliers.statistical);
        CHECK(tiled.result.outliers.planarity == whole.result.outliers.planarity);
        CHECK(tiled.result.voxel_size == whole.result.voxel_size);
        if (k.outliers) CHECK(whole.result.outliers.planarity > 10);
        check_same_mesh(read_mesh(dir.file("whole.ply")), read_mesh(dir.file("tiled.ply")),
                        whole.result.voxel_size);
    }
    // Any thread count: the same bytes.
    PipelineOptions o;
    o.write_vdb = false;
    o.splat.voxel_size = 0.03;
    o.tile = 48;
    o.stream = StreamMode::always;
    o.threads = 1;
    run(dir.file("in.ply"), dir.file("one.ply"), o);
    o.threads = 2;
    run(dir.file("in.ply"), dir.file("two.ply"), o);
    CHECK(read_bytes(dir.file("one.ply")) == read_bytes(dir.file("two.ply")));
}

TEST_CASE("streamed tiles: points without normals are read whole, and still tiled exactly",
          "[tiles][stream]") {
    TempDir dir;
    PointCloud c = streamable_cloud(3, false);
    c.normals.clear();
    write_points(dir.file("in.ply"), c);
    PipelineOptions o;
    o.write_vdb = false;
    o.splat.voxel_size = 0.04;
    run(dir.file("in.ply"), dir.file("whole.ply"), o);
    o.tile = 48;
    o.stream = StreamMode::always;
    const RunResult tiled = run(dir.file("in.ply"), dir.file("tiled.ply"), o);
    CHECK(tiled.result.stream_units == 0);  // the orientation of estimated normals spans the cloud
    CHECK(tiled.result.tiles > 1);
    check_same_mesh(read_mesh(dir.file("whole.ply")), read_mesh(dir.file("tiled.ply")), 0.04);
}

namespace {

/// The samples of a tile job (every bucket's, by their row in the cloud): the columns its
/// tiles splat. Reads the layout of tile_jobs.cpp: a tag, then sections of arrays, each a
/// 64-bit length and the values.
PointCloud job_samples(const std::string& dir, std::size_t buckets) {
    std::vector<std::pair<std::uint32_t, std::size_t>> rows;
    std::vector<Vec3f> p, n;
    std::vector<float> s;
    for (std::size_t j = 0; j < buckets; ++j) {
        const std::string bytes = read_bytes(dir + "/bucket-" + std::to_string(j) + ".bin");
        std::size_t at = 8;
        const auto array = [&](auto& out) {
            using T = typename std::decay_t<decltype(out)>::value_type;
            std::uint64_t len = 0;
            std::memcpy(&len, bytes.data() + at, 8);
            at += 8;
            const std::size_t first = out.size();
            out.resize(first + len);
            std::memcpy(out.data() + first, bytes.data() + at, len * sizeof(T));
            at += len * sizeof(T);
        };
        while (at < bytes.size()) {
            std::vector<std::uint32_t> index;
            std::vector<Vec3f> colors;
            std::vector<float> confidences;
            array(index);
            for (std::uint32_t i : index) rows.push_back({i, rows.size()});
            array(p);
            array(n);
            array(s);
            array(colors);
            array(confidences);
        }
    }
    std::sort(rows.begin(), rows.end());
    PointCloud c;
    for (const auto& r : rows) {
        c.positions.push_back(p[r.second]);
        c.normals.push_back(n[r.second]);
        if (!s.empty()) c.scales.push_back(s[r.second]);
    }
    return c;
}

template <typename T>
bool same_bits(const Column<T>& a, const Column<T>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0;
}

/// A streamed tile job of `input` (o.tile set) holds the samples the in-memory point stages
/// leave in the cloud, bit for bit.
void check_streamed_samples(const std::string& input, const std::string& job, PipelineOptions o) {
    o.stream = StreamMode::always;
    REQUIRE(::mkdir(job.c_str(), 0755) == 0);
    const TileJob prepared = prepare_tiles(input, job, o);
    CHECK(prepared.result.stream_units >= 8);
    std::size_t buckets = 0;
    while (file_exists(job + "/bucket-" + std::to_string(buckets) + ".bin")) ++buckets;
    const PointCloud streamed = job_samples(job, buckets);
    PointCloud whole = read_points(input).cloud;
    o.tile = 0;
    const PipelineResult r = reconstruct(whole, o);  // leaves the samples in `whole`
    CHECK(prepared.result.outliers.statistical == r.outliers.statistical);
    CHECK(prepared.result.outliers.planarity == r.outliers.planarity);
    CHECK(prepared.result.normals.estimated == r.normals.estimated);
    CHECK(prepared.result.normals.repaired == r.normals.repaired);
    CHECK(prepared.result.normals.flipped == r.normals.flipped);
    CHECK(same_bits(streamed.positions, whole.positions));
    CHECK(same_bits(streamed.normals, whole.normals));
    CHECK(same_bits(streamed.scales, whole.scales));
}

}  // namespace

TEST_CASE("streamed tiles: the job's samples are the in-memory point stages', bit for bit",
          "[tiles][stream]") {
    TempDir dir;
    for (const bool outliers : {true, false}) {
        INFO("outliers " << outliers);
        write_points(dir.file("in.ply"), streamable_cloud(11, true));
        PipelineOptions o;
        o.outliers.enabled = outliers;
        o.splat.voxel_size = 0.03;
        o.tile = 48;
        check_streamed_samples(dir.file("in.ply"), dir.file(outliers ? "job1" : "job0"), o);
    }
}

TEST_CASE("streamed tiles: the planarity test runs again when the sampled spacing was too wide",
          "[tiles][stream]") {
    // Pass 1 runs the planarity test above planarity_spacing x 0.9 x a median d sampled over
    // the cells, the median not known yet. Here the sample misses the dense patch that holds
    // most points (the true median): 100,000 points over 100 x 100, 120,000 over 0.3 x 0.3,
    // and ten scattered blobs above the patch, which only the planarity rule removes. Pass 1
    // runs again for every point, and the samples are the in-memory stages'.
    std::mt19937 rng(4);
    std::uniform_real_distribution<float> wide(-50.0f, 50.0f), patch(0.0f, 0.3f), in(0.05f, 0.25f);
    std::normal_distribution<float> g(0.0f, 0.002f);
    PointCloud c;
    const auto add = [&c](float x, float y, float z) {
        c.positions.push_back({x, y, z});
        c.normals.push_back({0.0f, 0.0f, 1.0f});
    };
    for (int i = 0; i < 100000; ++i) add(wide(rng), wide(rng), 0.0f);
    for (int i = 0; i < 120000; ++i) add(patch(rng), patch(rng), 0.0f);
    for (int b = 0; b < 10; ++b) {
        const float x = in(rng), y = in(rng);
        for (int i = 0; i < 40; ++i) add(x + g(rng), y + g(rng), 0.01f + g(rng));
    }
    TempDir dir;
    write_points(dir.file("in.ply"), c);
    bool again = false;
    const LogHandler old = set_log_handler([&again](LogLevel, const std::string& m) {
        again = again || m.find("runs again") != std::string::npos;
    });
    PipelineOptions o;
    o.splat.voxel_size = 0.5;
    o.tile = 32;
    check_streamed_samples(dir.file("in.ply"), dir.file("job"), o);
    set_log_handler(old);
    CHECK(again);
}

TEST_CASE("streamed tiles: normals estimated and oriented each on its own (--up, --viewpoint) "
          "are the in-memory stage's, bit for bit", "[tiles][stream]") {
    // The streamable cloud without normals, plus a rotated cube sampled at random: its crisp
    // edges take the wider look, which reads the lists of the neighbours too.
    PointCloud c = streamable_cloud(13, false);
    const PointCloud cube = sample_uniform(make_shape("cube").mesh, 12000, 17);
    for (std::size_t i = 0; i < cube.size(); ++i) {
        const Vec3f& q = cube.positions[i];
        c.positions.push_back({q[0] + 0.2f, q[1] - 0.3f, q[2] + 2.0f});
        c.normals.push_back(cube.normals[i]);
    }
    TempDir dir;
    struct Case {
        const char* name;
        bool normals, outliers;
        NormalMode mode;
        std::optional<Vec3d> up, viewpoint;
    };
    for (const Case& k :
         {Case{"no normals, up", false, true, NormalMode::automatic, Vec3d{0, 0, 1}, {}},
          Case{"no normals, viewpoint, no outliers", false, false, NormalMode::automatic, {},
               Vec3d{0.3, 0.2, 4.0}},
          Case{"a ninth zero, viewpoint", true, true, NormalMode::automatic, {},
               Vec3d{-0.5, 1.0, 0.5}},
          Case{"estimate over the file's, up", true, true, NormalMode::estimate,
               Vec3d{0, 1, 0}, {}}}) {
        INFO(k.name);
        PointCloud in = c;
        if (!k.normals) in.normals.clear();
        for (std::size_t i = 0; i < in.normals.size(); i += 9) in.normals.edit()[i] = {0, 0, 0};
        const std::string file = dir.file(std::string(k.name) + ".ply");
        write_points(file, in);
        PipelineOptions o;
        o.outliers.enabled = k.outliers;
        o.normals.mode = k.mode;
        o.normals.up = k.up;
        o.normals.viewpoint = k.viewpoint;
        o.splat.voxel_size = 0.03;
        o.tile = 48;
        const std::string job = dir.file(std::string(k.name) + ".job");
        check_streamed_samples(file, job, o);
        // The run: the bytes of the tiled run that reads the points whole.
        o.write_vdb = false;
        o.stream = StreamMode::always;
        const RunResult streamed = run(file, dir.file("streamed.ply"), o);
        CHECK(streamed.result.stream_units >= 8);
        CHECK(streamed.result.normals.estimated >= 5000);
        o.stream = StreamMode::never;
        run(file, dir.file("whole.ply"), o);
        CHECK(read_bytes(dir.file("streamed.ply")) == read_bytes(dir.file("whole.ply")));
    }
}

namespace {

/// A LAS 1.2 file of point format 2 (20 bytes as format 0, then 16-bit RGB) holding `p` at
/// millimetre resolution with offset (1000, 2000, 0), and their classes and colours.
void write_las(const std::string& path, const std::vector<std::array<double, 3>>& p,
               const std::vector<std::uint8_t>& cls,
               const std::vector<std::array<std::uint16_t, 3>>& rgb) {
    std::string h(227, '\0');
    const auto put = [&h](std::size_t at, const auto& v) { std::memcpy(&h[at], &v, sizeof(v)); };
    h.replace(0, 4, "LASF");
    h[24] = 1;
    h[25] = 2;
    put(94, std::uint16_t(227));
    put(96, std::uint32_t(227));
    h[104] = 2;
    put(105, std::uint16_t(26));
    put(107, std::uint32_t(p.size()));
    const double offset[3] = {1000.0, 2000.0, 0.0};
    for (std::size_t a = 0; a < 3; ++a) {
        put(131 + 8 * a, 0.001);
        put(155 + 8 * a, offset[a]);
    }
    std::string body(26 * p.size(), '\0');
    for (std::size_t i = 0; i < p.size(); ++i) {
        char* r = &body[26 * i];
        for (std::size_t a = 0; a < 3; ++a) {
            const std::int32_t v = std::int32_t(std::lround((p[i][a] - offset[a]) * 1000.0));
            std::memcpy(r + 4 * a, &v, 4);
        }
        r[14] = 0x09;  // return 1 of 1
        r[15] = char(cls[i]);
        std::memcpy(r + 20, rgb[i].data(), 6);
    }
    write_bytes(path, h + body);
}

}  // namespace

TEST_CASE("a LAS file's estimated normals face up by default, as PDAL's", "[tiles][las]") {
    // A rolling ground with a block 12 m high whose roof (no walls: rays straight down) lifts
    // the centroid: the MST's outward flux would turn the ground over.
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(0.0, 40.0);
    const std::size_t n = 12000;
    std::vector<std::array<double, 3>> p(n);
    std::vector<std::uint8_t> cls(n, 2);
    std::vector<std::array<std::uint16_t, 3>> rgb(n, {100, 100, 100});
    for (std::size_t i = 0; i < n; ++i) {
        const double x = u(rng), y = u(rng);
        const bool roof = x > 10.0 && x < 25.0 && y > 10.0 && y < 25.0;
        p[i] = {1000.0 + x, 2000.0 + y, roof ? 12.0 : 0.4 * std::sin(0.3 * x) * std::cos(0.2 * y)};
    }
    TempDir dir;
    write_las(dir.file("in.las"), p, cls, rgb);
    PipelineOptions o;
    o.write_vdb = false;
    o.splat.voxel_size = 0.6;
    auto down_share = [](const Mesh& m) {
        double down = 0.0, all = 0.0;
        for (const Triangle& t : m.faces) {
            const Vec3f& a = m.vertices[std::size_t(t[0])];
            const Vec3f& b = m.vertices[std::size_t(t[1])];
            const Vec3f& c = m.vertices[std::size_t(t[2])];
            const double nz = (double(b[0]) - a[0]) * (double(c[1]) - a[1]) -
                              (double(b[1]) - a[1]) * (double(c[0]) - a[0]);
            all += std::fabs(nz);
            if (nz < 0.0) down -= nz;
        }
        return down / all;
    };
    const RunResult r = run(dir.file("in.las"), dir.file("out.ply"), o);
    CHECK(r.result.normals.orientation == "up");
    CHECK(down_share(r.result.mesh) < 0.01);
    // Both pieces stay: the roof is no smaller piece to drop beside the ground.
    CHECK(mesh_topology(r.result.mesh).components == 2);
    // The same points as a PLY file: not LAS, so the height field is recognised instead.
    PointCloud c = read_points(dir.file("in.las")).cloud;
    write_points(dir.file("in.ply"), c);
    const RunResult ply = run(dir.file("in.ply"), dir.file("ply.ply"), o);
    CHECK(ply.result.normals.orientation == "height field");
    CHECK(down_share(ply.result.mesh) < 0.01);
}

TEST_CASE("streamed tiles: LAS and text files stream too, a chunk of rows at a time",
          "[tiles][stream]") {
    // An airborne-like tile: 1.2M random points of a rolling surface (over a chunk of 2^20
    // rows), two classes, 8-bit colours but for one 16-bit colour in the last chunk (the scale
    // of every colour depends on it).
    std::mt19937 rng(21);
    std::uniform_real_distribution<double> u(0.0, 20.0);
    const std::size_t n = 1200000;
    std::vector<std::array<double, 3>> p(n);
    std::vector<std::uint8_t> cls(n);
    std::vector<std::array<std::uint16_t, 3>> rgb(n);
    for (std::size_t i = 0; i < n; ++i) {
        const double x = 1000.0 + u(rng), y = 2000.0 + u(rng);
        p[i] = {x, y, 0.3 * std::sin(x) * std::cos(0.7 * y)};
        cls[i] = i % 3 == 0 ? 1 : 2;
        rgb[i] = {std::uint16_t(i % 256), std::uint16_t(int(x * 10.0) % 256), 77};
    }
    rgb[n - 5] = {4000, 5000, 6000};
    TempDir dir;
    write_las(dir.file("in.las"), p, cls, rgb);
    std::string text;
    for (std::size_t i = 0; i < n; ++i) {
        char line[96];
        std::snprintf(line, sizeof line, "%.3f %.3f %.3f\n", p[i][0], p[i][1], p[i][2]);
        text += line;
    }
    write_bytes(dir.file("in.xyz"), text);
    PipelineOptions o;
    o.write_vdb = false;
    o.outliers.enabled = false;
    o.normals.up = Vec3d{0, 0, 1};
    o.splat.voxel_size = 0.1;
    o.tile = 64;
    for (const std::string in : {"in.las", "in.xyz", "in.las classes"}) {
        INFO(in);
        o.read.classes.clear();
        if (in == "in.las classes") o.read.classes = {2};
        const std::string file = dir.file(in.substr(0, 6));
        o.stream = StreamMode::always;
        const RunResult streamed = run(file, dir.file("streamed.ply"), o);
        CHECK(streamed.result.stream_units >= 8);
        CHECK(streamed.result.normals.estimated == (o.read.classes.empty() ? n : n - n / 3));
        o.stream = StreamMode::never;
        run(file, dir.file("whole.ply"), o);
        CHECK(read_bytes(dir.file("streamed.ply")) == read_bytes(dir.file("whole.ply")));
    }
}

TEST_CASE("streamed tiles: lists reaching past a region's halo are searched again, wider",
          "[tiles][stream]") {
    // A plane of 400,000 random points with a hole at its centre, where the regions of the
    // point stages meet, holding 40 sparse points: their 16 nearest lie further than a cell,
    // past the halo of one cell around their region.
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> u(-10.0f, 10.0f), v(-4.0f, 4.0f);
    PointCloud c;
    while (c.size() < 400000) {
        const float x = u(rng), y = u(rng);
        if (x * x + y * y < 16.0f) continue;
        c.positions.push_back({x, y, 0.0f});
        c.normals.push_back({0.0f, 0.0f, 1.0f});
    }
    for (int i = 0; i < 40;) {
        const float x = v(rng), y = v(rng);
        if (x * x + y * y >= 16.0f) continue;
        c.positions.push_back({x, y, 0.0f});
        c.normals.push_back({0.0f, 0.0f, 1.0f});
        ++i;
    }
    TempDir dir;
    write_points(dir.file("in.ply"), c);
    PipelineOptions o;
    o.splat.voxel_size = 0.25;
    o.tile = 64;
    check_streamed_samples(dir.file("in.ply"), dir.file("job"), o);
    // Normals estimated: a saddle (so that a normal depends on which neighbours it has) with a
    // wider hole and 15 sparser points in it, without normals. The lists of their 10 nearest
    // kept points reach several cells.
    PointCloud d;
    const auto saddle = [](float x, float y) { return Vec3f{x, y, 0.03f * (x * x - y * y)}; };
    while (d.size() < 200000) {
        const float x = u(rng), y = u(rng);
        if (x * x + y * y >= 49.0f) d.positions.push_back(saddle(x, y));
    }
    std::uniform_real_distribution<float> w(-7.0f, 7.0f);
    for (int i = 0; i < 15;) {
        const float x = w(rng), y = w(rng);
        if (x * x + y * y >= 49.0f) continue;
        d.positions.push_back(saddle(x, y));
        ++i;
    }
    write_points(dir.file("bare.ply"), d);
    o.normals.up = Vec3d{0, 0, 1};
    for (const bool outliers : {true, false}) {
        INFO("normals estimated, outliers " << outliers);
        o.outliers.enabled = outliers;
        check_streamed_samples(dir.file("bare.ply"), dir.file(outliers ? "job1" : "job0"), o);
    }
}

namespace {

/// Starts `vdbrecon ARGS` (split on spaces), kills it with SIGKILL after `seconds` unless it
/// ended before; returns its exit code, or -1 when it was killed.
int run_killed_after(const std::vector<std::string>& args, double seconds) {
    const pid_t pid = ::fork();
    if (pid == 0) {
        const int null = ::open("/dev/null", O_WRONLY);
        ::dup2(null, 1);
        ::dup2(null, 2);
        std::vector<char*> argv{const_cast<char*>(VDBRECON_CLI)};
        for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
        argv.push_back(nullptr);
        ::execv(VDBRECON_CLI, argv.data());
        ::_exit(127);
    }
    int status = 0;
    const auto start = std::chrono::steady_clock::now();
    while (::waitpid(pid, &status, WNOHANG) == 0) {
        if (std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() > seconds) {
            ::kill(pid, SIGKILL);
            ::waitpid(pid, &status, 0);
            break;
        }
        ::usleep(2000);
    }
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace

TEST_CASE("job directory (--job-dir): a tiled run killed at any moment resumes to the bytes of an uninterrupted one",
          "[tiles][resume]") {
    TempDir dir;
    const Shape shape = make_shape("boss");
    write_points(dir.file("in.ply"), sample_uniform(shape.mesh, 60000, 4));
    const std::string in = dir.file("in.ply"), job = dir.file("job");
    const std::string common = " --tile 24 --no-vdb --job-dir '" + job + "'";
    REQUIRE(run_cli("'" + in + "' -o '" + dir.file("whole.ply") + "' --tile 24 --no-vdb -q").code == 0);
    const std::string whole = read_bytes(dir.file("whole.ply"));

    // Killed while it writes tile 3's piece: the pieces before it are kept, its own half-written
    // temporary is removed when the run starts again.
    const CliRun crashed = run_cli("'" + in + "' -o '" + dir.file("a.ply") + "'" + common,
                                   "VDBRECON_CRASH_AT=piece:3");
    CHECK(crashed.code == 128 + SIGKILL);  // as the shell reports it
    CHECK_FALSE(file_exists(dir.file("a.ply")));
    CHECK(file_exists(job + "/piece-2.bin"));
    CHECK_FALSE(file_exists(job + "/piece-3.bin"));
    CHECK(count_files(job) > 4);
    const CliRun resumed = run_cli("'" + in + "' -o '" + dir.file("a.ply") + "'" + common);
    INFO(resumed.err);
    REQUIRE(resumed.code == 0);
    CHECK(resumed.err.find("3 of ") != std::string::npos);  // pieces 0-2 were kept
    CHECK(read_bytes(dir.file("a.ply")) == whole);

    // SIGKILL at random moments, again and again, in a new directory: each run gets further.
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> after(0.05, 1.2);
    const std::string job2 = dir.file("job2");
    const std::vector<std::string> args{in, "-o", dir.file("b.ply"), "--tile", "24", "--no-vdb",
                                        "-q", "--job-dir", job2};
    int kills = 0, code = -1;
    for (int attempt = 0; attempt < 60 && code != 0; ++attempt) {
        // Later attempts wait longer, so that a slow machine still gets past the preparation.
        code = run_killed_after(args, after(rng) * (1.0 + 0.1 * attempt));
        kills += code == -1;
    }
    INFO(kills << " kills");
    REQUIRE(code == 0);
    CHECK(kills >= 2);
    CHECK(read_bytes(dir.file("b.ply")) == whole);

    // Options after the stitch may change (the pieces are the same); the job's own may not.
    CHECK(run_cli("'" + in + "' -o '" + dir.file("c.ply") + "'" + common + " --decimate 0.5").code == 0);
    const CliRun other = run_cli("'" + in + "' -o '" + dir.file("d.ply") + "'" + common + " --support 2.5");
    CHECK(other.code != 0);
    CHECK(other.err.find("splat.support") != std::string::npos);
    CHECK_FALSE(file_exists(dir.file("d.ply")));
}

TEST_CASE("job directory (--job-dir): a changed input, a foreign directory and a busy one are refused", "[tiles][resume]") {
    TempDir dir;
    const Shape shape = make_shape("boss");
    write_points(dir.file("in.ply"), sample_uniform(shape.mesh, 8000, 5));
    const std::string in = dir.file("in.ply"), job = dir.file("job");
    const std::string common = " --tile 32 --no-vdb -q --job-dir '" + job + "'";
    REQUIRE(run_cli("'" + in + "' -o '" + dir.file("a.ply") + "'" + common).code == 0);
    // The same size, other points.
    write_points(in, sample_uniform(shape.mesh, 8000, 6));
    const CliRun changed = run_cli("'" + in + "' -o '" + dir.file("b.ply") + "'" + common);
    CHECK(changed.code != 0);
    CHECK(changed.err.find("has changed") != std::string::npos);
    // The same input with another mesher: refused, the option named (the mesher by its name).
    write_points(in, sample_uniform(shape.mesh, 8000, 5));
    const CliRun other =
        run_cli("'" + in + "' -o '" + dir.file("b.ply") + "'" + common + " --mesher dc");
    CHECK(other.code != 0);
    CHECK(other.err.find("made with mesh.method dual, this run has dc") != std::string::npos);
    // A directory of other files is not taken for a job.
    ::mkdir(dir.file("mine").c_str(), 0755);
    write_bytes(dir.file("mine/notes.txt"), "keep me");
    const CliRun foreign = run_cli("'" + in + "' -o '" + dir.file("b.ply") + "' --job-dir '" +
                                   dir.file("mine") + "'");
    CHECK(foreign.code != 0);
    CHECK(foreign.err.find("not a vdbrecon job directory") != std::string::npos);
    CHECK(read_bytes(dir.file("mine/notes.txt")) == "keep me");
    // A directory another run holds.
    std::remove((job + "/manifest.txt").c_str());
    const int fd = ::open((job + "/lock").c_str(), O_RDWR);
    REQUIRE(::flock(fd, LOCK_EX) == 0);
    const CliRun busy = run_cli("'" + in + "' -o '" + dir.file("b.ply") + "'" + common);
    ::close(fd);
    CHECK(busy.code != 0);
    CHECK(busy.err.find("in use") != std::string::npos);
}

TEST_CASE("tile jobs in a directory: prepare_tiles resumes, pieces kept there finish the run",
          "[tiles][resume]") {
    TempDir dir;
    const Shape shape = make_shape("boss");
    write_points(dir.file("in.ply"), sample_uniform(shape.mesh, 12000, 4));
    PipelineOptions o;
    o.tile = 32;
    o.write_vdb = false;
    run(dir.file("in.ply"), dir.file("run.ply"), o);
    const TileJob job = prepare_tiles(dir.file("in.ply"), dir.file("job"), o);
    REQUIRE(job.tiles > 4);
    for (std::size_t i = 0; i < job.tiles; i += 2) save_tile_piece(dir.file("job"), i, run_tile(dir.file("job"), i, o));
    // Prepared again: taken as it is; the odd pieces are missing.
    const TileJob again = prepare_tiles(dir.file("in.ply"), dir.file("job"), o);
    CHECK(again.tiles == job.tiles);
    CHECK(has_tile_piece(dir.file("job"), 0));
    CHECK_FALSE(has_tile_piece(dir.file("job"), 1));
    CHECK_THROWS_AS(finish_tiles(dir.file("in.ply"), dir.file("x.ply"), dir.file("job"), o), IoError);
    for (std::size_t i = 1; i < job.tiles; i += 2) save_tile_piece(dir.file("job"), i, run_tile(dir.file("job"), i, o));
    finish_tiles(dir.file("in.ply"), dir.file("job.ply"), dir.file("job"), o);
    CHECK(read_bytes(dir.file("job.ply")) == read_bytes(dir.file("run.ply")));
    // Another tile's bytes under a piece's name are not a piece of it.
    write_bytes(dir.file("job") + "/piece-1.bin", run_tile(dir.file("job"), 0, o));
    CHECK_FALSE(has_tile_piece(dir.file("job"), 1));
}
