// Cameras and their images: pinhole intrinsics, camera-to-world poses, depth and colour images
// and organized clouds, as the scene readers (scene.h) give them and fusion (fusion.h) takes
// them. Plain data with no OpenVDB in sight, so the readers build on their own (fuzz/).
//
// Pose convention: camera-to-world rigid transforms, 4x4 row-major, OpenCV camera axes (x
// right, y down, looking down +z). Readers of scenes with OpenGL axes (NeRF/Blender
// transforms.json: y up, looking down -z) convert (scene.h).
#pragma once

#include <array>
#include <cstddef>
#include <vector>

#include "vdbrecon/types.h"

namespace vdbrecon {

/// Pinhole intrinsics in pixels; pixel (u, v) has its centre at (u, v) (u right, v down).
struct Intrinsics {
    double fx = 0.0, fy = 0.0, cx = 0.0, cy = 0.0;
    int width = 0, height = 0;

    /// Throws InvalidArgument naming the field when not usable.
    void validate() const;
};

/// An image's size in pixels; 0 where it is not known.
struct ImageSize {
    int width = 0, height = 0;
};

/// A depth image: width x height values, row-major, top row first, in world units; 0, NaN,
/// inf and negative values are "no measurement".
struct DepthImage {
    int width = 0, height = 0;
    std::vector<float> depth;

    float at(int u, int v) const {
        return depth[std::size_t(v) * std::size_t(width) + std::size_t(u)];
    }
};

/// A colour image: width x height pixels, row-major, top row first, RGB 0..1 (the stored 8-bit
/// values / 255, as point colours are read).
struct ColorImage {
    int width = 0, height = 0;
    std::vector<Vec3f> rgb;
};

/// Camera-to-world rigid transform, row-major 4x4 (OpenCV camera axes).
using Pose = std::array<double, 16>;

/// Throws InvalidArgument when the pose is not finite, its last row not (0 0 0 1), or its 3x3
/// part not a rotation (orthonormal within 1e-3, determinant +1).
void validate_pose(const Pose& pose);

/// An organized cloud (a depth camera's frame as points, PCL's organized PCD): width x height
/// points in raster order, NaN where nothing was measured, relative to `origin`, seen from
/// `sensor` (world).
struct OrganizedCloud {
    int width = 0, height = 0;
    std::vector<Vec3f> points;
    std::vector<Vec3f> colors;  ///< per point (PCD rgb / rgba, 0..1), or empty
    Vec3d origin{0.0, 0.0, 0.0};
    Vec3d sensor{0.0, 0.0, 0.0};
};

}  // namespace vdbrecon
