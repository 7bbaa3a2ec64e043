// Writing .vdb files: OpenVDB writes the header, descriptors, metadata, transforms and
// topology; we write the leaf buffers, which are nearly all of the bytes.
//
// Why: openvdb::io::File::write (OpenVDB 10) makes a pass over every leaf for the delayed-load
// metadata, then writes each leaf through std::ostream in several small writes (a system call
// for most leaves), one leaf at a time. On the bunny at 0.5 mm (35.6 MB, 4 grids) that took
// 0.13-0.29 s of a second core; this writer takes 0.05-0.07 s. Here one pass classifies the
// leaves (in parallel), and the buffers are serialised in parallel into a 1 MB block that is
// hashed and written at once.
//
// The leaf layout follows OpenVDB's file format (io/Compression.h, format version 224) with
// active-mask compression: the value mask (64 bytes), a byte saying which inactive values the
// reader must restore, those values, a selection mask where there are two, then the active
// values (or all 512 values when the inactive ones take more than two values). The test "vdb
// files: the bytes openvdb::io::File writes, ..." (tests/test_io.cpp) compares whole files.
#include "detail/vdb_file.h"

#include <openvdb/io/Archive.h>
#include <openvdb/io/Compression.h>
#include <openvdb/io/DelayedLoadMetadata.h>
#include <openvdb/io/GridDescriptor.h>
#include <openvdb/io/io.h>
#include <openvdb/tree/LeafManager.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <set>
#include <sstream>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "detail/simd.h"
#ifdef VDBRECON_HAVE_AVX2_PATHS
#include <immintrin.h>
#endif

#include "detail/io_common.h"
#include "vdbrecon/error.h"

namespace vdbrecon::detail {
namespace {

namespace vio = openvdb::io;
constexpr std::uint32_t kCompression = vio::COMPRESS_ACTIVE_MASK;
constexpr std::size_t kMaskBytes = 64;
constexpr std::size_t kLeafValues = 512;
/// The header's random UUID: 36 characters after the magic (8 bytes), three uint32 versions
/// and the "has grid offsets" byte.
constexpr std::size_t kUuidOffset = 8 + 4 + 4 + 4 + 1;
constexpr std::size_t kUuidLength = 36;

/// Archive's header and per-grid compression flags are protected; they are used as they are.
class Archive : public vio::Archive {
  public:
    Archive() {
        setCompression(kCompression);
        setGridStatsMetadataEnabled(true);
    }
    using vio::Archive::setGridCompression;
    using vio::Archive::writeHeader;
};

/// Eight FNV-1a style lanes over the 8-byte words of the file after the UUID, word i into lane
/// i mod 8 (independent multiply chains; with two, the bunny's 36 MB file at 0.5 mm took the
/// writer 0.064 s at 1 thread, with eight 0.060 s), then the last bytes one by one; the lanes
/// folded into 128 bits become a version-5 style UUID.
class ContentHash {
  public:
    void add(const char* p, std::size_t n) {
        std::size_t i = 0;
        while (tail_size_ > 0 && tail_size_ < 8 && i < n) tail_[tail_size_++] = p[i++];
        if (tail_size_ == 8) {
            word(tail_);
            tail_size_ = 0;
        }
        for (; lane_ != 0 && i + 8 <= n; i += 8) word(p + i);
        for (; i + 64 <= n; i += 64) {  // lane_ is 0: a word for each lane
            for (int j = 0; j < kLanes; ++j) h_[j] = mix(h_[j], load(p + i + 8 * j));
        }
        for (; i + 8 <= n; i += 8) word(p + i);
        for (; i < n; ++i) tail_[tail_size_++] = p[i];
    }

