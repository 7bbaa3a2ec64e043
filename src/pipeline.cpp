// The reconstruction pipeline (see pipeline.h).
#include "vdbrecon/pipeline.h"
#include "vdbrecon/tiles.h"

#include <sys/resource.h>
#include <sys/stat.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <tbb/task_group.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <sstream>

#include "detail/io_common.h"
#include "detail/job_dir.h"
#include "detail/parked.h"
#include "detail/release.h"
#include "detail/run.h"
#include "detail/spool.h"
#include "detail/stream_tiles.h"
#include "detail/tiles.h"
#include "detail/volume_grids.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/log.h"

#ifndef VDBRECON_VERSION
#define VDBRECON_VERSION "0.0.0"
#endif

namespace vdbrecon {

const char* version() { return VDBRECON_VERSION; }

void PipelineOptions::validate() const {
    outliers.validate();
    normals.validate();
    close.validate();
    // voxel_size 0 means "choose"; check the rest with a stand-in voxel.
    SplatOptions s = splat;
    if (s.voxel_size == 0.0) s.voxel_size = 1.0;
    s.validate();
    mesh.validate();
    clean.validate();
    preview.validate();
    if (decimate.ratio != 1.0 || decimate.max_error != 0.0) decimate.validate();
    if (planes.enabled) planes.validate();
    if (texture.enabled) {
        texture.validate();
        if (!planes.enabled) {
            throw InvalidArgument("texture: textures are made for planar regions; enable the "
                                  "planes stage too (CLI --planes)");
        }
    }
    if (tile < -1 || tile > 65536) {
        throw InvalidArgument("tile = " + std::to_string(tile) +
                              ": must be in 0..65536 voxels (0 = untiled, -1 = automatic)");
    }
    if (tile != 0 && close.solid_radius > 0) {
        throw InvalidArgument("tile: a solid closing needs the whole surface at once; use "
                              "hole closing (--close) or no tiles");
    }
    if (threads < 0 || threads > 1024) {
        throw InvalidArgument("threads = " + std::to_string(threads) + ": must be in 0..1024");
    }
    if (!(std::isfinite(auto_voxel_factor) && auto_voxel_factor > 0.0)) {
        throw InvalidArgument("auto_voxel_factor must be a positive number");
    }
    if (!(auto_voxel_max_cells >= 16.0 && auto_voxel_max_cells <= 65536.0)) {
        throw InvalidArgument("auto_voxel_max_cells must be in 16..65536");
    }
}

double choose_voxel_size(const PointCloud& cloud, double spacing, const PipelineOptions& options) {
    return detail::voxel_for(bounding_box(cloud.positions).diagonal(), spacing, options);
}

double detail::voxel_for(double diag, double spacing, const PipelineOptions& options) {
    double voxel = options.auto_voxel_factor * spacing;
    if (!(voxel > 0.0)) voxel = diag / 300.0;  // no spacing information
    voxel = std::max(voxel, diag / options.auto_voxel_max_cells);
    if (!(voxel > 0.0)) {
        throw NumericalError("cannot choose a voxel size: all points coincide. Hint: --voxel");
    }
    return voxel;
}

std::string stage_volume_path(const std::string& mesh_path, const std::string& stage) {
    return detail::path_stem(mesh_path) + "." + stage + ".vdb";
}

[[noreturn]] void detail::rethrow_naming(const std::string& input, const Error& e) {
    const std::string what = e.what();
    if (what.rfind(input + ": ", 0) == 0) throw;
    const std::string m = input + ": " + what;
    if (dynamic_cast<const IoError*>(&e)) throw IoError(m);
    if (dynamic_cast<const FormatError*>(&e)) throw FormatError(m);
    if (dynamic_cast<const InvalidArgument*>(&e)) throw InvalidArgument(m);
    if (dynamic_cast<const NumericalError*>(&e)) throw NumericalError(m);
    throw Error(m);
}

double detail::peak_rss_mb() {
    struct rusage ru {};
    ::getrusage(RUSAGE_SELF, &ru);
    return double(ru.ru_maxrss) / 1024.0;  // Linux reports kilobytes
}

namespace {

using detail::in_arena;
using detail::peak_rss_mb;
using detail::StageClock;

std::string basename_stem(const std::string& path) {
    const std::size_t slash = path.find_last_of('/');
    std::string base = slash == std::string::npos ? path : path.substr(slash + 1);
    const std::size_t dot = base.find_last_of('.');
    if (dot != std::string::npos && dot > 0) base = base.substr(0, dot);
    return base;
}

bool same_file(const std::string& a, const std::string& b) {
    struct stat sa {}, sb {};
    if (::stat(a.c_str(), &sa) != 0 || ::stat(b.c_str(), &sb) != 0) return false;
    return sa.st_dev == sb.st_dev && sa.st_ino == sb.st_ino;
}

}  // namespace

namespace {

/// The median sample spacing for the automatic voxel: from the first stage that searched
/// neighbours, else the per-point scales' median.
double sample_spacing(const PipelineResult& r) {
    if (r.outliers.density_spacing > 0.0) return r.outliers.density_spacing;
    if (r.normals.density_spacing > 0.0) return r.normals.density_spacing;
    return r.normals.median_scale;
}

/// The hole-filling stage (fill_holes, watertight) and, with watertight, the closed mesh's
/// volume in `frame` (handed to on_volume as "closed").
void fill_and_close(PipelineResult& r, const PipelineOptions& options, const Volume& frame,
                    const StageCallback& on_stage, const VolumeCallback& on_volume) {
    if (!options.watertight && options.fill_holes == 0) return;
    {
        StageClock clock(r.timings, on_stage, "fill");
        HoleFillOptions h;
        h.max_edges = options.watertight ? 0 : options.fill_holes;
        r.holes = fill_holes(r.mesh, h);
        r.mesh = std::move(r.holes.mesh);
        r.holes.mesh = Mesh{};
    }
    if (!options.watertight || r.mesh.faces.empty()) return;
    const TopologyStats t = mesh_topology(r.mesh);
    if (!t.watertight() || t.components != 1) {
        // A loop through a non-manifold vertex, or a fill across a wide, warped loop (an open
        // scan of no closed object) that folds onto itself.
        log_warning("watertight: the filled mesh still has " + std::to_string(t.boundary_edges) +
                    " boundary and " + std::to_string(t.nonmanifold_edges) +
                    " non-manifold edges in " + std::to_string(t.components) +
                    " pieces (largest loop filled: " + std::to_string(r.holes.largest_filled) +
                    " edges); --watertight is meant for scans of closed objects");
    }
    StageClock clock(r.timings, on_stage, "closed volume");
    Volume closed = mesh_volume(r.mesh, frame);
    closed.metadata["watertight"] = "1";
    if (on_volume) on_volume("closed", closed);
    if (options.keep_volumes) r.closed_volume = std::move(closed);
}

/// The stages after the mesh: clean > fill (and, with watertight, the closed volume in
/// `frame`) > planes > decimate.
void mesh_cleanup_stages(PipelineResult& r, const PipelineOptions& options, const Volume& frame,
                         const StageCallback& on_stage, const VolumeCallback& on_volume) {
    {
        StageClock clock(r.timings, on_stage, "clean");
        CleanOptions clean = options.clean;
        if (options.watertight) clean.min_component_ratio = 1.0;  // one piece
        // The evidence is counted in samples: the cloud's spacing (a tiled run's is its plan's,
        // so that the tiles and the whole volume agree), else the mesh's edges.
        if (clean.sample_spacing == 0.0) {
            clean.sample_spacing = sample_spacing(r) > 0.0 ? sample_spacing(r) : r.spacing;
        }
        r.clean_stats = clean_mesh(std::move(r.mesh), clean, r.mesh_stats.support);
        detail::release(r.mesh_stats.support);
        r.mesh = std::move(r.clean_stats.mesh);
        r.clean_stats.mesh = Mesh{};
    }
    fill_and_close(r, options, frame, on_stage, on_volume);
    if (options.planes.enabled && !r.mesh.faces.empty()) {
        StageClock clock(r.timings, on_stage, "planes");
        r.planes = planar_regions(r.mesh, options.planes, r.voxel_size);
        r.mesh = std::move(r.planes.mesh);
        r.planes.mesh = Mesh{};
    }
    if (options.decimate.ratio != 1.0 || options.decimate.max_error != 0.0) {
        StageClock clock(r.timings, on_stage, "decimate");
        r.decimation = vdbrecon::decimate(r.mesh, options.decimate);
        r.mesh = std::move(r.decimation.mesh);
        r.decimation.mesh = Mesh{};
    }
}

/// The stages after the splat, on r.volume: close > mesh > clean > fill (and the closed
/// volume). The volumes go to on_volume once the mesh is made, while the stages after it run:
/// the mesh stage scales over the threads, the clean stage is serial (bunny at 0.5 mm, 2
/// threads: its .vdb written beside the mesh stage took a thread from it for 0.1 s).
void mesh_stages(PipelineResult& r, const PipelineOptions& options, const StageCallback& on_stage,
                 const VolumeCallback& on_volume) {
    tbb::task_group side;
    auto stop_side = [&] {
        side.cancel();
        try {
            side.wait();
        } catch (...) {
        }
    };
    const Volume* meshed = &r.volume;
    if (options.close.enabled()) {
        StageClock clock(r.timings, on_stage, "close");
        r.close = close_volume(r.volume, options.close, options.mesh);
        r.closed_volume = std::move(r.close.volume);
        r.close.volume = Volume{};
        meshed = &r.closed_volume;
    }
    {
        StageClock clock(r.timings, on_stage, "mesh");
        r.mesh_stats = extract_mesh(*meshed, options.mesh);
        r.mesh = std::move(r.mesh_stats.mesh);
        r.mesh_stats.mesh = Mesh{};
    }
    if (on_volume) {
        side.run([&] { on_volume("splat", r.volume); });
        if (meshed != &r.volume) side.run([&] { on_volume("closed", r.closed_volume); });
    }
    try {
        // --watertight keeps the grid frame for the closed mesh's volume.
        Volume frame;
        if (options.watertight) {
            frame.sdf = openvdb::FloatGrid::create(r.volume.sdf->background());  // its frame only
            frame.sdf->setTransform(r.volume.sdf->transform().copy());
            frame.voxel_size = r.volume.voxel_size;
            frame.origin = r.volume.origin;
            frame.metadata = r.volume.metadata;
        }
        mesh_cleanup_stages(r, options, frame, on_stage, on_volume);
    } catch (...) {
        stop_side();
        throw;
    }
    side.wait();  // rethrows what on_volume threw
    if (!options.keep_volumes) {
        r.volume = Volume{};
        r.closed_volume = Volume{};
    }
}

}  // namespace

detail::TiledOptions detail::tiled_options(const PipelineOptions& options,
                                           const SplatOptions& splat, double spacing) {
    detail::TiledOptions t;
    t.splat = splat;
    t.close = options.close;
    t.mesh = options.mesh;
    t.tile = options.tile;
    t.sample_spacing = spacing;
    return t;
}

namespace {

/// A tiled surface's mesh and statistics into the result.
void take_tiled(PipelineResult& r, detail::TiledResult&& tiled) {
    r.splat = std::move(tiled.splat);
    r.close = std::move(tiled.close);
    r.mesh_stats = std::move(tiled.mesh);
    r.mesh = std::move(r.mesh_stats.mesh);
    r.mesh_stats.mesh = Mesh{};
    r.tiles = tiled.tiles;
    r.tile = tiled.tile;
    r.tile_halo = tiled.halo;
    if (r.spacing == 0.0) r.spacing = tiled.sample_spacing;
    r.max_tile_points = tiled.max_tile_points;
}

/// mesh_cleanup_stages for a tiled mesh: no volume, its frame made from the voxel and origin.
void tiled_cleanup_stages(PipelineResult& r, const PipelineOptions& options, double voxel,
                          const Vec3d& origin, const StageCallback& on_stage,
                          const VolumeCallback& on_volume) {
    Volume frame;  // the grid frame, for --watertight's closed volume
    if (options.watertight) {
        frame = detail::make_volume(openvdb::FloatGrid::create(0.0f),
                                    openvdb::FloatGrid::create(0.0f),
                                    openvdb::Vec3fGrid::create(), nullptr, voxel, origin);
    }
    mesh_cleanup_stages(r, options, frame, on_stage, on_volume);
}

/// splat > close > mesh tile by tile (detail/tiles.h) on an oriented cloud (freed once the
/// tiles are meshed, before their pieces are welded, when `consume`), then the stages after
/// the mesh. No volume is kept or handed to
/// on_volume: no tile holds the whole of it.
void tiled_stages(PipelineResult& r, PointCloud& cloud, bool consume,
                  const SplatOptions& splat_options, const PipelineOptions& options,
                  const StageCallback& on_stage, const VolumeCallback& on_volume) {
    const Vec3d origin = cloud.origin;
    {
        StageClock clock(r.timings, on_stage, "tiles");
        detail::TiledResult tiled = detail::tiled_surface(
            cloud, detail::tiled_options(options, splat_options, sample_spacing(r)), consume);
        take_tiled(r, std::move(tiled));
    }
    tiled_cleanup_stages(r, options, splat_options.voxel_size, origin, on_stage, on_volume);
}

/// Whether splat() refused for the memory budget (check_memory's message).
bool over_budget(const InvalidArgument& e) {
    return std::string(e.what()).find(" of memory (") != std::string::npos;
}

/// The splat, into r; false, with nothing done, when it would exceed the memory budget and the
/// run may tile itself instead (PipelineOptions::auto_tile; r.auto_tiled says why). A refusal
/// for the budget also suggests tiles.
bool splat_untiled(PipelineResult& r, const PointCloud& cloud, const SplatOptions& splat_options,
                   const PipelineOptions& options, const StageCallback& on_stage) {
    StageClock clock(r.timings, on_stage, "splat");
    try {
        r.splat = splat(cloud, splat_options);
    } catch (const InvalidArgument& e) {
        if (!over_budget(e)) throw;
        std::string what = e.what();
        if (options.close.solid_radius > 0) throw;  // needs the whole surface: no tiles
        if (!options.auto_tile) {
            throw InvalidArgument(what + ", or --tile auto (tile by tile, the same mesh)");
        }
        what = what.substr(0, what.find(". Hint"));
        if (what.compare(0, 7, "splat: ") == 0) what = what.substr(7);
        r.auto_tiled = what;
        log_info("tiles: " + what + ": the run tiles itself (--tile auto; --tile 0 refuses)");
        return false;
    }
    r.volume = std::move(r.splat.volume);
    r.splat.volume = Volume{};
    return true;
}

/// The planar regions' textures from the (kept) cloud's colours, when asked for.
void texture_stage(PipelineResult& r, const PointCloud& cloud, const PipelineOptions& options,
                   const StageCallback& on_stage) {
    if (!options.texture.enabled || r.mesh.faces.empty()) return;
    StageClock clock(r.timings, on_stage, "texture");
    r.texture = texture_regions(r.mesh, r.planes.planes, cloud, options.texture, r.voxel_size);
}

/// The normal stage of point_stages: normals and scales into the cloud. Where no normal is to
/// be estimated and the scales need a neighbour search of its own (no outlier stage handed them
/// over), the search runs with the cloud's normals, colours and confidences parked
/// (detail/parked.h, above OutlierOptions::park_bytes). Otherwise the stage gets the normals
/// lent (a borrowed column): what it keeps unchanged it shares rather than copies (a 20M-point
/// cloud's normals are 229 MiB).
void normal_stage(PipelineResult& r, PointCloud& cloud, const PipelineOptions& options,
                  KnnResult& neighbours) {
    if (r.outliers.spacing.empty() && !normals_need_neighbours(cloud, options.normals) &&
        scales_need_neighbours(cloud, options.normals)) {
        detail::ParkedColumns parked(
            cloud, options.outliers.park_bytes,
            detail::kParkNormals | detail::kParkColors | detail::kParkConfidences, "normals");
        r.normals = estimate_scales(cloud, options.normals);
        parked.restore();  // (also done, on an error, by its destructor)
    } else {
        Column<Vec3f> own = std::move(cloud.normals);
        cloud.normals = own.view();
        try {
            r.normals = r.outliers.spacing.empty()
                            ? estimate_normals(cloud, options.normals, neighbours)
                            : estimate_normals(cloud, options.normals, r.outliers.spacing);
        } catch (...) {
            cloud.normals = std::move(own);  // the caller's cloud keeps its normals
            throw;
        }
        const bool unchanged = r.normals.normals.borrowed() &&
                               r.normals.normals.data() == own.data() && !own.empty();
        cloud.normals = unchanged ? std::move(own) : std::move(r.normals.normals);
    }
    neighbours = KnnResult{};  // #P x k lists: not kept through the splat
    detail::release(r.outliers.spacing);
    cloud.scales = std::move(r.normals.scales);
    r.normals.normals.clear();
    r.normals.scales.clear();
}

/// reconstruct(); `consume`: free the cloud after the splat.
/// The stages on the points: outliers > normals and scales > the voxel (chosen when
/// options.splat has none); returns the splat's options with that voxel.
SplatOptions point_stages(PipelineResult& r, PointCloud& cloud, const PipelineOptions& options,
                          const StageCallback& on_stage) {
    KnnResult neighbours;  // the outlier stage's, reused by a normal estimation
    if (options.outliers.enabled) {
        StageClock clock(r.timings, on_stage, "outliers");
        // Its lists are kept (64 bytes a point) only for a normal estimation to reuse; the
        // kNN scale alone it hands over without them.
        OutlierHandOver hand_over;
        hand_over.lists = normals_need_neighbours(cloud, options.normals);
        if (!hand_over.lists && scales_need_neighbours(cloud, options.normals)) {
            hand_over.spacing_k = options.normals.k;
        }
        r.outliers = remove_outliers(std::move(cloud), options.outliers, hand_over);
        cloud = std::move(r.outliers.cloud);
        r.outliers.cloud = PointCloud{};
        if (cloud.empty()) throw InvalidArgument("reconstruct: every point was an outlier");
        if (hand_over.lists) {
            const int k = std::min<int>(options.normals.k, int(cloud.size()) - 1);
            neighbours = std::move(r.outliers.neighbours)
                             .subset(r.outliers.removed, cloud.positions, k);
        }
        r.outliers.neighbours = KnnResult{};
    }
    {
        StageClock clock(r.timings, on_stage, "normals");
        normal_stage(r, cloud, options, neighbours);
    }
    SplatOptions splat_options = options.splat;
    if (splat_options.voxel_size == 0.0) {
        r.spacing = sample_spacing(r);
        splat_options.voxel_size = choose_voxel_size(cloud, r.spacing, options);
        r.voxel_chosen = true;
    }
    r.voxel_size = splat_options.voxel_size;
    if (!(bounding_box(cloud.positions).diagonal() > 0.0)) {
        // A single oriented sample would give a disc the size of its kernel: not a surface.
        throw NumericalError("reconstruct: all " + std::to_string(cloud.size()) +
                             " points coincide; no surface can be reconstructed");
    }
    return splat_options;
}

PipelineResult reconstruct_cloud(PointCloud& cloud, bool consume, const PipelineOptions& options,
                                 const StageCallback& on_stage, const VolumeCallback& on_volume) {
    options.validate();
    if (cloud.empty()) throw InvalidArgument("reconstruct: the point cloud is empty");
    if (options.texture.enabled && cloud.colors.size() != cloud.size()) {
        throw InvalidArgument("texture: the input points have no colours to make textures from");
    }
    consume &= !options.texture.enabled;  // the texture stage reads the points' colours
    PipelineResult r;
    in_arena(options.threads, [&] {
        const SplatOptions splat_options = point_stages(r, cloud, options, on_stage);
        if (options.tile != 0 || !splat_untiled(r, cloud, splat_options, options, on_stage)) {
            PipelineOptions tiled = options;
            if (tiled.tile == 0) tiled.tile = detail::kAutoTile;  // over the budget
            tiled_stages(r, cloud, consume, splat_options, tiled, on_stage, on_volume);
            texture_stage(r, cloud, options, on_stage);
            return;
        }
        // The trims' gap test allows the random gaps of the sample: it needs its spacing, which
        // the volume carries (also in its file) for the closing and the mesher.
        if (const double h = sample_spacing(r); h > 0.0) {
            r.volume.metadata["sample_spacing"] = detail::format_number(h);  // round-trips
        }
        if (consume) cloud = PointCloud{};
        mesh_stages(r, options, on_stage, on_volume);
        texture_stage(r, cloud, options, on_stage);
    });
    if (r.mesh.faces.empty()) {
        log_warning("reconstruct: the surface is empty (no valid cell crosses zero)");
    }
    return r;
}

}  // namespace

PipelineResult reconstruct(PointCloud& cloud, const PipelineOptions& options,
                           const StageCallback& on_stage, const VolumeCallback& on_volume) {
    return reconstruct_cloud(cloud, false, options, on_stage, on_volume);
}

PipelineResult reconstruct(PointCloud&& cloud, const PipelineOptions& options,
                           const StageCallback& on_stage, const VolumeCallback& on_volume) {
    return reconstruct_cloud(cloud, true, options, on_stage, on_volume);
}

namespace detail {

namespace {
void write_outputs(RunResult& out, const PipelineOptions& options, const std::string& input,
                   StagedOutputs& staged, std::vector<StageTiming>& timings,
                   const StageCallback& on_stage);
}  // namespace

RunResult run_to_files(const std::string& input, const std::string& output,
                       const PipelineOptions& options, const StageCallback& on_stage,
                       const RunCompute& compute) {
    options.validate();
    RunResult out;
    out.mesh_path = output.empty() ? basename_stem(input) + ".recon.ply" : output;
    const std::string ext = file_extension(out.mesh_path);
    if (ext != "ply" && ext != "obj") {
        throw InvalidArgument("output '" + out.mesh_path + "': unknown mesh extension (use .ply or .obj)");
    }
    if (same_file(input, out.mesh_path)) {
        throw InvalidArgument("output '" + out.mesh_path + "' is the input file; refusing to overwrite it");
    }
    // A tiled run holds no tile's volume past its tile: no stage volume to write.
    const bool vdb = options.write_vdb && options.tile == 0;
    if (vdb) {
        out.vdb_path = stage_volume_path(out.mesh_path, "splat");
        if (options.close.enabled() || options.watertight) {
            out.closed_vdb_path = stage_volume_path(out.mesh_path, "closed");
        }
    }
    if (options.texture.enabled) {
        if (ext != "obj") {
            throw InvalidArgument("output '" + out.mesh_path + "': a textured mesh is an OBJ with "
                                  "a material file and an atlas; name the output .obj");
        }
        out.material_path = texture_mtl_path(out.mesh_path);
        out.texture_path = texture_png_path(out.mesh_path);
        for (const std::string& p : {out.material_path, out.texture_path}) {
            if (same_file(input, p) || p == options.preview_path) {
                throw InvalidArgument("output '" + p + "' (the texture's) is the input or the "
                                      "preview; refusing to overwrite it");
            }
            detail::check_writable(p);
        }
    }
    // Fail before the work, not after it.
    detail::check_writable(out.mesh_path);
    if (!out.vdb_path.empty()) detail::check_writable(out.vdb_path);
    if (!out.closed_vdb_path.empty()) detail::check_writable(out.closed_vdb_path);
    if (!options.preview_path.empty()) {
        check_image_path(options.preview_path);
        detail::check_writable(options.preview_path);
    }

    // Every output is written under a temporary name and renamed into place only when the
    // whole run has succeeded: a failure at any stage leaves earlier outputs untouched.
    detail::StagedOutputs staged;
    std::vector<StageTiming> timings;
    // TBB sets itself up at a process's first parallel loop: it loads its allocator library,
    // looks for a resource manager and starts the worker threads (2-3 ms on the 2-core VM). Done
    // here, that start-up is not charged to the first stage's work.
    tbb::parallel_for(0, 2, [](int) {});
    // The volumes are written while the stages after the mesh run (mesh_stages).
    double vdb_seconds = 0.0;
    std::mutex vdb_mutex;  // the two volumes may be written at the same time
    VolumeCallback write_vdb;
    std::string vdb_temp, closed_vdb_temp;
    if (vdb) {
        vdb_temp = staged.stage(out.vdb_path);
        if (!out.closed_vdb_path.empty()) closed_vdb_temp = staged.stage(out.closed_vdb_path);
        write_vdb = [&](const std::string& stage, const Volume& v) {
            const auto start = std::chrono::steady_clock::now();
            const std::size_t bytes =
                write_volume(stage == "closed" ? closed_vdb_temp : vdb_temp, v);
            const double s =
                std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
            std::lock_guard<std::mutex> lock(vdb_mutex);
            vdb_seconds += s;
            out.vdb_grid_bytes += bytes;
        };
    }
    // Errors of the computing stages name the input they are about ("scan.ply: splat: ...").
    try {
        out.result = compute(out, timings, write_vdb);
        if (out.result.tile != 0) {  // tiled itself: no stage volume was whole
            out.vdb_path.clear();
            out.closed_vdb_path.clear();
        }
        if (out.result.mesh.faces.empty()) {
            std::ostringstream s;
            s << "no surface: no valid cell crosses zero at voxel " << out.result.voxel_size
              << ". Hint: a larger --voxel, or more data";
            throw NumericalError(s.str());
        }
    } catch (const IoError& e) {
        const std::string named = staged.final_names(e.what());
        if (named != e.what()) throw IoError(named);  // writing a .vdb file: it names that
        detail::rethrow_naming(input, e);
    } catch (const Error& e) {
        detail::rethrow_naming(input, e);
    } catch (const std::bad_alloc&) {
        throw NumericalError(input + ": out of memory. Hint: a larger --voxel, or a smaller "
                                     "--max-memory so that the estimate refuses such runs");
    } catch (const std::exception& e) {  // OpenVDB's and the standard library's
        throw NumericalError(input + ": " + e.what());
    }
    timings.insert(timings.end(), out.result.timings.begin(), out.result.timings.end());
    try {
        write_outputs(out, options, input, staged, timings, on_stage);
    } catch (const IoError& e) {
        throw IoError(staged.final_names(e.what()));
    }
    if (vdb) timings.push_back({"vdb (in the background)", vdb_seconds, peak_rss_mb()});
    out.result.timings = std::move(timings);
    return out;
}

namespace {

/// The mesh (with its texture) and the preview under their staged names, then all renamed
/// into place.
void write_outputs(RunResult& out, const PipelineOptions& options, const std::string& input,
                   StagedOutputs& staged, std::vector<StageTiming>& timings,
                   const StageCallback& on_stage) {
    {
        StageClock clock(timings, on_stage, "write");
        WriteOptions w = options.write;
        std::ostringstream c;
        c << "vdbrecon " << version() << " from " << input << ", voxel " << out.result.voxel_size;
        w.comments.insert(w.comments.begin(), c.str());
        if (options.texture.enabled) {
            detail::write_textured(staged, out.mesh_path, out.result.mesh, out.result.texture, w);
            if (out.result.texture.empty()) out.texture_path.clear();
        } else {
            const std::string mesh_temp = staged.stage(out.mesh_path);
            in_arena(options.threads, [&] { write_mesh(mesh_temp, out.result.mesh, w); });
        }
    }
    if (!options.preview_path.empty()) {
        StageClock clock(timings, on_stage, "preview");
        write_image(staged.stage(options.preview_path),
                    render_preview(out.result.mesh, options.preview));
    }
    in_arena(options.threads, [&] { staged.commit_all(); });
}

}  // namespace

}  // namespace detail

namespace {

/// A tile job's pieces welded (the "stitch"), then the stages after the mesh, into r.
void stitch_stages(PipelineResult& r, const std::string& dir, std::size_t count,
                   const PieceSource& pieces, const PipelineOptions& options,
                   const StageCallback& on_stage, const VolumeCallback& on_volume) {
    double voxel = 0.0;
    Vec3d origin{0.0, 0.0, 0.0};
    {
        StageClock clock(r.timings, on_stage, "stitch");
        take_tiled(r, detail::finish_tile_job(dir, count, pieces,
                                              detail::tiled_options(options, options.splat, 0.0),
                                              voxel, origin));
    }
    r.voxel_size = voxel;
    tiled_cleanup_stages(r, options, voxel, origin, on_stage, on_volume);
}

/// A tiled run streamed through its input (detail/stream_tiles.h): the tile job in a temporary
/// directory, its tiles one after another (their pieces waiting on disk), then the stitch and
/// the stages after the mesh, as finish_tiles() does. False, with nothing done, when the input
/// cannot be streamed.
bool run_streamed(const std::string& input, const PipelineOptions& options,
                  const StageCallback& on_stage, const VolumeCallback& on_volume, RunResult& out,
                  std::vector<StageTiming>& timings, PipelineResult& r) {
    if (options.tile == 0) return false;
    const detail::ScratchDir dir("tiles: the tile job");
    TileJob job;
    {
        StageClock clock(timings, on_stage, "read and point stages, streamed");
        bool streamed = false;
        in_arena(options.threads, [&] {
            streamed = detail::prepare_streamed(input, dir.path(), options, job);
        });
        if (!streamed) return false;
    }
    out.read = std::move(job.read);
    r = std::move(job.result);
    in_arena(options.threads, [&] {
        detail::Spool pieces("tiles: the tiles' pieces");
        const detail::TiledOptions to = detail::tiled_options(options, options.splat, 0.0);
        {
            StageClock clock(r.timings, on_stage, "tiles");
            for (std::size_t i = 0; i < job.tiles; ++i) {
                pieces.add(detail::run_tile_job(dir.path(), i, to));
            }
            detail::trim_heap();  // what the tiles freed, before the surface is joined
        }
        const PieceSource source = [&](std::size_t i, std::string& b) { return pieces.get(i, b); };
        stitch_stages(r, dir.path(), job.tiles, source, options, on_stage, on_volume);
    });
    return true;
}

/// Refuses options a tile job cannot run with.
void check_tile_job(const PipelineOptions& options) {
    if (options.tile == 0) {
        throw InvalidArgument("prepare_tiles: options.tile is 0; give a tile edge, or -1 (auto)");
    }
    if (options.texture.enabled) {
        throw InvalidArgument("texture: not with tile jobs (the tiles do not keep the points' "
                              "colours); use --tile in one process");
    }
}

/// A tile job of `input` in the job directory: taken as an earlier run prepared it, or
/// prepared now (read, point stages, the samples bucketed by tile) and recorded. `options` are
/// the run's (input_options applied).
TileJob prepare_job(const std::string& input, const detail::JobDir& dir,
                    const PipelineOptions& options) {
    if (std::optional<TileJob> done = dir.prepared()) {
        log_info(dir.path() + ": the tile job was prepared by an earlier run: " +
                 std::to_string(done->tiles) + " tiles; resuming");
        return std::move(*done);
    }
    TileJob job;
    job.dir = dir.path();
    in_arena(options.threads, [&] {
        if (detail::prepare_streamed(input, dir.path(), options, job)) return;
        job.read = read_points(input, options.read);
        PointCloud cloud = std::move(job.read.cloud);
        job.read.cloud = PointCloud{};
        if (cloud.empty()) throw InvalidArgument("reconstruct: the point cloud is empty");
        const SplatOptions splat_options = point_stages(job.result, cloud, options, {});
        job.voxel_size = splat_options.voxel_size;
        const double spacing = sample_spacing(job.result);
        job.tiles = detail::write_tile_job(
            cloud, detail::tiled_options(options, splat_options, spacing), dir.path(), &job.tile);
    });
    dir.save_prepared(job);
    return job;
}

/// The pieces kept in a job directory, read one at a time.
PieceSource piece_files(const std::string& dir) {
    return [dir](std::size_t i, std::string& buffer) {
        const std::string path = detail::piece_path(dir, i);
        struct stat st {};
        if (::stat(path.c_str(), &st) != 0) {
            throw IoError(path + ": tile " + std::to_string(i) + "'s piece is missing");
        }
        buffer = detail::read_file(path);
        return std::string_view(buffer);
    };
}

/// A tiled run in the job directory options.job_dir (detail/job_dir.h): its preparation unless
/// an earlier run finished it, the tiles whose pieces are not there yet, each kept as it is
/// done, then the stitch and the stages after the mesh: the bytes of an uninterrupted run.
PipelineResult run_in_job_dir(const std::string& input, const PipelineOptions& options,
                              const StageCallback& on_stage, const VolumeCallback& on_volume,
                              RunResult& out, std::vector<StageTiming>& timings) {
    check_tile_job(options);
    const detail::JobDir dir(options.job_dir, input, options);
    TileJob job;
    {
        StageClock clock(timings, on_stage, "read and point stages");
        job = prepare_job(input, dir, options);
    }
    out.read = std::move(job.read);
    PipelineResult r = std::move(job.result);
    in_arena(options.threads, [&] {
        const detail::TiledOptions to = detail::tiled_options(options, options.splat, 0.0);
        std::size_t kept = 0;
        {
            StageClock clock(r.timings, on_stage, "tiles");
            for (std::size_t i = 0; i < job.tiles; ++i) {
                if (has_tile_piece(dir.path(), i)) {
                    ++kept;
                    continue;
                }
                save_tile_piece(dir.path(), i, detail::run_tile_job(dir.path(), i, to));
            }
            detail::trim_heap();
        }
        if (kept > 0) {
            log_info(dir.path() + ": " + std::to_string(kept) + " of " + std::to_string(job.tiles) +
                     " tiles' pieces were there from an earlier run");
        }
        stitch_stages(r, dir.path(), job.tiles, piece_files(dir.path()), options, on_stage, on_volume);
    });
    return r;
}

}  // namespace

namespace {

/// Whether `path` is a LAS file (its signature; LAZ too, which the reader then refuses).
bool is_las_file(const std::string& path) {
    char magic[4] = {0, 0, 0, 0};
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) return false;
    const std::size_t got = std::fread(magic, 1, 4, f);
    std::fclose(f);
    return got == 4 && std::memcmp(magic, "LASF", 4) == 0;
}

/// The options a run from the file `input` goes with: a LAS file's estimated normals face up
/// (PDAL's convention) unless a viewpoint, an up direction or OrientRule::mst says otherwise;
/// with `auto_tiled`, a run whose points would take over half the memory budget tiles itself
/// (PipelineOptions::auto_tile), and *auto_tiled says why.
PipelineOptions input_options(const std::string& input, const PipelineOptions& options,
                              std::string* auto_tiled) {
    PipelineOptions o = options;
    const NormalOptions& n = options.normals;
    if (!n.orients_locally() && n.orient == OrientRule::automatic && is_las_file(input)) {
        o.normals.up = Vec3d{0.0, 0.0, 1.0};
        log_info(input + ": a LAS file: estimated normals face up (0,0,1), as PDAL's do; "
                         "--viewpoint, --up or --orient mst to override");
    }
    if (!o.job_dir.empty() && o.tile == 0) {
        o.tile = detail::kAutoTile;
        log_info(input + ": --job-dir: a tiled run (--tile auto)");
    }
    if (auto_tiled && o.tile == 0 && o.auto_tile && o.close.solid_radius == 0) {
        const double need = detail::points_memory_estimate(input, o.normals);
        const double budget = double(memory_budget(o.splat));
        if (need > 0.5 * budget) {
            std::ostringstream s;
            s << "its points need about " << int(need / 1e6) << " MB in memory, over half of "
              << "--max-memory " << int(budget / 1e6) << " MB";
            *auto_tiled = s.str();
            o.tile = detail::kAutoTile;
            log_info(input + ": tiles: " + *auto_tiled +
                     ": the run tiles itself (--tile auto; --tile 0 refuses)");
        }
    }
    return o;
}

}  // namespace

