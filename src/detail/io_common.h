// Internals shared by the readers and writers.
#pragma once

#include <array>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "vdbrecon/io.h"
#include "vdbrecon/types.h"

namespace vdbrecon {
struct TextureAtlas;
}

namespace vdbrecon::detail {

/// Points as a reader produces them: double coordinates (before choosing a local frame) and
/// optional attributes, each either empty or one entry per row.
struct RawPoints {
    std::vector<double> xyz;            ///< 3 per row, or empty when xyz_float holds the rows
    std::vector<Vec3f> xyz_float;       ///< the rows, when every coordinate came as a float
                                        ///< (exact in single precision: half the memory)
    std::vector<Vec3f> normals;         ///< per row or empty
    std::vector<Vec3f> colors;          ///< per row or empty, 0..1
    std::vector<float> scales;          ///< 1 per row or empty
    std::vector<float> confidences;     ///< 1 per row or empty
    std::vector<std::int32_t> scans;    ///< 1 per row or empty: the scan a row came from
    LasAttributes las;                  ///< LAS rows: 1 per row each, else empty
    std::vector<Triangle> faces;        ///< only for meshes

    std::size_t rows() const { return xyz_float.empty() ? xyz.size() / 3 : xyz_float.size(); }
    /// Row i's coordinates.
    std::array<double, 3> row(std::size_t i) const {
        if (!xyz_float.empty()) {
            const Vec3f& p = xyz_float[i];
            return {double(p[0]), double(p[1]), double(p[2])};
        }
        return {xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]};
    }
};

/// The whole file in memory. Throws IoError naming the file (missing, a directory, unreadable).
std::string read_file(const std::string& path);

/// A file's bytes to parse: a regular file is mapped (its pages are the page cache's, and those
/// parsed can be let go), anything else is read into memory (read_file, whose errors name the
/// file). A mapped file that another process truncates while it is read ends the process with
/// SIGBUS, as with any mapped reader.
class FileBytes {
  public:
    explicit FileBytes(const std::string& path);
    ~FileBytes();
    FileBytes(const FileBytes&) = delete;
    FileBytes& operator=(const FileBytes&) = delete;

    std::string_view bytes() const;
    /// The whole pages before `upto` leave memory (a mapped file's; a later read maps them in
    /// again from the file, so this only ever costs time).
    void let_go(const char* upto);

  private:
    const char* map_ = nullptr;
    std::size_t size_ = 0, released_ = 0;
    std::string copy_;
};

/// Drops non-finite rows (or throws, per options), normalises normals (zero/NaN ones become
/// 0,0,0 and are counted), picks the local frame, and fills a ReadResult.
ReadResult finalize_points(RawPoints&& raw, const std::string& path, const std::string& format,
                           const ReadOptions& options);

/// The warnings of a read (rows dropped, normals to re-estimate), or its error when no point
/// is left.
void report_read(const std::string& path, const ReadResult& result);

/// Handed a chunk of a streamed file's points in pass `pass`: rows [first, ...) of the file
/// (those dropped for non-finite coordinates left out), as read_points would have them.
using PointsSink = std::function<void(ReadResult& chunk, std::size_t first, int pass)>;

/// A PLY, LAS or text file's points a chunk at a time (kStreamRows rows), in the local frame of
/// the whole file, so that the chunks' clouds joined are read_points' cloud; `passes` times
/// over, after a first pass for the frame. No more than a chunk of rows in memory. `totals` gets the format,
/// the frame (its cloud's origin, and no point) and the counts. Returns false, having read
/// nothing, for a file of another format. Throws as read_points (its warnings and errors about
/// the whole file come after the chunks of the first pass). `frame` gets what the frame's pass
/// found. With `need_normals`, a file whose points have no normals (not a PLY file with normals)
/// is of another format.
struct StreamFrame {
    std::size_t rows = 0;   ///< rows with finite coordinates (the points of the cloud)
    double diagonal = 0.0;  ///< of their bounding box, world units
};
bool stream_points(const std::string& path, const ReadOptions& options, const PointsSink& sink,
                   ReadResult& totals, int passes = 1, StreamFrame* frame = nullptr,
                   bool need_normals = false);

