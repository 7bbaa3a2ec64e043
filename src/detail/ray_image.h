// The rays of one LiDAR scan, binned by direction, for the TSDF rule's scans (detail/tsdf.h):
// which rays cross a voxel, and how far the rays of a cone reach.
//
// A spinning LiDAR's rays are not a pinhole image: they cover the whole circle, with beams of
// their own elevations. They are binned on latitude (elevation) and longitude (azimuth) about
// the sensor, in square bins of about the rays' angular spacing (sqrt(solid angle covered /
// rays)), so a query looks at the few bins of its cone. A ray crosses a voxel when its line
// passes within the voxel's half diagonal of the voxel's centre, in front of the sensor: the
// voxels VDBFusion's ray traversal visits (I. Vizzo et al., "VDBFusion: Flexible and Efficient
// TSDF Integration of Range Sensor Data", Sensors 2022), found from the voxel's side.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

namespace vdbrecon::detail {

class RayImage {
  public:
    /// `hits` relative to the sensor; hits at the sensor (range 0 or not finite) are left out.
    explicit RayImage(const std::vector<std::array<double, 3>>& hits);

    /// Calls f(ray, range, along) for every ray whose line passes within `radius` of `p`
    /// (relative to the sensor) in front of the sensor, in one fixed order (bin by bin, rays in
    /// their order in `hits`): `ray` indexes `hits`, `along` is p's distance along the ray.
    template <class F>
    void rays_near(const std::array<double, 3>& p, double radius, F&& f) const;

    /// The largest range of the rays whose direction lies within `angle` (radians) of the unit
    /// direction `d`, or 0 when there is none (a bound: whole bins are taken).
    double farthest(const std::array<double, 3>& d, double angle) const;

    std::size_t rays() const { return range_.size(); }
    /// The rays' mean angular spacing (the bins' edge), radians.
    double spacing() const { return bin_; }

  private:
    /// The bins a cone of half-angle `angle` about the unit direction d touches: rows
    /// [row0, row1], columns [col0, col1] (wrapped modulo cols_; every column when all).
    struct Window {
        int row0, row1, col0, col1;
        bool all;
    };
    Window window(const std::array<double, 3>& d, double angle) const;
    std::size_t bin_of(const std::array<double, 3>& d) const;

    double bin_ = 0.0;  ///< bin edge, radians
    int rows_ = 0, cols_ = 0;
    std::vector<std::uint32_t> start_;  ///< rows_ x cols_ + 1 offsets into the rays below
    std::vector<std::uint32_t> ray_;    ///< the rays, bin by bin (their index in hits)
    std::vector<std::array<double, 3>> dir_;  ///< unit directions, in bin order
    std::vector<double> range_;               ///< ranges, in bin order
    std::vector<float> far_;                  ///< per bin, the largest range (0: empty)
};

template <class F>
void RayImage::rays_near(const std::array<double, 3>& p, double radius, F&& f) const {
    const double r2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
    if (!(r2 > radius * radius) || range_.empty()) return;  // the sensor is within the voxel
    const double r = std::sqrt(r2);
    const std::array<double, 3> d{p[0] / r, p[1] / r, p[2] / r};
    const Window w = window(d, std::asin(radius / r));
    const double rad2 = radius * radius;
    auto visit = [&](std::size_t bin) {
        for (std::uint32_t k = start_[bin]; k < start_[bin + 1]; ++k) {
            const std::array<double, 3>& e = dir_[k];
            const double along = p[0] * e[0] + p[1] * e[1] + p[2] * e[2];
            if (along > 0.0 && r2 - along * along <= rad2) f(std::size_t(ray_[k]), range_[k], along);
        }
    };
    for (int row = w.row0; row <= w.row1; ++row) {
        const std::size_t base = std::size_t(row) * std::size_t(cols_);
        if (w.all) {
            for (int c = 0; c < cols_; ++c) visit(base + std::size_t(c));
            continue;
        }
        for (int c = w.col0; c <= w.col1; ++c) visit(base + std::size_t(((c % cols_) + cols_) % cols_));
    }
}

}  // namespace vdbrecon::detail
