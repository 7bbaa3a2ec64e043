// Splatting oriented points into sparse grids (see splat.h for the kernel and references).
//
// Determinism: every (block, point) pair is listed (a block is 2x2x2 leaves, 16^3 voxels), the
// list is sorted by (block key, point index), and each block is then summed by exactly one task
// in increasing point order. No floating-point sum depends on scheduling, so the grids are
// bit-identical for any thread count.
//
// Cost: the Gaussian is separable, exp(-|d|^2/s^2) = gx(dx) gy(dy) gz(dz), and the linear basis
// is additive, n.d = nx dx + ny dy + nz dz; per (block, point) piece two exponentials per axis
// are evaluated (the rest by recurrence), each row of the spherical support is one run of
// voxels, and the voxel loop is a handful of multiply-adds on per-block arrays of sums.
#include "vdbrecon/splat.h"

#include <openvdb/tools/SignedFloodFill.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <climits>
#include <cmath>
#include <limits>
#include <memory>
#include <numeric>
#include <optional>
#include <sstream>
#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "detail/cell_groups.h"
#include "detail/creases.h"
#include "detail/exp8.h"
#include "detail/fill_later.h"
#include "detail/io_common.h"
#include "detail/kernels.h"
#include "detail/radix_sort.h"
#include "detail/release.h"
#include "detail/select.h"
#include "detail/simd.h"
#include "detail/splat_frame.h"
#include "detail/volume_grids.h"
#include "vdbrecon/error.h"

namespace vdbrecon {

std::size_t memory_budget(const SplatOptions& options) {
    if (options.max_memory > 0) return options.max_memory;
    const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGE_SIZE);
    if (pages <= 0 || page <= 0) return std::size_t(8) << 30;  // unknown: assume 16 GB
    return std::size_t(pages) / 2 * std::size_t(page);
}

namespace {

/// "12.3 GB" / "456 MB".
std::string human_bytes(double bytes) {
    std::ostringstream s;
    s.precision(3);
    if (bytes >= 1e9) {
        s << bytes / 1e9 << " GB";
    } else {
        s << std::max(1.0, std::round(bytes / 1e6)) << " MB";
    }
    return s.str();
}

/// Refuses a run whose estimate exceeds the budget, before the big allocations. The volume
/// (and the mesh) grow with the surface area in voxels, i.e. about 1/voxel^2: the hint scales
/// the voxel by sqrt(need / budget) and a margin.
void check_memory(double need, const SplatOptions& options, const char* what) {
    const double budget = double(memory_budget(options));
    if (need <= budget) return;
    const double voxel = options.voxel_size * std::sqrt(need / budget) * 1.25;
    std::ostringstream s;
    s.precision(2);
    s << "splat: voxel size " << options.voxel_size << " needs about " << human_bytes(need)
      << " of memory (" << what << "), more than the budget of " << human_bytes(budget)
      << ". Hint: --voxel " << voxel << " or larger, or raise --max-memory";
    throw InvalidArgument(s.str());
}

}  // namespace

void SplatOptions::validate() const {
    auto positive = [](double v, const char* name) {
        if (!(std::isfinite(v) && v > 0.0)) {
            std::ostringstream s;
            s << "splat." << name << " = " << v << ": must be a positive number";
            throw InvalidArgument(s.str());
        }
    };
    positive(voxel_size, "voxel_size");
    positive(scale_factor, "scale_factor");
    positive(sigma_voxels, "sigma_voxels");
    positive(min_sigma_voxels, "min_sigma_voxels");
    positive(max_sigma_voxels, "max_sigma_voxels");
    if (min_sigma_voxels > max_sigma_voxels) {
        throw InvalidArgument("splat.min_sigma_voxels must not exceed splat.max_sigma_voxels");
    }
    if (!(support >= 1.0 && support <= 6.0)) {
        throw InvalidArgument("splat.support = " + std::to_string(support) +
                              ": must be in 1..6 (sigmas)");
    }
    if (!(std::isfinite(min_weight) && min_weight >= 0.0)) {
        throw InvalidArgument("splat.min_weight = " + std::to_string(min_weight) +
                              ": must be a non-negative number");
    }
    if (!(crease_angle >= 0.0 && crease_angle < 90.0)) {
        throw InvalidArgument("splat.crease_angle = " + std::to_string(crease_angle) +
                              ": must be in 0..90 degrees (0 = off)");
    }
    if (!(aggregate >= 0.0 && aggregate <= 4.0)) {
        throw InvalidArgument("splat.aggregate = " + std::to_string(aggregate) +
                              ": must be in 0..4 (sigmas; 0 = off)");
    }
    if (!(aggregate_max_cell >= 0.0 && std::isfinite(aggregate_max_cell))) {
        throw InvalidArgument("splat.aggregate_max_cell = " + std::to_string(aggregate_max_cell) +
                              ": must be a non-negative number (voxels; 0 = no cap)");
    }
}

namespace detail {

/// Grids that carry the sums from one splat to the next (SplatAccumulator): per voxel the
/// summed w, u and u * phi, the vector to the nearest sample so far (world units) and, with
/// colours, the summed u * rgb. Leaves exist wherever a kernel reached; each block's leaves are
/// read and written only by the task that sums that block.
struct SplatState {
    SplatOptions options;
    Vec3d origin{0.0, 0.0, 0.0};
    openvdb::FloatGrid::Ptr w = openvdb::FloatGrid::create(0.0f);
    openvdb::FloatGrid::Ptr u = openvdb::FloatGrid::create(0.0f);
    openvdb::FloatGrid::Ptr uphi = openvdb::FloatGrid::create(0.0f);
    openvdb::Vec3fGrid::Ptr nearest = openvdb::Vec3fGrid::create(openvdb::Vec3f(0.0f));
    openvdb::Vec3fGrid::Ptr color;  ///< u * rgb sums; null without colours
    bool colors = false, started = false;
    std::size_t points = 0, skipped = 0, updates = 0, clouds = 0;
    float max_r = 0.0f;  ///< largest kernel radius so far, voxels
    double sigma_min = std::numeric_limits<double>::infinity(), sigma_max = 0.0;
    std::vector<double> sigma_medians;  ///< one per cloud, world units
    /// The first cloud, not summed yet (owned): alone, its volume is made from its block sums,
    /// as splat() makes it; it is summed onto the grids when a second cloud comes.
    std::optional<PointCloud> first;
};

}  // namespace detail

namespace {

using detail::Kernel;
using detail::Kernels;
using detail::SplatState;

constexpr int kLeafLog2 = 3;  // 8^3 leaves, OpenVDB's default FloatTree leaf
constexpr int kLeafDim = 1 << kLeafLog2;
constexpr int kLeafVoxels = kLeafDim * kLeafDim * kLeafDim;
// Points are summed per block of 2x2x2 leaves: a kernel (usually 7 voxels across) is cut into
// fewer pieces by 16-voxel blocks than by 8-voxel leaves (2.3 instead of 5.2 per point on the
// bunny), and each piece costs a setup (its clipped box, six exp()) and shorter rows.
constexpr int kBlockLog2 = kLeafLog2 + 1;
constexpr int kBlockDim = 1 << kBlockLog2;
constexpr int kBlockVoxels = kBlockDim * kBlockDim * kBlockDim;
// Index coordinates stay within +-kMaxVoxelIndex (volume_grids.h): block coordinates then span
// at most 2^20 per axis, and a packed block key (BlockCodec) at most 60 bits.
using detail::kMaxVoxelIndex;

inline int floor_div_block(int v) {
    return v >= 0 ? v >> kBlockLog2 : -((-v + kBlockDim - 1) >> kBlockLog2);
}

/// Block coordinates packed into one key relative to the scan's lowest block, each axis in just
/// the bits its range needs, x high and z low: keys sort like (bx, by, bz), and a scan of a few
/// hundred blocks per axis is sorted in two 11-bit radix passes.
struct BlockCodec {
    int lo[3] = {0, 0, 0};
    int bits[3] = {0, 0, 0};

