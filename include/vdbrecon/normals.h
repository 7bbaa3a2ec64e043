// Normal and scale estimation for point clouds.
//
// Normal: the eigenvector of the smallest eigenvalue of the covariance of the k nearest
// neighbours (PCA). Orientation, in order of preference: towards a known viewpoint (sensor
// position) or along a known direction (`up`); otherwise by what the cloud is (OrientRule):
//  - a height field (most normals within 30 degrees of vertical, and a vertical line through
//    the cloud meets one surface in most places: airborne LiDAR, a terrain, a floor seen from
//    above) faces up: its near-horizontal surfaces are turned up and fixed, and the steep rest
//    (walls) takes their orientation by the propagation below;
//  - the same seen from a sensor at the origin (every point in front of it, within a 75-degree
//    cone around +z: a depth camera's frame in its own axes) faces the origin;
//  - anything else: minimum-spanning-tree propagation over the kNN graph with edge cost
//    1 - |n_i . n_j| (H. Hoppe et al., "Surface reconstruction from unorganized points",
//    SIGGRAPH 1992), each connected component's sign then chosen by what it is: an open sheet
//    that faces mostly up or down (its mean normal) faces up, a closed object faces out (the
//    outward flux of its normals), anything else keeps its seed's sign (its highest point,
//    turned away from the centroid).
// Scale: the mean distance to the k nearest neighbours (the sample footprint FSSR expects,
// S. Fuhrmann and M. Goesele, "Floating scale surface reconstruction", SIGGRAPH 2014).
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "vdbrecon/knn.h"
#include "vdbrecon/types.h"

namespace vdbrecon {

enum class NormalMode {
    automatic,  ///< keep the file's normals when every point has one, estimate otherwise
    estimate,   ///< always estimate (ignore the file's normals)
    keep,       ///< use the file's normals; error when the cloud has none
};

enum class ScaleMode {
    automatic,  ///< the file's per-point scale when present, else the kNN spacing
    knn,        ///< always the mean kNN distance
    none,       ///< no per-point scale (splat falls back to a fixed sigma in voxels)
};

/// How estimated normals are oriented when neither a viewpoint nor an up direction is given.
enum class OrientRule {
    automatic,  ///< by what the cloud is (height field, a sensor's frame, MST; see above)
    mst,        ///< always the MST propagation with its per-component sign
};

struct NormalOptions {
    /// Where normals come from.
    NormalMode mode = NormalMode::automatic;
    /// Neighbours used for PCA normals, orientation and the kNN scale (count).
    int k = 10;
    /// Sensor position in world coordinates; when set, normals are turned towards it.
    std::optional<Vec3d> viewpoint;
    /// A direction estimated normals are turned towards (a viewpoint at infinity: 0,0,1 for
    /// airborne data); not with a viewpoint. Either orients each point on its own, so that a
    /// streamed tiled run (PipelineOptions::stream) can estimate normals a region at a time;
    /// without them the orientation propagates over the whole cloud.
    std::optional<Vec3d> up;
    /// Without a viewpoint or `up`: how the orientation is chosen.
    OrientRule orient = OrientRule::automatic;
    /// Where the per-point scale comes from.
    ScaleMode scale = ScaleMode::automatic;
    /// The neighbour search (when the outlier stage hands over no lists).
    KnnOptions knn;

    /// Throws InvalidArgument naming the field when out of range.
    void validate() const;
    /// Whether estimated normals are oriented each on its own (a viewpoint or `up`), not by
    /// propagation over the whole cloud.
    bool orients_locally() const { return viewpoint.has_value() || up.has_value(); }
};

struct NormalResult {
    /// #P unit normals: estimated, or the input's (the same borrowed memory when the input
    /// borrows it and none had to be re-estimated)
    Column<Vec3f> normals;
    Column<float> scales;  ///< #P per-point scale in world units, or empty (ScaleMode::none)
    std::size_t estimated = 0;   ///< points whose normal was estimated here
    std::size_t repaired = 0;    ///< kept normals that were zero/NaN and were re-estimated
    std::size_t flipped = 0;     ///< estimated normals flipped by the orientation step
    std::size_t components = 0;  ///< kNN-graph components oriented separately (MST mode)
    bool oriented_to_viewpoint = false;  ///< towards the viewpoint or along `up`
    /// The rule that oriented the estimated normals, for the log: "viewpoint", "up", "height
    /// field", "sensor at the origin", "MST"; empty when none was estimated.
    std::string orientation;
    /// MST components whose sign was chosen by each rule (orientation "MST" or "height field"):
    /// open sheets turned up, closed objects turned out by their flux, the rest by the seed.
    std::size_t components_up = 0, components_flux = 0, components_seed = 0;
    double median_scale = 0.0;   ///< median of `scales` (0 when none), world units
    /// The median sample spacing from the density of each point's k nearest (see
    /// median_density_spacing in knn.h) when this stage searched neighbours itself, else 0;
    /// world units.
    double density_spacing = 0.0;
};

/// Whether estimate_normals() will estimate any normal, which needs every point's neighbour
/// lists (the kNN scale alone does not: it is summed as the neighbours are searched).
bool normals_need_neighbours(const PointCloud& cloud, const NormalOptions& options = {});

/// Whether estimate_normals() will compute any kNN scale.
bool scales_need_neighbours(const PointCloud& cloud, const NormalOptions& options = {});

/// Estimates (or checks) normals and per-point scale. Deterministic for any thread count.
NormalResult estimate_normals(const PointCloud& cloud, const NormalOptions& options = {});

/// The same, with the cloud's self-neighbours already known (e.g. from remove_outliers, via
/// KnnResult::subset): used when they hold at least options.k neighbours per point, else
/// computed as above. The result is the same either way (up to the order of neighbours at
/// exactly equal distances).
NormalResult estimate_normals(const PointCloud& cloud, const NormalOptions& options,
                              const KnnResult& known_neighbours);

/// The same, with each point's kNN scale already known (the mean distance to its options.k
/// nearest neighbours, e.g. OutlierResult::spacing; one per point): used for the scale, and
/// neighbours are searched only when normals are to be estimated.
NormalResult estimate_normals(const PointCloud& cloud, const NormalOptions& options,
                              const std::vector<float>& known_spacing);

/// The per-point scales alone (and the median and density spacing), as estimate_normals()
/// makes them, from the positions (and any scales the cloud has); the normals are neither read
/// nor returned (NormalResult::normals empty), so a caller may keep them elsewhere meanwhile.
NormalResult estimate_scales(const PointCloud& cloud, const NormalOptions& options = {});

}  // namespace vdbrecon
