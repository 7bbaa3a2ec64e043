// numpy conversions and log forwarding (see bind.h).
#include <mutex>

#include "bind.h"
#include "vdbrecon/log.h"

namespace vdbrecon::python {

namespace {

std::string describe(const py::handle& obj) {
    if (py::isinstance<py::array>(obj)) {
        const py::array a = py::reinterpret_borrow<py::array>(obj);
        std::string shape = "(";
        for (py::ssize_t i = 0; i < a.ndim(); ++i) {
            shape += (i ? ", " : "") + std::to_string(a.shape(i));
        }
        shape += a.ndim() == 1 ? ",)" : ")";
        const bool c = (a.flags() & py::array::c_style) != 0;
        return "a " + std::string(py::str(a.dtype())) + " array of shape " + shape +
               (c ? "" : " (not C-contiguous)");
    }
    return "a " + std::string(py::str(py::type::of(obj).attr("__name__")));
}

/// Checks dtype, layout and shape; returns the array.
template <typename Scalar>
py::array_t<Scalar, py::array::c_style> checked(const py::handle& obj, const char* name,
                                                py::ssize_t cols, py::ssize_t rows,
                                                const char* expected) {
    using Array = py::array_t<Scalar, py::array::c_style>;
    if (!py::isinstance<Array>(obj)) {
        throw py::type_error(std::string(name) + ": expected " + expected + ", got " +
                             describe(obj));
    }
    Array a = py::reinterpret_borrow<Array>(obj);
    const bool shape_ok = cols > 0 ? (a.ndim() == 2 && a.shape(1) == cols) : (a.ndim() == 1);
    if (!shape_ok) {
        throw py::value_error(std::string(name) + ": expected " + expected + ", got " +
                              describe(obj));
    }
    if (rows >= 0 && a.shape(0) != rows) {
        throw py::value_error(std::string(name) + ": expected " + std::to_string(rows) +
                              " rows (one per point/vertex), got " + std::to_string(a.shape(0)));
    }
    return a;
}

}  // namespace

namespace {

/// A shared owner holding a reference to `o`, dropped under the GIL whichever thread lets go.
std::shared_ptr<const void> keep_alive(py::object o) {
    return std::shared_ptr<const void>(new py::object(std::move(o)), [](const void* p) {
        py::gil_scoped_acquire gil;
        delete static_cast<const py::object*>(p);
    });
}

/// A column of `Row`s reading the checked array `a` in place and holding it.
template <typename Row, typename Array>
Column<Row> borrow_checked(Array a) {
    const auto* data = reinterpret_cast<const Row*>(a.data());
    const auto n = std::size_t(a.shape(0));  // before `a` is moved from
    return Column<Row>::borrow(data, n, keep_alive(std::move(a)));
}

}  // namespace

Column<Vec3f> borrow_rows(const py::handle& array, const char* name, py::ssize_t rows) {
    return borrow_checked<Vec3f>(
        checked<float>(array, name, 3, rows, "a C-contiguous float32 array of shape (N, 3)"));
}

Column<float> borrow_column(const py::handle& array, const char* name, py::ssize_t rows) {
    return borrow_checked<float>(
        checked<float>(array, name, 0, rows, "a C-contiguous float32 array of shape (N,)"));
}

Column<Triangle> borrow_faces(const py::handle& array, const char* name, std::size_t vertices) {
    auto a =
        checked<std::int32_t>(array, name, 3, -1, "a C-contiguous int32 array of shape (F, 3)");
    const auto* faces = reinterpret_cast<const Triangle*>(a.data());
    for (std::size_t f = 0; f < std::size_t(a.shape(0)); ++f) {
        for (const std::int32_t i : faces[f]) {
            if (i < 0 || std::size_t(i) >= vertices) {
                throw py::value_error(std::string(name) + ": face " + std::to_string(f) +
                                      " has vertex index " + std::to_string(i) + ", outside 0.." +
                                      std::to_string(vertices) + "-1");
            }
        }
    }
    return borrow_checked<Triangle>(std::move(a));
}

namespace {

template <typename Scalar>
py::array view(const Scalar* data, py::ssize_t rows, py::ssize_t cols, py::handle owner) {
    if (rows == 0) {  // no storage to point at
        if (cols) return py::array_t<Scalar>(std::vector<py::ssize_t>{0, cols});
        return py::array_t<Scalar>(std::vector<py::ssize_t>{0});
    }
    if (cols == 0) {
        return py::array_t<Scalar>({rows}, {py::ssize_t(sizeof(Scalar))}, data, owner);
    }
    return py::array_t<Scalar>({rows, cols},
                               {py::ssize_t(sizeof(Scalar)) * cols, py::ssize_t(sizeof(Scalar))},
                               data, owner);
}

}  // namespace

namespace {

/// `a`, made read-only when the column it shows borrows its memory.
template <typename T>
py::array guarded(py::array a, const Column<T>& c) {
    if (c.borrowed() && a.size() > 0) a.attr("setflags")(py::arg("write") = false);
    return a;
}

}  // namespace

py::array view_rows(const Column<Vec3f>& v, py::handle owner) {
    return guarded(view(reinterpret_cast<const float*>(v.data()), py::ssize_t(v.size()), 3, owner),
                   v);
}

py::array view_faces(const Column<Triangle>& v, py::handle owner) {
    return guarded(
        view(reinterpret_cast<const std::int32_t*>(v.data()), py::ssize_t(v.size()), 3, owner), v);
}

py::array view_column(const Column<float>& v, py::handle owner) {
    return guarded(view(v.data(), py::ssize_t(v.size()), 0, owner), v);
}

py::object view_or_none(const Column<Vec3f>& v, py::handle owner) {
    if (v.empty()) return py::none();
    return view_rows(v, owner);
}

py::object view_or_none(const Column<float>& v, py::handle owner) {
    if (v.empty()) return py::none();
    return view_column(v, owner);
}

py::tuple to_tuple(const Vec3d& v) { return py::make_tuple(v[0], v[1], v[2]); }

// ---- log forwarding --------------------------------------------------------------------------

namespace {

// The library calls the handler from the calling thread only, so each thread buffers its own.
thread_local std::vector<std::pair<LogLevel, std::string>> t_messages;

}  // namespace

void flush_log() {
    if (t_messages.empty()) return;
    std::vector<std::pair<LogLevel, std::string>> messages;
    messages.swap(t_messages);
    py::object logger = py::module_::import("logging").attr("getLogger")("vdbrecon");
    for (const auto& [level, text] : messages) {
        const int py_level = level == LogLevel::warning ? 30 : level == LogLevel::info ? 20 : 10;
        logger.attr("log")(py_level, "%s", text);
    }
}

void bind_common(py::module_& m) {
    set_log_handler([](LogLevel level, const std::string& message) {
        t_messages.emplace_back(level, message);
    });
    m.def("_flush_log", &flush_log, "Forwards buffered library messages to logging (internal).");
}

}  // namespace vdbrecon::python
