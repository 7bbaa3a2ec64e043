// Morphological closing of the volume (see close.h).
#include "vdbrecon/close.h"

#include <openvdb/tools/ChangeBackground.h>
#include <openvdb/tools/LevelSetMeasure.h>
#include <openvdb/tools/LevelSetRebuild.h>
#include <openvdb/tools/MeshToVolume.h>
#include <openvdb/tools/Morphology.h>
#include <openvdb/tools/SignedFloodFill.h>
#include <openvdb/tree/LeafManager.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cstdlib>
#include <cmath>
#include <vector>

#include "detail/support.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"

namespace vdbrecon {

void CloseOptions::validate() const {
    if (hole_radius < 0 || hole_radius > 64) {
        throw InvalidArgument("close.hole_radius = " + std::to_string(hole_radius) +
                              ": must be in 0..64 voxels");
    }
    if (solid_radius < 0 || solid_radius > 64) {
        throw InvalidArgument("close.solid_radius = " + std::to_string(solid_radius) +
                              ": must be in 0..64 voxels");
    }
}

namespace {

using openvdb::Coord;
using openvdb::MaskTree;
using openvdb::Vec3f;
using FloatTree = openvdb::FloatTree;
using Vec3fTree = openvdb::Vec3fTree;

/// The valid voxels the mesher's trims would keep (detail::SupportTest: relative weight and
/// distance to the samples), plus any voxels an earlier closing vouched for.
MaskTree::Ptr supported_voxels(const Volume& v, const MeshOptions& m) {
    auto mask = std::make_shared<MaskTree>(v.sdf->tree(), false, openvdb::TopologyCopy());
    const detail::SupportTest support(v, m);
    if (support.enabled()) {
        openvdb::tree::LeafManager<MaskTree> leaves(*mask);
        leaves.foreach ([&](MaskTree::LeafNodeType& leaf, std::size_t) {
            detail::SupportTest::Accessors acc = support.accessors();
            for (auto it = leaf.beginValueOn(); it; ++it) {
                if (support.at_voxel(acc, it.getCoord()) != detail::Support::ok) {
                    leaf.setValueOff(it.pos());
                }
            }
        });
    }
    if (v.fill) mask->topologyUnion(v.fill->tree());
    return mask;
}

/// Closes the mask's active set with a (2R+1)^3 cube (dilation, then erosion).
void morphological_close(MaskTree& mask, int radius) {
    openvdb::tools::dilateActiveValues(mask, radius, openvdb::tools::NN_FACE_EDGE_VERTEX,
                                       openvdb::tools::IGNORE_TILES);
    openvdb::tools::erodeActiveValues(mask, radius, openvdb::tools::NN_FACE_EDGE_VERTEX,
                                      openvdb::tools::IGNORE_TILES);
    mask.prune();
}

/// The voxels of `mask` next to the zero level of `sdf` (within 0.9 voxel) extruded along the
/// surface normal (the SDF gradient) `radius` voxels to each side. The closing of a thin shell
/// leaves a hole of 2R voxels open on a tilted surface: the corner of the (2R+1)^3 cube pokes
/// about R / sqrt(2) voxels into the hole from each side. Closing this slab (2R + 1 voxels
/// thick) bridges the hole at the surface, and the extrusion adds nothing across a border.
MaskTree::Ptr extruded(const MaskTree& mask, const openvdb::FloatGrid& sdf, int radius) {
    using Leaf = MaskTree::LeafNodeType;
    std::vector<const Leaf*> leaves;
    leaves.reserve(mask.leafCount());
    for (auto it = mask.cbeginLeaf(); it; ++it) leaves.push_back(it.getLeaf());
    tbb::enumerable_thread_specific<MaskTree> parts;
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size(), 16),
                      [&](const tbb::blocked_range<std::size_t>& r) {
        openvdb::tree::ValueAccessor<MaskTree> out(parts.local());
        detail::FloatAccessor acc(sdf.tree());
        for (std::size_t l = r.begin(); l < r.end(); ++l) {
            for (auto it = leaves[l]->cbeginValueOn(); it; ++it) {
                const Coord c = it.getCoord();
                const openvdb::Vec3d g = detail::central_gradient(acc, c);
                const double len = g.length();
                if (!(len > 1e-12) || std::fabs(double(acc.getValue(c))) > 0.9 * len) continue;
                const openvdb::Vec3d n = g / len;
                for (int k = -2 * radius; k <= 2 * radius; ++k) {  // half-voxel steps
                    const openvdb::Vec3d q = c.asVec3d() + n * (0.5 * k);
                    out.setValueOn(Coord(int(std::lround(q[0])), int(std::lround(q[1])),
                                         int(std::lround(q[2]))));
                }
            }
        }
    });
    auto result = std::make_shared<MaskTree>();
    for (MaskTree& part : parts) result->topologyUnion(part);
    return result;
}

