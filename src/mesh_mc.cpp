// The `mc` mesher: marching cubes over the valid cells (see mesh.h and detail/cube.h).
//
// Vertices are the edge crossings, shared by the (up to four) cells around an edge; each cell's
// oriented loops are fanned into triangles from an apex chosen so that no diagonal joins two
// crossings on a common cube face (detail/cube.h: fan_apex), which keeps the mesh manifold. A
// loop without such an apex (a saddle loop through ambiguous faces) is fanned around an extra
// vertex at the centroid of its crossings.
#include "detail/crossings.h"
#include "detail/mesh_common.h"

namespace vdbrecon::detail {

RawSurface mesh_mc(const Volume& volume, const MeshOptions& options) {
    const openvdb::FloatTree& tree = volume.sdf->tree();
    const float iso = float(options.isovalue);
    Crossings crossings = find_crossings(tree, iso, true);
    // Per leaf: triangles, and centre points of loops fanned around one. Centre points are
    // numbered after all crossings; a triangle refers to one as -(local index + 1) until then.
    struct LeafOut {
        std::vector<Triangle> triangles;
        std::vector<openvdb::Vec3f> centres;
    };
    std::vector<LeafOut> per_leaf(tree.leafCount());
    for_each_surface_cell(
        tree, crossings, iso, [&](std::size_t L, const SurfaceCell& cell, FloatAccessor&) {
            LeafOut& out = per_leaf[L];
            for (int l = 0; l < cell.loops.count; ++l) {
                const std::uint8_t* e = cell.loops.edge[l];
                const int n = cell.loops.size[l];
                auto id = [&](int i) { return std::int32_t(cell.edge_id[e[(i + n) % n]]); };
                const int apex = fan_apex(cell.loops, l);
                if (apex >= 0) {
                    for (int i = 1; i + 1 < n; ++i) {
                        out.triangles.push_back({id(apex), id(apex + i), id(apex + i + 1)});
                    }
                    continue;
                }
                openvdb::Vec3f centre(0.0f);
                for (int i = 0; i < n; ++i) centre += crossings.points[std::size_t(id(i))];
                out.centres.push_back(centre / float(n));
                const std::int32_t c = -std::int32_t(out.centres.size());
                for (int i = 0; i < n; ++i) out.triangles.push_back({c, id(i), id(i + 1)});
            }
        });
    RawSurface raw;
    raw.points = std::move(crossings.points);
    std::size_t total = 0;
    for (const LeafOut& o : per_leaf) total += o.triangles.size();
    raw.triangles.reserve(total);
    for (LeafOut& o : per_leaf) {
        const std::int32_t base = std::int32_t(raw.points.size());
        for (Triangle t : o.triangles) {
            if (t[0] < 0) t[0] = base - t[0] - 1;
            raw.triangles.push_back(t);
        }
        raw.points.insert(raw.points.end(), o.centres.begin(), o.centres.end());
        o = {};
    }
    return raw;
}

}  // namespace vdbrecon::detail
