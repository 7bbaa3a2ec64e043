// The splat's field next to sharp creases.
//
// Near a sharp edge the splat's weighted average of tangent planes blends the planes of the
// faces that meet there. It rounds the edge over about a kernel width and, worse, where only a
// few samples reach (the border of the valid band, 2-3 sigma off the surface), the plane of one
// face extrapolated across the edge can outvote the face a voxel actually faces: the sign is
// wrong there, the zero level runs into the band's border and the mesh opens (3-24 boundary
// edges on each of our closed CAD test parts, with every mesher and every trim off).
//
// So the voxels next to a crease are evaluated again from the samples that reach them, with the
// splat's own kernels and weights u_i, face by face:
//  1. the samples around a leaf are grouped by normal (leader clustering: within half the
//     crease angle of a group's first sample); a face is a connected piece of samples whose
//     groups' mean normals are closer than the crease angle (a curved surface is a chain of
//     groups; connected_faces), and a face of one group is split where the offsets n.p of its
//     samples leave a gap of a voxel (the treads of a step). Stray normals make no face: a
//     handful of samples, or samples whose positions span a patch at an angle to their
//     normals (grazing views, misaligned overlaps of a scan; a curved face over a wide arc is
//     tested group by group); a voxel where such samples carry half the weight or more keeps
//     the splat's value;
//  2. each face f gives its own field F_f(x) = sum_f u_i n_i.(x - p_i) / sum_f u_i: the splat's
//     field of that face alone, continued across the edge, with the second-order correction
//     of a curved face's tangent planes (FaceSums::field);
//  3. where two or three faces reach a voxel (two samples each at least), they are combined as
//     the solid they bound. A pair is convex when each face's samples lie behind the other's
//     plane, F_a(c_b) + F_b(c_a) < 0 (c: a face's weighted centroid); a convex pair meets as
//     max(F_a, F_b) (intersection of half-spaces), a concave one as min (union); faces facing
//     the same way (a step's treads) as a union. With three faces, all pairs alike give max or
//     min of all, otherwise the odd pair is combined first: max(F_k, min(F_a, F_b)) when (a, b)
//     is the only concave pair, min(F_k, max(F_a, F_b)) when it is the only convex one.
//     The centroids can mislead: a face whose plane reaches past the concave edge where it ends
//     (its other face out of reach) looks convex to its neighbour, and a face that runs on past
//     another's edge straddles that plane. So every way the faces can meet (max, min, the three-
//     face forms, one face alone) is also scored on the samples: each lies on the surface, so
//     the right way is ~0 at every sample of the faces, with each face's field continued
//     linearly from the voxel. A way that fits them at least 4/3 as well as the centroids' wins
//     (a dent of 0.9-1.4 voxel and small holes next to concave edges at 1x the spacing).
// For planar faces with exact normals this is the exact signed distance next to edges and
// corners and across thin walls (whose two sides are a convex pair): the zero level is sharp
// and its sign right out to the band's border. Elsewhere -- one face, more than three -- the
// splat's value stays. It is the piecewise fitting of S. Fleishman, D. Cohen-Or and
// C. T. Silva, "Robust moving least-squares fitting with sharp features" (SIGGRAPH 2005), on
// the splat's linear basis, with the pieces combined as in CSG.
//
// Cost: the samples are indexed by cells of 4 voxels, each with a summary of its normal groups;
// a leaf gathers its samples and evaluates its voxels only when the summaries of the cells
// within reach of most kernels (95 %) show two faces. Each voxel is computed on its own from samples in a fixed order:
// the result does not depend on the thread count.
#include "detail/creases.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <tuple>
#include <utility>
#include <vector>

#include "detail/compact.h"
#include "detail/fill_later.h"
#include "detail/radix_sort.h"
#include "detail/select.h"
#include "detail/union_find.h"

namespace vdbrecon::detail {
namespace {

constexpr double kCell = 4.0;            ///< sample cell edge, voxels
constexpr int kMaxGroups = 16;           ///< normal groups around one leaf, at most
constexpr int kMinFaceSamples = 4;       ///< a face has at least this many samples around a leaf
constexpr int kMinCreaseFace = 12;       ///< ... and a leaf's crease test needs two this large
/// Stray samples' share of a voxel's weight, at most: where they weigh more, the faces do not
/// carry the voxel and the splat's blend stays. A half, not a tenth: at a thin wedge's tip (the
/// fan part's 40-degree blades) the few samples with blended normals carry 10-50 % of the
/// weight in the band past the tip, and the blend there turned the sign and opened the mesh
/// (fan, 200k samples, estimated normals, seed 1: 145/121/74/59 -> 8/5/0/0 boundary edges, mc
/// and dc at 1x and 1.5x). With no bound at all, a planar region of the room scan fell to 98 %
/// of its points within half a voxel of the --planes mesh.
constexpr double kMaxStray = 0.5;
/// The largest bend of a face's normals per voxel of its samples' spread across them for which
/// its field is corrected for curvature (FaceSums::field): 0.1, a radius of 10 voxels for a
/// sphere, 5 for a cylinder seen along its axis as much as across. The flat faces of CAD parts
/// with estimated normals, some blended next to edges, bend more where they bend at all; with
/// 0.25 a few of their dual-contouring meshes moved by 0.15-0.3 voxel (the fan's blade tips,
/// an L-bracket), with 0.1 fewer and less (bench/RESULTS.md).
constexpr double kMaxFaceCurvature = 0.1;
constexpr double kStepGap = 1.0;         ///< offset gap (voxels) that splits parallel faces

/// Leader clustering of unit normals: a normal joins the first group whose first normal is
/// within the angle (cosine `cos_group`), else starts a new one. At most kMaxGroups groups, held
/// in place (a leaf's screening makes one; no allocation).
class NormalGroups {
  public:
    explicit NormalGroups(double cos_group) : cos_group_(cos_group) {}

    /// The group of normal n (weighted by `count` samples), or -1 past kMaxGroups groups.
    int add(const openvdb::Vec3d& n, int count = 1) {
        int g = 0;
        while (g < size_ && n.dot(leader_[std::size_t(g)]) < cos_group_) ++g;
        if (g == size_) {
            if (g == kMaxGroups) return -1;
            leader_[std::size_t(g)] = n;
            sum_[std::size_t(g)] = openvdb::Vec3d(0.0);
            count_[std::size_t(g)] = 0;
            ++size_;
        }
        sum_[std::size_t(g)] += double(count) * n;
        count_[std::size_t(g)] += count;
        return g;
    }
    int size() const { return size_; }
    int count(int g) const { return count_[std::size_t(g)]; }