/// All active voxels of a mask, in the tree's (deterministic) leaf order.
std::vector<Coord> active_coords(const MaskTree& mask) {
    std::vector<Coord> out;
    out.reserve(std::size_t(mask.activeVoxelCount()));
    for (auto it = mask.cbeginValueOn(); it; ++it) {
        if (it.isVoxelValue()) out.push_back(it.getCoord());
    }
    return out;
}

/// Extends values into `target` voxels layer by layer from the `known` ones (both updated: a
/// filled voxel becomes known, unreached voxels stay in `target`). Each layer is the target
/// voxels with a known 26-neighbour; a voxel's value is the 1/d^2-weighted mean over those
/// neighbours of, for the sdf, the first-order prediction phi_j + grad_j . (x - x_j), and for the
/// colour the neighbour's colour. Gradients of the original voxels are central (or one-sided)
/// differences over `original`; filled voxels carry the mean gradient of their sources. Values
/// of one layer depend only on earlier layers, so the result is independent of the thread count.
/// Returns the number of voxels filled.
std::size_t extend_layers(FloatTree* sdf, const MaskTree* original, Vec3fTree* color,
                          MaskTree& known, MaskTree& target, float clamp) {
    Vec3fTree gradient(Vec3f(0.0f));  // of filled voxels
    std::size_t filled = 0;
    for (;;) {
        const std::vector<Coord> todo = active_coords(target);
        struct Update {
            float phi = 0.0f;
            Vec3f grad{0.0f}, rgb{0.0f};
            bool ok = false;
        };
        std::vector<Update> up(todo.size());
        tbb::parallel_for(tbb::blocked_range<std::size_t>(0, todo.size(), 1024),
                          [&](const tbb::blocked_range<std::size_t>& r) {
            openvdb::tree::ValueAccessor<const MaskTree> kacc(known);
            std::unique_ptr<openvdb::tree::ValueAccessor<const MaskTree>> oacc;
            std::unique_ptr<openvdb::tree::ValueAccessor<const FloatTree>> sacc;
            std::unique_ptr<openvdb::tree::ValueAccessor<const Vec3fTree>> gacc, cacc;
            if (sdf) {
                oacc = std::make_unique<openvdb::tree::ValueAccessor<const MaskTree>>(*original);
                sacc = std::make_unique<openvdb::tree::ValueAccessor<const FloatTree>>(*sdf);
                gacc = std::make_unique<openvdb::tree::ValueAccessor<const Vec3fTree>>(gradient);
            }
            if (color) cacc = std::make_unique<openvdb::tree::ValueAccessor<const Vec3fTree>>(*color);
            // Gradient of an original voxel: differences over original neighbours.
            auto original_gradient = [&](const Coord& c) {
                const float f0 = sacc->getValue(c);
                Vec3f g(0.0f);
                for (int a = 0; a < 3; ++a) {
                    Coord lo = c, hi = c;
                    --lo[a];
                    ++hi[a];
                    const bool has_lo = oacc->isValueOn(lo), has_hi = oacc->isValueOn(hi);
                    if (has_lo && has_hi) {
                        g[a] = 0.5f * (sacc->getValue(hi) - sacc->getValue(lo));
                    } else if (has_hi) {
                        g[a] = sacc->getValue(hi) - f0;
                    } else if (has_lo) {
                        g[a] = f0 - sacc->getValue(lo);
                    }
                }
                return g;
            };
            for (std::size_t i = r.begin(); i < r.end(); ++i) {
                const Coord& x = todo[i];
                double wsum = 0.0, phi = 0.0;
                openvdb::Vec3d grad(0.0), rgb(0.0);
                for (int dx = -1; dx <= 1; ++dx) {
                    for (int dy = -1; dy <= 1; ++dy) {
                        for (int dz = -1; dz <= 1; ++dz) {
                            const int d2 = dx * dx + dy * dy + dz * dz;
                            if (d2 == 0) continue;
                            const Coord j = x.offsetBy(dx, dy, dz);
                            if (!kacc.isValueOn(j)) continue;
                            const double w = 1.0 / d2;
                            wsum += w;
                            if (sdf) {
                                const Vec3f g = oacc->isValueOn(j) ? original_gradient(j)
                                                                   : gacc->getValue(j);
                                // phi(x) ~ phi_j + g_j . (x - x_j), with x - x_j = -(dx, dy, dz)
                                phi += w * (sacc->getValue(j) - (g[0] * dx + g[1] * dy + g[2] * dz));
                                grad += w * openvdb::Vec3d(g);
                            }
                            if (color) rgb += w * openvdb::Vec3d(cacc->getValue(j));
                        }
                    }
                }
                if (wsum == 0.0) continue;
                Update& u = up[i];
                u.ok = true;
                u.phi = std::clamp(float(phi / wsum), -clamp, clamp);
                u.grad = Vec3f(grad / wsum);
                u.rgb = Vec3f(rgb / wsum);
            }
        });
        std::size_t layer = 0;
        for (std::size_t i = 0; i < todo.size(); ++i) {
            if (!up[i].ok) continue;
            ++layer;
            const Coord& x = todo[i];
            if (sdf) {
                sdf->setValueOn(x, up[i].phi);
                gradient.setValueOn(x, up[i].grad);
            }
            if (color) color->setValueOn(x, up[i].rgb);
            known.setValueOn(x);
            target.setValueOff(x);
        }
        filled += layer;
        if (layer == 0) break;
    }
    target.clear();
    return filled;
}

