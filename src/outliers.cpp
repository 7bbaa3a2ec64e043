// Point outlier removal (see outliers.h).
#include "vdbrecon/outliers.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>

#include "detail/compact.h"
#include "detail/outlier_rules.h"
#include "detail/parked.h"
#include "detail/release.h"
#include "detail/select.h"
#include "vdbrecon/error.h"
#include "vdbrecon/knn.h"

namespace vdbrecon {

void OutlierOptions::validate() const {
    knn.validate();
    if (k < 3 || k > 1000) {
        throw InvalidArgument("outliers.k = " + std::to_string(k) + ": must be in 3..1000");
    }
    if (!(statistical_ratio == 0.0 || (statistical_ratio >= 1.0 && std::isfinite(statistical_ratio)))) {
        throw InvalidArgument("outliers.statistical_ratio = " + std::to_string(statistical_ratio) +
                              ": must be 0 (off) or a number >= 1");
    }
    if (!(planarity_ratio >= 0.0 && planarity_ratio < 1.0)) {
        throw InvalidArgument("outliers.planarity_ratio = " + std::to_string(planarity_ratio) +
                              ": must be in [0, 1)");
    }
    if (!(planarity_spacing >= 0.0 && std::isfinite(planarity_spacing))) {
        throw InvalidArgument("outliers.planarity_spacing = " + std::to_string(planarity_spacing) +
                              ": must be a non-negative number");
    }
}

namespace {

/// Keeps the rows not removed, in place (does not throw).
template <typename T>
void compact(std::vector<T>& values, const std::vector<char>& removed, std::size_t kept) {
    std::size_t out = 0;
    for (std::size_t i = 0; i < values.size(); ++i) {
        if (!removed[i]) values[out++] = values[i];
    }
    values.resize(kept);
}

/// The same for an owned column (a borrowed one is left alone).
template <typename T>
void compact_owned(Column<T>& v, const std::vector<char>& removed, std::size_t kept) {
    if (!v.empty() && !v.borrowed()) compact(v.edit(), removed, kept);
}

/// The kept rows of a borrowed column as a new array (empty for an owned one): borrowed memory
/// is never written to.
template <typename T>
Column<T> copy_borrowed(const Column<T>& v, const std::vector<char>& removed, std::size_t kept) {
    std::vector<T> out;
    if (!v.borrowed() || v.empty()) return out;
    out.reserve(kept);
    for (std::size_t i = 0; i < v.size(); ++i) {
        if (!removed[i]) out.push_back(v[i]);
    }
    return out;
}

/// The element of rank n / 2 of v (what std::nth_element puts there), without a copy of v
/// (detail::select_rank).
double median_of(const std::vector<float>& v) {
    return double(detail::select_rank(v.size() / 2, v));
}

/// Rows with the first `width` entries of their neighbour lists: those that wait for something
/// of their neighbours (see classify), and those kept for the planarity rule (KeptLists).
struct RowLists {
    std::size_t width = 0;
    std::vector<int> rows, lists;
    void add(int row, const int* nb) {
        rows.push_back(row);
        lists.insert(lists.end(), nb, nb + width);
    }
    const int* list(std::size_t e) const { return lists.data() + e * width; }
};

/// A row and its neighbour list, wherever the list is held.
struct RowList {
    int row;
    const int* nb;
};

/// The lists the search hands over that the planarity rule may want (see classify): rows above
/// kKeepShare of its bound, taken with their batch's median d for the cloud's, which is known
/// only at the end. At most a fifth of the points' lists (13 bytes a point at k = 16), the
/// first in batch order. Bunny scans: 24k lists kept, all 17k candidates among them; dragon
/// scans: 53k kept, all 32k candidates.
struct KeptLists {
    static constexpr double kKeepShare = 0.9;
    RowLists lists;
    std::size_t most;

    KeptLists(std::size_t width, std::size_t most_rows) : lists{width, {}, {}}, most(most_rows) {}
    bool full() const { return lists.rows.size() >= most; }

