#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <random>

#include "detail/union_find.h"
#include "support.h"
#include "support_volume.h"
#include "vdbrecon/clean.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/mesh.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

Mesh sphere_mesh(double radius, double voxel, const openvdb::Vec3f& centre = {0, 0, 0}) {
    return extract_mesh(sphere_volume(float(radius), centre, float(voxel))).mesh;
}

/// Appends `b` to `a` (indices shifted).
void append(Mesh& a, const Mesh& b) {
    const std::int32_t base = std::int32_t(a.vertices.size());
    std::vector<Vec3f>& vertices = a.vertices.edit();
    std::vector<Vec3f>& normals = a.normals.edit();
    vertices.insert(vertices.end(), b.vertices.begin(), b.vertices.end());
    normals.insert(normals.end(), b.normals.begin(), b.normals.end());
    for (Triangle t : b.faces) a.faces.push_back({t[0] + base, t[1] + base, t[2] + base});
}

/// A tetrahedron (4 faces) at `c`.
Mesh tetra(float x, float y, float z) {
    Mesh m;
    m.vertices = {{x, y, z}, {x + 0.01f, y, z}, {x, y + 0.01f, z}, {x, y, z + 0.01f}};
    m.normals.assign(4, {0.0f, 0.0f, 1.0f});
    m.faces = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
    return m;
}

double radial_spread(const Mesh& m, double r, double* mean_error = nullptr) {
    double worst = 0.0, sum = 0.0;
    for (const Vec3f& v : m.vertices) {
        const double e = std::sqrt(double(v[0]) * v[0] + double(v[1]) * v[1] + double(v[2]) * v[2]) - r;
        worst = std::max(worst, std::fabs(e));
        sum += e;
    }
    if (mean_error) *mean_error = sum / double(m.vertices.size());
    return worst;
}

}  // namespace

TEST_CASE("clean: pieces too few samples built are removed, exactly those", "[clean]") {
    Mesh big = sphere_mesh(1.0, 0.05);
    Mesh small = sphere_mesh(0.3, 0.05, {3.0f, 0.0f, 0.0f});  // a second real object, ~9 % size
    const std::size_t big_faces = big.faces.size(), small_faces = small.faces.size();
    Mesh m = big;
    append(m, tetra(5, 5, 5));
    append(m, small);
    append(m, tetra(-5, 0, 0));
    append(m, tetra(0, -5, 0));
    // The spacing of a sample a voxel apart: a tetrahedron of 1 cm sides is 0.1 sample's
    // worth, the small sphere 450, the big one 5000.
    CleanOptions by_samples;
    by_samples.sample_spacing = 0.05;
    const CleanResult r = clean_mesh(m, by_samples);
    REQUIRE(r.components_before == 5);
    REQUIRE(r.removed_components == 3);
    REQUIRE(r.removed_unsupported == 3);
    REQUIRE(r.removed_small == 0);
    REQUIRE(r.removed_faces == 12);
    REQUIRE(r.removed_vertices == 12);
    REQUIRE(r.mesh.faces.size() == big_faces + small_faces);
    REQUIRE(r.mesh.normals.size() == r.mesh.vertices.size());
    const TopologyStats t = mesh_topology(r.mesh);
    REQUIRE(t.components == 2);
    REQUIRE(t.boundary_edges == 0);
    // Order is kept: the big sphere comes first, unchanged.
    for (std::size_t f = 0; f < big_faces; ++f) REQUIRE(r.mesh.faces[f] == big.faces[f]);
    // Without a spacing the evidence is counted in the mesh's median edges: the same verdict.
    REQUIRE(clean_mesh(m).removed_components == 3);
    // For one object, a ratio drops the small sphere too (a piece smaller than half the big
    // one, however well supported); 0 samples and ratio 0 keep everything.
    CleanOptions strict = by_samples;
    strict.min_component_ratio = 0.5;
    const CleanResult one = clean_mesh(m, strict);
    REQUIRE(one.mesh.faces.size() == big_faces);
    REQUIRE(one.removed_small == 1);
    REQUIRE(one.removed_unsupported == 3);
    CleanOptions keep;
    keep.min_component_samples = 0.0;
    REQUIRE(clean_mesh(m, keep).mesh.faces.size() == m.faces.size());
    CleanOptions absolute = keep;
    absolute.min_component_faces = 5;
    REQUIRE(clean_mesh(m, absolute).removed_components == 3);
    // The pieces' faces interleaved (shuffled): the same verdicts, each piece whole.
    Mesh shuffled = m;
    std::vector<Triangle>& faces = shuffled.faces.edit();
    std::shuffle(faces.begin(), faces.end(), std::mt19937(7));
    const CleanResult s = clean_mesh(shuffled, by_samples);
    REQUIRE(s.components_before == 5);
    REQUIRE(s.removed_unsupported == 3);
    REQUIRE(s.removed_faces == 12);
    REQUIRE(s.mesh.faces.size() == big_faces + small_faces);
    REQUIRE(mesh_topology(s.mesh).components == 2);
    REQUIRE(clean_mesh(shuffled, strict).mesh.faces.size() == big_faces);
}

