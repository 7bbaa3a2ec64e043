// Scenes of posed depth images: transforms.json and TUM RGB-D folders (see scene.h).
#include <sys/stat.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <sstream>

#include "detail/io_common.h"
#include "detail/io_pcd.h"
#include "detail/scene_layouts.h"
#include "vdbrecon/error.h"
#include "vdbrecon/io.h"
#include "vdbrecon/scene.h"

namespace vdbrecon {

namespace {

using Json = nlohmann::json;

bool is_file(const std::string& p) {
    struct stat st {};
    return ::stat(p.c_str(), &st) == 0 && S_ISREG(st.st_mode);
}
bool is_dir(const std::string& p) {
    struct stat st {};
    return ::stat(p.c_str(), &st) == 0 && S_ISDIR(st.st_mode);
}
std::string dir_of(const std::string& path) {
    const std::size_t slash = path.find_last_of('/');
    return slash == std::string::npos ? "." : path.substr(0, slash);
}
std::string join(const std::string& dir, const std::string& rel) {
    if (!rel.empty() && rel[0] == '/') return rel;
    std::string r = rel;
    while (r.rfind("./", 0) == 0) r = r.substr(2);
    return dir + "/" + r;
}

/// A number from a JSON object, or `fallback` when the key is absent; FormatError when the
/// value is not a finite number.
double number(const Json& obj, const char* key, double fallback, const std::string& path,
              const std::string& where) {
    auto it = obj.find(key);
    if (it == obj.end() || it->is_null()) return fallback;
    if (!it->is_number() || !std::isfinite(it->get<double>())) {
        throw FormatError(detail::where(path, where + "'" + key + "' is not a finite number"));
    }
    return it->get<double>();
}

/// An image size ("w", "h") in pixels, or `fallback` when the key is absent; FormatError when
/// it is not a whole number in 1..65536.
int image_side(const Json& obj, const char* key, int fallback, const std::string& path,
               const std::string& where) {
    const double v = number(obj, key, NAN, path, where);
    if (std::isnan(v)) return fallback;
    if (!(v >= 1.0 && v <= 65536.0 && v == std::floor(v))) {
        throw FormatError(detail::where(path, where + "'" + key + "' is " +
                                                  detail::format_number(v) +
                                                  ", not a positive number of pixels (a whole "
                                                  "number up to 65536)"));
    }
    return int(v);
}

/// The camera of a transforms.json object (the file's top level, or a frame overriding it).
Intrinsics camera(const Json& obj, const Intrinsics& base, const std::string& path,
                  const std::string& where) {
    Intrinsics K = base;
    K.width = image_side(obj, "w", K.width, path, where);
    K.height = image_side(obj, "h", K.height, path, where);
    for (const char* key : {"fl_x", "fl_y", "camera_angle_x", "camera_angle_y"}) {
        // Given, a focal length or field of view must be positive (absent: from another key),
        // and a field of view less than pi.
        const double v = number(obj, key, NAN, path, where);
        if (obj.contains(key) && !obj.at(key).is_null() && !(v > 0.0)) {
            throw FormatError(detail::where(path, where + "'" + key + "' is " +
                                                      detail::format_number(v) +
                                                      ", not a positive number"));
        }
        if (key[0] == 'c' && v >= M_PI) {
            throw FormatError(detail::where(path, where + "'" + key + "' is " +
                                                      detail::format_number(v) +
                                                      " radians, not a field of view below pi"));
        }
    }
    const double angle_x = number(obj, "camera_angle_x", NAN, path, where);
    const double angle_y = number(obj, "camera_angle_y", NAN, path, where);
    if (std::isfinite(angle_x) && K.width > 0) K.fx = K.fy = 0.5 * K.width / std::tan(0.5 * angle_x);
    if (std::isfinite(angle_y) && K.height > 0) K.fy = 0.5 * K.height / std::tan(0.5 * angle_y);
    K.fx = number(obj, "fl_x", K.fx, path, where);
    K.fy = number(obj, "fl_y", obj.contains("fl_x") && !obj.contains("fl_y") ? K.fx : K.fy, path, where);
    // Corner-based principal point (NeRF) to our pixel-centre one.
    const double cx = number(obj, "cx", NAN, path, where), cy = number(obj, "cy", NAN, path, where);
    if (std::isfinite(cx)) K.cx = cx - 0.5;
    if (std::isfinite(cy)) K.cy = cy - 0.5;
    return K;
}

/// A frame's colour image: file_path when it names an existing .png/.jpg (as given, or with
/// that extension added), other than the depth file; else "".
std::string color_file(const Json& frame, const std::string& dir, const std::string& depth) {
    auto it = frame.find("file_path");
    if (it == frame.end() || !it->is_string()) return "";
    const std::string p = join(dir, it->get<std::string>());
    const std::string ext = file_extension(p);
    if ((ext == "png" || ext == "jpg" || ext == "jpeg") && p != depth && is_file(p)) return p;
    if (!ext.empty() && ext != "png" && ext != "jpg" && ext != "jpeg") return "";
    for (const char* e : {".png", ".jpg", ".jpeg"}) {
        if (is_file(p + e) && p + e != depth) return p + e;
    }
    return "";
}

/// A frame's depth file: depth_file_path (or depth_path), else file_path plus a depth suffix.
std::string depth_file(const Json& frame, const std::string& dir, const std::string& path,
                       const std::string& where) {
    for (const char* key : {"depth_file_path", "depth_path"}) {
        auto it = frame.find(key);
        if (it == frame.end()) continue;
        if (!it->is_string()) throw FormatError(detail::where(path, where + "'" + key + "' is not a string"));
        std::string p = join(dir, it->get<std::string>());
        if (file_extension(p).empty()) {
            for (const char* ext : {".exr", ".png"}) {
                if (is_file(p + ext)) return p + ext;
            }
        }
        return p;
    }
    auto it = frame.find("file_path");
    if (it == frame.end() || !it->is_string()) {
        throw FormatError(detail::where(path, where + "has neither 'depth_file_path' nor 'file_path'"));
    }
    std::string stem = join(dir, it->get<std::string>());
    const std::string ext = file_extension(stem);
    if (!ext.empty()) stem = stem.substr(0, stem.size() - ext.size() - 1);
    const char* suffixes[] = {"_depth.exr", "_depth.png", "_depth_0001.exr", "_depth_0001.png", ".depth.exr"};
    for (const char* s : suffixes) {
        if (is_file(stem + s)) return stem + s;
    }
    throw IoError(detail::where(path, where + "no depth image beside '" +
                                          detail::printable(it->get<std::string>()) +
                                          "' (tried _depth.exr, _depth.png, _depth_0001.exr, "
                                          "_depth_0001.png, .depth.exr)"));
}

/// A 4x4 transform_matrix (OpenGL camera axes) as a camera-to-world pose in OpenCV axes.
Pose gl_pose(const Json& frame, const std::string& path, const std::string& where) {
    auto it = frame.find("transform_matrix");
    if (it == frame.end()) throw FormatError(detail::where(path, where + "has no 'transform_matrix'"));
    const Json& m = *it;
    Pose pose{};
    bool ok = m.is_array() && m.size() == 4;
    for (std::size_t r = 0; ok && r < 4; ++r) {
        ok = m[r].is_array() && m[r].size() == 4;
        for (std::size_t c = 0; ok && c < 4; ++c) {
            ok = m[r][c].is_number();
            if (ok) pose[r * 4 + c] = m[r][c].get<double>();
        }
    }
    if (!ok) throw FormatError(detail::where(path, where + "'transform_matrix' is not 4x4 numbers"));
    // OpenGL (y up, looking down -z) to OpenCV (y down, looking down +z): negate columns 1, 2.
    for (std::size_t r = 0; r < 3; ++r) {
        pose[r * 4 + 1] = -pose[r * 4 + 1];
        pose[r * 4 + 2] = -pose[r * 4 + 2];
    }
    try {
        validate_pose(pose);
    } catch (const InvalidArgument& e) {
        throw FormatError(detail::where(path, where + e.what()));
    }
    return pose;
}

Scene read_transforms(const std::string& path, const SceneOptions& options) {
    Json doc;
    try {
        doc = Json::parse(detail::read_file(path));
    } catch (const Json::exception& e) {
        throw FormatError(detail::where(path, std::string("not valid JSON: ") + detail::printable(e.what())));
    }
    if (!doc.is_object()) throw FormatError(detail::where(path, "the top level is not a JSON object"));
    auto frames = doc.find("frames");
    if (frames == doc.end() || !frames->is_array() || frames->empty()) {
        throw FormatError(detail::where(path, "no 'frames' (a non-empty array)"));
    }
    const Intrinsics base = camera(doc, Intrinsics{NAN, NAN, NAN, NAN, 0, 0}, path, "");
    double metres_per_unit = number(doc, "depth_scale", NAN, path, "");
    metres_per_unit = number(doc, "integer_depth_scale", metres_per_unit, path, "");
    if (std::isfinite(metres_per_unit) && !(metres_per_unit > 0.0)) {
        throw FormatError(detail::where(path, "'depth_scale' must be positive (metres per unit)"));
    }
    Scene scene;
    scene.kind = "transforms.json";
    const std::string dir = dir_of(path);
    ImageSize sized;  // the first image's, for a field of view without a size
    for (std::size_t i = 0; i < frames->size(); ++i) {
        const Json& f = (*frames)[i];
        const std::string where = "frame " + std::to_string(i) + ": ";
        if (!f.is_object()) throw FormatError(detail::where(path, where + "is not a JSON object"));
        SceneFrame frame;
        frame.depth_path = depth_file(f, dir, path, where);
        frame.color_path = color_file(f, dir, frame.depth_path);
        frame.pose = gl_pose(f, path, where);
        frame.intrinsics = options.intrinsics ? *options.intrinsics : camera(f, base, path, where);
        frame.units_per_metre = options.units_per_metre > 0.0 ? options.units_per_metre
                                : std::isfinite(metres_per_unit) ? 1.0 / metres_per_unit
                                                                 : 1000.0;
        if (!options.intrinsics && frame.intrinsics.width == 0 && !(frame.intrinsics.fx > 0.0) &&
            (f.contains("camera_angle_x") || doc.contains("camera_angle_x"))) {
            // NeRF's synthetic scenes give the field of view and no size: the focal length
            // comes from the size of the first frame's image (read once).
            if (sized.width == 0) {
                const DepthImage img = read_depth_image(frame.depth_path, frame.units_per_metre);
                sized = ImageSize{img.width, img.height};
            }
            const Intrinsics size_only{NAN, NAN, NAN, NAN, sized.width, sized.height};
            frame.intrinsics = camera(f, camera(doc, size_only, path, ""), path, where);
        }
        const Intrinsics& K = frame.intrinsics;
        if (!(std::isfinite(K.fx) && K.fx > 0.0 && std::isfinite(K.fy) && K.fy > 0.0)) {
            throw FormatError(detail::where(path, where + "no focal length (fl_x or camera_angle_x)"));
        }
        if ((K.width == 0) != (K.height == 0)) {
            throw FormatError(detail::where(path, where + "'w' and 'h' go together (or neither: "
                                                          "the image's size)"));
        }
        scene.frames.push_back(std::move(frame));
    }
    return scene;
}

/// TUM's "timestamp rest" lines (# comments), in file order.
std::vector<std::pair<double, std::string>> tum_lines(const std::string& path) {
    const std::string text = detail::read_file(path);
    std::vector<std::pair<double, std::string>> out;
    std::istringstream in(text);
    std::string line;
    std::size_t number = 0;
    while (std::getline(in, line)) {
        ++number;
        if (line.empty() || line[0] == '#' || line.find_first_not_of(" \t\r") == std::string::npos) continue;
        std::istringstream l(line);
        double t = NAN;
        std::string rest;
        l >> t;
        std::getline(l, rest);
        const std::size_t a = rest.find_first_not_of(" \t"), b = rest.find_last_not_of(" \t\r");
        if (!std::isfinite(t) || a == std::string::npos) {
            throw FormatError(detail::where(path, "line " + std::to_string(number) +
                                                      ": expected 'timestamp ...', got '" +
                                                      detail::printable(line) + "'"));
        }
        out.push_back({t, rest.substr(a, b - a + 1)});
    }
    if (out.empty()) throw FormatError(detail::where(path, "no entries"));
    return out;
}

/// The rotation matrix (row-major) of a unit quaternion.
std::array<double, 9> quaternion_rotation(double x, double y, double z, double w) {
    return {1 - 2 * (y * y + z * z), 2 * (x * y - z * w),     2 * (x * z + y * w),
            2 * (x * y + z * w),     1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w),     2 * (y * z + x * w),     1 - 2 * (x * x + y * y)};
}

/// Camera-to-world from TUM's tx ty tz qx qy qz qw.
Pose tum_pose(const std::string& values, const std::string& path, double t) {
    std::istringstream in(values);
    double v[7];
    for (double& x : v) {
        if (!(in >> x) || !std::isfinite(x)) {
            std::ostringstream s;
            s.precision(17);
            s << "pose at " << t << ": expected tx ty tz qx qy qz qw";
            throw FormatError(detail::where(path, s.str()));
        }
    }
    const double x = v[3], y = v[4], z = v[5], w = v[6];
    const double n = std::sqrt(x * x + y * y + z * z + w * w);
    if (!(std::fabs(n - 1.0) < 1e-2)) {
        std::ostringstream s;
        s.precision(17);
        s << "pose at " << t << ": the quaternion has length " << n << ", not 1";
        throw FormatError(detail::where(path, s.str()));
    }
    const std::array<double, 9> r = quaternion_rotation(x / n, y / n, z / n, w / n);
    return {r[0], r[1], r[2], v[0], r[3], r[4], r[5], v[1], r[6], r[7], r[8], v[2], 0, 0, 0, 1};
}

Scene read_tum(const std::string& depth_txt, const SceneOptions& options) {
    const std::string dir = dir_of(depth_txt);
    const std::string gt_path = dir + "/groundtruth.txt";
    if (!options.intrinsics) {
        throw InvalidArgument(detail::where(depth_txt, "a TUM scene needs the intrinsics: "
                                                       "--intrinsics fx,fy,cx,cy (the TUM default "
                                                       "is 525,525,319.5,239.5)"));
    }
    const auto depth = tum_lines(depth_txt);
    const auto gt = tum_lines(gt_path);
    // The colour images (rgb.txt), by time: the nearest within 0.02 s goes with a depth frame.
    std::vector<std::pair<double, std::string>> rgb;
    if (is_file(dir + "/rgb.txt")) rgb = tum_lines(dir + "/rgb.txt");
    std::sort(rgb.begin(), rgb.end());
    const auto nearest_rgb = [&](const std::vector<std::pair<double, std::string>>& list, double t) {
        auto c = std::lower_bound(list.begin(), list.end(), std::make_pair(t, std::string()));
        std::string best;
        double gap = 0.02;
        for (auto x : {c, c == list.begin() ? c : c - 1}) {
            if (x == list.end()) continue;
            if (std::fabs(x->first - t) <= gap) gap = std::fabs(x->first - t), best = join(dir, x->second);
        }
        return best;
    };
    std::vector<std::size_t> order(gt.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::stable_sort(order.begin(), order.end(),
                     [&](std::size_t a, std::size_t b) { return gt[a].first < gt[b].first; });
    Scene scene;
    scene.kind = "tum";
    for (const auto& [t, file] : depth) {
        // The nearest ground-truth timestamp, within 0.02 s (TUM's associate.py).
        auto it = std::lower_bound(order.begin(), order.end(), t,
                                   [&](std::size_t i, double v) { return gt[i].first < v; });
        std::size_t best = gt.size();
        double gap = 0.02;
        for (auto c : {it, it == order.begin() ? it : it - 1}) {
            if (c == order.end()) continue;
            const double d = std::fabs(gt[*c].first - t);
            if (d <= gap) gap = d, best = *c;
        }
        if (best == gt.size()) continue;  // no pose for this frame
        SceneFrame frame;
        frame.depth_path = join(dir, file);
        frame.color_path = nearest_rgb(rgb, t);
        frame.pose = tum_pose(gt[best].second, gt_path, gt[best].first);
        frame.intrinsics = *options.intrinsics;
        frame.units_per_metre = options.units_per_metre > 0.0 ? options.units_per_metre : 5000.0;
        scene.frames.push_back(std::move(frame));
    }
    if (scene.frames.empty()) {
        throw FormatError(detail::where(depth_txt, "no depth frame has a ground-truth pose within "
                                                   "0.02 s in " + gt_path));
    }
    return scene;
}

}  // namespace

ScanSensors read_scan_sensors(const std::string& path) {
    const std::string text = detail::read_file(path);
    const bool conf = file_extension(path) == "conf";
    ScanSensors out;
    std::istringstream in(text);
    std::string line;
    std::size_t number = 0;
    while (std::getline(in, line)) {
        ++number;
        std::istringstream l(line);
        std::string first;
        if (!(l >> first) || first[0] == '#') continue;
        auto bad = [&](const std::string& what) {
            return FormatError(detail::where(path, "line " + std::to_string(number) + ": " + what));
        };
        if (conf) {
            if (first != "bmesh") continue;  // camera, mesh, ... lines
            std::string file;
            double v[7];
            l >> file;
            for (double& x : v) {
                if (!(l >> x) || !std::isfinite(x)) throw bad("expected 'bmesh FILE tx ty tz qx qy qz qw'");
            }
            const double n = std::sqrt(v[3] * v[3] + v[4] * v[4] + v[5] * v[5] + v[6] * v[6]);
            if (!(std::fabs(n - 1.0) < 1e-2)) throw bad("the quaternion is not of unit length");
            // world = R(q)^T p + t, the scanner looking along +z of the scan: R(q)^T e_z, the
            // third row of R(q).
            const std::array<double, 9> r = quaternion_rotation(v[3] / n, v[4] / n, v[5] / n, v[6] / n);
            out.directions.push_back({r[6], r[7], r[8]});
        } else {
            double v[3];
            std::istringstream row(line);
            for (double& x : v) {
                if (!(row >> x) || !std::isfinite(x)) throw bad("expected 'x y z' (a scan's sensor position)");
            }
            out.origins.push_back({v[0], v[1], v[2]});
        }
    }
    if (out.size() == 0) throw FormatError(detail::where(path, "no scan sensors"));
    return out;
}

OrganizedCloud read_organized_cloud(const std::string& path) {
    const std::string content = detail::read_file(path);
    detail::PcdData pcd = detail::read_pcd(path, content);
    if (pcd.height <= 1) {
        throw FormatError(detail::where(path, "not an organized cloud (HEIGHT is 1): fuse needs the "
                                              "sensor's raster; reconstruct it as a point file"));
    }
    OrganizedCloud c;
    c.width = int(pcd.width);
    c.height = int(pcd.height);
    const std::size_t n = pcd.raw.rows();
    // A local frame at the box centre of the finite points (georeferenced clouds keep float
    // precision), as the point readers choose.
    std::vector<double> finite;
    for (std::size_t i = 0; i < n; ++i) {
        const double* x = &pcd.raw.xyz[3 * i];
        if (std::isfinite(x[0]) && std::isfinite(x[1]) && std::isfinite(x[2])) finite.insert(finite.end(), x, x + 3);
    }
    if (finite.empty()) throw FormatError(detail::where(path, "no finite point"));
    c.origin = detail::choose_origin(finite.data(), finite.size() / 3);
    c.points.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
        for (int a = 0; a < 3; ++a) {
            c.points[i][std::size_t(a)] = float(pcd.raw.xyz[3 * i + std::size_t(a)] - c.origin[std::size_t(a)]);
        }
    }
    if (pcd.viewpoint) c.sensor = {(*pcd.viewpoint)[0], (*pcd.viewpoint)[1], (*pcd.viewpoint)[2]};
    if (pcd.raw.colors.size() == n) c.colors = std::move(pcd.raw.colors);
    return c;
}

