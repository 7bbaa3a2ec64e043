// Streamed tile jobs (see detail/stream_tiles.h).
//
// Passes over the input, a chunk of rows at a time (detail::stream_points: the first finds the
// local frame and the box): the points per cell; the points into a scratch file grouped by cell
// (cubes holding about kCellPoints points of a surface), cells in key order, each cell's points
// in the cloud's order. Then passes over regions ("units": the cubes of an octree over the
// cells), each loaded with a halo of cells around it:
//   1. what the outlier rules and the kNN scale take from each point's list but the median d:
//      d_i, the k-th distance, the statistical verdict, the planarity test (where it may be
//      asked: d_i above planarity_spacing x 0.9 x a median d sampled over the cells; pass 1
//      runs again for every point should the median be lower), the mean distance to the first
//      ks neighbours and what may take one of those away (without the outlier rules: d_i over
//      the scale's k, the scale); then the median d, by selection;
//   2. the rules, and the scale of the kept points: the first ks neighbours' mean distance, or
//      a walk over a list searched again where one of those may go; then, where normals are
//      estimated (oriented each on its own: a viewpoint, an up direction), each kept point's
//      PCA normal from its kn nearest kept points and the wider look over its neighbours'
//      lists (normals.cpp's per point); then the density spacing and the voxel;
//   3. the kernel sizes of the kept samples; then the kernel frame and the tile grid;
//   4. the kept samples into the tile job's buckets.
//
// Exactness. A point's k nearest among the loaded points are its k nearest in the cloud when
// the k-th is closer than the nearest face of the loaded box beyond which there are points (a
// point outside is at least that far): its list is certified. Each result reads only certified
// lists: d_i its own; a verdict its own list and the d_j of its neighbours; the planarity test
// its own list; a walk its own lists and the spilled rules of the points it passes; a normal
// its own list of kept points, and where it looks wider its neighbours' lists. A unit that
// needs a list not certified is loaded again with a wider halo. The loaded points keep the
// cloud's order (sorted by row), so ties between equal distances break by index as in the
// whole cloud, every sum is taken in the same order, and the results are those of the stages on
// the whole cloud (outliers.cpp, normals.cpp, kernel_frame), bit for bit.
#include "detail/stream_tiles.h"

#include <sys/stat.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <deque>
#include <functional>
#include <limits>
#include <map>
#include <numeric>
#include <unordered_map>

#include "detail/cell_store.h"
#include "detail/io_common.h"
#include "detail/normal_rules.h"
#include "detail/outlier_rules.h"
#include "detail/radix_sort.h"
#include "detail/select.h"
#include "detail/splat_frame.h"
#include "detail/spool.h"
#include "detail/tiles.h"
#include "vdbrecon/error.h"
#include "vdbrecon/knn.h"
#include "vdbrecon/log.h"

namespace vdbrecon::detail {
namespace {

using streamed::CellStore;
using streamed::Key;
using streamed::Layout;
using streamed::Loaded;

/// Points a cell holds on average, were the cloud a surface spread evenly over its box.
constexpr double kCellPoints = 1024.0;

/// Thrown inside, and caught by prepare_streamed(), when the file turns out not to be
/// streamable.
struct NotStreamable {
    std::string why;
};

/// A unit: the cells whose points it decides.
struct Unit {
    std::vector<std::size_t> cells;  ///< sorted
    Key lo, hi;                      ///< their box
};

/// The faces of a loaded box beyond which there are points (infinitely far where none are):
/// a point's k nearest among the loaded points are certified when the k-th is nearer than
/// margin().
struct Reach {
    double lo[3], hi[3];
    const CellStore* store = nullptr;
    const Loaded* loaded = nullptr;
    double margin(const Vec3f& p) const {
        double m = HUGE_VAL;
        for (int a = 0; a < 3; ++a) m = std::min({m, double(p[a]) - lo[a], hi[a] - double(p[a])});
        return m;
    }
    /// Within the loaded box, or else every occupied cell the k-th neighbour's ball meets is
    /// loaded (the ball of a point beyond the box, loaded on its own).
    bool certified(const Vec3f& p, float kth_sq) const {
        const double r = std::sqrt(double(kth_sq));
        // float positions and distances: a margin of their rounding
        const double size = std::max({std::fabs(p[0]), std::fabs(p[1]), std::fabs(p[2])});
        const double reach = r + 1e-6 * (r + double(size)) + 1e-30;
        if (reach < margin(p)) return true;
        if (loaded->cells.size() == store->keys().size()) return true;  // all of them
        Key a, b;
        for (std::size_t x = 0; x < 3; ++x) {
            a[x] = int(std::floor((double(p[x]) - reach) / store->edge()));
            b[x] = int(std::floor((double(p[x]) + reach) / store->edge()));
        }
        bool all = true;
        store->cells_in(a, b, [&](std::size_t j) {
            all = all && std::binary_search(loaded->cells.begin(), loaded->cells.end(), j);
        });
        return all;
    }
};

/// How a unit is loaded: a halo of `ring` cells around its box, and the boxes of the balls of
/// single points whose k-th neighbour lies further (a far stray needs the points around it,
/// not a ring that wide around the whole unit).
struct Halo {
    int ring = 1;
    std::vector<std::array<Key, 2>> balls;
};

class StreamJob {
  public:
    StreamJob(const std::string& input, const std::string& dir, const PipelineOptions& options)
        : input_(input), dir_(dir), options_(options) {
        outliers_ = options.outliers.enabled;
        k_ = outliers_ ? options.outliers.k : options.normals.k;
        local_ = options.normals.orients_locally();
    }

    void run(TileJob& job);

