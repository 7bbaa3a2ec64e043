// Principal components of a point's k-neighbourhood, shared by normal estimation and the
// planarity outlier test.
#pragma once

#include <Eigen/Eigenvalues>
#include <cstddef>
#include <vector>

#include "vdbrecon/types.h"

namespace vdbrecon::detail {

/// Covariance of point i and its k neighbours `nb` (coordinates relative to point i, so far-away
/// frames keep their precision): eigenvalues ascending, and the eigenvector of the smallest.
/// False when the solver fails.
inline bool neighbourhood_pca(Span<Vec3f> pts, std::size_t i, const int* nb, int k,
                              Eigen::Vector3d& eigenvalues, Eigen::Vector3d& smallest) {
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    const Vec3f& c = pts[i];
    auto rel = [&](std::size_t j) {
        return Eigen::Vector3d(double(pts[j][0]) - c[0], double(pts[j][1]) - c[1],
                               double(pts[j][2]) - c[2]);
    };
    for (int j = 0; j < k; ++j) mean += rel(std::size_t(nb[j]));
    mean /= double(k + 1);  // the point itself contributes (0,0,0)
    Eigen::Matrix3d cov = mean * mean.transpose();  // the point itself: (0 - mean)(0 - mean)^T
    for (int j = 0; j < k; ++j) {
        const Eigen::Vector3d d = rel(std::size_t(nb[j])) - mean;
        cov += d * d.transpose();
    }
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(cov);
    if (es.info() != Eigen::Success) return false;
    eigenvalues = es.eigenvalues();
    smallest = es.eigenvectors().col(0);
    return true;
}

}  // namespace vdbrecon::detail
