// Vectors whose elements a parallel loop writes after sizing them: not zero-filled first.
#pragma once

#include <memory>
#include <new>
#include <utility>
#include <vector>

namespace vdbrecon::detail {

/// An allocator whose construct() without arguments default-initialises: a vector of trivial
/// elements sized by its constructor or resize() is not zero-filled first. For per-element arrays
/// that parallel loops fill anyway; the zero fill would be one serial pass over all of them, over
/// fresh memory its page faults too (the splat's 8 MB of (block, point) pairs and the radix
/// sort's copy of them on the bunny at 0.5 mm). Elements with constructors of their own (such as
/// std::pair's, which zeroes) are still constructed by them.
template <typename T>
struct NoZeroFill : std::allocator<T> {
    template <typename U>
    struct rebind {
        using other = NoZeroFill<U>;
    };
    NoZeroFill() = default;
    template <typename U>
    NoZeroFill(const NoZeroFill<U>&) noexcept {}
    template <typename U>
    void construct(U* p) noexcept {
        ::new (static_cast<void*>(p)) U;
    }
    template <typename U, typename... Args>
    void construct(U* p, Args&&... args) {
        ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
};

/// A vector whose sized construction leaves trivial elements uninitialised (see NoZeroFill).
template <typename T>
using FillLater = std::vector<T, NoZeroFill<T>>;

}  // namespace vdbrecon::detail
