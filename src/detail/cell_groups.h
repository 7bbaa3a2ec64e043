// Presumming (aggregate_samples, splat.h) a cloud at a time into one set of cell groups, for a
// fusion that gathers the groups of many frames before it splats them.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "vdbrecon/splat.h"

namespace vdbrecon::detail {

/// aggregate_samples() for samples that come in runs of one cell (a depth frame's, in image
/// order): the cells in CellGroups' hash table, which remembers the last cell, instead of a
/// sort (Kinect frames fused at 1 cm: 17 % slower with the sort). The same groups; a cloud
/// reaching 2^18 cells or more from the origin is returned as it is.
PointCloud presum_in_order(PointCloud cloud, const SplatOptions& options, double cell);

/// Presumming's cells (aggregate_samples): a sample's sigma level (half octaves about
/// min_sigma_voxels, kBelow of them below it for sigmas before the clamp) and its cell on that
/// level's grid, fixed in the cloud's frame: `cell` sigmas of the level on an edge, at most
/// `max_cell` voxels (0: no cap). `raw_levels`: a sample's level follows its sigma before the
/// clamp (raw_sigma_voxels), else its kernel's.
class PresumCells {
  public:
    static constexpr int kBelow = 8;             ///< levels below min_sigma_voxels
    static constexpr int kLevels = kBelow + 15;  ///< sigma levels
    PresumCells(const SplatOptions& options, double cell, double max_cell, bool raw_levels);
    /// The cells splat() presums in (SplatOptions::aggregate, aggregate_max_cell, raw levels):
    /// the one rule of its groups and of the tiles' anchors, which must agree.
    static PresumCells of_splat(const SplatOptions& options) {
        return PresumCells(options, options.aggregate, options.aggregate_max_cell, true);
    }
    /// The level of a sample of this scale (0: none) whose kernel's sigma is s (voxels).
    int sample_level(const SplatOptions& options, float scale, double s) const {
        return level(raw_levels_ ? raw_sigma_voxels(options, scale) : s);
    }
    /// The level of a kernel of sigma s (voxels).
    int level(double s) const {
        // The level of min_sigma up to 2^0.25 min_sigma (1.18920712 ...), where the rounded
        // 2 log2 is 0, without a log.
        if (s >= min_sigma_ && s <= 1.189 * min_sigma_) return kBelow;
        const int l = int(std::lround(2.0 * std::log2(s / min_sigma_)));
        return std::clamp(l, -kBelow, kLevels - 1 - kBelow) + kBelow;
    }
    /// Coordinate x (world units, the cloud's frame) as the level's cell index, or false when it
    /// lies 2^18 cells or more from the origin.
    bool cell(double x, int level, std::int64_t& c) const {
        // floor(x) for |x| < 2^18 as a truncation of the positive x + 2^19 (no libm call where
        // the target lacks SSE4.1's rounding instruction).
        const double y = x * inv_edge_[level];
        if (!(std::fabs(y) < double(kBias))) return false;
        c = std::int64_t(y + double(2 * kBias)) - 2 * kBias;
        return true;
    }
    /// Point p's cell on the level's grid, or false when an axis lies 2^18 cells or more from
    /// the origin (the one rule of presumming's keys and the tiles' anchors).
    bool cell(const Vec3f& p, int level, std::int64_t c[3]) const {
        for (int a = 0; a < 3; ++a) {
            if (!cell(double(p[a]), level, c[a])) return false;
        }
        return true;
    }
    /// The centre of cell c of the level along one axis, world units.
    double centre(std::int64_t c, int level) const { return (double(c) + 0.5) / inv_edge_[level]; }
    /// Half the largest cell's diagonal, world units.
    double max_half_diagonal() const;
    static constexpr int kBits = 19;  ///< bits of a biased cell index
    static constexpr std::int64_t kBias = std::int64_t(1) << (kBits - 1);

