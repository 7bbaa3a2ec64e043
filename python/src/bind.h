// Shared pieces of the pybind11 module `vdbrecon._vdbrecon`: numpy arrays borrowed as Columns
// and Columns shown as numpy views, option-struct binding (fields with their documentation and
// defaults), enum choices as strings, and calling the library without the GIL.
//
// One bind_<stage>.cpp per public header. Adding a stage (as bind_close.cpp did): write
// bind_<stage>.cpp with `void bind_<stage>(py::module_&)`, declare it below, call it from
// module.cpp, list it in python/CMakeLists.txt, and add its options struct to PipelineOptions in
// bind_pipeline.cpp (`nested("close", &PipelineOptions::close)`). vdbrecon/__init__.py picks up
// the new pipeline options from the `_fields` tables; the stage's own function needs a wrapper
// there.
//
// Only vdbrecon's public headers are included here; the OpenVDB-heavy templates stay in the
// library.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cstdint>
#include <optional>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "vdbrecon/choices.h"
#include "vdbrecon/error.h"
#include "vdbrecon/types.h"

namespace vdbrecon::python {

namespace py = pybind11;

// ---- numpy arrays ----------------------------------------------------------------------------

/// A column reading a C-contiguous float32 (N, 3) array in place (no copy): it borrows the
/// array's memory and keeps the array alive (released under the GIL) for as long as the column
/// or a copy of it lives. Anything else raises TypeError (wrong dtype or layout:
/// vdbrecon/__init__.py converts before calling) or ValueError (wrong shape, or `rows` given and
/// different). `name` appears in the message.
Column<Vec3f> borrow_rows(const py::handle& array, const char* name, py::ssize_t rows = -1);
/// Same for a C-contiguous float32 (N,) array.
Column<float> borrow_column(const py::handle& array, const char* name, py::ssize_t rows = -1);
/// Same for a C-contiguous int32 (F, 3) array of vertex indices, each in 0..vertices-1.
Column<Triangle> borrow_faces(const py::handle& array, const char* name, std::size_t vertices);

/// A numpy view of a column (no copy) that keeps `owner` (the Python object owning the column)
/// alive: (N, 3) float32 rows, (F, 3) int32 faces, (N,) float32. A column that borrows someone
/// else's array gives a read-only view (that array may be read-only, and it is not the owner's
/// to change). The column must never be resized while the owner lives.
py::array view_rows(const Column<Vec3f>& v, py::handle owner);
py::array view_faces(const Column<Triangle>& v, py::handle owner);
py::array view_column(const Column<float>& v, py::handle owner);
/// A view, or None when `v` is empty (optional attributes).
py::object view_or_none(const Column<Vec3f>& v, py::handle owner);
py::object view_or_none(const Column<float>& v, py::handle owner);

/// Moves a vector onto the heap and returns a numpy array owning it (no copy), shape
/// (size, cols) or (size,) when cols == 0.
template <typename Row>
py::array adopt(std::vector<Row>&& v, py::ssize_t cols);

/// A (3,) Vec3d as a Python tuple, and back (any sequence of three numbers).
py::tuple to_tuple(const Vec3d& v);

// ---- enum options as strings (the CLI's names) ----------------------------------------------

/// Parses a choice; TypeError for a non-string, InvalidArgument (-> vdbrecon.InvalidArgument,
/// a ValueError) for an unknown name, naming the field and the valid names.
template <typename E>
E parse_choice(const Choices<E>& choices, const std::string& field, const py::handle& value) {
    if (!py::isinstance<py::str>(value)) {
        throw py::type_error(field + ": expected a string, one of " + choice_list(choices, ", ", "'") +
                             "; got " + std::string(py::str(py::type::of(value).attr("__name__"))));
    }
    const std::string s = value.cast<std::string>();
    if (const E* e = find_choice(choices, s)) return *e;
    throw InvalidArgument(field + ": '" + s + "' is not one of " + choice_list(choices, ", ", "'"));
}

// ---- options structs -------------------------------------------------------------------------

/// Binds an options struct: a default constructor, one property per field (with its
/// documentation: meaning, unit, space), `validate()`, `__repr__`, `__eq__`, and the class
/// attributes the Python layer reads:
///   _fields  = (("name", "doc"), ...) in declaration order,
///   _choices = {"name": ("choice", ...)} for enum fields.
/// Defaults are never written down here: Python reads them from a default-constructed object.
template <typename T>
class OptionsClass {
  public:
    OptionsClass(py::module_& m, const char* name, const char* doc) : cls_(m, name, doc) {
        cls_.def(py::init<>(), "Every field at its default.");
    }

    template <typename M>
    OptionsClass& field(const char* name, M T::*member, const char* doc) {
        cls_.def_readwrite(name, member, doc);
        fields_.append(py::make_tuple(name, doc));
        return *this;
    }

    template <typename E>
    OptionsClass& choice(const char* name, E T::*member, Choices<E> choices, const char* doc) {
        const std::string field =
            std::string(cls_.attr("__name__").template cast<std::string>()) + "." + name;
        cls_.def_property(
            name, [member, choices](const T& o) { return choice_name(choices, o.*member); },
            [member, choices, field](T& o, const py::object& v) {
                o.*member = parse_choice(choices, field, v);
            },
            doc);
        fields_.append(py::make_tuple(name, doc));
        py::list names;
        for (const auto& c : choices) names.append(c.first);
        choices_[name] = py::tuple(names);
        return *this;
    }

    /// A nested options struct (PipelineOptions.splat, ...): listed in `_stages`, not `_fields`.
    template <typename M>
    OptionsClass& nested(const char* name, M T::*member, const char* doc) {
        cls_.def_readwrite(name, member, doc);
        stages_.append(name);
        return *this;
    }

