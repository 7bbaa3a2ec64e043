// The `dc` mesher: dual contouring (see mesh.h).
//
// Each oriented loop of a cell (detail/cube.h) is one connected patch of the surface in that
// cell and gets one vertex, at the minimiser of the quadric error of its crossings:
//
//     E(x) = sum_i (n_i . (x - p_i))^2 + bias |x - m|^2,    m = mean of the p_i,
//
// with p_i the crossing points and n_i the normalised SDF gradients there (Hermite data). The
// 3x3 normal matrix is decomposed (it is A^T A, so its eigenvectors are A's right singular
// vectors); directions whose singular value is below dc_truncation times the largest are left at
// the mass point, as in Ju et al. 2002 and P. Lindstrom, "Out-of-core simplification of large
// polygonal models", SIGGRAPH 2000. At features the planes are reweighted (IRLS) so a smeared
// normal cannot tilt the vertex, after the doubtful planes of a curved face there are merged
// into one second-order plane (merge_curved); on smooth curved patches the vertex is placed by
// a second-order estimate from the Hermite data instead (see solve_qef). The vertex stays within
// a voxel of its cell.
//
// Hermite data next to sharp features: a crossing whose end voxels see no single linear region
// of the field gets a smeared gradient and often an interpolated position across a kink. Before
// the solve such crossings borrow the tangent plane of a reliable crossing nearby that explains
// their samples (repair_hermite), so the planes of all faces meeting at a corner reach the cells
// around it -- the idea of extrapolating from the side of a kink where the field is linear, as in
// ENO schemes (A. Harten et al., J. Comput. Phys. 1987), applied to whole planes.
//
// Each crossed edge becomes a quad joining the vertices of its four cells (the patch of each cell
// that contains the edge's crossing), ordered counter-clockwise around the outward direction and
// split along the diagonal that follows a sharp edge (between vertices whose patch normals agree)
// or, on smooth parts, whose triangles stay closer to the zero level of the SDF (estimated to
// second order from the vertices' field values and patch normals). The patch normals are also the
// vertex normals handed to finish_mesh().
#include <tbb/enumerable_thread_specific.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <limits>
#include <memory>
#include <numeric>

#include "detail/crossings.h"
#include "detail/dual_surface.h"
#include "detail/mesh_common.h"
#include "detail/release.h"

namespace vdbrecon::detail {
namespace {

/// The 3x3x3 neighbourhood of a voxel: values and active states, index (dx+1)*9 + (dy+1)*3 + dz+1.
struct Stencil27 {
    float f[27];
    std::uint8_t on[27];

    static constexpr int at(int dx, int dy, int dz) { return (dx + 1) * 9 + (dy + 1) * 3 + dz + 1; }
    static constexpr int kCentre = 13;
    static constexpr int kStep[3] = {9, 3, 1};

