#include <tbb/task_arena.h>

#include <algorithm>
#include <iterator>
#include <random>
#include <tuple>

#include "detail/compact.h"
#include "detail/mesh_graph.h"
#include "detail/radix_sort.h"
#include "detail/union_find.h"
#include "support.h"
#include "support_volume.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/mesh.h"
#include "vdbrecon/splat.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

double radial_error(const Mesh& m, const Vec3d& c, double r) {
    double worst = 0;
    for (const Vec3f& v : m.vertices) {
        const double d = std::sqrt(std::pow(v[0] + m.origin[0] - c[0], 2) +
                                   std::pow(v[1] + m.origin[1] - c[1], 2) +
                                   std::pow(v[2] + m.origin[2] - c[2], 2));
        worst = std::max(worst, std::fabs(d - r));
    }
    return worst;
}

}  // namespace

TEST_CASE("level-set sphere: closed, genus 0, outward, right volume", "[mesh]") {
    const Volume v = sphere_volume(1.0f, {0.2f, -0.3f, 0.1f}, 0.05f);
    const auto method = GENERATE(Mesher::dual, Mesher::vdb);
    CAPTURE(int(method));
    MeshOptions o;
    o.method = method;
    const MeshResult r = extract_mesh(v, o);
    const TopologyStats t = mesh_topology(r.mesh);
    REQUIRE(t.faces > 1000);
    REQUIRE(t.boundary_edges == 0);
    REQUIRE(t.nonmanifold_edges == 0);
    REQUIRE(t.components == 1);
    REQUIRE(t.euler == 2);
    REQUIRE(t.signed_volume == Approx(4.0 / 3.0 * M_PI).epsilon(0.01));
    REQUIRE(radial_error(r.mesh, {0.2, -0.3, 0.1}, 1.0) < 0.1 * 0.05);
    REQUIRE(r.mesh.normals.size() == r.mesh.vertices.size());
    for (std::size_t i = 0; i < r.mesh.vertices.size(); ++i) {
        const Vec3f& p = r.mesh.vertices[i];
        const Vec3f& n = r.mesh.normals[i];
        const double d = (p[0] - 0.2) * n[0] + (p[1] + 0.3) * n[1] + (p[2] - 0.1) * n[2];
        REQUIRE(d > 0.99);  // unit radius: outward unit normal
    }
}

TEST_CASE("splatted sphere meshes closed with Euler characteristic 2", "[mesh]") {
    const double radius = 0.5, voxel = 0.01;
    PointCloud s = sample_sphere(40000, radius);
    s.scales.assign(s.size(), 0.009f);  // the sample spacing: sqrt(4 pi r^2 / n)
    SplatOptions o;
    o.voxel_size = voxel;
    const SplatResult sr = splat(s, o);
    const MeshResult r = extract_mesh(sr.volume);
    const TopologyStats t = mesh_topology(r.mesh);
    REQUIRE(t.boundary_edges == 0);
    REQUIRE(t.nonmanifold_edges == 0);
    REQUIRE(t.components == 1);
    REQUIRE(t.euler == 2);
    REQUIRE(t.signed_volume == Approx(4.0 / 3.0 * M_PI * std::pow(radius, 3)).epsilon(0.01));
    REQUIRE(radial_error(r.mesh, {0, 0, 0}, radius) < 0.2 * voxel);
    REQUIRE(r.trimmed_faces == 0);
}

TEST_CASE("an open patch stays open and nothing is meshed outside the data", "[mesh]") {
    const PointCloud plane = sample_plane(61, 0.3);  // [-0.3, 0.3]^2, spacing 0.01
    SplatOptions o;
    o.voxel_size = 0.01;
    const SplatResult sr = splat(plane, o);
    const MeshResult r = extract_mesh(sr.volume);
    const TopologyStats t = mesh_topology(r.mesh);
    REQUIRE(t.components == 1);
    REQUIRE(t.boundary_edges > 100);
    REQUIRE(t.nonmanifold_edges == 0);
    REQUIRE(t.euler == 1);  // a disc
    const double gap = MeshOptions{}.max_gap * o.voxel_size;
    for (const Vec3f& v : r.mesh.vertices) {
        REQUIRE(std::fabs(v[2]) < 1e-5);
        REQUIRE(std::fabs(v[0]) <= 0.3 + gap);
        REQUIRE(std::fabs(v[1]) <= 0.3 + gap);
    }
    // With a wider kernel support and a lower min_weight the valid band reaches ~3 sigma past
    // the data (1e-4 of the on-surface weight); without the
    // data-distance and weight trims the sheet grows with it: the trims bite, and cut the
    // sheet within a voxel of the last samples.
    o.support = 6.0;
    o.min_weight = 1e-4;
    const SplatResult wide_band = splat(plane, o);
    MeshOptions loose;
    loose.max_gap = std::numeric_limits<double>::infinity();
    loose.min_surface_weight = 0.0;
    const MeshResult trimmed = extract_mesh(wide_band.volume);
    const BBox tight = bounding_box(trimmed.mesh.vertices);
    const BBox wide = bounding_box(extract_mesh(wide_band.volume, loose).mesh.vertices);
    INFO("trimmed to " << tight.max[0] << ", untrimmed " << wide.max[0]);
    REQUIRE(trimmed.trimmed_faces > 0);
    REQUIRE(wide.max[0] > tight.max[0] + 1.5 * o.voxel_size);
    REQUIRE(tight.max[0] < 0.3 + 1.0 * o.voxel_size);
    REQUIRE(mesh_topology(trimmed.mesh).components == 1);
}

