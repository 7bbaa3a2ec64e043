// Textures for planar regions (issue 25 point 4): a rotated cube and an L-bracket, sampled
// uniformly at random with a colour that is a known function of position, come out with one
// texture rectangle per face whose texels carry that function where the texture coordinates say;
// the map from the surface to the atlas is a similarity of scale 1/texel, not mirrored; the atlas
// is the same for any thread count; the OBJ, its material file and the PNG say the same.
#include <zlib.h>

#include <cmath>
#include <fstream>
#include <random>
#include <sstream>

#include "shapes.h"
#include "support.h"
#include "vdbrecon/error.h"
#include "vdbrecon/pipeline.h"
#include "vdbrecon/texture.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

/// The colour painted on the surface: smooth, different on every face of a part.
Vec3f paint(const Vec3f& p) {
    const double k = 2.0 * M_PI / 0.6;
    return {float(0.5 + 0.4 * std::sin(k * p[0])), float(0.5 + 0.4 * std::sin(k * p[1] + 1.0)),
            float(0.5 + 0.4 * std::cos(k * p[2]))};
}

struct Textured {
    PipelineResult r;
    double voxel = 0.0;
};

Textured textured(const std::string& name, int threads = 0, int max_size = 8192,
                  double texel = 0.0, int tile = 0) {
    const Shape shape = make_shape(name);
    PointCloud sample = sample_uniform(shape.mesh, 60000, 5);
    std::vector<Vec3f> colors(sample.size());
    for (std::size_t i = 0; i < sample.size(); ++i) colors[i] = paint(sample.positions[i]);
    sample.colors = std::move(colors);
    PipelineOptions o;
    Textured t;
    o.splat.voxel_size = t.voxel = spacing_of(shape.area, 60000);
    o.mesh.method = Mesher::dc;
    o.planes.enabled = true;
    o.texture.enabled = true;
    o.texture.max_size = max_size;
    o.texture.texel = texel;
    o.tile = tile;
    o.threads = threads;
    t.r = reconstruct(sample, o);
    return t;
}

/// The atlas texel under texture coordinate uv (nearest), 0..1 per channel.
Vec3f lookup(const TextureAtlas& a, const Vec2f& uv) {
    const int x = std::clamp(int(std::floor(uv[0] * a.width)), 0, a.width - 1);
    const int y = std::clamp(int(std::floor((1.0 - uv[1]) * a.height)), 0, a.height - 1);
    const std::size_t k = (std::size_t(y) * std::size_t(a.width) + std::size_t(x)) * 3;
    return {a.rgb[k] / 255.0f, a.rgb[k + 1] / 255.0f, a.rgb[k + 2] / 255.0f};
}

std::uint32_t be32(const std::string& s, std::size_t at) {
    std::uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v = (v << 8) | std::uint8_t(s[at + std::size_t(i)]);
    return v;
}

}  // namespace

