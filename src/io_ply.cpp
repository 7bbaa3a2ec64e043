// PLY reading and writing (G. Turk, "The PLY Polygon File Format", 1994).
//
// Reader: ascii and binary little/big endian; every scalar type and its alias (char/int8,
// uchar/uint8, short/int16, ushort/uint16, int/int32, uint/uint32, float/float32,
// double/float64); vertex properties in any order; list properties and other elements walked
// and skipped. The header's counts are checked against the file size before anything is
// allocated, so a hostile header cannot make us reserve terabytes.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <limits>

#include "detail/io_common.h"
#include "vdbrecon/error.h"

// The build's version string, not version() from pipeline.h: the readers and writers must build
// without OpenVDB (fuzz/ compiles only the io sources).
#ifndef VDBRECON_VERSION
#define VDBRECON_VERSION "0.0.0"
#endif

namespace vdbrecon::detail {
namespace {

enum class PlyType : std::uint8_t { int8, uint8, int16, uint16, int32, uint32, float32, float64 };
enum class Encoding { ascii, binary_le, binary_be };

std::size_t type_size(PlyType t) {
    switch (t) {
        case PlyType::int8:
        case PlyType::uint8: return 1;
        case PlyType::int16:
        case PlyType::uint16: return 2;
        case PlyType::int32:
        case PlyType::uint32:
        case PlyType::float32: return 4;
        case PlyType::float64: return 8;
    }
    return 0;
}

bool parse_type(const std::string& s, PlyType& t) {
    static const struct {
        const char* name;
        PlyType type;
    } table[] = {{"char", PlyType::int8},      {"int8", PlyType::int8},
                 {"uchar", PlyType::uint8},    {"uint8", PlyType::uint8},
                 {"short", PlyType::int16},    {"int16", PlyType::int16},
                 {"ushort", PlyType::uint16},  {"uint16", PlyType::uint16},
                 {"int", PlyType::int32},      {"int32", PlyType::int32},
                 {"uint", PlyType::uint32},    {"uint32", PlyType::uint32},
                 {"float", PlyType::float32},  {"float32", PlyType::float32},
                 {"double", PlyType::float64}, {"float64", PlyType::float64}};
    for (const auto& e : table) {
        if (s == e.name) {
            t = e.type;
            return true;
        }
    }
    return false;
}

bool is_integer(PlyType t) { return t != PlyType::float32 && t != PlyType::float64; }

/// Full-scale value of an integer colour channel (uchar 255, ushort 65535, ...).
double colour_scale(PlyType t) {
    switch (t) {
        case PlyType::int8: return 127.0;
        case PlyType::uint8: return 255.0;
        case PlyType::int16: return 32767.0;
        case PlyType::uint16: return 65535.0;
        case PlyType::int32:
        case PlyType::uint32: return 255.0;  // rare; assume 8-bit values stored wide
        default: return 1.0;
    }
}

struct Property {
    std::string name;
    PlyType type = PlyType::float32;
    bool list = false;
    PlyType count_type = PlyType::uint8;
};

struct Element {
    std::string name;
    std::uint64_t count = 0;
    std::vector<Property> props;
    std::size_t line = 0;  // header line, for messages
};

struct Header {
    Encoding encoding = Encoding::ascii;
    std::vector<Element> elements;
    std::size_t body = 0;  // byte offset of the body
};

std::vector<std::string> split_words(const std::string& line) {
    std::vector<std::string> w;
    std::size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
        std::size_t j = i;
        while (j < line.size() && line[j] != ' ' && line[j] != '\t') ++j;
        if (j > i) w.push_back(line.substr(i, j - i));
        i = j;
    }
    return w;
}

Header parse_header(const std::string& path, std::string_view content) {
    Header h;
    std::size_t pos = 0, lineno = 0;
    bool have_format = false, ended = false;
    while (pos < content.size()) {
        std::size_t eol = content.find('\n', pos);
        if (eol == std::string::npos) break;
        std::string line(content.substr(pos, eol - pos));
        pos = eol + 1;
        ++lineno;
        if (!line.empty() && line.back() == '\r') line.pop_back();
        if (lineno == 1) {
            if (line != "ply") throw FormatError(where(path, "not a PLY file (no 'ply' magic)"));
            continue;
        }
        const std::vector<std::string> w = split_words(line);
        const std::string at = "header line " + std::to_string(lineno) + ": ";
        if (w.empty() || w[0] == "comment" || w[0] == "obj_info") continue;
        if (w[0] == "end_header") {
            ended = true;
            break;
        }
        if (w[0] == "format") {
            if (w.size() != 3) throw FormatError(where(path, at + "malformed format line"));
            if (w[1] == "ascii") {
                h.encoding = Encoding::ascii;
            } else if (w[1] == "binary_little_endian") {
                h.encoding = Encoding::binary_le;
            } else if (w[1] == "binary_big_endian") {
                h.encoding = Encoding::binary_be;
            } else {
                throw FormatError(where(path, at + "unknown format '" + printable(w[1]) + "'"));
            }
            if (w[2] != "1.0" && w[2] != "1") {
                throw FormatError(
                    where(path, at + "unsupported PLY version '" + printable(w[2]) + "'"));
            }
            have_format = true;
        } else if (w[0] == "element") {
            if (w.size() != 3) throw FormatError(where(path, at + "malformed element line"));
            Element e;
            e.name = w[1];
            e.line = lineno;
            const char* b = w[2].data();
            const auto r = std::from_chars(b, b + w[2].size(), e.count);
            if (r.ec != std::errc() || r.ptr != b + w[2].size()) {
                throw FormatError(where(path, at + "bad element count '" + printable(w[2]) + "'"));
            }
            h.elements.push_back(std::move(e));
        } else if (w[0] == "property") {
            if (h.elements.empty()) {
                throw FormatError(where(path, at + "property before any element"));
            }
            Property p;
            if (w.size() == 5 && w[1] == "list") {
                p.list = true;
                if (!parse_type(w[2], p.count_type) || !parse_type(w[3], p.type)) {
                    throw FormatError(where(path, at + "unknown list type"));
                }
                if (!is_integer(p.count_type)) {
                    throw FormatError(where(path, at + "list count type must be an integer"));
                }
                p.name = w[4];
            } else if (w.size() == 3) {
                if (!parse_type(w[1], p.type)) {
                    throw FormatError(
                        where(path, at + "unknown property type '" + printable(w[1]) + "'"));
                }
                p.name = w[2];
            } else {
                throw FormatError(where(path, at + "malformed property line"));
            }
            h.elements.back().props.push_back(std::move(p));
        } else {
            throw FormatError(where(path, at + "unknown header keyword '" + printable(w[0]) + "'"));
        }
    }
    if (!ended) throw FormatError(where(path, "header has no end_header line (truncated?)"));
    if (!have_format) throw FormatError(where(path, "header has no format line"));
    h.body = pos;
    return h;
}

/// The value of type T at b, in the file's byte order (the reader's twin of put_binary below).
template <typename T>
T get_binary(const unsigned char* b, bool big_endian) {
    unsigned char bytes[sizeof(T)];
    std::memcpy(bytes, b, sizeof(T));
    if (big_endian) std::reverse(bytes, bytes + sizeof(T));
    T v;
    std::memcpy(&v, bytes, sizeof(T));
    return v;
}

/// The binary value of type t at b as a double. Each type's bytes are copied with their fixed
/// size (a copy of a size known only at run time was a call per value: most of a binary row's
/// parse).
double binary_value(const unsigned char* b, PlyType t, bool big_endian) {
    switch (t) {
        case PlyType::int8:
            return double(std::int8_t(b[0]));
        case PlyType::uint8:
            return double(b[0]);
        case PlyType::int16:
            return double(get_binary<std::int16_t>(b, big_endian));
        case PlyType::uint16:
            return double(get_binary<std::uint16_t>(b, big_endian));
        case PlyType::int32:
            return double(get_binary<std::int32_t>(b, big_endian));
        case PlyType::uint32:
            return double(get_binary<std::uint32_t>(b, big_endian));
        case PlyType::float32:
            return double(get_binary<float>(b, big_endian));
        case PlyType::float64:
            return get_binary<double>(b, big_endian);
    }
    return 0.0;
}

// Reads one scalar of type t; returns false at end of data.
class Cursor {
  public:
    Cursor(std::string_view content, std::size_t offset, Encoding enc)
        : p_(reinterpret_cast<const unsigned char*>(content.data()) + offset),
          end_(reinterpret_cast<const unsigned char*>(content.data()) + content.size()),
          enc_(enc) {}

