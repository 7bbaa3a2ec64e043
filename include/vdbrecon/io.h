// Reading point clouds and meshes, writing meshes and point clouds.
//
// Readers: PLY (ascii, binary little/big endian, any property order, every scalar type and alias,
// other elements and list properties skipped), XYZ/PTS text (x y z [nx ny nz]), OBJ (v, vn, f).
// Writers: PLY (three encodings) and OBJ, chosen by extension. Every write goes to a temporary
// file in the target directory and is renamed into place, so a failed run never leaves a
// half-written file under the final name.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "vdbrecon/types.h"

namespace vdbrecon {

/// What a reader does with a row whose coordinates are NaN or infinite.
enum class NonFinitePolicy {
    drop,   ///< drop the row and report the count (a warning through the log handler)
    error,  ///< throw FormatError naming the first such row
};

struct ReadOptions {
    /// Rows with NaN/inf coordinates: dropped with a counted warning, or an error.
    NonFinitePolicy non_finite = NonFinitePolicy::drop;
    /// Re-centre far-away coordinates (georeferenced scans) into a local float frame;
    /// the offset is kept in PointCloud::origin.
    bool local_frame = true;
    /// LAS input: keep only the points of these classification codes (e.g. {2, 6}: ground and
    /// buildings); empty keeps all. Refused for other formats.
    std::vector<int> classes;
};

/// The per-point attributes of a LAS file (empty for other formats), one entry per point of the
/// cloud.
struct LasAttributes {
    std::vector<std::uint8_t> classification;     ///< ASPRS class (2 ground, 6 building, ...)
    std::vector<std::uint16_t> intensity;         ///< return pulse magnitude, sensor units
    std::vector<std::uint8_t> return_number;      ///< 1-based, of number_of_returns
    std::vector<std::uint8_t> number_of_returns;  ///< returns of the pulse

    bool empty() const { return classification.empty(); }
};

/// What a point reader found.
struct ReadResult {
    PointCloud cloud;
    std::string format;                 ///< e.g. "ply binary_little_endian", "xyz", "obj"
    std::size_t rows = 0;               ///< rows in the file (before dropping)
    std::size_t dropped_nonfinite = 0;  ///< rows dropped for NaN/inf coordinates
    std::size_t first_dropped = 0;      ///< the first of them (when there are)
    std::size_t invalid_normals = 0;    ///< normals that were zero or NaN (set to 0,0,0)
    std::size_t bytes = 0;              ///< memory of the cloud as read (its arrays)
    /// The scan each point came from (PLY property `scan`, `scan_id` or `scan_index`, as the
    /// merged Stanford scans have it), one per point of the cloud; empty without one.
    std::vector<std::int32_t> scans;
    /// LAS input: classification, intensity and returns of every point kept.
    LasAttributes las;
};

/// Reads a point cloud; the format comes from the extension (.ply .xyz .pts .txt .obj .las), or
/// from the content when the extension is unknown. Throws IoError / FormatError naming the file.
ReadResult read_points(const std::string& path, const ReadOptions& options = {});

/// Reads a triangle mesh (PLY with a face element, or OBJ with f lines; polygons are fanned
/// into triangles). Throws IoError / FormatError naming the file.
Mesh read_mesh(const std::string& path);

/// read_points on a file's bytes already in memory (read_points reads the file and calls this).
/// `name` stands for the path: its extension picks the format (else the content does) and
/// every message starts with it. Throws FormatError.
ReadResult read_points_from_memory(std::string_view bytes, const std::string& name,
                                   const ReadOptions& options = {});

/// read_mesh on a file's bytes already in memory (read_mesh reads the file and calls this).
Mesh read_mesh_from_memory(std::string_view bytes, const std::string& name);

enum class PlyEncoding { binary_little_endian, binary_big_endian, ascii };

struct WriteOptions {
    /// PLY encoding (ignored for OBJ).
    PlyEncoding encoding = PlyEncoding::binary_little_endian;
    /// Extra header comments (PLY) or # lines (OBJ).
    std::vector<std::string> comments;
};

/// Writes a mesh as PLY or OBJ (by extension; anything else is an InvalidArgument). Vertex
/// normals and colours are written when present; world = origin + vertex (as double when the
/// origin is not zero). Atomic: temp file + rename.
void write_mesh(const std::string& path, const Mesh& mesh, const WriteOptions& options = {});

/// Writes a point cloud as PLY (every attribute the cloud has) or XYZ text. Atomic.
void write_points(const std::string& path, const PointCloud& cloud,
                  const WriteOptions& options = {});

/// Unlinks every temporary file a writer currently has open, and removes a tiled run's scratch
/// directory. Async-signal-safe, so a SIGINT / SIGTERM handler may call it before the process
/// dies (no partial outputs or scratch files survive).
void remove_temp_files_now();

/// Lower-case extension of a path without the dot ("" when there is none).
std::string file_extension(const std::string& path);

}  // namespace vdbrecon
