#include <openvdb/io/File.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "support.h"
#include "vdbrecon/error.h"
#include "vdbrecon/io.h"
#include "vdbrecon/log.h"
#include "vdbrecon/pipeline.h"
#include "vdbrecon/volume.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

PointCloud full_cloud() {
    PointCloud c = sample_sphere(500, 0.3, {0.1, -0.2, 0.05});
    for (std::size_t i = 0; i < c.size(); ++i) {
        // Colours that are exact in 8 bits, scales and confidences exact in float.
        c.colors.push_back({float(i % 256) / 255.0f, float((i * 7) % 256) / 255.0f,
                            float((i * 13) % 256) / 255.0f});
        c.scales.push_back(0.001f * float(1 + i % 5));
        c.confidences.push_back(0.25f * float(i % 4));
    }
    return c;
}

void require_same(const PointCloud& a, const PointCloud& b) {
    REQUIRE(a.size() == b.size());
    REQUIRE(a.positions == b.positions);
    REQUIRE(a.normals == b.normals);
    REQUIRE(a.scales == b.scales);
    REQUIRE(a.confidences == b.confidences);
    REQUIRE(a.colors.size() == b.colors.size());
    for (std::size_t i = 0; i < a.colors.size(); ++i) {
        for (int k = 0; k < 3; ++k) REQUIRE(a.colors[i][k] == Approx(b.colors[i][k]).margin(1e-6));
    }
}

/// Captures warnings while alive.
struct WarningCapture {
    std::vector<std::string> messages;
    LogHandler old;
    WarningCapture() {
        old = set_log_handler([this](LogLevel l, const std::string& m) {
            if (l == LogLevel::warning) messages.push_back(m);
        });
    }
    ~WarningCapture() { set_log_handler(old); }
};

template <typename T>
void put_le(std::string& s, T v) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    s.append(b, sizeof(T));
}
template <typename T>
void put_be(std::string& s, T v) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    for (std::size_t i = 0; i < sizeof(T); ++i) s.push_back(b[sizeof(T) - 1 - i]);
}

std::string error_of(const std::function<void()>& f) {
    try {
        f();
    } catch (const Error& e) {
        return e.what();
    }
    return "(no error)";
}

}  // namespace

TEST_CASE("PLY point round trip in all three encodings", "[io]") {
    TempDir dir;
    const PointCloud c = full_cloud();
    for (PlyEncoding enc : {PlyEncoding::binary_little_endian, PlyEncoding::binary_big_endian,
                            PlyEncoding::ascii}) {
        WriteOptions w;
        w.encoding = enc;
        const std::string path = dir.file("cloud.ply");
        write_points(path, c, w);
        const ReadResult r = read_points(path);
        CAPTURE(r.format);
        require_same(c, r.cloud);
        REQUIRE(r.dropped_nonfinite == 0);
    }
}

TEST_CASE("PLY mesh round trip keeps faces, normals and colours", "[io]") {
    TempDir dir;
    Mesh m;
    m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    m.normals = {{0, 0, 1}, {1, 0, 0}, {0, 1, 0}, {0.6f, 0.8f, 0}};
    m.colors = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}};
    m.faces = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
    for (const char* name : {"m.ply", "m.obj"}) {
        for (PlyEncoding enc : {PlyEncoding::binary_little_endian,
                                PlyEncoding::binary_big_endian, PlyEncoding::ascii}) {
            WriteOptions w;
            w.encoding = enc;
            write_mesh(dir.file(name), m, w);
            const Mesh r = read_mesh(dir.file(name));
            REQUIRE(r.vertices == m.vertices);
            REQUIRE(r.faces == m.faces);
            REQUIRE(r.normals == m.normals);
            REQUIRE(r.colors.size() == m.colors.size());
        }
    }
}