    std::size_t remaining() const { return std::size_t(end_ - p_); }
    const char* here() const { return reinterpret_cast<const char*>(p_); }

    // Status of the last failed read.
    enum class Fail { none, eof, not_a_number };
    Fail fail = Fail::none;
    std::string bad_token;

    bool read(PlyType t, double& v) {
        if (enc_ == Encoding::ascii) return read_ascii(v);
        const std::size_t n = type_size(t);
        if (remaining() < n) {
            fail = Fail::eof;
            return false;
        }
        v = binary_value(p_, t, enc_ == Encoding::binary_be);
        p_ += n;
        return true;
    }

    // Skips n binary bytes; false at end of data.
    bool skip(std::size_t n) {
        if (remaining() < n) {
            fail = Fail::eof;
            return false;
        }
        p_ += n;
        return true;
    }

  private:
    bool read_ascii(double& v) {
        while (p_ < end_ && (*p_ == ' ' || *p_ == '\t' || *p_ == '\n' || *p_ == '\r')) ++p_;
        if (p_ == end_) {
            fail = Fail::eof;
            return false;
        }
        const unsigned char* s = p_;
        while (p_ < end_ && !(*p_ == ' ' || *p_ == '\t' || *p_ == '\n' || *p_ == '\r')) ++p_;
        const char* b = reinterpret_cast<const char*>(s);
        const char* e = reinterpret_cast<const char*>(p_);
        if (!parse_double(b, e, v)) {
            fail = Fail::not_a_number;
            bad_token = printable(std::string_view(b, std::size_t(e - b)));
            return false;
        }
        return true;
    }

