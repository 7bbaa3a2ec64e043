// The command line: exit codes, messages, outputs. Runs the real binary.
#include <filesystem>
#include <fstream>

#include "huge_pages.h"
#include "support.h"
#include "vdbrecon/io.h"
#include "vdbrecon/splat.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

TEST_CASE("cli: help lists the defaults, version prints", "[cli]") {
    CliRun r = run_cli("--help");
    REQUIRE(r.code == 0);
    REQUIRE_THAT(r.out, Catch::Contains("--voxel") && Catch::Contains("--min-weight") &&
                            Catch::Contains("--viewpoint") && Catch::Contains("--threads"));
    // Defaults are printed from the options structs, not hard-coded.
    std::ostringstream w;
    w << "[" << SplatOptions{}.min_weight << "]";
    const std::size_t line = r.out.find("--min-weight");
    REQUIRE(r.out.substr(line, r.out.find('\n', line) - line).find(w.str()) != std::string::npos);
    r = run_cli("--version");
    REQUIRE(r.code == 0);
    REQUIRE_THAT(r.out, Catch::StartsWith("vdbrecon "));
}

TEST_CASE("cli: help groups the options by stage; fuse --help shows fuse's first", "[cli]") {
    const CliRun r = run_cli("--help");
    REQUIRE(r.code == 0);
    // The groups in pipeline order, each option under its own.
    const char* groups[] = {"input options:", "points and normals options:", "splat options:",
                            "close options:", "mesh options:", "refine options:",
                            "tiles and memory options:", "output options:", "fuse options:",
                            "eval options:"};
    std::size_t at = 0;
    for (const char* g : groups) {
        INFO(g);
        const std::size_t next = r.out.find(std::string("\n") + g, at);
        REQUIRE(next != std::string::npos);
        at = next + 1;
    }
    auto group_of = [&](const std::string& out, const std::string& option) {
        const std::size_t o = out.find("  " + option + " ");
        REQUIRE(o != std::string::npos);
        const std::size_t head = out.rfind(" options:", o);
        return out.substr(out.rfind('\n', head) + 1, head - out.rfind('\n', head) - 1);
    };
    CHECK(group_of(r.out, "--orient") == "points and normals");
    CHECK(group_of(r.out, "--crease-angle") == "splat");
    CHECK(group_of(r.out, "--min-samples") == "mesh");
    CHECK(group_of(r.out, "--decimate") == "refine");
    CHECK(group_of(r.out, "--tile") == "tiles and memory");
    const CliRun f = run_cli("fuse --help");
    REQUIRE(f.code == 0);
    CHECK(f.out.find("fuse options:") < f.out.find("splat options:"));
    CHECK(f.out.find("--skip-bad-frames") < f.out.find("--voxel"));
}

TEST_CASE("cli: reconstructs, writes mesh and volume, says where", "[cli]") {
    TempDir dir;
    write_points(dir.file("s.ply"), sample_sphere(20000, 1.0));
    CliRun r = run_cli(dir.file("s.ply") + " -o " + dir.file("m.ply") + " --voxel 0.05");
    INFO(r.err);
    REQUIRE(r.code == 0);
    REQUIRE_THAT(r.out, Catch::Contains("mesh: " + dir.file("m.ply")) &&
                            Catch::Contains("volume: " + dir.file("m.splat.vdb")));
    REQUIRE_THAT(r.err, Catch::Contains("time:") && Catch::Contains("splat"));
    REQUIRE(file_exists(dir.file("m.ply")));
    REQUIRE(file_exists(dir.file("m.splat.vdb")));
    // -q: nothing on stderr.
    r = run_cli(dir.file("s.ply") + " -o " + dir.file("q.ply") + " --voxel 0.05 -q --no-vdb");
    REQUIRE(r.code == 0);
    REQUIRE(r.err.empty());
    REQUIRE_FALSE(file_exists(dir.file("q.splat.vdb")));
    // eval prints JSON that compares the mesh with itself perfectly.
    r = run_cli("eval " + dir.file("m.ply") + " " + dir.file("m.ply") + " --samples 10000");
    REQUIRE(r.code == 0);
    REQUIRE_THAT(r.out, Catch::Contains("\"fscore\": 1}"));
}

