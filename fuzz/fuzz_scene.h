// The body shared by the scene and image fuzz targets. These readers take paths (libpng,
// libjpeg and OpenEXR read files; a layout is a folder), so each input is written to a scratch
// folder of the process and read from there: the very code path `vdbrecon fuse` runs.
//   - an image target's input is one file (fuzz.png, fuzz.exr, fuzz.jpg);
//   - a scene target's input is a folder: parts "=== NAME\n" + bytes, each written to NAME
//     (a relative path of up to three letters-digits-._- names; other names are skipped), the
//     part's bytes ending before the newline that starts the next part's "=== ".
// The promises checked (a broken one aborts, so libFuzzer keeps the input):
//   - a bad input raises vdbrecon::Error (anything else escaping is a finding) whose message is
//     one line starting with the path of the file (or folder) at fault;
//   - a depth image is width x height values, none NaN; a colour image's channels are in 0..1;
//     an image read with a size it does not have is refused;
//   - a scene has frames, each with a depth path, a rigid pose, usable intrinsics (focal
//     lengths positive, a size of 0 x 0 or 1..65536 a side) and positive depth units.
#pragma once

#include <stdlib.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <vector>

#include "fuzz_reader.h"
#include "vdbrecon/log.h"
#include "vdbrecon/scene.h"

