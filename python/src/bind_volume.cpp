// The fused volume (vdbrecon/volume.h) and its .vdb files. Grids cross into Python as .vdb
// paths or as numpy arrays of active voxels (index coordinates + values); the pyopenvdb bridge
// is in vdbrecon/__init__.py (through a temporary .vdb file: Debian's pyopenvdb is
// Boost.Python and shares no objects with this module).
#include <cmath>
#include <cstring>

#include "bind.h"
#include "vdbrecon/volume.h"

namespace vdbrecon::python {

namespace {

template <typename GridT>
py::tuple active_arrays(const GridT& grid) {
    using Value = typename GridT::ValueType;
    constexpr bool kVector = !std::is_same_v<Value, float>;
    std::vector<std::array<std::int32_t, 3>> coords;
    std::vector<Value> values;
    const auto count = grid.activeVoxelCount();
    coords.reserve(count);
    values.reserve(count);
    for (auto it = grid.cbeginValueOn(); it; ++it) {
        const Value v = *it;
        if (it.isVoxelValue()) {
            const openvdb::Coord c = it.getCoord();
            coords.push_back({c.x(), c.y(), c.z()});
            values.push_back(v);
        } else {  // an active tile: every voxel it covers
            const openvdb::CoordBBox box = it.getBoundingBox();
            for (auto c = box.begin(); c; ++c) {
                coords.push_back({(*c).x(), (*c).y(), (*c).z()});
                values.push_back(v);
            }
        }
    }
    py::array c = adopt(std::move(coords), 3);
    if constexpr (kVector) {
        std::vector<Vec3f> rows(values.size());
        if (!rows.empty()) std::memcpy(rows.data(), values.data(), rows.size() * sizeof(Vec3f));
        return py::make_tuple(c, adopt(std::move(rows), 3));
    } else {
        return py::make_tuple(c, adopt(std::move(values), 0));
    }
}

std::vector<std::array<std::int32_t, 3>> to_coords(const py::handle& obj, const char* name) {
    using Array = py::array_t<std::int32_t, py::array::c_style>;
    const std::string expected =
        std::string(name) + ": expected a C-contiguous int32 array of shape (N, 3)";
    if (!py::isinstance<Array>(obj)) throw py::type_error(expected);
    Array a = py::reinterpret_borrow<Array>(obj);
    if (a.ndim() != 2 || a.shape(1) != 3) throw py::value_error(expected);
    std::vector<std::array<std::int32_t, 3>> v(std::size_t(a.shape(0)));
    if (!v.empty()) std::memcpy(v.data(), a.data(), v.size() * 12);
    return v;
}

openvdb::math::Transform::Ptr make_transform(double voxel, const Vec3d& origin) {
    auto xform = openvdb::math::Transform::createLinearTransform(voxel);
    xform->postTranslate(openvdb::Vec3d(origin[0], origin[1], origin[2]));
    return xform;
}

Volume from_arrays(const py::object& coords_obj, const py::object& sdf_obj, double voxel_size,
                   const Vec3d& origin, const py::object& weight_obj, const py::object& nearest_obj,
                   const py::object& color_obj, const py::object& fill_obj,
                   const py::object& background_obj) {
    if (!(std::isfinite(voxel_size) && voxel_size > 0.0)) {
        throw InvalidArgument("voxel_size = " + std::to_string(voxel_size) +
                              ": must be a positive number (world units)");
    }
    const auto coords = to_coords(coords_obj, "coords");
    const auto n = py::ssize_t(coords.size());
    const Column<float> sdf = borrow_column(sdf_obj, "sdf", n);
    Column<float> weight;
    Column<Vec3f> nearest, color;
    if (!weight_obj.is_none()) weight = borrow_column(weight_obj, "weight", n);
    if (!nearest_obj.is_none()) nearest = borrow_rows(nearest_obj, "nearest", n);
    if (!color_obj.is_none()) color = borrow_rows(color_obj, "color", n);
    double background = 3.0 * voxel_size;
    if (!background_obj.is_none()) {
        background = background_obj.cast<double>();
        if (!(std::isfinite(background) && background > 0.0)) {
            throw InvalidArgument("background must be a positive distance (world units)");
        }
    } else {
        for (const float d : sdf) background = std::max(background, double(std::abs(d)));
    }

    Volume v;
    v.voxel_size = voxel_size;
    v.origin = origin;
    auto xform = make_transform(voxel_size, origin);
    v.sdf = openvdb::FloatGrid::create(float(background));
    v.sdf->setName("sdf");
    v.sdf->setGridClass(openvdb::GRID_LEVEL_SET);
    v.sdf->setTransform(xform);
    {
        auto acc = v.sdf->getAccessor();
        for (std::size_t i = 0; i < coords.size(); ++i) {
            const auto& c = coords[i];
            if (!std::isfinite(sdf[i])) {
                throw InvalidArgument("sdf: value " + std::to_string(i) + " is not finite");
            }
            acc.setValueOn(openvdb::Coord(c[0], c[1], c[2]),
                           std::clamp(sdf[i], -float(background), float(background)));
        }
    }
    if (!weight.empty()) {
        v.weight = openvdb::FloatGrid::create(0.0f);
        v.weight->setName("weight");
        v.weight->setTransform(xform->copy());
        auto acc = v.weight->getAccessor();
        for (std::size_t i = 0; i < coords.size(); ++i) {
            acc.setValueOn(openvdb::Coord(coords[i][0], coords[i][1], coords[i][2]), weight[i]);
        }
    }
    const auto vec_grid = [&](Span<Vec3f> values, const char* name) {
        auto g = openvdb::Vec3fGrid::create(openvdb::Vec3f(0.0f));
        g->setName(name);
        g->setTransform(xform->copy());
        auto acc = g->getAccessor();
        for (std::size_t i = 0; i < coords.size(); ++i) {
            const Vec3f& x = values[i];
            acc.setValueOn(openvdb::Coord(coords[i][0], coords[i][1], coords[i][2]),
                           openvdb::Vec3f(x[0], x[1], x[2]));
        }
        return g;
    };
    if (!nearest.empty()) {
        v.nearest = vec_grid(nearest, "nearest");
        v.nearest->setVectorType(openvdb::VEC_CONTRAVARIANT_RELATIVE);
    }
    if (!color.empty()) {
        v.color = vec_grid(color, "color");
        v.color->setVectorType(openvdb::VEC_INVARIANT);
    }
    if (!fill_obj.is_none()) {  // a mask: 1 on its voxels, as close_volume() makes it
        v.fill = openvdb::FloatGrid::create(0.0f);
        v.fill->setName("fill");
        v.fill->setTransform(xform->copy());
        auto acc = v.fill->getAccessor();
        for (const auto& c : to_coords(fill_obj, "fill")) {
            acc.setValueOn(openvdb::Coord(c[0], c[1], c[2]), 1.0f);
        }
    }
    return v;
}

py::list grid_names(const Volume& v) {
    py::list names;
    if (v.sdf) names.append("sdf");
    if (v.weight) names.append("weight");
    if (v.nearest) names.append("nearest");
    if (v.sdf) names.append("density");
    if (v.color) names.append("color");
    if (v.fill) names.append("fill");
    return names;
}

}  // namespace

void bind_volume(py::module_& m) {
    py::class_<Volume>(m, "Volume",
                       "The fused volume: sparse OpenVDB grids 'sdf' (level set, world units, "
                       "negative inside), 'weight' (summed kernel weight), 'nearest' (vector to "
                       "the nearest sample, world units), optional 'color', optional 'fill' (1 on "
                       "the voxels a closing vouches for, see close()), and 'density' (fog 0..1, "
                       "derived from sdf). Index-to-world: world = origin + voxel_size * "
                       "ijk. Cheap to copy (grids are shared, never modified in place).")
        .def_static(
            "from_arrays",
            [](const py::object& coords, const py::object& sdf, double voxel_size,
               const py::object& origin, const py::object& weight, const py::object& nearest,
               const py::object& color, const py::object& fill, const py::object& background) {
                const auto o = origin.cast<std::array<double, 3>>();
                return from_arrays(coords, sdf, voxel_size, {o[0], o[1], o[2]}, weight, nearest,
                                   color, fill, background);
            },
            py::arg("coords"), py::arg("sdf"), py::kw_only(), py::arg("voxel_size"),
            py::arg("origin") = py::make_tuple(0.0, 0.0, 0.0), py::arg("weight") = py::none(),
            py::arg("nearest") = py::none(), py::arg("color") = py::none(),
            py::arg("fill") = py::none(), py::arg("background") = py::none(),
            "Builds a Volume from active voxels: coords (N, 3) int32 index coordinates, sdf (N,) "
            "float32 signed distances in world units (negative inside); optional weight (N,), "
            "nearest (N, 3) and color (N, 3) on the same voxels; optional fill (M, 3) int32 index "
            "coordinates of the voxels a closing vouches for (to_arrays('fill')[0]). "
            "background: the sdf value of inactive voxels, world units (default max(3 voxels, "
            "max |sdf|)).")
        .def_readonly("voxel_size", &Volume::voxel_size, "Voxel edge, world units.")
        .def_property_readonly(
            "origin", [](const Volume& v) { return to_tuple(v.origin); },
            "World position of index (0, 0, 0).")
        .def_readonly("metadata", &Volume::metadata,
                      "File metadata (kernel, sigma range, options, ...), str -> str.")
        .def("grids", &grid_names, "Names of the grids this volume has (and writes).")
        .def("empty", &Volume::empty, "True when the sdf grid has no active voxel.")
        .def_property_readonly(
            "active_voxels",
            [](const Volume& v) { return v.sdf ? std::size_t(v.sdf->activeVoxelCount()) : 0; },
            "Valid (active) voxels of the sdf grid.")
        .def_property_readonly(
            "background", [](const Volume& v) { return v.sdf ? double(v.sdf->background()) : 0.0; },
            "The sdf value outside the narrow band, world units.")
        .def(
            "to_arrays",
            [](const Volume& v, const std::string& grid) -> py::tuple {
                if (grid == "sdf" && v.sdf) return active_arrays(*v.sdf);
                if (grid == "weight" && v.weight) return active_arrays(*v.weight);
                if (grid == "nearest" && v.nearest) return active_arrays(*v.nearest);
                if (grid == "color" && v.color) return active_arrays(*v.color);
                if (grid == "fill" && v.fill) return active_arrays(*v.fill);
                if (grid == "density" && v.sdf) {
                    openvdb::FloatGrid::Ptr d;
                    {
                        py::gil_scoped_release release;
                        d = make_density(*v.sdf);
                    }
                    return active_arrays(*d);
                }
                throw InvalidArgument("to_arrays: no grid '" + grid + "' in this volume (it has " +
                                      std::string(py::str(grid_names(v))) + ")");
            },
            py::arg("grid") = "sdf",
            "The active voxels of one grid as (coords, values): coords (N, 3) int32 index "
            "coordinates (world = origin + voxel_size * coords), values (N,) float32 for "
            "sdf/weight/density/fill or (N, 3) float32 for nearest/color.")
        .def("__repr__", [](const Volume& v) {
            return "Volume(voxel_size=" + std::to_string(v.voxel_size) +
                   ", active_voxels=" + std::to_string(v.sdf ? v.sdf->activeVoxelCount() : 0) +
                   ", grids=" + std::string(py::str(grid_names(v))) + ")";
        });

    m.def(
        "read_volume",
        [](const std::string& path) { return without_gil([&] { return read_volume(path); }); },
        py::arg("path"), "Reads a .vdb file with a level-set 'sdf' grid.");
    m.def(
        "write_volume",
        [](const std::string& path, const Volume& v) {
            return without_gil([&] { return write_volume(path, v); });
        },
        py::arg("path"), py::arg("volume"),
        "Writes sdf, weight, nearest, density, color and fill to a .vdb file, atomically; "
        "returns the grids' memory, bytes.");
}

}  // namespace vdbrecon::python
