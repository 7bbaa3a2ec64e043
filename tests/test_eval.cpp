#include <openvdb/tools/LevelSetSphere.h>

#include "support.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/mesh.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

Mesh cube(double s = 1.0, const Vec3d& origin = {0, 0, 0}) {
    Mesh m;
    m.origin = origin;
    for (int i = 0; i < 8; ++i) {
        m.vertices.push_back({float(s * (i & 1)), float(s * ((i >> 1) & 1)), float(s * (i >> 2))});
    }
    // Outward, counter-clockwise.
    m.faces = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
               {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
    return m;
}

Mesh sphere_mesh(float r, float voxel) {
    initialize_openvdb();
    Volume v;
    v.sdf = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(r, openvdb::Vec3f(0.0f),
                                                                     voxel, 3.0f);
    v.voxel_size = voxel;
    return extract_mesh(v).mesh;
}

/// The faces of `s` whose vertices all lie above z = 0 (the other vertices stay, unused).
Mesh upper_half(const Mesh& s) {
    Mesh top = s;
    top.faces.clear();
    for (const Triangle& t : s.faces) {
        if (s.vertices[t[0]][2] > 0 && s.vertices[t[1]][2] > 0 && s.vertices[t[2]][2] > 0) {
            top.faces.push_back(t);
        }
    }
    return top;
}

}  // namespace

TEST_CASE("topology of a closed cube and of an open one", "[eval]") {
    Mesh c = cube();
    TopologyStats t = mesh_topology(c);
    REQUIRE(t.vertices == 8);
    REQUIRE(t.faces == 12);
    REQUIRE(t.euler == 2);
    REQUIRE(t.watertight());
    REQUIRE(t.components == 1);
    REQUIRE(t.area == Approx(6.0));
    REQUIRE(t.signed_volume == Approx(1.0));
    c.faces.edit().pop_back();
    c.faces.edit().pop_back();  // remove the +x face
    t = mesh_topology(c);
    REQUIRE(t.boundary_edges == 4);
    REQUIRE(t.euler == 1);
    // A third face on an edge makes it non-manifold; a separate triangle is a component.
    c = cube();
    c.vertices.push_back({0.5f, -1.0f, 0.0f});
    c.faces.push_back({0, 1, 8});
    c.vertices.push_back({5, 5, 5});
    c.vertices.push_back({6, 5, 5});
    c.vertices.push_back({5, 6, 5});
    c.faces.push_back({9, 10, 11});
    t = mesh_topology(c);
    REQUIRE(t.nonmanifold_edges == 1);
    REQUIRE(t.components == 2);
}

TEST_CASE("exact point-to-mesh distances", "[eval]") {
    const MeshDistance d(cube());
    REQUIRE(d.distance({0.5f, 0.5f, 2.0f}) == Approx(1.0));    // above the top face
    REQUIRE(d.distance({2.0f, 2.0f, 2.0f}) == Approx(std::sqrt(3.0)));  // corner
    REQUIRE(d.distance({0.5f, -1.0f, -1.0f}) == Approx(std::sqrt(2.0)));  // edge
    REQUIRE(d.distance({0.5f, 0.5f, 0.25f}) == Approx(0.25));  // inside, nearest face z = 0
    // Against brute force (the minimum over every single triangle) on a coarse sphere mesh.
    const Mesh s = sphere_mesh(1.0f, 0.25f);
    REQUIRE(s.faces.size() > 100);
    std::vector<std::unique_ptr<MeshDistance>> single;
    for (const Triangle& t : s.faces) {
        Mesh one;
        one.vertices = s.vertices;
        one.faces = {t};
        single.push_back(std::make_unique<MeshDistance>(one));
    }
    const MeshDistance ds(s);
    for (const Vec3f& p : sample_surface(cube(3.0), 200, 9)) {
        double best = 1e9;
        for (const auto& f : single) best = std::min(best, f->distance(p));
        REQUIRE(ds.distance(p) == Approx(best).margin(1e-12));
    }
}

