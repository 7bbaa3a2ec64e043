// Normals and per-point scale (see normals.h for the method and references).
#include "vdbrecon/normals.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <queue>
#include <string>

#include "detail/normal_rules.h"
#include "detail/pca.h"
#include "detail/plane_count.h"
#include "detail/radix_sort.h"
#include "detail/select.h"
#include "detail/union_find.h"
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
    if (up) {
        const Vec3d& u = *up;
        if (!(std::isfinite(u[0]) && std::isfinite(u[1]) && std::isfinite(u[2]))) {
            throw InvalidArgument("normals.up: must be finite");
        }
        if (u[0] == 0.0 && u[1] == 0.0 && u[2] == 0.0) {
            throw InvalidArgument("normals.up: must not be the zero vector");
        }
        if (viewpoint) {
            throw InvalidArgument("normals: a viewpoint and an up direction were both given; "
                                  "give one");
        }
    }
}

namespace {

using detail::is_zero;

float dot(const Vec3f& a, const Vec3f& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

void flip(Vec3f& n) {
    for (float& c : n) c = -c;
}

/// A least-squares plane u . x = offset and its rms residual.
struct FitPlane {
    Eigen::Vector3d u = Eigen::Vector3d::Zero();
    double offset = 0.0, rms = 0.0;
};

/// The least-squares plane of the neighbours q[j] with take[j] (and of the point itself, at the
/// origin, when `with_point`). False with fewer than 3 points or a degenerate (linear) set.
bool fit_plane(const Eigen::Vector3d* q, int m, const bool* take, bool with_point,
               FitPlane& out) {
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    int count = with_point ? 1 : 0;
    for (int j = 0; j < m; ++j) {
        if (take[j]) {
            mean += q[j];
            ++count;
        }
    }
    if (count < 3) return false;
    mean /= double(count);
    Eigen::Matrix3d cov = with_point ? Eigen::Matrix3d(mean * mean.transpose())
                                     : Eigen::Matrix3d::Zero();
    for (int j = 0; j < m; ++j) {
        if (!take[j]) continue;
        const Eigen::Vector3d d = q[j] - mean;
        cov += d * d.transpose();
    }
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
    es.computeDirect(cov);  // closed form: several times faster than the iterative solver
    if (es.info() != Eigen::Success || !(es.eigenvalues()[1] > 1e-12 * es.eigenvalues()[2])) {
        return false;
    }
    out.u = es.eigenvectors().col(0);
    out.offset = out.u.dot(mean);
    out.rms = std::sqrt(std::max(0.0, es.eigenvalues()[0]) / count);
    return true;
}

/// The neighbourhood of a point (at the origin) around a sharp edge or corner: its neighbours'
/// positions q[0..m) and the tolerance of "on a plane".
struct Patch {
    const Eigen::Vector3d* q;
    int m;
    double tol;
    const detail::PlanePoints* axes;  ///< q by axis, for count_on

    bool on(const Eigen::Vector3d& u, double offset, int j, double band) const {
        return std::fabs(u.dot(q[j]) - offset) <= band;
    }
    bool on(const Eigen::Vector3d& u, double offset, int j) const { return on(u, offset, j, tol); }

    /// A crisp plane (a face of a sampled CAD part): its points lie within crisp_band() of it,
    /// and their least-squares fit within crisp_rms().
    double crisp_band() const { return 0.1 * tol; }
    double crisp_rms() const { return 0.05 * tol; }

    /// How many neighbours, each counted by its weight w[j] (1 or 0), are on() the plane
    /// u . x = offset within `band`, by the same arithmetic (detail::count_on_plane; the
    /// triples' inlier counts were most of the normal stage's time on overlapping scans).
    int count_on(const Eigen::Vector3d& u, double offset, double band, const double* w) const {
        const double v[3] = {u[0], u[1], u[2]};
        return detail::count_on_plane(*axes, w, v, offset, band);
    }

    /// The plane through three of the neighbours `among` (of the `nearest`, at most 16) that
    /// most of them lie on, within `band` (a deterministic RANSAC); returns how many, 0 with no
    /// plane.
    int triple_plane(const bool* among, double band, FitPlane& f, int nearest = 16) const {
        int best = 0;
        const int near = std::min({m, nearest, 16});
        double weight[64];
        detail::plane_weights(among, m, weight);
        for (int a = 0; a < near; ++a) {
            for (int b = a + 1; b < near && among[a]; ++b) {
                for (int c = b + 1; c < near && among[b]; ++c) {
                    if (!among[c]) continue;
                    Eigen::Vector3d u = (q[b] - q[a]).cross(q[c] - q[a]);
                    if (!(u.norm() > 0.0)) continue;
                    u.normalize();
                    const double off = u.dot(q[a]);
                    const int count = count_on(u, off, band, weight);
                    if (count > best) {
                        best = count;
                        f.u = u;
                        f.offset = off;
                    }
                }
            }
        }
        return best;
    }
};

/// The neighbours not on the point's own plane (`rest`) as one or two other crisp planes, each
/// 20 degrees or more off the own normal n: one plane through all of them first (their fit
/// within a twentieth of the tolerance), else the plane through three of them that most lie on
/// within a tenth (a deterministic RANSAC), refit to within a twentieth, and the same again for
/// what it leaves. False when the rest is no such set of planes. Fewer than three neighbours
/// off the own plane count as no other plane. (With the tolerance itself for "one plane", the
/// two other faces at a corner passed for one, which crisp_face then refused: the points
/// within a third of a voxel of a corner kept blended normals.)
bool other_planes(const Patch& p, const Eigen::Vector3d& n, bool* rest,
                  std::vector<FitPlane>& planes) {
    const double parallel = std::cos(20.0 * M_PI / 180.0);
    for (int round = 0; round < 2; ++round) {
        const int left = int(std::count(rest, rest + p.m, true));
        if (left < 3) return true;
        FitPlane f;
        if (!fit_plane(p.q, p.m, rest, false, f) || f.rms > p.crisp_rms()) {
            // The rest is not one plane: the plane through three of it with most inliers.
            if (p.triple_plane(rest, p.crisp_band(), f) < 3) return false;
            bool take[64] = {};
            for (int j = 0; j < p.m; ++j) {
                take[j] = rest[j] && p.on(f.u, f.offset, j, p.crisp_band());
            }
            if (!fit_plane(p.q, p.m, take, false, f) || f.rms > p.crisp_rms()) return false;
        }
        if (std::fabs(f.u.dot(n)) > parallel) return false;
        for (int j = 0; j < p.m; ++j) rest[j] = rest[j] && !p.on(f.u, f.offset, j);
        planes.push_back(f);
    }
    return std::count(rest, rest + p.m, true) < 3;
}

/// For a point with fewer than half its neighbours on its own plane (through it; those
/// neighbours are `own`): the index of another plane the point lies on, within a tenth of the
/// tolerance (an edge point: that plane's normal is as right as its own); else planes.size()
/// when it and two or more of its own neighbours lie off every other plane by more than half
/// the tolerance (a face of its own beside them); else -1. (Looser bounds, 2 tol and three
/// neighbours, gave other faces' normals to points up to 0.35 voxel from an edge, and with the
/// blended normals of corners they opened holes: 252 boundary edges against 196 over 60,000
/// samples of the cube, L-bracket and boss (3 seeds, 1x and 1.5x, mc and dc), 476 against 300
/// on the fan part at 1x with mc.)
int own_side(const Patch& p, const bool* own, const std::vector<FitPlane>& planes) {
    for (std::size_t f = 0; f < planes.size(); ++f) {
        if (std::fabs(planes[f].offset) <= p.crisp_band()) return int(f);
    }
    int off = 0;
    for (int j = 0; j < p.m; ++j) {
        if (!own[j]) continue;
        bool clear = true;
        for (const FitPlane& f : planes) {
            clear = clear && std::fabs(f.u.dot(p.q[j]) - f.offset) > 0.5 * p.tol;
        }
        off += clear;
    }
    return off >= 2 ? int(planes.size()) : -1;
}

/// The neighbourhood of point i: its k neighbours' positions relative to it (at most 64).
struct Neighbourhood {
    Eigen::Vector3d q[64];
    detail::PlanePoints axes;
    double ones[64];
    Patch patch{q, 0, 0.0, &axes};  // points into q and axes: not to be copied

    Neighbourhood(const Neighbourhood&) = delete;
    Neighbourhood& operator=(const Neighbourhood&) = delete;

    Neighbourhood(Span<Vec3f> pts, std::size_t i, const int* nb, int k) {
        const Vec3f& c = pts[i];
        const int m = std::min(k, 64);
        double reach = 0.0;
        for (int j = 0; j < m; ++j) {
            const Vec3f& p = pts[std::size_t(nb[j])];
            q[j] = Eigen::Vector3d(double(p[0]) - c[0], double(p[1]) - c[1], double(p[2]) - c[2]);
            reach += q[j].norm();
            axes.x[j] = q[j][0];
            axes.y[j] = q[j][1];
            axes.z[j] = q[j][2];
            ones[j] = 1.0;
        }
        axes.m = m;
        // "On a plane": within a tenth of the neighbours' mean distance.
        patch = Patch{q, m, 0.1 * reach / double(m), &axes};
    }
    /// Two or more neighbours within twice the tolerance of the point: they pin down little
    /// of a plane through it (tilted by 3 degrees or more, it still holds them within the
    /// crisp band), so the plane rests on the others, and the k nearest are too few to tell
    /// the point's own face at an edge or a corner. (A clump of
    /// three samples within 0.1 voxel on one face of the L-bracket's corner, 60k samples, seed
    /// 6: the plane through them and two points of the other faces outscored the face, which
    /// had one more point among the ten; the PCA blend left stayed, and the mesh opened.)
    bool crowded() const {
        int close = 0;
        for (int j = 0; j < patch.m; ++j) {
            close += q[j].squaredNorm() < 4.0 * patch.tol * patch.tol;
        }
        return close >= 2;
    }
    int inliers(const Eigen::Vector3d& u) const { return patch.count_on(u, 0.0, patch.tol, ones); }
    /// The truncated quadratic of MSAC (Torr & Zisserman 2000): neighbours nearer the plane
    /// count more, so a face whose points lie on it beats a plane tilted to graze a few points
    /// of both faces along an edge.
    double msac(const Eigen::Vector3d& u, double band) const {
        double score = 0.0;
        for (int j = 0; j < patch.m; ++j) score += msac_term(u.dot(q[j]), band);
        return score;
    }
    /// One neighbour's MSAC score at signed distance `d` from the plane.
    static double msac_term(double d, double band) {
        const double r = d / band;
        return std::max(0.0, 1.0 - r * r);
    }
    /// The planes through the point and two of its 10 nearest neighbours (not nearly
    /// collinear), in pair order: the candidates of best_plane. Returns their count (<= 45).
    int candidate_planes(Eigen::Vector3d (&u)[45]) const {
        int count = 0;
        const int pairs = std::min(patch.m, 10);
        for (int a = 0; a < pairs; ++a) {
            for (int b = a + 1; b < pairs; ++b) {
                Eigen::Vector3d v = q[a].cross(q[b]);
                const double len = v.norm();
                if (!(len > 0.3 * q[a].norm() * q[b].norm())) continue;  // nearly collinear
                u[count++] = v / len;
            }
        }
        return count;
    }
    /// The candidate scoring highest (the first of equals; zero when none scores above 0).
    static Eigen::Vector3d top_plane(const Eigen::Vector3d* u, const double* score, int count) {
        Eigen::Vector3d best = Eigen::Vector3d::Zero();
        double top = 0.0;
        for (int c = 0; c < count; ++c) {
            if (score[c] > top) {
                top = score[c];
                best = u[c];
            }
        }
        return best;
    }
    /// The plane through the point and two of its 10 nearest neighbours that scores highest
    /// (inlier count), by a deterministic RANSAC over all those pairs.
    template <typename Score>
    Eigen::Vector3d best_plane(Score score) const {
        Eigen::Vector3d u[45];
        double s[45];
        const int count = candidate_planes(u);
        for (int c = 0; c < count; ++c) s[c] = score(u[c]);
        return top_plane(u, s, count);
    }
    /// best_plane by the MSAC score within `band`: msac() of every candidate at once, a
    /// candidate per vector lane (the compiler's SSE2 loop over them), the neighbours in the
    /// same order and with the same operations as msac(), so the same scores to the bit.
    Eigen::Vector3d best_msac_plane(double band) const {
        Eigen::Vector3d u[45];
        const int count = candidate_planes(u);
        double ux[48], uy[48], uz[48], score[48] = {};
        for (int c = 0; c < count; ++c) {
            ux[c] = u[c][0];
            uy[c] = u[c][1];
            uz[c] = u[c][2];
        }
        for (int j = 0; j < patch.m; ++j) {
            const double qx = q[j][0], qy = q[j][1], qz = q[j][2];
            for (int c = 0; c < count; ++c) {
                score[c] += msac_term(ux[c] * qx + uy[c] * qy + uz[c] * qz, band);  // as dot()
            }
        }
        return top_plane(u, score, count);
    }
};

/// How a face (the point, at the origin, and the neighbours `own` on the plane through it with
/// normal u) meets another plane f.
struct Meeting {
    bool faces = false;        ///< each lies on one side of the other's plane (within tol)
    bool thin = false;         ///< ... opening by less than 60 degrees (a blade's tip)
    Eigen::Vector3d tip{0, 0, 0};  ///< the wedge's axis there: from the edge into both faces
};

/// Whether the face and the plane f meet as two faces at an edge: each lies on one side of the
/// other's plane, which a plane that merely slices through layers of points does not; and
/// their opening, the angle at the edge line between the directions to each face's points.
Meeting meeting(const Patch& p, const bool* own, const Eigen::Vector3d& u, const FitPlane& f) {
    auto one_side = [&](auto distance, auto member, bool with_point) {
        bool above = with_point && distance(Eigen::Vector3d::Zero()) > p.tol;
        bool below = with_point && distance(Eigen::Vector3d::Zero()) < -p.tol;
        for (int j = 0; j < p.m; ++j) {
            if (!member(j)) continue;
            const double d = distance(p.q[j]);
            above = above || d > p.tol;
            below = below || d < -p.tol;
        }
        return !(above && below);
    };
    Meeting out;
    if (!one_side([&](const Eigen::Vector3d& x) { return f.u.dot(x) - f.offset; },
                  [&](int j) { return own[j]; }, true) ||
        !one_side([&](const Eigen::Vector3d& x) { return u.dot(x); },
                  [&](int j) { return p.on(f.u, f.offset, j); }, false)) {
        return out;
    }
    const double c = u.dot(f.u);
    const Eigen::Vector3d d = u.cross(f.u).normalized();
    const Eigen::Vector3d x = f.offset / (1.0 - c * c) * (f.u - c * u);  // on the edge line
    Eigen::Vector3d a = -x, b = Eigen::Vector3d::Zero();  // the point itself is on its face
    int nb = 0;
    for (int j = 0; j < p.m; ++j) {
        if (own[j]) {
            a += p.q[j] - x;
        } else if (p.on(f.u, f.offset, j)) {
            b += p.q[j] - x;
            ++nb;
        }
    }
    if (nb == 0) return out;
    a -= a.dot(d) * d;
    b -= b.dot(d) * d;
    out.faces = a.norm() > 0.0 && b.norm() > 0.0;
    out.thin = a.dot(b) > 0.5 * a.norm() * b.norm();  // cos 60 degrees
    out.tip = (a.normalized() + b.normalized()).normalized();
    return out;
}

/// The crisp case of face_normal (a sampled CAD part; a scan's noise or curvature is not crisp):
/// the plane through the point chosen by MSAC within a band of a tenth of the tolerance,
/// scoring at least the PCA plane's, its points in that band a plane to within 1/200 of the
/// neighbours' distance, and the rest on one or two other crisp planes that meet it as faces
/// (an edge or a corner; meeting). With fewer than half the neighbours on its own face the
/// point must lie clear of the others (own_side), or on one of them, whose normal it then takes
/// (at a thin wedge's tip, the wedge's axis).
bool crisp_face(const Neighbourhood& h, const Eigen::Vector3d& pca, Eigen::Vector3d& n,
                bool* puzzled = nullptr) {
    const Patch& p = h.patch;
    const double band = p.crisp_band();
    const Eigen::Vector3d u = h.best_msac_plane(band);
    if (h.msac(u, band) < h.msac(pca, band)) return false;
    // Its own points: those within the band (points of a neighbouring face near the edge can
    // be within the tolerance), four or more (three at a corner), and a plane to within a
    // twentieth of the tolerance (a scan of a curved surface is not).
    bool own[64] = {}, rest[64] = {};
    int best = 0;
    for (int j = 0; j < p.m; ++j) {
        own[j] = p.on(u, 0.0, j, band);
        rest[j] = !own[j];
        best += own[j];
    }
    FitPlane fit;
    if (best < 3 || !fit_plane(p.q, p.m, own, true, fit) || fit.rms > p.crisp_rms()) return false;
    // From here on: a crisp plane through the point that the rest of the neighbours does not
    // explain (face_normal may look wider).
    if (puzzled) *puzzled = true;
    std::vector<FitPlane> planes;
    if (!other_planes(p, u, rest, planes)) return false;
    if (best < 4 && planes.size() < 2) return false;  // three points make any plane
    std::vector<Meeting> meets;  // the planes are crisp (other_planes)
    for (const FitPlane& f : planes) {
        meets.push_back(meeting(p, own, u, f));
        if (!meets.back().faces) return false;
    }
    if (2 * best < p.m) {
        if (planes.empty()) return false;
        const int side = own_side(p, own, planes);
        if (side < 0) return false;
        if (side < int(planes.size())) {  // on that plane too: an edge point
            // At the tip of a thin wedge neither face's normal relates to both faces as the
            // orientation needs (a chord within one face from a point with the other's normal
            // reads as a fold); the wedge's axis does, as a rounded tip's normal would.
            n = meets[std::size_t(side)].thin ? meets[std::size_t(side)].tip
                                              : planes[std::size_t(side)].u;
            return true;
        }
    }
    n = fit.u;
    return true;
}

/// Whether the point lies off a crisp plane that half its neighbours or more lie on (by more
/// than a tenth of the tolerance; the plane through three neighbours that most lie on within a
/// tenth of the tolerance, refit on those to within a twentieth): a point of a face that few of
/// its k neighbours share, next to an edge or a corner of a sampled part, where crisp_face
/// found no face of its own. A wider neighbourhood may show it (wider_look). (All but three
/// neighbours on the plane, as before, missed the points whose neighbours lie on two other
/// faces, next to corners and blade tips: dc's Hausdorff distance on the fan part with
/// estimated normals, 200k samples, seeds 1-4, 1x-3x, averaged 0.69 voxel, now 0.31. And a
/// least-squares fit that dropped the three farthest one by one tilted towards the few and
/// dropped three of the many: at a blade tip two points of one face with eight of the other for
/// neighbours kept a blended normal.)
bool beside_crisp_plane(const Neighbourhood& h) {
    const Patch& p = h.patch;
    if (p.m < 9) return false;
    bool all[64], take[64];
    std::fill(all, all + p.m, true);
    FitPlane f;
    // Half of them or more on the plane: three of those are among the m - m/2 + 3 nearest.
    const int half = (p.m + 1) / 2;
    if (p.triple_plane(all, p.crisp_band(), f, p.m - half + 3) < half) return false;
    for (int j = 0; j < p.m; ++j) take[j] = p.on(f.u, f.offset, j, p.crisp_band());
    return fit_plane(p.q, p.m, take, false, f) && f.rms <= p.crisp_rms() &&
           std::fabs(f.offset) > p.crisp_band();
}

/// Next to a sharp edge or corner the k neighbours of a point span two or three faces and their
/// PCA normal blends them. There the point's own face is the plane through it that most
/// neighbours lie on (within a tenth of their mean distance), found by a deterministic RANSAC
/// over the planes through the point and two of its nearest neighbours (in the spirit of robust
/// normal estimation next to sharp features, Li et al. 2010): crisp_face where the faces are
/// crisp; elsewhere (noise) only where the neighbourhood is two clean planes: half the
/// neighbours or more on the first, 1.5x the PCA plane's inliers, and the rest on one plane
/// within the tolerance, 20 degrees or more off the first. A noisy but smooth patch (or
/// overlapping scans) keeps its PCA normal. `variation` is the PCA's lambda_0 / sum lambda.
/// `wider`: whether the point is beside a crisp plane (beside_crisp_plane), asked where the
/// variation is above 0.02 as the non-crisp case is (a neighbourhood folding over an edge:
/// 0.05-0.15; asked at every point above 0.002, the room scan's normals took 0.53-0.59 ->
/// 0.63-0.71 s, and its mesh was no better).
bool face_normal(Span<Vec3f> pts, std::size_t i, const int* nb, int k, const Eigen::Vector3d& pca,
                 double variation, Eigen::Vector3d& n, bool& crisp, bool* wider) {
    const Neighbourhood h(pts, i, nb, k);
    bool puzzled = false;
    if (crisp_face(h, pca, n, &puzzled)) {
        crisp = true;
        return true;
    }
    if (wider) *wider = puzzled && h.crowded();
    if (variation <= 0.02) return false;
    if (wider && !*wider) *wider = beside_crisp_plane(h);
    const Patch& p = h.patch;
    n = h.best_plane([&](const Eigen::Vector3d& v) { return double(h.inliers(v)); });
    const int best = h.inliers(n);
    if (2 * best < p.m || 2 * best < 3 * h.inliers(pca)) return false;
    bool own[64] = {}, rest[64] = {};
    for (int j = 0; j < p.m; ++j) {
        own[j] = p.on(n, 0.0, j);
        rest[j] = !own[j];
    }
    FitPlane other;
    if (fit_plane(p.q, p.m, rest, false, other)) {  // the other face: one plane, clearly another
        if (other.rms > p.tol || std::fabs(other.u.dot(n)) > std::cos(20.0 * M_PI / 180.0)) {
            return false;
        }
    } else if (p.m - best >= 3) {
        return false;  // the rest is no plane
    }
    FitPlane fit;
    if (fit_plane(p.q, p.m, own, true, fit)) n = fit.u;
    return true;
}

}  // namespace

/// PCA normal of point i and its neighbours; next to a sharp edge, its face's (face_normal).
bool detail::neighbourhood_normal(Span<Vec3f> pts, std::size_t i, const int* nb, int k,
                                  Vec3f& normal, float& doubt, bool* wider) {
    Eigen::Vector3d ev, n;
    if (!detail::neighbourhood_pca(pts, i, nb, k, ev, n)) return false;
    // Degenerate: all points coincide, or they lie on a line (two vanishing eigenvalues).
    if (!(ev[2] > 0.0) || ev[1] <= 1e-12 * ev[2]) return false;
    n.normalize();
    // Surface variation lambda_0 / sum lambda (Pauly 2002): ~0 on a plane, 0.05-0.15 where the
    // neighbourhood folds over an edge; face_normal looks for faces above 0.002 (crisp ones)
    // and 0.02 (noisy ones). `doubt`, how far the orientation (orient_mst) may trust the
    // normal: the variation, 0 for a crisp face's normal.
    Eigen::Vector3d face;
    const double v = ev[0] / (ev[0] + ev[1] + ev[2]);
    bool crisp = false;
    if (v > 0.002 && face_normal(pts, i, nb, k, n, v, face, crisp, wider)) n = face;
    doubt = crisp ? 0.0f : float(v);
    normal = {float(n[0]), float(n[1]), float(n[2])};
    return std::isfinite(normal[0]) && std::isfinite(normal[1]) && std::isfinite(normal[2]);
}

namespace {

/// A set of point indices, cleared in O(1): open addressing over a table that marks its entries
/// with the generation they were added in (for the few hundred points two hops from one point).
class SeenSet {
  public:
    void clear() {
        if (++generation_ == 0) {  // wrapped: no stale entry may pass for a current one
            std::fill(table_.begin(), table_.end(), Slot{0, 0});
            generation_ = 1;
        }
        size_ = 0;
    }
    /// Adds i; false when it was there already.
    bool insert(std::int32_t i) {
        if (2 * (size_ + 1) > table_.size()) grow();
        const std::size_t mask = table_.size() - 1;
        for (std::size_t at = hash(i) & mask;; at = (at + 1) & mask) {
            Slot& s = table_[at];
            if (s.generation != generation_) {
                s = Slot{generation_, i};
                ++size_;
                return true;
            }
            if (s.index == i) return false;
        }
    }

