// Posed depth images rendered from known meshes, for the fusion tests and bench/fusion: a
// perspective z-buffer (planar depth, exact for the mesh's planar triangles), camera poses on a
// sphere around the object looking at its centre, and scene files (transforms.json with OpenGL
// poses, a TUM folder with OpenCV poses) written beside the depth images.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "vdbrecon/fusion.h"

namespace vdbrecon::test {

/// The planar depth of `mesh` seen by a camera (OpenCV axes, camera to world); 0 where no face.
DepthImage render_depth(const Mesh& mesh, const Intrinsics& K, const Pose& camera_to_world);

/// `count` camera poses on a sphere of `radius` around `centre` (a Fibonacci spiral, so every
/// side is seen), each looking at the centre.
std::vector<Pose> orbit_poses(int count, const Vec3d& centre, double radius);

/// Intrinsics of a width x height camera with horizontal field of view `fov_degrees`.
Intrinsics camera_intrinsics(int width, int height, double fov_degrees);

/// A smooth colour pattern of period `period` (world units) over space, to paint scenes whose
/// fused colours are checked: (0.5 + 0.4 sin(x/s), 0.5 + 0.4 cos(y/s), 0.5 + 0.4 sin(z/s + 1))
/// (bench/paint.py scores against the same).
Vec3f paint_pattern(const Vec3d& p, double period);

/// The colours `paint` gives the world points a camera sees (its depth image `depth`, planar);
/// black where it sees nothing.
ColorImage render_color(const DepthImage& depth, const Intrinsics& K, const Pose& camera_to_world,
                        const std::function<Vec3f(const Vec3d&)>& paint);

/// Adds Gaussian noise of `sigma` (world units) to every measured depth (seeded).
void add_depth_noise(DepthImage& depth, double sigma, std::uint64_t seed);

/// Writes the frames as <dir>/d_<i>.<ext> and <dir>/transforms.json (fl_x fl_y cx cy w h,
/// OpenGL transform_matrix, depth_scale for PNG); returns the json's path.
std::string write_transforms_scene(const std::string& dir, const std::vector<DepthImage>& depths,
                                   const Intrinsics& K, const std::vector<Pose>& poses,
                                   const std::string& ext, double units_per_metre = 1000.0);

/// Writes the frames as a TUM RGB-D folder: depth/<t>.png (5000 units per metre), depth.txt,
/// groundtruth.txt (quaternions); returns the folder.
std::string write_tum_scene(const std::string& dir, const std::vector<DepthImage>& depths,
                            const std::vector<Pose>& poses);

/// Writes the frames in a dataset layout: "7scenes" (frame-NNNNNN.depth.png in mm with 65535
/// where nothing was seen, .pose.txt, camera-intrinsics.txt), "redwood" (depth/*.png,
/// trajectory.log, camera_intrinsic.json), "scannet" (depth/N.png, pose/N.txt,
/// intrinsic/intrinsic_depth.txt) or "replica" (results/depthNNNNNN.png at 6553.5 units a
/// metre, traj.txt, cam_params.json); returns the folder.
/// With `colors`, each frame's colour image too where the layout has them (7scenes
/// frame-NNNNNN.color.png, redwood color/*.jpg, scannet color/N.jpg with
/// intrinsic/intrinsic_color.txt, replica results/frameNNNNNN.jpg).
std::string write_layout_scene(const std::string& layout, const std::string& dir,
                               const std::vector<DepthImage>& depths, const Intrinsics& K,
                               const std::vector<Pose>& poses,
                               const std::vector<ColorImage>* colors = nullptr);

}  // namespace vdbrecon::test