    int total() const { return bits[0] + bits[1] + bits[2]; }
    std::uint64_t pack(int bx, int by, int bz) const {
        return ((std::uint64_t(bx - lo[0]) << bits[1] | std::uint64_t(by - lo[1])) << bits[2]) |
               std::uint64_t(bz - lo[2]);
    }
    openvdb::Coord origin(std::uint64_t key) const {
        int b[3];
        for (int a = 2; a >= 0; --a) {
            b[a] = int(key & ((std::uint64_t(1) << bits[a]) - 1)) + lo[a];
            key >>= bits[a];
        }
        return openvdb::Coord(b[0] * kBlockDim, b[1] * kBlockDim, b[2] * kBlockDim);
    }
};

/// A (block, point) pair. Key = std::uint32_t (8-byte pairs) when the packed block keys fit 32
/// bits, as for any scan under ~1,600 blocks (26,000 voxels) across on each axis; else
/// std::uint64_t (16 bytes).
template <typename Key>
struct Pair {
    Key key;
    std::uint32_t point;
};
template <typename Key>
using PairList = detail::FillLater<Pair<Key>>;

struct Box {
    int lo[3], hi[3];
};

inline Box support_box(const Kernel& k) {
    Box b;
    const double c[3] = {k.cx, k.cy, k.cz};
    for (int a = 0; a < 3; ++a) {
        b.lo[a] = int(std::ceil(c[a] - k.r));
        b.hi[a] = int(std::floor(c[a] + k.r));
    }
    return b;
}

/// The part of box b inside the block at origin o, in block-local voxels [lo, hi] per axis;
/// false when they do not meet.
inline bool clip_to_block(const Box& b, const openvdb::Coord& o, int lo[3], int hi[3]) {
    for (int a = 0; a < 3; ++a) {
        lo[a] = std::max(b.lo[a], o[a]) - o[a];
        hi[a] = std::min(b.hi[a], o[a] + kBlockDim - 1) - o[a];
        if (hi[a] < lo[a]) return false;
    }
    return true;
}

/// The block's 8^3 leaves that the block-local box [lo, hi] (clip_to_block) reaches, bit
/// 4 x + 2 y + z for the leaf in half (x, y, z) of the block.
inline unsigned leaf_mask(const int lo[3], const int hi[3]) {
    // Per axis, the leaves in the halves the box reaches (index: bit 0 the low half, bit 1 the
    // high one); a leaf is reached when it is on every axis.
    static constexpr unsigned kAxisLeaves[3][4] = {
        {0x00, 0x0f, 0xf0, 0xff}, {0x00, 0x33, 0xcc, 0xff}, {0x00, 0x55, 0xaa, 0xff}};
    unsigned mask = 0xff;
    for (int a = 0; a < 3; ++a) {
        const unsigned halves = (lo[a] < kLeafDim ? 1u : 0u) | (hi[a] >= kLeafDim ? 2u : 0u);
        mask &= kAxisLeaves[a][halves];
    }
    return mask;
}

/// The blocks box b touches, block coordinates [lo, hi] per axis; false when the box is empty
/// (a kernel narrower than the voxel spacing can fall between voxels), which touches none. One
/// rule for counting, ranging and listing a point's pairs, so they always agree.
inline bool block_span(const Box& b, int lo[3], int hi[3]) {
    for (int a = 0; a < 3; ++a) {
        if (b.hi[a] < b.lo[a]) return false;
        lo[a] = floor_div_block(b.lo[a]);
        hi[a] = floor_div_block(b.hi[a]);
    }
    return true;
}

/// The blocks kernel k's support touches (block_span); false for a skipped kernel (r = 0) too.
/// The one test behind measure_kernels' pair counts and for_each_pair's listing: the listed
/// pairs fill an array sized by the counts, unzeroed.
inline bool kernel_span(const Kernel& k, int lo[3], int hi[3]) {
    return k.r > 0.0f && block_span(support_box(k), lo, hi);
}

using FloatLeaf = openvdb::FloatTree::LeafNodeType;
using Vec3Leaf = openvdb::Vec3fTree::LeafNodeType;

/// What one block contributes: the grids' leaves at its eight leaf places (none made where no
/// voxel is valid), counts.
struct BlockOut {
    detail::VolumeLeaves leaf[8];
    std::size_t updates = 0, touched = 0, active = 0;
    std::uint8_t leaves = 0;  ///< the leaves its kernels reach (leaf_mask)
};

/// Per-voxel sums of one block, as separate arrays: w, the averaging weight u = amp * w, u * phi,
/// and the nearest sample (squared distance, index units, and its point; the first sample in
/// point order wins ties). Float: a 16-voxel block row is one AVX-512 register, and each update
/// moves half the bytes of double sums (at 1 thread the splat took 0.448 -> 0.384 s on the
/// bunny at 0.5 mm). A voxel sums a few dozen to a few thousand terms; against double sums the
/// meshes moved by 3e-6 voxel on average, 1e-3 at most (bunny, dragon, Autzen; F and Chamfer
/// the same to 4 digits), and the grids between clouds were float already. Aligned for the
/// vector rows.
struct alignas(64) BlockSums {
    float w[kBlockVoxels], u[kBlockVoxels], uphi[kBlockVoxels], d2[kBlockVoxels];
    std::uint32_t nearest[kBlockVoxels];
};
/// Per-voxel colour sums of one block (u * rgb), one array per channel (the vector rows).
struct alignas(64) ColorSums {
    float r[kBlockVoxels], g[kBlockVoxels], b[kBlockVoxels];
};

/// One (block, point) piece: the kernel's box clipped to the block (block-local voxels lo..hi
/// per axis) and, per axis and voxel t of that range, the Gaussian factor g, the squared distance
/// d2 (index units) and the linear basis' share ph (world units), made in double and rounded
/// to the sums' float. Rows of a block's 16 voxels: the vector paths load whole rows and mask
/// out the entries outside the range (zero at first, then what earlier pieces left there).
struct Piece {
    int lo[3], hi[3];
    alignas(64) float g[3][kBlockDim];
    alignas(64) float d2[3][kBlockDim];
    alignas(64) float ph[3][kBlockDim];
    float r2, amp;
    std::uint32_t point;
};

/// Adds the piece to the sums, one spherical-support run of voxels per (x, y) row; returns the
/// number of voxel updates. The vector paths below make the same float operations in the same
/// order on every voxel (no FMA: fp-contract is off where the target has it).
template <bool kColors>
std::size_t add_piece(const Piece& p, const float* col, BlockSums& sums, ColorSums* csums) {
    std::size_t updates = 0;
    const float *gx = p.g[0], *gy = p.g[1], *gz = p.g[2];
    const float *dx2 = p.d2[0], *dy2 = p.d2[1], *dz2 = p.d2[2];
    const float *px = p.ph[0], *py = p.ph[1], *pz = p.ph[2];
    for (int x = p.lo[0]; x <= p.hi[0]; ++x) {
        for (int y = p.lo[1]; y <= p.hi[1]; ++y) {
            const float dxy2 = dx2[x] + dy2[y];
            if (dxy2 > p.r2) continue;
            // The row's voxels inside the spherical support: one run, as dz^2 is convex (and
            // rounding, monotone, keeps dxy2 + dz2 falling then rising).
            int z0 = p.lo[2], z1 = p.hi[2];
            while (z0 <= z1 && dxy2 + dz2[z0] > p.r2) ++z0;
            while (z1 >= z0 && dxy2 + dz2[z1] > p.r2) --z1;
            const float wxy = gx[x] * gy[y];
            const float pxy = px[x] + py[y];
            const int row = (x << (2 * kBlockLog2)) | (y << kBlockLog2);
            for (int z = z0; z <= z1; ++z) {
                const int i = row | z;
                const float d2 = dxy2 + dz2[z];
                const float w = wxy * gz[z];
                const float u = p.amp * w;
                sums.w[i] += w;
                sums.u[i] += u;
                sums.uphi[i] += u * (pxy + pz[z]);
                const bool nearer = d2 < sums.d2[i];
                sums.d2[i] = nearer ? d2 : sums.d2[i];
                sums.nearest[i] = nearer ? p.point : sums.nearest[i];
                if (kColors) {
                    csums->r[i] += u * col[0];
                    csums->g[i] += u * col[1];
                    csums->b[i] += u * col[2];
                }
            }
            updates += std::size_t(std::max(0, z1 - z0 + 1));
        }
    }
    return updates;
}

#ifdef VDBRECON_HAVE_AVX2_PATHS
/// Kernels wider than this (squared radius, voxels) take only their rows within the support's
/// disk in the vector paths below; narrower ones take every row of their box. Against every
/// row for all, splat at 1 thread: Autzen 0.163 -> 0.152 s, bunny, dragon, room, table the same
/// or less.
constexpr float kWideRows = 16.0f;

/// The rows y0..y1 of slice x a vector path takes: a wide kernel's within the support's disk
/// (dx^2 + dy^2 is convex in y), else the box's.
inline void row_run(const Piece& p, int x, bool wide, int& y0, int& y1) {
    y0 = p.lo[1];
    y1 = p.hi[1];
    if (!wide) return;
    const float dx2 = p.d2[0][x];
    while (y0 <= y1 && dx2 + p.d2[1][y0] > p.r2) ++y0;
    while (y1 >= y0 && dx2 + p.d2[1][y1] > p.r2) --y1;
}

/// add_piece eight voxels of a row at a time (AVX2), bit for bit the same sums: every voxel
/// sees the same float operations in the same order, lanes outside the piece's box or the
/// support add exact zeros (the sums are never -0) and keep their nearest sample. Lanes are the
/// aligned halves of the 16-voxel block row, so loads and stores stay inside the row.
template <bool kColors>
__attribute__((target("avx2"), optimize("fp-contract=off"))) std::size_t add_piece_avx2(
    const Piece& p, const float* col, BlockSums& sums, ColorSums* csums) {
    std::size_t updates = 0;
    __m256 rgb[3];
    for (int c = 0; c < 3; ++c) rgb[c] = _mm256_set1_ps(kColors ? col[c] : 0.0f);
    const __m256 r2 = _mm256_set1_ps(p.r2), amp = _mm256_set1_ps(p.amp);
    const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    const __m256i zlo = _mm256_set1_epi32(p.lo[2] - 1), zhi = _mm256_set1_epi32(p.hi[2] + 1);
    const __m256i point = _mm256_set1_epi32(int(p.point));
    const int zb0 = p.lo[2] & ~7;
    // The box part of each half's mask does not depend on the row.
    __m256 box[kBlockDim / 8];
    for (int zb = zb0; zb <= p.hi[2]; zb += 8) {
        const __m256i z = _mm256_add_epi32(_mm256_set1_epi32(zb), lane);
        box[zb >> 3] = _mm256_castsi256_ps(
            _mm256_and_si256(_mm256_cmpgt_epi32(z, zlo), _mm256_cmpgt_epi32(zhi, z)));
    }
    const float *dx2 = p.d2[0], *dy2 = p.d2[1];
    const bool wide = p.r2 > kWideRows;  // as add_piece_avx512's rows
    for (int x = p.lo[0]; x <= p.hi[0]; ++x) {
        int y0, y1;
        row_run(p, x, wide, y0, y1);
        for (int y = y0; y <= y1; ++y) {
            const float dxy2_s = dx2[x] + dy2[y];
            const __m256 dxy2 = _mm256_set1_ps(dxy2_s);
            const __m256 wxy = _mm256_set1_ps(p.g[0][x] * p.g[1][y]);
            const __m256 pxy = _mm256_set1_ps(p.ph[0][x] + p.ph[1][y]);
            const int row = (x << (2 * kBlockLog2)) | (y << kBlockLog2);
            for (int zb = zb0; zb <= p.hi[2]; zb += 8) {
                const __m256 d2 = _mm256_add_ps(dxy2, _mm256_load_ps(p.d2[2] + zb));
                const __m256 in = _mm256_and_ps(box[zb >> 3], _mm256_cmp_ps(d2, r2, _CMP_LE_OQ));
                const int m = _mm256_movemask_ps(in);
                updates += std::size_t(__builtin_popcount(unsigned(m)));
                const int i = row | zb;
                const __m256 w = _mm256_and_ps(in, _mm256_mul_ps(wxy, _mm256_load_ps(p.g[2] + zb)));
                const __m256 u = _mm256_mul_ps(amp, w);
                const __m256 uphi = _mm256_and_ps(
                    in, _mm256_mul_ps(u, _mm256_add_ps(pxy, _mm256_load_ps(p.ph[2] + zb))));
                _mm256_store_ps(sums.w + i, _mm256_add_ps(_mm256_load_ps(sums.w + i), w));
                _mm256_store_ps(sums.u + i, _mm256_add_ps(_mm256_load_ps(sums.u + i), u));
                _mm256_store_ps(sums.uphi + i, _mm256_add_ps(_mm256_load_ps(sums.uphi + i), uphi));
                const __m256 old = _mm256_load_ps(sums.d2 + i);
                const __m256 nearer = _mm256_and_ps(in, _mm256_cmp_ps(d2, old, _CMP_LT_OQ));
                _mm256_store_ps(sums.d2 + i, _mm256_blendv_ps(old, d2, nearer));
                auto* n = reinterpret_cast<__m256i*>(sums.nearest + i);
                _mm256_store_si256(n, _mm256_blendv_epi8(_mm256_load_si256(n), point,
                                                         _mm256_castps_si256(nearer)));
                if (kColors) {  // u is +0 on the lanes outside
                    float* to[3] = {csums->r + i, csums->g + i, csums->b + i};
                    for (int c = 0; c < 3; ++c) {
                        _mm256_store_ps(
                            to[c], _mm256_add_ps(_mm256_load_ps(to[c]), _mm256_mul_ps(u, rgb[c])));
                    }
                }
            }
        }
    }
    return updates;
}

/// add_piece_avx2 sixteen voxels at a time (AVX-512): a whole block row, one step per row of a
/// kernel's support. Lanes outside the piece's box or the support are masked off, and the sums
/// see the scalar loop's float operations in its order, so the result is the same bit for bit.
template <bool kColors>
__attribute__((target("avx512f,avx512vl"), optimize("fp-contract=off"))) std::size_t
add_piece_avx512(const Piece& p, const float* col, BlockSums& sums, ColorSums* csums) {
    std::size_t updates = 0;
    __m512 rgb[3];
    for (int c = 0; c < 3; ++c) rgb[c] = _mm512_set1_ps(kColors ? col[c] : 0.0f);
    const __m512 r2 = _mm512_set1_ps(p.r2), amp = _mm512_set1_ps(p.amp);
    const __m512i point = _mm512_set1_epi32(int(p.point));
    // The box part of the mask does not depend on the row.
    const __mmask16 box = __mmask16((0xffffu << p.lo[2]) & (0xffffu >> (15 - p.hi[2])));
    const __m512 dz2 = _mm512_load_ps(p.d2[2]), gz = _mm512_load_ps(p.g[2]);
    const __m512 pz = _mm512_load_ps(p.ph[2]);
    const float *dx2 = p.d2[0], *dy2 = p.d2[1];
    // A narrow kernel's rows: every row of the box, the corners outside the support with an
    // empty mask (a branch on the row was mispredicted often enough to cost more: bunny at
    // 0.5 mm, 1 thread, splat 0.380 -> 0.360 s; the AVX2 rows likewise). A wide one's: those
    // within the disk (row_run).
    const bool wide = p.r2 > kWideRows;
    for (int x = p.lo[0]; x <= p.hi[0]; ++x) {
        int y0, y1;
        row_run(p, x, wide, y0, y1);
        for (int y = y0; y <= y1; ++y) {
            const float dxy2_s = dx2[x] + dy2[y];
            const __m512 d2 = _mm512_add_ps(_mm512_set1_ps(dxy2_s), dz2);
            const __mmask16 in = _mm512_mask_cmp_ps_mask(box, d2, r2, _CMP_LE_OQ);
            updates += std::size_t(__builtin_popcount(unsigned(in)));
            const int i = (x << (2 * kBlockLog2)) | (y << kBlockLog2);
            const __m512 w = _mm512_mul_ps(_mm512_set1_ps(p.g[0][x] * p.g[1][y]), gz);
            const __m512 u = _mm512_mul_ps(amp, w);
            const __m512 uphi =
                _mm512_mul_ps(u, _mm512_add_ps(_mm512_set1_ps(p.ph[0][x] + p.ph[1][y]), pz));
            const __m512 sw = _mm512_load_ps(sums.w + i), su = _mm512_load_ps(sums.u + i);
            const __m512 sp = _mm512_load_ps(sums.uphi + i);
            _mm512_store_ps(sums.w + i, _mm512_mask_add_ps(sw, in, sw, w));
            _mm512_store_ps(sums.u + i, _mm512_mask_add_ps(su, in, su, u));
            _mm512_store_ps(sums.uphi + i, _mm512_mask_add_ps(sp, in, sp, uphi));
            const __mmask16 nearer =
                _mm512_mask_cmp_ps_mask(in, d2, _mm512_load_ps(sums.d2 + i), _CMP_LT_OQ);
            _mm512_mask_store_ps(sums.d2 + i, nearer, d2);
            _mm512_mask_store_epi32(sums.nearest + i, nearer, point);
            if (kColors) {
                float* to[3] = {csums->r + i, csums->g + i, csums->b + i};
                for (int c = 0; c < 3; ++c) {
                    const __m512 sc = _mm512_load_ps(to[c]);
                    _mm512_store_ps(to[c],
                                    _mm512_mask_add_ps(sc, in, sc, _mm512_mul_ps(u, rgb[c])));
                }
            }
        }
    }
    return updates;
}
#endif

/// The block index of leaf s's voxel v (s: which of the block's eight 8^3 leaves).
inline int block_index(int s, int v) {
    const int lx = (s >> 2) * kLeafDim, ly = ((s >> 1) & 1) * kLeafDim, lz = (s & 1) * kLeafDim;
    return ((lx + (v >> 6)) << (2 * kBlockLog2)) | ((ly + ((v >> 3) & 7)) << kBlockLog2) |
           (lz + (v & 7));
}
inline openvdb::Coord leaf_offset(int s) {
    return openvdb::Coord((s >> 2) * kLeafDim, ((s >> 1) & 1) * kLeafDim, (s & 1) * kLeafDim);
}

/// A voxel's sums, as emit_leaf() reads them.
struct VoxelSums {
    double w, u, uphi;
    openvdb::Vec3f nearest;  ///< voxel to nearest sample, world units
    double r, g, b;          ///< u * rgb
};

/// Whether a voxel with summed weight w is valid: w >= min_weight; or, within two voxels of the
/// surface (|sdf| <= 2 voxels), w >= min_weight / 5. The surface itself is kept where its
/// samples' kernels overlap thinly: past a convex corner whose estimated normals bend the
/// field's zero outward, a crossing cell's corners have a fifth to a half of the threshold (60k
/// samples on a cube, L-bracket and boss, 5 seeds, 1x and 1.5x, mc and dc: 267 -> 86 boundary
/// edges; 62 with min_weight / 5 everywhere). Farther out the band stays as it was (the bunny's
/// valid voxels +1.3 %, against +17 % with min_weight / 5 everywhere); what the thin overlap
/// adds past an open border is left to the support trims (mesh.h).
/// The weights are floats, so the thresholds are compared as the least floats at or above
/// them: the same outcome as comparing w in double with min_weight.
struct ValidRule {
    float full, low;  ///< min_weight and min_weight / 5 as the least floats at or above them
    double voxel;
    float background;

