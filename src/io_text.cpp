// Text point formats: XYZ / PTS (whitespace-separated columns) and Wavefront OBJ (v, vn, f).
#include <charconv>
#include <cmath>
#include <cstring>

#include "detail/io_common.h"
#include "vdbrecon/error.h"
#include "vdbrecon/log.h"

namespace vdbrecon::detail {
namespace {

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == ','; }

/// Splits a line into tokens (spaces, tabs and commas separate).
void tokenize(const char* b, const char* e, std::vector<std::pair<const char*, const char*>>& out) {
    out.clear();
    while (b < e) {
        while (b < e && is_space(*b)) ++b;
        const char* s = b;
        while (b < e && !is_space(*b)) ++b;
        if (b > s) out.emplace_back(s, b);
    }
}

/// Iterates over the lines of `content`, calling f(line_number, begin, end).
template <typename F>
void for_each_line(std::string_view content, F&& f) {
    const char* p = content.data();
    const char* end = p + content.size();
    std::size_t lineno = 0;
    while (p < end) {
        const char* eol = static_cast<const char*>(std::memchr(p, '\n', std::size_t(end - p)));
        if (!eol) eol = end;
        ++lineno;
        f(lineno, p, eol);
        p = eol + 1;
    }
}

}  // namespace

RawPoints read_xyz_raw(const std::string& path, std::string_view content,
                       const Consumed& consumed, const RowSink& sink) {
    RawPoints raw;
    std::size_t handed = 0;
    std::vector<std::pair<const char*, const char*>> tok;
    std::size_t columns = 0;
    bool first_data_line = true;
    double v[9];
    for_each_line(content, [&](std::size_t lineno, const char* b, const char* e) {
        tokenize(b, e, tok);
        if (tok.empty() || *tok[0].first == '#' || (tok[0].second - tok[0].first >= 2 &&
                                                     tok[0].first[0] == '/' &&
                                                     tok[0].first[1] == '/')) {
            return;
        }
        const std::string at = "line " + std::to_string(lineno) + ": ";
        if (first_data_line && tok.size() == 1) {
            // PTS files start with the point count.
            first_data_line = false;
            return;
        }
        first_data_line = false;
        if (columns == 0) {
            columns = tok.size();
            if (columns != 3 && columns != 4 && columns != 6 && columns != 7) {
                throw FormatError(where(
                    path, at + "found " + std::to_string(columns) +
                              " columns; expected 3 (x y z), 4 (x y z intensity), 6 (x y z nx ny nz)"
                              " or 7 (x y z intensity r g b, PTS)"));
            }
        }
        if (tok.size() != columns) {
            throw FormatError(where(path, at + "expected " + std::to_string(columns) +
                                              " numbers, found " + std::to_string(tok.size())));
        }
        for (std::size_t i = 0; i < columns; ++i) {
            if (!parse_double(tok[i].first, tok[i].second, v[i])) {
                const std::string_view token(tok[i].first,
                                             std::size_t(tok[i].second - tok[i].first));
                throw FormatError(where(path, at + "'" + printable(token) + "' is not a number"));
            }
        }
        raw.xyz.insert(raw.xyz.end(), v, v + 3);
        if (columns == 6) {
            raw.normals.push_back({float(v[3]), float(v[4]), float(v[5])});
        } else if (columns == 7) {
            raw.colors.push_back({float(v[4] / 255.0), float(v[5] / 255.0), float(v[6] / 255.0)});
        }
        if (raw.rows() % kStreamRows == 0) {
            hand_rows(raw, sink, handed, false);
            if (consumed) consumed(e);
        }
    });
    hand_rows(raw, sink, handed, true);
    return raw;
}

RawPoints read_obj_raw(const std::string& path, std::string_view content, bool want_faces) {
    RawPoints raw;
    std::vector<Vec3f> vn;                 // per vn line
    std::vector<std::int64_t> vertex_vn;   // per v: index of a vn from the faces, or -1
    bool all_colored = true;
    std::vector<std::pair<const char*, const char*>> tok;
    std::vector<std::int32_t> poly;
    for_each_line(content, [&](std::size_t lineno, const char* b, const char* e) {
        tokenize(b, e, tok);
        if (tok.empty()) return;
        const std::string key(tok[0].first, tok[0].second);
        const std::string at = "line " + std::to_string(lineno) + ": ";
        auto number = [&](std::size_t i) {
            double x;
            if (i >= tok.size() || !parse_double(tok[i].first, tok[i].second, x)) {
                throw FormatError(where(path, at + "malformed '" + printable(key) + "' line"));
            }
            return x;
        };
        if (key == "v") {
            for (std::size_t i = 1; i <= 3; ++i) raw.xyz.push_back(number(i));
            if (tok.size() >= 7) {
                raw.colors.push_back({float(number(4)), float(number(5)), float(number(6))});
            } else {
                all_colored = false;
            }
            vertex_vn.push_back(-1);
        } else if (key == "vn") {
            vn.push_back({float(number(1)), float(number(2)), float(number(3))});
        } else if (key == "f") {
            const std::int64_t nv = std::int64_t(raw.rows());
            const std::int64_t nn = std::int64_t(vn.size());
            poly.clear();
            for (std::size_t i = 1; i < tok.size(); ++i) {
                // v, v/t, v//n or v/t/n; indices are 1-based, negative ones count from the end.
                const char* s = tok[i].first;
                const char* slash = s;
                while (slash < tok[i].second && *slash != '/') ++slash;
                std::int64_t vi = 0, ni = 0;
                auto r = std::from_chars(s, slash, vi);
                if (r.ec != std::errc() || r.ptr != slash || vi == 0) {
                    throw FormatError(where(path, at + "malformed face index"));
                }
                vi = vi > 0 ? vi - 1 : nv + vi;
                if (vi < 0 || vi >= nv) {
                    throw FormatError(where(path, at + "face vertex index out of range"));
                }
                const char* second = slash < tok[i].second ? slash + 1 : slash;
                const char* slash2 = second;
                while (slash2 < tok[i].second && *slash2 != '/') ++slash2;
                if (slash2 < tok[i].second) {
                    r = std::from_chars(slash2 + 1, tok[i].second, ni);
                    if (r.ec == std::errc() && ni != 0) {
                        ni = ni > 0 ? ni - 1 : nn + ni;
                        if (ni >= 0 && ni < nn && vertex_vn[std::size_t(vi)] < 0) {
                            vertex_vn[std::size_t(vi)] = ni;
                        }
                    }
                }
                poly.push_back(std::int32_t(vi));
            }
            if (want_faces) {
                for (std::size_t i = 2; i < poly.size(); ++i) {
                    raw.faces.push_back({poly[0], poly[i - 1], poly[i]});
                }
            }
        }
    });
    const std::size_t n = raw.rows();
    if (!all_colored || raw.colors.size() != n) raw.colors.clear();
    if (!vn.empty()) {
        if (vn.size() == n) {
            raw.normals = std::move(vn);  // one vn per v, in the same order
        } else {
            std::size_t mapped = 0;
            for (std::int64_t k : vertex_vn) mapped += k >= 0;
            if (mapped == n) {
                raw.normals.resize(n);
                for (std::size_t i = 0; i < n; ++i) raw.normals[i] = vn[std::size_t(vertex_vn[i])];
            } else {
                log_warning(where(path, "normals ignored: " + std::to_string(vn.size()) +
                                            " vn lines do not match " + std::to_string(n) +
                                            " vertices"));
            }
        }
    }
    return raw;
}

}  // namespace vdbrecon::detail
