// Truncated signed distance fusion with space carving (see detail/tsdf.h).
#include "detail/tsdf.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "detail/volume_grids.h"
#include "vdbrecon/error.h"

namespace vdbrecon::detail {

using FloatLeaf = openvdb::FloatTree::LeafNodeType;

TsdfVolume::TsdfVolume(double voxel, double truncation_voxels, bool carve, const Vec3d& origin)
    : voxel_(voxel), truncation_(truncation_voxels * voxel), carve_(carve), origin_(origin),
      value_(openvdb::FloatGrid::create(1.0f)), weight_(openvdb::FloatGrid::create(0.0f)) {}

std::size_t TsdfVolume::integrate(const std::vector<std::array<double, 3>>& points,
                                  const std::vector<char>& measured, const Intrinsics& K,
                                  const Pose& m) {
    const int w = K.width, h = K.height;
    // Planar depth per pixel (0: none).
    std::vector<double> z(std::size_t(w) * std::size_t(h), 0.0);
    std::vector<openvdb::Coord> leaves;
    const int reach = int(std::ceil(truncation_ / voxel_));
    std::size_t valid = 0;
    for (std::size_t i = 0; i < z.size(); ++i) {
        if (!measured[i]) continue;
        const std::array<double, 3>& c = points[i];
        z[i] = c[2];
        ++valid;
        {
            // The leaves within the truncation of the pixel's point.
            openvdb::Coord lo, hi;
            for (int a = 0; a < 3; ++a) {
                const double wpt = m[std::size_t(4 * a)] * c[0] + m[std::size_t(4 * a + 1)] * c[1] +
                                   m[std::size_t(4 * a + 2)] * c[2] + m[std::size_t(4 * a + 3)] - origin_[std::size_t(a)];
                const int k = int(std::lround(wpt / voxel_));
                lo[a] = (k - reach) & ~7;
                hi[a] = (k + reach) & ~7;
            }
            for (int a = lo[0]; a <= hi[0]; a += 8) {
                for (int b = lo[1]; b <= hi[1]; b += 8) {
                    for (int e = lo[2]; e <= hi[2]; e += 8) leaves.emplace_back(a, b, e);
                }
            }
        }
    }
    pixels_ += valid;
    if (valid == 0) return 0;
    std::sort(leaves.begin(), leaves.end());
    leaves.erase(std::unique(leaves.begin(), leaves.end()), leaves.end());
    for (const openvdb::Coord& c : leaves) {  // serially: the trees' structure changes
        value_->tree().touchLeaf(c);
        weight_->tree().touchLeaf(c);
    }
    // Candidates: those leaves, or with carving every leaf held (the projection skips the
    // voxels the camera does not see).
    std::vector<FloatLeaf*> todo;
    if (carve_) {
        for (auto it = value_->tree().beginLeaf(); it; ++it) todo.push_back(&*it);
    } else {
        for (const openvdb::Coord& c : leaves) todo.push_back(value_->tree().probeLeaf(c));
    }
    const double trunc = truncation_;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, todo.size(), 8),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t j = rg.begin(); j < rg.end(); ++j) {
            FloatLeaf& val = *todo[j];
            FloatLeaf& wt = *weight_->tree().probeLeaf(val.origin());
            for (auto it = val.beginValueAll(); it; ++it) {
                const openvdb::Coord q = it.getCoord();
                double p[3];
                for (int a = 0; a < 3; ++a) p[a] = q[a] * voxel_ + origin_[std::size_t(a)] - m[std::size_t(4 * a + 3)];
                // Camera frame: R^T (x - t).
                const double cx = m[0] * p[0] + m[4] * p[1] + m[8] * p[2];
                const double cy = m[1] * p[0] + m[5] * p[1] + m[9] * p[2];
                const double cz = m[2] * p[0] + m[6] * p[1] + m[10] * p[2];
                if (!(cz > 0.0)) continue;
                const long u = std::lround(K.fx * cx / cz + K.cx), v = std::lround(K.fy * cy / cz + K.cy);
                if (u < 0 || v < 0 || u >= w || v >= h) continue;
                const double d = z[std::size_t(v) * std::size_t(w) + std::size_t(u)];
                if (d == 0.0) continue;
                const double sdf = d - cz;
                if (sdf < -trunc) continue;  // behind the surface: not seen
                const double t = std::min(1.0, sdf / trunc);
                const openvdb::Index idx = it.pos();
                const double w0 = double(wt.getValue(idx));
                const double v0 = w0 > 0.0 ? double(val.getValue(idx)) : 0.0;
                val.setValueOn(idx, float((v0 * w0 + t) / (w0 + 1.0)));
                wt.setValueOn(idx, float(w0 + 1.0));
            }
        }
    });
    return valid;
}

SplatResult TsdfVolume::result() const {
    const float background = float(truncation_);
    auto sdf = openvdb::FloatGrid::create(background);
    auto weight = openvdb::FloatGrid::create(0.0f);
    auto nearest = openvdb::Vec3fGrid::create(openvdb::Vec3f(0.0f));
    SplatResult r;
    for (auto it = value_->tree().cbeginLeaf(); it; ++it) {
        const FloatLeaf* wt = weight_->tree().probeConstLeaf(it->origin());
        std::unique_ptr<FloatLeaf> s, wl;
        std::unique_ptr<openvdb::Vec3fTree::LeafNodeType> nl;
        for (auto v = it->cbeginValueOn(); v; ++v) {
            const openvdb::Index idx = v.pos();
            const float wv = wt->getValue(idx);
            ++r.touched_voxels;
            if (!(wv > 0.0f) || !(std::fabs(*v) < 1.0f)) continue;  // unseen or free space
            if (!s) {
                s = std::make_unique<FloatLeaf>(it->origin(), background, false);
                wl = std::make_unique<FloatLeaf>(it->origin(), 0.0f, false);
                nl = std::make_unique<openvdb::Vec3fTree::LeafNodeType>(it->origin(), openvdb::Vec3f(0.0f), false);
            }
            s->setValueOn(idx, *v * background);
            wl->setValueOn(idx, wv);
            nl->setValueOn(idx, openvdb::Vec3f(0.0f));
            ++r.active_voxels;
        }
        if (!s) continue;
        ++r.leaves;
        sdf->tree().addLeaf(s.release());
        weight->tree().addLeaf(wl.release());
        nearest->tree().addLeaf(nl.release());
    }
    if (r.active_voxels == 0) {
        throw NumericalError("tsdf: no voxel near a measured surface");
    }
    r.volume = make_volume(sdf, weight, nearest, nullptr, voxel_, origin_);
    Volume& vol = r.volume;
    vol.metadata["kernel"] = "truncated signed distance along the rays (Curless and Levoy 1996)";
    vol.metadata["truncation"] = std::to_string(truncation_);
    vol.metadata["carving"] = carve_ ? "1" : "0";
    r.memory_bytes = vol.memory_bytes();
    return r;
}

}  // namespace vdbrecon::detail
