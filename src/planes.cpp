// Planar regions with crisp edges (see planes.h).
#include "vdbrecon/planes.h"

#include <Eigen/Dense>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <string>
#include <unordered_set>

#include "detail/mesh_graph.h"
#include "vdbrecon/decimate.h"
#include "vdbrecon/error.h"

namespace vdbrecon {

void PlaneOptions::validate() const {
    auto check = [](bool ok, const char* field, double v, const char* rule) {
        if (!ok) {
            throw InvalidArgument(std::string("planes.") + field + " = " + std::to_string(v) +
                                  ": " + rule);
        }
    };
    check(angle > 0.0 && angle < 90.0, "angle", angle, "must be in (0, 90) degrees");
    check(std::isfinite(distance) && distance > 0.0, "distance", distance,
          "must be a positive number of voxels");
    check(std::isfinite(min_area) && min_area >= 0.0, "min_area", min_area,
          "must be a non-negative number of square voxels");
    check(std::isfinite(max_move) && max_move > 0.0, "max_move", max_move,
          "must be a positive number of voxels");
    check(std::isfinite(max_error) && max_error > 0.0, "max_error", max_error,
          "must be a positive number of voxels");
    check(std::isfinite(region_error) && region_error > 0.0, "region_error", region_error,
          "must be a positive number of voxels");
}

namespace {

using V3 = Eigen::Vector3d;

V3 vec(const Vec3f& v) { return {double(v[0]), double(v[1]), double(v[2])}; }

/// Per face: unit normal (zero when degenerate), area, centroid, the faces across its edges
/// (-1 at a border or a non-manifold edge).
struct FaceData {
    std::vector<V3> normal, centre;
    std::vector<V3> smooth;  ///< smooth_normals()
    std::vector<double> area;
    std::vector<std::array<std::int32_t, 3>> across;
};

FaceData face_data(const Mesh& m) {
    const std::size_t nf = m.faces.size();
    FaceData d;
    d.normal.resize(nf);
    d.centre.resize(nf);
    d.area.resize(nf);
    d.across.assign(nf, {-1, -1, -1});
    for (std::size_t f = 0; f < nf; ++f) {
        const Triangle& t = m.faces[f];
        const V3 a = vec(m.vertices[std::size_t(t[0])]), b = vec(m.vertices[std::size_t(t[1])]),
                 c = vec(m.vertices[std::size_t(t[2])]);
        const V3 n = (b - a).cross(c - a);
        d.area[f] = 0.5 * n.norm();
        d.normal[f] = d.area[f] > 0.0 ? V3(n / n.norm()) : V3::Zero();
        d.centre[f] = (a + b + c) / 3.0;
    }
    detail::manifold_pairs(detail::sorted_sides(m.faces, [](std::size_t) { return true; }),
                           [&](const detail::EdgeSide& x, const detail::EdgeSide& y) {
                               d.across[std::size_t(x.face)][std::size_t(x.slot)] = y.face;
                               d.across[std::size_t(y.face)][std::size_t(y.slot)] = x.face;
                           });
    return d;
}

/// Scans are bumpy at the scale of a face: the growth compares the plane with each face's
/// normal averaged with its neighbours' that lie within `cos_angle` of it (not across a crease).
void smooth_normals(FaceData& d, double cos_angle) {
    const std::size_t nf = d.area.size();
    d.smooth.resize(nf);
    for (std::size_t f = 0; f < nf; ++f) {
        V3 n = d.area[f] * d.normal[f];
        for (std::int32_t g : d.across[f]) {
            if (g >= 0 && d.normal[std::size_t(g)].dot(d.normal[f]) >= cos_angle) {
                n += d.area[std::size_t(g)] * d.normal[std::size_t(g)];
            }
        }
        d.smooth[f] = n.norm() > 0.0 ? V3(n.normalized()) : V3::Zero();
    }
}

/// Faces in the order regions are seeded: flattest first (the largest angle to a neighbour),
/// ties by position (not by index: the same surface numbered otherwise, as tiles number it,
/// grows the same regions).
std::vector<std::int32_t> seed_order(const FaceData& d) {
    const std::size_t nf = d.area.size();
    std::vector<double> rough(nf, 2.0);
    for (std::size_t f = 0; f < nf; ++f) {
        double r = 0.0;
        for (std::int32_t g : d.across[f]) {
            r = std::max(r, g < 0 ? 2.0 : 1.0 - d.normal[f].dot(d.normal[std::size_t(g)]));
        }
        rough[f] = r;
    }
    std::vector<std::int32_t> order(nf);
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](std::int32_t a, std::int32_t b) {
        const double ra = rough[std::size_t(a)], rb = rough[std::size_t(b)];
        if (ra != rb) return ra < rb;
        const V3 &ca = d.centre[std::size_t(a)], &cb = d.centre[std::size_t(b)];
        if (ca[0] != cb[0]) return ca[0] < cb[0];
        if (ca[1] != cb[1]) return ca[1] < cb[1];
        return ca[2] != cb[2] ? ca[2] < cb[2] : a < b;
    });
    return order;
}

