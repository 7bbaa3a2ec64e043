// Format dispatch, the local frame, and the OBJ / XYZ writers (the shared primitives, atomic
// writes among them, are in io_common.cpp).
#include "vdbrecon/io.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <limits>
#include <map>
#include <mutex>
#include <set>
#include <sstream>
#include <utility>

#include "detail/io_common.h"
#include "detail/io_pcd.h"
#include "detail/release.h"
#include "detail/temp_files.h"
#include "vdbrecon/error.h"
#include "vdbrecon/log.h"

namespace vdbrecon {

double BBox::diagonal() const {
    if (empty()) return 0.0;
    double s = 0.0;
    for (int a = 0; a < 3; ++a) {
        const double d = double(max[a]) - double(min[a]);
        s += d * d;
    }
    return std::sqrt(s);
}

BBox bounding_box(Span<Vec3f> positions) {
    if (positions.empty()) return BBox{};
    // In parallel: min and max do not depend on the order, so neither on the threads. Each
    // part starts from the first position, as one pass over them all would.
    const BBox first{positions[0], positions[0]};
    auto extend = [](BBox b, const Vec3f& lo, const Vec3f& hi) {
        for (int a = 0; a < 3; ++a) {
            b.min[a] = std::min(b.min[a], lo[a]);
            b.max[a] = std::max(b.max[a], hi[a]);
        }
        return b;
    };
    return tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, positions.size(), 16384), first,
        [&](const tbb::blocked_range<std::size_t>& r, BBox b) {
            for (std::size_t i = r.begin(); i < r.end(); ++i) b = extend(b, positions[i], positions[i]);
            return b;
        },
        [&](const BBox& a, const BBox& b) { return extend(a, b.min, b.max); });
}


namespace detail {

std::string path_stem(const std::string& path) {
    const std::size_t slash = path.find_last_of('/');
    const std::size_t dot = path.find_last_of('.');
    if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return path;
    return path.substr(0, dot);
}

std::string read_file(const std::string& path) {
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0) {
        throw IoError(where(path, std::string("cannot open: ") + std::strerror(errno)));
    }
    if (S_ISDIR(st.st_mode)) throw IoError(where(path, "is a directory, not a file"));
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) throw IoError(where(path, std::string("cannot open: ") + std::strerror(errno)));
    std::string content;
    char chunk[1 << 16];
    if (S_ISREG(st.st_mode)) content.reserve(std::size_t(st.st_size));
    std::size_t n;
    while ((n = std::fread(chunk, 1, sizeof(chunk), f)) > 0) content.append(chunk, n);
    const bool failed = std::ferror(f) != 0;
    const int err = errno;
    std::fclose(f);
    if (failed) throw IoError(where(path, std::string("read error: ") + std::strerror(err)));
    return content;
}

FileBytes::FileBytes(const std::string& path) {
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    struct stat st {};
    if (fd >= 0 && ::fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0) {
        void* m = ::mmap(nullptr, std::size_t(st.st_size), PROT_READ, MAP_PRIVATE, fd, 0);
        if (m != MAP_FAILED) {
            map_ = static_cast<const char*>(m);
            size_ = std::size_t(st.st_size);
        }
    }
    if (fd >= 0) ::close(fd);
    if (!map_) copy_ = read_file(path);  // not mappable: read (and errors named) as before
}

FileBytes::~FileBytes() {
    if (map_) ::munmap(const_cast<char*>(map_), size_);
}

std::string_view FileBytes::bytes() const {
    return map_ ? std::string_view(map_, size_) : std::string_view(copy_);
}

void FileBytes::let_go(const char* upto) {
    if (!map_ || upto < map_) return;
    const auto page = std::size_t(::sysconf(_SC_PAGESIZE));
    const std::size_t end = std::min(std::size_t(upto - map_), size_) / page * page;
    if (end > released_) {
        ::madvise(const_cast<char*>(map_) + released_, end - released_, MADV_DONTNEED);
        released_ = end;
    }
}