TEST_CASE("clean: the evidence weighs a piece's area by its support, in the data's own scale",
          "[clean]") {
    // Two spheres of 450 samples' worth each (r = 0.3, spacing 0.05): one fully supported, one
    // built by a kernel's tail only (a twentieth of the typical weight: 22 samples' worth) and
    // one at a hundredth (4.5: the disc a few stray samples leave). Only the last goes.
    const Mesh big = sphere_mesh(1.0, 0.05);
    const Mesh small = sphere_mesh(0.3, 0.05, {3.0f, 0.0f, 0.0f});
    const Mesh faint = sphere_mesh(0.3, 0.05, {-3.0f, 0.0f, 0.0f});
    const Mesh stray = sphere_mesh(0.3, 0.05, {0.0f, 3.0f, 0.0f});
    Mesh m = big;
    append(m, small);
    append(m, faint);
    append(m, stray);
    std::vector<float> support;
    for (std::size_t i = 0; i < big.vertices.size() + small.vertices.size(); ++i) {
        support.push_back(4.0f + 0.001f * float(i % 7));
    }
    support.insert(support.end(), faint.vertices.size(), 0.2f);
    support.insert(support.end(), stray.vertices.size(), 0.04f);
    CleanOptions o;
    o.sample_spacing = 0.05;
    const CleanResult r = clean_mesh(m, o, support);
    CHECK(r.typical_support == Approx(4.0).margin(0.01));
    REQUIRE(r.components_before == 4);
    REQUIRE(r.removed_unsupported == 1);
    REQUIRE(r.mesh.faces.size() == m.faces.size() - stray.faces.size());
    // More weight everywhere (a denser scan, more frames) changes nothing; neither does the
    // scale: the same scene 10x larger with a 10x coarser spacing.
    for (float& w : support) w *= 8.0f;
    REQUIRE(clean_mesh(m, o, support).removed_unsupported == 1);
    Mesh large = m;
    for (Vec3f& v : large.vertices.edit()) v = {v[0] * 10.0f, v[1] * 10.0f, v[2] * 10.0f};
    o.sample_spacing = 0.5;
    REQUIRE(clean_mesh(large, o, support).removed_unsupported == 1);
    // A support of the wrong length is refused, not misread.
    support.pop_back();
    REQUIRE_THROWS_AS(clean_mesh(m, o, support), InvalidArgument);
}

TEST_CASE("clean: two faces touching at a vertex only are separate components", "[clean]") {
    Mesh m;
    m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {-1, 0, 0}, {0, -1, 0}};
    m.faces = {{0, 1, 2}, {0, 3, 4}};
    REQUIRE(clean_mesh(m).components_before == 2);
    REQUIRE(mesh_topology(m).components == 2);
}

TEST_CASE("clean: the components of a 5.7M-face mesh, found a range of vertices at a time",
          "[clean]") {
    // A 1701 x 1701 grid of vertices (numbered row by row, so every band of columns has
    // vertices in every range) whose column of quads x = 99, 199, ... is left out: 17 bands of
    // 99 quads, each one piece. Its 17.2M corners are more than one pass of the component search
    // lists (2^24), so it takes two.
    const int w = 1701, h = 1701;
    Mesh m;
    std::vector<Vec3f>& v = m.vertices.edit();
    for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) v.push_back({float(x), float(y), 0.0f});
    }
    std::vector<Triangle>& f = m.faces.edit();
    for (int y = 0; y + 1 < h; ++y) {
        for (int x = 0; x + 1 < w; ++x) {
            if (x % 100 == 99) continue;
            const std::int32_t a = y * w + x, b = a + 1, c = a + w, d = c + 1;
            f.push_back({a, b, d});
            f.push_back({a, d, c});
        }
    }
    REQUIRE(3 * f.size() > (std::size_t(1) << 24));
    const CleanResult r = clean_mesh(std::move(m));
    CHECK(r.components_before == 17);
    CHECK(r.removed_components == 0);
    CHECK(r.mesh.faces.size() == 2 * 1683 * 1700);
}

