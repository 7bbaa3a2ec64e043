// Planar regions of a mesh with crisp edges (after the Las Vegas Reconstruction toolkit's plane
// optimisation, T. Wiemann et al., "Automatic construction of polygonal maps from point cloud
// data", SSRR 2010; and region growing as in their mesh optimisation):
//
//  1. region growing over edge-adjacent faces, seeded at the flattest faces first: a face joins
//     a region when its normal is within `angle` of the region's plane normal and its three
//     vertices are within `distance` of the plane (the plane refitted as the region doubles);
//     regions smaller than `min_area` are no plane. A curved surface flat to within `distance`
//     over `min_area` becomes planar facets (as in LVR): tolerances are the user's;
//  2. each region's plane is the least-squares plane of its vertices;
//  3. vertices are moved onto the planes of the regions around them: one region, onto its plane;
//     two, onto the line where the planes meet (a crisp edge); three or more, onto the point
//     nearest to all of them (a corner) -- never farther than `max_move` (onto one plane: than
//     `distance`). Planes that meet at less than three times `angle` make no crease (facets of
//     one curved surface): such a vertex goes onto one of them;
//  4. the mesh is re-triangulated with few triangles: quadric error edge collapses (decimate.h)
//     that move the surface by at most `max_error`. A collapse inside a flat region, or along a
//     straight crease, costs nothing; corners and open borders stay put (as far as the bound
//     lets them move), the rest of the surface is simplified within the bound, the topology
//     stays (the decimator's link condition and flip test); then
//     Lawson's edge flips (C. Lawson, "Software for C1 surface interpolation", 1977) inside each
//     region make its triangulation the constrained Delaunay triangulation of its border and
//     the vertices left (no slivers where a polygon allows better), in position order.
//
// The region of every face of the result goes to Mesh::regions (-1: none). Deterministic.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "vdbrecon/types.h"

namespace vdbrecon {

struct PlaneOptions {
    /// Run the stage at all (the pipeline's --planes).
    bool enabled = false;
    /// A face joins a region when its normal is within this of the region's plane, degrees.
    double angle = 10.0;
    /// ... and its vertices within this of the plane, voxels.
    double distance = 0.5;
    /// Regions smaller than this are no plane, square voxels.
    double min_area = 50.0;
    /// No vertex moves farther than this onto its planes, voxels.
    double max_move = 2.0;
    /// The re-triangulation moves the surface by at most this, voxels (DecimateOptions::
    /// max_error). It applies to the whole mesh: inside a region and along a straight crease
    /// collapses cost nothing, the regions' ragged outlines straighten within their planes,
    /// and the rest (clutter, curved parts, open borders) is simplified within it. Room scan at
    /// 0.1 m: 0.01 keeps the rest dense (1.8x fewer faces than without the stage), 0.75 gives
    /// 14.8x with 99.9 % of the large regions' points within half a voxel (bench/RESULTS.md).
    double max_error = 0.75;
    /// ... but no vertex moves off the plane of a region face around it by more than this,
    /// voxels: regions, creases and corners stay where step 3 put them.
    double region_error = 0.01;

    /// Throws InvalidArgument naming the field when out of range.
    void validate() const;
};

/// A region's plane: normal . x = offset (unit normal, out of the surface; local frame).
struct Plane {
    Vec3d normal{0.0, 0.0, 1.0};
    double offset = 0.0;
    double area = 0.0;  ///< of its faces, before the re-triangulation, world units^2
};

struct PlaneResult {
    Mesh mesh;  ///< with `regions` per face
    std::vector<Plane> planes;
    std::size_t faces_before = 0, faces_after = 0;
    std::size_t planar_faces = 0;      ///< faces in a region before the re-triangulation
    std::size_t edge_vertices = 0;     ///< vertices moved onto the line of two planes
    std::size_t corner_vertices = 0;   ///< vertices moved onto the point of three or more
    std::size_t flips = 0;             ///< edge flips that made the regions Delaunay
};

/// Finds the planar regions of `mesh` (voxel: the unit of the options' lengths, world units).
PlaneResult planar_regions(const Mesh& mesh, const PlaneOptions& options, double voxel);

}  // namespace vdbrecon
