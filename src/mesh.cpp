// Surface extraction: options, dispatch, and what every mesher shares (see mesh.h).
#include "vdbrecon/mesh.h"

#include <openvdb/tools/Interpolation.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <numeric>
#include <optional>
#include <utility>

#include "detail/compact.h"
#include "detail/mesh_common.h"
#include "detail/mesh_graph.h"
#include "detail/radix_sort.h"
#include "detail/release.h"
#include "detail/support.h"
#include "vdbrecon/error.h"

namespace vdbrecon {

void MeshOptions::validate() const {
    if (!std::isfinite(isovalue)) throw InvalidArgument("mesh.isovalue must be finite");
    if (!(std::isfinite(min_surface_weight) && min_surface_weight >= 0.0)) {
        throw InvalidArgument("mesh.min_surface_weight = " + std::to_string(min_surface_weight) +
                              ": must be a non-negative number");
    }
    if (!(adaptivity >= 0.0 && adaptivity <= 1.0)) {
        throw InvalidArgument("mesh.adaptivity = " + std::to_string(adaptivity) +
                              ": must be in 0..1");
    }
    if (adaptivity > 0.0 && method != Mesher::vdb) {
        throw InvalidArgument("mesh.adaptivity = " + std::to_string(adaptivity) +
                              ": only the vdb mesher adapts (--mesher vdb)");
    }
    if (!(max_gap > 0.0)) {
        throw InvalidArgument("mesh.max_gap = " + std::to_string(max_gap) +
                              ": must be positive (infinity disables the test)");
    }
    if (!(max_gap_spacings >= 0.0)) {
        throw InvalidArgument("mesh.max_gap_spacings = " + std::to_string(max_gap_spacings) +
                              ": must be a non-negative number");
    }
    if (!(std::isfinite(sample_spacing) && sample_spacing >= 0.0)) {
        throw InvalidArgument("mesh.sample_spacing = " + std::to_string(sample_spacing) +
                              ": must be a non-negative number (0 = unknown)");
    }
    if (!(dc_truncation > 0.0 && dc_truncation < 1.0)) {
        throw InvalidArgument("mesh.dc_truncation = " + std::to_string(dc_truncation) +
                              ": must be in (0, 1)");
    }
    if (!(dc_bias >= 0.0 && std::isfinite(dc_bias))) {
        throw InvalidArgument("mesh.dc_bias = " + std::to_string(dc_bias) +
                              ": must be a non-negative number");
    }
}

namespace detail {
namespace {

/// The cells whose closed boxes contain the index-space point p (up to eps): lo..hi per axis.
void cells_around(const openvdb::Vec3d& p, int lo[3], int hi[3]) {
    constexpr double eps = 1e-4;
    for (int a = 0; a < 3; ++a) {
        lo[a] = int(std::floor(p[a] - eps));
        hi[a] = int(std::floor(p[a] + eps));
    }
}

/// Every cell whose closed box contains the index-space point `p` (up to eps) is valid.
bool point_in_valid_cells(FloatAccessor& acc, const openvdb::Vec3d& p) {
    int lo[3], hi[3];
    cells_around(p, lo, hi);
    for (int x = lo[0]; x <= hi[0]; ++x) {
        for (int y = lo[1]; y <= hi[1]; ++y) {
            for (int z = lo[2]; z <= hi[2]; ++z) {
                if (!cell_valid(acc, openvdb::Coord(x, y, z))) return false;
            }
        }
    }
    return true;
}

/// The SDF around one cell, for the gradient at points inside it: a view of the LeafBlock that
/// holds the cell's leaf (the cell's eight corners and their axis neighbours outside the cell
/// lie in the block), read in place. gradient() is the trilinear blend of the corners' central
/// differences (one-sided next to inactive voxels; zero at an inactive corner).
class CellStencil {
  public:
    /// The cell at voxel c, which lies in `block`'s leaf.
    void view(const LeafBlock& block, const openvdb::Coord& c) {
        int i = 0;
        block.index(c.offsetBy(-1), i);  // in the block: c is in its leaf
        f_ = block.values() + i;
        on_ = block.actives() + i;
    }

