// Range-image fusion (see fusion.h): depth pixels to oriented samples, one frame at a time into
// a SplatAccumulator.
#include "vdbrecon/fusion.h"

#include <tbb/parallel_for.h>
#include <tbb/parallel_pipeline.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <memory>
#include <sstream>
#include <utility>

#include "detail/cell_groups.h"
#include "detail/io_common.h"
#include "detail/run.h"
#include "detail/tsdf.h"
#include "vdbrecon/normals.h"
#include "vdbrecon/scene.h"
#include "detail/vec3.h"
#include "vdbrecon/error.h"
#include "vdbrecon/log.h"

namespace vdbrecon {

void DepthOptions::validate() const {
    if (!(std::isfinite(min_depth) && min_depth >= 0.0)) {
        throw InvalidArgument("depth.min_depth must be a non-negative number");
    }
    if (!(std::isfinite(max_depth) && max_depth >= 0.0)) {
        throw InvalidArgument("depth.max_depth must be a non-negative number (0 = no limit)");
    }
    if (max_depth > 0.0 && max_depth <= min_depth) {
        throw InvalidArgument("depth.max_depth must exceed depth.min_depth");
    }
    if (!(max_jump > 0.0 && max_jump <= 1.0)) {
        throw InvalidArgument("depth.max_jump must be in (0, 1] (a fraction of the depth)");
    }
    if (!(min_view_cos >= 0.0 && min_view_cos < 1.0)) {
        throw InvalidArgument("depth.min_view_cos must be in [0, 1)");
    }
    if (!(std::isfinite(truncation) && truncation >= 1.0 && truncation <= 64.0)) {
        throw InvalidArgument("depth.truncation must be in 1..64 voxels");
    }
    if (!(std::isfinite(aggregate) && aggregate >= 0.0 && aggregate <= 4.0)) {
        throw InvalidArgument("depth.aggregate must be in 0..4 (sigmas; 0 = off)");
    }
    if (!(std::isfinite(reference_depth) && reference_depth >= 0.0)) {
        throw InvalidArgument("depth.reference_depth must be a non-negative number (0 = off)");
    }
}

namespace {

using detail::V3;
using detail::cross;
using detail::dot;
using detail::sub;

/// The element of rank n / 2 (the upper median) of v, which it reorders; 0 for none.
template <typename T>
double median_of(std::vector<T>& v) {
    if (v.empty()) return 0.0;
    std::nth_element(v.begin(), v.begin() + std::ptrdiff_t(v.size() / 2), v.end());
    return double(v[v.size() / 2]);
}

/// Whether the 8 values at x are all zero bytes (+0.0f, or 8 flags off).
template <typename T>
bool none_of_8(const T* x) {
    static_assert(sizeof(T) == 1 || sizeof(T) == 4, "bytes or floats");
    std::uint64_t word[sizeof(T)];
    std::memcpy(word, x, sizeof word);
    std::uint64_t any = 0;
    for (std::uint64_t w : word) any |= w;
    return any == 0;
}

/// One row of a grid of points: its points, ranges, valid flags and pixel counts (count null
/// where every point stands for one pixel).
struct GridRow {
    const V3* p = nullptr;
    const double* r = nullptr;
    const char* valid = nullptr;
    const float* count = nullptr;
};

/// A grid of sensor-centred points (an image's pixels, or blocks of them, or an organized
/// cloud's points less the sensor position): valid[i] false where nothing was measured; r[i]
/// the range (distance from the sensor), which the depth-jump tests compare; count[i] the
/// pixels a point stands for.
struct FramePoints {
    int w = 0, h = 0;
    std::vector<V3> p;
    std::vector<double> r;
    std::vector<char> valid;
    std::vector<float> count;

    void resize(int width, int height) {
        w = width;
        h = height;
        const std::size_t n = std::size_t(w) * std::size_t(h);
        p.assign(n, V3{0, 0, 0});
        r.assign(n, 0.0);
        valid.assign(n, 0);
        count.assign(n, 1.0f);
    }
    void set(std::size_t i, const V3& x) {
        p[i] = x;
        r[i] = std::sqrt(dot(x, x));
        valid[i] = r[i] > 0.0;
    }

    std::size_t index(int u, int v) const { return std::size_t(v) * std::size_t(w) + std::size_t(u); }
    GridRow row(int v) const {
        const std::size_t i = index(0, v);
        return {p.data() + i, r.data() + i, valid.data() + i, count.data() + i};
    }
};

/// A depth image's pixels as camera-frame points, made row by row as they are asked for (the
/// points of rows v - 1, v and v + 1 at a time): a frame is mostly background, and the points of
/// a whole frame (37 bytes a pixel) cost more to write and read back than to make.
class DepthRows {
  public:
    const int w, h;

    DepthRows(const DepthImage& depth, const Intrinsics& K, const DepthOptions& o)
        : w(depth.width), h(depth.height), depth_(depth), K_(K), kind_(o.kind),
          min_depth_(o.min_depth), max_depth_(o.max_depth > 0.0 ? o.max_depth : HUGE_VAL) {
        for (int s = 0; s < 3; ++s) {
            p_[s].resize(std::size_t(w));
            r_[s].resize(std::size_t(w));
            valid_[s].resize(std::size_t(w));
        }
        // Each column's ray x, made once: the same quotient as per pixel (Kinect frames fused
        // at 1 cm: integrate 0.296 -> 0.292 s at 2 threads).
        ray_x_.resize(std::size_t(w));
        for (int u = 0; u < w; ++u) ray_x_[std::size_t(u)] = (u - K_.cx) / K_.fx;
    }

    /// Row v's points into p, r, valid (w entries each; p and r left as they are where
    /// nothing was measured).
    void project(int v, V3* p, double* r, char* valid) const {
        const float* d = depth_.depth.data() + std::size_t(v) * std::size_t(w);
        std::fill(valid, valid + w, 0);
        const double ray_y = (v - K_.cy) / K_.fy;
        for (int u = 0; u < w;) {
            if (u + 8 <= w && none_of_8(d + u)) {  // background (0) is skipped 8 pixels at a time
                u += 8;
                continue;
            }
            for (const int end = std::min(w, u + 8); u < end; ++u) {
                const double z = double(d[u]);
                if (!measured(z)) continue;
                const V3 x = point(ray_x_[std::size_t(u)], ray_y, z);
                p[u] = x;
                r[u] = std::sqrt(dot(x, x));
                valid[u] = r[u] > 0.0;
            }
        }
    }
    GridRow row(int v) const {
        const int s = v % 3;
        if (row_[s] != v) {
            project(v, p_[s].data(), r_[s].data(), valid_[s].data());
            row_[s] = v;
        }
        return {p_[s].data(), r_[s].data(), valid_[s].data(), nullptr};
    }
    /// The range of pixel i, 0 where nothing was measured.
    double range(std::size_t i) const {
        const int v = int(i / std::size_t(w)), u = int(i % std::size_t(w));
        const double z = double(depth_.depth[i]);
        if (!measured(z)) return 0.0;
        const V3 x = point(ray_x_[std::size_t(u)], (v - K_.cy) / K_.fy, z);
        return std::sqrt(dot(x, x));
    }