    const unsigned char* p_;
    const unsigned char* end_;
    Encoding enc_;
};

// What a vertex property feeds.
enum class Role : std::uint8_t {
    ignore, x, y, z, nx, ny, nz, red, green, blue, scale, confidence, scan
};

Role role_of(const std::string& name) {
    static const struct {
        const char* name;
        Role role;
    } table[] = {{"x", Role::x},
                 {"y", Role::y},
                 {"z", Role::z},
                 {"nx", Role::nx},
                 {"ny", Role::ny},
                 {"nz", Role::nz},
                 {"normal_x", Role::nx},
                 {"normal_y", Role::ny},
                 {"normal_z", Role::nz},
                 {"red", Role::red},
                 {"green", Role::green},
                 {"blue", Role::blue},
                 {"diffuse_red", Role::red},
                 {"diffuse_green", Role::green},
                 {"diffuse_blue", Role::blue},
                 {"r", Role::red},
                 {"g", Role::green},
                 {"b", Role::blue},
                 {"value", Role::scale},  // MVE / FSSR writes the sample scale as "value"
                 {"scale", Role::scale},
                 {"confidence", Role::confidence},
                 {"scan", Role::scan},
                 {"scan_id", Role::scan},
                 {"scan_index", Role::scan}};
    for (const auto& e : table) {
        if (name == e.name) return e.role;
    }
    return Role::ignore;
}

/// "vertex 12: ", the start of a message about one row of an element.
std::string at_row(const Element& e, std::uint64_t row) {
    return printable(e.name) + " " + std::to_string(row) + ": ";
}

[[noreturn]] void fail_at(const std::string& path, const Element& e, std::uint64_t row,
                          const Cursor& c, Encoding enc) {
    std::string what;
    if (c.fail == Cursor::Fail::not_a_number) {
        what = "'" + c.bad_token + "' is not a number";
    } else if (enc == Encoding::ascii) {
        what = "unexpected end of file";
    } else {
        what = "truncated binary data";
    }
    throw FormatError(where(path, at_row(e, row) + what));
}

// Smallest number of bytes (binary) or tokens (ascii) one record of `e` can occupy.
std::size_t min_record_size(const Element& e, Encoding enc) {
    std::size_t n = 0;
    for (const Property& p : e.props) {
        if (enc == Encoding::ascii) {
            n += 1;  // at least a digit (a bound against absurd counts; parsing names the row)
        } else {
            n += p.list ? type_size(p.count_type) : type_size(p.type);
        }
    }
    return n;
}

bool fixed_size(const Element& e) {
    return std::none_of(e.props.begin(), e.props.end(), [](const Property& p) { return p.list; });
}

// Reads the list length; validates it against the remaining data.
std::uint64_t read_list_count(const std::string& path, const Element& e, std::uint64_t row,
                              const Property& p, Cursor& c, Encoding enc) {
    double v = 0.0;
    if (!c.read(p.count_type, v)) fail_at(path, e, row, c, enc);
    if (!(v >= 0.0) || v != std::floor(v)) {
        throw FormatError(where(path, at_row(e, row) + "list '" + printable(p.name) +
                                          "' has invalid length " + format_number(v)));
    }
    const std::size_t per_item = enc == Encoding::ascii ? 1 : type_size(p.type);
    if (v * double(per_item) > double(c.remaining())) {
        throw FormatError(where(path, at_row(e, row) + "list '" + printable(p.name) +
                                          "' of length " + format_number(v) +
                                          " runs past the end of the file"));
    }
    return std::uint64_t(v);
}

void skip_element(const std::string& path, const Element& e, Cursor& c, Encoding enc) {
    if (e.props.empty()) return;  // rows without properties take no bytes, however many
    if (enc != Encoding::ascii && fixed_size(e)) {
        const std::size_t rec = min_record_size(e, enc);
        if (!c.skip(std::size_t(e.count) * rec)) {
            const std::uint64_t row = rec ? c.remaining() / rec : 0;
            fail_at(path, e, row, c, enc);
        }
        return;
    }
    double v;
    for (std::uint64_t row = 0; row < e.count; ++row) {
        for (const Property& p : e.props) {
            if (p.list) {
                const std::uint64_t n = read_list_count(path, e, row, p, c, enc);
                for (std::uint64_t k = 0; k < n; ++k) {
                    if (!c.read(p.type, v)) fail_at(path, e, row, c, enc);
                }
            } else if (!c.read(p.type, v)) {
                fail_at(path, e, row, c, enc);
            }
        }
    }
}

/// Where the vertex element's properties go: each role's first property into its column of
/// `raw` (the rest, and lists, are skipped). Rows are held a range at a time (hold()).
class VertexColumns {
  public:
    /// Throws FormatError naming `path` for a list coordinate or a missing x, y or z.
    VertexColumns(const std::string& path, const Element& e, RawPoints& raw) : raw_(raw) {
        PlyType colour_type = PlyType::uint8;
        for (const Property& p : e.props) {
            Role r = role_of(p.name);
            if (p.list && (r == Role::x || r == Role::y || r == Role::z)) {
                throw FormatError(where(path, printable(e.name) + " property '" + p.name +
                                                  "' is a list; coordinates must be scalars"));
            }
            if (p.list) r = Role::ignore;
            if (r != Role::ignore && has_[int(r)]) r = Role::ignore;  // first one wins
            if (r != Role::ignore) has_[int(r)] = true;
            if (r == Role::red) colour_type = p.type;
            // Float coordinates are kept as floats (exact): half the memory of doubles.
            if (r == Role::x || r == Role::y || r == Role::z) {
                float_xyz_ = float_xyz_ && p.type == PlyType::float32;
            }
            roles_.push_back(r);
        }
        for (Role r : {Role::x, Role::y, Role::z}) {
            if (!has_[int(r)]) {
                const char* n = r == Role::x ? "x" : r == Role::y ? "y" : "z";
                throw FormatError(
                    where(path, "element '" + printable(e.name) + "' has no '" + n + "' property"));
            }
        }
        normals_ = has_[int(Role::nx)] && has_[int(Role::ny)] && has_[int(Role::nz)];
        colors_ = has_[int(Role::red)] && has_[int(Role::green)] && has_[int(Role::blue)];
        cscale_ = 1.0 / colour_scale(colour_type);
    }

