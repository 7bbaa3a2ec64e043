// What the dual meshers (`dual` and `dc`) share: one vertex per chain of a cell's loop
// (crossings.h: loop_chains), gathered per leaf, and one quad per crossing whose four cells
// all have a vertex. They differ in where a vertex goes and how a quad is split.
#pragma once

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <memory>
#include <numeric>
#include <vector>

#include "detail/crossings.h"
#include "detail/mesh_common.h"

namespace vdbrecon::detail {

/// A growing array in fixed blocks: no copy when it grows and at most one block unused, where a
/// vector doubling its capacity copies everything and can leave half of it unused (memory that
/// is touched afresh costs about 1 ms per MB on the 2-core VM).
template <typename T>
class BlockArray {
  public:
    void push_back(const T& v) {
        if (size_ % kBlock == 0) blocks_.emplace_back(new T[kBlock]);
        blocks_.back()[size_++ % kBlock] = v;
    }
    std::size_t size() const { return size_; }
    const T& operator[](std::size_t i) const { return blocks_[i / kBlock][i % kBlock]; }

  private:
    static constexpr std::size_t kBlock = 8192;
    std::vector<std::unique_ptr<T[]>> blocks_;
    std::size_t size_ = 0;
};

/// The vertices of the surface cells, made leaf by leaf in parallel, and the four cells'
/// vertices of each crossing. A vertex is known as (leaf, index in the leaf) until numbered
/// (number()); every (crossing, slot) belongs to exactly one cell, so there are no two writers.
/// The vertices go to one block array per thread, a leaf's in a row (one thread visits all cells
/// of a leaf): an array per leaf meant an allocation and a free per leaf, which two threads
/// sharing one heap make slower than one.
template <typename V>
class DualVertices {
  public:
    static constexpr std::uint64_t kNone = ~std::uint64_t(0);

