// Evaluation against a reference mesh (vdbrecon/eval.h).
#include "bind.h"
#include "vdbrecon/eval.h"

namespace vdbrecon::python {

void bind_eval(py::module_& m) {
    OptionsClass<EvalOptions> o(m, "EvalOptions", "How a reconstruction is compared.");
    o.field("taus", &EvalOptions::taus,
            "Distance thresholds for precision/recall/F, world units; empty: 0.2 % of the "
            "reference's bounding-box diagonal (CLI eval --tau).")
        .field("samples", &EvalOptions::samples,
               "Samples drawn on each mesh, count (CLI eval --samples).")
        .field("seed", &EvalOptions::seed,
               "Seed of the sampler; the same seed gives the same numbers.")
        .field("mask_points", &EvalOptions::mask_points,
               "Coverage mask, e.g. the scan: a sequence of (x, y, z) rows, world units relative "
               "to mask_origin; reference samples farther than mask_distance from all of them "
               "are not counted in completeness and recall (CLI eval --mask-points).")
        .field("mask_origin", &EvalOptions::mask_origin,
               "World position of the mask points' local frame (PointCloud.origin of a scan).")
        .field("mask_distance", &EvalOptions::mask_distance,
               "Radius of the coverage mask, world units; > 0 with mask_points "
               "(CLI eval --mask-distance).")
        .field("ignore_reference_holes", &EvalOptions::ignore_reference_holes,
               "Leave out of accuracy and precision the reconstruction samples whose closest "
               "reference point is on the reference's open border (bool; CLI eval "
               "--ignore-reference-holes).");
    o.finish();

    py::class_<TopologyStats>(m, "TopologyStats", "Topology of a mesh.")
        .def_readonly("vertices", &TopologyStats::vertices)
        .def_readonly("faces", &TopologyStats::faces)
        .def_readonly("components", &TopologyStats::components,
                      "Edge-connected components of faces.")
        .def_readonly("boundary_edges", &TopologyStats::boundary_edges)
        .def_readonly("nonmanifold_edges", &TopologyStats::nonmanifold_edges)
        .def_readonly("degenerate_faces", &TopologyStats::degenerate_faces)
        .def_readonly("euler", &TopologyStats::euler, "V - E + F (referenced vertices only).")
        .def_readonly("area", &TopologyStats::area, "World units squared.")
        .def_readonly("signed_volume", &TopologyStats::signed_volume,
                      "Positive for closed outward-facing meshes, world units cubed.")
        .def("watertight", &TopologyStats::watertight, "No boundary and no non-manifold edge.")
        .def("__repr__", [](const TopologyStats& t) {
            return "TopologyStats(vertices=" + std::to_string(t.vertices) +
                   ", faces=" + std::to_string(t.faces) +
                   ", components=" + std::to_string(t.components) +
                   ", boundary_edges=" + std::to_string(t.boundary_edges) +
                   ", euler=" + std::to_string(t.euler) + ")";
        });

    py::class_<FScore>(m, "FScore", "Precision, recall and F-score at one threshold.")
        .def_readonly("tau", &FScore::tau, "World units.")
        .def_readonly("precision", &FScore::precision)
        .def_readonly("recall", &FScore::recall)
        .def_readonly("fscore", &FScore::fscore)
        .def("__repr__", [](const FScore& f) {
            return "FScore(tau=" + std::to_string(f.tau) + ", fscore=" + std::to_string(f.fscore) +
                   ")";
        });

    py::class_<EvalResult>(m, "EvalResult", "Distances (world units) and scores.")
        .def_readonly("accuracy", &EvalResult::accuracy, "Mean distance recon -> reference.")
        .def_readonly("completeness", &EvalResult::completeness,
                      "Mean distance reference -> recon.")
        .def_readonly("chamfer_l1", &EvalResult::chamfer_l1, "(accuracy + completeness) / 2.")
        .def_readonly("hausdorff", &EvalResult::hausdorff)
        .def_readonly("normal_consistency", &EvalResult::normal_consistency)
        .def_readonly("fscores", &EvalResult::fscores, "One FScore per tau.")
        .def_readonly("samples", &EvalResult::samples)
        .def_readonly("reference_samples", &EvalResult::reference_samples,
                      "Reference samples counted: all without a mask, the covered ones with one.")
        .def_readonly("recon_samples", &EvalResult::recon_samples,
                      "Reconstruction samples counted on its side (less those over the "
                      "reference's holes with ignore_reference_holes).")
        .def_readonly("recon", &EvalResult::recon, "TopologyStats of the reconstruction.")
        .def_readonly("reference", &EvalResult::reference, "TopologyStats of the reference.")
        .def(
            "to_json", [](const EvalResult& r) { return to_json(r); },
            "The JSON object `vdbrecon eval` prints.")
        .def("__repr__", [](const EvalResult& r) {
            return "EvalResult(chamfer_l1=" + std::to_string(r.chamfer_l1) +
                   ", hausdorff=" + std::to_string(r.hausdorff) + ")";
        });

    m.def(
        "evaluate",
        [](const Mesh& recon, const Mesh& reference, const EvalOptions& o) {
            return without_gil([&] { return evaluate(recon, reference, o); });
        },
        py::arg("recon"), py::arg("reference"), py::arg("options") = EvalOptions{},
        "Compares a reconstruction with a reference mesh.");
    m.def(
        "mesh_distances",
        [](const Mesh& mesh, const PointCloud& points) {
            std::vector<std::int32_t> faces;
            std::vector<double> d =
                without_gil([&] { return MeshDistance(mesh).distances(points, &faces); });
            return py::make_tuple(adopt(std::move(d), 0), adopt(std::move(faces), 0));
        },
        py::arg("mesh"), py::arg("points"),
        "Distances from points (a PointCloud) to a mesh and the closest face of each.");
    m.def(
        "mesh_topology",
        [](const Mesh& mesh) { return without_gil([&] { return mesh_topology(mesh); }); },
        py::arg("mesh"), "Topology statistics of a mesh.");
}

}  // namespace vdbrecon::python