TEST_CASE("faces never cross invalid voxels", "[mesh]") {
    Volume v = sphere_volume(1.0f, {0, 0, 0}, 0.05f);
    // Deactivate the band in the x > 0.5 slab: that part of the sphere is "not observed".
    for (auto it = v.sdf->beginValueOn(); it; ++it) {
        if (v.sdf->indexToWorld(it.getCoord()).x() > 0.5) it.setValueOff();
    }
    // The dual mesher makes no face there; volumeToMesh does, and its faces are dropped.
    for (Mesher m : {Mesher::dual, Mesher::vdb}) {
        CAPTURE(int(m));
        MeshOptions o;
        o.method = m;
        const MeshResult r = extract_mesh(v, o);
        REQUIRE((r.dropped_faces > 0) == (m == Mesher::vdb));
        for (const Vec3f& p : r.mesh.vertices) REQUIRE(p[0] < 0.5);
        const TopologyStats t = mesh_topology(r.mesh);
        REQUIRE(t.boundary_edges > 0);
        REQUIRE(t.nonmanifold_edges == 0);
    }
}

TEST_CASE("meshing far from the origin keeps precision", "[mesh]") {
    // The same sphere in a grid whose index origin sits at 1e7: the mesh is stored relative
    // to the volume origin, so it matches the one at the origin exactly.
    Volume a = sphere_volume(1.0f, {0, 0, 0}, 0.05f);
    Volume b = sphere_volume(1.0f, {0, 0, 0}, 0.05f);
    b.sdf = b.sdf->deepCopy();
    b.sdf->transform().postTranslate(openvdb::Vec3d(1e7, -2e7, 5e6));
    b.origin = {1e7, -2e7, 5e6};
    const Mesh ma = extract_mesh(a).mesh, mb = extract_mesh(b).mesh;
    REQUIRE(ma.vertices == mb.vertices);
    REQUIRE(ma.faces == mb.faces);
    REQUIRE(mb.origin == b.origin);
}

TEST_CASE("mesh options are validated", "[mesh]") {
    const Volume v = sphere_volume(1.0f, {0, 0, 0}, 0.1f);
    MeshOptions o;
    o.adaptivity = 2.0;
    REQUIRE_THROWS_AS(extract_mesh(v, o), InvalidArgument);
    o = {};
    o.adaptivity = 0.5;  // only volumeToMesh adapts
    REQUIRE_THROWS_WITH(extract_mesh(v, o), Catch::Contains("--mesher vdb"));
    o.method = Mesher::vdb;
    REQUIRE(mesh_topology(extract_mesh(v, o).mesh).faces > 100);
    o = {};
    o.max_gap = 0.0;
    REQUIRE_THROWS_AS(extract_mesh(v, o), InvalidArgument);
    REQUIRE_THROWS_AS(extract_mesh(Volume{}), InvalidArgument);
}

