// The compiled part of the Python package: vdbrecon._vdbrecon. The Pythonic layer (numpy
// conversion, keyword options, docstrings with defaults) is python/vdbrecon/__init__.py.
#include "bind.h"
#include "vdbrecon/pipeline.h"
#include "vdbrecon/volume.h"

PYBIND11_MODULE(_vdbrecon, m) {
    using namespace vdbrecon::python;
    m.doc() = "vdbrecon's C++ library (pybind11). Use the `vdbrecon` package, not this module.";
    m.attr("__version__") = vdbrecon::version();
    vdbrecon::initialize_openvdb();
    bind_common(m);
    bind_errors(m);
    bind_types(m);
    bind_io(m);
    bind_outliers(m);
    bind_normals(m);
    bind_volume(m);
    bind_splat(m);
    bind_mesh(m);
    bind_close(m);
    bind_clean(m);
    bind_holes(m);
    bind_decimate(m);
    bind_planes(m);
    bind_texture(m);
    bind_eval(m);
    bind_pipeline(m);
    bind_fusion(m);
    bind_tiles(m);
}