  private:
    struct Slot {
        std::uint32_t generation;
        std::int32_t index;
    };
    static std::size_t hash(std::int32_t i) { return std::uint32_t(i) * 2654435761u >> 8; }
    void grow() {
        std::vector<Slot> old;
        old.swap(table_);
        table_.assign(std::max<std::size_t>(1024, 2 * old.size()), Slot{0, 0});
        size_ = 0;
        for (const Slot& s : old) {
            if (s.generation == generation_) insert(s.index);
        }
    }
    std::vector<Slot> table_;
    std::uint32_t generation_ = 1;
    std::size_t size_ = 0;
};

/// Point i's k nearest and their k nearest (i itself left out), each once, sorted by squared
/// distance to i, then index: the candidates of the wider look, found with no second search.
void two_hop_ring(Span<Vec3f> pts, std::size_t i, int k,
                  const std::function<const int*(std::size_t)>& list,
                  std::vector<std::pair<float, int>>& ring) {
    // Each point once (most are reached through several neighbours), then sorted.
    thread_local SeenSet seen;
    seen.clear();
    ring.clear();
    const int* own = list(i);
    for (int j = 0; j < k; ++j) {
        const int a = own[j];
        if (seen.insert(a)) {
            ring.push_back({KnnResult::squared_distance(pts[i], pts[std::size_t(a)]), a});
        }
        const int* theirs = list(std::size_t(a));
        for (int l = 0; l < k; ++l) {
            const int c = theirs[l];
            if (std::size_t(c) == i || !seen.insert(c)) continue;
            ring.push_back({KnnResult::squared_distance(pts[i], pts[std::size_t(c)]), c});
        }
    }
    std::sort(ring.begin(), ring.end());
}

}  // namespace

/// The wider look (see normal_rules.h).
bool detail::wider_normal(Span<Vec3f> pts, std::size_t i, int k,
                          const std::function<const int*(std::size_t)>& list, Vec3f& normal) {
    const int wide = std::min(3 * k, 64);
    if (wide <= k) return false;
    std::vector<std::pair<float, int>> ring;
    two_hop_ring(pts, i, k, list, ring);
    const int m = std::min<int>(wide, int(ring.size()));
    if (m <= k) return false;
    std::vector<int> nb(static_cast<std::size_t>(m));
    for (int j = 0; j < m; ++j) nb[std::size_t(j)] = ring[std::size_t(j)].second;
    Eigen::Vector3d ev, pca, n;
    if (!detail::neighbourhood_pca(pts, i, nb.data(), m, ev, pca)) return false;
    const Neighbourhood h(pts, i, nb.data(), m);
    if (!crisp_face(h, pca.normalized(), n)) return false;
    normal = {float(n[0]), float(n[1]), float(n[2])};
    return true;
}

void detail::report_degenerate(std::size_t bad, std::size_t n) {
    if (bad > 0) {
        log_warning("normals: " + std::to_string(bad) +
                    " points have degenerate neighbourhoods (coincident or collinear) and "
                    "get no normal");
    }
    if (bad == n) {
        throw NumericalError("normals: every neighbourhood is degenerate (all points "
                             "coincident or collinear); no surface can be reconstructed");
    }
}

bool detail::orient_locally(const NormalOptions& options, const Vec3d& origin, const Vec3f& p,
                            Vec3f& normal) {
    Vec3f toward;
    if (options.up) {
        const Vec3d& u = *options.up;
        toward = {float(u[0]), float(u[1]), float(u[2])};
    } else {
        const Vec3d& v = *options.viewpoint;
        toward = {float(v[0] - origin[0] - p[0]), float(v[1] - origin[1] - p[1]),
                  float(v[2] - origin[2] - p[2])};
    }
    if (!(dot(normal, toward) < 0.0f)) return false;
    flip(normal);
    return true;
}

namespace {

/// Two readings of how the normal n_j at p_j agrees with n_i at p_i, each in -1..1 (negative:
/// one of them is flipped): Hoppe's n_i . n_j, and the mirror's. On a circle through both
/// points the normal at p_j is the one at p_i mirrored at the plane that bisects the chord
/// e = p_j - p_i, so n_i is mirrored so before it is compared (the criterion of S. Koenig and
/// S. Gumhold, "Consistent propagation of normal orientations in point clouds", VMV 2009). On
/// flat ground both are alike; unlike Hoppe's, the mirror stays near +1 across a sharp edge
/// turning by more than 90 degrees (a 40-degree blade tip: n_i . n_j = -0.77), where Hoppe's
/// rule flips one side.
struct Readings {
    float hoppe, mirror;
    /// The chord runs within 53 degrees of a normal: as likely to cross a layer of scanner
    /// noise (two misregistered scans of one surface) as a thin wall, where the mirror would
    /// turn the layers against each other.
    bool cone;

