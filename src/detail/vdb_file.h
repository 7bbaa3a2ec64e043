// Writing .vdb files without OpenVDB's per-leaf stream writes.
#pragma once

#include <openvdb/openvdb.h>

#include <functional>
#include <string>
#include <vector>

namespace vdbrecon::detail {

/// One grid of a file: `grid`, or, when that is null, the grid `make` returns when its turn to
/// be written comes (so that it need not coexist with the grids written before it).
struct FileGrid {
    openvdb::GridBase::ConstPtr grid;
    std::function<openvdb::GridBase::Ptr()> make;
};

/// Writes `grids` (float and Vec3f grids with distinct, non-empty names and trees of their own)
/// and the file metadata `meta` to the open file `file` (named `path` in errors), in the layout
/// openvdb::io::File::write gives with active-mask compression and grid statistics: OpenVDB
/// writes each grid's descriptor, metadata, transform and topology, and we write the leaf
/// buffers, in parallel into one large buffer at a time, with the bytes OpenVDB would write.
/// OpenVDB stamps a random UUID; this one is derived from the rest of the file, so equal grids
/// give byte-identical files whatever the run or thread count. Throws IoError when a write
/// fails and InvalidArgument for grids outside the above.
void write_vdb_file(std::FILE* file, const std::string& path, const std::vector<FileGrid>& grids,
                    const openvdb::MetaMap& meta);

}  // namespace vdbrecon::detail
