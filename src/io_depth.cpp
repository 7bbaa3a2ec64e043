// Depth images: OpenEXR through OpenEXR, 16-bit PNG through libpng (see scene.h).
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfIO.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <png.h>

#include <algorithm>
#include <cmath>
#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <sstream>
#include <stdexcept>

#include "detail/exr_header.h"
#include "detail/image_read.h"
#include "detail/io_common.h"
#include "vdbrecon/error.h"
#include "vdbrecon/io.h"
#include "vdbrecon/scene.h"

namespace vdbrecon {

namespace {

using detail::png_error_fn;
using detail::png_warning_fn;
using detail::PngError;
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

/// Why a depth image of w x h pixels is refused before its pixels are read, or "": another size
/// than the frame's camera, or a size no image may have.
std::string depth_size_problem(long w, long h, const ImageSize& expected) {
    if ((expected.width > 0 && w != expected.width) ||
        (expected.height > 0 && h != expected.height)) {
        return "the image is " + std::to_string(w) + " x " + std::to_string(h) +
               " pixels, the frame's camera " + std::to_string(expected.width) + " x " +
               std::to_string(expected.height);
    }
    return detail::image_size_problem(w, h);
}

/// The rows of an EXR image's depth channel, read a strip at a time and appended: the image
/// grows only as the file's chunks decode, so a header claiming a large data window over a few
/// bytes fails at its first missing chunk, not after allocating the whole image.
std::vector<float> read_exr_rows(Imf::InputFile& in, const std::string& channel) {
    // A multiple of every compression's lines per chunk (1, 16, 32, 256): no chunk is split.
    constexpr int kStrip = 256;
    const Imath::Box2i dw = in.header().dataWindow();
    const std::size_t w = std::size_t(long(dw.max.x) - dw.min.x + 1);
    std::vector<float> rows, strip;
    for (long y = dw.min.y; y <= dw.max.y; y += kStrip) {
        const int last = int(std::min<long>(dw.max.y, y + kStrip - 1));
        const Imath::Box2i box(Imath::V2i(dw.min.x, int(y)), Imath::V2i(dw.max.x, last));
        strip.assign(w * std::size_t(last - y + 1), 0.0f);
        Imf::FrameBuffer fb;
        fb.insert(channel.c_str(), Imf::Slice::Make(Imf::FLOAT, strip.data(), box));
        in.setFrameBuffer(fb);
        in.readPixels(int(y), last);
        rows.insert(rows.end(), strip.begin(), strip.end());
    }
    return rows;
}

/// An EXR file's bytes as OpenEXR reads a stream, mapped: the bytes exr_layout checked are the
/// bytes read, and OpenEXR reads chunks in place instead of copying them into buffers.
class ExrBytes : public Imf::IStream {
  public:
    ExrBytes(const std::string& path, std::string& bytes)
        : Imf::IStream(path.c_str()), bytes_(bytes) {}
    bool isMemoryMapped() const override { return true; }
    bool read(char c[], int n) override {
        std::memcpy(c, take(n), std::size_t(n));
        return at_ < bytes_.size();
    }
    char* readMemoryMapped(int n) override { return take(n); }
    std::uint64_t tellg() override { return at_; }
    void seekg(std::uint64_t at) override { at_ = at; }

