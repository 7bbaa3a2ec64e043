// Union-find with labels that do not depend on the order of the unions, shared by the meshes'
// connectivity (mesh_graph.h) and the normals' orientation patches.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace vdbrecon::detail {

/// Union-find over 0..n-1 whose roots are the smallest index of their set, so that the labels
/// do not depend on the order of the unions.
class MinUnionFind {
  public:
    explicit MinUnionFind(std::size_t n) : parent_(n) {
        for (std::size_t i = 0; i < n; ++i) parent_[i] = std::int32_t(i);
    }
    std::int32_t find(std::int32_t x) {
        while (parent_[std::size_t(x)] != x) {
            parent_[std::size_t(x)] = parent_[std::size_t(parent_[std::size_t(x)])];  // halving
            x = parent_[std::size_t(x)];
        }
        return x;
    }
    void unite(std::int32_t a, std::int32_t b) {
        a = find(a);
        b = find(b);
        if (a != b) parent_[std::size_t(std::max(a, b))] = std::min(a, b);
    }
    /// Every element's root; the structure is spent.
    std::vector<std::int32_t> labels() && {
        for (std::size_t i = 0; i < parent_.size(); ++i) parent_[i] = find(std::int32_t(i));
        return std::move(parent_);
    }

  private:
    std::vector<std::int32_t> parent_;
};

/// MinUnionFind for unions from several threads at once (lock-free: a root is linked under the
/// smaller one by compare-and-swap, and retried when another thread linked it first). The sets
/// do not depend on the order of the unions, nor therefore the labels, each set's smallest index.
class ConcurrentMinUnionFind {
  public:
    explicit ConcurrentMinUnionFind(std::size_t n) : parent_(n) {
        for (std::size_t i = 0; i < n; ++i) parent_[i].store(std::int32_t(i), kRelaxed);
    }
    std::int32_t find(std::int32_t x) const {
        for (;;) {
            const std::int32_t p = parent_[std::size_t(x)].load(kRelaxed);
            if (p == x) return x;
            x = p;
        }
    }
    void unite(std::int32_t a, std::int32_t b) {
        for (;;) {
            a = find(a);
            b = find(b);
            if (a == b) return;
            if (a > b) std::swap(a, b);  // b, the larger root, goes under a
            std::int32_t expected = b;
            if (parent_[std::size_t(b)].compare_exchange_weak(expected, a, kRelaxed)) return;
        }
    }
    /// Every element's root (after the unions, from one thread or after they all ended).
    std::vector<std::int32_t> labels() const {
        std::vector<std::int32_t> out(parent_.size());
        for (std::size_t i = 0; i < out.size(); ++i) {
            // A parent is smaller than its child: the roots of 0..i-1 are known already.
            const std::int32_t p = parent_[i].load(kRelaxed);
            out[i] = p == std::int32_t(i) ? p : out[std::size_t(p)];
        }
        return out;
    }

  private:
    static constexpr std::memory_order kRelaxed = std::memory_order_relaxed;
    std::vector<std::atomic<std::int32_t>> parent_;
};

}  // namespace vdbrecon::detail
