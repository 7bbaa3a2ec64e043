// Internals shared by the meshers (dual, vdb, mc, dc): grid sampling helpers and the raw surface
// each mesher hands to finish_mesh().
#pragma once

#include <openvdb/openvdb.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <utility>
#include <vector>

#include "detail/fill_later.h"
#include "vdbrecon/mesh.h"
#include "vdbrecon/volume.h"

namespace vdbrecon::detail {

using FloatAccessor = openvdb::tree::ValueAccessor<const openvdb::FloatTree>;
using Vec3Accessor = openvdb::tree::ValueAccessor<const openvdb::Vec3fTree>;

/// What a mesher produces: points in index space and triangles, counter-clockwise seen from the
/// positive (outside) side.
struct RawSurface {
    std::vector<openvdb::Vec3f> points;
    std::vector<Triangle> triangles;
    /// Per point, the mesher's own vertex normal (unit, or zero where it has none), or empty:
    /// finish_mesh() then takes the SDF gradient at the point.
    std::vector<openvdb::Vec3f> normals;
    /// True when points may lie in cells with invalid corners (volumeToMesh does not know the
    /// validity mask); finish_mesh() then drops the faces there.
    bool check_cells = false;
};

/// A leaf's voxels and a margin around them (origin - 1 .. origin + 9 on each axis) copied into
/// dense arrays, so stencils around the leaf's voxels and cells read arrays instead of walking the
/// tree; reads outside the block go to the accessor. It offers the accessor's probeValue(),
/// getValue() and isValueOn(), so stencil code is written once (as a template) for both.
class LeafBlock {
public:
    static constexpr int kN = 11;  ///< block width: one voxel before the leaf, two after

    explicit LeafBlock(FloatAccessor& acc) : acc_(acc) {}