RunResult run(const std::string& input, const std::string& output,
              const PipelineOptions& given, const StageCallback& on_stage) {
    given.validate();
    std::string auto_tiled;
    const PipelineOptions options = input_options(input, given, &auto_tiled);
    auto compute = [&](RunResult& out, std::vector<StageTiming>& timings,
                       const VolumeCallback& write_vdb) {
        if (!options.job_dir.empty()) {
            PipelineResult r = run_in_job_dir(input, options, on_stage, write_vdb, out, timings);
            r.auto_tiled = auto_tiled;
            return r;
        }
        PipelineResult streamed;
        if (run_streamed(input, options, on_stage, write_vdb, out, timings, streamed)) {
            streamed.auto_tiled = auto_tiled;
            return streamed;
        }
        PointCloud cloud;
        {
            StageClock clock(timings, on_stage, "read");
            out.read = read_points(input, options.read);
            cloud = std::move(out.read.cloud);
            out.read.cloud = PointCloud{};
        }
        const std::size_t points = cloud.size();
        PipelineResult r = reconstruct(std::move(cloud), options, on_stage, write_vdb);
        if (r.auto_tiled.empty()) r.auto_tiled = auto_tiled;
        if (r.mesh.faces.empty()) {
            std::ostringstream s;
            s << "no surface: no valid cell crosses zero at voxel " << r.voxel_size << " ("
              << points - r.outliers.statistical - r.outliers.planarity
              << " points). Hint: a larger --voxel, or more points";
            throw NumericalError(s.str());
        }
        return r;
    };
    return detail::run_to_files(input, output, options, on_stage, compute);
}

