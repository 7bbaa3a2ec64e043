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
    // The file is hashed in 64 kB chunks as it is read (not held in memory: it is as large as the
    // grids); `tail` carries the bytes of a word split between chunks.
    char head[kOffset + kLen];
    bool uuid = std::fread(head, 1, sizeof(head), f) == sizeof(head);
    for (std::size_t i = 0; uuid && i < kLen; ++i) {
        const char c = head[kOffset + i];
        const bool dash = i == 8 || i == 13 || i == 18 || i == 23;
        uuid = dash ? c == '-' : std::isxdigit(static_cast<unsigned char>(c)) != 0;
    }
    if (!uuid) {  // an unexpected layout: leave the file as OpenVDB wrote it
        std::fclose(f);
        return;
    }
    // Two FNV-1a style lanes over 8-byte words (byte-wise hashing of a 100 MB file is slow),
    // then the last bytes one by one.
    std::uint64_t h[2] = {0xcbf29ce484222325ULL, 0x84222325cbf29ce4ULL};
    std::vector<char> chunk(std::size_t(1) << 16);
    char tail[8];
    std::size_t tail_size = 0, n;
    auto word = [&h](const char* p) {
        std::uint64_t w;
        std::memcpy(&w, p, 8);
        h[0] = (h[0] ^ w) * 0x100000001b3ULL;
        h[1] = (h[1] ^ (w >> 32 | w << 32)) * 0x100000001b3ULL;
        h[1] ^= h[1] >> 29;
    };
    while ((n = std::fread(chunk.data(), 1, chunk.size(), f)) > 0) {
        std::size_t i = 0;
        while (tail_size > 0 && tail_size < 8 && i < n) tail[tail_size++] = chunk[i++];
        if (tail_size == 8) {
            word(tail);
            tail_size = 0;
        }
        for (; i + 8 <= n; i += 8) word(chunk.data() + i);
        for (; i < n; ++i) tail[tail_size++] = chunk[i];
    }
    for (std::size_t i = 0; i < tail_size; ++i) {
        for (std::uint64_t& x : h) x = (x ^ static_cast<unsigned char>(tail[i])) * 0x100000001b3ULL;
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

std::size_t write_volume(const std::string& path, const Volume& volume) {
    initialize_openvdb();
    if (!volume.sdf) throw InvalidArgument("write_volume: the volume has no sdf grid");
    openvdb::GridPtrVec grids;
    grids.push_back(volume.sdf);
    if (volume.weight) grids.push_back(volume.weight);
    if (volume.nearest) grids.push_back(volume.nearest);
    const openvdb::FloatGrid::Ptr density = make_density(*volume.sdf);
    grids.push_back(density);
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
    return volume.memory_bytes() + std::size_t(density->memUsage());
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
