// Point and mesh files (vdbrecon/io.h).
#include "bind.h"
#include "vdbrecon/io.h"

namespace vdbrecon::python {

namespace {

/// A numpy copy of a vector of integers.
template <typename T>
py::array_t<T> copy_array(const std::vector<T>& v) {
    return py::array_t<T>(py::ssize_t(v.size()), v.data());
}

}  // namespace

void bind_io(py::module_& m) {
    OptionsClass<ReadOptions> read(m, "ReadOptions", "How point files are read.");
    read.choice("non_finite", &ReadOptions::non_finite,
                non_finite_choices(),
                "Rows with NaN/inf coordinates: 'drop' them (a counted warning) or raise "
                "FormatError ('error').")
        .field("local_frame", &ReadOptions::local_frame,
               "Re-centre far-away (georeferenced) coordinates into a local float frame; the "
               "offset is kept in PointCloud.origin.")
        .field("classes", &ReadOptions::classes,
               "LAS input: keep only the points of these classification codes (e.g. [2, 6]); "
               "empty keeps all (CLI --classes).");
    read.finish(false);

    OptionsClass<WriteOptions> write(m, "WriteOptions", "How meshes and points are written.");
    write
        .choice("encoding", &WriteOptions::encoding,
                ply_encoding_choices(),
                "PLY encoding (ignored for OBJ); the CLI's --ascii selects 'ascii'.")
        .field("comments", &WriteOptions::comments,
               "Extra header comments (PLY) or # lines (OBJ), a list of strings.");
    write.finish(false);

    py::class_<ReadResult>(m, "ReadResult", "What read_points found.")
        .def_readonly("cloud", &ReadResult::cloud, "The PointCloud.")
        .def_readonly("format", &ReadResult::format, "e.g. 'ply binary_little_endian', 'xyz'.")
        .def_readonly("rows", &ReadResult::rows, "Rows in the file, before dropping.")
        .def_readonly("dropped_nonfinite", &ReadResult::dropped_nonfinite,
                      "Rows dropped for NaN/inf coordinates.")
        .def_readonly("invalid_normals", &ReadResult::invalid_normals,
                      "Normals that were zero or NaN (set to 0, 0, 0).")
        .def_property_readonly(
            "classification",
            [](const ReadResult& r) { return copy_array(r.las.classification); },
            "LAS: (N,) uint8 ASPRS class of every point (2 ground, 6 building, ...); empty "
            "for other formats.")
        .def_property_readonly(
            "intensity",
            [](const ReadResult& r) { return copy_array(r.las.intensity); },
            "LAS: (N,) uint16 return intensity, sensor units; empty for other formats.")
        .def_property_readonly(
            "return_number",
            [](const ReadResult& r) { return copy_array(r.las.return_number); },
            "LAS: (N,) uint8 return number, 1-based; empty for other formats.")
        .def_property_readonly(
            "number_of_returns",
            [](const ReadResult& r) { return copy_array(r.las.number_of_returns); },
            "LAS: (N,) uint8 returns of the point's pulse; empty for other formats.")
        .def("__repr__", [](const ReadResult& r) {
            return "ReadResult(" + std::to_string(r.cloud.size()) + " points, format='" + r.format +
                   "', rows=" + std::to_string(r.rows) + ")";
        });

    m.def(
        "read_points",
        [](const std::string& path, const ReadOptions& o) {
            return without_gil([&] { return read_points(path, o); });
        },
        py::arg("path"), py::arg("options") = ReadOptions{},
        "Reads a point cloud (.ply .xyz .pts .txt .obj).");
    m.def(
        "read_mesh",
        [](const std::string& path) { return without_gil([&] { return read_mesh(path); }); },
        py::arg("path"), "Reads a triangle mesh (.ply with faces, .obj).");
    m.def(
        "write_mesh",
        [](const std::string& path, const Mesh& mesh, const WriteOptions& o) {
            without_gil([&] { write_mesh(path, mesh, o); });
        },
        py::arg("path"), py::arg("mesh"), py::arg("options") = WriteOptions{},
        "Writes a mesh as .ply or .obj, atomically.");
    m.def(
        "write_points",
        [](const std::string& path, const PointCloud& cloud, const WriteOptions& o) {
            without_gil([&] { write_points(path, cloud, o); });
        },
        py::arg("path"), py::arg("cloud"), py::arg("options") = WriteOptions{},
        "Writes a point cloud as .ply or .xyz, atomically.");
}

}  // namespace vdbrecon::python
