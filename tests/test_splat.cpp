#include <tbb/global_control.h>

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <random>
#include <set>
#include <tuple>
#include <utility>

#include "detail/cell_groups.h"
#include "detail/exp8.h"
#include "detail/kernels.h"
#include "detail/splat_frame.h"
#include "grid_compare.h"
#include "shapes.h"
#include "support.h"
#include "vdbrecon/error.h"
#include "vdbrecon/splat.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

/// A noisy sphere with per-point scales and colours: exercises every accumulator.
PointCloud noisy_sphere(std::size_t n, double r, unsigned seed) {
    PointCloud c = sample_sphere(n, r);
    std::mt19937 rng(seed);
    std::normal_distribution<float> noise(0.0f, float(0.002 * r));
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (std::size_t i = 0; i < c.size(); ++i) {
        for (float& v : c.positions.edit()[i]) v += noise(rng);
        c.scales.push_back(float(r) * 0.02f * (0.8f + 0.4f * u(rng)));
        c.colors.push_back({u(rng), u(rng), u(rng)});
    }
    return c;
}

}  // namespace

TEST_CASE("splatting a plane gives its exact signed distance", "[splat]") {
    const PointCloud plane = sample_plane(101, 0.5);  // spacing 0.01 on z = 0, normal +z
    SplatOptions o;
    o.voxel_size = 0.01;
    const SplatResult r = splat(plane, o);
    const auto& sdf = *r.volume.sdf;
    REQUIRE(sdf.getGridClass() == openvdb::GRID_LEVEL_SET);
    REQUIRE(sdf.getName() == "sdf");
    REQUIRE(sdf.background() == Approx(3 * 0.01f));  // half width: 3 sigma of 1 voxel
    std::size_t checked = 0;
    for (auto it = sdf.cbeginValueOn(); it; ++it) {
        const openvdb::Vec3d x = sdf.indexToWorld(it.getCoord());
        // phi = n.(x - p) = z for every point: the average is z wherever it is defined.
        REQUIRE(*it == Approx(x.z()).margin(1e-6));
        REQUIRE(std::fabs(x.z()) <= 3 * 0.01 + 1e-9);  // nothing beyond the support
        ++checked;
    }
    REQUIRE(checked > 101 * 101 * 3);
    // Away from the borders every voxel within one sigma of the plane is valid.
    openvdb::FloatGrid::ConstAccessor acc = sdf.getConstAccessor();
    for (int i = -40; i <= 40; i += 5) {
        for (int k = -1; k <= 1; ++k) REQUIRE(acc.isValueOn(openvdb::Coord(i, -i / 2, k)));
    }
    // The weight grid has the same topology and counts the samples: about pi (sigma/h)^2.
    REQUIRE(r.volume.weight->tree().hasSameTopology(sdf.tree()));
    const float w0 = r.volume.weight->getConstAccessor().getValue(openvdb::Coord(0, 0, 0));
    REQUIRE(w0 == Approx(M_PI).epsilon(0.15));
}

TEST_CASE("a voxel is valid at min_weight, or at a fifth of it within two voxels of the surface",
          "[splat]") {
    // One sample at the origin, normal +z, sigma 2 voxels: a voxel's weight is exp(-d^2/4)
    // and its sdf its z (voxels). min_weight 0.4, a fifth of it 0.08.
    PointCloud one;
    one.positions.push_back({0.0f, 0.0f, 0.0f});
    one.normals.push_back({0.0f, 0.0f, 1.0f});
    SplatOptions o;
    o.voxel_size = 1.0;
    o.sigma_voxels = 2.0;
    o.min_weight = 0.4;
    o.crease_angle = 0.0;
    const SplatResult r = splat(one, o);
    const auto acc = r.volume.sdf->getConstAccessor();
    auto valid = [&](int x, int y, int z) { return acc.isValueOn(openvdb::Coord(x, y, z)); };
    CHECK(valid(1, 0, 0));   // w 0.78: full weight
    CHECK(valid(2, 0, 0));   // w 0.37, on the surface
    CHECK(valid(0, 0, 2));   // w 0.37, two voxels off
    CHECK(valid(3, 0, 0));   // w 0.105, on the surface
    CHECK(!valid(0, 0, 3));  // w 0.105, three voxels off
    CHECK(!valid(2, 0, 3));  // w 0.04: under a fifth
    CHECK(!valid(4, 0, 0));  // w 0.018
    REQUIRE(r.volume.weight->getConstAccessor().getValue(openvdb::Coord(3, 0, 0)) ==
            Approx(std::exp(-9.0 / 4.0)).epsilon(1e-5));
}

