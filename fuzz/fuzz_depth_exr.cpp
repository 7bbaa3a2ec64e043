// libFuzzer target: read_depth_image of a OpenEXR depth image (OpenEXR 3) (scripts/fuzz.sh).
#include "fuzz_scene.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    return vdbrecon::fuzz::read_depth(data, size, "exr");
}
