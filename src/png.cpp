// The 8-bit RGB PNG encoder (see detail/png.h): one IDAT chunk, no filter, deflate level 6.
#include "detail/png.h"

#include <zlib.h>

#include "detail/io_common.h"
#include "vdbrecon/error.h"

namespace vdbrecon::detail {

namespace {

void put_u32(std::string& s, std::uint32_t v) {
    for (int sh = 24; sh >= 0; sh -= 8) s.push_back(char((v >> sh) & 0xff));
}

void png_chunk(std::string& out, const char* type, const std::string& data) {
    put_u32(out, std::uint32_t(data.size()));
    std::string body(type, 4);
    body += data;
    out += body;
    put_u32(out, std::uint32_t(crc32(0L, reinterpret_cast<const Bytef*>(body.data()), uInt(body.size()))));
}

}  // namespace

std::string encode_png_rgb8(int width, int height, const std::uint8_t* rgb,
                            const std::string& path) {
    const std::size_t row = std::size_t(width) * 3;
    std::string raw;
    raw.reserve(std::size_t(height) * (row + 1));
    for (int y = 0; y < height; ++y) {
        raw.push_back('\0');  // filter: none
        raw.append(reinterpret_cast<const char*>(rgb) + std::size_t(y) * row, row);
    }
    uLongf size = compressBound(uLong(raw.size()));
    std::string z(size, '\0');
    if (compress2(reinterpret_cast<Bytef*>(z.data()), &size,
                  reinterpret_cast<const Bytef*>(raw.data()), uLong(raw.size()), 6) != Z_OK) {
        throw IoError(where(path, "cannot compress the PNG data"));
    }
    z.resize(size);
    std::string out("\x89PNG\r\n\x1a\n", 8);
    std::string ihdr;
    put_u32(ihdr, std::uint32_t(width));
    put_u32(ihdr, std::uint32_t(height));
    ihdr += std::string("\x08\x02\x00\x00\x00", 5);  // 8 bits, RGB, deflate, no filter, no interlace
    png_chunk(out, "IHDR", ihdr);
    png_chunk(out, "IDAT", z);
    png_chunk(out, "IEND", "");
    return out;
}

void write_png_rgb8(const std::string& path, int width, int height, const std::uint8_t* rgb) {
    const std::string bytes = encode_png_rgb8(width, height, rgb, path);
    AtomicFile file(path);
    ByteWriter w(file.stream());
    w.put(bytes);
    w.flush();
    file.commit();
}

}  // namespace vdbrecon::detail