    template <typename Field>
    void gather(Field& field, const openvdb::Coord& v) {
        for (int dx = -1; dx <= 1; ++dx) {
            for (int dy = -1; dy <= 1; ++dy) {
                for (int dz = -1; dz <= 1; ++dz) {
                    const int i = at(dx, dy, dz);
                    on[i] = field.probeValue(v.offsetBy(dx, dy, dz), f[i]);
                }
            }
        }
    }
};

/// Gradient at a voxel that does not smear across a kink of the field (the medial planes inside a
/// box, the rounded region outside its edges), in the spirit of essentially non-oscillatory
/// differencing (A. Harten et al., J. Comput. Phys. 1987) but choosing whole stencils, which also
/// works for kinks oblique to the grid. Candidates: the central difference, and the eight
/// one-sided "octant" differences (forward or backward along each axis). Each is scored by how
/// well its plane predicts the neighbours it did not use (central: the mismatch of forward and
/// backward differences; octant: the octant's three face-diagonal corners and its far corner),
/// and the best one wins; the central difference is preferred unless an octant is clearly better,
/// so smooth curved fields keep second-order gradients. Index units; false when the voxel is
/// inactive. `misfit` is the winner's score relative to the slope (0 for a locally linear field;
/// large at a corner, where no stencil stays in one linear region).
///
/// The neighbourhood is read in place: `f` and `on` point at the voxel in dense arrays whose
/// index steps along x, y and z are `step` (a Stencil27's, or a LeafBlock's for voxels inside it).
bool robust_gradient(const float* f, const std::uint8_t* on, const int step[3], openvdb::Vec3d& g,
                     double& misfit) {
    if (!on[0]) return false;
    const double f0 = f[0];
    const int* kStep = step;
    double fm[3], fp[3];
    bool om[3], op[3];
    for (int a = 0; a < 3; ++a) {
        om[a] = on[-kStep[a]];
        fm[a] = f[-kStep[a]];
        op[a] = on[kStep[a]];
        fp[a] = f[kStep[a]];
    }
    // Central candidate (one-sided where a neighbour is missing) and its kink score.
    openvdb::Vec3d central(0.0);
    double central_score = 0.0, slope = 0.0;
    for (int a = 0; a < 3; ++a) {
        if (om[a] && op[a]) {
            central[a] = 0.5 * (fp[a] - fm[a]);
            central_score += 0.5 * std::fabs((fp[a] - f0) - (f0 - fm[a]));
        } else if (op[a]) {
            central[a] = fp[a] - f0;
        } else if (om[a]) {
            central[a] = f0 - fm[a];
        }
        slope = std::max(slope, std::fabs(central[a]));
    }
    g = central;
    misfit = slope > 0.0 ? central_score / slope : 0.0;
    if (central_score <= 0.02 * slope) return true;  // locally linear: done
    double best = central_score;
    // One-sided differences f(v +- e_a) - f(v). An octant's plane predicts the corner that steps
    // along the axes in a set as f0 plus the sum of its differences along them.
    double dp[3], dm[3];
    for (int a = 0; a < 3; ++a) {
        dp[a] = fp[a] - f0;
        dm[a] = fm[a] - f0;
    }
    for (int octant = 0; octant < 8; ++octant) {
        double d[3];  // the octant's difference along each axis (its gradient times the sign)
        int off[3];
        bool ok = true;
        for (int a = 0; a < 3; ++a) {
            const bool plus = (octant >> a) & 1;
            ok = ok && (plus ? op[a] : om[a]);
            d[a] = plus ? dp[a] : dm[a];
            off[a] = plus ? kStep[a] : -kStep[a];
        }
        if (!ok) continue;
        // Its corners with two or three steps: (x, y), (x, z), (y, z) and (x, y, z).
        const int corner[4] = {off[0] + off[1], off[0] + off[2], off[1] + off[2],
                               off[0] + off[1] + off[2]};
        const double predicted[4] = {d[0] + d[1], d[0] + d[2], d[1] + d[2], d[0] + d[1] + d[2]};
        double score = 0.0;
        int used = 0;
        for (int k = 0; k < 4; ++k) {
            if (!on[corner[k]]) continue;
            score += std::fabs(double(f[corner[k]]) - f0 - predicted[k]);
            ++used;
        }
        if (used < 3) continue;
        if (used == 4) score *= 0.75;  // the mean over three corners
        // An octant must beat the central difference clearly to be chosen.
        if (score < 0.5 * best) {
            best = score;
            g = openvdb::Vec3d(octant & 1 ? d[0] : -d[0], octant & 2 ? d[1] : -d[1],
                               octant & 4 ? d[2] : -d[2]);
        }
    }
    misfit = slope > 0.0 ? best / slope : 0.0;
    return true;
}

/// Hermite data (point and unit normal) of the crossing on the edge v0 -> v0 + e_axis.
///
/// Where the field is smooth along the edge -- each end's tangent-plane model predicts the other
/// end's value within kKinkTolerance voxels -- this is the linear interpolation of the values
/// and of the ends' robust gradients. Otherwise a kink of the distance
/// field lies between the ends (near a sharp edge the inside end measures the distance to the
/// other face): the crossing is where the edge meets the tangent plane of the end whose linear
/// region contains it, with that end's robust gradient as normal. For a distance field sampled
/// from a box this recovers exact face points and normals next to its edges. `weight` (0..1)
/// says how well the gradient fitted the data; at corners, where no stencil does, the planes of
/// the other crossings then carry the quadric.
template <typename Field, typename Gradient>
void hermite(Field& acc, Gradient&& gradient, const openvdb::Coord& v0, int axis, float iso,
             openvdb::Vec3d& point, openvdb::Vec3f& normal, float& weight) {
    constexpr double kKinkTolerance = 0.1;  // voxels (the field's values are world units)
    openvdb::Coord v1 = v0;
    v1[axis] += 1;
    const double f0 = double(acc.getValue(v0)) - iso, f1 = double(acc.getValue(v1)) - iso;
    const double t_lin = f0 / (f0 - f1);
    point = v0.asVec3d();
    point[axis] += t_lin;
    openvdb::Vec3d g0, g1;
    double m0 = 0.0, m1 = 0.0;
    const bool have0 = gradient(v0, g0, m0), have1 = gradient(v1, g1, m1);
    // In index units the gradient of a distance field has length 1 / voxel; compare in voxels.
    const double unit0 = have0 ? g0.length() : 0.0, unit1 = have1 ? g1.length() : 0.0;
    const bool smooth = unit0 > 0.0 && unit1 > 0.0 &&
                        std::fabs(f1 - (f0 + g0[axis])) <= kKinkTolerance * unit0 &&
                        std::fabs(f0 - (f1 - g1[axis])) <= kKinkTolerance * unit1;
    if (!smooth && unit0 > 0.0 && unit1 > 0.0 && g0[axis] != g1[axis]) {
        // Along the edge the field is two linear pieces, one from each end, meeting at the
        // kink t_k where the models agree; a root is real only on its own end's side of t_k.
        const double tk = (f1 - g1[axis] - f0) / (g0[axis] - g1[axis]);
        const double t0 = g0[axis] != 0.0 ? -f0 / g0[axis] : -1.0;
        const double t1 = g1[axis] != 0.0 ? 1.0 - f1 / g1[axis] : -1.0;
        const bool in0 = t0 >= 0.0 && t0 <= std::min(1.0, tk);
        const bool in1 = t1 <= 1.0 && t1 >= std::max(0.0, tk);
        if (in0 || in1) {
            const bool use0 = in0 && (!in1 || m0 <= m1);
            point = v0.asVec3d();
            point[axis] += use0 ? t0 : t1;
            const openvdb::Vec3d& g = use0 ? g0 : g1;
            normal = openvdb::Vec3f(g / g.length());
            weight = float(1.0 / (1.0 + std::pow((use0 ? m0 : m1) / 0.05, 2)));
            return;
        }
    }
    openvdb::Vec3d g = (have0 ? (1.0 - t_lin) * g0 : openvdb::Vec3d(0.0)) +
                       (have1 ? t_lin * g1 : openvdb::Vec3d(0.0));
    const double len = g.length();
    normal = len > 0.0 ? openvdb::Vec3f(g / len) : openvdb::Vec3f(0.0f);
    const double m = (1.0 - t_lin) * m0 + t_lin * m1;
    weight = float(1.0 / (1.0 + std::pow(m / 0.05, 2)));
}

/// The Hermite data of one crossing (index space), kept together: the passes below read all three.
struct HermiteSample {
    openvdb::Vec3f point;
    openvdb::Vec3f normal;  ///< unit, or zero where the field gave no gradient
    float weight;           ///< 0..1: how well the gradient fitted the data (see hermite())
};

/// Thresholds of repair_hermite (see there).
constexpr float kUnreliable = 0.5f, kReliable = 0.9f;
constexpr int kReach = 2;  // voxels, between edge start voxels (Chebyshev)

/// A reliable crossing's plane offered to an unreliable one (see repair_hermite).
struct PlaneCandidate {
    std::size_t j;
    double t, u;  ///< root on the edge; u: the same, measured from the inside end
    double m0, m1, off, agree;
};

/// A reliable crossing's plane along an edge: its values at the edge's ends, in voxels.
struct PlaneLine {
    double at0, at1;
};

constexpr double kMatch = 0.02;  ///< voxels: a plane explains an end's value (repair_hermite)

/// Rule 2 of repair_hermite: the candidate that the field's pieces along the edge pass through.
/// `end0` and `end1` hold the planes explaining each end's value; the crossing plane c is taken
/// when some a of end0 and b of end1 meet its line in order, 0 <= s_a <= t_c <= s_b <= 1 (the
/// field follows a from the start, then c through its root, then b). Ties: the plane closest to
/// our point.
const PlaneCandidate* three_pieces(const std::vector<PlaneCandidate>& cand, double f0, double f1,
                                   const std::vector<PlaneLine>& end0,
                                   const std::vector<PlaneLine>& end1) {
    const auto meet = [](const PlaneLine& a, const PlaneLine& c) {
        const double slope = (a.at1 - a.at0) - (c.at1 - c.at0);
        return slope != 0.0 ? (c.at0 - a.at0) / slope : -1.0;
    };
    const PlaneCandidate* pick = nullptr;
    for (const PlaneCandidate& c : cand) {
        const PlaneLine line{f0 - c.m0, f1 - c.m1};
        bool before = false, after = false;
        for (const PlaneLine& a : end0) {
            const double s = meet(a, line);
            before |= s >= 0.0 && s <= c.t;
        }
        for (const PlaneLine& b : end1) {
            const double s = meet(b, line);
            after |= s >= c.t && s <= 1.0;
        }
        if (before && after && (!pick || c.off < pick->off)) pick = &c;
    }
    return pick;
}

/// Rules 1 to 4 of repair_hermite: the plane the crossing takes, or null. `reliable` holds every
/// reliable crossing within reach, `cand` those whose plane the edge crosses, both in the order
/// of a walk over the voxels around the edge's start, then over axes; `end0` and `end1` the
/// reliable planes that explain each end's value (f0, f1).
const PlaneCandidate* pick_plane(const std::vector<PlaneCandidate>& cand,
                                 const std::vector<std::size_t>& reliable,
                                 const FillLater<HermiteSample>& data, double f0, double f1,
                                 const std::vector<PlaneLine>& end0,
                                 const std::vector<PlaneLine>& end1) {
    constexpr double kOnPlane = 0.06;  // voxels
    constexpr double kFace = 0.005;    // voxels
    constexpr double kRoughAgreement = 0.7;
    // Whether j lies on a confirmed face (rules 1 and 4; see repair_hermite).
    const auto is_face = [&](std::size_t j) {
        const openvdb::Vec3d nj(data[j].normal), pj(data[j].point);
        openvdb::Vec3d first(0.0);
        bool have_first = false;
        for (std::size_t k : reliable) {
            const openvdb::Vec3d d = openvdb::Vec3d(data[k].point) - pj;
            if (!(openvdb::Vec3d(data[k].normal).dot(nj) > 0.9999 &&
                  std::fabs(nj.dot(d)) <= kFace)) {
                continue;
            }
            // Points a voxel apart in two directions: a flat patch, not the band along which a
            // curved surface stays close to one tangent plane.
            if (have_first && first.cross(d).length() >= first.length()) return true;
            if (!have_first && d.lengthSqr() >= 1.0) {
                first = d;
                have_first = true;
            }
        }
        return false;
    };
    // Rule 1: an end's value explained, least extrapolation (ties: normal agreement).
    const PlaneCandidate* pick = nullptr;
    double best = 2.0;
    for (const PlaneCandidate& c : cand) {
        const double reach = std::min(std::fabs(c.m0) <= kMatch ? c.t : 2.0,
                                      std::fabs(c.m1) <= kMatch ? 1.0 - c.t : 2.0);
        if (reach < 2.0 &&
            (reach < best - 1e-6 || (reach <= best + 1e-6 && c.agree > pick->agree)) &&
            is_face(c.j)) {
            best = std::min(best, reach);
            pick = &c;
        }
    }
    if (pick) return pick;
    if ((pick = three_pieces(cand, f0, f1, end0, end1))) return pick;
    // Rule 3: the closest plane through our point (ties: normal agreement).
    best = kOnPlane;
    for (const PlaneCandidate& c : cand) {
        if (c.off < best - 1e-3 || (pick && c.off <= best + 1e-3 && c.agree > pick->agree)) {
            best = std::min(best, c.off);
            pick = &c;
        }
    }
    if (pick) return pick;
    // Rule 4: the first root of a confirmed face below the field.
    const PlaneCandidate* below = nullptr;
    for (const PlaneCandidate& c : cand) {
        if (c.agree >= kRoughAgreement && c.m0 >= -kMatch && c.m1 >= -kMatch &&
            (!below || c.u < below->u) && is_face(c.j)) {
            below = &c;
        }
    }
    return below;
}

/// The reliable crossings of each leaf, in crossing order (voxel order, then axis), and a way to
/// gather those around a leaf.
struct ReliableCrossings {
    std::vector<std::size_t> begin;  ///< per leaf, into ids (leafCount() + 1)
    std::vector<std::uint32_t> ids;

