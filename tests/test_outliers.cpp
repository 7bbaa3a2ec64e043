// Point outlier removal (outliers.h): a sphere with stray points, a cube whose corners must stay.
#include <random>

#include "support.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/knn.h"
#include "vdbrecon/normals.h"
#include "vdbrecon/outliers.h"
#include "vdbrecon/pipeline.h"

using namespace vdbrecon;
using namespace vdbrecon::test;

namespace {

/// Appends `count` points uniform in [-extent, extent]^3 with random unit normals.
std::size_t add_strays(PointCloud& c, std::size_t count, double extent, unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(float(-extent), float(extent));
    std::normal_distribution<float> g;
    for (std::size_t i = 0; i < count; ++i) {
        c.positions.push_back({u(rng), u(rng), u(rng)});
        Vec3f n{g(rng), g(rng), g(rng)};
        const float len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        for (float& v : n) v /= len;
        c.normals.push_back(n);
    }
    return count;
}

}  // namespace

TEST_CASE("outliers: strays around a sphere go, the sphere stays", "[outliers]") {
    const std::size_t surface = 30000;
    PointCloud c = sample_sphere(surface, 1.0);
    add_strays(c, surface / 50, 1.2, 3);  // 2 %
    OutlierOptions o;
    o.enabled = true;
    const OutlierResult r = remove_outliers(c, o);
    // Strays more than 2 voxels (at voxel 0.05) off the sphere must go; nearer ones are as
    // good as noisy surface samples and may stay.
    std::size_t far = 0, far_removed = 0, near_removed = 0, surface_removed = 0;
    for (std::size_t i = 0; i < c.size(); ++i) {
        const Vec3f& p = c.positions[i];
        const double off = std::fabs(std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) - 1.0);
        if (i < surface) {
            surface_removed += r.removed[i];
        } else if (off > 0.1) {
            ++far;
            far_removed += r.removed[i];
        } else {
            near_removed += r.removed[i];
        }
    }
    INFO("statistical " << r.statistical << ", planarity " << r.planarity << "; far strays removed "
                        << far_removed << " of " << far << ", near ones " << near_removed
                        << " of " << surface / 50 - far << ", surface points " << surface_removed);
    CHECK(r.statistical > 0);
    CHECK(r.planarity > 0);
    CHECK(far_removed >= far * 85 / 100);  // measured 430 of 482: the misses are strays whose
    // neighbours are strays in a nearly planar layout; alone they weigh too little to make a
    // surface (the pipeline test below)
    CHECK(surface_removed == 0);
    REQUIRE(r.cloud.size() == c.size() - r.statistical - r.planarity);
    REQUIRE(r.cloud.normals.size() == r.cloud.size());
}

TEST_CASE("outliers: a densely sampled cube keeps its corners and edges", "[outliers]") {
    PointCloud c;
    const int n = 60;
    for (int face = 0; face < 6; ++face) {
        const int axis = face / 2;
        const float side = face % 2 ? 1.0f : -1.0f;
        for (int i = 0; i < n; ++i) {
            for (int j = 0; j < n; ++j) {
                Vec3f p{}, nrm{};
                p[axis] = side;
                p[(axis + 1) % 3] = -1.0f + 2.0f * float(i) / float(n - 1);
                p[(axis + 2) % 3] = -1.0f + 2.0f * float(j) / float(n - 1);
                nrm[axis] = side;
                c.positions.push_back(p);
                c.normals.push_back(nrm);
            }
        }
    }
    OutlierOptions o;
    o.enabled = true;
    const OutlierResult r = remove_outliers(c, o);
    CHECK(r.statistical == 0);
    CHECK(r.planarity == 0);
}

TEST_CASE("outliers: the reconstruction with strays matches the clean one", "[outliers][pipeline]") {
    const double voxel = 0.05;
    PointCloud clean = sample_sphere(30000, 1.0);
    PointCloud noisy = clean;
    add_strays(noisy, 600, 1.2, 11);
    PipelineOptions o;
    o.splat.voxel_size = voxel;
    o.outliers.enabled = false;  // (on by default)
    const PipelineResult ref = reconstruct(clean, o);

    PointCloud without = noisy;
    const PipelineResult plain = reconstruct(without, o);
    o.outliers.enabled = true;
    const PipelineResult filtered = reconstruct(noisy, o);

    const TopologyStats t = mesh_topology(filtered.mesh);
    CHECK(t.watertight());
    CHECK(t.components == 1);
    EvalOptions e;
    e.samples = 200000;
    const double with_removal = evaluate(filtered.mesh, ref.mesh, e).hausdorff;
    const double no_removal = evaluate(plain.mesh, ref.mesh, e).hausdorff;
    INFO("Hausdorff to the clean result: " << with_removal / voxel << " voxels with --outliers, "
         << no_removal / voxel << " voxels without ("
         << mesh_topology(plain.mesh).components << " components)");
    CHECK(with_removal < 0.25 * voxel);
    CHECK(no_removal > with_removal);
}

