// A tiled run (PipelineOptions::tile) cut in three, so that its tiles can run in other
// processes or on other machines sharing a directory (vdbrecon.distributed runs them as Dask
// tasks):
//
//   1. prepare_tiles(): read, outliers, normals, voxel, then the oriented samples bucketed by
//      tile into files in `dir`, with the plan every tile shares;
//   2. run_tile(): one tile's piece of the surface, as bytes, from the files around it -- any
//      process, in any order, as often as needed (a tile's piece depends on nothing else);
//   3. finish_tiles(): the pieces in tile order welded, finished, cleaned and written: the bytes
//      `vdbrecon INPUT -o OUTPUT --tile N` writes with the same options.
#pragma once

#include <cstddef>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "vdbrecon/pipeline.h"

namespace vdbrecon {

/// What prepare_tiles() did.
struct TileJob {
    std::string dir;
    std::size_t tiles = 0;     ///< tiles to run: run_tile(dir, 0 .. tiles - 1)
    int tile = 0;              ///< the tile edge, voxels
    double voxel_size = 0.0;   ///< the voxel used, world units
    PipelineResult result;     ///< statistics of the stages on the points (no mesh)
    ReadResult read;           ///< counts of the read (no cloud)
};

/// Reads `input` and runs the point stages, then writes the job into the directory `dir`
/// (made when missing). options.tile: the tile edge in voxels, or -1 (auto: the first guess of
/// the in-memory run, which there halves the edge while a tile is over --max-memory; here a
/// tile over it fails). A directory an earlier call prepared for the same input and options is
/// taken as it is (the job resumes); one of another input or other options is refused, and so
/// is one that holds other files. Throws as run() does.
TileJob prepare_tiles(const std::string& input, const std::string& dir,
                      const PipelineOptions& options);

/// Tile `index`'s piece of the surface. The options must close holes as those given to
/// prepare_tiles() did (the closing radius sets the halo).
std::string run_tile(const std::string& dir, std::size_t index, const PipelineOptions& options);

/// Keeps tile `index`'s piece in the job directory (written under a temporary name and renamed:
/// a piece there is whole), where has_tile_piece() and finish_tiles() find it.
void save_tile_piece(const std::string& dir, std::size_t index, const std::string& piece);

/// Whether the job directory holds tile `index`'s piece (a whole one, of that tile).
bool has_tile_piece(const std::string& dir, std::size_t index);

/// finish_tiles() of the pieces kept in the job directory (save_tile_piece); a missing one is
/// an error naming it.
RunResult finish_tiles(const std::string& input, const std::string& output, const std::string& dir,
                       const PipelineOptions& options, const StageCallback& on_stage = {});

/// Writes the mesh of the pieces (every tile's, in tile order) as run() does, naming `input` in
/// its header and errors.
RunResult finish_tiles(const std::string& input, const std::string& output, const std::string& dir,
                       const std::vector<std::string>& pieces, const PipelineOptions& options,
                       const StageCallback& on_stage = {});

/// Piece i's bytes (run_tile's answer): a view of them, or read into `buffer` (from a file,
/// say) and a view of that. Read one at a time, twice each (sizes, then contents).
using PieceSource = std::function<std::string_view(std::size_t i, std::string& buffer)>;

/// The same from `count` pieces that need not all be in memory at once.
RunResult finish_tiles(const std::string& input, const std::string& output, const std::string& dir,
                       std::size_t count, const PieceSource& pieces,
                       const PipelineOptions& options, const StageCallback& on_stage = {});

}  // namespace vdbrecon
