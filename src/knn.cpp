// Exact kNN on a Morton-ordered cell grid (see knn.h).
//
// A cube around the points is divided into 2^L cells per axis, L chosen so that an occupied cell
// holds about kPerCell points on average. The points are sorted by the Morton code of their
// cell (ties in input order), so that the points of any cell of any coarser level (a prefix of
// the code) are one contiguous run, and kept in that order as separate x, y, z arrays; the runs
// of the level-L cells are listed once (cell code and first point), and found by a hash table
// of their codes.
//
// Queries go cell by cell: the candidates of all queries in a cell are the points of its 3x3x3
// block of cells, gathered once into contiguous arrays; each query measures them all (an AVX2
// loop where the CPU has one, else one the compiler vectorises), keeps those within a bound
// from the previous query's answer (and of those, when more than k, the ones within 1.25 times
// that answer's k-th squared distance), and makes its list of the k smallest of them, ordered
// by (distance, point index) so that the answer does not depend on the gathering order: with
// AVX-512 by ranking up to 48 at once (rank_select_avx512), else by insertion into a list of
// up to 16 held in registers, a key taking its place without a branch. A cell of very many
// queries and candidates (a stack of duplicates) has its queries split among the threads.
// The answer is exact when the k-th distance is
// smaller than the distance from the query to the outside of the block, which no point outside
// the block can beat; otherwise (sparse regions, stray points, queries outside the cube) the
// query is repeated on the block of its cell at the next coarser level, down to level 0, where
// the block is the whole cube. Exact ties are broken by the point index, so the result is
// deterministic and independent of the thread count.
//
// This is the "cell list" of molecular dynamics with a space-filling-curve order (e.g.
// H. Samet, "Foundations of Multidimensional and Metric Data Structures", 2006, on Morton
// order; the level choice from the occupied-cell count of each level is ours). It replaces
// FLANN's kd-tree: 5x faster on the bunny scans at 2 threads (bench/knn.sh), mostly because it
// builds in parallel and shares each cell's candidates among its queries.
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "detail/fill_later.h"
#include "detail/knn_flann.h"
#include "detail/radix_sort.h"
#include "detail/select.h"
#include "detail/simd.h"
#include "vdbrecon/error.h"
#include "vdbrecon/knn.h"

namespace vdbrecon {

namespace {

/// A point's (or query's) Morton code and index, sorted by code (no initialisers: arrays of
/// them are filled in parallel, not zeroed first).
struct Coded {
    std::uint64_t code;
    std::uint32_t i;
};

constexpr int kBits = 21;               ///< finest level: 2^21 cells per axis
/// Target mean points per occupied cell. Measured: with 16 instead of 12 the outlier stage
/// (k = 16) took 7-11 % less at 1 thread on the bunny, dragon, Kinect and Autzen scans, the same
/// on the room and Redwood ones; 8 took 30 % more, 20-32 a few per cent more than 16.
constexpr double kPerCell = 16.0;

/// The 27 cells of a block, nearest first (centre, faces, edges, corners), so that a query's
/// list of the best fills with near points early and rejects most of the rest at once.
constexpr int kBlockOrder[27][3] = {
    {0, 0, 0},   {-1, 0, 0},  {1, 0, 0},   {0, -1, 0},  {0, 1, 0},   {0, 0, -1},   {0, 0, 1},
    {-1, -1, 0}, {-1, 1, 0},  {1, -1, 0},  {1, 1, 0},   {-1, 0, -1}, {-1, 0, 1},   {1, 0, -1},
    {1, 0, 1},   {0, -1, -1}, {0, -1, 1},  {0, 1, -1},  {0, 1, 1},   {-1, -1, -1}, {-1, -1, 1},
    {-1, 1, -1}, {-1, 1, 1},  {1, -1, -1}, {1, -1, 1},  {1, 1, -1},  {1, 1, 1}};

/// Spreads the low 21 bits of v to every third bit.
std::uint64_t spread(std::uint64_t v) {
    v &= 0x1fffff;
    v = (v | v << 32) & 0x1f00000000ffffULL;
    v = (v | v << 16) & 0x1f0000ff0000ffULL;
    v = (v | v << 8) & 0x100f00f00f00f00fULL;
    v = (v | v << 4) & 0x10c30c30c30c30c3ULL;
    v = (v | v << 2) & 0x1249249249249249ULL;
    return v;
}

/// Inverse of spread().
std::uint32_t compact(std::uint64_t v) {
    v &= 0x1249249249249249ULL;
    v = (v | v >> 2) & 0x10c30c30c30c30c3ULL;
    v = (v | v >> 4) & 0x100f00f00f00f00fULL;
    v = (v | v >> 8) & 0x1f0000ff0000ffULL;
    v = (v | v >> 16) & 0x1f00000000ffffULL;
    v = (v | v >> 32) & 0x1fffff;
    return std::uint32_t(v);
}

std::uint64_t morton(std::uint32_t x, std::uint32_t y, std::uint32_t z) {
    return spread(x) << 2 | spread(y) << 1 | spread(z);
}

/// A (squared distance, point index) pair as one integer that orders like the pair: the bits of
/// a non-negative float order like its value.
std::uint64_t pair_key(float d, int id) {
    std::uint32_t bits;
    std::memcpy(&bits, &d, sizeof bits);
    return std::uint64_t(bits) << 32 | std::uint32_t(id);
}

/// Marks an empty place of Best: above every key of a distance (the float bits of a NaN), and
/// positive as a signed integer, as the vector comparison needs.
constexpr std::uint64_t kNoKey = 0x7fffffffffffffffULL;

#ifdef VDBRECON_HAVE_AVX2_PATHS
/// Best::select's insertions for lists of 4 R keys (R <= 4, so k <= 16, the sizes the pipeline asks
/// for), held in registers. A candidate below the k-th kept key enters without a branch on its
/// place: every place takes its own key, the new one or its left neighbour's, as Best::offer
/// does. `last` = k - 1 is the place of the k-th key. The same lists as the scalar path.
template <int R>
__attribute__((target("avx2"))) void offer_avx2(int last, std::uint64_t* keys, const float* d,
                                                const int* ids, const std::uint32_t* keep,
                                                std::size_t kept, int self) {
    __m256i a[R];
    for (int r = 0; r < R; ++r) {
        a[r] = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(keys + 4 * r));
    }
    // The k-th key is read back from its register, not from memory, which would wait for the
    // store of the whole register.
    const int l = last % 4;
    const __m256i pick = _mm256_setr_epi32(2 * l, 2 * l + 1, 0, 0, 0, 0, 0, 0);
    std::uint64_t limit = keys[last];
    for (std::size_t i = 0; i < kept; ++i) {
        const std::uint32_t j = keep[i];
        const std::uint64_t key = pair_key(d[j], ids[j]);
        if (key >= limit || ids[j] == self) continue;
        const __m256i x = _mm256_set1_epi64x(std::int64_t(key));
        __m256i carry = x, carry_gt = _mm256_setzero_si256();
        for (int r = 0; r < R; ++r) {
            const __m256i gt = _mm256_cmpgt_epi64(a[r], x);
            // Each place's left neighbour, [carry, a0, a1, a2], and whether it is above the key.
            const __m256i left =
                _mm256_blend_epi32(_mm256_permute4x64_epi64(a[r], 0x90), carry, 0x03);
            const __m256i left_gt =
                _mm256_blend_epi32(_mm256_permute4x64_epi64(gt, 0x90), carry_gt, 0x03);
            carry = _mm256_permute4x64_epi64(a[r], 0xff);
            carry_gt = _mm256_permute4x64_epi64(gt, 0xff);
            a[r] = _mm256_blendv_epi8(a[r], _mm256_blendv_epi8(x, left, left_gt), gt);
        }
        limit = std::uint64_t(
            _mm_cvtsi128_si64(_mm256_castsi256_si128(_mm256_permutevar8x32_epi32(a[R - 1], pick))));
    }
    for (int r = 0; r < R; ++r) {
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(keys + 4 * r), a[r]);
    }
}

