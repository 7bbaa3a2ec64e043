// Normal and scale estimation (vdbrecon/normals.h).
#include "bind.h"
#include "vdbrecon/normals.h"

namespace vdbrecon::python {

void bind_normals(py::module_& m) {
    OptionsClass<NormalOptions> o(m, "NormalOptions",
                                  "Normal and per-point scale estimation (PCA over k nearest "
                                  "neighbours, Hoppe 1992 MST orientation).");
    o.choice("mode", &NormalOptions::mode,
             normal_mode_choices(),
             "Where normals come from: 'auto' keeps the file's normals when every point has one "
             "and estimates otherwise, 'estimate' always estimates, 'keep' requires them (CLI "
             "--normals).")
        .field("k", &NormalOptions::k,
               "Neighbours used for PCA normals, orientation and the kNN scale (count; CLI --k).")
        .field("viewpoint", &NormalOptions::viewpoint,
               "Sensor position (x, y, z), world units; estimated normals are turned towards it. "
               "None: minimum-spanning-tree orientation (CLI --viewpoint).")
        .field("up", &NormalOptions::up,
               "A direction (x, y, z) estimated normals are turned towards, e.g. (0, 0, 1) for "
               "airborne data; not with a viewpoint. Like the viewpoint it orients each point "
               "on its own, so a tiled run can stream a cloud without normals. None: "
               "orientation by `orient` (CLI --up).")
        .choice("orient", &NormalOptions::orient, orient_rule_choices(),
                "Without a viewpoint or up: 'auto' orients by what the cloud is (a height field "
                "faces up, a depth camera's frame the origin, else the MST with closed objects "
                "facing out and open sheets up), 'mst' always the MST (CLI --orient).")
        .choice(
            "scale", &NormalOptions::scale,
            scale_mode_choices(),
            "Per-point scale: 'auto' the file's when present else the mean kNN distance, "
            "'knn' always the kNN distance, 'none' no scale (CLI --scale).")
        .nested("knn", &NormalOptions::knn,
                "The neighbour search when the outlier stage hands over no lists (KnnOptions).");
    o.finish();

    py::class_<NormalResult>(m, "NormalResult", "What estimate_normals produced.")
        .def_property_readonly(
            "normals",
            [](py::object self) { return view_rows(self.cast<NormalResult&>().normals, self); },
            "(N, 3) float32 unit normals (the kept ones, or estimated).")
        .def_property_readonly(
            "scales",
            [](py::object self) { return view_or_none(self.cast<NormalResult&>().scales, self); },
            "(N,) float32 per-point scale in world units, or None (scale='none').")
        .def_readonly("estimated", &NormalResult::estimated, "Points whose normal was estimated.")
        .def_readonly("repaired", &NormalResult::repaired,
                      "Kept normals that were zero/NaN and were re-estimated.")
        .def_readonly("flipped", &NormalResult::flipped,
                      "Estimated normals flipped by the orientation step.")
        .def_readonly("components", &NormalResult::components,
                      "kNN-graph components oriented separately (MST mode).")
        .def_readonly("oriented_to_viewpoint", &NormalResult::oriented_to_viewpoint)
        .def_readonly("orientation", &NormalResult::orientation,
                      "The rule that oriented the estimated normals: 'viewpoint', 'up', 'height "
                      "field', 'sensor at the origin', 'MST' ('' when none was estimated).")
        .def_readonly("components_up", &NormalResult::components_up,
                      "MST components turned up as open sheets.")
        .def_readonly("components_flux", &NormalResult::components_flux,
                      "MST components turned outward by their flux (closed objects).")
        .def_readonly("components_seed", &NormalResult::components_seed,
                      "MST components left with their seed's sign.")
        .def_readonly("median_scale", &NormalResult::median_scale,
                      "Median of `scales`, world units (0 when none).")
        .def_readonly("density_spacing", &NormalResult::density_spacing,
                      "Median sample spacing from the neighbours' density when this stage "
                      "searched them, else 0; world units.")
        .def("__repr__", [](const NormalResult& r) {
            return "NormalResult(" + std::to_string(r.normals.size()) +
                   " normals, estimated=" + std::to_string(r.estimated) +
                   ", median_scale=" + std::to_string(r.median_scale) + ")";
        });

    m.def(
        "estimate_normals",
        [](const PointCloud& cloud, const NormalOptions& o) {
            return without_gil([&] { return estimate_normals(cloud, o); });
        },
        py::arg("cloud"), py::arg("options") = NormalOptions{},
        "Estimates (or checks) normals and per-point scales.");
}

}  // namespace vdbrecon::python