/// A float grid that is 1 on the mask's active voxels, named "fill", in the volume's frame.
openvdb::FloatGrid::Ptr make_fill_grid(const MaskTree& mask, const openvdb::FloatGrid& sdf) {
    auto tree = std::make_shared<FloatTree>(mask, 0.0f, 1.0f, openvdb::TopologyCopy());
    auto grid = openvdb::FloatGrid::create(tree);
    grid->setTransform(sdf.transform().copy());
    grid->setName("fill");
    return grid;
}

/// The valid voxels the splat's own threshold made valid (weight >= its min_weight), without
/// those valid only for lying near the surface with a fifth of it (splat.h): their field is a
/// thin overlap of kernel tails, which the extension into a hole must neither start from nor
/// keep where it reaches (extrapolated from them, the bridged cap of a sphere was 0.65 voxel off
/// at its rim instead of 0.39). `mask`: the valid voxels, all kept when the volume does not say
/// its threshold.
MaskTree full_weight_voxels(const Volume& v, MaskTree mask) {
    const auto it = v.metadata.find("min_weight");
    if (!v.weight || it == v.metadata.end()) return mask;
    const double min_weight = std::strtod(it->second.c_str(), nullptr);
    if (!(min_weight > 0.0)) return mask;
    openvdb::tree::LeafManager<MaskTree> leaves(mask);
    leaves.foreach ([&](MaskTree::LeafNodeType& leaf, std::size_t) {
        openvdb::tree::ValueAccessor<const FloatTree> w(v.weight->tree());
        for (auto on = leaf.beginValueOn(); on; ++on) {
            if (double(w.getValue(on.getCoord())) < min_weight) leaf.setValueOff(on.pos());
        }
    });
    return mask;
}