/// offer_avx2 with lists of 8 keys to a register (AVX-512, R <= 2, so k <= 16): a place's left
/// neighbour comes from valignq, the comparisons are masks. The same lists as the scalar path.
template <int R>
__attribute__((target("avx512f"))) void offer_avx512(int last, std::uint64_t* keys, const float* d,
                                                     const int* ids, const std::uint32_t* keep,
                                                     std::size_t kept, int self) {
    __m512i a[R];
    for (int r = 0; r < R; ++r) a[r] = _mm512_loadu_si512(keys + 8 * r);
    const __m512i pick = _mm512_set1_epi64(last % 8);
    std::uint64_t limit = keys[last];
    for (std::size_t i = 0; i < kept; ++i) {
        const std::uint32_t j = keep[i];
        const std::uint64_t key = pair_key(d[j], ids[j]);
        if (key >= limit || ids[j] == self) continue;
        const __m512i x = _mm512_set1_epi64(std::int64_t(key));
        __m512i carry = x;
        for (int r = 0; r < R; ++r) {
            // Each place's left neighbour, [carry, a0 .. a6], and whether it and the place are
            // above the key (compared, not shifted from one mask to the other: mask shifts go
            // through a general register, a longer chain).
            const __m512i left = _mm512_maskz_alignr_epi64(0xff, a[r], carry, 7);
            const __mmask8 gt = _mm512_cmpgt_epi64_mask(a[r], x);
            const __mmask8 left_gt = _mm512_cmpgt_epi64_mask(left, x);
            carry = a[r];
            a[r] = _mm512_mask_blend_epi64(gt, a[r], _mm512_mask_blend_epi64(left_gt, x, left));
        }
        // (The zero-masked forms: GCC 12's unmasked ones start from an "undefined" vector that
        // -Wmaybe-uninitialized reports.)
        limit = std::uint64_t(_mm_cvtsi128_si64(_mm512_maskz_extracti32x4_epi32(
            0xf, _mm512_maskz_permutexvar_epi64(0xff, pick, a[R - 1]), 0)));
    }
    for (int r = 0; r < R; ++r) _mm512_storeu_si512(keys + 8 * r, a[r]);
}

/// The most candidates rank_select_avx512 takes at once (six registers of keys); above it each
/// candidate's rank costs more compares than offer_avx512's insertions.
constexpr std::size_t kRankSelectMax = 48;

/// Best::select into a list of up to 16 places, by rank instead of insertion: each
/// candidate's rank is the count of candidates' keys below its own (the keys are distinct, but
/// for kNoKey, which marks `self`), counted for eight keys to a register at once, and the
/// candidates of rank below k are scattered to their places. No candidate waits on the one
/// before (insertion is one chain of dependent steps per candidate entering). The same list as
/// the other paths: the k smallest keys, ascending, kNoKey past the candidates.
__attribute__((target("avx512f"))) void rank_select_avx512(int k, std::uint64_t* keys,
                                                           const float* d, const int* ids,
                                                           const std::uint32_t* keep,
                                                           std::size_t kept, int self) {
    alignas(64) std::uint64_t cand[kRankSelectMax];
    const std::size_t regs = (kept + 7) / 8;
    for (std::size_t i = 0; i < kept; ++i) {
        const std::uint32_t j = keep[i];
        cand[i] = ids[j] == self ? kNoKey : pair_key(d[j], ids[j]);
    }
    for (std::size_t i = kept; i < regs * 8; ++i) cand[i] = kNoKey;
    __m512i c[kRankSelectMax / 8], rank[kRankSelectMax / 8];
    for (std::size_t r = 0; r < regs; ++r) {
        c[r] = _mm512_load_si512(cand + 8 * r);
        rank[r] = _mm512_setzero_si512();
    }
    const __m512i one = _mm512_set1_epi64(1);
    for (std::size_t i = 0; i < kept; ++i) {
        const __m512i x = _mm512_set1_epi64(std::int64_t(cand[i]));
        for (std::size_t r = 0; r < regs; ++r) {
            rank[r] =
                _mm512_mask_add_epi64(rank[r], _mm512_cmpgt_epi64_mask(c[r], x), rank[r], one);
        }
    }
    const __m512i places = _mm512_set1_epi64(k);
    for (std::size_t r = 0; r < regs; ++r) {
        // kNoKey (self, padding) ranks after every real key; where it lands among the first k
        // places, it writes the empty mark that is there already.
        const __mmask8 in = _mm512_cmplt_epi64_mask(rank[r], places);
        _mm512_mask_i64scatter_epi64(keys, in, rank[r], c[r], 8);
    }
}
#endif