TEST_CASE("sampling is area-uniform and deterministic", "[eval]") {
    const Mesh c = cube();
    std::vector<std::int32_t> faces;
    const std::vector<Vec3f> a = sample_surface(c, 60000, 42, &faces);
    const std::vector<Vec3f> b = sample_surface(c, 60000, 42);
    REQUIRE(a == b);
    REQUIRE(sample_surface(c, 100, 43) != sample_surface(c, 100, 42));
    // Equal-area faces: each gets 1/12 of the samples (binomial sd ~ 68).
    std::vector<int> count(12, 0);
    for (std::int32_t f : faces) ++count[std::size_t(f)];
    for (int n : count) REQUIRE(std::abs(n - 5000) < 400);
    for (const Vec3f& p : a) {
        for (float v : p) REQUIRE((v >= -1e-6f && v <= 1.0f + 1e-6f));
    }
}

TEST_CASE("metrics: identical meshes score perfectly, offset meshes by the offset", "[eval]") {
    const Mesh s = sphere_mesh(1.0f, 0.02f);
    EvalOptions o;
    o.samples = 100000;
    o.taus = {0.01, 0.05};
    EvalResult r = evaluate(s, s, o);
    REQUIRE(r.accuracy < 1e-6);
    REQUIRE(r.completeness < 1e-6);
    REQUIRE(r.fscores[0].fscore == Approx(1.0));
    REQUIRE(r.normal_consistency == Approx(1.0).margin(1e-6));
    REQUIRE(r.recon.watertight());

    const Mesh big = sphere_mesh(1.03f, 0.02f);
    r = evaluate(big, s, o);
    REQUIRE(r.accuracy == Approx(0.03).margin(0.002));
    REQUIRE(r.completeness == Approx(0.03).margin(0.002));
    REQUIRE(r.chamfer_l1 == Approx(0.03).margin(0.002));
    REQUIRE(r.fscores[0].fscore < 0.01);  // tau 0.01 < offset 0.03
    REQUIRE(r.fscores[1].fscore == Approx(1.0));

    // A shifted copy in another frame is the same mesh in world space.
    Mesh moved = s;
    moved.origin = {100.0, 0.0, 0.0};
    for (Vec3f& v : moved.vertices.edit()) v[0] -= 100.0f;
    REQUIRE(evaluate(moved, s, o).accuracy < 1e-4);

    // Half the sphere: precision stays 1, recall halves.
    Mesh half = s;
    half.faces.clear();
    for (const Triangle& t : s.faces) {
        if (s.vertices[t[0]][2] > 0 && s.vertices[t[1]][2] > 0 && s.vertices[t[2]][2] > 0) {
            half.faces.push_back(t);
        }
    }
    r = evaluate(half, s, o);
    REQUIRE(r.fscores[0].precision == Approx(1.0));
    REQUIRE(r.fscores[0].recall == Approx(0.5).margin(0.02));
}

TEST_CASE("eval JSON has every field", "[eval]") {
    const Mesh c = cube();
    EvalOptions o;
    o.samples = 2000;
    const std::string j = to_json(evaluate(c, c, o));
    for (const char* key : {"accuracy", "completeness", "chamfer_l1", "hausdorff",
                            "normal_consistency", "precision", "recall", "fscore", "tau",
                            "components", "boundary_edges", "nonmanifold_edges", "watertight"}) {
        REQUIRE_THAT(j, Catch::Contains(std::string("\"") + key + "\""));
    }
    // Default tau: 0.2 % of the reference diagonal.
    REQUIRE(evaluate(c, c, o).fscores[0].tau == Approx(0.002 * std::sqrt(3.0)));
}

