// Planar regions with crisp edges (vdbrecon/planes.h).
#include "bind.h"
#include "vdbrecon/planes.h"

namespace vdbrecon::python {

void bind_planes(py::module_& m) {
    OptionsClass<PlaneOptions> o(m, "PlaneOptions",
                                 "Planar regions (region growing), their vertices moved onto the "
                                 "planes, edges and corners, then re-triangulated with few faces.");
    o.field("enabled", &PlaneOptions::enabled, "Run the stage (bool; CLI --planes).")
        .field("angle", &PlaneOptions::angle,
               "A face joins a region within this angle of its plane, degrees (CLI "
               "--plane-angle).")
        .field("distance", &PlaneOptions::distance,
               "... and with its vertices within this of the plane, voxels (CLI "
               "--plane-distance).")
        .field("min_area", &PlaneOptions::min_area,
               "Smaller regions are no plane, square voxels (CLI --plane-min-area).")
        .field("max_move", &PlaneOptions::max_move,
               "No vertex moves farther than this onto its planes, voxels.")
        .field("max_error", &PlaneOptions::max_error,
               "The re-triangulation (regions and the rest of the mesh) moves the surface by "
               "at most this, voxels (CLI --plane-error).")
        .field("region_error", &PlaneOptions::region_error,
               "... but no vertex moves off the plane of a region face around it by more than "
               "this, voxels: regions, creases and corners stay.");
    o.finish();

    py::class_<Plane>(m, "Plane", "normal . x = offset (local frame of the mesh).")
        .def_property_readonly("normal", [](const Plane& p) { return to_tuple(p.normal); })
        .def_readonly("offset", &Plane::offset)
        .def_readonly("area", &Plane::area, "Area of its faces, world units^2.");

    py::class_<PlaneResult>(m, "PlaneResult", "The mesh with planar regions and what was found.")
        .def_readonly("mesh", &PlaneResult::mesh, "The Mesh (regions per face).")
        .def_readonly("planes", &PlaneResult::planes, "A Plane per region.")
        .def_readonly("faces_before", &PlaneResult::faces_before)
        .def_readonly("faces_after", &PlaneResult::faces_after)
        .def_readonly("planar_faces", &PlaneResult::planar_faces,
                      "Faces in a region before the re-triangulation.")
        .def_readonly("edge_vertices", &PlaneResult::edge_vertices,
                      "Vertices moved onto the line of two planes.")
        .def_readonly("corner_vertices", &PlaneResult::corner_vertices,
                      "Vertices moved onto the point of three or more planes.")
        .def_readonly("flips", &PlaneResult::flips,
                      "Edge flips that made the regions' triangulations Delaunay.");

    m.def(
        "planar_regions",
        [](const Mesh& mesh, const PlaneOptions& o, double voxel) {
            return without_gil([&] { return planar_regions(mesh, o, voxel); });
        },
        py::arg("mesh"), py::arg("options"), py::arg("voxel"),
        "Planar regions of a mesh with crisp edges, re-triangulated.");
}

}  // namespace vdbrecon::python
