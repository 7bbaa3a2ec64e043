// vdbrecon command line.
//
//   vdbrecon INPUT [options]            reconstruct a mesh (+ .vdb volumes) from a point cloud
//   vdbrecon eval RECON REF [options]   compare a mesh with a reference, print JSON
//
// Exit codes: 0 ok, 2 usage or invalid argument, 3 I/O or file format, 4 anything else.
#include <malloc.h>
#include <sys/resource.h>
#include <unistd.h>

#include <cctype>
#include <charconv>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "vdbrecon/choices.h"
#include "vdbrecon/error.h"
#include "vdbrecon/eval.h"
#include "vdbrecon/io.h"
#include "vdbrecon/log.h"
#include "vdbrecon/pipeline.h"
#include "vdbrecon/scene.h"

namespace {

using namespace vdbrecon;

constexpr int kExitOk = 0, kExitUsage = 2, kExitIo = 3, kExitOther = 4;

struct UsageError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

std::string fmt(double v) {
    std::ostringstream s;
    s << v;
    return s.str();
}

template <typename E>
E parse_choice(const std::string& opt, const std::string& value, const Choices<E>& choices) {
    if (const E* e = find_choice(choices, value)) return *e;
    throw UsageError(opt + ": '" + value + "' is not one of " + choice_list(choices, ", "));
}

/// "8G", "500M", "1.5T", "2048K" or a plain byte count -> bytes.
std::size_t parse_bytes(const std::string& opt, const std::string& s) {
    std::string digits = s;
    double unit = 1.0;
    if (!digits.empty()) {
        switch (std::toupper(static_cast<unsigned char>(digits.back()))) {
            case 'K': unit = 1024.0; break;
            case 'M': unit = 1024.0 * 1024.0; break;
            case 'G': unit = 1024.0 * 1024.0 * 1024.0; break;
            case 'T': unit = 1024.0 * 1024.0 * 1024.0 * 1024.0; break;
            default: break;
        }
        if (unit > 1.0) digits.pop_back();
    }
    double v = 0.0;
    const char* b = digits.c_str();
    const auto r = std::from_chars(b, b + digits.size(), v);
    if (digits.empty() || r.ec != std::errc() || r.ptr != b + digits.size() ||
        !std::isfinite(v) || !(v * unit >= 1.0) || v * unit > 1e18) {
        throw UsageError(opt + ": '" + s + "' is not a memory size (e.g. 8G, 500M)");
    }
    return std::size_t(v * unit);
}

std::string fmt_bytes(std::size_t bytes) {
    std::ostringstream s;
    s.precision(3);
    s << double(bytes) / (1024.0 * 1024.0 * 1024.0) << "G";
    return s.str();
}

/// Bytes in MB of 2^20 bytes, like the peak memory lines (getrusage's KiB / 1024), one decimal.
std::string fmt_megabytes(std::size_t bytes) {
    std::ostringstream s;
    s << std::fixed;
    s.precision(1);
    s << double(bytes) / (1024.0 * 1024.0) << " MB";
    return s.str();
}

/// The orientation rule of estimated normals, for the log: "MST in 3 component(s) (1 open
/// sheet turned up, 2 closed objects out)".
std::string orientation_text(const NormalResult& n) {
    std::ostringstream s;
    if (n.orientation == "viewpoint") return "facing the viewpoint";
    if (n.orientation == "up") return "facing the up direction";
    if (n.orientation == "sensor at the origin") {
        return "facing the origin (seen as from a camera there, one surface along each ray: a "
               "depth camera's frame; --viewpoint or --orient mst to override)";
    }
    if (n.orientation == "height field") {
        s << "facing up (a height field: most normals near vertical, one surface over most "
             "places; --orient mst to override)";
    } else {
        s << "MST in " << n.components << " component(s)";
    }
    std::vector<std::string> how;
    if (n.components_up) how.push_back(std::to_string(n.components_up) + " open sheet(s) up");
    if (n.components_flux) {
        how.push_back(std::to_string(n.components_flux) + " closed object(s) outward");
    }
    if (n.components_seed) how.push_back(std::to_string(n.components_seed) + " by their seed");
    for (std::size_t i = 0; i < how.size(); ++i) s << (i ? ", " : ": ") << how[i];
    return s.str();
}

/// The usage lines and the input formats.
void help_usage() {
    std::cout
        << "vdbrecon " << version() << " - surface reconstruction from point clouds on OpenVDB\n"
        << "\n"
        << "Usage: vdbrecon INPUT [options]\n"
        << "  or:  vdbrecon fuse SCENE [fuse options] [reconstruction options]\n"
        << "  or:  vdbrecon eval RECON REF [eval options]\n"
        << "\n"
        << "INPUT: .ply (ascii/binary), .xyz/.pts/.txt (x y z [nx ny nz]), .obj (v/vn),\n"
        << "       .las (LAS 1.0-1.4, point formats 0-10; LAZ: decompress it first)\n";
}

/// The reconstruction options of the stage group "input", with their defaults.
void help_input() {
    std::cout << "\ninput options:\n"
        << "  --classes C,C,...      LAS input: keep the points of these classes (e.g. 2,6:\n"
        << "                         ground, buildings) [all]\n";
}

/// The reconstruction options of the stage group "points and normals", with their defaults.
void help_points() {
    const PipelineOptions d;
    std::cout << "\npoints and normals options:\n"
        << "  --outliers, --no-outliers\n"
        << "                         remove stray points before splatting (statistical and\n"
        << "                         planarity rules, k=" << d.outliers.k << ") ["
        << (d.outliers.enabled ? "on" : "off") << "]\n"
        << "  --normals MODE         " << choice_list(normal_mode_choices(), "|") << " ["
        << choice_name(normal_mode_choices(), d.normals.mode) << "]\n"
        << "  --k K                  neighbours for normals and spacing [" << d.normals.k << "]\n"
        << "  --scale MODE           per-point scale: " << choice_list(scale_mode_choices(), "|") << " ["
        << choice_name(scale_mode_choices(), d.normals.scale) << "]\n"
        << "  --knn NAME             neighbour search: " << choice_list(knn_backend_choices(), "|")
        << " (FLANN's kd-tree) ["
        << choice_name(knn_backend_choices(), d.normals.knn.backend) << "]\n"
        << "  --knn-eps E            flann: eps-approximate search (no neighbour farther than\n"
        << "                         sqrt(1+E) x the true k-th; huge clouds); 0 = exact ["
        << fmt(d.normals.knn.eps) << "]\n"
        << "  --viewpoint x,y,z      sensor position; estimated normals face it [none]\n"
        << "  --up x,y,z             direction estimated normals face (airborne: 0,0,1); like\n"
           "                         --viewpoint, lets --tile stream a cloud without\n"
           "                         normals [none; LAS files: 0,0,1]\n"
        << "  --orient RULE          " << choice_list(orient_rule_choices(), "|")
        << ", without --viewpoint/--up: auto faces a height\n"
           "                         field up, a depth camera's frame its origin, anything else\n"
           "                         by MST (closed objects out, open sheets up); mst: the MST\n"
           "                         always ["
        << choice_name(orient_rule_choices(), d.normals.orient) << "]\n";
}

/// The reconstruction options of the stage group "splat", with their defaults.
void help_splat() {
    const PipelineOptions d;
    std::cout
        << "\nsplat options:\n"
        << "  --voxel V              voxel edge, world units [auto: " << fmt(d.auto_voxel_factor)
        << " x median point spacing]\n"
        << "  --sigma S              kernel width, sigma = S x per-point scale ["
        << fmt(d.splat.scale_factor) << "]\n"
        << "  --sigma-voxels S       sigma for points without a scale, voxels ["
        << fmt(d.splat.sigma_voxels) << "]\n"
        << "  --min-sigma S          smallest sigma, voxels [" << fmt(d.splat.min_sigma_voxels)
        << "]\n"
        << "  --max-sigma S          largest sigma, voxels [" << fmt(d.splat.max_sigma_voxels)
        << "]\n"
        << "  --support R            kernel support radius, sigmas [" << fmt(d.splat.support)
        << "]\n"
        << "  --min-weight W         voxels with less weight are empty (W/5 near the surface) ["
        << fmt(d.splat.min_weight) << "]\n"
        << "  --crease-angle A       sample normals this far apart (degrees) meet at a sharp\n"
        << "                         crease: each face's own field, no blend ["
        << fmt(d.splat.crease_angle) << "; 0: off]\n"
        << "  --aggregate C          presum the samples of one cell of C sigmas (one sigma\n"
        << "                         level, normals within the crease angle) into one kernel;\n"
        << "                         a point cloud's cells at most "
        << fmt(d.splat.aggregate_max_cell) << " voxels; 0 = off [" << fmt(d.splat.aggregate)
        << "; fuse: " << fmt(DepthOptions{}.aggregate) << "]\n";
}

/// The reconstruction options of the stage group "close", with their defaults.
void help_close() {
    const PipelineOptions d;
    std::cout << "\nclose options:\n"
        << "  --close R              close holes up to ~2R voxels across (dilate, fill, erode);\n"
        << "                         open borders stay [" << d.close.hole_radius << ": off]\n"
        << "  --close-solid R        close concavities narrower than ~2R voxels of a\n"
        << "                         watertight surface [" << d.close.solid_radius << ": off]\n";
}

/// The reconstruction options of the stage group "mesh", with their defaults.
void help_mesh() {
    const PipelineOptions d;
    std::cout
        << "\nmesh options:\n"
        << "  --mesher NAME          " << choice_list(mesher_choices(), "|") << " ["
        << choice_name(mesher_choices(), d.mesh.method) << "]\n"
        << "  --adaptivity A         volumeToMesh adaptivity 0..1, --mesher vdb only ["
        << fmt(d.mesh.adaptivity) << "]\n"
        << "  --surface-weight W     faces whose summed weight is below W times the weight at\n"
        << "                         their nearest point, reached from an open border, are\n"
        << "                         trimmed (ghost sheets past a scan's edge; 0 = off) ["
        << fmt(d.mesh.min_surface_weight) << "]\n"
        << "  --max-gap G            faces farther than G voxels (and 2.5 point spacings) from\n"
        << "                         every point are trimmed [" << fmt(d.mesh.max_gap) << "]\n"
        << "  --min-samples N        drop pieces backed by fewer than N samples (their area in\n"
           "                         sample spacings^2, times their weight where below the\n"
           "                         typical), 0 = keep all ["
        << fmt(d.clean.min_component_samples) << "]\n"
        << "  --min-component R      also drop pieces with fewer faces than R x the largest's\n"
           "                         (for one object; 1 = the largest only) ["
        << fmt(d.clean.min_component_ratio) << "]\n"
        << "  --smooth N             Taubin lambda|mu smoothing iterations ["
        << d.clean.smooth_iterations << "]\n";
}

/// The reconstruction options of the stage group "refine", with their defaults.
void help_refine() {
    const PipelineOptions d;
    std::cout << "\nrefine options:\n"
        << "  --fill-holes N         fill the mesh's boundary loops of at most N edges with a\n"
        << "                         fair patch (Liepa 2003) [" << d.fill_holes << ": off]\n"
        << "  --watertight           a closed, manifold, one-piece mesh: keep the largest piece,\n"
        << "                         fill every hole; its volume goes to <out>.closed.vdb [off]\n"
        << "  --decimate R           keep at most R of the faces (QEM edge collapses, Garland &\n"
        << "                         Heckbert 1997; topology, borders and colours kept) [1: off]\n"
        << "  --max-error E          stop decimating before a collapse moves the surface more\n"
        << "                         than E, world units [0: no limit]\n"
        << "  --placement P          decimated vertex: edge (the quadric's minimum on the edge)\n"
        << "                         or free (its unconstrained minimum) [edge]\n"
        << "  --planes               planar regions with crisp edges and corners, each\n"
        << "                         re-triangulated with few faces; region id per face [off]\n"
        << "  --plane-angle A        a face joins a region within A degrees of its plane ["
        << fmt(d.planes.angle) << "]\n"
        << "  --plane-distance D     ... and with its vertices within D voxels of it ["
        << fmt(d.planes.distance) << "]\n"
        << "  --plane-min-area A     smaller regions are no plane, square voxels ["
        << fmt(d.planes.min_area) << "]\n"
        << "  --plane-error E        the re-triangulation (regions and the rest of the mesh)\n"
        << "                         moves the surface by at most E voxels ["
        << fmt(d.planes.max_error) << "]\n"
        << "  --texture              textures for the planar regions from the points' colours\n"
        << "                         (turns --planes on): OUT.obj + OUT.mtl + OUT.texture.png [off]\n"
        << "  --texel T              texture texel edge, world units [half a voxel]\n";
}

/// The reconstruction options of the stage group "tiles and memory", with their defaults.
void help_tiles() {
    const PipelineOptions d;
    std::cout << "\ntiles and memory options:\n"
        << "  --max-memory SIZE      memory budget, e.g. 8G, 500M: a run that would need more\n"
           "                         tiles itself (--tile 0: refuses it)\n"
        << "                         [half the physical memory: " << fmt_bytes(memory_budget(d.splat))
        << "]\n"
        << "  --tile N|auto          splat, close and mesh tiles of N^3 voxels one at a time\n"
        << "                         (each with a halo of samples): less memory, the same mesh;\n"
        << "                         auto: the largest that fits --max-memory; no .vdb is\n"
        << "                         written; 0: never, not even over --max-memory\n"
           "                         [0: untiled unless over --max-memory]\n"
        << "  --stream MODE          tiles: read a PLY file with normals (with --up or\n"
        << "                         --viewpoint: a PLY, LAS or text file) a chunk at a time\n"
        << "                         and run the point stages a region at a time (memory\n"
        << "                         bounded by a region, the same mesh): "
        << choice_list(stream_mode_choices(), "|") << ";\n"
        << "                         auto: when the points would take over half of\n"
        << "                         --max-memory ["
        << choice_name(stream_mode_choices(), d.stream) << "]\n"
        << "  --job-dir DIR          keep the tiled run's job directory in DIR: the same\n"
        << "                         command again resumes from the tiles it finished (the\n"
        << "                         same output); another input or options are refused\n"
        << "                         [none]\n"
        << "  --threads N            worker threads, 0 = all cores [" << d.threads << "]\n";
}

/// The reconstruction options of the stage group "output", with their defaults.
void help_output() {
    std::cout << "\noutput options:\n"
        << "  -o, --output PATH      mesh to write, .ply or .obj [<input stem>.recon.ply]\n"
        << "                         the volume goes to <output stem>.splat.vdb (and the\n"
        << "                         closed one to <output stem>.closed.vdb)\n"
        << "  --ascii                write ascii PLY [binary little endian]\n"
        << "  --no-vdb               do not write the .vdb volume\n"
        << "  --preview PATH         write a shaded picture of the mesh: .png, or .exr with a\n"
        << "                         depth channel Z [none]\n"
        << "  -q, --quiet            no progress or timings on stderr\n"
        << "  --help, --version\n";
}

/// Every reconstruction option, grouped by stage.
void help_reconstruction() {
    help_input();
    help_points();
    help_splat();
    help_close();
    help_mesh();
    help_refine();
    help_tiles();
    help_output();
}

/// fuse's own options.
void help_fuse() {
    std::cout
        << "\n"
        << "fuse options: SCENE is a transforms.json (NeRF/Blender: depth_file_path or\n"
        << "      file_path + _depth.exr/.png, transform_matrix in OpenGL axes), a folder of a\n"
        << "      dataset layout (TUM RGB-D, 7-Scenes/3DMatch, Redwood/Open3D, ScanNet,\n"
        << "      Replica/NICE-SLAM, KITTI LiDAR scans; detected from its files), an\n"
        << "      organized .pcd, or a point file of scans; depth images .exr (channel Z,\n"
        << "      depth, R, Y or a layer's .Z) or 16-bit .png. Every reconstruction option\n"
        << "      applies.\n"
        << "  --scan-origins FILE    SCENE is a point file of scans (PLY 'scan' property): their\n"
        << "                         sensors, 'x y z' per scan or a Stanford .conf (directions)\n"
        << "  --depth-scale S        PNG depth units per metre [transforms.json: 1/depth_scale,\n"
        << "                         TUM 5000, else 1000]\n"
        << "  --intrinsics fx,fy,cx,cy[,w,h]  pixels, pixel centres at integers (needed for TUM)\n"
        << "  --depth-kind K         planar (along the optical axis) or ray (range) [planar]\n"
        << "  --min-depth D, --max-depth D    depths outside are no measurement [0, none]\n"
        << "  --max-jump J           no normal across a depth jump > J x depth [0.05]\n"
        << "  --min-view-cos C       no sample seen more grazing than this cosine ["
        << fmt(DepthOptions{}.min_view_cos) << "]\n"
        << "  --reference-depth D    confidence falls as (D/depth)^2 beyond D [off]\n"
        << "  --fusion splat|tsdf    FSSR samples (default), or the classic truncated SDF along\n"
        << "                         the rays with free-space carving (VDBFusion/KinectFusion)\n"
        << "  --sdf-trunc T          tsdf truncation, voxels [4]; --no-carve: no carving\n"
        << "  --merge-footprint F    merge pixel blocks of frames whose footprint is below F,\n"
        << "                         world units; 0 = never [min-sigma x voxel / 2]\n"
        << "  --frame-step N, --max-frames N  every N-th frame; at most N frames [1, all]\n"
        << "  --skip-bad-frames      a frame that cannot be read or fused is skipped with a\n"
           "                         warning naming it [off: the run stops with its error]\n"
        << "  --min-range R, --max-range R  LiDAR scans: points nearer or farther than this\n"
           "                         from the sensor are no measurement, world units [0, none]\n"
        << "  --no-color             ignore the frames' colour images (.png, .jpg): a grey mesh\n"
           "                         [colour images fused into vertex colours]\n"
        << "  the voxel defaults to 1.4 x the first frame's median pixel footprint\n";
}

/// eval's options and the exit codes.
void help_eval() {
    const EvalOptions e;
    std::cout
        << "\n"
        << "eval options:\n"
        << "  --tau T[,T...]         F-score thresholds, world units [0.2% of REF's diagonal]\n"
        << "  --samples N            samples per mesh [" << e.samples << "]\n"
        << "  --mask-points FILE     points (e.g. the scan): REF regions farther than\n"
        << "                         --mask-distance from all of them are not counted in\n"
        << "                         completeness and recall [none]\n"
        << "  --mask-distance D      mask radius, world units (needed with --mask-points)\n"
        << "  --ignore-reference-holes\n"
        << "                         RECON's samples whose closest REF point is on REF's open\n"
        << "                         border (RECON covers a hole of REF) are not counted in\n"
        << "                         accuracy and precision [off]\n"
        << "\n"
        << "exit codes: 0 ok, 2 usage/invalid argument, 3 I/O or file format, 4 other error\n";
}

/// `vdbrecon --help`: the usage, the reconstruction options by stage, fuse's, eval's.
void print_help() {
    help_usage();
    help_reconstruction();
    help_fuse();
    help_eval();
}

/// `vdbrecon fuse --help`: fuse's own options first, then the reconstruction options.
void print_fuse_help() {
    help_usage();
    help_fuse();
    help_reconstruction();
    help_eval();
}

double parse_number(const std::string& opt, const std::string& s) {
    double v = 0.0;
    const char* b = s.c_str();
    const auto r = std::from_chars(b, b + s.size(), v);
    if (r.ec != std::errc() || r.ptr != b + s.size() || !std::isfinite(v)) {
        throw UsageError(opt + ": '" + s + "' is not a finite number");
    }
    return v;
}

int parse_int(const std::string& opt, const std::string& s) {
    int v = 0;
    const char* b = s.c_str();
    const auto r = std::from_chars(b, b + s.size(), v);
    if (r.ec != std::errc() || r.ptr != b + s.size()) {
        throw UsageError(opt + ": '" + s + "' is not an integer");
    }
    return v;
}

std::vector<double> parse_list(const std::string& opt, const std::string& s) {
    std::vector<double> out;
    std::size_t start = 0;
    while (start <= s.size()) {
        const std::size_t comma = s.find(',', start);
        const std::string part = s.substr(start, comma == std::string::npos ? std::string::npos
                                                                            : comma - start);
        out.push_back(parse_number(opt, part));
        if (comma == std::string::npos) break;
        start = comma + 1;
    }
    return out;
}

struct Args {
    std::vector<std::string> positional;
    std::size_t i = 0;
    std::vector<std::string> argv;

