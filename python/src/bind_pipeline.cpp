// The whole reconstruction (vdbrecon/pipeline.h).
#include "bind.h"
#include "vdbrecon/choices.h"
#include "vdbrecon/pipeline.h"

namespace vdbrecon::python {

namespace {

/// reconstruct() replaces the arrays of the cloud it is given (normals, scales, and all of them
/// with outlier removal). The Python PointCloud must not change under its numpy views, so the
/// call works on a cloud that borrows every array of it (PointCloud::view, no copy); the Python
/// object holds the arrays for the duration of the call.
PipelineResult reconstruct_borrowed(const PointCloud& cloud, const PipelineOptions& options) {
    PointCloud work = cloud.view();
    return reconstruct(work, options);
}

/// PipelineOptions: every stage's options and the run's own.
void bind_pipeline_options(py::module_& m) {
    OptionsClass<PipelineOptions> o(m, "PipelineOptions",
                                    "Every knob of the reconstruction: one nested options struct "
                                    "per stage plus the pipeline's own fields.");
    o.nested("read", &PipelineOptions::read, "ReadOptions (run() only).")
        .nested("outliers", &PipelineOptions::outliers, "OutlierOptions; on by default.")
        .nested("normals", &PipelineOptions::normals, "NormalOptions.")
        .nested("splat", &PipelineOptions::splat,
                "SplatOptions; splat.voxel_size == 0 chooses the voxel from the point spacing.")
        .nested("close", &PipelineOptions::close, "CloseOptions; off by default.")
        .nested("mesh", &PipelineOptions::mesh, "MeshOptions.")
        .nested("clean", &PipelineOptions::clean, "CleanOptions.")
        .nested("planes", &PipelineOptions::planes,
                "PlaneOptions; off by default (planes_enabled=True, CLI --planes).")
        .nested("decimate", &PipelineOptions::decimate,
                "DecimateOptions; off while ratio is 1 and max_error 0.")
        .nested("texture", &PipelineOptions::texture,
                "TextureOptions; off by default (texture_enabled=True with planes_enabled=True, "
                "CLI --texture); run() then writes an OBJ, <out>.mtl and <out>.texture.png.")
        .nested("write", &PipelineOptions::write, "WriteOptions (run() only).")
        .field("fill_holes", &PipelineOptions::fill_holes,
               "Fill the mesh's boundary loops of at most this many edges (Liepa 03), count; "
               "0 = none (CLI --fill-holes).")
        .field("watertight", &PipelineOptions::watertight,
               "A closed, manifold, one-piece mesh: keep the largest piece, fill every hole; "
               "closed_volume is its signed distance field (bool; CLI --watertight).")
        .field("tile", &PipelineOptions::tile,
               "Splat, close and mesh cubes of this many voxels one at a time (rounded up to a "
               "multiple of 8), each from the samples within a halo of it: the same mesh in "
               "less memory, no volumes kept; 0 = untiled, -1 = the largest that fits "
               "splat.max_memory (CLI --tile N|auto).")
        .field("auto_tile", &PipelineOptions::auto_tile,
               "With tile = 0: tile anyway (as tile = -1) when the run would not fit "
               "splat.max_memory, and keep no volumes; False refuses such a run (CLI --tile 0).")
        .choice("stream", &PipelineOptions::stream, stream_mode_choices(),
                "Tiled runs from a file (run(), prepare_tiles()): read a PLY file with normals "
                "a chunk at a time and run the point stages a region at a time, memory bounded "
                "by a region, the same mesh; 'auto' when the points would take over half of "
                "splat.max_memory, 'on' whenever the file allows it, 'off' (CLI --stream).")
        .field("job_dir", &PipelineOptions::job_dir,
               "run() from a file: keep the tiled run's job directory here, so that the same run "
               "again resumes from the tiles it finished (the same bytes); another input or "
               "other options are refused; implies tiling (CLI --job-dir).")
        .field("threads", &PipelineOptions::threads,
               "Worker threads, 0 = all cores; the output does not depend on it (CLI --threads).")
        .field("write_vdb", &PipelineOptions::write_vdb,
               "Write <out>.splat.vdb (and <out>.closed.vdb when closing) next to the mesh "
               "(run() only; CLI --no-vdb sets False).")
        .field("keep_volumes", &PipelineOptions::keep_volumes,
               "Return the splatted (and closed) volumes in the result; False frees them once "
               "the mesh is made (lower peak memory; the CLI sets False).")
        .field("auto_voxel_factor", &PipelineOptions::auto_voxel_factor,
               "Automatic voxel = auto_voxel_factor * the median sample spacing (from the "
               "density of each point's nearest neighbours), dimensionless.")
        .field("auto_voxel_max_cells", &PipelineOptions::auto_voxel_max_cells,
               "The automatic voxel is never finer than the bounding-box diagonal / this, count.");
    o.finish();
}

}  // namespace

void bind_pipeline(py::module_& m) {
    bind_pipeline_options(m);
    py::class_<StageTiming>(m, "StageTiming", "Wall time of one stage.")
        .def_readonly("stage", &StageTiming::stage)
        .def_readonly("seconds", &StageTiming::seconds)
        .def_readonly("peak_rss_mb", &StageTiming::peak_rss_mb,
                      "Peak resident memory of the process when the stage ended, MB.")
        .def("__repr__", [](const StageTiming& t) {
            return "StageTiming('" + t.stage + "', seconds=" + std::to_string(t.seconds) + ")";
        });

    py::class_<PipelineResult>(m, "PipelineResult", "Everything reconstruct() produced.")
        .def_readonly("mesh", &PipelineResult::mesh, "The Mesh.")
        .def_readonly("volume", &PipelineResult::volume, "The splatted Volume.")
        .def_property_readonly(
            "closed_volume",
            [](const PipelineResult& r) -> py::object {
                if (!r.closed_volume.sdf) return py::none();
                return py::cast(r.closed_volume);
            },
            "The closed Volume that was meshed (with its 'fill' grid), or None without closing.")
        .def_readonly("outliers", &PipelineResult::outliers,
                      "OutlierResult (counts and the removed flags of the input points; no "
                      "cloud).")
        .def_readonly("normals", &PipelineResult::normals,
                      "NormalResult (counts; its arrays are empty here).")
        .def_readonly("splat", &PipelineResult::splat, "SplatResult (statistics; no volume).")
        .def_readonly("close", &PipelineResult::close,
                      "CloseResult (statistics; no volume, see closed_volume).")
        .def_readonly("mesh_stats", &PipelineResult::mesh_stats,
                      "MeshResult (statistics; no mesh).")
        .def_readonly("holes", &PipelineResult::holes,
                      "HoleFillResult (statistics; no mesh) of fill_holes / watertight.")
        .def_readonly("planes", &PipelineResult::planes,
                      "PlaneResult (planes and statistics; no mesh) of planes_enabled=True.")
        .def_readonly("texture", &PipelineResult::texture,
                      "TextureAtlas of texture_enabled=True (empty: width 0).")
        .def_readonly("clean_stats", &PipelineResult::clean_stats,
                      "CleanResult (statistics; no mesh).")
        .def_readonly("voxel_size", &PipelineResult::voxel_size, "The voxel used, world units.")
        .def_readonly("voxel_chosen", &PipelineResult::voxel_chosen,
                      "True when the voxel was picked automatically.")
        .def_readonly("spacing", &PipelineResult::spacing,
                      "The median sample spacing it was picked from, world units.")
        .def_readonly("tile", &PipelineResult::tile,
                      "Tiled runs: the tile edge used, voxels (0: untiled).")
        .def_readonly("auto_tiled", &PipelineResult::auto_tiled,
                      "Why the run tiled itself over its memory budget ('' when it did not).")
        .def_readonly("tile_halo", &PipelineResult::tile_halo,
                      "Tiled runs: the halo of samples around each tile, voxels.")
        .def_readonly("tiles", &PipelineResult::tiles,
                      "Tiled runs: the tiles that had samples near them.")
        .def_readonly("max_tile_points", &PipelineResult::max_tile_points,
                      "Tiled runs: samples of the largest tile with its halo.")
        .def_readonly("stream_units", &PipelineResult::stream_units,
                      "Streamed tiled runs: the regions the point stages ran on one at a time "
                      "(0: the cloud was in memory).")
        .def_readonly("stream_largest", &PipelineResult::stream_largest,
                      "Streamed tiled runs: the points of the largest region with its halo.")
        .def_readonly("timings", &PipelineResult::timings, "StageTiming per stage.")
        .def("__repr__", [](const PipelineResult& r) {
            return "PipelineResult(" + std::to_string(r.mesh.faces.size()) +
                   " faces, voxel_size=" + std::to_string(r.voxel_size) + ")";
        });

    py::class_<RunResult>(m, "RunResult", "What run() did.")
        .def_readonly("result", &RunResult::result, "The PipelineResult.")
        .def_readonly("read", &RunResult::read, "The ReadResult (counts; no cloud).")
        .def_readonly("mesh_path", &RunResult::mesh_path)
        .def_readonly("vdb_path", &RunResult::vdb_path,
                      "<out>.splat.vdb; empty when no .vdb was written.")
        .def_readonly("closed_vdb_path", &RunResult::closed_vdb_path,
                      "<out>.closed.vdb; empty without closing or when no .vdb was written.")
        .def_readonly("material_path", &RunResult::material_path,
                      "<out>.mtl with texture_enabled, else empty.")
        .def_readonly("texture_path", &RunResult::texture_path,
                      "<out>.texture.png with texture_enabled and planar regions, else empty.");

    m.def("version", &version, "Library version, 'major.minor.patch'.");
    m.def(
        "reconstruct",
        [](PointCloud& cloud, const PipelineOptions& options) {
            return without_gil([&] { return reconstruct_borrowed(cloud, options); });
        },
        py::arg("cloud"), py::arg("options"),
        "Runs outliers > normals > splat > close > mesh > clean on a PointCloud (left "
        "unchanged).");
    m.def(
        "run",
        [](const std::string& input, const std::string& output, const PipelineOptions& options) {
            return without_gil([&] { return run(input, output, options); });
        },
        py::arg("input"), py::arg("output"), py::arg("options"),
        "Reads `input`, reconstructs, writes `output`, <output stem>.splat.vdb and, when "
        "closing, <output stem>.closed.vdb (the CLI).");
    m.def("stage_volume_path", &stage_volume_path, py::arg("mesh_path"), py::arg("stage"),
          "'out/scan.ply', 'splat' -> 'out/scan.splat.vdb'.");
}

}  // namespace vdbrecon::python