  private:
    void read();
    void make_units();
    Loaded load(const Unit& u, const Halo& h) const;
    Loaded load(const Unit& u, int ring) const;
    void widen(Halo& next, const Unit& u, const Vec3f& p, float kth_sq) const;
    Reach reach_of(const Loaded& l) const;
    std::array<Key, 2> ball_of(const Vec3f& p, float kth_sq) const;
    int ring_for(const Unit& u, const std::array<Key, 2>& ball) const;
    void spacing_pass(const Unit& u);
    struct Lists;
    void search(Lists& st, const std::vector<std::size_t>& rows) const;
    std::vector<std::size_t> halo_of(const Lists& st, const std::vector<std::size_t>& rows,
                                     int width, std::vector<std::size_t>& fails) const;
    bool widen_for(Halo& h, const Unit& u, const Loaded& l, const std::vector<float>& kth,
                   const std::vector<std::size_t>& fails) const;
    void verdict_pass(const Unit& u);
    double sampled_median_d() const;
    void verdicts();
    char rule_of(char verdict, char scattered_nb, float d) const;
    int walk(const Loaded& l, const KnnIndex& index, const Reach& reach, std::size_t i,
             const std::vector<char>& rule, const Unit& u, std::vector<int>& kept_nb,
             float& spacing) const;
    void walk_again(const Unit& u, const std::vector<std::uint32_t>& rows,
                    std::vector<float>& spacing) const;
    void rules_pass(const Unit& u);
    static void pca_normals(const Lists& st, const std::vector<std::size_t>& need,
                            std::vector<Vec3f>& normal, std::vector<char>& ok,
                            std::vector<char>& wider);
    bool kept_normals(const Loaded& l, const std::vector<std::size_t>& need,
                      std::vector<Vec3f>& normal, std::vector<char>& ok, std::vector<float>& kth,
                      std::vector<std::size_t>& fails) const;
    void normals_pass(const Unit& u);
    void finish_normals(PipelineResult& r) const;
    bool keeps(const Loaded& l, std::size_t i) const {
        return options_.normals.scale == ScaleMode::automatic && l.cloud.has_scales() &&
               l.cloud.scales[i] > 0.0f;
    }
    PointCloud samples(const Unit& u, std::vector<std::uint32_t>& rows) const;
    KernelFrame frame(const SplatOptions& splat);
    void buckets(const TileGrid& g, const TileAnchors& anchors, TilePlan& plan);
    double sample_spacing();
    double file_scale_median() const;

