// Presumming (aggregate_samples, splat.h) a cloud at a time into one set of cell groups, for a
// fusion that gathers the groups of many frames before it splats them.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "vdbrecon/splat.h"

namespace vdbrecon::detail {

/// The groups of aggregate_samples() kept open: clouds added one after another sum into the
/// same groups (a group of later samples joins the first group of its cell whose summed normal
/// is less than 90 degrees from its own), and take() gives them as aggregate_samples() of the
/// clouds joined in order would. The cells live in a hash table, so adding costs no sort.
class CellGroups {
  public:
    /// `cell` > 0: the cell edge in sigmas of each level. `colors`: whether the clouds added
    /// have colours (all or none).
    CellGroups(const SplatOptions& options, double cell, bool colors);

    /// Adds the cloud's samples in order (those the splat would skip are left out); false,
    /// adding nothing, when one reaches more than 2^19 cells from the origin.
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
    struct Group {
        double c, sigma;
        double p[3], n[3], rgb[3];
        std::uint32_t next;  ///< the cell's next group
    };
    static constexpr Group kZero{0.0, 0.0, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}, kNone};
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
    static constexpr int kLevels = 15;  ///< sigma levels, half octaves above min_sigma_voxels
    double inv_edge_[kLevels];          ///< 1 / the cell edge of each level, world units
    Blocks groups_;
    std::vector<Slot> slots_;  ///< open addressing, a power of two, at most half full
    std::size_t cells_ = 0;
    std::uint64_t last_key_ = ~std::uint64_t(0);  ///< the cell found last (none: all ones)
    std::size_t last_slot_ = 0;
};

}  // namespace vdbrecon::detail