    DualVertices(std::size_t leaves, std::size_t crossings)
        : leaf_buffer_(leaves, nullptr),
          leaf_first_(leaves, 0),
          base_(leaves + 1, 0),
          around_(crossings) {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, around_.size(), 4096),
                          [&](const tbb::blocked_range<std::size_t>& r) {
                              std::fill(around_.begin() + std::ptrdiff_t(r.begin()),
                                        around_.begin() + std::ptrdiff_t(r.end()),
                                        std::array<std::uint64_t, 4>{kNone, kNone, kNone, kNone});
                          });
    }

    /// Adds vertex v of leaf L for the chain of cell loop l that starts at loop position
    /// `start` and holds `size` edges: those edges' crossings learn it. Call from the thread
    /// that visits leaf L (for_each_surface_cell).
    void add(std::size_t L, const SurfaceCell& cell, int l, int start, int size, const V& v) {
        if (!leaf_buffer_[L]) {  // the leaf's first vertex
            leaf_buffer_[L] = &buffers_.local();
            leaf_first_[L] = leaf_buffer_[L]->size();
        }
        const std::uint64_t id = (std::uint64_t(L) << 32) | base_[L + 1]++;
        leaf_buffer_[L]->push_back(v);
        const int n = cell.loops.size[l];
        for (int i = 0; i < size; ++i) {
            const int e = cell.loops.edge[l][(start + i) % n];
            const int a = kEdgeAxis[e];
            const int* s = kCubeCorner[kEdgeCorner[e][0]];
            // Which of the four cells around the edge this one is: its offset from the edge's
            // start voxel along the two other axes (b, c) = (a + 1, a + 2).
            const int slot = s[(a + 1) % 3] + 2 * s[(a + 2) % 3];
            around_[std::size_t(cell.edge_id[e])][std::size_t(slot)] = id;
        }
    }

    /// Numbers the vertices in leaf order; returns their count.
    std::size_t number() {
        std::partial_sum(base_.begin(), base_.end(), base_.begin());
        return base_.back();
    }

    /// After number(): hands each vertex to put(its number, vertex), in parallel, and frees the
    /// per-thread arrays.
    template <typename Put>
    void gather(Put&& put) {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaf_buffer_.size(), 16),
                          [&](const tbb::blocked_range<std::size_t>& r) {
                              for (std::size_t L = r.begin(); L < r.end(); ++L) {
                                  if (!leaf_buffer_[L]) continue;
                                  const BlockArray<V>& in = *leaf_buffer_[L];
                                  for (std::size_t k = 0; k < base_[L + 1] - base_[L]; ++k) {
                                      put(base_[L] + k, in[leaf_first_[L] + k]);
                                  }
                              }
                          });
        buffers_.clear();
    }

    /// The triangles, after number(): one quad per crossing whose four cells all have a
    /// vertex, counter-clockwise seen from outside, split in two by `diagonal02(v)` (true: along
    /// v[0]-v[2], else v[1]-v[3]). Counted per leaf first, so each leaf writes its triangles
    /// straight into place.
    template <typename Diagonal>
    void emit_quads(const Crossings& crossings, std::vector<Triangle>& triangles,
                    Diagonal&& diagonal02) const {
        const std::size_t leaves = leaf_buffer_.size();
        std::vector<std::size_t> first(leaves + 1, 0);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves, 64),
                          [&](const tbb::blocked_range<std::size_t>& r) {
                              for (std::size_t L = r.begin(); L < r.end(); ++L) {
                                  first[L + 1] =
                                      2 * quads_of_leaf(crossings, L, [](std::size_t) {});
                              }
                          });
        std::partial_sum(first.begin(), first.end(), first.begin());
        triangles.resize(first.back());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves, 8),
                          [&](const tbb::blocked_range<std::size_t>& r) {
                              for (std::size_t L = r.begin(); L < r.end(); ++L) {
                                  Triangle* out = triangles.data() + first[L];
                                  quads_of_leaf(crossings, L, [&](std::size_t c) {
                                      const auto& q = around_[c];
                                      // Counter-clockwise around +axis: slots 0, 1, 3, 2. Outward
                                      // is +axis when the edge starts inside.
                                      std::array<std::int32_t, 4> v = {global(q[0]), global(q[1]),
                                                                       global(q[3]), global(q[2])};
                                      if (!crossings.start_inside[c])
                                          std::reverse(v.begin(), v.end());
                                      if (diagonal02(v)) {
                                          *out++ = {v[0], v[1], v[2]};
                                          *out++ = {v[0], v[2], v[3]};
                                      } else {
                                          *out++ = {v[0], v[1], v[3]};
                                          *out++ = {v[1], v[2], v[3]};
                                      }
                                  });
                              }
                          });
    }

  private:
    /// Calls quad(c) for each crossing c of leaf L whose four cells all have a vertex, in
    /// order; returns how many there are.
    template <typename Quad>
    std::size_t quads_of_leaf(const Crossings& crossings, std::size_t L, Quad&& quad) const {
        std::size_t n = 0;
        for (std::size_t c = crossings.leaf_begin[L]; c < crossings.leaf_begin[L + 1]; ++c) {
            const auto& q = around_[c];
            if (q[0] == kNone || q[1] == kNone || q[2] == kNone || q[3] == kNone) continue;
            quad(c);
            ++n;
        }
        return n;
    }

    std::int32_t global(std::uint64_t id) const {
        return std::int32_t(base_[id >> 32] + (id & 0xffffffffu));
    }

    tbb::enumerable_thread_specific<BlockArray<V>> buffers_;
    std::vector<BlockArray<V>*> leaf_buffer_;
    std::vector<std::size_t> leaf_first_;
    std::vector<std::size_t> base_;  ///< per leaf its vertex count (at L + 1), then first index
    FillLater<std::array<std::uint64_t, 4>> around_;  ///< per crossing, its cells' vertices
};

}  // namespace vdbrecon::detail
