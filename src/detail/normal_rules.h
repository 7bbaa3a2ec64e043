// The normal of one point from its neighbour lists, and its local orientation: what
// estimate_normals does per point, shared with the streamed tiles (stream_tiles.cpp), which
// run it a region at a time.
#pragma once

#include <cstddef>
#include <functional>

#include "vdbrecon/normals.h"
#include "vdbrecon/types.h"

namespace vdbrecon::detail {

/// Whether a normal is (0, 0, 0): none (to estimate, or left unsplatted).
inline bool is_zero(const Vec3f& n) { return n[0] == 0.0f && n[1] == 0.0f && n[2] == 0.0f; }

/// The PCA normal of point i from its k nearest `nb` (unoriented); next to a sharp edge, its
/// face's. False for a degenerate neighbourhood (coincident or collinear points). `doubt`: how
/// far an orientation by propagation may trust it; `wider`: whether a wider look is due
/// (wider_normal).
bool neighbourhood_normal(Span<Vec3f> pts, std::size_t i, const int* nb, int k, Vec3f& normal,
                          float& doubt, bool* wider = nullptr);

/// The wider look of a point flagged by neighbourhood_normal: its 3k nearest among the k
/// nearest of its k nearest (list(j): point j's k nearest, no second search); true, with its
/// crisp face's normal, where those show one.
bool wider_normal(Span<Vec3f> pts, std::size_t i, int k,
                  const std::function<const int*(std::size_t)>& list, Vec3f& normal);

/// Warns of `bad` points of `n` left without a normal (a degenerate neighbourhood); throws
/// NumericalError when that is all of them.
void report_degenerate(std::size_t bad, std::size_t n);

/// Turns an estimated normal at p (local frame `origin`) towards options.viewpoint or along
/// options.up; true when it was flipped. Each point on its own: no other point is read.
bool orient_locally(const NormalOptions& options, const Vec3d& origin, const Vec3f& p,
                    Vec3f& normal);

}  // namespace vdbrecon::detail