  private:
    double min_sigma_;
    bool raw_levels_;
    double inv_edge_[kLevels];  ///< 1 / the cell edge of each level, world units
};

/// aggregate_samples() in given cells (see there; `max_angle` likewise), `options` validated by
/// the caller (it made the cells from them).
PointCloud presum_in_cells(PointCloud cloud, const SplatOptions& options, const PresumCells& cells,
                           double max_angle);

/// A group's sums (the samples' confidence c, c sigma, c p, c n and c rgb), in double.
struct GroupSums {
    double c, sigma;
    double p[3], n[3], rgb[3];
};

/// The groups of aggregate_samples() kept open: clouds added one after another sum into the
/// same groups (a group of later samples joins the first group of its cell whose summed normal
/// is less than 90 degrees from its own), and take() gives them as aggregate_samples() of the
/// clouds joined in order would. The cells live in a hash table, so adding costs no sort.
class CellGroups {
  public:
    /// `cell` > 0: the cell edge in sigmas of each level (PresumCells, no cap). `colors`:
    /// whether the clouds added have colours (all or none).
    CellGroups(const SplatOptions& options, double cell, bool colors);

    /// Adds the cloud's samples in order (those the splat would skip are left out); false,
    /// adding nothing, when one reaches 2^18 cells or more from the origin.
    bool add(const PointCloud& cloud);
    /// The groups as samples, cells in (level, z, y, x) order and each cell's groups in the
    /// order they were opened, in `origin`'s frame; empties this.
    PointCloud take(const Vec3d& origin);

    bool empty() const { return groups_.size() == 0; }
    bool colors() const { return colors_; }
    /// Memory of the groups and the cells' table, bytes.
    std::size_t memory_bytes() const {
        return groups_.size() * sizeof(Group) + slots_.capacity() * sizeof(Slot);
    }

  private:
    static constexpr std::uint32_t kNone = 0xffffffffu;
    /// Trivial, so that a block of them is made without initialising (Blocks::add zeroes each).
    struct Group : GroupSums {
        std::uint32_t next;  ///< the cell's next group
    };
    static constexpr Group kZero{{0.0, 0.0, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}}, kNone};
    /// The groups in blocks of 4096: growth never copies them, nor holds room for twice as
    /// many (a batch of frames holds ~10^5 groups).
    class Blocks {
      public:
        std::size_t size() const { return size_; }
        Group& operator[](std::uint32_t g) { return blocks_[g >> kLog][g & (kSize - 1)]; }
        const Group& operator[](std::uint32_t g) const { return blocks_[g >> kLog][g & (kSize - 1)]; }
        /// A new zero group; its index. A block's groups are zeroed as they are added, not all
        /// when it is made (4096 constructor calls of a small `rep stos` each cost more).
        std::uint32_t add() {
            if ((size_ & (kSize - 1)) == 0) {
                blocks_.push_back(std::unique_ptr<Group[]>(new Group[kSize]));
            }
            const std::uint32_t g = std::uint32_t(size_++);
            (*this)[g] = kZero;
            return g;
        }
        void clear() {
            blocks_.clear();
            size_ = 0;
        }

      private:
        static constexpr int kLog = 12;
        static constexpr std::size_t kSize = std::size_t(1) << kLog;
        std::vector<std::unique_ptr<Group[]>> blocks_;
        std::size_t size_ = 0;
    };
    struct Slot {
        std::uint64_t key;
        std::uint32_t first;  ///< the cell's first group
    };

    std::uint32_t& first_group(std::uint64_t key);
    /// A table twice as large, or more, so that it holds `cells` at most half full.
    void grow(std::size_t cells);

    SplatOptions options_;
    bool colors_;
    PresumCells cells_of_;
    Blocks groups_;
    std::vector<Slot> slots_;  ///< open addressing, a power of two, at most half full
    std::size_t cells_ = 0;
    std::uint64_t last_key_ = ~std::uint64_t(0);  ///< the cell found last (none: all ones)
    std::size_t last_slot_ = 0;
};

}  // namespace vdbrecon::detail