namespace {

bool finite_row(const double* p) {
    return std::isfinite(p[0]) && std::isfinite(p[1]) && std::isfinite(p[2]);
}

/// `p - origin` in single precision into q; returns the first axis where that is not finite
/// (a coordinate like 1e300, or points spread wider than float's range), or -1.
int in_frame(const double* p, const Vec3d& origin, Vec3f& q) {
    int bad = -1;
    for (int a = 0; a < 3; ++a) {
        q[a] = float(p[a] - origin[a]);
        if (bad < 0 && !std::isfinite(q[a])) bad = a;
    }
    return bad;
}

/// in_frame's point; throws FormatError naming the row when it does not fit.
Vec3f local_point(const double* p, const Vec3d& origin, const std::string& path,
                  const char* row_kind, std::size_t row) {
    Vec3f q;
    const int a = in_frame(p, origin, q);
    if (a >= 0) {
        throw FormatError(where(path, std::string(row_kind) + " " + std::to_string(row) +
                                          ": coordinate " + format_number(p[a]) +
                                          " is out of single-precision range (even relative "
                                          "to the centre of the points)"));
    }
    return q;
}

}  // namespace

namespace {

constexpr std::size_t kRowGrain = 16384;  ///< rows a task of the passes over a cloud's rows

/// The box of finite rows, and the local frame choose_origin picks from it.
struct RowBounds {
    double lo[3] = {HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi[3] = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
    bool any = false;
    std::size_t rows = 0;  ///< finite ones

    void add(const std::array<double, 3>& p) {
        if (!finite_row(p.data())) return;  // rows the reader drops
        any = true;
        ++rows;
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], p[std::size_t(a)]);
            hi[a] = std::max(hi[a], p[std::size_t(a)]);
        }
    }

    void merge(const RowBounds& o) {
        any |= o.any;
        rows += o.rows;
        for (int a = 0; a < 3; ++a) {
            lo[a] = std::min(lo[a], o.lo[a]);
            hi[a] = std::max(hi[a], o.hi[a]);
        }
    }

    double diagonal() const {
        double diag2 = 0.0;
        for (int a = 0; a < 3 && any; ++a) diag2 += (hi[a] - lo[a]) * (hi[a] - lo[a]);
        return std::sqrt(diag2);
    }

    Vec3d origin() const {
        if (!any) return {0.0, 0.0, 0.0};
        double magnitude = 0.0;
        for (int a = 0; a < 3; ++a) {
            magnitude = std::max({magnitude, std::fabs(lo[a]), std::fabs(hi[a])});
        }
        const double diag = diagonal();
        // A float carries 24 bits: at magnitude M its spacing is M * 2^-23. Keep that below
        // extent * 2^-20 (a millionth of the scan), i.e. re-centre once M > 8 * extent.
        if (magnitude <= 8.0 * std::max(diag, 1e-30) || magnitude < 1.0) return {0.0, 0.0, 0.0};
        const double q = std::ldexp(1.0, int(std::ceil(std::log2(std::max(diag, 1e-6)))));
        Vec3d origin;
        for (int a = 0; a < 3; ++a) {
            // 0.5 lo + 0.5 hi, not 0.5 (lo + hi), which overflows near double's maximum; and
            // beyond 2^52 q the centre is a multiple of q already (c / q could overflow).
            const double c = 0.5 * lo[a] + 0.5 * hi[a];
            origin[a] = std::fabs(c) < std::ldexp(q, 52) ? std::round(c / q) * q : c;
        }
        return origin;
    }
};

/// choose_origin over rows row(i) (std::array<double, 3>), in parallel: the box is the same in
/// any order.
template <typename Row>
Vec3d origin_of_rows(std::size_t rows, const Row& row) {
    const RowBounds b = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, rows, kRowGrain), RowBounds{},
        [&](const tbb::blocked_range<std::size_t>& r, RowBounds part) {
            for (std::size_t i = r.begin(); i < r.end(); ++i) part.add(row(i));
            return part;
        },
        [](RowBounds a, const RowBounds& b) {
            a.merge(b);
            return a;
        });
    return b.origin();
}

}  // namespace