/// The k smallest pair keys seen so far, ascending, in a list whose empty places hold kNoKey
/// (k rounded up to a multiple of 4 places, of 8 for the AVX-512 lists; those past the k-th are
/// never read).
class Best {
  public:
    explicit Best(int k)
        : k_(k),
          wide_(detail::wide_vector_loops()),
          key_(std::size_t(wide_ ? (k + 7) / 8 * 8 : (k + 3) / 4 * 4)),
          vector_(detail::vector_loops()) {
        clear();
    }
    void clear() { std::fill(key_.begin(), key_.end(), kNoKey); }
    int k() const { return k_; }
    bool full() const { return key_[std::size_t(k_ - 1)] != kNoKey; }
    /// Keys from this one up cannot enter: the last kept key once full, else none.
    std::uint64_t limit() const { return full() ? key_[std::size_t(k_ - 1)] : ~std::uint64_t(0); }
    /// The k-th squared distance once full, else infinity.
    float worst() const { return full() ? dist(k_ - 1) : std::numeric_limits<float>::infinity(); }
    /// Inserts `key` in order; the largest key falls off the end.
    void offer(std::uint64_t key) {
        std::uint64_t* k = key_.data();
        int j = int(key_.size()) - 1;
        while (j > 0 && k[j - 1] > key) {
            k[j] = k[j - 1];
            --j;
        }
        k[j] = key;
    }
    /// The list of the k smallest of the candidates keep[0 .. kept) of a block (squared
    /// distances d, indices ids) alone, the point `self` left out.
    void select(const float* d, const int* ids, const std::uint32_t* keep, std::size_t kept,
                int self) {
        clear();
#ifdef VDBRECON_HAVE_AVX2_PATHS
        if (wide_ && key_.size() <= 16 && kept <= kRankSelectMax) {
            return rank_select_avx512(k_, key_.data(), d, ids, keep, kept, self);
        }
        if (wide_ && key_.size() <= 16) {
            std::uint64_t* k = key_.data();
            return key_.size() == 8 ? offer_avx512<1>(k_ - 1, k, d, ids, keep, kept, self)
                                    : offer_avx512<2>(k_ - 1, k, d, ids, keep, kept, self);
        }
        if (vector_) {
            std::uint64_t* k = key_.data();
            switch (key_.size()) {
            case 4: return offer_avx2<1>(k_ - 1, k, d, ids, keep, kept, self);
            case 8: return offer_avx2<2>(k_ - 1, k, d, ids, keep, kept, self);
            case 12: return offer_avx2<3>(k_ - 1, k, d, ids, keep, kept, self);
            case 16: return offer_avx2<4>(k_ - 1, k, d, ids, keep, kept, self);
            default: break;
            }
        }
#endif
        std::uint64_t lim = limit();
        for (std::size_t i = 0; i < kept; ++i) {
            const std::uint32_t j = keep[i];
            const std::uint64_t key = pair_key(d[j], ids[j]);
            if (key >= lim || ids[j] == self) continue;
            offer(key);
            lim = limit();
        }
    }
    float dist(int j) const {
        const std::uint32_t bits = std::uint32_t(key_[std::size_t(j)] >> 32);
        float d;
        std::memcpy(&d, &bits, sizeof d);
        return d;
    }
    int id(int j) const { return int(std::uint32_t(key_[std::size_t(j)])); }

  private:
    int k_;
    bool wide_;  ///< select() by AVX-512 (lists of up to 16)
    std::vector<std::uint64_t> key_;
    bool vector_;  ///< select() by AVX2
};

/// One answer into its row; dist may be null (distances not kept).
void write_row(const Best& best, int k, int* idx, float* dist) {
    for (int j = 0; j < k; ++j) idx[j] = best.id(j);
    if (dist) {
        for (int j = 0; j < k; ++j) dist[j] = best.dist(j);
    }
}

#ifdef VDBRECON_HAVE_AVX2_PATHS

/// For each 8-bit mask, the positions of its set bits, in order (the compaction's shuffle).
struct CompressTable {
    std::uint32_t lane[256][8];
    CompressTable() {
        for (int m = 0; m < 256; ++m) {
            int o = 0;
            for (int j = 0; j < 8; ++j) {
                if (m >> j & 1) lane[m][o++] = std::uint32_t(j);
            }
            while (o < 8) lane[m][o++] = 0;
        }
    }
};
const CompressTable kCompress;

/// Block::keep_within's loops eight candidates at a time (m a multiple of 8; keep has room for
/// m + 8): the same float operations in the same order, so the same distances and the same kept
/// list. No FMA, which would round differently.
__attribute__((target("avx2"))) std::size_t keep_within_avx2(const float* bx, const float* by,
                                                             const float* bz, std::size_t m,
                                                             const float q[3], float bound,
                                                             float* d, std::uint32_t* keep) {
    const __m256 qx = _mm256_set1_ps(q[0]), qy = _mm256_set1_ps(q[1]), qz = _mm256_set1_ps(q[2]);
    const __m256 lim = _mm256_set1_ps(bound);
    const __m256i iota = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    std::size_t kept = 0;
    for (std::size_t j = 0; j < m; j += 8) {
        const __m256 ex = _mm256_sub_ps(_mm256_loadu_ps(bx + j), qx);
        const __m256 ey = _mm256_sub_ps(_mm256_loadu_ps(by + j), qy);
        const __m256 ez = _mm256_sub_ps(_mm256_loadu_ps(bz + j), qz);
        const __m256 dd = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(ex, ex), _mm256_mul_ps(ey, ey)),
                                        _mm256_mul_ps(ez, ez));
        _mm256_storeu_ps(d + j, dd);
        const int mask = _mm256_movemask_ps(_mm256_cmp_ps(dd, lim, _CMP_LE_OQ));
        if (mask == 0) continue;
        const __m256i lanes =
            _mm256_loadu_si256(reinterpret_cast<const __m256i*>(kCompress.lane[mask]));
        const __m256i ids = _mm256_add_epi32(_mm256_permutevar8x32_epi32(iota, lanes),
                                             _mm256_set1_epi32(int(j)));
        _mm256_storeu_si256(reinterpret_cast<__m256i*>(keep + kept), ids);
        kept += std::size_t(__builtin_popcount(unsigned(mask)));
    }
    return kept;
}

/// Blocks of more candidates than this lie mostly outside any one query's bound (the room
/// scan's stacks of duplicate points): keep_within_avx512 skips their empty steps by a branch.
constexpr std::size_t kSparseCandidates = 512;

/// keep_within_avx2 sixteen candidates at a time (AVX-512; m a multiple of 8, the last step
/// masked to its 8 where m is not one of 16; keep and near have room for m + 16): the kept
/// indices are compressed in a register, and those within `guess` too into `near` (their count
/// in *near_count), in the same pass. kSkip: a step with no lane kept stores nothing (a branch,
/// cheaper where most steps keep none); else its compressed indices are stored anyway and the
/// next step overwrites them (no branch to mispredict where steps keep some lanes and some
/// none: the bunny's outlier stage took 0.172 -> 0.156 s at 1 thread). fp-contract is off
/// (AVX-512 implies FMA), so the distances are the other loops' bit for bit.
template <bool kSkip>
__attribute__((target("avx512f"), optimize("fp-contract=off"))) std::size_t keep_within_steps(
    const float* bx, const float* by, const float* bz, std::size_t m, const float q[3], float bound,
    float* d, std::uint32_t* keep, float guess, std::uint32_t* near, std::size_t* near_count) {
    const __m512 qx = _mm512_set1_ps(q[0]), qy = _mm512_set1_ps(q[1]), qz = _mm512_set1_ps(q[2]);
    const __m512 lim = _mm512_set1_ps(bound), close = _mm512_set1_ps(guess);
    const __m512i iota = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    std::size_t kept = 0, nearer = 0;
    for (std::size_t j = 0; j < m; j += 16) {
        const __mmask16 lanes = m - j >= 16 ? __mmask16(0xffff) : __mmask16(0x00ff);
        const __m512 ex = _mm512_sub_ps(_mm512_maskz_loadu_ps(lanes, bx + j), qx);
        const __m512 ey = _mm512_sub_ps(_mm512_maskz_loadu_ps(lanes, by + j), qy);
        const __m512 ez = _mm512_sub_ps(_mm512_maskz_loadu_ps(lanes, bz + j), qz);
        const __m512 dd = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(ex, ex), _mm512_mul_ps(ey, ey)),
                                        _mm512_mul_ps(ez, ez));
        _mm512_mask_storeu_ps(d + j, lanes, dd);
        const __mmask16 in = _mm512_mask_cmp_ps_mask(lanes, dd, lim, _CMP_LE_OQ);
        if (kSkip && in == 0) continue;
        const __m512i at = _mm512_add_epi32(iota, _mm512_set1_epi32(int(j)));
        _mm512_storeu_si512(keep + kept, _mm512_maskz_compress_epi32(in, at));
        kept += std::size_t(__builtin_popcount(unsigned(in)));
        if (near) {
            const __mmask16 nb = _mm512_mask_cmp_ps_mask(in, dd, close, _CMP_LE_OQ);
            _mm512_storeu_si512(near + nearer, _mm512_maskz_compress_epi32(nb, at));
            nearer += std::size_t(__builtin_popcount(unsigned(nb)));
        }
    }
    if (near_count) *near_count = nearer;
    return kept;
}

