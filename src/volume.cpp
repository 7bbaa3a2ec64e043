// Volume files (.vdb) and the derived density grid.
#include "vdbrecon/volume.h"

#include <openvdb/io/File.h>
#include <openvdb/tree/LeafManager.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <mutex>
#include <set>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "detail/simd.h"
#ifdef VDBRECON_HAVE_AVX2_PATHS
#include <immintrin.h>
#endif

#include "detail/io_common.h"
#include "detail/vdb_file.h"
#include "vdbrecon/error.h"
#include "vdbrecon/pipeline.h"

namespace vdbrecon {

std::size_t Volume::memory_bytes() const {
    std::size_t bytes = 0;
    auto add = [&bytes](const openvdb::GridBase* g) {
        if (g) bytes += std::size_t(g->memUsage());
    };
    add(sdf.get());
    add(weight.get());
    add(nearest.get());
    add(color.get());
    add(fill.get());
    return bytes;
}

void initialize_openvdb() {
    static std::once_flag once;
    std::call_once(once, [] { openvdb::initialize(); });
}

namespace {

using FloatLeaf = openvdb::FloatTree::LeafNodeType;

/// The density of an sdf value s: a linear ramp of half-width `ramp`, 0.5 on the surface.
inline float density_of(float s, float ramp) {
    return std::clamp(0.5f - s / (2.0f * ramp), 0.0f, 1.0f);
}

/// Writes into `leaf` (at the sdf leaf's origin; every value and the mask are written) the
#ifdef VDBRECON_HAVE_AVX2_PATHS
/// fill_density's loop over one mask word (64 voxels) sixteen at a time (AVX-512): the same
/// operations and values as the SSE2 form below; returns the word of voxels kept on. The
/// bunny's density grid at 0.5 mm, 1 thread: 9.5 -> 7.8 ms (median of 8, with the tree).
__attribute__((target("avx512f"))) std::uint64_t density_word_wide(const float* sv, float* dv,
                                                                   std::uint64_t on, float ramp) {
    const __m512 half = _mm512_set1_ps(0.5f), width = _mm512_set1_ps(2.0f * ramp);
    const __m512 zero = _mm512_setzero_ps(), one = _mm512_set1_ps(1.0f);
    std::uint64_t kept = 0;
    for (int j = 0; j < 64; j += 16) {
        const __m512 v = _mm512_sub_ps(half, _mm512_div_ps(_mm512_loadu_ps(sv + j), width));
        const __mmask16 hi = _mm512_cmp_ps_mask(one, v, _CMP_LT_OS);
        const __mmask16 lo = _mm512_cmp_ps_mask(v, zero, _CMP_LT_OS);
        const __m512 d = _mm512_mask_blend_ps(lo, _mm512_mask_blend_ps(hi, v, one), zero);
        const __mmask16 keep = __mmask16(on >> j) & _mm512_cmp_ps_mask(d, zero, _CMP_NEQ_UQ);
        _mm512_storeu_ps(dv + j, _mm512_maskz_mov_ps(keep, d));
        kept |= std::uint64_t(keep) << j;
    }
    return kept;
}
#endif

/// density of each active voxel of `s`, those of density 0 switched off; whether any is left
/// on (all off and 0 is the background). Four voxels at a time over the buffers and the mask's
/// words where SSE2 is there (x86-64 always), the same values as density_of one at a time. The
/// bunny's density grid at 0.5 mm, 1 thread: 8.6 -> 2.8 ms against a value iterator and
/// setValueOn.
bool fill_density(const FloatLeaf& s, FloatLeaf* leaf, float ramp, bool wide) {
    const float* sv = s.buffer().data();
    float* dv = leaf->buffer().data();
    FloatLeaf::NodeMaskType mask;
    bool any = false;
    for (openvdb::Index w = 0; w < FloatLeaf::NodeMaskType::WORD_COUNT; ++w) {
        const std::uint64_t on = s.getValueMask().getWord<std::uint64_t>(w);
        std::uint64_t kept = 0;
        openvdb::Index j = 0;
#ifdef VDBRECON_HAVE_AVX2_PATHS
        if (wide) {
            kept = density_word_wide(sv + 64 * w, dv + 64 * w, on, ramp);
            j = 64;
        }
#endif
#if defined(__SSE2__)
        const __m128 half = _mm_set1_ps(0.5f), width = _mm_set1_ps(2.0f * ramp);
        const __m128 zero = _mm_setzero_ps(), one = _mm_set1_ps(1.0f);
        for (; j < 64; j += 4) {
            const openvdb::Index i = 64 * w + j;
            // clamp(v, 0, 1) as std::clamp has it: v < 0 ? 0 : (1 < v ? 1 : v), NaN kept.
            const __m128 v = _mm_sub_ps(half, _mm_div_ps(_mm_loadu_ps(sv + i), width));
            const __m128 hi = _mm_cmplt_ps(one, v), lo = _mm_cmplt_ps(v, zero);
            __m128 d = _mm_or_ps(_mm_and_ps(hi, one), _mm_andnot_ps(hi, v));
            d = _mm_andnot_ps(lo, d);  // 0 where v < 0
            const int active = int((on >> j) & 15);
            const __m128 act = _mm_castsi128_ps(_mm_setr_epi32(
                -(active & 1), -((active >> 1) & 1), -((active >> 2) & 1), -((active >> 3) & 1)));
            const __m128 keep = _mm_and_ps(act, _mm_cmpneq_ps(d, zero));
            _mm_storeu_ps(dv + i, _mm_and_ps(keep, d));
            kept |= std::uint64_t(_mm_movemask_ps(keep)) << j;
        }
#endif
        for (; j < 64; ++j) {
            const openvdb::Index i = 64 * w + j;
            const float d = density_of(sv[i], ramp);
            const bool keep = ((on >> j) & 1) != 0 && d != 0.0f;
            dv[i] = keep ? d : 0.0f;
            kept |= std::uint64_t(keep) << j;
        }
        mask.getWord<std::uint64_t>(w) = kept;
        any = any || kept != 0;
    }
    leaf->setValueMask(mask);
    return any;
}

/// The density tree as a copy of the sdf's topology with every active voxel's density, the
/// voxels of density 0 switched off, then pruned (make_density's definition).
openvdb::FloatTree::Ptr density_by_copy(const openvdb::FloatTree& sdf, float ramp) {
    const bool wide = detail::wide_vector_loops();
    openvdb::FloatTree::Ptr tree =
        std::make_shared<openvdb::FloatTree>(sdf, 0.0f, 0.0f, openvdb::TopologyCopy());
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(*tree);
    leaves.foreach ([&](FloatLeaf& leaf, std::size_t) {
        const auto* src = sdf.probeConstLeaf(leaf.origin());
        if (src) fill_density(*src, &leaf, ramp, wide);  // one left all off goes in the prune
    });
    tree->prune(0.0f);
    return tree;
}

/// The same tree for an sdf without active tiles, made directly: a leaf per sdf leaf, filled
/// in parallel, and only those that keep a voxel of density added, in leaf order; the prune
/// then turns those of one value throughout into tiles and merges what the copy's would at the
/// internal levels. (OpenVDB's topology copy allocates every leaf from all threads at once and
/// keeps the empty ones for the prune to free.)
openvdb::FloatTree::Ptr density_direct(const openvdb::FloatTree& sdf, float ramp) {
    const bool wide = detail::wide_vector_loops();
    openvdb::tree::LeafManager<const openvdb::FloatTree> src(sdf);
    // The leaves are allocated on one thread, then filled in parallel: allocated from two
    // threads at once they contended for the CLI's one heap arena (bunny at 0.5 mm, 2 threads,
    // beside the clean stage: the grid in 16-18 ms, no page faults; so, 7-10 ms).
    std::vector<std::unique_ptr<FloatLeaf>> made(src.leafCount());
    for (std::size_t i = 0; i < made.size(); ++i) {
        made[i] = std::make_unique<FloatLeaf>(src.leaf(i).origin(), 0.0f, false);
    }
    std::vector<char> keep(made.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, made.size(), 64),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t i = r.begin(); i < r.end(); ++i) {
                              keep[i] = fill_density(src.leaf(i), made[i].get(), ramp, wide);
                          }
                      });
    openvdb::FloatTree::Ptr tree = std::make_shared<openvdb::FloatTree>(0.0f);
    for (std::size_t i = 0; i < made.size(); ++i) {
        if (keep[i]) tree->addLeaf(made[i].release());
    }
    tree->prune(0.0f);
    return tree;
}

}  // namespace