  private:
    /// Whether a depth value is a measurement (0, NaN, inf and values out of range are not).
    bool measured(double z) const {
        return std::isfinite(z) && z > min_depth_ && z > 0.0 && z <= max_depth_;
    }
    /// The point of a pixel whose ray is (rx, ry, 1): rx = (u - cx) / fx, ry = (v - cy) / fy.
    V3 point(double rx, double ry, double z) const {
        const V3 ray = {rx, ry, 1.0};
        if (kind_ == DepthKind::ray) z /= std::sqrt(dot(ray, ray));
        return {ray[0] * z, ray[1] * z, z};
    }

    const DepthImage& depth_;
    const Intrinsics& K_;
    DepthKind kind_;
    double min_depth_, max_depth_;
    mutable std::vector<V3> p_[3];
    mutable std::vector<double> r_[3];
    mutable std::vector<char> valid_[3];
    mutable int row_[3] = {-1, -1, -1};  ///< the row each buffer holds
    std::vector<double> ray_x_;          ///< per column
};

FramePoints back_project(const DepthImage& depth, const Intrinsics& K, const DepthOptions& o) {
    const DepthRows rows(depth, K, o);
    FramePoints f;
    f.resize(depth.width, depth.height);
    for (int v = 0; v < f.h; ++v) {
        const std::size_t i = f.index(0, v);
        rows.project(v, &f.p[i], &f.r[i], &f.valid[i]);
    }
    return f;
}

/// The pixel blocks (b x b) a frame is merged into where its footprint is below
/// `merge_footprint`: b = floor(merge_footprint / the median footprint), at most 4.
int merge_factor(const DepthRows& f, double focal, double merge_footprint) {
    if (!(merge_footprint > 0.0)) return 1;
    std::vector<double> z;
    const std::size_t n = std::size_t(f.w) * std::size_t(f.h);
    for (std::size_t i = 0; i < n; i += 7) {  // a sample of the pixels is enough
        const double r = f.range(i);
        if (r > 0.0) z.push_back(r);
    }
    if (z.empty()) return 1;
    const double footprint = median_of(z) / focal;
    return std::clamp(int(std::floor(merge_footprint / footprint)), 1, 4);
}

/// b x b blocks of pixels as one point each: the mean of the block's pixels on the surface of
/// its median depth (within max_jump), standing for their count. Averaging pixels that each
/// weigh the same is what splatting them with kernels wider than their spacing does, at a
/// b^2-th of the kernels.
FramePoints merge_blocks(const FramePoints& f, int b, double max_jump) {
    FramePoints m;
    m.resize((f.w + b - 1) / b, (f.h + b - 1) / b);
    std::vector<double> z;
    for (int bv = 0; bv < m.h; ++bv) {
        for (int bu = 0; bu < m.w; ++bu) {
            z.clear();
            const int u1 = std::min(f.w, (bu + 1) * b), v1 = std::min(f.h, (bv + 1) * b);
            for (int v = bv * b; v < v1; ++v) {
                for (int u = bu * b; u < u1; ++u) {
                    if (f.valid[f.index(u, v)]) z.push_back(f.r[f.index(u, v)]);
                }
            }
            if (z.empty()) continue;
            const double ref = median_of(z);
            V3 sum{0, 0, 0};
            int n = 0;
            for (int v = bv * b; v < v1; ++v) {
                for (int u = bu * b; u < u1; ++u) {
                    const std::size_t i = f.index(u, v);
                    if (!f.valid[i] || std::fabs(f.r[i] - ref) > max_jump * ref) continue;
                    for (int a = 0; a < 3; ++a) sum[std::size_t(a)] += f.p[i][std::size_t(a)];
                    ++n;
                }
            }
            const std::size_t j = m.index(bu, bv);
            m.set(j, {sum[0] / n, sum[1] / n, sum[2] / n});
            m.count[j] = float(n);
        }
    }
    return m;
}

/// The oriented samples of a grid of camera-frame points (see fusion.h); `focal`: the grid's
/// focal length in cells. Grid: FramePoints or DepthRows (rows by row(v)).
template <typename Grid>
PointCloud grid_samples(const Grid& f, double focal, const Pose& pose, const DepthOptions& options,
                        const Vec3d& origin, std::vector<std::uint32_t>* cells = nullptr) {
    const int w = f.w, h = f.h;
    auto usable = [&](const GridRow* row, int u, double d) {  // a neighbour on the same surface
        if (!row || u < 0 || u >= w) return false;
        return row->valid[u] && std::fabs(row->r[u] - d) <= options.max_jump * d;
    };
    // A tangent along one image axis between neighbours a (row ra, column ua) and b: central
    // difference, else one-sided; false when neither neighbour is usable.
    auto tangent = [&](const GridRow* ra, int ua, const GridRow* rb, int ub, const V3& p, double d,
                       V3& t, double& step) {
        const bool a = usable(ra, ua, d), b = usable(rb, ub, d);
        if (!a && !b) return false;
        const V3 lo = a ? ra->p[ua] : p, hi = b ? rb->p[ub] : p;
        t = sub(hi, lo);
        step = std::sqrt(dot(t, t)) / double(int(a) + int(b));
        return step > 0.0;
    };
    PointCloud cloud;
    cloud.origin = origin;
    std::vector<Vec3f> positions, normals;
    std::vector<float> scales, confidences;
    const V3 t = {pose[3], pose[7], pose[11]};
    auto rotate = [&](const V3& x) {
        return V3{pose[0] * x[0] + pose[1] * x[1] + pose[2] * x[2],
                  pose[4] * x[0] + pose[5] * x[1] + pose[6] * x[2],
                  pose[8] * x[0] + pose[9] * x[1] + pose[10] * x[2]};
    };
    // A row's samples are gathered, then appended at once (no growth check per sample). Room
    // for a sample per cell is reserved: the pages past the samples are never touched, and the
    // growth by doubling copied each frame's samples about twice (5 % of a fusion's CPU).
    const std::size_t width = static_cast<std::size_t>(w);
    const std::size_t most = width * static_cast<std::size_t>(h);
    positions.reserve(most);
    normals.reserve(most);
    scales.reserve(most);
    confidences.reserve(most);
    std::vector<Vec3f> row_p(width), row_n(width);
    std::vector<float> row_s(width), row_c(width);
    auto append = [](auto& to, const auto& from, std::size_t k) {
        to.insert(to.end(), from.begin(), from.begin() + std::ptrdiff_t(k));
    };
    GridRow up, row, down;
    for (int v = 0; v < h; ++v) {
        std::size_t k = 0;
        if (v > 0) up = row;
        row = v > 0 ? down : f.row(v);
        if (v + 1 < h) down = f.row(v + 1);
        const GridRow* above = v > 0 ? &up : nullptr;
        const GridRow* below = v + 1 < h ? &down : nullptr;
        for (int u = 0; u < w; ++u) {
            if (!row.valid[u]) {
                if ((u & 7) == 0 && u + 8 <= w && none_of_8(row.valid + u)) u += 7;  // 8 at a time
                continue;
            }
            const V3& p = row.p[u];
            V3 tu, tv;
            double su = 0.0, sv = 0.0;
            const double range = row.r[u];
            if (!tangent(&row, u - 1, &row, u + 1, p, range, tu, su) ||
                !tangent(above, u, below, u, p, range, tv, sv)) {
                continue;
            }
            V3 n = cross(tu, tv);
            const double len = std::sqrt(dot(n, n)), dist = range;  // |p|
            if (!(len > 0.0)) continue;
            double c = -dot(n, p) / (len * dist);  // cosine of the viewing angle, signed
            if (c < 0.0) {  // orient toward the camera
                n = {-n[0], -n[1], -n[2]};
                c = -c;
            }
            if (c < options.min_view_cos) continue;
            // Footprint: the spacing to the neighbours, at most that of a cell seen at
            // min_view_cos (a jump below max_jump must not widen the kernel further).
            const double footprint = std::min(0.5 * (su + sv), dist / focal / options.min_view_cos);
            double conf = c * (row.count ? double(row.count[u]) : 1.0);
            if (options.reference_depth > 0.0 && range > options.reference_depth) {
                const double r = options.reference_depth / range;
                conf *= r * r;
            }
            const V3 pw = rotate(p), nw = rotate(n);
            row_p[k] = {float(pw[0] + t[0] - origin[0]), float(pw[1] + t[1] - origin[1]),
                        float(pw[2] + t[2] - origin[2])};
            row_n[k] = {float(nw[0] / len), float(nw[1] / len), float(nw[2] / len)};
            row_s[k] = float(footprint);
            row_c[k++] = float(conf);
            if (cells) cells->push_back(std::uint32_t(std::size_t(v) * width + std::size_t(u)));
        }
        append(positions, row_p, k);
        append(normals, row_n, k);
        append(scales, row_s, k);
        append(confidences, row_c, k);
    }
    cloud.positions = std::move(positions);
    cloud.normals = std::move(normals);
    cloud.scales = std::move(scales);
    cloud.confidences = std::move(confidences);
    return cloud;
}

/// The focal length (in cells) of an organized grid: the median of range / spacing between
/// horizontal neighbours on one surface.
double grid_focal(const FramePoints& f, double max_jump) {
    std::vector<double> q;
    for (int v = 0; v < f.h; v += 3) {
        for (int u = 0; u + 1 < f.w; u += 3) {
            const std::size_t i = f.index(u, v), j = i + 1;
            if (!f.valid[i] || !f.valid[j] || std::fabs(f.r[i] - f.r[j]) > max_jump * f.r[i]) continue;
            const double d = std::sqrt(dot(sub(f.p[i], f.p[j]), sub(f.p[i], f.p[j])));
            if (d > 0.0) q.push_back(f.r[i] / d);
        }
    }
    return q.empty() ? 1.0 : median_of(q);
}

}  // namespace

namespace {

/// The colour the camera (intrinsics K, the image `color`) sees at the camera-frame point
/// (x, y, z): bilinear, clamped at the border (pixel centres at integers).
Vec3f seen_color(const ColorImage& color, const Intrinsics& K, double x, double y, double z) {
    const int w = color.width, h = color.height;
    const double u = z > 0.0 ? K.fx * x / z + K.cx : 0.0;
    const double v = z > 0.0 ? K.fy * y / z + K.cy : 0.0;
    const double uc = std::clamp(u, 0.0, double(w - 1)), vc = std::clamp(v, 0.0, double(h - 1));
    const int u0 = std::min(int(uc), w - 1), v0 = std::min(int(vc), h - 1);
    const int u1 = std::min(u0 + 1, w - 1), v1 = std::min(v0 + 1, h - 1);
    const float fu = float(uc - u0), fv = float(vc - v0);
    const auto at = [&](int a, int b) {
        return color.rgb[std::size_t(b) * std::size_t(w) + std::size_t(a)];
    };
    const Vec3f c00 = at(u0, v0), c10 = at(u1, v0), c01 = at(u0, v1), c11 = at(u1, v1);
    Vec3f out;
    for (std::size_t c = 0; c < 3; ++c) {
        out[c] = (1 - fv) * ((1 - fu) * c00[c] + fu * c10[c]) + fv * ((1 - fu) * c01[c] + fu * c11[c]);
    }
    return out;
}

void check_color(const ColorImage& color, const Intrinsics& K) {
    if (color.width <= 0 || color.height <= 0 ||
        color.rgb.size() != std::size_t(color.width) * std::size_t(color.height)) {
        throw InvalidArgument("colour image: its pixels do not fill width x height");
    }
    K.validate();
}

}  // namespace

void color_samples(PointCloud& samples, const ColorImage& color, const Intrinsics& K,
                   const Pose& pose) {
    check_color(color, K);
    const std::size_t n = samples.size();
    std::vector<Vec3f> out(n);
    const Vec3d& o = samples.origin;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            const Vec3f& p = samples.positions[i];
            // World to camera: R^T (x - t).
            const double d[3] = {o[0] + p[0] - pose[3], o[1] + p[1] - pose[7],
                                 o[2] + p[2] - pose[11]};
            out[i] = seen_color(color, K, pose[0] * d[0] + pose[4] * d[1] + pose[8] * d[2],
                                pose[1] * d[0] + pose[5] * d[1] + pose[9] * d[2],
                                pose[2] * d[0] + pose[6] * d[1] + pose[10] * d[2]);
        }
    });
    samples.colors = std::move(out);
}

