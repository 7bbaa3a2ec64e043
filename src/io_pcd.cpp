// PCD (the Point Cloud Library's format, v0.5-0.7): ascii, binary and binary_compressed (LZF,
// fields stored one after another). Fields x y z, normal_x normal_y normal_z, rgb / rgba
// (packed in a float or uint32), any others skipped; WIDTH x HEIGHT (organized when HEIGHT >
// 1) and the VIEWPOINT (sensor position and orientation) are kept for fusion.
#include <array>
#include <cmath>
#include <optional>
#include <cstring>
#include <sstream>

#include "detail/io_common.h"
#include "detail/io_pcd.h"
#include "vdbrecon/error.h"

namespace vdbrecon::detail {

namespace {

struct Field {
    std::string name;
    int size = 4;
    char type = 'F';
    int count = 1;
    std::size_t offset = 0;  ///< within a binary record, bytes
    std::size_t element = 0;  ///< index of its first value within an ascii row
};

/// LZF decompression (the format of Marc Lehmann's liblzf, which PCL uses): a control byte
/// below 32 starts a run of ctrl + 1 literal bytes; otherwise a back-reference of length
/// (ctrl >> 5) + 2 (7 + the next byte + 2 for the longest) at distance ((ctrl & 31) << 8) + the
/// next byte + 1. False on any reference outside the data.
bool lzf_decompress(const unsigned char* in, std::size_t n, unsigned char* out, std::size_t m) {
    std::size_t i = 0, o = 0;
    while (i < n) {
        unsigned ctrl = in[i++];
        if (ctrl < 32) {
            const std::size_t len = ctrl + 1;
            if (i + len > n || o + len > m) return false;
            std::memcpy(out + o, in + i, len);
            i += len;
            o += len;
        } else {
            std::size_t len = ctrl >> 5;
            if (len == 7) {
                if (i >= n) return false;
                len += in[i++];
            }
            len += 2;
            if (i >= n) return false;
            const std::size_t back = ((ctrl & 31u) << 8) + in[i++] + 1;
            if (back > o || o + len > m) return false;
            for (std::size_t k = 0; k < len; ++k, ++o) out[o] = out[o - back];  // may overlap
        }
    }
    return o == m;
}

double read_value(const unsigned char* p, const Field& f) {
    switch (f.type) {
        case 'F':
            if (f.size == 4) { float v; std::memcpy(&v, p, 4); return v; }
            if (f.size == 8) { double v; std::memcpy(&v, p, 8); return v; }
            break;
        case 'U':
            if (f.size == 1) return p[0];
            if (f.size == 2) { std::uint16_t v; std::memcpy(&v, p, 2); return v; }
            if (f.size == 4) { std::uint32_t v; std::memcpy(&v, p, 4); return v; }
            break;
        case 'I':
            if (f.size == 1) return static_cast<std::int8_t>(p[0]);
            if (f.size == 2) { std::int16_t v; std::memcpy(&v, p, 2); return v; }
            if (f.size == 4) { std::int32_t v; std::memcpy(&v, p, 4); return v; }
            break;
    }
    return NAN;
}

/// The colour of a packed rgb/rgba value (float or uint32 bits: 0x00RRGGBB), 0..1.
std::array<float, 3> unpack_rgb(const unsigned char* p) {
    std::uint32_t bits;
    std::memcpy(&bits, p, 4);
    return {float((bits >> 16) & 255u) / 255.0f, float((bits >> 8) & 255u) / 255.0f,
            float(bits & 255u) / 255.0f};
}

/// A PCD header: its fields (with offsets), counts, DATA kind; `pos` is where the data starts.
struct Header {
    std::vector<Field> fields;
    std::size_t points = 0, width = 0, height = 1, record = 0, elements = 0, pos = 0;
    std::string data;
    std::optional<std::array<double, 7>> viewpoint;
};

Header read_header(const std::string& path, std::string_view content) {
    Header hd;
    std::vector<Field>& fields = hd.fields;
    std::size_t &points = hd.points, &pos = hd.pos, &width = hd.width, &height = hd.height;
    std::string& data = hd.data;
    auto fail = [&](const std::string& m) { return FormatError(where(path, m)); };
    // Header: one keyword per line until DATA.
    while (data.empty()) {
        const std::size_t eol = content.find('\n', pos);
        if (eol == std::string_view::npos) throw fail("truncated PCD header (no DATA line)");
        std::istringstream line{std::string(content.substr(pos, eol - pos))};
        pos = eol + 1;
        std::string key;
        if (!(line >> key) || key[0] == '#') continue;
        auto numbers = [&](auto& dst) {
            for (auto& d : dst) {
                if (!(line >> d)) throw fail("bad PCD " + key + " line");
            }
        };
        if (key == "VERSION") {
        } else if (key == "FIELDS") {
            std::string n;
            while (line >> n) fields.push_back(Field{n});
        } else if (key == "SIZE" || key == "TYPE" || key == "COUNT") {
            for (Field& f : fields) {
                std::string v;
                if (!(line >> v)) throw fail("PCD " + key + " has fewer entries than FIELDS");
                if (key == "TYPE") f.type = v[0];
                else if (key == "SIZE") f.size = std::atoi(v.c_str());
                else f.count = std::atoi(v.c_str());
            }
        } else if (key == "WIDTH") {
            if (!(line >> width)) throw fail("bad PCD WIDTH line");
        } else if (key == "HEIGHT") {
            if (!(line >> height)) throw fail("bad PCD HEIGHT line");
        } else if (key == "VIEWPOINT") {
            std::array<double, 7> v{};
            numbers(v);
            hd.viewpoint = v;
        } else if (key == "POINTS") {
            if (!(line >> points)) throw fail("bad PCD POINTS line");
        } else if (key == "DATA") {
            if (!(line >> data)) throw fail("bad PCD DATA line");
        } else {
            throw fail("unknown PCD header line '" + printable(key) + "'");
        }
    }
    if (fields.empty()) throw fail("PCD header without FIELDS");
    if (points == 0) points = width * height;
    if (width * height != points || points == 0 || points > (std::size_t(1) << 31)) {
        throw fail("PCD WIDTH x HEIGHT (" + std::to_string(width) + " x " + std::to_string(height) +
                   ") does not match POINTS " + std::to_string(points));
    }
    std::size_t& record = hd.record;
    std::size_t& elements = hd.elements;
    for (Field& f : fields) {
        const bool ok = f.count >= 1 && f.count <= 1024 &&
                        ((f.type == 'F' && (f.size == 4 || f.size == 8)) ||
                         ((f.type == 'U' || f.type == 'I') && (f.size == 1 || f.size == 2 || f.size == 4)));
        if (!ok) throw fail("PCD field '" + printable(f.name) + "' has an unsupported TYPE/SIZE/COUNT");
        f.offset = record;
        f.element = elements;
        record += std::size_t(f.size) * std::size_t(f.count);
        elements += std::size_t(f.count);
    }
    return hd;
}

}  // namespace

PcdData read_pcd(const std::string& path, std::string_view content) {
    PcdData out;
    const Header hd = read_header(path, content);
    const std::vector<Field>& fields = hd.fields;
    const std::size_t points = hd.points, record = hd.record, elements = hd.elements, pos = hd.pos;
    const std::string& data = hd.data;
    out.viewpoint = hd.viewpoint;
    auto fail = [&](const std::string& m) { return FormatError(where(path, m)); };
    auto find = [&](const char* n) -> const Field* {
        for (const Field& f : fields) {
            if (f.name == n) return &f;
        }
        return nullptr;
    };
    const Field *fx = find("x"), *fy = find("y"), *fz = find("z");
    if (!fx || !fy || !fz) throw fail("PCD without x y z fields");
    const Field *nx = find("normal_x"), *ny = find("normal_y"), *nz = find("normal_z");
    const Field* rgb = find("rgb") ? find("rgb") : find("rgba");
    const bool normals = nx && ny && nz, colors = rgb && rgb->size == 4;
    out.width = hd.width;
    out.height = hd.height;
    // The header's point count against what the data can hold, before anything is sized by it:
    // binary records whole; LZF expands a byte into at most ~88 (a 3-byte reference copies 264);
    // an ASCII value takes two bytes at least (a digit and a separator).
    const std::size_t available = content.size() - pos;
    if (data != "binary" && data != "binary_compressed" && data != "ascii") {
        throw fail("unknown PCD DATA '" + printable(data) + "' (ascii, binary, binary_compressed)");
    }
    if (data == "binary" && available < points * record) throw fail("truncated PCD binary data");
    if (data == "binary_compressed" && points * record / 100 > available) {
        throw fail("PCD compressed data: " + std::to_string(points) +
                   " points cannot come from the file's " + std::to_string(available) + " bytes");
    }
    if (data == "ascii" && points * elements > available / 2 + 1) {
        throw fail("truncated PCD ascii data: " + std::to_string(points) + " points of " +
                   std::to_string(elements) + " values need more than the file's " +
                   std::to_string(available) + " bytes");
    }
    out.raw.xyz.resize(points * 3);
    if (normals) out.raw.normals.resize(points);
    if (colors) out.raw.colors.resize(points);

    // Each point's record bytes: a pointer for binary data, a field-major gather for compressed.
    std::vector<unsigned char> unpacked;
    const auto* bytes = reinterpret_cast<const unsigned char*>(content.data()) + pos;
    auto value = [&](std::size_t i, const Field& f) -> const unsigned char* {
        if (data == "binary") return bytes + i * record + f.offset;
        // binary_compressed: every field's values for all points, one field after another.
        return unpacked.data() + f.offset * points + i * std::size_t(f.size) * std::size_t(f.count);
    };
    if (data == "binary_compressed") {
        std::uint32_t packed = 0, size = 0;
        if (available < 8) throw fail("truncated PCD compressed data");
        std::memcpy(&packed, bytes, 4);
        std::memcpy(&size, bytes + 4, 4);
        if (size != points * record || packed > available - 8) {
            throw fail("PCD compressed sizes do not match the header or the file");
        }
        unpacked.resize(size);
        if (!lzf_decompress(bytes + 8, packed, unpacked.data(), size)) {
            throw fail("corrupt PCD compressed data (LZF)");
        }
    } else if (data == "ascii") {
        std::istringstream text{std::string(content.substr(pos))};
        std::vector<double> row(elements);
        for (std::size_t i = 0; i < points; ++i) {
            std::size_t e = 0;
            for (const Field& f : fields) {
                for (int c = 0; c < f.count; ++c, ++e) {
                    std::string tok;
                    if (!(text >> tok)) throw fail("truncated PCD ascii data at point " + std::to_string(i));
                    double v = NAN;
                    if (tok != "nan" && tok != "NaN" && !parse_double(tok.data(), tok.data() + tok.size(), v)) {
                        throw fail("bad PCD ascii value '" + printable(tok) + "'");
                    }
                    row[e] = v;
                }
            }
            auto at = [&](const Field* f) { return row[f->element]; };
            for (int a = 0; a < 3; ++a) out.raw.xyz[3 * i + std::size_t(a)] = at(a == 0 ? fx : a == 1 ? fy : fz);
            if (normals) {
                for (int a = 0; a < 3; ++a)
                    out.raw.normals[i][std::size_t(a)] = float(at(a == 0 ? nx : a == 1 ? ny : nz));
            }
            if (colors) {
                const float f = float(at(rgb));
                const auto c = unpack_rgb(reinterpret_cast<const unsigned char*>(&f));
                out.raw.colors[i] = c;
            }
        }
        return out;
    }
    for (std::size_t i = 0; i < points; ++i) {
        out.raw.xyz[3 * i] = read_value(value(i, *fx), *fx);
        out.raw.xyz[3 * i + 1] = read_value(value(i, *fy), *fy);
        out.raw.xyz[3 * i + 2] = read_value(value(i, *fz), *fz);
        if (normals) {
            out.raw.normals[i] = {float(read_value(value(i, *nx), *nx)),
                                  float(read_value(value(i, *ny), *ny)),
                                  float(read_value(value(i, *nz), *nz))};
        }
        if (colors) {
            out.raw.colors[i] = unpack_rgb(value(i, *rgb));
        }
    }
    return out;
}

}  // namespace vdbrecon::detail