PipelineResult reconstruct_volume(Volume volume, const PipelineOptions& options,
                                  const StageCallback& on_stage, const VolumeCallback& on_volume) {
    options.validate();
    if (volume.empty()) throw InvalidArgument("reconstruct: the volume is empty");
    if (options.texture.enabled) {
        throw InvalidArgument("texture: needs the input points' colours; a volume has none");
    }
    PipelineResult r;
    r.voxel_size = volume.voxel_size;
    r.volume = std::move(volume);
    in_arena(options.threads, [&] { mesh_stages(r, options, on_stage, on_volume); });
    if (r.mesh.faces.empty()) {
        log_warning("reconstruct: the surface is empty (no valid cell crosses zero)");
    }
    return r;
}

TileJob prepare_tiles(const std::string& input, const std::string& dir,
                      const PipelineOptions& given) {
    given.validate();
    const PipelineOptions options = input_options(input, given, nullptr);
    check_tile_job(options);
    try {
        const detail::JobDir job_dir(dir, input, options);
        return prepare_job(input, job_dir, options);
    } catch (const Error& e) {
        detail::rethrow_naming(input, e);
    }
}

std::string run_tile(const std::string& dir, std::size_t index, const PipelineOptions& options) {
    options.validate();
    return in_arena(options.threads, [&] {
        return detail::run_tile_job(dir, index, detail::tiled_options(options, options.splat, 0.0));
    });
}