    /// Rows [first, first + m) are held, at row - first.
    void hold(std::size_t first, std::size_t m) {
        base_ = first;
        const auto size = [](auto& v, bool want, std::size_t len) {
            v.clear();
            if (want) v.resize(len);
        };
        size(raw_.xyz_float, float_xyz_, m);
        size(raw_.xyz, !float_xyz_, 3 * m);
        size(raw_.normals, normals_, m);
        size(raw_.colors, colors_, m);
        size(raw_.scales, has_[int(Role::scale)], m);
        size(raw_.confidences, has_[int(Role::confidence)], m);
        size(raw_.scans, has_[int(Role::scan)], m);
    }
    std::size_t base() const { return base_; }
    bool used(std::size_t k) const { return roles_[k] != Role::ignore; }

    /// Property k's value v of file row `file_row` (a held one) into its column.
    void store(std::size_t file_row, std::size_t k, double v) {
        const std::size_t row = file_row - base_;
        switch (roles_[k]) {
            case Role::ignore:
                break;
            case Role::x:
                put_coordinate(row, 0, v);
                break;
            case Role::y:
                put_coordinate(row, 1, v);
                break;
            case Role::z:
                put_coordinate(row, 2, v);
                break;
            case Role::nx:
                if (normals_) raw_.normals[row][0] = float(v);
                break;
            case Role::ny:
                if (normals_) raw_.normals[row][1] = float(v);
                break;
            case Role::nz:
                if (normals_) raw_.normals[row][2] = float(v);
                break;
            case Role::red:
                if (colors_) raw_.colors[row][0] = float(v * cscale_);
                break;
            case Role::green:
                if (colors_) raw_.colors[row][1] = float(v * cscale_);
                break;
            case Role::blue:
                if (colors_) raw_.colors[row][2] = float(v * cscale_);
                break;
            case Role::scale:
                raw_.scales[row] = float(v);
                break;
            case Role::confidence:
                raw_.confidences[row] = float(v);
                break;
            case Role::scan:  // NaN: no scan, as a negative index
                raw_.scans[row] =
                    std::isnan(v) ? -1 : std::int32_t(std::clamp(v, -1.0, 2147483647.0));
                break;
        }
    }