    py::class_<T>& cls() { return cls_; }

    /// Call last: publishes _fields/_choices and the generic methods.
    void finish(bool has_validate = true) {
        cls_.attr("_fields") = py::tuple(fields_);
        cls_.attr("_choices") = choices_;
        cls_.attr("_stages") = py::tuple(stages_);
        if (has_validate) {
            if constexpr (has_validate_v<T>) {
                cls_.def(
                    "validate", [](const T& o) { o.validate(); },
                    "Raises vdbrecon.InvalidArgument (a ValueError) naming the first field out of "
                    "range.");
            }
        }
        cls_.def("__repr__", [](const py::object& self) {
            py::list parts;
            for (const py::handle name : py::type::of(self).attr("_stages")) {
                parts.append(py::str("{}={!r}").format(name, self.attr(name)));
            }
            for (const py::handle f : py::type::of(self).attr("_fields")) {
                const py::object name = f.cast<py::tuple>()[0];
                parts.append(py::str("{}={!r}").format(name, self.attr(name)));
            }
            return py::str("{}({})").format(py::type::of(self).attr("__name__"),
                                            py::str(", ").attr("join")(parts));
        });
        cls_.def("__eq__", [](const py::object& a, const py::object& b) {
            if (!py::type::of(a).is(py::type::of(b))) return false;
            for (const py::handle f : py::type::of(a).attr("_fields")) {
                const py::object name = f.cast<py::tuple>()[0];
                if (!a.attr(name).equal(b.attr(name))) return false;
            }
            for (const py::handle name : py::type::of(a).attr("_stages")) {
                if (!a.attr(name).equal(b.attr(name))) return false;
            }
            return true;
        });
    }

  private:
    template <typename U, typename = void>
    struct HasValidate : std::false_type {};
    template <typename U>
    struct HasValidate<U, std::void_t<decltype(std::declval<const U&>().validate())>>
        : std::true_type {};
    template <typename U>
    static constexpr bool has_validate_v = HasValidate<U>::value;

    py::class_<T> cls_;
    py::list fields_;
    py::list stages_;
    py::dict choices_;
};

// ---- calling the library ---------------------------------------------------------------------

/// Runs `f` with the GIL released. Library log messages emitted meanwhile (always from this
/// thread) are buffered and forwarded afterwards to the Python logger "vdbrecon" (info ->
/// logging.INFO, warnings -> logging.WARNING), also when `f` throws.
template <typename F>
auto without_gil(F&& f) -> decltype(f());

void flush_log();

// ---- the bind functions, one per stage (module.cpp calls them in this order) -----------------

void bind_common(py::module_& m);    // log forwarding
void bind_errors(py::module_& m);    // exception classes
void bind_types(py::module_& m);     // PointCloud, Mesh, BBox
void bind_io(py::module_& m);        // read_points, read_mesh, write_mesh, write_points
void bind_outliers(py::module_& m);  // remove_outliers
void bind_normals(py::module_& m);   // estimate_normals
void bind_volume(py::module_& m);    // Volume, read_volume, write_volume
void bind_splat(py::module_& m);     // splat
void bind_mesh(py::module_& m);      // extract_mesh
void bind_close(py::module_& m);     // close_volume (after bind_mesh: takes MeshOptions)
void bind_clean(py::module_& m);     // clean_mesh
void bind_holes(py::module_& m);     // fill_holes
void bind_decimate(py::module_& m);  // decimate
void bind_planes(py::module_& m);    // planar_regions
void bind_texture(py::module_& m);   // texture_regions, write_textured_mesh (after bind_planes)
void bind_eval(py::module_& m);      // evaluate, mesh_topology
void bind_pipeline(py::module_& m);  // PipelineOptions, reconstruct, run
void bind_fusion(py::module_& m);    // DepthOptions, _Fusion (after bind_pipeline)
void bind_tiles(py::module_& m);     // prepare_tiles, run_tile, finish_tiles (after bind_pipeline)

// ---- template definitions --------------------------------------------------------------------

template <typename Row>
py::array adopt(std::vector<Row>&& v, py::ssize_t cols) {
    using Scalar = std::conditional_t<
        std::is_same_v<Row, Vec3f>, float,
        std::conditional_t<std::is_same_v<Row, Triangle>, std::int32_t,
                           std::conditional_t<std::is_same_v<Row, std::array<std::int32_t, 3>>,
                                              std::int32_t, Row>>>;
    auto* heap = new std::vector<Row>(std::move(v));
    py::capsule owner(heap, [](void* p) { delete static_cast<std::vector<Row>*>(p); });
    const py::ssize_t n = py::ssize_t(heap->size());
    const auto* data = reinterpret_cast<const Scalar*>(heap->data());
    if (cols == 0) return py::array_t<Scalar>({n}, {py::ssize_t(sizeof(Scalar))}, data, owner);
    return py::array_t<Scalar>(
        {n, cols}, {py::ssize_t(sizeof(Scalar)) * cols, py::ssize_t(sizeof(Scalar))}, data, owner);
}

template <typename F>
auto without_gil(F&& f) -> decltype(f()) {
    using R = decltype(f());
    try {
        if constexpr (std::is_void_v<R>) {
            {
                py::gil_scoped_release release;
                f();
            }
            flush_log();
        } else {
            std::optional<R> r;
            {
                py::gil_scoped_release release;
                r.emplace(f());
            }
            flush_log();
            return std::move(*r);
        }
    } catch (...) {
        flush_log();  // the GIL is held again here: the release guard has been destroyed
        throw;
    }
}

}  // namespace vdbrecon::python
