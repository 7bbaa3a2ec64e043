// The value of a given rank among non-negative floats that need not all be in memory at once
// (what std::nth_element puts there), shared by the outlier stage (the median d of a cloud in
// memory) and the streamed tiles (medians and percentiles of values spilled to disk).
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

#include "vdbrecon/types.h"

namespace vdbrecon::detail {

/// The value of rank `rank` among the values >= 0 that scan(fn) hands over a chunk at a time
/// (fn(values, count)), in two scans: a histogram of their top 16 bits (such floats order like
/// their bit patterns), then only the values of the bucket that holds the rank, selected.
/// Negative values (markers) order after all of them (the sign bit): a rank below the count of
/// the values >= 0 selects among those alone.
template <typename Scan>
float select_rank(std::uint64_t rank, const Scan& scan) {
    const auto bucket = [](float x) {
        std::uint32_t bits;
        std::memcpy(&bits, &x, sizeof bits);
        return std::size_t(bits >> 16);
    };
    std::vector<std::uint64_t> count(std::size_t(1) << 16, 0);
    scan([&](const float* v, std::size_t n) {
        for (std::size_t i = 0; i < n; ++i) ++count[bucket(v[i])];
    });
    std::size_t b = 0;
    std::uint64_t below = 0;
    while (below + count[b] <= rank) below += count[b++];
    std::vector<float> in;
    in.reserve(std::size_t(count[b]));
    scan([&](const float* v, std::size_t n) {
        for (std::size_t i = 0; i < n; ++i) {
            if (bucket(v[i]) == b) in.push_back(v[i]);
        }
    });
    const auto at = in.begin() + std::ptrdiff_t(rank - below);
    std::nth_element(in.begin(), at, in.end());
    return *at;
}

/// The same over the values of an array (a vector, a column).
inline float select_rank(std::uint64_t rank, Span<float> v) {
    return select_rank(rank, [v](const auto& fn) { fn(v.data(), v.size()); });
}
inline float select_rank(std::uint64_t rank, const std::vector<float>& v) {
    return select_rank(rank, Span<float>(v));
}

}  // namespace vdbrecon::detail
