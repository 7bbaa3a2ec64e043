// The body shared by the reader fuzz targets: parse the bytes as a point cloud (and as a mesh),
// then check what the readers promise. A broken promise aborts, so libFuzzer keeps the input:
//   - a malformed file raises vdbrecon::Error (anything else escaping is a finding) whose
//     message is one line starting with the file name;
//   - a successful read has points, finite positions, one entry per point in every attribute,
//     unit or zero normals, non-negative scales, and faces that index existing vertices.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

#include "vdbrecon/error.h"
#include "vdbrecon/io.h"

namespace vdbrecon::fuzz {

inline void check(bool ok, const char* promise) {
    if (!ok) {
        std::fprintf(stderr, "fuzz: broken promise: %s\n", promise);
        std::abort();
    }
}

inline bool finite(const Vec3f& v) {
    return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

template <typename V>
bool per_point(const V& attribute, std::size_t n) {
    return attribute.empty() || attribute.size() == n;
}

inline void check_cloud(const ReadResult& r) {
    const PointCloud& c = r.cloud;
    const std::size_t n = c.size();
    check(n > 0, "a successful read has points");
    check(r.rows == n + r.dropped_nonfinite, "rows = points + dropped rows");
    check(r.invalid_normals <= n, "invalid normals <= points");
    check(per_point(c.normals, n) && per_point(c.colors, n) && per_point(c.scales, n) &&
              per_point(c.confidences, n),
          "every attribute has one entry per point");
    check(std::isfinite(c.origin[0]) && std::isfinite(c.origin[1]) && std::isfinite(c.origin[2]),
          "the origin is finite");
    for (const Vec3f& p : c.positions) check(finite(p), "positions are finite floats");
    for (const Vec3f& v : c.normals) {
        const double len =
            std::sqrt(double(v[0]) * v[0] + double(v[1]) * v[1] + double(v[2]) * v[2]);
        check(len == 0.0 || std::fabs(len - 1.0) < 1e-5, "normals are unit or zero");
    }
    for (float s : c.scales) check(std::isfinite(s) && s >= 0.0f, "scales are finite and >= 0");
}

inline void check_mesh(const Mesh& m) {
    const std::size_t n = m.vertices.size();
    check(!m.faces.empty(), "a successful mesh read has faces");
    check(per_point(m.normals, n) && per_point(m.colors, n), "one normal/colour per vertex");
    for (const Vec3f& p : m.vertices) check(finite(p), "vertices are finite floats");
    for (const Triangle& t : m.faces) {
        for (std::int32_t i : t) check(i >= 0 && std::size_t(i) < n, "faces index vertices");
    }
}

inline void check_error(const Error& e, const std::string& name) {
    const std::string m = e.what();
    check(m.compare(0, name.size() + 2, name + ": ") == 0, "errors start with the file name");
    check(m.size() > name.size() + 2, "errors say what is wrong");
    check(m.find('\n') == std::string::npos, "errors are one line");
}

/// Reads `data` as the file `name` (its extension picks the reader); also as a mesh if `mesh`.
inline int read_all(const std::uint8_t* data, std::size_t size, const std::string& name,
                    bool mesh) {
    const std::string_view bytes(reinterpret_cast<const char*>(data), size);
    try {
        check_cloud(read_points_from_memory(bytes, name));
    } catch (const Error& e) {
        check_error(e, name);
    }
    if (mesh) {
        try {
            check_mesh(read_mesh_from_memory(bytes, name));
        } catch (const Error& e) {
            check_error(e, name);
        }
    }
    return 0;
}

}  // namespace vdbrecon::fuzz