openvdb::FloatGrid::Ptr make_density(const openvdb::FloatGrid& sdf) {
    // Linear ramp across +-1.5 voxels of the zero crossing: 0 outside, 1 inside, 0.5 on the
    // surface. Only valid (active) sdf voxels carry density; everything else is 0. (An active
    // tile of the sdf stays an active tile of 0.)
    const float ramp = float(1.5 * sdf.voxelSize()[0]);
    openvdb::FloatTree::Ptr tree = sdf.tree().hasActiveTiles() ? density_by_copy(sdf.tree(), ramp)
                                                               : density_direct(sdf.tree(), ramp);
    auto grid = openvdb::FloatGrid::create(tree);
    grid->setTransform(sdf.transform().copy());
    grid->setName("density");
    grid->setGridClass(openvdb::GRID_FOG_VOLUME);
    return grid;
}

std::size_t write_volume(const std::string& path, const Volume& volume) {
    initialize_openvdb();
    if (!volume.sdf) throw InvalidArgument("write_volume: the volume has no sdf grid");
    // Each grid under its role's name (read_volume finds them by name), in full floats (a grid
    // read from a file saved with half floats keeps its values, in twice the bytes) and with a
    // tree of its own (one shared with another grid, an instance in its file, is copied): the
    // file writer's terms. A grid that already meets them is written as it is; the others
    // through a copy, so the caller's grids never change.
    std::vector<detail::FileGrid> grids;
    std::set<const openvdb::TreeBase*> trees;
    auto add = [&](const openvdb::GridBase::Ptr& grid, const char* role) {
        if (!grid) return;
        openvdb::GridBase::Ptr g = grid;
        const bool shared = !trees.insert(&g->baseTree()).second;
        if (shared || g->getName() != role || g->saveFloatAsHalf()) {
            g = shared ? g->deepCopyGrid() : g->copyGrid();
            if (shared) trees.insert(&g->baseTree());
            g->setName(role);
            g->setSaveFloatAsHalf(false);
        }
        grids.push_back({g, {}});
    };
    add(volume.sdf, "sdf");
    add(volume.weight, "weight");
    add(volume.nearest, "nearest");
    // The density grid is made when its turn comes, not beside the three grids before it: the
    // stages that run meanwhile (the CLI writes the volume beside the clean stage) have freed
    // their arrays by then, and it is freed once written (bunny at 0.5 mm: 15 MB).
    std::size_t density_bytes = 0;
    grids.push_back({nullptr, [&] {
                         openvdb::FloatGrid::Ptr density = make_density(*volume.sdf);
                         density_bytes = std::size_t(density->memUsage());
                         return openvdb::GridBase::Ptr(density);
                     }});
    add(volume.color, "color");
    add(volume.fill, "fill");

    openvdb::MetaMap meta;
    meta.insertMeta("creator", openvdb::StringMetadata(std::string("vdbrecon ") + version()));
    meta.insertMeta("vdbrecon_voxel_size", openvdb::DoubleMetadata(volume.voxel_size));
    for (const auto& [key, value] : volume.metadata) {
        meta.insertMeta("vdbrecon_" + key, openvdb::StringMetadata(value));
    }

    detail::AtomicFile file(path);
    try {
        detail::write_vdb_file(file.stream(), path, grids, meta);
    } catch (const openvdb::Exception& e) {
        throw IoError(detail::where(path, std::string("cannot write: ") + e.what()));
    }
    file.commit();
    return volume.memory_bytes() + density_bytes;
}

