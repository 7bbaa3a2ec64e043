// Job directories kept for resuming tiled runs (see detail/job_dir.h).
#include "detail/job_dir.h"

#include <dirent.h>
#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iomanip>
#include <sstream>
#include <vector>

#include "detail/io_common.h"
#include "vdbrecon/choices.h"
#include "vdbrecon/error.h"

namespace vdbrecon::detail {

namespace {

// ---- the options that shape the plan and the pieces -------------------------------------------

/// `name value` lines; doubles with every digit, so any change shows.
class OptionLines {
  public:
    template <typename T>
    OptionLines& add(const char* name, const T& v) {
        s_ << name << ' ' << v << '\n';
        return *this;
    }
    OptionLines& add(const char* name, double v) {
        s_ << name << ' ' << std::setprecision(17) << v << '\n';
        return *this;
    }
    OptionLines& add(const char* name, bool v) { return add(name, int(v)); }
    OptionLines& add(const char* name, const std::optional<Vec3d>& v) {
        if (!v) return add(name, "none");
        s_ << name << std::setprecision(17) << ' ' << (*v)[0] << ' ' << (*v)[1] << ' ' << (*v)[2] << '\n';
        return *this;
    }
    std::string str() const { return s_.str(); }

  private:
    std::ostringstream s_;
};

}  // namespace

std::string job_options_text(const PipelineOptions& o) {
    // Every option of the stages up to the pieces: read, outliers, normals, splat, close, mesh,
    // and the tiling. Left out: what only sets time or memory of an exact computation (threads,
    // the outlier stage's parking, the splat's slab pairs) and the stages after the stitch.
    OptionLines l;
    std::string classes;
    for (int c : o.read.classes) classes += std::to_string(c) + ",";
    l.add("read.non_finite", int(o.read.non_finite))
        .add("read.local_frame", o.read.local_frame)
        .add("read.classes", classes.empty() ? std::string("all") : classes);
    const OutlierOptions& u = o.outliers;
    l.add("outliers.enabled", u.enabled).add("outliers.k", u.k)
        .add("outliers.statistical_ratio", u.statistical_ratio)
        .add("outliers.planarity_ratio", u.planarity_ratio)
        .add("outliers.planarity_spacing", u.planarity_spacing)
        .add("outliers.knn", int(u.knn.backend)).add("outliers.knn_eps", u.knn.eps);
    const NormalOptions& n = o.normals;
    l.add("normals.mode", int(n.mode)).add("normals.k", n.k).add("normals.viewpoint", n.viewpoint)
        .add("normals.up", n.up).add("normals.orient", int(n.orient)).add("normals.scale", int(n.scale))
        .add("normals.knn", int(n.knn.backend)).add("normals.knn_eps", n.knn.eps);
    const SplatOptions& s = o.splat;
    l.add("splat.voxel_size", s.voxel_size)
        .add("splat.scale_factor", s.scale_factor)
        .add("splat.sigma_voxels", s.sigma_voxels)
        .add("splat.min_sigma_voxels", s.min_sigma_voxels)
        .add("splat.max_sigma_voxels", s.max_sigma_voxels)
        .add("splat.support", s.support)
        .add("splat.min_weight", s.min_weight)
        .add("splat.crease_angle", s.crease_angle)
        .add("splat.aggregate", s.aggregate)
        .add("splat.aggregate_max_cell", s.aggregate_max_cell)
        .add("splat.max_memory", s.max_memory)
        .add("auto_voxel_factor", o.auto_voxel_factor)
        .add("auto_voxel_max_cells", o.auto_voxel_max_cells);
    l.add("close.hole_radius", o.close.hole_radius).add("close.solid_radius", o.close.solid_radius);
    const MeshOptions& m = o.mesh;
    // By name: the enum's numbers changed when the dual mesher came first (a job made before
    // then recorded vdb as 0, which is dual's number now).
    l.add("mesh.method", choice_name(mesher_choices(), m.method))
        .add("mesh.isovalue", m.isovalue)
        .add("mesh.adaptivity", m.adaptivity)
        .add("mesh.min_surface_weight", m.min_surface_weight)
        .add("mesh.max_gap", m.max_gap)
        .add("mesh.max_gap_spacings", m.max_gap_spacings)
        .add("mesh.sample_spacing", m.sample_spacing)
        .add("mesh.dc_truncation", m.dc_truncation)
        .add("mesh.dc_bias", m.dc_bias)
        .add("mesh.normals", m.normals);
    l.add("tile", o.tile).add("stream", int(o.stream));
    return l.str();
}

namespace {

// ---- the input's fingerprint -----------------------------------------------------------------

/// A 64-bit hash of the file's bytes (not cryptographic: it tells a changed file from the one
/// the job was made of). Words of 8 bytes mixed by multiply and xor-shift.
std::uint64_t content_hash(const std::string& path) {
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) throw IoError(path + ": cannot open: " + std::strerror(errno));
    std::vector<unsigned char> buf(std::size_t(1) << 20);
    std::uint64_t h = 0x9e3779b97f4a7c15ull, total = 0;
    for (;;) {
        const std::size_t got = std::fread(buf.data(), 1, buf.size(), f);
        for (std::size_t i = 0; i < got; i += 8) {
            std::uint64_t w = 0;
            std::memcpy(&w, buf.data() + i, std::min<std::size_t>(8, got - i));
            h = (h ^ w) * 0xff51afd7ed558ccdull;
            h ^= h >> 29;
        }
        total += got;
        if (got < buf.size()) break;
    }
    const bool failed = std::ferror(f);
    std::fclose(f);
    if (failed) throw IoError(path + ": read failed");
    h = (h ^ total) * 0xc4ceb9fe1a85ec53ull;
    return h ^ (h >> 32);
}

struct Fingerprint {
    std::string path;
    std::uint64_t size = 0, hash = 0;
    long long mtime_ns = 0;
};

Fingerprint fingerprint(const std::string& input) {
    struct stat st {};
    if (::stat(input.c_str(), &st) != 0) throw IoError(input + ": cannot open: " + std::strerror(errno));
    Fingerprint f;
    char* abs = ::realpath(input.c_str(), nullptr);
    f.path = abs ? abs : input;
    std::free(abs);
    f.size = std::uint64_t(st.st_size);
    f.mtime_ns = (long long)st.st_mtim.tv_sec * 1000000000LL + st.st_mtim.tv_nsec;
    f.hash = content_hash(input);
    return f;
}

std::string manifest_text(const Fingerprint& f, const PipelineOptions& options) {
    std::ostringstream s;
    s << "vdbrecon tile job 1\n"
      << "input.path " << f.path << '\n'
      << "input.size " << f.size << '\n'
      << "input.mtime_ns " << f.mtime_ns << '\n'
      << "input.hash " << std::hex << f.hash << std::dec << '\n'
      << job_options_text(options);
    return s.str();
}

/// The value of `key` in a manifest's lines ("" when absent).
std::string value_of(const std::string& text, const std::string& key) {
    std::istringstream in(text);
    std::string line;
    while (std::getline(in, line)) {
        if (line.compare(0, key.size() + 1, key + " ") == 0) return line.substr(key.size() + 1);
    }
    return "";
}

/// Why the manifest `had` is not `want`'s job ("" when it is).
std::string difference(const std::string& had, const std::string& want) {
    if (value_of(had, "input.size") != value_of(want, "input.size") ||
        value_of(had, "input.hash") != value_of(want, "input.hash")) {
        return "its input " + value_of(had, "input.path") + " has changed (size or content)";
    }
    std::istringstream a(had), b(want);
    std::string la, lb;
    while (true) {
        const bool ga = bool(std::getline(a, la)), gb = bool(std::getline(b, lb));
        if (!ga && !gb) return "";
        if (la.compare(0, 6, "input.") == 0 && lb.compare(0, 6, "input.") == 0) continue;
        if (la != lb) {
            const std::string key = (gb ? lb : la).substr(0, (gb ? lb : la).find(' '));
            return "it was made with " + key + " " + value_of(had, key) + ", this run has " +
                   value_of(want, key);
        }
    }
}

void write_text(const std::string& path, const std::string& text) {
    AtomicFile f(path);
    if (std::fwrite(text.data(), 1, text.size(), f.stream()) != text.size()) {
        throw IoError(path + ": write failed");
    }
    f.commit();
}

/// The names in `dir` (without . and ..).
std::vector<std::string> entries(const std::string& dir) {
    std::vector<std::string> names;
    DIR* d = ::opendir(dir.c_str());
    if (!d) throw IoError(dir + ": cannot open the job directory: " + std::strerror(errno));
    while (const dirent* e = ::readdir(d)) {
        const std::string n = e->d_name;
        if (n != "." && n != "..") names.push_back(n);
    }
    ::closedir(d);
    return names;
}

}  // namespace

