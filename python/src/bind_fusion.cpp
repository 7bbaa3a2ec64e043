// Range-image fusion (vdbrecon/fusion.h): the Fusion class with numpy depth images.
#include "bind.h"
#include "vdbrecon/choices.h"
#include "vdbrecon/fusion.h"

namespace vdbrecon::python {

namespace {

/// A (H, W) float32 C-contiguous array as a DepthImage (copied: the fusion keeps nothing).
DepthImage depth_image(const py::array_t<float, py::array::c_style | py::array::forcecast>& a) {
    if (a.ndim() != 2) throw InvalidArgument("depth: expected an (H, W) array");
    DepthImage img;
    img.height = int(a.shape(0));
    img.width = int(a.shape(1));
    img.depth.assign(a.data(), a.data() + a.size());
    return img;
}

/// An (H, W, 3) float array (0..1) as a ColorImage (copied).
ColorImage color_image(const py::array_t<float, py::array::c_style | py::array::forcecast>& a) {
    if (a.ndim() != 3 || a.shape(2) != 3) throw InvalidArgument("color: expected an (H, W, 3) array");
    ColorImage img;
    img.height = int(a.shape(0));
    img.width = int(a.shape(1));
    img.rgb.resize(std::size_t(a.size() / 3));
    const float* d = a.data();
    for (std::size_t i = 0; i < img.rgb.size(); ++i) img.rgb[i] = {d[3 * i], d[3 * i + 1], d[3 * i + 2]};
    return img;
}

Pose pose_of(const py::array_t<double, py::array::c_style | py::array::forcecast>& a) {
    if (a.size() != 16) throw InvalidArgument("pose: expected a (4, 4) camera-to-world matrix");
    Pose p;
    std::copy(a.data(), a.data() + 16, p.begin());
    return p;
}

}  // namespace

void bind_fusion(py::module_& m) {
    OptionsClass<DepthOptions> o(m, "DepthOptions", "How depth pixels become samples (fuse).");
    o.choice("kind", &DepthOptions::kind, depth_kind_choices(),
             "'planar': depth along the optical axis; 'ray': range along the pixel's ray "
             "(CLI --depth-kind).")
        .choice("rule", &DepthOptions::rule, fusion_rule_choices(),
                "'splat': FSSR samples into the splat's grids; 'tsdf': truncated signed distance "
                "along the rays with free-space carving (CLI --fusion).")
        .field("truncation", &DepthOptions::truncation,
               "tsdf: truncation distance, voxels (CLI --sdf-trunc).")
        .field("carve", &DepthOptions::carve,
               "tsdf: carve free space, so objects that moved away disappear (CLI --no-carve "
               "sets False).")
        .field("min_depth", &DepthOptions::min_depth,
               "Depths at or below this are no measurement, world units (CLI --min-depth).")
        .field("max_depth", &DepthOptions::max_depth,
               "Depths beyond this are no measurement, world units; 0 = no limit (CLI "
               "--max-depth).")
        .field("max_jump", &DepthOptions::max_jump,
               "Neighbours whose depth differs by more than this fraction of the pixel's are "
               "not used for its normal (CLI --max-jump).")
        .field("min_view_cos", &DepthOptions::min_view_cos,
               "Pixels seen at a grazing angle, cosine below this, give no sample (CLI "
               "--min-view-cos).")
        .field("merge_footprint", &DepthOptions::merge_footprint,
               "Frames whose pixel footprint is below this are merged into pixel blocks, world "
               "units; 0 = never, < 0 = half the smallest kernel (CLI --merge-footprint).")
        .field("aggregate", &DepthOptions::aggregate,
               "Samples of one sigma level and normal direction in one cell of this edge, in "
               "sigmas, are presummed into one kernel; 0 = off (CLI --aggregate).")
        .field("batch_samples", &DepthOptions::batch_samples,
               "Samples gathered before they are splatted together, count; 0 = every frame on "
               "its own. Only time and memory depend on it.")
        .field("reference_depth", &DepthOptions::reference_depth,
               "Beyond this depth the confidence falls as (reference/depth)^2, world units; 0 = "
               "off (CLI --reference-depth).");
    o.finish();

    py::class_<Fusion>(m, "_Fusion", "Fuses posed depth images into one volume (internal).")
        .def(py::init<const PipelineOptions&, const DepthOptions&, const Vec3d&>(),
             py::arg("options"), py::arg("depth"), py::arg("origin"))
        .def(
            "integrate_depth",
            [](Fusion& f, const py::array_t<float, py::array::c_style | py::array::forcecast>& depth,
               double fx, double fy, double cx, double cy,
               const py::array_t<double, py::array::c_style | py::array::forcecast>& pose) {
                const DepthImage img = depth_image(depth);
                const Intrinsics K{fx, fy, cx, cy, img.width, img.height};
                const Pose p = pose_of(pose);
                return without_gil([&] { return f.integrate(img, K, p); });
            },
            py::arg("depth"), py::arg("fx"), py::arg("fy"), py::arg("cx"), py::arg("cy"),
            py::arg("pose"))
        .def(
            "integrate_color",
            [](Fusion& f, const py::array_t<float, py::array::c_style | py::array::forcecast>& depth,
               double fx, double fy, double cx, double cy,
               const py::array_t<double, py::array::c_style | py::array::forcecast>& pose,
               const py::array_t<float, py::array::c_style | py::array::forcecast>& color,
               double cfx, double cfy, double ccx, double ccy) {
                const DepthImage img = depth_image(depth);
                const ColorImage col = color_image(color);
                const Intrinsics K{fx, fy, cx, cy, img.width, img.height};
                const Intrinsics C{cfx, cfy, ccx, ccy, col.width, col.height};
                const Pose p = pose_of(pose);
                return without_gil([&] { return f.integrate(img, K, p, col, C); });
            },
            py::arg("depth"), py::arg("fx"), py::arg("fy"), py::arg("cx"), py::arg("cy"),
            py::arg("pose"), py::arg("color"), py::arg("cfx"), py::arg("cfy"), py::arg("ccx"),
            py::arg("ccy"))
        .def(
            "integrate_scan",
            [](Fusion& f, const PointCloud& scan, const Vec3d& sensor) {
                return without_gil([&] { return f.integrate_scan(scan, sensor); });
            },
            py::arg("scan"), py::arg("sensor"))
        .def(
            "integrate_cloud",
            [](Fusion& f, const PointCloud& cloud) {
                return without_gil([&] { return f.integrate(cloud); });
            },
            py::arg("cloud"))
        .def("volume", [](const Fusion& f) { return without_gil([&] { return f.volume(); }); })
        .def("reconstruct",
             [](const Fusion& f) { return without_gil([&] { return f.reconstruct(); }); })
        .def_property_readonly("frames", &Fusion::frames)
        .def_property_readonly("samples", &Fusion::samples);
}

}  // namespace vdbrecon::python