    /// One reliable crossing near a leaf, with a key that sorts by start voxel, then axis.
    struct Near {
        openvdb::Coord start;
        std::uint32_t key, j;
    };

    /// The reliable crossings whose edge starts within kReach of the leaf at `origin`, sorted by
    /// start voxel (x, y, z) and axis: for an edge in the leaf, the order of a walk over the
    /// voxels around its start, then over axes.
    static constexpr int kW = 8 + 2 * kReach;  ///< width of the box around() gathers from

    void around(const Crossings& crossings, const openvdb::Coord& origin,
                std::vector<Near>& near) const {
        const openvdb::Coord lo = origin.offsetBy(-kReach), hi = origin.offsetBy(7 + kReach);
        near.clear();
        for (int dx = -8; dx <= 8; dx += 8) {
            for (int dy = -8; dy <= 8; dy += 8) {
                for (int dz = -8; dz <= 8; dz += 8) {
                    const std::int64_t leaf =
                        crossings.leaf_index.find(origin.offsetBy(dx, dy, dz));
                    if (leaf < 0) continue;
                    for (std::size_t k = begin[std::size_t(leaf)]; k < begin[std::size_t(leaf) + 1];
                         ++k) {
                        const std::uint32_t j = ids[k];
                        const openvdb::Coord& c = crossings.start[j];
                        if (c[0] < lo[0] || c[1] < lo[1] || c[2] < lo[2] || c[0] > hi[0] ||
                            c[1] > hi[1] || c[2] > hi[2]) {
                            continue;
                        }
                        const openvdb::Coord b = c - lo;
                        const int cell = (b[0] * kW + b[1]) * kW + b[2];
                        near.push_back({c, std::uint32_t(cell * 3 + crossings.axis[j]), j});
                    }
                }
            }
        }
        std::sort(near.begin(), near.end(),
                  [](const Near& a, const Near& b) { return a.key < b.key; });
    }

