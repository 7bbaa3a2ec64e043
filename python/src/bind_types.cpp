// PointCloud and Mesh (vdbrecon/types.h). Their arrays are numpy views of the C++ arrays (no
// copy); the views keep the owning object alive. The arrays are never resized after
// construction, so the views stay valid: to change an attribute, build a new object. A
// PointCloud built from numpy arrays borrows them (Column::borrow): no copy either way.
#include "bind.h"

namespace vdbrecon::python {

namespace {

Vec3d to_vec3d(const py::handle& o, const char* name) {
    try {
        const auto v = o.cast<std::array<double, 3>>();
        return {v[0], v[1], v[2]};
    } catch (const py::cast_error&) {
        throw py::type_error(std::string(name) + ": expected three numbers (x, y, z)");
    }
}

}  // namespace

void bind_types(py::module_& m) {
    py::class_<PointCloud>(m, "PointCloud",
                           "An unstructured point sample of a surface. World position = origin + "
                           "position (positions are float32 relative to a double origin, so "
                           "georeferenced coordinates keep their precision).")
        .def(py::init([](const py::object& positions, const py::object& normals,
                         const py::object& colors, const py::object& scales,
                         const py::object& confidences, const py::object& origin) {
                 PointCloud c;
                 c.positions = borrow_rows(positions, "positions");
                 const auto n = py::ssize_t(c.positions.size());
                 if (!normals.is_none()) c.normals = borrow_rows(normals, "normals", n);
                 if (!colors.is_none()) c.colors = borrow_rows(colors, "colors", n);
                 if (!scales.is_none()) c.scales = borrow_column(scales, "scales", n);
                 if (!confidences.is_none()) {
                     c.confidences = borrow_column(confidences, "confidences", n);
                 }
                 c.origin = to_vec3d(origin, "origin");
                 return c;
             }),
             py::arg("positions"), py::arg("normals") = py::none(), py::arg("colors") = py::none(),
             py::arg("scales") = py::none(), py::arg("confidences") = py::none(),
             py::arg("origin") = py::make_tuple(0.0, 0.0, 0.0),
             "Borrows C-contiguous float32 arrays without copying them (the cloud keeps them "
             "alive; change them only when no call is using the cloud): positions (N, 3) world "
             "units relative to origin; normals (N, 3) unit, outward; colors (N, 3) linear 0..1 "
             "RGB; scales (N,) sample footprint in world units; confidences (N,). Other dtypes "
             "and layouts raise TypeError here; the vdbrecon functions convert them once.")
        .def_property_readonly(
            "positions",
            [](py::object self) { return view_rows(self.cast<PointCloud&>().positions, self); },
            "(N, 3) float32 view, world units relative to `origin`.")
        .def_property_readonly(
            "normals",
            [](py::object self) { return view_or_none(self.cast<PointCloud&>().normals, self); },
            "(N, 3) float32 view of unit outward normals, or None.")
        .def_property_readonly(
            "colors",
            [](py::object self) { return view_or_none(self.cast<PointCloud&>().colors, self); },
            "(N, 3) float32 view of linear 0..1 RGB colours, or None.")
        .def_property_readonly(
            "scales",
            [](py::object self) { return view_or_none(self.cast<PointCloud&>().scales, self); },
            "(N,) float32 view of per-point footprints (world units), or None.")
        .def_property_readonly(
            "confidences",
            [](py::object self) {
                return view_or_none(self.cast<PointCloud&>().confidences, self);
            },
            "(N,) float32 view of per-point confidences, or None.")
        .def_property(
            "origin", [](const PointCloud& c) { return to_tuple(c.origin); },
            [](PointCloud& c, const py::object& o) { c.origin = to_vec3d(o, "origin"); },
            "World position of the local frame's origin, (x, y, z) doubles.")
        .def("__len__", &PointCloud::size)
        .def("has_normals", &PointCloud::has_normals)
        .def("has_colors", &PointCloud::has_colors)
        .def("has_scales", &PointCloud::has_scales)
        .def("__repr__", [](const PointCloud& c) {
            std::string s = "PointCloud(" + std::to_string(c.size()) + " points";
            if (c.has_normals()) s += ", normals";
            if (c.has_colors()) s += ", colors";
            if (c.has_scales()) s += ", scales";
            if (c.has_confidences()) s += ", confidences";
            return s + ")";
        });

    py::class_<Mesh>(m, "Mesh",
                     "An indexed triangle mesh; world position = origin + vertex. Triangles are "
                     "counter-clockwise seen from outside.")
        .def(py::init([](const py::object& vertices, const py::object& faces,
                         const py::object& normals, const py::object& colors,
                         const py::object& origin) {
                 Mesh mesh;
                 mesh.vertices = borrow_rows(vertices, "vertices");
                 const auto n = py::ssize_t(mesh.vertices.size());
                 mesh.faces = borrow_faces(faces, "faces", mesh.vertices.size());
                 if (!normals.is_none()) mesh.normals = borrow_rows(normals, "normals", n);
                 if (!colors.is_none()) mesh.colors = borrow_rows(colors, "colors", n);
                 mesh.origin = to_vec3d(origin, "origin");
                 return mesh;
             }),
             py::arg("vertices"), py::arg("faces"), py::arg("normals") = py::none(),
             py::arg("colors") = py::none(), py::arg("origin") = py::make_tuple(0.0, 0.0, 0.0),
             "Borrows (no copy; the mesh keeps them alive) vertices (V, 3) float32, faces (F, 3) "
             "int32 (indices checked), optional normals and colors (V, 3) float32. Views of "
             "borrowed arrays are read-only.")
        .def_property_readonly(
            "vertices",
            [](py::object self) { return view_rows(self.cast<Mesh&>().vertices, self); },
            "(V, 3) float32 view, world units relative to `origin`.")
        .def_property_readonly(
            "faces", [](py::object self) { return view_faces(self.cast<Mesh&>().faces, self); },
            "(F, 3) int32 view of vertex indices, counter-clockwise seen from outside.")
        .def_property_readonly(
            "normals",
            [](py::object self) { return view_or_none(self.cast<Mesh&>().normals, self); },
            "(V, 3) float32 view of unit outward vertex normals, or None.")
        .def_property_readonly(
            "colors", [](py::object self) { return view_or_none(self.cast<Mesh&>().colors, self); },
            "(V, 3) float32 view of linear 0..1 RGB vertex colours, or None.")
        .def_property_readonly(
            "regions",
            [](const Mesh& mesh) -> py::object {
                if (mesh.regions.empty()) return py::none();
                return py::array_t<std::int32_t>(py::ssize_t(mesh.regions.size()),
                                                 mesh.regions.data());
            },
            "(F,) int32 copy of each face's planar region (-1: none; planes=True), or None.")
        .def_property(
            "origin", [](const Mesh& c) { return to_tuple(c.origin); },
            [](Mesh& c, const py::object& o) { c.origin = to_vec3d(o, "origin"); },
            "World position of the local frame's origin, (x, y, z) doubles.")
        .def("empty", &Mesh::empty, "True when the mesh has no faces.")
        .def("__repr__", [](const Mesh& mesh) {
            return "Mesh(" + std::to_string(mesh.vertices.size()) + " vertices, " +
                   std::to_string(mesh.faces.size()) + " faces" +
                   (mesh.normals.empty() ? "" : ", normals") +
                   (mesh.colors.empty() ? "" : ", colors") + ")";
        });
}

}  // namespace vdbrecon::python