    bool done() const { return i >= argv.size(); }
    const std::string& next() { return argv[i++]; }
    std::string value(const std::string& opt) {
        if (done()) throw UsageError(opt + " needs a value");
        return next();
    }
};

void install_signal_handlers() {
    auto handler = [](int sig) {
        remove_temp_files_now();
        std::signal(sig, SIG_DFL);
        std::raise(sig);
    };
    std::signal(SIGINT, handler);
    std::signal(SIGTERM, handler);
}

long peak_rss_mb() {
    struct rusage ru {};
    getrusage(RUSAGE_SELF, &ru);
    return ru.ru_maxrss / 1024;
}

/// The resident memory now (/proc/self/statm), in MB; 0 where it cannot be read.
double resident_mb() {
    std::ifstream statm("/proc/self/statm");
    long size = 0, resident = 0;
    if (!(statm >> size >> resident)) return 0.0;
    return double(resident) * double(sysconf(_SC_PAGESIZE)) / (1024.0 * 1024.0);
}

int run_eval(Args& args) {
    EvalOptions options;
    std::vector<std::string> files;
    std::string mask_path;
    while (!args.done()) {
        const std::string a = args.next();
        if (a == "--tau") {
            options.taus = parse_list(a, args.value(a));
        } else if (a == "--samples") {
            const double n = parse_number(a, args.value(a));
            if (n < 1000 || n > 1e8 || n != std::floor(n)) {
                throw UsageError("--samples must be a whole number in 1000..1e8");
            }
            options.samples = std::size_t(n);
        } else if (a == "--mask-points") {
            mask_path = args.value(a);
        } else if (a == "--ignore-reference-holes") {
            options.ignore_reference_holes = true;
        } else if (a == "--mask-distance") {
            options.mask_distance = parse_number(a, args.value(a));
            if (!(options.mask_distance > 0.0)) throw UsageError("--mask-distance must be positive");
        } else if (!a.empty() && a[0] == '-') {
            throw UsageError("eval: unknown option '" + a + "'");
        } else {
            files.push_back(a);
        }
    }
    if (files.size() != 2) throw UsageError("eval needs two meshes: RECON REF");
    for (double t : options.taus) {
        if (!(t > 0.0)) throw UsageError("--tau values must be positive");
    }
    if (mask_path.empty() != (options.mask_distance == 0.0)) {
        throw UsageError("--mask-points and --mask-distance go together");
    }
    const Mesh recon = read_mesh(files[0]);
    const Mesh ref = read_mesh(files[1]);
    if (!mask_path.empty()) {
        PointCloud mask = read_points(mask_path).cloud;
        options.mask_points = mask.positions.release_vector();
        options.mask_origin = mask.origin;
    }
    std::cout << to_json(evaluate(recon, ref, options));
    return kExitOk;
}

/// `startup_rss_mb`: what the process held before it read anything, the executable and the
/// shared libraries the dynamic linker mapped (libopenvdb.so alone is 28 MB: its symbol tables
/// are read in full, since it is linked with BIND_NOW); the log says how much the run added.
/// Consumes option `a` (and its value) when it is one of the pipeline's; false otherwise.
bool parse_pipeline_option(const std::string& a, Args& args, PipelineOptions& o) {
    if (a == "--voxel") {
        o.splat.voxel_size = parse_number(a, args.value(a));
        if (!(o.splat.voxel_size > 0.0)) {
            throw UsageError("--voxel must be a positive number (got " +
                             fmt(o.splat.voxel_size) + ")");
        }
    } else if (a == "--sigma") {
        o.splat.scale_factor = parse_number(a, args.value(a));
    } else if (a == "--sigma-voxels") {
        o.splat.sigma_voxels = parse_number(a, args.value(a));
    } else if (a == "--min-sigma") {
        o.splat.min_sigma_voxels = parse_number(a, args.value(a));
    } else if (a == "--max-sigma") {
        o.splat.max_sigma_voxels = parse_number(a, args.value(a));
    } else if (a == "--support") {
        o.splat.support = parse_number(a, args.value(a));
    } else if (a == "--min-weight") {
        o.splat.min_weight = parse_number(a, args.value(a));
    } else if (a == "--crease-angle") {
        o.splat.crease_angle = parse_number(a, args.value(a));
    } else if (a == "--aggregate") {
        o.splat.aggregate = parse_number(a, args.value(a));
    } else if (a == "--surface-weight") {
        o.mesh.min_surface_weight = parse_number(a, args.value(a));
    } else if (a == "--max-gap") {
        o.mesh.max_gap = parse_number(a, args.value(a));
    } else if (a == "--normals") {
        o.normals.mode = parse_choice(a, args.value(a), normal_mode_choices());
    } else if (a == "--k") {
        o.normals.k = parse_int(a, args.value(a));
    } else if (a == "--stream") {
        o.stream = parse_choice(a, args.value(a), stream_mode_choices());
    } else if (a == "--job-dir") {
        o.job_dir = args.value(a);
    } else if (a == "--scale") {
        o.normals.scale = parse_choice(a, args.value(a), scale_mode_choices());
    } else if (a == "--knn") {
        o.normals.knn.backend = parse_choice(a, args.value(a), knn_backend_choices());
        o.outliers.knn.backend = o.normals.knn.backend;
    } else if (a == "--knn-eps") {
        o.normals.knn.eps = parse_number(a, args.value(a));
        o.outliers.knn.eps = o.normals.knn.eps;
    } else if (a == "--classes") {
        for (double c : parse_list(a, args.value(a))) {
            if (!(c >= 0 && c <= 255 && c == std::floor(c))) {
                throw UsageError("--classes: LAS classification codes are integers 0..255");
            }
            o.read.classes.push_back(int(c));
        }
    } else if (a == "--viewpoint") {
        const std::vector<double> v = parse_list(a, args.value(a));
        if (v.size() != 3) throw UsageError("--viewpoint needs three numbers: x,y,z");
        o.normals.viewpoint = Vec3d{v[0], v[1], v[2]};
    } else if (a == "--up") {
        const std::vector<double> v = parse_list(a, args.value(a));
        if (v.size() != 3) throw UsageError("--up needs three numbers: x,y,z");
        o.normals.up = Vec3d{v[0], v[1], v[2]};
    } else if (a == "--orient") {
        o.normals.orient = parse_choice(a, args.value(a), orient_rule_choices());
    } else if (a == "--outliers") {
        o.outliers.enabled = true;
    } else if (a == "--no-outliers") {
        o.outliers.enabled = false;
    } else if (a == "--close") {
        o.close.hole_radius = parse_int(a, args.value(a));
    } else if (a == "--close-solid") {
        o.close.solid_radius = parse_int(a, args.value(a));
    } else if (a == "--fill-holes") {
        const int n = parse_int(a, args.value(a));
        if (n < 0) throw UsageError(a + ": " + std::to_string(n) + " must be >= 0");
        o.fill_holes = std::size_t(n);
    } else if (a == "--watertight") {
        o.watertight = true;
    } else if (a == "--decimate") {
        o.decimate.ratio = parse_number(a, args.value(a));
    } else if (a == "--max-error") {
        o.decimate.max_error = parse_number(a, args.value(a));
    } else if (a == "--placement") {
        o.decimate.placement = parse_choice(a, args.value(a), placement_choices());
    } else if (a == "--planes") {
        o.planes.enabled = true;
    } else if (a == "--plane-angle") {
        o.planes.angle = parse_number(a, args.value(a));
    } else if (a == "--plane-distance") {
        o.planes.distance = parse_number(a, args.value(a));
    } else if (a == "--plane-min-area") {
        o.planes.min_area = parse_number(a, args.value(a));
    } else if (a == "--plane-error") {
        o.planes.max_error = parse_number(a, args.value(a));
    } else if (a == "--texture") {
        o.texture.enabled = true;
        o.planes.enabled = true;
    } else if (a == "--texel") {
        o.texture.texel = parse_number(a, args.value(a));
    } else if (a == "--mesher") {
        o.mesh.method = parse_choice(a, args.value(a), mesher_choices());
    } else if (a == "--adaptivity") {
        o.mesh.adaptivity = parse_number(a, args.value(a));
    } else if (a == "--min-samples") {
        o.clean.min_component_samples = parse_number(a, args.value(a));
    } else if (a == "--min-component") {
        o.clean.min_component_ratio = parse_number(a, args.value(a));
    } else if (a == "--smooth") {
        o.clean.smooth_iterations = parse_int(a, args.value(a));
    } else if (a == "--ascii") {
        o.write.encoding = PlyEncoding::ascii;
    } else if (a == "--threads") {
        o.threads = parse_int(a, args.value(a));
        if (o.threads < 0) throw UsageError("--threads must be >= 0");
    } else if (a == "--max-memory") {
        o.splat.max_memory = parse_bytes(a, args.value(a));
    } else if (a == "--preview") {
        o.preview_path = args.value(a);
    } else if (a == "--no-vdb") {
        o.write_vdb = false;
    } else if (a == "--tile") {
        const std::string v = args.value(a);
        o.tile = v == "auto" ? -1 : parse_int(a, v);
        o.auto_tile = o.tile != 0;
        if (o.tile < -1 || (o.tile == -1 && v != "auto")) {
            throw UsageError(a + ": " + v + " must be a number of voxels > 0, or auto");
        }
    } else {
        return false;
    }
    return true;
}

/// The options every run takes (-o, -q, the pipeline's) and its one positional input.
void parse_common_option(const std::string& a, Args& args, PipelineOptions& o, std::string& input,
                         std::string& output, bool& quiet) {
    if (a == "-o" || a == "--output") {
        output = args.value(a);
    } else if (a == "-q" || a == "--quiet") {
        quiet = true;
    } else if (parse_pipeline_option(a, args, o)) {
    } else if (a.size() > 1 && a[0] == '-') {
        throw UsageError("unknown option '" + a + "' (see --help)");
    } else if (input.empty()) {
        input = a;
    } else {
        throw UsageError("more than one input given ('" + input + "' and '" + a + "')");
    }
}

/// Warnings to stderr, and (unless quiet) information and each stage's start; returns the
/// stage callback.
StageCallback install_log_handler(bool quiet) {
    set_log_handler([quiet](LogLevel level, const std::string& m) {
        if (level == LogLevel::warning) {
            std::cerr << "vdbrecon: warning: " << m << "\n";
        } else if (level == LogLevel::info && !quiet) {
            std::cerr << "vdbrecon: " << m << "\n";
        }
    });
    return [quiet](const std::string& stage) {
        if (!quiet) std::cerr << "vdbrecon: " << stage << " ...\n";
    };
}

/// What a run did, on stderr; the output paths on stdout.
void report(const RunResult& r, const PipelineOptions& o,
            std::chrono::steady_clock::time_point start, double startup_rss_mb, bool fused) {
    const PipelineResult& p = r.result;
    {
        std::ostringstream s;
        if (fused) {
            s << "vdbrecon: fused " << r.read.rows << " samples (" << r.read.format << ")";
            if (p.splat.points > 0) s << " as " << p.splat.points << " kernels";
            s << "\n";
        } else {
            s << "vdbrecon: read " << r.read.rows << " rows (" << r.read.format << ")";
            if (p.stream_units == 0) s << ", " << fmt_megabytes(r.read.bytes) << " in memory";
            if (r.read.dropped_nonfinite) s << ", dropped " << r.read.dropped_nonfinite << " NaN/inf";
            s << "\n";
        }
        if (o.outliers.enabled) {
            s << "vdbrecon: outliers: removed " << p.outliers.statistical << " (statistical) + "
              << p.outliers.planarity << " (planarity) points\n";
        }
        if (!fused) {
            s << "vdbrecon: normals: ";
            if (p.normals.estimated == 0) {
                s << "from the file";
            } else {
                s << p.normals.estimated << " estimated (k=" << o.normals.k << "), oriented by "
                  << orientation_text(p.normals);
            }
            s << "; median scale " << p.normals.median_scale << "\n";
        }
        s << "vdbrecon: voxel " << p.voxel_size;
        if (p.voxel_chosen) {
            s << " (chosen: " << o.auto_voxel_factor << " x median "
              << (fused ? "pixel footprint of the first frame" : "spacing ") ;
            if (!fused) s << p.spacing;
            s << "; set --voxel to override)";
        }
        s << "\n";
        if (p.stream_units > 0) {
            s << "vdbrecon: points: streamed, never held whole; the point stages in "
              << p.stream_units << " regions, the largest " << p.stream_largest
              << " points with its halo\n";
        }
        if (!p.auto_tiled.empty()) {
            s << "vdbrecon: tiles: the run tiled itself (" << p.auto_tiled
              << "); no .vdb is written (no tile holds the whole volume); --tile 0 refuses "
                 "instead\n";
        }
        if (p.tile > 0) {
            s << "vdbrecon: tiles: " << p.tiles << " tiles of " << p.tile << "^3 voxels, halo "
              << p.tile_halo << " voxels, largest " << p.max_tile_points << " samples; "
              << p.splat.active_voxels << " valid voxels in " << p.splat.leaves
              << " leaves (halos counted in each tile)\n";
        } else {
            s << "vdbrecon: splat: sigma " << p.splat.sigma_min << " .. " << p.splat.sigma_max
              << " (median " << p.splat.sigma_median << "), ";
            if (p.splat.samples > p.splat.points) {
                s << p.splat.samples << " samples presummed into " << p.splat.points
                  << " kernels, ";
            }
            s << p.splat.active_voxels << " valid voxels in " << p.splat.leaves << " leaves, "
              << p.splat.updates << " kernel updates, grids " << fmt_megabytes(p.splat.memory_bytes)
              << " in memory";
            if (p.splat.skipped_points) s << ", " << p.splat.skipped_points << " points without normal";
            if (p.splat.crease_voxels) s << ", " << p.splat.crease_voxels << " voxels at creases";
            s << "\n";
        }
        if (o.close.hole_radius > 0) {
            s << "vdbrecon: close: " << p.close.supported_voxels << " supported voxels -> "
              << p.close.closed_voxels << " after closing by " << o.close.hole_radius << ", "
              << p.close.filled_voxels << " filled\n";
        }
        if (o.close.solid_radius > 0) {
            s << "vdbrecon: close-solid: " << p.close.solid_voxels_before << " -> "
              << p.close.solid_voxels_after << " voxels inside\n";
        }
        if (r.vdb_grid_bytes) {
            s << "vdbrecon: vdb: grids written " << fmt_megabytes(r.vdb_grid_bytes)
              << " in memory (the splat's and the density grid made for the file)\n";
        }
        s << "vdbrecon: mesh: " << p.mesh.vertices.size() << " vertices, " << p.mesh.faces.size()
          << " triangles (" << p.mesh_stats.dropped_faces << " dropped outside valid cells, "
          << p.mesh_stats.trimmed_faces << " trimmed as unsupported)\n";
        s << "vdbrecon: clean: removed " << p.clean_stats.removed_components << " of "
          << p.clean_stats.components_before << " pieces (" << p.clean_stats.removed_faces
          << " faces): " << p.clean_stats.removed_unsupported << " backed by fewer than "
          << fmt(o.clean.min_component_samples) << " samples";
        if (o.clean.min_component_ratio > 0.0 || o.watertight) {
            s << ", " << p.clean_stats.removed_small << " smaller than "
              << (o.watertight ? 1.0 : o.clean.min_component_ratio) << " x the largest";
        }
        if (p.clean_stats.smoothed_iterations) {
            s << ", " << p.clean_stats.smoothed_iterations << " Taubin iterations";
        }
        s << "\n";
        if (p.decimation.faces_before > 0) {
            s << "vdbrecon: decimate: " << p.decimation.faces_before << " -> "
              << p.decimation.faces_after << " faces (" << p.decimation.collapses
              << " collapses, largest error " << p.decimation.max_error << ")\n";
        }
        if (o.planes.enabled) {
            s << "vdbrecon: planes: " << p.planes.planes.size() << " planar regions ("
              << p.planes.planar_faces << " of " << p.planes.faces_before << " faces), "
              << p.planes.edge_vertices << " vertices onto edges, " << p.planes.corner_vertices
              << " onto corners; " << p.planes.faces_before << " -> " << p.planes.faces_after
              << " faces, " << p.planes.flips << " Delaunay flips\n";
        }
        if (!p.texture.empty()) {
            s << "vdbrecon: texture: " << p.texture.regions << " regions in a " << p.texture.width
              << " x " << p.texture.height << " atlas, texel " << p.texture.texel << "; "
              << p.texture.points << " points coloured " << p.texture.texels_seen << " of "
              << p.texture.texels << " texels (the rest interpolated)\n";
        }
        if (p.holes.loops > 0) {
            s << "vdbrecon: fill: " << p.holes.filled << " of " << p.holes.loops
              << " holes filled (" << p.holes.added_faces << " faces; largest " << p.holes.largest_filled
              << " edges";
            if (p.holes.largest_open) s << ", largest left open " << p.holes.largest_open;
            s << ")\n";
        }
        s << "vdbrecon: time:";
        std::ostringstream mem;
        mem << "vdbrecon: peak memory after:";
        for (const StageTiming& t : p.timings) {
            s << " " << t.stage << " " << std::fixed;
            s.precision(3);
            s << t.seconds << " s,";
            mem << " " << t.stage << " " << long(t.peak_rss_mb) << " MB,";
        }
        const double wall =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        const long peak = peak_rss_mb();
        s << " wall " << wall << " s; peak memory " << peak << " MB, "
          << std::lround(double(peak) - startup_rss_mb) << " MB above the "
          << std::lround(startup_rss_mb) << " MB at start-up\n";
        std::string m = mem.str();
        m.back() = '\n';
        s << m;
        std::cerr << s.str();
        std::cout << "mesh: " << r.mesh_path << "\n";
        if (!r.vdb_path.empty()) std::cout << "volume: " << r.vdb_path << "\n";
        if (!o.preview_path.empty()) std::cout << "preview: " << o.preview_path << "\n";
        if (!r.closed_vdb_path.empty()) std::cout << "closed volume: " << r.closed_vdb_path << "\n";
        if (!r.material_path.empty()) std::cout << "material: " << r.material_path << "\n";
        if (!r.texture_path.empty()) std::cout << "texture: " << r.texture_path << "\n";
    }
}

/// Ends the process once every output is written and reported, without destroying the run's
/// results: the system takes their memory back at once, where freeing the grids' leaves and the
/// mesh one by one (two threads contending for the heap) took 0.03-0.04 s of the bunny's 0.8 s.
[[noreturn]] void finish(int code) {
    std::cout.flush();
    std::cerr.flush();
    std::fflush(nullptr);
    std::_Exit(code);
}

/// The volumes stay in the result, not freed (the process ends without destroying them, see
/// finish), unless a preview is rendered after the stages: it then reuses their memory.
void keep_volumes_unless_preview(PipelineOptions& o) { o.keep_volumes = o.preview_path.empty(); }

int run_reconstruct(Args& args, double startup_rss_mb) {
    const auto start = std::chrono::steady_clock::now();
    PipelineOptions o;
    std::string input, output;
    bool quiet = false;
    while (!args.done()) {
        parse_common_option(args.next(), args, o, input, output, quiet);
    }
    if (input.empty()) throw UsageError("no input file (see --help)");
    keep_volumes_unless_preview(o);

    const StageCallback on_stage = install_log_handler(quiet);
    const RunResult r = run(input, output, o, on_stage);
    if (!quiet) report(r, o, start, startup_rss_mb, false);
    finish(kExitOk);
}

int run_fuse(Args& args, double startup_rss_mb) {
    const auto start = std::chrono::steady_clock::now();
    PipelineOptions o;
    FuseOptions f;
    std::string input, output;
    bool quiet = false;
    while (!args.done()) {
        const std::string a = args.next();
        if (a == "--depth-scale") {
            f.scene.units_per_metre = parse_number(a, args.value(a));
            if (!(f.scene.units_per_metre > 0.0)) throw UsageError("--depth-scale must be > 0");
        } else if (a == "--intrinsics") {
            const std::vector<double> v = parse_list(a, args.value(a));
            if (v.size() != 4 && v.size() != 6) {
                throw UsageError("--intrinsics needs fx,fy,cx,cy (or fx,fy,cx,cy,width,height)");
            }
            Intrinsics K{v[0], v[1], v[2], v[3], 0, 0};
            if (v.size() == 6) K.width = int(v[4]), K.height = int(v[5]);
            f.scene.intrinsics = K;
        } else if (a == "--depth-kind") {
            f.depth.kind = parse_choice(a, args.value(a), depth_kind_choices());
        } else if (a == "--min-depth") {
            f.depth.min_depth = parse_number(a, args.value(a));
        } else if (a == "--max-depth") {
            f.depth.max_depth = parse_number(a, args.value(a));
        } else if (a == "--max-jump") {
            f.depth.max_jump = parse_number(a, args.value(a));
        } else if (a == "--min-view-cos") {
            f.depth.min_view_cos = parse_number(a, args.value(a));
        } else if (a == "--scan-origins") {
            f.scan_sensors = args.value(a);
        } else if (a == "--fusion") {
            f.depth.rule = parse_choice(a, args.value(a), fusion_rule_choices());
        } else if (a == "--sdf-trunc") {
            f.depth.truncation = parse_number(a, args.value(a));
        } else if (a == "--no-carve") {
            f.depth.carve = false;
        } else if (a == "--merge-footprint") {
            f.depth.merge_footprint = parse_number(a, args.value(a));
        } else if (a == "--aggregate") {
            f.depth.aggregate = parse_number(a, args.value(a));
        } else if (a == "--reference-depth") {
            f.depth.reference_depth = parse_number(a, args.value(a));
        } else if (a == "--skip-bad-frames") {
            f.skip_bad_frames = true;
        } else if (a == "--no-color") {
            f.color = false;
        } else if (a == "--min-range" || a == "--max-range") {
            const double r = parse_number(a, args.value(a));
            if (!(std::isfinite(r) && r >= 0.0)) throw UsageError(a + " must be >= 0");
            (a == "--min-range" ? f.min_range : f.max_range) = r;
        } else if (a == "--frame-step" || a == "--max-frames") {
            const int n = parse_int(a, args.value(a));
            if (n < (a == "--frame-step" ? 1 : 0)) throw UsageError(a + ": " + std::to_string(n) + " is out of range");
            (a == "--frame-step" ? f.frame_step : f.max_frames) = std::size_t(n);
        } else {
            parse_common_option(a, args, o, input, output, quiet);
        }
    }
    if (input.empty()) throw UsageError("fuse: no scene (a transforms.json or a TUM folder)");
    keep_volumes_unless_preview(o);
    const StageCallback on_stage = install_log_handler(quiet);
    const RunResult r = fuse(input, output, o, f, on_stage);
    if (!quiet) report(r, o, start, startup_rss_mb, true);
    finish(kExitOk);
}

}  // namespace