TEST_CASE("splatting a sphere: sign and magnitude near the surface", "[splat]") {
    const double radius = 0.5, voxel = 0.01;
    const PointCloud s = sample_sphere(40000, radius);  // spacing ~ 0.0044
    SplatOptions o;
    o.voxel_size = voxel;
    const SplatResult r = splat(s, o);
    const auto& sdf = *r.volume.sdf;
    std::size_t near = 0;
    for (auto it = sdf.cbeginValueOn(); it; ++it) {
        const double d = sdf.indexToWorld(it.getCoord()).length() - radius;
        if (std::fabs(d) > 0.5 * voxel) REQUIRE((*it > 0) == (d > 0));
        if (std::fabs(d) < 2 * voxel) {
            REQUIRE(*it == Approx(d).margin(0.1 * voxel));
            ++near;
        }
    }
    REQUIRE(near > 10000);
}

TEST_CASE("splatting is bit-identical for any thread count", "[splat]") {
    const PointCloud c = noisy_sphere(30000, 1.0, 3);
    SplatOptions o;
    o.voxel_size = 0.02;
    SplatResult one;
    {
        tbb::global_control g(tbb::global_control::max_allowed_parallelism, 1);
        one = splat(c, o);
    }
    const SplatResult many = splat(c, o);
    REQUIRE(one.updates == many.updates);
    REQUIRE(same_volumes(one.volume, many.volume));
}

TEST_CASE("splatting a slab of blocks at a time gives the same grids", "[splat]") {
    // Slabs far smaller than the pairs: many x-columns of blocks, sorted and summed one slab
    // after the other, and a slab limit below one column's pairs (one column per slab).
    const PointCloud c = noisy_sphere(40000, 1.0, 5);
    SplatOptions o;
    o.voxel_size = 0.01;
    const SplatResult whole = splat(c, o);
    for (std::size_t limit : {std::size_t(20000), std::size_t(1)}) {
        o.slab_pairs = limit;
        const SplatResult slabs = splat(c, o);
        REQUIRE(slabs.updates == whole.updates);
        REQUIRE(same_volumes(whole.volume, slabs.volume));
    }
}

TEST_CASE("the memory budget counts the leaves the kernels reach, in one slab or many", "[splat]") {
    // Under a budget the leaves are counted from the sums, above it by a pass over the pairs
    // first: both give the same count, so the run fits exactly when its leaves fit, whether it
    // is summed in one slab or in many (each slab checks the count so far).
    const PointCloud c = noisy_sphere(40000, 1.0, 5);
    SplatOptions o;
    o.voxel_size = 0.01;
    o.aggregate = 0.0;  // the kernels counted below are the samples'
    // Room for the points and their (block, point) pairs, not the leaves: the refusal names the
    // count of the one slab, which holds every leaf.
    o.max_memory = c.size() * 64 + (std::size_t(4) << 20);
    std::size_t leaves = 0;
    try {
        splat(c, o);
    } catch (const InvalidArgument& e) {
        const std::string m = e.what();
        const std::size_t end = m.find(" leaves of 8^3 voxels");
        REQUIRE(end != std::string::npos);
        leaves = std::stoul(m.substr(m.rfind('(', end) + 1));
    }
    // The count is that of the 8^3 leaves the kernels' support boxes meet, counted here from
    // each box's leaf range (the splat counts them block by block, from each leaf's half).
    std::set<std::tuple<int, int, int>> met;
    const detail::Kernels kernels(c, o);
    for (std::size_t i = 0; i < c.size(); ++i) {
        const detail::Kernel k = kernels(i, false);
        if (!(k.r > 0.0f)) continue;
        const double centre[3] = {k.cx, k.cy, k.cz};
        int lo[3], hi[3];
        bool empty = false;
        for (int a = 0; a < 3; ++a) {
            const int first = int(std::ceil(centre[a] - k.r)),
                      last = int(std::floor(centre[a] + k.r));
            empty = empty || last < first;
            lo[a] = int(std::floor(first / 8.0));
            hi[a] = int(std::floor(last / 8.0));
        }
        if (empty) continue;
        for (int x = lo[0]; x <= hi[0]; ++x) {
            for (int y = lo[1]; y <= hi[1]; ++y) {
                for (int z = lo[2]; z <= hi[2]; ++z) met.insert({x, y, z});
            }
        }
    }
    REQUIRE(leaves == met.size());
    const std::size_t need = c.size() * 64 + leaves * SplatOptions::kBytesPerLeaf;
    for (std::size_t limit : {std::size_t(0), std::size_t(1)}) {  // one slab; one per column
        o.slab_pairs = limit;
        o.max_memory = need;
        REQUIRE(splat(c, o).volume.sdf->activeVoxelCount() > 0);
        o.max_memory = need - 1;
        REQUIRE_THROWS_AS(splat(c, o), InvalidArgument);
    }
}