/// The least-squares plane of the faces' vertices, its normal turned like `towards`.
Plane fit_plane(const Mesh& m, const std::vector<std::int32_t>& faces, const V3& towards,
                double area) {
    std::vector<std::int32_t> verts;
    for (std::int32_t f : faces) {
        for (std::int32_t v : m.faces[std::size_t(f)]) verts.push_back(v);
    }
    std::sort(verts.begin(), verts.end());
    verts.erase(std::unique(verts.begin(), verts.end()), verts.end());
    // Summed in the order of their positions, not their numbers (a tiled mesh numbers them
    // otherwise and must get the same plane).
    std::sort(verts.begin(), verts.end(), [&](std::int32_t a, std::int32_t b) {
        const Vec3f &pa = m.vertices[std::size_t(a)], &pb = m.vertices[std::size_t(b)];
        return pa != pb ? pa < pb : a < b;
    });
    V3 c = V3::Zero();
    for (std::int32_t v : verts) c += vec(m.vertices[std::size_t(v)]);
    c /= double(verts.size());
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    for (std::int32_t v : verts) {
        const V3 e = vec(m.vertices[std::size_t(v)]) - c;
        cov += e * e.transpose();
    }
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
    V3 n = eig.eigenvectors().col(0);
    if (n.dot(towards) < 0.0) n = -n;
    Plane p;
    p.normal = {n[0], n[1], n[2]};
    p.offset = n.dot(c);
    p.area = area;
    return p;
}

/// Region growing (see planes.h, step 1-2): per face its region (-1: none), and the planes.
std::vector<std::int32_t> grow_regions(const Mesh& m, const FaceData& d, const PlaneOptions& o,
                                       double voxel, std::vector<Plane>& planes) {
    const std::size_t nf = d.area.size();
    const double cos_angle = std::cos(o.angle * M_PI / 180.0);
    const double dist = o.distance * voxel, min_area = o.min_area * voxel * voxel;
    std::vector<std::int32_t> region(nf, -1), tried(nf, -1);
    std::vector<char> seeded(nf, 0);
    std::vector<std::int32_t> members;
    std::int32_t attempt = 0;
    for (const std::int32_t seed : seed_order(d)) {
        if (region[std::size_t(seed)] >= 0 || seeded[std::size_t(seed)] ||
            d.area[std::size_t(seed)] == 0.0) {
            continue;
        }
        ++attempt;
        V3 n = d.normal[std::size_t(seed)];
        double offset = n.dot(d.centre[std::size_t(seed)]);
        V3 sum_an = V3::Zero(), sum_ac = V3::Zero();
        double sum_a = 0.0;
        std::size_t refit = 2;
        members.assign(1, seed);
        tried[std::size_t(seed)] = attempt;
        for (std::size_t q = 0; q < members.size(); ++q) {
            const std::size_t f = std::size_t(members[q]);
            sum_an += d.area[f] * d.normal[f];
            sum_ac += d.area[f] * d.centre[f];
            sum_a += d.area[f];
            if (members.size() >= refit) {  // the plane of the region so far
                n = sum_an.normalized();
                offset = n.dot(sum_ac / sum_a);
                refit *= 2;
            }
            for (const std::int32_t g : d.across[f]) {
                if (g < 0 || region[std::size_t(g)] >= 0 || tried[std::size_t(g)] == attempt ||
                    d.area[std::size_t(g)] == 0.0 || d.smooth[std::size_t(g)].dot(n) < cos_angle) {
                    continue;
                }
                bool near = true;
                for (std::int32_t v : m.faces[std::size_t(g)]) {
                    near = near && std::fabs(n.dot(vec(m.vertices[std::size_t(v)])) - offset) <= dist;
                }
                if (!near) continue;
                tried[std::size_t(g)] = attempt;
                members.push_back(g);
            }
        }
        if (sum_a < min_area) {
            for (std::int32_t f : members) seeded[std::size_t(f)] = 1;  // seeds no more attempts
            continue;
        }
        const auto id = std::int32_t(planes.size());
        for (std::int32_t f : members) region[std::size_t(f)] = id;
        planes.push_back(fit_plane(m, members, sum_an, sum_a));
    }
    return region;
}

