// The cloud of a streamed tile job on disk, grouped by cell (stream_tiles.cpp): a scratch file
// of fixed-size records (a point's row in the cloud, its position, and the columns the file
// has), cells in key order, each cell's points in the cloud's order; loaded a box of cells at a
// time, in the cloud's order. Side files hold one value per point in the same order.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <numeric>
#include <string>
#include <unordered_map>
#include <vector>

#include "detail/radix_sort.h"
#include "detail/spool.h"
#include "detail/tiles.h"
#include "vdbrecon/types.h"

namespace vdbrecon::detail::streamed {

using Key = TileKey;  // a cell's coordinates

/// A record's columns: its row in the cloud (uint32), position and normal, and those of the
/// optional columns the file has.
struct Layout {
    bool normals = true, colors = false, scales = false, confidences = false;
    std::size_t bytes() const {
        return 16 + (normals ? 12 : 0) + (colors ? 12 : 0) + (scales ? 4 : 0) +
               (confidences ? 4 : 0);
    }
};

/// Points of the store loaded for a region, in the cloud's order.
struct Loaded {
    PointCloud cloud;
    std::vector<std::uint32_t> row;  ///< each point's row in the whole cloud (increasing)
    std::vector<char> core;          ///< whether it lies in the region, not the halo
    /// The cells read, in the store's order: their first record and size, and whether the
    /// region holds them; and where each loaded point was among their records.
    std::vector<std::array<std::uint64_t, 3>> ranges;
    std::vector<std::uint32_t> order;
    Key lo{}, hi{};                  ///< the box of cells loaded around the region
    std::vector<std::size_t> cells;  ///< every cell loaded (sorted): that box's, and others
    std::size_t size() const { return row.size(); }
};

/// The cloud on disk, grouped by cell.
class CellStore {
  public:
    CellStore(Layout layout, double edge)
        : layout_(layout), edge_(edge), file_("tiles: the points by cell") {}

    double edge() const { return edge_; }
    bool has_scales() const { return layout_.scales; }
    bool has_normals() const { return layout_.normals; }
    const std::vector<Key>& keys() const { return keys_; }
    std::uint64_t cell_size(std::size_t j) const { return begin_[j + 1] - begin_[j]; }
    std::uint64_t points() const { return begin_.empty() ? 0 : begin_.back(); }
    const Key& lowest() const { return lowest_; }
    const Key& highest() const { return highest_; }

    Key key_of(const Vec3f& p) const {
        Key k;
        for (int a = 0; a < 3; ++a) k[std::size_t(a)] = int(std::floor(double(p[a]) / edge_));
        return k;
    }

    void count(const PointCloud& chunk) {
        for (std::size_t i = 0; i < chunk.size(); ++i) ++counts_[key_of(chunk.positions[i])];
    }

    /// After count(): the cells' ranges.
    void place() {
        for (const auto& e : counts_) keys_.push_back(e.first);
        std::sort(keys_.begin(), keys_.end());
        begin_.assign(1, 0);
        lowest_ = highest_ = keys_.front();
        for (std::size_t j = 0; j < keys_.size(); ++j) {
            begin_.push_back(begin_.back() + counts_[keys_[j]]);
            counts_[keys_[j]] = j;  // from here on: the cell's number
            for (std::size_t a = 0; a < 3; ++a) {
                lowest_[a] = std::min(lowest_[a], keys_[j][a]);
                highest_[a] = std::max(highest_[a], keys_[j][a]);
            }
        }
        fill_.assign(begin_.begin(), begin_.end() - 1);
    }

