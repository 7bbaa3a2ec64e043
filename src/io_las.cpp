// ASPRS LAS 1.0-1.4 point clouds (point data record formats 0-10), the format of airborne and
// terrestrial LiDAR. Coordinates are X * scale + offset in double (then the reader's local
// frame); RGB (formats 2, 3, 5, 7, 8, 10) becomes colours; classification, intensity and
// returns go to ReadResult::las; ReadOptions::classes keeps the
// points of some classes. LAZ (compressed LAS) is refused with a hint. Layout per the LAS 1.4
// specification (R15): public header block, then point records of `record length` bytes at
// `offset to point data`.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "detail/io_common.h"
#include "vdbrecon/error.h"
#include "vdbrecon/io.h"

namespace vdbrecon::detail {
namespace {

template <typename T>
T get(std::string_view b, std::size_t at) {
    T v;
    std::memcpy(&v, b.data() + at, sizeof(T));
    return v;  // LAS is little-endian, as every platform vdbrecon builds on
}

/// Size of the fields a point format defines (its record may be longer: extra bytes).
std::size_t core_size(int format) {
    static const std::size_t sizes[11] = {20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67};
    return sizes[format];
}

/// Byte offset of the RGB triple in a record of the format, or 0 when it has none.
std::size_t rgb_offset(int format) {
    switch (format) {
        case 2: return 20;
        case 3: case 5: return 28;
        case 7: case 8: case 10: return 30;
        default: return 0;
    }
}

/// Whether the file is LAZ (compressed LAS): by its header's compression bit, or its extension.
bool is_laz(const std::string& path, std::string_view content) {
    if (content.size() >= 105 && content.compare(0, 4, "LASF") == 0) {
        return (std::uint8_t(content[104]) & 0xC0) != 0;  // LASzip sets bit 7 (or 6)
    }
    return file_extension(path) == "laz";
}

}  // namespace

RawPoints read_las_raw(const std::string& path, std::string_view b, const std::vector<int>& classes,
                       const Consumed& consumed, const RowSink& sink) {
    if (is_laz(path, b)) {
        throw FormatError(where(path, "LAZ (compressed LAS) is not read; decompress it first, e.g. "
                                      "`laszip -i in.laz -o out.las` or `pdal translate in.laz "
                                      "out.las`"));
    }
    if (b.size() < 227 || b.compare(0, 4, "LASF") != 0) {
        throw FormatError(where(path, "not a LAS file (no 'LASF' signature or a header shorter "
                                      "than 227 bytes)"));
    }
    const int major = std::uint8_t(b[24]), minor = std::uint8_t(b[25]);
    if (major != 1 || minor > 4) {
        throw FormatError(where(path, "LAS version " + std::to_string(major) + "." +
                                          std::to_string(minor) + " is not supported (1.0-1.4)"));
    }
    const std::uint16_t header_size = get<std::uint16_t>(b, 94);
    const std::uint32_t data_offset = get<std::uint32_t>(b, 96);
    const int format = std::uint8_t(b[104]) & 0x3F;
    const std::uint16_t record = get<std::uint16_t>(b, 105);
    std::uint64_t count = get<std::uint32_t>(b, 107);
    if (minor >= 4 && header_size >= 375 && b.size() >= 255) {
        const std::uint64_t count14 = get<std::uint64_t>(b, 247);
        if (count == 0 || count14 > count) count = count14;
    }
    if (format > 10) {
        throw FormatError(where(path, "point data record format " + std::to_string(format) +
                                          " is not defined (0-10)"));
    }
    if (record < core_size(format)) {
        throw FormatError(where(path, "point record length " + std::to_string(record) +
                                          " is shorter than format " + std::to_string(format) +
                                          " needs (" + std::to_string(core_size(format)) + ")"));
    }
    if (data_offset < header_size || data_offset > b.size() ||
        count > (b.size() - data_offset) / record) {
        throw FormatError(where(path, "truncated: the header announces " + std::to_string(count) +
                                          " points of " + std::to_string(record) + " bytes at offset " +
                                          std::to_string(data_offset) + ", the file has " +
                                          std::to_string(b.size()) + " bytes"));
    }
    double scale[3], offset[3];
    for (int a = 0; a < 3; ++a) {
        scale[a] = get<double>(b, 131 + 8 * std::size_t(a));
        offset[a] = get<double>(b, 155 + 8 * std::size_t(a));
        if (!(std::isfinite(scale[a]) && scale[a] != 0.0 && std::isfinite(offset[a]))) {
            throw FormatError(where(path, "invalid scale or offset in the header"));
        }
    }
    bool keep_class[256] = {};
    for (int c : classes) {
        if (c >= 0 && c < 256) keep_class[c] = true;
    }
    const std::size_t class_at = format >= 6 ? 16 : 15;
    const std::uint8_t class_mask = format >= 6 ? 0xFF : 0x1F;
    const std::size_t rgb = rgb_offset(format);
    // Returns: bits 0-2 and 3-5 of byte 14 in formats 0-5, its two nibbles in 6-10.
    const int return_bits = format >= 6 ? 4 : 3;
    const std::uint8_t return_mask = std::uint8_t((1 << return_bits) - 1);
    const auto kept = [&](std::size_t at) {
        return classes.empty() || keep_class[std::uint8_t(b[at + class_at]) & class_mask];
    };
    // 16-bit colours, unless every value fits in 8 bits (some writers store 0-255).
    std::uint16_t max_rgb = 0;
    for (std::uint64_t i = 0; i < count && rgb; ++i) {
        const std::size_t at = data_offset + std::size_t(i) * record;
        if (!kept(at)) continue;
        for (std::size_t c = 0; c < 3; ++c) {
            max_rgb = std::max(max_rgb, get<std::uint16_t>(b, at + rgb + 2 * c));
        }
    }
    const float full = max_rgb > 255 ? 65535.0f : 255.0f;
    RawPoints raw;
    const std::size_t hold = std::size_t(sink ? std::min<std::uint64_t>(count, kStreamRows) : count);
    raw.xyz.reserve(3 * hold);
    if (rgb) raw.colors.reserve(hold);
    LasAttributes& las = raw.las;
    las.classification.reserve(hold);
    las.intensity.reserve(hold);
    las.return_number.reserve(hold);
    las.number_of_returns.reserve(hold);
    std::size_t handed = 0;
    for (std::uint64_t i = 0; i < count; ++i) {
        const std::size_t at = data_offset + std::size_t(i) * record;
        if (!kept(at)) continue;
        const std::uint8_t returns = std::uint8_t(b[at + 14]);
        las.classification.push_back(std::uint8_t(b[at + class_at]) & class_mask);
        las.intensity.push_back(get<std::uint16_t>(b, at + 12));
        las.return_number.push_back(returns & return_mask);
        las.number_of_returns.push_back(std::uint8_t(returns >> return_bits) & return_mask);
        for (int a = 0; a < 3; ++a) {
            raw.xyz.push_back(double(get<std::int32_t>(b, at + 4 * std::size_t(a))) * scale[a] +
                              offset[a]);
        }
        if (rgb) {
            Vec3f c;
            for (int k = 0; k < 3; ++k) {
                c[std::size_t(k)] =
                    float(get<std::uint16_t>(b, at + rgb + 2 * std::size_t(k))) / full;
            }
            raw.colors.push_back(c);
        }
        if (raw.rows() % kStreamRows == 0) {
            hand_rows(raw, sink, handed, false);
            if (consumed) consumed(b.data() + at + record);
        }
    }
    hand_rows(raw, sink, handed, true);
    return raw;
}

}  // namespace vdbrecon::detail
