// Tile jobs (see detail/tiles.h): a tiled run cut into a preparation that writes the oriented
// samples into a directory, bucketed by tile, with the plan every tile shares; tile tasks that
// each read the buckets around their tile and return their piece of the surface as bytes; and a
// finish that welds the pieces in tile order. Each tile's samples are those the in-memory tiled
// run (tiles.cpp) picks, in the same order, so the pieces, and the mesh, are the same.
//
// Files: <dir>/plan.bin, <dir>/bucket-<j>.bin (occupied tile j's samples: their indices in the
// whole cloud and their columns). Little-endian machine layout of plain values, each file
// tagged, written under a temporary name and renamed into place.
#include <algorithm>
#include <cstring>
#include <string_view>

#include "detail/io_common.h"
#include "detail/tiles.h"
#include "vdbrecon/error.h"

namespace vdbrecon::detail {
namespace {

constexpr char kPlanTag[8] = {'v', 'd', 'b', 'r', 'P', 'L', 'N', '2'};
constexpr char kBucketTag[8] = {'v', 'd', 'b', 'r', 'B', 'K', 'T', '1'};
constexpr char kPieceTag[8] = {'v', 'd', 'b', 'r', 'P', 'C', 'E', '2'};

class Bytes {
  public:
    template <typename T>
    void put(const T& v) {
        bytes_.append(reinterpret_cast<const char*>(&v), sizeof(T));
    }
    template <typename T>
    void put_array(const T* data, std::size_t n) {
        put<std::uint64_t>(n);
        bytes_.append(reinterpret_cast<const char*>(data), n * sizeof(T));
    }
    template <typename V>
    void put_vector(const V& v) {
        put_array(v.data(), v.size());
    }
    std::string& str() { return bytes_; }

  private:
    std::string bytes_;
};

class Reader {
  public:
    Reader(std::string_view bytes, std::string what) : bytes_(bytes), what_(std::move(what)) {}
    bool at_end() const { return at_ == bytes_.size(); }
    template <typename T>
    T get() {
        need(sizeof(T));
        T v;
        std::memcpy(&v, bytes_.data() + at_, sizeof(T));
        at_ += sizeof(T);
        return v;
    }
    /// Steps over an array written by Bytes::put_vector; returns its length.
    template <typename T>
    std::size_t skip_vector() {
        const auto n = get<std::uint64_t>();
        if (n > (bytes_.size() - at_) / sizeof(T)) fail();
        at_ += n * sizeof(T);
        return std::size_t(n);
    }
    template <typename T>
    std::vector<T> get_vector() {
        const std::size_t from = at_ + sizeof(std::uint64_t);
        std::vector<T> v(skip_vector<T>());
        std::memcpy(v.data(), bytes_.data() + from, v.size() * sizeof(T));
        return v;
    }
    /// Appends an array written by Bytes::put_vector to v.
    template <typename T>
    void append_to(std::vector<T>& v) {
        const std::vector<T> more = get_vector<T>();
        v.insert(v.end(), more.begin(), more.end());
    }
    void tag(const char (&t)[8]) {
        need(8);
        if (std::memcmp(bytes_.data() + at_, t, 8) != 0) {
            throw FormatError(what_ + ": not a vdbrecon tile job file of this version");
        }
        at_ += 8;
    }

