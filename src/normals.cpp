// Normals and per-point scale (see normals.h for the method and references).
#include "vdbrecon/normals.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <queue>

#include "detail/pca.h"
#include "vdbrecon/error.h"
#include "vdbrecon/knn.h"
#include "vdbrecon/log.h"

namespace vdbrecon {

void NormalOptions::validate() const {
    knn.validate();
    if (k < 3 || k > 1000) {
        throw InvalidArgument("normals.k = " + std::to_string(k) + ": must be in 3..1000");
    }
    if (viewpoint) {
        for (double c : *viewpoint) {
            if (!std::isfinite(c)) throw InvalidArgument("normals.viewpoint: must be finite");
        }
    }
}

namespace {

bool is_zero(const Vec3f& n) { return n[0] == 0.0f && n[1] == 0.0f && n[2] == 0.0f; }

float dot(const Vec3f& a, const Vec3f& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

void flip(Vec3f& n) {
    for (float& c : n) c = -c;
}

/// The plane fit of the neighbours (relative positions q[0..m)) that lie within `tol` of the
/// plane through the point with normal n, the point itself included: the refined normal, or n
/// when the fit degenerates.
Eigen::Vector3d refit(const Eigen::Vector3d* q, int m, const Eigen::Vector3d& n, double tol,
                      bool inliers) {
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    int count = inliers ? 1 : 0;
    for (int j = 0; j < m; ++j) {
        if ((std::fabs(n.dot(q[j])) <= tol) == inliers) {
            mean += q[j];
            ++count;
        }
    }
    if (count < 3) return Eigen::Vector3d::Zero();
    mean /= double(count);
    Eigen::Matrix3d cov = inliers ? Eigen::Matrix3d(mean * mean.transpose()) : Eigen::Matrix3d::Zero();
    for (int j = 0; j < m; ++j) {
        if ((std::fabs(n.dot(q[j])) <= tol) != inliers) continue;
        const Eigen::Vector3d d = q[j] - mean;
        cov += d * d.transpose();
    }
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(cov);
    if (es.info() != Eigen::Success || !(es.eigenvalues()[1] > 1e-12 * es.eigenvalues()[2])) {
        return Eigen::Vector3d::Zero();
    }
    // The residual of the fit, as the eigenvector's length, rides along: |result| = 1 + rms.
    return es.eigenvectors().col(0) * (1.0 + std::sqrt(std::max(0.0, es.eigenvalues()[0]) / count));
}

/// Next to a sharp edge the k neighbours of a point span two faces and their PCA normal blends
/// both. There the point's own face is the plane through it that most neighbours lie on (within
/// a tenth of their mean distance), found by a deterministic RANSAC over the planes through the
/// point and two of its nearest neighbours (in the spirit of robust normal estimation next to
/// sharp features, Li et al. 2010). It replaces the PCA normal only where the neighbourhood is
/// two clean planes: half the neighbours or more on the first, 1.5x the PCA plane's inliers, and
/// the rest on one plane within the same tolerance, 20 degrees or more off the first; a noisy
/// but smooth patch (or overlapping scans) keeps its PCA normal.
bool face_normal(Span<Vec3f> pts, std::size_t i, const int* nb, int k, const Eigen::Vector3d& pca,
                 Eigen::Vector3d& n) {
    const Vec3f& c = pts[i];
    Eigen::Vector3d q[64];
    const int m = std::min(k, 64);
    double reach = 0.0;
    for (int j = 0; j < m; ++j) {
        const Vec3f& p = pts[std::size_t(nb[j])];
        q[j] = Eigen::Vector3d(double(p[0]) - c[0], double(p[1]) - c[1], double(p[2]) - c[2]);
        reach += q[j].norm();
    }
    const double tol = 0.1 * reach / double(m);
    auto inliers = [&](const Eigen::Vector3d& u) {
        int count = 0;
        for (int j = 0; j < m; ++j) count += std::fabs(u.dot(q[j])) <= tol;
        return count;
    };
    int best = 0;
    const int pairs = std::min(m, 10);
    for (int a = 0; a < pairs; ++a) {
        for (int b = a + 1; b < pairs; ++b) {
            Eigen::Vector3d u = q[a].cross(q[b]);
            const double len = u.norm();
            if (!(len > 0.3 * q[a].norm() * q[b].norm())) continue;  // nearly collinear
            u /= len;
            const int count = inliers(u);
            if (count > best) {
                best = count;
                n = u;
            }
        }
    }
    if (2 * best < m || 2 * best < 3 * inliers(pca)) return false;
    const Eigen::Vector3d other = refit(q, m, n, tol, false);
    if (other.norm() > 0.0) {  // the other face: one plane, clearly another
        const double rms = other.norm() - 1.0;
        if (rms > tol || std::fabs(other.normalized().dot(n)) > std::cos(20.0 * M_PI / 180.0)) {
            return false;
        }
    } else if (m - best >= 3) {
        return false;  // the rest is no plane
    }
    const Eigen::Vector3d own = refit(q, m, n, tol, true);
    if (own.norm() > 0.0) n = own.normalized();
    return true;
}

/// PCA normal of point i and its neighbours; next to a sharp edge, its face's (face_normal).
bool neighbourhood_normal(Span<Vec3f> pts, std::size_t i, const int* nb, int k,
                          Vec3f& normal) {
    Eigen::Vector3d ev, n;
    if (!detail::neighbourhood_pca(pts, i, nb, k, ev, n)) return false;
    // Degenerate: all points coincide, or they lie on a line (two vanishing eigenvalues).
    if (!(ev[2] > 0.0) || ev[1] <= 1e-12 * ev[2]) return false;
    n.normalize();
    // Surface variation lambda_0 / sum lambda (Pauly 2002): ~0 on a plane, 0.05-0.15 where the
    // neighbourhood folds over an edge.
    Eigen::Vector3d face;
    if (ev[0] > 0.02 * (ev[0] + ev[1] + ev[2]) && face_normal(pts, i, nb, k, n, face)) n = face;
    normal = {float(n[0]), float(n[1]), float(n[2])};
    return std::isfinite(normal[0]) && std::isfinite(normal[1]) && std::isfinite(normal[2]);
}

/// How well the normal n_j at p_j agrees with n_i at p_i, in -1..1 (negative: one of them is
/// flipped). On a circle through both points the normal at p_j is the one at p_i mirrored at
/// the plane that bisects the chord e = p_j - p_i, so n_i is mirrored so before it is compared
/// (the criterion of S. Koenig and S. Gumhold, "Consistent propagation of normal orientations
/// in point clouds", VMV 2009). On flat ground this is Hoppe's n_i . n_j; unlike it, it stays
/// near +1 across a sharp edge turning by more than 90 degrees (a 40-degree blade tip: n_i .
/// n_j = -0.77), where Hoppe's rule flips one side.
float agreement(const Vec3f& pi, const Vec3f& ni, const Vec3f& pj, const Vec3f& nj) {
    const Vec3f e = {pj[0] - pi[0], pj[1] - pi[1], pj[2] - pi[2]};
    const float len2 = dot(e, e);
    if (!(len2 > 0.0f)) return dot(ni, nj);
    const float inv = 1.0f / std::sqrt(len2);
    const float ei = dot(ni, e) * inv, ej = dot(nj, e) * inv;
    // A chord within 53 degrees of a normal is as likely to cross a layer of scanner noise
    // (two misregistered scans of one surface) as a thin wall: the mirror would turn the layers
    // against each other, so such pairs keep Hoppe's rule. Bunny scans: 99.31 % of estimated
    // normals agree with the scanner's under Hoppe's rule, 93.9 % with the mirror everywhere,
    // 99.28 % so; the fan part's blades: 31.1 %, 99.7 %, 99.7 %.
    if (std::max(std::fabs(ei), std::fabs(ej)) > 0.6f) return dot(ni, nj);
    return dot(ni, nj) - 2.0f * ei * ej;
}

/// Hoppe-style orientation: Prim's minimum spanning tree over the symmetric kNN graph with edge
/// cost 1 - |agreement|, propagating the sign from the seed along tree edges. Points in state
/// kFree are re-oriented; kFixed points (already oriented) seed their neighbourhoods; kExcluded
/// points (no normal) take no part. Returns the number of components seeded at a free point.
enum : char { kExcluded = 0, kFree = 1, kFixed = 2 };
std::size_t orient_mst(Span<Vec3f> pts, std::vector<Vec3f>& normals,
                       const KnnResult& knn, const std::vector<char>& state,
                       std::size_t& flipped) {
    const std::size_t n = pts.size();
    const int k = knn.k;
    // Symmetric adjacency in CSR form.
    std::vector<std::uint32_t> degree(n + 1, 0);
    for (std::size_t i = 0; i < n; ++i) {
        const int* nb = knn.neighbours(i);
        for (int j = 0; j < k; ++j) {
            ++degree[i];
            ++degree[std::size_t(nb[j])];
        }
    }
    std::vector<std::size_t> start(n + 1, 0);
    for (std::size_t i = 0; i < n; ++i) start[i + 1] = start[i] + degree[i];
    std::vector<std::int32_t> adj(start[n]);
    std::vector<std::size_t> fill(start.begin(), start.end() - 1);
    for (std::size_t i = 0; i < n; ++i) {
        const int* nb = knn.neighbours(i);
        for (int j = 0; j < k; ++j) {
            adj[fill[i]++] = nb[j];
            adj[fill[std::size_t(nb[j])]++] = std::int32_t(i);
        }
    }

    struct Edge {
        float cost;
        std::int32_t to, from;
        bool operator>(const Edge& o) const {
            if (cost != o.cost) return cost > o.cost;
            if (to != o.to) return to > o.to;
            return from > o.from;
        }
    };
    std::priority_queue<Edge, std::vector<Edge>, std::greater<Edge>> heap;
    std::vector<char> done(n, 0);
    auto push_neighbours = [&](std::size_t i) {
        for (std::size_t e = start[i]; e < start[i + 1]; ++e) {
            const std::size_t j = std::size_t(adj[e]);
            if (done[j] || state[j] != kFree) continue;
            const float c = 1.0f - std::min(1.0f, std::fabs(agreement(pts[i], normals[i], pts[j], normals[j])));
            heap.push({c, std::int32_t(j), std::int32_t(i)});
        }
    };
    auto grow = [&]() {
        while (!heap.empty()) {
            const Edge e = heap.top();
            heap.pop();
            const std::size_t j = std::size_t(e.to);
            if (done[j]) continue;
            done[j] = 1;
            const std::size_t i = std::size_t(e.from);
            if (agreement(pts[i], normals[i], pts[j], normals[j]) < 0.0f) {
                flip(normals[j]);
                ++flipped;
            }
            push_neighbours(j);
        }
    };

    // Fixed (already oriented) points first: they seed their neighbourhoods.
    for (std::size_t i = 0; i < n; ++i) {
        if (state[i] != kFree) done[i] = 1;
    }
    for (std::size_t i = 0; i < n; ++i) {
        if (state[i] == kFixed) push_neighbours(i);
    }
    grow();

    // Remaining components: seed at the highest unvisited point, normal turned away from the
    // cloud's centroid (for the top of a closed object that is "up and out").
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const Vec3f& p : pts) centroid += Eigen::Vector3d(p[0], p[1], p[2]);
    centroid /= double(n);
    std::vector<std::int32_t> order(n);
    for (std::size_t i = 0; i < n; ++i) order[i] = std::int32_t(i);
    std::sort(order.begin(), order.end(), [&](std::int32_t a, std::int32_t b) {
        if (pts[std::size_t(a)][2] != pts[std::size_t(b)][2]) {
            return pts[std::size_t(a)][2] > pts[std::size_t(b)][2];
        }
        return a < b;
    });
    std::size_t components = 0;
    for (std::int32_t s : order) {
        const std::size_t i = std::size_t(s);
        if (done[i]) continue;
        ++components;
        done[i] = 1;
        const Vec3f& p = pts[i];
        Vec3f out = {float(p[0] - centroid[0]), float(p[1] - centroid[1]),
                     float(p[2] - centroid[2])};
        if (dot(out, out) == 0.0f) out = {0.0f, 0.0f, 1.0f};
        if (dot(normals[i], out) < 0.0f) {
            flip(normals[i]);
            ++flipped;
        }
        push_neighbours(i);
        grow();
    }
    return components;
}

}  // namespace

bool scales_need_neighbours(const PointCloud& cloud, const NormalOptions& options) {
    if (options.scale == ScaleMode::knn) return true;
    return options.scale == ScaleMode::automatic &&
           (!cloud.has_scales() || std::any_of(cloud.scales.begin(), cloud.scales.end(),
                                               [](float s) { return !(s > 0.0f); }));
}

namespace {

/// Whether every point's normal is to be estimated (not only the zero ones).
bool estimates_all(const PointCloud& cloud, const NormalOptions& options) {
    return options.mode == NormalMode::estimate || !cloud.has_normals();
}

NormalResult estimate_normals_with(const PointCloud& cloud, const NormalOptions& options,
                                   const KnnResult* known, const std::vector<float>* spacing) {
    options.validate();
    const std::size_t n = cloud.size();
    NormalResult result;
    if (n == 0) throw InvalidArgument("normals: the point cloud is empty");

    if (options.mode == NormalMode::keep && !cloud.has_normals()) {
        throw InvalidArgument(
            "normals: the input has no normals and --normals keep was given. Hint: --normals "
            "estimate");
    }
    const bool estimate_all = estimates_all(cloud, options);
    std::vector<char> needs(n, 0);
    std::size_t needed = 0;
    if (estimate_all) {
        std::fill(needs.begin(), needs.end(), 1);
        needed = n;
    } else {
        for (std::size_t i = 0; i < n; ++i) {
            if (is_zero(cloud.normals[i])) {
                needs[i] = 1;
                ++needed;
            }
        }
    }
    const bool need_scale = scales_need_neighbours(cloud, options);

    // Kept arrays are Column copies: a borrowed input is shared, not copied, until written.
    if (estimate_all) {
        result.normals = std::vector<Vec3f>(n, Vec3f{0, 0, 0});
    } else {
        result.normals = cloud.normals;
    }
    if (options.scale != ScaleMode::none && cloud.has_scales()) result.scales = cloud.scales;
    auto median_scale = [&result] {
        if (result.scales.empty()) return;
        std::vector<float> s = result.scales.to_vector();
        std::nth_element(s.begin(), s.begin() + std::ptrdiff_t(s.size() / 2), s.end());
        result.median_scale = s[s.size() / 2];
    };

    if (needed == 0 && !need_scale) {
        median_scale();
        return result;
    }
    if (n < 2) {
        throw NumericalError("normals: " + std::to_string(n) +
                             " point(s) are too few to estimate normals or spacing");
    }

    // The k nearest neighbours: given, or searched here. Only normals need whole lists; for the
    // scale alone each point's are summed as their batch is searched, none kept.
    const int want = std::min<int>(options.k, int(n) - 1);
    const bool given = known && known->k == want && known->indices.size() == n * std::size_t(want);
    const bool have_lists = given || needed > 0;  // every point's, given or searched below
    if (spacing && spacing->size() != n) spacing = nullptr;
    const bool search = !given && (needed > 0 || !spacing);
    const std::unique_ptr<KnnIndex> index =
        search ? std::make_unique<KnnIndex>(cloud.positions, options.knn) : nullptr;
    KnnResult own;
    if (!given && needed > 0) own = index->self_neighbours(options.k);
    if (!given) known = &own;
    const KnnResult& knn = *known;
    const int k = want;
    // Squared distances to the k-th neighbour, for the density spacing, when searched here.
    std::vector<float> kth_sq(search ? n : 0);
    if (search && needed > 0) {
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t i = r.begin(); i < r.end(); ++i) {
                kth_sq[i] = knn.sq_dist(cloud.positions, i, k - 1);
            }
        });
    }

    // PCA normals where needed.
    std::vector<char> degenerate(n, 0);
    if (needed > 0) {
        std::vector<Vec3f>& normals = result.normals.edit();
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1024),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t i = r.begin(); i < r.end(); ++i) {
                if (!needs[i]) continue;
                Vec3f nrm;
                if (k >= 2 && neighbourhood_normal(cloud.positions, i, knn.neighbours(i), k, nrm)) {
                    normals[i] = nrm;
                } else {
                    degenerate[i] = 1;
                }
            }
        });
        std::size_t bad = 0;
        for (std::size_t i = 0; i < n; ++i) {
            if (degenerate[i]) {
                ++bad;
                normals[i] = {0.0f, 0.0f, 0.0f};  // left unsplatted
            }
        }
        if (bad > 0) {
            log_warning("normals: " + std::to_string(bad) +
                        " points have degenerate neighbourhoods (coincident or collinear) and "
                        "get no normal");
        }
        result.estimated = needed - bad;
        if (!estimate_all) result.repaired = needed - bad;
        if (bad == n) {
            throw NumericalError("normals: every neighbourhood is degenerate (all points "
                                 "coincident or collinear); no surface can be reconstructed");
        }

        // Orientation.
        if (options.viewpoint) {
            result.oriented_to_viewpoint = true;
            const Vec3d& v = *options.viewpoint;
            for (std::size_t i = 0; i < n; ++i) {
                if (!needs[i] || degenerate[i]) continue;
                const Vec3f& p = cloud.positions[i];
                const Vec3f to_view = {float(v[0] - cloud.origin[0] - p[0]),
                                       float(v[1] - cloud.origin[1] - p[1]),
                                       float(v[2] - cloud.origin[2] - p[2])};
                if (dot(normals[i], to_view) < 0.0f) {
                    flip(normals[i]);
                    ++result.flipped;
                }
            }
        } else {
            std::vector<char> state(n);
            for (std::size_t i = 0; i < n; ++i) {
                state[i] = degenerate[i] ? kExcluded : needs[i] ? kFree : kFixed;
            }
            result.components =
                orient_mst(cloud.positions, normals, knn, state, result.flipped);
        }
    }

    if (need_scale) {
        if (result.scales.empty()) result.scales.assign(n, 0.0f);
        std::vector<float>& scales = result.scales.edit();
        // A file's scale stays in automatic mode.
        const auto keeps = [&](std::size_t i) {
            return options.scale == ScaleMode::automatic && scales[i] > 0.0f;
        };
        // Mean distance from point i to its neighbours nb[0..k).
        const auto scale = [&](std::size_t i, const int* nb, const float* d2) {
            if (keeps(i)) return;
            double s = 0.0;
            for (int j = 0; j < k; ++j) {
                s += std::sqrt(double(d2 ? d2[j]
                                         : KnnResult::squared_distance(
                                               cloud.positions[i],
                                               cloud.positions[std::size_t(nb[j])])));
            }
            scales[i] = float(s / double(k));
        };
        if (have_lists) {
            tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096),
                              [&](const tbb::blocked_range<std::size_t>& r) {
                for (std::size_t i = r.begin(); i < r.end(); ++i) {
                    scale(i, knn.neighbours(i), knn.has_distances() ? knn.sq_dists(i) : nullptr);
                }
            });
        } else if (spacing) {
            for (std::size_t i = 0; i < n; ++i) {
                if (!keeps(i)) scales[i] = (*spacing)[i];
            }
        } else {
            index->visit_self_neighbours(
                k, [&](const int* rows, std::size_t count, int, const int* idx) {
                    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 4096),
                                      [&](const tbb::blocked_range<std::size_t>& r) {
                        for (std::size_t t = r.begin(); t < r.end(); ++t) {
                            const std::size_t i = std::size_t(rows[t]);
                            const int* nb = idx + t * std::size_t(k);
                            scale(i, nb, nullptr);
                            kth_sq[i] = KnnResult::squared_distance(
                                cloud.positions[i], cloud.positions[std::size_t(nb[k - 1])]);
                        }
                    });
                });
        }
    }
    median_scale();
    result.density_spacing = median_density_spacing(kth_sq, k);
    return result;
}

}  // namespace

bool normals_need_neighbours(const PointCloud& cloud, const NormalOptions& options) {
    return estimates_all(cloud, options) ||
           std::any_of(cloud.normals.begin(), cloud.normals.end(),
                       [](const Vec3f& v) { return is_zero(v); });
}

NormalResult estimate_normals(const PointCloud& cloud, const NormalOptions& options) {
    return estimate_normals_with(cloud, options, nullptr, nullptr);
}

NormalResult estimate_normals(const PointCloud& cloud, const NormalOptions& options,
                              const KnnResult& known_neighbours) {
    return estimate_normals_with(cloud, options, &known_neighbours, nullptr);
}

NormalResult estimate_normals(const PointCloud& cloud, const NormalOptions& options,
                              const std::vector<float>& known_spacing) {
    return estimate_normals_with(cloud, options, nullptr, &known_spacing);
}

}  // namespace vdbrecon