JobDir::JobDir(const std::string& dir, const std::string& input, const PipelineOptions& options)
    : dir_(dir) {
    if (::mkdir(dir.c_str(), 0777) != 0 && errno != EEXIST) {
        throw IoError(dir + ": cannot make the job directory: " + std::strerror(errno));
    }
    lock_fd_ = ::open((dir + "/lock").c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0666);
    if (lock_fd_ < 0) throw IoError(dir + ": cannot open the job directory's lock: " + std::strerror(errno));
    if (::flock(lock_fd_, LOCK_EX | LOCK_NB) != 0) {
        ::close(lock_fd_);
        lock_fd_ = -1;
        throw InvalidArgument(dir + ": the job directory is in use by another run");
    }
    try {
        check_manifest(input, options);
    } catch (...) {
        ::close(lock_fd_);  // no destructor for an object whose constructor threw
        throw;
    }
}

void JobDir::check_manifest(const std::string& input, const PipelineOptions& options) const {
    const std::string& dir = dir_;
    const std::string manifest = dir + "/manifest.txt";
    const std::string want = manifest_text(fingerprint(input), options);
    std::vector<std::string> names = entries(dir);
    // A run killed while writing leaves its temporary files (".<name>.tmp.<pid>.<n>"): gone.
    for (const std::string& n : names) {
        if (n[0] == '.' && n.find(".tmp.") != std::string::npos) std::remove((dir + "/" + n).c_str());
    }
    bool has_manifest = false, others = false;
    for (const std::string& n : names) {
        has_manifest = has_manifest || n == "manifest.txt";
        others = others || (n != "lock" && n != "manifest.txt" && n.find(".tmp.") == std::string::npos);
    }
    if (!has_manifest) {
        if (others) {
            throw InvalidArgument(dir + ": not a vdbrecon job directory (it holds other files and "
                                        "no manifest.txt). Hint: an empty or new directory");
        }
        write_text(manifest, want);
        return;
    }
    const std::string why = difference(read_file(manifest), want);
    if (!why.empty()) {
        throw InvalidArgument(dir + ": the job directory is another run's: " + why +
                              ". Hint: remove it, or give another --job-dir");
    }
}