    using Labels = std::array<int, kMaxGroups>;
    /// Faces: groups joined when their mean normals are closer than the crease angle. Sets the
    /// face of each group, numbered in order of first group; returns the number of faces.
    int face_labels(double cos_crease, Labels& face) const {
        const int n = size();
        std::array<openvdb::Vec3d, kMaxGroups> means;
        Labels parent, number;
        for (int g = 0; g < n; ++g) {
            means[std::size_t(g)] = mean(g);
            parent[std::size_t(g)] = g;
            number[std::size_t(g)] = -1;
        }
        const auto root = [&](int g) {
            while (parent[std::size_t(g)] != g) g = parent[std::size_t(g)];
            return g;
        };
        for (int a = 0; a < n; ++a) {
            for (int b = a + 1; b < n; ++b) {
                if (!(means[std::size_t(a)].dot(means[std::size_t(b)]) > cos_crease)) continue;
                const int ra = root(a), rb = root(b);
                parent[std::size_t(std::max(ra, rb))] = std::min(ra, rb);
            }
        }
        int faces = 0;
        for (int g = 0; g < n; ++g) {
            const int r = root(g);
            if (number[std::size_t(r)] < 0) number[std::size_t(r)] = faces++;
            face[std::size_t(g)] = number[std::size_t(r)];
        }
        return faces;
    }
    openvdb::Vec3d mean(int g) const { return sum_[std::size_t(g)].unitSafe(); }
    /// Whether groups a and b are one face by their normals: mean normals closer than the
    /// crease angle (cosine `cos_crease`).
    bool close(int a, int b, double cos_crease) const {
        return mean(a).dot(mean(b)) > cos_crease;
    }

  private:
    double cos_group_;
    int size_ = 0;
    std::array<openvdb::Vec3d, kMaxGroups> leader_, sum_;
    std::array<int, kMaxGroups> count_;
};

/// How many of the `faces` faces (face_size: their sample counts) hold at least `least` samples.
int faces_of_size(const int* face_size, int faces, int least) {
    return int(std::count_if(face_size, face_size + faces, [&](int s) { return s >= least; }));
}

/// The samples sorted by cell (cells of kCell voxels), each cell's run of them and a summary of
/// its normals (the mean normal and size of each group), with an index tree of the cells.
class SampleCells {
  public:
    struct Cell {
        std::uint32_t begin = 0, end = 0;
        std::array<openvdb::Vec3f, 4> normal{};  ///< mean normal of each group
        std::array<int, 4> count{};
        int groups = 0;  ///< 5: more than four
    };