    std::string uuid() {
        std::uint64_t h[2] = {0xcbf29ce484222325ULL, 0x84222325cbf29ce4ULL};
        for (int j = 0; j < kLanes; ++j) {
            h[0] = mix(h[0], h_[j]);
            h[1] = mix(h[1], h_[kLanes - 1 - j]);
        }
        for (std::size_t i = 0; i < tail_size_; ++i) {
            for (std::uint64_t& x : h) {
                x = (x ^ static_cast<unsigned char>(tail_[i])) * 0x100000001b3ULL;
            }
        }
        tail_size_ = 0;
        unsigned char b[16];
        for (int i = 0; i < 8; ++i) {
            b[i] = static_cast<unsigned char>(h[0] >> (8 * i));
            b[8 + i] = static_cast<unsigned char>(h[1] >> (8 * i));
        }
        b[6] = static_cast<unsigned char>((b[6] & 0x0f) | 0x50);  // version 5 (name-based)
        b[8] = static_cast<unsigned char>((b[8] & 0x3f) | 0x80);  // RFC 4122 variant
        char text[kUuidLength + 1];
        std::snprintf(text, sizeof(text),
                      "%02x%02x%02x%02x-%02x%02x-%02x%02x-%02x%02x-%02x%02x%02x%02x%02x%02x", b[0],
                      b[1], b[2], b[3], b[4], b[5], b[6], b[7], b[8], b[9], b[10], b[11], b[12],
                      b[13], b[14], b[15]);
        return std::string(text, kUuidLength);
    }

  private:
    static constexpr int kLanes = 8;

    static std::uint64_t load(const char* p) {
        std::uint64_t w;
        std::memcpy(&w, p, 8);
        return w;
    }
    static std::uint64_t mix(std::uint64_t h, std::uint64_t w) {
        h = (h ^ w) * 0x100000001b3ULL;
        return h ^ (h >> 29);
    }
    void word(const char* p) {
        h_[lane_] = mix(h_[lane_], load(p));
        lane_ = (lane_ + 1) % kLanes;
    }

    std::uint64_t h_[kLanes] = {0xcbf29ce484222325ULL, 0x84222325cbf29ce4ULL, 0x9e3779b97f4a7c15ULL,
                                0xbf58476d1ce4e5b9ULL, 0x94d049bb133111ebULL, 0x2545f4914f6cdd1dULL,
                                0x165667b19e3779f9ULL, 0x27d4eb2f165667c5ULL};
    int lane_ = 0;
    char tail_[8];
    std::size_t tail_size_ = 0;
};

/// The file through a 1 MB block: bytes are appended (or serialised in place with room() and
/// advance()), each full block is hashed (past the UUID) and written with one call.
class Output {
  public:
    Output(std::FILE* file, const std::string& path)
        : file_(file), path_(path), block_(std::size_t(1) << 20) {}

    std::int64_t position() const { return std::int64_t(written_ + used_); }
    std::size_t capacity() const { return block_.size(); }

    void put(const std::string& bytes) { put(bytes.data(), bytes.size()); }
    void put(const void* p, std::size_t n) {
        const char* c = static_cast<const char*>(p);
        while (n > 0) {
            if (used_ == block_.size()) flush();
            const std::size_t k = std::min(n, block_.size() - used_);
            std::memcpy(block_.data() + used_, c, k);
            used_ += k;
            c += k;
            n -= k;
        }
    }
    /// `n` (<= capacity()) contiguous bytes to fill, then advance(n).
    char* room(std::size_t n) {
        if (block_.size() - used_ < n) flush();
        return block_.data() + used_;
    }
    void advance(std::size_t n) { used_ += n; }

    /// Writes the rest, then the UUID derived from everything after it.
    void finish() {
        flush();
        const std::string uuid = hash_.uuid();
        if (std::fseek(file_, long(kUuidOffset), SEEK_SET) != 0 ||
            std::fwrite(uuid.data(), 1, uuid.size(), file_) != uuid.size() ||
            std::fflush(file_) != 0) {
            fail();
        }
    }

  private:
    void flush() {
        const std::size_t skip = written_ >= kUuidOffset + kUuidLength
                                     ? 0
                                     : std::min(used_, kUuidOffset + kUuidLength - written_);
        // The hash and the write read the same block: at once, where a second thread is free
        // (bunny at 0.5 mm, 2 threads: the writer 0.057 -> 0.049 s). errno is the writing
        // thread's.
        int error = 0;
        tbb::parallel_invoke(
            [&] { hash_.add(block_.data() + skip, used_ - skip); },
            [&] {
                if (used_ > 0 && std::fwrite(block_.data(), 1, used_, file_) != used_) {
                    error = errno != 0 ? errno : EIO;
                }
            });
        if (error != 0) fail(error);
        written_ += used_;
        used_ = 0;
    }
    [[noreturn]] void fail(int error = errno) const {
        throw IoError(where(path_, std::string("cannot write: ") + std::strerror(error)));
    }

