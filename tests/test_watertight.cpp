// Closed in, closed out (issue 22): generated closed shapes (tests/shapes.h: CAD parts and
// organic shapes, uniform random samples with exact or estimated normals) come out closed with
// every mesher at voxels of 1x to 3x the sample spacing; thin walls stay intact; --close R closes
// holes 2R voxels across and leaves an open border where it was; dual contouring keeps the
// sharp edges of polyhedral parts.
#include <cmath>
#include <cstdint>

#include "shapes.h"
#include "support.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/pipeline.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

constexpr std::size_t kPoints = 60000;

Mesher mesher_named(const std::string& m) {
    return m == "dual"  ? Mesher::dual
           : m == "vdb" ? Mesher::vdb
           : m == "mc"  ? Mesher::mc
                        : Mesher::dc;
}

PipelineResult reconstruct_at(PointCloud cloud, double voxel, const std::string& mesher,
                              int close = 0) {
    PipelineOptions o;
    o.splat.voxel_size = voxel;
    o.mesh.method = mesher_named(mesher);
    o.close.hole_radius = close;
    return reconstruct(cloud, o);
}

}  // namespace

TEST_CASE("closed shapes come out closed with every mesher at 1x to 3x the spacing", "[watertight]") {
    for (const std::string name : {"cube", "drilled", "fan", "torus", "blob"}) {
        const Shape shape = make_shape(name);
        const PointCloud sample = sample_uniform(shape.mesh, kPoints, 3);
        const double h = spacing_of(shape.area, kPoints);
        for (double factor : {1.0, 3.0}) {
            for (const std::string mesher : {"dual", "vdb", "mc", "dc"}) {
                const PipelineResult r = reconstruct_at(sample, factor * h, mesher);
                const TopologyStats t = mesh_topology(r.mesh);
                INFO(name << " at " << factor << "x the spacing, " << mesher);
                CHECK(t.boundary_edges == 0);
                CHECK(t.nonmanifold_edges == 0);
                CHECK(t.components == 1);
            }
        }
    }
}

TEST_CASE("a face next to a concave edge keeps its plane at 1x the spacing", "[watertight][crease]") {
    // The crease model combined a face whose plane it continued past the concave edge where the
    // face ends (its other face out of reach) as the max of a convex pair: a dent of 0.9-1.4
    // voxel, and on the cross a hole (4 boundary edges with mc and dc). These samples showed it
    // before the faces' ways of meeting were scored on their samples.
    for (const std::string name : {"cross", "fan"}) {
        const Shape shape = make_shape(name);
        const PointCloud sample = sample_uniform(shape.mesh, kPoints, 9);
        const double voxel = spacing_of(shape.area, kPoints);
        for (const std::string mesher : {"mc", "dc"}) {
            const Mesh m = reconstruct_at(sample, voxel, mesher).mesh;
            const double worst = deviation(shape, m, voxel).vertex;
            INFO(name << ", " << mesher << ": worst vertex " << worst << " voxel");
            CHECK(mesh_topology(m).boundary_edges == 0);
            // (mc cuts sharp edges: its vertices lie up to ~0.4 voxel off the true surface.)
            CHECK(worst <= (mesher == "dc" ? 0.25 : 0.6));
        }
    }
}

TEST_CASE("CAD parts with estimated normals come out closed", "[watertight][normals]") {
    // The fan's 40-degree blade tips opened along their length (122-201 boundary edges on its
    // 200k sample): normals turned against their face next to the tips (see normals.cpp,
    // bridges), and the blend the crease model kept where a few blended normals weighed a tenth
    // of a voxel's weight past the tip (creases.cpp, kMaxStray). Then corners kept holes of
    // 4-32 boundary edges (the fan's 60k sample at 1x: 19/32 with mc/dc; the cube's: 8/13),
    // where the normals of the points within a third of a voxel blended two faces (normals.cpp,
    // other_planes and beside_crisp_plane), and one such sample among a face's few at a blade
    // tip's end left the crease model one face there (creases.cpp, consistent()). The
    // L-bracket's seed 6 (8/9 at 1x): a clump of three samples at a corner whose ten nearest
    // held one more point of their face (normals.cpp, Neighbourhood::crowded).
    // The fan's seed 6 at 1x (4/4/5): the one sample of a blade's end face near its tip kept
    // a blend (normals.cpp, adopt_neighbour_faces).
    struct Case {
        const char* name;
        std::size_t points;
        std::uint64_t seed;
        bool one_factor = false;  // 1x only
    };
    for (const Case c : {Case{"fan", 200000, 2}, Case{"fan", 200000, 6, true},
                         Case{"fan", kPoints, 5}, Case{"cube", kPoints, 4},
                         Case{"lbracket", kPoints, 6}, Case{"boss", kPoints, 1},
                         Case{"pocket", kPoints, 1}, Case{"cross", kPoints, 1},
                         Case{"drilled", kPoints, 1}}) {
        const Shape shape = make_shape(c.name);
        PointCloud sample = sample_uniform(shape.mesh, c.points, c.seed);
        sample.normals.clear();  // kNN PCA with crisp faces, Hoppe orientation
        const double h = spacing_of(shape.area, c.points);
        for (double factor : {1.0, 1.5}) {
            if (c.one_factor && factor != 1.0) continue;
            for (const std::string mesher : {"dual", "vdb", "mc", "dc"}) {
                if (c.points != 200000 && mesher == "vdb") continue;
                const TopologyStats t = mesh_topology(reconstruct_at(sample, factor * h, mesher).mesh);
                INFO(c.name << " (" << c.points << " samples, seed " << c.seed << ") at " << factor
                            << "x the spacing, " << mesher);
                CHECK(t.boundary_edges == 0);
                CHECK(t.nonmanifold_edges == 0);
                CHECK(t.components == 1);
            }
        }
    }
}

