// Readers of RGB-D dataset layouts (scene_layouts.cpp), each listing the frames of a folder as
// read_scene() does (scene.h): depth file, intrinsics, camera-to-world pose in OpenCV axes, PNG
// depth units. Missing or unreadable files throw IoError / FormatError naming them.
//  - 7-Scenes / 3DMatch: frame-NNNNNN.depth.png (mm; 0 and 65535 are no measurement) with
//    frame-NNNNNN.pose.txt (4x4 camera-to-world); camera-intrinsics.txt (3x3) in the folder or
//    its parent, else --intrinsics.
//  - Redwood / Open3D: one *.log trajectory (per frame three ids and a 4x4 camera-to-world),
//    depth/*.png (mm) in name order, camera_intrinsic.json as Open3D writes it (width, height,
//    a column-major intrinsic_matrix), else --intrinsics.
//  - ScanNet exports: depth/N.png (mm), pose/N.txt (4x4; a pose of -inf rows, ScanNet's lost
//    tracking, is skipped with a warning), intrinsic/intrinsic_depth.txt (4x4, K top-left).
//  - KITTI LiDAR sequences: velodyne/*.bin (float32 x y z intensity; or .ply / .pcd scans) and
//    poses.txt (a 3x4 pose a line); with calib.txt's `Tr:` (velodyne to camera 0) the poses
//    are camera 0's, and the scans go into the first scan's LiDAR frame (Tr^-1 P_i Tr, as
//    VDBFusion writes its meshes); without it the poses are the scans' own.
//  - Replica / NICE-SLAM: traj.txt (a 4x4 camera-to-world a line), results/depthNNNNNN.png,
//    cam_params.json (camera: w h fx fy cx cy scale) in the folder or its parent, else
//    --intrinsics (and --depth-scale; NICE-SLAM's is 6553.5 units a metre).
#pragma once

#include <string>

#include "vdbrecon/scene.h"

namespace vdbrecon::detail {

Scene read_7scenes(const std::string& folder, const SceneOptions& options);
Scene read_redwood(const std::string& folder, const std::string& log, const SceneOptions& options);
Scene read_scannet(const std::string& folder, const SceneOptions& options);
Scene read_replica(const std::string& folder, const SceneOptions& options);
Scene read_kitti(const std::string& folder, const SceneOptions& options);

/// Which of the layouts above `folder` holds ("7scenes", "redwood" with its trajectory in
/// `log`, "scannet", "replica", "kitti"), or "" for none.
std::string detect_layout(const std::string& folder, std::string& log);

}  // namespace vdbrecon::detail
