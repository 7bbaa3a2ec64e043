// A tile job prepared from a file streamed through, never held whole (stream_tiles.cpp): the
// point stages (outliers, normals oriented each on its own, the kNN scale, the voxel) run a
// region of the cloud at a time, with a
// halo that makes each point's neighbour lists exact, so that memory is bounded by a region and
// a tile, not by the input, and the job is the one prepare_tiles() writes from the whole cloud.
#pragma once

#include <string>

#include "vdbrecon/pipeline.h"
#include "vdbrecon/tiles.h"

namespace vdbrecon::detail {

/// Why `options` keep a tiled run from streaming its input ("" when they do not): normals to
/// estimate with no viewpoint or up direction (their orientation spans the whole cloud), an
/// approximate neighbour search, a texture (it reads every point's colour), or no tiles.
std::string stream_refusal(const PipelineOptions& options);

/// About the bytes the in-memory point stages would take for the file `input` (from its size
/// and whether it has normals; 0 when it cannot be read).
double points_memory_estimate(const std::string& input, const NormalOptions& options);

/// prepare_tiles() streaming `input` (options as stream_refusal() accepts). Returns false,
/// having written nothing, when the file turns out not to be streamable -- not a PLY, LAS or
/// text file; without a viewpoint or up direction, not a PLY file or points without normals
/// or with a zero one (to estimate); fewer than the outlier rules' neighbours -- and the caller
/// then reads it whole. Throws as prepare_tiles().
bool prepare_streamed(const std::string& input, const std::string& dir,
                      const PipelineOptions& options, TileJob& job);

}  // namespace vdbrecon::detail