/// Moves the vertices onto the planes of the regions around them (step 3).
void snap_vertices(Mesh& m, const std::vector<std::int32_t>& region,
                   const std::vector<Plane>& planes, const PlaneOptions& o, double voxel,
                   PlaneResult& r) {
    const std::size_t nv = m.vertices.size();
    const detail::VertexFaces vf = detail::vertex_faces(m.faces, nv);
    std::vector<Vec3f>& verts = m.vertices.edit();
    const double max_move = o.max_move * voxel, dist = o.distance * voxel;
    const double cos_crease = std::cos(std::min(3.0 * o.angle, 89.0) * M_PI / 180.0);
    std::vector<std::int32_t> around;
    for (std::size_t v = 0; v < nv; ++v) {
        around.clear();
        for (std::size_t k = vf.first[v]; k < vf.first[v + 1]; ++k) {
            const std::int32_t g = region[std::size_t(vf.around[k])];
            if (g >= 0) around.push_back(g);
        }
        std::sort(around.begin(), around.end());
        around.erase(std::unique(around.begin(), around.end()), around.end());
        if (around.empty()) continue;
        // Planes meeting at less than three times the growth angle make no crease (regions of
        // one gently curved surface): v goes onto the first region's plane only.
        bool crease = true;
        for (std::size_t i = 1; i < around.size() && crease; ++i) {
            for (std::size_t j = 0; j < i && crease; ++j) {
                const Vec3d& ni = planes[std::size_t(around[i])].normal;
                const Vec3d& nj = planes[std::size_t(around[j])].normal;
                crease = ni[0] * nj[0] + ni[1] * nj[1] + ni[2] * nj[2] < cos_crease;
            }
        }
        if (!crease) around.resize(1);
        // The point nearest to v on all its planes: (sum n n^T + eps I) x = sum n d + eps p; the
        // small eps picks the nearest such point where the planes share a direction (an edge).
        const V3 p = vec(verts[v]);
        constexpr double eps = 1e-9;
        Eigen::Matrix3d a = eps * Eigen::Matrix3d::Identity();
        V3 b = eps * p;
        for (std::int32_t g : around) {
            const Plane& pl = planes[std::size_t(g)];
            const V3 n(pl.normal[0], pl.normal[1], pl.normal[2]);
            a += n * n.transpose();
            b += pl.offset * n;
        }
        const V3 x = a.ldlt().solve(b);
        // Onto one plane, no farther than the growth let it be; onto an edge or a corner (which
        // the mesher rounded), up to max_move.
        const double most = around.size() == 1 ? std::min(max_move, dist) : max_move;
        if (!x.allFinite() || (x - p).norm() > most) continue;
        verts[v] = {float(x[0]), float(x[1]), float(x[2])};
        r.edge_vertices += around.size() == 2;
        r.corner_vertices += around.size() >= 3;
    }
}