    /// Whether the cell's eight corners are active.
    bool valid() const {
        for (int x = 1; x <= 2; ++x) {
            for (int y = 1; y <= 2; ++y) {
                for (int z = 1; z <= 2; ++z) {
                    if (!on_[at(x, y, z)]) return false;
                }
            }
        }
        return true;
    }

    /// The gradient at the point with cell-local coordinates t (index units).
    openvdb::Vec3d gradient(const openvdb::Vec3d& t) const {
        openvdb::Vec3d g(0.0);
        for (int dx = 0; dx <= 1; ++dx) {
            for (int dy = 0; dy <= 1; ++dy) {
                for (int dz = 0; dz <= 1; ++dz) {
                    const double w = (dx ? t[0] : 1.0 - t[0]) * (dy ? t[1] : 1.0 - t[1]) *
                                     (dz ? t[2] : 1.0 - t[2]);
                    if (w != 0.0) g += w * corner_gradient(dx + 1, dy + 1, dz + 1);
                }
            }
        }
        return g;
    }

  private:
    /// The view's index of stencil voxel (x, y, z), 0..3 per axis from c - 1.
    static int at(int x, int y, int z) {
        return x * LeafBlock::kStep[0] + y * LeafBlock::kStep[1] + z;
    }

    openvdb::Vec3d corner_gradient(int x, int y, int z) const {
        openvdb::Vec3d g(0.0);
        const int c = at(x, y, z);
        if (!on_[c]) return g;
        const double f0 = double(f_[c]);
        for (int a = 0; a < 3; ++a) {
            const int lo = c - LeafBlock::kStep[a], hi = c + LeafBlock::kStep[a];
            const bool l = on_[lo], h = on_[hi];
            const double fl = double(f_[lo]), fh = double(f_[hi]);
            if (l && h) {
                g[a] = 0.5 * (fh - fl);
            } else if (h) {
                g[a] = fh - f0;
            } else if (l) {
                g[a] = f0 - fl;
            }
        }
        return g;
    }

