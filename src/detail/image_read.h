// What the image readers (io_depth.cpp, io_color.cpp) share: the largest image a header may
// claim before any pixel buffer is allocated, and libpng's error hooks.
#pragma once

#include <png.h>

#include <cstdio>

namespace vdbrecon::detail {

/// The largest side an image may have (pixels).
constexpr int kMaxImageSide = 1 << 16;
/// At most this many pixels (a 16k x 8k image): a hostile header must not make us allocate
/// gigabytes before a single row is read.
constexpr long kMaxImagePixels = 1L << 27;

/// libpng reports errors through longjmp; the message is kept for the exception.
struct PngError {
    char message[256] = {0};
};
inline void png_error_fn(png_structp png, png_const_charp msg) {
    auto* e = static_cast<PngError*>(png_get_error_ptr(png));
    std::snprintf(e->message, sizeof e->message, "%s", msg);
    png_longjmp(png, 1);
}
inline void png_warning_fn(png_structp, png_const_charp) {}

}  // namespace vdbrecon::detail