  private:
    void put_coordinate(std::size_t row, int a, double v) {
        if (float_xyz_) {
            raw_.xyz_float[row][std::size_t(a)] = float(v);
        } else {
            raw_.xyz[3 * row + std::size_t(a)] = v;
        }
    }

    RawPoints& raw_;
    std::vector<Role> roles_;
    bool has_[int(Role::scan) + 1] = {};  // one per role (scan is the last)
    bool float_xyz_ = true, normals_ = false, colors_ = false;
    double cscale_ = 1.0;
    std::size_t base_ = 0;
};

void read_vertices(const std::string& path, const Element& e, Cursor& c, Encoding enc,
                   RawPoints& raw, const Consumed& consumed, const RowSink& sink) {
    VertexColumns columns(path, e, raw);
    const std::size_t n = std::size_t(e.count);
    if (!sink) columns.hold(0, n);  // all of them at once
    // Binary rows without lists all have the same size: when the data holds all of them, chunks
    // of rows are read in parallel, in place. Otherwise (ASCII, lists, a truncated file) row by
    // row with a cursor, which also finds and reports the row where the data ends.
    bool fixed = enc != Encoding::ascii;
    std::size_t row_bytes = 0;
    std::vector<std::pair<std::size_t, std::size_t>> used;  // (property, offset in the row)
    for (std::size_t k = 0; k < e.props.size(); ++k) {
        fixed = fixed && !e.props[k].list;
        if (columns.used(k)) used.emplace_back(k, row_bytes);
        row_bytes += type_size(e.props[k].type);
    }
    if (fixed && c.remaining() / row_bytes >= n) {
        const auto* data = reinterpret_cast<const unsigned char*>(c.here());
        const bool big_endian = enc == Encoding::binary_be;
        // A chunk of rows at a time, each chunk's bytes then handed to `consumed` (a mapped
        // file lets their pages go: the file is not held in memory beside its rows).
        for (std::size_t first = 0; first < n; first += kStreamRows) {
            const std::size_t last = std::min(n, first + kStreamRows);
            if (sink) columns.hold(first, last - first);
            tbb::parallel_for(tbb::blocked_range<std::size_t>(first, last, 16384),
                              [&](const tbb::blocked_range<std::size_t>& r) {
                                  for (std::size_t row = r.begin(); row < r.end(); ++row) {
                                      const unsigned char* q = data + row * row_bytes;
                                      for (const auto& [k, at] : used) {
                                          columns.store(
                                              row, k,
                                              binary_value(q + at, e.props[k].type, big_endian));
                                      }
                                  }
                              });
            if (sink) sink(raw, first);
            if (consumed) consumed(c.here() + last * row_bytes);
        }
        c.skip(n * row_bytes);
        return;
    }
    for (std::size_t row = 0; row < n; ++row) {
        if (sink && row % kStreamRows == 0) {
            if (row > 0) sink(raw, columns.base());
            columns.hold(row, std::min(kStreamRows, n - row));
        }
        double v;
        for (std::size_t k = 0; k < e.props.size(); ++k) {
            const Property& p = e.props[k];
            if (p.list) {
                const std::uint64_t len = read_list_count(path, e, row, p, c, enc);
                for (std::uint64_t i = 0; i < len; ++i) {
                    if (!c.read(p.type, v)) fail_at(path, e, row, c, enc);
                }
                continue;
            }
            if (!c.read(p.type, v)) fail_at(path, e, row, c, enc);
            columns.store(row, k, v);
        }
    }
    if (sink && n > 0) sink(raw, columns.base());
}

void read_faces(const std::string& path, const Element& e, Cursor& c, Encoding enc,
                RawPoints& raw) {
    int index_prop = -1;
    for (std::size_t k = 0; k < e.props.size(); ++k) {
        const Property& p = e.props[k];
        if (p.list && (p.name == "vertex_indices" || p.name == "vertex_index")) {
            index_prop = int(k);
            break;
        }
    }
    if (index_prop < 0) {
        throw FormatError(where(path, "element 'face' has no 'vertex_indices' list"));
    }
    std::vector<std::int64_t> poly;
    double v;
    for (std::uint64_t row = 0; row < e.count; ++row) {
        for (std::size_t k = 0; k < e.props.size(); ++k) {
            const Property& p = e.props[k];
            if (!p.list) {
                if (!c.read(p.type, v)) fail_at(path, e, row, c, enc);
                continue;
            }
            const std::uint64_t len = read_list_count(path, e, row, p, c, enc);
            poly.clear();
            for (std::uint64_t i = 0; i < len; ++i) {
                if (!c.read(p.type, v)) fail_at(path, e, row, c, enc);
                if (int(k) == index_prop) {
                    if (!(v >= 0.0) || v > double(std::numeric_limits<std::int32_t>::max()) ||
                        v != std::floor(v)) {
                        throw FormatError(where(path, "face " + std::to_string(row) +
                                                          ": invalid vertex index " +
                                                          format_number(v)));
                    }
                    poly.push_back(std::int64_t(v));
                }
            }
            // Fan triangulation of polygons (triangles pass through unchanged).
            for (std::size_t i = 2; i < poly.size(); ++i) {
                raw.faces.push_back({std::int32_t(poly[0]), std::int32_t(poly[i - 1]),
                                     std::int32_t(poly[i])});
            }
        }
    }
}

}  // namespace