    /// Keeps the rows of one batch (d_i in `spacing`) whose d_i is above the bound.
    void add_batch(const int* batch_rows, std::size_t count, const int* idx,
                   const std::vector<float>& spacing, double planarity_spacing) {
        std::vector<float> d;  // every 16th row's: the median need not be exact
        for (std::size_t t = 0; t < count; t += 16)
            d.push_back(spacing[std::size_t(batch_rows[t])]);
        const auto mid = d.begin() + std::ptrdiff_t(d.size() / 2);
        std::nth_element(d.begin(), mid, d.end());
        const double least = kKeepShare * planarity_spacing * double(*mid);
        std::vector<std::size_t> keep = detail::indices_where(count, [&](std::size_t t) {
            return double(spacing[std::size_t(batch_rows[t])]) > least;
        });
        keep.resize(std::min(keep.size(), most - lists.rows.size()));  // the first, until full
        const std::size_t at = lists.rows.size(), w = lists.width;
        lists.rows.resize(at + keep.size());
        lists.lists.resize((at + keep.size()) * w);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, keep.size(), 1024),
                          [&](const tbb::blocked_range<std::size_t>& rg) {
                              for (std::size_t j = rg.begin(); j < rg.end(); ++j) {
                                  lists.rows[at + j] = batch_rows[keep[j]];
                                  std::copy_n(idx + keep[j] * w, w,
                                              lists.lists.data() + (at + j) * w);
                              }
                          });
    }

    /// The lists of the rows `wanted` (ascending), null where none is kept.
    std::vector<const int*> find(const std::vector<std::size_t>& wanted) const {
        std::vector<std::pair<int, std::size_t>> by_row(lists.rows.size());
        for (std::size_t e = 0; e < lists.rows.size(); ++e) by_row[e] = {lists.rows[e], e};
        std::sort(by_row.begin(), by_row.end());
        std::vector<const int*> out(wanted.size(), nullptr);
        std::size_t e = 0;
        for (std::size_t c = 0; c < wanted.size(); ++c) {
            while (e < by_row.size() && std::size_t(by_row[e].first) < wanted[c]) ++e;
            if (e < by_row.size() && std::size_t(by_row[e].first) == wanted[c]) {
                out[c] = lists.list(by_row[e].second);
            }
        }
        return out;
    }
};

/// try_row(row, nb) on every entry of `work`, in parallel: whether each was resolved.
template <typename Try>
std::vector<char> try_rows(const std::vector<RowList>& work, const Try& try_row) {
    std::vector<char> done(work.size(), 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, work.size(), 2048),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t e = rg.begin(); e < rg.end(); ++e) {
            done[e] = try_row(std::size_t(work[e].row), work[e].nb) ? 1 : 0;
        }
    });
    return done;
}

/// `head` entries head_at(e), then the rows that wait, as the entries of `out`, in parallel
/// (serial appends were a per-batch tail).
template <typename HeadAt>
void then_waiting(std::size_t head, const HeadAt& head_at, const RowLists& waiting,
                  std::vector<RowList>& out) {
    out.resize(head + waiting.rows.size());
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, out.size(), 8192),
        [&](const tbb::blocked_range<std::size_t>& rg) {
            for (std::size_t e = rg.begin(); e < rg.end(); ++e) {
                out[e] =
                    e < head ? head_at(e) : RowList{waiting.rows[e - head], waiting.list(e - head)};
            }
        });
}

/// The entries of `work` that are not `done`, with the first `width` entries of their lists
/// (copied: the lists may be a batch's, which the search reuses), in order: the rows that wait.
RowLists waiting_rows(const std::vector<RowList>& work, const std::vector<char>& done,
                      std::size_t width) {
    RowLists out{width, {}, {}};
    for (std::size_t e :
         detail::indices_where(work.size(), [&](std::size_t e) { return !done[e]; })) {
        out.add(work[e].row, work[e].nb);
    }
    return out;
}

