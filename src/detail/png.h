// An 8-bit RGB PNG encoder (zlib), for the preview pictures and the texture atlas.
#pragma once

#include <cstdint>
#include <string>

namespace vdbrecon::detail {

/// The bytes of a PNG file of width x height pixels from `rgb` (3 bytes a pixel, rows top
/// first). Throws IoError naming `path` when zlib fails.
std::string encode_png_rgb8(int width, int height, const std::uint8_t* rgb,
                            const std::string& path);

/// Writes those bytes to `path` (under a temporary name, renamed into place). Throws IoError.
void write_png_rgb8(const std::string& path, int width, int height, const std::uint8_t* rgb);

}  // namespace vdbrecon::detail
