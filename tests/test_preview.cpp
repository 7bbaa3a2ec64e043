// Preview pictures (preview.h): a sphere's silhouette and depth against the pinhole model, the
// PNG and EXR files read back, colours where they belong.
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <zlib.h>

#include "support.h"
#include "support_volume.h"
#include "vdbrecon/error.h"
#include "vdbrecon/mesh.h"
#include "vdbrecon/pipeline.h"
#include "vdbrecon/preview.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

Mesh sphere_mesh(float radius) {
    return extract_mesh(sphere_volume(radius, openvdb::Vec3f(0.0f), radius / 40.0f)).mesh;
}

std::uint32_t be32(const std::string& s, std::size_t at) {
    std::uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v = (v << 8) | std::uint8_t(s[at + std::size_t(i)]);
    return v;
}

}  // namespace

TEST_CASE("preview: a sphere's silhouette and depth follow the pinhole camera", "[preview]") {
    const double r = 2.0;
    PreviewOptions o;
    o.width = 400;
    o.height = 300;
    const Image img = render_preview(sphere_mesh(float(r)), o);
    REQUIRE(img.width == 400);
    REQUIRE(img.height == 300);
    const std::size_t centre = std::size_t(150) * 400 + 200;
    REQUIRE(img.alpha[centre] == 1.0f);
    REQUIRE(img.alpha[0] == 0.0f);
    REQUIRE(std::isinf(img.depth[0]));
    // The camera looks at the centre: the depth there is the eye distance minus the radius.
    const double eye = double(img.depth[centre]) + r;
    // Silhouette of a sphere at distance D: a disc of angular radius asin(r / D).
    const double f = 0.5 * o.height / std::tan(0.5 * o.fov_degrees * M_PI / 180.0);
    const double disc = f * std::tan(std::asin(r / eye));
    double covered = 0.0;
    for (float a : img.alpha) covered += a;
    INFO("eye distance " << eye << ", disc radius " << disc << " px");
    CHECK(covered == Approx(M_PI * disc * disc).epsilon(0.02));
    // The disc fits the frame (the whole object is framed) and is not tiny.
    CHECK(disc < 0.5 * o.height);
    CHECK(disc > 0.2 * o.height);
    // Lit from the upper left: the upper-left of the disc is brighter than the lower-right.
    const auto lum = [&](int x, int y) {
        const std::size_t k = (std::size_t(y) * 400 + std::size_t(x)) * 3;
        return img.rgb[k] + img.rgb[k + 1] + img.rgb[k + 2];
    };
    const int d = int(0.5 * disc);
    CHECK(lum(200 - d, 150 - d) > 1.5f * lum(200 + d, 150 + d));
}

TEST_CASE("preview: PNG and EXR files carry the picture and the depth", "[preview]") {
    TempDir dir;
    PreviewOptions o;
    o.width = 64;
    o.height = 48;
    const Image img = render_preview(sphere_mesh(1.0f), o);

    write_image(dir.file("p.png"), img);
    const std::string png = read_bytes(dir.file("p.png"));
    REQUIRE(png.substr(0, 8) == std::string("\x89PNG\r\n\x1a\n", 8));
    REQUIRE(png.substr(12, 4) == "IHDR");
    REQUIRE(be32(png, 16) == 64u);
    REQUIRE(be32(png, 20) == 48u);
    const std::size_t idat = png.find("IDAT");
    REQUIRE(idat != std::string::npos);
    const std::uint32_t zlen = be32(png, idat - 4);
    std::string raw(std::size_t(48) * (64 * 3 + 1), '\0');
    uLongf rawlen = uLongf(raw.size());
    REQUIRE(uncompress(reinterpret_cast<Bytef*>(raw.data()), &rawlen,
                       reinterpret_cast<const Bytef*>(png.data() + idat + 4), zlen) == Z_OK);
    REQUIRE(rawlen == raw.size());
    // Background pixel: light grey; centre pixel: darker than the background and not black.
    const auto px = [&](int x, int y, int c) {
        return int(std::uint8_t(raw[std::size_t(y) * (64 * 3 + 1) + 1 + std::size_t(x) * 3 + std::size_t(c)]));
    };
    CHECK(px(0, 0, 0) == 235);
    CHECK(px(32, 24, 1) > 40);
    CHECK(px(32, 24, 1) < 235);

    write_image(dir.file("p.exr"), img);
    Imf::InputFile in(dir.file("p.exr").c_str());
    REQUIRE(in.header().channels().findChannel("Z") != nullptr);
    REQUIRE(in.header().channels().findChannel("A") != nullptr);
    std::vector<float> z(64 * 48), red(64 * 48);
    Imf::FrameBuffer fb;
    fb.insert("Z", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(z.data()), sizeof(float), 64 * sizeof(float)));
    fb.insert("R", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(red.data()), sizeof(float), 64 * sizeof(float)));
    in.setFrameBuffer(fb);
    in.readPixels(0, 47);
    for (std::size_t i = 0; i < z.size(); ++i) {
        REQUIRE((z[i] == img.depth[i] || (std::isinf(z[i]) && std::isinf(img.depth[i]))));
        REQUIRE(red[i] == img.rgb[i * 3]);
    }

    REQUIRE_THROWS_AS(write_image(dir.file("p.jpg"), img), InvalidArgument);
    REQUIRE(count_files(dir.path()) == 2);  // no temp files left behind
}

TEST_CASE("preview: vertex colours show where they are", "[preview]") {
    Mesh m = sphere_mesh(1.0f);
    m.colors.resize(m.vertices.size());
    for (std::size_t i = 0; i < m.vertices.size(); ++i) {
        m.colors.edit()[i] =
            m.vertices[i][1] > 0.0f ? Vec3f{1.0f, 0.0f, 0.0f} : Vec3f{0.0f, 0.0f, 1.0f};
    }
    PreviewOptions o;
    o.width = 200;
    o.height = 200;
    const Image img = render_preview(m, o);
    const auto rgb = [&](int x, int y) {
        const std::size_t k = (std::size_t(y) * 200 + std::size_t(x)) * 3;
        return std::array<float, 3>{img.rgb[k], img.rgb[k + 1], img.rgb[k + 2]};
    };
    // +y is up in the picture: red above the equator, blue below. The camera looks down by
    // about 23 degrees, so the front of the equator shows about 0.4 disc radii (~35 px) below
    // the centre: sample well above and well below it.
    const auto top = rgb(100, 70), bottom = rgb(100, 175);
    CHECK(top[0] > 5.0f * top[2]);
    CHECK(bottom[2] > 5.0f * bottom[0]);
}

TEST_CASE("preview: the CLI writes the picture and refuses other extensions early",
          "[preview][cli]") {
    TempDir dir;
    write_points(dir.file("s.ply"), sample_sphere(5000, 1.0));
    const CliRun ok = run_cli("'" + dir.file("s.ply") + "' -o '" + dir.file("s.recon.ply") +
                              "' --no-vdb -q --preview '" + dir.file("s.png") + "'");
    REQUIRE(ok.code == 0);
    REQUIRE(file_exists(dir.file("s.png")));
    REQUIRE(file_exists(dir.file("s.recon.ply")));
    const CliRun bad = run_cli("'" + dir.file("s.ply") + "' -o '" + dir.file("t.ply") +
                               "' --no-vdb --preview '" + dir.file("s.bmp") + "'");
    CHECK(bad.code == 2);
    CHECK(bad.err.find("s.bmp") != std::string::npos);
    CHECK_FALSE(file_exists(dir.file("t.ply")));  // refused before any work
}