TEST_CASE("smooth closed shapes with estimated normals come out closed", "[watertight]") {
    for (const std::string name : {"torus", "blob"}) {
        const Shape shape = make_shape(name);
        PointCloud sample = sample_uniform(shape.mesh, kPoints, 4);
        sample.normals.clear();  // kNN PCA + Hoppe orientation
        const double h = spacing_of(shape.area, kPoints);
        for (double factor : {1.0, 3.0}) {
            const PipelineResult r = reconstruct_at(sample, factor * h, "mc");
            const TopologyStats t = mesh_topology(r.mesh);
            INFO(name << " at " << factor << "x the spacing");
            CHECK(t.boundary_edges == 0);
            CHECK(t.nonmanifold_edges == 0);
            CHECK(t.components == 1);
        }
    }
}

TEST_CASE("walls 3 voxels thick stay intact", "[watertight]") {
    const double voxel = 0.01, wall = 3 * voxel;
    double area = 0.0;
    const PointCloud block = sample_thin_walled_block(wall, 200000, 5, &area);
    REQUIRE(spacing_of(area, 200000) < voxel);
    for (const std::string mesher : {"mc", "dc"}) {
        const PipelineResult r = reconstruct_at(block, voxel, mesher);
        const TopologyStats t = mesh_topology(r.mesh);
        INFO(mesher);
        CHECK(t.boundary_edges == 0);
        CHECK(t.nonmanifold_edges == 0);
        CHECK(t.components == 2);  // the block and the closed cavity's wall
    }
}

TEST_CASE("hole closing by R closes holes 2R voxels across in a closed sample", "[watertight][close]") {
    for (const std::string name : {"cube", "sphere", "drilled"}) {
        const Shape shape = make_shape(name);
        const double h = spacing_of(shape.area, kPoints);
        for (int radius : {2, 3}) {
            const double voxel = 1.5 * h;
            PointCloud holed = sample_uniform(shape.mesh, kPoints, 6);
            const std::vector<Vec3f> centres = punch_holes(holed, 4, radius * voxel, 9);
            REQUIRE(centres.size() == 4);
            INFO(name << ", holes " << 2 * radius << " voxels across");
            if (radius == 3) {  // (holes 4 voxels across may be bridged without closing)
                const TopologyStats open = mesh_topology(reconstruct_at(holed, voxel, "mc").mesh);
                REQUIRE(open.boundary_edges > 0);
            }
            for (const std::string mesher : {"mc", "dc"}) {
                const TopologyStats t =
                    mesh_topology(reconstruct_at(holed, voxel, mesher, radius).mesh);
                INFO(mesher);
                CHECK(t.boundary_edges == 0);
                CHECK(t.nonmanifold_edges == 0);
                CHECK(t.components == 1);
            }
        }
    }
}

TEST_CASE("hole closing keeps the outer border of an open patch within a voxel", "[watertight][close]") {
    // A 2 x 2 patch of the plane z = 0 sampled uniformly at random.
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    PointCloud patch;
    for (int i = 0; i < 40000; ++i) {
        patch.positions.push_back({float(u(rng)), float(u(rng)), 0.0f});
        patch.normals.push_back({0.0f, 0.0f, 1.0f});
    }
    const double voxel = 0.02;  // the spacing is 0.01
    const Mesh open = reconstruct_at(patch, voxel, "mc").mesh;
    const Mesh closed = reconstruct_at(patch, voxel, "mc", 4).mesh;
    const BBox a = bounding_box(open.vertices), b = bounding_box(closed.vertices);
    for (int k = 0; k < 2; ++k) {
        CHECK(b.min[k] > -1.0 - voxel);
        CHECK(b.max[k] < 1.0 + voxel);
        CHECK(std::fabs(b.min[k] - a.min[k]) < voxel);
        CHECK(std::fabs(b.max[k] - a.max[k]) < voxel);
    }
    const std::vector<double> loops = boundary_loop_lengths(closed);
    REQUIRE(loops.size() == 1);
    CHECK(loops[0] == Approx(boundary_loop_lengths(open).at(0)).epsilon(0.05));
}

