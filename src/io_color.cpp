// Colour images for fusion: PNG read through libpng, JPEG through libjpeg-turbo (see scene.h),
// both Debian's decoders of hostile files, a claimed size checked before any pixel buffer
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

/// A file opened for reading or writing, closed on every path out.
struct File {
    std::FILE* f;
    explicit File(std::FILE* file) : f(file) {}
    ~File() {
        if (f) std::fclose(f);
    }
};

std::string size_problem(long w, long h) {
    if (w > 0 && h > 0 && w <= detail::kMaxImageSide && h <= detail::kMaxImageSide &&
        w * h <= detail::kMaxImagePixels) {
        return "";
    }
    return "an image of " + std::to_string(w) + " x " + std::to_string(h) +
           " pixels, more than a colour image can have (2^27)";
}

ColorImage read_png_color(const std::string& path) {
    File file(std::fopen(path.c_str(), "rb"));
    if (!file.f) throw IoError(detail::where(path, std::string("cannot open: ") + std::strerror(errno)));
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
        png_set_user_limits(png, detail::kMaxImageSide, detail::kMaxImageSide);
        png_init_io(png, file.f);
        png_read_info(png, info);
        const long w = long(png_get_image_width(png, info)), h = long(png_get_image_height(png, info));
        problem = size_problem(w, h);
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
    img.rgb.resize(std::size_t(img.width) * std::size_t(img.height));
    for (std::size_t i = 0; i < img.rgb.size(); ++i) {
        img.rgb[i] = {pixels[3 * i] / 255.0f, pixels[3 * i + 1] / 255.0f, pixels[3 * i + 2] / 255.0f};
    }
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
    File file(std::fopen(path.c_str(), "rb"));
    if (!file.f) throw IoError(detail::where(path, std::string("cannot open: ") + std::strerror(errno)));
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
        jpeg_stdio_src(&info, file.f);
        jpeg_read_header(&info, TRUE);
        problem = size_problem(long(info.image_width), long(info.image_height));
        if (problem.empty()) {
            info.out_color_space = JCS_RGB;
            jpeg_start_decompress(&info);
            const std::size_t w = info.output_width, h = info.output_height;
            pixels.resize(w * h * 3);
            while (info.output_scanline < info.output_height) {
                JSAMPROW row = pixels.data() + std::size_t(info.output_scanline) * w * 3;
                jpeg_read_scanlines(&info, &row, 1);
            }
            jpeg_finish_decompress(&info);
            img.width = int(w);
            img.height = int(h);
        }
    }
    jpeg_destroy_decompress(&info);
    if (!problem.empty()) throw FormatError(detail::where(path, problem));
    img.rgb.resize(std::size_t(img.width) * std::size_t(img.height));
    for (std::size_t i = 0; i < img.rgb.size(); ++i) {
        img.rgb[i] = {pixels[3 * i] / 255.0f, pixels[3 * i + 1] / 255.0f, pixels[3 * i + 2] / 255.0f};
    }
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