PointCloud organized_samples(const OrganizedCloud& c, const DepthOptions& options,
                             const Vec3d& origin) {
    options.validate();
    if (c.width <= 0 || c.height <= 0 ||
        c.points.size() != std::size_t(c.width) * std::size_t(c.height)) {
        throw InvalidArgument("organized cloud: its points do not fill width x height");
    }
    FramePoints f;
    f.resize(c.width, c.height);
    const double max_depth = options.max_depth > 0.0 ? options.max_depth : HUGE_VAL;
    for (std::size_t i = 0; i < c.points.size(); ++i) {
        const Vec3f& x = c.points[i];
        const V3 p = {double(x[0]) + c.origin[0] - c.sensor[0], double(x[1]) + c.origin[1] - c.sensor[1],
                      double(x[2]) + c.origin[2] - c.sensor[2]};
        if (!(std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]))) continue;
        f.set(i, p);
        if (!(f.r[i] > options.min_depth && f.r[i] <= max_depth)) f.valid[i] = 0;
    }
    // The sensor frame is the world's axes moved to the sensor: a pure translation.
    const Pose pose{1, 0, 0, c.sensor[0], 0, 1, 0, c.sensor[1], 0, 0, 1, c.sensor[2], 0, 0, 0, 1};
    if (c.colors.size() != c.points.size()) {
        return grid_samples(f, grid_focal(f, options.max_jump), pose, options, origin);
    }
    // Each sample is a point of the raster: it keeps that point's colour.
    std::vector<std::uint32_t> cells;
    PointCloud s = grid_samples(f, grid_focal(f, options.max_jump), pose, options, origin, &cells);
    std::vector<Vec3f> colors(cells.size());
    for (std::size_t j = 0; j < cells.size(); ++j) colors[j] = c.colors[cells[j]];
    s.colors = std::move(colors);
    return s;
}

