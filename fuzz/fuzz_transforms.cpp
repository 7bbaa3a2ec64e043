// libFuzzer target: transforms.json (read_scene), in a folder that also holds the files its
// frames' file_path may name: r_0.png with r_0_depth.png, r_1_depth_0001.exr, d.exr
// (scripts/fuzz.sh).
#include "fuzz_scene.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using namespace vdbrecon;
    static const fuzz::fs::path dir = [] {
        const fuzz::fs::path d = fuzz::scratch() / "transforms";
        fuzz::fs::create_directories(d);
        for (const char* name : {"r_0.png", "r_0_depth.png", "r_1_depth_0001.exr", "d.exr"}) {
            fuzz::write_file(d / name, "");
        }
        return d;
    }();
    const std::string json = (dir / "transforms.json").string();
    fuzz::write_file(json, std::string_view(reinterpret_cast<const char*>(data), size));
    fuzz::read_scene_at(json, dir, SceneOptions{});
    return 0;
}
