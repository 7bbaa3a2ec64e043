// Reading posed depth images: depth image files and the scene files that list them with their
// cameras (`vdbrecon fuse`).
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

#include "vdbrecon/fusion.h"

namespace vdbrecon {

/// Reads a depth image (.exr, .png); PNG values are divided by `units_per_metre` (EXR values
/// are taken as they are). Throws IoError / FormatError naming the file.
DepthImage read_depth_image(const std::string& path, double units_per_metre = 1000.0);

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
    /// "Replica", "organized pcd"
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

/// What `vdbrecon fuse` does besides the pipeline's options.
struct FuseOptions {
    /// A point-file scene (SCENE is .ply, .xyz, .las, ...): the sensors of its scans (the
    /// points' `scan` property picks one; without it, the only sensor). Empty for depth scenes.
    std::string scan_sensors;
    SceneOptions scene;
    DepthOptions depth;
    /// Integrate every step-th frame (1 = all).
    std::size_t frame_step = 1;
    /// At most this many frames (0 = all).
    std::size_t max_frames = 0;
    /// A frame that cannot be read or fused (a corrupt or missing file, another size) is
    /// skipped with one warning naming it, instead of stopping the run with that error.
    bool skip_bad_frames = false;
    /// Fuse the frames' colour images where the scene has them (vertex colours); false skips
    /// them (--no-color).
    bool color = true;
    /// LiDAR scans: points nearer to the sensor than this, or farther than max_range (0 =
    /// none), are no measurement (the car's own roof, far noise); world units.
    double min_range = 0.0;
    double max_range = 0.0;
};

/// Reads a scene, fuses its frames one at a time (the pipeline's splat options; voxel 0 =
/// auto_voxel_factor x the first frame's median pixel footprint), meshes and writes the result
/// as run() does (mesh, <out>.splat.vdb, preview; all or nothing). Errors name the scene and
/// the depth file. The local frame's origin is the first camera's position.
RunResult fuse(const std::string& scene, const std::string& output, const PipelineOptions& options,
               const FuseOptions& fuse_options = {}, const StageCallback& on_stage = {});

/// Reads a scene: a transforms.json file, or a folder of one of the layouts, detected by the
/// files present: transforms.json, TUM RGB-D (depth.txt), 7-Scenes / 3DMatch, Redwood /
/// Open3D, ScanNet, Replica / NICE-SLAM, KITTI LiDAR scans (see src/detail/scene_layouts.h); a folder that is none
/// of them is an error listing what was looked for. The depth files are not opened. Throws
/// IoError / FormatError / InvalidArgument naming the file.
Scene read_scene(const std::string& path, const SceneOptions& options = {});

}  // namespace vdbrecon