    ValidRule(double min_weight, double voxel_size, float band)
        : full(float_at_least(min_weight)),
          low(float_at_least(0.2 * min_weight)),
          voxel(voxel_size),
          background(band) {}

    static float float_at_least(double t) {
        float f = float(t);
        if (double(f) < t) f = std::nextafter(f, std::numeric_limits<float>::infinity());
        return f;
    }
};

/// The valid voxels of one leaf (ValidRule) as its value mask, from its weights a row of eight
/// voxels at a time (`at.w_row(r)`: the weights of leaf offsets 8 r .. 8 r + 7), without a
/// branch on the common outcomes (w = 0, w >= min_weight), which the band's ragged edge mixes
/// within a leaf; only the voxels in between look at their sdf (`at(v)`). Adds the voxels
/// summed (w > 0) to `touched`.
template <typename At>
openvdb::util::NodeMask<3> valid_mask(const At& at, const ValidRule& rule, std::size_t& touched) {
    openvdb::util::NodeMask<3> mask;  // all off
    std::uint64_t* words = &mask.template getWord<std::uint64_t>(0);
    for (int row = 0; row < kLeafVoxels / 8; ++row) {
        const float* w = at.w_row(row);
        unsigned summed = 0, full = 0, low = 0;
#if defined(__x86_64__)
        // Two halves of four (SSE2 is in every x86-64): ordered comparisons, false for a NaN
        // as the scalar ones.
        const __m128 zero = _mm_setzero_ps(), f = _mm_set1_ps(rule.full), l = _mm_set1_ps(rule.low);
        for (int h = 0; h < 2; ++h) {
            const __m128 x = _mm_loadu_ps(w + 4 * h);
            summed |= unsigned(_mm_movemask_ps(_mm_cmpgt_ps(x, zero))) << (4 * h);
            full |= unsigned(_mm_movemask_ps(_mm_cmpge_ps(x, f))) << (4 * h);
            low |= unsigned(_mm_movemask_ps(_mm_cmpge_ps(x, l))) << (4 * h);
        }
#else
        for (int z = 0; z < 8; ++z) {
            summed |= unsigned(w[z] > 0.0f) << z;
            full |= unsigned(w[z] >= rule.full) << z;
            low |= unsigned(w[z] >= rule.low) << z;
        }
#endif
        touched += std::size_t(__builtin_popcount(summed));
        unsigned valid = summed & full;
        for (unsigned mid = summed & ~full & low; mid != 0; mid &= mid - 1) {
            const int z = __builtin_ctz(mid);
            const VoxelSums x = at(row * 8 + z);
            const double sdf =
                std::clamp(x.uphi / x.u, -double(rule.background), double(rule.background));
            if (std::fabs(sdf) <= 2.0 * rule.voxel) valid |= 1u << z;
        }
        words[row >> 3] |= std::uint64_t(valid) << ((row & 7) * 8);
    }
    return mask;
}

/// One output leaf (sdf, weight, nearest and colour) at lo_world from the sums of its voxels
/// (`at(v)`, v the leaf offset): the valid voxels (valid_mask) get sdf = u phi / u (clamped to
/// the band), weight w, the nearest vector and the mean colour, written into the new leaves'
/// buffers. Nothing is made when no voxel is valid. The one rule for splat() and the
/// accumulator.
template <typename At>
void emit_leaf(const openvdb::Coord& lo_world, At&& at, bool colors, const ValidRule& rule,
               BlockOut& out, int s) {
    const openvdb::util::NodeMask<3> mask = valid_mask(at, rule, out.touched);
    const std::size_t active = mask.countOn();
    out.active += active;
    if (active == 0) return;
    const float background = rule.background;
    detail::VolumeLeaves& place = out.leaf[s];
    place.make(lo_world, background, colors);
    float* sdf = place.sdf->buffer().data();
    float* weight = place.weight->buffer().data();
    openvdb::Vec3f* nearest = place.nearest->buffer().data();
    openvdb::Vec3f* color = colors ? place.color->buffer().data() : nullptr;
    for (auto it = mask.beginOn(); it; ++it) {
        const int v = int(it.pos());
        const VoxelSums x = at(v);
        const double inv_u = 1.0 / x.u;
        sdf[v] = float(std::clamp(x.uphi * inv_u, -double(background), double(background)));
        weight[v] = float(x.w);
        nearest[v] = x.nearest;
        if (color)
            color[v] = openvdb::Vec3f(float(x.r * inv_u), float(x.g * inv_u), float(x.b * inv_u));
    }
    place.set_mask(mask);
}

constexpr std::uint32_t kNoPoint = std::numeric_limits<std::uint32_t>::max();

/// Loads the state's sums of the block at o into `sums` (zero where it has none); the nearest
/// sample of a loaded voxel is the state's (kNoPoint), until a nearer one comes.
void load_state(const SplatState& state, const openvdb::Coord& o, double voxel, BlockSums& sums,
                ColorSums* csums) {
    const double inv_voxel2 = 1.0 / (voxel * voxel);
    for (int s = 0; s < 8; ++s) {
        const openvdb::Coord lo = o + leaf_offset(s);
        const FloatLeaf* wl = state.w->tree().probeConstLeaf(lo);
        if (!wl) continue;
        // The leaves' value arrays directly (leaf order: x-major, rows of 8 along z).
        const float* w = wl->buffer().data();
        const float* u = state.u->tree().probeConstLeaf(lo)->buffer().data();
        const float* uphi = state.uphi->tree().probeConstLeaf(lo)->buffer().data();
        const openvdb::Vec3f* nearest = state.nearest->tree().probeConstLeaf(lo)->buffer().data();
        const openvdb::Vec3f* color =
            state.colors ? state.color->tree().probeConstLeaf(lo)->buffer().data() : nullptr;
        for (int v = 0; v < kLeafVoxels; ++v) {
            if (!(w[v] > 0.0f)) continue;
            const int i = block_index(s, v);
            sums.w[i] = w[v];
            sums.u[i] = u[v];
            sums.uphi[i] = uphi[v];
            sums.d2[i] = float(openvdb::Vec3d(nearest[v]).lengthSqr() * inv_voxel2);
            sums.nearest[i] = kNoPoint;
            if (color) {
                const openvdb::Vec3f& c = color[v];
                csums->r[i] = c[0];
                csums->g[i] = c[1];
                csums->b[i] = c[2];
            }
        }
    }
}

/// Writes the block's sums back to the state's leaves (made beforehand for every leaf a kernel
/// reaches). Values only: the state's grids mean "summed" by w > 0, not by active bits.
void store_state(SplatState& state, const openvdb::Coord& o, const Kernels& kernels, double voxel,
                 const BlockSums& sums, const ColorSums* csums) {
    for (int s = 0; s < 8; ++s) {
        const openvdb::Coord lo = o + leaf_offset(s);
        FloatLeaf* wl = state.w->tree().probeLeaf(lo);
        if (!wl) continue;
        float* w = wl->buffer().data();
        float* u = state.u->tree().probeLeaf(lo)->buffer().data();
        float* uphi = state.uphi->tree().probeLeaf(lo)->buffer().data();
        openvdb::Vec3f* nearest = state.nearest->tree().probeLeaf(lo)->buffer().data();
        openvdb::Vec3f* color = state.colors ? state.color->tree().probeLeaf(lo)->buffer().data() : nullptr;
        for (int v = 0; v < kLeafVoxels; ++v) {
            const int i = block_index(s, v);
            if (!(sums.w[i] > 0.0f)) continue;
            w[v] = sums.w[i];
            u[v] = sums.u[i];
            uphi[v] = sums.uphi[i];
            if (sums.nearest[i] != kNoPoint) {
                const openvdb::Vec3d k = kernels.centre(sums.nearest[i]);
                const openvdb::Coord c = FloatLeaf::offsetToLocalCoord(openvdb::Index(v)) + lo;
                nearest[v] = openvdb::Vec3f((k - c.asVec3d()) * voxel);
            }
            if (color) color[v] = openvdb::Vec3f(csums->r[i], csums->g[i], csums->b[i]);
        }
    }
}

/// Sums every (point, voxel) contribution of one 16^3 block, in increasing point order, onto
/// the state's sums when there is a state (and writes them back), else onto zero (and emits
/// the block's output leaves).
template <bool kColors, typename P>
void splat_block(const openvdb::Coord& o, const P* begin, const P* end, const Kernels& kernels,
                 const PointCloud& cloud, double voxel, const ValidRule& rule, int vector_rows,
                 SplatState* state, BlockSums& sums, ColorSums* csums, BlockOut& out) {
    std::fill(std::begin(sums.w), std::end(sums.w), 0.0f);
    std::fill(std::begin(sums.u), std::end(sums.u), 0.0f);
    std::fill(std::begin(sums.uphi), std::end(sums.uphi), 0.0f);
    std::fill(std::begin(sums.d2), std::end(sums.d2), std::numeric_limits<float>::infinity());
    if (kColors) {
        std::fill(std::begin(csums->r), std::end(csums->r), 0.0f);
        std::fill(std::begin(csums->g), std::end(csums->g), 0.0f);
        std::fill(std::begin(csums->b), std::end(csums->b), 0.0f);
    }
    if (state) load_state(*state, o, voxel, sums, csums);
    Piece p{};  // zeroed: the vector rows read (and mask out) lanes outside the box
    std::size_t updates = 0;
    constexpr std::ptrdiff_t kAhead = 8;  // pieces
    for (const P* q = begin; q != end; ++q) {
        if (end - q > kAhead) kernels.prefetch(q[kAhead].point);
        const Kernel k = kernels(q->point);
        if (!clip_to_block(support_box(k), o, p.lo, p.hi)) continue;
        out.leaves |= std::uint8_t(leaf_mask(p.lo, p.hi));
        const double inv_s2 = k.inv_s2;
        p.r2 = float(double(k.r) * double(k.r));
        p.amp = k.amp;
        p.point = q->point;
        // Gaussian on consecutive voxels by recurrence, two exponentials per axis instead of one
        // per voxel: g(d+1) = g(d) q(d), q(d) = exp(-(2d+1)/s^2), q(d+1) = q(d) exp(-2/s^2); the
        // seven made at once (exp8). The x factor carries the confidence (exactly 1 without one).
        const double c[3] = {k.cx, k.cy, k.cz};
        const float nc[3] = {k.nx, k.ny, k.nz};
        double arg[8] = {-2.0 * inv_s2}, e[8];
        for (int a = 0; a < 3; ++a) {
            const double d0 = double(o[a] + p.lo[a]) - c[a];  // index units
            arg[1 + 2 * a] = -d0 * d0 * inv_s2;
            arg[2 + 2 * a] = -(2.0 * d0 + 1.0) * inv_s2;
        }
        detail::exp8(arg, e, vector_rows);
        const double rho = e[0];
        for (int a = 0; a < 3; ++a) {
            double gt = e[1 + 2 * a] * (a == 0 ? double(k.conf) : 1.0);
            double qt = e[2 + 2 * a];
            for (int t = p.lo[a]; t <= p.hi[a]; ++t) {
                const double d = double(o[a] + t) - c[a];
                p.d2[a][t] = float(d * d);
                p.g[a][t] = float(gt);
                p.ph[a][t] = float(double(nc[a]) * d * voxel);  // world units
                gt *= qt;
                qt *= rho;
            }
        }
        const float* col = kColors ? cloud.colors[q->point].data() : nullptr;
#ifdef VDBRECON_HAVE_AVX2_PATHS
        if (vector_rows > 0) {
            updates += vector_rows == 2 ? add_piece_avx512<kColors>(p, col, sums, csums)
                                        : add_piece_avx2<kColors>(p, col, sums, csums);
            continue;
        }
#endif
        updates += add_piece<kColors>(p, col, sums, csums);
    }
    out.updates = updates;
    if (state) {
        store_state(*state, o, kernels, voxel, sums, csums);
        return;
    }
    // The block's eight leaves, each written only when one of its voxels is valid.
    for (int s = 0; s < 8; ++s) {
        struct At {
            const BlockSums& sums;
            const ColorSums* csums;
            const Kernels& kernels;
            openvdb::Coord lo_world;
            double voxel;
            int s;
            const float* w_row(int row) const { return sums.w + block_index(s, row * 8); }
            VoxelSums operator()(int v) const {
                const int i = block_index(s, v);
                // Stored as the vector from the voxel to the sample, world units.
                const openvdb::Vec3d k = kernels.centre(sums.nearest[i]);
                const openvdb::Coord c = FloatLeaf::offsetToLocalCoord(openvdb::Index(v)) + lo_world;
                const double ex = double(c[0]) - k[0], ey = double(c[1]) - k[1],
                             ez = double(c[2]) - k[2];
                VoxelSums x{sums.w[i], sums.u[i], sums.uphi[i],
                            openvdb::Vec3f(float(-ex * voxel), float(-ey * voxel), float(-ez * voxel)),
                            0, 0, 0};
                if (kColors) x.r = csums->r[i], x.g = csums->g[i], x.b = csums->b[i];
                return x;
            }
        };
        const openvdb::Coord lo_world = o + leaf_offset(s);
        emit_leaf(lo_world, At{sums, csums, kernels, lo_world, voxel, s}, kColors, rule, out, s);
    }
}

/// What sum_blocks() needs of splat().
struct BlockSetup {
    const Kernels& kernels;
    const BlockCodec& codec;
    const PointCloud& cloud;
    const SplatOptions& options;
    float background;  ///< the sdf's background, world units
    SplatState* state;  ///< sums carried over from earlier clouds (the accumulator), or null
};

/// The (block, point) pairs are listed, sorted and summed one slab of block x-coordinates at a
/// time, a slab holding at most this many pairs (or one x-column): a sorted list of 8-byte
/// pairs and the radix sort's copy of it are then at most 8 bytes per point of the cloud (its
/// own memory is 24 or more), instead of ~40 for all pairs at once; a cloud of up to 4M pairs
/// (the bunny scans: 1M) is one slab. Keys sort x first, so the slabs' blocks in slab order
/// are all blocks in key order: the result does not depend on the slabs.
std::size_t slab_pairs(std::size_t n, const SplatOptions& options) {
    if (options.slab_pairs > 0) return options.slab_pairs;
    return std::max<std::size_t>(std::size_t(1) << 22, n / 2);
}

/// The pairs of point i's kernel with blocks whose x-coordinate is in [x0, x1]: calls
/// fn(bx, by, bz) for each, in (bx, by, bz) order; returns their count.
template <typename Fn>
std::size_t for_each_pair(const Kernels& kernels, std::size_t i, int x0, int x1, Fn&& fn) {
    int lo[3], hi[3];
    const Kernel k = kernels(i, false);
    if (!kernel_span(k, lo, hi)) return 0;
    lo[0] = std::max(lo[0], x0);
    hi[0] = std::min(hi[0], x1);
    std::size_t count = 0;
    for (int bx = lo[0]; bx <= hi[0]; ++bx) {
        for (int by = lo[1]; by <= hi[1]; ++by) {
            for (int bz = lo[2]; bz <= hi[2]; ++bz) {
                fn(bx, by, bz);
                ++count;
            }
        }
    }
    return count;
}

/// Makes the state's leaves (in all its grids) that the blocks' kernels reach and do not exist
/// yet (serially: the tree's structure changes); returns the state's leaf count, for the
/// memory estimate.
template <typename Key>
std::size_t make_state_leaves(SplatState& state, const BlockCodec& codec,
                              const PairList<Key>& pairs,
                              const std::vector<std::size_t>& block_begin,
                              const std::vector<std::uint8_t>& touched_leaves) {
    for (std::size_t B = 0; B + 1 < block_begin.size(); ++B) {
        const openvdb::Coord o = codec.origin(pairs[block_begin[B]].key);
        for (int s = 0; s < 8; ++s) {
            if (!(touched_leaves[B] >> s & 1u)) continue;
            const openvdb::Coord lo = o + leaf_offset(s);
            if (state.w->tree().probeConstLeaf(lo)) continue;
            state.w->tree().touchLeaf(lo);
            state.u->tree().touchLeaf(lo);
            state.uphi->tree().touchLeaf(lo);
            state.nearest->tree().touchLeaf(lo);
            if (state.colors) state.color->tree().touchLeaf(lo);
        }
    }
    return state.w->tree().leafCount();
}

/// The slabs of block x-columns [x0, x1] (see slab_pairs): each holds at most `limit` pairs, or
/// one column; *largest is the pairs of the largest. `total`: all pairs.
std::vector<std::pair<int, int>> plan_slabs(const Kernels& kernels, int x_lo, int x_hi,
                                            std::size_t limit, std::size_t total,
                                            std::size_t* largest) {
    *largest = total;
    if (total <= limit) return {{x_lo, x_hi}};
    // Per-thread counts, added up (integers: the same for any thread count).
    const std::size_t columns = std::size_t(x_hi - x_lo + 1);
    tbb::enumerable_thread_specific<std::vector<std::size_t>> per_thread(
        [columns] { return std::vector<std::size_t>(columns, 0); });
    detail::for_each_chunk(kernels.size(), [&](std::size_t, std::size_t begin, std::size_t end) {
        std::vector<std::size_t>& column = per_thread.local();
        for (std::size_t i = begin; i < end; ++i) {
            for_each_pair(kernels, i, x_lo, x_hi, [&](int bx, int, int) { ++column[std::size_t(bx - x_lo)]; });
        }
    });
    std::vector<std::size_t> column(columns, 0);
    for (const auto& local : per_thread) {
        for (std::size_t x = 0; x < columns; ++x) column[x] += local[x];
    }
    std::vector<std::pair<int, int>> slabs;
    *largest = 0;
    std::size_t in_slab = 0;
    for (int x = x_lo; x <= x_hi; ++x) {
        const std::size_t c = column[std::size_t(x - x_lo)];
        if (in_slab > 0 && in_slab + c > limit) {
            *largest = std::max(*largest, in_slab);
            in_slab = 0;
        }
        if (in_slab == 0) slabs.push_back({x, x});
        slabs.back().second = x;
        in_slab += c;
    }
    *largest = std::max(*largest, in_slab);
    return slabs;
}

/// The pairs of each chunk of points (detail::for_each_chunk) in each slab: [chunk][slab].
std::vector<std::size_t> pairs_per_slab(const Kernels& kernels, const std::vector<std::pair<int, int>>& slabs,
                                        std::vector<std::size_t> chunk_pairs, int x_lo, int x_hi) {
    if (slabs.size() == 1) return chunk_pairs;
    std::vector<std::size_t> in_slab(chunk_pairs.size() * slabs.size(), 0);
    detail::for_each_chunk(kernels.size(), [&](std::size_t c, std::size_t begin, std::size_t end) {
        std::vector<std::size_t> count(slabs.size(), 0);  // stored once (see above)
        std::size_t s = 0;  // the slab of the last column seen (columns come in order)
        for (std::size_t i = begin; i < end; ++i) {
            for_each_pair(kernels, i, x_lo, x_hi, [&](int bx, int, int) {
                while (bx > slabs[s].second) ++s;
                while (bx < slabs[s].first) --s;
                ++count[s];
            });
        }
        std::copy(count.begin(), count.end(), in_slab.begin() + std::ptrdiff_t(c * slabs.size()));
    });
    return in_slab;
}

/// The 8^3 leaves (of its eight) each block's kernels touch, as bit masks: for the memory
/// estimate and the state's leaves.
template <typename Key>
std::vector<std::uint8_t> touched_leaf_masks(const Kernels& kernels, const BlockCodec& codec,
                                             const PairList<Key>& pairs,
                                             const std::vector<std::size_t>& block_begin) {
    const std::size_t num_blocks = block_begin.size() - 1;
    std::vector<std::uint8_t> touched(num_blocks, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, num_blocks, 64),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t B = rg.begin(); B < rg.end(); ++B) {
            const openvdb::Coord o = codec.origin(pairs[block_begin[B]].key);
            unsigned mask = 0;
            for (std::size_t j = block_begin[B]; j < block_begin[B + 1]; ++j) {
                int lo[3], hi[3];
                if (!clip_to_block(support_box(kernels(pairs[j].point, false)), o, lo, hi)) continue;
                mask |= leaf_mask(lo, hi);
            }
            touched[B] = std::uint8_t(mask);
        }
    });
    return touched;
}

