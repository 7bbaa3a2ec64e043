// Range-image fusion: posed depth images become oriented, scaled, weighted samples, splatted
// into the same sparse grids as point input, one frame at a time (SplatAccumulator), so memory
// follows the grid, not the number of frames.
//
// Each valid pixel (u, v) with depth d is back-projected through the pinhole model to the
// camera-frame point p = d (( u - cx) / fx, (v - cy) / fy, 1) (planar depth; for range along
// the ray, d is first divided by the ray's length) and moved to the world by the pose. As in
// FSSR's input path (S. Fuhrmann and M. Goesele, "Floating Scale Surface Reconstruction",
// SIGGRAPH 2014):
//  - normal: the cross product of the central differences to the pixel's four neighbours
//    (one-sided where a neighbour is missing), oriented toward the camera; a neighbour across
//    a depth jump (relative difference > max_jump) is not used, and a pixel with no usable pair
//    gives no sample;
//  - scale: the pixel footprint, d / f (f = the mean focal length in pixels), divided by the
//    cosine of the viewing angle (a grazing pixel covers more surface);
//  - merging: where the pixel footprint is far below the voxel, b x b pixel blocks become one
//    sample (their mean; confidence x their count), which is what kernels wider than the pixel
//    spacing would average anyway;
//  - confidence: the cosine of the viewing angle (pixels at a grazing angle below
//    min_view_cos give no sample) times (reference depth / d)^2 past the reference depth:
//    structured-light and stereo depth noise grows with the square of the depth (Khoshelham
//    and Elberink 2012), so far pixels weigh less.
//
// Cameras, poses and images are camera.h's (camera-to-world, OpenCV axes); scenes of them are
// read by scene.h's readers; fuse() below runs the whole command.
#pragma once

#include <array>
#include <cstddef>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "vdbrecon/camera.h"
#include "vdbrecon/pipeline.h"
#include "vdbrecon/scene.h"
#include "vdbrecon/splat.h"
#include "vdbrecon/types.h"
#include "vdbrecon/volume.h"

namespace vdbrecon {

/// What a depth value measures.
enum class DepthKind {
    planar,  ///< along the optical axis (z), as depth cameras and renderers' Z passes give
    ray,     ///< range along the pixel's ray
};

/// How frames are accumulated.
enum class FusionRule {
    splat,  ///< FSSR samples into the splat's grids (the default: one code path with points)
    tsdf,   ///< truncated signed distance along the rays, with free-space carving (VDBFusion,
            ///< KinectFusion; src/detail/tsdf.h)
};

struct DepthOptions {
    DepthKind kind = DepthKind::planar;
    FusionRule rule = FusionRule::splat;
    /// tsdf: the truncation distance, voxels.
    double truncation = 4.0;
    /// tsdf: carve free space (voxels seen in front of the surface move toward +1, so objects
    /// that moved away disappear).
    bool carve = true;
    /// Depths at or below this (world units) are "no measurement".
    double min_depth = 0.0;
    /// Depths beyond this are "no measurement" (world units; 0 = no limit).
    double max_depth = 0.0;
    /// Neighbours whose depth differs by more than this fraction of the pixel's depth are
    /// across a depth jump: not used for its normal (dimensionless).
    double max_jump = 0.05;
    /// Pixels seen at a grazing angle, cos(angle between the ray and the normal) below this,
    /// give no sample. 0.2 (78 degrees): the samples between 0.1 and 0.2 are the noisiest and,
    /// with footprints up to 10x a pixel's, did half the splat's work; without them the bunny
    /// sequence at 1 mm scores F@1mm 0.99999 / Chamfer 35.7 um (0.99969 / 36.2 um with them),
    /// the Kinect frame at 1.3 cm has 99.5 % of its mesh within a voxel of the scan (98.6 %) from
    /// 98.5 % of the samples, the bunny's range scans F@0.5mm 0.99714 (0.99711).
    double min_view_cos = 0.2;
    /// Frames whose median pixel footprint is below this (world units) are merged into b x b
    /// pixel blocks, b = floor(merge_footprint / footprint) <= 4: each block's pixels on one
    /// surface become one sample at their mean, standing for (confidence x) their count. Samples
    /// much denser than the smallest kernel (min_sigma_voxels voxels) only add work: kernels
    /// wider than their spacing average them anyway. 0 = never; < 0 = automatic (Fusion: half
    /// the smallest kernel, 0.5 x min_sigma_voxels x voxel / scale_factor, so merged samples
    /// stay at most sigma/2 apart; bunny frames at 0.58 mm footprint: no merging at voxel 1 mm,
    /// 3 x 3 blocks at 4 mm, integration 4x faster, F@4mm 0.9983 either way).
    double merge_footprint = -1.0;
    /// Samples presummed before the splat (aggregate_samples, splat.h): those of one sigma
    /// level in one cell of this edge (in sigmas) whose normals agree within 90 degrees become
    /// one kernel at their mean. Frames see each patch many times with several pixels per
    /// voxel, so the kernels drop tenfold or more (bunny sequence, 30 frames at 1 mm: 1.19 M
    /// samples, 84 k kernels at 1.5; F@1mm 0.99969 vs 0.99988 and Chamfer 36.2 vs 36.5 um
    /// against none; 1.0: 0.99978 / 35.6 um at 184 k kernels; 2.0: 0.99966 / 40.0 um).
    /// 0 = every sample its own kernel.
    double aggregate = 1.5;
    /// Samples gathered before they are splatted together (0: every frame on its own). Only
    /// time and memory depend on it (and the last bits of the grids: a batch's cell groups are
    /// summed once more, and its nearest samples are compared with the stored ones' distances):
    /// the same options give the same grids for any thread count.
    std::size_t batch_samples = std::size_t(1) << 21;
    /// Depth up to which pixels have full confidence; beyond it the confidence falls as
    /// (reference / d)^2 (world units; 0 = no fall-off).
    double reference_depth = 0.0;