TEST_CASE("texture: each face of a CAD part carries its colours where its coordinates say",
          "[texture]") {
    for (const std::string name : {"cube", "lbracket"}) {
        INFO(name);
        const Textured t = textured(name);
        const Mesh& m = t.r.mesh;
        const TextureAtlas& a = t.r.texture;
        REQUIRE(!a.empty());
        CHECK(a.regions == t.r.planes.planes.size());
        CHECK(a.texel == Approx(0.5 * t.voxel));
        REQUIRE(a.uv.size() == m.faces.size());
        double area = 0.0;
        for (const Plane& pl : t.r.planes.planes) area += pl.area;
        std::mt19937_64 rng(3);
        std::uniform_real_distribution<double> unit(0.0, 1.0);
        double err_sum = 0.0, err_max = 0.0;
        std::size_t samples = 0;
        // Per region, its texture coordinates' box in texels (to check that none overlap).
        std::vector<std::array<double, 4>> box(a.regions, {1e30, 1e30, -1e30, -1e30});
        for (std::size_t f = 0; f < m.faces.size(); ++f) {
            const Triangle& tri = m.faces[f];
            const Vec3f* p[3] = {&m.vertices[std::size_t(tri[0])], &m.vertices[std::size_t(tri[1])],
                                 &m.vertices[std::size_t(tri[2])]};
            const auto& uv = a.uv[f];
            REQUIRE(m.regions[f] >= 0);  // every face of these parts is in a region
            double tx[3], ty[3];         // corners in texels
            for (int c = 0; c < 3; ++c) {
                REQUIRE(uv[c][0] >= 0.0f);
                REQUIRE(uv[c][0] <= 1.0f);
                REQUIRE(uv[c][1] >= 0.0f);
                REQUIRE(uv[c][1] <= 1.0f);
                tx[c] = uv[c][0] * double(a.width);
                ty[c] = uv[c][1] * double(a.height);
                auto& b = box[std::size_t(m.regions[f])];
                b = {std::min(b[0], tx[c]), std::min(b[1], ty[c]), std::max(b[2], tx[c]),
                     std::max(b[3], ty[c])};
            }
            // A similarity of scale 1 / texel: each edge's length in texels.
            for (int c = 0; c < 3; ++c) {
                const int d = (c + 1) % 3;
                double len = 0.0;
                for (int k = 0; k < 3; ++k) {
                    len += std::pow(double((*p[d])[std::size_t(k)]) - (*p[c])[std::size_t(k)], 2.0);
                }
                const double in_texels = std::hypot(tx[d] - tx[c], ty[d] - ty[c]);
                CHECK(in_texels == Approx(std::sqrt(len) / a.texel).epsilon(1e-3).margin(1e-3));
            }
            // Counter-clockwise in the texture as on the surface seen from outside: not mirrored.
            const double area2 = (tx[1] - tx[0]) * (ty[2] - ty[0]) - (tx[2] - tx[0]) * (ty[1] - ty[0]);
            CHECK(area2 > 0.0);
            // The texture's colour at random points of the face against the painted colour,
            // about 3000 points per part (by area).
            const double ex = double((*p[1])[0]) - (*p[0])[0], ey = double((*p[1])[1]) - (*p[0])[1],
                         ez = double((*p[1])[2]) - (*p[0])[2];
            const double fx = double((*p[2])[0]) - (*p[0])[0], fy = double((*p[2])[1]) - (*p[0])[1],
                         fz = double((*p[2])[2]) - (*p[0])[2];
            const double face_area = 0.5 * std::sqrt(std::pow(ey * fz - ez * fy, 2) +
                                                     std::pow(ez * fx - ex * fz, 2) +
                                                     std::pow(ex * fy - ey * fx, 2));
            const int draws = 1 + int(3000.0 * face_area / area);
            for (int s = 0; s < draws; ++s) {
                double b1 = unit(rng), b2 = unit(rng);
                if (b1 + b2 > 1.0) {
                    b1 = 1.0 - b1;
                    b2 = 1.0 - b2;
                }
                const double b0 = 1.0 - b1 - b2;
                Vec3f q;
                Vec2f w;
                for (int k = 0; k < 3; ++k) {
                    q[std::size_t(k)] = float(b0 * (*p[0])[std::size_t(k)] + b1 * (*p[1])[std::size_t(k)] +
                                              b2 * (*p[2])[std::size_t(k)]);
                }
                for (int k = 0; k < 2; ++k) {
                    w[std::size_t(k)] = float(b0 * uv[0][std::size_t(k)] + b1 * uv[1][std::size_t(k)] +
                                              b2 * uv[2][std::size_t(k)]);
                }
                const Vec3f got = lookup(a, w), want = paint(q);
                for (int k = 0; k < 3; ++k) {
                    const double e = std::fabs(double(got[std::size_t(k)]) - want[std::size_t(k)]);
                    err_sum += e;
                    err_max = std::max(err_max, e);
                    ++samples;
                }
            }
        }
        const double mean = err_sum / double(samples);
        INFO("colour error mean " << mean << ", max " << err_max << " over " << samples);
        CHECK(mean < 0.02);
        CHECK(err_max < 0.15);
        // The regions' rectangles do not overlap in the atlas.
        for (std::size_t i = 0; i < box.size(); ++i) {
            for (std::size_t j = i + 1; j < box.size(); ++j) {
                const bool apart = box[i][2] <= box[j][0] || box[j][2] <= box[i][0] ||
                                   box[i][3] <= box[j][1] || box[j][3] <= box[i][1];
                CHECK(apart);
            }
        }
        // Most texels were reached by points; the rest is interpolation (the rectangles' corners
        // beside the L-bracket's L-shaped faces, the padding, gaps of the random sample).
        CHECK(a.texels_seen > a.texels * 6 / 10);
        CHECK(a.points > 50000);
    }
}