namespace {

/// The kernel's transparent huge page modes, the chosen one in brackets ("" where unknown).
std::string thp_mode() {
    return vdbrecon::launcher::first_line("/sys/kernel/mm/transparent_hugepage/enabled");
}

}  // namespace

TEST_CASE("cli: the huge-page tunables change nothing but the speed", "[cli]") {
    // Without GLIBC_TUNABLES the launcher starts vdbrecon-core with glibc.malloc.hugetlb=1 (where
    // the kernel's THP mode is "madvise"); with the tunable named it passes it on as it is. Both
    // runs must see the same arguments (a path with a space and a quote) and write the same bytes.
    INFO("THP mode: " << thp_mode());
    TempDir dir;
    write_points(dir.file("s.ply"), sample_sphere(20000, 1.0));
    const auto args = [&](const std::string& out) {
        return dir.file("s.ply") + " -o \"" + dir.file(out) + "\" --voxel 0.05 --no-vdb";
    };
    const CliRun again = run_cli(args("it's a.ply"), "env -u GLIBC_TUNABLES");
    const CliRun as_is = run_cli(args("it's b.ply"), "env GLIBC_TUNABLES=glibc.malloc.hugetlb=0");
    INFO(again.err << as_is.err);
    REQUIRE(again.code == 0);
    REQUIRE(as_is.code == 0);
    REQUIRE_THAT(again.out, Catch::Contains("mesh: " + dir.file("it's a.ply")));
    REQUIRE(file_exists(dir.file("it's a.ply")));
    REQUIRE(read_bytes(dir.file("it's a.ply")) == read_bytes(dir.file("it's b.ply")));
}

TEST_CASE("cli: the launcher passes arguments and tunables on, and says what it cannot run",
          "[cli]") {
    // The rule itself is tested on made-up sysfs trees below; here it decides on this machine's.
    const bool advised = vdbrecon::launcher::huge_pages_help("/sys");
    INFO("THP mode: " << thp_mode() << "; free pages reported to a host: "
                      << vdbrecon::launcher::free_memory_goes_to_host("/sys"));
    TempDir dir;
    const std::string launcher = dir.file("vdbrecon");
    std::filesystem::copy_file(VDBRECON_CLI, launcher);
    const auto run = [&](const std::string& env) {
        const std::string cmd = env + " '" + launcher + "' \"a b\" \"it's\" >'" + dir.file("out") +
                                "' 2>'" + dir.file("err") + "'";
        const int status = std::system(cmd.c_str());
        return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    };
    // No vdbrecon-core beside it: one line naming the program, exit code 4.
    REQUIRE(run("env -u GLIBC_TUNABLES") == 4);
    REQUIRE(read_bytes(dir.file("err")) == "vdbrecon: error: cannot run " +
                                               dir.file("vdbrecon-core") +
                                               ": No such file or directory\n");
    // A stand-in core that prints what it was given.
    {
        std::ofstream core(dir.file("vdbrecon-core"));
        core << "#!/bin/sh\nprintf '%s|' \"$GLIBC_TUNABLES\" \"$@\"\n";
    }
    std::filesystem::permissions(dir.file("vdbrecon-core"), std::filesystem::perms::owner_all);
    REQUIRE(run("env -u GLIBC_TUNABLES") == 0);
    const std::string tunables =
        advised ? "glibc.malloc.hugetlb=1:glibc.malloc.top_pad=" + std::to_string(64 << 20) : "";
    REQUIRE(read_bytes(dir.file("out")) == tunables + "|a b|it's|");
    // Other tunables are kept; a hugetlb already named is left as it is.
    REQUIRE(run("env GLIBC_TUNABLES=glibc.malloc.arena_max=1") == 0);
    REQUIRE(read_bytes(dir.file("out")) ==
            "glibc.malloc.arena_max=1" + (advised ? ":" + tunables : "") + "|a b|it's|");
    REQUIRE(run("env GLIBC_TUNABLES=glibc.malloc.hugetlb=0") == 0);
    REQUIRE(read_bytes(dir.file("out")) == "glibc.malloc.hugetlb=0|a b|it's|");
}

