// Morphological closing of the volume (vdbrecon/close.h).
#include "bind.h"
#include "vdbrecon/close.h"

namespace vdbrecon::python {

void bind_close(py::module_& m) {
    OptionsClass<CloseOptions> o(m, "CloseOptions",
                                 "Morphological closing of the volume before meshing (dilate > "
                                 "fill > erode); both radii 0 (the default) = off.");
    o.field("hole_radius", &CloseOptions::hole_radius,
            "Hole closing radius, voxels (0 = off): the voxels the mesher's trims keep are "
            "closed with a (2R+1)^3 cube and the new ones filled from their neighbours; holes "
            "up to about 2R voxels across close, open borders stay (CLI --close).")
        .field("solid_radius", &CloseOptions::solid_radius,
               "Solid closing radius, voxels (0 = off): the watertight surface is offset out by "
               "R and back in by R; concavities narrower than about 2R close (CLI "
               "--close-solid).");
    o.finish();
    o.cls().def("enabled", &CloseOptions::enabled, "True when a radius is > 0.");

    py::class_<CloseResult>(m, "CloseResult", "The closed volume and what the closing did.")
        .def_readonly("volume", &CloseResult::volume,
                      "The closed Volume; its 'fill' grid marks the voxels the closing vouches "
                      "for (the mesher keeps faces there whatever their weight or gap).")
        .def_readonly("supported_voxels", &CloseResult::supported_voxels,
                      "Hole closing: valid voxels the mesher's trims would keep, count.")
        .def_readonly("closed_voxels", &CloseResult::closed_voxels,
                      "Hole closing: supported voxels after the closing, count.")
        .def_readonly("filled_voxels", &CloseResult::filled_voxels,
                      "Voxels that had no splatted value and were filled, count.")
        .def_readonly("solid_voxels_before", &CloseResult::solid_voxels_before,
                      "Solid closing: voxels inside the surface before, count.")
        .def_readonly("solid_voxels_after", &CloseResult::solid_voxels_after,
                      "Solid closing: voxels inside the surface after, count.")
        .def("__repr__", [](const CloseResult& r) {
            return "CloseResult(supported_voxels=" + std::to_string(r.supported_voxels) +
                   ", closed_voxels=" + std::to_string(r.closed_voxels) +
                   ", filled_voxels=" + std::to_string(r.filled_voxels) +
                   ", solid_voxels_before=" + std::to_string(r.solid_voxels_before) +
                   ", solid_voxels_after=" + std::to_string(r.solid_voxels_after) + ")";
        });

    m.def(
        "close_volume",
        [](const Volume& volume, const CloseOptions& o, const MeshOptions& mesh) {
            return without_gil([&] { return close_volume(volume, o, mesh); });
        },
        py::arg("volume"), py::arg("options") = CloseOptions{},
        py::arg("mesh_options") = MeshOptions{},
        "Closes the volume; mesh_options give the trims that define the supported voxels. "
        "Returns the input unchanged when both radii are 0.");
}

}  // namespace vdbrecon::python