    const float* f_ = nullptr;
    const std::uint8_t* on_ = nullptr;
};

/// Whether the index-space point p lies in one cell only (not within eps of a cell face).
bool in_one_cell(const openvdb::Vec3d& p) {
    int lo[3], hi[3];
    cells_around(p, lo, hi);
    return lo[0] == hi[0] && lo[1] == hi[1] && lo[2] == hi[2];
}

/// Classifies the points the triangles use (invalid cell, supported, weak, far; see
/// detail/support.h), takes their normals from the SDF gradient into `grad` when the mesher gave
/// none, and samples the weight grid (trilinear) at the valid ones into `weight` when it is not
/// empty (the support test's own sample where it took one).
std::vector<char> classify_points(const Volume& volume, const MeshOptions& options,
                                  const RawSurface& raw, bool own_normals,
                                  std::vector<openvdb::Vec3f>& grad, std::vector<float>& weight) {
    const openvdb::FloatGrid& sdf = *volume.sdf;
    const std::size_t npoints = raw.points.size();
    // Only points some triangle uses are looked at (marching cubes hands over every crossing).
    std::vector<char> used(npoints, 0);
    mark_used_vertices(raw.triangles, used.data(), char(1));
    std::vector<char> status(npoints, kInvalid);
    const SupportTest support(volume, options);
    const bool need_stencil = raw.check_cells || !own_normals;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, npoints, 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        FloatAccessor acc(sdf.tree());
        SupportTest::Accessors sacc = support.accessors();
        std::unique_ptr<FloatAccessor> facc;
        if (volume.fill) facc = std::make_unique<FloatAccessor>(volume.fill->tree());
        std::unique_ptr<FloatAccessor> wacc;
        if (!weight.empty()) wacc = std::make_unique<FloatAccessor>(volume.weight->tree());
        CellStencil stencil;
        // The mesher's points come leaf by leaf: each stencil reads the dense copy of its cell's
        // leaf and margin (most stencils cross a leaf's face, where the accessor's cache misses).
        std::unique_ptr<LeafBlock> block;
        openvdb::Coord block_leaf;
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            if (!used[i]) continue;
            const openvdb::Vec3d p(raw.points[i]);
            const openvdb::Coord c(int(std::floor(p[0])), int(std::floor(p[1])),
                                   int(std::floor(p[2])));
            if (need_stencil) {
                const openvdb::Coord leaf(c[0] & ~7, c[1] & ~7, c[2] & ~7);
                if (!block || leaf != block_leaf) {
                    if (!block) block = std::make_unique<LeafBlock>(acc);
                    block->load(leaf);
                    block_leaf = leaf;
                }
                stencil.view(*block, c);
                if (raw.check_cells &&
                    !(in_one_cell(p) ? stencil.valid() : point_in_valid_cells(acc, p))) {
                    continue;
                }
                if (!own_normals) grad[i] = openvdb::Vec3f(stencil.gradient(p - c.asVec3d()));
            }
            status[i] = kSupported;
            // A closing vouches for the points whose nearest voxel it closed (it judged that
            // voxel's support where the surface is, see SupportTest::at_voxel).
            std::optional<double> w;
            if (!facc ||
                !facc->isValueOn(openvdb::Coord(int(std::lround(p[0])), int(std::lround(p[1])),
                                                int(std::lround(p[2]))))) {
                const Support s = support.at(sacc, p, &w);
                if (s != Support::ok) status[i] = s == Support::far ? kFar : kWeak;
            }
            if (wacc) weight[i] = float(w ? *w : box_sample(*wacc, p));
        }
    });
    return status;
}

/// The unsupported faces (a vertex not kSupported), numbered in face order: slot[f] their number
/// (-1 for the others), face_of their faces, mine[v] set for their points. Counted, then
/// numbered, by chunks in parallel.
struct UnsupportedFaces {
    std::vector<std::int32_t> slot, face_of;
    std::vector<char> mine;
};

UnsupportedFaces unsupported_faces(const std::vector<Triangle>& tris,
                                   const std::vector<char>& status, std::size_t npoints) {
    const std::size_t nf = tris.size();
    UnsupportedFaces u;
    u.slot.resize(nf);
    u.mine.assign(npoints, 0);
    std::size_t total = 0;
    const std::vector<std::size_t> first = chunk_offsets(
        nf,
        [&](std::size_t, std::size_t begin, std::size_t end) {
            std::size_t count = 0;
            for (std::size_t f = begin; f < end; ++f) {
                bool unsupported = false;
                for (std::int32_t v : tris[f]) unsupported |= status[std::size_t(v)] != kSupported;
                u.slot[f] = unsupported ? 0 : -1;
                count += unsupported;
            }
            return count;
        },
        total);
    u.face_of.resize(total);
    for_each_chunk(nf, [&](std::size_t c, std::size_t begin, std::size_t end) {
        std::int32_t next = std::int32_t(first[c]);
        for (std::size_t f = begin; f < end; ++f) {
            if (u.slot[f] < 0) continue;
            u.face_of[std::size_t(next)] = std::int32_t(f);
            u.slot[f] = next++;
            for (std::int32_t v : tris[f]) {
                __atomic_store_n(&u.mine[std::size_t(v)], char(1), __ATOMIC_RELAXED);
            }
        }
    });
    return u;
}

/// The runs of the unsupported faces' sorted sides (one edge each): the first side of each
/// (first.back() = the number of sides) and how many faces of the whole mesh use its edge
/// (1: the open border). Those are the run's own sides plus the supported faces with that
/// edge, found by a search for their edges between two points of unsupported faces, the few
/// next to them. (With every face's such edges searched, the mesh stage of the Kinect frames
/// fused at 1 cm, 113k faces trimmed, took 0.127 / 0.076 s at 1 / 2 threads; 0.112 / 0.066 s
/// so.)
struct EdgeRuns {
    std::vector<std::size_t> first;
    std::vector<std::atomic<std::uint32_t>> uses;
};