/// Keeps freed memory in the heap for the next stage: each stage allocates and frees arrays of
/// tens of MB, which glibc would otherwise map afresh and page-fault in every time (9 % of the
/// CPU time on the bunny). Costs a few MB of peak memory (210 -> 217 MB on the bunny).
/// One heap (arena) for all threads: with one per worker thread, memory one worker freed could
/// not serve the next stage's allocations on another (bunny 0.5 mm, 2 threads: peak 200-204 ->
/// 194 MB); the stages allocate in large blocks, so the shared lock is rarely taken.
void tune_heap() {
    mallopt(M_MMAP_THRESHOLD, 32 << 20);  // glibc's largest: bigger blocks are still mapped
    mallopt(M_TRIM_THRESHOLD, 1 << 30);
    mallopt(M_ARENA_MAX, 1);
}

int main(int argc, char** argv) {
    tune_heap();
    Args args;
    args.argv.assign(argv + 1, argv + argc);
    install_signal_handlers();
    try {
        if (args.argv.empty()) {
            print_help();
            return kExitUsage;
        }
        for (const std::string& a : args.argv) {
            if (a == "--help" || a == "-h") {
                if (args.argv[0] == "fuse") {
                    print_fuse_help();
                } else {
                    print_help();
                }
                return kExitOk;
            }
            if (a == "--version") {
                std::cout << "vdbrecon " << version() << "\n";
                return kExitOk;
            }
        }
        if (args.argv[0] == "eval") {
            args.i = 1;
            return run_eval(args);
        }
        if (args.argv[0] == "fuse") {
            args.i = 1;
            return run_fuse(args, resident_mb());
        }
        return run_reconstruct(args, resident_mb());
    } catch (const UsageError& e) {
        std::cerr << "vdbrecon: error: " << e.what() << "\n";
        return kExitUsage;
    } catch (const InvalidArgument& e) {
        std::cerr << "vdbrecon: error: " << e.what() << "\n";
        return kExitUsage;
    } catch (const IoError& e) {
        std::cerr << "vdbrecon: error: " << e.what() << "\n";
        return kExitIo;
    } catch (const FormatError& e) {
        std::cerr << "vdbrecon: error: " << e.what() << "\n";
        return kExitIo;
    } catch (const std::bad_alloc&) {
        std::cerr << "vdbrecon: error: out of memory. Hint: a larger --voxel\n";
        return kExitOther;
    } catch (const std::exception& e) {
        std::cerr << "vdbrecon: error: " << e.what() << "\n";
        return kExitOther;
    }
}