std::size_t keep_within_avx512(const float* bx, const float* by, const float* bz, std::size_t m,
                               const float q[3], float bound, float* d, std::uint32_t* keep,
                               float guess, std::uint32_t* near, std::size_t* near_count) {
    return m > kSparseCandidates
               ? keep_within_steps<true>(bx, by, bz, m, q, bound, d, keep, guess, near, near_count)
               : keep_within_steps<false>(bx, by, bz, m, q, bound, d, keep, guess, near,
                                          near_count);
}
#endif

}  // namespace

struct KnnIndex::Impl {
    Span<Vec3f> points;                  ///< the input (not copied)
    std::size_t n = 0;
    KnnBackend backend = KnnBackend::grid;
    std::unique_ptr<detail::FlannKnn> flann;  ///< backend == flann
    double lo[3] = {0, 0, 0};
    double extent = 1.0;                 ///< edge of the bounding cube, world units
    double to_grid = 1.0;                ///< finest cells per world unit
    int level = 0;                       ///< the cell level of the cell list
    /// The points in Morton order and their indices in the input, each followed by kCopy
    /// entries of padding (gather()'s copies). Filled in parallel, not zeroed first.
    detail::FillLater<float> x, y, z;
    detail::FillLater<int> id;
    static constexpr std::size_t kCopy = 16;
    std::vector<std::uint64_t> cell_key;   ///< occupied level-`level` cells, ascending prefixes
    std::vector<std::uint32_t> cell_first;  ///< first point of each (size = cells + 1)
    /// Open-addressing hash table of the occupied cells (slot -> cell number, or kNoCell), so
    /// that a block's 27 cells are found without searching cell_key.
    std::vector<std::uint32_t> cell_slot;
    int slot_bits = 0;
    static constexpr std::uint32_t kNoCell = ~std::uint32_t(0);

    std::size_t slot_of(std::uint64_t key) const {  // Fibonacci hashing
        return std::size_t((key * 0x9E3779B97F4A7C15ULL) >> (64 - slot_bits));
    }

    /// Fills cell_slot from cell_key, at most half full.
    void index_cells() {
        slot_bits = 1;
        while ((std::size_t(1) << slot_bits) < 2 * cell_key.size()) ++slot_bits;
        cell_slot.assign(std::size_t(1) << slot_bits, kNoCell);
        const std::size_t mask = cell_slot.size() - 1;
        for (std::size_t g = 0; g < cell_key.size(); ++g) {
            std::size_t s = slot_of(cell_key[g]);
            while (cell_slot[s] != kNoCell) s = (s + 1) & mask;
            cell_slot[s] = std::uint32_t(g);
        }
    }

    /// Points [begin, end) of the level-`level` cell `key` (empty if it is not occupied).
    void finest_range(std::uint64_t key, std::uint32_t& begin, std::uint32_t& end) const {
        const std::size_t mask = cell_slot.size() - 1;
        for (std::size_t s = slot_of(key);; s = (s + 1) & mask) {
            const std::uint32_t g = cell_slot[s];
            if (g == kNoCell) break;
            if (cell_key[g] == key) {
                begin = cell_first[g];
                end = cell_first[g + 1];
                return;
            }
        }
        begin = end = 0;
    }

    /// Quantised finest-level coordinate of a world coordinate on axis a (clamped to the grid).
    std::uint32_t quantise(double v, int a) const {
        const double g = std::floor((v - lo[a]) * to_grid);
        if (!(g > 0.0)) return 0;  // also NaN
        return g >= double((1u << kBits) - 1) ? (1u << kBits) - 1 : std::uint32_t(g);
    }

    /// The coordinates of the level-l cell that holds world point p (clamped to the grid).
    void cell_of(const float p[3], int l, std::uint32_t c[3]) const {
        for (int a = 0; a < 3; ++a) c[a] = quantise(p[a], a) >> (kBits - l);
    }

    /// The Morton code of that cell.
    std::uint64_t code_of(const float p[3], int l) const {
        std::uint32_t c[3];
        cell_of(p, l, c);
        return morton(c[0], c[1], c[2]);
    }

    /// Points [begin, end) of the level-l cell with prefix `prefix` (l <= level): at the finest
    /// level from the hash table, at coarser ones by searching cell_key.
    void cell_range(int l, std::uint64_t prefix, std::uint32_t& begin, std::uint32_t& end) const {
        if (l == level) return finest_range(prefix, begin, end);
        const int shift = 3 * (level - l);
        const std::uint64_t a = prefix << shift, b = (prefix + 1) << shift;
        const auto first = std::lower_bound(cell_key.begin(), cell_key.end(), a);
        const auto last = std::lower_bound(first, cell_key.end(), b);
        begin = cell_first[std::size_t(first - cell_key.begin())];
        end = cell_first[std::size_t(last - cell_key.begin())];
    }

    /// The candidates of a 3x3x3 block of cells, in gathering order (the first m entries of
    /// the arrays, which only grow), and scratch for measure().
    struct Block {
        std::vector<float> x, y, z;
        std::vector<int> id;
        std::vector<float> d;
        std::vector<std::uint32_t> keep, near;
        std::size_t m = 0;
        bool vector = detail::vector_loops();  ///< keep_within() by AVX2
        bool wide = detail::wide_vector_loops();  ///< ... by AVX-512
        /// Room for `count` candidates.
        void reserve(std::size_t count) {
            if (count <= x.size()) return;
            count = std::max(count, 2 * x.size());
            x.resize(count);
            y.resize(count);
            z.resize(count);
            id.resize(count);
            d.resize(count);
            keep.resize(count + 16);
            near.resize(count + 16);
        }
    };

