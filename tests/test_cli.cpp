// The command line: exit codes, messages, outputs. Runs the real binary.
#include <sys/wait.h>

#include "support.h"
#include "vdbrecon/io.h"
#include "vdbrecon/splat.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

struct Run {
    int code = -1;
    std::string out, err;
};

Run cli(const std::string& args, const TempDir& dir) {
    const std::string out = dir.file(".stdout"), err = dir.file(".stderr");
    const std::string cmd = std::string(VDBRECON_CLI) + " " + args + " >" + out + " 2>" + err;
    const int status = std::system(cmd.c_str());
    Run r;
    r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    r.out = read_bytes(out);
    r.err = read_bytes(err);
    std::remove(out.c_str());
    std::remove(err.c_str());
    return r;
}

}  // namespace

TEST_CASE("cli: help lists the defaults, version prints", "[cli]") {
    TempDir dir;
    Run r = cli("--help", dir);
    REQUIRE(r.code == 0);
    REQUIRE_THAT(r.out, Catch::Contains("--voxel") && Catch::Contains("--min-weight") &&
                            Catch::Contains("--viewpoint") && Catch::Contains("--threads"));
    // Defaults are printed from the options structs, not hard-coded.
    std::ostringstream w;
    w << "[" << SplatOptions{}.min_weight << "]";
    const std::size_t line = r.out.find("--min-weight");
    REQUIRE(r.out.substr(line, r.out.find('\n', line) - line).find(w.str()) != std::string::npos);
    r = cli("--version", dir);
    REQUIRE(r.code == 0);
    REQUIRE_THAT(r.out, Catch::StartsWith("vdbrecon "));
}

TEST_CASE("cli: reconstructs, writes mesh and volume, says where", "[cli]") {
    TempDir dir;
    write_points(dir.file("s.ply"), sample_sphere(20000, 1.0));
    Run r = cli(dir.file("s.ply") + " -o " + dir.file("m.ply") + " --voxel 0.05", dir);
    INFO(r.err);
    REQUIRE(r.code == 0);
    REQUIRE_THAT(r.out, Catch::Contains("mesh: " + dir.file("m.ply")) &&
                            Catch::Contains("volume: " + dir.file("m.splat.vdb")));
    REQUIRE_THAT(r.err, Catch::Contains("time:") && Catch::Contains("splat"));
    REQUIRE(file_exists(dir.file("m.ply")));
    REQUIRE(file_exists(dir.file("m.splat.vdb")));
    // -q: nothing on stderr.
    r = cli(dir.file("s.ply") + " -o " + dir.file("q.ply") + " --voxel 0.05 -q --no-vdb", dir);
    REQUIRE(r.code == 0);
    REQUIRE(r.err.empty());
    REQUIRE_FALSE(file_exists(dir.file("q.splat.vdb")));
    // eval prints JSON that compares the mesh with itself perfectly.
    r = cli("eval " + dir.file("m.ply") + " " + dir.file("m.ply") + " --samples 10000", dir);
    REQUIRE(r.code == 0);
    REQUIRE_THAT(r.out, Catch::Contains("\"fscore\": 1}"));
}

TEST_CASE("cli: usage errors exit 2, I/O and format errors exit 3, nothing is written",
          "[cli]") {
    TempDir dir;
    write_points(dir.file("s.ply"), sample_sphere(2000, 1.0));
    const std::string in = dir.file("s.ply");
    struct Case {
        std::string args;
        int code;
        std::string message;
    };
    const Case cases[] = {
        {in + " --voxel 0", 2, "--voxel must be a positive number"},
        {in + " --voxel -1", 2, "--voxel must be a positive number"},
        {in + " --voxel nan", 2, "--voxel: 'nan' is not a finite number"},
        {in + " --voxel abc", 2, "'abc' is not a finite number"},
        {in + " --voxel 1e-12", 2, "too small for this scan"},
        {in + " --bogus", 2, "unknown option '--bogus'"},
        {in + " --normals sideways", 2, "not one of auto, estimate, keep"},
        {in + " --viewpoint 1,2", 2, "--viewpoint needs three numbers"},
        {"", 2, "no input file"},
        {dir.file("missing.ply"), 3, dir.file("missing.ply") + ": cannot open"},
        {dir.path(), 3, "is a directory"},
        {in + " -o " + dir.file("nodir/out.ply"), 3, dir.file("nodir/out.ply")},
        {in + " -o " + in, 2, "refusing to overwrite"},
    };
    for (const Case& c : cases) {
        const bool has_output = c.args.find(" -o ") != std::string::npos;
        const Run r = cli(has_output ? c.args : c.args + " -o " + dir.file("out.ply"), dir);
        CAPTURE(c.args, r.err);
        REQUIRE(r.code == c.code);
        // Exactly one error line, the last one (progress lines may precede it).
        const std::size_t at = r.err.find("vdbrecon: error: ");
        REQUIRE(at != std::string::npos);
        REQUIRE(r.err.find("error", at + 16) == std::string::npos);
        const std::string line = r.err.substr(at);
        REQUIRE_THAT(line, Catch::Contains(c.message));
        REQUIRE(std::count(line.begin(), line.end(), '\n') == 1);
        REQUIRE(count_files(dir.path()) == 1);                       // only the input
    }
    write_bytes(dir.file("t.ply"), "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\n");
    const Run r = cli(dir.file("t.ply") + " -o " + dir.file("out.ply"), dir);
    REQUIRE(r.code == 3);
    REQUIRE_THAT(r.err, Catch::Contains(dir.file("t.ply") + ": header has no end_header"));
}
