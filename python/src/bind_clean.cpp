// Mesh cleanup (vdbrecon/clean.h).
#include "bind.h"
#include "vdbrecon/clean.h"

namespace vdbrecon::python {

void bind_clean(py::module_& m) {
    OptionsClass<CleanOptions> o(m, "CleanOptions",
                                 "Mesh cleanup: small edge-connected components are removed, "
                                 "optional Taubin lambda|mu smoothing (Taubin 95).");
    o.field("min_component_ratio", &CleanOptions::min_component_ratio,
            "Components with fewer faces than this fraction of the largest one's are removed; "
            "0 keeps all (CLI --min-component).")
        .field("min_component_faces", &CleanOptions::min_component_faces,
               "Components with fewer faces than this are removed, whatever the ratio, count.")
        .field("smooth_iterations", &CleanOptions::smooth_iterations,
               "Taubin lambda|mu iterations, 0 = no smoothing (CLI --smooth).")
        .field("smooth_lambda", &CleanOptions::smooth_lambda,
               "Taubin's shrinking factor, in (0, 1).")
        .field("smooth_mu", &CleanOptions::smooth_mu,
               "Taubin's inflating factor, in (-1, -lambda).");
    o.finish();

    py::class_<CleanResult>(m, "CleanResult", "The cleaned mesh and what was removed.")
        .def_readonly("mesh", &CleanResult::mesh, "The Mesh.")
        .def_readonly("components_before", &CleanResult::components_before,
                      "Edge-connected components in the input.")
        .def_readonly("removed_components", &CleanResult::removed_components,
                      "Components dropped as too small.")
        .def_readonly("removed_faces", &CleanResult::removed_faces,
                      "Faces in the dropped components.")
        .def_readonly("removed_vertices", &CleanResult::removed_vertices,
                      "Vertices no longer referenced.")
        .def_readonly("smoothed_iterations", &CleanResult::smoothed_iterations,
                      "Taubin iterations applied.")
        .def("__repr__", [](const CleanResult& r) {
            return "CleanResult(" + std::to_string(r.mesh.faces.size()) +
                   " faces, removed_components=" + std::to_string(r.removed_components) + ")";
        });

    m.def(
        "clean_mesh",
        [](const Mesh& mesh, const CleanOptions& o) {
            return without_gil([&] { return clean_mesh(mesh, o); });
        },
        py::arg("mesh"), py::arg("options") = CleanOptions{},
        "Removes small components and optionally smooths the mesh.");
}

}  // namespace vdbrecon::python