bool ply_has_normals(const std::string& path, std::string_view content) {
    const Header h = parse_header(path, content);
    for (const Element& e : h.elements) {
        if (e.name != "vertex") continue;
        int found = 0;
        for (const Property& p : e.props) {
            const Role r = role_of(p.name);
            found += !p.list && (r == Role::nx || r == Role::ny || r == Role::nz);
        }
        return found >= 3;
    }
    return false;
}

RawPoints read_ply_raw(const std::string& path, std::string_view content, bool want_faces,
                       std::string& format, const Consumed& consumed, const RowSink& sink) {
    const Header h = parse_header(path, content);
    format = h.encoding == Encoding::ascii       ? "ply ascii"
             : h.encoding == Encoding::binary_le ? "ply binary_little_endian"
                                                 : "ply binary_big_endian";
    const auto vertex = std::find_if(h.elements.begin(), h.elements.end(),
                                     [](const Element& e) { return e.name == "vertex"; });
    if (vertex == h.elements.end()) throw FormatError(where(path, "no 'vertex' element"));

    // Every element must fit in what is left of the file before we allocate for it.
    const std::size_t body = content.size() - h.body;
    double needed = 0.0;
    for (const Element& e : h.elements) {
        const double before = needed;
        const std::size_t rec = min_record_size(e, h.encoding);
        needed += double(e.count) * double(rec);
        if (needed > double(body) + 1.0) {
            const std::string declared = " (the header declares " + std::to_string(e.count) +
                                         " rows";
            if (h.encoding != Encoding::ascii && fixed_size(e) && rec > 0) {
                // Earlier elements may have claimed a byte more than there is (the +1 above).
                const auto whole =
                    std::uint64_t(std::max(0.0, double(body) - before) / double(rec));
                throw FormatError(where(path, at_row(e, whole) + "truncated binary data" +
                                                  declared + ", the file holds " +
                                                  std::to_string(whole) + ")"));
            }
            throw FormatError(where(path, printable(e.name) +
                                              ": the file is too short for its rows" + declared +
                                              ", " + std::to_string(body) + " bytes of data)"));
        }
        if (&e == &*vertex && !want_faces) break;  // later elements are never read
    }

    RawPoints raw;
    Cursor c(content, h.body, h.encoding);
    bool have_faces = false;
    for (const Element& e : h.elements) {
        if (&e == &*vertex) {
            read_vertices(path, e, c, h.encoding, raw, consumed, sink);
            if (!want_faces) break;
        } else if (want_faces && e.name == "face" && !have_faces) {
            read_faces(path, e, c, h.encoding, raw);
            have_faces = true;
        } else {
            skip_element(path, e, c, h.encoding);
        }
    }
    if (want_faces) {
        const std::size_t nv = raw.rows();
        for (std::size_t f = 0; f < raw.faces.size(); ++f) {
            for (std::int32_t i : raw.faces[f]) {
                if (std::size_t(i) >= nv) {
                    throw FormatError(where(path, "face " + std::to_string(f) +
                                                      ": vertex index " + std::to_string(i) +
                                                      " out of range (" + std::to_string(nv) +
                                                      " vertices)"));
                }
            }
        }
    }
    return raw;
}

