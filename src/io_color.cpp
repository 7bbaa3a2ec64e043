// Colour images for fusion: PNG read through libpng, JPEG through libjpeg-turbo (see scene.h),
// both Debian's decoders of hostile files, from the file's bytes in memory, a claimed size
// checked against the largest image and against the file's size before any pixel buffer
// (detail/image_read.h); PNG written by the project's encoder (detail/png.h).
#include <csetjmp>
#include <cstddef>
#include <cstdio>  // before jpeglib.h, which uses FILE and size_t
#include <cstring>
#include <memory>

#include <jpeglib.h>
#include <png.h>

#include "detail/image_read.h"
#include "detail/io_common.h"
#include "detail/png.h"
#include "vdbrecon/error.h"
#include "vdbrecon/io.h"
#include "vdbrecon/scene.h"

namespace vdbrecon {

namespace {

/// A Huffman-coded JPEG spends at least a bit on each 8 x 8 block of its fullest component (512
/// pixels a byte); four times that leaves room for arithmetic coding of flat images. A file
/// that claims more pixels a byte than this is cut short (libjpeg would decode the missing rows
/// as grey) or lies about its size.
constexpr double kMaxJpegPixelsPerByte = 2048.0;

/// The pixels of a colour image, 8-bit RGB, as 0..1.
std::vector<Vec3f> rgb_of(const std::vector<std::uint8_t>& pixels, std::size_t n) {
    float level[256];  // the same quotients, looked up instead of three divisions a pixel
    for (int k = 0; k < 256; ++k) level[k] = float(k) / 255.0f;
    std::vector<Vec3f> rgb(n);
    for (std::size_t i = 0; i < n; ++i) {
        rgb[i] = {level[pixels[3 * i]], level[pixels[3 * i + 1]], level[pixels[3 * i + 2]]};
    }
    return rgb;
}

ColorImage read_png_color(const std::string& path) {
    const std::string file = detail::read_file(path);
    const std::string chunks = detail::png_chunk_problem(file);
    if (!chunks.empty()) throw FormatError(detail::where(path, chunks));
    detail::PngBytes input{file};
    detail::PngError err;
    png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &err, detail::png_error_fn,
                                             detail::png_warning_fn);
    png_infop info = png ? png_create_info_struct(png) : nullptr;
    ColorImage img;
    std::vector<std::uint8_t> pixels;
    std::vector<png_bytep> rows;
    std::string problem;
    if (!png || !info) {
        problem = "out of memory";
    } else if (setjmp(png_jmpbuf(png))) {
        problem = std::string("not a readable PNG file: ") + err.message;
    } else {
        detail::start_png_reader(png, input);
        png_read_info(png, info);
        const long w = long(png_get_image_width(png, info)), h = long(png_get_image_height(png, info));
        const int bits = png_get_bit_depth(png, info) * png_get_channels(png, info);
        problem = detail::image_size_problem(w, h);
        if (problem.empty()) {
            problem = detail::file_size_problem(w, h, detail::png_least_bytes(w, h, bits),
                                                long(file.size()));
        }
        if (problem.empty()) {
            // Every kind to 8-bit RGB: palettes expanded, grey to RGB, alpha and 16 bits dropped.
            png_set_expand(png);
            png_set_strip_16(png);
            png_set_strip_alpha(png);
            png_set_gray_to_rgb(png);
            png_set_interlace_handling(png);
            png_read_update_info(png, info);
            const std::size_t row_bytes = png_get_rowbytes(png, info);
            if (row_bytes != std::size_t(w) * 3) {
                problem = "unexpected row size after conversion to RGB";
            } else {
                pixels.resize(row_bytes * std::size_t(h));
                rows.resize(std::size_t(h));
                for (long y = 0; y < h; ++y) rows[std::size_t(y)] = pixels.data() + row_bytes * std::size_t(y);
                png_read_image(png, rows.data());
                img.width = int(w);
                img.height = int(h);
            }
        }
    }
    png_destroy_read_struct(png ? &png : nullptr, info ? &info : nullptr, nullptr);
    if (!problem.empty()) throw FormatError(detail::where(path, problem));
    img.rgb = rgb_of(pixels, std::size_t(img.width) * std::size_t(img.height));
    return img;
}

struct JpegFail {
    jpeg_error_mgr mgr;
    std::jmp_buf jump;
    char message[JMSG_LENGTH_MAX] = {0};
};
void jpeg_fail(j_common_ptr info) {
    auto* e = reinterpret_cast<JpegFail*>(info->err);
    (*info->err->format_message)(info, e->message);
    std::longjmp(e->jump, 1);
}
void jpeg_quiet(j_common_ptr, int) {}

ColorImage read_jpeg_color(const std::string& path) {
    const std::string file = detail::read_file(path);
    jpeg_decompress_struct info{};
    JpegFail err;
    info.err = jpeg_std_error(&err.mgr);
    err.mgr.error_exit = jpeg_fail;
    err.mgr.emit_message = jpeg_quiet;
    ColorImage img;
    std::vector<std::uint8_t> pixels;
    std::string problem;
    if (setjmp(err.jump)) {
        problem = std::string("not a readable JPEG file: ") + err.message;
    } else {
        jpeg_create_decompress(&info);
        jpeg_mem_src(&info, reinterpret_cast<const unsigned char*>(file.data()),
                     static_cast<unsigned long>(file.size()));
        jpeg_read_header(&info, TRUE);
        const long w = long(info.image_width), h = long(info.image_height);
        problem = detail::image_size_problem(w, h);
        if (problem.empty()) {
            problem = detail::file_size_problem(w, h, double(w) * double(h) / kMaxJpegPixelsPerByte,
                                                long(file.size()));
        }
        if (problem.empty()) {
            info.out_color_space = JCS_RGB;
            jpeg_start_decompress(&info);
            const std::size_t row = std::size_t(info.output_width) * 3;
            pixels.resize(row * info.output_height);
            while (info.output_scanline < info.output_height) {
                JSAMPROW at = pixels.data() + std::size_t(info.output_scanline) * row;
                jpeg_read_scanlines(&info, &at, 1);
            }
            jpeg_finish_decompress(&info);
            img.width = int(info.output_width);
            img.height = int(info.output_height);
        }
    }
    jpeg_destroy_decompress(&info);
    if (!problem.empty()) throw FormatError(detail::where(path, problem));
    img.rgb = rgb_of(pixels, std::size_t(img.width) * std::size_t(img.height));
    return img;
}

std::uint8_t to_byte(float v) {
    return std::uint8_t(v <= 0.0f ? 0 : v >= 1.0f ? 255 : int(v * 255.0f + 0.5f));
}

}  // namespace