    const std::string& input_;
    const std::string& dir_;
    const PipelineOptions& options_;
    ReadResult totals_;
    std::unique_ptr<CellStore> store_;
    std::uint64_t n_ = 0;
    std::vector<Unit> units_;
    bool outliers_ = false, need_scale_ = false;
    bool local_ = false;         ///< normals oriented each on its own (a viewpoint, up)
    bool estimate_ = false;      ///< normals to estimate (all, or the file's zero ones)
    bool estimate_all_ = false;  ///< every point's (--normals estimate, or none in the file)
    int k_ = 0;   ///< neighbours of pass 1: the outlier rules', else the kNN scale's
    int ks_ = 0;  ///< with the outlier rules, the kNN scale's (0: no scale to find)
    int kn_ = 0;  ///< neighbours of the normals' PCA (on the kept points)
    CellStore::Side<float> d_{"tiles: d of the points"}, kth_{"tiles: k-th distances"};
    CellStore::Side<float> scale_{"tiles: scales"};
    CellStore::Side<char> removed_{"tiles: outlier flags"};
    CellStore::Side<char> verdict_{"tiles: verdicts"}, scattered_{"tiles: planarity tests"};
    CellStore::Side<char> touched_{"tiles: neighbours failing"};
    CellStore::Side<float> first_{"tiles: first scales"}, most_{"tiles: neighbours' d"};
    CellStore::Side<Vec3f> normal_{"tiles: normals"};
    std::uint64_t estimated_ = 0, flipped_ = 0, degenerate_ = 0;
    double median_d_ = 0.0, median_scale_ = 0.0;
    double scattered_from_ = 0.0;  ///< pass 1 runs the planarity test on d_i above this
    std::uint64_t statistical_ = 0, planarity_ = 0, kept_ = 0;
    std::uint64_t largest_ = 0;  ///< points of the largest unit loaded, with its halo
    Vec3f lowest_{HUGE_VALF, HUGE_VALF, HUGE_VALF}, highest_{-HUGE_VALF, -HUGE_VALF, -HUGE_VALF};
};

/// What a pass knows of one loading of a unit (or of its kept points): per point whose list of
/// k was searched, the list and whether it is certified, d_i, the k-th distance and the mean
/// distance to its first ks neighbours (ks = 0: none).
struct StreamJob::Lists {
    Lists(const Loaded& loaded, const Reach& r, const KnnIndex& i, int k_, int ks_)
        : l(loaded), reach(r), index(i), k(k_), ks(ks_), list_of(loaded.size(), nullptr),
          certified(loaded.size(), 0), d(loaded.size(), 0.0f),
          kth(loaded.size(), 0.0f), first(loaded.size(), 0.0f) {}
    const Loaded& l;
    Reach reach;
    const KnnIndex& index;
    int k, ks;
    std::vector<const int*> list_of;  ///< nullptr: not searched
    std::vector<char> certified;
    std::vector<float> d, kth, first;
    std::deque<KnnResult> lists;
};

void StreamJob::read() {
    bool any_zero_scale = false;
    std::uint32_t row = 0;
    StreamFrame frame;
    const auto sink = [&](ReadResult& chunk, std::size_t, int pass) {
        const PointCloud& c = chunk.cloud;
        if (pass == 0) {
            if (c.size() > 0 && !c.has_normals() && !local_) {
                throw NotStreamable{"its points have no normals (to estimate; --up or "
                                    "--viewpoint would orient them locally)"};
            }
            if (chunk.invalid_normals > 0 && !local_) {
                throw NotStreamable{"a normal is zero (to estimate; --up or --viewpoint would "
                                    "orient it locally)"};
            }
            if (c.size() > 0 && options_.normals.mode == NormalMode::keep && !c.has_normals()) {
                throw NotStreamable{"--normals keep, and no normals"};  // (the error in memory)
            }
            if (frame.rows >= std::size_t(UINT32_MAX)) {
                throw InvalidArgument("tiles: more than 2^32 points");
            }
            if (frame.rows < std::size_t(k_) + 1) throw NotStreamable{"too few points"};
            if (!store_ && c.size() > 0) {
                const double edge =
                    frame.diagonal * std::sqrt(std::min(1.0, kCellPoints / double(frame.rows)));
                store_ = std::make_unique<CellStore>(
                    Layout{c.has_normals(), c.has_colors(), c.has_scales(), c.has_confidences()},
                    edge > 0.0 ? edge : 1.0);
            }
            if (c.size() == 0) return;
            for (std::size_t i = 0; i < c.size(); ++i) {
                for (int a = 0; a < 3; ++a) {
                    lowest_[a] = std::min(lowest_[a], c.positions[i][a]);
                    highest_[a] = std::max(highest_[a], c.positions[i][a]);
                }
                any_zero_scale = any_zero_scale || (c.has_scales() && !(c.scales[i] > 0.0f));
            }
            store_->count(c);
            return;
        }
        if (row == 0) store_->place();
        store_->write(c, row);
        row += std::uint32_t(c.size());
    };
    if (!stream_points(input_, options_.read, sink, totals_, 2, &frame, !local_)) {
        throw NotStreamable{local_ ? "not a PLY, LAS or text point file"
                                   : "not a PLY file whose points have normals (to estimate "
                                     "them, their orientation spans the whole cloud; --up or "
                                     "--viewpoint would orient them locally)"};
    }
    n_ = store_->points();
    estimate_all_ = options_.normals.mode == NormalMode::estimate || !store_->has_normals();
    estimate_ = estimate_all_ || totals_.invalid_normals > 0;
    const bool scales = totals_.rows > 0 && store_->has_scales();
    need_scale_ = options_.normals.scale == ScaleMode::knn ||
                  (options_.normals.scale == ScaleMode::automatic && (!scales || any_zero_scale));
    if (!outliers_) k_ = std::min<int>(options_.normals.k, int(n_) - 1);
    ks_ = outliers_ && need_scale_ ? options_.normals.k : 0;
}

/// Units: the cubes of an octree over the cells, split while a cube holds more than a budget's
/// worth of points (about 1 KB a point through the neighbour searches) or an eighth of the cloud
/// (so that every cloud goes through units and their halos). Dense regions get small cubes;
/// sparse ones (strays in empty space) few large ones.
void StreamJob::make_units() {
    const std::uint64_t target = std::clamp<std::uint64_t>(
        std::min<std::uint64_t>(memory_budget(options_.splat) / 1024, n_ / 8),
        std::uint64_t(1) << 12, std::uint64_t(1) << 22);
    int side = 1;
    for (std::size_t a = 0; a < 3; ++a) {
        while (side <= store_->highest()[a] - store_->lowest()[a]) side *= 2;
    }
    const std::function<void(const Key&, int)> split = [&](const Key& lo, int n) {
        const Key hi{lo[0] + n - 1, lo[1] + n - 1, lo[2] + n - 1};
        Unit u;
        std::uint64_t points = 0;
        store_->cells_in(lo, hi, [&](std::size_t j) {
            u.cells.push_back(j);
            points += store_->cell_size(j);
        });
        if (u.cells.empty()) return;
        if (points <= target || n == 1) {
            std::sort(u.cells.begin(), u.cells.end());
            u.lo = lo;
            u.hi = hi;
            units_.push_back(std::move(u));
            return;
        }
        const int h = n / 2;
        for (int c = 0; c < 8; ++c) {
            split({lo[0] + (c & 1) * h, lo[1] + (c >> 1 & 1) * h, lo[2] + (c >> 2 & 1) * h}, h);
        }
    };
    split(store_->lowest(), side);
}

Loaded StreamJob::load(const Unit& u, const Halo& h) const {
    Key lo = u.lo, hi = u.hi;
    for (std::size_t a = 0; a < 3; ++a) {
        // no cells beyond the occupied ones: the box stops there
        lo[a] = std::max(lo[a] - h.ring, store_->lowest()[a]);
        hi[a] = std::min(hi[a] + h.ring, store_->highest()[a]);
    }
    std::vector<std::array<Key, 2>> boxes{{lo, hi}};
    boxes.insert(boxes.end(), h.balls.begin(), h.balls.end());
    Loaded l = store_->load(boxes, u.cells);
    l.cloud.origin = totals_.cloud.origin;
    return l;
}

Loaded StreamJob::load(const Unit& u, int ring) const {
    Halo h;
    h.ring = ring;
    return load(u, h);
}

/// Widens a unit's halo for a point whose list is not certified: a ring of up to two cells
/// more, else the ball of its k-th neighbour.
void StreamJob::widen(Halo& next, const Unit& u, const Vec3f& p, float kth_sq) const {
    const std::array<Key, 2> ball = ball_of(p, kth_sq);
    const int ring = ring_for(u, ball);
    if (ring <= 2) {
        next.ring = std::max(next.ring, ring);
    } else {
        next.balls.push_back(ball);
    }
}

/// Widens the halo for the points `fails` of a loading; false when there are none.
bool StreamJob::widen_for(Halo& h, const Unit& u, const Loaded& l, const std::vector<float>& kth,
                          const std::vector<std::size_t>& fails) const {
    if (fails.empty()) return false;
    Halo next = h;
    for (std::size_t i : fails) widen(next, u, l.cloud.positions[i], kth[i]);
    if (next.ring == h.ring && next.balls.size() == h.balls.size()) ++next.ring;  // (progress)
    h = std::move(next);
    return true;
}

Reach StreamJob::reach_of(const Loaded& l) const {
    Reach r;
    r.store = store_.get();
    r.loaded = &l;
    const double e = store_->edge();
    for (std::size_t a = 0; a < 3; ++a) {
        r.lo[a] = l.lo[a] <= store_->lowest()[a] ? -HUGE_VAL : double(l.lo[a]) * e;
        r.hi[a] = l.hi[a] >= store_->highest()[a] ? HUGE_VAL : double(l.hi[a] + 1) * e;
    }
    return r;
}

/// The box of the cells the ball of this point's k-th neighbour meets (1 % wider).
std::array<Key, 2> StreamJob::ball_of(const Vec3f& p, float kth_sq) const {
    const double r = 1.01 * std::sqrt(double(kth_sq)) + 1e-6 * store_->edge();
    std::array<Key, 2> ball;
    for (std::size_t a = 0; a < 3; ++a) {
        ball[0][a] = int(std::floor((double(p[a]) - r) / store_->edge()));
        ball[1][a] = int(std::floor((double(p[a]) + r) / store_->edge()));
    }
    return ball;
}

/// The halo (cells) whose box around the unit holds a ball, with a cell spare.
int StreamJob::ring_for(const Unit& u, const std::array<Key, 2>& ball) const {
    int ring = 0;
    for (std::size_t a = 0; a < 3; ++a) {
        ring = std::max({ring, u.lo[a] - ball[0][a], ball[1][a] - u.hi[a]});
    }
    return ring + 1;
}

/// A loading's core points in the store's order, cell after cell: near ones searched together.
std::vector<std::size_t> core_rows(const Loaded& l) {
    std::vector<std::size_t> rows(l.size());
    for (std::size_t i = 0; i < l.size(); ++i) rows[l.order[i]] = i;
    rows.erase(std::remove_if(rows.begin(), rows.end(), [&](std::size_t i) { return !l.core[i]; }),
               rows.end());
    return rows;
}

/// Pass 1 without the outlier rules: the kNN scale of the unit's points (their mean distance to
/// their k nearest, unless the file's scale stays) and the k-th neighbour's squared distance.
void StreamJob::spacing_pass(const Unit& u) {
    for (Halo h;;) {
        const Loaded l = load(u, h);
        if (l.size() <= std::size_t(k_)) {
            h.ring *= 2;
            continue;
        }
        const KnnIndex index(l.cloud.positions, options_.normals.knn);
        Lists st(l, reach_of(l), index, k_, ks_);
        const std::vector<std::size_t> core = core_rows(l);
        search(st, core);
        std::vector<std::size_t> fails;
        for (std::size_t i : core) {
            if (!st.certified[i]) fails.push_back(i);
        }
        if (widen_for(h, u, l, st.kth, fails)) continue;
        largest_ = std::max<std::uint64_t>(largest_, l.size());
        kth_.write(l, st.kth);
        for (std::size_t i = 0; i < l.size(); ++i) {
            if (keeps(l, i)) st.d[i] = l.cloud.scales[i];
        }
        scale_.write(l, st.d);
        return;
    }
}

/// Searches the lists of `rows` of a loading: each point's list, d_i, k-th distance and the
/// mean distance to its first ks (the kNN scale when those are kept), when its list is
/// certified.
void StreamJob::search(Lists& st, const std::vector<std::size_t>& rows) const {
    if (rows.empty()) return;
    const Span<Vec3f> pts = st.l.cloud.positions;
    const int k = st.k, ks = st.ks;
    st.lists.push_back(st.index.self_neighbours_of(rows, k));
    const KnnResult& got = st.lists.back();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, rows.size(), 1024),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t a = rg.begin(); a < rg.end(); ++a) {
            const std::size_t i = rows[a];
            const int* nb = st.list_of[i] = got.neighbours(a);
            st.kth[i] = KnnResult::squared_distance(pts[i], pts[std::size_t(nb[k - 1])]);
            if (!st.reach.certified(pts[i], st.kth[i])) continue;
            st.certified[i] = 1;
            st.d[i] = mean_distance(pts, i, nb, k, ks, ks > 0 ? &st.first[i] : nullptr);
        }
    });
}