Vec3d choose_origin(const double* xyz, std::size_t rows) {
    return origin_of_rows(rows, [&](std::size_t i) {
        return std::array<double, 3>{xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]};
    });
}

Vec3d choose_origin(const RawPoints& raw) {
    return origin_of_rows(raw.rows(), [&](std::size_t i) { return raw.row(i); });
}

namespace {

/// The first `rows` rows of an attribute column (empty when it is: the file has no such
/// attribute), moved out. (The readers fill Vec3f rows directly: a flat float array copied
/// into rows took 1.4 ms of the bunny's read, on one thread, and its memory twice.)
template <typename T>
std::vector<T> take_rows(std::vector<T>&& column, std::size_t rows) {
    if (!column.empty()) column.resize(rows);
    return std::move(column);
}

}  // namespace

namespace {

/// What the rows hold before they are converted: those with a NaN or infinite coordinate, and
/// the first finite one that does not fit in single precision in the frame (local_point).
struct RowScan {
    static constexpr std::size_t kNone = std::numeric_limits<std::size_t>::max();
    std::size_t nonfinite = 0, first_nonfinite = kNone, first_unfit = kNone;

    void merge(const RowScan& o) {
        nonfinite += o.nonfinite;
        first_nonfinite = std::min(first_nonfinite, o.first_nonfinite);
        first_unfit = std::min(first_unfit, o.first_unfit);
    }
};

RowScan scan_rows(const RawPoints& raw, const Vec3d& origin) {
    return tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, raw.rows(), kRowGrain), RowScan{},
        [&](const tbb::blocked_range<std::size_t>& r, RowScan part) {
            for (std::size_t i = r.begin(); i < r.end(); ++i) {
                const std::array<double, 3> p = raw.row(i);
                Vec3f q;
                if (!finite_row(p.data())) {
                    ++part.nonfinite;
                    part.first_nonfinite = std::min(part.first_nonfinite, i);
                } else if (in_frame(p.data(), origin, q) >= 0) {
                    part.first_unfit = std::min(part.first_unfit, i);
                }
            }
            return part;
        },
        [](RowScan x, const RowScan& y) {
            x.merge(y);
            return x;
        });
}

/// Row i's coordinates: from `positions` when they hold the float rows (in place), else from
/// the raw rows.
std::array<double, 3> row_at(const RawPoints& raw, const std::vector<Vec3f>& positions,
                             bool in_place, std::size_t i) {
    if (!in_place) return raw.row(i);
    return {double(positions[i][0]), double(positions[i][1]), double(positions[i][2])};
}

/// The rows' positions in the frame, when every row is finite: row by row, in parallel (in place
/// when `positions` holds the float rows already).
void convert_rows(const RawPoints& raw, const Vec3d& origin, std::vector<Vec3f>& positions,
                  bool in_place) {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, positions.size(), kRowGrain),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t i = r.begin(); i < r.end(); ++i) {
                              in_frame(row_at(raw, positions, in_place, i).data(), origin,
                                       positions[i]);
                          }
                      });
}

/// The finite rows' positions in the frame, the others dropped and every attribute compacted
/// with them, in place (one pass, in row order: rarely taken).
std::size_t compact_rows(RawPoints& raw, const Vec3d& origin, std::vector<Vec3f>& positions,
                         bool in_place) {
    std::size_t kept = 0;
    for (std::size_t i = 0; i < positions.size(); ++i) {
        const std::array<double, 3> p = row_at(raw, positions, in_place, i);
        if (!finite_row(p.data())) continue;
        in_frame(p.data(), origin, positions[kept]);
        if (kept != i) {
            auto keep = [&](auto& v) {
                if (!v.empty()) v[kept] = v[i];
            };
            keep(raw.normals);
            keep(raw.colors);
            keep(raw.scales);
            keep(raw.confidences);
            keep(raw.scans);
            keep(raw.las.classification);
            keep(raw.las.intensity);
            keep(raw.las.return_number);
            keep(raw.las.number_of_returns);
        }
        ++kept;
    }
    return kept;
}