EdgeRuns count_edge_uses(const std::vector<Triangle>& tris, const EdgeSides& sides,
                         const UnsupportedFaces& u) {
    EdgeRuns runs;
    std::vector<std::uint64_t> keys;
    for (std::size_t i = 0; i < sides.size(); ++i) {
        if (i == 0 || sides[i].key != sides[i - 1].key) {
            keys.push_back(sides[i].key);
            runs.first.push_back(i);
        }
    }
    runs.first.push_back(sides.size());
    runs.uses = std::vector<std::atomic<std::uint32_t>>(keys.size());
    for (std::size_t e = 0; e < keys.size(); ++e) {
        runs.uses[e].store(std::uint32_t(runs.first[e + 1] - runs.first[e]),
                           std::memory_order_relaxed);
    }
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, tris.size(), 16384),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t f = r.begin(); f < r.end(); ++f) {
                              if (u.slot[f] >= 0) continue;  // its sides are counted
                              const Triangle& t = tris[f];
                              for (int k = 0; k < 3; ++k) {
                                  const std::int32_t a = t[k], b = t[(k + 1) % 3];
                                  if (a == b || !u.mine[std::size_t(a)] || !u.mine[std::size_t(b)])
                                      continue;
                                  const auto it =
                                      std::lower_bound(keys.begin(), keys.end(), edge_key(a, b));
                                  if (it != keys.end() && *it == edge_key(a, b)) {
                                      runs.uses[std::size_t(it - keys.begin())].fetch_add(
                                          1, std::memory_order_relaxed);
                                  }
                              }
                          }
                      });
    return runs;
}

/// Which unsupported faces to trim: the edge-connected regions of unsupported faces (a vertex
/// weak or far) that hold a far vertex or an edge of the open border (an edge no other face
/// shares). Faces in invalid cells must be gone already. Works on the unsupported faces'
/// edges only (memory in proportion to them, not to the mesh: a 24 M face terrain had built
/// every edge of the mesh twice over, 1.2 GB, to answer for its 27 k unsupported faces). In
/// parallel: the regions are a union-find whose roots are the smallest number, so the labels
/// do not depend on the order of the unions.
std::vector<char> trimmed_faces(const std::vector<Triangle>& tris, const std::vector<char>& status,
                                std::size_t npoints) {
    std::vector<char> trim(tris.size(), 0);
    const UnsupportedFaces u = unsupported_faces(tris, status, npoints);
    const std::size_t n = u.face_of.size();
    if (n == 0) return trim;
    // The unsupported faces' edges, sorted: faces with one key share that edge. A degenerate
    // edge (a, a) joins nothing.
    EdgeSides sides = sorted_sides(tris, [&](std::size_t f) { return u.slot[f] >= 0; });
    compact_in_place(
        sides, [&](std::size_t i) { return (sides[i].key >> 32) != (sides[i].key & 0xffffffffu); });
    const EdgeRuns runs = count_edge_uses(tris, sides, u);
    // Regions, and their seeds: a face on the open border or with a far point.
    ConcurrentMinUnionFind sets(n);
    std::vector<char> seeded(n, 0);
    const auto seed = [&](std::size_t j) {
        __atomic_store_n(&seeded[j], char(1), __ATOMIC_RELAXED);
    };
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, runs.uses.size(), 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t e = r.begin(); e < r.end(); ++e) {
                              const bool border = runs.uses[e].load(std::memory_order_relaxed) == 1;
                              const std::int32_t head =
                                  u.slot[std::size_t(sides[runs.first[e]].face)];
                              for (std::size_t i = runs.first[e]; i < runs.first[e + 1]; ++i) {
                                  const std::int32_t me = u.slot[std::size_t(sides[i].face)];
                                  if (border) seed(std::size_t(me));
                                  if (i > runs.first[e]) sets.unite(me, head);
                              }
                          }
                      });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 16384),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t j = r.begin(); j < r.end(); ++j) {
                              for (std::int32_t v : tris[std::size_t(u.face_of[j])]) {
                                  if (status[std::size_t(v)] == kFar) seed(j);
                              }
                          }
                      });
    // A set is trimmed when one of its faces is seeded: each seed marks its root (only roots
    // are written, so no face's own seed changes while it is read).
    const std::vector<std::int32_t> label = sets.labels();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 16384),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t j = r.begin(); j < r.end(); ++j) {
                              if (__atomic_load_n(&seeded[j], __ATOMIC_RELAXED))
                                  seed(std::size_t(label[j]));
                          }
                      });
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 16384),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t j = r.begin(); j < r.end(); ++j) {
                              trim[std::size_t(u.face_of[j])] = seeded[std::size_t(label[j])];
                          }
                      });
    return trim;
}

}  // namespace

