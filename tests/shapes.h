// Closed test shapes with known geometry, for the watertightness and sharpness tests and for
// bench/shapes: CAD parts made of planes and cylinders (extrusions, lofts and stacks of planar
// regions, turned off the grid axes by a rotation) and smooth organic shapes, each an exact,
// closed, 2-manifold triangle mesh; uniform random oriented samples of them (exact face normals,
// not a raster); their sharp edges and corners; and a block with thin walls between spherical
// cavities, sampled from its implicit description.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "vdbrecon/types.h"

namespace vdbrecon::test {

struct Shape {
    std::string name;
    Mesh mesh;         ///< closed, 2-manifold, counter-clockwise seen from outside
    bool cad = false;  ///< made of planes and cylinders, with sharp edges
    double area = 0.0;
};

/// Names of the CAD parts: cube, lbracket, fan, drilled, boss, pocket, cross.
std::vector<std::string> cad_shape_names();
/// Names of the smooth shapes: sphere, torus, blob.
std::vector<std::string> organic_shape_names();
/// The shape of that name, about one unit across, rotated off the grid axes; besides the names
/// above, "house" (a gabled house: walls, a two-plane roof, gable ends, a floor; the planes
/// tests only). Throws std::invalid_argument for an unknown name.
Shape make_shape(const std::string& name);

/// `n` points drawn uniformly by area on the mesh (seeded), each with its face's exact normal.
PointCloud sample_uniform(const Mesh& mesh, std::size_t n, std::uint64_t seed);

/// The sample spacing of `n` uniform samples on `area`: sqrt(area / n), the raster spacing of
/// the same density.
double spacing_of(double area, std::size_t n);

/// Sharp edges (dihedral angle above `angle_degrees`) as segments, and corners (vertices where
/// three or more sharp edges meet).
struct Features {
    std::vector<Vec3f> corners;
    std::vector<std::array<Vec3f, 2>> edges;
};
Features sharp_features(const Mesh& mesh, double angle_degrees = 30.0);

/// Points along the sharp edges, at most `step` apart (both ends of each edge included).
std::vector<Vec3f> points_on_edges(const Features& f, double step);

/// How far a reconstruction of `shape` lies from it, in voxels of `voxel` (world units): the
/// worst distance of its vertices to the shape's surface; for a CAD part also the worst point of
/// a sharp edge (points every quarter voxel along the edges; distance to the reconstruction)
/// and the worst corner (distance to the nearest vertex); 0 for a smooth shape.
struct Deviation {
    double vertex = 0.0, edge = 0.0, corner = 0.0;
};
Deviation deviation(const Shape& shape, const Mesh& mesh, double voxel);

/// A block of edge 1 with spherical cavities cut into it: one opening through each of two faces
/// and meeting each other, and one closed inside. The thinnest walls, between the cavities and
/// between a cavity and a face, are `wall` thick (world units). `n` uniform random samples with
/// exact normals (outward from the solid).
PointCloud sample_thin_walled_block(double wall, std::size_t n, std::uint64_t seed,
                                    double* area = nullptr);

/// Removes the samples within `radius` of the first sample's position taken, for each of
/// `count` holes, from seeded random samples of the cloud: round holes of diameter 2 radius
/// punched into the surface, at least 4 radii apart. Returns the hole centres.
std::vector<Vec3f> punch_holes(PointCloud& cloud, int count, double radius, std::uint64_t seed);

}  // namespace vdbrecon::test