TEST_CASE("the vector rows give the scalar rows' grids bit for bit", "[splat]") {
    // The splat takes the AVX-512 or else the AVX2 rows where the CPU has them;
    // VDBRECON_NO_AVX512 forces AVX2, VDBRECON_SCALAR the scalar loop. Per-point scales make
    // every sum (w, u, u phi, nearest, colour) differ per point; with and without colours.
    for (const bool colored : {false, true}) {
        PointCloud c = noisy_sphere(30000, 1.0, 5);
        if (!colored) c.colors.clear();
        SplatOptions o;
        o.voxel_size = 0.013;
        ::setenv("VDBRECON_SCALAR", "1", 1);
        const SplatResult scalar = splat(c, o);
        ::unsetenv("VDBRECON_SCALAR");
        ::setenv("VDBRECON_NO_AVX512", "1", 1);
        const SplatResult avx2 = splat(c, o);
        ::unsetenv("VDBRECON_NO_AVX512");
        const SplatResult widest = splat(c, o);
        INFO("colours: " << colored);
        for (const SplatResult* vector : {&avx2, &widest}) {
            REQUIRE(scalar.updates == vector->updates);
            REQUIRE(scalar.active_voxels == vector->active_voxels);
            REQUIRE(same_grids(*scalar.volume.sdf, *vector->volume.sdf));
            REQUIRE(same_grids(*scalar.volume.weight, *vector->volume.weight));
            REQUIRE(same_grids(*scalar.volume.nearest, *vector->volume.nearest));
            REQUIRE(bool(scalar.volume.color) == colored);
            if (colored) REQUIRE(same_grids(*scalar.volume.color, *vector->volume.color));
        }
    }
}

TEST_CASE("exp8 is within 2 ulp of exp and gives the same bits on every path", "[splat]") {
    // The splat's Gaussians come from exp8 (detail/exp8.h): its scalar and AVX-512 paths must
    // agree bit for bit (the grids may not depend on the CPU) and stay close to exp().
    const auto ulps = [](double a, double b) {
        std::int64_t ia, ib;
        std::memcpy(&ia, &a, 8);
        std::memcpy(&ib, &b, 8);
        return std::abs(ia - ib);  // both positive: the distance of their bit patterns
    };
    std::vector<double> x = {0.0,
                             -0.0,
                             1e-300,
                             -1e-17,
                             0.5 * std::log(2.0),
                             -0.5 * std::log(2.0),
                             -std::log(2.0),
                             1.0,
                             -1.0,
                             -2.0,
                             -9.0,
                             -16.5,
                             700.0,
                             detail::kExp8Min,
                             -706.0,
                             -1e6};
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> wide(-700.0, 700.0), narrow(-20.0, 0.0);
    for (int i = 0; i < 20000; ++i) x.push_back(i % 2 ? wide(rng) : narrow(rng));
    while (x.size() % 8) x.push_back(-3.0);
    std::vector<int> paths = {0, 1};  // 1: the scalar loop too
    if (detail::wide_vector_loops()) paths.push_back(2);
    INFO("paths available: " << paths.size());
    std::int64_t worst = 0;
    for (std::size_t i = 0; i < x.size(); i += 8) {
        double y[3][8];
        for (int path : paths) detail::exp8(&x[i], y[path], path);
        for (int j = 0; j < 8; ++j) {
            const double want = std::exp(std::max(x[i + j], detail::kExp8Min));
            INFO("x = " << x[i + j]);
            REQUIRE(std::isfinite(y[0][j]));
            worst = std::max(worst, ulps(y[0][j], want));
            for (int path : paths) REQUIRE(std::memcmp(&y[path][j], &y[0][j], 8) == 0);
        }
    }
    REQUIRE(worst <= 2);
    // NaN (never an argument of the splat's) gives exp(kExp8Min) on every path alike.
    double nan[8], y[3][8];
    std::fill(nan, nan + 8, std::numeric_limits<double>::quiet_NaN());
    for (int path : paths) detail::exp8(nan, y[path], path);
    const double floor_value = detail::exp8_scalar_one(detail::kExp8Min);
    for (int path : paths) {
        for (int j = 0; j < 8; ++j) REQUIRE(std::memcmp(&y[path][j], &floor_value, 8) == 0);
    }
}