    /// Gathers the points of the 3x3x3 block around level-l cell c into `b`: the cells' runs
    /// found first, then copied element by element (most hold a dozen points).
    void gather(int l, const std::uint32_t c[3], Block& b) const {
        const std::int64_t top = (std::int64_t(1) << l) - 1;
        std::uint32_t begin[27], end[27];
        int runs = 0;
        std::size_t total = 0;
        // Each axis' three coordinates spread once (morton() = their interleaving), not 27
        // times over.
        std::uint64_t spread_of[3][3];
        bool inside_of[3][3];
        for (int a = 0; a < 3; ++a) {
            for (int d = 0; d < 3; ++d) {
                const std::int64_t v = std::int64_t(c[a]) + d - 1;
                inside_of[a][d] = v >= 0 && v <= top;
                spread_of[a][d] = spread(std::uint64_t(inside_of[a][d] ? v : 0)) << (2 - a);
            }
        }
        for (const auto& o : kBlockOrder) {
            const int dx = o[0] + 1, dy = o[1] + 1, dz = o[2] + 1;
            if (!(inside_of[0][dx] && inside_of[1][dy] && inside_of[2][dz])) continue;
            cell_range(l, spread_of[0][dx] | spread_of[1][dy] | spread_of[2][dz], begin[runs],
                       end[runs]);
            total += end[runs] - begin[runs];
            runs += end[runs] > begin[runs];
        }
        // Padded to whole groups of 8 for keep_within(): a NaN candidate is never within any
        // bound, so the padding is never kept, by the scalar loop either.
        b.m = (total + 7) / 8 * 8;
        b.reserve(b.m + kCopy);
        float *bx = b.x.data(), *by = b.y.data(), *bz = b.z.data();
        int* bid = b.id.data();
        std::size_t o = 0;
        // kCopy entries at a time, fixed-size copies that the compiler unrolls: a run's last
        // copy may read past it (the arrays have kCopy entries of padding) and write past it
        // (the next run, or the padding below, overwrites them; the block has room).
        for (int r = 0; r < runs; ++r) {
            const std::size_t len = end[r] - begin[r];
            for (std::size_t t = 0; t < len; t += kCopy) {
                const std::size_t j = begin[r] + t;
                std::memcpy(bx + o + t, x.data() + j, kCopy * sizeof(float));
                std::memcpy(by + o + t, y.data() + j, kCopy * sizeof(float));
                std::memcpy(bz + o + t, z.data() + j, kCopy * sizeof(float));
                std::memcpy(bid + o + t, id.data() + j, kCopy * sizeof(int));
            }
            o += len;
        }
        const float nan = std::numeric_limits<float>::quiet_NaN();
        for (; o < b.m; ++o) {
            bx[o] = by[o] = bz[o] = nan;
            bid[o] = -1;
        }
    }

    /// Distance from world point q to the outside of the block around level-l cell c (infinite
    /// on sides beyond the cube, where no point lies).
    double clearance(int l, const std::uint32_t c[3], const float q[3]) const {
        const double h = extent / double(std::int64_t(1) << l);
        const std::int64_t top = (std::int64_t(1) << l) - 1;
        double best = std::numeric_limits<double>::infinity();
        for (int a = 0; a < 3; ++a) {
            if (std::int64_t(c[a]) - 1 > 0) best = std::min(best, q[a] - (lo[a] + (double(c[a]) - 1) * h));
            if (std::int64_t(c[a]) + 2 <= top) best = std::min(best, lo[a] + (double(c[a]) + 2) * h - q[a]);
        }
        // Margin for the rounding of the quantisation and of float distances.
        return best - 1e-5 * h - 1e-6 * extent;
    }

    /// Squared distances from q to the candidates of `b` (into b.d) and the candidates within
    /// `bound`, in block order (into b.keep); returns their count. With `near_count`, also those
    /// of them within `guess` (into b.near, their count into *near_count).
    static std::size_t keep_within(Block& b, const float q[3], float bound, float guess = 0.0f,
                                   std::size_t* near_count = nullptr) {
#ifdef VDBRECON_HAVE_AVX2_PATHS
        if (b.wide) {
            return keep_within_avx512(b.x.data(), b.y.data(), b.z.data(), b.m, q, bound, b.d.data(),
                                      b.keep.data(), guess, near_count ? b.near.data() : nullptr,
                                      near_count);
        }
#endif
        const std::size_t kept = keep_within_narrow(b, q, bound);
        if (near_count) *near_count = near_within(b, kept, guess);
        return kept;
    }

    /// keep_within's distances and kept candidates without AVX-512.
    static std::size_t keep_within_narrow(Block& b, const float q[3], float bound) {
#ifdef VDBRECON_HAVE_AVX2_PATHS
        if (b.vector)
            return keep_within_avx2(b.x.data(), b.y.data(), b.z.data(), b.m, q, bound, b.d.data(),
                                    b.keep.data());
#endif
        const std::size_t m = b.m;
        const float qx = q[0], qy = q[1], qz = q[2];
        float* d = b.d.data();
        const float *bx = b.x.data(), *by = b.y.data(), *bz = b.z.data();
        for (std::size_t j = 0; j < m; ++j) {
            const float ex = bx[j] - qx, ey = by[j] - qy, ez = bz[j] - qz;
            d[j] = ex * ex + ey * ey + ez * ez;
        }
        std::uint32_t* keep = b.keep.data();  // branch-free compaction
        std::size_t kept = 0;
        for (std::size_t j = 0; j < m; ++j) {
            keep[kept] = std::uint32_t(j);
            kept += d[j] <= bound;
        }
        return kept;
    }

    /// The first `kept` entries of b.keep within squared distance `guess` (into b.near, in
    /// order); returns their count.
    static std::size_t near_within(Block& b, std::size_t kept, float guess) {
        const float* d = b.d.data();
        const std::uint32_t* keep = b.keep.data();
        std::uint32_t* near = b.near.data();
        std::size_t count = 0;
        for (std::size_t e = 0; e < kept; ++e) {
            near[count] = keep[e];
            count += d[keep[e]] <= guess;
        }
        return count;
    }

    /// Offers every candidate of `b` except `self` within squared distance `bound` of q to
    /// `best` (bound: an upper bound of the k-th distance, or infinity when none is known).
    ///
    /// `guess`, a smaller bound that may fail: where more than k candidates lie within it, the
    /// k nearest do too (with all their ties), and only those are offered, so fewer enter the
    /// list to be pushed out again; else all within `bound` are. Neither bound changes the
    /// answer: with fewer than k candidates the list is not full and the caller measures again
    /// without a bound.
    static void measure(Block& b, const float q[3], int self, float bound, Best& best,
                        float guess = std::numeric_limits<float>::infinity()) {
        std::size_t count = 0;
        std::size_t kept = keep_within(b, q, bound, guess, guess < bound ? &count : nullptr);
        const float* d = b.d.data();
        const std::uint32_t* keep = b.keep.data();
        if (count > std::size_t(best.k())) {
            keep = b.near.data();
            kept = count;
        }
        best.select(d, b.id.data(), keep, kept, self);
    }

    /// Whether `best` holds the exact answer for a query at q with the block of level-l cell c.
    bool settled(const Best& best, int l, const std::uint32_t c[3], const float q[3]) const {
        if (!best.full()) return l == 0;
        const double clear = clearance(l, c, q);
        return std::isinf(clear) || (clear > 0.0 && double(best.worst()) < clear * clear);
    }

    /// Answers one query from scratch, at coarser and coarser levels from `from` down.
    void answer_alone(const float q[3], int self, int from, Block& b, Best& best) const {
        for (int l = from; l >= 0; --l) {
            std::uint32_t c[3];
            cell_of(q, l, c);
            gather(l, c, b);
            measure(b, q, self, std::numeric_limits<float>::infinity(), best);
            if (settled(best, l, c, q)) return;
        }
    }