    /// After place(): a chunk's points (rows first_row on) into their cells (a counting sort
    /// of the chunk by cell, then a write per cell it touches).
    void write(const PointCloud& chunk, std::uint32_t first_row) {
        const std::size_t n = chunk.size(), rec = layout_.bytes();
        std::vector<std::uint32_t> cell(n);
        std::vector<std::size_t> at(keys_.size() + 1, 0);  // counts, then offsets
        for (std::size_t i = 0; i < n; ++i) {
            cell[i] = std::uint32_t(counts_.find(key_of(chunk.positions[i]))->second);
            ++at[cell[i] + 1];
        }
        std::partial_sum(at.begin(), at.end(), at.begin());
        const std::vector<std::size_t> start = at;
        std::string bytes(n * rec, '\0');
        for (std::size_t i = 0; i < n; ++i) {
            pack(chunk, i, first_row + std::uint32_t(i), bytes.data() + at[cell[i]]++ * rec);
        }
        for (std::size_t j = 0; j < keys_.size(); ++j) {
            const std::size_t count = start[j + 1] - start[j];
            if (count == 0) continue;
            file_.write_at(fill_[j] * rec, bytes.data() + start[j] * rec, count * rec);
            fill_[j] += count;
        }
    }

    /// The cells in the box [lo, hi] (fn(j) for occupied cell j, in key order).
    template <typename Fn>
    void cells_in(const Key& lo, const Key& hi, Fn&& fn) const {
        for (int x = lo[0]; x <= hi[0]; ++x) {
            for (int y = lo[1]; y <= hi[1]; ++y) {
                auto it = std::lower_bound(keys_.begin(), keys_.end(), Key{x, y, lo[2]});
                for (; it != keys_.end() && (*it)[0] == x && (*it)[1] == y && (*it)[2] <= hi[2];
                     ++it) {
                    fn(std::size_t(it - keys_.begin()));
                }
            }
        }
    }

    /// The points of the cells in boxes[0] (the loaded box) and the other boxes; those of the
    /// cells `core` (sorted) are the core.
    Loaded load(const std::vector<std::array<Key, 2>>& boxes,
                const std::vector<std::size_t>& core_cells) const {
        Loaded l;
        l.lo = boxes[0][0];
        l.hi = boxes[0][1];
        for (const auto& b : boxes) cells_in(b[0], b[1], [&](std::size_t j) { l.cells.push_back(j); });
        std::sort(l.cells.begin(), l.cells.end());
        l.cells.erase(std::unique(l.cells.begin(), l.cells.end()), l.cells.end());
        std::uint64_t total = 0;
        for (std::size_t j : l.cells) {
            const bool core = std::binary_search(core_cells.begin(), core_cells.end(), j);
            l.ranges.push_back({begin_[j], cell_size(j), core ? 1u : 0u});
            total += cell_size(j);
        }
        const std::size_t rec = layout_.bytes();
        std::string bytes(std::size_t(total) * rec, '\0');
        std::vector<char> core(total);
        std::size_t o = 0;
        for (const auto& r : l.ranges) {
            file_.read_at(r[0] * rec, bytes.data() + o * rec, std::size_t(r[1]) * rec);
            std::fill_n(core.begin() + std::ptrdiff_t(o), r[1], char(r[2]));
            o += std::size_t(r[1]);
        }
        // In the cloud's order: (row, record) pairs sorted by row.
        std::vector<std::array<std::uint32_t, 2>> by_row(total);
        for (std::size_t i = 0; i < total; ++i) {
            std::memcpy(&by_row[i][0], bytes.data() + i * rec, 4);
            by_row[i][1] = std::uint32_t(i);
        }
        int bits = 1;
        while (bits < 32 && (std::uint64_t(1) << bits) < points()) ++bits;
        radix_sort(by_row, bits, [](const std::array<std::uint32_t, 2>& e) { return e[0]; });
        l.order.resize(total);
        for (std::size_t i = 0; i < total; ++i) l.order[i] = by_row[i][1];
        unpack(bytes, l);
        l.core.resize(total);
        for (std::size_t i = 0; i < total; ++i) l.core[i] = core[l.order[i]];
        return l;
    }

