// A tiled run's job directory kept for resuming (PipelineOptions::job_dir, prepare_tiles()).
//
// Files besides the tile job's own (plan.bin, bucket-<j>.bin; tile_jobs.cpp):
//   manifest.txt   written first: what the job is of (the input's path, size, modification
//                  time and content hash; the options that shape the plan and the pieces). A
//                  directory whose manifest says anything else is refused, never mixed.
//   job.txt        written when the preparation is done (after plan.bin): the job's summary
//                  (tiles, tile edge, voxel, the read's counts), so a resumed run skips it.
//   piece-<i>.bin  tile i's piece, each written under a temporary name and renamed: a file
//                  there is whole (a run killed while writing one leaves only the temporary,
//                  removed when the directory is next opened).
//   lock           held (flock) while a process has the directory open: a second run on it at
//                  the same time is refused; the kernel releases it when the holder dies.
// The options after the stitch (cleanup, holes, decimation, planes, output) may change between
// runs: they run again from the pieces.
#pragma once

#include <cstddef>
#include <optional>
#include <string>

#include "vdbrecon/pipeline.h"
#include "vdbrecon/tiles.h"

namespace vdbrecon::detail {

/// The options that shape a tile job's plan and pieces, one `name value` line each.
std::string job_options_text(const PipelineOptions& options);

class JobDir {
  public:
    /// Opens `dir` (made when missing) for a job of `input` with `options` (as the run uses
    /// them). An empty directory gets a manifest; one with a manifest of another input or other
    /// options, or with files but no manifest, is refused (InvalidArgument naming what differs).
    JobDir(const std::string& dir, const std::string& input, const PipelineOptions& options);
    ~JobDir();
    JobDir(const JobDir&) = delete;
    JobDir& operator=(const JobDir&) = delete;

    const std::string& path() const { return dir_; }
    /// The job's summary when its preparation was finished by an earlier run.
    std::optional<TileJob> prepared() const;
    /// Records a finished preparation (after the plan).
    void save_prepared(const TileJob& job) const;

  private:
    /// Writes the manifest of a new job, or checks an earlier run's against this one's.
    void check_manifest(const std::string& input, const PipelineOptions& options) const;

    std::string dir_;
    int lock_fd_ = -1;
};

/// Tile i's piece file in a job directory.
std::string piece_path(const std::string& dir, std::size_t i);

/// Crash points for the resume tests: when the environment variable VDBRECON_CRASH_AT is
/// `<what>:<i>` (e.g. "piece:3"), the process kills itself (SIGKILL) at that point.
void crash_point(const char* what, std::size_t i);

}  // namespace vdbrecon::detail