    std::FILE* file_;
    std::string path_;
    std::vector<char> block_;
    std::size_t used_ = 0, written_ = 0;
    ContentHash hash_;
};

/// Calls f(i) for each set bit i of `words` (8 words of 64 bits), in order; with `off`, for each
/// clear bit. f returns false to stop.
template <typename F>
void for_each_bit(const std::uint64_t* words, bool off, F&& f) {
    for (int w = 0; w < 8; ++w) {
        std::uint64_t bits = off ? ~words[w] : words[w];
        while (bits) {
            if (!f(w * 64 + __builtin_ctzll(bits))) return;
            bits &= bits - 1;
        }
    }
}

/// The number of set bits of a leaf's 8 mask words.
std::size_t count_on(const std::uint64_t* words) {
    std::size_t count = 0;
    for (int w = 0; w < 8; ++w) count += openvdb::util::CountOn(words[w]);
    return count;
}

/// The bits of a leaf's voxels whose value equals v (==, as classify_leaf compares), as 8
/// mask words. (The vector forms below where SSE2 is there: x86-64 always.)
template <typename T>
void equal_bits(const T* values, const T& v, std::uint64_t* out) {
    for (int w = 0; w < 8; ++w) {
        std::uint64_t bits = 0;
        for (int j = 0; j < 64; ++j) bits |= std::uint64_t(values[w * 64 + j] == v) << j;
        out[w] = bits;
    }
}

#if defined(__SSE2__)
void equal_bits(const float* values, float v, std::uint64_t* out) {
    const __m128 b = _mm_set1_ps(v);
    for (int w = 0; w < 8; ++w) {
        std::uint64_t bits = 0;
        for (int j = 0; j < 64; j += 4) {
            const __m128 x = _mm_loadu_ps(values + w * 64 + j);
            bits |= std::uint64_t(_mm_movemask_ps(_mm_cmpeq_ps(x, b))) << j;
        }
        out[w] = bits;
    }
}

void equal_bits(const openvdb::Vec3f* values, const openvdb::Vec3f& v, std::uint64_t* out) {
    // Four voxels are three vectors of four floats; of the 12 compare bits, voxel j's are 3j,
    // 3j + 1 and 3j + 2.
    const __m128 b0 = _mm_setr_ps(v[0], v[1], v[2], v[0]);
    const __m128 b1 = _mm_setr_ps(v[1], v[2], v[0], v[1]);
    const __m128 b2 = _mm_setr_ps(v[2], v[0], v[1], v[2]);
    const float* f = values[0].asPointer();
    for (int w = 0; w < 8; ++w) {
        std::uint64_t bits = 0;
        for (int j = 0; j < 64; j += 4, f += 12) {
            const unsigned m =
                unsigned(_mm_movemask_ps(_mm_cmpeq_ps(_mm_loadu_ps(f), b0))) |
                unsigned(_mm_movemask_ps(_mm_cmpeq_ps(_mm_loadu_ps(f + 4), b1))) << 4 |
                unsigned(_mm_movemask_ps(_mm_cmpeq_ps(_mm_loadu_ps(f + 8), b2))) << 8;
            const unsigned all = m & m >> 1 & m >> 2;
            const unsigned four = (all & 1) | (all >> 2 & 2) | (all >> 4 & 4) | (all >> 6 & 8);
            bits |= std::uint64_t(four) << j;
        }
        out[w] = bits;
    }
}
#endif

/// Whether the writer takes its vector forms below (AVX-512 CPUs, with BMI2 as all of them
/// have it): the bits compared sixteen floats at a time, and the active values copied by
/// compress-stores instead of one voxel at a time. The same bits and bytes as the forms above
/// (the test "vdb files: the bytes openvdb::io::File writes" runs both). On the bunny at
/// 0.5 mm (4 grids, 29k leaves), 1 thread, 8 runs each: the leaves' classification 15.2-17.0
/// -> 11.5-13.4 ms, their serialisation 12.0-13.5 -> 10.3-11.4 ms.
bool wide_writer() {
#ifdef VDBRECON_HAVE_AVX2_PATHS
    static const bool bmi2 = __builtin_cpu_supports("bmi2");
    return bmi2 && wide_vector_loops();
#else
    return false;
#endif
}

#ifdef VDBRECON_HAVE_AVX2_PATHS

/// Every third bit of a 48-bit word (bits 0, 3, ..., 45).
constexpr std::uint64_t kEveryThird = 0x249249249249ULL;

__attribute__((target("avx512f"))) void equal_bits_wide(const float* values, float v,
                                                        std::uint64_t* out) {
    const __m512 b = _mm512_set1_ps(v);
    for (int w = 0; w < 8; ++w) {
        std::uint64_t bits = 0;
        for (int j = 0; j < 64; j += 16) {
            const __m512 x = _mm512_loadu_ps(values + w * 64 + j);
            bits |= std::uint64_t(_mm512_cmp_ps_mask(x, b, _CMP_EQ_OQ)) << j;
        }
        out[w] = bits;
    }
}

/// Sixteen voxels are three vectors of sixteen floats, the components in turn: voxel j's compare
/// bits are 3j, 3j + 1 and 3j + 2 of the 48.
__attribute__((target("avx512f,bmi2"))) void equal_bits_wide(const openvdb::Vec3f* values,
                                                             const openvdb::Vec3f& v,
                                                             std::uint64_t* out) {
    __m512 b[3];
    for (int r = 0; r < 3; ++r) {
        alignas(64) float lane[16];
        for (int i = 0; i < 16; ++i) lane[i] = v[(16 * r + i) % 3];
        b[r] = _mm512_load_ps(lane);
    }
    const float* f = values[0].asPointer();
    for (int w = 0; w < 8; ++w) {
        std::uint64_t bits = 0;
        for (int j = 0; j < 64; j += 16, f += 48) {
            std::uint64_t m = 0;
            for (int r = 0; r < 3; ++r) {
                const __mmask16 eq =
                    _mm512_cmp_ps_mask(_mm512_loadu_ps(f + 16 * r), b[r], _CMP_EQ_OQ);
                m |= std::uint64_t(eq) << (16 * r);
            }
            bits |= _pext_u64(m & m >> 1 & m >> 2, kEveryThird) << j;
        }
        out[w] = bits;
    }
}

/// The active values of a leaf (bits `on`), in order, at `out`; returns the end.
__attribute__((target("avx512f"))) char* active_values_wide(const std::uint64_t* on,
                                                            const float* values, char* out) {
    for (int g = 0; g < 32; ++g) {
        const auto m = __mmask16(on[g >> 2] >> (16 * (g & 3)));
        _mm512_mask_compressstoreu_ps(out, m, _mm512_loadu_ps(values + 16 * g));
        out += sizeof(float) * std::size_t(__builtin_popcount(unsigned(m)));
    }
    return out;
}

__attribute__((target("avx512f,bmi2"))) char* active_values_wide(const std::uint64_t* on,
                                                                 const openvdb::Vec3f* values,
                                                                 char* out) {
    const float* f = values[0].asPointer();
    for (int g = 0; g < 32; ++g, f += 48) {
        const std::uint64_t m16 = (on[g >> 2] >> (16 * (g & 3))) & 0xffffu;
        const std::uint64_t m48 = _pdep_u64(m16, kEveryThird) * 7;  // each voxel's three bits
        for (int r = 0; r < 3; ++r) {
            const auto m = __mmask16(m48 >> (16 * r));
            _mm512_mask_compressstoreu_ps(out, m, _mm512_loadu_ps(f + 16 * r));
            out += sizeof(float) * std::size_t(__builtin_popcount(unsigned(m)));
        }
    }
    return out;
}
#endif

/// equal_bits, by the vector form when `wide` (wide_writer()).
template <typename T>
void equal_bits(const T* values, const T& v, std::uint64_t* out, bool wide) {
#ifdef VDBRECON_HAVE_AVX2_PATHS
    if (wide) {
        equal_bits_wide(values, v, out);
        return;
    }
#endif
    (void)wide;
    equal_bits(values, v, out);
}

/// How one leaf goes into the file: OpenVDB's per-node indicator (the enum in Compression.h),
/// the inactive values it stores (codes 2, 4, 5; inactive[1] is the one a selection mask marks)
/// and the leaf's size in bytes.
template <typename T>
struct LeafCode {
    std::int8_t code = vio::NO_MASK_OR_INACTIVE_VALS;
    T inactive[2];
    std::size_t bytes = 0;
};

template <typename T>
bool has_selection_mask(const LeafCode<T>& c) {
    return c.code == vio::MASK_AND_NO_INACTIVE_VALS || c.code == vio::MASK_AND_ONE_INACTIVE_VAL ||
           c.code == vio::MASK_AND_TWO_INACTIVE_VALS;
}

template <typename T>
int stored_inactive_values(const LeafCode<T>& c) {
    if (c.code == vio::MASK_AND_TWO_INACTIVE_VALS) return 2;
    return c.code == vio::NO_MASK_AND_ONE_INACTIVE_VAL || c.code == vio::MASK_AND_ONE_INACTIVE_VAL
               ? 1
               : 0;
}

/// What classify_leaf's walk over the inactive voxels finds (their distinct values in `seen`,
/// their number in `n`) when those values are only bg and -bg, as in nearly every leaf of the
/// splat's grids: found from the voxels equal to each, a few vector compares, instead of a walk
/// over every inactive voxel, which went to the end of 7,262 of each grid's 7,278 leaves on the
/// bunny at 0.5 mm (its volume written at 1 thread: 0.081 -> 0.064 s). False, with nothing set,
/// for other leaves.
template <typename T>
bool inactive_of_background(const std::uint64_t* on, const T* values, const T& bg, T* seen, int& n,
                            bool wide) {
    std::uint64_t plus[8], minus[8];
    equal_bits(values, bg, plus, wide);
    const T minus_bg = -bg;
    const bool symmetric = minus_bg == bg;  // a zero background
    if (!symmetric) equal_bits(values, minus_bg, minus, wide);
    std::uint64_t any_plus = 0, any_minus = 0;
    for (int w = 0; w < 8; ++w) {
        const std::uint64_t off = ~on[w];
        const std::uint64_t m = symmetric ? 0 : off & minus[w];
        if (off & ~plus[w] & ~m) return false;  // another value
        any_plus |= off & plus[w];
        any_minus |= m;
    }
    // The walk's order of first meeting does not matter: one value is taken as it is, and of
    // two, bg is put second.
    n = 0;
    if (any_minus) seen[n++] = minus_bg;
    if (any_plus) seen[n++] = bg;
    return true;
}

/// The indicator of a leaf from its distinct inactive values (compared with ==, in the order
/// met, at most three counted) and the tree's background bg: none or only +bg need nothing;
/// one other value is stored (or flagged, for -bg); two values need a selection mask (bit set
/// for the second), with +bg left implicit and -bg flagged; more than two, every value is
/// stored.
template <typename T>
LeafCode<T> classify_leaf(const std::uint64_t* on, const T* values, const T& bg, bool wide) {
    LeafCode<T> c;
    T seen[2] = {bg, bg};
    int n = 0;
    if (!inactive_of_background(on, values, bg, seen, n, wide)) {
        for_each_bit(on, /*off=*/true, [&](int i) {
            const T& v = values[i];
            if (!((n > 0 && v == seen[0]) || (n > 1 && v == seen[1]))) {
                if (n < 2) seen[n] = v;
                ++n;
            }
            return n < 3;
        });
    }
    const T minus_bg = -bg;
    if (n == 1 && !(seen[0] == bg)) {
        c.code =
            seen[0] == minus_bg ? vio::NO_MASK_AND_MINUS_BG : vio::NO_MASK_AND_ONE_INACTIVE_VAL;
    } else if (n == 2 && !(seen[0] == bg) && !(seen[1] == bg)) {
        c.code = vio::MASK_AND_TWO_INACTIVE_VALS;
    } else if (n == 2) {
        if (seen[0] == bg) std::swap(seen[0], seen[1]);  // the other value first, bg second
        c.code =
            seen[0] == minus_bg ? vio::MASK_AND_NO_INACTIVE_VALS : vio::MASK_AND_ONE_INACTIVE_VAL;
    } else if (n > 2) {
        c.code = vio::NO_MASK_AND_ALL_VALS;
    }
    c.inactive[0] = seen[0];
    c.inactive[1] = seen[1];
    const std::size_t count = c.code == vio::NO_MASK_AND_ALL_VALS ? kLeafValues : count_on(on);
    c.bytes = kMaskBytes + 1 + sizeof(T) * (std::size_t(stored_inactive_values(c)) + count) +
              (has_selection_mask(c) ? kMaskBytes : 0);
    return c;
}

/// Serialises one leaf (c.bytes bytes) at `out`.
template <typename T>
void write_leaf(const std::uint64_t* on, const T* values, const LeafCode<T>& c, char* out,
                bool wide) {
    std::memcpy(out, on, kMaskBytes);
    out += kMaskBytes;
    *out++ = char(c.code);
    const int stored = stored_inactive_values(c);
    std::memcpy(out, c.inactive, sizeof(T) * std::size_t(stored));
    out += sizeof(T) * std::size_t(stored);
    if (c.code == vio::NO_MASK_AND_ALL_VALS) {
        std::memcpy(out, values, sizeof(T) * kLeafValues);
        return;
    }
    if (has_selection_mask(c)) {
        std::uint64_t selection[8];  // the inactive voxels of the second value
        equal_bits(values, c.inactive[1], selection, wide);
        for (int w = 0; w < 8; ++w) selection[w] &= ~on[w];
        std::memcpy(out, selection, kMaskBytes);
        out += kMaskBytes;
    }
#ifdef VDBRECON_HAVE_AVX2_PATHS
    if (wide) {
        active_values_wide(on, values, out);
        return;
    }
#endif
    for_each_bit(on, /*off=*/false, [&](int i) {
        std::memcpy(out, &values[i], sizeof(T));
        out += sizeof(T);
        return true;
    });
}

/// The bounding box of a leaf's active voxels (mask words `on`; leaf origin `o`), empty when
/// there are none. A voxel's offset is x << 6 | y << 3 | z: word x, byte y of it, bit z.
openvdb::CoordBBox active_box(const std::uint64_t* on, const openvdb::Coord& o) {
    int x0 = -1, x1 = -1;
    std::uint64_t rows = 0;
    for (int x = 0; x < 8; ++x) {
        if (on[x] == 0) continue;
        if (x0 < 0) x0 = x;
        x1 = x;
        rows |= on[x];
    }
    if (x0 < 0) return {};
    unsigned zs = 0;
    for (int y = 0; y < 8; ++y) zs |= unsigned(rows >> (8 * y)) & 0xffu;
    const int y0 = __builtin_ctzll(rows) / 8, y1 = (63 - __builtin_clzll(rows)) / 8;
    const int z0 = __builtin_ctz(zs), z1 = 31 - __builtin_clz(zs);
    return {o.offsetBy(x0, y0, z0), o.offsetBy(x1, y1, z1)};
}

/// One grid's leaves in file order (the order of Tree::writeBuffers), their codes and the offset
/// of each in the grid's buffers (offsets.back() is their total size).
template <typename TreeT>
struct LeafBuffers {
    using T = typename TreeT::ValueType;
    using Leaf = typename TreeT::LeafNodeType;