TEST_CASE("clean: Taubin smoothing removes noise and keeps a sphere's size", "[clean]") {
    const double r = 1.0, voxel = 0.05;
    const Mesh clean = sphere_mesh(r, voxel);
    Mesh noisy = clean;
    std::mt19937 rng(5);
    std::normal_distribution<float> noise(0.0f, float(0.2 * voxel));
    for (Vec3f& v : noisy.vertices.edit()) {
        for (float& c : v) c += noise(rng);
    }
    CleanOptions o;
    o.smooth_iterations = 10;
    const CleanResult sc = clean_mesh(clean, o);
    REQUIRE(sc.smoothed_iterations == 10);
    double mean = 0.0;
    // Shrinkage of the clean sphere over 10 iterations: below 0.1 voxel on average and at worst.
    REQUIRE(radial_spread(sc.mesh, r, &mean) < 0.1 * voxel);
    REQUIRE(std::fabs(mean) < 0.1 * voxel);
    // Plain Laplacian smoothing (mu = lambda would not be allowed) shrinks; Taubin does not:
    // its volume stays within 0.5 %.
    REQUIRE(mesh_topology(sc.mesh).signed_volume ==
            Approx(mesh_topology(clean).signed_volume).epsilon(0.005));
    // Noise of 0.2 voxel is mostly removed.
    const double before = radial_spread(noisy, r);
    const CleanResult sn = clean_mesh(noisy, o);
    double rms_before = 0, rms_after = 0;
    for (std::size_t i = 0; i < noisy.vertices.size(); ++i) {
        auto rad = [&](const Vec3f& v) {
            return std::sqrt(double(v[0]) * v[0] + double(v[1]) * v[1] + double(v[2]) * v[2]) - r;
        };
        rms_before += std::pow(rad(noisy.vertices[i]), 2);
        rms_after += std::pow(rad(sn.mesh.vertices[i]), 2);
    }
    REQUIRE(before > 0.5 * voxel);
    REQUIRE(std::sqrt(rms_after) < 0.4 * std::sqrt(rms_before));
    // Normals are recomputed and point outwards.
    for (std::size_t i = 0; i < sn.mesh.vertices.size(); ++i) {
        const Vec3f& p = sn.mesh.vertices[i];
        const Vec3f& n = sn.mesh.normals[i];
        REQUIRE(p[0] * n[0] + p[1] * n[1] + p[2] * n[2] > 0.9);
    }
}

TEST_CASE("clean: smoothing keeps the border of an open patch in place", "[clean]") {
    Mesh m;
    const int n = 20;
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> bump(-0.02f, 0.02f);
    for (int i = 0; i <= n; ++i) {
        for (int j = 0; j <= n; ++j) m.vertices.push_back({float(i) / n, float(j) / n, bump(rng)});
    }
    for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
            const int a = i * (n + 1) + j, b = a + 1, c = a + n + 1, d = c + 1;
            m.faces.push_back({a, c, b});
            m.faces.push_back({b, c, d});
        }
    }
    CleanOptions o;
    o.smooth_iterations = 20;
    const Mesh s = clean_mesh(m, o).mesh;
    double interior_bump = 0.0;
    for (int i = 0; i <= n; ++i) {
        for (int j = 0; j <= n; ++j) {
            const std::size_t v = std::size_t(i * (n + 1) + j);
            if (i == 0 || j == 0 || i == n || j == n) {
                REQUIRE(s.vertices[v] == m.vertices[v]);
            } else {
                interior_bump = std::max(interior_bump, double(std::fabs(s.vertices[v][2])));
            }
        }
    }
    REQUIRE(interior_bump < 0.02);
}

TEST_CASE("clean: options are validated, bad faces rejected", "[clean]") {
    const Mesh m = tetra(0, 0, 0);
    CleanOptions o;
    o.min_component_ratio = 1.5;
    REQUIRE_THROWS_AS(clean_mesh(m, o), InvalidArgument);
    o = {};
    o.smooth_mu = -0.3;  // |mu| < lambda: shrinks
    REQUIRE_THROWS_AS(clean_mesh(m, o), InvalidArgument);
    o = {};
    o.smooth_iterations = -1;
    REQUIRE_THROWS_AS(clean_mesh(m, o), InvalidArgument);
    Mesh bad = m;
    bad.faces.push_back({0, 1, 7});
    REQUIRE_THROWS_AS(clean_mesh(bad), InvalidArgument);
    REQUIRE(clean_mesh(Mesh{}).mesh.faces.empty());
}

TEST_CASE("union-find: unions from several threads give the one-thread labels", "[clean]") {
    // 200k elements joined by 150k random pairs (many sets, long chains), in parallel in
    // pieces of 64 and one after another: the same sets, each labelled by its smallest index.
    const std::size_t n = 200000;
    std::mt19937 rng(7);
    std::uniform_int_distribution<std::int32_t> pick(0, std::int32_t(n) - 1);
    std::vector<std::pair<std::int32_t, std::int32_t>> pairs(150000);
    for (auto& p : pairs) p = {pick(rng), pick(rng)};
    detail::MinUnionFind serial(n);
    for (const auto& p : pairs) serial.unite(p.first, p.second);
    const std::vector<std::int32_t> expected = std::move(serial).labels();
    for (int round = 0; round < 3; ++round) {
        detail::ConcurrentMinUnionFind sets(n);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, pairs.size(), 64),
                          [&](const tbb::blocked_range<std::size_t>& r) {
                              for (std::size_t i = r.begin(); i < r.end(); ++i) {
                                  sets.unite(pairs[i].first, pairs[i].second);
                              }
                          });
        REQUIRE(sets.labels() == expected);
    }
    REQUIRE(std::count_if(expected.begin(), expected.end(), [&](std::int32_t l) {
                return l != expected[std::size_t(l)];
            }) == 0);  // labels are roots
    const std::size_t sets_count = std::size_t(
        std::count_if(expected.begin(), expected.end(),
                      [i = std::int32_t(0)](std::int32_t l) mutable { return l == i++; }));
    CHECK(sets_count > 1000);
    CHECK(sets_count < n / 2);
}
