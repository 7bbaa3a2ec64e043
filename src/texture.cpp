// Textures for planar regions (see texture.h).
#include "vdbrecon/texture.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cstdint>
#include <cmath>
#include <limits>
#include <sstream>

#include "detail/io_common.h"
#include "detail/png.h"
#include "detail/vec3.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/log.h"

namespace vdbrecon {

void TextureOptions::validate() const {
    if (!(std::isfinite(texel) && texel >= 0.0)) {
        throw InvalidArgument("texture.texel must be a length >= 0 (world units; 0 = half a voxel)");
    }
    if (!(std::isfinite(max_distance) && max_distance > 0.0 && max_distance <= 100.0)) {
        throw InvalidArgument("texture.max_distance must be in (0, 100] voxels");
    }
    if (!(std::isfinite(splat_sigma) && splat_sigma >= 0.1 && splat_sigma <= 16.0)) {
        throw InvalidArgument("texture.splat_sigma must be in [0.1, 16] texels");
    }
    if (padding < 0 || padding > 64) {
        throw InvalidArgument("texture.padding must be in 0..64 texels");
    }
    if (max_size < 16 || max_size > 32768) {
        throw InvalidArgument("texture.max_size must be in 16..32768 texels");
    }
}

namespace {

using detail::cross;
using detail::dot;
using detail::unit;
using detail::V3;
V3 v3(const Vec3f& p) { return detail::widen(p); }

/// Faces or vertices grouped by region, in index order: items of region r are
/// items[start[r] .. start[r + 1]).
struct Groups {
    std::vector<std::size_t> start;
    std::vector<std::int32_t> items;
};

/// Groups 0..owner.size() by owner (-1: none), keeping index order within a group.
Groups group_by(Span<std::int32_t> owner, std::size_t groups) {
    Groups g;
    g.start.assign(groups + 1, 0);
    for (std::int32_t o : owner) {
        if (o >= 0) ++g.start[std::size_t(o) + 1];
    }
    for (std::size_t r = 0; r < groups; ++r) g.start[r + 1] += g.start[r];
    g.items.resize(g.start[groups]);
    std::vector<std::size_t> next(g.start.begin(), g.start.end() - 1);
    for (std::size_t i = 0; i < owner.size(); ++i) {
        if (owner[i] >= 0) g.items[next[std::size_t(owner[i])]++] = std::int32_t(i);
    }
    return g;
}

/// A region's rectangle of texels in its plane. Texel column x covers the plane coordinate
/// u = u0 + (x - pad .. x - pad + 1) * texel, row y (downwards) v = v1 - (y - pad .. y - pad + 1)
/// * texel: (u, v, normal) is right-handed, so the picture is not mirrored seen from outside.
struct Rect {
    V3 u_axis{1, 0, 0}, v_axis{0, 1, 0};
    double u0 = 0.0, u1 = 0.0, v0 = 0.0, v1 = 0.0;  ///< extent of the region's vertices
    int w = 0, h = 0;  ///< texels, padding included
    int x = 0, y = 0;  ///< top-left corner in the atlas
};

/// Convex hull of 2D points (Andrew's monotone chain), counter-clockwise, no collinear points.
std::vector<std::array<double, 2>> convex_hull(std::vector<std::array<double, 2>> p) {
    std::sort(p.begin(), p.end());
    p.erase(std::unique(p.begin(), p.end()), p.end());
    if (p.size() < 3) return p;
    const auto turn = [](const std::array<double, 2>& o, const std::array<double, 2>& a,
                         const std::array<double, 2>& b) {
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
    };
    std::vector<std::array<double, 2>> h(2 * p.size());
    std::size_t k = 0;
    for (std::size_t i = 0; i < p.size(); ++i) {  // lower hull
        while (k >= 2 && turn(h[k - 2], h[k - 1], p[i]) <= 0.0) --k;
        h[k++] = p[i];
    }
    for (std::size_t i = p.size() - 1, lower = k + 1; i-- > 0;) {  // upper hull
        while (k >= lower && turn(h[k - 2], h[k - 1], p[i]) <= 0.0) --k;
        h[k++] = p[i];
    }
    h.resize(k - 1);
    return h;
}

/// The region's rectangle: the smallest-area rectangle around its vertices in the plane (one
/// side along an edge of their convex hull: H. Freeman & R. Shapira, "Determining the
/// minimum-area encasing rectangle for an arbitrary closed curve", CACM 1975).
Rect region_frame(const Mesh& mesh, const std::vector<std::int32_t>& vertices, const V3& normal) {
    // Any right-handed basis of the plane first: (a, b, normal).
    int k = 0;
    for (int i = 1; i < 3; ++i) {
        if (std::fabs(normal[std::size_t(i)]) < std::fabs(normal[std::size_t(k)])) k = i;
    }
    V3 e{0, 0, 0};
    e[std::size_t(k)] = 1.0;
    const V3 a = unit(cross(e, normal));
    const V3 b = cross(normal, a);
    std::vector<std::array<double, 2>> st;
    st.reserve(vertices.size());
    for (std::int32_t v : vertices) {
        const V3 p = v3(mesh.vertices[std::size_t(v)]);
        st.push_back({dot(p, a), dot(p, b)});
    }
    const std::vector<std::array<double, 2>> hull = convex_hull(std::move(st));
    double best = std::numeric_limits<double>::infinity(), c = 1.0, s = 0.0;
    for (std::size_t i = 0; i < hull.size() && hull.size() >= 2; ++i) {
        const auto& p = hull[i];
        const auto& q = hull[(i + 1) % hull.size()];
        const double len = std::hypot(q[0] - p[0], q[1] - p[1]);
        if (!(len > 0.0)) continue;
        const double ci = (q[0] - p[0]) / len, si = (q[1] - p[1]) / len;
        double lo[2] = {1e300, 1e300}, hi[2] = {-1e300, -1e300};
        for (const auto& h : hull) {
            const double x = ci * h[0] + si * h[1], y = -si * h[0] + ci * h[1];
            lo[0] = std::min(lo[0], x);
            hi[0] = std::max(hi[0], x);
            lo[1] = std::min(lo[1], y);
            hi[1] = std::max(hi[1], y);
        }
        const double area = (hi[0] - lo[0]) * (hi[1] - lo[1]);
        if (area < best * (1.0 - 1e-9)) {
            best = area;
            c = ci;
            s = si;
        }
    }
    Rect r;
    r.u_axis = {c * a[0] + s * b[0], c * a[1] + s * b[1], c * a[2] + s * b[2]};
    r.v_axis = {-s * a[0] + c * b[0], -s * a[1] + c * b[1], -s * a[2] + c * b[2]};
    r.u0 = r.v0 = std::numeric_limits<double>::infinity();
    r.u1 = r.v1 = -std::numeric_limits<double>::infinity();
    for (std::int32_t v : vertices) {
        const V3 p = v3(mesh.vertices[std::size_t(v)]);
        const double u = dot(p, r.u_axis), w = dot(p, r.v_axis);
        r.u0 = std::min(r.u0, u);
        r.u1 = std::max(r.u1, u);
        r.v0 = std::min(r.v0, w);
        r.v1 = std::max(r.v1, w);
    }
    return r;
}

/// Continuous texel coordinates (x right, y down, from the rectangle's corner) of p.
std::array<double, 2> texel_coords(const Rect& r, const V3& p, double texel, int pad) {
    return {pad + (dot(p, r.u_axis) - r.u0) / texel, pad + (r.v1 - dot(p, r.v_axis)) / texel};
}

/// The largest rectangle edge for `texel`, texels (padding included), in double: a texel far
/// too small must not overflow an int.
double largest_edge(const std::vector<Rect>& rects, double texel, int pad) {
    double edge = 0.0;
    for (const Rect& r : rects) {
        edge = std::max({edge, std::ceil((r.u1 - r.u0) / texel), std::ceil((r.v1 - r.v0) / texel)});
    }
    return edge + 1 + 2 * pad;
}

/// Rectangle sizes for `texel`, packed on shelves, tallest first, into an atlas about as wide
/// as it is tall. Returns the atlas size. Every edge must fit an int (largest_edge).
std::array<std::int64_t, 2> pack(std::vector<Rect>& rects, double texel, int pad) {
    double area = 0.0;
    int widest = 1;
    for (Rect& r : rects) {
        r.w = int(std::ceil((r.u1 - r.u0) / texel)) + 1 + 2 * pad;
        r.h = int(std::ceil((r.v1 - r.v0) / texel)) + 1 + 2 * pad;
        area += double(r.w) * double(r.h);
        widest = std::max(widest, r.w);
    }
    std::vector<std::size_t> order(rects.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::sort(order.begin(), order.end(), [&](std::size_t i, std::size_t j) {
        if (rects[i].h != rects[j].h) return rects[i].h > rects[j].h;
        if (rects[i].w != rects[j].w) return rects[i].w > rects[j].w;
        return i < j;
    });
    const std::int64_t width = std::max<std::int64_t>(widest, std::int64_t(std::ceil(std::sqrt(area))));
    std::int64_t x = 0, y = 0, shelf = 0;
    for (std::size_t i : order) {
        Rect& r = rects[i];
        if (x + r.w > width) {
            x = 0;
            y += shelf;
            shelf = 0;
        }
        r.x = int(std::min<std::int64_t>(x, INT32_MAX));
        r.y = int(std::min<std::int64_t>(y, INT32_MAX));
        x += r.w;
        shelf = std::max<std::int64_t>(shelf, r.h);
    }
    return {width, y + shelf};
}

/// Colour and weight planes of a w x h image.
struct Layer {
    int w = 0, h = 0;
    std::vector<float> rgb, weight;
    Layer(int w_, int h_)
        : w(w_), h(h_), rgb(std::size_t(w_) * std::size_t(h_) * 3, 0.0f),
          weight(std::size_t(w_) * std::size_t(h_), 0.0f) {}
    std::size_t at(int x, int y) const { return std::size_t(y) * std::size_t(w) + std::size_t(x); }
};

/// Fills the texels of weight 0 by pull-push (Gortler et al. 1996): each coarser level holds the
/// weighted mean of its 2x2 children (weights summed, clamped to 1), and a texel below weight
/// 1 blends in its parent's colour on the way down. Texels with points keep their colour.
void pull_push(Layer& base) {
    std::vector<Layer> levels;
    levels.push_back(std::move(base));
    while (levels.back().w > 1 || levels.back().h > 1) {
        const Layer& f = levels.back();
        Layer c((f.w + 1) / 2, (f.h + 1) / 2);
        for (int y = 0; y < f.h; ++y) {
            for (int x = 0; x < f.w; ++x) {
                const std::size_t i = f.at(x, y), o = c.at(x / 2, y / 2);
                const float wt = f.weight[i];
                c.weight[o] += wt;
                for (std::size_t ch = 0; ch < 3; ++ch) c.rgb[o * 3 + ch] += wt * f.rgb[i * 3 + ch];
            }
        }
        for (std::size_t o = 0; o < c.weight.size(); ++o) {
            if (c.weight[o] > 0.0f) {
                for (std::size_t ch = 0; ch < 3; ++ch) c.rgb[o * 3 + ch] /= c.weight[o];
                c.weight[o] = std::min(c.weight[o], 1.0f);
            }
        }
        levels.push_back(std::move(c));
    }
    Layer& top = levels.back();
    if (top.weight[0] == 0.0f) {  // no point at all: mid grey
        top.rgb = {0.5f, 0.5f, 0.5f};
        top.weight[0] = 1.0f;
    }
    for (std::size_t l = levels.size() - 1; l-- > 0;) {
        Layer& f = levels[l];
        const Layer& c = levels[l + 1];
        for (int y = 0; y < f.h; ++y) {
            for (int x = 0; x < f.w; ++x) {
                const std::size_t i = f.at(x, y), o = c.at(x / 2, y / 2);
                const float wt = f.weight[i];
                if (wt >= 1.0f) continue;
                for (std::size_t ch = 0; ch < 3; ++ch) {
                    f.rgb[i * 3 + ch] = wt * f.rgb[i * 3 + ch] + (1.0f - wt) * c.rgb[o * 3 + ch];
                }
                f.weight[i] = 1.0f;
            }
        }
    }
    base = std::move(levels.front());
}

struct RegionStats {
    std::size_t points = 0, seen = 0;
};

/// One region's texels from its points (their Gaussian-weighted mean colour), the rest filled.
Layer raster_region(const Rect& r, const std::int32_t* points, std::size_t count,
                    const PointCloud& cloud, const V3& shift, double texel,
                    const TextureOptions& o, RegionStats& stats) {
    Layer acc(r.w, r.h);
    const double sigma = o.splat_sigma, reach = 3.0 * sigma;
    const double inv2s2 = 1.0 / (2.0 * sigma * sigma);
    for (std::size_t k = 0; k < count; ++k) {
        const std::size_t i = std::size_t(points[k]);
        const Vec3f& col = cloud.colors[i];
        if (!(std::isfinite(col[0]) && std::isfinite(col[1]) && std::isfinite(col[2]))) continue;
        const Vec3f& q = cloud.positions[i];
        const V3 p{q[0] + shift[0], q[1] + shift[1], q[2] + shift[2]};
        const auto [sx, sy] = texel_coords(r, p, texel, o.padding);
        const int x0 = std::max(0, int(std::floor(sx - reach))), x1 = std::min(r.w - 1, int(std::floor(sx + reach)));
        const int y0 = std::max(0, int(std::floor(sy - reach))), y1 = std::min(r.h - 1, int(std::floor(sy + reach)));
        bool used = false;
        for (int y = y0; y <= y1; ++y) {
            for (int x = x0; x <= x1; ++x) {
                const double dx = x + 0.5 - sx, dy = y + 0.5 - sy;
                const double d2 = dx * dx + dy * dy;
                if (d2 > reach * reach) continue;
                const float wt = float(std::exp(-d2 * inv2s2));
                const std::size_t t = acc.at(x, y);
                acc.weight[t] += wt;
                for (std::size_t ch = 0; ch < 3; ++ch) acc.rgb[t * 3 + ch] += wt * cloud.colors[i][ch];
                used = true;
            }
        }
        stats.points += used;
    }
    for (std::size_t t = 0; t < acc.weight.size(); ++t) {
        if (acc.weight[t] > 0.0f) {
            for (std::size_t ch = 0; ch < 3; ++ch) acc.rgb[t * 3 + ch] /= acc.weight[t];
            acc.weight[t] = 1.0f;  // a texel with points keeps their colour
            ++stats.seen;
        }
    }
    pull_push(acc);
    return acc;
}

/// The region of each input point: that of its nearest face when within `reach` of it.
std::vector<std::int32_t> point_regions(const Mesh& mesh, const PointCloud& cloud, double reach) {
    std::vector<std::int32_t> face;
    const std::vector<double> d = MeshDistance(mesh).distances(cloud, &face);
    std::vector<std::int32_t> owner(cloud.size(), -1);
    for (std::size_t i = 0; i < owner.size(); ++i) {
        if (d[i] <= reach && face[i] >= 0) owner[i] = mesh.regions[std::size_t(face[i])];
    }
    return owner;
}

/// Checks the inputs; returns the number of regions the faces use.
std::size_t check_inputs(const Mesh& mesh, const std::vector<Plane>& planes,
                         const PointCloud& points, const TextureOptions& options, double voxel) {
    options.validate();
    if (!(std::isfinite(voxel) && voxel > 0.0)) {
        throw InvalidArgument("texture: the voxel must be a positive length");
    }
    if (points.colors.size() != points.size() || points.empty()) {
        throw InvalidArgument("texture: the input points have no colours to make textures from");
    }
    if (mesh.regions.size() != mesh.faces.size()) {
        throw InvalidArgument("texture: the mesh has no planar regions (run the planes stage first)");
    }
    std::size_t regions = 0;
    for (std::int32_t r : mesh.regions) {
        if (r >= 0 && std::size_t(r) >= planes.size()) {
            throw InvalidArgument("texture: face region " + std::to_string(r) + " has no plane (" +
                                  std::to_string(planes.size()) + " planes)");
        }
        regions = std::max(regions, std::size_t(r + 1));
    }
    return regions;
}

/// The texel to use: the options', else half a voxel; grown until the packed atlas fits.
double fit_texel(std::vector<Rect>& rects, const TextureOptions& o, double voxel,
                 std::array<int, 2>& size) {
    const double asked = o.texel > 0.0 ? o.texel : 0.5 * voxel;
    double texel = asked;
    for (int attempt = 0;; ++attempt) {
        if (attempt == 100) throw NumericalError("texture: the regions do not fit any atlas");
        const double largest = largest_edge(rects, texel, o.padding);
        if (largest > o.max_size) {
            texel *= std::max(1.05, largest / double(o.max_size));
            continue;
        }
        const std::array<std::int64_t, 2> packed = pack(rects, texel, o.padding);
        const std::int64_t edge = std::max(packed[0], packed[1]);
        if (edge <= o.max_size) {
            size = {int(packed[0]), int(packed[1])};
            break;
        }
        texel *= std::max(1.05, std::sqrt(double(edge) / double(o.max_size)));
    }
    if (texel != asked) {
        std::ostringstream s;
        s << "texture: texel " << asked << " would need an atlas over " << o.max_size
          << " texels a side; using " << texel;
        log_warning(s.str());
    }
    return texel;
}

}  // namespace

TextureAtlas texture_regions(const Mesh& mesh, const std::vector<Plane>& planes,
                             const PointCloud& points, const TextureOptions& options, double voxel) {
    const std::size_t regions = check_inputs(mesh, planes, points, options, voxel);
    TextureAtlas atlas;
    const float nan = std::numeric_limits<float>::quiet_NaN();
    atlas.uv.assign(mesh.faces.size(), {Vec2f{nan, nan}, Vec2f{nan, nan}, Vec2f{nan, nan}});
    if (regions == 0) {
        log_warning("texture: the mesh has no planar region; it keeps its vertex colours");
        return atlas;
    }
    const Groups faces = group_by(mesh.regions, regions);
    std::vector<Rect> rects(regions);
    tbb::parallel_for(std::size_t(0), regions, [&](std::size_t r) {
        std::vector<std::int32_t> verts;
        for (std::size_t k = faces.start[r]; k < faces.start[r + 1]; ++k) {
            for (std::int32_t v : mesh.faces[std::size_t(faces.items[k])]) verts.push_back(v);
        }
        std::sort(verts.begin(), verts.end());
        verts.erase(std::unique(verts.begin(), verts.end()), verts.end());
        if (!verts.empty()) rects[r] = region_frame(mesh, verts, planes[r].normal);
    });
    std::array<int, 2> size{0, 0};
    atlas.texel = fit_texel(rects, options, voxel, size);
    atlas.width = size[0];
    atlas.height = size[1];
    atlas.rgb.assign(std::size_t(atlas.width) * std::size_t(atlas.height) * 3, 0);

    const V3 shift{points.origin[0] - mesh.origin[0], points.origin[1] - mesh.origin[1],
                   points.origin[2] - mesh.origin[2]};
    const Groups owned =
        group_by(point_regions(mesh, points, options.max_distance * voxel), regions);
    std::vector<RegionStats> stats(regions);
    tbb::parallel_for(std::size_t(0), regions, [&](std::size_t r) {
        const Rect& rect = rects[r];
        if (faces.start[r] == faces.start[r + 1]) return;  // no face: nothing to texture
        const Layer layer = raster_region(rect, owned.items.data() + owned.start[r],
                                          owned.start[r + 1] - owned.start[r], points, shift,
                                          atlas.texel, options, stats[r]);
        for (int y = 0; y < rect.h; ++y) {
            for (int x = 0; x < rect.w; ++x) {
                const std::size_t src = layer.at(x, y);
                const std::size_t dst =
                    (std::size_t(rect.y + y) * std::size_t(atlas.width) + std::size_t(rect.x + x)) * 3;
                for (std::size_t ch = 0; ch < 3; ++ch) {
                    const double c = std::clamp(double(layer.rgb[src * 3 + ch]), 0.0, 1.0);
                    atlas.rgb[dst + ch] = std::uint8_t(std::lround(255.0 * c));
                }
            }
        }
        for (std::size_t k = faces.start[r]; k < faces.start[r + 1]; ++k) {
            const std::size_t f = std::size_t(faces.items[k]);
            for (int c = 0; c < 3; ++c) {
                const auto [sx, sy] = texel_coords(
                    rect, v3(mesh.vertices[std::size_t(mesh.faces[f][std::size_t(c)])]),
                    atlas.texel, options.padding);
                atlas.uv[f][std::size_t(c)] = {float((rect.x + sx) / atlas.width),
                                               float(1.0 - (rect.y + sy) / atlas.height)};
            }
        }
    });
    for (std::size_t r = 0; r < regions; ++r) {
        if (faces.start[r] == faces.start[r + 1]) continue;
        ++atlas.regions;
        atlas.points += stats[r].points;
        atlas.texels += std::size_t(rects[r].w) * std::size_t(rects[r].h);
        atlas.texels_seen += stats[r].seen;
    }
    return atlas;
}

std::string texture_mtl_path(const std::string& obj_path) {
    return detail::path_stem(obj_path) + ".mtl";
}

std::string texture_png_path(const std::string& obj_path) {
    return detail::path_stem(obj_path) + ".texture.png";
}

namespace detail {

namespace {

std::string file_name(const std::string& path) {
    const std::size_t slash = path.find_last_of('/');
    return slash == std::string::npos ? path : path.substr(slash + 1);
}

/// The material file: a plain grey material and, with an atlas, the textured one.
void write_mtl(const std::string& path, const std::string& png_name, bool textured) {
    AtomicFile file(path);
    ByteWriter out(file.stream());
    out.put("# vdbrecon materials\n"
            "newmtl vdbrecon_surface\nKa 0 0 0\nKd 0.8 0.8 0.8\nKs 0 0 0\nd 1\nillum 1\n");
    if (textured) {
        out.put("\nnewmtl vdbrecon_texture\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\nmap_Kd " +
                png_name + "\n");
    }
    out.flush();
    file.commit();
}

}  // namespace

void write_textured(StagedOutputs& staged, const std::string& obj_path, const Mesh& mesh,
                    const TextureAtlas& atlas, const WriteOptions& options) {
    if (atlas.uv.size() != mesh.faces.size()) {
        throw InvalidArgument("write_textured_mesh: " + std::to_string(atlas.uv.size()) +
                              " faces of texture coordinates for " +
                              std::to_string(mesh.faces.size()) + " faces");
    }
    const std::string mtl = texture_mtl_path(obj_path), png = texture_png_path(obj_path);
    ObjMaterials materials;
    materials.mtl_name = file_name(mtl);
    materials.uv = &atlas.uv;
    write_obj_file(staged.stage(obj_path), mesh, options, &materials);
    write_mtl(staged.stage(mtl), file_name(png), !atlas.empty());
    if (!atlas.empty()) {
        write_png_rgb8(staged.stage(png), atlas.width, atlas.height, atlas.rgb.data());
    }
}

}  // namespace detail

void write_textured_mesh(const std::string& obj_path, const Mesh& mesh, const TextureAtlas& atlas,
                         const WriteOptions& options) {
    if (file_extension(obj_path) != "obj") {
        throw InvalidArgument("output '" + obj_path + "': a textured mesh is written as .obj");
    }
    detail::check_writable(obj_path);
    detail::StagedOutputs staged;
    detail::write_textured(staged, obj_path, mesh, atlas, options);
    staged.commit_all();
}

}  // namespace vdbrecon
