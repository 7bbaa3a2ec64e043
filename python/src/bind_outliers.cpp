// Point outlier removal (vdbrecon/outliers.h).
#include "bind.h"
#include "vdbrecon/outliers.h"

namespace vdbrecon::python {

namespace {

/// The 0/1 flags as a (N,) numpy bool view (no copy) owned by `owner`.
py::array view_flags(const std::vector<char>& flags, py::handle owner) {
    static_assert(sizeof(char) == sizeof(bool));
    const py::dtype dtype("bool");
    const auto n = py::ssize_t(flags.size());
    if (n == 0) return py::array(dtype, std::vector<py::ssize_t>{0});
    return py::array(dtype, {n}, {py::ssize_t(1)}, flags.data(), owner);
}

}  // namespace

void bind_outliers(py::module_& m) {
    OptionsClass<KnnOptions> knn(m, "KnnOptions",
                                 "The neighbour search of the outlier and normal stages.");
    knn.choice("backend", &KnnOptions::backend, knn_backend_choices(),
               "'grid' (our exact cell-grid search) or 'flann' (FLANN's kd-tree; CLI --knn).")
        .field("eps", &KnnOptions::eps,
               "flann: eps-approximate search, no neighbour farther than sqrt(1 + eps) x the "
               "true k-th; 0 = exact (CLI --knn-eps).");
    knn.finish();

    OptionsClass<OutlierOptions> o(
        m, "OutlierOptions",
        "Point outlier removal before splatting, over each point's k nearest neighbours: a "
        "statistical rule (mean neighbour distance d_i against the neighbours' average) and a "
        "planarity rule (scattered, sparse clusters).");
    o.field("enabled", &OutlierOptions::enabled,
            "Run the removal at all (bool; CLI --outliers / --no-outliers).")
        .field("k", &OutlierOptions::k, "Neighbours per point, count (3..1000).")
        .field("statistical_ratio", &OutlierOptions::statistical_ratio,
               "Statistical rule: remove when d_i > ratio x the neighbours' mean d_j, "
               "dimensionless (0 disables the rule, else >= 1).")
        .field("planarity_ratio", &OutlierOptions::planarity_ratio,
               "Planarity rule: lambda_0 / lambda_1 of the neighbourhood covariance above this, "
               "dimensionless in [0, 1) (0 disables the rule) ...")
        .field("planarity_spacing", &OutlierOptions::planarity_spacing,
               "... and d_i above this times the cloud's median d, dimensionless.")
        .field("park_bytes", &OutlierOptions::park_bytes,
               "Memory only: the cloud's columns the neighbour searches do not read (normals, "
               "colours, scales, confidences) wait in an unnamed temporary file ($TMPDIR) while "
               "they run when they hold at least this many bytes (0: always).")
        .nested("knn", &OutlierOptions::knn, "The neighbour search (KnnOptions).");
    o.finish();

    py::class_<OutlierResult>(m, "OutlierResult", "The kept points and what was removed.")
        .def_readonly("cloud", &OutlierResult::cloud,
                      "PointCloud of the kept points, every attribute, in input order.")
        .def_readonly("statistical", &OutlierResult::statistical,
                      "Points removed by the statistical rule, count.")
        .def_readonly("planarity", &OutlierResult::planarity,
                      "Points removed by the planarity rule (and not the statistical one), count.")
        .def_readonly("density_spacing", &OutlierResult::density_spacing,
                      "The kept points' median sample spacing from their neighbours' density, "
                      "world units (0 when the removal did not run).")
        .def_property_readonly(
            "removed",
            [](py::object self) { return view_flags(self.cast<OutlierResult&>().removed, self); },
            "(N,) bool view, one flag per input point, True = removed (empty in a "
            "PipelineResult whose outlier stage was off).")
        .def("__repr__", [](const OutlierResult& r) {
            return "OutlierResult(" + std::to_string(r.cloud.size()) +
                   " kept, statistical=" + std::to_string(r.statistical) +
                   ", planarity=" + std::to_string(r.planarity) + ")";
        });

    m.def(
        "remove_outliers",
        [](const PointCloud& cloud, const OutlierOptions& o) {
            return without_gil([&] { return remove_outliers(cloud, o); });
        },
        py::arg("cloud"), py::arg("options") = OutlierOptions{},
        "Removes outlier points; nothing when options.enabled is False or with fewer than k + 1 "
        "points.");
}

}  // namespace vdbrecon::python