    explicit LeafBuffers(const TreeT& tree) {
        openvdb::tree::LeafManager<const TreeT> manager(tree);
        leaves.resize(manager.leafCount());
        codes.resize(leaves.size());
        const T bg = tree.background();
        // With the codes, the active voxels' count and bounding box (minima, maxima and sums:
        // the same whatever the split).
        struct Stats {
            openvdb::CoordBBox box;
            openvdb::Index64 count = 0;
        };
        tbb::enumerable_thread_specific<Stats> stats;
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size(), 256),
                          [&](const tbb::blocked_range<std::size_t>& r) {
                              std::uint64_t w[8];
                              Stats& mine = stats.local();
                              for (std::size_t i = r.begin(); i < r.end(); ++i) {
                                  leaves[i] = &manager.leaf(i);
                                  words(i, w);
                                  codes[i] = classify_leaf(w, leaves[i]->buffer().data(), bg, wide);
                                  mine.count += count_on(w);
                                  mine.box.expand(active_box(w, leaves[i]->origin()));
                              }
                          });
        for (const Stats& s : stats) {
            active_count += s.count;
            active_voxels.expand(s.box);
        }
        leaf_stats = !tree.hasActiveTiles() && active_count > 0;
        offsets.assign(leaves.size() + 1, 0);
        for (std::size_t i = 0; i < leaves.size(); ++i)
            offsets[i + 1] = offsets[i] + codes[i].bytes;
    }

