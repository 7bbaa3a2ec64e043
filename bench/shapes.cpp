// Watertightness and sharpness on generated shapes (issue 22): each closed shape of
// tests/shapes.h is sampled with uniform random points carrying exact face normals, reconstructed
// in-process at several voxel sizes with each mesher, and scored against its exact mesh:
// boundary and non-manifold edges, pieces, Hausdorff and Chamfer distance (in voxels), and for
// the CAD parts the worst corner (nearest vertex) and the worst point of a sharp edge (distance
// to the mesh), also in voxels. Prints a markdown table.
//
//   shapes_bench [--shapes a,b,...] [--factors 1,1.5,3] [--meshers vdb,mc,dc] [--points N]
//                [--holes K,R] [--close R] [--watertight] [--surface-weight W] [--max-gap G]
//                [--samples S] [--threads T] [--estimate-normals] [--seeds SAMPLE,HOLES]
//                [--save DIR]
//
// --factors: voxel = factor x spacing, spacing = sqrt(area / points). --holes K,R: K round holes
// of R voxels radius punched into each sample. --save DIR writes each mesh and its sample.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "shapes.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/io.h"
#include "vdbrecon/pipeline.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

std::vector<std::string> split(const std::string& s) {
    std::vector<std::string> out;
    std::stringstream in(s);
    std::string part;
    while (std::getline(in, part, ',')) out.push_back(part);
    return out;
}

struct Row {
    TopologyStats topo;
    double hausdorff = 0, chamfer = 0, corner = 0, edge = 0, seconds = 0;
};

Row score(const Shape& shape, const Mesh& mesh, double voxel, std::size_t samples) {
    Row row;
    EvalOptions e;
    e.samples = samples;
    e.taus = {voxel};
    const EvalResult r = evaluate(mesh, shape.mesh, e);
    row.topo = r.recon;
    // Hausdorff also over the vertices (samples alone can miss a spike's tip).
    const Deviation dev = deviation(shape, mesh, voxel);
    row.hausdorff = std::max(r.hausdorff / voxel, dev.vertex);
    row.chamfer = r.chamfer_l1 / voxel;
    row.edge = dev.edge;
    row.corner = dev.corner;
    return row;
}

}  // namespace

int main(int argc, char** argv) {
    std::vector<std::string> names = cad_shape_names();
    for (const std::string& n : organic_shape_names()) names.push_back(n);
    std::vector<double> factors = {1.0, 1.5, 3.0};
    std::vector<std::string> meshers = {"vdb", "mc", "dc"};
    std::size_t points = 200000, samples = 300000;
    int holes = 0;
    double hole_radius = 0;
    std::string save;
    bool estimate = false;
    std::uint64_t sample_seed = 1, hole_seed = 5;
    PipelineOptions base;
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        const auto next = [&]() -> std::string {
            if (i + 1 >= argc) {
                std::fprintf(stderr, "%s needs a value\n", a.c_str());
                std::exit(2);
            }
            return argv[++i];
        };
        if (a == "--shapes") {
            names = split(next());
        } else if (a == "--factors") {
            factors.clear();
            for (const std::string& f : split(next())) factors.push_back(std::stod(f));
        } else if (a == "--meshers") {
            meshers = split(next());
        } else if (a == "--points") {
            points = std::stoul(next());
        } else if (a == "--samples") {
            samples = std::stoul(next());
        } else if (a == "--holes") {
            const std::vector<std::string> h = split(next());
            holes = std::stoi(h.at(0));
            hole_radius = std::stod(h.at(1));
        } else if (a == "--close") {
            base.close.hole_radius = std::stoi(next());
        } else if (a == "--surface-weight") {
            base.mesh.min_surface_weight = std::stod(next());
        } else if (a == "--min-weight") {
            base.splat.min_weight = std::stod(next());
        } else if (a == "--support") {
            base.splat.support = std::stod(next());
        } else if (a == "--sigma-voxels") {
            base.normals.scale = ScaleMode::none;
            base.splat.sigma_voxels = std::stod(next());
        } else if (a == "--max-gap") {
            base.mesh.max_gap = std::stod(next());
        } else if (a == "--threads") {
            base.threads = std::stoi(next());
        } else if (a == "--seeds") {
            const std::vector<std::string> v = split(next());
            sample_seed = std::stoull(v.at(0));
            hole_seed = std::stoull(v.at(1));
        } else if (a == "--estimate-normals") {
            estimate = true;
        } else if (a == "--save") {
            save = next();
        } else {
            std::fprintf(stderr, "unknown argument %s\n", a.c_str());
            return 2;
        }
    }
    std::error_code error;
    if (!save.empty() && !std::filesystem::is_directory(save, error)) {
        std::fprintf(stderr, "--save %s: no such directory\n", save.c_str());
        return 2;
    }
    std::printf("| shape | voxel/spacing | mesher | boundary edges | non-manifold edges | pieces | "
                "Hausdorff (vox) | Chamfer (vox) | worst corner (vox) | worst edge point (vox) | "
                "time (s) |\n|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (const std::string& name : names) {
        const Shape shape = make_shape(name);
        const double h = spacing_of(shape.area, points);
        PointCloud sample = sample_uniform(shape.mesh, points, sample_seed);
        for (double factor : factors) {
            const double voxel = factor * h;
            PointCloud cloud = sample;
            if (holes > 0) punch_holes(cloud, holes, hole_radius * voxel, hole_seed);
            if (estimate) cloud.normals.clear();
            if (!save.empty() && holes > 0) {
                char buf[64];
                std::snprintf(buf, sizeof buf, "%.2f", factor);
                write_points(save + "/" + name + "_" + buf + ".holed.ply", cloud);
            }
            for (const std::string& m : meshers) {
                PipelineOptions o = base;
                o.splat.voxel_size = voxel;
                o.mesh.method = m == "vdb" ? Mesher::vdb : m == "mc" ? Mesher::mc : Mesher::dc;
                PointCloud c = cloud;
                const auto start = std::chrono::steady_clock::now();
                const PipelineResult r = reconstruct(c, o);
                if (m == meshers.front()) {
                    std::fprintf(stderr, "%s %.2f: voxel %.6g\n", name.c_str(), factor, voxel);
                }
                const double seconds =
                    std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
                Row row = score(shape, r.mesh, voxel, samples);
                row.seconds = seconds;
                if (!save.empty()) {
                    char buf[64];
                    std::snprintf(buf, sizeof buf, "%.2f", factor);
                    write_mesh(save + "/" + name + "_" + buf + "_" + m + ".ply", r.mesh);
                }
                std::printf("| %s | %.2f | %s | %zu | %zu | %zu | %.3f | %.4f | %s | %s | %.2f |\n",
                            name.c_str(), factor, m.c_str(), row.topo.boundary_edges,
                            row.topo.nonmanifold_edges, row.topo.components, row.hausdorff,
                            row.chamfer, shape.cad ? std::to_string(row.corner).substr(0, 5).c_str() : "-",
                            shape.cad ? std::to_string(row.edge).substr(0, 5).c_str() : "-",
                            row.seconds);
                std::fflush(stdout);
            }
        }
        if (!save.empty()) {
            write_points(save + "/" + name + ".sample.ply", sample);
            write_mesh(save + "/" + name + ".truth.ply", shape.mesh);
        }
    }
    return 0;
}
