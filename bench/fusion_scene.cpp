// Writes a depth sequence for bench/fusion.sh as a transforms.json scene (16-bit PNG depth,
// 8-bit colour images rgb_i.png where there is colour):
//
//   fusion_scene MESH OUTDIR [--frames 30] [--size 640 480] [--noise 0] [--scale 1] [--paint P]
//     renders MESH (its vertices times `scale`) from `frames` poses on a sphere (Fibonacci
//     spiral, 1.6 diagonals from its centre, 50 degree field of view), adds Gaussian depth noise
//     of `noise` world units, and paints the mesh with test::paint_pattern (period P world
//     units, default a sixth of the diagonal; bench/paint.py scores against it). A scaled mesh
//     is written as OUTDIR/reference.ply.
//   fusion_scene --pcd ORGANIZED.pcd OUTDIR [--frames 30]
//     a real depth camera's frame (PCL's organized PCD, camera frame) as `frames` images of a
//     static camera: depth = z, intrinsics fitted to the points (least squares of u against
//     x / z and of v against y / z), colour where the cloud has it.
//
// Depth is stored in the finest power-of-ten unit whose 16 bits hold the farthest depth (10 um
// for the bunny, 0.1 mm for Kinect ranges); prints the json's path.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <string>

#include "depth_scenes.h"
#include "vdbrecon/io.h"
#include "vdbrecon/scene.h"

using namespace vdbrecon;