    void words(std::size_t i, std::uint64_t* w) const {
        for (openvdb::Index k = 0; k < 8; ++k)
            w[k] = leaves[i]->valueMask().template getWord<std::uint64_t>(k);
    }

    /// Serialises leaves [first, last) at `out` (their offsets relative to leaf `first`).
    void write(std::size_t first, std::size_t last, char* out) const {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(first, last, 64),
                          [&](const tbb::blocked_range<std::size_t>& r) {
                              std::uint64_t w[8];
                              for (std::size_t i = r.begin(); i < r.end(); ++i) {
                                  words(i, w);
                                  write_leaf(w, leaves[i]->buffer().data(), codes[i],
                                             out + (offsets[i] - offsets[first]), wide);
                              }
                          });
    }

    std::vector<const Leaf*> leaves;
    std::vector<LeafCode<T>> codes;
    std::vector<std::size_t> offsets;
    openvdb::CoordBBox active_voxels;   ///< of the leaves
    openvdb::Index64 active_count = 0;  ///< of the leaves
    /// True when the leaves hold every active value (no active tiles) and there is one: then
    /// active_voxels and active_count are the tree's (see add_stats).
    bool leaf_stats = false;
    bool wide = wide_writer();  ///< the vector forms
};

/// GridBase::addStatsMetadata's four entries, its bounding box and count from the leaves' pass
/// where they give them (each grid's evalActiveVoxelBoundingBox and activeVoxelCount walked
/// the tree again: bunny at 0.5 mm, 1 thread, 0.5-1 ms a grid).
template <typename GridT>
void add_stats(openvdb::GridBase& copy, const GridT& grid,
               const LeafBuffers<typename GridT::TreeType>& buffers) {
    if (!buffers.leaf_stats) {
        copy.addStatsMetadata();
        return;
    }
    const openvdb::CoordBBox& box = buffers.active_voxels;
    copy.removeMeta(openvdb::GridBase::META_FILE_BBOX_MIN);
    copy.removeMeta(openvdb::GridBase::META_FILE_BBOX_MAX);
    copy.removeMeta(openvdb::GridBase::META_FILE_MEM_BYTES);
    copy.removeMeta(openvdb::GridBase::META_FILE_VOXEL_COUNT);
    copy.insertMeta(openvdb::GridBase::META_FILE_BBOX_MIN,
                    openvdb::Vec3IMetadata(box.min().asVec3i()));
    copy.insertMeta(openvdb::GridBase::META_FILE_BBOX_MAX,
                    openvdb::Vec3IMetadata(box.max().asVec3i()));
    copy.insertMeta(openvdb::GridBase::META_FILE_MEM_BYTES,
                    openvdb::Int64Metadata(openvdb::Int64(grid.memUsage())));
    copy.insertMeta(openvdb::GridBase::META_FILE_VOXEL_COUNT,
                    openvdb::Int64Metadata(openvdb::Int64(buffers.active_count)));
}

