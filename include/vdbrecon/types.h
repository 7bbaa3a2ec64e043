// vdbrecon: surface reconstruction from oriented point clouds on OpenVDB grids.
//
// Core data types shared by every stage. Points and meshes are structures of arrays whose
// per-point attributes are N x 3 row-major float arrays (std::vector<Vec3f>), so they map to
// numpy (N, 3) float32 arrays without copies.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace vdbrecon {

/// A 3-vector of floats; 12 bytes, no padding, so std::vector<Vec3f> is an N x 3 float array.
using Vec3f = std::array<float, 3>;
/// A 3-vector of doubles (world-frame origins, viewpoints).
using Vec3d = std::array<double, 3>;
/// A triangle: three vertex indices, counter-clockwise seen from outside.
using Triangle = std::array<std::int32_t, 3>;

static_assert(sizeof(Vec3f) == 12, "Vec3f must be three packed floats");
static_assert(sizeof(Triangle) == 12, "Triangle must be three packed int32");

/// An unstructured point sample of a surface.
///
/// Positions are stored relative to `origin` (world = origin + position) so that georeferenced
/// coordinates (e.g. 1e7 m) keep float precision. Every optional attribute is either empty or
/// has exactly one entry per point.
struct PointCloud {
    std::vector<Vec3f> positions;  ///< #P by 3, world units, relative to `origin`
    std::vector<Vec3f> normals;    ///< #P by 3 or empty; unit length, pointing out of the object
    std::vector<Vec3f> colors;     ///< #P by 3 or empty; linear 0..1 RGB
    std::vector<float> scales;     ///< #P or empty; sample footprint (spacing), world units
    std::vector<float> confidences;  ///< #P or empty; per-point confidence (file-defined units)
    Vec3d origin{0.0, 0.0, 0.0};     ///< world position of the local frame's origin

    std::size_t size() const { return positions.size(); }
    bool empty() const { return positions.empty(); }
    bool has_normals() const { return !normals.empty(); }
    bool has_colors() const { return !colors.empty(); }
    bool has_scales() const { return !scales.empty(); }
    bool has_confidences() const { return !confidences.empty(); }
};

/// An indexed triangle mesh. Vertices are relative to `origin`, like PointCloud positions.
struct Mesh {
    std::vector<Vec3f> vertices;    ///< #V by 3, world units, relative to `origin`
    std::vector<Vec3f> normals;     ///< #V by 3 or empty; unit outward vertex normals
    std::vector<Vec3f> colors;      ///< #V by 3 or empty; linear 0..1 RGB
    std::vector<Triangle> faces;    ///< #F by 3, counter-clockwise seen from outside
    Vec3d origin{0.0, 0.0, 0.0};    ///< world position of the local frame's origin

    bool empty() const { return faces.empty(); }
};

/// Axis-aligned bounding box of float positions; empty when min > max.
struct BBox {
    Vec3f min{1.0f, 1.0f, 1.0f};
    Vec3f max{0.0f, 0.0f, 0.0f};
    bool empty() const { return min[0] > max[0]; }
    /// Length of the diagonal (0 for an empty box).
    double diagonal() const;
};

/// Bounding box of a set of positions.
BBox bounding_box(const std::vector<Vec3f>& positions);

}  // namespace vdbrecon
