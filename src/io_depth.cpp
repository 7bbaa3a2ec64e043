// Depth images: OpenEXR through OpenEXR, 16-bit PNG through libpng (see scene.h).
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <png.h>

#include <cmath>
#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <sstream>

#include "detail/image_read.h"
#include "detail/io_common.h"
#include "vdbrecon/error.h"
#include "vdbrecon/io.h"
#include "vdbrecon/scene.h"

namespace vdbrecon {

namespace {

using detail::PngError;
using detail::png_error_fn;
using detail::png_warning_fn;
constexpr int kMaxSide = detail::kMaxImageSide;
constexpr long kMaxPixels = detail::kMaxImagePixels;
/// Blender marks pixels that saw nothing with 1e10 (in half: 65504, the largest half).
constexpr float kNoHit = 65504.0f;

/// The depth channel of an EXR header (see scene.h), or "" when there is none.
std::string depth_channel(const Imf::ChannelList& channels) {
    for (const char* name : {"Z", "depth", "Depth", "R", "Y"}) {
        if (channels.findChannel(name)) return name;
    }
    for (auto it = channels.begin(); it != channels.end(); ++it) {
        const std::string n = it.name();
        const std::size_t dot = n.rfind('.');
        const std::string last = dot == std::string::npos ? n : n.substr(dot + 1);
        if (last == "Z" || last == "depth" || last == "Depth") return n;
    }
    return "";
}

DepthImage read_exr_depth(const std::string& path) {
    DepthImage img;
    try {
        Imf::InputFile in(path.c_str());
        const Imath::Box2i dw = in.header().dataWindow();
        const long w = long(dw.max.x) - dw.min.x + 1, h = long(dw.max.y) - dw.min.y + 1;
        if (w <= 0 || h <= 0 || w > kMaxSide || h > kMaxSide || w * h > kMaxPixels) {
            throw FormatError(detail::where(path, "EXR data window of " + std::to_string(w) +
                                                      " x " + std::to_string(h) + " pixels"));
        }
        const std::string channel = depth_channel(in.header().channels());
        if (channel.empty()) {
            std::string names;
            for (auto it = in.header().channels().begin(); it != in.header().channels().end(); ++it) {
                names += std::string(names.empty() ? "" : ", ") + it.name();
            }
            throw FormatError(detail::where(
                path, "no depth channel (Z, depth, R, Y or a layer's .Z) among: " +
                          detail::printable(names)));
        }
        img.width = int(w);
        img.height = int(h);
        img.depth.assign(std::size_t(w) * std::size_t(h), 0.0f);
        Imf::FrameBuffer fb;
        char* base = reinterpret_cast<char*>(img.depth.data()) -
                     (std::ptrdiff_t(dw.min.x) + std::ptrdiff_t(dw.min.y) * w) * std::ptrdiff_t(sizeof(float));
        fb.insert(channel.c_str(), Imf::Slice(Imf::FLOAT, base, sizeof(float), sizeof(float) * std::size_t(w),
                                              1, 1, 0.0));
        in.setFrameBuffer(fb);
        in.readPixels(dw.min.y, dw.max.y);
    } catch (const Error&) {
        throw;
    } catch (const std::exception& e) {
        throw FormatError(detail::where(path, std::string("not a readable EXR file: ") +
                                                  detail::printable(e.what())));
    }
    for (float& d : img.depth) {
        if (!(d < kNoHit)) d = 0.0f;  // no hit, NaN, inf
    }
    return img;
}

DepthImage read_png_depth(const std::string& path, double units_per_metre) {
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) throw IoError(detail::where(path, std::string("cannot open: ") + std::strerror(errno)));
    PngError err;
    png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &err, png_error_fn, png_warning_fn);
    png_infop info = png ? png_create_info_struct(png) : nullptr;
    DepthImage img;
    std::vector<png_bytep> rows;
    std::vector<std::uint16_t> pixels;
    std::string problem;
    if (!png || !info) {
        problem = "out of memory";
    } else if (setjmp(png_jmpbuf(png))) {
        problem = std::string("not a readable PNG file: ") + err.message;
    } else {
        png_set_user_limits(png, kMaxSide, kMaxSide);
        // Every chunk's CRC is still checked (libpng's default), and it covers the compressed
        // bytes the zlib stream's Adler-32 would check once more after inflating them.
        png_set_option(png, PNG_IGNORE_ADLER32, PNG_OPTION_ON);
        png_init_io(png, f);
        png_read_info(png, info);
        const png_uint_32 w = png_get_image_width(png, info), h = png_get_image_height(png, info);
        const int depth = png_get_bit_depth(png, info), type = png_get_color_type(png, info);
        if (long(w) * long(h) > kMaxPixels) {
            problem = "PNG of " + std::to_string(w) + " x " + std::to_string(h) +
                      " pixels, more than a depth image can have (2^27)";
        } else if (type != PNG_COLOR_TYPE_GRAY || (depth != 16 && depth != 8)) {
            problem = "a depth PNG must be 16-bit (or 8-bit) greyscale; this one has colour type " +
                      std::to_string(type) + " at " + std::to_string(depth) + " bits";
        } else {
            png_set_interlace_handling(png);
            png_read_update_info(png, info);
            const std::size_t row_bytes = png_get_rowbytes(png, info);
            pixels.resize((row_bytes * h + 1) / 2);  // 16-bit words: aligned for the loop below
            auto* bytes = reinterpret_cast<png_bytep>(pixels.data());
            rows.resize(h);
            for (png_uint_32 y = 0; y < h; ++y) rows[y] = bytes + row_bytes * y;
            png_read_image(png, rows.data());
            img.width = int(w);
            img.height = int(h);
            img.depth.resize(std::size_t(w) * h);
            const double s = 1.0 / units_per_metre;
            float* out = img.depth.data();
            if (depth == 16) {  // big-endian words; a loop the compiler vectorises
                constexpr bool swap = __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__;
                const std::uint16_t* in = pixels.data();
                for (std::size_t i = 0; i < img.depth.size(); ++i) {
                    const std::uint16_t v = swap ? std::uint16_t(in[i] >> 8 | in[i] << 8) : in[i];
                    out[i] = float(double(v) * s);
                }
            } else {
                for (std::size_t i = 0; i < img.depth.size(); ++i) out[i] = float(double(bytes[i]) * s);
            }
        }
    }
    png_destroy_read_struct(png ? &png : nullptr, info ? &info : nullptr, nullptr);
    std::fclose(f);
    if (!problem.empty()) throw FormatError(detail::where(path, problem));
    return img;
}