TEST_CASE("mesh: face normal sums a block of vertices at a time, in face order, any thread count",
          "[mesh]") {
    // A wavy 300 x 300 grid (90k vertices, 178k faces) with its faces in the vertices' order,
    // as a mesher makes them, then shuffled (every run of faces then reaches every block). Each
    // vertex's sum must be its faces' normals added in face order (the reference below, bit for
    // bit) for any block and thread count. Jittered, so that the sums round and their order shows
    // in the bits.
    const int w = 300;
    Mesh m;
    std::vector<Vec3f>& v = m.vertices.edit();
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> jitter(-0.3f, 0.3f);
    for (int y = 0; y < w; ++y) {
        for (int x = 0; x < w; ++x) {
            v.push_back(
                {x + jitter(rng), y + jitter(rng), float(std::sin(0.37 * x) * std::cos(0.23 * y))});
        }
    }
    std::vector<Triangle> faces;
    for (int y = 0; y + 1 < w; ++y) {
        for (int x = 0; x + 1 < w; ++x) {
            const std::int32_t a = y * w + x, b = a + 1, c = a + w, d = c + 1;
            faces.push_back({a, b, d});
            faces.push_back({a, d, c});
        }
    }
    for (const bool shuffled : {false, true}) {
        CAPTURE(shuffled);
        if (shuffled) std::shuffle(faces.begin(), faces.end(), std::mt19937(7));
        m.faces = faces;
        std::vector<std::array<double, 3>> want(v.size(), {0.0, 0.0, 0.0});
        for (const Triangle& t : faces) {
            const Vec3f &a = v[std::size_t(t[0])], &b = v[std::size_t(t[1])],
                        &c = v[std::size_t(t[2])];
            const double u[3] = {double(b[0]) - a[0], double(b[1]) - a[1], double(b[2]) - a[2]};
            const double s[3] = {double(c[0]) - a[0], double(c[1]) - a[1], double(c[2]) - a[2]};
            const double n[3] = {u[1] * s[2] - u[2] * s[1], u[2] * s[0] - u[0] * s[2],
                                 u[0] * s[1] - u[1] * s[0]};
            for (std::int32_t i : t) {
                for (int k = 0; k < 3; ++k) want[std::size_t(i)][k] += n[k];
            }
        }
        for (const int threads : {1, 2}) {
            tbb::task_arena arena(threads);
            arena.execute([&] {
                const detail::FaceNormalSums sums(m);
                for (const auto& [first, last] : std::vector<std::pair<std::size_t, std::size_t>>{
                         {0, v.size()}, {0, 4000}, {12345, 60000}, {89999, 90000}}) {
                    const std::vector<std::array<double, 3>> got = sums(first, last);
                    REQUIRE(got.size() == last - first);
                    std::size_t differ = 0;
                    for (std::size_t i = first; i < last; ++i) differ += got[i - first] != want[i];
                    CHECK(differ == 0);
                }
                CHECK(detail::face_normal_sums(m) == want);
            });
        }
    }
}

TEST_CASE("mesh: sorted sides are every taken face's edges by (key, face, slot), any size",
          "[mesh]") {
    // Random faces over few and over many vertices (the radix sort packs the two ends in the
    // bits the largest index needs), many faces (listed by several chunks), every third face
    // not taken; against a list made on one thread and sorted by the whole tuple. Degenerate
    // edges (a face repeating a vertex) are listed too.
    for (const std::int32_t vertices : {7, 300, 300000}) {
        CAPTURE(vertices);
        std::mt19937 rng{std::uint32_t(vertices)};
        std::uniform_int_distribution<std::int32_t> pick(0, vertices - 1);
        std::vector<Triangle> faces(200000);
        for (Triangle& t : faces) t = {pick(rng), pick(rng), pick(rng)};
        const auto take = [](std::size_t f) { return f % 3 != 0; };
        std::vector<std::tuple<std::uint64_t, std::int32_t, std::int32_t>> want;
        for (std::size_t f = 0; f < faces.size(); ++f) {
            if (!take(f)) continue;
            for (int k = 0; k < 3; ++k) {
                want.emplace_back(
                    detail::edge_key(faces[f][std::size_t(k)], faces[f][std::size_t((k + 1) % 3)]),
                    std::int32_t(f), k);
            }
        }
        std::sort(want.begin(), want.end());
        for (int threads : {1, 2}) {
            tbb::task_arena arena(threads);
            const detail::EdgeSides got =
                arena.execute([&] { return detail::sorted_sides(faces, take); });
            REQUIRE(got.size() == want.size());
            std::size_t wrong = 0;
            for (std::size_t i = 0; i < got.size(); ++i) {
                wrong += std::make_tuple(got[i].key, got[i].face, got[i].slot) != want[i];
            }
            CHECK(wrong == 0);
        }
    }
}