    Readings(const Vec3f& pi, const Vec3f& ni, const Vec3f& pj, const Vec3f& nj)
        : hoppe(dot(ni, nj)), mirror(hoppe), cone(false) {
        const Vec3f e = {pj[0] - pi[0], pj[1] - pi[1], pj[2] - pi[2]};
        const float len2 = dot(e, e);
        if (!(len2 > 0.0f)) return;
        const float inv = 1.0f / std::sqrt(len2);
        const float ei = dot(ni, e) * inv, ej = dot(nj, e) * inv;
        mirror = hoppe - 2.0f * ei * ej;
        cone = std::max(std::fabs(ei), std::fabs(ej)) > 0.6f;
    }

    /// The agreement the orientation follows: the mirror's, and in the cone Hoppe's. Bunny
    /// scans: 99.31 % of estimated normals agree with the scanner's under Hoppe's rule,
    /// 93.9 % with the mirror everywhere, 99.28 % so; the fan part's blades: 31.1 %, 99.7 %,
    /// 99.7 %.
    float agreement() const { return cone ? hoppe : mirror; }

    /// In the cone, the two readings disagree in sign: one of them is wrong.
    bool torn() const { return cone && (mirror < 0.0f) != (hoppe < 0.0f); }

    /// The cost of propagating the orientation along this pair in the spanning tree:
    /// 1 - |agreement|; in the cone, 1 (the last resort) when the readings disagree in sign
    /// (across a thin wedge with crisp face normals -- a 40-degree blade tip: Hoppe -0.77,
    /// mirror +1.0 -- as across layers of noise -- Hoppe +0.95, mirror -0.9 -- one of them is
    /// wrong, and the tree goes round by surer edges where it can), else by the better fit
    /// (a 90-degree edge between crisp faces: Hoppe 0.1, mirror 1.0).
    float cost() const {
        if (!cone) return 1.0f - std::min(1.0f, std::fabs(mirror));
        if (torn()) return 1.0f;
        return 1.0f - std::min(1.0f, std::max(std::fabs(hoppe), std::fabs(mirror)));
    }
};

/// Whether a component's normals point out of the volume it encloses: the flux of the normals,
/// sum n . (p - c) over its points p (c: their centroid), is 3x the enclosed volume for a closed
/// surface sampled uniformly with outward normals (the divergence theorem), whatever its shape.
/// +1 or -1 where it is clear (a fifth or more of sum |n . (p - c)|), 0 where it is not (an
/// open patch such as a terrain, whose seed's "up and out" then stands).
int outward_flux(Span<Vec3f> pts, const std::vector<Vec3f>& normals,
                 const std::vector<std::int32_t>& members) {
    Eigen::Vector3d c = Eigen::Vector3d::Zero();
    for (std::int32_t m : members) {
        const Vec3f& p = pts[std::size_t(m)];
        c += Eigen::Vector3d(p[0], p[1], p[2]);
    }
    c /= double(members.size());
    double flux = 0.0, total = 0.0;
    for (std::int32_t m : members) {
        const Vec3f& p = pts[std::size_t(m)];
        const Vec3f& nm = normals[std::size_t(m)];
        const double f = nm[0] * (p[0] - c[0]) + nm[1] * (p[1] - c[1]) + nm[2] * (p[2] - c[2]);
        flux += f;
        total += std::fabs(f);
    }
    if (!(std::fabs(flux) >= 0.2 * total) || total == 0.0) return 0;
    return flux > 0.0 ? 1 : -1;
}

/// The sign a component grown from a free seed takes (+1 as grown, -1 turned round), by what
/// it is: an open sheet whose normals face mostly one way along z (their mean, each weighted by
/// the area it stands for, the squared distance to its k-th neighbour, is 0.5 or more along z:
/// a terrain, a floor, a roof; a closed surface's is 0) faces up; else a closed object faces
/// out where its flux says so clearly (outward_flux); else the seed's sign stands. The flux
/// alone would turn a terrain over wherever trees or roofs lift the centroid above the ground.
int component_sign(Span<Vec3f> pts, const std::vector<Vec3f>& normals, const KnnResult& knn,
                   const std::vector<std::int32_t>& members, NormalResult& result) {
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    double total = 0.0;
    for (std::int32_t m : members) {
        const Vec3f& nm = normals[std::size_t(m)];
        const double a = knn.k > 0 ? double(knn.sq_dist(pts, std::size_t(m), knn.k - 1)) : 1.0;
        mean += a * Eigen::Vector3d(nm[0], nm[1], nm[2]);
        total += a;
    }
    if (total > 0.0 && std::fabs(mean[2]) >= 0.5 * total) {
        ++result.components_up;
        return mean[2] > 0.0 ? 1 : -1;
    }
    const int flux = outward_flux(pts, normals, members);
    ++(flux != 0 ? result.components_flux : result.components_seed);
    return flux >= 0 ? 1 : -1;
}

/// The symmetric kNN graph in CSR form: point i's neighbours (its own and those that have it
/// as theirs) are adj[start[i] .. start[i + 1]).
std::vector<std::int32_t> symmetric_adjacency(const KnnResult& knn, std::size_t n,
                                              std::vector<std::size_t>& start) {
    std::vector<std::uint32_t> degree(n + 1, 0);
    for (std::size_t i = 0; i < n; ++i) {
        const int* nb = knn.neighbours(i);
        for (int j = 0; j < knn.k; ++j) {
            ++degree[i];
            ++degree[std::size_t(nb[j])];
        }
    }
    start.assign(n + 1, 0);
    for (std::size_t i = 0; i < n; ++i) start[i + 1] = start[i] + degree[i];
    std::vector<std::int32_t> adj(start[n]);
    std::vector<std::size_t> fill(start.begin(), start.end() - 1);
    for (std::size_t i = 0; i < n; ++i) {
        const int* nb = knn.neighbours(i);
        for (int j = 0; j < knn.k; ++j) {
            adj[fill[i]++] = nb[j];
            adj[fill[std::size_t(nb[j])]++] = std::int32_t(i);
        }
    }
    return adj;
}

enum : char { kExcluded = 0, kFree = 1, kFixed = 2 };

/// Bridges for the points with a torn edge in the kNN graph (Readings::torn): up to kBridges
/// edges to the nearest points two hops away, not yet their neighbours, that lie on the
/// point's own plane (normals' lines within 14 degrees, the chord within 6 degrees of both
/// planes). At a thin wedge's tip (a 40-degree blade) a patch of points has for its k nearest
/// itself and the points of the other face across the tip, where Hoppe's reading and the
/// mirror's disagree; the rest of its own face lies 1.5-2 voxels on, beyond its lists.
/// Without a bridge the tree reaches the patch only across the tip and may turn it against its
/// face (21 normals on the fan part, 200k samples, seed 1, all of them in such patches; 0 with
/// the bridges). A bridge's chord lies in the plane, out of the cone, where both readings agree.
/// Returned as pairs (i, j), i < j, sorted.
std::vector<std::pair<std::int32_t, std::int32_t>> coplanar_bridges(
    Span<Vec3f> pts, const std::vector<Vec3f>& normals, const std::vector<char>& state,
    const std::vector<std::int32_t>& adj, const std::vector<std::size_t>& start) {
    constexpr float kParallel = 0.97f, kInPlane = 0.1f;
    constexpr int kBridges = 3;
    const std::size_t n = pts.size();
    std::vector<std::int32_t> found(n * kBridges, -1);
    auto in_plane = [&](std::size_t i, std::size_t j, float& d2) {
        const Vec3f e = {pts[j][0] - pts[i][0], pts[j][1] - pts[i][1], pts[j][2] - pts[i][2]};
        d2 = dot(e, e);
        const float lim = kInPlane * kInPlane * d2;
        const float a = dot(normals[i], e), b = dot(normals[j], e);
        return d2 > 0.0f && a * a <= lim && b * b <= lim &&
               std::fabs(dot(normals[i], normals[j])) >= kParallel;
    };
    tbb::enumerable_thread_specific<SeenSet> seen_sets;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1024),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        std::vector<std::pair<float, std::int32_t>> cand;
        SeenSet& seen = seen_sets.local();
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            if (state[i] == kExcluded) continue;
            bool torn = false;
            for (std::size_t e = start[i]; e < start[i + 1] && !torn; ++e) {
                const std::size_t j = std::size_t(adj[e]);
                torn = state[j] != kExcluded &&
                       Readings(pts[i], normals[i], pts[j], normals[j]).torn();
            }
            if (!torn) continue;
            // Each point two hops away once (most are reached through several neighbours).
            cand.clear();
            seen.clear();
            for (std::size_t e = start[i]; e < start[i + 1]; ++e) {
                const std::size_t h = std::size_t(adj[e]);
                for (std::size_t f = start[h]; f < start[h + 1]; ++f) {
                    const std::size_t j = std::size_t(adj[f]);
                    float d2;
                    if (j != i && state[j] != kExcluded && seen.insert(std::int32_t(j)) &&
                        in_plane(i, j, d2)) {
                        cand.push_back({d2, std::int32_t(j)});
                    }
                }
            }
            // The kBridges nearest distinct candidates, by (distance, index), that are not an
            // edge already: one pass keeping them in order (a point reached twice is the same
            // pair twice), not a sort of them all.
            std::pair<float, std::int32_t> best[kBridges];
            int taken = 0;
            for (const auto& c : cand) {
                if (taken == kBridges && !(c < best[kBridges - 1])) continue;
                if (std::find(best, best + taken, c) != best + taken) continue;
                if (std::find(adj.begin() + std::ptrdiff_t(start[i]),
                              adj.begin() + std::ptrdiff_t(start[i + 1]), c.second) !=
                    adj.begin() + std::ptrdiff_t(start[i + 1])) {
                    continue;  // an edge already
                }
                int at = taken < kBridges ? taken++ : kBridges - 1;
                for (; at > 0 && c < best[at - 1]; --at) best[at] = best[at - 1];
                best[at] = c;
            }
            for (int t = 0; t < taken; ++t) found[i * kBridges + std::size_t(t)] = best[t].second;
        }
    });
    std::vector<std::pair<std::int32_t, std::int32_t>> bridges;
    for (std::size_t i = 0; i < n; ++i) {
        for (int c = 0; c < kBridges; ++c) {
            const std::int32_t j = found[i * kBridges + std::size_t(c)];
            if (j >= 0) {
                bridges.push_back({std::min(std::int32_t(i), j), std::max(std::int32_t(i), j)});
            }
        }
    }
    tbb::parallel_sort(bridges.begin(), bridges.end());
    bridges.erase(std::unique(bridges.begin(), bridges.end()), bridges.end());
    return bridges;
}

