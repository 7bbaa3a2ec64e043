// What a file-to-file run shares between its front ends (run() for point files, fuse() for
// range-image scenes): stage timing, the thread arena, and the output staging around a compute
// step (checks before the work, .vdb files written while the next stage runs, mesh and preview
// written under temporary names and renamed into place only when everything succeeded).
#pragma once

#include <tbb/task_arena.h>

#include <chrono>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "vdbrecon/error.h"
#include "vdbrecon/pipeline.h"

namespace vdbrecon::detail {

/// Rethrows `e` as the same kind of error with "input: " in front, unless it names it already
/// (the readers' errors do).
[[noreturn]] void rethrow_naming(const std::string& input, const Error& e);

/// The process's peak resident memory so far, MB.
double peak_rss_mb();

/// Times a stage from construction to destruction into `timings` (and announces it to cb).
class StageClock {
  public:
    StageClock(std::vector<StageTiming>& timings, const StageCallback& cb, const char* name)
        : timings_(timings), name_(name), start_(std::chrono::steady_clock::now()) {
        if (cb) cb(name);
    }
    ~StageClock() {
        const auto end = std::chrono::steady_clock::now();
        timings_.push_back(
            {name_, std::chrono::duration<double>(end - start_).count(), peak_rss_mb()});
    }
    StageClock(const StageClock&) = delete;
    StageClock& operator=(const StageClock&) = delete;

  private:
    std::vector<StageTiming>& timings_;
    std::string name_;
    std::chrono::steady_clock::time_point start_;
};

/// Runs f in an arena of `threads` worker threads (0 = all cores).
template <typename F>
auto in_arena(int threads, F&& f) {
    tbb::task_arena arena(threads > 0 ? threads : tbb::task_arena::automatic);
    return arena.execute(std::forward<F>(f));
}

/// The compute step of a run: reads its input (recording its stages in `timings`, its read
/// counts in `out.read`) and returns the reconstruction, handing each volume to `write_vdb`.
using RunCompute = std::function<PipelineResult(RunResult& out, std::vector<StageTiming>& timings,
                                                const VolumeCallback& write_vdb)>;

/// A file-to-file run around `compute`: output checks, staging, the mesh, .vdb files and the
/// preview; errors name `input`.
RunResult run_to_files(const std::string& input, const std::string& output,
                       const PipelineOptions& options, const StageCallback& on_stage,
                       const RunCompute& compute);

}  // namespace vdbrecon::detail