/// A block's sums (147 kB, and 98 kB of colour sums) per thread, not per task: allocated
/// between the blocks' leaves, a task's sums left a hole in the one heap that the next task's
/// did not fit, and the heap grew (bunny 10 %: its resident size varied from run to run by 10 MB).
struct BlockScratch {
    std::unique_ptr<BlockSums> sums;
    std::unique_ptr<ColorSums> csums;
};

/// One slab's blocks (block x-coordinates [x0, x1]): its pairs listed in point order and
/// sorted, the memory budget checked on its leaves (`num_leaves`: those of earlier slabs,
/// updated), and every block summed, appended to `blocks` in key order.
template <typename Key>
void sum_slab(const BlockSetup& setup, int x0, int x1, const std::vector<std::size_t>& chunk_first,
              tbb::enumerable_thread_specific<BlockScratch>& scratch_per_thread,
              std::size_t& num_leaves, std::vector<BlockOut>& blocks) {
    const Kernels& kernels = setup.kernels;
    const BlockCodec& codec = setup.codec;
    PairList<Key> pairs(chunk_first.back());  // not zeroed: the loop below writes every pair
    detail::for_each_chunk(kernels.size(), [&](std::size_t c, std::size_t begin, std::size_t end) {
        std::size_t o = chunk_first[c];
        for (std::size_t i = begin; i < end; ++i) {
            for_each_pair(kernels, i, x0, x1, [&](int bx, int by, int bz) {
                pairs[o++] = {Key(codec.pack(bx, by, bz)), std::uint32_t(i)};
            });
        }
    });
    // A stable radix sort of pairs made in point order: (key, point) order.
    detail::radix_sort(pairs, codec.total(), [](const Pair<Key>& p) { return p.key; });
    std::vector<std::size_t> block_begin;
    for (std::size_t i = 0; i < pairs.size(); ++i) {
        if (i == 0 || pairs[i].key != pairs[i - 1].key) block_begin.push_back(i);
    }
    block_begin.push_back(pairs.size());
    const std::size_t num_blocks = block_begin.size() - 1;
    // The budget on the leaves: eight a block at most, a bound that costs nothing. Only where it
    // exceeds the budget, or an accumulator's state needs them made first, are the leaves the
    // kernels reach counted before the sums (a pass over the pairs, ~5 % of the splat on the
    // bunny); otherwise the sums count them (BlockOut::leaves), the same number.
    const auto need = [&](std::size_t leaves) {
        return double(kernels.size()) * 64.0 + double(leaves) * double(SplatOptions::kBytesPerLeaf);
    };
    const bool count_first = setup.state != nullptr || need(num_leaves + 8 * num_blocks) >
                                                           double(memory_budget(setup.options));
    if (count_first) {
        std::vector<std::uint8_t> touched = touched_leaf_masks(kernels, codec, pairs, block_begin);
        for (std::uint8_t m : touched) num_leaves += std::size_t(__builtin_popcount(m));
        if (setup.state) num_leaves = make_state_leaves(*setup.state, codec, pairs, block_begin, touched);
        std::ostringstream what;
        what << num_leaves << " leaves of 8^3 voxels";
        check_memory(need(num_leaves), setup.options, what.str().c_str());
    }
    const bool colors = setup.cloud.has_colors();
    const double voxel = setup.options.voxel_size;
    const ValidRule rule(setup.options.min_weight, voxel, setup.background);
    // 2: AVX-512 rows, 1: AVX2 rows, 0: the scalar loop.
    const int vector_rows = detail::vector_loops() ? (detail::wide_vector_loops() ? 2 : 1) : 0;
    const std::size_t first_block = blocks.size();
    blocks.resize(first_block + num_blocks);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, num_blocks, 1),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        BlockScratch& scratch = scratch_per_thread.local();
        if (!scratch.sums) scratch.sums = std::make_unique<BlockSums>();
        if (colors && !scratch.csums) scratch.csums = std::make_unique<ColorSums>();
        for (std::size_t B = rg.begin(); B < rg.end(); ++B) {
            const Pair<Key>* b = pairs.data() + block_begin[B];
            const Pair<Key>* e = pairs.data() + block_begin[B + 1];
            BlockOut& out = blocks[first_block + B];
            if (colors) {
                splat_block<true>(codec.origin(b->key), b, e, kernels, setup.cloud, voxel, rule,
                                  vector_rows, setup.state, *scratch.sums, scratch.csums.get(),
                                  out);
            } else {
                splat_block<false>(codec.origin(b->key), b, e, kernels, setup.cloud, voxel, rule,
                                   vector_rows, setup.state, *scratch.sums, scratch.csums.get(),
                                   out);
            }
        }
    });
    if (!count_first) {
        for (std::size_t B = 0; B < num_blocks; ++B) {
            num_leaves += std::size_t(__builtin_popcount(blocks[first_block + B].leaves));
        }
    }
}

