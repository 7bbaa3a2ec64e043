// Preview pictures (see preview.h): a small z-buffer rasteriser, PNG through detail/png.h, EXR through
// OpenEXR.
#include "vdbrecon/preview.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfOutputFile.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "detail/io_common.h"
#include "detail/mesh_graph.h"
#include "detail/png.h"
#include "detail/vec3.h"
#include "vdbrecon/error.h"
#include "vdbrecon/io.h"

namespace vdbrecon {

void PreviewOptions::validate() const {
    if (width < 16 || width > 16384 || height < 16 || height > 16384) {
        throw InvalidArgument("preview: " + std::to_string(width) + "x" + std::to_string(height) +
                              " pixels: width and height must be in 16..16384");
    }
    if (!(fov_degrees >= 5.0 && fov_degrees <= 120.0)) {
        throw InvalidArgument("preview.fov_degrees = " + std::to_string(fov_degrees) +
                              ": must be in 5..120");
    }
}

namespace {

using detail::add;
using detail::cross;
using detail::dot;
using detail::mul;
using detail::sub;
using detail::unit;
using detail::V3;
V3 v3(const Vec3f& p) { return detail::widen(p); }

double srgb_to_linear(double c) {
    return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
}
double linear_to_srgb(double c) {
    c = std::clamp(c, 0.0, 1.0);
    return c <= 0.0031308 ? 12.92 * c : 1.055 * std::pow(c, 1.0 / 2.4) - 0.055;
}

/// Per-corner shading normals with an angle threshold (as 3D tools' "auto smooth"): the
/// area-weighted mean of the face normals around the corner's vertex that are within 30 degrees
/// of the corner's face.
class AutoSmooth {
  public:
    explicit AutoSmooth(const Mesh& mesh)
        : around_(detail::vertex_faces(mesh.faces, mesh.vertices.size())) {
        normals_.resize(mesh.faces.size());
        for (std::size_t f = 0; f < normals_.size(); ++f) {
            const Triangle& t = mesh.faces[f];
            const V3 a = v3(mesh.vertices[std::size_t(t[0])]);
            normals_[f] = cross(sub(v3(mesh.vertices[std::size_t(t[1])]), a),
                                sub(v3(mesh.vertices[std::size_t(t[2])]), a));
        }
    }
    V3 corner(std::size_t v, const V3& face_n) const {
        V3 sum{0, 0, 0};
        for (std::size_t j = around_.first[v]; j < around_.first[v + 1]; ++j) {
            const V3& n = normals_[std::size_t(around_.around[j])];
            const double len = std::sqrt(dot(n, n));
            if (len > 0.0 && dot(n, face_n) > 0.866 * len) sum = add(sum, n);
        }
        return dot(sum, sum) > 0.0 ? unit(sum) : face_n;
    }