/// Unit normals (a unit one stays bit-exact), zero where a normal is zero or not finite; returns
/// how many are. In parallel.
std::size_t unit_normals(std::vector<Vec3f>& normals) {
    return tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, normals.size(), kRowGrain), std::size_t(0),
        [&](const tbb::blocked_range<std::size_t>& r, std::size_t invalid) {
            for (std::size_t i = r.begin(); i < r.end(); ++i) {
                Vec3f& n = normals[i];
                const double len =
                    std::sqrt(double(n[0]) * n[0] + double(n[1]) * n[1] + double(n[2]) * n[2]);
                if (!std::isfinite(len) || len < 1e-12) {
                    n = {0.0f, 0.0f, 0.0f};
                    ++invalid;
                } else if (std::fabs(len - 1.0) > 1e-6) {
                    for (float& c : n) c = float(c / len);
                }
            }
            return invalid;
        },
        std::plus<std::size_t>());
}

/// The errors a pass over the rows in order meets first: a row that does not fit in single
/// precision; with NonFinitePolicy::error, a NaN or infinite row before it.
void throw_row_errors(const RowScan& scan, const RawPoints& raw, const Vec3d& origin,
                      const std::string& path, const ReadOptions& options, std::size_t first) {
    if (options.non_finite == NonFinitePolicy::error && scan.first_nonfinite < scan.first_unfit) {
        throw FormatError(where(path, "row " + std::to_string(first + scan.first_nonfinite) +
                                          ": NaN or infinite coordinate"));
    }
    if (scan.first_unfit != RowScan::kNone) {
        const std::array<double, 3> p = raw.row(scan.first_unfit);
        local_point(p.data(), origin, path, "row", first + scan.first_unfit);  // throws
        throw Error("read: internal error: a row neither fits nor fails");
    }
}

/// finalize_points for rows [first, first + raw.rows()) of a file, in the frame `origin`: the
/// cloud and counts into `result` (whose counts add up over chunks), nothing logged.
void finalize_rows(RawPoints&& raw, const std::string& path, const ReadOptions& options,
                   const Vec3d& origin, std::size_t first, ReadResult& result) {
    const std::size_t rows = raw.rows();
    result.rows += rows;
    const RowScan scan = scan_rows(raw, origin);
    throw_row_errors(scan, raw, origin, path, options, first);
    if (scan.nonfinite > 0) {
        if (result.dropped_nonfinite == 0) result.first_dropped = first + scan.first_nonfinite;
        result.dropped_nonfinite += scan.nonfinite;
    }
    PointCloud& cloud = result.cloud;
    cloud.origin = origin;
    // Float rows become the positions in place (each row is read before it is overwritten).
    const bool in_place = !raw.xyz_float.empty();
    std::vector<Vec3f> positions;
    if (in_place) {
        positions = std::move(raw.xyz_float);
    } else {
        positions.resize(rows);
    }
    std::size_t kept = rows;
    if (scan.nonfinite == 0) {
        convert_rows(raw, origin, positions, in_place);
    } else {
        kept = compact_rows(raw, origin, positions, in_place);
    }
    detail::release(raw.xyz);  // (xyz_float, if any, became the positions)
    positions.resize(kept);
    cloud.positions = std::move(positions);

    std::vector<Vec3f> normals = take_rows(std::move(raw.normals), kept);
    cloud.colors = take_rows(std::move(raw.colors), kept);
    cloud.confidences = take_rows(std::move(raw.confidences), kept);
    result.scans = take_rows(std::move(raw.scans), kept);
    LasAttributes& las = result.las;
    las.classification = take_rows(std::move(raw.las.classification), kept);
    las.intensity = take_rows(std::move(raw.las.intensity), kept);
    las.return_number = take_rows(std::move(raw.las.return_number), kept);
    las.number_of_returns = take_rows(std::move(raw.las.number_of_returns), kept);
    result.invalid_normals += unit_normals(normals);
    cloud.normals = std::move(normals);
    std::vector<float> scales = take_rows(std::move(raw.scales), kept);
    for (float& s : scales) {
        if (!std::isfinite(s) || s < 0.0f) s = 0.0f;  // 0 = unknown; the normals stage fills it
    }
    cloud.scales = std::move(scales);
}

}  // namespace