    SampleCells(const Kernels& kernels, std::size_t n, double cos_group)
        : index_(std::make_shared<openvdb::Int32Tree>(-1)) {
        // Each sample's cell, centre and radius, and each chunk's range of cells, in parallel
        // (a kernel costs an evaluation, made once: not again in cell order), then those with
        // a support, in order, into memory that is not zeroed first; the cells' runs found by
        // chunks (bunny at 0.5 mm: 17.6-18.8 -> 14.1-15.4 ms at 2 threads, 27-28 -> 23-25 ms
        // at 1, against pairs zero-filled, kernels made twice and one loop for the runs).
        FillLater<Keyed> keyed(n);
        FillLater<std::array<float, 4>> where(n);  // by sample
        std::vector<char> used(n);
        std::vector<openvdb::CoordBBox> range(chunk_count(n));
        for_each_chunk(n, [&](std::size_t c, std::size_t begin, std::size_t end) {
            openvdb::CoordBBox box;  // empty
            for (std::size_t i = begin; i < end; ++i) {
                const Kernel k = kernels(i, false);
                used[i] = k.r > 0.0f;
                const openvdb::Coord at = cell({k.cx, k.cy, k.cz});
                keyed[i] = {at[0], at[1], at[2], std::uint32_t(i)};
                where[i] = {float(k.cx), float(k.cy), float(k.cz), k.r};
                if (used[i]) box.expand(at);
            }
            range[c] = box;
        });
        compact_in_place(keyed, [&](std::size_t i) { return used[i] != 0; });
        openvdb::CoordBBox box;
        for (const openvdb::CoordBBox& b : range) {
            if (!b.empty()) box.expand(b);
        }
        sort_by_cell(keyed, box);
        // The samples in cell order, and the cells: their runs, found by chunks in parallel.
        const std::size_t m = keyed.size();
        order_.resize(m);
        where_.resize(m);
        std::size_t cells = 0;
        const std::vector<std::size_t> first = chunk_offsets(
            m,
            [&](std::size_t, std::size_t begin, std::size_t end) {
                std::size_t starts = 0;
                for (std::size_t j = begin; j < end; ++j) {
                    order_[j] = keyed[j].sample;
                    where_[j] = where[keyed[j].sample];
                    starts += j == 0 || !same_cell(keyed[j], keyed[j - 1]);
                }
                return starts;
            },
            cells);
        cells_.resize(cells);
        for_each_chunk(m, [&](std::size_t c, std::size_t begin, std::size_t end) {
            std::size_t at = first[c];
            for (std::size_t j = begin; j < end; ++j) {
                if (j > 0 && same_cell(keyed[j], keyed[j - 1])) continue;
                cells_[at].begin = std::uint32_t(j);
                if (at > 0) cells_[at - 1].end = std::uint32_t(j);
                ++at;
            }
        });
        if (cells > 0) cells_.back().end = std::uint32_t(m);
        openvdb::tree::ValueAccessor<openvdb::Int32Tree> index(*index_);
        for (std::size_t c = 0; c < cells; ++c) {
            const Keyed& k = keyed[cells_[c].begin];
            index.setValueOn(openvdb::Coord(k.x, k.y, k.z), int(c));
        }
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cells_.size(), 256),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t c = r.begin(); c < r.end(); ++c) summarise(cells_[c], kernels, cos_group);
        });
    }

    /// A sample's cell (x, y, z) and the sample.
    struct Keyed {
        std::int32_t x, y, z;
        std::uint32_t sample;
    };
    static bool same_cell(const Keyed& a, const Keyed& b) {
        return a.x == b.x && a.y == b.y && a.z == b.z;
    }

    /// Sorts (cell, sample) entries (in sample order) by cell, then sample: a radix sort on the
    /// cells' offsets from the lowest packed x-major, or where they need more than 64 bits a
    /// comparison sort. The entries are distinct, so the order is unique either way. `box`: the
    /// range of their cells.
    static void sort_by_cell(FillLater<Keyed>& keyed, const openvdb::CoordBBox& box) {
        if (keyed.empty()) return;
        const openvdb::Coord lo = box.min(), hi = box.max();
        int bits[3], total = 0;
        for (int a = 0; a < 3; ++a) {
            const std::uint64_t span = std::uint64_t(std::int64_t(hi[a]) - lo[a]);
            bits[a] = 0;
            while (bits[a] < 64 && (span >> bits[a]) != 0) ++bits[a];
            total += bits[a];
        }
        if (total > 64) {
            tbb::parallel_sort(keyed.begin(), keyed.end(), [](const Keyed& a, const Keyed& b) {
                return std::tie(a.x, a.y, a.z, a.sample) < std::tie(b.x, b.y, b.z, b.sample);
            });
            return;
        }
        radix_sort(keyed, total, [&](const Keyed& e) {
            const std::int32_t at[3] = {e.x, e.y, e.z};
            std::uint64_t key = 0;
            for (int a = 0; a < 3; ++a) {
                key = (key << bits[a]) | std::uint64_t(std::int64_t(at[a]) - lo[a]);
            }
            return key;
        });
    }

    static openvdb::Coord cell(const openvdb::Vec3d& x) {
        return openvdb::Coord(int(std::floor(x[0] / kCell)), int(std::floor(x[1] / kCell)),
                              int(std::floor(x[2] / kCell)));
    }

    using Accessor = openvdb::tree::ValueAccessor<const openvdb::Int32Tree>;
    Accessor accessor() const { return Accessor(*index_); }

    /// Calls fn(cell) for every non-empty cell in lo..hi (inclusive), in x, y, z order. A row's
    /// cells within one leaf of the index come from a byte of its value mask, not a probe each
    /// (the crease test looks at 6^3 cells around every leaf of the splat: bunny at 0.5 mm, 1
    /// thread, 21-22.6 -> 19.5-20.4 ms).
    template <typename Fn>
    void cells_in(Accessor& acc, const openvdb::Coord& lo, const openvdb::Coord& hi,
                  Fn&& fn) const {
        using IndexLeaf = openvdb::Int32Tree::LeafNodeType;
        for (int x = lo[0]; x <= hi[0]; ++x) {
            for (int y = lo[1]; y <= hi[1]; ++y) {
                for (int z0 = lo[2]; z0 <= hi[2];) {
                    const int z1 = std::min(hi[2], z0 | int(IndexLeaf::DIM - 1));  // one leaf's
                    const openvdb::Coord c(x, y, z0);
                    if (const IndexLeaf* leaf = acc.probeConstLeaf(c)) {
                        // The row's offsets are row .. row + 7 (z fastest), one byte of a word.
                        const openvdb::Index row = IndexLeaf::coordToOffset(c) & ~openvdb::Index(7);
                        const std::uint64_t word =
                            leaf->getValueMask().getWord<std::uint64_t>(row >> 6);
                        unsigned bits = unsigned(word >> (row & 63)) & 0xffu;
                        bits &= (0xffu << (z0 & 7)) & (0xffu >> (7 - (z1 & 7)));
                        for (; bits != 0; bits &= bits - 1) {
                            const int cell = leaf->getValue(row + unsigned(__builtin_ctz(bits)));
                            fn(cells_[std::size_t(cell)]);
                        }
                    }
                    z0 = z1 + 1;
                }
            }
        }
    }
    std::size_t sample(std::uint32_t j) const { return order_[j]; }
    /// Sample j's centre (index units, float) and support radius (voxels), for quick tests.
    const std::array<float, 4>& where(std::uint32_t j) const { return where_[j]; }

  private:
    void summarise(Cell& cell, const Kernels& kernels, double cos_group) const {
        NormalGroups groups(cos_group);
        for (std::uint32_t j = cell.begin; j < cell.end; ++j) {
            if (groups.add(openvdb::Vec3d(kernels.unit_normal(order_[j]))) < 0 ||
                groups.size() > 4) {
                cell.groups = 5;
                return;
            }
        }
        cell.groups = groups.size();
        for (int g = 0; g < cell.groups; ++g) {
            cell.normal[std::size_t(g)] = openvdb::Vec3f(groups.mean(g));
            cell.count[std::size_t(g)] = groups.count(g);
        }
    }

    openvdb::Int32Tree::Ptr index_;
    std::vector<Cell> cells_;
    std::vector<std::uint32_t> order_;
    std::vector<std::array<float, 4>> where_;
};

/// The samples whose support reaches one leaf, in a fixed order, and their faces.
struct LocalSamples {
    std::vector<Kernel> kernel;
    std::vector<int> face;  ///< -1: in no face (too few samples like it)

    void clear() {
        kernel.clear();
        face.clear();
    }
    std::size_t size() const { return kernel.size(); }
};