    /// Query i is excluded from its own answer: none, the point self[i], or point i itself.
    struct Self {
        const int* ids = nullptr;
        bool is_query = false;
        int of(std::size_t i) const { return is_query ? int(i) : ids ? ids[i] : -1; }
    };

    /// The k nearest points of queries q (excluding Self's point), into rows of idx/dist.
    /// `order` lists the query indices so that each run [first[g], first[g + 1]) of it lies in
    /// one level-`level` cell, whose key is keys[g], for the groups g in [g0, g1). Query
    /// order[j] goes to row j - row_base, or with row_base = kByQuery to row order[j].
    static constexpr std::size_t kByQuery = ~std::size_t(0);
    /// Distances a cell's queries measure in all (queries x candidates) above which search()
    /// splits the cell's queries among the threads.
    static constexpr std::size_t kSplitWork = std::size_t(1) << 18;
    void search(Span<Vec3f> q, Self self, const int* order, const std::uint32_t* first,
                const std::uint64_t* keys, std::size_t g0, std::size_t g1, int k, int* idx,
                float* dist, std::size_t row_base = kByQuery) const;

    /// search() for arbitrary queries: groups them by cell first.
    void search(Span<Vec3f> q, Self self, int k, int* idx, float* dist) const;
};

void KnnOptions::validate() const {
    if (!(std::isfinite(eps) && eps >= 0.0)) throw InvalidArgument("knn.eps must be >= 0 (0 = exact)");
}

KnnIndex::KnnIndex(Span<Vec3f> points, const KnnOptions& options) : impl_(std::make_unique<Impl>()) {
    options.validate();
    if (points.empty()) throw InvalidArgument("kNN index: no points");
    Impl& m = *impl_;
    const std::size_t n = points.size();
    if (n > std::size_t(std::numeric_limits<int>::max())) {
        throw InvalidArgument("kNN index: more than 2^31 - 1 points");
    }
    m.points = points;
    m.n = n;
    const BBox box = bounding_box(points);  // in parallel
    const double lo[3] = {box.min[0], box.min[1], box.min[2]};
    const double hi[3] = {box.max[0], box.max[1], box.max[2]};
    double extent = 0.0;
    for (int a = 0; a < 3; ++a) {
        if (!std::isfinite(lo[a]) || !std::isfinite(hi[a])) {
            throw InvalidArgument("kNN index: non-finite point coordinates");
        }
        m.lo[a] = lo[a];
        extent = std::max(extent, hi[a] - lo[a]);
    }
    m.extent = extent > 0.0 ? extent * (1.0 + 1e-6) : 1.0;
    if (options.backend == KnnBackend::flann) {
        m.backend = KnnBackend::flann;
        m.flann = std::make_unique<detail::FlannKnn>(points, options.eps);
        return;  // no grid
    }

    m.to_grid = double(1u << kBits) / m.extent;

    // The cell size: where the mean points per occupied cell reaches kPerCell, interpolated
    // between the two power-of-two levels around it (occupancy ~ a power of the cell size).
    // Occupancy is counted on every `stride`-th point (sorted codes: consecutive codes first
    // differ at a level, and so on every finer one), with the target scaled alike; only speed
    // depends on this choice, never the answers.
    {
        const std::size_t stride = n > 65536 ? 4 : 1;
        std::vector<std::uint64_t> codes((n + stride - 1) / stride);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, codes.size(), 8192),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t j = r.begin(); j < r.end(); ++j) {
                codes[j] = m.code_of(points[j * stride].data(), kBits);
            }
        });
        detail::radix_sort(codes, 3 * kBits, [](std::uint64_t c) { return c; });
        std::size_t first_diff[kBits + 1] = {};
        for (std::size_t i = 1; i < codes.size(); ++i) {
            const std::uint64_t d = codes[i] ^ codes[i - 1];
            if (d != 0) ++first_diff[kBits - (63 - __builtin_clzll(d)) / 3];
        }
        std::vector<double> ppc(kBits + 1);
        double occupied = 1.0;
        for (int l = 0; l <= kBits; ++l) {
            occupied += double(first_diff[l]);
            ppc[std::size_t(l)] = double(codes.size()) / occupied;
        }
        const double target = kPerCell / double(stride);
        int l = 0;
        while (l < kBits && ppc[std::size_t(l + 1)] >= target) ++l;
        double h = m.extent / double(1u << l);
        if (l < kBits && ppc[std::size_t(l)] > ppc[std::size_t(l + 1)]) {
            h *= std::exp2(-std::log(ppc[std::size_t(l)] / target) /
                           std::log(ppc[std::size_t(l)] / ppc[std::size_t(l + 1)]));
        }
        // The cube grows so that this size is one of its levels.
        m.level = std::clamp(int(std::ceil(std::log2(m.extent / h) - 1e-9)), 0, kBits);
        m.extent = std::max(m.extent, h * double(1u << m.level));
        m.to_grid = double(1u << kBits) / m.extent;
    }

    // The points in Morton order three levels below the cells (so that consecutive queries in
    // a cell are close, which tightens their bounds), ties in index order: a stable radix sort.
    const int fine = std::min(kBits, m.level + 3);
    detail::FillLater<Coded> keyed(n);  // not zeroed: the loop writes every entry
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 8192),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            keyed[i] = {m.code_of(points[i].data(), fine), std::uint32_t(i)};
        }
    });
    detail::radix_sort(keyed, 3 * fine, [](const Coded& e) { return e.code; });

    m.x.resize(n + Impl::kCopy);
    m.y.resize(n + Impl::kCopy);
    m.z.resize(n + Impl::kCopy);
    m.id.resize(n + Impl::kCopy);
    std::fill(m.x.begin() + std::ptrdiff_t(n), m.x.end(), 0.0f);  // the padding
    std::fill(m.y.begin() + std::ptrdiff_t(n), m.y.end(), 0.0f);
    std::fill(m.z.begin() + std::ptrdiff_t(n), m.z.end(), 0.0f);
    std::fill(m.id.begin() + std::ptrdiff_t(n), m.id.end(), 0);
    const int shift = 3 * (fine - m.level);  // a fine code to its level-L cell
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 8192),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            const Vec3f& p = points[keyed[i].i];
            m.x[i] = p[0];
            m.y[i] = p[1];
            m.z[i] = p[2];
            m.id[i] = int(keyed[i].i);
            keyed[i].code >>= shift;
        }
    });
    for (std::size_t i = 0; i < n; ++i) {
        if (i == 0 || keyed[i].code != m.cell_key.back()) {
            m.cell_key.push_back(keyed[i].code);
            m.cell_first.push_back(std::uint32_t(i));
        }
    }
    m.cell_first.push_back(std::uint32_t(n));
    m.index_cells();
}

KnnIndex::~KnnIndex() = default;

std::size_t KnnIndex::size() const { return impl_->n; }

KnnBackend KnnIndex::backend() const { return impl_->backend; }