PointCloud scan_samples(const PointCloud& scan, const std::optional<Vec3d>& origin,
                        const std::optional<Vec3d>& direction, const DepthOptions& options, int k) {
    options.validate();
    if (!origin && !direction) throw InvalidArgument("scan_samples: the scan needs a sensor");
    PointCloud c = scan.view();
    if (!c.has_normals() || !c.has_scales()) {
        NormalOptions n;
        n.k = std::min<int>(k, int(c.size()) - 1);
        n.mode = c.has_normals() ? NormalMode::keep : NormalMode::estimate;
        n.scale = ScaleMode::knn;
        if (origin) n.viewpoint = *origin;
        if (c.size() < 3) return PointCloud{};
        NormalResult r = estimate_normals(c, n);
        if (!c.has_normals()) c.normals = std::move(r.normals);
        if (!c.has_scales()) c.scales = std::move(r.scales);
    }
    PointCloud out;
    out.origin = c.origin;
    std::vector<Vec3f> pos, nrm, col;
    std::vector<float> scl, conf;
    for (std::size_t i = 0; i < c.size(); ++i) {
        const Vec3f& p = c.positions[i];
        V3 view;
        if (origin) {
            view = {(*origin)[0] - (double(p[0]) + c.origin[0]), (*origin)[1] - (double(p[1]) + c.origin[1]),
                    (*origin)[2] - (double(p[2]) + c.origin[2])};
        } else {
            view = {(*direction)[0], (*direction)[1], (*direction)[2]};
        }
        const V3 n = {c.normals[i][0], c.normals[i][1], c.normals[i][2]};
        const double ln = std::sqrt(dot(n, n)), lv = std::sqrt(dot(view, view));
        if (!(ln > 0.0) || !(lv > 0.0)) continue;
        double cosv = dot(n, view) / (ln * lv);
        Vec3f nf = c.normals[i];
        if (cosv < 0.0) {  // toward the sensor
            nf = {-nf[0], -nf[1], -nf[2]};
            cosv = -cosv;
        }
        if (cosv < options.min_view_cos) continue;
        pos.push_back(p);
        nrm.push_back(nf);
        scl.push_back(c.scales[i]);
        conf.push_back(float(cosv * (c.has_confidences() ? double(c.confidences[i]) : 1.0)));
        if (c.has_colors()) col.push_back(c.colors[i]);
    }
    out.positions = std::move(pos);
    out.normals = std::move(nrm);
    out.scales = std::move(scl);
    out.confidences = std::move(conf);
    if (c.has_colors()) out.colors = std::move(col);
    return out;
}

namespace {

/// Refuses a frame whose image, intrinsics, pose or options do not fit together.
void check_frame(const DepthImage& depth, const Intrinsics& K, const Pose& pose,
                 const DepthOptions& options) {
    K.validate();
    options.validate();
    validate_pose(pose);
    if (depth.width != K.width || depth.height != K.height) {
        std::ostringstream s;
        s << "depth image is " << depth.width << " x " << depth.height
          << " pixels, the intrinsics say " << K.width << " x " << K.height;
        throw InvalidArgument(s.str());
    }
    if (depth.depth.size() != std::size_t(depth.width) * std::size_t(depth.height)) {
        throw InvalidArgument("depth image: its values do not fill width x height");
    }
}

}  // namespace

PointCloud depth_samples(const DepthImage& depth, const Intrinsics& K, const Pose& pose,
                         const DepthOptions& options, const Vec3d& origin) {
    check_frame(depth, K, pose, options);
    const double focal = 0.5 * (K.fx + K.fy);
    const DepthRows rows(depth, K, options);
    const int b = merge_factor(rows, focal, options.merge_footprint);
    if (b == 1) return grid_samples(rows, focal, pose, options, origin);
    const FramePoints merged = merge_blocks(back_project(depth, K, options), b, options.max_jump);
    return grid_samples(merged, focal / b, pose, options, origin);
}

namespace {

PipelineOptions checked(const PipelineOptions& options) {
    if (!(options.splat.voxel_size > 0.0)) {
        throw InvalidArgument("fusion: the voxel size must be given (> 0)");
    }
    options.validate();
    return options;
}

}  // namespace

Fusion::Fusion(const PipelineOptions& options, const DepthOptions& depth, const Vec3d& origin)
    : options_(checked(options)), depth_(depth), accumulator_(options_.splat, origin) {
    depth_.validate();
    if (depth_.rule == FusionRule::tsdf) {
        tsdf_ = std::make_unique<detail::TsdfVolume>(options_.splat.voxel_size, depth_.truncation,
                                                     depth_.carve, origin);
    }
    if (depth_.merge_footprint < 0.0) {  // automatic: up to half the smallest kernel
        const SplatOptions& s = options_.splat;
        depth_.merge_footprint = 0.5 * s.min_sigma_voxels * s.voxel_size / s.scale_factor;
    }
}

Fusion::~Fusion() = default;
Fusion::Fusion(Fusion&&) noexcept = default;
Fusion& Fusion::operator=(Fusion&&) noexcept = default;

std::size_t Fusion::memory_bytes() const {
    if (tsdf_) return tsdf_->memory_bytes();
    // The sums, and the batch waiting to be splatted into them.
    const std::size_t per_sample = 4 * sizeof(Vec3f) + 2 * sizeof(float);
    return accumulator_.memory_bytes() + (groups_ ? groups_->memory_bytes() : 0) +
           pending_.size() * per_sample;
}