void report_read(const std::string& path, const ReadResult& result) {
    if (result.rows == 0) throw FormatError(where(path, "contains no points"));
    if (result.dropped_nonfinite > 0) {
        if (result.dropped_nonfinite == result.rows) {
            throw FormatError(where(path, "all " + std::to_string(result.rows) +
                                              " rows have NaN or infinite coordinates"));
        }
        log_warning(where(path, "dropped " + std::to_string(result.dropped_nonfinite) + " of " +
                                    std::to_string(result.rows) +
                                    " rows with NaN or infinite coordinates (first: row " +
                                    std::to_string(result.first_dropped) + ")"));
    }
    if (result.invalid_normals > 0) {
        log_warning(where(path, std::to_string(result.invalid_normals) +
                                    " normals are zero or NaN; they will be re-estimated"));
    }
}

ReadResult finalize_points(RawPoints&& raw, const std::string& path, const std::string& format,
                           const ReadOptions& options) {
    ReadResult result;
    result.format = format;
    if (raw.rows() == 0) throw FormatError(where(path, "contains no points"));
    const Vec3d origin = options.local_frame ? choose_origin(raw) : Vec3d{0, 0, 0};
    finalize_rows(std::move(raw), path, options, origin, 0, result);
    report_read(path, result);
    result.bytes = result.cloud.memory_bytes();
    return result;
}

Mesh finalize_mesh(RawPoints&& raw, const std::string& path) {
    Mesh mesh;
    const std::size_t rows = raw.rows();
    for (std::size_t i = 0; i < rows; ++i) {
        if (!finite_row(raw.row(i).data())) {
            throw FormatError(where(path, "vertex " + std::to_string(i) +
                                              ": NaN or infinite coordinate"));
        }
    }
    mesh.origin = choose_origin(raw);
    std::vector<Vec3f>& vertices = mesh.vertices.edit();
    vertices.resize(rows);
    for (std::size_t i = 0; i < rows; ++i) {
        vertices[i] = local_point(raw.row(i).data(), mesh.origin, path, "vertex", i);
    }
    mesh.normals = take_rows(std::move(raw.normals), rows);
    mesh.colors = take_rows(std::move(raw.colors), rows);
    mesh.faces = std::move(raw.faces);
    return mesh;
}


}  // namespace detail

// ---------------------------------------------------------------------------------------------
// Dispatch

