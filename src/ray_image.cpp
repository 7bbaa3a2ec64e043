// A LiDAR scan's rays binned by direction (see detail/ray_image.h).
#include "detail/ray_image.h"

#include <algorithm>
#include <cmath>

namespace vdbrecon::detail {

namespace {

constexpr double kPi = 3.14159265358979323846;
/// At most this many bins (64 MB of offsets): finer scans put more rays in a bin.
constexpr double kMaxBins = double(1 << 24);

/// The solid angle the directions cover, counted on a 1-degree latitude/longitude grid (each
/// cell a direction falls in counts its whole area).
double covered_solid_angle(const std::vector<std::array<double, 3>>& dirs) {
    constexpr int kRows = 180, kCols = 360;
    const double cell = kPi / kRows;
    std::vector<char> hit(std::size_t(kRows) * kCols, 0);
    for (const auto& d : dirs) {
        const int row = std::min(kRows - 1, int((std::asin(std::clamp(d[2], -1.0, 1.0)) + 0.5 * kPi) / cell));
        const int col = std::min(kCols - 1, int((std::atan2(d[1], d[0]) + kPi) / cell));
        hit[std::size_t(row) * kCols + std::size_t(col)] = 1;
    }
    double omega = 0.0;
    for (int row = 0; row < kRows; ++row) {
        // The cell's area: the band's area / columns.
        const double band = std::sin(-0.5 * kPi + (row + 1) * cell) - std::sin(-0.5 * kPi + row * cell);
        for (int col = 0; col < kCols; ++col) omega += hit[std::size_t(row) * kCols + std::size_t(col)] * band * cell;
    }
    return omega;
}

}  // namespace

std::size_t RayImage::bin_of(const std::array<double, 3>& d) const {
    const int row = std::min(rows_ - 1, int((std::asin(std::clamp(d[2], -1.0, 1.0)) + 0.5 * kPi) / bin_));
    const int col = std::min(cols_ - 1, int((std::atan2(d[1], d[0]) + kPi) / bin_));
    return std::size_t(row) * std::size_t(cols_) + std::size_t(col);
}

RayImage::RayImage(const std::vector<std::array<double, 3>>& hits) {
    std::vector<std::array<double, 3>> dirs;
    std::vector<double> ranges;
    std::vector<std::uint32_t> index;
    for (std::size_t i = 0; i < hits.size(); ++i) {
        const auto& h = hits[i];
        const double r = std::sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]);
        if (!(r > 0.0) || !std::isfinite(r)) continue;
        dirs.push_back({h[0] / r, h[1] / r, h[2] / r});
        ranges.push_back(r);
        index.push_back(std::uint32_t(i));
    }
    if (dirs.empty()) return;
    // Bins of about the rays' spacing, no finer than kMaxBins allow.
    const double spacing = std::sqrt(covered_solid_angle(dirs) / double(dirs.size()));
    // Whole bins round the circle, so a window's columns wrap exactly.
    rows_ = int(std::ceil(kPi / std::clamp(spacing, std::sqrt(2.0 * kPi * kPi / kMaxBins), kPi / 8.0)));
    cols_ = 2 * rows_;
    bin_ = kPi / rows_;
    // Counting sort by bin, stable: the rays of a bin keep their order.
    std::vector<std::size_t> bins(dirs.size());
    start_.assign(std::size_t(rows_) * std::size_t(cols_) + 1, 0);
    for (std::size_t i = 0; i < dirs.size(); ++i) {
        bins[i] = bin_of(dirs[i]);
        ++start_[bins[i] + 1];
    }
    for (std::size_t b = 1; b < start_.size(); ++b) start_[b] += start_[b - 1];
    std::vector<std::uint32_t> next(start_.begin(), start_.end() - 1);
    ray_.resize(dirs.size());
    dir_.resize(dirs.size());
    range_.resize(dirs.size());
    far_.assign(start_.size() - 1, 0.0f);
    for (std::size_t i = 0; i < dirs.size(); ++i) {
        const std::uint32_t k = next[bins[i]]++;
        ray_[k] = index[i];
        dir_[k] = dirs[i];
        range_[k] = ranges[i];
        // Rounded up: a bound.
        far_[bins[i]] = std::max(far_[bins[i]], std::nextafter(float(ranges[i]), HUGE_VALF));
    }
}

RayImage::Window RayImage::window(const std::array<double, 3>& d, double angle) const {
    const double lat = std::asin(std::clamp(d[2], -1.0, 1.0));
    const double lon = std::atan2(d[1], d[0]);
    // A margin for the rounding of the bins' edges.
    const double a = angle + 1e-9;
    Window w{};
    w.row0 = std::max(0, int(std::floor((lat - a + 0.5 * kPi) / bin_)));
    w.row1 = std::min(rows_ - 1, int(std::floor((lat + a + 0.5 * kPi) / bin_)));
    // The cone's longitudes: within asin(sin a / cos lat) of the centre's, unless it holds a pole.
    w.all = std::fabs(lat) + a >= 0.5 * kPi;
    if (!w.all) {
        const double s = std::sin(a) / std::cos(lat);
        const double span = s >= 1.0 ? kPi : std::asin(s);
        w.col0 = int(std::floor((lon - span + kPi) / bin_));
        w.col1 = int(std::floor((lon + span + kPi) / bin_));
        w.all = w.col1 - w.col0 + 1 >= cols_;
    }
    return w;
}

double RayImage::farthest(const std::array<double, 3>& d, double angle) const {
    if (range_.empty()) return 0.0;
    const Window w = window(d, angle);
    float far = 0.0f;
    for (int row = w.row0; row <= w.row1; ++row) {
        const float* bins = far_.data() + std::size_t(row) * std::size_t(cols_);
        if (w.all) {
            far = std::max(far, *std::max_element(bins, bins + cols_));
            continue;
        }
        for (int c = w.col0; c <= w.col1; ++c) far = std::max(far, bins[((c % cols_) + cols_) % cols_]);
    }
    return double(far);
}

}  // namespace vdbrecon::detail
