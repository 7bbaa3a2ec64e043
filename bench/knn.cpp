// kNN benchmark and cross-check: vdbrecon's Morton-grid kNN (src/knn.cpp) against FLANN's exact
// single kd-tree (what vdbrecon used before), on the bunny scans and synthetic clouds. Every
// query's k squared distances must be equal (neighbour ids may differ only among exact ties);
// prints build and query times, best of 3, on the given thread count. See bench/knn.sh.
#include <flann/flann.hpp>
#include <tbb/global_control.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <random>

#include "vdbrecon/io.h"
#include "vdbrecon/knn.h"

using namespace vdbrecon;

namespace {

double now() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch())
        .count();
}

/// Compares and times both on `pts` (k self-neighbours); returns the number of mismatched rows.
std::size_t run(const std::vector<Vec3f>& pts, int k, const char* name) {
    double ours_build = 1e9, ours_query = 1e9, flann_build = 1e9, flann_query = 1e9;
    KnnResult ours;
    std::vector<float> fd;
    const int kq = k + 1;  // FLANN's lists include the point itself
    for (int rep = 0; rep < 3; ++rep) {
        double t0 = now();
        KnnIndex index(pts);
        double t1 = now();
        ours = index.self_neighbours(k);
        double t2 = now();
        ours_build = std::min(ours_build, t1 - t0);
        ours_query = std::min(ours_query, t2 - t1);

        flann::Matrix<float> data(const_cast<float*>(pts[0].data()), pts.size(), 3);
        t0 = now();
        flann::Index<flann::L2_Simple<float>> fi(data, flann::KDTreeSingleIndexParams(15));
        fi.buildIndex();
        t1 = now();
        std::vector<int> fi_idx(pts.size() * std::size_t(kq));
        fd.assign(fi_idx.size(), 0.0f);
        // Queries in parallel chunks, as vdbrecon did.
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, pts.size(), 2048),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            flann::Matrix<float> q(const_cast<float*>(pts[r.begin()].data()), r.size(), 3);
            flann::Matrix<int> mi(&fi_idx[r.begin() * kq], r.size(), std::size_t(kq));
            flann::Matrix<float> md(&fd[r.begin() * kq], r.size(), std::size_t(kq));
            fi.knnSearch(q, mi, md, std::size_t(kq),
                         flann::SearchParams(flann::FLANN_CHECKS_UNLIMITED, 0.0f, true));
        });
        t2 = now();
        flann_build = std::min(flann_build, t1 - t0);
        flann_query = std::min(flann_query, t2 - t1);
    }
    std::size_t bad = 0;
    for (std::size_t i = 0; i < pts.size(); ++i) {
        std::vector<float> f(fd.begin() + long(i * kq), fd.begin() + long((i + 1) * kq));
        const auto self = std::find(f.begin(), f.end(), 0.0f);  // one zero is the point itself
        f.erase(self != f.end() ? self : f.end() - 1);
        bool same = true;
        for (int j = 0; j < k; ++j) {
            same = same && f[std::size_t(j)] == ours.sq_dists(i)[j] &&
                   ours.neighbours(i)[j] != int(i);
        }
        bad += !same;
    }
    std::printf("| %s | %zu | %d | %.3f | %.3f | %.3f | %.3f | %.2fx | %zu |\n", name, pts.size(), k,
                ours_build, ours_query, flann_build, flann_query,
                (flann_build + flann_query) / (ours_build + ours_query), bad);
    return bad;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 3) {
        std::fprintf(stderr, "usage: knn SCAN.ply THREADS\n");
        return 2;
    }
    tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                                std::size_t(std::atoi(argv[2])));
    std::printf("| cloud | points | k | ours build s | ours query s | FLANN build s | FLANN query s "
                "| speed-up | mismatched rows |\n|---|---|---|---|---|---|---|---|---|\n");
    std::size_t bad = 0;
    const ReadResult scan = read_points(argv[1]);
    const std::vector<Vec3f> bunny(scan.cloud.positions.begin(), scan.cloud.positions.end());
    bad += run(bunny, 16, "bunny scans (outlier stage)");
    bad += run(bunny, 10, "bunny scans (normal stage)");
    std::mt19937 rng(1);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<Vec3f> cube, plane, dups;
    for (int i = 0; i < 200000; ++i) cube.push_back({u(rng), u(rng), u(rng)});
    for (int i = 0; i < 200000; ++i) plane.push_back({u(rng), u(rng), 0.001f * u(rng)});
    for (int i = 0; i < 100; ++i) plane.push_back({100 * u(rng), 100 * u(rng), 100 * u(rng)});
    for (int i = 0; i < 5000; ++i) {
        const Vec3f p = {u(rng), u(rng), u(rng)};
        for (int j = 0; j < 20; ++j) dups.push_back(p);
    }
    bad += run(cube, 16, "uniform cube");
    bad += run(plane, 16, "plane + 100 far strays");
    bad += run(dups, 16, "20 copies of each point");
    std::printf("\nmismatched rows in all: %zu\n", bad);
    return bad == 0 ? 0 : 1;
}