/// A region's plane as a 2D frame (u, v, normal right-handed: counter-clockwise faces seen from
/// outside stay counter-clockwise).
struct Frame2 {
    V3 u, v;
    explicit Frame2(const Vec3d& normal) {
        const V3 n(normal[0], normal[1], normal[2]);
        int k = 0;
        for (int i = 1; i < 3; ++i) {
            if (std::fabs(n[i]) < std::fabs(n[k])) k = i;
        }
        u = V3::Unit(k).cross(n).normalized();
        v = n.cross(u);
    }
    Eigen::Vector2d operator()(const Vec3f& p) const {
        const V3 q = vec(p);
        return {q.dot(u), q.dot(v)};
    }
};

double orient(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c) {
    return (b - a).x() * (c - a).y() - (b - a).y() * (c - a).x();
}

/// > 0 when d lies inside the circle through a, b, c (counter-clockwise).
double incircle(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c,
                const Eigen::Vector2d& d) {
    const Eigen::Vector2d p = a - d, q = b - d, r = c - d;
    return p.squaredNorm() * orient({0, 0}, q, r) - q.squaredNorm() * orient({0, 0}, p, r) +
           r.squaredNorm() * orient({0, 0}, p, q);
}

/// An edge inside a region whose flip would make the pair of faces Delaunay (Lawson 1977).
struct Flip {
    std::array<double, 3> key;  ///< the edge's midpoint: the order flips are tried in
    std::int32_t f, g;
    int slot;  ///< the edge is f's corners slot, slot + 1
};

/// The flips one pass may make: edges between two faces of one region whose far corner lies
/// strictly inside the other face's circumcircle (in the region's plane), where the quad is
/// convex, the new diagonal is no edge yet, and all four corners lie within `tolerance` of the
/// plane (so the surface moves by no more). Sorted by position, not by number.
std::vector<Flip> flips_wanted(const Mesh& m, const std::vector<std::int32_t>& region,
                               const std::vector<Plane>& planes, double tolerance) {
    // The edges two faces of one region share (an edge used by more faces is left alone).
    std::vector<Flip> out;
    const auto regional = [&](std::size_t f) { return region[f] >= 0; };
    detail::manifold_pairs(detail::sorted_sides(m.faces, regional), [&](const detail::EdgeSide& x,
                                                                        const detail::EdgeSide& y) {
        const std::size_t f = std::size_t(x.face);
        const int k = x.slot;
        const std::int32_t g = y.face, r = region[f];
        if (region[std::size_t(g)] != r) return;
        const Plane& pl = planes[std::size_t(r)];
        const Triangle& t = m.faces[f];
        const std::int32_t a = t[std::size_t(k)], b = t[std::size_t((k + 1) % 3)],
                           c = t[std::size_t((k + 2) % 3)];
        std::int32_t e = -1;  // g's corner off the edge
        for (std::int32_t v : m.faces[std::size_t(g)]) {
            if (v != a && v != b) e = v;
        }
        bool flat = true;
        for (std::int32_t v : {a, b, c, e}) {
            const Vec3f& p = m.vertices[std::size_t(v)];
            flat &= std::fabs(pl.normal[0] * p[0] + pl.normal[1] * p[1] + pl.normal[2] * p[2] -
                              pl.offset) <= tolerance;
        }
        if (!flat) return;
        const Frame2 frame(pl.normal);
        const Eigen::Vector2d pa = frame(m.vertices[std::size_t(a)]),
                              pb = frame(m.vertices[std::size_t(b)]),
                              pc = frame(m.vertices[std::size_t(c)]),
                              pe = frame(m.vertices[std::size_t(e)]);
        const double scale = std::max({(pa - pc).squaredNorm(), (pb - pc).squaredNorm(),
                                       (pa - pe).squaredNorm(), (pb - pe).squaredNorm()});
        // Strictly inside (ties stay as they are); the new faces (a, e, c) and (e, b, c)
        // counter-clockwise (the quad a e b c convex).
        if (!(incircle(pa, pb, pc, pe) > 1e-9 * scale * scale)) return;
        if (!(orient(pa, pe, pc) > 1e-9 * scale && orient(pe, pb, pc) > 1e-9 * scale)) return;
        const V3 mid = 0.5 * (vec(m.vertices[std::size_t(a)]) + vec(m.vertices[std::size_t(b)]));
        out.push_back({{mid[0], mid[1], mid[2]}, std::int32_t(f), g, k});
    });
    std::sort(out.begin(), out.end(), [](const Flip& x, const Flip& y) { return x.key < y.key; });
    return out;
}

