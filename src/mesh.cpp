// Surface extraction (see mesh.h).
#include "vdbrecon/mesh.h"

#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <limits>
#include <memory>
#include <sstream>

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
}

namespace {

using FloatAccessor = openvdb::tree::ValueAccessor<const openvdb::FloatTree>;
using Vec3Accessor = openvdb::tree::ValueAccessor<const openvdb::Vec3fTree>;

/// A cell (the cube between voxel ijk and ijk+1) is valid when its eight corners are active.
bool cell_valid(FloatAccessor& acc, const openvdb::Coord& c) {
    for (int dx = 0; dx <= 1; ++dx) {
        for (int dy = 0; dy <= 1; ++dy) {
            for (int dz = 0; dz <= 1; ++dz) {
                if (!acc.isValueOn(c.offsetBy(dx, dy, dz))) return false;
            }
        }
    }
    return true;
}

/// Every cell whose closed box contains the index-space point `p` (up to eps) is valid.
bool point_in_valid_cells(FloatAccessor& acc, const openvdb::Vec3d& p) {
    constexpr double eps = 1e-4;
    int lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
        lo[a] = int(std::floor(p[a] - eps));
        hi[a] = int(std::floor(p[a] + eps));
    }
    for (int x = lo[0]; x <= hi[0]; ++x) {
        for (int y = lo[1]; y <= hi[1]; ++y) {
            for (int z = lo[2]; z <= hi[2]; ++z) {
                if (!cell_valid(acc, openvdb::Coord(x, y, z))) return false;
            }
        }
    }
    return true;
}

/// Distance (world units) from the index-space point p to the nearest of the samples recorded at
/// the eight corners of its cell: an upper bound of the distance to the data that is exact
/// whenever p's nearest sample is some corner's nearest sample (the usual case).
double nearest_sample_distance(Vec3Accessor& acc, const openvdb::Vec3d& p, double voxel) {
    const openvdb::Coord c(int(std::floor(p[0])), int(std::floor(p[1])), int(std::floor(p[2])));
    double best = std::numeric_limits<double>::infinity();
    for (int dx = 0; dx <= 1; ++dx) {
        for (int dy = 0; dy <= 1; ++dy) {
            for (int dz = 0; dz <= 1; ++dz) {
                const openvdb::Coord q = c.offsetBy(dx, dy, dz);
                openvdb::Vec3f e;
                if (!acc.probeValue(q, e)) continue;
                // sample = corner + e (world); vertex = p * voxel
                const openvdb::Vec3d d = (q.asVec3d() - p) * voxel + openvdb::Vec3d(e);
                best = std::min(best, d.length());
            }
        }
    }
    return best;
}

/// Central-difference gradient at a voxel (one-sided next to invalid voxels), index units.
openvdb::Vec3d voxel_gradient(FloatAccessor& acc, const openvdb::Coord& c) {
    openvdb::Vec3d g(0.0);
    float f0;
    if (!acc.probeValue(c, f0)) return g;
    for (int a = 0; a < 3; ++a) {
        openvdb::Coord lo = c, hi = c;
        lo[a] -= 1;
        hi[a] += 1;
        float fl, fh;
        const bool l = acc.probeValue(lo, fl), h = acc.probeValue(hi, fh);
        if (l && h) {
            g[a] = 0.5 * (double(fh) - double(fl));
        } else if (h) {
            g[a] = double(fh) - double(f0);
        } else if (l) {
            g[a] = double(f0) - double(fl);
        }
    }
    return g;
}

/// SDF gradient at an index-space point: trilinear blend of the corner gradients.
openvdb::Vec3d gradient_at(FloatAccessor& acc, const openvdb::Vec3d& p) {
    const openvdb::Coord c(int(std::floor(p[0])), int(std::floor(p[1])), int(std::floor(p[2])));
    const openvdb::Vec3d t = p - c.asVec3d();
    openvdb::Vec3d g(0.0);
    for (int dx = 0; dx <= 1; ++dx) {
        for (int dy = 0; dy <= 1; ++dy) {
            for (int dz = 0; dz <= 1; ++dz) {
                const double w = (dx ? t[0] : 1.0 - t[0]) * (dy ? t[1] : 1.0 - t[1]) *
                                 (dz ? t[2] : 1.0 - t[2]);
                g += w * voxel_gradient(acc, c.offsetBy(dx, dy, dz));
            }
        }
    }
    return g;
}

}  // namespace