TEST_CASE("a scan too wide for 32-bit block keys gives the grids of its parts", "[splat]") {
    // Two spheres 30,000 voxels apart on every axis: their blocks span more than 2^32 packed
    // keys (16-byte pairs), each sphere alone fits 32 bits (8-byte pairs). Their supports do
    // not meet and sigma is uniform, so the union's grids are exactly the two parts' grids.
    const PointCloud a = sample_sphere(3000, 1.0);
    const PointCloud b = sample_sphere(3000, 1.0, {600.0, -600.0, 600.0});
    PointCloud both = a;
    both.positions.edit().insert(both.positions.edit().end(), b.positions.begin(), b.positions.end());
    both.normals.edit().insert(both.normals.edit().end(), b.normals.begin(), b.normals.end());
    SplatOptions o;
    o.voxel_size = 0.02;
    const SplatResult ra = splat(a, o), rb = splat(b, o), rab = splat(both, o);
    REQUIRE(rab.updates == ra.updates + rb.updates);
    REQUIRE(rab.leaves == ra.leaves + rb.leaves);
    auto same_leaves = [](const auto& whole, const auto& part) {
        for (auto it = part.tree().cbeginLeaf(); it; ++it) {
            const auto* w = whole.tree().probeConstLeaf(it->origin());
            if (!w || w->getValueMask() != it->getValueMask()) return false;
            if (std::memcmp(w->buffer().data(), it->buffer().data(),
                            sizeof(*it->buffer().data()) * it->SIZE) != 0) {
                return false;
            }
        }
        return true;
    };
    REQUIRE(same_leaves(*rab.volume.sdf, *ra.volume.sdf));
    REQUIRE(same_leaves(*rab.volume.sdf, *rb.volume.sdf));
    REQUIRE(same_leaves(*rab.volume.weight, *ra.volume.weight));
    REQUIRE(same_leaves(*rab.volume.weight, *rb.volume.weight));
    REQUIRE(same_leaves(*rab.volume.nearest, *rb.volume.nearest));
}

TEST_CASE("kernels too narrow to reach a voxel add nothing and break nothing", "[splat]") {
    // sigma 0.1 voxel, support 3: a point whose centre lies 0.3-0.7 voxel from the grid on any
    // axis reaches no voxel (an empty support box). Such points, the last one included, must
    // list no (block, point) pair: the grids equal those of the other points alone.
    PointCloud all, reaching;
    for (int i = 0; i < 4000; ++i) {
        const float x = 0.01f * float(i % 64), y = 0.01f * float(i / 64);
        const bool empty = i % 3 == 0 || i == 3999;
        const Vec3f p{x, y, empty ? 0.005f : 0.0f};  // 0.5 voxel off the grid in z, or on it
        all.positions.push_back(p);
        all.normals.push_back({0.0f, 0.0f, 1.0f});
        if (!empty) {
            reaching.positions.push_back(p);
            reaching.normals.push_back({0.0f, 0.0f, 1.0f});
        }
    }
    SplatOptions o;
    o.voxel_size = 0.01;
    o.sigma_voxels = 0.1;
    o.min_sigma_voxels = 0.1;
    const SplatResult a = splat(all, o), b = splat(reaching, o);
    REQUIRE(a.updates == b.updates);
    REQUIRE(same_grids(*a.volume.sdf, *b.volume.sdf));
    REQUIRE(same_grids(*a.volume.weight, *b.volume.weight));
    // None reaches a voxel: a clear error, not an empty volume.
    PointCloud none;
    for (std::size_t i = 0; i < all.size(); i += 3) {
        none.positions.push_back(all.positions[i]);
        none.normals.push_back(all.normals[i]);
    }
    REQUIRE_THROWS_WITH(splat(none, o), Catch::Contains("no voxel reached the minimum weight"));
}

TEST_CASE("colour is the weighted mean of the point colours", "[splat]") {
    PointCloud plane = sample_plane(41, 0.2);
    plane.colors.assign(plane.size(), Vec3f{0.25f, 0.5f, 1.0f});
    SplatOptions o;
    o.voxel_size = 0.01;
    const SplatResult r = splat(plane, o);
    REQUIRE(r.volume.color);
    for (auto it = r.volume.color->cbeginValueOn(); it; ++it) {
        REQUIRE((*it)[0] == Approx(0.25f).epsilon(1e-5));
        REQUIRE((*it)[2] == Approx(1.0f).epsilon(1e-5));
    }
}

