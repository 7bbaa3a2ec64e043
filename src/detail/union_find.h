// Union-find with labels that do not depend on the order of the unions, shared by the meshes'
// connectivity (mesh_graph.h) and the normals' orientation patches.
#pragma once

#include <algorithm>
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

}  // namespace vdbrecon::detail