TEST_CASE("dual contouring is no less accurate than marching cubes on smooth shapes",
          "[watertight][dc]") {
    // Issue 22 point 4: dc's Chamfer distance never worse than mc's on smooth shapes. Measured
    // (voxel): sphere 1x dc 0.0119 -> 0.0083 with its vertices on the field's zero (mc 0.0101),
    // 3x 0.0146 -> 0.0078 (0.0132); torus 1x 0.0152 -> 0.0122 (0.0143), 3x 0.0213 -> 0.0132
    // (0.0192).
    for (const std::string name : {"sphere", "torus"}) {
        const Shape shape = make_shape(name);
        const PointCloud sample = sample_uniform(shape.mesh, kPoints, 11);
        const double h = spacing_of(shape.area, kPoints);
        for (double factor : {1.0, 3.0}) {
            EvalOptions e;
            e.samples = 300000;
            const double voxel = factor * h;
            const double dc = evaluate(reconstruct_at(sample, voxel, "dc").mesh, shape.mesh, e)
                                  .chamfer_l1 / voxel;
            const double mc = evaluate(reconstruct_at(sample, voxel, "mc").mesh, shape.mesh, e)
                                  .chamfer_l1 / voxel;
            INFO(name << " at " << factor << "x: Chamfer dc " << dc << ", mc " << mc << " voxel");
            CHECK(dc <= mc);
            CHECK(dc < 0.02);
        }
    }
}

TEST_CASE("dual contouring keeps the sharp edges of polyhedral parts", "[watertight][dc]") {
    // Concave corners (the cross's, the pocket's, the L-bracket's inner one) were 0.15-0.3 voxel
    // off before repair_hermite's rule 2 gave their smeared crossings the third plane. The fan's
    // 40-degree blade tips were cut by ~1.7 voxel (Hausdorff 1.26) before the feature path solved
    // its planes without the bias first.
    for (const std::string name : {"cube", "cross", "pocket", "lbracket", "fan"}) {
        const Shape shape = make_shape(name);
        const PointCloud sample = sample_uniform(shape.mesh, kPoints, 7);
        const double voxel = 1.5 * spacing_of(shape.area, kPoints);
        const Deviation dc = deviation(shape, reconstruct_at(sample, voxel, "dc").mesh, voxel);
        const Deviation mc = deviation(shape, reconstruct_at(sample, voxel, "mc").mesh, voxel);
        // Every corner has a dc vertex within 0.1 voxel.
        INFO(name << ": vertex-to-surface distance dc " << dc.vertex << ", mc " << mc.vertex
                  << " voxels; worst corner " << dc.corner);
        CHECK(dc.vertex <= 0.25);
        CHECK(dc.vertex <= 0.5 * mc.vertex);
        CHECK(dc.corner <= 0.1);
    }
}

TEST_CASE("dual contouring keeps the edges of parts with cylinders", "[watertight][dc][crease]") {
    // A block with a boss and a drilled block, at 1x and 3x the sample spacing (the cylinders'
    // radii are 33 and 24 voxels, then 11 and 8). Before the crease model's faces had to be
    // connected, the block's side wall and the boss's wall 9 voxels inside it were one face
    // that failed the test of positions against normals, and a curved face seen over a wide arc
    // was rejected whole: the splat's blend stayed there, and the boss at 3x was 0.31 (seed 1)
    // and 0.43 (seed 2) voxel off (Hausdorff). Before merge_curved the drilled hole's rim at 3x
    // was cut by 0.15 voxel; before the crease model's second-order face fields and the face
    // test of repair_hermite's rule 1, by 0.10-0.15 voxel at 1x and 3x (seeds 1-3).
    for (const std::string name : {"boss", "drilled"}) {
        const Shape shape = make_shape(name);
        for (std::uint64_t seed : {1, 2, 3}) {
            const PointCloud sample = sample_uniform(shape.mesh, kPoints, seed);
            for (double factor : {1.0, 3.0}) {
                const double voxel = factor * spacing_of(shape.area, kPoints);
                const Deviation dc =
                    deviation(shape, reconstruct_at(sample, voxel, "dc").mesh, voxel);
                INFO(name << " at " << factor << "x, seed " << seed << ": Hausdorff " << dc.vertex
                          << ", worst edge point " << dc.edge << " voxel");
                CHECK(dc.vertex <= 0.25);
                CHECK(dc.edge <= 0.1);
            }
        }
    }
}