std::size_t Fusion::samples() const {
    return tsdf_ ? tsdf_->pixels() : samples_;
}

PointCloud Fusion::presum(PointCloud samples) const {
    return detail::presum_in_order(std::move(samples), options_.splat, depth_.aggregate);
}

// A frame's samples are presummed on their own (they fit the caches), the batch's groups once
// more as they are added (the frames' groups of one cell become one).
void Fusion::add(const PointCloud& samples, std::size_t count) {
    samples_ += count;
    if (samples.empty()) return;
    if (depth_.batch_samples == 0) {
        accumulator_.add(samples);
        return;
    }
    if (depth_.aggregate > 0.0) {
        if (groups_ && groups_->colors() != samples.has_colors()) flush();  // one kind a batch
        if (!groups_) {
            groups_ = std::make_unique<detail::CellGroups>(options_.splat, depth_.aggregate,
                                                           samples.has_colors());
        }
        if (!groups_->add(samples)) {  // beyond the cells' reach: splatted as they are
            flush();
            accumulator_.add(samples);
            return;
        }
    } else {
        auto append = [](auto& into, const auto& from) {
            if (from.empty()) return;
            into.edit().insert(into.edit().end(), from.begin(), from.end());
        };
        if (!pending_.empty() && (samples.has_colors() != pending_.has_colors() ||
                                  samples.has_scales() != pending_.has_scales() ||
                                  samples.has_confidences() != pending_.has_confidences())) {
            flush();  // a batch holds one kind of sample
        }
        pending_.origin = samples.origin;
        append(pending_.positions, samples.positions);
        append(pending_.normals, samples.normals);
        append(pending_.colors, samples.colors);
        append(pending_.scales, samples.scales);
        append(pending_.confidences, samples.confidences);
    }
    batched_ += samples.size();
    if (batched_ >= depth_.batch_samples) flush();
}

void Fusion::flush() const {
    if (groups_ && !groups_->empty()) accumulator_.add(groups_->take(accumulator_.origin()));
    if (!pending_.empty()) accumulator_.add(std::move(pending_));
    pending_ = PointCloud{};
    batched_ = 0;
}

PreparedFrame Fusion::prepare(const DepthImage& depth, const Intrinsics& K, const Pose& pose,
                              const ColorImage* color, const Intrinsics* color_K) const {
    return prepare(depth, K, pose, [&](Intrinsics& C) {
        if (color) C = *color_K;
        return color;
    });
}

PreparedFrame Fusion::prepare(const DepthImage& depth, const Intrinsics& K, const Pose& pose,
                              const ColorSource& color_source) const {
    PreparedFrame out;
    Intrinsics C;
    if (!tsdf_) {
        PointCloud samples = depth_samples(depth, K, pose, depth_, accumulator_.origin());
        if (const ColorImage* color = color_source(C)) color_samples(samples, *color, C, pose);
        out.samples = samples.size();
        out.groups = presum(std::move(samples));  // owned: the samples die here
        return out;
    }
    check_frame(depth, K, pose, depth_);
    const ColorImage* color = color_source(C);
    if (color) check_color(*color, C);
    const DepthRows rows(depth, K, depth_);
    std::vector<Vec3f> colors;  // each measured pixel's colour, seen from the same pose
    if (color) colors.assign(std::size_t(rows.w) * std::size_t(rows.h), Vec3f{0.0f, 0.0f, 0.0f});
    // A colour image registered to the depth image (the same camera): a pixel's own colour.
    const bool registered = color && C.fx == K.fx && C.fy == K.fy && C.cx == K.cx &&
                            C.cy == K.cy && color->width == K.width && color->height == K.height;
    auto row = [&](int v, const V3*& points, const char*& measured) {
        const GridRow r = rows.row(v);
        points = r.p;
        measured = r.valid;
        if (!color) return;
        const std::size_t first = std::size_t(v) * std::size_t(rows.w);
        for (int u = 0; u < rows.w; ++u) {
            if (!r.valid[u]) continue;
            const V3& x = r.p[u];
            colors[first + std::size_t(u)] = registered
                                                 ? color->rgb[first + std::size_t(u)]
                                                 : seen_color(*color, C, x[0], x[1], x[2]);
        }
    };
    auto f = std::make_shared<detail::TsdfFrame>(tsdf_->prepare(row, K, pose));
    f->colors = std::move(colors);
    out.samples = f->measured;
    out.tsdf = std::move(f);
    return out;
}

std::size_t Fusion::integrate(const PreparedFrame& frame) {
    if (tsdf_) {
        if (!frame.tsdf)
            throw InvalidArgument(
                "fusion: a frame prepared for the splat rule given to the tsdf rule");
        ++frames_;
        return tsdf_->integrate(*frame.tsdf);
    }
    if (frame.tsdf)
        throw InvalidArgument("fusion: a frame prepared for the tsdf rule given to the splat rule");
    ++frames_;
    add(frame.groups, frame.samples);
    return frame.samples;
}

std::size_t Fusion::integrate(const DepthImage& depth, const Intrinsics& K, const Pose& pose) {
    return integrate(prepare(depth, K, pose));
}

std::size_t Fusion::integrate(const DepthImage& depth, const Intrinsics& K, const Pose& pose,
                              const ColorImage& color, const Intrinsics& color_K) {
    return integrate(prepare(depth, K, pose, &color, &color_K));
}

std::size_t Fusion::add_frame(const PointCloud& samples) {
    ++frames_;
    if (samples.empty()) return 0;
    add(presum(samples.view()), samples.size());
    return samples.size();
}

std::size_t Fusion::integrate(const PointCloud& cloud) {
    if (tsdf_) throw InvalidArgument("fusion: the tsdf rule integrates depth images, not clouds");
    if (cloud.empty() || cloud.origin == accumulator_.origin()) return add_frame(cloud);
    // The same points in the fusion's frame.
    PointCloud moved = cloud.view();
    std::vector<Vec3f> p(cloud.positions.begin(), cloud.positions.end());
    const Vec3d& o = accumulator_.origin();
    for (Vec3f& x : p) {
        for (int a = 0; a < 3; ++a) x[a] = float(double(x[a]) + cloud.origin[a] - o[a]);
    }
    moved.positions = std::move(p);
    moved.origin = o;
    return add_frame(moved);
}

SplatResult Fusion::splat() const { return fused(false); }

SplatResult Fusion::take_splat() { return fused(true); }

