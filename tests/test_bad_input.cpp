// The bad-input catalogue (issue 6, point 1) and the fuzzers' regression tests (point 4).
//
// Every malformed or degenerate input we know of goes through the real command line, and the
// test checks the whole behaviour. A refusal must exit non-zero, print exactly one error line
// "vdbrecon: error: <file>: <problem>" (warnings may precede it) and leave the directory as it
// was: the out.ply and out.splat.vdb of an earlier run survive byte for byte and no temporary
// file is left. An input that must work must reconstruct the right surface. Inputs are written
// by the tests, never committed.
//
// Item -> test case ("bad input: ..."):
//   empty file                          -> empty file
//   header only                         -> header only, or cut inside the header
//   truncated binary body               -> truncated binary body
//   header claims more vertices         -> header claims more vertices than the file holds
//   a vertex element without x          -> vertex element without x, y or z
//   unknown format line                 -> unknown or malformed format line
//   list property inside vertex         -> list properties inside vertex are skipped; ...
//   big-endian PLY with doubles         -> binary big-endian PLY with double coordinates
//   NaN / inf coordinates               -> NaN and inf coordinates are dropped with a counted ...
//   zero-length and NaN normals         -> zero-length and NaN normals are re-estimated
//   all points identical                -> all points identical; ..., with normals and --voxel
//   a single point                      -> a single point
//   2 points                            -> 2 points (no surface: refused, nothing written)
//   planar scan without thickness       -> a planar scan with no thickness
//   coordinates around 1e7              -> coordinates around 1e7 reconstruct in a local frame
//   --voxel 0, negative, NaN            -> --voxel 0, negative, NaN or inf
//   --voxel too small for memory        -> --voxel so small the grid would not fit in memory
//                                          (the memory budget, issue 6 point 2); also: a
//                                          millimetre-sized scan in metres with a voxel below
//                                          1.5e-5 (OpenVDB's transforms refuse it)
//   output in a missing / read-only dir -> output in a missing or read-only directory
//   input that is a directory           -> input that is a directory
//   pipeline errors name the input      -> errors from the pipeline name the input file
//
// Fuzzing regressions ("fuzz: ..."), read through read_points_from_memory as fuzz/ does:
//   fuzz_ply: a double coordinate of 1e300 became an infinite float
//     -> a coordinate beyond float range is refused, not read as inf
//   fuzz_ply: NUL bytes in an element name cut the message short at the file name
//     -> file text in messages is escaped and cut short
//   review, confirmed by fuzz_ply's UBSan: -1.0 converted to an unsigned row count
//     -> the size check never converts a negative byte count
//   review: an ascii element with no properties and 2^64 rows looped 2^64 times
//     -> an element without properties is skipped however many rows it claims
//   review: 1e-400 was read as inf (and its row dropped), "+-5" as -5
//     -> numbers beyond double's range and doubled signs
//
// Fuzzing regressions of the scene readers (issue 47), read from files as `vdbrecon fuse` reads
// them, with the invalid metadata and the header sizes every scene reader must refuse:
//   fuzz_depth_png: a tEXt chunk claiming 800 MB in a 293-byte file; libpng allocated it
//     -> a PNG chunk longer than its file is refused before libpng allocates it
//   fuzz_depth_exr: an attribute claiming 1.6 GB; a v3f attribute of 8 bytes, after which
//     OpenEXR read out of step with the file
//     -> an EXR file's headers are checked against the file before OpenEXR reads them
//   issue 47, point 2 -> a depth image of another size than its frame's camera is refused
//     unread; an image header claiming more pixels than its file can hold is refused
//   review: "w": 1e300 in transforms.json and cam_params.json went through int(double)
//     -> bad metadata: transforms.json sizes, focal lengths, fields of view and poses; the
//        layouts refuse non-rotations, NaN and unusable intrinsics
//
// The same reader errors are also checked at library level (exact exception text) in
// test_io.cpp: "PLY reader errors name the file and the problem" (empty file, no end_header,
// no x, unknown format, absurd vertex count, truncated body and list), "NaN and inf rows are
// dropped with a counted warning", "zero and NaN normals are flagged, others normalised",
// "georeferenced coordinates keep their precision in a local frame" and "writes are atomic:
// failures leave no file behind". Usage errors that are not about the input (unknown options,
// --voxel abc, a missing input file, -o onto the input) stay in test_cli.cpp.
#include <dirent.h>
#include <sys/stat.h>
#include <zlib.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <vector>

#include "support.h"
#include "vdbrecon/error.h"
#include "vdbrecon/io.h"
#include "vdbrecon/scene.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

#if defined(__SANITIZE_ADDRESS__)
constexpr bool kAddressSanitizer = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
constexpr bool kAddressSanitizer = true;
#else
constexpr bool kAddressSanitizer = false;
#endif
#else
constexpr bool kAddressSanitizer = false;
#endif

constexpr int kAnyFailure = -100;  // run_refused: any non-zero exit code
constexpr double kVoxel = 0.1;     // for the unit spheres of 2000 points (spacing 0.08)
const std::string kXyzFloat = "property float x\nproperty float y\nproperty float z\n";

// ---------------------------------------------------------------------------------------------
// Writing inputs

template <typename T>
void put(std::string& s, T v, bool big_endian) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    if (big_endian) std::reverse(b, b + sizeof(T));
    s.append(b, sizeof(T));
}

std::string ply_header(const std::string& format, const std::string& count,
                       const std::string& properties = kXyzFloat) {
    return "ply\nformat " + format + " 1.0\nelement vertex " + count + "\n" + properties +
           "end_header\n";
}

/// Shortest text that reads back as exactly `v`.
std::string text(float v) {
    char buf[32];
    return std::string(buf, std::to_chars(buf, buf + sizeof(buf), v).ptr);
}

/// "x y z nx ny nz\n" (or "x y z\n"), each number read back exactly.
std::string xyz_row(const PointCloud& c, std::size_t i, bool normals) {
    std::string row =
        text(c.positions[i][0]) + ' ' + text(c.positions[i][1]) + ' ' + text(c.positions[i][2]);
    if (normals) {
        for (float n : c.normals[i]) row += ' ' + text(n);
    }
    return row + '\n';
}

std::string xyz_text(const PointCloud& c, bool normals) {
    std::string s;
    for (std::size_t i = 0; i < c.size(); ++i) s += xyz_row(c, i, normals);
    return s;
}

/// `n` copies of the same point (with an upward normal when `normals`).
std::string identical_points(int n, bool normals) {
    std::string s;
    for (int i = 0; i < n; ++i) s += normals ? "0.5 -0.25 2 0 0 1\n" : "0.5 -0.25 2\n";
    return s;
}

// ---------------------------------------------------------------------------------------------
// Running the command line

/// Every entry under `dir`, recursively, with its bytes ("(directory)" for directories).
void snapshot(const std::string& dir, const std::string& prefix,
              std::map<std::string, std::string>& out) {
    DIR* d = ::opendir(dir.c_str());
    REQUIRE(d != nullptr);
    while (const dirent* e = ::readdir(d)) {
        const std::string name = e->d_name;
        if (name == "." || name == "..") continue;
        const std::string path = dir + "/" + name;
        struct stat st {};
        REQUIRE(::lstat(path.c_str(), &st) == 0);
        if (S_ISDIR(st.st_mode)) {
            out[prefix + name] = "(directory)";
            snapshot(path, prefix + name + "/", out);
        } else {
            out[prefix + name] = read_bytes(path);
        }
    }
    ::closedir(d);
}

std::map<std::string, std::string> snapshot(const std::string& dir) {
    std::map<std::string, std::string> s;
    snapshot(dir, "", s);
    return s;
}

std::vector<std::string> lines(const std::string& s) {
    std::vector<std::string> out;
    std::size_t start = 0;
    while (start < s.size()) {
        const std::size_t eol = s.find('\n', start);
        out.push_back(s.substr(start, eol - start));
        if (eol == std::string::npos) break;
        start = eol + 1;
    }
    return out;
}

/// A directory with the outputs of an earlier run in it, which a failed run must not touch.
struct Workspace {
    TempDir dir;
    std::string out = dir.file("out.ply");

    Workspace() {
        write_bytes(out, "previous mesh\n");
        write_bytes(dir.file("out.splat.vdb"), "previous volume\n");
    }
    /// Writes an input file and returns its path.
    std::string input(const std::string& name, const std::string& bytes) const {
        write_bytes(dir.file(name), bytes);
        return dir.file(name);
    }
    std::string input(const std::string& name, const PointCloud& cloud) const {
        write_points(dir.file(name), cloud);
        return dir.file(name);
    }
};

struct Refusal {
    std::string error;                  ///< the error line without "vdbrecon: error: "
    std::vector<std::string> warnings;  ///< the warning lines without "vdbrecon: warning: "
};

