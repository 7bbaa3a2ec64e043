// Small double 3-vector helpers on std::array<double, 3>, for the code that works in double
// without Eigen or OpenVDB types (evaluation, fusion, decimation, previews, textures).
#pragma once

#include <array>
#include <cmath>

namespace vdbrecon::detail {

using V3 = std::array<double, 3>;

inline V3 sub(const V3& a, const V3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
inline V3 add(const V3& a, const V3& b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }
inline V3 mul(const V3& a, double s) { return {a[0] * s, a[1] * s, a[2] * s}; }
inline double dot(const V3& a, const V3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
inline V3 cross(const V3& a, const V3& b) {
    return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
/// a / |a|; the zero vector stays zero.
inline V3 unit(const V3& a) {
    const double l = std::sqrt(dot(a, a));
    return l > 0.0 ? mul(a, 1.0 / l) : a;
}
/// A float 3-vector (Vec3f) in double.
inline V3 widen(const std::array<float, 3>& p) { return {p[0], p[1], p[2]}; }

}  // namespace vdbrecon::detail
