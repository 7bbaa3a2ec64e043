// The RGB-D dataset layouts of detail/scene_layouts.h: each a small reader that lists the frames
// (depth file, intrinsics, camera-to-world pose in OpenCV axes, depth units), as read_scene()
// does for transforms.json and TUM folders.
#include "detail/scene_layouts.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <initializer_list>
#include <optional>
#include <sstream>

#include "detail/io_common.h"
#include "vdbrecon/error.h"
#include "vdbrecon/log.h"

namespace vdbrecon::detail {

namespace fs = std::filesystem;

namespace {

bool exists_file(const fs::path& p) {
    std::error_code ec;
    return fs::is_regular_file(p, ec);
}
bool exists_dir(const fs::path& p) {
    std::error_code ec;
    return fs::is_directory(p, ec);
}

/// The files of `dir` whose names start with `prefix` and end with `suffix`, by the number
/// between them (frame-000012 after frame-000002; names without a number last, by name).
std::vector<std::pair<long, fs::path>> numbered_files(const fs::path& dir, const std::string& prefix,
                                                      const std::string& suffix) {
    std::vector<std::pair<long, fs::path>> out;
    std::error_code ec;
    for (const fs::directory_entry& e : fs::directory_iterator(dir, ec)) {
        const std::string name = e.path().filename().string();
        if (name.size() <= prefix.size() + suffix.size() || name.compare(0, prefix.size(), prefix) != 0 ||
            name.compare(name.size() - suffix.size(), suffix.size(), suffix) != 0) {
            continue;
        }
        const std::string mid = name.substr(prefix.size(), name.size() - prefix.size() - suffix.size());
        const bool digits = !mid.empty() && mid.size() < 12 &&
                            std::all_of(mid.begin(), mid.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)); });
        if (!digits) continue;
        out.push_back({std::stol(mid), e.path()});
    }
    std::sort(out.begin(), out.end());
    return out;
}

/// The numbers of a text (whitespace or commas between them), checked finite unless
/// `allow_inf` (ScanNet marks a lost pose with -inf).
std::vector<double> numbers_in(const std::string& text, const fs::path& path,
                               bool allow_inf = false) {
    std::vector<double> v;
    const char* p = text.data();
    const char* end = p + text.size();
    while (p < end) {
        while (p < end && (std::isspace(static_cast<unsigned char>(*p)) || *p == ',')) ++p;
        if (p == end) break;
        const char* q = p;
        while (q < end && !std::isspace(static_cast<unsigned char>(*q)) && *q != ',') ++q;
        double x = 0.0;
        if (!parse_double(p, q, x) && std::string(p, q) != "-inf" && std::string(p, q) != "inf") {
            throw FormatError(where(path.string(), "'" + printable(std::string_view(p, std::size_t(q - p))) +
                                                       "' is not a number"));
        }
        if (std::string(p, q) == "-inf") x = -INFINITY;
        if (std::string(p, q) == "inf") x = INFINITY;
        if (std::isnan(x) || (std::isinf(x) && !allow_inf)) {
            throw FormatError(where(path.string(), "a value is not finite"));
        }
        v.push_back(x);
        p = q;
    }
    return v;
}

/// numbers_in of a whole file.
std::vector<double> numbers_of(const fs::path& path, bool allow_inf = false) {
    return numbers_in(read_file(path.string()), path, allow_inf);
}

/// A 4x4 row-major camera-to-world pose from 16 numbers of `path` starting at `at`.
Pose pose_at(const std::vector<double>& v, std::size_t at) {
    Pose p{};
    for (std::size_t i = 0; i < 16; ++i) p[i] = v[at + i];
    return p;
}

/// `pose` when it is a rigid camera-to-world transform (validate_pose), else FormatError naming
/// `path` (and `what`: which of its poses).
Pose rigid(const Pose& pose, const fs::path& path, const std::string& what = "") {
    try {
        validate_pose(pose);
    } catch (const InvalidArgument& e) {
        throw FormatError(where(path.string(), what + e.what()));
    }
    return pose;
}

/// A pose file of exactly 16 numbers (a 4x4 matrix); false for a pose marked lost (-inf).
bool read_pose_file(const fs::path& path, Pose& pose) {
    const std::vector<double> v = numbers_of(path, true);
    if (v.size() != 16) {
        throw FormatError(where(path.string(), "expected a 4x4 matrix (16 numbers), found " +
                                                   std::to_string(v.size())));
    }
    for (double x : v) {
        if (!std::isfinite(x)) return false;
    }
    pose = rigid(pose_at(v, 0), path);
    return true;
}