namespace {

enum class Format { ply, xyz, obj, las, pcd };

Format detect_format(const std::string& path, std::string_view content) {
    const std::string ext = file_extension(path);
    if (ext == "ply") return Format::ply;
    if (ext == "xyz" || ext == "pts" || ext == "txt" || ext == "asc" || ext == "xyzn") {
        return Format::xyz;
    }
    if (ext == "obj") return Format::obj;
    if (ext == "las" || ext == "laz") return Format::las;
    if (ext == "pcd") return Format::pcd;
    if (content.compare(0, 3, "ply") == 0) return Format::ply;
    if (content.compare(0, 4, "LASF") == 0) return Format::las;
    throw FormatError(detail::where(
        path, "unknown file type '." + ext + "' (supported: .ply, .xyz/.pts/.txt, .obj, .las, .pcd)"));
}

/// Parses a whole file's bytes into raw rows; `want_faces` also reads faces (meshes).
detail::RawPoints read_raw(std::string_view content, const std::string& path, bool want_faces,
                           std::string& format, const std::vector<int>& classes = {},
                           const detail::Consumed& consumed = {}) {
    if (content.empty()) throw FormatError(detail::where(path, "file is empty"));
    const Format f = detect_format(path, content);
    if (!classes.empty() && f != Format::las) {
        throw InvalidArgument(detail::where(path, "point classes are chosen only in LAS files"));
    }
    switch (f) {
        case Format::las:
            if (want_faces) throw FormatError(detail::where(path, "a LAS file holds no faces"));
            format = "las";
            return detail::read_las_raw(path, content, classes, consumed);
        case Format::pcd:
            if (want_faces) throw FormatError(detail::where(path, "a PCD file holds no faces"));
            format = "pcd";
            return detail::read_pcd(path, content).raw;
        case Format::ply:
            return detail::read_ply_raw(path, content, want_faces, format, consumed);
        case Format::xyz:
            if (want_faces) {
                throw FormatError(detail::where(path, "a text point file holds no faces"));
            }
            format = "xyz";
            return detail::read_xyz_raw(path, content, consumed);
        case Format::obj:
            format = "obj";
            return detail::read_obj_raw(path, content, want_faces);
    }
    return {};
}

/// A point file's rows a chunk at a time (a streamed read): PLY, LAS or text.
void read_rows(const std::string& path, std::string_view bytes, Format f,
               const std::vector<int>& classes, std::string& format,
               const detail::Consumed& consumed, const detail::RowSink& sink) {
    switch (f) {
        case Format::las:
            format = "las";
            detail::read_las_raw(path, bytes, classes, consumed, sink);
            return;
        case Format::xyz:
            format = "xyz";
            detail::read_xyz_raw(path, bytes, consumed, sink);
            return;
        default:
            detail::read_ply_raw(path, bytes, false, format, consumed, sink);
    }
}

}  // namespace

ReadResult read_points_from_memory(std::string_view bytes, const std::string& name,
                                   const ReadOptions& options) {
    std::string format;
    detail::RawPoints raw = read_raw(bytes, name, false, format, options.classes);
    return detail::finalize_points(std::move(raw), name, format, options);
}

Mesh read_mesh_from_memory(std::string_view bytes, const std::string& name) {
    std::string format;
    detail::RawPoints raw = read_raw(bytes, name, true, format);
    if (raw.faces.empty()) throw FormatError(detail::where(name, "has no faces"));
    return detail::finalize_mesh(std::move(raw), name);
}

ReadResult read_points(const std::string& path, const ReadOptions& options) {
    std::string format;
    detail::RawPoints raw;
    {
        detail::FileBytes file(path);
        raw = read_raw(file.bytes(), path, false, format, options.classes,
                       [&](const char* upto) { file.let_go(upto); });
    }  // the file's bytes are let go before the cloud is made from the rows
    return detail::finalize_points(std::move(raw), path, format, options);
}