/// Whether the selected samples (of one face) lie across their normals: where their positions
/// span a patch (the least of the three principal spreads below a quarter of the middle one),
/// its normal must be within half the crease angle of the samples' mean normal. Samples of a
/// scanned surface with wrong normals (grazing views, misaligned overlaps) make a group of their
/// own whose positions follow the surface, not their normals. One sample does not decide it: the
/// test is made again without the sample farthest from the plane through their centroid with
/// their mean normal. (At the end of the fan part's blade tips a sample of the end face
/// with a blended normal joined the few samples of a blade's face there, tilted their patch
/// and left the leaf with one face, the splat's blend, and a hole: fan, 200k samples, seed 2.)
template <typename Select>
bool consistent(const LocalSamples& s, Select&& selected, double cos_group) {
    // The thread's array, kept between calls: grown afresh each call, its reallocations from
    // both threads took the CLI's one heap lock from each other (detail/release.h, heap_lock).
    static thread_local std::vector<Eigen::Vector3d> p;
    p.clear();
    Eigen::Vector3d mean_n = Eigen::Vector3d::Zero(), centre = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < s.size(); ++i) {
        if (!selected(i)) continue;
        const Kernel& k = s.kernel[i];
        mean_n += Eigen::Vector3d(k.nx, k.ny, k.nz);
        p.emplace_back(k.cx, k.cy, k.cz);
        centre += p.back();
    }
    mean_n.normalize();
    const auto patch_fits = [&](std::size_t skip) {
        const std::size_t n = p.size() - (skip < p.size() ? 1 : 0);
        Eigen::Vector3d c = Eigen::Vector3d::Zero();
        for (std::size_t i = 0; i < p.size(); ++i) c += i == skip ? Eigen::Vector3d::Zero() : p[i];
        c /= double(n);
        Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
        for (std::size_t i = 0; i < p.size(); ++i) {
            if (i != skip) cov += (p[i] - c) * (p[i] - c).transpose();
        }
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
        es.computeDirect(cov);
        const Eigen::Vector3d lambda = es.eigenvalues();  // ascending
        if (!(lambda[0] < 0.25 * lambda[1])) return true;  // no patch to tell from
        return std::fabs(es.eigenvectors().col(0).dot(mean_n)) >= cos_group;
    };
    if (patch_fits(p.size())) return true;
    centre /= double(p.size());
    std::size_t far = 0;
    for (std::size_t i = 1; i < p.size(); ++i) {
        if (std::fabs(mean_n.dot(p[i] - centre)) > std::fabs(mean_n.dot(p[far] - centre))) far = i;
    }
    return p.size() > std::size_t(kMinFaceSamples) && patch_fits(far);
}

/// The faces of the local samples (sets s.face; returns how many): connected pieces of samples
/// whose normal groups are closer than the crease angle (a curved surface is a chain of
/// groups). Connected: on a grid of cells two kernel widths across (twice the samples' mean
/// sigma, at least two voxels), the (cell, group) pairs of neighbouring cells (26-neighbourhood,
/// or the same cell) whose groups are that close are joined. Faces are numbered in the order of
/// their first sample.
///
/// Leader clustering alone puts samples far apart in one group, and joining groups by their
/// normals alone joins pieces that do not meet: the side wall of a block and, 9 voxels inside
/// it, a cylindrical boss's wall facing 10-40 degrees away were one face, whose samples span no
/// plane along their normals (consistent()), so the leaf kept the splat's blend and dual
/// contouring rounded the block's edge below the boss by 0.3 voxel (boss, 60,000 samples, a
/// voxel of 3x the spacing).
int connected_faces(LocalSamples& s, const std::vector<int>& group, const NormalGroups& groups,
                    double cos_crease) {
    openvdb::Vec3d lo(std::numeric_limits<double>::max()), hi(-lo);
    double sigma = 0.0;
    for (const Kernel& k : s.kernel) {
        const openvdb::Vec3d p(k.cx, k.cy, k.cz);
        lo = openvdb::math::minComponent(lo, p);
        hi = openvdb::math::maxComponent(hi, p);
        sigma += k.s;
    }
    double cell = 2.0 * std::max(1.0, sigma / double(s.size()));
    const auto cells = [&](int a) { return int((hi[a] - lo[a]) / cell) + 1; };
    while (cells(0) > 64 || cells(1) > 64 || cells(2) > 64) cell *= 2.0;
    const int n[3] = {cells(0), cells(1), cells(2)};
    const auto index = [&](const Kernel& k) {
        const int x = int((k.cx - lo[0]) / cell), y = int((k.cy - lo[1]) / cell),
                  z = int((k.cz - lo[2]) / cell);
        return (x * n[1] + y) * n[2] + z;
    };
    // Each sample's cell; the groups present in each cell, and the number of the cell's first
    // (cell, group) node.
    std::vector<int> cell_of(s.size());
    std::vector<std::uint16_t> present(std::size_t(n[0] * n[1] * n[2]), 0);
    for (std::size_t i = 0; i < s.size(); ++i) {
        cell_of[i] = index(s.kernel[i]);
        present[std::size_t(cell_of[i])] |= std::uint16_t(1u << group[i]);
    }
    std::vector<std::int32_t> first(present.size());
    std::int32_t nodes = 0;
    for (std::size_t c = 0; c < present.size(); ++c) {
        first[c] = nodes;
        nodes += std::int32_t(__builtin_popcount(present[c]));
    }
    const auto node = [&](int c, int g) {
        return first[std::size_t(c)] +
               __builtin_popcount(present[std::size_t(c)] & ((1u << g) - 1u));
    };
    std::array<std::uint16_t, kMaxGroups> joinable{};  // the groups one face with g by normal
    for (int a = 0; a < groups.size(); ++a) {
        for (int b = 0; b < groups.size(); ++b) {
            if (groups.close(a, b, cos_crease)) joinable[std::size_t(a)] |= 1u << b;
        }
    }
    MinUnionFind pieces(static_cast<std::size_t>(nodes));
    for (int x = 0; x < n[0]; ++x) {
        for (int y = 0; y < n[1]; ++y) {
            for (int z = 0; z < n[2]; ++z) {
                const int c = (x * n[1] + y) * n[2] + z;
                const unsigned here = present[std::size_t(c)];
                if (here == 0) continue;
                // The cell itself and its 13 neighbours that come after it.
                for (int d = 13; d < 27; ++d) {
                    const int u = x + d / 9 - 1, v = y + d / 3 % 3 - 1, w = z + d % 3 - 1;
                    if (u >= n[0] || v < 0 || v >= n[1] || w < 0 || w >= n[2]) continue;
                    const int c2 = (u * n[1] + v) * n[2] + w;
                    const unsigned there = present[std::size_t(c2)];
                    for (unsigned m = here; m != 0; m &= m - 1) {
                        const int g = __builtin_ctz(m);
                        const unsigned to = there & joinable[std::size_t(g)];
                        for (unsigned m2 = to; m2 != 0; m2 &= m2 - 1) {
                            pieces.unite(node(c, g), node(c2, __builtin_ctz(m2)));
                        }
                    }
                }
            }
        }
    }
    const std::vector<std::int32_t> root = std::move(pieces).labels();
    std::vector<int> number(root.size(), -1);
    int count = 0;
    s.face.resize(s.size());
    for (std::size_t i = 0; i < s.size(); ++i) {
        const std::int32_t r = root[std::size_t(node(cell_of[i], group[i]))];
        if (number[std::size_t(r)] < 0) number[std::size_t(r)] = count++;
        s.face[i] = number[std::size_t(r)];
    }
    return count;
}