/// `K` when its focal lengths are positive, its principal point finite and its size either
/// 0 x 0 (the images') or in 1..65536 a side (as Intrinsics::validate), else FormatError
/// naming `path`.
Intrinsics usable(const Intrinsics& K, const fs::path& path) {
    Intrinsics k = K;
    if (k.width == 0 && k.height == 0) k.width = k.height = 1;
    try {
        k.validate();
    } catch (const InvalidArgument& e) {
        throw FormatError(where(path.string(), e.what()));
    }
    return K;
}

/// A JSON value that is an image size: a whole number of pixels in 0..65536 (0: the
/// images'); -1 when it is not.
int json_side(const nlohmann::json& v) {
    if (!v.is_number()) return -1;
    const double x = v.get<double>();
    return x >= 0.0 && x <= 65536.0 && x == std::floor(x) ? int(x) : -1;
}

/// Intrinsics from a 3x3 (or 4x4, K in its top-left corner) matrix file.
Intrinsics matrix_intrinsics(const fs::path& path) {
    const std::vector<double> v = numbers_of(path);
    if (v.size() != 9 && v.size() != 16) {
        throw FormatError(where(path.string(), "expected a 3x3 or 4x4 intrinsic matrix, found " +
                                                   std::to_string(v.size()) + " numbers"));
    }
    const std::size_t row = v.size() == 9 ? 3 : 4;
    Intrinsics K;
    K.fx = v[0];
    K.cx = v[2];
    K.fy = v[row + 1];
    K.cy = v[row + 2];
    if (!(K.fx > 0.0 && K.fy > 0.0)) {
        throw FormatError(where(path.string(), "the focal lengths are not positive"));
    }
    return usable(K, path);
}

/// The given intrinsics, else those of the first file of `candidates` that exists (read by
/// `read`), else an error naming what was looked for.
template <typename Read>
Intrinsics intrinsics_of(const SceneOptions& options, const std::vector<fs::path>& candidates,
                         const std::string& layout, const std::string& hint, Read&& read) {
    if (options.intrinsics) return *options.intrinsics;
    for (const fs::path& c : candidates) {
        if (exists_file(c)) return read(c);
    }
    std::string looked;
    for (const fs::path& c : candidates) looked += (looked.empty() ? "" : ", ") + c.string();
    throw InvalidArgument(where(candidates.front().parent_path().string(),
                                layout + ": no intrinsics (looked for " + looked +
                                    "); give --intrinsics fx,fy,cx,cy" + hint));
}

/// Open3D's camera_intrinsic.json: width, height, intrinsic_matrix (3x3, column-major).
Intrinsics open3d_intrinsics(const fs::path& path) {
    const std::string text = read_file(path.string());
    const nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
    const auto m = j.is_object() ? j.find("intrinsic_matrix") : j.end();
    if (!j.is_object() || m == j.end() || !m->is_array() || m->size() != 9) {
        throw FormatError(where(path.string(), "not an Open3D camera intrinsic (JSON with an "
                                               "'intrinsic_matrix' of 9 numbers)"));
    }
    double a[9];
    for (std::size_t i = 0; i < 9; ++i) {
        if (!(*m)[i].is_number()) throw FormatError(where(path.string(), "intrinsic_matrix: not a number"));
        a[i] = (*m)[i].get<double>();
    }
    Intrinsics K;
    K.fx = a[0];
    K.fy = a[4];
    K.cx = a[6];
    K.cy = a[7];
    if (j.contains("width")) K.width = json_side(j["width"]);
    if (j.contains("height")) K.height = json_side(j["height"]);
    if (!(K.fx > 0.0 && K.fy > 0.0 && K.width >= 0 && K.height >= 0)) {
        throw FormatError(where(path.string(),
                                "the focal lengths or the size are not positive "
                                "(width and height: whole numbers up to 65536)"));
    }
    return usable(K, path);
}

/// Replica's (NICE-SLAM's) cam_params.json: camera {w, h, fx, fy, cx, cy, scale}.
Intrinsics replica_intrinsics(const fs::path& path, double& scale) {
    const nlohmann::json j = nlohmann::json::parse(read_file(path.string()), nullptr, false);
    const auto c = j.is_object() ? j.find("camera") : j.end();
    if (c == j.end() || !c->is_object()) {
        throw FormatError(where(path.string(), "no 'camera' object (w, h, fx, fy, cx, cy, scale)"));
    }
    auto num = [&](const char* key) {
        const auto it = c->find(key);
        if (it == c->end() || !it->is_number() || !(it->get<double>() > 0.0)) {
            throw FormatError(where(path.string(), std::string("camera.") + key +
                                                       " is missing or not a positive number"));
        }
        return it->get<double>();
    };
    auto side = [&](const char* key) {
        const int v = num(key) > 0.0 ? json_side(c->at(key)) : -1;
        if (v <= 0) {
            throw FormatError(where(
                path.string(),
                std::string("camera.") + key + " is not a whole number of pixels up to 65536"));
        }
        return v;
    };
    Intrinsics K;
    K.width = side("w");
    K.height = side("h");
    K.fx = num("fx");
    K.fy = num("fy");
    K.cx = num("cx");
    K.cy = num("cy");
    scale = num("scale");
    return usable(K, path);
}

