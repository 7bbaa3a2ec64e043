// Test helpers: analytic point samples, temporary directories, the shared data corpus.
#pragma once

#include <catch2/catch.hpp>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "vdbrecon/types.h"

namespace vdbrecon::test {

/// N points on a sphere (Fibonacci spiral: nearly uniform, deterministic) with outward normals.
inline PointCloud sample_sphere(std::size_t n, double radius, const Vec3d& centre = {0, 0, 0}) {
    PointCloud c;
    const double golden = M_PI * (3.0 - std::sqrt(5.0));
    for (std::size_t i = 0; i < n; ++i) {
        const double y = 1.0 - 2.0 * (double(i) + 0.5) / double(n);
        const double r = std::sqrt(1.0 - y * y);
        const double t = golden * double(i);
        const double nx = r * std::cos(t), nz = r * std::sin(t);
        c.positions.push_back({float(centre[0] + radius * nx), float(centre[1] + radius * y),
                               float(centre[2] + radius * nz)});
        c.normals.push_back({float(nx), float(y), float(nz)});
    }
    return c;
}

/// A square patch of the plane z = 0 (normal +z), `n` x `n` jittered grid points over
/// [-half, half]^2.
inline PointCloud sample_plane(int n, double half, unsigned seed = 7) {
    PointCloud c;
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> jitter(-0.25, 0.25);
    const double h = 2.0 * half / double(n - 1);
    for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
            c.positions.push_back({float(-half + h * (i + jitter(rng))),
                                   float(-half + h * (j + jitter(rng))), 0.0f});
            c.normals.push_back({0.0f, 0.0f, 1.0f});
        }
    }
    return c;
}

/// Lengths of the closed loops the boundary edges (one incident face) form, longest first; empty
/// when there is no boundary, {-1} when the boundary edges do not form simple loops.
inline std::vector<double> boundary_loop_lengths(const Mesh& m) {
    std::map<std::pair<int, int>, int> count;  // undirected edge -> faces
    for (const Triangle& t : m.faces) {
        for (int k = 0; k < 3; ++k) {
            const int a = t[k], b = t[(k + 1) % 3];
            ++count[{std::min(a, b), std::max(a, b)}];
        }
    }
    std::map<int, std::vector<int>> adj;
    for (const auto& [e, n] : count) {
        if (n != 1) continue;
        adj[e.first].push_back(e.second);
        adj[e.second].push_back(e.first);
    }
    for (const auto& [v, nb] : adj) {
        if (nb.size() != 2) return {-1.0};
    }
    auto dist = [&](int a, int b) {
        const Vec3f &p = m.vertices[std::size_t(a)], &q = m.vertices[std::size_t(b)];
        return std::sqrt(double(p[0] - q[0]) * (p[0] - q[0]) + double(p[1] - q[1]) * (p[1] - q[1]) +
                         double(p[2] - q[2]) * (p[2] - q[2]));
    };
    std::map<int, bool> seen;
    std::vector<double> loops;
    for (const auto& [v, nb] : adj) {
        if (seen[v]) continue;
        double length = 0.0;
        std::vector<int> stack{v};
        while (!stack.empty()) {
            const int x = stack.back();
            stack.pop_back();
            if (seen[x]) continue;
            seen[x] = true;
            for (int y : adj[x]) {
                if (x < y) length += dist(x, y);  // each edge once
                stack.push_back(y);
            }
        }
        loops.push_back(length);
    }
    std::sort(loops.rbegin(), loops.rend());
    return loops;
}

/// Number of boundary loops (-1 when the boundary edges do not form simple loops).
inline int boundary_loops(const Mesh& m) {
    const std::vector<double> l = boundary_loop_lengths(m);
    return l.size() == 1 && l[0] < 0.0 ? -1 : int(l.size());
}

/// An environment variable set while alive, then put back as it was (unset if it was).
class ScopedEnv {
  public:
    ScopedEnv(const char* name, const char* value) : name_(name) {
        const char* old = std::getenv(name);
        had_ = old != nullptr;
        if (had_) old_ = old;
        ::setenv(name, value, 1);
    }
    ~ScopedEnv() {
        if (had_) {
            ::setenv(name_.c_str(), old_.c_str(), 1);
        } else {
            ::unsetenv(name_.c_str());
        }
    }
    ScopedEnv(const ScopedEnv&) = delete;
    ScopedEnv& operator=(const ScopedEnv&) = delete;

  private:
    std::string name_, old_;
    bool had_ = false;
};

/// A fresh empty directory under /tmp, removed (with its files) when the object dies.
class TempDir {
public:
    TempDir() {
        char tmpl[] = "/tmp/vdbrecon_test_XXXXXX";
        const char* p = ::mkdtemp(tmpl);
        REQUIRE(p != nullptr);
        path_ = p;
    }
    ~TempDir() {
        const std::string cmd = "rm -rf '" + path_ + "'";
        if (std::system(cmd.c_str()) != 0) std::fprintf(stderr, "could not remove %s\n", path_.c_str());
    }
    std::string file(const std::string& name) const { return path_ + "/" + name; }
    const std::string& path() const { return path_; }

private:
    std::string path_;
};

inline bool file_exists(const std::string& p) {
    struct stat st {};
    return ::stat(p.c_str(), &st) == 0;
}

inline std::string read_bytes(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    std::ostringstream s;
    s << f.rdbuf();
    return s.str();
}

inline void write_bytes(const std::string& path, const std::string& bytes) {
    std::ofstream f(path, std::ios::binary);
    f << bytes;
}

/// Number of files in a directory (to check that nothing, not even a temp file, was left).
inline int count_files(const std::string& dir) {
    const std::string cmd = "ls -A '" + dir + "' | wc -l";
    FILE* p = ::popen(cmd.c_str(), "r");
    int n = -1;
    if (p) {
        if (std::fscanf(p, "%d", &n) != 1) n = -1;
        ::pclose(p);
    }
    return n;
}

/// What a run of the command-line tool did.
struct CliRun {
    int code = -1;  ///< exit code, -1 if it died from a signal
    std::string out, err;
};

/// Runs `PREFIX vdbrecon ARGS` through the shell (PREFIX: e.g. "ulimit -v N;" or a command that
/// drops privileges), capturing stdout and stderr in a directory of their own.
inline CliRun run_cli(const std::string& args, const std::string& prefix = {}) {
    TempDir capture;
    const std::string out = capture.file("stdout"), err = capture.file("stderr");
    const std::string cmd =
        prefix + " " + VDBRECON_CLI + " " + args + " >'" + out + "' 2>'" + err + "'";
    const int status = std::system(cmd.c_str());
    CliRun r;
    r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    r.out = read_bytes(out);
    r.err = read_bytes(err);
    return r;
}

/// Path of a file in ../shared/data, or "" (with a visible warning) when the corpus is absent,
/// as in a user's clone: such tests then pass vacuously and say so.
inline std::string shared_data(const std::string& relative) {
    const std::string p = std::string(VDBRECON_SHARED_DATA) + "/" + relative;
    if (!file_exists(p)) {
        WARN("SKIPPED: " << p << " not found (../shared/data is only present on CI and dev "
                             "machines)");
        return {};
    }
    return p;
}

}  // namespace vdbrecon::test