/// The CSR graph (adj, start) with the edges `extra` added both ways.
void add_edges(std::vector<std::int32_t>& adj, std::vector<std::size_t>& start,
               const std::vector<std::pair<std::int32_t, std::int32_t>>& extra) {
    if (extra.empty()) return;
    const std::size_t n = start.size() - 1;
    std::vector<std::size_t> degree(n, 0);
    for (const auto& e : extra) {
        ++degree[std::size_t(e.first)];
        ++degree[std::size_t(e.second)];
    }
    std::vector<std::size_t> grown(n + 1, 0);
    for (std::size_t i = 0; i < n; ++i) {
        grown[i + 1] = grown[i] + (start[i + 1] - start[i]) + degree[i];
    }
    std::vector<std::int32_t> out(grown[n]);
    std::vector<std::size_t> fill(n);
    for (std::size_t i = 0; i < n; ++i) {
        fill[i] = std::copy(adj.begin() + std::ptrdiff_t(start[i]),
                            adj.begin() + std::ptrdiff_t(start[i + 1]),
                            out.begin() + std::ptrdiff_t(grown[i])) - out.begin();
    }
    for (const auto& e : extra) {
        out[fill[std::size_t(e.first)]++] = e.second;
        out[fill[std::size_t(e.second)]++] = e.first;
    }
    adj.swap(out);
    start.swap(grown);
}