/// Codes of a bound (largest_code); kInfinite and above are no finite bound.
constexpr std::uint16_t kInfinite = 65534;

/// The upper bound of a non-negative value that largest_code() gives.
double largest_bound(std::uint16_t code) {
    if (code == 0) return 0.0;
    if (code >= kInfinite) return std::numeric_limits<double>::infinity();
    return std::exp2(double(code) / 64.0 - 512.0);
}

/// 16 bits that bound v >= 0 from above, within a factor 2^(1/64) (see largest_bound).
std::uint16_t largest_code(double v) {
    if (!(v > 0.0)) return 0;
    int code = int(std::clamp(std::ceil((std::log2(v) + 512.0) * 64.0), 1.0, double(kInfinite)));
    while (code < kInfinite && largest_bound(std::uint16_t(code)) < v) ++code;
    return std::uint16_t(code);
}

/// A list's near_code (classify): one of its first ks neighbours fails the statistical rule
/// (kTouched), not yet known (kWaiting), else largest_code of their largest d_j.
constexpr std::uint16_t kTouched = 65535, kWaiting = 0;

/// The rules' verdicts from the statistical one's (`verdict`) and each point's d_i: 1 =
/// statistical, 2 = planarity (the candidates' lists handed over, kept or searched again), 0 =
/// kept; the counts and r.removed filled in.
std::vector<char> apply_rules(const KnnIndex& index, Span<Vec3f> pts, const OutlierOptions& options,
                              const OutlierHandOver& hand_over, int k,
                              const std::vector<float>& spacing, std::vector<char>&& verdict,
                              double median, const KeptLists& kept, OutlierResult& r) {
    using detail::kFails;
    const std::size_t n = pts.size();
    // 3 = a planarity candidate, decided below.
    std::vector<char> rule(n, 0);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t i = rg.begin(); i < rg.end(); ++i) {
            if (verdict[i] == kFails) {
                rule[i] = 1;
            } else if (detail::planarity_candidate(verdict[i], spacing[i], median, options)) {
                rule[i] = 3;
            }
        }
    });
    detail::release(verdict);
    const std::vector<std::size_t> candidates =
        detail::indices_where(n, [&](std::size_t i) { return rule[i] == 3; });
    std::vector<const int*> list(candidates.size(), nullptr);
    if (hand_over.lists) {
        for (std::size_t c = 0; c < candidates.size(); ++c) {
            list[c] = r.neighbours.neighbours(candidates[c]);
        }
    } else {
        list = kept.find(candidates);
    }
    std::vector<std::size_t> again, again_rows;  // candidates without a list, and their rows
    for (std::size_t c = 0; c < candidates.size(); ++c) {
        if (list[c]) continue;
        again.push_back(c);
        again_rows.push_back(candidates[c]);
    }
    const KnnResult searched = index.self_neighbours_of(again_rows, k);
    for (std::size_t e = 0; e < again.size(); ++e) list[again[e]] = searched.neighbours(e);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, candidates.size(), 256),
                      [&](const tbb::blocked_range<std::size_t>& rg) {
        for (std::size_t c = rg.begin(); c < rg.end(); ++c) {
            const std::size_t i = candidates[c];
            rule[i] = detail::scattered(pts, i, list[c], k, options) ? 2 : 0;
        }
    });
    for (std::size_t i = 0; i < n; ++i) {
        if (rule[i] == 1) ++r.statistical;
        if (rule[i] == 2) ++r.planarity;
        r.removed[i] = rule[i] != 0;
    }
    return rule;
}

