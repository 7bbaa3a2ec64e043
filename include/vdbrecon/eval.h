// Evaluation of a reconstruction against a reference mesh, and mesh topology statistics.
//
// Both meshes are sampled uniformly by area; each sample's distance to the other mesh is the
// exact point-to-triangle distance (bounding-volume hierarchy). With d_r = distances of
// reconstruction samples to the reference and d_g = of reference samples to the reconstruction:
//   accuracy = mean d_r, completeness = mean d_g, chamfer_l1 = (accuracy + completeness) / 2,
//   hausdorff = max(max d_r, max d_g), precision(tau) = P(d_r < tau), recall(tau) = P(d_g < tau),
//   F(tau) = 2 P R / (P + R) (Knapitsch et al., "Tanks and Temples", 2017),
//   normal_consistency = mean |n . n_closest| over both directions (Mescheder et al. 2019).
// With a coverage mask (EvalOptions::mask_points), d_g keeps only the reference samples within
// mask_distance of a mask point: completeness and recall then score the part of the reference
// that the input actually covers (a turntable scan that misses the top and bottom).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "vdbrecon/types.h"

namespace vdbrecon {

struct EvalOptions {
    /// Distance thresholds for precision/recall/F, world units. Empty: 0.2 % of the reference's
    /// bounding-box diagonal (0.5 mm on the Stanford bunny).
    std::vector<double> taus;
    /// Samples drawn on each mesh (count).
    std::size_t samples = 1000000;
    /// Seed of the sampler; the same seed gives the same numbers.
    std::uint64_t seed = 1;
    /// Coverage mask, e.g. the scan the reconstruction came from: when non-empty, reference
    /// samples farther than `mask_distance` from every mask point are left out of everything
    /// measured from the reference side (completeness, recall, Hausdorff, normal consistency),
    /// so regions the scanner never saw do not count as missing. #M by 3, world units, relative
    /// to `mask_origin`.
    std::vector<Vec3f> mask_points;
    /// World position of the mask points' local frame (PointCloud::origin of a read scan).
    Vec3d mask_origin{0.0, 0.0, 0.0};
    /// Radius of the mask around each mask point, world units; must be > 0 with mask points.
    double mask_distance = 0.0;
    /// Leave out of everything measured from the reconstruction's side (accuracy, precision,
    /// Hausdorff, normal consistency) the reconstruction samples whose closest reference point
    /// lies on an open border of the reference: the part of the reconstruction that covers a
    /// hole of the reference (the Stanford bunny's reference mesh is open underneath), where
    /// there is nothing to compare with.
    bool ignore_reference_holes = false;

    void validate() const;
};

struct TopologyStats {
    std::size_t vertices = 0;
    std::size_t faces = 0;
    std::size_t components = 0;         ///< edge-connected components of faces
    std::size_t boundary_edges = 0;     ///< edges with one incident face
    std::size_t nonmanifold_edges = 0;  ///< edges with more than two incident faces
    std::size_t degenerate_faces = 0;   ///< faces with a repeated vertex index
    std::int64_t euler = 0;             ///< V - E + F (counting referenced vertices only)
    double area = 0.0;                  ///< world units squared
    double signed_volume = 0.0;         ///< positive for closed outward-facing meshes
    bool watertight() const { return boundary_edges == 0 && nonmanifold_edges == 0; }
};

struct FScore {
    double tau = 0, precision = 0, recall = 0, fscore = 0;
};

struct EvalResult {
    double accuracy = 0, completeness = 0, chamfer_l1 = 0, hausdorff = 0;
    double normal_consistency = 0;
    std::vector<FScore> fscores;  ///< one per tau
    std::size_t samples = 0;
    /// Reference samples counted on the reference side: `samples` without a mask, those within
    /// `mask_distance` of a mask point with one.
    std::size_t reference_samples = 0;
    /// Reconstruction samples counted on its side: `samples`, less those over the reference's
    /// holes with ignore_reference_holes.
    std::size_t recon_samples = 0;
    TopologyStats recon, reference;
};

/// Topology statistics of a mesh.
TopologyStats mesh_topology(const Mesh& mesh);

/// Samples `count` points uniformly by area (deterministic for a seed); also returns the face
/// each sample lies on when `faces` is non-null.
std::vector<Vec3f> sample_surface(const Mesh& mesh, std::size_t count, std::uint64_t seed,
                                  std::vector<std::int32_t>* faces = nullptr);

/// Exact distance queries from points to a triangle mesh.
class MeshDistance {
public:
    explicit MeshDistance(const Mesh& mesh);
    ~MeshDistance();
    MeshDistance(const MeshDistance&) = delete;
    MeshDistance& operator=(const MeshDistance&) = delete;

    /// Distance (world units) from `p` to the closest point of the mesh; `face` receives the
    /// index of the closest face when non-null.
    double distance(const Vec3f& p, std::int32_t* face = nullptr) const;
    /// Distances of many points, in parallel.
    std::vector<double> distances(const std::vector<Vec3f>& points,
                                  std::vector<std::int32_t>* faces = nullptr) const;
    /// Distances of a cloud's points, each moved into the mesh's frame first (the two may have
    /// different origins), in parallel.
    std::vector<double> distances(const PointCloud& cloud,
                                  std::vector<std::int32_t>* faces = nullptr) const;

private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

/// Compares a reconstruction with a reference. Both meshes must share a world frame (their
/// origins may differ). Throws InvalidArgument for empty meshes.
EvalResult evaluate(const Mesh& recon, const Mesh& reference, const EvalOptions& options = {});

/// The result as a JSON object (what `vdbrecon eval` prints).
std::string to_json(const EvalResult& result);

}  // namespace vdbrecon
