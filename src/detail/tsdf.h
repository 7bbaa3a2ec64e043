// The classic truncated signed distance along the camera rays (Curless and Levoy 1996,
// KinectFusion: Newcombe et al. 2011), the second accumulation rule of range-image fusion
// (fusion.h, DepthOptions::rule == FusionRule::tsdf), with free-space carving.
//
// Per frame, every voxel in a candidate set is projected into the image (pinhole, nearest
// pixel); with d the pixel's planar depth and z the voxel's, sdf = d - z. Voxels with
// sdf < -truncation (behind the surface) are left alone; the others get the running weighted
// average of clamp(sdf / truncation, -1, 1) with weight 1 per frame. Candidates are the leaves
// within the truncation of the frame's back-projected pixels; with carving, also every leaf the
// volume already holds that the camera sees: voxels observed in front of the measured surface
// get +1 (free), so objects that moved away are carved out as frames accumulate.
//
// LiDAR scans (integrate_scan) are not pinhole images. A voxel takes the nearest of the rays
// that cross it (their lines pass within its half diagonal; detail/ray_image.h): in front of its
// hit by the truncation or more the voxel is free (+1); nearer, its value is its distance to the
// hit's tangent plane (the hit's normal from the scan's own neighbours), weighted by the cosine
// of the hit's viewing angle. Voxels no ray crosses are left alone, as VDBFusion's ray traversal
// leaves them (I. Vizzo et al., Sensors 2022): a ray that ends on the ground far away says
// nothing about the ground between the beams.
//
// With colours (one per pixel or hit), a voxel within the truncation of the surface also averages the
// colour of its pixel, with a weight of its own (free-space updates leave it alone).
//
// Each voxel is updated by one task from its own value, frame after frame, so the grids are
// the same bit for bit for any thread count.
#pragma once

#include <openvdb/openvdb.h>

#include <array>
#include <cstdint>
#include <functional>
#include <vector>

#include "detail/volume_grids.h"
#include "vdbrecon/fusion.h"
#include "vdbrecon/splat.h"

namespace vdbrecon::detail {

/// The deepest measured depth of each 8 x 8 block of a frame's pixels (0: none).
struct DepthTiles {
    static constexpr int kLog = 3;
    int columns = 0;
    std::vector<double> max;
    DepthTiles() = default;
    DepthTiles(const std::vector<float>& z, int w, int h);
    /// The deepest depth of the pixels u0..u1 x v0..v1 (and of their blocks' others).
    double deepest(int u0, int v0, int u1, int v1) const;
};

/// A depth frame as TsdfVolume::integrate reads it, made from its pixels alone (not from the
/// volume: frames are prepared in parallel while earlier ones are integrated).
struct TsdfFrame {
    std::vector<float> z;                ///< planar depth per pixel, 0 where nothing was measured
    DepthTiles tiles;                    ///< of z
    std::vector<openvdb::Coord> leaves;  ///< within the truncation of its points, sorted
    std::vector<Vec3f> colors;           ///< per pixel (set by the caller), or empty
    Intrinsics K;
    Pose pose{};
    std::size_t measured = 0;
};

/// One row v of a frame's pixels: their camera-frame points (planar depth in [2]; the
/// back-projection and the measurement rules of depth_samples) and whether each was measured.
using TsdfRows =
    std::function<void(int v, const std::array<double, 3>*& points, const char*& measured)>;

class TsdfVolume {
  public:
    TsdfVolume(double voxel, double truncation_voxels, bool carve, const Vec3d& origin);

    /// A frame made ready to integrate from its rows (K.height calls of `rows`); const, so
    /// several frames may be prepared at once.
    TsdfFrame prepare(const TsdfRows& rows, const Intrinsics& K, const Pose& pose) const;
    /// Adds a prepared frame; returns its measured pixels.
    std::size_t integrate(const TsdfFrame& frame);
    /// Adds a LiDAR scan: its samples (scan_samples: hits with normals toward the sensor,
    /// confidences and colours or none) measured from the sensor at `sensor` (world); returns
    /// the hits used.
    std::size_t integrate_scan(const PointCloud& samples, const Vec3d& sensor);
    /// The volume: sdf = value x truncation (world units) on the voxels with |value| < 1,
    /// weight = frames that saw them, nearest = 0 (no sample positions: no trims).
    SplatResult result() const;
    std::size_t pixels() const { return pixels_; }
    /// Memory of the grids, bytes.
    std::size_t memory_bytes() const;

  private:
    using FloatLeaf = openvdb::FloatTree::LeafNodeType;
    bool leaf_seen(const openvdb::Coord& origin, const Intrinsics& K, const Pose& pose,
                   const DepthTiles& tiles) const;
    using ColorLeaf = openvdb::Vec3fTree::LeafNodeType;
    /// `colors` (per pixel) with their leaves, or none.
    struct LeafColors {
        const std::vector<Vec3f>* pixels = nullptr;
        ColorLeaf* color = nullptr;
        FloatLeaf* weight = nullptr;
    };
    void update_leaf(FloatLeaf& value, FloatLeaf& weight, const std::vector<float>& z,
                     const Intrinsics& K, const Pose& pose, const LeafColors& colors,
                     int vector_rows) const;
    static void update_colors(const LeafColors& colors, openvdb::Index first, std::uint32_t updated,
                              const std::int32_t* pixel, const float* t);
    struct Scan;
    bool leaf_seen(const openvdb::Coord& origin, const Scan& scan) const;
    void update_leaf(FloatLeaf& value, FloatLeaf& weight, const Scan& scan,
                     const LeafColors& colors) const;
    /// Touches `leaves` (within the truncation of a frame's points) and returns the leaves to
    /// update: those, or with carving every leaf held; makes the colour grids' leaves too.
    std::vector<FloatLeaf*> candidates(const std::vector<openvdb::Coord>& leaves, bool colors);
    LeafColors leaf_colors(const std::vector<Vec3f>* colors, const openvdb::Coord& origin) const;
    /// result()'s leaves of one TSDF leaf (none made where no voxel is kept).
    struct ResultLeaves {
        VolumeLeaves leaves;
        std::size_t touched = 0, active = 0;
    };
    void result_leaves(const FloatLeaf& value, float background, ResultLeaves& out) const;

    double voxel_, truncation_;
    bool carve_;
    Vec3d origin_;
    openvdb::FloatGrid::Ptr value_, weight_;
    openvdb::Vec3fGrid::Ptr color_;          ///< averaged colour, once a frame had colours
    openvdb::FloatGrid::Ptr color_weight_;   ///< ... and its weight
    std::size_t pixels_ = 0;
};

}  // namespace vdbrecon::detail