/// The spacing of the kept points whose first ks neighbours may have lost one (near_code
/// kTouched, or a neighbour the planarity rule could take): from the first ks kept points of
/// their nearest, into first_spacing.
void respace_touched(const KnnIndex& index, Span<Vec3f> pts, const OutlierOptions& options, int k,
                     int ks, double median, const std::vector<char>& rule,
                     std::vector<std::uint16_t>&& near_code, const OutlierResult& r,
                     std::vector<float>& first_spacing) {
    const std::size_t n = pts.size();
    // largest_bound(code) > planarity_spacing x median, as a least code (largest_bound does
    // not fall as the code grows), not an exp2 for each point.
    const double least = options.planarity_spacing * median;
    std::uint32_t planar_from = 1u << 16;  // no code
    if (options.planarity_ratio > 0.0) {
        std::uint32_t lo = 0, hi = 1u << 16;  // the first code above `least` is in [lo, hi]
        while (lo < hi) {
            const std::uint32_t mid = (lo + hi) / 2;
            if (largest_bound(std::uint16_t(mid)) > least) {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        planar_from = lo;
    }
    std::vector<std::size_t> again = detail::indices_where(n, [&](std::size_t i) {
        return rule[i] == 0 && (near_code[i] == kTouched || near_code[i] >= planar_from);
    });
    detail::release(near_code);
    // Their spacing from the first ks kept points of their K nearest: the nearest ks kept ones,
    // ties broken by index as among the kept points alone. K grows (from k) for the few rows
    // whose K nearest hold fewer than ks kept points; with K = n - 1 all do, as more than ks
    // points are kept.
    std::vector<std::size_t> rows = std::move(again);
    for (int K = k; !rows.empty(); K = int(std::min<std::size_t>(2 * std::size_t(K), n - 1))) {
        const KnnResult lists = index.self_neighbours_of(rows, K);
        std::vector<char> short_row(rows.size(), 0);
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, rows.size(), 1024),
                          [&](const tbb::blocked_range<std::size_t>& rg) {
            std::vector<int> kept_nb(std::size_t(ks), 0);
            for (std::size_t a = rg.begin(); a < rg.end(); ++a) {
                int m = 0;
                for (int j = 0; j < lists.k && m < ks; ++j) {
                    const int nb = lists.neighbours(a)[j];
                    if (!r.removed[std::size_t(nb)]) kept_nb[std::size_t(m++)] = nb;
                }
                if (m < ks) {
                    short_row[a] = 1;
                } else {
                    first_spacing[rows[a]] = detail::mean_distance(pts, rows[a], kept_nb.data(), ks);
                }
            }
        });
        std::size_t out = 0;
        for (std::size_t a = 0; a < rows.size(); ++a) {
            if (short_row[a]) rows[out++] = rows[a];
        }
        rows.resize(out);
        if (!rows.empty() && std::size_t(K) >= n - 1) {
            throw Error("outliers: internal error: too few kept neighbours for the spacing");
        }
    }
}

