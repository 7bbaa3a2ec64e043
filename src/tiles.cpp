// Tiled reconstruction (see detail/tiles.h).
//
// Splatting is local: a voxel's sums are those of the kernels that reach it, each added in
// increasing point order (splat.cpp), so the splat of a subset of the cloud in the same order
// gives every voxel all of whose kernels are in the subset exactly the whole cloud's value, bit
// for bit, once the few statistics the splat takes from all kernels (the median sigma of the
// area weights, the band's half width, the crease test's reach: detail::KernelFrame) are the
// whole cloud's. The crease model, the hole closing and the meshers read a bounded neighbourhood
// of a voxel. So a tile of N^3 voxels is exact given the samples within a halo of it:
//
//   exact margin  : what a face in the tile reads around it -- the mesher's cells, stencils and
//                   support test (4 voxels), and a hole closing of radius R (dilation and
//                   erosion 2R, the slab R, the layers that extend the field up to 2R, + 4)
//   sample margin : what a voxel of that zone is summed from -- kernels up to max_r away, and,
//                   for the crease model, the samples and sample cells (4 voxels) that reach or
//                   surround its leaf (8 voxels) within the crease test's reach
//
// Each tile keeps the triangles whose centroid lies in it (each triangle has one owner, computed
// from its points' coordinates, which both tiles beside a tile face compute alike) and
// classifies their points (finish_mesh's first half). finish_surface welds points at equal
// coordinates (bit for bit), as it does for an untiled surface, which joins the pieces. The trims (which follow connected regions of the whole surface), the compaction,
// the normals and colours then run on the welded surface as on the untiled one
// (detail::finish_surface): the result has the untiled mesh's faces on its vertices.
#include "detail/tiles.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <type_traits>
#include <unordered_map>

#include "detail/io_common.h"
#include "detail/mesh_common.h"
#include "detail/mesh_graph.h"
#include "detail/release.h"
#include "detail/splat_frame.h"
#include "detail/spool.h"
#include "vdbrecon/error.h"

