// Range-image fusion: depth pixels to samples, depth image files, scene files, and fused meshes
// of known shapes seen from every side (tests/depth_scenes.h renders them).
#include <tbb/task_arena.h>
#include <zlib.h>

#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <functional>
#include <numeric>
#include <random>
#include <sstream>
#include <unordered_map>

#include "depth_scenes.h"
#include "grid_compare.h"
#include "shapes.h"
#include "support.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/fusion.h"
#include "vdbrecon/io.h"
#include "vdbrecon/knn.h"
#include "vdbrecon/scene.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

Vec3d centre_of(const Mesh& m) {
    const BBox b = bounding_box(m.vertices);
    return {0.5 * (double(b.min[0]) + b.max[0]) + m.origin[0],
            0.5 * (double(b.min[1]) + b.max[1]) + m.origin[1],
            0.5 * (double(b.min[2]) + b.max[2]) + m.origin[2]};
}

struct Views {
    Intrinsics K;
    std::vector<Pose> poses;
    std::vector<DepthImage> depths;
};

/// n samples of a sphere, all of one colour.
PointCloud coloured_sphere(std::size_t n, double radius, const Vec3d& centre, const Vec3f& rgb) {
    PointCloud s = test::sample_sphere(n, radius, centre);
    s.colors.assign(s.size(), rgb);
    return s;
}

/// The accumulator's splat options: voxel 1 cm, no crease model (it has none).
SplatOptions accumulator_options() {
    SplatOptions o;
    o.voxel_size = 0.01;
    o.crease_angle = 0.0;
    o.aggregate = 0.0;  // splat() as an accumulator sums: every sample its own kernel
    return o;
}

/// `count` views of the mesh from a sphere `distance` diagonals away.
Views views_of(const Mesh& mesh, int count, int width, int height, double distance = 2.0) {
    Views v;
    v.K = camera_intrinsics(width, height, 50.0);
    const double diag = bounding_box(mesh.vertices).diagonal();
    v.poses = orbit_poses(count, centre_of(mesh), distance * diag);
    for (const Pose& p : v.poses) v.depths.push_back(render_depth(mesh, v.K, p));
    return v;
}

PipelineOptions fusion_options(double voxel) {
    PipelineOptions o;
    o.splat.voxel_size = voxel;
    o.splat.crease_angle = 0.0;
    return o;
}

/// `vdbrecon fuse SCENE -o MESH --voxel VOXEL OPTIONS` (the voxel with every digit).
CliRun run_fuse(const std::string& scene, const std::string& mesh, double voxel,
                const std::string& options = "") {
    std::ostringstream args;
    args.precision(17);
    args << "fuse '" << scene << "' -o '" << mesh << "' --voxel " << voxel << " " << options;
    return run_cli(args.str());
}

EvalResult compare(const Mesh& recon, const Mesh& ref, double tau) {
    EvalOptions e;
    e.taus = {tau};
    e.samples = 200000;
    return evaluate(recon, ref, e);
}

}  // namespace