/// The normal group of each face's samples, or -2 where they belong to several.
std::vector<int> face_groups(const LocalSamples& s, const std::vector<int>& group, int count) {
    std::vector<int> face_group(static_cast<std::size_t>(count), -1);
    for (std::size_t i = 0; i < s.size(); ++i) {
        int& g = face_group[std::size_t(s.face[i])];
        g = g == -1 || g == group[i] ? group[i] : -2;
    }
    return face_group;
}

/// Splits each face of one normal group at gaps of kStepGap in the offsets n.p of its samples
/// (the treads of a step). Returns the new number of faces.
int split_steps(LocalSamples& s, const std::vector<int>& group, const NormalGroups& groups,
                int count) {
    const std::vector<int> face_group = face_groups(s, group, count);
    const int faces = count;
    for (int f = 0; f < faces; ++f) {
        const int g = face_group[std::size_t(f)];
        if (g < 0) continue;
        const openvdb::Vec3d m = groups.mean(g);
        std::vector<std::pair<double, std::size_t>> offset;
        for (std::size_t i = 0; i < s.size(); ++i) {
            const Kernel& k = s.kernel[i];
            if (s.face[i] == f) offset.push_back({m.dot(openvdb::Vec3d(k.cx, k.cy, k.cz)), i});
        }
        std::sort(offset.begin(), offset.end());
        for (std::size_t k = 1; k < offset.size(); ++k) {
            if (offset[k].first - offset[k - 1].first < kStepGap) continue;
            const int face = count++;  // from here on, a new face
            for (std::size_t j = k; j < offset.size(); ++j) s.face[offset[j].second] = face;
        }
    }
    return count;
}

/// Stray normals are no face (-1): fewer than kMinFaceSamples samples, or samples whose
/// normals do not fit their positions (see consistent()). A face of several groups that fails
/// keeps the groups that pass on their own: a curved face seen over a wide arc spans no plane
/// (a boss of 11 voxels' radius, 78 degrees of it around one leaf, was rejected whole, the
/// leaf kept the splat's blend and the boss's foot came out 0.42 voxel off; 60,000 samples,
/// seed 2, a voxel of 3x the spacing). Renumbers the faces left; returns how many.
int drop_strays(LocalSamples& s, const std::vector<int>& group, int groups, int count,
                double cos_group) {
    const std::vector<int> face_group = face_groups(s, group, count);
    const std::size_t row = kMaxGroups;
    std::vector<int> size(static_cast<std::size_t>(count), 0), part(size.size() * row, 0);
    for (std::size_t i = 0; i < s.size(); ++i) {
        ++size[std::size_t(s.face[i])];
        ++part[std::size_t(s.face[i]) * row + std::size_t(group[i])];
    }
    std::vector<std::uint8_t> keep(part.size(), 0);  // per (face, group)
    std::vector<int> number(size.size(), -1);
    int faces = 0;
    for (int f = 0; f < count; ++f) {
        if (size[std::size_t(f)] < kMinFaceSamples) continue;
        std::uint8_t* kept = &keep[std::size_t(f) * row];
        if (consistent(s, [&](std::size_t i) { return s.face[i] == f; }, cos_group)) {
            std::fill_n(kept, row, 1);
        } else if (face_group[std::size_t(f)] == -2) {
            for (int g = 0; g < groups; ++g) {
                kept[g] = part[std::size_t(f) * row + std::size_t(g)] >= kMinFaceSamples &&
                          consistent(s, [&](std::size_t i) {
                              return s.face[i] == f && group[i] == g;
                          }, cos_group);
            }
        }
        if (std::find(kept, kept + row, 1) != kept + row) number[std::size_t(f)] = faces++;
    }
    for (std::size_t i = 0; i < s.size(); ++i) {
        const std::size_t f = std::size_t(s.face[i]);
        s.face[i] = keep[f * row + std::size_t(group[i])] ? number[f] : -1;
    }
    return faces;
}

/// Assigns the local samples to faces (see the file comment, step 1). Returns how many.
int assign_faces(LocalSamples& s, double cos_group, double cos_crease) {
    if (s.size() == 0) return 0;
    NormalGroups groups(cos_group);
    std::vector<int> group(s.size());
    for (std::size_t i = 0; i < s.size(); ++i) {
        const Kernel& k = s.kernel[i];
        group[i] = groups.add(openvdb::Vec3d(k.nx, k.ny, k.nz));
        if (group[i] < 0) return 0;
    }
    const int count = split_steps(s, group, groups, connected_faces(s, group, groups, cos_crease));
    return drop_strays(s, group, groups.size(), count, cos_group);
}

/// One face's sums at a voxel x: u, u phi (world units), u n, u (p - x) and u (p - x)(p - x)^T
/// (voxels).
struct FaceSums {
    double u = 0.0, uphi = 0.0;
    openvdb::Vec3d un{0.0}, up{0.0};
    double upp[6] = {0, 0, 0, 0, 0, 0};  ///< u (p - x)(p - x)^T: xx, xy, xz, yy, yz, zz (voxels^2)
    int count = 0;