/// Lists the (block, point) pairs, sorts them, checks the memory budget and sums every block,
/// a slab of blocks at a time (see slab_pairs): the blocks' outputs in key order.
/// `chunk_pairs`: the pairs of the points of each chunk (detail::for_each_chunk), `x_hi` the
/// highest block x-coordinate.
template <typename Key>
std::vector<BlockOut> sum_blocks(const BlockSetup& setup, std::vector<std::size_t> chunk_pairs,
                                 int x_hi) {
    const std::size_t n = setup.kernels.size();
    const std::size_t total = std::accumulate(chunk_pairs.begin(), chunk_pairs.end(), std::size_t(0));
    const int x_lo = setup.codec.lo[0];
    std::size_t largest = 0;
    const std::vector<std::pair<int, int>> slabs =
        plan_slabs(setup.kernels, x_lo, x_hi, slab_pairs(n, setup.options), total, &largest);
    // Memory budget, first on the (block, point) pairs of a slab and the sort's copy of them,
    // then (sum_slab) on the distinct leaves.
    const double point_bytes = double(n) * 64.0;  // the cloud
    check_memory(point_bytes + 2.0 * double(largest) * sizeof(Pair<Key>), setup.options,
                 "for the index of the leaves its kernels touch");
    const std::size_t chunks = chunk_pairs.size();
    const std::vector<std::size_t> in_slab =
        pairs_per_slab(setup.kernels, slabs, std::move(chunk_pairs), x_lo, x_hi);
    std::vector<BlockOut> blocks;
    tbb::enumerable_thread_specific<BlockScratch> scratch_per_thread;
    std::size_t num_leaves = 0;
    for (std::size_t slab = 0; slab < slabs.size(); ++slab) {
        std::vector<std::size_t> chunk_first(chunks + 1, 0);
        for (std::size_t c = 0; c < chunks; ++c) {
            chunk_first[c + 1] = chunk_first[c] + in_slab[c * slabs.size() + slab];
        }
        sum_slab<Key>(setup, slabs[slab].first, slabs[slab].second, chunk_first, scratch_per_thread,
                      num_leaves, blocks);
    }
    return blocks;
}

