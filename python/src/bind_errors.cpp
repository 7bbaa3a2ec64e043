// Library exceptions as Python exceptions:
//   vdbrecon.Error            (Exception)       base of everything the library raises
//   vdbrecon.IoError          (Error, OSError)  a file could not be opened, read, written, renamed
//   vdbrecon.FormatError      (Error, OSError)  a file is malformed, truncated or unsupported
//   vdbrecon.InvalidArgument  (Error, ValueError)  an option or argument out of range
//   vdbrecon.NumericalError   (Error, RuntimeError) no meaningful result (degenerate input, ...)
#include "bind.h"

namespace vdbrecon::python {

namespace {

PyObject* make_exception(py::module_& m, const char* name, PyObject* bases, const char* doc) {
    const std::string qualified = std::string("vdbrecon.") + name;
    PyObject* type = PyErr_NewExceptionWithDoc(qualified.c_str(), doc, bases, nullptr);
    if (!type) throw py::error_already_set();
    m.add_object(name, py::handle(type));  // steals nothing: add_object increfs
    return type;
}

PyObject* g_error = nullptr;
PyObject* g_io = nullptr;
PyObject* g_format = nullptr;
PyObject* g_invalid = nullptr;
PyObject* g_numerical = nullptr;

}  // namespace

void bind_errors(py::module_& m) {
    g_error = make_exception(m, "Error", PyExc_Exception, "Base of every vdbrecon exception.");
    const auto bases = [](PyObject* a, PyObject* b) {
        return py::make_tuple(py::handle(a), py::handle(b));
    };
    py::tuple io_bases = bases(g_error, PyExc_OSError);
    g_io = make_exception(m, "IoError", io_bases.ptr(),
                          "A file could not be opened, read, written or renamed (an OSError).");
    g_format = make_exception(m, "FormatError", io_bases.ptr(),
                              "A file was readable but malformed, truncated or unsupported "
                              "(an OSError); the message starts with the file name.");
    py::tuple value_bases = bases(g_error, PyExc_ValueError);
    g_invalid = make_exception(m, "InvalidArgument", value_bases.ptr(),
                               "An option or argument is out of range or inconsistent (a "
                               "ValueError); the message names the field and the value.");
    py::tuple runtime_bases = bases(g_error, PyExc_RuntimeError);
    g_numerical = make_exception(m, "NumericalError", runtime_bases.ptr(),
                                 "A computation could not produce a meaningful result (degenerate "
                                 "input, empty volume, ...).");

    py::register_exception_translator([](std::exception_ptr p) {
        try {
            if (p) std::rethrow_exception(p);
        } catch (const IoError& e) {
            PyErr_SetString(g_io, e.what());
        } catch (const FormatError& e) {
            PyErr_SetString(g_format, e.what());
        } catch (const InvalidArgument& e) {
            PyErr_SetString(g_invalid, e.what());
        } catch (const NumericalError& e) {
            PyErr_SetString(g_numerical, e.what());
        } catch (const Error& e) {
            PyErr_SetString(g_error, e.what());
        }
    });
}

}  // namespace vdbrecon::python
