// Surface extraction: options, dispatch, and what every mesher shares (see mesh.h).
#include "vdbrecon/mesh.h"

#include <openvdb/tools/Interpolation.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <limits>
#include <memory>

#include "detail/mesh_common.h"
#include "detail/mesh_graph.h"
#include "detail/release.h"
#include "vdbrecon/error.h"

namespace vdbrecon {

void MeshOptions::validate() const {
    if (!std::isfinite(isovalue)) throw InvalidArgument("mesh.isovalue must be finite");
    if (!(std::isfinite(min_surface_weight) && min_surface_weight >= 0.0)) {
        throw InvalidArgument("mesh.min_surface_weight = " + std::to_string(min_surface_weight) +
                              ": must be a non-negative number");
    }
    if (!(adaptivity >= 0.0 && adaptivity <= 1.0)) {
        throw InvalidArgument("mesh.adaptivity = " + std::to_string(adaptivity) +
                              ": must be in 0..1");
    }
    if (!(max_gap > 0.0)) {
        throw InvalidArgument("mesh.max_gap = " + std::to_string(max_gap) +
                              ": must be positive (infinity disables the test)");
    }
    if (!(dc_truncation > 0.0 && dc_truncation < 1.0)) {
        throw InvalidArgument("mesh.dc_truncation = " + std::to_string(dc_truncation) +
                              ": must be in (0, 1)");
    }
    if (!(dc_bias >= 0.0 && std::isfinite(dc_bias))) {
        throw InvalidArgument("mesh.dc_bias = " + std::to_string(dc_bias) +
                              ": must be a non-negative number");
    }
}

namespace detail {
namespace {

/// The cells whose closed boxes contain the index-space point p (up to eps): lo..hi per axis.
void cells_around(const openvdb::Vec3d& p, int lo[3], int hi[3]) {
    constexpr double eps = 1e-4;
    for (int a = 0; a < 3; ++a) {
        lo[a] = int(std::floor(p[a] - eps));
        hi[a] = int(std::floor(p[a] + eps));
    }
}

/// Every cell whose closed box contains the index-space point `p` (up to eps) is valid.
bool point_in_valid_cells(FloatAccessor& acc, const openvdb::Vec3d& p) {
    int lo[3], hi[3];
    cells_around(p, lo, hi);
    for (int x = lo[0]; x <= hi[0]; ++x) {
        for (int y = lo[1]; y <= hi[1]; ++y) {
            for (int z = lo[2]; z <= hi[2]; ++z) {
                if (!cell_valid(acc, openvdb::Coord(x, y, z))) return false;
            }
        }
    }
    return true;
}

/// The SDF around one cell, for the gradient at points inside it: the cell's eight corners and
/// their axis neighbours outside the cell (32 voxels), read once instead of seven reads per
/// corner. gradient() is the trilinear blend of the corners' central differences (one-sided next
/// to inactive voxels; zero at an inactive corner).
class CellStencil {
public:
    void load(FloatAccessor& acc, const openvdb::Coord& c) {
        for (int x = 0; x < 4; ++x) {
            for (int y = 0; y < 4; ++y) {
                for (int z = 0; z < 4; ++z) {
                    if ((x % 3 == 0) + (y % 3 == 0) + (z % 3 == 0) > 1) continue;  // not read
                    on_[x][y][z] = acc.probeValue(c.offsetBy(x - 1, y - 1, z - 1), f_[x][y][z]);
                }
            }
        }
    }

    /// Whether the cell's eight corners are active.
    bool valid() const {
        for (int x = 1; x <= 2; ++x) {
            for (int y = 1; y <= 2; ++y) {
                for (int z = 1; z <= 2; ++z) {
                    if (!on_[x][y][z]) return false;
                }
            }
        }
        return true;
    }

    /// The gradient at the point with cell-local coordinates t (index units).
    openvdb::Vec3d gradient(const openvdb::Vec3d& t) const {
        openvdb::Vec3d g(0.0);
        for (int dx = 0; dx <= 1; ++dx) {
            for (int dy = 0; dy <= 1; ++dy) {
                for (int dz = 0; dz <= 1; ++dz) {
                    const double w = (dx ? t[0] : 1.0 - t[0]) * (dy ? t[1] : 1.0 - t[1]) *
                                     (dz ? t[2] : 1.0 - t[2]);
                    if (w != 0.0) g += w * corner_gradient(dx + 1, dy + 1, dz + 1);
                }
            }
        }
        return g;
    }

private:
    openvdb::Vec3d corner_gradient(int x, int y, int z) const {
        openvdb::Vec3d g(0.0);
        if (!on_[x][y][z]) return g;
        const double f0 = double(f_[x][y][z]);
        const int at[3] = {x, y, z};
        for (int a = 0; a < 3; ++a) {
            int lo[3] = {x, y, z}, hi[3] = {x, y, z};
            lo[a] = at[a] - 1;
            hi[a] = at[a] + 1;
            const bool l = on_[lo[0]][lo[1]][lo[2]], h = on_[hi[0]][hi[1]][hi[2]];
            const double fl = double(f_[lo[0]][lo[1]][lo[2]]), fh = double(f_[hi[0]][hi[1]][hi[2]]);
            if (l && h) {
                g[a] = 0.5 * (fh - fl);
            } else if (h) {
                g[a] = fh - f0;
            } else if (l) {
                g[a] = f0 - fl;
            }
        }
        return g;
    }