namespace vdbrecon::detail {
namespace {

int round_up(int v, int m) { return (v + m - 1) / m * m; }

/// Voxels around a tile whose values its faces read (see above).
int exact_margin(const CloseOptions& close) {
    return 4 + (close.hole_radius > 0 ? 6 * close.hole_radius + 4 : 0);
}

/// Voxels around the exact zone whose samples its voxels are summed from (see above).
int sample_margin(const KernelFrame& frame) {
    const int reach = int(std::ceil(double(frame.max_r)));
    const int cells = 4 * (int(std::ceil(double(frame.r_typical) / 4.0)) + 1);
    return 8 + std::max(reach, cells) + 1;
}


}  // namespace

TileKey tile_of(const openvdb::Vec3d& c, const TileGrid& g) {
    TileKey k;
    for (int a = 0; a < 3; ++a) {
        k[std::size_t(a)] = int(std::floor((c[a] - g.origin[std::size_t(a)]) / g.n));
    }
    return k;
}

void sort_unique(std::vector<TileKey>& v) {
    std::sort(v.begin(), v.end());
    v.erase(std::unique(v.begin(), v.end()), v.end());
}

void add_tiles_near(const openvdb::Vec3d& c, const TileGrid& g, std::vector<TileKey>& out) {
    const TileKey lo = tile_of(c - openvdb::Vec3d(g.reach), g);
    const TileKey hi = tile_of(c + openvdb::Vec3d(g.reach), g);
    if (lo == hi) return;  // its own tile, an occupied one
    for (int x = lo[0]; x <= hi[0]; ++x) {
        for (int y = lo[1]; y <= hi[1]; ++y) {
            for (int z = lo[2]; z <= hi[2]; ++z) out.push_back({x, y, z});
        }
    }
}

TileAnchors::TileAnchors(const SplatOptions& options) : options_(options) {
    if (options.aggregate > 0.0) {
        cells_ = PresumCells::of_splat(options);
        slack_ = cells_->max_half_diagonal() / options.voxel_size;
    }
}

openvdb::Vec3d TileAnchors::operator()(const PointCloud& cloud, std::size_t i) const {
    const double voxel = options_.voxel_size;
    if (!cells_) return kernel_centre(cloud, i, voxel);
    const float scale = cloud.has_scales() ? cloud.scales[i] : 0.0f;
    const int level = cells_->sample_level(options_, scale, kernel_sigma_voxels(options_, scale));
    std::int64_t c[3];
    // A sample beyond the cells' range is splat as it is (aggregate_samples).
    if (!cells_->cell(cloud.positions[i], level, c)) return kernel_centre(cloud, i, voxel);
    return {cells_->centre(c[0], level) / voxel, cells_->centre(c[1], level) / voxel,
            cells_->centre(c[2], level) / voxel};
}

Buckets bucket_points(const PointCloud& cloud, const TileAnchors& anchors, const TileGrid& g) {
    // A counting sort by tile, stable (increasing index within a tile): two passes over the
    // points and a table of the occupied tiles, no key stored per point.
    std::unordered_map<TileKey, std::size_t, TileKeyHash> slot;  // points per tile, then its bucket
    const std::size_t np = cloud.size();
    for (std::size_t i = 0; i < np; ++i) ++slot[tile_of(anchors(cloud, i), g)];
    Buckets b;
    for (const auto& e : slot) b.keys.push_back(e.first);
    std::sort(b.keys.begin(), b.keys.end());
    b.begin.push_back(0);
    for (std::size_t j = 0; j < b.keys.size(); ++j) {
        std::size_t& s = slot[b.keys[j]];
        b.begin.push_back(b.begin.back() + s);
        s = j;
    }
    std::vector<std::size_t> fill(b.begin.begin(), b.begin.end() - 1);
    b.order.resize(np);
    for (std::size_t i = 0; i < np; ++i) {
        const std::size_t j = slot.find(tile_of(anchors(cloud, i), g))->second;
        b.order[fill[j]++] = std::uint32_t(i);
    }
    return b;
}

std::vector<TileKey> tiles_to_visit(const PointCloud& cloud, const Buckets& b, const TileGrid& g,
                                    const TileAnchors& anchors) {
    std::vector<TileKey> out = b.keys;
    const std::size_t flush = 2 * b.keys.size() + (std::size_t(1) << 20);
    for (std::size_t i = 0; i < cloud.size(); ++i) {
        add_tiles_near(anchors(cloud, i), g, out);
        if (out.size() > flush) sort_unique(out);
    }
    sort_unique(out);
    return out;
}

namespace {

/// The points whose anchor lies within `halo` voxels of tile t, in increasing order.
std::vector<std::uint32_t> tile_points(const PointCloud& cloud, const Buckets& b, const TileKey& t,
                                       const TileGrid& g, const TileAnchors& anchors) {
    std::vector<std::uint32_t> idx;
    for_each_bucket_near(b.keys, t, g, [&](std::size_t j) {
        for (std::size_t q = b.begin[j]; q < b.begin[j + 1]; ++q) {
            if (in_halo(anchors(cloud, b.order[q]), t, g)) idx.push_back(b.order[q]);
        }
    });
    std::sort(idx.begin(), idx.end());
    return idx;
}

/// Whether tile t owns the triangle: the tile of its centroid (from the exact sum of its
/// points' coordinates, which every tile that meshes it computes alike).
bool owns(const TileKey& t, const RawSurface& raw, const Triangle& tri, const TileGrid& g) {
    for (int a = 0; a < 3; ++a) {
        const double s = double(raw.points[std::size_t(tri[0])][a]) +
                         double(raw.points[std::size_t(tri[1])][a]) +
                         double(raw.points[std::size_t(tri[2])][a]);
        const double o = 3.0 * g.origin[std::size_t(a)];
        if (int(std::floor((s - o) / (3.0 * g.n))) != t[std::size_t(a)]) return false;
    }
    return true;
}

/// The tile's piece: its own triangles, classified, on the points they use.
ClassifiedSurface tile_piece(const Volume& volume, const MeshOptions& options, RawSurface raw,
                             const TileKey& t, const TileGrid& g) {
    std::size_t kept = 0;
    for (const Triangle& tri : raw.triangles) {
        if (owns(t, raw, tri, g)) raw.triangles[kept++] = tri;
    }
    raw.triangles.resize(kept);
    ClassifiedSurface s = classify_surface(volume, options, std::move(raw));
    // Only the points its triangles use.
    std::size_t used = 0;
    const std::vector<std::int32_t> remap = compact_vertices(s.triangles, s.points.size(), &used);
    ClassifiedSurface out;
    out.dropped_faces = s.dropped_faces;
    out.points.resize(used);
    out.status.resize(used);
    out.grad.resize(used);
    if (!s.colors.empty()) out.colors.resize(used);
    if (!s.weight.empty()) out.weight.resize(used);
    for (std::size_t i = 0; i < s.points.size(); ++i) {
        if (remap[i] < 0) continue;
        const std::size_t j = std::size_t(remap[i]);
        out.points[j] = s.points[i];
        out.status[j] = s.status[i];
        out.grad[j] = s.grad[i];
        if (!s.colors.empty()) out.colors[j] = s.colors[i];
        if (!s.weight.empty()) out.weight[j] = s.weight[i];
    }
    out.triangles = std::move(s.triangles);  // renumbered by compact_vertices
    return out;
}

}  // namespace

PointCloud subset(const PointCloud& cloud, const std::vector<std::uint32_t>& idx) {
    auto pick = [&](const auto& column) {
        using T = std::decay_t<decltype(column[0])>;
        std::vector<T> v;
        if (column.empty()) return v;
        v.reserve(idx.size());
        for (std::uint32_t i : idx) v.push_back(column[i]);
        return v;
    };
    PointCloud s;
    s.positions = pick(cloud.positions);
    s.normals = pick(cloud.normals);
    s.colors = pick(cloud.colors);
    s.scales = pick(cloud.scales);
    s.confidences = pick(cloud.confidences);
    s.origin = cloud.origin;
    return s;
}

void append(ClassifiedSurface& all, ClassifiedSurface&& piece) {
    const auto offset = std::int32_t(all.points.size());
    if (all.points.size() + piece.points.size() > std::size_t(INT32_MAX)) {
        throw NumericalError("tiles: the mesh has more than 2^31 points");
    }
    all.points.insert(all.points.end(), piece.points.begin(), piece.points.end());
    all.status.insert(all.status.end(), piece.status.begin(), piece.status.end());
    all.grad.insert(all.grad.end(), piece.grad.begin(), piece.grad.end());
    all.colors.insert(all.colors.end(), piece.colors.begin(), piece.colors.end());
    all.weight.insert(all.weight.end(), piece.weight.begin(), piece.weight.end());
    for (Triangle t : piece.triangles) {
        for (std::int32_t& v : t) v += offset;
        all.triangles.push_back(t);
    }
    all.dropped_faces += piece.dropped_faces;
}

namespace {

/// The tile edge for `--tile auto`: the largest multiple of 8 (at least 32) whose tile with its
/// halo should fit the memory budget left beside the cloud. A surface crossing a cube of E
/// voxels touches about c (E / 8)^2 of its leaves (c = 1 for a plane through it; 3 allows for
/// a folded surface), each costing SplatOptions::kBytesPerLeaf through the tile's stages.
}  // namespace

int auto_tile(std::size_t beside, const SplatOptions& splat, int halo) {
    const double budget = double(memory_budget(splat)) - 1.5 * double(beside);
    const double leaves = std::max(0.0, budget) / double(SplatOptions::kBytesPerLeaf) / 3.0;
    const double edge = 8.0 * std::sqrt(leaves) - 2.0 * halo;
    return std::max(32, int(std::min(edge, 65536.0)) / 8 * 8);
}

namespace {

bool any_usable(const PointCloud& part) {
    for (std::size_t i = 0; i < part.size(); ++i) {
        const Vec3f& nr = part.normals[i];
        const double len =
            std::sqrt(double(nr[0]) * nr[0] + double(nr[1]) * nr[1] + double(nr[2]) * nr[2]);
        if (kernel_usable(len, part.has_confidences() ? part.confidences[i] : 1.0f)) return true;
    }
    return false;
}

}  // namespace

ClassifiedSurface tile_surface(const PointCloud& part, const TiledOptions& options,
                               const TileSetup& setup, const TileKey& t, TiledResult& stats) {
    if (part.empty() || !any_usable(part)) return {};
    SplatResult s;
    try {
        s = splat_in_frame(presum(part, options.splat), options.splat, setup.frame, &part);
    } catch (const NumericalError&) {
        return {};  // no valid voxel near this tile: no surface in it
    }
    ++stats.tiles;
    stats.max_tile_points = std::max(stats.max_tile_points, part.size());
    stats.splat.active_voxels += s.active_voxels;
    stats.splat.leaves += s.leaves;
    stats.splat.updates += s.updates;
    stats.splat.crease_voxels += s.crease_voxels;
    Volume volume = std::move(s.volume);
    if (options.sample_spacing > 0.0) {
        volume.metadata["sample_spacing"] = format_number(options.sample_spacing);
    }
    if (options.close.enabled()) {
        CloseResult c = close_volume(volume, options.close, options.mesh);
        volume = std::move(c.volume);
        stats.close.supported_voxels += c.supported_voxels;
        stats.close.closed_voxels += c.closed_voxels;
        stats.close.filled_voxels += c.filled_voxels;
    }
    return tile_piece(volume, options.mesh, mesh_raw(volume, options.mesh), t, setup.grid);
}

namespace {

/// Every tile's piece, in tile order, into the spool.
void all_tiles(const PointCloud& cloud, const TiledOptions& options, const TileSetup& setup,
               TiledResult& stats, Spool& spool) {
    const TileAnchors anchors(options.splat);
    const Buckets buckets = bucket_points(cloud, anchors, setup.grid);
    for (const TileKey& t : tiles_to_visit(cloud, buckets, setup.grid, anchors)) {
        const PointCloud part = subset(cloud, tile_points(cloud, buckets, t, setup.grid, anchors));
        spool.add(piece_bytes(tile_surface(part, options, setup, t, stats), spool.size(), {}));
    }
}

}  // namespace

TileGrid tile_margins(const KernelFrame& frame, const CloseOptions& close,
                      const SplatOptions& splat) {
    // Anchors lie up to `slack` voxels from the kernels' centres (presumming cells).
    const int slack = int(std::ceil(TileAnchors(splat).slack()));
    TileGrid g;
    g.halo = round_up(exact_margin(close) + sample_margin(frame) + slack, 8);
    // A face lies within the kernels' reach of a sample, or in a hole a closing bridges.
    g.reach = double(frame.max_r) + exact_margin(close) + slack;
    if (splat.aggregate > 0.0) {
        g.aggregate = splat.aggregate;
        g.aggregate_max_cell = splat.aggregate_max_cell;
    }
    return g;
}

int tile_edge(const TiledOptions& options, std::size_t beside, int halo) {
    return options.tile == kAutoTile ? auto_tile(beside, options.splat, halo)
                                     : round_up(options.tile, 8);
}

void place_grid(TileGrid& g, const Vec3f& lowest_point, double voxel) {
    for (int a = 0; a < 3; ++a) {
        const double lowest = double(lowest_point[a]) / voxel - g.reach;
        g.origin[std::size_t(a)] = int(std::floor(lowest / 8.0)) * 8;
    }
}

void check_tiled(const TiledOptions& options, std::size_t points) {
    if (options.close.solid_radius > 0) {
        throw InvalidArgument("tiles: a solid closing (--solid-close) needs the whole surface "
                              "at once and cannot run tile by tile");
    }
    if (options.tile == 0 || options.tile < kAutoTile) {
        throw InvalidArgument("tiles: the tile edge must be positive (or kAutoTile)");
    }
    if (points >= std::size_t(UINT32_MAX)) throw InvalidArgument("tiles: more than 2^32 points");
}

TileSetup tile_setup(const PointCloud& cloud, const TiledOptions& options) {
    check_tiled(options, cloud.size());
    TileSetup setup;
    setup.frame = kernel_frame(cloud, options.splat);
    TileGrid& g = setup.grid;
    g = tile_margins(setup.frame, options.close, options.splat);
    g.n = tile_edge(options, cloud.memory_bytes(), g.halo);
    place_grid(g, bounding_box(cloud.positions).min, options.splat.voxel_size);
    return setup;
}

TiledResult tiled_surface(PointCloud& cloud, const TiledOptions& options, bool release) {
    TileSetup setup = tile_setup(cloud, options);
    TileGrid& g = setup.grid;
    for (;;) {
        TiledResult result;
        result.tile = g.n;
        result.sample_spacing = options.sample_spacing;
        result.halo = g.halo;
        try {
            Spool spool("tiles: the tiles' pieces");  // on disk while the cloud is in memory
            all_tiles(cloud, options, setup, result, spool);
            result.splat.sigma_median = setup.frame.sigma_median;
            result.splat.points = cloud.size();
            const Vec3d origin = cloud.origin;
            if (release) cloud = PointCloud{};
            trim_heap();  // what the tiles freed, before the surface is joined
            TiledResult counted_already;
            const PieceSource source = [&](std::size_t i, std::string& b) {
                return spool.get(i, b);
            };
            ClassifiedSurface all =
                join_pieces(spool.size(), source, counted_already, "tiles: piece");
            result.mesh =
                finish_surface(std::move(all), options.splat.voxel_size, origin, options.mesh);
            return result;
        } catch (const InvalidArgument& e) {
            // A tile over the memory budget: with an automatic edge, half as large (the
            // estimate assumes a surface of average folding), from the start.
            const bool memory = std::string(e.what()).find(" of memory (") != std::string::npos;
            if (options.tile != kAutoTile || !memory || g.n <= 32) throw;
            g.n = std::max(32, g.n / 2 / 8 * 8);
        }
    }
}

}  // namespace vdbrecon::detail