std::vector<Vec3f> read_kitti_scan(const std::string& path) {
    const std::string bytes = detail::read_file(path);
    constexpr std::size_t kPoint = 4 * sizeof(float);  // x y z intensity
    if (bytes.size() % kPoint != 0) {
        throw FormatError(detail::where(path,
                                        "a KITTI scan is float32 x y z intensity (16 bytes a "
                                        "point); the file's " +
                                            std::to_string(bytes.size()) + " bytes are not"));
    }
    std::vector<Vec3f> points(bytes.size() / kPoint);
    for (std::size_t i = 0; i < points.size(); ++i) {
        std::memcpy(points[i].data(), bytes.data() + i * kPoint, sizeof(Vec3f));
    }
    return points;
}

Scene read_scene(const std::string& path, const SceneOptions& options) {
    if (options.intrinsics) {  // its size may be left to the images
        Intrinsics K = *options.intrinsics;
        if (K.width == 0 && K.height == 0) K.width = K.height = 1;
        K.validate();
    }
    if (is_dir(path)) {
        if (is_file(path + "/transforms.json")) return read_transforms(path + "/transforms.json", options);
        if (is_file(path + "/depth.txt")) return read_tum(path + "/depth.txt", options);
        std::string log;
        const std::string layout = detail::detect_layout(path, log);
        if (layout == "7scenes") return detail::read_7scenes(path, options);
        if (layout == "redwood") return detail::read_redwood(path, log, options);
        if (layout == "scannet") return detail::read_scannet(path, options);
        if (layout == "replica") return detail::read_replica(path, options);
        if (layout == "kitti") return detail::read_kitti(path, options);
        throw FormatError(detail::where(
            path, "not a scene folder: looked for transforms.json, depth.txt (TUM), "
                  "frame-NNNNNN.depth.png (7-Scenes/3DMatch), a .log and depth/ (Redwood/Open3D), "
                  "pose/ depth/ intrinsic/ (ScanNet), traj.txt and results/ (Replica), "
                  "velodyne/ and poses.txt (KITTI)"));
    }
    const std::string ext = file_extension(path);
    if (ext == "json") return read_transforms(path, options);
    if (ext == "pcd") {
        Scene scene;
        scene.kind = "organized pcd";
        SceneFrame frame;
        frame.depth_path = path;
        frame.organized = true;
        scene.frames.push_back(frame);
        return scene;
    }
    if (ext == "txt") return read_tum(path, options);
    if (!is_file(path)) throw IoError(detail::where(path, "no such file or folder"));
    throw FormatError(detail::where(path, "not a scene: expected a transforms.json, or a TUM "
                                          "RGB-D folder or its depth.txt"));
}

}  // namespace vdbrecon