/// What summing one cloud found.
struct CloudSums {
    std::vector<BlockOut> blocks;  ///< splat() only: an accumulator's sums go to its state
    float max_r = 0.0f;            ///< largest kernel radius, voxels
    float r_typical = 0.0f;        ///< the crease test's typical reach (measure_kernels)
    std::vector<std::size_t> chunk_pairs;  ///< each chunk's (block, point) pairs
    int block_lo[3] = {INT_MAX, INT_MAX, INT_MAX}, block_hi[3] = {INT_MIN, INT_MIN, INT_MIN};
    float background = 0.0f;       ///< the band's half width, world units
    double sigma_min = 0.0, sigma_median = 0.0, sigma_max = 0.0;  ///< world units
    std::size_t skipped = 0;       ///< points without a usable normal or confidence
};

void check_cloud(const PointCloud& cloud) {
    if (cloud.empty()) throw InvalidArgument("splat: the point cloud is empty");
    if (!cloud.has_normals()) {
        throw InvalidArgument("splat: the points have no normals. Hint: estimate them first "
                              "(--normals estimate)");
    }
}

/// What measure_kernels gathers from one chunk of kernels.
struct ChunkMeasure {
    double index = 0.0;  ///< largest |centre coordinate|, index units
    float r = 0.0f;      ///< largest radius, voxels
    std::size_t skipped = 0, pairs = 0;
    int lo[3] = {INT_MAX, INT_MAX, INT_MAX}, hi[3] = {INT_MIN, INT_MIN, INT_MIN};  ///< blocks

    /// Counts the (block, point) pairs of kernel k and widens the blocks' range by its span.
    void add_pairs(const Kernel& k) {
        int blo[3], bhi[3];
        if (!kernel_span(k, blo, bhi)) return;
        std::size_t count = 1;
        for (int a = 0; a < 3; ++a) {
            count *= std::size_t(bhi[a] - blo[a] + 1);
            lo[a] = std::min(lo[a], blo[a]);
            hi[a] = std::max(hi[a], bhi[a]);
        }
        pairs += count;
    }
    void merge(const ChunkMeasure& m) {
        index = std::max(index, m.index);
        r = std::max(r, m.r);
        skipped += m.skipped;
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], m.lo[a]);
            hi[a] = std::max(hi[a], m.hi[a]);
        }
    }
};

/// Narrow-band half width: no |sdf| can exceed the largest support radius (voxels).
float band_background(float max_r, double voxel) {
    return float(std::max(3.0, std::ceil(double(max_r))) * voxel);
}

/// The kernels' range and sigmas, in one pass over them: refuses clouds no kernel of which is
/// usable and voxels the index range or OpenVDB's transforms cannot take; counts each chunk's
/// (block, point) pairs and the range of blocks they touch for sum_kernels (the kernels' boxes
/// do not depend on the area normalisation set after this); with `reach`, the crease test's
/// reach (detail::crease_reach) from the same kernels.
void measure_kernels(const Kernels& kernels, double voxel, CloudSums& out, bool reach = false) {
    const std::size_t n = kernels.size();
    const std::size_t chunks = detail::chunk_count(n);
    std::vector<ChunkMeasure> chunk(chunks);
    std::vector<float> sigmas(n);  // voxels; -1 for a skipped point
    std::vector<float> radius(reach ? n : 0);
    detail::for_each_chunk(n, [&](std::size_t c, std::size_t begin, std::size_t end) {
        // In locals, stored once: neighbouring chunks' entries share a cache line, and writing
        // them per point made the two threads take it from each other (bunny: 7 ms -> 2 ms).
        ChunkMeasure m;
        for (std::size_t i = begin; i < end; ++i) {
            const Kernel k = kernels(i, false);
            m.index = std::max({m.index, std::fabs(k.cx), std::fabs(k.cy), std::fabs(k.cz)});
            m.r = std::max(m.r, k.r);
            m.skipped += k.r == 0.0f;
            sigmas[i] = k.r == 0.0f ? -1.0f : k.s;
            if (reach) radius[i] = k.r;
            m.add_pairs(k);
        }
        chunk[c] = m;
    });

    // Range check before any big allocation.
    ChunkMeasure all;
    for (const ChunkMeasure& m : chunk) all.merge(m);
    out.max_r = all.r;
    out.skipped = all.skipped;
    detail::check_kernel_range(all.index, all.r, out.skipped, n, voxel);
    out.chunk_pairs.resize(chunks);
    for (std::size_t c = 0; c < chunks; ++c) out.chunk_pairs[c] = chunk[c].pairs;
    std::copy(all.lo, all.lo + 3, out.block_lo);
    std::copy(all.hi, all.hi + 3, out.block_hi);
    if (reach) out.r_typical = detail::crease_reach(radius).r_typical;

    // Sigma statistics (world units). The median by select_rank (a histogram, then a small
    // selection) rather than nth_element over every sigma (3-4 ms of one thread on the bunny):
    // the -1 of a skipped point orders after every sigma (its sign bit), so rank valid / 2 among
    // all of them is the valid ones' median.
    {
        const std::size_t valid = n - out.skipped;
        out.sigma_median = double(detail::select_rank(valid / 2, sigmas)) * voxel;
        float lo = std::numeric_limits<float>::max(), hi = 0.0f;
        for (const float s : sigmas) {
            if (s == -1.0f) continue;
            lo = std::min(lo, s);
            hi = std::max(hi, s);
        }
        out.sigma_min = double(lo) * voxel;
        out.sigma_max = double(hi) * voxel;
    }
}

/// Lists, sorts and sums the (block, point) pairs of measured kernels (measure_kernels).
void sum_kernels(const Kernels& kernels, const PointCloud& cloud, const SplatOptions& options,
                 SplatState* state, CloudSums& out) {
    const double voxel = options.voxel_size;
    BlockCodec codec;
    for (int a = 0; a < 3; ++a) {
        const int lo = out.block_lo[a], hi = out.block_hi[a];
        if (lo > hi) break;  // no kernel reaches a voxel: no pairs, the default codec
        codec.lo[a] = lo;
        while (std::uint32_t(hi - lo) >> codec.bits[a]) ++codec.bits[a];
    }
    out.background = band_background(out.max_r, voxel);
    BlockSetup setup{kernels, codec, cloud, options, out.background, state};
    const int x_hi = out.block_lo[0] > out.block_hi[0] ? 0 : out.block_hi[0];
    out.blocks = codec.total() <= 32
                     ? sum_blocks<std::uint32_t>(setup, std::move(out.chunk_pairs), x_hi)
                     : sum_blocks<std::uint64_t>(setup, std::move(out.chunk_pairs), x_hi);
}

