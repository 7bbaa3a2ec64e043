// Tiled reconstruction (see tiles.cpp): splat > close > mesh one tile of the index space at a
// time, from the samples near it, and stitch the tiles' pieces into the surface the whole
// volume gives.
#pragma once

#include <openvdb/openvdb.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "detail/cell_groups.h"
#include "detail/mesh_common.h"
#include "detail/splat_frame.h"
#include "vdbrecon/close.h"
#include "vdbrecon/mesh.h"
#include "vdbrecon/splat.h"
#include "vdbrecon/tiles.h"
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
    int tile = 0;                     ///< the tile edge used, voxels
    int halo = 0;                     ///< voxels of samples around a tile, each side
    double sample_spacing = 0.0;      ///< TiledOptions::sample_spacing (the plan's)
};

/// Tile coordinates (x, y, z).
using TileKey = std::array<int, 3>;

/// A hash of tile (or cell) coordinates.
struct TileKeyHash {
    std::size_t operator()(const TileKey& k) const {
        return std::size_t(k[0]) * 73856093u ^ std::size_t(k[1]) * 19349663u ^
               std::size_t(k[2]) * 83492791u;
    }
};

/// Tiles of n^3 voxels, tile (0, 0, 0) starting at voxel `origin` (a multiple of 8 at the
/// cloud's lowest corner less `reach`: a cloud narrower than n fits one tile), and the halo of
/// samples around each.
struct TileGrid {
    int n = 0;
    std::array<int, 3> origin{0, 0, 0};
    int halo = 0;
    double reach = 0.0;  ///< voxels from a sample's anchor within which faces can lie
    /// The presumming the samples were placed for (SplatOptions::aggregate, aggregate_max_cell).
    double aggregate = 0.0, aggregate_max_cell = 0.0;
};

/// What every tile of a cloud shares: the whole cloud's kernel statistics and the grid.
struct TileSetup {
    KernelFrame frame;
    TileGrid grid;
};

/// The halo and reach of tiles for these kernels and options (n and origin left 0).
TileGrid tile_margins(const KernelFrame& frame, const CloseOptions& close,
                      const SplatOptions& splat);

/// The tile edge for `--tile auto`: the largest multiple of 8 (at least 32) whose tile with its
/// halo should fit the memory budget left beside `beside` bytes held through the tiles.
int auto_tile(std::size_t beside, const SplatOptions& splat, int halo);

/// The tile edge: options.tile rounded up to a multiple of 8, or auto_tile's first guess.
int tile_edge(const TiledOptions& options, std::size_t beside, int halo);

/// Sets g.origin from the cloud's lowest corner (g.reach set).
void place_grid(TileGrid& g, const Vec3f& lowest_point, double voxel);

/// Throws InvalidArgument for options a tiled run refuses (a solid closing, no tile edge) and for
/// 2^32 points or more.
void check_tiled(const TiledOptions& options, std::size_t points);

/// Checks the options and sets the tiles of `cloud` up (kAutoTile: auto_tile's first guess).
TileSetup tile_setup(const PointCloud& cloud, const TiledOptions& options);

/// Point i's kernel centre, index space (as the splat computes it).
inline openvdb::Vec3d kernel_centre(const PointCloud& cloud, std::size_t i, double voxel) {
    const Vec3f& p = cloud.positions[i];
    return {double(p[0]) / voxel, double(p[1]) / voxel, double(p[2]) / voxel};
}

/// Where the tiles place a sample (index space): its kernel centre, or, where the splat
/// presums (SplatOptions::aggregate), the centre of its presumming cell, so that a cell's
/// samples go to the same tiles and each tile presums whole cells into the groups the whole
/// cloud's splat makes. A group's centre lies within slack() voxels of its cell's centre.
class TileAnchors {
  public:
    explicit TileAnchors(const SplatOptions& options);
    openvdb::Vec3d operator()(const PointCloud& cloud, std::size_t i) const;
    double slack() const { return slack_; }

  private:
    SplatOptions options_;
    std::optional<PresumCells> cells_;
    double slack_ = 0.0;
};

/// Whether an anchor (index space) lies within the halo of tile t.
inline bool in_halo(const openvdb::Vec3d& c, const TileKey& t, const TileGrid& g) {
    for (int a = 0; a < 3; ++a) {
        const double lo = g.origin[std::size_t(a)] + double(t[std::size_t(a)]) * g.n - g.halo;
        if (!(c[a] >= lo && c[a] < lo + g.n + 2.0 * g.halo)) return false;
    }
    return true;
}

/// Calls fn(j) for each occupied tile keys[j] (keys sorted) whose samples can lie in tile t's
/// halo.
template <typename Fn>
void for_each_bucket_near(const std::vector<TileKey>& keys, const TileKey& t, const TileGrid& g,
                          Fn&& fn) {
    const int reach = (g.halo + g.n - 1) / g.n;
    for (int dx = -reach; dx <= reach; ++dx) {
        for (int dy = -reach; dy <= reach; ++dy) {
            for (int dz = -reach; dz <= reach; ++dz) {
                const TileKey k{t[0] + dx, t[1] + dy, t[2] + dz};
                const auto it = std::lower_bound(keys.begin(), keys.end(), k);
                if (it != keys.end() && *it == k) fn(std::size_t(it - keys.begin()));
            }
        }
    }
}

/// The tile holding an anchor (index space).
TileKey tile_of(const openvdb::Vec3d& c, const TileGrid& g);

