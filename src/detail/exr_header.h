// An OpenEXR file's headers walked before OpenEXR reads them (io_depth.cpp), so that what they
// claim is checked against the file's size first. OpenEXR 3.1's C++ reader allocates what a
// header says before reading what follows it: an attribute's size, a preview image's pixels,
// the offset table of every chunk the data window implies, and a decoding buffer of a chunk's
// lines across every channel. A few hostile bytes could claim gigabytes of any of them.
//
// The layout (OpenEXR's "OpenEXR File Layout"): the magic number 20000630, a version word
// (2, flags: 0x200 tiled, 0x400 long names, 0x800 deep, 0x1000 multi-part), then per part a
// header of attributes (name\0 type\0 int32 size, then size bytes) ended by an empty name
// (multi-part files end their headers with one more), then the parts' offset tables (8 bytes a
// chunk), then the chunks. All little-endian.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "detail/io_common.h"

namespace vdbrecon::detail {

/// Decoded bytes any EXR file may claim, however small: 16 MB (a 2k x 2k float image).
constexpr double kExrFreeBytes = 16.0 * (1 << 20);
/// Beyond that, decoded bytes per byte of the file: deflate's limit (ZIP, ZIPS, PXR24's zlib;
/// image_read.h), which RLE, B44 and uncompressed data stay far below.
constexpr double kExrMaxRatio = 1032.0;

/// What the depth reader needs of an EXR file's first part, or why OpenEXR must not read it.
struct ExrLayout {
    long width = 0, height = 0;  ///< the first part's data window
    std::string problem;         ///< "" when the headers fit the file
};

namespace exr_internal {

/// A part's header, as far as the checks go.
struct Part {
    std::int32_t window[4] = {0, 0, -1, -1};  ///< dataWindow: x min, y min, x max, y max
    bool has_window = false;
    int compression = -1;
    double bytes_per_pixel = 0.0;    ///< all channels (subsampling ignored: an upper bound)
    std::uint32_t tile[2] = {0, 0};  ///< tile size, 0 x 0 for scan lines
};

/// Little-endian reading of `bytes` from `at`; a read past the end sets `failed`.
struct Reader {
    std::string_view bytes;
    std::size_t at = 0;
    bool failed = false;