    /// The face's signed distance at the voxel (world units), corrected for curvature. On a
    /// surface of curvature k the mean of the samples' tangent planes, uphi / u, is off by
    /// k <s^2> / 2 (s: a sample's offset along the surface from the voxel's foot point, <>:
    /// the kernel-weighted mean), and the plane through their centroid with their mean normal
    /// is off by k (2 <s>^2 - <s^2>) / 2. Their mean is off by k <s>^2 / 2 only, which
    /// vanishes where the samples lie around the foot point. This is the second-order estimate
    /// of smooth_estimate in mesh_dc.cpp, sum_i u_i (n_i.(x - p_i) - (x - p_i).(n_i - n) / 2)
    /// / u, summed here over the samples. Without it the wall of a drilled hole of 24 voxels'
    /// radius read 0.07 voxel high next to its rim, where few samples reach and those lie far
    /// off, and the rim's dual-contouring vertices were 0.10-0.15 voxel off. For a plane the
    /// two are the same.
    ///
    /// The two differ by k Var(s); where that says k > kMaxFaceCurvature (Var(s): the spread
    /// of the samples' positions across n) the face is no smooth surface but, say, samples of
    /// two faces grouped as one (estimated normals blended next to the fan's 40-degree blade
    /// tips: a tip's voxels fell from 1.4 to 0.45 voxel and the tip was cut by a voxel), and
    /// the mean of the tangent planes stays.
    double field(double voxel) const {
        const double f = tangent_mean(), len = un.length();
        if (!(len > 0.0)) return f;
        const openvdb::Vec3d n = un / len, mean = up / u;  // mean: centroid - x, voxels
        const double centroid_plane = -n.dot(mean) * voxel;
        // The spread of the positions (voxels^2) along n, and across it.
        const double along = n[0] * n[0] * upp[0] + n[1] * n[1] * upp[3] + n[2] * n[2] * upp[5] +
                             2.0 * (n[0] * n[1] * upp[1] + n[0] * n[2] * upp[2] +
                                    n[1] * n[2] * upp[4]);
        const double across = (upp[0] + upp[3] + upp[5] - along) / u -
                              (mean.lengthSqr() - n.dot(mean) * n.dot(mean));
        // A plane (the two agree within 1e-6 voxel) keeps the tangent planes' mean bit for
        // bit: the rounding of the mean alone left two faces of an L-bracket in no region of
        // the --planes stage.
        const double bend = std::fabs(f - centroid_plane) / voxel;
        if (!(bend > 1e-6 && bend <= kMaxFaceCurvature * across)) return f;
        return 0.5 * (f + centroid_plane);
    }
    /// The mean of the samples' tangent planes at the voxel (world units): the field before
    /// the curvature correction, which is what the ways the faces meet are chosen and scored
    /// on (field_at, LeafSums::score); the correction refines the value only.
    double tangent_mean() const { return uphi / u; }
    /// This face's field at another face's weighted centroid.
    double field_at(const FaceSums& other, double voxel) const {
        return tangent_mean() + un.dot(other.up) / (u * other.u) * voxel;
    }
};

/// Whether faces a and b meet convexly: each lies behind the other's plane. Faces facing the
/// same way (the treads of a step) meet as a union, like a concave pair.
bool convex(const FaceSums& a, const FaceSums& b, double voxel) {
    if (a.un.dot(b.un) > 0.9 * a.un.length() * b.un.length()) return false;
    return a.field_at(b, voxel) + b.field_at(a, voxel) < 0.0;
}

constexpr int kWays[4] = {0, 0, 4, 11};  ///< how many ways n faces can meet (see meet())
constexpr int kMaxWays = kWays[3];

/// The ways 2 or 3 faces' fields f[] can meet (see the file comment, step 3): 0 max of all
/// (convex), 1 min of all (concave); with three faces, 2 + k: max(f_k, min(the other two)),
/// 5 + k: min(f_k, max(the other two)); and the last n ways: one face alone (the others'
/// samples barely reach, and their planes are continued past where their faces end).
double meet(int how, const double* f, int n) {
    if (how >= kWays[n] - n) return f[how - (kWays[n] - n)];  // one face alone
    if (n == 2) return how == 0 ? std::max(f[0], f[1]) : std::min(f[0], f[1]);
    if (how == 0) return std::max({f[0], f[1], f[2]});
    if (how == 1) return std::min({f[0], f[1], f[2]});
    const int k = (how - 2) % 3;
    const double a = f[(k + 1) % 3], b = f[(k + 2) % 3];
    return how < 5 ? std::max(f[k], std::min(a, b)) : std::min(f[k], std::max(a, b));
}

/// How 2 or 3 faces meet by their centroids: each pair convex or concave (see convex()); with
/// three faces, all pairs alike give max or min of all, otherwise the odd pair is combined
/// first.
int centroid_meet(const FaceSums* g, int n, double voxel) {
    if (n == 2) return convex(g[0], g[1], voxel) ? 0 : 1;
    const bool c01 = convex(g[0], g[1], voxel), c02 = convex(g[0], g[2], voxel),
               c12 = convex(g[1], g[2], voxel);
    const int convex_pairs = int(c01) + int(c02) + int(c12);
    if (convex_pairs == 3) return 0;
    if (convex_pairs == 0) return 1;
    const bool odd_is_convex = convex_pairs == 1;
    int k = 2;  // the face outside the odd pair
    if (c02 == odd_is_convex) {
        k = 1;
    } else if (c12 == odd_is_convex) {
        k = 0;
    }
    return odd_is_convex ? 5 + k : 2 + k;
}

/// Whether the summaries of the cells within `margin` cells of a leaf show two faces of at
/// least kMinCreaseFace samples. Cells of more than four normal groups, and regions of more
/// than kMaxGroups, are noise to this test (no crease of a few faces looks like that).
bool leaf_near_crease(const SampleCells& cells, SampleCells::Accessor& acc,
                      const openvdb::Coord& origin, int margin, double cos_group,
                      double cos_crease) {
    NormalGroups groups(cos_group);
    bool noise = false;
    cells.cells_in(acc, SampleCells::cell(origin.asVec3d()).offsetBy(-margin),
                   SampleCells::cell(origin.offsetBy(7).asVec3d()).offsetBy(margin),
                   [&](const SampleCells::Cell& c) {
        for (int g = 0; g < c.groups && c.groups <= 4 && !noise; ++g) {
            noise = groups.add(openvdb::Vec3d(c.normal[std::size_t(g)]),
                               c.count[std::size_t(g)]) < 0;
        }
    });
    if (noise || groups.size() < 2) return false;
    NormalGroups::Labels face_of_group, size{};
    const int faces = groups.face_labels(cos_crease, face_of_group);
    for (int g = 0; g < groups.size(); ++g) {
        size[std::size_t(face_of_group[std::size_t(g)])] += groups.count(g);
    }
    return faces_of_size(size.data(), faces, kMinCreaseFace) >= 2;
}