/// The points of the halo among the first `width` entries of the lists of `rows`, not yet
/// searched (sorted); the rows whose own lists are not certified go to `fails`.
std::vector<std::size_t> StreamJob::halo_of(const Lists& st, const std::vector<std::size_t>& rows,
                                            int width, std::vector<std::size_t>& fails) const {
    std::vector<std::size_t> out;
    for (std::size_t i : rows) {
        if (!st.certified[i]) {
            fails.push_back(i);
            continue;
        }
        for (int j = 0; j < width; ++j) {
            const std::size_t q = std::size_t(st.list_of[i][j]);
            if (!st.list_of[q]) out.push_back(q);
        }
    }
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
    return out;
}

/// Pass 1 with the outlier rules: what the rules and the kNN scale take from each point's list,
/// all but what waits for the median d: d_i, its k-th distance, its statistical verdict,
/// whether its neighbourhood is scattered (the planarity test), the mean distance to its first
/// ks neighbours, and what may take one of those away (one fails the statistical rule; the
/// largest d_j of those passing it with a scattered neighbourhood). The verdicts need the d_j of
/// the neighbours, and those of the first ks neighbours their neighbours' d: the lists of the
/// halo points within two steps are searched too.
void StreamJob::verdict_pass(const Unit& u) {
    const OutlierOptions& o = options_.outliers;
    const int ks = ks_;
    for (Halo h;;) {
        const Loaded l = load(u, h);
        const std::size_t m = l.size();
        if (m <= std::size_t(k_)) {
            h.ring *= 2;
            continue;
        }
        const KnnIndex index(l.cloud.positions, o.knn);
        Lists st(l, reach_of(l), index, k_, ks_);
        const std::vector<std::size_t> core = core_rows(l);
        std::vector<std::size_t> fails;  // points whose lists are to be certified
        search(st, core);
        search(st, halo_of(st, core, k_, fails));  // the d_j of their neighbours
        // The points whose verdicts are needed: the unit's, and the halo's among their first ks
        // neighbours; then the d_j of those neighbours' neighbours.
        std::vector<std::size_t> judged = core;
        for (std::size_t i : core) {
            for (int j = 0; j < ks && st.certified[i]; ++j) {
                const std::size_t q = std::size_t(st.list_of[i][j]);
                if (!l.core[q]) judged.push_back(q);
            }
        }
        std::sort(judged.begin() + std::ptrdiff_t(core.size()), judged.end());
        judged.erase(std::unique(judged.begin() + std::ptrdiff_t(core.size()), judged.end()),
                     judged.end());
        search(st, halo_of(st, judged, k_, fails));
        std::vector<char> verdict(m, kUnknown), scattered_nb(m, 0);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, judged.size(), 1024),
                          [&](const tbb::blocked_range<std::size_t>& rg) {
            for (std::size_t a = rg.begin(); a < rg.end(); ++a) {
                const std::size_t i = judged[a];
                const int* nb = st.list_of[i];
                if (!nb || !st.certified[i]) continue;
                double sum = 0.0;
                bool known = true;
                for (int j = 0; j < k_ && known; ++j) {
                    const std::size_t q = std::size_t(nb[j]);
                    known = st.certified[q] != 0;
                    sum += double(st.d[q]);
                }
                if (!known) continue;
                verdict[i] = statistical_verdict(st.d[i], sum, k_, o);
                // The planarity test only where it may be asked (d_i above scattered_from_).
                scattered_nb[i] = verdict[i] == kPasses && o.planarity_ratio > 0.0 &&
                                  double(st.d[i]) > scattered_from_ &&
                                  scattered(l.cloud.positions, i, nb, k_, o);
            }
        });
        for (std::size_t i : judged) {
            if (verdict[i] != kUnknown || !st.certified[i]) continue;  // (the latter in fails)
            for (int j = 0; j < k_; ++j) {
                const std::size_t q = std::size_t(st.list_of[i][j]);
                if (!st.certified[q]) fails.push_back(q);
            }
        }
        if (widen_for(h, u, l, st.kth, fails)) continue;
        largest_ = std::max<std::uint64_t>(largest_, m);
        std::vector<char> touched(m, 0);
        std::vector<float> most(m, -1.0f);
        for (std::size_t i : core) {
            for (int j = 0; j < ks; ++j) {
                const std::size_t q = std::size_t(st.list_of[i][j]);
                touched[i] = touched[i] || verdict[q] == kFails;
                if (scattered_nb[q]) most[i] = std::max(most[i], st.d[q]);
            }
        }
        d_.write(l, st.d);
        kth_.write(l, st.kth);
        verdict_.write(l, verdict);
        scattered_.write(l, scattered_nb);
        first_.write(l, st.first);
        touched_.write(l, touched);
        most_.write(l, most);
        return;
    }
}