TEST_CASE("PLY reader: any property order, every scalar type and alias", "[io]") {
    TempDir dir;
    // Two vertices; properties in a deliberately odd order with mixed types, plus an
    // unrelated element before and a face element (with lists) after the vertices.
    const std::string header_props =
        "element camera 1\n"
        "property list uchar float params\n"
        "property int16 id\n"
        "element vertex 2\n"
        "property uchar red\n"
        "property float64 z\n"
        "property short flags\n"
        "property list uint8 int32 junk\n"
        "property double x\n"
        "property uint8 green\n"
        "property float32 nz\n"
        "property int8 tag\n"
        "property float ny\n"
        "property ushort quality\n"
        "property uint blue\n"
        "property float nx\n"
        "property float value\n"
        "property int y\n"
        "property float confidence\n"
        "element face 1\n"
        "property list uchar int vertex_indices\n";
    struct V {
        unsigned char r;
        double z;
        short flags;
        double x;
        unsigned char g;
        float nz;
        signed char tag;
        float ny;
        unsigned short q;
        unsigned b;
        float nx;
        float value;
        int y;
        float conf;
    };
    const V vs[2] = {{255, -1.5, -3, 2.25, 0, 1.0f, -7, 0.0f, 65535, 255, 0.0f, 0.5f, -4, 0.75f},
                     {0, 3.0, 12, -0.5, 51, 0.0f, 100, 1.0f, 0, 102, 0.0f, 0.25f, 9, 1.0f}};
    for (int mode = 0; mode < 3; ++mode) {
        std::string body;
        const bool be = mode == 1;
        auto put = [&](auto v) { be ? put_be(body, v) : put_le(body, v); };
        if (mode == 2) {
            body = "3 0.5 1.5 2.5 -2\n";
            for (const V& v : vs) {
                std::ostringstream s;
                s << int(v.r) << ' ' << v.z << ' ' << v.flags << " 2 7 8 " << v.x << ' '
                  << int(v.g) << ' ' << v.nz << ' ' << int(v.tag) << ' ' << v.ny << ' ' << v.q
                  << ' ' << v.b << ' ' << v.nx << ' ' << v.value << ' ' << v.y << ' ' << v.conf
                  << '\n';
                body += s.str();
            }
            body += "3 0 1 1\n";
        } else {
            put(std::uint8_t(3));
            put(0.5f), put(1.5f), put(2.5f);
            put(std::int16_t(-2));
            for (const V& v : vs) {
                put(v.r), put(v.z), put(v.flags);
                put(std::uint8_t(2)), put(std::int32_t(7)), put(std::int32_t(8));
                put(v.x), put(v.g), put(v.nz), put(v.tag), put(v.ny), put(v.q), put(v.b);
                put(v.nx), put(v.value), put(v.y), put(v.conf);
            }
            put(std::uint8_t(3)), put(std::int32_t(0)), put(std::int32_t(1)), put(std::int32_t(1));
        }
        const char* fmt[] = {"binary_little_endian", "binary_big_endian", "ascii"};
        const std::string path = dir.file("odd.ply");
        write_bytes(path, std::string("ply\nformat ") + fmt[mode] + " 1.0\ncomment odd\n" +
                              header_props + "end_header\n" + body);
        const ReadResult r = read_points(path);
        CAPTURE(fmt[mode]);
        REQUIRE(r.cloud.size() == 2);
        for (int i = 0; i < 2; ++i) {
            REQUIRE(r.cloud.positions[i][0] == float(vs[i].x));
            REQUIRE(r.cloud.positions[i][1] == float(vs[i].y));
            REQUIRE(r.cloud.positions[i][2] == float(vs[i].z));
            REQUIRE(r.cloud.normals[i] == Vec3f{vs[i].nx, vs[i].ny, vs[i].nz});
            REQUIRE(r.cloud.scales[i] == vs[i].value);
            REQUIRE(r.cloud.confidences[i] == vs[i].conf);
            REQUIRE(r.cloud.colors[i][0] == Approx(vs[i].r / 255.0));
            REQUIRE(r.cloud.colors[i][1] == Approx(vs[i].g / 255.0));
            REQUIRE(r.cloud.colors[i][2] == Approx(vs[i].b / 255.0));
        }
    }
}

TEST_CASE("PLY reader: float colours and MVE 'value' scale", "[io]") {
    TempDir dir;
    const std::string path = dir.file("c.ply");
    write_bytes(path,
                "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                "property float z\nproperty float red\nproperty float green\nproperty float blue\n"
                "property float scale\nend_header\n1 2 3 0.25 0.5 1 0.01\n");
    const ReadResult r = read_points(path);
    REQUIRE(r.cloud.colors[0] == Vec3f{0.25f, 0.5f, 1.0f});
    REQUIRE(r.cloud.scales[0] == 0.01f);
    REQUIRE_FALSE(r.cloud.has_normals());
}

TEST_CASE("PLY reader errors name the file and the problem", "[io]") {
    TempDir dir;
    const std::string path = dir.file("bad.ply");
    const std::string head =
        "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
        "property float y\nproperty float z\nend_header\n";

    SECTION("truncated binary body") {
        std::string body;
        for (int i = 0; i < 7; ++i) put_le(body, float(i));  // 2 whole vertices + 1 float
        body += "ab";
        // The size check catches it before parsing: the header promises more than the file has.
        write_bytes(path, head + body);
        const std::string e = error_of([&] { read_points(path); });
        REQUIRE(e == path + ": vertex 2: truncated binary data (the header declares 3 rows, the "
                            "file holds 2)");
    }
    SECTION("truncated list data reports the row") {
        std::string h =
            "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n"
            "property float y\nproperty float z\nproperty list uchar float extra\nend_header\n";
        std::string body;
        for (int i = 0; i < 3; ++i) put_le(body, float(i));
        put_le(body, std::uint8_t(0));
        for (int i = 0; i < 3; ++i) put_le(body, float(i));
        put_le(body, std::uint8_t(1));
        body += "xy";  // half a float
        write_bytes(path, h + body);
        REQUIRE(error_of([&] { read_points(path); }) ==
                path + ": vertex 1: list 'extra' of length 1 runs past the end of the file");
    }
    SECTION("malformed headers and bodies") {
        const std::string xyz = "property float x\nproperty float y\nproperty float z\n";
        const struct {
            std::string content, message;
        } cases[] = {
            {"ply\nformat ascii 1.0\nelement vertex 2\n" + xyz + "end_header\n1 2 3\n4 5\n",
             "vertex 1: unexpected end of file"},
            {"ply\nformat ascii 1.0\nelement vertex 1\n" + xyz + "end_header\n1 two 3\n",
             "vertex 0: 'two' is not a number"},
            {"ply\nformat ascii 1.0\nelement vertex 1\nproperty float y\nproperty float z\n"
             "end_header\n2 3\n",
             "element 'vertex' has no 'x' property"},
            {"ply\nformat binary_middle_endian 1.0\nelement vertex 0\nend_header\n",
             "header line 2: unknown format 'binary_middle_endian'"},
            {"ply\nformat ascii 1.0\nelement vertex 10\nproperty float x\n",
             "header has no end_header line (truncated?)"},
            {"", "file is empty"},
            {"ply\nformat ascii 1.0\nelement vertex 0\n" + xyz + "end_header\n",
             "contains no points"},
            // An absurd count is refused before anything is allocated.
            {"ply\nformat binary_little_endian 1.0\nelement vertex 999999999999\n" + xyz +
                 "end_header\n",
             "vertex 0: truncated binary data (the header declares 999999999999 rows, the file "
             "holds 0)"},
        };
        for (const auto& c : cases) {
            write_bytes(path, c.content);
            REQUIRE(error_of([&] { read_points(path); }) == path + ": " + c.message);
        }
    }
    SECTION("missing file and directory") {
        REQUIRE_THAT(error_of([&] { read_points(dir.file("nope.ply")); }),
                     Catch::StartsWith(dir.file("nope.ply") + ": cannot open"));
        REQUIRE_THROWS_AS(read_points(dir.path()), IoError);
        REQUIRE(error_of([&] { read_points(dir.path()); }) ==
                dir.path() + ": is a directory, not a file");
    }
}