TEST_CASE("depth pixels of a plane become samples on it, facing the camera", "[fusion]") {
    const Intrinsics K = camera_intrinsics(64, 48, 60.0);
    DepthImage img{64, 48, std::vector<float>(64 * 48, 2.0f)};
    const Pose identity{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    // A camera at (1, 2, 3) turned 90 degrees about z.
    const Pose turned{0, -1, 0, 1, 1, 0, 0, 2, 0, 0, 1, 3, 0, 0, 0, 1};
    const PointCloud s = depth_samples(img, K, identity, DepthOptions{});
    REQUIRE(s.size() == 64 * 48);
    const double footprint = 2.0 / K.fx;
    for (std::size_t i = 0; i < s.size(); ++i) {
        REQUIRE(s.positions[i][2] == Approx(2.0).margin(1e-6));
        REQUIRE(s.normals[i][2] == Approx(-1.0).margin(1e-6));
        REQUIRE(s.scales[i] == Approx(footprint).epsilon(1e-3));
        REQUIRE(s.confidences[i] <= 1.0f);
    }
    // The centre pixel looks straight at the plane: full confidence.
    const std::size_t c = 24 * 64 + 32;
    CHECK(s.confidences[c] == Approx(1.0).margin(2e-3));
    const PointCloud t = depth_samples(img, K, turned, DepthOptions{});
    REQUIRE(t.size() == s.size());
    for (std::size_t i = 0; i < s.size(); i += 97) {
        // x' = -y + 1, y' = x + 2, z' = z + 3
        CHECK(t.positions[i][0] == Approx(-s.positions[i][1] + 1.0).margin(1e-5));
        CHECK(t.positions[i][1] == Approx(s.positions[i][0] + 2.0).margin(1e-5));
        CHECK(t.positions[i][2] == Approx(s.positions[i][2] + 3.0).margin(1e-5));
    }
    // The same plane as a range image: depth along the ray is longer off the axis.
    DepthImage range = img;
    for (int v = 0; v < 48; ++v) {
        for (int u = 0; u < 64; ++u) {
            const double x = (u - K.cx) / K.fx, y = (v - K.cy) / K.fy;
            range.depth[std::size_t(v * 64 + u)] = float(2.0 * std::sqrt(x * x + y * y + 1.0));
        }
    }
    DepthOptions ray;
    ray.kind = DepthKind::ray;
    const PointCloud r = depth_samples(range, K, identity, ray);
    REQUIRE(r.size() == s.size());
    for (std::size_t i = 0; i < r.size(); ++i) REQUIRE(r.positions[i][2] == Approx(2.0).margin(1e-5));
}

TEST_CASE("no normal across a depth jump, none from lone pixels, none past max_depth", "[fusion]") {
    const Intrinsics K = camera_intrinsics(32, 32, 60.0);
    DepthImage img{32, 32, std::vector<float>(32 * 32, 1.0f)};
    for (int v = 0; v < 32; ++v) {
        for (int u = 16; u < 32; ++u) img.depth[std::size_t(v * 32 + u)] = 3.0f;  // a step
    }
    img.depth[5 * 32 + 5] = NAN;
    const Pose I{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    const PointCloud s = depth_samples(img, K, I, DepthOptions{});
    // Every pixel has a neighbour on its own side: all but the NaN one give a sample, and every
    // normal faces the camera squarely (none is tilted by the step).
    REQUIRE(s.size() == 32 * 32 - 1);
    for (std::size_t i = 0; i < s.size(); ++i) REQUIRE(s.normals[i][2] == Approx(-1.0).margin(1e-6));
    DepthOptions near;
    near.max_depth = 2.0;
    CHECK(depth_samples(img, K, I, near).size() == 16 * 32 - 1);
    DepthImage lone{32, 32, std::vector<float>(32 * 32, 0.0f)};
    lone.depth[10 * 32 + 10] = 1.0f;
    CHECK(depth_samples(lone, K, I, DepthOptions{}).empty());
}

TEST_CASE("poses that are not rigid transforms are refused", "[fusion]") {
    Pose p{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    CHECK_NOTHROW(validate_pose(p));
    Pose scaled = p;
    scaled[0] = 2.0;
    CHECK_THROWS_AS(validate_pose(scaled), InvalidArgument);
    Pose mirrored = p;
    mirrored[10] = -1.0;
    CHECK_THROWS_WITH(validate_pose(mirrored), Catch::Contains("not a rotation"));
    Pose nan = p;
    nan[3] = NAN;
    CHECK_THROWS_WITH(validate_pose(nan), Catch::Contains("NaN"));
}

TEST_CASE("depth images round-trip through EXR exactly and PNG to a unit", "[fusion][io]") {
    TempDir dir;
    DepthImage img{7, 5, {}};
    for (int i = 0; i < 35; ++i) img.depth.push_back(i % 6 == 0 ? 0.0f : 0.5f + 0.0731f * float(i));
    write_depth_image(dir.file("d.exr"), img);
    const DepthImage e = read_depth_image(dir.file("d.exr"));
    REQUIRE(e.width == 7);
    REQUIRE(e.height == 5);
    CHECK(e.depth == img.depth);
    write_depth_image(dir.file("d.png"), img, 5000.0);
    const DepthImage p = read_depth_image(dir.file("d.png"), 5000.0);
    REQUIRE(p.depth.size() == img.depth.size());
    for (std::size_t i = 0; i < img.depth.size(); ++i) {
        REQUIRE(p.depth[i] == Approx(img.depth[i]).margin(0.5 / 5000.0 + 1e-7));
    }
    CHECK_THROWS_WITH(write_depth_image(dir.file("far.png"), img, 1e6), Catch::Contains("65535"));
    write_bytes(dir.file("bad.png"), "\x89PNG\r\n\x1a\n garbage");
    CHECK_THROWS_WITH(read_depth_image(dir.file("bad.png")), Catch::Contains("bad.png"));
    write_bytes(dir.file("bad.exr"), "v/1\x01 not an exr");
    CHECK_THROWS_AS(read_depth_image(dir.file("bad.exr")), FormatError);
    CHECK_THROWS_AS(read_depth_image(dir.file("missing.exr")), IoError);
    // A header promising 60000 x 60000 pixels (valid CRCs), then no data: refused before any
    // allocation of that size.
    std::string ihdr = "IHDR";
    for (std::uint32_t v : {60000u, 60000u}) {
        for (int b = 3; b >= 0; --b) ihdr += char((v >> (8 * b)) & 255u);
    }
    ihdr += std::string("\x10\x00\x00\x00\x00", 5);
    const unsigned long crc = crc32(0L, reinterpret_cast<const Bytef*>(ihdr.data()), uInt(ihdr.size()));
    std::string png = std::string("\x89PNG\r\n\x1a\n", 8) + std::string("\x00\x00\x00\x0d", 4) + ihdr;
    for (int b = 3; b >= 0; --b) png += char((crc >> (8 * b)) & 255u);
    const std::string idat = "IDAT\x78\x9c";  // the start of a zlib stream, then nothing
    const unsigned long idat_crc = crc32(0L, reinterpret_cast<const Bytef*>(idat.data()), uInt(idat.size()));
    png += std::string("\x00\x00\x00\x02", 4) + idat;
    for (int b = 3; b >= 0; --b) png += char((idat_crc >> (8 * b)) & 255u);
    write_bytes(dir.file("huge.png"), png);
    CHECK_THROWS_WITH(read_depth_image(dir.file("huge.png")), Catch::Contains("huge.png") && Catch::Contains("60000"));
}

TEST_CASE("the accumulator gives the same grids for any thread count", "[fusion]") {
    const Shape box = make_shape("cube");
    const Views v = views_of(box.mesh, 6, 160, 120);
    auto fuse_with = [&](int threads) {
        tbb::task_arena arena(threads);
        return arena.execute([&] {
            Fusion f(fusion_options(0.03));
            for (std::size_t i = 0; i < v.depths.size(); ++i) f.integrate(v.depths[i], v.K, v.poses[i]);
            return f.volume();
        });
    };
    const Volume a = fuse_with(1), b = fuse_with(2);
    REQUIRE(a.sdf->activeVoxelCount() == b.sdf->activeVoxelCount());
    REQUIRE(a.sdf->activeVoxelCount() > 1000);
    auto acc = b.sdf->getConstAccessor();
    auto wacc = b.weight->getConstAccessor();
    for (auto it = a.sdf->cbeginValueOn(); it; ++it) {
        REQUIRE(acc.getValue(it.getCoord()) == *it);
        REQUIRE(wacc.getValue(it.getCoord()) == a.weight->getConstAccessor().getValue(it.getCoord()));
    }
}

TEST_CASE("a sphere and a box seen from 24 poses fuse into one closed piece", "[fusion]") {
    for (const char* name : {"sphere", "cube"}) {
        const Shape shape = make_shape(name);
        const double voxel = bounding_box(shape.mesh.vertices).diagonal() / 80.0;
        const Views v = views_of(shape.mesh, 24, 320, 240);
        Fusion f(fusion_options(voxel), DepthOptions{}, Vec3d{0.25, -0.5, 1.0});
        for (std::size_t i = 0; i < v.depths.size(); ++i) f.integrate(v.depths[i], v.K, v.poses[i]);
        const PipelineResult r = f.reconstruct();
        const EvalResult e = compare(r.mesh, shape.mesh, voxel);
        INFO(name << ": F@voxel " << e.fscores[0].fscore << ", chamfer " << e.chamfer_l1 / voxel
                  << " voxels, " << e.recon.boundary_edges << " boundary edges");
        CHECK(e.fscores[0].fscore >= 0.99);
        CHECK(e.recon.components == 1);
        CHECK(e.recon.boundary_edges == 0);
        CHECK(e.recon.nonmanifold_edges == 0);
    }
}

TEST_CASE("vdbrecon fuse reads transforms.json (EXR and PNG) and TUM folders alike", "[fusion][cli]") {
    const Shape shape = make_shape("boss");
    const double voxel = bounding_box(shape.mesh.vertices).diagonal() / 60.0;
    const Views v = views_of(shape.mesh, 20, 200, 150);
    TempDir exr, png, tum, out;
    const std::string scenes[] = {
        write_transforms_scene(exr.path(), v.depths, v.K, v.poses, "exr"),
        write_transforms_scene(png.path(), v.depths, v.K, v.poses, "png", 10000.0),
        write_tum_scene(tum.path(), v.depths, v.poses)};
    for (const std::string& scene : scenes) {
      // Presummed (the default) and not: frames prepared in parallel own their samples either way.
      for (const char* aggregate : {"", " --aggregate 0"}) {
        const std::string mesh = out.file("m.ply");
        std::ostringstream args;
        args.precision(17);
        args << "fuse '" << scene << "' -o '" << mesh << "' --voxel " << voxel << " -q" << aggregate;
        if (scene == tum.path()) {
            args << " --intrinsics " << v.K.fx << "," << v.K.fy << "," << v.K.cx << "," << v.K.cy;
        }
        const CliRun r = run_cli(args.str());
        INFO(scene << ": " << r.err);
        REQUIRE(r.code == 0);
        REQUIRE(file_exists(out.file("m.splat.vdb")));
        const EvalResult e = compare(read_mesh(mesh), shape.mesh, voxel);
        INFO("F@voxel " << e.fscores[0].fscore << ", chamfer " << e.chamfer_l1 / voxel << " voxels");
        CHECK(e.fscores[0].fscore >= 0.99);
        CHECK(e.recon.components == 1);
        CHECK(e.recon.watertight());
      }
    }
}

TEST_CASE("vdbrecon fuse detects the RGB-D dataset layouts of a folder", "[fusion][cli][layouts]") {
    const Shape shape = make_shape("boss");
    const double voxel = bounding_box(shape.mesh.vertices).diagonal() / 60.0;
    const Views v = views_of(shape.mesh, 20, 200, 150);
    const struct {
        const char* layout;
        const char* logged;
    } cases[] = {{"7scenes", "7-Scenes/3DMatch"}, {"redwood", "Redwood/Open3D"},
                 {"scannet", "ScanNet"}, {"replica", "Replica"}};
    for (const auto& c : cases) {
        TempDir dir, out;
        write_layout_scene(c.layout, dir.path(), v.depths, v.K, v.poses);
        const CliRun r = run_fuse(dir.path(), out.file("m.ply"), voxel);
        INFO(c.layout << ": " << r.err);
        REQUIRE(r.code == 0);
        CHECK(r.err.find(std::string("(") + c.logged + ")") != std::string::npos);
        const EvalResult e = compare(read_mesh(out.file("m.ply")), shape.mesh, voxel);
        INFO("F@voxel " << e.fscores[0].fscore);
        CHECK(e.fscores[0].fscore >= 0.99);
        CHECK(e.recon.components == 1);
        CHECK(e.recon.watertight());
    }
}

TEST_CASE("fuse: the frames' colour images become the mesh's colours, in every layout",
          "[fusion][cli][color]") {
    const Shape shape = make_shape("boss");
    const double diag = bounding_box(shape.mesh.vertices).diagonal();
    const double voxel = diag / 60.0;
    const Views v = views_of(shape.mesh, 20, 200, 150);
    // A smooth pattern over the part (about ten voxels a period): what the cameras see.
    const double s = diag / 6.0;
    const auto paint = [s](const Vec3d& p) { return paint_pattern(p, s); };
    std::vector<ColorImage> colors;
    for (std::size_t i = 0; i < v.poses.size(); ++i) {
        colors.push_back(render_color(v.depths[i], v.K, v.poses[i], paint));
    }
    // The mean and the worst 99th-percentile colour error of the mesh's vertices.
    const auto color_error = [&](const Mesh& m, double& p99) {
        std::vector<double> e;
        for (std::size_t i = 0; i < m.vertices.size(); ++i) {
            const Vec3d w{m.origin[0] + m.vertices[i][0], m.origin[1] + m.vertices[i][1],
                          m.origin[2] + m.vertices[i][2]};
            const Vec3f want = paint(w), got = m.colors[i];
            e.push_back((std::fabs(want[0] - got[0]) + std::fabs(want[1] - got[1]) +
                         std::fabs(want[2] - got[2])) / 3.0);
        }
        std::sort(e.begin(), e.end());
        p99 = e[e.size() * 99 / 100];
        return std::accumulate(e.begin(), e.end(), 0.0) / double(e.size());
    };
    for (const std::string layout : {"transforms", "tum", "7scenes", "redwood", "scannet", "replica"}) {
        TempDir dir, out;
        std::string scene = dir.path();
        std::string extra;
        if (layout == "transforms") {
            scene = write_transforms_scene(dir.path(), v.depths, v.K, v.poses, "png", 10000.0);
            for (std::size_t i = 0; i < colors.size(); ++i) {
                write_color_image(dir.file("rgb_" + std::to_string(i) + ".png"), colors[i]);
            }
        } else if (layout == "tum") {
            write_tum_scene(dir.path(), v.depths, v.poses);
            ::mkdir(dir.file("rgb").c_str(), 0755);
            std::ostringstream list;
            list.precision(17);
            for (std::size_t i = 0; i < colors.size(); ++i) {  // 5 ms after each depth frame
                const std::string name = "rgb/" + std::to_string(i) + ".png";
                write_color_image(dir.file(name), colors[i]);
                list << 1305031102.0 + 0.0333 * double(i) + 0.005 << " " << name << "\n";
            }
            write_bytes(dir.file("rgb.txt"), list.str());
            std::ostringstream k;
            k.precision(17);
            k << " --intrinsics " << v.K.fx << "," << v.K.fy << "," << v.K.cx << "," << v.K.cy;
            extra = k.str();
        } else {
            write_layout_scene(layout, dir.path(), v.depths, v.K, v.poses, &colors);
        }
        std::ostringstream args;
        args.precision(17);
        args << "fuse '" << scene << "' -o '" << out.file("m.ply") << "' --voxel " << voxel << " -q"
             << extra;
        // The mesh of `fuse` with these arguments and `more`.
        const auto fused = [&](const std::string& more) {
            const CliRun r = run_cli(args.str() + more);
            INFO(layout << more << ": " << r.err);
            REQUIRE(r.code == 0);
            return read_mesh(out.file("m.ply"));
        };
        const Mesh m = fused("");
        REQUIRE(m.colors.size() == m.vertices.size());
        double p99 = 0.0;
        const double mean = color_error(m, p99);
        INFO("colour error: mean " << mean << ", 99th percentile " << p99);
        // Measured: PNG 0.0024 (under a 255th), 99th percentile 0.0075; JPEG (quality 95)
        // 0.0063 and 0.031.
        CHECK(mean < 0.01);
        CHECK(p99 < 0.06);
        if (layout == "7scenes") {
            // The tsdf rule averages each voxel's pixel colour near the surface.
            const Mesh tm = fused(" --fusion tsdf");
            REQUIRE(tm.colors.size() == tm.vertices.size());
            double tsdf_p99 = 0.0;
            const double tsdf_mean = color_error(tm, tsdf_p99);
            INFO("tsdf colour error: mean " << tsdf_mean << ", 99th percentile " << tsdf_p99);
            CHECK(tsdf_mean < 0.02);
            // --no-color: a grey mesh.
            CHECK(fused(" --no-color").colors.empty());
        }
    }
}

TEST_CASE("fuse: broken dataset layouts give one line naming the file", "[fusion][cli][layouts][bad]") {
    const Shape shape = make_shape("sphere");
    const Views v = views_of(shape.mesh, 4, 64, 48);
    TempDir out;
    auto fuse = [&](const std::string& dir, const std::string& extra = "") {
        return run_cli("fuse '" + dir + "' -o '" + out.file("m.ply") + "' --voxel 0.05 -q " + extra);
    };
    auto check_failed = [&](const CliRun& r, const std::string& names) {
        INFO(r.err);
        CHECK(r.code != 0);
        CHECK(r.err.find(names) != std::string::npos);
        CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
        CHECK(!file_exists(out.file("m.ply")));
    };
    {  // a folder of none of them: the error lists what was looked for
        TempDir empty;
        const CliRun r = fuse(empty.path());
        check_failed(r, "not a scene folder");
        CHECK(r.err.find("7-Scenes") != std::string::npos);
        CHECK(r.err.find("ScanNet") != std::string::npos);
    }
    {  // 7-Scenes: a missing pose
        TempDir d;
        write_layout_scene("7scenes", d.path(), v.depths, v.K, v.poses);
        std::remove(d.file("frame-000002.pose.txt").c_str());
        check_failed(fuse(d.path()), "frame-000002.pose.txt");
    }
    {  // ScanNet: unreadable intrinsics; a lost pose (-inf) is skipped with a warning
        TempDir d;
        write_layout_scene("scannet", d.path(), v.depths, v.K, v.poses);
        const std::string good = read_bytes(d.file("intrinsic/intrinsic_depth.txt"));
        write_bytes(d.file("intrinsic/intrinsic_depth.txt"), "fx fy\n");
        check_failed(fuse(d.path()), "intrinsic_depth.txt");
        write_bytes(d.file("intrinsic/intrinsic_depth.txt"), good);
        write_bytes(d.file("pose/1.txt"), "-inf -inf -inf -inf\n-inf -inf -inf -inf\n"
                                          "-inf -inf -inf -inf\n-inf -inf -inf -inf\n");
        const CliRun r = run_cli("fuse '" + d.path() + "' -o '" + out.file("m.ply") + "' --voxel 0.05");
        INFO(r.err);
        CHECK(r.code == 0);
        CHECK(r.err.find("1.txt: the pose is marked lost") != std::string::npos);
        for (const std::string f : {out.file("m.ply"), out.file("m.splat.vdb")}) std::remove(f.c_str());
    }
    {  // Redwood: a truncated trajectory
        TempDir d;
        write_layout_scene("redwood", d.path(), v.depths, v.K, v.poses);
        const std::string log = read_bytes(d.file("trajectory.log"));
        write_bytes(d.file("trajectory.log"), log.substr(0, log.size() / 2));
        check_failed(fuse(d.path()), "trajectory.log");
    }
    {  // Replica: no cam_params.json and no --intrinsics
        TempDir d;
        write_layout_scene("replica", d.path(), v.depths, v.K, v.poses);
        std::remove(d.file("cam_params.json").c_str());
        check_failed(fuse(d.path()), "cam_params.json");
    }
}

TEST_CASE("the bunny's reference mesh seen from 24 poses fuses back onto itself", "[fusion][data]") {
    const std::string gt = shared_data("stanford_bunny/bun_zipper_gt.ply");
    if (gt.empty()) return;
    const Mesh bunny = read_mesh(gt);
    const double voxel = 0.001;
    const Views v = views_of(bunny, 24, 320, 240, 1.5);
    Fusion f(fusion_options(voxel), DepthOptions{}, centre_of(bunny));
    for (std::size_t i = 0; i < v.depths.size(); ++i) f.integrate(v.depths[i], v.K, v.poses[i]);
    const PipelineResult r = f.reconstruct();
    EvalOptions o;
    o.taus = {voxel};
    o.samples = 300000;
    o.ignore_reference_holes = true;  // the reference is open underneath
    const EvalResult e = evaluate(r.mesh, bunny, o);
    INFO("F@1mm " << e.fscores[0].fscore << ", chamfer " << e.chamfer_l1 * 1e6 << " um, "
                  << e.recon.components << " pieces");
    CHECK(e.fscores[0].fscore >= 0.99);
    CHECK(e.recon.components == 1);
}

TEST_CASE("fuse: bad frames give one line naming the file, a non-zero exit and no output", "[fusion][cli][bad]") {
    const Shape shape = make_shape("sphere");
    const Views v = views_of(shape.mesh, 4, 64, 48);
    TempDir dir, out;
    const std::string json = write_transforms_scene(dir.path(), v.depths, v.K, v.poses, "exr");
    const std::string good = read_bytes(json);
    const std::string mesh = out.file("m.ply");
    auto fuse = [&](const std::string& extra = "") {
        return run_cli("fuse '" + json + "' -o '" + mesh + "' --voxel 0.05 -q " + extra);
    };
    auto check_failed = [&](const CliRun& r, const std::string& names, const std::string& what) {
        INFO(r.err);
        CHECK(r.code != 0);
        CHECK(r.err.find(names) != std::string::npos);
        CHECK(r.err.find(what) != std::string::npos);
        CHECK(std::count(r.err.begin(), r.err.end(), '\n') == 1);
        CHECK(!file_exists(mesh));
        CHECK(!file_exists(out.file("m.splat.vdb")));
        CHECK(count_files(out.path()) == 0);
    };
    {  // a frame of another size
        DepthImage small{32, 24, std::vector<float>(32 * 24, 1.0f)};
        write_depth_image(dir.file("d_2.exr"), small);
        check_failed(fuse(), "d_2.exr", "32 x 24");
        write_depth_image(dir.file("d_2.exr"), v.depths[2]);
    }
    {  // a missing file
        std::rename(dir.file("d_1.exr").c_str(), dir.file("gone.exr").c_str());
        check_failed(fuse(), "d_1.exr", "d_1.exr");
        std::rename(dir.file("gone.exr").c_str(), dir.file("d_1.exr").c_str());
    }
    {  // a truncated frame in the middle stops the run naming it; --skip-bad-frames goes on
       // with one warning naming it (the other frames fuse as before)
        const std::string bytes = read_bytes(dir.file("d_2.exr"));
        write_bytes(dir.file("d_2.exr"), bytes.substr(0, bytes.size() / 2));
        check_failed(fuse(), "d_2.exr", "d_2.exr");
        const CliRun skipped = run_cli("fuse '" + json + "' -o '" + mesh +
                                       "' --voxel 0.05 --skip-bad-frames");
        INFO(skipped.err);
        CHECK(skipped.code == 0);
        CHECK(file_exists(mesh));
        const std::string warning = "d_2.exr: frame skipped (--skip-bad-frames)";
        CHECK(skipped.err.find(warning) != std::string::npos);
        CHECK(skipped.err.find(warning) == skipped.err.rfind(warning));  // once
        for (const std::string f : {mesh, out.file("m.splat.vdb")}) std::remove(f.c_str());
        write_bytes(dir.file("d_2.exr"), bytes);
    }
    for (const char* bad : {"\"w\": 0", "\"h\": -48", "\"fl_x\": 0"}) {  // invalid metadata
        std::string s = good;
        const std::string key = std::string(bad).substr(0, std::string(bad).find(':') + 1);
        const std::size_t at = s.find(key);
        REQUIRE(at != std::string::npos);
        s.replace(at, s.find_first_of(",}\n", at) - at, bad);
        write_bytes(json, s);
        check_failed(fuse(), "transforms.json", "not a positive number");
    }
    write_bytes(json, good);
    auto with_matrix = [&](const std::string& row) {  // frame 0's first row replaced
        std::string s = good;
        const std::size_t a = s.find("\"transform_matrix\": [[") + 22;
        const std::size_t b = s.find(']', a);
        s.replace(a, b - a, row);
        write_bytes(json, s);
    };
    with_matrix("2, 0, 0, 1");
    check_failed(fuse(), "transforms.json", "not a rotation");
    with_matrix("NaN, 0, 0, 1");
    check_failed(fuse(), "transforms.json", "JSON");
    write_bytes(json, good.substr(0, good.size() / 2));
    check_failed(fuse(), "transforms.json", "JSON");
    write_bytes(json, good);
    {  // empty depth images: nothing measured anywhere
        for (int i = 0; i < 4; ++i) {
            write_depth_image(dir.file("d_" + std::to_string(i) + ".exr"),
                              DepthImage{64, 48, std::vector<float>(64 * 48, 0.0f)});
        }
        check_failed(fuse(), "transforms.json", "has a usable pixel");
    }
    check_failed(run_cli("fuse '" + dir.file("nothing.json") + "' -o '" + mesh + "' --voxel 0.05 -q"),
                 "nothing.json", "nothing.json");
}

TEST_CASE("frames far finer than the voxel are merged into pixel blocks, same surface", "[fusion]") {
    const Shape shape = make_shape("sphere");
    const double voxel = bounding_box(shape.mesh.vertices).diagonal() / 30.0;
    const Views v = views_of(shape.mesh, 12, 320, 240);
    auto fuse_with = [&](double merge) {
        DepthOptions d;
        d.merge_footprint = merge;
        Fusion f(fusion_options(voxel), d);
        for (std::size_t i = 0; i < v.depths.size(); ++i) f.integrate(v.depths[i], v.K, v.poses[i]);
        return std::make_pair(f.samples(), f.reconstruct().mesh);
    };
    const auto [all, full] = fuse_with(0.0);
    const auto [merged, coarse] = fuse_with(-1.0);  // automatic: up to half a voxel
    // The footprint is about voxel / 7 here: 3 x 3 blocks.
    CHECK(merged * 6 < all);
    const EvalResult a = compare(full, shape.mesh, voxel), b = compare(coarse, shape.mesh, voxel);
    INFO("chamfer all " << a.chamfer_l1 / voxel << ", merged " << b.chamfer_l1 / voxel << " voxels");
    CHECK(b.fscores[0].fscore >= 0.99);
    CHECK(b.chamfer_l1 <= 1.2 * a.chamfer_l1 + 0.01 * voxel);
    CHECK(b.recon.watertight());
}

TEST_CASE("PCD: ascii, binary and binary_compressed read the same points", "[fusion][io][pcd]") {
    TempDir dir;
    const std::string header =
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z normal_x normal_y normal_z\nSIZE 4 4 4 4 4 4\n"
        "TYPE F F F F F F\nCOUNT 1 1 1 1 1 1\nWIDTH 2\nHEIGHT 2\nVIEWPOINT 1 2 3 1 0 0 0\nPOINTS 4\n";
    write_bytes(dir.file("a.pcd"), header + "DATA ascii\n0 0 1 0 0 -1\nnan nan nan 0 0 0\n"
                                            "0.5 0 1 0 0 -1\n0 0.5 1.25 0 0.6 -0.8\n");
    std::string bin = header + "DATA binary\n";
    const float v[4][6] = {{0, 0, 1, 0, 0, -1}, {NAN, NAN, NAN, 0, 0, 0}, {0.5f, 0, 1, 0, 0, -1}, {0, 0.5f, 1.25f, 0, 0.6f, -0.8f}};
    bin.append(reinterpret_cast<const char*>(v), sizeof v);
    write_bytes(dir.file("b.pcd"), bin);
    for (const char* name : {"a.pcd", "b.pcd"}) {
        const ReadResult r = read_points(dir.file(name));
        INFO(name);
        REQUIRE(r.rows == 4);
        REQUIRE(r.cloud.size() == 3);  // the NaN point dropped
        CHECK(r.cloud.positions[2][2] + float(r.cloud.origin[2]) == Approx(1.25f));
        CHECK(r.cloud.normals[2][1] == Approx(0.6f));
        const OrganizedCloud o = read_organized_cloud(dir.file(name));
        CHECK(o.width == 2);
        CHECK(o.height == 2);
        CHECK(std::isnan(o.points[1][0]));
        CHECK(o.sensor == Vec3d{1, 2, 3});
    }
    write_bytes(dir.file("t.pcd"), bin.substr(0, bin.size() - 10));
    CHECK_THROWS_WITH(read_points(dir.file("t.pcd")), Catch::Contains("t.pcd") && Catch::Contains("truncated"));
    std::string lzf = header;
    lzf.replace(lzf.find("POINTS 4\n"), 9, "POINTS 4\nDATA binary_compressed\n");
    lzf += std::string("\x08\x00\x00\x00\x60\x00\x00\x00", 8) + "\x1f\x01\x02";  // bad reference
    write_bytes(dir.file("c.pcd"), lzf);
    CHECK_THROWS_WITH(read_points(dir.file("c.pcd")), Catch::Contains("c.pcd"));
}

TEST_CASE("fuse: an organized PCD's rgb becomes the mesh's colours", "[fusion][pcd][color]") {
    // One view of the boss part as a depth camera's organized cloud in its own axes (sensor at
    // the origin), each point with the colour a smooth pattern gives it.
    const Shape shape = make_shape("boss");
    const Views v = views_of(shape.mesh, 1, 200, 150);
    const double diag = bounding_box(shape.mesh.vertices).diagonal(), s = diag / 6.0;
    const auto paint = [s](const Vec3d& p) { return paint_pattern(p, s); };
    const DepthImage& d = v.depths[0];
    std::string pcd = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\n"
                      "COUNT 1 1 1 1\nWIDTH " + std::to_string(d.width) + "\nHEIGHT " +
                      std::to_string(d.height) + "\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " +
                      std::to_string(d.depth.size()) + "\nDATA binary\n";
    for (int y = 0; y < d.height; ++y) {
        for (int x = 0; x < d.width; ++x) {
            const float z = d.at(x, y);
            float row[4] = {NAN, NAN, NAN, 0.0f};
            if (z > 0.0f) {
                row[0] = float((x - v.K.cx) / v.K.fx * z);
                row[1] = float((y - v.K.cy) / v.K.fy * z);
                row[2] = z;
                const Vec3f c = paint({row[0], row[1], row[2]});
                const std::uint32_t bits = std::uint32_t(std::lround(c[0] * 255.0f)) << 16 |
                                           std::uint32_t(std::lround(c[1] * 255.0f)) << 8 |
                                           std::uint32_t(std::lround(c[2] * 255.0f));
                std::memcpy(&row[3], &bits, 4);
            }
            pcd.append(reinterpret_cast<const char*>(row), sizeof row);
        }
    }
    TempDir dir;
    write_bytes(dir.file("frame.pcd"), pcd);
    const double voxel = diag / 60.0;
    const CliRun r = run_fuse(dir.file("frame.pcd"), dir.file("m.ply"), voxel, "-q --no-vdb");
    INFO(r.err);
    REQUIRE(r.code == 0);
    const Mesh m = read_mesh(dir.file("m.ply"));
    REQUIRE(m.colors.size() == m.vertices.size());
    REQUIRE(m.vertices.size() > 100);
    double sum = 0.0;
    for (std::size_t i = 0; i < m.vertices.size(); ++i) {
        const Vec3f want = paint({m.origin[0] + m.vertices[i][0], m.origin[1] + m.vertices[i][1],
                                  m.origin[2] + m.vertices[i][2]});
        for (std::size_t c = 0; c < 3; ++c) sum += std::fabs(want[c] - m.colors[i][c]) / 3.0;
    }
    const double mean = sum / double(m.vertices.size());
    INFO("mean colour error " << mean);
    CHECK(mean < 0.01);
    const CliRun g = run_fuse(dir.file("frame.pcd"), dir.file("m.ply"), voxel, "-q --no-vdb --no-color");
    REQUIRE(g.code == 0);
    CHECK(read_mesh(dir.file("m.ply")).colors.empty());
}

TEST_CASE("the Kinect frame: its compressed PCD is its PLY twin, and fuses as an organized cloud", "[fusion][pcd][data]") {
    const std::string pcd = shared_data("pcl_kinect/capture0001.pcd");
    const std::string ply = shared_data("pcl_kinect/capture0001.ply");
    if (pcd.empty() || ply.empty()) return;
    const ReadResult a = read_points(pcd), b = read_points(ply);
    REQUIRE(a.cloud.size() == b.cloud.size());
    double worst = 0.0;
    for (std::size_t i = 0; i < a.cloud.size(); ++i) {
        for (int k = 0; k < 3; ++k) {
            worst = std::max(worst, std::fabs(double(a.cloud.positions[i][std::size_t(k)]) + a.cloud.origin[std::size_t(k)] -
                                              double(b.cloud.positions[i][std::size_t(k)]) - b.cloud.origin[std::size_t(k)]));
        }
    }
    CHECK(worst < 1e-6);
    const OrganizedCloud frame = read_organized_cloud(pcd);
    REQUIRE(frame.width == 640);
    REQUIRE(frame.height == 480);
    const double voxel = 0.013;  // MANIFEST's suggestion
    Fusion f(fusion_options(voxel), DepthOptions{}, frame.origin);
    // 249,647 measured points; those seen more grazing than min_view_cos (78 degrees: ~1.5 %)
    // or without a neighbour on their surface give none.
    CHECK(f.integrate(frame) > 235000);
    const Mesh m = f.reconstruct().mesh;
    REQUIRE(m.vertices.size() > 10000);
    // Precision: the mesh's vertices lie on the scan (within a voxel of a point), better than
    // the point pipeline's 92.6 % (PLY, --voxel 0.013): 99.5 % with presumming and no samples
    // more grazing than min_view_cos (98.6 % with them, 95.4 % before presumming).
    KnnIndex index(b.cloud.positions);
    std::vector<Vec3f> q(m.vertices.begin(), m.vertices.end());
    for (Vec3f& x : q) {
        for (int k = 0; k < 3; ++k) x[std::size_t(k)] = float(double(x[std::size_t(k)]) + m.origin[std::size_t(k)] - b.cloud.origin[std::size_t(k)]);
    }
    const KnnResult nn = index.query(q, 1);
    std::size_t near = 0;
    for (std::size_t i = 0; i < q.size(); ++i) near += nn.sq_dists(i)[0] <= voxel * voxel;
    INFO("within a voxel: " << double(near) / double(q.size()));
    CHECK(double(near) / double(q.size()) >= 0.98);
}

TEST_CASE("tsdf fusion: a sphere is one closed piece, and carving removes an object that moved", "[fusion][tsdf]") {
    const Shape sphere = make_shape("sphere");
    const double voxel = bounding_box(sphere.mesh.vertices).diagonal() / 80.0;
    const Views v = views_of(sphere.mesh, 24, 320, 240);
    DepthOptions tsdf;
    tsdf.rule = FusionRule::tsdf;
    auto fuse = [&](const DepthOptions& d, const std::vector<DepthImage>& depths, int threads,
                    double scale = 1.0) {
        tbb::task_arena arena(threads);
        return arena.execute([&] {
            PipelineOptions o = fusion_options(voxel * scale);
            o.clean.min_component_ratio = 0.0;  // the cube is a small piece beside the room
            Fusion f(o, d);
            for (std::size_t i = 0; i < depths.size(); ++i) f.integrate(depths[i], v.K, v.poses[i]);
            return f.reconstruct().mesh;
        });
    };
    const Mesh m = fuse(tsdf, v.depths, 2);
    const EvalResult e = compare(m, sphere.mesh, voxel);
    INFO("tsdf sphere: F@voxel " << e.fscores[0].fscore << ", chamfer " << e.chamfer_l1 / voxel << " voxels");
    CHECK(e.fscores[0].fscore >= 0.99);
    CHECK(e.recon.components == 1);
    CHECK(e.recon.watertight());
    const Mesh one = fuse(tsdf, v.depths, 1);
    CHECK(one.vertices == m.vertices);
    CHECK(one.faces == m.faces);

    // A cube next to the sphere in the first 12 frames, gone in the last 12, inside a large
    // enclosing sphere (a room: every ray ends on a surface, so free space is observed).
    const Vec3d c = centre_of(sphere.mesh);
    auto add = [](Mesh& to, const Mesh& from, double scale, const Vec3d& about, const Vec3d& at) {
        const std::size_t base = to.vertices.size();
        for (const Vec3f& x : from.vertices) {
            Vec3f y;
            for (int k = 0; k < 3; ++k) {
                const std::size_t a = std::size_t(k);
                y[a] = float((double(x[a]) + from.origin[a] - about[a]) * scale + at[a] - to.origin[a]);
            }
            to.vertices.push_back(y);
        }
        for (const Triangle& t : from.faces) {
            to.faces.push_back({t[0] + int(base), t[1] + int(base), t[2] + int(base)});
        }
    };
    Mesh room = sphere.mesh;
    add(room, sphere.mesh, 12.0, c, c);  // radius 6, around the cameras at 3.5
    Mesh with_cube = room;
    const Shape cube = make_shape("cube");
    const Vec3d at{c[0] + 0.9, c[1], c[2]};
    add(with_cube, cube.mesh, 0.3, centre_of(cube.mesh), at);
    std::vector<DepthImage> moved;
    for (std::size_t i = 0; i < v.poses.size(); ++i) {
        moved.push_back(render_depth(i < 12 ? with_cube : room, v.K, v.poses[i]));
    }
    auto near_cube = [&](const Mesh& mesh) {
        std::size_t n = 0;
        for (const Vec3f& x : mesh.vertices) {
            bool in = true;
            for (int k = 0; k < 3; ++k) {
                const std::size_t a = std::size_t(k);
                in = in && std::fabs(double(x[a]) + mesh.origin[a] - at[a]) < 0.3;
            }
            n += in;
        }
        return n;
    };
    DepthOptions kept = tsdf;
    kept.carve = false;
    const std::size_t stays = near_cube(fuse(kept, moved, 2, 3.0));
    const std::size_t carved = near_cube(fuse(tsdf, moved, 2, 3.0));
    INFO("vertices where the cube was: " << stays << " without carving, " << carved << " with");
    CHECK(stays > 20);  // without carving the cube stays
    CHECK(carved == 0);
}

TEST_CASE("tsdf fusion: the AVX2 and AVX-512 rows give the scalar rows' grids bit for bit",
          "[fusion][tsdf]") {
    // A painted part seen from 12 cameras close enough that it leaves the image: voxels behind,
    // in front of and across the surface, projections off the image, and the colour pass.
    const Shape shape = make_shape("boss");
    const double diag = bounding_box(shape.mesh.vertices).diagonal();
    const double voxel = diag / 50.0;
    const Views v = views_of(shape.mesh, 12, 160, 120, 0.8);
    const auto paint = [diag](const Vec3d& p) { return paint_pattern(p, diag / 6.0); };
    DepthOptions d;
    d.rule = FusionRule::tsdf;
    auto fused = [&] {
        Fusion f(fusion_options(voxel), d);
        for (std::size_t i = 0; i < v.poses.size(); ++i) {
            f.integrate(v.depths[i], v.K, v.poses[i],
                        render_color(v.depths[i], v.K, v.poses[i], paint), v.K);
        }
        return f.volume();
    };
    ::setenv("VDBRECON_SCALAR", "1", 1);
    const Volume scalar = fused();
    ::unsetenv("VDBRECON_SCALAR");
    ::setenv("VDBRECON_NO_AVX512", "1", 1);
    const Volume avx2 = fused();
    ::unsetenv("VDBRECON_NO_AVX512");
    const Volume wide = fused();  // AVX-512 where the CPU has it
    REQUIRE(scalar.sdf->activeVoxelCount() > 10000);
    REQUIRE(scalar.color);
    for (const Volume* vector : {&avx2, &wide}) {
        REQUIRE(vector->color);
        CHECK(same_grids(*scalar.sdf, *vector->sdf));
        CHECK(same_grids(*scalar.weight, *vector->weight));
        CHECK(same_grids(*scalar.color, *vector->color));
    }
}

TEST_CASE("fuse: scans of a point file, each seen from its own sensor", "[fusion][scans]") {
    // A sphere seen by six scanners on the axes: each point belongs to the scan of the scanner
    // that sees it most squarely; the file has no normals: they are estimated per scan and
    // turned toward its scanner.
    const Shape sphere = make_shape("sphere");
    const PointCloud s = sample_uniform(sphere.mesh, 60000, 5);
    const Vec3d c = centre_of(sphere.mesh);
    std::vector<Vec3d> sensors;
    for (int a = 0; a < 3; ++a) {
        for (double sign : {1.0, -1.0}) {
            Vec3d o = c;
            o[std::size_t(a)] += 3.0 * sign;
            sensors.push_back(o);
        }
    }
    TempDir dir;
    std::ostringstream ply;
    ply.precision(9);
    ply << "ply\nformat ascii 1.0\nelement vertex " << s.size()
        << "\nproperty float x\nproperty float y\nproperty float z\nproperty uchar scan\nend_header\n";
    for (std::size_t i = 0; i < s.size(); ++i) {
        double p[3], best = -2.0;
        int scan = 0;
        for (int k = 0; k < 3; ++k) p[k] = double(s.positions[i][std::size_t(k)]) + s.origin[std::size_t(k)];
        for (std::size_t j = 0; j < sensors.size(); ++j) {
            double v[3], len = 0.0, d = 0.0;
            for (int k = 0; k < 3; ++k) v[k] = sensors[j][std::size_t(k)] - p[k], len += v[k] * v[k];
            for (int k = 0; k < 3; ++k) d += v[k] * double(s.normals[i][std::size_t(k)]);
            if (d / std::sqrt(len) > best) best = d / std::sqrt(len), scan = int(j);
        }
        ply << p[0] << " " << p[1] << " " << p[2] << " " << scan << "\n";
    }
    write_bytes(dir.file("scans.ply"), ply.str());
    std::ostringstream origins;
    origins.precision(17);
    for (const Vec3d& o : sensors) origins << o[0] << " " << o[1] << " " << o[2] << "\n";
    write_bytes(dir.file("sensors.txt"), "# x y z per scan\n" + origins.str());
    const double voxel = spacing_of(sphere.area, s.size()) * 1.5;
    std::ostringstream args;
    args << "fuse '" << dir.file("scans.ply") << "' --scan-origins '" << dir.file("sensors.txt")
         << "' -o '" << dir.file("m.ply") << "' --voxel " << voxel << " -q";
    const CliRun r = run_cli(args.str());
    INFO(r.err);
    REQUIRE(r.code == 0);
    const EvalResult e = compare(read_mesh(dir.file("m.ply")), sphere.mesh, voxel);
    INFO("F@voxel " << e.fscores[0].fscore << ", chamfer " << e.chamfer_l1 / voxel << " voxels");
    CHECK(e.fscores[0].fscore >= 0.99);
    CHECK(e.recon.components == 1);
    CHECK(e.recon.watertight());
    // A point of a scan the sensor file does not have; more sensors than a file without scans.
    write_bytes(dir.file("one.txt"), origins.str().substr(0, origins.str().find('\n') + 1));
    const CliRun bad = run_cli("fuse '" + dir.file("scans.ply") + "' --scan-origins '" +
                               dir.file("one.txt") + "' -o '" + dir.file("b.ply") + "' --voxel 0.05 -q");
    CHECK(bad.code != 0);
    CHECK(bad.err.find("scans.ply") != std::string::npos);
    CHECK(bad.err.find("sensors") != std::string::npos);
    CHECK(!file_exists(dir.file("b.ply")));
}

TEST_CASE("fuse: the bunny's ten range scans with their scanners from bun.conf", "[fusion][scans][data]") {
    const std::string scans = shared_data("stanford_bunny/bun_scans_aligned.ply");
    const std::string conf = shared_data("stanford_bunny/bun.conf");
    const std::string gt = shared_data("stanford_bunny/bun_zipper_gt.ply");
    if (scans.empty() || conf.empty() || gt.empty()) return;
    const ScanSensors s = read_scan_sensors(conf);
    REQUIRE(s.directions.size() == 10);
    // bun045's scanner, as bun_scans_aligned_scans.csv gives it.
    CHECK(s.directions[1][0] == Approx(0.563056).margin(1e-5));
    CHECK(s.directions[1][2] == Approx(0.826320).margin(1e-5));
    TempDir dir;
    const CliRun r = run_cli("fuse '" + scans + "' --scan-origins '" + conf + "' -o '" +
                             dir.file("b.ply") + "' --voxel 0.0005 -q --no-vdb");
    INFO(r.err);
    REQUIRE(r.code == 0);
    EvalOptions o;
    o.taus = {0.0005};
    o.samples = 300000;
    const EvalResult e = evaluate(read_mesh(dir.file("b.ply")), read_mesh(gt), o);
    INFO("F@0.5mm " << e.fscores[0].fscore << ", chamfer " << e.chamfer_l1 * 1e6 << " um");
    CHECK(e.fscores[0].fscore >= 0.995);
    CHECK(e.recon.components == 1);
}

TEST_CASE("presummed frames fuse the same surface with a fraction of the kernels", "[fusion][aggregate]") {
    for (const char* name : {"sphere", "boss"}) {
        const Shape shape = make_shape(name);
        const double voxel = bounding_box(shape.mesh.vertices).diagonal() / 80.0;
        const Views v = views_of(shape.mesh, 24, 320, 240);
        auto fuse_with = [&](double aggregate, std::size_t& updates) {
            DepthOptions d;
            d.aggregate = aggregate;
            Fusion f(fusion_options(voxel), d);
            for (std::size_t i = 0; i < v.depths.size(); ++i) f.integrate(v.depths[i], v.K, v.poses[i]);
            updates = f.splat().updates;
            return compare(f.reconstruct().mesh, shape.mesh, voxel);
        };
        std::size_t raw_updates = 0, sum_updates = 0;
        const EvalResult raw = fuse_with(0.0, raw_updates);
        const EvalResult sum = fuse_with(DepthOptions{}.aggregate, sum_updates);
        INFO(name << ": chamfer " << sum.chamfer_l1 / voxel << " voxel presummed, "
                  << raw.chamfer_l1 / voxel << " raw; kernel updates " << sum_updates << " vs "
                  << raw_updates);
        CHECK(sum_updates * 3 < raw_updates);
        CHECK(sum.fscores[0].fscore >= 0.99);
        CHECK(sum.chamfer_l1 <= raw.chamfer_l1 + 0.02 * voxel);
        CHECK(sum.recon.components == 1);
        CHECK(sum.recon.boundary_edges == 0);
    }
}

TEST_CASE("a fusion's batch presums its clouds' groups once more, as of them joined", "[fusion][aggregate]") {
    // Three interleaved thirds of a sphere with scales and confidences, integrated as clouds:
    // each is presummed, the batch sums their groups once more as they arrive (one hash table
    // of cells, no sort). That must give, bit for bit, what presumming the groups joined gives.
    const PointCloud all = test::sample_sphere(30000, 0.5);
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(0.5f, 2.0f), s(0.002f, 0.03f);
    PointCloud parts[3];
    for (std::size_t i = 0; i < all.size(); ++i) {
        PointCloud& p = parts[i % 3];
        p.positions.push_back(all.positions[i]);
        p.normals.push_back(all.normals[i]);
        p.confidences.push_back(u(rng));
        p.scales.push_back(s(rng));
    }
    const PipelineOptions po = fusion_options(0.01);
    const double cell = DepthOptions{}.aggregate;
    auto same = [](const Volume& a, const Volume& b) {
        REQUIRE(a.sdf->activeVoxelCount() == b.sdf->activeVoxelCount());
        REQUIRE(a.sdf->activeVoxelCount() > 10000);
        auto sacc = b.sdf->getConstAccessor();
        auto wacc = b.weight->getConstAccessor();
        auto wa = a.weight->getConstAccessor();
        for (auto it = a.sdf->cbeginValueOn(); it; ++it) {
            REQUIRE(sacc.getValue(it.getCoord()) == *it);
            REQUIRE(wacc.getValue(it.getCoord()) == wa.getValue(it.getCoord()));
        }
    };
    for (std::size_t batch : {std::size_t(1) << 21, std::size_t(1)}) {
        DepthOptions d;
        d.batch_samples = batch;  // one batch, or a flush after every cloud
        Fusion f(po, d);
        for (const PointCloud& p : parts) f.integrate(p);
        const Volume fused = f.volume();
        SplatAccumulator reference(po.splat);
        PointCloud joined;
        for (const PointCloud& p : parts) {
            const PointCloud g = aggregate_samples(p.view(), po.splat, cell);
            if (batch == 1) {
                reference.add(aggregate_samples(g.view(), po.splat, cell));
                continue;
            }
            for (std::size_t i = 0; i < g.size(); ++i) {
                joined.positions.push_back(g.positions[i]);
                joined.normals.push_back(g.normals[i]);
                joined.confidences.push_back(g.confidences[i]);
                joined.scales.push_back(g.scales[i]);
            }
        }
        if (batch != 1) reference.add(aggregate_samples(joined.view(), po.splat, cell));
        INFO("batch_samples " << batch);
        same(fused, reference.result().volume);
    }
}

TEST_CASE("taking an accumulator's result gives result()'s volume and frees the sums", "[fusion][splat]") {
    const PointCloud s = coloured_sphere(40000, 0.5, {0.0, 0.0, 0.0}, {0.2f, 0.4f, 0.6f});
    const SplatOptions o = accumulator_options();
    SplatAccumulator acc(o);
    acc.add(s);
    const std::size_t before = acc.memory_bytes();
    const SplatResult kept = acc.result(), taken = acc.take_result();
    INFO("sums " << before << " bytes before, " << acc.memory_bytes() << " after");
    CHECK(acc.memory_bytes() * 20 < before);
    CHECK(acc.clouds() == 0);
    REQUIRE(kept.volume.sdf->activeVoxelCount() > 10000);
    REQUIRE(taken.volume.sdf->activeVoxelCount() == kept.volume.sdf->activeVoxelCount());
    CHECK(taken.updates == kept.updates);
    auto sdf = taken.volume.sdf->getConstAccessor();
    auto w = taken.volume.weight->getConstAccessor();
    auto near = taken.volume.nearest->getConstAccessor();
    auto col = taken.volume.color->getConstAccessor();
    auto kw = kept.volume.weight->getConstAccessor();
    auto kn = kept.volume.nearest->getConstAccessor();
    auto kc = kept.volume.color->getConstAccessor();
    for (auto it = kept.volume.sdf->cbeginValueOn(); it; ++it) {
        const openvdb::Coord c = it.getCoord();
        REQUIRE(sdf.isValueOn(c));
        REQUIRE(sdf.getValue(c) == *it);
        REQUIRE(w.getValue(c) == kw.getValue(c));
        REQUIRE(near.getValue(c) == kn.getValue(c));
        REQUIRE(col.getValue(c) == kc.getValue(c));
    }
    // The spent accumulator starts again.
    acc.add(s);
    CHECK(acc.result().volume.sdf->activeVoxelCount() == kept.volume.sdf->activeVoxelCount());
}

TEST_CASE(
    "an accumulator's first cloud alone is splatted from double sums, and result() between adds "
    "changes nothing",
    "[fusion][splat]") {
    // The accumulator holds its first cloud until a second comes: alone, its volume is
    // splat()'s (no crease model) up to the constant factor of the area normalisation, so the
    // weights are the same bits and the sdf the same within rounding.
    const PointCloud a = coloured_sphere(30000, 0.5, {0.0, 0.0, 0.0}, {0.2f, 0.4f, 0.6f});
    const PointCloud b = coloured_sphere(30000, 0.5, {0.3, 0.0, 0.0}, {0.8f, 0.1f, 0.3f});
    const SplatOptions o = accumulator_options();
    SplatAccumulator one(o);
    one.add(a);
    CHECK(one.clouds() == 1);
    CHECK(one.points() == a.size());
    const Volume alone = one.result().volume, direct = splat(a, o).volume;
    REQUIRE(alone.sdf->activeVoxelCount() > 10000);
    CHECK(same_grids(*alone.weight, *direct.weight));
    REQUIRE(alone.sdf->activeVoxelCount() == direct.sdf->activeVoxelCount());
    auto d = direct.sdf->getConstAccessor();
    for (auto it = alone.sdf->cbeginValueOn(); it; ++it) {
        REQUIRE(*it == Approx(d.getValue(it.getCoord())).margin(1e-6 * o.voxel_size));
    }
    // A second cloud: the same grids whether result() was asked for in between or not.
    one.add(b);
    SplatAccumulator both(o);
    both.add(a);
    both.add(b);
    const Volume after = one.result().volume, straight = both.result().volume;
    CHECK(one.clouds() == 2);
    CHECK(same_volumes(after, straight));
    CHECK(after.sdf->activeVoxelCount() > alone.sdf->activeVoxelCount());
}

TEST_CASE("an accumulator of two clouds is the splat of both within rounding", "[fusion][splat]") {
    // The second cloud is summed onto the first one's sums, stored in float leaves made
    // beforehand for every leaf a kernel reaches (make_state_leaves, from each kernel's leaf
    // mask): a leaf missed there loses the first cloud's sums. With one sigma for all (no
    // scales) the area normalisation is 1 either way, so only the float rounding of the stored
    // sums may differ: a few voxels at the validity threshold and sdf values within rounding.
    const PointCloud a = coloured_sphere(30000, 0.5, {0.0, 0.0, 0.0}, {0.2f, 0.4f, 0.6f});
    const PointCloud b = coloured_sphere(30000, 0.4, {0.3, 0.05, -0.02}, {0.8f, 0.1f, 0.3f});
    REQUIRE(!a.has_scales());
    const SplatOptions o = accumulator_options();
    SplatAccumulator acc(o);
    acc.add(a);
    acc.add(b);
    const Volume summed = acc.result().volume;
    PointCloud joined;
    for (const PointCloud* c : {&a, &b}) {
        for (std::size_t i = 0; i < c->size(); ++i) {
            joined.positions.push_back(c->positions[i]);
            joined.normals.push_back(c->normals[i]);
            joined.colors.push_back(c->colors[i]);
        }
    }
    const Volume direct = splat(joined, o).volume;
    const openvdb::Index64 n = direct.sdf->activeVoxelCount();
    REQUIRE(n > 20000);
    auto s = summed.sdf->getConstAccessor();
    std::size_t only_direct = 0, far = 0;
    for (auto it = direct.sdf->cbeginValueOn(); it; ++it) {
        if (!s.isValueOn(it.getCoord())) {
            ++only_direct;
            continue;
        }
        far += std::fabs(s.getValue(it.getCoord()) - *it) > 1e-6 * o.voxel_size;
    }
    INFO(only_direct << " of " << n << " voxels only in the splat's, " << far << " differ");
    CHECK(only_direct * 2000 < n);
    CHECK(far == 0);
    CHECK(summed.sdf->activeVoxelCount() <= n + n / 2000);
}

TEST_CASE("vdbrecon fuse --fusion tsdf: frames read in parallel, the library's volume, any threads", "[fusion][cli][tsdf]") {
    // The CLI reads frames in parallel and integrates them in order; the result must be what
    // the library's Fusion gives for the same images one after another, bit for bit, at 1 and
    // 2 threads, and a closed piece on a sphere.
    const Shape shape = make_shape("sphere");
    const double voxel = bounding_box(shape.mesh.vertices).diagonal() / 60.0;
    const Views v = views_of(shape.mesh, 20, 200, 150);
    TempDir scene_dir, out;
    const std::string scene = write_transforms_scene(scene_dir.path(), v.depths, v.K, v.poses, "exr");
    std::string bytes[2];
    for (int threads : {1, 2}) {
        const std::string mesh = out.file("t" + std::to_string(threads) + ".ply");
        const CliRun r =
            run_fuse(scene, mesh, voxel, "-q --no-vdb --fusion tsdf --threads " + std::to_string(threads));
        INFO(r.err);
        REQUIRE(r.code == 0);
        bytes[threads - 1] = read_bytes(mesh);
    }
    CHECK(bytes[0] == bytes[1]);
    const EvalResult e = compare(read_mesh(out.file("t1.ply")), shape.mesh, voxel);
    INFO("F@voxel " << e.fscores[0].fscore << ", chamfer " << e.chamfer_l1 / voxel << " voxels");
    CHECK(e.fscores[0].fscore >= 0.97);
    CHECK(e.recon.components == 1);
    CHECK(e.recon.watertight());
    // The library, frame after frame (EXR keeps the depths as floats).
    DepthOptions d;
    d.rule = FusionRule::tsdf;
    const Scene sc = read_scene(scene, SceneOptions{});
    Fusion f(fusion_options(voxel), d, Vec3d{sc.frames[0].pose[3], sc.frames[0].pose[7], sc.frames[0].pose[11]});
    for (const SceneFrame& frame : sc.frames) {
        const DepthImage img = read_depth_image(frame.depth_path, frame.units_per_metre);
        Intrinsics K = frame.intrinsics;
        K.width = img.width;
        K.height = img.height;
        f.integrate(img, K, frame.pose);
    }
    const Mesh library = f.reconstruct().mesh;
    const Mesh cli = read_mesh(out.file("t1.ply"));
    REQUIRE(library.vertices.size() == cli.vertices.size());
    REQUIRE(library.faces.size() == cli.faces.size());
    for (std::size_t i = 0; i < cli.vertices.size(); ++i) {
        for (int a = 0; a < 3; ++a) {
            REQUIRE(double(library.vertices[i][a]) + library.origin[a] ==
                    Approx(double(cli.vertices[i][a]) + cli.origin[a]).margin(1e-5 * voxel));
        }
    }
}

TEST_CASE("tsdf fusion: a pixel beyond 2^23 voxels is one clear error, not a wrapped index", "[fusion][tsdf][bad]") {
    const Shape sphere = make_shape("sphere");
    const double voxel = bounding_box(sphere.mesh.vertices).diagonal() / 80.0;
    const Views v = views_of(sphere.mesh, 2, 64, 48);
    DepthOptions tsdf;
    tsdf.rule = FusionRule::tsdf;
    Fusion f(fusion_options(voxel), tsdf);
    f.integrate(v.depths[0], v.K, v.poses[0]);
    DepthImage far = v.depths[1];
    far.depth[far.depth.size() / 2] = float(1e8 * voxel);  // ~10^8 voxels away
    try {
        f.integrate(far, v.K, v.poses[1]);
        FAIL("no error");
    } catch (const NumericalError& e) {
        CHECK(std::string(e.what()).find("2^23 voxels") != std::string::npos);
    }
}

namespace {

/// A street for a car's LiDAR (z up): the ground, two facades along x, three poles and a parked
/// car, as boxes; the ray cast returns the nearest hit within 80 m (0: none).
struct Street {
    struct Box {
        Vec3d lo, hi;
    };
    std::vector<Box> boxes = {{{0, 8, 0}, {50, 14, 12}},      // left facade at y = 8
                              {{0, -14, 0}, {50, -8, 12}},    // right facade at y = -8
                              {{10, 5, 0}, {10.2, 5.2, 4}},   // poles
                              {{25, -5.2, 0}, {25.2, -5, 4}},
                              {{40, 5, 0}, {40.2, 5.2, 4}},
                              {{20, 3, 0}, {24, 5, 1.5}}};    // a parked car
    double cast(const Vec3d& o, const Vec3d& d) const {
        double best = d[2] < 0.0 ? -o[2] / d[2] : HUGE_VAL;  // the ground z = 0
        for (const Box& b : boxes) {
            double t0 = 0.0, t1 = best;
            for (int a = 0; a < 3; ++a) {
                const std::size_t k = std::size_t(a);
                if (std::fabs(d[k]) < 1e-12) {
                    if (o[k] < b.lo[k] || o[k] > b.hi[k]) t0 = HUGE_VAL;
                    continue;
                }
                double ta = (b.lo[k] - o[k]) / d[k], tb = (b.hi[k] - o[k]) / d[k];
                if (ta > tb) std::swap(ta, tb);
                t0 = std::max(t0, ta);
                t1 = std::min(t1, tb);
            }
            if (t0 <= t1 && t0 > 0.0) best = std::min(best, t0);
        }
        return best <= 80.0 ? best : 0.0;
    }
    /// The distance from p to the nearest surface (ground or box).
    double distance(const Vec3d& p) const {
        double best = std::fabs(p[2]);
        for (const Box& b : boxes) {
            double out2 = 0.0, in = HUGE_VAL;
            for (std::size_t a = 0; a < 3; ++a) {
                const double e = std::max({b.lo[a] - p[a], 0.0, p[a] - b.hi[a]});
                out2 += e * e;
                in = std::min(in, std::min(p[a] - b.lo[a], b.hi[a] - p[a]));
            }
            best = std::min(best, out2 > 0.0 ? std::sqrt(out2) : std::max(0.0, in));
        }
        return best;
    }
};

/// The first scan's sensor, in the street's frame.
const Vec3d kStreetSensor{2.0, 0.0, 1.73};

/// Ten scans of a street, 4 m apart along it, from a sensor 1.73 m up turning a little (yaw),
/// 64 beams from -24.8 to +2 degrees, 720 steps a turn, 1 cm range noise, written into `dir` as
/// KITTI writes them (velodyne/*.bin, camera 0's poses, calib.txt's Tr). `street(i)` is what
/// scan i sees. Returns the exact hits within 30 m, in the first scan's frame.
std::vector<Vec3d> write_kitti_street(const TempDir& dir, const std::function<Street(int)>& street_at) {
    std::mt19937_64 rng(3);
    std::normal_distribution<double> noise(0.0, 0.01);
    std::vector<Pose> lidar;  // scan to the first scan's frame
    std::vector<std::vector<float>> scans;
    std::vector<Vec3d> hits;
    const Vec3d s0 = kStreetSensor;
    for (int i = 0; i < 10; ++i) {
        const Street street = street_at(i);
        const double yaw = 0.05 * std::sin(i), c = std::cos(yaw), s = std::sin(yaw);
        const Vec3d at{2.0 + 4.0 * i, 0.3 * std::sin(0.7 * i), 1.73};
        lidar.push_back({c, -s, 0, at[0] - s0[0], s, c, 0, at[1] - s0[1], 0, 0, 1, at[2] - s0[2], 0, 0, 0, 1});
        std::vector<float> bin;
        for (int b = 0; b < 64; ++b) {
            const double el = (-24.8 + 26.8 * b / 63.0) * M_PI / 180.0;
            for (int a = 0; a < 720; ++a) {
                const double az = 2.0 * M_PI * a / 720.0;
                const Vec3d local{std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el)};
                const Vec3d world{c * local[0] - s * local[1], s * local[0] + c * local[1], local[2]};
                const double t = street.cast(at, world);
                if (t <= 0.0) continue;
                const double r = t + noise(rng);
                for (double v : {local[0] * r, local[1] * r, local[2] * r, 0.0}) bin.push_back(float(v));
                if (t <= 30.0) {
                    hits.push_back({at[0] + world[0] * t - s0[0], at[1] + world[1] * t - s0[1],
                                    at[2] + world[2] * t - s0[2]});
                }
            }
        }
        scans.push_back(std::move(bin));
    }
    // KITTI writes camera 0's poses: P_i = Tr T_i Tr^-1, with Tr the LiDAR to camera 0.
    const Pose tr{0, -1, 0, 0.02, 0, 0, -1, -0.08, 1, 0, 0, -0.27, 0, 0, 0, 1};
    const Pose tr_inv{0, 0, 1, 0.27, -1, 0, 0, 0.02, 0, -1, 0, -0.08, 0, 0, 0, 1};
    const auto mul = [](const Pose& a, const Pose& b) {
        Pose c{};
        for (int r = 0; r < 4; ++r) {
            for (int k = 0; k < 4; ++k) {
                for (int j = 0; j < 4; ++j) c[std::size_t(4 * r + k)] += a[std::size_t(4 * r + j)] * b[std::size_t(4 * j + k)];
            }
        }
        return c;
    };
    ::mkdir(dir.file("velodyne").c_str(), 0755);
    std::ostringstream poses, calib;
    poses.precision(17);
    calib.precision(17);
    for (std::size_t i = 0; i < scans.size(); ++i) {
        char name[32];
        std::snprintf(name, sizeof name, "velodyne/%06zu.bin", i);
        write_bytes(dir.file(name), std::string(reinterpret_cast<const char*>(scans[i].data()),
                                                scans[i].size() * sizeof(float)));
        const Pose p = mul(tr, mul(lidar[i], tr_inv));
        for (int k = 0; k < 12; ++k) poses << (k ? " " : "") << p[std::size_t(k)];
        poses << "\n";
    }
    calib << "P0: 718.856 0 607.1928 0 0 718.856 185.2157 0 0 0 1 0\nTr:";
    for (int k = 0; k < 12; ++k) calib << " " << tr[std::size_t(k)];
    calib << "\n";
    write_bytes(dir.file("poses.txt"), poses.str());
    write_bytes(dir.file("calib.txt"), calib.str());
    return hits;
}

/// F at `tol` of a mesh (in the first scan's frame) against the street's surfaces (precision:
/// vertices within tol of a surface) and the exact hits (recall: hits with a vertex within tol).
double street_fscore(const Mesh& m, const Street& street, const std::vector<Vec3d>& hits, double tol) {
    std::vector<Vec3d> w;
    std::size_t near = 0;
    const Vec3d& s0 = kStreetSensor;
    for (const Vec3f& v : m.vertices) {
        w.push_back({m.origin[0] + v[0], m.origin[1] + v[1], m.origin[2] + v[2]});
        near += street.distance({w.back()[0] + s0[0], w.back()[1] + s0[1], w.back()[2] + s0[2]}) <= tol;
    }
    const double precision = double(near) / double(w.size());
    // Recall: exact hits with a mesh vertex within tol (a hash grid of the vertices).
    std::unordered_map<std::int64_t, std::vector<std::size_t>> grid;
    const auto key = [&](const Vec3d& p, int dx, int dy, int dz) {
        return (std::int64_t(std::floor(p[0] / tol)) + dx + 100000) * 4000000000LL +
               (std::int64_t(std::floor(p[1] / tol)) + dy + 10000) * 20000 +
               (std::int64_t(std::floor(p[2] / tol)) + dz + 5000);
    };
    for (std::size_t i = 0; i < w.size(); ++i) grid[key(w[i], 0, 0, 0)].push_back(i);
    std::size_t found = 0;
    for (const Vec3d& h : hits) {
        bool hit = false;
        for (int dx = -1; dx <= 1 && !hit; ++dx) {
            for (int dy = -1; dy <= 1 && !hit; ++dy) {
                for (int dz = -1; dz <= 1 && !hit; ++dz) {
                    const auto it = grid.find(key(h, dx, dy, dz));
                    if (it == grid.end()) continue;
                    for (std::size_t j : it->second) {
                        const double ex = w[j][0] - h[0], ey = w[j][1] - h[1], ez = w[j][2] - h[2];
                        if (ex * ex + ey * ey + ez * ez <= tol * tol) {
                            hit = true;
                            break;
                        }
                    }
                }
            }
        }
        found += hit;
    }
    const double recall = double(found) / double(hits.size());
    INFO("precision " << precision << ", recall " << recall);
    return 2 * precision * recall / (precision + recall);
}

/// The mesh's vertices (world, the street's frame) inside `b` grown by `margin`, between z0
/// and z1.
std::size_t vertices_in(const Mesh& m, const Street::Box& b, double margin, double z0, double z1) {
    std::size_t n = 0;
    for (const Vec3f& v : m.vertices) {
        const Vec3d p{m.origin[0] + v[0] + kStreetSensor[0], m.origin[1] + v[1] + kStreetSensor[1],
                      m.origin[2] + v[2] + kStreetSensor[2]};
        if (p[2] < z0 || p[2] > z1) continue;
        bool inside = true;
        for (std::size_t a = 0; a < 2; ++a) inside = inside && p[a] > b.lo[a] - margin && p[a] < b.hi[a] + margin;
        n += inside;
    }
    return n;
}

/// The street's mesh: F at 2 voxels >= 0.95 against the exact hits, and the poles and facades
/// there (vertices on each pole 1-3 m up, on each facade, on the parked car).
void check_street(const Mesh& m, const Street& street, const std::vector<Vec3d>& hits, double voxel) {
    const double f = street_fscore(m, street, hits, 2 * voxel);
    INFO("F@2 voxels " << f);
    CHECK(f >= 0.95);
    for (std::size_t b = 0; b < street.boxes.size(); ++b) {
        CAPTURE(b);
        const double z0 = b == 5 ? 0.5 : 1.0, z1 = b < 2 ? 6.0 : b < 5 ? 3.0 : 1.4;
        CHECK(vertices_in(m, street.boxes[b], 0.2, z0, z1) >= 10);
    }
}

}  // namespace

TEST_CASE("fuse: a KITTI sequence of a ray-cast street from a 64-beam LiDAR", "[fusion][kitti]") {
    const Street street;
    TempDir dir, out;
    const std::vector<Vec3d> hits = write_kitti_street(dir, [&](int) { return street; });
    const double voxel = 0.1;
    const CliRun r = run_cli("fuse '" + dir.path() + "' -o '" + out.file("m.ply") +
                             "' --voxel 0.1 --max-range 30 --no-vdb");
    INFO(r.err);
    REQUIRE(r.code == 0);
    CHECK(r.err.find("(KITTI)") != std::string::npos);
    const Mesh m = read_mesh(out.file("m.ply"));
    REQUIRE(m.vertices.size() > 1000);
    check_street(m, street, hits, voxel);
}

TEST_CASE("fuse --fusion tsdf: a KITTI street's car that drove away is carved out", "[fusion][kitti][tsdf]") {
    // A second car stands at x = 30..34 in the first three scans, then is gone; the sensor
    // passes it at x = 10..14 and sees its place empty from the other side in the last ones.
    const Street street;
    const Street::Box moved{{30, -5, 0}, {34, -3, 1.5}};
    TempDir dir, out;
    std::vector<Vec3d> hits = write_kitti_street(dir, [&](int i) {
        Street s = street;
        if (i < 3) s.boxes.push_back(moved);
        return s;
    });
    // The static street's hits only: the mesh is checked against it.
    hits.erase(std::remove_if(hits.begin(), hits.end(), [&](const Vec3d& h) {
                   const Vec3d p{h[0] + kStreetSensor[0], h[1] + kStreetSensor[1], h[2] + kStreetSensor[2]};
                   return street.distance(p) > 0.05;
               }), hits.end());
    const double voxel = 0.1;
    const std::string common = "' --voxel 0.1 --max-range 30 --no-vdb";
    const CliRun tsdf = run_cli("fuse '" + dir.path() + "' -o '" + out.file("t.ply") + common + " --fusion tsdf --threads 2");
    INFO(tsdf.err);
    REQUIRE(tsdf.code == 0);
    const CliRun splat = run_cli("fuse '" + dir.path() + "' -o '" + out.file("s.ply") + common);
    REQUIRE(splat.code == 0);
    // The same bytes from one thread as from two.
    REQUIRE(run_cli("fuse '" + dir.path() + "' -o '" + out.file("t1.ply") + common +
                    " --fusion tsdf --threads 1").code == 0);
    CHECK(read_bytes(out.file("t1.ply")) == read_bytes(out.file("t.ply")));
    const Mesh t = read_mesh(out.file("t.ply")), s = read_mesh(out.file("s.ply"));
    // The splat rule keeps what any scan saw: the car is in its mesh; the rays of the later
    // scans carve it out of the tsdf's.
    const std::size_t car_splat = vertices_in(s, moved, 0.0, 0.5, 1.4);
    const std::size_t car_tsdf = vertices_in(t, moved, 0.0, 0.5, 1.4);
    INFO("car vertices: splat " << car_splat << ", tsdf " << car_tsdf);
    CHECK(car_splat >= 50);
    CHECK(car_tsdf == 0);
    // The rest of the street is there: the ground under the car too.
    check_street(t, street, hits, voxel);
    const Street::Box under{{30.5, -4.5, 0}, {33.5, -3.5, 0}};
    CHECK(vertices_in(t, under, 0.0, -0.2, 0.2) >= 20);
}

TEST_CASE("Fusion::integrate_scan: LiDAR scans of a sphere, by both rules", "[fusion][tsdf][kitti]") {
    // Six sensors 3 m from a unit sphere, each casting 30000 rays uniformly into the cone that
    // holds the sphere; the hits are exact (the sphere at the origin, the fusion's origin off it).
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    const double voxel = 0.04;
    for (FusionRule rule : {FusionRule::tsdf, FusionRule::splat}) {
        CAPTURE(int(rule));
        DepthOptions d;
        d.rule = rule;
        Fusion f(fusion_options(voxel), d, Vec3d{0.1, 0.2, -0.3});
        for (int s = 0; s < 6; ++s) {
            Vec3d sensor{0.0, 0.0, 0.0};
            sensor[std::size_t(s / 2)] = s % 2 ? -3.0 : 3.0;
            PointCloud scan;
            scan.origin = sensor;  // points relative to the sensor, as a scan's file has them
            std::vector<Vec3f> pts;
            const double cos_max = std::sqrt(1.0 - 1.0 / 9.0);  // the sphere's cone from 3 m
            while (pts.size() < 30000) {
                const double z = cos_max + (1.0 - cos_max) * u(rng), phi = 2.0 * M_PI * u(rng);
                const double rxy = std::sqrt(1.0 - z * z);
                const Vec3d local{rxy * std::cos(phi), rxy * std::sin(phi), z};
                // The ray toward the centre is -sensor / 3: a frame with it as z.
                const std::size_t ax = std::size_t(s / 2);
                Vec3d dir{0.0, 0.0, 0.0};
                dir[ax] = (s % 2 ? 1.0 : -1.0) * local[2];
                dir[(ax + 1) % 3] = local[0];
                dir[(ax + 2) % 3] = local[1];
                // |sensor + t dir| = 1: t^2 + 2 t (sensor . dir) + 9 - 1 = 0
                const double b = sensor[0] * dir[0] + sensor[1] * dir[1] + sensor[2] * dir[2];
                const double disc = b * b - 8.0;
                if (disc < 0.0) continue;
                const double t = -b - std::sqrt(disc);
                pts.push_back({float(t * dir[0]), float(t * dir[1]), float(t * dir[2])});
            }
            scan.positions = std::move(pts);
            CHECK(f.integrate_scan(scan, sensor) > 25000);
        }
        const Mesh m = f.reconstruct().mesh;
        REQUIRE(m.vertices.size() > 1000);
        double worst = 0.0;
        for (const Vec3f& v : m.vertices) {
            const Vec3d p{v[0] + m.origin[0], v[1] + m.origin[1], v[2] + m.origin[2]};
            worst = std::max(worst, std::fabs(std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) - 1.0));
        }
        INFO("farthest vertex from the sphere: " << worst / voxel << " voxels");
        CHECK(worst < 0.5 * voxel);
        const TopologyStats st = mesh_topology(m);
        CHECK(st.components == 1);
        CHECK(st.watertight());
    }
}

TEST_CASE("vdbrecon fuse: a volume over --max-memory stops the run before the other frames", "[fusion][cli]") {
    const Shape shape = make_shape("sphere");
    const double voxel = bounding_box(shape.mesh.vertices).diagonal() / 150.0;
    const Views v = views_of(shape.mesh, 12, 160, 120);
    TempDir scene_dir, out;
    const std::string scene = write_transforms_scene(scene_dir.path(), v.depths, v.K, v.poses, "exr");
    for (const char* rule : {"splat", "tsdf"}) {
        CAPTURE(rule);
        const CliRun r = run_fuse(scene, out.file("m.ply"), voxel,
                                  std::string("--fusion ") + rule + " --max-memory 1M");
        INFO(r.err);
        CHECK(r.code != 0);
        CHECK(r.err.find("over --max-memory 1 MB") != std::string::npos);
        CHECK(r.err.find(" of 12 frames") != std::string::npos);
        CHECK(r.err.find("(12 of 12 frames)") == std::string::npos);
        CHECK_FALSE(file_exists(out.file("m.ply")));
        CHECK(count_files(out.path()) == 0);
    }
}

TEST_CASE("transforms.json with a field of view and no image size (NeRF synthetic)", "[fusion][scene]") {
    // Blender's NeRF-synthetic scenes give camera_angle_x and no w, h or fl_x: the focal
    // length comes from the first image's width. The same frames with fl_x, cx, w, h fuse to
    // the same mesh.
    const Shape shape = make_shape("sphere");
    const double voxel = bounding_box(shape.mesh.vertices).diagonal() / 60.0;
    const Views v = views_of(shape.mesh, 6, 96, 72);
    TempDir scene_dir, out;
    const std::string scene = write_transforms_scene(scene_dir.path(), v.depths, v.K, v.poses, "exr");
    std::string json = read_bytes(scene);
    const std::size_t a = json.find("\"fl_x\""), b = json.find("\"depth_scale\"");
    REQUIRE(a != std::string::npos);
    REQUIRE(b != std::string::npos);
    std::ostringstream angle;
    angle.precision(17);
    angle << "\"camera_angle_x\": " << 2.0 * std::atan(0.5 * v.K.width / v.K.fx) << ",\n  ";
    json.replace(a, b - a, angle.str());
    const std::string fov = scene_dir.file("fov.json");
    write_bytes(fov, json);
    const Scene s = read_scene(fov);
    REQUIRE(s.frames.size() == 6);
    CHECK(s.frames[5].intrinsics.width == v.K.width);
    CHECK(s.frames[5].intrinsics.height == v.K.height);
    CHECK(s.frames[5].intrinsics.fx == Approx(v.K.fx).epsilon(1e-12));
    CHECK(s.frames[5].intrinsics.fy == Approx(v.K.fy).epsilon(1e-12));
    Mesh mesh[2];
    for (int k = 0; k < 2; ++k) {
        const CliRun r = run_fuse(k ? fov : scene, out.file("m.ply"), voxel, "-q --no-vdb");
        INFO(r.err);
        REQUIRE(r.code == 0);
        mesh[k] = read_mesh(out.file("m.ply"));
    }
    CHECK(mesh[0].faces.size() > 1000);
    CHECK(mesh[0].vertices == mesh[1].vertices);  // the header names its input: not the bytes
    CHECK(mesh[0].faces == mesh[1].faces);
}
