// Tiled reconstruction (see tiles.cpp): splat > close > mesh one tile of the index space at a
// time, from the samples near it, and stitch the tiles' pieces into the surface the whole
// volume gives.
#pragma once

#include <cstddef>

#include "vdbrecon/close.h"
#include "vdbrecon/mesh.h"
#include "vdbrecon/splat.h"
#include "vdbrecon/types.h"

namespace vdbrecon::detail {

/// TiledOptions::tile for an edge chosen from the memory budget (PipelineOptions::tile).
constexpr int kAutoTile = -1;

struct TiledOptions {
    SplatOptions splat;  ///< voxel_size > 0
    CloseOptions close;  ///< hole closing only: a solid closing needs the whole surface
    MeshOptions mesh;
    int tile = 0;  ///< tile edge, voxels (> 0; rounded up to a multiple of 8), or kAutoTile
    double sample_spacing = 0.0;  ///< the whole cloud's, world units (the trims' gap test)
};

struct TiledResult {
    MeshResult mesh;
    SplatResult splat;  ///< statistics only (no volume): sums over the tiles, the cloud's sigmas
    CloseResult close;  ///< statistics only: sums over the tiles
    std::size_t tiles = 0;            ///< tiles that held samples near them
    std::size_t max_tile_points = 0;  ///< samples of the largest tile (its own and its halo)
    std::size_t max_tile_bytes = 0;   ///< memory of the largest tile's grids
    int tile = 0;                     ///< the tile edge used, voxels
    int halo = 0;                     ///< voxels of samples around a tile, each side
};

/// The mesh of `cloud` (oriented; scales and colours used as by splat()) reconstructed tile by
/// tile: the same faces on the same vertices as splat > close_volume > extract_mesh of the
/// whole cloud, in another order. Throws InvalidArgument for a solid closing.
TiledResult tiled_surface(const PointCloud& cloud, const TiledOptions& options);

}  // namespace vdbrecon::detail