void KnnIndex::Impl::search(Span<Vec3f> q, Self self, const int* order,
                            const std::uint32_t* first, const std::uint64_t* keys, std::size_t g0,
                            std::size_t g1, int k, int* idx, float* dist,
                            std::size_t row_base) const {
    const bool own = order == id.data();  // the queries are the index's points, in its order
    const float* own_xyz[3] = {x.data(), y.data(), z.data()};
    // One thread's scratch: the gathered block, the lists, and the previous query's k-th
    // distance and position, whose sum with the distance between the two bounds this one's
    // (triangle inequality; the margin covers float rounding), also from the last query of the
    // cell before: only speed depends on the bound, never the answer.
    struct Scratch {
        Block block, alone;
        Best best;
        float prev[3] = {0.0f, 0.0f, 0.0f}, prev_worst = -1.0f;  // -1: no query before
        explicit Scratch(int k) : best(k) {}
    };
    // Queries j0..j1 of the cell c, whose block `s` holds.
    const auto answer = [&](const std::uint32_t c[3], std::uint32_t j0, std::uint32_t j1,
                            Scratch& s) {
        for (std::uint32_t j = j0; j < j1; ++j) {
            const std::size_t i = std::size_t(order[j]);
            // The index's own points in its order (self_neighbours) are read from its copies,
            // in memory order, not from the input (a cache miss a query).
            float p[3];
            for (int a = 0; a < 3; ++a) p[a] = own ? own_xyz[a][j] : q[i][a];
            const int me = self.of(i);
            float bound = std::numeric_limits<float>::infinity();
            const bool after = s.prev_worst >= 0.0f;
            if (after) {
                const float ex = p[0] - s.prev[0], ey = p[1] - s.prev[1], ez = p[2] - s.prev[2];
                const float r = std::sqrt(s.prev_worst) + std::sqrt(ex * ex + ey * ey + ez * ez);
                bound = r * r * 1.0001f;
            }
            // The previous query's k-th squared distance, a quarter more, as the guess.
            measure(s.block, p, me, bound, s.best,
                    after ? 1.25f * s.prev_worst : std::numeric_limits<float>::infinity());
            if (!s.best.full()) {
                measure(s.block, p, me, std::numeric_limits<float>::infinity(), s.best);
            }
            if (!settled(s.best, level, c, p)) answer_alone(p, me, level - 1, s.alone, s.best);
            const std::size_t row = row_base == kByQuery ? i : j - row_base;
            write_row(s.best, k, idx + row * std::size_t(k),
                      dist ? dist + row * std::size_t(k) : nullptr);
            std::copy(p, p + 3, s.prev);
            s.prev_worst = s.best.worst();
        }
    };
    const bool split = tbb::this_task_arena::max_concurrency() > 1;
    // A thread's scratch lives through the search: made per task, its growing arrays were
    // allocated and freed from both threads at once, and the CLI's one heap arena puts a thread
    // that finds its lock taken to sleep (detail/release.h, heap_lock). A thread that takes
    // another task while it waits for a split cell's (below) uses the same scratch; the waiting
    // task gathers its next block afresh.
    tbb::enumerable_thread_specific<Scratch> scratch(k);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(g0, g1, 16), [&](const tbb::blocked_range<
                                                                       std::size_t>& r) {
        Scratch& s = scratch.local();
        s.prev_worst = -1.0f;
        for (std::size_t g = r.begin(); g < r.end(); ++g) {
            const std::uint32_t c[3] = {compact(keys[g] >> 2), compact(keys[g] >> 1),
                                        compact(keys[g])};
            gather(level, c, s.block);
            // A cell whose queries each measure a large block (a stack of duplicate points:
            // the room scan's, 0.12 s of one thread while the other waited) is split among the
            // threads, each with its own copy of the block.
            const std::uint32_t n = first[g + 1] - first[g];
            if (split && std::size_t(n) * s.block.m > kSplitWork) {
                tbb::parallel_for(tbb::blocked_range<std::uint32_t>(first[g], first[g + 1], 128),
                                  [&](const tbb::blocked_range<std::uint32_t>& js) {
                                      Scratch t(k);
                                      gather(level, c, t.block);
                                      answer(c, js.begin(), js.end(), t);
                                  });
                s.prev_worst = -1.0f;
                continue;
            }
            answer(c, first[g], first[g + 1], s);
        }
    });
}

void KnnIndex::Impl::search(Span<Vec3f> q, Self self, int k, int* idx, float* dist) const {
    if (flann) {
        flann->search(q, self.is_query ? nullptr : self.ids, self.is_query ? 0 : -1, k, idx, dist);
        return;
    }
    detail::FillLater<Coded> keyed(q.size());  // not zeroed: the loop writes every entry
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, q.size(), 8192),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            keyed[i] = {code_of(q[i].data(), level), std::uint32_t(i)};
        }
    });
    detail::radix_sort(keyed, 3 * level, [](const Coded& e) { return e.code; });
    std::vector<int> order(q.size());
    std::vector<std::uint32_t> first;
    std::vector<std::uint64_t> keys;
    for (std::size_t i = 0; i < keyed.size(); ++i) {
        order[i] = int(keyed[i].i);
        if (i == 0 || keyed[i].code != keys.back()) {
            keys.push_back(keyed[i].code);
            first.push_back(std::uint32_t(i));
        }
    }
    first.push_back(std::uint32_t(q.size()));
    search(q, self, order.data(), first.data(), keys.data(), 0, keys.size(), k, idx, dist);
}

KnnResult KnnIndex::self_neighbours(int k, bool distances) const {
    const Impl& m = *impl_;
    KnnResult out;
    out.k = std::max(0, std::min<int>(k, int(m.n) - 1));
    if (out.k == 0) return out;
    out.indices.resize(m.n * std::size_t(out.k));
    if (distances) out.sq_distances.resize(out.indices.size());
    if (m.flann) {
        m.flann->search(m.points, nullptr, 0, out.k, out.indices.data(),
                        distances ? out.sq_distances.data() : nullptr);
        return out;
    }
    // The queries are the points themselves, taken in the index's order, whose runs are its
    // cells; each answer goes straight to the point's row.
    m.search(m.points, Impl::Self{nullptr, true}, m.id.data(), m.cell_first.data(),
             m.cell_key.data(), 0, m.cell_key.size(), out.k, out.indices.data(),
             distances ? out.sq_distances.data() : nullptr);
    return out;
}