    /// Throws InvalidArgument naming the field when out of range.
    void validate() const;
};

/// The oriented samples of one frame: positions relative to `origin`, normals toward the
/// camera, scales (footprint) and confidences. Pixels without a measurement, a normal or
/// a usable viewing angle give none. Throws InvalidArgument when the image does not match the
/// intrinsics' size or the pose is not a rotation.
PointCloud depth_samples(const DepthImage& depth, const Intrinsics& K, const Pose& camera_to_world,
                         const DepthOptions& options, const Vec3d& origin = {0.0, 0.0, 0.0});

/// Gives each sample (relative to samples.origin) the colour the camera with intrinsics K at
/// `camera_to_world` saw there: the sample projected into `color` (its own intrinsics, as
/// ScanNet's colour camera has; the same pose as the depth) and read bilinearly, clamped at the
/// border. A sample's colour is then splatted with the weights of its signed distance, so a
/// surface's colour is the weighted mean of the pixels that saw it.
void color_samples(PointCloud& samples, const ColorImage& color, const Intrinsics& K,
                   const Pose& camera_to_world);

/// The oriented samples of an organized cloud, by the rules of depth_samples (neighbours in
/// the raster, normals toward the sensor, footprint, confidence). Throws InvalidArgument when
/// the points do not fill width x height.
PointCloud organized_samples(const OrganizedCloud& cloud, const DepthOptions& options,
                             const Vec3d& origin = {0.0, 0.0, 0.0});

/// The oriented samples of one scan's points seen from its sensor (a position, else a unit
/// direction toward it): normals kept from the cloud or estimated from the scan's own
/// neighbours (k = normals.k), turned toward the sensor; scale the kNN spacing unless the cloud
/// has scales; confidence the cosine of the viewing angle (below min_view_cos: no sample).
PointCloud scan_samples(const PointCloud& scan, const std::optional<Vec3d>& origin,
                        const std::optional<Vec3d>& direction, const DepthOptions& options,
                        int k = 10);

/// Fuses posed depth images (and oriented clouds) into one volume, one frame at a time.
namespace detail {
class TsdfVolume;
class CellGroups;
struct TsdfFrame;
}

/// A depth frame made ready for a fusion by Fusion::prepare: the splat rule's samples
/// presummed, or the tsdf rule's planar depth and the leaves it reaches.
struct PreparedFrame {
    PointCloud groups;                              ///< splat rule
    std::shared_ptr<const detail::TsdfFrame> tsdf;  ///< tsdf rule
    std::size_t samples = 0;  ///< the samples (tsdf: measured pixels) it stands for
};

class Fusion {
  public:
    /// options.splat.voxel_size must be > 0. `origin`: the world position of the local frame
    /// (pick one near the scene, e.g. the first camera, for far-away coordinates).
    explicit Fusion(const PipelineOptions& options, const DepthOptions& depth = {},
                    const Vec3d& origin = {0.0, 0.0, 0.0});
    ~Fusion();
    Fusion(Fusion&&) noexcept;
    Fusion& operator=(Fusion&&) noexcept;

