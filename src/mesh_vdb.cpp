// The `vdb` mesher: OpenVDB's tools::volumeToMesh (dual marching cubes).
#include <openvdb/tools/VolumeToMesh.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "detail/mesh_common.h"
#include "vdbrecon/error.h"

namespace vdbrecon::detail {

RawSurface mesh_vdb(const Volume& volume, const MeshOptions& options) {
    const openvdb::FloatGrid& sdf = *volume.sdf;
    // volumeToMesh decides inside/outside from the grid class: the sdf must be a level set.
    if (sdf.getGridClass() != openvdb::GRID_LEVEL_SET) {
        throw InvalidArgument("extract_mesh: the sdf grid must have class GRID_LEVEL_SET");
    }
    // Mesh in index space (unit transform), so far-away origins and voxel sizes do not matter.
    openvdb::FloatGrid::ConstPtr index_grid = sdf.copyReplacingMetadataAndTransform(
        sdf, openvdb::math::Transform::createLinearTransform(1.0));
    openvdb::tools::VolumeToMesh mesher(options.isovalue, options.adaptivity);
    mesher(*index_grid);

    RawSurface raw;
    raw.check_cells = true;  // volumeToMesh knows nothing of the validity mask
    // The triangles first, from the mesher's points; its polygons freed, then the points copied
    // and the mesher's freed: its arrays and ours never all coexist (4 MB on the bunny).
    openvdb::tools::PointList& points = mesher.pointList();
    // For a level set volumeToMesh's polygons are clockwise seen from outside: reverse them.
    // Quads are split along their shorter diagonal.
    auto len2 = [&](openvdb::Index32 a, openvdb::Index32 b) {
        return (points[a] - points[b]).lengthSqr();
    };
    openvdb::tools::PolygonPoolList& pools = mesher.polygonPoolList();
    const std::size_t npools = mesher.polygonPoolListSize();
    std::vector<std::size_t> first(npools + 1, 0);  // each pool's first triangle
    for (std::size_t p = 0; p < npools; ++p) {
        first[p + 1] = first[p] + 2 * pools[p].numQuads() + pools[p].numTriangles();
    }
    raw.triangles.resize(first[npools]);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, npools, 1),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t p = r.begin(); p < r.end(); ++p) {
            const openvdb::tools::PolygonPool& pool = pools[p];
            Triangle* out = raw.triangles.data() + first[p];
            for (std::size_t q = 0; q < pool.numQuads(); ++q) {
                const openvdb::Vec4I& v = pool.quad(q);
                const auto i = [&](int k) { return std::int32_t(v[k]); };
                if (len2(v[0], v[2]) <= len2(v[1], v[3])) {
                    *out++ = {i(3), i(2), i(0)};
                    *out++ = {i(2), i(1), i(0)};
                } else {
                    *out++ = {i(3), i(2), i(1)};
                    *out++ = {i(3), i(1), i(0)};
                }
            }
            for (std::size_t t = 0; t < pool.numTriangles(); ++t) {
                const openvdb::Vec3I& v = pool.triangle(t);
                *out++ = {std::int32_t(v[2]), std::int32_t(v[1]), std::int32_t(v[0])};
            }
        }
    });
    pools.reset();  // serially: frees from two threads at once contend for the heap's lock
    raw.points.assign(points.get(), points.get() + mesher.pointListSize());
    points.reset();
    return raw;
}

}  // namespace vdbrecon::detail