SplatResult Fusion::fused(bool take) const {
    if (tsdf_) {
        if (tsdf_->pixels() == 0) {
            throw NumericalError("fusion: none of the " + std::to_string(frames_) +
                                 " frames has a usable pixel");
        }
        SplatResult r = tsdf_->result();
        r.volume.metadata["frames"] = std::to_string(frames_);
        return r;
    }
    flush();
    if (accumulator_.clouds() == 0) {
        throw NumericalError("fusion: none of the " + std::to_string(frames_) +
                             " frames has a usable pixel (depth missing or out of range, or "
                             "no neighbour for a normal)");
    }
    SplatResult r = take ? accumulator_.take_result() : accumulator_.result();
    // The mesher's gap test allows gaps of a few sample spacings: here the pixel footprint.
    const double spacing = r.sigma_median / options_.splat.scale_factor;
    if (spacing > 0.0) r.volume.metadata["sample_spacing"] = detail::format_number(spacing);
    r.volume.metadata["frames"] = std::to_string(frames_);
    return r;
}

std::size_t Fusion::integrate(const OrganizedCloud& cloud) {
    if (tsdf_) throw InvalidArgument("fusion: the tsdf rule integrates depth images, not clouds");
    return add_frame(organized_samples(cloud, depth_, accumulator_.origin()));
}

std::size_t Fusion::integrate_scan(const PointCloud& scan, const Vec3d& sensor) {
    if (!tsdf_) return integrate(scan_samples(scan, sensor, std::nullopt, depth_, options_.normals.k));
    // The tsdf rule keeps grazing hits (their normals make their distances): a surface seen at
    // grazing angles only would have holes without them.
    DepthOptions all = depth_;
    all.min_view_cos = 0.0;
    ++frames_;
    return tsdf_->integrate_scan(scan_samples(scan, sensor, std::nullopt, all, options_.normals.k), sensor);
}

Volume Fusion::volume() const { return splat().volume; }

PipelineResult Fusion::reconstruct(const StageCallback& on_stage,
                                   const VolumeCallback& on_volume) const {
    return reconstruct_volume(volume(), options_, on_stage, on_volume);
}

// ---- the file front end: vdbrecon fuse ----------------------------------------------------

namespace {

/// The frame's intrinsics, completed from its image (size; principal point at the centre).
Intrinsics frame_intrinsics(const SceneFrame& frame, const DepthImage& img) {
    Intrinsics K = frame.intrinsics;
    if (K.width == 0 && K.height == 0) {
        K.width = img.width;
        K.height = img.height;
    }
    if (!std::isfinite(K.cx)) K.cx = 0.5 * K.width - 0.5;
    if (!std::isfinite(K.cy)) K.cy = 0.5 * K.height - 0.5;
    return K;
}

/// The median footprint of a frame's samples (world units), for the automatic voxel.
double median_footprint(const PointCloud& s) {
    std::vector<float> f = s.scales.to_vector();
    return median_of(f);
}

}  // namespace

namespace {

/// The fusion of a run, made when the first frame's (or scan's) samples are known: they choose
/// the voxel when none is given.
class FusionStart {
  public:
    FusionStart(const PipelineOptions& options, const FuseOptions& fo) : po_(options), fo_(fo) {
        po_.splat.crease_angle = 0.0;  // the accumulator has no crease model
    }
    Fusion& get(const PointCloud& first, const std::string& name, const Vec3d& origin) {
        if (fusion_) return *fusion_;
        if (po_.splat.voxel_size == 0.0) {
            const double h = median_footprint(first);
            if (!(h > 0.0)) {
                throw NumericalError(name + ": the first frame has no usable pixel to choose a "
                                            "voxel from. Hint: --voxel");
            }
            po_.splat.voxel_size = po_.auto_voxel_factor * h;
        }
        fusion_ = std::make_unique<Fusion>(po_, fo_.depth, origin);
        return *fusion_;
    }
    bool started() const { return bool(fusion_); }
    Fusion& operator*() { return *fusion_; }
    /// Frees the fusion's sums (once its volume is made: the mesh stages need the room).
    void release() { fusion_.reset(); }
    /// Stops the run, after `frame` (`done` of `total` frames), when the fusion holds more than
    /// the memory budget (--max-memory): before the frames still to come grow it further, and
    /// before the mesh stages need as much again.
    void check_memory(const std::string& frame, std::size_t done, std::size_t total) const {
        if (!fusion_) return;
        const std::size_t held = fusion_->memory_bytes(), budget = memory_budget(po_.splat);
        if (held <= budget) return;
        std::ostringstream s;
        s << "fuse: after " << frame << " (" << done << " of " << total << " frames) the volume "
          << "takes " << held / 1000000 << " MB, over --max-memory " << budget / 1000000
          << " MB. Hint: a larger --voxel, --max-depth / --max-range, --frame-step, or "
          << "--max-memory";
        throw NumericalError(s.str());
    }
    const PipelineOptions& options() const { return po_; }
    const FuseOptions& fuse_options() const { return fo_; }