    /// The run of `near` (as around() left it for the leaf at `origin`) whose edges start within
    /// kReach of voxel s along x: the key sorts by x first, so they are contiguous.
    static std::pair<const Near*, const Near*> x_window(const std::vector<Near>& near,
                                                        const openvdb::Coord& origin,
                                                        const openvdb::Coord& s) {
        const int bx = s[0] - origin[0] + kReach;  // s's x in the box
        const std::uint32_t lo = std::uint32_t(std::max(bx - kReach, 0) * kW * kW * 3),
                            hi = std::uint32_t((bx + kReach + 1) * kW * kW * 3);
        const auto by_key = [](const Near& e, std::uint32_t key) { return e.key < key; };
        const Near* first = std::lower_bound(near.data(), near.data() + near.size(), lo, by_key);
        return {first, std::lower_bound(first, near.data() + near.size(), hi, by_key)};
    }
};

/// Repairs the Hermite data of unreliable crossings from reliable neighbours.
///
/// Next to a corner or a sharp edge no stencil around a crossing's end voxels may stay in one
/// linear region of the field, so the crossing's gradient is smeared (low weight) and, where
/// neither end's own model was trusted, its position is a linear interpolation across a kink.
/// The faces meeting there are usually seen cleanly by crossings a voxel or two away. Each
/// reliable neighbour j (weight >= kReliable, edge start within kReach voxels) offers its
/// tangent plane P_j(x) = n_j . (x - p_j) (index units), provided our edge v0 -> v1 crosses it
/// in the right direction (n_j rises from the inside end to the outside end) at a root t_j in
/// [0, 1]. In order of preference the crossing takes the plane that
///   1. explains one end's value, |f(v_k) / voxel - P_j(v_k)| <= kMatch: that end lies in the
///      plane's linear region (over the face outside a convex feature, or where the face is the
///      nearest one inside). Along the edge the field is a few linear pieces and at most one of
///      them has its root on the edge; the match extrapolated least from its end wins. Only a
///      confirmed face has a linear region (see rule 4): a curved wall's tangent plane from
///      two voxels away explains a value by chance (a drilled hole's rim crossing moved 0.28
///      voxel along its edge and took a normal 6 degrees off);
///   2. carries the field between two planes that explain the ends' values but do not cross
///      the edge: the field follows a from one end, then our plane c through its root, then b
///      to the other end, the lines meeting in that order along the edge (three_pieces). This
///      is a corner where a concave and a convex edge meet (an L-bracket's inner corner, a
///      pocket's rim): each end lies in a third face's linear region;
///   3. passes within kOnPlane of our crossing point (the position was right, only the normal
///      was smeared);
///   4. bounds the field: a face of a convex feature has f >= P_j everywhere near it, so the
///      crossing comes no later than any such plane's root and lies on the plane whose root
///      comes first. (The mirror rule for concave features, f <= P_j and the last root, misfired
///      on the walls of drilled holes in our tests and is left out.) Tangent planes of a
///      curved surface bound the field too but do not carry the crossing, so this rule takes
///      only planes confirmed as faces: more reliable crossings on the same plane (within
///      kFace, normals within a degree) a voxel away in two directions (a curved surface stays
///      that close to one tangent plane only in a narrow band; a cylinder along a line), and
///      roughly agreeing with our own normal (a face's plane extended past its edge, across a
///      hole, bounds the field as well).
/// The crossing then takes the plane's normal and weight, and its point moves along the edge to
/// the root. The searches read only the first pass's data and the repairs are applied after all
/// of them, so the result does not depend on the order of evaluation. For a box sampled exactly
/// this makes every crossing exact.
///
/// Work per leaf: on a scanned surface reliable crossings are few (under one within reach of an
/// unreliable crossing on average, on the bunny), so each search walks a short list of the
/// reliable crossings around its leaf instead of probing the 125 voxels around its edge.
void repair_hermite(const Crossings& crossings, const openvdb::FloatTree& tree,
                    const std::vector<const openvdb::FloatTree::LeafNodeType*>& leaves,
                    double voxel, float iso, FillLater<HermiteSample>& data) {
    const std::size_t n_leaves = leaves.size();
    ReliableCrossings rel;
    rel.begin.assign(n_leaves + 1, 0);
    bool any_unreliable = false;
    for (std::size_t L = 0; L < n_leaves; ++L) {
        for (std::size_t i = crossings.leaf_begin[L]; i < crossings.leaf_begin[L + 1]; ++i) {
            if (data[i].weight >= kReliable) rel.ids.push_back(std::uint32_t(i));
            any_unreliable |= data[i].weight < kUnreliable;
        }
        rel.begin[L + 1] = rel.ids.size();
    }
    if (!any_unreliable || rel.ids.empty()) return;

    struct Repair {
        std::uint32_t i, j;  ///< the crossing, and the one whose plane it takes
        double t;            ///< the plane's root on the edge
    };
    // Collected per thread (a list per leaf meant allocations per leaf, slower on two threads
    // sharing the heap). The order they are applied in does not matter: a repaired crossing is
    // unreliable and takes the data of a reliable one, which is never repaired.
    tbb::enumerable_thread_specific<std::vector<Repair>> repairs;
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, n_leaves, 8),
        [&](const tbb::blocked_range<std::size_t>& r) {
            FloatAccessor acc(tree);
            std::vector<ReliableCrossings::Near> near;
            std::vector<std::size_t> reliable;
            std::vector<PlaneCandidate> cand;
            std::vector<PlaneLine> end0, end1;
            std::vector<Repair>& found = repairs.local();
            for (std::size_t L = r.begin(); L < r.end(); ++L) {
                const std::size_t begin = crossings.leaf_begin[L],
                                  end = crossings.leaf_begin[L + 1];
                if (std::none_of(data.begin() + std::ptrdiff_t(begin),
                                 data.begin() + std::ptrdiff_t(end),
                                 [](const HermiteSample& h) { return h.weight < kUnreliable; })) {
                    continue;
                }
                rel.around(crossings, leaves[L]->origin(), near);
                if (near.empty()) continue;
                for (std::size_t i = begin; i < end; ++i) {
                    if (!(data[i].weight < kUnreliable)) continue;
                    const openvdb::Vec3d p(data[i].point), n(data[i].normal);
                    const int axis = crossings.axis[i];
                    const openvdb::Coord& s = crossings.start[i];
                    openvdb::Coord s1 = s;
                    s1[axis] += 1;
                    const openvdb::Vec3d v0 = s.asVec3d(), v1 = s1.asVec3d();
                    const double rise = crossings.start_inside[i] ? 1.0 : -1.0;
                    reliable.clear();
                    cand.clear();
                    end0.clear();
                    end1.clear();
                    double f0 = 0.0, f1 = 0.0;  // the ends' values in voxels, read when needed
                    const auto window = ReliableCrossings::x_window(near, leaves[L]->origin(), s);
                    for (const ReliableCrossings::Near* it = window.first; it != window.second;
                         ++it) {
                        const ReliableCrossings::Near& e = *it;
                        if (std::abs(e.start[0] - s[0]) > kReach ||
                            std::abs(e.start[1] - s[1]) > kReach ||
                            std::abs(e.start[2] - s[2]) > kReach) {
                            continue;
                        }
                        const std::size_t j = e.j;
                        if (reliable.empty()) {  // s is in the leaf, s1 too unless past its face
                            f0 = (double(leaves[L]->getValue(s)) - iso) / voxel;
                            f1 = (double((s1[axis] & 7) ? leaves[L]->getValue(s1)
                                                        : acc.getValue(s1)) -
                                  iso) /
                                 voxel;
                        }
                        reliable.push_back(j);
                        const openvdb::Vec3d nj(data[j].normal), pj(data[j].point);
                        const PlaneLine line{nj.dot(v0 - pj), nj.dot(v1 - pj)};
                        if (std::fabs(f0 - line.at0) <= kMatch) end0.push_back(line);
                        if (std::fabs(f1 - line.at1) <= kMatch) end1.push_back(line);
                        if (!(rise * nj[axis] > 0.05)) continue;
                        const double t = -line.at0 / nj[axis];
                        if (!(t >= 0.0 && t <= 1.0)) continue;
                        cand.push_back({j, t, rise > 0.0 ? t : 1.0 - t, f0 - line.at0,
                                        f1 - line.at1, std::fabs(nj.dot(p - pj)), nj.dot(n)});
                    }
                    if (const PlaneCandidate* pick =
                            pick_plane(cand, reliable, data, f0, f1, end0, end1)) {
                        found.push_back({std::uint32_t(i), std::uint32_t(pick->j), pick->t});
                    }
                }
            }
        });
    for (const std::vector<Repair>& found : repairs) {
        for (const Repair& e : found) {
            const int axis = crossings.axis[e.i];
            data[e.i].point[axis] = float(double(crossings.start[e.i][axis]) + e.t);
            data[e.i].normal = data[e.j].normal;
            data[e.i].weight = data[e.j].weight;
        }
    }
}

