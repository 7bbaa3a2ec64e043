// The whole reconstruction: read > outliers > normals/scale > splat > close > mesh > clean > write.
//
// PipelineOptions nests one options struct per stage; the CLI and the Python module fill the
// same struct, so both offer the same knobs with the same names and defaults.
#pragma once

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "vdbrecon/clean.h"
#include "vdbrecon/close.h"
#include "vdbrecon/decimate.h"
#include "vdbrecon/holes.h"
#include "vdbrecon/io.h"
#include "vdbrecon/mesh.h"
#include "vdbrecon/normals.h"
#include "vdbrecon/outliers.h"
#include "vdbrecon/planes.h"
#include "vdbrecon/preview.h"
#include "vdbrecon/texture.h"
#include "vdbrecon/splat.h"
#include "vdbrecon/types.h"
#include "vdbrecon/volume.h"

namespace vdbrecon {

/// Library version, "major.minor.patch".
const char* version();

/// Whether a tiled run from a file streams its input: reads it a chunk at a time and runs the
/// stages on the points a region at a time, so that its memory is bounded by a region and a
/// tile, not by the input. The same mesh either way; streaming takes about twice as long in
/// the point stages. A PLY file whose points all have normals streams; so does a PLY, LAS or
/// text file whose normals are estimated when normals.viewpoint or normals.up orients each on
/// its own (without them the orientation spans the cloud, which is then read whole).
enum class StreamMode {
    automatic,  ///< when the points in memory would take more than half of splat.max_memory
    always,     ///< whenever the input allows it
    never,
};

struct PipelineOptions {
    ReadOptions read;
    OutlierOptions outliers;  ///< on by default
    NormalOptions normals;
    SplatOptions splat;  ///< splat.voxel_size == 0: chosen from the point spacing
    CloseOptions close;  ///< off by default
    MeshOptions mesh;
    CleanOptions clean;
    WriteOptions write;
    /// Worker threads; 0 = all cores. The output does not depend on it.
    int threads = 0;
    /// run() only: write a shaded picture of the mesh here (.png, or .exr with a depth
    /// channel); empty = none.
    std::string preview_path;
    PreviewOptions preview;
    /// Fill the mesh's boundary loops of at most this many edges (Liepa 2003, see holes.h);
    /// 0 = none.
    std::size_t fill_holes = 0;
    /// A closed, manifold, one-piece mesh: only the largest piece is kept and every boundary
    /// loop is filled (whatever fill_holes says); the result's closed_volume (run():
    /// <out>.closed.vdb) is the signed distance field of that mesh.
    bool watertight = false;
    /// Planar regions with crisp edges, re-triangulated with few faces (planes.h); off by
    /// default. Runs after the hole filling, before the decimation.
    PlaneOptions planes;
    /// QEM decimation of the final mesh (decimate.h); off while ratio is 1 and max_error 0.
    DecimateOptions decimate;
    /// Textures for the planar regions from the points' colours (texture.h), after the
    /// decimation; off by default. Needs `planes` enabled and points with colours; run() then
    /// writes an OBJ with <out>.mtl and <out>.texture.png. Not for volumes or tile jobs.
    TextureOptions texture;
    /// Write <out>.splat.vdb (and <out>.closed.vdb when closing) next to the mesh (not with
    /// `tile`: no stage volume is ever whole then).
    bool write_vdb = true;
    /// Splat, close and mesh tile by tile: cubes of this many voxels (rounded up to a multiple
    /// of 8), each from the samples within a halo around it, so that only one tile's grids are
    /// in memory at a time; 0 = the whole volume at once. The mesh has the same faces on the
    /// same vertices as the untiled one (in another order), for any tile size and thread count.
    /// -1 = automatic: the largest edge whose tile should fit splat.max_memory beside the
    /// cloud. Not with a solid closing (close.solid_radius), which needs the whole surface.
    int tile = 0;
    /// With tile == 0: tile anyway (as tile = -1 would) when the run would not fit
    /// splat.max_memory: decided before the point stages from the file's size where run()
    /// reads a file, else when the splat's estimate exceeds the budget. The same mesh; no stage
    /// volume is written then. false: refuse such a run (the CLI's --tile 0).
    bool auto_tile = true;
    /// Tiled runs from a file (run(), prepare_tiles()): stream the input (see StreamMode).
    StreamMode stream = StreamMode::automatic;
    /// run() from a file: keep the tiled run's job directory here (made when missing), so that
    /// the same run again resumes from the tiles it finished, with the same output bytes; a
    /// directory of another input or other options is refused. Implies tiling (tile 0 becomes
    /// automatic). Empty: a temporary job directory, when one is needed. See detail/job_dir.h.
    std::string job_dir;
    /// Return the splatted (and closed) volumes in the result. false frees them as soon as the
    /// mesh is made and the volume callback has returned, which lowers the peak memory of the
    /// clean stage by the grids' size; the CLI, which has written them to .vdb files by then,
    /// sets it false.
    bool keep_volumes = true;
    /// Automatic voxel = auto_voxel_factor * the median sample spacing (dimensionless). The
    /// spacing is measured from the density of each point's nearest neighbours (the outlier
    /// stage's k, else the normal stage's; see median_density_spacing in knn.h), so a random
    /// subsample of a scan gets the voxel its density calls for, as a scanner's raster does.
    /// When no stage searched neighbours (no outlier removal, and the file has normals and
    /// scales) the median per-point scale stands in for the spacing. 1.4 gives the Stanford
    /// bunny scans 0.53 mm, near the 0.5 mm suggested for them.
    double auto_voxel_factor = 1.4;
    /// The automatic voxel is never finer than the bounding-box diagonal / this (count).
    double auto_voxel_max_cells = 1024.0;