TEST_CASE("NaN and inf rows are dropped with a counted warning", "[io]") {
    TempDir dir;
    const std::string path = dir.file("nan.xyz");
    write_bytes(path, "0 0 0\nnan 1 2\n1 1 1\n3 inf 4\n-inf 0 0\n2 2 2\n");
    WarningCapture w;
    const ReadResult r = read_points(path);
    REQUIRE(r.rows == 6);
    REQUIRE(r.dropped_nonfinite == 3);
    REQUIRE(r.cloud.positions == std::vector<Vec3f>{{0, 0, 0}, {1, 1, 1}, {2, 2, 2}});
    REQUIRE(w.messages.size() == 1);
    REQUIRE_THAT(w.messages[0], Catch::Contains("dropped 3 of 6 rows"));

    ReadOptions strict;
    strict.non_finite = NonFinitePolicy::error;
    REQUIRE(error_of([&] { read_points(path, strict); }) ==
            path + ": row 1: NaN or infinite coordinate");
}

TEST_CASE("zero and NaN normals are flagged, others normalised", "[io]") {
    TempDir dir;
    const std::string path = dir.file("n.xyz");
    write_bytes(path, "0 0 0 0 0 2\n1 0 0 0 0 0\n2 0 0 nan 0 1\n");
    WarningCapture w;
    const ReadResult r = read_points(path);
    REQUIRE(r.invalid_normals == 2);
    REQUIRE(r.cloud.normals[0] == Vec3f{0, 0, 1});
    REQUIRE(r.cloud.normals[1] == Vec3f{0, 0, 0});
    REQUIRE(r.cloud.normals[2] == Vec3f{0, 0, 0});
}

TEST_CASE("XYZ text: 3 and 6 columns, PTS count line, comments", "[io]") {
    TempDir dir;
    write_bytes(dir.file("a.xyz"), "# comment\n1 2 3\n4,5,6\n\n7\t8 9\n");
    ReadResult r = read_points(dir.file("a.xyz"));
    REQUIRE(r.cloud.positions == std::vector<Vec3f>{{1, 2, 3}, {4, 5, 6}, {7, 8, 9}});
    REQUIRE_FALSE(r.cloud.has_normals());

    write_bytes(dir.file("b.xyz"), "1 2 3 0 0 1\n4 5 6 0 -1 0\n");
    r = read_points(dir.file("b.xyz"));
    REQUIRE(r.cloud.normals == std::vector<Vec3f>{{0, 0, 1}, {0, -1, 0}});

    write_bytes(dir.file("c.pts"), "2\n1 2 3 10 255 0 0\n4 5 6 10 0 255 0\n");
    r = read_points(dir.file("c.pts"));
    REQUIRE(r.cloud.size() == 2);
    REQUIRE(r.cloud.colors[1] == Vec3f{0, 1, 0});

    write_bytes(dir.file("d.xyz"), "1 2 3\n4 5\n");
    REQUIRE(error_of([&] { read_points(dir.file("d.xyz")); }) ==
            dir.file("d.xyz") + ": line 2: expected 3 numbers, found 2");

    // Round trip through the XYZ writer.
    PointCloud c = sample_sphere(50, 1.0);
    write_points(dir.file("e.xyz"), c);
    r = read_points(dir.file("e.xyz"));
    REQUIRE(r.cloud.positions == c.positions);
    REQUIRE(r.cloud.normals == c.normals);
}