namespace {

/// Points at the same position (bit for bit) become one, the first of them: marching cubes
/// puts the crossings of every edge at a corner whose value is the iso-value there, and tiles
/// (tiles.cpp) each hand over the points of their faces along shared tile faces. Faces left
/// with a repeated point (no area) are dropped.
void weld_coincident(ClassifiedSurface& s) {
    std::vector<std::int32_t> used;
    {
        std::vector<char> in(s.points.size(), 0);
        for (const Triangle& t : s.triangles) {
            for (std::int32_t v : t) in[std::size_t(v)] = 1;
        }
        for (std::size_t i = 0; i < in.size(); ++i) {
            if (in[i]) used.push_back(std::int32_t(i));
        }
    }
    auto key = [&](std::int32_t i) {
        std::array<std::uint32_t, 3> k;
        std::memcpy(k.data(), &s.points[std::size_t(i)][0], sizeof k);
        return k;
    };
    // The points by a 32-bit hash of their position, then index (sorted in place as one 64-bit
    // value each), then within each run of one hash every point after the first with its
    // position maps to that first, the lowest index: the same pairs as sorting by (position,
    // index), for any thread count. Runs of distinct positions are nearly always single points.
    std::vector<std::uint64_t> order(used.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, used.size(), 16384),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t j = r.begin(); j < r.end(); ++j) {
                              const auto k = key(used[j]);
                              std::uint64_t h = (std::uint64_t(k[0]) * 0x9e3779b97f4a7c15ULL) ^
                                                (std::uint64_t(k[1]) * 0xc2b2ae3d27d4eb4fULL) ^
                                                (std::uint64_t(k[2]) * 0x165667b19e3779f9ULL);
                              h ^= h >> 29;
                              order[j] = (h & 0xffffffff00000000ULL) | std::uint32_t(used[j]);
                          }
                      });
    release(used);
    // Made in index order, so a stable sort on the hash alone orders them by the whole value
    // (a radix sort: the bunny's 338k points took a comparison sort 20 ms of one thread).
    radix_sort(order, 32, [](std::uint64_t v) { return v >> 32; });
    std::vector<std::int32_t> to;  // (duplicate, first) pairs
    std::vector<std::int32_t> firsts;  // the distinct positions of the current run
    for (std::size_t a = 0, b = 0; a < order.size(); a = b) {
        while (b < order.size() && (order[b] >> 32) == (order[a] >> 32)) ++b;
        if (b - a == 1) continue;
        firsts.clear();
        for (std::size_t j = a; j < b; ++j) {
            const std::int32_t i = std::int32_t(order[j] & 0xffffffffu);
            const auto same = std::find_if(firsts.begin(), firsts.end(),
                                           [&](std::int32_t f) { return key(f) == key(i); });
            if (same == firsts.end()) {
                firsts.push_back(i);
            } else {
                to.push_back(i);
                to.push_back(*same);
            }
        }
    }
    release(order);
    if (to.empty()) return;
    std::vector<std::int32_t> id(s.points.size());
    std::iota(id.begin(), id.end(), 0);
    for (std::size_t j = 0; j < to.size(); j += 2) id[std::size_t(to[j])] = to[j + 1];
    std::size_t kept = 0;
    for (const Triangle& f : s.triangles) {
        const Triangle t{id[std::size_t(f[0])], id[std::size_t(f[1])], id[std::size_t(f[2])]};
        if (t[0] == t[1] || t[1] == t[2] || t[2] == t[0]) {
            ++s.dropped_faces;
            continue;
        }
        s.triangles[kept++] = t;
    }
    s.triangles.resize(kept);
}