  private:
    char* take(int n) {
        if (n < 0 || at_ > bytes_.size() || std::uint64_t(n) > bytes_.size() - at_) {
            throw std::runtime_error("the file ends early");
        }
        char* p = &bytes_[std::size_t(at_)];
        at_ += std::uint64_t(n);
        return p;
    }
    std::string& bytes_;
    std::uint64_t at_ = 0;
};

DepthImage read_exr_depth(const std::string& path, std::string bytes, const ImageSize& expected) {
    // The headers are walked before OpenEXR reads them: it allocates what they claim.
    const detail::ExrLayout layout = detail::exr_layout(bytes);
    std::string problem = layout.problem;
    if (problem.empty()) problem = depth_size_problem(layout.width, layout.height, expected);
    if (!problem.empty()) throw FormatError(detail::where(path, problem));
    DepthImage img;
    try {
        ExrBytes stream(path, bytes);
        Imf::InputFile in(stream);
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
        img.depth = read_exr_rows(in, channel);
        img.width = int(layout.width);
        img.height = int(layout.height);
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

/// A PNG's values (8- or 16-bit) as depths: value / units_per_metre.
void png_depths(const std::vector<std::uint16_t>& pixels, int bits, double units_per_metre,
                DepthImage& img) {
    img.depth.resize(std::size_t(img.width) * std::size_t(img.height));
    const double s = 1.0 / units_per_metre;
    float* out = img.depth.data();
    if (bits == 16) {  // big-endian words; a loop the compiler vectorises
        constexpr bool swap = __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__;
        const std::uint16_t* in = pixels.data();
        for (std::size_t i = 0; i < img.depth.size(); ++i) {
            const std::uint16_t v = swap ? std::uint16_t(in[i] >> 8 | in[i] << 8) : in[i];
            out[i] = float(double(v) * s);
        }
    } else {
        const auto* bytes = reinterpret_cast<const std::uint8_t*>(pixels.data());
        for (std::size_t i = 0; i < img.depth.size(); ++i) out[i] = float(double(bytes[i]) * s);
    }
}

/// Why a depth PNG's header is refused before its pixels are read, or "".
std::string png_header_problem(long w, long h, int bits, int type, const ImageSize& expected,
                               long file_bytes) {
    std::string problem = depth_size_problem(w, h, expected);
    if (!problem.empty()) return problem;
    if (type != PNG_COLOR_TYPE_GRAY || (bits != 16 && bits != 8)) {
        return "a depth PNG must be 16-bit (or 8-bit) greyscale; this one has colour type " +
               std::to_string(type) + " at " + std::to_string(bits) + " bits";
    }
    return detail::file_size_problem(w, h, detail::png_least_bytes(w, h, bits), file_bytes);
}

DepthImage read_png_depth(const std::string& path, double units_per_metre,
                          const ImageSize& expected) {
    const std::string file = detail::read_file(path);
    const std::string chunks = detail::png_chunk_problem(file);
    if (!chunks.empty()) throw FormatError(detail::where(path, chunks));
    detail::PngBytes input{file};
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
        detail::start_png_reader(png, input);
        // Every chunk's CRC is still checked (libpng's default), and it covers the compressed
        // bytes the zlib stream's Adler-32 would check once more after inflating them.
        png_set_option(png, PNG_IGNORE_ADLER32, PNG_OPTION_ON);
        png_read_info(png, info);
        const png_uint_32 w = png_get_image_width(png, info), h = png_get_image_height(png, info);
        const int bits = png_get_bit_depth(png, info);
        problem = png_header_problem(long(w), long(h), bits, png_get_color_type(png, info),
                                     expected, long(file.size()));
        if (problem.empty()) {
            png_set_interlace_handling(png);
            png_read_update_info(png, info);
            const std::size_t row_bytes = png_get_rowbytes(png, info);
            pixels.resize((row_bytes * h + 1) / 2);  // 16-bit words: aligned for png_depths
            auto* bytes = reinterpret_cast<png_bytep>(pixels.data());
            rows.resize(h);
            for (png_uint_32 y = 0; y < h; ++y) rows[y] = bytes + row_bytes * y;
            png_read_image(png, rows.data());
            img.width = int(w);
            img.height = int(h);
            png_depths(pixels, bits, units_per_metre, img);
        }
    }
    png_destroy_read_struct(png ? &png : nullptr, info ? &info : nullptr, nullptr);
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

DepthImage read_depth_image(const std::string& path, double units_per_metre,
                            const ImageSize& expected) {
    check_units(path, units_per_metre);
    const std::string ext = file_extension(path);
    DepthImage img;
    if (ext == "exr") {
        img = read_exr_depth(path, detail::read_file(path), expected);
    } else if (ext == "png") {
        img = read_png_depth(path, units_per_metre, expected);
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
