// Stable in-place compaction of a vector in parallel (the mesh stage's face filters), and the
// indices where a predicate holds, on the fixed chunks of detail/radix_sort.h.
#pragma once

#include <algorithm>
#include <cstddef>
#include <vector>

#include "detail/radix_sort.h"

namespace vdbrecon::detail {

/// Keeps the elements v[i] for which keep(i) holds, in their order, and returns how many were
/// dropped. keep(i) may read v[i] (it is called before v[i] is moved). Each chunk is compacted
/// within itself in parallel, then the kept runs are moved down in chunk order: one memmove per
/// chunk instead of a serial pass of element copies over the whole vector.
template <typename T, typename A, typename Keep>
std::size_t compact_in_place(std::vector<T, A>& v, Keep&& keep) {
    const std::size_t n = v.size();
    std::vector<std::size_t> kept(chunk_count(n), 0);
    for_each_chunk(n, [&](std::size_t c, std::size_t begin, std::size_t end) {
        std::size_t out = begin;
        for (std::size_t i = begin; i < end; ++i) {
            if (keep(i)) v[out++] = v[i];
        }
        kept[c] = out - begin;
    });
    const std::size_t size = chunk_size(n);
    std::size_t out = 0;
    for (std::size_t c = 0; c < kept.size(); ++c) {
        const auto from = v.begin() + std::ptrdiff_t(c * size);
        if (out != c * size)
            std::move(from, from + std::ptrdiff_t(kept[c]), v.begin() + std::ptrdiff_t(out));
        out += kept[c];
    }
    v.resize(out);
    return n - out;
}

/// The indices i in [0, n) where keep(i) holds, ascending: counted, then listed, by chunks in
/// parallel (keep(i) is called twice).
template <typename Keep>
std::vector<std::size_t> indices_where(std::size_t n, Keep&& keep) {
    std::size_t total = 0;
    const std::vector<std::size_t> first = chunk_offsets(
        n,
        [&](std::size_t, std::size_t begin, std::size_t end) {
            std::size_t count = 0;
            for (std::size_t i = begin; i < end; ++i) count += keep(i) ? 1 : 0;
            return count;
        },
        total);
    std::vector<std::size_t> out(total);
    for_each_chunk(n, [&](std::size_t c, std::size_t begin, std::size_t end) {
        std::size_t at = first[c];
        for (std::size_t i = begin; i < end; ++i) {
            if (keep(i)) out[at++] = i;
        }
    });
    return out;
}

}  // namespace vdbrecon::detail