/// The rule on a point from what verdict_pass spilled: 0 kept, 1 statistical, 2 planarity.
char StreamJob::rule_of(char verdict, char scattered_nb, float d) const {
    if (verdict == kFails) return 1;
    return planarity_candidate(verdict, d, median_d_, options_.outliers) && scattered_nb ? 2 : 0;
}

/// The scale of kept point i: the mean distance to its ks nearest kept points, walking its
/// lists (of k, then 2k, ... points) until ks are kept. Returns 0 when found; or the halo
/// needed to certify a list (-1: more points).
int StreamJob::walk(const Loaded& l, const KnnIndex& index, const Reach& reach, std::size_t i,
                    const std::vector<char>& rule, const Unit& u, std::vector<int>& kept_nb,
                    float& spacing) const {
    const int ks = ks_;
    const Span<Vec3f> pts = l.cloud.positions;
    for (int K = k_;; K *= 2) {
        if (std::size_t(K) >= l.size()) return -1;  // more points needed: a wider halo
        const KnnResult list = index.self_neighbours_of({i}, K);
        const int* nb = list.neighbours(0);
        const float kth = KnnResult::squared_distance(pts[i], pts[std::size_t(nb[K - 1])]);
        if (!reach.certified(pts[i], kth)) return ring_for(u, ball_of(pts[i], kth));
        kept_nb.clear();
        for (int j = 0; j < K && int(kept_nb.size()) < ks; ++j) {
            if (rule[std::size_t(nb[j])] == 0) kept_nb.push_back(nb[j]);
        }
        if (int(kept_nb.size()) == ks) {
            spacing = mean_distance(pts, i, kept_nb.data(), ks);
            return 0;
        }
    }
}

/// The scales of the kept points `rows` (rows in the whole cloud) that one of their first ks
/// neighbours may have left: walked from lists searched again, with the rules of every loaded
/// point from what verdict_pass spilled.
void StreamJob::walk_again(const Unit& u, const std::vector<std::uint32_t>& rows,
                           std::vector<float>& spacing) const {
    for (int ring = 1;;) {
        const Loaded l = load(u, ring);
        const std::vector<float> d = d_.read(l);
        const std::vector<char> verdict = verdict_.read(l), scattered_nb = scattered_.read(l);
        std::vector<char> rule(l.size());
        for (std::size_t i = 0; i < l.size(); ++i) rule[i] = rule_of(verdict[i], scattered_nb[i], d[i]);
        const KnnIndex index(l.cloud.positions, options_.outliers.knn);
        const Reach reach = reach_of(l);
        std::vector<int> needed(rows.size(), 0);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, rows.size(), 16),
                          [&](const tbb::blocked_range<std::size_t>& rg) {
            std::vector<int> kept_nb;
            for (std::size_t a = rg.begin(); a < rg.end(); ++a) {
                const auto at = std::lower_bound(l.row.begin(), l.row.end(), rows[a]);
                needed[a] = walk(l, index, reach, std::size_t(at - l.row.begin()), rule, u,
                                 kept_nb, spacing[a]);
            }
        });
        int wider = 0;
        for (int v : needed) wider = v < 0 ? std::max(wider, 2 * ring) : std::max(wider, v);
        if (wider > 0 && l.lo == store_->lowest() && l.hi == store_->highest()) {
            // every point is loaded and a walk still finds too few kept ones
            throw NotStreamable{"too few points kept for the kNN scale"};
        }
        if (wider == 0) return;
        ring = std::max(ring + 1, wider);
    }
}

/// Pass 2: the outlier rules on the unit's points, now that the median d is known, and the kNN
/// scale of those kept: the mean distance to their first ks neighbours, or, where one of those
/// may go, a walk (walk_again).
void StreamJob::rules_pass(const Unit& u) {
    const Loaded l = load(u, 0);
    const std::size_t m = l.size();
    const std::vector<float> d = d_.read(l), first = first_.read(l), most = most_.read(l);
    const std::vector<char> verdict = verdict_.read(l), scattered_nb = scattered_.read(l);
    const std::vector<char> touched = touched_.read(l);
    std::vector<char> removed(m, 0);
    std::vector<float> scale(m, 0.0f);
    std::vector<std::size_t> again;
    for (std::size_t i = 0; i < m; ++i) {
        if (!l.core[i]) continue;
        const char rule = rule_of(verdict[i], scattered_nb[i], d[i]);
        removed[i] = rule != 0;
        statistical_ += rule == 1;
        planarity_ += rule == 2;
        if (removed[i]) continue;
        ++kept_;
        for (int a = 0; a < 3; ++a) {
            lowest_[a] = std::min(lowest_[a], l.cloud.positions[i][a]);
            highest_[a] = std::max(highest_[a], l.cloud.positions[i][a]);
        }
        if (!need_scale_) continue;
        if (keeps(l, i)) {
            scale[i] = l.cloud.scales[i];
        } else if (touched[i] || planarity_candidate(kPasses, most[i], median_d_, options_.outliers)) {
            again.push_back(i);  // one of its first ks neighbours may go
        } else {
            scale[i] = first[i];
        }
    }
    if (!again.empty()) {
        std::vector<std::uint32_t> rows;
        for (std::size_t i : again) rows.push_back(l.row[i]);
        std::vector<float> walked(rows.size(), 0.0f);
        walk_again(u, rows, walked);
        for (std::size_t a = 0; a < again.size(); ++a) scale[again[a]] = walked[a];
    }
    removed_.write(l, removed);
    if (need_scale_) scale_.write(l, scale);
}

/// The kept points of a loading (`removed`: its points' outlier flags; empty: none), in its
/// order, with its box and cells (for Reach); `at`: each one's index in the loading.
Loaded kept_of(const Loaded& l, const std::vector<char>& removed, std::vector<std::size_t>& at) {
    Loaded kept;
    at.clear();
    std::vector<Vec3f> pos;
    for (std::size_t i = 0; i < l.size(); ++i) {
        if (!removed.empty() && removed[i]) continue;
        at.push_back(i);
        pos.push_back(l.cloud.positions[i]);
        kept.row.push_back(l.row[i]);
        kept.core.push_back(l.core[i]);
    }
    kept.cloud.positions = std::move(pos);
    kept.cloud.origin = l.cloud.origin;
    kept.lo = l.lo;
    kept.hi = l.hi;
    kept.cells = l.cells;
    return kept;
}

