// What the image readers (io_depth.cpp, io_color.cpp) share: the checks of a header's claimed
// size, made before any pixel buffer is allocated, and libpng's set-up (a file's bytes read
// from memory, limits, error hooks).
#pragma once

#include <png.h>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>
#include <string_view>

namespace vdbrecon::detail {

/// The largest side an image may have (pixels).
constexpr int kMaxImageSide = 1 << 16;
/// At most this many pixels (a 16k x 8k image): a hostile header must not make us allocate
/// gigabytes before a single row is read.
constexpr long kMaxImagePixels = 1L << 27;
/// Deflate (PNG's IDAT, EXR's ZIP) codes a run of 258 bytes in no less than 2 bits: its data
/// never expands more than 1032-fold.
constexpr double kMaxDeflateRatio = 1032.0;

/// Why a header's w x h is not believed, or "" when it is: a side outside 1..kMaxImageSide, or
/// more than kMaxImagePixels pixels.
inline std::string image_size_problem(long w, long h) {
    if (w > 0 && h > 0 && w <= kMaxImageSide && h <= kMaxImageSide && w * h <= kMaxImagePixels) {
        return "";
    }
    return "an image of " + std::to_string(w) + " x " + std::to_string(h) +
           " pixels, more than an image may have (2^16 a side, 2^27 pixels)";
}

/// Why a file of `file_bytes` bytes cannot hold the w x h image its header claims, whose
/// pixels take at least `least_bytes` bytes at the format's best compression, or "" when it
/// can: the file is truncated, or its header lies.
inline std::string file_size_problem(long w, long h, double least_bytes, long file_bytes) {
    if (least_bytes <= double(file_bytes)) return "";
    return "the header claims " + std::to_string(w) + " x " + std::to_string(h) +
           " pixels, which take at least " + std::to_string(long(least_bytes)) +
           " bytes; the file has " + std::to_string(file_bytes) +
           " (truncated, or a corrupt header)";
}

/// Why a PNG file's chunks do not fit in its bytes, or "": each chunk's claimed length, up to
/// IEND, must lie within the file. libpng allocates an ancillary chunk's length before reading
/// its data, so a few bytes claiming a 2 GB text chunk would cost 2 GB.
inline std::string png_chunk_problem(std::string_view png) {
    std::size_t at = 8;  // after the signature (libpng checks it)
    while (png.size() >= at + 8) {
        const auto byte = [&](std::size_t i) { return std::uint32_t(std::uint8_t(png[at + i])); };
        const std::uint32_t length = byte(0) << 24 | byte(1) << 16 | byte(2) << 8 | byte(3);
        const std::string type(png.substr(at + 4, 4));
        if (std::uint64_t(length) + 12 > png.size() - at) {
            std::string printable;
            for (char c : type) {
                printable += (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') ? c : '?';
            }
            return "the chunk '" + printable + "' at byte " + std::to_string(at) + " claims " +
                   std::to_string(length) + " bytes, past the end of the file (" +
                   std::to_string(png.size()) + " bytes)";
        }
        if (type == "IEND") break;
        at += 12 + std::size_t(length);
    }
    return "";
}

/// A PNG file's bytes, as libpng reads them (png_read_bytes).
struct PngBytes {
    std::string_view bytes;
    std::size_t at = 0;
};
inline void png_read_bytes(png_structp png, png_bytep out, png_size_t n) {
    auto* in = static_cast<PngBytes*>(png_get_io_ptr(png));
    if (n > in->bytes.size() - in->at) png_error(png, "the file ends early");
    std::memcpy(out, in->bytes.data() + in->at, n);
    in->at += n;
}

/// Points a PNG reader at `input` with the limits the readers share: sides of at most
/// kMaxImageSide, and every ancillary chunk but tRNS (text, ICC profiles, ...: nothing the
/// readers use) skipped unread.
inline void start_png_reader(png_structp png, PngBytes& input) {
    png_set_read_fn(png, &input, png_read_bytes);
    png_set_user_limits(png, kMaxImageSide, kMaxImageSide);
    png_set_keep_unknown_chunks(png, PNG_HANDLE_CHUNK_NEVER, nullptr, -1);
#ifdef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
    // fuzz/: mutated chunks keep their old checksums; checking them would end every read at the
    // first mutation, before the code behind it.
    png_set_crc_action(png, PNG_CRC_QUIET_USE, PNG_CRC_QUIET_USE);
    png_set_option(png, PNG_IGNORE_ADLER32, PNG_OPTION_ON);
#endif
}

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

/// The least bytes a PNG's compressed data takes for w x h pixels of `bits` bits (all
/// channels): its rows, a filter byte each, inflate to no more than kMaxDeflateRatio times it.
inline double png_least_bytes(long w, long h, int bits) {
    return double(h) * (1.0 + double(w) * bits / 8.0) / kMaxDeflateRatio;
}

}  // namespace vdbrecon::detail
