// Splatting (vdbrecon/splat.h).
#include "bind.h"
#include "vdbrecon/splat.h"

namespace vdbrecon::python {

void bind_splat(py::module_& m) {
    OptionsClass<SplatOptions> o(m, "SplatOptions",
                                 "Gaussian splatting of oriented points into the volume (FSSR, "
                                 "Fuhrmann and Goesele 2014).");
    o.field("voxel_size", &SplatOptions::voxel_size,
            "Voxel edge, world units; 0 = chosen from the point spacing (CLI --voxel).")
        .field("scale_factor", &SplatOptions::scale_factor,
               "sigma_i = scale_factor * scale_i for points with a per-point scale, dimensionless "
               "(CLI --sigma).")
        .field("sigma_voxels", &SplatOptions::sigma_voxels,
               "sigma for points without a scale, voxels (CLI --sigma-voxels).")
        .field("min_sigma_voxels", &SplatOptions::min_sigma_voxels,
               "Lower bound on sigma, voxels (CLI --min-sigma).")
        .field("max_sigma_voxels", &SplatOptions::max_sigma_voxels,
               "Upper bound on sigma, voxels (CLI --max-sigma).")
        .field("support", &SplatOptions::support,
               "Support radius of the kernel, sigmas (CLI --support).")
        .field("min_weight", &SplatOptions::min_weight,
               "Voxels with less summed weight are invalid (inactive), but for those within two "
               "voxels of the surface, which need a fifth of it; dimensionless (CLI --min-weight).")
        .field("aggregate", &SplatOptions::aggregate,
               "Presumming: the samples of one cell of this many sigmas (one sigma level, normals "
               "within crease_angle, 90 degrees without one) become one kernel; 0 = every "
               "sample its own (CLI --aggregate).")
        .field("aggregate_max_cell", &SplatOptions::aggregate_max_cell,
               "... cells no wider than this, voxels; 0 = no cap.")
        .field("max_memory", &SplatOptions::max_memory,
               "Memory budget of the run, bytes; 0 = half the physical memory. splat() refuses "
               "with a suggested voxel size, before allocating the grids, when its estimate "
               "exceeds it (CLI --max-memory).");
    o.finish();

    py::class_<SplatResult>(m, "SplatResult", "The volume and statistics of a splat.")
        .def_readonly("volume", &SplatResult::volume, "The Volume.")
        .def_readonly("active_voxels", &SplatResult::active_voxels, "Valid voxels.")
        .def_readonly("touched_voxels", &SplatResult::touched_voxels,
                      "Voxels with any weight (valid or not).")
        .def_readonly("leaves", &SplatResult::leaves, "8^3 leaves allocated.")
        .def_readonly("memory_bytes", &SplatResult::memory_bytes, "Memory of the grids, bytes.")
        .def_readonly("points", &SplatResult::points,
                      "Kernels splatted (samples, or their presummed groups).")
        .def_readonly("samples", &SplatResult::samples, "Samples given.")
        .def_readonly("updates", &SplatResult::updates,
                      "Point-voxel kernel evaluations inside the support.")
        .def_readonly("sigma_min", &SplatResult::sigma_min, "World units.")
        .def_readonly("sigma_median", &SplatResult::sigma_median, "World units.")
        .def_readonly("sigma_max", &SplatResult::sigma_max, "World units.")
        .def_readonly("skipped_points", &SplatResult::skipped_points,
                      "Points without a usable normal, not splatted.")
        .def("__repr__", [](const SplatResult& r) {
            return "SplatResult(active_voxels=" + std::to_string(r.active_voxels) +
                   ", leaves=" + std::to_string(r.leaves) +
                   ", sigma_median=" + std::to_string(r.sigma_median) + ")";
        });

    m.def(
        "splat",
        [](const PointCloud& cloud, const SplatOptions& o) {
            return without_gil([&] { return splat(cloud, o); });
        },
        py::arg("cloud"), py::arg("options"), "Splats an oriented cloud into a Volume.");
}

}  // namespace vdbrecon::python
