// A parallel, stable least-significant-digit radix sort on an integer key, shared by the splat
// (its (block, point) pairs) and the kNN index (points by grid cell).
#pragma once

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

namespace vdbrecon::detail {

/// Elements per chunk of for_each_chunk(), at most.
constexpr std::size_t kChunk = std::size_t(1) << 16;

/// The elements per chunk for n elements: kChunk, or for fewer than 8 kChunk elements the power
/// of two (at least 4096) that makes about eight chunks, so that a small array's loops have
/// work for every thread too (the 50k kernels of 30 Kinect frames fused at 1 cm were one chunk,
/// each pass over them serial). What the loops compute does not depend on the chunking.
inline std::size_t chunk_size(std::size_t n) {
    std::size_t size = 4096;
    while (size < kChunk && 8 * size < n) size *= 2;
    return size;
}

/// How many chunks for_each_chunk() splits n elements into.
inline std::size_t chunk_count(std::size_t n) {
    const std::size_t size = chunk_size(n);
    return (n + size - 1) / size;
}

/// Runs fn(chunk, begin, end) over the chunk_size(n)-element chunks of [0, n), in parallel.
template <typename Fn>
void for_each_chunk(std::size_t n, Fn&& fn) {
    const std::size_t size = chunk_size(n);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, chunk_count(n), 1),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t c = r.begin(); c < r.end(); ++c) {
            fn(c, c * size, std::min(n, (c + 1) * size));
        }
    });
}

/// Each chunk's offset (for_each_chunk's chunks of [0, n)): the sum of count(chunk, begin, end)
/// over the chunks before it, the counts made in parallel; `total` gets the sum of all. For
/// listing a varying number of items per element into one array in order, by chunks in
/// parallel: counted first, then each chunk written from its offset.
template <typename Count>
std::vector<std::size_t> chunk_offsets(std::size_t n, Count&& count, std::size_t& total) {
    std::vector<std::size_t> first(chunk_count(n), 0);
    for_each_chunk(n, [&](std::size_t c, std::size_t begin, std::size_t end) {
        first[c] = count(c, begin, end);
    });
    total = 0;
    for (std::size_t& f : first) total += std::exchange(f, total);
    return first;
}

/// Sorts v stably by key(element), whose values lie below 2^bits: 11-bit digits, each pass a
/// per-chunk histogram and scatter in parallel. A stable sort's result is unique, so it does
/// not depend on the chunking or the thread count.
template <typename T, typename A, typename Key>
void radix_sort(std::vector<T, A>& v, int bits, Key&& key) {
    const std::size_t n = v.size();
    if (n < 2 || bits <= 0) return;
    constexpr int kDigit = 11;
    constexpr std::size_t kBuckets = std::size_t(1) << kDigit;
    const std::size_t chunks = chunk_count(n);
    std::vector<T, A> tmp(n);  // a FillLater one is not zeroed first: every pass writes it all
    std::vector<std::size_t> count(chunks * kBuckets);  // [chunk][digit]
    for (int shift = 0; shift < bits; shift += kDigit) {
        auto digit = [&](const T& e) { return std::size_t(key(e) >> shift) & (kBuckets - 1); };
        for_each_chunk(n, [&](std::size_t c, std::size_t begin, std::size_t end) {
            std::size_t* h = &count[c * kBuckets];
            std::fill(h, h + kBuckets, 0);
            for (std::size_t i = begin; i < end; ++i) ++h[digit(v[i])];
        });
        // Where each (digit, chunk) run starts: digits in order, chunks in order within one.
        std::size_t at = 0;
        for (std::size_t d = 0; d < kBuckets; ++d) {
            for (std::size_t c = 0; c < chunks; ++c) {
                const std::size_t k = count[c * kBuckets + d];
                count[c * kBuckets + d] = at;
                at += k;
            }
        }
        for_each_chunk(n, [&](std::size_t c, std::size_t begin, std::size_t end) {
            std::size_t* h = &count[c * kBuckets];
            for (std::size_t i = begin; i < end; ++i) tmp[h[digit(v[i])]++] = v[i];
        });
        v.swap(tmp);
    }
}

}  // namespace vdbrecon::detail