/// The first of `stem` + each extension that is a file, else "".
std::string first_image(const fs::path& stem, std::initializer_list<const char*> exts) {
    for (const char* e : exts) {
        fs::path p = stem;
        p += e;
        if (exists_file(p)) return p.string();
    }
    return "";
}

/// The image files of a folder (.png, .jpg, .jpeg), in name order.
std::vector<fs::path> images_in(const fs::path& dir) {
    std::vector<fs::path> out;
    std::error_code ec;
    for (const fs::directory_entry& e : fs::directory_iterator(dir, ec)) {
        const std::string x = e.path().extension().string();
        if (x == ".png" || x == ".jpg" || x == ".jpeg") out.push_back(e.path());
    }
    std::sort(out.begin(), out.end());
    return out;
}

SceneFrame frame_of(const fs::path& depth, const Intrinsics& K, const Pose& pose, double units,
                    const SceneOptions& options) {
    SceneFrame f;
    f.depth_path = depth.string();
    f.intrinsics = K;
    f.pose = pose;
    f.units_per_metre = options.units_per_metre > 0.0 ? options.units_per_metre : units;
    return f;
}

void require_frames(const Scene& scene, const fs::path& dir, const std::string& what) {
    if (scene.frames.empty()) throw FormatError(where(dir.string(), scene.kind + ": no frames (" + what + ")"));
}

}  // namespace

Scene read_7scenes(const std::string& folder, const SceneOptions& options) {
    const fs::path dir(folder);
    Scene scene;
    scene.kind = "7-Scenes/3DMatch";
    const Intrinsics K = intrinsics_of(
        options, {dir / "camera-intrinsics.txt", dir.parent_path() / "camera-intrinsics.txt"},
        scene.kind, " (7-Scenes' Kinect: 585,585,320,240)", matrix_intrinsics);
    for (const auto& [index, depth] : numbered_files(dir, "frame-", ".depth.png")) {
        const fs::path pose_path = dir / ("frame-" + depth.filename().string().substr(6, depth.filename().string().size() - 16) + ".pose.txt");
        if (!exists_file(pose_path)) throw IoError(where(pose_path.string(), "missing: the pose of " + depth.filename().string()));
        Pose pose{};
        if (!read_pose_file(pose_path, pose)) {
            log_warning(pose_path.string() + ": the pose is marked lost (inf); frame skipped");
            continue;
        }
        SceneFrame f = frame_of(depth, K, pose, 1000.0, options);
        f.invalid_value = 65535;
        const std::string name = depth.filename().string();
        f.color_path = first_image(dir / name.substr(0, name.size() - 10), {".color.png", ".color.jpg"});
        scene.frames.push_back(std::move(f));
    }
    require_frames(scene, dir, "frame-NNNNNN.depth.png with .pose.txt");
    return scene;
}

Scene read_redwood(const std::string& folder, const std::string& log, const SceneOptions& options) {
    const fs::path dir(folder);
    Scene scene;
    scene.kind = "Redwood/Open3D";
    const Intrinsics K = intrinsics_of(options, {dir / "camera_intrinsic.json", dir / "intrinsic.json"},
                                       scene.kind, " (PrimeSense: 525,525,319.5,239.5)",
                                       open3d_intrinsics);
    // The .log trajectory: per frame a line of three ids, then the 4x4 camera-to-world rows.
    const std::vector<double> v = numbers_of(log);
    if (v.size() % 19 != 0 || v.empty()) {
        throw FormatError(where(log, "not a trajectory of 19 numbers a frame (3 ids, a 4x4 "
                                     "matrix); found " + std::to_string(v.size()) + " numbers"));
    }
    std::vector<fs::path> depths;  // the depth images in name order
    std::error_code ec;
    for (const fs::directory_entry& e : fs::directory_iterator(dir / "depth", ec)) {
        if (e.path().extension() == ".png") depths.push_back(e.path());
    }
    std::sort(depths.begin(), depths.end());
    const std::size_t frames = v.size() / 19;
    if (depths.size() < frames) {
        throw FormatError(where(log, std::to_string(frames) + " poses for " +
                                         std::to_string(depths.size()) + " images in " +
                                         (dir / "depth").string()));
    }
    std::vector<fs::path> colors = images_in(dir / "color");
    if (colors.empty()) colors = images_in(dir / "image");
    for (std::size_t i = 0; i < frames; ++i) {
        const Pose pose = rigid(pose_at(v, 19 * i + 3), log, "frame " + std::to_string(i) + ": ");
        scene.frames.push_back(frame_of(depths[i], K, pose, 1000.0, options));
        if (colors.size() == depths.size()) scene.frames.back().color_path = colors[i].string();
    }
    return scene;
}