/// Gathers the samples whose support reaches the leaf at `origin`.
void gather(const SampleCells& cells, SampleCells::Accessor& acc, const Kernels& kernels,
            const openvdb::Coord& origin, float r_max, LocalSamples& s) {
    s.clear();
    const openvdb::Vec3d lo = origin.asVec3d() - openvdb::Vec3d(r_max),
                         hi = origin.asVec3d() + openvdb::Vec3d(7.0 + r_max);
    cells.cells_in(acc, SampleCells::cell(lo), SampleCells::cell(hi),
                   [&](const SampleCells::Cell& c) {
        for (std::uint32_t j = c.begin; j < c.end; ++j) {
            // A float test with a margin first, the exact one on the kernel after.
            const std::array<float, 4>& w = cells.where(j);
            float e2 = 0.0f;
            for (int a = 0; a < 3; ++a) {
                const float e = std::max({float(origin[a]) - w[std::size_t(a)],
                                          w[std::size_t(a)] - float(origin[a] + 7), 0.0f});
                e2 += e * e;
            }
            if (e2 > (w[3] + 0.01f) * (w[3] + 0.01f)) continue;
            const Kernel k = kernels(cells.sample(j));
            const double p[3] = {k.cx, k.cy, k.cz};
            double d2 = 0.0;  // to the leaf's box
            for (int a = 0; a < 3; ++a) {
                const double e =
                    std::max({double(origin[a]) - p[a], p[a] - double(origin[a] + 7), 0.0});
                d2 += e * e;
            }
            if (d2 <= double(k.r) * double(k.r)) s.kernel.push_back(k);
        }
    });
}

/// Every face's sums at every voxel of a leaf (voxel-major), and per voxel the weight of all
/// samples and of the stray ones: summed sample by sample over each kernel's support within
/// the leaf, as the splat sums, in the local samples' order.
class LeafSums {
  public:
    void reset(int faces) {
        faces_ = faces;
        face_.assign(512 * std::size_t(faces), FaceSums{});
        all_.assign(512, 0.0);
        stray_.assign(512, 0.0);
    }

    void add(const LocalSamples& s, const openvdb::Coord& origin, double voxel) {
        prepare(s, origin);
        reach(s, [&](std::size_t i, int v, double u, const openvdb::Vec3d& d) {
            all_[std::size_t(v)] += u;
            const int f = s.face[i];
            if (f < 0) {
                stray_[std::size_t(v)] += u;
                return;
            }
            const Kernel& k = s.kernel[i];
            const openvdb::Vec3d n(k.nx, k.ny, k.nz);
            FaceSums& F = face_[std::size_t(v * faces_ + f)];
            F.u += u;
            F.uphi += u * n.dot(d) * voxel;
            F.un += u * n;
            F.up -= u * d;
            F.upp[0] += u * d[0] * d[0];
            F.upp[1] += u * d[0] * d[1];
            F.upp[2] += u * d[0] * d[2];
            F.upp[3] += u * d[1] * d[1];
            F.upp[4] += u * d[1] * d[2];
            F.upp[5] += u * d[2] * d[2];
            ++F.count;
        });
    }

    /// After add(): how well each way the voxel's faces can meet fits their samples. Every
    /// sample lies on the surface, so the right way is ~0 at each one: score = the sum over the
    /// samples of the voxel's faces of u |meet(the faces' fields at the sample)|, with each
    /// face's field continued linearly from the voxel.
    /// Only the leaf's active voxels (`active`) are scored: value() is asked of no other. A
    /// voxel where stray samples carry more than kMaxStray of the weight gets no faces: the
    /// splat's blend is safer there.
    void score(const LocalSamples& s, double voxel, const openvdb::util::NodeMask<3>& active) {
        present_.assign(512, {-1, -1, -1});
        score_.assign(512 * kMaxWays, 0.0);
        for (int v = 0; v < 512; ++v) {
            if (!active.isOn(openvdb::Index(v))) continue;
            if (stray_[std::size_t(v)] > kMaxStray * all_[std::size_t(v)]) continue;
            int count = 0;
            for (int f = 0; f < faces_ && count <= 3; ++f) {
                if (face_[std::size_t(v * faces_ + f)].count < 2) continue;
                if (count < 3) present_[std::size_t(v)][std::size_t(count)] = f;
                ++count;
            }
            if (count > 3 || count < 2) present_[std::size_t(v)][0] = -1;
        }
        reach(s, [&](std::size_t i, int v, double u, const openvdb::Vec3d& d) {
            const std::array<int, 3>& p = present_[std::size_t(v)];
            const int f = s.face[i];
            if (p[0] < 0 || f < 0 || (f != p[0] && f != p[1] && f != p[2])) return;
            const int n = p[2] < 0 ? 2 : 3;
            double at[3];
            for (int j = 0; j < n; ++j) {
                const FaceSums& F = face_[std::size_t(v * faces_ + p[std::size_t(j)])];
                at[j] = F.tangent_mean() - F.un.dot(d) / F.u * voxel;  // at the sample, x - d
            }
            for (int way = 0; way < kWays[n]; ++way) {
                score_[std::size_t(v * kMaxWays + way)] += u * std::fabs(meet(way, at, n));
            }
        });
    }

    /// The piecewise value of voxel v (leaf offset), or false when fewer than two or more than
    /// three faces reach it, or stray samples carry more than kMaxStray of its weight (score()).
    /// The faces meet as their centroids say (centroid_meet) unless another way fits their
    /// samples at least 4/3 as well (its score below 3/4 of theirs; score()).
    bool value(int v, double voxel, double& out) const {
        const std::array<int, 3>& p = present_[std::size_t(v)];
        if (p[0] < 0) return false;
        const int n = p[2] < 0 ? 2 : 3;
        FaceSums present[3];
        double f[3];
        for (int j = 0; j < n; ++j) {
            present[j] = face_[std::size_t(v * faces_ + p[std::size_t(j)])];
            f[j] = present[j].field(voxel);
        }
        int way = centroid_meet(present, n, voxel);
        const double* sc = &score_[std::size_t(v * kMaxWays)];
        const int best = int(std::min_element(sc, sc + kWays[n]) - sc);
        if (sc[best] < 0.75 * sc[way]) way = best;
        out = meet(way, f, n);
        return true;
    }

