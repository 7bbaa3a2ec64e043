// A shaded preview picture of a mesh: z-buffer rasterisation with a perspective camera that
// frames the whole mesh, written as PNG (8-bit sRGB) or OpenEXR (linear float R, G, B, A and a
// depth channel Z).
//
// Camera: looks at the centre of the bounding box from where the area-weighted mean normal points
// (an open scan is seen from its scanned side), or, for closed shapes whose normals cancel out,
// from the front (+z) and a little above (+y), aimed at the centre of the bounding box and as
// close as keeps 99.5 % of the vertices in the picture (stray fragments do not shrink the view). Up is +y,
// or +z when the view is along y. Shading: a key light from the upper left of the camera and a
// fill light, applied to the vertex colours (when the mesh has them; taken as sRGB values like
// 8-bit PLY colours) or to a neutral clay colour; back faces -- the inside of an open surface,
// or wrongly oriented triangles -- are tinted orange. 2x2 supersampling.
//
// Deterministic: triangles are drawn in order, ties in depth keep the earlier one.
#pragma once

#include <string>
#include <vector>

#include "vdbrecon/types.h"

namespace vdbrecon {

struct PreviewOptions {
    int width = 960;   ///< pixels
    int height = 720;  ///< pixels
    /// Vertical field of view, degrees.
    double fov_degrees = 35.0;

    /// Throws InvalidArgument naming the field when out of range.
    void validate() const;
};

struct Image {
    int width = 0, height = 0;
    std::vector<float> rgb;    ///< width*height*3, linear, row-major from the top
    std::vector<float> alpha;  ///< width*height coverage, 0..1
    /// width*height distance from the camera plane along the view axis, world units; +infinity
    /// where no surface was hit.
    std::vector<float> depth;
};

/// Renders the mesh (see above). Throws InvalidArgument for an empty mesh.
Image render_preview(const Mesh& mesh, const PreviewOptions& options = {});

/// Throws InvalidArgument unless the path ends in .png or .exr (what write_image writes).
void check_image_path(const std::string& path);

/// Writes the image as .png or .exr (by extension), atomically. Throws IoError, InvalidArgument
/// for another extension.
void write_image(const std::string& path, const Image& image);

}  // namespace vdbrecon