TEST_CASE("mesh: face components join the faces that share an edge, any mesh", "[mesh]") {
    // Against one-thread unions of every two faces holding both ends of an edge: random faces
    // over 7 and 300 vertices (vertices of hundreds of faces, non-manifold edges), a grid of
    // quads with faces flipped, repeated and made degenerate, over many vertices.
    const auto reference = [](const std::vector<Triangle>& faces) {
        std::vector<std::tuple<std::uint64_t, std::int32_t>> uses;
        for (std::size_t f = 0; f < faces.size(); ++f) {
            const Triangle& t = faces[f];
            for (int k = 0; k < 3; ++k) {
                const std::int32_t a = t[std::size_t(k)], b = t[std::size_t((k + 1) % 3)];
                if (a != b) uses.emplace_back(detail::edge_key(a, b), std::int32_t(f));
            }
        }
        std::sort(uses.begin(), uses.end());
        detail::MinUnionFind sets(faces.size());
        for (std::size_t i = 1; i < uses.size(); ++i) {
            if (std::get<0>(uses[i]) == std::get<0>(uses[i - 1])) {
                sets.unite(std::get<1>(uses[i]), std::get<1>(uses[i - 1]));
            }
        }
        return std::move(sets).labels();
    };
    std::vector<std::pair<std::vector<Triangle>, std::int32_t>> meshes;
    for (const auto& [vertices, count] : {std::pair<int, int>{7, 500}, {300, 6000}}) {
        std::mt19937 rng{std::uint32_t(vertices)};
        std::uniform_int_distribution<std::int32_t> pick(0, vertices - 1);
        std::vector<Triangle> faces(static_cast<std::size_t>(count));
        for (Triangle& t : faces) t = {pick(rng), pick(rng), pick(rng)};
        meshes.emplace_back(std::move(faces), vertices);
    }
    {
        const std::int32_t n = 400;  // n x n vertices, two faces a quad
        std::mt19937 rng{5};
        std::vector<Triangle> faces;
        for (std::int32_t y = 0; y + 1 < n; ++y) {
            for (std::int32_t x = 0; x + 1 < n; ++x) {
                const std::int32_t v = y * n + x;
                if (rng() % 17 == 0) continue;  // holes: several components
                faces.push_back({v, v + 1, v + n + 1});
                faces.push_back(rng() % 5 == 0 ? Triangle{v, v + n, v + n + 1}  // flipped
                                               : Triangle{v, v + n + 1, v + n});
                if (rng() % 23 == 0) faces.push_back(faces.back());       // a repeated face
                if (rng() % 29 == 0) faces.push_back({v, v, v + n + 1});  // degenerate
                if (rng() % 31 == 0) faces.push_back({v, v, v});
            }
        }
        meshes.emplace_back(std::move(faces), n * n);
    }
    for (const auto& [faces, vertices] : meshes) {
        CAPTURE(faces.size(), vertices);
        const std::vector<std::int32_t> want = reference(faces);
        for (int threads : {1, 2}) {
            tbb::task_arena arena(threads);
            const std::vector<std::int32_t> got = arena.execute(
                [&] { return detail::face_components(faces, std::size_t(vertices)); });
            CHECK(got == want);
        }
    }
}

TEST_CASE("chunks: for_each_chunk covers 0..n once; compaction and radix sort keep the order",
          "[mesh]") {
    // Sizes around the chunk sizes' steps (4096 .. 65536, eight chunks below 8 x 65536).
    for (const std::size_t n :
         {std::size_t(0), std::size_t(1), std::size_t(4095), std::size_t(4097), std::size_t(32769),
          std::size_t(524287), std::size_t(524288), std::size_t(524289), std::size_t(1000003)}) {
        CAPTURE(n);
        const std::size_t size = detail::chunk_size(n), chunks = detail::chunk_count(n);
        CHECK(size >= 4096);
        CHECK(size <= detail::kChunk);
        CHECK(chunks * size >= n);
        std::vector<int> seen(n, 0);
        std::vector<char> chunk_seen(chunks, 0);
        detail::for_each_chunk(n, [&](std::size_t c, std::size_t begin, std::size_t end) {
            chunk_seen[c] = 1;
            CHECK(begin == c * size);
            for (std::size_t i = begin; i < end; ++i) ++seen[i];
        });
        CHECK(std::count(seen.begin(), seen.end(), 1) == std::ptrdiff_t(n));
        CHECK(std::count(chunk_seen.begin(), chunk_seen.end(), 1) == std::ptrdiff_t(chunks));
        // Compaction keeps the kept elements in order; a radix sort is stable.
        std::mt19937 rng{std::uint32_t(n)};
        std::vector<std::uint32_t> v(n);
        for (std::uint32_t& x : v) x = rng();
        std::vector<std::uint32_t> kept;
        std::copy_if(v.begin(), v.end(), std::back_inserter(kept),
                     [](std::uint32_t x) { return x % 5 != 0; });
        std::vector<std::uint32_t> compacted = v;
        detail::compact_in_place(compacted, [&](std::size_t i) { return v[i] % 5 != 0; });
        CHECK(compacted == kept);
        std::vector<std::pair<std::uint32_t, std::size_t>> pairs(n), want(n);
        for (std::size_t i = 0; i < n; ++i) pairs[i] = want[i] = {v[i] >> 20, i};
        std::stable_sort(want.begin(), want.end(),
                         [](const auto& a, const auto& b) { return a.first < b.first; });
        detail::radix_sort(pairs, 12, [](const auto& e) { return std::uint64_t(e.first); });
        CHECK(pairs == want);
    }
}
