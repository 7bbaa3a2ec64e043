// Posed depth images of known meshes (see depth_scenes.h).
#include "depth_scenes.h"

#include <sys/stat.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iomanip>
#include <random>
#include <sstream>

#include "vdbrecon/scene.h"

namespace vdbrecon::test {

namespace {

using V3 = std::array<double, 3>;

V3 normalize(const V3& a) {
    const double l = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    return {a[0] / l, a[1] / l, a[2] / l};
}
V3 cross(const V3& a, const V3& b) {
    return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

}  // namespace

DepthImage render_depth(const Mesh& mesh, const Intrinsics& K, const Pose& m) {
    DepthImage img;
    img.width = K.width;
    img.height = K.height;
    img.depth.assign(std::size_t(K.width) * std::size_t(K.height), 0.0f);
    std::vector<double> z(img.depth.size(), HUGE_VAL);
    // World to camera: R^T (x - t).
    auto to_camera = [&](const Vec3f& v) {
        const double p[3] = {double(v[0]) + mesh.origin[0] - m[3], double(v[1]) + mesh.origin[1] - m[7],
                             double(v[2]) + mesh.origin[2] - m[11]};
        return V3{m[0] * p[0] + m[4] * p[1] + m[8] * p[2], m[1] * p[0] + m[5] * p[1] + m[9] * p[2],
                  m[2] * p[0] + m[6] * p[1] + m[10] * p[2]};
    };
    for (const Triangle& t : mesh.faces) {
        V3 c[3];
        double sx[3], sy[3];
        bool front = true;
        for (int k = 0; k < 3; ++k) {
            c[k] = to_camera(mesh.vertices[std::size_t(t[std::size_t(k)])]);
            if (!(c[k][2] > 1e-6)) front = false;
            sx[k] = K.fx * c[k][0] / c[k][2] + K.cx;
            sy[k] = K.fy * c[k][1] / c[k][2] + K.cy;
        }
        if (!front) continue;  // the tests keep the whole object in front of the camera
        const double area = (sx[1] - sx[0]) * (sy[2] - sy[0]) - (sx[2] - sx[0]) * (sy[1] - sy[0]);
        if (area == 0.0) continue;
        const int x0 = std::max(0, int(std::ceil(std::min({sx[0], sx[1], sx[2]}))));
        const int x1 = std::min(K.width - 1, int(std::floor(std::max({sx[0], sx[1], sx[2]}))));
        const int y0 = std::max(0, int(std::ceil(std::min({sy[0], sy[1], sy[2]}))));
        const int y1 = std::min(K.height - 1, int(std::floor(std::max({sy[0], sy[1], sy[2]}))));
        for (int y = y0; y <= y1; ++y) {
            for (int x = x0; x <= x1; ++x) {
                double b[3];
                for (int k = 0; k < 3; ++k) {
                    const int i = (k + 1) % 3, j = (k + 2) % 3;
                    b[k] = ((sx[j] - sx[i]) * (y - sy[i]) - (sy[j] - sy[i]) * (x - sx[i])) / area;
                }
                if (b[0] < 0 || b[1] < 0 || b[2] < 0) continue;
                // 1/z is linear in screen space.
                const double inv = b[0] / c[0][2] + b[1] / c[1][2] + b[2] / c[2][2];
                const double d = 1.0 / inv;
                const std::size_t p = std::size_t(y) * std::size_t(K.width) + std::size_t(x);
                if (d < z[p]) z[p] = d;
            }
        }
    }
    for (std::size_t p = 0; p < z.size(); ++p) img.depth[p] = std::isfinite(z[p]) ? float(z[p]) : 0.0f;
    return img;
}

std::vector<Pose> orbit_poses(int count, const Vec3d& centre, double radius) {
    std::vector<Pose> poses;
    const double golden = M_PI * (3.0 - std::sqrt(5.0));
    for (int i = 0; i < count; ++i) {
        const double zc = 1.0 - 2.0 * (i + 0.5) / count, r = std::sqrt(1.0 - zc * zc);
        const V3 dir = {r * std::cos(golden * i), r * std::sin(golden * i), zc};
        const V3 eye = {centre[0] + radius * dir[0], centre[1] + radius * dir[1], centre[2] + radius * dir[2]};
        const V3 zc_axis = normalize({-dir[0], -dir[1], -dir[2]});  // looking at the centre
        const V3 up = std::fabs(zc_axis[2]) > 0.9 ? V3{0, 1, 0} : V3{0, 0, 1};
        const V3 x = normalize(cross(zc_axis, up));
        const V3 y = cross(zc_axis, x);
        poses.push_back({x[0], y[0], zc_axis[0], eye[0], x[1], y[1], zc_axis[1], eye[1],
                         x[2], y[2], zc_axis[2], eye[2], 0, 0, 0, 1});
    }
    return poses;
}

Intrinsics camera_intrinsics(int width, int height, double fov_degrees) {
    const double f = 0.5 * width / std::tan(0.5 * fov_degrees * M_PI / 180.0);
    return Intrinsics{f, f, 0.5 * width - 0.5, 0.5 * height - 0.5, width, height};
}

void add_depth_noise(DepthImage& depth, double sigma, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> noise(0.0, sigma);
    for (float& d : depth.depth) {
        if (d > 0.0f) d = float(double(d) + noise(rng));
    }
}

std::string write_transforms_scene(const std::string& dir, const std::vector<DepthImage>& depths,
                                   const Intrinsics& K, const std::vector<Pose>& poses,
                                   const std::string& ext, double units_per_metre) {
    std::ostringstream j;
    j.precision(17);
    // NeRF's principal point counts from the image corner: ours + 0.5.
    j << "{\n  \"fl_x\": " << K.fx << ", \"fl_y\": " << K.fy << ", \"cx\": " << K.cx + 0.5
      << ", \"cy\": " << K.cy + 0.5 << ", \"w\": " << K.width << ", \"h\": " << K.height
      << ",\n  \"depth_scale\": " << 1.0 / units_per_metre << ",\n  \"frames\": [\n";
    for (std::size_t i = 0; i < depths.size(); ++i) {
        const std::string name = "d_" + std::to_string(i) + "." + ext;
        write_depth_image(dir + "/" + name, depths[i], units_per_metre);
        Pose gl = poses[i];  // OpenCV to OpenGL camera axes: negate columns 1 and 2
        for (int r = 0; r < 3; ++r) gl[std::size_t(r * 4 + 1)] *= -1, gl[std::size_t(r * 4 + 2)] *= -1;
        j << "    {\"file_path\": \"./rgb_" << i << ".png\", \"depth_file_path\": \"./" << name
          << "\", \"transform_matrix\": [";
        for (int r = 0; r < 4; ++r) {
            j << (r ? ", " : "") << "[" << gl[std::size_t(r * 4)] << ", " << gl[std::size_t(r * 4 + 1)]
              << ", " << gl[std::size_t(r * 4 + 2)] << ", " << gl[std::size_t(r * 4 + 3)] << "]";
        }
        j << "]}" << (i + 1 < depths.size() ? "," : "") << "\n";
    }
    j << "  ]\n}\n";
    const std::string path = dir + "/transforms.json";
    std::ofstream(path) << j.str();
    return path;
}

std::string write_tum_scene(const std::string& dir, const std::vector<DepthImage>& depths,
                            const std::vector<Pose>& poses) {
    ::mkdir((dir + "/depth").c_str(), 0755);
    std::ostringstream list, gt;
    list.precision(17);
    gt.precision(17);
    list << "# depth maps\n# timestamp filename\n";
    gt << "# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n";
    for (std::size_t i = 0; i < depths.size(); ++i) {
        const double t = 1305031102.0 + 0.0333 * double(i);
        const std::string name = "depth/" + std::to_string(i) + ".png";
        write_depth_image(dir + "/" + name, depths[i], 5000.0);
        list << t << " " << name << "\n";
        const Pose& m = poses[i];
        // Rotation matrix to quaternion (Shepperd's method, largest diagonal first).
        double qw, qx, qy, qz;
        const double tr = m[0] + m[5] + m[10];
        if (tr > 0) {
            const double s = 2.0 * std::sqrt(tr + 1.0);
            qw = 0.25 * s, qx = (m[9] - m[6]) / s, qy = (m[2] - m[8]) / s, qz = (m[4] - m[1]) / s;
        } else if (m[0] > m[5] && m[0] > m[10]) {
            const double s = 2.0 * std::sqrt(1.0 + m[0] - m[5] - m[10]);
            qw = (m[9] - m[6]) / s, qx = 0.25 * s, qy = (m[1] + m[4]) / s, qz = (m[2] + m[8]) / s;
        } else if (m[5] > m[10]) {
            const double s = 2.0 * std::sqrt(1.0 + m[5] - m[0] - m[10]);
            qw = (m[2] - m[8]) / s, qx = (m[1] + m[4]) / s, qy = 0.25 * s, qz = (m[6] + m[9]) / s;
        } else {
            const double s = 2.0 * std::sqrt(1.0 + m[10] - m[0] - m[5]);
            qw = (m[4] - m[1]) / s, qx = (m[2] + m[8]) / s, qy = (m[6] + m[9]) / s, qz = 0.25 * s;
        }
        gt << t + 0.004 << " " << m[3] << " " << m[7] << " " << m[11] << " " << qx << " " << qy
           << " " << qz << " " << qw << "\n";
    }
    std::ofstream(dir + "/depth.txt") << list.str();
    std::ofstream(dir + "/groundtruth.txt") << gt.str();
    return dir;
}

}  // namespace vdbrecon::test

namespace vdbrecon::test {

namespace {

/// A 4x4 row-major matrix as four text lines.
std::string matrix_text(const Pose& m) {
    std::ostringstream s;
    s.precision(17);
    for (int r = 0; r < 4; ++r) {
        for (int c = 0; c < 4; ++c) s << (c ? " " : "") << m[std::size_t(r * 4 + c)];
        s << "\n";
    }
    return s.str();
}

/// The depth in millimetres as a dataset stores it, holes (0) kept, `none` where nothing was
/// seen (7-Scenes writes 65535 there).
DepthImage with_none(DepthImage d, float none_metres) {
    for (float& v : d.depth) {
        if (!(v > 0.0f)) v = none_metres;
    }
    return d;
}

std::string frame_number(std::size_t i, int width) {
    std::ostringstream s;
    s << std::setw(width) << std::setfill('0') << i;
    return s.str();
}

}  // namespace

Vec3f paint_pattern(const Vec3d& p, double s) {
    return Vec3f{float(0.5 + 0.4 * std::sin(p[0] / s)), float(0.5 + 0.4 * std::cos(p[1] / s)),
                 float(0.5 + 0.4 * std::sin(p[2] / s + 1.0))};
}

ColorImage render_color(const DepthImage& depth, const Intrinsics& K, const Pose& m,
                        const std::function<Vec3f(const Vec3d&)>& paint) {
    ColorImage c;
    c.width = depth.width;
    c.height = depth.height;
    c.rgb.assign(depth.depth.size(), Vec3f{0.0f, 0.0f, 0.0f});
    for (int v = 0; v < depth.height; ++v) {
        for (int u = 0; u < depth.width; ++u) {
            const double z = depth.at(u, v);
            if (!(z > 0.0)) continue;
            const double x = (u - K.cx) / K.fx * z, y = (v - K.cy) / K.fy * z;
            const Vec3d w{m[0] * x + m[1] * y + m[2] * z + m[3], m[4] * x + m[5] * y + m[6] * z + m[7],
                          m[8] * x + m[9] * y + m[10] * z + m[11]};
            c.rgb[std::size_t(v) * std::size_t(depth.width) + std::size_t(u)] = paint(w);
        }
    }
    return c;
}

std::string write_layout_scene(const std::string& layout, const std::string& dir,
                               const std::vector<DepthImage>& depths, const Intrinsics& K,
                               const std::vector<Pose>& poses,
                               const std::vector<ColorImage>* colors) {
    auto color = [&](std::size_t i, const std::string& path) {
        if (colors) write_color_image(path, (*colors)[i]);
    };
    std::ostringstream k;
    k.precision(17);
    if (layout == "7scenes") {
        k << K.fx << " 0 " << K.cx << "\n0 " << K.fy << " " << K.cy << "\n0 0 1\n";
        std::ofstream(dir + "/camera-intrinsics.txt") << k.str();
        for (std::size_t i = 0; i < depths.size(); ++i) {
            const std::string stem = dir + "/frame-" + frame_number(i, 6);
            write_depth_image(stem + ".depth.png", with_none(depths[i], 65.535f), 1000.0);
            color(i, stem + ".color.png");
            std::ofstream(stem + ".pose.txt") << matrix_text(poses[i]);
        }
    } else if (layout == "redwood") {
        ::mkdir((dir + "/depth").c_str(), 0755);
        ::mkdir((dir + "/color").c_str(), 0755);
        k << "{\"width\": " << K.width << ", \"height\": " << K.height
          << ", \"intrinsic_matrix\": [" << K.fx << ", 0, 0, 0, " << K.fy << ", 0, " << K.cx << ", "
          << K.cy << ", 1]}\n";
        std::ofstream(dir + "/camera_intrinsic.json") << k.str();
        std::ostringstream log;
        for (std::size_t i = 0; i < depths.size(); ++i) {
            write_depth_image(dir + "/depth/" + frame_number(i, 6) + ".png", depths[i], 1000.0);
            color(i, dir + "/color/" + frame_number(i, 6) + ".jpg");
            log << i << " " << i << " " << i + 1 << "\n" << matrix_text(poses[i]);
        }
        std::ofstream(dir + "/trajectory.log") << log.str();
    } else if (layout == "scannet") {
        for (const char* sub : {"/depth", "/pose", "/intrinsic", "/color"}) {
            ::mkdir((dir + sub).c_str(), 0755);
        }
        k << K.fx << " 0 " << K.cx << " 0\n0 " << K.fy << " " << K.cy << " 0\n0 0 1 0\n0 0 0 1\n";
        std::ofstream(dir + "/intrinsic/intrinsic_depth.txt") << k.str();
        std::ofstream(dir + "/intrinsic/intrinsic_color.txt") << k.str();
        for (std::size_t i = 0; i < depths.size(); ++i) {
            write_depth_image(dir + "/depth/" + std::to_string(i) + ".png", depths[i], 1000.0);
            color(i, dir + "/color/" + std::to_string(i) + ".jpg");
            std::ofstream(dir + "/pose/" + std::to_string(i) + ".txt") << matrix_text(poses[i]);
        }
    } else if (layout == "replica") {
        ::mkdir((dir + "/results").c_str(), 0755);
        k << "{\"camera\": {\"w\": " << K.width << ", \"h\": " << K.height << ", \"fx\": " << K.fx
          << ", \"fy\": " << K.fy << ", \"cx\": " << K.cx << ", \"cy\": " << K.cy
          << ", \"scale\": 6553.5}}\n";
        std::ofstream(dir + "/cam_params.json") << k.str();
        std::ostringstream traj;
        traj.precision(17);
        for (std::size_t i = 0; i < depths.size(); ++i) {
            write_depth_image(dir + "/results/depth" + frame_number(i, 6) + ".png", depths[i], 6553.5);
            color(i, dir + "/results/frame" + frame_number(i, 6) + ".jpg");
            for (std::size_t j = 0; j < 16; ++j) traj << (j ? " " : "") << poses[i][j];
            traj << "\n";
        }
        std::ofstream(dir + "/traj.txt") << traj.str();
    }
    return dir;
}

}  // namespace vdbrecon::test