TEST_CASE("the nearest-sample grid points at a real kernel centre", "[splat]") {
    // A sample's, or with presumming its group's (detail::presum).
    const PointCloud s = sample_sphere(8000, 1.0);
    SplatOptions o;
    o.voxel_size = 0.05;
    for (double aggregate : {0.0, 1.5}) {
        o.aggregate = aggregate;
        const PointCloud centres = detail::presum(s, o);
        CHECK((aggregate > 0.0 ? centres.size() < s.size() : centres.size() == s.size()));
        const SplatResult r = splat(s, o);
        const auto& g = *r.volume.nearest;
        std::size_t n = 0;
        for (auto it = g.cbeginValueOn(); it && n < 2000; ++it, ++n) {
            const openvdb::Vec3d p = g.indexToWorld(it.getCoord()) + openvdb::Vec3d(*it);
            double best = 1e9;
            for (const Vec3f& q : centres.positions) {
                best = std::min(best, (p - openvdb::Vec3d(q[0], q[1], q[2])).length());
            }
            REQUIRE(best < 1e-5);
        }
    }
}

TEST_CASE("splat rejects bad input clearly", "[splat]") {
    PointCloud s = sample_sphere(100, 1.0);
    SplatOptions o;
    REQUIRE_THROWS_AS(splat(s, o), InvalidArgument);  // voxel 0
    o.voxel_size = -1;
    REQUIRE_THROWS_AS(splat(s, o), InvalidArgument);
    o.voxel_size = std::nan("");
    REQUIRE_THROWS_AS(splat(s, o), InvalidArgument);
    o.voxel_size = 1e-9;  // 1e9 voxels across
    REQUIRE_THROWS_WITH(splat(s, o), Catch::Contains("too small for this scan"));
    o.voxel_size = 0.1;
    PointCloud bare = s;
    bare.normals.clear();
    REQUIRE_THROWS_WITH(splat(bare, o), Catch::Contains("no normals"));
    PointCloud zero = s;
    zero.normals.assign(zero.size(), Vec3f{0, 0, 0});
    REQUIRE_THROWS_WITH(splat(zero, o), Catch::Contains("usable"));
    // Half the normals zero: those points are skipped, not splatted as garbage.
    PointCloud half = s;
    for (std::size_t i = 0; i < half.size(); i += 2) half.normals.edit()[i] = {0, 0, 0};
    REQUIRE(splat(half, o).skipped_points == 50);
}

namespace {

/// n points uniformly at random on a sphere of radius r about the origin, exact normals.
PointCloud random_sphere(std::size_t n, double r, unsigned seed) {
    PointCloud c;
    std::mt19937 rng(seed);
    std::normal_distribution<double> g(0.0, 1.0);
    for (std::size_t i = 0; i < n; ++i) {
        double v[3] = {g(rng), g(rng), g(rng)};
        const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        c.positions.push_back({float(r * v[0] / len), float(r * v[1] / len), float(r * v[2] / len)});
        c.normals.push_back({float(v[0] / len), float(v[1] / len), float(v[2] / len)});
    }
    return c;
}

double total_confidence(const PointCloud& c) {
    double s = 0.0;
    for (float x : c.confidences) s += double(x);
    return s;
}

}  // namespace

TEST_CASE("presummed samples splat the same sphere with a fraction of the kernels", "[splat][aggregate]") {
    const double radius = 0.5;
    const PointCloud s = random_sphere(200000, radius, 11);  // spacing ~ 0.002
    for (double voxel : {0.01, 0.02}) {
        SplatOptions o;
        o.voxel_size = voxel;
        o.crease_angle = 0.0;
        o.aggregate = 0.0;  // splat() of the samples as they are, and of the groups
        const PointCloud g = aggregate_samples(s.view(), o, 1.5);
        INFO("voxel " << voxel << ": " << g.size() << " groups of " << s.size() << " samples");
        CHECK(g.size() * 10 < s.size());
        CHECK(total_confidence(g) == Approx(double(s.size())).epsilon(1e-6));
        const SplatResult raw = splat(s, o), sum = splat(g, o);
        CHECK(raw.points == s.size());
        CHECK(sum.points == g.size());
        CHECK(sum.updates * 10 < raw.updates);
        const auto& a = *raw.volume.sdf;
        auto b = sum.volume.sdf->getConstAccessor();
        double worst = 0.0, worst_raw = 0.0, diff = 0.0;
        std::size_t near = 0;
        for (auto it = a.cbeginValueOn(); it; ++it) {
            const double d = a.indexToWorld(it.getCoord()).length() - radius;
            if (std::fabs(d) > 1.5 * voxel || !b.isValueOn(it.getCoord())) continue;
            const double v = b.getValue(it.getCoord());
            worst = std::max(worst, std::fabs(v - d));
            worst_raw = std::max(worst_raw, std::fabs(*it - d));
            diff += std::fabs(v - *it);
            ++near;
        }
        INFO("worst |sdf - d|: " << worst / voxel << " voxel presummed, " << worst_raw / voxel
                                 << " raw; mean |presummed - raw| " << diff / near / voxel);
        CHECK(near > 5000);
        CHECK(worst < 0.05 * voxel);
        CHECK(diff / double(near) < 0.01 * voxel);
    }
}