/// Converts raw mesh rows into a Mesh (faces must index existing rows; checked by the reader).
Mesh finalize_mesh(RawPoints&& raw, const std::string& path);

/// Picks a local frame for coordinates: (0,0,0) unless the points are far from the origin
/// compared with their extent, then the box centre rounded to a power-of-two grid.
Vec3d choose_origin(const double* xyz, std::size_t rows);
Vec3d choose_origin(const RawPoints& raw);

/// `path` without its extension (the last '.' of its file name and what follows).
std::string path_stem(const std::string& path);

/// "file: message" — the prefix every reader error carries.
std::string where(const std::string& path, const std::string& message);

/// Text from a file, fit for a one-line message: bytes outside printable ASCII become \xNN, and
/// more than 32 characters are cut to 29 + "...".
std::string printable(std::string_view text);

/// Throws IoError naming `path` unless a file can be created there: its directory must exist,
/// be a directory and be writable, and `path` itself must not be a directory.
void check_writable(const std::string& path);

/// Moves the file `temp` to `final_path` in the same directory, replacing a file there
/// atomically, and returns 0 or the errno of the failure. An older regular file is swapped out
/// (renameat2 RENAME_EXCHANGE) and removed rather than renamed over, which ext4 would turn into
/// a flush of the new file's data; like rename, nothing is synced to disk.
int move_into_place(const std::string& temp, const std::string& final_path);

/// Writes to a temporary file in the target directory; commit() renames it onto the final
/// path. If never committed, the destructor removes the temporary file.
class AtomicFile {
public:
    explicit AtomicFile(const std::string& final_path);
    ~AtomicFile();
    AtomicFile(const AtomicFile&) = delete;
    AtomicFile& operator=(const AtomicFile&) = delete;

    const std::string& temp_path() const { return temp_; }
    const std::string& final_path() const { return final_; }
    /// An open stdio stream on the temp file (for writers that stream bytes).
    std::FILE* stream();
    /// Creates the (empty) temp file and closes it again, for writers that open the path
    /// themselves: failures are reported here, in our words, naming the final path.
    void create();
    /// Closes the stream (if any), checks for write errors and renames. Throws IoError.
    void commit();

private:
    std::string final_, temp_;
    std::FILE* file_ = nullptr;
    bool committed_ = false;
};

/// The outputs of one run as a unit: each is written under a temporary name in its target
/// directory (same extension, so writers that pick the format by extension work on it), and
/// commit_all() renames them all into place once the whole run has succeeded. What was not
/// committed is removed by the destructor, or by remove_temp_files_now() on SIGINT / SIGTERM:
/// a run that fails at any stage leaves the earlier outputs untouched.
class StagedOutputs {
public:
    StagedOutputs() = default;
    ~StagedOutputs();
    StagedOutputs(const StagedOutputs&) = delete;
    StagedOutputs& operator=(const StagedOutputs&) = delete;

    /// The temporary path to write `final_path` to.
    std::string stage(const std::string& final_path);
    /// Renames every staged file that was written onto its final path. Throws IoError.
    void commit_all();
    /// `message` with every temporary name replaced by its final path (errors from writers
    /// name the file they were given, which the user never asked for).
    std::string final_names(std::string message) const;

private:
    struct Entry {
        std::string temp, final;
        bool committed = false;
    };
    std::vector<Entry> files_;
};

/// What an OBJ with materials adds to a plain one: `mtllib`, per face the texture coordinates
/// of its corners (NaN for faces without: those use the plain material).
struct ObjMaterials {
    std::string mtl_name;  ///< the material file's name, beside the OBJ
    const std::vector<std::array<std::array<float, 2>, 3>>* uv = nullptr;
};