/// The rules of remove_outliers: fills r.removed, the counts, and what is handed over
/// (r.neighbours; r.spacing for every input point, compacted by the caller).
///
/// One neighbour search, visited a batch at a time (in the index's spatial order). Each batch
/// gives its points' d_i. A point's local average, and with it the statistical rule, is taken
/// as soon as all its neighbours have their d_j, so its list waits until then (few wait long).
/// The planarity rule needs the median d first, so its candidates (a few per cent of the
/// points) are known only at the end. Each batch keeps the lists of its rows that may be among
/// them, by its own median d (KeptLists); the candidates found without one are searched again,
/// which gives the same lists (the search is exact and breaks ties by index). On the bunny
/// scans, searching all 17k candidates again took about 0.02 s at 1 thread, as they lie apart
/// (no shared cells).
///
/// The spacing handed over is the mean distance to the spacing_k nearest *kept* points. It is
/// taken from the point's own list, whose first spacing_k points are its nearest kept ones
/// unless one of them goes. Which ones go is known only at the end, so the list waits a second
/// time, until its first spacing_k neighbours have met the statistical rule: it then records
/// whether one of them failed it, else a bound of the largest d_j among them (a planarity
/// removal needs d_j above planarity_spacing x median). Those points are searched again at the
/// end, as KnnResult::subset does: the first spacing_k kept points of their list, or of a longer
/// one when fewer than spacing_k of their k are kept.
void classify(const PointCloud& cloud, const OutlierOptions& options,
              const OutlierHandOver& hand_over, OutlierResult& r) {
    const std::size_t n = cloud.size();
    const Span<Vec3f> pts = cloud.positions;
    const KnnIndex index(pts, options.knn);
    const int k = options.k;  // < n (checked by the caller)
    const std::size_t ku = std::size_t(k);
    const int ks = hand_over.spacing_k <= k ? hand_over.spacing_k : 0;  // 0: none to hand over
    if (hand_over.lists) {
        r.neighbours.k = k;
        r.neighbours.indices.resize(n * ku);
    }
    // Per point: d_i (-1 until its batch is searched), and the statistical rule's verdict.
    using detail::kUnknown, detail::kFails, detail::kPasses, detail::kNoLocal;
    std::vector<float> spacing(n, -1.0f);  // float: 4 bytes a point of a large cloud
    std::vector<char> verdict(n, kUnknown);
    // For the spacing: its value from the first ks of all points, and whether one of those may
    // go (kTouched: one fails the statistical rule; else largest_code of their largest d_j).
    std::vector<float> first_spacing(ks > 0 ? n : 0);
    std::vector<float> kth_sq(n);  // squared distance to the k-th neighbour: the density
    std::vector<std::uint16_t> near_code(ks > 0 ? n : 0, kWaiting);
    // The statistical rule, once every neighbour has its d_j.
    const auto try_verdict = [&](std::size_t i, const int* nb) {
        double sum = 0.0;
        for (int j = 0; j < k; ++j) {
            const double d = spacing[std::size_t(nb[j])];
            if (d < 0.0) return false;
            sum += d;
        }
        verdict[i] = detail::statistical_verdict(spacing[i], sum, k, options);
        return true;
    };
    // What may take a near neighbour away, once the first ks neighbours have their verdicts.
    const auto try_near = [&](std::size_t i, const int* nb) {
        double most = 0.0;
        bool fails = false;
        for (int j = 0; j < ks; ++j) {
            const std::size_t m = std::size_t(nb[j]);
            if (verdict[m] == kUnknown) return false;
            fails = fails || verdict[m] == kFails;
            most = std::max(most, double(spacing[m]));
        }
        near_code[i] = fails ? kTouched : std::max<std::uint16_t>(1, largest_code(most));
        return true;
    };
    KeptLists kept(ku, hand_over.lists || options.planarity_ratio <= 0.0 ? 0 : n / 5);
    RowLists for_spacing{ku, {}, {}}, for_verdicts{std::size_t(ks), {}, {}};
    std::vector<RowList> work, work_near;
    // The lists of one batch (1/64 of the points), and of the rows still waiting, are all that
    // is held of them.
    index.visit_self_neighbours(k, [&](const int* rows, std::size_t count, int, const int* idx) {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 4096),
                          [&](const tbb::blocked_range<std::size_t>& rg) {
            for (std::size_t t = rg.begin(); t < rg.end(); ++t) {
                const std::size_t i = std::size_t(rows[t]);
                const int* nb = idx + t * ku;
                // The sum over the first ks neighbours is a prefix of the one over all k.
                spacing[i] = detail::mean_distance(pts, i, nb, k, ks,
                                                   ks > 0 ? &first_spacing[i] : nullptr);
                kth_sq[i] = KnnResult::squared_distance(pts[i], pts[std::size_t(nb[k - 1])]);
                if (hand_over.lists) std::copy_n(nb, ku, r.neighbours.indices.data() + i * ku);
            }
        });
        if (!kept.full()) {
            kept.add_batch(rows, count, idx, spacing, options.planarity_spacing);
        }
        // Verdicts of the batch's rows and of the waiting ones (two parallel passes, so no row
        // reads a verdict while it is written); the rows still short of something wait.
        then_waiting(
            count,
            [&](std::size_t t) {
                return RowList{rows[t], idx + t * ku};
            },
            for_spacing, work);
        const std::vector<char> done = try_rows(work, try_verdict);
        RowLists still = waiting_rows(work, done, ku);
        if (ks > 0) {
            const std::vector<std::size_t> resolved =
                detail::indices_where(work.size(), [&](std::size_t e) { return done[e] != 0; });
            then_waiting(
                resolved.size(), [&](std::size_t j) { return work[resolved[j]]; }, for_verdicts,
                work_near);
            const std::vector<char> near_done = try_rows(work_near, try_near);
            for_verdicts = waiting_rows(work_near, near_done, std::size_t(ks));
        }
        for_spacing = std::move(still);
    }, std::max<std::size_t>(std::size_t(1) << 16, n / 64));  // 1/64: a large cloud's lists
    // After the last batch every d_j, and then every verdict, is known: nothing waits.
    if (!for_spacing.rows.empty() || !for_verdicts.rows.empty()) {
        throw Error("outliers: internal error: unresolved neighbour lists");
    }
    for_spacing = {};
    for_verdicts = {};
    detail::release(work);  // (work = {} would keep the memory)
    detail::release(work_near);

    const double median = median_of(spacing);
    std::vector<char> rule = apply_rules(index, pts, options, hand_over, k, spacing,
                                         std::move(verdict), median, kept, r);
    kept = KeptLists(0, 0);
    const std::size_t kept_count = n - r.statistical - r.planarity;
    compact(kth_sq, r.removed, kept_count);
    r.density_spacing = median_density_spacing(kth_sq, k);
    detail::release(kth_sq);
    if (ks == 0 || kept_count <= std::size_t(ks)) return;  // too few kept: no spacing

    respace_touched(index, pts, options, k, ks, median, rule, std::move(near_code), r,
                    first_spacing);
    r.spacing = std::move(first_spacing);  // input order; compacted with the cloud
}

}  // namespace