TEST_CASE("texture: the same atlas for any thread count and tiles; a texel too fine grows to fit",
          "[texture]") {
    const Textured one = textured("lbracket", 1), two = textured("lbracket", 2);
    CHECK(one.r.texture.rgb == two.r.texture.rgb);
    REQUIRE(one.r.texture.uv.size() == two.r.texture.uv.size());
    CHECK(std::memcmp(one.r.texture.uv.data(), two.r.texture.uv.data(),
                      one.r.texture.uv.size() * sizeof(one.r.texture.uv[0])) == 0);
    const Textured small = textured("lbracket", 0, 128);
    CHECK(std::max(small.r.texture.width, small.r.texture.height) <= 128);
    CHECK(std::max(one.r.texture.width, one.r.texture.height) > 128);
    CHECK(small.r.texture.texel > 0.5 * small.voxel);
    // Tile by tile (another vertex and face numbering): the same atlas.
    const Textured tiled = textured("lbracket", 0, 8192, 0.0, 16);
    CHECK(tiled.r.tiles > 1);
    CHECK(tiled.r.texture.rgb == one.r.texture.rgb);
    CHECK(tiled.r.texture.points == one.r.texture.points);
    // An absurd texel (a 1e12-texel rectangle) grows to fit too.
    const Textured tiny = textured("cube", 0, 256, 1e-12);
    CHECK(std::max(tiny.r.texture.width, tiny.r.texture.height) <= 256);
    CHECK(std::max(tiny.r.texture.width, tiny.r.texture.height) > 128);
}

TEST_CASE("texture: the OBJ, its material file and the PNG atlas", "[texture]") {
    const Textured t = textured("cube");
    const Mesh& m = t.r.mesh;
    const TextureAtlas& a = t.r.texture;
    TempDir dir;
    const std::string obj = dir.file("part.obj");
    write_textured_mesh(obj, m, a);
    CHECK(texture_mtl_path(obj) == dir.file("part.mtl"));
    CHECK(texture_png_path(obj) == dir.file("part.texture.png"));
    CHECK(count_files(dir.path()) == 3);
    // The OBJ: the material file, a texture coordinate per distinct textured corner, every face
    // textured (all are in a region), read back with the same vertices and faces.
    const std::string text = read_bytes(obj);
    CHECK(text.find("mtllib part.mtl\n") != std::string::npos);
    CHECK(text.find("usemtl vdbrecon_texture\n") != std::string::npos);
    CHECK(text.find("usemtl vdbrecon_surface\n") == std::string::npos);
    std::istringstream lines(text);
    std::string line;
    std::vector<Vec2f> vt;
    std::size_t faces = 0;
    bool checked_face = false;
    while (std::getline(lines, line)) {
        if (line.rfind("vt ", 0) == 0) {
            std::istringstream s(line.substr(3));
            Vec2f uv;
            s >> uv[0] >> uv[1];
            vt.push_back(uv);
        } else if (line.rfind("f ", 0) == 0) {
            // f v/t/n: the corner's coordinates are the atlas's for that face and corner.
            int v[3], tt[3], n[3];
            REQUIRE(std::sscanf(line.c_str(), "f %d/%d/%d %d/%d/%d %d/%d/%d", &v[0], &tt[0], &n[0],
                                &v[1], &tt[1], &n[1], &v[2], &tt[2], &n[2]) == 9);
            for (int c = 0; c < 3; ++c) {
                CHECK(v[c] == m.faces[faces][std::size_t(c)] + 1);
                CHECK(n[c] == v[c]);
                if (!checked_face) {
                    REQUIRE(tt[c] >= 1);
                    REQUIRE(std::size_t(tt[c]) <= vt.size());
                    CHECK(vt[std::size_t(tt[c] - 1)][0] == Approx(a.uv[faces][std::size_t(c)][0]).margin(1e-6));
                    CHECK(vt[std::size_t(tt[c] - 1)][1] == Approx(a.uv[faces][std::size_t(c)][1]).margin(1e-6));
                }
            }
            checked_face = true;
            ++faces;
        }
    }
    CHECK(faces == m.faces.size());
    CHECK(vt.size() >= m.vertices.size());   // edge vertices have one per region
    CHECK(vt.size() <= 3 * m.faces.size());
    const Mesh back = read_mesh(obj);
    CHECK(back.vertices.size() == m.vertices.size());
    CHECK(back.faces.size() == m.faces.size());
    // The material file names the atlas; the atlas decodes to the texture's bytes.
    CHECK(read_bytes(dir.file("part.mtl")).find("map_Kd part.texture.png\n") != std::string::npos);
    const std::string png = read_bytes(dir.file("part.texture.png"));
    REQUIRE(png.substr(12, 4) == "IHDR");
    REQUIRE(be32(png, 16) == std::uint32_t(a.width));
    REQUIRE(be32(png, 20) == std::uint32_t(a.height));
    const std::size_t idat = png.find("IDAT");
    REQUIRE(idat != std::string::npos);
    const std::size_t row = std::size_t(a.width) * 3 + 1;
    std::string raw(std::size_t(a.height) * row, '\0');
    uLongf rawlen = uLongf(raw.size());
    REQUIRE(uncompress(reinterpret_cast<Bytef*>(raw.data()), &rawlen,
                       reinterpret_cast<const Bytef*>(png.data() + idat + 4), be32(png, idat - 4)) == Z_OK);
    REQUIRE(rawlen == raw.size());
    bool same = true;
    for (int y = 0; y < a.height; ++y) {
        same &= raw.compare(std::size_t(y) * row + 1, row - 1,
                            reinterpret_cast<const char*>(a.rgb.data()) + std::size_t(y) * (row - 1),
                            row - 1) == 0;
    }
    CHECK(same);
    CHECK_THROWS_AS(write_textured_mesh(dir.file("part.ply"), m, a), InvalidArgument);
}

