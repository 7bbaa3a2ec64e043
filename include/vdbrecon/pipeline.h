// The whole reconstruction: read > normals/scale > splat > mesh > clean > write.
//
// PipelineOptions nests one options struct per stage; the CLI and the Python module fill the
// same struct, so both offer the same knobs with the same names and defaults.
#pragma once

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "vdbrecon/clean.h"
#include "vdbrecon/io.h"
#include "vdbrecon/mesh.h"
#include "vdbrecon/normals.h"
#include "vdbrecon/splat.h"
#include "vdbrecon/types.h"
#include "vdbrecon/volume.h"

namespace vdbrecon {

/// Library version, "major.minor.patch".
const char* version();

struct PipelineOptions {
    ReadOptions read;
    NormalOptions normals;
    SplatOptions splat;  ///< splat.voxel_size == 0: chosen from the point spacing
    MeshOptions mesh;
    CleanOptions clean;
    WriteOptions write;
    /// Worker threads; 0 = all cores. The output does not depend on it.
    int threads = 0;
    /// Write <out>.splat.vdb next to the mesh.
    bool write_vdb = true;
    /// Automatic voxel = auto_voxel_factor * median per-point scale (dimensionless).
    double auto_voxel_factor = 1.0;
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
    Volume volume;
    NormalResult normals;       ///< normals/scales moved into the cloud; counts kept
    SplatResult splat;          ///< volume moved into `volume`; statistics kept
    MeshResult mesh_stats;      ///< mesh moved out; statistics kept
    CleanResult clean_stats;    ///< mesh moved into `mesh`; statistics kept
    double voxel_size = 0.0;    ///< the voxel used, world units
    bool voxel_chosen = false;  ///< true when it was picked automatically
    std::vector<StageTiming> timings;
};

/// Progress callback: stage name, called when a stage starts.
using StageCallback = std::function<void(const std::string& stage)>;

/// Called with the splatted volume; runs concurrently with mesh extraction (on the same worker
/// threads), e.g. to write the volume to disk while the mesh is being built.
using VolumeCallback = std::function<void(const Volume& volume)>;

/// Runs normals > splat > mesh > clean on an in-memory cloud (normals and scales are filled in).
/// Exceptions from `on_volume` propagate once meshing has finished.
PipelineResult reconstruct(PointCloud& cloud, const PipelineOptions& options,
                           const StageCallback& on_stage = {},
                           const VolumeCallback& on_volume = {});

/// Output paths of a file-to-file run.
struct RunResult {
    PipelineResult result;
    ReadResult read;            ///< cloud moved into the pipeline; counts kept
    std::string mesh_path;
    std::string vdb_path;       ///< empty when no .vdb was written
};

/// Reads `input`, reconstructs and writes `output` (.ply or .obj) and <output stem>.splat.vdb.
/// An empty `output` means <input stem>.recon.ply beside the input.
RunResult run(const std::string& input, const std::string& output, const PipelineOptions& options,
              const StageCallback& on_stage = {});

/// The automatic voxel size for a cloud whose per-point scales have a median `median_scale`.
double choose_voxel_size(const PointCloud& cloud, double median_scale,
                         const PipelineOptions& options);

/// Path of a stage's volume file: "out/scan.ply" + "splat" -> "out/scan.splat.vdb".
std::string stage_volume_path(const std::string& mesh_path, const std::string& stage);

}  // namespace vdbrecon
