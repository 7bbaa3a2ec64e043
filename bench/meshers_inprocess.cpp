// In-process mesher timing (bench/meshers_inprocess.sh): meshes one volume with each mesher, at 1
// and 2 threads, and prints the best of N runs of the mesher alone and of the whole mesh stage
// (mesher + finish_mesh, what vdbrecon logs as "mesh") as lines "mesher threads mesher_s stage_s
// faces". Without the point reading, splat and process start around it, so two builds can be
// compared at the millisecond level.
//   meshers_inprocess VOLUME.vdb [N=7] [MESHERS=dual,vdb,mc,dc]  (a build without one of them
//   skips it)
#include <malloc.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "detail/mesh_common.h"
#include "vdbrecon/choices.h"
#include "vdbrecon/volume.h"

int main(int argc, char** argv) {
    using namespace vdbrecon;
    using Clock = std::chrono::steady_clock;
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s VOLUME.vdb [N=7] [MESHERS=dual,vdb,mc,dc]\n", argv[0]);
        return 2;
    }
    // The heap as the CLI sets it up (apps/vdbrecon.cpp, tune_heap; meshers_inprocess.sh also
    // sets its huge-page tunable): freed memory stays for the next run, so a mesher is timed
    // without page-faulting in fresh memory, as it runs after the splat in the CLI.
    mallopt(M_MMAP_THRESHOLD, 32 << 20);
    mallopt(M_TRIM_THRESHOLD, 1 << 30);
    mallopt(M_ARENA_MAX, 1);
    const Volume volume = read_volume(argv[1]);
    const int reps = argc > 2 ? std::atoi(argv[2]) : 7;
    const std::string which = argc > 3 ? argv[3] : "dual,vdb,mc,dc";
    MeshOptions options;
    for (int threads : {1, 2}) {
        tbb::task_arena arena(threads);
        arena.execute([&] {
            for (const std::string name : {"dual", "vdb", "mc", "dc"}) {
                if (which.find(name) == std::string::npos) continue;
                const Mesher* method = find_choice(mesher_choices(), name);
                if (!method) continue;
                options.method = *method;
                double mesher = 1e30, stage = 1e30;
                std::size_t faces = 0;
                for (int r = 0; r < reps; ++r) {
                    const auto t0 = Clock::now();
                    detail::RawSurface raw = detail::mesh_raw(volume, options);
                    const auto t1 = Clock::now();
                    const MeshResult m = detail::finish_mesh(volume, options, std::move(raw));
                    const auto t2 = Clock::now();
                    mesher = std::min(mesher, std::chrono::duration<double>(t1 - t0).count());
                    stage = std::min(stage, std::chrono::duration<double>(t2 - t0).count());
                    faces = m.mesh.faces.size();
                }
                std::printf("%s %d %.4f %.4f %zu\n", name.c_str(), threads, mesher, stage, faces);
            }
        });
    }
    return 0;
}