/// Every entry (i, adj[e]) of the orientation graph read once, with the normals as estimated:
/// the cost of propagating the orientation along it -- Readings::cost plus the endpoints' doubt
/// (x10, at most 1) -- and its lean: the sign of its agreement, doubled where the edge is sure
/// (the reading the sign follows at 0.9 or more, not torn, cost below 0.1); 0 where an
/// endpoint is excluded. Turning either normal turns the lean, not the cost.
struct EdgeReadings {
    std::vector<float> cost;
    std::vector<signed char> lean;

    EdgeReadings(Span<Vec3f> pts, const std::vector<Vec3f>& normals,
                 const std::vector<float>& doubt, const std::vector<std::int32_t>& adj,
                 const std::vector<std::size_t>& start, const std::vector<char>& state)
        : cost(adj.size(), 1.0f), lean(adj.size(), 0) {
        constexpr float kSure = 0.9f, kSureCost = 0.1f;
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, pts.size(), 1024),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t i = r.begin(); i < r.end(); ++i) {
                if (state[i] == kExcluded) continue;
                for (std::size_t e = start[i]; e < start[i + 1]; ++e) {
                    const std::size_t j = std::size_t(adj[e]);
                    if (state[j] == kExcluded) continue;
                    const Readings rd(pts[i], normals[i], pts[j], normals[j]);
                    cost[e] = rd.cost() + std::min(1.0f, 10.0f * (doubt[i] + doubt[j]));
                    const float a = rd.agreement();
                    const bool sure = !rd.torn() && std::fabs(a) >= kSure && cost[e] < kSureCost;
                    lean[e] = static_cast<signed char>((a < 0.0f ? -1 : 1) * (sure ? 2 : 1));
                }
            }
        });
    }

    /// The sign of entry e's agreement once the normals of its ends have been turned as
    /// `turned` says.
    int sign(std::size_t e, char turned_i, char turned_j) const {
        return (lean[e] < 0) != (turned_i != turned_j) ? -1 : 1;
    }
};

/// What Prim's tree (grow_tree) leaves: per point its parent in the tree (-1 for a seed and for
/// points not free), the component it was grown in (-1: from fixed points, or not free), and
/// per component grown from a free seed, that seed.
struct OrientTree {
    std::vector<std::int32_t> parent, component;
    std::vector<std::int32_t> seeds;
};