    /// Adds one frame; returns its number of samples (0: nothing usable in it, not an error).
    std::size_t integrate(const DepthImage& depth, const Intrinsics& K, const Pose& camera_to_world);
    /// The same with its colour image, seen through `color_K` from the same pose
    /// (color_samples); the tsdf rule takes the depth only.
    std::size_t integrate(const DepthImage& depth, const Intrinsics& K, const Pose& camera_to_world,
                          const ColorImage& color, const Intrinsics& color_K);
    /// Adds an oriented cloud (normals required), e.g. one scan with normals toward its sensor.
    std::size_t integrate(const PointCloud& cloud);
    /// A depth frame (and its colour image seen through *color_K, or none) made ready for
    /// integrate(PreparedFrame) without changing the fusion, so several frames may be prepared
    /// at once, from several threads, while earlier ones are integrated.
    PreparedFrame prepare(const DepthImage& depth, const Intrinsics& K, const Pose& camera_to_world,
                          const ColorImage* color = nullptr,
                          const Intrinsics* color_K = nullptr) const;
    /// The colour image of a frame made when prepare() needs it: returns it (null: none) and
    /// sets its intrinsics; it must live until prepare() returns.
    using ColorSource = std::function<const ColorImage*(Intrinsics& color_K)>;
    /// The same, the colour image asked for only when it is needed (the splat rule: after the
    /// depth samples are made, so that a frame's depth and colour arrays are not held at once).
    PreparedFrame prepare(const DepthImage& depth, const Intrinsics& K, const Pose& camera_to_world,
                          const ColorSource& color) const;
    /// Adds a frame made by this fusion's prepare(): the same volume as integrate() of the
    /// frame; returns its samples.
    std::size_t integrate(const PreparedFrame& frame);
    /// Adds an organized cloud (organized_samples).
    std::size_t integrate(const OrganizedCloud& cloud);
    /// Adds a LiDAR scan: its points (relative to scan.origin, colours optional) measured from
    /// the sensor at `sensor` (world). The splat rule samples it (scan_samples: normals from the
    /// scan's own neighbours, toward the sensor); the tsdf rule updates the voxels its rays
    /// cross, carving the free space in front of each hit. Returns the samples or hits used.
    std::size_t integrate_scan(const PointCloud& scan, const Vec3d& sensor);

    /// The fused volume so far (NumericalError when nothing valid was integrated).
    Volume volume() const;
    /// The same with the splat's statistics.
    SplatResult splat() const;
    /// The same, spending the fusion: its sums are freed as the volume is made (the volume
    /// takes their memory), and nothing integrated before is left in it.
    SplatResult take_splat();
    /// close > mesh > clean > fill of the fused volume, by the pipeline's options.
    PipelineResult reconstruct(const StageCallback& on_stage = {},
                               const VolumeCallback& on_volume = {}) const;

    /// Memory of what the fusion holds (its sums, or the tsdf rule's grids), bytes.
    std::size_t memory_bytes() const;
    std::size_t frames() const { return frames_; }
    std::size_t samples() const;
    const PipelineOptions& options() const { return options_; }
    const DepthOptions& depth_options() const { return depth_; }
    const Vec3d& origin() const { return accumulator_.origin(); }
    bool tsdf() const { return bool(tsdf_); }

  private:
    PipelineOptions options_;
    DepthOptions depth_;
    /// Counts a frame and adds its samples; returns their count.
    std::size_t add_frame(const PointCloud& samples);
    /// The samples (relative to origin()) presummed (DepthOptions::aggregate).
    PointCloud presum(PointCloud samples) const;
    /// Adds presummed groups that stand for `samples` samples.
    void add(const PointCloud& groups, std::size_t samples);
    void flush() const;
    /// splat(), or take_splat() when `take` (the accumulator is mutable, as flush() needs).
    SplatResult fused(bool take) const;

    // Samples are gathered into batches of depth.batch_samples before they are splatted (a
    // batch touches each block's stored sums once): presummed frames'
    // groups into the batch's cell groups (groups_, the frames' groups of one cell summed
    // once more), samples not presummed (depth.aggregate 0) into pending_. Flushing a batch
    // does not change what the fusion holds, so the const accessors may do it.
    mutable SplatAccumulator accumulator_;
    mutable PointCloud pending_;
    mutable std::unique_ptr<detail::CellGroups> groups_;
    mutable std::size_t batched_ = 0;  ///< samples (or groups) in the batch
    std::size_t samples_ = 0;  ///< samples added (before aggregation)
    std::unique_ptr<detail::TsdfVolume> tsdf_;  ///< rule == tsdf
    std::size_t frames_ = 0;
};

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

}  // namespace vdbrecon