OutlierResult remove_outliers(const PointCloud& cloud, const OutlierOptions& options,
                              const OutlierHandOver& hand_over) {
    PointCloud copy = cloud;  // copies owned arrays, shares borrowed ones (never written)
    return remove_outliers(std::move(copy), options, hand_over);
}

OutlierResult remove_outliers(PointCloud&& cloud, const OutlierOptions& options,
                              const OutlierHandOver& hand_over) {
    options.validate();
    OutlierResult r;
    r.removed.assign(cloud.size(), 0);
    if (options.enabled && cloud.size() >= std::size_t(options.k) + 1) {  // else nothing goes
        {
            detail::ParkedColumns parked(cloud, options.park_bytes, detail::kParkAll,
                                         "outliers");
            classify(cloud, options, hand_over, r);
            parked.restore();
        }
        const std::size_t kept = cloud.size() - r.statistical - r.planarity;
        // Borrowed columns are copied first: if a copy fails, the cloud is still whole.
        Column<Vec3f> positions = copy_borrowed(cloud.positions, r.removed, kept);
        Column<Vec3f> normals = copy_borrowed(cloud.normals, r.removed, kept);
        Column<Vec3f> colors = copy_borrowed(cloud.colors, r.removed, kept);
        Column<float> scales = copy_borrowed(cloud.scales, r.removed, kept);
        Column<float> confidences = copy_borrowed(cloud.confidences, r.removed, kept);
        const auto place = [&](auto& column, auto& copy) {
            if (column.borrowed()) {
                column = std::move(copy);
            } else {
                compact_owned(column, r.removed, kept);
            }
        };
        place(cloud.positions, positions);
        place(cloud.normals, normals);
        place(cloud.colors, colors);
        place(cloud.scales, scales);
        place(cloud.confidences, confidences);
        if (!r.spacing.empty()) compact(r.spacing, r.removed, kept);
    }
    r.cloud = std::move(cloud);
    return r;
}

}  // namespace vdbrecon