/// A grid's bytes between its descriptor and its buffers, written by OpenVDB as
/// Archive::writeGrid writes them: compression flags, metadata (a shallow copy with the
/// delayed-load codes, the statistics and the compression's name), transform, topology.
template <typename GridT>
std::string grid_head(const Archive& archive, const GridT& grid,
                      const LeafBuffers<typename GridT::TreeType>& buffers) {
    std::ostringstream os(std::ios_base::binary);
    auto stream_meta = std::make_shared<vio::StreamMetadata>();
    vio::setStreamMetadataPtr(os, stream_meta, /*transfer=*/false);
    vio::setDataCompression(os, kCompression);
    vio::setWriteGridStatsMetadata(os, true);
    stream_meta->setHalfFloat(grid.saveFloatAsHalf());
    stream_meta->gridMetadata() = static_cast<const openvdb::MetaMap&>(grid);
    archive.setGridCompression(os, grid);

    vio::DelayedLoadMetadata delayed;
    delayed.resizeMask(buffers.codes.size());
    for (std::size_t i = 0; i < buffers.codes.size(); ++i)
        delayed.setMask(i, buffers.codes[i].code);
    const openvdb::GridBase::Ptr copy = openvdb::ConstPtrCast<openvdb::GridBase>(grid.copyGrid());
    copy->insertMeta(openvdb::GridBase::META_FILE_DELAYED_LOAD, delayed);
    add_stats(*copy, grid, buffers);
    copy->insertMeta(
        openvdb::GridBase::META_FILE_COMPRESSION,
        openvdb::StringMetadata(vio::compressionToString(vio::getDataCompression(os))));
    copy->writeMeta(os);
    grid.writeTransform(os);
    grid.writeTopology(os);
    return os.str();
}