TEST_CASE("outlier options are validated", "[outliers]") {
    OutlierOptions o;
    o.k = 2;
    REQUIRE_THROWS_AS(o.validate(), InvalidArgument);
    o = {};
    o.statistical_ratio = 0.5;
    REQUIRE_THROWS_AS(o.validate(), InvalidArgument);
    o = {};
    o.planarity_ratio = 1.0;
    REQUIRE_THROWS_AS(o.validate(), InvalidArgument);
}

TEST_CASE("outliers: the in-place removal keeps the same points as the copying one", "[outliers]") {
    PointCloud c = sample_sphere(6000, 1.0);
    add_strays(c, 300, 1.2, 5);
    for (std::size_t i = 0; i < c.size(); ++i) {
        c.colors.push_back({float(i % 7) / 7.0f, float(i % 11) / 11.0f, float(i % 13) / 13.0f});
        c.scales.push_back(0.01f + 0.001f * float(i % 5));
    }
    OutlierOptions o;
    o.enabled = true;
    const OutlierResult copied = remove_outliers(c, o, OutlierHandOver{true, 0});
    REQUIRE(copied.statistical + copied.planarity > 0);
    // The kept lists are the full search's.
    REQUIRE(copied.neighbours.indices == KnnIndex(c.positions).self_neighbours(o.k).indices);
    const auto same = [&](const OutlierResult& r) {
        CHECK(r.removed == copied.removed);
        CHECK(r.neighbours.indices == copied.neighbours.indices);
        CHECK(r.cloud.positions.to_vector() == copied.cloud.positions.to_vector());
        CHECK(r.cloud.normals.to_vector() == copied.cloud.normals.to_vector());
        CHECK(r.cloud.colors.to_vector() == copied.cloud.colors.to_vector());
        CHECK(r.cloud.scales.to_vector() == copied.cloud.scales.to_vector());
    };
    SECTION("owned arrays are compacted in place") {
        PointCloud owned = c;
        const Vec3f* storage = owned.positions.data();
        const OutlierResult r = remove_outliers(std::move(owned), o, OutlierHandOver{true, 0});
        same(r);
        CHECK(r.cloud.positions.data() == storage);  // no copy was made
    }
    SECTION("without kept lists (searched a batch at a time) the same points go") {
        const OutlierResult r = remove_outliers(c, o);
        CHECK(r.neighbours.indices.empty());
        CHECK(r.statistical == copied.statistical);
        CHECK(r.planarity == copied.planarity);
        CHECK(r.removed == copied.removed);
        CHECK(r.cloud.positions.to_vector() == copied.cloud.positions.to_vector());
    }
    SECTION("columns parked in a temporary file during the search come back the same") {
        OutlierOptions parking = o;
        parking.park_bytes = 0;  // always
        same(remove_outliers(c, parking, OutlierHandOver{true, 0}));
        PointCloud mixed = c;  // a borrowed column stays where it is
        mixed.scales = Column<float>::borrow(c.scales.data(), c.size());
        same(remove_outliers(std::move(mixed), parking, OutlierHandOver{true, 0}));
    }
    SECTION("without a temporary directory the columns stay in memory") {
        OutlierOptions parking = o;
        parking.park_bytes = 0;
        const ScopedEnv tmpdir("TMPDIR", "/nonexistent-vdbrecon-dir");
        same(remove_outliers(c, parking, OutlierHandOver{true, 0}));
    }
    SECTION("borrowed arrays are copied, never written") {
        PointCloud borrowed;
        borrowed.positions = Column<Vec3f>::borrow(c.positions.data(), c.size());
        borrowed.normals = Column<Vec3f>::borrow(c.normals.data(), c.size());
        borrowed.colors = Column<Vec3f>::borrow(c.colors.data(), c.size());
        borrowed.scales = Column<float>::borrow(c.scales.data(), c.size());
        const std::vector<Vec3f> before = c.positions.to_vector();
        const OutlierResult r = remove_outliers(std::move(borrowed), o, OutlierHandOver{true, 0});
        same(r);
        CHECK(c.positions.to_vector() == before);
        CHECK_FALSE(r.cloud.positions.borrowed());
    }
}