TEST_CASE("presumming presummed parts sums what their samples would", "[splat][aggregate]") {
    SplatOptions o;
    o.voxel_size = 0.02;
    PointCloud all = random_sphere(60000, 0.5, 5);
    all.confidences.assign(all.size(), 1.0f);
    std::mt19937 rng(2);
    std::uniform_real_distribution<float> u(0.5f, 2.0f);
    for (float& c : all.confidences.edit()) c = u(rng);
    PointCloud first, second;  // every other sample
    for (std::size_t i = 0; i < all.size(); ++i) {
        PointCloud& part = i % 2 ? second : first;
        part.positions.push_back(all.positions[i]);
        part.normals.push_back(all.normals[i]);
        part.confidences.push_back(all.confidences[i]);
    }
    const PointCloud a = aggregate_samples(first.view(), o, 1.5), b = aggregate_samples(second.view(), o, 1.5);
    PointCloud parts = a;
    for (std::size_t i = 0; i < b.size(); ++i) {
        parts.positions.push_back(b.positions[i]);
        parts.normals.push_back(b.normals[i]);
        parts.scales.push_back(b.scales[i]);
        parts.confidences.push_back(b.confidences[i]);
    }
    const PointCloud direct = aggregate_samples(all.view(), o, 1.5);
    const PointCloud twice = aggregate_samples(parts.view(), o, 1.5);
    REQUIRE(twice.size() == direct.size());
    for (std::size_t i = 0; i < direct.size(); ++i) {
        for (int k = 0; k < 3; ++k) {
            REQUIRE(twice.positions[i][k] == Approx(direct.positions[i][k]).margin(1e-6));
            REQUIRE(twice.normals[i][k] == Approx(direct.normals[i][k]).margin(1e-5));
        }
        REQUIRE(twice.confidences[i] == Approx(direct.confidences[i]).epsilon(1e-5));
        REQUIRE(twice.scales[i] == Approx(direct.scales[i]).epsilon(1e-5));
    }
}

TEST_CASE("presumming keeps the two sides of a thin wall apart", "[splat][aggregate]") {
    SplatOptions o;
    o.voxel_size = 0.01;
    std::mt19937 rng(9);
    std::uniform_real_distribution<float> u(-0.2f, 0.2f);
    PointCloud wall;  // two faces 0.3 voxel apart, normals facing away from each other
    for (int i = 0; i < 40000; ++i) {
        const bool top = i % 2;
        wall.positions.push_back({u(rng), u(rng), top ? 0.003f : 0.0f});
        wall.normals.push_back({0.0f, 0.0f, top ? 1.0f : -1.0f});
    }
    const PointCloud g = aggregate_samples(wall.view(), o, 1.5);
    double up = 0.0, down = 0.0;
    for (std::size_t i = 0; i < g.size(); ++i) {
        REQUIRE(std::fabs(g.normals[i][2]) == Approx(1.0f).margin(1e-6));
        REQUIRE(g.positions[i][2] == (g.normals[i][2] > 0 ? 0.003f : 0.0f));
        (g.normals[i][2] > 0 ? up : down) += double(g.confidences[i]);
    }
    CHECK(up == Approx(20000.0));
    CHECK(down == Approx(20000.0));
    CHECK(g.size() < 20000);
}

TEST_CASE("presumming leaves out what the splat would skip, the same for any thread count", "[splat][aggregate]") {
    SplatOptions o;
    o.voxel_size = 0.02;
    PointCloud c = random_sphere(50000, 0.5, 3);
    c.confidences.assign(c.size(), 1.0f);
    c.colors.assign(c.size(), Vec3f{0.25f, 0.5f, 1.0f});
    c.positions.edit()[10][1] = std::nanf("");
    c.normals.edit()[20] = {0.0f, 0.0f, 0.0f};
    c.confidences.edit()[30] = 0.0f;
    c.normals.edit()[40][0] = INFINITY;
    PointCloud one;
    {
        tbb::global_control g(tbb::global_control::max_allowed_parallelism, 1);
        one = aggregate_samples(c.view(), o, 1.0);
    }
    const PointCloud many = aggregate_samples(c.view(), o, 1.0);
    CHECK(total_confidence(many) == Approx(double(c.size() - 4)).epsilon(1e-7));
    REQUIRE(one.size() == many.size());
    REQUIRE(std::equal(one.positions.begin(), one.positions.end(), many.positions.begin()));
    REQUIRE(std::equal(one.normals.begin(), one.normals.end(), many.normals.begin()));
    REQUIRE(std::equal(one.confidences.begin(), one.confidences.end(), many.confidences.begin()));
    for (const Vec3f& rgb : many.colors) REQUIRE(rgb[1] == Approx(0.5f));
    CHECK(aggregate_samples(c.view(), o, 0.0).size() == c.size());  // off: the cloud as it is
}

