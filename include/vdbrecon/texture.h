// Textures for the planar regions of a mesh (planes.h), after the Las Vegas Reconstruction
// toolkit's textured planar clusters (T. Wiemann et al., "Automatic construction of polygonal
// maps from point cloud data", SSRR 2010):
//
//  1. each region gets a rectangle of texels in its plane: the smallest-area rectangle around
//     its vertices (u x v = the plane's normal, so the texture is not mirrored seen from
//     outside), with a border of `padding` texels;
//  2. every input point whose nearest mesh face lies in a region, within `max_distance` of it,
//     colours the texels around its projection: a Gaussian of `splat_sigma` texels weights its
//     colour (the weighted mean per texel, in the colours' own encoding, as vertex colours);
//  3. texels no point reached are filled by pull-push interpolation over an image pyramid
//     (S. Gortler et al., "The Lumigraph", SIGGRAPH 1996), so the rectangle is covered whole,
//     also under the padding (no seams where mipmapping reads past a polygon's edge);
//  4. the rectangles are packed on shelves (tallest first) into one atlas of at most `max_size`
//     texels a side; a texel too small for that grows until the atlas fits (with a warning).
//
// Faces in no region get no texture coordinates (they keep the vertex colours). Deterministic:
// each rectangle sums its points in input order, whatever the thread count.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "vdbrecon/io.h"
#include "vdbrecon/planes.h"
#include "vdbrecon/types.h"

namespace vdbrecon {

struct TextureOptions {
    /// Run the stage at all (the pipeline's --texture; needs the planes stage).
    bool enabled = false;
    /// Edge of a texel, world units; 0 = half a voxel.
    double texel = 0.0;
    /// Points farther than this from their nearest face colour nothing, voxels.
    double max_distance = 1.0;
    /// Standard deviation of a point's footprint in the texture, texels.
    double splat_sigma = 0.6;
    /// Texels around each region's rectangle, filled like the rest of it.
    int padding = 2;
    /// Largest atlas edge, texels (4096: 48 MB of 8-bit RGB, what engines take everywhere).
    int max_size = 4096;

    /// Throws InvalidArgument naming the field when out of range.
    void validate() const;
};

/// Texture coordinates (u right, v up, 0..1 over the atlas: the OBJ convention).
using Vec2f = std::array<float, 2>;

struct TextureAtlas {
    int width = 0, height = 0;
    /// 8-bit colours (the points' encoding, normally sRGB), width x height x 3, the first row at
    /// the top of the picture (v = 1).
    std::vector<std::uint8_t> rgb;
    /// Per face, the texture coordinates of its three corners; NaN for faces in no region.
    std::vector<std::array<Vec2f, 3>> uv;
    double texel = 0.0;              ///< the texel used, world units
    std::size_t regions = 0;         ///< regions textured
    std::size_t points = 0;          ///< input points that coloured a texel
    std::size_t texels = 0;          ///< texels of the regions' rectangles (padding included)
    std::size_t texels_seen = 0;     ///< ... of them reached by a point (the rest interpolated)

    bool empty() const { return width == 0; }
};

/// Textures the regions of `mesh` (its `regions` column; `planes`[id] is region id's plane) from
/// the colours of `points` (positions relative to points.origin). `voxel`: the unit of the
/// options' lengths in voxels, world units. Throws InvalidArgument when the points have no
/// colours or the mesh no regions column.
TextureAtlas texture_regions(const Mesh& mesh, const std::vector<Plane>& planes,
                             const PointCloud& points, const TextureOptions& options, double voxel);

/// The material file and the atlas written beside an OBJ: <stem>.mtl and <stem>.texture.png.
std::string texture_mtl_path(const std::string& obj_path);
std::string texture_png_path(const std::string& obj_path);

/// Writes `obj_path` (.obj) with its material file and its atlas (texture_mtl_path,
/// texture_png_path): the faces in a region use the atlas by their texture coordinates, the
/// others a plain material (and the vertex colours, when the mesh has them). Each file is written
/// under a temporary name and renamed into place once all three are written. Throws IoError.
void write_textured_mesh(const std::string& obj_path, const Mesh& mesh, const TextureAtlas& atlas,
                         const WriteOptions& options = {});

}  // namespace vdbrecon
