// The PCD reader (src/io_pcd.cpp), shared by read_points and organized-cloud fusion.
#pragma once

#include <array>
#include <optional>
#include <string>
#include <string_view>

#include "detail/io_common.h"

namespace vdbrecon::detail {

struct PcdData {
    RawPoints raw;  ///< every point, NaN ones included (an organized cloud's holes)
    std::size_t width = 0, height = 1;
    /// VIEWPOINT: sensor position tx ty tz and orientation qw qx qy qz (PCL's order).
    std::optional<std::array<double, 7>> viewpoint;
};

/// Parses a PCD file's bytes. Throws FormatError naming `path`.
PcdData read_pcd(const std::string& path, std::string_view content);

}  // namespace vdbrecon::detail