  private:
    void need(std::size_t n) {
        if (n > bytes_.size() - at_) fail();
    }
    [[noreturn]] void fail() { throw FormatError(what_ + ": truncated"); }
    std::string_view bytes_;
    std::string what_;
    std::size_t at_ = 0;
};

void write_file(const std::string& path, const std::string& bytes) {
    AtomicFile f(path);
    if (std::fwrite(bytes.data(), 1, bytes.size(), f.stream()) != bytes.size()) {
        throw IoError(path + ": write failed");
    }
    f.commit();
}

std::string plan_path(const std::string& dir) { return dir + "/plan.bin"; }

using Plan = TilePlan;

std::string plan_bytes(const Plan& p) {
    Bytes b;
    b.str().append(kPlanTag, 8);
    b.put(p.voxel);
    b.put(p.origin);
    b.put(p.sample_spacing);
    b.put(p.setup.frame);
    b.put(p.setup.grid);
    b.put(p.points);
    b.put_vector(p.tiles);
    b.put_vector(p.buckets);
    return std::move(b.str());
}

Plan read_plan(const std::string& dir) {
    const std::string path = plan_path(dir);
    const std::string bytes = read_file(path);
    Reader r(bytes, path);
    r.tag(kPlanTag);
    Plan p;
    p.voxel = r.get<double>();
    p.origin = r.get<Vec3d>();
    p.sample_spacing = r.get<double>();
    p.setup.frame = r.get<KernelFrame>();
    p.setup.grid = r.get<TileGrid>();
    p.points = r.get<std::uint64_t>();
    p.tiles = r.get_vector<TileKey>();
    p.buckets = r.get_vector<TileKey>();
    return p;
}

/// The options a tile runs with: the caller's, at the plan's voxel and sample spacing; refused
/// when they would give another halo than the plan's (its buckets were cut for that one).
TiledOptions tile_options(const Plan& plan, const TiledOptions& given) {
    TiledOptions o = given;
    o.splat.voxel_size = plan.voxel;
    o.sample_spacing = plan.sample_spacing;
    o.tile = plan.setup.grid.n;
    const TileGrid g = tile_margins(plan.setup.frame, o.close, o.splat);
    const TileGrid& p = plan.setup.grid;
    if (g.halo != p.halo || g.reach != p.reach || g.aggregate != p.aggregate ||
        g.aggregate_max_cell != p.aggregate_max_cell) {
        throw InvalidArgument(
            "tile job: the options differ from those it was prepared with "
            "(the closing radius and the presumming set the tiles' halo)");
    }
    return o;
}

/// Tile t's samples from the buckets around it, in the whole cloud's order.
PointCloud read_tile_samples(const std::string& dir, const Plan& plan, const TileKey& t,
                             const TileAnchors& anchors) {
    PointCloud loaded;  // the buckets' samples, one bucket after another
    std::vector<std::uint32_t> index;  // ... and their rows in the whole cloud
    for_each_bucket_near(plan.buckets, t, plan.setup.grid, [&](std::size_t j) {
        const std::string path = bucket_path(dir, j);
        const std::string bytes = read_file(path);
        Reader r(bytes, path);
        r.tag(kBucketTag);
        while (!r.at_end()) {  // its sections, one after another
            r.append_to(index);
            r.append_to(loaded.positions.edit());
            r.append_to(loaded.normals.edit());
            r.append_to(loaded.scales.edit());
            r.append_to(loaded.colors.edit());
            r.append_to(loaded.confidences.edit());
        }
    });
    std::vector<std::uint32_t> rows;
    for (std::size_t i = 0; i < index.size(); ++i) {
        if (in_halo(anchors(loaded, i), t, plan.setup.grid)) {
            rows.push_back(std::uint32_t(i));
        }
    }
    std::sort(rows.begin(), rows.end(),
              [&](std::uint32_t a, std::uint32_t b) { return index[a] < index[b]; });
    PointCloud out = subset(loaded, rows);
    out.origin = plan.origin;
    return out;
}

}  // namespace

std::string bucket_path(const std::string& dir, std::size_t j) {
    return dir + "/bucket-" + std::to_string(j) + ".bin";
}

std::string bucket_tag() { return std::string(kBucketTag, 8); }

std::string bucket_section(const std::vector<std::uint32_t>& index, const PointCloud& rows) {
    Bytes out;
    out.put_vector(index);
    out.put_vector(rows.positions);
    out.put_vector(rows.normals);
    out.put_vector(rows.scales);
    out.put_vector(rows.colors);
    out.put_vector(rows.confidences);
    return std::move(out.str());
}

void write_tile_plan(const std::string& dir, const TilePlan& plan) {
    write_file(plan_path(dir), plan_bytes(plan));  // last: a job with a plan is whole
}

std::size_t write_tile_job(const PointCloud& cloud, const TiledOptions& options,
                           const std::string& dir, int* tile) {
    if (options.tile == 0) throw InvalidArgument("tile job: no tile size (tile = 0)");
    Plan plan;
    plan.setup = tile_setup(cloud, options);  // checks the options
    plan.voxel = options.splat.voxel_size;
    plan.origin = cloud.origin;
    plan.sample_spacing = options.sample_spacing;
    plan.points = cloud.size();
    const TileAnchors anchors(options.splat);
    const Buckets b = bucket_points(cloud, anchors, plan.setup.grid);
    plan.tiles = tiles_to_visit(cloud, b, plan.setup.grid, anchors);
    plan.buckets = b.keys;
    for (std::size_t j = 0; j < b.keys.size(); ++j) {
        const std::vector<std::uint32_t> index(b.order.begin() + std::ptrdiff_t(b.begin[j]),
                                               b.order.begin() + std::ptrdiff_t(b.begin[j + 1]));
        std::string bytes(kBucketTag, 8);
        bytes += bucket_section(index, subset(cloud, index));
        write_file(bucket_path(dir, j), bytes);
    }
    write_tile_plan(dir, plan);
    if (tile) *tile = plan.setup.grid.n;
    return plan.tiles.size();
}

std::string run_tile_job(const std::string& dir, std::size_t index, const TiledOptions& options) {
    const Plan plan = read_plan(dir);
    if (index >= plan.tiles.size()) {
        throw InvalidArgument("tile job: tile " + std::to_string(index) + " of " +
                              std::to_string(plan.tiles.size()));
    }
    const TiledOptions o = tile_options(plan, options);
    const TileKey& t = plan.tiles[index];
    TiledResult stats;
    const ClassifiedSurface s = tile_surface(read_tile_samples(dir, plan, t, TileAnchors(o.splat)),
                                             o, plan.setup, t, stats);
    return piece_bytes(s, index, stats);
}

std::string piece_bytes(const ClassifiedSurface& s, std::size_t index, const TiledResult& stats) {
    Bytes b;
    b.str().append(kPieceTag, 8);
    b.put<std::uint64_t>(index);
    b.put_vector(s.points);
    b.put_vector(s.triangles);
    b.put_vector(s.status);
    b.put_vector(s.grad);
    b.put_vector(s.colors);
    b.put_vector(s.weight);
    b.put<std::uint64_t>(s.dropped_faces);
    b.put<std::uint64_t>(stats.tiles);
    b.put<std::uint64_t>(stats.max_tile_points);
    b.put<std::uint64_t>(stats.splat.active_voxels);
    b.put<std::uint64_t>(stats.splat.leaves);
    return std::move(b.str());
}

namespace {

/// Piece i read back (checked: its index, sizes that agree, faces on its points), its
/// statistics added to `stats`.
ClassifiedSurface read_piece(std::string_view bytes, std::size_t i, TiledResult& stats,
                             const std::string& what) {
    Reader r(bytes, what + " " + std::to_string(i));
    r.tag(kPieceTag);
    if (r.get<std::uint64_t>() != i) throw InvalidArgument(what + ": pieces out of order");
    ClassifiedSurface s;
    s.points = r.get_vector<openvdb::Vec3f>();
    s.triangles = r.get_vector<Triangle>();
    s.status = r.get_vector<char>();
    s.grad = r.get_vector<openvdb::Vec3f>();
    s.colors = r.get_vector<openvdb::Vec3f>();
    s.weight = r.get_vector<float>();
    s.dropped_faces = r.get<std::uint64_t>();
    stats.tiles += r.get<std::uint64_t>();
    stats.max_tile_points = std::max<std::size_t>(stats.max_tile_points, r.get<std::uint64_t>());
    stats.splat.active_voxels += r.get<std::uint64_t>();
    stats.splat.leaves += r.get<std::uint64_t>();
    const std::size_t np = s.points.size();
    bool ok = s.status.size() == np && s.grad.size() == np &&
              (s.colors.empty() || s.colors.size() == np) &&
              (s.weight.empty() || s.weight.size() == np);
    for (const Triangle& t : s.triangles) {
        for (std::int32_t v : t) ok = ok && v >= 0 && std::size_t(v) < np;
    }
    if (!ok) throw FormatError(what + " " + std::to_string(i) + ": inconsistent");
    return s;
}

/// The lengths of piece i's arrays (read_piece's layout), read without copying them.
struct PieceSizes {
    std::size_t points = 0, triangles = 0, colors = 0, weights = 0;
};
PieceSizes piece_sizes(std::string_view bytes, std::size_t i, const std::string& what) {
    Reader r(bytes, what + " " + std::to_string(i));
    r.tag(kPieceTag);
    r.get<std::uint64_t>();  // the index, checked by read_piece
    PieceSizes s;
    s.points = r.skip_vector<openvdb::Vec3f>();
    s.triangles = r.skip_vector<Triangle>();
    r.skip_vector<char>();            // status
    r.skip_vector<openvdb::Vec3f>();  // grad
    s.colors = r.skip_vector<openvdb::Vec3f>();
    s.weights = r.skip_vector<float>();
    return s;
}

}  // namespace

bool is_piece(std::string_view bytes, std::size_t index) {
    try {
        Reader r(bytes, "piece");
        r.tag(kPieceTag);
        if (r.get<std::uint64_t>() != index) return false;
        piece_sizes(bytes, index, "piece");
        return true;
    } catch (const FormatError&) {
        return false;
    }
}

std::size_t tile_job_tiles(const std::string& dir) { return read_plan(dir).tiles.size(); }

ClassifiedSurface join_pieces(std::size_t n, const PieceSource& source, TiledResult& stats,
                              const std::string& what) {
    std::string buffer;
    std::size_t points = 0, triangles = 0, colors = 0, weights = 0;
    for (std::size_t i = 0; i < n; ++i) {  // the sizes first
        const PieceSizes s = piece_sizes(source(i, buffer), i, what);
        points += s.points;
        triangles += s.triangles;
        colors += s.colors;
        weights += s.weights;
    }
    ClassifiedSurface all;
    all.points.reserve(points);
    all.status.reserve(points);
    all.grad.reserve(points);
    all.colors.reserve(colors);
    all.weight.reserve(weights);
    all.triangles.reserve(triangles);
    for (std::size_t i = 0; i < n; ++i) append(all, read_piece(source(i, buffer), i, stats, what));
    return all;
}

TiledResult finish_tile_job(const std::string& dir, std::size_t count, const PieceSource& pieces,
                            const TiledOptions& options, double& voxel, Vec3d& origin) {
    const Plan plan = read_plan(dir);
    if (count != plan.tiles.size()) {
        throw InvalidArgument("tile job: " + std::to_string(count) + " pieces for " +
                              std::to_string(plan.tiles.size()) + " tiles");
    }
    const TiledOptions o = tile_options(plan, options);
    TiledResult result;
    result.tile = plan.setup.grid.n;
    result.sample_spacing = plan.sample_spacing;
    result.halo = plan.setup.grid.halo;
    ClassifiedSurface all = join_pieces(count, pieces, result, "tile job piece");
    result.splat.sigma_median = plan.setup.frame.sigma_median;
    result.splat.points = plan.points;
    voxel = plan.voxel;
    origin = plan.origin;
    result.mesh = finish_surface(std::move(all), plan.voxel, plan.origin, o.mesh);
    return result;
}

}  // namespace vdbrecon::detail
