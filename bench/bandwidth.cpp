// Memory bandwidth of this machine, STREAM style (J. McCalpin, "Memory bandwidth and machine
// balance", 1995): copy (a = b) and triad (a = b + s c) over arrays far larger than the caches,
// on 1 and 2 threads (TBB, static partition), best of 5 runs. Bytes counted as STREAM does
// (copy: 16 per element, triad: 24), without write-allocate traffic.
//   bench/bandwidth.sh   (compiles this file and runs it)
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <vector>

int main() {
    const std::size_t n = std::size_t(1) << 26;  // 64 Mi doubles = 512 MiB per array
    std::vector<double> a(n, 1.0), b(n, 2.0), c(n, 3.0);
    for (int threads : {1, 2}) {
        tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
        auto run = [&](auto body) {
            double best = 1e30;
            for (int rep = 0; rep < 5; ++rep) {
                const auto t0 = std::chrono::steady_clock::now();
                tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, n / 64),
                                  [&](const tbb::blocked_range<std::size_t>& r) {
                                      for (std::size_t i = r.begin(); i < r.end(); ++i) body(i);
                                  },
                                  tbb::static_partitioner());
                best = std::min(best, std::chrono::duration<double>(
                                          std::chrono::steady_clock::now() - t0).count());
            }
            return best;
        };
        const double copy = run([&](std::size_t i) { a[i] = b[i]; });
        const double triad = run([&](std::size_t i) { a[i] = b[i] + 3.0 * c[i]; });
        std::printf("threads %d: copy %.1f GB/s, triad %.1f GB/s\n", threads,
                    16.0 * double(n) / copy / 1e9, 24.0 * double(n) / triad / 1e9);
    }
    std::printf("check %.1f\n", a[n / 2]);
    return 0;
}