/// The mesh's vertex normals: the normalised SDF gradient `grad` (per point before the
/// compaction `remap`), or the area-weighted face normal where the gradient vanishes or points
/// against it. The face normals are summed a block of vertices at a time: a mesh of tens of
/// millions of vertices never holds all its sums (24 bytes a vertex).
void vertex_normals(Mesh& mesh, std::vector<openvdb::Vec3f>&& grad,
                    const std::vector<std::int32_t>& remap) {
    // The gradients in vertex order, in place: remap increases and never exceeds the index.
    for (std::size_t i = 0; i < remap.size(); ++i) {
        if (remap[i] >= 0) grad[std::size_t(remap[i])] = grad[i];
    }
    const std::size_t nv = mesh.vertices.size();
    std::vector<Vec3f>& normals = mesh.normals.edit();
    normals.resize(nv);
    // 3 MB of sums a block, each block a pass over the faces (the bunny's 338k vertices in one
    // block took 8 MB, most of it fresh memory at the mesh stage's peak).
    constexpr std::size_t kBlock = std::size_t(1) << 17;
    const FaceNormalSums face_normal_sums(mesh);
    for (std::size_t first = 0; first < nv; first += kBlock) {
        const std::size_t last = std::min(nv, first + kBlock);
        const std::vector<std::array<double, 3>> face_n = face_normal_sums(first, last);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(first, last, 16384),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t v = r.begin(); v < r.end(); ++v) {
                openvdb::Vec3d g(grad[v]);
                const auto& s = face_n[v - first];
                const openvdb::Vec3d fn(s[0], s[1], s[2]);
                if (!(g.length() > 1e-12) || g.dot(fn) < 0.0) g = fn;
                const double len = g.length();
                if (len > 0.0) g /= len;
                normals[v] = {float(g[0]), float(g[1]), float(g[2])};
            }
        });
    }
    release(grad);
}

}  // namespace

ClassifiedSurface classify_surface(const Volume& volume, const MeshOptions& options,
                                   RawSurface&& raw) {
    const std::size_t npoints = raw.points.size();
    ClassifiedSurface out;
    // The vertex normals before the face-normal fallback: the mesher's own, or the SDF gradient
    // (trilinear blend of central differences), which needs a stencil around each point.
    const bool own_normals = raw.normals.size() == npoints && npoints > 0;
    out.grad = own_normals ? std::move(raw.normals)
                           : std::vector<openvdb::Vec3f>(npoints, openvdb::Vec3f(0.0f));
    if (volume.weight) out.weight.assign(npoints, 0.0f);
    out.status = classify_points(volume, options, raw, own_normals, out.grad, out.weight);

    // Faces in invalid cells are dropped. Compacted in place (a filtered copy would add the
    // mesh's faces to the peak).
    out.triangles = std::move(raw.triangles);
    std::vector<Triangle>& tris = out.triangles;
    const std::vector<char>& status = out.status;
    out.dropped_faces = compact_in_place(tris, [&](std::size_t f) {
        const Triangle& t = tris[f];
        return status[std::size_t(t[0])] && status[std::size_t(t[1])] && status[std::size_t(t[2])];
    });
    out.points = std::move(raw.points);
    if (volume.color) {
        out.colors.assign(npoints, openvdb::Vec3f(0.0f));
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, npoints, 4096),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            Vec3Accessor cacc(volume.color->tree());
            for (std::size_t i = r.begin(); i < r.end(); ++i) {
                if (status[i] == kInvalid) continue;
                out.colors[i] = openvdb::tools::BoxSampler::sample(
                    cacc, openvdb::Vec3d(out.points[i]));
            }
        });
    }
    return out;
}