/// Sorts v and drops repeated keys.
void sort_unique(std::vector<TileKey>& v);

/// Appends the tiles other than its own within g.reach voxels of an anchor (tiles_to_visit
/// is those of every sample, and the occupied tiles).
void add_tiles_near(const openvdb::Vec3d& c, const TileGrid& g, std::vector<TileKey>& out);

/// The points of a cloud bucketed by the tile of their anchor.
struct Buckets {
    std::vector<TileKey> keys;         ///< occupied tiles, sorted
    std::vector<std::size_t> begin;    ///< their ranges in `order` (keys.size() + 1)
    std::vector<std::uint32_t> order;  ///< point indices by (tile, index)
};
Buckets bucket_points(const PointCloud& cloud, const TileAnchors& anchors, const TileGrid& g);

/// The tiles to visit, sorted: those within g.reach voxels of a sample's anchor.
std::vector<TileKey> tiles_to_visit(const PointCloud& cloud, const Buckets& b, const TileGrid& g,
                                    const TileAnchors& anchors);

/// Tile t's piece of the surface from the samples in its halo (`part`, in the whole cloud's
/// order): presummed (whole cells: TileAnchors) and splat in the whole cloud's frame, close,
/// mesh, keep the tile's own triangles.
/// Statistics are added to `stats`. Empty when no voxel near the tile is valid.
ClassifiedSurface tile_surface(const PointCloud& part, const TiledOptions& options,
                               const TileSetup& setup, const TileKey& t, TiledResult& stats);

/// The rows `idx` of a cloud, in that order, with every column it has (and its origin).
PointCloud subset(const PointCloud& cloud, const std::vector<std::uint32_t>& idx);

/// Appends a tile's piece to the pieces so far (finish_surface welds them).
void append(ClassifiedSurface& all, ClassifiedSurface&& piece);

/// The mesh of `cloud` (oriented; scales and colours used as by splat()) reconstructed tile by
/// tile: the same faces on the same vertices as splat > close_volume > extract_mesh of the
/// whole cloud, in another order. With `release`, the cloud is emptied once every tile is
/// meshed: welding the pieces does not need it, and its memory then serves the weld. Throws
/// InvalidArgument for a solid closing.
TiledResult tiled_surface(PointCloud& cloud, const TiledOptions& options, bool release = false);

// ---- Tile jobs (tile_jobs.cpp): the same tiles in other processes --------------------------

/// The tiles' options from the pipeline's (pipeline.cpp), at the voxel and sample spacing the
/// point stages gave.
TiledOptions tiled_options(const PipelineOptions& options, const SplatOptions& splat,
                           double spacing);

/// choose_voxel_size for a cloud of this bounding-box diagonal (pipeline.cpp).
double voxel_for(double diag, double spacing, const PipelineOptions& options);

/// What every tile task reads first (<dir>/plan.bin).
struct TilePlan {
    double voxel = 0.0;
    Vec3d origin{0.0, 0.0, 0.0};
    double sample_spacing = 0.0;
    TileSetup setup;
    std::uint64_t points = 0;
    std::vector<TileKey> tiles;    ///< to visit, in order
    std::vector<TileKey> buckets;  ///< occupied, sorted (bucket-<j>.bin)
};

/// Writes the plan, the last file of a job (a job with a plan is whole).
void write_tile_plan(const std::string& dir, const TilePlan& plan);

/// Occupied tile j's bucket file in a job's directory: its tag, then sections of samples (each
/// their rows in the whole cloud, increasing, and their columns), read one after another.
std::string bucket_path(const std::string& dir, std::size_t j);
std::string bucket_tag();
std::string bucket_section(const std::vector<std::uint32_t>& index, const PointCloud& rows);

/// Writes the oriented cloud into `dir` bucketed by tile, with the plan every tile shares
/// (options.tile: an edge, or kAutoTile for auto_tile's guess); returns the number of tiles
/// (and the tile edge in *tile).
std::size_t write_tile_job(const PointCloud& cloud, const TiledOptions& options,
                           const std::string& dir, int* tile = nullptr);

/// Tile `index`'s piece of the surface (bytes), from the job in `dir`: the piece the in-memory
/// run makes of it. The options must give the plan's halo (the same closing).
std::string run_tile_job(const std::string& dir, std::size_t index, const TiledOptions& options);

/// Whether `bytes` are a whole piece of tile `index` (its tag, index and arrays).
bool is_piece(std::string_view bytes, std::size_t index);

/// The number of tiles of the job in `dir` (its plan's).
std::size_t tile_job_tiles(const std::string& dir);

/// Tile `index`'s piece as bytes, with the tile's statistics (the answer of run_tile_job).
std::string piece_bytes(const ClassifiedSurface& piece, std::size_t index,
                        const TiledResult& stats);

/// Pieces 0 .. n - 1 appended in order into one surface, each array sized exactly first (so the
/// surface of a large run takes no more than it holds); their statistics added to `stats`.
/// `what` names the pieces in errors.
ClassifiedSurface join_pieces(std::size_t n, const PieceSource& source, TiledResult& stats,
                              const std::string& what);

/// Every tile's piece (in tile order) welded and finished: the in-memory run's mesh. Sets the
/// job's voxel and origin.
TiledResult finish_tile_job(const std::string& dir, std::size_t count, const PieceSource& pieces,
                            const TiledOptions& options, double& voxel, Vec3d& origin);

}  // namespace vdbrecon::detail