TEST_CASE("a coverage mask restricts completeness and recall to the covered reference", "[eval]") {
    // Reference: the whole sphere. Reconstruction: the faces above z = 0 (a subset of the
    // reference's faces, so the covered part scores exactly 0). Mask: points above z = 0.05,
    // as a scan that only saw the top would give.
    const Mesh s = sphere_mesh(1.0f, 0.02f);
    const Mesh top = upper_half(s);
    std::vector<Vec3f> upper, lower;
    for (const Vec3f& p : sample_sphere(100000, 1.0).positions) {
        if (p[2] > 0.05f) upper.push_back(p);
        if (p[2] < -0.05f) lower.push_back(p);
    }
    EvalOptions o;
    o.samples = 100000;
    o.taus = {0.01};

    const EvalResult all = evaluate(top, s, o);
    REQUIRE(all.reference_samples == o.samples);
    REQUIRE(all.completeness > 0.15);  // the bottom half is missing
    REQUIRE(all.fscores[0].recall == Approx(0.5).margin(0.02));

    o.mask_points = upper;
    o.mask_distance = 0.02;
    const EvalResult masked = evaluate(top, s, o);
    // Kept: the reference above z = 0.05 - 0.02, i.e. (1 - 0.03) / 2 of the sphere's area.
    REQUIRE(double(masked.reference_samples) / double(o.samples) == Approx(0.485).margin(0.01));
    REQUIRE(masked.completeness < 1e-6);
    REQUIRE(masked.fscores[0].recall == Approx(1.0));
    // Each kept sample keeps its own face: normals agree exactly on the shared faces.
    REQUIRE(masked.normal_consistency == Approx(1.0).margin(1e-6));
    REQUIRE(all.normal_consistency < 0.99);
    // The reconstruction side is not masked.
    REQUIRE(masked.accuracy == all.accuracy);
    REQUIRE(masked.fscores[0].precision == all.fscores[0].precision);
    REQUIRE(masked.hausdorff < all.hausdorff);

    // The same mask in another local frame (a read scan's origin) keeps the same samples.
    EvalOptions shifted = o;
    shifted.mask_origin = {100.0, 0.0, -50.0};
    for (Vec3f& p : shifted.mask_points) {
        p[0] -= 100.0f;
        p[2] += 50.0f;
    }
    const EvalResult moved = evaluate(top, s, shifted);
    REQUIRE(std::abs(double(moved.reference_samples) - double(masked.reference_samples)) < 50);
    REQUIRE(moved.completeness < 1e-6);

    // A mask on the uncovered half keeps only what the reconstruction misses.
    o.mask_points = lower;
    const EvalResult bottom = evaluate(top, s, o);
    REQUIRE(bottom.completeness > all.completeness);
    REQUIRE(bottom.fscores[0].recall < 0.01);
    REQUIRE_THAT(to_json(bottom), Catch::Contains("\"reference_samples\": " +
                                                  std::to_string(bottom.reference_samples)));
}

TEST_CASE("a coverage mask needs a radius and must overlap the reference", "[eval]") {
    const Mesh c = cube();
    EvalOptions o;
    o.samples = 2000;
    o.mask_points = {{0.5f, 0.5f, 0.0f}};
    // No mask_distance, or a negative one: refused by validate(), naming the field.
    REQUIRE_THROWS_AS(evaluate(c, c, o), InvalidArgument);
    REQUIRE_THROWS_WITH(evaluate(c, c, o), Catch::StartsWith("eval.mask_distance"));
    o.mask_distance = -1.0;
    REQUIRE_THROWS_WITH(evaluate(c, c, o), Catch::StartsWith("eval.mask_distance"));
    o.mask_distance = 0.1;
    REQUIRE(evaluate(c, c, o).reference_samples > 0);
    o.mask_points = {{5.0f, 5.0f, 5.0f}};  // nowhere near the cube
    REQUIRE_THROWS_AS(evaluate(c, c, o), InvalidArgument);
    REQUIRE_THROWS_WITH(evaluate(c, c, o), Catch::Contains("no reference sample"));
}

TEST_CASE("ignore_reference_holes leaves out what covers a hole of the reference", "[eval]") {
    // Reference: the upper half of a sphere (open along the equator). Reconstruction: the whole
    // sphere, whose lower half covers the reference's hole.
    const Mesh s = sphere_mesh(1.0f, 0.02f);
    const Mesh top = upper_half(s);
    EvalOptions o;
    o.samples = 100000;
    o.taus = {0.01};
    const EvalResult all = evaluate(s, top, o);
    REQUIRE(all.recon_samples == o.samples);
    REQUIRE(all.fscores[0].precision == Approx(0.5).margin(0.02));
    o.ignore_reference_holes = true;
    const EvalResult kept = evaluate(s, top, o);
    // The lower half (and the sliver below the reference's jagged rim) is left out; the rest
    // is the reference's own faces.
    REQUIRE(double(kept.recon_samples) / double(o.samples) == Approx(0.5).margin(0.02));
    REQUIRE(kept.fscores[0].precision == Approx(1.0));
    REQUIRE(kept.accuracy < 1e-6);
    REQUIRE(kept.fscores[0].recall == all.fscores[0].recall);  // the reference side is unchanged
    REQUIRE_THAT(to_json(kept), Catch::Contains("\"recon_samples\": " +
                                                std::to_string(kept.recon_samples)));
    // A closed reference has no hole: nothing is left out.
    REQUIRE(evaluate(s, s, o).recon_samples == o.samples);
}