// ---------------------------------------------------------------------------------------------
// Writer

namespace {

/// Stores v at p in the file's byte order and advances p.
template <typename T>
void put_binary(char*& p, T v, bool big_endian) {
    std::memcpy(p, &v, sizeof(T));
    if (big_endian) std::reverse(p, p + sizeof(T));
    p += sizeof(T);
}

std::uint8_t to_byte(float c) {
    const float v = std::round(std::clamp(std::isfinite(c) ? c : 0.0f, 0.0f, 1.0f) * 255.0f);
    return std::uint8_t(v);
}

/// Writes `rows` binary rows of `row` bytes each to the stream, rows [first, last) made by
/// put(first, last, at) at `at`, a block of about 1 MB at a time: a block's rows are made in
/// parallel while the block before is written. (The bunny's 17 MB mesh at 0.5 mm, the run's
/// serial tail: 9 -> 6 ms at 2 threads, 10 -> 9 ms at 1, against rows packed in a 64 kB block
/// copied into the ByteWriter's buffer.)
template <typename Put>
void write_rows(std::FILE* file, std::size_t rows, std::size_t row, const Put& put) {
    const std::size_t per_block = std::max<std::size_t>(1, (std::size_t(1) << 20) / row);
    std::vector<char> making(per_block * row), ready(per_block * row);
    std::size_t ready_bytes = 0;
    for (std::size_t first = 0; first < rows || ready_bytes > 0;) {
        const std::size_t last = std::min(rows, first + per_block);
        tbb::parallel_invoke(
            [&] {
                tbb::parallel_for(tbb::blocked_range<std::size_t>(first, last, 4096),
                                  [&](const tbb::blocked_range<std::size_t>& r) {
                                      put(r.begin(), r.end(),
                                          making.data() + (r.begin() - first) * row);
                                  });
            },
            [&] {  // a failure sets the stream's error flag, which AtomicFile::commit reports
                if (ready_bytes > 0) std::fwrite(ready.data(), 1, ready_bytes, file);
            });
        making.swap(ready);
        ready_bytes = (last - first) * row;
        first = last;
    }
}

}  // namespace

