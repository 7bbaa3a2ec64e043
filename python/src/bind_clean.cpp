// Mesh cleanup (vdbrecon/clean.h).
#include "bind.h"
#include "vdbrecon/clean.h"

namespace vdbrecon::python {

void bind_clean(py::module_& m) {
    OptionsClass<CleanOptions> o(m, "CleanOptions",
                                 "Mesh cleanup: edge-connected components too few samples "
                                 "built are removed, optional Taubin lambda|mu smoothing "
                                 "(Taubin 95).");
    o.field("min_component_samples", &CleanOptions::min_component_samples,
            "Components backed by fewer samples than this are removed: the sum over their faces "
            "of area * min(1, weight / median weight) / spacing^2; 0 keeps all (CLI "
            "--min-samples).")
        .field("sample_spacing", &CleanOptions::sample_spacing,
               "The sample spacing the evidence is counted in, world units; 0 = the mesh's "
               "median edge length.")
        .field("min_component_ratio", &CleanOptions::min_component_ratio,
            "Components with fewer faces than this fraction of the largest one's are removed "
            "too; 0 (default) keeps all, 1 only the largest (CLI --min-component).")
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
                      "Components dropped.")
        .def_readonly("removed_unsupported", &CleanResult::removed_unsupported,
                      "... of them backed by too few samples.")
        .def_readonly("removed_small", &CleanResult::removed_small,
                      "... of them smaller than min_component_ratio x the largest.")
        .def_readonly("typical_support", &CleanResult::typical_support,
                      "The median summed weight at the vertices (0 without support).")
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
        [](const Mesh& mesh, const CleanOptions& o, const py::object& support) {
            std::vector<float> w;
            if (!support.is_none()) {
                const Column<float> c = borrow_column(support, "support",
                                                      py::ssize_t(mesh.vertices.size()));
                w.assign(c.begin(), c.end());
            }
            return without_gil([&] { return clean_mesh(mesh, o, w); });
        },
        py::arg("mesh"), py::arg("options") = CleanOptions{}, py::arg("support") = py::none(),
        "Removes components too few samples built (support: per-vertex summed weight, "
        "MeshResult.support) and optionally smooths the mesh.");
}

}  // namespace vdbrecon::python