Scene read_scannet(const std::string& folder, const SceneOptions& options) {
    const fs::path dir(folder);
    Scene scene;
    scene.kind = "ScanNet";
    const Intrinsics K = intrinsics_of(options, {dir / "intrinsic" / "intrinsic_depth.txt"}, scene.kind,
                                       "", matrix_intrinsics);
    // The colour camera has its own intrinsics (and size, taken from its images).
    std::optional<Intrinsics> color_K;
    if (exists_file(dir / "intrinsic" / "intrinsic_color.txt")) {
        color_K = matrix_intrinsics(dir / "intrinsic" / "intrinsic_color.txt");
    }
    for (const auto& [index, depth] : numbered_files(dir / "depth", "", ".png")) {
        const fs::path pose_path = dir / "pose" / (std::to_string(index) + ".txt");
        if (!exists_file(pose_path)) throw IoError(where(pose_path.string(), "missing: the pose of " + depth.string()));
        Pose pose{};
        if (!read_pose_file(pose_path, pose)) {
            log_warning(pose_path.string() + ": the pose is marked lost (-inf); frame skipped");
            continue;
        }
        SceneFrame f = frame_of(depth, K, pose, 1000.0, options);
        f.color_path = first_image(dir / "color" / std::to_string(index), {".jpg", ".png"});
        f.color_intrinsics = color_K;
        scene.frames.push_back(std::move(f));
    }
    require_frames(scene, dir, "depth/N.png with pose/N.txt");
    return scene;
}

Scene read_replica(const std::string& folder, const SceneOptions& options) {
    const fs::path dir(folder);
    Scene scene;
    scene.kind = "Replica";
    double scale = 6553.5;  // NICE-SLAM's png_depth_scale for Replica
    Intrinsics K;
    if (options.intrinsics) {
        K = *options.intrinsics;
    } else {
        K = intrinsics_of(options, {dir / "cam_params.json", dir.parent_path() / "cam_params.json"},
                          scene.kind, " and --depth-scale 6553.5",
                          [&](const fs::path& p) { return replica_intrinsics(p, scale); });
    }
    const fs::path traj = dir / "traj.txt";
    const std::vector<double> v = numbers_of(traj);
    if (v.size() % 16 != 0 || v.empty()) {
        throw FormatError(where(traj.string(), "expected a 4x4 camera-to-world matrix (16 numbers) a "
                                               "line; found " + std::to_string(v.size()) + " numbers"));
    }
    const auto depths = numbered_files(dir / "results", "depth", ".png");
    if (depths.size() != v.size() / 16) {
        throw FormatError(where(traj.string(), std::to_string(v.size() / 16) + " poses for " +
                                                   std::to_string(depths.size()) + " depth images in " +
                                                   (dir / "results").string()));
    }
    for (std::size_t i = 0; i < depths.size(); ++i) {
        const Pose pose = rigid(pose_at(v, 16 * i), traj, "line " + std::to_string(i + 1) + ": ");
        scene.frames.push_back(frame_of(depths[i].second, K, pose, scale, options));
        const std::string name = depths[i].second.filename().string();  // depthNNNNNN.png
        scene.frames.back().color_path =
            first_image(dir / "results" / ("frame" + name.substr(5, name.size() - 9)), {".jpg", ".png"});
    }
    return scene;
}