/// Hoppe-style orientation: Prim's minimum spanning tree over the graph (adj, start) by the
/// readings' cost, propagating the sign along tree edges. Points in state kFree are
/// re-oriented; kFixed points (already oriented) seed their neighbourhoods; kExcluded points (no
/// normal) take no part. The remaining components are seeded at their highest point, its normal
/// turned away from the centroid. Each free point's flip toggles turned[i].
OrientTree grow_tree(Span<Vec3f> pts, std::vector<Vec3f>& normals, const EdgeReadings& readings,
                     const std::vector<std::int32_t>& adj, const std::vector<std::size_t>& start,
                     const std::vector<char>& state, std::vector<char>& turned) {
    const std::size_t n = pts.size();
    OrientTree tree;
    tree.parent.assign(n, -1);
    tree.component.assign(n, -1);
    // 16 bytes: the entry's lean is all the sign needs (EdgeReadings::sign).
    struct Edge {
        float cost;
        std::int32_t to, from;
        bool against;  // readings.lean[e] < 0
        bool operator>(const Edge& o) const {
            if (cost != o.cost) return cost > o.cost;
            if (to != o.to) return to > o.to;
            return from > o.from;
        }
    };
    std::priority_queue<Edge, std::vector<Edge>, std::greater<Edge>> heap;
    std::vector<char> done(n, 0);
    // The least edge to each point pushed so far (cost, then from): one that would not come
    // before it is not pushed, which leaves the tree as it is and the heap a third the size.
    const std::pair<float, std::int32_t> none(std::numeric_limits<float>::infinity(),
                                              std::numeric_limits<std::int32_t>::max());
    std::vector<std::pair<float, std::int32_t>> least(n, none);
    // Through surer points first: a blended normal where the neighbourhood folds over an edge is
    // the least reliable (its doubt), and as a leaf of the tree it turns only itself.
    auto push_neighbours = [&](std::size_t i) {
        for (std::size_t e = start[i]; e < start[i + 1]; ++e) {
            const std::size_t j = std::size_t(adj[e]);
            if (done[j]) continue;  // so is every point not free
            const std::pair<float, std::int32_t> key(readings.cost[e], std::int32_t(i));
            if (!(key < least[j])) continue;
            least[j] = key;
            heap.push({key.first, std::int32_t(j), key.second, readings.lean[e] < 0});
        }
    };
    auto grow = [&](std::int32_t component) {
        while (!heap.empty()) {
            const Edge e = heap.top();
            heap.pop();
            const std::size_t j = std::size_t(e.to);
            if (done[j]) continue;
            done[j] = 1;
            tree.parent[j] = e.from;
            tree.component[j] = component;
            if (e.against != (turned[std::size_t(e.from)] != turned[j])) {
                flip(normals[j]);
                turned[j] ^= 1;
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
    grow(-1);

    // Remaining components: seed at the highest unvisited point, normal turned away from the
    // cloud's centroid (for the top of a closed object that is "up and out").
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const Vec3f& p : pts) centroid += Eigen::Vector3d(p[0], p[1], p[2]);
    centroid /= double(n);
    std::vector<std::int32_t> order(n);
    for (std::size_t i = 0; i < n; ++i) order[i] = std::int32_t(i);
    tbb::parallel_sort(order.begin(), order.end(), [&](std::int32_t a, std::int32_t b) {
        if (pts[std::size_t(a)][2] != pts[std::size_t(b)][2]) {
            return pts[std::size_t(a)][2] > pts[std::size_t(b)][2];
        }
        return a < b;
    });
    for (std::int32_t s : order) {
        const std::size_t i = std::size_t(s);
        if (done[i]) continue;
        const std::int32_t c = std::int32_t(tree.seeds.size());
        tree.seeds.push_back(s);
        done[i] = 1;
        tree.component[i] = c;
        const Vec3f& p = pts[i];
        Vec3f out = {float(p[0] - centroid[0]), float(p[1] - centroid[1]),
                     float(p[2] - centroid[2])};
        if (dot(out, out) == 0.0f) out = {0.0f, 0.0f, 1.0f};
        if (dot(normals[i], out) < 0.0f) {
            flip(normals[i]);
            turned[i] ^= 1;
        }
        push_neighbours(i);
        grow(c);
    }
    return tree;
}

/// Patches of points the tree oriented with certainty, and the links between them.
struct Patches {
    struct Link {
        std::int32_t to;  // the patch linked to
        float strength;   // the best pair's 1 - cost
        double vote;      // the summed vote of the pairs near the best
    };
    std::vector<std::int32_t> of;    // per point its patch, -1 where excluded
    std::vector<char> anchored;      // per patch: holds a fixed point
    std::vector<std::size_t> start;  // the links in CSR form: patch p's are
    std::vector<Link> links;         // links[start[p] .. start[p + 1])
};

/// A graph edge between two patches: its cost and its vote (sure_patches).
struct Pair {
    std::int32_t a, b;  // the patches, a < b
    float cost;
    double vote;
};

/// The links between patches from the pairs across them: a link's strength is its best pair's
/// 1 - cost, its vote the sum over the pairs within kNear of the best cost. Not the best
/// pair alone: at a corner whose faces meet at 95 degrees, one edge convex and one concave, a
/// pair of points on two faces with no edge between them reads 0.79 in the mirror for the
/// wrong sign, and the next 15 pairs across that face's border (0.38-0.48) for the right one
/// (the fan part, 60k samples, seed 7). Not every pair: at a 40-degree blade tip the many
/// lopsided pairs across the tip read the wrong sign at 0.5-0.75 (the mirror holds only where
/// both points lie as far from the tip), and the tip is the weakest link between its faces.
void link_patches(std::vector<Pair>& pairs, Patches& patches) {
    constexpr float kNear = 0.25f;
    // A total order (pairs equal in it are equal), so the parallel sort's result is unique.
    tbb::parallel_sort(pairs.begin(), pairs.end(), [](const Pair& x, const Pair& y) {
        if (x.a != y.a) return x.a < y.a;
        if (x.b != y.b) return x.b < y.b;
        if (x.cost != y.cost) return x.cost < y.cost;
        return x.vote < y.vote;
    });
    // One link per patch pair, in place of its first pair: cost = best, vote = summed near it.
    std::size_t links = 0;
    for (std::size_t r = 0; r < pairs.size(); ++r) {
        const Pair p = pairs[r];
        if (links > 0 && pairs[links - 1].a == p.a && pairs[links - 1].b == p.b) {
            if (p.cost <= pairs[links - 1].cost + kNear) pairs[links - 1].vote += p.vote;
        } else {
            pairs[links++] = p;
        }
    }
    pairs.resize(links);
    const std::size_t count = patches.anchored.size();
    patches.start.assign(count + 1, 0);
    for (const Pair& l : pairs) {
        ++patches.start[std::size_t(l.a) + 1];
        ++patches.start[std::size_t(l.b) + 1];
    }
    for (std::size_t p = 0; p < count; ++p) patches.start[p + 1] += patches.start[p];
    patches.links.resize(patches.start.back());
    std::vector<std::size_t> fill(patches.start.begin(), patches.start.end() - 1);
    for (const Pair& l : pairs) {
        patches.links[fill[std::size_t(l.a)]++] = {l.b, 1.0f - l.cost, l.vote};
        patches.links[fill[std::size_t(l.b)]++] = {l.a, 1.0f - l.cost, l.vote};
    }
}

/// Splits the points the tree oriented into patches joined by sure edges that agree as the tree
/// left the normals, and links them (link_patches): each graph edge across two patches votes
/// +-(1 - cost) by the sign of its agreement, none at cost 1; the tree's own edges add 1e-6,
/// so that where nothing else speaks the tree's choice stands.
Patches sure_patches(const EdgeReadings& readings, const std::vector<std::int32_t>& adj,
                     const std::vector<std::size_t>& start, const std::vector<char>& state,
                     const std::vector<char>& turned, const std::vector<std::int32_t>& parent) {
    constexpr double kTreeTie = 1e-6;
    const std::size_t n = state.size();
    auto sure = [&](std::size_t i, std::size_t e) {
        const std::size_t j = std::size_t(adj[e]);
        return std::abs(readings.lean[e]) == 2 && readings.sign(e, turned[i], turned[j]) > 0;
    };
    detail::ConcurrentMinUnionFind sets(n);
    detail::for_each_chunk(n, [&](std::size_t, std::size_t begin, std::size_t end) {
        for (std::size_t i = begin; i < end; ++i) {
            for (std::size_t e = start[i]; e < start[i + 1]; ++e) {
                if (std::size_t(adj[e]) > i && sure(i, e)) sets.unite(std::int32_t(i), adj[e]);
            }
        }
    });
    const std::vector<std::int32_t> root = sets.labels();
    Patches patches;
    patches.of.assign(n, -1);
    std::vector<std::int32_t> id(n, -1);
    std::int32_t count = 0;
    for (std::size_t i = 0; i < n; ++i) {
        if (state[i] == kExcluded) continue;
        std::int32_t& p = id[std::size_t(root[i])];
        if (p < 0) p = count++;
        patches.of[i] = p;
    }
    patches.anchored.assign(std::size_t(count), 0);
    for (std::size_t i = 0; i < n; ++i) {
        if (state[i] == kFixed) patches.anchored[std::size_t(patches.of[i])] = 1;
    }
    // The pairs by chunks of points in parallel: counted, then each chunk's listed from its
    // offset, in the order of a serial pass and with no slack capacity (the largest array of
    // the orientation: 2.3M pairs on the bunny scans).
    auto across = [&](std::size_t i, auto&& take) {
        if (state[i] == kExcluded) return;
        for (std::size_t e = start[i]; e < start[i + 1]; ++e) {
            const std::size_t j = std::size_t(adj[e]);
            if (j <= i || state[j] == kExcluded || patches.of[i] == patches.of[j]) continue;
            const bool tree = parent[j] == std::int32_t(i) || parent[i] == std::int32_t(j);
            const float cost = std::min(readings.cost[e], 1.0f);
            if (cost >= 1.0f && !tree) continue;
            take(e, j, cost, tree);
        }
    };
    std::size_t total = 0;
    const std::vector<std::size_t> first = detail::chunk_offsets(
        n,
        [&](std::size_t, std::size_t begin, std::size_t end) {
            std::size_t count = 0;
            for (std::size_t i = begin; i < end; ++i) {
                across(i, [&](std::size_t, std::size_t, float, bool) { ++count; });
            }
            return count;
        },
        total);
    std::vector<Pair> pairs(total);
    detail::for_each_chunk(n, [&](std::size_t c, std::size_t begin, std::size_t end) {
        std::size_t at = first[c];
        for (std::size_t i = begin; i < end; ++i) {
            across(i, [&](std::size_t e, std::size_t j, float cost, bool tree) {
                const std::int32_t a = patches.of[i], b = patches.of[j];
                const double vote = readings.sign(e, turned[i], turned[j]) * (1.0 - double(cost));
                pairs[at++] = {std::min(a, b), std::max(a, b), cost,
                               vote + (tree ? kTreeTie : 0.0)};
            });
        }
    });
    link_patches(pairs, patches);
    return patches;
}

/// Per patch +1 (keep the tree's orientation) or -1 (turn it): Prim's maximum spanning tree
/// over the links by strength, grown from the anchored patches, then from the patch of each
/// free component's seed, which keeps its sign. A patch reached takes the sign that its links
/// to the patches with a sign ask for, each by its strength (its vote's sign, once): not the
/// reaching link's alone. (The fan at 200k samples, seed 8: its largest face, 32,235 points,
/// was reached by a link of strength 0.92 whose pairs near the best voted +2.6 for the wrong
/// sign, where its 11 other links, 0.50-0.89 each, all asked for the right one. Nor the pairs'
/// votes summed over the links: a 40-degree blade tip's link sums -764 for the wrong sign,
/// against +180 and +262 for the right one from the blade's other two links.)
std::vector<signed char> orient_patches(const Patches& patches, const OrientTree& tree) {
    const std::size_t count = patches.anchored.size();
    std::vector<signed char> sign(count, 0);
    struct Step {
        float strength;
        std::int32_t to, from;  // the patch reached, and the patch it is reached from
        bool operator<(const Step& o) const {
            if (strength != o.strength) return strength < o.strength;
            if (to != o.to) return to > o.to;
            return from > o.from;
        }
    };
    std::priority_queue<Step> heap;
    // The best step to each patch pushed so far (strength, then from): a step that would pop
    // after it would find the patch signed, so it is not pushed (as grow_tree's `least`).
    std::vector<std::pair<float, std::int32_t>> best(
        count, {-std::numeric_limits<float>::infinity(), std::numeric_limits<std::int32_t>::max()});
    auto push = [&](std::int32_t p) {
        for (std::size_t e = patches.start[std::size_t(p)]; e < patches.start[std::size_t(p) + 1];
             ++e) {
            const std::int32_t q = patches.links[e].to;
            if (sign[std::size_t(q)] != 0) continue;
            const float strength = patches.links[e].strength;
            std::pair<float, std::int32_t>& b = best[std::size_t(q)];
            if (!(strength > b.first || (strength == b.first && p < b.second))) continue;
            b = {strength, p};
            heap.push({strength, q, p});
        }
    };
    // The sign the link entry e (of patch p, to a patch with a sign) asks of p.
    auto asked = [&](std::size_t e) {
        const signed char other = sign[std::size_t(patches.links[e].to)];
        return patches.links[e].vote < 0.0 ? -other : other;
    };
    auto grow = [&]() {
        while (!heap.empty()) {
            const Step s = heap.top();
            heap.pop();
            const std::size_t p = std::size_t(s.to);
            if (sign[p] != 0) continue;
            // Each link to a patch with a sign asks for one, by its strength.
            double sum = 0.0;
            int reached = 1;  // the sign the reaching link asks for
            for (std::size_t e = patches.start[p]; e < patches.start[p + 1]; ++e) {
                if (sign[std::size_t(patches.links[e].to)] == 0) continue;
                sum += double(patches.links[e].strength) * asked(e);
                if (patches.links[e].to == s.from) reached = asked(e);
            }
            const int own = sum != 0.0 ? (sum < 0.0 ? -1 : 1) : reached;
            sign[p] = static_cast<signed char>(own);
            push(s.to);
        }
    };
    for (std::size_t p = 0; p < count; ++p) {
        if (patches.anchored[p]) sign[p] = 1;
    }
    for (std::size_t p = 0; p < count; ++p) {
        if (patches.anchored[p]) push(std::int32_t(p));
    }
    grow();
    for (std::int32_t s : tree.seeds) {
        const std::int32_t p = patches.of[std::size_t(s)];
        if (sign[std::size_t(p)] != 0) continue;
        sign[std::size_t(p)] = 1;
        push(p);
        grow();
    }
    for (signed char& s : sign) {
        if (s == 0) s = 1;
    }
    return sign;
}

/// Orientation in three steps, over the symmetric kNN graph and its coplanar bridges, each
/// edge read once (EdgeReadings).
/// 1. Prim's tree (grow_tree).
/// 2. Where the tree crossed between patches it oriented with certainty (sure_patches), the
///    crossing is decided again by the pairs across near the best, not by the one pair the tree
///    took (link_patches, orient_patches).
/// 3. A component grown from a free seed is turned round as a whole when its outward flux says
///    so.
/// 4. A point that took a neighbour's face (`donor`: adopt_neighbour_faces) takes its
///    orientation too.
/// Returns the number of components seeded at a free point; `flipped` counts the free points
/// whose normal ends turned.
std::size_t orient_mst(Span<Vec3f> pts, std::vector<Vec3f>& normals,
                       const std::vector<float>& doubt, const std::vector<std::int32_t>& donor,
                       const KnnResult& knn, const std::vector<char>& state,
                       NormalResult& result) {
    const std::size_t n = pts.size();
    std::vector<std::size_t> start;
    std::vector<std::int32_t> adj = symmetric_adjacency(knn, n, start);
    add_edges(adj, start, coplanar_bridges(pts, normals, state, adj, start));
    const EdgeReadings readings(pts, normals, doubt, adj, start, state);
    std::vector<char> turned(n, 0);
    const OrientTree tree = grow_tree(pts, normals, readings, adj, start, state, turned);
    const Patches patches = sure_patches(readings, adj, start, state, turned, tree.parent);
    const std::vector<signed char> sign = orient_patches(patches, tree);
    for (std::size_t i = 0; i < n; ++i) {
        if (state[i] == kFree && sign[std::size_t(patches.of[i])] < 0) {
            flip(normals[i]);
            turned[i] ^= 1;
        }
    }

    std::vector<std::vector<std::int32_t>> members(tree.seeds.size());
    for (std::size_t i = 0; i < n; ++i) {
        const std::int32_t c = tree.component[i];
        if (c >= 0) members[std::size_t(c)].push_back(std::int32_t(i));
    }
    for (const std::vector<std::int32_t>& m : members) {
        if (component_sign(pts, normals, knn, m, result) >= 0) continue;
        for (std::int32_t i : m) {
            flip(normals[std::size_t(i)]);
            turned[std::size_t(i)] ^= 1;
        }
    }
    // A face's normal adopted from a point of that face takes that point's orientation: its
    // own edges reach only other faces, whose readings are the least sure.
    for (std::size_t i = 0; i < donor.size(); ++i) {
        if (donor[i] < 0 || state[i] != kFree) continue;
        if (dot(normals[i], normals[std::size_t(donor[i])]) < 0.0f) {
            flip(normals[i]);
            turned[i] ^= 1;
        }
    }
    result.flipped += std::size_t(std::count(turned.begin(), turned.end(), 1));
    return tree.seeds.size();
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

/// The points flagged `wider` (beside_crisp_plane, or a crowded puzzle) look again
/// (detail::wider_normal): where their 3k nearest among their neighbours' neighbours show the
/// point's own crisp face, its normal replaces the PCA one, and the flag is cleared.
void wider_look(Span<Vec3f> pts, const KnnResult& knn, int k, std::vector<char>& wider,
                std::vector<Vec3f>& normals, std::vector<float>& doubt) {
    const auto list = [&knn](std::size_t j) { return knn.neighbours(j); };
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, pts.size(), 4096),
                      [&](const tbb::blocked_range<std::size_t>& b) {
        for (std::size_t i = b.begin(); i < b.end(); ++i) {
            if (!wider[i] || !detail::wider_normal(pts, i, k, list, normals[i])) continue;
            wider[i] = 0;
            if (!doubt.empty()) doubt[i] = 0.0f;
        }
    });
}

/// The points the wider look left without a face of their own (`wider` still set) take the
/// crisp face of a neighbour or a neighbour's neighbour whose plane passes through them, within
/// a hundredth of their neighbours' mean distance, where exactly one such face does (normals'
/// lines within 5 degrees count as one face); `crisp`: the points whose normal is a face's,
/// before this pass. Returns per point the one whose face it took (its donor, whose
/// orientation it takes in orient_mst), else -1. Its doubt stays: a taker's own edges reach
/// only other faces' points, and with the doubt cleared their readings turned a whole face
/// (32,320 normals of the fan's seed 6 below). (The one sample of a blade's end face in 2.3 voxels at its 40-degree
/// tip, the fan at 200k samples, seed 6: its ten nearest lie on the two faces of the tip, its
/// wider look saw four points of its own face, and a plane grazing the tip's face scored more;
/// the PCA blend it kept opened the mesh, 4-5 boundary edges. Its own face's points, 2.3-2.7
/// voxels on, have that face's crisp normal, and their plane passes through it.) The streamed
/// tiles estimate no normal so (they orient each point on its own, and this pass reads the
/// normals of two hops of neighbours), so it runs only where the orientation is propagated.
std::vector<std::int32_t> adopt_neighbour_faces(Span<Vec3f> pts, const KnnResult& knn, int k,
                                                const std::vector<char>& wider,
                                                const std::vector<char>& crisp,
                                                std::vector<Vec3f>& normals) {
    const float same = std::cos(5.0f * float(M_PI) / 180.0f);
    const auto list = [&knn](std::size_t j) { return knn.neighbours(j); };
    std::vector<std::int32_t> donor(pts.size(), -1);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, pts.size(), 4096),
                      [&](const tbb::blocked_range<std::size_t>& b) {
        std::vector<std::pair<float, int>> ring;
        for (std::size_t i = b.begin(); i < b.end(); ++i) {
            if (!wider[i]) continue;
            two_hop_ring(pts, i, k, list, ring);
            double reach = 0.0;
            const int* own = list(i);
            for (int j = 0; j < k; ++j) {
                reach += std::sqrt(double(
                    KnnResult::squared_distance(pts[i], pts[std::size_t(own[j])])));
            }
            const double band = 0.01 * reach / double(k);
            int faces = 0, from = -1;
            for (const auto& [d2, c] : ring) {
                if (!crisp[std::size_t(c)]) continue;
                const Vec3f& u = normals[std::size_t(c)];
                const Vec3f& q = pts[std::size_t(c)];
                const double off = double(u[0]) * (double(pts[i][0]) - q[0]) +
                                   double(u[1]) * (double(pts[i][1]) - q[1]) +
                                   double(u[2]) * (double(pts[i][2]) - q[2]);
                if (std::fabs(off) > band) continue;
                if (faces == 0) {
                    from = c;  // the nearest such face's point
                    faces = 1;
                } else if (std::fabs(dot(normals[std::size_t(from)], u)) < same) {
                    faces = 2;
                    break;
                }
            }
            if (faces == 1) donor[i] = from;
        }
    });
    for (std::size_t i = 0; i < pts.size(); ++i) {
        if (donor[i] >= 0) normals[i] = normals[std::size_t(donor[i])];
    }
    return donor;
}

