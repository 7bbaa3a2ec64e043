// Checks of cameras and poses (camera.h), on their own so that the scene readers build without
// OpenVDB (fuzz/).
#include "vdbrecon/camera.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>

#include "vdbrecon/error.h"

namespace vdbrecon {

void Intrinsics::validate() const {
    auto positive = [](double v, const char* name) {
        if (!(std::isfinite(v) && v > 0.0)) {
            std::ostringstream s;
            s << "intrinsics: " << name << " = " << v << ": must be a positive number";
            throw InvalidArgument(s.str());
        }
    };
    positive(fx, "fx");
    positive(fy, "fy");
    if (!std::isfinite(cx) || !std::isfinite(cy)) {
        throw InvalidArgument("intrinsics: cx and cy must be finite numbers");
    }
    if (width <= 0 || height <= 0 || width > (1 << 16) || height > (1 << 16)) {
        throw InvalidArgument("intrinsics: image size " + std::to_string(width) + " x " +
                              std::to_string(height) + " is not in 1..65536");
    }
}

void validate_pose(const Pose& m) {
    for (double v : m) {
        if (!std::isfinite(v)) throw InvalidArgument("pose: has a NaN or infinite entry");
    }
    if (m[12] != 0.0 || m[13] != 0.0 || m[14] != 0.0 || m[15] != 1.0) {
        throw InvalidArgument("pose: the last row must be 0 0 0 1");
    }
    double worst = 0.0;  // |R^T R - I|, largest entry
    for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) {
            double dot = 0.0;
            for (int r = 0; r < 3; ++r) {
                dot += m[std::size_t(r * 4 + a)] * m[std::size_t(r * 4 + b)];
            }
            worst = std::max(worst, std::fabs(dot - (a == b ? 1.0 : 0.0)));
        }
    }
    const double det = m[0] * (m[5] * m[10] - m[6] * m[9]) - m[1] * (m[4] * m[10] - m[6] * m[8]) +
                       m[2] * (m[4] * m[9] - m[5] * m[8]);
    if (worst > 1e-3 || det < 0.0) {
        std::ostringstream s;
        s << "pose: the 3x3 part is not a rotation (|R^T R - I| = " << worst << ", det " << det
          << "); poses must be rigid camera-to-world transforms";
        throw InvalidArgument(s.str());
    }
}

}  // namespace vdbrecon