void write_ply(const std::string& path, Span<Vec3f> positions, const Vec3d& origin,
               Span<Vec3f> normals, Span<Vec3f> colors, Span<float> scales,
               Span<float> confidences, const Column<Triangle>* faces,
               const WriteOptions& options, Span<std::int32_t> regions) {
    const bool far = origin != Vec3d{0, 0, 0};
    const bool ascii = options.encoding == PlyEncoding::ascii;
    const bool big = options.encoding == PlyEncoding::binary_big_endian;

    std::string header = "ply\nformat ";
    header += ascii ? "ascii" : big ? "binary_big_endian" : "binary_little_endian";
    header += " 1.0\ncomment written by vdbrecon ";
    header += VDBRECON_VERSION;
    header += "\n";
    for (const std::string& c : options.comments) {
        std::string line = c;
        std::replace(line.begin(), line.end(), '\n', ' ');
        header += "comment " + line + "\n";
    }
    header += "element vertex " + std::to_string(positions.size()) + "\n";
    const char* coord = far ? "double" : "float";
    for (const char* a : {"x", "y", "z"}) header += std::string("property ") + coord + " " + a + "\n";
    if (!normals.empty()) header += "property float nx\nproperty float ny\nproperty float nz\n";
    if (!colors.empty()) {
        header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    }
    if (!scales.empty()) header += "property float value\n";
    if (!confidences.empty()) header += "property float confidence\n";
    if (faces) {
        header += "element face " + std::to_string(faces->size()) + "\n";
        header += "property list uchar int vertex_indices\n";
        if (!regions.empty()) header += "property int region\n";
    }
    header += "end_header\n";

    AtomicFile file(path);
    ByteWriter out(file.stream());
    out.put(header);
    if (ascii) {
        std::string rec;
        for (std::size_t i = 0; i < positions.size(); ++i) {
            rec.clear();
            for (int a = 0; a < 3; ++a) {
                if (a) rec += ' ';
                rec += far ? format_number(origin[a] + double(positions[i][a]))
                           : format_number(positions[i][a]);
            }
            if (!normals.empty()) {
                for (float v : normals[i]) rec += ' ' + format_number(v);
            }
            if (!colors.empty()) {
                for (float v : colors[i]) rec += ' ' + std::to_string(int(to_byte(v)));
            }
            if (!scales.empty()) rec += ' ' + format_number(scales[i]);
            if (!confidences.empty()) rec += ' ' + format_number(confidences[i]);
            rec += '\n';
            out.write(rec.data(), rec.size());
        }
        if (faces) {
            for (std::size_t f = 0; f < faces->size(); ++f) {
                const Triangle& t = (*faces)[f];
                rec = "3 " + std::to_string(t[0]) + ' ' + std::to_string(t[1]) + ' ' +
                      std::to_string(t[2]);
                if (!regions.empty()) rec += ' ' + std::to_string(regions[f]);
                rec += '\n';
                out.write(rec.data(), rec.size());
            }
        }
    } else {
        out.flush();  // the header; the rows go to the stream after it
        const std::size_t vertex_row = (far ? 24 : 12) + (normals.empty() ? 0 : 12) +
                                       (colors.empty() ? 0 : 3) + (scales.empty() ? 0 : 4) +
                                       (confidences.empty() ? 0 : 4);
        // The rows' inputs in locals: the rows' byte stores could alias anything reached through
        // a reference, which was then read again for every value.
        write_rows(file.stream(), positions.size(), vertex_row,
                   [&](std::size_t first, std::size_t last, char* p) {
                       const Span<Vec3f> pos = positions, nrm = normals, col = colors;
                       const Span<float> scl = scales, cnf = confidences;
                       const Vec3d o = origin;
                       const bool b = big, wide = far;
                       for (std::size_t i = first; i < last; ++i) {
                           for (int a = 0; a < 3; ++a) {
                               if (wide) {
                                   put_binary(p, o[a] + double(pos[i][a]), b);
                               } else {
                                   put_binary(p, pos[i][a], b);
                               }
                           }
                           if (!nrm.empty()) {
                               for (float v : nrm[i]) put_binary(p, v, b);
                           }
                           if (!col.empty()) {
                               for (float v : col[i]) put_binary(p, to_byte(v), b);
                           }
                           if (!scl.empty()) put_binary(p, scl[i], b);
                           if (!cnf.empty()) put_binary(p, cnf[i], b);
                       }
                   });
        if (faces) {
            const std::size_t face_row = 13 + (regions.empty() ? 0 : 4);
            write_rows(file.stream(), faces->size(), face_row,
                       [&](std::size_t first, std::size_t last, char* p) {
                           const Triangle* tri = faces->data();
                           const Span<std::int32_t> reg = regions;
                           const bool b = big;
                           for (std::size_t f = first; f < last; ++f) {
                               put_binary(p, std::uint8_t(3), b);
                               for (std::int32_t v : tri[f]) put_binary(p, v, b);
                               if (!reg.empty()) put_binary(p, reg[f], b);
                           }
                       });
        }
    }
    out.flush();
    file.commit();
}

}  // namespace vdbrecon::detail