/// Hole closing: close the supported voxels with a (2R+1)^3 cube, fill the new ones.
Volume close_holes(const Volume& in, int radius, const MeshOptions& mesh, CloseResult& stats) {
    MaskTree::Ptr closed = supported_voxels(in, mesh);
    stats.supported_voxels = std::size_t(closed->activeVoxelCount());
    closed->topologyUnion(*extruded(*closed, *in.sdf, radius));
    const MaskTree slab = *closed;
    morphological_close(*closed, radius);

    Volume out = in;
    auto sdf = openvdb::gridPtrCast<openvdb::FloatGrid>(in.sdf->deepCopyGrid());
    const MaskTree valid(in.sdf->tree(), false, openvdb::TopologyCopy());
    const MaskTree original = full_weight_voxels(in, valid);
    MaskTree known = original;
    // The holes of band and slab together get values; so do the closed voxels up to two
    // voxels past the band around the bridged holes (dents of the band's faces there, where the
    // cube of the closing fits in, would leave invalid cells at the surface); not the rest of
    // the slab.
    MaskTree band = original;
    if (in.fill) band.topologyUnion(in.fill->tree());
    band.topologyUnion(slab);
    MaskTree target = band;
    morphological_close(target, radius);
    target.topologyDifference(band);
    MaskTree near = *closed;
    near.topologyDifference(slab);
    MaskTree past_band = original;
    for (MaskTree* m : {&near, &past_band}) {
        openvdb::tools::dilateActiveValues(*m, 2, openvdb::tools::NN_FACE_EDGE_VERTEX,
                                           openvdb::tools::IGNORE_TILES);
    }
    near.topologyIntersection(past_band);
    near.topologyIntersection(*closed);
    target.topologyUnion(near);
    target.topologyDifference(original);
    openvdb::Vec3fGrid::Ptr color;
    if (in.color) color = openvdb::gridPtrCast<openvdb::Vec3fGrid>(in.color->deepCopyGrid());
    // Thin-overlap voxels (valid, but not of full weight) in the target get new values; they
    // were valid before, so they are not counted as filled.
    MaskTree revalued = target;
    revalued.topologyIntersection(valid);
    stats.filled_voxels = extend_layers(&sdf->tree(), &original, color ? &color->tree() : nullptr,
                                        known, target, in.sdf->background());
    revalued.topologyIntersection(known);
    stats.filled_voxels -= std::size_t(revalued.activeVoxelCount());
    // Voxels the extension could not reach (no known voxel connects to them) are not vouched for.
    closed->topologyIntersection(known);
    stats.closed_voxels = std::size_t(closed->activeVoxelCount());
    openvdb::tools::signedFloodFill(sdf->tree());
    out.sdf = sdf;
    out.color = color;
    out.fill = make_fill_grid(*closed, *sdf);
    return out;
}

/// The signed distance field of a closed mesh (local frame, world units) in index space (unit
/// voxels, origin at index 0: far-away origins keep their precision), `out` / `in` voxels
/// outside / inside.
openvdb::FloatGrid::Ptr index_space_sdf(const Mesh& m, double voxel, float out, float in) {
    std::vector<openvdb::Vec3s> points(m.vertices.size());
    for (std::size_t i = 0; i < points.size(); ++i) {
        for (int a = 0; a < 3; ++a) points[i][a] = float(m.vertices[i][a] / voxel);
    }
    std::vector<openvdb::Vec3I> tris(m.faces.size());
    for (std::size_t i = 0; i < tris.size(); ++i) {
        tris[i] = openvdb::Vec3I(openvdb::Index32(m.faces[i][0]), openvdb::Index32(m.faces[i][1]),
                                 openvdb::Index32(m.faces[i][2]));
    }
    const auto unit = openvdb::math::Transform::createLinearTransform(1.0);
    return openvdb::tools::meshToSignedDistanceField<openvdb::FloatGrid>(*unit, points, tris, {},
                                                                         out, in);
}

/// An index-space level set back in world units and the frame of `frame`, named "sdf".
void to_volume_frame(openvdb::FloatGrid& g, double voxel, float half_width,
                     const openvdb::FloatGrid& frame) {
    openvdb::tree::LeafManager<FloatTree> leaves(g.tree());
    leaves.foreach ([&](FloatTree::LeafNodeType& leaf, std::size_t) {
        for (auto it = leaf.beginValueAll(); it; ++it) it.setValue(float(*it * voxel));
    });
    openvdb::tools::changeLevelSetBackground(g.tree(), float(half_width * voxel));
    g.setTransform(frame.transform().copy());
    g.setName("sdf");
    g.setGridClass(openvdb::GRID_LEVEL_SET);
}