namespace {

/// A made-up sysfs tree: the THP mode line and virtio devices (id, negotiated features, bound).
struct FakeSys {
    TempDir dir;
    explicit FakeSys(const std::string& thp) {
        std::filesystem::create_directories(dir.file("kernel/mm/transparent_hugepage"));
        std::ofstream(dir.file("kernel/mm/transparent_hugepage/enabled")) << thp << "\n";
    }
    void device(const std::string& name, const std::string& id, const std::string& features,
                bool bound = true) {
        const std::string d = dir.file("bus/virtio/devices/" + name);
        std::filesystem::create_directories(d);
        std::ofstream(d + "/device") << id << "\n";
        std::ofstream(d + "/features") << features << "\n";
        if (bound) std::filesystem::create_directories(d + "/driver");
    }
    std::string root() const { return dir.path(); }
};

}  // namespace

TEST_CASE("launcher: huge pages where the kernel gives them on request and memory stays", "[cli]") {
    using vdbrecon::launcher::free_memory_goes_to_host;
    using vdbrecon::launcher::huge_pages_help;
    // Bit 5 (VIRTIO_BALLOON_F_REPORTING) of a balloon's features: this VM's balloon, and one
    // with the same bits but for bit 5.
    const std::string reporting = "0110010100000000000000000000000010000000";
    const std::string silent = "0110000100000000000000000000000010000000";
    {
        FakeSys sys("always [madvise] never");  // bare metal: no virtio at all
        CHECK_FALSE(free_memory_goes_to_host(sys.root()));
        CHECK(huge_pages_help(sys.root()));
    }
    {
        FakeSys sys("always [madvise] never");
        sys.device("virtio0", "0x0005", reporting);
        sys.device("virtio1", "0x0002", silent);  // a disk
        CHECK(free_memory_goes_to_host(sys.root()));
        CHECK_FALSE(huge_pages_help(sys.root()));
    }
    {
        FakeSys sys("always [madvise] never");
        sys.device("virtio0", "0x0005", silent);            // a balloon that does not report
        sys.device("virtio1", "0x0002", reporting);         // bit 5 of another device means else
        sys.device("virtio2", "0x0005", reporting, false);  // no driver bound: nothing reported
        CHECK_FALSE(free_memory_goes_to_host(sys.root()));
        CHECK(huge_pages_help(sys.root()));
    }
    {
        FakeSys sys("[always] madvise never");  // huge pages without advice: nothing to add
        CHECK_FALSE(huge_pages_help(sys.root()));
        FakeSys never("always madvise [never]");
        CHECK_FALSE(huge_pages_help(never.root()));
    }
    CHECK_FALSE(huge_pages_help("/nonexistent/sys"));  // nothing readable: glibc's defaults
}

// Bad inputs, bad --voxel values and unwritable outputs: tests/test_bad_input.cpp.
TEST_CASE("cli: usage errors exit 2, I/O and format errors exit 3, nothing is written", "[cli]") {
    TempDir dir;
    write_points(dir.file("s.ply"), sample_sphere(2000, 1.0));
    const std::string in = dir.file("s.ply");
    struct Case {
        std::string args;
        int code;
        std::string message;
    };
    const Case cases[] = {
        {in + " --voxel abc", 2, "'abc' is not a finite number"},
        {in + " --bogus", 2, "unknown option '--bogus'"},
        {in + " --normals sideways", 2, "not one of auto, estimate, keep"},
        {in + " --viewpoint 1,2", 2, "--viewpoint needs three numbers"},
        {in + " --tile -3", 2, "--tile: -3 must be a number of voxels > 0, or auto"},
        {in + " --tile 16 --close-solid 2", 2, "a solid closing needs the whole surface"},
        {"", 2, "no input file"},
        {dir.file("missing.ply"), 3, dir.file("missing.ply") + ": cannot open"},
        {in + " -o " + in, 2, "refusing to overwrite"},
    };
    for (const Case& c : cases) {
        const bool has_output = c.args.find(" -o ") != std::string::npos;
        const CliRun r = run_cli(has_output ? c.args : c.args + " -o " + dir.file("out.ply"));
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
}
