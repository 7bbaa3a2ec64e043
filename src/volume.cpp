// Volume files (.vdb) and the derived density grid.
#include "vdbrecon/volume.h"

#include <openvdb/io/File.h>
#include <openvdb/tree/LeafManager.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstring>
#include <mutex>

#include "detail/io_common.h"
#include "vdbrecon/error.h"
#include "vdbrecon/pipeline.h"

namespace vdbrecon {

void initialize_openvdb() {
    static std::once_flag once;
    std::call_once(once, [] { openvdb::initialize(); });
}

openvdb::FloatGrid::Ptr make_density(const openvdb::FloatGrid& sdf) {
    // Linear ramp across +-1.5 voxels of the zero crossing: 0 outside, 1 inside, 0.5 on the
    // surface. Only valid (active) sdf voxels carry density; everything else is 0.
    const float ramp = float(1.5 * sdf.voxelSize()[0]);
    openvdb::FloatTree::Ptr tree = std::make_shared<openvdb::FloatTree>(
        sdf.tree(), 0.0f, 0.0f, openvdb::TopologyCopy());
    openvdb::tree::LeafManager<openvdb::FloatTree> leaves(*tree);
    leaves.foreach ([&](openvdb::FloatTree::LeafNodeType& leaf, std::size_t) {
        const auto* src = sdf.tree().probeConstLeaf(leaf.origin());
        if (!src) return;
        for (auto it = leaf.beginValueOn(); it; ++it) {
            const float d = std::clamp(0.5f - src->getValue(it.pos()) / (2.0f * ramp), 0.0f, 1.0f);
            it.setValue(d);
            if (d == 0.0f) it.setValueOff();
        }
    });
    tree->prune(0.0f);
    auto grid = openvdb::FloatGrid::create(tree);
    grid->setTransform(sdf.transform().copy());
    grid->setName("density");
    grid->setGridClass(openvdb::GRID_FOG_VOLUME);
    return grid;
}

namespace {

/// OpenVDB stamps every file with a random UUID (36 ASCII characters after the 8-byte magic,
/// three uint32 versions and a flag byte), so two writes of the same grids differ. Replace it
/// with one derived from the rest of the file (an FNV-style hash, as a version-5 style UUID):
/// equal volumes then give byte-identical files whatever the thread count or the run.
void make_uuid_deterministic(const std::string& file) {
    constexpr long kOffset = 8 + 4 + 4 + 4 + 1;
    constexpr std::size_t kLen = 36;
    std::FILE* f = std::fopen(file.c_str(), "r+b");
    if (!f) throw IoError(detail::where(file, "cannot reopen the temporary .vdb file"));
    std::string content;
    char chunk[1 << 16];
    std::size_t n;
    while ((n = std::fread(chunk, 1, sizeof(chunk), f)) > 0) content.append(chunk, n);
    auto is_uuid = [&] {
        if (content.size() < kOffset + kLen) return false;
        for (std::size_t i = 0; i < kLen; ++i) {
            const char c = content[kOffset + i];
            const bool dash = i == 8 || i == 13 || i == 18 || i == 23;
            if (dash ? c != '-' : !std::isxdigit(static_cast<unsigned char>(c))) return false;
        }
        return true;
    };
    if (!is_uuid()) {  // an unexpected layout: leave the file as OpenVDB wrote it
        std::fclose(f);
        return;
    }
    // Two FNV-1a style lanes over 8-byte words (byte-wise hashing of a 100 MB file is slow).
    std::uint64_t h[2] = {0xcbf29ce484222325ULL, 0x84222325cbf29ce4ULL};
    std::size_t i = kOffset + kLen;
    for (; i + 8 <= content.size(); i += 8) {
        std::uint64_t word;
        std::memcpy(&word, content.data() + i, 8);
        h[0] = (h[0] ^ word) * 0x100000001b3ULL;
        h[1] = (h[1] ^ (word >> 32 | word << 32)) * 0x100000001b3ULL;
        h[1] ^= h[1] >> 29;
    }
    for (; i < content.size(); ++i) {
        for (std::uint64_t& x : h) x = (x ^ static_cast<unsigned char>(content[i])) * 0x100000001b3ULL;
    }
    unsigned char b[16];
    for (int i = 0; i < 8; ++i) {
        b[i] = static_cast<unsigned char>(h[0] >> (8 * i));
        b[8 + i] = static_cast<unsigned char>(h[1] >> (8 * i));
    }
    b[6] = static_cast<unsigned char>((b[6] & 0x0f) | 0x50);  // version 5 (name-based)
    b[8] = static_cast<unsigned char>((b[8] & 0x3f) | 0x80);  // RFC 4122 variant
    char text[kLen + 1];
    std::snprintf(text, sizeof(text),
                  "%02x%02x%02x%02x-%02x%02x-%02x%02x-%02x%02x-%02x%02x%02x%02x%02x%02x", b[0],
                  b[1], b[2], b[3], b[4], b[5], b[6], b[7], b[8], b[9], b[10], b[11], b[12], b[13],
                  b[14], b[15]);
    const bool ok = std::fseek(f, kOffset, SEEK_SET) == 0 && std::fwrite(text, 1, kLen, f) == kLen;
    if (std::fclose(f) != 0 || !ok) {
        throw IoError(detail::where(file, "cannot write the .vdb header"));
    }
}

}  // namespace

void write_volume(const std::string& path, const Volume& volume) {
    initialize_openvdb();
    if (!volume.sdf) throw InvalidArgument("write_volume: the volume has no sdf grid");
    openvdb::GridPtrVec grids;
    grids.push_back(volume.sdf);
    if (volume.weight) grids.push_back(volume.weight);
    if (volume.nearest) grids.push_back(volume.nearest);
    grids.push_back(make_density(*volume.sdf));
    if (volume.color) grids.push_back(volume.color);
    if (volume.fill) grids.push_back(volume.fill);

    openvdb::MetaMap meta;
    meta.insertMeta("creator", openvdb::StringMetadata(std::string("vdbrecon ") + version()));
    meta.insertMeta("vdbrecon_voxel_size", openvdb::DoubleMetadata(volume.voxel_size));
    for (const auto& [key, value] : volume.metadata) {
        meta.insertMeta("vdbrecon_" + key, openvdb::StringMetadata(value));
    }

    detail::AtomicFile file(path);
    file.create();  // permission and space problems are reported in our words
    try {
        openvdb::io::File out(file.temp_path());
        // Active-mask compression only: Blosc saved ~6 % of the size of the bunny's grids (float
        // distances barely compress) for ~40 % more write time.
        out.setCompression(openvdb::io::COMPRESS_ACTIVE_MASK);
        out.write(grids, meta);
        out.close();
    } catch (const openvdb::Exception& e) {
        throw IoError(detail::where(path, std::string("cannot write: ") + e.what()));
    }
    make_uuid_deterministic(file.temp_path());
    file.commit();
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