TEST_CASE("crease model: samples spread over more than 64 bits of cells index them as well",
          "[splat][crease]") {
    // The crease model sorts its samples by cell with a radix sort on the cells' packed offsets,
    // or with a comparison sort when they span more than 64 bits. Two samples 7.9M voxels from
    // the origin on every axis, on either side (splat() allows 8.4M; 2^22 cells a side: 66 bits)
    // take the second path; the cube's field must be the same as without them, crease voxels
    // included (one sigma for all, so no median moves).
    const Shape cube = make_shape("cube");
    const PointCloud near = sample_uniform(cube.mesh, 20000, 3);
    SplatOptions o;
    o.voxel_size = spacing_of(cube.area, 20000);
    PointCloud both = near;
    const float far = float(o.voxel_size * 7.9e6);
    both.positions.push_back({far, far, far});
    both.positions.push_back({-far, -far, -far});
    both.normals.push_back({0.0f, 0.0f, 1.0f});
    both.normals.push_back({0.0f, 0.0f, 1.0f});
    const SplatResult a = splat(near, o), b = splat(both, o);
    REQUIRE(a.crease_voxels > 0);
    REQUIRE(b.crease_voxels == a.crease_voxels);
    std::size_t compared = 0;
    auto bacc = b.volume.sdf->getConstAccessor();
    for (auto it = a.volume.sdf->cbeginValueOn(); it; ++it, ++compared) {
        float v = 0.0f;
        REQUIRE(bacc.probeValue(it.getCoord(), v));
        REQUIRE(v == *it);
    }
    REQUIRE(compared == a.active_voxels);
    REQUIRE(b.active_voxels > a.active_voxels);  // and the far samples' own voxels
}

namespace {

/// A sphere of random samples with what presumming reads: confidences, colours, scales over
/// several sigma levels, a third of the normals flipped (more than one group a cell) and a few
/// samples the splat skips.
PointCloud mixed_sphere(std::size_t n, unsigned seed) {
    PointCloud c = random_sphere(n, 0.5, seed);
    std::mt19937 rng(seed + 1);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<Vec3f>& normals = c.normals.edit();
    for (std::size_t i = 0; i < c.size(); ++i) {
        c.confidences.push_back(0.5f + u(rng));
        c.scales.push_back(0.01f * (0.8f + 4.0f * u(rng)));
        c.colors.push_back({u(rng), u(rng), u(rng)});
        if (i % 3 == 0) normals[i] = {-normals[i][0], -normals[i][1], -normals[i][2]};
    }
    normals[7] = {0.0f, 0.0f, 0.0f};
    c.confidences.edit()[9] = 0.0f;
    return c;
}

template <typename T>
bool same_bits(const Column<T>& a, const Column<T>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0;
}

}  // namespace

TEST_CASE(
    "presumming a cloud at once gives the open cell groups' samples bit for bit, at any thread "
    "count",
    "[splat][aggregate]") {
    SplatOptions o;
    o.voxel_size = 0.01;
    const PointCloud c = mixed_sphere(60000, 21);
    detail::CellGroups open(o, 1.5, true);
    REQUIRE(open.add(c));
    const PointCloud expected = open.take(c.origin);
    PointCloud one;
    {
        tbb::global_control g(tbb::global_control::max_allowed_parallelism, 1);
        one = aggregate_samples(c.view(), o, 1.5);
    }
    const PointCloud many = aggregate_samples(c.view(), o, 1.5);
    for (const PointCloud* x : {&std::as_const(one), &many}) {
        REQUIRE(x->size() == expected.size());
        CHECK(same_bits(x->positions, expected.positions));
        CHECK(same_bits(x->normals, expected.normals));
        CHECK(same_bits(x->colors, expected.colors));
        CHECK(same_bits(x->scales, expected.scales));
        CHECK(same_bits(x->confidences, expected.confidences));
    }
    CHECK(expected.size() * 2 < c.size());
}

