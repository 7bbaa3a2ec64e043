// kNN benchmark and cross-check of KnnIndex's backends (knn.h): our Morton-grid search, FLANN's
// exact kd-tree and FLANN's eps-approximate search, on the bunny scans,
// the room scan (half its points exact copies), synthetic clouds and, optionally, a large
// synthetic cloud. Exactness: every query's k squared distances against brute force on a sample
// of queries (ids may differ only among exact ties). Times: build and self-neighbour lists
// (visited in batches, as the outlier stage does), best of 3 (of 1 above 5M points) on the given
// thread count.
// See bench/knn.sh.
#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>

#include "vdbrecon/io.h"
#include "vdbrecon/knn.h"

using namespace vdbrecon;

namespace {

double now() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch())
        .count();
}

const char* name_of(KnnBackend b) { return b == KnnBackend::grid ? "grid" : "flann"; }

/// Rows (of `samples` spread over the cloud) whose k distances differ from brute force.
std::size_t wrong_rows(const std::vector<Vec3f>& pts, const KnnIndex& index, int k, int samples) {
    std::vector<std::size_t> rows;
    for (int s = 0; s < samples; ++s) rows.push_back(std::size_t(s) * pts.size() / std::size_t(samples));
    const KnnResult r = index.self_neighbours_of(rows, k);
    std::size_t bad = 0;
    std::vector<float> all;
    for (std::size_t j = 0; j < rows.size(); ++j) {
        const Vec3f& q = pts[rows[j]];
        all.clear();
        for (std::size_t i = 0; i < pts.size(); ++i) {
            if (i != rows[j]) all.push_back(KnnResult::squared_distance(q, pts[i]));
        }
        std::partial_sort(all.begin(), all.begin() + k, all.end());
        bool same = true;
        for (int m = 0; m < k; ++m) same = same && all[std::size_t(m)] == r.sq_dists(j)[m];
        bad += !same;
    }
    return bad;
}

void run(const std::vector<Vec3f>& pts, int k, const std::string& name, int samples) {
    struct Way {
        KnnBackend backend;
        double eps;
    };
    for (const Way w : {Way{KnnBackend::grid, 0.0}, Way{KnnBackend::flann, 0.0},
                        Way{KnnBackend::flann, 1.0}}) {
        KnnOptions o;
        o.backend = w.backend;
        o.eps = w.eps;
        double build = 1e9, query = 1e9;
        for (int rep = 0; rep < (pts.size() > 5000000 ? 1 : 3); ++rep) {
            const double t0 = now();
            KnnIndex index(pts, o);
            const double t1 = now();
            std::size_t seen = 0;
            index.visit_self_neighbours(k, [&](const int*, std::size_t count, int, const int*) {
                seen += count;
            });
            const double t2 = now();
            build = std::min(build, t1 - t0);
            query = std::min(query, t2 - t1);
            if (seen != pts.size()) std::abort();
        }
        const std::size_t bad = wrong_rows(pts, KnnIndex(pts, o), k, samples);
        std::string way = name_of(w.backend);
        if (w.eps > 0.0) way += " eps " + std::to_string(int(w.eps));
        std::printf("| %s | %zu | %d | %s | %.3f | %.3f | %.3f | %zu of %d |\n", name.c_str(),
                    pts.size(), k, way.c_str(), build, query, build + query, bad, samples);
        std::fflush(stdout);
    }
}

std::vector<Vec3f> read(const char* path) {
    const ReadResult r = read_points(path);
    return {r.cloud.positions.begin(), r.cloud.positions.end()};
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 4) {
        std::fprintf(stderr, "usage: knn BUNNY.ply ROOM.ply THREADS [LARGE_MILLIONS]\n");
        return 2;
    }
    tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                                std::size_t(std::atoi(argv[3])));
    std::printf("| cloud | points | k | search | build s | lists s | total s | rows not exact "
                "(brute force) |\n|---|---|---|---|---|---|---|---|\n");
    run(read(argv[1]), 16, "bunny scans", 400);
    run(read(argv[2]), 16, "room scan (50 % exact copies)", 400);
    std::mt19937 rng(1);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<Vec3f> cube, dups;
    for (int i = 0; i < 200000; ++i) cube.push_back({u(rng), u(rng), u(rng)});
    for (int i = 0; i < 5000; ++i) {
        const Vec3f p = {u(rng), u(rng), u(rng)};
        for (int j = 0; j < 20; ++j) dups.push_back(p);
    }
    run(cube, 16, "uniform cube", 400);
    run(dups, 16, "20 copies of each point", 400);
    if (argc > 4) {  // a terrain-like sheet of N million points: z = a gentle wave plus noise
        const std::size_t n = std::size_t(std::atof(argv[4]) * 1e6);
        std::vector<Vec3f> large(n);
        std::normal_distribution<float> noise(0.0f, 0.002f);
        for (Vec3f& p : large) {
            const float x = 100.0f * u(rng), y = 100.0f * u(rng);
            p = {x, y, 2.0f * std::sin(0.1f * x) * std::cos(0.07f * y) + noise(rng)};
        }
        run(large, 16, std::to_string(n / 1000000) + "M-point terrain", 20);
    }
    return 0;
}