  private:
    PipelineOptions po_;
    const FuseOptions& fo_;
    std::unique_ptr<Fusion> fusion_;
};

/// A LiDAR scan frame's points (f.scan) in the fusion's frame (relative to `origin`): a KITTI
/// .bin (float32 x y z intensity) or a point file, in the sensor's frame, moved by f.pose; the
/// points nearer than fo.min_range or farther than fo.max_range from the sensor left out.
PointCloud scan_points(const SceneFrame& f, const FuseOptions& fo, const Vec3d& origin) {
    std::vector<std::array<double, 3>> local;
    if (file_extension(f.depth_path) == "bin") {
        for (const Vec3f& p : read_kitti_scan(f.depth_path)) local.push_back({p[0], p[1], p[2]});
    } else {
        const ReadResult r = read_points(f.depth_path);
        for (const Vec3f& p : r.cloud.positions) {
            local.push_back({p[0] + r.cloud.origin[0], p[1] + r.cloud.origin[1], p[2] + r.cloud.origin[2]});
        }
    }
    const Pose& m = f.pose;
    const double far = fo.max_range > 0.0 ? fo.max_range : HUGE_VAL;
    PointCloud c;
    c.origin = origin;
    std::vector<Vec3f> pos;
    pos.reserve(local.size());
    for (const auto& p : local) {
        const double r = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
        if (!std::isfinite(r) || !(r > fo.min_range) || r > far) continue;
        pos.push_back({float(m[0] * p[0] + m[1] * p[1] + m[2] * p[2] + m[3] - origin[0]),
                       float(m[4] * p[0] + m[5] * p[1] + m[6] * p[2] + m[7] - origin[1]),
                       float(m[8] * p[0] + m[9] * p[1] + m[10] * p[2] + m[11] - origin[2])});
    }
    c.positions = std::move(pos);
    return c;
}

/// Starts the fusion, if it is not yet, at the first scan that has usable samples: without a
/// voxel, their spacing chooses it (whatever the rule).
void start_with_scan(FusionStart& fusion, const PointCloud& points, const std::optional<Vec3d>& sensor,
                     const std::optional<Vec3d>& direction, const std::string& name) {
    if (fusion.started()) return;
    if (fusion.options().splat.voxel_size > 0.0) {
        fusion.get(PointCloud{}, name, points.origin);
        return;
    }
    const PointCloud samples = detail::in_arena(fusion.options().threads, [&] {
        return scan_samples(points, sensor, direction, fusion.fuse_options().depth,
                            fusion.options().normals.k);
    });
    if (!samples.empty()) fusion.get(samples, name, points.origin);
}

/// A LiDAR scan frame: fused from its sensor (Fusion::integrate_scan).
void integrate_scan_frame(const SceneFrame& f, const FuseOptions& fo, FusionStart& fusion) {
    validate_pose(f.pose);
    const Vec3d sensor{f.pose[3], f.pose[7], f.pose[11]};
    const Vec3d origin = fusion.started() ? (*fusion).origin() : sensor;
    const int threads = fusion.options().threads;
    const PointCloud points = scan_points(f, fo, origin);
    start_with_scan(fusion, points, sensor, std::nullopt, f.depth_path);
    if (!fusion.started()) return;
    Fusion& fu = *fusion;
    detail::in_arena(threads, [&] { fu.integrate_scan(points, sensor); });
}

/// A scene frame's depth image, its layout's "no measurement" value cleared.
DepthImage frame_depth(const SceneFrame& f) {
    DepthImage img = read_depth_image(f.depth_path, f.units_per_metre,
                                      {f.intrinsics.width, f.intrinsics.height});
    if (f.invalid_value > 0) {
        // Stored values convert to depth / units exactly enough to tell the largest apart.
        const float none = float((double(f.invalid_value) - 0.5) / f.units_per_metre);
        for (float& d : img.depth) {
            if (d >= none) d = 0.0f;
        }
    }
    return img;
}

/// One depth frame read and prepared for the fusion (Fusion::prepare), or its error.
struct FrameSamples {
    PreparedFrame frame;
    std::exception_ptr error;
};

/// The colour camera of a frame whose depth camera is K: its own intrinsics, else K scaled to
/// the colour image's size (pixel centres at integers).
Intrinsics color_camera(const SceneFrame& f, const Intrinsics& K, const ColorImage& c) {
    if (f.color_intrinsics) {
        Intrinsics C = *f.color_intrinsics;
        if (C.width == 0 && C.height == 0) C.width = c.width, C.height = c.height;
        return C;
    }
    if (c.width == K.width && c.height == K.height) return K;
    const double sx = double(c.width) / K.width, sy = double(c.height) / K.height;
    return Intrinsics{K.fx * sx, K.fy * sy, (K.cx + 0.5) * sx - 0.5, (K.cy + 0.5) * sy - 0.5,
                      c.width, c.height};
}

FrameSamples frame_samples(const SceneFrame& f, const Fusion& fusion, bool color) {
    FrameSamples out;
    try {
        const DepthImage img = frame_depth(f);
        const Intrinsics K = frame_intrinsics(f, img);  // checked with the frame
        ColorImage c;
        out.frame = fusion.prepare(img, K, f.pose, [&](Intrinsics& C) -> const ColorImage* {
            if (!color || f.color_path.empty()) return nullptr;
            c = read_color_image(f.color_path);
            C = color_camera(f, K, c);
            return &c;
        });
    } catch (...) {
        out.error = std::current_exception();
    }
    return out;
}

/// The warning for a frame --skip-bad-frames skips.
void skip_frame(const std::string& path, const Error& e) {
    std::string what = e.what();
    if (what.compare(0, path.size() + 2, path + ": ") == 0) what = what.substr(path.size() + 2);
    log_warning(path + ": frame skipped (--skip-bad-frames): " + what);
}

/// Depth frames [first, last): read (and with the splat rule turned into samples) in parallel, at
/// most kInFlight at once, and added to the fusion one after another in frame order as they are
/// ready, while later frames are read (an error is the first bad frame's, whatever the threads).
void integrate_depth_frames(const std::vector<const SceneFrame*>& frames, std::size_t first,
                            std::size_t last, const FusionStart& start, Fusion& fusion,
                            int threads, bool skip_bad, bool color) {
    constexpr std::size_t kInFlight = 8;  // frames in flight: a few MB of samples each
    using Ready = std::pair<std::size_t, FrameSamples>;
    std::size_t next = first;
    auto read = [&](tbb::flow_control& fc) {
        if (next == last) fc.stop();
        return next++;
    };
    auto prepare = [&](std::size_t i) {
        return Ready(i, frame_samples(*frames[i], fusion, color));
    };
    auto add = [&](Ready r) {
        try {
            const FrameSamples& s = r.second;
            if (s.error) std::rethrow_exception(s.error);
            fusion.integrate(s.frame);
        } catch (const Error& e) {
            if (!skip_bad) detail::rethrow_naming(frames[r.first]->depth_path, e);
            skip_frame(frames[r.first]->depth_path, e);
        }
        start.check_memory(frames[r.first]->depth_path, r.first + 1, frames.size());
    };
    detail::in_arena(threads, [&] {
        tbb::parallel_pipeline(
            kInFlight, tbb::make_filter<void, std::size_t>(tbb::filter_mode::serial_in_order, read) &
                           tbb::make_filter<std::size_t, Ready>(tbb::filter_mode::parallel, prepare) &
                           tbb::make_filter<Ready, void>(tbb::filter_mode::serial_in_order, add));
    });
}

/// A frame integrated on its own: a LiDAR scan, an organized cloud, or the first depth frame
/// when its samples choose the voxel. False for a depth frame that joins a parallel run.
bool integrate_alone(const SceneFrame& f, const FuseOptions& fo, FusionStart& fusion) {
    const int threads = fusion.options().threads;
    if (f.scan) {
        integrate_scan_frame(f, fo, fusion);
        return true;
    }
    if (f.organized) {
        OrganizedCloud c = read_organized_cloud(f.depth_path);
        if (!fo.color) c.colors.clear();
        Fusion& fu = fusion.get(organized_samples(c, fo.depth), f.depth_path, c.origin);
        detail::in_arena(threads, [&] { fu.integrate(c); });
        return true;
    }
    if (!fusion.started() && fusion.options().splat.voxel_size > 0.0) {
        // The voxel is known: the first frame joins the parallel run.
        fusion.get(PointCloud{}, f.depth_path, Vec3d{f.pose[3], f.pose[7], f.pose[11]});
    }
    if (fusion.started()) return false;
    // The first frame: its samples choose the voxel.
    const DepthImage img = frame_depth(f);
    const Intrinsics K = frame_intrinsics(f, img);
    fusion.get(depth_samples(img, K, f.pose, fo.depth), f.depth_path,
               Vec3d{f.pose[3], f.pose[7], f.pose[11]});
    Fusion& fu = *fusion;
    if (fo.color && !f.color_path.empty()) {
        const ColorImage c = read_color_image(f.color_path);
        const Intrinsics C = color_camera(f, K, c);
        detail::in_arena(threads, [&] { fu.integrate(img, K, f.pose, c, C); });
    } else {
        detail::in_arena(threads, [&] { fu.integrate(img, K, f.pose); });
    }
    return true;
}

/// A scene's frames (depth images, organized clouds, LiDAR scans), read and integrated in
/// order; runs of depth frames go through integrate_depth_frames. The fusion's memory is
/// checked after each frame (FusionStart::check_memory).
void integrate_frames(const Scene& scene, const FuseOptions& fo, FusionStart& fusion) {
    std::vector<const SceneFrame*> frames;
    for (std::size_t i = 0; i < scene.frames.size(); i += fo.frame_step) {
        if (fo.max_frames > 0 && frames.size() == fo.max_frames) break;
        frames.push_back(&scene.frames[i]);
    }
    for (std::size_t g = 0; g < frames.size();) {
        const SceneFrame& f = *frames[g];
        bool alone = true;
        try {
            alone = integrate_alone(f, fo, fusion);
        } catch (const Error& e) {
            if (!fo.skip_bad_frames) detail::rethrow_naming(f.depth_path, e);
            skip_frame(f.depth_path, e);
        }
        if (alone) {
            fusion.check_memory(f.depth_path, ++g, frames.size());
            continue;
        }
        std::size_t end = g;
        while (end < frames.size() && !frames[end]->organized && !frames[end]->scan) ++end;
        integrate_depth_frames(frames, g, end, fusion, *fusion, fusion.options().threads,
                               fo.skip_bad_frames, fo.color);
        g = end;
    }
}

/// The points of a multi-scan file, one scan at a time (scan_samples); returns the rows read.
std::size_t integrate_scans(const std::string& path, const FuseOptions& fo, FusionStart& fusion,
                            const PipelineOptions& options) {
    const ScanSensors sensors = read_scan_sensors(fo.scan_sensors);
    if (fo.depth.rule == FusionRule::tsdf && sensors.origins.empty()) {
        throw InvalidArgument(fo.scan_sensors + ": the tsdf rule casts rays from each scan's sensor "
                              "position; these sensors are directions. Hint: --fusion splat");
    }
    ReadResult read = read_points(path, options.read);
    const PointCloud& cloud = read.cloud;
    std::vector<std::int32_t> scans = read.scans;
    if (scans.empty()) {
        if (sensors.size() != 1) {
            throw FormatError(path + ": the points have no 'scan' property to pick one of the " +
                              std::to_string(sensors.size()) + " sensors in " + fo.scan_sensors);
        }
        scans.assign(cloud.size(), 0);
    }
    std::vector<std::vector<std::size_t>> members(sensors.size());
    for (std::size_t i = 0; i < scans.size(); ++i) {
        if (scans[i] < 0 || std::size_t(scans[i]) >= sensors.size()) {
            throw FormatError(path + ": point " + std::to_string(i) + " is of scan " +
                              std::to_string(scans[i]) + ", but " + fo.scan_sensors + " has " +
                              std::to_string(sensors.size()) + " sensors");
        }
        members[std::size_t(scans[i])].push_back(i);
    }
    for (std::size_t s = 0; s < members.size(); ++s) {
        if (members[s].empty()) continue;
        PointCloud part;
        part.origin = cloud.origin;
        auto pick = [&](const auto& column, auto& into) {
            if (column.empty()) return;
            std::vector<std::decay_t<decltype(column[0])>> v;
            for (std::size_t i : members[s]) v.push_back(column[i]);
            into = std::move(v);
        };
        pick(cloud.positions, part.positions);
        pick(cloud.normals, part.normals);
        pick(cloud.colors, part.colors);
        pick(cloud.scales, part.scales);
        pick(cloud.confidences, part.confidences);
        std::optional<Vec3d> origin, direction;
        if (!sensors.origins.empty()) origin = sensors.origins[s];
        else direction = sensors.directions[s];
        start_with_scan(fusion, part, origin, direction, path);
        if (!fusion.started()) continue;
        Fusion& fu = *fusion;
        if (origin) {
            detail::in_arena(options.threads, [&] { fu.integrate_scan(part, *origin); });
        } else {
            const PointCloud samples = detail::in_arena(options.threads, [&] {
                return scan_samples(part, origin, direction, fo.depth, options.normals.k);
            });
            detail::in_arena(options.threads, [&] { fu.integrate(samples); });
        }
        fusion.check_memory(path + " scan " + std::to_string(s), s + 1, members.size());
    }
    return read.rows;
}

}  // namespace

