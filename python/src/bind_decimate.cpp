// QEM decimation (vdbrecon/decimate.h).
#include "bind.h"
#include "vdbrecon/choices.h"
#include "vdbrecon/decimate.h"

namespace vdbrecon::python {

void bind_decimate(py::module_& m) {
    OptionsClass<DecimateOptions> o(m, "DecimateOptions",
                                    "Quadric error metric decimation (Garland and Heckbert 97): "
                                    "topology, borders and colours kept.");
    o.field("ratio", &DecimateOptions::ratio,
            "Keep at most this fraction of the faces, 0 < ratio <= 1; 1 = no face-count target "
            "(CLI --decimate).")
        .field("max_error", &DecimateOptions::max_error,
               "No collapse whose error exceeds this, world units; 0 = no limit (CLI "
               "--max-error): the larger of the RMS distances to the planes of the original "
               "faces and border edges the vertex stands for and of its distance to the planes "
               "of the border and region outline edges around it.")
        .field("region_error", &DecimateOptions::region_error,
               "With planar regions (mesh.regions): no collapse moves a vertex off the plane of "
               "a region face around it by more than this, world units; 0 = max_error.")
        .choice("placement", &DecimateOptions::placement, placement_choices(),
                "'edge': the quadric's minimum on the collapsed edge (closer to the scanned "
                "surface); 'free': its unconstrained minimum (CLI --placement).")
        .field("border_weight", &DecimateOptions::border_weight,
               "Weight of the open border's planes against the faces' (dimensionless).")
        .field("max_normal_turn", &DecimateOptions::max_normal_turn,
               "A collapse may turn a face's normal by at most this, degrees.");
    o.finish();

    py::class_<DecimateResult>(m, "DecimateResult", "The decimated mesh and what was done.")
        .def_readonly("mesh", &DecimateResult::mesh, "The Mesh.")
        .def_readonly("faces_before", &DecimateResult::faces_before)
        .def_readonly("faces_after", &DecimateResult::faces_after)
        .def_readonly("collapses", &DecimateResult::collapses, "Edge collapses made.")
        .def_readonly("refused", &DecimateResult::refused,
                      "Collapses refused (topology, flips).")
        .def_readonly("max_error", &DecimateResult::max_error,
                      "The largest error of a collapse made, world units.")
        .def("__repr__", [](const DecimateResult& r) {
            return "DecimateResult(" + std::to_string(r.faces_before) + " -> " +
                   std::to_string(r.faces_after) + " faces)";
        });

    m.def(
        "decimate",
        [](const Mesh& mesh, const DecimateOptions& o) {
            return without_gil([&] { return decimate(mesh, o); });
        },
        py::arg("mesh"), py::arg("options"), "Decimates a mesh by QEM edge collapses.");
}

}  // namespace vdbrecon::python