/// The normals of the points with needs[i] (`needed` of them), from their k nearest (knn) PCA
/// (neighbourhood_normal), oriented towards the viewpoint or by orient_mst; degenerate
/// neighbourhoods get no normal (0, 0, 0). Fills the counts of `result`.
/// What a cloud's shape says of the orientation of its estimated normals (OrientRule::automatic).
enum class Shape { other, height_field, sensor_frame };

/// Whether the free points are seen as from a depth camera at the origin in its own axes: every
/// point in front of it (z > 0), within 56 degrees of +z, the origin inside the cloud's x-y
/// extent, the far points 1.5x as far as the near ones (a terrain is seen from far above, not
/// from a point under it).
bool seen_from_origin(const PointCloud& cloud, const std::vector<char>& state, double& depth) {
    Span<Vec3f> pts = cloud.positions;
    const Vec3d& o = cloud.origin;
    double zmin = std::numeric_limits<double>::infinity(), zmax = 0.0;
    double xlo = zmin, xhi = -zmin, ylo = zmin, yhi = -zmin;
    bool in_front = true;
    for (std::size_t i = 0; i < pts.size() && in_front; ++i) {
        if (state[i] != kFree) continue;
        const double x = o[0] + pts[i][0], y = o[1] + pts[i][1], z = o[2] + pts[i][2];
        in_front = z > 0.0 && std::max(std::fabs(x), std::fabs(y)) <= 1.5 * z;
        zmin = std::min(zmin, z);
        zmax = std::max(zmax, z);
        xlo = std::min(xlo, x);
        xhi = std::max(xhi, x);
        ylo = std::min(ylo, y);
        yhi = std::max(yhi, y);
    }
    depth = 0.5 * (zmin + zmax);
    return in_front && zmax >= 1.5 * zmin && xlo < 0.0 && xhi > 0.0 && ylo < 0.0 && yhi > 0.0;
}

/// How many free points lie in a single layer along their column: the points of a column of
/// `width` x `width` cells of (x, y) -- or, `rays`, of (x / z, y / z) in the origin's frame,
/// the rays from the origin -- sorted by z with no gap over 2 `gap`.
std::size_t single_layer(const PointCloud& cloud, const std::vector<char>& state, double width,
                         double gap, bool rays) {
    Span<Vec3f> pts = cloud.positions;
    struct Entry {
        std::int64_t column;
        float z;
        bool operator<(const Entry& o) const {
            return column != o.column ? column < o.column : z < o.z;
        }
    };
    std::vector<Entry> e;
    for (std::size_t i = 0; i < pts.size(); ++i) {
        if (state[i] != kFree) continue;
        double x = pts[i][0], y = pts[i][1];
        if (rays) {
            const double z = cloud.origin[2] + pts[i][2];
            x = (cloud.origin[0] + x) / z;
            y = (cloud.origin[1] + y) / z;
        }
        const auto cx = std::int64_t(std::floor(x / width));
        const auto cy = std::int64_t(std::floor(y / width));
        e.push_back({(cx << 32) ^ (cy & 0xffffffff), pts[i][2]});
    }
    tbb::parallel_sort(e.begin(), e.end());
    std::size_t single = 0;
    for (std::size_t a = 0, b = 0; a < e.size(); a = b) {
        bool one = true;
        for (b = a + 1; b < e.size() && e[b].column == e[a].column; ++b) {
            one = one && double(e[b].z) - double(e[b - 1].z) <= 2.0 * gap;
        }
        if (one) single += b - a;
    }
    return single;
}