RunResult fuse(const std::string& scene_path, const std::string& output,
               const PipelineOptions& options, const FuseOptions& fo,
               const StageCallback& on_stage) {
    if (fo.frame_step == 0) throw InvalidArgument("fuse: the frame step must be at least 1");
    fo.depth.validate();
    const std::string out_path =
        output.empty() ? scene_path + ".recon.ply" : output;  // a folder: <folder>.recon.ply
    auto compute = [&](RunResult& out, std::vector<StageTiming>& timings,
                       const VolumeCallback& write_vdb) {
        FusionStart fusion(options, fo);
        if (!fo.scan_sensors.empty()) {
            detail::StageClock clock(timings, on_stage, "integrate");
            integrate_scans(scene_path, fo, fusion, options);
            out.read.format = "scans";
        } else {
            Scene scene;
            {
                detail::StageClock clock(timings, on_stage, "read scene");
                scene = read_scene(scene_path, fo.scene);
            }
            detail::StageClock clock(timings, on_stage, "integrate");
            integrate_frames(scene, fo, fusion);
            out.read.format = scene.kind;
        }
        if (!fusion.started()) {
            throw NumericalError("fuse: no frame has a usable pixel or point");
        }
        out.read.rows = (*fusion).samples();
        SplatResult splat;
        {
            detail::StageClock clock(timings, on_stage, "splat");
            splat = detail::in_arena(fusion.options().threads, [&] { return (*fusion).take_splat(); });
            fusion.release();
        }
        Volume volume = std::move(splat.volume);
        splat.volume = Volume{};
        PipelineResult r =
            reconstruct_volume(std::move(volume), fusion.options(), on_stage, write_vdb);
        r.splat = std::move(splat);
        r.voxel_chosen = options.splat.voxel_size == 0.0;
        return r;
    };
    return detail::run_to_files(scene_path, out_path, options, on_stage, compute);
}

}  // namespace vdbrecon