namespace {

struct Args {
    std::string input, dir;
    bool pcd = false;
    int frames = 30, width = 640, height = 480;
    double noise = 0.0, scale = 1.0, paint = 0.0;
};

Args parse(int argc, char** argv) {
    Args a;
    int positional = 0;
    for (int i = 1; i < argc; ++i) {
        const char* s = argv[i];
        const auto next = [&]() { return i + 1 < argc ? argv[++i] : throw std::runtime_error(s); };
        if (!std::strcmp(s, "--pcd"))
            a.pcd = true;
        else if (!std::strcmp(s, "--frames"))
            a.frames = std::atoi(next());
        else if (!std::strcmp(s, "--size"))
            a.width = std::atoi(next()), a.height = std::atoi(next());
        else if (!std::strcmp(s, "--noise"))
            a.noise = std::atof(next());
        else if (!std::strcmp(s, "--scale"))
            a.scale = std::atof(next());
        else if (!std::strcmp(s, "--paint"))
            a.paint = std::atof(next());
        else if (positional == 0)
            a.input = s, ++positional;
        else if (positional == 1)
            a.dir = s, ++positional;
        else
            throw std::runtime_error(s);
    }
    if (positional != 2 || a.frames < 1) throw std::runtime_error("arguments");
    return a;
}

/// Least-squares fit of pixel = f * t + c over the pairs (t, pixel).
void fit_axis(const std::vector<std::array<double, 2>>& pairs, double& f, double& c) {
    double n = 0, st = 0, sp = 0, stt = 0, stp = 0;
    for (const auto& q : pairs)
        n += 1, st += q[0], sp += q[1], stt += q[0] * q[0], stp += q[0] * q[1];
    f = (n * stp - st * sp) / (n * stt - st * st);
    c = (sp - f * st) / n;
}

/// The finest power-of-ten depth unit (per world unit) whose 16 bits hold every depth.
double depth_units(const std::vector<DepthImage>& depths) {
    float far = 0.0f;
    for (const DepthImage& d : depths)
        for (float z : d.depth) far = std::isfinite(z) ? std::max(far, z) : far;
    return std::pow(10.0, std::floor(std::log10(65535.0 / std::max(double(far), 1e-3))));
}

std::string write_pcd_scene(const Args& a) {
    const OrganizedCloud c = read_organized_cloud(a.input);
    DepthImage d{c.width, c.height, std::vector<float>(c.points.size(), 0.0f)};
    std::vector<std::array<double, 2>> us, vs;
    for (int v = 0; v < c.height; ++v) {
        for (int u = 0; u < c.width; ++u) {
            const std::size_t i = std::size_t(v) * std::size_t(c.width) + std::size_t(u);
            const Vec3f& p = c.points[i];
            const double x = p[0] + c.origin[0] - c.sensor[0], y = p[1] + c.origin[1] - c.sensor[1],
                         z = p[2] + c.origin[2] - c.sensor[2];
            if (!(z > 0.0) || !std::isfinite(x) || !std::isfinite(y)) continue;
            d.depth[i] = float(z);
            us.push_back({x / z, double(u)});
            vs.push_back({y / z, double(v)});
        }
    }
    Intrinsics K{0, 0, 0, 0, c.width, c.height};
    fit_axis(us, K.fx, K.cx);
    fit_axis(vs, K.fy, K.cy);
    std::fprintf(stderr, "fitted intrinsics: fx %.3f fy %.3f cx %.3f cy %.3f (%zu pixels)\n", K.fx,
                 K.fy, K.cx, K.cy, us.size());
    Pose pose{1, 0, 0, c.sensor[0], 0, 1, 0, c.sensor[1], 0, 0, 1, c.sensor[2], 0, 0, 0, 1};
    if (!c.colors.empty()) {
        const ColorImage rgb{c.width, c.height, c.colors};
        for (int i = 0; i < a.frames; ++i)
            write_color_image(a.dir + "/rgb_" + std::to_string(i) + ".png", rgb);
    }
    const std::vector<DepthImage> depths(std::size_t(a.frames), d);
    return test::write_transforms_scene(a.dir, depths, K,
                                        std::vector<Pose>(std::size_t(a.frames), pose), "png",
                                        depth_units(depths));
}

std::string write_mesh_scene(const Args& a) {
    Mesh mesh = read_mesh(a.input);
    for (Vec3f& p : mesh.vertices.edit())
        p = Vec3f{float(p[0] * a.scale), float(p[1] * a.scale), float(p[2] * a.scale)};
    for (double& o : mesh.origin) o *= a.scale;
    if (a.scale != 1.0) write_mesh(a.dir + "/reference.ply", mesh);  // what to score against
    const BBox b = bounding_box(mesh.vertices);
    const Vec3d centre{0.5 * (double(b.min[0]) + b.max[0]) + mesh.origin[0],
                       0.5 * (double(b.min[1]) + b.max[1]) + mesh.origin[1],
                       0.5 * (double(b.min[2]) + b.max[2]) + mesh.origin[2]};
    const Intrinsics K = test::camera_intrinsics(a.width, a.height, 50.0);
    const std::vector<Pose> poses = test::orbit_poses(a.frames, centre, 1.6 * b.diagonal());
    std::vector<DepthImage> depths;
    for (int i = 0; i < a.frames; ++i) {
        depths.push_back(test::render_depth(mesh, K, poses[std::size_t(i)]));
        if (a.noise > 0.0) test::add_depth_noise(depths.back(), a.noise, std::uint64_t(i) + 1);
    }
    const double s = a.paint > 0.0 ? a.paint : b.diagonal() / 6.0;
    const auto paint = [s](const Vec3d& p) { return test::paint_pattern(p, s); };
    for (int i = 0; i < a.frames; ++i) {
        const Pose& pose = poses[std::size_t(i)];
        const DepthImage clean = test::render_depth(mesh, K, pose);
        write_color_image(a.dir + "/rgb_" + std::to_string(i) + ".png",
                          test::render_color(clean, K, pose, paint));
    }
    std::fprintf(stderr, "camera %.3f from the centre, focal %.1f pixels\n", 1.6 * b.diagonal(),
                 K.fx);
    return test::write_transforms_scene(a.dir, depths, K, poses, "png", depth_units(depths));
}

}  // namespace

int main(int argc, char** argv) {
    Args a;
    try {
        a = parse(argc, argv);
    } catch (const std::exception& e) {
        std::fprintf(stderr,
                     "fusion_scene: bad argument near '%s'\nusage: fusion_scene MESH OUTDIR "
                     "[--frames N] [--size W H] [--noise S] [--scale S] [--paint P]\n"
                     "       fusion_scene --pcd ORGANIZED.pcd OUTDIR [--frames N]\n",
                     e.what());
        return 2;
    }
    std::printf("%s\n", (a.pcd ? write_pcd_scene(a) : write_mesh_scene(a)).c_str());
    return 0;
}