bool detail::stream_points(const std::string& path, const ReadOptions& options,
                           const PointsSink& sink, ReadResult& totals, int passes,
                           StreamFrame* frame, bool need_normals) {
    // First pass: the frame, from the box of all finite rows.
    RowBounds box;
    std::string format;
    Format f;
    {
        detail::FileBytes file(path);
        const std::string_view bytes = file.bytes();
        if (bytes.empty()) throw FormatError(detail::where(path, "file is empty"));
        f = detect_format(path, bytes);
        if (f != Format::ply && f != Format::las && f != Format::xyz) return false;
        if (need_normals && (f != Format::ply || !detail::ply_has_normals(path, bytes))) {
            return false;
        }
        if (!options.classes.empty() && f != Format::las) {
            throw InvalidArgument(
                detail::where(path, "point classes are chosen only in LAS files"));
        }
        read_rows(path, bytes, f, options.classes, format,
                  [&](const char* upto) { file.let_go(upto); },
                  [&](detail::RawPoints& raw, std::size_t) {
            for (std::size_t i = 0; i < raw.rows(); ++i) box.add(raw.row(i));
        });
    }
    const Vec3d origin = options.local_frame ? box.origin() : Vec3d{0, 0, 0};
    if (frame) {
        frame->rows = box.rows;
        frame->diagonal = box.diagonal();
    }
    // Then the passes over the chunks, finalized in that frame.
    totals = ReadResult{};
    totals.format = format;
    totals.cloud.origin = origin;
    ReadResult chunk;
    for (int pass = 0; pass < passes; ++pass) {
        detail::FileBytes again(path);  // (the last pass let its pages go)
        read_rows(path, again.bytes(), f, options.classes, format,
                  [&](const char* upto) { again.let_go(upto); },
                  [&](detail::RawPoints& raw, std::size_t first) {
            chunk = ReadResult{};
            finalize_rows(std::move(raw), path, options, origin, first, chunk);
            if (pass == 0) {
                totals.rows += chunk.rows;
                if (chunk.dropped_nonfinite > 0 && totals.dropped_nonfinite == 0) {
                    totals.first_dropped = chunk.first_dropped;
                }
                totals.dropped_nonfinite += chunk.dropped_nonfinite;
                totals.invalid_normals += chunk.invalid_normals;
            }
            sink(chunk, first, pass);
        });
        if (pass == 0) detail::report_read(path, totals);
    }
    return true;
}

Mesh read_mesh(const std::string& path) {
    return read_mesh_from_memory(detail::read_file(path), path);
}

// ---------------------------------------------------------------------------------------------
// Writers

namespace detail {

namespace {

/// The vertex lines of an OBJ: positions (with colours when the mesh has them), then normals.
void put_obj_vertices(ByteWriter& out, const Mesh& mesh) {
    const bool far = mesh.origin != Vec3d{0, 0, 0};
    const bool colors = mesh.colors.size() == mesh.vertices.size() && !mesh.colors.empty();
    std::string line;
    for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
        line = "v";
        for (int a = 0; a < 3; ++a) {
            line += ' ';
            line += far ? format_number(mesh.origin[a] + double(mesh.vertices[i][a]))
                        : format_number(mesh.vertices[i][a]);
        }
        if (colors) {
            for (int a = 0; a < 3; ++a) line += ' ' + format_number(mesh.colors[i][a]);
        }
        line += '\n';
        out.put(line);
    }
    if (mesh.normals.size() == mesh.vertices.size()) {
        for (const Vec3f& n : mesh.normals) {
            out.put("vn " + format_number(n[0]) + ' ' + format_number(n[1]) + ' ' +
                    format_number(n[2]) + '\n');
        }
    }
}

/// `vt` lines for the textured corners; returns each corner's index (1-based; 0: none). A vertex
/// with the same coordinates in several faces gets one line.
std::vector<std::array<std::size_t, 3>> put_obj_uvs(ByteWriter& out, const Mesh& mesh,
                                                    const ObjMaterials& m) {
    std::vector<std::array<std::size_t, 3>> index(mesh.faces.size(), {0, 0, 0});
    std::map<std::array<std::uint32_t, 3>, std::size_t> line;  // (vertex, u bits, v bits)
    for (std::size_t f = 0; f < mesh.faces.size(); ++f) {
        for (std::size_t c = 0; c < 3; ++c) {
            const std::array<float, 2>& uv = (*m.uv)[f][c];
            if (std::isnan(uv[0])) continue;
            std::array<std::uint32_t, 3> key{std::uint32_t(mesh.faces[f][c]), 0, 0};
            std::memcpy(&key[1], &uv[0], 4);
            std::memcpy(&key[2], &uv[1], 4);
            const auto [it, fresh] = line.emplace(key, line.size() + 1);
            if (fresh) out.put("vt " + format_number(uv[0]) + ' ' + format_number(uv[1]) + '\n');
            index[f][c] = it->second;
        }
    }
    return index;
}

}  // namespace