    bool has(std::size_t n) const { return !failed && bytes.size() - at >= n; }
    std::uint32_t u32() {
        if (!has(4)) return failed = true, 0u;
        std::uint32_t v = 0;
        for (int i = 3; i >= 0; --i) v = v << 8 | std::uint8_t(bytes[at + std::size_t(i)]);
        at += 4;
        return v;
    }
    std::int32_t i32() { return std::int32_t(u32()); }
    /// A NUL-terminated string of at most `max` characters.
    std::string text(std::size_t max) {
        const std::size_t end = failed ? std::string_view::npos : bytes.find('\0', at);
        if (end == std::string_view::npos || end - at > max) return failed = true, std::string();
        std::string s(bytes.substr(at, end - at));
        at = end + 1;
        return s;
    }
};

/// Lines a chunk of a scan-line part holds, by compression (0 when unknown).
inline int lines_per_chunk(int compression) {
    static const int lines[10] = {1, 1, 1, 16, 32, 16, 32, 32, 32, 256};
    return compression >= 0 && compression < 10 ? lines[compression] : 0;
}

/// The size of a value of a type OpenEXR reads whatever size its attribute gives (-1 for the
/// types of any size): an attribute of another size would put it out of step with the file.
inline int fixed_size(const std::string& type) {
    static const std::pair<const char*, int> sizes[] = {
        {"box2i", 16},      {"box2f", 16},   {"chromaticities", 32},
        {"compression", 1}, {"double", 8},   {"envmap", 1},
        {"float", 4},       {"int", 4},      {"keycode", 28},
        {"lineOrder", 1},   {"m33f", 36},    {"m33d", 72},
        {"m44f", 64},       {"m44d", 128},   {"rational", 8},
        {"tiledesc", 9},    {"timecode", 8}, {"v2i", 8},
        {"v2f", 8},         {"v2d", 16},     {"v3i", 12},
        {"v3f", 12},        {"v3d", 24},     {"deepImageState", 1}};
    for (const auto& [name, size] : sizes) {
        if (type == name) return size;
    }
    return -1;
}

/// The channel list's bytes per pixel; false when it is malformed or does not end where its
/// attribute does (OpenEXR reads it to its end marker).
inline bool read_channels(std::string_view value, Part& part) {
    Reader r{value};
    while (r.has(1) && value[r.at] != '\0') {
        r.text(255);
        const std::int32_t type = r.i32();
        r.u32();  // pLinear, reserved
        const std::int32_t xs = r.i32(), ys = r.i32();
        if (r.failed || type < 0 || type > 2 || xs < 1 || ys < 1) return false;
        part.bytes_per_pixel += type == 1 ? 2.0 : 4.0;
    }
    return r.has(1) && r.at + 1 == value.size();
}

/// Why an attribute's value cannot be what its type says, or "" (the types OpenEXR allocates
/// for by a count inside the value, and those the checks need).
inline std::string read_value(const std::string& name, const std::string& type,
                              std::string_view value, Part& part) {
    Reader r{value};
    const int fixed = fixed_size(type);
    if (fixed >= 0 && std::size_t(fixed) != value.size()) {
        return std::to_string(value.size()) + " bytes, not the " + std::to_string(fixed) +
               " of a " + type;
    }
    if (type == "preview") {
        const double w = r.u32(), h = r.u32();
        if (r.failed || 8.0 + 4.0 * w * h != double(value.size())) {
            return "a preview image of another size";
        }
    } else if (type == "stringvector") {
        while (!r.failed && r.at < value.size()) {
            const std::int32_t n = r.i32();
            if (r.failed || n < 0 || !r.has(std::size_t(n))) {
                return "a string longer than its attribute";
            }
            r.at += std::size_t(n);
        }
    } else if (name == "dataWindow" && type == "box2i") {
        for (std::int32_t& v : part.window) v = r.i32();
        part.has_window = !r.failed;
    } else if (name == "compression" && type == "compression") {
        part.compression = std::uint8_t(value[0]);
    } else if (type == "chlist") {
        Part ignored;
        if (!read_channels(value, name == "channels" ? part : ignored)) {
            return "a malformed channel list";
        }
    } else if (name == "tiles" && type == "tiledesc") {
        part.tile[0] = r.u32();
        part.tile[1] = r.u32();
        if (r.failed || part.tile[0] == 0 || part.tile[1] == 0) {
            return "a malformed tile description";
        }
    }
    return "";
}

/// Reads one part's header into `part`; returns why it is malformed, or "".
inline std::string read_header(Reader& r, std::size_t max_name, Part& part) {
    while (r.has(1) && r.bytes[r.at] != '\0') {
        const std::string name = r.text(max_name), type = r.text(max_name);
        const std::int32_t size = r.i32();
        if (r.failed) return "a header cut short";
        if (size < 0 || !r.has(std::size_t(size))) {
            return "the attribute '" + printable(name) + "' claims " + std::to_string(size) +
                   " bytes, past the end of the file (" + std::to_string(r.bytes.size()) +
                   " bytes)";
        }
        const std::string problem =
            read_value(name, type, r.bytes.substr(r.at, std::size_t(size)), part);
        if (!problem.empty()) return "the attribute '" + printable(name) + "' holds " + problem;
        r.at += std::size_t(size);
    }
    if (!r.has(1)) return "a header cut short";
    ++r.at;  // the empty name that ends it
    if (!part.has_window || part.compression < 0 || part.bytes_per_pixel == 0.0) {
        return "a header without dataWindow, compression or channels";
    }
    return "";
}

/// Why the file cannot hold what `part` claims, or "": its chunks' offsets (`chunks` adds
/// them up over the parts) and its decoded bytes.
inline std::string part_problem(const Part& part, double file_bytes, double& chunks) {
    const double w = double(part.window[2]) - part.window[0] + 1.0;
    const double h = double(part.window[3]) - part.window[1] + 1.0;
    if (!(w >= 1.0 && h >= 1.0)) return "an empty data window";
    const bool tiled = part.tile[0] > 0;
    const int lines = lines_per_chunk(part.compression);
    if (lines == 0) return "an unknown compression (" + std::to_string(part.compression) + ")";
    const double tx = tiled ? double(part.tile[0]) : w, ty = tiled ? double(part.tile[1]) : lines;
    chunks += tiled ? std::ceil(w / tx) * std::ceil(h / ty) : std::ceil(h / ty);
    // OpenEXR decodes a chunk of tx x ty pixels at once (tiles: into a row of tiles, w x ty),
    // the whole image a chunk at a time.
    const double largest = part.bytes_per_pixel * std::max({tx * ty, w * ty, w * h});
    if (largest > std::max(kExrFreeBytes, kExrMaxRatio * file_bytes)) {
        const std::string tiles =
            tiled ? " in tiles of " + std::to_string(long(tx)) + " x " + std::to_string(long(ty))
                  : "";
        return "the header claims " + std::to_string(long(w)) + " x " + std::to_string(long(h)) +
               " pixels of " + std::to_string(long(part.bytes_per_pixel)) + " bytes" + tiles +
               ", more than the file's " + std::to_string(long(file_bytes)) +
               " bytes can hold (truncated, or a corrupt header)";
    }
    return "";
}

}  // namespace exr_internal

/// Walks the headers of an EXR file's bytes: every attribute within the file, the values
/// OpenEXR sizes buffers by consistent, the offset tables within the file, and no part claiming
/// more decoded bytes than kExrFreeBytes or kExrMaxRatio times the file's size.
inline ExrLayout exr_layout(std::string_view file) {
    using namespace exr_internal;
    ExrLayout out;
    Reader r{file};
    const std::uint32_t magic = r.u32(), version = r.u32();
    if (r.failed || magic != 20000630u || (version & 0xFF) != 2) {
        out.problem = "not an EXR file (no magic number and version 2)";
        return out;
    }
    const bool multi = version & 0x1000;
    const std::size_t max_name = 255;  // as OpenEXR reads names, long-names flag or not
    std::vector<Part> parts;
    do {
        parts.emplace_back();
        out.problem = read_header(r, max_name, parts.back());
        if (!out.problem.empty()) return out;
    } while (multi && r.has(1) && file[r.at] != '\0');
    if (multi && !r.has(1)) {
        out.problem = "a header cut short";
        return out;
    }
    if (multi) ++r.at;  // the empty header that ends the list
    double chunks = 0.0;
    for (const Part& p : parts) {
        out.problem = part_problem(p, double(file.size()), chunks);
        if (!out.problem.empty()) return out;
    }
    if (8.0 * chunks > double(file.size()) - double(r.at)) {
        out.problem = "the offset table of " + std::to_string(long(chunks)) +
                      " chunks does not fit in the file (" + std::to_string(file.size()) +
                      " bytes): truncated, or a corrupt header";
        return out;
    }
    out.width = long(parts[0].window[2]) - parts[0].window[0] + 1;
    out.height = long(parts[0].window[3]) - parts[0].window[1] + 1;
    return out;
}

}  // namespace vdbrecon::detail