void write_png_depth(const std::string& path, const DepthImage& img, double units_per_metre) {
    std::vector<std::uint8_t> pixels(img.depth.size() * 2);
    for (std::size_t i = 0; i < img.depth.size(); ++i) {
        const double d = double(img.depth[i]);
        long v = 0;
        if (std::isfinite(d) && d > 0.0) {
            v = std::lround(d * units_per_metre);
            if (v > 65535) {
                throw InvalidArgument(detail::where(path, "depth " + std::to_string(d) +
                                                              " exceeds 65535 PNG units"));
            }
        }
        pixels[2 * i] = std::uint8_t(v >> 8);
        pixels[2 * i + 1] = std::uint8_t(v & 255);
    }
    detail::AtomicFile file(path);
    std::FILE* f = file.stream();
    PngError err;
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &err, png_error_fn, png_warning_fn);
    png_infop info = png ? png_create_info_struct(png) : nullptr;
    std::vector<png_bytep> rows(std::size_t(img.height));
    std::string problem;
    if (!png || !info) {
        problem = "out of memory";
    } else if (setjmp(png_jmpbuf(png))) {
        problem = err.message;
    } else {
        png_init_io(png, f);
        png_set_IHDR(png, info, png_uint_32(img.width), png_uint_32(img.height), 16,
                     PNG_COLOR_TYPE_GRAY, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
                     PNG_FILTER_TYPE_DEFAULT);
        png_write_info(png, info);
        for (int y = 0; y < img.height; ++y) {
            rows[std::size_t(y)] = pixels.data() + std::size_t(y) * std::size_t(img.width) * 2;
        }
        png_write_image(png, rows.data());
        png_write_end(png, nullptr);
    }
    png_destroy_write_struct(png ? &png : nullptr, info ? &info : nullptr);
    if (!problem.empty()) throw IoError(detail::where(path, "cannot write the PNG: " + problem));
    file.commit();
}

void write_exr_depth(const std::string& path, const DepthImage& img) {
    detail::AtomicFile file(path);
    file.create();
    try {
        Imf::Header header(img.width, img.height);
        header.channels().insert("Z", Imf::Channel(Imf::FLOAT));
        Imf::OutputFile out(file.temp_path().c_str(), header);
        Imf::FrameBuffer fb;
        fb.insert("Z", Imf::Slice(Imf::FLOAT,
                                  const_cast<char*>(reinterpret_cast<const char*>(img.depth.data())),
                                  sizeof(float), sizeof(float) * std::size_t(img.width)));
        out.setFrameBuffer(fb);
        out.writePixels(img.height);
    } catch (const std::exception& e) {
        throw IoError(detail::where(path, std::string("cannot write the EXR file: ") + e.what()));
    }
    file.commit();
}

void check_units(const std::string& path, double units_per_metre) {
    if (!(std::isfinite(units_per_metre) && units_per_metre > 0.0)) {
        throw InvalidArgument(detail::where(path, "depth units per metre must be a positive number"));
    }
}

}  // namespace

DepthImage read_depth_image(const std::string& path, double units_per_metre) {
    check_units(path, units_per_metre);
    const std::string ext = file_extension(path);
    DepthImage img;
    if (ext == "exr") {
        detail::read_file(path).clear();  // missing / unreadable: our IoError, not OpenEXR's
        img = read_exr_depth(path);
    } else if (ext == "png") {
        img = read_png_depth(path, units_per_metre);
    } else {
        throw FormatError(detail::where(path, "unknown depth image extension (use .exr or .png)"));
    }
    if (img.width <= 0 || img.height <= 0) throw FormatError(detail::where(path, "empty depth image"));
    return img;
}

void write_depth_image(const std::string& path, const DepthImage& depth, double units_per_metre) {
    check_units(path, units_per_metre);
    if (depth.width <= 0 || depth.height <= 0 ||
        depth.depth.size() != std::size_t(depth.width) * std::size_t(depth.height)) {
        throw InvalidArgument(detail::where(path, "depth image: its values do not fill width x height"));
    }
    const std::string ext = file_extension(path);
    if (ext == "exr") {
        write_exr_depth(path, depth);
    } else if (ext == "png") {
        write_png_depth(path, depth, units_per_metre);
    } else {
        throw InvalidArgument(detail::where(path, "unknown depth image extension (use .exr or .png)"));
    }
}

}  // namespace vdbrecon