/// One patch vertex before global numbering.
struct PatchVertex {
    openvdb::Vec3f position;
    openvdb::Vec3f normal;  ///< mean normal of the patch's crossings
    float level;            ///< the trilinear sdf minus the iso-value at the vertex, in voxels
};

/// How far a vertex may leave its cell, in voxels. Where a corner or edge of the shape is thinner
/// than the grid (a rotated box's corner), no cell around it changes sign and its vertex has to
/// come from a neighbouring cell. The corner of a rotated box can lie up to about a voxel from
/// the nearest cell whose crossings see all three faces (half a voxel cut 1 corner in 12 random
/// boxes by 0.3 voxel).
constexpr double kCellMargin = 1.0;
/// ... and a corner that the planes of its patch pass through (exact_corner, solve_qef): the
/// fan's blade-tip corners lie up to ~1.3 voxel outside the nearest cell whose crossings see all
/// three faces (1.0 cut one by 0.28 voxel at 1.5x the sample spacing).
constexpr double kCornerMargin = 1.5;

/// The least weight a crossing's plane has in the quadric. A low weight says its normal is
/// doubtful, but a doubtful plane still locates the vertex better than the mass point in a
/// direction no other crossing constrains: without the floor a curved wall meeting a flat face
/// (a drilled hole's rim, normals weighted ~0.02 by the curvature) fell below the truncation and
/// the rim vertex slid 0.3 voxel onto the face.
constexpr float kMinPlaneWeight = 0.2f;

/// What the vertex placement needs: Hermite data of every crossing.
struct QefData {
    const FillLater<HermiteSample>& data;
    double truncation, bias;
};

/// The truncated solution of ata x = atb when the quadric is dominated by one direction, as for
/// a flat patch (normals within a degree): only the largest eigenvalue lambda_1 passes the
/// truncation (relative cutoff `truncation`^2 lambda_1) and x = (v . atb / lambda_1) v with v its
/// eigenvector. v comes from power iteration started at the patch's mean normal `start`, which
/// converges by a factor lambda_2 / lambda_1 <= truncation^2 per step; three steps leave an error
/// far below float precision (the bunny's mesh bytes did not change) for less work than a full
/// eigendecomposition. False (no solution) when the other two eigenvalues might pass the cutoff:
/// their sum, the trace minus lambda_1, exceeds it.
bool flat_solution(const Eigen::Matrix3d& ata, const Eigen::Vector3d& atb,
                   const Eigen::Vector3d& start, double truncation, Eigen::Vector3d& x) {
    Eigen::Vector3d v = start;
    for (int step = 0; step < 3; ++step) v = (ata * v).normalized();
    const double lambda = v.dot(ata * v);
    if (!(lambda > 0.0) || ata.trace() - lambda > truncation * truncation * lambda) return false;
    x = (v.dot(atb) / lambda) * v;
    return true;
}

/// A patch's Hermite data, read once (the solves below each go over it): crossing points,
/// unit normals and weights, and their mass point.
struct PatchPlanes {
    Eigen::Vector3d P[12], N[12];
    double W[12];
    int n = 0;
    Eigen::Vector3d mass;
};

/// The quadric in y = x - mass, E(y) = y^T ata y - 2 atb^T y + const: each plane weighted by its
/// Hermite weight (at least kMinPlaneWeight) times robust[i], plus bias |y|^2.
struct Quadric {
    Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
    Eigen::Vector3d atb = Eigen::Vector3d::Zero();

    Quadric() = default;
    Quadric(const PatchPlanes& pl, const double* robust, double bias)
        : ata(bias * Eigen::Matrix3d::Identity()), atb(Eigen::Vector3d::Zero()) {
        for (int i = 0; i < pl.n; ++i) {
            const Eigen::Vector3d& nn = pl.N[i];
            const double b = nn.dot(pl.P[i] - pl.mass);
            const double w = std::max(double(kMinPlaneWeight), pl.W[i]) * robust[i];
            ata += w * nn * nn.transpose();
            atb += w * b * nn;
        }
    }

    /// The minimiser with singular values below `truncation` times the largest dropped.
    Eigen::Vector3d truncated(double truncation) const {
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
        es.computeDirect(ata);
        const Eigen::Vector3d lambda = es.eigenvalues();  // ascending, = singular values squared
        const double cutoff = truncation * truncation * lambda[2];
        Eigen::Vector3d y = Eigen::Vector3d::Zero();
        for (int k = 0; k < 3; ++k) {
            if (lambda[k] > cutoff && lambda[k] > 0.0) {
                const Eigen::Vector3d v = es.eigenvectors().col(k);
                y += (v.dot(atb) / lambda[k]) * v;
            }
        }
        return y;
    }
};

/// The vertex of a patch whose planes meet at a feature. One crossing whose normal was smeared
/// across the kink tilts the solution off both faces; iteratively reweighted least squares with
/// a Cauchy weight on each plane's residual (in voxels) lets the consistent planes win. Returns
/// the vertex and, in `last`, the last round's quadric.
Eigen::Vector3d reweighted_solve(const PatchPlanes& pl, double truncation, double bias,
                                 Quadric& last) {
    double robust[12];
    std::fill(robust, robust + pl.n, 1.0);
    Eigen::Vector3d y;
    for (int round = 0; round < 4; ++round) {
        last = Quadric(pl, robust, bias);
        y = last.truncated(truncation);
        for (int i = 0; i < pl.n; ++i) {
            const double r = pl.N[i].dot(y + pl.mass - pl.P[i]) / 0.02;
            robust[i] = 1.0 / (1.0 + r * r);
        }
    }
    return y + pl.mass;
}

constexpr double kExactCorner = 0.05;  ///< voxels (see exact_corner)

/// Whether the planes of the patch's crossings that are not unreliable (weight >= kUnreliable,
/// at least three crossings) all pass within kExactCorner voxels of x: exact faces meeting at x
/// (a corner, or a point of an edge when the crossings hold two planes). A crossing next to a
/// corner often has a middling weight (0.535 on the fan's cap next to a blade tip, whose corner
/// was 0.17 voxel off when only weights >= kReliable counted).
bool exact_corner(const PatchPlanes& pl, const Eigen::Vector3d& x) {
    int counted = 0;
    for (int i = 0; i < pl.n; ++i) {
        if (pl.W[i] < double(kUnreliable)) continue;
        if (!(std::fabs(pl.N[i].dot(x - pl.P[i])) <= kExactCorner)) return false;
        ++counted;
    }
    return counted >= 3;
}