TEST_CASE("texture: refused without colours, without planes, on a volume", "[texture]") {
    PointCloud plain = sample_sphere(2000, 1.0);
    PipelineOptions o;
    o.splat.voxel_size = 0.1;
    o.planes.enabled = true;
    o.texture.enabled = true;
    try {
        reconstruct(plain, o);
        FAIL("no error");
    } catch (const InvalidArgument& e) {
        CHECK(std::string(e.what()).find("colours") != std::string::npos);
    }
    o.planes.enabled = false;
    CHECK_THROWS_AS(o.validate(), InvalidArgument);
    o.planes.enabled = true;
    o.texture.texel = -1.0;
    CHECK_THROWS_AS(o.validate(), InvalidArgument);
    Mesh no_regions;
    no_regions.vertices = {Vec3f{0, 0, 0}, Vec3f{1, 0, 0}, Vec3f{0, 1, 0}};
    no_regions.faces = {Triangle{0, 1, 2}};
    plain.colors = std::vector<Vec3f>(plain.size(), Vec3f{0.5f, 0.5f, 0.5f});
    CHECK_THROWS_AS(texture_regions(no_regions, {}, plain, TextureOptions{}, 0.1), InvalidArgument);
}

TEST_CASE("texture: the CLI writes the three files, or nothing", "[texture][cli]") {
    TempDir dir;
    const Shape shape = make_shape("cube");
    PointCloud sample = sample_uniform(shape.mesh, 20000, 2);
    std::vector<Vec3f> colors(sample.size());
    for (std::size_t i = 0; i < sample.size(); ++i) colors[i] = paint(sample.positions[i]);
    const PointCloud uncoloured = sample;
    sample.colors = std::move(colors);
    write_points(dir.file("cube.ply"), sample);
    write_points(dir.file("grey.ply"), uncoloured);
    const std::string voxel = " --voxel " + std::to_string(spacing_of(shape.area, 20000));
    CliRun r = run_cli("'" + dir.file("cube.ply") + "' -o '" + dir.file("out.ply") + "'" + voxel + " --texture");
    CHECK(r.code != 0);
    CHECK(r.err.find("out.ply") != std::string::npos);
    CHECK(r.err.find(".obj") != std::string::npos);
    r = run_cli("'" + dir.file("grey.ply") + "' -o '" + dir.file("out.obj") + "'" + voxel + " --texture");
    CHECK(r.code != 0);
    CHECK(r.err.find("colours") != std::string::npos);
    CHECK(count_files(dir.path()) == 2);  // nothing written
    r = run_cli("'" + dir.file("cube.ply") + "' -o '" + dir.file("out.obj") + "'" + voxel +
                " --texture --texel 0.02 --mesher dc -q");
    REQUIRE(r.code == 0);
    CHECK(file_exists(dir.file("out.obj")));
    CHECK(file_exists(dir.file("out.mtl")));
    CHECK(file_exists(dir.file("out.texture.png")));
    CHECK(file_exists(dir.file("out.splat.vdb")));
    CHECK(count_files(dir.path()) == 6);
}