/// One grid: descriptor (with the offsets, known in advance), head, then the leaf buffers one
/// block at a time.
template <typename GridT>
void write_grid(Output& out, const Archive& archive, const GridT& grid) {
    const LeafBuffers<typename GridT::TreeType> buffers(grid.tree());
    const std::string head = grid_head(archive, grid, buffers);
    vio::GridDescriptor gd(grid.getName(), grid.type(), grid.saveFloatAsHalf());
    std::ostringstream desc(std::ios_base::binary);
    gd.writeHeader(desc);
    const std::int64_t grid_pos = out.position() + std::int64_t(desc.tellp()) + 3 * 8;
    gd.setGridPos(grid_pos);
    gd.setBlockPos(grid_pos + std::int64_t(head.size()));
    gd.setEndPos(gd.getBlockPos() + std::int64_t(buffers.offsets.back()));
    gd.writeStreamPos(desc);
    out.put(desc.str());
    out.put(head);
    const std::vector<std::size_t>& offsets = buffers.offsets;
    for (std::size_t first = 0, n = buffers.leaves.size(); first < n;) {
        // As many leaves as fit a block (one leaf is at most 6.3 kB of the 1 MB).
        const std::size_t last =
            std::size_t(std::upper_bound(offsets.begin() + std::ptrdiff_t(first) + 1, offsets.end(),
                                         offsets[first] + out.capacity()) -
                        offsets.begin()) -
            1;
        const std::size_t bytes = offsets[last] - offsets[first];
        buffers.write(first, last, out.room(bytes));
        out.advance(bytes);
        first = last;
    }
}