TEST_CASE("OBJ: v/vn pairs and f-mapped normals", "[io]") {
    TempDir dir;
    write_bytes(dir.file("a.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn 0 0 1\nvn 0 0 1\n");
    ReadResult r = read_points(dir.file("a.obj"));
    REQUIRE(r.cloud.size() == 3);
    REQUIRE(r.cloud.normals[2] == Vec3f{0, 0, 1});

    write_bytes(dir.file("b.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 -1\nf 1//1 2//1 3//1\n");
    r = read_points(dir.file("b.obj"));
    REQUIRE(r.cloud.normals == std::vector<Vec3f>(3, Vec3f{0, 0, -1}));
    const Mesh m = read_mesh(dir.file("b.obj"));
    REQUIRE(m.faces == std::vector<Triangle>{{0, 1, 2}});

    write_bytes(dir.file("c.obj"), "v 0 0 0\nf 1 2 3\n");
    REQUIRE(error_of([&] { read_points(dir.file("c.obj")); }) ==
            dir.file("c.obj") + ": line 2: face vertex index out of range");
}

TEST_CASE("georeferenced coordinates keep their precision in a local frame", "[io]") {
    TempDir dir;
    // 1 mm apart at 1e7 m: a float would round these to the same value (spacing 1 m).
    std::string text;
    for (int i = 0; i < 10; ++i) {
        text += "10000000." + std::to_string(100 + i) + " 5000000.5 12.25\n";
    }
    write_bytes(dir.file("geo.xyz"), text);
    const ReadResult r = read_points(dir.file("geo.xyz"));
    REQUIRE(r.cloud.origin[0] != 0.0);
    for (int i = 1; i < 10; ++i) {
        const double dx = double(r.cloud.positions[i][0]) - double(r.cloud.positions[i - 1][0]);
        REQUIRE(dx == Approx(0.001).margin(1e-6));
    }
    // Written back in double precision, world coordinates survive.
    write_points(dir.file("geo.ply"), r.cloud);
    const ReadResult back = read_points(dir.file("geo.ply"));
    REQUIRE(back.cloud.origin == r.cloud.origin);
    REQUIRE(back.cloud.positions == r.cloud.positions);
}

TEST_CASE("PLY float coordinates: read in place, from a mapped file in chunks, as from doubles",
          "[io]") {
    // 1.1M rows (two chunks of the mapped reader), far from the origin (a local frame), with
    // NaN rows; the same values written as doubles read to the same cloud.
    const std::size_t n = 1100000;
    const auto header = [&](const char* type) {
        return std::string("ply\nformat binary_little_endian 1.0\nelement vertex ") +
               std::to_string(n) + "\nproperty " + type + " x\nproperty " + type +
               " y\nproperty " + type + " z\nproperty float nx\nproperty float ny\n"
               "property float nz\nend_header\n";
    };
    std::string as_float = header("float"), as_double = header("double");
    for (std::size_t i = 0; i < n; ++i) {
        const float p[3] = {100000.0f + float(i % 1000) * 0.125f, -50000.0f + float(i / 1000),
                            i % 99991 == 7 ? std::nanf("") : 20.0f + float(i % 7)};
        for (float v : p) {
            put_le(as_float, v);
            put_le(as_double, double(v));
        }
        for (float v : {0.0f, 0.6f, 0.8f}) {
            put_le(as_float, v);
            put_le(as_double, v);
        }
    }
    TempDir dir;
    write_bytes(dir.file("f.ply"), as_float);
    write_bytes(dir.file("d.ply"), as_double);
    WarningCapture w;  // the NaN rows' warnings
    const ReadResult f = read_points(dir.file("f.ply"));
    const ReadResult d = read_points(dir.file("d.ply"));
    const ReadResult m = read_points_from_memory(as_float, "f.ply");
    REQUIRE(f.rows == n);
    REQUIRE(f.dropped_nonfinite == 12);
    REQUIRE(f.cloud.origin[0] != 0.0);
    for (const ReadResult* r : {&d, &m}) {
        REQUIRE(r->dropped_nonfinite == f.dropped_nonfinite);
        REQUIRE(r->cloud.origin == f.cloud.origin);
        require_same(r->cloud, f.cloud);
    }
    // Each kept row is its file value less the origin, rounded once.
    const Vec3f& q = f.cloud.positions[5];
    REQUIRE(q[0] == float(double(100000.0f + 5 * 0.125f) - f.cloud.origin[0]));
}

TEST_CASE("writes are atomic: failures leave no file behind", "[io]") {
    TempDir dir;
    const PointCloud c = sample_sphere(10, 1.0);
    REQUIRE_THROWS_AS(write_points(dir.file("missing/dir/x.ply"), c), IoError);
    REQUIRE(count_files(dir.path()) == 0);
    REQUIRE_THROWS_AS(write_points(dir.file("x.stl"), c), InvalidArgument);
    REQUIRE(count_files(dir.path()) == 0);
    // A good write leaves exactly the target (no temp files).
    write_points(dir.file("x.ply"), c);
    REQUIRE(count_files(dir.path()) == 1);
}

TEST_CASE("writes replace an older file, a link to one and a hard-linked one as rename would",
          "[io]") {
    TempDir dir;
    const PointCloud small = sample_sphere(10, 1.0), large = sample_sphere(20, 1.0);
    REQUIRE(small.size() != large.size());
    const std::string x = dir.file("x.ply"), y = dir.file("y.ply"), z = dir.file("z.ply");
    write_points(x, small);
    write_points(x, large);  // swapped with the older file, which is then removed
    REQUIRE(count_files(dir.path()) == 1);
    REQUIRE(read_points(x).cloud.size() == large.size());
    // A symbolic link at the target is replaced, not followed: its target keeps its data.
    write_points(y, small);
    REQUIRE(::unlink(x.c_str()) == 0);
    REQUIRE(::symlink(y.c_str(), x.c_str()) == 0);
    write_points(x, large);
    struct stat st {};
    REQUIRE(::lstat(x.c_str(), &st) == 0);
    REQUIRE(S_ISREG(st.st_mode));
    REQUIRE(read_points(y).cloud.size() == small.size());
    // A second hard link keeps the old data; the target gets the new.
    REQUIRE(::link(y.c_str(), z.c_str()) == 0);
    write_points(y, large);
    REQUIRE(read_points(y).cloud.size() == large.size());
    REQUIRE(read_points(z).cloud.size() == small.size());
    REQUIRE(count_files(dir.path()) == 3);
    // A directory at the target is refused and left as it was.
    const std::string d = dir.file("d.ply");
    REQUIRE(::mkdir(d.c_str(), 0755) == 0);
    REQUIRE_THROWS_AS(write_points(d, small), IoError);
    REQUIRE(::stat(d.c_str(), &st) == 0);
    REQUIRE(S_ISDIR(st.st_mode));
    REQUIRE(count_files(dir.path()) == 4);
}

TEST_CASE("LAS: the Autzen tile reads as its PLY twin; classes filter; LAZ is refused", "[io][las]") {
    const std::string las = shared_data("pdal_autzen/autzen_trim.las");
    const std::string ply = shared_data("pdal_autzen/autzen_trim.ply");
    if (las.empty() || ply.empty()) return;
    const ReadResult a = read_points(las);  // local frame: origin + float offsets
    ReadOptions world;
    world.local_frame = false;  // the twin is near 0 already
    const ReadResult b = read_points(ply, world);
    REQUIRE(a.format == "las");
    REQUIRE(a.cloud.size() == 110000);
    REQUIRE(b.cloud.size() == a.cloud.size());
    // The twin is shifted by (-636000, -848900, 0) and stored as float.
    double worst = 0.0;
    for (std::size_t i = 0; i < a.cloud.size(); ++i) {
        const double shift[3] = {636000.0, 848900.0, 0.0};
        for (int k = 0; k < 3; ++k) {
            const double x = a.cloud.origin[k] + double(a.cloud.positions[i][k]);
            const double y = double(b.cloud.positions[i][k]) + shift[k];
            worst = std::max(worst, std::fabs(x - y));
        }
    }
    INFO("largest coordinate difference " << worst << " ft (the twin stores float)");
    CHECK(worst < 1e-3);  // LAS scale 0.01 ft; the float twin rounds to ~6e-5
    // Colours: the twin has them as 8 bits of the LAS's 16.
    REQUIRE(a.cloud.has_colors());
    double colour = 0.0;
    for (std::size_t i = 0; i < a.cloud.size(); ++i) {
        for (int k = 0; k < 3; ++k) {
            colour = std::max(colour, double(std::fabs(a.cloud.colors[i][k] - b.cloud.colors[i][k])));
        }
    }
    CHECK(colour < 1.5 / 255.0);
    // Classes: 83,893 of class 1, 26,107 of class 2 (MANIFEST).
    ReadOptions ground;
    ground.classes = {2};
    CHECK(read_points(las, ground).cloud.size() == 26107);
    ground.classes = {1, 2};
    CHECK(read_points(las, ground).cloud.size() == 110000);
    // Per-point attributes: classification, intensity, returns (up to 4 in this tile).
    const LasAttributes& at = a.las;
    REQUIRE(at.classification.size() == a.cloud.size());
    REQUIRE(at.intensity.size() == a.cloud.size());
    REQUIRE(at.return_number.size() == a.cloud.size());
    REQUIRE(at.number_of_returns.size() == a.cloud.size());
    CHECK(std::count(at.classification.begin(), at.classification.end(), 1) == 83893);
    CHECK(std::count(at.classification.begin(), at.classification.end(), 2) == 26107);
    std::size_t bad_returns = 0, multiple = 0;
    for (std::size_t i = 0; i < a.cloud.size(); ++i) {
        bad_returns += at.return_number[i] < 1 || at.return_number[i] > at.number_of_returns[i] ||
                       at.number_of_returns[i] > 4;
        multiple += at.number_of_returns[i] > 1;
    }
    CHECK(bad_returns == 0);
    CHECK(multiple > 1000);
    CHECK(*std::max_element(at.intensity.begin(), at.intensity.end()) > 0);
    ground.classes = {2};
    const ReadResult g = read_points(las, ground);
    REQUIRE(g.las.classification.size() == 26107);
    CHECK(std::count(g.las.classification.begin(), g.las.classification.end(), 2) == 26107);
    CHECK(b.las.empty());  // other formats have none
    // Classes on a non-LAS file, a LAZ file and a truncated LAS: one-line errors naming the file.
    REQUIRE_THROWS_WITH(read_points(ply, ground), Catch::Contains("autzen_trim.ply") &&
                                                      Catch::Contains("LAS"));
    TempDir dir;
    std::string bytes = read_bytes(las);
    bytes[104] = char(std::uint8_t(bytes[104]) | 0x80);  // LASzip's compression bit
    write_bytes(dir.file("tile.laz"), bytes);
    REQUIRE_THROWS_WITH(read_points(dir.file("tile.laz")), Catch::Contains("tile.laz") &&
                                                               Catch::Contains("laszip"));
    write_bytes(dir.file("cut.las"), read_bytes(las).substr(0, 100000));
    REQUIRE_THROWS_WITH(read_points(dir.file("cut.las")), Catch::Contains("cut.las") &&
                                                              Catch::Contains("truncated"));
}

namespace {

/// make_density's definition: the sdf's topology copied, every active voxel given its density
/// and switched off where that is 0, then pruned.
openvdb::FloatTree::Ptr density_by_definition(const openvdb::FloatGrid& sdf) {
    const float ramp = float(1.5 * sdf.voxelSize()[0]);
    auto tree =
        std::make_shared<openvdb::FloatTree>(sdf.tree(), 0.0f, 0.0f, openvdb::TopologyCopy());
    for (auto leaf = tree->beginLeaf(); leaf; ++leaf) {
        const auto* src = sdf.tree().probeConstLeaf(leaf->origin());
        for (auto it = leaf->beginValueOn(); it; ++it) {
            const float d = std::clamp(0.5f - src->getValue(it.pos()) / (2.0f * ramp), 0.0f, 1.0f);
            it.setValue(d);
            if (d == 0.0f) it.setValueOff();
        }
    }
    tree->prune(0.0f);
    return tree;
}

/// The same nodes, tiles, values and states.
void require_same_tree(const openvdb::FloatTree& a, const openvdb::FloatTree& b) {
    REQUIRE(a.leafCount() == b.leafCount());
    REQUIRE(a.nonLeafCount() == b.nonLeafCount());
    REQUIRE(a.activeTileCount() == b.activeTileCount());
    REQUIRE(a.activeVoxelCount() == b.activeVoxelCount());
    for (auto leaf = a.cbeginLeaf(); leaf; ++leaf) {
        const auto* other = b.probeConstLeaf(leaf->origin());
        REQUIRE(other != nullptr);
        REQUIRE(other->getValueMask() == leaf->getValueMask());
        for (openvdb::Index i = 0; i < 512; ++i) REQUIRE(other->getValue(i) == leaf->getValue(i));
    }
    for (auto it = a.cbeginValueOn(); it; ++it) {
        if (it.isVoxelValue()) continue;  // tiles: the same value, as a tile of the same size
        REQUIRE(b.getValue(it.getCoord()) == *it);
        REQUIRE(b.getValueDepth(it.getCoord()) == a.getValueDepth(it.getCoord()));
    }
}

}  // namespace

TEST_CASE("vdb files: the density grid is the sdf's valid voxels' ramp, pruned", "[io]") {
    // A sphere's narrow band, a leaf wholly inside (density 1 everywhere: a tile), one wholly
    // outside (density 0: no leaf), one half of each.
    const float voxel = 0.1f;
    openvdb::FloatGrid::Ptr sdf = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
        2.0f, openvdb::Vec3f(0.0f), voxel, 3.0f);
    auto fill_leaf = [&](const openvdb::Coord& origin, auto value) {
        auto* leaf = sdf->tree().touchLeaf(origin);
        for (openvdb::Index i = 0; i < 512; ++i) leaf->setValueOn(i, value(i));
    };
    fill_leaf(openvdb::Coord(400, 0, 0), [&](openvdb::Index) { return -2.0f * voxel; });
    fill_leaf(openvdb::Coord(408, 0, 0), [&](openvdb::Index) { return 2.0f * voxel; });
    fill_leaf(openvdb::Coord(416, 0, 0),
              [&](openvdb::Index i) { return i < 256 ? -voxel : voxel; });
    // Active and inactive voxels interleaved, densities 0, 1 and between, and -0.
    auto* mixed = sdf->tree().touchLeaf(openvdb::Coord(424, 0, 0));
    for (openvdb::Index i = 0; i < 512; ++i) {
        const float v = i == 5 ? -0.0f : 0.4f * voxel * (float(i % 11) - 5.0f);
        if (i % 3 == 0) {
            mixed->setValueOff(i, -v);
        } else {
            mixed->setValueOn(i, v);
        }
    }
    REQUIRE_FALSE(sdf->tree().hasActiveTiles());
    {
        // The same tree without the AVX-512 form of the voxels' ramp.
        ::setenv("VDBRECON_NO_AVX512", "1", 1);
        const openvdb::FloatGrid::Ptr narrow = make_density(*sdf);
        ::unsetenv("VDBRECON_NO_AVX512");
        require_same_tree(narrow->tree(), *density_by_definition(*sdf));
    }
    const openvdb::FloatGrid::Ptr density = make_density(*sdf);
    REQUIRE(density->getName() == "density");
    REQUIRE(density->getGridClass() == openvdb::GRID_FOG_VOLUME);
    require_same_tree(density->tree(), *density_by_definition(*sdf));
    REQUIRE(density->tree().getValueDepth(openvdb::Coord(403, 3, 3)) == 2);  // a leaf-sized tile
    REQUIRE(density->tree().getValue(openvdb::Coord(403, 3, 3)) == 1.0f);
    REQUIRE(density->tree().probeConstLeaf(openvdb::Coord(408, 0, 0)) == nullptr);
    REQUIRE(density->tree().getValue(openvdb::Coord(0, 0, 20)) == 0.5f);  // on the surface

    // An sdf with an active tile (a closed volume's interior) keeps it, as a tile of 0.
    sdf->tree().addTile(1, openvdb::Coord(800, 0, 0), -1.0f, true);
    REQUIRE(sdf->tree().hasActiveTiles());
    const openvdb::FloatGrid::Ptr with_tile = make_density(*sdf);
    require_same_tree(with_tile->tree(), *density_by_definition(*sdf));
    REQUIRE(with_tile->tree().isValueOn(openvdb::Coord(803, 3, 3)));
}

TEST_CASE("vdb files: the bytes openvdb::io::File writes, with a UUID from the content", "[io]") {
    // write_volume writes the leaf buffers itself (src/vdb_file.cpp). Leaves are made to take
    // every one of the format's seven ways of storing inactive values, in both orders where the
    // order matters, with NaN and -0, in float and Vec3f grids (backgrounds 0 and not), beside
    // tiles and an empty grid.
    initialize_openvdb();
    const float bg = 0.3f;
    Volume v;
    v.voxel_size = 0.1;
    v.sdf = openvdb::FloatGrid::create(bg);
    v.sdf->setName("sdf");
    v.sdf->setGridClass(openvdb::GRID_LEVEL_SET);
    v.sdf->setTransform(openvdb::math::Transform::createLinearTransform(0.1));
    const float nan = std::numeric_limits<float>::quiet_NaN();
    // Inactive values of each leaf (in the order met), beside one active voxel at its corner.
    const std::vector<std::vector<float>> leaves = {
        {},           {-bg},        {bg, -bg},        {-bg, bg}, {0.5f},          {0.5f, bg},
        {bg, 0.5f},   {0.5f, 0.7f}, {0.5f, 0.7f, bg}, {nan},     {nan, nan, nan}, {bg, nan},
        {-0.0f, 0.0f}};
    auto acc = v.sdf->getAccessor();
    for (std::size_t l = 0; l < leaves.size(); ++l) {
        const openvdb::Coord o(int(8 * l), 0, 0);
        for (int i = 0; i < 512; ++i) {
            const openvdb::Coord c = o + openvdb::Coord(i >> 6, (i >> 3) & 7, i & 7);
            const std::vector<float>& vals = leaves[l];
            if (i == 0 || vals.empty()) {
                acc.setValueOn(c, -0.01f * float(i % 7));
            } else {
                acc.setValueOff(c, vals[std::size_t(i) % vals.size()]);
            }
        }
    }
    v.sdf->tree().addTile(1, openvdb::Coord(4096, 0, 0), -bg, false);    // inactive tile, inside
    v.sdf->tree().addTile(1, openvdb::Coord(4096, 128, 0), 0.1f, true);  // active tile
    v.weight = openvdb::FloatGrid::create(0.0f);
    v.weight->setName("weight");
    v.weight->tree().topologyUnion(v.sdf->tree());
    v.weight->tree().setValueOff(openvdb::Coord(1, 0, 0), -0.0f);
    v.nearest = openvdb::Vec3fGrid::create();
    v.nearest->setName("nearest");
    auto nacc = v.nearest->getAccessor();
    nacc.setValueOn(openvdb::Coord(0, 0, 0), openvdb::Vec3f(1, 2, 3));
    nacc.setValueOff(openvdb::Coord(0, 0, 1), openvdb::Vec3f(0, 0, -0.0f));
    nacc.setValueOn(openvdb::Coord(16, 0, 0), openvdb::Vec3f(4, 5, 6));
    nacc.setValueOff(openvdb::Coord(16, 0, 1), openvdb::Vec3f(0, 1, 0));
    nacc.setValueOff(openvdb::Coord(16, 0, 2), openvdb::Vec3f(0, 2, 0));
    nacc.setValueOff(openvdb::Coord(16, 0, 3), openvdb::Vec3f(0, 3, 0));
    // Vec3f leaves beside a background other than 0: inactive values -bg only, +bg and -bg
    // in both orders, and -bg with another value.
    const openvdb::Vec3f cbg(0.5f, -1.0f, 2.0f);
    v.color = openvdb::Vec3fGrid::create(cbg);
    v.color->setName("color");
    auto cacc = v.color->getAccessor();
    const std::vector<std::vector<openvdb::Vec3f>> cleaves = {
        {-cbg}, {cbg, -cbg}, {-cbg, cbg}, {-cbg, openvdb::Vec3f(0.5f, 1.0f, 2.0f)}};
    for (std::size_t l = 0; l < cleaves.size(); ++l) {
        const openvdb::Coord o(int(8 * l), 0, 0);
        cacc.setValueOn(o, openvdb::Vec3f(1, 1, 1));
        for (int i = 1; i < 512; ++i) {
            const std::vector<openvdb::Vec3f>& vals = cleaves[l];
            cacc.setValueOff(o + openvdb::Coord(i >> 6, (i >> 3) & 7, i & 7),
                             vals[std::size_t(i) % vals.size()]);
        }
    }
    // Leaves with every other voxel or so active, in a scattered pattern (the writer copies
    // the active values sixteen at a time where AVX-512 is there).
    std::uint32_t state = 12345u;
    for (int i = 0; i < 512; ++i) {
        state = state * 1664525u + 1013904223u;
        const openvdb::Coord c(i >> 6, 64 + ((i >> 3) & 7), i & 7);
        const float x = float(state >> 8) / float(1 << 24);
        if (state >> 31) {
            acc.setValueOn(c, x - 0.5f);
            nacc.setValueOn(c, openvdb::Vec3f(x, -x, 2.0f * x));
        } else {
            acc.setValueOff(c, (state >> 30) & 1 ? bg : -bg);
        }
    }
    v.fill = openvdb::FloatGrid::create(1.0f);
    v.fill->setName("fill");  // empty
    v.metadata["kernel"] = "gaussian";
    for (const auto& g : {openvdb::GridBase::Ptr(v.weight), openvdb::GridBase::Ptr(v.nearest),
                          openvdb::GridBase::Ptr(v.color), openvdb::GridBase::Ptr(v.fill)}) {
        g->setTransform(v.sdf->transform().copy());
    }

    TempDir dir;
    write_volume(dir.file("ours.vdb"), v);
    {
        openvdb::io::File ref(dir.file("openvdb.vdb"));
        ref.setCompression(openvdb::io::COMPRESS_ACTIVE_MASK);
        openvdb::MetaMap meta;
        meta.insertMeta("creator", openvdb::StringMetadata(std::string("vdbrecon ") + version()));
        meta.insertMeta("vdbrecon_voxel_size", openvdb::DoubleMetadata(v.voxel_size));
        meta.insertMeta("vdbrecon_kernel", openvdb::StringMetadata("gaussian"));
        ref.write({v.sdf, v.weight, v.nearest, make_density(*v.sdf), v.color, v.fill}, meta);
    }
    std::string ours = read_bytes(dir.file("ours.vdb"));
    std::string theirs = read_bytes(dir.file("openvdb.vdb"));
    REQUIRE(ours.size() == theirs.size());
    const std::size_t uuid = 8 + 4 + 4 + 4 + 1;
    REQUIRE(ours[uuid + 14] == '5');  // a version-5 UUID, ...
    write_volume(dir.file("again.vdb"), v);
    REQUIRE(read_bytes(dir.file("again.vdb")) == ours);  // ... the same for the same grids,
    {
        // ... another for another value anywhere in the file (the first voxel here).
        Volume other = v;
        other.sdf = v.sdf->deepCopy();
        auto it = other.sdf->tree().beginValueOn();
        REQUIRE(it);
        it.setValue(*it + 0.25f);
        write_volume(dir.file("other.vdb"), other);
        const std::string o = read_bytes(dir.file("other.vdb"));
        REQUIRE(o.size() > uuid + 36);
        REQUIRE(o.compare(uuid, 36, ours, uuid, 36) != 0);
    }
    // The same bytes without the vector forms.
    ::setenv("VDBRECON_NO_AVX512", "1", 1);
    write_volume(dir.file("no_avx512.vdb"), v);
    ::unsetenv("VDBRECON_NO_AVX512");
    REQUIRE(read_bytes(dir.file("no_avx512.vdb")) == ours);
    ours.replace(uuid, 36, 36, '-');
    theirs.replace(uuid, 36, 36, '-');
    REQUIRE(ours == theirs);

    // The file reads back through OpenVDB with every value in place, NaN included.
    const Volume back = read_volume(dir.file("ours.vdb"));
    auto same = [](float a, float b) { return a == b || (std::isnan(a) && std::isnan(b)); };
    for (auto it = v.sdf->tree().cbeginValueAll(); it; ++it) {
        const openvdb::Coord c = it.getCoord();
        REQUIRE(same(back.sdf->tree().getValue(c), *it));
        REQUIRE(back.sdf->tree().isValueOn(c) == it.isValueOn());
    }
    REQUIRE(back.nearest->tree().getValue(openvdb::Coord(16, 0, 2)) == openvdb::Vec3f(0, 2, 0));
}

TEST_CASE("vdb files: half-float, renamed and instanced grids write in full, as their roles",
          "[io]") {
    // A volume read from a file saved with half floats (or whose grids share a tree, or carry
    // other names) is written through copies in full floats under the role names; the caller's
    // grids are left as they were.
    initialize_openvdb();
    TempDir dir;
    Volume v;
    v.voxel_size = 0.5;
    v.sdf = openvdb::FloatGrid::create(1.5f);
    v.sdf->setName("distance");
    v.sdf->setGridClass(openvdb::GRID_LEVEL_SET);
    v.sdf->setTransform(openvdb::math::Transform::createLinearTransform(0.5));
    for (int i = 0; i < 20; ++i)
        v.sdf->tree().setValueOn(openvdb::Coord(i, 0, 0), 0.1f * float(i) - 1.0f);
    v.sdf->setSaveFloatAsHalf(true);
    v.weight = openvdb::FloatGrid::create(v.sdf->treePtr());  // shares the sdf's tree
    v.weight->setName("weight");
    v.weight->setTransform(v.sdf->transform().copy());
    write_volume(dir.file("v.vdb"), v);
    REQUIRE(v.sdf->getName() == "distance");
    REQUIRE(v.sdf->saveFloatAsHalf());
    REQUIRE(&v.weight->tree() == &v.sdf->tree());

    const Volume back = read_volume(dir.file("v.vdb"));
    REQUIRE(back.weight);
    REQUIRE(&back.weight->tree() != &back.sdf->tree());
    for (int i = 0; i < 20; ++i) {
        const openvdb::Coord c(i, 0, 0);
        REQUIRE(back.sdf->tree().getValue(c) == v.sdf->tree().getValue(c));  // full floats
        REQUIRE(back.weight->tree().getValue(c) == v.sdf->tree().getValue(c));
    }
    REQUIRE_FALSE(back.sdf->saveFloatAsHalf());
}