/// What the cloud's shape says of its estimated normals. A depth camera's frame in its own axes
/// where it is seen as from a sensor at the origin (seen_from_origin), most of its normals
/// (60 %) within 60 degrees of their ray from the origin, and one surface along most rays
/// (75 %; a closed object before the origin shows two). Else a height field where most normals
/// (60 %) lie within 30 degrees of vertical and a vertical line through most places meets one
/// surface only (the points of a column of 2 x 2 cells of the k-th neighbour distance lie in
/// one layer, no gap over twice that): a terrain with roofs and trees (whose canopy and ground
/// are two layers) passes; a closed object (a top and a bottom), a room (a floor and a
/// ceiling) do not. (Frames were once tested among height fields only: the PCL table scene,
/// looking down at the table, has 20 % vertical normals, capture0001 70 % of its points over
/// one vertical layer; as "other", 99 % and 60 % of their normals faced away from the camera.)
Shape cloud_shape(const PointCloud& cloud, const std::vector<Vec3f>& normals,
                  const std::vector<char>& state, const KnnResult& knn, int k) {
    Span<Vec3f> pts = cloud.positions;
    const Vec3d& o = cloud.origin;
    std::vector<float> reach;
    std::size_t free = 0, vertical = 0, facing = 0;
    for (std::size_t i = 0; i < pts.size(); ++i) {
        if (state[i] != kFree) continue;
        ++free;
        const Vec3f& n = normals[i];
        vertical += std::fabs(n[2]) >= 0.866f;
        const double x = o[0] + pts[i][0], y = o[1] + pts[i][1], z = o[2] + pts[i][2];
        const double along = n[0] * x + n[1] * y + n[2] * z;
        facing += along * along >= 0.25 * (x * x + y * y + z * z);
        reach.push_back(knn.sq_dist(pts, i, k - 1));
    }
    if (free < 16) return Shape::other;
    // A camera sees surfaces that face it, one along each ray (a closed object before it, two).
    double depth = 0.0;
    const bool camera =
        double(facing) >= 0.6 * double(free) && seen_from_origin(cloud, state, depth);
    const bool upright = double(vertical) >= 0.6 * double(free);
    if (!camera && !upright) return Shape::other;  // most clouds: no layers to count
    std::nth_element(reach.begin(), reach.begin() + std::ptrdiff_t(reach.size() / 2), reach.end());
    const double cell = 2.0 * std::sqrt(double(reach[reach.size() / 2]));
    if (!(cell > 0.0)) return Shape::other;
    if (camera && single_layer(cloud, state, cell / depth, cell, true) >= 0.75 * double(free)) {
        return Shape::sensor_frame;
    }
    if (!upright) return Shape::other;
    const std::size_t single = single_layer(cloud, state, cell, cell, false);
    log_info("normals: height-field test: " +
             std::to_string(int(100.0 * double(vertical) / double(free))) +
             " % of the normals within 30 degrees of vertical (a height field has 60 % or more), " +
             std::to_string(int(100.0 * double(single) / double(free))) +
             " % of the points over a single surface (75 % or more)");
    return double(single) < 0.75 * double(free) ? Shape::other : Shape::height_field;
}

/// Orients the estimated normals (state kFree) by the cloud's shape where OrientRule::automatic
/// recognises it: a sensor's frame faces the origin (every point on its own; their state
/// becomes kFixed), a height field's near-horizontal surfaces face up and become kFixed (the
/// steep rest is left to the propagation from them). Returns the rule's name, "" for none.
std::string orient_by_shape(const PointCloud& cloud, const NormalOptions& options,
                            const KnnResult& knn, int k, std::vector<Vec3f>& normals,
                            std::vector<char>& state, std::size_t& flipped) {
    if (options.orient != OrientRule::automatic || k < 2) return "";
    const Shape shape = cloud_shape(cloud, normals, state, knn, k);
    if (shape == Shape::other) return "";
    NormalOptions toward;
    if (shape == Shape::sensor_frame) {
        toward.viewpoint = Vec3d{0.0, 0.0, 0.0};
    } else {
        toward.up = Vec3d{0.0, 0.0, 1.0};
    }
    for (std::size_t i = 0; i < state.size(); ++i) {
        if (state[i] != kFree) continue;
        if (shape == Shape::height_field && std::fabs(normals[i][2]) < 0.5f) continue;
        flipped += detail::orient_locally(toward, cloud.origin, cloud.positions[i], normals[i]);
        state[i] = kFixed;
    }
    return shape == Shape::sensor_frame ? "sensor at the origin" : "height field";
}

void estimate_needed(const PointCloud& cloud, const NormalOptions& options, const KnnResult& knn,
                     int k, const std::vector<char>& needs, std::size_t needed,
                     bool estimate_all, NormalResult& result) {
    const std::size_t n = cloud.size();
    std::vector<char> degenerate(n, 0), wider(n, 0);
    std::vector<float> doubt(options.orients_locally() ? 0 : n, 0.0f);
    std::vector<Vec3f>& normals = result.normals.edit();
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 1024),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            if (!needs[i]) continue;
            Vec3f nrm;
            float v = 0.0f;
            bool w = false;
            if (k >= 2 &&
                detail::neighbourhood_normal(cloud.positions, i, knn.neighbours(i), k, nrm, v, &w)) {
                normals[i] = nrm;
                if (!doubt.empty()) doubt[i] = v;
                wider[i] = w;
            } else {
                degenerate[i] = 1;
            }
        }
    });
    wider_look(cloud.positions, knn, k, wider, normals, doubt);
    std::vector<std::int32_t> donor;
    if (!options.orients_locally()) {
        std::vector<char> crisp(n, 0);
        for (std::size_t i = 0; i < n; ++i) {
            crisp[i] = needs[i] && !degenerate[i] && doubt[i] == 0.0f;
        }
        donor = adopt_neighbour_faces(cloud.positions, knn, k, wider, crisp, normals);
    }
    std::size_t bad = 0;
    for (std::size_t i = 0; i < n; ++i) {
        if (degenerate[i]) {
            ++bad;
            normals[i] = {0.0f, 0.0f, 0.0f};  // left unsplatted
        }
    }
    result.estimated = needed - bad;
    if (!estimate_all) result.repaired = needed - bad;
    detail::report_degenerate(bad, n);

    // Orientation.
    if (options.orients_locally()) {
        result.oriented_to_viewpoint = true;
        result.orientation = options.up ? "up" : "viewpoint";
        for (std::size_t i = 0; i < n; ++i) {
            if (!needs[i] || degenerate[i]) continue;
            result.flipped += detail::orient_locally(options, cloud.origin, cloud.positions[i],
                                                     normals[i]);
        }
    } else {
        std::vector<char> state(n);
        for (std::size_t i = 0; i < n; ++i) {
            state[i] = degenerate[i] ? kExcluded : needs[i] ? kFree : kFixed;
        }
        // Whole clouds of estimated normals only: a file's normals already say how they face.
        if (estimate_all) {
            result.orientation = orient_by_shape(cloud, options, knn, k, normals, state,
                                                 result.flipped);
        }
        if (result.orientation.empty()) result.orientation = "MST";
        // A sensor's frame is oriented whole; otherwise the propagation (from the fixed points).
        if (std::count(state.begin(), state.end(), char(kFree)) > 0) {
            result.components =
                orient_mst(cloud.positions, normals, doubt, donor, knn, state, result);
        }
    }
}

/// The per-point scale, the mean distance to the k nearest neighbours (a file's positive scale
/// stays in automatic mode): from the lists when there are (`have_lists`), else from the outlier
/// stage's `spacing`, else from a batched search on `index` that also fills kth_sq.
void fill_scales(const PointCloud& cloud, const NormalOptions& options, const KnnResult& knn,
                 int k, bool have_lists, const std::vector<float>* spacing,
                 const KnnIndex* index, std::vector<float>& kth_sq, NormalResult& result) {
    const std::size_t n = cloud.size();
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

/// estimate_normals(); `scales_only`: the scales alone (estimate_scales), the normals neither
/// read nor returned.
NormalResult estimate_normals_with(const PointCloud& cloud, const NormalOptions& options,
                                   const KnnResult* known, const std::vector<float>* spacing,
                                   bool scales_only = false) {
    options.validate();
    const std::size_t n = cloud.size();
    NormalResult result;
    if (n == 0) throw InvalidArgument("normals: the point cloud is empty");

    if (!scales_only && options.mode == NormalMode::keep && !cloud.has_normals()) {
        throw InvalidArgument(
            "normals: the input has no normals and --normals keep was given. Hint: --normals "
            "estimate");
    }
    const bool estimate_all = !scales_only && estimates_all(cloud, options);
    std::vector<char> needs(scales_only ? 0 : n, 0);
    std::size_t needed = 0;
    if (estimate_all) {
        std::fill(needs.begin(), needs.end(), 1);
        needed = n;
    } else if (!scales_only) {
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
    } else if (!scales_only) {
        result.normals = cloud.normals;
    }
    if (options.scale != ScaleMode::none && cloud.has_scales()) result.scales = cloud.scales;
    auto median_scale = [&result] {
        if (result.scales.empty()) return;
        // What nth_element would put in the middle, without a copy of the scales to reorder
        // (3 ms of one thread on the bunny's 362k, the other idle). A file's negative or NaN
        // scales order after all others (select_rank).
        const Span<float> s = result.scales;
        result.median_scale = detail::select_rank(s.size() / 2, s);
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
    if (needed > 0) estimate_needed(cloud, options, knn, k, needs, needed, estimate_all, result);

    if (need_scale) {
        fill_scales(cloud, options, knn, k, have_lists, spacing, index.get(), kth_sq, result);
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

NormalResult estimate_scales(const PointCloud& cloud, const NormalOptions& options) {
    return estimate_normals_with(cloud, options, nullptr, nullptr, true);
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