/// The output grids.
struct Grids {
    openvdb::FloatGrid::Ptr sdf, weight;
    openvdb::Vec3fGrid::Ptr nearest, color;
};

/// The blocks' leaves put into trees (serial; leaves are disjoint, so the order does not
/// matter); throws NumericalError when no voxel is valid.
Grids assemble(std::vector<BlockOut>& blocks, bool colors, float background,
               const SplatOptions& options, SplatResult& result) {
    const double voxel = options.voxel_size;
    Grids g;
    g.sdf = openvdb::FloatGrid::create(background);
    g.weight = openvdb::FloatGrid::create(0.0f);
    g.nearest = openvdb::Vec3fGrid::create(openvdb::Vec3f(0.0f));
    if (colors) g.color = openvdb::Vec3fGrid::create(openvdb::Vec3f(0.0f));
    detail::VolumeTrees trees(*g.sdf, *g.weight, *g.nearest, g.color.get());
    for (BlockOut& l : blocks) {
        result.updates += l.updates;
        result.touched_voxels += l.touched;
        result.active_voxels += l.active;
        for (detail::VolumeLeaves& leaves : l.leaf) result.leaves += leaves.add_to(trees);
    }
    if (result.active_voxels == 0) {
        std::ostringstream s;
        s << "splat: no voxel reached the minimum weight " << options.min_weight
          << " (the points are too sparse for voxel " << voxel
          << "). Hint: a larger --voxel or a smaller --min-weight";
        throw NumericalError(s.str());
    }
    return g;
}

/// The volume of finished grids: signs flood-filled, transforms, names and metadata.
void finish_volume(Grids g, const Vec3d& origin, std::size_t points, const SplatOptions& options,
                   SplatResult& result) {
    result.points = points;
    const double voxel = options.voxel_size;
    auto &sdf = g.sdf, &weight = g.weight;
    auto &nearest = g.nearest, &color = g.color;
    result.volume = detail::make_volume(sdf, weight, nearest, color, voxel, origin);
    Volume& vol = result.volume;
    std::ostringstream k;
    k << "gaussian w = exp(-d^2/sigma^2), support " << options.support
      << " sigma, linear basis n.(x-p), averaged with (sigma_median/sigma)^2 w";
    vol.metadata["kernel"] = k.str();
    vol.metadata["sigma_median"] = std::to_string(result.sigma_median);
    vol.metadata["sigma_min"] = std::to_string(result.sigma_min);
    vol.metadata["sigma_max"] = std::to_string(result.sigma_max);
    vol.metadata["scale_factor"] = std::to_string(options.scale_factor);
    vol.metadata["min_weight"] = detail::format_number(options.min_weight);  // exact: the closing reads it
    vol.metadata["crease_angle"] = std::to_string(options.crease_angle);
    vol.metadata["points"] = std::to_string(points);
    result.memory_bytes = vol.memory_bytes();
}

/// A leaf at `origin`, all voxels off, with its buffer allocated but not filled.
template <typename Leaf>
std::unique_ptr<Leaf> unfilled_leaf(const openvdb::Coord& origin) {
    auto leaf = std::make_unique<Leaf>(openvdb::PartialCreate(), origin,
                                       typename Leaf::ValueType(0), false);
    leaf->buffer().allocate();
    return leaf;
}

}  // namespace

void detail::VolumeLeaves::make(const openvdb::Coord& origin, float background, bool colors) {
    {
        const tbb::spin_mutex::scoped_lock lock(detail::heap_lock());
        sdf = unfilled_leaf<FloatLeaf>(origin);
        weight = unfilled_leaf<FloatLeaf>(origin);
        nearest = unfilled_leaf<Vec3Leaf>(origin);
        if (colors) color = unfilled_leaf<Vec3Leaf>(origin);
    }
    std::fill(sdf->buffer().data(), sdf->buffer().data() + FloatLeaf::SIZE, background);
    std::fill(weight->buffer().data(), weight->buffer().data() + FloatLeaf::SIZE, 0.0f);
    std::fill(nearest->buffer().data(), nearest->buffer().data() + Vec3Leaf::SIZE,
              openvdb::Vec3f(0.0f));
    if (color) {
        std::fill(color->buffer().data(), color->buffer().data() + Vec3Leaf::SIZE,
                  openvdb::Vec3f(0.0f));
    }
}

void detail::VolumeLeaves::set_mask(const openvdb::util::NodeMask<3>& mask) {
    sdf->setValueMask(mask);
    weight->setValueMask(mask);
    nearest->setValueMask(mask);
    if (color) color->setValueMask(mask);
}

bool detail::VolumeLeaves::add_to(VolumeTrees& trees) {
    if (!sdf) return false;
    trees.sdf_.addLeaf(sdf.release());
    trees.weight_.addLeaf(weight.release());
    trees.nearest_.addLeaf(nearest.release());
    if (trees.color_ && color) trees.color_->addLeaf(color.release());
    return true;
}

Volume detail::make_volume(openvdb::FloatGrid::Ptr sdf, openvdb::FloatGrid::Ptr weight,
                           openvdb::Vec3fGrid::Ptr nearest, openvdb::Vec3fGrid::Ptr color,
                           double voxel, const Vec3d& origin) {
    // Inactive values take the sign of their neighbourhood (a proper narrow-band level set).
    openvdb::tools::signedFloodFill(sdf->tree());
    openvdb::math::Transform::Ptr xform = openvdb::math::Transform::createLinearTransform(voxel);
    xform->postTranslate(openvdb::Vec3d(origin[0], origin[1], origin[2]));
    sdf->setTransform(xform);
    sdf->setName("sdf");
    sdf->setGridClass(openvdb::GRID_LEVEL_SET);
    weight->setTransform(xform->copy());
    weight->setName("weight");
    nearest->setTransform(xform->copy());
    nearest->setName("nearest");
    nearest->setVectorType(openvdb::VEC_CONTRAVARIANT_RELATIVE);
    if (color) {
        color->setTransform(xform->copy());
        color->setName("color");
        color->setVectorType(openvdb::VEC_INVARIANT);
    }
    Volume vol;
    vol.sdf = sdf;
    vol.weight = weight;
    vol.nearest = nearest;
    vol.color = color;
    vol.voxel_size = voxel;
    vol.origin = origin;
    return vol;
}

namespace {

/// splat(), in the whole cloud's frame (frame == nullptr: this cloud's own). `samples`: the
/// samples the crease model reads when `cloud` holds their presummed groups (nullptr: cloud).
SplatResult splat_cloud(const PointCloud& cloud, const SplatOptions& options,
                        const detail::KernelFrame* frame, const PointCloud* samples = nullptr) {
    options.validate();
    initialize_openvdb();
    check_cloud(cloud);
    const double voxel = options.voxel_size;
    SplatResult result;
    // Per-point kernels, made when needed; first their range, sigmas and usable normals.
    Kernels kernels(cloud, options);
    CloudSums sums;
    measure_kernels(kernels, voxel, sums, !frame && options.crease_angle > 0.0);
    result.skipped_points = sums.skipped;
    result.samples = cloud.size();
    result.sigma_min = sums.sigma_min;
    result.sigma_median = sums.sigma_median;
    result.sigma_max = sums.sigma_max;
    detail::CreaseReach reach;
    if (frame) {
        result.sigma_median = frame->sigma_median;
        sums.max_r = frame->max_r;  // the band's half width
        reach = {frame->max_r, frame->r_typical};
    } else if (options.crease_angle > 0.0) {
        reach = {sums.max_r, sums.r_typical};
    }
    // Area normalisation: every sample's kernel carries the same mass, so where fine and coarse
    // samples overlap the fine ones (smaller footprint, usually the more accurate, e.g. not at a
    // grazing angle) dominate -- the scale weighting of FSSR.
    kernels.set_median_sigma(result.sigma_median / voxel);
    sum_kernels(kernels, cloud, options, nullptr, sums);
    Grids g = assemble(sums.blocks, cloud.has_colors(), sums.background, options, result);
    // Next to sharp creases, the field of each face on its own, combined as the solid they
    // bound, from the samples themselves (groups would blend a crease's few samples).
    std::optional<Kernels> sample_kernels;
    if (samples) {
        sample_kernels.emplace(*samples, options);
        sample_kernels->set_median_sigma(result.sigma_median / voxel);
    }
    const Kernels& crease_kernels = sample_kernels ? *sample_kernels : kernels;
    const detail::CreaseStats creases =
        detail::sharpen_creases(g.sdf->tree(), crease_kernels, crease_kernels.size(), voxel,
                                options.crease_angle * M_PI / 180.0, sums.background, reach);
    result.crease_voxels = creases.modelled;
    finish_volume(std::move(g), cloud.origin, cloud.size(), options, result);
    return result;
}

}  // namespace

SplatResult splat(const PointCloud& cloud, const SplatOptions& options) {
    if (!(options.aggregate > 0.0)) return splat_cloud(cloud, options, nullptr);
    // The groups' kernels in the samples' frame (median sigma, band, crease reach), as the
    // tiles of the same cloud splat them (tiles.cpp).
    const detail::KernelFrame frame = detail::kernel_frame(cloud, options);
    SplatResult r = splat_cloud(detail::presum(cloud, options), options, &frame, &cloud);
    r.samples = cloud.size();
    r.skipped_points = frame.skipped;
    return r;
}

PointCloud detail::presum(const PointCloud& cloud, const SplatOptions& options) {
    if (!(options.aggregate > 0.0)) return cloud.view();
    options.validate();  // before the cells are made from it
    return presum_in_cells(cloud.view(), options, PresumCells::of_splat(options),
                           options.crease_angle > 0.0 ? options.crease_angle : 90.0);
}

void detail::check_kernel_range(double max_index, float max_r, std::size_t skipped,
                                std::size_t n, double voxel) {
    if (skipped == n) {
        throw InvalidArgument("splat: none of the " + std::to_string(n) +
                              " points has a usable (non-zero, finite) normal");
    }
    if (max_index + max_r > kMaxVoxelIndex) {
        std::ostringstream s;
        s << "splat: voxel size " << voxel << " is too small for this scan: it would need "
          << std::ceil(max_index + max_r) << " voxels from the origin along one axis (limit "
          << kMaxVoxelIndex << "). Hint: use a larger --voxel";
        throw InvalidArgument(s.str());
    }
    if (voxel < SplatOptions::kMinVoxelSize) {
        std::ostringstream s;
        s << "splat: voxel size " << voxel << " is below " << SplatOptions::kMinVoxelSize
          << " world units, the smallest OpenVDB's transforms accept. Hint: express the scan in "
             "smaller units (e.g. millimetres instead of metres)";
        throw InvalidArgument(s.str());
    }
}