  private:
    detail::VertexFaces around_;
    std::vector<V3> normals_;  // unnormalised: area-weighted
};

struct Camera {
    V3 eye, right, up, forward;
    double focal = 1.0;  // pixels
    double cx = 0.0, cy = 0.0;
};

Camera frame_mesh(const Mesh& mesh, int w, int h, double fov_degrees) {
    // The box from the 0.5 and 99.5 percentiles of each coordinate: a few stray fragments far
    // away do not shrink the object to a dot.
    V3 lo, hi;
    std::vector<float> coord(mesh.vertices.size());
    for (int a = 0; a < 3; ++a) {
        for (std::size_t i = 0; i < coord.size(); ++i) coord[i] = mesh.vertices[i][a];
        const std::size_t k0 = coord.size() / 200, k1 = coord.size() - 1 - coord.size() / 200;
        std::nth_element(coord.begin(), coord.begin() + std::ptrdiff_t(k0), coord.end());
        lo[a] = coord[k0];
        std::nth_element(coord.begin(), coord.begin() + std::ptrdiff_t(k1), coord.end());
        hi[a] = coord[k1];
    }
    V3 normal_sum{0, 0, 0};
    double area = 0.0;
    for (const Triangle& t : mesh.faces) {
        const V3 a = v3(mesh.vertices[std::size_t(t[0])]), b = v3(mesh.vertices[std::size_t(t[1])]),
                 c = v3(mesh.vertices[std::size_t(t[2])]);
        const V3 n = cross(sub(b, a), sub(c, a));  // twice the area, outward
        normal_sum = add(normal_sum, n);
        area += std::sqrt(dot(n, n));
    }
    const V3 centre = mul(add(lo, hi), 0.5);
    const double radius = std::max(0.5 * std::sqrt(dot(sub(hi, lo), sub(hi, lo))), 1e-12);
    // Open scans: from the side their normals face. Closed shapes: front and a little above.
    V3 dir = std::sqrt(dot(normal_sum, normal_sum)) > 0.3 * area ? unit(normal_sum)
                                                                 : unit(V3{0.35, 0.45, 1.0});
    V3 world_up{0, 1, 0};
    if (std::fabs(dot(dir, world_up)) > 0.95) world_up = {0, 0, 1};
    const double half_fov = 0.5 * fov_degrees * M_PI / 180.0;
    Camera c;
    c.forward = mul(dir, -1.0);
    c.right = unit(cross(c.forward, world_up));
    c.up = cross(c.right, c.forward);
    // The nearest eye distance at which each vertex is in the picture; the 99.5th percentile of
    // those (stray fragments aside) plus a margin frames the object.
    const double ty = std::tan(half_fov), tx = ty * double(w) / double(h);
    std::vector<double> need(mesh.vertices.size());
    for (std::size_t i = 0; i < need.size(); ++i) {
        const V3 rel = sub(v3(mesh.vertices[i]), centre);
        need[i] = std::max(std::fabs(dot(rel, c.right)) / tx, std::fabs(dot(rel, c.up)) / ty) -
                  dot(rel, c.forward);
    }
    const std::size_t k = need.size() - 1 - need.size() / 200;
    std::nth_element(need.begin(), need.begin() + std::ptrdiff_t(k), need.end());
    const double dist = std::max(need[k] * 1.08, 1e-3 * radius);
    c.eye = add(centre, mul(dir, dist));
    c.focal = 0.5 * h / std::tan(half_fov);
    c.cx = 0.5 * w;
    c.cy = 0.5 * h;
    return c;
}

}  // namespace

Image render_preview(const Mesh& mesh, const PreviewOptions& options) {
    options.validate();
    if (mesh.faces.empty()) throw InvalidArgument("preview: the mesh has no faces");
    constexpr int ss = 2;  // supersampling per axis
    const int W = options.width * ss, H = options.height * ss;
    const Camera cam = frame_mesh(mesh, W, H, options.fov_degrees);

    // Vertices in camera space: x right, y up, z along the view (> 0 in front).
    const std::size_t nv = mesh.vertices.size();
    std::vector<V3> proj(nv);  // pixel x, pixel y, depth
    for (std::size_t i = 0; i < nv; ++i) {
        const V3 d = sub(v3(mesh.vertices[i]), cam.eye);
        const double z = dot(d, cam.forward);
        proj[i] = {cam.cx + cam.focal * dot(d, cam.right) / z,
                   cam.cy - cam.focal * dot(d, cam.up) / z, z};
    }
    const bool colours = mesh.colors.size() == nv;
    std::vector<V3> base(colours ? nv : 0);
    for (std::size_t i = 0; i < base.size(); ++i) {
        for (int a = 0; a < 3; ++a) base[i][a] = srgb_to_linear(std::clamp(double(mesh.colors[i][a]), 0.0, 1.0));
    }
    const V3 clay{0.55, 0.58, 0.62}, back_tint{0.85, 0.42, 0.18};
    const V3 key = unit(add(add(mul(cam.right, -0.5), mul(cam.up, 0.7)), mul(cam.forward, -0.6)));
    const V3 fill = unit(add(mul(cam.right, 0.6), mul(cam.forward, -0.8)));

    const AutoSmooth smooth(mesh);
    const float inf = std::numeric_limits<float>::infinity();
    std::vector<float> zbuf(std::size_t(W) * std::size_t(H), inf);
    std::vector<float> col(std::size_t(W) * std::size_t(H) * 3, 0.0f);
    for (const Triangle& t : mesh.faces) {
        const std::size_t i0 = std::size_t(t[0]), i1 = std::size_t(t[1]), i2 = std::size_t(t[2]);
        const V3 &a = proj[i0], &b = proj[i1], &c = proj[i2];
        if (!(a[2] > 0.0 && b[2] > 0.0 && c[2] > 0.0)) continue;  // behind the eye (never, framed)
        const double area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        if (area == 0.0) continue;
        const int x0 = std::max(0, int(std::ceil(std::min({a[0], b[0], c[0]}) - 0.5)));
        const int x1 = std::min(W - 1, int(std::floor(std::max({a[0], b[0], c[0]}) - 0.5)));
        const int y0 = std::max(0, int(std::ceil(std::min({a[1], b[1], c[1]}) - 0.5)));
        const int y1 = std::min(H - 1, int(std::floor(std::max({a[1], b[1], c[1]}) - 0.5)));
        if (x0 > x1 || y0 > y1) continue;
        const V3 pa = v3(mesh.vertices[i0]), pb = v3(mesh.vertices[i1]), pc = v3(mesh.vertices[i2]);
        const V3 face_n = unit(cross(sub(pb, pa), sub(pc, pa)));
        // Seen from its back: the camera is on the inner side of the triangle's plane.
        const bool back = dot(face_n, sub(cam.eye, pa)) < 0.0;
        // Auto-smooth shading: each corner shades with the normal of the faces around its
        // vertex that are within 30 degrees of this one, so that sharp edges look as sharp as
        // the mesh is (vertex normals blend the two faces of an edge).
        V3 corner_n[3];
        const std::size_t ids[3] = {i0, i1, i2};
        for (int k = 0; k < 3; ++k) corner_n[k] = smooth.corner(ids[k], face_n);
        for (int y = y0; y <= y1; ++y) {
            for (int x = x0; x <= x1; ++x) {
                const double px = x + 0.5, py = y + 0.5;
                // Barycentric weights from edge functions (screen space).
                double w0 = ((b[0] - px) * (c[1] - py) - (b[1] - py) * (c[0] - px)) / area;
                double w1 = ((c[0] - px) * (a[1] - py) - (c[1] - py) * (a[0] - px)) / area;
                double w2 = 1.0 - w0 - w1;
                if (w0 < 0.0 || w1 < 0.0 || w2 < 0.0) continue;
                // Perspective-correct: 1/z is affine in screen space.
                const double iz = w0 / a[2] + w1 / b[2] + w2 / c[2];
                const double z = 1.0 / iz;
                const std::size_t k = std::size_t(y) * std::size_t(W) + std::size_t(x);
                if (!(z < zbuf[k])) continue;
                zbuf[k] = float(z);
                w0 *= z / a[2];
                w1 *= z / b[2];
                w2 = 1.0 - w0 - w1;
                const V3 n0 = unit(add(add(mul(corner_n[0], w0), mul(corner_n[1], w1)),
                                       mul(corner_n[2], w2)));
                V3 n = n0;
                V3 albedo = colours ? add(add(mul(base[i0], w0), mul(base[i1], w1)), mul(base[i2], w2))
                                    : clay;
                if (back) {
                    n = mul(n, -1.0);
                    albedo = {albedo[0] * back_tint[0], albedo[1] * back_tint[1],
                              albedo[2] * back_tint[2]};
                }
                const double light = 0.12 + 0.75 * std::max(0.0, dot(n, key)) +
                                     0.25 * std::max(0.0, dot(n, fill));
                for (int ch = 0; ch < 3; ++ch) col[k * 3 + std::size_t(ch)] = float(albedo[ch] * light);
            }
        }
    }

    // Downsample: box filter for colour and coverage, nearest surface for depth.
    Image img;
    img.width = options.width;
    img.height = options.height;
    const std::size_t n = std::size_t(img.width) * std::size_t(img.height);
    img.rgb.assign(n * 3, 0.0f);
    img.alpha.assign(n, 0.0f);
    img.depth.assign(n, inf);
    for (int y = 0; y < img.height; ++y) {
        for (int x = 0; x < img.width; ++x) {
            const std::size_t o = std::size_t(y) * std::size_t(img.width) + std::size_t(x);
            for (int sy = 0; sy < ss; ++sy) {
                for (int sx = 0; sx < ss; ++sx) {
                    const std::size_t k = std::size_t(y * ss + sy) * std::size_t(W) + std::size_t(x * ss + sx);
                    if (zbuf[k] == inf) continue;
                    img.alpha[o] += 1.0f / (ss * ss);
                    img.depth[o] = std::min(img.depth[o], zbuf[k]);
                    for (int ch = 0; ch < 3; ++ch) img.rgb[o * 3 + std::size_t(ch)] += col[k * 3 + std::size_t(ch)] / (ss * ss);
                }
            }
        }
    }
    return img;
}

namespace {

/// 8-bit RGB PNG over a light background (the picture in the README).
void write_png(const std::string& path, const Image& img) {
    const double background = 0.92;  // sRGB-encoded grey
    const double bg_lin = srgb_to_linear(background);
    std::vector<std::uint8_t> rgb(std::size_t(img.height) * std::size_t(img.width) * 3);
    for (std::size_t o = 0; o < std::size_t(img.height) * std::size_t(img.width); ++o) {
        const double a = img.alpha[o];
        for (std::size_t ch = 0; ch < 3; ++ch) {
            const double c = img.rgb[o * 3 + ch] + (1.0 - a) * bg_lin;
            rgb[o * 3 + ch] = std::uint8_t(std::lround(255.0 * linear_to_srgb(c)));
        }
    }
    detail::write_png_rgb8(path, img.width, img.height, rgb.data());
}

/// Linear float R, G, B, A and Z (depth, world units; +inf on the background).
void write_exr(const std::string& path, const Image& img) {
    detail::AtomicFile file(path);
    file.create();
    try {
        Imf::Header header(img.width, img.height);
        const char* names[] = {"R", "G", "B", "A", "Z"};
        for (const char* c : names) header.channels().insert(c, Imf::Channel(Imf::FLOAT));
        Imf::OutputFile out(file.temp_path().c_str(), header);
        Imf::FrameBuffer fb;
        const std::size_t px = sizeof(float), row = px * std::size_t(img.width);
        auto* rgb = const_cast<char*>(reinterpret_cast<const char*>(img.rgb.data()));
        for (int ch = 0; ch < 3; ++ch) {
            fb.insert(names[ch], Imf::Slice(Imf::FLOAT, rgb + std::size_t(ch) * px, 3 * px, 3 * row));
        }
        fb.insert("A", Imf::Slice(Imf::FLOAT, const_cast<char*>(reinterpret_cast<const char*>(img.alpha.data())), px, row));
        fb.insert("Z", Imf::Slice(Imf::FLOAT, const_cast<char*>(reinterpret_cast<const char*>(img.depth.data())), px, row));
        out.setFrameBuffer(fb);
        out.writePixels(img.height);
    } catch (const std::exception& e) {
        throw IoError(detail::where(path, std::string("cannot write the EXR file: ") + e.what()));
    }
    file.commit();
}

}  // namespace

void check_image_path(const std::string& path) {
    const std::string ext = file_extension(path);
    if (ext != "png" && ext != "exr") {
        throw InvalidArgument("preview '" + path + "': unknown image extension (use .png or .exr)");
    }
}

void write_image(const std::string& path, const Image& image) {
    check_image_path(path);
    if (file_extension(path) == "png") {
        write_png(path, image);
    } else {
        write_exr(path, image);
    }
}

}  // namespace vdbrecon