/// A curved but smooth patch (normals spread by more than ~0.8 and less than ~25 degrees) has
/// no feature to keep, and the intersection of its tangent planes lies off the curved surface
/// (outside a convex one by about t^2 / 2R for crossings at tangential distance t). The vertex
/// goes on the line through the mass point m along the mean normal, at the mean of each
/// crossing's second-order estimate of the surface there: its tangent plane's height a_i,
/// corrected by the bend its normal shows, -(p_i - m).(n_i - mean_n) / 2 -- exact to second
/// order for any radius of curvature, and it needs only the Hermite data (the trilinear field,
/// which would serve too, is rounded next to sharp edges and pulled vertices off flat faces
/// there). False when no crossing's normal is within 60 degrees of the mean.
bool smooth_estimate(const PatchPlanes& pl, const Eigen::Vector3d& mean_n, Eigen::Vector3d& x) {
    double sum = 0.0, wsum = 0.0;
    for (int i = 0; i < pl.n; ++i) {
        const Eigen::Vector3d &p = pl.P[i], &nn = pl.N[i];
        const double cosine = nn.dot(mean_n);
        if (!(cosine > 0.5)) continue;
        const Eigen::Vector3d d = p - pl.mass;
        sum += pl.W[i] * (nn.dot(d) / cosine - 0.5 * d.dot(nn - mean_n));
        wsum += pl.W[i];
    }
    if (!(wsum > 0.0)) return false;
    x = pl.mass + (sum / wsum) * mean_n;
    return true;
}

/// Planes of a curved face at a feature, as one: the doubtful planes (weight < kUnreliable) whose
/// normals lie within 25 degrees of the first of them and are not all parallel become the
/// second-order plane of smooth_estimate, through the surface point over their mass point, with
/// their mean normal and the weight they had together in the quadric (each at least
/// kMinPlaneWeight). The tangent planes of a curved face
/// disagree with each other by the bend between their crossings: the reweighting read that as
/// noise and dropped them, and the bias pulled the vertex to the mass point (a drilled hole's
/// rim, where its wall of 8 voxels' radius meets the top face: 0.16 voxel inside the top face,
/// 60,000 samples, a voxel of 3x the spacing). Exact planes (weight >= kUnreliable) stay as
/// they are; so do the planes of a face seen cleanly.
void merge_curved(PatchPlanes& pl) {
    constexpr double kCurvedFace = 0.9063;  // cos 25 degrees
    bool used[12] = {};
    PatchPlanes out;
    out.mass = pl.mass;
    for (int i = 0; i < pl.n; ++i) {
        if (used[i]) continue;
        used[i] = true;
        int member[12], count = 1;
        member[0] = i;
        if (pl.W[i] < double(kUnreliable)) {
            for (int j = i + 1; j < pl.n; ++j) {
                if (used[j] || !(pl.W[j] < double(kUnreliable)) ||
                    !(pl.N[i].dot(pl.N[j]) > kCurvedFace)) {
                    continue;
                }
                used[j] = true;
                member[count++] = j;
            }
        }
        Eigen::Vector3d mean_n = Eigen::Vector3d::Zero();
        double min_cos = 1.0;
        for (int k = 0; k < count; ++k) mean_n += pl.N[member[k]];
        mean_n.normalize();
        for (int k = 0; k < count; ++k) min_cos = std::min(min_cos, mean_n.dot(pl.N[member[k]]));
        if (count == 1 || !(min_cos < 0.99995)) {
            for (int k = 0; k < count; ++k) {
                out.P[out.n] = pl.P[member[k]];
                out.N[out.n] = pl.N[member[k]];
                out.W[out.n++] = pl.W[member[k]];
            }
            continue;
        }
        PatchPlanes face;
        face.mass = Eigen::Vector3d::Zero();
        double weight = 0.0;
        for (int k = 0; k < count; ++k) {
            face.P[k] = pl.P[member[k]];
            face.N[k] = pl.N[member[k]];
            face.W[k] = std::max(double(kMinPlaneWeight), pl.W[member[k]]);
            face.mass += face.P[k];
            weight += face.W[k];
        }
        face.n = count;
        face.mass /= double(count);
        Eigen::Vector3d x;
        if (!smooth_estimate(face, mean_n, x)) x = face.mass;
        out.P[out.n] = x;
        out.N[out.n] = mean_n;
        out.W[out.n++] = weight;
    }
    pl = out;
}