void detail::kernel_sizes(const PointCloud& cloud, const SplatOptions& options,
                          std::vector<float>& sigma, std::vector<float>& radius,
                          double& max_index) {
    options.validate();
    check_cloud(cloud);
    const Kernels kernels(cloud, options);
    const std::size_t n = cloud.size();
    sigma.resize(n);
    radius.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
        const Kernel k = kernels(i, false);
        max_index = std::max({max_index, std::fabs(k.cx), std::fabs(k.cy), std::fabs(k.cz)});
        radius[i] = k.r;
        sigma[i] = k.r == 0.0f ? -1.0f : k.s;
    }
}

detail::KernelFrame detail::kernel_frame(const PointCloud& cloud, const SplatOptions& options) {
    options.validate();
    check_cloud(cloud);
    Kernels kernels(cloud, options);
    CloudSums sums;
    measure_kernels(kernels, options.voxel_size, sums, true);
    KernelFrame frame;
    frame.sigma_median = sums.sigma_median;
    frame.max_r = sums.max_r;
    frame.r_typical = sums.r_typical;
    frame.skipped = sums.skipped;
    return frame;
}

SplatResult detail::splat_in_frame(const PointCloud& cloud, const SplatOptions& options,
                                   const KernelFrame& frame, const PointCloud* samples) {
    return splat_cloud(cloud, options, &frame, samples);
}

SplatAccumulator::SplatAccumulator(const SplatOptions& options, const Vec3d& origin)
    : state_(std::make_unique<detail::SplatState>()) {
    options.validate();
    initialize_openvdb();
    state_->options = options;
    state_->origin = origin;
}
SplatAccumulator::~SplatAccumulator() = default;
SplatAccumulator::SplatAccumulator(SplatAccumulator&&) noexcept = default;
SplatAccumulator& SplatAccumulator::operator=(SplatAccumulator&&) noexcept = default;

const SplatOptions& SplatAccumulator::options() const { return state_->options; }
const Vec3d& SplatAccumulator::origin() const { return state_->origin; }
std::size_t SplatAccumulator::clouds() const { return state_->clouds + (state_->first ? 1 : 0); }
std::size_t SplatAccumulator::points() const {
    return state_->points + (state_->first ? state_->first->size() : 0);
}

std::size_t SplatAccumulator::memory_bytes() const {
    const SplatState& st = *state_;
    return std::size_t(st.w->memUsage() + st.u->memUsage() + st.uphi->memUsage() +
                       st.nearest->memUsage() + (st.color ? st.color->memUsage() : 0)) +
           (st.first ? st.first->memory_bytes() : 0);
}

namespace {

/// The kernels of a cloud added to an accumulator, measured, with the voxel as the area
/// normalisation's reference sigma: a constant factor of every u, which cancels in
/// u phi / u, so clouds added apart still mix correctly.
Kernels added_kernels(const PointCloud& cloud, const SplatOptions& options, CloudSums& sums) {
    Kernels kernels(cloud, options);
    measure_kernels(kernels, options.voxel_size, sums);
    kernels.set_median_sigma(1.0);
    return kernels;
}

/// Sums a cloud onto the state's grids.
void sum_onto(SplatState& st, const PointCloud& cloud) {
    CloudSums sums;
    const Kernels kernels = added_kernels(cloud, st.options, sums);
    sum_kernels(kernels, cloud, st.options, &st, sums);
    for (const BlockOut& b : sums.blocks) st.updates += b.updates;
    st.points += cloud.size();
    st.skipped += sums.skipped;
    st.clouds += 1;
    st.max_r = std::max(st.max_r, sums.max_r);
    st.sigma_min = std::min(st.sigma_min, sums.sigma_min);
    st.sigma_max = std::max(st.sigma_max, sums.sigma_max);
    st.sigma_medians.push_back(sums.sigma_median);
}

/// The volume of an accumulator that holds one cloud: its blocks' sums made into output leaves
/// directly, as splat() does (no crease model).
SplatResult single_cloud_result(const SplatOptions& options, const PointCloud& cloud) {
    CloudSums sums;
    const Kernels kernels = added_kernels(cloud, options, sums);
    sum_kernels(kernels, cloud, options, nullptr, sums);
    SplatResult result;
    result.skipped_points = sums.skipped;
    result.samples = cloud.size();
    result.sigma_min = sums.sigma_min;
    result.sigma_median = sums.sigma_median;
    result.sigma_max = sums.sigma_max;
    Grids g = assemble(sums.blocks, cloud.has_colors(), sums.background, options, result);
    finish_volume(std::move(g), cloud.origin, cloud.size(), options, result);
    result.volume.metadata["clouds"] = "1";
    result.volume.metadata["crease_angle"] = "0";
    return result;
}

/// The cloud with arrays of its own (a borrowed column is copied).
PointCloud owned(PointCloud c) {
    c.positions.edit();
    c.normals.edit();
    c.colors.edit();
    c.scales.edit();
    c.confidences.edit();
    return c;
}

}  // namespace

void SplatAccumulator::add(PointCloud cloud) {
    SplatState& st = *state_;
    check_cloud(cloud);
    if (cloud.origin != st.origin) {
        throw InvalidArgument("splat: a cloud added to an accumulator must share its origin");
    }
    if (st.started && cloud.has_colors() != st.colors) {
        throw InvalidArgument("splat: every cloud added to an accumulator must have colours, or "
                              "none");
    }
    if (!st.started) {
        st.started = true;
        st.colors = cloud.has_colors();
        st.first = owned(std::move(cloud));  // summed when a second cloud comes
        return;
    }
    if (st.first) {
        if (st.colors) st.color = openvdb::Vec3fGrid::create(openvdb::Vec3f(0.0f));
        const PointCloud first = std::move(*st.first);
        st.first.reset();
        sum_onto(st, first);
    }
    sum_onto(st, cloud);
}

namespace {

/// Frees a leaf's values (it reads as zeros afterwards); the leaf stays in its tree. For the
/// leaves of a state being consumed, which are not const (see accumulated_result).
template <typename Leaf>
void free_values(const Leaf* leaf) {
    typename Leaf::Buffer none(openvdb::PartialCreate(), typename Leaf::ValueType{});
    const_cast<Leaf*>(leaf)->buffer().swap(none);
}

/// The volume of an accumulator's sums (SplatAccumulator::result). With `consume`, st is
/// `consume`'s state: each leaf's values are freed as soon as its output leaf is made, so that
/// the output grids take the memory of the sums instead of more (the state is then spent).
SplatResult accumulated_result(const SplatState& st, SplatState* consume) {
    if (st.clouds == 0) throw InvalidArgument("splat: nothing was added to the accumulator");
    const SplatOptions& options = st.options;
    SplatResult result;
    result.skipped_points = st.skipped;
    result.sigma_min = st.sigma_min;
    result.sigma_max = st.sigma_max;
    std::vector<double> medians = st.sigma_medians;  // the median of the clouds' medians
    std::nth_element(medians.begin(), medians.begin() + std::ptrdiff_t(medians.size() / 2),
                     medians.end());
    result.sigma_median = medians[medians.size() / 2];
    const float background = band_background(st.max_r, options.voxel_size);
    struct At {
        const FloatLeaf *wl, *ul, *uphil;
        const Vec3Leaf *nearestl, *colorl;
        double w(int v) const { return double(wl->getValue(openvdb::Index(v))); }
        const float* w_row(int row) const { return wl->buffer().data() + row * 8; }
        VoxelSums operator()(int v) const {
            const auto i = openvdb::Index(v);
            VoxelSums x{w(v), double(ul->getValue(i)), double(uphil->getValue(i)),
                        nearestl->getValue(i), 0, 0, 0};
            if (colorl) {
                const openvdb::Vec3f c = colorl->getValue(i);
                x.r = double(c[0]), x.g = double(c[1]), x.b = double(c[2]);
            }
            return x;
        }
    };
    // One output leaf per state leaf, in parallel (each task writes its own BlockOut).
    std::vector<At> leaves;
    leaves.reserve(st.w->tree().leafCount());
    for (auto it = st.w->tree().cbeginLeaf(); it; ++it) {
        const openvdb::Coord lo = it->origin();
        leaves.push_back({&*it, st.u->tree().probeConstLeaf(lo), st.uphi->tree().probeConstLeaf(lo),
                          st.nearest->tree().probeConstLeaf(lo),
                          st.colors ? st.color->tree().probeConstLeaf(lo) : nullptr});
    }
    std::vector<BlockOut> blocks(leaves.size());
    const ValidRule rule(options.min_weight, options.voxel_size, background);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size(), 16),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t j = rg.begin(); j < rg.end(); ++j) {
            const At& at = leaves[j];
            emit_leaf(at.wl->origin(), at, st.colors, rule, blocks[j], 0);
            if (!consume) continue;
            free_values(at.wl);
            free_values(at.ul);
            free_values(at.uphil);
            free_values(at.nearestl);
            if (at.colorl) free_values(at.colorl);
        }
    });
    result.updates = st.updates;
    Grids g = assemble(blocks, st.colors, background, options, result);
    finish_volume(std::move(g), st.origin, st.points, options, result);
    result.volume.metadata["clouds"] = std::to_string(st.clouds);
    result.volume.metadata["crease_angle"] = "0";
    return result;
}

}  // namespace

SplatResult SplatAccumulator::result() const {
    if (state_->first) return single_cloud_result(state_->options, *state_->first);
    return accumulated_result(*state_, nullptr);
}

SplatResult SplatAccumulator::take_result() {
    SplatResult r = state_->first ? single_cloud_result(state_->options, *state_->first)
                                  : accumulated_result(*state_, state_.get());
    auto fresh = std::make_unique<detail::SplatState>();
    fresh->options = state_->options;
    fresh->origin = state_->origin;
    state_ = std::move(fresh);
    return r;
}

}  // namespace vdbrecon