JobDir::~JobDir() {
    if (lock_fd_ >= 0) ::close(lock_fd_);  // releases the lock
}

std::optional<TileJob> JobDir::prepared() const {
    const std::string path = dir_ + "/job.txt";
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0) return std::nullopt;
    const std::string text = read_file(path);
    TileJob job;
    job.dir = dir_;
    try {
        job.tiles = std::stoull(value_of(text, "tiles"));
        job.tile = std::stoi(value_of(text, "tile"));
        job.voxel_size = std::stod(value_of(text, "voxel"));
        job.read.rows = std::stoull(value_of(text, "rows"));
    } catch (const std::exception&) {
        throw FormatError(path + ": not a job summary. Hint: remove the job directory");
    }
    job.read.format = value_of(text, "format");
    job.result.voxel_size = job.voxel_size;
    return job;
}

void JobDir::save_prepared(const TileJob& job) const {
    std::ostringstream s;
    s << "tiles " << job.tiles << "\ntile " << job.tile << "\nvoxel " << std::setprecision(17)
      << job.voxel_size << "\nrows " << job.read.rows << "\nformat " << job.read.format << '\n';
    write_text(dir_ + "/job.txt", s.str());
}

std::string piece_path(const std::string& dir, std::size_t i) {
    return dir + "/piece-" + std::to_string(i) + ".bin";
}

void crash_point(const char* what, std::size_t i) {
    const char* at = std::getenv("VDBRECON_CRASH_AT");
    if (!at) return;
    const std::string want = std::string(what) + ":" + std::to_string(i);
    if (want == at) ::raise(SIGKILL);
}

}  // namespace vdbrecon::detail
