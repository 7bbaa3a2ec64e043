// Mesh hole filling (vdbrecon/holes.h).
#include "bind.h"
#include "vdbrecon/holes.h"

namespace vdbrecon::python {

void bind_holes(py::module_& m) {
    OptionsClass<HoleFillOptions> o(m, "HoleFillOptions",
                                    "Mesh hole filling (Liepa 03): each boundary loop gets a "
                                    "minimum-dihedral triangulation, refined and faired.");
    o.field("max_edges", &HoleFillOptions::max_edges,
            "Loops with more boundary edges than this stay open; 0 fills every loop, count "
            "(CLI --fill-holes).")
        .field("refine", &HoleFillOptions::refine,
               "Split the patch to the density of the mesh around the hole (bool).")
        .field("fair", &HoleFillOptions::fair,
               "Move the patch's new vertices to the bi-Laplacian surface (bool).");
    o.finish();

    py::class_<HoleFillResult>(m, "HoleFillResult", "The filled mesh and what was added.")
        .def_readonly("mesh", &HoleFillResult::mesh, "The Mesh.")
        .def_readonly("loops", &HoleFillResult::loops, "Boundary loops found.")
        .def_readonly("filled", &HoleFillResult::filled, "Loops filled.")
        .def_readonly("added_faces", &HoleFillResult::added_faces, "Faces added.")
        .def_readonly("added_vertices", &HoleFillResult::added_vertices, "Vertices added.")
        .def_readonly("largest_filled", &HoleFillResult::largest_filled,
                      "Edges of the longest loop filled.")
        .def_readonly("largest_open", &HoleFillResult::largest_open,
                      "Edges of the longest loop left open (0: none).")
        .def("__repr__", [](const HoleFillResult& r) {
            return "HoleFillResult(" + std::to_string(r.filled) + " of " +
                   std::to_string(r.loops) + " loops filled, " + std::to_string(r.added_faces) +
                   " faces added)";
        });

    m.def(
        "fill_holes",
        [](const Mesh& mesh, const HoleFillOptions& o) {
            return without_gil([&] { return fill_holes(mesh, o); });
        },
        py::arg("mesh"), py::arg("options") = HoleFillOptions{},
        "Fills the mesh's boundary loops with fair patches.");
}

}  // namespace vdbrecon::python
