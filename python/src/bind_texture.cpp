// Textures for planar regions (vdbrecon/texture.h).
#include "bind.h"
#include "vdbrecon/texture.h"

namespace vdbrecon::python {

void bind_texture(py::module_& m) {
    OptionsClass<TextureOptions> o(m, "TextureOptions",
                                   "Textures for the planar regions from the points' colours: "
                                   "one rectangle per region, packed into one atlas.");
    o.field("enabled", &TextureOptions::enabled,
            "Run the stage (bool; needs planes_enabled; CLI --texture).")
        .field("texel", &TextureOptions::texel,
               "Edge of a texel, world units; 0 = half a voxel (CLI --texel).")
        .field("max_distance", &TextureOptions::max_distance,
               "Points farther than this from their nearest face colour nothing, voxels.")
        .field("splat_sigma", &TextureOptions::splat_sigma,
               "Standard deviation of a point's footprint in the texture, texels.")
        .field("padding", &TextureOptions::padding,
               "Texels around each region's rectangle, filled like the rest, count.")
        .field("max_size", &TextureOptions::max_size,
               "Largest atlas edge, texels; a finer texel grows until the atlas fits.");
    o.finish();

    py::class_<TextureAtlas>(m, "TextureAtlas", "The planar regions' texture atlas.")
        .def_property_readonly(
            "image",
            [](const TextureAtlas& a) {
                return py::array_t<std::uint8_t>(
                    {py::ssize_t(a.height), py::ssize_t(a.width), py::ssize_t(3)}, a.rgb.data());
            },
            "(height, width, 3) uint8 colours, the first row at the top (v = 1).")
        .def_property_readonly(
            "uv",
            [](const TextureAtlas& a) {
                return py::array_t<float>(
                    {py::ssize_t(a.uv.size()), py::ssize_t(3), py::ssize_t(2)},
                    a.uv.empty() ? nullptr : a.uv[0][0].data());
            },
            "(F, 3, 2) float32 texture coordinates of each face's corners (u right, v up, "
            "0..1); NaN for faces in no region.")
        .def_readonly("width", &TextureAtlas::width)
        .def_readonly("height", &TextureAtlas::height)
        .def_readonly("texel", &TextureAtlas::texel, "The texel used, world units.")
        .def_readonly("regions", &TextureAtlas::regions, "Regions textured.")
        .def_readonly("points", &TextureAtlas::points, "Input points that coloured a texel.")
        .def_readonly("texels", &TextureAtlas::texels,
                      "Texels of the regions' rectangles (padding included).")
        .def_readonly("texels_seen", &TextureAtlas::texels_seen,
                      "Texels reached by a point (the rest interpolated).")
        .def("__repr__", [](const TextureAtlas& a) {
            return "TextureAtlas(" + std::to_string(a.width) + " x " + std::to_string(a.height) +
                   ", " + std::to_string(a.regions) + " regions)";
        });

    m.def(
        "texture_regions",
        [](const Mesh& mesh, const std::vector<Plane>& planes, const PointCloud& points,
           const TextureOptions& o, double voxel) {
            return without_gil([&] { return texture_regions(mesh, planes, points, o, voxel); });
        },
        py::arg("mesh"), py::arg("planes"), py::arg("points"), py::arg("options"),
        py::arg("voxel"), "Textures the planar regions of a mesh from the points' colours.");
    m.def(
        "write_textured_mesh",
        [](const std::string& path, const Mesh& mesh, const TextureAtlas& atlas) {
            without_gil([&] { write_textured_mesh(path, mesh, atlas); });
        },
        py::arg("path"), py::arg("mesh"), py::arg("atlas"),
        "Writes an OBJ with its material file (<stem>.mtl) and atlas (<stem>.texture.png).");
}

}  // namespace vdbrecon::python