/// The vertex of one patch (the crossings `edges[0..n)` of `cell`), and the patch's mean normal.
openvdb::Vec3d solve_qef(const SurfaceCell& cell, const std::uint8_t* edges, int n,
                         const QefData& q, openvdb::Vec3f& normal, bool& smooth) {
    smooth = false;
    PatchPlanes pl;
    pl.n = n;
    pl.mass = Eigen::Vector3d::Zero();
    for (int i = 0; i < n; ++i) {
        const HermiteSample& h = q.data[std::size_t(cell.edge_id[edges[i]])];
        pl.P[i] = Eigen::Vector3d(h.point[0], h.point[1], h.point[2]);
        pl.N[i] = Eigen::Vector3d(h.normal[0], h.normal[1], h.normal[2]);
        pl.W[i] = h.weight;
        pl.mass += pl.P[i];
    }
    pl.mass /= double(n);
    // Spread of the normals: decides between the feature path (planes meet at an edge or corner)
    // and the smooth path (project onto the level set, below).
    double min_cos = 1.0;
    Eigen::Vector3d mean_n = Eigen::Vector3d::Zero();
    for (int i = 0; i < n; ++i) mean_n += pl.N[i];
    mean_n.normalize();
    normal = openvdb::Vec3f(float(mean_n[0]), float(mean_n[1]), float(mean_n[2]));
    for (int i = 0; i < n; ++i) min_cos = std::min(min_cos, mean_n.dot(pl.N[i]));
    double margin = kCellMargin;
    const auto inside = [&](const Eigen::Vector3d& x) {
        for (int a = 0; a < 3; ++a) {
            if (!(x[a] >= cell.origin[a] - margin && x[a] <= cell.origin[a] + 1.0 + margin)) {
                return false;
            }
        }
        return true;
    };
    const double ones[12] = {1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1};
    Quadric quad;  // of the solution, for the box-constrained minimum below
    Eigen::Vector3d x;
    if (min_cos > 0.9 && min_cos < 0.9999 && smooth_estimate(pl, mean_n, x)) {
        // No quadric is solved then; it is built only if the vertex leaves the cell.
        if (inside(x)) {
            smooth = true;
            return openvdb::Vec3d(x[0], x[1], x[2]);
        }
        quad = Quadric(pl, ones, q.bias);
    } else if (min_cos < 0.9) {
        // The feature path. The bias pulls the solution towards the mass point by bias / lambda
        // along a weakly constrained direction (between the faces of the fan's 40-degree blade
        // tips, lambda ~ 0.3), and the reweighting then reads that pull as the residual of the
        // plane that constrains the direction and drives it out: the tip's corner vertex slid
        // 0.64 voxel onto the edge of the other two faces. So the planes are first solved
        // without the bias; where the planes pass through that solution (exact_corner) it is
        // the vertex, a corner of exact faces, which may lie up to kCornerMargin outside the cell
        // (an acute tip, thinner than the grid, changes the sign of no cell around it). Else (a
        // scan's noisy planes) the bias keeps the vertex near its crossings.
        merge_curved(pl);
        x = reweighted_solve(pl, q.truncation, 0.0, quad);
        if (exact_corner(pl, x)) {
            margin = kCornerMargin;
        } else if (std::any_of(pl.W, pl.W + pl.n, [](double w) { return w >= kUnreliable; })) {
            // With an exact plane among them, the bias joins the last round's weights once:
            // reweighting with the bias in place drove out a plane that alone held a direction
            // (a boss's rim, 1.5x the spacing: its one cylinder plane, weight 0.24, 0.17 voxel
            // off). Where every plane is doubtful (estimated normals, scans) the bias stays in
            // every round and keeps noisy planes near their crossings (once there: the boss
            // from estimated normals at 1x, seed 10, 1.73 -> 2.08 voxel).
            quad.ata += q.bias * Eigen::Matrix3d::Identity();
            x = quad.truncated(q.truncation) + pl.mass;
        } else {
            x = reweighted_solve(pl, q.truncation, q.bias, quad);
        }
    } else {
        quad = Quadric(pl, ones, q.bias);
        if (flat_solution(quad.ata, quad.atb, mean_n, q.truncation, x)) {
            smooth = min_cos < 0.999999;  // a curved patch, however gently; not a plane's
        } else {
            x = quad.truncated(q.truncation);
        }
        x += pl.mass;
    }
    if (inside(x)) return openvdb::Vec3d(x[0], x[1], x[2]);
    smooth = false;  // the box-constrained minimum below is no surface estimate to refine
    // Outside the (grown) cell: minimise the quadric over it instead. It is convex, so coordinate
    // descent from the clamped point converges to the box-constrained minimum (a clamp alone
    // would slide the vertex off the surface). E(y) = y^T Q y - 2 c^T y, y = x - mass.
    Eigen::Vector3d y, ylo, yhi;
    for (int a = 0; a < 3; ++a) {
        ylo[a] = double(cell.origin[a]) - margin - pl.mass[a];
        yhi[a] = double(cell.origin[a]) + 1.0 + margin - pl.mass[a];
        y[a] = std::clamp(x[a] - pl.mass[a], ylo[a], yhi[a]);
    }
    const Eigen::Matrix3d& ata = quad.ata;
    const Eigen::Vector3d& atb = quad.atb;
    for (int sweep = 0; sweep < 32; ++sweep) {
        for (int a = 0; a < 3; ++a) {
            if (!(ata(a, a) > 0.0)) continue;
            const double rest = ata.row(a).dot(y) - ata(a, a) * y[a];
            y[a] = std::clamp((atb[a] - rest) / ata(a, a), ylo[a], yhi[a]);
        }
    }
    x = y + pl.mass;
    return openvdb::Vec3d(x[0], x[1], x[2]);
}

/// The trilinear sdf minus `iso` at the index-space point x, in voxels: from the corners of
/// `cell` when x lies in it (the usual case for a vertex), else from the tree (inactive voxels
/// read as their stored value).
float level_at(const SurfaceCell& cell, const openvdb::Vec3d& x, FloatAccessor& acc, float iso,
               double inv_voxel, openvdb::Vec3d* grad = nullptr) {
    openvdb::Coord c = cell.origin;
    openvdb::Vec3d t = x - c.asVec3d();
    float f[8];
    std::copy(cell.value, cell.value + 8, f);
    if (!(t[0] >= 0.0 && t[0] <= 1.0 && t[1] >= 0.0 && t[1] <= 1.0 && t[2] >= 0.0 && t[2] <= 1.0)) {
        c = openvdb::Coord(int(std::floor(x[0])), int(std::floor(x[1])), int(std::floor(x[2])));
        t = x - c.asVec3d();
        for (int k = 0; k < 8; ++k) {
            f[k] =
                acc.getValue(c.offsetBy(kCubeCorner[k][0], kCubeCorner[k][1], kCubeCorner[k][2]));
        }
    }
    double v = 0.0;
    openvdb::Vec3d g(0.0);
    for (int k = 0; k < 8; ++k) {
        const double wx = kCubeCorner[k][0] ? t[0] : 1.0 - t[0],
                     wy = kCubeCorner[k][1] ? t[1] : 1.0 - t[1],
                     wz = kCubeCorner[k][2] ? t[2] : 1.0 - t[2];
        const double fk = double(f[k]) - iso;
        v += wx * wy * wz * fk;
        if (!grad) continue;  // the level alone, for most vertices
        g[0] += (kCubeCorner[k][0] ? 1.0 : -1.0) * wy * wz * fk;
        g[1] += (kCubeCorner[k][1] ? 1.0 : -1.0) * wx * wz * fk;
        g[2] += (kCubeCorner[k][2] ? 1.0 : -1.0) * wx * wy * fk;
    }
    if (grad) *grad = g * inv_voxel;
    return float(v * inv_voxel);
}

/// A vertex of a smooth or gently curved patch moved along the patch's normal `n` onto the
/// zero of the trilinear field (two Newton steps); returns its level there (level_at). The
/// Hermite estimate (solve_qef) is second-order exact for a clean distance field, but on a
/// splatted field its normals carry the noise of the gradients: the field's own zero lies
/// closer to the surface (dc's Chamfer distance on a sphere, torus and blob at 1-3 voxels per
/// sample spacing 0.0055-0.0105 -> 0.0026-0.0071 voxel, below marching cubes'; the bunny scans
/// 60.6 -> 59.5 um). A step is taken only where the field agrees with the patch: its gradient
/// within 5 degrees of n and its zero within 0.03 voxel. Next to a sharp edge the trilinear
/// field is rounded and the step would pull the vertex off the face.
float onto_level_set(const SurfaceCell& cell, const openvdb::Vec3f& n, FloatAccessor& acc,
                     float iso, double inv_voxel, openvdb::Vec3d& x) {
    const openvdb::Vec3d nn(n);
    for (int step = 0;; ++step) {
        openvdb::Vec3d g;
        const float level = level_at(cell, x, acc, iso, inv_voxel, &g);
        const double d = g.dot(nn), f = double(level);
        if (step == 2 || !(d > 0.996 * g.length()) || std::fabs(f / d) > 0.03) return level;
        x -= (f / d) * nn;
    }
}

}  // namespace