/// Refuses a grid outside write_vdb_file's terms, or one whose name or tree an earlier one has.
void check_grid(const openvdb::GridBase::ConstPtr& g, std::set<std::string>& names,
                std::set<const openvdb::TreeBase*>& trees) {
    const bool known = g && (g->isType<openvdb::FloatGrid>() || g->isType<openvdb::Vec3SGrid>());
    if (!known || g->getName().empty() || !names.insert(g->getName()).second ||
        !trees.insert(&g->baseTree()).second || g->saveFloatAsHalf()) {
        throw InvalidArgument(
            "write_vdb_file: grids must be float or Vec3f grids with distinct names and "
            "trees of their own, without half floats");
    }
}

/// Frees a tree's leaves on this thread. OpenVDB's clear() frees them from every thread at once,
/// and the CLI's one heap arena then puts a thread that finds its lock taken to sleep
/// (detail/release.h, heap_lock): the file is written beside another stage (the CLI's clean),
/// whose allocations the parallel frees held up.
template <typename TreeT>
void free_leaves(TreeT& tree) {
    std::vector<typename TreeT::LeafNodeType*> leaves;
    tree.stealNodes(leaves);
    for (auto* leaf : leaves) delete leaf;
}

}  // namespace

void write_vdb_file(std::FILE* file, const std::string& path, const std::vector<FileGrid>& grids,
                    const openvdb::MetaMap& meta) {
    // The given grids are checked before anything is written, a made one when it is made.
    std::set<std::string> names;
    std::set<const openvdb::TreeBase*> trees;
    for (const FileGrid& g : grids) {
        if (g.grid || !g.make) check_grid(g.grid, names, trees);
    }
    const Archive archive;
    std::ostringstream head(std::ios_base::binary);
    archive.writeHeader(head, /*seekable=*/true);
    meta.writeMeta(head);
    const std::int32_t count = std::int32_t(grids.size());
    head.write(reinterpret_cast<const char*>(&count), sizeof(count));

    Output out(file, path);
    out.put(head.str());
    for (const FileGrid& source : grids) {
        openvdb::GridBase::Ptr made;
        if (!source.grid) {
            made = source.make();
            check_grid(made, names, trees);
        }
        const openvdb::GridBase& g = made ? *made : *source.grid;
        if (g.isType<openvdb::FloatGrid>()) {
            write_grid(out, archive, static_cast<const openvdb::FloatGrid&>(g));
        } else {
            write_grid(out, archive, static_cast<const openvdb::Vec3SGrid&>(g));
        }
        if (made) {
            // A made grid is freed here; its tree's address may serve a later one.
            trees.erase(&g.baseTree());
            if (made->isType<openvdb::FloatGrid>()) {
                free_leaves(static_cast<openvdb::FloatGrid&>(*made).tree());
            } else {
                free_leaves(static_cast<openvdb::Vec3SGrid&>(*made).tree());
            }
        }
    }
    out.finish();
}

}  // namespace vdbrecon::detail