void save_tile_piece(const std::string& dir, std::size_t index, const std::string& piece) {
    const std::string path = detail::piece_path(dir, index);
    detail::AtomicFile f(path);
    // Half, then (in the resume tests) a crash, then the rest: a killed write leaves a temporary.
    const std::size_t half = piece.size() / 2;
    bool ok = std::fwrite(piece.data(), 1, half, f.stream()) == half && std::fflush(f.stream()) == 0;
    detail::crash_point("piece", index);
    ok = ok && std::fwrite(piece.data() + half, 1, piece.size() - half, f.stream()) == piece.size() - half;
    if (!ok) throw IoError(path + ": write failed");
    f.commit();
}

bool has_tile_piece(const std::string& dir, std::size_t index) {
    const std::string path = detail::piece_path(dir, index);
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0) return false;
    return detail::is_piece(detail::read_file(path), index);
}

RunResult finish_tiles(const std::string& input, const std::string& output, const std::string& dir,
                       const PipelineOptions& options, const StageCallback& on_stage) {
    return finish_tiles(input, output, dir, detail::tile_job_tiles(dir), piece_files(dir), options,
                        on_stage);
}

RunResult finish_tiles(const std::string& input, const std::string& output, const std::string& dir,
                       const std::vector<std::string>& pieces, const PipelineOptions& options,
                       const StageCallback& on_stage) {
    const PieceSource source = [&](std::size_t i, std::string&) {
        return std::string_view(pieces[i]);
    };
    return finish_tiles(input, output, dir, pieces.size(), source, options, on_stage);
}

RunResult finish_tiles(const std::string& input, const std::string& output, const std::string& dir,
                       std::size_t count, const PieceSource& pieces,
                       const PipelineOptions& options, const StageCallback& on_stage) {
    if (options.texture.enabled) {
        throw InvalidArgument("texture: not with tile jobs (the tiles do not keep the points' "
                              "colours); use --tile in one process");
    }
    PipelineOptions o = options;
    if (o.tile == 0) o.tile = -1;  // a tiled run's outputs: no .vdb
    auto compute = [&](RunResult&, std::vector<StageTiming>&, const VolumeCallback& write_vdb) {
        PipelineResult r;
        in_arena(o.threads, [&] { stitch_stages(r, dir, count, pieces, o, on_stage, write_vdb); });
        return r;
    };
    return detail::run_to_files(input, output, o, on_stage, compute);
}

}  // namespace vdbrecon