MeshResult extract_mesh(const Volume& volume, const MeshOptions& options) {
    options.validate();
    if (!volume.sdf) throw InvalidArgument("extract_mesh: the volume has no sdf grid");
    initialize_openvdb();
    const openvdb::FloatGrid& sdf = *volume.sdf;
    const double voxel = sdf.voxelSize()[0];
    MeshResult result;

    // Mesh in the local frame (scale only, no translation) so far-away origins keep precision.
    openvdb::FloatGrid::ConstPtr local = sdf.copyReplacingMetadataAndTransform(
        sdf, openvdb::math::Transform::createLinearTransform(voxel));
    openvdb::tools::VolumeToMesh mesher(options.isovalue, options.adaptivity);
    // volumeToMesh decides inside/outside from the grid class: the sdf must be a level set.
    if (local->getGridClass() != openvdb::GRID_LEVEL_SET) {
        throw InvalidArgument("extract_mesh: the sdf grid must have class GRID_LEVEL_SET");
    }
    mesher(*local);

    const std::size_t npoints = mesher.pointListSize();
    const openvdb::tools::PointList& points = mesher.pointList();
    const openvdb::tools::PolygonPoolList& pools = mesher.polygonPoolList();
    const std::size_t npools = mesher.polygonPoolListSize();

    // Classify the points: 0 = in an invalid cell, 1 = keep, 2 = trimmed (too little weight, or
    // farther than max_gap voxels from every sample).
    const bool trim_weight = volume.weight && options.min_surface_weight > 0.0;
    const bool trim_gap = volume.nearest && std::isfinite(options.max_gap);
    const double max_gap = options.max_gap * voxel;
    std::vector<char> point_ok(npoints, 0);
    std::vector<openvdb::Vec3f> grad(npoints, openvdb::Vec3f(0.0f));
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, npoints, 4096),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        FloatAccessor acc(sdf.tree());
        std::unique_ptr<FloatAccessor> wacc;
        std::unique_ptr<Vec3Accessor> nacc;
        if (trim_weight) wacc = std::make_unique<FloatAccessor>(volume.weight->tree());
        if (trim_gap) nacc = std::make_unique<Vec3Accessor>(volume.nearest->tree());
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
            const openvdb::Vec3d p = openvdb::Vec3d(points[i]) / voxel;
            if (!point_in_valid_cells(acc, p)) continue;
            point_ok[i] = 1;
            grad[i] = openvdb::Vec3f(gradient_at(acc, p));
            if (trim_weight &&
                openvdb::tools::BoxSampler::sample(*wacc, p) < options.min_surface_weight) {
                point_ok[i] = 2;
            }
            if (trim_gap && nearest_sample_distance(*nacc, p, voxel) > max_gap) point_ok[i] = 2;
        }
    });
    auto keep = [&](std::initializer_list<openvdb::Index32> vs) {
        bool trimmed = false;
        for (openvdb::Index32 v : vs) {
            if (point_ok[v] == 0) return 0;
            trimmed |= point_ok[v] == 2;
        }
        return trimmed ? 2 : 1;
    };

    // Triangles: volumeToMesh's polygons are clockwise seen from outside for a level set, so
    // every polygon is reversed. Quads are split along their shorter diagonal.
    std::vector<Triangle> tris;
    auto len2 = [&](openvdb::Index32 a, openvdb::Index32 b) {
        return (points[a] - points[b]).lengthSqr();
    };
    for (std::size_t p = 0; p < npools; ++p) {
        const openvdb::tools::PolygonPool& pool = pools[p];
        for (std::size_t q = 0; q < pool.numQuads(); ++q) {
            const openvdb::Vec4I& v = pool.quad(q);
            const int k = keep({v[0], v[1], v[2], v[3]});
            if (k != 1) {
                (k == 0 ? result.dropped_faces : result.trimmed_faces) += 2;
                continue;
            }
            // Reversed quad: v3 v2 v1 v0.
            if (len2(v[0], v[2]) <= len2(v[1], v[3])) {
                tris.push_back({std::int32_t(v[3]), std::int32_t(v[2]), std::int32_t(v[0])});
                tris.push_back({std::int32_t(v[2]), std::int32_t(v[1]), std::int32_t(v[0])});
            } else {
                tris.push_back({std::int32_t(v[3]), std::int32_t(v[2]), std::int32_t(v[1])});
                tris.push_back({std::int32_t(v[3]), std::int32_t(v[1]), std::int32_t(v[0])});
            }
        }
        for (std::size_t t = 0; t < pool.numTriangles(); ++t) {
            const openvdb::Vec3I& v = pool.triangle(t);
            const int k = keep({v[0], v[1], v[2]});
            if (k != 1) {
                ++(k == 0 ? result.dropped_faces : result.trimmed_faces);
                continue;
            }
            tris.push_back({std::int32_t(v[2]), std::int32_t(v[1]), std::int32_t(v[0])});
        }
    }

    // Compact: keep referenced points only, in their original order.
    std::vector<std::int32_t> remap(npoints, -1);
    for (const Triangle& t : tris) {
        for (std::int32_t i : t) remap[std::size_t(i)] = 0;
    }
    Mesh& mesh = result.mesh;
    mesh.origin = volume.origin;
    std::int32_t next = 0;
    for (std::size_t i = 0; i < npoints; ++i) {
        if (remap[i] < 0) continue;
        remap[i] = next++;
        mesh.vertices.push_back({points[i][0], points[i][1], points[i][2]});
    }
    for (Triangle& t : tris) {
        for (std::int32_t& i : t) i = remap[std::size_t(i)];
    }
    mesh.faces = std::move(tris);

    if (options.normals && !mesh.vertices.empty()) {
        // Normalised SDF gradient; area-weighted face normals where it vanishes or disagrees.
        std::vector<openvdb::Vec3d> face_n(mesh.vertices.size(), openvdb::Vec3d(0.0));
        for (const Triangle& t : mesh.faces) {
            const openvdb::Vec3d a(mesh.vertices[t[0]].data()), b(mesh.vertices[t[1]].data()),
                c(mesh.vertices[t[2]].data());
            const openvdb::Vec3d fn = (b - a).cross(c - a);
            for (std::int32_t i : t) face_n[std::size_t(i)] += fn;
        }
        mesh.normals.resize(mesh.vertices.size());
        for (std::size_t i = 0; i < npoints; ++i) {
            if (remap[i] < 0) continue;
            const std::size_t v = std::size_t(remap[i]);
            openvdb::Vec3d g(grad[i]);
            if (!(g.length() > 1e-12) || g.dot(face_n[v]) < 0.0) g = face_n[v];
            const double len = g.length();
            if (len > 0.0) g /= len;
            mesh.normals[v] = {float(g[0]), float(g[1]), float(g[2])};
        }
    }
    return result;
}

}  // namespace vdbrecon
