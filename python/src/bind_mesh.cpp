// Surface extraction (vdbrecon/mesh.h).
#include "bind.h"
#include "vdbrecon/mesh.h"

namespace vdbrecon::python {

void bind_mesh(py::module_& m) {
    OptionsClass<MeshOptions> o(m, "MeshOptions",
                                "Surface extraction from the volume's sdf grid: 'dual' dual "
                                "marching cubes (Nielson 04; volumeToMesh's surface, faster), "
                                "'vdb' OpenVDB volumeToMesh, 'mc' marching cubes (Lorensen 87), "
                                "'dc' dual contouring (Ju 02).");
    o.choice("method", &MeshOptions::method, mesher_choices(),
             "Which mesher extracts the surface (CLI --mesher).")
        .field("isovalue", &MeshOptions::isovalue,
               "Iso-value of the surface, world units (0 = the zero crossing of the SDF).")
        .field("adaptivity", &MeshOptions::adaptivity,
               "volumeToMesh adaptivity, 0 (uniform) .. 1 (coarsest), method 'vdb' only; keep 0 "
               "for open scans (CLI --adaptivity).")
        .field("min_surface_weight", &MeshOptions::min_surface_weight,
               "Relative support: a vertex whose summed weight is below this times the weight "
               "at its nearest sample is unsupported; unsupported faces reached from an open "
               "border or a gap are trimmed. Dimensionless; 0 disables (CLI --surface-weight).")
        .field("max_gap", &MeshOptions::max_gap,
               "Faces with a vertex farther than this (and max_gap_spacings sample spacings) "
               "from every sample are trimmed, voxels; inf disables the test (CLI --max-gap).")
        .field("max_gap_spacings", &MeshOptions::max_gap_spacings,
               "The gap test never trims closer than this many sample spacings, so that the "
               "random gaps of a sample are no gap (dimensionless).")
        .field("sample_spacing", &MeshOptions::sample_spacing,
               "Median sample spacing, world units; 0 = the volume's 'sample_spacing' metadata "
               "(reconstruct records it).")
        .field("dc_truncation", &MeshOptions::dc_truncation,
               "Dual contouring: singular values of the quadric below this fraction of the "
               "largest are dropped.")
        .field("dc_bias", &MeshOptions::dc_bias,
               "Dual contouring: pull towards the mass point of the crossings, relative to one "
               "crossing's plane (0 = none).")
        .field("normals", &MeshOptions::normals,
               "Compute per-vertex normals from the SDF gradient (bool).");
    o.finish();

    py::class_<MeshResult>(m, "MeshResult", "The mesh and what was removed from it.")
        .def_readonly("mesh", &MeshResult::mesh, "The Mesh.")
        .def_readonly("dropped_faces", &MeshResult::dropped_faces,
                      "Faces removed because they touched an invalid cell.")
        .def_readonly("trimmed_faces", &MeshResult::trimmed_faces,
                      "Faces trimmed as unsupported (relative weight or gap).")
        .def_property_readonly(
            "support",
            [](const MeshResult& r) {
                std::vector<float> v = r.support;
                return adopt(std::move(v), 0);
            },
            "(V,) float32: the summed kernel weight at each vertex (empty without a weight "
            "grid); clean_mesh's support.")
        .def("__repr__", [](const MeshResult& r) {
            return "MeshResult(" + std::to_string(r.mesh.faces.size()) +
                   " faces, dropped_faces=" + std::to_string(r.dropped_faces) +
                   ", trimmed_faces=" + std::to_string(r.trimmed_faces) + ")";
        });

    m.def(
        "extract_mesh",
        [](const Volume& volume, const MeshOptions& o) {
            return without_gil([&] { return extract_mesh(volume, o); });
        },
        py::arg("volume"), py::arg("options") = MeshOptions{},
        "Extracts the iso-surface of volume.sdf.");
}

}  // namespace vdbrecon::python