/// The PCA normals of the kept points `need` of a loading (st: their lists, certified or not),
/// as normals.cpp's per point: false where degenerate; `wider` where a wider look is due.
void StreamJob::pca_normals(const Lists& st, const std::vector<std::size_t>& need,
                            std::vector<Vec3f>& normal, std::vector<char>& ok,
                            std::vector<char>& wider) {
    const Span<Vec3f> pts = st.l.cloud.positions;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, need.size(), 256),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t a = rg.begin(); a < rg.end(); ++a) {
            const std::size_t i = need[a];
            if (!st.certified[i]) continue;
            float doubt = 0.0f;
            bool w = false;
            ok[i] = st.k >= 2 &&
                    neighbourhood_normal(pts, i, st.list_of[i], st.k, normal[i], doubt, &w);
            wider[i] = ok[i] && w;
        }
    });
}

/// The normals of the kept points `need` of a loading of a unit's kept points `l` (PCA and the
/// wider look; not oriented), and whether each is not degenerate (`ok`); false, with the points
/// whose lists are not certified in `fails` (and every k-th distance in `kth`), when the halo
/// is too narrow.
bool StreamJob::kept_normals(const Loaded& l, const std::vector<std::size_t>& need,
                             std::vector<Vec3f>& normal, std::vector<char>& ok,
                             std::vector<float>& kth, std::vector<std::size_t>& fails) const {
    const KnnIndex index(l.cloud.positions, options_.normals.knn);
    Lists st(l, reach_of(l), index, kn_, 0);
    search(st, need);
    const std::size_t m = l.size();
    std::vector<char> wider(m, 0);
    pca_normals(st, need, normal, ok, wider);
    // The wider look reads the lists of the neighbours.
    std::vector<std::size_t> next;
    for (std::size_t i : need) {
        if (!st.certified[i]) fails.push_back(i);
        for (int j = 0; j < st.k && wider[i]; ++j) {
            const std::size_t q = std::size_t(st.list_of[i][j]);
            if (!st.list_of[q]) next.push_back(q);
        }
    }
    std::sort(next.begin(), next.end());
    next.erase(std::unique(next.begin(), next.end()), next.end());
    search(st, next);
    for (std::size_t q : next) {
        if (!st.certified[q]) fails.push_back(q);
    }
    kth = st.kth;
    if (!fails.empty()) return false;
    const auto list = [&st](std::size_t j) { return st.list_of[j]; };
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, need.size(), 256),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t a = rg.begin(); a < rg.end(); ++a) {
            const std::size_t i = need[a];
            if (wider[i]) wider_normal(l.cloud.positions, i, st.k, list, normal[i]);
        }
    });
    return true;
}

/// The normals the in-memory stage estimates (all, or the file's zero ones), a unit at a time
/// (normals.cpp's per point, detail/normal_rules.h) on the kept points: each one's PCA normal
/// from its kn_ nearest kept points, the wider look over its neighbours' lists where due, the
/// local orientation. Every list read is certified; the halo widens until it is.
void StreamJob::normals_pass(const Unit& u) {
    for (Halo h;;) {
        const Loaded all = load(u, h);
        std::vector<std::size_t> at;
        const Loaded l = kept_of(all, outliers_ ? removed_.read(all) : std::vector<char>(), at);
        const std::size_t m = l.size();
        if (m <= std::size_t(kn_)) {
            h.ring *= 2;
            continue;
        }
        // The core points whose normals are estimated, in the store's order (near ones
        // together).
        const Span<Vec3f> file = all.cloud.normals;
        std::vector<std::size_t> kept_index(all.size(), SIZE_MAX), need;
        for (std::size_t j = 0; j < m; ++j) kept_index[at[j]] = j;
        for (std::size_t i : core_rows(all)) {
            const std::size_t j = kept_index[i];
            if (j != SIZE_MAX && (estimate_all_ || is_zero(file[i]))) need.push_back(j);
        }
        std::vector<Vec3f> normal(m, Vec3f{0, 0, 0});
        std::vector<char> ok(m, 0);
        std::vector<float> kth;
        std::vector<std::size_t> fails;
        if (!kept_normals(l, need, normal, ok, kth, fails)) {
            widen_for(h, u, l, kth, fails);
            continue;
        }
        largest_ = std::max<std::uint64_t>(largest_, all.size());
        std::vector<Vec3f> out(all.size(), Vec3f{0, 0, 0});
        if (!file.empty()) std::copy(file.begin(), file.end(), out.begin());
        for (std::size_t i : need) {
            if (!ok[i]) {
                ++degenerate_;
                out[at[i]] = {0.0f, 0.0f, 0.0f};  // left unsplatted
                continue;
            }
            ++estimated_;
            flipped_ += orient_locally(options_.normals, l.cloud.origin, l.cloud.positions[i],
                                       normal[i]);
            out[at[i]] = normal[i];
        }
        normal_.write(all, out);
        return;
    }
}

/// The normal stage's counts and warnings, after normals_pass.
void StreamJob::finish_normals(PipelineResult& r) const {
    if (!estimate_) return;
    r.normals.estimated = estimated_;
    r.normals.repaired = estimate_all_ ? 0 : estimated_;
    r.normals.flipped = flipped_;
    r.normals.oriented_to_viewpoint = true;
    report_degenerate(degenerate_, kept_);
}

/// The unit's kept points as the tiles' samples (the columns the in-memory stages leave in the
/// cloud), and their rows in the whole cloud.
PointCloud StreamJob::samples(const Unit& u, std::vector<std::uint32_t>& rows) const {
    Loaded l = load(u, 0);
    const std::vector<char> removed = outliers_ ? removed_.read(l) : std::vector<char>(l.size(), 0);
    if (estimate_) l.cloud.normals = normal_.read(l);
    if (options_.normals.scale == ScaleMode::none) {
        l.cloud.scales.clear();
    } else if (need_scale_) {
        l.cloud.scales = scale_.read(l);
    }
    std::vector<std::uint32_t> keep;
    rows.clear();
    for (std::size_t i = 0; i < l.size(); ++i) {
        if (!l.core[i] || removed[i]) continue;
        keep.push_back(std::uint32_t(i));
        rows.push_back(l.row[i]);
    }
    return subset(l.cloud, keep);
}