void write_obj_file(const std::string& path, const Mesh& mesh, const WriteOptions& options,
                    const ObjMaterials* materials) {
    AtomicFile file(path);
    ByteWriter out(file.stream());
    out.put("# vdbrecon mesh\n");
    for (const std::string& c : options.comments) out.put("# " + c + "\n");
    if (materials) out.put("mtllib " + materials->mtl_name + "\n");
    put_obj_vertices(out, mesh);
    const bool normals = mesh.normals.size() == mesh.vertices.size() && !mesh.normals.empty();
    std::vector<std::array<std::size_t, 3>> uv;
    if (materials) uv = put_obj_uvs(out, mesh, *materials);
    // Faces without texture coordinates first (the plain material), then the textured ones.
    for (int pass = 0; pass < (materials ? 2 : 1); ++pass) {
        bool first = true;
        for (std::size_t f = 0; f < mesh.faces.size(); ++f) {
            const bool textured = materials && uv[f][0] != 0;
            if (textured != (pass == 1)) continue;
            if (first && materials) {
                out.put(pass == 0 ? "usemtl vdbrecon_surface\n" : "usemtl vdbrecon_texture\n");
            }
            first = false;
            std::string line = "f";
            for (int c = 0; c < 3; ++c) {
                const std::string idx = std::to_string(mesh.faces[f][std::size_t(c)] + 1);
                line += ' ' + idx;
                if (textured) line += '/' + std::to_string(uv[f][std::size_t(c)]);
                if (normals) line += (textured ? "/" : "//") + idx;
            }
            line += '\n';
            out.put(line);
        }
    }
    out.flush();
    file.commit();
}

}  // namespace detail

namespace {

void write_xyz(const std::string& path, const PointCloud& cloud) {
    detail::AtomicFile file(path);
    detail::ByteWriter out(file.stream());
    const bool far = cloud.origin != Vec3d{0, 0, 0};
    std::string line;
    for (std::size_t i = 0; i < cloud.size(); ++i) {
        line.clear();
        for (int a = 0; a < 3; ++a) {
            if (a) line += ' ';
            line += far ? detail::format_number(cloud.origin[a] + double(cloud.positions[i][a]))
                        : detail::format_number(cloud.positions[i][a]);
        }
        if (cloud.has_normals()) {
            for (int a = 0; a < 3; ++a) line += ' ' + detail::format_number(cloud.normals[i][a]);
        }
        line += '\n';
        out.put(line);
    }
    out.flush();
    file.commit();
}

}  // namespace

void write_mesh(const std::string& path, const Mesh& mesh, const WriteOptions& options) {
    const std::string ext = file_extension(path);
    if (ext == "ply") {
        const bool n = !mesh.normals.empty() && mesh.normals.size() == mesh.vertices.size();
        const bool c = !mesh.colors.empty() && mesh.colors.size() == mesh.vertices.size();
        if (!mesh.regions.empty() && mesh.regions.size() != mesh.faces.size()) {
            throw InvalidArgument("write_mesh: " + std::to_string(mesh.regions.size()) +
                                  " face regions for " + std::to_string(mesh.faces.size()) +
                                  " faces");
        }
        detail::write_ply(path, mesh.vertices, mesh.origin, n ? mesh.normals : Span<Vec3f>(),
                          c ? mesh.colors : Span<Vec3f>(), {}, {}, &mesh.faces, options,
                          mesh.regions);
    } else if (ext == "obj") {
        detail::write_obj_file(path, mesh, options);
    } else {
        throw InvalidArgument("output '" + path +
                              "': unknown mesh extension (use .ply or .obj)");
    }
}

void write_points(const std::string& path, const PointCloud& cloud, const WriteOptions& options) {
    const std::string ext = file_extension(path);
    if (ext == "ply") {
        detail::write_ply(path, cloud.positions, cloud.origin, cloud.normals, cloud.colors,
                          cloud.scales, cloud.confidences, nullptr, options);
    } else if (ext == "xyz") {
        write_xyz(path, cloud);
    } else {
        throw InvalidArgument("output '" + path +
                              "': unknown point-cloud extension (use .ply or .xyz)");
    }
}

}  // namespace vdbrecon