void KnnIndex::visit_self_neighbours(int k, const BatchVisitor& visit, std::size_t batch) const {
    const Impl& m = *impl_;
    k = std::max(0, std::min<int>(k, int(m.n) - 1));
    if (k == 0) return;
    if (batch == 0) batch = std::max<std::size_t>(std::size_t(1) << 16, m.n / 32);
    std::vector<int> idx;
    if (m.flann) {  // batches of points in index order
        std::vector<int> rows;
        for (std::size_t p0 = 0; p0 < m.n; p0 += batch) {
            const std::size_t count = std::min(batch, m.n - p0);
            rows.resize(count);
            for (std::size_t j = 0; j < count; ++j) rows[j] = int(p0 + j);
            idx.resize(count * std::size_t(k));
            m.flann->search(Span<Vec3f>(m.points.data() + p0, count), nullptr, long(p0), k,
                            idx.data(), nullptr);
            visit(rows.data(), count, k, idx.data());
        }
        return;
    }
    for (std::size_t g0 = 0; g0 < m.cell_key.size();) {
        // Whole cells, at least `batch` points (or the rest).
        const std::size_t p0 = m.cell_first[g0];
        const auto end = std::lower_bound(m.cell_first.begin() + std::ptrdiff_t(g0),
                                          m.cell_first.end() - 1, std::uint32_t(p0 + batch));
        const std::size_t g1 = std::max(g0 + 1, std::size_t(end - m.cell_first.begin()));
        const std::size_t count = m.cell_first[g1] - p0;
        idx.resize(count * std::size_t(k));
        m.search(m.points, Impl::Self{nullptr, true}, m.id.data(), m.cell_first.data(),
                 m.cell_key.data(), g0, g1, k, idx.data(), nullptr, p0);
        visit(m.id.data() + p0, count, k, idx.data());
        g0 = g1;
    }
}

KnnResult KnnIndex::self_neighbours_of(const std::vector<std::size_t>& rows, int k) const {
    const Impl& m = *impl_;
    KnnResult out;
    out.k = std::max(0, std::min<int>(k, int(m.n) - 1));
    if (out.k == 0 || rows.empty()) return out;
    std::vector<Vec3f> q(rows.size());
    std::vector<int> self(rows.size());
    for (std::size_t j = 0; j < rows.size(); ++j) {
        q[j] = m.points[rows[j]];
        self[j] = int(rows[j]);
    }
    out.indices.resize(rows.size() * std::size_t(out.k));
    out.sq_distances.resize(out.indices.size());
    m.search(q, Impl::Self{self.data(), false}, out.k, out.indices.data(), out.sq_distances.data());
    return out;
}

KnnResult KnnIndex::query(Span<Vec3f> queries, int k) const {
    KnnResult r;
    r.k = std::max(0, std::min<int>(k, int(size())));
    if (r.k == 0 || queries.empty()) return r;
    r.indices.resize(queries.size() * std::size_t(r.k));
    r.sq_distances.resize(r.indices.size());
    impl_->search(queries, Impl::Self{}, r.k, r.indices.data(), r.sq_distances.data());
    return r;
}

KnnResult KnnResult::subset(const std::vector<char>& removed, Span<Vec3f> kept_points,
                            int k_sub, std::size_t* requeried) const& {
    KnnResult copy = *this;
    return std::move(copy).subset(removed, kept_points, k_sub, requeried);
}

KnnResult KnnResult::subset(const std::vector<char>& removed, Span<Vec3f> kept_points,
                            int k_sub, std::size_t* requeried) && {
    if (requeried) *requeried = 0;
    const std::size_t n = removed.size();
    if (k_sub <= 0 || k_sub > k || indices.size() != n * std::size_t(k)) return {};
    if (kept_points.empty() || std::size_t(k_sub) >= kept_points.size()) return {};
    std::vector<int> renumber(n, -1);
    std::size_t m = 0;
    for (std::size_t i = 0; i < n; ++i) {
        if (!removed[i]) renumber[i] = int(m++);
    }
    if (m != kept_points.size()) throw InvalidArgument("kNN subset: kept point count mismatch");
    // In place, a chunk of rows at a time: a chunk's new rows are made in parallel into scratch,
    // then copied down over the old ones. New row r starts at r k_sub <= i k for its old row i,
    // so no copy reaches an old row that a later chunk has still to read; the lists never exist
    // twice (at 5M points and k = 16 the old ones alone are 640 MB).
    constexpr std::size_t kChunkRows = std::size_t(1) << 15;
    const std::size_t ks = std::size_t(k_sub);
    const bool with_d2 = has_distances();
    std::vector<char> short_row(m, 0);
    std::vector<int> new_idx;
    std::vector<float> new_d2;
    std::size_t m1 = 0;
    for (std::size_t c0 = 0; c0 < n; c0 += kChunkRows) {
        const std::size_t c1 = std::min(n, c0 + kChunkRows);
        // Kept rows of the chunk: [m0, m1) in the new numbering.
        const std::size_t m0 = m1;
        for (std::size_t i = c0; i < c1; ++i) m1 += removed[i] ? 0 : 1;
        if (m1 == m0) continue;  // the whole chunk was removed
        new_idx.resize((m1 - m0) * ks);
        if (with_d2) new_d2.resize(new_idx.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(c0, c1, 4096),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t i = r.begin(); i < r.end(); ++i) {
                if (removed[i]) continue;
                const std::size_t row = (std::size_t(renumber[i]) - m0) * ks;
                std::size_t o = 0;
                for (int j = 0; j < k && o < ks; ++j) {
                    const int nb = renumber[std::size_t(neighbours(i)[j])];
                    if (nb < 0) continue;
                    new_idx[row + o] = nb;
                    if (with_d2) new_d2[row + o] = sq_dists(i)[j];
                    ++o;
                }
                if (o < ks) short_row[std::size_t(renumber[i])] = 1;
            }
        });
        std::copy(new_idx.begin(), new_idx.end(), indices.begin() + std::ptrdiff_t(m0 * ks));
        std::copy(new_d2.begin(), new_d2.end(), sq_distances.begin() + std::ptrdiff_t(m0 * ks));
    }
    KnnResult out;
    out.k = k_sub;
    out.indices = std::move(indices);
    out.sq_distances = std::move(sq_distances);
    out.indices.resize(m * ks);  // keeps the capacity: shrinking would copy
    if (with_d2) out.sq_distances.resize(m * ks);
    k = 0;
    std::vector<std::size_t> incomplete;
    for (std::size_t j = 0; j < m; ++j) {
        if (short_row[j]) incomplete.push_back(j);
    }
    if (!incomplete.empty()) KnnIndex(kept_points).fill_rows(out, incomplete);
    if (requeried) *requeried = incomplete.size();
    return out;
}

void KnnIndex::fill_rows(KnnResult& r, const std::vector<std::size_t>& rows) const {
    if (rows.empty() || r.k == 0) return;
    const KnnResult found = self_neighbours_of(rows, r.k);
    const bool with_d2 = r.has_distances();
    const std::size_t k = std::size_t(r.k);
    for (std::size_t j = 0; j < rows.size(); ++j) {
        std::copy_n(found.neighbours(j), k, &r.indices[rows[j] * k]);
        if (with_d2) std::copy_n(found.sq_dists(j), k, &r.sq_distances[rows[j] * k]);
    }
}

double median_density_spacing(const std::vector<float>& kth_sq, int k) {
    if (kth_sq.empty() || k <= 0) return 0.0;
    // The element nth_element would put at the middle, without reordering the 362k distances
    // of the bunny (3-4 ms of one thread).
    return density_spacing(detail::select_rank(kth_sq.size() / 2, kth_sq), k);
}

double density_spacing(float kth_sq, int k) { return std::sqrt(double(kth_sq) * M_PI / double(k)); }

}  // namespace vdbrecon
