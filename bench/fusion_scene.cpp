// Writes a rendered depth sequence of a mesh for bench/fusion.sh: `fusion_scene MESH OUTDIR
// [frames] [width] [height] [noise]` renders MESH from `frames` poses on a sphere (Fibonacci
// spiral, 1.6 diagonals from its centre, 50 degree field of view), adds Gaussian depth noise of
// `noise` world units, and writes OUTDIR/transforms.json with 16-bit PNG depth (10 um units)
// and 8-bit colour images rgb_i.png of the mesh painted with test::paint_pattern (period
// `paint` world units, default a sixth of the diagonal; bench/paint.py scores against it).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "depth_scenes.h"
#include "vdbrecon/io.h"
#include "vdbrecon/scene.h"

using namespace vdbrecon;

int main(int argc, char** argv) {
    if (argc < 3) {
        std::fprintf(stderr, "usage: fusion_scene MESH OUTDIR [frames 30] [width 640] [height 480] "
                             "[noise 0] [paint period: diagonal / 6]\n");
        return 2;
    }
    const Mesh mesh = read_mesh(argv[1]);
    const std::string dir = argv[2];
    const int frames = argc > 3 ? std::atoi(argv[3]) : 30;
    const int width = argc > 4 ? std::atoi(argv[4]) : 640, height = argc > 5 ? std::atoi(argv[5]) : 480;
    const double noise = argc > 6 ? std::atof(argv[6]) : 0.0;
    const BBox b = bounding_box(mesh.vertices);
    const Vec3d centre{0.5 * (double(b.min[0]) + b.max[0]) + mesh.origin[0],
                       0.5 * (double(b.min[1]) + b.max[1]) + mesh.origin[1],
                       0.5 * (double(b.min[2]) + b.max[2]) + mesh.origin[2]};
    const Intrinsics K = test::camera_intrinsics(width, height, 50.0);
    const std::vector<Pose> poses = test::orbit_poses(frames, centre, 1.6 * b.diagonal());
    std::vector<DepthImage> depths;
    for (int i = 0; i < frames; ++i) {
        depths.push_back(test::render_depth(mesh, K, poses[std::size_t(i)]));
        if (noise > 0.0) test::add_depth_noise(depths.back(), noise, std::uint64_t(i) + 1);
    }
    const double s = argc > 7 ? std::atof(argv[7]) : b.diagonal() / 6.0;
    const auto paint = [s](const Vec3d& p) { return test::paint_pattern(p, s); };
    for (int i = 0; i < frames; ++i) {
        const Pose& pose = poses[std::size_t(i)];
        const DepthImage clean = test::render_depth(mesh, K, pose);
        write_color_image(dir + "/rgb_" + std::to_string(i) + ".png",
                          test::render_color(clean, K, pose, paint));
    }
    const std::string json = test::write_transforms_scene(dir, depths, K, poses, "png", 1e5);
    std::printf("%s\n", json.c_str());
    return 0;
}