/// Pass 3: the whole cloud's kernel statistics (kernel_frame's, by selection over the
/// kernels' sizes spilled a unit at a time).
KernelFrame StreamJob::frame(const SplatOptions& splat) {
    Spool sigmas("tiles: kernel sizes"), radii("tiles: kernel radii");
    double max_index = 0.0;
    std::uint64_t usable = 0;
    float max_r = 0.0f;
    std::vector<std::uint32_t> rows;
    for (const Unit& u : units_) {
        const PointCloud part = samples(u, rows);
        if (part.empty()) continue;
        std::vector<float> sigma, radius;
        kernel_sizes(part, splat, sigma, radius, max_index);
        sigma.erase(std::remove(sigma.begin(), sigma.end(), -1.0f), sigma.end());
        usable += sigma.size();
        max_r = std::max(max_r, *std::max_element(radius.begin(), radius.end()));
        sigmas.add_vector(sigma);
        radii.add_vector(radius);
    }
    check_kernel_range(max_index, max_r, kept_ - usable, kept_, splat.voxel_size);
    const auto scan = [](const Spool& spool) {
        return [&spool](const auto& fn) {
            for (std::size_t b = 0; b < spool.size(); ++b) {
                const std::vector<float> v = spool.get_vector<float>(b);
                fn(v.data(), v.size());
            }
        };
    };
    KernelFrame f;
    f.sigma_median = double(select_rank(usable / 2, scan(sigmas))) * splat.voxel_size;
    f.max_r = max_r;
    f.r_typical = select_rank(std::uint64_t(0.95 * double(kept_ - 1)), scan(radii));
    return f;
}

/// Pass 4: the kept samples into the buckets of their tiles, and the tiles to visit.
void StreamJob::buckets(const TileGrid& g, const TileAnchors& anchors, TilePlan& plan) {
    std::map<Key, std::string> parts;  // occupied tile -> its file while being written
    std::vector<TileKey> near;
    std::vector<std::uint32_t> rows;
    for (const Unit& u : units_) {
        const PointCloud part = samples(u, rows);
        std::map<Key, std::vector<std::uint32_t>> by_tile;
        for (std::size_t i = 0; i < part.size(); ++i) {
            const openvdb::Vec3d c = anchors(part, i);
            by_tile[tile_of(c, g)].push_back(std::uint32_t(i));
            add_tiles_near(c, g, near);
        }
        sort_unique(near);
        for (const auto& e : by_tile) {
            std::vector<std::uint32_t> index;
            for (std::uint32_t i : e.second) index.push_back(rows[i]);
            auto it = parts.find(e.first);
            const bool fresh = it == parts.end();
            if (fresh) {
                it = parts.emplace(e.first, dir_ + "/bucket-part-" + std::to_string(parts.size()) +
                                                ".tmp").first;
            }
            std::FILE* f = std::fopen(it->second.c_str(), fresh ? "wb" : "ab");
            const std::string bytes =
                (fresh ? bucket_tag() : std::string()) +
                bucket_section(index, subset(part, e.second));
            const bool ok = f && std::fwrite(bytes.data(), 1, bytes.size(), f) == bytes.size();
            if ((f && std::fclose(f) != 0) || !ok) throw IoError(it->second + ": write failed");
        }
    }
    for (const auto& e : parts) {
        const std::string to = bucket_path(dir_, plan.buckets.size());
        if (std::rename(e.second.c_str(), to.c_str()) != 0) throw IoError(to + ": rename failed");
        plan.buckets.push_back(e.first);
    }
    plan.tiles = plan.buckets;
    plan.tiles.insert(plan.tiles.end(), near.begin(), near.end());
    sort_unique(plan.tiles);
}

/// The median sample spacing the in-memory stages would give (pipeline.cpp's sample_spacing).
double StreamJob::sample_spacing() {
    const auto scan_side = [&](const CellStore::Side<float>& side, bool kept_only) {
        return [&side, kept_only, this](const auto& fn) {
            std::vector<char> removed;
            std::vector<float> kept;
            side.scan(n_, [&](const float* v, std::uint64_t first, std::size_t count) {
                if (!kept_only) return fn(v, count);
                removed.resize(count);
                removed_.scan_range(first, removed.data(), count);
                kept.clear();
                for (std::size_t i = 0; i < count; ++i) {
                    if (!removed[i]) kept.push_back(v[i]);
                }
                fn(kept.data(), kept.size());
            });
        };
    };
    if (options_.normals.scale != ScaleMode::none) {
        median_scale_ = need_scale_ ? select_rank(kept_ / 2, scan_side(scale_, outliers_))
                                    : file_scale_median();
    }
    if (outliers_ || need_scale_) {  // the density spacing of the first search
        return density_spacing(select_rank(kept_ / 2, scan_side(kth_, outliers_)), k_);
    }
    return median_scale_;  // the file's scales (all > 0 here), or 0 (--scale none)
}

/// The median of the file's scales over the kept points.
double StreamJob::file_scale_median() const {
    std::vector<std::uint32_t> rows;
    Spool scales("tiles: scales");
    for (const Unit& u : units_) scales.add_vector(samples(u, rows).scales.to_vector());
    return select_rank(kept_ / 2, [&](const auto& fn) {
        for (std::size_t b = 0; b < scales.size(); ++b) {
            const std::vector<float> v = scales.get_vector<float>(b);
            fn(v.data(), v.size());
        }
    });
}

/// The median d (the outlier rules' mean distance to the k nearest) over a sample of cells
/// spread over the store, each loaded with a ring of cells (lists not certified: an estimate).
double StreamJob::sampled_median_d() const {
    const std::size_t cells = store_->keys().size();
    const std::size_t step = std::max<std::size_t>(1, cells / 32);
    std::vector<float> ds;
    for (std::size_t j = 0; j < cells; j += step) {
        Unit u;
        u.cells = {j};
        u.lo = u.hi = store_->keys()[j];
        const Loaded l = load(u, 1);
        if (l.size() <= std::size_t(k_)) continue;
        const KnnIndex index(l.cloud.positions, options_.outliers.knn);
        const std::vector<std::size_t> core = core_rows(l);
        const KnnResult got = index.self_neighbours_of(core, k_);
        for (std::size_t a = 0; a < core.size(); ++a) {
            ds.push_back(mean_distance(l.cloud.positions, core[a], got.neighbours(a), k_));
        }
    }
    if (ds.empty()) return 0.0;
    std::nth_element(ds.begin(), ds.begin() + std::ptrdiff_t(ds.size() / 2), ds.end());
    return double(ds[ds.size() / 2]);
}