/// Hermite data at the crossings, leaf by leaf (a crossing's stencils stay in its leaf's block).
FillLater<HermiteSample> hermite_data(
    const openvdb::FloatTree& tree, const Crossings& crossings,
    const std::vector<const openvdb::FloatTree::LeafNodeType*>& leaves, float iso) {
    FillLater<HermiteSample> data(crossings.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size(), 8),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          FloatAccessor acc(tree);
                          auto block = std::make_unique<LeafBlock>(acc);
                          // Robust gradients of the block's voxels, computed once per leaf
                          // (a voxel ends up to six crossing edges).
                          struct Cached {
                              openvdb::Vec3d g;
                              double misfit;
                              std::uint32_t stamp;
                              bool have;
                          };
                          std::vector<Cached> cache(LeafBlock::kN * LeafBlock::kN * LeafBlock::kN,
                                                    Cached{{0.0, 0.0, 0.0}, 0.0, 0u, false});
                          std::uint32_t stamp = 0;
                          auto gradient = [&](const openvdb::Coord& v, openvdb::Vec3d& g,
                                              double& misfit) {
                              int i;
                              if (!block->index(v, i) || !block->interior(i)) {
                                  Stencil27 s;
                                  s.gather(acc, v);
                                  return robust_gradient(s.f + Stencil27::kCentre,
                                                         s.on + Stencil27::kCentre,
                                                         Stencil27::kStep, g, misfit);
                              }
                              Cached& c = cache[std::size_t(i)];
                              if (c.stamp != stamp) {
                                  c.have = robust_gradient(block->values() + i,
                                                           block->actives() + i, LeafBlock::kStep,
                                                           c.g, c.misfit);
                                  c.stamp = stamp;
                              }
                              g = c.g;
                              misfit = c.misfit;
                              return c.have;
                          };
                          for (std::size_t L = r.begin(); L < r.end(); ++L) {
                              const std::size_t begin = crossings.leaf_begin[L],
                                                end = crossings.leaf_begin[L + 1];
                              if (begin == end) continue;
                              block->load(leaves[L]->origin());
                              ++stamp;
                              for (std::size_t i = begin; i < end; ++i) {
                                  openvdb::Vec3d p;
                                  hermite(*block, gradient, crossings.start[i], crossings.axis[i],
                                          iso, p, data[i].normal, data[i].weight);
                                  data[i].point = openvdb::Vec3f(p);
                              }
                          }
                      });
    return data;
}

/// Which diagonal splits a quad (vertices v, counter-clockwise seen from outside): true for
/// v[0]-v[2]. Next to a sharp edge the diagonal must run along it, between the two vertices
/// whose patch normals agree, not across it (which cuts the edge off). The field cannot tell: it
/// is rounded at the edge. Where the normals do not discriminate, the field decides.
bool dc_diagonal02(const RawSurface& raw, const FillLater<float>& level,
                   const std::array<std::int32_t, 4>& v) {
    const openvdb::Vec3f* x[4];
    const openvdb::Vec3f* n[4];
    double e[4];
    for (int k = 0; k < 4; ++k) {
        x[k] = &raw.points[std::size_t(v[k])];
        n[k] = &raw.normals[std::size_t(v[k])];
        e[k] = double(level[std::size_t(v[k])]);
    }
    const double agree02 = double(n[0]->dot(*n[2])), agree13 = double(n[1]->dot(*n[3]));
    if (std::fabs(agree02 - agree13) > 0.05) return agree02 > agree13;
    // The diagonal whose triangles stay closer to the zero level: the field at each triangle's
    // centroid, estimated to second order from its vertices. For a quadratic f with Hessian H,
    // f at the centroid of x_1..x_3 is sum_i f(x_i) / 3 - sum_{i<j} d_ij^T H d_ij / 18 with
    // d_ij = x_j - x_i, and d_ij^T H d_ij = d_ij . (grad f(x_j) - grad f(x_i)). f(x_i) is the
    // vertex's level; the gradient of a distance field (voxels per voxel) is its unit normal,
    // taken as the patch normal. This replaces four trilinear lookups per quad.
    const auto bend = [&](int a, int b) { return double((*x[b] - *x[a]).dot(*n[b] - *n[a])); };
    const auto off = [&](int a, int b, int d) {
        return std::fabs((e[a] + e[b] + e[d]) / 3.0 -
                         (bend(a, b) + bend(b, d) + bend(a, d)) / 18.0);
    };
    return off(0, 1, 2) + off(0, 2, 3) <= off(0, 1, 3) + off(1, 2, 3);
}

RawSurface mesh_dc(const Volume& volume, const MeshOptions& options) {
    const openvdb::FloatTree& tree = volume.sdf->tree();
    const float iso = float(options.isovalue);
    Crossings crossings = find_crossings(tree, iso, false);

    std::vector<const openvdb::FloatTree::LeafNodeType*> leaves;
    tree.getNodes(leaves);
    FillLater<HermiteSample> data = hermite_data(tree, crossings, leaves, iso);
    repair_hermite(crossings, tree, leaves, volume.sdf->voxelSize()[0], iso, data);
    // One vertex per chain, at the minimiser of its quadric.
    const QefData qef{data, options.dc_truncation, options.dc_bias};
    const double inv_voxel = 1.0 / volume.sdf->voxelSize()[0];
    DualVertices<PatchVertex> vertices(leaves.size(), crossings.size());
    for_each_surface_cell(
        tree, crossings, iso, [&](std::size_t L, const SurfaceCell& cell, FloatAccessor& acc) {
            for (int l = 0; l < cell.loops.count; ++l) {
                int start[12], size[12];
                const int chains = loop_chains(cell, l, acc, iso, start, size);
                for (int c = 0; c < chains; ++c) {
                    std::uint8_t chain[12];
                    const int n = cell.loops.size[l];
                    for (int i = 0; i < size[c]; ++i)
                        chain[i] = cell.loops.edge[l][(start[c] + i) % n];
                    PatchVertex v;
                    bool smooth = false;
                    openvdb::Vec3d x = solve_qef(cell, chain, size[c], qef, v.normal, smooth);
                    v.level = smooth ? onto_level_set(cell, v.normal, acc, iso, inv_voxel, x)
                                     : level_at(cell, x, acc, iso, inv_voxel);
                    v.position = openvdb::Vec3f(x);
                    vertices.add(L, cell, l, start[c], size[c], v);
                }
            }
        });

    // What the quads no longer need goes before they are made (the mesh stage's peak memory).
    release(data);
    release(crossings.masks);
    release(crossings.start);
    release(crossings.axis);

    RawSurface raw;
    // The patch normals are the vertex normals too: a mean of the crossings' robust gradients,
    // they stay true next to sharp edges, where the SDF's gradient at the vertex is smeared.
    const std::size_t count = vertices.number();
    raw.points.resize(count);
    std::vector<openvdb::Vec3f>& patch_normal = raw.normals;
    patch_normal.resize(count);
    FillLater<float> level(count);
    vertices.gather([&](std::size_t i, const PatchVertex& v) {
        raw.points[i] = v.position;
        patch_normal[i] = v.normal;
        level[i] = v.level;
    });
    vertices.emit_quads(crossings, raw.triangles, [&](const std::array<std::int32_t, 4>& v) {
        return dc_diagonal02(raw, level, v);
    });
    return raw;
}

}  // namespace vdbrecon::detail