/// Runs `PREFIX vdbrecon INPUT -o OUT -q ARGS` and checks what every refusal must do: exit
/// `code` (any non-zero one for kAnyFailure), nothing on stdout, warning lines and then exactly
/// one error line on stderr, and the workspace exactly as it was.
Refusal run_refused(const Workspace& w, const std::string& input, const std::string& args, int code,
                    const std::string& out = {}, const std::string& prefix = {}) {
    const auto before = snapshot(w.dir.path());
    const CliRun r = run_cli(input + " -o " + (out.empty() ? w.out : out) + " -q " + args, prefix);
    CAPTURE(input, args, r.code, r.err);
    if (code == kAnyFailure) {
        REQUIRE(r.code > 0);
    } else {
        REQUIRE(r.code == code);
    }
    REQUIRE(r.out.empty());
    REQUIRE_THAT(r.err, Catch::EndsWith("\n"));
    const std::vector<std::string> err = lines(r.err);
    REQUIRE_FALSE(err.empty());
    Refusal refusal;
    for (std::size_t i = 0; i + 1 < err.size(); ++i) {
        REQUIRE_THAT(err[i], Catch::StartsWith("vdbrecon: warning: "));
        refusal.warnings.push_back(err[i].substr(19));
    }
    REQUIRE_THAT(err.back(), Catch::StartsWith("vdbrecon: error: "));
    refusal.error = err.back().substr(17);
    REQUIRE(snapshot(w.dir.path()) == before);  // nothing created, changed or left behind
    return refusal;
}

/// A refusal of a bad file: exit 3 and the error "<input>: <problem>" exactly, no warning.
void require_bad_file(const Workspace& w, const std::string& input, const std::string& problem) {
    const Refusal r = run_refused(w, input, "", 3);
    REQUIRE(r.error == input + ": " + problem);
    REQUIRE(r.warnings.empty());
}

struct Success {
    Mesh mesh;
    std::vector<std::string> warnings;
};

/// Runs `vdbrecon INPUT -o OUT -q --no-vdb ARGS`, which must succeed, and reads the mesh back.
Success run_ok(const std::string& input, const std::string& out,
               const std::string& args = "--voxel 0.1") {
    const CliRun r = run_cli(input + " -o " + out + " -q --no-vdb " + args);
    CAPTURE(input, args, r.err);
    REQUIRE(r.code == 0);
    Success s;
    for (const std::string& line : lines(r.err)) {
        REQUIRE_THAT(line, Catch::StartsWith("vdbrecon: warning: "));
        s.warnings.push_back(line.substr(19));
    }
    s.mesh = read_mesh(out);
    return s;
}

/// Every vertex within `tolerance` of the sphere (world coordinates, in double).
void require_on_sphere(const Mesh& m, const Vec3d& centre, double radius, double tolerance) {
    REQUIRE(m.faces.size() > 1000);
    double worst = 0.0;
    for (const Vec3f& v : m.vertices) {
        double d2 = 0.0;
        for (int a = 0; a < 3; ++a) {
            const double d = m.origin[a] + double(v[a]) - centre[a];
            d2 += d * d;
        }
        worst = std::max(worst, std::fabs(std::sqrt(d2) - radius));
    }
    CAPTURE(m.origin[0], m.origin[1], m.origin[2]);
    REQUIRE(worst < tolerance);
    // Closed and facing outwards: the signed volume is the ball's.
    double volume = 0.0;
    for (const Triangle& t : m.faces) {
        const Vec3f &a = m.vertices[t[0]], &b = m.vertices[t[1]], &c = m.vertices[t[2]];
        volume += (double(a[0]) * (double(b[1]) * c[2] - double(b[2]) * c[1]) -
                   double(a[1]) * (double(b[0]) * c[2] - double(b[2]) * c[0]) +
                   double(a[2]) * (double(b[0]) * c[1] - double(b[1]) * c[0])) /
                  6.0;
    }
    REQUIRE(volume == Approx(4.0 / 3.0 * M_PI * radius * radius * radius).epsilon(0.05));
}

/// No hole: every `step`-th sample (world = sample + offset) has a mesh vertex within `reach`.
void require_covers(const Mesh& m, const PointCloud& samples, const Vec3d& offset, double reach,
                    std::size_t step = 10) {
    for (std::size_t i = 0; i < samples.size(); i += step) {
        double best = 1e300;
        for (const Vec3f& v : m.vertices) {
            double d2 = 0.0;
            for (int a = 0; a < 3; ++a) {
                const double d =
                    (m.origin[a] + double(v[a])) - (offset[a] + samples.positions[i][a]);
                d2 += d * d;
            }
            best = std::min(best, d2);
        }
        CAPTURE(i);
        REQUIRE(std::sqrt(best) < reach);
    }
}