TEST_CASE("presumming caps its cells and splats samples beyond the cells' range on their own",
          "[splat][aggregate]") {
    SplatOptions o;
    o.voxel_size = 0.01;
    PointCloud c = mixed_sphere(40000, 4);
    const PointCloud wide = aggregate_samples(c.view(), o, 1.5);
    const PointCloud capped = aggregate_samples(c.view(), o, 1.5, 1.0);
    CHECK(capped.size() > wide.size());  // the larger sigmas' cells are narrower
    // Samples 2^19 cells of a voxel or more from the origin: each a group of its own, after the
    // groups of the rest, which stay those of the cloud without them.
    const float far = float(o.voxel_size * 600000.0);
    for (int i = 0; i < 3; ++i) {
        c.positions.push_back({far + float(i), 0.0f, 0.0f});
        c.normals.push_back({0.0f, 0.0f, 2.0f});
        c.confidences.push_back(1.0f);
        c.scales.push_back(0.01f);
        c.colors.push_back({1.0f, 0.0f, 0.0f});
    }
    const PointCloud with = aggregate_samples(c.view(), o, 1.5, 1.0);
    REQUIRE(with.size() == capped.size() + 3);
    CHECK(std::memcmp(with.positions.data(), capped.positions.data(),
                      capped.size() * sizeof(Vec3f)) == 0);
    for (int i = 0; i < 3; ++i) {
        const std::size_t k = capped.size() + std::size_t(i);
        CHECK(with.positions[k][0] == far + float(i));
        CHECK(with.normals[k][2] == 2.0f);
        CHECK(with.confidences[k] == 1.0f);
    }
}

TEST_CASE(
    "splat() presumming: the sphere's field within a hundredth of a voxel of every sample's own "
    "kernel",
    "[splat][aggregate]") {
    const double radius = 0.5, voxel = 0.01;
    const PointCloud s = random_sphere(150000, radius, 8);  // spacing ~ 0.0023: 4 a voxel
    SplatOptions exact;
    exact.voxel_size = voxel;
    CHECK(exact.aggregate == 0.0);  // off by default
    SplatOptions o = exact;
    o.aggregate = 1.5;
    const SplatResult a = splat(s, o), b = splat(s, exact);
    CHECK(a.samples == s.size());
    CHECK(a.points * 3 < s.size());
    CHECK(b.points == s.size());
    CHECK(a.updates * 3 < b.updates);
    CHECK(a.sigma_median == b.sigma_median);  // the samples' frame
    auto acc = a.volume.sdf->getConstAccessor();
    double worst = 0.0, mean = 0.0;
    std::size_t near = 0;
    for (auto it = b.volume.sdf->cbeginValueOn(); it; ++it) {
        const double d = b.volume.sdf->indexToWorld(it.getCoord()).length() - radius;
        if (std::fabs(d) > 1.5 * voxel) continue;
        REQUIRE(acc.isValueOn(it.getCoord()));
        const double e = std::fabs(double(acc.getValue(it.getCoord())) - double(*it));
        worst = std::max(worst, e);
        mean += e;
        ++near;
    }
    INFO("presummed - exact: worst " << worst / voxel << ", mean " << mean / near / voxel
                                     << " voxel");
    CHECK(near > 20000);
    CHECK(worst < 0.05 * voxel);
    CHECK(mean / double(near) < 0.01 * voxel);
}

TEST_CASE("splat()'s presumming cells follow the samples' own spacing, not the clamped sigma",
          "[splat][aggregate]") {
    // A plane sampled at a quarter of a voxel, each sample's scale its spacing: the kernels'
    // sigma is clamped to a voxel, but the cells are 1.5 x a quarter voxel, so a group holds a
    // few samples (cells of the clamped sigma would hold ~36).
    const double voxel = 0.04, h = voxel / 4.0;
    PointCloud plane;
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    for (int i = 0; i < 64000; ++i) {
        plane.positions.push_back({u(rng), u(rng), 0.0f});
        plane.normals.push_back({0.0f, 0.0f, 1.0f});
        plane.scales.push_back(float(h));
    }
    SplatOptions o;
    o.voxel_size = voxel;
    o.aggregate = 1.5;
    const PointCloud groups = detail::presum(plane, o);
    const double per_group = double(plane.size()) / double(groups.size());
    INFO(per_group << " samples a group");
    CHECK(per_group > 1.5);
    CHECK(per_group < 5.0);
    const PointCloud clamped = aggregate_samples(plane.view(), o, 1.5, 1.25, 30.0, false);
    CHECK(double(plane.size()) / double(clamped.size()) > 20.0);
    CHECK(splat(plane, o).sigma_median == Approx(voxel));  // the kernels' sigma: clamped
}
