// libFuzzer target: the scene folders of the dataset layouts (read_scene of a folder: TUM,
// 7-Scenes / 3DMatch, Redwood / Open3D, ScanNet, Replica, KITTI with its .bin scans), plus the
// frame files that come with them: scan sensors (*.conf, *sensors.txt) and organized PCD
// clouds (*.pcd). The input is the folder's files (fuzz_scene.h); the scene is read with and
// without intrinsics given (TUM needs them) (scripts/fuzz.sh).
#include "fuzz_scene.h"

namespace {

using namespace vdbrecon;

void read_sensors(const std::string& path, const fuzz::fs::path& dir) {
    try {
        const ScanSensors s = read_scan_sensors(path);
        fuzz::check(s.size() > 0, "a sensor file has sensors");
        for (const Vec3d& o : s.origins) {
            fuzz::check(std::isfinite(o[0] + o[1] + o[2]), "sensor positions are finite");
        }
        for (const Vec3d& d : s.directions) {
            const double n = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            fuzz::check(std::fabs(n - 1.0) < 1e-6, "sensor directions are unit vectors");
        }
    } catch (const Error& e) {
        fuzz::check_error_in(e, dir);
    }
}

void read_organized(const std::string& path, const fuzz::fs::path& dir) {
    try {
        const OrganizedCloud c = read_organized_cloud(path);
        fuzz::check(c.width > 0 && c.height > 1, "an organized cloud is a raster");
        fuzz::check(c.points.size() == std::size_t(c.width) * std::size_t(c.height),
                    "an organized cloud has width x height points");
        fuzz::check(c.colors.empty() || c.colors.size() == c.points.size(), "one colour a point");
    } catch (const Error& e) {
        fuzz::check_error_in(e, dir);
    }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const fuzz::fs::path dir = fuzz::scratch() / "scene";
    const std::vector<std::string> names =
        fuzz::write_folder(dir, std::string_view(reinterpret_cast<const char*>(data), size));
    fuzz::read_scene_at(dir.string(), dir, SceneOptions{});
    SceneOptions given;
    given.intrinsics = Intrinsics{525.0, 525.0, 319.5, 239.5, 640, 480};
    fuzz::read_scene_at(dir.string(), dir, given);
    for (const std::string& name : names) {
        const std::string path = (dir / name).string(), ext = file_extension(path);
        const bool sensors =
            name.size() >= 11 && name.compare(name.size() - 11, 11, "sensors.txt") == 0;
        if (ext == "conf" || sensors) read_sensors(path, dir);
        if (ext == "pcd") read_organized(path, dir);
    }
    return 0;
}