MeshResult finish_surface(ClassifiedSurface&& surface, double voxel, const Vec3d& origin,
                          const MeshOptions& options) {
    const std::size_t npoints = surface.points.size();
    MeshResult result;
    weld_coincident(surface);
    result.dropped_faces = surface.dropped_faces;
    // Faces trimmed where unsupported (see trimmed_faces).
    std::vector<Triangle> tris = std::move(surface.triangles);
    const std::vector<char> trim = trimmed_faces(tris, surface.status, npoints);
    result.trimmed_faces = compact_in_place(tris, [&](std::size_t f) { return !trim[f]; });

    // Compact: keep referenced points only, in their original order.
    std::size_t kept_points = 0;
    const std::vector<std::int32_t> remap = compact_vertices(tris, npoints, &kept_points);
    Mesh& mesh = result.mesh;
    mesh.origin = origin;
    std::vector<Vec3f>& vertices = mesh.vertices.edit();
    vertices.resize(kept_points);  // sized first: growth by doubling would raise the peak
    // Each kept point to its place (remap is one to one: any thread order writes the same).
    auto scatter = [&](auto&& put) {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, npoints, 16384),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t i = r.begin(); i < r.end(); ++i) {
                if (remap[i] >= 0) put(std::size_t(remap[i]), i);
            }
        });
    };
    scatter([&](std::size_t to, std::size_t i) {
        const openvdb::Vec3f& p = surface.points[i];
        vertices[to] = {float(p[0] * voxel), float(p[1] * voxel), float(p[2] * voxel)};
    });
    mesh.faces = std::move(tris);
    release(surface.points);  // not needed from here on: less to hold while the normals are made
    if (!surface.colors.empty() && !mesh.vertices.empty()) {
        std::vector<Vec3f>& colors = mesh.colors.edit();
        colors.resize(mesh.vertices.size());
        scatter([&](std::size_t to, std::size_t i) {
            const openvdb::Vec3f& c = surface.colors[i];
            colors[to] = {c[0], c[1], c[2]};
        });
    }
    release(surface.colors);
    if (!surface.weight.empty() && !mesh.vertices.empty()) {
        result.support.resize(mesh.vertices.size());
        scatter([&](std::size_t to, std::size_t i) { result.support[to] = surface.weight[i]; });
    }
    release(surface.weight);
    release(surface.status);
    if (options.normals && !mesh.vertices.empty()) {
        vertex_normals(mesh, std::move(surface.grad), remap);
    }
    return result;
}

MeshResult finish_mesh(const Volume& volume, const MeshOptions& options, RawSurface&& raw) {
    return finish_surface(classify_surface(volume, options, std::move(raw)),
                          volume.sdf->voxelSize()[0], volume.origin, options);
}

RawSurface mesh_raw(const Volume& volume, const MeshOptions& options) {
    switch (options.method) {
        case Mesher::dual:
            return mesh_dual(volume, options);
        case Mesher::vdb: return mesh_vdb(volume, options);
        case Mesher::mc: return mesh_mc(volume, options);
        case Mesher::dc: return mesh_dc(volume, options);
    }
    return {};
}

}  // namespace detail

MeshResult extract_mesh(const Volume& volume, const MeshOptions& options) {
    options.validate();
    if (!volume.sdf) throw InvalidArgument("extract_mesh: the volume has no sdf grid");
    initialize_openvdb();
    return detail::finish_mesh(volume, options, detail::mesh_raw(volume, options));
}

}  // namespace vdbrecon