/// Pass 1 with the outlier rules, and the median d. The planarity test (a PCA) is asked of the
/// points above planarity_spacing x the median only, which pass 1 does not know yet: it runs
/// above that many times 0.9 x a sampled median, and pass 1 runs again, for every point, should
/// the median turn out lower (the results are the same either way).
void StreamJob::verdicts() {
    const OutlierOptions& o = options_.outliers;
    const double floor = 0.9 * sampled_median_d();
    scattered_from_ = o.planarity_spacing * floor;
    for (const Unit& u : units_) verdict_pass(u);
    median_d_ = select_rank(n_ / 2, [&](const auto& fn) {
        d_.scan(n_, [&](const float* v, std::uint64_t, std::size_t c) { fn(v, c); });
    });
    if (median_d_ < floor && scattered_from_ > 0.0) {
        log_info("tiles: the median spacing is below the sampled one; the planarity test runs "
                 "again for every point");
        scattered_from_ = 0.0;
        for (const Unit& u : units_) verdict_pass(u);
    }
}

void StreamJob::run(TileJob& job) {
    read();
    make_units();
    if (outliers_) {
        verdicts();
    } else if (need_scale_) {
        for (const Unit& u : units_) spacing_pass(u);
    }
    kept_ = n_;
    if (outliers_) {
        kept_ = 0;
        lowest_ = {HUGE_VALF, HUGE_VALF, HUGE_VALF};
        highest_ = {-HUGE_VALF, -HUGE_VALF, -HUGE_VALF};
        for (const Unit& u : units_) rules_pass(u);
        if (kept_ == 0) throw InvalidArgument("reconstruct: every point was an outlier");
    }
    PipelineResult& r = job.result;
    if (estimate_) {
        if (kept_ < 3) throw NotStreamable{"too few points kept to estimate normals"};
        kn_ = std::min<int>(options_.normals.k, int(kept_) - 1);
        for (const Unit& u : units_) normals_pass(u);
        finish_normals(r);
    }
    r.outliers.statistical = statistical_;
    r.outliers.planarity = planarity_;
    const double spacing = sample_spacing();
    r.normals.median_scale = median_scale_;
    (outliers_ ? r.outliers.density_spacing
               : need_scale_ ? r.normals.density_spacing : r.normals.median_scale) = spacing;
    SplatOptions splat = options_.splat;
    const double diag = BBox{lowest_, highest_}.diagonal();
    if (splat.voxel_size == 0.0) {
        r.spacing = spacing;
        splat.voxel_size = voxel_for(diag, spacing, options_);
        r.voxel_chosen = true;
    }
    r.voxel_size = splat.voxel_size;
    if (!(diag > 0.0)) {
        throw NumericalError("reconstruct: all " + std::to_string(kept_) +
                             " points coincide; no surface can be reconstructed");
    }
    const TiledOptions to = tiled_options(options_, splat, spacing);
    check_tiled(to, kept_);
    TilePlan plan;
    plan.voxel = splat.voxel_size;
    plan.origin = totals_.cloud.origin;
    plan.sample_spacing = spacing;
    plan.points = kept_;
    plan.setup.frame = frame(splat);
    TileGrid& g = plan.setup.grid;
    g = tile_margins(plan.setup.frame, to.close, to.splat);
    g.n = tile_edge(to, 0, g.halo);
    place_grid(g, lowest_, splat.voxel_size);
    buckets(g, TileAnchors(to.splat), plan);
    write_tile_plan(dir_, plan);
    r.stream_units = units_.size();
    r.stream_largest = largest_;
    job.tiles = plan.tiles.size();
    job.tile = g.n;
    job.voxel_size = splat.voxel_size;
    job.read = std::move(totals_);
    job.read.cloud = PointCloud{};
}

}  // namespace

std::string stream_refusal(const PipelineOptions& options) {
    if (options.tile == 0) return "no tiles";
    if (options.stream == StreamMode::never) return "--stream off";
    if (options.texture.enabled) return "a texture reads every point's colour";
    if (options.normals.mode == NormalMode::estimate && !options.normals.orients_locally()) {
        return "normals to estimate (their orientation spans the cloud; --up or --viewpoint "
               "would orient them locally)";
    }
    if (options.outliers.knn.backend != KnnBackend::grid ||
        options.normals.knn.backend != KnnBackend::grid) {
        return "--knn flann (the streamed stages use the grid search, whose ties break by index)";
    }
    if (options.outliers.enabled && options.normals.k > options.outliers.k) {
        return "more neighbours for the scale than for the outlier rules";
    }
    return "";
}

/// About the bytes the in-memory point stages would take for this file: twice the size of a
/// binary PLY file with normals kept (48 bytes a point: 20M terrain points, 965 MB); six times
/// that of a file whose normals are estimated (their lists are kept too, about 100 bytes a
/// point: 1M terrain points, 116 MB; a row is 12-34 bytes in PLY, LAS or text).
double points_memory_estimate(const std::string& input, const NormalOptions& options) {
    struct stat st {};
    if (::stat(input.c_str(), &st) != 0) return 0.0;
    if (options.mode == NormalMode::estimate) return 6.0 * double(st.st_size);
    bool normals = false;
    try {
        const FileBytes file(input);
        const std::string_view bytes = file.bytes();
        normals = bytes.compare(0, 3, "ply") == 0 && ply_has_normals(input, bytes);
    } catch (const std::exception&) {
        // the read names the problem
    }
    return (normals ? 2.0 : 6.0) * double(st.st_size);
}

bool prepare_streamed(const std::string& input, const std::string& dir,
                      const PipelineOptions& options, TileJob& job) {
    std::string why = stream_refusal(options);
    if (why.empty() && options.stream == StreamMode::automatic) {
        const double need = points_memory_estimate(input, options.normals);
        const double budget = double(memory_budget(options.splat));
        if (need <= 0.5 * budget) {
            why = "the points fit in memory (about " + std::to_string(int(need / 1e6)) +
                  " MB, half of --max-memory is " + std::to_string(int(0.5 * budget / 1e6)) +
                  " MB; --stream on streams them)";
        }
    }
    if (why.empty()) {
        try {
            StreamJob(input, dir, options).run(job);
            return true;
        } catch (const NotStreamable& e) {
            why = e.why;
        }
    }
    log_info(input + ": tiles: the points are read whole, not streamed: " + why);
    return false;
}

}  // namespace vdbrecon::detail