namespace vdbrecon::fuzz {

namespace fs = std::filesystem;

/// The process's scratch folder (made once, under $TMPDIR or /tmp; removed at exit), quiet
/// logging with it: the readers' warnings are not findings.
inline const fs::path& scratch() {
    static const fs::path dir = [] {
        set_log_handler([](LogLevel, const std::string&) {});
        std::string pattern = (fs::temp_directory_path() / "vdbrecon-fuzz-XXXXXX").string();
        if (!::mkdtemp(pattern.data())) std::abort();
        std::atexit([] {
            std::error_code ec;
            fs::remove_all(scratch(), ec);
        });
        return fs::path(pattern);
    }();
    return dir;
}

/// With FUZZ_VERBOSE set (replaying an input by hand), says what a read gave.
inline void note(const std::string& what) {
    static const bool verbose = std::getenv("FUZZ_VERBOSE") != nullptr;
    if (verbose) std::fprintf(stderr, "fuzz: %s\n", what.c_str());
}

inline void write_file(const fs::path& path, std::string_view bytes) {
    std::ofstream(path, std::ios::binary).write(bytes.data(), std::streamsize(bytes.size()));
}

inline void check_error_in(const Error& e, const fs::path& dir) {
    const std::string m = e.what(), prefix = dir.string();
    note(m);
    check(m.compare(0, prefix.size(), prefix) == 0, "errors start with the path at fault");
    check(m.find(": ", prefix.size()) != std::string::npos, "errors say what is wrong");
    check(m.find('\n') == std::string::npos, "errors are one line");
}

// ---------------------------------------------------------------------------------------------
// Images

inline void check_depth(const DepthImage& img) {
    check(img.width > 0 && img.height > 0, "a depth image has pixels");
    check(img.depth.size() == std::size_t(img.width) * std::size_t(img.height),
          "a depth image is width x height values");
    for (float d : img.depth) check(!std::isnan(d) && d < 65504.0f, "depths are numbers or 0");
}

/// Reads `data` as the depth image fuzz.<ext>; read again with another size expected, it must
/// be refused.
inline int read_depth(const std::uint8_t* data, std::size_t size, const std::string& ext) {
    const std::string path = (scratch() / ("fuzz." + ext)).string();
    write_file(path, std::string_view(reinterpret_cast<const char*>(data), size));
    try {
        const DepthImage img = read_depth_image(path, 1000.0);
        note("a depth image of " + std::to_string(img.width) + " x " + std::to_string(img.height));
        check_depth(img);
        try {
            read_depth_image(path, 1000.0, ImageSize{img.width, img.height + 1});
            check(false, "a depth image of another size than expected is refused");
        } catch (const FormatError& e) {
            check_error(e, path);
        }
    } catch (const Error& e) {
        note(e.what());
        check_error(e, path);
    }
    return 0;
}

/// Reads `data` as the colour image fuzz.<ext>.
inline int read_color(const std::uint8_t* data, std::size_t size, const std::string& ext) {
    const std::string path = (scratch() / ("fuzz." + ext)).string();
    write_file(path, std::string_view(reinterpret_cast<const char*>(data), size));
    try {
        const ColorImage img = read_color_image(path);
        note("a colour image of " + std::to_string(img.width) + " x " + std::to_string(img.height));
        check(img.width > 0 && img.height > 0, "a colour image has pixels");
        check(img.rgb.size() == std::size_t(img.width) * std::size_t(img.height),
              "a colour image is width x height pixels");
        for (const Vec3f& c : img.rgb) {
            for (float v : c) check(v >= 0.0f && v <= 1.0f, "colours are in 0..1");
        }
    } catch (const Error& e) {
        note(e.what());
        check_error(e, path);
    }
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Scenes

/// Whether `name` is a relative path the scene targets write: 1 to 3 names of letters, digits,
/// '.', '_' and '-', none "." or "..".
inline bool usable_name(std::string_view name) {
    if (name.empty() || name.size() > 64 || name.front() == '/' || name.back() == '/') return false;
    int parts = 1;
    std::size_t start = 0;
    for (std::size_t i = 0; i <= name.size(); ++i) {
        if (i < name.size() && name[i] != '/') {
            const char c = name[i];
            const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') ||
                            (c >= '0' && c <= '9') || c == '.' || c == '_' || c == '-';
            if (!ok) return false;
            continue;
        }
        const std::string_view part = name.substr(start, i - start);
        if (part.empty() || part == "." || part == "..") return false;
        if (i < name.size()) ++parts;
        start = i + 1;
    }
    return parts <= 3;
}

/// The parts of a scene input, "=== NAME\n" + bytes joined by newlines, as (NAME, bytes); bytes
/// before the first part are ignored.
inline std::vector<std::pair<std::string, std::string_view>> parts_of(std::string_view in) {
    std::vector<std::pair<std::string, std::string_view>> parts;
    constexpr std::string_view kMark = "=== ";
    std::size_t at = in.compare(0, kMark.size(), kMark) == 0 ? 0 : in.find("\n=== ");
    if (at != std::string_view::npos && in[at] == '\n') ++at;
    while (at != std::string_view::npos && at < in.size()) {
        const std::size_t eol = in.find('\n', at);
        if (eol == std::string_view::npos) break;
        const std::string name(in.substr(at + kMark.size(), eol - at - kMark.size()));
        const std::size_t next = in.find("\n=== ", eol);
        const std::size_t end = next == std::string_view::npos ? in.size() : next;
        parts.push_back({name, in.substr(eol + 1, end - eol - 1)});
        at = next == std::string_view::npos ? next : next + 1;
    }
    return parts;
}

/// Writes the parts of a scene input into a fresh folder `dir`; returns the names written.
inline std::vector<std::string> write_folder(const fs::path& dir, std::string_view in) {
    std::error_code ec;
    fs::remove_all(dir, ec);
    fs::create_directories(dir, ec);
    std::vector<std::string> names;
    for (const auto& [name, bytes] : parts_of(in)) {
        if (!usable_name(name)) continue;
        const fs::path p = dir / name;
        fs::create_directories(p.parent_path(), ec);
        if (fs::exists(p, ec)) continue;
        write_file(p, bytes);
        names.push_back(name);
    }
    return names;
}

inline void check_intrinsics(const Intrinsics& K) {
    check(std::isfinite(K.fx) && K.fx > 0.0 && std::isfinite(K.fy) && K.fy > 0.0,
          "focal lengths are positive");
    check(!std::isinf(K.cx) && !std::isinf(K.cy),
          "the principal point is finite (or NaN: the centre)");
    const bool from_image = K.width == 0 && K.height == 0;
    check(from_image || (K.width > 0 && K.height > 0 && K.width <= 65536 && K.height <= 65536),
          "an image size is 0 x 0 (the image's) or 1..65536 a side");
}

inline void check_scene(const Scene& scene) {
    check(!scene.kind.empty() && !scene.frames.empty(), "a scene has a kind and frames");
    for (const SceneFrame& f : scene.frames) {
        check(!f.depth_path.empty(), "a frame has a depth file");
        try {
            validate_pose(f.pose);
        } catch (const InvalidArgument&) {
            check(false, "a frame's pose is a rigid transform");
        }
        if (!f.scan && !f.organized) check_intrinsics(f.intrinsics);
        if (f.color_intrinsics) check_intrinsics(*f.color_intrinsics);
        check(std::isfinite(f.units_per_metre) && f.units_per_metre > 0.0,
              "depth units are positive");
    }
}

/// Reads a scene at `path` (a folder or a file in `dir`), checks it and reads its KITTI scans.
inline void read_scene_at(const std::string& path, const fs::path& dir,
                          const SceneOptions& options) {
    try {
        const Scene scene = read_scene(path, options);
        note(scene.kind + ": " + std::to_string(scene.frames.size()) + " frames");
        check_scene(scene);
        for (const SceneFrame& f : scene.frames) {
            if (!f.scan || file_extension(f.depth_path) != "bin") continue;
            try {
                const std::size_t points = read_kitti_scan(f.depth_path).size();
                check(points * 16 == fs::file_size(f.depth_path), "a scan is 16 bytes a point");
            } catch (const Error& e) {
                check_error_in(e, dir);
            }
        }
    } catch (const Error& e) {
        check_error_in(e, dir);
    }
}

}  // namespace vdbrecon::fuzz