    float f_[4][4][4];
    bool on_[4][4][4];
};

/// Whether the index-space point p lies in one cell only (not within eps of a cell face).
bool in_one_cell(const openvdb::Vec3d& p) {
    int lo[3], hi[3];
    cells_around(p, lo, hi);
    return lo[0] == hi[0] && lo[1] == hi[1] && lo[2] == hi[2];
}

/// Distance (world units) from the index-space point p to the nearest of the samples recorded at
/// the eight corners of its cell: an upper bound of the distance to the data that is exact
/// whenever p's nearest sample is some corner's nearest sample (the usual case).
double nearest_sample_distance(Vec3Accessor& acc, const openvdb::Vec3d& p, double voxel) {
    const openvdb::Coord c(int(std::floor(p[0])), int(std::floor(p[1])), int(std::floor(p[2])));
    // Squared distances, one square root at the end: the same value (sqrt is monotonic and
    // correctly rounded), without eight square roots in a dependent chain of minima.
    double best = std::numeric_limits<double>::infinity();
    for (int dx = 0; dx <= 1; ++dx) {
        for (int dy = 0; dy <= 1; ++dy) {
            for (int dz = 0; dz <= 1; ++dz) {
                const openvdb::Coord q = c.offsetBy(dx, dy, dz);
                openvdb::Vec3f e;
                if (!acc.probeValue(q, e)) continue;
                // sample = corner + e (world); point = p * voxel
                const openvdb::Vec3d d = (q.asVec3d() - p) * voxel + openvdb::Vec3d(e);
                best = std::min(best, d.lengthSqr());
            }
        }
    }
    return std::sqrt(best);
}

}  // namespace

MeshResult finish_mesh(const Volume& volume, const MeshOptions& options, RawSurface&& raw) {
    const openvdb::FloatGrid& sdf = *volume.sdf;
    const double voxel = sdf.voxelSize()[0];
    const std::size_t npoints = raw.points.size();
    MeshResult result;

    // Classify the points: 0 = in an invalid cell, 1 = keep, 2 = trimmed (too little weight, or
    // farther than max_gap voxels from every sample).
    const bool trim_weight = volume.weight && options.min_surface_weight > 0.0;
    const bool trim_gap = volume.nearest && std::isfinite(options.max_gap);
    const double max_gap = options.max_gap * voxel;
    // Only points some triangle uses are looked at (marching cubes hands over every crossing).
    std::vector<char> used(npoints, 0);
    for (const Triangle& t : raw.triangles) {
        for (std::int32_t v : t) used[std::size_t(v)] = 1;
    }
    std::vector<char> point_ok(npoints, 0);
    // The vertex normals before the face-normal fallback: the mesher's own, or the SDF gradient
    // (trilinear blend of central differences), which needs a stencil around each point.
    const bool own_normals = raw.normals.size() == npoints && npoints > 0;
    std::vector<openvdb::Vec3f> grad =
        own_normals ? std::move(raw.normals)
                    : std::vector<openvdb::Vec3f>(npoints, openvdb::Vec3f(0.0f));
    const bool need_stencil = raw.check_cells || !own_normals;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, npoints, 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        FloatAccessor acc(sdf.tree());
        std::unique_ptr<FloatAccessor> wacc;
        std::unique_ptr<Vec3Accessor> nacc;
        if (trim_weight) wacc = std::make_unique<FloatAccessor>(volume.weight->tree());
        if (trim_gap) nacc = std::make_unique<Vec3Accessor>(volume.nearest->tree());
        std::unique_ptr<FloatAccessor> facc;
        if (volume.fill) facc = std::make_unique<FloatAccessor>(volume.fill->tree());
        CellStencil stencil;
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            if (!used[i]) continue;
            const openvdb::Vec3d p(raw.points[i]);
            const openvdb::Coord c(int(std::floor(p[0])), int(std::floor(p[1])),
                                   int(std::floor(p[2])));
            if (need_stencil) {
                stencil.load(acc, c);
                if (raw.check_cells &&
                    !(in_one_cell(p) ? stencil.valid() : point_in_valid_cells(acc, p))) {
                    continue;
                }
                if (!own_normals) grad[i] = openvdb::Vec3f(stencil.gradient(p - c.asVec3d()));
            }
            point_ok[i] = 1;
            if (facc && point_in_valid_cells(*facc, p)) continue;  // a closing vouches for it
            if (trim_weight &&
                openvdb::tools::BoxSampler::sample(*wacc, p) < options.min_surface_weight) {
                point_ok[i] = 2;
            }
            if (trim_gap && nearest_sample_distance(*nacc, p, voxel) > max_gap) point_ok[i] = 2;
        }
    });

    // Faces: dropped in invalid cells, trimmed for weight or distance.
    // Compacted in place (a filtered copy would add the mesh's faces to the peak).
    std::vector<Triangle> tris = std::move(raw.triangles);
    std::size_t kept = 0;
    for (const Triangle& t : tris) {
        int worst = 1;
        for (std::int32_t v : t) {
            const int ok = point_ok[std::size_t(v)];
            if (ok == 0) worst = 0;
            if (ok == 2 && worst == 1) worst = 2;
        }
        if (worst == 1) {
            tris[kept++] = t;
        } else {
            ++(worst == 0 ? result.dropped_faces : result.trimmed_faces);
        }
    }
    tris.resize(kept);

    // Compact: keep referenced points only, in their original order.
    std::size_t kept_points = 0;
    const std::vector<std::int32_t> remap = compact_vertices(tris, npoints, &kept_points);
    Mesh& mesh = result.mesh;
    mesh.origin = volume.origin;
    std::vector<Vec3f>& vertices = mesh.vertices.edit();
    vertices.resize(kept_points);  // sized first: growth by doubling would raise the peak
    for (std::size_t i = 0; i < npoints; ++i) {
        if (remap[i] < 0) continue;
        const openvdb::Vec3f& p = raw.points[i];
        vertices[std::size_t(remap[i])] = {float(p[0] * voxel), float(p[1] * voxel),
                                           float(p[2] * voxel)};
    }
    mesh.faces = std::move(tris);

    if (volume.color && !mesh.vertices.empty()) {
        std::vector<Vec3f>& colors = mesh.colors.edit();
        colors.resize(mesh.vertices.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, npoints, 4096),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            Vec3Accessor cacc(volume.color->tree());
            for (std::size_t i = r.begin(); i < r.end(); ++i) {
                if (remap[i] < 0) continue;
                const openvdb::Vec3f c =
                    openvdb::tools::BoxSampler::sample(cacc, openvdb::Vec3d(raw.points[i]));
                colors[std::size_t(remap[i])] = {c[0], c[1], c[2]};
            }
        });
    }
    release(raw.points);  // not needed from here on: less to hold while the normals are made
    if (options.normals && !mesh.vertices.empty()) {
        // Normalised SDF gradient; area-weighted face normals where it vanishes or disagrees.
        const std::vector<std::array<double, 3>> face_n = face_normal_sums(mesh);
        std::vector<Vec3f>& normals = mesh.normals.edit();
        normals.resize(mesh.vertices.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, npoints, 16384),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t i = r.begin(); i < r.end(); ++i) {
                if (remap[i] < 0) continue;
                const std::size_t v = std::size_t(remap[i]);
                openvdb::Vec3d g(grad[i]);
                const openvdb::Vec3d fn(face_n[v][0], face_n[v][1], face_n[v][2]);
                if (!(g.length() > 1e-12) || g.dot(fn) < 0.0) g = fn;
                const double len = g.length();
                if (len > 0.0) g /= len;
                normals[v] = {float(g[0]), float(g[1]), float(g[2])};
            }
        });
    }
    return result;
}

}  // namespace detail

MeshResult extract_mesh(const Volume& volume, const MeshOptions& options) {
    options.validate();
    if (!volume.sdf) throw InvalidArgument("extract_mesh: the volume has no sdf grid");
    initialize_openvdb();
    detail::RawSurface raw;
    switch (options.method) {
        case Mesher::vdb: raw = detail::mesh_vdb(volume, options); break;
        case Mesher::mc: raw = detail::mesh_mc(volume, options); break;
        case Mesher::dc: raw = detail::mesh_dc(volume, options); break;
    }
    return detail::finish_mesh(volume, options, std::move(raw));
}

}  // namespace vdbrecon