  private:
    /// Each local sample's support within the leaf at `origin`: per axis the voxel range and,
    /// per voxel t of it, the offset e from the centre and the Gaussian factor. Made once for
    /// add() and score(), not twice (bunny at 0.5 mm, 1 thread, 75 leaves 16.4 -> 15.0 ms,
    /// median of 8).
    struct Axes {
        int lo[3], hi[3];
        double e[3][8], g[3][8];
    };
    void prepare(const LocalSamples& s, const openvdb::Coord& origin) {
        axes_.resize(s.size());
        for (std::size_t i = 0; i < s.size(); ++i) {
            const Kernel& k = s.kernel[i];
            const double c[3] = {k.cx, k.cy, k.cz};
            Axes& x = axes_[i];
            for (int a = 0; a < 3; ++a) {
                x.lo[a] = std::max(0, int(std::ceil(c[a] - k.r)) - origin[a]);
                x.hi[a] = std::min(7, int(std::floor(c[a] + k.r)) - origin[a]);
                for (int t = x.lo[a]; t <= x.hi[a]; ++t) {
                    x.e[a][t] = double(origin[a] + t) - c[a];
                    x.g[a][t] = std::exp(-(x.e[a][t] * x.e[a][t]) * k.inv_s2);
                }
            }
        }
    }

    /// Calls fn(sample, voxel offset, u, voxel - sample centre) for every voxel of the leaf
    /// within each local sample's support, in the samples' order (prepare() first).
    template <typename Fn>
    void reach(const LocalSamples& s, Fn&& fn) const {
        double e2[3][8];
        for (std::size_t i = 0; i < s.size(); ++i) {
            const Kernel& k = s.kernel[i];
            const Axes& x = axes_[i];
            const double r2 = double(k.r) * double(k.r);
            for (int a = 0; a < 3; ++a) {
                for (int t = x.lo[a]; t <= x.hi[a]; ++t) e2[a][t] = x.e[a][t] * x.e[a][t];
            }
            for (int ix = x.lo[0]; ix <= x.hi[0]; ++ix) {
                for (int iy = x.lo[1]; iy <= x.hi[1]; ++iy) {
                    const double dxy2 = e2[0][ix] + e2[1][iy];
                    if (dxy2 > r2) continue;
                    for (int iz = x.lo[2]; iz <= x.hi[2]; ++iz) {
                        if (dxy2 + e2[2][iz] > r2) continue;
                        const double u = double(k.amp) * x.g[0][ix] * x.g[1][iy] * x.g[2][iz];
                        fn(i, (ix << 6) | (iy << 3) | iz, u,
                           openvdb::Vec3d(x.e[0][ix], x.e[1][iy], x.e[2][iz]));
                    }
                }
            }
        }
    }

    int faces_ = 0;
    std::vector<FaceSums> face_;
    std::vector<double> all_, stray_;
    std::vector<std::array<int, 3>> present_;  ///< per voxel its 2-3 faces, or -1 first
    std::vector<double> score_;                ///< per voxel and way (score())
    std::vector<Axes> axes_;                   ///< per local sample (prepare())
};

}  // namespace

CreaseReach crease_reach(const std::vector<float>& radius) {
    CreaseReach reach;
    if (radius.empty()) return reach;
    reach.r_max = *std::max_element(radius.begin(), radius.end());
    // The crease test looks as far as most kernels reach (95 %): a crease only the widest
    // kernels see from a leaf leaves the splat's value there. The radii are >= 0 (0: a point
    // skipped); select_rank gives what nth_element would put at that rank, without reordering
    // them (nth_element took 3-4 ms of one thread on the bunny's 362k).
    reach.r_typical = select_rank(std::size_t(0.95 * double(radius.size() - 1)), radius);
    return reach;
}

CreaseStats sharpen_creases(openvdb::FloatTree& sdf, const Kernels& kernels, std::size_t points,
                            double voxel, double crease_angle, float background,
                            const CreaseReach& reach) {
    CreaseStats stats;
    if (!(crease_angle > 0.0)) return stats;
    const float r_max = reach.r_max, r_typical = reach.r_typical;
    const double cos_group = std::cos(0.5 * crease_angle), cos_crease = std::cos(crease_angle);
    const SampleCells cells(kernels, points, cos_group);
    const int margin = int(std::ceil(double(r_typical) / kCell));  // cells most kernels reach

    std::vector<openvdb::FloatTree::LeafNodeType*> leaves;
    sdf.getNodes(leaves);
    std::vector<std::size_t> candidates(leaves.size(), 0), modelled(leaves.size(), 0);
    // Each thread's samples and sums live through the loop (made per task, their arrays were
    // allocated and freed from both threads at once: detail/release.h, heap_lock).
    struct Scratch {
        LocalSamples s;
        LeafSums sums;
    };
    tbb::enumerable_thread_specific<Scratch> scratch;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size(), 4),
                      [&](const tbb::blocked_range<std::size_t>& range) {
        SampleCells::Accessor acc = cells.accessor();
        LocalSamples& s = scratch.local().s;
        LeafSums& sums = scratch.local().sums;
        for (std::size_t L = range.begin(); L < range.end(); ++L) {
            auto& leaf = *leaves[L];
            if (!leaf_near_crease(cells, acc, leaf.origin(), margin, cos_group, cos_crease)) {
                continue;
            }
            // Faces among the samples most kernels reach from the leaf first (cheap), then
            // among all the samples that reach it.
            gather(cells, acc, kernels, leaf.origin(), r_typical, s);
            if (assign_faces(s, cos_group, cos_crease) < 2) continue;
            gather(cells, acc, kernels, leaf.origin(), r_max, s);
            const int faces = assign_faces(s, cos_group, cos_crease);
            if (faces < 2) continue;
            sums.reset(faces);
            sums.add(s, leaf.origin(), voxel);
            sums.score(s, voxel, leaf.getValueMask());
            for (auto it = leaf.beginValueOn(); it; ++it) {
                ++candidates[L];
                double value = 0.0;
                if (!sums.value(int(it.pos()), voxel, value)) continue;
                ++modelled[L];
                it.setValue(float(std::clamp(value, -double(background), double(background))));
            }
        }
    });
    for (std::size_t L = 0; L < leaves.size(); ++L) {
        stats.candidates += candidates[L];
        stats.modelled += modelled[L];
    }
    return stats;
}

}  // namespace vdbrecon::detail