namespace {

/// Row-major 4x4 from a 3x4 of v starting at `at`.
Pose pose34(const std::vector<double>& v, std::size_t at) {
    Pose p{};
    for (std::size_t i = 0; i < 12; ++i) p[i] = v[at + i];
    p[15] = 1.0;
    return p;
}

Pose multiply(const Pose& a, const Pose& b) {
    Pose c{};
    for (int r = 0; r < 4; ++r) {
        for (int k = 0; k < 4; ++k) {
            double s = 0.0;
            for (int j = 0; j < 4; ++j) s += a[std::size_t(4 * r + j)] * b[std::size_t(4 * j + k)];
            c[std::size_t(4 * r + k)] = s;
        }
    }
    return c;
}

/// The inverse of a rigid transform (R^T, -R^T t).
Pose rigid_inverse(const Pose& m) {
    Pose r{};
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) r[std::size_t(4 * i + j)] = m[std::size_t(4 * j + i)];
        r[std::size_t(4 * i + 3)] = -(m[std::size_t(i)] * m[3] + m[std::size_t(4 + i)] * m[7] +
                                       m[std::size_t(8 + i)] * m[11]);
    }
    r[15] = 1.0;
    return r;
}

/// calib.txt's `Tr:` (or `Tr_velo_to_cam:`) as a 4x4.
Pose kitti_calibration(const fs::path& path) {
    std::istringstream in(read_file(path.string()));
    std::string line;
    while (std::getline(in, line)) {
        for (const std::string key : {"Tr:", "Tr_velo_to_cam:"}) {
            if (line.compare(0, key.size(), key) != 0) continue;
            const std::vector<double> v = numbers_in(line.substr(key.size()), path);
            if (v.size() != 12) {
                throw FormatError(where(path.string(), key + " needs 12 numbers (a 3x4 matrix), has " +
                                                           std::to_string(v.size())));
            }
            return rigid(pose34(v, 0), path, key + " ");
        }
    }
    throw FormatError(where(path.string(), "no 'Tr:' line (velodyne to camera 0)"));
}

}  // namespace

Scene read_kitti(const std::string& folder, const SceneOptions&) {
    const fs::path dir(folder);
    Scene scene;
    scene.kind = "KITTI";
    std::vector<fs::path> scans;
    std::error_code ec;
    for (const fs::directory_entry& e : fs::directory_iterator(dir / "velodyne", ec)) {
        const std::string x = e.path().extension().string();
        if (x == ".bin" || x == ".ply" || x == ".pcd") scans.push_back(e.path());
    }
    std::sort(scans.begin(), scans.end());
    const fs::path poses_path = dir / "poses.txt";
    const std::vector<double> v = numbers_of(poses_path);
    if (v.size() % 12 != 0 || v.empty()) {
        throw FormatError(where(poses_path.string(), "expected a 3x4 pose (12 numbers) a line; found " +
                                                         std::to_string(v.size()) + " numbers"));
    }
    if (v.size() / 12 < scans.size()) {
        throw FormatError(where(poses_path.string(), std::to_string(v.size() / 12) + " poses for " +
                                                         std::to_string(scans.size()) + " scans in " +
                                                         (dir / "velodyne").string()));
    }
    const bool calibrated = exists_file(dir / "calib.txt");
    Pose tr{}, tr_inv{};
    if (calibrated) {
        tr = kitti_calibration(dir / "calib.txt");
        tr_inv = rigid_inverse(tr);
    }
    for (std::size_t i = 0; i < scans.size(); ++i) {
        SceneFrame f;
        f.depth_path = scans[i].string();
        f.scan = true;
        const Pose p = rigid(pose34(v, 12 * i), poses_path, "line " + std::to_string(i + 1) + ": ");
        f.pose = calibrated ? multiply(tr_inv, multiply(p, tr)) : p;
        scene.frames.push_back(std::move(f));
    }
    require_frames(scene, dir, "velodyne/*.bin with poses.txt");
    return scene;
}

std::string detect_layout(const std::string& folder, std::string& log) {
    const fs::path dir(folder);
    if (exists_dir(dir / "velodyne") && exists_file(dir / "poses.txt")) return "kitti";
    if (!numbered_files(dir, "frame-", ".depth.png").empty()) return "7scenes";
    if (exists_dir(dir / "pose") && exists_dir(dir / "depth") && exists_dir(dir / "intrinsic")) {
        return "scannet";
    }
    if (exists_file(dir / "traj.txt") && exists_dir(dir / "results")) return "replica";
    if (exists_dir(dir / "depth")) {
        std::vector<fs::path> logs;
        std::error_code ec;
        for (const fs::directory_entry& e : fs::directory_iterator(dir, ec)) {
            if (e.path().extension() == ".log" && e.is_regular_file()) logs.push_back(e.path());
        }
        std::sort(logs.begin(), logs.end());
        if (logs.size() == 1) {
            log = logs.front().string();
            return "redwood";
        }
        if (logs.size() > 1) {
            throw FormatError(where(folder, "Redwood/Open3D: " + std::to_string(logs.size()) +
                                                " .log trajectories; give the folder one"));
        }
    }
    return "";
}

}  // namespace vdbrecon::detail