    /// A scratch file of one value per point, in the store's order.
    template <typename T>
    class Side {
      public:
        explicit Side(const char* what) : file_(what) {}
        /// The loaded points' values, in their order.
        std::vector<T> read(const Loaded& l) const {
            std::vector<T> flat(l.size());
            std::size_t o = 0;
            for (const auto& r : l.ranges) {
                file_.read_at(r[0] * sizeof(T), flat.data() + o, std::size_t(r[1]) * sizeof(T));
                o += std::size_t(r[1]);
            }
            std::vector<T> out(l.size());
            for (std::size_t i = 0; i < l.size(); ++i) out[i] = flat[l.order[i]];
            return out;
        }
        /// The core points' values (v has one per loaded point; the halo's are not written).
        void write(const Loaded& l, const std::vector<T>& v) {
            std::vector<T> flat(l.size());
            for (std::size_t i = 0; i < l.size(); ++i) flat[l.order[i]] = v[i];
            std::size_t o = 0;
            for (const auto& r : l.ranges) {
                if (r[2]) {
                    file_.write_at(r[0] * sizeof(T), flat.data() + o,
                                   std::size_t(r[1]) * sizeof(T));
                }
                o += std::size_t(r[1]);
            }
        }
        /// Values [first, first + n) of the store's order.
        void scan_range(std::uint64_t first, T* to, std::size_t n) const {
            file_.read_at(first * sizeof(T), to, n * sizeof(T));
        }
        /// fn(values, first, count) over the first n values, a chunk at a time.
        template <typename Fn>
        void scan(std::uint64_t n, Fn&& fn) const {
            constexpr std::uint64_t kChunk = std::uint64_t(1) << 20;
            std::vector<T> buffer;
            for (std::uint64_t first = 0; first < n; first += kChunk) {
                buffer.resize(std::size_t(std::min(kChunk, n - first)));
                file_.read_at(first * sizeof(T), buffer.data(), buffer.size() * sizeof(T));
                fn(buffer.data(), first, buffer.size());  // (values, first index, count)
            }
        }

      private:
        Spool file_;
    };

  private:
    void pack(const PointCloud& c, std::size_t i, std::uint32_t row, char* p) const {
        const auto put = [&p](const void* v, std::size_t n) {
            std::memcpy(p, v, n);
            p += n;
        };
        put(&row, 4);
        put(&c.positions[i], 12);
        if (layout_.normals) put(&c.normals[i], 12);
        if (layout_.colors) put(&c.colors[i], 12);
        if (layout_.scales) put(&c.scales[i], 4);
        if (layout_.confidences) put(&c.confidences[i], 4);
    }

    void unpack(const std::string& bytes, Loaded& l) const {
        const std::size_t n = l.order.size(), rec = layout_.bytes();
        std::vector<Vec3f> pos(n), nrm(layout_.normals ? n : 0), col(layout_.colors ? n : 0);
        std::vector<float> sc(layout_.scales ? n : 0), conf(layout_.confidences ? n : 0);
        l.row.resize(n);
        for (std::size_t i = 0; i < n; ++i) {
            const char* p = bytes.data() + std::size_t(l.order[i]) * rec;
            const auto get = [&p](void* v, std::size_t len) {
                std::memcpy(v, p, len);
                p += len;
            };
            get(&l.row[i], 4);
            get(&pos[i], 12);
            if (layout_.normals) get(&nrm[i], 12);
            if (layout_.colors) get(&col[i], 12);
            if (layout_.scales) get(&sc[i], 4);
            if (layout_.confidences) get(&conf[i], 4);
        }
        l.cloud.positions = std::move(pos);
        l.cloud.normals = std::move(nrm);
        l.cloud.colors = std::move(col);
        l.cloud.scales = std::move(sc);
        l.cloud.confidences = std::move(conf);
    }

    Layout layout_;
    double edge_;
    std::unordered_map<Key, std::uint64_t, TileKeyHash> counts_;
    std::vector<Key> keys_;
    std::vector<std::uint64_t> begin_, fill_;
    Key lowest_{}, highest_{};
    mutable Spool file_;
};

}  // namespace vdbrecon::detail::streamed