/// Makes each region's triangulation its constrained Delaunay triangulation (the region's
/// border and the vertices the collapses left are the constraints): Lawson's edge flips, in
/// passes, each flipping in position order the edges found wanting at its start, skipping
/// faces an earlier flip of the pass changed. Returns the number of flips.
std::size_t delaunay_flips(Mesh& m, const std::vector<std::int32_t>& region,
                           const std::vector<Plane>& planes, double tolerance) {
    std::size_t flips = 0;
    std::vector<Triangle>& faces = m.faces.edit();
    std::unordered_set<std::uint64_t> edges;  // every edge of the mesh, kept up to date
    for (const Triangle& t : faces) {
        for (int k = 0; k < 3; ++k) {
            edges.insert(detail::edge_key(t[std::size_t(k)], t[std::size_t((k + 1) % 3)]));
        }
    }
    for (int pass = 0; pass < 1000; ++pass) {
        const std::vector<Flip> wanted = flips_wanted(m, region, planes, tolerance);
        if (wanted.empty()) break;
        std::vector<char> touched(faces.size(), 0);
        for (const Flip& w : wanted) {
            if (touched[std::size_t(w.f)] || touched[std::size_t(w.g)]) continue;
            const Triangle t = faces[std::size_t(w.f)];
            const std::int32_t a = t[std::size_t(w.slot)], b = t[std::size_t((w.slot + 1) % 3)],
                               c = t[std::size_t((w.slot + 2) % 3)];
            std::int32_t e = -1;
            for (std::int32_t x : faces[std::size_t(w.g)]) {
                if (x != a && x != b) e = x;
            }
            if (!edges.insert(detail::edge_key(c, e)).second) continue;  // the diagonal exists
            edges.erase(detail::edge_key(a, b));
            faces[std::size_t(w.f)] = {a, e, c};
            faces[std::size_t(w.g)] = {e, b, c};
            touched[std::size_t(w.f)] = touched[std::size_t(w.g)] = 1;
            ++flips;
        }
    }
    return flips;
}

}  // namespace

PlaneResult planar_regions(const Mesh& mesh, const PlaneOptions& options, double voxel) {
    options.validate();
    if (!(std::isfinite(voxel) && voxel > 0.0)) {
        throw InvalidArgument("planar_regions: the voxel must be a positive number");
    }
    PlaneResult r;
    r.faces_before = mesh.faces.size();
    Mesh m;
    m.vertices = std::vector<Vec3f>(mesh.vertices.begin(), mesh.vertices.end());
    m.faces = std::vector<Triangle>(mesh.faces.begin(), mesh.faces.end());
    m.colors = std::vector<Vec3f>(mesh.colors.begin(), mesh.colors.end());
    m.normals = std::vector<Vec3f>(mesh.normals.begin(), mesh.normals.end());
    m.origin = mesh.origin;
    if (m.faces.empty()) {
        r.mesh = std::move(m);
        return r;
    }
    FaceData d = face_data(m);
    smooth_normals(d, std::cos(options.angle * M_PI / 180.0));
    std::vector<std::int32_t> region = grow_regions(m, d, options, voxel, r.planes);
    r.planar_faces = std::size_t(std::count_if(region.begin(), region.end(),
                                               [](std::int32_t g) { return g >= 0; }));
    snap_vertices(m, region, r.planes, options, voxel, r);
    m.regions = std::move(region);
    DecimateOptions dec;
    dec.max_error = options.max_error * voxel;
    dec.region_error = options.region_error * voxel;
    r.mesh = decimate(m, dec).mesh;
    r.flips = delaunay_flips(r.mesh, r.mesh.regions.to_vector(), r.planes,
                             options.region_error * voxel);
    r.faces_after = r.mesh.faces.size();
    return r;
}

}  // namespace vdbrecon