ColorImage read_color_image(const std::string& path) {
    const std::string ext = file_extension(path);
    if (ext == "png") return read_png_color(path);
    if (ext == "jpg" || ext == "jpeg") return read_jpeg_color(path);
    throw FormatError(detail::where(path, "unknown colour image type '." + ext + "' (.png, .jpg)"));
}

void write_color_image(const std::string& path, const ColorImage& image) {
    if (image.width <= 0 || image.height <= 0 ||
        image.rgb.size() != std::size_t(image.width) * std::size_t(image.height)) {
        throw InvalidArgument(detail::where(path, "colour image: its pixels do not fill width x height"));
    }
    const std::string ext = file_extension(path);
    if (ext != "png" && ext != "jpg" && ext != "jpeg") {
        throw InvalidArgument(detail::where(path, "colour images are written as .png or .jpg"));
    }
    std::vector<std::uint8_t> bytes(image.rgb.size() * 3);
    for (std::size_t i = 0; i < image.rgb.size(); ++i) {
        for (std::size_t c = 0; c < 3; ++c) bytes[3 * i + c] = to_byte(image.rgb[i][c]);
    }
    if (ext == "png") {  // the project's 8-bit RGB encoder (previews, texture atlases)
        detail::write_png_rgb8(path, image.width, image.height, bytes.data());
        return;
    }
    detail::AtomicFile out(path);
    const std::size_t row = std::size_t(image.width) * 3;
    jpeg_compress_struct info{};
    JpegFail err;
    info.err = jpeg_std_error(&err.mgr);
    err.mgr.error_exit = jpeg_fail;
    if (setjmp(err.jump)) {
        jpeg_destroy_compress(&info);
        throw IoError(detail::where(path, std::string("cannot write the JPEG: ") + err.message));
    }
    jpeg_create_compress(&info);
    jpeg_stdio_dest(&info, out.stream());
    info.image_width = JDIMENSION(image.width);
    info.image_height = JDIMENSION(image.height);
    info.input_components = 3;
    info.in_color_space = JCS_RGB;
    jpeg_set_defaults(&info);
    jpeg_set_quality(&info, 95, TRUE);
    jpeg_start_compress(&info, TRUE);
    while (info.next_scanline < info.image_height) {
        JSAMPROW r = bytes.data() + std::size_t(info.next_scanline) * row;
        jpeg_write_scanlines(&info, &r, 1);
    }
    jpeg_finish_compress(&info);
    jpeg_destroy_compress(&info);
    out.commit();
}

}  // namespace vdbrecon