    /// Copies the leaf at `origin` and the margin from its neighbours (or their tiles).
    void load(const openvdb::Coord& origin) {
        base_ = origin.offsetBy(-1);
        // Per axis and neighbour offset d (-1, 0, 1): block range and the neighbour's first voxel.
        static constexpr int kBegin[3] = {0, 1, 9}, kEnd[3] = {1, 9, 11}, kLocal[3] = {7, 0, 0};
        for (int dx = 0; dx < 3; ++dx) {
            for (int dy = 0; dy < 3; ++dy) {
                for (int dz = 0; dz < 3; ++dz) {
                    const openvdb::Coord o = origin.offsetBy(8 * (dx - 1), 8 * (dy - 1), 8 * (dz - 1));
                    const auto* leaf = acc_.probeConstLeaf(o);
                    const int z0 = kBegin[dz], nz = kEnd[dz] - z0, lz0 = kLocal[dz];
                    if (!leaf) {
                        float tile = 0.0f;
                        const std::uint8_t tile_on = acc_.probeValue(o, tile);
                        for (int x = kBegin[dx]; x < kEnd[dx]; ++x) {
                            for (int y = kBegin[dy]; y < kEnd[dy]; ++y) {
                                const int row = (x * kN + y) * kN + z0;
                                std::fill(value_ + row, value_ + row + nz, tile);
                                std::fill(on_ + row, on_ + row + nz, tile_on);
                            }
                        }
                        continue;
                    }
                    const float* data = leaf->buffer().data();
                    const auto& mask = leaf->getValueMask();
                    for (int x = kBegin[dx]; x < kEnd[dx]; ++x) {
                        const int lx = kLocal[dx] + x - kBegin[dx];
                        for (int y = kBegin[dy]; y < kEnd[dy]; ++y) {
                            const int ly = kLocal[dy] + y - kBegin[dy];
                            const int row = (x * kN + y) * kN + z0;
                            // A z-row of a leaf: 8 consecutive values, one byte of its mask word.
                            const float* src = data + ((lx << 6) | (ly << 3) | lz0);
                            const unsigned bits =
                                mask.template getWord<std::uint8_t>(openvdb::Index(lx * 8 + ly)) >>
                                lz0;
                            if (nz == 8) {  // fixed-size copies, which the compiler inlines
                                std::copy(src, src + 8, value_ + row);
                                for (int z = 0; z < 8; ++z) on_[row + z] = (bits >> z) & 1u;
                            } else {  // the margins: one voxel before the leaf, two after
                                value_[row] = src[0];
                                on_[row] = bits & 1u;
                                if (nz == 2) {
                                    value_[row + 1] = src[1];
                                    on_[row + 1] = (bits >> 1) & 1u;
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    /// The block index of voxel c, when c is in the block.
    bool index(const openvdb::Coord& c, int& i) const {
        const unsigned x = unsigned(c[0] - base_[0]), y = unsigned(c[1] - base_[1]),
                       z = unsigned(c[2] - base_[2]);
        if (x >= unsigned(kN) || y >= unsigned(kN) || z >= unsigned(kN)) return false;
        i = int((x * kN + y) * kN + z);
        return true;
    }

    float value(int i) const { return value_[i]; }
    bool on(int i) const { return on_[i] != 0; }
    /// The dense arrays, block index i = (x * kN + y) * kN + z (steps kStep along x, y, z).
    const float* values() const { return value_; }
    const std::uint8_t* actives() const { return on_; }
    static constexpr int kStep[3] = {kN * kN, kN, 1};
    /// Whether block index i has all 26 neighbours in the block.
    static bool interior(int i) {
        const int x = i / (kN * kN), y = (i / kN) % kN, z = i % kN;
        return x > 0 && x < kN - 1 && y > 0 && y < kN - 1 && z > 0 && z < kN - 1;
    }

    bool probeValue(const openvdb::Coord& c, float& f) {
        int i;
        if (!index(c, i)) return acc_.probeValue(c, f);
        f = value_[i];
        return on_[i];
    }
    float getValue(const openvdb::Coord& c) {
        int i;
        return index(c, i) ? value_[i] : acc_.getValue(c);
    }
    bool isValueOn(const openvdb::Coord& c) {
        int i;
        return index(c, i) ? bool(on_[i]) : acc_.isValueOn(c);
    }

private:
    FloatAccessor& acc_;
    openvdb::Coord base_;
    float value_[kN * kN * kN];
    std::uint8_t on_[kN * kN * kN];
};

/// A cell (the cube between voxel c and c + 1) is valid when its eight corners are active.
inline bool cell_valid(FloatAccessor& acc, const openvdb::Coord& c) {
    for (int dx = 0; dx <= 1; ++dx) {
        for (int dy = 0; dy <= 1; ++dy) {
            for (int dz = 0; dz <= 1; ++dz) {
                if (!acc.isValueOn(c.offsetBy(dx, dy, dz))) return false;
            }
        }
    }
    return true;
}

/// Turns a mesher's raw surface into the result: drops faces in invalid cells (when asked),
/// with too little weight or too far from the data, compacts the vertices, and adds normals and
/// colours.
MeshResult finish_mesh(const Volume& volume, const MeshOptions& options, RawSurface&& raw);

/// What finish_mesh makes of a point a triangle uses.
enum PointStatus : char { kInvalid = 0, kSupported = 1, kWeak = 2, kFar = 3 };

/// A raw surface with what the volume says of each point (finish_mesh's first half, which
/// reads the volume; the second half, finish_surface, needs only this).
struct ClassifiedSurface {
    std::vector<openvdb::Vec3f> points;  ///< index space
    std::vector<Triangle> triangles;     ///< faces with a point in an invalid cell dropped
    std::vector<char> status;            ///< per point, a PointStatus (kInvalid when unused)
    std::vector<openvdb::Vec3f> grad;    ///< per point, the mesher's normal or the SDF gradient
    std::vector<openvdb::Vec3f> colors;  ///< per point, from the "color" grid; empty without
    std::vector<float> weight;           ///< per point, from the "weight" grid; empty without
    std::size_t dropped_faces = 0;
};

/// Classifies the points the triangles use and drops the faces in invalid cells.
ClassifiedSurface classify_surface(const Volume& volume, const MeshOptions& options,
                                   RawSurface&& raw);

/// Trims unsupported faces from the open border inwards, compacts the points, makes world
/// vertices (x voxel, in the frame of `origin`), colours and normals. Every step looks only at
/// the surface, so a surface stitched from tiles' pieces finishes as the whole one would.
MeshResult finish_surface(ClassifiedSurface&& surface, double voxel, const Vec3d& origin,
                          const MeshOptions& options);

/// The raw surface of options.method.
RawSurface mesh_raw(const Volume& volume, const MeshOptions& options);

RawSurface mesh_vdb(const Volume& volume, const MeshOptions& options);
RawSurface mesh_mc(const Volume& volume, const MeshOptions& options);
RawSurface mesh_dc(const Volume& volume, const MeshOptions& options);
RawSurface mesh_dual(const Volume& volume, const MeshOptions& options);

}  // namespace vdbrecon::detail