    /// Validates every nested struct; throws InvalidArgument naming the field.
    void validate() const;
};

/// Wall time of one stage, and the process's peak resident memory when it ended.
struct StageTiming {
    std::string stage;
    double seconds = 0.0;
    double peak_rss_mb = 0.0;  ///< peak so far (monotonic): the stage that raises it used it
};

struct PipelineResult {
    Mesh mesh;
    Volume volume;              ///< the splatted volume (empty unless options.keep_volumes)
    Volume closed_volume;       ///< the closed volume that was meshed (empty without closing
                                ///< or without options.keep_volumes)
    OutlierResult outliers;     ///< kept points moved into the cloud; counts and flags kept
    NormalResult normals;       ///< normals/scales moved into the cloud; counts kept
    SplatResult splat;          ///< volume moved into `volume`; statistics kept
    CloseResult close;          ///< volume moved into `closed_volume`; statistics kept
    MeshResult mesh_stats;      ///< mesh moved out; statistics kept
    CleanResult clean_stats;    ///< mesh moved into `mesh`; statistics kept
    HoleFillResult holes;       ///< mesh moved into `mesh`; statistics kept
    PlaneResult planes;         ///< mesh moved into `mesh`; planes and statistics kept
    DecimateResult decimation;  ///< mesh moved into `mesh`; statistics kept (none: 0 faces)
    TextureAtlas texture;       ///< the planar regions' atlas (empty without options.texture)
    double voxel_size = 0.0;    ///< the voxel used, world units
    bool voxel_chosen = false;  ///< true when it was picked automatically
    double spacing = 0.0;       ///< the median sample spacing it was picked from, world units
    int tile = 0;               ///< tiled runs: the tile edge used, voxels (0: untiled)
    /// Why the run tiled itself (PipelineOptions::auto_tile); empty when it did not.
    std::string auto_tiled;
    int tile_halo = 0;          ///< ... the halo of samples around each tile, voxels
    std::size_t tiles = 0;      ///< ... tiles that had samples near them
    std::size_t max_tile_points = 0;  ///< ... samples of the largest tile with its halo
    /// Tiled runs that streamed their input (never held whole): the regions the point stages
    /// ran on one at a time (0: the cloud was in memory), and the points of the largest with
    /// its halo.
    std::size_t stream_units = 0;
    std::size_t stream_largest = 0;
    std::vector<StageTiming> timings;
};

/// Progress callback: stage name, called when a stage starts.
using StageCallback = std::function<void(const std::string& stage)>;

/// Called with each stage's volume ("splat", then "closed" when closing) once the mesh is made;
/// runs concurrently with the stages after it (on the same worker threads), e.g. to write the
/// volume to disk meanwhile.
using VolumeCallback = std::function<void(const std::string& stage, const Volume& volume)>;

/// Runs outliers > normals > splat > close > mesh > clean on an in-memory cloud (outliers are
/// removed from it, normals and scales filled in). Exceptions from `on_volume` propagate once
/// the stages after the mesh have finished.
PipelineResult reconstruct(PointCloud& cloud, const PipelineOptions& options,
                           const StageCallback& on_stage = {},
                           const VolumeCallback& on_volume = {});

/// The same for a cloud the caller gives up: its memory is freed once the splat is done, so it
/// does not add to the peak of the later stages.
PipelineResult reconstruct(PointCloud&& cloud, const PipelineOptions& options,
                           const StageCallback& on_stage = {},
                           const VolumeCallback& on_volume = {});

/// The stages after the splat (close > mesh > clean > fill holes) on a volume made elsewhere:
/// a SplatAccumulator's (range-image fusion), a .vdb file's. Throws InvalidArgument for an
/// empty volume.
PipelineResult reconstruct_volume(Volume volume, const PipelineOptions& options,
                                  const StageCallback& on_stage = {},
                                  const VolumeCallback& on_volume = {});

/// Output paths of a file-to-file run.
struct RunResult {
    PipelineResult result;
    ReadResult read;            ///< cloud moved into the pipeline; counts kept
    std::string mesh_path;
    std::string vdb_path;       ///< <out>.splat.vdb; empty when no .vdb was written
    std::string closed_vdb_path;  ///< <out>.closed.vdb; empty without closing or .vdb output
    std::string material_path;    ///< <out>.mtl with a texture, else empty
    std::string texture_path;     ///< <out>.texture.png with a texture that has regions, else empty
    /// Memory of the grids written to the .vdb files (write_volume's sum), bytes; 0 without them.
    std::size_t vdb_grid_bytes = 0;
};

/// Reads `input`, reconstructs and writes `output` (.ply or .obj), <output stem>.splat.vdb and,
/// when closing, <output stem>.closed.vdb.
/// An empty `output` means <input stem>.recon.ply beside the input.
RunResult run(const std::string& input, const std::string& output, const PipelineOptions& options,
              const StageCallback& on_stage = {});

/// The automatic voxel size for a cloud whose median sample spacing is `spacing` (world units;
/// 0 when unknown: then the bounding box decides).
double choose_voxel_size(const PointCloud& cloud, double spacing, const PipelineOptions& options);

/// Path of a stage's volume file: "out/scan.ply" + "splat" -> "out/scan.splat.vdb".
std::string stage_volume_path(const std::string& mesh_path, const std::string& stage);

}  // namespace vdbrecon