/// Solid closing: exact distance field of the meshed surface, offset out by R and back in by R.
Volume close_solid(const Volume& in, int radius, const MeshOptions& mesh, CloseResult& stats) {
    // Dual contouring keeps the sharp rims of grooves and cavities: marching cubes would chamfer
    // them by ~0.3 voxel, and the offsets below turn that into a dimple of ~0.8 voxel where a
    // groove was closed (measured on the grooved sphere of the tests).
    MeshOptions mo = mesh;
    mo.method = Mesher::dc;
    mo.normals = false;
    const Mesh m = extract_mesh(in, mo).mesh;
    const TopologyStats topo = mesh_topology(m);
    if (m.faces.empty()) {
        throw NumericalError("close-solid: the volume has no surface to close");
    }
    if (topo.boundary_edges > 0) {
        throw NumericalError(
            "close-solid: the surface is open (" + std::to_string(topo.boundary_edges) +
            " boundary edges); solid closing needs a watertight surface. Hint: close its holes "
            "first with --close R");
    }
    const double voxel = in.sdf->voxelSize()[0];
    const float r = float(radius), band = 3.0f;
    const float half_width = std::max(band, float(in.sdf->background() / voxel));
    // The distance field needs to reach R voxels out for the dilation (and enclosed cavities come
    // out inside: meshToVolume marks as outside only what its sweeps from the exterior reach).
    auto d0 = index_space_sdf(m, voxel, r + band, band);
    stats.solid_voxels_before = std::size_t(std::llround(openvdb::tools::levelSetVolume(*d0, false)));
    auto d1 = openvdb::tools::levelSetRebuild(*d0, r, band, r + band);  // dilated by R
    auto d2 = openvdb::tools::levelSetRebuild(*d1, -r, half_width, half_width);  // eroded by R
    stats.solid_voxels_after = std::size_t(std::llround(openvdb::tools::levelSetVolume(*d2, false)));

    to_volume_frame(*d2, voxel, half_width, *in.sdf);

    Volume out = in;
    out.sdf = d2;
    const MaskTree band_mask(d2->tree(), false, openvdb::TopologyCopy());
    out.fill = make_fill_grid(band_mask, *d2);
    if (in.color) {
        // Colours of the new band: kept where the old band had them, extended elsewhere.
        auto color = openvdb::gridPtrCast<openvdb::Vec3fGrid>(in.color->deepCopyGrid());
        MaskTree known(color->tree(), false, openvdb::TopologyCopy());
        MaskTree target = band_mask;
        target.topologyDifference(known);
        extend_layers(nullptr, nullptr, &color->tree(), known, target, 0.0f);
        color->tree().topologyIntersection(d2->tree());
        out.color = color;
    }
    return out;
}

}  // namespace

CloseResult close_volume(const Volume& volume, const CloseOptions& options,
                         const MeshOptions& mesh) {
    options.validate();
    mesh.validate();
    if (!volume.sdf) throw InvalidArgument("close_volume: the volume has no sdf grid");
    initialize_openvdb();
    CloseResult result;
    result.volume = volume;
    if (options.hole_radius > 0) {
        result.volume = close_holes(result.volume, options.hole_radius, mesh, result);
    }
    if (options.solid_radius > 0) {
        result.volume = close_solid(result.volume, options.solid_radius, mesh, result);
    }
    if (options.enabled()) {
        result.volume.metadata["close_hole_radius"] = std::to_string(options.hole_radius);
        result.volume.metadata["close_solid_radius"] = std::to_string(options.solid_radius);
    }
    return result;
}

Volume mesh_volume(const Mesh& mesh, const Volume& frame, float half_width) {
    if (!frame.sdf) throw InvalidArgument("mesh_volume: the frame volume has no sdf");
    if (mesh.faces.empty()) throw InvalidArgument("mesh_volume: the mesh is empty");
    const double voxel = frame.sdf->voxelSize()[0];
    auto sdf = index_space_sdf(mesh, voxel, half_width, half_width);
    to_volume_frame(*sdf, voxel, half_width, *frame.sdf);
    Volume out;
    out.sdf = sdf;
    out.voxel_size = frame.voxel_size;
    out.origin = frame.origin;
    out.metadata = frame.metadata;
    const MaskTree band(sdf->tree(), false, openvdb::TopologyCopy());
    out.fill = make_fill_grid(band, *sdf);
    return out;
}

}  // namespace vdbrecon
