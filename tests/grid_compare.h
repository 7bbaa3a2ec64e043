// Bit-for-bit comparison of OpenVDB grids and volumes (the determinism and vector-loop tests).
#pragma once

#include <cstring>

#include "vdbrecon/volume.h"

namespace vdbrecon::test {

/// The same active voxels, leaves and values, bit for bit.
template <typename GridT>
bool same_grids(const GridT& a, const GridT& b) {
    if (a.activeVoxelCount() != b.activeVoxelCount() ||
        a.tree().leafCount() != b.tree().leafCount()) {
        return false;
    }
    for (auto it = a.tree().cbeginLeaf(); it; ++it) {
        const auto* other = b.tree().probeConstLeaf(it->origin());
        if (!other || other->getValueMask() != it->getValueMask()) return false;
        if (std::memcmp(it->buffer().data(), other->buffer().data(),
                        sizeof(typename GridT::ValueType) * it->SIZE) != 0) {
            return false;
        }
    }
    return true;
}

/// The sdf, weight, nearest and colour grids of two volumes are bit-identical.
inline bool same_volumes(const Volume& a, const Volume& b) {
    return same_grids(*a.sdf, *b.sdf) && same_grids(*a.weight, *b.weight) &&
           same_grids(*a.nearest, *b.nearest) && same_grids(*a.color, *b.color);
}

}  // namespace vdbrecon::test