void require_same_mesh(const Mesh& a, const Mesh& b) {
    REQUIRE(a.faces.size() > 100);
    REQUIRE(a.origin == b.origin);
    REQUIRE(a.vertices == b.vertices);
    REQUIRE(a.faces == b.faces);
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Malformed files

TEST_CASE("bad input: empty file", "[cli][bad_input]") {
    Workspace w;
    for (const char* name : {"empty.ply", "empty.xyz", "empty.pts", "empty.obj"}) {
        require_bad_file(w, w.input(name, ""), "file is empty");
    }
}

TEST_CASE("bad input: header only, or cut inside the header", "[cli][bad_input]") {
    Workspace w;
    require_bad_file(w, w.input("ascii.ply", ply_header("ascii", "3")),
                     "vertex: the file is too short for its rows (the header declares 3 rows, 0 "
                     "bytes of data)");
    require_bad_file(w, w.input("le.ply", ply_header("binary_little_endian", "3")),
                     "vertex 0: truncated binary data (the header declares 3 rows, the file "
                     "holds 0)");
    require_bad_file(w, w.input("none.ply", ply_header("binary_big_endian", "0")),
                     "contains no points");
    require_bad_file(w, w.input("cut.ply", "ply\nformat ascii 1.0\nelement vertex 5\n" + kXyzFloat),
                     "header has no end_header line (truncated?)");
    require_bad_file(w, w.input("magic.ply", "ply\n"),
                     "header has no end_header line (truncated?)");
    require_bad_file(w, w.input("nomagic.ply", "PLY\n"), "not a PLY file (no 'ply' magic)");
    // The text formats' equivalent: nothing but a count line or comments.
    require_bad_file(w, w.input("count.pts", "3\n"), "contains no points");
    require_bad_file(w, w.input("comments.xyz", "# x y z\n// none\n\n"), "contains no points");
    require_bad_file(w, w.input("names.obj", "# nothing\no thing\ng group\n"),
                     "contains no points");
}

TEST_CASE("bad input: truncated binary body", "[cli][bad_input]") {
    Workspace w;
    for (const bool big : {false, true}) {
        std::string body;
        for (int i = 0; i < 7; ++i) put(body, float(i), big);  // 2 whole vertices and a bit
        const std::string in =
            w.input(big ? "be.ply" : "le.ply",
                    ply_header(big ? "binary_big_endian" : "binary_little_endian", "3") + body);
        require_bad_file(w, in,
                         "vertex 2: truncated binary data (the header declares 3 rows, "
                         "the file holds 2)");
    }
    // With a list property the size check cannot know the row length: the row is named when
    // the data runs out, inside the list or after it.
    const std::string props = kXyzFloat + "property list uchar float extra\n";
    std::string body;
    for (int i = 0; i < 3; ++i) put(body, float(i), false);
    put(body, std::uint8_t(2), false);
    put(body, 1.0f, false);  // one of the two list items
    require_bad_file(w, w.input("list.ply", ply_header("binary_little_endian", "1", props) + body),
                     "vertex 0: list 'extra' of length 2 runs past the end of the file");
    const std::string list_first = "property list uchar float extra\n" + kXyzFloat;
    body.clear();
    put(body, std::uint8_t(3), false);  // a long list, so the file passes the size check
    for (int i = 0; i < 6; ++i) put(body, float(i), false);
    put(body, std::uint8_t(0), false);
    put(body, 1.0f, false);  // x of vertex 1, then nothing
    require_bad_file(
        w, w.input("list2.ply", ply_header("binary_little_endian", "2", list_first) + body),
        "vertex 1: truncated binary data");
}

TEST_CASE("bad input: header claims more vertices than the file holds", "[cli][bad_input]") {
    Workspace w;
    require_bad_file(w, w.input("ascii.ply", ply_header("ascii", "5") + "0 0 0\n1 0 0\n0 1 0\n"),
                     "vertex 3: unexpected end of file");
    std::string body;
    for (int i = 0; i < 30; ++i) put(body, float(i), false);
    require_bad_file(w, w.input("le.ply", ply_header("binary_little_endian", "1000") + body),
                     "vertex 10: truncated binary data (the header declares 1000 rows, the file "
                     "holds 10)");
    // Counts that would need exabytes are refused before anything is allocated.
    require_bad_file(
        w, w.input("huge.ply", ply_header("binary_little_endian", "18446744073709551615") + body),
        "vertex 10: truncated binary data (the header declares "
        "18446744073709551615 rows, the file holds 10)");
    require_bad_file(w, w.input("ascii_huge.ply", ply_header("ascii", "99999999999") + "1 2 3\n"),
                     "vertex: the file is too short for its rows (the header declares "
                     "99999999999 rows, 6 bytes of data)");
    require_bad_file(w, w.input("over.ply", ply_header("ascii", "99999999999999999999")),
                     "header line 3: bad element count '99999999999999999999'");
    require_bad_file(w, w.input("negative.ply", ply_header("ascii", "-1")),
                     "header line 3: bad element count '-1'");
}

TEST_CASE("bad input: vertex element without x, y or z", "[cli][bad_input]") {
    Workspace w;
    require_bad_file(
        w,
        w.input("nox.ply",
                ply_header("ascii", "1", "property float y\nproperty float z\n") + "2 3\n"),
        "element 'vertex' has no 'x' property");
    require_bad_file(w,
                     w.input("noz.ply", ply_header("ascii", "1",
                                                   "property float x\nproperty float y\n"
                                                   "property float nz\n") +
                                            "1 2 3\n"),
                     "element 'vertex' has no 'z' property");
    require_bad_file(w,
                     w.input("novertex.ply", "ply\nformat ascii 1.0\nelement point 1\n" +
                                                 kXyzFloat + "end_header\n1 2 3\n"),
                     "no 'vertex' element");
}

TEST_CASE("bad input: unknown or malformed format line", "[cli][bad_input]") {
    Workspace w;
    const std::string rest = "element vertex 1\n" + kXyzFloat + "end_header\n1 2 3\n";
    const struct {
        std::string format_line, problem;
    } cases[] = {
        {"format binary_middle_endian 1.0\n",
         "header line 2: unknown format 'binary_middle_endian'"},
        {"format ascii 2.0\n", "header line 2: unsupported PLY version '2.0'"},
        {"format ascii\n", "header line 2: malformed format line"},
        {"", "header has no format line"},
        {"formt ascii 1.0\n", "header line 2: unknown header keyword 'formt'"},
    };
    for (const auto& c : cases) {
        require_bad_file(w, w.input("f.ply", "ply\n" + c.format_line + rest), c.problem);
    }
}

TEST_CASE("bad input: list properties inside vertex are skipped; a list x is refused",
          "[cli][bad_input]") {
    Workspace w;
    const PointCloud c = sample_sphere(2000, 1.0);
    const std::string plain = w.input("plain.ply", c);
    // The same points with a list of 0..3 ints between y and z, and one after the normals.
    const std::string props =
        "property float x\nproperty float y\nproperty list uchar int junk\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\n"
        "property list ushort double more\n";
    std::string binary = ply_header("binary_little_endian", std::to_string(c.size()), props);
    std::string ascii = ply_header("ascii", std::to_string(c.size()), props);
    for (std::size_t i = 0; i < c.size(); ++i) {
        const auto& p = c.positions[i];
        const auto& n = c.normals[i];
        const int len = int(i % 4);
        put(binary, p[0], false), put(binary, p[1], false), put(binary, std::uint8_t(len), false);
        ascii += text(p[0]) + ' ' + text(p[1]) + ' ' + std::to_string(len);
        for (int k = 0; k < len; ++k) {
            put(binary, std::int32_t(k - 7), false);
            ascii += ' ' + std::to_string(k - 7);
        }
        put(binary, p[2], false);
        ascii += ' ' + text(p[2]);
        for (float v : n) put(binary, v, false), ascii += ' ' + text(v);
        put(binary, std::uint16_t(1), false), put(binary, 0.5, false);
        ascii += " 1 0.5\n";
    }
    const Success reference = run_ok(plain, w.dir.file("plain.out.ply"));
    require_on_sphere(reference.mesh, {0, 0, 0}, 1.0, 0.25 * kVoxel);
    for (const auto& [name, bytes] : {std::pair{"binary.ply", binary}, {"ascii.ply", ascii}}) {
        const Success s = run_ok(w.input(name, bytes), w.dir.file(std::string("out_") + name));
        REQUIRE(s.warnings.empty());
        require_same_mesh(s.mesh, reference.mesh);
    }
    require_bad_file(w,
                     w.input("listx.ply", ply_header("ascii", "1",
                                                     "property list uchar float x\n"
                                                     "property float y\nproperty float z\n") +
                                              "1 5 2 3\n"),
                     "vertex property 'x' is a list; coordinates must be scalars");
}

// ---------------------------------------------------------------------------------------------
// Unusual but valid files: they must reconstruct the right surface

TEST_CASE("bad input: binary big-endian PLY with double coordinates", "[cli][bad_input]") {
    Workspace w;
    const PointCloud c = sample_sphere(2000, 1.0);
    const std::string le = w.input("le.ply", c);  // float, little endian: the reference
    std::string be = ply_header("binary_big_endian", std::to_string(c.size()),
                                "property double x\nproperty double y\nproperty double z\n"
                                "property double nx\nproperty double ny\nproperty double nz\n");
    for (std::size_t i = 0; i < c.size(); ++i) {
        for (float v : c.positions[i]) put(be, double(v), true);
        for (float v : c.normals[i]) put(be, double(v), true);
    }
    const std::string in = w.input("be.ply", be);
    const ReadResult r = read_points(in);
    REQUIRE(r.format == "ply binary_big_endian");
    REQUIRE(r.cloud.positions == c.positions);
    REQUIRE(r.cloud.normals == c.normals);

    const Success s = run_ok(in, w.dir.file("be.out.ply"));
    REQUIRE(s.warnings.empty());
    require_on_sphere(s.mesh, {0, 0, 0}, 1.0, 0.25 * kVoxel);
    require_same_mesh(s.mesh, run_ok(le, w.dir.file("le.out.ply")).mesh);
}

TEST_CASE("bad input: NaN and inf coordinates are dropped with a counted warning",
          "[cli][bad_input]") {
    Workspace w;
    const PointCloud c = sample_sphere(2000, 1.0);
    std::string bad;
    for (std::size_t i = 0; i < c.size(); ++i) {
        if (i == 5) bad += "nan 0 0 0 0 1\n";
        if (i == 700) bad += "1 inf 0 0 0 1\n";
        if (i == 1999) bad += "-inf 2 -nan 0 0 1\n";
        bad += xyz_row(c, i, true);
    }
    const std::string in = w.input("nan.xyz", bad);
    const Success s = run_ok(in, w.dir.file("nan.out.ply"));
    REQUIRE(s.warnings == std::vector<std::string>{
                              in + ": dropped 3 of 2003 rows with NaN or infinite coordinates "
                                   "(first: row 5)"});
    // Exactly the surface of the clean points.
    const Success clean = run_ok(w.input("clean.xyz", xyz_text(c, true)), w.dir.file("c.ply"));
    require_same_mesh(s.mesh, clean.mesh);

    require_bad_file(w, w.input("allnan.xyz", "nan nan nan\ninf 0 0\n"),
                     "all 2 rows have NaN or infinite coordinates");
    std::string le = ply_header("binary_little_endian", "2");
    for (int i = 0; i < 6; ++i) put(le, std::numeric_limits<float>::quiet_NaN(), false);
    require_bad_file(w, w.input("allnan.ply", le), "all 2 rows have NaN or infinite coordinates");
}

TEST_CASE("bad input: zero-length and NaN normals are re-estimated", "[cli][bad_input]") {
    Workspace w;
    PointCloud c = sample_sphere(2000, 1.0);
    const Success clean = run_ok(w.input("clean.ply", c), w.dir.file("clean.out.ply"));
    std::vector<Vec3f>& normals = c.normals.edit();
    normals[10] = {0, 0, 0};
    normals[20] = {std::numeric_limits<float>::quiet_NaN(), 0, 1};
    normals[1500] = {0, 0, 0};
    const std::string in = w.input("some.ply", c);
    const Success s = run_ok(in, w.dir.file("some.out.ply"));
    REQUIRE(s.warnings == std::vector<std::string>{
                              in + ": 3 normals are zero or NaN; they will be re-estimated"});
    require_on_sphere(s.mesh, {0, 0, 0}, 1.0, 0.25 * kVoxel);
    // Three re-estimated normals barely move the surface.
    REQUIRE(double(s.mesh.vertices.size()) ==
            Approx(double(clean.mesh.vertices.size())).epsilon(0.01));

    for (Vec3f& n : normals) n = {0, 0, 0};
    const std::string none = w.input("none.ply", c);
    const Success all = run_ok(none, w.dir.file("none.out.ply"));
    REQUIRE(all.warnings ==
            std::vector<std::string>{none +
                                     ": 2000 normals are zero or NaN; they will be re-estimated"});
    require_on_sphere(all.mesh, {0, 0, 0}, 1.0, 0.25 * kVoxel);
}

TEST_CASE("bad input: a planar scan with no thickness", "[cli][bad_input]") {
    Workspace w;
    const PointCloud c = sample_plane(40, 1.0);  // z = 0 exactly, spacing 0.05
    for (const bool normals : {true, false}) {
        CAPTURE(normals);
        const std::string in = w.input(normals ? "n.xyz" : "p.xyz", xyz_text(c, normals));
        const Success s = run_ok(in, w.dir.file(normals ? "n.out.ply" : "p.out.ply"));
        REQUIRE(s.warnings.empty());
        const Mesh& m = s.mesh;
        REQUIRE(m.faces.size() > 500);
        float lo = 1e9f, hi = -1e9f;
        for (const Vec3f& v : m.vertices) {
            REQUIRE(std::fabs(v[2]) < 1e-4f);  // flat: no invented thickness
            lo = std::min(lo, v[0]);
            hi = std::max(hi, v[0]);
        }
        REQUIRE(lo < -0.9f);
        REQUIRE(hi > 0.9f);
        REQUIRE(lo > -1.1f - float(kVoxel));
        REQUIRE(hi < 1.1f + float(kVoxel));
        // One consistent side: every face normal is +z, or every one is -z.
        int up = 0, down = 0;
        for (const Triangle& t : m.faces) {
            const Vec3f &a = m.vertices[t[0]], &b = m.vertices[t[1]], &d = m.vertices[t[2]];
            const float nz = (b[0] - a[0]) * (d[1] - a[1]) - (b[1] - a[1]) * (d[0] - a[0]);
            (nz > 0 ? up : down) += 1;
        }
        REQUIRE((up == 0 || down == 0));
        if (normals) REQUIRE(down == 0);  // the file's +z normals are kept
    }
}

TEST_CASE("bad input: coordinates around 1e7 reconstruct in a local frame", "[cli][bad_input]") {
    Workspace w;
    // Georeferenced LiDAR: a unit sphere 10,000 km out, written in full double precision. A float
    // has a spacing of 1 there, so working in world floats would collapse the sphere.
    const Vec3d centre{1e7 + 0.3, 2e7 - 0.7, 123.25};
    const PointCloud c = sample_sphere(2000, 1.0);
    std::string text_rows;
    char buf[32];
    for (std::size_t i = 0; i < c.size(); ++i) {
        for (int a = 0; a < 3; ++a) {
            text_rows += std::string(buf, std::to_chars(buf, buf + sizeof(buf),
                                                        centre[a] + double(c.positions[i][a]))
                                              .ptr) +
                         ' ';
        }
        text_rows += text(c.normals[i][0]) + ' ' + text(c.normals[i][1]) + ' ' +
                     text(c.normals[i][2]) + '\n';
    }
    const std::string in = w.input("geo.xyz", text_rows);
    const Success s = run_ok(in, w.dir.file("geo.out.ply"));
    REQUIRE(s.warnings.empty());
    REQUIRE(s.mesh.origin != Vec3d{0, 0, 0});
    require_on_sphere(s.mesh, centre, 1.0, 0.25 * kVoxel);
    require_covers(s.mesh, c, centre, kVoxel);
}

// ---------------------------------------------------------------------------------------------
// Degenerate clouds

TEST_CASE("bad input: all points identical", "[cli][bad_input]") {
    Workspace w;
    const std::string with_normals = w.input("same.xyz", identical_points(100, true));
    Refusal r = run_refused(w, with_normals, "", 4);
    REQUIRE_THAT(r.error,
                 Catch::EndsWith("cannot choose a voxel size: all points coincide. Hint: --voxel"));
    REQUIRE(r.warnings.empty());

    const std::string bare = w.input("bare.xyz", identical_points(100, false));
    r = run_refused(w, bare, "--voxel 0.1", 4);
    REQUIRE_THAT(r.error, Catch::EndsWith("normals: every neighbourhood is degenerate (all points "
                                          "coincident or collinear); no surface can be "
                                          "reconstructed"));
    REQUIRE(r.warnings ==
            std::vector<std::string>{"normals: 100 points have degenerate neighbourhoods "
                                     "(coincident or collinear) and get no normal"});
}

TEST_CASE("bad input: all points identical, with normals and --voxel", "[cli][bad_input]") {
    Workspace w;
    const std::string in = w.input("same.xyz", identical_points(100, true));
    const Refusal r = run_refused(w, in, "--voxel 0.1", kAnyFailure);
    REQUIRE_THAT(r.error, Catch::StartsWith(in + ": "));
}

TEST_CASE("bad input: a single point", "[cli][bad_input]") {
    Workspace w;
    for (const bool normals : {true, false}) {
        const std::string in = w.input("one.xyz", normals ? "1 2 3 0 0 1\n" : "1 2 3\n");
        for (const char* args : {"", "--voxel 0.1"}) {
            const Refusal r = run_refused(w, in, args, 4);
            REQUIRE_THAT(r.error,
                         Catch::EndsWith("normals: 1 point(s) are too few to estimate normals or "
                                         "spacing"));
        }
    }
}

TEST_CASE("bad input: 2 points", "[cli][bad_input]") {
    Workspace w;
    const std::string in = w.input("two.xyz", "1 2 3 0 0 1\n1.1 2 3 0 0 1\n");
    for (const char* args : {"", "--voxel 0.1"}) {
        const Refusal r = run_refused(w, in, args, 4);
        REQUIRE_THAT(r.error, Catch::StartsWith(in + ": ") && Catch::Contains("no surface"));
    }
}

TEST_CASE("bad input: errors from the pipeline name the input file", "[cli][bad_input]") {
    Workspace w;
    const std::string one = w.input("one.xyz", "1 2 3 0 0 1\n");
    CHECK_THAT(run_refused(w, one, "", 4).error, Catch::StartsWith(one + ": "));
    const std::string same = w.input("same.xyz", identical_points(10, true));
    CHECK_THAT(run_refused(w, same, "", 4).error, Catch::StartsWith(same + ": "));
    const std::string sphere = w.input("s.ply", sample_sphere(500, 1.0));
    CHECK_THAT(run_refused(w, sphere, "--voxel 1e-12", 2).error, Catch::StartsWith(sphere + ": "));
}

TEST_CASE("bad input: --voxel so small the grid would not fit in memory", "[cli][bad_input]") {
    Workspace w;
    // 200,000 samples of a unit sphere at voxel 1e-4: every point's kernel fills its own
    // 64 leaves, about 130 GB in all, yet the index range is fine. The run must be refused up
    // front. The cap only keeps a missing check from taking the machine down; under ASan,
    // whose shadow memory rules out ulimit -v, the sanitizer's RSS limit does that.
    const std::string in = w.input("big.ply", sample_sphere(200000, 1.0));
    const std::string cap = kAddressSanitizer
                                ? "ASAN_OPTIONS=\"$ASAN_OPTIONS:hard_rss_limit_mb=1500\""
                                : "ulimit -v 2000000;";
    const Refusal r = run_refused(w, in, "--voxel 1e-4", kAnyFailure, {}, cap);
    REQUIRE_THAT(r.error, Catch::StartsWith(in + ": ") && Catch::Contains("memory"));
}

TEST_CASE("bad input: --max-memory with --tile 0 refuses before the grids and suggests a voxel "
          "that fits", "[cli][bad_input]") {
    Workspace w;
    const std::string in = w.input("s.ply", sample_sphere(5000, 1.0));
    // A unit sphere at voxel 0.005 touches about 16k leaves, some 500 MB. (Without --tile 0
    // the run would tile itself: test_tiles.cpp.)
    const Refusal r = run_refused(w, in, "--voxel 0.005 --max-memory 20M --tile 0", 2);
    REQUIRE_THAT(r.error, Catch::StartsWith(in + ": splat: voxel size 0.005 needs about ") &&
                              Catch::Contains("more than the budget of 21 MB") &&
                              Catch::Contains("or --tile auto"));
    const std::size_t at = r.error.find("Hint: --voxel ");
    REQUIRE(at != std::string::npos);
    const double suggested = std::stod(r.error.substr(at + 14));
    CHECK(suggested > 0.005);
    CHECK(suggested < 0.1);
    // The suggestion fits the same budget.
    const Success s = run_ok(in, w.dir.file("fits.ply"),
                             "--voxel " + std::to_string(suggested) + " --max-memory 20M");
    require_on_sphere(s.mesh, {0, 0, 0}, 1.0, 0.25 * suggested);
    for (const char* bad : {"0", "-5M", "12Q", "G", "nan"}) {
        const Refusal b = run_refused(w, in, std::string("--max-memory ") + bad, 2);
        REQUIRE(b.error == std::string("--max-memory: '") + bad +
                               "' is not a memory size (e.g. 8G, 500M)");
    }
}

// OpenVDB's ScaleMap refuses voxel^3 < 3e-15, i.e. voxels below 1.44e-5 world units: such a run
// is refused with a hint to change units instead of failing inside OpenVDB after the splat.
TEST_CASE("bad input: a millimetre-sized scan in metres with a voxel below 1.5e-5",
          "[cli][bad_input]") {
    Workspace w;
    // A sphere of radius 1 mm in metres, spacing 2.5e-5: a 1.2e-5 voxel would be sensible.
    const std::string in = w.input("tiny.ply", sample_sphere(20000, 1e-3));
    const Refusal r = run_refused(w, in, "--voxel 1.2e-5", 2);
    REQUIRE_THAT(r.error, Catch::StartsWith(in + ": splat: voxel size 1.2e-05 is below 1.5e-05") &&
                              Catch::EndsWith("(e.g. millimetres instead of metres)"));
    // The same scan in millimetres reconstructs.
    PointCloud mm = sample_sphere(20000, 1.0);
    const std::string in_mm = w.input("tiny_mm.ply", mm);
    const Success s = run_ok(in_mm, w.dir.file("tiny_mm.out.ply"), "--voxel 0.012");
    require_on_sphere(s.mesh, {0, 0, 0}, 1.0, 0.25 * 0.012);
}

TEST_CASE("bad input: output in a missing or read-only directory", "[cli][bad_input]") {
    Workspace w;
    const std::string in = w.input("s.ply", sample_sphere(500, 1.0));
    SECTION("missing directory") {
        const std::string out = w.dir.file("missing/out.ply");
        const Refusal r = run_refused(w, in, "", 3, out);
        REQUIRE(r.error ==
                out + ": cannot write: directory '" + w.dir.file("missing/") + "' does not exist");
    }
    SECTION("read-only directory, with an earlier output in it") {
        const std::string ro = w.dir.file("ro");
        REQUIRE(::mkdir(ro.c_str(), 0755) == 0);
        write_bytes(ro + "/out.ply", "previous mesh\n");
        REQUIRE(::chmod(ro.c_str(), 0555) == 0);
        // root writes anywhere: run the tool as nobody, who can read the input but not write.
        std::string prefix;
        if (::geteuid() == 0) {
            REQUIRE(::chmod(w.dir.path().c_str(), 0755) == 0);
            REQUIRE(std::system("command -v setpriv >/dev/null") == 0);
            prefix = "setpriv --reuid=65534 --regid=65534 --clear-groups";
        }
        const std::string out = ro + "/out.ply";
        const Refusal r = run_refused(w, in, "", 3, out, prefix);
        REQUIRE(r.error == out + ": cannot write: directory '" + ro + "/' is not writable");
        REQUIRE(::chmod(ro.c_str(), 0755) == 0);
    }
    SECTION("the output path is a directory") {
        const std::string out = w.dir.file("dir.ply");
        REQUIRE(::mkdir(out.c_str(), 0755) == 0);
        const Refusal r = run_refused(w, in, "", 3, out);
        REQUIRE(r.error == out + ": cannot write: is a directory");
    }
    SECTION("a directory that takes no files: the error names the output, not a temporary") {
        // /proc passes the directory checks as root but refuses to create a file; others are
        // refused by the checks. Either way the message names an output that was asked for
        // (the mesh or its .splat.vdb, whichever is written first).
        const std::string out = "/proc/vdbrecon_out.ply";
        const Refusal r = run_refused(w, in, "", 3, out);
        CAPTURE(r.error);
        REQUIRE((r.error.rfind(out + ": cannot ", 0) == 0 ||
                 r.error.rfind("/proc/vdbrecon_out.splat.vdb: cannot ", 0) == 0));
        REQUIRE(r.error.find("staged") == std::string::npos);
    }
}

namespace {

/// Runs `command` in the background, waits (up to 60 s: a sanitizer build is ~10x slower) until
/// `ls LISTED | grep -q PATTERN` finds what it writes, then sends it SIG (INT, TERM); requires
/// that it was seen and that the run died of the signal.
void interrupt(const std::string& command, const std::string& listed, const std::string& pattern,
               const char* sig) {
    TempDir capture;
    const std::string script =
        command + " & pid=$!; seen=no; for i in $(seq 6000); do if ls -a " + listed +
        " 2>/dev/null | grep -q " + pattern + "; then seen=yes; break; fi; sleep 0.01; done; " +
        "kill -" + sig + " $pid; wait $pid; echo \"$? $seen\"\n";
    write_bytes(capture.file("interrupt.sh"), script);
    const std::string result = capture.file("result");
    REQUIRE(std::system(("sh '" + capture.file("interrupt.sh") + "' >'" + result +
                         "' 2>/dev/null").c_str()) == 0);
    const std::string got = read_bytes(result);
    INFO("signal " << sig << ": exit status and whether " << pattern << " was seen: " << got);
    // Killed by the signal: the shell reports 128 + its number (SIGINT 2, SIGTERM 15).
    REQUIRE(got == std::to_string(128 + (std::string(sig) == "INT" ? 2 : 15)) + " yes\n");
}

}  // namespace

TEST_CASE("bad input: an interrupted run removes its temporary files", "[cli][bad_input]") {
    // Issue 6 point 3. The run is interrupted once its first output (the .vdb, written while the
    // mesh is extracted) is on disk under a temporary name; the earlier outputs must survive.
    Workspace w;
    const std::string in = w.input("big.ply", sample_sphere(200000, 1.0));
    const auto before = snapshot(w.dir.path());
    for (const char* sig : {"INT", "TERM"}) {
        interrupt(std::string(VDBRECON_CLI) + " '" + in + "' -o '" + w.out + "' -q --voxel 0.004",
                  "'" + w.dir.path() + "'", "staged", sig);
        REQUIRE(snapshot(w.dir.path()) == before);
    }
}

TEST_CASE("bad input: an interrupted tiled run removes its scratch directory", "[cli][bad_input]") {
    // The tile job of a streamed tiled run waits in $TMPDIR/vdbrecon-tiles-*: interrupted once
    // its buckets are there, the run leaves none of it (and the outputs as they were).
    Workspace w;
    const std::string in = w.input("big.ply", sample_sphere(200000, 1.0));
    const auto before = snapshot(w.dir.path());
    for (const char* sig : {"INT", "TERM"}) {
        TempDir tmp;
        interrupt("TMPDIR='" + tmp.path() + "' " + VDBRECON_CLI + " '" + in + "' -o '" + w.out +
                      "' -q --voxel 0.004 --tile 32 --stream on",
                  "'" + tmp.path() + "'/vdbrecon-tiles-*", "bucket", sig);
        REQUIRE(snapshot(tmp.path()).empty());
        REQUIRE(snapshot(w.dir.path()) == before);
    }
}

TEST_CASE("bad input: input that is a directory", "[cli][bad_input]") {
    Workspace w;
    const std::string in = w.dir.file("scan.ply");
    REQUIRE(::mkdir(in.c_str(), 0755) == 0);
    require_bad_file(w, in, "is a directory, not a file");
}

// ---------------------------------------------------------------------------------------------
// Fuzzing regressions (fuzz/, scripts/fuzz.sh). Each input, or the smallest of its kind, goes
// through read_points_from_memory / read_mesh_from_memory as in the fuzz targets.

namespace {

std::string read_error(const std::string& bytes, const std::string& name, bool mesh = false) {
    try {
        if (mesh) {
            read_mesh_from_memory(bytes, name);
        } else {
            read_points_from_memory(bytes, name);
        }
    } catch (const Error& e) {
        return e.what();
    }
    return "(no error)";
}

}  // namespace

TEST_CASE("fuzz: a coordinate beyond float range is refused, not read as inf", "[io][fuzz]") {
    // fuzz_ply: a double x of about 1e300 became an infinite float position.
    std::string le = ply_header("binary_little_endian", "2",
                                "property double x\nproperty double y\nproperty double z\n");
    for (double v : {1.0, 2.0, 3.0, 1e300, 0.0, 0.0}) put(le, v, false);
    REQUIRE(read_error(le, "f.ply") ==
            "f.ply: row 1: coordinate 1e+300 is out of "
            "single-precision range (even relative to the centre of "
            "the points)");
    // Points spread wider than float's range, in any reader, as points or as a mesh.
    REQUIRE(read_error("-1e39 0 0\n1e39 0 0\n", "f.xyz") ==
            "f.xyz: row 0: coordinate -1e+39 is out of single-precision range (even relative to "
            "the centre of the points)");
    REQUIRE(read_error("v 1e300 0 0\nv 0 0 0\nv 0 1 0\nf 1 2 3\n", "f.obj", true) ==
            "f.obj: vertex 0: coordinate 1e+300 is out of single-precision range (even relative "
            "to the centre of the points)");
    // Far out but close together is fine: the local frame takes the offset (the centre used
    // to be computed as 0.5 (lo + hi), which overflows to inf here).
    const ReadResult r =
        read_points_from_memory("1.7e308 -1.7e308 1e308\n1.7e308 -1.7e308 1e308\n", "far.xyz");
    REQUIRE(r.cloud.origin == Vec3d{1.7e308, -1.7e308, 1e308});
    REQUIRE(r.cloud.positions == std::vector<Vec3f>(2, Vec3f{0, 0, 0}));
}

TEST_CASE("bad rows among many: the first in file order decides, as row by row", "[io][fuzz]") {
    // The rows are checked in parallel pieces of 16384; what is reported must not depend on that.
    const auto xyz = [](std::size_t nan_row, std::size_t huge_row) {
        std::string text;
        for (std::size_t i = 0; i < 50000; ++i) {
            if (i == nan_row) {
                text += "nan 0 0\n";
            } else if (i == huge_row) {
                text += "1e39 0 0\n";
            } else {
                text += std::to_string(i % 100) + " " + std::to_string(i / 100) + " 1\n";
            }
        }
        return text;
    };
    ReadOptions strict;
    strict.non_finite = NonFinitePolicy::error;
    const auto error_of = [](const std::string& text, const ReadOptions& o) {
        try {
            read_points_from_memory(text, "f.xyz", o);
        } catch (const Error& e) {
            return std::string(e.what());
        }
        return std::string("(no error)");
    };
    const std::string huge = ": coordinate 1e+39 is out of single-precision range";
    CHECK_THAT(error_of(xyz(20000, 40000), ReadOptions{}),
               Catch::StartsWith("f.xyz: row 40000" + huge));
    CHECK(error_of(xyz(20000, 40000), strict) == "f.xyz: row 20000: NaN or infinite coordinate");
    CHECK_THAT(error_of(xyz(40000, 20000), strict), Catch::StartsWith("f.xyz: row 20000" + huge));
    // Dropped rows: counted, the first named, the others kept in order.
    std::string text = xyz(17000, -1);
    text.replace(text.find("0 330 1\n"), 8, "0 inf 1\n");  // row 33000
    const ReadResult r = read_points_from_memory(text, "f.xyz");
    REQUIRE(r.dropped_nonfinite == 2);
    REQUIRE(r.first_dropped == 17000);
    REQUIRE(r.cloud.size() == 49998);
    CHECK(r.cloud.positions[16999] == Vec3f{99, 169, 1});
    CHECK(r.cloud.positions[17000] == Vec3f{1, 170, 1});  // row 17001
    CHECK(r.cloud.positions[32999] == Vec3f{1, 330, 1});  // row 33001
    CHECK(r.cloud.positions[49997] == Vec3f{99, 499, 1});
}

TEST_CASE("fuzz: file text in messages is escaped and cut short", "[io][fuzz]") {
    // fuzz_ply: an element named with NUL bytes made the message end at the file name.
    const std::string name("a\0b\x1b[1m", 7);
    const std::string header = "ply\nformat binary_little_endian 1.0\nelement " + name +
                               " 1\nproperty float q\nelement vertex 1\n" + kXyzFloat +
                               "end_header\n";
    REQUIRE(read_error(header + "xy", "f.ply") ==
            "f.ply: a\\x00b\\x1b[1m 0: truncated binary data (the header declares 1 rows, the "
            "file holds 0)");
    REQUIRE(read_error(ply_header("ascii", "1") + "1 2 " + std::string(100, 'z') + "\n", "f.ply") ==
            "f.ply: vertex 0: 'zzzzzzzzzzzzzzzzzzzzzzzzzzzzz...' is not a number");
    REQUIRE(read_error(ply_header("ascii", "1") + "1 2 \x01\xff\n", "f.ply") ==
            "f.ply: vertex 0: '\\x01\\xff' is not a number");
    REQUIRE(read_error("1 2 \x07\n", "f.xyz") == "f.xyz: line 1: '\\x07' is not a number");
    REQUIRE(read_error("ply\nformat \x1b]0;title\x07 1.0\n", "f.ply") ==
            "f.ply: header line 2: unknown format '\\x1b]0;title\\x07'");
}

TEST_CASE("fuzz: an element without properties is skipped however many rows it claims",
          "[io][fuzz]") {
    // Review: skipping 2^64 empty ascii rows looped 2^64 times (the size check, which bounds
    // every other element by the file size, sees zero bytes per row).
    for (const char* format : {"ascii", "binary_little_endian"}) {
        std::string bytes = std::string("ply\nformat ") + format +
                            " 1.0\nelement junk 18446744073709551615\nelement vertex 1\n" +
                            kXyzFloat + "end_header\n";
        if (format[0] == 'a') {
            bytes += "1 2 3\n";
        } else {
            for (float v : {1.0f, 2.0f, 3.0f}) put(bytes, v, false);
        }
        CAPTURE(format);
        const PointCloud c = read_points_from_memory(bytes, "f.ply").cloud;
        REQUIRE(c.size() == 1);
        for (int a = 0; a < 3; ++a) REQUIRE(c.origin[a] + c.positions[0][a] == a + 1.0);
    }
}

TEST_CASE("fuzz: the size check never converts a negative byte count", "[io][fuzz]") {
    // Review, confirmed by fuzz_ply's UBSan: the vertices claim one byte more than the body
    // holds (the check allows that byte), so for the faces "bytes left" was -1, and converting
    // -1.0 to an unsigned row count is undefined behaviour.
    const std::string bytes =
        "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty uchar x\n"
        "property uchar y\nproperty uchar z\nproperty uchar w\nelement face 5\n"
        "property uchar q\nend_header\nabc";
    REQUIRE(read_error(bytes, "f.ply", true) ==
            "f.ply: face 0: truncated binary data (the header declares 5 rows, the file holds 0)");
}

TEST_CASE("fuzz: numbers beyond double's range and doubled signs", "[io][fuzz]") {
    // Review: an underflowing number (1e-400) was read as inf and its row dropped.
    for (const char* name : {"f.xyz", "f.ply"}) {
        std::string bytes = "1e-400 2 3\n-1e400 0 0\n4 5 -4.9e-324\n";
        if (name[2] == 'p') bytes = ply_header("ascii", "3") + bytes;
        CAPTURE(name);
        const ReadResult r = read_points_from_memory(bytes, name);
        REQUIRE(r.dropped_nonfinite == 1);
        REQUIRE(r.cloud.positions == std::vector<Vec3f>{{0, 2, 3}, {4, 5, -0.0f}});
    }
    REQUIRE(read_error("+-5 1 2\n", "f.xyz") == "f.xyz: line 1: '+-5' is not a number");
    REQUIRE(read_error(ply_header("ascii", "1") + "1 +-2 3\n", "f.ply") ==
            "f.ply: vertex 0: '+-2' is not a number");
    REQUIRE(read_error("v 1 ++2 3\n", "f.obj") == "f.obj: line 1: malformed 'v' line");
}

TEST_CASE("fuzz: reading a file and reading its bytes are one mechanism", "[io][fuzz]") {
    TempDir dir;
    PointCloud c = sample_sphere(50, 1.0);
    c.colors.assign(c.size(), Vec3f{1, 0, 0});
    for (const char* name : {"c.ply", "c.xyz"}) {
        write_points(dir.file(name), c);
        const ReadResult a = read_points(dir.file(name));
        const ReadResult b = read_points_from_memory(read_bytes(dir.file(name)), dir.file(name));
        REQUIRE(a.format == b.format);
        REQUIRE(a.cloud.positions == b.cloud.positions);
        REQUIRE(a.cloud.normals == b.cloud.normals);
        REQUIRE(a.cloud.colors == b.cloud.colors);
    }
    Mesh m;
    m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
    m.faces = {{0, 1, 2}};
    write_mesh(dir.file("m.obj"), m);
    REQUIRE(read_mesh_from_memory(read_bytes(dir.file("m.obj")), "m.obj").faces == m.faces);
    // The name picks the reader and heads the messages, as a path does.
    REQUIRE(read_error("1 2 3\n", "scan.ply") == "scan.ply: not a PLY file (no 'ply' magic)");
    REQUIRE(read_error("1 2 3\n", "scan.stl") ==
            "scan.stl: unknown file type '.stl' (supported: .ply, .xyz/.pts/.txt, .obj, .las, .pcd)");
}

// ---------------------------------------------------------------------------------------------
// Fuzzing regressions of the scene readers (issue 47): images, transforms.json and the dataset
// layouts' files, read from files as fuse reads them (the fuzz targets write each input to a
// scratch folder). Then the invalid metadata every scene reader must refuse, and the header
// sizes no reader may allocate before the file's size confirms them.

namespace {

/// The message of the Error `read` throws, or "(no error)".
template <typename Read>
std::string error_of(Read&& read) {
    try {
        read();
    } catch (const Error& e) {
        return e.what();
    }
    return "(no error)";
}

std::string be32(std::uint32_t v) {
    return {char(v >> 24), char(v >> 16 & 255u), char(v >> 8 & 255u), char(v & 255u)};
}

/// A PNG chunk with its CRC; `length` is the claimed data length (that of `data` by default).
std::string png_chunk(const std::string& type, const std::string& data, long length = -1) {
    const std::string body = type + data;
    const auto crc = crc32(0L, reinterpret_cast<const Bytef*>(body.data()), uInt(body.size()));
    return be32(std::uint32_t(length < 0 ? data.size() : std::size_t(length))) + body +
           be32(std::uint32_t(crc));
}

/// The signature and IHDR of a PNG of w x h pixels (`bits`, colour type `type`).
std::string png_start(std::uint32_t w, std::uint32_t h, int bits = 16, int type = 0) {
    return std::string("\x89PNG\r\n\x1a\n", 8) +
           png_chunk("IHDR", be32(w) + be32(h) + std::string{char(bits), char(type), 0, 0, 0});
}

/// `bytes` with the first `find` replaced by `replace` (which must be there).
std::string patched(std::string bytes, const std::string& find, const std::string& replace) {
    const std::size_t at = bytes.find(find);
    REQUIRE(at != std::string::npos);
    return bytes.replace(at, find.size(), replace);
}

/// A little-endian 32-bit word.
std::string le32(std::uint32_t v) {
    return {char(v & 255u), char(v >> 8 & 255u), char(v >> 16 & 255u), char(v >> 24)};
}

DepthImage ramp(int w, int h) {
    DepthImage d{w, h, {}};
    for (int i = 0; i < w * h; ++i) d.depth.push_back(0.5f + 0.01f * float(i));
    return d;
}

}  // namespace

namespace {

/// The PNG bytes, as a depth image and as a colour image, are refused with `message` after
/// the file's path.
void check_png_refused(const std::string& png, const std::string& message) {
    TempDir dir;
    for (const char* name : {"d.png", "c.png"}) {
        write_bytes(dir.file(name), png);
        const std::string what = name[0] == 'd'
                                     ? error_of([&] { read_depth_image(dir.file(name)); })
                                     : error_of([&] { read_color_image(dir.file(name)); });
        REQUIRE(what == dir.file(name) + message);
    }
}

}  // namespace

TEST_CASE("fuzz: a PNG chunk longer than its file is refused before libpng allocates it",
          "[fusion][io][fuzz]") {
    // fuzz_depth_png: a tEXt chunk claiming 838,860,808 bytes in a 293-byte file: libpng
    // allocated 800 MB for it before finding the file short. Every chunk up to IEND must now
    // lie within the file, and ancillary chunks are skipped unread.
    const std::string png =
        png_start(2, 2) + be32(838860808u) + "tEXt" + std::string("depth\0mm", 8);
    check_png_refused(png, ": the chunk 'tEXt' at byte 33 claims 838860808 bytes, past the end "
                           "of the file (49 bytes)");
}

TEST_CASE("fuzz: an EXR file's headers are checked against the file before OpenEXR reads them",
          "[fusion][io][fuzz]") {
    TempDir dir;
    const std::string path = dir.file("d.exr");
    write_depth_image(path, ramp(7, 5));
    const std::string good = read_bytes(path);
    auto error_with = [&](const std::string& bytes) {
        write_bytes(path, bytes);
        return error_of([&] { read_depth_image(path); });
    };
    // fuzz_depth_exr: an attribute claiming 1.6 GB in an 83-byte file; OpenEXR allocated it.
    const std::string compression = std::string("compression\0compression\0", 24);
    REQUIRE(error_with(patched(good, compression + le32(1), compression + le32(1668415488u))) ==
            path + ": the attribute 'compression' claims 1668415488 bytes, past the end of the " +
                "file (" + std::to_string(good.size()) + " bytes)");
    // fuzz_depth_exr: a v3f of 8 bytes. OpenEXR reads a v3f's 12 whatever its size says, and
    // went on out of step with the file, into the 1.6 GB "size" of what followed.
    REQUIRE(error_with(patched(good, std::string("screenWindowCenter\0v2f", 22),
                               std::string("screenWindowCenter\0v3f", 22))) ==
            path + ": the attribute 'screenWindowCenter' holds 8 bytes, not the 12 of a v3f");
    // A data window the file cannot hold: its decoded pixels, or its table of chunk offsets.
    const std::string window =
        std::string("dataWindow\0box2i\0", 17) + le32(16) + le32(0) + le32(0);
    REQUIRE_THAT(
        error_with(patched(good, window + le32(6) + le32(4), window + le32(59999) + le32(59999))),
        Catch::StartsWith(path + ": the header claims 60000 x 60000 pixels of 4 bytes, "
                                 "more than the file's ") &&
            Catch::EndsWith(" bytes can hold (truncated, or a corrupt header)"));
    REQUIRE_THAT(
        error_with(patched(good, window + le32(6) + le32(4), window + le32(6) + le32(1999))),
        Catch::StartsWith(path + ": the offset table of 125 chunks does not fit in the file"));
    write_bytes(path, good);
    REQUIRE(read_depth_image(path).depth == ramp(7, 5).depth);
}

TEST_CASE("bounded: a depth image of another size than its frame's camera is refused unread",
          "[fusion][io][bad_input]") {
    TempDir dir;
    for (const char* name : {"d.exr", "d.png"}) {
        write_depth_image(dir.file(name), ramp(7, 5));
        auto read_as = [&](int w, int h) {
            return read_depth_image(dir.file(name), 1000.0, ImageSize{w, h});
        };
        REQUIRE(error_of([&] { read_as(8, 5); }) ==
                dir.file(name) + ": the image is 7 x 5 pixels, the frame's camera 8 x 5");
        REQUIRE(read_as(7, 5).width == 7);
        REQUIRE(read_as(0, 0).height == 5);
    }
}

TEST_CASE("bounded: an image header claiming more pixels than its file can hold is refused",
          "[fusion][io][bad_input]") {
    // 4000 x 4000 16-bit pixels inflate from at least 31 kB of deflate data (1032-fold at
    // most); a 4000 x 4000 JPEG has at least 7.8 kB of entropy-coded data. These files have a
    // few hundred bytes: libpng would fail a row later, after the buffers; libjpeg would
    // decode the missing rows as grey.
    const std::string png =
        png_start(4000, 4000) + png_chunk("IDAT", "\x78\x9c") + png_chunk("IEND", "");
    check_png_refused(png, ": the header claims 4000 x 4000 pixels, which take at least 31011 "
                           "bytes; the file has 59 (truncated, or a corrupt header)");
    TempDir dir;
    ColorImage small{6, 4, std::vector<Vec3f>(24, Vec3f{0.5f, 0.25f, 1.0f})};
    write_color_image(dir.file("c.jpg"), small);
    const std::string jpeg = read_bytes(dir.file("c.jpg"));
    const std::size_t sof = jpeg.find("\xff\xc0");
    REQUIRE(sof != std::string::npos);
    std::string big = jpeg;
    big.replace(sof + 5, 4, std::string("\x0f\xa0\x0f\xa0", 4));  // height, width 4000
    write_bytes(dir.file("big.jpg"), big);
    REQUIRE_THAT(
        error_of([&] { read_color_image(dir.file("big.jpg")); }),
        Catch::StartsWith(dir.file("big.jpg") + ": the header claims 4000 x 4000 pixels") &&
            Catch::EndsWith("(truncated, or a corrupt header)"));
    REQUIRE(read_color_image(dir.file("c.jpg")).width == 6);
}

TEST_CASE("bad metadata: transforms.json sizes, focal lengths, fields of view and poses",
          "[fusion][bad_input]") {
    TempDir dir;
    const std::string json = dir.file("transforms.json");
    const std::string identity = "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]";
    auto error_with = [&](const std::string& camera, const std::string& matrix) {
        write_bytes(json, "{" + camera +
                              ", \"frames\": [{\"file_path\": \"a\", \"depth_file_path\": "
                              "\"a.png\", \"transform_matrix\": " +
                              matrix + "}]}");
        return error_of([&] { read_scene(json); });
    };
    const std::string fine = "\"fl_x\": 500, \"w\": 64, \"h\": 48";
    REQUIRE(error_with(fine, identity) == "(no error)");
    // Review: "w": 1e300 went through int(double), undefined behaviour (UBSan's float-cast).
    REQUIRE(error_with("\"fl_x\": 500, \"w\": 1e300, \"h\": 48", identity) ==
            json + ": 'w' is 1e+300, not a positive number of pixels (a whole number up to 65536)");
    REQUIRE(error_with("\"fl_x\": 500, \"w\": 64, \"h\": 47.5", identity) ==
            json + ": 'h' is 47.5, not a positive number of pixels (a whole number up to 65536)");
    REQUIRE(error_with("\"fl_x\": 500, \"w\": 64", identity) ==
            json + ": frame 0: 'w' and 'h' go together (or neither: the image's size)");
    REQUIRE(error_with("\"fl_x\": -500", identity) ==
            json + ": 'fl_x' is -500, not a positive number");
    // A field of view of pi or more made a negative or infinite focal length.
    REQUIRE(error_with("\"camera_angle_x\": 3.5, \"w\": 64, \"h\": 48", identity) ==
            json + ": 'camera_angle_x' is 3.5 radians, not a field of view below pi");
    REQUIRE_THAT(error_with(fine, "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 3, 0], [0, 0, 0, 1]]"),
                 Catch::StartsWith(json + ": frame 0: pose: the 3x3 part is not a rotation"));
    REQUIRE_THAT(error_with(fine, "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]"),
                 Catch::StartsWith(json + ": frame 0: pose: the last row must be 0 0 0 1"));
}

TEST_CASE("bad metadata: the layouts refuse non-rotations, NaN and unusable intrinsics",
          "[fusion][bad_input][layouts]") {
    const std::string pose = "1 0 0 0.5\n0 1 0 0\n0 0 1 2\n0 0 0 1\n";
    const std::string scaled = "2 0 0 0.5\n0 1 0 0\n0 0 1 2\n0 0 0 1\n";
    const std::string rotation = ": pose: the 3x3 part is not a rotation";
    {  // 7-Scenes: a pose file (poses used to be checked only when fused, naming the image)
        TempDir d;
        write_bytes(d.file("camera-intrinsics.txt"), "585 0 320\n0 585 240\n0 0 1\n");
        write_bytes(d.file("frame-000000.depth.png"), "");
        write_bytes(d.file("frame-000000.pose.txt"), scaled);
        REQUIRE_THAT(error_of([&] { read_scene(d.path()); }),
                     Catch::StartsWith(d.file("frame-000000.pose.txt") + rotation));
    }
    {  // ScanNet: -inf is a lost pose (skipped), NaN a broken file
        TempDir d;
        for (const char* sub : {"depth", "pose", "intrinsic"}) ::mkdir(d.file(sub).c_str(), 0755);
        write_bytes(d.file("intrinsic/intrinsic_depth.txt"),
                    "577 0 319.5 0\n0 578 239.5 0\n0 0 1 0\n0 0 0 1\n");
        write_bytes(d.file("depth/0.png"), "");
        write_bytes(d.file("pose/0.txt"), "nan 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
        REQUIRE(error_of([&] { read_scene(d.path()); }) ==
                d.file("pose/0.txt") + ": a value is not finite");
        write_bytes(d.file("intrinsic/intrinsic_depth.txt"), "577 0 319.5\n0 -578 239.5\n0 0 1\n");
        REQUIRE(error_of([&] { read_scene(d.path()); }) ==
                d.file("intrinsic/intrinsic_depth.txt") + ": the focal lengths are not positive");
    }
    {  // Redwood: a trajectory's frame; an absurd image size in camera_intrinsic.json
        TempDir d;
        ::mkdir(d.file("depth").c_str(), 0755);
        for (const char* f : {"depth/0.png", "depth/1.png"}) write_bytes(d.file(f), "");
        write_bytes(d.file("trajectory.log"), "0 0 1\n" + pose + "1 1 2\n" + scaled);
        const std::string intrinsic =
            "{\"width\": %, \"height\": 480, \"intrinsic_matrix\": "
            "[525, 0, 0, 0, 525, 0, 319.5, 239.5, 1]}";
        write_bytes(d.file("camera_intrinsic.json"), patched(intrinsic, "%", "640"));
        REQUIRE_THAT(error_of([&] { read_scene(d.path()); }),
                     Catch::StartsWith(d.file("trajectory.log") + ": frame 1" + rotation));
        write_bytes(d.file("camera_intrinsic.json"), patched(intrinsic, "%", "1000000000000"));
        REQUIRE_THAT(error_of([&] { read_scene(d.path()); }),
                     Catch::StartsWith(d.file("camera_intrinsic.json") +
                                       ": the focal lengths or the size are not positive"));
    }
    {  // Replica: camera.w of 1e300 went through int(double) (UBSan); a mirrored pose
        TempDir d;
        ::mkdir(d.file("results").c_str(), 0755);
        for (const char* f : {"results/depth000000.png", "results/depth000001.png"}) {
            write_bytes(d.file(f), "");
        }
        write_bytes(d.file("traj.txt"),
                    "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 0 0 0 0 1 0 0 0 0 -1 0 0 0 0 1\n");
        const std::string params =
            "{\"camera\": {\"w\": %, \"h\": 680, \"fx\": 600, \"fy\": 600, "
            "\"cx\": 599.5, \"cy\": 339.5, \"scale\": 6553.5}}";
        write_bytes(d.file("cam_params.json"), patched(params, "%", "1e300"));
        REQUIRE(error_of([&] { read_scene(d.path()); }) ==
                d.file("cam_params.json") +
                    ": camera.w is not a whole number of pixels up to 65536");
        write_bytes(d.file("cam_params.json"), patched(params, "%", "1200"));
        REQUIRE_THAT(error_of([&] { read_scene(d.path()); }),
                     Catch::StartsWith(d.file("traj.txt") + ": line 2" + rotation));
    }
    {  // KITTI: calib.txt's Tr, a line of poses.txt, NaN
        TempDir d;
        ::mkdir(d.file("velodyne").c_str(), 0755);
        write_bytes(d.file("velodyne/000000.bin"), "");
        write_bytes(d.file("poses.txt"), "1 0 0 0 0 1 0 0 0 0 1 0\n");
        write_bytes(d.file("calib.txt"), "Tr: 1 0 0 0 0 1 0 0 0 0 2 0\n");
        REQUIRE_THAT(
            error_of([&] { read_scene(d.path()); }),
            Catch::StartsWith(d.file("calib.txt") + ": Tr: pose: the 3x3 part is not a rotation"));
        std::remove(d.file("calib.txt").c_str());
        write_bytes(d.file("poses.txt"), "1 0 0 0 0 1 0 0 0 0 1 nan\n");
        REQUIRE(error_of([&] { read_scene(d.path()); }) ==
                d.file("poses.txt") + ": a value is not finite");
        write_bytes(d.file("poses.txt"), "0 1 0 0 1 0 0 0 0 0 1 0\n");
        REQUIRE_THAT(error_of([&] { read_scene(d.path()); }),
                     Catch::StartsWith(d.file("poses.txt") + ": line 1" + rotation));
    }
}

TEST_CASE("KITTI scans: float32 x y z intensity a point, whole points only",
          "[fusion][io][kitti]") {
    TempDir d;
    const float v[8] = {1.5f, -2.0f, 0.25f, 0.5f, 3.0f, 4.0f, -5.0f, 0.0f};
    const std::string bytes(reinterpret_cast<const char*>(v), sizeof v);
    write_bytes(d.file("0.bin"), bytes);
    REQUIRE(read_kitti_scan(d.file("0.bin")) ==
            std::vector<Vec3f>{{1.5f, -2.0f, 0.25f}, {3, 4, -5}});
    write_bytes(d.file("1.bin"), bytes.substr(0, 20));
    REQUIRE(error_of([&] { read_kitti_scan(d.file("1.bin")); }) ==
            d.file("1.bin") +
                ": a KITTI scan is float32 x y z intensity (16 bytes a point); the "
                "file's 20 bytes are not");
    REQUIRE_THAT(error_of([&] { read_kitti_scan(d.file("missing.bin")); }),
                 Catch::StartsWith(d.file("missing.bin") + ": "));
}

TEST_CASE("fuzz: a PCD header's point count is checked against its data before allocating",
          "[io][fuzz][pcd]") {
    // fuzz_pcd (with a 256 MB allocation limit): WIDTH 333333333 in a 130-byte file made the
    // reader size three arrays of a billion floats before it looked at the data.
    const std::string head = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                             "WIDTH 333333333\nHEIGHT 1\nPOINTS 333333333\n";
    const std::string compressed = head + "DATA binary_compressed\n" +
                                   std::string("\x05\x00\x00\x00\x18\x00\x00\x00\x00\xe0\x0e\x00", 12);
    CHECK(read_error(compressed, "f.pcd").find("points cannot come from the file's") != std::string::npos);
    CHECK(read_error(head + "DATA binary\n" + std::string(24, '\0'), "f.pcd") ==
          "f.pcd: truncated PCD binary data");
    CHECK(read_error(head + "DATA ascii\n1 2 3\n", "f.pcd").find("truncated PCD ascii data") !=
          std::string::npos);
}

TEST_CASE("fuzz: a NaN scan index is no scan, not an undefined conversion", "[io][fuzz]") {
    // fuzz_ply under UBSan: a float `scan` of NaN was converted to int32.
    std::string ply = ply_header("binary_little_endian", "2",
                                 "property float x\nproperty float y\nproperty float z\n"
                                 "property float scan\n");
    for (float v : {0.0f, 0.0f, 0.0f, std::nanf(""), 1.0f, 0.0f, 0.0f, 2.0f}) put(ply, v, false);
    const ReadResult r = read_points_from_memory(ply, "f.ply");
    REQUIRE(r.scans.size() == 2);
    CHECK(r.scans[0] == -1);
    CHECK(r.scans[1] == 2);
}