/// Writes `mesh` as an OBJ at `path` (atomically), with `materials` when non-null.
void write_obj_file(const std::string& path, const Mesh& mesh, const WriteOptions& options,
                    const ObjMaterials* materials = nullptr);

/// Stages an OBJ at `obj_path` with its material file and atlas (texture.h's paths) in `staged`
/// and writes them there.
void write_textured(StagedOutputs& staged, const std::string& obj_path, const Mesh& mesh,
                    const TextureAtlas& atlas, const WriteOptions& options);

/// Buffered writer on an AtomicFile's stream; errors surface at commit.
class ByteWriter {
public:
    explicit ByteWriter(std::FILE* f) : f_(f) { buf_.reserve(kSize); }
    ~ByteWriter() { flush(); }
    void write(const void* data, std::size_t n);
    void put(const std::string& s) { write(s.data(), s.size()); }
    void flush();

private:
    static constexpr std::size_t kSize = 1 << 20;
    std::FILE* f_;
    std::string buf_;
};

/// Parses the whole token [b, e) as a decimal number (an optional leading '+', "nan", "inf" and
/// "infinity" allowed); true on success. Magnitudes beyond double's range become +-inf, below
/// it +-0 or a subnormal, as strtod gives them.
bool parse_double(const char* b, const char* e, double& v);

/// Shortest round-trip decimal text of a float / double (std::to_chars).
std::string format_number(float v);
std::string format_number(double v);

/// Told that the bytes before a point of the content will not be read again.
using Consumed = std::function<void(const char* upto)>;

/// Handed the vertex rows [first, first + chunk.rows()) of a file, a chunk at a time, instead of
/// their being kept (a streamed read: the whole file's rows are never in memory at once).
using RowSink = std::function<void(RawPoints& chunk, std::size_t first)>;

/// Reads a PLY file into raw rows; `want_faces` also reads the face element. `consumed` (may be
/// empty) hears of the vertex rows read, a chunk at a time. With a `sink`, the vertex rows go to
/// it, kStreamRows at a time, and the RawPoints returned holds none.
RawPoints read_ply_raw(const std::string& path, std::string_view content, bool want_faces,
                       std::string& format, const Consumed& consumed = {},
                       const RowSink& sink = {});
constexpr std::size_t kStreamRows = std::size_t(1) << 20;
/// A streamed read's hand-over in the LAS and text readers: with a sink, the rows held go to it
/// once there are kStreamRows of them (at the `end`, any there are) and are let go; `handed`
/// counts the rows handed.
void hand_rows(RawPoints& raw, const RowSink& sink, std::size_t& handed, bool end);
/// Whether a PLY file's vertex element has normals (nx ny nz or an alias). Throws FormatError
/// for a bad header.
bool ply_has_normals(const std::string& path, std::string_view content);
/// Reads XYZ / PTS text; `consumed` and `sink` as read_ply_raw's.
RawPoints read_xyz_raw(const std::string& path, std::string_view content,
                       const Consumed& consumed = {}, const RowSink& sink = {});
/// Reads OBJ (v, vn, f).
RawPoints read_obj_raw(const std::string& path, std::string_view content, bool want_faces);
/// ASPRS LAS 1.0-1.4 (io_las.cpp): the points of `classes` (all when empty), RGB as colours;
/// `consumed` and `sink` as read_ply_raw's.
RawPoints read_las_raw(const std::string& path, std::string_view content,
                       const std::vector<int>& classes, const Consumed& consumed = {},
                       const RowSink& sink = {});

/// PLY writer for clouds and meshes. Empty attributes are left out; `faces` may be null;
/// `regions` (one per face) are the faces' `region` property.
void write_ply(const std::string& path, Span<Vec3f> positions, const Vec3d& origin,
               Span<Vec3f> normals, Span<Vec3f> colors, Span<float> scales,
               Span<float> confidences, const Column<Triangle>* faces,
               const WriteOptions& options, Span<std::int32_t> regions = {});

}  // namespace vdbrecon::detail
