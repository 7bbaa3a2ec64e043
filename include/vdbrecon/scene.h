// Reading posed depth images: depth image files and the scene files that list them with their
// cameras (`vdbrecon fuse`; fusion.h). No OpenVDB here: the readers build on their own (fuzz/).
//
// Depth images:
//  - OpenEXR: the channel "Z", else "depth" / "Depth", "R", "Y", else a layer's ".Z" / ".Depth"
//    (Blender's "ViewLayer.Depth.Z", Houdini's "depth.Z"); half, float or uint. Blender marks
//    pixels that saw nothing with 1e10 (65504 in half): values >= 65504 are "no measurement".
//  - PNG: 16-bit (or 8-bit) greyscale, value / units_per_metre (TUM: 5000, Open3D/Redwood and
//    most depth cameras: 1000); 0 = no measurement.
// Scenes:
//  - transforms.json (NeRF / Blender / instant-ngp / nerfstudio): `fl_x fl_y cx cy w h` or
//    `camera_angle_x` [`camera_angle_y`], optionally per frame; `frames[]` with
//    `depth_file_path` (else `file_path` plus a depth suffix tried in turn: _depth.exr,
//    _depth.png, _depth_0001.exr, _depth_0001.png, .depth.exr) and a 4x4 camera-to-world
//    `transform_matrix` in OpenGL camera axes (x right, y up, looking down -z), converted to
//    OpenCV axes. cx, cy count from the image's corner (pixel (0, 0) covers [0,1]^2), as
//    NeRF's ray generators do, so our pixel-centre intrinsics are cx - 0.5, cy - 0.5.
//    `depth_scale` or `integer_depth_scale` (metres per stored unit) applies to PNG depth.
//  - an organized PCD file (PCL's depth camera frames): one frame of points, fused by
//    organized_samples.
//  - TUM RGB-D folder (or its depth.txt): `depth.txt` (timestamp path) and `groundtruth.txt`
//    (timestamp tx ty tz qx qy qz qw, camera-to-world, OpenCV axes), associated by the nearest
//    timestamp within 0.02 s (TUM's associate.py); the intrinsics must be given.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "vdbrecon/camera.h"
#include "vdbrecon/types.h"

namespace vdbrecon {

/// Reads a depth image (.exr, .png); PNG values are divided by `units_per_metre` (EXR values
/// are taken as they are). The size the header claims is checked before any pixel buffer is
/// made: against `expected` (a side of 0: any; a frame's intrinsics' size), against the largest
/// image (2^16 a side, 2^27 pixels) and against what the file's bytes can hold. Throws IoError /
/// FormatError naming the file.
DepthImage read_depth_image(const std::string& path, double units_per_metre = 1000.0,
                            const ImageSize& expected = {});

/// Reads a colour image: .png (8- or 16-bit grey, RGB, RGBA or palette; libpng) or .jpg /
/// .jpeg (libjpeg-turbo), as RGB 0..1. Throws IoError / FormatError naming the file.
ColorImage read_color_image(const std::string& path);

/// Writes a colour image as 8-bit RGB: .png, or .jpg at quality 95. Atomic. Throws IoError /
/// InvalidArgument.
void write_color_image(const std::string& path, const ColorImage& image);

/// Writes a depth image: .exr (one float channel "Z") or .png (16-bit greyscale, value =
/// round(depth x units_per_metre), 0 for no measurement; depths past 65535 units are refused).
/// Atomic (temporary file + rename). Throws IoError / InvalidArgument.
void write_depth_image(const std::string& path, const DepthImage& depth,
                       double units_per_metre = 1000.0);

/// One frame of a scene.
struct SceneFrame {
    std::string depth_path;  ///< a depth image, or an organized cloud's file
    bool organized = false;  ///< depth_path is an organized cloud (read_organized_cloud)
    /// depth_path is a LiDAR scan in its sensor's frame (KITTI .bin: float32 x y z intensity;
    /// or a point file), `pose` the sensor to world: its points are sampled by scan_samples
    /// from the sensor at the pose's origin.
    bool scan = false;
    Intrinsics intrinsics;  ///< width/height 0: taken from the image (cx, cy then its centre)
    Pose pose{};            ///< camera to world, OpenCV axes
    double units_per_metre = 1000.0;  ///< for PNG depth
    /// A stored PNG value that means "no measurement" besides 0 (7-Scenes' 65535); 0 = none.
    int invalid_value = 0;
    /// The frame's colour image (.png, .jpg), or empty.
    std::string color_path;
    /// The colour camera's intrinsics when they are not the depth's (ScanNet); without them a
    /// colour image of another size is the depth camera's scaled.
    std::optional<Intrinsics> color_intrinsics;
};

struct SceneOptions {
    /// PNG depth units per metre; 0 = the scene's own (transforms.json's depth_scale; TUM 5000;
    /// else 1000).
    double units_per_metre = 0.0;
    /// Intrinsics for every frame (required for TUM; overrides transforms.json's).
    std::optional<Intrinsics> intrinsics;
};

struct Scene {
    /// The layout: "transforms.json", "tum", "7-Scenes/3DMatch", "Redwood/Open3D", "ScanNet",
    /// "Replica", "KITTI", "organized pcd"
    std::string kind;
    std::vector<SceneFrame> frames;
};

/// Reads an organized cloud: a PCD file with HEIGHT > 1 (ascii, binary or binary_compressed);
/// NaN points are kept as holes of the raster, the sensor is the VIEWPOINT's position (its
/// orientation is not needed: normals face the sensor). Throws IoError / FormatError.
OrganizedCloud read_organized_cloud(const std::string& path);

/// The sensors of a multi-scan point file, by scan index: each a position (a scanner at a
/// point) or a unit direction toward the scanner (an orthographic range scanner, as the
/// Stanford scans were taken).
struct ScanSensors {
    std::vector<Vec3d> origins;     ///< one per scan, or empty
    std::vector<Vec3d> directions;  ///< one per scan, or empty
    std::size_t size() const { return origins.empty() ? directions.size() : origins.size(); }
};

/// Reads scan sensors: a Stanford .conf (`bmesh file tx ty tz qx qy qz qw` per scan, in scan
/// order; each scan looks along +z of its frame, world = R(q)^T p + t: directions), or a text
/// file of `x y z` per scan (origins; # comments). Throws IoError / FormatError.
ScanSensors read_scan_sensors(const std::string& path);

/// Reads a KITTI velodyne scan (.bin: float32 x y z intensity a point, little-endian) as its
/// points in the sensor's frame, in file order; points with NaN or inf coordinates are kept
/// (what uses them leaves them out). Throws IoError / FormatError naming the file.
std::vector<Vec3f> read_kitti_scan(const std::string& path);

/// Reads a scene: a transforms.json file, or a folder of one of the layouts, detected by the
/// files present: transforms.json, TUM RGB-D (depth.txt), 7-Scenes / 3DMatch, Redwood /
/// Open3D, ScanNet, Replica / NICE-SLAM, KITTI LiDAR scans (see src/detail/scene_layouts.h); a
/// folder that is none of them is an error listing what was looked for. The depth files are not
/// opened, except the first of a transforms.json that gives a field of view and no image size
/// (NeRF's synthetic scenes), for its size. Throws IoError / FormatError / InvalidArgument
/// naming the file.
Scene read_scene(const std::string& path, const SceneOptions& options = {});

}  // namespace vdbrecon