Volume read_volume(const std::string& path) {
    initialize_openvdb();
    Volume v;
    try {
        detail::read_file(path);  // existence and "is a directory" checks with our messages
        openvdb::io::File in(path);
        in.open(false);
        if (!in.hasGrid("sdf")) {
            throw FormatError(detail::where(path, "has no grid named 'sdf'"));
        }
        v.sdf = openvdb::gridPtrCast<openvdb::FloatGrid>(in.readGrid("sdf"));
        if (!v.sdf) throw FormatError(detail::where(path, "grid 'sdf' is not a float grid"));
        if (in.hasGrid("weight")) {
            v.weight = openvdb::gridPtrCast<openvdb::FloatGrid>(in.readGrid("weight"));
        }
        if (in.hasGrid("nearest")) {
            v.nearest = openvdb::gridPtrCast<openvdb::Vec3fGrid>(in.readGrid("nearest"));
        }
        if (in.hasGrid("color")) {
            v.color = openvdb::gridPtrCast<openvdb::Vec3fGrid>(in.readGrid("color"));
        }
        if (in.hasGrid("fill")) {
            v.fill = openvdb::gridPtrCast<openvdb::FloatGrid>(in.readGrid("fill"));
        }
        const openvdb::MetaMap::Ptr meta = in.getMetadata();
        for (auto it = meta->beginMeta(); it != meta->endMeta(); ++it) {
            const std::string& key = it->first;
            if (key.rfind("vdbrecon_", 0) == 0 && key != "vdbrecon_voxel_size") {
                v.metadata[key.substr(9)] = it->second->str();
            }
        }
        in.close();
    } catch (const openvdb::Exception& e) {
        throw FormatError(detail::where(path, std::string("not a readable .vdb file: ") + e.what()));
    }
    if (!v.sdf->hasUniformVoxels() || !v.sdf->transform().isLinear()) {
        throw FormatError(detail::where(path, "grid 'sdf' needs a linear transform with cubic voxels"));
    }
    v.sdf->setGridClass(openvdb::GRID_LEVEL_SET);
    v.voxel_size = v.sdf->voxelSize()[0];
    const openvdb::Vec3d o = v.sdf->transform().indexToWorld(openvdb::Vec3d(0.0, 0.0, 0.0));
    v.origin = {o[0], o[1], o[2]};
    return v;
}

}  // namespace vdbrecon