TEST_CASE("outliers: planarity candidates whose lists the search did not keep are searched again",
          "[outliers]") {
    // A dense sphere (200k points: the median d) and, far from it, a plane three times as
    // sparse (90k points, batches of their own) with a scattered blob on it. Every plane point is
    // a planarity candidate, but its batch keeps only the lists above its own median d, so most
    // candidates are searched again; the blob's must still go, as with the whole lists.
    PointCloud c = sample_sphere(200000, 1.0);
    const float h = 0.024f;  // the sphere's spacing is about 0.008
    for (int i = 0; i < 300; ++i) {
        for (int j = 0; j < 300; ++j) {
            c.positions.push_back({20.0f, float(i) * h, float(j) * h});
            c.normals.push_back({1.0f, 0.0f, 0.0f});
        }
    }
    const std::size_t blob = add_strays(c, 400, 0.15, 5);
    std::vector<Vec3f>& pos = c.positions.edit();
    for (std::size_t b = c.size() - blob; b < c.size(); ++b) {
        pos[b] = {pos[b][0] + 20.0f, pos[b][1] + 3.6f, pos[b][2] + 3.6f};
    }
    OutlierOptions o;
    const OutlierResult whole = remove_outliers(c, o, OutlierHandOver{true, 0});
    const OutlierResult batched = remove_outliers(c, o, OutlierHandOver{false, 10});
    REQUIRE(whole.planarity > 100);
    CHECK(batched.planarity == whole.planarity);
    CHECK(batched.statistical == whole.statistical);
    CHECK(batched.removed == whole.removed);
    std::size_t blob_gone = 0;
    for (std::size_t b = c.size() - blob; b < c.size(); ++b) blob_gone += batched.removed[b];
    CHECK(blob_gone > blob / 2);
}

TEST_CASE("outliers: batches of the neighbour search give the rules of the whole lists",
          "[outliers]") {
    // Large enough for several batches (rows whose neighbours come in later batches wait for
    // them), with strays for both rules and a patch of scattered points (planarity).
    PointCloud c = sample_sphere(200000, 1.0);
    add_strays(c, 2000, 1.3, 9);
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(-0.02f, 0.02f);
    for (int i = 0; i < 300; ++i) {
        c.positions.push_back({1.05f + u(rng), u(rng), u(rng)});
        c.normals.push_back({1.0f, 0.0f, 0.0f});
    }
    OutlierOptions o;
    const OutlierResult kept = remove_outliers(c, o, OutlierHandOver{true, 0});
    const OutlierResult batched = remove_outliers(c, o, OutlierHandOver{false, 10});
    REQUIRE(kept.statistical > 0);
    REQUIRE(kept.planarity > 0);
    CHECK(batched.statistical == kept.statistical);
    CHECK(batched.planarity == kept.planarity);
    CHECK(batched.removed == kept.removed);
    CHECK(batched.neighbours.indices.empty());

    // The rules straight from the whole lists (outliers.h): the statistical removals exactly,
    // and planarity removals only among the points spaced beyond planarity_spacing x median.
    const std::size_t n = c.size();
    const KnnResult all = KnnIndex(c.positions).self_neighbours(o.k);
    std::vector<double> d(n, 0.0);
    for (std::size_t i = 0; i < n; ++i) {
        for (int j = 0; j < o.k; ++j) d[i] += std::sqrt(double(all.sq_dists(i)[j]));
        d[i] /= o.k;
    }
    std::vector<double> sorted = d;
    std::nth_element(sorted.begin(), sorted.begin() + std::ptrdiff_t(n / 2), sorted.end());
    const double median = sorted[n / 2];
    std::size_t statistical = 0, wrong = 0;
    for (std::size_t i = 0; i < n; ++i) {
        double local = 0.0;
        for (int j = 0; j < o.k; ++j) local += d[std::size_t(all.neighbours(i)[j])];
        local /= o.k;
        const bool stat = local > 0.0 && d[i] / local > o.statistical_ratio;
        const bool candidate = !stat && local > 0.0 && d[i] > o.planarity_spacing * median;
        statistical += stat;
        wrong += stat ? !batched.removed[i] : (batched.removed[i] && !candidate);
    }
    CHECK(batched.statistical == statistical);
    CHECK(wrong == 0);

    // The spacing handed over is the normal stage's kNN scale of the kept points, bit for bit
    // (its own search there), also next to removed points and where a list kept too few.
    NormalOptions no;
    no.k = 10;
    no.scale = ScaleMode::knn;
    const NormalResult own = estimate_normals(batched.cloud, no);
    REQUIRE(batched.spacing.size() == batched.cloud.size());
    CHECK(batched.spacing == own.scales.to_vector());
    CHECK(estimate_normals(batched.cloud, no, batched.spacing).scales.to_vector() ==
          own.scales.to_vector());
    // The spacing over all k neighbours (spacing_k = k).
    no.k = o.k;
    const OutlierResult all_k = remove_outliers(c, o, OutlierHandOver{false, o.k});
    CHECK(all_k.spacing == estimate_normals(all_k.cloud, no).scales.to_vector());
    no.k = 10;
    // The statistical rule alone (no planarity candidates to point at the lists to redo).
    o.planarity_ratio = 0.0;
    const OutlierResult stat_only = remove_outliers(c, o, OutlierHandOver{false, 10});
    REQUIRE(stat_only.statistical > 0);
    CHECK(stat_only.spacing == estimate_normals(stat_only.cloud, no).scales.to_vector());
}
